#!/usr/bin/env python3
"""What the batch's worker plugin (``batch_dask.WorkerSettings``) changes in a worker started with dask's
defaults: the estimate stage of one simulated session, timed in

* worker A: a LocalCluster worker as dask starts it (nanny's ``MALLOC_TRIM_THRESHOLD_=65536``);
* worker B: the same after the plugin's allocator setting (``batch_dask._malloc_thresholds``: mmap
  threshold 32 MiB, trim threshold 64 MiB);
* this process (no ``MALLOC_TRIM_THRESHOLD_``): the plain-process reference;

interleaved A, B, process for ``--repeat`` rounds after one warm-up each, with wall and CPU time and the
load average (the machine may be shared).  Writes ``--json`` (default
docs/benchmarks/batch_worker_settings.json)::

    python benchmarks/batch_worker_settings.py --minutes 2 --repeat 5
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"


def _session(work: Path, minutes: float):
    """One simulated session, ingested and initialized here; its Session (stage estimate to run)."""
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.pipeline import batch as B
    from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation

    write_simulation(simulate(load_config(CONFIG), SimOptions(duration_s=60 * minutes, seed=3)), work / "logs")
    m = work / "m.csv"
    m.write_text(f"session,receiver_csv,config,stages\ns,{work}/logs/receiver.csv,{CONFIG},ingest init estimate\n")
    (s,) = B.read_manifest(m)
    B.prepare_outdir([s], m, work / "out")
    for st in ("ingest", "init"):
        B.execute_stage(s, st, False)
    return s


def _copy(s, folder: Path):
    """The session with its own folder (its own states.mcap), same run.mcap and init.json bytes."""
    c = copy.deepcopy(s)
    folder.mkdir(parents=True, exist_ok=True)
    for f in ("run.mcap", "init.json"):
        shutil.copy(Path(s.folder) / f, folder / f)
    c.folder = str(folder)
    return c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=2.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", default=str(ROOT / "docs" / "benchmarks" / "batch_worker_settings.json"))
    a = ap.parse_args()
    os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    import distributed

    from cdgps_cli.pipeline import batch as B
    from cdgps_cli.pipeline import batch_dask as BD

    work = Path(tempfile.mkdtemp(prefix="cdgps-wsettings-"))
    try:
        s = _session(work, a.minutes)
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                      env=B.BLAS_ENV) as cl, distributed.Client(cl) as c:
            wa, wb = sorted(c.scheduler_info()["workers"])
            env = c.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
            said = c.run(lambda: BD._malloc_thresholds(os.environ.get(BD.TRIM_KEY), None), workers=[wb])[wb]
            where = {"A dask defaults": _copy(s, work / "A"), "B plugin's allocator": _copy(s, work / "B"),
                     "plain process": _copy(s, work / "P")}
            rows = {k: [] for k in where}
            for rnd in range(a.repeat + 1):
                for k, sess in where.items():
                    if k == "plain process":
                        r = B.execute_stage(sess, "estimate", False)
                    else:
                        r = c.submit(B.execute_stage, sess, "estimate", False, workers=[wa if k[0] == "A" else wb],
                                     pure=False).result()
                    if rnd:                                   # round 0: warm-up (lazy imports)
                        rows[k].append({"wall_s": round(r["elapsed_s"], 3), "cpu_s": round(r["cpu_s"], 3),
                                        "load1": round(os.getloadavg()[0], 2)})
                    print(k, rnd, round(r["elapsed_s"], 3), round(r["cpu_s"], 3), flush=True)
        out = {"minutes": a.minutes, "repeat": a.repeat, "cpus": os.cpu_count(), "worker_env_trim": env,
               "plugin_on_B": said, "runs": rows,
               "median": {k: {q: statistics.median(x[q] for x in v) for q in ("wall_s", "cpu_s")}
                          for k, v in rows.items()}}
        Path(a.json).write_text(json.dumps(out, indent=2) + "\n")
        for k, v in out["median"].items():
            print(f"{k:24s} median wall {v['wall_s']:.3f} s, CPU {v['cpu_s']:.3f} s")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
