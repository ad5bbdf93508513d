"""Multi-GNSS RTK from files (``cdgps rtk``): read, check, solve (estimation/rtk_multi.py), write the solution.

Every check runs before anything is written; the output is written atomically (io/atomic.py), so a
refused input leaves nothing behind.  The output's suffix picks its format (:data:`OUTPUT_FORMATS`):
RTKLIB ``.pos`` (lat/lon/height, Q, ns, σ, age, ratio: ``rtkplot``/``pos2kml`` read it), NMEA GGA
(``.nmea``/``.gga``), GeoJSON, or CSV — the signals used with their wavelengths and the options in
``#`` comment lines, then one row per epoch (:func:`solution_text`; the fixed position where fixed,
else the float one).
"""

from __future__ import annotations

import functools
import io as _io
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

from cdgps_cli.config.limits import GEOCENTRIC_RANGE_M, MASK_DEG
from cdgps_cli import __version__
from cdgps_cli.config.options import (CODE_NOISE_MIN_WINDOWS, default_direction, CODE_NOISE_WINDOW_S, GNSS_WEIGHTINGS, HEADER_CHECK_EPOCHS,
                                      HEADER_POSITION_TOL_M, MOVING_ROVER_FLOAT_M, MULTI_GNSS_DEFAULTS,
                                      ORIGIN_MOVE_SIGMAS, ROVER_ORIGIN_TOL_M)
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import distinct_times, gps_time_str, nominal_interval_s, spans_meet, time_span
from cdgps_cli.core.signals import AUTO_SYSTEMS, SIGNALS, SYSTEM_NAMES, signal
from cdgps_cli.estimation.rtk_multi import (RTK_MODES, check_common_signals, receiver_geometry, receivers_code_noise,
                                            reported_positions, solve_rtk, troposphere_at_epochs)
from cdgps_cli.measurement.code_steps import code_steps_warning
from cdgps_cli.measurement.channel_screen import naming_screened, without_unusable_channels
from cdgps_cli.measurement.slips import unflagged_slip_text
from cdgps_cli.measurement.time_window import OUTSIDE_WINDOW, in_window, pair_in_window, window_errors, window_masks, with_dropped
from cdgps_cli.io.atomic import write_atomic
from cdgps_cli.io.gnss_sequence import (merge_signal_tables, pieces_text, refuse_another_receiver, refuse_spans_apart,
                                       systems_merged_text)
from cdgps_cli.io.log_sequence import expand_paths, join_tables, one_file_for_two_receivers
from cdgps_cli.io.rinex import COMPRESSED_MAGIC, NAV_SYSTEMS, read_rinex_nav, reading_notes
from cdgps_cli.io.rinex_signals import (signals_by_file, first_of_repeated_epochs, signal_attributes, glonass_without_frequency_text, out_of_order_text,
                                        read_rinex_signals,
                                        repeated_epochs_text, signals_in_file)
from cdgps_cli.io.solution_formats import POS_FRAMES, Q_FIX, Q_FLOAT, csv_text, finite_or, geojson_text, nmea_gga_text, pos_text
from cdgps_cli.model.gps.orbits import ecef_to_enu, ecef_to_geodetic, enu_matrix
from cdgps_cli.model.gps.positioning import antenna_reference_point_m, rover_delta_note, spp_spread
from cdgps_cli.pipeline.antenna_models import antenna_models, with_antenna_model

__all__ = ["validate_options", "rtk_from_files", "common_signals"]


def _model_option_errors(opt: dict) -> list:
    """What is wrong with the zenith wet delay options (``tropo_*``) and the antenna options (``antex``,
    ``base_antenna``, ``rover_antenna``) of ``opt``."""
    bad = []
    v = opt["tropo_threshold_km"]
    if v is not None and not (_as_float(v) is not None and math.isfinite(_as_float(v)) and _as_float(v) >= 0):
        bad.append(f"tropo_threshold_km: expected a baseline length in km >= 0 (or None: iono_threshold_km's), "
                   f"got {v!r}")
    for key, low, what in (("tropo_initial_m", -math.inf, "a zenith wet delay in m"),
                           ("tropo_rw_m_per_sqrt_s", 0.0, "a random walk in m/√s >= 0")):
        v = _as_float(opt[key])
        if not (v is not None and math.isfinite(v) and v >= low):
            bad.append(f"{key}: expected {what}, got {opt[key]!r}")
    v = _as_float(opt["tropo_sigma_m"])
    if not (v is not None and math.isfinite(v) and v > 0):
        bad.append(f"tropo_sigma_m: expected a σ in m > 0, got {opt['tropo_sigma_m']!r}")
    for key in ("antex", "base_antenna", "rover_antenna"):
        if opt[key] is not None and not (isinstance(opt[key], (str, Path)) and str(opt[key]).strip()):
            bad.append(f"{key}: expected {'an ANTEX file' if key == 'antex' else 'an antenna type'} name, got {opt[key]!r}")
    return bad


def _as_float(v) -> float | None:
    """``v`` as a float, None when it is not a number (a bool is not)."""
    if isinstance(v, bool):
        return None
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def validate_options(options: dict) -> dict:
    """Options merged over MULTI_GNSS_DEFAULTS; CdgpsError listing every bad key at once."""
    opt = {**MULTI_GNSS_DEFAULTS, **options}
    bad = [f"{k}: unknown option" for k in options if k not in MULTI_GNSS_DEFAULTS]
    if opt["mode"] not in RTK_MODES:
        bad.append(f"mode: expected one of {', '.join(repr(m) for m in RTK_MODES)}, got {opt['mode']!r}")
    if opt["pos_frame"] not in POS_FRAMES:
        bad.append(f"pos_frame: expected one of {', '.join(repr(f) for f in POS_FRAMES)}, got {opt['pos_frame']!r}")
    if not (np.isfinite(float(opt["iono_threshold_km"])) and float(opt["iono_threshold_km"]) >= 0):
        bad.append(f"iono_threshold_km: expected a baseline length in km >= 0, got {opt['iono_threshold_km']}")
    model_bad = _model_option_errors(opt)
    bad += model_bad
    if not model_bad:                               # numbers given as text (an API caller's): numbers from here on
        for key in ("tropo_initial_m", "tropo_sigma_m", "tropo_rw_m_per_sqrt_s"):
            opt[key] = float(opt[key])
        if opt["tropo_threshold_km"] is not None:
            opt["tropo_threshold_km"] = float(opt["tropo_threshold_km"])
    if opt["direction"] is None:
        opt["direction"] = default_direction(opt["mode"])
    if opt["direction"] not in ("forward", "backward", "combined"):
        bad.append(f"direction: expected 'forward', 'backward' or 'combined', got {opt['direction']!r}")
    if not (np.isfinite(float(opt["code_correlation_s"])) and float(opt["code_correlation_s"]) >= 0):
        bad.append(f"code_correlation_s: expected a number of seconds >= 0, got {opt['code_correlation_s']}")
    if opt["code_noise"] not in ("auto", "model"):
        bad.append(f"code_noise: expected 'auto' or 'model', got {opt['code_noise']!r}")
    if opt["age_noise"] not in ("auto", "model"):
        bad.append(f"age_noise: expected 'auto' or 'model', got {opt['age_noise']!r}")
    if not 0.0 <= float(opt["wrong_fix_probability"]) < 1.0:
        bad.append(f"wrong_fix_probability: expected a probability in [0, 1) (0: no wrong-fix test), "
                   f"got {opt['wrong_fix_probability']}")
    if not 0.0 <= float(opt["min_success_rate"]) < 1.0:
        bad.append(f"min_success_rate: expected a probability in [0, 1) (0: the ratio test alone), "
                   f"got {opt['min_success_rate']}")
    for s in (() if opt["signals"] == "auto" else opt["signals"]):
        if s not in SIGNALS:
            bad.append(f"signals: unknown signal {s!r} (known: {', '.join(SIGNALS)})")
    if opt["weighting"] not in GNSS_WEIGHTINGS:
        bad.append(f"weighting: expected {' or '.join(map(repr, GNSS_WEIGHTINGS))}, got {opt['weighting']!r}")
    if not MASK_DEG.contains(float(opt["mask_deg"])):
        bad.append(f"mask_deg: expected a value in {MASK_DEG.text()}, got {opt['mask_deg']}")
    hold = opt["hold_after_fixes"]
    if isinstance(hold, bool) or not isinstance(hold, (int, np.integer)) or hold < 1:
        bad.append(f"hold_after_fixes: expected a whole number of consecutive fixed epochs >= 1 before fix-and-hold "
                   f"feeds the integers back, got {hold!r}")
    if float(opt["ratio"]) < 1:
        bad.append(f"ratio: expected ≥ 1, got {opt['ratio']}")
    for key in ("sync_tol_s", "max_age_s"):
        v = float(opt[key])
        if not (np.isfinite(v) and v > 0):
            bad.append(f"{key}: expected a number of seconds > 0, got {opt[key]}")
    if float(opt["max_age_s"]) < float(opt["sync_tol_s"]):
        bad.append(f"max_age_s: expected ≥ sync_tol_s ({opt['sync_tol_s']} s), got {opt['max_age_s']}")
    bad += window_errors(opt["start_gps_s"], opt["end_gps_s"])
    if bad:
        raise CdgpsError("invalid rtk options: " + "; ".join(bad))
    return opt


def _time_window(b: pd.DataFrame, r: pd.DataFrame, hr: dict, opt: dict, base_path, rover_path) -> tuple:
    """The base and rover tables cut to the options' window (``start_gps_s`` … ``end_gps_s``, the rover's epochs within
    ``sync_tol_s`` as :func:`~cdgps_cli.measurement.time_window.in_window` takes them; the base's ``max_age_s`` wider on each side), the rover's header
    with its file's epochs outside the window taken out of ``file_epochs``, and how many those are (of the file's
    epochs when its header lists them, ``file_epoch_times``; else of the table's); the same tables and 0 without a
    window.  CdgpsError naming the rover's span when no rover epoch is inside, and the base's when no base epoch is
    within ``max_age_s`` of it."""
    lo, hi = opt["start_gps_s"], opt["end_gps_s"]
    if lo is None and hi is None:
        return b, r, hr, 0
    tol, tr = float(opt["sync_tol_s"]), r["time_gps_s"].to_numpy()
    kb, keep = pair_in_window(b["time_gps_s"].to_numpy(), tr, lo, hi, tol, float(opt["max_age_s"]),
                              (f"{base_path} (base)", f"{rover_path} (rover)"))
    listed = hr.get("file_epoch_times")
    all_t = distinct_times(tr) if listed is None else np.asarray(listed.t, dtype=np.float64)
    n_outside = int(np.sum(~in_window(all_t, lo, hi, tol)))
    if hr.get("file_epochs") is not None:        # (counted apart, not as epochs without a phase)
        hr = {**hr, "file_epochs": int(hr["file_epochs"]) - n_outside}
    return b[kb].reset_index(drop=True), r[keep].reset_index(drop=True), hr, n_outside


def _holds_none_of(exc: CdgpsError) -> bool:
    """Whether a navigation reader's error only says the file holds no ephemerides of the systems asked
    for (a Galileo file when GPS is wanted): the file is passed over; any other error (a truncated,
    malformed or missing file) is the user's to see."""
    text = str(exc)
    return any(m in text for m in ("ephemeris records (records found by system", "navigation file for system",
                                   "GLONASS navigation file"))


def _nav(paths, systems) -> pd.DataFrame:
    tabs = []
    for p in paths:
        sysc = tuple(c for c in systems if c in NAV_SYSTEMS)
        try:
            tabs.append(read_rinex_nav(p, systems=sysc))
        except CdgpsError as exc:
            if not _holds_none_of(exc):
                raise
    if not tabs:
        raise CdgpsError(f"no usable ephemerides in {', '.join(map(str, paths))} for systems {', '.join(systems)}")
    nav = pd.concat(tabs, ignore_index=True).drop_duplicates(["sat", "toe_gps_s"]).reset_index(drop=True)
    nav.attrs = {}          # the files' header notes: pandas deep-copies attrs into every subset (a third of the run)
    return nav


#: solution formats RTKLIB's tools write that rtk does not (an output named so would silently be CSV)
NOT_WRITTEN_FORMATS = {".kml": "KML (RTKLIB's pos2kml makes it from a .pos)", ".kmz": "KMZ", ".gpx": "GPX",
                       ".sbp": "Swift's SBP", ".stat": "RTKLIB's solution status"}


def _refuse_a_format_not_written(out_path) -> None:
    """An output whose suffix names a solution format rtk does not write is refused (it would be CSV)."""
    fmt = NOT_WRITTEN_FORMATS.get(Path(str(out_path)).suffix.lower())
    if fmt is not None:
        raise CdgpsError(f"{out_path}: rtk does not write {fmt}; name the output .pos, .nmea, .gga, .geojson or .csv "
                         f"(any other suffix: CSV)")


def _refuse_disjoint_spans(base: pd.DataFrame, rover: pd.DataFrame, max_age_s: float, base_path, rover_path) -> None:
    """CdgpsError naming both spans when no rover epoch can have a base epoch within ``max_age_s`` (logs of two days):
    said before the rover is placed, whose single-point position with the other day's ephemerides failed first with a
    message about satellites (a sweep of two u-blox logs seven years apart)."""
    sb, sr = (time_span(df["time_gps_s"].to_numpy(dtype=np.float64)) for df in (base, rover))
    if sb is None or sr is None or spans_meet(sb, sr, max_age_s):
        return                                  # (a file without epochs: its own reader's words say so)
    raise CdgpsError(f"no common epochs: {base_path} (base) spans {gps_time_str(sb[0])} – {gps_time_str(sb[1])} and "
                     f"{rover_path} (rover) {gps_time_str(sr[0])} – {gps_time_str(sr[1])}: no rover epoch has a base "
                     f"epoch within {max_age_s:g} s (max_age_s)")


def _refuse_empty(path, who: str) -> None:
    """An empty receiver file is named as such: from its bytes neither reader can tell which it should be."""
    p = Path(path)
    if p.is_file() and p.stat().st_size == 0:
        raise CdgpsError(f"{path} ({who}): empty file; expected a RINEX observation file or a u-blox UBX log")


def rtk_from_files(base_path, rover_path, nav_paths, out_csv, *, base_xyz_m=None, options: dict | None = None) -> dict:
    """Solve base → rover and write ``out_csv``; returns the summary (fix rate, static position …).

    ``base_path`` and ``rover_path`` are each a file, or a list of files and quoted glob patterns:
    consecutive files of one receiver (hourly or daily), joined in time order into one record
    (:func:`_read_receiver`)."""
    opt = validate_options(options or {})
    if opt["pos_frame"] != MULTI_GNSS_DEFAULTS["pos_frame"] and Path(str(out_csv)).suffix.lower() != ".pos":
        raise CdgpsError(f"{out_csv}: pos_frame {opt['pos_frame']!r} (--pos-frame) is the coordinates of a .pos output; "
                         f"this output is not one (its suffix is not .pos)")
    _refuse_a_format_not_written(out_csv)
    pair = _read_pair(base_path, rover_path, nav_paths, opt)
    with naming_screened(pair.screened):
        return _rtk_from_pair(pair, out_csv, opt, base_xyz_m)


def _rtk_from_pair(pair: SimpleNamespace, out_csv, opt: dict, base_xyz_m) -> dict:
    """:func:`rtk_from_files` once the pair is read (:func:`_read_pair`)."""
    b, r, hb, hr, nav, warnings = pair.b, pair.r, pair.hb, pair.hr, pair.nav, pair.warnings
    base_path, rover_path, nav_paths = pair.base_path, pair.rover_path, pair.nav_paths
    # the base first: a rover without a position is placed by single-point positioning started at the base
    bx = _base_antenna(hb, base_xyz_m, base_path)
    if base_xyz_m is None:
        _check_base_header(bx, pair.codes[0], nav, base_path)
    warnings += rover_delta_note(hr, f"{rover_path} (rover)")
    rx, rx_from_spp = _rover_origin(hr, pair.codes[1], nav, bx, rover_path, warnings)
    ant = _antenna_models(opt, {"base": hb, "rover": hr}, {"base": base_path, "rover": rover_path}, warnings)
    gb, gr = (_geometry(df, nav, xyz, path, who, nav_paths, ant[who]) for df, xyz, path, who in
              ((b, bx, base_path, "base"), (r, rx, rover_path, "rover")))
    warnings += _geometry_warnings({"base": (base_path, gb), "rover": (rover_path, gr)})
    gb.attrs, gr.attrs = {}, {}
    code_noise = receivers_code_noise(gb, gr, opt)       # the observations' own: the same for every solve below
    warnings += _code_noise_warning(code_noise, {"base": base_path, "rover": rover_path},
                                    {"base": nominal_interval_s(gb["time_gps_s"].to_numpy()),
                                     "rover": nominal_interval_s(gr["time_gps_s"].to_numpy())})
    try:
        rover = (r, rover_path, rx_from_spp, ant["rover"], hr.get("position_source"))
        placed = rx
        rx, gr = _place_rover(gb, gr, bx, rx, opt, rover=rover, nav=(nav, nav_paths), warnings=warnings)
        if rx is not placed:           # the origin is no longer the file's position: the second note says what it is
            rover = (rover[0], rover[1], False, rover[3], "a-priori position (moved there, above)")
        res, gr, per_epoch = _solve_where_the_rover_is(gb, gr, bx, rx, opt, rover=rover, nav=(nav, nav_paths),
                                                       code_noise=code_noise, warnings=warnings)
    except CdgpsError as exc:
        if str(exc).startswith(("no common epochs", "no common satellites", "no double differences")):
            raise CdgpsError(f"{rover_path} (rover) and {base_path} (base): {exc}") from None
        raise
    ep = with_dropped(_count_epochs_without_phase(_count_epochs_without_geometry(res["epoch_pairing"], r, gr), hr, r),
                       OUTSIDE_WINDOW, pair.n_outside)
    warnings += _solution_warnings(res, ep, opt, rover_path)
    applied = {**opt, "antex": opt["antex"] if any(m is not None for m in ant.values()) else None}
    text = solution_text(res, pair.sigs, applied, out_csv, bx, inputs=(*pair.rover_files, *pair.base_files, *nav_paths))
    write_atomic(out_csv, lambda tmp: Path(tmp).write_text(text, newline=""))
    antennas = {"antex": None if opt["antex"] is None else str(opt["antex"]),
                **{who: (None if m is None else " ".join(m.name.split())) for who, m in ant.items()}}
    codes = {who: {k: v for k, v in (h.get("signal_codes") or {}).items() if k in pair.sigs} or None
             for who, h in (("base", pair.hb), ("rover", pair.hr))}   # (the RINEX types read; None: a u-blox log)
    return {**_summary(res, per_epoch), "signals": pair.sigs, "signal_codes": codes, "epoch_pairing": ep,
            "antennas": antennas,
            "output": str(out_csv), "mode": opt["mode"], "pos_frame": opt["pos_frame"],
            "base_xyz_m": [float(v) for v in bx], "warnings": warnings}


def _read_pair(base_path, rover_path, nav_paths, opt: dict) -> SimpleNamespace:
    """``rtk``'s inputs read and checked: the files expanded (none empty), the signals (``auto`` resolved, kept in
    ``opt["signals"]``), the ephemerides, both receivers' headers and signal tables (in the options' time window;
    repeated epochs and unlocked channels out), checked to share epochs and signals; what was noticed in
    ``warnings``.  Attributes: ``b``, ``r``, ``hb``, ``hr``, ``nav``, ``nav_paths``, ``sigs``, ``base_files``,
    ``rover_files``, ``base_path``, ``rover_path`` (their names as text), ``n_outside`` (rover epochs outside the
    window), ``warnings``."""
    base_files, rover_files = (expand_paths(_as_list(p), f"--{who}") for p, who in ((base_path, "base"), (rover_path, "rover")))
    # a navigation file named twice, or matched by two patterns, is read once (its ephemerides are merged anyway)
    nav_paths = expand_paths(list(nav_paths or ()), "--nav", repeats="once")
    for files, who in ((base_files, "base"), (rover_files, "rover")):
        for path in files:
            _refuse_empty(path, who)
    base_path, rover_path = pieces_text(base_files), pieces_text(rover_files)
    warnings = one_file_for_two_receivers({"--base": base_files, "--rover": rover_files})
    auto = opt["signals"] == "auto"
    sigs = _auto_signals(base_files, rover_files, nav_paths, warnings) if auto else list(opt["signals"])
    opt["signals"] = tuple(sigs)
    systems = sorted({signal(s).system for s in sigs})
    for c in systems:
        if c not in NAV_SYSTEMS:
            raise CdgpsError(f"signals of system {c} cannot be processed yet (broadcast ephemerides read for "
                             f"{', '.join(NAV_SYSTEMS)} only)")
    # read first for its GLONASS frequency numbers; the observation files' errors come first
    nav, nav_error, nav_paths = _run_nav(nav_paths, systems, base_files, rover_files, (base_path, rover_path))
    # GLONASS frequency numbers: the observation header's, else the navigation records'
    glo_k = ({sat: int(k) for sat, k in nav.dropna(subset=["glonass_k"]).groupby("sat")["glonass_k"].first().items()}
             if "glonass_k" in nav.columns else {})
    attrs, notes = signal_attributes({who: [("ubx" if is_ubx_log(p) else "rinex", p, None) for p in fs]
                                      for who, fs in (("base", base_files), ("rover", rover_files))}, sigs)
    warnings += notes
    hb, b = _read_receiver(base_files, sigs, glo_k, "base", warnings, attrs["base"])
    hr, r = _read_receiver(rover_files, sigs, glo_k, "rover", warnings, attrs["rover"])
    # the channels without a usable phase, from the whole files (a phase's sign is the receiver's, not the window's);
    # single-point positions take every code, a channel left out for its phase too
    screened: list = []
    kept = [_without_unusable_channels(df, path, who, screened) for df, path, who in ((b, base_path, "base"),
                                                                                        (r, rover_path, "rover"))]
    b, r, hr, n_outside = _time_window(b, r, hr, opt, base_path, rover_path)
    if opt["start_gps_s"] is not None or opt["end_gps_s"] is not None:
        masks = window_masks(kept[0]["time_gps_s"].to_numpy(), kept[1]["time_gps_s"].to_numpy(), opt["start_gps_s"],
                             opt["end_gps_s"], float(opt["sync_tol_s"]), float(opt["max_age_s"]))
        kept = [df[m].reset_index(drop=True) for df, m in zip(kept, masks)]
    _refuse_disjoint_spans(b, r, float(opt["max_age_s"]), base_path, rover_path)
    if nav_error is not None:
        raise nav_error
    codes = tuple(_first_of_repeated_epochs(df, path, who, []) for df, path, who in ((b, base_path, "base"),
                                                                                      (r, rover_path, "rover")))
    b, r = (_first_of_repeated_epochs(df, path, who, warnings) for df, path, who in ((kept[0], base_path, "base"),
                                                                                     (kept[1], rover_path, "rover")))
    warnings += screened
    with naming_screened(screened):
        if auto:            # a header may list a signal its records never hold: 'auto' keeps those both files observe
            sigs, b, r = _observed_signals(sigs, b, r, {"base": base_path, "rover": rover_path}, warnings)
            opt["signals"] = tuple(sigs)
        check_common_signals(b, r, sigs, nav, {"base": str(base_path), "rover": str(rover_path),
                                               "nav": ", ".join(map(str, nav_paths))})
    return SimpleNamespace(b=b, r=r, hb=hb, hr=hr, nav=nav, nav_paths=nav_paths, sigs=sigs, base_files=base_files,
                           rover_files=rover_files, base_path=base_path, rover_path=rover_path, n_outside=n_outside,
                           warnings=warnings, screened=screened, codes=codes)


def _solution_warnings(res: dict, ep: dict, opt: dict, rover_path) -> list:
    """What a solution says beside its numbers: the rover epochs not used and why, a float variance out of the model,
    slips no receiver flagged, code steps taken out."""
    out = []
    if ep["dropped"]:
        out.append(f"{rover_path} (rover): {sum(ep['dropped'].values())} of {ep['rover_epochs']} epochs not used: "
                   + "; ".join(f"{n} {why}" for why, n in ep["dropped"].items())
                   + f" (max_age_s {opt['max_age_s']:g} s)")
    out += _float_variance_warning(res)
    ev = res["unflagged_slips"]
    out += unflagged_slip_text(ev["sat"], ev["signal"], ev["time_gps_s"])
    cs = res["code_clock_steps"]
    return out + code_steps_warning(cs["step_m"], cs["signal"], cs["time_gps_s"])


def _run_nav(nav_paths: list, systems: list, base_files: list, rover_files: list, paths: tuple) -> tuple:
    """(ephemerides, the CdgpsError to raise once the observation files are read, or None, what the ephemerides came
    from): the navigation files', else the u-blox logs' RXM-SFRBX ephemerides of ``systems``."""
    try:
        if nav_paths:
            return _nav(nav_paths, systems), None, nav_paths
        nav = _ubx_nav((*base_files, *rover_files))
        nav_error = None if nav is not None else CdgpsError(
            f"no broadcast ephemerides: no --nav given and neither {paths[0]} nor {paths[1]} is a u-blox log "
            f"with RXM-SFRBX ephemerides")
        nav = nav[nav["sat"].str[0].isin(systems)] if nav is not None else pd.DataFrame()
        return nav, nav_error, [f"RXM-SFRBX of {', '.join(str(p) for p in (*base_files, *rover_files) if is_ubx_log(p))}"]
    except CdgpsError as exc:
        return pd.DataFrame(), exc, nav_paths


def _base_antenna(header: dict, base_xyz_m, base_path) -> np.ndarray:
    """The base antenna's position, ECEF m: ``base_xyz_m`` as given, else its header's marker plus its ANTENNA: DELTA
    H/E/N (:func:`~cdgps_cli.model.gps.positioning.antenna_reference_point_m`, as RTKLIB's rinexhead); CdgpsError
    when there is none, or it is not on the Earth."""
    bx = np.asarray(base_xyz_m if base_xyz_m is not None else header["approx_position_xyz_m"] or (), dtype=float)
    if bx.shape != (3,):
        raise CdgpsError(f"{base_path}: the base has no position (no APPROX POSITION XYZ; give --base-xyz X Y Z)")
    _check_position(bx, f"{base_path} (base)", "--base-xyz" if base_xyz_m is not None else "its APPROX POSITION XYZ",
                    "" if base_xyz_m is not None else "; give the base's surveyed position with --base-xyz X Y Z")
    return bx if base_xyz_m is not None else antenna_reference_point_m(header, f"{base_path} (base)")


def _geometry_warnings(tables: dict) -> list:
    """The warnings of :func:`receiver_geometry`'s notes (``tables``: who → (path, geometry table)): satellites
    dropped for want of a healthy ephemeris, and phases without a pseudorange of their own."""
    out = [f"{path} ({who}): observations of {len(d)} satellite(s) without a healthy ephemeris covering them "
           f"dropped: " + ", ".join(f"{s} ({n} epochs)" for s, n in d.items())
           for who, (path, g) in tables.items() if (d := g.attrs["dropped"])]
    return out + [f"{path} ({who}): {sum(d.values())} phase observation(s) without a pseudorange of their own not "
                  f"used: " + ", ".join(f"{sig} {n}" for sig, n in d.items())
                  for who, (path, g) in tables.items() if (d := g.attrs["no_code"])]


def _code_noise_warning(code_noise: dict, paths: dict, intervals_s: dict) -> list:
    """A warning per receiver whose code noise ``--code-noise auto`` could not measure (fewer full windows of
    code-minus-carrier than it needs): its codes are then weighed as modelled, which a low-cost receiver's are not
    (a u-blox M8P: 47 times the model's variance), so its float σ and integer tests may be optimistic.  Why: a
    receiver whose epochs (``intervals_s``, its nominal interval, s) put fewer than three in a window (a 30 s CORS
    file) has no full window at all; otherwise its arcs were too short or cut too often by slips and gaps."""
    if code_noise.get("mode") != "auto":
        return []

    def why(who: str) -> str:
        dt = intervals_s.get(who, math.nan)
        if math.isfinite(dt) and 3.0 * dt > CODE_NOISE_WINDOW_S:
            return (f"its epochs, {dt:g} s apart, put fewer than the 3 a {CODE_NOISE_WINDOW_S:g} s window of code "
                    f"minus carrier needs in each")
        return (f"{code_noise['windows'][who]} full {CODE_NOISE_WINDOW_S:g} s windows of code minus carrier without a "
                f"slip or a gap, {CODE_NOISE_MIN_WINDOWS} needed")
    return [f"{paths[who]} ({who}): its code noise could not be measured ({why(who)}): its codes are weighed as "
            f"modelled, and a low-cost receiver's are noisier (--code-noise; the float σ may then be optimistic)"
            for who in ("base", "rover") if not np.isfinite(code_noise[who])]


#: above this variance factor of the float positions (σ doubled) ``rtk`` says that it scaled them
FLOAT_VARIANCE_WARNING = 4.0


def _float_variance_warning(res: dict) -> list:
    """A warning when the float positions' σ were scaled by more than :data:`FLOAT_VARIANCE_WARNING`
    (:func:`~cdgps_cli.estimation.rtk_multi.float_variance_factor`)."""
    fv = res.get("float_variance") or {}
    k = fv.get("factor")
    if k is None or not k > FLOAT_VARIANCE_WARNING:
        return []
    return [f"the forward and backward float solutions disagree by {k:.3g} times the variance their σ give (more "
            f"than the {fv['threshold']:.3g} chance allows for {fv['independent_samples']:.3g} independent samples; "
            f"the receivers' errors are correlated in time, e.g. code multipath): the float epochs' σ are scaled by "
            f"{k ** 0.5:.3g} (float_variance in the summary)"]


def _summary(res: dict, per_epoch: bool) -> dict:
    """The JSON summary's fields of a :func:`solve_rtk` solution (``per_epoch``: solved again with the rover's
    troposphere at each fixed epoch)."""
    c = res["code_noise"]
    return {"epochs": int(len(res["time_gps_s"])), "fixed_pct": float(100 * res["fixed"].mean()),
            "fixed_epochs": int(res["fixed"].sum()), "direction": res["direction"],
            "fixes_rejected": res["fixes_rejected"], "partial_fixes": res["partial_fixes"],
            "wrong_fix_resets": res["wrong_fix_resets"], "ambiguities_released": res["ambiguities_released"],
            "unflagged_slips": res["unflagged_slips"],         # slips no receiver flagged: a new ambiguity from each
            "float_variance": res["float_variance"],      # combined mode (the passes' disagreement); null for one pass
            "age_noise": res["age_noise"], "code_clock_steps": res["code_clock_steps"],
            "code_noise": {"mode": c["mode"], "variance_factor": c["factor"],       # an estimate not made: null
                           "estimates": {w: (float(c[w]) if np.isfinite(c[w]) else None) for w in ("base", "rover")},
                           "windows": c["windows"]},
            "last_xyz_m": res["last_xyz_m"].tolist(),     # the last epoch's solution (fixed when it is), ECEF m
            "static_xyz_m": None if res["static_xyz_m"] is None else res["static_xyz_m"].tolist(),  # --mode static only
            "iono_model": res["iono_model"],
            "wet_troposphere": res["wet_troposphere"],       # zenith wet delays: estimated (last values, σ) or neglected
            "rover_troposphere": "at each epoch's solution" if per_epoch else "at the a-priori position"}


OUTPUT_FORMATS = {".pos": "RTKLIB .pos", ".nmea": "NMEA GGA", ".gga": "NMEA GGA", ".geojson": "GeoJSON", ".csv": "CSV"}


def _solution_columns(res, base_xyz):
    """Per epoch: ECEF position (fixed where fixed), its covariance (ECEF), quality, geodetic and
    ENU-baseline coordinates and the ENU covariance."""
    fixed = res["fixed"]
    xyz, cov = reported_positions(res)
    lat, lon, h = ecef_to_geodetic(xyz)
    R = enu_matrix(lat, lon)                                   # (n, 3, 3) rows e, n, u
    cov_enu = np.einsum("nij,njk,nlk->nil", R, cov, R)
    enu = ecef_to_enu(xyz, base_xyz)
    q = np.where(fixed, Q_FIX, Q_FLOAT)
    return xyz, cov, q, np.degrees(lat), np.degrees(lon), h, enu, cov_enu


def _velocity_enu(res, lat_deg, lon_deg):
    """Constant-velocity mode's velocity per epoch (fixed where fixed, else float) in the local east, north, up
    axes at the rover (n, 3; m/s), its covariance (n, 3, 3; m²/s²) and σ (n, 3; m/s); None in the other modes."""
    if "float_vel_m_s" not in res:
        return None
    fixed = res["fixed"]
    v = np.where(fixed[:, None], res["fixed_vel_m_s"], res["float_vel_m_s"])
    C = np.where(fixed[:, None, None], res["fixed_vel_cov_m2_s2"], res["float_vel_cov_m2_s2"])
    R = enu_matrix(np.radians(lat_deg), np.radians(lon_deg))          # (n, 3, 3) rows e, n, u
    C_enu = np.einsum("nij,njk,nlk->nil", R, C, R)
    return np.einsum("nij,nj->ni", R, v), C_enu, np.sqrt(np.abs(np.einsum("nii->ni", C_enu)))


def _pos_frame(frame: str, xyz, cov, llh, enu, cov_enu, base_xyz) -> tuple:
    """A .pos file's coordinates (n, 3) and their covariance (n, 3, 3; m²) in ``frame`` (RTKLIB's out-solformat):
    "llh" latitude, longitude (deg), height (m) with the covariance in north, east, up at the rover; "xyz" ECEF with
    its ECEF covariance; "enu" the baseline's east, north, up at the base (RTKLIB's e/n/u-baseline) with the
    covariance turned to those axes."""
    if frame == "llh":
        return np.c_[llh[0], llh[1], llh[2]], cov_enu[:, [1, 0, 2]][:, :, [1, 0, 2]]
    if frame == "xyz":
        return xyz, cov
    bl, bo, _ = ecef_to_geodetic(np.asarray(base_xyz, float))
    R = enu_matrix(bl, bo)                                      # (3, 3) rows e, n, u at the base
    return enu, np.einsum("ij,njk,lk->nil", R, cov, R)


def _partial_ratio_note(q, ratio, opt: dict) -> list:
    """A .pos header line when a float (Q=2) line's ratio passes the test: there only part of the DD ambiguities was
    fixed (partial fixing; the ratio is that part's) or, combined, the other pass contradicted the fix, and the
    position stays float (RTKLIB 2.4.3 fixes no part: a tool that reads ratio ≥ 3 as fixed would be misled; the CSV's
    n_dd_ambiguities counts the ambiguities fixed)."""
    n = int(np.sum((np.asarray(q) == 2) & (np.asarray(ratio) >= opt["ratio"])))
    if not n:
        return []
    return [f"ratio     : on {n} float (Q=2) line(s) the ratio is {opt['ratio']:g} or more while the position stays "
            f"float: only part of the DD ambiguities was fixed (partial fixing) or the other pass contradicted the fix "
            f"(combined); Q says whether the position is fixed"]


def _window_text(opt: dict) -> str:
    """The rover epochs asked for (``start_gps_s`` / ``end_gps_s``) as a solution header says them; "" without."""
    lo, hi = opt.get("start_gps_s"), opt.get("end_gps_s")
    if lo is None and hi is None:
        return ""
    return (f", rover epochs {'its first' if lo is None else gps_time_str(lo)} – "
            f"{'its last' if hi is None else gps_time_str(hi)} (--start-time / --end-time)")


def solution_text(res: dict, sigs, opt: dict, out_path, base_xyz, *, inputs=()) -> str:
    """The solution as the text of the format ``out_path``'s suffix names (:data:`OUTPUT_FORMATS`;
    any other suffix: CSV).  CSV columns: ``time_gps_s, x_m, y_m, z_m, fixed, n_dd_ambiguities, ratio,
    n_satellites, age_s, e_m, n_m, u_m`` (ENU baseline from the base) and ``sigma_e_m, sigma_n_m, sigma_u_m``;
    in constant-velocity mode also the velocity in the rover's east, north, up axes, ``ve_m_s, vn_m_s, vu_m_s``,
    and its ``sigma_ve_m_s, sigma_vn_m_s, sigma_vu_m_s`` (in ``.pos``: RTKLIB's velocity columns, in GeoJSON:
    each point's properties)."""
    xyz, cov, q, lat, lon, h, enu, cov_enu = _solution_columns(res, base_xyz)
    vel = _velocity_enu(res, lat, lon)
    t, ns, age = res["time_gps_s"], res["n_satellites"], res["base_age_s"]
    ratio = np.array([finite_or(r, 0.0) for r in res["ratio"]])
    sig_enu = np.sqrt(np.abs(np.einsum("nii->ni", cov_enu)))
    suffix = Path(str(out_path)).suffix.lower()
    passes = _passes_text(opt["mode"], res["direction"], res.get("static_every_line_all_epochs"))
    desc = (f"cdgps {__version__} rtk, mode {opt['mode']}, {passes}, "
            f"signals {' '.join(sigs)}, mask {opt['mask_deg']:g} deg, "
            f"ratio {opt['ratio']:g}, max age {opt['max_age_s']:g} s, ionosphere {res['iono_model']}"
            + (", zenith wet delays estimated" if res["wet_troposphere"]["model"] == "estimated" else "")
            + (f", receiver antenna models from {opt['antex']}" if opt.get("antex") else "")
            + _window_text(opt))
    if suffix == ".pos":
        bl, bo, bh = ecef_to_geodetic(np.asarray(base_xyz, float))
        ref = (" ".join(f"{v:.4f}" for v in np.asarray(base_xyz, float)) if opt["pos_frame"] == "xyz"   # as RTKLIB's
               else f"{np.degrees(bl):.9f} {np.degrees(bo):.9f} {bh:.4f}")
        header = [f"program   : {desc}", *(f"inp file  : {p}" for p in inputs), f"ref pos   : {ref}",
                  *_partial_ratio_note(q, ratio, opt)]
        neu = None if vel is None else (vel[0][:, [1, 0, 2]], vel[1][:, [1, 0, 2]][:, :, [1, 0, 2]])
        coords, frame_cov = _pos_frame(opt["pos_frame"], xyz, cov, (lat, lon, h), enu, cov_enu, base_xyz)
        return pos_text(t, coords, q, ns, frame_cov, age, ratio, frame=opt["pos_frame"], header=header,
                        velocity_neu=neu)
    if suffix in (".nmea", ".gga"):
        return nmea_gga_text(t, lat, lon, h, q, ns, age)
    if suffix == ".geojson":
        return geojson_text(t, lat, lon, h, q, ns, sig_enu, properties={"program": desc, "inputs": [str(p) for p in inputs],
                                                                        "height": "ellipsoidal (WGS84), m"},
                            velocity_enu=None if vel is None else (vel[0], vel[2]))
    buf = _io.StringIO()
    for s in sigs:
        buf.write(f"# signal {s} wavelength_m {signal(s).wavelength_m:.9f}\n" if not signal(s).fdma_step_hz
                  else f"# signal {s} FDMA (wavelength per satellite)\n")
    if any(signal(x).fdma_step_hz for x in sigs):
        buf.write(f"# glonass {'fixed (glonass_fix: identical receivers)' if opt['glonass_fix'] else 'float'} "
                  "(FDMA: DD ambiguities are not integer multiples of one wavelength)\n")
    buf.write(f"# mode {opt['mode']}, {passes}, ionosphere {res['iono_model']} baseline_km {res['baseline_km']:.3f} ratio {opt['ratio']}\n")
    buf.write(csv_text({"time_gps_s": t, "x_m": xyz[:, 0], "y_m": xyz[:, 1], "z_m": xyz[:, 2],
                        "fixed": res["fixed"].astype(int), "n_dd_ambiguities": res["n_dd_ambiguities"],
                        "ratio": res["ratio"], "n_satellites": ns, "age_s": age,
                        "e_m": enu[:, 0], "n_m": enu[:, 1], "u_m": enu[:, 2],
                        "sigma_e_m": sig_enu[:, 0], "sigma_n_m": sig_enu[:, 1], "sigma_u_m": sig_enu[:, 2],
                        **_velocity_columns(vel)},
                       float_format="%.4f"))
    return buf.getvalue()


def _passes_text(mode: str, direction: str, every_line: bool | None = None) -> str:
    """The passes a solution comes from, for the files' headers; in static mode, which line holds the solution from
    every epoch (``every_line``: whether static combined gave it to every line, :func:`_static_smoothed`)."""
    text = {"forward": "forward pass", "backward": "backward pass",
            "combined": "forward and backward passes combined"}[direction]
    if mode == "static":
        text += {"forward": " (the last line: the solution from every epoch)",
                 "backward": " (the first line: the solution from every epoch)",
                 "combined": " (every line: the solution from every epoch)" if every_line is not False else
                 " (each line the passes' combination at that epoch: their solutions from every epoch disagreed)"
                 }[direction]
    return text


def _velocity_columns(vel) -> dict:
    """The CSV's velocity columns (m/s) of :func:`_velocity_enu`'s result; none without a velocity."""
    if vel is None:
        return {}
    v, _, sd = vel
    return {**{f"v{a}_m_s": v[:, i] for i, a in enumerate("enu")},
            **{f"sigma_v{a}_m_s": sd[:, i] for i, a in enumerate("enu")}}


_GEOCENTRIC_RANGE_M = GEOCENTRIC_RANGE_M          # one home: config/limits.py


def _check_position(xyz, who: str, source: str, fix: str = "") -> None:
    r = float(np.linalg.norm(xyz))
    if not (np.all(np.isfinite(xyz)) and _GEOCENTRIC_RANGE_M[0] <= r <= _GEOCENTRIC_RANGE_M[1]):
        raise CdgpsError(f"{who}: position from {source} is {' '.join(f'{v:g}' for v in xyz)} m, {r / 1e3:.1f} km from the "
                         f"Earth's centre; expected an ECEF position on the Earth ({_GEOCENTRIC_RANGE_M[0] / 1e3:.0f}–"
                         f"{_GEOCENTRIC_RANGE_M[1] / 1e3:.0f} km){fix}")


def _rover_origin(header: dict, obs: pd.DataFrame, nav, base_xyz, path, warnings: list) -> np.ndarray:
    """The rover's a-priori position: its header's APPROX POSITION XYZ when that is on the Earth,
    else (no position, or 0 0 0 as u-blox converters write) the mean single-point position from its
    pseudoranges (a warning says so); and whether it is that single-point position."""
    hx = np.asarray(header.get("approx_position_xyz_m") or (0.0, 0.0, 0.0), dtype=float)
    r = float(np.linalg.norm(hx))
    if np.all(np.isfinite(hx)) and _GEOCENTRIC_RANGE_M[0] <= r <= _GEOCENTRIC_RANGE_M[1]:
        return hx, False
    x, sig = _single_point(obs, nav, base_xyz, f"{path} (rover)")
    if x is None:
        raise CdgpsError(f"{path} (rover): no usable APPROX POSITION XYZ and no {sig} pseudoranges covered by the "
                         f"navigation data for a single-point position")
    warnings.append(f"{path} (rover): no position on the Earth in the file (APPROX POSITION XYZ, RTCM 1005/1006: "
                    f"{' '.join(f'{v:g}' for v in hx)}); the a-priori position is the mean single-point position from "
                    f"its {sig} pseudoranges, refined by a float solution")
    return np.asarray(x, dtype=float), True


def _single_point(obs: pd.DataFrame, nav, x0, what: str, max_epochs: int | None = None) -> tuple:
    """(the static single-point position of a receiver's signal table from the pseudoranges of its GPS L1, else its
    first signal, ECEF m, from ``max_epochs`` epochs spread over the record (None: all), or None when it has none
    covered by the navigation data; that signal's name)."""
    sig = "G:L1" if (obs["signal"] == "G:L1").any() else str(obs["signal"].iloc[0])
    o = obs[obs["signal"].to_numpy() == sig]
    x = spp_spread(o["sat"].to_numpy(), o["time_gps_s"].to_numpy(), o["pseudorange_m"].to_numpy(), nav, x0_ecef_m=x0,
                   max_epochs=max_epochs, what=what)
    return x, sig


def _check_base_header(bx, obs: pd.DataFrame, nav, path) -> None:
    """CdgpsError when the base's header position ``bx`` is more than :data:`~cdgps_cli.config.options.
    HEADER_POSITION_TOL_M` from its single-point position (from :data:`~cdgps_cli.config.options.
    HEADER_CHECK_EPOCHS` epochs): every rover position would be as far off, and the warnings would blame the rover's
    header (a Trimble NetR9's RINEX 3.02 file 207 km off).  No check when no single-point position can be made."""
    try:
        spp, sig = _single_point(obs, nav, bx, f"{path} (base)", HEADER_CHECK_EPOCHS)
    except CdgpsError:
        return
    off = float(np.linalg.norm(spp - bx)) if spp is not None else 0.0
    if off > HEADER_POSITION_TOL_M:
        raise CdgpsError(f"{path} (base): its header position (APPROX POSITION XYZ) is {off / 1e3:.4g} km from its "
                         f"single-point position from its {sig} pseudoranges ({' '.join(f'{v:.1f}' for v in spp)}); "
                         f"every rover position would be as far off: give the base's surveyed position with --base-xyz "
                         f"X Y Z (the single-point one is good to a few metres)")


def _solve_where_the_rover_is(gb, gr, bx, rx, opt: dict, *, rover: tuple, nav: tuple, code_noise: dict, warnings: list):
    """:func:`solve_rtk`, solved again when its fixed epochs show the rover's troposphere was computed where the
    rover is not (a height or the fixed median more than :data:`ROVER_ORIGIN_TOL_M` from the origin ``rx``): the
    origin moved to the fixed median when that is far (a warning says so), the delay at each fixed epoch's
    position.  ``rover`` is (observation table, path, whether ``rx`` is a single-point position, antenna model or
    None, what gave the file's position: None for a RINEX header), ``nav`` (table, paths), ``code_noise`` the observations' :func:`receivers_code_noise`.  Returns (solution, the rover's geometry
    table, whether it was solved again)."""
    r, rover_path, rx_from_spp, antenna, source = rover
    res = solve_rtk(gb, gr, bx, rx, options=opt, code_noise=code_noise)
    xyz_ep = _troposphere_positions(res, rx)
    moved = np.nanmedian(xyz_ep, axis=0) - rx if np.isfinite(xyz_ep).any() else np.zeros(3)
    far = np.linalg.norm(moved) > ROVER_ORIGIN_TOL_M
    if not (far or _heights_differ(xyz_ep, rx)):
        return res, gr, False
    if far:
        warnings.append(_origin_moved_note(rover_path, rx, moved, rx_from_spp, header_source=source))
        rx = rx + moved
        gr = _geometry(r, nav[0], rx, rover_path, "rover", nav[1], antenna)
        gr.attrs = {}
    gr = troposphere_at_epochs(gr, res["time_gps_s"], xyz_ep)
    return solve_rtk(gb, gr, bx, rx, options=opt, code_noise=code_noise), gr, True


def _place_rover(gb, gr, bx, rx, opt: dict, *, rover: tuple, nav: tuple, warnings: list):
    """The rover's origin moved to where it is (:func:`_static_float_offset`: its static float solution, or a moving
    rover's code mean) when that is more than :data:`ROVER_ORIGIN_TOL_M` away, with its geometry recomputed there: a single-point origin is metres off, and so
    may a header's be (u-blox converters), and the rover's troposphere (≈ 0.3 mm per metre of height) is computed at
    the origin.  ``rover`` is (observation table, path, whether ``rx`` is a single-point position, antenna model or
    None, what gave the file's position: None for a RINEX header), ``nav`` (table, paths).  Returns (origin, geometry)."""
    r, rover_path, from_spp, antenna, source = rover
    moved, to, apart_m = _static_float_offset(gb, gr, bx, rx, opt)
    if opt["mode"] == "static" and apart_m is not None:     # as init's static fit (baseline._check_static_fit)
        raise CdgpsError(f"{rover_path} (rover): the rover moves (its static float solution is {apart_m:.0f} m from the "
                         f"mean position of its code: its phase fits no static position), and --mode static assumes it "
                         f"does not; use --mode kinematic (or constant-velocity)")
    if to.startswith("undetermined"):
        warnings.append(f"{rover_path} (rover): {to.removeprefix('undetermined: ')}: its a-priori position is kept")
        return rx, gr
    if np.linalg.norm(moved) <= ROVER_ORIGIN_TOL_M:
        return rx, gr
    if not from_spp:                      # (a single-point origin's own warning already says it is refined)
        warnings.append(_origin_moved_note(rover_path, rx, moved, False, to, header_source=source))
    gr = _geometry(r, nav[0], rx + moved, rover_path, "rover", nav[1], antenna)
    gr.attrs = {}
    return rx + moved, gr


def _static_float_offset(gb, gr, bx, rx, opt: dict) -> tuple:
    """The rover's offset from ``rx`` (ECEF m) to where it is, what that is (for the warning) and, when the rover
    moves, how far its static float solution is from the code's mean position (m; else None): its static float
    solution by the static engine's batch (no fixing), with rtk's signals, mask, weights and epoch pairing; or, when
    that lies more than :data:`MOVING_ROVER_FLOAT_M` from the same least squares on the code alone (the phase of a
    moving rover fits no static position), the code's mean position.  Zeros when that batch cannot serve these
    data (the solve that follows reports their errors).  The origin only needs to be where the rover is to a metre
    (its troposphere and the linearization)."""
    from cdgps_cli.estimation.static_engine import static_float_offset, static_option_names
    keys = static_option_names()
    try:
        off, cov, code_only = static_float_offset(gb, gr, bx, rx, {**{k: v for k, v in opt.items() if k in keys},
                                                                   "fix": False, "fix_and_hold": False,
                                                                   "code_noise": "model"})
        if not (np.all(np.isfinite(off)) and np.all(np.isfinite(cov))):
            return np.zeros(3), "", None
        if np.linalg.norm(off) <= ROVER_ORIGIN_TOL_M:
            return off, "its static float solution", None
        if not _determined(off, cov):         # (nor can it tell a moving rover: its distance to the code's mean is noise)
            return np.zeros(3), _undetermined_note("its static float solution", off, cov), None
        code, code_cov = code_only()
    except (CdgpsError, np.linalg.LinAlgError):
        return np.zeros(3), "", None
    apart = float(np.linalg.norm(off - code))
    if np.all(np.isfinite(code)) and apart > MOVING_ROVER_FLOAT_M:
        if not _determined(code, code_cov):
            return np.zeros(3), _undetermined_note("the mean position of its code", code, code_cov), None
        return code, (f"the mean position of its code (its static float solution lands {apart:.0f} m from that mean: "
                      f"the rover moves, and its phase fits no static position)"), apart
    return off, "its static float solution", None


def _determined(offset_m, cov_m2) -> bool:
    """Whether an offset (3,) m of covariance (3, 3) m² says where the rover is: longer than
    :data:`ORIGIN_MOVE_SIGMAS` times its 3-D σ (two satellites over ten minutes of a 35 km pair gave a static float
    14.6 m away with σ of tens of metres: the data do not place the rover, and moving its a-priori position there
    would only add that noise to its troposphere and linearization)."""
    return bool(np.linalg.norm(offset_m) > ORIGIN_MOVE_SIGMAS * np.sqrt(max(float(np.trace(cov_m2)), 0.0)))


def _undetermined_note(what: str, offset_m, cov_m2) -> str:
    """The reason (prefixed ``undetermined: ``) an offset that :func:`_determined` refuses was not used."""
    return (f"undetermined: {what} is {np.linalg.norm(offset_m):.1f} m from its a-priori position with a 3-D σ of "
            f"{np.sqrt(max(float(np.trace(cov_m2)), 0.0)):.1f} m (more than 1/{ORIGIN_MOVE_SIGMAS:g} of that distance: "
            f"these data do not say where the rover is)")




def _fixed_positions(res: dict) -> np.ndarray:
    """ECEF position (m) of each fixed epoch of a :func:`solve_rtk` solution, NaN rows elsewhere (a float
    position may be metres off: it says nothing about where the rover's troposphere is)."""
    return np.where(res["fixed"][:, None], res["fixed_xyz_m"], np.nan)


def _troposphere_positions(res: dict, origin_m: np.ndarray) -> np.ndarray:
    """Where the rover is at each epoch, for its troposphere (ECEF m; NaN rows: at the origin): the fixed position
    of a fixed epoch, else the float position when its height is off the origin's by more than three times its
    3-D σ and :data:`ROVER_ORIGIN_TOL_M` (a rover that climbs, and whose phases fix nothing while its troposphere
    is computed at the origin: a simulated rover 1 km up had its float 1 m high and no fix); a float position
    within that says nothing about where the rover's troposphere is."""
    xyz = _fixed_positions(res)
    flt = res["float_xyz_m"]
    dh = np.abs(ecef_to_geodetic(flt)[2] - ecef_to_geodetic(origin_m)[2])
    sigma = np.sqrt(np.abs(np.trace(res["float_cov_m2"], axis1=1, axis2=2)))
    away = ~res["fixed"] & np.isfinite(dh) & (dh > np.maximum(ROVER_ORIGIN_TOL_M, 3.0 * sigma))
    xyz[away] = flt[away]
    return xyz


def _heights_differ(xyz_m: np.ndarray, origin_m: np.ndarray) -> bool:
    """Whether an epoch's height is more than :data:`ROVER_ORIGIN_TOL_M` from the origin's."""
    h = ecef_to_geodetic(xyz_m)[2]
    return bool(np.any(np.abs(h[np.isfinite(h)] - ecef_to_geodetic(origin_m)[2]) > ROVER_ORIGIN_TOL_M))


def _origin_moved_note(path, rx, moved, from_spp: bool, to: str = "", header_source: str | None = None) -> str:
    """The warning that the rover's a-priori position was moved to its solution (up = height change, m); ``to``
    names where it was moved before solving (default: solved again from the solution's median position);
    ``header_source`` what gave the file's own position (None: a RINEX header's APPROX POSITION XYZ)."""
    lat, lon, _ = ecef_to_geodetic(rx)
    up = float(enu_matrix(lat, lon)[2] @ moved)
    source = "single-point position" if from_spp else (header_source or "APPROX POSITION XYZ")
    if to:
        return (f"{path} (rover): its {source} is {np.linalg.norm(moved):.1f} m (height {up:+.1f} m) from {to}, "
                f"more than {ROVER_ORIGIN_TOL_M:g} m: the rover's a-priori position (its troposphere, about 1 mm of "
                f"height per metre of height error otherwise) moved there before solving")
    return (f"{path} (rover): its {source} is {np.linalg.norm(moved):.1f} m from the solution (height {up:+.1f} m), "
            f"more than {ROVER_ORIGIN_TOL_M:g} m: solved again from the solution's median position, with the rover's "
            f"troposphere at each epoch's position (about 1 mm of height per metre of height error otherwise)")


def _geometry(df, nav, xyz, path, who, nav_paths, antenna=None):
    """receiver_geometry with the file names and spans in its errors; with ``antenna`` (an
    :class:`~cdgps_cli.io.antex.AntennaModel`) its phase-centre model taken out of the phases and codes
    (:func:`with_antenna_model`)."""
    try:
        g = receiver_geometry(df, nav, xyz)
    except CdgpsError as exc:
        t = df["time_gps_s"].to_numpy()
        toe = nav["toe_gps_s"].to_numpy() if "toe_gps_s" in nav.columns and len(nav) else np.zeros(0)
        span = (f"observations {gps_time_str(float(t.min()))} – {gps_time_str(float(t.max()))}" if t.size else "no observations")
        eph = (f"ephemerides with toe {gps_time_str(float(toe.min()))} – {gps_time_str(float(toe.max()))}" if toe.size
               else "no ephemerides")
        raise CdgpsError(f"{path} ({who}) and {', '.join(map(str, nav_paths))}: {exc}; {span}, {eph} (give the "
                         f"navigation file(s) of the observations' day)") from None
    if antenna is None:
        return g
    try:
        return with_antenna_model(g, antenna, xyz)
    except CdgpsError as exc:
        raise CdgpsError(f"{path} ({who}): {exc}; leave that signal out (--signals), give an ANTEX file that has it, "
                         f"or --{who}-antenna none") from None


def _antenna_models(opt: dict, headers: dict, paths: dict, warnings: list) -> dict:
    """{"base": model, "rover": model} of option ``antex`` (:func:`~cdgps_cli.pipeline.antenna_models.antenna_models`;
    each receiver's antenna is its option's, ``base_antenna`` / ``rover_antenna``, or its RINEX header's)."""
    return antenna_models(opt["antex"], {"base": opt["base_antenna"], "rover": opt["rover_antenna"]}, headers, paths,
                          warnings, {w: f"--{w}-antenna" for w in ("base", "rover")})


def is_ubx_log(path) -> bool:
    """Whether the file is a u-blox log (UBX frames) rather than a RINEX text file: plain or gzip-compressed (the
    other compressions are the RINEX readers': compress, bzip2, zip), its first line (decompressed) not a RINEX
    header line and a UBX sync word in its first 64 KiB."""
    try:
        with open(path, "rb") as f:
            head = f.read(65536)
    except OSError as exc:
        raise CdgpsError(f"{path}: cannot read ({exc.strerror})") from None
    if head.startswith(b"\x1f\x8b"):           # gzip: a u-blox log as RINEX files are, judged by its first 64 KiB
        import gzip  # noqa: PLC0415
        import zlib  # noqa: PLC0415

        try:
            with gzip.open(path, "rb") as g:
                head = g.read(65536)
        except (OSError, EOFError, zlib.error):
            return False                         # (the RINEX reader names a damaged archive)
    elif head.startswith(COMPRESSED_MAGIC):
        return False
    first = head.split(b"\n", 1)[0]
    return b"RINEX VERSION / TYPE" not in first and b"\xb5\x62" in head


@functools.lru_cache(maxsize=4)
def _ubx_decoded(path: str, mtime_ns: int, size: int):
    """A u-blox log read once per command: its summary (RTCM base position), every signal's table
    with loss of lock from the lock times and half-cycle status, and its SFRBX ephemerides."""
    return _ubx_table(path)


def _ubx_table(path: str, data: bytes | None = None):
    """:func:`_ubx_decoded`'s decoding of a log (``data``: its bytes when joined from consecutive logs, ``path``
    naming them)."""
    from cdgps_cli.io.ubx import UBX_SIGNALS, read_ubx_log, read_ubx_signals  # noqa: PLC0415
    from cdgps_cli.measurement.channels import ubx_loss_of_lock  # noqa: PLC0415 (not the ingest pipeline: its imports are the MCAP run's)

    tab = read_ubx_signals(path, list(UBX_SIGNALS), data=data)
    # each row's channel (satellite and signal) as one integer: the same channels as "sat:signal" strings, whose
    # sort and comparisons cost 3x more (the loss-of-lock bits depend on the channels, not on their order)
    sat_code, _ = pd.factorize(tab["sat"])
    sig_code, sig_names = pd.factorize(tab["signal"])
    key = sat_code.astype(np.int64) * max(len(sig_names), 1) + sig_code
    tab["lli"] = ubx_loss_of_lock(tab["time_gps_s"].to_numpy(), key, tab["phase_cycles"].to_numpy(),
                                  tab["lock_time_ms"].to_numpy(dtype=np.float64), tab["half_cycle"].to_numpy() == 1)
    info, _, nav = read_ubx_log(path, data=data)
    return info, tab.drop(columns=["lock_time_ms", "half_cycle"]), nav


def _ubx(path):
    st = Path(path).stat()
    return _ubx_decoded(str(path), st.st_mtime_ns, st.st_size)


def _as_list(paths) -> list:
    return [paths] if isinstance(paths, (str, Path)) else list(paths)


#: header fields that must agree between the files of one receiver's record: another receiver, site or antenna
#: (other clock, biases, phase centre), or another tracking mode of a signal (another phase bias), is not one record
ONE_RECEIVER_FIELDS = ("marker_name", "receiver_type", "antenna_type", "signal_codes")


def _read_receiver(files: list, sigs, glo_k, who: str, warnings: list,
                   attributes: dict | None = None) -> tuple[dict, pd.DataFrame]:
    """A receiver's header and signal table (:func:`_read_observations`) from its file, or from its consecutive
    files (hourly, daily) joined in time order into one record: an epoch a later file repeats is taken from the
    earlier file, files that interleave are refused (:func:`~cdgps_cli.io.log_sequence.join_tables`), and the
    files must be of one receiver (:data:`ONE_RECEIVER_FIELDS`; the header of the first file in time order is
    kept)."""
    if len(files) == 1:
        return _read_observations(files[0], sigs, glo_k, who, warnings, attributes)
    ubx = all(is_ubx_log(p) for p in files)
    said: list = []               # consecutive u-blox logs are decoded again as one stream (below): not their pieces'
    try:
        reads = [_read_observations(p, sigs, glo_k, who, said, attributes) for p in files]
    except CdgpsError:            # (a file without some signal asked: its systems may be in files of their own)
        split = None if any(is_ubx_log(p) for p in files) else signals_by_file(files, sigs)
        if split is None:
            raise
        return _merged_systems(files, split, glo_k, who, warnings, attributes)
    tab, report, order = join_tables([(str(p), df) for p, (_, df) in zip(files, reads)], "time_gps_s", np.nan,
                                     gps_time_str, what=f"{pieces_text(files)} ({who})")
    refuse_another_receiver(who, [reads[i][0] for i in order], [files[i] for i in order], ONE_RECEIVER_FIELDS)
    if ubx and not report.overlaps:     # one byte stream in time order: a frame cut by a file boundary is whole again
        try:
            return _ubx_stream([files[i] for i in order], sigs, who, warnings)
        except CdgpsError as exc:       # the stream goes back in time (a piece repeated under another name …)
            if "earlier than the previous one" not in str(exc):
                raise
    if ubx:                              # logs that repeat one another's epochs: joined table by table, as RINEX
        said = [w for w in said if "truncated frame" not in w]
        warnings.append(f"{pieces_text(files)} ({who}): the u-blox logs repeat one another's epochs: joined log by log "
                        f"(an epoch repeated kept once, from the earlier log); a frame cut at a log's end is not "
                        f"joined again")
    warnings.extend(said + report.warnings)
    tab.attrs = {}
    joined = _joined_file_epochs([h for h, _ in reads])
    return {**reads[order[0]][0], "file_epochs": None if joined is None else int(joined.t.size),
            "file_epoch_times": joined}, tab


def _merged_systems(files: list, split: list, glo_k, who: str, warnings: list,
                    attributes: dict | None) -> tuple[dict, pd.DataFrame]:
    """A receiver's header and signal table from its files of one system each (:func:`~cdgps_cli.io.rinex_signals.signals_by_file`): each read
    with its own signals, their rows merged epoch by epoch (in time order, the files' order within an epoch); the
    header of the first file, its epochs those of every file.  CdgpsError when the files do not cover one span (a
    file per system is written over the same time) or are not of one receiver."""
    reads = [_read_observations(p, sub, glo_k, who, warnings, attributes) for p, sub in zip(files, split)]
    refuse_spans_apart(who, files, split, [df["time_gps_s"].to_numpy() for _, df in reads])
    refuse_another_receiver(who, [h for h, _ in reads], files, tuple(f for f in ONE_RECEIVER_FIELDS
                                                                    if f != "signal_codes"))
    tab = merge_signal_tables([df for _, df in reads])
    warnings.append(systems_merged_text(who, files, split))
    joined = _joined_file_epochs([h for h, _ in reads])
    codes = {k: v for h, _ in reads for k, v in (h.get("signal_codes") or {}).items()}
    return {**reads[0][0], "signal_codes": codes, "file_epochs": None if joined is None else int(joined.t.size),
            "file_epoch_times": joined}, tab


def _joined_file_epochs(headers: list):
    """The observation epochs of consecutive files joined (:class:`~cdgps_cli.io.rinex_signals.EpochTimes`): the union
    of each file's epochs (``file_epoch_times``, those without a phase of the signals used too: an epoch two files
    both hold counts once); None when a file's are not known."""
    from cdgps_cli.io.rinex_signals import EpochTimes  # noqa: PLC0415

    times = [h.get("file_epoch_times") for h in headers]
    if any(t is None for t in times):
        return None
    return EpochTimes(np.unique(np.concatenate([t.t for t in times])))


def _ubx_stream(files: list, sigs, who: str, warnings: list) -> tuple[dict, pd.DataFrame]:
    """Consecutive u-blox logs of one receiver (in time order) read as one log: their bytes joined, decoded as
    :func:`_read_observations` decodes one (the position of the last RTCM 1005/1006; what the stream lost named
    in ``warnings``)."""
    from cdgps_cli.io.gnss_sequence import ubx_bytes  # noqa: PLC0415

    name = pieces_text(files)
    parts = [ubx_bytes(p) for p in files]
    info, tab, nav = _ubx_table(name, b"".join(parts))
    starts = np.cumsum([0] + [len(b) for b in parts])

    def in_piece(o: int) -> str:                  # a stream offset as the file and byte it is in
        i = int(np.searchsorted(starts, o, side="right")) - 1
        return f"{Path(files[i]).name} byte {o - starts[i]}"
    where = {k: [in_piece(int(o)) for o in info[k]] for k in ("bad_frame_offsets", "undecodable_frame_offsets",
                                                               "bad_rtcm_offsets") if info.get(k)}
    return _ubx_receiver(name, ({**info, **where}, tab, nav), sigs, who, warnings)


def _ubx_receiver(name, decoded: tuple, sigs, who: str, warnings: list) -> tuple[dict, pd.DataFrame]:
    """A decoded u-blox log (``_ubx_table``'s) as a receiver's header (the last RTCM 1005/1006 position) and signal
    table of ``sigs``; what the log lost named in ``warnings``."""
    from cdgps_cli.io.ubx import integrity_problems  # noqa: PLC0415

    info, tab, _ = decoded
    problems = integrity_problems(info)
    if problems:
        warnings.append(f"{name} ({who}): skipped: {'; '.join(problems)}")
    base = info.get("rtcm_base")
    return ({"approx_position_xyz_m": base["arp_ecef_m"] if base else None, "position_source": "RTCM 1005/1006 position",
             "file_epochs": int(np.unique(tab["time_gps_s"].to_numpy()).size)},
            tab[tab["signal"].isin(list(sigs))].reset_index(drop=True))


def _read_observations(path, sigs, glo_k, who: str, warnings: list,
                       attributes: dict | None = None) -> tuple[dict, pd.DataFrame]:
    """A receiver's header (``approx_position_xyz_m``) and signal table, from RINEX or from a u-blox
    log's RXM-RAWX (loss of lock from the lock times and half-cycle status; the position from its
    RTCM 1005/1006 when it has one; what the log lost — bad checksums, skipped bytes, a frame cut by
    the end of the file — named in ``warnings``, as ``ingest`` does)."""
    if not is_ubx_log(path):
        header, obs = read_rinex_signals(path, sigs, glo_k, attributes=attributes)
        header["file_epochs"] = obs.attrs.pop("file_epochs", None)
        header["file_epoch_times"] = obs.attrs.pop("file_epoch_times", None)
        unknown = obs.attrs.pop("glonass_without_frequency", None)
        if unknown:
            warnings.append(glonass_without_frequency_text(f"{path} ({who})", unknown))
        back = obs.attrs.pop("epochs_out_of_order", None)
        if back:
            warnings.append(out_of_order_text(f"{path} ({who})", back[0], back[1]))
        warnings.extend(reading_notes(header, f"{path} ({who})"))
        return header, obs
    return _ubx_receiver(path, _ubx(path), sigs, who, warnings)


#: why a rover epoch read from its file never reached the epoch pairing
NO_GEOMETRY = "without a satellite position (no pseudorange, or no healthy ephemeris)"


def _count_epochs_without_geometry(pairing: dict, rover: pd.DataFrame, geometry: pd.DataFrame) -> dict:
    """The epoch pairing's summary with the rover epochs read but left without a geometry row (every row of the
    epoch lacked a pseudorange, or an ephemeris covering it) counted too: in ``rover_epochs`` and in ``dropped``."""
    return with_dropped(pairing, NO_GEOMETRY,
                         np.setdiff1d(rover["time_gps_s"].to_numpy(), geometry["time_gps_s"].to_numpy()).size)


#: why a rover epoch of its file never reached the signal table
NO_PHASE = "without a carrier phase of the signals used"


def _count_epochs_without_phase(pairing: dict, header: dict, rover: pd.DataFrame) -> dict:
    """The epoch pairing's summary with the rover file's epochs that hold no carrier phase of the signals used
    (code only, no satellite, other signals: the signal table has no row of them) counted in ``rover_epochs``
    and ``dropped``; ``header["file_epochs"]``: the file's distinct observation epochs (None: not known, e.g.
    several files joined)."""
    n_file = header.get("file_epochs")
    return with_dropped(pairing, NO_PHASE, 0 if n_file is None else
                         int(n_file) - int(np.unique(rover["time_gps_s"].to_numpy()).size))


def _unrecorded(signal_name: str, where: str) -> str:
    """The warning of a signal left out because a header lists it but no record of ``where`` holds its phase."""
    return f"{signal_name} not used: listed in the header of {where} but no record holds its phase"


def _observed_signals(sigs: list, base: pd.DataFrame, rover: pd.DataFrame, paths: dict, warnings: list):
    """(signals, base rows, rover rows) of the signals ``sigs`` that both receivers' records hold a phase of; each
    signal dropped (a header's observation type no record fills) is named in a warning; CdgpsError when none is left."""
    held = {who: set(df["signal"].unique()) for who, df in (("base", base), ("rover", rover))}
    keep = [s for s in sigs if s in held["base"] and s in held["rover"]]
    for s in sigs:
        if s not in keep:
            empty = [who for who in ("base", "rover") if s not in held[who]]
            warnings.append(_unrecorded(s, " and ".join(f"{paths[w]} ({w})" for w in empty)))
    if not keep:
        raise CdgpsError(f"{paths['base']} (base) and {paths['rover']} (rover) share no signal with phase "
                         f"observations: base holds {' '.join(sorted(held['base'])) or 'none'}, rover "
                         f"{' '.join(sorted(held['rover'])) or 'none'}")
    if len(keep) == len(sigs):
        return sigs, base, rover
    return (keep, *(df[df["signal"].isin(keep).to_numpy()].reset_index(drop=True) for df in (base, rover)))


def _ubx_signals(path) -> list[str]:
    return sorted(set(_ubx(path)[1]["signal"]))


def _ubx_nav(paths) -> pd.DataFrame | None:
    """Broadcast ephemerides decoded from the RXM-SFRBX frames of the u-blox logs among ``paths``."""
    navs = [_ubx(p)[2] for p in dict.fromkeys(map(str, paths)) if is_ubx_log(p)]
    navs = [n for n in navs if n is not None and len(n)]
    if not navs:
        return None
    nav = pd.concat(navs, ignore_index=True).drop_duplicates(["sat", "toe_gps_s"]).reset_index(drop=True)
    nav.attrs = {}
    return nav


def _auto_signals(base_files, rover_files, nav_paths, warnings: list) -> list[str]:
    """Every signal both receivers' files hold (a receiver's files together) whose system has ephemerides in the
    navigation files (systems the navigation data lack are named in a warning); CdgpsError when none is left."""
    return common_signals({"base": _as_list(base_files), "rover": _as_list(rover_files)}, nav_paths, warnings)


def common_signals(receivers: dict, nav_paths, warnings: list) -> list[str]:
    """Every signal all ``receivers`` hold (name → its files, a receiver's files together) whose system has
    ephemerides in ``nav_paths`` (without any: in the u-blox logs' RXM-SFRBX frames), in :data:`SIGNALS` order:
    ``rtk``'s ``--signals auto`` and ``config``'s.  Systems the navigation data lack are named in a warning;
    CdgpsError when no signal is left."""
    files = {n: _as_list(f) for n, f in receivers.items()}
    held = {n: set().union(*(_ubx_signals(p) if is_ubx_log(p) else signals_in_file(p) for p in fs))
            for n, fs in files.items()}
    every = [s for s in SIGNALS if signal(s).system in AUTO_SYSTEMS and all(s in h for h in held.values())]
    qzss = [s for s in SIGNALS if s.startswith("J:") and all(s in h for h in held.values())]
    systems = sorted({signal(s).system for s in every + qzss if signal(s).system in NAV_SYSTEMS})
    have = set()
    for p in nav_paths:
        try:
            have |= set(read_rinex_nav(p, systems=tuple(systems))["sat"].str[0])
        except CdgpsError as exc:
            if not _holds_none_of(exc):
                raise
    all_files = [p for fs in files.values() for p in fs]
    if not nav_paths:
        ubx_nav = _ubx_nav(all_files)
        have = set(ubx_nav["sat"].str[0]) if ubx_nav is not None else set()
    use = [s for s in every if signal(s).system in have]
    lost = sorted({signal(s).system for s in every} - have)
    source = (', '.join(map(str, nav_paths)) if nav_paths else
              "the RXM-SFRBX frames of the u-blox logs (no --nav given)"
              if any(is_ubx_log(p) for p in all_files) else "any file (no --nav given)")
    warnings += _unprocessed_systems_note(files) + _qzss_left_out_note(qzss, len(files), "J" in have, source)
    if lost:
        warnings.append(f"signals of {', '.join(SYSTEM_NAMES.get(c, c) for c in lost)} held by "
                        f"{'both files' if len(files) == 2 else 'every receiver'} are not used: no ephemerides for "
                        f"them in {source}")
    if not use:
        raise CdgpsError(f"{' and '.join(f'{pieces_text(fs)} ({n})' for n, fs in files.items())} share no signal with "
                         f"ephemerides in {source}: "
                         + ", ".join(f"{n} {'holds ' if i == 0 else ''}{' '.join(sorted(held[n])) or 'none'}"
                                     for i, n in enumerate(files)))
    return use


def _qzss_left_out_note(qzss: list, n_receivers: int, have_ephemerides: bool, source: str) -> list:
    """A note naming the QZSS signals every receiver holds (``qzss``), which ``auto`` leaves out
    (:data:`~cdgps_cli.core.signals.AUTO_SYSTEMS`), and how to use them — or that the navigation data (``source``)
    have no QZSS ephemerides for them."""
    if not qzss:
        return []
    held = f"QZSS signals held by {'both files' if n_receivers == 2 else 'every receiver'} ({', '.join(qzss)})"
    if not have_ephemerides:
        return [f"{held} are not used: no QZSS ephemerides in {source}"]
    return [f"{held} are left out by --signals auto: name them (--signals, [gnss] signals) to use them"]


def _unprocessed_systems_note(files: dict) -> list:
    """A note naming the systems (SBAS, NavIC) whose phases every receiver's RINEX 3 files hold and that no
    signal of cdgps belongs to (``auto`` would leave them out without a word)."""
    from cdgps_cli.core.signals import OTHER_SYSTEM_NAMES  # noqa: PLC0415
    from cdgps_cli.io.rinex_signals import phase_systems_in_file  # noqa: PLC0415

    held = None
    for fs in files.values():
        mine = set().union(*(phase_systems_in_file(p) for p in fs if not is_ubx_log(p)))
        held = mine if held is None else held & mine
    other = sorted(c for c in (held or ()) if c in OTHER_SYSTEM_NAMES)
    if not other:
        return []
    return [f"{', '.join(f'{OTHER_SYSTEM_NAMES[c]} ({c})' for c in other)} phases held by "
            f"{'both files' if len(files) == 2 else 'every receiver'} are not used: cdgps processes "
            f"{', '.join(list(SYSTEM_NAMES.values())[:-1])} and {list(SYSTEM_NAMES.values())[-1]} signals"]


def recorded_signals(rinex: dict, sigs: list, warnings: list) -> list[str]:
    """Of ``sigs`` (from the headers, :func:`common_signals`), those every RINEX receiver's records hold a phase of
    (``rinex``: antenna → its file): a header may list observation types no record fills (a file cut down to one
    system), which ``config`` wrote into ``[gnss] signals`` and ``ingest`` then refused; each signal left out is named
    in ``warnings``, as ``rtk --signals auto`` names it (:func:`_observed_signals`).  CdgpsError when none is left."""
    from cdgps_cli.io.rinex_signals import read_rinex_signals  # noqa: PLC0415
    keep = list(sigs)
    for n, p in rinex.items():
        held = set()
        for q in _as_list(p):
            try:
                held |= set(read_rinex_signals(q, keep)[1]["signal"].unique())
            except CdgpsError:        # (e.g. GLONASS slots only the navigation file has): not checked, all kept
                held |= set(keep)
        warnings += [_unrecorded(s, f"{pieces_text(_as_list(p))} ({n})") for s in keep if s not in held]
        keep = [s for s in keep if s in held]
    if not keep:
        raise CdgpsError(f"the receivers share no signal with phase observations in their records ({', '.join(sigs)} "
                         f"listed in their headers)")
    return keep


def _without_unusable_channels(df: pd.DataFrame, path, who: str, warnings: list) -> pd.DataFrame:
    """:func:`~cdgps_cli.measurement.channel_screen.without_unusable_channels` of a receiver (its unlocked channels
    and those of reversed phase), its warnings added."""
    kept, notes = without_unusable_channels(df, f"{path} ({who})")
    warnings += notes
    return kept


def _first_of_repeated_epochs(df: pd.DataFrame, path, who: str, warnings: list) -> pd.DataFrame:
    """The rows of a receiver whose epoch was written more than once, kept once (the first record);
    a warning names the file and the repeated epochs."""
    kept, t, n_rows = first_of_repeated_epochs(df)
    if n_rows:
        warnings.append(repeated_epochs_text(f"{path} ({who})", t, n_rows))
    return kept
