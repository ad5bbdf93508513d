"""Navigation-bit synchronization of a tracked channel (histogram method; Kaplan & Hegarty Sec. 5.10).

The 50 bit/s data bits change only at a C/A code epoch, every 20 code periods.  The channel's 1 ms
updates are not aligned to the code epochs: a sign change of the prompt I between updates k − 1 and
k means a bit edge at the code epoch inside block k − 1 or the one inside block k.  An epoch in the
first quarter of its block gives the block the new bit's sign (the edge is in block k), one in the
last quarter the old sign (block k − 1); near mid-block the noise decides, and the block holding the
edge is the one whose |I| is smaller (|1 − 2f| of full amplitude for an edge at fraction f).  Each
change votes for the epoch so chosen, numbered modulo 20 code periods (the code phase at each block
start is known); the edge is the number with the most votes, its time that of the first change agreeing
with it (by either of its two candidate epochs) carried back by whole bits, and the share of changes
agreeing measures the consistency (noise changes the sign of a locked 1 ms I rarely above 35 dB-Hz,
where amplitude/σ ≈ 2.5).
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.constants import GPS_L1_HZ
from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, CODE_LENGTH

#: code periods per navigation bit
PERIODS_PER_BIT = 20
#: sign changes needed before a bit edge is reported
MIN_CHANGES = 3


def bit_sync(out: dict) -> dict:
    """Bit edge of one channel from :func:`cdgps_cli.tracking.channel.track`'s outputs.

    Parameters
    ----------
    out : dict
        ``i_prompt``, ``pll`` (bool), ``time_s`` (block starts, s), ``code_phase_chips`` (at the block
        starts, chips mod 1023), ``doppler_hz``; arrays of shape (n_updates,).

    Returns
    -------
    dict
        ``bit_edge_s``: time of the first bit edge (s from the first sample, in [0, one bit ≈ 0.02)), or None when
        fewer than :data:`MIN_CHANGES` sign changes were seen; ``bit_changes``: sign changes counted;
        ``bit_sync_fraction``: the share of them at the dominant code epoch (of the 20 in a bit).
    """
    i = np.asarray(out["i_prompt"], dtype=float)
    flips = sign_changes(i, np.asarray(out["pll"], dtype=bool))
    return bit_sync_at(i[flips - 1], i[flips], *(np.asarray(out[k], dtype=float)[flips]
                                                  for k in ("time_s", "doppler_hz", "code_phase_chips")))


def sign_changes(i_prompt: np.ndarray, pll: np.ndarray) -> np.ndarray:
    """Indices k of the updates whose prompt I changes sign from update k − 1, both with the PLL running."""
    return np.flatnonzero(pll[1:] & pll[:-1] & (np.sign(i_prompt[1:]) * np.sign(i_prompt[:-1]) < 0)) + 1


def bit_sync_at(i_before: np.ndarray, i_at: np.ndarray, time_s: np.ndarray, doppler_hz: np.ndarray,
                code_phase_chips: np.ndarray) -> dict:
    """:func:`bit_sync` from the sign changes alone: at each change k (:func:`sign_changes`), the prompt I
    of updates k − 1 and k, and update k's start time (s), Doppler (Hz) and code phase (chips); shapes (n,)."""
    t = np.asarray(time_s, dtype=float)
    if t.size < MIN_CHANGES:
        return {"bit_edge_s": None, "bit_changes": int(t.size), "bit_sync_fraction": None}
    rate = CHIP_RATE_HZ * (1.0 + doppler_hz / GPS_L1_HZ)
    period_s = CODE_LENGTH / rate
    later = t + (CODE_LENGTH - code_phase_chips % CODE_LENGTH) / rate
    cand = np.stack([later - period_s, later], axis=1)                    # the epochs in blocks k − 1 and k
    count = np.r_[0, np.cumsum(np.round(np.diff(later) / period_s[1:]))].astype(np.int64)   # epochs since the first
    idx = np.stack([count - 1, count], axis=1) % PERIODS_PER_BIT
    frac = (later - t) / period_s                                          # where block k's epoch falls in it
    weak_before = np.abs(i_before) < np.abs(i_at)                          # the transition block is the weaker one
    pick = np.where(frac > 0.75, 0, np.where(frac < 0.25, 1, np.where(weak_before, 0, 1)))
    best = int(np.argmax(np.bincount(idx[np.arange(t.size), pick], minlength=PERIODS_PER_BIT)))
    near = (idx == best).any(axis=1)
    first = int(np.flatnonzero(near)[0])
    edge = cand[first, 1] if idx[first, 1] == best else cand[first, 0]
    bit_s = PERIODS_PER_BIT * period_s[first]                              # one bit at this channel's code rate
    return {"bit_edge_s": float(edge - bit_s * np.floor(edge / bit_s)), "bit_changes": int(t.size),
            "bit_sync_fraction": float(np.mean(near))}
