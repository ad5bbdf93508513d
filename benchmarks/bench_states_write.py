#!/usr/bin/env python3
"""The STATES writing of ``cdgps estimate`` (``pipeline.estimate_outputs.write_states``: the JSON
channels, the 3-D scene, the packed arrays) on the testbed hour, for source trees side by side.

The testbed hour as benchmarks/bench_driver.py makes it (simulate 1 h at 10 Hz, σ 2 cm; ingest; init
on 60 s), or ``--data DIR`` holding its run.mcap and init.json.  Each tree (``--tree NAME=PATH``), in a
fresh process per round with that tree on PYTHONPATH, estimates once (not timed), then writes STATES
``--writes`` times; the best wall and CPU (user + system, every thread) seconds of a round are kept.
Rounds interleave the trees; the machine's load is recorded.  Writes docs/benchmarks/states_write.json::

    python benchmarks/bench_states_write.py --tree before=/tmp/before --tree after=.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

CHILD = """
import json, os, sys, time
for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"): os.environ.setdefault(v, "1")
from cdgps_cli.estimation.filter import EstimateOptions, estimate
from cdgps_cli.io.run import read_run
from cdgps_cli.pipeline.estimate_outputs import write_states
d = sys.argv[1]
run = read_run(d + "/run.mcap")
text = open(d + "/init.json").read()
res = estimate(run, json.loads(text), EstimateOptions())
wall = cpu = 1e9
for _ in range(int(sys.argv[2])):
    t, c = time.perf_counter(), time.process_time()
    write_states(res, d + "/run.mcap", json.loads(text), text, sys.argv[3], {}, run_sha256="x")
    wall, cpu = min(wall, time.perf_counter() - t), min(cpu, time.process_time() - c)
print(json.dumps({"wall_s": wall, "cpu_s": cpu}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tree", action="append", required=True, help="NAME=PATH of a source tree (repeatable)")
    ap.add_argument("--data", type=Path, help="folder with the testbed hour's run.mcap and init.json")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--writes", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "states_write.json")
    a = ap.parse_args()
    trees = [t.split("=", 1) for t in a.tree]
    with tempfile.TemporaryDirectory() as td:
        d = a.data or Path(td)
        if a.data is None:
            from bench_driver import setup
            setup(d, 1.0, 1)
        rounds = []
        for _ in range(a.rounds):
            row = {"load_start": os.getloadavg()[0]}
            for name, path in trees:
                env = dict(os.environ, PYTHONPATH=str(Path(path).resolve()))
                p = subprocess.run([sys.executable, "-c", CHILD, str(d), str(a.writes), str(Path(td) / f"{name}.mcap")],
                                   env=env, cwd=Path(path).resolve(), capture_output=True, text=True, check=True)
                row[name] = json.loads(p.stdout.strip().splitlines()[-1])
            row["load_end"] = os.getloadavg()[0]
            rounds.append(row)
    res = {"rounds": rounds, "command": "python benchmarks/bench_states_write.py " + " ".join(sys.argv[1:]),
           "date": time.strftime("%Y-%m-%d %H:%M")}
    for name, _ in trees:
        res[name] = {k: float(np.median([r[name][k] for r in rounds])) for k in ("wall_s", "cpu_s")}
        res[name].update({"best_" + k: float(min(r[name][k] for r in rounds)) for k in ("wall_s", "cpu_s")})
        print(f"{name:8s} write_states median wall {res[name]['wall_s']:.3f} s, CPU {res[name]['cpu_s']:.3f} s "
              f"(best {res[name]['best_wall_s']:.3f} / {res[name]['best_cpu_s']:.3f} s)")
    print("loads", [[round(r["load_start"], 2), round(r["load_end"], 2)] for r in rounds])
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
