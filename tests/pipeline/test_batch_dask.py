"""`cdgps batch` on a dask LocalCluster (cdgps_cli.pipeline.batch_dask), on three small simulated sessions:

* every output byte-identical to the single commands (run here through the CLI, by hand-written
  argument lists), on 2 workers with a worker killed mid-task and a task that fails twice, and on 1 worker;
* a task failing more often than --retries: the session reported with its message, never dropped;
* --resume skips exactly what is still valid and redoes what an option change touches.

--resume after kill -9 of the batch process and a GNSS session: tests/pipeline/test_batch_dask_resume.py
(a file of its own, so that pytest-xdist's ``--dist loadfile`` spreads the two).

Paths are recorded inside the outputs (RUN.mcap names its logs, STATES its RUN and INIT), so every
run writes into the same OUTDIR path and is compared with the reference, then moved away.
"""

from __future__ import annotations

import filecmp
import json
import os
import shutil

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.pipeline import batch as B
from cdgps_cli.pipeline.batch_dask import PROFILE_KEY, local_cluster, run_batch
from tests.pipeline._batch_campaign import CONFIG, DURATION_S, assert_same_tree as _assert_same_tree

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """Three simulated sessions, the manifest, and the reference outputs of the single commands."""
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation

    root = tmp_path_factory.mktemp("campaign")
    cfg = load_config(CONFIG)
    for i, name in enumerate(("s1", "s2", "s3")):
        write_simulation(simulate(cfg, SimOptions(duration_s=DURATION_S, seed=11 + i)), root / "logs" / name)
    shutil.copy(CONFIG, root / "logs" / "testbed.toml")
    manifest = root / "logs" / "campaign.csv"
    head = "session,receiver_csv,gyro_csv,config,time,stages,smooth,init_duration_s,date\n"
    rows = {"a": "a,s1/receiver.csv,s1/gyro.csv,testbed.toml,2026-11-01,{},true,10,2026-12-01\n",
            "b": "b,s2/receiver.csv,s2/gyro.csv,testbed.toml,2026-11-02,ingest init estimate,,10,\n",
            "c": "c,s3/receiver.csv,,testbed.toml,2026-11-03,ingest+init+estimate,true,10,\n"}
    # the campaign: a's report (it computes the spectra too), b and c to STATES.mcap
    manifest.write_text(head + rows["a"].format("ingest init estimate report") + rows["b"] + rows["c"])
    out = root / "out"
    L = root / "logs"
    o = {n: out / n for n in "abc"}
    commands = [
        ["ingest", L / "s1/receiver.csv", L / "s1/gyro.csv", "--config", L / "testbed.toml", "-o", o["a"] / "run.mcap"],
        ["init", o["a"] / "run.mcap", "--duration", "10", "-o", o["a"] / "init.json"],
        ["estimate", o["a"] / "run.mcap", "--init", o["a"] / "init.json", "--smooth", "-o", o["a"] / "states.mcap"],
        ["report", "spectrum", o["a"] / "states.mcap", "--gyro", o["a"] / "run.mcap", "--date", "2026-12-01",
         "-o", o["a"] / "report"],
        ["ingest", L / "s2/receiver.csv", L / "s2/gyro.csv", "--config", L / "testbed.toml", "-o", o["b"] / "run.mcap"],
        ["init", o["b"] / "run.mcap", "--duration", "10", "-o", o["b"] / "init.json"],
        ["estimate", o["b"] / "run.mcap", "--init", o["b"] / "init.json", "-o", o["b"] / "states.mcap"],
        ["ingest", L / "s3/receiver.csv", "--config", L / "testbed.toml", "-o", o["c"] / "run.mcap"],
        ["init", o["c"] / "run.mcap", "--duration", "10", "-o", o["c"] / "init.json"],
        ["estimate", o["c"] / "run.mcap", "--init", o["c"] / "init.json", "--smooth", "-o", o["c"] / "states.mcap"],
    ]
    for argv in commands:
        r = CliRunner().invoke(main, ["-q", *map(str, argv)])
        assert r.exit_code == 0, (argv, r.output)
    ref = root / "reference"
    out.rename(ref)
    return {"root": root, "manifest": manifest, "out": out, "ref": ref, "faults": root / "faults"}


@pytest.fixture(scope="module")
def client(campaign):
    """The batch's own LocalCluster (batch_dask.local_cluster) of 1, then 2 worker processes, one thread
    each, dashboard off, BLAS at one thread; the fault hook's folder in the workers' environment (an
    empty folder: no faults)."""
    campaign["faults"].mkdir()
    with local_cluster(1, env={B.FAULT_ENV: str(campaign["faults"])}) as cluster, distributed.Client(cluster) as c:
        c.cluster = cluster          # the first test runs on 1 worker, then the cluster is scaled to 2
        yield c


def _faults(campaign, *lines):
    folder = campaign["faults"]
    for f in folder.iterdir():
        f.unlink()
    if lines:
        (folder / "faults").write_text("\n".join(lines) + "\n")


def _attempts(campaign, session, stage) -> int:
    p = campaign["faults"] / f"{session}-{stage}.attempts"
    return len(p.read_text().split()) if p.exists() else 0


#: files of the campaign: a (run, init, states, report/ of 7 files), b and c (run, init, states)
CAMPAIGN_FILES = 3 + 7 + 3 + 3


def _set_aside(campaign, name):
    campaign["out"].rename(campaign["root"] / name)


def test_one_worker_gives_the_single_commands_bytes(campaign, client):
    # the batch's own cluster runs its workers without dask's profiler (its samples grew a worker's memory)
    import dask

    assert set(client.run(lambda: dask.config.get(PROFILE_KEY)).values()) == {False}
    s = run_batch(campaign["manifest"], campaign["out"], client=client, retries=0)
    assert s["workers"] == 1 and s["counts"] == {"sessions": 3, "done": 3}, s["failures"]
    _assert_same_tree(campaign["ref"], campaign["out"], CAMPAIGN_FILES)
    # as many sessions in flight as worker threads (batch_dask._submit_and_wait): one worker, one session at a time
    records = sorted(campaign["out"].glob(f"*/{B.RECORD_DIR}/*.json"), key=lambda p: p.stat().st_mtime_ns)
    order = [p.parent.parent.name for p in records]
    assert order == sorted(order), f"stages finished in the order {order}, not session by session"
    _set_aside(campaign, "run-1-worker")
    client.cluster.scale(2)
    client.wait_for_workers(2, timeout=120)


def test_two_workers_a_killed_worker_and_a_flaky_task_give_the_same_bytes(campaign, client):
    _faults(campaign, "b/init kill 1", "a/estimate raise 2")
    s = run_batch(campaign["manifest"], campaign["out"], client=client, retries=2)
    assert s["workers"] == 2 and s["counts"] == {"sessions": 3, "done": 3}, s["failures"]
    assert _attempts(campaign, "b", "init") == 2           # killed once, then done on a (restarted) worker
    assert _attempts(campaign, "a", "estimate") == 3       # failed twice, the third try succeeded
    _assert_same_tree(campaign["ref"], campaign["out"], CAMPAIGN_FILES)
    a = next(e for e in s["sessions"] if e["session"] == "a")
    assert a["stages"]["estimate"]["blas_threads"]["OPENBLAS_NUM_THREADS"] == "1"
    assert a["integers"] > 0 and 0 <= a["integers_fixed"] <= a["integers"]
    assert a["nis_per_dof"] > 0 and a["noise_sigma_m"] > 0 and len(a["modes"]) > 0
    assert {m["mode"] for m in a["modes"]} == {t["mode"] for t in s["trends"]}
    assert json.loads((campaign["out"] / "batch.json").read_text())["counts"] == s["counts"]
    html = (campaign["out"] / "index.html").read_text()
    assert 'href="a/report/report.html"' in html and "Mode trends" in html


def test_resume_skips_what_holds_and_redoes_what_changed(campaign, client):
    """(continues on the complete OUTDIR of the test above)"""
    _faults(campaign)
    s = run_batch(campaign["manifest"], campaign["out"], client=client, resume=True)
    assert s["counts"] == {"sessions": 3, "up to date": 3}
    text = campaign["manifest"].read_text()
    try:       # c without smoothing: c's estimate again, its ingest and init are still valid
        campaign["manifest"].write_text(text.replace("ingest+init+estimate,true", "ingest+init+estimate,false"))
        s = run_batch(campaign["manifest"], campaign["out"], client=client, resume=True)
        c = next(e for e in s["sessions"] if e["session"] == "c")
        assert {k: v["status"] for k, v in c["stages"].items()} == {"ingest": "skipped", "init": "skipped",
                                                                    "estimate": "done"}
        assert not filecmp.cmp(campaign["ref"] / "c/states.mcap", campaign["out"] / "c/states.mcap", shallow=False)
    finally:
        campaign["manifest"].write_text(text)
    # back to the reference options: c's estimate again; a touched log (same bytes) is not a change
    os.utime(campaign["root"] / "logs" / "s3" / "receiver.csv")
    s = run_batch(campaign["manifest"], campaign["out"], client=client, resume=True)
    c = next(e for e in s["sessions"] if e["session"] == "c")
    assert c["stages"]["estimate"]["status"] == "done" and c["stages"]["ingest"]["status"] == "skipped"
    _assert_same_tree(campaign["ref"], campaign["out"], CAMPAIGN_FILES)
    # an output changed behind the batch's back is redone; what reads it is not, as its bytes come back
    (campaign["out"] / "a" / "init.json").write_text("{}")
    s = run_batch(campaign["manifest"], campaign["out"], client=client, resume=True)
    a = next(e for e in s["sessions"] if e["session"] == "a")
    assert {k: v["status"] for k, v in a["stages"].items()} == {"ingest": "skipped", "init": "done",
                                                                "estimate": "skipped", "report": "skipped"}
    _assert_same_tree(campaign["ref"], campaign["out"], CAMPAIGN_FILES)
    other = campaign["manifest"].with_name("other.csv")
    other.write_text(text)
    with pytest.raises(CdgpsError, match="another batch manifest"):
        run_batch(other, campaign["out"], client=client, resume=True)
    _set_aside(campaign, "run-2-workers")


def test_a_task_failing_more_than_retries_is_reported_not_dropped(campaign, client):
    # the worker the test before killed is back (a loaded machine once had it restarting still: 1 worker of 2)
    client.wait_for_workers(2, timeout=120)
    _faults(campaign, "b/ingest raise 5")
    m = campaign["manifest"].with_name("failing.csv")
    lines = campaign["manifest"].read_text().splitlines()
    m.write_text("\n".join([lines[0], lines[2].replace("ingest init estimate", "ingest init")]) + "\n")
    out = campaign["root"] / "out-failing"
    s = run_batch(m, out, client=client, retries=1)
    assert _attempts(campaign, "b", "ingest") == 2
    assert s["counts"] == {"sessions": 1, "failed": 1}
    (b,) = s["sessions"]
    assert b["status"] == "failed" and "injected failure of b/ingest" in b["error"]
    assert b["stages"]["init"] == {"status": "not run", "reason": "ingest failed"}
    assert s["failures"] == [{"session": "b", "error": b["error"]}]
    assert "injected failure of b/ingest" in (out / "index.html").read_text()
    r = CliRunner().invoke(main, ["batch", str(m), "-o", str(out), "--resume", "--retries", "1",
                                  "--scheduler", client.scheduler.address])
    assert r.exit_code == 3 and "session b failed: ingest: InjectedFault: injected failure" in r.output
    _faults(campaign)                          # the fault gone, --resume does the session (scheduler file)
    # a scheduler file as `dask scheduler --scheduler-file` writes it (Client.write_scheduler_file fails on
    # this distributed version: tuple keys in its scheduler_info)
    (campaign["root"] / "scheduler.json").write_text(json.dumps({"type": "Scheduler",
                                                                 "address": client.scheduler.address}))
    r = CliRunner().invoke(main, ["batch", str(m), "-o", str(out), "--resume", "--json",
                                  "--scheduler", str(campaign["root"] / "scheduler.json")])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["counts"] == {"sessions": 1, "done": 1} and s["workers"] == 2
