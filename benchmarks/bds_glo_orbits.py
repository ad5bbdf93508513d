"""Consistency of BeiDou and GLONASS broadcast orbits between consecutive records (issue 14 items 1-2).

For every satellite of the navigation file(s) with two records less than 2 h (BeiDou) / 30 min
(GLONASS) apart, both records are evaluated at the instant between their reference times and the
3-D distance printed; for GLONASS also the distance between the state integrated over the full
interval and the next record's broadcast state.  Usage:

    .venv/bin/python benchmarks/bds_glo_orbits.py [NAV ...]      # default: the tests/data subsets
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from cdgps_cli.io.rinex import read_rinex_nav  # noqa: E402
from cdgps_cli.model.gps.glonass_orbit import glonass_position  # noqa: E402
from cdgps_cli.model.gps.orbits import BEIDOU_GEO_PRNS, sat_position_ecef  # noqa: E402

STATE = ["x_m", "y_m", "z_m", "vx_m_per_s", "vy_m_per_s", "vz_m_per_s"]
ACCEL = ["ax_m_per_s2", "ay_m_per_s2", "az_m_per_s2"]


def _pairs(nav, sat, max_gap_s):
    recs = nav[nav["sat"] == sat].sort_values("toe_gps_s")
    for k in range(len(recs) - 1):
        a, b = recs.iloc[k], recs.iloc[k + 1]
        if 0 < b["toe_gps_s"] - a["toe_gps_s"] <= max_gap_s:
            yield a, b


def main(paths):
    for path in paths:
        nav = read_rinex_nav(path, systems=("C", "R"))
        print(f"# {Path(path).name}")
        print("sat  kind  dt_s  midpoint_gap_m  integrated_to_next_m")
        for sat in sorted(nav["sat"].unique()):
            kind = ("GEO" if int(sat[1:]) in BEIDOU_GEO_PRNS else "MEO/IGSO") if sat[0] == "C" else "GLONASS"
            for a, b in _pairs(nav, sat, 7200.0 if sat[0] == "C" else 1800.0):
                t = 0.5 * (a["toe_gps_s"] + b["toe_gps_s"])
                gap = float(np.linalg.norm(sat_position_ecef(a, t)[0] - sat_position_ecef(b, t)[0]))
                full = ""
                if sat[0] == "R":
                    end = glonass_position(a[STATE].to_numpy(float)[None], a[ACCEL].to_numpy(float)[None],
                                           [b["toe_gps_s"] - a["toe_gps_s"]])[0]
                    full = f"{np.linalg.norm(end[:3] - b[STATE].to_numpy(float)[:3]):.2f}"
                print(f"{sat}  {kind:8s} {b['toe_gps_s'] - a['toe_gps_s']:6.0f}  {gap:8.2f}  {full}")


if __name__ == "__main__":
    args = sys.argv[1:] or [str(REPO / "tests" / "data" / "MOJN00DNK_R_20201770000_subset.rnx"),
                            str(REPO / "tests" / "data" / "BRDM00DLR_R_20130010000_01D_MN.rnx")]
    main(args)
