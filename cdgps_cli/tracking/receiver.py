"""Acquire and track every satellite strong enough in a block of samples (a multi-channel receiver)."""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.tracking.acquisition import FALSE_ALARM, NONCOHERENT_MS, acquire
from cdgps_cli.tracking.bitsync import bit_sync
from cdgps_cli.tracking.channel import PHASE_LOCK_THRESHOLD, WINDOW, TrackOptions, track

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
    wanted = list(range(1, 33)) if prns is None else list(prns)
    say = progress or (lambda m: None)
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
    baseband = samples if if_hz == 0 else samples * np.exp(-2j * np.pi * if_hz * np.arange(samples.size) / fs_hz)
    tracks, sats = {}, []
    for a in found:
        say(f"tracking PRN {a.prn} ({a.doppler_hz:+.0f} Hz, peak {a.peak_to_noise:.1f} × noise) …")
        aid = None if aids.get(a.prn) is None else np.asarray(aids[a.prn], dtype=float)
        start_hz = a.doppler_hz - (float(aid.ravel()[0]) if aid is not None and aid.size else 0.0)
        r = track(baseband, fs_hz, a.prn, start_hz, a.code_phase_chips, opt, aid_doppler_hz=aid)
        tracks[a.prn] = r
        sats.append(_summary(a, r))
    return {"acquisition": [a.__dict__ for a in acq], "satellites": sats, "tracks": tracks}


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
