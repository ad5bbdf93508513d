"""GPS measurement models shared by the static-baseline solver: troposphere, receiver clocks,
epoch matching, per-receiver reception geometry, and a simulator of two static receivers.

* :func:`tropo_zenith_hydrostatic_m`, :func:`niell_hydrostatic_mapping`, :func:`tropo_hydrostatic_m`
  — Saastamoinen zenith hydrostatic delay under the standard atmosphere, mapped with the Niell
  (1996) hydrostatic mapping function.  This is the a priori troposphere that RTKLIB 2.4.3 applies
  to every undifferenced range in relative positioning (``zdres`` in ``rtkpos.c``), so that both
  programs model the same thing; over a short baseline it largely cancels in the double
  differences (GEONET 3040–0759: 5.6 m of height difference, about 2 mm zenith; leaving it out
  moves that solution by 2–5 mm).
* :func:`estimate_receiver_clock` — receiver clock offset per epoch from L1 pseudoranges at a known
  position, so that geometry can be computed at each receiver's *true* reception time.
* :func:`spp_static` — static single-point position (all epochs, one clock per epoch), used when
  a RINEX header has no APPROX POSITION.
* :func:`match_epochs` — pair two receivers' epochs whose time tags differ by less than a tolerance
  (the receivers here steer their clocks in 1 ms steps, so tags drift by a few ms).
* :func:`reception_geometry` — satellite position (Sagnac-corrected), clock, range, azimuth and
  elevation, troposphere for the rows of one receiver at their true reception times.
* :func:`synthetic_gps_nav` — broadcast ephemerides of a nominal 30-satellite GPS-like
  constellation for any date (simulations without a real navigation file).
* :func:`simulate_static_pair` — L1 phase and pseudorange of two static receivers from broadcast
  ephemerides with integer ambiguities, receiver clocks, slips, noise and C/N0, as tables in the format
  of :func:`~cdgps_cli.io.rinex.read_rinex_obs` (for tests and benchmarks).

Units: positions ECEF (WGS-84) m; angles rad; times GPS seconds since 1980-01-06; clocks s;
phases cycles of the L1 carrier; pseudoranges and delays m.  Functions are pure.
"""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pandas as pd

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.model.gps.orbits import (  # noqa: I001
    _orbitcore,
    kernel_available,
    GM_GPS,
    MAX_EPHEMERIS_AGE_GLONASS_S,
    MAX_EPHEMERIS_AGE_S,
    azimuth_elevation,
    ecef_to_geodetic,
    elevation,
    enu_matrix,
    healthy_ephemeris,
    reception_ephemeris,
    sat_position_at_reception,
    sat_positions_at_reception,
)
from cdgps_cli.core.checks import header_position_m
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import GPS_EPOCH, nominal_interval_s  # noqa: F401 (re-exported)
from cdgps_cli.core.records import OBS_COLUMNS
from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M

__all__ = [
    "day_of_year",
    "tropo_zenith_hydrostatic_m",
    "niell_hydrostatic_mapping",
    "niell_wet_mapping",
    "tropo_hydrostatic_m",
    "ephemeris_coverage",
    "ephemeris_coverage_all",
    "spp_spread",
    "estimate_receiver_clock",
    "spp_static",
    "nominal_interval_s",
    "match_epochs",
    "reception_geometry",
    "simulate_static_pair",
    "synthetic_gps_nav",
    "synthetic_nav",
]

"""GPS L1 carrier wavelength c / 1575.42 MHz, m."""


# ----------------------------------------------------------------------------------------------
# troposphere (a priori, hydrostatic)
# ----------------------------------------------------------------------------------------------


#: an antenna farther than this from its marker in any axis is refused (m): a header's nonsense, not a mast
ANTENNA_DELTA_MAX_M = 1.0e4


def antenna_reference_point_m(header: dict, what: str = "the header"):
    """The antenna reference point (ARP) of a RINEX header's station, ECEF m (3,): its APPROX POSITION XYZ (the
    marker) plus its ``ANTENNA: DELTA H/E/N`` (the ARP's height above the marker and its east and north offsets, m)
    turned from the east-north-up axes at the marker; the marker itself, unchanged, when the delta is absent or zero;
    None when the header has no usable position (:func:`~cdgps_cli.core.checks.header_position_m`).

    A reference station's file gives the marker's surveyed coordinates and the antenna's height above it (a CORS:
    centimetres to metres): the phases are the antenna's.  RTKLIB's ``rnx2rtkp`` does the same with a base position
    taken from its header (``ant2-postype=rinexhead``; measured: a DELTA H/E/N of 0.5 / 0.1 / −0.2 m moves its rover
    by that vector) and applies no delta to a position given as coordinates or to the rover's header.  ``what``
    names the file in the error raised for a delta that is not three finite numbers within
    :data:`ANTENNA_DELTA_MAX_M` of the marker."""
    pos = header_position_m(header)
    delta = header.get("antenna_delta_hen_m")
    if pos is None or delta is None:
        return pos
    h, e, n = (float(v) for v in delta)
    if not all(math.isfinite(v) and abs(v) <= ANTENNA_DELTA_MAX_M for v in (h, e, n)):
        raise CdgpsError(f"{what}: ANTENNA: DELTA H/E/N ({h!r} {e!r} {n!r} m) is not three numbers within "
                         f"±{ANTENNA_DELTA_MAX_M:g} m of the marker")
    if h == e == n == 0.0:
        return pos
    lat, lon, _ = ecef_to_geodetic(pos)
    return pos + enu_matrix(lat, lon).T @ np.array([e, n, h])


def rover_delta_note(header: dict, what: str) -> list:
    """A note (a list of one string, or none) when a rover's header gives a non-zero ANTENNA: DELTA H/E/N: its
    positions are its antenna's (the reference point), not the marker's below it, which is not solved for (RTKLIB
    applies no rover delta from the header either).  ``what`` names the file."""
    d = header.get("antenna_delta_hen_m")
    if d is None or not any(float(v) != 0.0 for v in d):
        return []
    return [f"{what}: its header's ANTENNA: DELTA H/E/N ({' '.join(f'{float(v):g}' for v in d)} m) is not applied: "
            f"the positions are of its antenna reference point, not of the marker that far below it"]


def day_of_year(t_gps_s) -> np.ndarray:
    """Fractional day of year of GPS times (1.0 at January 1, 00:00), as RTKLIB's ``time2doy``.

    Parameters
    ----------
    t_gps_s : float or array_like
        GPS seconds since 1980-01-06.

    Returns
    -------
    ndarray
        Day of year, days (leap seconds ignored: the NMF seasonal term varies over months).
    """
    t = np.asarray(t_gps_s, dtype=np.float64)
    flat = t.ravel()
    out = np.empty_like(flat)
    # one calendar conversion per distinct day (times of one file span a day or two)
    days = np.floor(flat / 86400.0)
    for d in np.unique(days):
        date = GPS_EPOCH + dt.timedelta(days=float(d))
        jan1 = dt.datetime(date.year, 1, 1)
        start_s = (jan1 - GPS_EPOCH).total_seconds()
        sel = days == d
        out[sel] = (flat[sel] - start_s) / 86400.0 + 1.0
    return out.reshape(t.shape)


def tropo_zenith_hydrostatic_m(lat_rad, h_m) -> np.ndarray:
    """Saastamoinen zenith hydrostatic delay with the standard atmosphere, m.

    Pressure ``P = 1013.25·(1 − 2.2557e-5·h)^5.2568`` hPa (h clipped at 0) and
    ``ZHD = 0.0022768·P / (1 − 0.00266·cos 2φ − 0.00028·h/km)`` (Saastamoinen 1972; the form of
    RTKLIB's ``tropmodel`` with zero humidity).  Heights outside −100 m … 10 km give 0.

    Parameters
    ----------
    lat_rad : float or array_like
        Geodetic latitude, rad.
    h_m : float or array_like
        Ellipsoidal height, m.

    Returns
    -------
    ndarray
        Zenith hydrostatic delay, m (about 2.3 m at sea level).
    """
    lat = np.asarray(lat_rad, dtype=np.float64)
    h = np.asarray(h_m, dtype=np.float64)
    hc = np.clip(h, 0.0, 1e4)  # beyond 10 km the result is 0 anyway; no NaN from a negative base
    pres = 1013.25 * np.power(1.0 - 2.2557e-5 * hc, 5.2568)
    zhd = 0.0022768 * pres / (1.0 - 0.00266 * np.cos(2.0 * lat) - 0.00028 * hc / 1e3)
    return np.where((h < -100.0) | (h > 1e4), 0.0, zhd)


# Niell (1996), Table 3: hydrostatic a, b, c (average and amplitude) at latitudes 15, 30, 45, 60, 75°
_NMF_AVG = np.array([
    [1.2769934e-3, 1.2683230e-3, 1.2465397e-3, 1.2196049e-3, 1.2045996e-3],
    [2.9153695e-3, 2.9152299e-3, 2.9288445e-3, 2.9022565e-3, 2.9024912e-3],
    [62.610505e-3, 62.837393e-3, 63.721774e-3, 63.824265e-3, 64.258455e-3],
])
_NMF_AMP = np.array([
    [0.0, 1.2709626e-5, 2.6523662e-5, 3.4000452e-5, 4.1202191e-5],
    [0.0, 2.1414979e-5, 3.0160779e-5, 7.2562722e-5, 11.723375e-5],
    [0.0, 9.0128400e-5, 4.3497037e-5, 84.795348e-5, 170.37206e-5],
])
_NMF_HEIGHT = (2.53e-5, 5.49e-3, 1.14e-3)


def _marini(sin_el, a, b, c):
    """Marini continued fraction normalised to 1 at zenith."""
    return (1.0 + a / (1.0 + b / (1.0 + c))) / (sin_el + a / (sin_el + b / (sin_el + c)))


def niell_hydrostatic_mapping(el_rad, lat_rad, h_m, doy) -> np.ndarray:
    """Niell (1996) hydrostatic mapping function with its height correction.

    Parameters
    ----------
    el_rad : array_like
        Elevation, rad (≤ 0 gives 0).
    lat_rad : float or array_like
        Geodetic latitude, rad (the seasonal phase is shifted by half a year in the south).
    h_m : float or array_like
        Ellipsoidal height, m (used for the height correction, as RTKLIB does).
    doy : float or array_like
        Fractional day of year (:func:`day_of_year`).

    Returns
    -------
    ndarray
        Hydrostatic mapping factor (1 at zenith, about 3.8 at 15° elevation).
    """
    el = np.asarray(el_rad, dtype=np.float64)
    lat_deg = np.degrees(np.asarray(lat_rad, dtype=np.float64))
    h = np.asarray(h_m, dtype=np.float64)
    doy = np.asarray(doy, dtype=np.float64)
    alat = np.abs(lat_deg)
    grid = np.array([15.0, 30.0, 45.0, 60.0, 75.0])
    if lat_deg.ndim == 0 and h.ndim == 0 and doy.shape == el.shape and el.size and kernel_available():
        # one receiver: one pass in C, the same operations (tested equal)
        p = [np.interp(alat, grid, t[k]) for t in (_NMF_AVG, _NMF_AMP) for k in range(3)]
        out = np.empty(el.shape)
        _orbitcore.niell(np.ascontiguousarray(el), np.ascontiguousarray(doy),
                         np.array([*p, np.where(lat_deg < 0.0, 0.5, 0.0), h, *_NMF_HEIGHT], dtype=np.float64), out)
        return out
    y = (doy - 28.0) / 365.25 + np.where(lat_deg < 0.0, 0.5, 0.0)
    cosy = np.cos(2.0 * np.pi * y)
    coef = [np.interp(alat, grid, _NMF_AVG[k]) - np.interp(alat, grid, _NMF_AMP[k]) * cosy for k in range(3)]
    sin_el = np.sin(np.maximum(el, 1e-6))
    m = _marini(sin_el, *coef)
    dm = (1.0 / sin_el - _marini(sin_el, *_NMF_HEIGHT)) * h / 1e3
    return np.where(el > 0.0, m + dm, 0.0)


# Niell (1996), Table 4: wet a, b, c at latitudes 15, 30, 45, 60, 75° (no seasonal term, no height correction)
_NMF_WET = np.array([
    [5.8021897e-4, 5.6794847e-4, 5.8118019e-4, 5.9727542e-4, 6.1641693e-4],
    [1.4275268e-3, 1.5138625e-3, 1.4572752e-3, 1.5007428e-3, 1.7599082e-3],
    [4.3472961e-2, 4.6729510e-2, 4.3908931e-2, 4.4626982e-2, 5.4736038e-2],
])


def niell_wet_mapping(el_rad, lat_rad) -> np.ndarray:
    """Niell (1996) wet mapping function: the slant wet delay is this factor times the zenith wet delay.

    The three coefficients of the Marini continued fraction are interpolated linearly in |latitude| between
    the table's rows (15–75°; constant beyond them), as RTKLIB's ``nmf``; the wet function has neither a
    seasonal term nor a height correction.

    Parameters
    ----------
    el_rad : array_like
        Elevation, rad (≤ 0 gives 0).
    lat_rad : float or array_like
        Geodetic latitude, rad.

    Returns
    -------
    ndarray
        Wet mapping factor (1 at zenith, about 3.8 at 15° elevation, close to 1/sin(el) above 30°).

    References
    ----------
    A. E. Niell, "Global mapping functions for the atmosphere delay at radio wavelengths", J. Geophys.
    Res. 101(B2), 3227–3246, 1996 (Table 4).
    """
    el = np.asarray(el_rad, dtype=np.float64)
    alat = np.abs(np.degrees(np.asarray(lat_rad, dtype=np.float64)))
    grid = np.array([15.0, 30.0, 45.0, 60.0, 75.0])
    coef = [np.interp(alat, grid, _NMF_WET[k]) for k in range(3)]
    m = _marini(np.sin(np.maximum(el, 1e-6)), *coef)
    return np.where(el > 0.0, m, 0.0)


def tropo_hydrostatic_m(el_rad, lat_rad, h_m, t_gps_s) -> np.ndarray:
    """Slant hydrostatic troposphere delay: Saastamoinen zenith delay × Niell mapping, m.

    Parameters
    ----------
    el_rad : array_like
        Elevation, rad.
    lat_rad, h_m : float or array_like
        Receiver geodetic latitude (rad) and ellipsoidal height (m).
    t_gps_s : float or array_like
        Time, GPS seconds (for the seasonal term of the mapping function).

    Returns
    -------
    ndarray
        Slant delay, m (0 for elevations ≤ 0).
    """
    return tropo_zenith_hydrostatic_m(lat_rad, h_m) * niell_hydrostatic_mapping(el_rad, lat_rad, h_m, day_of_year(t_gps_s))


# ----------------------------------------------------------------------------------------------
# ephemeris coverage, receiver clock, single-point position
# ----------------------------------------------------------------------------------------------


def ephemeris_coverage(nav: pd.DataFrame, sats, t_gps_s, *, max_age_s: float | None = None) -> np.ndarray:
    """Which (satellite, time) pairs have a healthy broadcast ephemeris within ``max_age_s`` of toe.

    Parameters
    ----------
    nav : DataFrame
        Ephemerides (:func:`~cdgps_cli.io.rinex.read_rinex_nav`).
    sats : array_like of str, shape (N,)
        Satellite of each row ("G05").
    t_gps_s : array_like, shape (N,)
        Time of each row, GPS s.
    max_age_s : float, optional
        Largest accepted |t − toe|, s (the rule of :func:`~cdgps_cli.model.gps.orbits.select_ephemeris`;
        default per system: 7200, GLONASS 1800).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    return ephemeris_coverage_all(nav, sats, (t_gps_s,), max_age_s=max_age_s)


def ephemeris_coverage_all(nav: pd.DataFrame, sats, times, *, max_age_s: float | None = None) -> np.ndarray:
    """:func:`ephemeris_coverage` of the same rows at each of several time arrays, all required (their AND),
    with the ephemerides sorted and the rows grouped by satellite once.

    Parameters
    ----------
    nav, sats, max_age_s
        As for :func:`ephemeris_coverage`.
    times : sequence of array_like, each shape (N,)
        Times of each row, GPS s.

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    sats = np.asarray(sats, dtype=object)
    ts = [np.asarray(t, dtype=np.float64) for t in times]
    ok = np.zeros(ts[0].shape, dtype=bool)
    # each satellite's sorted healthy toes (as a groupby("sat") over nav's healthy rows gives them; only the
    # two columns taken, not a filtered copy of the whole table)
    healthy = healthy_ephemeris(nav["sat"].to_numpy(), nav["sv_health"].to_numpy())
    codes, names = pd.factorize(nav["sat"].to_numpy()[healthy], sort=True)
    toe_all = nav["toe_gps_s"].to_numpy()[healthy]
    toes = {s: np.sort(toe_all[codes == i]) for i, s in enumerate(names)}
    for s, sel in _groups(sats):
        toe = toes.get(s)
        if toe is None or toe.size == 0:
            continue
        age = max_age_s if max_age_s is not None else (MAX_EPHEMERIS_AGE_GLONASS_S if str(s).startswith("R") else MAX_EPHEMERIS_AGE_S)
        hit = None
        for t in ts:
            k = np.searchsorted(toe, t[sel])
            before = toe[np.clip(k - 1, 0, toe.size - 1)]
            after = toe[np.clip(k, 0, toe.size - 1)]
            h = np.minimum(np.abs(t[sel] - before), np.abs(t[sel] - after)) <= age
            hit = h if hit is None else hit & h
        ok[sel] = hit
    return ok


def _groups(sats) -> list:
    """(satellite, row indices) for each distinct satellite, sorted by name; rows keep their order.
    One hash pass and one sort instead of a string comparison over all rows per satellite."""
    codes, names = pd.factorize(np.asarray(sats, dtype=object), sort=True)
    order = np.argsort(codes, kind="stable")
    counts = np.bincount(codes[codes >= 0], minlength=len(names))
    cuts = np.r_[0, np.cumsum(counts)]
    return [(names[i], order[cuts[i]:cuts[i + 1]]) for i in range(len(names))]


def _rows_geometry(nav, sats, t_label, t_true, rx_ecef, *, troposphere: bool, ephemeris=None, azimuth: bool = True):
    """Satellite geometry for rows: returns xyz (N,3), clock (N,), range (N,), az, el, trop (N,).
    ``ephemeris``: :func:`~cdgps_cli.model.gps.orbits.reception_ephemeris` of (sats, t_label), if the
    caller has it (each satellite's rows are exactly a :func:`sat_position_at_reception` call's).
    ``azimuth`` False: az is None (callers that use the elevation only; el is the same)."""
    n = t_label.size
    rx = np.asarray(rx_ecef, dtype=np.float64)
    g = sat_positions_at_reception(nav, sats, t_label, rx, rx_clock_s=t_label - t_true, ephemeris=ephemeris)
    xyz, clk, rng = g.xyz_m, g.clock_s, g.range_m
    az, el = azimuth_elevation(rx, xyz) if azimuth else (None, elevation(rx, xyz))
    if troposphere:
        lat, _, h = ecef_to_geodetic(rx)
        trop = tropo_hydrostatic_m(el, lat, h, t_true)
    else:
        trop = np.zeros(n)
    return xyz, clk, rng, az, el, trop


def estimate_receiver_clock(
    epoch_index,
    sats,
    t_tag_s,
    pseudorange_m,
    nav: pd.DataFrame,
    rx_ecef_m,
    *,
    n_epochs: int | None = None,
    mask_rad: float = math.radians(10.0),
    troposphere: bool = True,
    iterations: int = 3,
    what: str = "receiver",
    return_measured: bool = False,
) -> np.ndarray:
    """Receiver clock offset per epoch from L1 pseudoranges at a known receiver position.

    The clock is the median over the satellites above ``mask_rad`` of
    ``P − (ρ − c·dt_sat + T)`` / c, iterated so that ρ is computed at the true reception time
    ``t_tag − dt_rx`` (a 5 ms clock error moves a satellite by up to 4 m).  Epochs without a
    usable pseudorange take the clock interpolated linearly in time from their neighbours.

    The orbits are evaluated once, at the time tags; the later passes move ``ρ − c·dt_sat`` to
    ``t_tag − dt_rx`` to first order, with its rate from each satellite's neighbouring rows
    (:func:`_rate_along_satellites`): the term left out, ρ̈·dt_rx²/2, is below 3 µm for
    |dt_rx| ≤ 5 ms, and a one-sided rate over a gap of Δt adds ≈ ρ̈·Δt·dt_rx/2 (1 cm for
    Δt = 30 s), so the clock is the full passes' to 10⁻¹¹ s at 1–4 Hz and 10⁻¹⁰ s at 30 s steps (tested;
    10⁻¹⁰ s moves a satellite by 0.1 µm) at a third of their cost.

    Parameters
    ----------
    epoch_index : array_like of int, shape (N,)
        Epoch of each row, 0 … n_epochs−1.
    sats : array_like of str, shape (N,)
        Satellite of each row.
    t_tag_s : array_like, shape (N,)
        Receiver time tag of each row, GPS s.
    pseudorange_m : array_like, shape (N,)
        L1 pseudorange, m (NaN if absent).
    nav : DataFrame
        Broadcast ephemerides; rows must be covered (:func:`ephemeris_coverage`).
    rx_ecef_m : array_like, shape (3,)
        Receiver position, ECEF m (metre-level is enough: 1 km of error gives < 4 µs).
    n_epochs : int, optional
        Number of epochs (default ``max(epoch_index) + 1``).
    mask_rad : float
        Elevation cutoff for the clock estimate, rad.
    troposphere : bool
        Subtract the a priori hydrostatic troposphere.
    iterations : int
        Passes (≥ 2 needed for the reception-time effect).
    what : str
        Name used in error messages.
    return_measured : bool
        Also return which epochs had a usable pseudorange (the others' clock is interpolated).

    Returns
    -------
    ndarray, shape (n_epochs,)
        Receiver clock offset dt_rx (time tag − GPS time), s; with ``return_measured`` (that, a bool
        (n_epochs,) array).

    Raises
    ------
    CdgpsError
        If no epoch has a usable pseudorange.
    """
    ep = np.asarray(epoch_index, dtype=np.int64)
    sats = np.asarray(sats, dtype=object)
    t = np.asarray(t_tag_s, dtype=np.float64)
    pr = np.asarray(pseudorange_m, dtype=np.float64)
    ne = int(ep.max()) + 1 if n_epochs is None else int(n_epochs)
    have = np.isfinite(pr)
    if not have.any():
        raise CdgpsError(f"{what}: no L1 pseudoranges; they are needed to find the receiver clock offset "
                         f"(true reception time) of each epoch")
    clk = np.zeros(ne)
    idx = np.flatnonzero(have)
    ep_t = np.full(ne, np.nan)
    ep_t[ep] = t
    _, dts, rng, _, el, trop = _rows_geometry(nav, sats[idx], t[idx], t[idx], rx_ecef_m, troposphere=troposphere,
                                              azimuth=False)
    model = rng - SPEED_OF_LIGHT_M_S * dts + trop               # at the time tags (dt_rx = 0)
    rate = _rate_along_satellites(sats[idx], t[idx], rng - SPEED_OF_LIGHT_M_S * dts)
    use = el > mask_rad
    if not use.any():
        use = el > 0.0
    for _ in range(max(1, iterations)):
        res = (pr[idx] - (model - rate * clk[ep[idx]])) / SPEED_OF_LIGHT_M_S
        df = pd.DataFrame({"ep": ep[idx][use], "r": res[use]})
        med = df.groupby("ep")["r"].median()
        new = np.full(ne, np.nan)
        new[med.index.to_numpy()] = med.to_numpy()
        good = np.isfinite(new)
        if not good.any():
            raise CdgpsError(f"{what}: no pseudorange from a satellite above the horizon; cannot find the receiver clock")
        if not good.all():
            tt = np.where(np.isfinite(ep_t), ep_t, np.interp(np.arange(ne), np.flatnonzero(np.isfinite(ep_t)),
                                                              ep_t[np.isfinite(ep_t)]))
            new[~good] = np.interp(tt[~good], tt[good], new[good])
        clk = new
    return (clk, good) if return_measured else clk


def _rate_along_satellites(sats: np.ndarray, t_s: np.ndarray, value: np.ndarray) -> np.ndarray:
    """d(value)/dt per row from the rows of the same satellite before and after it in time: the mean of the
    backward and forward slopes where both exist, the one that exists at an end, 0 for a satellite's only row
    (rows at one time of one satellite count as one)."""
    codes = pd.factorize(sats)[0]
    order = np.lexsort((t_s, codes))
    c, t, v = codes[order], t_s[order], value[order]
    dt = np.diff(t)
    ok = (c[1:] == c[:-1]) & (dt > 0)
    slope = np.where(ok, np.diff(v) / np.where(ok, dt, 1.0), 0.0)
    back = np.r_[0.0, slope]
    fwd = np.r_[slope, 0.0]
    nb, nf = np.r_[False, ok], np.r_[ok, False]
    both = nb & nf
    rate = np.where(both, 0.5 * (back + fwd), back + fwd)
    out = np.empty_like(rate)
    out[order] = rate
    return out


def epochs_spread(n_epochs: int, max_epochs: int | None) -> np.ndarray:
    """(n_epochs,) bool: ``max_epochs`` epochs spread evenly over ``n_epochs`` (the first and the last among them; all
    when ``max_epochs`` is None or not fewer), for a single-point position that checks a header's."""
    keep = np.zeros(n_epochs, dtype=bool)
    if max_epochs is None or n_epochs <= max_epochs:
        keep[:] = True
    else:
        keep[np.linspace(0, n_epochs - 1, max_epochs).round().astype(np.int64)] = True
    return keep


def spp_spread(sats, t_tag_s, pseudorange_m, nav: pd.DataFrame, *, x0_ecef_m=None, max_epochs: int | None = None,
               what: str = "receiver") -> np.ndarray | None:
    """A receiver's static single-point position (ECEF m, :func:`spp_static`) from its pseudoranges (rows of
    ``sats``, ``t_tag_s``, ``pseudorange_m``) that ``nav`` covers (:func:`ephemeris_coverage`), from ``max_epochs`` of
    those epochs spread over the record (:func:`epochs_spread`; None: all), started at ``x0_ecef_m``; None when no
    finite pseudorange is covered.  The one function behind the header checks and the a-priori positions of
    ``rtk``, ``init`` / ``estimate`` and ``config``."""
    sats = np.asarray(sats, dtype=object)
    t = np.asarray(t_tag_s, dtype=np.float64)
    pr = np.asarray(pseudorange_m, dtype=np.float64)
    ok = np.isfinite(pr)
    ok[ok] = ephemeris_coverage(nav, sats[ok], t[ok])
    sats, t, pr = sats[ok], t[ok], pr[ok]
    if not t.size:
        return None
    tags, ep = np.unique(t, return_inverse=True)
    keep = epochs_spread(tags.size, max_epochs)[ep]
    _, ep = np.unique(ep[keep], return_inverse=True)
    x, _ = spp_static(ep, sats[keep], t[keep], pr[keep], nav, x0_ecef_m=x0_ecef_m, what=what)
    return np.asarray(x, dtype=np.float64)


def spp_static(
    epoch_index,
    sats,
    t_tag_s,
    pseudorange_m,
    nav: pd.DataFrame,
    *,
    x0_ecef_m=None,
    mask_rad: float = math.radians(10.0),
    max_iterations: int = 12,
    what: str = "receiver",
) -> tuple[np.ndarray, np.ndarray]:
    """Static single-point position from L1 pseudoranges: one position, one clock per epoch.

    Gauss-Newton on ``P = |x_sat − x| + c·dt_rx(epoch) − c·dt_sat + T``; the clocks are eliminated
    epoch by epoch (each epoch's residuals are centred), so the cost is linear in the epochs.

    Parameters
    ----------
    epoch_index, sats, t_tag_s, pseudorange_m
        As in :func:`estimate_receiver_clock`.
    nav : DataFrame
        Broadcast ephemerides.
    x0_ecef_m : array_like, shape (3,), optional
        Starting position (default: the Earth's centre).
    mask_rad : float
        Elevation cutoff once the position is known to 10 km, rad.
    max_iterations : int
        Iteration cap.
    what : str
        Name used in error messages.

    Returns
    -------
    x_ecef_m : ndarray, shape (3,)
        Position, ECEF m (a few metres: no ionosphere model).
    clock_s : ndarray, shape (n_epochs,)
        Receiver clock per epoch, s.

    Raises
    ------
    CdgpsError
        Too few pseudoranges, or no convergence.
    """
    ep = np.asarray(epoch_index, dtype=np.int64)
    sats = np.asarray(sats, dtype=object)
    t = np.asarray(t_tag_s, dtype=np.float64)
    pr = np.asarray(pseudorange_m, dtype=np.float64)
    have = np.isfinite(pr)
    if have.sum() < 6:
        raise CdgpsError(f"{what}: too few L1 pseudoranges ({int(have.sum())}) for a single-point position")
    ep, sats, t, pr = ep[have], sats[have], t[have], pr[have]
    ne = int(ep.max()) + 1
    x = np.zeros(3) if x0_ecef_m is None else np.asarray(x0_ecef_m, dtype=np.float64).copy()
    clk = np.zeros(ne)
    for it in range(max_iterations):
        near = np.linalg.norm(x) > 6.3e6
        xyz, dts, rng, _, el, trop = _rows_geometry(nav, sats, t, t - clk[ep], x, troposphere=near, azimuth=False)
        use = (el > mask_rad) if near and np.linalg.norm(x) < 6.5e6 else np.ones(el.size, dtype=bool)
        res = pr - (rng - SPEED_OF_LIGHT_M_S * dts + trop)
        g = -(xyz - x) / rng[:, None]
        w = use.astype(float)
        cnt = np.bincount(ep, weights=w, minlength=ne)
        ok_ep = cnt >= 4
        w = w * ok_ep[ep]
        cnt = np.bincount(ep, weights=w, minlength=ne)
        safe = np.maximum(cnt, 1.0)
        rbar = np.bincount(ep, weights=w * res, minlength=ne) / safe
        gbar = np.stack([np.bincount(ep, weights=w * g[:, k], minlength=ne) / safe for k in range(3)], axis=1)
        gc = g - gbar[ep]
        rc = res - rbar[ep]
        nmat = (gc * w[:, None]).T @ gc
        if np.linalg.cond(nmat) > 1e12:
            raise CdgpsError(f"{what}: single-point position is not solvable (fewer than 4 satellites per epoch)")
        dx = np.linalg.solve(nmat, (gc * w[:, None]).T @ rc)
        x = x + dx
        clk = (rbar - gbar @ dx) / SPEED_OF_LIGHT_M_S
        clk[~ok_ep] = np.nan
        if np.isnan(clk).any():
            good = np.isfinite(clk)
            if not good.any():
                raise CdgpsError(f"{what}: no epoch with 4 satellites for a single-point position")
            clk[~good] = np.interp(np.flatnonzero(~good), np.flatnonzero(good), clk[good])
        if np.linalg.norm(dx) < 1e-3 and it >= 2:
            return x, clk
    raise CdgpsError(f"{what}: single-point position did not converge in {max_iterations} iterations")


# ----------------------------------------------------------------------------------------------
# epochs
# ----------------------------------------------------------------------------------------------


def match_epochs(t_a_s, t_b_s, *, tol_s: float = 0.025) -> tuple[np.ndarray, np.ndarray]:
    """Pair the epochs of two receivers whose time tags differ by at most ``tol_s``.

    Each epoch of ``a`` is paired with the nearest epoch of ``b``; pairs farther apart than
    ``tol_s`` are dropped, and each epoch of ``b`` is used at most once (the nearest wins).

    Parameters
    ----------
    t_a_s, t_b_s : array_like
        Distinct, increasing epoch time tags of receivers a and b, GPS s.
    tol_s : float
        Largest tag difference accepted, s (RTKLIB's DTTOL is 0.025 s).

    Returns
    -------
    ia, ib : ndarray of int
        Indices into ``t_a_s`` and ``t_b_s`` of the matched epochs, increasing.
    """
    ta = np.asarray(t_a_s, dtype=np.float64)
    tb = np.asarray(t_b_s, dtype=np.float64)
    if ta.size == 0 or tb.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    k = np.clip(np.searchsorted(tb, ta), 1, max(tb.size - 1, 1))
    if tb.size == 1:
        k = np.zeros(ta.size, dtype=np.int64)
        near = k
    else:
        left, right = k - 1, k
        near = np.where(np.abs(ta - tb[left]) <= np.abs(ta - tb[right]), left, right)
    d = np.abs(ta - tb[near])
    ok = d <= tol_s
    ia = np.flatnonzero(ok)
    ib = near[ok]
    # one a per b: keep the nearest
    order = np.lexsort((d[ia], ib))
    ia, ib = ia[order], ib[order]
    first = np.ones(ib.size, dtype=bool)
    first[1:] = ib[1:] != ib[:-1]
    ia, ib = ia[first], ib[first]
    srt = np.argsort(ia)
    return ia[srt].astype(np.int64), ib[srt].astype(np.int64)


# ----------------------------------------------------------------------------------------------
# reception geometry
# ----------------------------------------------------------------------------------------------


def reception_geometry(nav: pd.DataFrame, sats, t_label_s, t_true_s, rx_ecef_m, *, troposphere: bool = True,
                       ephemeris=None) -> dict:
    """Satellite geometry for observation rows of one receiver at their true reception times.

    Parameters
    ----------
    nav : DataFrame
        Broadcast ephemerides.
    sats : array_like of str, shape (N,)
        Satellite of each row.
    t_label_s : array_like, shape (N,)
        Nominal epoch time shared by the receivers, GPS s: it selects the ephemeris, so both
        receivers of a double difference use the same one even when their tags straddle a switch.
    t_true_s : array_like, shape (N,)
        True (GPS-time) reception instant of each row: time tag − receiver clock, s.
    rx_ecef_m : array_like, shape (3,) or (N, 3)
        Receiver position, ECEF m.
    troposphere : bool
        Compute the hydrostatic troposphere (else zeros).
    ephemeris : ReceptionEphemeris, optional
        :func:`~cdgps_cli.model.gps.orbits.reception_ephemeris` of (``sats``, ``t_label_s``), for a caller
        that evaluates the same rows for two receivers (both receivers of a pair share ``sats`` and
        ``t_label_s``): selected here when absent; the result is the same either way.

    Returns
    -------
    dict
        ``sat_xyz_m`` (N, 3) satellite position at transmission in the ECEF frame of reception;
        ``sat_clock_s`` (N,); ``range_m`` (N,) geometric range; ``az_rad``, ``el_rad`` (N,);
        ``trop_m`` (N,) slant hydrostatic delay.
    """
    sats = np.asarray(sats, dtype=object)
    tl = np.asarray(t_label_s, dtype=np.float64)
    tt = np.asarray(t_true_s, dtype=np.float64)
    xyz, clk, rng, az, el, trop = _rows_geometry(nav, sats, tl, tt, rx_ecef_m, troposphere=troposphere,
                                                 ephemeris=ephemeris)
    return {"sat_xyz_m": xyz, "sat_clock_s": clk, "range_m": rng, "az_rad": az, "el_rad": el, "trop_m": trop}


# ----------------------------------------------------------------------------------------------
# simulation of two static receivers
# ----------------------------------------------------------------------------------------------


def simulate_static_pair(
    nav: pd.DataFrame,
    base_ecef_m,
    rover_ecef_m,
    t_start_s: float,
    duration_s: float,
    interval_s: float,
    *,
    sats=None,
    mask_rad: float = math.radians(5.0),
    phase_sigma_m: float | tuple = 0.002,
    code_sigma_m: float | tuple = 0.5,
    clock_drift_ms: tuple[float, float] = (-4.0, 5.0),
    slips: tuple = (),
    seed: int = 0,
    troposphere: bool = True,
    rover_offset_enu_m=None,
    random_slips: int = 0,
    slip_mask_rad: float | None = None,
    slip_min_epochs: int = 10,
    clock_offset_ms: tuple[float, float] = (0.0, 0.0),
    tag_resolution_s: float | None = 1e-3,
    base_every: int = 1,
) -> dict:
    """Synthesize L1 observations of a static base and rover from broadcast ephemerides.

    Each receiver's clock offset dt drifts linearly from ``clock_offset_ms`` by ``clock_drift_ms``
    over the span; its time tags are the nominal epochs plus dt rounded to ``tag_resolution_s``
    (1 ms, as the GEONET receivers write them; unrounded for u-blox-like tags), and the
    measurement instant is ``tag − dt``.  For each satellite above ``mask_rad`` at
    both receivers and covered by a healthy ephemeris:
    ``P = ρ + c·(dt − dt_sat) + T + ε_P`` and ``L = (ρ + c·(dt − dt_sat) + T + ε_L)/λ + N + f``,
    with ρ, dt_sat at the measurement instant, N an integer per satellite and lock segment (a new
    one after each gap in visibility) and f a fractional phase bias common to the receiver.
    ε_L, ε_P are white, either with one σ or with the elevation model σ² = a² + b²/sin²el of each
    receiver's own elevation (the estimator's default weighting, RTKLIB's).  Each record also
    carries a C/N0 of :data:`CN0_MODEL` ``35 + 15·sin el`` dB-Hz (noise-free, so deterministic); the
    RINEX writer turns it into the signal-strength digit.

    Parameters
    ----------
    nav : DataFrame
        Broadcast ephemerides (they define the truth and are reused by the solver).
    base_ecef_m, rover_ecef_m : array_like, shape (3,)
        True antenna positions, ECEF m.
    t_start_s, duration_s, interval_s : float
        Nominal epochs ``t_start + k·interval`` for ``0 ≤ k·interval < duration``, GPS s.
    sats : list of str, optional
        Satellites to simulate (default: all in ``nav``).
    mask_rad : float
        Simulated tracking mask at both receivers, rad.
    phase_sigma_m, code_sigma_m : float or (float, float)
        White noise of undifferenced phase and code, m: a number σ (the same at all elevations) or
        a pair (a, b) for σ² = a² + b²/sin²el (el of that receiver and satellite).
    clock_drift_ms : (float, float)
        Base and rover clock offset at the end of the span minus that at its start, ms.
    clock_offset_ms : (float, float)
        Base and rover clock offset at the start of the span, ms (default 0).
    tag_resolution_s : float or None
        Time tags are the nominal epochs plus the clock offset rounded to this, s (default 1 ms,
        as GEONET receivers write them: measurement instants within 0.5 ms of the nominal
        epochs); None: not rounded — the receiver measures at the nominal GPS epochs and stamps
        them with its own clock (tags off whole seconds by the offset, as u-blox receivers do).
    base_every : int
        Keep the base's records of every ``base_every``-th nominal epoch only (a base at a lower
        rate than the rover); a slip flag of a dropped record moves to the satellite's next kept one.
    slips : sequence of (receiver, sat, t_gps_s, cycles)
        Cycle slips (receiver ``"base"`` or ``"rover"``): from the first record at or after
        nominal time ``t_gps_s`` to the end of its lock segment, the phase is shifted by
        ``cycles``; that first record carries LLI = 1.
    random_slips : int
        Further slips drawn at random (own generator from ``seed``, so the noise does not change)
        among the records that are tracked at both receivers above ``slip_mask_rad`` (default
        ``mask_rad``) with at least ``slip_min_epochs`` consecutive such epochs before and after
        the slip in the same arc, inside 5–95 % of the span, and at least ``slip_min_epochs``
        epochs from any other random slip of the satellite; receiver and record uniform among
        those, size a non-zero integer in [−50, 49].  Fewer when there are not enough such
        records (the returned ``slips`` say how many were made).
    seed : int
        Random seed.
    troposphere : bool
        Add the hydrostatic troposphere model to both receivers' observables.
    rover_offset_enu_m : array_like, shape (n_epochs, 3), optional
        A moving rover: its antenna at nominal epoch k is ``rover_ecef_m`` plus this east/north/up
        offset (m, in the local frame at ``rover_ecef_m``); default static.

    Returns
    -------
    dict
        ``base``, ``rover``: DataFrames with :data:`~cdgps_cli.io.rinex.OBS_COLUMNS`;
        ``base_header``, ``rover_header``: dicts with ``approx_position_xyz_m``, ``interval_s``,
        ``marker_name``, ``path``; ``ambiguities``: DataFrame (receiver, sat, t_from_s, n_cycles)
        of the integer part of each lock segment and of each slip; ``frac_bias_cycles``:
        {receiver: f}; ``clock_s``: {receiver: dt per nominal epoch}; ``slips``: list of dicts
        (``receiver``, ``sat``, ``time_gps_s`` nominal epoch of the flagged record, ``cycles``,
        ``elevation_deg`` there, ``random``) of the slips applied, explicit ones first.
    """
    gen = np.random.default_rng(seed)
    n_ep = int(math.floor(duration_s / interval_s - 1e-9)) + 1
    t_nom = t_start_s + np.arange(n_ep) * interval_s
    if sats is None:
        sats = sorted(nav["sat"].unique().tolist())
    stations = {"base": np.asarray(base_ecef_m, float), "rover": np.asarray(rover_ecef_m, float)}
    track = {}
    if rover_offset_enu_m is not None:
        off = np.asarray(rover_offset_enu_m, dtype=np.float64)
        if off.shape != (n_ep, 3):
            raise ValueError(f"rover_offset_enu_m must have shape ({n_ep}, 3), got {off.shape}")
        lat_r, lon_r, _ = ecef_to_geodetic(stations["rover"])
        track["rover"] = stations["rover"] + off @ enu_matrix(lat_r, lon_r)
    clock, tag, t_true = _receiver_clocks(stations, t_nom, t_start_s, duration_s, clock_drift_ms, clock_offset_ms,
                                          tag_resolution_s)
    per_sat = _visible_geometry(nav, sats, stations, track, t_nom, t_true, mask_rad)
    drawn = _draw_random_slips(per_sat, t_nom, int(random_slips), mask_rad if slip_mask_rad is None else slip_mask_rad,
                               max(int(slip_min_epochs), 1), np.random.default_rng(seed + 104_729))
    slips = [(*sl, False) for sl in slips] + [(*sl, True) for sl in drawn]
    applied = []
    frames = {}
    amb_rows = []
    fracs = {}
    for name, x in stations.items():
        frac = float(gen.uniform(-0.5, 0.5))
        fracs[name] = frac
        # the troposphere where the receiver is at each epoch (a rover that climbs: ≈ 0.3 mm per metre of height)
        lat, _, h = ecef_to_geodetic(track[name]) if name in track else ecef_to_geodetic(x)
        recs = []
        for s, idx_all, vis, geo in per_sat:
            idx = idx_all[vis]
            rho, dts, el = (a[vis] for a in geo[name])
            tt = t_true[name][idx]
            at = (lat[idx], h[idx]) if name in track else (lat, h)
            trop = tropo_hydrostatic_m(el, *at, tt) if troposphere else np.zeros(idx.size)
            seg_start = np.concatenate([[True], np.diff(idx) > 1])
            seg_id = np.cumsum(seg_start) - 1
            n_int = gen.integers(-2_000_000, 2_000_000, size=int(seg_id.max()) + 1)
            amb = n_int[seg_id].astype(np.float64)
            for j in np.flatnonzero(seg_start):
                amb_rows.append((name, s, "lock", float(t_nom[idx[j]]), int(n_int[seg_id[j]])))
            amb, lli = _apply_slips(name, s, t_nom[idx], seg_id, el, amb, slips, amb_rows, applied)
            common = rho + SPEED_OF_LIGHT_M_S * (clock[name][idx] - dts) + trop
            recs.append(pd.DataFrame({
                "time_gps_s": tag[name][idx],
                "sat": s,
                "phase_l1_cycles": (common + gen.normal(0.0, _noise_sigma(phase_sigma_m, el), idx.size)) / GPS_L1_WAVELENGTH_M
                + amb + frac,
                "lli_l1": lli,
                "ssi_l1": np.zeros(idx.size, dtype=np.int64),
                "pseudorange_l1_m": common + gen.normal(0.0, _noise_sigma(code_sigma_m, el), idx.size),
                "snr_l1_dbhz": CN0_MODEL[0] + CN0_MODEL[1] * np.sin(el),
                "rx_clock_offset_s": np.nan,
                "epoch_flag": np.zeros(idx.size, dtype=np.int64),
                "_k": idx,
            }))
        df = pd.concat(recs, ignore_index=True) if recs else pd.DataFrame(columns=[*OBS_COLUMNS, "_k"])
        if name == "base" and base_every > 1:
            df = _decimate(df, int(base_every))
        frames[name] = df.sort_values(["time_gps_s", "sat"], kind="stable").reset_index(drop=True)[list(OBS_COLUMNS)]
    headers = {
        name: {"approx_position_xyz_m": tuple(float(v) for v in stations[name]), "interval_s": float(interval_s),
               "marker_name": name.upper(), "path": f"<simulated {name}>"}
        for name in stations
    }
    return {
        "base": frames["base"], "rover": frames["rover"],
        "base_header": headers["base"], "rover_header": headers["rover"],
        "ambiguities": pd.DataFrame(amb_rows, columns=["receiver", "sat", "kind", "t_from_s", "n_cycles"]),
        "frac_bias_cycles": fracs,
        "clock_s": clock,
        "slips": sorted(applied, key=lambda d: d["random"]),
    }


def _receiver_clocks(stations: dict, t_nom, t_start_s, duration_s, clock_drift_ms, clock_offset_ms,
                     tag_resolution_s) -> tuple[dict, dict, dict]:
    """:func:`simulate_static_pair`'s receiver clocks per nominal epoch (s; offset + linear drift), time tags
    (nominal + clock, rounded to ``tag_resolution_s``) and true reception times (tag − clock), per station."""
    clock, tag, t_true = {}, {}, {}
    for j, name in enumerate(stations):
        clock[name] = clock_drift_ms[j] * 1e-3 * (t_nom - t_start_s) / max(duration_s, 1e-9) + clock_offset_ms[j] * 1e-3
        if tag_resolution_s == 1e-3:
            tag[name] = t_nom + np.round(clock[name] * 1e3) * 1e-3
        elif tag_resolution_s:
            tag[name] = t_nom + np.round(clock[name] / tag_resolution_s) * tag_resolution_s
        else:
            tag[name] = t_nom + clock[name]
        t_true[name] = tag[name] - clock[name]
    return clock, tag, t_true


def _visible_geometry(nav, sats, stations: dict, track: dict, t_nom, t_true: dict, mask_rad: float) -> list:
    """Per satellite with an ephemeris: (sat, its covered epochs, visible at both stations above ``mask_rad``,
    {station: (range m, satellite clock s, elevation rad)}) at each station's true reception times (the rover on
    its ``track`` when it moves)."""
    per_sat = []
    for s in sats:
        idx = np.flatnonzero(ephemeris_coverage(nav, np.full(t_nom.size, s, dtype=object), t_nom))
        if idx.size == 0:
            continue
        geo = {}
        vis = np.ones(idx.size, dtype=bool)
        for name, x in stations.items():
            xs = track[name][idx] if name in track else x
            g = sat_position_at_reception(nav, s, t_nom[idx], xs, rx_clock_s=t_nom[idx] - t_true[name][idx])
            el = azimuth_elevation(xs, g.xyz_m)[1]
            vis &= el > mask_rad
            geo[name] = (g.range_m, g.clock_s, el)
        if vis.any():
            per_sat.append((s, idx, vis, geo))
    return per_sat


def _apply_slips(name: str, s: str, t: np.ndarray, seg_id: np.ndarray, el: np.ndarray, amb: np.ndarray, slips: list,
                 amb_rows: list, applied: list) -> tuple[np.ndarray, np.ndarray]:
    """Station ``name``'s slips of satellite ``s`` (records at nominal times ``t``): each shifts the rest of the lock
    segment it falls in by its cycles and flags its first record (LLI bit 0); recorded in ``amb_rows`` and
    ``applied``.  Returns the ambiguities (cycles) and LLI per record."""
    lli = np.zeros(t.size, dtype=np.int64)
    for rx_name, sl_sat, sl_t, cyc, rnd in slips:
        if rx_name != name or sl_sat != s:
            continue
        after = t >= sl_t
        if after.any():
            j0 = int(np.argmax(after))
            amb = amb + np.where(after & (seg_id == seg_id[j0]), float(cyc), 0.0)
            lli[j0] |= 1
            amb_rows.append((name, s, "slip", float(t[j0]), int(cyc)))
            applied.append({"receiver": name, "sat": s, "time_gps_s": float(t[j0]), "cycles": int(cyc),
                            "elevation_deg": round(math.degrees(float(el[j0])), 3), "random": rnd})
    return amb, lli


def _decimate(df: pd.DataFrame, every: int) -> pd.DataFrame:
    """Records of nominal epochs ``k % every == 0`` (column ``_k``); the LLI slip bit of a dropped
    record is carried to the next kept record of the same satellite."""
    df = df.sort_values(["sat", "_k"], kind="stable").reset_index(drop=True)
    keep = (df["_k"].to_numpy() % every) == 0
    lli = df["lli_l1"].to_numpy().copy()
    sat = df["sat"].to_numpy()
    carry = 0
    for i in range(len(df)):
        if i and sat[i] != sat[i - 1]:
            carry = 0
        if keep[i]:
            lli[i] |= carry
            carry = 0
        else:
            carry |= lli[i] & 1
    df["lli_l1"] = lli
    return df[keep]


CN0_MODEL = (35.0, 15.0)
"""Simulated C/N0 = CN0_MODEL[0] + CN0_MODEL[1]·sin(el), dB-Hz (35 at the horizon, 50 at the zenith)."""


def _noise_sigma(spec, el_rad):
    """σ of each row: a number → that σ; a pair (a, b) → √(a² + b²/sin²el) (sin el ≥ 0.001)."""
    if np.ndim(spec) == 0:
        return float(spec)
    a, b = (float(v) for v in spec)
    sin_el = np.maximum(np.sin(np.asarray(el_rad, dtype=np.float64)), 1e-3)
    return np.sqrt(a * a + (b / sin_el) ** 2)


def _draw_random_slips(per_sat, t_nom, n, mask_rad, min_epochs, gen) -> list:
    """``n`` random slips (receiver, sat, nominal time, cycles) on well-tracked records (see
    :func:`simulate_static_pair`); fewer if there are not enough candidates."""
    if n <= 0:
        return []
    n_ep = t_nom.size
    lo, hi = 0.05 * (n_ep - 1), 0.95 * (n_ep - 1)
    cand_sat, cand_ep = [], []
    for k, (s, idx_all, vis, geo) in enumerate(per_sat):
        ep = idx_all[vis]
        ok = (geo["base"][2][vis] > mask_rad) & (geo["rover"][2][vis] > mask_rad)
        # runs of consecutive epochs tracked above the mask at both receivers
        start = ok & np.concatenate([[True], ~ok[:-1] | (np.diff(ep) != 1)])
        run = np.cumsum(start)
        for r in np.unique(run[ok]):
            j = np.flatnonzero(ok & (run == r))
            pos = np.arange(j.size)
            good = (pos >= min_epochs) & (j.size - pos >= min_epochs)
            e = ep[j[good]]
            e = e[(e >= lo) & (e <= hi)]
            cand_sat.append(np.full(e.size, k))
            cand_ep.append(e)
    if not cand_ep:
        return []
    cand_sat, cand_ep = np.concatenate(cand_sat), np.concatenate(cand_ep)
    out, taken = [], {}
    for c in gen.permutation(2 * cand_ep.size):
        if len(out) == n:
            break
        k, e = int(cand_sat[c // 2]), int(cand_ep[c // 2])
        if any(abs(e - x) < min_epochs for x in taken.get(k, ())):
            continue
        taken.setdefault(k, []).append(e)
        out.append(("base" if c % 2 == 0 else "rover", per_sat[k][0], float(t_nom[e]), int(gen.integers(-50, 50)) or 1))
    return out


# ----------------------------------------------------------------------------------------------
# a synthetic constellation (broadcast-ephemeris records of nominal Keplerian orbits)
# ----------------------------------------------------------------------------------------------


def synthetic_gps_nav(t_start_s: float, duration_s: float, *, planes: int = 6, per_plane: int = 6,
                      seed: int = 0, record_interval_s: float = 7200.0) -> pd.DataFrame:
    """Broadcast ephemerides of a nominal GPS-like constellation covering a span.

    ``planes × per_plane`` satellites ``G01…`` (default 36, G01–G36: more than GPS's 32 PRNs, so
    that at least 5 are above 15° everywhere at all times) on near-circular orbits (semi-major
    axis 26 559.7 km, inclination 55°, eccentricity 0.002–0.012, nodes 360°/planes apart,
    satellites evenly spaced in each plane, node regression
    −8·10⁻⁹ rad/s), with small satellite clock offsets and drifts.  One record per satellite
    every ``record_interval_s`` (on even multiples of it in GPS time) from 2 h before the span to
    2 h after it, each the exact continuation of the same Keplerian orbit, so
    :func:`~cdgps_cli.model.gps.orbits.sat_position_ecef` is continuous across record changes.  The
    harmonic corrections (Cuc … Cis) are zero.  Not real orbits: for simulations only.

    Returns
    -------
    DataFrame
        Columns :data:`~cdgps_cli.io.rinex.NAV_COLUMNS` (``line`` = 0), healthy (``sv_health`` 0).
    """
    return _synthetic_kepler_nav("G", 26_559_700.0, 55.0, GM_GPS, t_start_s, duration_s, planes, per_plane,
                                 seed, record_interval_s)


SYNTHETIC_ORBITS = {"G": (26_559_700.0, 55.0, 6, 6), "E": (29_599_800.0, 56.0, 3, 8), "C": (27_906_100.0, 55.0, 3, 8)}
"""Nominal medium-Earth orbit per system of :func:`synthetic_nav`: semi-major axis (m), inclination
(deg), planes, satellites per plane (Galileo: the Walker 24/3/1 shell of the OS SIS ICD, 29 599.8 km,
56°; BeiDou: the BDS-3 MEO Walker 24/3/1 shell, 21 528 km altitude, 55°).  BeiDou also has the
geosynchronous satellites of :data:`SYNTHETIC_BEIDOU_GEO_LON_DEG` and :data:`SYNTHETIC_BEIDOU_IGSO`."""
SYNTHETIC_BEIDOU_GEO_LON_DEG = (58.75, 80.0, 110.5, 140.0, 160.0)
"""Longitudes (deg E) of the synthetic BeiDou GEO satellites C01–C05 (the BDS GEO slots)."""
SYNTHETIC_BEIDOU_IGSO = (118.0, 55.0, 3)
"""Synthetic BeiDou IGSO satellites C06–C08: longitude (deg E) where their common figure-eight
ground track crosses the equator, inclination (deg), number (nodes 360°/number apart)."""
SYNTHETIC_BEIDOU_FIRST_MEO_PRN = 19
"""PRN of the first synthetic BeiDou MEO satellite (C19–C42, as BDS-3's MEO PRNs begin at 19)."""
_SYSTEM_ORDER = "GEC"


def synthetic_nav(systems, t_start_s: float, duration_s: float, *, seed: int = 0,
                  record_interval_s: float = 7200.0) -> pd.DataFrame:
    """Broadcast ephemerides of nominal constellations of several systems (``"G"``, ``"E"``, ``"C"``).

    GPS is :func:`synthetic_gps_nav` with ``seed`` (identical records); Galileo satellites
    ``E01…E24`` on the orbits of :data:`SYNTHETIC_ORBITS` with the Galileo GM (seed + 1); BeiDou
    (seed + 2, :func:`synthetic_beidou_nav`) ``C01…C05`` GEO, ``C06…C08`` IGSO and ``C19…C42`` MEO.
    Records in the GPS form (Galileo ``week`` as a GPS week, as RINEX 3 writes it; BeiDou in BDT:
    ``week``/``toe_sow_s``/``transmit_sow_s`` BDT, the ``*_gps_s`` columns GPS seconds, as
    :func:`~cdgps_cli.io.rinex.read_rinex_nav` returns them).  Simulations only.
    """
    from cdgps_cli.model.gps.orbits import GM_BY_SYSTEM  # noqa: PLC0415

    tabs = []
    for c in sorted(set(systems), key=lambda x: _SYSTEM_ORDER.index(x) if x in _SYSTEM_ORDER else 99):
        if c not in SYNTHETIC_ORBITS:
            raise CdgpsError(f"synthetic ephemerides exist for systems {', '.join(SYNTHETIC_ORBITS)}, not {c!r}")
        if c == "C":
            tabs.append(synthetic_beidou_nav(t_start_s, duration_s, seed=seed + 2, record_interval_s=record_interval_s))
            continue
        a, inc, planes, per_plane = SYNTHETIC_ORBITS[c]
        tabs.append(_synthetic_kepler_nav(c, a, inc, GM_BY_SYSTEM[c], t_start_s, duration_s, planes, per_plane,
                                          seed + _SYSTEM_ORDER.index(c), record_interval_s))
    return pd.concat(tabs, ignore_index=True)


def synthetic_beidou_nav(t_start_s: float, duration_s: float, *, seed: int = 0,
                         record_interval_s: float = 7200.0) -> pd.DataFrame:
    """Broadcast ephemerides of a nominal BeiDou constellation (BDS-ICD-B1I 3.0 record layout).

    * ``C01…C05`` GEO at the longitudes :data:`SYNTHETIC_BEIDOU_GEO_LON_DEG`: geosynchronous
      (n = ω_e of CGCS2000), eccentricity 0.0002–0.001, physical inclination 0.5–1.5°; their
      records are written for the ICD's GEO algorithm (Kepler elements in the frame R_X(5°)·ECEF(t_oe),
      see :func:`_geo_record_elements`), so :func:`~cdgps_cli.model.gps.orbits.sat_position_ecef`
      turns them back into the same inertial two-body orbit;
    * ``C06…C08`` IGSO (:data:`SYNTHETIC_BEIDOU_IGSO`: 55°, nodes 120° apart, one ground track
      crossing the equator at 118° E);
    * ``C19…C42`` MEO, the Walker 24/3/1 shell of :data:`SYNTHETIC_ORBITS` ``"C"``.

    Time: BDT = GPST − 14 s.  Records every ``record_interval_s`` on whole multiples of it in
    **BDT** (t_oe, t_oc), ``week``/``toe_sow_s``/``transmit_sow_s`` in BDT, ``toe_gps_s``/``toc_gps_s``/
    ``transmit_gps_s`` in GPS seconds; ``iode`` = AODE (5 bits), ``iodc`` = AODC, ``tgd_s`` = TGD1.
    Each record is the exact continuation of the same orbit (no jump at a record change).  Not real
    orbits: for simulations only.
    """
    from cdgps_cli.core.gps_time import GPS_MINUS_BDT_S  # noqa: PLC0415
    from cdgps_cli.model.gps.orbits import GM_BEIDOU, OMEGA_E_BEIDOU  # noqa: PLC0415

    a, inc, planes, per_plane = SYNTHETIC_ORBITS["C"]
    meo = _synthetic_kepler_nav("C", a, inc, GM_BEIDOU, t_start_s, duration_s, planes, per_plane, seed, record_interval_s,
                                first_prn=SYNTHETIC_BEIDOU_FIRST_MEO_PRN)
    gen = np.random.default_rng(seed + 1000)
    a_gso = (GM_BEIDOU / OMEGA_E_BEIDOU**2) ** (1.0 / 3.0)
    step = float(record_interval_s)
    t_ref = math.floor((t_start_s - GPS_MINUS_BDT_S) / step) * step + GPS_MINUS_BDT_S
    toes = np.arange(t_ref - step, t_start_s + duration_s + 2 * step, step)
    rows = []
    for k, lon in enumerate(SYNTHETIC_BEIDOU_GEO_LON_DEG):
        node, argp = gen.uniform(-math.pi, math.pi, 2)
        el = {"a": a_gso, "e": gen.uniform(2e-4, 1e-3), "inc": math.radians(gen.uniform(0.5, 1.5)), "node": node,
              "argp": argp, "m_ref": math.radians(lon) - node - argp, "omega_dot": 0.0}
        rows += _element_records(f"C{k + 1:02d}", el, t_ref, toes, "C", _sat_clock(gen), geo=True)
    lon_x, inc_igso, n_igso = SYNTHETIC_BEIDOU_IGSO
    for k in range(n_igso):
        node = 2 * math.pi * k / n_igso
        argp = gen.uniform(-math.pi, math.pi)
        el = {"a": a_gso, "e": gen.uniform(2e-3, 8e-3), "inc": math.radians(inc_igso), "node": node, "argp": argp,
              "m_ref": math.radians(lon_x) - node - argp, "omega_dot": -8.0e-9}
        rows += _element_records(f"C{len(SYNTHETIC_BEIDOU_GEO_LON_DEG) + k + 1:02d}", el, t_ref, toes, "C",
                                 _sat_clock(gen), geo=False)
    from cdgps_cli.core.records import NAV_COLUMNS  # noqa: PLC0415

    gso = pd.DataFrame(rows)[list(NAV_COLUMNS)]
    return pd.concat([gso, meo], ignore_index=True).sort_values(["sat", "toe_gps_s"], kind="stable").reset_index(drop=True)


def _sat_clock(gen) -> tuple[float, float, float]:
    """(af0 s, af1 s/s, T_GD s) of a synthetic satellite clock."""
    return gen.uniform(-2e-4, 2e-4), gen.uniform(-5e-12, 5e-12), gen.uniform(-1e-8, 1e-8)


def _system_week_sow(letter: str, t_gps_s: float) -> tuple[int, float]:
    """(week, seconds of week) of a GPS time in the time scale a system's records use (BeiDou: BDT)."""
    from cdgps_cli.core.gps_time import BDT_WEEK_OFFSET, GPS_MINUS_BDT_S  # noqa: PLC0415

    if letter == "C":
        t = t_gps_s - GPS_MINUS_BDT_S
        week = int(t // 604800)
        return week - BDT_WEEK_OFFSET, float(t - week * 604800)
    week = int(t_gps_s // 604800)
    return week, float(t_gps_s - week * 604800)


def _rot_x(phi: float) -> np.ndarray:
    """Frame rotation about X by ``phi`` (rad), the R_X of BDS-ICD-B1I §5.2.4.12."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def _rot_z(phi: float) -> np.ndarray:
    """Frame rotation about Z by ``phi`` (rad), the R_Z of BDS-ICD-B1I §5.2.4.12."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def _geo_record_elements(inc: float, node: float, argp: float, theta_rad: float) -> tuple[float, float, float]:
    """(i, Ω, ω) rad of an orbit of inertial elements ``inc, node, argp`` in the frame of a BeiDou GEO
    record, x_GK = R_X(+5°) · R_Z(θ) · x_I with θ = ω_e (t_oe − t_ref) (the inverse of the ICD's
    x_ECEF = R_Z(ω_e t_k) · R_X(−5°) · x_GK): the perigee direction P and the orbit normal W are
    rotated and the elements read back (W = (sin Ω sin i, −cos Ω sin i, cos i), P_z = sin ω sin i)."""
    from cdgps_cli.model.gps.orbits import BEIDOU_GEO_TILT_RAD  # noqa: PLC0415

    co, so, cw, sw, ci, si = (math.cos(node), math.sin(node), math.cos(argp), math.sin(argp),
                              math.cos(inc), math.sin(inc))
    p_vec = np.array([co * cw - so * sw * ci, so * cw + co * sw * ci, sw * si])
    w_vec = np.array([so * si, -co * si, ci])
    q = _rot_x(-BEIDOU_GEO_TILT_RAD) @ _rot_z(theta_rad)
    p2, w2 = q @ p_vec, q @ w_vec
    inc2 = math.acos(max(-1.0, min(1.0, w2[2])))
    node2 = math.atan2(w2[0], -w2[1])
    argp2 = math.atan2(p2[2] / math.sin(inc2), p2[0] * math.cos(node2) + p2[1] * math.sin(node2))
    return inc2, node2, argp2


def _element_records(sat: str, el: dict, t_ref: float, toes, letter: str, clock: tuple, *, geo: bool) -> list[dict]:
    """One broadcast record per t_oe (GPS s) of the orbit with inertial elements ``el`` at ``t_ref``
    (``a`` m, ``e``, ``inc``, ``node``, ``argp``, ``m_ref`` rad, ``omega_dot`` rad/s; the inertial
    frame is the ECEF frame at ``t_ref``), each the exact continuation of that orbit."""
    from cdgps_cli.model.gps.orbits import GM_BY_SYSTEM, OMEGA_E_BY_SYSTEM  # noqa: PLC0415

    gm, we = GM_BY_SYSTEM[letter], OMEGA_E_BY_SYSTEM[letter]
    n0 = math.sqrt(gm / el["a"] ** 3)
    af0, af1, tgd = clock
    prn = int(sat[1:])
    rows = []
    for k, toe in enumerate(toes):
        week, sow = _system_week_sow(letter, float(toe))
        dt_ = float(toe) - t_ref
        inc, node, argp = el["inc"], el["node"] + el["omega_dot"] * dt_ - we * dt_, el["argp"]
        if geo:
            inc, node, argp = _geo_record_elements(el["inc"], el["node"], el["argp"], we * dt_)
        iod = int((k + 7 * prn) % (32 if letter == "C" else 256))
        rows.append(_nav_row(sat, float(toe), week, sow, af0 + af1 * dt_, af1, tgd, iod, {
            "m0_rad": math.remainder(el["m_ref"] + n0 * dt_, 2 * math.pi), "e": el["e"],
            "sqrt_a_sqrt_m": math.sqrt(el["a"]), "omega0_rad": math.remainder(node + we * sow, 2 * math.pi),
            "i0_rad": inc, "omega_rad": argp, "omega_dot_rad_per_s": el["omega_dot"]}))
    return rows


def _nav_row(sat: str, toe: float, week: int, sow: float, af0: float, af1: float, tgd: float, iod: int, orbit: dict) -> dict:
    """A :data:`NAV_COLUMNS` record (harmonic corrections, Δn, IDOT and af2 zero; healthy; transmitted
    an hour before t_oe, at t_oe in a week's first hour)."""
    row = {"sat": sat, "toc_gps_s": toe, "af0_s": af0, "af1_s_per_s": af1, "af2_s_per_s2": 0.0, "iode": iod,
           "crs_m": 0.0, "delta_n_rad_per_s": 0.0, "cuc_rad": 0.0, "cus_rad": 0.0, "toe_sow_s": sow, "cic_rad": 0.0,
           "cis_rad": 0.0, "crc_m": 0.0, "idot_rad_per_s": 0.0, "codes_l2": 1, "week": week, "l2p_data_flag": 0,
           "sv_accuracy_m": 2.0, "sv_health": 0, "tgd_s": tgd, "iodc": iod,
           "transmit_sow_s": sow - 3600.0 if sow >= 3600.0 else sow, "fit_interval_h": 4.0, "toe_gps_s": toe,
           "transmit_gps_s": toe - 3600.0 if sow >= 3600.0 else toe, "line": 0}
    row.update(orbit)
    if sat[0] == "C":            # BeiDou: no L2 codes / P flag / fit interval in the record
        row.update({"codes_l2": -1, "l2p_data_flag": -1, "fit_interval_h": float("nan")})
    return row


def _synthetic_kepler_nav(letter: str, a: float, inc_deg: float, gm: float, t_start_s: float, duration_s: float,
                          planes: int, per_plane: int, seed: int, record_interval_s: float, *,
                          first_prn: int = 1) -> pd.DataFrame:
    """Records of ``planes × per_plane`` near-circular orbits of radius ``a`` (m), see :func:`synthetic_gps_nav`
    (t_oe on whole multiples of ``record_interval_s`` in the system's time scale; BeiDou: BDT)."""
    from cdgps_cli.core.gps_time import GPS_MINUS_BDT_S  # noqa: PLC0415

    gen = np.random.default_rng(seed)
    step = float(record_interval_s)
    off = GPS_MINUS_BDT_S if letter == "C" else 0.0
    t_ref = math.floor((t_start_s - off) / step) * step + off
    toes = np.arange(t_ref - step, t_start_s + duration_s + 2 * step, step)
    rows = []
    prn = first_prn - 1
    for p in range(planes):
        node = 2 * math.pi * p / planes + gen.uniform(-0.02, 0.02)
        for q in range(per_plane):
            prn += 1
            m_ref = 2 * math.pi * q / per_plane + gen.uniform(-0.05, 0.05)
            ecc = gen.uniform(0.002, 0.012)
            argp = gen.uniform(-math.pi, math.pi)
            inc = math.radians(inc_deg) + gen.uniform(-0.01, 0.01)
            el = {"a": a, "e": ecc, "inc": inc, "node": node, "argp": argp, "m_ref": m_ref, "omega_dot": -8.0e-9}
            rows += _element_records(f"{letter}{prn:02d}", el, t_ref, toes, letter, _sat_clock(gen), geo=False)
    df = pd.DataFrame(rows)
    from cdgps_cli.core.records import NAV_COLUMNS  # noqa: PLC0415

    return df[list(NAV_COLUMNS)].sort_values(["sat", "toe_gps_s"], kind="stable").reset_index(drop=True)
