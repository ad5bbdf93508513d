"""An epoch a logger wrote twice in a row (the same time tag) is read once, the first record, and noted in the
header's ``repeated_epochs`` (io/rinex.py); ``config``/``ingest`` refused such a file ("repeats the previous epoch")
where ``rtk`` warned and used it (the adversarial sweep of session 20, D11).  Epochs going backwards stay refused."""

from __future__ import annotations

import json

import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import read_rinex_obs
from cdgps_cli.io.rinex_signals import first_of_repeated_epochs, read_rinex_signals
from tests._shared import REPO_ROOT, run_cli

SHARED = REPO_ROOT.parent / "shared" / "data"
MOSAIC = SHARED / "real-pairs" / "mosaic-static"
GEONET_V2 = SHARED / "rinex" / "07590920.05o"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data absent")


def _epochs(text: str):
    """(header lines, [epoch blocks of lines]) of a RINEX 3 or 2 observation text."""
    lines = text.splitlines(keepends=True)
    end = next(i for i, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    head, body = lines[:end], lines[end:]
    if head[0][:9].strip().startswith("3"):
        starts = [i for i, ln in enumerate(body) if ln.startswith(">")]
        return head, [body[a:b] for a, b in zip(starts, starts[1:] + [len(body)])]
    n_types = next(int(ln[:6]) for ln in head if ln[60:].strip() == "# / TYPES OF OBSERV")
    per_sat, blocks, i = -(-n_types // 5), [], 0
    while i < len(body):
        nsat = int(body[i][29:32])
        size = 1 + (nsat - 1) // 12 + nsat * per_sat
        blocks.append(body[i:i + size])
        i += size
    return head, blocks


def _edited(src, tmp_path, how: str, k: int = 40):
    head, blocks = _epochs(src.read_text())
    if how == "repeat":
        blocks.insert(k + 1, list(blocks[k]))
    else:                                                  # two epochs swapped
        blocks[k], blocks[k + 1] = blocks[k + 1], blocks[k]
    p = tmp_path / f"{how}_{src.name}"
    p.write_text("".join(head) + "".join("".join(b) for b in blocks))
    return p, len(head) + sum(len(b) for b in blocks[:k + 1]) + 1


@pytest.mark.parametrize("src", [MOSAIC / "rover.obs", GEONET_V2], ids=["rinex3", "rinex2"])
def test_an_epoch_written_twice_is_read_once(tmp_path, src):
    if not src.exists():
        pytest.skip(f"{src} absent")
    p, line = _edited(src, tmp_path, "repeat")
    hdr0, obs0 = read_rinex_obs(src)
    hdr, obs = read_rinex_obs(p)
    assert obs.equals(obs0) and hdr["n_epochs"] == hdr0["n_epochs"]
    assert [(r["line"], r["time_gps_s"]) for r in hdr["repeated_epochs"]] == [(line, obs0["time_gps_s"].unique()[40])]
    assert "repeated_epochs" not in hdr0
    if src.suffix == ".obs":                               # the signal reader's table, kept once the same way
        sig0 = read_rinex_signals(src, ["G:L1", "G:L2"])[1]
        sig, times, n_rows = first_of_repeated_epochs(read_rinex_signals(p, ["G:L1", "G:L2"])[1])
        assert sig.equals(sig0) and times.size == 1 and n_rows > 0


def test_epochs_going_backwards_stay_refused(tmp_path):
    p, line = _edited(MOSAIC / "rover.obs", tmp_path, "swap")
    with pytest.raises(CdgpsError, match=r"earlier than the previous epoch"):
        read_rinex_obs(p)


def test_config_ingest_init_take_a_rover_with_an_epoch_written_twice(tmp_path):
    """The real mosaic pair, the rover's epoch 40 written twice: config → ingest → init exit 0, ingest warns naming
    the file and the line, and INIT's states are the unedited pair's."""
    p, line = _edited(MOSAIC / "rover.obs", tmp_path, "repeat")
    got = {}
    for rover, tag in ((MOSAIC / "rover.obs", "ref"), (p, "rep")):
        for args in (("config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={rover}", "--nav",
                      MOSAIC / "base.nav", "--master", "base", "-o", tmp_path / f"{tag}.toml"),
                     ("ingest", "--config", tmp_path / f"{tag}.toml", "-o", tmp_path / f"{tag}.mcap"),
                     ("init", tmp_path / f"{tag}.mcap", "-o", tmp_path / f"{tag}.json")):
            r = run_cli(*args)
            assert r.exit_code == 0, (args[0], r.output)
            if args[0] == "ingest":
                said = [ln for ln in r.stderr.splitlines() if "written more than once" in ln]
                assert len(said) == (tag == "rep") and (tag == "ref" or f"line {line};" in said[0]), r.stderr
        got[tag] = json.loads((tmp_path / f"{tag}.json").read_text())
    assert got["rep"]["states"] == got["ref"]["states"]
