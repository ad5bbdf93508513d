#!/usr/bin/env python3
"""The reading and geometry stages of ``cdgps rtk``, this tree against an earlier one (issue 28 item 6).

For every case of ``bench_rtk_rtklib.py`` a child process per tree (``PYTHONPATH``) times, as library
calls, the stages of ``pipeline.gnss_multi.rtk_from_files`` that read and place the data: both
receivers' observations (``_read_observations``: the RINEX signal reader, or a u-blox log's
RXM-RAWX and SFRBX), the navigation files (``_nav``; for a u-blox base its SFRBX ephemerides, read
with its observations) and the satellite geometry of both receivers (``receiver_geometry``:
ephemeris selection, orbits, az/el, troposphere).  Each child reports the least of ``--repeat``
calls per stage (every cache cleared before each); the trees take turns for ``--rounds`` rounds and
the least is kept: a loaded machine only adds time, so the least is the figure least disturbed by
the seven other agents on this machine.  The child also checks that both trees give the same
tables (a hash of them).  Writes ``docs/benchmarks/gnss_read_geometry.json``::

    PYTHONPATH=. python benchmarks/bench_gnss_read_geometry.py --before /tmp/before-tree
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_rtk_rtklib import cases  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "gnss_read_geometry.json"

CHILD = r'''
import hashlib, json, sys, time
import numpy as np, pandas as pd
from cdgps_cli.pipeline import gnss_multi as gm
from cdgps_cli.estimation.rtk_multi import receiver_geometry
from cdgps_cli.io import ubx
c = json.loads(sys.argv[1]); repeat = int(sys.argv[2])
def clear():
    gm._ubx_decoded.cache_clear()
    getattr(ubx, "_LAST_DECODED", {}).clear()
def best(fn):
    out, ts = None, []
    for _ in range(repeat):
        clear(); t = time.perf_counter(); out = fn(); ts.append(time.perf_counter() - t)
    return min(ts), out
sigs, systems = c["signals"], sorted({s[0] for s in c["signals"]})
t_nav, nav = best(lambda: gm._nav(c["navs"], systems) if c["navs"] else gm._ubx_nav((c["base"], c["rover"])))
nav = nav[nav["sat"].str[0].isin(systems)] if not c["navs"] else nav
glo = ({sat: int(k) for sat, k in nav.dropna(subset=["glonass_k"]).groupby("sat")["glonass_k"].first().items()}
       if "glonass_k" in nav.columns else {})
def both():
    return gm._read_observations(c["base"], sigs, glo)[1], gm._read_observations(c["rover"], sigs, glo)[1]
t_obs, (b, r) = best(both)
xyz = c["base_xyz"] or gm._read_observations(c["base"], sigs, glo)[0]["approx_position_xyz_m"]
t_geo, (gb, gr) = best(lambda: (receiver_geometry(b, nav, xyz), receiver_geometry(r, nav, xyz)))
h = hashlib.sha256()
for df in (b, r, gb, gr, nav):
    h.update(pd.util.hash_pandas_object(df.reset_index(drop=True), index=False).to_numpy().tobytes())
print(json.dumps({"read_observations_s": t_obs, "read_navigation_s": t_nav, "geometry_s": t_geo, "tables_sha256": h.hexdigest()}))
'''


def child(tree: str, c: dict, repeat: int) -> dict:
    env = {**os.environ, "PYTHONPATH": tree}
    arg = json.dumps({k: (str(v) if isinstance(v, Path) else [str(x) for x in v] if k == "navs" else v)
                      for k, v in c.items() if k in ("base", "rover", "navs", "signals", "base_xyz")})
    # cwd: ``python -c`` puts the working directory first on sys.path, before PYTHONPATH
    p = subprocess.run([sys.executable, "-c", CHILD, arg, str(repeat)], capture_output=True, text=True, env=env,
                       timeout=900, cwd=tree)
    if p.returncode != 0:
        raise SystemExit(f"{tree} on {c['name']}:\n{p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, help="the earlier source tree (its cdgps_cli/ is imported)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    trees = {"after": str(ROOT), "before": a.before}
    res = {"load_average_1min_at_start": round(os.getloadavg()[0], 2), "before_tree": a.before, "repeat": a.repeat,
           "rounds": a.rounds, "cases": {}}
    with tempfile.TemporaryDirectory() as d:
        for c in cases(Path(d)):
            runs = {k: [] for k in trees}
            for _ in range(a.rounds):
                for k, tree in trees.items():
                    runs[k].append(child(tree, c, a.repeat))
            row = {}
            for k in trees:
                for stage in ("read_observations_s", "read_navigation_s", "geometry_s"):
                    row[f"{stage[:-2]}_{k}_s"] = round(min(r[stage] for r in runs[k]), 4)
            for stage in ("read_observations", "read_navigation", "geometry"):
                row[f"{stage}_speed_up"] = round(row[f"{stage}_before_s"] / row[f"{stage}_after_s"], 2)
            row["identical_tables"] = len({r["tables_sha256"] for rs in runs.values() for r in rs}) == 1
            res["cases"][c["name"]] = row
            print(c["name"], json.dumps(row), flush=True)
    res["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print("wrote", a.out)


if __name__ == "__main__":
    main()
