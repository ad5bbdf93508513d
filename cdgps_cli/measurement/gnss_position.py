"""A GNSS antenna's position solution (RTK / PPP, position domain) as an engine measurement model.

The antenna's displacement from its nominal position, in the structure frame, against a reference
off the structure (a base on the ground):

    z = p_a(U ξ) − p_a(0) + ν     (m, per axis x, y, z)

(:func:`cdgps_cli.model.kinematics.point_positions`, non-linear with section rotations), ν white with
σ per axis.  The carrier-phase models (:class:`~cdgps_cli.measurement.model.SatelliteDDModal`) stack
with the sensors the same way; this one is the position-domain GNSS of the fusion literature
(docs/adding-a-sensor.md) and of the fusion benchmark.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.measurement.sensor import SampledSensor, core_size
from cdgps_cli.model.kinematics import point_positions
from cdgps_cli.model.points import select_points

__all__ = ["GnssPosition"]


class GnssPosition(SampledSensor):
    """Parameters: ``cfg``; ``antenna`` (antenna or ``[[points]]`` name); ``values`` (M, 3) m;
    ``k_of`` (N,); ``sigma_m`` (one or per axis); ``n_core`` (default 2 n_m)."""

    kind, quantity, unit = "gnss_position", "gnss", "m"

    def __init__(self, cfg, antenna, values, k_of, sigma_m, n_core: int | None = None):
        self.cfg, self.pts = cfg, select_points(cfg, antenna)
        self.U = np.asarray(cfg.mode_shapes, dtype=float)
        self.p0 = point_positions(cfg, np.zeros((1, cfg.n_q)), self.pts.section, self.pts.position_m,
                                  self.pts.displacement)[0, 0]
        super().__init__(antenna, ["x", "y", "z"], values, k_of, sigma_m, np.zeros((3, core_size(cfg, n_core))))

    def response(self, x):
        nm = self.cfg.n_modes
        q = self.U @ np.asarray(x, dtype=float)[:nm]
        p, J = point_positions(self.cfg, q[None], self.pts.section, self.pts.position_m, self.pts.displacement,
                               jacobian=True)
        H = np.zeros((3, self.n_core))
        H[:, :nm] = J[0, 0] @ self.U
        return p[0, 0] - self.p0, H
