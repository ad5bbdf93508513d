#!/usr/bin/env python3
"""Batch SD rows (``baseline._prepare``) against the static engine's (``receiver_geometry`` + ``paired_sd_rows``) on
the real mosaic pair (GPS L1): the same (epoch, satellite) rows, their satellite positions, base elevations and the
DD of phase minus modelled SD range at the fixed solution (render28: how far the INIT/STATES numbers would move if
they were rendered on the engine's rows instead of the batch's; run from a directory that is not a worktree)::

    PYTHONPATH=<tree> python benchmarks/compare_engine_batch_rows.py [../shared/data/real-pairs/mosaic-static]
"""
import sys
import numpy as np
from pathlib import Path
from cdgps_cli.estimation import baseline as bl
from cdgps_cli.estimation.baseline import Station, BaselineOptions
from cdgps_cli.estimation.rtk_multi import receiver_geometry
from cdgps_cli.estimation.static_engine import options_from_baseline, _static_options
from cdgps_cli.measurement.dd_signals import paired_sd_rows
from cdgps_cli.measurement.epoch_pairing import pair_epochs
from cdgps_cli.io.rinex import read_rinex_obs, read_rinex_nav
M = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real-pairs" / "mosaic-static")
b, r = [Station(n, *read_rinex_obs(M / f"{n}.obs")) for n in ("base", "rover")]
nav = read_rinex_nav(M / "base.nav", systems=("G",))
res = bl.solve_static_baseline(b, r, nav, engine=True, keep_work=True)
w = res["_work"]; d = w["data"]
xm, xr0 = w["xm"], w["xr0"]
xr = xr0 + w["r_enu"].T @ w["x_final"]
opt = _static_options(options_from_baseline(BaselineOptions(kinematic_series=False)))
gb, gr = receiver_geometry(bl.l1_signal_table(b.obs), nav, xm), receiver_geometry(bl.l1_signal_table(r.obs), nav, xr0)
pairs = pair_epochs(gr["time_gps_s"].to_numpy(), gb["time_gps_s"].to_numpy(), sync_tol_s=opt["sync_tol_s"], max_age_s=opt["max_age_s"])
rows = paired_sd_rows(gb, gr, pairs, opt, mask_rover=True)
ep = np.searchsorted(rows["ptr"], np.arange(rows["sats"].size), side="right") - 1
key_e = {(int(e), str(s)): i for i, (e, s) in enumerate(zip(ep, rows["sats"]))}
idx = np.array([key_e.get((int(e), d.sat_names[s]), -1) for e, s in zip(d.epoch, d.sat)])
ok = idx >= 0
print("batch rows", d.sat.size, "engine rows", rows["sats"].size, "matched", int(ok.sum()))
i = idx[ok]
dsat = np.linalg.norm(d.rover_sat_xyz[ok] - rows["sat_xyz"][i], axis=1)
print("rover-side satellite position difference, m: median %.3g max %.3g" % (np.median(dsat), dsat.max()))
print("base elevation difference, rad: max %.3g" % np.max(np.abs(d.el_base[ok] - rows["el"][i])))
# modelled SD (range + satellite clock + troposphere) at the fixed rover position, m
batch_model = (np.linalg.norm(d.rover_sat_xyz - xr, axis=1) + d.rover_clk_trop_m - d.base_model_m)[ok]
y_b = d.y_phase_m[ok] - batch_model
y_e = rows["phase_sd_m"][i] - (np.linalg.norm(rows["sat_xyz"][i] - xr, axis=1) - np.linalg.norm(rows["sat_base_xyz"][i] - xm, axis=1))
# compare as DDs against each epoch's first matched row (receiver clocks cancel)
e_ok = d.epoch[ok]
first = np.r_[True, e_ok[1:] != e_ok[:-1]]
fi = np.maximum.accumulate(np.where(first, np.arange(e_ok.size), 0))
ddd = (y_b - y_b[fi]) - (y_e - y_e[fi])
ddd -= np.round(ddd / bl.GPS_L1_WAVELENGTH_M) * bl.GPS_L1_WAVELENGTH_M     # ambiguity datum differences
print("DD (phase − model) batch − engine, m: rms %.3g max %.3g" % (np.sqrt(np.mean(ddd[~first] ** 2)), np.abs(ddd[~first]).max()))
