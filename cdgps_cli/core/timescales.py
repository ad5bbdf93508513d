"""Time scales of cdgps files: GPS time, UTC (Unix time) and the relative time of pseudolite runs.

MCAP log and publish times are Unix time (nanoseconds since 1970-01-01T00:00:00 UTC) so that
viewers such as Foxglove show the real date; the payload keeps each file's own time scale in
``time_s``:

* ``gps`` — GNSS runs (RINEX / UBX): ``time_s`` is GPS time, seconds since 1980-01-06T00:00:00
  (no leap seconds).  Unix time = GPS time + 315 964 800 s − (GPS − UTC), where GPS − UTC is the
  number of leap seconds inserted since 1980 (table below; 18 s since 2017-01-01).  A leap
  second itself (23:59:60 UTC) has no Unix time of its own: it gets the Unix second that follows
  it, so log times never go back.
* ``relative`` — pseudolite (structure) runs: ``time_s`` counts seconds from the start of the
  recording, which has no absolute date.  Their log time is ``time_s`` after the Unix epoch
  (:data:`RELATIVE_EPOCH_UTC`, 1970-01-01T00:00:00 UTC), so a viewer's clock reads the run's own
  seconds (00:01:00 is ``time_s`` = 60) and a date of 1970-01-01 says "no absolute date".
"""

from __future__ import annotations

import bisect
import math

import numpy as np

GPS_EPOCH_UNIX_S = 315_964_800
"""1980-01-06T00:00:00 UTC as Unix time, s."""

RELATIVE_EPOCH_UTC = "1970-01-01T00:00:00Z"
"""The log-time origin of runs whose ``time_s`` is relative (pseudolite runs): the Unix epoch."""

TIME_SCALES = ("gps", "relative")

# UTC dates (as Unix time, s) from which GPS − UTC took the value given (IERS Bulletin C).
_LEAP_UNIX_S = np.array([
    362793600,    # 1981-07-01  1
    394329600,    # 1982-07-01  2
    425865600,    # 1983-07-01  3
    489024000,    # 1985-07-01  4
    567993600,    # 1988-01-01  5
    631152000,    # 1990-01-01  6
    662688000,    # 1991-01-01  7
    709948800,    # 1992-07-01  8
    741484800,    # 1993-07-01  9
    773020800,    # 1994-07-01 10
    820454400,    # 1996-01-01 11
    867715200,    # 1997-07-01 12
    915148800,    # 1999-01-01 13
    1136073600,   # 2006-01-01 14
    1230768000,   # 2009-01-01 15
    1341100800,   # 2012-07-01 16
    1435708800,   # 2015-07-01 17
    1483228800,   # 2017-01-01 18
], dtype=np.int64)
# the same instants as GPS seconds (GPS time runs ahead of UTC by the count in force just after)
_LEAP_GPS_S = _LEAP_UNIX_S - GPS_EPOCH_UNIX_S + np.arange(1, _LEAP_UNIX_S.size + 1)
_LEAP_GPS_LIST = _LEAP_GPS_S.tolist()


def gps_minus_utc_s(gps_s) -> np.ndarray | int:
    """Leap seconds GPS − UTC in force at GPS time ``gps_s`` (s since 1980-01-06), integer s.

    Parameters
    ----------
    gps_s : float or array_like
        GPS time, s.

    Returns
    -------
    int or ndarray of int64
        0 before 1981-07-01, 18 from 2017-01-01 (the last leap second announced).
    """
    n = np.searchsorted(_LEAP_GPS_S, np.asarray(gps_s, dtype=float), side="right")
    return int(n) if np.ndim(n) == 0 else n.astype(np.int64)


def unix_ns(time_s, scale: str) -> int:
    """Log time (Unix nanoseconds, UTC) of a payload time ``time_s`` in time scale ``scale``.

    Parameters
    ----------
    time_s : float
        Seconds in the file's time scale (GPS s for ``"gps"``, run seconds for ``"relative"``).
    scale : {"gps", "relative"}

    Returns
    -------
    int
        Nanoseconds since 1970-01-01T00:00:00 UTC (rounded to the nearest nanosecond).
    """
    t = float(time_s)
    if scale == "relative":
        return int(round(t * 1e9))
    if scale == "gps":
        whole = math.floor(t)
        sec = whole + GPS_EPOCH_UNIX_S - bisect.bisect_right(_LEAP_GPS_LIST, whole)   # (gps_minus_utc_s, per call)
        return sec * 1_000_000_000 + int(round((t - whole) * 1e9))
    raise ValueError(f"time scale {scale!r}: expected one of {', '.join(TIME_SCALES)}")


def unix_ns_list(times_s, scale: str) -> list[int]:
    """:func:`unix_ns` of each of ``times_s`` (a list or 1-D array of floats): the same integers,
    computed as arrays (the same double operations; numpy's ``rint`` rounds halves to even as
    Python's ``round``), one by one where a time is not finite or too large for int64 nanoseconds."""
    t = np.asarray(times_s, dtype=float)
    if scale not in TIME_SCALES:
        raise ValueError(f"time scale {scale!r}: expected one of {', '.join(TIME_SCALES)}")
    if t.size == 0:
        return []
    if not (np.isfinite(t).all() and np.abs(t).max() < 4e9):
        return [unix_ns(v, scale) for v in t.tolist()]
    if scale == "relative":
        return np.rint(t * 1e9).astype(np.int64).tolist()
    whole = np.floor(t)
    leap = np.searchsorted(_LEAP_GPS_S, whole, side="right")
    sec = whole.astype(np.int64) + GPS_EPOCH_UNIX_S - leap
    return (sec * 1_000_000_000 + np.rint((t - whole) * 1e9).astype(np.int64)).tolist()
