"""RINEX files joined by ``cat`` (a software receiver's two runs in one file; RTKLIB reads on): a further header
whose version, type and observation types are the first's is skipped and said (io/rinex._without_repeated_headers);
one of other observation types is refused naming its line.  Checked on real files cut in two and joined again with
the header between: the same tables and the same ``rtk`` solution as the whole files."""

from __future__ import annotations

import json

import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
from cdgps_cli.io.rinex_signals import read_rinex_signals
from tests._shared import MOSAIC_DIR, REPO_ROOT, run_cli

GEONET = REPO_ROOT / "tests" / "data" / "07590920.05o"


def _joined(path, at: float = 0.5) -> tuple[str, int]:
    """The file's text cut at an epoch line near ``at`` of its body and joined again with its header between, and the
    line the second header starts at."""
    lines = path.read_text().splitlines(keepends=True)
    end = next(i for i, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    v3 = lines[0].lstrip()[:1] == "3"
    cut = next(i for i in range(end + int(at * (len(lines) - end)), len(lines))
               if (lines[i].startswith(">") if v3 else lines[i][:1] == " " and lines[i][28:29] == "0"
                   and lines[i][3:4] == " " and lines[i][26:27] == "."))
    return "".join(lines[:cut] + lines[:end] + lines[cut:]), cut + 1


@pytest.mark.parametrize("path", [GEONET, MOSAIC_DIR / "rover.obs"], ids=["rinex2-geonet", "rinex3-mosaic"])
def test_a_file_joined_with_its_header_between_reads_as_the_whole_file(tmp_path, path):
    if not path.exists():
        pytest.skip(f"{path} absent")
    text, line = _joined(path)
    (tmp_path / "joined.obs").write_text(text)
    h1, whole = read_rinex_obs(path)
    h2, joined = read_rinex_obs(tmp_path / "joined.obs")
    assert joined.equals(whole) and h2["repeated_headers"] == [line] and "repeated_headers" not in h1
    if path.suffix == ".obs":
        sig = ("G:L1", "E:E1")
        assert read_rinex_signals(tmp_path / "joined.obs", sig)[1].equals(read_rinex_signals(path, sig)[1])


def test_rtk_reads_on_and_says_so(tmp_path):
    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    text, line = _joined(MOSAIC_DIR / "rover.obs", 0.3)
    (tmp_path / "rover.obs").write_text(text)
    nav = (MOSAIC_DIR / "base.nav").read_text()
    end = next(i for i, ln in enumerate(nav.splitlines(keepends=True)) if ln[60:].strip() == "END OF HEADER") + 1
    head = "".join(nav.splitlines(keepends=True)[:end])
    (tmp_path / "base.nav").write_text(nav + head + nav[len(head):])     # a navigation file joined to itself
    assert read_rinex_nav(tmp_path / "base.nav").equals(read_rinex_nav(MOSAIC_DIR / "base.nav"))
    out = {}
    for name, rover, navf in (("joined", tmp_path / "rover.obs", tmp_path / "base.nav"),
                              ("whole", MOSAIC_DIR / "rover.obs", MOSAIC_DIR / "base.nav")):
        r = run_cli("-q", "rtk", "--base", MOSAIC_DIR / "base.obs", "--rover", rover, "--nav", navf, "--signals",
                    "G:L1", "-o", tmp_path / f"{name}.pos", "--json")
        assert r.exit_code == 0, r.output
        out[name] = json.loads(r.output[r.output.index("{"):])
    assert out["joined"]["static_xyz_m"] == out["whole"]["static_xyz_m"]
    assert any(f"a second header at line(s) {line}" in w for w in out["joined"]["warnings"])


def test_a_second_header_of_other_observation_types_is_refused_naming_its_line(tmp_path):
    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    text, line = _joined(MOSAIC_DIR / "rover.obs")
    lines = text.splitlines(keepends=True)
    k = next(i for i in range(line - 1, len(lines)) if lines[i][60:].strip() == "SYS / # / OBS TYPES")
    lines[k] = lines[k][:7] + lines[k][11:60] + "    " + lines[k][60:]      # one type fewer in the second header
    (tmp_path / "joined.obs").write_text("".join(lines))
    with pytest.raises(CdgpsError, match=rf"joined.obs: line {line}: a second header whose version, file type or "
                                         r"observation types are not the first's"):
        read_rinex_obs(tmp_path / "joined.obs")


def test_an_events_header_lines_are_not_a_second_header(tmp_path):
    """An event (epoch flag 4) whose special records repeat the file's version line is the receiver's own header
    information, read as before; a header joined after it still is a second header (a review found both cut)."""
    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    lines = (MOSAIC_DIR / "rover.obs").read_text().splitlines(keepends=True)
    end = next(i for i, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    epochs = [i for i in range(end, len(lines)) if lines[i].startswith(">")]
    c1, c2 = epochs[len(epochs) // 4], epochs[3 * len(epochs) // 4]
    event = [lines[0], "RECORDING RESUMED".ljust(60) + "COMMENT\n"]
    block = ">".ljust(31) + "4" + f"{len(event):3d}\n" + "".join(event)
    head = "".join(lines[:end])
    (tmp_path / "event.obs").write_text(head + "".join(lines[end:c1]) + block + "".join(lines[c1:]))
    (tmp_path / "both.obs").write_text(head + "".join(lines[end:c1]) + block + "".join(lines[c1:c2]) + head
                                       + "".join(lines[c2:]))
    _, whole = read_rinex_obs(MOSAIC_DIR / "rover.obs")
    h, ev = read_rinex_obs(tmp_path / "event.obs")
    assert ev.equals(whole) and "repeated_headers" not in h
    h, both = read_rinex_obs(tmp_path / "both.obs")
    assert both.equals(whole) and len(h["repeated_headers"]) == 1


def test_hatanaka_files_joined_are_read_and_the_decompressors_note_said(tmp_path):
    """Compact RINEX files joined by ``cat``: crx2rnx reads on by itself; what it says is a cdgps warning (it was a
    raw Python warning, twice)."""
    import warnings  # noqa: PLC0415

    import hatanaka  # noqa: PLC0415

    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    text = (MOSAIC_DIR / "rover.obs").read_text()
    lines = text.splitlines(keepends=True)
    end = next(i for i, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    cut = [i for i in range(end, len(lines)) if lines[i].startswith(">")][150]
    halves = ["".join(lines[:cut]), "".join(lines[:end] + lines[cut:])]
    (tmp_path / "cat.crx").write_bytes(b"".join(hatanaka.rnx2crx(h.encode()) for h in halves))
    with warnings.catch_warnings():
        warnings.simplefilter("error")                              # (none may reach Python's warnings)
        h, joined = read_rinex_obs(tmp_path / "cat.crx")
    assert joined.equals(read_rinex_obs(MOSAIC_DIR / "rover.obs")[1])
    assert any("crx2rnx" in x for x in h["decompress_notes"]) and "repeated_headers" not in h
