"""QZSS (and SBAS, NavIC) phases the files hold: ``--signals auto`` left them out without a word (a sweep of the
real car pair, whose RTKLIB reference uses QZSS); a warning now names them.  RINEX 3 headers only (RINEX 2 lists its
types for every system at once)."""

from __future__ import annotations

import json

import pytest

from cdgps_cli.io.rinex_signals import phase_systems_in_file
from tests._shared import REPO_ROOT, run_cli

DATA = REPO_ROOT / "tests" / "data"
CAR = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "geonet-car"


def test_the_systems_a_header_holds_phases_of(tmp_path):
    assert phase_systems_in_file(DATA / "ESBC00DNK_R_20201770000_subset.rnx") == {"C", "G", "R"}
    assert phase_systems_in_file(DATA / "07590920.05o") == set()            # RINEX 2: not per system


def test_rtk_and_config_name_qzss_they_leave_out(tmp_path):
    if not CAR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    assert "J" in phase_systems_in_file(CAR / "SEPT265G.21O") and "J" in phase_systems_in_file(CAR / "3034265G.21O")
    r = run_cli("rtk", "--base", CAR / "3034265G.21O", "--rover", CAR / "SEPT265G.21O", "--nav", CAR / "SEPT2650.21P",
                "--signals", "auto", "-o", tmp_path / "car.pos", "--json")
    assert r.exit_code == 0, r.output
    note = "QZSS (J) phases held by both files are not used"
    assert any(note in w for w in json.loads(r.stdout)["warnings"])
    r = run_cli("config", "--rinex", f"base={CAR / '3034265G.21O'}", "--rinex", f"rover={CAR / 'SEPT265G.21O'}",
                "--nav", CAR / "SEPT2650.21P", "--master", "base", "-o", tmp_path / "c.toml")
    assert r.exit_code == 0 and note in r.output
