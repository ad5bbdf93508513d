"""The GNSS modal path's start state with fused accelerometers (issue 30, helper modalstart).

Per seed on configs/tower-fusion.toml (20 s, 10 Hz GNSS, 100 Hz accelerometers): simulate-gnss-structure,
ingest, init, then ``estimate --structure --smooth`` with the GNSS alone and with ``--fuse accel``;
reports evaluate's NEES per dof (modal positions, from the first epoch and after 5 s), the RMS error
of the 5 Hz mode q4 (the GNSS Nyquist), the per-mode NEES (diagonal) and the accelerometer rows
rejected by the outlier gate (6σ: expected false alarms ≈ 2e-9 per row).

    python benchmarks/modal_start.py --seeds 1 2 3 4 5 --out docs/benchmarks/modal_start.json
"""

from __future__ import annotations

import argparse
import collections
import datetime
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "tower-fusion.toml"


def _cdgps(*args) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    subprocess.run([sys.executable, "-m", "cdgps_cli.cli.commands", "-q", *map(str, args)], check=True, env=env,
                   cwd=ROOT, stdout=subprocess.DEVNULL)


def one_seed(seed: int, duration_s: float, d: Path) -> dict:
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.io.coordinate_columns import coordinate_table
    from cdgps_cli.io.states import States
    from cdgps_cli.pipeline.estimate_outputs import evaluate

    if not (d / "init.json").exists():
        _cdgps("simulate-gnss-structure", CONFIG, "--duration", duration_s, "--gnss-interval", 0.1, "--seed", seed, "-o", d)
        _cdgps("ingest", "--config", d / "config.toml", "-o", d / "run.mcap")
        _cdgps("init", d / "run.mcap", "-o", d / "init.json")
    cfg = load_config(CONFIG)
    truth, _ = coordinate_table(pd.read_csv(d / "truth.csv"), cfg)
    tq, q_true = truth["time_s"].to_numpy(), truth[list(cfg.coord_names)].to_numpy()
    out = {"seed": seed}
    for name, fuse in (("gnss", ()), ("fused", ("--fuse", "accel"))):
        _cdgps("estimate", d / "run.mcap", "--init", d / "init.json", "--structure", CONFIG, "--smooth", *fuse,
               "-o", d / f"{name}.mcap")
        st = States(d / f"{name}.mcap")
        e = st.q - q_true[np.searchsorted(tq, st.time_s)]
        ev0, ev5 = (evaluate(d, d / f"{name}.mcap", converge_s=c) for c in (0.0, 5.0))
        rej = collections.Counter(ev["antenna"] for ev in st.events if ev.get("kind") == "outlier")
        out[name] = {"nees_per_dof": ev0["nees"]["mean"] / ev0["nees"]["dof"],
                     "nees_per_dof_after_5s": ev5["nees"]["mean"] / ev5["nees"]["dof"],
                     "nees_per_mode": np.mean(e**2 / st.sigma_q**2, axis=0).round(3).tolist(),
                     "q4_rms_m": float(np.sqrt(np.mean(e[:, 3] ** 2))), "outliers": dict(rej)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--work", default=None, help="keep the simulated runs here (reused when present)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "modal_start.json"))
    a = ap.parse_args()
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(a.work or tmp)
        runs = []
        for s in a.seeds:
            r = one_seed(s, a.duration, work / f"seed{s}")
            runs.append(r)
            print(f"seed {s}: NEES/dof gnss {r['gnss']['nees_per_dof']:.3f} fused {r['fused']['nees_per_dof']:.3f}, "
                  f"q4 {r['gnss']['q4_rms_m'] * 1e3:.3f} / {r['fused']['q4_rms_m'] * 1e3:.3f} mm, "
                  f"outliers {r['fused']['outliers']}", flush=True)
    doc = {"benchmark": "benchmarks/modal_start.py", "config": "configs/tower-fusion.toml",
           "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%MZ"),
           "machine": {"cpus": os.cpu_count(), "load_1min": os.getloadavg()[0]},
           "settings": {"seeds": a.seeds, "duration_s": a.duration},
           "summary": {k: {"nees_per_dof_mean": float(np.mean([r[k]["nees_per_dof"] for r in runs])),
                           "outlier_rows": int(sum(sum(r[k]["outliers"].values()) for r in runs))}
                       for k in ("gnss", "fused")},
           "runs": runs}
    Path(a.out).write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc["summary"], indent=1))


if __name__ == "__main__":
    main()
