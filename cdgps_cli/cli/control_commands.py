"""Control: `cdgps control design` (LQR gain) and `cdgps report control`; thin shells over
:mod:`cdgps_cli.control` and :mod:`cdgps_cli.report.control`."""

from __future__ import annotations

from pathlib import Path

import click

from cdgps_cli.config.options import CONTROL_TUNED_WEIGHTS, CONTROL_WEIGHTS
from cdgps_cli.core import progress
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.cli.app import _warn, _say, _output_option, _emit_json, _report_outputs, main
from cdgps_cli.cli.stage_commands import report


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
@_report_outputs()
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
