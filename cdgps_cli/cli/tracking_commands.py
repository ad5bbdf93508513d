"""Receiver tracking loops: `cdgps track`, `cdgps simulate-if`, `cdgps track-structure`;
thin shells over :mod:`cdgps_cli.pipeline.track` and :mod:`cdgps_cli.pipeline.if_chain`."""

from __future__ import annotations


import click

from cdgps_cli.config.options import TRACK_DEFAULTS
from cdgps_cli.core import progress
from cdgps_cli.cli.app import _say, _warn, _output_option, _named_by_flags, _emit_json, main


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
    for w in s["warnings"]:
        _warn(w)
    for sat in s["satellites"]:
        cn0 = "–" if sat["cn0_dbhz"] is None else f"{sat['cn0_dbhz']:.1f}"
        _say(ctx, f"  PRN {sat['prn']:>2}: {sat['doppler_hz']:+8.1f} Hz, code {sat['code_phase_chips']:7.2f} chips, "
                  f"C/N0 {cn0} dB-Hz, phase lock {'yes' if sat['phase_lock'] else 'no'} "
                  f"({100 * sat['phase_lock_fraction']:.0f}% of windows)")
    _say(ctx, f"wrote {output}: {len(s['satellites'])} satellites, {s['duration_s']:.3f} s")
    if as_json:
        _emit_json({k: v for k, v in s.items() if k != "acquisition"})


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
