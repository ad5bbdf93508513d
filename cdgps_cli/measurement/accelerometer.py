"""Accelerometer (uniaxial or triaxial) at a point of the structure, as an engine measurement model.

Each axis e (unit vector, body frame) of an accelerometer at point P reads the dynamic specific force

    a = eᵀ J_P U ξ̈ + g (e × ẑ)ᵀ Θ_P U ξ + b + ν,     ξ̈ = −Λ ξ − C ξ̇ + S d     (m/s²)

with J_P = ∂p_P/∂q at q = 0 (the mode shapes' translation at the point), ξ̈ from the modal dynamics
(:func:`cdgps_cli.model.fusion_dynamics.modal_acceleration_map`) and the held disturbance d when the
state carries it (:class:`~cdgps_cli.model.fusion_dynamics.ModalDisturbance`; else ξ̈ lacks it), the
second term the gravity seen by an axis tilted by the mount's rotation θ = Θ_P q (small angles; the
static 1 g on a vertical axis is removed by the reader), b the axis's bias (a random-walk state) and
ν white noise.  Terms of second order in the motion (centripetal, J̇ q̇) and thruster inputs are left out.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.constants import STANDARD_GRAVITY_M_S2
from cdgps_cli.measurement.sensor import SampledSensor, axis_vectors, rotation_map, translation_map
from cdgps_cli.model.fusion_dynamics import modal_acceleration_map

__all__ = ["Accelerometer"]


class Accelerometer(SampledSensor):
    """Parameters: ``cfg``; ``name``; ``point`` (an antenna or ``[[points]]`` name); ``axes`` ("x",
    ["x", "y", "z"] or 3-vectors, body frame); ``values`` (M, n_axes) m/s²; ``k_of`` (N,);
    ``sigma_m_s2``; ``bias_sigma_m_s2`` / ``bias_drift_m_s2_per_sqrt_s`` (None: no bias state);
    ``rotation_rad`` (3, n_q) the mount's own rotation per unit coordinate (FE slopes), optional;
    ``disturbance`` S (n_m, r) of the state's d (None: state [ξ, ξ̇]); ``gravity_m_s2`` (0: no tilt term)."""

    kind, quantity, unit = "accel", "accel", "m_s2"

    def __init__(self, cfg, name, point, axes, values, k_of, sigma_m_s2, bias_sigma_m_s2=None,
                 bias_drift_m_s2_per_sqrt_s=0.0, rotation_rad=None, disturbance=None,
                 gravity_m_s2: float = STANDARD_GRAVITY_M_S2):
        E, names = axis_vectors(axes)
        J0, section = translation_map(cfg, point)
        U = np.asarray(cfg.mode_shapes, dtype=float)
        nm = cfg.n_modes
        S = np.zeros((nm, 0)) if disturbance is None else np.asarray(disturbance, dtype=float)
        acc = np.hstack([modal_acceleration_map(cfg), S])                 # ξ̈ = acc @ x_core
        M = E @ J0 @ U @ acc
        tilt = float(gravity_m_s2) * np.cross(E, [0.0, 0.0, 1.0]) @ rotation_map(cfg, section, rotation_rad) @ U
        M[:, :nm] += tilt
        self.point = point
        super().__init__(name, names, values, k_of, sigma_m_s2, M, bias_sigma_m_s2, bias_drift_m_s2_per_sqrt_s)
