"""Tilt meter / inclinometer: the rotation of its mount about an axis, as an engine measurement model.

A tilt meter with unit axis e (body frame) on a mount whose small-angle rotation is θ = Θ q (its
section's rotation coordinates, its own FE mode-shape slopes ``rotation_rad``, the rigid rotation
about the vertical; :func:`cdgps_cli.measurement.sensor.rotation_map`) reads

    t = eᵀ Θ U ξ + b + ν     (rad)

with b its bias (a random-walk state) and ν white noise.  (An inclinometer built on accelerometers
also feels horizontal acceleration / g; this model takes the ideal rotation sensor.)
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.measurement.sensor import SampledSensor, axis_vectors, core_size, rotation_map

__all__ = ["TiltMeter"]


class TiltMeter(SampledSensor):
    """Parameters: ``cfg``; ``name``; ``axis`` ("x", "y", "z" or a 3-vector, or a list of them);
    ``values`` (M, n_axes) rad; ``k_of`` (N,); ``sigma_rad``; ``section`` index (−1: body);
    ``rotation_rad`` (3, n_q) optional; ``bias_sigma_rad`` / ``bias_drift_rad_per_sqrt_s`` (None: no
    bias state); ``n_core`` the leading states it is placed on (default 2 n_m)."""

    kind, quantity, unit = "tilt", "tilt", "rad"

    def __init__(self, cfg, name, axis, values, k_of, sigma_rad, section: int = -1, rotation_rad=None,
                 bias_sigma_rad=None, bias_drift_rad_per_sqrt_s=0.0, n_core: int | None = None):
        E, names = axis_vectors(axis)
        M = np.zeros((len(names), core_size(cfg, n_core)))
        M[:, :cfg.n_modes] = E @ rotation_map(cfg, section, rotation_rad) @ np.asarray(cfg.mode_shapes, float)
        super().__init__(name, names, values, k_of, sigma_rad, M, bias_sigma_rad, bias_drift_rad_per_sqrt_s)
