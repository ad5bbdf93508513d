#!/usr/bin/env python3
"""``cdgps info`` on one MCAP file with two source trees, alternately (issue 29: info < 1 s at 24 h).

Each round runs ``cdgps -q info --json FILE`` once per tree, in a fresh process with that tree on
PYTHONPATH and the working directory outside both (so ``sys.path[0]`` does not pick a tree), and
records wall s, the child's CPU s (user + sys, all threads) and the 1-minute load average when it
started; the machine may be shared, so compare the trees within one run::

    python benchmarks/info_ab.py /tmp/long/24h/run.mcap --tree before=/tmp/before --tree after=. --rounds 7
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def one(tree: Path, mcap: Path) -> dict:
    load = os.getloadavg()[0]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "from cdgps_cli.cli.commands import main; main()", "-q", "info", "--json",
                    str(mcap)], env=dict(os.environ, PYTHONPATH=str(tree)), stdout=subprocess.DEVNULL, check=True,
                   cwd=tempfile.gettempdir())
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"wall_s": round(wall, 3), "cpu_s": round(cpu, 3), "load_1min": round(load, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mcap", type=Path)
    ap.add_argument("--tree", action="append", required=True, help="NAME=PATH (repeatable)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    trees = {n: Path(p).resolve() for n, p in (t.split("=", 1) for t in a.tree)}
    res: dict = {n: [] for n in trees}
    for _ in range(a.rounds):
        for n, t in trees.items():
            res[n].append(one(t, a.mcap))
    for n, v in res.items():
        print(f"{n}: wall median {statistics.median(x['wall_s'] for x in v):.3f} s, best {min(x['wall_s'] for x in v):.3f} s; "
              f"CPU best {min(x['cpu_s'] for x in v):.3f} s")
    if a.out:
        a.out.write_text(json.dumps({"file": str(a.mcap), "bytes": a.mcap.stat().st_size, "rounds": res}, indent=1) + "\n")


if __name__ == "__main__":
    main()
