"""LAMBDA reduction on well-conditioned matrices never blows up (issue 28 item 4).

The former reduction size-reduced only the sub-diagonal element before each swap test (MLAMBDA's
lazy strategy); the other entries of ``L`` grew through the swaps without bound and, on a real
47x47 covariance from the mosaic G+E+C dual-frequency run, the Gauss integers reached 1e80
("integer entries too large for int64").  The reduction now size-reduces the whole column."""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cdgps_cli.estimation import ambiguity as amb

sys.path.insert(0, str(Path(__file__).parent))
import lambda_legacy as legacy  # noqa: E402  (the former lazy reduction)

REAL_Q = Path(__file__).resolve().parents[1] / "data" / "lambda_q_mosaic_gec_47.npy"


def _check_decorrelation(Q):
    """Decorrelate ``Q`` (n, n); assert Z unimodular and Zᵀ Q Z = Lᵀ D L; return (L, d, Z)."""
    L, d = amb.ld_factorize(Q)
    Lr, dr, Z = amb.decorrelate(L, d)
    n = Q.shape[0]
    Zi = np.round(np.linalg.inv(Z.astype(float))).astype(np.int64)
    np.testing.assert_array_equal(Zi @ Z, np.eye(n, dtype=np.int64))      # integer inverse: unimodular
    np.testing.assert_allclose(Z.T @ Q @ Z, Lr.T @ np.diag(dr) @ Lr, rtol=1e-7, atol=1e-9 * np.abs(Q).max())
    assert np.all(np.abs(np.tril(Lr, -1)) <= 0.5 + 1e-12)
    np.testing.assert_allclose(np.sum(np.log(dr)), np.sum(np.log(d)), atol=1e-8)   # det Q kept
    return Lr, dr, Z


def _python_and_kernel(Q):
    """decorrelate on the compiled kernel (when built) and on the Python loops: bit-identical."""
    L, d = amb.ld_factorize(Q)
    out = amb.decorrelate(L, d)
    with pytest.MonkeyPatch.context() as m:
        m.setenv("CDGPS_NO_KERNEL", "1")
        ref = amb.decorrelate(L, d)
    for a, b in zip(out, ref):
        np.testing.assert_array_equal(a, b)


def test_real_mosaic_covariance_decorrelates():
    Q = np.load(REAL_Q)
    L, d = amb.ld_factorize(Q)
    with pytest.raises(legacy.AmbiguityError, match="too large for int64"):
        legacy.decorrelate(L, d)                       # the former reduction: the reported crash
    Lr, dr, Z = _check_decorrelation(Q)
    assert np.abs(Z).max() < 100
    Qz = Z.T @ Q @ Z
    assert np.diag(Qz).max() <= np.diag(Q).max()
    assert np.diag(Qz).sum() <= np.diag(Q).sum()
    _python_and_kernel(Q)


def test_real_mosaic_search_matches_brute_force_on_a_block():
    Q = np.load(REAL_Q)
    rng = np.random.default_rng(7)
    for idx in ([0, 1, 2, 3], [10, 11, 20, 30, 46], [5, 6, 7, 8]):
        Qs = Q[np.ix_(idx, idx)]
        a = rng.uniform(-30, 30, len(idx))
        cands, s = amb.lambda_search(a, Qs, candidates=2)
        Qi = np.linalg.inv(Qs)
        base = np.round(a)
        best = sorted(
            (float((a - base - off) @ Qi @ (a - base - off)), tuple((base + off).astype(int)))
            for off in map(np.array, itertools.product(range(-3, 4), repeat=len(idx))))
        np.testing.assert_allclose(s, [best[0][0], best[1][0]], rtol=1e-9)
        assert tuple(cands[0]) == best[0][1]
    # the full 47-ambiguity search: float ambiguities drawn around known integers
    truth = rng.integers(-50, 50, 47)
    a = truth + np.linalg.cholesky(Q) @ rng.standard_normal(47) * 0.3
    c47, s47 = amb.lambda_search(a, Q, candidates=2)
    np.testing.assert_array_equal(c47[0], truth)


@st.composite
def spd_matrices(draw):
    """SPD covariances (cycles^2), n = 1..60, eigenvalues spread over up to 7 decades, random basis."""
    n = draw(st.integers(1, 60))
    seed = draw(st.integers(0, 2**32 - 1))
    lo = draw(st.floats(-6.0, -1.0))
    hi = draw(st.floats(-1.0, 1.5))
    rng = np.random.default_rng(seed)
    Qo, _ = np.linalg.qr(rng.standard_normal((n, n)))
    ev = 10.0 ** rng.uniform(lo, hi, n)
    Q = (Qo * ev) @ Qo.T
    return 0.5 * (Q + Q.T)


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(spd_matrices())
def test_decorrelation_never_overflows(Q):
    Lr, dr, Z = _check_decorrelation(Q)
    assert np.abs(Z).max() < 10**6
    _python_and_kernel(Q)


def test_z_matrix_stays_in_int64_when_its_entries_are_small(monkeypatch):
    """The overflow guard follows the columns' actual largest entries: a real 47x47 reduction (|Z| < 30)
    is formed in int64, on the kernel and on the Python loops, not in the exact Python-integer form."""
    Q = np.load(REAL_Q)
    L, d = amb.ld_factorize(Q)
    _, _, ops = amb._reduce(L, d)
    ref = amb._z_matrix_exact(ops, 47)

    def no_exact(ops, n):
        raise AssertionError("_z_matrix_exact called")

    monkeypatch.setattr(amb, "_z_matrix_exact", no_exact)
    np.testing.assert_array_equal(amb._z_matrix(ops, 47), ref)
    monkeypatch.setenv("CDGPS_NO_KERNEL", "1")
    np.testing.assert_array_equal(amb._z_matrix(ops, 47), ref)
