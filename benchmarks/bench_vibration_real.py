"""A known vibration added to a real rover's RINEX, recovered by cdgps and by RTKLIB (issue 28, "How it is checked").

A vibration d(t) = A·sin(2πf(t − t₀))·u along a fixed direction u (azimuth, elevation) is added to
every pseudorange and carrier phase of the real rover file through each satellite's line of sight
(``sim/rinex_edit.range_change_of_motion``: Δρ_s = −e_sᵀ d(t), e_s from the broadcast ephemeris;
every system of the navigation file).  The edited rover and the unedited real base then go through

* ``cdgps rtk`` (kinematic, forward + backward combined, its defaults);
* ``cdgps ingest → init → estimate`` with ``[gnss.displacement] model = "random_walk"``
  (σ = ``RW_SIGMA`` m/√s, ``--smooth``): the smoothed states, and the single-epoch (kinematic)
  series of the same STATES (``export --kinematic``);
* RTKLIB ``rnx2rtkp`` (kinematic, combined, ratio 3, mask 15°, the same signals, base position and
  navigation file; ``pos1-navsys`` through ``-k``);

and a sine (plus offset and drift, :func:`cdgps_cli.analysis.sine_fit.fit_sine`) is fitted to the
solution projected on u, over the fixed epochs (``rtk``: fixed; RTKLIB: Q = 1; the pipeline: epochs
with states).  The receivers' own noise and multipath stay in: nothing is subtracted.  The same fit
on (edited − unedited) solutions of the same program shows what the program transmits of the motion
alone (``clean_difference``).

Criteria (the issue): amplitude within 10 %, frequency within 1 %, from ≥ 95 % of the rover's epochs;
where the receivers' own noise makes 10 % impossible, no worse than RTKLIB on the same files.

Data: ``real-pairs/mosaic-static`` (two Septentrio mosaic-X5, 5 min at 1 Hz, 0.99 m) — the clean
real pair; ``real-pairs/geonet-car`` first 35 s (the car standing, mosaic-X5 against the GEONET
station 3034 5.4 km away, GPS + Galileo L1; the only other real pair); ``real-pairs/ublox-walk`` —
a real u-blox log without a base: a zero baseline (the unedited UBX log as base, its RINEX with the
vibration as rover) that checks 4 Hz u-blox epochs 2 ms off the grid, not receiver noise (which
cancels); its ephemerides are the log's own RXM-SFRBX ones (4 GPS, 7 Galileo), written as RINEX for
the edit and (GPS records only: Debian rnx2rtkp produces no solution from the file with the Galileo
records, not investigated) for RTKLIB, whose base there is the unedited RINEX of the same log.  Writes ``docs/benchmarks/vibration_real.json``.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_vibration_real.py [--quick] [--no-rtklib] [--only DATA]
[--m8p DIR] [--cv] [--phase-noise-auto] [--multipath-auto] [--out JSON]``; ``--cv`` adds the pipeline's constant-velocity model
(``cdgps pipeline constant_velocity``); ``--phase-noise-auto`` runs the pipeline with ``[gnss.displacement]
phase_noise = "auto"`` (the per-epoch states' phase variances scaled to the single-epoch residuals); ``--multipath-auto``
with ``multipath = "auto"`` (Gauss–Markov phase multipath states, session 35);
``--sweep`` adds the random-walk σ sweep (:func:`rw_sigma_sweep`) to the existing JSON.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
CDGPS = str(Path(sys.executable).parent / "cdgps")
OUT = ROOT / "docs" / "benchmarks" / "vibration_real.json"
NAVSYS = {"G": 1, "R": 4, "E": 8, "C": 32}
RW_SIGMA = 0.1                      # m/√s: lets a 3 mm, 0.3 Hz motion (5.7 mm/s) through the smoother
#: m/s/√s, ``--cv``: white acceleration of the constant-velocity model, so that its smoother passes 0.3 Hz with
#: u-blox noise (the pipeline's default 0.1 cut the M8P's 2 mm, 0.3 Hz vertical motion by 20 %)
CV_ACCEL = 1.0
MS = SHARED / "real-pairs" / "mosaic-static"
CAR = SHARED / "real-pairs" / "geonet-car"
WALK = SHARED / "real-pairs" / "ublox-walk"

#: vibrations: amplitude m, frequency Hz, direction (azimuth, elevation) deg
VIBRATIONS = [
    (0.003, 0.10, (30.0, 0.0)),
    (0.003, 0.20, (120.0, 30.0)),
    (0.002, 0.30, (0.0, 90.0)),
    (0.001, 0.25, (60.0, 0.0)),
]


def _unit(az_deg, el_deg):
    a, e = math.radians(az_deg), math.radians(el_deg)
    return np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])


def _header_xyz(path: Path) -> tuple:
    """A RINEX file's APPROX POSITION XYZ, ECEF m."""
    for ln in Path(path).read_text(errors="replace").splitlines():
        if ln[60:].strip() == "APPROX POSITION XYZ":
            return tuple(float(x) for x in ln[:60].split())
    raise SystemExit(f"{path}: no APPROX POSITION XYZ")


def datasets():
    """name → base, rover, navs, base ECEF, rover a-priori ECEF, signal sets {label: (signals, RTKLIB freq)}, t0, keep.
    ``--m8p DIR`` adds the u-blox M8P pair of jdesbonnet/GNSS_RTK_data (2018-10-04 12:37, static, 0.33 m;
    no licence: not in ../shared, fetched locally): DIR holds convbin's base1.obs, rover1.obs and base1.nav
    (``convbin -od -os -oi -ot -f 1`` of base-20181004-1236.ubx and rover-20181004-1237.ubx), and, when DIR also
    holds the OSi CORS glw1277m.18o / .18n of the same repository's zip, the CORS to the M8P rover (196 m)."""
    extra = {}
    if "--m8p" in sys.argv:
        d = Path(sys.argv[sys.argv.index("--m8p") + 1])
        extra["u-blox M8P pair"] = dict(base=d / "base1.obs", rover=d / "rover1.obs", navs=[d / "base1.nav"],
                                        base_xyz=(3774090.1382928407, -601663.0449456355, 5089319.199168801),
                                        t0=None, keep=None, signals={"GPS L1": (("G:L1",), 1),
                                                                     "GPS+GLONASS L1": (("G:L1", "R:G1"), 1)})
        cors = d / "glw1277m.18o"
        if cors.exists():          # the OSi CORS GLW1 (Leica, RINEX 2.11 at 5 s) 196 m from the M8P rover
            extra["CORS GLW1 to the M8P rover"] = dict(base=cors, rover=d / "rover1.obs", navs=[d / "glw1277m.18n"],
                                                       base_xyz=_header_xyz(cors), t0=None, keep=None,
                                                       signals={"GPS L1": (("G:L1",), 1)})
    return {**extra,
        "mosaic-static": dict(base=MS / "base.obs", rover=MS / "rover.obs", navs=[MS / "base.nav"],
                              base_xyz=(-3817681.1213, 3562839.4311, 3650159.1593), t0=1403252400.0, keep=None,
                              signals={"GPS L1": (("G:L1",), 1), "GPS+Galileo L1": (("G:L1", "E:E1"), 1)}),
        "geonet-car standing 35 s": dict(base=CAR / "3034265G.21O", rover=CAR / "SEPT265G.21O", navs=[CAR / "SEPT2650.21P"],
                                         base_xyz=(-3959400.631, 3385704.533, 3667523.111), t0=1316327400.0,
                                         keep=(0.0, 34.5), signals={"GPS+Galileo L1": (("G:L1", "E:E1"), 1)}),
        "ublox-walk zero baseline": dict(base=WALK / "gnss_1730.ubx", rover=WALK / "gnss_1730_convbin.obs", navs=[],
                                         ubx_nav=WALK / "gnss_1730.ubx",
                                         base_xyz=(-1276975.6547, -4717238.8712, 4087235.6076), t0=None, keep=None,
                                         signals={"GPS+Galileo L1": (("G:L1", "E:E1"), 1)}),
    }


def edit_rover(ds: dict, vib, tmp: Path, tag: str) -> Path:
    """The rover file with the vibration (None: only cut to ``keep``)."""
    from cdgps_cli.io.rinex import read_rinex_nav  # noqa: PLC0415
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s, range_change_of_motion  # noqa: PLC0415

    text = ds["rover"].read_text()
    times = epoch_times_gps_s(text)
    t0 = ds["t0"] if ds["t0"] is not None else float(times[0])
    keep = None if ds["keep"] is None else (lambda t: ds["keep"][0] <= t - t0 <= ds["keep"][1])
    rc = None
    if vib is not None:
        amp, f, (az, el) = vib
        nav_path = ds.get("rinex_nav") or ds["navs"][0]
        nav = pd.concat([read_rinex_nav(nav_path, systems=(s,)) for s in ("G", "E", "R", "C")
                         if _has_system(nav_path, s)], ignore_index=True)
        u = _unit(az, el)
        rc = range_change_of_motion(nav, np.asarray(ds["rover_xyz"]), lambda t: amp * math.sin(2 * math.pi * f * (t - t0)) * u,
                                    times_gps_s=times)
    out = tmp / f"rover_{tag}.obs"
    out.write_text(edit_rinex3_obs(text, keep=keep, range_change_m=rc))
    return out


def _has_system(nav_path: Path, s: str) -> bool:
    from cdgps_cli.io.rinex import read_rinex_nav  # noqa: PLC0415

    try:
        return len(read_rinex_nav(nav_path, systems=(s,))) > 0
    except Exception:  # noqa: BLE001   (a system the file's reader refuses is left out)
        return False


def _run(cmd):
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=1800)
    if p.returncode != 0:
        raise SystemExit(f"failed ({p.returncode}): {' '.join(map(str, cmd))}\n{p.stderr[-3000:]}")
    return p


def run_rtk(ds, rover: Path, signals, tmp: Path):
    """cdgps rtk: (time GPS s, ENU m about the base, used mask)."""
    out = tmp / "rtk.csv"
    _run([CDGPS, "-q", "rtk", "--base", ds["base"], "--rover", rover, *sum((["--nav", n] for n in ds["navs"]), []),
          "--signals", ",".join(signals), "--base-xyz", *ds["base_xyz"], "-o", out])
    d = pd.read_csv(out, comment="#")
    return d["time_gps_s"].to_numpy(), d[["e_m", "n_m", "u_m"]].to_numpy(), d["fixed"].to_numpy() == 1


def run_pipeline(ds, rover: Path, signals, tmp: Path, model: str = "random_walk"):
    """ingest → init → estimate --smooth (``model``: random walk, or with ``--cv`` constant velocity of white
    acceleration ``CV_ACCEL``, init on the same random-walk float): {model: (t, ENU, used)} and, for
    the random walk, "kinematic": (…) (the single-epoch series)."""
    cfg = tmp / "run.toml"
    kind = "ubx" if ds["base"].suffix.lower() == ".ubx" else "rinex"
    cfg.write_text("\n".join([
        "[gnss]", 'name = "vibration"', 'master = "base"', f"nav = {json.dumps([str(n) for n in ds['navs']])}",
        f"signals = {json.dumps(list(signals))}", "", "[gnss.displacement]", f'model = "{model}"',
        f"sigma_m_per_sqrt_s = {RW_SIGMA}", *([f"accel_sigma_m_per_s_per_sqrt_s = {CV_ACCEL}"]
                                              if model == "constant_velocity" else []),
        *(['phase_noise = "auto"'] if "--phase-noise-auto" in sys.argv else []),
        *(['multipath = "auto"'] if "--multipath-auto" in sys.argv else []),
        "", '[gnss.antennas."base"]', f'{kind} = "{ds["base"]}"',
        f"position_ecef_m = [{', '.join(map(str, ds['base_xyz']))}]", "", '[gnss.antennas."rover"]', f'rinex = "{rover}"', ""]))
    _run([CDGPS, "-q", "ingest", "--config", cfg, "-o", tmp / "run.mcap"])
    _run([CDGPS, "-q", "init", tmp / "run.mcap", "-o", tmp / "init.json"])
    _run([CDGPS, "-q", "estimate", tmp / "run.mcap", "--init", tmp / "init.json", "-o", tmp / "states.mcap", "--smooth"])
    out = {}
    for key, extra in ((model, []), ("kinematic", ["--kinematic"]))[:2 if model == "random_walk" else 1]:
        _run([CDGPS, "-q", "export", tmp / "states.mcap", *extra, "-o", tmp / f"{key}.csv"])
        d = pd.read_csv(tmp / f"{key}.csv")
        enu = d[["rover_e_m", "rover_n_m", "rover_u_m"]].to_numpy(dtype=np.float64)      # (an empty series too)
        out[key] = (d["time_s"].to_numpy(dtype=np.float64), enu, np.isfinite(enu).all(axis=1))
    if model == "random_walk" and "--cv" in sys.argv:
        out.update(run_pipeline(ds, rover, signals, tmp, "constant_velocity"))
    return out


def run_rtklib(ds, rover: Path, signals, freq, tmp: Path):
    """rnx2rtkp kinematic combined: (time GPS s, ENU m about the base, Q = 1 mask)."""
    from cdgps_cli.core.gps_time import gps_seconds  # noqa: PLC0415
    from cdgps_cli.model.gps.orbits import ecef_to_enu  # noqa: PLC0415

    def when(day: str, hms: str) -> float:
        y, mo, dd = (int(v) for v in day.split("/"))
        h, mi, sec = hms.split(":")
        return gps_seconds(y, mo, dd, int(h), int(mi), float(sec))

    conf = tmp / "rtklib.conf"
    systems = sorted({s[0] for s in signals})
    conf.write_text("\n".join([
        "pos1-posmode=kinematic", f"pos1-frequency={'l1' if freq == 1 else 'l1+l2'}", "pos1-soltype=combined",
        "pos1-elmask=15", "pos1-tropopt=saas", "pos1-ionoopt=off", f"pos1-navsys={sum(NAVSYS[s] for s in systems)}",
        "pos2-armode=continuous", "pos2-arthres=3", "pos2-gloarmode=off", "out-solformat=xyz", "out-timesys=gpst",
        "ant2-postype=xyz", *(f"ant2-pos{i + 1}={v:.4f}" for i, v in enumerate(ds["base_xyz"])), ""]))
    base = ds["base"]
    if base.suffix.lower() == ".ubx":            # RTKLIB reads the base as RINEX: the unedited convbin file
        base = ds["rover"]
    navs = ds["navs"] or [ds["rtklib_nav"]]
    out = tmp / "rtklib.pos"
    p = subprocess.run(["rnx2rtkp", "-k", str(conf), "-o", str(out), str(rover), str(base), *map(str, navs)],
                       capture_output=True, text=True, timeout=600)
    rows = [ln.split() for ln in out.read_text().splitlines() if ln.strip() and not ln.startswith("%")] if out.exists() else []
    if p.returncode != 0 or not rows:
        raise SystemExit(f"rnx2rtkp failed (exit {p.returncode}, {len(rows)} lines):\n{p.stderr[-2000:]}")
    t = np.array([when(r[0], r[1]) for r in rows])
    xyz = np.array([[float(r[2]), float(r[3]), float(r[4])] for r in rows])
    return t, ecef_to_enu(xyz, np.asarray(ds["base_xyz"])), np.array([int(r[5]) for r in rows]) == 1


def score(sol, vib, n_rover: int, t0: float, clean=None) -> dict:
    """Sine fit of the solution along u over its used epochs (and of edited − clean where both are used)."""
    from cdgps_cli.analysis.sine_fit import fit_sine  # noqa: PLC0415

    amp, f, (az, el) = vib
    t, enu, used = sol
    y = enu @ _unit(az, el)
    fit = fit_sine(t[used] - t0, y[used], f)
    row = {"epochs": int(t.size), "used": int(used.sum()), "used_fraction": round(float(used.sum()) / n_rover, 4),
           "amplitude_mm": round(1e3 * fit.amplitude, 3), "amplitude_error_pct": round(100 * (fit.amplitude / amp - 1), 2),
           "frequency_hz": round(fit.frequency_hz, 6), "frequency_error_pct": round(100 * (fit.frequency_hz / f - 1), 3),
           "residual_rms_mm": round(1e3 * fit.residual_rms, 3)}
    row["passes"] = bool(abs(row["amplitude_error_pct"]) <= 10 and abs(row["frequency_error_pct"]) <= 1
                         and row["used_fraction"] >= 0.95)
    if clean is not None:
        tc, ec, uc = clean
        common, i, j = np.intersect1d(np.round(t, 3), np.round(tc, 3), return_indices=True)
        ok = used[i] & uc[j]
        if ok.sum() >= 5:
            fd = fit_sine(common[ok] - t0, (enu[i] - ec[j])[ok] @ _unit(az, el), f)
            row["clean_difference"] = {"amplitude_error_pct": round(100 * (fd.amplitude / amp - 1), 2),
                                       "frequency_error_pct": round(100 * (fd.frequency_hz / f - 1), 3),
                                       "residual_rms_mm": round(1e3 * fd.residual_rms, 3)}
    return row


def rw_sigma_sweep() -> dict:
    """The random-walk smoother's σ on the case it attenuates most (mosaic-static, GPS L1, 2 mm vertical
    at 0.3 Hz): amplitude and frequency errors for σ = 0.1, 0.3, 1 m/√s (``--sweep``; added to the JSON)."""
    global RW_SIGMA
    ds = datasets()["mosaic-static"]
    ds["rover_xyz"] = _rover_xyz(ds)
    vib = VIBRATIONS[2]
    out, keep = {}, RW_SIGMA
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        rover = edit_rover(ds, vib, tmp, "sweep")
        for sigma in (0.1, 0.3, 1.0):
            RW_SIGMA = sigma
            r = score(run_pipeline(ds, rover, ("G:L1",), tmp)["random_walk"], vib, 301, ds["t0"])
            out[str(sigma)] = {k: r[k] for k in ("amplitude_error_pct", "frequency_error_pct", "residual_rms_mm", "passes")}
            print("rw sigma", sigma, json.dumps(out[str(sigma)]), flush=True)
    RW_SIGMA = keep
    return {"case": "mosaic-static GPS L1, 2 mm, 0.3 Hz, up", "by_sigma_m_per_sqrt_s": out}


def main() -> None:
    if "--sweep" in sys.argv:                 # only the σ sweep, added to the existing JSON
        res = json.loads(OUT.read_text())
        res["rw_sigma_sweep"] = rw_sigma_sweep()
        OUT.write_text(json.dumps(res, indent=1) + "\n")
        print(f"wrote {OUT}")
        return
    peer = "--no-rtklib" not in sys.argv
    quick = "--quick" in sys.argv
    if peer and not shutil.which("rnx2rtkp"):
        raise SystemExit("rnx2rtkp not found: apt-get install rtklib (or --no-rtklib)")
    res = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                       "load_average_1min_at_start": round(os.getloadavg()[0], 2)},
           "rw_sigma_m_per_sqrt_s": RW_SIGMA, "vibrations": [list(v[:2]) + [list(v[2])] for v in VIBRATIONS],
           "phase_noise": "auto" if "--phase-noise-auto" in sys.argv else "model",
           "multipath": "auto" if "--multipath-auto" in sys.argv else "off",
           "criteria": "amplitude within 10 %, frequency within 1 %, from >= 95 % of the rover's epochs",
           "cases": []}
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        only = sys.argv[sys.argv.index("--only") + 1] if "--only" in sys.argv else None
        for name, ds in datasets().items():
            if only and not name.startswith(only):
                continue
            if not ds["rover"].exists():
                print(f"skip {name}: {ds['rover']} absent", flush=True)
                continue
            ds["rover_xyz"] = _rover_xyz(ds)
            if "ubx_nav" in ds:          # the log's own SFRBX ephemerides (convbin's .nav lacks Galileo) as RINEX
                from cdgps_cli.io.rinex_write import write_rinex_nav  # noqa: PLC0415
                from cdgps_cli.io.ubx import read_ubx_log  # noqa: PLC0415

                nav = read_ubx_log(ds["ubx_nav"])[2]
                ds["rinex_nav"], ds["rtklib_nav"] = tmp / "sfrbx.nav", tmp / "sfrbx_gps.nav"
                write_rinex_nav(ds["rinex_nav"], nav)
                write_rinex_nav(ds["rtklib_nav"], nav[nav["sat"].str[0] == "G"], leap_seconds=18)
            vibs = VIBRATIONS[:2] if quick else VIBRATIONS
            if name.startswith("geonet-car"):          # 35 s: 0.2–0.3 Hz only (≥ 7 cycles)
                vibs = [v for v in vibs if v[1] >= 0.2]
            clean_rover = edit_rover(ds, None, tmp, "clean")
            from cdgps_cli.sim.rinex_edit import epoch_times_gps_s  # noqa: PLC0415
            t_rover = epoch_times_gps_s(clean_rover.read_text())
            n_rover, t0 = int(t_rover.size), (ds["t0"] if ds["t0"] is not None else float(t_rover[0]))
            for label, (signals, freq) in ds["signals"].items():
                clean = {"cdgps rtk": run_rtk(ds, clean_rover, signals, tmp), **{
                    f"cdgps pipeline {k}": v for k, v in run_pipeline(ds, clean_rover, signals, tmp).items()}}
                if peer:
                    clean["rnx2rtkp"] = run_rtklib(ds, clean_rover, signals, freq, tmp)
                for k, vib in enumerate(vibs):
                    rover = edit_rover(ds, vib, tmp, f"v{k}")
                    sols = {"cdgps rtk": run_rtk(ds, rover, signals, tmp), **{
                        f"cdgps pipeline {kk}": v for kk, v in run_pipeline(ds, rover, signals, tmp).items()}}
                    if peer:
                        sols["rnx2rtkp"] = run_rtklib(ds, rover, signals, freq, tmp)
                    row = {"data": name, "signals": label, "amplitude_mm": 1e3 * vib[0], "frequency_hz": vib[1],
                           "direction_az_el_deg": list(vib[2]), "rover_epochs": n_rover,
                           "results": {m: score(s, vib, n_rover, t0, clean.get(m)) for m, s in sols.items()}}
                    res["cases"].append(row)
                    print(json.dumps({k2: v for k2, v in row.items() if k2 != "results"}), flush=True)
                    for m, r in row["results"].items():
                        print(f"   {m:32s} used {r['used']:4d}/{n_rover}  A {r['amplitude_error_pct']:+7.2f} %  "
                              f"f {r['frequency_error_pct']:+7.3f} %  rms {r['residual_rms_mm']:.2f} mm  "
                              f"{'PASS' if r['passes'] else 'fail'}  clean-diff A "
                              f"{(r.get('clean_difference') or {}).get('amplitude_error_pct')}", flush=True)
    res["seconds"] = round(time.perf_counter() - t_start, 1)
    res["machine"]["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    out = Path(sys.argv[sys.argv.index("--out") + 1]) if "--out" in sys.argv else OUT
    if not quick:
        out.write_text(json.dumps(res, indent=1) + "\n")
        print(f"wrote {out}")


def _rover_xyz(ds) -> np.ndarray:
    """The rover's header APPROX POSITION XYZ (metres off at most: only the lines of sight use it)."""
    with open(ds["rover"], errors="replace") as f:
        for ln in f:
            if ln[60:].strip() == "APPROX POSITION XYZ":
                xyz = np.array([float(v) for v in ln[:60].split()])
                return xyz if np.linalg.norm(xyz) > 6e6 else np.asarray(ds["base_xyz"], dtype=float)
            if ln[60:].strip() == "END OF HEADER":
                break
    return np.asarray(ds["base_xyz"], dtype=float)


if __name__ == "__main__":
    main()
