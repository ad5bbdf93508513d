"""From the regulator's signed thruster commands to non-negative forces of on/off jets.

The LQR of :mod:`cdgps_cli.control.lqr` treats every thruster as a signed force input.  A jet can
only push, but jets mounted in opposing pairs (same section, same point, opposite directions, as the
testbed's clusters of four) realize a signed force together: their generalized forces are equal and
opposite, so the pair's net command u_i − u_j is fired on i when positive and on j when negative,
with the same generalized force Υ u.  A jet without an opposite fires only positive commands.
"""

from __future__ import annotations

import numpy as np


def opposing_pairs(section, position_m, direction, tol: float = 1e-9) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, of thrusters at the same section and point pushing in opposite directions.

    Parameters
    ----------
    section : array_like, shape (m,)
        Section index of each thruster.
    position_m : array_like, shape (m, 3)
        Attachment point in the body frame, m.
    direction : array_like, shape (m, 3)
        Unit force direction.
    tol : float
        Tolerance on positions (m) and on the direction sum.
    """
    sec = np.asarray(section)
    pos = np.asarray(position_m, float)
    d = np.asarray(direction, float)
    used: set[int] = set()
    pairs = []
    for i in range(len(sec)):
        if i in used:
            continue
        for j in range(i + 1, len(sec)):
            if j in used or sec[j] != sec[i]:
                continue
            if np.all(np.abs(pos[j] - pos[i]) <= tol) and np.all(np.abs(d[j] + d[i]) <= tol):
                pairs.append((i, j))
                used.update((i, j))
                break
    return pairs


def realize_forces(u_n, pairs) -> np.ndarray:
    """Non-negative thrust per jet with the same generalized force as the signed commands.

    Parameters
    ----------
    u_n : array_like, shape (..., m)
        Signed commands from the regulator, N.
    pairs : list of (int, int)
        From :func:`opposing_pairs`.

    Returns
    -------
    ndarray, shape (..., m)
        Requested thrust per jet, N (≥ 0).
    """
    u = np.asarray(u_n, dtype=float)
    out = np.clip(u, 0.0, None)
    for i, j in pairs:
        net = u[..., i] - u[..., j]
        out[..., i] = np.clip(net, 0.0, None)
        out[..., j] = np.clip(-net, 0.0, None)
    return out
