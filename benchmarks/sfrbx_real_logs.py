#!/usr/bin/env python3
"""What real u-blox logs' RXM-SFRBX frames give (issue 14 item 3): frame counts per system and signal,
decode statistics, records, and the agreement of consecutive records of one satellite (each evaluated
at the instant between their t_oe; broadcast orbits agree to a few metres) — a real-data check for logs
without RXM-RAWX pseudoranges.

    python benchmarks/sfrbx_real_logs.py LOG [LOG …] [--week W]

The GPS week dates GPS/Galileo records: RXM-RAWX's, else ``--week``, else the BeiDou records' BDT week
+ 1356 (a log with BeiDou D1 dates itself).  Logs used in docs/gnss-pipeline.md: pygnssutils
examples/pygpsdata-rxmsfrbx.log and tests/pygpsdata_testobsnavdata.log (BSD-3), gpsd
test/daemon/ublox-glo.log and ublox-ned-m8t-sbfrx3.log (BSD-2).
"""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.io.sfrbx import sfrbx_ephemerides  # noqa: E402
from cdgps_cli.io.ubx_frames import split_stream  # noqa: E402
from cdgps_cli.model.gps.orbits import sat_position_ecef  # noqa: E402


def consecutive_agreement(nav) -> dict:
    """Per system: max and median |Δx| (m) of consecutive records at their mid time, and the count."""
    out = collections.defaultdict(list)
    for sat, g in nav.groupby("sat"):
        g = g.drop_duplicates("toe_gps_s").sort_values("toe_gps_s").reset_index(drop=True)
        for i in range(len(g) - 1):
            tm = 0.5 * (g["toe_gps_s"][i] + g["toe_gps_s"][i + 1])
            a, _ = sat_position_ecef(g.iloc[i], tm)
            b, _ = sat_position_ecef(g.iloc[i + 1], tm)
            out[sat[0]].append(float(np.linalg.norm(a - b)))
    return {k: {"pairs": len(v), "median_m": float(np.median(v)), "max_m": float(np.max(v))} for k, v in out.items()}


def one_log(path: Path, week: int | None) -> dict:
    ubx, _, _ = split_stream(path.read_bytes())
    kinds = collections.Counter()
    for _, c, m, fr in ubx:
        pl = fr[6:-2]
        if (c, m) == (0x02, 0x13):
            kinds[f"gnss{pl[0]}/sig{pl[2]}/{pl[4]}w"] += 1
        elif (c, m) == (0x02, 0x15) and week is None:
            week = int.from_bytes(pl[8:10], "little")
    nav, st = sfrbx_ephemerides(ubx, week, glonass=True)
    if week is None and (nav["sat"].str[0] == "C").any():
        week = int(nav.loc[nav["sat"].str[0] == "C", "week"].iloc[0]) + 1356
        nav, st = sfrbx_ephemerides(ubx, week, glonass=True)
    return {"log": path.name, "week": week, "frames": dict(sorted(kinds.items())), "stats": st,
            "records": nav.groupby(nav["sat"].str[0])["sat"].agg(["count", "nunique"]).to_dict("index") if len(nav) else {},
            "consecutive": consecutive_agreement(nav) if len(nav) else {}}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("logs", nargs="+", type=Path)
    ap.add_argument("--week", type=int, default=None)
    a = ap.parse_args(argv)
    for p in a.logs:
        r = one_log(p, a.week)
        print(f"{r['log']}: week {r['week']}")
        print(f"  SFRBX frames (gnssId/sigId/words): {r['frames']}")
        print(f"  decode: { {k: v for k, v in r['stats'].items() if v} }")
        print(f"  records (count, satellites) per system: {r['records']}")
        for k, v in r["consecutive"].items():
            print(f"  consecutive records {k}: {v['pairs']} pairs, |dx| median {v['median_m']:.2f} m, max {v['max_m']:.2f} m")


if __name__ == "__main__":
    main()
