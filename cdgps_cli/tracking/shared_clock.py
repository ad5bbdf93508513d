"""Channels tracked together with a shared receiver-clock loop.

Every channel's carrier NCO runs at f_i = f_loop,i + f_aid,i + f_clk: its own loop's frequency, its
external Doppler aid (line-of-sight motion, :mod:`cdgps_cli.tracking.aiding`), and the clock
frequency f_clk that all channels share (Alban et al. 2003, Eq. 3: f_PLL = f_dopp + f_clk + f_noise).
After the FLL pull-in, per update:

* each channel's Costas discriminator gives e_i (rad);
* the common mode ē = Σ w_i e_i / Σ w_i drives the clock loop (second order, ``clock_bn_hz``), whose
  frequency is f_clk — the clock drift estimated from all channels at once (its thermal noise is that of
  one channel divided by the number of channels, for equal weights);
* each channel's own PLL is driven by e_i − ē, the part no other channel shares (the aiding error).

With identical channel loops the two are decoupled: the common mode of the channels' errors sees only
the clock loop, the differential modes only the channel loops.  So the channel loops can be narrow
(aided line-of-sight motion is slow) while the oscillator's phase noise — common to all channels — is
followed by the wider clock loop.  The code loops are as in :mod:`cdgps_cli.tracking.channel`.

A per-update Python loop over channels (the correlations compiled when the kernel is built).
"""

from __future__ import annotations

import math

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, CODE_LENGTH, ca_code
from cdgps_cli.tracking.channel import (L1_HZ, OUT_FIELDS, TrackOptions, dll_step, fll_step, initial_state, loop_params,
                      outputs_dict)
from cdgps_cli.tracking.correlator import correlate
from cdgps_cli.tracking.loops import LoopFilter


class SharedClockReceiver:
    """Channels and their shared clock loop; :meth:`run` consumes samples piece by piece.

    Parameters
    ----------
    fs_hz : float
    starts : sequence of (prn, doppler_hz, code_phase_chips)
        Acquisition of each channel (Doppler minus the first aid value when the aid is a full Doppler).
    opt : TrackOptions
        The channel loops (``pll_bn_hz`` is each channel's own bandwidth).
    clock_bn_hz : float
        Noise bandwidth of the shared (second-order) clock loop, Hz.
    weights : sequence of float, optional
        Per channel weight of the common mode (e.g. linear C/N0); equal if omitted.
    """

    def __init__(self, fs_hz: float, starts, opt: TrackOptions | None = None, *, clock_bn_hz: float = 15.0,
                 weights=None):
        self.opt = TrackOptions() if opt is None else opt
        self.starts = [(int(p), float(d), float(c)) for p, d, c in starts]
        nch = len(self.starts)
        if nch == 0:
            raise CdgpsError("shared clock: no channel to track")
        w = np.ones(nch) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != (nch,) or np.any(w < 0) or not w.sum() > 0:
            raise CdgpsError(f"weights: expected {nch} values ≥ 0, not all zero")
        self.w = w / w.sum()
        self.fs_hz = fs_hz
        self.par = loop_params(self.opt, fs_hz)
        self.n = int(self.par[0])
        self.T = self.n / fs_hz
        self.codes = [ca_code(p) for p, _, _ in self.starts]
        self.states = [initial_state(d, c) for _, d, c in self.starts]
        self.plls = [LoopFilter(float(self.par[4]), self.T, order=self.opt.pll_order) for _ in self.starts]
        self.fll = LoopFilter(self.opt.fll_bn_hz, self.T, order=1)
        self.dll = LoopFilter(self.opt.dll_bn_hz, self.T, order=1)
        self.clock = LoopFilter(clock_bn_hz, self.T, order=2)
        self.f_clk_hz = 0.0
        self.k = 0

    def run(self, samples: np.ndarray, aids=None) -> tuple[np.ndarray, np.ndarray]:
        """Track the whole 1 ms updates in ``samples`` (continuing from the previous call).

        Parameters
        ----------
        aids : sequence of (ndarray of shape (n_updates,) or None), optional
            Per channel, external Doppler per update of this piece (Hz).

        Returns
        -------
        rows : ndarray, shape (n_channels, n_updates, len(OUT_FIELDS))
        clock_doppler_hz : ndarray, shape (n_updates,)
            f_clk applied to each update.
        """
        nch, n, T, opt = len(self.starts), self.n, self.T, self.opt
        x = np.ascontiguousarray(samples, dtype=np.complex128)
        m = x.size // n
        aid = np.zeros((nch, m))
        for i, a in enumerate(aids or [None] * nch):
            if a is not None:
                a = np.asarray(a, dtype=float)
                if a.shape != (m,):
                    raise CdgpsError(f"aids[{i}]: expected one value per 1 ms update ({m}), got shape {a.shape}")
                aid[i] = a
        pull_in, narrow_at, bn_first, bn_final = int(self.par[2]), int(self.par[3]), float(self.par[4]), float(self.par[5])
        half = opt.spacing_chips / 2.0
        rows = np.zeros((nch, m, len(OUT_FIELDS)))
        f_clk = np.zeros(m)
        err = np.zeros(nch)
        prompts = [0j] * nch
        for j in range(m):
            k = self.k
            blk = x[j * n:(j + 1) * n]
            f_clk[j] = self.f_clk_hz
            for i, s in enumerate(self.states):
                f_now = s[1] + aid[i, j] + self.f_clk_hz
                code_rate = CHIP_RATE_HZ * (1.0 + f_now / L1_HZ)
                e, p, late = correlate(blk, self.codes[i], s[3], f_now, self.fs_hz, s[4], code_rate, half)
                err[i] = math.atan(p.imag / p.real) if p.real != 0 else 0.0
                rows[i, j] = (k * T, f_now, s[3], s[4] % CODE_LENGTH, p.real, p.imag, k >= pull_in, err[i])
                s[3] += f_now * T
                s[4] += code_rate * T
                dll_step(s, e, late, self.dll, opt.spacing_chips, T)
                prompts[i] = p
            if k < pull_in:
                for s, p in zip(self.states, prompts):
                    fll_step(s, p, self.fll, T)
            else:
                common = float(self.w @ err)
                self.f_clk_hz = self.clock.update(common) / (2 * math.pi)
                for s, pll, e_i in zip(self.states, self.plls, err):
                    pll.bn_hz = bn_final if 0 <= narrow_at <= k else bn_first
                    s[1] = s[2] + pll.update(e_i - common) / (2 * math.pi)
            for s, p in zip(self.states, prompts):
                s[5], s[6] = p.real, p.imag
                s[0] = k + 1
            self.k = k + 1
        return rows, f_clk


def track_shared_clock(samples: np.ndarray, fs_hz: float, starts, opt: TrackOptions | None = None, *,
                       clock_bn_hz: float = 15.0, aids=None, weights=None) -> dict:
    """Track several satellites with a shared clock loop (one call of :class:`SharedClockReceiver`).

    Returns
    -------
    dict
        ``tracks``: per channel the arrays of :func:`cdgps_cli.tracking.channel.track` (``doppler_hz`` is the
        NCO's total); ``clock_doppler_hz``: f_clk per update (Hz).
    """
    rx = SharedClockReceiver(fs_hz, starts, opt, clock_bn_hz=clock_bn_hz, weights=weights)
    rows, f_clk = rx.run(samples, aids)
    return {"tracks": [outputs_dict(r, fs_hz) for r in rows], "clock_doppler_hz": f_clk}
