"""The slew's rotations about the vertical (q3/q6/q9) against the thruster layout (issue 31 item 3).

The paper says only that "a cluster of four actuators is located on the end of each of the six rigid
booms" and that the layout "was chosen to provide control of all important modes"; Fig. 9's pulse
names ±z jets (a3+z, a4−z, …), so each cluster has a +z and a −z jet and two horizontal ones.  The
config's reading is ±x (a torque about the vertical on each section, 1 N·m per N).  The rigid
rotation puts 95 % of its inertia in the end sections' translation (60 kg at 4 m), which ±x jets
reach only through the tubes; ±y jets on the end sections push that mass directly (4 N·m per N
about the centre).  Layouts compared, every other line of configs/testbed-1998.toml unchanged:

* ``x``   (the config): ±x, ±z at all six arm tips;
* ``end-y``: ±y instead of ±x on the end sections' arms (C1, C3), ±x on the centre section;
* ``all-y``: ±y instead of ±x on all arms.

Each slew uses the same rigid-body acceleration as the config's profile (the profile's authority
fraction scaled by the ratio of rigid authorities), the ``tuned`` weights designed on that layout,
the estimator in the loop, seeds 1..N.  Per layout: arrival, the largest |q3/q6/q9|, |q2/q5/q8|,
|q1/q4/q7| and the jets' saturated fraction.  About 20 s per run.

    python benchmarks/paper_thruster_layout.py [--seeds 2]
    python benchmarks/paper_thruster_layout.py --qx 33.7     # the paper's weight form at the scale Fig. 6 implies

Writes docs/benchmarks/paper-thruster-layout.json (with --qx: paper-thruster-layout-qx<W>.json).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.control.slew import SLEW_AUTHORITY_FRACTION, rigid_authority  # noqa: E402

CONFIG = ROOT / "configs" / "testbed-1998.toml"
CDGPS = str(Path(sys.executable).parent / "cdgps")
LAYOUTS = {"x": (), "end-y": (1, 2, 5, 6), "all-y": (1, 2, 3, 4, 5, 6)}


def layout_text(text: str, arms_y) -> str:
    """The config with the ±x jets of arms ``arms_y`` (1..6) turned to ±y (same position and force)."""
    for a in arms_y:
        for sign, y in (("+", "1.0"), ("-", "-1.0")):
            pat = re.compile(rf'(name = "a{a}){re.escape(sign)}x("\n(?:.*\n)*?)direction = \[[^\]]*\]')
            text, n = pat.subn(rf'\g<1>{sign}y\g<2>direction = [0.0, {y}, 0.0]', text, count=1)
            assert n == 1, (a, sign)
    return text


def _run(*args) -> str:
    p = subprocess.run([CDGPS, "-q", *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(p.stderr[-2000:])
    return p.stdout


def slew(cfg_path: Path, gains: Path, seed: int, fraction: float, out: Path) -> dict:
    """One slew at the profile's authority ``fraction``: the report's metrics and coordinates."""
    code = ("import sys, cdgps_cli.control.slew as s; s.SLEW_AUTHORITY_FRACTION = float(sys.argv[1]); "
            "from cdgps_cli.cli.commands import main; main(sys.argv[2:])")
    p = subprocess.run([sys.executable, "-c", code, str(fraction), "-q", "simulate", str(cfg_path), "--scenario", "slew",
                        "--duration", "40", "--seed", str(seed), "--disturbance-scale", "0.05", "--controller",
                        str(gains), "-o", str(out)], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(p.stderr[-2000:])
    rep = json.loads(_run("report", "control", gains, "--closed", out, "--date", "2026-01-01", "-o", f"{out}-rep", "--json"))
    c = rep["coordinates"]["closed"]
    worst = lambda names: max(c[q]["max_abs"] for q in names)  # noqa: E731
    return {"seed": seed, "arrived_s": rep["metrics"]["closed"]["arrived_s_after_command"],
            "vertical_deg": worst(("q3", "q6", "q9")), "twist_deg": worst(("q2", "q5", "q8")),
            "lateral_mm": worst(("q1", "q4", "q7")), "saturated": rep["controllers"]["closed"].get("saturated_fraction")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--qx", type=float, default=None,
                    help="design with --weights paper --qx W (benchmarks/paper_fig6_weights.py) instead of tuned")
    a = ap.parse_args(argv)
    weights = ("--weights", "tuned") if a.qx is None else ("--weights", "paper", "--qx", f"{a.qx:g}")
    base_acc = rigid_authority(load_config(CONFIG))[2]
    res = {}
    with tempfile.TemporaryDirectory(prefix="cdgps-layout-") as tmp:
        w = Path(tmp)
        for name, arms in LAYOUTS.items():
            cfg_path = w / f"{name}.toml"
            cfg_path.write_text(layout_text(CONFIG.read_text(), arms))
            acc = rigid_authority(load_config(cfg_path))[2]
            fraction = SLEW_AUTHORITY_FRACTION * base_acc / acc
            gains = w / f"gains-{name}.json"
            _run("control", "design", cfg_path, *weights, "-o", gains)
            runs = [slew(cfg_path, gains, s, fraction, w / f"slew-{name}-{s}") for s in range(1, a.seeds + 1)]
            res[name] = {"rigid_authority_ratio": acc / base_acc, "profile_fraction": fraction, "runs": runs}
            print(name, json.dumps(res[name]), flush=True)
    print("| layout | rigid authority × | arrived (s) | q3/q6/q9 max (°) | q2/q5/q8 max (°) | q1/q4/q7 max (mm) | saturated |")
    print("|---|---|---|---|---|---|---|")
    for name, r in res.items():
        rr = r["runs"]
        arr = [x["arrived_s"] for x in rr]
        print(f"| {name} | {r['rigid_authority_ratio']:.2f} | "
              f"{'–'.join('none' if v is None else f'{v:.1f}' for v in arr)} | "
              f"{max(x['vertical_deg'] for x in rr):.2f} | {max(x['twist_deg'] for x in rr):.2f} | "
              f"{max(x['lateral_mm'] for x in rr):.1f} | {max(x['saturated'] or 0 for x in rr):.0%} |")
    name = "paper-thruster-layout.json" if a.qx is None else f"paper-thruster-layout-qx{a.qx:g}.json"
    (ROOT / "docs" / "benchmarks" / name).write_text(
        json.dumps({"benchmark": "paper_thruster_layout", "seeds": a.seeds, "weights": list(weights), "layouts": res},
                   indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
