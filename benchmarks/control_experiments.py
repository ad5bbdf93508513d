"""The 1998 paper's control experiments on the testbed model, measured (issue 15 items 4-5).

Runs, with the paper's weights (the design default), the tuned weights and a Fig. 6 pole placement:
  * pulse rejection (Fig. 9-10): open loop vs closed loop on the GPS estimate vs full-state feedback;
  * slew +14 -> -22 deg (Figs. 11-12): with and without vibration control, profile and step command;
  * the wall time of a 60 s closed-loop `cdgps simulate` with the default design (target < 10 s).
The noise and multipath sweep is benchmarks/control_sweep.py.
Writes docs/benchmarks/control-experiments.json and the figures docs/figures/control-{pulse,slew}.png, and
prints markdown tables for docs/control.md.

    python benchmarks/control_experiments.py [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.options import CONTROL_TUNED_WEIGHTS  # noqa: E402
from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.pipeline.closed_loop import simulate_closed_loop  # noqa: E402
from cdgps_cli.control.design import PAPER_WEIGHTS, design_for_structure  # noqa: E402
from cdgps_cli.control.metrics import pulse_metrics, slew_metrics  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402

CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"
#: our weights for our thruster model (`control design --weights tuned`; the paper's Υ is unpublished; see
#: docs/control.md)
TUNED = dict(CONTROL_TUNED_WEIGHTS)
#: the paper's weight form scaled to place our poles where Fig. 6 has them (rigid-body about 30 s,
#: vibration about 5 s: 29.6 s and 3.3-4.9 s), for comparison
PAPER_POLES = {"qx": 10.0, "rigid_factor": 0.04, "rate_factor": 0.1}
#: the in-loop filter with the config's W (scale 1), i.e. without the separation rule
CONFIG_W = 1.0
#: the process-noise scale closest to the separation rule for the paper's weights (the rule cannot be
#: met; the loop keeps the config's W, this row shows why)
CLOSEST = 1000.0
#: the 1998 testbed's multipath, 1.5 cm (1 sigma) per antenna (Sec. I), 30 s correlation
PAPER_MP = 0.015
#: true disturbance during the control experiments, as a fraction of the filter's fictitious process
#: noise (the paper: "there is really no significant process noise for the experimental system")
DISTURBANCE = 0.05
INTERNAL = ("q2", "q5", "q8")


def _gains(cfg, **w):
    d, p = design_for_structure(cfg, **w)
    return {"A": d.A, "B": d.B, "K": d.K, "poles": p, "config": {"sha256": cfg.sha256}}, p


def _deg(sim, name):
    return np.degrees(sim.q[:, list(sim.cfg.coord_names).index(name)])


def _with_multipath_model(cfg, multipath_m, model):
    """The config with its filter's [model] multipath set to the simulated one (model=True)."""
    return dataclasses.replace(cfg, multipath_sigma_m=float(multipath_m or 0.0)) if model else cfg


def pulse_case(cfg, gains, seed, phase_m=None, multipath_m=None, feedback="gps", noise_scale=None, mp_model=False):
    cfg = _with_multipath_model(cfg, multipath_m, mp_model)
    opt = SimOptions(duration_s=30.0, scenario="pulse", seed=seed, disturbance_scale=DISTURBANCE,
                     phase_sigma_m=phase_m, multipath_sigma_m=multipath_m)
    o = simulate(cfg, opt)
    c, r = simulate_closed_loop(cfg, opt, gains, feedback=feedback, estimator_noise_scale=noise_scale)
    seg = next(s for s in c.truth["segments"] if s["kind"] == "pulse")
    m = pulse_metrics(o.time_s, {k: _deg(o, k) for k in INTERNAL}, {k: _deg(c, k) for k in INTERNAL},
                      seg["start_s"], seg["end_s"])
    return {"ratio_max": max(m[k]["peak_ratio"] for k in ("q5", "q8")),
            "back_s_max": max(np.inf if m[k]["closed_back_within_s_after_pulse"] is None
                              else m[k]["closed_back_within_s_after_pulse"] for k in ("q5", "q8")),
            "saturated_fraction": r.saturated_fraction, "metrics": m,
            "estimator_scale": c.truth["controller"]["estimator_process_noise_scale"]}


def slew_case(cfg, gains, seed, vibration=True, reference="profile", phase_m=None, multipath_m=None, feedback="gps",
              noise_scale=None, mp_model=False):
    cfg = _with_multipath_model(cfg, multipath_m, mp_model)
    opt = SimOptions(duration_s=60.0, scenario="slew", seed=seed, disturbance_scale=DISTURBANCE,
                     phase_sigma_m=phase_m, multipath_sigma_m=multipath_m)
    c, r = simulate_closed_loop(cfg, opt, gains, vibration_control=vibration, feedback=feedback,
                                slew_reference_kind=reference, estimator_noise_scale=noise_scale)
    sim = cfg.simulation
    m = slew_metrics(c.time_s, _deg(c, "q10"), {k: _deg(c, k) for k in INTERNAL}, sim["slew_to_deg"], sim["slew_time_s"])
    m["internal_max_all_deg"] = max(m["internal_max_deg"].values())
    # the paper's Fig. 11 figures are "as measured by GPS": the same metrics on the estimate
    ctrl = c.tables["controller.csv"]
    e = slew_metrics(c.time_s, np.degrees(ctrl["q10_hat"].to_numpy()),
                     {k: np.degrees(ctrl[f"{k}_hat"].to_numpy()) for k in INTERNAL}, sim["slew_to_deg"], sim["slew_time_s"])
    m["estimated_arrived_s_after_command"] = e["arrived_s_after_command"]
    m["estimated_internal_max_all_deg"] = max(e["internal_max_deg"].values())
    m["saturated_fraction"] = r.saturated_fraction
    m["estimator_scale"] = c.truth["controller"]["estimator_process_noise_scale"]
    return m


def _fmt(v, spec=".2f"):
    return "never" if v is None or not np.isfinite(v) else format(v, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 seeds")
    args = ap.parse_args()
    seeds = range(1, 4) if args.quick else range(1, 11)
    cfg = load_config(CONFIG)
    tuned, tuned_poles = _gains(cfg, **TUNED)
    paper, paper_poles = _gains(cfg, **PAPER_WEIGHTS)
    ppoles, ppoles_poles = _gains(cfg, **PAPER_POLES)
    out = {"weights": {"paper": PAPER_WEIGHTS, "tuned": TUNED}, "paper_pole_weights": PAPER_POLES,
           "disturbance_scale": DISTURBANCE, "seeds": list(seeds),
           "settling_s": {"tuned": tuned_poles["settling_time_s"], "paper": paper_poles["settling_time_s"],
                          "paper_poles": ppoles_poles["settling_time_s"]}}

    rows = {}
    for label, g, fb, ns, *mpk in (("paper weights, GPS estimate (the config's W: rule not met)", paper, "gps", None),
                                   ("paper weights, true state", paper, "truth", None),
                                   ("paper weights, GPS estimate, the rule's closest scale", paper, "gps", CLOSEST),
                                   ("tuned, GPS estimate (separation rule)", tuned, "gps", None),
                                   ("tuned, GPS estimate, the config's W", tuned, "gps", CONFIG_W),
                                   ("tuned, true state", tuned, "truth", None),
                                   ("Fig. 6 poles, GPS estimate (separation rule)", ppoles, "gps", None),
                                   ("Fig. 6 poles, true state", ppoles, "truth", None),
                                   ("paper weights, 1.5 cm multipath, modelled in the filter", paper, "gps", None,
                                    PAPER_MP, True),
                                   ("tuned, 1.5 cm multipath, modelled in the filter", tuned, "gps", None, PAPER_MP, True),
                                   ("tuned, 1.5 cm multipath, not modelled", tuned, "gps", None, PAPER_MP, False)):
        mp, mm = mpk if mpk else (None, False)
        res = [pulse_case(cfg, g, s, feedback=fb, noise_scale=ns, multipath_m=mp, mp_model=mm) for s in seeds]
        rows[label] = {k: [r[k] for r in res] for k in ("ratio_max", "back_s_max", "saturated_fraction",
                                                        "estimator_scale")}
        print(f"pulse {label}: ratio {np.mean(rows[label]['ratio_max']):.3f}, back {np.median(rows[label]['back_s_max']):.1f} s",
              flush=True)
    out["pulse"] = rows

    srows = {}
    mp15 = {"multipath_m": PAPER_MP, "mp_model": True}
    for label, g, kw in (("paper weights, vibration control, profile", paper, {}),
                         ("paper weights, true state", paper, {"feedback": "truth"}),
                         ("paper weights, no vibration control, profile", paper, {"vibration": False}),
                         ("paper weights, shaped step (no feed-forward)", paper, {"reference": "shaped-step"}),
                         ("paper weights, raw step into the LQR", paper, {"reference": "step"}),
                         ("paper weights, 1.5 cm multipath, modelled", paper, mp15),
                         ("tuned, vibration control, profile", tuned, {}),
                         ("tuned, profile, the config's W", tuned, {"noise_scale": CONFIG_W}),
                         ("tuned, true state", tuned, {"feedback": "truth"}),
                         ("tuned, no vibration control, profile", tuned, {"vibration": False}),
                         ("tuned, shaped step (no feed-forward)", tuned, {"reference": "shaped-step"}),
                         ("tuned, no vibration control, shaped step", tuned, {"vibration": False, "reference": "shaped-step"}),
                         ("tuned, raw step into the LQR", tuned, {"reference": "step"}),
                         ("tuned, no vibration control, raw step", tuned, {"vibration": False, "reference": "step"}),
                         ("tuned, 1.5 cm multipath, modelled", tuned, mp15),
                         ("tuned, 1.5 cm multipath, not modelled", tuned, {"multipath_m": PAPER_MP}),
                         ("tuned, no vibration control, 1.5 cm multipath, modelled", tuned, {"vibration": False, **mp15}),
                         ("Fig. 6 poles, profile", ppoles, {})):
        res = [slew_case(cfg, g, s, **kw) for s in seeds]
        srows[label] = {k: [r[k] for r in res] for k in ("arrived_s_after_command", "final_error_deg",
                                                         "final_peak_to_peak_deg", "internal_max_all_deg",
                                                         "saturated_fraction", "estimator_scale",
                                                         "estimated_arrived_s_after_command",
                                                         "estimated_internal_max_all_deg")}
        print(f"slew {label}: arrived {srows[label]['arrived_s_after_command']}", flush=True)
    out["slew"] = srows

    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        cdgps = [sys.executable, "-m", "cdgps_cli.cli.commands", "-q"]
        tq = []                                   # the default design: the paper's weights
        subprocess.run([*cdgps, "control", "design", str(CONFIG), *tq, "-o", str(t / "g.json")], check=True)
        t0, r0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([*cdgps, "simulate", str(CONFIG), "--scenario", "slew", "--duration", "60", "--controller",
                        str(t / "g.json"), "--disturbance-scale", str(DISTURBANCE), "-o", str(t / "slew")], check=True)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        out["wall_s_60s_closed_loop_command"] = time.perf_counter() - t0
        out["cpu_s_60s_closed_loop_command"] = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        print(f"60 s closed-loop simulate: {out['wall_s_60s_closed_loop_command']:.2f} s wall, "
              f"{out['cpu_s_60s_closed_loop_command']:.2f} s CPU", flush=True)
        com = ["--disturbance-scale", str(DISTURBANCE), "--seed", "1"]
        subprocess.run([*cdgps, "simulate", str(CONFIG), "--scenario", "slew", "--duration", "60", "--controller",
                        str(t / "g.json"), "--no-vibration-control", *com, "-o", str(t / "slew-nov")], check=True)
        subprocess.run([*cdgps, "simulate", str(CONFIG), "--scenario", "slew", "--duration", "60", "--controller",
                        str(t / "g.json"), *com, "-o", str(t / "slew1")], check=True)
        subprocess.run([*cdgps, "report", "control", str(t / "g.json"), "--closed", str(t / "slew1"), "--no-vibration",
                        str(t / "slew-nov"), "-o", str(t / "rs"), "--date", "2026-12-02"], check=True)
        for kind in ("open", "closed"):
            extra = [] if kind == "open" else ["--controller", str(t / "g.json")]
            subprocess.run([*cdgps, "simulate", str(CONFIG), "--scenario", "pulse", "--duration", "30", *extra, *com,
                            "-o", str(t / f"p-{kind}")], check=True)
        subprocess.run([*cdgps, "simulate", str(CONFIG), "--scenario", "pulse", "--duration", "30", "--controller",
                        str(t / "g.json"), "--feedback", "truth", *com, "-o", str(t / "p-truth")], check=True)
        subprocess.run([*cdgps, "report", "control", str(t / "g.json"), "--open", str(t / "p-open"), "--closed",
                        str(t / "p-closed"), "--full-state", str(t / "p-truth"), "-o", str(t / "rp"), "--date", "2026-12-02"],
                       check=True)
        figs = ROOT / "docs" / "figures"
        shutil.copy(t / "rp" / "pulse.png", figs / "control-pulse.png")
        shutil.copy(t / "rs" / "slew.png", figs / "control-slew.png")
        shutil.copy(t / "rs" / "poles.png", figs / "control-poles-testbed.png")

    (ROOT / "docs" / "benchmarks" / "control-experiments.json").write_text(json.dumps(out, indent=2, default=float) + "\n")
    print("\n| pulse run | peak ratio (worst of q5, q8), mean [min–max] | seeds ≤ 1/3 | back within 10% of the open-loop peak after the pulse (s), median [max] | filter W scale |")
    print("|---|---|---|---|---|")
    for k, v in rows.items():
        r, b = np.array(v["ratio_max"]), np.array(v["back_s_max"])
        print(f"| {k} | {r.mean():.3f} [{r.min():.3f}–{r.max():.3f}] | {int(np.sum(r <= 1 / 3))}/{len(r)} | "
              f"{_fmt(np.median(b), '.1f')} [{_fmt(b.max(), '.1f')}] | {v['estimator_scale'][0]:.3g} |")
    print("\n| slew run | within 0.5° (s after command), median [max] | by 30 s | largest internal angle (°), mean [max] | within 1° | final p-p (°) | as estimated: within 0.5° (s), median; internal max (°), mean [max] |")
    print("|---|---|---|---|---|---|---|")
    for k, v in srows.items():
        a = np.array([np.inf if x is None else x for x in v["arrived_s_after_command"]])
        i = np.array(v["internal_max_all_deg"])
        ae = np.array([np.inf if x is None else x for x in v["estimated_arrived_s_after_command"]])
        ie = np.array(v["estimated_internal_max_all_deg"])
        print(f"| {k} | {_fmt(np.median(a), '.1f')} [{_fmt(a.max(), '.1f')}] | {int(np.sum(a <= 30.0))}/{len(a)} | "
              f"{i.mean():.2f} [{i.max():.2f}] | {int(np.sum(i <= 1.0))}/{len(i)} | "
              f"{np.mean(v['final_peak_to_peak_deg']):.3f} | {_fmt(np.median(ae), '.1f')}; {ie.mean():.2f} [{ie.max():.2f}] |")


if __name__ == "__main__":
    main()
