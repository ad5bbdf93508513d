"""Rate gyro as a measurement (the config's ``[[gyros]]``: axis, section, ``rotation_rad``), as an
engine measurement model.

Gyro g reads the rate of its mount's rotation about its axis (the small-angle map G of
:func:`cdgps_cli.model.kinematics.gyro_matrix`, the one the spectra's gyro check and the simulator use):

    ω = G_g U ξ̇ + b + ν     (rad/s)

with b its bias (a random-walk state, as the simulator's drift) and ν white noise.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.measurement.sensor import SampledSensor, axis_vectors, core_size
from cdgps_cli.model.kinematics import gyro_matrix

__all__ = ["RateGyro"]


class RateGyro(SampledSensor):
    """Parameters: ``cfg``; ``gyros`` names of ``[[gyros]]`` read together (one axis each);
    ``values`` (M, n_gyros) rad/s; ``k_of`` (N,); ``sigma_rad_s``; ``bias_sigma_rad_s`` /
    ``bias_drift_rad_s_per_sqrt_s`` (None: no bias state); ``n_core`` (default 2 n_m); ``name``
    (default "gyros").  Fields ``gyro_<axis>_rad_s`` (the gyros' axes x, y, z; their names when two
    share an axis or an axis is skewed)."""

    kind, quantity, unit = "gyro", "gyro", "rad_s"

    def __init__(self, cfg, gyros, values, k_of, sigma_rad_s, bias_sigma_rad_s=None,
                 bias_drift_rad_s_per_sqrt_s=0.0, n_core: int | None = None, name: str = "gyros"):
        idx = [list(cfg.gyro_names).index(g) for g in gyros]
        nm = cfg.n_modes
        M = np.zeros((len(idx), core_size(cfg, n_core)))
        M[:, nm:2 * nm] = gyro_matrix(cfg)[idx] @ np.asarray(cfg.mode_shapes, float)
        _, axes = axis_vectors([tuple(cfg.gyro_axis[i]) for i in idx])
        if len(set(axes)) < len(axes) or any(a.startswith("a") for a in axes):
            axes = list(gyros)                       # several gyros about one axis, or skewed axes: by name
        super().__init__(name, axes, values, k_of, sigma_rad_s, M, bias_sigma_rad_s, bias_drift_rad_s_per_sqrt_s)
