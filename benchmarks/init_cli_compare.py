#!/usr/bin/env python3
"""The whole ``cdgps init`` process of two checkouts on the testbed hour, timed in turn (issue 30 item 1).

The case: ``configs/testbed-1998-lumped.toml``, ``cdgps simulate --duration 3600 --seed 7 --noise-m
0.01`` then ``ingest`` (made once, by this checkout), then ``cdgps --quiet init RUN`` (automatic
window, 8 starts) as a child process with ``PYTHONPATH`` set to each checkout, the two alternating
for ``--rounds`` rounds (order swapped every round).  Reports per side the best and median wall time
and the ratio this / other of each round (the load moves between them; the load average is
recorded), and checks that both wrote the same INIT.json but its ``elapsed_s``.

    python benchmarks/init_cli_compare.py --other /path/to/other-checkout [--rounds 7]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"
CLI = "from cdgps_cli.cli.commands import main; main()"


def cdgps(tree: Path, *args) -> float:
    env = dict(os.environ, PYTHONPATH=str(tree))
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", CLI, *map(str, args)], cwd=tree, env=env, check=True,
                   capture_output=True, text=True)
    return time.perf_counter() - t


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--other", type=Path, required=True, help="the checkout to compare with")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "init_cli_compare.json")
    args = ap.parse_args(argv)
    sides = {"this": ROOT, "other": args.other.resolve()}
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        cdgps(ROOT, "--quiet", "simulate", CONFIG, "--duration", 3600, "--seed", 7, "--noise-m", 0.01, "-o", d / "sim")
        cdgps(ROOT, "--quiet", "ingest", d / "sim" / "receiver.csv", "--config", CONFIG, "-o", d / "run.mcap")
        load0 = os.getloadavg()[0]
        times = {k: [] for k in sides}
        loads = []
        for i in range(args.rounds):
            for name in (("this", "other") if i % 2 == 0 else ("other", "this")):
                times[name].append(cdgps(sides[name], "--quiet", "init", d / "run.mcap", "-o", d / f"{name}.json"))
            loads.append(round(os.getloadavg()[0], 2))
            print(f"round {i + 1}: this {times['this'][-1]:.3f} s, other {times['other'][-1]:.3f} s "
                  f"(load {loads[-1]})", flush=True)
        inits = [{k: v for k, v in json.loads((d / f"{n}.json").read_text()).items() if k != "elapsed_s"} for n in sides]
    ratios = [a / b for a, b in zip(times["this"], times["other"])]
    res = {"case": "cdgps init on the testbed hour (lumped config, seed 7, 1 cm, automatic window)",
           "this": str(sides["this"]), "other": str(sides["other"]), "wall_s": times,
           "best_s": {k: min(v) for k, v in times.items()}, "median_s": {k: statistics.median(v) for k, v in times.items()},
           "ratio_per_round": ratios, "ratio_median": statistics.median(ratios),
           "same_init_json": inits[0] == inits[1], "load_average_start": round(load0, 2), "load_average_rounds": loads}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    print(f"best this {res['best_s']['this']:.3f} s, other {res['best_s']['other']:.3f} s; ratio median "
          f"{res['ratio_median']:.3f}; same INIT.json: {res['same_init_json']}; wrote {args.out}")


if __name__ == "__main__":
    main()
