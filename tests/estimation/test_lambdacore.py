"""The compiled LAMBDA kernels (``_lambdacore``) against the Python loops they replace: the same
reduction (factors and operation list) and the same search (candidates, norms, cap) bit for bit."""

from __future__ import annotations

import os

import numpy as np
import pytest

from cdgps_cli.estimation import ambiguity as amb

needs_kernel = pytest.mark.skipif(amb._kernel() is None, reason="_lambdacore not compiled (or CDGPS_NO_KERNEL)")


def test_lambda_kernel_is_built():
    """`pip install -e .` (make venv) compiles the extension (optional in setup.py, so a failed build is silent)."""
    if os.environ.get("CDGPS_NO_KERNEL", "") not in ("", "0"):
        pytest.skip("CDGPS_NO_KERNEL is set")
    assert amb._kernel() is not None, (
        "cdgps_cli.estimation._lambdacore is missing or stale: rebuild with `pip install -e .` (needs a C compiler "
        "and the Python headers), or set CDGPS_NO_KERNEL=1 to use the Python loops")


def _python(monkeypatch, fn, *args, **kw):
    """``fn(*args, **kw)`` on the Python loops (the kernel disabled)."""
    with monkeypatch.context() as m:
        m.setenv("CDGPS_NO_KERNEL", "1")
        assert amb._kernel() is None
        return fn(*args, **kw)


def _outcome(fn, *args, **kw):
    """The result of ``fn(*args, **kw)``, or its exception as (type, message)."""
    try:
        return fn(*args, **kw)
    except Exception as exc:          # noqa: BLE001
        return type(exc), str(exc)


def _same(x, y) -> bool:
    """Results (tuples of arrays) or exceptions equal bit for bit."""
    if isinstance(x[0], type) or isinstance(y[0], type):
        return x == y
    return all(np.array_equal(u, v, equal_nan=u.dtype.kind == "f") for u, v in zip(x, y, strict=True))


def _covariances(seed=3):
    """Ambiguity covariances (cycles²) as the filters make them: strongly correlated DD sets of 1 to 60
    ambiguities (a few geometry columns plus small white noise), some badly scaled."""
    rng = np.random.default_rng(seed)
    out = []
    for n in (1, 2, 3, 5, 8, 13, 21, 30, 45, 60):
        G = rng.normal(size=(n, min(n, 4))) * rng.uniform(0.5, 8)
        Q = G @ G.T + np.diag(rng.uniform(2e-3, 5e-2, n))
        out.append((rng.normal(scale=30.0, size=n), Q * 10.0 ** rng.integers(-3, 1)))
    return out


@needs_kernel
@pytest.mark.parametrize("case", range(10))
def test_reduce_and_search_identical(monkeypatch, case):
    a, Q = _covariances()[case]
    L, d = amb.ld_factorize(Q)
    Lc, dc, opsc = amb._reduce(L, d)
    Lp, dp, opsp = _python(monkeypatch, amb._reduce, L, d)
    assert np.array_equal(Lc, Lp) and np.array_equal(dc, dp)
    assert [tuple(o) for o in opsc] == [tuple(o) for o in opsp]
    assert all(type(v) is int for o in opsc for v in o)
    zs = np.asarray(amb._forward(opsc, (a - np.floor(a + 0.5)).tolist()))
    for m in (1, 2, 5):
        assert _same(_outcome(amb.search, Lc, dc, zs, m, max_nodes=20_000),
                     _python(monkeypatch, _outcome, amb.search, Lc, dc, zs, m, max_nodes=20_000))
    assert _same(_outcome(amb.lambda_search, a, Q, 2, max_nodes=20_000),
                 _python(monkeypatch, _outcome, amb.lambda_search, a, Q, 2, max_nodes=20_000))
    assert _same(_outcome(_fixed, a, Q),
                 _python(monkeypatch, _outcome, _fixed, a, Q))


def _fixed(a, Q):
    """partial_fix's mask, integers and ratio (as arrays)."""
    r = amb.partial_fix(a, Q, max_nodes=20_000)
    return r["fixed_mask"], r["integers"], np.array([r["ratio"], r["ratio_full_set"], r["success_rate"]])


@needs_kernel
def test_z_matrix_identical(monkeypatch):
    """Z from the operations: the reductions of the test covariances, and operation lists whose bound
    reaches 2**62 (the exact Python-integer form: the same Z, or the same error)."""
    for a, Q in _covariances():
        ops = amb._reduce(*amb.ld_factorize(Q))[2]
        Zc = _outcome(lambda o, n: (amb._z_matrix(o, n),), ops, a.size)
        assert _same(Zc, _python(monkeypatch, _outcome, lambda o, n: (amb._z_matrix(o, n),), ops, a.size))
    big = 2**40
    for ops in ([(1, 0, big), (0, 1, big), (1, 0, -big)], [(1, 0, big), (0, 1, 0), (1, 0, big), (0, 1, 3)],
                [(1, 0, 2**70)], [(1, 0, 3), (0, 1, 0), (2, 1, -2)]):
        assert _same(_outcome(lambda o: (amb._z_matrix(o, 3),), ops),
                     _python(monkeypatch, _outcome, lambda o: (amb._z_matrix(o, 3),), ops))


@needs_kernel
def test_search_cap_identical(monkeypatch):
    """A weak float solution that exceeds the node cap: the same error (with the same count of
    candidates found) from both."""
    a, Q = _covariances()[8]
    L, d = amb.ld_factorize(Q * 1e4)
    zs = np.linspace(-0.4, 0.4, d.size)
    with pytest.raises(amb.SearchLimitError) as ec:
        amb.search(L, d, zs, 2, max_nodes=500)
    with pytest.raises(amb.SearchLimitError) as ep:
        _python(monkeypatch, amb.search, L, d, zs, 2, max_nodes=500)
    assert str(ec.value) == str(ep.value)


@needs_kernel
def test_search_ties_and_views(monkeypatch):
    """Equal norms (a float exactly between integers, identity covariance) keep the Python order, and a
    non-contiguous block (the tail of a reduced factor, as rtk_multi searches) is accepted."""
    zc, sc = amb.search(np.eye(3), np.ones(3), np.array([0.5, 0.5, 0.0]), 4)
    zp, sp = _python(monkeypatch, amb.search, np.eye(3), np.ones(3), np.array([0.5, 0.5, 0.0]), 4)
    assert np.array_equal(zc, zp) and np.array_equal(sc, sp)
    a, Q = _covariances()[7]
    Lr, dr, _ = amb._reduce(*amb.ld_factorize(Q))
    zc, sc = amb.search(Lr[10:, 10:], dr[10:], a[10:] % 1.0, 2)
    zp, sp = _python(monkeypatch, amb.search, Lr[10:, 10:], dr[10:], a[10:] % 1.0, 2)
    assert np.array_equal(zc, zp) and np.array_equal(sc, sp)


@needs_kernel
def test_reduce_huge_integer_falls_back(monkeypatch):
    """A Gauss transformation beyond 2**62 is left to the Python loop (the kernel answers None)."""
    L = np.array([[1.0, 0.0], [3e19, 1.0]])
    d = np.array([1.0, 1.0])
    assert amb._lambdacore.reduce(L.copy(), d.copy(), amb.PERM_RTOL) is None
    try:
        expected = _python(monkeypatch, amb._reduce, L, d)
    except Exception as exc:         # noqa: BLE001  (whatever the Python loop does, the default path does too)
        with pytest.raises(type(exc)):
            amb._reduce(L, d)
    else:
        got = amb._reduce(L, d)
        assert np.array_equal(got[0], expected[0]) and got[2] == expected[2]
