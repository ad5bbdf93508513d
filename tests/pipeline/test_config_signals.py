"""``cdgps config --signals``: the starter config's ``[gnss] signals`` chosen as ``cdgps rtk --signals auto`` chooses
them (one function, ``gnss_multi.common_signals``), a list given on purpose kept, and bad lists refused with exit 2
naming the option."""

import tomllib

import pytest

from tests._shared import REPO_ROOT, run_cli

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
