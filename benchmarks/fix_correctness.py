"""Fix correctness of ``cdgps rtk`` on real data: fixed epochs and wrong fixes where the answer is known.

Cases (../shared/data/real-pairs, see their READMEs):

* geonet-car G+E L1 (car, CORS 5.4 km, forward + backward combined): fixed epochs over the whole
  file (RTKLIB combined: 265, docs/benchmarks/rtk_rtklib.json) and, on the two standing segments
  (06:30:00-06:30:34 and 06:35:12-06:35:59), wrong fixes = fixed epochs more than 5 cm (3-D) from
  the README's static multi-GNSS answers;
* mosaic-static run kinematic (GPS L1 and G+E L1): wrong fixes = fixed epochs more than 5 cm from
  the baseline of the two position files;
* the same rover with a known 3 mm, 0.2 Hz motion added along a line of sight
  (tests/pipeline/test_vibration_real.py): fixed epochs more than 5 cm from the answer plus the motion;
* ublox-walk: the UBX log against its own RINEX conversion, a zero baseline (answer 0).

Run: ``PYTHONPATH=. python benchmarks/fix_correctness.py [--option key=value ...] [-o out.json]``;
results in docs/benchmarks/fix_correctness.json.
"""

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.pipeline.gnss_multi import rtk_from_files  # noqa: E402

SHARED = ROOT.parent / "shared" / "data" / "real-pairs"
CAR, MOSAIC = SHARED / "geonet-car", SHARED / "mosaic-static"
CAR_BASE = (-3959400.631, 3385704.533, 3667523.111)
CAR_START = (5083.057, 1707.376, -1.192)        # README: G+E+J L1+L2 static, start segment
CAR_END = (5049.078, 1691.873, -1.360)          # README: G+E+J L1 static, end segment fixed mean
MOSAIC_BASE = (-3817681.1213, 3562839.4311, 3650159.1593)
MOSAIC_ENU = (-0.2232, -0.9647, 0.0096)         # README: from the two position files
WALK_BASE = (-1276975.6547, -4717238.8712, 4087235.6076)   # its receiver's first NAV-PVT fix
WRONG_M = 0.05


def _run(base, rover, nav, base_xyz, signals, options, tmp):
    out = Path(tmp) / "sol.csv"
    s = rtk_from_files(base, rover, [nav], out, base_xyz_m=base_xyz, options={"signals": signals, **options})
    d = pd.read_csv(out, comment="#")
    return s, d


def _count(d, fixed_mask, ref_enu):
    enu = d[["e_m", "n_m", "u_m"]].to_numpy()
    dev = np.linalg.norm(enu - np.asarray(ref_enu), axis=-1)
    f = fixed_mask
    return int(f.sum()), int((f & (dev > WRONG_M)).sum()), float(dev[f].max()) if f.any() else float("nan")


def car(options, tmp):
    s, d = _run(CAR / "3034265G.21O", CAR / "SEPT265G.21O", CAR / "SEPT2650.21P", CAR_BASE, ("G:L1", "E:E1"), options, tmp)
    t = (d["time_gps_s"] - d["time_gps_s"].iloc[0]).to_numpy()
    fixed = d["fixed"].to_numpy() == 1
    a = _count(d, fixed & (t <= 34), CAR_START)
    b = _count(d, fixed & (t >= 312), CAR_END)
    return {"case": "geonet-car G+E L1", "epochs": s["epochs"], "fixed": s["fixed_epochs"], "rtklib_fixed": 265,
            "rejected": s["fixes_rejected"], "resets": s["wrong_fix_resets"], "start_fixed_of_35": a[0], "start_wrong": a[1], "start_max_dev_m": a[2],
            "end_fixed_of_48": b[0], "end_wrong": b[1], "end_max_dev_m": b[2]}


def mosaic(options, tmp, signals, rover=None, motion=None):
    s, d = _run(MOSAIC / "base.obs", rover or MOSAIC / "rover.obs", MOSAIC / "base.nav", MOSAIC_BASE, signals, options, tmp)
    fixed = d["fixed"].to_numpy() == 1
    if motion is not None:
        d[["e_m", "n_m", "u_m"]] -= motion(d["time_gps_s"].to_numpy())
    n, wrong, dev = _count(d, fixed, MOSAIC_ENU)
    return {"case": f"mosaic kinematic {'+'.join(signals)}" + (" + 3 mm vibration" if motion else ""),
            "epochs": s["epochs"], "fixed": n, "rtklib_fixed": 299 if signals == ("E:E1",) else 301, "wrong": wrong, "max_dev_m": dev,
            "rejected": s["fixes_rejected"], "resets": s["wrong_fix_resets"]}


def walk(options, tmp):
    """The u-blox walk's UBX log (base) against its own RINEX conversion (rover): a zero baseline, answer 0."""
    w = SHARED / "ublox-walk"
    out = Path(tmp) / "walk.csv"
    s = rtk_from_files(w / "gnss_1730.ubx", w / "gnss_1730_convbin.obs", [], out, base_xyz_m=WALK_BASE,
                       options={"signals": ("G:L1", "E:E1"), **options})
    d = pd.read_csv(out, comment="#")
    n, wrong, dev = _count(d, d["fixed"].to_numpy() == 1, (0.0, 0.0, 0.0))
    return {"case": "ublox-walk zero baseline G+E L1 (UBX base, RINEX rover)", "epochs": s["epochs"], "fixed": n,
            "wrong": wrong, "max_dev_m": dev, "rejected": s["fixes_rejected"], "resets": s["wrong_fix_resets"]}


def vibrated_rover(tmp):
    """The mosaic rover with tests/pipeline/test_vibration_real.py's motion; (path, motion(t) -> (n, 3) ENU m)."""
    from cdgps_cli.io.rinex import read_rinex_nav
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s, range_change_of_motion
    amp, f, az, el, t0 = 0.003, 0.2, math.radians(120.0), math.radians(30.0), 1403252400.0
    u = np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])
    text = (MOSAIC / "rover.obs").read_text()
    nav = pd.concat([read_rinex_nav(MOSAIC / "base.nav", systems=(s,)) for s in ("G", "E")], ignore_index=True)
    xyz = np.array(MOSAIC_BASE) + np.array([-0.2556, -0.6052, -0.7812])
    motion = range_change_of_motion(nav, xyz, lambda t: amp * math.sin(2 * math.pi * f * (t - t0)) * u,
                                    times_gps_s=epoch_times_gps_s(text))
    p = Path(tmp) / "rover_vib.obs"
    p.write_text(edit_rinex3_obs(text, range_change_m=motion))
    return p, lambda t: amp * np.sin(2 * np.pi * f * (t - t0))[:, None] * u


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--option", action="append", default=[], help="rtk option key=value (JSON value)")
    ap.add_argument("--cases", default="car,mosaic,vib,walk")
    ap.add_argument("-o", "--out")
    a = ap.parse_args(argv)
    options = {k: json.loads(v) for k, v in (o.split("=", 1) for o in a.option)}
    # without --option: the policy before issue 28 item 4 (no fix-and-hold) and the defaults now
    configs = {"given": options} if options else {"before (--no-fix-and-hold)": {"fix_and_hold": False}, "defaults": {}}
    result = {"wrong_fix_m": WRONG_M, "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name, opt in configs.items():
            rows = _cases(a.cases.split(","), opt, tmp)
            result["runs"][name] = {"options": opt, "cases": rows}
            for r in rows:
                print(name, json.dumps(r))
    if a.out:
        Path(a.out).write_text(json.dumps(result, indent=1) + "\n")


def _cases(cases, options, tmp):
    rows = []
    if "car" in cases:
        rows.append(car(options, tmp))
    if "mosaic" in cases:
        rows += [mosaic(options, tmp, s) for s in (("G:L1",), ("E:E1",), ("G:L1", "E:E1"))]
    if "walk" in cases:
        rows.append(walk(options, tmp))
    if "vib" in cases:
        p, motion = vibrated_rover(tmp)
        rows.append(mosaic(options, tmp, ("G:L1", "E:E1"), p, motion))
    return rows

if __name__ == "__main__":
    main()
