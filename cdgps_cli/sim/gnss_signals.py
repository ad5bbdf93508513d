"""Multi-GNSS, multi-frequency carrier phase and pseudorange of one (possibly moving) receiver.

:func:`simulate_receiver_signals` gives, for the signals asked for (names of
:mod:`cdgps_cli.core.signals`, e.g. ``G:L1``, ``G:L2``, ``E:E1``, ``E:E5a``, ``C:B1I``, ``C:B2a``), one
row per epoch, satellite and signal:

    P_g = ρ + c·(dt − dt_sat) + T + ε_P,      φ_g = (ρ + c·(dt − dt_sat) + T + ε_φ,g) / λ_g + N_g + f_g

with ρ the geometric range (light time and Earth rotation, :func:`~cdgps_cli.model.gps.orbits.sat_position_at_reception`)
at the true reception instant ``tag − dt``, dt the receiver clock (drifting linearly), T the a priori
hydrostatic troposphere (plus, when asked, a zenith wet delay mapped by Niell's wet function), N_g an integer per signal, satellite and lock segment (a new one after each
visibility gap), f_g a fractional phase bias per signal common to all satellites (the receiver's
inter-frequency phase bias: it cancels in double differences within a signal), ε white with
σ² = a² + b²/sin²el per signal (independent between signals).  Time tags are the nominal epochs (a
receiver steering its time tags to GPS time).  No ionosphere: the structures are short baselines, on
which it cancels in the double differences.  The satellite clock includes T_GD for every signal
(common to both receivers of a baseline, so it cancels in the single differences).  Every system's
satellites come from ``nav`` evaluated at GPS time (BeiDou records carry GPS seconds in their
``*_gps_s`` columns, BDT = GPST − 14 s, so one time axis serves all); every satellite of a system is
observed on every signal of it asked for (real BeiDou: B2I on BDS-2 only, B2a on BDS-3 only).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.core.signals import signal
from cdgps_cli.model.gps.orbits import azimuth_elevation, ecef_to_geodetic, enu_matrix, sat_position_at_reception
from cdgps_cli.model.gps.positioning import CN0_MODEL, ephemeris_coverage, niell_wet_mapping, tropo_hydrostatic_m

__all__ = ["simulate_receiver_signals", "SIGNAL_OBS_COLUMNS"]

SIGNAL_OBS_COLUMNS = ("time_gps_s", "sat", "signal", "phase_cycles", "pseudorange_m", "lli", "snr_dbhz")


def _sigma(a_m: float, b_m: float, el_rad):
    return np.sqrt(a_m**2 + (b_m / np.maximum(np.sin(el_rad), 1e-3)) ** 2)


def simulate_receiver_signals(nav: pd.DataFrame, rx_ecef_m, t_start_s: float, n_epochs: int, interval_s: float,
                              signals, *, offset_enu_m=None, seed: int = 0, mask_rad: float = math.radians(10.0),
                              phase_sigma_m: tuple = (0.003, 0.003), code_sigma_m: float = 0.5,
                              clock_drift_ms: float = 0.0, troposphere: bool = True, zenith_wet_m=0.0) -> dict:
    """Observations of ``signals`` at one receiver (see the module docstring for the model).

    Parameters
    ----------
    nav : DataFrame
        Broadcast ephemerides of every system of ``signals`` (they define the truth).
    rx_ecef_m : array_like (3,)
        Nominal antenna position, ECEF m.
    t_start_s, n_epochs, interval_s : float, int, float
        Epochs ``t_start + k·interval``, GPS s.
    signals : sequence of str
        Signal names; a satellite is observed on every signal of its system.
    offset_enu_m : ndarray (n_epochs, 3), optional
        Antenna displacement from ``rx_ecef_m`` per epoch, east/north/up m (default static).
    seed : int
    mask_rad : float
        Tracking mask, rad.
    phase_sigma_m : (a, b)
        Phase noise σ² = a² + b²/sin²el, m; code noise ``code_sigma_m`` (white, m).
    clock_drift_ms : float
        Receiver clock offset at the end of the span (it starts at 0 and drifts linearly), ms.
    troposphere : bool
        The a-priori hydrostatic troposphere T in the observations.
    zenith_wet_m : float or array_like (n_epochs,)
        Zenith wet delay at the receiver, m (per epoch when an array): each observation is delayed by it times the
        Niell wet mapping factor at its elevation (:func:`~cdgps_cli.model.gps.positioning.niell_wet_mapping`),
        phase and code alike; 0 (the default) leaves it out.

    Returns
    -------
    dict
        ``obs`` (DataFrame, :data:`SIGNAL_OBS_COLUMNS`, sorted by time, signal, satellite),
        ``ambiguities`` (DataFrame ``signal, sat, t_from_s, n_cycles``: the integer of each lock
        segment), ``frac_bias_cycles`` ({signal: f}), ``clock_s`` (n_epochs,).
    """
    gen = np.random.default_rng(seed)
    names = list(dict.fromkeys(signals))
    t_nom = t_start_s + np.arange(int(n_epochs)) * float(interval_s)
    span = max(t_nom[-1] - t_nom[0], 1e-9)
    clock = clock_drift_ms * 1e-3 * (t_nom - t_nom[0]) / span
    x0 = np.asarray(rx_ecef_m, float)
    lat, lon, h = ecef_to_geodetic(x0)
    zwd = np.broadcast_to(np.asarray(zenith_wet_m, dtype=float), t_nom.shape)
    track = np.broadcast_to(x0, (t_nom.size, 3)) if offset_enu_m is None else x0 + np.asarray(offset_enu_m, float) @ enu_matrix(lat, lon)
    fracs = {g: float(gen.uniform(-0.5, 0.5)) for g in names}
    systems = {signal(g).system for g in names}
    frames, amb_rows = [], []
    sats = [s for s in sorted(nav["sat"].unique()) if s[0] in systems]
    covered = ephemeris_coverage(nav, np.repeat(np.array(sats, dtype=object), t_nom.size),
                                 np.tile(t_nom, len(sats))).reshape(len(sats), t_nom.size)
    for s, cov in zip(sats, covered):
        idx = np.flatnonzero(cov)
        if idx.size == 0:
            continue
        geo = sat_position_at_reception(nav, s, t_nom[idx], track[idx], rx_clock_s=clock[idx])
        el = azimuth_elevation(track[idx], geo.xyz_m)[1]
        vis = el > mask_rad
        idx, el, rho, dts = idx[vis], el[vis], geo.range_m[vis], geo.clock_s[vis]
        if idx.size == 0:
            continue
        trop = tropo_hydrostatic_m(el, lat, h, t_nom[idx] - clock[idx]) if troposphere else 0.0
        common = rho + SPEED_OF_LIGHT_M_S * (clock[idx] - dts) + trop
        if np.any(zwd):
            common = common + zwd[idx] * niell_wet_mapping(el, lat)
        seg_start = np.r_[True, np.diff(idx) > 1]
        seg_id = np.cumsum(seg_start) - 1
        for g in (g for g in names if signal(g).system == s[0]):
            lam = signal(g).wavelength_m
            n_int = gen.integers(-2_000_000, 2_000_000, size=int(seg_id[-1]) + 1)
            amb_rows += [(g, s, float(t_nom[idx[j]]), int(n_int[seg_id[j]])) for j in np.flatnonzero(seg_start)]
            ph = (common + gen.normal(0.0, _sigma(*phase_sigma_m, el))) / lam + n_int[seg_id] + fracs[g]
            pr = common + gen.normal(0.0, code_sigma_m, idx.size)
            frames.append(pd.DataFrame({"time_gps_s": t_nom[idx], "sat": s, "signal": g, "phase_cycles": ph,
                                        "pseudorange_m": pr, "lli": np.zeros(idx.size, dtype=np.int64),
                                        "snr_dbhz": CN0_MODEL[0] + CN0_MODEL[1] * np.sin(el)}))
    obs = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=list(SIGNAL_OBS_COLUMNS))
    obs = obs.sort_values(["time_gps_s", "signal", "sat"], kind="stable").reset_index(drop=True)
    return {"obs": obs, "ambiguities": pd.DataFrame(amb_rows, columns=["signal", "sat", "t_from_s", "n_cycles"]),
            "frac_bias_cycles": fracs, "clock_s": clock}
