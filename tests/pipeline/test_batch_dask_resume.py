"""`cdgps batch` (cdgps_cli.pipeline.batch_dask) where the worker processes are not what is tested: a file of
its own beside tests/pipeline/test_batch_dask.py (the 2-worker cluster, a killed worker, retries), so that
pytest-xdist's ``--dist loadfile`` spreads the two.

* --resume after kill -9 of the batch process (its own cluster of one worker process): what was recorded
  is skipped, the rest done, same bytes as the single commands;
* a GNSS session (RINEX receivers listed in a GNSS config) gives the single commands' bytes.

The batches this file runs itself use one worker thread in this process (a LocalCluster with
``processes=False``): the stages, the records and the resume logic are the same as on worker processes,
without starting and importing into worker processes.  Paths are recorded inside the outputs, so every
run writes into the OUTDIR path of the reference.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.mcap_integrity import read_metadata
from cdgps_cli.pipeline import batch as B
from cdgps_cli.pipeline.batch_dask import run_batch
from tests.pipeline._batch_campaign import CONFIG, DURATION_S, assert_same_tree as _assert_same_tree

distributed = pytest.importorskip("distributed")


def _cli(*argv) -> None:
    r = CliRunner().invoke(main, ["-q", *map(str, argv)])
    assert r.exit_code == 0, (argv, r.output)


@pytest.fixture(scope="module")
def session_a(tmp_path_factory):
    """Session a of test_batch_dask.py's campaign (same log, same seed), its manifest to the spectra, and
    the reference outputs of the single commands."""
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation

    root = tmp_path_factory.mktemp("campaign")
    L = root / "logs"
    write_simulation(simulate(load_config(CONFIG), SimOptions(duration_s=DURATION_S, seed=11)), L / "s1")
    shutil.copy(CONFIG, L / "testbed.toml")
    killed = L / "killed.csv"
    killed.write_text("session,receiver_csv,gyro_csv,config,time,stages,smooth,init_duration_s,date\n"
                      "a,s1/receiver.csv,s1/gyro.csv,testbed.toml,2026-11-01,ingest init estimate spectra,true,10,"
                      "2026-12-01\n")
    out = root / "out"
    a = out / "a"
    _cli("ingest", L / "s1/receiver.csv", L / "s1/gyro.csv", "--config", L / "testbed.toml", "-o", a / "run.mcap")
    _cli("init", a / "run.mcap", "--duration", "10", "-o", a / "init.json")
    _cli("estimate", a / "run.mcap", "--init", a / "init.json", "--smooth", "-o", a / "states.mcap")
    _cli("spectra", a / "states.mcap", "--gyro", a / "run.mcap", "-o", a / "spectra")
    out.rename(root / "reference")
    return {"root": root, "killed": killed, "out": out, "ref": root / "reference"}


@pytest.fixture(scope="module")
def inproc():
    """One worker thread in this process."""
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cl, \
            distributed.Client(cl) as c:
        yield c


@pytest.mark.slow
def test_resume_after_kill_9_of_the_batch_process(session_a, inproc):
    """`cdgps batch` killed with SIGKILL once some stages are recorded; --resume finishes the rest."""
    campaign = session_a
    cdgps = Path(sys.executable).with_name("cdgps")
    proc = subprocess.Popen([str(cdgps), "-q", "batch", str(campaign["killed"]), "-o", str(campaign["out"]),
                             "--workers", "1"], start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not (campaign["out"] / "a" / B.RECORD_DIR / "ingest.json").exists():
            assert proc.poll() is None and time.monotonic() < deadline, "the batch ended before it was killed"
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)          # its cluster's processes (started by this test)
        except ProcessLookupError:
            pass
    assert not (campaign["out"] / "batch.json").exists()
    recorded = {(s, p.stem) for s in "a" for p in (campaign["out"] / s / B.RECORD_DIR).glob("*.json")}
    assert ("a", "ingest") in recorded and len(recorded) < 4
    s = run_batch(campaign["killed"], campaign["out"], client=inproc, resume=True)
    skipped = {(e["session"], k) for e in s["sessions"] for k, v in e["stages"].items() if v["status"] == "skipped"}
    assert skipped == recorded                             # exactly what had finished is skipped
    assert s["counts"] == {"sessions": 1, "done": 1}
    _assert_same_tree(campaign["ref"], campaign["out"], 3 + 4)


def test_a_gnss_session_gives_the_single_commands_bytes(tmp_path, inproc):
    """RINEX receivers listed in a GNSS config: ingest → init → estimate --smooth."""
    root = tmp_path / "gnss"
    r = CliRunner().invoke(main, ["-q", "simulate-gnss", "--duration", "60", "--seed", "2", "-o", str(root / "pair")])
    assert r.exit_code == 0, r.output
    cfg = root / "pair/config.toml"      # random walk: --smooth changes STATES (a static run's would not)
    cfg.write_text(cfg.read_text().replace('model = "static"', 'model = "random_walk"', 1))
    (root / "m.csv").write_text("session,gnss_config,smooth\npair,pair/config.toml,true\n")
    o = root / "out" / "pair"
    for argv in (["ingest", "--config", root / "pair/config.toml", "-o", o / "run.mcap"],
                 ["init", o / "run.mcap", "-o", o / "init.json"],
                 ["estimate", o / "run.mcap", "--init", o / "init.json", "--smooth", "-o", o / "states.mcap"]):
        r = CliRunner().invoke(main, ["-q", *map(str, argv)])
        assert r.exit_code == 0, (argv, r.output)
    meta = read_metadata(o / "states.mcap")
    assert [json.loads(r["options"])["smooth"] for r in meta.values() if "options" in r] == [True], meta.keys()
    (root / "out").rename(root / "reference")
    s = run_batch(root / "m.csv", root / "out", client=inproc)
    assert s["counts"] == {"sessions": 1, "done": 1}, s["failures"]
    (e,) = s["sessions"]
    assert e["integers_fixed"] == e["integers"] > 0 and e["rovers"]["rover"]["solution"] == "fixed"
    _assert_same_tree(root / "reference", root / "out", 3)


def test_gnss_sessions_on_windows_of_one_run_give_the_single_commands_bytes(tmp_path, inproc):
    """One GNSS RUN processed window by window (issue 29: a long record hour by hour, each session in the memory of
    its window): sessions on the same run_mcap with init_start_s / init_duration_s write what `cdgps init --start
    --duration` and `cdgps estimate` write."""
    root = tmp_path / "gnss"
    _cli("simulate-gnss", "--duration", "120", "--seed", "4", "-o", root / "pair")
    _cli("ingest", "--config", root / "pair/config.toml", "-o", root / "run.mcap")
    (root / "m.csv").write_text("session,run_mcap,init_start_s,init_duration_s\n"
                                "w0,run.mcap,0,60\nw1,run.mcap,60,\n")
    for w, window in (("w0", ("--start", 0, "--duration", 60)), ("w1", ("--start", 60))):
        o = root / "reference" / w
        _cli("init", root / "run.mcap", *window, "-o", o / "init.json")
        _cli("estimate", root / "run.mcap", "--init", o / "init.json", "-o", o / "states.mcap")
    s = run_batch(root / "m.csv", root / "out", client=inproc)
    assert s["counts"] == {"sessions": 2, "done": 2}, s["failures"]
    _assert_same_tree(root / "reference", root / "out", 4)
    inits = [json.loads((root / "out" / w / "init.json").read_text()) for w in ("w0", "w1")]
    assert [i["window"]["start_s"] for i in inits] == [0.0, 60.0]
    assert [i["rovers"]["rover"]["epochs"]["n_epochs_used"] for i in inits] == [60, 60]
