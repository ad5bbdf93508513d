"""What made the paper's LQR weights diverge on our thruster model, and what fixed it (issue 15,
docs/control.md "The paper's weights in the loop").

The same pulse (Fig. 9) under the paper's weights (W = 5000, 0.01, 0.01, the design default) and the
tuned ones, with the actuator made progressively more real: the linear law applied as signed forces
(no limit), the same with each jet clipped at 1.4 N, the whole command scaled down until no jet
exceeds 1.4 N, and the PWPF modulator without its input limit (the textbook filter, which winds up
under saturated requests) at T_m = 0.85 s and 0.3 s and with it at 0.85 s (the default); the true
state fed back, the GPS estimate with the loop's filter as chosen for the gain (the config's W for
the paper's weights, whose separation rule cannot be met) and, for the paper's weights, with the
rule's closest scale (1000).  Seeds 1-3.  Prints a markdown table.

    python benchmarks/control_paper_weights.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import control_experiments as ce  # noqa: E402
from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.control.allocation import opposing_pairs, realize_forces  # noqa: E402
from cdgps_cli.control.design import PAPER_WEIGHTS, design_for_structure  # noqa: E402
from cdgps_cli.control.metrics import pulse_metrics  # noqa: E402
from cdgps_cli.control.modulation import PwpfParams  # noqa: E402
from cdgps_cli.model.dynamics import discrete_model  # noqa: E402
from cdgps_cli.pipeline.closed_loop import simulate_closed_loop  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402

SEEDS = (1, 2, 3)


def ideal_actuator(cfg, K, kind, duration_s=30.0):
    """Largest |q2, q5, q8| (deg) in the first 10 s and last 5 s, fraction of periods saturated, with
    the regulator's forces applied held over each period (no modulator), true state fed back."""
    model = discrete_model(cfg)
    A, B, T = model.A, model.B, model.T
    pairs = opposing_pairs(cfg.thruster_section, cfg.thruster_position_m, cfg.thruster_direction)
    fmax = np.asarray(cfg.thruster_max_force_n, float)
    sim = cfg.simulation
    jets = [list(cfg.thruster_names).index(j) for j in sim["pulse_thrusters"]]
    U, nm = np.asarray(cfg.mode_shapes), cfg.n_modes
    idx = [list(cfg.coord_names).index(c) for c in ce.INTERNAL]
    x, q, sat, N = np.zeros(2 * nm), [], 0, int(round(duration_s / T))
    for k in range(N):
        q.append(np.degrees(U[idx] @ x[:nm]))
        f = realize_forces(-K @ x, pairs)
        if kind == "clip":
            sat += bool(np.any(f > fmax))
            f = np.minimum(f, fmax)
        elif kind == "scale":
            r = float(np.max(f / fmax))
            sat += r > 1
            f = f / max(r, 1.0)
        if sim["pulse_time_s"] <= k * T < sim["pulse_time_s"] + sim["pulse_duration_s"]:
            f[jets] = sim["pulse_force_n"]
        for i, j in pairs:                    # the pair's signed force on its first jet (same Υu)
            f[i], f[j] = f[i] - f[j], 0.0
        x = A @ x + B @ f
    q = np.abs(np.array(q))
    return q[:100].max(), q[-50:].max(), sat / N


def modulated(cfg, gains, pwpf, feedback, noise_scale=None):
    rows = []
    for seed in SEEDS:
        opt = SimOptions(duration_s=30.0, scenario="pulse", seed=seed, disturbance_scale=ce.DISTURBANCE)
        o = simulate(cfg, opt)
        c, r = simulate_closed_loop(cfg, opt, gains, feedback=feedback, pwpf=pwpf, estimator_noise_scale=noise_scale)
        seg = next(s for s in c.truth["segments"] if s["kind"] == "pulse")
        m = pulse_metrics(o.time_s, {k: ce._deg(o, k) for k in ce.INTERNAL}, {k: ce._deg(c, k) for k in ce.INTERNAL},
                          seg["start_s"], seg["end_s"])
        rows.append((max(m[k]["peak_ratio"] for k in ("q5", "q8")),
                     max(np.abs(ce._deg(c, k)[-50:]).max() for k in ce.INTERNAL), r.saturated_fraction))
    return np.array(rows)


def main():
    cfg = load_config(ce.CONFIG)
    print("| weights | actuator | feedback | peak ratio (3 seeds) | largest internal angle, last 5 of 30 s (°) "
          "| saturated |\n|---|---|---|---|---|---|")
    for name, w in (("paper", PAPER_WEIGHTS), ("tuned", ce.TUNED)):
        d, p = design_for_structure(cfg, **w)
        gains = {"A": d.A, "B": d.B, "K": d.K, "poles": p, "config": {"sha256": cfg.sha256}}
        print(f"| {name} | linear closed loop max |z| = {np.abs(np.linalg.eigvals(d.closed_loop)).max():.4f}, "
              f"max |K| {np.abs(d.K).max():.1f} N per unit | | | | |")
        for kind in ("linear", "clip", "scale"):
            first, late, sat = ideal_actuator(cfg, d.K, kind)
            print(f"| {name} | forces {kind} (no modulator) | truth | peak {first:.2f}° | {late:.3f} | {sat:.3f} of periods |")
        cases = [(f"PWPF T_m = {tm} s, no input limit", PwpfParams(time_constant_s=tm, anti_windup=False), fb, None)
                 for tm in (0.85, 0.3) for fb in ("truth", "gps")]
        cases += [("PWPF T_m = 0.85 s, input limit (default)", PwpfParams(), fb, None) for fb in ("truth", "gps")]
        if name == "paper":
            cases.append(("PWPF T_m = 0.85 s, input limit, filter at the rule's closest scale 1000", PwpfParams(),
                          "gps", 1000.0))
        for label, pwpf, fb, ns in cases:
            r = modulated(cfg, gains, pwpf, fb, ns)
            print(f"| {name} | {label} | {fb} | {', '.join(f'{v:.3f}' for v in r[:, 0])} | "
                  f"{r[:, 1].max():.2f} | {r[:, 2].mean():.3f} of jet-periods |", flush=True)


if __name__ == "__main__":
    main()
