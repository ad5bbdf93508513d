"""Times of a cdgps file for people: which time scale its ``time_s`` is in, and how to print it.

* ``gps`` — GNSS runs (RINEX / UBX) and their STATES: GPS seconds since 1980-01-06, printed as a
  GPST calendar date (``2005-04-02 00:00:00 GPST``);
* ``utc`` — Unix time, seconds since 1970-01-01 UTC, printed as a UTC calendar date;
* ``relative`` — pseudolite (structure) runs: seconds from the start of the recording, which
  has no date, printed as seconds.

The scale is read from the channel's ``time_scale`` metadata where the file has it (``gps``,
``relative``, ``utc``/``unix``); older files without it are told apart by their ingest/estimate
metadata (``kind = gnss``) and, failing that, by size: no structure recording lasts 1e8 s (3 years),
so larger times are GPS seconds.
"""

from __future__ import annotations

import datetime as _dt
import math

import numpy as np

SCALES = ("gps", "utc", "relative")
_ALIASES = {"unix": "utc", "utc": "utc", "gps": "gps", "relative": "relative"}
_ABSOLUTE_AFTER_S = 1e8


def time_scale(contents, topic: str | None = None, times=None) -> str:
    """Time scale of ``topic`` in MCAP ``contents`` (:func:`~cdgps_cli.io.mcap.read_mcap`).

    Parameters
    ----------
    contents : McapContents
    topic : str, optional
        Channel whose ``time_scale`` metadata to use (default: the first channel that has one).
    times : array_like, optional
        The times themselves, s (last resort for files without any time-scale record).

    Returns
    -------
    str
        One of :data:`SCALES`.
    """
    chan = getattr(contents, "channel_metadata", {}) or {}
    metas = [chan.get(topic, {})] if topic is not None else []
    metas += list(chan.values())
    for md in metas:
        scale = _ALIASES.get(str(md.get("time_scale", "")).lower())
        if scale:
            return scale
    if any(md.get("kind") == "gnss" for md in contents.metadata.values()):
        return "gps"
    if times is not None:
        t = np.asarray(times, dtype=float)
        t = t[np.isfinite(t)]
        if t.size and float(np.max(np.abs(t))) > _ABSOLUTE_AFTER_S:
            return "gps"
    return "relative"


def format_time(t: float | None, scale: str) -> str:
    """``t`` (s, in ``scale``) as text: a calendar date for ``gps``/``utc``, seconds otherwise."""
    if t is None or not math.isfinite(t):
        return "-"
    if scale == "gps":
        from cdgps_cli.core.gps_time import gps_time_str

        return gps_time_str(t)
    if scale == "utc":
        whole = math.floor(t)
        d = _dt.datetime(1970, 1, 1) + _dt.timedelta(seconds=int(whole))
        ms = int(round((t - whole) * 1000))
        if ms == 1000:
            d, ms = d + _dt.timedelta(seconds=1), 0
        return d.strftime("%Y-%m-%d %H:%M:%S") + (f".{ms:03d}" if ms else "") + " UTC"
    return f"{t:g} s"


def median_spacing_s(times, sources=None) -> float | None:
    """Sampling period of a series: the median spacing of its distinct times, s (None: < 2 times).

    Distinct times, because several messages may share one epoch (ephemerides); the median, so that
    receiver-clock jitter, gaps and a few odd epochs do not change it.  With ``sources`` (one label
    per time, e.g. the receiver of each message), the spacing is taken within each source and the
    median over all of them: two receivers logging 30 s epochs a few ms apart sample every 30 s,
    not every few ms.
    """
    t = np.asarray(times, dtype=float)
    if sources is None:
        groups = [t]
    else:
        src = np.asarray(sources, dtype=object)
        groups = [t[src == s] for s in dict.fromkeys(src.tolist())]
    d = [np.diff(np.unique(g[np.isfinite(g)])) for g in groups]
    d = np.concatenate(d) if d else np.zeros(0)
    return float(np.median(d)) if d.size else None


def format_period(period_s: float | None) -> str:
    """A sampling period for people: ``0.1 s``, ``30 s``, ``2 h``; ``-`` when unknown."""
    if period_s is None or not math.isfinite(period_s) or period_s <= 0:
        return "-"
    if period_s >= 7200:
        return f"{period_s / 3600:.4g} h"
    if period_s >= 120:
        return f"{period_s / 60:.4g} min"
    return f"{period_s:.6g} s"
