"""Unflagged cycle slips: a step in one channel's residuals that its lock indicator did not report.

A slip the receiver did not flag adds k·λ (k a whole or, with a half-cycle ambiguity, a half
number of cycles) to every later phase of the channel.  A batch fit that gives the channel one
bias for the whole lock segment cannot follow it: the channel's residuals keep a step of nearly
the slip's size (the other channels hold the structure's state), split around the segment's mean.

:func:`residual_steps` finds such a step per channel with a local two-sample test: at every epoch
k of a contiguous stretch of one bias segment, the mean of up to ``half_width`` residuals from k on
minus the mean of up to ``half_width`` before k, divided by its standard deviation under white
noise.  The channel's noise σ is estimated robustly from its first differences (median absolute
deviation): a step is one difference among hundreds, and slow multipath barely moves the
differences.  A step is reported when both

* its z value exceeds ``z_min`` (white noise alone: the largest of a few thousand correlated
  normal values stays below ≈ 5), and
* its size is at least ``min_cycles`` of a wavelength (a quarter cycle by default: half the
  smallest slip; time-correlated multipath of a few centimetres does not jump that far within the
  test's few seconds).

The largest such step per stretch is returned; the caller splits the segment there, refits and
looks again (several slips on one channel are found one per round).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdgps_cli.measurement.multipath import segment_stretches

#: the test's half width (s): residuals on each side of a candidate epoch
STEP_HALF_WIDTH_S = 2.0
#: z value a step must exceed
STEP_Z_MIN = 6.0
#: … and its size, in cycles (half the smallest slip, a half cycle)
STEP_MIN_CYCLES = 0.25


@dataclass(frozen=True)
class ResidualStep:
    """A step in one channel's residuals: the first epoch after it and its size."""

    channel: int        # column of the residual matrix
    epoch: int          # row index of the first epoch after the step
    step_m: float       # mean after − mean before (m)
    z: float            # step / its σ under white noise
    sigma_m: float      # the channel's robust white-noise σ (m)


def robust_sigma(e: np.ndarray) -> float:
    """White-noise σ (m) of a residual stretch from its first differences (1.4826 × MAD / √2)."""
    d = np.diff(e)
    if d.size < 2:
        return float("nan")
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def local_steps(e: np.ndarray, half_width: int) -> tuple[np.ndarray, np.ndarray]:
    """(step, scale) for every split k = 1 … L−1 of a stretch ``e`` (L,): step = mean(e[k:k+w]) −
    mean(e[k−w:k]) and scale = sqrt(1/n_before + 1/n_after), w = ``half_width`` (fewer at the ends)."""
    L = e.size
    cs = np.r_[0.0, np.cumsum(e)]
    k = np.arange(1, L)
    lo, hi = np.maximum(k - half_width, 0), np.minimum(k + half_width, L)
    nb, na = k - lo, hi - k
    step = (cs[hi] - cs[k]) / na - (cs[k] - cs[lo]) / nb
    return step, np.sqrt(1.0 / nb + 1.0 / na)


def residual_steps(resid: np.ndarray, segment: np.ndarray, wavelength_m: float, dt_s: float,
                   z_min: float = STEP_Z_MIN, min_cycles: float = STEP_MIN_CYCLES,
                   half_width_s: float = STEP_HALF_WIDTH_S) -> list[ResidualStep]:
    """The largest significant step of each contiguous stretch of one bias segment per channel.

    Parameters
    ----------
    resid : ndarray (N, C)
        Residuals of a batch fit (m), NaN where a channel has no phase.
    segment : ndarray (N, C)
        Bias-segment index of each residual (−1: none).
    wavelength_m : float
        Carrier wavelength (m).
    dt_s : float
        Epoch interval (s).
    z_min, min_cycles, half_width_s : float
        The test's thresholds and half width (module constants by default).

    Returns
    -------
    list of ResidualStep
        By channel, then epoch.
    """
    w = max(int(round(half_width_s / dt_s)), 2)
    out = []
    for c, a, b in segment_stretches(resid, segment, 3):
        e = resid[a:b, c]
        sig = robust_sigma(e)
        if not (np.isfinite(sig) and sig > 0):
            continue
        step, scale = local_steps(e, w)
        z = step / (sig * scale)
        cand = np.abs(step) >= min_cycles * wavelength_m
        if not cand.any():
            continue
        j = int(np.argmax(np.where(cand, np.abs(z), -np.inf)))
        if abs(z[j]) >= z_min:
            out.append(ResidualStep(c, a + j + 1, float(step[j]), float(z[j]), sig))
    return out
