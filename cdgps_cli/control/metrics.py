"""Figures of merit of the 1998 control experiments (Sec. VI.C–D), from time series.

Angles in, numbers out (degrees and seconds); definitions are stated with each function so a
report can say where its numbers came from.
"""

from __future__ import annotations

import numpy as np

#: an internal angle is "back" when it stays within this fraction of its open-loop first peak
#: (pulse experiment; about the resolution of the paper's Fig. 10 at its 10° scale)
BACK_FRACTION = 0.1
#: the slew has "arrived" when the rigid-body angle stays within this many degrees of the command
ARRIVED_WITHIN_DEG = 0.5
#: every generalized coordinate of the closed-loop experiments is checked against a limit (issue 31):
#: a rotation within the paper's 1° for the sections' internal rotations (Fig. 11) ...
ROTATION_LIMIT_DEG = 1.0
#: ... a translation within the displacement a 1° rotation gives at 1 m (the testbed's arm length), mm
TRANSLATION_LIMIT_MM = 1000.0 * np.radians(1.0)
#: the pulse experiment checks every coordinate from this long after the pulse ends ("the system returned to
#: the initial configuration within 3 s of the end of the pulse", Sec. VI.C)
PULSE_BACK_S = 3.0
#: the slew is "done within 30 s" (Sec. VI.D): the rigid-body angle is checked against
#: :data:`ARRIVED_WITHIN_DEG` about the command from this long after the command, s
SLEW_DONE_S = 30.0


def first_peak_deg(time_s, angle_deg, after_s: float) -> float:
    """Largest |angle| between ``after_s`` and the first zero crossing after its first extremum
    (the first oscillation peak), deg; the overall maximum if it never crosses zero."""
    t = np.asarray(time_s)
    a = np.asarray(angle_deg)[t >= after_s]
    if a.size == 0:
        return float("nan")
    k = int(np.argmax(np.abs(a) > 0.5 * np.abs(a).max())) if np.abs(a).max() > 0 else 0
    sign = np.sign(a[k]) or 1.0
    cross = np.flatnonzero(np.sign(a[k:]) == -sign)
    end = k + (int(cross[0]) if cross.size else len(a) - k)
    return float(np.abs(a[:end]).max())


def settle_time_s(time_s, error_deg, within_deg: float, after_s: float) -> float | None:
    """First time ≥ ``after_s`` from which |error| stays ≤ ``within_deg`` to the end (None: never)."""
    t = np.asarray(time_s)
    e = np.abs(np.asarray(error_deg))
    sel = t >= after_s
    t, e = t[sel], e[sel]
    outside = np.flatnonzero(e > within_deg)
    if outside.size == 0:
        return float(t[0]) if t.size else None
    k = int(outside[-1]) + 1
    return float(t[k]) if k < len(t) else None


def pulse_metrics(time_s, open_deg: dict, closed_deg: dict, pulse_start_s: float, pulse_end_s: float) -> dict:
    """Pulse rejection (Fig. 10): per angle the open-loop first peak, the closed-loop peak, their
    ratio, the open-loop peak-to-peak over the last 10 s (persisting oscillation), and when the
    closed-loop angle is back within :data:`BACK_FRACTION` of the open-loop first peak for good (s after
    the pulse end)."""
    t = np.asarray(time_s)
    out = {}
    for name in closed_deg:
        o, c = np.asarray(open_deg[name]), np.asarray(closed_deg[name])
        po = first_peak_deg(t, o, pulse_start_s)
        pc = float(np.abs(c[t >= pulse_start_s]).max())
        back = settle_time_s(t, c, BACK_FRACTION * po, pulse_start_s)
        tail = t >= t[-1] - 10.0
        out[name] = {"open_first_peak_deg": po, "closed_peak_deg": pc,
                     "peak_ratio": pc / po if po > 0 else None,
                     "open_tail_peak_to_peak_deg": float(np.ptp(o[tail])),
                     "closed_back_within_s_after_pulse": None if back is None else max(back - pulse_end_s, 0.0)}
    return out


def slew_metrics(time_s, rigid_deg, internal_deg: dict, command_deg: float, command_s: float) -> dict:
    """Slew (Figs. 11–12): when the rigid-body angle is within :data:`ARRIVED_WITHIN_DEG` of the
    command for good (s after the command), its final error and peak-to-peak over the last 10 s, and
    the largest |internal angle| after the command, deg."""
    t = np.asarray(time_s)
    r = np.asarray(rigid_deg)
    arrived = settle_time_s(t, r - command_deg, ARRIVED_WITHIN_DEG, command_s)
    tail = t >= t[-1] - 10.0
    after = t >= command_s
    return {"arrived_s_after_command": None if arrived is None else arrived - command_s,
            "final_error_deg": float(r[-1] - command_deg),
            "final_peak_to_peak_deg": float(np.ptp(r[tail])),
            "internal_max_deg": {k: float(np.abs(np.asarray(v)[after]).max()) for k, v in internal_deg.items()}}


def coordinate_checks(time_s, values: dict, kinds: dict, after_s: float, limits: dict | None = None) -> dict:
    """Every coordinate's largest |value| from ``after_s`` on against its limit.

    Parameters
    ----------
    time_s : array_like, shape (n,)
    values : dict
        Coordinate name -> samples (n,) in SI units (rad for a rotation, m for a translation).
    kinds : dict
        Coordinate name -> ``"rotation"``, ``"translation"`` or another kind (not checked: no limit).
    after_s : float
        Only samples at ``time_s >= after_s`` count.
    limits : dict, optional
        Name -> limit in the reported unit (deg or mm), replacing its kind's default
        (:data:`ROTATION_LIMIT_DEG`, :data:`TRANSLATION_LIMIT_MM`).

    Returns
    -------
    dict
        Name -> ``{"kind", "unit" ("deg" or "mm"), "max_abs", "limit", "within"}``; ``limit`` and
        ``within`` are None for a kind without a limit; ``max_abs`` and ``within`` are None when no
        sample is at or after ``after_s`` (not checked: the run ends before).
    """
    t = np.asarray(time_s)
    sel = t >= after_s
    out = {}
    for name, v in values.items():
        kind = kinds.get(name)
        scale, unit, limit = {"rotation": (np.degrees(1.0), "deg", ROTATION_LIMIT_DEG),
                              "translation": (1000.0, "mm", TRANSLATION_LIMIT_MM)}.get(kind, (1.0, "", None))
        if limit is not None and limits and name in limits:
            limit = float(limits[name])
        m = float(np.abs(np.asarray(v, dtype=float)[sel]).max() * scale) if sel.any() else None
        out[name] = {"kind": kind, "unit": unit, "max_abs": m, "limit": limit,
                     "within": None if limit is None or m is None else bool(m <= limit)}
    return out
