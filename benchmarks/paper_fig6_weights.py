"""What weights the paper's Fig. 6 implies on our testbed model (issue 31 item 2).

Fig. 6 (Teague, How & Parkinson 1998, Sec. V): with Q_x* = 5000 diag(1, …, 1, 0.01),
Q_x = diag(Q_x*, 0.01 Q_x*), Q_u = I, the rigid-body pole settles in ≈ 30 s and the vibration
poles in ≈ 5 s.  On our model (mass-normalized shapes, u in N, our Υ) those weights give a rigid
pole of ≈ 21 s and vibration poles of ≈ 1.1 s.  Keeping the paper's form W·diag(1, …, 1, f_rigid)
with the rate factor f_rate = 0.01 and Q_u = I, this finds by bisection

1. the state weight W at which the median settling of the moved vibration modes is 5 s;
2. at that W, the rigid factor f_rigid at which the rigid-body pole settles in 30 s;

and reports both designs, the factor W_paper / W (the scale between the paper's units of ξ and u
and ours: Q_x/Q_u scales as (input unit / state unit)²), and the largest gain entry.  Linear
algebra only (a few seconds):

    python benchmarks/paper_fig6_weights.py [CONFIG]     # default configs/testbed-1998.toml

Writes docs/benchmarks/paper-fig6-weights.json.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.control.design import design_for_structure  # noqa: E402
from cdgps_cli.control.lqr import PAPER_RATE_FACTOR, PAPER_RIGID_FACTOR, PAPER_STATE_WEIGHT  # noqa: E402

RIGID_TARGET_S, VIBRATION_TARGET_S = 30.0, 5.0
#: modes whose closed-loop settling exceeds this are not "moved" (e.g. the swing, uncontrollable)
MOVED_MAX_S = 100.0


def settling(cfg, qx: float, rigid_factor: float) -> tuple[float, float, dict, float]:
    """(rigid-body settling s, median moved vibration settling s, per mode, max |K|) of the design."""
    d, poles = design_for_structure(cfg, qx=qx, rigid_factor=rigid_factor, rate_factor=PAPER_RATE_FACTOR)
    s = poles["settling_time_s"]["closed_loop"]
    vib = sorted(v for k, v in s.items() if k != "rigid-body" and v is not None and v < MOVED_MAX_S)
    return float(s["rigid-body"]), float(np.median(vib)), s, float(np.abs(d.K).max())


def bisect_log(f, lo: float, hi: float, target: float, increasing: bool, n: int = 40) -> float:
    """x in [lo, hi] (log scale) with f(x) = target, f monotone."""
    for _ in range(n):
        mid = math.sqrt(lo * hi)
        if (f(mid) > target) == increasing:
            hi = mid
        else:
            lo = mid
    return math.sqrt(lo * hi)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    path = Path(argv[0]) if argv else ROOT / "configs" / "testbed-1998.toml"
    cfg = load_config(path)
    rows = {}
    r, v, s, k = settling(cfg, PAPER_STATE_WEIGHT, PAPER_RIGID_FACTOR)
    rows["paper"] = {"qx": PAPER_STATE_WEIGHT, "rigid_factor": PAPER_RIGID_FACTOR, "rigid_s": r, "vibration_median_s": v,
                     "settling_s": s, "max_abs_gain": k}
    w = bisect_log(lambda q: settling(cfg, q, PAPER_RIGID_FACTOR)[1], 1e-2, PAPER_STATE_WEIGHT, VIBRATION_TARGET_S, False)
    r, v, s, k = settling(cfg, w, PAPER_RIGID_FACTOR)
    rows["vibration 5 s"] = {"qx": w, "rigid_factor": PAPER_RIGID_FACTOR, "rigid_s": r, "vibration_median_s": v,
                             "settling_s": s, "max_abs_gain": k}
    f = bisect_log(lambda x: settling(cfg, w, x)[0], 1e-6, 1e3, RIGID_TARGET_S, False)
    r, v, s, k = settling(cfg, w, f)
    rows["vibration 5 s, rigid 30 s"] = {"qx": w, "rigid_factor": f, "rigid_s": r, "vibration_median_s": v,
                                         "settling_s": s, "max_abs_gain": k}
    print("| weights | W | f_rigid | rigid-body settling (s) | median vibration settling (s) | max abs K |")
    print("|---|---|---|---|---|---|")
    for name, row in rows.items():
        print(f"| {name} | {row['qx']:.4g} | {row['rigid_factor']:.3g} | {row['rigid_s']:.1f} | "
              f"{row['vibration_median_s']:.2f} | {row['max_abs_gain']:.3g} |")
    print(f"W_paper / W = {PAPER_STATE_WEIGHT / w:.0f}: unit scale sqrt = {math.sqrt(PAPER_STATE_WEIGHT / w):.1f}")
    out = ROOT / "docs" / "benchmarks" / "paper-fig6-weights.json"
    out.write_text(json.dumps({"benchmark": "paper_fig6_weights", "config": str(path.relative_to(ROOT)) if
                               path.is_relative_to(ROOT) else str(path), "rows": rows,
                               "paper_over_fitted_weight": PAPER_STATE_WEIGHT / w}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
