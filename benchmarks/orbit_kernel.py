#!/usr/bin/env python3
"""The orbit kernel (cdgps_cli.model.gps._orbitcore) against the numpy code it replaces, on a day of rows.

Rows: every satellite with a healthy ephemeris above 10° at one receiver, every ``--step`` seconds of ``--hours``
hours from the first toe + 2 h of a RINEX navigation file (``--nav``, e.g. the 24 h GNSS pair's nav.rnx; default
a synthetic GPS constellation), as a receiver's rows (the 24 h pair's receiver has 868 058).  In one
process, alternately with the kernel and with ``CDGPS_NO_KERNEL=1`` (numpy), ``--rounds`` times, each
measured in thread CPU time (the machine may be shared), the least kept:

* ``reception``: ``sat_positions_at_reception`` of all rows (light time, Kepler per satellite block), as one pass
  of ``positioning.estimate_receiver_clock``;
* ``rows``: ``sat_position_rows`` of all rows at three times (``rtk_multi.receiver_geometry``'s three calls);
* ``clock``: ``estimate_receiver_clock`` itself (three passes of orbits, elevation and troposphere), from
  pseudoranges made of the geometric range and a receiver clock.

Every output of the two paths is compared byte for byte.  Writes ``--out`` (JSON)::

    python benchmarks/orbit_kernel.py --nav /tmp/gnss-24h/nav.rnx --out docs/benchmarks/orbit_kernel.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.model.gps import orbits
from cdgps_cli.model.gps.positioning import ephemeris_coverage, estimate_receiver_clock, synthetic_gps_nav

RX = np.array([-3961904.0, 3348993.0, 3698211.0])


def _rows(nav, hours: float, step: float):
    """(satellites, times) of every covered satellite above 10° at RX every ``step`` s, epoch by epoch."""
    t0 = float(nav["toe_gps_s"].min()) + 7200.0
    t = t0 + np.arange(0.0, hours * 3600.0, step)
    sats = np.array(sorted(nav["sat"].unique()), dtype=object)
    s, tt = np.repeat(sats, t.size), np.tile(t, sats.size)
    ok = ephemeris_coverage(nav, s, tt)
    s, tt = s[ok], tt[ok]
    up = orbits.elevation(RX, orbits.sat_position_rows(orbits.ephemeris_rows(nav, s, tt), tt)[0]) > np.radians(10.0)
    order = np.argsort(tt[up], kind="stable")
    return s[up][order], tt[up][order]


def _digest(arrays) -> str:
    return hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in arrays)).hexdigest()[:16]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nav", type=Path)
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--step", type=float, default=1.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    if not orbits.kernel_available():
        raise SystemExit("the compiled orbit kernel is not available (build it, unset CDGPS_NO_KERNEL)")
    nav = read_rinex_nav(a.nav) if a.nav else synthetic_gps_nav(1_300_000_000.0, a.hours * 3600.0 + 14400.0)
    sats, t = _rows(nav, a.hours, a.step)
    eph = orbits.reception_ephemeris(nav, sats, t)
    rows_eph = orbits.ephemeris_rows(nav, sats, t)
    g = orbits.sat_positions_at_reception(nav, sats, t, RX, ephemeris=eph)
    epoch = np.unique(t, return_inverse=True)[1].reshape(-1)
    clk_rx = 3e-4 + 1e-3 * np.sin(np.arange(epoch.max() + 1) / 5000.0)
    pr = g.range_m - SPEED_OF_LIGHT_M_S * g.clock_s + SPEED_OF_LIGHT_M_S * clk_rx[epoch]
    cases = {
        "reception": lambda: tuple(orbits.sat_positions_at_reception(nav, sats, t, RX, rx_clock_s=clk_rx[epoch],
                                                                     ephemeris=eph)),
        "rows": lambda: tuple(x for dt in (0.075, 0.0712345, 0.0712344)
                              for x in orbits.sat_position_rows(rows_eph, t - dt)),
        "clock": lambda: (estimate_receiver_clock(epoch, sats, t, pr, nav, RX),),
    }
    cpu = {k: {"kernel": [], "numpy": []} for k in cases}
    digests = {k: set() for k in cases}
    for _ in range(a.rounds):
        for name, fn in cases.items():
            for path in ("numpy", "kernel"):
                os.environ["CDGPS_NO_KERNEL"] = "1" if path == "numpy" else ""
                c0 = time.thread_time()
                out = fn()
                cpu[name][path].append(round(time.thread_time() - c0, 3))
                digests[name].add(_digest(out))
    os.environ["CDGPS_NO_KERNEL"] = ""
    res = {"rows": int(t.size), "satellites": int(len(set(sats))), "hours": a.hours, "step_s": a.step,
           "nav": str(a.nav) if a.nav else "synthetic GPS", "rounds": a.rounds,
           "load_1min_end": round(os.getloadavg()[0], 2), "machine": platform.machine(), "cases": {}}
    for name in cases:
        n, k = min(cpu[name]["numpy"]), min(cpu[name]["kernel"])
        res["cases"][name] = {"numpy_cpu_s": n, "kernel_cpu_s": k, "ratio": round(n / k, 2),
                              "numpy_rounds": cpu[name]["numpy"], "kernel_rounds": cpu[name]["kernel"],
                              "identical": len(digests[name]) == 1}
        print(f"{name:9s} numpy {n:7.3f} s  kernel {k:7.3f} s  x{n / k:5.2f}  identical {len(digests[name]) == 1}")
    if a.out:
        a.out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
