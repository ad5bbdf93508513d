"""Epochs that line up (issue 14 item 2): receiver-clock offsets off whole seconds, different rates.

Each scenario simulates a static base/rover pair (20 min, the default synthetic constellation and
positions, ``cdgps_cli.model.gps.positioning.simulate_static_pair``) twice with the same seed — once with the
scenario's clock offsets and rates, once offset-free (tags on whole seconds, clocks at zero) —
and solves both with ``solve_static_baseline`` in each alignment mode.  Reported: the share of
the common span's epochs that are differenced, the epoch-alignment counts per receiver, the fixed
solution's difference from the offset-free one, and the time.

Scenarios: ``8ms`` — u-blox-like rover tags at .992 s (clock offset −8 ms drifting by +1.5 ms over
the span, tags = nominal epoch + offset), 1 Hz base on whole seconds; ``8ms-5s-base`` — the same
rover beside a 5 s base (a CORS receiver) and 40 slips; ``3hz-1hz`` — a 3 Hz rover at −8 ms beside
a 1 Hz base at +6 ms; ``opposite-14ms`` — base tags 14 ms after, rover tags 14 ms before the
whole seconds (28 ms apart: the former pairing, tag differences within 25 ms, found no common
epoch at all).

Usage::

    python benchmarks/bench_epoch_align.py [--json docs/benchmarks/epoch_align.json]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.estimation.baseline import BaselineOptions, Station, solve_static_baseline  # noqa: E402
from cdgps_cli.model.gps.positioning import simulate_static_pair, synthetic_gps_nav  # noqa: E402
from cdgps_cli.sim.gnss import DEFAULT_MASTER_XYZ, DEFAULT_ROVER_XYZ  # noqa: E402
from cdgps_cli.io.rinex import gps_seconds  # noqa: E402

T0 = gps_seconds(2024, 1, 1)
SCENARIOS = {
    #  name: (rate_hz, base_every, clock offset ms (base, rover), drift ms, slips)
    "8ms": (1.0, 1, (0.0, -8.0), (0.0, 1.5), 0),
    "8ms-5s-base": (1.0, 5, (0.0, -8.0), (0.0, 1.5), 40),
    "3hz-1hz": (3.0, 3, (6.0, -8.0), (0.5, 1.5), 0),
    "opposite-14ms": (1.0, 1, (14.0, -14.0), (0.5, -0.5), 0),
}


def solve(nav, duration_s, rate_hz, base_every, offset, drift, slips, raw, mode, seed):
    xm, xr = np.array(DEFAULT_MASTER_XYZ), np.array(DEFAULT_ROVER_XYZ)
    sim = simulate_static_pair(nav, xm, xr, T0, duration_s, 1.0 / rate_hz, phase_sigma_m=(0.003, 0.003),
                               clock_offset_ms=offset, clock_drift_ms=drift, tag_resolution_s=None if raw else 1e-3,
                               seed=seed, base_every=base_every, random_slips=slips, mask_rad=math.radians(10.0))
    opt = BaselineOptions(epoch_alignment=mode, kinematic_series=False)
    t0 = time.perf_counter()
    res = solve_static_baseline(Station("base", {"approx_position_xyz_m": xm, "path": "base"}, sim["base"]),
                                Station("rover", {"approx_position_xyz_m": xr, "path": "rover"}, sim["rover"]),
                                nav, opt, master_xyz=xm, rover_xyz=xr)
    return res, time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    nav = synthetic_gps_nav(T0, args.duration + 300.0, seed=3)
    rows = []
    for name, (rate, every, off, drift, slips) in SCENARIOS.items():
        ref, _ = solve(nav, args.duration, rate, every, (0.0, 0.0), (0.0, 0.0), slips, False, "geometry", args.seed)
        for mode in ("geometry", "doppler"):
            res, dt = solve(nav, args.duration, rate, every, off, drift, slips, True, mode, args.seed)
            al = res["epochs"]["epoch_alignment"]
            sol, sol_ref = res["fixed"] or res["float"], ref["fixed"] or ref["float"]
            d = np.array(sol["enu_m"]) - np.array(sol_ref["enu_m"])
            row = {"scenario": name, "mode": mode, "solution": res["solution"], "reference_solution": ref["solution"],
                   "epochs_differenced": res["epochs"]["n_epochs_used"],
                   "epochs_differenced_offset_free": ref["epochs"]["n_epochs_used"],
                   "share_differenced": res["epochs"]["n_epochs_used"] / ref["epochs"]["n_epochs_used"],
                   "max_abs_diff_from_offset_free_mm": float(np.max(np.abs(d)) * 1e3),
                   "diff_enu_mm": (d * 1e3).tolist(), "n_fixed": res["ambiguities"]["n_fixed"],
                   "n_segments": res["ambiguities"]["n_segments"], "time_s": dt,
                   "alignment": {k: {kk: v[kk] for kk in ("epochs", "on_grid", "off_grid_kept", "corrected",
                                                           "dropped_off_grid", "dropped_duplicate",
                                                           "rows_dropped_no_rate", "matched", "max_offset_ms",
                                                           "grid_s")}
                                 for k, v in al.items()}}
            rows.append(row)
            print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()
                              if k not in ("diff_enu_mm",)}), flush=True)
    if args.json:
        out = {"machine": platform.platform(), "python": platform.python_version(), "numpy": np.__version__,
               "duration_s": args.duration, "seed": args.seed, "rows": rows}
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
