"""Positions of points on the structure (antennas, thrusters) as functions of the coordinates q.

A point attached to section ``s`` with nominal body-frame position ``r`` moves as

    p(q) = o + Rz(q_rigid) @ ( c_s + t_s(q) + R_s(q) @ (r - c_s) + D @ q )

where ``o`` is the body origin in the lab frame, ``c_s`` the section pivot, ``t_s`` the section's
translation (coordinates along body axes), ``R_s = Rz(θz) @ Ry(θy) @ Rx(θx)`` its rotation (exact,
large angles allowed), and ``D`` (3, n_q) an optional linear displacement per coordinate (mode
shapes at the point from finite-element software).  All functions are vectorized over epochs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # annotations only: the config reader (TOML, schema) is not on the rtk path
    from cdgps_cli.config.structure import StructureConfig


def _rot(axis: int, angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Elementary rotation matrices and their derivatives, shape (N, 3, 3) each."""
    c, s = np.cos(angle), np.sin(angle)
    n = angle.shape[0]
    R = np.zeros((n, 3, 3))
    dR = np.zeros((n, 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]   # plane of rotation, right-handed
    R[:, axis, axis] = 1.0
    R[:, i, i] = c
    R[:, j, j] = c
    R[:, i, j] = -s
    R[:, j, i] = s
    dR[:, i, i] = -s
    dR[:, j, j] = -s
    dR[:, i, j] = -c
    dR[:, j, i] = c
    return R, dR


def rotation_z(angle_rad: np.ndarray) -> np.ndarray:
    """Rotation about the vertical axis, shape (N, 3, 3)."""
    return _rot(2, np.atleast_1d(np.asarray(angle_rad, dtype=float)))[0]


def point_positions(cfg: StructureConfig, q: np.ndarray, section: np.ndarray, position_m: np.ndarray,
                    displacement: np.ndarray | None = None, jacobian: bool = False):
    """Lab-frame positions of body points, and optionally their Jacobians.

    Parameters
    ----------
    cfg : StructureConfig
    q : ndarray, shape (N, n_q)
        Generalized coordinates per epoch (metres / radians as declared in the config).
    section : ndarray of int, shape (P,)
        Section index per point, -1 for points fixed to the body frame.
    position_m : ndarray, shape (P, 3)
        Nominal positions in the body frame, metres.
    displacement : ndarray, shape (P, 3, n_q), optional
        Linear displacement per coordinate (metres per unit coordinate).
    jacobian : bool
        Also return ∂p/∂q.

    Returns
    -------
    p : ndarray, shape (N, P, 3)
        Positions in the lab frame, metres.
    J : ndarray, shape (N, P, 3, n_q)
        Only when ``jacobian`` is true.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n, n_q = q.shape
    P = len(section)
    local = np.empty((n, P, 3))
    dlocal = np.zeros((n, P, 3, n_q)) if jacobian else None
    rotations = {}                      # section → (R_s, [(coordinate, ∂R_s/∂q_j)]), computed once per section
    for k in range(P):
        s = int(section[k])
        r = np.asarray(position_m[k], dtype=float)
        if s < 0:
            local[:, k, :] = r
            continue
        sec = cfg.sections[s]
        if s not in rotations:
            rotations[s] = _section_rotation(sec, q, jacobian)
        Rtot, dR = rotations[s]
        rel = r - sec.pivot_m
        pos = sec.pivot_m + Rtot @ rel
        for axis, j in sec.translation:
            pos[:, axis] += q[:, j]
        local[:, k, :] = pos
        if jacobian:
            for axis, j in sec.translation:
                dlocal[:, k, axis, j] += 1.0
            for j, M in dR:
                dlocal[:, k, :, j] += M @ rel
    if displacement is not None:
        local += np.einsum("pij,nj->npi", displacement, q)
        if jacobian:
            dlocal += displacement[None]
    if cfg.rigid_index is not None:
        Rb, dRb = _rot(2, q[:, cfg.rigid_index])
        # stacked matmul: 2–4× less CPU than the equivalent einsum on these shapes
        p = local @ Rb.transpose(0, 2, 1) + cfg.body_origin_m
        if jacobian:
            J = Rb[:, None] @ dlocal
            J[:, :, :, cfg.rigid_index] += local @ dRb.transpose(0, 2, 1)
    else:
        p = local + cfg.body_origin_m
        J = dlocal
    return (p, J) if jacobian else p


def _section_rotation(sec, q: np.ndarray, jacobian: bool):
    """A section's rotation R_s = Rz(θz) @ Ry(θy) @ Rx(θx) over the epochs (N, 3, 3) and, with
    ``jacobian``, [(coordinate j, ∂R_s/∂q_j (N, 3, 3))] (the product with the factor of q_j differentiated)."""
    n = q.shape[0]
    mats = []
    for axis in (2, 1, 0):          # Rz @ Ry @ Rx
        j = next((jj for ax, jj in sec.rotation if ax == axis), None)
        if j is None:
            mats.append((None, None, None))
            continue
        Ra, dRa = _rot(axis, q[:, j])
        mats.append((j, Ra, dRa))
    Rtot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for j, Ra, _ in mats:
        if j is not None:
            Rtot = Rtot @ Ra
    dR = []
    if jacobian:
        for idx, (j, _, dRa) in enumerate(mats):
            if j is None:
                continue
            M = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
            for idx2, (j2, Ra2, _) in enumerate(mats):
                if j2 is None:
                    continue
                M = M @ (dRa if idx2 == idx else Ra2)
            dR.append((j, M))
    return Rtot, dR


def antenna_positions(cfg: StructureConfig, q: np.ndarray, jacobian: bool = False):
    """Lab-frame positions (N, n_a, 3) of every antenna (and Jacobians (N, n_a, 3, n_q))."""
    return point_positions(cfg, q, cfg.antenna_section, cfg.antenna_position_m,
                           cfg.antenna_displacement, jacobian=jacobian)


def gyro_matrix(cfg: StructureConfig) -> np.ndarray:
    """Small-angle rate-gyro map G, shape (n_g, n_q): rate_rad_s = G @ dq/dt.

    A single-axis gyro with axis a reads a · ω, where ω is the sum of its section's rotation rates
    about its axes, its mode-shape rotations (``rotation_rad``) and the rigid-body rate about the
    vertical (see :func:`cdgps_cli.config.structure.gyro_rate_map`).
    """
    from cdgps_cli.config.structure import gyro_rate_map  # noqa: PLC0415 (see the module imports)
    return gyro_rate_map(cfg.sections, cfg.gyro_section, cfg.gyro_axis, cfg.gyro_rotation, cfg.rigid_index, cfg.n_q)


def thruster_forcing(cfg: StructureConfig) -> np.ndarray:
    """Generalized force per newton of each thruster, Υ of Eq. (5), shape (n_q, n_u).

    Υ[:, k] = J_k(0)ᵀ d_k with J_k the Jacobian of the thruster's attachment point at q = 0 and
    d_k its unit force direction (virtual work), so that modal forcing is Uᵀ Υ u for
    mass-normalized mode shapes.
    """
    n_u = len(cfg.thruster_names)
    if n_u == 0:
        return np.zeros((cfg.n_q, 0))
    _, J = point_positions(cfg, np.zeros((1, cfg.n_q)), cfg.thruster_section, cfg.thruster_position_m,
                           None, jacobian=True)
    return np.einsum("kiq,ki->qk", J[0], cfg.thruster_direction)


class EpochGeometry:
    """Single-epoch antenna positions and Jacobians, precompiled from a config for speed.

    Same model as :func:`point_positions` (tested against it) but organized for one state at a
    time, as the Kalman filter needs: all section rotations are built at once from closed-form
    entries, and the constant parts of the Jacobian (translations, linear displacements) are
    precomputed.
    """

    def __init__(self, cfg: StructureConfig):
        self.cfg = cfg
        S = len(cfg.sections)
        nq = cfg.n_q
        self.rot_idx = np.full((S, 3), -1, dtype=int)      # coordinate driving rotation about x, y, z
        for s, sec in enumerate(cfg.sections):
            for axis, j in sec.rotation:
                self.rot_idx[s, axis] = j
        self.rot_mask = self.rot_idx >= 0
        self.rot_take = np.where(self.rot_mask, self.rot_idx, 0)
        sec = np.asarray(cfg.antenna_section)
        self.on_section = sec >= 0
        self.sec = np.where(sec >= 0, sec, 0)
        A = len(sec)
        pivots = np.array([s.pivot_m for s in cfg.sections]) if S else np.zeros((0, 3))
        self.pivot = np.where(self.on_section[:, None], pivots[self.sec] if S else 0.0, 0.0)
        self.rel = np.asarray(cfg.antenna_position_m) - self.pivot
        self.D = np.asarray(cfg.antenna_displacement)                      # (A, 3, nq)
        self.J_const = self.D.copy()
        self.trans = []
        for a in range(A):
            if self.on_section[a]:
                for axis, j in cfg.sections[self.sec[a]].translation:
                    self.J_const[a, axis, j] += 1.0
                    self.trans.append((a, axis, j))
        self.trans_a = np.array([t[0] for t in self.trans], dtype=int)
        self.trans_ax = np.array([t[1] for t in self.trans], dtype=int)
        self.trans_j = np.array([t[2] for t in self.trans], dtype=int)
        # rotation Jacobian scatter: for each antenna on a section and each driven axis
        pairs = [(a, axis, self.rot_idx[self.sec[a], axis]) for a in range(A) if self.on_section[a]
                 for axis in range(3) if self.rot_idx[self.sec[a], axis] >= 0]
        self.rj_a = np.array([p[0] for p in pairs], dtype=int)
        self.rj_axis = np.array([p[1] for p in pairs], dtype=int)
        self.rj_q = np.array([p[2] for p in pairs], dtype=int)
        self.rigid = cfg.rigid_index
        self.origin = np.asarray(cfg.body_origin_m)
        self.has_D = bool(np.any(self.D))
        self.all_on_section = bool(np.all(self.on_section))
        self.rj_sec = self.sec[self.rj_a] if self.rj_a.size else self.rj_a
        self.rel_rj = self.rel[self.rj_a][:, :, None] if self.rj_a.size else None
        self.rel_col = self.rel[:, :, None]
        self.nq = nq
        self.A = A

    # templates: an elementary rotation about axis a is T0[a] + cos·Tc[a] + sin·Ts[a] (3×3)
    _T0 = np.zeros((3, 3, 3))
    _Tc = np.zeros((3, 3, 3))
    _Ts = np.zeros((3, 3, 3))
    for _a, (_i, _j) in enumerate([(1, 2), (2, 0), (0, 1)]):
        _T0[_a, _a, _a] = 1.0
        _Tc[_a, _i, _i] = _Tc[_a, _j, _j] = 1.0
        _Ts[_a, _i, _j] = -1.0
        _Ts[_a, _j, _i] = 1.0

    def _section_rotations(self, q):
        ang = np.where(self.rot_mask, q[self.rot_take], 0.0)              # (S, 3) θx, θy, θz
        c = np.cos(ang)[..., None, None]
        s = np.sin(ang)[..., None, None]
        E = self._T0 + c * self._Tc + s * self._Ts                        # (S, 3, 3, 3) Rx, Ry, Rz
        dE = c * self._Ts - s * self._Tc                                  # their derivatives
        Rx, Ry, Rz = E[:, 0], E[:, 1], E[:, 2]
        RzRy = Rz @ Ry
        R = RzRy @ Rx
        dR = np.stack([RzRy @ dE[:, 0], Rz @ dE[:, 1] @ Rx, dE[:, 2] @ Ry @ Rx], axis=1)  # (S, 3, 3, 3)
        return R, dR

    def positions(self, q: np.ndarray, jacobian: bool = True):
        """Antenna positions (A, 3) in the lab frame and Jacobians (A, 3, n_q) for one q (n_q,)."""
        q = np.asarray(q, dtype=float)
        local = self.pivot + self.D @ q if self.has_D else self.pivot
        J = self.J_const.copy() if jacobian else None
        if len(self.cfg.sections):
            R, dR = self._section_rotations(q)
            rot = (R[self.sec] @ self.rel_col)[:, :, 0]                     # (A, 3)
            local = local + (rot if self.all_on_section else np.where(self.on_section[:, None], rot, self.rel))
            if self.trans:
                local[self.trans_a, self.trans_ax] += q[self.trans_j]        # (antenna, axis) pairs are unique
            if jacobian and self.rj_a.size:
                cols = (dR[self.rj_sec, self.rj_axis] @ self.rel_rj)[:, :, 0]
                J[self.rj_a, :, self.rj_q] += cols                           # (antenna, coordinate) pairs are unique
        else:
            local = local + self.rel
        if self.rigid is not None:
            psi = float(q[self.rigid])
            c, s = np.cos(psi), np.sin(psi)
            Rb = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            p = local @ Rb.T + self.origin
            if jacobian:
                J = np.matmul(Rb, J)                                         # (3,3) @ (A,3,nq)
                dRb = np.array([[-s, -c, 0.0], [c, -s, 0.0], [0.0, 0.0, 0.0]])
                J[:, :, self.rigid] += local @ dRb.T
        else:
            p = local + self.origin
        return (p, J) if jacobian else p


def section_angles(cfg: StructureConfig) -> list[tuple[str, str, np.ndarray]]:
    """The angles reports speak of, as small-angle sums of rotation coordinates.

    One angle per section and body axis the section rotates about (its own coordinate, plus the
    rigid-body rotation about the vertical for the z axis: ``C2_z`` = q6+q10 on the testbed), and
    ``body_z`` for the rigid-body rotation itself.

    Returns
    -------
    list of (name, expression, coefficients)
        ``name`` is a plain identifier (letters, digits, ``_``) usable as a field name; the
        expression is the sum as text (``"q6+q10"``); coefficients has shape (n_q,), rad per
        coordinate unit.
    """
    out, used = [], set()

    def add(label: str, coef: np.ndarray) -> None:
        name = "".join(ch if ch.isascii() and (ch.isalnum() or ch == "_") else "_" for ch in label)
        if not name or name[0].isdigit():
            name = "s_" + name
        base, i = name, 2
        while name in used:
            name, i = f"{base}_{i}", i + 1
        used.add(name)
        expr = "+".join(cfg.coord_names[j] for j in np.flatnonzero(coef))
        out.append((name, expr, coef))

    if cfg.rigid_index is not None:
        c = np.zeros(cfg.n_q)
        c[cfg.rigid_index] = 1.0
        add("body_z", c)
    for s in cfg.sections:
        for axis in sorted({a for a, _ in s.rotation}):
            c = np.zeros(cfg.n_q)
            for a, j in s.rotation:
                if a == axis:
                    c[j] += 1.0
            if axis == 2 and cfg.rigid_index is not None:
                c[cfg.rigid_index] += 1.0
            add(f"{s.name}_{'xyz'[axis]}", c)
    return out
