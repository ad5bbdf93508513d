"""How well does a window of length L estimate a 30 s Gauss–Markov multipath? (issue 11 item 5)

The automatic multipath model of ``init`` (:func:`cdgps_cli.measurement.multipath.fit_autocovariance`)
fits σ_mp, τ and the white σ to the pooled autocovariance of per-channel residual stretches.  This
study isolates the estimator from the batch: per trial, C channels of first-order Gauss–Markov
multipath (σ_mp, τ, exact discretization, stationary start) plus white noise are sampled at the
testbed's 10 Hz over L seconds and handed to ``fit_autocovariance`` as the residuals of one bias
segment per channel (the batch's demeaning per segment is what the estimator models).  What the
batch's structure trajectory absorbs is not in this study, so it shows the window-length part
of the error only.  Reported per L: mean and 10–90 % range of σ̂_mp/σ_mp, τ̂/τ and of the drift
ratio (σ̂²/τ̂)/(σ²/τ), the quantity that sets the filter's multipath prediction variance over a step.

Usage: ``python benchmarks/multipath_window.py [--trials 40] [--channels 36] [--windows 60,120,240,480]``
(seconds; a few seconds per window on one core).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from cdgps_cli.measurement.multipath import fit_autocovariance  # noqa: E402


def gm_series(rng, n: int, c: int, dt_s: float, sigma_m: float, tau_s: float) -> np.ndarray:
    """(n, c) stationary first-order Gauss–Markov samples: m_{k+1} = a m_k + σ √(1−a²) ω_k."""
    a = math.exp(-dt_s / tau_s)
    w = rng.standard_normal((n, c)) * sigma_m * math.sqrt(1.0 - a * a)
    m = np.empty((n, c))
    m[0] = rng.standard_normal(c) * sigma_m
    for k in range(1, n):
        m[k] = a * m[k - 1] + w[k]
    return m


def study(window_s: float, trials: int, channels: int, dt_s: float, sigma_m: float, tau_s: float,
          white_m: float, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    n = int(round(window_s / dt_s))
    seg = np.zeros((n, channels), dtype=np.int64)
    s_r, t_r, d_r, det = [], [], [], 0
    for _ in range(trials):
        y = gm_series(rng, n, channels, dt_s, sigma_m, tau_s) + white_m * rng.standard_normal((n, channels))
        f = fit_autocovariance(y, seg, dt_s)
        s_r.append(f["sigma_m"] / sigma_m)
        t_r.append(f["time_constant_s"] / tau_s)
        d_r.append((f["sigma_m"] ** 2 / f["time_constant_s"]) / (sigma_m**2 / tau_s))
        det += f["detected"]

    def stats(v):
        v = np.asarray(v)
        return {"mean": float(v.mean()), "p10": float(np.quantile(v, 0.1)), "p90": float(np.quantile(v, 0.9))}

    return {"window_s": window_s, "trials": trials, "detected": det, "sigma_ratio": stats(s_r),
            "tau_ratio": stats(t_r), "drift_ratio": stats(d_r)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--channels", type=int, default=36)
    ap.add_argument("--windows", default="60,120,240,480")
    ap.add_argument("--sigma-m", type=float, default=0.015)
    ap.add_argument("--tau-s", type=float, default=30.0)
    ap.add_argument("--white-m", type=float, default=0.002)
    ap.add_argument("--dt-s", type=float, default=0.1)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    rows = []
    for i, w in enumerate(float(v) for v in a.windows.split(",")):
        r = study(w, a.trials, a.channels, a.dt_s, a.sigma_m, a.tau_s, a.white_m, seed=1000 + i)
        rows.append(r)
        print(f"L = {w:5.0f} s: detected {r['detected']}/{r['trials']}; σ̂/σ {r['sigma_ratio']['mean']:.2f} "
              f"({r['sigma_ratio']['p10']:.2f}–{r['sigma_ratio']['p90']:.2f}); τ̂/τ {r['tau_ratio']['mean']:.2f} "
              f"({r['tau_ratio']['p10']:.2f}–{r['tau_ratio']['p90']:.2f}); drift ratio {r['drift_ratio']['mean']:.2f} "
              f"({r['drift_ratio']['p10']:.2f}–{r['drift_ratio']['p90']:.2f})", flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
