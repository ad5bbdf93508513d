"""Command-line interface: thin click shells over the library functions.

User errors (:class:`CdgpsError`) are printed on stderr as ``cdgps: error: …`` without a traceback
and exit with status 2.  ``--json`` prints a machine-readable summary on stdout; human messages and
progress go to stderr and are silenced by ``--quiet``.
"""

from __future__ import annotations

import atexit
import gc
import json
import math
import sys
from contextlib import contextmanager
from pathlib import Path

import click

from cdgps_cli.config.options import (CONTROL_TUNED_WEIGHTS, CONTROL_WEIGHTS, ESTIMATE_DEFAULTS, GNSS_DEFAULTS,
                                      INIT_MAX_ITERATIONS, INIT_STARTS, RATIO_THRESHOLD, SPECTRA_DEFAULTS,
                                      TRACK_DEFAULTS, X_AXIS_AZIMUTH_DEG)
from cdgps_cli import __version__
from cdgps_cli.core import progress
from cdgps_cli.io.atomic import TERMINATED_EXIT, Terminated, sigterm_raises
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.states_layout import COVARIANCE_CHOICES as _STATES_COVARIANCE
from cdgps_cli.io.states_layout import DEFAULT_COVARIANCE as _STATES_DEFAULT_COVARIANCE
from cdgps_cli.io.states_layout import DEFAULT_PREVIEW_RATE_HZ as _STATES_PREVIEW_RATE_HZ
from cdgps_cli.cli.guard import GuardedCommand


def _no_collection_at_exit() -> None:
    """At interpreter exit, move every object to the collector's permanent generation (``gc.freeze``):
    the final collections then do not walk them all (the process frees its memory anyway).

    With numpy, scipy and pandas loaded the exit of ``cdgps estimate`` took 0.1–0.3 s of cyclic
    collection, ≈ 0.04 s without (docs/benchmarks/io.md).  Nothing cdgps writes depends on it: outputs
    are closed (and renamed into place) before the command returns, and Python flushes stdout/stderr
    and runs ``weakref.finalize``/``atexit`` callbacks whether or not objects are frozen.
    """
    gc.freeze()


atexit.register(_no_collection_at_exit)

_GC_THRESHOLDS = (100_000, 50, 100)
"""Cyclic-collector thresholds while a command runs (Python's default: 700, 10, 10).  The imports of
numpy/scipy/pandas and the per-epoch Python objects of the filter and the writers make hundreds of
thousands of objects that are not garbage; with the default first threshold the collector walks them
again and again (``cdgps estimate`` on 1 h of 10 Hz: about 0.15 s of 1.9 s, in 4 interleaved runs at
load 1).  Reference counting still frees everything at once; only cycles wait a little longer."""


def _quiet_after_command(ctx, param, value):
    """``-q`` given after a subcommand: the same as ``cdgps -q``."""
    if value:
        ctx.ensure_object(dict)["quiet"] = True
        progress.configure(enabled=False)


_QUIET_HELP = "No progress or human summaries on stderr (also accepted before the command)."


class _Command(GuardedCommand):
    """A subcommand that also accepts ``-q/--quiet`` after its name (``cdgps info X -q``); finite
    floats and outputs that are never an input (:class:`cdgps_cli.cli.guard.GuardedCommand`)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.params.append(click.Option(["-q", "--quiet"], is_flag=True, expose_value=False, is_eager=True,
                                        callback=_quiet_after_command, help=_QUIET_HELP))


class _Group(click.Group):
    command_class = _Command
    group_class = type                     # subgroups (``report``) are _Group too

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if not any(p.name == "quiet" for p in self.params):
            self.params.append(click.Option(["-q", "--quiet"], is_flag=True, expose_value=False, is_eager=True,
                                            callback=_quiet_after_command, help=_QUIET_HELP))

    def main(self, *args, **kwargs):
        """Run the command with the cyclic collector's first threshold at :data:`_GC_THRESHOLDS`
        (restored afterwards, for callers in the same process)."""
        before = gc.get_threshold()
        gc.set_threshold(*_GC_THRESHOLDS)
        try:
            return super().main(*args, **kwargs)
        finally:
            gc.set_threshold(*before)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except CdgpsError as exc:
            _fail(ctx, str(exc))
        except BrokenPipeError:                 # stdout read by `| head` that has exited
            _quiet_broken_pipe(ctx)
        except Terminated:                      # SIGTERM: temporaries already removed on the way up
            progress.close_all()
            click.echo("cdgps: terminated (SIGTERM); no partial output left", err=True)
            ctx.exit(TERMINATED_EXIT)
        except MemoryError:                     # last line of defence (inputs are bounded first)
            _fail(ctx, "out of memory: the inputs or options ask for more memory than this machine has "
                       "(a shorter --duration or a smaller input)")
        except OSError as exc:                  # last line of defence: a full device while writing
            from cdgps_cli.io.atomic import is_no_room, output_error

            if not is_no_room(exc):
                raise
            _fail(ctx, str(output_error(exc.filename or "an output", exc)))


def _fail(ctx, message: str) -> None:
    """Print a user error (no traceback) and exit with status 2."""
    progress.close_all()
    click.echo(f"cdgps: error: {message}", err=True)
    ctx.exit(2)


#: exit status after stdout was closed by its reader: 128 + SIGPIPE, as a shell reports a program
#: killed by SIGPIPE (``cdgps info X --json | head -1``); nothing is printed
BROKEN_PIPE_EXIT = 141


def _quiet_broken_pipe(ctx) -> None:
    """Exit quietly when the reader of stdout has gone; stdout points to /dev/null afterwards so the
    interpreter's final flush does not complain either."""
    import os

    progress.close_all()
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):              # no real stdout (library use, test runner)
        pass
    ctx.exit(BROKEN_PIPE_EXIT)


def _echo(text: str) -> None:
    """Print command output on stdout; a full device there is a user error naming stdout."""
    try:
        click.echo(text)
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise CdgpsError(f"standard output: cannot write: {exc.strerror or exc} (is it redirected to a full "
                         f"device?)") from None


def _warn(msg: str) -> None:
    """One voice for warnings (issue 32): ``cdgps: warning: …`` on stderr, also with --quiet (a warning
    is about the data or the result, not progress)."""
    progress.write(f"cdgps: warning: {msg}")


def _say(ctx, msg: str) -> None:
    if not ctx.obj.get("quiet"):
        progress.write(msg)


def _output_option(dest: str, help: str, *, directory: bool = False, old: tuple = ()):
    """The one spelling of every output, ``-o/--output``; ``old`` spellings (``--out``, ``--csv``)
    are still accepted for older scripts and named in the help text, not listed as options."""
    return click.option("-o", "--output", *old, dest, cls=_AliasedOption, aliases=old, required=True,
                        type=click.Path(file_okay=False) if directory else click.Path(dir_okay=False),
                        help=help.rstrip(".") + (f" (older spelling {', '.join(old)} still accepted)." if old else "."))


class _AliasedOption(click.Option):
    """An option whose older spellings parse but do not show in the usage line and help."""

    def __init__(self, *args, aliases=(), **kwargs):
        super().__init__(*args, **kwargs)
        self.aliases = tuple(aliases)

    def get_help_record(self, ctx):
        shown, self.opts = self.opts, [o for o in self.opts if o not in self.aliases]
        try:
            return super().get_help_record(ctx)
        finally:
            self.opts = shown


def _named_by_flags(build, flags: dict):
    """``build()``, with the library's field names in its CdgpsError replaced by the command-line
    flags the user gave (``mask_deg must be in [0, 90)`` → ``--mask-deg must be in [0, 90)``)."""
    import re

    try:
        return build()
    except CdgpsError as exc:
        msg = str(exc)
        for field, flag in flags.items():
            msg = re.sub(rf"(?<![\w-]){re.escape(field)}(?!\w)", flag, msg)
        raise CdgpsError(msg) from None


def _emit_json(data: dict) -> None:
    _echo(json.dumps(data, indent=2, sort_keys=False))


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="cdgps")
@click.option("--quiet", "-q", is_flag=True, help="No progress or human summaries on stderr.")
@click.pass_context
def main(ctx, quiet):
    """cdgps: carrier-phase GPS sensing of flexible structures.

    Stages, chained through files: simulate (or your own logs) → ingest → RUN.mcap → init →
    estimate → spectra → report.  See README.md.
    """
    ctx.ensure_object(dict)
    ctx.obj["quiet"] = quiet
    progress.configure(enabled=not quiet)
    ctx.call_on_close(lambda: progress.configure(enabled=False))   # library use stays silent
    ctx.with_resource(sigterm_raises())     # SIGTERM cleans up as SIGINT does (cdgps_cli.io.atomic)


@main.command(short_help="Simulate a structure run → receiver/gyro/truth CSV")
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--duration", "duration_s", type=float, default=60.0, show_default=True, help="Seconds to simulate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (same seed → identical files).")
@click.option("--scenario", type=click.Choice(["free", "static", "pulse", "slew"]), default="free", show_default=True,
              help="free vibration; static (motion, then rest at the surveyed angle); pulse (Fig. 9 thruster pulse); "
                   "slew (Fig. 11, needs --controller).")
@click.option("--noise-m", "phase_sigma_m", type=float, default=None, help="White phase noise, metres (default: config [simulation]).")
@click.option("--multipath-m", "multipath_sigma_m", type=float, default=None, help="Slow multipath sigma, metres (default: config).")
@click.option("--slip", "slips", multiple=True, metavar="ANT:TX:TIME_S:CYCLES", help="Inject a cycle slip (repeatable).")
@click.option("--outage", "outages", multiple=True, metavar="TX:START_S:DURATION_S", help="Lose a transmitter for a while (repeatable).")
@click.option("--random-slips", type=int, default=0, show_default=True, help="Number of random cycle slips to inject.")
@click.option("--disturbance-scale", type=float, default=None,
              help="True disturbance as a fraction of the config's process noise (default: config; 1 = filter model).")
@click.option("--controller", "gains_json", default=None, type=click.Path(dir_okay=False),
              help="Close the loop with this GAINS.json (from `cdgps control design`): EKF on the carrier phase, "
                   "LQR, PWPF modulators, on/off thrusters (pulse or slew scenario).")
@click.option("--no-vibration-control", is_flag=True,
              help="With --controller: the rigid-body-only regulator of Fig. 12 (vibration poles left open loop).")
@click.option("--feedback", type=click.Choice(["gps", "truth"]), default="gps", show_default=True,
              help="With --controller: feed back the EKF's estimate, or the true state (full-state feedback).")
@click.option("--slew-reference", type=click.Choice(["profile", "shaped-step", "step"]), default="profile", show_default=True,
              help="With --controller, slew: a bang-bang angle profile with feed-forward thrust, the paper's step command through the controller's rate- and acceleration-limited command filter (no feed-forward), or the raw step.")
@click.option("--noise-scale", "noise_scales", multiple=True, metavar="NAME:FACTOR",
              help="Multiply the white phase noise of every channel of a rover antenna or transmitter (repeatable).")
@_output_option("out_dir", "Output directory.", directory=True, old=("--out",))
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def simulate(ctx, config, duration_s, seed, scenario, phase_sigma_m, multipath_sigma_m, slips, outages,
             random_slips, disturbance_scale, noise_scales, gains_json, no_vibration_control, feedback,
             slew_reference, out_dir, as_json):
    """Simulate a structure run: receiver.csv, gyro.csv, truth.csv, truth.json (+ actuators.csv)."""
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.sim.structure import SimOptions, parse_noise_scale, parse_outage, parse_slip, simulate as run_sim, write_simulation

    cfg = load_config(config)
    opt = SimOptions(duration_s=duration_s, seed=seed, scenario=scenario, phase_sigma_m=phase_sigma_m,
                     multipath_sigma_m=multipath_sigma_m, slips=[parse_slip(s) for s in slips],
                     outages=[parse_outage(o) for o in outages], random_slips=random_slips,
                     disturbance_scale=disturbance_scale, noise_scale=dict(parse_noise_scale(t) for t in noise_scales))
    if gains_json is None and (no_vibration_control or feedback != "gps" or slew_reference != "profile"):
        raise CdgpsError("--no-vibration-control, --feedback and --slew-reference need --controller GAINS.json")
    gains = None
    if gains_json is not None:
        from cdgps_cli.io.gains_file import read_gains

        gains = read_gains(gains_json, config)          # checked before any work
    _say(ctx, f"simulating {cfg.name}: {scenario}, {duration_s:g} s, seed {seed} …")
    with progress.stage("simulating"):
        if gains is None:
            sim = run_sim(cfg, opt)
        else:
            from cdgps_cli.pipeline.closed_loop import simulate_closed_loop

            sim, loop = simulate_closed_loop(cfg, opt, gains, vibration_control=not no_vibration_control,
                                             feedback=feedback, slew_reference_kind=slew_reference)
            if loop.saturated_fraction > 0.2:
                _warn(f"the jets were asked for more than their maximum force in "
                               f"{100 * loop.saturated_fraction:.0f}% of jet-periods; the gain asks for more authority "
                               f"than the thrusters have (`cdgps control design --weights tuned` or a smaller --qx, docs/control.md)")
            if loop.estimator.get("met") is False:
                _warn("the in-loop estimator cannot be made "
                               f"{loop.estimator['separation']:g}x faster than this regulator ({loop.estimator['rule']}); "
                               "the estimate lags the regulator (`cdgps control design --weights tuned` or a smaller --qx)")
    summary = write_simulation(sim, out_dir)
    _say(ctx, f"wrote {summary['receiver_rows']} phase rows, {summary['gyro_rows']} gyro rows, "
              f"{summary['slips']} slip/relock events to {out_dir}/")
    if not cfg.gyro_names:
        _say(ctx, "  the config declares no gyros: gyro.csv has the header only (ingest accepts it as it is)")
    if as_json:
        _emit_json(summary)


@main.command(short_help="Validate logs and write one RUN.mcap")
@click.argument("receiver_csv", required=False, type=click.Path(dir_okay=False))
@click.argument("gyro_csv", required=False, type=click.Path(dir_okay=False))
@click.option("--actuators", "actuator_csv", type=click.Path(dir_okay=False),
              help="Thruster command log CSV (or a quoted glob pattern of consecutive files).")
@click.option("--config", "config", type=click.Path(dir_okay=False),
              help="Structure config TOML (CSV logs), or a GNSS run config (RINEX/UBX; docs/gnss-pipeline.md).")
@click.option("--rinex", "rinex", multiple=True, metavar="ANTENNA=FILE",
              help="GNSS: RINEX 2.1x/3.x observation file of an antenna (plain, gzip, Hatanaka); repeatable. An antenna "
                   "repeated, or ANTENNA='PATTERN' (quoted glob), gives its consecutive files: one record.")
@click.option("--ubx", "ubx", multiple=True, metavar="ANTENNA=FILE",
              help="GNSS: u-blox UBX log with RXM-RAWX; repeatable (several files per antenna as for --rinex).")
@click.option("--nav", "nav", multiple=True, type=click.Path(dir_okay=False), help="GNSS: RINEX GPS navigation file; repeatable.")
@click.option("--master", "master", default=None, help="GNSS: the reference antenna at a known position.")
@click.option("--strict", is_flag=True,
              help="GNSS: refuse a UBX log with lost data (frames failing the checksum, undecodable RXM-RAWX, bytes "
                   "skipped between frames, a truncated tail) instead of reporting it with a warning.")
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="RUN.mcap to write.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def ingest(ctx, receiver_csv, gyro_csv, actuator_csv, config, rinex, ubx, nav, master, strict, output, as_json):
    """Validate logs and write one self-contained RUN.mcap.

    \b
    Structure runs:  cdgps ingest receiver.csv [gyro.csv] --config STRUCTURE.toml -o RUN.mcap
    GNSS runs:       cdgps ingest --rinex A=a.obs --rinex B=b.obs --nav brdc.nav [--ubx C=c.ubx]
                                  [--master A] [--config GNSS.toml] -o RUN.mcap
                     cdgps ingest --config GNSS.toml -o RUN.mcap   (files listed in the config)
    Many files per antenna (hourly/daily logs) as one record:
                     cdgps ingest --rinex A='a_*.obs' --rinex B=b1.obs --rinex B=b2.obs ... -o RUN.mcap
                     cdgps ingest 'receiver_*.csv' 'gyro_*.csv' --config STRUCTURE.toml -o RUN.mcap

    
    Several files of one antenna (the option repeated, or a quoted glob pattern) are joined in time
    order of their first epochs (not their names): an epoch repeated by a later file is kept once
    (warning naming both files), gaps between files are reported (summary, --json "joins", warnings);
    files of another receiver, marker, antenna, L1 signal or rate are refused (docs/gnss-pipeline.md).
    """
    gnss = bool(rinex or ubx or nav or master)
    if not gnss and config and receiver_csv is None:
        from cdgps_cli.config.structure import config_kind

        try:
            gnss = config_kind(Path(config).read_text(errors="replace")) == "gnss"
        except OSError as exc:
            raise CdgpsError(f"{config}: cannot read config: {exc.strerror}") from None
    if gnss:
        if receiver_csv or gyro_csv or actuator_csv:
            raise CdgpsError("CSV logs and GNSS receiver files (--rinex/--ubx/--nav/--master, or a GNSS config) cannot be "
                             "mixed in one ingest")
        _ingest_gnss(ctx, config, rinex, ubx, nav, master, output, as_json, strict)
        return
    if strict:
        raise click.UsageError("--strict applies to GNSS receiver files (UBX logs given with --ubx or in a GNSS config)")
    if receiver_csv is None:
        raise click.UsageError("Missing argument 'RECEIVER_CSV' (or give GNSS files with --rinex/--ubx).")
    if config is None:
        raise click.UsageError("Missing option '--config'.")
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.pipeline.ingest import ingest_structure

    cfg = load_config(config)
    _say(ctx, f"ingesting {receiver_csv}" + (f" + {gyro_csv}" if gyro_csv else "") + f" with {cfg.name} …")
    s = ingest_structure(cfg, receiver_csv, output, gyro_csv, actuator_csv)
    _say(ctx, f"wrote {output}: {s['phase_messages']} epochs ({s['start_s']:g}–{s['end_s']:g} s), "
              f"{s['channels']} channels, {len(s['gaps'])} gaps, {s['lock_restarts']} lock restarts")
    if gyro_csv and s["gyro_rows"] == 0:
        _say(ctx, f"  {gyro_csv}: header only (the config declares no gyros): no gyro topic")
    for g in s["gaps"][:10]:
        _say(ctx, f"  gap {g['start_s']:g}–{g['end_s']:g} s ({g['missing_epochs']} epochs missing)")
    for k, j in s.get("joins", {}).items():
        _say(ctx, f"  {k}: {len(j['files'])} files joined in time order: " + ", ".join(f["file"] for f in j["files"]))
    for w in s.get("warnings", []):
        _warn(w)
    if as_json:
        _emit_json(s)


def _parse_named(items, option: str, what: str = "antenna", form: str = "ANTENNA=FILE") -> dict:
    """NAME=FILE options (--rinex/--ubx) → {name: path}; ``what`` and ``form`` word the messages."""
    out = {}
    for it in items:
        name, sep, path = it.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise CdgpsError(f"{option} expects {form} (e.g. 3040=30400920.05o), got {it!r}")
        if name.strip() in out:
            raise CdgpsError(f"{option}: {what} {name.strip()!r} given twice")
        out[name.strip()] = path.strip()
    return out


def _parse_named_files(items, option: str) -> dict:
    """ANTENNA=FILE options of ``ingest`` (--rinex/--ubx) → {antenna: [file or pattern, …]}: an antenna
    repeated, or a quoted glob pattern, gives its consecutive files (joined into one record)."""
    out: dict = {}
    for it in items:
        name, sep, path = it.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise CdgpsError(f"{option} expects ANTENNA=FILE or ANTENNA='PATTERN' (e.g. 3040=30400920.05o, "
                             f"rover='rover_*.obs'), got {it!r}")
        out.setdefault(name.strip(), []).append(path.strip())
    return out


def _grid_note(c: dict | None) -> str:
    """' (of N rover epochs: K bridged to a master epoch up to A s away; M not used: reasons)' for a
    pair (an ingest summary entry with ``pairing``, or the pairing summary itself), or ''."""
    p = (c.get("pairing") if c and "pairing" in c else c) or {}
    parts = []
    if p.get("bridged"):
        parts.append(f"{p['bridged']} bridged to a master epoch up to {p['max_age_s']:.3g} s away")
    if p.get("dropped"):
        parts.append(f"{sum(p['dropped'].values())} not used: " + ", ".join(f"{k} {why}" for why, k in p["dropped"].items()))
    return f" (of {p['rover_epochs']} rover epochs: {'; '.join(parts)})" if parts else ""


def _ingest_gnss(ctx, config, rinex, ubx, nav, master, output, as_json, strict=False):
    from cdgps_cli.config.structure import load_gnss_config, parse_gnss_config
    from cdgps_cli.io.gnss_run import default_config_text
    from cdgps_cli.pipeline.gnss_ingest import ingest_gnss

    rx, ub = _parse_named_files(rinex, "--rinex"), _parse_named_files(ubx, "--ubx")
    if config:
        cfg = load_gnss_config(config)
    else:
        if not (rx or ub):
            raise CdgpsError("give receiver files with --rinex/--ubx ANTENNA=FILE, or a GNSS config (--config) listing them")
        files = {n: ("rinex", p) for n, p in rx.items()} | {n: ("ubx", p) for n, p in ub.items()}
        if master is None and len(files) > 1:
            raise CdgpsError(f"--master is required: which of {', '.join(files)} is the reference receiver at a known "
                             f"position (or give a --config naming it)")
        if master is not None and master not in files:
            raise CdgpsError(f"master {master!r} is not one of the receivers given: {', '.join(files)}")
        cfg = parse_gnss_config(default_config_text(files, list(nav), master), "<generated config>")
    s = ingest_gnss(cfg, output, rinex=rx or None, ubx=ub or None, nav_paths=list(nav) if nav else None, master=master,
                    progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)), strict=strict)
    for n, g in s["integrity"].items():        # lost data is reported even with --quiet
        if g["problems"]:
            _warn(f"{g['file']} ({n}): corrupt UBX data, skipped: {', '.join(g['problems'])}; "
                  f"{g['n_frames']} frames read (the run lacks what was lost; 'ingest --strict' refuses such a log)")
        if g.get("other_protocols"):
            _say(ctx, f"  {g['file']} ({n}): skipped other protocols' frames between the UBX frames: {g['other_protocols']}")
    _say(ctx, f"wrote {output}: GNSS run {s['config']}, master {s['master']}, {len(s['receivers'])} receiver(s), "
              f"{s['ephemerides']} ephemerides, {cfg.displacement} displacement model")
    for r in s["receivers"]:
        _say(ctx, f"  {r['name']:<8} {r['format']:<5} {r['file']}: {r['epochs']} epochs {r['first']} – {r['last']} "
                  f"({r['interval_s']:g} s), {r['satellites']} satellites, {r['phase_rows']} phases, {r['slips']} slips, "
                  f"{r['half_cycle_rows']} half-cycle rows")
    for n, c in s["common_epochs"].items():
        _say(ctx, f"  {n}: {c['common_epochs']} epochs in common with {s['master']}" + _grid_note(c))
    for w in s["warnings"]:
        _warn(w)
    if as_json:
        _emit_json(s)


def _write_json_atomic(path: str, data: dict) -> None:
    from cdgps_cli.io.atomic import write_bytes_atomic

    write_bytes_atomic(path, (json.dumps(data, indent=2) + "\n").encode())


def _placement_options(f):
    """--x-axis-azimuth-deg and --receiver of a GNSS run with --structure (init and estimate)."""
    f = click.option("--receiver", "receiver_map", multiple=True, metavar="ANTENNA=RECEIVER",
                     help="With --structure: the receiver of a structure antenna (repeatable; default: the same name).")(f)
    return click.option("--x-axis-azimuth-deg", "x_axis_azimuth_deg", type=float, default=X_AXIS_AZIMUTH_DEG, show_default=True,
                        help="With --structure: azimuth of the structure x axis, degrees clockwise from north "
                             "(90: x east, y north).")(f)


@main.command("init", short_help="Batch bias init and LAMBDA integers → INIT.json")
@click.argument("run_mcap", type=click.Path(dir_okay=False))
@click.option("--start", "start_s", type=float, default=None, help="Window start, s (default: automatic).")
@click.option("--duration", "duration_s", type=float, default=None, help="Window length, s (default: 60 s).")
@click.option("--no-process-noise", is_flag=True, help="1995 variant: no process noise in the batch.")
@click.option("--float-only", is_flag=True, help="Do not fix integers (float biases only).")
@click.option("--ratio", "ratio_threshold", type=float, default=RATIO_THRESHOLD, show_default=True, help="Ratio-test threshold.")
@click.option("--no-partial", is_flag=True, help="Do not try partial integer fixing when the full set fails.")
@click.option("--starts", type=int, default=INIT_STARTS, show_default=True, help="Initial guesses of the rigid angle (cold start).")
@click.option("--max-iterations", type=int, default=INIT_MAX_ITERATIONS, show_default=True, help="Gauss-Newton iteration cap.")
@click.option("--sigma-m", type=float, default=None,
              help="Measurement noise for every channel, m (default: estimated per channel from the data, prior from the config).")
@click.option("--multipath-sigma-m", "multipath_sigma_m", type=float, default=None,
              help="Multipath modelled as a first-order Gauss-Markov state per channel with this sigma, m "
                   "(default: the config's [model] multipath_sigma_m; when that is 0 too, switched on "
                   "automatically with sigma and tau fitted to the residuals if they are time-correlated, with a "
                   "WARNING; 0 = not modelled). Recorded in INIT.json and used by estimate.")
@click.option("--multipath-tau-s", "multipath_time_constant_s", type=float, default=None,
              help="Time constant of that multipath, s (default: the config's [model] multipath_time_constant_s).")
@click.option("--structure", "structure", default=None, type=click.Path(dir_okay=False),
              help="GNSS runs: also the model-aided batch initialization of this structure's modal state on the "
                   "first 60 s of double differences (INIT.json 'modal_init', used by 'estimate --structure').")
@_placement_options
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="INIT.json to write.")
@click.option("--json", "as_json", is_flag=True, help="Also print INIT.json on stdout.")
@click.pass_context
def init_cmd(ctx, run_mcap, start_s, duration_s, no_process_noise, float_only, ratio_threshold, no_partial,
             starts, max_iterations, sigma_m, multipath_sigma_m, multipath_time_constant_s, output, as_json,
             structure=None, x_axis_azimuth_deg=X_AXIS_AZIMUTH_DEG, receiver_map=()):
    """Batch bias initialization (Eq. 9-15) with LAMBDA integer fixing → INIT.json.

    On a GNSS run (RINEX/UBX receivers): float DD solution, LAMBDA integers (ratio test, partial
    fixing) and the fixed static displacement of every rover → INIT.json (docs/gnss-pipeline.md).
    """
    import hashlib

    from cdgps_cli.io.file_checks import GNSS_RUN, RUNS, require_kind

    if require_kind(run_mcap, RUNS, "RUN_MCAP") == GNSS_RUN:      # (the file's metadata read once)
        _init_gnss(ctx, run_mcap, float_only, ratio_threshold, no_partial, output, as_json,
                   structure=(structure, x_axis_azimuth_deg, receiver_map) if (structure or receiver_map) else None,
                   structure_only={"--start": start_s is not None, "--duration": duration_s is not None,
                                   "--no-process-noise": no_process_noise, "--sigma-m": sigma_m is not None,
                                   "--starts": starts != INIT_STARTS, "--max-iterations": max_iterations != INIT_MAX_ITERATIONS,
                                   "--multipath-sigma-m": multipath_sigma_m is not None,
                                   "--multipath-tau-s": multipath_time_constant_s is not None})
        return
    from cdgps_cli.estimation.initializer import InitOptions, initialize
    from cdgps_cli.io.run import read_run

    if structure is not None or receiver_map:
        raise CdgpsError("--structure/--receiver apply to GNSS runs (from 'cdgps ingest --rinex/--ubx'); a structure "
                         "run's RUN.mcap already names its structure config")
    run = read_run(run_mcap)
    opt = InitOptions(start_s=start_s, duration_s=duration_s, process_noise=not no_process_noise,
                      fix_integers=not float_only, ratio_threshold=ratio_threshold, partial=not no_partial,
                      starts=starts, max_iterations=max_iterations, sigma_m=sigma_m,
                      multipath_sigma_m=multipath_sigma_m, multipath_time_constant_s=multipath_time_constant_s,
                      progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)))
    res = initialize(run, opt)
    res["run_sha256"] = hashlib.sha256(Path(run_mcap).read_bytes()).hexdigest()
    res.pop("elapsed_s", None)          # keep INIT.json byte-identical across runs
    _write_json_atomic(output, res)
    n_seg = len(res["biases"])                      # one bias (and integer) per lock segment
    n_ch = sum(1 for b in res["biases"] if b["current"])
    ratio = res["ratio"] if isinstance(res["ratio"], str) or res["ratio"] is None else f"{res['ratio']:.2f}"
    _say(ctx, f"INIT: {n_ch} channels, {n_seg} bias segments, {res['n_fixed']} of {n_seg} segment integers fixed, ratio {ratio}, "
              f"{res['iterations']} iterations, cost/dof {res['cost_per_dof']:.3f}, "
              f"σ {res['sigma_m'] * 1000:.2f} mm ({res['noise']['source'].split(' (')[0]})"
              + (f", multipath Gauss–Markov σ {res['multipath']['sigma_m'] * 1000:.2f} mm τ "
                 f"{res['multipath']['time_constant_s']:g} s" if "multipath" in res else "") + f" → {output}")
    for w in res["noise"].get("warnings", []):
        _warn(w)
    if as_json:
        _emit_json(res)


@main.command(short_help="EKF (Eq. 16-23) [+ RTS smoother] → STATES.mcap")
@click.argument("run_mcap", type=click.Path(dir_okay=False))
@click.option("--init", "init_json", required=True, type=click.Path(dir_okay=False), help="INIT.json from 'cdgps init'.")
@click.option("--smooth", is_flag=True, help="Add a Rauch-Tung-Striebel smoothing pass (post-processing).")
@click.option("--biases", type=click.Choice(["fixed", "states"]), default="fixed", show_default=True,
              help="fixed: biases from INIT; states: biases in the filter state (1995 variant).")
@click.option("--sigma-m", type=float, default=None, help="Measurement noise, m (default: INIT's).")
@click.option("--nis-probability", type=float, default=ESTIMATE_DEFAULTS["nis_probability"], show_default=True, help="Chi-square level of the NIS test.")
@click.option("--outlier-sigma", type=float, default=ESTIMATE_DEFAULTS["outlier_sigma"], show_default=True, help="Innovation outlier threshold (sigmas).")
@click.option("--process-noise-scale", type=float, default=ESTIMATE_DEFAULTS["process_noise_scale"], show_default=True,
              help="Multiplies the config's process-noise standard deviations (Q x scale^2): below 1 for a "
                   "structure at rest or only lightly disturbed (static survey), above 1 for stronger excitation.")
@click.option("--rest", "rest", multiple=True, metavar="START:END",
              help="Static mode: the structure is declared at rest from START to END seconds (END may be left "
                   "out: to the end of the log); there the process noise is further multiplied by "
                   "--rest-process-noise-scale, so the filter averages instead of following. Repeatable. "
                   "'--rest auto': segments found from the data (zero-velocity test on the modal velocities).")
@click.option("--rest-process-noise-scale", type=float, default=ESTIMATE_DEFAULTS["rest_process_noise_scale"], show_default=True,
              help="Process-noise standard-deviation factor inside --rest segments.")
@click.option("--rest-retry-s", type=float, default=ESTIMATE_DEFAULTS["rest_retry_s"], show_default=True,
              help="When the data show motion inside a --rest segment, the filter leaves static mode and tries "
                   "it again this many seconds later (0: not again in that segment).")
@click.option("--rest-window-s", type=float, default=ESTIMATE_DEFAULTS["rest_window_s"], show_default=True,
              help="--rest auto: sliding window of the zero-velocity chi-square test, s.")
@click.option("--rest-dwell-s", type=float, default=ESTIMATE_DEFAULTS["rest_dwell_s"], show_default=True,
              help="--rest auto: the test must pass this long before rest is entered, s.")
@click.option("--allow-other-run", is_flag=True,
              help="Use an INIT.json made from another run than RUN_MCAP (its run_sha256 differs); echoed in the "
                   "summary and the STATES metadata. Without it such a pairing is refused.")
@click.option("--structure", "structure", default=None, type=click.Path(dir_okay=False),
              help="GNSS runs: a structure config (docs/config-format.md) whose modal model is estimated from the "
                   "double differences instead of the rover displacements (docs/gnss-pipeline.md).")
@_placement_options
@click.option("--covariance", type=click.Choice(_STATES_COVARIANCE), default=_STATES_DEFAULT_COVARIANCE,
              show_default=True,
              help="What STATES.mcap holds per epoch: modal = the states xi and the modal-position covariance P_xi "
                   "of the estimate (what evaluate's NEES, export --points and report static use; the forward "
                   "filter of a --smooth run: its 1-sigma only); full = also the rates xidot of every epoch, the "
                   "whole state covariance P of both series, and P_xi in the JSON messages.")
@click.option("--foxglove-rate-hz", type=float, default=None,
              help="Rate of the Foxglove JSON channels (/cdgps/state, angles_deg, residuals), Hz; 0: every epoch "
                   "(slow to write, large). Default: from the config's highest mode (at least "
                   f"{_STATES_PREVIEW_RATE_HZ:g} Hz, the mode inside the preview's passband). The motion is "
                   "low-pass filtered before decimation, so no mode shows at a false frequency. The packed "
                   "arrays that cdgps reads hold every epoch.")
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="STATES.mcap to write.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def estimate(ctx, run_mcap, init_json, smooth, biases, sigma_m, nis_probability, outlier_sigma, process_noise_scale,
             output, as_json, rest=(), rest_process_noise_scale=ESTIMATE_DEFAULTS["rest_process_noise_scale"],
             rest_retry_s=ESTIMATE_DEFAULTS["rest_retry_s"], structure=None, x_axis_azimuth_deg=X_AXIS_AZIMUTH_DEG,
             receiver_map=(), rest_window_s=3.0, rest_dwell_s=2.0, allow_other_run=False,
             covariance=_STATES_DEFAULT_COVARIANCE, foxglove_rate_hz=None):
    """Extended Kalman filter (Eq. 16-23) [+ RTS smoother] over a RUN from INIT → STATES.mcap.

    On a GNSS run: per-epoch rover displacement states <ant>_e/_n/_u with 1σ from INIT's
    integers (static: the batch solution; random_walk: Kalman filter [+ RTS smoother]), plus
    single-epoch solutions, DD residuals and slip/reference events (docs/gnss-pipeline.md).
    """
    from cdgps_cli.io.file_checks import GNSS_RUN, RUNS, require_kind

    if require_kind(run_mcap, RUNS, "RUN_MCAP") == GNSS_RUN:      # (the file's metadata read once)
        with _init_named(init_json):
            _estimate_gnss(ctx, run_mcap, init_json, smooth, output, as_json,
                           structure_only={"--biases": biases != "fixed", "--sigma-m": sigma_m is not None,
                                           "--nis-probability": nis_probability != 0.999, "--outlier-sigma": outlier_sigma != 6.0,
                                           "--process-noise-scale": process_noise_scale != 1.0,
                                           "--rest": bool(rest),
                                           "--rest-process-noise-scale": rest_process_noise_scale != 0.005,
                                           "--rest-retry-s": rest_retry_s != 1.0,
                                           "--rest-window-s": rest_window_s != 3.0, "--rest-dwell-s": rest_dwell_s != 2.0},
                           structure=structure, x_axis_azimuth_deg=x_axis_azimuth_deg, receiver_map=receiver_map,
                           allow_other_run=allow_other_run)
        return
    if foxglove_rate_hz is not None and not (foxglove_rate_hz >= 0 and math.isfinite(foxglove_rate_hz)):
        raise CdgpsError(f"--foxglove-rate-hz must be a finite rate >= 0 (0: every epoch), got {foxglove_rate_hz:g}")
    if structure is not None or receiver_map:
        raise CdgpsError("--structure/--receiver apply to GNSS runs (from 'cdgps ingest --rinex/--ubx'); a structure "
                         "run already has its config")
    from cdgps_cli.estimation.filter import EstimateOptions, estimate as run_ekf, validate_rest_segments
    from cdgps_cli.io.run import read_run
    from cdgps_cli.io.scratch import DiskHistory
    from cdgps_cli.pipeline.estimate_outputs import write_states

    if not 0.5 < nis_probability < 1.0:
        raise CdgpsError(f"--nis-probability must be in (0.5, 1), got {nis_probability:g}")
    from cdgps_cli.io.file_checks import read_init_json

    init, init_text = read_init_json(init_json)
    pairing = _check_pairing(ctx, init, init_json, run_mcap, allow_other_run)
    rest_auto = any(r.strip().lower() == "auto" for r in rest)
    if rest_auto and len(rest) > 1:
        raise CdgpsError("--rest auto cannot be combined with declared --rest START:END segments")
    rest_segments = () if rest_auto else tuple(_parse_rest(r) for r in rest)
    validate_rest_segments(rest_segments, rest_process_noise_scale, rest_retry_s)
    if rest_auto:
        from cdgps_cli.estimation.rest import validate_detector

        validate_detector(rest_window_s, rest_dwell_s, 1.0)
    run = read_run(run_mcap)
    opt = EstimateOptions(biases=biases, smooth=smooth, sigma_m=sigma_m, nis_probability=nis_probability,
                          outlier_sigma=outlier_sigma, process_noise_scale=process_noise_scale,
                          rest_segments_s=rest_segments, rest_process_noise_scale=rest_process_noise_scale,
                          rest_retry_s=rest_retry_s, rest_auto=rest_auto, rest_window_s=rest_window_s,
                          rest_dwell_s=rest_dwell_s,
                          keep_filtered_covariance="full" if covariance == "full" else "modal",
                          init_source=str(init_json),
                          # the filter's history on disk beside the output (removed however the run ends),
                          # so memory does not grow with the record; the result holds what STATES stores
                          history=DiskHistory(Path(output).resolve().parent),
                          keep_covariance="full" if covariance == "full" else "modal",
                          progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)))
    _say(ctx, f"estimating {run_mcap} from {init_json} (biases {biases}{', smoothing' if smooth else ''}) …")
    with _init_named(init_json):
        res = run_ekf(run, init, opt)
    del run                                  # the phase table is not needed for writing (memory)
    options = opt.echo()
    if allow_other_run:
        options.update(allow_other_run=True, init_run_sha256=pairing["init_run_sha256"])
    s = write_states(res, run_mcap, init, init_text, output, options, covariance=covariance,
                     preview_rate_hz=foxglove_rate_hz, run_sha256=pairing["run_sha256"])
    s["init_run"] = pairing
    nis_text = "no filter epoch with data" if s["mean_nis_per_dof"] is None else f"mean NIS/dof {s['mean_nis_per_dof']:.3f}"
    w = s.get("window")
    src = (f"; {w['start_s']:g}–{w['end_s']:g} s from INIT's batch solution, then the filter" if w else "")
    _say(ctx, f"wrote {output}: {s['epochs']} epochs ({s['start_s']:g}–{s['end_s']:g} s{src}), "
              f"{nis_text}, {s['events']} events")
    if res.noise:
        nz = res.noise
        rng_txt = (f", {nz['sigma_m_min'] * 1000:.2f}–{nz['sigma_m_max'] * 1000:.2f} mm per channel"
                   if nz.get("sigma_m_max", 0) > nz.get("sigma_m_min", 0) else "")
        worst = nz.get("worst_channel")
        inno = nz.get("innovation_sigma_m")
        inno_txt = ("none (no filter epoch with data)" if inno is None or not math.isfinite(inno)
                    else f"{inno * 1000:.2f} mm")
        _say(ctx, f"  measurement σ {nz['sigma_m'] * 1000:.2f} mm RMS{rng_txt} ({nz['source']}); innovation-based "
                  f"estimate {inno_txt}"
                  + (f"; {worst['channel']} still {worst['relative_variance']:.2f}× the others' variance ratio"
                     if worst else ""))
        mpn = res.noise.get("multipath")
        if mpn:
            _say(ctx, f"  multipath: Gauss–Markov state per channel, σ {mpn['sigma_m'] * 1000:.2f} mm, τ "
                      f"{mpn['time_constant_s']:g} s (from INIT.json; filter on the numpy path)")
    for ev in s["event_list"][:20]:
        ch = f" {ev['antenna']}/{ev['transmitter']}" if ev["antenna"] else ""
        _say(ctx, f"  {ev['time_s']:8.2f} s{ch}: {ev['kind']} → {ev['action']}")
    if len(s["event_list"]) > 20:
        _say(ctx, f"  … {len(s['event_list']) - 20} more events (topic /cdgps/events)")
    s["measurement_noise"] = res.noise
    if as_json:
        _emit_json(s)


@contextmanager
def _init_named(init_json):
    """The library names INIT problems ``INIT.json: …``; on the command line, name the file given."""
    try:
        yield
    except CdgpsError as exc:
        msg = str(exc)
        if msg.startswith("INIT.json"):
            raise CdgpsError(f"{init_json}{msg[len('INIT.json'):]}") from None
        raise


def _check_pairing(ctx, init: dict, init_json, run_mcap, allow_other_run: bool) -> dict:
    """INIT.json's run_sha256 against RUN_MCAP (file_checks.check_init_run), with the warnings."""
    from cdgps_cli.io.file_checks import check_init_run

    pairing = check_init_run(init, init_json, run_mcap, allow_other_run)
    if pairing["allowed"]:
        _warn(f"{init_json} was made from another run (run_sha256 {pairing['init_run_sha256'][:12]}…) "
                  f"than {run_mcap} ({pairing['run_sha256'][:12]}…); used anyway (--allow-other-run)")
    elif pairing["matches"] is None:
        _warn(f"{init_json} records no run_sha256: whether it comes from {run_mcap} is not checked")
    return pairing


def _parse_rest(text: str) -> tuple[float, float]:
    """'START:END' (seconds; END may be empty: to the end of the log) → (start_s, end_s)."""
    a, sep, b = text.partition(":")
    try:
        if not sep:
            raise ValueError
        start = float(a)
        end = float(b) if b.strip() else float("inf")
    except ValueError:
        raise CdgpsError(f"--rest {text!r}: expected START:END in seconds, e.g. 80:140 or 80:, or auto") from None
    return start, end


@main.command(short_help="Export coordinates and their 1σ to CSV")
@click.argument("states_mcap", type=click.Path(dir_okay=False))
@_output_option("out_csv", "CSV to write.", old=("--csv",))
@click.option("--kinematic", is_flag=True,
              help="GNSS STATES only: export the single-epoch (kinematic) solutions instead of the states.")
@click.option("--points", "points", default=None, metavar="LIST",
              help="Also export displacements and 1-sigma (J P Jᵀ) of points: antennas, points (the config's "
                   "[[points]]), all, or comma-separated names.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def export(ctx, states_mcap, out_csv, kinematic, points, as_json):
    """Export estimated coordinates and their 1-sigma to CSV (columns line up with truth.csv)."""
    from cdgps_cli.io.file_checks import GNSS_STATES, STATES, require_kind
    from cdgps_cli.pipeline.estimate_outputs import export_csv

    require_kind(states_mcap, GNSS_STATES if kinematic else STATES,
                 "--kinematic: STATES_MCAP" if kinematic else "STATES_MCAP")   # the option that asks for a GNSS file
    if kinematic:
        from cdgps_cli.pipeline.gnss import export_kinematic_csv

        s = export_kinematic_csv(states_mcap, out_csv)
    else:
        s = export_csv(states_mcap, out_csv, points=points)
    _say(ctx, f"wrote {s['rows']} rows to {out_csv}" + (f" ({len(s['points'])} points)" if s.get("points") else ""))
    if as_json:
        _emit_json(s)


@main.command(short_help="Errors vs simulator truth: RMS, NEES, NIS")
@click.option("--truth", "truth_dir", required=True, type=click.Path(file_okay=False), help="Simulator output directory.")
@click.option("--estimate", "states_mcap", required=True, type=click.Path(dir_okay=False), help="STATES.mcap.")
@click.option("--converge-s", type=float, default=1.0, show_default=True, help="Seconds after the start excluded from RMS.")
@click.option("--json", "as_json", is_flag=True, help="Print the full result as JSON on stdout.")
@click.pass_context
def evaluate(ctx, truth_dir, states_mcap, converge_s, as_json):
    """Errors of an estimate against simulator truth: RMS per coordinate, NEES, NIS, biases."""
    from cdgps_cli.io.file_checks import STATES, require_kind
    from cdgps_cli.pipeline.estimate_outputs import evaluate as run_eval

    require_kind(states_mcap, STATES, "--estimate")
    r = run_eval(truth_dir, states_mcap, converge_s)
    if as_json:
        _emit_json(r)
        return
    lines = [f"{states_mcap} vs {truth_dir}: {r['epochs']} epochs ({r['start_s']:g}–{r['end_s']:g} s)"]
    for n, v in r["rms_error"].items():
        u = r["rms_error_units"][n]
        extra = f"  ({r['rms_error_deg'][n]:.4f} deg)" if n in r["rms_error_deg"] else ""
        lines.append(f"  RMS error {n:>8}: {v:.6f} {u}{extra}")
    ne = r["nees"]
    lines.append(f"  NEES (dof {ne['dof']}): mean {ne['mean']:.2f}, 95% interval {ne['interval95_single'][0]:.2f}–"
                 f"{ne['interval95_single'][1]:.2f}, {100 * ne['fraction_in_interval']:.1f}% of epochs inside")
    if r.get("nis"):
        lines.append(f"  NIS: mean per dof {r['nis']['mean_per_dof']:.3f}, {100 * r['nis']['fraction_in_interval95']:.1f}% in 95% interval")
    lines.append(f"  within 3 sigma: {100 * r['within_3sigma_fraction']:.1f}% of epochs; converged after "
                 f"{'never' if r['convergence_s'] is None else format(r['convergence_s'], '.2f') + ' s'} (NEES below its 99.9% bound for 1 s)")
    if "bias_error" in r:
        b = r["bias_error"]
        lines.append(f"  final biases: RMS error {b['rms_m'] * 1000:.2f} mm, {b['wrong_integers']} wrong integers of {b['channels']}")
    _echo("\n".join(lines))


def _states_and_gyro(states_mcap, gyro_mcap, chunked: bool = False):
    """STATES.mcap (state series only; ``chunked``: read in chunks, io.states.StatesChunks) and,
    optionally, the gyro log of a RUN.mcap."""
    from cdgps_cli.io.file_checks import STATES, STRUCTURE_RUN, require_kind
    from cdgps_cli.io.run import read_run
    from cdgps_cli.io.states import States, StatesChunks

    require_kind(states_mcap, STATES, "STATES_MCAP")
    if gyro_mcap:
        require_kind(gyro_mcap, STRUCTURE_RUN, "--gyro")
    st = StatesChunks(states_mcap) if chunked else States(states_mcap, diagnostics=False)
    return st, (read_run(gyro_mcap, phase=False) if gyro_mcap else None)


def _spectra_options(coords, segment_s, overlap, pad):
    from cdgps_cli.analysis.spectra import SpectraOptions

    return SpectraOptions(coords=tuple(c.strip() for c in coords.split(",") if c.strip()) if coords else None,
                          segment_s=segment_s, overlap=overlap, pad=pad)


_spectra_opts = [
    click.option("--gyro", "gyro_mcap", type=click.Path(dir_okay=False), help="RUN.mcap with the gyro log."),
    click.option("--coords", default=None, help="Comma-separated coordinates (default: all but the rigid one)."),
    click.option("--segment-s", type=float, default=None, help="Welch/FDD segment length, s (default: min(duration/4, 600 s))."),
    click.option("--overlap", type=float, default=SPECTRA_DEFAULTS["overlap"], show_default=True, help="Segment overlap fraction."),
    click.option("--pad", type=int, default=SPECTRA_DEFAULTS["pad"], show_default=True, help="FFT zero-padding factor."),
]


def _with(opts):
    def deco(f):
        for o in reversed(opts):
            f = o(f)
        return f
    return deco


@main.command(short_help="PSDs vs gyros, FDD modes → psd.csv, peaks.json")
@click.argument("states_mcap", type=click.Path(dir_okay=False))
@_with(_spectra_opts)
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False), help="Output directory.")
@click.option("--json", "as_json", is_flag=True, help="Print peaks.json on stdout.")
@click.pass_context
def spectra(ctx, states_mcap, gyro_mcap, coords, segment_s, overlap, pad, out_dir, as_json):
    """Welch PSDs vs gyros, FDD modal identification → psd.csv, peaks.json, psd.png, fdd.png."""
    from cdgps_cli.report.sensor_reports import run_spectra
    st, run = _states_and_gyro(states_mcap, gyro_mcap, chunked=True)
    with progress.stage("spectra, mode fits and figures"):
        s = run_spectra(st, run, _spectra_options(coords, segment_s, overlap, pad), out_dir)
    seen = sum(1 for m in s["modes"] if m["seen"])
    _say(ctx, f"wrote {', '.join(s['files'])} to {out_dir}/: {seen} of {len(s['modes'])} modes identified")
    for m in s["modes"]:
        g = "–" if m["gps_hz"] is None else f"{m['gps_hz']:.4f}"
        e = "" if m["error_pct"] is None else f" ({m['error_pct']:+.2f}%)"
        _say(ctx, f"  {m['mode']:<12} model {m['model_hz']:.4f} Hz  GPS {g} Hz{e}  {'seen' if m['seen'] else 'not seen'}")
    if as_json:
        _emit_json({"modes": s["modes"], "settings": s["settings"]})


@main.group(short_help="Sensor-test reports (markdown, JSON, HTML)")
def report():
    """Sensor-test reports (markdown, JSON and a self-contained HTML page)."""


@report.command("static", short_help="Static sensor test (1998 Fig. 7): mean, noise")
@click.argument("states_mcap", type=click.Path(dir_okay=False))
@click.option("--gyro", "gyro_mcap", type=click.Path(dir_okay=False), help="RUN.mcap with the gyro log.")
@click.option("--angle", required=True, help='Angle expression, e.g. "q6+q10" (see README).')
@click.option("--survey-deg", type=float, default=None, help="Surveyed angle, degrees.")
@click.option("--start", "start_s", type=float, default=None, help="Rest segment start, s (default: detected).")
@click.option("--end", "end_s", type=float, default=None, help="Rest segment end, s (default: detected).")
@click.option("--gyro-name", default=None, help="Gyro to integrate (default: the one whose axis matches the angle).")
@click.option("--date", "date", default=None, metavar="ISO_DATE",
              help="Date printed in the report (default: $SOURCE_DATE_EPOCH, else the newest input's modification time).")
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False), help="Output directory.")
@click.option("--json", "as_json", is_flag=True, help="Print report.json on stdout.")
@click.pass_context
def report_static(ctx, states_mcap, gyro_mcap, angle, survey_deg, start_s, end_s, gyro_name, out_dir, as_json, date):
    """Static sensor test (1998 paper Fig. 7): mean vs survey, noise, GPS and gyro drift."""
    from cdgps_cli.report.sensor_reports import static_report
    st, run = _states_and_gyro(states_mcap, gyro_mcap)
    with progress.stage("static report"):
        d = static_report(st, run, angle, survey_deg, out_dir, start_s, end_s, gyro_name, date=date)
    err = "" if d["error_deg"] is None else f", error {d['error_deg']:+.4f}°"
    gd = "" if d["gyro_drift_deg_per_min"] is None else f", gyro drift {d['gyro_drift_deg_per_min']:+.4f}°/min"
    _say(ctx, f"{angle}: mean {d['mean_deg']:.4f}°{err}, noise {d['noise_rms_deg']:.4f}° RMS, "
              f"drift {d['drift_deg_per_min']:+.4f}°/min{gd} on {d['start_s']:.1f}–{d['end_s']:.1f} s")
    if d["static_mode"]["active_fraction"] != 1.0:
        _warn(d["static_mode"]["statement"])
    _say(ctx, f"report: {Path(out_dir) / 'report.html'}")
    if as_json:
        _emit_json(d)


@report.command("control", short_help="Control experiments (1998 Figs. 6, 10-12)")
@click.argument("gains_json", type=click.Path(dir_okay=False))
@click.option("--closed", "closed_dir", required=True, type=click.Path(file_okay=False),
              help="`cdgps simulate --controller` folder (closed loop on the GPS estimate).")
@click.option("--open", "open_dir", type=click.Path(file_okay=False),
              help="Open-loop `cdgps simulate` folder of the same scenario (required for pulse).")
@click.option("--full-state", "full_state_dir", type=click.Path(file_okay=False),
              help="Closed loop with --feedback truth (what the estimator costs).")
@click.option("--no-vibration", "no_vibration_dir", type=click.Path(file_okay=False),
              help="Closed loop with --no-vibration-control (Fig. 12).")
@click.option("--date", "date", default=None, metavar="ISO_DATE",
              help="Date printed in the report (default: $SOURCE_DATE_EPOCH, else the newest input's modification time).")
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False), help="Output directory.")
@click.option("--json", "as_json", is_flag=True, help="Print report.json on stdout.")
@click.pass_context
def report_control(ctx, gains_json, closed_dir, open_dir, full_state_dir, no_vibration_dir, date, out_dir, as_json):
    """Pulse rejection (Fig. 10) or slew (Figs. 11-12) with the design's poles (Fig. 6)."""
    from cdgps_cli.report.control import control_report

    runs = {k: v for k, v in (("closed", closed_dir), ("open", open_dir), ("full_state", full_state_dir),
                              ("no_vibration", no_vibration_dir)) if v}
    with progress.stage("control report"):
        d = control_report(gains_json, runs, out_dir, date=date)
    _say(ctx, f"{d['scenario']} report: {Path(out_dir) / 'report.html'}")
    if as_json:
        _emit_json(d)


@report.command("spectrum", short_help="Dynamic sensor test (1998 Fig. 8): PSDs, modes")
@click.argument("states_mcap", type=click.Path(dir_okay=False))
@_with(_spectra_opts)
@click.option("--date", "date", default=None, metavar="ISO_DATE",
              help="Date printed in the report (default: $SOURCE_DATE_EPOCH, else the newest input's modification time).")
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False), help="Output directory.")
@click.option("--json", "as_json", is_flag=True, help="Print report.json on stdout.")
@click.pass_context
def report_spectrum(ctx, states_mcap, gyro_mcap, coords, segment_s, overlap, pad, out_dir, as_json, date):
    """Dynamic sensor test (1998 paper Fig. 8): PSDs vs gyros and identified modes vs the model."""
    from cdgps_cli.report.sensor_reports import spectrum_report
    st, run = _states_and_gyro(states_mcap, gyro_mcap, chunked=True)
    with progress.stage("spectra, mode fits and figures"):
        d = spectrum_report(st, run, _spectra_options(coords, segment_s, overlap, pad), out_dir, date=date)
    _say(ctx, d["summary"])
    _say(ctx, f"report: {Path(out_dir) / 'report.html'}")
    if as_json:
        _emit_json(d)


@main.command(short_help="Topics, dates, sampling, gaps, slips of an MCAP")
@click.argument("mcap_file", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the full summary as JSON on stdout.")
@click.option("--deep", is_flag=True,
              help="Also decompress and decode every message (chunk CRCs, JSON) and check the file's summary "
                   "record against them; without it the answer comes from the summary and metadata records "
                   "after the file's CRC checks (docs/hardening.md, 'MCAP integrity').")
@click.pass_context
def info(ctx, mcap_file, as_json, deep):
    """Topics, counts, time span, sampling, gaps, channels and slips of an MCAP file."""
    from cdgps_cli.core.time_format import format_period
    from cdgps_cli.io.mcap import INFO_METADATA
    from cdgps_cli.io.run import summary_info

    s = None if deep else summary_info(mcap_file)         # the summary and records (no pandas, no numerics)
    if s is None:                                          # older files, GNSS runs, --deep: every message
        from cdgps_cli.pipeline.gnss_ingest import run_info

        s = run_info(mcap_file, deep=deep)
    if as_json:
        _emit_json(s)
        return
    out = [f"{s['file']}"]
    for t in s["topics"]:
        out.append(f"  {t['topic']:<22} {t['messages']:>8} msgs  {_span(t)}  period {format_period(t['median_period_s'])}"
                   f"  ({t['schema']}, {t['message_encoding']})")
    if "config" in s:
        c = s["config"]
        out.append(f"  config {c['name']} (sha256 {c['config_sha256'][:12]}…), master {c['master']}")
        out.append(f"  channels: {len(s['channels'])}; gaps: {len(s['gaps'])}; lock restarts (slips/relocks): {len(s['slips'])}")
        for g in s["gaps"][:10]:
            out.append(f"    gap {g['start_s']:g}–{g['end_s']:g} s ({g['missing_epochs']} epochs missing)")
        for sl in s["slips"][:20]:
            out.append(f"    lock restart {sl['antenna']}/{sl['transmitter']} at {sl['time_s']:g} s")
        if len(s["slips"]) > 20:
            out.append(f"    … {len(s['slips']) - 20} more")
    if "gnss" in s:
        out.extend(_gnss_info_lines(s["gnss"]))
    for name, md in s["metadata"].items():
        if name == INFO_METADATA:                 # what the lines above were made from
            continue
        out.append(f"  metadata {name}: " + ", ".join(f"{k}={v if len(v) <= 60 else v[:57] + '…'}"
                                                     for k, v in sorted(md.items()) if not k.endswith(("sha256", "_integrity"))))
    _echo("\n".join(out))


def _span(t: dict) -> str:
    """A topic's time span for ``info``: ``0–3600 s`` (run seconds) or two calendar dates."""
    if t["start_s"] is None:
        return "-"
    if t.get("time_scale", "relative") == "relative":
        return f"{t['start_s']:g}–{t['end_s']:g} s"
    return t["start"] if t["start"] == t["end"] else f"{t['start']} – {t['end']}"


def _gnss_info_lines(g: dict) -> list:
    c = g["config"]
    out = [f"  GNSS run: config {c['name']} (sha256 {c['config_sha256'][:12]}…), master {g['master']}, rovers "
           f"{', '.join(g['rovers']) or 'none'}, displacement {c['displacement']}; coordinates {', '.join(g['coordinates']) or '-'}"]
    for r in g["receivers"]:
        out.append(f"    {r['name']:<8} {r['format']:<5} {r['file']}: {r['epochs']} epochs {r['first']} – {r['last']} "
                   f"({r['interval_s']:g} s), {r['satellites']} satellites, {r['phase_rows']} phases; lock: {r['arcs']} arcs, "
                   f"{r['slips']} slips, {r['half_cycle_rows']} half-cycle rows; position: {r['position_source'] or 'none'}")
        if "integrity" in r:
            from cdgps_cli.io.ubx import integrity_line

            out.append(f"      integrity: {integrity_line(r['integrity'])}")
    for n, k in g["common_epochs"].items():
        out.append(f"    {n}: {k} epochs in common with {g['master']}" + _grid_note((g.get("epoch_pairing") or {}).get(n)))
    toe = g["ephemeris_toe"]
    out.append(f"    ephemerides: {g['ephemerides']} records of {g['ephemeris_satellites']} satellites"
               + (f", toe {toe[0]} – {toe[1]}" if toe else " (none: ingest with --nav before 'cdgps init')"))
    return out


# ----------------------------------------------------------------------------------------------
# static baseline from real receiver logs (RINEX + broadcast ephemeris): docs/geonet.md


def _write_text_atomic(path: str, text: str) -> None:
    from cdgps_cli.io.atomic import write_atomic

    write_atomic(path, lambda tmp: Path(tmp).write_text(text))


@main.command("baseline", short_help="Static baseline of two RINEX receivers → JSON")
@click.option("--config", "job", type=click.Path(dir_okay=False), default=None,
              help="Baseline job TOML (files, master, options; see docs/geonet.md). Options below override it.")
@click.option("--rinex", "rinex", multiple=True, metavar="NAME=PATH", help="RINEX observation file of a station (give two).")
@click.option("--nav", "nav", multiple=True, type=click.Path(dir_okay=False), help="RINEX GPS navigation file (repeatable).")
@click.option("--master", default=None, help="Station held at its RINEX header position (the reference).")
@click.option("--mask-deg", type=float, default=None, help=f"Elevation mask, degrees [{GNSS_DEFAULTS['mask_deg']:g}].")
@click.option("--ratio", "ratio_threshold", type=float, default=None, help=f"LAMBDA ratio-test threshold [{GNSS_DEFAULTS['ratio']:g}].")
@click.option("--min-success-rate", type=float, default=None,
              help=f"Bootstrapped success rate an integer set (or partial subset) must reach besides the ratio test "
                   f"(0: ratio test only) [{GNSS_DEFAULTS['min_success_rate']:g}].")
@click.option("--max-age", "max_age_s", type=float, default=None,
              help=f"Oldest master epoch bridged to a rover epoch, s [{GNSS_DEFAULTS['max_age_s']:g}, RTKLIB's].")
@click.option("--weighting", type=click.Choice(["elevation", "equal"]), default=None,
              help="Phase weights: a²+b²/sin²(el) or equal [elevation].")
@click.option("--no-partial", is_flag=True, help="Do not try partial fixing when the full set fails the ratio test.")
@click.option("--float-only", is_flag=True, help="Do not fix integers (float solution only).")
@click.option("--no-troposphere", is_flag=True, help="No a priori hydrostatic troposphere.")
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="Result JSON to write.")
@click.option("--json", "as_json", is_flag=True, help="Also print the result JSON on stdout.")
@click.pass_context
def baseline_cmd(ctx, job, rinex, nav, master, mask_deg, ratio_threshold, min_success_rate, max_age_s, weighting, no_partial,
                 float_only, no_troposphere, output, as_json):
    """Static baseline from two receivers' RINEX L1 phase: float, LAMBDA integers, fixed → JSON."""
    import dataclasses

    from cdgps_cli.estimation.baseline import BaselineOptions, format_summary, json_safe
    from cdgps_cli.pipeline.baseline_job import baseline_from_files, load_baseline_job

    positions = {}
    if job:
        cfg = load_baseline_job(job)
        stations, navs, mst, opt = cfg["rinex"], cfg["nav"], cfg["master"], cfg["options"]
        positions = cfg.get("positions", {})
    else:
        stations, navs, mst, opt = {}, [], None, BaselineOptions()
    if rinex:
        stations = _parse_named(rinex, "--rinex", "station", "NAME=PATH")
    if nav:
        navs = list(nav)
    mst = master or mst
    if len(stations) != 2:
        raise CdgpsError(f"give exactly two stations with --rinex NAME=PATH (or --config), got {len(stations)}")
    if not navs:
        raise CdgpsError("give at least one navigation file with --nav (or --config)")
    if not mst:
        raise CdgpsError(f"--master is required: which of {', '.join(stations)} is the reference at its header position")
    if mst not in stations:
        raise CdgpsError(f"master {mst!r} is not one of the stations given: {', '.join(stations)}")
    changes = {}
    if mask_deg is not None:
        changes["mask_deg"] = mask_deg
    if ratio_threshold is not None:
        changes["ratio_threshold"] = ratio_threshold
    if min_success_rate is not None:
        changes["min_success_rate"] = min_success_rate
    if max_age_s is not None:
        changes["max_age_s"] = max_age_s
    if weighting is not None:
        changes["weighting"] = weighting
    if no_partial:
        changes["partial"] = False
    if float_only:
        changes["fix"] = False
    if no_troposphere:
        changes["troposphere"] = False
    flags = {"mask_deg": "--mask-deg", "ratio_threshold": "--ratio", "max_age_s": "--max-age", "weighting": "--weighting",
             "min_success_rate": "--min-success-rate"}
    opt = dataclasses.replace(opt, **changes)
    _named_by_flags(opt.validate, {k: flags[k] for k in changes if k in flags})
    rover = next(n for n in stations if n != mst)
    _say(ctx, f"baseline {mst} → {rover}: {len(navs)} navigation file(s), mask {opt.mask_deg:g}°, ratio {opt.ratio_threshold:g} …")
    res = json_safe(baseline_from_files(stations, navs, mst, opt,
                                        positions={k: v for k, v in positions.items() if k in stations}))
    if job:
        res["inputs"]["config"] = str(job)
    timing = res.pop("timing_s", {})        # wall-clock: stderr only, so the file is byte-identical across runs
    _write_json_atomic(output, res)
    _say(ctx, format_summary(res))
    _say(ctx, "timing (s): " + ", ".join(f"{k} {v:.2f}" for k, v in timing.items()))
    _say(ctx, f"wrote {output}")
    if as_json:
        _emit_json(res)


@main.command("config", short_help="Starter GNSS run config from receiver headers")
@click.option("--rinex", "rinex", multiple=True, metavar="ANTENNA=FILE", help="RINEX observation file of an antenna.")
@click.option("--ubx", "ubx", multiple=True, metavar="ANTENNA=FILE", help="u-blox UBX log (RXM-RAWX) of an antenna.")
@click.option("--nav", "nav", multiple=True, type=click.Path(dir_okay=False), help="RINEX GPS navigation file.")
@click.option("--master", default=None, help="Reference antenna (default: the first RINEX one with a header position).")
@click.option("--displacement", type=click.Choice(["static", "random_walk"]), default="static", show_default=True,
              help="Rover displacement model.")
@click.option("--sigma", "sigma", type=float, default=None, help="random_walk process noise, m/√s per component [0.001].")
@click.option("--name", default=None, help="Run name (default: the antenna names).")
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="Config TOML to write.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary (the written config as it loads, notes) on stdout.")
@click.pass_context
def config_cmd(ctx, rinex, ubx, nav, master, displacement, sigma, name, output, as_json):
    """Write a starter GNSS run config from the receiver files' headers (for ingest and baseline)."""
    from cdgps_cli.pipeline.gnss_ingest import starter_gnss_config

    if sigma is not None and displacement != "random_walk":
        raise CdgpsError("--sigma is the random-walk process noise: use it with --displacement random_walk")
    notes: list = []
    text = starter_gnss_config(_parse_named(rinex, "--rinex"), _parse_named(ubx, "--ubx"), list(nav), master,
                               displacement=displacement, sigma_m_per_sqrt_s=sigma,
                               relative_to=Path(output).resolve().parent, name=name, notes=notes)
    _write_text_atomic(output, text)
    for n in notes:
        click.echo(f"cdgps: note: {n}", err=True)
    _say(ctx, f"wrote {output}")
    if as_json:
        from cdgps_cli.config.structure import load_gnss_config

        _emit_json({"output": output, "config": load_gnss_config(output).summary(), "notes": notes})


@main.command("baseline-config", short_help="Starter baseline job TOML from RINEX headers")
@click.option("--rinex", "rinex", multiple=True, required=True, metavar="NAME=PATH", help="RINEX observation file (give two).")
@click.option("--nav", "nav", multiple=True, required=True, type=click.Path(dir_okay=False), help="RINEX GPS navigation file.")
@click.option("--master", default=None, help="Reference station (default: the first --rinex).")
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="Job TOML to write.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary (stations, master, navigation files, options) on stdout.")
@click.pass_context
def baseline_config_cmd(ctx, rinex, nav, master, output, as_json):
    """Write a starter baseline job TOML for 'cdgps baseline --config' (headers summarised in comments).

    The file is a GNSS run config (docs/gnss-pipeline.md), so it also serves 'cdgps ingest'.
    """
    from cdgps_cli.pipeline.baseline_job import load_baseline_job
    from cdgps_cli.pipeline.gnss_ingest import starter_gnss_config

    stations = _parse_named(rinex, "--rinex", "station", "NAME=PATH")
    if len(stations) != 2:
        raise CdgpsError(f"a baseline job needs exactly two RINEX observation files (NAME=PATH), got {len(stations)}")
    master = master or next(iter(stations))
    text = starter_gnss_config(stations, {}, list(nav), master, relative_to=Path(output).resolve().parent)
    _write_text_atomic(output, text)
    job = load_baseline_job(output)  # the written job must load
    _say(ctx, f"wrote {output}")
    if as_json:
        import dataclasses

        _emit_json({"output": output, "master": job["master"], "stations": {k: str(v) for k, v in job["rinex"].items()},
                    "nav": [str(v) for v in job["nav"]], "options": dataclasses.asdict(job["options"])})


# ----------------------------------------------------------------------------------------------
# GNSS pipeline from real (or simulated) receiver files: docs/gnss-pipeline.md


def _reject_structure_options(given: dict, what: str) -> None:
    used = [k for k, v in given.items() if v]
    if used:
        raise CdgpsError(f"{', '.join(used)}: structure-run option(s), not used by {what} on a GNSS run "
                         f"(see docs/gnss-pipeline.md)")


def _init_gnss(ctx, run_mcap, float_only, ratio_threshold, no_partial, output, as_json, structure_only, structure=None):
    import hashlib

    from click.core import ParameterSource

    from cdgps_cli.pipeline.gnss import gnss_init
    from cdgps_cli.io.gnss_run import read_gnss_run

    _reject_structure_options(structure_only, "'cdgps init'")
    run = read_gnss_run(run_mcap)
    over = {}
    if ctx.get_parameter_source("ratio_threshold") != ParameterSource.DEFAULT:
        over["ratio_threshold"] = ratio_threshold
    if no_partial:
        over["partial"] = False
    if float_only:
        over["fix"] = False
    say = None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True))
    modal = _structure_options(*structure) if structure is not None else None
    res = gnss_init(run, options=over, progress=say)
    if modal is not None:
        from cdgps_cli.pipeline.gnss_modal import gnss_modal_init

        res["modal_init"] = gnss_modal_init(run, res, modal[0], receivers=modal[1], x_axis_azimuth_deg=structure[1],
                                            progress=say)
    res["run_sha256"] = hashlib.sha256(Path(run_mcap).read_bytes()).hexdigest()
    _write_json_atomic(output, res)
    for r, v in res["rovers"].items():
        ratio = v["ratio"] if v["ratio"] is None or isinstance(v["ratio"], str) else f"{v['ratio']:.1f}"
        st = ", ".join(f"{k} {x:+.4f} ± {v['sigma'][k]:.4f}" for k, x in v["states"].items())
        glo = f" ({v['n_float_glonass']} GLONASS float)" if v.get("n_float_glonass") else ""
        _say(ctx, f"INIT {run.master} → {r}: {v['solution']}, {v['n_fixed']} of {v['n_estimated']} integers fixed{glo}, "
                  f"ratio {ratio} (threshold {v['ratio_threshold']:g}); static displacement (m): {st}")
    if "modal_init" in res:
        mi = res["modal_init"]
        if "refused" in mi:
            _say(ctx, f"INIT modal ({mi['structure']}): refused ({mi['refused']}); estimate will use the baselines' integers")
        else:
            _say(ctx, f"INIT modal ({mi['structure']}, window {mi['window']['epochs']} epochs): {mi['integer_fixing']}, "
                      f"{mi['agree_with_init']['equal']} of {mi['agree_with_init']['compared']} equal to the baselines'")
    _say(ctx, f"wrote {output}")
    if as_json:
        _emit_json(res)


def _estimate_gnss(ctx, run_mcap, init_json, smooth, output, as_json, structure_only, structure=None,
                   x_axis_azimuth_deg=X_AXIS_AZIMUTH_DEG, receiver_map=(), allow_other_run=False):
    from cdgps_cli.pipeline.gnss import gnss_estimate
    from cdgps_cli.io.gnss_run import read_gnss_run

    _reject_structure_options(structure_only, "'cdgps estimate'")
    from cdgps_cli.io.file_checks import read_init_json

    init, init_text = read_init_json(init_json)
    pairing = _check_pairing(ctx, init, init_json, run_mcap, allow_other_run)
    extra = {"allow_other_run": True, "init_run_sha256": pairing["init_run_sha256"]} if allow_other_run else None
    run = read_gnss_run(run_mcap)
    if structure is not None or receiver_map:
        _estimate_gnss_modal(ctx, run, init, init_text, output, as_json, smooth, structure, x_axis_azimuth_deg,
                             receiver_map, extra, pairing)
        return
    _say(ctx, f"estimating {run_mcap} from {init_json} ({run.cfg.displacement} displacement"
              f"{', smoothing' if smooth and run.cfg.displacement == 'random_walk' else ''}) …")
    s = gnss_estimate(run, init, init_text, output, smooth=smooth,
                      progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)), extra_options=extra)
    s["init_run"] = pairing
    _say(ctx, f"wrote {output}: {s['epochs']} epochs ({s['start']} – {s['end']}), {s['kinematic_epochs']} single-epoch "
              f"solutions, {s['events']} events")
    for r, v in s["rovers"].items():
        st = ", ".join(f"{k} {x:+.4f}" for k, x in v["static_enu_m"].items())
        _say(ctx, f"  {r}: {v['solution']} ({v['n_fixed']}/{v['n_estimated']} integers), static (m) {st}")
        k = v["kinematic_rms_m"]
        if k:
            _say(ctx, f"    single-epoch scatter about static over {v['kinematic_epochs']} epochs: RMS E {k['e'] * 1e3:.1f} "
                      f"N {k['n'] * 1e3:.1f} U {k['u'] * 1e3:.1f} mm")
    for ev in s["event_list"][:20]:
        _say(ctx, f"  {_gps_time(ev['time_s'])} {ev['antenna']}/{ev['transmitter']}: {ev['kind']} → {ev['action']}")
    if len(s["event_list"]) > 20:
        _say(ctx, f"  … {len(s['event_list']) - 20} more events (topic /cdgps/events)")
    if as_json:
        s = dict(s)
        _emit_json(s)


def _structure_options(structure, x_axis_azimuth_deg, receiver_map):
    """--structure / --x-axis-azimuth-deg / --receiver of a GNSS run → (StructureConfig, {antenna: receiver})."""
    from cdgps_cli.config.structure import load_config

    if structure is None:
        raise CdgpsError("--receiver needs --structure (a structure config)")
    if not -360.0 <= x_axis_azimuth_deg <= 360.0:
        raise CdgpsError(f"--x-axis-azimuth-deg must be in [-360, 360], got {x_axis_azimuth_deg:g}")
    cfg = load_config(structure)
    mapping = {}
    for it in receiver_map:
        a, sep, r = it.partition("=")
        if not sep or not a.strip() or not r.strip():
            raise CdgpsError(f"--receiver expects ANTENNA=RECEIVER, got {it!r}")
        if a.strip() not in cfg.antenna_names:
            raise CdgpsError(f"--receiver {it!r}: {a.strip()!r} is not an antenna of {structure} "
                             f"({', '.join(cfg.antenna_names)})")
        mapping[a.strip()] = r.strip()
    return cfg, mapping


def _estimate_gnss_modal(ctx, run, init, init_text, output, as_json, smooth, structure, x_axis_azimuth_deg,
                         receiver_map, extra=None, pairing=None):
    """``cdgps estimate RUN --init INIT --structure STRUCT.toml``: the modal model on the DDs (gnss_modal.py)."""
    from cdgps_cli.pipeline.gnss_modal import gnss_modal_estimate

    cfg, mapping = _structure_options(structure, x_axis_azimuth_deg, receiver_map)
    _say(ctx, f"estimating the modal model of {cfg.name} from {run.path} and its INIT"
              f"{' (smoothing)' if smooth else ''} …")
    s = gnss_modal_estimate(run, init, init_text, cfg, output, receivers=mapping, x_axis_azimuth_deg=x_axis_azimuth_deg,
                            smooth=smooth, progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)),
                            extra_options=extra)
    s["init_run"] = pairing
    _say(ctx, f"wrote {output}: {s['epochs']} epochs, coordinates {', '.join(s['coordinates'])}, mean NIS/dof "
              f"{s['mean_nis_per_dof']:.3f}, {s['events']} events")
    for a, v in s["integers"].items():
        _say(ctx, f"  {a} ({s['receivers'][a]}): {v['fixed']}/{v['estimated']} integers fixed; nominal position "
                  f"{s['nominal_mismatch_m'][a] * 1e3:.1f} mm from the structure's")
    if as_json:
        _emit_json(s)


def _gps_time(t: float) -> str:
    from cdgps_cli.core.gps_time import gps_time_str

    return gps_time_str(t)


@main.command("simulate-gnss-structure", short_help="Simulate a structure seen by GNSS receivers → RINEX")
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--duration", "duration_s", type=float, default=1200.0, show_default=True, help="Seconds to simulate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (same seed → identical files).")
@click.option("--x-axis-azimuth-deg", "x_axis_azimuth_deg", type=float, default=X_AXIS_AZIMUTH_DEG, show_default=True,
              help="Azimuth of the structure x axis, degrees clockwise from north (90: x east, y north).")
@click.option("--master-xyz", default=None, metavar="X,Y,Z", help="ECEF position of the master antenna, m [GEONET 3040].")
@click.option("--signals", default=None, metavar="SIG,SIG…",
              help="Signals every receiver tracks, e.g. G:L1,G:L2,E:E1,E:E5a,C:B1I,C:B2a (GPS, Galileo, BeiDou; G:L1 "
                   "required); "
                   "written to the config's [gnss] signals.  Default: GPS L1 without a signals list.")
@_output_option("out_dir", "Output directory.", directory=True, old=("--out",))
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def simulate_gnss_structure_cmd(ctx, config, duration_s, seed, x_axis_azimuth_deg, master_xyz, signals, out_dir, as_json):
    """Simulate a structure's free motion seen by one GNSS receiver per antenna → RINEX + truth.

    With --signals the receivers track GPS, Galileo and BeiDou (GEO, IGSO, MEO) on every signal given
    (multi-signal RINEX 3) and the written config lists them ([gnss] signals), so the modal path uses them all.

    The structure config's modal model moves the antennas (scenario free, at the config's sample
    period); every antenna, the master too, has its own receiver.  The files feed
    'cdgps ingest --config DIR/config.toml', 'cdgps init', then
    'cdgps estimate … --structure CONFIG' and 'cdgps evaluate --truth DIR'.
    """
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.pipeline.gnss_modal import simulate_structure_gnss
    from cdgps_cli.sim.gnss import DEFAULT_MASTER_XYZ, parse_vector

    if not duration_s > 0:
        raise CdgpsError(f"--duration must be positive, got {duration_s:g}")
    if not -360.0 <= x_axis_azimuth_deg <= 360.0:
        raise CdgpsError(f"--x-axis-azimuth-deg must be in [-360, 360], got {x_axis_azimuth_deg:g}")
    cfg = load_config(config)
    s = simulate_structure_gnss(
        out_dir, cfg, master_ecef_m=parse_vector(master_xyz, "--master-xyz") if master_xyz else DEFAULT_MASTER_XYZ,
        x_axis_azimuth_deg=x_axis_azimuth_deg, duration_s=duration_s, seed=seed,
        signals=None if signals is None else [g.strip() for g in signals.split(",") if g.strip()],
        progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)))
    _say(ctx, f"wrote {out_dir}/: " + ", ".join(f"{k} {v}" for k, v in s.items() if isinstance(v, (int, float, str)))[:400])
    if as_json:
        _emit_json(s)


@main.command("simulate-gnss", short_help="Simulate a GPS L1 master + rover pair → RINEX")
@click.option("--duration", "duration_s", type=float, default=3600.0, show_default=True, help="Seconds to simulate.")
@click.option("--rate-hz", type=float, default=1.0, show_default=True, help="Epochs per second.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (same seed → identical files).")
@click.option("--start", "start", default=None,
              help="First epoch, GPS time YYYY-MM-DD[THH:MM:SS] [2024-01-01, or the first hour of --nav].")
@click.option("--nav", "nav", multiple=True, type=click.Path(dir_okay=False),
              help="Real RINEX navigation file(s) to simulate with [a synthetic 36-satellite constellation].")
@click.option("--master", "master", default="base", show_default=True, help="Master antenna name.")
@click.option("--rover", "rover", default="rover", show_default=True, help="Rover antenna name.")
@click.option("--master-xyz", default=None, metavar="X,Y,Z", help="Master ECEF position, m [GEONET 3040].")
@click.option("--rover-xyz", default=None, metavar="X,Y,Z", help="Rover NOMINAL ECEF position, m [GEONET 0759, 3.3 km away].")
@click.option("--displacement", "displacement", default="0.031,-0.022,0.017", show_default=True, metavar="E,N,U",
              help="Rover's true displacement from its nominal position, m.")
@click.option("--random-walk", "random_walk", type=float, default=None, metavar="SIGMA",
              help="Rover also random-walks with SIGMA m/√s per component (config model random_walk).")
@click.option("--slips", "n_slips", type=int, default=0, show_default=True, help="Random LLI-flagged cycle slips.")
@click.option("--phase-noise-m", type=float, default=None,
              help="Undifferenced white phase noise, m [default: the elevation model sigma^2 = a^2 + b^2/sin^2(el), "
                   "a = b = 3 mm per receiver, the estimator's default weighting].")
@click.option("--code-noise-m", type=float, default=0.5, show_default=True, help="Undifferenced pseudorange noise, m.")
@click.option("--clock-offset-ms", "clock_offset", default="0,0", show_default=True, metavar="M,R",
              help="Master and rover receiver-clock offset at the start, ms.")
@click.option("--clock-drift-ms", "clock_drift", default="-4,5", show_default=True, metavar="M,R",
              help="Change of the master and rover clock offsets over the span, ms.")
@click.option("--raw-tags", is_flag=True,
              help="Time tags = nominal epoch + clock offset, not rounded to 1 ms (u-blox-like epochs off whole seconds).")
@click.option("--master-rate-hz", type=float, default=None,
              help="The master records at this lower rate (a divisor of --rate-hz), e.g. 0.2 for a 5 s CORS receiver.")
@_output_option("out_dir", "Output directory.", directory=True, old=("--out",))
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def simulate_gnss_cmd(ctx, duration_s, rate_hz, seed, start, nav, master, rover, master_xyz, rover_xyz, displacement,
                      random_walk, n_slips, phase_noise_m, code_noise_m, clock_offset, clock_drift, raw_tags,
                      master_rate_hz, out_dir, as_json):
    """Simulate a master + rover GPS L1 pair → RINEX 3 obs/nav files, truth.csv/json, config.toml.

    The rover antenna is displaced from its nominal (header) position by --displacement (plus a
    random walk with --random-walk); the files feed 'cdgps ingest --config DIR/config.toml'.
    """
    from cdgps_cli.sim.gnss import DEFAULT_MASTER_XYZ, DEFAULT_ROVER_XYZ, parse_start, parse_vector, simulate_gnss_pair

    s = simulate_gnss_pair(
        out_dir, duration_s=duration_s, rate_hz=rate_hz, seed=seed,
        start_gps_s=parse_start(start) if start else None, nav_paths=list(nav), master=master, rover=rover,
        master_xyz=parse_vector(master_xyz, "--master-xyz") if master_xyz else DEFAULT_MASTER_XYZ,
        rover_xyz=parse_vector(rover_xyz, "--rover-xyz") if rover_xyz else DEFAULT_ROVER_XYZ,
        displacement_enu_m=parse_vector(displacement, "--displacement"), random_walk_sigma=random_walk,
        n_slips=n_slips, phase_sigma_m=phase_noise_m, code_sigma_m=code_noise_m,
        clock_offset_ms=parse_vector(clock_offset, "--clock-offset-ms", 2),
        clock_drift_ms=parse_vector(clock_drift, "--clock-drift-ms", 2), raw_tags=raw_tags,
        master_rate_hz=master_rate_hz,
        progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)))
    _say(ctx, f"wrote {', '.join(s['files'])} to {out_dir}/: {s['epochs']} epochs, {s['satellites']} satellites, "
              f"{s['slips']} slips, {s['displacement_model']} rover")
    if as_json:
        _emit_json(s)



@main.group(short_help="LQR gain design for the thrusters (1998 Sec. V)")
def control():
    """Control with GPS in the loop: discrete LQR design on the modal model (1998 paper, Sec. V)."""


def _weights_option(text: str | None, name: str):
    """--qx / --qu: one number or a comma-separated diagonal (the library checks the length)."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise CdgpsError(f"{name} {text!r}: expected a number or comma-separated numbers, e.g. 5000 or 1,1,0.5") from None
    return values[0] if len(values) == 1 else values


@control.command("design", short_help="Discrete LQR gain → GAINS.json (+ z-plane figure)")
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--weights", "weight_set", type=click.Choice(["paper", "tuned"]), default=CONTROL_WEIGHTS,
              show_default=True,
              help="Named weights: the paper's Sec. V numbers (Qx* = 5000·diag(1,…,1,0.01), Qx = diag(Qx*, 0.01·Qx*), "
                   "Qu = I), or the experiments' tuned ones (W = {qx:g}, f_rigid = {rigid_factor:g}, "
                   "f_rate = {rate_factor:g}; docs/control.md).  --qx, --qu, --rigid-factor and --rate-factor change "
                   "parts of it.".format(**CONTROL_TUNED_WEIGHTS))
@click.option("--qx", default=None, metavar="W|LIST",
              help="State weight: one number W in the paper's form Qx* = W·diag(1,…,1,f_rigid), "
                   "Qx = diag(Qx*, f_rate·Qx*); or the whole diagonal of Qx (amplitudes, then rates) "
                   "[the --weights set's: 5000 for the paper's].")
@click.option("--qu", default=None, metavar="R|LIST",
              help="Input weight: one number (times I) or one per thruster [I, the paper's].")
@click.option("--rigid-factor", type=float, default=None,
              help="Weight of the rigid-body mode relative to the others in Qx* [the --weights set's: 0.01 for the paper's].")
@click.option("--rate-factor", type=float, default=None,
              help="Weight of the modal rates relative to the amplitudes, Qx = diag(Qx*, f·Qx*) "
                   "[the --weights set's: 0.01 for the paper's].")
@_output_option("output", "GAINS.json to write.")
@click.option("--figure", "figure_png", default=None, type=click.Path(dir_okay=False),
              help="Also write the z-plane pole figure (Fig. 6 style) to this PNG.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary (poles, settling times) on stdout.")
@click.pass_context
def control_design(ctx, config, weight_set, qx, qu, rigid_factor, rate_factor, output, figure_png, as_json):
    """Discrete LQR u = −K x on the config's modal model (Eq. 4, 24), by default with the paper's weights.

    Writes the model A, B the gain was designed on, the weights (and which set they are: paper, tuned
    or custom), K, and the open- and closed-loop poles (z and s planes, frequency, damping, 2 % settling
    time per mode).  The thruster force model Υ is derived from the config's thruster geometry (the
    paper's is not published).
    """
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.control.design import design_for_structure, state_names, weight_set_name
    from cdgps_cli.io.gains_file import gains_record, write_gains

    cfg = load_config(config)
    opts = {"weights": weight_set, "qx": qx, "qu": qu, "rigid_factor": rigid_factor, "rate_factor": rate_factor}
    design, poles = design_for_structure(cfg, _weights_option(qx, "--qx"), _weights_option(qu, "--qu"),
                                         rigid_factor, rate_factor, weight_set)
    from cdgps_cli.control.estimator_design import loop_estimator

    rec = gains_record(design, poles, config_path=config, state_names=state_names(cfg),
                       thruster_names=cfg.thruster_names, options=opts,
                       weight_set=weight_set_name(cfg, design.Qx, design.Qu))
    est = loop_estimator(cfg, design.K)       # informative: `simulate --controller` applies the same rule
    rec["loop_estimator"] = {"process_noise_scale": est["scale"], "separation": est["separation"], "met": est["met"],
                             "estimator_settling_s": est["estimator_settling_s"], "rule": est["rule"]}
    write_gains(output, rec)
    if figure_png:
        from cdgps_cli.report.control_figures import pole_figure

        pole_figure(poles, figure_png, f"{cfg.name}: LQR poles at {1 / design.sample_period_s:g} Hz")
    settle = poles["settling_time_s"]["closed_loop"]
    _say(ctx, f"wrote {output}: K {design.K.shape[0]}×{design.K.shape[1]}, Riccati residual "
              f"{design.riccati_residual:.1e}" + (f", figure {figure_png}" if figure_png else ""))
    for mode, t in settle.items():
        t0 = poles["settling_time_s"]["open_loop"][mode]
        _say(ctx, f"  {mode:<12} 2% settling: open loop {'∞' if t0 is None else f'{t0:.1f} s':>9}, "
                  f"closed loop {'∞' if t is None else f'{t:.1f} s':>9}")
    _say(ctx, f"  in-loop filter: {est['rule']}")
    if not est["met"]:
        _warn(f"the in-loop estimator cannot be made {est['separation']:g}x faster than this "
                       "regulator; in the closed loop the estimate will lag it (--weights tuned or a smaller --qx, docs/control.md)")
    if as_json:
        _emit_json({"output": output, "riccati_residual": design.riccati_residual,
                    "settling_time_s": poles["settling_time_s"], "poles": poles,
                    "loop_estimator": rec["loop_estimator"]})


#: library field → flag of `cdgps track` / `track-structure` (their option errors name the flag given)
TRACK_FLAGS = {"pll_bn_hz": "--pll-bn", "pull_in_s": "--pull-in", "prns": "--prn"}


@main.command("track", short_help="Track GPS L1 C/A in raw IF samples → TRACK.mcap")
@click.argument("iq_file", type=click.Path(dir_okay=False))
@click.option("--format", "fmt", required=True, type=click.Choice(["int8-iq", "int16-iq", "int8-real", "int16-real"]),
              help="Sample format: interleaved signed I,Q (complex) or real samples, 8 or 16 bit.")
@click.option("--iq-sign", type=click.Choice(["minus", "plus"]), default="minus", show_default=True,
              help="Complex formats: read I − jQ (Pocket SDR convention) or I + jQ.")
@click.option("--fs", "fs_hz", type=float, required=True, help="Sample rate, Hz.")
@click.option("--if", "if_hz", type=float, default=0.0, show_default=True, help="Intermediate frequency, Hz (0: baseband).")
@click.option("--prn", "prns", type=int, multiple=True, help="Track only these PRNs (repeatable; default: every one acquired).")
@click.option("--duration", "duration_s", type=float, default=None, help="Seconds of the file to use (default: all).")
@click.option("--pll-bn", "pll_bn_hz", type=float, default=TRACK_DEFAULTS["pll_bn_hz"], show_default=True, help="PLL noise bandwidth, Hz, in (0, 100].")
@click.option("--pull-in", "pull_in_s", type=float, default=TRACK_DEFAULTS["pull_in_s"], show_default=True, help="FLL pull-in before the PLL, s (0 or more).")
@click.option("--noncoherent-ms", type=int, default=None,
              help="Acquisition: 1 ms correlations summed non-coherently [10] (10 detects 38 dB-Hz, 20 36 dB-Hz, "
                   "docs/tracking.md).")
@click.option("--false-alarm", type=float, default=None,
              help="Acquisition: probability that noise alone is taken for a satellite, per PRN searched [1e-4].")
@_output_option("output", "TRACK.mcap to write.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary (satellites with prn, doppler_hz, "
              "code_phase_chips, cn0_dbhz, phase_lock) on stdout.")
@click.pass_context
def track_cmd(ctx, iq_file, fmt, iq_sign, fs_hz, if_hz, prns, duration_s, pll_bn_hz, pull_in_s, noncoherent_ms,
              false_alarm, output, as_json):
    """Acquire every GPS L1 C/A satellite strong enough in a raw sample file and track it (FLL pull-in,
    Costas PLL, carrier-aided DLL): Doppler, code phase, carrier phase, C/N0 and lock per millisecond."""
    from cdgps_cli.pipeline.track import track_file
    from cdgps_cli.tracking.channel import TrackOptions
    from cdgps_cli.tracking.receiver import check_prns

    opt = _named_by_flags(lambda: TrackOptions(pll_bn_hz=pll_bn_hz, pull_in_s=pull_in_s), TRACK_FLAGS)
    _named_by_flags(lambda: check_prns(prns), TRACK_FLAGS)
    with progress.stage("tracking"):
        s = track_file(iq_file, output, fmt=fmt, fs_hz=fs_hz, if_hz=if_hz, iq_sign=iq_sign,
                       prns=list(prns) or None, duration_s=duration_s, opt=opt, noncoherent_ms=noncoherent_ms,
                       false_alarm=false_alarm, progress=None if ctx.obj.get("quiet") else progress.write)
    for sat in s["satellites"]:
        cn0 = "–" if sat["cn0_dbhz"] is None else f"{sat['cn0_dbhz']:.1f}"
        _say(ctx, f"  PRN {sat['prn']:>2}: {sat['doppler_hz']:+8.1f} Hz, code {sat['code_phase_chips']:7.2f} chips, "
                  f"C/N0 {cn0} dB-Hz, phase lock {'yes' if sat['phase_lock'] else 'no'} "
                  f"({100 * sat['phase_lock_fraction']:.0f}% of windows)")
    _say(ctx, f"wrote {output}: {len(s['satellites'])} satellites, {s['duration_s']:.3f} s")
    if as_json:
        _emit_json({k: v for k, v in s.items() if k != "acquisition"})


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
    except (CdgpsError, click.exceptions.Exit, click.ClickException, KeyboardInterrupt, Terminated):
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

@main.command("simulate-if", short_help="Simulate GPS IF samples of a structure's antennas")
@click.argument("config", type=click.Path(dir_okay=False))
@click.argument("sim_dir", type=click.Path(file_okay=False))
@click.option("--start", "start_s", type=float, default=0.0, show_default=True,
              help="Structure time of the first sample, s (inside the simulation SIM_DIR).")
@click.option("--duration", "duration_s", type=float, default=1.0, show_default=True,
              help="Seconds of samples (each antenna's file: 2 bytes × fs × duration).")
@click.option("--fs", "fs_hz", type=float, default=4e6, show_default=True,
              help="Sample rate, Hz (a whole number of samples per millisecond, at least 2.1 MHz).")
@click.option("--if", "if_hz", type=float, default=0.0, show_default=True, help="Intermediate frequency, Hz (0: baseband).")
@click.option("--bits", type=int, default=8, show_default=True, help="Quantizer bits per component, 1 to 8.")
@click.option("--iq-sign", type=click.Choice(["minus", "plus"]), default="minus", show_default=True,
              help="Write Q so that the samples read back as I − jQ (Pocket SDR convention) or I + jQ.")
@click.option("--cn0", "cn0", multiple=True, metavar="DB|TX:DB",
              help="C/N0 in dB-Hz of every transmitter (DB) or of one (TX:DB, repeatable) [45].")
@click.option("--prn", "prns", multiple=True, metavar="TX:PRN",
              help="PRN of a transmitter (repeatable; default PRN 1, 2, … in config order).")
@click.option("--oscillator", default="0,0,0", show_default=True, metavar="H0,H-1,H-2",
              help="Receiver oscillator (shared by every antenna): fractional-frequency PSD h0 + h-1/f + h-2/f².")
@click.option("--clock-offset-ppm", type=float, default=0.0, show_default=True,
              help="Receiver oscillator frequency offset, ppm (a Doppler common to every transmitter).")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (same seed → identical files).")
@_output_option("out_dir", "Output directory (<antenna>.bin per antenna and the manifest if.json).", directory=True)
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def simulate_if_cmd(ctx, config, sim_dir, start_s, duration_s, fs_hz, if_hz, bits, iq_sign, cn0, prns, oscillator,
                    clock_offset_ppm, seed, out_dir, as_json):
    """Simulate the GPS L1 C/A samples (int8 I/Q) each antenna of a structure receives, on the antenna
    trajectories of a `cdgps simulate` folder: C/A codes, navigation bits, delays and carrier phases from
    the geometry, thermal noise, one receiver oscillator for all antennas, quantization.
    `cdgps track-structure OUT_DIR/if.json` turns them into a receiver log."""
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.pipeline.if_chain import parse_cn0, parse_oscillator, parse_prns, simulate_if
    from cdgps_cli.sim.if_samples import IfOptions, StructureIf

    cfg = load_config(config)
    every, per = parse_cn0(cn0)
    spec = StructureIf(start_s=start_s, duration_s=duration_s, cn0_dbhz=45.0 if every is None else every,
                       cn0_overrides=per, prns=parse_prns(prns), oscillator=parse_oscillator(oscillator, clock_offset_ppm),
                       options=IfOptions(fs_hz=fs_hz, if_hz=if_hz, bits=bits, iq_sign=iq_sign, seed=seed))
    with progress.stage("simulating IF samples"):
        s = simulate_if(cfg, sim_dir, out_dir, spec, progress=None if ctx.obj.get("quiet") else progress.write)
    _say(ctx, f"wrote {len(s['antennas'])} sample files of {s['duration_s']:g} s ({s['bytes'] / 2**20:.1f} MiB) and "
              f"if.json to {out_dir}/")
    if as_json:
        _emit_json(s)


@main.command("track-structure", short_help="Track a structure's IF samples → receiver log")
@click.argument("if_json", type=click.Path(dir_okay=False))
@click.option("--config", "config", required=True, type=click.Path(dir_okay=False),
              help="Structure config the samples were simulated for (its antennas, master, epochs).")
@click.option("--pll-bn", "pll_bn_hz", type=float, default=TRACK_DEFAULTS["pll_bn_hz"], show_default=True, help="PLL noise bandwidth, Hz, in (0, 100].")
@click.option("--pull-in", "pull_in_s", type=float, default=TRACK_DEFAULTS["pull_in_s"], show_default=True, help="FLL pull-in before the PLL, s (0 or more).")
@click.option("--aid", type=click.Choice(["none", "truth", "gyro", "model"]), default="none", show_default=True,
              help="External Doppler aid of every PLL: none; truth, the true line-of-sight Doppler from IF_JSON's truth "
                   "(a perfect inertial or structural-model prediction); gyro, the Doppler of the antenna velocity "
                   "derived from the structure's rate gyros (--gyro, with their biases and noise) through the kinematics; "
                   "model, the same rates through the config's mode shapes.")
@click.option("--gyro", "gyro_csv", type=click.Path(dir_okay=False, exists=True), default=None,
              help="gyro.csv of `cdgps simulate` (needed by --aid gyro and --aid model).")
@click.option("--pose", "pose_csv", type=click.Path(dir_okay=False, exists=True), default=None,
              help="--aid gyro/model: the structure's pose at the first sample, from a CSV with time_s and the "
                   "config's coordinates (truth.csv of `cdgps simulate`, or an estimate's states CSV); the gyros "
                   "carry it on.  Default: the rest pose (all coordinates 0).")
@click.option("--clock-bn", "clock_bn_hz", type=float, default=None,
              help="Share one receiver-clock loop of this noise bandwidth (Hz, in (0, 100]) among each antenna's channels "
                   "(the clock-error frequency estimated across channels; default: independent loops).")
@click.option("--acquisition", type=click.Choice(["search", "truth"]), default="search", show_default=True,
              help="Start the loops from an FFT search of each file, or from IF_JSON's true Doppler and code phase "
                   "(an assisted start, to study the loops below the search's threshold).")
@_output_option("output", "Receiver log CSV to write (time_s,receiver,master,antenna,transmitter,phase_cycles,lock,snr_dbhz).")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary (rows, channels, satellites per antenna) on stdout.")
@click.pass_context
def track_structure_cmd(ctx, if_json, config, pll_bn_hz, pull_in_s, aid, gyro_csv, pose_csv, clock_bn_hz, acquisition,
                        output, as_json):
    """Track every antenna's samples listed in IF_JSON (from `cdgps simulate-if`), difference each
    antenna's carrier phase against the master's per transmitter (half cycles resolved by the data
    bits) and write the native receiver log at the config's epochs, for `cdgps ingest`."""
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.pipeline.if_chain import ChainOptions, track_structure
    from cdgps_cli.tracking.channel import TrackOptions

    def options():
        o = ChainOptions(track=TrackOptions(pll_bn_hz=pll_bn_hz, pull_in_s=pull_in_s), aid=aid,
                         acquisition=acquisition, gyro_csv=gyro_csv, pose_csv=pose_csv, clock_bn_hz=clock_bn_hz)
        o.check()
        return o

    opt = _named_by_flags(options, {**TRACK_FLAGS, "clock_bn_hz": "--clock-bn"})
    cfg = load_config(config)
    with progress.stage("tracking"):
        s = track_structure(if_json, cfg, output, opt, progress=None if ctx.obj.get("quiet") else progress.write)
    _say(ctx, f"wrote {output}: {s['rows']} rows, {s['epochs']} epochs, "
              f"{sum(c['segments'] for c in s['channels'])} lock segments on {len(s['channels'])} channels")
    if as_json:
        _emit_json(s)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())


@main.command(short_help="Multi-GNSS, multi-frequency RTK of a pair → CSV")
@click.option("--base", "base_file", required=True, type=click.Path(dir_okay=False),
              help="Base observations: RINEX, or a u-blox log (RXM-RAWX; its RTCM 1005/1006 position is used).")
@click.option("--rover", "rover_file", required=True, type=click.Path(dir_okay=False),
              help="Rover observations: RINEX, or a u-blox log (RXM-RAWX).")
@click.option("--nav", "nav_files", multiple=True, type=click.Path(dir_okay=False),
              help="RINEX navigation file(s) with the GPS / Galileo / BeiDou / GLONASS ephemerides (repeatable); "
                   "without it, the u-blox logs' RXM-SFRBX ephemerides.")
@click.option("--signals", default="auto", show_default=True,
              help="Comma-separated signals (G:L1, G:L2, G:L5, E:E1, E:E5a, E:E5b, C:B1I, C:B2I, C:B2a, R:G1, R:G2; "
                   "GLONASS stays float unless --glonass-fix), or 'auto': every one both files hold whose system has "
                   "ephemerides in --nav.")
@click.option("--mode", type=click.Choice(["kinematic", "static"]), default="kinematic", show_default=True,
              help="kinematic: random-walk rover position, a solution per epoch; static: one position for the span.")
@click.option("--base-xyz", nargs=3, type=float, default=None, help="Base ECEF position, m (default: its header).")
@click.option("--glonass-fix", is_flag=True, default=False,
              help="Fix GLONASS (FDMA) integers too: only for identical base and rover receivers (default: float).")
@click.option("--mask-deg", type=float, default=None,
              help=f"Elevation mask, degrees [{__import__('cdgps_cli.config.options', fromlist=['x']).MULTI_GNSS_DEFAULTS['mask_deg']:g}].")
@click.option("--ratio", "ratio_threshold", type=float, default=None,
              help=f"LAMBDA ratio-test threshold [{__import__('cdgps_cli.config.options', fromlist=['x']).MULTI_GNSS_DEFAULTS['ratio']:g}].")
@click.option("--max-age", "max_age_s", type=float, default=None,
              help="Oldest base epoch bridged across a base gap or a lower base rate, s "
                   f"[{__import__('cdgps_cli.config.options', fromlist=['x']).EPOCH_PAIRING_DEFAULTS['max_age_s']:g}, RTKLIB's].")
@click.option("--sync-tol", "sync_tol_s", type=float, default=None,
              help="Base and rover epochs this close are simultaneous, s "
                   f"[{__import__('cdgps_cli.config.options', fromlist=['x']).EPOCH_PAIRING_DEFAULTS['sync_tol_s']:g}].")
@click.option("--direction", type=click.Choice(["forward", "backward", "combined"]), default=None,
              help="Kinematic passes: forward, backward, or both combined - an epoch is fixed where the passes' fixes "
                   "agree (or one's fix agrees with the other's float); disagreeing fixes are rejected [combined].")
@click.option("--code-correlation", "code_correlation_s", type=float, default=None,
              help="Correlation time of the code errors, s: their variance is inflated by (1+ρ)/(1−ρ), ρ = e^(−Δt/τ), so "
                   "a minute of correlated multipath is not taken as 60 independent ranges [0: white, as RTKLIB].")
@click.option("--fix-and-hold", is_flag=True, default=False,
              help="After --hold-after-fixes consecutive fixed epochs, feed the fixed integers back as measurements "
                   "(RTKLIB's fix-and-hold; a wrong fix is then held too: the combined mode's check still applies).")
@click.option("--hold-after-fixes", "hold_after_fixes", type=click.IntRange(min=1), default=None,
              help="Consecutive fixed epochs before --fix-and-hold holds the integers (RTKLIB pos2-arminfix) "
                   f"[{__import__('cdgps_cli.config.options', fromlist=['x']).MULTI_GNSS_DEFAULTS['hold_after_fixes']}].")
@click.option("--min-success-rate", type=float, default=None,
              help="Bootstrapped success rate an integer set must reach; when the whole set does not, the part that "
                   "does is fixed and the epoch stays float [0.999].")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output: .pos (RTKLIB, lat/lon/height), .nmea/.gga (NMEA GGA), .geojson, or CSV (any other suffix).")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary (epochs used and why others were not, fixes) on stdout.")
@click.pass_context
def rtk(ctx, base_file, rover_file, nav_files, signals, mode, base_xyz, glonass_fix, mask_deg, ratio_threshold, max_age_s,
        sync_tol_s, direction, code_correlation_s, fix_and_hold, hold_after_fixes, min_success_rate, output, as_json):
    """Double differences per constellation and frequency, integers by LAMBDA (docs/gnss-pipeline.md, "Multi-GNSS").

    The rover's epochs drive the solution: each takes the nearest base epoch within --max-age (a base
    with gaps or a lower rate is bridged, its σ growing with the age); every rover epoch not used is
    counted with its reason."""
    from cdgps_cli.pipeline.gnss_multi import rtk_from_files

    options = {"signals": "auto" if signals.strip() == "auto" else tuple(x.strip() for x in signals.split(",") if x.strip()),
               "mode": mode, "fix_and_hold": fix_and_hold,
               "glonass_fix": glonass_fix}
    for key, value in (("mask_deg", mask_deg), ("ratio", ratio_threshold), ("max_age_s", max_age_s),
                       ("sync_tol_s", sync_tol_s), ("direction", direction), ("min_success_rate", min_success_rate),
                       ("code_correlation_s", code_correlation_s), ("hold_after_fixes", hold_after_fixes)):
        if value is not None:
            options[key] = value
    s = rtk_from_files(base_file, rover_file, list(nav_files), output, base_xyz_m=base_xyz or None, options=options)
    for w in s["warnings"]:
        _warn(w)
    ep = s["epoch_pairing"]
    _say(ctx, f"{output}: {s['epochs']} of {ep['rover_epochs']} rover epochs ({ep['bridged']} bridged across base gaps, "
              f"max age {ep['max_age_s']:.3g} s), fixed {s['fixed_pct']:.1f} % ({s['direction']}; "
              f"{s['fixes_rejected']} fixes rejected where the passes disagree), ionosphere {s['iono_model']}, "
              f"signals {' '.join(s['signals'])}")
    if as_json:
        _emit_json({k: v for k, v in s.items()})
