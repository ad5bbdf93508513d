"""Where control degrades (issue 15 item 4): phase noise and multipath against the pulse and slew
figures of merit, seeds 1-3, the paper's weights (the design default) or the tuned ones
(docs/control.md "Where control degrades").

Multipath is the simulator's first-order Gauss-Markov error per antenna (30 s), modelled in the
loop's filter at the simulated sigma (the estimation pipeline's `[model] multipath_sigma_m`); the
filter keeps weighting with the config's 2 cm.  Writes docs/benchmarks/control-sweep-<weights>.json and prints a
markdown table.

    python benchmarks/control_sweep.py [--weights paper|tuned]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import control_experiments as ce  # noqa: E402
from cdgps_cli.config.structure import load_config  # noqa: E402

SEEDS = (1, 2, 3)
PHASE_M = (0.002, 0.01, 0.02)
MULTIPATH_M = (0.0, 0.005, 0.0075, 0.01, 0.015)
#: (phase σ, multipath σ) cells: the grid, and 5 cm of phase noise alone (where the loop itself degrades)
CELLS = [(ph, mp) for ph in PHASE_M for mp in MULTIPATH_M] + [(0.05, 0.0)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--weights", choices=("paper", "tuned"), default="paper")
    args = ap.parse_args()
    weights = ce.PAPER_WEIGHTS if args.weights == "paper" else ce.TUNED
    cfg = load_config(ce.CONFIG)
    gains, _ = ce._gains(cfg, **weights)
    t0 = time.perf_counter()
    rows = []
    for ph, mp in CELLS:
        p = [ce.pulse_case(cfg, gains, s, phase_m=ph, multipath_m=mp, mp_model=mp > 0) for s in SEEDS]
        s = [ce.slew_case(cfg, gains, s, phase_m=ph, multipath_m=mp, mp_model=mp > 0) for s in SEEDS]
        rows.append({"phase_sigma_m": ph, "multipath_sigma_m": mp, "multipath_modelled": mp > 0, "seeds": list(SEEDS),
                     "pulse_ratio": [r["ratio_max"] for r in p],
                     "slew_internal_max_deg": [r["internal_max_all_deg"] for r in s],
                     "slew_final_error_deg": [abs(r["final_error_deg"]) for r in s],
                     "slew_final_pp_deg": [r["final_peak_to_peak_deg"] for r in s],
                     "slew_arrived_s": [np.inf if r["arrived_s_after_command"] is None else r["arrived_s_after_command"]
                                        for r in s],
                     "saturated_fraction": [r["saturated_fraction"] for r in s]})
        print(f"{ph} {mp}: {rows[-1]}", flush=True)
    (ROOT / "docs" / "benchmarks" / f"control-sweep-{args.weights}.json").write_text(json.dumps(
        {"weights": weights, "disturbance_scale": ce.DISTURBANCE, "rows": rows,
         "wall_s": time.perf_counter() - t0}, indent=1) + "\n")
    print("\n| phase σ (cm) | multipath σ (cm), modelled | slew: largest q2/q5/q8 after the command (°), mean [max] "
          "| q2/q5/q8 within 1° | slew: final-angle error (°), mean [max] | final peak to peak, last 10 s (°) "
          "| within 0.5° (s), max | pulse ratio, mean [max] |\n|---|---|---|---|---|---|---|---|")
    for r in rows:
        im, fe, pr = (np.array(r[k]) for k in ("slew_internal_max_deg", "slew_final_error_deg", "pulse_ratio"))
        ok = int(np.sum(im <= 1.0))
        print(f"| {100 * r['phase_sigma_m']:g} | {100 * r['multipath_sigma_m']:g} | {im.mean():.2f} [{im.max():.2f}] "
              f"| {ok}/{len(im)} | {fe.mean():.3f} [{fe.max():.3f}] | {np.mean(r['slew_final_pp_deg']):.3f} "
              f"| {max(r['slew_arrived_s']):.1f} | {pr.mean():.3f} [{pr.max():.3f}] |")


if __name__ == "__main__":
    main()
