"""``cdgps config --signals``: the starter config's ``[gnss] signals`` chosen as ``cdgps rtk --signals auto`` chooses
them (one function, ``gnss_multi.common_signals``), a list given on purpose kept, and bad lists refused with exit 2
naming the option."""

import tomllib

import pytest

from tests._shared import one_system_rinex3, REPO_ROOT, run_cli

SHARED = REPO_ROOT.parent / "shared" / "data"
MOSAIC = SHARED / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def _config(tmp_path, *extra):
    out = tmp_path / "c.toml"
    r = run_cli("config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={MOSAIC / 'rover.obs'}",
                "--nav", MOSAIC / "base.nav", *extra, "-o", out)
    return r, (tomllib.loads(out.read_text())["gnss"] if out.exists() else None)


def test_auto_writes_every_signal_both_files_hold_as_rtk_chooses_them(tmp_path):
    from cdgps_cli.pipeline.gnss_multi import common_signals

    r, g = _config(tmp_path)
    assert r.exit_code == 0, r.output
    both = common_signals({"base": [MOSAIC / "base.obs"], "rover": [MOSAIC / "rover.obs"]}, [MOSAIC / "base.nav"], [])
    assert {"G:L1", "R:G1", "E:E1", "C:B1I"} <= set(both)                 # the premise: four systems in both files
    assert g["signals"] == both


def test_a_list_given_is_written_as_given_and_gps_l1_alone_writes_no_key(tmp_path):
    r, g = _config(tmp_path, "--signals", "G:L1,R:G1")
    assert r.exit_code == 0 and g["signals"] == ["G:L1", "R:G1"]
    r, g = _config(tmp_path, "--signals", "G:L1")
    assert r.exit_code == 0 and "signals" not in g


@pytest.mark.parametrize("bad, words", [("G:L1,X:Y", ["--signals", "'X:Y'"]), ("G:L1,G:L1", ["--signals", "twice"]),
                                        (" ", ["--signals", "none"])])
def test_bad_lists_exit_2_naming_the_option(tmp_path, bad, words):
    r, g = _config(tmp_path, "--signals", bad)
    assert r.exit_code == 2 and g is None and "Traceback" not in r.output
    assert all(w in r.output for w in words), r.output


def test_a_glonass_only_run_goes_through_init_float(tmp_path):
    """GLONASS alone (FDMA, never fixed without glonass_fix): ``init`` has no integer to fix and reports a float
    solution (LAMBDA on an empty set was a traceback)."""
    r, g = _config(tmp_path, "--signals", "R:G1")
    assert r.exit_code == 0 and g["signals"] == ["R:G1"]
    for args in (("ingest", "--config", tmp_path / "c.toml", "-o", tmp_path / "r.mcap"),
                 ("init", tmp_path / "r.mcap", "-o", tmp_path / "i.json")):
        res = run_cli("-q", *args)
        assert res.exit_code == 0 and "Traceback" not in res.output, (args, res.output)
    import json
    rov = json.loads((tmp_path / "i.json").read_text())["rovers"]["rover"]
    assert rov["solution"] == "float" and rov["n_fixed"] == 0


def test_a_galileo_only_pair_gets_a_config_that_init_fixes(tmp_path):
    """Files holding Galileo alone (no GPS observation type in their headers): config wrote nothing ("GPS L1
    carrier phase is needed", from reading the GPS L1 table for its comments); the run's signals say what is
    needed, with ``--signals`` as with ``auto``."""
    for who in ("base", "rover"):
        (tmp_path / f"{who}.obs").write_text(one_system_rinex3((MOSAIC / f"{who}.obs").read_text(), "E"))
    files = ("--rinex", f"base={tmp_path / 'base.obs'}", "--rinex", f"rover={tmp_path / 'rover.obs'}",
             "--nav", MOSAIC / "base.nav")
    for extra, name in (((), "auto.toml"), (("--signals", "E:E1,E:E5a"), "given.toml")):
        r = run_cli("-q", "config", *files, *extra, "-o", tmp_path / name)
        assert r.exit_code == 0, r.output
        g = tomllib.loads((tmp_path / name).read_text())["gnss"]
        assert g["signals"] and all(s.startswith("E:") for s in g["signals"])
        assert "301 epochs" in (tmp_path / name).read_text()
    r = run_cli("-q", "ingest", "--config", tmp_path / "given.toml", "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output
    r = run_cli("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    assert r.exit_code == 0, r.output
    assert "INIT base → rover: fixed" in r.stderr, r.stderr


def test_auto_leaves_out_the_signals_a_header_lists_but_no_record_holds(tmp_path):
    """Headers listing every system, records of GPS alone: ``config`` wrote the headers' signals and ``ingest``
    refused the run ("no E:E1 … phase observations"); the signals no record holds are now left out, each named."""
    for who in ("base", "rover"):
        (tmp_path / f"{who}.obs").write_text(one_system_rinex3((MOSAIC / f"{who}.obs").read_text(), "G", header_too=False))
    r = run_cli("config", "--rinex", f"base={tmp_path / 'base.obs'}", "--rinex", f"rover={tmp_path / 'rover.obs'}",
                "--nav", MOSAIC / "base.nav", "-o", tmp_path / "c.toml")
    assert r.exit_code == 0, r.output
    assert tomllib.loads((tmp_path / "c.toml").read_text())["gnss"]["signals"] == ["G:L1", "G:L2", "G:L5"]
    assert "E:E1 not used: listed in the header of" in r.stderr
    r = run_cli("-q", "ingest", "--config", tmp_path / "c.toml", "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output


def test_auto_keeps_glonass_when_only_the_navigation_file_has_its_slots(tmp_path):
    """Headers without GLONASS SLOT / FRQ # lines (the frequency numbers in the navigation file): the check of which
    signals the records hold cannot read GLONASS there, and must not drop every signal for it (it fell back to GPS
    L1 alone)."""
    for who in ("base", "rover"):
        text = "\n".join(ln for ln in (MOSAIC / f"{who}.obs").read_text().splitlines()
                         if ln[60:].strip() != "GLONASS SLOT / FRQ #") + "\n"
        (tmp_path / f"{who}.obs").write_text(text)
    r = run_cli("-q", "config", "--rinex", f"base={tmp_path / 'base.obs'}", "--rinex", f"rover={tmp_path / 'rover.obs'}",
                "--nav", MOSAIC / "base.nav", "-o", tmp_path / "c.toml")
    assert r.exit_code == 0, r.output
    sig = tomllib.loads((tmp_path / "c.toml").read_text())["gnss"]["signals"]
    assert {"G:L1", "E:E1", "R:G1"} <= set(sig)
