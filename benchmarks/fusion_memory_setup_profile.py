#!/usr/bin/env python3
"""Where the GNSS modal set-up's memory goes (issue 29): the RUN of an existing record is read, then
:func:`cdgps_cli.pipeline.gnss_modal._modal_setup` (every rover's baseline with INIT's integers) runs
under ``tracemalloc`` (30-frame tracebacks); a sampler thread snapshots each new traced high, and the
sites of the highest snapshot are summed by their innermost three ``cdgps_cli`` frames.  Gives the live
heap after the RUN read, the set-up's traced peak and what it keeps, MiB; with two or more records the
growth per minute of record of each.  The tree measured is the one on ``PYTHONPATH``.

Example::

    PYTHONPATH=. python benchmarks/fusion_memory_setup_profile.py /tmp/rec2:2 /tmp/rec5:5 --out x.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import threading
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CFG = ROOT / "configs" / "tower-fusion.toml"


def one(record: Path, top: int) -> dict:
    """The set-up's traced figures (MiB) and its top sites on ``record`` (this process)."""
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, read_gnss_run
    from cdgps_cli.pipeline import gnss_modal

    cfg = load_config(CFG)
    init = json.loads((record / "init.json").read_text())
    tracemalloc.start(30)
    run = read_gnss_run(record / "run.mcap", columns=SOLVER_COLUMNS)
    base = tracemalloc.get_traced_memory()[0] / 2**20
    tracemalloc.reset_peak()
    best = {"mib": 0.0, "snap": None}
    done = threading.Event()

    def sample() -> None:
        while not done.wait(0.2):
            cur = tracemalloc.get_traced_memory()[0] / 2**20
            if cur > best["mib"] * 1.01:
                best["mib"], best["snap"] = cur, tracemalloc.take_snapshot()

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    su = gnss_modal._modal_setup(run, init, cfg, None, 90.0, lambda m: None)
    kept, peak = (v / 2**20 for v in tracemalloc.get_traced_memory())
    done.set()
    th.join()
    del su
    sites: dict = {}
    for st in best["snap"].statistics("traceback") if best["snap"] else []:
        fr = [f for f in st.traceback if "cdgps_cli" in f.filename]
        key = " < ".join(f"{Path(f.filename).name}:{f.lineno}" for f in fr[-3:][::-1]) if fr else "(outside cdgps_cli)"
        sites[key] = sites.get(key, 0) + st.size
    rows = sorted(sites.items(), key=lambda kv: -kv[1])[:top]
    return {"after_run_read_mib": round(base, 1), "setup_traced_peak_mib": round(peak, 1),
            "kept_after_setup_mib": round(kept, 1), "sampled_high_mib": round(best["mib"], 1),
            "top_sites_mib": {k: round(v / 2**20, 2) for k, v in rows}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("records", nargs="+", help="RECORD_DIR:MINUTES (directories with run.mcap and init.json)")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--top", type=int, default=15)
    ap.add_argument("--tree", default="", help="what the tree on PYTHONPATH is, for the JSON")
    ap.add_argument("--one", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one is not None:                               # (the child: one record, JSON on stdout)
        print(json.dumps(one(a.one, a.top)))
        return
    runs = {}
    for item in a.records:
        d, _, m = item.rpartition(":")
        out = subprocess.run([sys.executable, __file__, "x", "--one", d, "--top", str(a.top)], check=True,
                             capture_output=True, text=True)
        runs[float(m)] = json.loads(out.stdout.strip().splitlines()[-1])
        print(m, json.dumps(runs[float(m)])[:300], flush=True)
    doc = {"command": "PYTHONPATH=<tree> python benchmarks/fusion_memory_setup_profile.py " + " ".join(a.records),
           "tree": a.tree, "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "loadavg_1min": os.getloadavg()[0], "runs": {f"{m:g}min": r for m, r in sorted(runs.items())}}
    if len(runs) > 1:
        (m0, r0), (m1, r1) = min(runs.items()), max(runs.items())
        g = {k: round((r1[k] - r0[k]) / (m1 - m0), 2) for k in r0 if k.endswith("_mib") and k != "top_sites_mib"}
        s0, s1 = r0["top_sites_mib"], r1["top_sites_mib"]
        g["top_sites"] = dict(sorted(((k, round((s1[k] - s0.get(k, 0.0)) / (m1 - m0), 3)) for k in s1),
                                     key=lambda kv: -kv[1]))
        doc["growth_mib_per_min"] = g
    text = json.dumps(doc, indent=1, ensure_ascii=False) + "\n"
    if a.out:
        a.out.write_text(text)
    else:
        print(text)


if __name__ == "__main__":
    main()
