#!/usr/bin/env python3
"""Integer-fix success rate of ``cdgps init`` versus window length and phase noise.

For every (model, noise, seed) one free-vibration run is simulated (library functions, the same
code as ``cdgps simulate``) and initialized on nested windows [0, w] for each window length w
(``initialize`` with the default options: 8 rigid-angle starts, ratio threshold 3, partial fixing;
the 1995 model uses the 1995 batch without process noise unless ``--dof2-process-noise``).  Each
initialization is classified as

* ``success``      every integer correct AND every integer fixed,
* ``fixed wrong``  at least one *fixed* integer differs from the truth (the dangerous case),
* ``not fixed``    no fixed integer is wrong but some are left float (ratio test / partial fixing),
* ``error``        ``initialize`` raised (window not observable, no convergence).

For the 1995 model a ladder of window lengths (in epochs) is scanned per seed and the smallest
window at which every integer is fixed and correct is recorded ("epochs needed").

The runs are built in memory (``Run`` from the simulated receiver table) instead of going through
receiver.csv → ``write_run`` → RUN.mcap; the phase table is the one ``read_run`` would return.

Writes docs/init-success.md (markdown tables + how it was produced + date).  Example::

    python benchmarks/init_success.py                       # full grid, 100 seeds, 2 workers
    python benchmarks/init_success.py --seeds 3 --out /tmp/smoke.md     # smoke run
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import multiprocessing as mp  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.core.errors import CdgpsError  # noqa: E402
from cdgps_cli.estimation.initializer import InitOptions, initialize  # noqa: E402
from cdgps_cli.io.run import Run  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402

CONFIGS = {"testbed": ROOT / "configs" / "testbed-1998-lumped.toml",
           "dof2": ROOT / "configs" / "teague-1995-2dof.toml"}
WRONG_BASIN_M = 1.0     # float-bias RMS error above this: converged to a wrong local minimum
DOF2_LADDER = [3, 4, 5, 6, 7, 8, 10, 12, 15, 20, 30, 40, 60, 80]
_CFG = {}


def _cfg(model):
    if model not in _CFG:
        _CFG[model] = load_config(CONFIGS[model])
    return _CFG[model]


def classify(res: dict, truth: dict) -> dict:
    """Outcome of one initialization against truth.json's biases (runs without slips)."""
    tb = {(b["antenna"], b["transmitter"]): b for b in truth["biases"]}
    wrong = fixed_wrong = n_fixed = 0
    err = []
    for b in res["biases"]:
        t = tb[(b["antenna"], b["transmitter"])]
        bad = b["integer_cycles"] != t["integer_cycles"]
        wrong += bad
        n_fixed += b["fixed"]
        fixed_wrong += bad and b["fixed"]
        err.append(b["float_bias_m"] - t["bias_m"])
    m = len(res["biases"])
    if fixed_wrong:
        outcome = "fixed_wrong"
    elif n_fixed == m and wrong == 0:
        outcome = "success"
    else:
        outcome = "not_fixed"
    ratio = res["ratio"]
    ratio = math.inf if ratio == "inf" else (float("nan") if ratio is None else float(ratio))
    return {"outcome": outcome, "n_wrong": int(wrong), "n_fixed": int(n_fixed), "n_bias": m, "ratio": ratio,
            "float_rms_m": float(np.sqrt(np.mean(np.square(err))))}


def run_task(task: dict) -> list[dict]:
    """Simulate one run and initialize it on each window of the task."""
    cfg = _cfg(task["model"])
    T = cfg.sample_period_s
    if task["model"] == "dof2":
        durations = [ne * T - 1e-6 for ne in task["windows"]]       # ne epochs: 0 … (ne−1)·T
        sim_dur = max(task["windows"]) * T
    else:
        durations = [float(w) for w in task["windows"]]              # w s: w/T + 1 epochs
        sim_dur = max(durations)
    sim = simulate(cfg, SimOptions(duration_s=sim_dur, seed=task["seed"], phase_sigma_m=task["noise"]))
    run = Run(f"<{task['model']} seed {task['seed']}>", cfg, sim.receiver.reset_index(drop=True), sim.gyro, None, {})
    out = []
    for w, dur in zip(task["windows"], durations):
        opt = InitOptions(start_s=0.0, duration_s=dur, process_noise=task["process_noise"])
        t0 = time.perf_counter()
        row = {"model": task["model"], "noise": task["noise"], "seed": task["seed"], "window": w}
        try:
            res = initialize(run, opt)
            row.update(classify(res, sim.truth))
            row["epochs"] = res["window"]["epochs"]
        except CdgpsError as exc:
            row.update({"outcome": "error", "error": str(exc).split(":")[0], "ratio": float("nan"),
                        "float_rms_m": float("nan"), "n_wrong": None, "n_fixed": 0})
        row["time_s"] = time.perf_counter() - t0
        out.append(row)
    return out


def _fmt_ratio(v):
    if not np.isfinite(v):
        return "inf" if v == math.inf else "–"
    return f"{v:.1f}"


def summarize(rows: list[dict], model: str, key_windows: list) -> list[dict]:
    cells = []
    noises = sorted({r["noise"] for r in rows if r["model"] == model})
    for noise in noises:
        for w in key_windows:
            sel = [r for r in rows if r["model"] == model and r["noise"] == noise and r["window"] == w]
            if not sel:
                continue
            n = len(sel)
            cnt = {k: sum(r["outcome"] == k for r in sel) for k in ("success", "fixed_wrong", "not_fixed", "error")}
            ratios = np.array([r["ratio"] for r in sel if r["outcome"] != "error"], dtype=float)
            fin = ratios[np.isfinite(ratios)]
            fr = np.array([r["float_rms_m"] for r in sel if r["outcome"] != "error"], dtype=float)
            basin = sorted(r["seed"] for r in sel if r["outcome"] != "error" and r["float_rms_m"] > WRONG_BASIN_M)
            fw_seeds = sorted(r["seed"] for r in sel if r["outcome"] == "fixed_wrong")
            epochs = sorted({r.get("epochs") for r in sel if r.get("epochs")})
            cells.append({"model": model, "noise": noise, "window": w, "epochs": epochs[0] if len(epochs) == 1 else epochs,
                          "runs": n, **cnt, "success_rate": cnt["success"] / n,
                          "mean_ratio": float(np.mean(fin)) if fin.size else float("nan"),
                          "median_ratio": float(np.median(ratios)) if ratios.size else float("nan"),
                          "min_ratio": float(np.min(ratios)) if ratios.size else float("nan"),
                          "float_rms_cm_median": float(np.median(fr) * 100) if fr.size else float("nan"),
                          "wrong_basin": len(basin), "wrong_basin_seeds": basin, "fixed_wrong_seeds": fw_seeds,
                          "errors": sorted({r["error"] for r in sel if r["outcome"] == "error"}),
                          "mean_time_s": float(np.mean([r["time_s"] for r in sel]))})
    return cells


def epochs_needed(rows: list[dict], ladder: list[int]) -> list[dict]:
    out = []
    for noise in sorted({r["noise"] for r in rows if r["model"] == "dof2"}):
        per_seed = {}
        for r in rows:
            if r["model"] == "dof2" and r["noise"] == noise:
                per_seed.setdefault(r["seed"], {})[r["window"]] = r["outcome"]
        need = []
        for seed, res in per_seed.items():
            first = next((ne for ne in ladder if res.get(ne) == "success"), None)
            need.append(first)
        got = np.array([v for v in need if v is not None], dtype=float)
        out.append({"noise": noise, "seeds": len(need), "never": sum(v is None for v in need),
                    "min": int(got.min()) if got.size else None,
                    "median": float(np.median(got)) if got.size else None,
                    "p90": float(np.percentile(got, 90)) if got.size else None,
                    "max": int(got.max()) if got.size else None,
                    "histogram": {str(ne): int(sum(v == ne for v in need)) for ne in ladder if any(v == ne for v in need)}})
    return out


def write_markdown(path: Path, args, tb_cells, d2_cells, need, wall_s, n_inits, reduced_note) -> None:
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    L = ["# Integer-fix success rate of `cdgps init`", "",
         f"Produced {now} by `python benchmarks/init_success.py {' '.join(sys.argv[1:])}` "
         f"({n_inits} initializations, {args.seeds} seeds per cell, {args.workers} worker processes, "
         f"wall time {wall_s / 60:.1f} min on {os.cpu_count()} CPUs, Python {platform.python_version()}).", ""]
    if reduced_note:
        L += [reduced_note, ""]
    L += ["How: for each (model, noise, seed) one free-vibration run is simulated with the library "
          "(`simulate(cfg, SimOptions(duration_s, seed, phase_sigma_m=noise))`, seeds 0…N−1) and initialized "
          "with `initialize(run, InitOptions(start_s=0, duration_s=window))` on nested windows starting at 0 s. "
          "Defaults otherwise: 8 rigid-angle starts, ratio threshold 3, partial fixing on, measurement weighting "
          "from the config (testbed 2 cm, 1995 model 1 cm) whatever the simulated noise. "
          + ("The 1995 model uses the 1995 batch (no process noise in the batch; the simulator still applies "
             "the config's process noise). " if not args.dof2_process_noise else
             "The 1995 model uses the batch with process noise. ")
          + "Runs are built in memory from the simulated receiver table (no CSV/MCAP round trip).", "",
          "Outcomes: **success** = every integer correct and fixed; **fixed wrong** = at least one fixed integer "
          "differs from the truth (dangerous); **not fixed** = no wrong fixed integer, but some left float; "
          "**error** = `initialize` raised (not observable / no convergence). Ratio = LAMBDA second-best/best "
          "squared norm (full set). Float RMS = RMS over channels of float bias − true bias (median over runs). "
          f"**wrong basin** = Gauss–Newton converged to a wrong local minimum (float RMS > {WRONG_BASIN_M:g} m; these runs "
          "are also counted in one of the other columns).", ""]

    def table(cells, wname):
        out = [f"| {wname} | epochs | noise (m) | runs | success | fixed wrong | not fixed | error | wrong basin "
               "| median ratio | min ratio | mean ratio | median float RMS (cm) | mean time (s) |",
               "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for c in cells:
            out.append(f"| {c['window']:g} | {c['epochs']} | {c['noise']:g} | {c['runs']} | **{100 * c['success_rate']:.0f} %** "
                       f"| {c['fixed_wrong']} | {c['not_fixed']} | {c['error']} | {c['wrong_basin']} "
                       f"| {_fmt_ratio(c['median_ratio'])} | {_fmt_ratio(c['min_ratio'])} | {_fmt_ratio(c['mean_ratio'])} "
                       f"| {c['float_rms_cm_median']:.2f} | {c['mean_time_s']:.2f} |")
        return out

    def details(cells, unit):
        out = []
        for c in cells:
            bits = []
            if c["fixed_wrong_seeds"]:
                bits.append(f"fixed wrong: seeds {', '.join(map(str, c['fixed_wrong_seeds']))}")
            if c["wrong_basin_seeds"]:
                bits.append(f"wrong basin (float RMS > {WRONG_BASIN_M:g} m): seeds {', '.join(map(str, c['wrong_basin_seeds']))}")
            if c["errors"]:
                bits.append(f"errors: {'; '.join(c['errors'])}")
            if bits:
                out.append(f"- {c['window']:g} {unit}, noise {c['noise']:g} m: " + "; ".join(bits))
        return out + [""] if out else []

    if tb_cells:
        L += ["## Testbed (configs/testbed-1998-lumped.toml, 36 channels, 10 Hz)", ""] + table(tb_cells, "window (s)") + [""]
        L += details(tb_cells, "s")
    if d2_cells:
        L += ["## 1995 two-DOF model (configs/teague-1995-2dof.toml, 12 channels, 0.12 s)", ""]
        L += table(d2_cells, "window (epochs)") + [""]
        L += details(d2_cells, "epochs")
    if need:
        L += ["### 1995 model: epochs needed to fix every integer correctly",
              "",
              f"Smallest window on the ladder {args.dof2_ladder} at which every integer is fixed and correct "
              "(the paper reports integers within 2 cycles after 2.4 s = 20 epochs).", "",
              "| noise (m) | seeds | min | median | 90th pct | max | never (within ladder) | histogram (epochs: seeds) |",
              "|---:|---:|---:|---:|---:|---:|---:|---|"]
        for e in need:
            hist = ", ".join(f"{k}: {v}" for k, v in e["histogram"].items())
            L.append(f"| {e['noise']:g} | {e['seeds']} | {e['min']} | {e['median']:g} | {e['p90']:.1f} | {e['max']} | {e['never']} | {hist} |")
        L.append("")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(L))


def _floats(s):
    return [float(v) for v in s.split(",") if v.strip()]


def _ints(s):
    return [int(v) for v in s.split(",") if v.strip()]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=100, help="seeds 0…N−1 per cell (default 100)")
    ap.add_argument("--testbed-windows", type=_floats, default=[10.0, 20.0, 30.0, 60.0], help="seconds, comma separated")
    ap.add_argument("--testbed-noise", type=_floats, default=[0.005, 0.01, 0.02], help="metres, comma separated")
    ap.add_argument("--dof2-epochs", type=_ints, default=[10, 20, 40, 80], help="1995 windows (epochs) in the table")
    ap.add_argument("--dof2-ladder", type=_ints, default=DOF2_LADDER, help="1995 windows scanned for 'epochs needed'")
    ap.add_argument("--dof2-noise", type=_floats, default=[0.01, 0.02, 0.05], help="metres, comma separated")
    ap.add_argument("--dof2-process-noise", action="store_true", help="1995 model: batch with process noise")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "init-success.md")
    ap.add_argument("--raw", type=Path, default=None, help="also write every run as JSON lines here")
    ap.add_argument("--note", default="", help="extra note for the markdown (e.g. why the grid was reduced)")
    args = ap.parse_args(argv)
    args.dof2_ladder = sorted(set(args.dof2_ladder) | set(args.dof2_epochs))
    tasks = []
    for noise in args.testbed_noise:
        for seed in range(args.seeds):
            if args.testbed_windows:
                tasks.append({"model": "testbed", "noise": noise, "seed": seed, "windows": args.testbed_windows,
                              "process_noise": True})
    for noise in args.dof2_noise:
        for seed in range(args.seeds):
            if args.dof2_ladder:
                tasks.append({"model": "dof2", "noise": noise, "seed": seed, "windows": args.dof2_ladder,
                              "process_noise": args.dof2_process_noise})
    # long tasks first so the two workers finish together
    tasks.sort(key=lambda t: t["model"] != "testbed")
    t0 = time.perf_counter()
    rows = []
    raw = open(args.raw, "w") if args.raw else None
    with mp.get_context("fork").Pool(args.workers) as pool:
        for i, res in enumerate(pool.imap_unordered(run_task, tasks, chunksize=1), 1):
            rows.extend(res)
            if raw:
                for r in res:
                    raw.write(json.dumps(r) + "\n")
                raw.flush()
            if i % 10 == 0 or i == len(tasks):
                print(f"[{time.perf_counter() - t0:7.1f} s] {i}/{len(tasks)} tasks", flush=True)
    if raw:
        raw.close()
    wall = time.perf_counter() - t0
    tb_cells = summarize(rows, "testbed", args.testbed_windows)
    d2_cells = summarize(rows, "dof2", args.dof2_epochs)
    need = epochs_needed(rows, args.dof2_ladder)
    write_markdown(args.out, args, tb_cells, d2_cells, need, wall, len(rows), args.note)
    for c in tb_cells + d2_cells:
        print(f"{c['model']:8s} window {c['window']:>5} noise {c['noise']:<6g} success {100 * c['success_rate']:5.1f} % "
              f"fixed-wrong {c['fixed_wrong']:3d} not-fixed {c['not_fixed']:3d} error {c['error']:3d} "
              f"median ratio {_fmt_ratio(c['median_ratio'])}")
    for e in need:
        print(f"dof2 noise {e['noise']:g}: epochs needed median {e['median']} p90 {e['p90']} max {e['max']} never {e['never']}")
    print(f"wrote {args.out} ({len(rows)} initializations in {wall / 60:.1f} min)")


if __name__ == "__main__":
    main()
