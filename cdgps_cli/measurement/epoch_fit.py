"""Per-epoch least squares of grouped single-difference rows for a position (or displacement) and one common term
per signal group — the fit that the time-differenced slip search (:mod:`.slips`) and the static engine's check of
fixed integers (:func:`cdgps_cli.estimation.static_engine.epoch_phase_misfit`) both make.

Within a group the rows share an unknown common term (receiver clocks, phase biases, the SD arcs' datum); it is
eliminated by centring each group on its weighted mean (what weighting the rows as their double differences does),
after which the group terms and the 3 parameters are orthogonal: each epoch's 3×3 normal equations are the centred
rows' sums, formed for every epoch at once with ``np.bincount``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["EpochFit", "full_rank", "grouped_epoch_fit"]


def full_rank(m: np.ndarray) -> np.ndarray:
    """(k,) bool: each symmetric (k, 3, 3) matrix has its smallest eigenvalue above 1e-10 of its largest (an epoch's
    rows can be enough in number and still not fix a position: L1 and L2 of two or three satellites)."""
    if not len(m):
        return np.zeros(0, dtype=bool)
    ev = np.linalg.eigvalsh(m)
    return ev[:, 0] > 1e-10 * np.maximum(ev[:, -1], np.finfo(float).tiny)


class EpochFit(NamedTuple):
    """:func:`grouped_epoch_fit`'s result."""

    gc: np.ndarray          # (M, 3) the rows' coefficients, each group's weighted mean removed
    yc: np.ndarray          # (M,) the rows' values, likewise
    group_weight: np.ndarray  # (n_groups,) Σ w of each group (1 where 0, to divide by)
    ok: np.ndarray          # (n_ep,) bool: the epochs fitted (usable and of full rank)
    step: np.ndarray        # (n_ep, 3) each fitted epoch's solution (0 elsewhere)
    n_inv: np.ndarray       # (n_ep, 3, 3) its normal matrix's inverse (0 elsewhere)
    chi2: np.ndarray        # (n_ep,) the weighted residual sum of squares at the solution (0 elsewhere)


def grouped_epoch_fit(y, w, g, group, epoch, n_groups: int, n_epochs: int, usable=None) -> EpochFit:
    """Fit every epoch's rows ``y`` (M,) by ``g`` (M, 3) × 3 parameters plus one common term per group.

    Parameters
    ----------
    y : ndarray (M,)
        Row values (m).
    w : ndarray (M,)
        Weights 1/σ² (0 leaves a row out).
    g : ndarray (M, 3)
        Coefficients of the 3 parameters.
    group, epoch : ndarray of int (M,)
        Each row's group (0 … ``n_groups`` − 1; a group lies within one epoch) and epoch (0 … ``n_epochs`` − 1).
    usable : ndarray of bool (n_epochs,), optional
        Epochs that may be fitted (default all); those whose normal matrix is not of full rank (:func:`full_rank`)
        are not.

    Returns
    -------
    EpochFit
    """
    s = np.bincount(group, weights=w, minlength=n_groups).astype(float)
    safe = np.where(s > 0, s, 1.0)
    mean_g = np.stack([np.bincount(group, weights=w * g[:, c], minlength=n_groups) for c in range(3)], axis=1)
    mean_y = np.bincount(group, weights=w * y, minlength=n_groups)
    gc, yc = g - (mean_g / safe[:, None])[group], y - (mean_y / safe)[group]
    nmat, rhs = np.zeros((n_epochs, 3, 3)), np.zeros((n_epochs, 3))
    for a in range(3):
        rhs[:, a] = np.bincount(epoch, weights=w * yc * gc[:, a], minlength=n_epochs)
        for b in range(a, 3):
            nmat[:, a, b] = nmat[:, b, a] = np.bincount(epoch, weights=w * gc[:, a] * gc[:, b], minlength=n_epochs)
    ss = np.bincount(epoch, weights=w * yc * yc, minlength=n_epochs).astype(float)
    ok = np.ones(n_epochs, dtype=bool) if usable is None else np.asarray(usable, dtype=bool).copy()
    ok[ok] = full_rank(nmat[ok])
    step, n_inv, chi2 = np.zeros((n_epochs, 3)), np.zeros((n_epochs, 3, 3)), np.zeros(n_epochs)
    n_inv[ok] = np.linalg.inv(nmat[ok])
    step[ok] = np.einsum("kab,kb->ka", n_inv[ok], rhs[ok])
    chi2[ok] = ss[ok] - np.einsum("kc,kc->k", rhs[ok], step[ok])
    return EpochFit(gc, yc, safe, ok, step, n_inv, chi2)
