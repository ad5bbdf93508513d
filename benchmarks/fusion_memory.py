#!/usr/bin/env python3
"""Peak memory of a fused run (``cdgps estimate --structure --fuse accel,gyro,tilt --smooth``) on
configs/tower-fusion.toml (10 Hz GNSS, 100 Hz sensors) at several record lengths, two code trees side
by side (issue 29, helper `fusedisk`) → docs/benchmarks/fusion_memory.json.

Per duration the record is made once (simulate-gnss-structure → ingest → init, this tree); then the
``estimate`` command runs as a child process under each tree (``PYTHONPATH``), in interleaved
rounds; its peak RSS (``/usr/bin/time``: the process's own), the peak PSS summed over it and any process it
forks (benchmarks/tree_memory.py) and wall time are recorded with the load average.

Example::

    python benchmarks/fusion_memory.py --before /tmp/base --minutes 2,5,15
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
import tree_memory  # noqa: E402  (benchmarks/tree_memory.py)

CFG = ROOT / "configs" / "tower-fusion.toml"
CDGPS = Path(sys.executable).with_name("cdgps")


def run(tree: Path, *args) -> tuple[float, float, float]:
    """(peak RSS MiB of the command's process, peak PSS MiB summed over it and the processes it forks
    (benchmarks/tree_memory.py), wall s) of ``cdgps -q args`` with ``tree`` on PYTHONPATH."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    with tempfile.TemporaryFile("w+") as err:
        res = tree_memory.measure(["/usr/bin/time", "-f", "__TIME__ %M", str(CDGPS), "-q", *map(str, args)],
                                  env=env, stdout=subprocess.DEVNULL, stderr=err, text=True)
        err.seek(0)
        text = err.read()
    if res["exit"] != 0:
        raise SystemExit(f"{args[0]} failed under {tree}: {text[-2000:]}")
    rss_kib = float([ln for ln in text.splitlines() if ln.startswith("__TIME__")][-1].split()[1])
    return rss_kib / 1024.0, res["peak_tree_pss_mib"], res["wall_s"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", type=Path, required=True, help="the tree to compare with (e.g. an export of main)")
    ap.add_argument("--minutes", default="2,5,15")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "fusion_memory.json")
    ap.add_argument("--before-label", default="export of main 9b902ba", help="what --before is, for the JSON")
    a = ap.parse_args()
    trees = {"before": a.before.resolve(), "after": ROOT}
    results = []
    with tempfile.TemporaryDirectory(prefix="fusion-memory-") as tmp:
        for minutes in [float(m) for m in a.minutes.split(",")]:
            d = Path(tmp) / f"{minutes:g}min"
            run(ROOT, "simulate-gnss-structure", CFG, "--duration", 60 * minutes, "--gnss-interval", "0.1",
                "--seed", "3", "-o", d)
            run(ROOT, "ingest", "--config", d / "config.toml", "-o", d / "run.mcap")
            run(ROOT, "init", d / "run.mcap", "-o", d / "init.json")
            row = {"minutes": minutes, "epochs_100hz": int(round(minutes * 6000)) + 1}
            for r in range(a.rounds):
                for name in (("before", "after") if r % 2 == 0 else ("after", "before")):
                    rss, pss, wall = run(trees[name], "estimate", d / "run.mcap", "--init", d / "init.json", "--structure",
                                    CFG, "--smooth", "--fuse", "accel,gyro,tilt", "-o", d / f"{name}.mcap")
                    row.setdefault(name, []).append({"peak_rss_mib": round(rss, 1), "peak_tree_pss_mib": pss,
                                                     "wall_s": round(wall, 2),
                                                     "loadavg_1min": os.getloadavg()[0]})
            results.append(row)
            print(json.dumps(row), flush=True)
    a.out.write_text(json.dumps({"command": f"python benchmarks/fusion_memory.py --before <{a.before_label}> "
                                            f"--minutes {a.minutes} --rounds {a.rounds}",
                                 "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                                 "config": "configs/tower-fusion.toml", "fuse": "accel,gyro,tilt",
                                 "cpu_count": os.cpu_count(), "results": results}, indent=1) + "\n")


if __name__ == "__main__":
    main()
