"""``init`` on a rover whose time tags sit 30 ms after the second (its clock 30 ms off, the ranges with it, as a
receiver that does not steer its clock writes them): every epoch was dropped ("no common epochs … within 30 s")
while ``rtk`` bridged every one; in the default "geometry" alignment an epoch up to a third of the step off its grid
time is now labelled with it (model/gps/epoch_align.align_receiver), each receiver's geometry evaluated at its own
reception instant as before: the solution is the unedited pair's."""

from __future__ import annotations

import json

import pytest

from cdgps_cli.sim.rinex_edit import edit_rinex3_obs
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def _init(d, rover, tag: str) -> dict:
    for args in (("config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={rover}", "--nav",
                  MOSAIC / "base.nav", "--master", "base", "--signals", "G:L1", "-o", d / f"{tag}.toml"),
                 ("ingest", "--config", d / f"{tag}.toml", "-o", d / f"{tag}.mcap"),
                 ("init", d / f"{tag}.mcap", "-o", d / f"{tag}.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args[0], r.output)
    return json.loads((d / f"{tag}.json").read_text())


def test_a_rover_30_ms_off_the_second_gives_the_same_solution(tmp_path):
    late = tmp_path / "rover_late.obs"
    late.write_text(edit_rinex3_obs((MOSAIC / "rover.obs").read_text(), clock_offset_s=lambda t: 0.030))
    ref, got = _init(tmp_path, MOSAIC / "rover.obs", "ref"), _init(tmp_path, late, "late")
    assert got["rovers"]["rover"]["n_fixed"] == ref["rovers"]["rover"]["n_fixed"] > 0
    assert got["rovers"]["rover"]["epochs"]["n_epochs_used"] == ref["rovers"]["rover"]["epochs"]["n_epochs_used"] == 301
    for k, v in ref["states"].items():
        assert got["states"][k] == pytest.approx(v, abs=2e-4), k
