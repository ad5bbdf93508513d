"""Phases of systems cdgps does not process (SBAS, NavIC) that the files hold: ``--signals auto`` would leave them
out without a word, so a warning names them.  QZSS is processed when named (tests/pipeline/test_qzss.py) and left
out by ``auto`` (core.signals.AUTO_SYSTEMS says why); a warning names the QZSS signals both files hold and how to
use them (a sweep of the real car pair, whose RTKLIB reference uses QZSS).  RINEX 3 headers only (RINEX 2 lists its
types for every system at once)."""

from __future__ import annotations

import json

import pytest

from cdgps_cli.io.rinex_signals import phase_systems_in_file
from cdgps_cli.pipeline.gnss_multi import _unprocessed_systems_note
from tests._shared import REPO_ROOT, run_cli

DATA = REPO_ROOT / "tests" / "data"
CAR = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "geonet-car"


def test_the_systems_a_header_holds_phases_of(tmp_path):
    assert phase_systems_in_file(DATA / "ESBC00DNK_R_20201770000_subset.rnx") == {"C", "G", "R"}
    assert phase_systems_in_file(DATA / "demo3.10o") == {"G", "R", "S"}
    assert phase_systems_in_file(DATA / "07590920.05o") == set()            # RINEX 2: not per system


def test_sbas_phases_every_receiver_holds_are_named():
    both = {"base": [DATA / "demo3.10o"], "rover": [DATA / "demo3.10o"]}
    note = _unprocessed_systems_note(both)
    assert len(note) == 1 and note[0].startswith("SBAS (S) phases held by both files are not used")
    assert "QZSS" in note[0]                                              # among the systems that are processed
    assert _unprocessed_systems_note({"base": [DATA / "demo3.10o"],
                                      "rover": [DATA / "ESBC00DNK_R_20201770000_subset.rnx"]}) == []


def test_rtk_and_config_name_the_qzss_auto_leaves_out(tmp_path):
    if not CAR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    assert "J" in phase_systems_in_file(CAR / "SEPT265G.21O") and "J" in phase_systems_in_file(CAR / "3034265G.21O")
    r = run_cli("rtk", "--base", CAR / "3034265G.21O", "--rover", CAR / "SEPT265G.21O", "--nav", CAR / "SEPT2650.21P",
                "--signals", "auto", "-o", tmp_path / "car.pos", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert not any(s.startswith("J:") for s in out["signals"])
    note = "QZSS signals held by both files (J:L1, J:L2, J:L5) are left out by --signals auto: name them"
    assert any(note in w for w in out["warnings"])
    r = run_cli("config", "--rinex", f"base={CAR / '3034265G.21O'}", "--rinex", f"rover={CAR / 'SEPT265G.21O'}",
                "--nav", CAR / "SEPT2650.21P", "--master", "base", "-o", tmp_path / "c.toml")
    assert r.exit_code == 0 and note in r.output and '"J:L1"' not in (tmp_path / "c.toml").read_text()


def test_qzss_without_ephemerides_is_said_so(tmp_path):
    if not CAR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    from cdgps_cli.io.rinex import read_rinex_nav
    from cdgps_cli.io.rinex_write import write_rinex_nav

    nav = tmp_path / "ge.rnx"                              # the car's navigation file without its QZSS records
    write_rinex_nav(nav, read_rinex_nav(CAR / "SEPT2650.21P", systems=("G", "E")))
    r = run_cli("rtk", "--base", CAR / "3034265G.21O", "--rover", CAR / "SEPT265G.21O", "--nav", nav,
                "--signals", "auto", "-o", tmp_path / "car.pos", "--json")
    assert r.exit_code == 0, r.output
    note = f"QZSS signals held by both files (J:L1, J:L2, J:L5) are not used: no QZSS ephemerides in {nav}"
    assert note in json.loads(r.stdout)["warnings"]
