"""Min/max envelope decimation of long time series for plotting (pure numerics, no I/O).

A 24 h record at 10 Hz has 864,000 epochs; a figure 1,000 pixels wide shows at most 1,000 columns.
Drawing every epoch makes a slow, large PNG and shows nothing more: each pixel column can show only
the lowest and the highest value that falls in it.  :class:`EnvelopeBins` keeps exactly that, per
bin of consecutive epochs, fed one chunk of epochs at a time (so a record is never held whole), and
:func:`envelope_line` draws it as one polyline through (t, min), (t, max) of every bin, which covers
every extreme of the record.  With no more epochs than bins, every bin holds one epoch and the line is
the series itself.
"""

from __future__ import annotations

import numpy as np

#: bins across a figure's width (≈ its pixel columns at the report's size and resolution)
DEFAULT_BINS = 1000


class EnvelopeBins:
    """Per-bin minimum, maximum, sum and count of ``n_series`` series over ``n_epochs`` epochs.

    Epoch ``i`` (0-based, over the whole record) falls in bin ``i * n_bins // n_epochs``, so bins hold
    consecutive epochs, as equal in number as can be.  NaN values are ignored (a bin with none finite
    stays NaN).

    Parameters
    ----------
    n_epochs : int
        Epochs of the whole record (N).
    n_series : int
        Series fed together (columns of the blocks given to :meth:`add`).
    n_bins : int
        Bins wanted; fewer when ``n_epochs`` is smaller (one epoch per bin).
    """

    def __init__(self, n_epochs: int, n_series: int, n_bins: int = DEFAULT_BINS):
        if n_epochs < 1 or n_series < 0 or n_bins < 1:
            raise ValueError(f"n_epochs {n_epochs}, n_series {n_series}, n_bins {n_bins}: expected ≥ 1, ≥ 0, ≥ 1")
        self.n_epochs = int(n_epochs)
        self.n_bins = min(int(n_bins), self.n_epochs)
        self.lo = np.full((self.n_bins, n_series), np.nan)
        self.hi = np.full((self.n_bins, n_series), np.nan)
        self.band_lo = np.full((self.n_bins, n_series), np.nan)
        self.band_hi = np.full((self.n_bins, n_series), np.nan)
        self.sum = np.zeros((self.n_bins, n_series))
        self.count = np.zeros((self.n_bins, n_series), dtype=np.int64)
        self.t_first = np.full(self.n_bins, np.nan)
        self.t_last = np.full(self.n_bins, np.nan)

    def bin_of(self, start: int, k: int) -> np.ndarray:
        """Bin index of epochs ``start … start + k − 1``."""
        return (np.arange(start, start + k, dtype=np.int64) * self.n_bins) // self.n_epochs

    def add(self, start: int, time_s: np.ndarray, values: np.ndarray, low: np.ndarray | None = None,
            high: np.ndarray | None = None) -> None:
        """Feed epochs ``start … start + k − 1``: times (k,) and values (k, n_series).

        ``low`` / ``high`` (k, n_series), when given, are the lower and upper edges of a band
        about the values (e.g. value ∓ σ): their per-bin minimum / maximum go to ``band_lo`` /
        ``band_hi``.  ``lo`` / ``hi`` (per-bin extremes) and the sum and count (for :meth:`mean`) are
        always of ``values``."""
        values = np.asarray(values, dtype=float).reshape(len(time_s), -1)
        if len(time_s) == 0:
            return
        b = self.bin_of(start, len(time_s))
        cut = np.flatnonzero(np.diff(b)) + 1
        first = np.concatenate([[0], cut])
        ub = b[first]
        with np.errstate(invalid="ignore"), _quiet():
            lo = np.fmin.reduceat(values, first, axis=0)
            hi = np.fmax.reduceat(values, first, axis=0)
            if low is not None:
                blo = np.fmin.reduceat(np.asarray(low, dtype=float).reshape(values.shape), first, axis=0)
                bhi = np.fmax.reduceat(np.asarray(high, dtype=float).reshape(values.shape), first, axis=0)
                self.band_lo[ub] = np.fmin(self.band_lo[ub], blo)
                self.band_hi[ub] = np.fmax(self.band_hi[ub], bhi)
        finite = np.isfinite(values)
        s = np.add.reduceat(np.where(finite, values, 0.0), first, axis=0)
        c = np.add.reduceat(finite.astype(np.int64), first, axis=0)
        self.lo[ub] = np.fmin(self.lo[ub], lo)
        self.hi[ub] = np.fmax(self.hi[ub], hi)
        self.sum[ub] += s
        self.count[ub] += c
        t = np.asarray(time_s, dtype=float)
        last = np.concatenate([cut - 1, [len(t) - 1]])
        self.t_first[ub] = np.where(np.isnan(self.t_first[ub]), t[first], self.t_first[ub])
        self.t_last[ub] = t[last]

    def mean(self) -> np.ndarray:
        """Per-bin mean of the finite values (n_bins, n_series); NaN where a bin has none."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.count > 0, self.sum / np.maximum(self.count, 1), np.nan)

    def centre_s(self) -> np.ndarray:
        """Per-bin time, s: the middle of its first and last epoch."""
        return 0.5 * (self.t_first + self.t_last)


class _quiet:
    """Silence numpy's all-NaN warnings inside a block (reduceat of fmin/fmax warns on none)."""

    def __enter__(self):
        import warnings

        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *exc):
        self._w.__exit__(*exc)


def minmax_envelope(time_s: np.ndarray, y: np.ndarray, n_bins: int = DEFAULT_BINS):
    """The envelope of one series held in memory: ``(t (B,), low (B,), high (B,))``.

    The same numbers as feeding :class:`EnvelopeBins` chunk by chunk (any chunking)."""
    y = np.asarray(y, dtype=float)
    env = EnvelopeBins(len(y), 1, n_bins)
    env.add(0, np.asarray(time_s, dtype=float), y[:, None])
    return env.centre_s(), env.lo[:, 0], env.hi[:, 0]


def envelope_line(t: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One polyline through every bin's extremes, ``(x (2B,), y (2B,))``: (t₀, low₀), (t₀, high₀),
    (t₁, low₁), …; a bin with one epoch (low = high) gives the series itself."""
    x = np.repeat(np.asarray(t, dtype=float), 2)
    y = np.column_stack([low, high]).ravel()
    return x, y
