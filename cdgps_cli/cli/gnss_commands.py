"""GNSS commands beside the stages: baseline, rtk, config, baseline-config, simulate-gnss,
simulate-gnss-structure; each a thin shell over its library function."""

from __future__ import annotations

from pathlib import Path

import click

from cdgps_cli.config.options import GNSS_DEFAULTS, X_AXIS_AZIMUTH_DEG
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.signals import SIGNALS
from cdgps_cli.cli.app import (_warn, _say, _output_option, _named_by_flags, _emit_json, main, _parse_named,
                               _parse_antenna_types,
                               _parse_named_files, _write_json_atomic, _write_text_atomic)


def _time_window_options(f):
    """``--start-time`` / ``--end-time``: the rover epochs a GNSS command solves (RTKLIB's ``-ts`` / ``-te``; one
    rule for every GNSS command, :mod:`cdgps_cli.measurement.time_window`)."""
    f = click.option("--end-time", "end_time", default=None,
                     help="Last rover epoch solved, GPS time, as --start-time (RTKLIB's -te) [the record's last].")(f)
    return click.option("--start-time", "start_time", default=None,
                        help="First rover epoch solved, GPS time: YYYY/MM/DD HH:MM:SS[.f] or YYYY-MM-DDTHH:MM:SS[.f] "
                             "(RTKLIB's -ts) [the record's first].")(f)


def _time_window(start_time: str | None, end_time: str | None) -> dict:
    """``{"start_gps_s": …, "end_gps_s": …}`` of the flags given (GPS s), each parsed or refused naming its flag."""
    from cdgps_cli.core.gps_time import parse_gps_time

    return {key: parse_gps_time(text, flag) for key, text, flag in
            (("start_gps_s", start_time, "--start-time"), ("end_gps_s", end_time, "--end-time")) if text is not None}


@main.command("baseline", short_help="Static baseline of two RINEX receivers → JSON")
@click.option("--config", "job", type=click.Path(dir_okay=False), default=None,
              help="Baseline job TOML (files, master, options; see docs/geonet.md). Options below override it.")
@click.option("--rinex", "rinex", multiple=True, metavar="NAME=PATH",
              help="RINEX observation file of a station (give two). A station repeated, or NAME='PATTERN' (quoted "
                   "glob), gives its consecutive files (hourly, daily): one record.")
@click.option("--nav", "nav", multiple=True, type=click.Path(dir_okay=False), help="RINEX GPS navigation file (repeatable).")
@click.option("--master", default=None, help="Station held at its RINEX header position (the reference).")
@click.option("--master-xyz", "master_xyz", nargs=3, type=float, default=None,
              help="The master's surveyed antenna position, ECEF m, instead of its RINEX header's (a header without "
                   "one, or 0 0 0 as software receivers and converters write) [the job's position_ecef_m, else its "
                   "header's].")
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
@click.option("--glonass-fix", is_flag=True,
              help="Fix GLONASS double differences as integers too (identical receivers only: their inter-frequency "
                   "biases cancel); else GLONASS stays float.")
@click.option("--no-troposphere", is_flag=True, help="No a priori hydrostatic troposphere.")
@click.option("--iono-threshold-km", "iono_threshold_km", type=float, default=None,
              help="Refuse a baseline at least this long: this static solution neglects the DD ionosphere and the "
                   "zenith wet delays (use 'cdgps rtk' there), as init's [gnss] iono_threshold_km "
                   f"[{GNSS_DEFAULTS['iono_threshold_km']:g}].")
@click.option("--antex", "antex", type=click.Path(dir_okay=False), default=None,
              help="ANTEX file (igs20.atx …): each station's antenna phase-centre offset and variations taken out of "
                   "its observations, as 'cdgps rtk --antex' [the job's antex, else none].")
@click.option("--antenna", "antenna", multiple=True, metavar="NAME=TYPE",
              help="A station's antenna type and radome as the ANTEX file names them (\"TRM59800.80 SCIT\"), or none "
                   "(no model) [its RINEX header's ANT # / TYPE].")
@_time_window_options
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="Result JSON to write.")
@click.option("--json", "as_json", is_flag=True, help="Also print the result JSON on stdout.")
@click.pass_context
def baseline_cmd(ctx, job, rinex, nav, master, master_xyz, mask_deg, ratio_threshold, min_success_rate, max_age_s, weighting, no_partial,
                 float_only, glonass_fix, no_troposphere, iono_threshold_km, antex, antenna, start_time, end_time, output,
                 as_json):
    """Static baseline from two receivers' RINEX L1 phase: float, LAMBDA integers, fixed → JSON."""
    from cdgps_cli.estimation.baseline import format_summary, json_safe
    from cdgps_cli.pipeline.baseline_job import baseline_from_files, baseline_inputs, load_baseline_job

    window = _time_window(start_time, end_time)
    changes = {k: v for k, v in (("mask_deg", mask_deg), ("ratio_threshold", ratio_threshold),
                                 ("min_success_rate", min_success_rate), ("max_age_s", max_age_s),
                                 ("weighting", weighting)) if v is not None}
    changes.update({k: v for k, flag, v in (("partial", no_partial, False), ("fix", float_only, False),
                                             ("glonass_fix", glonass_fix, True),
                                             ("troposphere", no_troposphere, False)) if flag})
    flags = {"mask_deg": "--mask-deg", "ratio_threshold": "--ratio", "max_age_s": "--max-age", "weighting": "--weighting",
             "min_success_rate": "--min-success-rate"}
    loaded = load_baseline_job(job) if job else None        # (its errors name its keys, not the flags)
    inp = _named_by_flags(lambda: baseline_inputs(
        loaded, stations=_parse_named_files(rinex, "--rinex", "NAME") if rinex else None, nav_paths=nav, master=master,
        changes=changes, antenna_types=_parse_antenna_types(antenna, "NAME"), iono_threshold_km=iono_threshold_km,
        antex=antex, master_xyz=master_xyz), {k: flags[k] for k in changes if k in flags})
    notes, opt = inp.pop("notes"), inp["options"]
    rover = next(n for n in inp["rinex"] if n != inp["master"])
    _say(ctx, f"baseline {inp['master']} → {rover}: {len(inp['nav_paths'])} navigation file(s), mask {opt.mask_deg:g}°, "
              f"ratio {opt.ratio_threshold:g} …")
    res = json_safe(baseline_from_files(**inp, **window))
    if job:
        res["inputs"]["config"] = str(job)
    for w in notes:
        _warn(w)
    if notes:
        res["warnings"] = notes + list(res.get("warnings") or [])
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
@click.option("--displacement", type=click.Choice(["static", "random_walk", "constant_velocity"]), default="static",
              show_default=True, help="Rover displacement model.")
@click.option("--sigma", "sigma", type=float, default=None, help="random_walk process noise, m/√s per component [0.001].")
@click.option("--name", default=None, help="Run name (default: the antenna names).")
@click.option("--signals", default="auto", show_default=True,
              help="[gnss] signals: 'auto' (every GPS, Galileo, BeiDou and GLONASS signal all receivers hold whose system "
                   "has ephemerides in --nav, "
                   "or in the u-blox logs' RXM-SFRBX; as 'cdgps rtk'), or comma-separated names (G:L1,E:E1,...). "
                   "GPS L1 alone writes no key (the GPS L1 path).")
@click.option("-o", "--output", "output", required=True, type=click.Path(dir_okay=False), help="Config TOML to write.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary (the written config as it loads, notes) on stdout.")
@click.pass_context
def config_cmd(ctx, rinex, ubx, nav, master, displacement, sigma, name, signals, output, as_json):
    """Write a starter GNSS run config from the receiver files' headers (for ingest and baseline)."""
    from cdgps_cli.pipeline.gnss_ingest import starter_gnss_config

    if sigma is not None and displacement == "static":
        raise CdgpsError("--sigma is the random-walk process noise: use it with --displacement random_walk (or "
                         "constant_velocity, whose init resolves the integers on the random-walk float)")
    notes: list = []
    warnings: list = []
    sig = "auto" if signals.strip() == "auto" else [x.strip() for x in signals.split(",") if x.strip()]
    text = starter_gnss_config(_parse_named(rinex, "--rinex"), _parse_named(ubx, "--ubx"), list(nav), master,
                               displacement=displacement, sigma_m_per_sqrt_s=sigma,
                               relative_to=Path(output).resolve().parent, name=name, notes=notes, warnings=warnings,
                               signals=sig)
    _write_text_atomic(output, text)
    for w in warnings:
        _warn(w)
    for n in notes:
        click.echo(f"cdgps: note: {n}", err=True)
    _say(ctx, f"wrote {output}")
    if as_json:
        from cdgps_cli.config.structure import load_gnss_config

        _emit_json({"output": output, "config": load_gnss_config(output).summary(), "notes": notes,
                    "warnings": warnings})


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
    warnings: list = []
    text = starter_gnss_config(stations, {}, list(nav), master, relative_to=Path(output).resolve().parent,
                               warnings=warnings)
    _write_text_atomic(output, text)
    for w in warnings:
        _warn(w)
    job = load_baseline_job(output)  # the written job must load
    _say(ctx, f"wrote {output}")
    if as_json:
        import dataclasses

        _emit_json({"output": output, "master": job["master"], "stations": {k: str(v) for k, v in job["rinex"].items()},
                    "nav": [str(v) for v in job["nav"]], "options": dataclasses.asdict(job["options"])})


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
@click.option("--gnss-interval", "gnss_interval_s", type=float, default=None, metavar="SECONDS",
              help="Receivers' epoch interval, a multiple of the config's sample_period_s (e.g. 0.1 for 10 Hz GNSS on a "
                   "structure simulated at 100 Hz) [the sample period].")
@_output_option("out_dir", "Output directory.", directory=True, old=("--out",))
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary on stdout.")
@click.pass_context
def simulate_gnss_structure_cmd(ctx, config, duration_s, seed, x_axis_azimuth_deg, master_xyz, signals, out_dir, as_json,
                                gnss_interval_s=None):
    """Simulate a structure's free motion seen by one GNSS receiver per antenna → RINEX + truth.

    With --signals the receivers track GPS, Galileo and BeiDou (GEO, IGSO, MEO) on every signal given
    (multi-signal RINEX 3) and the written config lists them ([gnss] signals), so the modal path uses them all.

    The structure config's modal model moves the antennas (scenario free, at the config's sample
    period); every antenna, the master too, has its own receiver.  The files feed
    'cdgps ingest --config DIR/config.toml', 'cdgps init', then
    'cdgps estimate … --structure CONFIG' and 'cdgps evaluate --truth DIR'.  A config with sensors
    ([[accelerometers]], [[tilts]], [[gyros]]) also gets their CSV logs (accel.csv, tilt.csv, gyro.csv;
    noise, bias and bias drift as configured), listed in the written config for ingest and
    'estimate --fuse'.
    """
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.pipeline.gnss_modal import simulate_structure_gnss
    from cdgps_cli.sim.gnss import DEFAULT_MASTER_XYZ, parse_vector
    from cdgps_cli.sim.structure import check_receiver_epochs

    if not duration_s > 0:
        raise CdgpsError(f"--duration must be positive, got {duration_s:g}")
    if not -360.0 <= x_axis_azimuth_deg <= 360.0:
        raise CdgpsError(f"--x-axis-azimuth-deg must be in [-360, 360], got {x_axis_azimuth_deg:g}")
    cfg = load_config(config)
    check_receiver_epochs(duration_s, cfg.sample_period_s, gnss_interval_s)
    s = simulate_structure_gnss(
        out_dir, cfg, master_ecef_m=parse_vector(master_xyz, "--master-xyz") if master_xyz else DEFAULT_MASTER_XYZ,
        x_axis_azimuth_deg=x_axis_azimuth_deg, duration_s=duration_s, seed=seed,
        signals=None if signals is None else [g.strip() for g in signals.split(",") if g.strip()],
        progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)), gnss_interval_s=gnss_interval_s)
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
@click.option("--constant-velocity", "accel_sigma", type=float, default=None, metavar="SIGMA",
              help="Rover's velocity random-walks with SIGMA m/s/√s per component, from rest (white acceleration; "
                   "config model constant_velocity). Not with --random-walk.")
@click.option("--slips", "n_slips", type=int, default=0, show_default=True, help="Random LLI-flagged cycle slips.")
@click.option("--phase-noise-m", type=float, default=None,
              help="Undifferenced white phase noise, m [default: the elevation model sigma^2 = a^2 + b^2/sin^2(el), "
                   "a = b = 3 mm per receiver, the estimator's default weighting].")
@click.option("--code-noise-m", type=float, default=0.5, show_default=True, help="Undifferenced pseudorange noise, m.")
@click.option("--multipath-m", "multipath_m", type=float, default=0.0, show_default=True,
              help="Rover phase multipath: each satellite's L1 phase carries a first-order Gauss-Markov error of this "
                   "sigma, m (0: none).")
@click.option("--multipath-tau-s", "multipath_tau_s", type=float, default=30.0, show_default=True,
              help="Its correlation time, s.")
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
                      random_walk, accel_sigma, n_slips, phase_noise_m, code_noise_m, multipath_m, multipath_tau_s,
                      clock_offset, clock_drift, raw_tags, master_rate_hz, out_dir, as_json):
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
        master_rate_hz=master_rate_hz, accel_sigma=accel_sigma, multipath_sigma_m=multipath_m,
        multipath_tau_s=multipath_tau_s, progress=None if ctx.obj.get("quiet") else (lambda m: click.echo(m, err=True)))
    _say(ctx, f"wrote {', '.join(s['files'])} to {out_dir}/: {s['epochs']} epochs, {s['satellites']} satellites, "
              f"{s['slips']} slips, {s['displacement_model']} rover")
    if as_json:
        _emit_json(s)


@main.command(short_help="Multi-GNSS, multi-frequency RTK of a pair → CSV")
@click.option("--base", "base_file", required=True, multiple=True, type=click.Path(dir_okay=False),
              help="Base observations: RINEX, or a u-blox log (RXM-RAWX; its RTCM 1005/1006 position is used). "
                   "Repeated, or a quoted glob pattern: the base's consecutive files (hourly, daily), joined in time "
                   "order into one record.")
@click.option("--rover", "rover_file", required=True, multiple=True, type=click.Path(dir_okay=False),
              help="Rover observations: RINEX, or a u-blox log (RXM-RAWX); repeated, or a quoted glob pattern, as "
                   "--base.")
@click.option("--nav", "nav_files", multiple=True, type=click.Path(dir_okay=False),
              help="RINEX navigation file(s) with the GPS / Galileo / BeiDou / QZSS / GLONASS ephemerides (repeatable); "
                   "without it, the u-blox logs' RXM-SFRBX ephemerides.")
@click.option("--signals", default="auto", show_default=True,
              help=f"Comma-separated signals ({', '.join(SIGNALS)}; GLONASS stays float unless --glonass-fix), or "
                   "'auto': every GPS, Galileo, BeiDou and GLONASS signal both files hold whose system has ephemerides "
                   "in --nav (QZSS only when named).")
@click.option("--mode", type=click.Choice(["kinematic", "constant-velocity", "static"]), default="kinematic", show_default=True,
              help="kinematic: random-walk rover position, a solution per epoch; constant-velocity: position and "
                   "velocity, the velocity a random walk (white acceleration), written out too (ENU m/s and σ; "
                   "RTKLIB's velocity columns in .pos); static: one position for the span, its estimate from "
                   "the data so far written at every epoch (forward: the last line uses them all, as RTKLIB's static "
                   "mode; see --direction).")
@click.option("--base-xyz", nargs=3, type=float, default=None,
              help="Base antenna ECEF position, m (default: its header's APPROX POSITION XYZ plus its ANTENNA: DELTA "
                   "H/E/N, as RTKLIB's base from its header; a rover's delta is not applied).")
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
@click.option("--iono-threshold-km", "iono_threshold_km", type=float, default=None,
              help="Baseline length from which the DD ionosphere is estimated (a state per satellite, σ growing with "
                   "the length); shorter baselines neglect it, as RTKLIB's ionoopt=brdc on a short baseline; a large "
                   "value neglects it on any baseline, as init's [gnss] iono_threshold_km "
                   f"[{__import__('cdgps_cli.config.options', fromlist=['x']).MULTI_GNSS_DEFAULTS['iono_threshold_km']:g}].")
@click.option("--tropo-threshold-km", "tropo_threshold_km", type=float, default=None,
              help="Baseline length from which the zenith wet delays of the base and the rover are estimated (a "
                   "random-walk state each, Niell wet mapping, RTKLIB's tropopt=est); shorter baselines take the "
                   "a-priori hydrostatic troposphere alone; a large value never estimates them [the "
                   "--iono-threshold-km value: the long-baseline model estimates both].")
@click.option("--antex", "antex", type=click.Path(dir_okay=False), default=None,
              help="ANTEX file (IGS .atx): the receiver antennas' phase-centre offsets and elevation variations are "
                   "taken out of the observations (RTKLIB's file-rcvantfile; mixed antennas differ by centimetres in "
                   "height). Each antenna is its RINEX header's ANT # / TYPE unless --base-antenna / --rover-antenna "
                   "name it [none].")
@click.option("--base-antenna", "base_antenna", default=None,
              help="The base's antenna type and radome as ANTEX writes them (e.g. 'LEIAR25.R4 LEIT'), or 'none' for no "
                   "model (with --antex) [its header's].")
@click.option("--rover-antenna", "rover_antenna", default=None,
              help="The rover's antenna, as --base-antenna [its header's].")
@click.option("--direction", type=click.Choice(["forward", "backward", "combined"]), default=None,
              help="Passes: forward, backward, or both combined - an epoch is fixed where the passes' fixes agree (or "
                   "one's fix agrees with the other's float); disagreeing fixes are rejected [kinematic: combined; "
                   "static: forward, whose last epoch uses them all].")
@click.option("--code-correlation", "code_correlation_s", type=float, default=None,
              help="Correlation time of the code errors, s: their variance is inflated by (1+ρ)/(1−ρ), ρ = e^(−Δt/τ), so "
                   "a minute of correlated multipath is not taken as 60 independent ranges (0: white, as RTKLIB) "
                   f"[{__import__('cdgps_cli.config.options', fromlist=['x']).MULTI_GNSS_DEFAULTS['code_correlation_s']:g}].")
@click.option("--code-noise", "code_noise", type=click.Choice(["auto", "model"]), default=None,
              help="auto: scale the code variance by the files' own code noise, each receiver's code-minus-carrier "
                   "averaged over 30 s against the model (a u-blox M8P: x47, geodetic receivers: x1), so the float σ "
                   "and the integer tests are honest; model: the code σ as modelled [auto].")
@click.option("--age-noise", "age_noise", type=click.Choice(["auto", "model"]), default=None,
              help="auto: a bridged base observation's σ grows by what the base's own observations minus their model "
                   "drift per second (at least RTKLIB's 1.5 mm/s; a 2008 Crescent base: 10 mm/s); model: 1.5 mm/s "
                   "[auto].")
@click.option("--fix-and-hold/--no-fix-and-hold", default=None,
              help="After --hold-after-fixes consecutive fixed epochs, feed the fixed integers back as measurements "
                   "(RTKLIB's fix-and-hold); while held, an epoch that contradicts them (--wrong-fix-probability) "
                   "sets the ambiguities back to float [on].")
@click.option("--wrong-fix-probability", "wrong_fix_probability", type=float, default=None,
              help="Wrong-fix test while integers are held: an epoch whose NIS exceeds this χ² quantile of its DDs "
                   "resets the ambiguities to float (0: off) "
                   f"[{__import__('cdgps_cli.config.options', fromlist=['x']).MULTI_GNSS_DEFAULTS['wrong_fix_probability']:g}].")
@click.option("--hold-after-fixes", "hold_after_fixes", type=click.IntRange(min=1), default=None,
              help="Consecutive fixed epochs before --fix-and-hold holds the integers (RTKLIB pos2-arminfix) "
                   f"[{__import__('cdgps_cli.config.options', fromlist=['x']).MULTI_GNSS_DEFAULTS['hold_after_fixes']}].")
@click.option("--min-success-rate", type=float, default=None,
              help="Bootstrapped success rate an integer set must reach; when the whole set does not, the part that "
                   "does is fixed and the epoch stays float (0: the ratio test alone, as RTKLIB) [0.999].")
@click.option("--float-only", is_flag=True, help="Do not fix integers (float solution only; RTKLIB pos2-armode=off).")
@_time_window_options
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output: .pos (RTKLIB, lat/lon/height), .nmea/.gga (NMEA GGA), .geojson, or CSV (any other suffix; .kml, .kmz, .gpx, .sbp, .stat are refused: pos2kml makes KML from a .pos).")
@click.option("--pos-frame", "pos_frame", type=click.Choice(["llh", "xyz", "enu"]), default=None,
              help="Coordinates of a .pos output (RTKLIB out-solformat): llh latitude/longitude/height, xyz ECEF, "
                   "enu the baseline's east/north/up at the base [llh].")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary (epochs used and why others were not, fixes) on stdout.")
@click.pass_context
def rtk(ctx, base_file, rover_file, nav_files, signals, mode, base_xyz, glonass_fix, mask_deg, ratio_threshold, max_age_s,
        sync_tol_s, iono_threshold_km, tropo_threshold_km, antex, base_antenna, rover_antenna, direction, code_correlation_s, code_noise, age_noise, fix_and_hold, wrong_fix_probability,
        hold_after_fixes, min_success_rate, float_only, start_time, end_time, output, pos_frame, as_json):
    """Double differences per constellation and frequency, integers by LAMBDA (docs/gnss-pipeline.md, "Multi-GNSS").

    The rover's epochs drive the solution: each takes the nearest base epoch within --max-age (a base
    with gaps or a lower rate is bridged, its σ growing with the age); every rover epoch not used is
    counted with its reason."""
    from cdgps_cli.pipeline.gnss_multi import rtk_from_files

    options = {"signals": "auto" if signals.strip() == "auto" else tuple(x.strip() for x in signals.split(",") if x.strip()),
               "mode": mode, "glonass_fix": glonass_fix}
    options.update(_time_window(start_time, end_time))
    if float_only:
        options["fix"] = False
    for key, value in (("mask_deg", mask_deg), ("ratio", ratio_threshold), ("max_age_s", max_age_s),
                       ("sync_tol_s", sync_tol_s), ("iono_threshold_km", iono_threshold_km),
                       ("tropo_threshold_km", tropo_threshold_km), ("antex", antex), ("base_antenna", base_antenna),
                       ("rover_antenna", rover_antenna), ("direction", direction), ("min_success_rate", min_success_rate),
                       ("code_correlation_s", code_correlation_s), ("code_noise", code_noise), ("age_noise", age_noise),
                       ("hold_after_fixes", hold_after_fixes),
                       ("fix_and_hold", fix_and_hold), ("wrong_fix_probability", wrong_fix_probability),
                       ("pos_frame", pos_frame)):
        if value is not None:
            options[key] = value
    s = rtk_from_files(list(base_file), list(rover_file), list(nav_files), output, base_xyz_m=base_xyz or None,
                       options=options)
    for w in s["warnings"]:
        _warn(w)
    ep = s["epoch_pairing"]
    _say(ctx, f"{output}: {s['epochs']} of {ep['rover_epochs']} rover epochs ({ep['bridged']} bridged to a base epoch up to --max-age away, "
              f"{ep.get('interpolated', 0)} of them interpolated, max age {ep['max_age_s']:.3g} s), fixed {s['fixed_pct']:.1f} % ({s['direction']}; "
              f"{s['fixes_rejected']} fixes rejected where the passes disagree, {s['wrong_fix_resets']} held fixes reset, "
              f"{s['ambiguities_released']} single ambiguities released), ionosphere {s['iono_model']}, "
              f"wet troposphere {s['wet_troposphere']['model']}, "
              f"signals {' '.join(s['signals'])}, code variance x{s['code_noise']['variance_factor']:.3g} ({s['code_noise']['mode']})")
    if as_json:
        _emit_json({k: v for k, v in s.items()})
