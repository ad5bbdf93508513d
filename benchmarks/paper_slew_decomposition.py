"""Why the slew swings the sections about the vertical (q3/q6/q9): one ingredient changed at a time (issue 31).

The slew of ``benchmarks/paper.py`` (configs/testbed-1998.toml, ``tuned`` weights, GPS estimate in the loop,
bang-bang profile with feed-forward) keeps q2/q5/q8 within 1° but swings q3/q6/q9 by 3.5-3.9°.  Candidates:

* ``truth``: the true state fed back instead of the EKF's estimate (is it the estimator?);
* ``bending-x10``, ``bending-x100``: the weights of the four bending modes, the only modes with q3/q6/q9
  in their shapes, raised 10× / 100× (amplitude and rate; is it the weights on those coordinates?);
* ``elastic-x10``: every elastic mode's weight raised 10× (W 100 → 1000);
* ``no-vibration-control``: the rigid-only regulator (is it the vibration loop?);
* ``shaped-step``, ``step``: the paper's step command (filtered / raw) instead of the profile.

The thruster-layout alternatives (Υ) are ``benchmarks/paper_thruster_layout.py``'s.  Per variant and seed:
arrival (s after the command), final error, the largest |q3/q6/q9| (deg), |q2/q5/q8| (deg), |q1/q4/q7| (mm)
and the jets' saturated fraction; and for Fig. 12a, over the tail from 30 s after the command to the end of the
60 s run, the largest |error| about the target and the number of target crossings of the rigid-body angle q10
and of the centre section's vertical angle q6 + q10 (what the centre antennas measure, Sec. VI.A).  About
7 CPU s per run, two at a time.

    python benchmarks/paper_slew_decomposition.py [--seeds 2]

Writes docs/benchmarks/paper-slew-decomposition.json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
CDGPS = str(Path(sys.executable).parent / "cdgps")
TESTBED = ROOT / "configs" / "testbed-1998.toml"
#: the modes whose shapes move q3/q6/q9 (configs/testbed-1998.toml)
BENDING = ("bending-1", "bending-2", "bending-3", "bending-4")
#: variant -> (weight change: None, ("bending", factor) or ("elastic", factor); extra simulate options)
VARIANTS = {
    "gps": (None, ()),
    "truth": (None, ("--feedback", "truth")),
    "bending-x10": (("bending", 10.0), ()),
    "bending-x100": (("bending", 100.0), ()),
    "elastic-x10": (("elastic", 10.0), ()),
    "no-vibration-control": (None, ("--no-vibration-control",)),
    "shaped-step": (None, ("--slew-reference", "shaped-step")),
    "step": (None, ("--slew-reference", "step")),
}


def _run(*args) -> str:
    p = subprocess.run([CDGPS, "-q", *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"cdgps {' '.join(map(str, args))} failed:\n{p.stderr[-2000:]}")
    return p.stdout


def _gains(w: Path, change) -> Path:
    """The tuned design, with the diagonal of Q_x scaled on the chosen modes."""
    base = w / "gains-tuned.json"
    if not base.exists():
        _run("control", "design", TESTBED, "--weights", "tuned", "-o", base)
    if change is None:
        return base
    kind, factor = change
    g = json.loads(base.read_text())
    names, diag = g["state_names"], [g["Qx"][i][i] for i in range(len(g["Qx"]))]
    pick = (lambda n: n.split(" ")[0] in BENDING) if kind == "bending" else (lambda n: not n.startswith("rigid"))
    diag = [d * factor if pick(n) else d for n, d in zip(names, diag)]
    out = w / f"gains-{kind}-x{factor:g}.json"
    _run("control", "design", TESTBED, "--weights", "tuned", "--qx", ",".join(f"{d:g}" for d in diag), "-o", out)
    return out


#: the slew target (deg) and command time (s): configs/testbed-1998.toml [simulation]
SLEW_TO_DEG, COMMAND_S, TAIL_AFTER_S, DURATION_S = -22.0, 5.0, 30.0, 60


def _tail(out: Path) -> dict:
    """Fig. 12a: the oscillation about the target from TAIL_AFTER_S after the command on (deg, crossings)."""
    q = pd.read_csv(out / "truth.csv")
    tail = q["time_s"].to_numpy() >= COMMAND_S + TAIL_AFTER_S
    res = {}
    for name, ang in (("rigid", q["q10_rad"]), ("centre", q["q6_rad"] + q["q10_rad"])):
        err = np.degrees(ang.to_numpy()[tail]) - SLEW_TO_DEG
        res[name] = {"max_abs_deg": round(float(np.abs(err).max()), 3),
                     "crossings": int(np.sum(np.diff(np.sign(err)) != 0))}
    return res


def _slew(w: Path, name: str, seed: int, gains: Path, extra) -> dict:
    out = w / f"slew-{name}-{seed}"
    _run("simulate", TESTBED, "--scenario", "slew", "--duration", DURATION_S, "--seed", seed, "--disturbance-scale", 0.05,
         "--controller", gains, *extra, "-o", out)
    rep = json.loads(_run("report", "control", gains, "--closed", out, "--date", "2026-01-01", "-o", f"{out}-rep",
                          "--json"))
    c, m = rep["coordinates"]["closed"], rep["metrics"]["closed"]
    big = lambda qs: round(max(c[q]["max_abs"] for q in qs), 3)  # noqa: E731
    return {"seed": seed, "arrived_s": m["arrived_s_after_command"], "final_error_deg": round(m["final_error_deg"], 3),
            "vertical_deg": big(("q3", "q6", "q9")), "twist_deg": big(("q2", "q5", "q8")),
            "lateral_mm": big(("q1", "q4", "q7")),
            "saturated": round(rep["controllers"]["closed"].get("saturated_fraction") or 0.0, 3), "tail": _tail(out)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "paper-slew-decomposition.json")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="cdgps-slewdec-") as tmp:
        w = Path(tmp)
        gains = {n: _gains(w, ch) for n, (ch, _) in VARIANTS.items()}
        jobs = [(n, s) for n in VARIANTS for s in range(1, a.seeds + 1)]
        with ThreadPoolExecutor(max_workers=2) as ex:
            runs = list(ex.map(lambda j: _slew(w, j[0], j[1], gains[j[0]], VARIANTS[j[0]][1]), jobs))
    res = {n: [r for (m, _), r in zip(jobs, runs) if m == n] for n in VARIANTS}
    for n, rs in res.items():
        print(n, json.dumps(rs), flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"benchmark": "paper_slew_decomposition", "seeds": a.seeds, "bending_modes": BENDING,
                                 "variants": res}, indent=1) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
