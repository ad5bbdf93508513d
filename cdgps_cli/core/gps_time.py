"""GPS time: the GPS epoch, calendar ↔ GPS seconds, and GPS seconds as text.

The one home of the GPS time scale (no leap seconds): the RINEX and UBX readers, the orbit and
receiver models and the messages all take it from here.
"""

from __future__ import annotations

import datetime as _dt
import math

import numpy as np

GPS_EPOCH = _dt.datetime(1980, 1, 6)
SECONDS_PER_WEEK = 604800
_GPS_EPOCH_ORDINAL = GPS_EPOCH.toordinal()


def gps_seconds(year: int, month: int, day: int, hour: int = 0, minute: int = 0, second: float = 0.0) -> float:
    """GPS seconds since 1980-01-06 00:00:00 for a calendar date and time (in GPS time).

    Parameters
    ----------
    year, month, day, hour, minute : int
        Calendar date and time of day (GPS time scale, no leap seconds).
    second : float
        Seconds of the minute, s.

    Returns
    -------
    float
        GPS seconds, s.  The whole-second part is computed in integers, so the result is as exact
        as a float64 allows (0.24 µs around 2020).
    """
    days = _dt.date(int(year), int(month), int(day)).toordinal() - _GPS_EPOCH_ORDINAL
    return float(days * 86400 + int(hour) * 3600 + int(minute) * 60) + float(second)


def gps_time_str(t_gps_s: float) -> str:
    """Format GPS seconds as ``YYYY-MM-DD hh:mm:ss.sss GPST`` (for messages)."""
    if not np.isfinite(t_gps_s):
        return "NaN"
    whole = math.floor(t_gps_s)
    frac = t_gps_s - whole
    d = GPS_EPOCH + _dt.timedelta(seconds=int(whole))
    ms = int(round(frac * 1000))
    if ms == 1000:
        d += _dt.timedelta(seconds=1)
        ms = 0
    s = d.strftime("%Y-%m-%d %H:%M:%S")
    return f"{s}.{ms:03d} GPST" if ms else f"{s} GPST"


def nominal_interval_s(t_s) -> float:
    """Median spacing of distinct epoch times (rounded to 1 ms), s; NaN for fewer than 2 epochs.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Epoch times, s (any order, repeats allowed).
    """
    u = np.unique(np.asarray(t_s, dtype=np.float64))
    if u.size < 2:
        return math.nan
    return float(np.round(np.median(np.diff(u)), 3))
