"""Edit a real RINEX 3 observation file into a harder one whose answer is known.

Real base + rover pairs are scarce, and the real ones that are clean (identical 1 s tags, no base
gaps) do not exercise what low-cost receivers do.  :func:`edit_rinex3_obs` turns such a real file
into one that does, changing only what the edit says and leaving every other byte as recorded:

* ``keep(t)`` — drop epochs (a base that logs with gaps, a lower rate);
* ``clock_offset_s(t)`` — a receiver clock that is off by δ (millisecond steering, clock jumps):
  the time tag becomes t + δ and every pseudorange and carrier phase gains c·δ (cycles: c·δ/λ),
  exactly as a receiver whose clock reads δ ahead would have measured them.  The double
  differences are unchanged: a solver that models each receiver's reception instant must give
  the same answer as on the original file;
* ``code_clock_s(t)`` — a clock jump that the codes carry and the phases do not (tags on the grid): the
  ranges taken δ earlier, the codes c·δ more;
* ``range_change_m(t, sats)`` — a known antenna motion: every pseudorange and phase of satellite
  s at epoch t changes by the geometric range change Δρ_s(t) (m; cycles Δρ/λ), for instance
  Δρ = −eᵀ d(t) with e the unit vector to the satellite and d(t) a vibration
  (:func:`range_change_of_motion`).

Wavelengths come from the RINEX 3 band digit of each observation code (RINEX 3.04 Table 4; GLONASS
FDMA bands 1 and 2 from the header's ``GLONASS SLOT / FRQ #``).  Event records (epoch flag > 1) are
copied unchanged.  Pure text → text: the caller reads and writes the files.
"""

from __future__ import annotations

import datetime as _dt
import math

import numpy as np

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix, sat_position_ecef, select_ephemeris

__all__ = ["edit_rinex3_obs", "range_change_of_motion", "epoch_times_gps_s", "BAND_FREQUENCY_HZ"]

#: carrier of each (system, RINEX 3 band digit), Hz (RINEX 3.04 Table 4); GLONASS 1/2 are FDMA (below)
BAND_FREQUENCY_HZ = {
    ("G", "1"): 1575.42e6, ("G", "2"): 1227.60e6, ("G", "5"): 1176.45e6,
    ("E", "1"): 1575.42e6, ("E", "5"): 1176.45e6, ("E", "7"): 1207.14e6, ("E", "8"): 1191.795e6, ("E", "6"): 1278.75e6,
    ("C", "1"): 1575.42e6, ("C", "2"): 1561.098e6, ("C", "5"): 1176.45e6, ("C", "7"): 1207.14e6,
    ("C", "8"): 1191.795e6, ("C", "6"): 1268.52e6,
    ("J", "1"): 1575.42e6, ("J", "2"): 1227.60e6, ("J", "5"): 1176.45e6, ("J", "6"): 1278.75e6,
    ("S", "1"): 1575.42e6, ("S", "5"): 1176.45e6, ("I", "5"): 1176.45e6, ("I", "9"): 2492.028e6,
    ("R", "3"): 1202.025e6, ("R", "4"): 1600.995e6, ("R", "6"): 1248.06e6,
}
_GLONASS_FDMA = {"1": (1602.0e6, 0.5625e6), "2": (1246.0e6, 0.4375e6)}
_GPS_EPOCH = _dt.datetime(1980, 1, 6)


def _header(lines):
    """Observation types per system, GLONASS frequency numbers and the index of the first record."""
    types, slots, sys_cur = {}, {}, None
    for i, ln in enumerate(lines):
        label = ln[60:80].strip()
        if i == 0 and (not label.startswith("RINEX VERSION") or not ln[:9].strip().startswith("3")):
            raise CdgpsError(f"line 1: a RINEX 3 observation file is needed (got {ln[:20].strip()!r} …)")
        if label == "SYS / # / OBS TYPES":
            if ln[0] != " ":
                sys_cur = ln[0]
                types[sys_cur] = []
            types[sys_cur] += ln[7:60].split()
        elif label == "GLONASS SLOT / FRQ #":
            f = ln[4:60].split()
            for k in range(0, len(f) - 1, 2):
                slots[f[k]] = int(f[k + 1])
        elif label == "END OF HEADER":
            return types, slots, i + 1
    raise CdgpsError("no END OF HEADER line")


def _wavelength(sat: str, code: str, slots: dict) -> float:
    band = code[1]
    if sat[0] == "R" and band in _GLONASS_FDMA:
        if sat not in slots:
            return math.nan
        f0, df = _GLONASS_FDMA[band]
        return SPEED_OF_LIGHT_M_S / (f0 + slots[sat] * df)
    f = BAND_FREQUENCY_HZ.get((sat[0], band))
    return SPEED_OF_LIGHT_M_S / f if f else math.nan


def _epoch_gps_s(ln: str) -> float:
    y, mo, d, h, mi = (int(ln[a:b]) for a, b in ((2, 6), (7, 9), (10, 12), (13, 15), (16, 18)))
    sec = float(ln[18:29])
    return (_dt.datetime(y, mo, d, h, mi) - _GPS_EPOCH).total_seconds() + sec


def _epoch_line(ln: str, offset_s: float) -> str:
    """The epoch line with its time tag moved by ``offset_s``, in whole 100 ns steps (float64 GPS
    seconds near 1.4·10⁹ resolve only 0.24 µs, so the tag is not rebuilt from them)."""
    y, mo, d, h, mi = (int(ln[a:b]) for a, b in ((2, 6), (7, 9), (10, 12), (13, 15), (16, 18)))
    ticks = round(float(ln[18:29]) * 10**7) + round(offset_s * 10**7)
    when = _dt.datetime(y, mo, d, h, mi) + _dt.timedelta(seconds=ticks // 10**7)
    frac = ticks % 10**7
    return (f"> {when.year:4d} {when.month:02d} {when.day:02d} {when.hour:02d} {when.minute:02d}"
            f"{when.second:3d}.{frac:07d}" + ln[29:])


def _shift_record(ln: str, codes: list, sat: str, slots: dict, dr_m: float, code_only_m: float = 0.0) -> str:
    """One satellite line with every L (cycles) and C (m) value moved by the range change ``dr_m``, the C values
    by ``code_only_m`` more."""
    if dr_m == 0.0 and code_only_m == 0.0:
        return ln
    out = list(ln.ljust(3 + 16 * len(codes)))
    for k, code in enumerate(codes):
        a = 3 + 16 * k
        field = "".join(out[a:a + 14])
        if not field.strip() or code[0] not in "LC":
            continue
        lam = _wavelength(sat, code, slots) if code[0] == "L" else 1.0
        if not math.isfinite(lam):
            continue
        out[a:a + 14] = f"{float(field) + dr_m / lam + (code_only_m if code[0] == 'C' else 0.0):14.3f}"
    return "".join(out).rstrip()


def _doppler_range_rate_m_s(ln: str, codes: list, sat: str, slots: dict) -> float:
    """The satellite's range rate from the line's first Doppler (Hz, RINEX sign: positive approaching), m/s;
    CdgpsError without one (the edit cannot move that satellite's ranges as the others')."""
    for k, code in enumerate(codes):
        field = ln[3 + 16 * k:3 + 16 * k + 14]
        if code[0] == "D" and field.strip():
            lam = _wavelength(sat, "L" + code[1:], slots)
            if math.isfinite(lam):
                return -float(field) * lam
    raise CdgpsError(f"code_clock_s: {sat} has no Doppler in its record '{ln[:40]}…' to move its ranges by")


def _phase_negated(ln: str, codes: list) -> str:
    """One satellite line with its carrier phases (L) and Dopplers (D) written with the wrong sign."""
    out = list(ln.ljust(3 + 16 * len(codes)))
    for k, code in enumerate(codes):
        a = 3 + 16 * k
        field = "".join(out[a:a + 14])
        if field.strip() and code[0] in "LD":
            out[a:a + 14] = f"{-float(field):14.3f}"
    return "".join(out).rstrip()


def edit_rinex3_obs(text: str, *, keep=None, clock_offset_s=None, range_change_m=None, code_clock_s=None,
                    phase_negated=()) -> str:
    """Edit a RINEX 3 observation file's text (module docstring).

    Parameters
    ----------
    text : str
        The file's contents.
    keep : callable, optional
        ``keep(t_gps_s) -> bool``: whether the epoch tagged t (GPS s) stays (default: all).
    clock_offset_s : callable, optional
        ``clock_offset_s(t_gps_s) -> float``: the receiver clock's offset δ at that epoch, s.
    range_change_m : callable, optional
        ``range_change_m(t_gps_s, sats) -> array (len(sats),)``: geometric range change of each
        satellite of the epoch (``sats`` like ``["G05", "E11", …]``), m.
    code_clock_s : callable, optional
        ``code_clock_s(t_gps_s) -> float``: a receiver clock offset δ that the codes carry and the phases and time
        tag do not (a receiver whose carrier stays continuous when its clock is reset by a millisecond): the
        signals were received δ earlier than tagged, so every pseudorange and phase takes the range change over δ
        (−ρ̇ δ, ρ̇ from the satellite's first Doppler in the line) and every pseudorange c·δ more.
    phase_negated : collection of str, optional
        Satellites (``"G05"``) whose carrier phases and Dopplers are written with the wrong sign, as a receiver with
        that defect writes them (gnss-sdr 0.0.19 did for some satellites; measurement/phase_sign).

    Returns
    -------
    str
        The edited file (the header as it was).

    Raises
    ------
    CdgpsError
        Not a RINEX 3 observation file, or a record cut short.
    """
    lines = text.splitlines()
    types, slots, i = _header(lines)
    out = lines[:i]
    while i < len(lines):
        ln = lines[i]
        if not ln.startswith(">"):
            raise CdgpsError(f"line {i + 1}: expected an epoch record starting with '>', got {ln[:20]!r}")
        flag, n = int(ln[31:32] or 0), int(ln[32:35])
        body = lines[i + 1:i + 1 + n]
        if len(body) < n:
            raise CdgpsError(f"line {i + 1}: the epoch announces {n} records but the file ends after {len(body)}")
        i += 1 + n
        if flag > 1:
            out += [ln, *body]
            continue
        t = _epoch_gps_s(ln)
        if keep is not None and not keep(t):
            continue
        sats = [b[:3].replace(" ", "0") for b in body]
        dr = np.zeros(n)
        if range_change_m is not None and n:
            dr = dr + np.asarray(range_change_m(t, sats), dtype=float)
        if clock_offset_s is not None:
            d = float(clock_offset_s(t))
            dr = dr + SPEED_OF_LIGHT_M_S * d
            ln = _epoch_line(ln, d)
        code_m = 0.0
        if code_clock_s is not None:
            d = float(code_clock_s(t))
            code_m = SPEED_OF_LIGHT_M_S * d
            dr = dr - d * np.array([_doppler_range_rate_m_s(b, types.get(s[0], []), s, slots)
                                    for b, s in zip(body, sats)])
        out.append(ln)
        body = [_shift_record(b, types.get(s[0], []), s, slots, float(r), code_m) for b, s, r in zip(body, sats, dr)]
        out += [_phase_negated(b, types.get(s[0], [])) if s in phase_negated else b for b, s in zip(body, sats)]
    return "\n".join(out) + "\n"


def epoch_times_gps_s(text: str) -> np.ndarray:
    """The time tags (GPS s) of a RINEX 3 observation file's observation epochs (flag 0 or 1), in file
    order: the ``times_gps_s`` of :func:`range_change_of_motion` for that file."""
    lines = text.splitlines()
    i = _header(lines)[2]
    out = []
    while i < len(lines):
        ln = lines[i]
        if not ln.startswith(">"):
            raise CdgpsError(f"line {i + 1}: expected an epoch record starting with '>', got {ln[:20]!r}")
        if int(ln[31:32] or 0) <= 1:
            out.append(_epoch_gps_s(ln))
        i += 1 + int(ln[32:35])
    return np.asarray(out, dtype=float)


def _unit_vectors(nav, sat: str, t: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Unit vectors (N, 3) from ``xyz`` to ``sat`` at times ``t`` (transmission 0.075 s earlier); rows
    of 0 where the satellite has no healthy ephemeris near the time."""
    try:
        eph = select_ephemeris(nav, sat, t)
        ok = np.ones(t.size, dtype=bool)
    except CdgpsError:                                    # some times uncovered: find which, one by one
        ok = np.zeros(t.size, dtype=bool)
        for k, tk in enumerate(t):
            try:
                select_ephemeris(nav, sat, np.array([tk]))
                ok[k] = True
            except CdgpsError:
                pass
        if not ok.any():
            return np.zeros((t.size, 3))
        eph = select_ephemeris(nav, sat, t[ok])
    p, _ = sat_position_ecef(eph, t[ok] - 0.075)
    e = np.asarray(p, dtype=float).reshape(-1, 3) - xyz
    out = np.zeros((t.size, 3))
    out[ok] = e / np.linalg.norm(e, axis=1, keepdims=True)
    return out


def range_change_of_motion(nav, xyz_m, displacement_enu_m, times_gps_s=None):
    """``range_change_m`` for :func:`edit_rinex3_obs`: the range change of an antenna at ``xyz_m``
    (ECEF, m) displaced by ``displacement_enu_m(t) -> (3,)`` (east, north, up, m) at GPS time t, to
    each satellite of an epoch with an ephemeris in ``nav`` (others: 0): Δρ_s = −e_sᵀ d(t), e_s the
    unit vector from the antenna to the satellite (at t − 0.075 s of flight; the direction changes
    by < 10⁻⁵ rad over the flight time).

    ``times_gps_s`` (optional, the file's epochs: :func:`epoch_times_gps_s`): the unit vectors of
    every satellite at those times are computed at once, vectorized (the same values to 10⁻¹³ m,
    about 100 times faster than one epoch at a time); an epoch not among them is computed alone."""
    xyz = np.asarray(xyz_m, dtype=float)
    lat, lon, _ = ecef_to_geodetic(xyz)
    r_enu = enu_matrix(lat, lon)                         # rows: east, north, up in ECEF
    have = set(nav["sat"].unique())
    grid = None if times_gps_s is None else np.unique(np.asarray(times_gps_s, dtype=float))
    cache: dict = {}

    def unit(s: str, t: float) -> np.ndarray:
        if grid is not None:
            k = int(np.searchsorted(grid, t))
            if k < grid.size and grid[k] == t:
                if s not in cache:
                    cache[s] = _unit_vectors(nav, s, grid, xyz)
                return cache[s][k]
        return _unit_vectors(nav, s, np.array([t]), xyz)[0]

    def change(t, sats):
        d_ecef = r_enu.T @ np.asarray(displacement_enu_m(t), dtype=float)
        return np.array([-(unit(s, t) @ d_ecef) if s in have else 0.0 for s in sats])

    return change
