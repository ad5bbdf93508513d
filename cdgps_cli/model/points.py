"""Displacements of structure points (antennas, named ``[[points]]``) and their 1-σ from estimated states.

A point's lab-frame position is p(q) (:func:`cdgps_cli.model.kinematics.point_positions`) with q = U ξ.
Its displacement from the nominal position is d = p(q̂) − p(0), and its covariance to first order

    Cov(d) = J U P_ξ Uᵀ Jᵀ,        J = ∂p/∂q at q̂  (3 × n_q),

with P_ξ the modal-position covariance of the estimate (``P_xi`` in STATES.mcap).  For modal
coordinates with FE mode shapes (``displacement_m``) p is linear in q and this is exact; with
section rotations it is the usual linearization at the estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.kinematics import point_positions


@dataclass(frozen=True)
class PointSet:
    """Points to evaluate: names, section index (-1: body frame), nominal position in B (P, 3),
    linear displacement per coordinate (P, 3, n_q)."""

    names: tuple
    section: np.ndarray
    position_m: np.ndarray
    displacement: np.ndarray


def select_points(cfg: StructureConfig, spec: str) -> PointSet:
    """Points named by ``spec``: ``antennas``, ``points`` (the config's [[points]]), ``all``, or a
    comma-separated list of antenna and point names (the keywords may be mixed in)."""
    n_p = len(cfg.point_names)
    table = {n: ("antenna", i) for i, n in enumerate(cfg.antenna_names)}
    table.update({n: ("point", i) for i, n in enumerate(cfg.point_names)})
    chosen = []
    for item in (s.strip() for s in spec.split(",")):
        if not item:
            continue
        if item in ("antennas", "all"):
            chosen += list(cfg.antenna_names)
        if item in ("points", "all"):
            chosen += list(cfg.point_names)
        if item in ("antennas", "points", "all"):
            continue
        if item not in table:
            raise CdgpsError(f"--points: {item!r} is not an antenna or a [[points]] name of config {cfg.name!r} "
                             f"(antennas: {', '.join(cfg.antenna_names)}; points: {', '.join(cfg.point_names) or 'none'}; "
                             "or the keywords antennas, points, all)")
        chosen.append(item)
    names = list(dict.fromkeys(chosen))
    if not names:
        raise CdgpsError(f"--points {spec!r} selects no point (config {cfg.name!r} has "
                         f"{len(cfg.antenna_names)} antennas and {n_p} [[points]])")
    sec, pos, disp = [], [], []
    for n in names:
        kind, i = table[n]
        if kind == "antenna":
            sec.append(cfg.antenna_section[i])
            pos.append(cfg.antenna_position_m[i])
            disp.append(cfg.antenna_displacement[i])
        else:
            sec.append(cfg.point_section[i])
            pos.append(cfg.point_position_m[i])
            disp.append(cfg.point_displacement[i])
    return PointSet(tuple(names), np.array(sec, dtype=int), np.array(pos, dtype=float).reshape(-1, 3),
                    np.array(disp, dtype=float).reshape(-1, 3, cfg.n_q))


def point_displacements(cfg: StructureConfig, pts: PointSet, xi: np.ndarray, P_xi: np.ndarray):
    """Displacements of the points and their 1-σ per lab axis.

    Parameters
    ----------
    cfg : StructureConfig
    pts : PointSet
    xi : ndarray, shape (N, n_m)
        Estimated modal positions.
    P_xi : ndarray, shape (N, n_m, n_m)
        Their covariances.

    Returns
    -------
    d_m : ndarray, shape (N, P, 3)
        p(U ξ) − p(0), metres, lab frame.
    sigma_m : ndarray, shape (N, P, 3)
        sqrt(diag(J U P_ξ Uᵀ Jᵀ)) per axis, metres.
    cov_m2 : ndarray, shape (N, P, 3, 3)
        The full 3×3 covariance of each point's displacement, m².
    """
    U = np.asarray(cfg.mode_shapes)
    q = np.asarray(xi, dtype=float) @ U.T
    p, J = point_positions(cfg, q, pts.section, pts.position_m, pts.displacement, jacobian=True)
    p0 = point_positions(cfg, np.zeros((1, cfg.n_q)), pts.section, pts.position_m, pts.displacement)
    JU = J @ U                                                   # (N, P, 3, n_m)
    cov = np.einsum("npim,nmk,npjk->npij", JU, np.asarray(P_xi, dtype=float), JU)
    sigma = np.sqrt(np.maximum(np.einsum("npii->npi", cov), 0.0))
    return p - p0, sigma, cov


def point_columns(cfg: StructureConfig, pts: PointSet, xi: np.ndarray, P_xi: np.ndarray) -> dict:
    """CSV columns ``<point>_d{x,y,z}_m`` and ``sigma_<point>_d{x,y,z}_m`` in point order."""
    d, s, _ = point_displacements(cfg, pts, xi, P_xi)
    cols = {}
    for k, name in enumerate(pts.names):
        for a, ax in enumerate("xyz"):
            cols[f"{name}_d{ax}_m"] = d[:, k, a]
        for a, ax in enumerate("xyz"):
            cols[f"sigma_{name}_d{ax}_m"] = s[:, k, a]
    return cols
