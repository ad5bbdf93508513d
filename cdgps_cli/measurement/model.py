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
  that epoch, noise D Σ Dᵀ jointly over the rovers (:func:`cdgps_cli.measurement.differencing.joint_dd_covariance`);
  with ``code=True`` also the pseudorange DDs (no ambiguity, their own D Σ_P Dᵀ), as the modal batch
  initialization uses them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import block_diag, solve_triangular
from scipy.linalg.lapack import dtrtrs as _dtrtrs

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.measurement.differencing import joint_dd_covariance
from cdgps_cli.measurement.phase import EpochPhaseModel
from cdgps_cli.model.kinematics import EpochGeometry

__all__ = ["Rows", "MeasurementModel", "PseudoliteSD", "SatelliteDDModal", "dd_modal_h_and_H"]



def solve_lower(L: np.ndarray, v: np.ndarray) -> np.ndarray:
    """L⁻¹ v for a lower-triangular L (m, m) and v (m,) or (m, p): LAPACK trtrs called as
    ``scipy.linalg.solve_triangular(L, v, lower=True, check_finite=False)`` calls it (the same
    numbers), without that wrapper's per-call checks (≈ 15 µs; the filters whiten three times an
    epoch)."""
    L = np.asarray(L, dtype=float)
    v = np.asarray(v, dtype=float)
    if v.size == 0 or L.ndim != 2 or L.shape[0] != L.shape[1] or v.shape[0] != L.shape[0]:
        return solve_triangular(L, v, lower=True, check_finite=False)      # its shapes and messages
    if L.flags.f_contiguous:
        x, info = _dtrtrs(L, v, lower=1, trans=0)
    else:                                     # the transposed system, as trtrs expects Fortran order
        x, info = _dtrtrs(L.T, v, lower=0, trans=1)
    if info != 0:
        return solve_triangular(L, v, lower=True, check_finite=False)      # its error for this case
    return x

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
            return solve_lower(self.chol_m, v)
        return v / (self.sigma_m if v.ndim == 1 else self.sigma_m[:, None])

    def subset(self, keep) -> "Rows":
        """The rows ``keep`` (indices or mask), their noise the sub-block of the covariance."""
        keep = np.flatnonzero(np.asarray(keep)) if np.asarray(keep).dtype == bool else np.asarray(keep, dtype=int)
        ctx = self.context
        ctx = tuple(np.asarray(c)[keep] for c in ctx) if isinstance(ctx, tuple) else (None if ctx is None else np.asarray(ctx)[keep])
        if self.chol_m is not None:
            C = self.covariance()[np.ix_(keep, keep)]
            return Rows(self.z_m[keep], [self.labels[i] for i in keep], self.segment[keep], chol_m=np.linalg.cholesky(C),
                        context=ctx)
        return Rows(self.z_m[keep], [self.labels[i] for i in keep], self.segment[keep], sigma_m=self.sigma_m[keep], context=ctx)

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
        # no segments: one −1 seen at every (epoch, channel) (read-only; no (N, C) array in memory)
        self.seg = (np.broadcast_to(np.int64(-1), self.y.shape) if segment is None
                    else np.asarray(segment, dtype=np.int64))
        self.n_state = 2 * cfg.n_modes
        ids = np.zeros(0, dtype=np.int64) if segment is None else np.unique(self.seg[self.seg >= 0])
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
        optionally ``seg`` (ambiguity-segment id per row); with ``code``, ``rc`` (SD pseudorange
        residual at the nominal position, m, NaN where missing) and ``code_ratio`` (code σ / phase σ).
    k_of : list of ndarray (n_epochs,) int
        Per slot, the table epoch of each common epoch (−1: none).
    ant_idx : ndarray (n_rov,) int
        Structure antenna index of each slot.
    d_hdr : ndarray (n_rov, 3)
        Nominal receiver position relative to the master, structure frame, m.

    code : bool
        Add every epoch's pseudorange DDs (after the phase rows; labels (slot, ``"<satellite>/code"``),
        no ambiguity, segment −1): the same far-field model h(x), their own noise D Σ_P Dᵀ with
        Σ_P = ``code_ratio``² Σ (jointly over the rovers, independent of the phase).  They pin each
        DD's absolute value to decimetres, hence the float ambiguities and the slow (rigid) modes the
        phase alone leaves nearly constant over a window.

    Rows are labelled (slot, satellite); a row's segment key is (slot, segment of the satellite,
    segment of the reference), so a slip of either satellite starts a new DD ambiguity.
    """

    def __init__(self, cfg: StructureConfig, R_struct, tabs, k_of, ant_idx, d_hdr, code: bool = False):
        self.cfg, self.R, self.tabs, self.k_of = cfg, np.asarray(R_struct, float), tabs, k_of
        self.ant_idx, self.d_hdr = np.asarray(ant_idx, dtype=int), np.asarray(d_hdr, float)
        self.code = bool(code)
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

    def _slot_rows(self, a: int, tb: dict, ke: int, code: bool):
        """Slot ``a``'s DDs at its table epoch ``ke`` (phase, or with ``code`` pseudorange: rows whose code
        is finite, against the phase reference when its code is finite): a dict of the pieces, or None."""
        d, ref = tb["d"], tb["ref"][ke]
        rows = np.arange(d.ptr[ke], d.ptr[ke + 1])
        rows = rows[tb["use"][rows]]
        if code:
            rows = rows[np.isfinite(tb["rc"][rows])]
        if rows.size < 2 or not np.any(rows == ref):
            return None
        pos = int(np.flatnonzero(rows == ref)[0])
        u = (d.rover_sat_xyz[rows] - tb["xm"]) @ self.R          # structure-frame directions from the master
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        others = np.delete(np.arange(rows.size), pos)
        names = [d.sat_names[int(d.sat[i])] for i in rows]
        sg = tb.get("seg")
        if code:
            seg = [-1] * others.size
        else:
            seg = [self._column((a, int(sg[rows[i]]), int(sg[ref]))) if sg is not None else -1 for i in others]
        zc, f2 = ("rc", tb["code_ratio"] ** 2) if code else ("r0", 1.0)
        return {"z": tb[zc][rows[others]] - tb[zc][ref], "s": u[others] - u[pos], "slot": [a] * others.size,
                "labels": [(a, names[i] + ("/code" if code else "")) for i in others], "seg": seg,
                "vr": f2 * tb["var_rover"][rows], "vm": f2 * tb["var_master"][rows], "sats": names, "ref": pos}

    def rows(self, k: int) -> Rows | None:
        """Epoch k's DDs of every slot: the phase rows, then (``code``) the pseudorange rows; noise
        D Σ Dᵀ jointly over the slots, phase and code independent (block-diagonal)."""
        kinds = []
        for code in ((False, True) if self.code else (False,)):
            parts = []
            for a, tb in enumerate(self.tabs):
                ke = self.k_of[a][k]
                if ke >= 0 and tb["ref"][ke] >= 0:
                    p = self._slot_rows(a, tb, ke, code)
                    if p is not None:
                        parts.append(p)
            if parts:
                kinds.append(parts)
        if not kinds:
            return None
        blocks = [joint_dd_covariance([p["vr"] for p in ps], [p["vm"] for p in ps], [p["sats"] for p in ps],
                                      [p["ref"] for p in ps]) for ps in kinds]
        C = block_diag(*blocks)
        flat = [p for ps in kinds for p in ps]
        return Rows(np.concatenate([p["z"] for p in flat]), [lb for p in flat for lb in p["labels"]],
                    np.asarray([s for p in flat for s in p["seg"]], dtype=np.int64), chol_m=np.linalg.cholesky(C),
                    context=(np.asarray([s for p in flat for s in p["slot"]]), np.vstack([p["s"] for p in flat])))

    def predict(self, x, rows: Rows):
        slot, srows = rows.context
        h, Hxi = dd_modal_h_and_H(self.geo, self.U, np.asarray(x, float)[:self.nm], self.cfg.master_index,
                                  self.ant_idx, slot, srows, self.d_hdr)
        H = np.zeros((h.size, self.n_state))
        H[:, :self.nm] = Hxi
        return h, H


@dataclass
class PackedDD:
    """Every epoch's DD rows of a :class:`SatelliteDDModal` in padded arrays (C = most rows of an epoch).

    Attributes
    ----------
    m : ndarray (N,) int
        Rows of each epoch (the first m of its C slots; the others are padding).
    z_m : ndarray (N, C)
        DD values, m (0 in padding).
    L : ndarray (N, C, C)
        Lower Cholesky factor of each epoch's D Σ Dᵀ (identity in padding), m.
    var_m2 : ndarray (N, C)
        Diagonal of D Σ Dᵀ, m² (1 in padding).
    srows : ndarray (N, C, 3)
        s_j − s_r per row (structure frame; 0 in padding).
    ant : ndarray (N, C) int
        Structure antenna of each row (the master in padding).
    hconst_m : ndarray (N, C)
        (s_j − s_r)ᵀ d_a: the constant part of h, m.
    slot : ndarray (N, C) int
        Rover slot of each row (−1 in padding).
    sat : ndarray (N, C) int
        Satellite of each row (index into ``sat_names``).
    segment : ndarray (N, C) int
        Segment column of each row (−1 in padding).
    """

    m: np.ndarray
    z_m: np.ndarray
    L: np.ndarray
    var_m2: np.ndarray
    srows: np.ndarray
    ant: np.ndarray
    hconst_m: np.ndarray
    slot: np.ndarray
    sat: np.ndarray
    segment: np.ndarray
    sat_names: list


def _unique_pairs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(np.stack([a, b], axis=1), axis=0, return_inverse=True)`` for integer arrays ≥ −1,
    through one int64 key per pair (a 1-D sort instead of a sort of row views; same order)."""
    a = np.asarray(a, dtype=np.int64) + 1
    b = np.asarray(b, dtype=np.int64) + 1
    base = int(b.max(initial=0)) + 1
    keys, inv = np.unique(a * base + b, return_inverse=True)
    return np.stack([keys // base - 1, keys % base - 1], axis=1), inv


def _dd_entries(model: "SatelliteDDModal", names: dict) -> dict:
    """All DD rows of every slot as flat arrays (common epoch, slot, row, reference row, …)."""
    cols = {k: [] for k in ("k", "slot", "z", "s", "vr", "vrr", "vm", "vmr", "sat", "satr", "seg")}
    for a, tb in enumerate(model.tabs):
        d = tb["d"]
        common = np.full(len(d.ptr) - 1, -1, dtype=np.int64)
        ok = model.k_of[a] >= 0
        common[model.k_of[a][ok]] = np.flatnonzero(ok)
        epoch = np.repeat(np.arange(len(d.ptr) - 1), np.diff(d.ptr))
        ref = np.asarray(tb["ref"])[epoch]
        cnt = np.bincount(epoch, weights=tb["use"].astype(float), minlength=len(d.ptr) - 1)[epoch]
        rows = np.flatnonzero(tb["use"] & (ref >= 0) & (np.arange(epoch.size) != ref) & (common[epoch] >= 0) & (cnt >= 2))
        rr = ref[rows]
        u = d.rover_sat_xyz - tb["xm"]
        u = u @ model.R
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        gsat = np.array([names.setdefault(s, len(names)) for s in d.sat_names], dtype=np.int64)[np.asarray(d.sat, dtype=np.int64)]
        sg = tb.get("seg")
        cols["k"].append(common[epoch[rows]])
        cols["slot"].append(np.full(rows.size, a))
        cols["z"].append(tb["r0"][rows] - tb["r0"][rr])
        cols["s"].append(u[rows] - u[rr])
        for key, v in (("vr", tb["var_rover"]), ("vm", tb["var_master"]), ("sat", gsat)):
            cols[key].append(v[rows])
            cols[key + "r"].append(v[rr])
        if sg is None:
            cols["seg"].append(np.full(rows.size, -1, dtype=np.int64))
        else:
            pairs, inv = _unique_pairs(sg[rows], sg[rr])
            # columns in order of first appearance (as rows(k) assigns them epoch by epoch)
            first = np.full(len(pairs), rows.size, dtype=np.int64)
            np.minimum.at(first, inv.reshape(-1), np.arange(rows.size))
            col = np.empty(len(pairs), dtype=np.int64)
            for p_ in np.argsort(first, kind="stable"):
                col[p_] = model._column((a, int(pairs[p_, 0]), int(pairs[p_, 1])))
            cols["seg"].append(col[inv.reshape(-1)])
    out = {k: np.concatenate([np.asarray(v) for v in val]) if val else np.zeros(0) for k, val in cols.items()}
    order = np.lexsort((out["slot"], out["k"]))          # epoch, then slot, then row (stable)
    return {k: v[order] for k, v in out.items()}


def pack_dd(model: "SatelliteDDModal") -> PackedDD:
    """:class:`PackedDD` of ``model`` (the rows of :meth:`SatelliteDDModal.rows`, vectorized over epochs)."""
    names: dict = {}
    e = _dd_entries(model, names)
    N = model.n_epochs
    k = e["k"].astype(np.int64)
    m = np.bincount(k, minlength=N).astype(np.int64)
    # an epoch needs two rows of one rover … every DD row has its reference, so any row counts
    C = int(m.max(initial=0))
    first = np.cumsum(m) - m
    pos = np.arange(k.size) - first[k]

    def grid(v, fill, dtype=float):
        g = np.full((N, C) + np.shape(v)[1:], fill, dtype=dtype)
        g[k, pos] = v
        return g

    slot, sat, satr = grid(e["slot"], -1, np.int64), grid(e["sat"], -1, np.int64), grid(e["satr"], -2, np.int64)
    vr, vrr, vm, vmr = grid(e["vr"], 0.0), grid(e["vrr"], 0.0), grid(e["vm"], 0.0), grid(e["vmr"], 0.0)

    sm, smr = np.sqrt(vm), np.sqrt(vmr)
    same_slot = slot[:, :, None] == slot[:, None, :]
    rover_v, rover_vr = np.where(same_slot, vr[:, :, None], 0.0), np.where(same_slot, vrr[:, :, None], 0.0)
    del same_slot

    def term(sx, rover, mx, sy, my):
        """Cov(SD x, SD y): the rover's variance when they are one SD, the master's for one satellite
        (in place on one temporary: the same numbers as (same · (rover + mx myᵀ)))."""
        t = mx[:, :, None] * my[:, None, :]
        t += rover
        t *= sx[:, :, None] == sy[:, None, :]
        return t

    cov = term(sat, rover_v, sm, sat, sm)
    cov -= term(sat, rover_v, sm, satr, smr)
    cov -= term(satr, rover_vr, smr, sat, sm)
    cov += term(satr, rover_vr, smr, satr, smr)
    del rover_v, rover_vr
    pad = slot < 0
    cov[pad] = 0.0
    cov.transpose(0, 2, 1)[pad] = 0.0
    cov[np.broadcast_to(np.eye(C, dtype=bool), cov.shape) & pad[:, :, None]] = 1.0
    L = np.linalg.cholesky(cov)
    z = grid(e["z"], 0.0)
    srows = grid(e["s"], 0.0)
    ant = np.where(slot >= 0, model.ant_idx[np.maximum(slot, 0)], model.cfg.master_index)
    hconst = np.einsum("kci,kci->kc", srows, np.where(slot[..., None] >= 0, model.d_hdr[np.maximum(slot, 0)], 0.0))
    inv_names = sorted(names, key=names.get)
    return PackedDD(m=m, z_m=z, L=L, var_m2=np.diagonal(cov, axis1=1, axis2=2).copy(),
                    srows=srows, ant=ant.astype(np.int64), hconst_m=hconst, slot=slot, sat=sat,
                    segment=grid(np.asarray(e["seg"], dtype=np.int64), -1, np.int64), sat_names=inv_names)
