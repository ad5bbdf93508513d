"""Honest uncertainties with default options (issue 11 items 4–5): NEES/NIS and 95 % coverage.

For each structure config and each simulated noise case (white phase noise 2 mm / 1 cm / 2 cm, and
slow multipath: first-order Gauss–Markov with the config's time constant on top of white noise),
several seeds: ``simulate`` (120 s, the config's default disturbance) → ``init`` with default
options (automatic window) → ``estimate`` with default options → ``evaluate`` against the truth.
Reported: integers fixed / total and wrong fixes, the batch's estimated σ, the filter's NEES/dof and
NIS/dof means and the share of epochs inside their 95 % chi-square intervals.

Usage: ``python benchmarks/noise_consistency.py [--seeds 5] [--cases white|multipath|all] [--out FILE.json]``
(one process).  ``--table FILE.json`` prints the markdown table of a saved run (mean and min–max over
seeds per cell, each marked against the targets NEES/dof and NIS/dof in [0.7, 1.4], 95 % coverage in
[90 %, 98 %]) without running anything.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.estimation.filter import EstimateOptions, estimate  # noqa: E402
from cdgps_cli.core.errors import CdgpsError  # noqa: E402
from cdgps_cli.estimation.initializer import InitOptions, initialize  # noqa: E402
from cdgps_cli.core.records import memory_run  # noqa: E402
from cdgps_cli.io.run import write_run  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation  # noqa: E402
from cdgps_cli.pipeline.estimate_outputs import evaluate, write_states  # noqa: E402

CONFIGS = {"testbed-1998": ROOT / "configs" / "testbed-1998-lumped.toml",
           "teague-1995-2dof": ROOT / "configs" / "teague-1995-2dof.toml",
           "fe-mast-noise": ROOT / "configs" / "fe-mast-noise.toml"}
WHITE = [0.002, 0.01, 0.02]
MULTIPATH = [(0.002, 0.015)]


def truth_bias(sim):
    b = {(r["antenna"], r["transmitter"]): r["bias_m"] for r in sim.truth["biases"]}
    return b


def one(cfg, white_m, mp_m, seed, d: Path) -> dict:
    sim = simulate(cfg, SimOptions(duration_s=120.0, seed=seed, phase_sigma_m=white_m, multipath_sigma_m=mp_m))
    run = memory_run(cfg, sim.receiver)
    out = {"seed": seed}
    try:
        init = initialize(run, InitOptions())
    except CdgpsError as exc:
        out["init_error"] = str(exc)
        return out
    tb = truth_bias(sim)
    fixed = [b for b in init["biases"] if b["fixed"]]
    out["n_bias"] = len(init["biases"])
    out["n_fixed"] = len(fixed)
    out["wrong"] = sum(abs(b["bias_m"] - tb[(b["antenna"], b["transmitter"])]) > 0.25 * cfg.wavelength_m
                       for b in fixed)
    out["sigma_hat_m"] = init["sigma_m"]
    res = estimate(run, init, EstimateOptions())
    sub = d / f"s{seed}"
    write_simulation(sim, sub)
    write_run(cfg, sub / "receiver.csv", sub / "run.mcap")
    write_states(res, sub / "run.mcap", init, json.dumps(init), sub / "states.mcap", {})
    ev = evaluate(sub, sub / "states.mcap")
    dof = ev["nees"].get("dof") or cfg.n_modes
    out["nees_per_dof"] = ev["nees"]["mean"] / dof
    out["nees_in95"] = ev["nees"]["fraction_in_interval"]
    out["nis_per_dof"] = ev["nis"]["mean_per_dof"]
    out["nis_in95"] = ev["nis"]["fraction_in_interval95"]
    return out


TARGET_PER_DOF = (0.7, 1.4)
TARGET_COVERAGE = (0.90, 0.98)


def _cell(runs, key, lo, hi, pct=False) -> str:
    """'mean (min–max) ✓' over the seeds that initialized; ✗ when the mean or any seed is off target."""
    v = np.array([r[key] for r in runs if r.get(key) is not None], dtype=float)
    if v.size == 0:
        return "–"
    f = (lambda x: f"{100 * x:.1f} %") if pct else (lambda x: f"{x:.2f}")
    ok_mean = lo <= v.mean() <= hi
    n_out = int(np.sum((v < lo) | (v > hi)))
    mark = "in" if ok_mean else "**OUT**"
    seeds = f"; {n_out} seed{'s' if n_out != 1 else ''} out" if n_out else ""
    return f"{f(v.mean())} ({f(v.min())}–{f(v.max())}) {mark}{seeds}"


def table(rows) -> str:
    """Markdown table of :func:`main`'s rows: per cell mean (min–max over seeds), in/out of target."""
    out = ["| config | white noise | seeds (refused) | σ̂ INIT (mm) | integers all fixed / wrong | NEES/dof | "
           "NEES in 95 % | NIS/dof | NIS in 95 % |", "|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        ok = [r for r in row["runs"] if "init_error" not in r]
        sig = np.array([1000 * r["sigma_hat_m"] for r in ok])
        out.append(f"| {row['config']} | {1000 * row['white_m']:g} mm"
                   + (f" + {1000 * row['multipath_m']:g} mm multipath" if row["multipath_m"] else "")
                   + f" | {row['seeds']} ({row['init_refused']}) | {sig.mean():.2f} ({sig.min():.2f}–{sig.max():.2f}) | "
                   f"{row['all_fixed_runs']}/{len(ok)} / {row['wrong_fixes']} | "
                   f"{_cell(ok, 'nees_per_dof', *TARGET_PER_DOF)} | {_cell(ok, 'nees_in95', *TARGET_COVERAGE, pct=True)} | "
                   f"{_cell(ok, 'nis_per_dof', *TARGET_PER_DOF)} | {_cell(ok, 'nis_in95', *TARGET_COVERAGE, pct=True)} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--table", default=None, help="print the markdown table of a saved --out JSON and exit")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--cases", default="all", choices=("white", "multipath", "all"))
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    if a.table:
        print(table(json.loads(Path(a.table).read_text())))
        return
    cases = ([(w, 0.0) for w in WHITE] if a.cases in ("white", "all") else []) + \
            (MULTIPATH if a.cases in ("multipath", "all") else [])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.configs.split(","):
            cfg = load_config(CONFIGS.get(name, name))
            for w, mp in cases:
                runs = [one(cfg, w, mp, s, Path(tmp) / f"{cfg.name}-{w}-{mp}") for s in range(1, a.seeds + 1)]
                ok = [r for r in runs if "init_error" not in r]
                def m(key):
                    v = [r[key] for r in ok if r.get(key) is not None]
                    return float(np.mean(v)) if v else float("nan")
                row = {"config": cfg.name, "white_m": w, "multipath_m": mp, "seeds": a.seeds,
                       "init_refused": len(runs) - len(ok),
                       "all_fixed_runs": sum(r["n_fixed"] == r["n_bias"] for r in ok),
                       "wrong_fixes": sum(r["wrong"] for r in ok),
                       "sigma_hat_mm": 1000 * m("sigma_hat_m"), "nees_per_dof": m("nees_per_dof"),
                       "nees_in95": m("nees_in95"), "nis_per_dof": m("nis_per_dof"), "nis_in95": m("nis_in95"),
                       "runs": runs}
                rows.append(row)
                print(f"{cfg.name:18s} white {w * 1000:4.1f} mm mp {mp * 1000:4.1f} mm: refused {row['init_refused']}, "
                      f"all fixed {row['all_fixed_runs']}/{len(ok)}, wrong {row['wrong_fixes']}, σ̂ {row['sigma_hat_mm']:.2f} mm, "
                      f"NEES/dof {row['nees_per_dof']:.2f} ({100 * row['nees_in95']:.0f}% in 95%), "
                      f"NIS/dof {row['nis_per_dof']:.2f} ({100 * row['nis_in95']:.0f}% in 95%)", flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))
    print(table(rows))


if __name__ == "__main__":
    main()
