"""What limits the closed-loop pulse rejection of Fig. 10 with the GPS estimate in the loop (issue 31).

The pulse experiment of ``benchmarks/paper.py`` (configs/testbed-1998.toml, 20 s, disturbance scale
0.05, the Fig. 9 pulse at 5 s) is rerun in-process with one ingredient of the loop swapped at a time:

* ``gps``           the experiment as ``cdgps simulate --controller`` runs it (EKF estimate fed back);
* ``truth``         the true state fed back (no estimator);
* ``gps-noisefree`` the EKF fed noise-free carrier phases (its lag alone, no measurement noise);
* ``gps-known``     the EKF predicts with the pulse's firings too (Eq. 18: x̄ = A x + B u, u every firing
                    the computer commanded) instead of meeting the pulse as an unknown disturbance;
* ``gps-known-noisefree`` both;
* ``gps-ideal`` / ``truth-ideal``  an ideal continuous force (request clipped to 1.4 N, held over the
                    period) instead of the PWPF on/off jets;
* ``gps-W1`` / ``gps-W10x``  the filter's process noise at the paper's W (scale 1) / 10× the
                    separation rule's scale (lag against noise); ``gps-known-W1`` the pulse known and
                    the paper's W.

Figures: the closed/open peak ratio of q5, q8 (largest over both and the seeds), when both are back
within 10 % of the open-loop first peak for good (s after the pulse end; inf: not within the run), and
the jets' saturated fraction, the same definitions as ``cdgps report control``
(:func:`cdgps_cli.control.metrics.pulse_metrics`).

    PYTHONPATH=. python benchmarks/paper_pulse_decomposition.py [--seeds 3] [--weights tuned,paper,fig6]

writes docs/benchmarks/paper_pulse_decomposition.json.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.control.metrics import pulse_metrics  # noqa: E402
from cdgps_cli.io.gains_file import read_gains  # noqa: E402
from cdgps_cli.pipeline.closed_loop import closed_loop_trajectory  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402

TESTBED = ROOT / "configs" / "testbed-1998.toml"
CDGPS = str(Path(sys.executable).parent / "cdgps")
#: the Fig. 6-implied state weight of benchmarks/paper_fig6_weights.py (docs/paper-reproduction.md)
FIG6_QX = 33.7
WEIGHTS = {"tuned": ("--weights", "tuned"), "paper": ("--weights", "paper"),
           "fig6": ("--weights", "paper", "--qx", f"{FIG6_QX:g}")}
#: variant -> (feedback, noise-free measurements, pulse known to the EKF, actuator, process-noise factor)
VARIANTS = {
    "gps": ("gps", False, False, "pwpf", None),
    "truth": ("truth", False, False, "pwpf", None),
    "gps-noisefree": ("gps", True, False, "pwpf", None),
    "gps-known": ("gps", False, True, "pwpf", None),
    "gps-known-noisefree": ("gps", True, True, "pwpf", None),
    "gps-ideal": ("gps", False, False, "ideal", None),
    "truth-ideal": ("truth", False, False, "ideal", None),
    "gps-W1": ("gps", False, False, "pwpf", "W1"),
    "gps-W10x": ("gps", False, False, "pwpf", 10.0),
    "gps-known-W1": ("gps", False, True, "pwpf", "W1"),
}
ANGLES = ("q5", "q8")


def _options(seed: int) -> SimOptions:
    return SimOptions(duration_s=20.0, seed=seed, scenario="pulse", disturbance_scale=0.05)


def _deg(cfg, sim) -> dict:
    return {a: np.degrees(sim.q[:, list(cfg.coord_names).index(a)]) for a in ANGLES}


def run_variant(cfg, gains, seed: int, open_deg: dict, variant: str, rule_scale: float) -> dict:
    feedback, noisefree, known, actuator, factor = VARIANTS[variant]
    scale = None if factor is None else (1.0 if factor == "W1" else factor * rule_scale)
    record: dict = {}
    hook = closed_loop_trajectory(cfg, "pulse", gains, feedback=feedback, record=record, estimator_noise_scale=scale,
                                  actuator=actuator, pulse_known=known)
    if noisefree:
        inner = hook
        hook = lambda t, x0, w, noise: inner(t, x0, w, np.zeros_like(noise))  # noqa: E731
    sim = simulate(cfg, _options(seed), trajectory=hook)
    s = cfg.simulation
    m = pulse_metrics(sim.time_s, open_deg, _deg(cfg, sim), s["pulse_time_s"], s["pulse_time_s"] + s["pulse_duration_s"])
    r = record["result"]
    return {"ratio": max(m[a]["peak_ratio"] for a in ANGLES),
            "back_s": max(math.inf if m[a]["closed_back_within_s_after_pulse"] is None
                          else m[a]["closed_back_within_s_after_pulse"] for a in ANGLES),
            "saturated": r.saturated_fraction, "estimator_scale": r.estimator["scale"]}


def decompose(seeds: int, weights=tuple(WEIGHTS), variants=tuple(VARIANTS), log=print) -> dict:
    """Every variant on every weight set over seeds 1..seeds: per weight set and variant the worst ratio,
    back time and saturated fraction over the seeds, and the per-seed figures."""
    cfg = load_config(TESTBED)
    t0 = time.perf_counter()
    opened = {s: _deg(cfg, simulate(cfg, _options(s))) for s in range(1, seeds + 1)}
    out = {"config": "configs/testbed-1998.toml", "seeds": seeds, "duration_s": 20.0, "disturbance_scale": 0.05,
           "fig6_qx": FIG6_QX, "load_average_1min": os.getloadavg()[0], "results": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for wname in weights:
            g = Path(tmp) / f"gains-{wname}.json"
            subprocess.run([CDGPS, "control", "design", str(TESTBED), *WEIGHTS[wname], "-o", str(g)], check=True,
                           capture_output=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
            gains = read_gains(g, TESTBED)
            rule = None
            for v in variants:
                runs = []
                for s in range(1, seeds + 1):
                    runs.append(run_variant(cfg, gains, s, opened[s], v, rule or 1.0))
                    if v == "gps":
                        rule = runs[-1]["estimator_scale"]
                row = {"ratio": max(r["ratio"] for r in runs), "back_s": max(r["back_s"] for r in runs),
                       "saturated": max(r["saturated"] for r in runs), "estimator_scale": runs[0]["estimator_scale"],
                       "per_seed": runs}
                out["results"].setdefault(wname, {})[v] = row
                log(f"{wname:6s} {v:20s} ratio {row['ratio']:.3f}  back {row['back_s']:.2f} s  "
                    f"saturated {100 * row['saturated']:.1f} %  W scale {row['estimator_scale']:.3g}")
    out["wall_s"] = time.perf_counter() - t0
    return _finite(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--weights", default=",".join(WEIGHTS))
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("-o", "--output", default=str(ROOT / "docs" / "benchmarks" / "paper_pulse_decomposition.json"))
    a = ap.parse_args()
    out = decompose(a.seeds, a.weights.split(","), a.variants.split(","), log=lambda m: print(m, flush=True))
    Path(a.output).write_text(json.dumps(out, indent=1) + "\n")


def _finite(v):
    """inf / nan -> None (strict JSON; a back time of None: not back within the run)."""
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_finite(x) for x in v]
    return None if isinstance(v, float) and not math.isfinite(v) else v


if __name__ == "__main__":
    main()
