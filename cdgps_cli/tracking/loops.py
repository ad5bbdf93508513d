"""Carrier and code loop filters (Alban et al. 2003, Sec. II; Kaplan & Hegarty, Ch. 5).

A PLL with the NCO as integrator (1/s) and the loop filter F(s) = K1 (τ1 s + 1)/s has the closed
loop H(s) = K1 (τ1 s + 1) / (s² + K1 τ1 s + K1): ω_n² = K1, 2 ζ ω_n = K1 τ1, and the one-sided
noise bandwidth

    B_n = ∫₀^∞ |H(j2πf)|² df = (K1 τ1 + 1/τ1) / 4 = (ω_n / 2)(ζ + 1/(4ζ))   (Hz).

The third-order loop uses F(s) = b3 ω0 + a3 ω0²/s + ω0³/s² with a3 = 1.1, b3 = 2.4 and
B_n = 0.7845 ω0 (Kaplan Table 5.6).  Discrete filters integrate with the trapezoidal rule at the
update period T; they are valid for B_n T ≪ 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from cdgps_cli.core.errors import CdgpsError

#: damping of the second-order loops
ZETA = 1.0 / math.sqrt(2.0)
#: third-order loop constants (Kaplan & Hegarty, Table 5.6)
A3, B3, BN_OVER_W0_3 = 1.1, 2.4, 0.7845


def pll2_gains(bn_hz: float, zeta: float = ZETA) -> tuple[float, float]:
    """(K1 in 1/s², τ1 in s) of the paper's F(s) = K1(τ1 s + 1)/s for noise bandwidth ``bn_hz``."""
    if not (bn_hz > 0 and zeta > 0):
        raise CdgpsError(f"loop bandwidth and damping must be positive, got {bn_hz!r} Hz, ζ = {zeta!r}")
    wn = 2.0 * bn_hz / (zeta + 1.0 / (4.0 * zeta))
    return wn * wn, 2.0 * zeta / wn


def pll2_bandwidth_hz(k1: float, tau1: float) -> float:
    """Noise bandwidth B_n (Hz) of the loop with F(s) = K1(τ1 s + 1)/s: (K1 τ1 + 1/τ1)/4."""
    return (k1 * tau1 + 1.0 / tau1) / 4.0


def pll2_response(f_hz, bn_hz: float, zeta: float = ZETA) -> np.ndarray:
    """Closed-loop response H(j2πf) = K1(τ1 s + 1)/(s² + K1τ1 s + K1) of the continuous second-order loop."""
    k1, tau1 = pll2_gains(bn_hz, zeta)
    s = 2j * np.pi * np.asarray(f_hz, dtype=float)
    return k1 * (tau1 * s + 1) / (s * s + k1 * tau1 * s + k1)


@dataclass
class LoopFilter:
    """Discrete loop filter: error (rad, or chips) per update → frequency command (rad/s, chips/s).

    ``order`` 2: F(s) = K1(τ1 s + 1)/s; ``order`` 3: F(s) = b3 ω0 + a3 ω0²/s + ω0³/s²;
    ``order`` 1: F(s) = 4 B_n (a first-order loop, e.g. the DLL).
    """

    bn_hz: float
    period_s: float
    order: int = 2
    _i1: float = field(default=0.0, repr=False)
    _i2: float = field(default=0.0, repr=False)
    _e1: float = field(default=0.0, repr=False)
    _y1: float = field(default=0.0, repr=False)

    def __post_init__(self):
        if self.order not in (1, 2, 3):
            raise CdgpsError(f"loop order: expected 1, 2 or 3, got {self.order!r}")
        if not (self.bn_hz > 0 and self.period_s > 0):
            raise CdgpsError(f"loop: bandwidth and period must be positive, got {self.bn_hz!r} Hz, {self.period_s!r} s")

    def reset(self, integrator: float = 0.0) -> None:
        """Clear the state; ``integrator`` presets the (first) integrator, e.g. a frequency from the FLL."""
        self._i1, self._i2, self._e1, self._y1 = integrator, 0.0, 0.0, 0.0

    def update(self, error: float) -> float:
        """One update with the discriminator output; returns the command (error units per second)."""
        T = self.period_s
        if self.order == 1:
            return 4.0 * self.bn_hz * error
        if self.order == 2:
            k1, tau1 = pll2_gains(self.bn_hz)
            self._i1 += 0.5 * T * k1 * (error + self._e1)              # ∫ K1 e dt (trapezoid)
            self._e1 = error
            return k1 * tau1 * error + self._i1
        w0 = self.bn_hz / BN_OVER_W0_3
        y = A3 * w0 * w0 * error
        self._i2 += 0.5 * T * w0**3 * (error + self._e1)               # ω0³ ∫ e
        self._i1 += 0.5 * T * (y + self._i2 + self._y1)                # ∫ (a3 ω0² e + ω0³ ∫e)
        self._y1 = y + self._i2
        self._e1 = error
        return B3 * w0 * error + self._i1
