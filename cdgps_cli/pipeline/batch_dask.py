"""`cdgps batch` on dask.distributed: one task per session-stage, retries, survived worker deaths.

:func:`run_batch` is the entry point (the CLI is a thin shell over it).  It takes an existing
``distributed.Client`` (tests, notebooks), a scheduler address ``tcp://HOST:PORT`` or a scheduler
file (a real cluster: ``dask scheduler --scheduler-file F`` and ``dask worker --scheduler-file F``),
or starts a LocalCluster: one worker process per core, one thread each, BLAS pinned to one thread,
dashboard off unless asked.

Dask gives: dependencies between tasks (a stage waits for the one it reads), ``retries=K`` for a
task that raises, and rescheduling of the tasks of a worker that died on another worker (up to
``distributed.scheduler.allowed-failures`` deaths, then the task fails with KilledWorker, reported).
"""

from __future__ import annotations

import json
import logging
import os
import time
import uuid
from datetime import datetime, timezone
from pathlib import Path

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.pipeline import batch as B


#: dask's worker default ``MALLOC_TRIM_THRESHOLD_=65536`` (``distributed.nanny.pre-spawn-environ``) fixes
#: glibc's mmap threshold at 128 kB: every array above it is then a fresh mmap, page-faulted anew at each
#: allocation, and the stages ran ≈ 1.4× slower in a worker than in a plain process (docs/batch.md).  The
#: batch drops that default (glibc's own adaptive thresholds, as in the serial loop) and returns a
#: stage's freed memory itself once the stage is done (:func:`cdgps_cli.pipeline.batch.release_memory`).
#: A value the user set in the environment is kept.
TRIM_KEY = "MALLOC_TRIM_THRESHOLD_"


#: dask's statistical profiler in each worker (a stack sample every 10 ms, kept for the dashboard's
#: profile page) made a worker's resident memory grow without bound, ≈ 2.6 MB per session of 3 min
#: (243 → 395 MB over 60 sessions on one worker; with it off: flat at 220 MB, docs/batch.md).  It is off
#: unless the dashboard is asked for.
PROFILE_KEY = "distributed.worker.profile.enabled"


def local_cluster(workers: int | None = None, dashboard: bool = False, env: dict | None = None):
    """A LocalCluster of ``workers`` processes (default: the cores), one thread each, BLAS at one thread,
    without dask's fixed malloc trim threshold (see :data:`TRIM_KEY`), without the workers' statistical
    profiler unless ``dashboard`` (see :data:`PROFILE_KEY`); ``env`` adds variables to the workers'
    environment (tests)."""
    import dask
    from distributed import LocalCluster

    n = workers or os.cpu_count() or 1
    with dask.config.set({f"distributed.nanny.pre-spawn-environ.{TRIM_KEY}": os.environ.get(TRIM_KEY),
                          PROFILE_KEY: bool(dashboard)}):
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, silence_logs=logging.ERROR,
                            dashboard_address=":8787" if dashboard else None, env={**B.BLAS_ENV, **(env or {})})


def connect(scheduler: str | None = None, workers: int | None = None, dashboard: bool = False):
    """(client, cluster or None): to ``scheduler`` (address or scheduler file), else a new LocalCluster."""
    from distributed import Client

    try:
        if scheduler is None:
            cluster = local_cluster(workers, dashboard)
            return Client(cluster), cluster
        if os.path.isfile(scheduler):
            return Client(scheduler_file=scheduler, timeout="20s"), None
        return Client(scheduler, timeout="20s"), None
    except (OSError, TimeoutError) as exc:
        raise CdgpsError(f"--scheduler {scheduler}: cannot reach the dask scheduler: {exc}") from None


def _error_text(fut) -> str:
    exc = fut.exception()
    if isinstance(exc, CdgpsError):
        return str(exc)
    name = type(exc).__name__
    if name == "KilledWorker":
        return (f"the worker running it died too often ({exc}); the session was given up "
                f"(distributed.scheduler.allowed-failures)")
    return f"{name}: {exc}"


def run_batch(manifest: str | Path, outdir: str | Path, *, client=None, scheduler: str | None = None,
              workers: int | None = None, resume: bool = False, retries: int = 2, dashboard: bool = False,
              progress=None) -> dict:
    """Run every session-stage of a manifest; write OUTDIR/batch.json and OUTDIR/index.html.

    Parameters
    ----------
    manifest : path of the CSV or TOML manifest (:mod:`cdgps_cli.pipeline.batch`)
    outdir : the campaign folder (one sub-folder per session)
    client : an existing ``distributed.Client`` (then ``scheduler`` and ``workers`` are not used)
    scheduler : ``tcp://HOST:PORT`` or a scheduler file; default a LocalCluster of ``workers``
    resume : skip the stages whose record still holds (same inputs, options and outputs)
    retries : how many times a task that raises is tried again
    progress : callable(str) or None, told of sessions done / failed / running

    Returns
    -------
    dict, the content of batch.json (``sessions``, ``trends``, ``failures``, ``counts`` …)

    Raises
    ------
    CdgpsError
        On a bad manifest (every problem listed), an OUTDIR of another campaign, an unreachable scheduler.
    """
    if retries < 0:
        raise CdgpsError(f"--retries must be ≥ 0, got {retries}")
    if workers is not None and workers < 1:
        raise CdgpsError(f"--workers must be ≥ 1, got {workers}")
    sessions = B.read_manifest(manifest)
    B.prepare_outdir(sessions, manifest, outdir, claim=False)       # refused before any cluster starts
    cluster, own = None, client is None
    if own:
        client, cluster = connect(scheduler, workers, dashboard)
    try:
        out = B.prepare_outdir(sessions, manifest, outdir)           # nothing written if it cannot connect
    except BaseException:
        if own:
            client.close()
        if cluster is not None:
            cluster.close()
        raise
    t0 = time.perf_counter()
    started = _now()
    try:
        n_workers = len(client.scheduler_info(n_workers=-1)["workers"]) if _has_n_workers(client) else \
            len(client.scheduler_info()["workers"])
        results, errors = _submit_and_wait(client, sessions, resume, retries, progress)
    finally:
        if own:
            client.close()
        if cluster is not None:
            cluster.close()
    entries = [B.session_summary(s, results.get(s.name, {}), errors.get(s.name, {})) for s in sessions]
    summary = {"manifest": str(Path(manifest).resolve()), "outdir": str(out), "started": started, "finished": _now(),
               "elapsed_s": round(time.perf_counter() - t0, 3), "workers": n_workers, "retries": retries,
               "resume": resume, "counts": _counts(entries), "sessions": entries,
               "trends": B.mode_trends([e for e in entries if "modes" in e]),
               "failures": [{"session": e["session"], "error": e["error"]} for e in entries if "error" in e]}
    from cdgps_cli.io.atomic import write_bytes_atomic
    from cdgps_cli.report.batch_index import write_index

    write_index(summary, out)
    write_bytes_atomic(out / "batch.json", (json.dumps(summary, indent=2) + "\n").encode())
    return summary


def _has_n_workers(client) -> bool:
    import inspect

    return "n_workers" in inspect.signature(client.scheduler_info).parameters


def _worker_threads(client) -> int:
    """Threads of the cluster's workers now (at least 1): how many sessions :func:`_submit_and_wait` keeps
    in flight."""
    try:
        info = client.scheduler_info(n_workers=-1) if _has_n_workers(client) else client.scheduler_info()
        return max(1, sum(w.get("nthreads", 1) for w in info["workers"].values()))
    except Exception:              # a scheduler that does not answer now: one session at a time
        return 1


def _submit_session(client, s, resume, retries, token, owner) -> list:
    """Submit every stage of session ``s`` (each depending on the stages it needs); its futures."""
    mine = {}
    for st in s.stages:
        deps = [mine[d] for d in B.DEPENDS[st] if d in mine]
        f = client.submit(B.execute_stage, s, st, resume, *deps, key=f"cdgps-batch-{s.name}-{st}-{token}",
                          retries=retries, pure=False)
        mine[st] = f
        owner[f.key] = (s.name, st)
    return list(mine.values())


def _submit_and_wait(client, sessions, resume, retries, progress):
    """Run every session-stage; collect {session: {stage: result}} and {session: {stage: error}}.

    Sessions are submitted in manifest order and only as many are in flight as the workers have threads
    (asked again each time one ends, so workers that join are used): a worker then runs one session's
    stages one after the other and the campaign's tail is at most one session on each worker.  With every
    session submitted at once, dask ran them breadth first and left two sessions' chains on one worker at
    the end while the other sat idle (16 × 10 min on 2 workers: one worker idle the last 4 s of 57 s,
    docs/batch.md).
    """
    from distributed import as_completed

    token = uuid.uuid4().hex[:8]
    owner, queue = {}, list(sessions)
    results, errors = {}, {}
    left = {s.name: len(s.stages) for s in sessions}
    failed, started, said = set(), set(), None
    pending = as_completed()
    in_flight = 0
    while queue or in_flight:
        while queue and in_flight < _worker_threads(client):
            for f in _submit_session(client, queue.pop(0), resume, retries, token, owner):
                pending.add(f)
            in_flight += 1
        f = next(pending)
        name, st = owner[f.key]
        left[name] -= 1
        started.add(name)
        if f.status == "finished":
            results.setdefault(name, {})[st] = f.result()
        else:
            errors.setdefault(name, {})[st] = _error_text(f)
            failed.add(name)
        if left[name] == 0:
            in_flight -= 1
        if progress is not None:
            done = {n for n, k in left.items() if k == 0} - failed
            running = (started | _processing(client, owner)) - done - failed
            line = (f"batch: {len(done)} of {len(sessions)} sessions done, {len(failed)} failed, "
                    f"{len(running)} running")
            if line != said:
                progress(line)
                said = line
    return results, errors


def _processing(client, owner) -> set:
    """Sessions with a stage being processed by a worker right now."""
    try:
        keys = {k for ks in client.processing().values() for k in ks}
    except Exception:              # progress only: never fail the batch over it
        return set()
    return {owner[k][0] for k in keys if k in owner}


def _counts(entries) -> dict:
    c = {"sessions": len(entries)}
    for e in entries:
        c[e["status"]] = c.get(e["status"], 0) + 1
    return c


def _now() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
