"""Value checks shared by every library function: finite numbers, JSON value kinds, a usable
a-priori receiver position.

These are the library's own checks (numerics and readers call them and name their own fields);
the command line adds its option-level checks in :mod:`cdgps_cli.cli.guard` on top.
"""

from __future__ import annotations

import math

import numpy as np

from cdgps_cli.core.errors import CdgpsError

#: an ECEF position closer than this to the Earth's centre is not a receiver position, m
#: (a RINEX header's APPROX POSITION XYZ of 0 0 0 means "unknown")
MIN_RECEIVER_RADIUS_M = 6.0e6


def require_finite(value: float | None, name: str, positive: bool = False, nonnegative: bool = False) -> None:
    """Library-side check of one float argument; ``name`` is the field's own name in the message."""
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CdgpsError(f"{name} must be a finite number, got {value!r}")
    if positive and not value > 0:
        raise CdgpsError(f"{name} must be positive, got {value!r}")
    if nonnegative and value < 0:
        raise CdgpsError(f"{name} must not be negative, got {value!r}")


def is_json_number(value) -> bool:
    """True for an int or float that is not a bool (JSON ``true`` is not 1.0)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def has_bool(value) -> bool:
    """True if ``value`` is, or a nested list holds, a JSON boolean (iterative: no recursion limit)."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, bool):
            return True
        if isinstance(v, list):
            stack.extend(v)
    return False


def header_position_m(header: dict):
    """A RINEX header's ``approx_position_xyz_m`` as an ECEF position (3,), m, when it is usable:
    three finite numbers at least :data:`MIN_RECEIVER_RADIUS_M` from the Earth's centre; else None."""
    pos = header.get("approx_position_xyz_m")
    if pos is None:
        return None
    pos = np.asarray(pos, dtype=np.float64)
    if pos.shape != (3,) or not np.all(np.isfinite(pos)) or np.linalg.norm(pos) < MIN_RECEIVER_RADIUS_M:
        return None
    return pos
