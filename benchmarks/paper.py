#!/usr/bin/env python3
"""Every headline of the three papers, reproduced by one command (issue 31 item 3): ``make paper``.

Runs the ``cdgps`` commands a user would run (each headline lists them) on the bundled data and on
fresh simulations, plus the tracking studies of ``benchmarks/tracking_paper.py`` in-process, and writes

* ``docs/paper-reproduction.md``: per headline the paper's statement, our figure, whether it is met,
  the commands, a note where the comparison is not like for like, and the figures beside the
  paper's description (copied to ``docs/figures/paper-*.png``);
* ``docs/benchmarks/paper.json``: every number behind the table.

Nothing is tuned to fit: a headline that is not reproduced says so with the measurement.

    python benchmarks/paper.py                 # everything (≈ 3 min on 2 quiet cores)
    python benchmarks/paper.py --quick         # 1995, the static test, Fig. 6 (≈ 1 min; what `make test` runs)
    python benchmarks/paper.py --only 1995,fig6 --out /tmp/paper   # some headlines, elsewhere
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import math
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CDGPS = str(Path(sys.executable).parent / "cdgps")
TESTBED = ROOT / "configs" / "testbed-1998.toml"
DOF2 = ROOT / "configs" / "teague-1995-2dof.toml"
QUICK = ("1995", "model", "static", "fig6")
#: the slews' disturbance (× the config's process noise), as benchmarks/control_experiments.py uses
SLEW_DISTURBANCE = 0.05
#: the paper's slew target (Sec. VI.D), the config default [simulation] slew_to_deg
SLEW_TO_DEG = -22.0
#: seeds of the step-command variant of Fig. 12a
STEP_SEEDS = 2
#: the weights of the pulse and slew experiments: the paper's saturate the jets on our Υ (43-45 % of
#: jet-periods) and do not finish the slew, so the experiments use the set the paper's own rule ("the
#: maximum control authority ... without saturating the actuators") gave, `cdgps control design --weights
#: tuned`; the paper's weights are run beside them on PAPER_WEIGHT_SEEDS seeds and reported in the notes
EXPERIMENT_WEIGHTS = "tuned"
PAPER_WEIGHT_SEEDS = 3
#: Fig. 10's open-loop swing, "approximately 10 deg peak-to-peak": met within ±30 %
OPEN_PULSE_PP_DEG, OPEN_PULSE_TOL = 10.0, 0.3
#: the pulse with the paper's EKF read literally (Eq. 18 with the pulse in u, the paper's W): W's scale
PULSE_EQ18_W_SCALE = 1.0
#: simulations run at once (each is its own `cdgps` process): the 2 cores of the reference machine
JOBS = int(os.environ.get("CDGPS_PAPER_JOBS", "2"))
ALL = ("1995", "model", "static", "psd", "fig6", "pulse", "slew", "tracking")


@dataclass
class Headline:
    """One row of the reproduction table."""

    paper: str                 # "1995", "1998", "2003"
    where: str                 # figure / section of the paper
    claim: str                 # the paper's statement, quoted or closely paraphrased
    ours: str = ""             # our figure, with its unit
    met: bool | None = None    # None: not comparable like for like (see note)
    commands: list = field(default_factory=list)
    note: str = ""
    figure: str | None = None  # docs-relative path of our figure
    values: dict = field(default_factory=dict)
    key: str = ""              # the runner that measured it (ALL); --only replaces these rows only


def cdgps(*args, cwd=None) -> str:
    """Run one cdgps command; its stdout (exit status checked, stderr shown on failure)."""
    p = subprocess.run([CDGPS, "-q", *map(str, args)], capture_output=True, text=True, cwd=cwd)
    if p.returncode != 0:
        raise SystemExit(f"cdgps {' '.join(map(str, args))} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return p.stdout


def cdgps_json(*args) -> dict:
    return json.loads(cdgps(*args, "--json"))


def _pmap(fn, items) -> list:
    """``[fn(*i) for i in items]``, JOBS at a time (the runs are independent subprocesses writing to their
    own folders, so threads suffice); results in the order of ``items``."""
    items = list(items)
    if JOBS <= 1 or len(items) <= 1:
        return [fn(*i) for i in items]
    with ThreadPoolExecutor(max_workers=JOBS) as ex:
        return list(ex.map(lambda i: fn(*i), items))


def _cpu_s() -> float:
    """CPU seconds (user + system) of this process and its finished children so far."""
    me, ch = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + ch.ru_utime + ch.ru_stime


def _chain(steps) -> dict:
    """Run the commands in order; the last one's --json summary."""
    for s in steps[:-1]:
        cdgps(*s)
    return cdgps_json(*steps[-1])


def _cmd(*args) -> str:
    return "cdgps " + " ".join(str(a).replace(str(ROOT) + "/", "") for a in args)


def _figure(src: Path, name: str, figdir: Path) -> str:
    figdir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, figdir / name)
    return f"figures/{name}"


# ----------------------------------------------------------------------------------------------
# 1995: the 2-DOF structure, batch init then EKF


def h1995(w: Path, figdir: Path) -> list[Headline]:
    d = w / "dof2"
    steps = [("ingest", ROOT / "data/teague-1995/receiver.csv.xz", "--config", DOF2, "-o", d / "run.mcap"),
             ("init", d / "run.mcap", "--start", 0, "--duration", 2.4, "--no-process-noise", "-o", d / "init.json"),
             ("estimate", d / "run.mcap", "--init", d / "init.json", "--biases", "states", "-o", d / "states.mcap")]
    d.mkdir(parents=True)
    out = [cdgps_json(*s) for s in steps]
    ev = cdgps_json("evaluate", "--truth", ROOT / "data/teague-1995", "--estimate", d / "states.mcap")
    cmds = [_cmd(*s) for s in steps] + [_cmd("evaluate", "--truth", "data/teague-1995", "--estimate", d / "states.mcap")]
    rms = ev["rms_error_deg"]
    init = out[1]
    n_fixed, n_seg = init.get("n_fixed"), len(init.get("biases", [])) or init.get("n_segments")
    return [
        Headline("1995", "Sec. V, Fig. 6", "the estimator converged to within 0.3 deg RMS of the q1 and q2 states "
                 "(batch over the first ≈ 2 s, then the EKF)",
                 ours=f"RMS error q1 {rms['q1']:.3f}°, q2 {rms['q2']:.3f}° over the whole 30 s record"
                      + ("" if max(rms.values()) <= 0.3 else
                         f" ({100 * (max(rms.values()) / 0.3 - 1):.0f} % above 0.300°: met at the paper's one-figure "
                         "precision, the table allows 5 %)"),
                 met=max(rms.values()) <= 0.3 * 1.05, commands=cmds, values={"evaluate": ev, "init": init},
                 note=f"NEES mean {ev['nees']['mean']:.2f} for {ev['nees']['dof']} states (expected ≈ {ev['nees']['dof']}): "
                      "the reported σ is optimistic on this record; NIS/dof "
                      f"{ev['nis']['mean_per_dof']:.2f}. The data are the bundled simulation of the paper's structure "
                      "(data/teague-1995), not the paper's recording.",
                 figure="figures/dof2_estimate.png"),
        Headline("1995", "Sec. IV", "integer biases found by the batch initialization",
                 ours=f"{n_fixed} of {n_seg} integers fixed; {ev['bias_error']['wrong_integers']} wrong "
                      f"(bias RMS error {1000 * ev['bias_error']['rms_m']:.2f} mm)",
                 met=ev["bias_error"]["wrong_integers"] == 0 and n_fixed == n_seg, commands=cmds[:2]),
    ]


# ----------------------------------------------------------------------------------------------
# 1998: static test (Fig. 7), PSD vs gyro (Fig. 8)


def _load_script(relpath: str):
    """The module of the script ``ROOT / relpath`` (scripts and benchmarks are not a package)."""
    name = Path(relpath).stem
    spec = importlib.util.spec_from_file_location(name, ROOT / relpath)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def _testbed_script():
    return _load_script("scripts/make_testbed_config.py")


def hmodel(w: Path, figdir: Path) -> list[Headline]:
    mt = _testbed_script()
    M, K = mt.testbed_matrices(mt.FITTED)
    modes = mt.model_modes(M, K)
    err = {n: 100 * (modes[n][0] / mt.TABLE1[n][0] - 1) for n in mt.ORDER[:-1]}
    within = [n for n, e in err.items() if abs(e) <= 5.0]
    out = [n for n in err if n not in within]
    m12 = mt.model_modes(*mt.testbed_matrices(mt.FITTED_12M))
    err12 = {n: 100 * (m12[n][0] / mt.TABLE1[n][0] - 1) for n in mt.ORDER[:-1]}
    worst = max(err, key=lambda n: abs(err[n]))
    return [Headline(
        "1998", "Table 1, Figs. 3–5", "an 8 m, 180 kg structure: three rigid sections joined by ½ in. aluminium tubes "
        "(3.7 m) hung on 12 m threads; eight elastic modes at Table 1's measured frequencies (within 5 %), shapes from "
        "NASTRAN",
        ours=f"our mass/stiffness model (fitted: tube wall {mt.FITTED.wall_m * 1e3:.2f} mm, section I_xx = "
             f"{mt.FITTED.ixx_kg_m2:.1f} kg·m², suspension {mt.FITTED.pendulum_length_m:.2f} m): {len(within)} of 8 "
             f"modes within 5 % of Table 1 (worst {worst} {err[worst]:+.1f} %)"
             + ("; " + ", ".join(f"{n} {err[n]:+.1f} %" for n in out) if out else "")
             + f"; with 12 m threads: swing {err12['swing']:+.1f} %, bending-1 {err12['bending-1']:+.1f} %",
        met=not out, commands=["python scripts/make_testbed_config.py --fit",
                               "python scripts/make_testbed_config.py --fit --threads-12m"],
        values={"model_hz": {n: modes[n][0] for n in err}, "error_pct": err, "fitted": vars(mt.FITTED),
                "error_pct_12m_threads": err12, "swing_bound_12m_hz": mt.swing_bound_hz(12.0)},
        note="docs/testbed-model.md derives the model. With the paper's 12 m threads the swing mode (the whole "
             f"structure swinging sideways) is at most sqrt(g/L)/2π = {mt.swing_bound_hz(12.0):.4f} Hz whatever the "
             "tubes and sections (a thread attached above the centre of mass only lowers it): Table 1's 0.160 Hz ± 5 % "
             "needs an 8.8–10.8 m suspension. Fitting the suspension's lateral stiffness (effective length) with the "
             f"other parameters gives {mt.FITTED.pendulum_length_m:.2f} m and brings bending-1 (half its energy in "
             "sideways translation) within 5 % too; the config uses it and states the assumption. The config takes "
             "Table 1's frequencies with our shapes, as the paper adjusted its NASTRAN frequencies to the measured ones.")]


def hstatic(w: Path, figdir: Path) -> list[Headline]:
    d = w / "static"
    d.mkdir(parents=True)
    src = d / "sim"
    steps = [("simulate", TESTBED, "--duration", 180, "--seed", 12, "--scenario", "static", "--noise-m", 0.002,
              "-o", src),
             ("ingest", src / "receiver.csv", src / "gyro.csv", "--config", TESTBED, "-o", d / "run.mcap"),
             ("init", d / "run.mcap", "--sigma-m", 0.002, "-o", d / "init.json"),
             ("estimate", d / "run.mcap", "--init", d / "init.json", "--rest", "80:", "--smooth", "-o", d / "states.mcap"),
             ("report", "static", d / "states.mcap", "--gyro", d / "run.mcap", "--angle", "q6+q10", "--survey-deg", -1.4,
              "--date", "2026-01-01", "-o", d / "report")]
    r = _chain(steps)
    fig = _figure(d / "report" / "static.png", "paper-static.png", figdir)
    return [Headline(
        "1998", "Sec. VI.A, Fig. 7", "centre-section vertical angle q6 + q10 at rest: −1.48° by GPS against a laser "
        "survey of −1.4°, 'essentially no drift', estimated noise < 0.02° RMS; the gyro drifts",
        ours=f"mean {r['mean_deg']:.3f}° (survey −1.4°: {r['error_deg']:+.3f}°), noise {r['noise_rms_deg']:.4f}° RMS, "
             f"drift {r['drift_deg_per_min']:+.4f}°/min; gyro drift {r['gyro_drift_deg_per_min']:+.3f}°/min",
        met=r["noise_rms_deg"] < 0.02 and abs(r["error_deg"]) < 0.1 and abs(r["drift_deg_per_min"]) < 0.01,
        commands=[_cmd(*s) for s in steps], values=r, figure=fig,
        note="A simulation of the test on configs/testbed-1998.toml with the paper's 2 mm static noise (motion, then "
             "rest from 80 s), so the survey value is the simulator's truth.")]


def hpsd(w: Path, figdir: Path) -> list[Headline]:
    d = w / "free"
    steps = [("simulate", TESTBED, "--duration", 1200, "--seed", 7, "--scenario", "free", "--noise-m", 0.02,
              "--disturbance-scale", 1, "-o", d / "sim"),
             ("ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", TESTBED, "-o", d / "run.mcap"),
             ("init", d / "run.mcap", "-o", d / "init.json"),
             ("estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "-o", d / "states.mcap"),
             ("report", "spectrum", d / "states.mcap", "--gyro", d / "run.mcap", "--date", "2026-01-01", "-o", d / "report")]
    r = _chain(steps)
    modes = [m for m in r["modes"] if m.get("gps_hz") is not None]
    errs = {m["mode"]: m["error_pct"] for m in modes}
    worst = max(errs, key=lambda k: abs(errs[k]))
    within = sum(abs(v) <= 5.0 for v in errs.values())
    gyro = {m["mode"]: 100 * (m["gps_hz"] / m["gyro_hz"] - 1) for m in modes if m.get("gyro_hz")}
    fig = _figure(d / "report" / "psd.png", "paper-psd.png", figdir)
    return [Headline(
        "1998", "Sec. VI.B, Fig. 8", "the GPS and gyro PSD peaks agree, and the peak frequencies are within 5 % of "
        "Table 1's model frequencies",
        ours=f"{within} of {len(errs)} modes within 5 % (worst {worst} {errs[worst]:+.2f} %); GPS vs gyro peaks within "
             f"{max(abs(v) for v in gyro.values()):.2f} % on the {len(gyro)} modes the gyros see",
        met=within == len(errs), commands=[_cmd(*s) for s in steps], values={"modes": r["modes"]}, figure=fig,
        note="Our structure is simulated from Table 1's frequencies, so this measures the estimator and the spectral "
             "method on a 20 min record at 2 cm noise, not the paper's model against its hardware.")]


# ----------------------------------------------------------------------------------------------
# 1998: control (Fig. 6 poles, Fig. 10 pulse, Figs. 11-12 slew)


def _design(w: Path, weights: str, qx: float | None = None) -> tuple[Path, dict, list]:
    tag = weights if qx is None else f"{weights}-qx{qx:g}"
    g = w / f"gains-{tag}.json"
    if not g.exists():
        extra = () if qx is None else ("--qx", f"{qx:g}")
        args = ("control", "design", TESTBED, "--weights", weights, *extra, "-o", g, "--figure", w / f"poles-{tag}.png")
        return g, cdgps_json(*args), [_cmd(*args)]
    return g, {}, []


def _fig6_weights() -> dict:
    """The state weight W (paper's form and factors) whose vibration poles settle in Fig. 6's 5 s, and
    the designs (benchmarks/paper_fig6_weights.py)."""
    fw = _load_script("benchmarks/paper_fig6_weights.py")
    from cdgps_cli.config.structure import load_config  # noqa: PLC0415

    cfg = load_config(TESTBED)
    qx = fw.bisect_log(lambda q: fw.settling(cfg, q, fw.PAPER_RIGID_FACTOR)[1], 1e-2, fw.PAPER_STATE_WEIGHT,
                       fw.VIBRATION_TARGET_S, False)
    qx = float(f"{qx:.3g}")
    rigid, vib, _, kmax = fw.settling(cfg, qx, fw.PAPER_RIGID_FACTOR)
    return {"qx": qx, "rigid_s": rigid, "vibration_median_s": vib, "max_abs_gain": kmax,
            "paper_over_qx": fw.PAPER_STATE_WEIGHT / qx}


def _gain_max(g: Path) -> float:
    """Largest |K| entry of a GAINS.json (N per unit of state)."""
    import numpy as np  # noqa: PLC0415

    return float(np.abs(np.asarray(json.loads(g.read_text())["K"], dtype=float)).max())


def hfig6(w: Path, figdir: Path) -> list[Headline]:
    g, s, cmds = _design(w, "paper")
    settle = s["settling_time_s"]["closed_loop"]
    rigid = settle.get("rigid-body")
    vib = [v for k, v in settle.items() if k != "rigid-body" and v is not None]
    fast = sorted(v for v in vib if v < 100)
    fig = _figure(w / "poles-paper.png", "paper-fig6-poles.png", figdir)
    f6 = _fig6_weights()
    s = {**s, "max_abs_gain": _gain_max(g)}
    return [Headline(
        "1998", "Sec. V, Fig. 6", "with the paper's weights the rigid-body closed-loop pole settles in ≈ 30 s and the "
        "vibration poles in ≈ 5 s",
        ours=f"rigid body {rigid:.1f} s; vibration modes " + ", ".join(
            f"{k} {v:.2f} s" for k, v in sorted(settle.items(), key=lambda kv: kv[1] or math.inf) if k != "rigid-body")
             + f"; with the one weight scale Fig. 6 implies (W = {f6['qx']:g} for 5000): rigid body {f6['rigid_s']:.1f} s, "
               f"vibration {f6['vibration_median_s']:.1f} s (median)",
        met=abs(rigid - 30) <= 10 and all(2.5 <= v <= 10 for v in fast),
        commands=cmds, values={**s, "fig6_implied_weights": f6}, figure=fig,
        note=f"With the paper's weights on our model (mass-normalized shapes, NASTRAN's default, and our Υ) the moved "
             f"vibration poles settle ≈ {5 / fast[len(fast) // 2]:.0f}× faster than the paper's ≈ 5 s and the rigid pole "
             "in the time above. The paper does not state the units of ξ and u; the weights' form fixes everything but "
             f"one scale, and that one scale reproduces both of Fig. 6's numbers: W = {f6['qx']:g} instead of 5000 "
             f"(f_rigid 0.01, f_rate 0.01, Q_u = I; a factor {f6['paper_over_qx']:.0f} between the paper's Q_x/Q_u and "
             f"ours) gives vibration poles of {f6['vibration_median_s']:.1f} s (median) and a rigid pole of "
             f"{f6['rigid_s']:.1f} s, with a largest gain of {f6['max_abs_gain']:.2f} N per unit against "
             f"{s.get('max_abs_gain', float('nan')):.3g} (`python benchmarks/paper_fig6_weights.py`). The readings of the units in "
             "`python benchmarks/control_weight_scaling.py configs/testbed-1998.toml` (unit-norm shapes, u / F_max, "
             "continuous design, 20 Hz) do not give both numbers; the factor is what Fig. 6 implies, not a unit we can name. The swing mode cannot be moved: the thrusters (±x, ±z at the arm tips, our "
             "assumption) exert no sideways force. With the literal weights the jets saturate in the pulse and slew "
             "experiments (below).")]


def _pulse_args(seed: int) -> tuple:
    return ("--scenario", "pulse", "--duration", 20, "--seed", seed, "--disturbance-scale", 0.05)


def _open_pulse(w: Path, seed: int) -> Path:
    """The open-loop pulse of one seed (simulated once, shared by every closed-loop run of that seed)."""
    o = w / f"pulse-open-{seed}"
    if not o.exists():
        cdgps("simulate", TESTBED, *_pulse_args(seed), "-o", o)
    return o


def _pulse(w: Path, seed: int, g: Path, tag: str, extra=()) -> dict:
    common = _pulse_args(seed)
    o, c = _open_pulse(w, seed), w / f"pulse-closed-{tag}-{seed}"
    cdgps("simulate", TESTBED, *common, "--controller", g, *extra, "-o", c)
    return cdgps_json("report", "control", g, "--open", o, "--closed", c, "--date", "2026-01-01", "-o",
                      w / f"pulse-rep-{tag}-{seed}")


def _pulse_eq18(w: Path, seed: int, g: Path, tag: str) -> dict:
    """The pulse with the paper's EKF as Sec. IV writes it: the time update x̄ = A x + B u (Eq. 18) with u
    every firing the computer commanded, the Fig. 9 pulse included, and the paper's W itself (scale 1).
    In-process (``cdgps simulate`` has no switch for it), then the same ``cdgps report control``."""
    from cdgps_cli.config.structure import load_config  # noqa: PLC0415
    from cdgps_cli.io.gains_file import read_gains  # noqa: PLC0415
    from cdgps_cli.pipeline.closed_loop import simulate_closed_loop  # noqa: PLC0415
    from cdgps_cli.sim.structure import SimOptions, write_simulation  # noqa: PLC0415

    o, c = w / f"pulse-open-{seed}", w / f"pulse-closed-{tag}-{seed}"
    opt = SimOptions(duration_s=20.0, seed=seed, scenario="pulse", disturbance_scale=0.05)
    sim, _ = simulate_closed_loop(load_config(TESTBED), opt, read_gains(g, TESTBED), pulse_known=True,
                                  estimator_noise_scale=PULSE_EQ18_W_SCALE)
    write_simulation(sim, c)
    return cdgps_json("report", "control", g, "--open", o, "--closed", c, "--date", "2026-01-01", "-o",
                      w / f"pulse-rep-{tag}-{seed}")


def _decompose_one(w: Path, seeds: int, weights: str) -> dict:
    """benchmarks/paper_pulse_decomposition.py on one weight set, in its own process."""
    out = w / f"pulse-decomposition-{weights}.json"
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "paper_pulse_decomposition.py"), "--seeds", str(seeds),
                        "--weights", weights, "-o", str(out)], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"paper_pulse_decomposition.py --weights {weights} failed:\n{p.stderr[-3000:]}")
    return json.loads(out.read_text())


def _merge_decomposition(names, parts) -> dict:
    """One paper_pulse_decomposition.py result from its per-weight-set runs (the worst over the seeds kept)."""
    out = {**parts[0], "results": {n: p["results"][n] for n, p in zip(names, parts)},
           "wall_s": max(p["wall_s"] for p in parts)}
    for rows in out["results"].values():         # the worst over the seeds is what the table quotes
        for row in rows.values():
            row.pop("per_seed")
    return out


def _pulse_summary(reps) -> dict:
    m = [r["metrics"]["closed"] for r in reps]
    coords = [r["coordinates"]["closed"] for r in reps]
    return {"ratio": max(x[q]["peak_ratio"] for x in m for q in ("q5", "q8")),
            "back": max(x[q]["closed_back_within_s_after_pulse"] or math.inf for x in m for q in ("q5", "q8")),
            "open_pp": max(x[q]["open_tail_peak_to_peak_deg"] for x in m for q in ("q5", "q8")),
            "all_within": sum(all(c["within"] is not False for c in cs.values()) for cs in coords),
            "worst": max(((k, c["max_abs"] / c["limit"], c["max_abs"], c["unit"]) for cs in coords for k, c in cs.items()
                          if c["limit"]), key=lambda v: v[1]),
            "saturated": max(r["controllers"]["closed"].get("saturated_fraction") or 0.0 for r in reps),
            "metrics": m, "coordinates": coords}


def _pulse_note(run, eq18, pap, fig6w, truth, f6, dec) -> str:
    r = dec["results"]

    def fig(wn, v):
        x = r[wn][v]
        back = "not back" if x["back_s"] is None else f"{x['back_s']:.1f} s"
        return f"{x['ratio']:.2f}/{back}"

    t = EXPERIMENT_WEIGHTS
    return (LIMITS_NOTE.format(when="from 3 s after the pulse's end (Sec. VI.C's 'within 3 s')",
                               rigid="q10 1° about its value at the pulse start (ours; the paper gives no number for it)")
            + " Met only under one reading, hence 'see note': "
            "the paper's time update x̄ = A x + B u (Eq. 18) uses the commands its computer issued, and the Fig. 9 pulse "
            "was fired by that computer through the same jets, so we put it in u; the paper does not say so. "
            + _pulse_10_seeds() + "What "
            f"limits the loop (`python benchmarks/paper_pulse_decomposition.py`, ratio/back, worst of {dec['seeds']} "
            f"seeds, one ingredient swapped at a time): {t} weights: GPS estimate {fig(t, 'gps')}, true state "
            f"{fig(t, 'truth')}, noise-free phases {fig(t, 'gps-noisefree')}, pulse known to the EKF {fig(t, 'gps-known')}, "
            f"pulse known and the paper's W {fig(t, 'gps-known-W1')}, ideal continuous force instead of PWPF "
            f"{fig(t, 'gps-ideal')} — the EKF's lag behind the unknown pulse costs the most, measurement noise and the "
            f"PWPF little. Literal weights: true state {fig('paper', 'truth')}, noise-free phases "
            f"{fig('paper', 'gps-noisefree')}, GPS estimate {fig('paper', 'gps')} (jets saturated "
            f"{100 * pap['saturated']:.0f} % of jet-periods), pulse known {fig('paper', 'gps-known')}, ideal force "
            f"{fig('paper', 'gps-ideal')} — the simulated 1 cm phase noise, through the estimate times the literal gain, saturates the 1.4 N jets. Fig. "
            f"6-implied weights (W = {f6['qx']:g}): even the true state gives {fig('fig6', 'truth')}: that gain is too "
            f"weak for one third (GPS estimate {fig('fig6', 'gps')}, saturated {100 * fig6w['saturated']:.1f} %). "
            f"Seed 1 through `cdgps simulate --feedback truth` with the literal weights: {truth['ratio']:.2f}, back "
            f"{_back(truth['back'])}.")


#: where the closed-loop reports' limits come from (cdgps report control, "Every coordinate")
LIMITS_NOTE = ("Every coordinate q1–q10 is checked {when} (`cdgps report control`, 'Every coordinate'; values in "
               "cdgps_cli/control/metrics.py, sources in cdgps_cli/report/control_coordinates.py): q2/q5/q8 within 1°, the "
               "paper's bound on the internal rotations (Sec. VI.D); q3/q6/q9 within 1° and q1/q4/q7 within 17.5 mm (1° at "
               "the 1 m arm) are ours, the paper states no limit for them; {rigid}.")


def _pulse_10_seeds() -> str:
    """The Eq. 18 reading and the default loop over 10 seeds (benchmarks/paper_pulse_decomposition.py --seeds 10),
    from its recorded JSON; empty without it."""
    path = ROOT / "docs" / "benchmarks" / "paper_pulse_decomposition_10seeds.json"
    if not path.exists():
        return ""
    r = json.loads(path.read_text())["results"].get(EXPERIMENT_WEIGHTS, {})
    if not {"gps", "gps-known-W1"} <= set(r):
        return ""

    def fig(v):
        back = "not back" if r[v]["back_s"] is None else f"back within {r[v]['back_s']:.1f} s"
        return f"≤ {r[v]['ratio']:.2f}, {back}"
    return (f"Over 10 seeds (docs/benchmarks/paper_pulse_decomposition_10seeds.json): that reading {fig('gps-known-W1')} "
            f"(about one third, not ≤ 1/3 in every seed); the pulse unknown to the EKF {fig('gps')}. ")


def _back(seconds: float) -> str:
    """'within X s' (after the pulse), or that it did not come back within the run."""
    return f"within {seconds:.1f} s" if math.isfinite(seconds) else "not within the 14 s left of the run"


def _pulse_mark(eq18: dict, run: dict, seeds: int) -> bool | None:
    """The pulse row's mark: met (about one third, ± 0.02; back within 3 s; every coordinate within its limit in
    every seed) on both readings; "see note" (None) when only the Eq. 18 reading (pulse in the EKF's u) meets it."""
    def ok(x):
        return x["ratio"] <= 1 / 3 + 0.02 and x["back"] <= 3.0 and x["all_within"] == seeds
    return True if ok(eq18) and ok(run) else (None if ok(eq18) else False)


def hpulse(w: Path, figdir: Path, seeds: int) -> list[Headline]:
    g, _, cmds = _design(w, EXPERIMENT_WEIGHTS)
    gp, _, cmds_p = _design(w, "paper")
    f6 = _fig6_weights()
    g6, _, cmds_6 = _design(w, "paper", f6["qx"])
    npap = min(seeds, PAPER_WEIGHT_SEEDS)
    _pmap(_open_pulse, [(w, s) for s in range(1, seeds + 1)])        # the open-loop runs first, once per seed
    names = tuple(_load_script("benchmarks/paper_pulse_decomposition.py").WEIGHTS)
    # the decomposition (one process per weight set, the longest jobs) first, then every other run, JOBS at a time
    reps = _pmap(lambda f, *a: f(*a), [(_decompose_one, w, seeds, n) for n in names]
                 + [(_pulse, w, s, g, EXPERIMENT_WEIGHTS) for s in range(1, seeds + 1)]
                 + [(_pulse, w, s, gp, "paper") for s in range(1, npap + 1)]
                 + [(_pulse, w, s, g6, "fig6") for s in range(1, npap + 1)]
                 + [(_pulse, w, 1, gp, "paper-truth", ("--feedback", "truth"))]
                 + [(_pulse_eq18, w, s, g, f"{EXPERIMENT_WEIGHTS}-eq18") for s in range(1, seeds + 1)])
    dec, reps = _merge_decomposition(names, reps[:len(names)]), reps[len(names):]
    run, pap = _pulse_summary(reps[:seeds]), _pulse_summary(reps[seeds:seeds + npap])
    fig6w = _pulse_summary(reps[seeds + npap:seeds + 2 * npap])
    truth, eq18 = _pulse_summary(reps[seeds + 2 * npap:seeds + 2 * npap + 1]), _pulse_summary(reps[-seeds:])
    fig = _figure(w / f"pulse-rep-{EXPERIMENT_WEIGHTS}-eq18-1" / "pulse.png", "paper-fig10-pulse.png", figdir)
    cmds += [_cmd("simulate", TESTBED, "--scenario", "pulse", "--duration", 20, "--seed", "S", "--disturbance-scale", 0.05,
                  "[--controller", f"gains-{EXPERIMENT_WEIGHTS}.json]", "-o", "DIR"),
             _cmd("report", "control", f"gains-{EXPERIMENT_WEIGHTS}.json", "--open", "OPEN", "--closed", "CLOSED", "-o",
                  "REPORT")]
    k, _, worst, unit = run["worst"]
    open_pp = run["open_pp"]
    return [
        Headline("1998", "Sec. VI.C, Fig. 10", "closed loop: q5 and q8 peak at about one third of the first open-loop "
                 "oscillation, and the structure is back within 3 s of the end of the pulse",
                 ours=f"reading the paper's EKF with the pulse in the time update's u (Eq. 18; the paper does not say "
                      f"so) and the paper's W: closed/open "
                      f"peak ratio ≤ {eq18['ratio']:.2f}, back {_back(eq18['back'])}; every coordinate q1–q10 within its "
                      f"limit from 3 s after the pulse in {eq18['all_within']} of {seeds} seeds (worst {eq18['worst'][0]} "
                      f"{eq18['worst'][2]:.2f} {eq18['worst'][3]}). With the pulse unknown to the EKF (W scaled by the "
                      f"separation rule): ≤ {run['ratio']:.2f}, back {_back(run['back'])}, {run['all_within']} of {seeds} "
                      f"(worst {k} {worst:.2f} {unit}) ({seeds} seeds, GPS estimate in the loop, weights {EXPERIMENT_WEIGHTS})",
                 met=_pulse_mark(eq18, run, seeds),
                 commands=cmds + cmds_p + cmds_6 + ["python benchmarks/paper_pulse_decomposition.py  # gps-known-W1: the Eq. 18 reading, in-process"], figure=fig,
                 values={"weights": EXPERIMENT_WEIGHTS, **run, "eq18": eq18, "paper_weights": pap, "fig6_weights": fig6w,
                         "fig6_qx": f6["qx"], "paper_weights_true_state_seed1": truth, "seeds": seeds,
                         "decomposition": dec},
                 note=_pulse_note(run, eq18, pap, fig6w, truth, f6, dec)),
        Headline("1998", "Fig. 10 (open loop)", "open loop: the pulse swings the longitudinal twist q5/q8 by ≈ 10° peak to peak",
                 ours=f"{open_pp:.1f}° peak to peak (largest of q5, q8 over the last 10 s, {seeds} seeds)",
                 met=abs(open_pp / OPEN_PULSE_PP_DEG - 1) <= OPEN_PULSE_TOL,
                 note=f"Met within ±{100 * OPEN_PULSE_TOL:.0f} %. Not fitted: the model's inertias come from Table 1's "
                      "frequencies and the tube's stiffness (docs/testbed-model.md); the lumped model it replaces "
                      "(configs/testbed-1998-lumped.toml) swung 50°. q5 moves up and q8 down at once, q2 follows about "
                      "2 s later, as the paper describes.",
                 values={"open_tail_peak_to_peak_deg": open_pp}),
    ]


def _slew(w: Path, seed: int, g: Path, tag: str, extra=()) -> dict:
    d = w / f"slew-{tag}-{seed}"
    cdgps("simulate", TESTBED, "--scenario", "slew", "--duration", 40, "--seed", seed, "--disturbance-scale", SLEW_DISTURBANCE,
          "--controller", g, *extra, "-o", d)
    rep = cdgps_json("report", "control", g, "--closed", d, "--date", "2026-01-01", "-o", w / f"slew-rep-{tag}-{seed}")
    return {**rep["metrics"]["closed"], "coordinates": rep["coordinates"]["closed"],
            "saturated": rep["controllers"]["closed"].get("saturated_fraction")}


def _step_slew(w: Path, seed: int, g: Path, tag: str, extra=()) -> dict:
    """The paper's raw step command (Fig. 12a), 60 s: the report's metrics and the true rigid angle's
    overshoot past the target and number of crossings of it (deg)."""
    import numpy as np  # noqa: PLC0415
    import pandas as pd  # noqa: PLC0415

    d = w / f"step-{tag}-{seed}"
    cdgps("simulate", TESTBED, "--scenario", "slew", "--duration", 60, "--seed", seed, "--disturbance-scale", SLEW_DISTURBANCE,
          "--controller", g, "--slew-reference", "step", *extra, "-o", d)
    rep = cdgps_json("report", "control", g, "--closed", d, "--date", "2026-01-01", "-o", w / f"step-rep-{tag}-{seed}")
    q = pd.read_csv(d / "truth.csv")
    err = np.degrees(q["q10_rad"].to_numpy()) - SLEW_TO_DEG
    first = int(np.argmax(np.sign(err) != np.sign(err[0])))
    after = err[first:] if first > 0 else err[:0]
    return {**rep["metrics"]["closed"], "saturated": rep["controllers"]["closed"].get("saturated_fraction"),
            "overshoot_deg": float(np.abs(after).max()) if after.size else 0.0,
            "crossings": int(np.sum(np.diff(np.sign(after)) != 0)) + (1 if after.size else 0),
            "vertical_max_deg": max(rep["coordinates"]["closed"][k]["max_abs"] for k in ("q3", "q6", "q9"))}


def _worst(runs, key):
    return max(abs(r[key]) if r[key] is not None else math.inf for r in runs)


def _largest(runs, names):
    return [max(r["coordinates"][q]["max_abs"] for q in names) for r in runs]


def hslew(w: Path, figdir: Path, seeds: int) -> list[Headline]:
    g, _, cmds = _design(w, EXPERIMENT_WEIGHTS)
    gp, _, _ = _design(w, "paper")
    nv, npap = min(seeds, 5), min(seeds, PAPER_WEIGHT_SEEDS)
    runs = _pmap(lambda f, *a: f(*a), [(_slew, w, s, g, "vib") for s in range(1, seeds + 1)]
                 + [(_slew, w, s, g, "novib", ("--no-vibration-control",)) for s in range(1, nv + 1)]
                 + [(_slew, w, s, gp, "paper") for s in range(1, npap + 1)]
                 + [(_step_slew, w, s, g, "vib") for s in range(1, STEP_SEEDS + 1)]
                 + [(_step_slew, w, s, g, "novib", ("--no-vibration-control",)) for s in range(1, STEP_SEEDS + 1)])
    vib, runs = runs[:seeds], runs[seeds:]
    novib, pap, runs = runs[:nv], runs[nv:nv + npap], runs[nv + npap:]
    step_v, step_nv = runs[:STEP_SEEDS], runs[STEP_SEEDS:]
    layout = _layout_study()
    est = _static_slew_deformation()
    arrived, final = _worst(vib, "arrived_s_after_command"), _worst(vib, "final_error_deg")
    internal = [max(r["internal_max_deg"][q] for q in ("q2", "q5", "q8")) for r in vib]
    ok_internal = sum(v <= 1.0 for v in internal)
    internal_nv = [max(r["internal_max_deg"][q] for q in ("q2", "q5", "q8")) for r in novib]
    vertical, lateral = _largest(vib, ("q3", "q6", "q9")), _largest(vib, ("q1", "q4", "q7"))
    vertical_nv = _largest(novib, ("q3", "q6", "q9"))
    all_within = sum(all(c["within"] is not False for c in r["coordinates"].values()) for r in vib)
    rigid_ok = sum(r["coordinates"].get("q10", {}).get("within") is True for r in vib)
    final_nv = _worst(novib, "final_error_deg")
    ratios = [nv / v for nv, v in zip(internal_nv, internal)]             # the same seeds 1..len(novib)
    more = [r > 1 for r in ratios]
    fig = _figure(w / "slew-rep-vib-1" / "slew.png", "paper-fig11-slew.png", figdir)
    cmds += [_cmd("simulate", TESTBED, "--scenario", "slew", "--duration", 40, "--seed", "S", "--disturbance-scale",
                  SLEW_DISTURBANCE, "--controller", f"gains-{EXPERIMENT_WEIGHTS}.json", "[--no-vibration-control]", "-o", "DIR"),
             _cmd("report", "control", f"gains-{EXPERIMENT_WEIGHTS}.json", "--closed", "DIR", "-o", "REPORT")]
    pap_arrived = _worst(pap, "arrived_s_after_command")
    pap_note = (f"With the paper's weights ({len(pap)} seeds) the jets saturate in "
                f"{100 * max(r['saturated'] or 0 for r in pap):.0f} % of jet-periods and the slew "
                + (f"arrives within {pap_arrived:.1f} s" if math.isfinite(pap_arrived) else
                   "does not arrive within the 35 s after the command")
                + f" (final error up to {_worst(pap, 'final_error_deg'):.1f}°; q2/q5/q8 up to "
                f"{max(max(r['internal_max_deg'].values()) for r in pap):.2f}°).")
    return [
        Headline("1998", "Sec. VI.D, Fig. 11", "slew +14° → −22°: done within 30 s, final angle within 0.5° as measured "
                 "by GPS, internal rotations q2/q5/q8 within 1°",
                 ours=f"arrived within {arrived:.1f} s, final error ≤ {final:.2f}°; q2/q5/q8 within 1° in {ok_internal} of "
                      f"{seeds} seeds (worst {max(internal):.2f}°; GPS estimate in the loop, weights {EXPERIMENT_WEIGHTS})"
                      + _centre_final_text(_slew_decomposition()),
                 met=_two_readings(arrived <= 30 and final <= 0.5 and ok_internal >= math.ceil(0.95 * seeds),
                                   _slew_decomposition()), commands=cmds, figure=fig,
                 values={"weights": EXPERIMENT_WEIGHTS, "with_vibration_control": vib, "paper_weights": pap},
                 note="'Final angle within 0.5° as measured by GPS': the paper does not say whether that is the "
                      "rigid-body angle q10 or the angle the centre section's antennas measure, q6 + q10 (Sec. VI.A's "
                      "angle); the row is met on the first reading, and marked 'see note' when the second is not within "
                      "0.5° (the figures above; `python benchmarks/paper_slew_decomposition.py`). "
                      f"q2/q5/q8 are the sections' twists about the structure's axis in our model (Fig. 10's 'longitudinal "
                      f"twist'). The structure is forced by {SLEW_DISTURBANCE:g} × the model's process noise throughout, "
                      "as in benchmarks/control_experiments.py (the paper's was at rest before the command). " + pap_note),
        Headline("1998", "Sec. VI.D (every coordinate)", "Fig. 11b's text calls the internal angles 'relative vertical "
                 "axis rotations' and has them within 1°; the other coordinates are not shown, and no limit is given "
                 "for them (issue 31: every coordinate checked against a stated limit)",
                 ours=f"rotations about the vertical q3/q6/q9 up to {max(vertical):.1f}° (over our 1° in "
                      f"{sum(v > 1.0 for v in vertical)} of {seeds} seeds, least {min(vertical):.1f}°), lateral "
                      f"translations q1/q4/q7 up to {max(lateral):.1f} mm (our limit 17.5 mm), q10 within 0.5° of the "
                      f"command from 30 s after it in {rigid_ok} of {seeds}; every coordinate within its "
                      f"limit in {all_within} of {seeds} seeds",
                 met=all_within >= math.ceil(0.95 * seeds),
                 values={"vertical_max_deg": vertical, "lateral_max_mm": lateral, "all_within": all_within,
                         "thruster_layouts": layout, "decomposition": _slew_decomposition(), "quasi_static": est},
                 note="The slew's torque comes from ±x jets on the 1 m arms (our reading of 'four actuators at the end of "
                      f"each boom'), i.e. as a torque on each section; the end sections' 60 kg at 4 m ({est['end_share_pct']:.0f} % "
                      "of the rotational inertia) can only be accelerated through the tubes, which bend: with the torque "
                      f"shared equally by the sections, K⁺(f − M r α) gives an end-section yaw of {est['yaw_deg'][0]:.1f}–"
                      f"{est['yaw_deg'][1]:.1f}° for a 36° bang-bang "
                      "slew in 30–25 s, and each switch of the acceleration rings the bending modes on top; the "
                      f"quasi-static part alone stays within 1° only for a slew of ≥ {est['slew_time_for_1deg_s']:.0f} s, "
                      "longer than the paper's 30 s. Vibration "
                      f"control does not remove it (without it: up to {max(vertical_nv):.1f}°). "
                      + _slew_dec_note(_slew_decomposition()) + _layout_note(layout)
                      + " " + LIMITS_NOTE.format(when="from the command", rigid="q10 within 0.5° of the command from 30 s "
                                                 "after it, the paper's 'within 30 s', 'final angle within 0.5°'")
                      + " The row is 'no' against our limits for q3/q6/q9 and q1/q4/q7, not against a number of the "
                      "paper's. Derivation and table: docs/testbed-model.md."
                      + " The paper's q2/q5/q8 are twists by Sec. VI.C and by Sec. VI.A's centre-section vertical angle "
                      "q6 + q10; if Fig. 11b shows rotations about the vertical, this is not reproduced."),
        Headline("1998", "Fig. 12b", "without vibration control the slew excites significant internal vibrations",
                 ours=f"q2/q5/q8 larger without vibration control in {sum(more)} of {len(novib)} seeds, by "
                      f"{min(ratios):.1f}–{max(ratios):.1f}× (up to {max(internal_nv):.2f}° against {max(internal):.2f}°); "
                      f"q3/q6/q9 up to {max(vertical_nv):.1f}° against {max(vertical):.1f}°",
                 met=all(more), values={"without_vibration_control": novib},
                 note="Same seeds, same reference and weights; the rigid-only regulator is the paper's low-bandwidth "
                      "design (rigid pole as in Fig. 6, vibration poles left open loop)."),
        Headline("1998", "Fig. 12a", "without vibration control the final rigid-body angle oscillates about the target",
                 ours=f"profile command: final error ≤ {final_nv:.2f}° without vibration control, ≤ {final:.2f}° with it "
                      f"({len(novib)} seeds); the paper's step command: overshoot {_span(step_nv, 'overshoot_deg')}° without, "
                      f"{_span(step_v, 'overshoot_deg')}° with vibration control ({STEP_SEEDS} seeds)",
                 met=False, values={"step_with_vibration_control": step_v, "step_without_vibration_control": step_nv},
                 commands=[_cmd("simulate", TESTBED, "--scenario", "slew", "--duration", 60, "--seed", "S",
                                "--disturbance-scale", SLEW_DISTURBANCE, "--controller", f"gains-{EXPERIMENT_WEIGHTS}.json",
                                "--slew-reference", "step", "[--no-vibration-control]", "-o", "DIR")],
                 note="Not reproduced. With the bang-bang reference and its feed-forward thrust (the default "
                      "--slew-reference profile) the rigid-only loop tracks as well as the full one. With the paper's step "
                      "command both loops swing far past the target (the jets saturate in "
                      f"{100 * max(r['saturated'] or 0 for r in step_v + step_nv):.0f} % of jet-periods and the rigid "
                      f"angle crosses the target {max(r['crossings'] for r in step_v + step_nv)} times at most), and "
                      f"arrive {_span(step_v, 'arrived_s_after_command')} s (with) and "
                      f"{_span(step_nv, 'arrived_s_after_command')} s (without) after the command: the harmonic motion "
                      "about the target is there, but in both runs, not only without vibration control; q3/q6/q9 reach "
                      f"{max(r['vertical_max_deg'] for r in step_v):.1f}° and "
                      f"{max(r['vertical_max_deg'] for r in step_nv):.1f}°. " + _fig12a_note(_slew_decomposition())),
    ]


def _span(runs, key) -> str:
    vals = [r[key] for r in runs]
    if any(v is None for v in vals):
        return "never" if all(v is None for v in vals) else f"{min(v for v in vals if v is not None):.1f}–never"
    lo, hi = min(vals), max(vals)
    return f"{lo:.1f}" if abs(hi - lo) < 0.05 else f"{lo:.1f}–{hi:.1f}"


def _layout_note(layout: dict) -> str:
    """One sentence per alternative thruster layout of benchmarks/paper_thruster_layout.py."""
    if not layout:
        return "(run `python benchmarks/paper_thruster_layout.py` for the thruster-layout comparison)"
    parts = []
    for name, r in layout.items():
        rr = r["runs"]
        parts.append(f"{name}: q3/q6/q9 ≤ {max(x['vertical_deg'] for x in rr):.1f}°, q2/q5/q8 ≤ "
                     f"{max(x['twist_deg'] for x in rr):.1f}°, q1/q4/q7 ≤ {max(x['lateral_mm'] for x in rr):.0f} mm, "
                     f"saturated {100 * max(x['saturated'] or 0 for x in rr):.0f} %")
    return ("Sideways jets push the end sections' mass directly (4 N·m per N about the centre): with ±y instead of ±x on "
            "the end sections' arms (end-y) or on all arms (all-y), same rigid acceleration, tuned weights designed on "
            f"each layout, {len(next(iter(layout.values()))['runs'])} seeds (`python benchmarks/paper_thruster_layout.py`) — "
            + "; ".join(parts) + ". The rotations about the vertical fall to ≈ 1°, but with the weights tuned for "
            "the ±x layout the loop then saturates the jets and the twists and translations pass their limits; "
            "the layout needs its own weights, which we have not tuned (the issue asks for a miss to be shown rather than "
            "tuned until it fits), so the config keeps ±x.")


def _static_slew_deformation(times_s=(30.0, 25.0), slew_deg=36.0) -> dict:
    """End-section yaw (deg) of the quasi-static deformation K⁺(f − M r α) for a bang-bang slew of
    ``slew_deg`` in each of ``times_s`` (α = 4·angle/T²) with the slew torque shared equally by the
    three sections (±x jets), on the fitted model; and the end sections' share of rᵀ M r (%)."""
    import numpy as np  # noqa: PLC0415

    mt = _testbed_script()
    M, K = mt.testbed_matrices(mt.FITTED)
    r = mt.rigid_rotation()
    inertia = float(r @ M @ r)
    yaw = []
    for t in times_s:
        alpha = 4 * math.radians(slew_deg) / t**2
        f = np.zeros(9)
        f[2::3] = inertia * alpha / 3
        yaw.append(math.degrees(float((np.linalg.pinv(K) @ (f - M @ r * alpha))[2])))
    end = mt.MASS_KG * float((mt.X_SECTIONS**2).sum())
    # the quasi-static yaw scales with α ∝ 1/T²: the bang-bang slew time that keeps it at 1° (s)
    t_1deg = times_s[0] * math.sqrt(abs(yaw[0]) / 1.0)
    return {"yaw_deg": yaw, "end_share_pct": 100 * end / inertia, "slew_time_for_1deg_s": t_1deg}


def _slew_decomposition() -> dict:
    """The slew decomposition of benchmarks/paper_slew_decomposition.py, from its last run's JSON."""
    path = ROOT / "docs" / "benchmarks" / "paper-slew-decomposition.json"
    return json.loads(path.read_text())["variants"] if path.exists() else {}


def _slew_dec_note(dec: dict) -> str:
    """Why q3/q6/q9 swing: the decomposition's worst figures per variant (one ingredient changed at a time)."""
    if not dec:
        return ""
    labels = {"gps": "as run", "truth": "true state fed back", "bending-x10": "bending-mode weights ×10",
              "bending-x100": "×100", "elastic-x10": "every elastic weight ×10",
              "no-vibration-control": "rigid-only regulator", "shaped-step": "the paper's step, filtered",
              "step": "raw step"}

    def one(n):
        rs = dec[n]
        arr = [r["arrived_s"] for r in rs]
        done = f"arrives {max(arr):.0f} s" if all(a is not None for a in arr) else "does not arrive"
        return (f"{labels.get(n, n)}: q3/q6/q9 ≤ {max(r['vertical_deg'] for r in rs):.1f}°, q2/q5/q8 ≤ "
                f"{max(r['twist_deg'] for r in rs):.2f}°, q1/q4/q7 ≤ {max(r['lateral_mm'] for r in rs):.0f} mm, "
                f"saturated {100 * max(r['saturated'] for r in rs):.0f} %, {done}")
    return (f"What drives q3/q6/q9 (`python benchmarks/paper_slew_decomposition.py`, {len(next(iter(dec.values())))} seeds, "
            "one ingredient changed at a time) — " + "; ".join(one(n) for n in labels if n in dec) + ". Neither the "
            "estimator nor the vibration loop nor the weights on the modes that carry q3/q6/q9 change it; raising those "
            "weights only saturates the jets. ")


def _centre_final_text(dec: dict) -> str:
    """The final angle read as the centre antennas measure it (q6 + q10) rather than the rigid-body angle:
    its largest swing about the target from 30 s after the command, with vibration control
    (benchmarks/paper_slew_decomposition.py); empty without that study."""
    if "gps" not in dec:
        return ""
    swing = max(r["tail"]["centre"]["max_abs_deg"] for r in dec["gps"])
    return (f". Read as the centre antennas' angle q6 + q10, the final angle still swings ±{swing:.2f}° about the "
            f"target 30–60 s after the command ({len(dec['gps'])} seeds of the decomposition): "
            + ("within" if swing <= 0.5 else "not within") + " 0.5° on that reading")


def _two_readings(rigid_met: bool, dec: dict) -> bool | None:
    """The slew row's mark: met on the rigid-body reading of "final angle"; "see note" (None) when the centre
    antennas' reading (q6 + q10) is not within 0.5° while the rigid-body one is — the paper does not say which."""
    if not rigid_met or "gps" not in dec:
        return rigid_met
    return True if max(r["tail"]["centre"]["max_abs_deg"] for r in dec["gps"]) <= 0.5 else None


def _fig12a_note(dec: dict) -> str:
    """Fig. 12a read as the angle the centre antennas measure (q6 + q10) against the rigid-body angle q10: the
    oscillation about the target from 30 s after the command (benchmarks/paper_slew_decomposition.py)."""
    if not {"gps", "no-vibration-control"} <= set(dec):
        return ""

    def tail(n, which):
        rs = [r["tail"][which] for r in dec[n]]
        return f"±{max(r['max_abs_deg'] for r in rs):.2f}° (≥ {min(r['crossings'] for r in rs)} crossings)"
    return ("A third reading, the 'final rigid-body angle' as the centre section's antennas measure it (q6 + q10, "
            "Sec. VI.A's angle), from 30 s after the command to 60 s, profile command "
            f"(`python benchmarks/paper_slew_decomposition.py`, {len(dec['gps'])} seeds): without vibration control "
            f"{tail('no-vibration-control', 'centre')}, with it {tail('gps', 'centre')}; the rigid-body mode q10 "
            f"alone {tail('no-vibration-control', 'rigid')} and {tail('gps', 'rigid')}. The measured angle does "
            "oscillate about the target, a little more without vibration control, but with it too (the undamped "
            "q6 share of the bending modes, the rotations about the vertical above): the paper's contrast is "
            "reproduced in direction only.")


def _layout_study() -> dict:
    """The thruster-layout comparison of benchmarks/paper_thruster_layout.py, from its last run's JSON."""
    path = ROOT / "docs" / "benchmarks" / "paper-thruster-layout.json"
    return json.loads(path.read_text())["layouts"] if path.exists() else {}


# ----------------------------------------------------------------------------------------------
# 2003: aided tracking loops


def _tracking_module():
    return _load_script("benchmarks/tracking_paper.py")


def _noise_suppression_db(tones: dict, above_hz: float = 20.0) -> tuple[float, float, tuple[float, float]]:
    """Mean dB by which the 3 Hz loop's measured |H| lies below the 15 Hz loop's at tones ≥ ``above_hz``
    (above both bandwidths, where Alban's "phase-noise suppression" applies), the same from the
    continuous second-order loops, and the tone band used (Hz)."""
    from cdgps_cli.tracking.loops import pll2_response  # noqa: PLC0415

    f = [x for x in tones["tones_hz"] if x >= above_hz]
    gain = {r["run"]: r["gain"] for r in tones["runs"]}
    idx = [tones["tones_hz"].index(x) for x in f]
    measured = [20 * math.log10(gain["15 Hz unaided"][i] / gain["3 Hz unaided"][i]) for i in idx]
    analytic = [20 * math.log10(abs(pll2_response(x, 15.0)) / abs(pll2_response(x, 3.0))) for x in f]
    return sum(measured) / len(measured), sum(analytic) / len(analytic), (min(f), max(f))


def htracking(w: Path, figdir: Path) -> list[Headline]:
    tp = _tracking_module()
    tones, jitter, shared = tp.study_tones(), tp.study_jitter(), tp.study_shared()
    bw = {r["run"]: r["bandwidth_3db_hz"] for r in tones["runs"]}
    aided_bw = bw.get("3 Hz aided, 30 Hz sensor")
    dyn = {(r["bn_hz"], r["loop"]): r for r in jitter["dynamics"]}
    j15, j3a = dyn[(15.0, "unaided")]["jitter_deg"], dyn[(3.0, "aided")]["jitter_deg"]
    gain_db = 20 * math.log10(j15 / j3a)
    supp_db, supp_analytic_db, supp_f = _noise_suppression_db(tones)
    tcxo = next(o for o in shared["oscillators"] if o["name"] == "TCXO")
    rows = {r["run"]: r for r in tcxo["rows"]}
    narrow = next((r for k, r in rows.items() if k.startswith("3 Hz + shared")), None)
    cmd = "python benchmarks/tracking_paper.py --only tones,jitter,shared"
    return [
        Headline("2003", "abstract, §III", "the aided carrier loop's tracking bandwidth matches the inertial sensor's (> 30 Hz)",
                 ours=f"−3 dB tracking bandwidth {aided_bw:.1f} Hz (3 Hz loop aided by a 30 Hz sensor); unaided 3 Hz: "
                      f"{bw['3 Hz unaided']:.1f} Hz", met=aided_bw is not None and aided_bw > 30, commands=[cmd],
                 values={"tones": tones}, figure="figures/tracking-tones.png"),
        Headline("2003", "abstract", "a 3 Hz aided loop suppresses phase noise 14 dB better than a traditional 15 Hz loop",
                 ours=f"{supp_db:.1f} dB: the 3 Hz loop's phase-noise transfer lies that far below the 15 Hz loop's "
                      f"(phase tones {supp_f[0]:g}–{supp_f[1]:g} Hz, 55 dB-Hz; analytic 20·log10(15/3) = {supp_analytic_db:.1f} dB); "
                      f"RMS jitter under 0.5 g at 2 Hz dynamics, 45 dB-Hz: {gain_db:.1f} dB ({j15:.2f}° → {j3a:.2f}°, "
                      "consumer accelerometer aid)", met=abs(supp_db - 14.0) <= 1.0,
                 commands=[cmd], values={"jitter": jitter, "noise_suppression_db": supp_db,
                                         "noise_suppression_analytic_db": supp_analytic_db,
                                         "noise_suppression_band_hz": list(supp_f), "jitter_ratio_db": gain_db},
                 figure="figures/tracking-jitter.png",
                 note="14 dB is 20·log10(15/3) = 13.98 dB: the ratio of the two loops' noise transfer H1(s) = K1(τ1 s + 1)/"
                      "(s² + K1τ1 s + K1) above their bandwidths, where |H1| ≈ K1τ1/ω = 2ζω_n/ω scales with B_n (Alban "
                      "Eq. 1–2: the reference phase and the phase noise pass through the same H1; aiding removes the "
                      "dynamics from the reference, not the noise). It is not an RMS-jitter ratio: for white (thermal) "
                      "noise σ² ∝ B_n gives 10·log10(5) = 7.0 dB, and our jitter ratio under stated dynamics "
                      f"({gain_db:.1f} dB) depends on the dynamics and C/N0, which the paper does not give. Our measured "
                      "tones are the unaided 3 and 15 Hz loops; the aided 3 Hz loop passes noise through the same H1."),
        Headline("2003", "abstract", "with low-cost inertial sensors and a typical TCXO the loop works at a 3 Hz bandwidth",
                 ours=(f"TCXO: independent 3 Hz loops lose lock ({rows['independent 3 Hz']['slips']} slips in "
                       f"{tcxo.get('duration_s', shared['duration_s'])} s); 3 Hz channels with a shared clock loop: "
                       f"{narrow['slips']} slips, jitter {narrow['jitter_deg_max']:.1f}°") if narrow else "see note",
                 met=None if narrow is None else narrow["slips"] == 0, commands=[cmd], values={"shared": shared},
                 figure="figures/tracking-oscillator.png",
                 note="With our TCXO phase-noise model a 3 Hz loop alone cannot follow the oscillator; the clock's "
                      "common part must be tracked once for all channels (a shared clock loop), which is how we hold 3 Hz."),
    ]


# ----------------------------------------------------------------------------------------------


def _runner_times(rows: list[Headline]) -> tuple[float, float]:
    """Wall and CPU seconds summed over the runners that measured ``rows`` (each runner once)."""
    seen = {h.key: h.values.get("runner_time_s") or {} for h in rows}
    return (sum(t.get("wall", 0.0) for t in seen.values()), sum(t.get("cpu", 0.0) for t in seen.values()))


#: issue 31's "What to deliver", sentence by sentence: (what it asks, the headline keys (paper, where) whose marks
#: and figures answer it, or None, where it is delivered)
ACCEPTANCE = (
    ("1. mass and stiffness so that frequencies, damping and shapes agree with Table 1 together",
     [("1998", "Table 1, Figs. 3–5")],
     "configs/testbed-1998.toml from `python scripts/make_testbed_config.py`; docs/testbed-model.md (the shapes "
     "the paper names, MAC ≥ 0.99; Table 1's time constants written into the config, as the paper did, not derived; "
     "the suspension length fitted, 9.51 m, as the paper's 12 m threads cannot give the swing mode)"),
    ("1. thruster geometry and force model Υ derived from the described layout, assumptions stated", None,
     "docs/testbed-model.md 'Force model Υ' (±x and ±z at each arm tip, our reading; the swing mode uncontrollable "
     "with it); other layouts measured by `python benchmarks/paper_thruster_layout.py`"),
    ("1. the previous config kept under another name if anything depends on it", None,
     "configs/testbed-1998-lumped.toml, byte for byte the config before issue 31 (sha256 49bd4822…, the "
     "config_sha256 of data/testbed-free and data/testbed-static); the tests, the demo and the bundled data use it"),
    ("2. static test", [("1998", "Sec. VI.A, Fig. 7")], "`cdgps report static` (commands below)"),
    ("2. PSD against the gyro", [("1998", "Sec. VI.B, Fig. 8")], "`cdgps report spectrum`"),
    ("2. pulse: open loop ≈ 10° p-p on the twist", [("1998", "Fig. 10 (open loop)")], "`cdgps report control`"),
    ("2. pulse: closed-loop peak ≤ 1/3, back within 3 s", [("1998", "Sec. VI.C, Fig. 10")],
     "`cdgps report control`; `python benchmarks/paper_pulse_decomposition.py`"),
    ("2. slew: within 30 s, final angle within 0.5°, q2/q5/q8 within 1° in ≥ 19 of 20 seeds (estimator in the loop)",
     [("1998", "Sec. VI.D, Fig. 11")], "`cdgps report control`; `python benchmarks/paper_slew_decomposition.py`"),
    ("2. the rigid-only contrast of Fig. 12", [("1998", "Fig. 12b"), ("1998", "Fig. 12a")],
     "`cdgps simulate --no-vibration-control`, `--slew-reference step`"),
    ("2. every generalized coordinate, q3/q6/q9 included, in the closed-loop reports and checked against a stated "
     "limit", [("1998", "Sec. VI.D (every coordinate)")],
     "`cdgps report control`: 'Every coordinate' (q1–q10, a limit row, where each limit comes from) and "
     "coordinates.png (each coordinate against the same limit). Shown and checked: delivered; the check fails for "
     "q3/q6/q9 in the slew (the row's mark)"),
    ("3. 1995: 0.3° RMS attitude, integers", [("1995", "Sec. V, Fig. 6"), ("1995", "Sec. IV")], "`make paper`"),
    ("3. 1998: Fig. 6 poles", [("1998", "Sec. V, Fig. 6")], "`cdgps control design --weights paper`; "
     "`python benchmarks/paper_fig6_weights.py`"),
    ("3. 2003: 3 Hz aided bandwidth, 14 dB, > 30 Hz aided",
     [("2003", "abstract, §III"), ("2003", "abstract")], "`python benchmarks/tracking_paper.py`"),
    ("3. one command runs every headline of the three papers and writes this table", None,
     "`make paper` (`python benchmarks/paper.py`): 1995 ×2, 1998 ×10, 2003 ×3 rows above, with commands and figures"),
    ("3. in under 15 minutes on 2 cores", None, None),
    ("3. a short subset in `make test`", None,
     "tests/test_paper_quick.py runs `benchmarks/paper.py --quick` (1995, Table 1, static test, Fig. 6; ≈ 11 s) "
     "and fails if a figure leaves its bound or a 'no' turns into 'yes' unannounced"),
)


def _acceptance(rows: list[Headline], runtime_s: float | None, quick: bool) -> list[str]:
    """Issue 31's acceptance, sentence by sentence: the marks and figures of the rows that answer it."""
    mark = {True: "yes", False: "**no**", None: "see note"}
    by = {(h.paper, h.where) for h in rows}
    wall, cpu = _runner_times(rows)
    timing = (f"{runtime_s:.0f} s wall for this run" if runtime_s is not None else
              f"{wall:.0f} s wall, {cpu:.0f} CPU s: the sum of the headlines' last runs (paper.json runner_time_s)")
    out = ["## Issue 31 acceptance", "",
           "Issue 31's 'What to deliver', sentence by sentence; the marks are the table's.", "",
           "| the issue asks | delivered | where | measured |", "|---|---|---|---|"]
    for ask, keys, where in ACCEPTANCE:
        if keys is None:
            done = "yes"
            got = ""
            if ask.startswith("3. in under 15"):
                done, where = ("yes" if (runtime_s or wall) < 900 else "**no**"), f"`make paper`, {JOBS} jobs"
                got = timing if not quick else f"{timing} (`--quick`: not the full run)"
        else:
            hs = [h for h in rows if (h.paper, h.where) in keys]       # 2003 has two rows at "abstract"
            if any(k not in by for k in keys):
                done, got = "not run here", "(`--quick`: only " + ", ".join(QUICK) + ")" if quick else "(not run)"
            else:
                marks = [h.met for h in hs]
                done = mark[False if False in marks else (None if None in marks else True)]
                if ask.startswith("2. every generalized"):
                    done = f"in the reports and checked: yes; within the limits: {done}"
                got = "; ".join(f"{h.where}: {h.ours}" for h in hs) if len(hs) > 1 else hs[0].ours
        out.append(f"| {ask} | {done} | {where} | {got} |")
    return out


def _md(rows: list[Headline], runtime_s: float, quick: bool) -> str:
    mark = {True: "yes", False: "**no**", None: "see note"}
    out = ["# The papers' headlines, reproduced", "",
           f"Generated by `python benchmarks/paper.py{' --quick' if quick else ''}` (`make paper`)"
           + (f" in {runtime_s:.0f} s" if runtime_s is not None else " (some headlines rerun with --only)")
           + f" on {datetime.date.today().isoformat()}; the numbers are in `docs/benchmarks/paper.json`. Each row gives the "
           "paper's statement, ours, whether it is reproduced, and the commands that measure it. Where the comparison "
           "is not like for like, or a number is not reproduced, the note says why with the measurement; nothing was "
           "tuned to fit. In the commands, `$WORK` is the run's temporary folder.", "",
           "| paper | where | the paper says | we measure | reproduced |", "|---|---|---|---|---|"]
    for h in rows:
        out.append(f"| {h.paper} | {h.where} | {h.claim} | {h.ours} | {mark[h.met]} |")
    out += ["", *_acceptance(rows, runtime_s, quick)]
    out += ["", "## Each headline", ""]
    for h in rows:
        out += [f"### {h.paper}, {h.where}", "", f"*Paper:* {h.claim}.", "", f"*Ours:* {h.ours}."]
        if h.note:
            out += ["", h.note]
        if h.commands:
            out += ["", "```sh", *h.commands, "```"]
        if h.figure:
            out += ["", f"![{h.where}]({h.figure})"]
        out.append("")
    return "\n".join(out)


RUNNERS = {"1995": lambda w, f, a: h1995(w, f), "model": lambda w, f, a: hmodel(w, f), "static": lambda w, f, a: hstatic(w, f), "psd": lambda w, f, a: hpsd(w, f),
           "fig6": lambda w, f, a: hfig6(w, f), "pulse": lambda w, f, a: hpulse(w, f, a.pulse_seeds),
           "slew": lambda w, f, a: hslew(w, f, a.slew_seeds), "tracking": lambda w, f, a: htracking(w, f)}


def _drop_work_folder(rows: list[Headline], tmp: str) -> None:
    """Write the run's temporary folder as ``$WORK`` in every headline's commands, so the generated page
    and json do not change from run to run by a random folder name."""
    for h in rows:
        h.commands = [c.replace(tmp, "$WORK") for c in h.commands]
        h.values = json.loads(json.dumps(h.values, default=str).replace(tmp, "$WORK"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}")
    ap.add_argument("--only", default=None, help=f"comma-separated subset of {', '.join(ALL)}")
    ap.add_argument("--pulse-seeds", type=int, default=3)
    ap.add_argument("--slew-seeds", type=int, default=20)
    ap.add_argument("--out", type=Path, default=ROOT / "docs", help="folder of paper-reproduction.md (figures/ inside it)")
    a = ap.parse_args(argv)
    names = a.only.split(",") if a.only else (QUICK if a.quick else ALL)
    unknown = [n for n in names if n not in RUNNERS]
    if unknown:
        ap.error(f"unknown headline(s) {unknown}; choose from {', '.join(ALL)}")
    t0 = time.perf_counter()
    rows: list[Headline] = []
    with tempfile.TemporaryDirectory(prefix="cdgps-paper-") as tmp:
        for n in names:
            t, cpu = time.perf_counter(), _cpu_s()
            got = RUNNERS[n](Path(tmp), a.out / "figures", a)
            wall_s, cpu_s = time.perf_counter() - t, _cpu_s() - cpu
            for h in got:
                h.key = n
                h.values.setdefault("runner_time_s", {"wall": round(wall_s, 1), "cpu": round(cpu_s, 1), "jobs": JOBS})
            rows += got
            print(f"{n}: {wall_s:.0f} s ({cpu_s:.0f} CPU s): " + "; ".join(f"{h.ours} [{h.met}]" for h in got), flush=True)
    runtime = time.perf_counter() - t0
    bench = a.out / "benchmarks" / "paper.json"
    if a.only and bench.exists():            # keep the other headlines of the last full run, in ALL's order
        earlier = [Headline(**h) for h in json.loads(bench.read_text())["headlines"] if h.get("key") not in names]
        rows = sorted(earlier + rows, key=lambda h: ALL.index(h.key) if h.key in ALL else len(ALL))
        runtime = None
    a.out.mkdir(parents=True, exist_ok=True)
    _drop_work_folder(rows, tmp)
    (a.out / "paper-reproduction.md").write_text(_md(rows, runtime, a.quick) + "\n")
    bench.parent.mkdir(parents=True, exist_ok=True)
    bench.write_text(json.dumps({"benchmark": "benchmarks/paper.py", "headlines": [asdict(h) for h in rows],
                                 "runtime_s": runtime, "machine": platform.platform(),
                                 "date": datetime.date.today().isoformat()}, indent=1, default=str) + "\n")
    print(f"wrote {a.out / 'paper-reproduction.md'} ({len(rows)} headlines" + (f", {runtime:.0f} s)" if runtime is not None else ")"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
