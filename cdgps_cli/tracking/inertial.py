"""Inertial-sensor error models by grade, and the Doppler aid an inertial sensor gives a carrier loop.

A sensor output is the true quantity through the sensor's bandwidth, plus a constant bias, plus white
noise given by its density N: averaged over an interval Δt the noise has standard deviation N/√Δt
(so an accelerometer's noise integrates to a velocity random walk of N √t, a gyro's to an angle random
walk).  The bandwidth is a first-order low-pass, −3 dB at ``bandwidth_hz``, discretized exactly
(y_k = a y_{k−1} + (1 − a) u_k, a = exp(−2π f_bw Δt)).

Typical values per grade after Groves, Principles of GNSS, Inertial, and Multisensor Integrated
Navigation Systems, 2nd ed. (2013), Sec. 4.4 (biases, noise; orders of magnitude, not data sheets).
Pure numerics: arrays in, arrays out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.constants import STANDARD_GRAVITY_M_S2 as G0_M_S2


DEG_PER_HOUR = math.pi / 180 / 3600                 # rad/s
DEG_PER_ROOT_HOUR = math.pi / 180 / 60              # rad/√s (angle random walk → rad/s/√Hz)
MICRO_G_PER_ROOT_HZ = 1e-6 * G0_M_S2                # m/s²/√Hz


@dataclass(frozen=True)
class InertialGrade:
    """Error model of one grade of accelerometers and gyros (SI units)."""

    name: str
    accel_bias_m_s2: float
    accel_noise_m_s2_per_rthz: float
    gyro_bias_rad_s: float
    gyro_noise_rad_s_per_rthz: float
    bandwidth_hz: float

    def __post_init__(self):
        for k, v in self.__dict__.items():
            if k != "name" and not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise CdgpsError(f"inertial grade {self.name!r}: {k} must be a finite number ≥ 0, got {v!r}")
        if self.bandwidth_hz <= 0:
            raise CdgpsError(f"inertial grade {self.name!r}: bandwidth_hz must be positive")


#: Groves (2013) Sec. 4.4: navigation grade ~0.03-0.1 mg, 0.01 °/h; tactical 1-10 mg, 1-100 °/h;
#: consumer MEMS > 10 mg, > 100 °/h; noise 20 / 100 / 300 µg/√Hz, 0.002 / 0.05 / 0.5 °/√h
GRADES = {g.name: g for g in (
    InertialGrade("navigation", 0.05e-3 * G0_M_S2, 20 * MICRO_G_PER_ROOT_HZ, 0.01 * DEG_PER_HOUR,
                  0.002 * DEG_PER_ROOT_HOUR, 100.0),
    InertialGrade("tactical", 1e-3 * G0_M_S2, 100 * MICRO_G_PER_ROOT_HZ, 1.0 * DEG_PER_HOUR,
                  0.05 * DEG_PER_ROOT_HOUR, 100.0),
    InertialGrade("consumer", 10e-3 * G0_M_S2, 300 * MICRO_G_PER_ROOT_HZ, 100.0 * DEG_PER_HOUR,
                  0.5 * DEG_PER_ROOT_HOUR, 30.0),
)}


def low_pass(u: np.ndarray, dt_s: float, bandwidth_hz: float) -> np.ndarray:
    """First-order low-pass (−3 dB at ``bandwidth_hz``) along axis 0, starting settled at u[0]."""
    u = np.asarray(u, dtype=float)
    a = math.exp(-2 * math.pi * bandwidth_hz * dt_s)
    y, _ = lfilter([1 - a], [1, -a], u, axis=0, zi=a * u[:1] if u.ndim == 1 else a * u[:1, :])
    return y


def sense(true: np.ndarray, dt_s: float, bias: float, noise_per_rthz: float, bandwidth_hz: float,
          rng: np.random.Generator) -> np.ndarray:
    """A sensor's output at interval ``dt_s`` for the true signal (axis 0 = time): band-limited + bias + noise."""
    if not (dt_s > 0 and math.isfinite(dt_s)):
        raise CdgpsError(f"dt_s: expected a positive interval in seconds, got {dt_s!r}")
    true = np.asarray(true, dtype=float)
    return low_pass(true, dt_s, bandwidth_hz) + bias + noise_per_rthz / math.sqrt(dt_s) * rng.standard_normal(true.shape)


def accelerometer_doppler_aid_hz(acc_los_m_s2: np.ndarray, dt_s: float, grade: InertialGrade,
                                 rng: np.random.Generator, v0_m_s: float = 0.0,
                                 wavelength_m: float = GPS_L1_WAVELENGTH_M) -> np.ndarray:
    """Doppler aid (Hz) from an accelerometer along the line of sight: the sensed acceleration
    integrated (trapezoid) from the known initial velocity ``v0_m_s`` (towards the satellite), over λ.

    ``acc_los_m_s2`` is the true acceleration towards the satellite at instants spaced ``dt_s``; the
    aid is given at the same instants.  The bias makes the aid drift by bias·t/λ Hz, the noise
    a random walk of N √t / λ.
    """
    a = sense(acc_los_m_s2, dt_s, grade.accel_bias_m_s2, grade.accel_noise_m_s2_per_rthz, grade.bandwidth_hz, rng)
    v = v0_m_s + np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * dt_s)])
    return v / wavelength_m


def gyro_antenna_velocity_m_s(omega_rad_s: np.ndarray, lever_arm_m: np.ndarray) -> np.ndarray:
    """Velocity (m/s) of an antenna at ``lever_arm_m`` (3,) from a rotation-rate sensor: ω × r, shape (n, 3)."""
    w = np.asarray(omega_rad_s, dtype=float)
    r = np.asarray(lever_arm_m, dtype=float)
    if w.ndim != 2 or w.shape[1] != 3 or r.shape != (3,):
        raise CdgpsError(f"expected rates of shape (n, 3) and a lever arm of shape (3,), got {w.shape} and {r.shape}")
    return np.cross(w, r)
