"""``report run`` on GNSS STATES whose single-epoch series lacks an epoch (one with too few satellites for a position
of its own): the report read the estimate's residual arrays against the single-epoch series' epochs and refused
the file as "damaged state arrays" (a sweep of real u-blox files, session 30: the real M8P pair's STATES)."""

from __future__ import annotations

import pytest

from tests._shared import REPO_ROOT, run_cli
from tests.pipeline.test_rtk_epoch_accounting import _edit_records

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def test_report_run_takes_states_whose_single_epoch_series_has_gaps(tmp_path):
    def three_gps(recs):                       # epoch 40: three GPS satellites, no single-epoch position
        keep, n = [], 0
        for r in recs:
            n += r[0] == "G"
            keep.append(r[0] != "G" or n <= 3)
        return keep
    rover = tmp_path / "rover.obs"
    rover.write_text(_edit_records((MOSAIC / "rover.obs").read_text(), {40}, three_gps))
    for args in (("ingest", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={rover}", "--nav",
                  MOSAIC / "base.nav", "--master", "base", "--signals", "G:L1", "-o", tmp_path / "run.mcap"),
                 ("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json"),
                 ("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "-o", tmp_path / "states.mcap")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args[0], r.output)
    r = run_cli("-q", "export", tmp_path / "states.mcap", "--kinematic", "-o", tmp_path / "kin.csv")
    assert r.exit_code == 0, r.output
    n_kin = sum(1 for ln in (tmp_path / "kin.csv").read_text().splitlines() if ln and ln[0].isdigit())
    assert n_kin == 300, n_kin                                   # the epoch of three satellites has none
    r = run_cli("-q", "report", "run", tmp_path / "states.mcap", "--no-spectra", "-o", tmp_path / "report")
    assert r.exit_code == 0 and "damaged" not in r.output, r.output
    page = (tmp_path / "report" / "index.html").read_text()
    assert "cdgps init on run.mcap, the whole record; rover: 15 of 15 integers fixed" in page    # provenance
    assert "300 s from 2024-06-24 08:20:00 GPST (GPS time 1403252400.0 s)" in page              # the start as a date
