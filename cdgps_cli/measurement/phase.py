"""Differential carrier-phase measurement model h(x) and its analytic Jacobian.

For rover antenna a, master M and transmitter j (Teague, How & Parkinson 1998, Eq. 2):

* near field (pseudolites):  h = |p_j − p_a| − |p_j − p_M|
* far field (planar wavefront, Teague et al. 1995 Eq. 1): the limit of the above for a source
  at infinity in unit direction s_j:  h = −s_jᵀ (p_a − p_M)

The measured phase in metres is λ·phase_cycles = h + b + ν with b = line bias + λ·(integer).
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.table import Table
from cdgps_cli.model.kinematics import antenna_positions


def channel_indices(cfg: StructureConfig, antennas, transmitters) -> tuple[np.ndarray, np.ndarray]:
    """Map antenna and transmitter names to config indices (arrays of equal length)."""
    ai = {n: i for i, n in enumerate(cfg.antenna_names)}
    ti = {n: i for i, n in enumerate(cfg.transmitter_names)}
    return (np.array([ai[a] for a in antennas], dtype=int), np.array([ti[t] for t in transmitters], dtype=int))


def row_channel_indices(cfg: StructureConfig, phase: Table, where: str = "phase table",
                        rows=None) -> tuple[np.ndarray, np.ndarray]:
    """Each row's antenna and transmitter index in the config, for a run's phase table.

    Parameters
    ----------
    cfg : StructureConfig
    phase : Table
        The run's phase table (:attr:`cdgps_cli.core.records.Run.phase`), R rows.
    where : str
        What to name in an error (the run's path).
    rows : ndarray of bool or int, optional
        Those rows only (default: all).

    Returns
    -------
    antenna, transmitter : ndarray (R,) of int64 (R: the rows selected)

    Raises
    ------
    CdgpsError
        A row names an antenna or transmitter the config does not have (listed).
    """
    bad = (phase.names_not_in("antenna", cfg.antenna_names, rows)
           + phase.names_not_in("transmitter", cfg.transmitter_names, rows))
    if bad:
        raise CdgpsError(f"{where}: antenna/transmitter not in the config: {', '.join(sorted(bad))}")
    return (phase.index_in("antenna", cfg.antenna_names, rows),
            phase.index_in("transmitter", cfg.transmitter_names, rows))


def all_channels(cfg: StructureConfig) -> tuple[np.ndarray, np.ndarray]:
    """Antenna and transmitter indices of every rover×transmitter channel, rover-major."""
    rov = cfg.rover_indices
    nt = len(cfg.transmitter_names)
    return np.repeat(rov, nt), np.tile(np.arange(nt), len(rov))


def phase_model_q(cfg: StructureConfig, q: np.ndarray, ant: np.ndarray, tx: np.ndarray,
                  jacobian: bool = False):
    """Geometric differential range h(q) in metres, per epoch and channel.

    Parameters
    ----------
    q : ndarray, shape (N, n_q)
    ant, tx : ndarray of int, shape (C,)
        Rover antenna and transmitter index of each channel.
    jacobian : bool
        Also return ∂h/∂q, shape (N, C, n_q).

    Returns
    -------
    h : ndarray, shape (N, C), metres
    """
    q = np.atleast_2d(q)
    if jacobian:
        p, J = antenna_positions(cfg, q, jacobian=True)
    else:
        p = antenna_positions(cfg, q)
    m = cfg.master_index
    pa, pm = p[:, ant, :], p[:, m, :][:, None, :]
    if cfg.transmitter_far_field:
        s = cfg.transmitter_position_m[tx]              # (C, 3) unit directions
        h = -np.einsum("ci,nci->nc", s, pa - pm)
        if not jacobian:
            return h
        dh = -np.einsum("ci,nciq->ncq", s, J[:, ant] - J[:, m][:, None])
        return h, dh
    tpos = cfg.transmitter_position_m[tx]               # (C, 3)
    va = tpos[None] - pa
    vm = tpos[None] - pm
    da = np.linalg.norm(va, axis=2)
    dm = np.linalg.norm(vm, axis=2)
    h = da - dm
    if not jacobian:
        return h
    ua = va / da[..., None]
    um = vm / dm[..., None]
    # ∂h/∂q = −u_aᵀ J_a + u_Mᵀ J_M: one batched product per antenna (no (N, C, 3, n_q) copy of J)
    dh = um @ J[:, m]
    for a in np.unique(ant).tolist():
        cs = np.flatnonzero(ant == a)
        dh[:, cs] -= ua[:, cs] @ J[:, a]
    return h, dh


def phase_model(cfg: StructureConfig, x: np.ndarray, ant: np.ndarray, tx: np.ndarray, jacobian: bool = False):
    """h(x) on the modal state x = [ξ, ξ̇] (N, 2·n_m); with ``jacobian`` also H = ∂h/∂x (N, C, 2·n_m)."""
    x = np.atleast_2d(x)
    nm = cfg.n_modes
    U = cfg.mode_shapes
    q = x[:, :nm] @ U.T
    if not jacobian:
        return phase_model_q(cfg, q, ant, tx)
    h, dq = phase_model_q(cfg, q, ant, tx, jacobian=True)
    H = np.zeros(dq.shape[:2] + (2 * nm,))
    H[:, :, :nm] = dq @ U
    return h, H


class EpochPhaseModel:
    """h(x) and H = ∂h/∂x for one modal state, fast path for the Kalman filter.

    Equivalent to :func:`phase_model` with N = 1 (tested against it).
    """

    def __init__(self, cfg: StructureConfig, ant: np.ndarray, tx: np.ndarray):
        from cdgps_cli.model.kinematics import EpochGeometry

        self.cfg = cfg
        self.geo = EpochGeometry(cfg)
        self.ant = np.asarray(ant, dtype=int)
        self.tx = np.asarray(tx, dtype=int)
        self.m = cfg.master_index
        self.U = np.asarray(cfg.mode_shapes)
        self.nm = cfg.n_modes
        self.far = cfg.transmitter_far_field
        self.tpos = np.asarray(cfg.transmitter_position_m)[self.tx]

    def __call__(self, x: np.ndarray):
        nm = self.nm
        q = self.U @ x[:nm]
        p, J = self.geo.positions(q)
        pa = p[self.ant]
        Ja = J[self.ant]                                                    # (C, 3, nq)
        if self.far:
            s = self.tpos
            h = -np.sum(s * (pa - p[self.m]), axis=1)
            dq = -(s[:, None, :] @ (Ja - J[self.m]))[:, 0, :]
        else:
            va = self.tpos - pa
            vm = self.tpos - p[self.m]
            da = np.sqrt(np.sum(va * va, axis=1))
            dm = np.sqrt(np.sum(vm * vm, axis=1))
            h = da - dm
            ua = va / da[:, None]
            um = vm / dm[:, None]
            dq = um @ J[self.m] - (ua[:, None, :] @ Ja)[:, 0, :]
        H = np.zeros((len(h), 2 * nm))
        H[:, :nm] = dq @ self.U
        return h, H
