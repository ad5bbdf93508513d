"""`cdgps batch` on dask.distributed: one task per session-stage, retries, survived worker deaths.

:func:`run_batch` is the entry point (the CLI is a thin shell over it).  It takes an existing
``distributed.Client`` (tests, notebooks), a scheduler address ``tcp://HOST:PORT`` or a scheduler
file (a real cluster: ``dask scheduler --scheduler-file F`` and ``dask worker --scheduler-file F``),
or starts a LocalCluster: one worker process per core, one thread each, BLAS pinned to one thread,
dashboard off unless asked.

It also starts a cluster manager named by ``MODULE.CLASS`` (``--cluster dask_jobqueue.SLURMCluster``)
with keyword options, and registers :class:`WorkerSettings` on whatever cluster it uses.

Dask gives: dependencies between tasks (a stage waits for the one it reads), ``retries=K`` for a
task that raises a worker fault (input errors are returned, not raised: :func:`run_task`), and
rescheduling of the tasks of a worker that died on another worker (up to
``distributed.scheduler.allowed-failures`` deaths, then the task fails with KilledWorker, reported).
"""

from __future__ import annotations

import json
import logging
import os
import time
import uuid
from datetime import date, datetime, timezone
from datetime import time as dtime
from pathlib import Path

from cdgps_cli.core import heap
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


#: exit status of `cdgps batch` when the batch ran to its end but some session failed (batch.json and
#: index.html written, each failure listed); 2 is a bad manifest, option or OUTDIR (nothing run)
EXIT_SESSIONS_FAILED = 3
#: exit status when the batch itself failed (the scheduler lost, an unexpected error of the batch layer):
#: no batch.json of this run; the traceback in OUTDIR/batch-error.log; the finished stages are recorded
EXIT_BATCH_FAILED = 4

#: glibc mallopt parameters, and the values :class:`WorkerSettings` gives a worker started with a fixed
#: trim threshold: the mmap threshold at glibc's own dynamic maximum (32 MiB on 64-bit), the trim
#: threshold at twice that (what glibc's adaptive rule reaches), so that arrays are heap memory again
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = heap.M_TRIM_THRESHOLD, heap.M_MMAP_THRESHOLD
MMAP_THRESHOLD_B = 32 * 1024 * 1024

try:
    from distributed import WorkerPlugin as _WorkerPluginBase
except ImportError:               # pragma: no cover  (distributed is a dependency)
    _WorkerPluginBase = object


class WorkerSettings(_WorkerPluginBase):
    """The worker settings that keep a batch worker's memory flat and its speed that of a plain
    process, applied by the batch to every worker of any cluster it uses (a dask WorkerPlugin:
    workers that join later get them too).

    On each worker :meth:`setup`

    * stops dask's statistical profiler, the worker's periodic callbacks that :data:`PROFILE_KEY`
      starts (its samples grew a worker's memory ≈ 2.6 MB per session without bound), unless
      ``profile`` (the dashboard was asked for);
    * when the worker was started with a fixed ``MALLOC_TRIM_THRESHOLD_`` (dask's nanny default,
      65536) that the batch's own environment does not ask for, sets glibc's mmap and trim thresholds
      back to large values (:data:`MMAP_THRESHOLD_B`; the variable itself is read only at process start);
    * sets the BLAS / OpenMP thread variables (:data:`cdgps_cli.pipeline.batch.BLAS_ENV`) where the
      worker has none (a BLAS already loaded keeps its pool: start workers with them, or with a nanny);
    * on a cluster the batch started itself (``ignore_sigint``), makes the worker process ignore Ctrl-C: the batch
      stops its workers, whose own KeyboardInterrupt printed their tasks' tracebacks (a user's cluster keeps its
      handling);

    and records what it did in ``worker.cdgps_settings``.  In a worker thread of the batch's own process
    (an in-process cluster) only the profiler is stopped: the process's environment and allocator are
    the user's.  Each stage's memory is also returned to the system after the stage (:func:`cdgps_cli.pipeline.batch.release_memory`, in the task itself).
    """

    name = "cdgps-batch-worker-settings"
    idempotent = False

    def __init__(self, profile: bool = False, trim_threshold: str | None = None, ignore_sigint: bool = False):
        import socket

        self.ignore_sigint = bool(ignore_sigint)      # only on a cluster the batch started (a user's keeps its own)
        self.profile = bool(profile)
        self.trim_threshold = trim_threshold          # the batch process's MALLOC_TRIM_THRESHOLD_, if any
        self.origin = (socket.gethostname(), os.getpid())

    def setup(self, worker) -> None:
        import socket

        done = {"profile": self.profile}
        if not self.profile:                          # the worker reads the config only when it starts
            for k in ("profile", "profile-cycle"):
                pc = worker.periodic_callbacks.pop(k, None)
                if pc is not None:
                    pc.stop()
            for k in ("profile_history", "profile_keys_history"):
                getattr(worker, k, []).clear()
        if (socket.gethostname(), os.getpid()) == self.origin:
            done["malloc"] = done["blas_env"] = "the batch's own process (threads): left as it is"
        else:
            done["malloc"] = _malloc_thresholds(os.environ.get(TRIM_KEY), self.trim_threshold)
            done["blas_env"] = {k: os.environ.setdefault(k, v) for k, v in B.BLAS_ENV.items()}
            done["sigint"] = (_ignore_sigint() if self.ignore_sigint else
                              "kept (a cluster the batch did not start: its own handling)")
        worker.cdgps_settings = done


def _ignore_sigint() -> str:
    """A worker process of its own ignores Ctrl-C: the batch process stops it (its nanny), while each worker's own
    KeyboardInterrupt printed a traceback of the task it was cancelled in (a sweep: 70 lines for one Ctrl-C)."""
    import signal

    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:                          # (not the process's main thread: left as it is)
        return "kept (not the worker process's main thread)"
    return "ignored (the batch process stops the worker)"


def _malloc_thresholds(worker_value: str | None, wanted: str | None) -> str:
    """Undo a fixed trim threshold in this process when the batch does not ask for one; what was done."""
    if worker_value is None:
        return "glibc defaults (no MALLOC_TRIM_THRESHOLD_)"
    if wanted is not None:
        return f"kept MALLOC_TRIM_THRESHOLD_={worker_value} (set in the batch's environment)"
    if not heap.available():
        return f"MALLOC_TRIM_THRESHOLD_={worker_value} kept (no glibc mallopt)"
    ok = heap.set_option(M_MMAP_THRESHOLD, MMAP_THRESHOLD_B) and heap.set_option(M_TRIM_THRESHOLD, 2 * MMAP_THRESHOLD_B)
    return (f"MALLOC_TRIM_THRESHOLD_={worker_value} overridden: mmap threshold {MMAP_THRESHOLD_B} B, trim threshold "
            f"{2 * MMAP_THRESHOLD_B} B" if ok else f"MALLOC_TRIM_THRESHOLD_={worker_value} kept (mallopt refused)")


def apply_worker_settings(client, dashboard: bool = False, own_cluster: bool = False) -> None:
    """Register :class:`WorkerSettings` on ``client``'s cluster (its workers now and later); ``own_cluster``: the
    batch started the cluster (its workers then leave Ctrl-C to it)."""
    client.register_plugin(WorkerSettings(profile=dashboard, trim_threshold=os.environ.get(TRIM_KEY),
                                          ignore_sigint=own_cluster))


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


def connect(scheduler: str | None = None, workers: int | None = None, dashboard: bool = False,
            cluster_class: str | None = None, cluster_options: dict | None = None):
    """(client, cluster or None): to ``scheduler`` (address or scheduler file), to a new cluster of the
    cluster manager ``cluster_class`` (:func:`start_cluster`), else a new LocalCluster."""
    from distributed import Client

    if cluster_class is not None:
        cluster = start_cluster(cluster_class, cluster_options or {}, workers)
        try:
            return Client(cluster), cluster
        except BaseException:
            cluster.close()
            raise
    try:
        if scheduler is None:
            cluster = local_cluster(workers, dashboard)
            return Client(cluster), cluster
        if os.path.isfile(scheduler):
            return Client(scheduler_file=scheduler, timeout="20s"), None
        return Client(scheduler, timeout="20s"), None
    except (OSError, TimeoutError) as exc:
        raise CdgpsError(f"--scheduler {scheduler}: cannot reach the dask scheduler: {exc}") from None


def cluster_manager_class(name: str):
    """The class ``MODULE.CLASS`` (e.g. ``dask_jobqueue.SLURMCluster``), imported by name.

    Raises
    ------
    CdgpsError
        When the module cannot be imported or has no such class.
    """
    import importlib

    mod, _, cls = name.rpartition(".")
    if not mod or not cls:
        raise CdgpsError(f"--cluster {name!r}: expected MODULE.CLASS, e.g. dask_jobqueue.SLURMCluster or "
                         f"distributed.LocalCluster")
    try:
        module = importlib.import_module(mod)
    except ImportError as exc:
        extra = " (pip install 'cdgps[cluster]' installs dask-jobqueue)" if mod.split(".")[0] == "dask_jobqueue" else ""
        raise CdgpsError(f"--cluster {name}: cannot import {mod}: {exc}{extra}") from None
    c = getattr(module, cls, None)
    if not isinstance(c, type):
        raise CdgpsError(f"--cluster {name}: {mod} has no class {cls}")
    return c


def start_cluster(name: str, options: dict, workers: int | None):
    """Start the cluster manager ``name`` with keyword ``options`` and ask it for workers.

    ``workers`` given: ``cluster.scale(workers)``; else the manager's own options decide (e.g.
    ``n_workers``), and a manager that has no worker then is asked for one.

    Raises
    ------
    CdgpsError
        When the class cannot be imported, refuses the options, or cannot start.
    """
    cls = cluster_manager_class(name)
    if not (callable(getattr(cls, "scale", None)) and callable(getattr(cls, "close", None))):
        raise CdgpsError(f"--cluster {name}: not a dask cluster manager (no scale/close methods); expected e.g. "
                         f"dask_jobqueue.SLURMCluster or distributed.LocalCluster")
    _check_submit_command(cls, name)
    cluster = _instantiate(cls, name, options)
    try:
        have = len(getattr(cluster, "worker_spec", None) or getattr(cluster, "workers", None) or {})
        if workers is not None or have == 0:
            cluster.scale(workers or 1)
    except BaseException:
        cluster.close()
        raise
    return cluster


def _check_submit_command(cls, name: str) -> None:
    """A job-queue cluster manager whose submit command (``sbatch``, ``qsub`` …) is not on PATH would
    fail to submit every job in the background while the batch waits for workers: refused up front."""
    import shutil

    cmd = getattr(getattr(cls, "job_cls", None), "submit_command", None)
    if isinstance(cmd, str) and cmd.split() and shutil.which(cmd.split()[0]) is None:
        raise CdgpsError(f"--cluster {name}: its job submit command {cmd.split()[0]!r} is not on this machine's PATH "
                         f"(run the batch where jobs can be submitted; --print-job-script shows the job script)")


def _instantiate(cls, name: str, options: dict):
    """``cls(**options)``; a refusal (unknown or bad keyword) or a failed start as a CdgpsError naming
    the class and the options."""
    shown = ", ".join(f"{k}={v!r}" for k, v in options.items()) or "no options"
    try:
        return cls(**options)
    except (TypeError, ValueError, KeyError) as exc:
        raise CdgpsError(f"--cluster {name}: refused the options ({shown}): {type(exc).__name__}: {exc}") from None
    except (OSError, RuntimeError, TimeoutError) as exc:
        raise CdgpsError(f"--cluster {name}: cannot start the cluster ({shown}): {type(exc).__name__}: {exc}") from None


def job_script(name: str, options: dict) -> str:
    """The job script a job-queue cluster manager (dask-jobqueue's SLURMCluster, PBSCluster …) would
    submit for one job of workers with these options; nothing is submitted.

    Raises
    ------
    CdgpsError
        As :func:`start_cluster`, and for a class that writes no job script.
    """
    cls = cluster_manager_class(name)
    if not callable(getattr(cls, "job_script", None)):
        raise CdgpsError(f"--cluster {name}: not a job-queue cluster manager (it writes no job script)")
    cluster = _instantiate(cls, name, options)
    try:
        return cluster.job_script()
    finally:
        cluster.close()


def parse_cluster_options(items) -> dict:
    """``KEY=VALUE`` texts to keyword options: VALUE read as a TOML value (``2``, ``true``, ``"x"``,
    ``["--time=01:00:00"]``, ``{dashboard_address=":0"}``), else kept as text (``4GiB``, ``normal``, and
    TOML dates and times: ``walltime=01:00:00``).

    Raises
    ------
    CdgpsError
        On an item without ``=`` or a key that is no Python name, or a key given twice.
    """
    import tomllib

    from cdgps_cli.core import toml_text

    out = {}
    for it in items:
        key, eq, text = it.partition("=")
        key = key.strip()
        if not eq or not key.isidentifier():
            raise CdgpsError(f"--cluster-option {it!r}: expected KEY=VALUE with KEY a keyword of the cluster class "
                             f"(e.g. queue=normal, cores=2, memory=4GiB)")
        if key in out:
            raise CdgpsError(f"--cluster-option {key}: given twice")
        try:
            v = toml_text.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            v = text.strip()
        out[key] = text.strip() if isinstance(v, (date, dtime)) else v     # walltime=01:00:00 stays text
    return out


def run_task(s, stage: str, resume: bool, *upstream) -> dict:
    """The task of one session-stage: :func:`cdgps_cli.pipeline.batch.execute_stage`, except that an
    input error (CdgpsError) is returned as a failed result, so that dask does not retry it (it would
    fail again the same way), and a stage whose upstream failed so is not run.  Worker faults (a
    RuntimeError, MemoryError, OSError, a killed worker) still raise: dask retries them."""
    if any(isinstance(u, dict) and u.get("status") in ("failed", "blocked") for u in upstream):
        return {"session": s.name, "stage": stage, "status": "blocked"}
    try:
        return B.execute_stage(s, stage, resume, *upstream)
    except CdgpsError as exc:
        return {"session": s.name, "stage": stage, "status": "failed", "error": str(exc)}


def _result_or_none(fut):
    """A completed future's result; None for an error or a cancelled future.  A future whose result
    was lost with a killed worker between completing and being read ('lost') is computed again by
    dask, and its result is waited for (it was reported as "NoneType: None" before)."""
    if fut.status == "error" or fut.cancelled():
        return None
    try:
        return fut.result()
    except Exception:                          # noqa: BLE001 - reported by _error_text
        return None


def _error_text(fut) -> str:
    if fut.cancelled():
        return "cancelled by the scheduler (its worker or the connection was lost)"
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
              cluster_class: str | None = None, cluster_options: dict | None = None, progress=None,
              warn=None) -> dict:
    """Run every session-stage of a manifest; write OUTDIR/batch.json and OUTDIR/index.html.

    Parameters
    ----------
    manifest : path of the CSV or TOML manifest (:mod:`cdgps_cli.pipeline.batch`)
    outdir : the campaign folder (one sub-folder per session)
    client : an existing ``distributed.Client`` (then ``scheduler`` and ``workers`` are not used)
    scheduler : ``tcp://HOST:PORT`` or a scheduler file; default a LocalCluster of ``workers``
    cluster_class, cluster_options : a cluster manager ``MODULE.CLASS`` and its keyword options
        (:func:`start_cluster`; ``workers`` is then what it is scaled to)
    resume : skip the stages whose record still holds (same inputs, options and outputs)
    retries : how many times a task that raises (a worker fault) is tried again; an input error
        (CdgpsError) is not retried
    progress : callable(str) or None, told of sessions done / failed / running
    warn : callable(str) or None, told of a stale OUTDIR lock taken over

    Returns
    -------
    dict, the content of batch.json (``sessions``, ``trends``, ``failures``, ``counts`` …)

    Raises
    ------
    CdgpsError
        On a bad manifest (every problem listed), an OUTDIR of another campaign or locked by another
        batch (:mod:`cdgps_cli.pipeline.batch_lock`), an unreachable scheduler, a cluster manager that
        cannot be imported or refuses its options.
    """
    from cdgps_cli.pipeline import batch_lock

    if retries < 0:
        raise CdgpsError(f"--retries must be ≥ 0, got {retries}")
    if workers is not None and workers < 1:
        raise CdgpsError(f"--workers must be ≥ 1, got {workers}")
    sessions = B.read_manifest(manifest)
    B.prepare_outdir(sessions, manifest, outdir, claim=False)       # refused before any cluster starts
    existed = Path(outdir).is_dir()
    lock = batch_lock.acquire(outdir, warn)
    try:
        return _run_locked(sessions, manifest, outdir, client, scheduler, workers, resume, retries, dashboard,
                           cluster_class, cluster_options, progress)
    finally:
        lock.release()
        if not existed:
            try:
                Path(outdir).rmdir()       # only if nothing was written (it could not connect)
            except OSError:
                pass


def _run_locked(sessions, manifest, outdir, client, scheduler, workers, resume, retries, dashboard,
                cluster_class, cluster_options, progress) -> dict:
    cluster, own = None, client is None
    if own:
        client, cluster = connect(scheduler, workers, dashboard, cluster_class, cluster_options)
    try:
        out = B.prepare_outdir(sessions, manifest, outdir)           # nothing written if it cannot connect
        apply_worker_settings(client, dashboard, own_cluster=cluster is not None)
        t0 = time.perf_counter()
        started = _now()
        n_workers = _n_workers(client)
        results, errors = _submit_and_wait(client, sessions, resume, retries, progress)
        n_workers = max(n_workers, _n_workers(client))         # a cluster manager's workers join as they start
    except BaseException:
        _close(client if own else None, cluster, quiet=True)
        raise
    _close(client if own else None, cluster)
    entries = [B.session_summary(s, results.get(s.name, {}), errors.get(s.name, {})) for s in sessions]
    summary = {"manifest": str(Path(manifest).resolve()), "outdir": str(out), "started": started, "finished": _now(),
               "elapsed_s": round(time.perf_counter() - t0, 3), "workers": n_workers, "retries": retries,
               "resume": resume, "counts": _counts(entries), "sessions": entries,
               "trends": B.mode_trends([e for e in entries if "modes" in e]),
               "position_trends": B.position_trends([e for e in entries if "rovers" in e]),
               "failures": [{"session": e["session"], "error": e["error"]} for e in entries if "error" in e]}
    summary = B.finite_json(summary)
    from cdgps_cli.io.atomic import write_bytes_atomic
    from cdgps_cli.report.batch_index import write_index

    write_bytes_atomic(out / "batch.json", (json.dumps(summary, indent=2, allow_nan=False) + "\n").encode())
    write_index(summary, out)
    return summary


def _close(client, cluster, quiet: bool = False) -> None:
    """Close what the batch opened; ``quiet``: while another exception is on its way, a failure to
    close (a cluster manager whose jobs never started cannot always be closed cleanly) does not hide it."""
    for thing in (client, cluster):
        if thing is None:
            continue
        try:
            thing.close()
        except Exception:
            if not quiet:
                raise


def _n_workers(client) -> int:
    info = client.scheduler_info(n_workers=-1) if _has_n_workers(client) else client.scheduler_info()
    return len(info["workers"])


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
        f = client.submit(run_task, s, st, resume, *deps, key=f"cdgps-batch-{s.name}-{st}-{token}",
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
        f = _next_done(pending, (lambda: in_flight < _worker_threads(client)) if queue else None)
        if f is None:                  # workers joined: submit more sessions first
            continue
        name, st = owner[f.key]
        left[name] -= 1
        started.add(name)
        r = _result_or_none(f)
        if r is None:
            errors.setdefault(name, {})[st] = _error_text(f)
            failed.add(name)
        elif r["status"] == "failed":         # an input error: not retried
            errors.setdefault(name, {})[st] = r["error"]
            failed.add(name)
        elif r["status"] != "blocked":        # blocked: its upstream failed (reported there)
            results.setdefault(name, {})[st] = r
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


def _next_done(pending, more_room=None, poll_s: float = 1.0):
    """The next finished future of ``pending``; with ``more_room`` (callable → bool, asked every
    ``poll_s`` while waiting), None as soon as it says the workers have room for more sessions (workers
    that joined: a cluster manager's jobs starting, hand-started workers)."""
    if more_room is None:
        return next(pending)
    asked = time.monotonic()
    while not pending.has_ready():
        time.sleep(0.02)
        if time.monotonic() - asked >= poll_s:
            if more_room():
                return None
            asked = time.monotonic()
    return next(pending)


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
