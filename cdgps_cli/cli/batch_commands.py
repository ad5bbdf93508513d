"""`cdgps batch`: many sessions on Dask (:mod:`cdgps_cli.pipeline.batch`)."""

from __future__ import annotations

from pathlib import Path

import click

from cdgps_cli.core import progress
from cdgps_cli.io.atomic import INTERRUPTED_EXIT, Terminated
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.cli.app import _echo, _warn, _say, _emit_json, main


@main.command("batch", short_help="Many sessions on Dask, resumable → batch.json")
@click.argument("manifest", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Campaign folder: OUTDIR/<session>/ per session, OUTDIR/batch.json and OUTDIR/index.html.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="A running dask scheduler: tcp://HOST:PORT or a scheduler file (default: a LocalCluster).")
@click.option("--cluster", "cluster_class", default=None, metavar="MODULE.CLASS",
              help="A dask cluster manager to start, e.g. dask_jobqueue.SLURMCluster (pip install 'cdgps[cluster]') "
                   "or distributed.LocalCluster; its options from --cluster-option and its own dask config "
                   "(jobqueue.yaml).")
@click.option("--cluster-option", "cluster_option", multiple=True, metavar="KEY=VALUE",
              help="A keyword of the --cluster class (repeatable): queue=normal, cores=2, memory=4GiB, "
                   "walltime=01:00:00, job_extra_directives='[\"--exclusive\"]' (VALUE is read as TOML, else text).")
@click.option("--print-job-script", is_flag=True,
              help="With a job-queue --cluster (dask-jobqueue): print the job script it would submit, and stop.")
@click.option("--workers", type=int, default=None,
              help="LocalCluster worker processes, one thread each (default: the number of cores); with --cluster "
                   "the workers asked of it (cluster.scale; default: its own options, at least 1).")
@click.option("--resume", is_flag=True,
              help="Skip the stages already done whose inputs, options and outputs are unchanged (sha256).")
@click.option("--retries", type=int, default=2, show_default=True,
              help="Times a task is tried again after a worker fault (an input error is not retried).")
@click.option("--dashboard", is_flag=True, help="LocalCluster: serve the dask dashboard on :8787.")
@click.option("--json", "as_json", is_flag=True, help="Print batch.json on stdout.")
@click.pass_context
def batch_cmd(ctx, manifest, out_dir, scheduler, cluster_class, cluster_option, print_job_script, workers, resume,
              retries, dashboard, as_json):
    """Run every session of a MANIFEST (CSV or TOML, docs/batch.md) through the stage commands on
    dask.distributed, one task per session-stage; same bytes as the single commands.

    \b
    Exit status:
      0  every session done (or up to date)
      2  bad manifest, option or OUTDIR, OUTDIR locked by another batch, scheduler or cluster
         unreachable: nothing run
      3  the batch ran to its end but some session failed (listed on stderr, in batch.json, index.html)
      4  the batch itself failed (e.g. the scheduler was lost): traceback in OUTDIR/batch-error.log;
         finished stages are recorded, --resume goes on from them
    130  interrupted (Ctrl-C): the sessions done are kept, --resume goes on from them
    """
    from cdgps_cli.pipeline.batch_dask import (EXIT_BATCH_FAILED, EXIT_SESSIONS_FAILED, job_script,
                                               parse_cluster_options, run_batch)

    if scheduler is not None and (workers is not None or dashboard):
        raise click.UsageError("--workers and --dashboard configure the LocalCluster; not with --scheduler")
    if cluster_class is not None and (scheduler is not None or dashboard):
        raise click.UsageError("--cluster starts a cluster: not with --scheduler or --dashboard")
    if cluster_option and cluster_class is None:
        raise click.UsageError("--cluster-option needs --cluster MODULE.CLASS")
    options = parse_cluster_options(cluster_option)
    if print_job_script:
        if cluster_class is None:
            raise click.UsageError("--print-job-script needs --cluster MODULE.CLASS (a dask-jobqueue class)")
        _echo(job_script(cluster_class, options).rstrip("\n"))
        return
    try:
        s = run_batch(manifest, out_dir, scheduler=scheduler, workers=workers, resume=resume, retries=retries,
                      dashboard=dashboard, cluster_class=cluster_class, cluster_options=options,
                      progress=None if ctx.obj.get("quiet") else progress.write,
                      warn=_warn)
    except KeyboardInterrupt:
        progress.close_all()
        click.echo(f"cdgps: batch interrupted (Ctrl-C); the sessions done are kept: run it again with --resume to go "
                   f"on ({Path(out_dir)})", err=True)
        ctx.exit(INTERRUPTED_EXIT)
    except (CdgpsError, click.exceptions.Exit, click.ClickException, Terminated):
        raise
    except Exception as exc:           # the batch layer itself, not a session (those are in batch.json)
        from cdgps_cli.io.atomic import is_no_room

        if isinstance(exc, OSError) and is_no_room(exc):
            raise
        _batch_failed(ctx, out_dir, exc, EXIT_BATCH_FAILED)
    c = s["counts"]
    _say(ctx, f"batch: {c['sessions']} sessions: " + ", ".join(f"{v} {k}" for k, v in c.items() if k != "sessions")
              + f" in {s['elapsed_s']:.1f} s on {s['workers']} workers → {Path(out_dir) / 'index.html'}")
    for f in s["failures"]:
        click.echo(f"cdgps: session {f['session']} failed: {f['error']}", err=True)
    if as_json:
        _emit_json(s)
    if s["failures"]:
        ctx.exit(EXIT_SESSIONS_FAILED)


def _batch_failed(ctx, out_dir, exc, code: int) -> None:
    """`cdgps batch` itself failed: one line on stderr, the traceback in OUTDIR/batch-error.log (when
    OUTDIR is a campaign folder), exit ``code``."""
    import traceback

    from cdgps_cli.pipeline import batch as B

    log = Path(out_dir) / B.ERROR_LOG
    where = ""
    if (Path(out_dir) / B.CAMPAIGN_FILE).is_file():
        try:
            log.write_text("".join(traceback.format_exception(exc)))
            where = f"; traceback in {log}"
        except OSError:
            pass
    progress.close_all()
    click.echo(f"cdgps: error: the batch itself failed: {type(exc).__name__}: {exc}{where}; the finished stages "
               f"are recorded (--resume goes on from them)", err=True)
    ctx.exit(code)
