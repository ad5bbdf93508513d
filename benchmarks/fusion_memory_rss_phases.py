#!/usr/bin/env python3
"""Peak RSS of a fused run phase by phase (issue 29, helper ``fused29``): ``cdgps estimate --structure
configs/tower-fusion.toml --smooth --fuse accel,gyro,tilt`` in-process on existing records, a thread
sampling ``VmRSS`` every 50 ms and charging it to the phase running (the RUN and sensor-log reads,
the GNSS modal set-up, the modal integers, the sensor parts, the forward filter, the RTS smoother, the
sensors' summary, the DD residuals, the STATES writer; no tracemalloc, so at full speed).  With two
or more records the JSON gives each phase's growth in MiB per minute between the shortest and the
longest.  The tree measured is the one on ``PYTHONPATH``.

Example::

    PYTHONPATH=. python benchmarks/fusion_memory_rss_phases.py /tmp/rec2:2 /tmp/rec10:10 --out x.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import subprocess
import sys
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CFG = ROOT / "configs" / "tower-fusion.toml"
#: (module, function, phase it starts); a phase runs until the next one starts
PHASES = [("cdgps_cli.pipeline.gnss_modal", "_modal_setup", "modal set-up (baselines)"),
          ("cdgps_cli.pipeline.gnss_modal", "_modal_integers", "modal integers (batch init)"),
          ("cdgps_cli.pipeline.fusion", "sensor_parts", "sensor parts"),
          ("cdgps_cli.pipeline.fusion", "filter_numpy", "forward filter"),
          ("cdgps_cli.pipeline.fusion", "rts_smooth_indexed", "RTS smoother"),
          ("cdgps_cli.pipeline.fusion", "_sensor_summary", "sensor summary"),
          ("cdgps_cli.pipeline.gnss_modal", "_dd_residuals", "DD residuals"),
          ("cdgps_cli.pipeline.estimate_outputs", "write_states", "STATES writer")]


def _rss_mib() -> float:
    with open("/proc/self/status") as fh:
        return next(int(ln.split()[1]) for ln in fh if ln.startswith("VmRSS:")) / 1024


def one(record: Path) -> dict:
    """{phase: peak RSS MiB} of one fused run on ``record`` (this process; run once per process)."""
    import importlib

    from cdgps_cli.cli.commands import main as cdgps_main

    state = {"phase": "RUN and sensor-log reads", "peak": {}}
    lock = threading.Lock()

    def starts(phase, fn):
        def wrapped(*a, **k):
            with lock:
                state["phase"] = phase
            return fn(*a, **k)
        return wrapped

    for mod, name, phase in PHASES:
        m = importlib.import_module(mod)
        setattr(m, name, starts(phase, getattr(m, name)))
    done = threading.Event()

    def sample():
        while not done.wait(0.05):
            v = _rss_mib()
            with lock:
                state["peak"][state["phase"]] = max(state["peak"].get(state["phase"], 0.0), v)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    try:
        cdgps_main(["-q", "estimate", str(record / "run.mcap"), "--init", str(record / "init.json"), "--structure",
                    str(CFG), "--smooth", "--fuse", "accel,gyro,tilt", "-o", str(record / "rss_phases.mcap")],
                   standalone_mode=False)
    finally:
        done.set()
        th.join()
    return {"peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            "phases_peak_rss_mib": {p: round(v, 1) for p, v in state["peak"].items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("records", nargs="+", help="RECORD_DIR:MINUTES (directories with run.mcap and init.json)")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--tree", default="", help="what the tree on PYTHONPATH is, for the JSON")
    ap.add_argument("--one", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one is not None:                               # (the child: one run, JSON on stdout)
        print(json.dumps(one(a.one)))
        return
    runs = {}
    for item in a.records:
        d, _, m = item.rpartition(":")
        out = subprocess.run([sys.executable, __file__, "x", "--one", d], check=True, capture_output=True, text=True)
        runs[float(m)] = json.loads(out.stdout.strip().splitlines()[-1])
        print(m, runs[float(m)], flush=True)
    doc = {"command": "PYTHONPATH=<tree> python benchmarks/fusion_memory_rss_phases.py " + " ".join(a.records),
           "tree": a.tree, "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "loadavg_1min": os.getloadavg()[0], "runs": {f"{m:g}min": r for m, r in sorted(runs.items())}}
    if len(runs) > 1:
        (m0, r0), (m1, r1) = min(runs.items()), max(runs.items())
        p0, p1 = r0["phases_peak_rss_mib"], r1["phases_peak_rss_mib"]
        doc["growth_mib_per_min"] = {p: round((p1[p] - p0[p]) / (m1 - m0), 2) for p in p1 if p in p0}
        doc["growth_mib_per_min"]["peak"] = round((r1["peak_rss_mib"] - r0["peak_rss_mib"]) / (m1 - m0), 2)
    text = json.dumps(doc, indent=1, ensure_ascii=False) + "\n"
    if a.out:
        a.out.write_text(text)
    else:
        print(text)


if __name__ == "__main__":
    main()
