"""``cdgps ingest`` / ``cdgps info`` of a structure run: the channel summary follows the one lock-segment
rule, so that info, ingest, init and the filter count the same segments (issue 13, §2.5 of
docs/architecture-map.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.table import Table

from cdgps_cli.config.structure import load_config
from cdgps_cli.estimation.filter import lock_events
from cdgps_cli.estimation.initializer import phase_matrix, window_data
from cdgps_cli.io.run import read_run
from cdgps_cli.pipeline.gnss_ingest import run_info
from cdgps_cli.pipeline.ingest import channel_summary, ingest_structure
from cdgps_cli.sim.structure import SimOptions, parse_outage, parse_slip, simulate, write_simulation

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"


@pytest.fixture(scope="module")
def edited_run(tmp_path_factory):
    """A 20 s testbed run with simulated slips and outages, 200 lost samples (the lock count goes on),
    and two hand-made lock anomalies the old `cdgps info` rule (lock == 0 only) missed: a count that
    decreases without reaching 0, and a count that jumps over a gap."""
    cfg = load_config(TESTBED)
    d = tmp_path_factory.mktemp("sim")
    res = simulate(cfg, SimOptions(duration_s=20.0, seed=7, phase_sigma_m=0.01,
                                   slips=[parse_slip("a2:PL3:5.0:-2"), parse_slip("a1:PL1:12.0:+1")],
                                   outages=[parse_outage("PL6:3:1"), parse_outage("PL2:14:0.5")]))
    write_simulation(res, d)
    df = pd.read_csv(d / "receiver.csv")
    rng = np.random.default_rng(3)
    df = df.drop(index=rng.choice(len(df), 200, replace=False))
    a3 = (df.antenna == "a3") & (df.transmitter == "PL4")
    df.loc[a3 & (df.time_s >= 7.95), "lock"] -= 30           # decreasing, never 0: a restart
    a4 = (df.antenna == "a4") & (df.transmitter == "PL5")
    df = df[~(a4 & (df.time_s > 10.05) & (df.time_s < 10.35))]
    df.loc[a4 & (df.time_s >= 10.35), "lock"] += 7            # the count jumps over the gap: re-acquired
    a3, a4 = (df.antenna == "a3") & (df.transmitter == "PL4"), (df.antenna == "a4") & (df.transmitter == "PL5")
    made = {("a3", "PL4", float(df.time_s[a3 & (df.time_s >= 7.95)].min())): "restart",
            ("a4", "PL5", float(df.time_s[a4 & (df.time_s >= 10.35)].min())): "reacquisition"}
    df.to_csv(d / "edited.csv", index=False)
    out = tmp_path_factory.mktemp("run") / "run.mcap"
    summary = ingest_structure(cfg, d / "edited.csv", out)
    return out, summary, made


def test_info_ingest_init_and_filter_count_the_same_segments(edited_run):
    path, summary, made = edited_run
    info = run_info(path)
    run = read_run(path)
    t = run.phase["time_s"]
    wd = window_data(run, float(t.min()), float(t.max()))
    per_channel_init = pd.Series([(s["antenna"], s["transmitter"]) for s in wd.segments]).value_counts()
    per_channel_info = {(c["antenna"], c["transmitter"]): c["segments"] for c in info["channels"]}
    assert per_channel_info == {k: int(v) for k, v in per_channel_init.items()}
    starts_init = sorted((s["antenna"], s["transmitter"], round(s["start_s"], 6)) for s in wd.segments
                         if s["start_s"] > min(x["start_s"] for x in wd.segments if x["channel"] == s["channel"]))
    starts_info = sorted((s["antenna"], s["transmitter"], round(s["time_s"], 6)) for s in info["slips"])
    assert starts_info == starts_init
    assert summary["lock_restarts"] == len(info["slips"]) == len(wd.segments) - len(wd.channels)
    # the filter's lock events: one per segment
    grid, y, lock, chans = phase_matrix(run, float(t.min()), float(t.max()))
    assert int((lock_events(y, lock) > 0).sum()) == len(wd.segments)
    # the hand-made anomalies are counted (the old info rule missed them), with their kinds
    kinds = {(s["antenna"], s["transmitter"], s["time_s"]): s["kind"] for s in info["slips"]}
    assert {k: kinds.get(k) for k in made} == made
    assert {(a, x) for a, x, _ in kinds} >= {("a2", "PL3"), ("a1", "PL1"), ("a1", "PL6"), ("a1", "PL2")}


def test_info_reports_slips_and_channels(edited_run):
    info = run_info(edited_run[0])
    assert len(info["channels"]) == 36 and info["gaps"] == []
    assert all(c["rows"] > 0 and c["first_s"] <= c["last_s"] for c in info["channels"])


def test_channel_summary_of_an_empty_table():
    assert channel_summary(Table({"time_s": np.array([]), "lock": np.array([], dtype=np.int64)},
                                 {"antenna": ([], []), "transmitter": ([], [])}), 0.1) == []
