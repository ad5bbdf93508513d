"""``cdgps baseline``'s inputs: baseline job files and the RINEX files they name.

The static baseline itself is numerics (:func:`cdgps_cli.estimation.baseline.solve_static_baseline`,
which never reads a file); this stage reads a job file (a GNSS run config with two RINEX antennas,
or the older ``[baseline]`` table of docs/geonet.md), the RINEX observation and navigation files,
and hands the solver its :class:`~cdgps_cli.estimation.baseline.Station` records and ephemerides.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.config.limits import check_on_earth
from cdgps_cli.config.options import IONO_THRESHOLD_KM
from cdgps_cli.core import toml_text
from cdgps_cli.core.errors import CdgpsError, join_problems
from cdgps_cli.estimation.baseline import BaselineOptions, Station, solve_static_baseline
from cdgps_cli.core.gps_time import distinct_times, gps_time_str
from cdgps_cli.io.gnss_run import antennas_info, merge_nav
from cdgps_cli.io.gnss_sequence import pieces_text, refuse_another_receiver
from cdgps_cli.io.log_sequence import expand_paths, is_pattern, join_tables, one_file_for_two_receivers
from cdgps_cli.io.rinex import read_rinex_obs
from cdgps_cli.measurement.channel_screen import naming_screened
from cdgps_cli.measurement.phase_sign import without_reversed_l1_phases
from cdgps_cli.measurement.time_window import OUTSIDE_WINDOW, pair_in_window, window_errors, window_text, with_dropped
from cdgps_cli.model.gps.positioning import antenna_reference_point_m
from cdgps_cli.pipeline.antenna_models import antenna_models, station_with_antenna_model

__all__ = ["load_stations", "baseline_from_files", "baseline_inputs", "load_baseline_job", "refuse_missing_files"]


def load_stations(rinex: dict, nav_paths, warnings: list | None = None,
                  screened: list | None = None) -> tuple[dict, pd.DataFrame]:
    """Read RINEX observation files (``{name: path}``, or ``{name: [paths and quoted glob patterns]}``: a station's
    consecutive files, hourly or daily, joined in time order into one record as ``ingest`` joins them; their joins'
    warnings into ``warnings``) and navigation files into Stations and one ephemeris table (duplicates across
    files removed); a station's GPS channels whose phase runs opposite to its code lose their phase, a warning naming
    them (:func:`~cdgps_cli.measurement.phase_sign.without_reversed_l1_phases`; into ``screened`` too, when given)."""
    if not nav_paths:
        raise CdgpsError("no navigation file given (--nav): GPS broadcast ephemerides are needed for satellite positions")
    stations, said = {}, warnings if warnings is not None else []
    for name, path in rinex.items():
        st = _read_station(name, path, said)
        obs, reversed_ = without_reversed_l1_phases(st.obs, f"{st.header.get('path', path)} ({name})")
        said += reversed_
        if screened is not None:
            screened += reversed_
        stations[name] = st._replace(obs=obs)
    return stations, merge_nav(nav_paths, ("G",))     # GPS files only; a Galileo-only file beside them is skipped


def _read_station(name: str, path, warnings: list) -> Station:
    """One station from its file, or from its consecutive files joined (:func:`load_stations`)."""
    files = expand_paths([path] if isinstance(path, (str, Path)) else list(path), f"--rinex {name}")
    reads = [read_rinex_obs(p) for p in files]
    if len(reads) == 1:
        return Station(name, *reads[0])
    tab, report, order = join_tables([(str(p), o) for p, (_, o) in zip(files, reads)], "time_gps_s", math.nan,
                                     gps_time_str, what=name)
    refuse_another_receiver(name, [reads[i][0] for i in order], [files[i] for i in order])
    warnings.extend(report.warnings)
    return Station(name, reads[order[0]][0], tab)


def refuse_missing_files(rinex: dict, nav_paths, origins: dict | None = None) -> None:
    """A receiver or navigation file that does not exist is named with where it was given.

    ``origins`` is a job's ``{"rinex": {station: source}, "nav": source}``, a source being e.g.
    ``"job.toml: [gnss.antennas.B] rinex"``; files without one are named by their option
    (``--rinex NAME``, ``--nav``)."""
    origins = origins or {}
    from_job = origins.get("rinex", {})
    given = [(from_job.get(n, f"--rinex {n}"), p) for n, p in rinex.items()]
    given += [(origins.get("nav", "--nav"), p) for p in nav_paths]
    for where, path in given:
        for p in ([path] if isinstance(path, (str, Path)) else path):
            if not Path(p).exists() and not is_pattern(str(p)):      # a pattern is expanded (and checked) when read
                raise CdgpsError(f"{where}: {p}: cannot read: no such file")


def baseline_from_files(rinex: dict, nav_paths, master: str, options: BaselineOptions | None = None,
                        positions: dict | None = None, origins: dict | None = None,
                        iono_threshold_km: float | None = IONO_THRESHOLD_KM, antex=None,
                        antenna_types: dict | None = None, start_gps_s: float | None = None,
                        end_gps_s: float | None = None) -> dict:
    """Read the files and solve (:func:`solve_static_baseline`); ``rinex`` maps exactly two station
    names to observation files, ``master`` is one of them; ``positions`` optionally gives
    ``{name: ECEF m}`` instead of the RINEX header positions; ``origins`` names where each path was
    given (:func:`refuse_missing_files`).  A baseline at least ``iono_threshold_km`` long is refused, as ``init``
    refuses it (:func:`~cdgps_cli.estimation.baseline.check_iono_rule`: this solution neglects the DD ionosphere and
    the wet delays); None: not checked.  ``antex``: an ANTEX file whose calibrations of the two antennas (named by
    ``antenna_types`` {station: type or "none"}, else by their RINEX headers) are taken out of their observations
    (:mod:`cdgps_cli.pipeline.antenna_models`); the result's ``antennas`` says which.  ``start_gps_s`` /
    ``end_gps_s`` (GPS s, each None: the record's end): the rover epochs solved, as ``rtk --start-time / --end-time``
    take them (:mod:`cdgps_cli.measurement.time_window`); the rover's epochs outside are counted in the result's
    ``epochs.epoch_pairing`` with their reason, and ``epochs.time_window`` says the window."""
    if len(rinex) != 2:
        raise CdgpsError(f"a baseline needs exactly two RINEX observation files (NAME=PATH), got {len(rinex)}: "
                         f"{', '.join(rinex) or 'none'}")
    if master not in rinex:
        raise CdgpsError(f"master {master!r} is not one of the stations given: {', '.join(rinex)}")
    opt = options or BaselineOptions()
    opt.validate()
    bad = window_errors(start_gps_s, end_gps_s)
    if bad:
        raise CdgpsError("invalid baseline time window: " + "; ".join(bad))
    refuse_missing_files(rinex, nav_paths, origins)
    rinex = {k: expand_paths([v] if isinstance(v, (str, Path)) else list(v), (origins or {}).get("rinex", {}).get(k, f"--rinex {k}"))
             for k, v in rinex.items()}
    shared = one_file_for_two_receivers({f"--rinex {k}": v for k, v in rinex.items()})
    rinex = {k: v[0] if len(v) == 1 else v for k, v in rinex.items()}     # one file: its name, as before
    joins: list = list(shared)
    screened: list = []
    stations, nav = load_stations(rinex, nav_paths, joins, screened)
    shown = {k: v if isinstance(v, (str, Path)) else pieces_text(v) for k, v in rinex.items()}
    rover = next(n for n in rinex if n != master)
    stations, n_outside = _cut_to_window(stations, master, rover, shown, opt, start_gps_s, end_gps_s)
    pos = positions or {}
    stations, antennas = _with_antenna_models(stations, nav, (master, rover), pos, shown, antex, antenna_types or {},
                                              joins)
    try:
        with naming_screened(screened):
            res = solve_static_baseline(stations[master], stations[rover], nav, options, master_xyz=pos.get(master),
                                        rover_xyz=pos.get(rover), engine=True, iono_threshold_km=iono_threshold_km)
    except CdgpsError as exc:
        if str(exc).startswith("the navigation data does not cover"):     # name the files that fell short
            raise CdgpsError(f"{exc} (navigation file(s) given: {', '.join(map(str, nav_paths))})") from None
        if not any(str(p) in str(exc) for p in shown.values()):   # the solver's words name no file
            raise CdgpsError(f"baseline {master} ({shown[master]}) → {rover} ({shown[rover]}): {exc}") from None
        raise
    res["inputs"] = {"rinex": {k: str(v) if isinstance(v, (str, Path)) else [str(p) for p in v] for k, v in rinex.items()},
                     "nav": [str(p) for p in nav_paths]}
    if joins:
        res["warnings"] = [*joins, *res.get("warnings", [])]
    if antennas is not None:
        res["antennas"] = antennas
    if start_gps_s is not None or end_gps_s is not None:
        ep = res["epochs"]
        ep["epoch_pairing"] = with_dropped(ep["epoch_pairing"], OUTSIDE_WINDOW, n_outside)
        ep["time_window"] = {"start_gps_s": start_gps_s, "end_gps_s": end_gps_s,
                             "window": window_text(start_gps_s, end_gps_s), "rover_epochs_outside": n_outside}
    return res


def _cut_to_window(stations: dict, master: str, rover: str, shown: dict, opt: BaselineOptions,
                   lo: float | None, hi: float | None) -> tuple[dict, int]:
    """The stations with the rover's epochs cut to the window [``lo``, ``hi``] (GPS s; None: open) and the master's
    to it widened by ``max_age_s`` on each side (where the window's rover epochs find their base epochs), and how
    many of the rover's distinct epochs are outside; the same stations and 0 without a window.  CdgpsError naming
    the file and its span when no rover epoch is inside, or no master epoch within ``max_age_s`` of it."""
    if lo is None and hi is None:
        return stations, 0
    t_b, t_r = (stations[n].obs["time_gps_s"].to_numpy(dtype="float64") for n in (master, rover))
    keep_b, keep_r = pair_in_window(t_b, t_r, lo, hi, opt.sync_tol_s, opt.max_age_s,
                                    (f"{shown[master]} ({master})", f"{shown[rover]} ({rover})"))
    out = dict(stations)
    for n, keep in ((master, keep_b), (rover, keep_r)):
        out[n] = stations[n]._replace(obs=stations[n].obs[keep].reset_index(drop=True))
    return out, int(distinct_times(t_r[~keep_r]).size)


def _with_antenna_models(stations: dict, nav, order: tuple, positions: dict, shown: dict, antex, types: dict,
                         warnings: list) -> tuple[dict, dict | None]:
    """(the stations with their antennas' calibrations from ``antex`` taken out, the result's ``antennas`` record, or
    None without a file); without one, ``warnings`` gets a note when the headers name different antenna types."""
    models = antenna_models(antex, {n: types.get(n) for n in order}, {n: stations[n].header for n in order},
                            {n: shown[n] for n in order}, warnings, {n: f"--antenna {n}=TYPE" for n in order})
    if antex is None:
        return stations, None
    out = dict(stations)
    for n in order:
        if models[n] is not None:
            out[n] = station_with_antenna_model(stations[n], nav, _seen_from(stations, order, positions, shown, n),
                                                models[n])
    return out, antennas_info(antex, models)


def _seen_from(stations: dict, order: tuple, positions: dict, shown: dict, n: str):
    """Where station ``n``'s satellites are seen from for its calibration (metres do not matter): its given position,
    its header's, else the master's (``order[0]``).  CdgpsError when none is known."""
    for m in (n, order[0]):
        xyz = positions.get(m)
        xyz = antenna_reference_point_m(stations[m].header, f"{shown[m]} ({m})") if xyz is None else xyz
        if xyz is not None:
            return xyz
    raise CdgpsError(f"{shown[n]} ({n}): no position to evaluate its antenna calibration at (no header position, "
                     f"nor the master's)")


_JOB_KEYS = {
    "name": str, "description": str, "master": str, "nav": list, "rinex": dict, "mask_deg": (int, float),
    "ratio": (int, float), "partial": bool, "weighting": str, "troposphere": bool, "sigma_a_m": (int, float),
    "sigma_b_m": (int, float), "code_ratio": (int, float), "max_gap_s": (int, float), "iono_threshold_km": (int, float),
    "antex": str,
}


def baseline_inputs(job=None, *, stations: dict | None = None, nav_paths=(), master: str | None = None,
                    changes: dict | None = None, antenna_types: dict | None = None,
                    iono_threshold_km: float | None = None, antex=None, master_xyz=None) -> dict:
    """The arguments of :func:`baseline_from_files`: a job file's (:func:`load_baseline_job`; None: none) with what
    was given beside it on top, as ``cdgps baseline`` takes them.

    Parameters
    ----------
    job : dict, optional
        A baseline job file as :func:`load_baseline_job` reads it (its errors are the file's, named by its keys).
    stations : dict, optional
        ``{name: observation file(s)}`` instead of the job's stations (the job's origins and antenna types, which
        name its own files, are then not used; a position it gives a station of the same name still is).
    nav_paths : sequence of paths
        Navigation files instead of the job's (empty: the job's).
    master : str, optional
        The reference station instead of the job's.
    changes : dict, optional
        :class:`~cdgps_cli.estimation.baseline.BaselineOptions` fields to set on the job's options (or the defaults).
    antenna_types : dict, optional
        ``{station: antenna type or "none"}`` on top of the job's.
    iono_threshold_km, antex : optional
        Instead of the job's (None: the job's, else the default / none).
    master_xyz : array_like (3,), optional
        The master's antenna position, ECEF m, instead of the job's or its RINEX header's (checked to be on the
        Earth).

    Returns
    -------
    dict
        ``rinex``, ``nav_paths``, ``master``, ``options``, ``positions``, ``origins``, ``iono_threshold_km``,
        ``antex``, ``antenna_types`` (the keywords of :func:`baseline_from_files`) and ``notes`` (the job's warnings).

    Raises
    ------
    CdgpsError
        Not two stations, no navigation file, no master or one that is not a station, an antenna type of a station not
        given, an invalid option (named by its field).
    """
    got = job if job else {
        "rinex": {}, "nav": [], "master": None, "options": BaselineOptions(), "positions": {}, "origins": {},
        "iono_threshold_km": IONO_THRESHOLD_KM, "antex": None, "antenna_types": {}, "notes": []}
    rinex, origins = got["rinex"], dict(got.get("origins") or {})
    positions, types = dict(got.get("positions") or {}), dict(got.get("antenna_types") or {})
    if stations:
        rinex, types = stations, {}         # the job's positions and antenna types name its stations, not these
        origins.pop("rinex", None)
    if nav_paths:
        origins.pop("nav", None)
    navs, mst = list(nav_paths) or list(got["nav"]), master or got["master"]
    if len(rinex) != 2:
        raise CdgpsError(f"give exactly two stations with --rinex NAME=PATH (or --config), got {len(rinex)}")
    if not navs:
        raise CdgpsError("give at least one navigation file with --nav (or --config)")
    if not mst:
        raise CdgpsError(f"--master is required: which of {', '.join(rinex)} is the reference at its header position")
    if mst not in rinex:
        raise CdgpsError(f"master {mst!r} is not one of the stations given: {', '.join(rinex)}")
    if master_xyz is not None:
        check_on_earth(master_xyz, "--master-xyz")
        positions[mst] = np.asarray(master_xyz, dtype=np.float64)
    opt = dataclasses.replace(got["options"], **(changes or {}))
    opt.validate()
    types.update(antenna_types or {})
    unknown = sorted(set(types) - set(rinex))
    if unknown:
        raise CdgpsError(f"--antenna {unknown[0]}: not one of the stations given ({', '.join(rinex)})")
    return {"rinex": rinex, "nav_paths": navs, "master": mst, "options": opt,
            "positions": {k: v for k, v in positions.items() if k in rinex}, "origins": origins,
            "iono_threshold_km": got["iono_threshold_km"] if iono_threshold_km is None else iono_threshold_km,
            "antex": antex or got.get("antex"), "antenna_types": types, "notes": list(got.get("notes") or [])}


def load_baseline_job(path) -> dict:
    """Read a baseline job file: a GNSS run config (``[gnss]`` table, docs/gnss-pipeline.md) with
    two RINEX antennas, or the older form with one ``[baseline]`` table (docs/geonet.md).

    Relative file paths are taken relative to the job file's directory.

    Returns
    -------
    dict
        ``name``, ``master``, ``rinex`` ({name: Path}), ``nav`` ([Path]), ``options``
        (:class:`BaselineOptions`), ``positions`` ({name: ECEF m} given in the file; the
        others come from the RINEX headers), ``origins`` (the file and key that give each
        station's file and the navigation files, for :func:`refuse_missing_files`), ``antex`` (the ANTEX file
        or None) and, from a GNSS run config, ``antenna_types`` ({name: antenna_type given}) and ``notes`` (its
        ``[gnss] signals`` other than GPS L1, not used).

    Raises
    ------
    CdgpsError
        Unreadable file, TOML syntax error, unknown or mistyped keys (all listed at once).
    """
    p = Path(path)
    try:
        text = p.read_text()
        text = text[1:] if text.startswith("\ufeff") else text     # a UTF-8 byte-order mark
        doc = toml_text.loads(text)
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise CdgpsError(f"{p}: not valid TOML: {exc}") from None
    if "gnss" in doc:
        return _job_from_gnss_config(p, text)
    problems = []
    extra = sorted(set(doc) - {"baseline"})
    if extra:
        problems.append(f"unknown top-level key(s) {', '.join(extra)} (a baseline job has one [baseline] table)")
    b = doc.get("baseline")
    if not isinstance(b, dict):
        raise CdgpsError(join_problems(f"{p}: invalid baseline job", problems + ["missing [baseline] table (or a [gnss] table)"]))
    for k, v in b.items():
        t = _JOB_KEYS.get(k)
        if t is None:
            problems.append(f"baseline.{k}: unknown key (known: {', '.join(sorted(_JOB_KEYS))})")
        elif not isinstance(v, t) or (t == (int, float) and isinstance(v, bool)):
            problems.append(f"baseline.{k}: expected {getattr(t, '__name__', 'a number')}, got {v!r}")
    for k in ("master", "rinex", "nav"):
        if k not in b:
            problems.append(f"baseline.{k}: required")
    base = p.parent
    rinex = {}
    if isinstance(b.get("rinex"), dict):
        for n, v in b["rinex"].items():
            if not isinstance(v, str):
                problems.append(f"baseline.rinex.{n}: expected a file path string, got {v!r}")
            else:
                rinex[str(n)] = (base / v) if not Path(v).is_absolute() else Path(v)
        if len(rinex) != 2:
            problems.append(f"baseline.rinex: expected exactly two stations, got {len(b['rinex'])}")
    nav = []
    if isinstance(b.get("nav"), list):
        for i, v in enumerate(b["nav"]):
            if not isinstance(v, str):
                problems.append(f"baseline.nav[{i}]: expected a file path string, got {v!r}")
            else:
                nav.append((base / v) if not Path(v).is_absolute() else Path(v))
        if not nav:
            problems.append("baseline.nav: at least one navigation file is needed")
    if isinstance(b.get("master"), str) and rinex and b["master"] not in rinex:
        problems.append(f"baseline.master: {b['master']!r} is not one of baseline.rinex ({', '.join(rinex)})")
    if problems:
        raise CdgpsError(join_problems(f"{p}: invalid baseline job", problems))
    kw = {}
    for k_job, k_opt in (("mask_deg", "mask_deg"), ("ratio", "ratio_threshold"), ("partial", "partial"),
                         ("weighting", "weighting"), ("troposphere", "troposphere"), ("sigma_a_m", "sigma_a_m"),
                         ("sigma_b_m", "sigma_b_m"), ("code_ratio", "code_ratio"), ("max_gap_s", "max_gap_s")):
        if k_job in b:
            kw[k_opt] = float(b[k_job]) if isinstance(b[k_job], (int, float)) and not isinstance(b[k_job], bool) else b[k_job]
    opt = BaselineOptions(**kw)
    try:
        opt.validate()
    except CdgpsError as exc:
        raise CdgpsError(f"{p}: {exc}") from None
    origins = {"rinex": {n: f"{p}: [baseline.rinex] {n}" for n in rinex}, "nav": f"{p}: [baseline] nav"}
    iono = float(b.get("iono_threshold_km", IONO_THRESHOLD_KM))
    if not (math.isfinite(iono) and iono >= 0):
        raise CdgpsError(f"{p}: baseline.iono_threshold_km: expected a baseline length in km >= 0, got {iono!r}")
    antex = b.get("antex")
    return {"name": b.get("name", p.stem), "master": b["master"], "rinex": rinex, "nav": nav, "options": opt,
            "positions": {}, "origins": origins, "iono_threshold_km": iono,
            "antex": None if antex is None else (base / antex if not Path(antex).is_absolute() else Path(antex))}


def _job_from_gnss_config(p: Path, text: str) -> dict:
    """A baseline job from a GNSS run config: exactly two antennas with RINEX files."""
    from cdgps_cli.config.structure import parse_gnss_config  # noqa: PLC0415

    cfg = parse_gnss_config(text, str(p), base_dir=p.resolve().parent)
    problems = []
    if not cfg.master:
        problems.append("gnss.master: required for a baseline")
    if len(cfg.antennas) != 2:
        problems.append(f"gnss.antennas: a baseline needs exactly two antennas, got {len(cfg.antennas)}")
    for a in cfg.antennas:
        if not a.rinex:
            problems.append(f"gnss.antennas.{a.name}: 'cdgps baseline' needs a rinex observation file"
                            + (" (UBX logs go through 'cdgps ingest')" if a.ubx else ""))
    if not cfg.nav:
        problems.append("gnss.nav: at least one navigation file is needed")
    if problems:
        raise CdgpsError(join_problems(f"{p}: not usable as a baseline job", problems))
    opt = BaselineOptions.from_gnss_config(cfg, motion="static")        # 'cdgps baseline' is the static solution
    try:
        opt.validate()
    except CdgpsError as exc:
        raise CdgpsError(f"{p}: {exc}") from None
    return {"name": cfg.name, "master": cfg.master, "rinex": {a.name: Path(a.rinex) for a in cfg.antennas},
            "nav": [Path(n) for n in cfg.nav], "options": opt, "iono_threshold_km": cfg.iono_threshold_km,
            "positions": {a.name: a.position_ecef_m for a in cfg.antennas if a.position_ecef_m is not None},
            "origins": {"rinex": {a.name: f"{p}: [gnss.antennas.{a.name}] rinex" for a in cfg.antennas},
                        "nav": f"{p}: [gnss] nav"},
            "antex": cfg.antex, "antenna_types": {a.name: a.antenna_type for a in cfg.antennas if a.antenna_type},
            "notes": _signals_not_used(p, cfg.signals)}


def _signals_not_used(p: Path, signals) -> list:
    """The note that a config's ``[gnss] signals`` other than GPS L1 are not ``cdgps baseline``'s (it solves GPS L1
    alone; 'cdgps rtk' and ``ingest`` → ``init`` take them); [] when it names none."""
    other = [s for s in (signals or ()) if s != "G:L1"]
    if not other:
        return []
    return [f"{p}: [gnss] signals {', '.join(other)} not used: 'cdgps baseline' solves GPS L1 alone ('cdgps rtk', "
            f"and 'cdgps ingest' → 'cdgps init', take every signal)"]
