"""The measurement-model interface of the estimation engine (../shared/design/architecture.md).

For epoch k a model gives what that epoch contributes, :meth:`MeasurementModel.rows` → :class:`Rows`:
observed-minus-known values z (m), a label per row, the noise (a diagonal σ, or the lower Cholesky
factor L of a full covariance C = L Lᵀ, e.g. D Σ Dᵀ of double differences correlated across rovers
through the common master) and each row's ambiguity-segment column; :meth:`MeasurementModel.predict`
gives h(x) (m) and H = ∂h/∂x for those rows.  The observation is z = h(x) + b_segment + ν, ν ~ N(0, C).

Implementations:

* :class:`PseudoliteSD` — single differences to pseudolites / far-field transmitters on the modal
  state (Eq. 2; :class:`cdgps_cli.measurement.phase.EpochPhaseModel`), diagonal σ per channel;
* :class:`SatelliteDDModal` — satellite double differences on the modal state (the structure placed
  on the Earth, :mod:`cdgps_cli.pipeline.gnss_modal`), far-field with the satellites' directions of
  that epoch, noise D Σ Dᵀ jointly over the rovers (:func:`cdgps_cli.measurement.differencing.joint_dd_covariance`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.measurement.differencing import joint_dd_covariance
from cdgps_cli.measurement.phase import EpochPhaseModel
from cdgps_cli.model.kinematics import EpochGeometry

__all__ = ["Rows", "MeasurementModel", "PseudoliteSD", "SatelliteDDModal", "dd_modal_h_and_H"]


@dataclass
class Rows:
    """What one epoch contributes (m rows).

    Attributes
    ----------
    z_m : ndarray (m,)
        Observed minus known values, m.
    labels : list of tuple
        One label per row (model-specific: (antenna, transmitter) or (rover slot, satellite)).
    segment : ndarray (m,) int
        Ambiguity-segment column of each row (index into the model's ``segment_keys``), −1: none.
    sigma_m : ndarray (m,) or None
        Diagonal noise σ, m (exactly one of ``sigma_m`` / ``chol_m`` is given).
    chol_m : ndarray (m, m) or None
        Lower Cholesky factor L of the full noise covariance C = L Lᵀ, m.
    context : object
        What :meth:`MeasurementModel.predict` needs for these rows (model-specific).
    """

    z_m: np.ndarray
    labels: list
    segment: np.ndarray
    sigma_m: np.ndarray | None = None
    chol_m: np.ndarray | None = None
    context: object = None

    def whiten(self, v: np.ndarray) -> np.ndarray:
        """C^{-1/2} v for v (m,) or (m, p): L⁻¹ v (full noise) or v / σ (diagonal)."""
        v = np.asarray(v, dtype=float)
        if self.chol_m is not None:
            return solve_triangular(self.chol_m, v, lower=True)
        return v / (self.sigma_m if v.ndim == 1 else self.sigma_m[:, None])

    def covariance(self) -> np.ndarray:
        """C (m, m), m²."""
        if self.chol_m is not None:
            return self.chol_m @ self.chol_m.T
        return np.diag(self.sigma_m**2)


class MeasurementModel:
    """Interface: ``n_epochs``, ``n_state``, ``segment_keys`` (one per ambiguity-segment column),
    ``rows(k)`` → :class:`Rows` or None, ``predict(x, rows)`` → (h (m,), H (m, n_state))."""

    n_epochs: int
    n_state: int
    segment_keys: list

    def rows(self, k: int) -> Rows | None:  # pragma: no cover - interface
        raise NotImplementedError

    def predict(self, x: np.ndarray, rows: Rows) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
        raise NotImplementedError


class PseudoliteSD(MeasurementModel):
    """Single differences λ·phase to pseudolites (near field) or far-field transmitters.

    Parameters
    ----------
    cfg : StructureConfig
    y_m : ndarray (N, C)
        λ·phase minus known biases, m; NaN where a channel is absent.
    ant, tx : ndarray (C,) int
        Antenna and transmitter index of each channel.
    sigma_m : ndarray (C,)
        Noise σ of each channel, m.
    segment : ndarray (N, C) int, optional
        Ambiguity-segment id of each (epoch, channel) (−1: bias known); default: none.
    """

    def __init__(self, cfg: StructureConfig, y_m, ant, tx, sigma_m, segment=None):
        self.cfg = cfg
        self.y = np.asarray(y_m, dtype=float)
        self.n_epochs, C = self.y.shape
        self.ant, self.tx = np.asarray(ant, dtype=int), np.asarray(tx, dtype=int)
        self.sigma = np.broadcast_to(np.asarray(sigma_m, dtype=float), (C,))
        if not np.all(np.isfinite(self.sigma) & (self.sigma > 0)):
            raise ValueError("PseudoliteSD: sigma_m must be positive and finite for every channel")
        self.seg = np.full(self.y.shape, -1, dtype=np.int64) if segment is None else np.asarray(segment, dtype=np.int64)
        self.n_state = 2 * cfg.n_modes
        ids = np.unique(self.seg[self.seg >= 0])
        self.segment_keys = [int(s) for s in ids]
        self._col = np.full(int(ids.max(initial=-1)) + 2, -1, dtype=np.int64)
        self._col[ids] = np.arange(ids.size)
        self._models: dict = {}

    def rows(self, k: int) -> Rows | None:
        c = np.flatnonzero(np.isfinite(self.y[k]))
        if c.size == 0:
            return None
        seg = self.seg[k, c]
        return Rows(self.y[k, c], [(self.cfg.antenna_names[self.ant[i]], self.cfg.transmitter_names[self.tx[i]]) for i in c],
                    np.where(seg >= 0, self._col[seg], -1), sigma_m=self.sigma[c].copy(), context=c)

    def predict(self, x, rows: Rows):
        key = rows.context.tobytes()
        m = self._models.get(key)
        if m is None:
            m = self._models[key] = EpochPhaseModel(self.cfg, self.ant[rows.context], self.tx[rows.context])
        return m(np.asarray(x, dtype=float))


def dd_modal_h_and_H(geo: EpochGeometry, U, xi, m_idx, ant_idx, slot, srows, d_hdr):
    """Far-field DD model on the modal positions ξ: h = −(s_j − s_r)ᵀ[(p_a(q) − p_M(q)) − d_a], q = U ξ.

    Parameters
    ----------
    geo : EpochGeometry
    U : ndarray (n_q, n_m)
    xi : ndarray (n_m,)
    m_idx : int
        Master antenna index.
    ant_idx : ndarray (n_rov,) int
        Antenna index of each rover slot.
    slot : ndarray (m,) int
        Rover slot of each DD row.
    srows : ndarray (m, 3)
        s_j − s_r of each row (structure frame).
    d_hdr : ndarray (n_rov, 3)
        Nominal receiver positions relative to the master (structure frame), m.

    Returns
    -------
    h : ndarray (m,), m
    H : ndarray (m, n_m), ∂h/∂ξ
    """
    q = U @ xi
    p, J = geo.positions(q)
    rel = p[ant_idx] - p[m_idx] - d_hdr
    Jr = J[ant_idx] - J[m_idx]
    h = -np.einsum("mi,mi->m", srows, rel[slot])
    Hq = -np.einsum("mi,miq->mq", srows, Jr[slot])
    return h, Hq @ U


class SatelliteDDModal(MeasurementModel):
    """Satellite double differences of several rovers against one master, on x = [ξ, ξ̇].

    Parameters
    ----------
    cfg : StructureConfig
    R_struct : ndarray (3, 3)
        ECEF vector = R_struct @ structure-frame vector (the placement's rotation).
    tabs : list of dict
        Per rover slot, the single-difference table of :mod:`cdgps_cli.pipeline.gnss_modal`: ``d`` (the
        baseline data: ``ptr``, ``sat``, ``sat_names``, ``rover_sat_xyz``), ``use`` (row usable),
        ``r0`` (SD residual at the nominal position, m), ``var_rover``/``var_master`` (undifferenced
        phase variances, m²), ``ref`` (reference row per epoch, −1 none), ``xm`` (master ECEF, m) and
        optionally ``seg`` (ambiguity-segment id per row).
    k_of : list of ndarray (n_epochs,) int
        Per slot, the table epoch of each common epoch (−1: none).
    ant_idx : ndarray (n_rov,) int
        Structure antenna index of each slot.
    d_hdr : ndarray (n_rov, 3)
        Nominal receiver position relative to the master, structure frame, m.

    Rows are labelled (slot, satellite); a row's segment key is (slot, segment of the satellite,
    segment of the reference), so a slip of either satellite starts a new DD ambiguity.
    """

    def __init__(self, cfg: StructureConfig, R_struct, tabs, k_of, ant_idx, d_hdr):
        self.cfg, self.R, self.tabs, self.k_of = cfg, np.asarray(R_struct, float), tabs, k_of
        self.ant_idx, self.d_hdr = np.asarray(ant_idx, dtype=int), np.asarray(d_hdr, float)
        self.geo = EpochGeometry(cfg)
        self.U = np.asarray(cfg.mode_shapes)
        self.nm = cfg.n_modes
        self.n_state = 2 * cfg.n_modes
        self.n_epochs = len(k_of[0]) if k_of else 0
        self.segment_keys: list = []
        self._col: dict = {}

    def _column(self, key) -> int:
        c = self._col.get(key)
        if c is None:
            c = self._col[key] = len(self.segment_keys)
            self.segment_keys.append(key)
        return c

    def rows(self, k: int) -> Rows | None:
        z, sd_rows, slot, labels, seg = [], [], [], [], []
        vr, vm, sats, refs = [], [], [], []
        for a, tb in enumerate(self.tabs):
            ke = self.k_of[a][k]
            if ke < 0 or tb["ref"][ke] < 0:
                continue
            d, ref = tb["d"], tb["ref"][ke]
            rows = np.arange(d.ptr[ke], d.ptr[ke + 1])
            rows = rows[tb["use"][rows]]
            if rows.size < 2:
                continue
            pos = int(np.flatnonzero(rows == ref)[0])
            u = (d.rover_sat_xyz[rows] - tb["xm"]) @ self.R          # structure-frame directions from the master
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            others = np.delete(np.arange(rows.size), pos)
            z.append(tb["r0"][rows[others]] - tb["r0"][ref])
            sd_rows.append(u[others] - u[pos])
            slot.extend([a] * others.size)
            names = [d.sat_names[int(d.sat[i])] for i in rows]
            labels.extend([(a, names[i]) for i in others])
            sg = tb.get("seg")
            seg.extend([self._column((a, int(sg[rows[i]]), int(sg[ref]))) if sg is not None else -1 for i in others])
            vr.append(tb["var_rover"][rows])
            vm.append(tb["var_master"][rows])
            sats.append(names)
            refs.append(pos)
        if not z:
            return None
        C = joint_dd_covariance(vr, vm, sats, refs)
        return Rows(np.concatenate(z), labels, np.asarray(seg, dtype=np.int64), chol_m=np.linalg.cholesky(C),
                    context=(np.asarray(slot), np.vstack(sd_rows)))

    def predict(self, x, rows: Rows):
        slot, srows = rows.context
        h, Hxi = dd_modal_h_and_H(self.geo, self.U, np.asarray(x, float)[:self.nm], self.cfg.master_index,
                                  self.ant_idx, slot, srows, self.d_hdr)
        H = np.zeros((h.size, self.n_state))
        H[:, :self.nm] = Hxi
        return h, H
