"""The common part of sampled structure sensors (accelerometer, tilt meter, rate gyro, GNSS position)
as engine measurement models (:class:`cdgps_cli.measurement.model.MeasurementModel`).

A sensor has ``n_axes`` axes sampled at its own times; on the filter's common time axis (the union
of every model's epochs, so the dynamics propagate at the fastest rate) ``k_of[k]`` is the sample
read at epoch k (−1: none, the multi-rate case: that epoch has no rows of this model).  Each axis
reads, in the sensor's unit,

    z = M x_core + b + ν,   ν ~ N(0, σ²)

with M (n_axes, n_core) the sensor's linear map on the leading ``n_core`` states ([ξ, ξ̇] or
[ξ, ξ̇, d], :mod:`cdgps_cli.model.fusion_dynamics`) and b the axis's bias: a state appended to the
state vector (``extra_states``: name, prior σ, random-walk σ per √s) when the sensor has a bias,
else none.  :func:`place` gives each model its bias columns after the core states, in order.
Rows are labelled (sensor name, ``<quantity>_<axis>_<unit>``), e.g. ("top", "accel_x_m_s2").
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.measurement.model import MeasurementModel, Rows

__all__ = ["SampledSensor", "align_epochs", "place", "axis_vectors", "rotation_map", "translation_map", "core_size", "AXIS_NAMES"]

AXIS_NAMES = ("x", "y", "z")


def axis_vectors(axes) -> tuple[np.ndarray, list]:
    """Unit axes (n, 3) and their names from "x", ["x", "y"], or 3-vectors (x, y, z for the basis
    vectors, else a0, a1 … by position)."""
    items = [axes] if isinstance(axes, str) or (len(axes) == 3 and not isinstance(axes[0], (str, list, tuple, np.ndarray))) \
        else list(axes)
    vecs, names = [], []
    for i, a in enumerate(items):
        if isinstance(a, str):
            vecs.append(np.eye(3)[AXIS_NAMES.index(a)])
            names.append(a)
        else:
            v = np.asarray(a, dtype=float)
            v = v / np.linalg.norm(v)
            basis = np.flatnonzero(np.isclose(np.abs(v), 1.0) & (v > 0))
            vecs.append(v)
            names.append(AXIS_NAMES[int(basis[0])] if basis.size else f"a{i}")   # a basis vector keeps its name
    return np.array(vecs).reshape(-1, 3), names


def align_epochs(common_time_s, sensor_time_s, tol_s: float = 1e-6) -> np.ndarray:
    """k_of (N,): the sensor sample at each common epoch (within ``tol_s``), −1 where none."""
    t = np.asarray(common_time_s, dtype=float)
    ts = np.asarray(sensor_time_s, dtype=float)
    k_of = np.full(t.size, -1, dtype=np.int64)
    if ts.size == 0 or t.size == 0:
        return k_of
    j = np.clip(np.searchsorted(t, ts), 0, t.size - 1)
    jm = np.clip(j - 1, 0, t.size - 1)
    j = np.where(np.abs(t[jm] - ts) < np.abs(t[j] - ts), jm, j)
    ok = np.abs(t[j] - ts) <= tol_s
    k_of[j[ok]] = np.flatnonzero(ok)
    return k_of


class SampledSensor(MeasurementModel):
    """A sensor of ``n_axes`` axes, linear in the state, with optional per-axis bias states.

    Parameters
    ----------
    name : str
        The sensor's name (first element of each row label).
    axis_names : list of str
    values : ndarray (M, n_axes)
        Samples in the sensor's unit (NaN: missing).
    k_of : ndarray (N,) int
        Sample index at each common epoch, −1: none.
    sigma : float or ndarray (n_axes,)
        White-noise σ per axis, sensor unit.
    M : ndarray (n_axes, n_core)
        The linear map on the leading ``n_core`` states.
    bias_sigma, bias_drift : float or None
        Prior σ of the bias (unit) and its random walk (unit/√s); None: no bias state.
    """

    kind = ""          # registry key
    quantity = ""      # first part of the field name (accel, tilt, gyro, gnss)
    unit = ""          # unit of the readings in field names (m_s2, rad, rad_s, m)

    def __init__(self, name, axis_names, values, k_of, sigma, M, bias_sigma=None, bias_drift=0.0):
        self.name, self.axis_names = str(name), list(axis_names)
        self.values = np.asarray(values, dtype=float).reshape(-1, len(self.axis_names))
        self.k_of = np.asarray(k_of, dtype=np.int64)
        self.n_epochs = self.k_of.size
        self.sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (len(self.axis_names),)).copy()
        if not np.all(np.isfinite(self.sigma) & (self.sigma > 0)):
            raise ValueError(f"{self.name}: sigma must be positive and finite on every axis, got {sigma!r}")
        self.M = np.asarray(M, dtype=float)
        self.n_core = self.M.shape[1]
        self.fields = [f"{self.quantity}_{a}_{self.unit}" for a in self.axis_names]
        self.extra_states = [] if bias_sigma is None else [
            (f"{self.name}_bias_{f}", float(bias_sigma), float(bias_drift)) for f in self.fields]
        self.bias_offset = self.n_core
        self.n_state = self.n_core + len(self.extra_states)
        self.segment_keys: list = []

    def rows(self, k: int) -> Rows | None:
        j = self.k_of[k]
        if j < 0:
            return None
        v = self.values[j]
        ax = np.flatnonzero(np.isfinite(v))
        if ax.size == 0:
            return None
        return Rows(v[ax].copy(), [(self.name, self.fields[i]) for i in ax], np.full(ax.size, -1, dtype=np.int64),
                    sigma_m=self.sigma[ax].copy(), context=ax)

    def response(self, x) -> tuple[np.ndarray, np.ndarray]:
        """(h (n_axes,), ∂h/∂x_core (n_axes, n_core)) without the bias; linear unless overridden."""
        return self.M @ np.asarray(x, dtype=float)[:self.n_core], self.M

    def predict(self, x, rows: Rows):
        x = np.asarray(x, dtype=float)
        ax = np.asarray(rows.context, dtype=int)
        h_all, Hc = self.response(x)
        h = h_all[ax].copy()
        H = np.zeros((ax.size, self.n_state))
        H[:, :self.n_core] = Hc[ax]
        if self.extra_states:
            cols = self.bias_offset + ax
            h += x[cols]
            H[np.arange(ax.size), cols] = 1.0
        return h, H


def place(models, n_core: int) -> int:
    """Give each model its bias columns after the ``n_core`` core states, in order; returns the total
    state size (set as every model's ``n_state``)."""
    off = n_core
    for m in models:
        if hasattr(m, "bias_offset"):
            m.bias_offset = off
        off += len(getattr(m, "extra_states", ()))
    for m in models:
        if hasattr(m, "bias_offset"):
            m.n_state = off
    return off


def rotation_map(cfg, section: int, rotation_rad=None) -> np.ndarray:
    """Small-angle rotation vector of a mount per unit coordinate, Θ (3, n_q): θ_rad = Θ q, from its
    section's rotation coordinates, its own ``rotation_rad`` (3, n_q; FE mode-shape slopes) and the
    rigid-body rotation about the vertical (the gyros' map, :func:`cdgps_cli.config.structure.gyro_rate_map`)."""
    from cdgps_cli.config.structure import gyro_rate_map  # noqa: PLC0415

    rot = None if rotation_rad is None else np.broadcast_to(np.asarray(rotation_rad, float), (3, 3, cfg.n_q))
    return gyro_rate_map(cfg.sections, [int(section)] * 3, np.eye(3), rot, cfg.rigid_index, cfg.n_q)


def translation_map(cfg, point: str) -> tuple[np.ndarray, int]:
    """∂p/∂q at q = 0 (3, n_q) of an antenna or ``[[points]]`` name, and its section (−1: body)."""
    from cdgps_cli.model.kinematics import point_positions  # noqa: PLC0415
    from cdgps_cli.model.points import select_points  # noqa: PLC0415

    pts = select_points(cfg, point)
    _, J = point_positions(cfg, np.zeros((1, cfg.n_q)), pts.section, pts.position_m, pts.displacement, jacobian=True)
    return J[0, 0], int(pts.section[0])


def core_size(cfg, n_core: int | None) -> int:
    """The core state size: ``n_core`` or 2 n_m ([ξ, ξ̇])."""
    n = 2 * cfg.n_modes if n_core is None else int(n_core)
    if n < 2 * cfg.n_modes:
        raise ValueError(f"n_core must be at least 2 n_m = {2 * cfg.n_modes}, got {n}")
    return n
