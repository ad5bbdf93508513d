"""Which reading of the paper's weights puts our poles where Fig. 6 has them (issue 15, docs/control.md).

The paper's Q_x* = 5000 diag(1, …, 1, 0.01), Q_x = diag(Q_x*, 0.01 Q_x*), Q_u = I weigh a state and an
input whose units the paper does not state.  The linear design (no modulator, no estimator) is
computed on the testbed config under each reading, and its closed-loop 2 % settling per mode is
compared with Fig. 6 (rigid-body about 30 s, vibration about 5 s):

* ``as implemented``: ξ of our mass-normalized mode shapes (UᵀMU = I), u in N, discrete at 10 Hz;
* ``Q_u on u / F_max``: the input weight on the command as a fraction of the jet's 1.4 N;
* ``ξ in q units``: ξ of unit-norm mode shapes (the paper's Λ = UᵀΦU with UᵀU = I), i.e. our Q_x
  scaled by ‖U_i‖² per mode;
* both of the last two;
* ``continuous LQR``: the same Q_x, Q_u on the continuous model (Eq. 6), its gain applied at 10 Hz
  (does the discrete period matter?);
* ``20 Hz``: the discrete design at twice the rate.

Also the largest gain entry.  Linear algebra only; seconds.

    python benchmarks/control_weight_scaling.py [CONFIG]     # default: configs/testbed-1998-lumped.toml (docs/control.md)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.linalg import solve_continuous_are

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.control.design import weights_for  # noqa: E402
from cdgps_cli.control.lqr import design_lqr  # noqa: E402
from cdgps_cli.control.poles import pole_table, slowest_settling_by_mode  # noqa: E402
from cdgps_cli.model.dynamics import continuous_model, discrete_model  # noqa: E402

CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"


def settling(cfg, M, T):
    s = slowest_settling_by_mode(pole_table(M, T, list(cfg.mode_names)))
    rigid = cfg.mode_names[list(cfg.mode_frequency_hz).index(0.0)]
    moved = [v for k, v in s.items() if k != rigid and v is not None and v < 200]
    return s[rigid], min(moved), max(moved)


def main() -> None:
    cfg = load_config(Path(sys.argv[1]) if len(sys.argv) > 1 else CONFIG)
    Qx, Qu = weights_for(cfg, weights="paper")
    norms = np.linalg.norm(np.asarray(cfg.mode_shapes), axis=0)
    S = np.diag(np.concatenate([norms, norms]))
    fmax = float(np.max(cfg.thruster_max_force_n))
    model = discrete_model(cfg)
    readings = {"as implemented (ξ mass-normalized, u in N)": (Qx, Qu),
                "Q_u on u / F_max": (Qx, Qu / fmax**2),
                "ξ in q units (‖U_i‖ = 1)": (S @ Qx @ S, Qu),
                "ξ in q units and Q_u on u / F_max": (S @ Qx @ S, Qu / fmax**2)}
    print("| reading of the paper's weights | rigid-body settling (s) | vibration settling, moved modes (s) "
          "| max abs K (N per unit) |\n|---|---|---|---|")
    for name, (Q, R) in readings.items():
        d = design_lqr(model.A, model.B, Q, R, model.T)
        r, lo, hi = settling(cfg, d.closed_loop, model.T)
        print(f"| {name} | {r:.1f} | {lo:.2f}–{hi:.2f} | {np.abs(d.K).max():.3g} |")
    Ac, Bc, _ = continuous_model(cfg)
    # continuous weights equivalent to the discrete sum (Eq. 24): Q/T and R/T per second (same ratio)
    P = solve_continuous_are(Ac, Bc, Qx / model.T, Qu / model.T)
    Kc = np.linalg.solve(Qu / model.T, Bc.T @ P)
    r, lo, hi = settling(cfg, model.A - model.B @ Kc, model.T)
    print(f"| continuous LQR, gain applied at 10 Hz | {r:.1f} | {lo:.2f}–{hi:.2f} | {np.abs(Kc).max():.3g} |")
    m20 = discrete_model(cfg, model.T / 2)
    d = design_lqr(m20.A, m20.B, Qx, Qu, m20.T)
    r, lo, hi = settling(cfg, d.closed_loop, m20.T)
    print(f"| discrete at 20 Hz | {r:.1f} | {lo:.2f}–{hi:.2f} | {np.abs(d.K).max():.3g} |")
    print(f"\nmode-shape norms ‖U_i‖: {', '.join(f'{n}: {v:.4g}' for n, v in zip(cfg.mode_names, norms))}")


if __name__ == "__main__":
    main()
