"""Multipath survived (issue 11 item 5): Gauss–Markov multipath states in ``init`` and ``estimate``.

Per config and seed: ``simulate`` 120 s of free vibration with first-order Gauss–Markov multipath
(σ 1.5 cm, the config's τ = 30 s) on top of 2 mm white noise → ``init`` (automatic window, σ
estimated) → ``estimate`` (defaults) → ``evaluate`` against the truth; per case: ``auto`` = default
options (init detects the time-correlated residuals and fits σ, τ itself), ``model`` = the true
model given (``init --multipath-sigma-m 0.015 --multipath-tau-s 30``), ``off`` = white noise only
(``--multipath-sigma-m 0``).
Reported per case: runs with every integer fixed, integers fixed / total, wrong fixes (|bias − truth|
> λ/4), NEES/dof of the modal positions, its 95 % coverage, NIS/dof and its 95 % coverage.

Usage: ``python benchmarks/multipath.py [--seeds 20 | --seed-list 5,6,10] [--configs testbed-1998,tower-120m-fe] [--cases auto,model,off] [--duration-s 120] [--window-s W] [--disturbance-scale S] [--out F.json]``
(single process; about 1.5–2 min per seed and config with the model on the testbed).
``--multipath-m 0 --white-m 0.01 --cases auto``: white-noise runs, where the auto case must stay off.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
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
           "tower-120m-fe": ROOT / "configs" / "tower-120m-fe.toml"}
WHITE_M, MP_M, TAU_S = 0.002, 0.015, 30.0


CASES = {"auto": {}, "model": dict(multipath_sigma_m=MP_M, multipath_time_constant_s=TAU_S),
         "off": dict(multipath_sigma_m=0.0)}


def one(cfg, seed: int, case: str, d: Path, white_m: float = WHITE_M, mp_m: float = MP_M,
        duration_s: float = 120.0, window_s: float | None = None, disturbance_scale: float | None = None) -> dict:
    sim = simulate(cfg, SimOptions(duration_s=duration_s, seed=seed, phase_sigma_m=white_m, multipath_sigma_m=mp_m,
                                   disturbance_scale=disturbance_scale))
    run = memory_run(cfg, sim.receiver)
    out = {"seed": seed}
    t = time.perf_counter()
    try:
        init = initialize(run, InitOptions(**CASES[case], **({} if window_s is None else {"duration_s": window_s})))
    except CdgpsError as exc:
        out["init_error"] = str(exc)
        return out
    truth = {(r["antenna"], r["transmitter"]): r["bias_m"] for r in sim.truth["biases"]}
    fixed = [b for b in init["biases"] if b["fixed"]]
    out.update(n_bias=len(init["biases"]), n_fixed=len(fixed), ratio=init["ratio"],
               wrong=sum(abs(b["bias_m"] - truth[(b["antenna"], b["transmitter"])]) > 0.25 * cfg.wavelength_m
                         for b in fixed),
               sigma_hat_m=init["sigma_m"], init_s=time.perf_counter() - t,
               mp_sigma_m=init.get("multipath", {}).get("sigma_m"),
               mp_tau_s=init.get("multipath", {}).get("time_constant_s"))
    res = estimate(run, init, EstimateOptions())
    sub = d / f"s{seed}"
    write_simulation(sim, sub)
    write_run(cfg, sub / "receiver.csv", sub / "run.mcap")
    write_states(res, sub / "run.mcap", init, json.dumps(init), sub / "states.mcap", {})
    ev = evaluate(sub, sub / "states.mcap")
    dof = ev["nees"].get("dof") or cfg.n_modes
    out.update(nees_per_dof=ev["nees"]["mean"] / dof, nees_in95=ev["nees"]["fraction_in_interval"],
               nis_per_dof=ev["nis"]["mean_per_dof"], nis_in95=ev["nis"]["fraction_in_interval95"],
               filter_path=res.filter_path, total_s=time.perf_counter() - t)
    return out


def summarize(cfg_name: str, model: str, runs: list) -> dict:
    ok = [r for r in runs if "init_error" not in r]

    def mean(key):
        v = [r[key] for r in ok if r.get(key) is not None]
        return float(np.mean(v)) if v else float("nan")

    return {"config": cfg_name, "model": model, "seeds": len(runs), "init_refused": len(runs) - len(ok),
            "all_fixed_runs": sum(r["n_fixed"] == r["n_bias"] for r in ok),
            "fixed": sum(r["n_fixed"] for r in ok), "biases": sum(r["n_bias"] for r in ok),
            "wrong_fixes": sum(r["wrong"] for r in ok), "sigma_hat_mm": 1000 * mean("sigma_hat_m"),
            "nees_per_dof": mean("nees_per_dof"), "nees_in95": mean("nees_in95"),
            "nis_per_dof": mean("nis_per_dof"), "nis_in95": mean("nis_in95"),
            "nees_per_dof_range": _range(ok, "nees_per_dof"), "nis_per_dof_range": _range(ok, "nis_per_dof"),
            "mp_sigma_mm_range": [1000 * v for v in _range(ok, "mp_sigma_m")], "mp_tau_s_range": _range(ok, "mp_tau_s"),
            "model_on_runs": sum(r.get("mp_sigma_m") is not None for r in ok),
            "seconds_per_run": mean("total_s"), "runs": runs}


def _range(runs: list, key: str) -> list:
    v = [r[key] for r in runs if r.get(key) is not None]
    return [float(min(v)), float(max(v))] if v else []


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--cases", default="auto,model,off", help="comma-separated: auto, model, off")
    ap.add_argument("--white-m", type=float, default=WHITE_M, help="simulated white phase noise, m")
    ap.add_argument("--multipath-m", type=float, default=MP_M,
                    help="simulated multipath σ, m (0: the false-positive check of the auto case)")
    ap.add_argument("--duration-s", type=float, default=120.0, help="simulated run length, s")
    ap.add_argument("--window-s", type=float, default=None, help="INIT window length, s (default: automatic)")
    ap.add_argument("--seed-list", default=None, help="comma-separated seeds instead of 1..--seeds")
    ap.add_argument("--disturbance-scale", type=float, default=None,
                    help="simulated disturbance / the filter's process noise (default: the config's [simulation])")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    seeds = [int(v) for v in a.seed_list.split(",")] if a.seed_list else list(range(1, a.seeds + 1))
    models = a.cases.split(",")
    if not set(models) <= set(CASES):
        ap.error(f"--cases: expected some of {', '.join(CASES)}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.configs.split(","):
            cfg = load_config(CONFIGS.get(name, name))
            for model in models:
                runs = []
                for s in seeds:
                    runs.append(one(cfg, s, model, Path(tmp) / f"{cfg.name}-{model}", a.white_m, a.multipath_m,
                                    a.duration_s, a.window_s, a.disturbance_scale))
                    print(f"  {cfg.name} model={model} seed {s}: {json.dumps(runs[-1])}", flush=True)
                row = summarize(cfg.name, model, runs)
                rows.append(row)
                print(f"{cfg.name:14s} {model:5s}: model on {row['model_on_runs']}, refused {row['init_refused']}, all "
                      f"fixed {row['all_fixed_runs']}/{row['seeds']}, fixed {row['fixed']}/{row['biases']}, wrong "
                      f"{row['wrong_fixes']}, σ̂ {row['sigma_hat_mm']:.2f} mm, NEES/dof {row['nees_per_dof']:.2f} "
                      f"({100 * row['nees_in95']:.1f}% in 95%, {row['nees_per_dof_range']}), NIS/dof {row['nis_per_dof']:.2f} "
                      f"({100 * row['nis_in95']:.1f}% in 95%), {row['seconds_per_run']:.0f} s/run", flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
