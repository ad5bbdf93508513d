#!/usr/bin/env python3
"""sha256 of every .mcap the golden chains and three testbed estimates write, for two source trees:
the check that a change to the STATES / MCAP writers keeps the files byte for byte (issue 30).

For each ``--tree NAME=PATH`` a fresh process with that tree on PYTHONPATH runs, in the same work
directory (RUN files of GNSS runs record input paths; give trees that sit side by side, e.g. two
``git archive`` copies in one folder, so that ``../shared`` is the same path): tests/golden's
``demo`` (without reports), ``gnss`` and ``gnss_structure`` chains, then a 150 s testbed run
estimated three ways (``--smooth --covariance full --foxglove-rate-hz 0 --scene-exaggeration auto``,
the defaults, ``--scene-exaggeration 0 --foxglove-rate-hz 3``).  Prints the files that differ::

    python benchmarks/states_bytes.py --tree before=/tmp/x/before --tree after=/tmp/x/after
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

CHILD = r"""
import hashlib, json, sys
from pathlib import Path
from tests.golden import golden_chains as gc
work = Path(sys.argv[1])
gc.run_demo(work / "demo", reports=False)
gc.run_gnss(work / "gnss")
gc.run_gnss_structure(work / "gs")
tb = gc.CONFIGS / "testbed-1998.toml"
with gc._cwd(work):
    gc.cdgps("simulate", tb, "--duration", 150, "--seed", 2, "--noise-m", 0.02, "--disturbance-scale", 1, "-o", "tb/sim")
    gc.cdgps("ingest", "tb/sim/receiver.csv", "--config", tb, "-o", "tb/run.mcap")
    gc.cdgps("init", "tb/run.mcap", "--duration", 30, "-o", "tb/init.json")
    gc.cdgps("estimate", "tb/run.mcap", "--init", "tb/init.json", "--smooth", "--covariance", "full",
             "--foxglove-rate-hz", 0, "--scene-exaggeration", "auto", "-o", "tb/states-full.mcap")
    gc.cdgps("estimate", "tb/run.mcap", "--init", "tb/init.json", "-o", "tb/states-default.mcap")
    gc.cdgps("estimate", "tb/run.mcap", "--init", "tb/init.json", "--scene-exaggeration", 0,
             "--foxglove-rate-hz", 3, "-o", "tb/states-noscene.mcap")
print(json.dumps({str(p.relative_to(work)): hashlib.sha256(p.read_bytes()).hexdigest()
                  for p in sorted(work.rglob("*.mcap"))}))
"""


def hashes(tree: Path, work: Path) -> dict:
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1")
    p = subprocess.run([sys.executable, "-c", CHILD, str(work)], cwd=tree, env=env, capture_output=True, text=True)
    if p.returncode:
        raise SystemExit(p.stderr[-3000:])
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tree", action="append", required=True, help="NAME=PATH of a source tree (repeatable)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as td:
        got = {n: hashes(Path(p).resolve(), Path(td) / "work") for n, p in (t.split("=", 1) for t in a.tree)}
    names = list(got)
    print(json.dumps(got, indent=1))
    for n in names[1:]:
        diff = sorted(k for k in set(got[names[0]]) | set(got[n]) if got[names[0]].get(k) != got[n].get(k))
        print(f"{names[0]} vs {n}: {len(got[n])} files, " + (f"differ: {', '.join(diff)}" if diff else "all identical"))


if __name__ == "__main__":
    main()
