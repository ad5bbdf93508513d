"""The pipeline stages: simulate, ingest, info, init, estimate, export, evaluate, spectra, report
static/spectrum (structure runs and GNSS runs alike); each a thin shell over its library function."""

from __future__ import annotations

import math
import re
from contextlib import contextmanager
from pathlib import Path

import click

from cdgps_cli.config.options import (ESTIMATE_DEFAULTS, INIT_MAX_ITERATIONS, INIT_STARTS, RATIO_THRESHOLD,
                                     SCENE_EXAGGERATION, SCENE_EXAGGERATION_MAX, SPECTRA_DEFAULTS, X_AXIS_AZIMUTH_DEG)
from cdgps_cli.core import progress
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.states_layout import COVARIANCE_CHOICES as _STATES_COVARIANCE
from cdgps_cli.io.states_layout import DEFAULT_COVARIANCE as _STATES_DEFAULT_COVARIANCE
from cdgps_cli.io.states_layout import DEFAULT_PREVIEW_RATE_HZ as _STATES_PREVIEW_RATE_HZ
from cdgps_cli.cli.app import (_echo, _warn, _say, _output_option, _emit_json, main, _parse_named_files,
                               _parse_antenna_types,
                               _write_json_atomic, _with, _report_outputs)


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
@click.option("--sensor-log", "sensor_logs", multiple=True, type=click.Path(dir_okay=False),
              help="GNSS: a sensor CSV log (accelerometers, tilt meters, gyros; units in the column names, "
                   "docs/file-formats.md), or [NAME=]FILE.ubx, a u-blox log's ESF-MEAS IMU data (sensors NAME-accel, "
                   "NAME-gyro; NAME default imu), for 'estimate --fuse'; repeatable. Default: the GNSS config's sensors "
                   "key. A --ubx receiver log with ESF-MEAS gives sensors ANTENNA-accel, ANTENNA-gyro by itself.")
@click.option("--signals", "signals", default=None, metavar="auto|NAMES",
              help="GNSS without --config: 'auto' (every GPS, Galileo, BeiDou and GLONASS signal all receivers hold whose "
                   "system has ephemerides, as "
                   "'cdgps config' and 'cdgps rtk' choose) or comma-separated names (G:L1,E:E1,...) [auto]; with "
                   "--config, its [gnss] signals.")
@click.option("--antex", "antex", type=click.Path(dir_okay=False), default=None,
              help="GNSS: ANTEX file of the receivers' antenna calibrations, kept in the RUN and taken out of their "
                   "observations by init/estimate [the config's antex, else none].")
@click.option("--antenna", "antenna", multiple=True, metavar="ANTENNA=TYPE",
              help="GNSS: an antenna's type and radome as the ANTEX file names them, or none [its RINEX header's].")
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="RUN.mcap to write.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def ingest(ctx, receiver_csv, gyro_csv, actuator_csv, config, rinex, ubx, nav, master, strict, output, as_json,
           sensor_logs=(), antex=None, antenna=(), signals=None):
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
    gnss = bool(rinex or ubx or nav or master or antex or antenna or signals)
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
        _ingest_gnss(ctx, config, rinex, ubx, nav, master, output, as_json, strict, sensor_logs, antex, antenna,
                     signals)
        return
    if sensor_logs:
        raise click.UsageError("--sensor-log applies to GNSS runs (the structure run's gyro log is GYRO_CSV)")
    if strict:
        raise click.UsageError("--strict applies to GNSS receiver files (UBX logs given with --ubx or in a GNSS config)")
    from cdgps_cli.config.structure import load_config

    if receiver_csv is None:
        if config is not None:
            load_config(config)          # a config that is not valid TOML is named first (it may be a GNSS one)
        raise click.UsageError("Missing argument 'RECEIVER_CSV' (or give GNSS files with --rinex/--ubx).")
    if config is None:
        raise click.UsageError("Missing option '--config'.")
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


def _ingest_gnss(ctx, config, rinex, ubx, nav, master, output, as_json, strict=False, sensor_logs=(), antex=None,
                 antenna=(), signals=None):
    from cdgps_cli.config.structure import load_gnss_config, parse_gnss_config
    from cdgps_cli.io.gnss_run import default_config_text
    from cdgps_cli.pipeline.gnss_ingest import chosen_signals, ingest_gnss, with_antenna_options

    rx, ub = _parse_named_files(rinex, "--rinex"), _parse_named_files(ubx, "--ubx")
    if config and signals is not None:
        raise CdgpsError(f"--signals: the config's [gnss] signals choose the signals of a run with --config ({config}); "
                         f"give --signals without --config, or write them in the config")
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
        sig = "auto" if signals is None or signals.strip() == "auto" else [x.strip() for x in signals.split(",") if x.strip()]
        said: list = []
        sig = chosen_signals(sig, rx, ub, list(nav), said)
        for w in said:
            _warn(w)
        cfg = parse_gnss_config(default_config_text(files, list(nav), master, sig), "<generated config>")
    if antex or antenna:
        cfg = with_antenna_options(cfg, antex, _parse_antenna_types(antenna))
    s = ingest_gnss(cfg, output, rinex=rx or None, ubx=ub or None, nav_paths=list(nav) if nav else None, master=master,
                    progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)), strict=strict,
                    sensor_paths=list(sensor_logs) if sensor_logs else None)
    from cdgps_cli.io.gnss_run import ubx_loss_warning

    for n, g in s["integrity"].items():        # lost data is reported even with --quiet
        if g["problems"]:
            _warn(ubx_loss_warning(n, g))
        if g.get("other_protocols"):
            _say(ctx, f"  {g['file']} ({n}): skipped other protocols' frames between the UBX frames: {g['other_protocols']}")
    _say(ctx, f"wrote {output}: GNSS run {s['config']}, master {s['master']}, {len(s['receivers'])} receiver(s), "
              f"{s['ephemerides']} ephemerides, {cfg.displacement} displacement model")
    for r in s["receivers"]:
        _say(ctx, f"  {r['name']:<8} {r['format']:<5} {r['file']}: {r['epochs']} epochs {r['first']} – {r['last']} "
                  f"({'one epoch' if r['interval_s'] is None else 'sampled at ' + format(r['interval_s'], 'g') + ' s'}), {r['satellites']} satellites, {r['phase_rows']} phases{_signals_note(r)}, "
                  f"{r['slips']} slips, {r['half_cycle_rows']} half-cycle rows")
    for n, c in s["common_epochs"].items():
        _say(ctx, f"  {n}: {c['common_epochs']} epochs in common with {s['master']}" + _grid_note(c))
    if "sensor_logs" in s:
        _say(ctx, f"  sensor logs ({', '.join(s['sensor_logs']['kinds'])}): {', '.join(s['sensor_logs']['files'])}")
    for n, imu in s.get("receiver_imu", {}).items():
        _say(ctx, f"  {n}: IMU in the receiver log ({imu['messages']} ESF-MEAS): sensors "
                  + ", ".join(f"{n}-{k}" for k in imu["kinds"]))
    for w in s["warnings"]:
        _warn(w)
    if as_json:
        _emit_json(s)


def _placement_options(f):
    """--x-axis-azimuth-deg and --receiver of a GNSS run with --structure (init and estimate)."""
    f = click.option("--receiver", "receiver_map", multiple=True, metavar="ANTENNA=RECEIVER",
                     help="With --structure: the receiver of a structure antenna (repeatable; default: the same name).")(f)
    return click.option("--x-axis-azimuth-deg", "x_axis_azimuth_deg", type=float, default=X_AXIS_AZIMUTH_DEG, show_default=True,
                        help="With --structure: azimuth of the structure x axis, degrees clockwise from north "
                             "(90: x east, y north).")(f)


@main.command("init", short_help="Batch bias init and LAMBDA integers → INIT.json")
@click.argument("run_mcap", type=click.Path(dir_okay=False))
@click.option("--start", "start_s", type=float, default=None,
              help="Window start, s (default: automatic; GNSS runs: from the record's first epoch, default 0).")
@click.option("--duration", "duration_s", type=float, default=None,
              help="Window length, s (default: 60 s; GNSS runs: to the record's end; estimate then uses the same window).")
@click.option("--every", "every_s", type=float, default=None,
              help="GNSS runs: an INIT per window of this many seconds from the record's first epoch (over --start "
                   "… --start + --duration of it), each solved alone; -o is then a pattern with {k}, the window's index "
                   "(init-{k:03d}.json), for 'cdgps estimate RUN --init \'init-*.json\''. A window without "
                   "observations of a receiver is skipped and said.")
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
def init_cmd(ctx, run_mcap, start_s, duration_s, every_s, no_process_noise, float_only, ratio_threshold, no_partial,
             starts, max_iterations, sigma_m, multipath_sigma_m, multipath_time_constant_s, output, as_json,
             structure=None, x_axis_azimuth_deg=X_AXIS_AZIMUTH_DEG, receiver_map=()):
    """Batch bias initialization (Eq. 9-15) with LAMBDA integer fixing → INIT.json.

    On a GNSS run (RINEX/UBX receivers): float DD solution, LAMBDA integers (ratio test, partial
    fixing) and the fixed static displacement of every rover → INIT.json (docs/gnss-pipeline.md).
    """
    from cdgps_cli.io.file_checks import GNSS_RUN, RUNS, require_kind

    gnss = require_kind(run_mcap, RUNS, "RUN_MCAP") == GNSS_RUN    # (the file's metadata read once)
    if every_s is not None:
        if not gnss or structure is not None or receiver_map:
            raise CdgpsError("--every: windows of a GNSS run's record (not with --structure / --receiver, nor on a "
                             "structure run)")
        _init_gnss_windows(ctx, run_mcap, every_s, start_s, duration_s, float_only, ratio_threshold, no_partial,
                           output, as_json, {"--no-process-noise": no_process_noise, "--sigma-m": sigma_m is not None,
                                             "--starts": starts != INIT_STARTS,
                                             "--max-iterations": max_iterations != INIT_MAX_ITERATIONS,
                                             "--multipath-sigma-m": multipath_sigma_m is not None,
                                             "--multipath-tau-s": multipath_time_constant_s is not None})
        return
    if gnss:
        _init_gnss(ctx, run_mcap, float_only, ratio_threshold, no_partial, output, as_json,
                   structure=(structure, x_axis_azimuth_deg, receiver_map) if (structure or receiver_map) else None,
                   window_s=None if start_s is None and duration_s is None else (start_s or 0.0, duration_s),
                   structure_only={"--no-process-noise": no_process_noise, "--sigma-m": sigma_m is not None,
                                   "--starts": starts != INIT_STARTS, "--max-iterations": max_iterations != INIT_MAX_ITERATIONS,
                                   "--multipath-sigma-m": multipath_sigma_m is not None,
                                   "--multipath-tau-s": multipath_time_constant_s is not None})
        return
    from cdgps_cli.estimation.initializer import InitOptions, initialize
    from cdgps_cli.io.atomic import file_sha256
    from cdgps_cli.io.run import read_run

    if structure is not None or receiver_map:
        raise CdgpsError("--structure/--receiver apply to GNSS runs (from 'cdgps ingest --rinex/--ubx'); a structure "
                         "run's RUN.mcap already names its structure config")
    run = read_run(run_mcap, on_disk=True)   # the phase table read in blocks from disk (init reads its window)
    opt = InitOptions(start_s=start_s, duration_s=duration_s, process_noise=not no_process_noise,
                      fix_integers=not float_only, ratio_threshold=ratio_threshold, partial=not no_partial,
                      starts=starts, max_iterations=max_iterations, sigma_m=sigma_m,
                      multipath_sigma_m=multipath_sigma_m, multipath_time_constant_s=multipath_time_constant_s,
                      progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)))
    res = initialize(run, opt)
    res["run_sha256"] = file_sha256(Path(run_mcap))      # (in pieces: not the whole file in memory)
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
@click.option("--init", "init_json", required=True, multiple=True, type=click.Path(dir_okay=False),
              help="INIT.json from 'cdgps init'. A GNSS run's displacement estimate takes several (repeated, or a quoted "
                   "glob pattern): INITs of windows of the run that do not overlap ('cdgps init --start --duration'), "
                   "each serving its own window, read and solved one at a time, into one STATES (the random walk and "
                   "constant velocity filtered and smoothed over all of them).")
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
@click.option("--fuse", "fuse", default=None, metavar="KINDS",
              help="Fuse the run's sensor logs of these kinds with the carrier phases (comma-separated: gyro,accel,tilt; "
                   "opt-in; default: the structure config's [fusion] fuse): GNSS runs with --structure (double "
                   "differences), or a structure run's rate gyros (--fuse gyro, single differences). "
                   "A fused gyro is no longer an independent check of the spectra.")
@click.option("--hold-out", "hold_out", multiple=True, metavar="SENSOR",
              help="With --fuse: keep this sensor out of the fusion, as an independent check (repeatable; adds to "
                   "[fusion] hold_out).")
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
@click.option("--scene-exaggeration", default=SCENE_EXAGGERATION, show_default=True, metavar="FACTOR|auto",
              help="The structure drawn in 3-D in STATES.mcap (/cdgps/scene, foxglove.SceneUpdate, at the Foxglove "
                   "rate): factor on the deformation (its rigid-body rotation at true scale); auto: 1, 2, 5, 10, … "
                   "so that the largest deformation shows at about 5% of the structure's size; 0: no 3-D scene.")
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="STATES.mcap to write.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def estimate(ctx, run_mcap, init_json, smooth, biases, sigma_m, nis_probability, outlier_sigma, process_noise_scale,
             output, as_json, rest=(), rest_process_noise_scale=ESTIMATE_DEFAULTS["rest_process_noise_scale"],
             rest_retry_s=ESTIMATE_DEFAULTS["rest_retry_s"], structure=None, x_axis_azimuth_deg=X_AXIS_AZIMUTH_DEG,
             receiver_map=(), rest_window_s=ESTIMATE_DEFAULTS["rest_window_s"],
             rest_dwell_s=ESTIMATE_DEFAULTS["rest_dwell_s"], allow_other_run=False,
             covariance=_STATES_DEFAULT_COVARIANCE, foxglove_rate_hz=None, scene_exaggeration=SCENE_EXAGGERATION,
             fuse=None, hold_out=()):
    """Extended Kalman filter (Eq. 16-23) [+ RTS smoother] over a RUN from INIT → STATES.mcap.

    On a GNSS run: per-epoch rover displacement states <ant>_e/_n/_u with 1σ from INIT's
    integers (static: the batch solution; random_walk / constant_velocity: Kalman filter [+ RTS smoother]), plus
    single-epoch solutions, DD residuals and slip/reference events (docs/gnss-pipeline.md).
    """
    from cdgps_cli.io.file_checks import GNSS_RUN, RUNS, require_kind
    from cdgps_cli.io.file_patterns import expand_paths

    init_jsons = expand_paths(init_json, "--init")
    gnss_run = require_kind(run_mcap, RUNS, "RUN_MCAP") == GNSS_RUN        # (the file's metadata read once)
    if len(init_jsons) > 1:
        if not gnss_run or structure is not None or receiver_map or fuse or hold_out:
            raise CdgpsError(f"--init given {len(init_jsons)} times: several INITs (windows of one record) serve only "
                             f"a GNSS run's displacement estimate (no --structure / --receiver / --fuse)")
        _estimate_gnss_windows(ctx, run_mcap, init_jsons, smooth, output, as_json, allow_other_run,
                               _structure_only_given(biases, sigma_m, nis_probability, outlier_sigma,
                                                     process_noise_scale, rest, rest_process_noise_scale, rest_retry_s,
                                                     rest_window_s, rest_dwell_s, structure, receiver_map,
                                                     scene_exaggeration, covariance, foxglove_rate_hz))
        return
    init_json = init_jsons[0]
    if gnss_run:
        with _init_named(init_json):
            _estimate_gnss(ctx, run_mcap, init_json, smooth, output, as_json,
                           structure_only=_structure_only_given(biases, sigma_m, nis_probability, outlier_sigma,
                                                                process_noise_scale, rest, rest_process_noise_scale,
                                                                rest_retry_s, rest_window_s, rest_dwell_s,
                                                                structure, receiver_map, scene_exaggeration,
                                                                covariance, foxglove_rate_hz),
                           structure=structure, x_axis_azimuth_deg=x_axis_azimuth_deg, receiver_map=receiver_map,
                           allow_other_run=allow_other_run, scene_exaggeration=_scene_factor(scene_exaggeration),
                           fuse=fuse, hold_out=hold_out)
        return
    scene_exaggeration = _check_structure_run_options(foxglove_rate_hz, scene_exaggeration, structure, receiver_map,
                                                      nis_probability)
    from cdgps_cli.estimation.filter import EstimateOptions
    from cdgps_cli.io.file_checks import read_init_json
    from cdgps_cli.io.run import read_run
    from cdgps_cli.io.scratch import DiskHistory
    from cdgps_cli.pipeline.estimate_outputs import write_states

    init, init_text = read_init_json(init_json)
    pairing = _check_pairing(ctx, init, init_json, run_mcap, allow_other_run)
    rest_auto, rest_segments = _rest_choice(rest, rest_process_noise_scale, rest_retry_s, rest_window_s, rest_dwell_s)
    run = read_run(run_mcap, on_disk=True)   # the phase table read in blocks from disk (memory flat in the record)
    opt = EstimateOptions(biases=biases, smooth=smooth, sigma_m=sigma_m, nis_probability=nis_probability,
                          outlier_sigma=outlier_sigma, process_noise_scale=process_noise_scale,
                          rest_segments_s=rest_segments, rest_process_noise_scale=rest_process_noise_scale,
                          rest_retry_s=rest_retry_s, rest_auto=rest_auto, rest_window_s=rest_window_s,
                          rest_dwell_s=rest_dwell_s,
                          keep_filtered_covariance="full" if covariance == "full" else "modal",
                          init_source=str(init_json),
                          # the filter's history on disk beside the output (removed however the run ends),
                          # so memory does not grow with the record; the result holds what STATES stores
                          history=DiskHistory(Path(output).resolve().parent, output),
                          keep_covariance="full" if covariance == "full" else "modal",
                          progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)))
    res, fuse_kinds = _run_structure_filter(ctx, run, init, init_json, run_mcap, opt, fuse, hold_out)
    del run                                  # the phase table is not needed for writing (memory)
    options = opt.echo()
    if fuse_kinds:
        options["fusion"] = res.fusion
    if allow_other_run:
        options.update(allow_other_run=True, init_run_sha256=pairing["init_run_sha256"])
    s = write_states(res, run_mcap, init, init_text, output, options, covariance=covariance,
                     preview_rate_hz=foxglove_rate_hz, run_sha256=pairing["run_sha256"],
                     scene_exaggeration=scene_exaggeration)
    s["init_run"] = pairing
    if fuse_kinds:
        s["fusion"] = res.fusion
    _say_structure_estimate(ctx, s, res, output)
    s["measurement_noise"] = res.noise
    if as_json:
        _emit_json(s)


def _structure_only_given(biases, sigma_m, nis_probability, outlier_sigma, process_noise_scale, rest,
                          rest_process_noise_scale, rest_retry_s, rest_window_s, rest_dwell_s, structure,
                          receiver_map, scene_exaggeration, covariance=_STATES_DEFAULT_COVARIANCE,
                          foxglove_rate_hz=None) -> dict:
    """{option: given} of ``cdgps estimate``'s structure-run options (given: not at its default), for
    the refusal of those a GNSS run does not use."""
    def not_default(**values):           # {--option: given}, against the one home of the defaults
        return {"--" + k.replace("_", "-"): v != ESTIMATE_DEFAULTS[k] for k, v in values.items()}

    return {"--biases": biases != "fixed", "--sigma-m": sigma_m is not None,
            **not_default(nis_probability=nis_probability, outlier_sigma=outlier_sigma,
                         process_noise_scale=process_noise_scale),
            "--rest": bool(rest),
            **not_default(rest_process_noise_scale=rest_process_noise_scale, rest_retry_s=rest_retry_s,
                         rest_window_s=rest_window_s, rest_dwell_s=rest_dwell_s),
            "--scene-exaggeration": structure is None and not receiver_map
            and str(scene_exaggeration) != str(SCENE_EXAGGERATION),
            # (a GNSS run's STATES: the positions' covariance and every epoch in the JSON channels; these were
            # ignored without a word)
            "--covariance": covariance != _STATES_DEFAULT_COVARIANCE, "--foxglove-rate-hz": foxglove_rate_hz is not None}


def _check_structure_run_options(foxglove_rate_hz, scene_exaggeration, structure, receiver_map,
                                 nis_probability: float) -> float | str:
    """Refuse a bad ``--foxglove-rate-hz`` (Hz), ``--structure``/``--receiver`` (GNSS runs only) and a
    ``--nis-probability`` outside (0.5, 1) on a structure run; the scene factor (:func:`_scene_factor`)."""
    if foxglove_rate_hz is not None and not (foxglove_rate_hz >= 0 and math.isfinite(foxglove_rate_hz)):
        raise CdgpsError(f"--foxglove-rate-hz must be a finite rate >= 0 (0: every epoch), got {foxglove_rate_hz:g}")
    scene_exaggeration = _scene_factor(scene_exaggeration)
    if structure is not None or receiver_map:
        raise CdgpsError("--structure/--receiver apply to GNSS runs (from 'cdgps ingest --rinex/--ubx'); a structure "
                         "run already has its config")
    if not 0.5 < nis_probability < 1.0:
        raise CdgpsError(f"--nis-probability must be in (0.5, 1), got {nis_probability:g}")
    return scene_exaggeration


def _rest_choice(rest, rest_process_noise_scale: float, rest_retry_s: float, rest_window_s: float,
                 rest_dwell_s: float) -> tuple[bool, tuple]:
    """``--rest``: (auto detection?, declared (start_s, end_s) segments), checked with the rest options."""
    from cdgps_cli.estimation.filter import validate_rest_segments

    rest_auto = any(r.strip().lower() == "auto" for r in rest)
    if rest_auto and len(rest) > 1:
        raise CdgpsError("--rest auto cannot be combined with declared --rest START:END segments")
    rest_segments = () if rest_auto else tuple(_parse_rest(r) for r in rest)
    validate_rest_segments(rest_segments, rest_process_noise_scale, rest_retry_s)
    if rest_auto:
        from cdgps_cli.estimation.rest import validate_detector

        validate_detector(rest_window_s, rest_dwell_s, 1.0)
    return rest_auto, rest_segments


def _run_structure_filter(ctx, run, init: dict, init_json, run_mcap, opt, fuse, hold_out) -> tuple:
    """The EKF [+ smoother] over a structure run, fused with its gyros when chosen:
    ``(result, fused sensor kinds)``."""
    from cdgps_cli.estimation.filter import estimate as run_ekf
    from cdgps_cli.pipeline.fusion import fusion_choice

    fuse_kinds, held = fusion_choice(run.cfg, fuse, hold_out)
    _say(ctx, f"estimating {run_mcap} from {init_json} (biases {opt.biases}{', smoothing' if opt.smooth else ''}"
              f"{', fusing ' + ','.join(fuse_kinds) if fuse_kinds else ''}) …")
    with _init_named(init_json):
        if fuse_kinds:
            from cdgps_cli.pipeline.fusion import fuse_with_pseudolite

            return fuse_with_pseudolite(run, init, opt, fuse_kinds, held), fuse_kinds
        return run_ekf(run, init, opt), fuse_kinds


def _say_structure_estimate(ctx, s: dict, res, output) -> None:
    """The structure-run estimate's lines on stderr: epochs, NIS, the measurement noise and the first events."""
    nis_text = "no filter epoch with data" if s["mean_nis_per_dof"] is None else f"mean NIS/dof {s['mean_nis_per_dof']:.3f}"
    w = s.get("window")
    src = (f"; {w['start_s']:g}–{w['end_s']:g} s from INIT's batch solution, then the filter" if w else "")
    _say(ctx, f"wrote {output}: {s['epochs']} epochs ({s['start_s']:g}–{s['end_s']:g} s{src}), "
              f"{nis_text}, {s['events']} events")
    if res.noise:
        _say_measurement_noise(ctx, res.noise)
    for ev in s["event_list"][:20]:
        ch = f" {ev['antenna']}/{ev['transmitter']}" if ev["antenna"] else ""
        _say(ctx, f"  {ev['time_s']:8.2f} s{ch}: {ev['kind']} → {ev['action']}")
    if len(s["event_list"]) > 20:
        _say(ctx, f"  … {len(s['event_list']) - 20} more events (topic /cdgps/events)")


def _say_measurement_noise(ctx, nz: dict) -> None:
    """The measurement σ (mm) the filter used, its innovation-based estimate and the multipath states."""
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
    mpn = nz.get("multipath")
    if mpn:
        _say(ctx, f"  multipath: Gauss–Markov state per channel, σ {mpn['sigma_m'] * 1000:.2f} mm, τ "
                  f"{mpn['time_constant_s']:g} s (from INIT.json; filter on the numpy path)")


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


@main.command("foxglove-layout", short_help="Foxglove layout for a STATES or RUN → JSON")
@click.argument("mcap_file", metavar="STATES_OR_RUN_MCAP", type=click.Path(dir_okay=False))
@_output_option("output", "Layout JSON to write (Foxglove: Layouts → Import from file)")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def foxglove_layout(ctx, mcap_file, output, as_json):
    """A Foxglove layout with the panels set for this kind of file. STATES.mcap: the structure in
    3-D (/cdgps/scene), the angles and coordinates with their 1-sigma, NIS against its 95%
    chi-square interval, and the events. Structure RUN.mcap: carrier-phase channels (one per antenna),
    their lock counters and C/N0, the gyro rates, and the phase messages; GNSS RUN.mcap: C/N0 and
    LLI flags per receiver, and the observations. Import it in Foxglove (Layouts → Import from
    file), then open the file (docs/file-formats.md, "Open in Foxglove")."""
    from cdgps_cli.io.file_checks import RUNS, STATES, require_kind
    from cdgps_cli.io.foxglove_layout import write_layout

    require_kind(mcap_file, STATES + RUNS, "STATES_OR_RUN_MCAP")
    s = write_layout(mcap_file, output)
    _say(ctx, f"wrote {output}: {len(s['panels'])} panels ({', '.join(s['panels'])})")
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


def _states_and_gyro(states_mcap, gyro_mcap, chunked: bool = False, covariance: bool = False):
    """STATES.mcap (state series only; ``chunked``: read in chunks, io.states.StatesChunks) and,
    optionally, the gyro log of a RUN.mcap."""
    from cdgps_cli.io.file_checks import STATES, STRUCTURE_RUN, require_kind
    from cdgps_cli.io.run import read_run
    from cdgps_cli.io.states import States, StatesChunks

    require_kind(states_mcap, STATES, "STATES_MCAP")
    if gyro_mcap:
        require_kind(gyro_mcap, STRUCTURE_RUN, "--gyro")
    st = StatesChunks(states_mcap, covariance=covariance) if chunked else States(states_mcap, diagnostics=False)
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


@main.command(short_help="PSDs, FDD modes, peaks → psd.csv, peaks.json")
@click.argument("states_mcap", type=click.Path(dir_okay=False))
@_with(_spectra_opts)
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False), help="Output directory.")
@click.option("--json", "as_json", is_flag=True, help="Print peaks.json on stdout.")
@click.pass_context
def spectra(ctx, states_mcap, gyro_mcap, coords, segment_s, overlap, pad, out_dir, as_json):
    """Welch PSDs vs gyros, FDD modal identification, each coordinate's spectral peaks (frequency, amplitude) →
    psd.csv, peaks.json, psd.png, fdd.png."""
    from cdgps_cli.report.sensor_reports import run_spectra
    st, run = _states_and_gyro(states_mcap, gyro_mcap, chunked=True)
    with progress.stage("spectra, mode fits and figures"):
        s = run_spectra(st, run, _spectra_options(coords, segment_s, overlap, pad), out_dir)
    seen = sum(1 for m in s["modes"] if m["seen"])
    found = (f"{seen} of {len(s['modes'])} modes identified" if s["modes"] else
             f"no model modes (the states' motion model has none), {len(s['peaks'])} spectral peak(s)")
    _say(ctx, f"wrote {', '.join(s['files'])} to {out_dir}/: {found}")
    if s.get("fusion") and not s["fusion"]["gyros_independent_check"]:
        _warn(s["fusion"]["note"])
    elif s.get("fusion"):
        _say(ctx, f"  {s['fusion']['note']}")
    for m in s["modes"]:
        g = "–" if m["gps_hz"] is None else f"{m['gps_hz']:.4f}"
        e = "" if m["error_pct"] is None else f" ({m['error_pct']:+.2f}%)"
        _say(ctx, f"  {m['mode']:<12} model {m['model_hz']:.4f} Hz  GPS {g} Hz{e}  {'seen' if m['seen'] else 'not seen'}")
    for p in s["peaks"]:
        _say(ctx, f"  peak {p['coordinate']:<12} {p['frequency_hz']:.4f} Hz  {_peak_amplitude_text(p)}  ({p['ratio']:.0f} × "
                  f"its floor)")
    if as_json:
        _emit_json({"modes": s["modes"], "peaks": s["peaks"], "settings": s["settings"]})


def _peak_amplitude_text(p: dict) -> str:
    """A spectral peak's amplitude as the summary prints it: the whole-record fit ± its σ (mm for metres, the unit
    else), or, for a peak no steady sinusoid explains, the PSD's amplitude so marked."""
    from cdgps_cli.report.sensor_reports import peak_amplitude  # noqa: PLC0415

    amp, sigma, unit, fit = peak_amplitude(p)
    unit = f" {unit}" if unit else ""
    if fit:
        return f"amplitude {amp:.3g} ± {sigma:.2g}{unit}"
    return f"amplitude ≈ {amp:.3g}{unit} (PSD; not a steady sinusoid)"


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
@_report_outputs()
@click.pass_context
def report_static(ctx, states_mcap, gyro_mcap, angle, survey_deg, start_s, end_s, gyro_name, out_dir, as_json, date):
    """Static sensor test (1998 paper Fig. 7): mean vs survey, noise, GPS and gyro drift."""
    from cdgps_cli.report.sensor_reports import static_report
    st, run = _states_and_gyro(states_mcap, gyro_mcap, chunked=True, covariance=True)   # STATES in chunks (issue 29)
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


@report.command("spectrum", short_help="Dynamic sensor test (1998 Fig. 8): PSDs, modes")
@click.argument("states_mcap", type=click.Path(dir_okay=False))
@_with(_spectra_opts)
@_report_outputs()
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


@report.command("run", short_help="One HTML page for one run: provenance, σ bands, NIS, modes, MAC")
@click.argument("states_mcap", type=click.Path(dir_okay=False))
@_with(_spectra_opts)
@click.option("--truth", "truth_dir", type=click.Path(file_okay=False),
              help="`cdgps simulate` folder of a simulated run: NEES and errors against its truth.csv.")
@click.option("--angle", default=None, help='Add the static-survey section for this angle, e.g. "q6+q10".')
@click.option("--survey-deg", type=float, default=None, help="Surveyed value of --angle, degrees.")
@click.option("--no-spectra", is_flag=True, default=False,
              help="Leave out the spectra, modes, MAC and mode shapes (on a long record the slowest part).")
@_report_outputs("Print report.json's summary on stdout.")
@click.pass_context
def report_run(ctx, states_mcap, gyro_mcap, coords, segment_s, overlap, pad, truth_dir, angle, survey_deg, no_spectra,
               date, out_dir, as_json):
    """One self-contained HTML page (index.html) for one estimated run: provenance, summary, time
    histories with ±1σ, NIS/NEES against χ² bounds, residuals per channel, PSDs and modes, the MAC
    matrix and mode shapes, and with --angle the static-survey statistics."""
    from cdgps_cli.io.file_checks import STATES, STRUCTURE_RUN, require_kind
    from cdgps_cli.io.run import read_run
    from cdgps_cli.report.run_data import StatesBlocks
    from cdgps_cli.report.run_report import run_report

    require_kind(states_mcap, STATES, "STATES_MCAP")
    if gyro_mcap:
        require_kind(gyro_mcap, STRUCTURE_RUN, "--gyro")
    run = read_run(gyro_mcap, phase=False) if gyro_mcap else None
    with StatesBlocks(states_mcap) as st, progress.stage("run report"):
        d = run_report(st, out_dir, run, truth_dir, _spectra_options(coords, segment_s, overlap, pad), angle,
                       survey_deg, date=date, spectra=not no_spectra)
    _say(ctx, f"report: {Path(out_dir) / 'index.html'}")
    if as_json:
        _emit_json(d["summary"])


@report.command("rtk", short_help="RTK solution (.pos) as one HTML page: ENU by fix/float, ratio")
@click.argument("pos_file", type=click.Path(dir_okay=False))
@_report_outputs("Print report.json's summary on stdout.", dated_by="the input's")
@click.pass_context
def report_rtk(ctx, pos_file, date, out_dir, as_json):
    """One self-contained HTML page (index.html) for an RTK solution file in RTKLIB's .pos layout
    (`cdgps rtk`, or RTKLIB's rnx2rtkp): east/north/up coloured fix/float/single with its ±1σ,
    satellites and ratio, the solver's header as provenance."""
    from cdgps_cli.report.rtk_report import rtk_report

    with progress.stage("rtk report"):
        d = rtk_report(pos_file, out_dir, date=date)
    _say(ctx, f"report: {Path(out_dir) / 'index.html'}")
    if as_json:
        _emit_json(d["summary"])


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


def _signals_note(r: dict) -> str:
    """A receiver summary's counts over its configured signals, after its GPS L1 ones (the lock counts): e.g.
    " (GPS L1); all signals: 38 satellites (C 10, E 9, G 12, R 7), 5123 phases"; empty without a signal table."""
    per = r.get("signal_satellites")
    if not per:
        return ""
    return (f" (GPS L1); all signals: {sum(per.values())} satellites ({', '.join(f'{k} {v}' for k, v in per.items())}), "
            f"{r['signal_phase_rows']} phases")


def _file_notes(r: dict) -> str:
    """What a receiver's file needed read otherwise: epochs in BeiDou or GLONASS time (converted to GPS time), a RINEX
    3.02 file's BeiDou B1I types (band 1 there, band 2 from 3.03); empty when neither."""
    notes = []
    if r.get("epochs_time_system"):
        notes.append(f"epochs in {r['epochs_time_system']}")
    if r.get("beidou_b1i_band1"):
        notes.append("BeiDou B1I as RINEX 3.02 names it (" + ", ".join(f"{a} read as {b}" for a, b in
                                                                     r["beidou_b1i_band1"].items()) + ")")
    return "; " + "; ".join(notes) if notes else ""


def _gnss_info_lines(g: dict) -> list:
    c = g["config"]
    out = [f"  GNSS run: config {c['name']} (sha256 {c['config_sha256'][:12]}…), master {g['master']}, rovers "
           f"{', '.join(g['rovers']) or 'none'}, displacement {c['displacement']}; coordinates {', '.join(g['coordinates']) or '-'}"]
    for r in g["receivers"]:
        every = "one epoch" if r["interval_s"] is None else f"sampled at {r['interval_s']:g} s"   # (None: one epoch)
        gaps = r.get("gaps")                               # (a RUN written before they were counted: none said)
        if gaps:
            every += (f"; {gaps['count']} gap{'s' if gaps['count'] != 1 else ''}, {gaps['missing_epochs']} epochs "
                      f"missing, the longest {gaps['longest_s']:g} s" if gaps["count"] else "; no gap")
        out.append(f"    {r['name']:<8} {r['format']:<5} {r['file']}: {r['epochs']} epochs {r['first']} – {r['last']} "
                   f"({every}), {r['satellites']} satellites, {r['phase_rows']} phases{_signals_note(r)}; "
                   f"lock: {r['arcs']} arcs, {r['slips']} slips, {r['half_cycle_rows']} half-cycle rows; position: "
                   f"{r['position_source'] or 'none'}" + _file_notes(r))
        if "integrity" in r:
            from cdgps_cli.io.ubx import integrity_line

            out.append(f"      integrity: {integrity_line(r['integrity'])}")
    for n, k in g["common_epochs"].items():
        out.append(f"    {n}: {k} epochs in common with {g['master']}" + _grid_note((g.get("epoch_pairing") or {}).get(n)))
    toe = g["ephemeris_toe"]
    out.append(f"    ephemerides: {g['ephemerides']} records of {g['ephemeris_satellites']} satellites"
               + (f", toe {toe[0]} – {toe[1]}" if toe else " (none: ingest with --nav before 'cdgps init')"))
    ant = g.get("antennas")
    if ant:
        out.append(f"    antenna models from {ant['antex']}: " + ", ".join(f"{n} {v or 'none'}"
                                                                           for n, v in ant["receivers"].items()))
    return out


# ----------------------------------------------------------------------------------------------
# GNSS pipeline from real (or simulated) receiver files: docs/gnss-pipeline.md


def _init_states_label(init: dict) -> str:
    """What ``init`` prints its rovers' states as: a static rover's displacement; under a moving model the mean
    (static) position over the record, which ``estimate``'s states move about."""
    model = init.get("displacement_model") or "static"
    if model == "static":
        return "static displacement (m)"
    return f"static displacement (the mean over the record; the origin of estimate's {model} states, m)"


def _reject_structure_options(given: dict, what: str) -> None:
    used = [k for k, v in given.items() if v]
    if used:
        raise CdgpsError(f"{', '.join(used)}: structure-run option(s), not used by {what} on a GNSS run "
                         f"(see docs/gnss-pipeline.md)")


def _init_options(ctx, ratio_threshold, no_partial, float_only) -> dict:
    """The GNSS init's option overrides of the flags given (gnss_init's ``options``)."""
    from click.core import ParameterSource

    over = {}
    if ctx.get_parameter_source("ratio_threshold") != ParameterSource.DEFAULT:
        over["ratio_threshold"] = ratio_threshold
    if no_partial:
        over["partial"] = False
    if float_only:
        over["fix"] = False
    return over


def _init_gnss_windows(ctx, run_mcap, every_s, start_s, duration_s, float_only, ratio_threshold, no_partial, output,
                       as_json, structure_only) -> None:
    """``cdgps init --every S``: an INIT per window (pipeline/gnss_init_windows)."""
    from cdgps_cli.pipeline.gnss_init_windows import init_windows

    _reject_structure_options(structure_only, "'cdgps init'")
    say = None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True))
    s = init_windows(run_mcap, every_s, output, start_s=start_s or 0.0, duration_s=duration_s,
                     options=_init_options(ctx, ratio_threshold, no_partial, float_only), progress=say)
    for w in s["windows"]:
        if w["file"] is None:
            _warn(f"window {w['k']} ({w['start_s']:g} s …) skipped: {w['skipped']}")
            continue
        _say(ctx, f"{w['file']}: " + "; ".join(
            f"{r} {v['solution']}, {v['n_fixed']} of {v['n_estimated']} integers" for r, v in w["rovers"].items()))
    glob = re.sub(r"\{k[^}]*\}", "*", output)
    _say(ctx, f"wrote {len(s['written'])} INITs of {len(s['windows'])} windows of {every_s:g} s; one STATES over "
              f"them: cdgps estimate {run_mcap} --init '{glob}' -o STATES.mcap")
    if as_json:
        _emit_json(s)


def _init_gnss(ctx, run_mcap, float_only, ratio_threshold, no_partial, output, as_json, structure_only, structure=None,
               window_s=None):
    from cdgps_cli.io.atomic import file_sha256
    from cdgps_cli.pipeline.gnss import gnss_init
    from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, read_gnss_run

    _reject_structure_options(structure_only, "'cdgps init'")
    run = read_gnss_run(run_mcap, columns=SOLVER_COLUMNS, window_s=window_s)
    over = _init_options(ctx, ratio_threshold, no_partial, float_only)
    say = None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True))
    modal = _structure_options(*structure) if structure is not None else None
    res = gnss_init(run, options=over, progress=say)
    if modal is not None:
        from cdgps_cli.pipeline.gnss_modal import gnss_modal_init

        res["modal_init"] = gnss_modal_init(run, res, modal[0], receivers=modal[1], x_axis_azimuth_deg=structure[1],
                                            progress=say)
    res["run_sha256"] = file_sha256(run_mcap)          # (in blocks: a day's RUN is not read into memory)
    _write_json_atomic(output, res)
    if run.window is not None:
        _say(ctx, f"window: {_gps_time(run.window['start_gps_s'])} – {_gps_time(run.window['end_gps_s'])} "
                  f"({run.window['start_s']:g} s after the record's first epoch, {run.window['duration_s']:g} s)")
    if run.window_past_the_end_note:
        _warn(run.window_past_the_end_note)
    for r, v in res["rovers"].items():
        ratio = v["ratio"] if v["ratio"] is None or isinstance(v["ratio"], str) else f"{v['ratio']:.1f}"
        st = ", ".join(f"{k} {x:+.4f} ± {v['sigma'][k]:.4f}" for k, x in v["states"].items())
        n_glo_fixed = int(v.get("n_glonass_fixed_by_engine") or 0)     # (counted in n_estimated, not in n_fixed)
        glo = (f" ({v['n_float_glonass']} GLONASS float)" if v.get("n_float_glonass") else "") + \
            (f" ({n_glo_fixed} of them GLONASS DDs, glonass_fix)" if n_glo_fixed else "")
        _say(ctx, f"INIT {run.master} → {r}: {v['solution']}, {v['n_fixed'] + n_glo_fixed} of {v['n_estimated']} "
                  f"integers fixed{glo}, "
                  f"ratio {ratio} (threshold {v['ratio_threshold']:g}); {_init_states_label(res)}: {st}")
        for w in v["warnings"]:              # (they were only in INIT.json)
            _warn(f"baseline {run.master} → {r}: {w}")
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


def _scene_factor(text) -> float | str:
    """--scene-exaggeration: "auto", or a factor in [0, SCENE_EXAGGERATION_MAX]."""
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not 0 <= v <= SCENE_EXAGGERATION_MAX:        # 1e308 drew an overflowed (inf) scene (fault campaign)
        raise CdgpsError(f"--scene-exaggeration {text!r}: expected a factor in [0, {SCENE_EXAGGERATION_MAX:g}] "
                         "(0: no 3-D scene) or 'auto'")
    return v


def _estimate_gnss(ctx, run_mcap, init_json, smooth, output, as_json, structure_only, structure=None,
                   x_axis_azimuth_deg=X_AXIS_AZIMUTH_DEG, receiver_map=(), allow_other_run=False,
                   scene_exaggeration=SCENE_EXAGGERATION, fuse=None, hold_out=()):
    from cdgps_cli.pipeline.gnss import gnss_estimate, init_window
    from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, read_gnss_run

    _reject_structure_options(structure_only, "'cdgps estimate'")
    from cdgps_cli.io.file_checks import read_init_json

    init, init_text = read_init_json(init_json)
    pairing = _check_pairing(ctx, init, init_json, run_mcap, allow_other_run)
    extra = {"allow_other_run": True, "init_run_sha256": pairing["init_run_sha256"]} if allow_other_run else None
    run = read_gnss_run(run_mcap, columns=SOLVER_COLUMNS, window=init_window(init))
    if structure is not None or receiver_map:
        _estimate_gnss_modal(ctx, run, init, init_text, output, as_json, smooth, structure, x_axis_azimuth_deg,
                             receiver_map, extra, pairing, scene_exaggeration, fuse=fuse, hold_out=hold_out)
        return
    if fuse or hold_out:
        raise CdgpsError("--fuse/--hold-out need --structure (the sensors are fused on the structure's modal state)")
    _say(ctx, f"estimating {run_mcap} from {init_json} ({run.cfg.displacement} displacement"
              f"{', smoothing' if smooth and run.cfg.displacement != 'static' else ''}) …")
    s = gnss_estimate(run, init, init_text, output, smooth=smooth,
                      progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)), extra_options=extra)
    s["init_run"] = pairing
    _say_gnss_estimate(ctx, s, output, run.cfg.displacement == "static", as_json)


def _estimate_gnss_windows(ctx, run_mcap, init_jsons: list, smooth, output, as_json, allow_other_run, structure_only):
    """``cdgps estimate RUN --init A --init B …`` on a GNSS run: the INITs of windows of the record, in time order,
    each serving its own window, into one STATES (:func:`cdgps_cli.pipeline.gnss.gnss_estimate_windows`)."""
    from cdgps_cli.io.file_checks import read_init_json
    from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, read_gnss_run
    from cdgps_cli.pipeline.gnss import EstimateWindow, gnss_estimate_windows, init_window

    _reject_structure_options(structure_only, "'cdgps estimate'")
    windows, pairings = [], []
    for path in init_jsons:
        with _init_named(path):
            init, text = read_init_json(path)
            pairings.append(_check_pairing(ctx, init, path, run_mcap, allow_other_run))
            span = init_window(init)
        windows.append(EstimateWindow(lambda span=span: read_gnss_run(run_mcap, columns=SOLVER_COLUMNS, window=span),
                                      init, text, str(path)))
    extra = ({"allow_other_run": True, "init_run_sha256": [p["init_run_sha256"] for p in pairings]}
             if allow_other_run else None)
    _say(ctx, f"estimating {run_mcap} from {len(windows)} INITs (each its window of the record) …")
    s = gnss_estimate_windows(windows, output, smooth=smooth,
                              progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)),
                              extra_options=extra)
    s["init_run"] = pairings
    _say_gnss_estimate(ctx, s, output, s["displacement_model"] == "static", as_json)


def _say_gnss_estimate(ctx, s: dict, output, static: bool, as_json: bool) -> None:
    """What ``cdgps estimate`` on a GNSS run says: the file, each rover's solution and scatter, notes, events,
    warnings, and the JSON summary when asked."""
    n_win = s.get("windows")
    _say(ctx, f"wrote {output}: {s['epochs']} epochs ({s['start']} – {s['end']}"
              + (f", {n_win} windows" if n_win else "") + f"), {s['kinematic_epochs']} single-epoch "
              f"solutions, {s['events']} events")
    for r, v in s["rovers"].items():               # (a moving rover's static solution: its states' origin, not its place)
        st = ", ".join(f"{k} {x:+.4f}" for k, x in v["static_enu_m"].items())
        _say(ctx, f"  {r}: {v['solution']} ({v['n_fixed']}/{v['n_estimated']} integers"
                  + (f" in {n_win} windows" if n_win else "") + "), "
                  + ("the first window's " if n_win else "")
                  + f"{'static' if static else 'origin of the states (the static solution)'} (m) {st}")
        k = v["kinematic_rms_m"]
        if k:
            _say(ctx, f"    single-epoch scatter about {'static' if static else 'that origin'}"
                      + (" (each window's own)" if n_win else "") + f" over {v['kinematic_epochs']} "
                      f"epochs: RMS E {k['e'] * 1e3:.1f} N {k['n'] * 1e3:.1f} U {k['u'] * 1e3:.1f} mm")
    for note in s.get("notes", []):
        _say(ctx, f"  note: {note}")
    for ev in s["event_list"][:20]:
        _say(ctx, f"  {_gps_time(ev['time_s'])} {ev['antenna']}/{ev['transmitter']}: {ev['kind']} → {ev['action']}")
    if len(s["event_list"]) > 20:
        _say(ctx, f"  … {len(s['event_list']) - 20} more events (topic /cdgps/events)")
    for w in s["warnings"]:
        _warn(w)
    if as_json:
        s = dict(s)
        _emit_json(s)


def _fused_history(output):
    """The fused filter's x, P on disk beside the output (removed however the run ends): memory of a chunk."""
    from cdgps_cli.io.scratch import DiskHistory

    return DiskHistory(Path(output).resolve().parent)


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
                         receiver_map, extra=None, pairing=None, scene_exaggeration=SCENE_EXAGGERATION, fuse=None,
                         hold_out=()):
    """``cdgps estimate RUN --init INIT --structure STRUCT.toml``: the modal model on the DDs (gnss_modal.py)."""
    from cdgps_cli.pipeline.fusion import fusion_choice
    from cdgps_cli.pipeline.gnss_modal import gnss_modal_estimate

    cfg, mapping = _structure_options(structure, x_axis_azimuth_deg, receiver_map)
    fuse_kinds, held = fusion_choice(cfg, fuse, hold_out)
    logs = None
    if fuse_kinds:
        from functools import partial

        from cdgps_cli.io.sensor_logs import read_run_sensor_logs

        logs = partial(read_run_sensor_logs, run.path)          # (read after the GNSS set-up, issue 29)
        _say(ctx, f"fusing {', '.join(fuse_kinds)} with the double differences"
                  + (f" (held out: {', '.join(held)})" if held else "") + " …")
    _say(ctx, f"estimating the modal model of {cfg.name} from {run.path} and its INIT"
              f"{' (smoothing)' if smooth else ''} …")
    s = gnss_modal_estimate(run, init, init_text, cfg, output, receivers=mapping, x_axis_azimuth_deg=x_axis_azimuth_deg,
                            smooth=smooth, progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)),
                            extra_options=extra, scene_exaggeration=scene_exaggeration, fuse=fuse_kinds, hold_out=held,
                            sensor_logs=logs, history=_fused_history(output) if fuse_kinds else None)
    s["init_run"] = pairing
    _say(ctx, f"wrote {output}: {s['epochs']} epochs, coordinates {', '.join(s['coordinates'])}, mean NIS/dof "
              f"{s['mean_nis_per_dof']:.3f}, {s['events']} events")
    for a, v in s["integers"].items():
        _say(ctx, f"  {a} ({s['receivers'][a]}): {v['fixed']}/{v['estimated']} integers fixed; nominal position "
                  f"{s['nominal_mismatch_m'][a] * 1e3:.1f} mm from the structure's")
    for name, v in (s.get("fusion") or {}).get("sensors", {}).items():
        _say(ctx, f"  fused {name}: {v['samples']} samples; residual RMS "
                  + ", ".join(f"{k} {r:.3g} (σ {v['sigma'][k]:.3g})" for k, r in v["residual_rms"].items() if r is not None)
                  + ("; final bias " + ", ".join(f"{k} {b:+.3g}" for k, b in v["final_bias"].items()) if v["final_bias"] else ""))
    if as_json:
        _emit_json(s)


def _gps_time(t: float) -> str:
    from cdgps_cli.core.gps_time import gps_time_str

    return gps_time_str(t)
