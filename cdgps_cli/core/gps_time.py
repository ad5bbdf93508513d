"""GPS time: the GPS epoch, calendar ↔ GPS seconds, and GPS seconds as text.

The one home of the GPS time scale (no leap seconds): the RINEX and UBX readers, the orbit and
receiver models and the messages all take it from here.
"""

from __future__ import annotations

import datetime as _dt
import math
import re

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

    Raises
    ------
    ValueError
        A date that does not exist (month 13, 30 February), or a time of day outside
        :func:`check_time_of_day`'s ranges.
    """
    check_time_of_day(hour, minute, second)
    days = _dt.date(int(year), int(month), int(day)).toordinal() - _GPS_EPOCH_ORDINAL
    return float(days * 86400 + int(hour) * 3600 + int(minute) * 60) + float(second)


#: seconds of a minute are below this (60.x is let through: a UTC file's leap second)
SECOND_MAX = 61.0


def check_time_of_day(hour, minute, second) -> None:
    """Refuse a clock time that cannot be: hour outside 0-23, minute outside 0-59, second outside
    [0, :data:`SECOND_MAX`) (a RINEX epoch line of second 61 or hour 25 is damage, not a later time).

    Raises
    ------
    ValueError
        Naming the field and its range (callers add the file and line).
    """
    if not 0 <= hour <= 23:
        raise ValueError(f"hour must be in 0..23, got {hour}")
    if not 0 <= minute <= 59:
        raise ValueError(f"minute must be in 0..59, got {minute}")
    if not 0 <= second < SECOND_MAX:
        raise ValueError(f"second must be in [0, {SECOND_MAX:g}), got {second}")


_GPS_TIME_TEXT = re.compile(r"([0-9]{4})([-/])([0-9]{2})\2([0-9]{2})[ T]([0-9]{2}):([0-9]{2})(?::([0-9]{2})(\.[0-9]+)?)?")


def parse_gps_time(text: str, what: str) -> float:
    """A GPS date and time written ``YYYY/MM/DD HH:MM[:SS[.f]]`` (RTKLIB's ``-ts`` form) or ``YYYY-MM-DDTHH:MM[:SS[.f]]``
    (ISO 8601; a space for the ``T`` too) → GPS seconds; ``what`` names the option in the error (CdgpsError) when the
    text is neither (a date alone is refused: it would mean its 00:00), or a time before GPS time began
    (1980-01-06)."""
    from cdgps_cli.core.errors import CdgpsError  # noqa: PLC0415

    m = _GPS_TIME_TEXT.fullmatch(str(text).strip())
    form = "YYYY/MM/DD HH:MM:SS[.f] or YYYY-MM-DDTHH:MM:SS[.f]"
    if m is None:
        raise CdgpsError(f"{what} expects a GPS date and time, {form}, got {text!r}")
    y, mo, d, h, mi = (int(m.group(k)) for k in (1, 3, 4, 5, 6))
    sec = int(m.group(7) or 0) + (float(m.group(8)) if m.group(8) else 0.0)
    try:
        _dt.date(y, mo, d)
        check_time_of_day(h, mi, sec)
        if sec >= 60:
            raise ValueError(f"second must be in [0, 60) (GPS time has no leap second), got {sec:g}")
    except ValueError as exc:
        raise CdgpsError(f"{what} expects a GPS date and time, {form}, got {text!r} ({exc})") from None
    t = gps_seconds(y, mo, d, h, mi, sec)
    if t < 0:
        raise CdgpsError(f"{what}: {text!r} is before GPS time began (1980-01-06 00:00:00)")
    return t


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


def distinct_times(t_s) -> np.ndarray:
    """``np.unique`` of time tags (float64), in O(n) without a sort when they do not decrease (a record's rows:
    a day at 10 Hz is ≈ 9 M of them, whose sort took ≈ 0.4 s each time); any other input (out of order, NaN) by
    ``np.unique`` itself.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Time tags, s (any order, repeats allowed).
    """
    t = np.asarray(t_s, dtype=np.float64)
    if t.ndim != 1 or t.size < 2 or not bool(np.all(t[1:] >= t[:-1])):
        return np.unique(t)
    keep = np.empty(t.size, dtype=bool)
    keep[0] = True
    np.not_equal(t[1:], t[:-1], out=keep[1:])
    return t[keep]


def nominal_interval_s(t_s) -> float:
    """Median spacing of distinct epoch times (rounded to 1 ms), s; NaN for fewer than 2 epochs.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Epoch times, s (any order, repeats allowed).
    """
    u = distinct_times(t_s)
    if u.size < 2:
        return math.nan
    return float(np.round(np.median(np.diff(u)), 3))


# ----------------------------------------------------------------------------------------------
# BeiDou time (BDT) and GLONASS time (GLONASST)
# ----------------------------------------------------------------------------------------------

BDT_WEEK_OFFSET = 1356
"""GPS week in which BDT week 0 starts (BDT epoch 2006-01-01 00:00:00 UTC; BDS-ICD-B1I §3.3)."""
GPS_MINUS_BDT_S = 14.0
"""GPST − BDT, s: the 14 leap seconds between 1980 and 2006 (BDT has no leap seconds)."""
GLONASST_MINUS_UTC_S = 3 * 3600.0
"""GLONASST − UTC(SU), s: GLONASS time is Moscow time (UTC + 3 h, with UTC's leap seconds)."""


def bdt_to_gps_s(week_bdt, sow_bdt_s):
    """GPS seconds (since 1980-01-06) of BDT week ``week_bdt`` and seconds of week ``sow_bdt_s``.

    BDT = GPST − 14 s and BDT week 0 = GPS week 1356, so t_GPS = (week + 1356)·604800 + sow + 14.
    Vectorized (array_like inputs broadcast).
    """
    return (np.asarray(week_bdt, dtype=np.float64) + BDT_WEEK_OFFSET) * SECONDS_PER_WEEK + np.asarray(sow_bdt_s, dtype=np.float64) + GPS_MINUS_BDT_S


def glonasst_to_gps_s(t_glonasst_s, gps_minus_utc_s):
    """GPS seconds of a GLONASS-time instant given as seconds of the same calendar count as
    :func:`gps_seconds` (i.e. ``gps_seconds(y, m, d, h, mi, s)`` of the GLONASST date and time).

    t_GPS = t_GLONASST − 3 h + (GPS − UTC); ``gps_minus_utc_s`` is the leap-second count in force
    (:func:`cdgps_cli.core.timescales.gps_minus_utc_s`; 18 s since 2017).
    """
    return np.asarray(t_glonasst_s, dtype=np.float64) - GLONASST_MINUS_UTC_S + np.asarray(gps_minus_utc_s, dtype=np.float64)


def grid_step_s(interval_s: float) -> float:
    """The grid of a receiver with this nominal interval, s: ``1/n`` s for ``n`` Hz, ``n`` s for
    one epoch every ``n`` s (each within 5 %: the median spacing of epochs with jitter or gaps),
    else the interval to 1 ms; 1 s if it is unknown (a single epoch)."""
    if not (math.isfinite(interval_s) and interval_s > 0):
        return 1.0
    rate = 1.0 / interval_s
    if rate >= 0.95 and abs(rate - round(rate)) < 0.05 * rate:
        return 1.0 / round(rate)
    if interval_s >= 1.0 and abs(interval_s - round(interval_s)) < 0.05 * interval_s:
        return float(round(interval_s))
    return round(interval_s, 3)


#: share of a receiver's epoch spacings that must be whole multiples of its sampling interval (sampling_interval_s)
SAMPLING_MULTIPLES_SHARE = 0.9


def sampling_interval_s(t_s) -> float:
    """The interval a receiver samples at, s: the grid (:func:`grid_step_s`) of the 5th percentile of its epoch
    spacings when at least :data:`SAMPLING_MULTIPLES_SHARE` of the spacings are whole multiples of it (within
    5 %), else the median spacing (:func:`~cdgps_cli.core.gps_time.nominal_interval_s`).  A log with gaps (a
    u-blox base interleaving RTCM: spacings of 1, 2, 3 … s, median 3 s) samples at 1 s; its median spacing
    would put two epochs in three off the grid."""
    u = np.unique(np.asarray(t_s, dtype=np.float64))
    if u.size < 3:
        return nominal_interval_s(u)
    d = np.diff(u)
    step = grid_step_s(float(np.percentile(d, 5)))
    k = d / step
    if np.mean(np.abs(k - np.round(k)) <= 0.05) >= SAMPLING_MULTIPLES_SHARE:
        return step
    return nominal_interval_s(u)


def time_span(t_s) -> tuple[float, float] | None:
    """(first, last) of the times ``t_s`` (s), or None when there is none."""
    t = np.asarray(t_s, dtype=np.float64)
    return (float(t.min()), float(t.max())) if t.size else None


def spans_meet(a: tuple | None, b: tuple | None, max_age_s: float) -> bool:
    """Whether two records' spans (:func:`time_span`) meet within ``max_age_s`` (a base epoch that old still pairs
    with a rover epoch); a record without epochs meets none."""
    if a is None or b is None:
        return False
    return a[0] <= b[1] + max_age_s and b[0] <= a[1] + max_age_s
