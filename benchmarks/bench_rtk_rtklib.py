"""`cdgps rtk` side by side with RTKLIB's `rnx2rtkp` on the same files, in one run (issue 28 item 6).

For each case both programs run as whole processes (wall clock from start to exit, median of
``--repeats``), with the same signals, elevation mask (15°), ratio threshold (3), base position and
navigation files; RTKLIB gets an explicit ``-k`` options file (``pos1-navsys`` for the systems —
Debian's ``-sys`` switch turns on other systems too — and ``pos1-frequency`` l1 or l1+l2: the
Debian build refuses l1+l2+l5) and combined forward/backward processing (``-c``) like our default.
The peer failing (non-zero exit, no solution lines) stops the benchmark with its stderr; a missing
``rnx2rtkp`` stops it too unless ``--no-rtklib``.  ``--before TREE`` times another source tree's
``cdgps rtk`` in the same rounds (before/after figures; its solution lines must be identical);
``--out FILE`` writes elsewhere than the default.

Figures per case: epochs and fixed epochs of each, seconds per epoch of each whole process (rounds
interleaved: cdgps, rnx2rtkp, cdgps, ...; medians) and
their ratio both ways (ours / RTKLIB, < 1: we are faster; and RTKLIB / ours), the difference of the fixed-epoch means (ENU,
mm; a static rover's figure) and, epoch by epoch where both fixed, the median and largest 3-D difference (mm).  Writes ``docs/benchmarks/rtk_rtklib.json``.

cdgps runs as on a user's machine: with bytecode caches (the environment without
``PYTHONDONTWRITEBYTECODE``, which a development shell may set: every run would recompile our
modules, ≈ 0.3 s) and after one untimed warm-up run per case that writes them; rnx2rtkp is timed as
before (no warm-up).  The start-up floor — the interpreter, ``import numpy``, ``import numpy,
pandas``, and the import of the rtk path — is measured the same way (``startup_floor``, the least
of several runs), and each
case also gives its ratio with our import time taken off (``speed_ratio_per_epoch_after_imports``).

Cases: the real Septentrio pair (mosaic-static) GPS L1 and multi-GNSS L1+L2; the same pair with a
u-blox-like base (a quarter of its epochs, ms clock steering; sim/rinex_edit); GEONET 0759→3040
GPS L1+L2; the Spirent GPS+Galileo set (2 km static rover) L1+L2; the car against a CORS 5 km
away (geonet-car) GPS+Galileo L1; the u-blox walk's UBX log as base against its own RINEX conversion
(zero baseline; RTKLIB reads the conversion on both sides).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
CDGPS = str(Path(sys.executable).parent / "cdgps")
OUT = ROOT / "docs" / "benchmarks" / "rtk_rtklib.json"
NAVSYS = {"G": 1, "R": 4, "E": 8, "C": 32}


def _case(name, base, rover, navs, base_xyz, signals, freq, rtklib_base=None, rtklib_navs=None):
    """A case; ``rtklib_base`` / ``rtklib_navs``: RTKLIB's inputs where ours are a u-blox log it cannot read."""
    return {"name": name, "base": base, "rover": rover, "navs": navs, "base_xyz": base_xyz, "signals": signals, "freq": freq,
            "rtklib_base": rtklib_base or base, "rtklib_navs": navs if rtklib_navs is None else rtklib_navs}


def cases(tmp: Path) -> list:
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs  # noqa: PLC0415

    ms = SHARED / "real-pairs" / "mosaic-static"
    ms_xyz = (-3817681.1213, 3562839.4311, 3650159.1593)
    rng = np.random.default_rng(7)
    keep, t = set(), 1403252400
    while t <= 1403252700:
        keep.add(t)
        t += int(rng.integers(1, 9))
    gappy = tmp / "base_gappy.obs"
    gappy.write_text(edit_rinex3_obs((ms / "base.obs").read_text(), keep=lambda t: round(t) in keep,
                                     clock_offset_s=lambda t: -0.010 + 0.001 * ((round(t) // 7) % 2)))
    rover_ms = tmp / "rover_ms.obs"
    rover_ms.write_text(edit_rinex3_obs((ms / "rover.obs").read_text(),
                                        clock_offset_s=lambda t: -0.009 + 0.001 * ((round(t) // 5) % 2)))
    ge = SHARED / "rinex-ge"
    car = SHARED / "real-pairs" / "geonet-car"
    geo = SHARED / "rinex"
    walk = SHARED / "real-pairs" / "ublox-walk"
    multi = ("G:L1", "G:L2", "R:G1", "R:G2", "E:E1", "E:E5b", "C:B1I", "C:B2I")
    return [
        _case("mosaic-static GPS L1", ms / "base.obs", ms / "rover.obs", [ms / "base.nav"], ms_xyz, ("G:L1",), 1),
        _case("mosaic-static G+R+E+C L1+L2", ms / "base.obs", ms / "rover.obs", [ms / "base.nav"], ms_xyz, multi, 2),
        _case("mosaic-static, u-blox-like gappy base, GPS L1", gappy, rover_ms, [ms / "base.nav"], ms_xyz, ("G:L1",), 1),
        _case("GEONET 0759-3040 GPS L1+L2", geo / "07590920.05o", geo / "30400920.05o", [geo / "07590920.05n"],
              None, ("G:L1", "G:L2"), 2),
        _case("Spirent 2 km static G+E L1+L2", ge / "Base-static_MO_Spirent.obs", ge / "Rover-static-2km-east_MO_Spirent.obs",
              [ge / "RINEX_GN_Spirent.23N", ge / "RINEX_EN_Spirent.23L"], (4157177.06580187, 671230.476590636, 4774767.03105544),
              ("G:L1", "G:L2", "E:E1", "E:E5b"), 2),
        _case("geonet-car G+E L1", car / "3034265G.21O", car / "SEPT265G.21O", [car / "SEPT2650.21P"],
              (-3959400.631, 3385704.533, 3667523.111), ("G:L1", "E:E1"), 1),
        # the u-blox reader on the rtk path: the walk's UBX log (RXM-RAWX, SFRBX ephemerides) against its own
        # RINEX conversion, a zero baseline; RTKLIB gets the conversion on both sides and its navigation file
        _case("ublox-walk zero baseline, UBX base, G+E L1", walk / "gnss_1730.ubx", walk / "gnss_1730_convbin.obs", [],
              (-1276975.6547, -4717238.8712, 4087235.6076), ("G:L1", "E:E1"), 1,
              rtklib_base=walk / "gnss_1730_convbin.obs", rtklib_navs=[walk / "gnss_1730_convbin.nav"]),
        *_m8p_cases(),
        *_f9p_cases(),
    ]


def _m8p_cases() -> list:
    """``--m8p DIR``: issue 28's u-blox M8P pair (jdesbonnet/GNSS_RTK_data 20181004, no licence: fetched locally;
    DIR holds convbin's base1.obs, rover1.obs, base1.nav and the OSi CORS glw1277m.18o / .18n of its zip) and the
    CORS to the M8P base and to its rover (196 m, a CORS-to-u-blox pair as issue 28's held-out one), GPS L1, the base
    position process1.sh gives RTKLIB."""
    if "--m8p" not in sys.argv:
        return []
    d = Path(sys.argv[sys.argv.index("--m8p") + 1])
    out = [_case("u-blox M8P pair GPS L1", d / "base1.obs", d / "rover1.obs", [d / "base1.nav"],
                 (3774090.1382928407, -601663.0449456355, 5089319.199168801), ("G:L1",), 1)]
    if (d / "glw1277m.18o").exists():
        out.append(_case("CORS GLW1 to the M8P base GPS L1", d / "glw1277m.18o", d / "base1.obs", [d / "glw1277m.18n"],
                         _header_xyz(d / "glw1277m.18o"), ("G:L1",), 1))
        out.append(_case("CORS GLW1 to the M8P rover GPS L1", d / "glw1277m.18o", d / "rover1.obs", [d / "glw1277m.18n"],
                         _header_xyz(d / "glw1277m.18o"), ("G:L1",), 1))
    return out


def _f9p_cases() -> list:
    """``--f9p DIR``: a real static F9P-class pair 1.23 km apart, 15 s, 4 h (geofis/ppk at 9d6602d, GPL-3.0: fetched
    locally; DIR is its ``example-rinex`` folder, base/ and rover/ each with the convbin RINEX 3.04 of 2022-02-25),
    G+E+C L1 and L1 + L2, the base at its header position."""
    if "--f9p" not in sys.argv:
        return []
    d = Path(sys.argv[sys.argv.index("--f9p") + 1])
    base, rover = d / "base" / "2022-02-25_00-00-00_GNSS-1.obs", d / "rover" / "2022-02-25_13-26-06_GNSS-1.obs"
    navs = [d / "base" / "2022-02-25_00-00-00_GNSS-1.nav"]
    return [_case("F9P pair 1.2 km G+E+C L1", base, rover, navs, _header_xyz(base), ("G:L1", "E:E1", "C:B1I"), 1),
            _case("F9P pair 1.2 km G+E+C L1+L2", base, rover, navs, _header_xyz(base),
                  ("G:L1", "G:L2", "E:E1", "E:E5b", "C:B1I"), 2)]


def _header_xyz(path: Path):
    for ln in path.read_text(errors="replace").splitlines():
        if ln[60:].strip() == "APPROX POSITION XYZ":
            return tuple(float(x) for x in ln[:60].split())
    raise SystemExit(f"{path}: no APPROX POSITION XYZ")


#: the environment of the cdgps runs: a user's, with bytecode caches
USER_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def _timed(cmd, env=None) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, env=env)
    return time.perf_counter() - t0, p


def startup_floor(repeats: int) -> dict:
    """Wall time (s) of the interpreter alone, of ``import numpy``, of ``import numpy, pandas`` and of
    importing the rtk path (CLI and pipeline modules), in :data:`USER_ENV`: the least of
    ``max(repeats, 7)`` runs taken in turn (a floor: a busy machine only adds to it).  The BLAS gets
    one thread, as ``cdgps_cli/__init__.py`` sets before numpy is imported (a thread pool's start
    costs a numpy import ≈ 0.04 s here)."""
    env = {**USER_ENV, **{v: USER_ENV.get(v, "1") for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}}
    imports = {"python_s": "pass", "import_numpy_s": "import numpy", "import_numpy_pandas_s": "import numpy, pandas",
               "import_cdgps_rtk_path_s": "import cdgps_cli.cli.commands, cdgps_cli.pipeline.gnss_multi"}
    times = {key: [] for key in imports}
    for code in imports.values():
        _timed([sys.executable, "-c", code], env)                           # warm-up: bytecode caches written
    for _ in range(max(repeats, 7)):
        for key, code in imports.items():
            times[key].append(_timed([sys.executable, "-c", code], env)[0])
    return {key: min(v) for key, v in times.items()}


def rtklib_command(c, tmp: Path) -> tuple[list, Path, Path]:
    """(command, options file, output) of rnx2rtkp on case ``c``; the options file is written."""
    systems = sorted({s[0] for s in c["signals"]})
    xyz = c["base_xyz"] or _header_xyz(c["base"])
    conf = tmp / "rtklib.conf"
    conf.write_text("\n".join([
        "pos1-posmode=kinematic", f"pos1-frequency={'l1' if c['freq'] == 1 else 'l1+l2'}", "pos1-soltype=combined",
        "pos1-elmask=15", "pos1-tropopt=saas", "pos1-ionoopt=off", f"pos1-navsys={sum(NAVSYS[s] for s in systems)}",
        "pos2-armode=continuous", "pos2-arthres=3", "pos2-gloarmode=off", "out-solformat=xyz", "out-timesys=gpst",
        "ant2-postype=xyz", *(f"ant2-pos{i + 1}={v:.4f}" for i, v in enumerate(xyz)), ""]))
    out = tmp / "rtklib.pos"
    return ["rnx2rtkp", "-k", str(conf), "-o", str(out), str(c["rover"]), str(c["rtklib_base"]),
            *map(str, c["rtklib_navs"])], conf, out


def run_rtklib_once(c, cmd, conf: Path, out: Path) -> tuple[float, list]:
    """One timed rnx2rtkp run: (seconds, solution rows); SystemExit with its stderr when it fails."""
    if out.exists():
        out.unlink()
    sec, p = _timed(cmd)
    rows = [ln.split() for ln in out.read_text().splitlines() if ln.strip() and not ln.startswith("%")] if out.exists() else []
    if p.returncode != 0 or not rows:
        raise SystemExit(f"rnx2rtkp failed on {c['name']} (exit {p.returncode}, {len(rows)} solution lines):\n"
                         f"{p.stderr[-2000:]}\noptions:\n{conf.read_text()}")
    return sec, rows


def cdgps_command(c, tmp: Path) -> tuple[list, Path]:
    out = tmp / "cdgps.csv"
    cmd = [CDGPS, "-q", "rtk", "--base", str(c["base"]), "--rover", str(c["rover"]), *sum((["--nav", str(n)] for n in c["navs"]), []),
           "--signals", ",".join(c["signals"]), "-o", str(out), "--json"]
    if c["base_xyz"]:
        cmd += ["--base-xyz", *map(str, c["base_xyz"])]
    return cmd, out


def run_cdgps_once(c, cmd) -> tuple[float, subprocess.CompletedProcess]:
    sec, p = _timed(cmd, USER_ENV)
    if p.returncode != 0:
        raise SystemExit(f"cdgps rtk failed on {c['name']}:\n{p.stderr[-2000:]}")
    return sec, p


def _gpst_s(day: str, clock: str) -> float:
    """Seconds of GPS time of an rnx2rtkp solution line's ``yyyy/mm/dd hh:mm:ss.sss`` (out-timesys=gpst)."""
    from datetime import datetime  # noqa: PLC0415

    d = datetime.strptime(day, "%Y/%m/%d") - datetime(1980, 1, 6)
    h, m, sec = clock.split(":")
    return d.days * 86400.0 + 3600.0 * int(h) + 60.0 * int(m) + float(sec)


def _solution_body(path: Path) -> list:
    """The solution lines of a cdgps CSV without its comment header (which names the output file)."""
    return [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]


def run_case(c, tmp: Path, repeats: int, peer: bool, before: str | None = None) -> dict:
    """Both programs on case ``c`` in interleaved rounds (cdgps, rnx2rtkp, cdgps, ...), after one untimed
    cdgps warm-up; medians of ``repeats`` rounds.  ``before``: another source tree (PYTHONPATH) whose
    ``cdgps rtk`` takes its turn in each round too (``cdgps_before_s``; its CSV must be identical)."""
    cmd_c, out_c = cdgps_command(c, tmp)
    _timed(cmd_c, USER_ENV)                              # untimed warm-up: bytecode caches, as on a user's machine
    if peer:
        cmd_r, conf, out_r = rtklib_command(c, tmp)
    if before:
        env_b = {**USER_ENV, "PYTHONPATH": before}
        cmd_b = [x if x != str(out_c) else str(out_c) + ".before.csv" for x in cmd_c]
        _timed(cmd_b, env_b)
    t_c, t_r, t_b = [], [], []
    for _ in range(repeats):
        sec, p = run_cdgps_once(c, cmd_c)
        t_c.append(sec)
        if peer:
            sec, rows = run_rtklib_once(c, cmd_r, conf, out_r)
            t_r.append(sec)
        if before:
            sec, pb = _timed(cmd_b, env_b)
            if pb.returncode != 0:
                raise SystemExit(f"cdgps rtk of {before} failed on {c['name']}:\n{pb.stderr[-2000:]}")
            t_b.append(sec)
    import pandas as pd  # noqa: PLC0415

    d = pd.read_csv(out_c, comment="#")
    res = {"cdgps_s": statistics.median(t_c), "cdgps_xyz": d[["x_m", "y_m", "z_m"]].to_numpy(),
           "cdgps_t": d["time_gps_s"].to_numpy(),
           "cdgps_fix": d["fixed"].to_numpy() == 1, "summary": json.loads(p.stdout)}
    if before:
        res["cdgps_before_s"] = statistics.median(t_b)
        res["identical_to_before"] = _solution_body(out_c) == _solution_body(Path(str(out_c) + ".before.csv"))
    if peer:
        q = np.array([int(r[5]) for r in rows])
        res.update(rtklib_s=statistics.median(t_r), rtklib_fix=q == 1,
                   rtklib_t=np.array([_gpst_s(r[0], r[1]) for r in rows]),
                   rtklib_xyz=np.array([[float(r[2]), float(r[3]), float(r[4])] for r in rows]),
                   base_xyz=c["base_xyz"] or _header_xyz(c["base"]))
    return res


def both_fixed_epochs(r: dict) -> dict:
    """Epoch by epoch where both programs fixed (times within 0.1 s: RTKLIB tags a solution with the receiver
    time corrected by its clock, cdgps with the rover's own tag): how many, and the median and
    largest 3-D distance between the two positions (mm).  The difference of the fixed means above only
    means something for a static rover: a moving one's mean depends on which epochs each fixed."""
    tc, tr = r["cdgps_t"][r["cdgps_fix"]], r["rtklib_t"][r["rtklib_fix"]]
    xc, xr = r["cdgps_xyz"][r["cdgps_fix"]], r["rtklib_xyz"][r["rtklib_fix"]]
    j = np.clip(np.searchsorted(tr, tc), 0, max(tr.size - 1, 0))
    if not tr.size:
        return {"both_fixed_epochs": 0}
    k = np.where((j > 0) & (np.abs(tr[j - 1] - tc) < np.abs(tr[j] - tc)), j - 1, j)
    same = np.abs(tr[k] - tc) < 0.1
    dist_mm = 1e3 * np.linalg.norm(xc[same] - xr[k[same]], axis=1)
    out = {"both_fixed_epochs": int(same.sum())}
    if same.any():
        out.update(both_fixed_median_3d_diff_mm=round(float(np.median(dist_mm)), 2),
                   both_fixed_max_3d_diff_mm=round(float(dist_mm.max()), 2),
                   both_fixed_over_10cm=int((dist_mm > 100).sum()))
    return out


def main() -> None:
    from cdgps_cli.model.gps.orbits import ecef_to_enu  # noqa: PLC0415

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="runs per program and case (median) [3]")
    ap.add_argument("--no-rtklib", action="store_true", help="time our side only")
    ap.add_argument("--before", metavar="TREE", help="also time another source tree's `cdgps rtk` in the same rounds")
    ap.add_argument("--out", type=Path, default=OUT, help=f"result JSON [{OUT}]")
    ap.add_argument("--f9p", type=Path, metavar="DIR", help="also a real F9P pair (geofis/ppk example-rinex fetched into "
                    "DIR; see _f9p_cases)")
    ap.add_argument("--m8p", type=Path, metavar="DIR", help="also issue 28's u-blox M8P pair and the CORS to its base "
                    "(jdesbonnet/GNSS_RTK_data 20181004, converted by convbin into DIR; see _m8p_cases)")
    args = ap.parse_args()
    repeats, peer, before, out = args.repeats, not args.no_rtklib, args.before, args.out
    if peer and not shutil.which("rnx2rtkp"):
        raise SystemExit("rnx2rtkp not found: apt-get install rtklib (or --no-rtklib for our side only)")
    res = {"machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
                       "cpus": os.cpu_count(), "load_average_1min_at_start": round(os.getloadavg()[0], 2)},
           "repeats": repeats,
           "cdgps_runs": "environment without PYTHONDONTWRITEBYTECODE (bytecode caches, as a user's install) and one "
                         "untimed warm-up run per case; rnx2rtkp timed as is (no warm-up); rounds interleaved "
                         "(cdgps, rnx2rtkp, cdgps, ...), medians",
           "ratios": "speed_ratio_per_epoch = cdgps ms/epoch / rnx2rtkp ms/epoch (< 1: cdgps faster); "
                     "rtklib_over_cdgps_per_epoch its inverse (> 1: cdgps faster)",
           "startup_floor": startup_floor(repeats), "cases": {}}
    print("startup floor", json.dumps(res["startup_floor"]), flush=True)
    floor = res["startup_floor"]["import_cdgps_rtk_path_s"]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for c in cases(tmp):
            r = run_case(c, tmp, repeats, peer, before)
            fix_c, sec_c = r["cdgps_fix"], r["cdgps_s"]
            summ = r["summary"]
            row = {"signals": list(c["signals"]), "epochs": int(len(fix_c)), "cdgps_fixed": int(fix_c.sum()),
                   "cdgps_s": sec_c, "cdgps_ms_per_epoch": 1e3 * sec_c / max(len(fix_c), 1),
                   "cdgps_fixes_rejected": summ["fixes_rejected"], "epoch_pairing": summ["epoch_pairing"]}
            if before:
                row.update(cdgps_before_s=r["cdgps_before_s"], speed_up_vs_before=r["cdgps_before_s"] / sec_c,
                           identical_to_before=r["identical_to_before"])
            if peer:
                fix_r, sec_r = r["rtklib_fix"], r["rtklib_s"]
                row.update(rtklib_epochs=int(len(fix_r)), rtklib_fixed=int(fix_r.sum()), rtklib_s=sec_r,
                           rtklib_ms_per_epoch=1e3 * sec_r / max(len(fix_r), 1))
                row["speed_ratio_per_epoch"] = row["cdgps_ms_per_epoch"] / row["rtklib_ms_per_epoch"]
                row["rtklib_over_cdgps_per_epoch"] = row["rtklib_ms_per_epoch"] / row["cdgps_ms_per_epoch"]
                row["speed_ratio_per_epoch_after_imports"] = ((sec_c - floor) / max(len(fix_c), 1)) / (sec_r / max(len(fix_r), 1))
                if fix_c.any() and fix_r.any():
                    bxyz = r["base_xyz"]
                    diff = (ecef_to_enu(r["cdgps_xyz"][fix_c], bxyz).mean(axis=0)
                            - ecef_to_enu(r["rtklib_xyz"][fix_r], bxyz).mean(axis=0))
                    row["fixed_mean_diff_enu_mm"] = [round(1e3 * float(v), 2) for v in diff]
                    row.update(both_fixed_epochs(r))
            res["cases"][c["name"]] = row
            print(c["name"], json.dumps({k: v for k, v in row.items() if k != "epoch_pairing"}), flush=True)
    res["machine"]["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    if before:
        res["before_tree"] = before
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
