"""The zenith wet delays of `rtk` against simulator truth: NEES and fixing with and without their estimate.

``python benchmarks/wet_troposphere.py [--out FILE]``

Simulated pairs (``sim.gnss_signals.simulate_receiver_signals`` with ``zenith_wet_m``; GPS L1 + L2; synthetic GPS
ephemerides; the simulator has no ionosphere):

* ``nees``: 60 km and 200 m of height apart, every 30 s for an hour, 0.10 / 0.20 m of zenith wet delay, seeds 1–8;
  static and kinematic, float and fixed, forward, the ionosphere neglected: the mean NEES of the position after the
  first 20 epochs (3 expected) and the final height errors.  Then the delays walking at the filter's rate (1e-4 m/√s)
  and at three times it, at 20 and 60 km, seeds 1–6 (float, static).
* ``threshold``: 12 and 30 km, 50 m of height, 0.10 / 0.12 m, every 10 s for an hour, seeds 1–2, `rtk`'s defaults
  but the wet delays estimated or neglected: fixed epochs, the first fix, the final height error and its σ.

Writes ``docs/benchmarks/wet_troposphere.json`` (docs/gnss-pipeline.md, session 29).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path

import numpy as np

from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.core.signals import signal
from cdgps_cli.estimation.rtk_multi import position_nees, receiver_geometry, reported_positions, solve_rtk
from cdgps_cli.model.gps.orbits import ecef_to_enu, ecef_to_geodetic, enu_matrix
from cdgps_cli.model.gps.positioning import synthetic_nav
from cdgps_cli.sim.gnss_signals import simulate_receiver_signals

OUT = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "wet_troposphere.json"


def pair(km: float, dz_m: float, zwd: tuple, n: int, dt_s: float, seed: int, walk: float = 0.0):
    """Base and rover geometry tables, their positions."""
    t0 = gps_seconds(2024, 3, 1)
    nav = synthetic_nav("G", t0, n * dt_s + 60, seed=seed)
    xb = np.array([-3978242.4, 3382841.2, 3649902.8])
    xr = xb + np.array([600.0 * km, 800.0 * km, dz_m]) @ enu_matrix(*ecef_to_geodetic(xb)[:2])
    rng = np.random.default_rng(seed)
    geo = []
    for k, (x, z) in enumerate(zip((xb, xr), zwd)):
        z = z + np.cumsum(rng.normal(0.0, walk * np.sqrt(dt_s), n)) if walk else z
        o = simulate_receiver_signals(nav, x, t0, n, dt_s, ("G:L1", "G:L2"), seed=10 * seed + k,
                                      clock_drift_ms=0.5 * (k + 1), zenith_wet_m=z)["obs"]
        geo.append(receiver_geometry(o.assign(wavelength_m=[signal(g).wavelength_m for g in o["signal"]]), nav, x))
    return geo, xb, xr


def solve(geo, xb, xr, **options) -> dict:
    res = solve_rtk(geo[0], geo[1], xb, xr + np.array([0.5, -0.3, 0.8]),
                    options={"code_noise": "model", "age_noise": "model", **options})
    xyz, cov = reported_positions(res)
    nees = position_nees(xyz, cov, xr)
    up = enu_matrix(*ecef_to_geodetic(xr)[:2])[2]
    return {"fixed": int(res["fixed"].sum()), "epochs": int(res["fixed"].size),
            "first_fix": int(np.argmax(res["fixed"])) if res["fixed"].any() else None,
            "up_error_mm": round(float(ecef_to_enu(xyz[-1], xr)[2]) * 1e3, 1),
            "up_sigma_mm": round(float(np.sqrt(up @ cov[-1] @ up)) * 1e3, 1), "nees": nees}


def nees_study() -> list:
    rows = []
    for mode in ("static", "kinematic"):
        for fix in (False, True):
            for wet in (True, False):
                runs = [solve(*pair(60.0, 200.0, (0.10, 0.20), 120, 30.0, s), mode=mode, fix=fix, direction="forward",
                              iono_threshold_km=1000.0, tropo_threshold_km=10.0 if wet else 1000.0) for s in range(1, 9)]
                rows.append({"mode": mode, "fix": fix, "wet": "estimated" if wet else "neglected",
                             "mean_nees": round(float(np.concatenate([r["nees"][20:] for r in runs]).mean()), 2),
                             "up_error_mm": [r["up_error_mm"] for r in runs]})
                print(json.dumps(rows[-1]), flush=True)
    for walk in (1e-4, 3e-4):
        for km, dz in ((60.0, 200.0), (20.0, 50.0)):
            runs = [solve(*pair(km, dz, (0.10, 0.20), 120, 30.0, s, walk), mode="static", fix=False, direction="forward",
                          iono_threshold_km=1000.0, tropo_threshold_km=1.0) for s in range(1, 7)]
            rows.append({"mode": "static", "fix": False, "wet": "estimated", "walk_m_per_sqrt_s": walk, "km": km,
                         "mean_nees": round(float(np.concatenate([r["nees"][20:] for r in runs]).mean()), 2)})
            print(json.dumps(rows[-1]), flush=True)
    return rows


def threshold_study() -> list:
    rows = []
    for km in (12.0, 30.0):
        for seed in (1, 2):
            geo, xb, xr = pair(km, 50.0, (0.10, 0.12), 360, 10.0, seed)
            for wet in (True, False):
                for mode in ("static", "kinematic"):
                    r = solve(geo, xb, xr, mode=mode, **({} if wet else {"tropo_threshold_km": 1e4}))
                    r.pop("nees")
                    rows.append({"km": km, "seed": seed, "wet": "estimated" if wet else "neglected", "mode": mode, **r})
                    print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    out = {"machine": {"python": platform.python_version(), "cores": os.cpu_count()},
           "nees": nees_study(), "threshold": threshold_study()}
    a.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
