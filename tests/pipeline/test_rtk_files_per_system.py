"""A receiver's systems in files of their own (gnss-sdr writes a RINEX file per system): ``rtk --rover G.obs
--rover E.obs`` merges them epoch by epoch (pipeline/gnss_multi._merged_systems).  Checked on the real mosaic-X5
rover split into a GPS file and a Galileo file by hand: the same solution, byte for byte, as the whole file; files
whose spans do not meet are refused naming them; files of one system each that repeat epochs stay consecutive
pieces."""

from __future__ import annotations

import json

import pytest

from tests._shared import MOSAIC_DIR, one_system_rinex3, run_cli


def _rtk(d, name, *rover):
    out = d / f"{name}.pos"
    args = ["-q", "rtk", "--base", MOSAIC_DIR / "base.obs", "--nav", MOSAIC_DIR / "base.nav", "--signals", "G:L1,E:E1",
            "-o", out, "--json"]
    for r in rover:
        args += ["--rover", r]
    r = run_cli(*args)
    return r, out


@pytest.fixture(scope="module")
def split(tmp_path_factory):
    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    d = tmp_path_factory.mktemp("per_system")
    text = (MOSAIC_DIR / "rover.obs").read_text()
    (d / "rover_g.obs").write_text(one_system_rinex3(text, "G"))
    (d / "rover_e.obs").write_text(one_system_rinex3(text, "E"))
    return d


def test_a_file_per_system_is_the_whole_file(split):
    d = split
    whole, whole_pos = _rtk(d, "whole", MOSAIC_DIR / "rover.obs")
    parts, parts_pos = _rtk(d, "parts", d / "rover_g.obs", d / "rover_e.obs")
    assert whole.exit_code == 0 and parts.exit_code == 0, parts.output
    assert "one receiver's systems in files of their own (rover_g.obs: G:L1; rover_e.obs: E:E1)" in parts.output
    body = lambda p: [ln for ln in p.read_text().splitlines() if not ln.startswith("%")]   # noqa: E731
    assert body(parts_pos) == body(whole_pos)
    s = json.loads(parts.output[parts.output.index("{"):])
    assert s["signals"] == ["G:L1", "E:E1"] and s["epochs"] == 301
    auto, _ = run_cli("-q", "rtk", "--base", MOSAIC_DIR / "base.obs", "--nav", MOSAIC_DIR / "base.nav", "--rover",
                      d / "rover_g.obs", "--rover", d / "rover_e.obs", "-o", d / "auto.pos", "--json"), None
    assert auto.exit_code == 0 and {"G:L1", "E:E1"} <= set(json.loads(auto.output[auto.output.index("{"):])["signals"])


def _epochs(text: str, keep) -> str:
    """A RINEX 3 observation file's text with the epochs whose index ``keep(k)`` says (its header as it is)."""
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    out, k = lines[:i], 0
    while i < len(lines):
        n = int(lines[i][32:35])
        if keep(k):
            out += lines[i:i + 1 + n]
        i, k = i + 1 + n, k + 1
    return "\n".join(out) + "\n"


def test_files_of_one_system_each_whose_spans_do_not_meet_are_refused(split):
    d = split
    (d / "rover_g_early.obs").write_text(_epochs((d / "rover_g.obs").read_text(), lambda k: k < 100))
    (d / "rover_e_late.obs").write_text(_epochs((d / "rover_e.obs").read_text(), lambda k: k >= 200))
    r, out = _rtk(d, "apart", d / "rover_g_early.obs", d / "rover_e_late.obs")
    assert r.exit_code == 2 and "their spans do not meet" in r.output and "rover_g_early.obs: G:L1" in r.output
    assert not out.exists()


def test_ingest_and_init_take_them_as_the_whole_file(split):
    """``ingest`` merges them as ``rtk`` does (the same GNSS path): ``init`` on the run of the split files gives the
    whole file's run's integers and static solution, bit for bit."""
    d = split
    inits = {}
    for name, rovers in (("whole", [MOSAIC_DIR / "rover.obs"]), ("parts", [d / "rover_g.obs", d / "rover_e.obs"])):
        args = ["ingest", "--rinex", f"base={MOSAIC_DIR / 'base.obs'}"]
        for r in rovers:
            args += ["--rinex", f"rover={r}"]
        args += ["--nav", MOSAIC_DIR / "base.nav", "--master", "base", "--signals", "G:L1,E:E1", "-o", d / f"{name}.mcap"]
        r = run_cli("-q", *args)
        assert r.exit_code == 0, r.output
        if name == "parts":
            assert "one receiver's systems in files of their own" in r.output
        r = run_cli("-q", "init", d / f"{name}.mcap", "-o", d / f"{name}_init.json")
        assert r.exit_code == 0, r.output
        inits[name] = json.loads((d / f"{name}_init.json").read_text())["rovers"]["rover"]
    for key in ("solution", "states", "sigma", "rover_ecef_m", "n_fixed", "n_estimated", "ratio"):
        assert inits["parts"][key] == inits["whole"][key], key


def test_ingest_merges_them_when_no_file_fails_alone(split):
    """Signals that do not need GPS L1 (G:L2 and E:E1): every file reads alone, and the pieces' join in time is what
    fails; the merge is tried there too (a review found ingest refusing what rtk merged)."""
    d = split
    r = run_cli("-q", "ingest", "--rinex", f"base={MOSAIC_DIR / 'base.obs'}", "--rinex", f"rover={d / 'rover_g.obs'}",
                "--rinex", f"rover={d / 'rover_e.obs'}", "--nav", MOSAIC_DIR / "base.nav", "--master", "base",
                "--signals", "G:L2,E:E1", "-o", d / "l2.mcap")
    assert r.exit_code == 0 and "one receiver's systems in files of their own" in r.output, r.output
    assert run_cli("-q", "init", d / "l2.mcap", "-o", d / "l2.json").exit_code == 0
