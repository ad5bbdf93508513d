#!/usr/bin/env python3
"""Rate gyros fused on the pseudolite testbed path (issue 30 item 3) → docs/benchmarks/fusion_testbed.json.

Per seed, through the commands: ``simulate`` configs/testbed-1998.toml (free vibration, the true
disturbance at the filter model's process noise: ``--disturbance-scale 1``), ``ingest`` (receiver.csv
+ gyro.csv), ``init --duration W``, then ``estimate --smooth`` with and without ``--fuse gyro``, and
``evaluate`` of both: NEES per dof of the modal positions (fused: its epochs, from INIT's window end;
phases alone: every epoch, its window from the batch solution), RMS errors from W + 1 s on
(``--converge-s``), seconds per estimate.

Example::

    python benchmarks/fusion_testbed.py                       # 10 seeds × 60 s (≈ 2–3 min)
    python benchmarks/fusion_testbed.py --seeds 3 --duration 40 --out /tmp/t.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from click.testing import CliRunner  # noqa: E402

from cdgps_cli.cli.commands import main  # noqa: E402

CONFIG = ROOT / "configs" / "testbed-1998.toml"
ANGLES = ("q2", "q3", "q5", "q6", "q8", "q9")      # section rotations, rad (the gyros' mounts)
TRANSLATIONS = ("q1", "q4", "q7")                  # m


def cli(*args) -> str:
    r = CliRunner().invoke(main, ["-q", *[str(a) for a in args]])
    if r.exit_code != 0:
        raise RuntimeError(f"cdgps {' '.join(map(str, args))}: {r.output}")
    return r.stdout


def one_seed(seed: int, duration: float, window: float, d: Path) -> dict | None:
    cli("simulate", CONFIG, "--duration", duration, "--seed", seed, "--disturbance-scale", 1, "-o", d / "sim")
    cli("ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", CONFIG, "-o", d / "run.mcap")
    try:
        cli("init", d / "run.mcap", "--duration", window, "-o", d / "init.json")
    except RuntimeError as exc:                    # (no integer fix on this seed: reported, not used)
        return {"seed": seed, "init_failed": str(exc)[-200:]}
    out = {"seed": seed}
    for name, extra in (("phases", ()), ("fused", ("--fuse", "gyro"))):
        t0 = time.perf_counter()
        cli("estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", *extra, "-o", d / f"{name}.mcap")
        dt = time.perf_counter() - t0
        conv = window + 1.0 if name == "phases" else 1.0
        e = json.loads(cli("evaluate", "--truth", d / "sim", "--estimate", d / f"{name}.mcap", "--converge-s", conv, "--json"))
        out[name] = {"epochs": e["epochs"], "nees_per_dof": e["nees"]["mean"] / e["nees"]["dof"], "estimate_s": dt,
                     "rms_angle_mrad": float(np.sqrt(np.mean([e["rms_error"][q] ** 2 for q in ANGLES])) * 1e3),
                     "rms_translation_mm": float(np.sqrt(np.mean([e["rms_error"][q] ** 2 for q in TRANSLATIONS])) * 1e3)}
    return out


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--window", type=float, default=10.0)
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "fusion_testbed.json"))
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, a.seeds + 1):
            d = Path(tmp) / f"s{seed}"
            d.mkdir()
            rows.append(one_seed(seed, a.duration, a.window, d))
            print(json.dumps(rows[-1]), flush=True)
    ok = [r for r in rows if "fused" in r]

    def stats(key, sub):
        v = np.array([r[key][sub] for r in ok])
        return {"mean": float(v.mean()), "min": float(v.min()), "max": float(v.max())}

    summary = {k: {s: stats(k, s) for s in ("nees_per_dof", "rms_angle_mrad", "rms_translation_mm", "estimate_s")}
               for k in ("phases", "fused")}
    summary["fused_nees_in_0.8_1.25"] = int(sum(0.8 <= r["fused"]["nees_per_dof"] <= 1.25 for r in ok))
    res = {"benchmark": "fusion_testbed", "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "command": "python benchmarks/fusion_testbed.py " + " ".join(sys.argv[1:]),
           "config": "configs/testbed-1998.toml", "seeds": a.seeds, "duration_s": a.duration, "init_window_s": a.window,
           "load_average": os.getloadavg(), "summary": summary, "runs": rows}
    Path(a.out).write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main_()
