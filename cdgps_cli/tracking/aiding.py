"""External Doppler for aided tracking (Alban et al. 2003, Sec. III) and the receiver clock drift as
the common mode of the channels' frequency errors.

* :func:`los_doppler_hz`: f_D = (V_rx − V_sat)·1_LOS / λ (the paper's Eq. 4; 1_LOS from the receiver to the
  satellite) from a receiver trajectory and a broadcast ephemeris, the satellite velocity by a
  central difference of its position at reception (the paper's Eq. 5 uses a forward one), plus the
  satellite clock's drift (its frequency offset, f_L1 · d(Δt_sv)/dt).  A receiver moving towards a
  satellite sees a positive Doppler.
* :func:`common_mode_hz`: the weighted mean over channels of per-channel frequency errors (measured
  minus predicted Doppler), i.e. the receiver clock's frequency error f_clk seen at L1, which every
  channel shares (f_PLL = f_dopp + f_clk + f_noise, the paper's Eq. 3); NaN channels are left out.
* :func:`clock_drift_s_per_s`: f_clk as the oscillator's fractional frequency error.

Pure numerics (the ephemeris table comes from :func:`cdgps_cli.io.rinex.read_rinex_nav`).
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.model.gps.orbits import sat_position_at_reception
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.tracking.channel import L1_HZ


def los_doppler_hz(nav, sat: str, t_rx_gps_s, rx_ecef_m, rx_velocity_ecef_m_s=0.0, *, step_s: float = 0.5,
                   with_satellite_clock: bool = True) -> np.ndarray:
    """Predicted L1 Doppler (Hz) of ``sat`` at reception times ``t_rx_gps_s`` (GPS s, shape (N,)).

    Parameters
    ----------
    nav : DataFrame
        Broadcast ephemerides (:func:`cdgps_cli.io.rinex.read_rinex_nav`).
    sat : str
        e.g. ``"G07"``.
    rx_ecef_m : array_like, shape (3,) or (N, 3)
        Receiver antenna position, ECEF, m.
    rx_velocity_ecef_m_s : array_like, shape (3,) or (N, 3), or 0
        Receiver antenna velocity, ECEF, m/s (a structure simulation, an INS, ω × r from gyros).
    step_s : float
        Half-width of the central difference giving the satellite velocity, s.
    with_satellite_clock : bool
        Add the satellite clock's frequency offset f_L1 · d(Δt_sv)/dt.
    """
    t = np.atleast_1d(np.asarray(t_rx_gps_s, dtype=float)).ravel()
    try:
        rx = np.broadcast_to(np.asarray(rx_ecef_m, dtype=float), (t.size, 3))
        v_rx = np.broadcast_to(np.asarray(rx_velocity_ecef_m_s, dtype=float), (t.size, 3))
    except ValueError:
        raise CdgpsError(f"rx_ecef_m, rx_velocity_ecef_m_s: expected shape (3,) or ({t.size}, 3) for {t.size} "
                         f"times, got {np.shape(rx_ecef_m)} and {np.shape(rx_velocity_ecef_m_s)}") from None
    if not (step_s > 0):
        raise CdgpsError(f"step_s: expected a positive time step, got {step_s!r}")
    g0 = sat_position_at_reception(nav, sat, t, rx)
    gm = sat_position_at_reception(nav, sat, t - step_s, rx)
    gp = sat_position_at_reception(nav, sat, t + step_s, rx)
    v_sat = (gp.xyz_m - gm.xyz_m) / (2 * step_s)
    los = (g0.xyz_m - rx) / g0.range_m[:, None]
    f = np.einsum("ij,ij->i", v_rx - v_sat, los) / GPS_L1_WAVELENGTH_M
    if with_satellite_clock:
        f = f + L1_HZ * (gp.clock_s - gm.clock_s) / (2 * step_s)
    return f


def common_mode_hz(freq_error_hz: np.ndarray, weights=None) -> np.ndarray:
    """Weighted mean over channels (last axis) of frequency errors (Hz), NaN entries left out.

    Parameters
    ----------
    freq_error_hz : ndarray, shape (..., n_channels)
        Per channel: tracked (or measured) Doppler minus the external prediction, Hz.
    weights : array_like, shape (n_channels,) or like ``freq_error_hz``, optional
        e.g. C/N0 (linear) — the frequency noise variance of a channel scales as 1/(C/N0).  Equal if omitted.

    Returns
    -------
    ndarray, shape (...)
        The common mode; NaN where no channel has a value.
    """
    e = np.asarray(freq_error_hz, dtype=float)
    try:
        w = np.ones(e.shape) if weights is None else np.broadcast_to(np.asarray(weights, dtype=float), e.shape)
    except ValueError:
        raise CdgpsError(f"weights: expected one per channel ({e.shape[-1]}) or the shape {e.shape}, "
                         f"got {np.shape(weights)}") from None
    if np.any(w < 0) or not np.all(np.isfinite(w)):
        raise CdgpsError("weights: expected finite values ≥ 0")
    ok = np.isfinite(e) & (w > 0)
    num = np.where(ok, e * w, 0.0).sum(axis=-1)
    den = np.where(ok, w, 0.0).sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


def clock_drift_s_per_s(clock_doppler_hz) -> np.ndarray:
    """Receiver clock drift (s/s, positive: the clock runs fast) from its Doppler at L1.

    A receiver oscillator running fast by δ (fractional) mixes the signal down with a local frequency
    f_L1(1 + δ): the apparent Doppler of every satellite drops by δ f_L1.
    """
    return -np.asarray(clock_doppler_hz, dtype=float) / L1_HZ
