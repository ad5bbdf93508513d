#!/usr/bin/env python3
"""Where a fused run's memory goes (issue 29, step 1): ``cdgps estimate --structure --smooth --fuse
accel,gyro,tilt`` on an existing record, in-process under ``tracemalloc``; a sampler thread takes a
snapshot each time the traced total reaches a new high, and the top allocation sites of the highest
snapshot are written as JSON (MiB per source line).

Example::

    python benchmarks/fusion_memory_profile.py RECORD_DIR --out /tmp/profile_5min.json
"""

from __future__ import annotations

import argparse
import json
import threading
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CFG = ROOT / "configs" / "tower-fusion.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("record", type=Path, help="directory with run.mcap and init.json")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--top", type=int, default=15)
    a = ap.parse_args()
    from cdgps_cli.cli.commands import main as cdgps_main

    best = {"mib": 0.0, "snap": None}
    done = threading.Event()

    def sample() -> None:
        while not done.wait(0.5):
            cur = tracemalloc.get_traced_memory()[0] / 2**20
            if cur > best["mib"] * 1.02:
                best["mib"], best["snap"] = cur, tracemalloc.take_snapshot()

    tracemalloc.start(1)
    t = threading.Thread(target=sample, daemon=True)
    t.start()
    try:
        cdgps_main(["-q", "estimate", str(a.record / "run.mcap"), "--init", str(a.record / "init.json"),
                    "--structure", str(CFG), "--smooth", "--fuse", "accel,gyro,tilt",
                    "-o", str(a.record / "profile.mcap")], standalone_mode=False)
    finally:
        done.set()
        t.join()
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    stats = best["snap"].statistics("lineno") if best["snap"] else []
    rows = [{"site": f"{Path(s.traceback[0].filename).name}:{s.traceback[0].lineno}",
             "mib": round(s.size / 2**20, 2), "blocks": s.count} for s in stats[:a.top]]
    a.out.write_text(json.dumps({"record": str(a.record), "traced_peak_mib": round(peak, 1),
                                 "sampled_high_mib": round(best["mib"], 1), "top_sites": rows}, indent=1) + "\n")
    print(json.dumps(rows[:8], indent=1))


if __name__ == "__main__":
    main()
