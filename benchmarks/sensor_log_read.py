#!/usr/bin/env python3
"""Time and peak Python memory of reading a GNSS RUN's sensor logs (``sensors/<kind>.csv`` attachments →
tables, what ``cdgps estimate --structure --fuse`` does first), this tree against another tree's
``io/sensor_logs.py`` (issue 29) → docs/benchmarks/sensor_log_read.json.

Best of interleaved rounds (wall time), then one tracemalloc pass each for the peak; the load average
is recorded beside them.

Example::

    python benchmarks/sensor_log_read.py RUN.mcap --before /tmp/base --rounds 3
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.io import sensor_logs as after  # noqa: E402
from cdgps_cli.io.mcap import read_mcap  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path, help="a GNSS RUN.mcap with sensor logs (e.g. tower-fusion, 15 min)")
    ap.add_argument("--before", type=Path, required=True, help="the tree to compare with")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "sensor_log_read.json")
    a = ap.parse_args()
    spec = importlib.util.spec_from_file_location("before_sensor_logs", a.before / "cdgps_cli" / "io" / "sensor_logs.py")
    before = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(before)
    att = {k: v for k, v in read_mcap(a.run, topics=[]).attachments.items() if k.startswith("sensors/")}
    mods = {"before": before, "after": after}
    wall = {name: [] for name in mods}
    for r in range(a.rounds):
        for name in (("before", "after") if r % 2 == 0 else ("after", "before")):
            t0 = time.perf_counter()
            mods[name].sensor_logs_from_attachments(att)
            wall[name].append(time.perf_counter() - t0)
    out = {"command": f"python benchmarks/sensor_log_read.py {a.run.name} --before <tree> --rounds {a.rounds}",
           "attachment_bytes": {k: len(v) for k, v in att.items()}, "loadavg_1min": os.getloadavg()[0]}
    for name, mod in mods.items():
        tracemalloc.start()
        mod.sensor_logs_from_attachments(att)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        out[name] = {"best_wall_s": round(min(wall[name]), 3), "wall_s": [round(w, 3) for w in wall[name]],
                     "peak_traced_mib": round(peak / 2**20, 1)}
    print(json.dumps(out, indent=1))
    a.out.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
