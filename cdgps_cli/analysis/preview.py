"""Anti-aliased decimation of the estimated motion for the Foxglove preview channels of STATES.mcap.

The JSON channels Foxglove plots carry every ``stride``-th epoch (the packed arrays keep every
epoch).  Taking every ``stride``-th sample of a signal folds everything above the preview's Nyquist
frequency onto a false one below it: the 120 m tower's 1.638 Hz mode at 1 Hz showed at 0.362 Hz.
Here the series is low-pass filtered first, then decimated:

* a linear-phase FIR (Kaiser window, the design of :func:`scipy.signal.firwin` / :func:`scipy.signal.kaiserord`,
  written here without importing scipy.signal)
  with its passband up to :data:`PASSBAND_FRACTION` of the preview's Nyquist frequency and at least
  :data:`STOPBAND_DB` dB attenuation from that Nyquist frequency on;
* applied centred on each kept epoch (zero phase: the filter's delay of (taps − 1)/2 samples is
  taken out), so a peak stays at its time stamp and the preview lines up with every other channel;
  a causal filter would draw each oscillation about half a second late.  Being an FIR of finite
  length, the same result can be computed block by block with (taps − 1)/2 epochs of look-ahead;
* computed only at the kept epochs (what :func:`scipy.signal.upfirdn` computes), with the first and last values
  repeated beyond the ends of the record (and of each run of complete epochs between missing ones).

:func:`preview_stride_for_modes` picks the stride from the structure's highest mode, so that the
mode lies inside the passband and is shown at its own frequency.
"""

from __future__ import annotations

import functools
import math

import numpy as np

PASSBAND_FRACTION = 0.8
"""Passband edge of the preview filter as a fraction of the preview's Nyquist frequency."""
STOPBAND_DB = 60.0
"""Minimum attenuation of the preview filter from the preview's Nyquist frequency on, dB."""


def preview_stride_for_modes(sample_period_s: float, mode_frequency_hz, max_stride: int) -> int:
    """The largest stride (≤ ``max_stride``, ≥ 1) whose preview passband holds the highest mode.

    Parameters
    ----------
    sample_period_s : float
        Epoch spacing of the estimate, s.
    mode_frequency_hz : array_like
        The model's mode frequencies, Hz.
    max_stride : int
        The stride of the default preview rate (never fewer previews than that).

    Returns
    -------
    int
        ``stride`` with ``PASSBAND_FRACTION · fs / (2 · stride) ≥ f_max`` (fs = 1 / sample period).
    """
    f = np.asarray(mode_frequency_hz, dtype=float)
    f = f[np.isfinite(f) & (f > 0)]
    if f.size == 0 or not sample_period_s > 0:
        return max(int(max_stride), 1)
    fit = math.floor(PASSBAND_FRACTION / (2.0 * float(f.max()) * sample_period_s) + 1e-9)
    return max(min(fit, int(max_stride)), 1)


@functools.lru_cache(maxsize=16)
def preview_filter(stride: int) -> np.ndarray:
    """Taps of the preview low-pass filter for decimation by ``stride`` (odd length 2·m·stride + 1);
    designed once per stride (read-only: every run between gaps shares it)."""
    taps = _design(stride)
    taps.flags.writeable = False
    return taps


def _design(stride: int) -> np.ndarray:
    """The windowed-sinc design of ``scipy.signal.firwin`` / ``kaiserord`` (Kaiser's formulas, Oppenheim &
    Schafer), written here so that ``cdgps estimate`` does not import scipy.signal (≈ 0.4 s of a
    process) nor scipy.special (numpy's i0 for the Kaiser window); equal to scipy's taps to ~1e-16
    (tests/io/test_states_preview.py)."""
    nyq = 1.0 / stride                                  # preview Nyquist, in units of the input's
    width = (1.0 - PASSBAND_FRACTION) * nyq
    A = STOPBAND_DB                                     # kaiserord: taps and β for this attenuation
    beta = 0.1102 * (A - 8.7) if A > 50 else (0.5842 * (A - 21) ** 0.4 + 0.07886 * (A - 21) if A > 21 else 0.0)
    numtaps = int(math.ceil((A - 7.95) / 2.285 / (math.pi * width) + 1))
    m = max(math.ceil((numtaps - 1) / (2 * stride)), 1)
    L = 2 * m * stride + 1
    cutoff = (1.0 + PASSBAND_FRACTION) / 2 * nyq        # low-pass edge, Nyquist = 1
    n = np.arange(L, dtype=float) - 0.5 * (L - 1)
    h = cutoff * np.sinc(cutoff * n)
    alpha = (L - 1) / 2.0
    h = h * (np.i0(beta * np.sqrt(1 - ((np.arange(L) - alpha) / alpha) ** 2.0)) / np.i0(beta))
    return h / np.sum(h)                                # unit gain at zero frequency


PREVIEW_BLOCK_EPOCHS = 16384
"""Epochs read at a time by :func:`anti_alias_decimate` (its memory does not grow with the record)."""


def anti_alias_decimate(x, stride: int, block_epochs: int = PREVIEW_BLOCK_EPOCHS) -> np.ndarray:
    """Low-pass filter ``x`` along its first axis and keep epochs 0, stride, 2·stride, …

    Parameters
    ----------
    x : ndarray (N, ...) or array-like
        A series sampled at constant spacing.  Epochs with a NaN keep their value; each run of
        complete epochs between them is filtered on its own (no NaN spreads over the filter's length).
        Only ``x.shape`` and row slices ``x[a:b]`` are used, a block of ``block_epochs`` rows at a
        time, so ``x`` may be a series on disk or computed block by block (issue 29).
    stride : int
        Keep every ``stride``-th epoch (1: ``x`` unchanged).
    block_epochs : int
        Rows read at a time (the result does not depend on it: each kept epoch is the same sum of
        the same products in any cutting).

    Returns
    -------
    ndarray (ceil(N / stride), ...)
        The filtered series at the kept epochs (zero phase).
    """
    n = x.shape[0]
    step = max(-(-int(block_epochs) // max(stride, 1)), 1) * max(stride, 1)     # whole strides per block
    if stride <= 1 or n == 0:
        return np.concatenate([np.array(x[a:a + step], dtype=float) for a in range(0, n, step)]) if n else \
            np.array(x[0:0], dtype=float)
    out = np.empty((len(range(0, n, stride)),) + tuple(x.shape[1:]))
    finite = np.empty(n, dtype=bool)
    for a in range(0, n, step):                          # epochs with a missing value: as they are
        rows = np.asarray(x[a:a + step], dtype=float)
        out[a // stride:a // stride + len(range(0, rows.shape[0], stride))] = rows[::stride]
        finite[a:a + rows.shape[0]] = np.isfinite(rows.reshape(rows.shape[0], -1)).all(axis=1)
    edges = np.flatnonzero(np.diff(np.r_[0, finite.astype(np.int8), 0]))
    for a, b in zip(edges[::2], edges[1::2]):            # each run of complete epochs on its own
        k0 = -(-a // stride) * stride                    # its first kept epoch
        if k0 < b:
            _filter_run(x, k0, b, stride, out, step // stride)
    return out


def _filter_run(x, k0: int, b: int, stride: int, out: np.ndarray, per_block: int) -> None:
    """Rows k0 … b−1 of ``x`` (NaN-free) filtered into ``out`` at their kept epochs, ``per_block``
    kept epochs at a time.  The run's ends are repeated beyond it: kept epoch j of the run is
    y_j = Σ_t h_t · padded[j·stride + 2·half − t], padded[p] = x[k0 + clip(p − half, 0, L − 1)] (what
    :func:`scipy.signal.upfirdn` (h, padded, down=stride) gives from its output 2·half/stride on), and
    each block of kept epochs reads exactly the padded rows it needs (the same terms in the same order
    as over the whole run)."""
    h = preview_filter(stride)
    half = (h.size - 1) // 2                             # a multiple of stride
    L = b - k0
    J = len(range(0, L, stride))
    step = max(per_block, 1)
    for j0 in range(0, J, step):
        j1 = min(j0 + step, J)
        p = np.arange(j0 * stride, (j1 - 1) * stride + 2 * half + 1)
        idx = np.clip(p - half, 0, L - 1)
        lo, hi = int(idx[0]), int(idx[-1]) + 1
        rows = np.asarray(x[k0 + lo:k0 + hi], dtype=float)[idx - lo]
        flat = rows.reshape(rows.shape[0], -1)
        win = np.lib.stride_tricks.sliding_window_view(flat, h.size, axis=0)[::stride][:j1 - j0]  # (n, C, taps), a view
        y = np.einsum("bct,t->bc", win, h[::-1])
        out[k0 // stride + j0:k0 // stride + j1] = y.reshape((j1 - j0,) + rows.shape[1:])
