#!/usr/bin/env python3
"""``initialize()`` of two checkouts timed in turn, for a ratio that holds on a loaded machine (issue 13 item 6).

The case is bench_init's: the testbed (``configs/testbed-1998-lumped.toml``), 60 s of free vibration (601
epochs), seed 1, 1 cm phase noise, ``initialize`` with the 8-start cold start (and 1 start).  Each
checkout is measured in its own child process with its own interpreter (its venv, its compiled
kernel), the two alternating ``--rounds`` times; each child runs the call ``--repeat`` times and keeps
its best wall-clock and best CPU time (``time.process_time``: all threads of the process).  The
summary gives per checkout the best over rounds and the ratio *this / other* of those bests, and of
each round (the spread says how much the load moved between the two).  The children also report the
INIT cost, integers fixed and iterations, so that a speed-up that changed the answer shows.

    python benchmarks/init_speed_compare.py --other /path/to/main-worktree [--other-python …/.venv/bin/python]

Writes ``--out`` (JSON: per round and summary, with the load average at the start and end).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

CHILD = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
from pathlib import Path
from cdgps_cli.config.structure import load_config
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.io.run import Run
from cdgps_cli.sim.structure import SimOptions, simulate
from cdgps_cli.estimation import kernel
cfg = load_config(Path(sys.argv[1]) / "configs" / "testbed-1998-lumped.toml")
dur, repeat = float(sys.argv[2]), int(sys.argv[3])
sim = simulate(cfg, SimOptions(duration_s=dur, seed=1, phase_sigma_m=0.01))
run = Run("<testbed>", cfg, sim.receiver.reset_index(drop=True), sim.gyro, None, {})
out = {"kernel": kernel.path_name()}
for starts in (8, 1):
    opt = InitOptions(start_s=0.0, duration_s=dur, starts=starts)
    initialize(run, opt)                                    # warm-up (imports, caches)
    wall, cpu = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        res = initialize(run, opt)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    out[f"starts{starts}"] = {"wall_s": min(wall), "cpu_s": min(cpu), "cost": res["cost"],
                              "n_fixed": res["n_fixed"], "iterations": res["iterations"]}
print(json.dumps(out))
"""


def child(python: str, root: Path, duration_s: float, repeat: int) -> dict:
    done = subprocess.run([python, "-c", CHILD, str(root), str(duration_s), str(repeat)], cwd=root,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--other", type=Path, required=True, help="the checkout to compare with (e.g. a worktree of main)")
    ap.add_argument("--other-python", default=None, help="its interpreter (default: OTHER/.venv/bin/python)")
    ap.add_argument("--python", default=sys.executable, help="this checkout's interpreter")
    ap.add_argument("--duration", type=float, default=60.0, help="window length in seconds (60 s: 601 epochs)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "init_compare.json")
    args = ap.parse_args(argv)
    other_py = args.other_python or str(args.other / ".venv" / "bin" / "python")
    sides = {"this": (args.python, ROOT), "other": (other_py, args.other.resolve())}
    load0 = os.getloadavg()
    rounds = []
    for i in range(args.rounds):
        rnd = {}
        for name in (("this", "other") if i % 2 == 0 else ("other", "this")):
            rnd[name] = child(*sides[name], args.duration, args.repeat)
            rnd[f"{name}_load_1min"] = round(os.getloadavg()[0], 2)
        rounds.append(rnd)
        s8, o8 = rnd["this"]["starts8"], rnd["other"]["starts8"]
        print(f"round {i + 1}: 8 starts this {s8['wall_s']:.3f} s wall / {s8['cpu_s']:.3f} s CPU, other "
              f"{o8['wall_s']:.3f} / {o8['cpu_s']:.3f} s, CPU ratio {s8['cpu_s'] / o8['cpu_s']:.3f} "
              f"(load {rnd['this_load_1min']}, {rnd['other_load_1min']})", flush=True)
    summary = {}
    for starts in ("starts8", "starts1"):
        best = {name: {k: min(r[name][starts][k] for r in rounds) for k in ("wall_s", "cpu_s")} for name in sides}
        summary[starts] = {
            "this": best["this"], "other": best["other"],
            "ratio_wall": best["this"]["wall_s"] / best["other"]["wall_s"],
            "ratio_cpu": best["this"]["cpu_s"] / best["other"]["cpu_s"],
            "ratio_cpu_per_round": [r["this"][starts]["cpu_s"] / r["other"][starts]["cpu_s"] for r in rounds],
            "same_answer": all(r["this"][starts]["n_fixed"] == r["other"][starts]["n_fixed"]
                               and r["this"][starts]["iterations"] == r["other"][starts]["iterations"]
                               and abs(r["this"][starts]["cost"] - r["other"][starts]["cost"])
                               <= 1e-9 * abs(r["other"][starts]["cost"]) for r in rounds),
        }
    res = {"case": f"testbed {args.duration:g} s, seed 1, sigma 1 cm", "this": str(ROOT), "other": str(sides["other"][1]),
           "rounds": rounds, "summary": summary,
           "load_average_start_end": [round(load0[0], 2), round(os.getloadavg()[0], 2)]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    for starts, s in summary.items():
        print(f"{starts}: this {s['this']['wall_s']:.3f} s wall / {s['this']['cpu_s']:.3f} s CPU; other "
              f"{s['other']['wall_s']:.3f} / {s['other']['cpu_s']:.3f}; ratio wall {s['ratio_wall']:.3f}, CPU "
              f"{s['ratio_cpu']:.3f} (per round {', '.join(f'{v:.2f}' for v in s['ratio_cpu_per_round'])}); "
              f"same answer: {s['same_answer']}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
