"""`gnss_ingest.lock_summary` (the lock counters `ingest` records per receiver and satellite): cut in groups of
satellites (a day's rows are not segmented at once, issue 29) it counts what one pass counts, and both count what a
plain loop over each satellite's rows counts (the double differences' rule, ``differencing.ambiguity_segments``: a new
arc at the first row, at a slip flag — LLI bit 0 — and after an epoch the receiver logged without the satellite; a
gap in the whole log cuts nothing — until session 29 every gap over 1.5 intervals did, and a real u-blox base logging
with gaps showed 1432 arcs for 56); the thin tables an hour-by-hour ingest keeps give the same counts as the
receiver's full table."""

import math

import numpy as np
import pytest

from cdgps_cli.core.gps_time import nominal_interval_s
from cdgps_cli.io.gnss_hours import ThinTables
from cdgps_cli.io.gnss_run import GnssReceiver, read_receiver_file
from cdgps_cli.pipeline import gnss_ingest
from cdgps_cli.pipeline.gnss_ingest import anchor_obs, lock_obs, lock_summary
from tests._shared import run_cli


@pytest.fixture(scope="module")
def rover(tmp_path_factory):
    d = tmp_path_factory.mktemp("lock")
    assert run_cli("-q", "simulate-gnss", "--duration", "600", "--slips", "12", "--seed", "8", "-o", d).exit_code == 0
    rx = read_receiver_file("rover", "rinex", d / "rover.rnx")
    raw = rx.raw.copy()
    gone = raw.index[(raw["sat"] == raw["sat"].iloc[0]) & raw["time_gps_s"].between(raw["time_gps_s"].iloc[0] + 100,
                                                                                     raw["time_gps_s"].iloc[0] + 130)]
    t0 = raw["time_gps_s"].iloc[0]
    logged_gap = raw.index[raw["time_gps_s"].between(t0 + 200, t0 + 230)]     # 30 s with no epoch at all: no cut
    rx.raw = raw.drop(gone.union(logged_gap)).reset_index(drop=True)        # and a 30 s outage of one satellite: a cut
    return rx


def _by_loop(rx) -> dict:
    r = rx.raw[np.isfinite(rx.raw["phase_cycles"].to_numpy())]
    epochs = sorted(set(r["time_gps_s"].tolist()))                 # the epochs the receiver logged (with a phase)
    index = {t: k for k, t in enumerate(epochs)}
    out = {}
    for sat, g in r.groupby("sat", sort=True):
        t, lli = g["time_gps_s"].tolist(), g["lli"].tolist()
        arcs = slips = 0
        for i in range(len(t)):
            if i == 0 or lli[i] & 1 or index[t[i]] - index[t[i - 1]] > 1:     # a logged epoch without it in between
                arcs += 1
            slips += bool(i and lli[i] & 1)
        out[sat] = {"rows": len(t), "slips": slips, "half_cycle_rows": sum(bool(x & 2) for x in lli), "arcs": arcs}
    return out


def test_counts_by_a_plain_loop(rover):
    got = lock_summary(rover, anchor_obs(rover, ()))
    assert got == _by_loop(rover)
    assert sum(v["slips"] for v in got.values()) >= 6 and max(v["arcs"] for v in got.values()) >= 3
    # the gap in the whole log cut no satellite's arc: a satellite without a slip has one arc
    quiet = [s for s, v in got.items() if v["slips"] == 0 and s != rover.raw["sat"].iloc[0]]
    assert quiet and all(got[s]["arcs"] == 1 for s in quiet), {s: got[s] for s in quiet}


def test_groups_of_satellites_count_as_one_pass(rover, monkeypatch):
    whole = lock_summary(rover, anchor_obs(rover, ()))
    monkeypatch.setattr(gnss_ingest, "_LOCK_ROWS_PER_PASS", 700)          # a few satellites a pass
    assert len(gnss_ingest._channel_groups(np.bincount(np.unique(rover.raw["sat"], return_inverse=True)[1]))) > 3
    assert lock_summary(rover, anchor_obs(rover, ())) == whole
    monkeypatch.setattr(gnss_ingest, "_LOCK_ROWS_PER_PASS", 1)             # one satellite a pass
    assert lock_summary(rover, anchor_obs(rover, ())) == whole


def test_thin_tables_count_as_the_full_table(rover):
    thin = ThinTables()
    for lo in range(0, len(rover.raw), 1000):                               # in blocks, as read hour by hour
        thin.add(rover.raw.iloc[lo:lo + 1000], None)
    rx = GnssReceiver("rover", "rinex", "rover.rnx", rover.header, thin.frame("raw"), rover.info)
    assert str(rx.raw["sat"].dtype) == "category" and rx.raw["phase_cycles"].dtype == np.float16   # (there or not)
    assert np.array_equal(np.isfinite(rx.raw["phase_cycles"].to_numpy()), np.isfinite(rover.raw["phase_cycles"]))
    assert lock_summary(rx, lock_obs(rx, ())) == lock_summary(rover, anchor_obs(rover, ()))


def test_no_phase_at_all():
    import pandas as pd  # noqa: PLC0415

    obs = pd.DataFrame({"time_gps_s": [1.0, 2.0], "sat": ["G01", "G01"], "phase_l1_cycles": [math.nan, math.nan],
                        "lli_l1": [0, 0]})
    assert lock_summary(None, obs) == {}


def test_a_receiver_logging_with_gaps_is_summarised_at_the_interval_it_samples_at(rover):
    """A base that logs three epochs in five (spacings 2, 1, 2 … s: median 2 s) samples at 1 s: ``info``, ``ingest``
    and ``config`` say so, as the solvers' grid does (they said 2 s, the median; 3 s for the real M8P base)."""
    from cdgps_cli.io.gnss_run import _receiver_summary

    raw = rover.raw
    t = raw["time_gps_s"].to_numpy()
    keep = np.isin(np.round(t - t[0]).astype(int) % 5, (0, 2, 3))
    rx = GnssReceiver("base", "rinex", "base.rnx", rover.header, raw[keep].reset_index(drop=True), rover.info)
    assert nominal_interval_s(np.unique(rx.raw["time_gps_s"].to_numpy())) == pytest.approx(2.0, abs=0.01)
    assert _receiver_summary("base", rx, {}, ("header", None))["interval_s"] == pytest.approx(1.0, abs=1e-9)
