"""Multi-GNSS dual/triple-frequency RTK (estimation/rtk_multi.py) against truth and RTKLIB (issue 14 item 5).

    .venv/bin/python benchmarks/bench_multignss.py [--no-rtklib]

rinex-ge (Spirent simulation, GPS L1/L2/L5 + Galileo E1/E5a/E5b, 10 min 1 Hz): the static rover
2 km east in kinematic mode (fix rate, first fix, fixed-epoch error RMS) and in static mode
(static solution error), the moving rover in kinematic mode (3-D error RMS of fixed epochs against
Rover-dynamic_PVA_Spirent.csv); GEONET 3040 → 0759 static with L1 and with L1 + L2 (difference).
If ``rnx2rtkp`` (Debian package rtklib) is installed the same cases go through it with matching
settings (mask 15°, ratio 3, broadcast ephemerides, Saastamoinen, Klobuchar off: relative mode).
Results are printed as a markdown table (copied into docs/gnss-pipeline.md).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cdgps_cli.core.gps_time import SECONDS_PER_WEEK  # noqa: E402
from cdgps_cli.estimation.rtk_multi import receiver_geometry, solve_rtk  # noqa: E402
from cdgps_cli.io.rinex import read_rinex_nav  # noqa: E402
from cdgps_cli.io.rinex_signals import read_rinex_signals  # noqa: E402
from cdgps_cli.model.gps.orbits import ecef_to_enu  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
GE = DATA / "rinex-ge"
BASE_XYZ = np.array([4157177.06580187, 671230.476590636, 4774767.03105544])
STATIC_XYZ = np.array([4156857.1195929, 673209.028774142, 4774767.03105544])
SIG_GE = ["G:L1", "G:L2", "G:L5", "E:E1", "E:E5a", "E:E5b"]


def _truth_dynamic(t_gps_s):
    df = pd.read_csv(GE / "Rover-dynamic_PVA_Spirent.csv")
    tt = (df["GpsCycle"].to_numpy() * 1024 + df["GpsWeek"].to_numpy()) * SECONDS_PER_WEEK + df["GpsToW [s]"].to_numpy()
    cols = ["Pos ECEF X [m]", "Pos ECEF Y [m]", "Pos ECEF Z [m]"]
    return np.stack([np.interp(t_gps_s, tt, df[c].to_numpy()) for c in cols], axis=1)


def _figures(t, xyz, fixed, truth):
    """fix %, first fix (s), H/V RMS of fixed epochs (mm) against truth (n, 3) or (3,)."""
    tr = np.broadcast_to(truth, xyz.shape)
    e = np.array([ecef_to_enu(x, r) for x, r in zip(xyz[fixed], tr[fixed])]) if fixed.any() else np.zeros((0, 3))
    h = 1e3 * np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)) if len(e) else np.nan
    v = 1e3 * np.sqrt(np.mean(e[:, 2] ** 2)) if len(e) else np.nan
    d3 = 1e3 * np.sqrt(np.mean(np.sum(e**2, axis=1))) if len(e) else np.nan
    first = t[np.argmax(fixed)] - t[0] if fixed.any() else np.nan
    return {"fix_pct": 100 * fixed.mean(), "first_fix_s": first, "h_rms_mm": h, "v_rms_mm": v, "rms3d_mm": d3}


def _ge_nav():
    return pd.concat([read_rinex_nav(GE / "RINEX_GN_Spirent.23N"), read_rinex_nav(GE / "RINEX_EN_Spirent.23L", systems=("E",))],
                     ignore_index=True)


def cdgps_cases() -> dict:
    nav = _ge_nav()
    _, b = read_rinex_signals(GE / "Base-static_MO_Spirent.obs", SIG_GE)
    gb = receiver_geometry(b, nav, BASE_XYZ)
    out = {}
    for name, f in (("static", "Rover-static-2km-east_MO_Spirent.obs"), ("dynamic", "Rover-dynamic_MO_Spirent.obs")):
        h, r = read_rinex_signals(GE / f, SIG_GE)
        x0 = np.asarray(h["approx_position_xyz_m"])
        gr = receiver_geometry(r, nav, x0)
        t0 = time.perf_counter()
        res = solve_rtk(gb, gr, BASE_XYZ, x0, options={"mode": "kinematic"})
        sec = time.perf_counter() - t0
        truth = STATIC_XYZ if name == "static" else _truth_dynamic(res["time_gps_s"])
        out[f"{name} kinematic"] = {**_figures(res["time_gps_s"], res["fixed_xyz_m"], res["fixed"], truth), "solve_s": sec}
        if name == "static":
            st = solve_rtk(gb, gr, BASE_XYZ, x0, options={"mode": "static"})
            out["static static"] = {"static_err_mm": 1e3 * float(np.linalg.norm(st["static_xyz_m"] - STATIC_XYZ)),
                                    "fixed_end": bool(st["fixed"][-1])}
    return out


def geonet_case() -> dict:
    d = DATA / "rinex"
    nav = pd.concat([read_rinex_nav(d / "30400920.05n"), read_rinex_nav(d / "07590920.05n")], ignore_index=True)
    nav = nav.drop_duplicates(["sat", "toe_gps_s"]).reset_index(drop=True)
    sols = {}
    for sig in (["G:L1"], ["G:L1", "G:L2"]):
        hb, b = read_rinex_signals(d / "30400920.05o", sig)
        hr, r = read_rinex_signals(d / "07590920.05o", sig)
        bx, rx = np.asarray(hb["approx_position_xyz_m"]), np.asarray(hr["approx_position_xyz_m"])
        res = solve_rtk(receiver_geometry(b, nav, bx), receiver_geometry(r, nav, rx), bx, rx, options={"mode": "static"})
        sols["+".join(sig)] = (res["static_xyz_m"], bool(res["fixed"][-1]), int(res["n_dd_ambiguities"][-1]))
    a, b_ = sols["G:L1"][0], sols["G:L1+G:L2"][0]
    return {"L1 fixed": sols["G:L1"][1], "L1+L2 fixed": sols["G:L1+G:L2"][1], "L1+L2 n_dd": sols["G:L1+G:L2"][2],
            "L1 vs L1+L2 mm": 1e3 * float(np.linalg.norm(a - b_)), "L1_xyz": a.tolist(), "L1L2_xyz": b_.tolist()}


def _rtklib(rover: Path, mode: str, freqs: int, base: Path, navs, ref_xyz, systems="G,E") -> pd.DataFrame:
    with tempfile.TemporaryDirectory() as tmp:
        conf = Path(tmp) / "opt.conf"
        conf.write_text("\n".join([f"pos1-posmode={mode}", f"pos1-frequency={ {1: 'l1', 2: 'l1+l2', 3: 'l1+l2+l5'}[freqs] }",
                                   "pos1-elmask=15", "pos1-tropopt=saas", "pos1-ionoopt=off", "pos2-armode=continuous",
                                   "pos2-arthres=3", "pos1-navsys=" + ("9" if systems == "G,E" else "1"), "out-solformat=xyz", "out-timeform=tow", "out-timesys=gpst",
                                   "ant2-postype=xyz", "ant2-pos1=%.4f" % ref_xyz[0], "ant2-pos2=%.4f" % ref_xyz[1],
                                   "ant2-pos3=%.4f" % ref_xyz[2], ""]))
        out = Path(tmp) / "out.pos"
        subprocess.run(["rnx2rtkp", "-k", str(conf), "-o", str(out), str(rover), str(base), *map(str, navs)],
                       check=True, capture_output=True, timeout=600)
        rows = [ln.split() for ln in out.read_text().splitlines() if ln and not ln.startswith("%")]
    df = pd.DataFrame([(float(r[0]) * SECONDS_PER_WEEK + float(r[1]), float(r[2]), float(r[3]), float(r[4]), int(r[5])) for r in rows],
                      columns=["t", "x", "y", "z", "q"])
    return df


def rtklib_cases() -> dict:
    navs = [GE / "RINEX_GN_Spirent.23N", GE / "RINEX_EN_Spirent.23L"]
    out = {}
    for name, f in (("static", "Rover-static-2km-east_MO_Spirent.obs"), ("dynamic", "Rover-dynamic_MO_Spirent.obs")):
        t0 = time.perf_counter()
        df = _rtklib(GE / f, "kinematic", 3, GE / "Base-static_MO_Spirent.obs", navs, BASE_XYZ)
        sec = time.perf_counter() - t0
        xyz, t = df[["x", "y", "z"]].to_numpy(), df["t"].to_numpy()
        truth = STATIC_XYZ if name == "static" else _truth_dynamic(t)
        out[f"{name} kinematic"] = {**_figures(t, xyz, df["q"].to_numpy() == 1, truth), "solve_s": sec}
    df = _rtklib(GE / "Rover-static-2km-east_MO_Spirent.obs", "static", 3, GE / "Base-static_MO_Spirent.obs", navs, BASE_XYZ)
    out["static static"] = {"static_err_mm": 1e3 * float(np.linalg.norm(df[["x", "y", "z"]].to_numpy()[-1] - STATIC_XYZ)),
                            "fixed_end": bool(df["q"].iloc[-1] == 1)}
    return out


def main() -> None:
    res = {"cdgps": cdgps_cases()}
    if "--no-rtklib" not in sys.argv and shutil.which("rnx2rtkp"):
        res["rtklib rnx2rtkp"] = rtklib_cases()
    else:
        print("rnx2rtkp not installed (apt-get install rtklib): RTKLIB column left out")
    for eng, cases in res.items():
        for case, figs in cases.items():
            print(f"| {eng} | {case} | " + ", ".join(f"{k}={v:.2f}" if isinstance(v, float) else f"{k}={v}" for k, v in figs.items()) + " |")
    g = geonet_case()
    print("GEONET 3040→0759 static:", {k: (round(v, 2) if isinstance(v, float) else v) for k, v in g.items() if "xyz" not in k})


if __name__ == "__main__":
    main()
