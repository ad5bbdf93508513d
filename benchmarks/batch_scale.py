#!/usr/bin/env python3
"""`cdgps batch` scale (issue 17 item 5): N simulated sessions, a LocalCluster of 2 workers against the
serial loop, in the same run, with CPU time, memory and load average beside every wall time.

1. simulates N sessions (testbed config, seeds 1…N, cached in ``--workdir``) and writes a manifest
   (stages ingest → init → estimate --smooth → spectra);
2. **serial, pinned**: a fresh process runs the same stage functions one session after another
   (:func:`cdgps_cli.pipeline.batch.execute_stage`, no dask) with BLAS/OpenMP at one thread, as in a
   worker;
3. **serial, default threads**: the same without the thread variables (OpenBLAS then uses every core
   for the few calls that are large enough);
4. **batch**: :func:`cdgps_cli.pipeline.batch_dask.run_batch` on a LocalCluster of ``--workers`` processes
   (one thread each, BLAS at one thread); wall time including the cluster's start; every worker's
   resident memory sampled every 0.25 s (psutil) and each task's own peak (``peak_rss_mb``);
5. repeated ``--repeat`` times in the order pinned, batch, default; the load average before and after
   every run (the machine may be shared: ``uptime``).

Memory "bounded by one session": a worker's peak must not grow with the sessions it has processed.  Two
figures: ``flat`` — the peak of a worker's tasks in its last session is within 5 % of that in its second
(the first carries the lazy imports); and the stricter
``worker_peak ≤ worker_idle + one_session_increment`` where ``one_session_increment`` is the peak of a
fresh process running one session minus that process's resident memory before the session (its lazy
imports included), and ``worker_idle`` the worker's resident memory after its start.

Prints a table and writes ``--json`` (default docs/benchmarks/batch-scale.json)::

    python benchmarks/batch_scale.py                              # 16 × 10 min, ≈ 5 min on 2 idle cores
    python benchmarks/batch_scale.py --sessions 4 --minutes 2 --json /tmp/b.json      # quick
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
               "NUMEXPR_NUM_THREADS")

#: the serial loop, in a fresh process: per session-stage wall / CPU / peak; JSON on stdout
SERIAL = r"""
import json, resource, sys, time
from cdgps_cli.pipeline import batch as B
sessions = B.read_manifest(sys.argv[1])
B.prepare_outdir(sessions, sys.argv[1], sys.argv[2])
base = B._proc_status_mb("VmRSS")
r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
rows = []
for s in sessions:
    done = {st: B.execute_stage(s, st, False) for st in s.stages}
    rows.append({"session": s.name, "stages": {st: {k: r[k] for k in ("elapsed_s", "cpu_s", "peak_rss_mb", "rss_mb")}
                                               for st, r in done.items()}})
r1 = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"wall_s": time.perf_counter() - t0, "cpu_s": r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime,
                  "rss_before_mb": base, "sessions": rows}))
"""


def _simulate(work: Path, n: int, duration_s: float) -> Path:
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation

    cfg = load_config(CONFIG)
    logs = work / f"logs-{duration_s:g}s"
    rows = ["session,receiver_csv,gyro_csv,config,time,stages,smooth"]
    for i in range(1, n + 1):
        d = logs / f"s{i:02d}"
        if not (d / "receiver.csv").is_file():
            write_simulation(simulate(cfg, SimOptions(duration_s=duration_s, seed=i)), d)
        rows.append(f"s{i:02d},{d}/receiver.csv,{d}/gyro.csv,{CONFIG},2026-11-{(i - 1) % 28 + 1:02d}T{(i - 1) // 28:02d}:00:00Z,"
                    "ingest init estimate spectra,true")
    m = logs / f"manifest-{n}.csv"
    m.write_text("\n".join(rows) + "\n")
    return m


def _fresh(path: Path) -> Path:
    if path.exists():
        shutil.rmtree(path)
    return path


def _load() -> list:
    return [round(x, 2) for x in os.getloadavg()]


def _serial(manifest: Path, out: Path, pinned: bool) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS and k != "MALLOC_TRIM_THRESHOLD_"}
    if pinned:
        from cdgps_cli.pipeline.batch import BLAS_ENV

        env.update(BLAS_ENV)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    load0, t = _load(), time.perf_counter()
    r = subprocess.run([sys.executable, "-c", SERIAL, str(manifest), str(_fresh(out))], env=env,
                       capture_output=True, text=True)
    if r.returncode:
        sys.exit(f"serial loop failed:\n{r.stderr}")
    res = json.loads(r.stdout.strip().splitlines()[-1])
    res.update(process_wall_s=time.perf_counter() - t, load_average_before=load0, load_average_after=_load())
    for e in res["sessions"]:
        st = e["stages"].values()
        e.update(wall_s=sum(x["elapsed_s"] for x in st), cpu_s=sum(x["cpu_s"] for x in st),
                 peak_rss_mb=max(x["peak_rss_mb"] or 0.0 for x in st))
    return res


class _Sampler(threading.Thread):
    """Resident memory of each worker process every ``dt_s`` seconds: {address: [(t_s, rss_mb), …]}."""

    def __init__(self, pids: dict, dt_s: float = 0.25):
        import psutil

        super().__init__(daemon=True)
        self.procs = {a: psutil.Process(p) for a, p in pids.items()}
        self.dt_s, self.t0, self.trace, self.stop = dt_s, time.perf_counter(), {a: [] for a in pids}, threading.Event()

    def run(self):
        while not self.stop.is_set():
            for a, p in self.procs.items():
                try:
                    self.trace[a].append((round(time.perf_counter() - self.t0, 2), round(p.memory_info().rss / 2**20, 1)))
                except Exception:        # a worker restarting: skip the sample
                    pass
            self.stop.wait(self.dt_s)


def _per_second(trace: list) -> list:
    """[(t_s, rss_mb), …] → the largest sample of each whole second, [mb, …]."""
    out = []
    for t_s, mb in trace:
        i = int(t_s)
        out.extend([0.0] * (i + 1 - len(out)))
        out[i] = max(out[i], mb)
    return out


def _batch(manifest: Path, out: Path, workers: int) -> dict:
    from distributed import Client

    from cdgps_cli.pipeline import batch as B
    from cdgps_cli.pipeline.batch_dask import local_cluster, run_batch

    load0, t = _load(), time.perf_counter()
    cluster = local_cluster(workers)
    client = Client(cluster)
    start_s = time.perf_counter() - t
    pids = client.run(os.getpid)
    idle = client.run(B._proc_status_mb, "VmRSS")
    env = client.run(lambda: {k: os.environ.get(k) for k in (*THREAD_VARS, "MALLOC_TRIM_THRESHOLD_")})
    sampler = _Sampler(pids)
    sampler.start()
    summary = run_batch(manifest, _fresh(out), client=client, retries=0)
    wall_s = time.perf_counter() - t
    sampler.stop.set()
    sampler.join()
    import psutil

    cpu = {a: sum(psutil.Process(p).cpu_times()[:2]) for a, p in pids.items()}
    client.close()
    cluster.close()
    by_pid = {f"{p}": a for a, p in pids.items()}
    per_worker = {a: {"pid": pids[a], "idle_rss_mb": idle[a], "process_cpu_s": round(cpu[a], 1), "env": env[a],
                      "sessions": [], "rss_trace_1s_max_mb": _per_second(sampler.trace[a])} for a in pids}
    tasks = []
    for e in summary["sessions"]:
        for st, r in e["stages"].items():
            tasks.append({"session": e["session"], "stage": st, "started": r["started"], **r})
    for r in sorted(tasks, key=lambda r: r["started"] or ""):
        w = per_worker.get(by_pid.get((r.get("worker") or ":").rsplit(":", 1)[1]))
        if w is not None:
            w["sessions"].append({k: r.get(k) for k in ("session", "stage", "elapsed_s", "cpu_s", "peak_rss_mb", "rss_mb")})
    for w in per_worker.values():
        w["peak_rss_mb"] = max([p or 0.0 for p in (x["peak_rss_mb"] for x in w["sessions"])] +
                               w["rss_trace_1s_max_mb"], default=None)
    return {"wall_s": wall_s, "cluster_start_s": round(start_s, 2), "load_average_before": load0,
            "load_average_after": _load(), "counts": summary["counts"], "tasks": len(tasks),
            "task_wall_sum_s": round(sum(r["elapsed_s"] for r in tasks), 2),
            "task_cpu_sum_s": round(sum(r["cpu_s"] or 0.0 for r in tasks), 2), "workers": per_worker}


def _session_mean(runs: list, key: str, skip_first: bool) -> float:
    xs = [e[key] for r in runs for e in r["sessions"][1 if skip_first else 0:]]
    return round(sum(xs) / len(xs), 3) if xs else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sessions", type=int, default=16)
    ap.add_argument("--minutes", type=float, default=10.0, help="minutes of record per session")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1, help="how many times the three runs are repeated")
    ap.add_argument("--no-default-threads", action="store_true", help="skip the serial loop at default threads")
    ap.add_argument("--workdir", default="/tmp/cdgps-batch-scale")
    ap.add_argument("--json", default=str(ROOT / "docs" / "benchmarks" / "batch-scale.json"))
    a = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    work = Path(a.workdir)
    load0, started = _load(), datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    t = time.perf_counter()
    manifest = _simulate(work, a.sessions, 60.0 * a.minutes)
    sim_s = time.perf_counter() - t
    runs = {"serial_pinned": [], "batch": [], "serial_default_threads": []}
    for i in range(a.repeat):
        runs["serial_pinned"].append(_serial(manifest, work / "serial", pinned=True))
        runs["batch"].append(_batch(manifest, work / "batch", a.workers))
        if not a.no_default_threads:
            runs["serial_default_threads"].append(_serial(manifest, work / "serial", pinned=False))
        print(f"repeat {i + 1}: serial pinned {runs['serial_pinned'][-1]['wall_s']:.1f} s, batch "
              f"{runs['batch'][-1]['wall_s']:.1f} s, load {_load()}", file=sys.stderr)
    sp, bt, sd = runs["serial_pinned"], runs["batch"], runs["serial_default_threads"]
    one = sp[0]["sessions"][0]
    one_increment = one["peak_rss_mb"] - sp[0]["rss_before_mb"]
    bound, n_st = {}, 4
    for r in bt:
        for addr, w in r["workers"].items():
            limit = w["idle_rss_mb"] + one_increment
            peaks = [x["peak_rss_mb"] or 0.0 for x in w["sessions"]]
            second, last = max(peaks[n_st:2 * n_st] or [0.0]), max(peaks[-n_st:] or [0.0])
            bound[f"{addr}#{len(bound)}"] = {"idle_rss_mb": w["idle_rss_mb"], "limit_mb": round(limit, 1),
                                             "peak_rss_mb": w["peak_rss_mb"], "bounded": w["peak_rss_mb"] <= limit,
                                             "task_peak_first_session_mb": max(peaks[:n_st] or [0.0]),
                                             "task_peak_second_session_mb": second,
                                             "task_peak_last_session_mb": last,
                                             "growth_second_to_last_mb": round(last - second, 1),
                                             "flat": last <= 1.05 * second}
    best = {k: min(x["wall_s"] for x in v) for k, v in runs.items() if v}
    res = {
        "started": started, "sessions": a.sessions, "duration_s": 60.0 * a.minutes, "workers": a.workers,
        "cores": os.cpu_count(), "stages": ["ingest", "init", "estimate", "spectra"], "repeat": a.repeat,
        "load_average_at_start": load0, "load_average_at_end": _load(), "simulate_s": round(sim_s, 1),
        "wall_s": {k: [round(x["wall_s"], 1) for x in v] for k, v in runs.items() if v},
        "cpu_s": {"serial_pinned": [round(x["cpu_s"], 1) for x in sp],
                  "serial_default_threads": [round(x["cpu_s"], 1) for x in sd],
                  "batch_tasks": [x["task_cpu_sum_s"] for x in bt],
                  "batch_worker_processes": [round(sum(w["process_cpu_s"] for w in x["workers"].values()), 1) for x in bt]},
        "speedup": {"vs_serial_pinned": [round(s["wall_s"] / b["wall_s"], 3) for s, b in zip(sp, bt)],
                    "vs_serial_default_threads": [round(s["wall_s"] / b["wall_s"], 3) for s, b in zip(sd, bt)],
                    "best_of_each": {k: round(best[k] / best["batch"], 3) for k in best if k != "batch"}},
        "per_session_s": {"serial_pinned_wall": _session_mean(sp, "wall_s", True),
                          "serial_pinned_cpu": _session_mean(sp, "cpu_s", True),
                          "serial_pinned_first_session_wall": round(one["wall_s"], 2),
                          "serial_default_threads_wall": _session_mean(sd, "wall_s", True) if sd else None,
                          "serial_default_threads_cpu": _session_mean(sd, "cpu_s", True) if sd else None,
                          "batch_task_wall": round(sum(x["task_wall_sum_s"] for x in bt) / (len(bt) * a.sessions), 3),
                          "batch_task_cpu": round(sum(x["task_cpu_sum_s"] for x in bt) / (len(bt) * a.sessions), 3)},
        "cluster_start_s": [x["cluster_start_s"] for x in bt],
        "tasks": bt[0]["tasks"],
        "overhead_s_per_task": [round((x["wall_s"] * a.workers - x["task_wall_sum_s"]) / x["tasks"], 3) for x in bt],
        "memory": {"one_session_alone_peak_rss_mb": one["peak_rss_mb"],
                   "one_session_alone_rss_before_mb": sp[0]["rss_before_mb"],
                   "one_session_increment_mb": round(one_increment, 1),
                   "serial_pinned_peak_per_session_mb": [e["peak_rss_mb"] for e in sp[0]["sessions"]],
                   "workers": bound},
        "load_average": {k: [[x["load_average_before"], x["load_average_after"]] for x in v] for k, v in runs.items() if v},
        "batch_counts": [x["counts"] for x in bt],
        "batch_runs": bt,
        "input_bytes_per_session": sum(f.stat().st_size for f in (manifest.parent / "s01").iterdir()),
        "output_bytes_per_session": sum(f.stat().st_size for f in (work / "batch" / "s01").rglob("*")
                                        if f.is_file() and ".batch" not in f.parts),
    }
    Path(a.json).write_text(json.dumps(res, indent=1) + "\n")
    print(f"{a.sessions} sessions × {a.minutes:g} min ({' → '.join(res['stages'])}), {os.cpu_count()} cores, "
          f"{a.workers} workers, load {load0} at start, {res['load_average_at_end']} at end")
    for k, v in res["wall_s"].items():
        print(f"  {k:24s} wall {v} s   load before/after {res['load_average'][k]}")
    print(f"  CPU s: {res['cpu_s']}")
    print(f"  speed-up: {res['speedup']}")
    print(f"  per session: {res['per_session_s']}")
    print(f"  overhead per task {res['overhead_s_per_task']} s; cluster start {res['cluster_start_s']} s")
    print(f"  memory: one session alone {one['peak_rss_mb']} MB peak ({one_increment:.0f} MB over its start); "
          + "; ".join(f"{k} idle {w['idle_rss_mb']} peak {w['peak_rss_mb']} ≤ {w['limit_mb']}: {w['bounded']}, "
                      f"task peak 2nd session {w['task_peak_second_session_mb']} → last "
                      f"{w['task_peak_last_session_mb']} (flat within 5 %: {w['flat']})" for k, w in bound.items()))
    print(f"  → {a.json}")


if __name__ == "__main__":
    main()
