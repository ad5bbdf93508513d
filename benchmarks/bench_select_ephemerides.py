#!/usr/bin/env python3
"""Ephemeris selection for every (satellite, epoch) row of a receiver: one ``select_ephemeris``
sub-frame per satellite concatenated and reordered (what ``estimation.rtk_multi`` did
before) against ``orbits.select_ephemerides`` (one row-position pass, one ``iloc``), on the shared
real pairs; least of ``--repeat`` interleaved calls, the tables compared for equality.  Writes
``docs/benchmarks/select_ephemerides.json``::

    PYTHONPATH=. python benchmarks/bench_select_ephemerides.py
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.model.gps.positioning import ephemeris_coverage
from cdgps_cli.model.gps.orbits import select_ephemeris, select_ephemerides
from cdgps_cli.pipeline import gnss_multi as gm


def _row_ephemerides(nav: pd.DataFrame, sats: np.ndarray, t: np.ndarray) -> pd.DataFrame:
    """The former way (rtk's until issue 28's speed work): one ``select_ephemeris`` sub-frame per
    satellite, concatenated and put back in row order — the reference the one-``iloc`` selection is timed against."""
    parts, order = [], []
    for sat, idx in pd.Series(sats).groupby(sats).indices.items():
        parts.append(select_ephemeris(nav, sat, t[idx]))
        order.append(idx)
    pos = np.empty(len(sats), dtype=np.int64)
    pos[np.concatenate(order)] = np.arange(len(sats))
    return pd.concat(parts, ignore_index=True).iloc[pos].reset_index(drop=True)


ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
CASES = {
    "mosaic-static base, G+R+E+C L1+L2": (SHARED / "real-pairs/mosaic-static/base.obs", [SHARED / "real-pairs/mosaic-static/base.nav"],
                                          ["G:L1", "G:L2", "R:G1", "R:G2", "E:E1", "E:E5b", "C:B1I", "C:B2I"]),
    "Spirent base, G+E L1+L2": (SHARED / "rinex-ge/Base-static_MO_Spirent.obs",
                                [SHARED / "rinex-ge/RINEX_GN_Spirent.23N", SHARED / "rinex-ge/RINEX_EN_Spirent.23L"],
                                ["G:L1", "G:L2", "E:E1", "E:E5b"]),
    "geonet-car base, G+E L1": (SHARED / "real-pairs/geonet-car/3034265G.21O", [SHARED / "real-pairs/geonet-car/SEPT2650.21P"],
                                ["G:L1", "E:E1"]),
}


def least(fn, repeat):
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return min(ts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "select_ephemerides.json")
    a = ap.parse_args()
    res = {"load_average_1min_at_start": round(os.getloadavg()[0], 2), "cases": {}}
    for name, (obs, navs, sigs) in CASES.items():
        nav = gm._nav(navs, sorted({s[0] for s in sigs}))
        glo = ({s: int(k) for s, k in nav.dropna(subset=["glonass_k"]).groupby("sat")["glonass_k"].first().items()}
               if "glonass_k" in nav.columns else {})
        df = gm._read_observations(obs, sigs, glo)[1]
        df = df[np.isfinite(df["pseudorange_m"])]
        df = df[ephemeris_coverage(nav, df["sat"].to_numpy(), df["time_gps_s"].to_numpy())]
        first = df.drop_duplicates(["time_gps_s", "sat"])
        sats, t = first["sat"].to_numpy(), first["time_gps_s"].to_numpy()
        a_ = _row_ephemerides(nav, sats, t)
        b_ = select_ephemerides(nav, sats, t)
        pd.testing.assert_frame_equal(a_, b_, check_exact=True)
        per_sat, one_take = [], []
        for _ in range(2):
            per_sat.append(least(lambda: _row_ephemerides(nav, sats, t), a.repeat))
            one_take.append(least(lambda: select_ephemerides(nav, sats, t), a.repeat))
        row = {"rows": int(len(sats)), "satellites": int(len(set(sats))), "per_satellite_subframes_s": round(min(per_sat), 4),
               "select_ephemerides_s": round(min(one_take), 4), "speed_up": round(min(per_sat) / min(one_take), 1),
               "identical": True}
        res["cases"][name] = row
        print(name, json.dumps(row), flush=True)
    res["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print("wrote", a.out)


if __name__ == "__main__":
    main()
