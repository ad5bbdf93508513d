"""GNSS satellite positions and clocks from broadcast ephemerides, and local geometry.

* :func:`sat_position_ecef` — the IS-GPS-200 user algorithm (IS-GPS-200N, Table 20-IV: Kepler
  orbit with harmonic corrections, Earth-fixed at the given time) and the satellite clock
  correction (Section 20.3.3.3.3.1: polynomial, relativistic eccentricity term, optional T_GD),
  vectorized over times (and, with a table of ephemerides, over records).  Galileo uses the same
  algorithm with its GM; BeiDou (BDS-ICD-B1I §5.2.4.12) its GM and Earth rotation rate, and for
  the GEO satellites (PRN 1–5, 59–63) the orbit in the inertial-like frame of t_oe rotated by −5°
  about X and then by ω_e·t_k about Z; GLONASS state-vector records are integrated
  (:mod:`cdgps_cli.model.gps.glonass_orbit`).
* :func:`select_ephemeris` — the healthy ephemeris with the nearest toe within ±2 h (the
  convention of RTKLIB and most receivers), or an error naming what is missing.
* :func:`sat_position_at_reception` — light-time iteration with the Earth-rotation (Sagnac)
  correction: satellite position at transmission, expressed in the ECEF frame at reception.
* :func:`ecef_to_geodetic`, :func:`geodetic_to_ecef` (WGS-84), :func:`enu_matrix`,
  :func:`ecef_to_enu`, :func:`azimuth_elevation`, :func:`elevation`.

The many-row functions (:func:`sat_positions_at_reception`, :func:`sat_position_rows`, :func:`azimuth_elevation`
of one receiver) run in the optional compiled kernel ``cdgps_cli.model.gps._orbitcore`` when it is built and
``CDGPS_NO_KERNEL`` is unset: the same values bit for bit as their numpy code, which runs otherwise
(tests/model/test_orbitcore.py).

All positions are ECEF (WGS-84), m; angles rad; times GPS seconds since 1980-01-06 (see
:mod:`cdgps_cli.io.rinex`); clock corrections s (positive: the satellite clock is ahead, so
``t_gps = t_sv - clock_s``).  Functions are pure and take numpy arrays.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import pandas as pd

from cdgps_cli.core.constants import MAX_EPHEMERIS_AGE_S, SPEED_OF_LIGHT_M_S  # noqa: F401 (MAX_EPHEMERIS_AGE_S: re-exported)
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_time_str
from cdgps_cli.core.records import GLONASS_NAV_COLUMNS
from cdgps_cli.model.gps.glonass_orbit import glonass_position

try:
    from cdgps_cli.model.gps import _orbitcore
except ImportError:                      # the optional extension is not built: the numpy functions below
    _orbitcore = None

__all__ = [
    "healthy_ephemeris",
    "QZSS_IGNORED_HEALTH_BITS",
    "GM_GPS",
    "GM_GALILEO",
    "GM_BY_SYSTEM",
    "GM_BEIDOU",
    "OMEGA_E_GPS",
    "OMEGA_E_BEIDOU",
    "OMEGA_E_BY_SYSTEM",
    "BEIDOU_GEO_PRNS",
    "BEIDOU_GEO_TILT_RAD",
    "MAX_EPHEMERIS_AGE_GLONASS_S",
    "F_RELATIVISTIC",
    "WGS84_A",
    "WGS84_F",
    "MAX_EPHEMERIS_AGE_S",
    "sat_position_ecef",
    "beidou_geo_rotation",
    "select_ephemeris",
    "select_ephemerides",
    "EphemerisRows",
    "ephemeris_rows",
    "sat_position_rows",
    "sat_position_at_reception",
    "ReceptionEphemeris",
    "reception_ephemeris",
    "sat_positions_at_reception",
    "ReceptionGeometry",
    "ecef_to_geodetic",
    "geodetic_to_ecef",
    "enu_matrix",
    "ecef_to_enu",
    "azimuth_elevation",
    "elevation",
]

GM_GPS = 3.986005e14
"""WGS-84 Earth gravitational constant as fixed by IS-GPS-200, m³/s²."""
OMEGA_E_GPS = 7.2921151467e-5
"""WGS-84 Earth rotation rate as fixed by IS-GPS-200, rad/s."""
GM_GALILEO = 3.986004418e14
"""Earth gravitational constant of the Galileo OS SIS ICD (Table 57, GTRF), m³/s²; Galileo's Earth
rotation rate is the same 7.2921151467e-5 rad/s, and its Kepler model is the GPS one with GST
(aligned to GPS time to a few ns, week numbers written as GPS weeks in RINEX 3 navigation files)."""
GM_BEIDOU = 3.986004418e14
"""Earth gravitational constant of CGCS2000 (BDS-ICD-B1I §5.2.4.11), m³/s²."""
OMEGA_E_BEIDOU = 7.2921150e-5
"""Earth rotation rate of CGCS2000 (BDS-ICD-B1I §5.2.4.11), rad/s."""
GM_BY_SYSTEM = {"G": GM_GPS, "E": GM_GALILEO, "C": GM_BEIDOU, "J": GM_GPS}
"""Gravitational constant per satellite-system letter (systems with a GPS-form Kepler ephemeris; QZSS: the GPS
values, IS-QZSS-PNT §5.5)."""
OMEGA_E_BY_SYSTEM = {"G": OMEGA_E_GPS, "E": OMEGA_E_GPS, "C": OMEGA_E_BEIDOU, "J": OMEGA_E_GPS}
"""Earth rotation rate of each Kepler system's user algorithm, rad/s (Galileo: the GPS value)."""
BEIDOU_GEO_PRNS = frozenset((1, 2, 3, 4, 5, 59, 60, 61, 62, 63))
"""BeiDou PRNs of geostationary satellites (BDS-ICD-B1I 3.0 §5.2.4.12; BDS-3 GEOs are 59–63)."""
BEIDOU_GEO_TILT_RAD = np.radians(-5.0)
"""Rotation about X applied to a BeiDou GEO orbit before the Earth rotation (BDS-ICD-B1I §5.2.4.12)."""
F_RELATIVISTIC = -4.442807633e-10
"""IS-GPS-200 relativistic clock constant F = −2·√GM / c², s/√m."""
WGS84_A = 6378137.0
"""WGS-84 semi-major axis, m."""
WGS84_F = 1.0 / 298.257223563
"""WGS-84 flattening."""
MAX_EPHEMERIS_AGE_GLONASS_S = 1800.0
"""Largest |t − t_b| for a GLONASS state-vector record, s (records come every 30 min; the ICD's
simplified integration is specified for 15 min)."""

_ORBIT_FIELDS = (
    "toe_gps_s",
    "toe_sow_s",
    "toc_gps_s",
    "sqrt_a_sqrt_m",
    "e",
    "m0_rad",
    "delta_n_rad_per_s",
    "omega_rad",
    "cuc_rad",
    "cus_rad",
    "crc_m",
    "crs_m",
    "cic_rad",
    "cis_rad",
    "i0_rad",
    "idot_rad_per_s",
    "omega0_rad",
    "omega_dot_rad_per_s",
    "af0_s",
    "af1_s_per_s",
    "af2_s_per_s2",
    "tgd_s",
)


def _params(eph) -> dict[str, np.ndarray]:
    """The orbit fields of one ephemeris (Series / mapping) or many (DataFrame) as float arrays."""
    if isinstance(eph, pd.DataFrame):
        missing = [f for f in _ORBIT_FIELDS if f not in eph.columns]
    elif isinstance(eph, (pd.Series, Mapping)):
        missing = [f for f in _ORBIT_FIELDS if f not in eph]
    else:
        raise TypeError(f"expected an ephemeris row (pandas Series or mapping) or a DataFrame, got {type(eph).__name__}")
    if missing:
        raise ValueError(f"ephemeris lacks field(s) {', '.join(missing)} (as produced by read_rinex_nav)")
    if isinstance(eph, pd.DataFrame):
        return _float_columns(eph, _ORBIT_FIELDS)
    return {f: np.float64(eph[f]) for f in _ORBIT_FIELDS}


def _float_columns(df: pd.DataFrame, fields) -> dict[str, np.ndarray]:
    """``{f: df[f].to_numpy(dtype=np.float64)}`` for the columns ``fields``, the same values taken as one
    (fields, rows) float block in one column selection (a column selection per field cost more than the
    orbit arithmetic on a few rows); each field a contiguous row of the block."""
    block = np.ascontiguousarray(df[list(fields)].to_numpy(dtype=np.float64).T)
    return dict(zip(fields, block))


def _sats(eph, shape) -> np.ndarray:
    """Satellite ids of the records ("G05" when absent), broadcast to ``shape``."""
    if isinstance(eph, pd.DataFrame):
        if "sat" not in eph.columns:
            return np.full(shape, "G00", dtype=object)
        return eph["sat"].astype(str).to_numpy().reshape(shape)
    sat = eph.get("sat", "G00") if isinstance(eph, (pd.Series, Mapping)) else "G00"
    return np.full(shape, str(sat), dtype=object)


def _system_constants(sats: np.ndarray):
    """(GM m³/s², ω_e rad/s, BeiDou-GEO flag, GLONASS flag) per record, arrays shaped like ``sats``
    (evaluated once per distinct satellite)."""
    codes, uniq = pd.factorize(sats.ravel())
    gm = np.array([GM_BY_SYSTEM.get(s[:1], GM_GPS) for s in uniq], dtype=float)
    we = np.array([OMEGA_E_BY_SYSTEM.get(s[:1], OMEGA_E_GPS) for s in uniq], dtype=float)
    geo = np.array([s[:1] == "C" and s[1:].isdigit() and int(s[1:]) in BEIDOU_GEO_PRNS for s in uniq], dtype=bool)
    glo = np.array([s[:1] == "R" for s in uniq], dtype=bool)
    return tuple(v[codes].reshape(sats.shape) for v in (gm, we, geo, glo))


def beidou_geo_rotation(xyz_gk_m: np.ndarray, we_tk_rad) -> np.ndarray:
    """R_Z(ω_e t_k) · R_X(−5°) · x_GK for BeiDou GEO satellites (BDS-ICD-B1I §5.2.4.12), m, shape (..., 3).

    R_X(φ) = [[1, 0, 0], [0, cos φ, sin φ], [0, −sin φ, cos φ]] and R_Z(φ) = [[cos φ, sin φ, 0],
    [−sin φ, cos φ, 0], [0, 0, 1]], written out component by component.
    """
    x, y, z = xyz_gk_m[..., 0], xyz_gk_m[..., 1], xyz_gk_m[..., 2]
    ct, st = np.cos(BEIDOU_GEO_TILT_RAD), np.sin(BEIDOU_GEO_TILT_RAD)
    y1, z1 = ct * y + st * z, -st * y + ct * z
    c, s = np.cos(we_tk_rad), np.sin(we_tk_rad)
    return np.stack([c * x + s * y1, -s * x + c * y1, z1], axis=-1)


def _eccentric_anomaly(m: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Solve Kepler's equation E − e·sin E = M by Newton iteration, each row on its own: a row stops after
    the first step below 1e-15 rad (at most 30), so its E depends on its own M and e alone, never on the other
    rows evaluated with it (a window of a record gives the whole record's values bit for bit, issue 29)."""
    m_b, e_b = np.broadcast_arrays(np.asarray(m, dtype=np.float64), np.asarray(e, dtype=np.float64))
    shape = m_b.shape
    ecc, mm = e_b.ravel(), m_b.ravel()
    big_e = mm.copy()
    go = np.arange(mm.size)
    for _ in range(30):
        b, eg = big_e[go], ecc[go]
        d = (b - eg * np.sin(b) - mm[go]) / (1.0 - eg * np.cos(b))
        big_e[go] = b - d
        go = go[~(np.abs(d) < 1e-15)]
        if not go.size:
            break
    return big_e.reshape(shape)


def sat_position_ecef(eph, t_gps_s, *, apply_tgd: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Satellite antenna position (ECEF at time ``t``) and clock correction from a broadcast ephemeris.

    Implements the IS-GPS-200 user algorithm for ephemeris determination (Table 20-IV) and the
    SV clock correction Δt_sv = af0 + af1·(t−toc) + af2·(t−toc)² + F·e·√A·sin E_k, minus T_GD for
    a single-frequency L1 user (Section 20.3.3.3.3.2).

    Parameters
    ----------
    eph : pandas.Series, mapping or DataFrame
        One ephemeris (a row of :func:`~cdgps_cli.io.rinex.read_rinex_nav`), applied at every time;
        or a DataFrame with one ephemeris per element of ``t_gps_s`` (same length).
    t_gps_s : float or array_like
        GPS system time(s) of signal transmission, GPS seconds since 1980-01-06.
    apply_tgd : bool, default True
        Subtract T_GD from the clock correction (correct for L1 C/A or P(Y) pseudoranges; leave
        False for the ionosphere-free combination, to which af0 refers).

    Returns
    -------
    xyz_m : ndarray, shape ``np.shape(t_gps_s) + (3,)``
        Satellite antenna phase centre, ECEF (WGS-84) at time ``t``, m.
    clock_s : ndarray, shape ``np.shape(t_gps_s)``
        Satellite clock correction Δt_sv, s (t_gps = t_sv − Δt_sv).

    Notes
    -----
    t − toe and t − toc are computed from continuous GPS seconds, so no week crossover handling is
    needed.  Accuracy is that of the broadcast message (about 1 m orbit, a few ns clock).
    """
    t = np.asarray(t_gps_s, dtype=np.float64)
    if isinstance(eph, pd.DataFrame) and eph.shape[0] != t.size:
        raise ValueError(f"a DataFrame of ephemerides must have one row per time ({eph.shape[0]} rows, {t.size} times)")
    sats = _sats(eph, t.shape)
    glo = _system_constants(sats)[3]
    if not glo.any():
        return _kepler_position(eph, t, sats, apply_tgd)
    if glo.all():
        return _glonass_record_position(eph, t)
    # a table mixing GLONASS and Kepler records: each part by its own algorithm
    xyz, clock = np.empty(t.shape + (3,)), np.empty(t.shape)
    flat_g = glo.ravel()
    for mask in (flat_g, ~flat_g):
        rows = np.flatnonzero(mask)
        part = eph.iloc[rows]
        tp = t.ravel()[rows]
        x, c = (_glonass_record_position(part, tp) if mask is flat_g
                else _kepler_position(part, tp, sats.ravel()[rows], apply_tgd))
        xyz.reshape(-1, 3)[rows], clock.reshape(-1)[rows] = x, c
    return xyz, clock


def _kepler_fields(eph, shape) -> dict:
    """The orbit fields :func:`_kepler_position` reads from ``eph`` (a DataFrame's shaped like the times)."""
    p = _params(eph)
    if isinstance(eph, pd.DataFrame):
        p = {k: v.reshape(shape) for k, v in p.items()}
    return p


def _kepler_position(eph, t: np.ndarray, sats: np.ndarray, apply_tgd: bool) -> tuple[np.ndarray, np.ndarray]:
    """The Kepler user algorithm of :func:`sat_position_ecef` (GPS, Galileo, BeiDou incl. GEO)."""
    return _kepler_at(_kepler_fields(eph, t.shape), _system_constants(sats), t, apply_tgd)


def _kepler_at(p: dict, constants: tuple, t: np.ndarray, apply_tgd: bool) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_kepler_position` from the fields ``p`` (:func:`_kepler_fields`) and the records'
    :func:`_system_constants`."""
    a = p["sqrt_a_sqrt_m"] ** 2
    gm, we, geo, _ = constants
    n0 = np.sqrt(gm / a**3)
    tk = t - p["toe_gps_s"]
    n = n0 + p["delta_n_rad_per_s"]
    mk = p["m0_rad"] + n * tk
    e = p["e"]
    ek = _eccentric_anomaly(mk, e)
    sin_e, cos_e = np.sin(ek), np.cos(ek)
    nu = np.arctan2(np.sqrt(1.0 - e * e) * sin_e, cos_e - e)
    phi = nu + p["omega_rad"]
    s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
    u = phi + p["cus_rad"] * s2 + p["cuc_rad"] * c2
    r = a * (1.0 - e * cos_e) + p["crs_m"] * s2 + p["crc_m"] * c2
    inc = p["i0_rad"] + p["idot_rad_per_s"] * tk + p["cis_rad"] * s2 + p["cic_rad"] * c2
    xp, yp = r * np.cos(u), r * np.sin(u)
    # GEO: the node stays in the frame of t_oe (no −ω_e·t_k); the Earth rotation comes after the tilt
    om = p["omega0_rad"] + (p["omega_dot_rad_per_s"] - np.where(geo, 0.0, we)) * tk - we * p["toe_sow_s"]
    cos_om, sin_om, cos_i = np.cos(om), np.sin(om), np.cos(inc)
    xyz = np.stack([xp * cos_om - yp * cos_i * sin_om, xp * sin_om + yp * cos_i * cos_om, yp * np.sin(inc)], axis=-1)
    if np.any(geo):
        xyz = np.where(geo[..., None], beidou_geo_rotation(xyz, we * tk), xyz)
    dt = t - p["toc_gps_s"]
    clock = p["af0_s"] + p["af1_s_per_s"] * dt + p["af2_s_per_s2"] * dt * dt + F_RELATIVISTIC * np.sqrt(gm / GM_GPS) * e * p["sqrt_a_sqrt_m"] * sin_e
    if apply_tgd:
        clock = clock - p["tgd_s"]
    return xyz, clock


def _glonass_record_position(eph, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and clock of GLONASS state-vector records (:data:`GLONASS_NAV_COLUMNS`) at GPS times ``t``."""
    return _glonass_at(_glonass_fields(eph, t.size), t)


def _glonass_fields(eph, size: int) -> dict:
    """The fields :func:`_glonass_record_position` reads from ``eph`` (a record's repeated ``size`` times)."""
    fields = GLONASS_NAV_COLUMNS[:9] + ("toe_gps_s", "af0_s", "af1_s_per_s")
    missing = [f for f in fields if f not in (eph.columns if isinstance(eph, pd.DataFrame) else eph)]
    if missing:
        raise ValueError(f"GLONASS ephemeris lacks field(s) {', '.join(missing)} (as produced by read_rinex_nav with 'R')")
    if isinstance(eph, pd.DataFrame):
        return _float_columns(eph, fields)
    return {f: np.full((size,), float(eph[f])) for f in fields}


def _glonass_at(v: dict, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_glonass_record_position` from the fields ``v`` (:func:`_glonass_fields`)."""
    flat = t.reshape(-1)
    state0 = np.column_stack([v[f] for f in GLONASS_NAV_COLUMNS[:6]])
    accel = np.column_stack([v[f] for f in GLONASS_NAV_COLUMNS[6:9]])
    dt = flat - v["toe_gps_s"]
    state = glonass_position(state0, accel, dt)
    clock = v["af0_s"] + v["af1_s_per_s"] * dt
    return state[:, :3].reshape(t.shape + (3,)), clock.reshape(t.shape)


QZSS_IGNORED_HEALTH_BITS = 0x01
"""Bits of a QZSS record's ``sv_health`` that do not concern its L1/L2/L5 ranging signals and are ignored: the
least significant of the six health bits of subframe 1 (IS-QZSS-PNT; RTKLIB masks the same bit, its "LEX
health", so a QZSS satellite flagged only there is used by both)."""


def healthy_ephemeris(sats, sv_health) -> np.ndarray:
    """Which ephemeris records are healthy: ``sv_health`` = 0, for QZSS (``J``) once the bits of
    :data:`QZSS_IGNORED_HEALTH_BITS` are cleared.

    Parameters
    ----------
    sats : array_like of str, shape (N,)
        Satellite of each record (``"G05"``, ``"J02"`` …).
    sv_health : array_like, shape (N,)
        The records' health field as broadcast (RINEX ``SV health``).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    h = np.asarray(sv_health, dtype=np.float64)
    sats = np.asarray(sats, dtype=object)
    qzss = sats.astype("U1") == "J" if sats.size else np.zeros(0, dtype=bool)    # (the first letter: the system)
    if not qzss.any():
        return h == 0
    masked = np.where(qzss & np.isfinite(h), np.bitwise_and(np.nan_to_num(h).astype(np.int64), ~QZSS_IGNORED_HEALTH_BITS), h)
    return masked == 0


def select_ephemeris(nav: pd.DataFrame, sat: str, t_gps_s, *, max_age_s: float | None = None) -> pd.DataFrame | pd.Series:
    """Pick, for each time, the healthy ephemeris of ``sat`` whose toe is nearest.

    Parameters
    ----------
    nav : DataFrame
        Ephemerides from :func:`~cdgps_cli.io.rinex.read_rinex_nav`.
    sat : str
        Satellite, e.g. ``"G05"``.
    t_gps_s : float or array_like
        Time(s), GPS seconds.
    max_age_s : float, optional
        Largest accepted |t − toe|, s; default :data:`MAX_EPHEMERIS_AGE_S` (7200), for GLONASS
        :data:`MAX_EPHEMERIS_AGE_GLONASS_S` (1800).

    Returns
    -------
    Series or DataFrame
        For a scalar time the chosen row; for an array one row per time (index 0…N−1).  Ties in
        |t − toe| (duplicate uploads) go to the latest transmission time.

    Raises
    ------
    CdgpsError
        When ``sat`` has no ephemeris at all, or no healthy one (:func:`healthy_ephemeris`) with
        |t − toe| ≤ ``max_age_s`` for some of the times; the message lists the uncovered times
        and the toe/health of the records the file has for that satellite.
    """
    t = np.asarray(t_gps_s, dtype=np.float64)
    scalar = t.ndim == 0
    out = nav.iloc[_ephemeris_rows(nav, sat, np.atleast_1d(t).ravel(), max_age_s)].reset_index(drop=True)
    if scalar:
        return out.iloc[0]
    return out


def _ephemeris_rows(nav: pd.DataFrame, sat: str, t1: np.ndarray, max_age_s: float | None,
                    columns: tuple | None = None) -> np.ndarray:
    """Row positions in ``nav`` of :func:`select_ephemeris`'s choice for ``sat`` at the times ``t1``
    (N,); CdgpsError as it says.  ``columns``: ``nav``'s sat, sv_health, toe and transmission-time
    columns as arrays (None: taken from ``nav``), for callers selecting many satellites."""
    sat_col, health, toe_col, transmit = columns or _ephemeris_columns(nav)
    if max_age_s is None:
        max_age_s = MAX_EPHEMERIS_AGE_GLONASS_S if str(sat).startswith("R") else MAX_EPHEMERIS_AGE_S
    rows = np.flatnonzero(sat_col == sat)                        # row positions, without sub-frames
    if rows.size == 0:
        have = sorted(nav["sat"].unique().tolist())
        raise CdgpsError(f"no broadcast ephemeris for {sat} in the navigation data (satellites present: {' '.join(have) or 'none'})")
    healthy = rows[healthy_ephemeris(sat_col[rows], health[rows])]
    chosen = np.full(t1.shape, -1, dtype=np.int64)
    if healthy.size:
        if transmit is not None:
            # argmin keeps the first of equal ages: order by latest transmission first (ties and
            # missing times keep the file's order, missing last: pandas' stable descending sort)
            healthy = healthy[np.argsort(-transmit[healthy], kind="stable")]
        toe = toe_col[healthy]
        age = np.abs(t1[:, None] - toe[None, :])
        best = np.argmin(age, axis=1)
        ok = age[np.arange(t1.size), best] <= max_age_s
        chosen = np.where(ok, best, -1)
    bad = chosen < 0
    if bad.any():
        recs = nav.iloc[rows]
        idx = np.flatnonzero(bad)
        shown = ", ".join(gps_time_str(x) for x in t1[idx[:3]]) + (" …" if idx.size > 3 else "")
        toes = recs.sort_values("toe_gps_s")
        lst = "; ".join(
            f"toe {gps_time_str(r.toe_gps_s)}" + ("" if healthy_ephemeris([sat], [r.sv_health])[0]
                                                  else f" (unhealthy, sv_health={r.sv_health})")
            for r in toes.itertuples()
        )
        if len(toes) > 8:
            lst = "; ".join(lst.split("; ")[:8]) + f"; … ({len(toes)} records)"
        raise CdgpsError(
            f"no healthy broadcast ephemeris for {sat} within ±{max_age_s / 3600:g} h of {idx.size} of {t1.size} requested time(s) "
            f"({shown}); the navigation data has for {sat}: {lst}"
        )
    return healthy[chosen]


def _ephemeris_columns(nav: pd.DataFrame) -> tuple:
    """(sat, sv_health, toe_gps_s, transmit_gps_s or None) of ``nav`` as arrays."""
    transmit = nav["transmit_gps_s"].to_numpy(dtype=np.float64) if "transmit_gps_s" in nav.columns else None
    return nav["sat"].to_numpy(), nav["sv_health"].to_numpy(), nav["toe_gps_s"].to_numpy(), transmit


def select_ephemerides(nav: pd.DataFrame, sats, t_gps_s) -> pd.DataFrame:
    """:func:`select_ephemeris` for many (satellite, time) pairs at once: row ``i`` is the ephemeris of
    ``sats[i]`` at ``t_gps_s[i]`` (index 0…N−1), the rows ``select_ephemeris`` chooses, taken from
    ``nav`` in one ``iloc`` (not one sub-frame per satellite).

    Parameters
    ----------
    nav : DataFrame
        Ephemerides (:func:`~cdgps_cli.io.rinex.read_rinex_nav`).
    sats : array_like of str, shape (N,)
    t_gps_s : array_like of float, shape (N,)
        GPS seconds.

    Raises
    ------
    CdgpsError
        As :func:`select_ephemeris`, for the first satellite in name order that is not covered.
    """
    sats = np.asarray(sats)
    t = np.asarray(t_gps_s, dtype=np.float64).ravel()
    rows = np.empty(t.size, dtype=np.int64)
    columns = _ephemeris_columns(nav)
    for sat, idx in pd.Series(sats).groupby(sats).indices.items():
        rows[idx] = _ephemeris_rows(nav, sat, t[idx], None, columns)
    return nav.iloc[rows].reset_index(drop=True)


class EphemerisRows(NamedTuple):
    """The ephemeris of every (satellite, time) row, selected once (:func:`ephemeris_rows`), laid out for
    :func:`sat_position_rows` to evaluate at any times (no per-row DataFrame)."""

    rows: np.ndarray
    """Position in the navigation table of each row's ephemeris (:func:`select_ephemerides`' choice), shape (N,)."""
    kepler: np.ndarray
    """Indices (0…N−1) of the Kepler-orbit rows (GPS, Galileo, BeiDou), in row order, shape (K,)."""
    constants: dict
    """:func:`_kepler_constants` of the navigation table (arrays of its length), taken at ``rows[kepler]``
    chunk by chunk."""
    glonass: np.ndarray
    """Indices of the GLONASS rows, shape (G,)."""
    glonass_eph: pd.DataFrame | None
    """Their ephemerides (rows of the navigation table), or None without GLONASS."""


def ephemeris_rows(nav: pd.DataFrame, sats, t_gps_s) -> EphemerisRows:
    """:func:`select_ephemerides`' choice for each (satellite, time) row, as row positions and orbit constants.

    ``sat_position_rows(ephemeris_rows(nav, sats, t), tt)`` is ``sat_position_ecef(select_ephemerides(nav, sats, t), tt)``
    value for value (the same ephemerides, the same operations, each row's Kepler equation iterated until its own step
    is below 1e-15 rad), without the DataFrame of N ephemerides.  CdgpsError as :func:`select_ephemerides`.
    """
    sats = np.asarray(sats, dtype=object).ravel()
    t = np.asarray(t_gps_s, dtype=np.float64).ravel()
    rows = np.empty(t.size, dtype=np.int64)
    columns = _ephemeris_columns(nav)
    for sat, idx in _sat_blocks(sats):                      # satellites in name order, as select_ephemerides
        rows[idx] = _ephemeris_rows(nav, sat, t[idx], None, columns)
    glo_nav = nav["sat"].astype(str).str.startswith("R").to_numpy()
    is_glo = glo_nav[rows]
    kepler, glonass = np.flatnonzero(~is_glo), np.flatnonzero(is_glo)
    consts = _kepler_constants(nav) if kepler.size else {}
    return EphemerisRows(rows, kepler, consts, glonass,
                         nav.iloc[rows[glonass]].reset_index(drop=True) if glonass.size else None)


def sat_position_rows(eph: EphemerisRows, t_gps_s, *, apply_tgd: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sat_position_ecef` of the rows of :func:`ephemeris_rows` at times ``t_gps_s`` (N,): position (N, 3) m
    and clock (N,) s, every value the one ``sat_position_ecef`` gives on :func:`select_ephemerides`' table."""
    t = np.asarray(t_gps_s, dtype=np.float64).ravel()
    if t.size != eph.rows.size:
        raise ValueError(f"the ephemeris selection has {eph.rows.size} rows, the times {t.size}")
    if t.size == 0:
        return np.empty((0, 3)), np.empty(0)
    xyz, clock = np.empty((t.size, 3)), np.empty(t.size)
    if eph.glonass.size:
        xyz[eph.glonass], clock[eph.glonass] = _glonass_record_position(eph.glonass_eph, t[eph.glonass])
    if eph.kepler.size and kernel_available():
        kc = _packed_constants(eph.constants)
        if eph.glonass.size:
            xyz[eph.kepler], clock[eph.kepler] = _kepler_compiled(kc, eph.rows[eph.kepler], t[eph.kepler], apply_tgd)
        else:                                          # every row a Kepler row, in order: written in place
            _kepler_compiled(kc, eph.rows, t, apply_tgd, (xyz, clock))
    elif eph.kepler.size:
        c, kep = eph.constants, eph.kepler
        nav_k, tq = eph.rows[kep], t[kep]
        tk = tq - c["toe_gps_s"][nav_k]
        ek = _eccentric_anomaly(c["m0_rad"][nav_k] + c["n"][nav_k] * tk, c["e"][nav_k])   # each row on its own
        for a in range(0, kep.size, CHUNK_ROWS):        # the rest elementwise, chunk by chunk (temporaries of MB)
            s = slice(a, a + CHUNK_ROWS)
            kc = {f: v[nav_k[s]] for f, v in c.items()}
            xyz[kep[s]], clock[kep[s]] = _kepler_at_anomaly(kc, tq[s], tk[s], ek[s], apply_tgd)
    return xyz, clock


class ReceptionGeometry(NamedTuple):
    """Result of :func:`sat_position_at_reception` (arrays over the reception times)."""

    xyz_m: np.ndarray
    """Satellite position at transmission, in the ECEF frame of the reception instant, m, shape (N, 3)."""
    clock_s: np.ndarray
    """Satellite clock correction at transmission (T_GD applied), s, shape (N,)."""
    range_m: np.ndarray
    """Geometric range |xyz_m − rx_ecef|, m, shape (N,)."""
    travel_time_s: np.ndarray
    """Signal travel time range_m / c, s, shape (N,)."""


def sat_position_at_reception(
    nav: pd.DataFrame,
    sat: str,
    t_rx_gps_s,
    rx_ecef_m,
    *,
    rx_clock_s=0.0,
    apply_tgd: bool = True,
    max_age_s: float | None = None,
) -> ReceptionGeometry:
    """Satellite position for signals received at ``t_rx``: light time and Earth rotation.

    Iterates τ = |R₃(ω_E τ)·x_sat(t_rx − dt_rx − τ) − x_rx| / c until τ changes by less than
    1 ps, where R₃(ω_E τ) rotates the satellite position from the ECEF frame at transmission to
    the ECEF frame at reception (the Sagnac correction, up to ~30 m in range).

    Parameters
    ----------
    nav : DataFrame
        Ephemerides from :func:`~cdgps_cli.io.rinex.read_rinex_nav`.
    sat : str
        Satellite, e.g. ``"G05"``.
    t_rx_gps_s : float or array_like
        Receiver time tags of reception, GPS seconds, shape (N,).
    rx_ecef_m : array_like, shape (3,) or (N, 3)
        Receiver antenna position, ECEF, m.
    rx_clock_s : float or array_like, default 0
        Receiver clock offset (time tag − GPS time), s; the true reception time is
        ``t_rx − rx_clock_s``.  A receiver clock error of δ s moves the satellite by up to
        ~0.8 m per ms along the line of sight (range rate ≤ 800 m/s).
    apply_tgd : bool, default True
        See :func:`sat_position_ecef`.
    max_age_s : float, optional
        See :func:`select_ephemeris` (default by system).  The ephemeris is chosen by the reception tag ``t_rx``, so two
        receivers sharing an epoch use the same ephemeris (required for double differences).

    Returns
    -------
    ReceptionGeometry
        ``xyz_m`` (N, 3), ``clock_s`` (N,), ``range_m`` (N,), ``travel_time_s`` (N,).

    Raises
    ------
    CdgpsError
        From :func:`select_ephemeris` when the satellite is not covered.
    """
    t_rx = np.atleast_1d(np.asarray(t_rx_gps_s, dtype=np.float64)).ravel()
    rx = np.asarray(rx_ecef_m, dtype=np.float64)
    if rx.shape != (3,) and rx.shape != (t_rx.size, 3):
        raise ValueError(f"rx_ecef_m must have shape (3,) or ({t_rx.size}, 3), got {rx.shape}")
    eph = select_ephemeris(nav, sat, t_rx, max_age_s=max_age_s)
    t_true = t_rx - np.asarray(rx_clock_s, dtype=np.float64)
    tau = np.full(t_rx.shape, 0.075)
    position = _position_of(eph, (t_true - tau).shape, apply_tgd)
    rot, clk, rng = np.empty((t_rx.size, 3)), np.empty(t_rx.size), np.empty(t_rx.size)
    go = np.ones(t_rx.size, dtype=bool)     # each row iterates until its own step is below 1e-12 s
    for _ in range(10):
        xyz, c_all = position(t_true - tau)
        theta = OMEGA_E_GPS * tau
        c, s = np.cos(theta), np.sin(theta)
        rot_all = np.stack([c * xyz[:, 0] + s * xyz[:, 1], -s * xyz[:, 0] + c * xyz[:, 1], xyz[:, 2]], axis=-1)
        rng_all = np.linalg.norm(rot_all - rx, axis=-1)
        new_tau = rng_all / SPEED_OF_LIGHT_M_S
        rot[go], clk[go], rng[go] = rot_all[go], c_all[go], rng_all[go]
        step = np.abs(new_tau - tau)
        tau = np.where(go, new_tau, tau)
        go &= ~(step < 1e-12)
        if not go.any():
            break
    return ReceptionGeometry(rot, clk, rng, tau)


def _position_of(eph, shape: tuple, apply_tgd: bool):
    """``t ↦ sat_position_ecef(eph, t, apply_tgd=apply_tgd)`` for times of ``shape``: the same values,
    the ephemeris fields of a DataFrame of one kind of orbit (Kepler or GLONASS, e.g. one satellite's)
    taken out of it once for all the light-time iterations instead of at each."""
    size = int(np.prod(shape))
    if not isinstance(eph, pd.DataFrame) or eph.shape[0] != size:
        return lambda t: sat_position_ecef(eph, t, apply_tgd=apply_tgd)
    sats = _sats(eph, shape)
    constants = _system_constants(sats)
    glo = constants[3]
    if not glo.any():
        p = _kepler_fields(eph, shape)
        return lambda t: _kepler_at(p, constants, np.asarray(t, dtype=np.float64), apply_tgd)
    if glo.all():
        v = _glonass_fields(eph, size)
        return lambda t: _glonass_at(v, np.asarray(t, dtype=np.float64))
    return lambda t: sat_position_ecef(eph, t, apply_tgd=apply_tgd)


class ReceptionEphemeris(NamedTuple):
    """The broadcast ephemeris of every (satellite, time) row, selected once (:func:`reception_ephemeris`).

    Rows are kept grouped by satellite: ``order`` lists the Kepler-orbit rows (GPS, Galileo, BeiDou)
    satellite after satellite, ``starts`` where each satellite's block begins in it and ``nav_rows``
    the ephemeris (row of ``kepler``) of each; ``glonass`` lists (satellite, row indices) of the GLONASS
    satellites, which :func:`sat_positions_at_reception` evaluates one by one.
    """

    n_rows: int
    """Number of rows N."""
    order: np.ndarray
    """Indices (0…N−1) of the Kepler rows, grouped by satellite in name order, shape (K,)."""
    starts: np.ndarray
    """Start of each Kepler satellite's block in ``order``, shape (S,)."""
    nav_rows: np.ndarray
    """Ephemeris of each row of ``order``: its position in the navigation table and in ``kepler``, shape (K,)."""
    kepler: dict
    """Per ephemeris of the navigation table (arrays of its length): the orbit fields and the
    time-independent terms of the user algorithm."""
    glonass: tuple
    """(satellite, row indices) of each GLONASS satellite."""


CHUNK_ROWS = 65536
"""Rows evaluated together by :func:`sat_positions_at_reception` (whole satellites; at least one):
the temporaries of the orbit stay a few MB however long the record."""


def _sat_blocks(sats: np.ndarray) -> list:
    """(satellite, row indices) for each distinct satellite in name order; rows keep their order."""
    codes, names = pd.factorize(sats, sort=True)
    order = np.argsort(codes, kind="stable")
    cuts = np.r_[0, np.cumsum(np.bincount(codes[codes >= 0], minlength=len(names)))]
    order = order[order.size - cuts[-1]:]                  # (rows without a satellite, code −1, sort first)
    return [(str(names[i]), order[cuts[i]:cuts[i + 1]]) for i in range(len(names))]


def reception_ephemeris(nav: pd.DataFrame, sats, t_rx_gps_s, *, max_age_s: float | None = None) -> ReceptionEphemeris:
    """Select, once, the ephemeris of each (satellite, reception tag) row for :func:`sat_positions_at_reception`.

    The choice is :func:`select_ephemeris`'s for each satellite at its rows' tags (so a caller evaluating
    the same rows several times, e.g. iterating on the receiver clock, selects them once).

    Parameters
    ----------
    nav : DataFrame
        Ephemerides (:func:`~cdgps_cli.io.rinex.read_rinex_nav`).
    sats : array_like of str, shape (N,)
        Satellite of each row.
    t_rx_gps_s : array_like, shape (N,)
        Receiver time tag of each row, GPS s (selects the ephemeris).
    max_age_s : float, optional
        See :func:`select_ephemeris`.

    Raises
    ------
    CdgpsError
        As :func:`select_ephemeris`, for the first satellite in name order not covered.
    """
    sats = np.asarray(sats, dtype=object).ravel()
    t = np.asarray(t_rx_gps_s, dtype=np.float64).ravel()
    blocks = _sat_blocks(sats)
    columns = _ephemeris_columns(nav)
    kep, glo, rows = [], [], []
    for sat, idx in blocks:
        r = _ephemeris_rows(nav, sat, t[idx], max_age_s, columns)
        if sat.startswith("R"):
            glo.append((sat, idx))
        else:
            kep.append(idx)
            rows.append(r)
    sizes = np.array([idx.size for idx in kep], dtype=np.int64)
    order = np.concatenate(kep) if kep else np.zeros(0, dtype=np.int64)
    nav_rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
    return ReceptionEphemeris(t.size, order, np.cumsum(np.r_[0, sizes[:-1]]).astype(np.int64) if kep else sizes,
                              nav_rows, _kepler_constants(nav) if kep else {}, tuple(glo))


def _kepler_constants(nav: pd.DataFrame) -> dict:
    """The orbit fields of every ephemeris of ``nav`` and the time-independent terms of
    :func:`_kepler_position`, computed by the same operations (so, taken per row, the same values)."""
    missing = [f for f in _ORBIT_FIELDS if f not in nav.columns]
    if missing:
        raise ValueError(f"ephemeris lacks field(s) {', '.join(missing)} (as produced by read_rinex_nav)")
    p = _float_columns(nav, _ORBIT_FIELDS)
    gm, we, geo, _ = _system_constants(nav["sat"].astype(str).to_numpy())
    a = p["sqrt_a_sqrt_m"] ** 2
    e = p["e"]
    p.update(a=a, n=np.sqrt(gm / a**3) + p["delta_n_rad_per_s"], sqrt_1_e2=np.sqrt(1.0 - e * e),
             node_rate=p["omega_dot_rad_per_s"] - np.where(geo, 0.0, we), node_toe=we * p["toe_sow_s"],
             rel=F_RELATIVISTIC * np.sqrt(gm / GM_GPS) * e * p["sqrt_a_sqrt_m"], we=we, geo=geo)
    return p


def _chunks(starts: np.ndarray, n: int, size: int) -> list:
    """Cut the blocks beginning at ``starts`` (of ``n`` rows) into runs of whole blocks of about
    ``size`` rows: [(first row, end row, block starts relative to the first row)]."""
    ends = np.r_[starts[1:], n]
    out, b0 = [], 0
    while b0 < starts.size:
        b1 = max(b0 + 1, int(np.searchsorted(ends, starts[b0] + size, side="right")))
        out.append((int(starts[b0]), int(ends[b1 - 1]), starts[b0:b1] - starts[b0]))
        b0 = b1
    return out


def _kepler_rows(k: dict, t: np.ndarray, apply_tgd: bool) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_kepler_position` for rows (``k``: :func:`_kepler_constants` of those rows), position (K, 3) m and
    clock (K,) s, by the same operations, each row's Kepler equation iterated on its own."""
    tk = t - k["toe_gps_s"]
    ek = _eccentric_anomaly(k["m0_rad"] + k["n"] * tk, k["e"])
    return _kepler_at_anomaly(k, t, tk, ek, apply_tgd)


def _kepler_at_anomaly(k: dict, t: np.ndarray, tk: np.ndarray, ek: np.ndarray, apply_tgd: bool):
    """The rest of :func:`_kepler_rows` once the eccentric anomaly ``ek`` is known (``tk`` = t − toe):
    elementwise, so any slice of rows gives those rows' values."""
    e = k["e"]
    sin_e, cos_e = np.sin(ek), np.cos(ek)
    phi = np.arctan2(k["sqrt_1_e2"] * sin_e, cos_e - e) + k["omega_rad"]
    s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
    u = phi + k["cus_rad"] * s2 + k["cuc_rad"] * c2
    r = k["a"] * (1.0 - e * cos_e) + k["crs_m"] * s2 + k["crc_m"] * c2
    inc = k["i0_rad"] + k["idot_rad_per_s"] * tk + k["cis_rad"] * s2 + k["cic_rad"] * c2
    xp, yp = r * np.cos(u), r * np.sin(u)
    om = k["omega0_rad"] + k["node_rate"] * tk - k["node_toe"]
    cos_om, sin_om, cos_i = np.cos(om), np.sin(om), np.cos(inc)
    xyz = np.stack([xp * cos_om - yp * cos_i * sin_om, xp * sin_om + yp * cos_i * cos_om, yp * np.sin(inc)], axis=-1)
    geo = k["geo"]
    if np.any(geo):
        xyz = np.where(geo[..., None], beidou_geo_rotation(xyz, k["we"] * tk), xyz)
    dt = t - k["toc_gps_s"]
    clock = k["af0_s"] + k["af1_s_per_s"] * dt + k["af2_s_per_s2"] * dt * dt + k["rel"] * sin_e
    if apply_tgd:
        clock = clock - k["tgd_s"]
    return xyz, clock


def sat_positions_at_reception(nav: pd.DataFrame, sats, t_rx_gps_s, rx_ecef_m, *, rx_clock_s=0.0,
                               apply_tgd: bool = True, max_age_s: float | None = None,
                               ephemeris: ReceptionEphemeris | None = None) -> ReceptionGeometry:
    """:func:`sat_position_at_reception` for rows of many satellites at once.

    Every row gives exactly what one :func:`sat_position_at_reception` call on it gives (the light-time and
    Kepler iterations stop row by row, by the same tests, so a row's value does not depend on the rows evaluated
    with it), but the orbit is evaluated over all rows together and the ephemerides are selected once.

    Parameters
    ----------
    nav : DataFrame
        Ephemerides.
    sats : array_like of str, shape (N,)
        Satellite of each row.
    t_rx_gps_s : array_like, shape (N,)
        Receiver time tags of reception, GPS s.
    rx_ecef_m : array_like, shape (3,) or (N, 3)
        Receiver antenna position, ECEF m.
    rx_clock_s : float or array_like (N,), default 0
        Receiver clock offset, s (true reception time ``t_rx − rx_clock_s``).
    apply_tgd : bool
        See :func:`sat_position_ecef`.
    max_age_s : float, optional
        See :func:`select_ephemeris`.
    ephemeris : ReceptionEphemeris, optional
        :func:`reception_ephemeris` of the same ``sats`` and ``t_rx_gps_s`` (and ``max_age_s``), for
        callers evaluating the same rows again; selected here when absent.

    Returns
    -------
    ReceptionGeometry
        Arrays over the rows in their given order.
    """
    t_rx = np.atleast_1d(np.asarray(t_rx_gps_s, dtype=np.float64)).ravel()
    rx = np.asarray(rx_ecef_m, dtype=np.float64)
    if rx.shape != (3,) and rx.shape != (t_rx.size, 3):
        raise ValueError(f"rx_ecef_m must have shape (3,) or ({t_rx.size}, 3), got {rx.shape}")
    eph = ephemeris if ephemeris is not None else reception_ephemeris(nav, sats, t_rx, max_age_s=max_age_s)
    if eph.n_rows != t_rx.size:
        raise ValueError(f"the ephemeris selection has {eph.n_rows} rows, the times {t_rx.size}")
    rx_clock = np.broadcast_to(np.asarray(rx_clock_s, dtype=np.float64), t_rx.shape)
    t_true = t_rx - rx_clock
    out = (np.empty((t_rx.size, 3)), np.empty(t_rx.size), np.empty(t_rx.size), np.empty(t_rx.size))
    for sat, idx in eph.glonass:
        g = sat_position_at_reception(nav, sat, t_rx[idx], rx[idx] if rx.ndim == 2 else rx,
                                      rx_clock_s=rx_clock[idx], apply_tgd=apply_tgd, max_age_s=max_age_s)
        for a, v in zip(out, g):
            a[idx] = v
    packed = _packed_constants(eph.kepler) if eph.order.size and kernel_available() else None
    chunks = _chunks(eph.starts, eph.order.size, CHUNK_ROWS)
    if packed is not None:
        rx = np.ascontiguousarray(rx)
        order = np.ascontiguousarray(eph.order, dtype=np.int64)
        scratch = _Scratch(max(r1 - r0 for r0, r1, _ in chunks))
    for r0, r1, _ in chunks:
        o = eph.order[r0:r1]
        if packed is not None:
            _light_time_compiled(packed, eph.nav_rows[r0:r1], t_true[o], rx, order[r0:r1], apply_tgd, out, scratch)
            continue
        k = {f: v[eph.nav_rows[r0:r1]] for f, v in eph.kepler.items()}
        g = _light_time_rows(k, t_true[o], rx[o] if rx.ndim == 2 else rx, apply_tgd)
        for a, v in zip(out, g):
            a[o] = v
    return ReceptionGeometry(*out)


def _light_time_rows(k: dict, t_true: np.ndarray, rx: np.ndarray, apply_tgd: bool):
    """The light-time iteration of :func:`sat_position_at_reception` on rows (``k``: their Kepler constants), each
    row stopping on its own test: (position (K, 3), clock, range, travel time)."""
    n = t_true.size
    rot, clk, rng = np.empty((n, 3)), np.empty(n), np.empty(n)
    tau = np.full(n, 0.075)
    per_row = rx.ndim == 2
    r = np.arange(n)                        # the rows still iterating
    for _ in range(10):
        sub = {f: v[r] for f, v in k.items()}
        tr = tau[r]
        xyz, c_r = _kepler_rows(sub, t_true[r] - tr, apply_tgd)
        theta = OMEGA_E_GPS * tr
        c, s = np.cos(theta), np.sin(theta)
        rot_r = np.stack([c * xyz[:, 0] + s * xyz[:, 1], -s * xyz[:, 0] + c * xyz[:, 1], xyz[:, 2]], axis=-1)
        rng_r = np.linalg.norm(rot_r - (rx[r] if per_row else rx), axis=-1)
        new_tau = rng_r / SPEED_OF_LIGHT_M_S
        step = np.abs(new_tau - tr)
        rot[r], clk[r], rng[r], tau[r] = rot_r, c_r, rng_r, new_tau
        r = r[~(step < 1e-12)]
        if not r.size:
            break
    return rot, clk, rng, tau


# ----------------------------------------------------------------------------------------------
# the compiled kernel (cdgps_cli.model.gps._orbitcore): the same values as the numpy functions above
# ----------------------------------------------------------------------------------------------

_CORE_API = 4
_CORE_FIELDS = ("toe_gps_s", "m0_rad", "n", "e", "sqrt_1_e2", "omega_rad", "cus_rad", "cuc_rad", "a", "crs_m", "crc_m",
                "i0_rad", "idot_rad_per_s", "cis_rad", "cic_rad", "omega0_rad", "node_rate", "node_toe", "geo", "we",
                "toc_gps_s", "af0_s", "af1_s_per_s", "af2_s_per_s2", "rel", "tgd_s")
"""Columns of the kernel's ephemeris matrix, in the order of its enum (``K_TOE`` … ``K_TGD``)."""


def kernel_available() -> bool:
    """True when the compiled orbit kernel is importable, current, and not disabled by the environment
    variable ``CDGPS_NO_KERNEL`` (anything but ``""`` / ``"0"``: the rule of :mod:`cdgps_cli.estimation.compiled`)."""
    if os.environ.get("CDGPS_NO_KERNEL", "") not in ("", "0"):
        return False
    return (_orbitcore is not None and getattr(_orbitcore, "API", None) == _CORE_API
            and getattr(_orbitcore, "NK", None) == len(_CORE_FIELDS))


def _packed_constants(k: dict) -> np.ndarray:
    """:func:`_kepler_constants` as the kernel's matrix, one row per ephemeris (n_eph, len(_CORE_FIELDS))."""
    return np.ascontiguousarray(np.column_stack([np.asarray(k[f], dtype=np.float64) for f in _CORE_FIELDS]))


def _core_state(n: int, n_blocks: int) -> tuple:
    """The kernel's per-row state (zero: nothing kept), its (y, x) of the true anomaly and the live blocks."""
    return (np.zeros((n, _orbitcore.NS)), np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n),
            np.ones(n_blocks, dtype=np.uint8))


def _core_kepler(kc: np.ndarray, rows: np.ndarray, t: np.ndarray, starts: np.ndarray, state: tuple, memo: bool,
                 apply_tgd: bool, xyz: np.ndarray, clk: np.ndarray, nu: np.ndarray | None = None) -> None:
    """Position (xyz) and clock (clk) of the rows of the live blocks at times ``t``: Kepler's equation in C,
    numpy's arctan2 of the true anomaly (a SIMD routine, not libm's atan2; into ``nu`` when given), the rest in C."""
    s, info, yat, xat, live = state
    _orbitcore.anomaly(kc, rows, t, starts, live, s, info, yat, xat, memo)
    nu = np.arctan2(yat, xat, out=nu)
    _orbitcore.kepler(kc, rows, t, starts, live, s, info, nu, xyz, clk, apply_tgd,
                      float(np.cos(BEIDOU_GEO_TILT_RAD)), float(np.sin(BEIDOU_GEO_TILT_RAD)))


def _kepler_compiled(kc: np.ndarray, rows: np.ndarray, t: np.ndarray, apply_tgd: bool,
                     out: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sat_position_rows`' Kepler rows in C: Kepler's equation (each row iterated until its own step is
    below 1e-15 rad), then the rest chunk by chunk (temporaries of MB), position (K, 3) m and clock (K,) s (written
    into ``out``, C-contiguous float64 arrays of those shapes, when given)."""
    n = t.size
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    t = np.ascontiguousarray(t, dtype=np.float64)
    ek = np.empty(n)
    _orbitcore.newton(kc, rows, t, ek, np.empty(n, dtype=np.uint8))
    xyz, clk = out if out is not None else (np.empty((n, 3)), np.empty(n))
    ct, st = float(np.cos(BEIDOU_GEO_TILT_RAD)), float(np.sin(BEIDOU_GEO_TILT_RAD))
    for a in range(0, n, CHUNK_ROWS):
        s = slice(a, a + CHUNK_ROWS)
        m = ek[s].size
        sn, cs, yat, xat = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
        _orbitcore.anomaly_trig(kc, rows[s], ek[s], sn, cs, yat, xat)
        _orbitcore.orbit(kc, rows[s], t[s], sn, cs, np.arctan2(yat, xat), xyz[s], clk[s], apply_tgd, ct, st)
    return xyz, clk


class _Scratch:
    """The light-time kernel's buffers for chunks of up to ``n`` rows, allocated once per
    :func:`sat_positions_at_reception` call (fresh pages for every chunk cost more than the arithmetic)."""

    def __init__(self, n: int):
        self.state = np.empty((n, _orbitcore.NS))          # no initial value needed: the first call sets every row
        self.info = np.empty(n, dtype=np.int64)
        self.yx = np.zeros((2, n))                           # finite values for np.arctan2 in rows not evaluated
        self.f = np.empty((4, n))                            # clock, travel time, time, true anomaly
        self.xyz = np.empty((n, 3))
        self.each = np.arange(n, dtype=np.int64)             # every row a block of its own
        self.live = np.empty(n, dtype=np.uint8)

    def take(self, n: int) -> tuple:
        """(state tuple for :func:`_core_kepler`, xyz, clock, τ = 0.075, time, true anomaly, block starts) for
        ``n`` rows, each row a block."""
        tau = self.f[1, :n]
        tau.fill(0.075)
        live = self.live[:n]
        live.fill(1)
        return ((self.state[:n], self.info[:n], self.yx[0, :n], self.yx[1, :n], live),
                self.xyz[:n], self.f[0, :n], tau, self.f[2, :n], self.f[3, :n], self.each[:n])


def _light_time_compiled(kc: np.ndarray, rows: np.ndarray, t_true: np.ndarray, rx: np.ndarray, order: np.ndarray,
                         apply_tgd: bool, out: tuple, scratch: _Scratch) -> None:
    """:func:`_light_time_rows` in C, written into rows ``order`` of ``out`` (position (N, 3), clock, range,
    travel time), value for value: every row is a block of its own for the kernel, so it iterates Kepler's
    equation and the light time on its own tests.  ``kc``: :func:`_packed_constants` of the navigation table;
    ``rows``: each row's ephemeris in it; ``t_true`` (K,) the rows' true reception times; ``rx`` (3,) or (N, 3)."""
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    state, xyz, clk, tau, t, nu, starts = scratch.take(t_true.size)
    for it in range(10):
        _core_kepler(kc, rows, np.subtract(t_true, tau, out=t), starts, state, it > 0, apply_tgd, xyz, clk, nu)
        if not _orbitcore.light(xyz, clk, starts, state[4], tau, rx, rx.ndim == 2, order, *out, OMEGA_E_GPS,
                                SPEED_OF_LIGHT_M_S):
            break


# ----------------------------------------------------------------------------------------------
# coordinates
# ----------------------------------------------------------------------------------------------


def ecef_to_geodetic(xyz_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF → WGS-84 geodetic latitude, longitude and ellipsoidal height.

    Parameters
    ----------
    xyz_m : array_like, shape (..., 3)
        ECEF coordinates, m.

    Returns
    -------
    lat_rad, lon_rad, h_m : ndarray, shape (...)
        Geodetic latitude and longitude, rad; height above the ellipsoid, m.  Iterated to
        below 1e-12 rad / 0.1 mm; the poles and the origin are handled (lon 0 on the axis).
    """
    xyz = np.asarray(xyz_m, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    e2 = WGS84_F * (2.0 - WGS84_F)
    r2 = x * x + y * y
    zk = np.zeros_like(z)
    zz = np.array(z, copy=True)
    v = np.full_like(z, WGS84_A)
    for _ in range(30):
        zk = zz
        sinp = zz / np.sqrt(np.maximum(r2 + zz * zz, 1e-300))
        v = WGS84_A / np.sqrt(1.0 - e2 * sinp * sinp)
        zz = z + v * e2 * sinp
        if np.all(np.abs(zz - zk) < 1e-5):
            break
    lat = np.where(r2 > 1e-12, np.arctan(zz / np.sqrt(np.maximum(r2, 1e-300))), np.where(z > 0, np.pi / 2, np.where(z < 0, -np.pi / 2, 0.0)))
    lon = np.where(r2 > 1e-12, np.arctan2(y, x), 0.0)
    h = np.sqrt(r2 + zz * zz) - v
    return lat, lon, h


def geodetic_to_ecef(lat_rad, lon_rad, h_m) -> np.ndarray:
    """WGS-84 geodetic latitude, longitude (rad) and height (m) → ECEF, m, shape (..., 3)."""
    lat = np.asarray(lat_rad, dtype=np.float64)
    lon = np.asarray(lon_rad, dtype=np.float64)
    h = np.asarray(h_m, dtype=np.float64)
    e2 = WGS84_F * (2.0 - WGS84_F)
    sinp, cosp = np.sin(lat), np.cos(lat)
    v = WGS84_A / np.sqrt(1.0 - e2 * sinp * sinp)
    return np.stack(np.broadcast_arrays((v + h) * cosp * np.cos(lon), (v + h) * cosp * np.sin(lon), (v * (1.0 - e2) + h) * sinp), axis=-1)


def enu_matrix(lat_rad, lon_rad) -> np.ndarray:
    """Rotation from ECEF to local east-north-up axes at a geodetic latitude/longitude.

    Parameters
    ----------
    lat_rad, lon_rad : float or array_like
        Geodetic latitude and longitude, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        R with rows (east, north, up), so that ``enu = R @ (xyz − xyz_ref)``.
    """
    lat = np.asarray(lat_rad, dtype=np.float64)
    lon = np.asarray(lon_rad, dtype=np.float64)
    sp, cp, sl, cl = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    zero = np.zeros(np.broadcast(lat, lon).shape)
    rows = [
        np.stack(np.broadcast_arrays(-sl, cl, zero), axis=-1),
        np.stack(np.broadcast_arrays(-sp * cl, -sp * sl, cp), axis=-1),
        np.stack(np.broadcast_arrays(cp * cl, cp * sl, sp), axis=-1),
    ]
    return np.stack(rows, axis=-2)


def ecef_to_enu(xyz_m, ref_ecef_m) -> np.ndarray:
    """Vectors from a reference point to ECEF points in the reference's local ENU frame, m, shape (..., 3)."""
    ref = np.asarray(ref_ecef_m, dtype=np.float64)
    lat, lon, _ = ecef_to_geodetic(ref)
    r = enu_matrix(lat, lon)
    d = np.asarray(xyz_m, dtype=np.float64) - ref
    return np.einsum("...ij,...j->...i", r, d)


def azimuth_elevation(rx_ecef_m, sat_ecef_m) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (from north, clockwise, in [0, 2π)) and elevation (rad) of satellites seen from a receiver.

    Parameters
    ----------
    rx_ecef_m : array_like, shape (3,) or (..., 3)
        Receiver position, ECEF, m.
    sat_ecef_m : array_like, shape (..., 3)
        Satellite positions, ECEF, m.

    Returns
    -------
    az_rad, el_rad : ndarray, shape (...)
    """
    e, n, u = _enu_components(rx_ecef_m, sat_ecef_m)
    az = np.mod(np.arctan2(e, n), 2.0 * np.pi)
    el = np.arctan2(u, np.hypot(e, n))
    return az, el


def elevation(rx_ecef_m, sat_ecef_m) -> np.ndarray:
    """The elevation of :func:`azimuth_elevation` alone (the same values), rad, shape (...)."""
    e, n, u = _enu_components(rx_ecef_m, sat_ecef_m)
    return np.arctan2(u, np.hypot(e, n))


def _enu_components(rx_ecef_m, sat_ecef_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """East, north and up of the satellites from the receiver, m (views of one (..., 3) array)."""
    rx = np.asarray(rx_ecef_m, dtype=np.float64)
    lat, lon, _ = ecef_to_geodetic(rx)
    r = enu_matrix(lat, lon)
    sat = np.asarray(sat_ecef_m, dtype=np.float64)
    if rx.shape == (3,) and sat.ndim == 2 and sat.shape[1] == 3 and kernel_available():
        enu = np.empty(sat.shape)                  # one pass in C, the einsum's sums (tested equal)
        _orbitcore.enu(np.ascontiguousarray(r), rx, np.ascontiguousarray(sat), enu)
    else:
        enu = np.einsum("...ij,...j->...i", r, sat - rx)
    return enu[..., 0], enu[..., 1], enu[..., 2]
