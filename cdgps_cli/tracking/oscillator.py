"""Receiver oscillator models by their power-law coefficients h0, h−1, h−2, and phase noise with
the matching Allan variance.

The fractional frequency y(t) = δf/f0 of a crystal oscillator has the one-sided spectral density
S_y(f) = h0 + h−1/f + h−2/f² (white, flicker and random-walk frequency noise; the phase terms h1, h2
are negligible at tracking-loop rates), whose Allan variance is (IEEE Std 1139; Barnes et al. 1971)

    σ_y²(τ) = h0 / (2τ) + 2 ln 2 · h−1 + (2π²/3) · h−2 · τ.

:func:`simulate_fractional_frequency` draws y averaged over each sample interval Δt:

* white FM: independent samples of variance h0 / (2Δt);
* random-walk FM: y_k = y_{k−1} + w_k, var w = 2π² h−2 Δt (the diffusion q = 2π² h−2);
* flicker FM: white noise of variance π h−1 through the fractional-difference filter (1 − z⁻¹)^(−1/2)
  (Kasdin & Walter 1992: impulse response g_0 = 1, g_k = g_{k−1}(k − 1/2)/k, applied by FFT),
  whose one-sided spectrum at f ≪ 1/Δt is π h−1 · 2Δt / (2π f Δt) = h−1 / f.

The time error is x = Σ y Δt (s) and the carrier phase error 2π f_carrier x (rad).  Pure numerics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import quad

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.tracking.channel import L1_HZ
from cdgps_cli.tracking.loops import pll2_response


@dataclass(frozen=True)
class Oscillator:
    """Power-law coefficients of S_y(f) (h0 in 1/Hz·Hz = s, h−1 dimensionless, h−2 in 1/s)."""

    name: str
    h0: float
    h_m1: float
    h_m2: float
    reference: str = ""

    def __post_init__(self):
        for k in ("h0", "h_m1", "h_m2"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise CdgpsError(f"oscillator {self.name!r}: {k} must be a finite number ≥ 0, got {v!r}")

    def allan_variance(self, tau_s) -> np.ndarray:
        """Analytic σ_y²(τ) for averaging times ``tau_s`` (s)."""
        tau = np.asarray(tau_s, dtype=float)
        return self.h0 / (2 * tau) + 2 * math.log(2) * self.h_m1 + 2 * math.pi**2 / 3 * self.h_m2 * tau

    def allan_deviation(self, tau_s) -> np.ndarray:
        """Analytic σ_y(τ)."""
        return np.sqrt(self.allan_variance(tau_s))


_BROWN_HWANG = ("Brown & Hwang, Introduction to Random Signals and Applied Kalman Filtering, 4th ed. (2012), "
                "Sec. 9.3, table of typical h coefficients")
#: a low-quality temperature-compensated crystal (Brown & Hwang's "low quality TCXO")
TCXO = Oscillator("TCXO", 2e-19, 7e-21, 2e-20, _BROWN_HWANG)
#: a high-quality temperature-compensated crystal (Brown & Hwang's "high quality TCXO")
TCXO_HQ = Oscillator("TCXO-HQ", 2e-21, 1e-22, 2e-20, _BROWN_HWANG)
#: an oven-controlled crystal (Brown & Hwang's "OCXO")
OCXO = Oscillator("OCXO", 2e-25, 7e-25, 6e-25, _BROWN_HWANG)
OSCILLATORS = {o.name: o for o in (TCXO, TCXO_HQ, OCXO)}


def _flicker(n: int, rng: np.random.Generator) -> np.ndarray:
    """n samples of unit-variance white noise through (1 − z⁻¹)^(−1/2) (linear convolution by FFT)."""
    k = np.arange(1, n)
    g = np.concatenate([[1.0], np.cumprod((k - 0.5) / k)])
    w = rng.standard_normal(n)
    size = 1 << int(2 * n - 1).bit_length()
    return np.fft.irfft(np.fft.rfft(w, size) * np.fft.rfft(g, size), size)[:n]


def simulate_fractional_frequency(osc: Oscillator, dt_s: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """Fractional frequency y averaged over each of n intervals of ``dt_s`` seconds, shape (n,)."""
    if not (dt_s > 0 and math.isfinite(dt_s)):
        raise CdgpsError(f"dt_s: expected a positive interval in seconds, got {dt_s!r}")
    if int(n) != n or n < 2:
        raise CdgpsError(f"n: expected an integer number of samples ≥ 2, got {n!r}")
    n = int(n)
    y = np.zeros(n)
    if osc.h0:
        y += math.sqrt(osc.h0 / (2 * dt_s)) * rng.standard_normal(n)
    if osc.h_m1:
        y += math.sqrt(math.pi * osc.h_m1) * _flicker(n, rng)
    if osc.h_m2:
        y += np.cumsum(math.sqrt(2 * math.pi**2 * osc.h_m2 * dt_s) * rng.standard_normal(n))
    return y


def simulate_time_error(osc: Oscillator, dt_s: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """Time error x (s) at n + 1 instants 0, Δt, …, nΔt (x₀ = 0): the running sum of y Δt."""
    y = simulate_fractional_frequency(osc, dt_s, n, rng)
    return np.concatenate([[0.0], np.cumsum(y) * dt_s])


def carrier_phase_noise_rad(osc: Oscillator, dt_s: float, n: int, rng: np.random.Generator,
                            carrier_hz: float = L1_HZ) -> np.ndarray:
    """Carrier phase error 2π f_carrier x (rad) at n + 1 instants spaced ``dt_s``."""
    return 2 * math.pi * carrier_hz * simulate_time_error(osc, dt_s, n, rng)


def pll_jitter_rad(osc: Oscillator, bn_hz: float, carrier_hz: float = L1_HZ, f_max_hz: float = 500.0) -> float:
    """Phase error (rad, 1σ) a second-order PLL of noise bandwidth ``bn_hz`` leaves from the oscillator:
    sqrt(∫ S_φ(f) |1 − H(j2πf)|² df) with S_φ(f) = f_c² (h0/f² + h−1/f³ + h−2/f⁴) (one-sided, rad²/Hz),
    from 1e-4 Hz to ``f_max_hz`` (half the 1 ms update rate).  For white FM alone this is
    π² f_c² h0 / (2 ζ ω_n) (tested)."""
    def integrand(log_f):
        f = math.exp(log_f)
        s_phi = carrier_hz**2 * (osc.h0 / f**2 + osc.h_m1 / f**3 + osc.h_m2 / f**4)
        return s_phi * abs(1 - pll2_response(f, bn_hz)) ** 2 * f
    return math.sqrt(quad(integrand, math.log(1e-4), math.log(f_max_hz), limit=400)[0])


def overlapping_allan_deviation(x_s: np.ndarray, dt_s: float, m: np.ndarray) -> np.ndarray:
    """Overlapping Allan deviation from time-error samples x (s) spaced ``dt_s``, at τ = m Δt.

    σ_y²(τ) = Σ_i (x_{i+2m} − 2 x_{i+m} + x_i)² / (2 τ² (N − 2m)) (Riley, NIST SP 1065, Eq. 11).
    """
    x = np.asarray(x_s, dtype=float)
    out = []
    for mm in np.atleast_1d(m).astype(int):
        if not 1 <= mm <= (x.size - 1) // 2:
            raise CdgpsError(f"averaging factor {mm}: expected 1 … {(x.size - 1) // 2} for {x.size} samples")
        d = x[2 * mm:] - 2 * x[mm:-mm] + x[:-2 * mm]
        out.append(math.sqrt(np.mean(d * d) / (2 * (mm * dt_s) ** 2)))
    return np.array(out)
