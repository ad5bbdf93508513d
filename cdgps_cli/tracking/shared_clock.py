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

from ..errors import CdgpsError
from .ca_code import CHIP_RATE_HZ, CODE_LENGTH, ca_code
from .channel import L1_HZ, OUT_FIELDS, TrackOptions, initial_state, loop_params, outputs_dict
from .correlator import correlate
from .loops import LoopFilter


def track_shared_clock(samples: np.ndarray, fs_hz: float, starts, opt: TrackOptions | None = None, *,
                       clock_bn_hz: float = 15.0, aids=None, weights=None) -> dict:
    """Track several satellites with a shared clock loop.

    Parameters
    ----------
    samples : ndarray, complex, shape (N,)
    fs_hz : float
    starts : sequence of (prn, doppler_hz, code_phase_chips)
        Acquisition of each channel (Doppler minus the first aid value when the aid is a full Doppler).
    opt : TrackOptions
        The channel loops (``pll_bn_hz`` is each channel's own bandwidth).
    clock_bn_hz : float
        Noise bandwidth of the shared clock loop, Hz.
    aids : sequence of (ndarray of shape (n_updates,) or None), optional
        Per channel, external Doppler per update (Hz).
    weights : sequence of float, optional
        Per channel weight of the common mode (e.g. linear C/N0); equal if omitted.

    Returns
    -------
    dict
        ``tracks``: per channel the arrays of :func:`cdgps_cli.tracking.channel.track` (``doppler_hz`` is the
        NCO's total); ``clock_doppler_hz``: f_clk per update (Hz).
    """
    opt = TrackOptions() if opt is None else opt
    starts = list(starts)
    nch = len(starts)
    if nch == 0:
        raise CdgpsError("track_shared_clock: no channel to track")
    par = loop_params(opt, fs_hz)
    n, pull_in, narrow_at = int(par[0]), int(par[2]), int(par[3])
    T = n / fs_hz
    m = samples.size // n
    aid = np.zeros((nch, m))
    for i, a in enumerate(aids or [None] * nch):
        if a is not None:
            a = np.asarray(a, dtype=float)
            if a.shape != (m,):
                raise CdgpsError(f"aids[{i}]: expected one value per 1 ms update ({m}), got shape {a.shape}")
            aid[i] = a
    w = np.ones(nch) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (nch,) or np.any(w < 0) or not w.sum() > 0:
        raise CdgpsError(f"weights: expected {nch} values ≥ 0, not all zero")
    w = w / w.sum()
    codes = [ca_code(int(s[0])) for s in starts]
    st = [initial_state(s[1], s[2]) for s in starts]
    pll = [LoopFilter(float(par[4]), T, order=opt.pll_order) for _ in starts]
    fll = LoopFilter(opt.fll_bn_hz, T, order=1)
    dll = LoopFilter(opt.dll_bn_hz, T, order=1)
    clock = LoopFilter(clock_bn_hz, T, order=2)
    f_clk = np.zeros(m)
    out = np.zeros((nch, m, len(OUT_FIELDS)))
    half = opt.spacing_chips / 2.0
    f_c = 0.0
    err = np.zeros(nch)
    for k in range(m):
        x = samples[k * n:(k + 1) * n]
        f_clk[k] = f_c
        prompts = []
        for i in range(nch):
            s = st[i]
            f_now = s[1] + aid[i, k] + f_c
            code_rate = CHIP_RATE_HZ * (1.0 + f_now / L1_HZ)
            e, p, late = correlate(x, codes[i], s[3], f_now, fs_hz, s[4], code_rate, half)
            err[i] = math.atan(p.imag / p.real) if p.real != 0 else 0.0
            out[i, k] = (k * T, f_now, s[3], s[4] % CODE_LENGTH, p.real, p.imag, k >= pull_in, err[i])
            s[3] += f_now * T
            s[4] += code_rate * T
            ea, la = abs(e), abs(late)
            if ea + la > 0:
                s[4] += dll.update((ea - la) / (ea + la) * (2.0 - opt.spacing_chips) / 2.0) * T
            prompts.append(p)
        if k < pull_in:
            for i, p in enumerate(prompts):
                s = st[i]
                if not math.isnan(s[5]):
                    cross = s[5] * p.imag - s[6] * p.real
                    dot = s[5] * p.real + s[6] * p.imag
                    s[1] += fll.update(math.atan(cross / dot) / (2 * math.pi * T) if dot != 0 else 0.0) * T
                s[2] = s[1]
        else:
            common = float(w @ err)
            f_c = clock.update(common) / (2 * math.pi)
            for i in range(nch):
                pll[i].bn_hz = float(par[5]) if 0 <= narrow_at <= k else float(par[4])
                st[i][1] = st[i][2] + pll[i].update(err[i] - common) / (2 * math.pi)
        for i, p in enumerate(prompts):
            st[i][5], st[i][6] = p.real, p.imag
    return {"tracks": [outputs_dict(out[i], fs_hz) for i in range(nch)], "clock_doppler_hz": f_clk}
