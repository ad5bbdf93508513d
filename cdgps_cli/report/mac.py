"""The modal assurance criterion matrix of two sets of mode shapes (pure numerics)."""

from __future__ import annotations

import numpy as np


def mac_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """MAC[i, j] = |a_iᴴ b_j|² / ((a_iᴴ a_i)(b_jᴴ b_j)) of the columns of ``a`` and ``b``.

    Parameters
    ----------
    a : (n, m_a) real or complex, one shape per column (e.g. identified)
    b : (n, m_b) real or complex, one shape per column (e.g. the model's)

    Returns
    -------
    ndarray (m_a, m_b) in [0, 1]: 1 for shapes equal up to a (complex) factor, 0 for orthogonal
    shapes; 0 where a shape is all zeros.
    """
    a = np.asarray(a)
    b = np.asarray(b)
    if a.ndim != 2 or b.ndim != 2 or a.shape[0] != b.shape[0]:
        raise ValueError(f"shapes {a.shape} and {b.shape}: expected (n, m_a) and (n, m_b) with the same n")
    num = np.abs(a.conj().T @ b) ** 2
    na = np.real(np.einsum("ij,ij->j", a.conj(), a))
    nb = np.real(np.einsum("ij,ij->j", b.conj(), b))
    den = np.outer(na, nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return np.clip(out, 0.0, 1.0)
