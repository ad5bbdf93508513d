"""Issue 12 item 4: commands that write several files replace them as a set, and SIGTERM cleans up
like SIGINT (cdgps_cli.io.atomic.output_set, sigterm_raises; docs/hardening.md "Output sets")."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import types
from pathlib import Path

import pytest
from click.testing import CliRunner

from cdgps_cli.io import atomic
from cdgps_cli.report import sensor_reports as reports
from cdgps_cli.io.atomic import SET_JOURNAL, Terminated, output_set, recover_output_folder, sigterm_raises, write_atomic
from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation
from cdgps_cli.analysis.spectra import SpectraOptions

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
SIM_SET = {"receiver.csv", "gyro.csv", "truth.csv", "truth.json"}
FAST_SPECTRA = SpectraOptions(pad=1, coords=("q2", "q5", "q8"))


def _files(d: Path) -> dict:
    """Every entry of ``d`` (hidden ones too) → its bytes (None for a folder)."""
    return {p.name: (None if p.is_dir() else p.read_bytes()) for p in sorted(d.iterdir())}


def _hidden(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if p.name.startswith("."))


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


@pytest.fixture(scope="module")
def fake_states(testbed_cfg, tmp_path_factory):
    """States-like objects (cfg, time_s, q, path) from the simulator's truth: spectra need no estimate
    (the path is a stand-in file, for the report's provenance)."""
    d = tmp_path_factory.mktemp("states")

    def make(seed):
        sim = simulate(testbed_cfg, SimOptions(duration_s=80.0, seed=seed))
        path = d / f"seed{seed}.mcap"
        path.write_bytes(b"stand-in %d" % seed)
        return types.SimpleNamespace(cfg=testbed_cfg, time_s=sim.time_s, q=sim.q, path=path)
    return make


# ----------------------------------------------------------------------------- failure mid-way

def test_spectra_disk_full_midway_leaves_earlier_set(fake_states, tmp_path, monkeypatch):
    out = tmp_path / "spectra"
    reports.run_spectra(fake_states(1), None, FAST_SPECTRA, out)
    before = _files(out)
    assert set(before) == {"psd.csv", "peaks.json", "psd.png", "fdd.png"}
    real = reports._atomic_bytes
    written = []

    def full_at_fdd(path, data):
        if Path(path).name == "fdd.png":                 # psd.csv, peaks.json, psd.png are written by then
            raise CdgpsError(str(atomic.output_error(path, OSError(errno.ENOSPC, "No space left on device"))))
        written.append(Path(path).name)
        real(path, data)

    monkeypatch.setattr(reports, "_atomic_bytes", full_at_fdd)
    with pytest.raises(CdgpsError) as e:
        reports.run_spectra(fake_states(2), None, FAST_SPECTRA, out)
    assert written == ["psd.csv", "peaks.json", "psd.png"]           # the new set was under way
    assert str(out / "fdd.png") in str(e.value) and "no space left" in str(e.value)
    assert ".cdgps-" not in str(e.value)                             # the final path, not the staging one
    assert _files(out) == before                                     # old set complete, nothing hidden left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spectra"]


def test_spectrum_report_is_one_set_with_its_spectra(fake_states, tmp_path, monkeypatch):
    """report spectrum writes the spectra files and the report as one set: a failure at the report
    leaves the earlier psd.csv too."""
    out = tmp_path / "r"
    reports.spectrum_report(fake_states(1), None, FAST_SPECTRA, out, date="2026-01-01")
    before = _files(out)
    assert {"psd.csv", "report.html"} <= set(before)
    real = reports._atomic_bytes
    monkeypatch.setattr(reports, "_atomic_bytes", lambda p, d: (_ for _ in ()).throw(OSError(errno.ENOSPC, "full", str(p)))
                        if Path(p).name == "report.html" else real(p, d))
    with pytest.raises(CdgpsError, match="no space left"):
        reports.spectrum_report(fake_states(2), None, FAST_SPECTRA, out, date="2026-01-01")
    assert _files(out) == before


def test_failure_in_a_new_folder_leaves_no_folder(tmp_path):
    out = tmp_path / "new" / "deeper"
    with pytest.raises(RuntimeError):
        with output_set(out) as dest:
            dest.path("a.csv").write_text("1\n")
            raise RuntimeError("computation failed")
    assert not out.exists()


# ----------------------------------------------------------------------------- success

def test_success_over_old_folder_leaves_exactly_the_new_set(testbed_cfg, tmp_path):
    out, fresh = tmp_path / "sim", tmp_path / "fresh"
    write_simulation(simulate(testbed_cfg, SimOptions(duration_s=6.0, seed=1, scenario="pulse")), out)
    assert set(_files(out)) == SIM_SET | {"actuators.csv"}
    (out / "notes.txt").write_text("my own notes\n")                 # not cdgps': kept as it is
    (out / "plots").mkdir()
    new = simulate(testbed_cfg, SimOptions(duration_s=5.0, seed=3))
    write_simulation(new, out)
    write_simulation(new, fresh)
    got = _files(out)
    assert set(got) == SIM_SET | {"notes.txt", "plots"}              # stale actuators.csv gone, no temporaries
    assert got["notes.txt"] == b"my own notes\n"
    assert {k: v for k, v in got.items() if k in SIM_SET} == _files(fresh)


def test_folder_where_a_file_goes_is_refused_before_anything_changes(testbed_cfg, tmp_path):
    out = tmp_path / "sim"
    write_simulation(simulate(testbed_cfg, SimOptions(duration_s=5.0, seed=1)), out)
    (out / "truth.json").unlink()
    (out / "truth.json").mkdir()
    before = _files(out)
    with pytest.raises(CdgpsError, match=r"truth.json: is a folder"):
        write_simulation(simulate(testbed_cfg, SimOptions(duration_s=5.0, seed=2)), out)
    assert _files(out) == before


def test_simulate_gnss_replaces_receivers_of_an_earlier_run(tmp_path):
    r = CliRunner()
    out = tmp_path / "g"
    base = ["simulate-gnss", "--duration", "60", "--seed", "1", "-o", str(out)]
    assert r.invoke(main, [*base, "--master", "m1", "--rover", "r1"]).exit_code == 0
    assert {"m1.rnx", "r1.rnx"} <= set(_files(out))
    assert r.invoke(main, [*base, "--master", "m2", "--rover", "r2"]).exit_code == 0
    assert set(_files(out)) == {"m2.rnx", "r2.rnx", "nav.rnx", "truth.csv", "truth.json", "config.toml"}


# ----------------------------------------------------------------------------- signals, in this process

def test_sigterm_during_commit_completes_the_set_then_terminates(tmp_path, monkeypatch):
    monkeypatch.setattr(atomic, "_renameat2", False)        # the journaled commit (no folder swap)
    out = tmp_path / "o"
    with output_set(out) as dest:
        for n in ("a.csv", "b.csv"):
            dest.path(n).write_text("old\n")
    real = atomic._roll_forward

    def signalled(o, commit):
        os.kill(os.getpid(), signal.SIGTERM)             # arrives between the first and the last rename
        time.sleep(0.05)
        real(o, commit)

    monkeypatch.setattr(atomic, "_roll_forward", signalled)
    with pytest.raises(Terminated):
        with output_set(out) as dest:
            for n in ("a.csv", "b.csv"):
                dest.path(n).write_text("new\n")
    assert _files(out) == {"a.csv": b"new\n", "b.csv": b"new\n"}
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL          # handler restored


def test_sigterm_while_writing_raises_and_cleans(tmp_path):
    out = tmp_path / "o"
    with output_set(out) as dest:
        dest.path("a.csv").write_text("old\n")
    with pytest.raises(Terminated):
        with output_set(out) as dest:
            dest.path("a.csv").write_text("half")
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)                                  # the handler raises before this ends
    assert _files(out) == {"a.csv": b"old\n"}


def test_embedding_programs_sigterm_handler_is_left_alone():
    seen = []
    old = signal.signal(signal.SIGTERM, lambda s, f: seen.append(s))
    try:
        with sigterm_raises():
            assert signal.getsignal(signal.SIGTERM) is not atomic._raise_terminated
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
        assert seen == [signal.SIGTERM]
    finally:
        signal.signal(signal.SIGTERM, old)


# ----------------------------------------------------------------------------- recovery after SIGKILL

def test_next_write_rolls_forward_an_interrupted_commit_and_removes_dead_staging(tmp_path):
    """The journaled commit (where the folder cannot be swapped, or left by an earlier version)."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "a.csv").write_text("new\n")                     # renamed in before the kill
    (out / "b.csv").write_text("old\n")                     # still old: a mixed set …
    (out / "c.csv").write_text("old only\n")                # … and an old file the new set lacks
    pid = _dead_pid()
    commit = out / f".cdgps-commit-{pid}-x"
    commit.mkdir()
    (commit / "b.csv").write_text("new\n")
    (commit / SET_JOURNAL).write_text(json.dumps({"files": ["a.csv", "b.csv"], "remove": ["c.csv"]}))
    staging = out / f".cdgps-new-{pid}-y"                   # a write SIGKILLed before its commit
    staging.mkdir()
    (staging / "a.csv").write_text("partial")
    live = out / f".cdgps-new-{os.getpid()}-z"              # a writer still running: left alone
    live.mkdir()
    done = recover_output_folder(out)
    assert len(done) == 2
    assert _files(out) == {"a.csv": b"new\n", "b.csv": b"new\n", live.name: None}
    live.rmdir()


def test_stale_single_file_temporary_of_a_dead_writer_is_removed(tmp_path):
    pid = _dead_pid()
    stale = tmp_path / f".x.csv.tmp{pid}"
    stale.write_text("half")
    running = tmp_path / f".x.csv.tmp{os.getppid()}"        # a live process's: kept
    running.write_text("busy")
    write_atomic(tmp_path / "x.csv", lambda p: p.write_text("1\n"))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["x.csv", running.name])


# ----------------------------------------------------------------------------- killed processes

_SLOW_SIMULATE = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from cdgps_cli.sim import structure as sim_mod
    from cdgps_cli.cli.commands import main

    ready = Path(sys.argv[1])
    real = sim_mod._write_atomic

    def slow(path, writer):
        real(path, writer)
        if Path(path).name == "receiver.csv":          # receiver.csv of the new set written: wait to be killed
            ready.write_text("writing")
            time.sleep(60)

    sim_mod._write_atomic = slow
    main(sys.argv[2:], prog_name="cdgps")
""")

_SLOW_SINGLE = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from cdgps_cli.io.atomic import write_atomic

    ready, target = Path(sys.argv[1]), Path(sys.argv[2])

    def writer(tmp):
        with open(tmp, "w") as fh:
            fh.write("half of a new file")
            fh.flush()
            ready.write_text("writing")
            time.sleep(60)

    write_atomic(target, writer)
""")


def _run_until_ready(script: str, ready: Path, args: list[str]) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-c", script, str(ready), *args], env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    while not ready.exists():
        assert p.poll() is None, p.communicate()
        assert time.monotonic() - t0 < 60, "the writer never started"
        time.sleep(0.02)
    return p


def test_sigterm_killed_simulate_leaves_seed1_set_and_no_temporaries(tmp_path):
    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["simulate", str(TESTBED), "--duration", "5", "--seed", "1", "-o", str(out)])
    assert r.exit_code == 0, r.output
    seed1 = _files(out)
    assert set(seed1) == SIM_SET
    p = _run_until_ready(_SLOW_SIMULATE, tmp_path / "ready",
                         ["simulate", str(TESTBED), "--duration", "5", "--seed", "3", "-o", str(out)])
    assert any(n.startswith(".run.tmp") for n in _hidden(tmp_path))     # the new set was under way (beside)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    assert p.returncode == atomic.TERMINATED_EXIT, err
    assert "terminated (SIGTERM)" in err and "Traceback" not in err
    assert _files(out) == seed1                                        # complete seed-1 set, nothing hidden
    assert _hidden(tmp_path) == []


def test_sigterm_during_single_file_write_leaves_no_temporary(tmp_path):
    target = tmp_path / "est.csv"
    target.write_text("the earlier file\n")
    p = _run_until_ready(_SLOW_SINGLE, tmp_path / "ready", [str(target)])
    assert any(n.startswith(".est.csv.tmp") for n in _hidden(tmp_path))
    p.send_signal(signal.SIGTERM)
    p.communicate(timeout=60)
    assert p.returncode != 0
    assert _hidden(tmp_path) == []
    assert target.read_text() == "the earlier file\n"


@pytest.mark.parametrize("name", ["a/b.rnx", ".hidden", "", SET_JOURNAL])
def test_output_names_outside_the_folder_are_a_clean_error(tmp_path, name):
    with pytest.raises(CdgpsError, match="plain, visible file name"):
        with output_set(tmp_path / "o") as dest:
            dest.path(name)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- folder swap (issue 32)

swap_only = pytest.mark.skipif(atomic._exchange_function() is None, reason="no renameat2 here")


def _old_folder(tmp_path) -> Path:
    out = tmp_path / "o"
    with output_set(out, replaces=("a.csv", "b.csv", "c.csv")) as dest:
        for n in ("a.csv", "b.csv", "c.csv"):
            dest.path(n).write_text("old\n")
    (out / "notes.txt").write_text("mine\n")                 # a user's file and folder: kept
    (out / "sub").mkdir()
    (out / "sub" / "x").write_text("x\n")
    return out


_NEW = {"a.csv": b"new\n", "b.csv": b"new\n", "notes.txt": b"mine\n", "sub": None}


def _write_new(out):
    with output_set(out, replaces=("a.csv", "b.csv", "c.csv")) as dest:
        for n in ("a.csv", "b.csv"):
            dest.path(n).write_text("new\n")


@swap_only
def test_swap_replaces_the_folder_in_one_step_keeping_other_files(tmp_path):
    out = _old_folder(tmp_path)
    mode = 0o750
    out.chmod(mode)
    _write_new(out)
    assert _files(out) == _NEW and (out / "sub" / "x").read_text() == "x\n"
    assert out.stat().st_mode & 0o777 == mode
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]


@swap_only
@pytest.mark.parametrize("step", ["before_link", "before_exchange", "after_exchange"])
def test_a_kill_at_each_step_of_the_swap_leaves_the_old_or_the_new_folder(tmp_path, monkeypatch, step):
    """A simulated SIGKILL (an exception no cleanup may run for: os._exit is not testable in-process,
    so the staging sibling is kept from the finally block too) at each step: the folder is the whole
    old set or the whole new one, and the next write removes what the dead process left."""
    out = _old_folder(tmp_path)
    old = _files(out)

    class Killed(BaseException):
        pass

    def kill(*a, **k):
        raise Killed()

    real_exchange = atomic.exchange_paths
    if step == "before_link":
        monkeypatch.setattr(atomic, "_link_tree", kill)
    elif step == "before_exchange":
        monkeypatch.setattr(atomic, "exchange_paths", kill)
    else:
        def exchange_then_die(a, b):
            assert real_exchange(a, b)
            raise Killed()
        monkeypatch.setattr(atomic, "exchange_paths", exchange_then_die)
    monkeypatch.setattr(atomic.shutil, "rmtree", lambda *a, **k: None)      # a killed process cleans nothing
    with pytest.raises(Killed):
        _write_new(out)
    assert _files(out) == (_NEW if step == "after_exchange" else old)
    leftover = tmp_path / f".o.tmp{os.getpid()}"
    assert leftover.is_dir()
    monkeypatch.undo()
    dead = tmp_path / f".o.tmp{_dead_pid()}"
    leftover.rename(dead)                                     # as if its process had died
    _write_new(out)
    assert _files(out) == _NEW
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]


@swap_only
def test_sigkilled_child_at_the_exchange_leaves_old_or_new_folder(tmp_path):
    """A real SIGKILL of a child process just before and just after the exchange: the folder is the
    whole old or the whole new one, and the watcher removes the sibling the dead process left."""
    for when in ("before", "after"):
        out = _old_folder(tmp_path / when)
        old = _files(out)
        script = textwrap.dedent(f"""
            import os, signal, sys
            from cdgps_cli.io import atomic
            real = atomic.exchange_paths
            def die(a, b):
                if {when!r} == "after":
                    real(a, b)
                os.kill(os.getpid(), signal.SIGKILL)
            atomic.exchange_paths = die
            with atomic.output_set(sys.argv[1], replaces=("a.csv", "b.csv", "c.csv")) as dest:
                for n in ("a.csv", "b.csv"):
                    dest.path(n).write_text("new\\n")
        """)
        r = subprocess.run([sys.executable, "-c", script, str(out)], env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert r.returncode == -signal.SIGKILL
        assert _files(out) == (_NEW if when == "after" else old)
        t0 = time.monotonic()                                 # the watcher removes the dead one's sibling
        while len(list((tmp_path / when).iterdir())) > 1 and time.monotonic() - t0 < 10:
            time.sleep(0.01)
        assert sorted(p.name for p in (tmp_path / when).iterdir()) == ["o"]
        _write_new(out)
        assert _files(out) == _NEW


@swap_only
def test_swap_falls_back_to_the_journal_in_the_current_folder(tmp_path, monkeypatch):
    out = _old_folder(tmp_path)
    monkeypatch.chdir(out)
    calls = []
    monkeypatch.setattr(atomic, "exchange_paths", lambda a, b: calls.append(1))
    _write_new(out)
    assert calls == [] and _files(out) == _NEW


def test_swap_falls_back_to_the_journal_where_the_exchange_is_refused(tmp_path, monkeypatch):
    out = _old_folder(tmp_path)
    monkeypatch.setattr(atomic, "exchange_paths", lambda a, b: False)     # e.g. NFS: EINVAL
    _write_new(out)
    assert _files(out) == _NEW
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]


def test_symlinked_output_folder_stays_a_symlink(tmp_path):
    out = _old_folder(tmp_path)
    link = tmp_path / "link"
    link.symlink_to(out)
    _write_new(link)
    assert link.is_symlink() and _files(out) == _NEW


@swap_only
def test_without_the_watcher_the_next_write_removes_a_killed_sets_sibling(tmp_path, monkeypatch):
    """Where the watcher cannot start, a SIGKILLed set's sibling is removed by the next write."""
    out = _old_folder(tmp_path / "w")
    script = textwrap.dedent("""
        import os, signal, sys
        from cdgps_cli.io import atomic
        atomic._start_reaper = lambda path: None
        atomic.exchange_paths = lambda a, b: os.kill(os.getpid(), signal.SIGKILL)
        with atomic.output_set(sys.argv[1], replaces=("a.csv", "b.csv", "c.csv")) as dest:
            dest.path("a.csv").write_text("new\\n")
    """)
    r = subprocess.run([sys.executable, "-c", script, str(out)], env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == -signal.SIGKILL
    assert len(list((tmp_path / "w").iterdir())) == 2           # o and its .o.tmpPID
    _write_new(out)
    assert sorted(p.name for p in (tmp_path / "w").iterdir()) == ["o"] and _files(out) == _NEW
