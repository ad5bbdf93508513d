"""Multi-GNSS RTK from files (``cdgps rtk``): read, check, solve (estimation/rtk_multi.py), write a CSV.

Every check runs before anything is written; the CSV is written atomically (io/atomic.py), so a
refused input leaves nothing behind.  The CSV echoes the signals used with their wavelengths and
the options in ``#`` comment lines, then one row per epoch: ``time_gps_s, x_m, y_m, z_m, fixed,
n_dd_ambiguities, ratio`` (the fixed position where fixed, else the float one).
"""

from __future__ import annotations

import io as _io
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.config.options import MULTI_GNSS_DEFAULTS
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.signals import SIGNALS, signal
from cdgps_cli.estimation.rtk_multi import check_common_signals, receiver_geometry, solve_rtk
from cdgps_cli.io.atomic import write_atomic
from cdgps_cli.io.rinex import NAV_SYSTEMS, read_rinex_nav
from cdgps_cli.io.rinex_signals import read_rinex_signals

__all__ = ["validate_options", "rtk_from_files"]


def validate_options(options: dict) -> dict:
    """Options merged over MULTI_GNSS_DEFAULTS; CdgpsError listing every bad key at once."""
    opt = {**MULTI_GNSS_DEFAULTS, **options}
    bad = [f"{k}: unknown option" for k in options if k not in MULTI_GNSS_DEFAULTS]
    if opt["mode"] not in ("kinematic", "static"):
        bad.append(f"mode: expected 'kinematic' or 'static', got {opt['mode']!r}")
    for s in opt["signals"]:
        if s not in SIGNALS:
            bad.append(f"signals: unknown signal {s!r} (known: {', '.join(SIGNALS)})")
    if not 0 <= float(opt["mask_deg"]) < 90:
        bad.append(f"mask_deg: expected a value in [0, 90), got {opt['mask_deg']}")
    if float(opt["ratio"]) < 1:
        bad.append(f"ratio: expected ≥ 1, got {opt['ratio']}")
    if bad:
        raise CdgpsError("invalid rtk options: " + "; ".join(bad))
    return opt


def _nav(paths, systems) -> pd.DataFrame:
    tabs = []
    for p in paths:
        sysc = tuple(c for c in systems if c in NAV_SYSTEMS)
        try:
            tabs.append(read_rinex_nav(p, systems=sysc))
        except CdgpsError as exc:
            if ("ephemeris records" not in str(exc) and "navigation file for system" not in str(exc)
                    and "GLONASS navigation file" not in str(exc)):
                raise
    if not tabs:
        raise CdgpsError(f"no usable ephemerides in {', '.join(map(str, paths))} for systems {', '.join(systems)}")
    nav = pd.concat(tabs, ignore_index=True)
    return nav.drop_duplicates(["sat", "toe_gps_s"]).reset_index(drop=True)


def rtk_from_files(base_path, rover_path, nav_paths, out_csv, *, base_xyz_m=None, options: dict | None = None) -> dict:
    """Solve base → rover and write ``out_csv``; returns the summary (fix rate, static position …)."""
    opt = validate_options(options or {})
    sigs = list(opt["signals"])
    systems = sorted({signal(s).system for s in sigs})
    for c in systems:
        if c not in NAV_SYSTEMS:
            raise CdgpsError(f"signals of system {c} cannot be processed yet (broadcast ephemerides read for "
                             f"{', '.join(NAV_SYSTEMS)} only)")
    try:                  # read first for its GLONASS frequency numbers; the observation files' errors come first
        nav, nav_error = _nav(nav_paths, systems), None
    except CdgpsError as exc:
        nav, nav_error = pd.DataFrame(), exc
    # GLONASS frequency numbers: the observation header's, else the navigation records'
    glo_k = ({sat: int(k) for sat, k in nav.dropna(subset=["glonass_k"]).groupby("sat")["glonass_k"].first().items()}
             if "glonass_k" in nav.columns else {})
    hb, b = read_rinex_signals(base_path, sigs, glo_k)
    hr, r = read_rinex_signals(rover_path, sigs, glo_k)
    if nav_error is not None:
        raise nav_error
    check_common_signals(b, r, sigs, nav, {"base": str(base_path), "rover": str(rover_path), "nav": ", ".join(map(str, nav_paths))})
    bx = np.asarray(base_xyz_m if base_xyz_m is not None else hb["approx_position_xyz_m"] or (), dtype=float)
    if bx.shape != (3,):
        raise CdgpsError(f"{base_path}: the base has no position (no APPROX POSITION XYZ; give --base-xyz X Y Z)")
    rx = np.asarray(hr["approx_position_xyz_m"] or bx, dtype=float)
    gb, gr = receiver_geometry(b, nav, bx), receiver_geometry(r, nav, rx)
    warnings = [f"{path} ({who}): observations of {len(d)} satellite(s) without a healthy ephemeris covering them "
                f"dropped: " + ", ".join(f"{s} ({n} epochs)" for s, n in d.items())
                for who, path, d in (("base", base_path, gb.attrs["dropped"]), ("rover", rover_path, gr.attrs["dropped"])) if d]
    res = solve_rtk(gb, gr, bx, rx, options=opt)
    xyz = np.where(res["fixed"][:, None], res["fixed_xyz_m"], res["float_xyz_m"])
    buf = _io.StringIO()
    for s in sigs:
        buf.write(f"# signal {s} wavelength_m {signal(s).wavelength_m:.9f}\n" if not signal(s).fdma_step_hz
                  else f"# signal {s} FDMA (wavelength per satellite)\n")
    if any(signal(x).fdma_step_hz for x in sigs):
        buf.write(f"# glonass {'fixed (glonass_fix: identical receivers)' if opt['glonass_fix'] else 'float'} "
                  "(FDMA: DD ambiguities are not integer multiples of one wavelength)\n")
    buf.write(f"# mode {opt['mode']} ionosphere {res['iono_model']} baseline_km {res['baseline_km']:.3f} ratio {opt['ratio']}\n")
    pd.DataFrame({"time_gps_s": res["time_gps_s"], "x_m": xyz[:, 0], "y_m": xyz[:, 1], "z_m": xyz[:, 2],
                  "fixed": res["fixed"].astype(int), "n_dd_ambiguities": res["n_dd_ambiguities"],
                  "ratio": res["ratio"]}).to_csv(buf, index=False, float_format="%.4f")
    write_atomic(out_csv, lambda tmp: Path(tmp).write_text(buf.getvalue()))
    return {"epochs": int(len(res["time_gps_s"])), "fixed_pct": float(100 * res["fixed"].mean()),
            "static_xyz_m": res["static_xyz_m"].tolist(), "iono_model": res["iono_model"], "signals": sigs,
            "warnings": warnings}
