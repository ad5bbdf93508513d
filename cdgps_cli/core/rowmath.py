"""Matrix products whose every row is computed the same way however many rows a call gets.

A BLAS product ``A @ B`` picks its kernels (and so the order and fusing of its multiply-adds) by the
shape of the call: the same row can differ in its last bit between a call on the whole record and
a call on a chunk of it.  Readers that stream a record in chunks and must give the same numbers as
one whole-record call use :func:`rows_matmul` instead: a fixed sequence of element-wise numpy
operations per row (no BLAS, no fused multiply-add), so the result of a row depends on that row
alone — identical for any chunking, and on any machine.
"""

from __future__ import annotations

import numpy as np


def rows_matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` summed term by term in the order of the inner index, row by row.

    Parameters
    ----------
    a : ndarray (k, n)
    b : ndarray (n, p) or (n,)

    Returns
    -------
    ndarray (k, p) or (k,), float64: Σ_j a[:, j] b[j], the terms added left to right.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    vec = b.ndim == 1
    b2 = b[:, None] if vec else b
    if a.ndim != 2 or a.shape[1] != b2.shape[0]:
        raise ValueError(f"rows_matmul: shapes {a.shape} and {b.shape} do not multiply")
    out = np.zeros((a.shape[0], b2.shape[1]))
    for j in range(a.shape[1]):
        out += a[:, j:j + 1] * b2[j]
    return out[:, 0] if vec else out
