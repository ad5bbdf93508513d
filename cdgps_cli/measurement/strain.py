"""Long-gauge strain sensor (a fibre-optic long-gauge sensor, an extensometer) between two points of
the structure, as an engine measurement model.

A gauge from point A to point B (antennas or ``[[points]]``; nominal positions p_A, p_B, gauge
length L = |p_B − p_A|, unit direction e = (p_B − p_A)/L) reads the change of its length per unit
length; to first order in the motion (q = U ξ, J_P = ∂p_P/∂q at q = 0,
:func:`cdgps_cli.measurement.sensor.translation_map`)

    ε = eᵀ (J_B − J_A) U ξ / L + b + ν     (dimensionless, unit "1")

with b its bias (a random-walk state: the gauge's zero drift) and ν white noise.  Rigid motion of
the whole structure leaves it at zero (J_B = J_A for a rigid translation; a small rigid rotation
moves B − A perpendicular to e).  Field ``strain_gauge_1``.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.sensor import SampledSensor, core_size

__all__ = ["StrainGauge", "gauge_map"]


def gauge_map(cfg, point_a: str, point_b: str) -> tuple[np.ndarray, float]:
    """(eᵀ (J_B − J_A) / L (n_q,), L m) of a gauge from ``point_a`` to ``point_b``."""
    from cdgps_cli.model.kinematics import point_positions  # noqa: PLC0415
    from cdgps_cli.model.points import select_points  # noqa: PLC0415

    ends = []
    for name in (point_a, point_b):
        pts = select_points(cfg, name)
        p, J = point_positions(cfg, np.zeros((1, cfg.n_q)), pts.section, pts.position_m, pts.displacement, jacobian=True)
        ends.append((p[0, 0], J[0, 0]))
    d = ends[1][0] - ends[0][0]
    L = float(np.linalg.norm(d))
    if not L > 0:
        raise CdgpsError(f"{cfg.path}: strains: point_a {point_a!r} and point_b {point_b!r} are at the same place "
                         "(gauge length 0); expected a gauge between two distinct positions")
    return (d / L) @ (ends[1][1] - ends[0][1]) / L, L


class StrainGauge(SampledSensor):
    """Parameters: ``cfg``; ``name``; ``point_a``, ``point_b`` (antenna or ``[[points]]`` names);
    ``values`` (M, 1) strain; ``k_of`` (N,); ``sigma`` (strain); ``bias_sigma`` / ``bias_drift`` (per
    √s; None: no bias state); ``n_core`` the leading states it is placed on (default 2 n_m)."""

    kind, quantity, unit = "strain", "strain", "1"

    def __init__(self, cfg, name, point_a, point_b, values, k_of, sigma, bias_sigma=None, bias_drift=0.0,
                 n_core: int | None = None):
        g, self.gauge_length_m = gauge_map(cfg, point_a, point_b)
        M = np.zeros((1, core_size(cfg, n_core)))
        M[0, :cfg.n_modes] = g @ np.asarray(cfg.mode_shapes, float)
        super().__init__(name, ["gauge"], values, k_of, sigma, M, bias_sigma, bias_drift)
