"""`cdgps batch` under faults (issue 32 item 4), fast: no stage computes anything here.

* the campaign trend fit never raises: degenerate series (σ ≈ 1e-15, constant values, one point, NaN,
  one time) give "not enough spread"; batch.json and index.html are written; --resume after it;
* an input error (CdgpsError) fails its session at once, without retry; worker faults (RuntimeError,
  OSError, MemoryError) are retried;
* the OUTDIR lock: a live holder refuses the second batch (exit 2, lock file, pid and host named), a
  dead one on this host is taken over with a warning;
* exit status 0 / 3 (some session failed) / 4 (the batch itself failed);
* `--cluster MODULE.CLASS --cluster-option K=V`, a refused class or options (exit 2), the job script.

Most tests run on an in-process cluster (threads), so the stage functions can be replaced by fakes
(``batch_stages.run_stage``); the worker plugin and real input errors run on a LocalCluster of one
worker process started with dask's defaults.
"""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.pipeline import batch as B
from cdgps_cli.pipeline import batch_dask as BD
from cdgps_cli.pipeline import batch_stages
from cdgps_cli.report.batch_index import write_index

distributed = pytest.importorskip("distributed")


# --------------------------------------------------------------------------- the trend fit

DEGENERATE = {
    "sigma 1e-15": ([0, 1, 2, 3], [0.020, 0.021, 0.019, 0.020], [1e-15, 1e-15, 1e-15, 1e-15]),
    "one sigma 1e-15 among real ones": ([0, 1, 2, 3], [0.020, 0.021, 0.019, 0.020], [1e-3, 1e-15, 2e-3, 1e-3]),
    "sigma underflowing": ([0, 1, 2], [1.0, 2.0, 3.0], [1e-200, 1e-200, 1e-200]),
    "constant values": ([0, 1, 2, 3], [0.02, 0.02, 0.02, 0.02], [1e-3, 1e-3, 1e-3, 1e-3]),
    "constant values, sigma 1e-15": ([0, 1, 2], [0.02, 0.02, 0.02], [1e-15, 1e-15, 1e-15]),
    "one point": ([0], [0.02], [1e-3]),
    "two points": ([0, 1], [0.02, 0.03], [1e-3, 1e-3]),
    "no point": ([], [], []),
    "NaN values": ([0, 1, 2], [float("nan"), 0.02, float("nan")], [1e-3, 1e-3, 1e-3]),
    "NaN sigma": ([0, 1, 2], [0.02, 0.03, 0.04], [float("nan")] * 3),
    "zero and negative sigma": ([0, 1, 2], [0.02, 0.03, 0.04], [0.0, -1.0, 1e-3]),
    "one time": ([5, 5, 5], [0.02, 0.03, 0.04], [1e-3, 1e-3, 1e-3]),
    "infinite value": ([0, 1, 2], [float("inf"), 0.03, 0.04], [1e-3, 1e-3, 1e-3]),
}


@pytest.mark.parametrize("case", sorted(DEGENERATE))
def test_a_degenerate_series_has_no_trend_and_says_why(case):
    t, y, s = DEGENERATE[case]
    with np.errstate(all="raise"):                    # not even a floating-point warning
        fit, note = B.trend_fit(t, y, s)
    assert fit is None and note.startswith(B.NO_SPREAD), (case, fit, note)
    assert B.weighted_trend(t, y, s) is None


def test_tiny_but_real_sigmas_still_fit():
    """σ 1e-8 on values of 1 is above the floor: a line, with the slope's σ of the weights."""
    t = np.arange(5.0)
    y = 1.0 + 1e-8 * np.array([0.3, -0.2, 0.1, 0.4, -0.5])
    fit, note = B.trend_fit(t, y, np.full(5, 1e-8))
    assert note is None and fit["n"] == 5
    assert fit["slope_sigma_per_day"] == pytest.approx(1e-8 / math.sqrt(10.0), rel=1e-9)


def _entries(damping, damping_sigma, gps_hz=(1.50, 1.51, 1.49), times=("2026-11-01", "2026-11-02", "2026-11-03")):
    return [{"session": f"s{i}", "time": B._time(t, None), "modes": [
        {"mode": "bend1", "model_hz": 1.5, "gps_hz": f, "gps_hz_sigma": 0.002, "damping": d,
         "damping_sigma": ds, "seen": True}]} for i, (t, f, d, ds) in enumerate(zip(times, gps_hz, damping, damping_sigma))]


def test_the_index_says_not_enough_spread(tmp_path):
    entries = _entries([0.02, 0.02, 0.02], [1e-15, 1e-15, 1e-15])
    (tr,) = B.mode_trends(entries)
    assert tr["frequency_trend_hz"] is not None and tr["frequency_trend_hz_note"] is None
    assert tr["damping_trend"] is None and tr["damping_trend_note"].startswith(B.NO_SPREAD)
    summary = {"manifest": str(tmp_path / "m.csv"), "counts": {"sessions": 3, "done": 3}, "workers": 1,
               "elapsed_s": 1.0, "started": "x", "finished": "y", "failures": [], "trends": [tr],
               "sessions": [{**e, "status": "done", "folder": str(tmp_path / e["session"]), "elapsed_s": 0.1}
                            for e in entries]}
    write_index(B.finite_json(summary), tmp_path)
    html = (tmp_path / "index.html").read_text()
    assert "not enough spread: σ ≈ 0" in html and (tmp_path / "trends.png").is_file()


def test_nan_everywhere_gives_strict_json_and_an_index(tmp_path):
    nan = float("nan")
    entries = _entries([nan, nan, nan], [nan, nan, nan], gps_hz=(nan, nan, nan))
    (tr,) = B.mode_trends(entries)
    assert tr["frequency_trend_hz"] is None and tr["damping_trend"] is None
    summary = B.finite_json({"trends": [tr], "x": [nan, float("inf"), 1.0]})
    text = json.dumps(summary, allow_nan=False)          # raises on any NaN left
    assert json.loads(text)["x"] == [None, None, 1.0]


# --------------------------------------------------------------------------- an in-process cluster

@pytest.fixture(scope="module")
def inproc():
    """One worker thread in this process: ``batch_stages.run_stage`` can be replaced by a fake."""
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cl, \
            distributed.Client(cl) as c:
        yield c


class FakeStages:
    """Stage functions that write a small output and return ``modes`` for spectra, failing as told:
    ``faults[(session, stage)] = [exception, …]`` raised on the first attempts, in order."""

    def __init__(self, modes=None):
        self.modes = modes or {}
        self.faults = {}
        self.calls = {}

    def __call__(self, s, stage):
        k = (s.name, stage)
        n = self.calls[k] = self.calls.get(k, 0) + 1
        todo = self.faults.get(k, [])
        if n <= len(todo):
            raise todo[n - 1]
        p = Path(s.path(stage))
        if stage == "spectra":
            p.mkdir(parents=True, exist_ok=True)
            (p / "spectra.csv").write_text("f_hz\n1\n")
            return {"modes": self.modes.get(s.name, [])}
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(f"{s.name} {stage}\n")
        return {"nis_per_dof": 1.0} if stage == "estimate" else {}


def _mode(damping, damping_sigma, hz=1.5):
    return {"mode": "bend1", "model_hz": 1.5, "gps_hz": hz, "gps_hz_sigma": 0.002, "damping": damping,
            "damping_sigma": damping_sigma, "seen": True}


@pytest.fixture
def fake(monkeypatch, tmp_path):
    """Three sessions from a (never read) RUN.mcap: init → estimate → spectra by :class:`FakeStages`;
    their damping is constant with σ 1e-15 (the campaign that crashed the trend fit)."""
    f = FakeStages({n: [_mode(0.02, 1e-15, hz)] for n, hz in (("a", 1.50), ("b", 1.51), ("c", 1.49))})
    monkeypatch.setattr(batch_stages, "run_stage", f)
    (tmp_path / "run.mcap").write_bytes(b"not read by the fake stages")
    (tmp_path / "m.csv").write_text("session,run_mcap,time,stages\n" + "".join(
        f"{n},run.mcap,2026-11-0{i + 1},init estimate spectra\n" for i, n in enumerate("abc")))
    f.manifest, f.out = tmp_path / "m.csv", tmp_path / "out"
    return f


def _batch(inproc, f, *extra):
    return CliRunner().invoke(main, ["batch", str(f.manifest), "-o", str(f.out), "--scheduler",
                                     inproc.scheduler.address, *extra])


def test_a_degenerate_damping_series_writes_the_index_and_resumes(inproc, fake):
    r = _batch(inproc, fake, "--json")
    assert r.exit_code == 0, r.output
    assert "Traceback" not in r.output
    s = json.loads((fake.out / "batch.json").read_text())
    assert s["counts"] == {"sessions": 3, "done": 3}
    (tr,) = s["trends"]
    assert tr["damping_trend"] is None and tr["damping_trend_note"].startswith("not enough spread")
    assert tr["frequency_trend_hz"]["n"] == 3
    assert "not enough spread" in (fake.out / "index.html").read_text()
    r = _batch(inproc, fake, "--resume", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["counts"] == {"sessions": 3, "up to date": 3}
    assert set(fake.calls.values()) == {1}                  # nothing redone
    assert not (fake.out / B.LOCK_FILE).exists()            # the lock released


def test_an_input_error_fails_at_once_and_worker_faults_are_retried(inproc, fake):
    fake.faults = {("a", "init"): [CdgpsError("run.mcap: channel 3: bad phase")] * 5,
                   ("b", "estimate"): [OSError(5, "Input/output error"), MemoryError()],
                   ("c", "init"): [RuntimeError("flaky")] * 5}
    r = _batch(inproc, fake, "--retries", "2")
    assert r.exit_code == BD.EXIT_SESSIONS_FAILED == 3, r.output
    assert fake.calls[("a", "init")] == 1                   # not retried
    assert fake.calls[("b", "estimate")] == 3               # two worker faults, then done
    assert fake.calls[("c", "init")] == 3                   # retried twice, then given up
    assert ("a", "estimate") not in fake.calls and ("c", "estimate") not in fake.calls
    s = json.loads((fake.out / "batch.json").read_text())
    st = {e["session"]: e for e in s["sessions"]}
    assert st["a"]["error"] == "init: run.mcap: channel 3: bad phase"
    assert st["a"]["stages"]["estimate"] == {"status": "not run", "reason": "init failed"}
    assert st["b"]["status"] == "done" and st["c"]["error"] == "init: RuntimeError: flaky"
    assert "session a failed: init: run.mcap: channel 3: bad phase" in r.output
    # the modes of b alone: one session, no line, said so
    assert s["trends"][0]["frequency_trend_hz_note"].startswith("not enough spread: 1 session")
    fake.faults = {}
    r = _batch(inproc, fake, "--resume", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["counts"] == {"sessions": 3, "up to date": 1, "done": 2}


def test_the_batch_itself_failing_exits_4(inproc, fake, monkeypatch):
    def lost(*a, **k):
        raise RuntimeError("scheduler connection lost")

    monkeypatch.setattr(BD, "_submit_and_wait", lost)
    r = _batch(inproc, fake)
    assert r.exit_code == BD.EXIT_BATCH_FAILED == 4, r.output
    assert "cdgps: error: the batch itself failed: RuntimeError: scheduler connection lost" in r.output
    assert "Traceback" not in r.output
    assert "scheduler connection lost" in (fake.out / B.ERROR_LOG).read_text()
    assert not (fake.out / B.LOCK_FILE).exists() and not (fake.out / "batch.json").exists()


# --------------------------------------------------------------------------- the OUTDIR lock

def _lock(out: Path, pid: int, host: str | None = None) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    p = out / B.LOCK_FILE
    p.write_text(json.dumps({"pid": pid, "host": host or socket.gethostname(), "since": "2026-12-04T05:00:00Z"}))
    return p


def test_a_held_lock_refuses_a_second_batch(inproc, fake):
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        lock = _lock(fake.out, holder.pid)
        r = _batch(inproc, fake)
        assert r.exit_code == 2, r.output
        assert str(lock) in r.output and f"pid {holder.pid} on host {socket.gethostname()}" in r.output
        assert sorted(p.name for p in fake.out.iterdir()) == [B.LOCK_FILE]     # nothing else written
        assert fake.calls == {}
    finally:
        holder.kill()
        holder.wait()
    # its holder gone: a stale lock, taken over with a warning
    r = _batch(inproc, fake)
    assert r.exit_code == 0, r.output
    assert f"cdgps: warning: {lock}: stale lock of pid {holder.pid}" in r.output
    assert not lock.exists()


def test_a_lock_of_another_host_is_refused(inproc, fake):
    lock = _lock(fake.out, 1, host="node-17.cluster")
    r = _batch(inproc, fake)
    assert r.exit_code == 2 and "pid 1 on host node-17.cluster" in r.output and "remove the file" in r.output
    assert lock.exists()


def test_two_acquires_in_one_process_the_second_refused(tmp_path):
    from cdgps_cli.pipeline import batch_lock

    first = batch_lock.acquire(tmp_path / "out")
    with pytest.raises(batch_lock.OutdirLocked, match=f"pid {os.getpid()}"):
        batch_lock.acquire(tmp_path / "out")
    first.release()
    batch_lock.acquire(tmp_path / "out").release()
    assert list((tmp_path / "out").iterdir()) == []


# --------------------------------------------------------------------------- --cluster

@pytest.mark.parametrize("workers, argv", [(1, ["--cluster-option", "n_workers=1"]),
                                           (2, ["--cluster-option", "n_workers=0", "--workers", "2"])])
def test_cluster_names_a_local_cluster_with_options(fake, workers, argv):
    r = CliRunner().invoke(main, ["batch", str(fake.manifest), "-o", str(fake.out), "--json",
                                  "--cluster", "distributed.LocalCluster", "--cluster-option", "processes=false",
                                  "--cluster-option", "threads_per_worker=1",
                                  "--cluster-option", "dashboard_address=':0'", *argv])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["counts"] == {"sessions": 3, "done": 3} and s["workers"] == workers
    assert not (fake.out / B.LOCK_FILE).exists()


def test_a_job_queue_class_without_its_submit_command_exits_2(fake, monkeypatch):
    """dask-jobqueue's SLURMCluster where there is no sbatch: refused before any job (which would fail in
    the background while the batch waited)."""
    pytest.importorskip("dask_jobqueue")
    monkeypatch.setenv("PATH", str(fake.manifest.parent))            # no sbatch there
    r = CliRunner().invoke(main, ["batch", str(fake.manifest), "-o", str(fake.out), "--cluster",
                                  "dask_jobqueue.SLURMCluster", "--cluster-option", "cores=1", "--cluster-option",
                                  "memory=1GiB"])
    assert r.exit_code == 2, r.output
    assert "job submit command 'sbatch' is not on this machine's PATH" in r.output
    assert not fake.out.exists()


@pytest.mark.parametrize("argv, says", [
    (["--cluster", "no_such_module.Cluster"], "--cluster no_such_module.Cluster: cannot import no_such_module"),
    (["--cluster", "distributed.NoSuchCluster"], "distributed has no class NoSuchCluster"),
    (["--cluster", "LocalCluster"], "expected MODULE.CLASS"),
    (["--cluster", "collections.OrderedDict"], "not a dask cluster manager"),
    (["--cluster", "distributed.LocalCluster", "--cluster-option", "processes=false", "--cluster-option",
      "bogus_option=1"], "refused the options (processes=False, bogus_option=1)"),
    (["--cluster", "distributed.LocalCluster", "--cluster-option", "nokey"], "expected KEY=VALUE"),
    (["--cluster", "distributed.LocalCluster", "--print-job-script"], "not a job-queue cluster manager"),
])
def test_a_cluster_that_cannot_be_had_exits_2(fake, argv, says):
    r = CliRunner().invoke(main, ["batch", str(fake.manifest), "-o", str(fake.out), *argv])
    assert r.exit_code == 2, r.output
    assert says in r.output and "Traceback" not in r.output
    assert not fake.out.exists() and fake.calls == {}


def test_cluster_option_values_are_toml_or_text():
    assert BD.parse_cluster_options(["cores=2", "memory=4GiB", "processes=false", "queue=normal",
                                     'job_extra_directives=["--exclusive"]', "walltime=01:00:00"]) == {
        "cores": 2, "memory": "4GiB", "processes": False, "queue": "normal",
        "job_extra_directives": ["--exclusive"], "walltime": "01:00:00"}
    with pytest.raises(CdgpsError, match="given twice"):
        BD.parse_cluster_options(["cores=2", "cores=4"])


def test_slurm_job_script(fake):
    """The worked example of docs/batch.md: the SLURM job script dask-jobqueue would submit."""
    pytest.importorskip("dask_jobqueue")
    r = CliRunner().invoke(main, ["batch", str(fake.manifest), "-o", str(fake.out), "--print-job-script",
                                  "--cluster", "dask_jobqueue.SLURMCluster", "--cluster-option", "queue=normal",
                                  "--cluster-option", "cores=2", "--cluster-option", "processes=2",
                                  "--cluster-option", "memory=4GiB", "--cluster-option", "walltime=01:00:00",
                                  "--cluster-option", "scheduler_options={dashboard_address=':0'}"])
    assert r.exit_code == 0, r.output
    for line in ("#SBATCH -p normal", "#SBATCH --cpus-per-task=2", "#SBATCH --mem=4G", "#SBATCH -t 01:00:00",
                 "--nthreads 1", "--nworkers 2"):
        assert line in r.stdout, r.stdout
    assert not fake.out.exists()


# --------------------------------------------------------------------------- worker processes with dask's defaults

@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """A LocalCluster of one worker process as dask starts it (profiler on, MALLOC_TRIM_THRESHOLD_ from
    the nanny), the fault hook's folder in its environment."""
    import dask

    faults = tmp_path_factory.mktemp("faults")
    with dask.config.set({BD.PROFILE_KEY: True}), distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                                  env={B.FAULT_ENV: str(faults)}) as cl, distributed.Client(cl) as c:
        c.faults = faults
        yield c


def _state(dask_worker):
    import os

    return {"profile_callback": "profile" in dask_worker.periodic_callbacks,
            "trim_env": os.environ.get(BD.TRIM_KEY),
            "settings": getattr(dask_worker, "cdgps_settings", None)}


def _sigint_handler():
    import signal

    h = signal.getsignal(signal.SIGINT)
    return "SIG_IGN" if h is signal.SIG_IGN else "SIG_DFL" if h is signal.SIG_DFL else getattr(h, "__qualname__", str(h))


def test_the_worker_plugin_applies_the_settings_on_a_cluster_started_without_them(plain, monkeypatch):
    (before,) = plain.run(_state).values()
    assert before["profile_callback"] and before["trim_env"] == "65536"
    (sig_before,) = plain.run(_sigint_handler).values()         # (a worker under pytest-xdist may start ignoring it)
    monkeypatch.delenv(BD.TRIM_KEY, raising=False)
    BD.apply_worker_settings(plain)
    (after,) = plain.run(_state).values()
    assert not after["profile_callback"]
    assert after["settings"]["malloc"].startswith("MALLOC_TRIM_THRESHOLD_=65536 overridden: mmap threshold 33554432")
    assert after["settings"]["blas_env"]["OMP_NUM_THREADS"] == "1"
    # a cluster the batch did not start keeps its own Ctrl-C handling (a review: a user's `dask worker` could no
    # longer be stopped by SIGINT); on its own cluster the batch makes its workers leave Ctrl-C to it
    assert after["settings"]["sigint"].startswith("kept (a cluster the batch did not start")
    assert plain.run(_sigint_handler) == {k: sig_before for k in plain.run(_sigint_handler)}     # left as it was
    BD.apply_worker_settings(plain, own_cluster=True)
    (own,) = plain.run(_state).values()
    assert own["settings"]["sigint"] == "ignored (the batch process stops the worker)"
    assert set(plain.run(_sigint_handler).values()) == {"SIG_IGN"}
    # a worker that joins later gets them too
    plain.cluster.scale(2)
    plain.wait_for_workers(2, timeout=120)
    states = list(plain.run(_state).values())
    assert [s["profile_callback"] for s in states] == [False, False]
    plain.cluster.scale(1)


def test_real_input_error_in_a_worker_process_is_not_retried(plain, tmp_path):
    """A corrupt RUN.mcap: init raises CdgpsError in the worker; two OSErrors before it were retried."""
    (tmp_path / "run.mcap").write_bytes(b"x" * 10)
    (tmp_path / "m.csv").write_text("session,run_mcap,stages\nbad,run.mcap,init estimate\n")
    (plain.faults / "faults").write_text("bad/init oserror 2\n")
    s = BD.run_batch(tmp_path / "m.csv", tmp_path / "out", client=plain, retries=3)
    attempts = (plain.faults / "bad-init.attempts").read_text().split()
    assert len(attempts) == 3                 # 2 OSErrors retried, the CdgpsError of the 3rd not (retries=3)
    (e,) = s["sessions"]
    assert e["status"] == "failed" and "run.mcap" in e["error"] and "not a valid MCAP file" in e["error"]
    assert e["stages"]["estimate"]["status"] == "not run"
    # the batch registered the plugin on this cluster
    assert all(st["settings"] is not None for st in plain.run(_state).values())
