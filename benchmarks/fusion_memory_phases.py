#!/usr/bin/env python3
"""What a fused run holds at each phase (issue 29, helper ``fused29``): ``cdgps estimate --structure
configs/tower-fusion.toml --smooth --fuse accel,gyro,tilt`` on existing records, in-process under
``tracemalloc`` (10 frames), with a snapshot taken

* ``run_read`` — when the GNSS RUN has been read (:func:`cdgps_cli.io.gnss_run.read_gnss_run` returns),
* ``setup_done`` — when the GNSS modal set-up has made its tables (``_modal_setup`` returns),
* ``filter_start`` — when the fused filter starts (:func:`cdgps_cli.pipeline.fusion.release_freed_heap`),
* ``high`` — the highest traced total, sampled every 0.5 s;

each allocation is charged to its innermost frame in ``cdgps_cli`` (so a numpy or pandas allocation
is named by the project line that asked for it).  With two or more records the JSON also gives, per
phase and site, the growth in MiB per minute of record between the shortest and the longest.

Example::

    python benchmarks/fusion_memory_phases.py /tmp/rec2:2 /tmp/rec10:10 --out docs/benchmarks/x.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import threading
import tracemalloc
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CFG = ROOT / "configs" / "tower-fusion.toml"
PHASES = ("run_read", "setup_done", "filter_start", "high")


def _by_site(snap) -> dict:
    """{project site: MiB} of a snapshot, each trace charged to its innermost cdgps_cli frame."""
    out: dict = defaultdict(float)
    for tr in snap.traces:
        site = "(imports and other)"
        for fr in tr.traceback:                       # oldest → most recent: the last project frame wins
            if "cdgps_cli" in fr.filename:
                site = f"{fr.filename.split('cdgps_cli/')[-1]}:{fr.lineno}"
        out[site] += tr.size / 2**20
    return dict(out)


def _wrap(module, name: str, after: bool, take) -> None:
    """Take a snapshot before (or after) each call of ``module.name``."""
    fn = getattr(module, name)

    def wrapped(*a, **k):
        if not after:
            take()
        r = fn(*a, **k)
        if after:
            take()
        return r

    setattr(module, name, wrapped)


def profile(record: Path) -> dict:
    """Snapshots of one fused run on ``record`` (run.mcap, init.json) by phase: {phase: {site: MiB}}."""
    from cdgps_cli.cli.commands import main as cdgps_main
    from cdgps_cli.io import gnss_run
    from cdgps_cli.pipeline import fusion, gnss_modal

    snaps: dict = {}
    best = {"mib": 0.0, "snap": None}
    lock = threading.Lock()

    def taker(phase):
        def take():
            with lock:
                snaps[phase] = (tracemalloc.get_traced_memory()[0] / 2**20, tracemalloc.take_snapshot())
        return take

    saved = [(gnss_run, "read_gnss_run"), (gnss_modal, "_modal_setup"), (fusion, "release_freed_heap")]
    originals = [getattr(m, n) for m, n in saved]
    _wrap(gnss_run, "read_gnss_run", True, taker("run_read"))
    _wrap(gnss_modal, "_modal_setup", True, taker("setup_done"))
    _wrap(fusion, "release_freed_heap", False, taker("filter_start"))
    done = threading.Event()

    def sample() -> None:
        while not done.wait(0.5):
            cur = tracemalloc.get_traced_memory()[0] / 2**20
            if cur > best["mib"] * 1.02:
                with lock:
                    best["mib"], best["snap"] = cur, tracemalloc.take_snapshot()

    tracemalloc.start(10)
    t = threading.Thread(target=sample, daemon=True)
    t.start()
    try:
        cdgps_main(["-q", "estimate", str(record / "run.mcap"), "--init", str(record / "init.json"),
                    "--structure", str(CFG), "--smooth", "--fuse", "accel,gyro,tilt",
                    "-o", str(record / "phases.mcap")], standalone_mode=False)
    finally:
        done.set()
        t.join()
        for (m, n), f in zip(saved, originals):
            setattr(m, n, f)
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    snaps["high"] = (best["mib"], best["snap"])
    return {"traced_peak_mib": round(peak, 1),
            "phases": {p: {"total_mib": round(snaps[p][0], 2), "sites": _by_site(snaps[p][1])}
                       for p in PHASES if p in snaps and snaps[p][1] is not None}}


def growth(runs: dict, top: int) -> dict:
    """Per phase: the sites that grow most, MiB per minute between the shortest and the longest record."""
    (m0, a), (m1, b) = min(runs.items()), max(runs.items())
    out = {}
    for p in PHASES:
        if p not in a["phases"] or p not in b["phases"]:
            continue
        sa, sb = a["phases"][p]["sites"], b["phases"][p]["sites"]
        g = {s: (sb.get(s, 0.0) - sa.get(s, 0.0)) / (m1 - m0) for s in set(sa) | set(sb)}
        rows = sorted(g.items(), key=lambda kv: -kv[1])[:top]
        out[p] = {"total_mib_per_min": round((b["phases"][p]["total_mib"] - a["phases"][p]["total_mib"]) / (m1 - m0), 3),
                  "sites_mib_per_min": [{"site": s, "mib_per_min": round(v, 3), f"mib_at_{m0:g}min": round(sa.get(s, 0.0), 2),
                                         f"mib_at_{m1:g}min": round(sb.get(s, 0.0), 2)} for s, v in rows]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("records", nargs="+", help="RECORD_DIR:MINUTES (directories with run.mcap and init.json)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--tree", default="", help="what the tree is (a commit), for the JSON")
    a = ap.parse_args()
    runs = {}
    for item in a.records:
        d, _, m = item.rpartition(":")
        runs[float(m)] = profile(Path(d))
        print(f"{m} min: traced peak {runs[float(m)]['traced_peak_mib']} MiB", flush=True)
    grow = growth(runs, a.top) if len(runs) > 1 else None
    for r in runs.values():                       # (only the largest sites in the JSON)
        for ph in r["phases"].values():
            ph["sites"] = dict(sorted(((s, round(v, 2)) for s, v in ph["sites"].items()), key=lambda kv: -kv[1])[:a.top])
    doc = {"command": "python benchmarks/fusion_memory_phases.py " + " ".join(a.records) + " --out ...",
           "tree": a.tree, "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "loadavg_1min": os.getloadavg()[0],
           "note": "tracemalloc traced bytes (Python/numpy heap), not RSS; each allocation charged to its innermost cdgps_cli line",
           "runs": {f"{m:g}min": r for m, r in sorted(runs.items())}}
    if grow:
        doc["growth"] = grow
    a.out.write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n")


if __name__ == "__main__":
    main()
