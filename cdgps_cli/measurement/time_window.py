"""The rover epochs a GNSS solution is asked for: a window of GPS time (``--start-time`` / ``--end-time``, RTKLIB's
``-ts`` / ``-te``), one rule for every GNSS command (``rtk``, ``baseline``).

A rover epoch tagged ``t`` is inside the window [``lo``, ``hi``] when ``t − lo ≥ −tol`` and ``t − hi < tol``, with
``tol`` the epoch-pairing tolerance ``sync_tol_s``: a tag at .998 s or .999 s belongs to the second that follows it,
as receivers that steer their clocks write it.  The epochs outside are counted with :data:`OUTSIDE_WINDOW` as their
reason, never dropped silently.  The base keeps its epochs within ``max_age_s`` of the window, where the window's
rover epochs find their pairs and bridges (:mod:`cdgps_cli.measurement.epoch_pairing`).
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_time_str, time_span

__all__ = ["OUTSIDE_WINDOW", "window_errors", "in_window", "window_text", "with_dropped", "pair_in_window", "window_masks"]

#: why a rover epoch of its file was not solved: outside ``start_gps_s`` … ``end_gps_s``
OUTSIDE_WINDOW = "outside the time window asked for (--start-time / --end-time)"


def window_errors(start_gps_s, end_gps_s) -> list:
    """What is wrong with a window: each end None or a finite GPS time in seconds, the start at or before the end
    (a list of sentences naming the key and its flag; empty when nothing is)."""
    bad = []
    for key, v in (("start_gps_s", start_gps_s), ("end_gps_s", end_gps_s)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))
                              or not np.isfinite(v)):
            bad.append(f"{key}: expected a GPS time in seconds or None, got {v!r}")
    if not bad and start_gps_s is not None and end_gps_s is not None and start_gps_s > end_gps_s:
        bad.append(f"end_gps_s (--end-time): expected at or after start_gps_s (--start-time, "
                   f"{gps_time_str(start_gps_s)}), got {gps_time_str(end_gps_s)}")
    return bad


def in_window(t: np.ndarray, lo: float, hi: float, tol: float) -> np.ndarray:
    """Which time tags ``t`` (GPS s) are in the window [``lo``, ``hi``]: at most ``tol`` s before its start, less than
    ``tol`` s after its end (None or ±inf: that end open)."""
    lo = -np.inf if lo is None else float(lo)
    hi = np.inf if hi is None else float(hi)
    t = np.asarray(t, dtype=np.float64)
    return (t - lo >= -tol) & (t - hi < tol)


def window_text(start_gps_s, end_gps_s) -> str:
    """The window as a sentence's part: "2024/06/24 08:21:00 – its end"."""
    return (f"{'its start' if start_gps_s is None else gps_time_str(start_gps_s)} – "
            f"{'its end' if end_gps_s is None else gps_time_str(end_gps_s)}")


def with_dropped(pairing: dict, reason: str, n: int) -> dict:
    """An epoch-pairing summary (:func:`~cdgps_cli.measurement.epoch_pairing.pair_epochs`) with ``n`` rover epochs
    more, dropped for ``reason`` (the same summary when ``n`` is 0)."""
    if n <= 0:
        return pairing
    return {**pairing, "rover_epochs": pairing["rover_epochs"] + n, "dropped": {**pairing["dropped"], reason: n}}


def window_masks(base_t, rover_t, lo, hi, tol: float, max_age_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a base's and a rover's time tags (GPS s) a window [``lo``, ``hi``] keeps: the rover's
    :func:`in_window` it, the base's within ``max_age_s`` more on each side (where the window's rover epochs find their
    pairs and bridges)."""
    age = float(max_age_s)
    return (in_window(base_t, None if lo is None else lo - age, None if hi is None else hi + age, tol),
            in_window(rover_t, lo, hi, tol))


def pair_in_window(base_t, rover_t, lo, hi, tol: float, max_age_s: float, names: tuple) -> tuple[np.ndarray,
                                                                                                   np.ndarray]:
    """:func:`window_masks`, refused when it keeps nothing.  ``names``: (base, rover) as the messages name them ("base.obs (base)").  CdgpsError
    naming the rover and its span when no rover epoch is inside, the base and its span when no base epoch is within
    ``max_age_s`` of it."""
    age = float(max_age_s)
    keep_b, keep_r = window_masks(base_t, rover_t, lo, hi, tol, age)
    for t, k, name, near in ((rover_t, keep_r, names[1], ""),
                             (base_t, keep_b, names[0], f" or within max_age_s ({age:g} s) of it")):
        if not k.any():
            span = time_span(t)
            has = f"{gps_time_str(span[0])} – {gps_time_str(span[1])}" if span else "no epoch"
            raise CdgpsError(f"{name}: no epoch in the window asked for{near} ({window_text(lo, hi)}: --start-time / "
                             f"--end-time); its epochs span {has}")
    return keep_b, keep_r
