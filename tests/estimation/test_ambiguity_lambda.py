"""Vectorized LAMBDA (issue 14 item 1): identical to the former pure-Python implementation on
random cases, brute force as the independent check on small ones, partial fixing from one
reduction, the search cap and the progress callback."""

from __future__ import annotations

import itertools
import time

import lambda_legacy as legacy  # the pre-issue-14 implementation, tests/estimation/lambda_legacy.py
import numpy as np
import pytest

from cdgps_cli.estimation import ambiguity as amb
from cdgps_cli.estimation.ambiguity import (
    AmbiguityError,
    SearchLimitError,
    lambda_search,
    partial_fix,
    ratio_test,
)


def random_spd(rng, n, cond_pow=3.0, corr=0.9):
    """A correlated SPD covariance (cycles^2) with eigenvalues spread over 10**cond_pow."""
    A = rng.standard_normal((n, n))
    Qo, _ = np.linalg.qr(A)
    ev = 10.0 ** rng.uniform(-cond_pow, 0.0, n) * 0.05
    Q = (Qo * ev) @ Qo.T
    # mix in a common (position-like) correlation
    g = rng.standard_normal((n, 3))
    Q = (1 - corr) * Q + corr * 0.02 * (g @ g.T) / 3 + 1e-4 * np.eye(n)
    return 0.5 * (Q + Q.T)


def dd_like_problem(n_amb, seed, n_ep=240, sigma_ph=0.003, sigma_code=0.3, lam=0.19):
    """Float ambiguities of a static DD problem: 3 position unknowns and ``n_amb`` ambiguities,
    each active over a random window of epochs, random slowly turning lines of sight."""
    rng = np.random.default_rng(seed)
    start = rng.integers(0, n_ep - 20, n_amb)
    length = rng.integers(20, n_ep, n_amb)
    stop = np.minimum(start + length, n_ep)
    u0 = rng.standard_normal((n_amb, 3))
    u1 = rng.standard_normal((n_amb, 3))
    N = np.zeros((3 + n_amb, 3 + n_amb))
    for k in range(0, n_ep, 4):
        act = np.flatnonzero((start <= k) & (k < stop))
        if act.size == 0:
            continue
        f = k / n_ep
        g = (1 - f) * u0[act] + f * u1[act]
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        rows = np.zeros((act.size, 3 + n_amb))
        rows[:, :3] = g
        rows[np.arange(act.size), 3 + act] = lam
        N += rows.T @ rows / sigma_ph**2
        N[:3, :3] += g.T @ g / sigma_code**2
    Q = np.linalg.inv(N + 1e-9 * np.eye(3 + n_amb))[3:, 3:] / lam**2
    Q = 0.5 * (Q + Q.T)
    truth = rng.integers(-50, 50, n_amb)
    a = truth + np.linalg.cholesky(Q) @ rng.standard_normal(n_amb)
    return a, Q, truth


def brute_force(a, Q, m=2, radius=3):
    """The ``m`` best integer vectors by enumerating a box around round(a)."""
    Qi = np.linalg.inv(Q)
    base = np.round(a)
    best = []
    for off in itertools.product(range(-radius, radius + 1), repeat=a.size):
        z = base + np.array(off)
        r = a - z
        best.append((float(r @ Qi @ r), tuple(z.astype(int))))
    best.sort()
    return [b[1] for b in best[:m]], np.array([b[0] for b in best[:m]])


@pytest.mark.parametrize("seed", range(40))
def test_identical_to_the_former_implementation(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 30))
    Q = random_spd(rng, n, cond_pow=rng.uniform(1, 3))
    a = rng.uniform(-20, 20, n)
    m = int(rng.integers(1, 5))
    c_new, s_new = lambda_search(a, Q, candidates=m)
    c_old, s_old = legacy.lambda_search(a, Q, candidates=m)
    np.testing.assert_array_equal(c_new, c_old)
    # the reduction now size-reduces whole columns during the walk (the former one only the
    # sub-diagonal, which let entries blow up): another Z, the same integers, norms to rounding
    np.testing.assert_allclose(s_new, s_old, rtol=1e-9, atol=1e-12)
    L, d = amb.ld_factorize(Q)
    L1, d1, Z1 = amb.decorrelate(L, d)
    assert round(abs(np.linalg.det(Z1.astype(float)))) == 1
    np.testing.assert_allclose(Z1.T @ Q @ Z1, L1.T @ np.diag(d1) @ L1, rtol=1e-8, atol=1e-10 * np.abs(Q).max())
    assert np.all(np.abs(np.tril(L1, -1)) <= 0.5 + 1e-12)
    np.testing.assert_allclose(np.sum(np.log(d1)), np.sum(np.log(d)), atol=1e-9)   # det Q kept


@pytest.mark.parametrize("n_amb", [60, 150])
def test_identical_to_the_former_implementation_on_dd_problems(n_amb):
    a, Q, truth = dd_like_problem(n_amb, seed=n_amb)
    c_new, s_new = lambda_search(a, Q)
    c_old, s_old = legacy.lambda_search(a, Q)
    np.testing.assert_array_equal(c_new, c_old)
    # the squared norms to the last bits: the compiled search sums in its own order, which on some CPUs
    # (Zen 1, AVX2) differs from numpy's by an ulp
    np.testing.assert_allclose(s_new, s_old, rtol=1e-13, atol=0)
    np.testing.assert_array_equal(c_new[0], truth)     # and the simulator's integers


@pytest.mark.parametrize("seed", range(25))
def test_matches_brute_force(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(1, 5))
    Q = random_spd(rng, n, cond_pow=2.0, corr=0.5) * rng.uniform(0.5, 4)
    a = rng.uniform(-5, 5, n)
    cands, s = lambda_search(a, Q, candidates=2)
    bf, s_bf = brute_force(a, Q, 2, radius=4 if n <= 3 else 3)
    np.testing.assert_allclose(s, s_bf, rtol=1e-9, atol=1e-12)
    assert tuple(cands[0]) == bf[0] or np.isclose(s[0], s[1])


def _partial_by_brute_force(a, Q, threshold, min_fixed=1):
    """Drop by decreasing variance (ties: lowest index), each subset by brute force."""
    n = a.size
    var = np.diag(Q)
    order = sorted(range(n), key=lambda i: (-var[i], i))
    for drop in range(0, n - min_fixed + 1):
        sub = np.sort(np.array(order[drop:]))
        bf, s = brute_force(a[sub], Q[np.ix_(sub, sub)], 2, radius=3)
        ratio = s[1] / s[0] if s[0] > 0 else np.inf
        if ratio >= threshold:
            return sub, np.array(bf[0]), ratio
    return None, None, None


@pytest.mark.parametrize("seed", range(30))
def test_partial_fix_matches_brute_force_and_former(seed):
    rng = np.random.default_rng(200 + seed)
    n = int(rng.integers(2, 5))
    Q = random_spd(rng, n, cond_pow=2.5, corr=0.3)
    Q[0, 0] += rng.uniform(0, 0.5)                      # one clearly weaker ambiguity
    a = rng.integers(-5, 5, n) + np.linalg.cholesky(Q) @ rng.standard_normal(n)
    thr = float(rng.uniform(1.5, 6))
    res = partial_fix(a, Q, threshold=thr)
    old = legacy.partial_fix(a, Q, threshold=thr)
    np.testing.assert_array_equal(res["fixed_mask"], old["fixed_mask"])
    np.testing.assert_array_equal(res["integers"], old["integers"])
    assert res["ratio"] == pytest.approx(old["ratio"], rel=1e-9)
    sub, ints, ratio = _partial_by_brute_force(a, Q, thr)
    if sub is None:
        assert res["n_fixed"] == 0
    else:
        np.testing.assert_array_equal(np.flatnonzero(res["fixed_mask"]), sub)
        np.testing.assert_array_equal(res["integers"][sub], ints)
        assert res["ratio"] == pytest.approx(ratio, rel=1e-7)


@pytest.mark.parametrize("seed", range(3))
def test_partial_fix_matches_former_on_larger_cases(seed):
    a, Q, truth = dd_like_problem(40, seed=300 + seed, n_ep=80)
    _, s = lambda_search(a, Q)
    full = ratio_test(s)[1]
    for thr in (full * 1.2, full * 3, 1e6):            # a few drops, many drops, none passing
        res = partial_fix(a, Q, threshold=thr)
        old = legacy.partial_fix(a, Q, threshold=thr)
        np.testing.assert_array_equal(res["fixed_mask"], old["fixed_mask"])
        np.testing.assert_array_equal(res["integers"], old["integers"])
        assert res["ratio"] == pytest.approx(old["ratio"], rel=1e-7)
        assert res["ratio_full_set"] == pytest.approx(full, rel=1e-12)


def test_partial_fix_of_many_segments_is_bounded():
    """150 ambiguities, every nested subset searched (nothing passes): the former loop took ~8 s
    on such a problem (one full LAMBDA per subset); one reduction takes a fraction of that."""
    a, Q, _ = dd_like_problem(150, seed=7)
    t0 = time.perf_counter()
    res = partial_fix(a, Q, threshold=1e9)
    dt = time.perf_counter() - t0
    assert res["n_fixed"] == 0 and res["subsets_searched"] == 150
    assert dt < 5.0


def test_progress_callback():
    a, Q, _ = dd_like_problem(20, seed=3, n_ep=60)
    calls = []
    res = partial_fix(a, Q, threshold=1e9, progress=lambda done, total: calls.append((done, total)))
    assert [c[0] for c in calls] == list(range(1, len(calls) + 1))
    assert len(calls) == res["subsets_searched"] == calls[0][1] == 20


def test_search_cap_raises_a_clear_error():
    rng = np.random.default_rng(5)
    n = 40
    Q = np.eye(n) * 4.0 + 0.5                           # ±2 cycles: nothing to enumerate quickly
    a = rng.uniform(-3, 3, n)
    with pytest.raises(SearchLimitError, match=r"stopped after 500 nodes for 40 ambiguities"):
        lambda_search(a, Q, max_nodes=500)
    res = partial_fix(a, Q, max_nodes=500, min_fixed=35)
    assert res["search_limited"] >= 1 and res["n_fixed"] == 0
    assert np.isnan(res["ratio_full_set"])
    assert issubclass(SearchLimitError, AmbiguityError)
    with pytest.raises(AmbiguityError, match="max_nodes"):
        lambda_search(a, Q, max_nodes=0)


def test_every_tail_of_the_reduction_is_a_reduction_of_its_subset():
    a, Q, _ = dd_like_problem(25, seed=11, n_ep=60)
    L, d = amb.ld_factorize(Q)
    seen = []

    def check(k, Lw, dw, zw, n_ops):
        ops = amb._reduce(L, d)[2][:0]  # noqa: F841  (documentation: prefix semantics below)
        Z = np.eye(Q.shape[0], dtype=np.int64)
        Zt = amb._z_matrix(all_ops[:n_ops], Q.shape[0])
        assert np.all(Zt[:k, :] == Z[:k, :]) and np.all(Zt[:, :k] == Z[:, :k])
        Qt = Q[k:, k:]
        Zs = Zt[k:, k:].astype(float)
        np.testing.assert_allclose(Lw[k:, k:].T @ np.diag(dw[k:]) @ Lw[k:, k:], Zs.T @ Qt @ Zs,
                                   rtol=1e-8, atol=1e-12)
        seen.append(k)

    all_ops = amb._reduce(L, d)[2]
    amb._reduce(L, d, on_tail=check)
    assert seen == list(range(Q.shape[0] - 1, 0, -1))


def test_resolve_reports_the_cap_and_falls_back_to_subsets():
    rng = np.random.default_rng(9)
    a, Q, truth = dd_like_problem(30, seed=21, n_ep=80)
    Qw = Q.copy()
    weak = np.arange(12)
    Qw[weak, weak] += 4.0                              # 12 hopeless ambiguities (±2 cycles each)
    a = a.copy()
    a[weak] += rng.uniform(-2, 2, weak.size)
    full = amb.resolve(a, Qw, 3.0, partial=False, max_nodes=100)
    assert full["limit_message"] and "stopped after 100 nodes" in full["limit_message"]
    assert not full["accepted"] and np.isnan(full["ratio_full_set"])
    part = amb.resolve(a, Qw, 3.0, partial=True, max_nodes=100)
    assert part["limit_message"] and part["partial"] and part["n_fixed"] >= 15
    np.testing.assert_array_equal(part["integers"][part["fixed_mask"]], truth[part["fixed_mask"]])
    assert not part["fixed_mask"][weak].any()
