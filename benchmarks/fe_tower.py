#!/usr/bin/env python3
"""The FE-model tower (configs/tower-120m-fe.toml) over seeds and noise levels → docs/benchmarks/fe_tower.json.

Per seed and white phase-noise level (the config's prior σ is 5 mm; the simulated forcing is the
model's process noise, disturbance scale 1): 300 s free vibration, INIT with default options,
``estimate`` with default options (biases fixed), then against the simulator's truth (computed here
from the modal states, independently of ``evaluate``):

* NEES/dof of the modal positions ξ and the share of epochs inside the per-epoch 95 % interval;
* NIS/dof of the filter;
* coverage of the exported top-point displacement (``export --points``' σ): share of epochs with
  |error| ≤ 1.96 σ, per lab axis x and y;
* integers fixed / wrong; spectra (default settings): frequency error of the four modes.

The config's σ is used as given (no noise estimation): at noise levels other than 5 mm the
figures show how wrong a fixed prior is (the subject of issue 11, item 4).

Example::

    python benchmarks/fe_tower.py                 # 5 seeds × 4 noise levels (≈ 3–6 min)
    python benchmarks/fe_tower.py --seeds 2 --noise 0.005
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.estimation.filter import EstimateOptions, estimate  # noqa: E402
from cdgps_cli.estimation.initializer import InitOptions, initialize  # noqa: E402
from cdgps_cli.model.points import point_displacements, select_points  # noqa: E402
from cdgps_cli.core.records import memory_run  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402
from cdgps_cli.analysis.spectra import SpectraOptions, compute_spectra  # noqa: E402

CFG = load_config(ROOT / "configs" / "tower-120m-fe.toml")


def one(seed: int, noise_m: float) -> dict:
    sim = simulate(CFG, SimOptions(duration_s=300.0, seed=seed, phase_sigma_m=noise_m))
    run = memory_run(CFG, sim.receiver, sim.gyro)
    init = initialize(run, InitOptions())
    res = estimate(run, init, EstimateOptions())
    nm = CFG.n_modes
    k = np.rint(res.time_s / CFG.sample_period_s).astype(int)
    d = res.x[:, :nm] - sim.x[k, :nm]
    P = res.P[:, :nm, :nm]
    nees = np.einsum("ni,ni->n", d, np.linalg.solve(P, d[..., None])[..., 0])
    ok = res.nis_dof > 0
    pts = select_points(CFG, "top")
    dp, sp, _ = point_displacements(CFG, pts, res.x[:, :nm], P)
    dt, _, _ = point_displacements(CFG, pts, sim.x[k, :nm], P)
    z = (dp - dt)[:, 0, :2] / sp[:, 0, :2]
    spec = compute_spectra(CFG, res.time_s, res.x[:, :nm] @ np.asarray(CFG.mode_shapes).T, None, None,
                           SpectraOptions())
    return {
        "seed": seed, "noise_m": noise_m, "epochs": int(len(res.time_s)),
        "n_fixed": init["n_fixed"], "segments": len(init["biases"]),
        "nees_per_dof": float(np.mean(nees) / nm),
        "nees_in_95": float(np.mean((nees >= chi2.ppf(0.025, nm)) & (nees <= chi2.ppf(0.975, nm)))),
        "nis_per_dof": float(np.mean(res.nis[ok] / res.nis_dof[ok])),
        "top_coverage_95": [float(np.mean(np.abs(z[:, a]) <= 1.96)) for a in range(2)],
        "top_sigma_median_m": [float(np.median(sp[:, 0, a])) for a in range(2)],
        "freq_error_pct": {m["mode"]: m["error_pct"] for m in spec["modes"]},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--noise", type=float, nargs="*", default=[0.002, 0.005, 0.01, 0.02])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "fe_tower.json")
    a = ap.parse_args()
    rows = []
    for noise in a.noise:
        for seed in range(1, a.seeds + 1):
            r = one(seed, noise)
            rows.append(r)
            print(f"noise {noise * 1000:4.1f} mm seed {seed}: NEES/dof {r['nees_per_dof']:.3f} "
                  f"({100 * r['nees_in_95']:.1f}% in 95%), NIS/dof {r['nis_per_dof']:.3f}, top 95% coverage "
                  f"x {100 * r['top_coverage_95'][0]:.1f}% y {100 * r['top_coverage_95'][1]:.1f}%, "
                  f"{r['n_fixed']}/{r['segments']} fixed, f errors "
                  + " ".join(f"{v:+.2f}%" if v is not None else "–" for v in r["freq_error_pct"].values()),
                  flush=True)
    summary = {}
    for noise in a.noise:
        sel = [r for r in rows if r["noise_m"] == noise]
        summary[f"{noise:g}"] = {
            "nees_per_dof_mean": float(np.mean([r["nees_per_dof"] for r in sel])),
            "nis_per_dof_mean": float(np.mean([r["nis_per_dof"] for r in sel])),
            "nees_in_95_mean": float(np.mean([r["nees_in_95"] for r in sel])),
            "top_coverage_95_mean": float(np.mean([r["top_coverage_95"] for r in sel])),
            "runs_all_fixed": sum(r["n_fixed"] == r["segments"] for r in sel), "runs": len(sel)}
    out = {"benchmark": "benchmarks/fe_tower.py", "config": "configs/tower-120m-fe.toml",
           "config_prior_sigma_m": CFG.measurement_sigma_m, "date": datetime.date.today().isoformat(),
           "machine": platform.platform(), "summary": summary, "runs": rows}
    a.out.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
