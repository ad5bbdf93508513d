"""Acquire and track every satellite strong enough in a block of samples (a multi-channel receiver).

:func:`track_all` tracks an array of samples held in memory; :func:`track_stream` the same recording
given as its first samples (for the acquisition) and an iterable of consecutive pieces of any length
(:class:`BlockTracker`), so a file of any length is tracked in bounded memory.  Both give the same
numbers exactly: every channel's loop state is carried from one piece to the next and an update that
straddles two pieces is run once both are there.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.tracking.acquisition import FALSE_ALARM, NONCOHERENT_MS, acquire
from cdgps_cli.tracking.bitsync import bit_sync, bit_sync_at, sign_changes
from cdgps_cli.tracking.channel import (OUT_FIELDS, PHASE_LOCK_THRESHOLD, WINDOW, TrackOptions, initial_state,
                                        outputs_dict, run_updates, track)
from cdgps_cli.tracking.shared_clock import SharedClockReceiver

#: fraction of the PLL's 20 ms windows (after one settling window) whose lock indicator must pass
#: for a satellite to count as in phase lock
LOCKED_FRACTION = 0.9


def track_all(samples: np.ndarray, fs_hz: float, prns=None, *, if_hz: float = 0.0, false_alarm: float = FALSE_ALARM,
              noncoherent_ms: int = NONCOHERENT_MS,
              opt: TrackOptions | None = None, progress=None, aids=None) -> dict:
    """Acquire ``prns`` (default 1–32) and track each acquired one.

    ``aids`` (optional) maps a PRN to its external Doppler per 1 ms update (Hz; e.g.
    :func:`cdgps_cli.tracking.aiding.los_doppler_hz` at the update times, or a structure simulation's
    line-of-sight velocity over λ): fed forward to that channel's NCO, its loop starting from the
    acquired Doppler minus the first aid value.  An aid for a PRN that is not acquired is an error.

    Returns
    -------
    dict
        ``acquisition`` (every PRN searched), ``satellites`` (summary per tracked PRN: ``prn``,
        ``doppler_hz`` (mean of the last 100 ms), ``code_phase_chips`` (acquisition, at the first sample),
        ``cn0_dbhz`` (median of the last five 20 ms windows), ``phase_lock`` (bool) and
        ``phase_lock_fraction``, the navigation-bit edge of :func:`cdgps_cli.tracking.bitsync.bit_sync`:
        ``bit_edge_s``, ``bit_changes``, ``bit_sync_fraction``) and ``tracks`` (per PRN, the arrays of :func:`cdgps_cli.tracking.channel.track`).
    """
    opt = TrackOptions() if opt is None else opt
    say = progress or (lambda m: None)
    acq, found, aids = _acquired(samples, fs_hz, prns, if_hz, false_alarm, noncoherent_ms, aids)
    baseband = to_baseband(samples, fs_hz, if_hz)
    tracks, sats = {}, []
    for a in found:
        say(f"tracking PRN {a.prn} ({a.doppler_hz:+.0f} Hz, peak {a.peak_to_noise:.1f} × noise) …")
        aid = aids.get(a.prn)
        r = track(baseband, fs_hz, a.prn, _start_hz(a, aid), a.code_phase_chips, opt, aid_doppler_hz=aid)
        tracks[a.prn] = r
        sats.append(_summary(a, r))
    return {"acquisition": [a.__dict__ for a in acq], "satellites": sats, "tracks": tracks}


def track_stream(head: np.ndarray, blocks, fs_hz: float, prns=None, *, n_samples: int, if_hz: float = 0.0,
                 false_alarm: float = FALSE_ALARM, noncoherent_ms: int = NONCOHERENT_MS,
                 opt: TrackOptions | None = None, progress=None, aids=None) -> dict:
    """:func:`track_all` of a recording of ``n_samples`` samples given in pieces; the same result exactly.

    Parameters
    ----------
    head : ndarray, shape (≥ noncoherent_ms ms of samples,)
        The recording's first samples: the acquisition searches these.
    blocks : iterable of ndarray
        The whole recording, from its first sample, as consecutive pieces of any lengths (e.g.
        :func:`cdgps_cli.io.iq_samples.iter_samples`); the pieces are tracked as they come.
    n_samples : int
        The recording's length (samples): sizes the outputs and the aids (one value per 1 ms update).
    """
    opt = TrackOptions() if opt is None else opt
    say = progress or (lambda m: None)
    acq, found, aids = _acquired(head, fs_hz, prns, if_hz, false_alarm, noncoherent_ms, aids)
    say("tracking PRN " + ", ".join(f"{a.prn} ({a.doppler_hz:+.0f} Hz, peak {a.peak_to_noise:.1f} × noise)"
                                    for a in found) + " …")
    rx = BlockTracker(fs_hz, [(a.prn, _start_hz(a, aids.get(a.prn)), a.code_phase_chips) for a in found], opt,
                      n_samples=n_samples, if_hz=if_hz, aids=[aids.get(a.prn) for a in found])
    for blk in blocks:
        rx.feed(blk)
    tracks = dict(zip([a.prn for a in found], rx.results()))
    return {"acquisition": [a.__dict__ for a in acq], "satellites": [_summary(a, tracks[a.prn]) for a in found],
            "tracks": tracks}


def check_prns(prns) -> list[int]:
    """The PRNs asked for, as a list: whole numbers 1-32, each once (else CdgpsError naming ``prns``)."""
    out = list(prns)
    bad = [p for p in out if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or not 1 <= p <= 32]
    if bad:
        raise CdgpsError(f"prns {bad[0]!r}: expected GPS PRNs, whole numbers 1-32")
    twice = sorted({p for p in out if out.count(p) > 1})
    if twice:
        raise CdgpsError(f"prns: PRN {', '.join(map(str, twice))} given twice")
    return out


def track_stream_to(sink, head: np.ndarray, blocks, fs_hz: float, prns=None, *, n_samples: int,
                    if_hz: float = 0.0, false_alarm: float = FALSE_ALARM, noncoherent_ms: int = NONCOHERENT_MS,
                    opt: TrackOptions | None = None, progress=None) -> dict:
    """:func:`track_stream` without keeping the outputs: they are handed to ``sink`` 20 ms window by window.

    ``sink(prns, columns)`` is called with the acquired PRNs (acquisition order) and, per channel, the
    arrays of :func:`cdgps_cli.tracking.channel.track` of the next whole 20 ms windows (the last call:
    the rest); concatenated over the calls they are :func:`track_stream`'s ``tracks`` exactly.  Memory
    does not grow with the recording.  Returns ``acquisition`` and ``satellites`` as :func:`track_all`.
    """
    opt = TrackOptions() if opt is None else opt
    say = progress or (lambda m: None)
    acq, found, _ = _acquired(head, fs_hz, prns, if_hz, false_alarm, noncoherent_ms, None)
    say("tracking PRN " + ", ".join(f"{a.prn} ({a.doppler_hz:+.0f} Hz, peak {a.peak_to_noise:.1f} × noise)"
                                    for a in found) + " …")
    rx = BlockTracker(fs_hz, [(a.prn, a.doppler_hz, a.code_phase_chips) for a in found], opt, n_samples=n_samples,
                      if_hz=if_hz, keep=False)
    summaries = [RunningSummary(a) for a in found]
    pending = np.zeros((len(found), 0, len(OUT_FIELDS)))
    for blk in blocks:
        pending = np.concatenate([pending, rx.feed(blk)], axis=1)
        whole = pending.shape[1] // WINDOW * WINDOW
        if whole:
            _hand_over(sink, found, summaries, pending[:, :whole], fs_hz)
            pending = pending[:, whole:]
    rx.check_complete()
    _hand_over(sink, found, summaries, pending, fs_hz)
    return {"acquisition": [a.__dict__ for a in acq], "satellites": [s.result() for s in summaries]}


def _hand_over(sink, found, summaries, rows: np.ndarray, fs_hz: float) -> None:
    cols = [outputs_dict(r, fs_hz) for r in rows]
    for s, c in zip(summaries, cols):
        s.add(c)
    sink([a.prn for a in found], cols)


class RunningSummary:
    """:func:`track_all`'s summary of one satellite, accumulated over consecutive pieces of its outputs
    (each starting on a 20 ms window boundary), keeping only what the summary needs: the last 100
    Dopplers, the last five windows' C/N0, lock-window counts and the prompt-I sign changes."""

    def __init__(self, acquisition):
        self.a = acquisition
        self.n = 0                                   # updates seen
        self.doppler = np.zeros(0)
        self.cn0 = np.zeros(0)
        self.lock_start = None                       # first update of the lock windows (PLL start + WINDOW)
        self.locked = self.windows = 0
        self.last = None                             # (i_prompt, pll) of the previous update
        self.flips = {k: [] for k in ("i_before", "i_at", "time_s", "doppler_hz", "code_phase_chips")}

    def add(self, r: dict) -> None:
        """The outputs (:func:`cdgps_cli.tracking.channel.outputs_dict`) of the next updates."""
        n0, m = self.n, r["time_s"].size
        self.doppler = np.concatenate([self.doppler, r["doppler_hz"]])[-100:]
        self.cn0 = np.concatenate([self.cn0, r["cn0_dbhz"][::WINDOW]])[-5:]
        pll = np.flatnonzero(r["pll"])
        if self.lock_start is None and pll.size:
            self.lock_start = n0 + int(pll[0]) + WINDOW
        if self.lock_start is not None and self.lock_start < n0 + m:
            # the updates lock_start + j·WINDOW that fall in this piece (indices in r)
            first = self.lock_start - n0 if self.lock_start >= n0 else (WINDOW - (n0 - self.lock_start) % WINDOW) % WINDOW
            pli = r["phase_lock"][first::WINDOW]
            self.locked += int(np.count_nonzero(pli > PHASE_LOCK_THRESHOLD))
            self.windows += pli.size
        i, run = r["i_prompt"], r["pll"]
        if self.last is not None:
            i, run = np.r_[self.last[0], i], np.r_[self.last[1], run]
        k = sign_changes(i, run)
        for key, v in (("i_before", i[k - 1]), ("i_at", i[k])):
            self.flips[key].append(v)
        at = k - (0 if self.last is None else 1)                # indices in r
        for key in ("time_s", "doppler_hz", "code_phase_chips"):
            self.flips[key].append(r[key][at])
        self.last = (r["i_prompt"][-1], r["pll"][-1]) if m else self.last
        self.n = n0 + m

    def result(self) -> dict:
        """The summary of :func:`track_all` (the same numbers)."""
        a, cn0 = self.a, self.cn0
        frac = self.locked / self.windows if self.windows else 0.0
        flips = [np.concatenate(self.flips[k]) if self.flips[k] else np.zeros(0)
                 for k in ("i_before", "i_at", "time_s", "doppler_hz", "code_phase_chips")]
        return {"prn": a.prn, "doppler_hz": float(np.mean(self.doppler)),
                "code_phase_chips": a.code_phase_chips, "acquisition_peak_ratio": a.peak_ratio,
                "acquisition_peak_to_noise": a.peak_to_noise,
                "cn0_dbhz": float(np.nanmedian(cn0)) if np.isfinite(cn0).any() else None,
                "phase_lock": bool(self.windows and frac >= LOCKED_FRACTION), "phase_lock_fraction": frac,
                **bit_sync_at(*flips)}


def _start_hz(a, aid) -> float:
    """The loop's first Doppler: the acquired one minus the aid's first value (the aid is fed forward)."""
    return a.doppler_hz - (float(aid.ravel()[0]) if aid is not None and aid.size else 0.0)


def _acquired(samples, fs_hz, prns, if_hz, false_alarm, noncoherent_ms, aids) -> tuple[list, list, dict]:
    """(every acquisition, the acquired ones, aids by PRN as float arrays); refuses a PRN given twice,
    a PRN asked for and not acquired, no satellite at all, an aid for a PRN not acquired."""
    wanted = list(range(1, 33)) if prns is None else check_prns(prns)
    acq = acquire(samples, fs_hz, wanted, if_hz=if_hz, false_alarm=false_alarm, noncoherent_ms=noncoherent_ms)
    found = [a for a in acq if a.acquired]
    if prns is not None:
        missing = [a for a in acq if not a.acquired]
        if missing:
            raise CdgpsError("not acquired: " + ", ".join(
                f"PRN {a.prn} (peak {a.peak_to_noise:.2f} × noise ≤ threshold {a.threshold:.2f} at false-alarm "
                f"probability {false_alarm:g})" for a in missing))
    if not found:
        best = sorted(acq, key=lambda a: -a.peak_to_noise / a.threshold)[:3]
        raise CdgpsError(f"no satellite acquired (false-alarm probability {false_alarm:g} per PRN); strongest peaks: "
                         + ", ".join(f"PRN {a.prn} {a.peak_to_noise:.2f} × noise (threshold {a.threshold:.2f}, "
                                     f"peak-to-second-peak {a.peak_ratio:.2f}) at {a.doppler_hz:+.0f} Hz" for a in best)
                         + ". Check --format, --iq-sign, --fs and --if")
    aids = {} if aids is None else {int(k): v for k, v in aids.items()}
    idle = sorted(set(aids) - {a.prn for a in found})
    if idle:
        raise CdgpsError("aids: given for PRN " + ", ".join(map(str, idle)) + ", not acquired (acquired: "
                         + (", ".join(str(a.prn) for a in found)) + ")")
    return acq, found, {k: None if v is None else np.asarray(v, dtype=float) for k, v in aids.items()}


def to_baseband(samples: np.ndarray, fs_hz: float, if_hz: float, first: int = 0) -> np.ndarray:
    """Samples at the IF ``if_hz`` mixed to baseband, ``first`` the index of ``samples[0]`` in the recording
    (so that pieces are mixed as the whole array would be); unchanged when ``if_hz`` is 0."""
    if if_hz == 0:
        return samples
    # the product's last bits depend on how numpy runs it: the whole-array expression of track_all,
    # ``samples * np.exp(…)``, multiplies in place into the exponential (numpy elides the temporary),
    # exponential first; so here, and on at least two samples (one alone takes another loop)
    k = max(samples.size, 2)
    e = np.exp(-2j * np.pi * if_hz * np.arange(first, first + k) / fs_hz)
    x = samples if samples.size == k else np.concatenate([samples, np.zeros(k - samples.size)])
    np.multiply(e, x, out=e)
    return e[:samples.size]


class BlockTracker:
    """Tracking channels fed a recording piece by piece (:meth:`feed`), pieces of any length.

    Each channel's loop state (:func:`cdgps_cli.tracking.channel.run_updates`) — or, with
    ``clock_bn_hz``, the :class:`cdgps_cli.tracking.shared_clock.SharedClockReceiver` — carries over
    from piece to piece; the samples of an update cut by a piece's end wait for the next piece.
    Outputs (one row per 1 ms update, 64 bytes per channel) are kept; the samples are not.

    Parameters
    ----------
    fs_hz : float
    starts : sequence of (prn, doppler_hz, code_phase_chips)
        Each channel's start (acquisition; Doppler minus the first aid value when aided).
    opt : TrackOptions, optional
    n_samples : int
        Length of the whole recording (samples).
    if_hz : float
        Intermediate frequency of the samples (mixed to baseband here), Hz.
    aids : sequence of (ndarray of shape (n_updates,) or None), optional
        Per channel, the external Doppler per 1 ms update of the whole recording (Hz).
    clock_bn_hz : float, optional
        Track the channels with a shared clock loop of this bandwidth (Hz) instead of independently.
    """

    def __init__(self, fs_hz: float, starts, opt: TrackOptions | None = None, *, n_samples: int, if_hz: float = 0.0,
                 aids=None, clock_bn_hz: float | None = None, keep: bool = True):
        self.opt = TrackOptions() if opt is None else opt
        self.fs_hz, self.if_hz = fs_hz, if_hz
        self.starts = [(int(p), float(d), float(c)) for p, d, c in starts]
        self.n = int(round(fs_hz * 1e-3))
        self.m = int(n_samples) // self.n
        self.aids = [None if a is None else np.asarray(a, dtype=float) for a in (aids or [None] * len(self.starts))]
        for i, a in enumerate(self.aids):
            if a is not None and a.shape != (self.m,):
                raise CdgpsError(f"aid_doppler_hz: expected one value per 1 ms update ({self.m}), got shape {a.shape}")
        self.out = np.zeros((len(self.starts), self.m if keep else 0, len(OUT_FIELDS)))
        self.keep = keep
        self.clock = None if clock_bn_hz is None else SharedClockReceiver(fs_hz, self.starts, self.opt,
                                                                           clock_bn_hz=clock_bn_hz)
        self.clock_doppler_hz = np.zeros(self.m)
        self.states = [initial_state(d, c) for _, d, c in self.starts]
        self.k = 0                       # updates done
        self.seen = 0                    # samples received
        self.rest = np.zeros(0)          # samples of the update cut by the last piece's end

    def feed(self, samples: np.ndarray) -> np.ndarray:
        """Track the whole updates that ``samples`` (the recording's next piece) complete; returns their
        rows, shape (n_channels, n_new_updates, len(OUT_FIELDS)) (kept as well unless ``keep`` is False)."""
        x = to_baseband(np.asarray(samples), self.fs_hz, self.if_hz, self.seen)
        self.seen += x.size
        if self.rest.size:
            x = np.concatenate([self.rest, x])
        m = min(x.size // self.n, self.m - self.k)
        self.rest = x[m * self.n:].copy() if self.k + m < self.m else np.zeros(0)
        body, k0, k1 = x[:m * self.n], self.k, self.k + m
        aids = [None if a is None else a[k0:k1] for a in self.aids]
        rows = np.zeros((len(self.starts), m, len(OUT_FIELDS)))
        if m and self.clock is not None:
            rows[:], self.clock_doppler_hz[k0:k1] = self.clock.run(body, aids)
        elif m:
            for i, (prn, _, _) in enumerate(self.starts):
                rows[i] = run_updates(body, self.fs_hz, prn, self.states[i], self.opt, aids[i])
        if self.keep:
            self.out[:, k0:k1] = rows
        self.k = k1
        return rows

    def check_complete(self) -> None:
        """Refuse a recording that ended before its ``n_samples``."""
        if self.k < self.m:
            raise CdgpsError(f"tracking: {self.k} of the recording's {self.m} updates received "
                             f"({self.seen} samples fed); the recording ended early")

    def results(self) -> list[dict]:
        """Per channel the arrays of :func:`cdgps_cli.tracking.channel.track` over the updates fed."""
        self.check_complete()
        if not self.keep:
            raise CdgpsError("tracking: the outputs were not kept (keep=False)")
        return [outputs_dict(r, self.fs_hz) for r in self.out]


def _summary(a, r: dict) -> dict:
    pll = np.flatnonzero(r["pll"])
    start = (pll[0] + WINDOW) if pll.size else len(r["pll"])
    pli = r["phase_lock"][start::WINDOW]
    frac = float(np.mean(pli > PHASE_LOCK_THRESHOLD)) if pli.size else 0.0
    cn0 = r["cn0_dbhz"][::WINDOW][-5:]
    return {"prn": a.prn, "doppler_hz": float(np.mean(r["doppler_hz"][-100:])),
            "code_phase_chips": a.code_phase_chips, "acquisition_peak_ratio": a.peak_ratio,
            "acquisition_peak_to_noise": a.peak_to_noise,
            "cn0_dbhz": float(np.nanmedian(cn0)) if np.isfinite(cn0).any() else None,
            "phase_lock": bool(pli.size and frac >= LOCKED_FRACTION), "phase_lock_fraction": frac, **bit_sync(r)}
