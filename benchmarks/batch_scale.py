#!/usr/bin/env python3
"""`cdgps batch` scale (issue 17 item 5): 16 simulated sessions of 10 minutes, 2 dask workers vs the
serial loop, in the same run.

1. simulates N sessions (testbed config, seeds 1…N, cached in ``--workdir``) and writes a manifest
   (stages ingest → init → estimate --smooth → spectra);
2. **serial**: the same stage functions one session after another in this process
   (:func:`cdgps_cli.pipeline.batch.execute_stage`, no dask), wall time;
3. **batch**: :func:`cdgps_cli.pipeline.batch_dask.run_batch` on a LocalCluster of ``--workers``
   processes (one thread each, BLAS at one thread), wall time including the cluster's start;
4. memory: peak RSS (``ru_maxrss``) of each worker process after the batch, against the peak RSS of a
   fresh process that runs one session's stages alone (the bound "one session per worker");
5. scheduler overhead per task: the batch's wall time against the sum of its task times.

Prints a table and writes ``--json`` (default docs/batch-scale.json).  The figures depend on the
machine's load: the report says how many cores and the load average at the start::

    python benchmarks/batch_scale.py                      # ≈ 10-20 min on 2 idle cores
    python benchmarks/batch_scale.py --sessions 4 --duration 120 --json /tmp/b.json
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "testbed-1998.toml"

ONE_SESSION = """
import resource, sys
from cdgps_cli.pipeline import batch as B
sessions = B.read_manifest(sys.argv[1])
B.prepare_outdir(sessions, sys.argv[1], sys.argv[2])
s = sessions[0]
for st in s.stages:
    B.execute_stage(s, st, False)
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
"""


def _simulate(work: Path, n: int, duration_s: float) -> Path:
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation

    cfg = load_config(CONFIG)
    logs = work / "logs"
    rows = ["session,receiver_csv,gyro_csv,config,time,stages,smooth"]
    for i in range(1, n + 1):
        d = logs / f"s{i:02d}"
        if not (d / "receiver.csv").is_file():
            write_simulation(simulate(cfg, SimOptions(duration_s=duration_s, seed=i)), d)
        rows.append(f"s{i:02d},{d}/receiver.csv,{d}/gyro.csv,{CONFIG},2026-11-{i:02d},ingest init estimate spectra,true")
    m = logs / "manifest.csv"
    m.write_text("\n".join(rows) + "\n")
    (logs / "one.csv").write_text("\n".join(rows[:2]) + "\n")
    return m


def _fresh(path: Path) -> Path:
    if path.exists():
        shutil.rmtree(path)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sessions", type=int, default=16)
    ap.add_argument("--duration", type=float, default=600.0, help="seconds per session")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--workdir", default="/tmp/cdgps-batch-scale")
    ap.add_argument("--json", default=str(ROOT / "docs" / "batch-scale.json"))
    a = ap.parse_args()
    for k, v in {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}.items():
        os.environ.setdefault(k, v)              # the serial loop under the same BLAS rule as the workers
    work = Path(a.workdir)
    load0 = os.getloadavg()
    t = time.perf_counter()
    manifest = _simulate(work, a.sessions, a.duration)
    sim_s = time.perf_counter() - t

    # one session alone in a fresh process: its peak memory
    out1 = _fresh(work / "one")
    r = subprocess.run([sys.executable, "-c", ONE_SESSION, str(manifest.with_name("one.csv")), str(out1)],
                       capture_output=True, text=True, check=True)
    one_peak_mb = float(r.stdout.strip().splitlines()[-1])

    from cdgps_cli.pipeline import batch as B
    from cdgps_cli.pipeline.batch_dask import local_cluster, run_batch

    # serial loop
    sessions = B.read_manifest(manifest)
    B.prepare_outdir(sessions, manifest, _fresh(work / "serial"))
    t = time.perf_counter()
    for s in sessions:
        for st in s.stages:
            B.execute_stage(s, st, False)
    serial_s = time.perf_counter() - t

    # batch on a LocalCluster (its start included)
    from distributed import Client

    t = time.perf_counter()
    cluster = local_cluster(a.workers)
    client = Client(cluster)
    summary = run_batch(manifest, _fresh(work / "batch"), client=client, retries=0)
    batch_s = time.perf_counter() - t
    peaks = client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    blas = client.run(lambda: {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")})
    client.close()
    cluster.close()
    task_s = sum(st["elapsed_s"] for e in summary["sessions"] for st in e["stages"].values())
    n_tasks = sum(len(e["stages"]) for e in summary["sessions"])
    res = {
        "sessions": a.sessions, "duration_s": a.duration, "stages": list(sessions[0].stages), "workers": a.workers,
        "cores": os.cpu_count(), "load_average_at_start": [round(x, 2) for x in load0],
        "load_average_at_end": [round(x, 2) for x in os.getloadavg()], "simulate_s": round(sim_s, 1),
        "serial_s": round(serial_s, 1), "batch_s": round(batch_s, 1), "speedup": round(serial_s / batch_s, 3),
        "serial_s_per_session": round(serial_s / a.sessions, 2), "tasks": n_tasks,
        "task_time_sum_s": round(task_s, 1),
        "overhead_s_per_task": round((batch_s * a.workers - task_s) / n_tasks, 3),
        "one_session_peak_rss_mb": round(one_peak_mb, 1),
        "worker_peak_rss_mb": {k: round(v, 1) for k, v in peaks.items()}, "worker_blas_env": blas,
        "batch_counts": summary["counts"],
        "input_bytes_per_session": sum(f.stat().st_size for f in (work / "logs" / "s01").iterdir()),
        "output_bytes_per_session": sum(f.stat().st_size for f in (work / "batch" / "s01").rglob("*") if f.is_file()),
    }
    Path(a.json).write_text(json.dumps(res, indent=2) + "\n")
    print(f"{a.sessions} sessions × {a.duration:g} s ({' → '.join(res['stages'])}), {os.cpu_count()} cores, "
          f"load {load0[0]:.1f} at start")
    print(f"  serial loop      {serial_s:8.1f} s  ({res['serial_s_per_session']:.1f} s per session)")
    print(f"  batch, {a.workers} workers {batch_s:8.1f} s  (speed-up {res['speedup']:.2f}×, cluster start included)")
    print(f"  overhead per task {res['overhead_s_per_task']:.3f} s (worker-seconds not spent in the stage functions)")
    print(f"  peak RSS: one session alone {one_peak_mb:.0f} MB; workers "
          + ", ".join(f"{v:.0f} MB" for v in peaks.values()))
    print(f"  → {a.json}")


if __name__ == "__main__":
    main()
