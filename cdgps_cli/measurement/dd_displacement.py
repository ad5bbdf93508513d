"""Satellite double differences on a displacement state (a :class:`~cdgps_cli.measurement.model.MeasurementModel`).

The state is x = [δx, a]: δx (3) the rover antenna's east/north/up displacement correction to a
linearization point (m; for the GNSS pipeline the static solution), and optionally a (n_a) corrections
to SD ambiguities (cycles) — the float solution under a moving rover estimates them with δx.  At the
linearization point each single difference (SD, rover − master, one row per epoch and satellite) of
an observation kind (L1 phase, pseudorange) has the residual r (m), the design g = ∂SD/∂δx (1 × 3,
the negated line of sight in the local frame) and, for phase, the column of its ambiguity.  The
double differences of epoch k against the kind's reference row are, with the DD operator D_k
(:func:`~cdgps_cli.measurement.differencing.dd_operator_batches`)::

    z_k = D_k r_k = D_k G_k δx + λ D_k E_k a + ν_k,     ν_k ~ N(0, D_k Σ_k D_kᵀ)

with Σ_k the diagonal SD variances (:func:`~cdgps_cli.measurement.differencing.sd_variance`) and E_k
the 0/1 map of each row to its ambiguity column (none for pseudorange, or for a known ambiguity).
The kinds of one epoch are independent (block-diagonal noise).  The model is linear: ``predict(x)``
is (H x, H).  Its whitened information H_kᵀ C_k⁻¹ H_k on δx equals G_kᵀ P_k G_k with the DD weights
P_k of :func:`~cdgps_cli.measurement.differencing.dd_weight_blocks`.

Rows are labelled (kind, satellite, reference satellite); ``segment`` is each row's ambiguity column
(−1: none), the column of the reference's ambiguity entering H with the opposite sign.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.measurement.differencing import dd_operator_batches
from cdgps_cli.measurement.model import MeasurementModel, Rows

__all__ = ["SDObservations", "SatelliteDDDisplacement"]


@dataclass
class SDObservations:
    """One kind of single differences of the rover pair.

    Attributes
    ----------
    residual_m : ndarray (N,)
        SD residual at the linearization point, m (for phase: with the known ambiguity removed).
    var_sd_m2 : ndarray (N,)
        SD variances, m².
    ref_rows : ndarray (n_epochs,) int
        Reference row of each epoch (−1: no DDs of this kind that epoch).
    usable : ndarray (N,) bool, optional
        Rows that enter the DDs (default all).
    ambiguity_col : ndarray (N,) int, optional
        Column of each row's ambiguity in a (−1: known); None: no ambiguities (pseudorange).
    kind : str
        Label of the kind ("phase", "code").
    wavelength_m : float, optional
        λ of this kind's ambiguities, m (a signal group's; default: the model's ``wavelength_m``).
    """

    residual_m: np.ndarray
    var_sd_m2: np.ndarray
    ref_rows: np.ndarray
    usable: np.ndarray | None = None
    ambiguity_col: np.ndarray | None = None
    kind: str = "phase"
    wavelength_m: float | None = None


class SatelliteDDDisplacement(MeasurementModel):
    """DDs of one rover against the master on x = [δx (3), a (n_ambiguities)].

    Parameters
    ----------
    ptr : array_like of int, shape (n_epochs + 1,)
        Epoch pointers of the SD rows (:func:`~cdgps_cli.measurement.differencing.epoch_pointers`).
    sat : array_like of int, shape (N,)
        Satellite index of each SD row (into ``sat_names``).
    sat_names : list of str
        Satellite names (the row labels).
    design : array_like, shape (N, 3)
        ∂SD/∂δx of each row.
    observations : list of SDObservations
        The kinds, stacked in this order within an epoch.
    n_ambiguities : int
        Number of ambiguity columns (cycles) after δx.
    wavelength_m : float
        λ of the ambiguities, m.

    The DDs of every epoch are formed once, vectorized over the epochs with the same number of
    usable rows; ``rows(k)`` only looks them up.
    """

    def __init__(self, ptr, sat, sat_names, design, observations, n_ambiguities: int = 0,
                 wavelength_m: float = GPS_L1_WAVELENGTH_M):
        g = np.asarray(design, dtype=float)
        self.n_epochs = len(ptr) - 1
        self.n_state = g.shape[1] + int(n_ambiguities)
        self.segment_keys = list(range(int(n_ambiguities)))
        self.sat_names = list(sat_names)
        self.lam = float(wavelength_m)
        sat = np.asarray(sat, dtype=np.int64)
        self._kinds = [_dd_tables(ptr, sat, g, ob, self.n_epochs) for ob in observations]
        self._lams = [self.lam if ob.wavelength_m is None else float(ob.wavelength_m) for ob in observations]
        self._one_lam = len(set(self._lams)) <= 1

    def rows(self, k: int) -> Rows | None:
        parts = [_epoch_part(kd, k, self.sat_names) for kd in self._kinds]
        if self._one_lam:
            lam = self._lams[0] if self._lams else self.lam
        else:                                   # signal groups: each row's own wavelength
            lam = np.concatenate([np.full(p[0].size, lm) for p, lm in zip(parts, self._lams) if p is not None]
                                 or [np.zeros(0)])
        parts = [p for p in parts if p is not None]
        if not parts:
            return None
        if len(parts) == 1:
            z, labels, col, col_ref, L, Hx = parts[0]
        else:
            z, labels, col, col_ref, L, Hx = (np.concatenate([p[0] for p in parts]), sum((p[1] for p in parts), []),
                                              np.concatenate([p[2] for p in parts]),
                                              np.concatenate([p[3] for p in parts]), _block_diagonal([p[4] for p in parts]),
                                              np.concatenate([p[5] for p in parts]))
        H = Hx
        if self.n_state > Hx.shape[1]:
            H = np.zeros((z.size, self.n_state))
            H[:, :Hx.shape[1]] = Hx
            i = np.arange(z.size)
            m = col >= 0
            H[i[m], Hx.shape[1] + col[m]] += lam if np.ndim(lam) == 0 else lam[m]
            m = col_ref >= 0
            H[i[m], Hx.shape[1] + col_ref[m]] -= lam if np.ndim(lam) == 0 else lam[m]
        return Rows(z, labels, col, chol_m=L, context=H)

    def predict(self, x, rows: Rows):
        H = rows.context
        return H @ np.asarray(x, dtype=float), H


def _dd_tables(ptr, sat, g, ob: SDObservations, n_epochs: int) -> dict:
    """The DDs of one kind for every epoch: per batch of epochs with equal row counts, z, D G, the
    Cholesky factor of D Σ Dᵀ, the rows' satellites and ambiguity columns; and where each epoch is."""
    r = np.asarray(ob.residual_m, dtype=float)
    var = np.asarray(ob.var_sd_m2, dtype=float)
    acol = None if ob.ambiguity_col is None else np.asarray(ob.ambiguity_col, dtype=np.int64)
    where = np.full((n_epochs, 2), -1, dtype=np.int64)
    batches = []
    for b, (eps, rows, d) in enumerate(dd_operator_batches(ptr, ob.ref_rows, r.size, usable=ob.usable)):
        ref_pos = np.argmax(d[:, 0, :] < 0, axis=1)
        others = ~np.eye(rows.shape[1], dtype=bool)[ref_pos]              # (K, n): non-reference rows
        oth = rows[others].reshape(rows.shape[0], -1)
        ref = rows[np.arange(rows.shape[0]), ref_pos]
        batches.append({
            "z": np.einsum("kin,kn->ki", d, r[rows]),
            "H": np.einsum("kin,knc->kic", d, g[rows]),
            "L": np.linalg.cholesky(np.einsum("kin,kn,kjn->kij", d, var[rows], d)),
            "sat": sat[oth], "ref_sat": sat[ref],
            "col": None if acol is None else acol[oth], "col_ref": None if acol is None else acol[ref],
        })
        where[eps, 0] = b
        where[eps, 1] = np.arange(eps.size)
    return {"where": where, "batches": batches, "kind": ob.kind}


def _epoch_part(kd: dict, k: int, names: list):
    b, i = kd["where"][k]
    if b < 0:
        return None
    bt = kd["batches"][b]
    ref = names[int(bt["ref_sat"][i])]
    labels = [(kd["kind"], names[int(s)], ref) for s in bt["sat"][i]]
    m = len(labels)
    col = np.full(m, -1, dtype=np.int64) if bt["col"] is None else bt["col"][i]
    col_ref = np.full(m, -1, dtype=np.int64) if bt["col_ref"] is None else np.full(m, bt["col_ref"][i])
    return bt["z"][i], labels, col, col_ref, bt["L"][i], bt["H"][i]


def _block_diagonal(blocks: list) -> np.ndarray:
    """The square blocks on the diagonal of one matrix (scipy's block_diag costs ~0.5 ms a call)."""
    m = sum(b.shape[0] for b in blocks)
    out = np.zeros((m, m))
    i = 0
    for b in blocks:
        out[i:i + b.shape[0], i:i + b.shape[0]] = b
        i += b.shape[0]
    return out
