"""Tests for cdgps_cli.estimation.ambiguity (LAMBDA integer least squares)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.linalg import cho_factor, solve_triangular

from cdgps_cli.estimation.ambiguity import (
    AmbiguityError,
    decorrelate,
    lambda_search,
    ld_factorize,
    partial_fix,
    ratio_test,
    resolve,
    search,
)

# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------


def qnorm(a, Q, z):
    """Independent squared norm (a - z)^T Q^{-1} (a - z) for rows of z.

    Uses a Cholesky factor of Q (no LAMBDA machinery).  Integer offsets are
    removed before subtracting so that large ambiguities lose no precision.
    """
    a = np.asarray(a, dtype=float)
    z = np.atleast_2d(np.asarray(z))
    base = np.floor(a + 0.5)
    e = (a - base)[None, :] - (z - base[None, :].astype(np.int64)).astype(float)
    c, lower = cho_factor(Q, lower=True)
    y = solve_triangular(c, e.T, lower=True)
    return np.sum(y * y, axis=0)


def brute_force(a, Q, radius2, m=2, max_points=2_000_000):
    """Exhaustive search of all integers z with norm <= radius2.

    Box justification: if (a - z)^T Q^{-1} (a - z) <= R then, by
    Cauchy-Schwarz, |a_i - z_i| <= sqrt(R * Q_ii) for every i.  So the box
    ceil(a_i - sqrt(R Q_ii)) .. floor(a_i + sqrt(R Q_ii)) contains every
    integer vector inside the ellipsoid of squared radius R.  Callers pass an
    R that is >= the m-th best norm (e.g. the largest norm among m distinct
    integer vectors whose norms were computed independently), so the true
    m best vectors are all in the box.
    """
    a = np.asarray(a, dtype=float)
    n = a.size
    base = np.floor(a + 0.5)
    f = a - base
    half = np.sqrt(radius2 * (1 + 1e-9) * np.diag(Q)) + 1e-9
    lo = np.ceil(f - half).astype(int)
    hi = np.floor(f + half).astype(int)
    sizes = hi - lo + 1
    total = int(np.prod(sizes))
    assert total <= max_points, f"brute-force box too large ({total} points)"
    grids = np.meshgrid(*[np.arange(l, h + 1) for l, h in zip(lo, hi)], indexing="ij")
    k = np.stack([g.ravel() for g in grids], axis=1)  # offsets from round(a)
    e = f[None, :] - k
    c, lower = cho_factor(Q, lower=True)
    y = solve_triangular(c, e.T, lower=True)
    norms = np.sum(y * y, axis=0)
    order = np.argsort(norms, kind="stable")[:m]
    return (k[order] + base.astype(np.int64)).astype(np.int64), norms[order], total


def random_orthogonal(rng, n):
    q, r = np.linalg.qr(rng.standard_normal((n, n)))
    return q * np.sign(np.diag(r))


def make_problem(rng, n, kind):
    """Random float ambiguities and covariance of a given flavour."""
    if kind == "moderate":
        A = rng.standard_normal((n, n))
        Q = A @ A.T / n * rng.uniform(0.2, 3.0) + 0.01 * np.eye(n)
    elif kind == "near_singular":
        # one eigenvalue 1e-6 times the largest: condition number ~1e6,
        # strong correlations between all ambiguities
        rest = rng.uniform(0.05, 1.0, n - 1)
        lam = np.concatenate([[1e-6 * rest.max()], rest])
        lam *= rng.uniform(0.1, 1.0) / lam.max()
        V = random_orthogonal(rng, n)
        Q = (V * lam) @ V.T
        Q = 0.5 * (Q + Q.T)
    else:  # pragma: no cover - test bug
        raise ValueError(kind)
    a = rng.integers(-10_000, 10_000, n) + rng.uniform(-2, 2, n)
    return a, Q


def gnss_like_covariance(rng, nsat=13, nfreq=3, sigma_phase=0.003, sigma_code=0.3):
    """Single-epoch double-difference ambiguity covariance (cycles^2).

    Multi-frequency phase + code, random satellite geometry, DD with the
    highest satellite as reference: n = (nsat - 1) * nfreq ambiguities.
    """
    lams = np.array([0.19029367, 0.24421021, 0.25482804, 0.2548280, 0.2])[:nfreq]
    az = rng.uniform(0, 2 * np.pi, nsat)
    el = rng.uniform(np.radians(10), np.radians(85), nsat)
    ref = int(np.argmax(el))
    others = [i for i in range(nsat) if i != ref]
    ns = nsat - 1
    D = np.zeros((ns, nsat))
    D[np.arange(ns), others] = 1.0
    D[:, ref] = -1.0
    u = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=1)
    G = D @ u
    Winv = np.linalg.inv(D @ D.T)
    nx = 3 + ns * nfreq
    N = np.zeros((nx, nx))
    for f, lam in enumerate(lams):
        A = np.zeros((ns, nx))
        A[:, :3] = G
        N += A.T @ Winv @ A / sigma_code**2
        A[:, 3 + f * ns : 3 + (f + 1) * ns] = lam * np.eye(ns)
        N += A.T @ Winv @ A / sigma_phase**2
    C = np.linalg.inv(N)
    Qa = C[3:, 3:]
    return 0.5 * (Qa + Qa.T)


# ---------------------------------------------------------------------------
# fixtures
# ---------------------------------------------------------------------------


@pytest.fixture
def rtklib_case1():
    """RTKLIB unit-test vectors, case 1 (n = 6).

    Source: tomojitakasu/RTKLIB, test/utest/t_lambda.c (a1, Q1, F1, s1).
    F1 is stored there as [ambiguity][candidate]; here cands[k] is candidate k.
    """
    a = np.array([1585184.171, -6716599.430, 3915742.905, 7627233.455, 9565990.879, 989457273.200])
    Q = np.full((6, 6), 0.112202)
    np.fill_diagonal(Q, 0.227134)
    Q[5, :] = Q[:, 5] = 0.103473
    Q[5, 5] = 0.434339
    F = np.array(
        [
            [1585184, -6716599, 3915743, 7627234, 9565991, 989457273],
            [1585184, -6716600, 3915743, 7627233, 9565991, 989457273],
        ],
        dtype=np.int64,
    )
    s = np.array([3.507984, 3.708456])
    return {"a": a, "Q": Q, "F": F, "s": s}


@pytest.fixture
def rtklib_case2():
    """RTKLIB unit-test vectors, case 2 (n = 10, nearly singular Q).

    Source: tomojitakasu/RTKLIB, test/utest/t_lambda.c (a2, Q2, F2, s2).
    Q2 has the block structure [[A, B], [B, C]] with the constant
    diagonal/off-diagonal values listed there.
    """
    a = np.array(
        [
            -13324172.755747, -10668894.713608, -7157225.010770, -6149367.974367,
            -7454133.571066, -5969200.494550, 8336734.058423, 6186974.084502,
            -17549093.883655, -13970158.922370,
        ]
    )

    def block(diag, off):
        b = np.full((5, 5), off)
        np.fill_diagonal(b, diag)
        return b

    Q = np.block(
        [
            [block(0.446320, 0.223160), block(0.572775, 0.286388)],
            [block(0.572775, 0.286388), block(0.735063, 0.367531)],
        ]
    )
    F = np.array(
        [
            [-13324188, -10668901, -7157236, -6149379, -7454143,
             -5969220, 8336726, 6186960, -17549108, -13970171],
            [-13324188, -10668908, -7157236, -6149379, -7454143,
             -5969220, 8336717, 6186960, -17549108, -13970171],
        ],
        dtype=np.int64,
    )
    s = np.array([1506.435789, 1612.811795])
    return {"a": a, "Q": Q, "F": F, "s": s}


@pytest.fixture
def textbook_case():
    """3-D example of Teunissen / de Jonge & Tiberius (1996)."""
    a = np.array([5.45, 3.10, 2.97])
    Q = np.array([[6.290, 5.978, 0.544], [5.978, 6.292, 2.340], [0.544, 2.340, 6.288]])
    return {"a": a, "Q": Q}


@pytest.fixture
def partial_case():
    """Deliberately ambiguous third component: full set fails, pair passes.

    a[2] sits half-way between two integers with a large variance; the first
    two are well determined.  The marginal variance of a[2] is the largest,
    so it is the first one dropped.
    """
    a = np.array([0.10, -0.05, 0.5])
    Q = np.array([[0.010, 0.004, 0.0], [0.004, 0.012, 0.0], [0.0, 0.0, 0.5]])
    return {"a": a, "Q": Q}


@pytest.fixture
def drop_order_case():
    """Largest-variance ambiguity is well determined, a medium one is a tie.

    Dropping by largest marginal variance removes index 2 first (still
    fails), then index 1 (the tie), leaving index 0 which passes.
    """
    a = np.array([0.02, 0.5, 0.01])
    Q = np.diag([0.01, 0.04, 0.09])
    return {"a": a, "Q": Q}


@pytest.fixture
def gnss36():
    rng = np.random.default_rng(20240611)
    Q = gnss_like_covariance(rng)
    truth = rng.integers(-1_000_000, 1_000_000, Q.shape[0]).astype(float)
    a = truth + np.linalg.cholesky(Q) @ rng.standard_normal(Q.shape[0])
    return {"a": a, "Q": Q, "truth": truth.astype(np.int64)}


# ---------------------------------------------------------------------------
# published vectors
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("case_name", ["rtklib_case1", "rtklib_case2"])
def test_rtklib_unit_vectors(case_name, request):
    case = request.getfixturevalue(case_name)
    cands, s = lambda_search(case["a"], case["Q"], candidates=2)
    assert cands.dtype == np.int64
    assert cands.shape == (2, case["a"].size)
    np.testing.assert_array_equal(cands, case["F"])
    # RTKLIB asserts |s - s_ref| < 1e-4
    np.testing.assert_allclose(s, case["s"], rtol=0, atol=1e-4)
    # norms agree with the definition evaluated independently
    np.testing.assert_allclose(s, qnorm(case["a"], case["Q"], cands), rtol=1e-7)


def test_textbook_3x3_matches_brute_force(textbook_case):
    a, Q = textbook_case["a"], textbook_case["Q"]
    cands, s = lambda_search(a, Q, candidates=3)
    bf, bf_s, _ = brute_force(a, Q, radius2=float(qnorm(a, Q, cands).max()), m=3)
    np.testing.assert_array_equal(cands, bf)
    np.testing.assert_allclose(s, bf_s, rtol=1e-9)
    # the well-known ILS solution of this example (float rounding would give
    # [5, 3, 3]); confirmed above by exhaustive enumeration
    np.testing.assert_array_equal(cands[0], [5, 3, 4])
    np.testing.assert_array_equal(cands[1], [6, 4, 4])
    assert s[0] == pytest.approx(0.2183311, abs=1e-6)


# ---------------------------------------------------------------------------
# building blocks
# ---------------------------------------------------------------------------


def test_ld_factorize_reconstructs(textbook_case, rtklib_case2):
    for Q in (textbook_case["Q"], rtklib_case2["Q"]):
        Q_in = Q.copy()
        L, d = ld_factorize(Q)
        n = Q.shape[0]
        np.testing.assert_array_equal(Q, Q_in)  # input untouched
        np.testing.assert_allclose(np.diag(L), np.ones(n))
        assert np.all(np.triu(L, 1) == 0)
        assert np.all(d > 0)
        np.testing.assert_allclose(L.T @ np.diag(d) @ L, Q, rtol=0, atol=1e-12 * np.abs(Q).max())
        # last pivot is the plain variance of the last ambiguity
        assert d[-1] == pytest.approx(Q[-1, -1])


@pytest.mark.parametrize(
    "Q",
    [
        np.array([[1.0, 2.0], [2.0, 1.0]]),  # indefinite
        np.array([[1.0, 1.0], [1.0, 1.0]]),  # singular
        np.array([[-1.0]]),
        np.array([[1.0, 0.5], [0.0, 1.0]]),  # not symmetric
    ],
)
def test_ld_factorize_rejects_non_spd(Q):
    with pytest.raises(AmbiguityError, match="not symmetric positive definite"):
        ld_factorize(Q)


def test_decorrelate_properties(textbook_case, rtklib_case2):
    for Q in (textbook_case["Q"], rtklib_case2["Q"]):
        L, d = ld_factorize(Q)
        L0, d0 = L.copy(), d.copy()
        Lz, dz, Z = decorrelate(L, d)
        np.testing.assert_array_equal(L, L0)
        np.testing.assert_array_equal(d, d0)
        assert Z.dtype == np.int64
        assert round(abs(np.linalg.det(Z.astype(float)))) == 1
        Qz = Z.T.astype(float) @ Q @ Z.astype(float)
        np.testing.assert_allclose(
            Lz.T @ np.diag(dz) @ Lz, Qz, rtol=0, atol=1e-9 * np.abs(Qz).max()
        )
        # size reduced and no adjacent swap left that would shrink d[k+1]
        assert np.all(np.abs(np.tril(Lz, -1)) <= 0.5 + 1e-12)
        n = dz.size
        for k in range(n - 1):
            assert dz[k] + Lz[k + 1, k] ** 2 * dz[k + 1] >= (1 - 1e-6) * dz[k + 1]
        # determinant (product of conditional variances) is invariant
        assert np.prod(dz) == pytest.approx(np.prod(d), rel=1e-8)


def test_decorrelate_reduces_textbook_correlation(textbook_case):
    Q = textbook_case["Q"]
    Lz, dz, Z = decorrelate(*ld_factorize(Q))
    Qz = Z.T.astype(float) @ Q @ Z.astype(float)
    corr = Qz / np.sqrt(np.outer(np.diag(Qz), np.diag(Qz)))
    corr0 = Q / np.sqrt(np.outer(np.diag(Q), np.diag(Q)))
    assert np.abs(corr - np.eye(3)).max() < np.abs(corr0 - np.eye(3)).max()
    assert np.diag(Qz).max() < np.diag(Q).max()


def test_search_diagonal_known_answer():
    # independent components: best = rounding, second = flip the component
    # with the smallest extra cost
    L = np.eye(3)
    d = np.array([0.04, 0.09, 0.01])
    zs = np.array([0.3, 1.9, -2.1])
    zn, s = search(L, d, zs, 3)
    np.testing.assert_array_equal(zn[0], [0, 2, -2])
    assert s[0] == pytest.approx(0.09 / 0.04 + 0.01 / 0.09 + 0.01 / 0.01)
    # flipping a[0] 0 -> 1 costs (0.49 - 0.09)/0.04 = 10, a[1] 2 -> 1 costs
    # (0.81 - 0.01)/0.09 = 8.89, a[2] costs (0.81 - 0.01)/0.01 = 80
    np.testing.assert_array_equal(zn[1], [0, 1, -2])
    np.testing.assert_array_equal(zn[2], [1, 2, -2])
    assert np.all(np.diff(s) >= 0)


def test_search_rejects_bad_arguments():
    with pytest.raises(AmbiguityError):
        search(np.eye(2), np.array([1.0, 1.0]), np.zeros(3), 2)
    with pytest.raises(AmbiguityError):
        search(np.eye(2), np.array([1.0, 1.0]), np.zeros(2), 0)


# ---------------------------------------------------------------------------
# brute force on random problems
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["moderate", "near_singular"])
@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_lambda_matches_brute_force(n, kind):
    rng = np.random.default_rng(1000 * n + (kind == "near_singular"))
    for _ in range(12):
        a, Q = make_problem(rng, n, kind)
        if kind == "near_singular":
            assert np.linalg.cond(Q) > 9e5
        cands, s = lambda_search(a, Q, candidates=2)
        assert cands.dtype == np.int64 and cands.shape == (2, n)
        assert not np.array_equal(cands[0], cands[1])
        own = qnorm(a, Q, cands)
        np.testing.assert_allclose(s, own, rtol=1e-9)
        bf, bf_s, _ = brute_force(a, Q, radius2=float(own.max()), m=2)
        np.testing.assert_allclose(s, bf_s, rtol=1e-9)
        if bf_s[1] - bf_s[0] > 1e-9 * bf_s[1]:  # no tie: vectors are unique
            np.testing.assert_array_equal(cands, bf)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_many_candidates_match_brute_force(n):
    rng = np.random.default_rng(7 + n)
    for _ in range(4):
        a, Q = make_problem(rng, n, "moderate")
        cands, s = lambda_search(a, Q, candidates=6)
        assert len({tuple(c) for c in cands}) == 6
        assert np.all(np.diff(s) >= 0)
        bf, bf_s, _ = brute_force(a, Q, radius2=float(qnorm(a, Q, cands).max()), m=6)
        np.testing.assert_allclose(s, bf_s, rtol=1e-9)
        np.testing.assert_array_equal(cands, bf)


def test_result_invariant_to_ambiguity_order():
    rng = np.random.default_rng(99)
    a, Q = make_problem(rng, 5, "near_singular")
    perm = rng.permutation(5)
    c1, s1 = lambda_search(a, Q)
    c2, s2 = lambda_search(a[perm], Q[np.ix_(perm, perm)])
    np.testing.assert_allclose(s1, s2, rtol=1e-8)
    np.testing.assert_array_equal(c1[:, perm], c2)


@pytest.mark.parametrize("kind", ["moderate", "near_singular"])
def test_large_integer_offsets(kind):
    # results must be exactly shift-equivariant even for offsets ~1e12
    # cycles, where a naive search on the raw floats loses ~1e-4 cycles
    rng = np.random.default_rng(5)
    a, Q = make_problem(rng, 4, kind)
    a = a - np.floor(a)  # fractional parts in [0, 1)
    c0, s0 = lambda_search(a, Q)
    shift = np.array([1_000_000, -3_000_000_000_000, 987_654_321, 2**40 + 12])
    c1, s1 = lambda_search(a + shift, Q)
    np.testing.assert_array_equal(c1, c0 + shift)
    # a + shift is rounded to the float grid (spacing ~2e-4 at 2**40), so
    # compare against norms of the *represented* float vector
    np.testing.assert_allclose(s1, qnorm(a + shift, Q, c1), rtol=1e-9)


@pytest.mark.parametrize("scale", [1e-6, 1e-3, 1e3])
def test_scale_of_q_only_scales_norms(scale):
    # ILS solution is invariant to scaling Q; norms scale by 1/scale
    rng = np.random.default_rng(11)
    a, Q = make_problem(rng, 5, "near_singular")
    c0, s0 = lambda_search(a, Q, candidates=3)
    c1, s1 = lambda_search(a, Q * scale, candidates=3)
    np.testing.assert_array_equal(c1, c0)
    np.testing.assert_allclose(s1, s0 / scale, rtol=1e-8)


def test_example_from_brief_large_offset():
    a = np.array([1e6 + 0.3, 2.0 - 0.1])
    Q = np.array([[0.05, 0.01], [0.01, 0.05]])
    cands, s = lambda_search(a, Q)
    np.testing.assert_array_equal(cands[0], [1_000_000, 2])
    np.testing.assert_allclose(s, qnorm(a, Q, cands), rtol=1e-9)


def test_single_ambiguity():
    cands, s = lambda_search([2.3], [[0.04]], candidates=3)
    np.testing.assert_array_equal(cands[:, 0], [2, 3, 1])
    np.testing.assert_allclose(s, np.array([0.09, 0.49, 1.69]) / 0.04)


def test_gnss36_resolves_truth_quickly(gnss36):
    a, Q = gnss36["a"], gnss36["Q"]
    assert Q.shape == (36, 36)
    cands, s = lambda_search(a, Q)
    np.testing.assert_array_equal(cands[0], gnss36["truth"])
    np.testing.assert_allclose(s, qnorm(a, Q, cands), rtol=1e-7)
    assert ratio_test(s)[0]
    # the search's work, not the wall clock (which a loaded machine inflates): this case needs
    # 1 000–2 000 nodes after the decorrelation (measured); ten times that trips the cap
    lambda_search(a, Q, max_nodes=20_000)


# ---------------------------------------------------------------------------
# validation
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "a, Q, m, match",
    [
        ([0.1, 0.2], np.eye(3)[:2], 2, "square"),
        ([0.1, 0.2], np.eye(3), 2, "size mismatch"),
        ([[0.1, 0.2]], np.eye(2), 2, "1-D"),
        ([], np.zeros((0, 0)), 2, "at least one"),
        ([0.1, np.nan], np.eye(2), 2, "a contains non-finite"),
        ([0.1, np.inf], np.eye(2), 2, "a contains non-finite"),
        ([0.1, 2.0**53], np.eye(2), 2, "2\\*\\*52"),
        ([0.1, 0.2], np.array([[1.0, np.nan], [np.nan, 1.0]]), 2, "Q contains non-finite"),
        ([0.1, 0.2], np.array([[1.0, 0.3], [0.2, 1.0]]), 2, "not symmetric"),
        ([0.1, 0.2], np.array([[1.0, 2.0], [2.0, 1.0]]), 2, "positive definite"),
        ([0.1, 0.2], np.zeros((2, 2)), 2, "positive definite"),
        ([0.1, 0.2], np.eye(2), 0, "candidates must be >= 1"),
        ([0.1, 0.2], np.eye(2), 1.5, "candidates must be an integer"),
        ([0.1, 0.2], np.eye(2), True, "candidates must be an integer"),
    ],
)
def test_validation_errors(a, Q, m, match):
    with pytest.raises(AmbiguityError, match=match):
        lambda_search(a, Q, candidates=m)


def test_validation_lists_all_problems():
    with pytest.raises(AmbiguityError) as exc:
        lambda_search([np.nan, 0.0, 1.0], np.eye(2), candidates=0)
    msg = str(exc.value)
    assert "non-finite" in msg and "size mismatch" in msg and "candidates" in msg
    assert issubclass(AmbiguityError, ValueError)


def test_tiny_asymmetry_is_tolerated(textbook_case):
    Q = textbook_case["Q"].copy()
    Q[0, 1] += 1e-12
    c_ref, s_ref = lambda_search(textbook_case["a"], textbook_case["Q"])
    c, s = lambda_search(textbook_case["a"], Q)
    np.testing.assert_array_equal(c, c_ref)
    np.testing.assert_allclose(s, s_ref, rtol=1e-9)


# ---------------------------------------------------------------------------
# ratio test and partial fixing
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "s, threshold, accepted, ratio",
    [
        ([1.0, 3.0], 3.0, True, 3.0),  # boundary is accepted
        ([1.0, 2.9], 3.0, False, 2.9),
        ([2.0, 9.0, 10.0], 3.0, True, 4.5),
        ([0.0, 1.0], 3.0, True, np.inf),
        ([0.0, 0.0], 3.0, False, 1.0),
        ([1.0, 1.5], 1.2, True, 1.5),
    ],
)
def test_ratio_test_values(s, threshold, accepted, ratio):
    ok, r = ratio_test(np.array(s), threshold=threshold)
    assert ok is accepted
    assert r == pytest.approx(ratio)


@pytest.mark.parametrize("s", [[1.0], [2.0, 1.0], [-1.0, 2.0], [1.0, np.nan]])
def test_ratio_test_rejects_bad_norms(s):
    with pytest.raises(AmbiguityError):
        ratio_test(np.array(s))


def test_partial_fix_full_set_passes(textbook_case, gnss36):
    res = partial_fix(gnss36["a"], gnss36["Q"])
    assert res["n_fixed"] == 36 and res["fixed_mask"].all()
    np.testing.assert_array_equal(res["integers"], gnss36["truth"])
    assert res["ratio"] >= 3.0
    assert res["integers"].dtype == np.int64 and res["fixed_mask"].dtype == bool


def test_partial_fix_drops_ambiguous_component(partial_case):
    a, Q = partial_case["a"], partial_case["Q"]
    # preconditions of the constructed case
    _, s_full = lambda_search(a, Q)
    assert not ratio_test(s_full)[0]
    sub_c, sub_s = lambda_search(a[:2], Q[:2, :2])
    ok_sub, ratio_sub = ratio_test(sub_s)
    assert ok_sub

    res = partial_fix(a, Q)
    np.testing.assert_array_equal(res["fixed_mask"], [True, True, False])
    np.testing.assert_array_equal(res["integers"][:2], sub_c[0])
    np.testing.assert_array_equal(res["integers"][:2], [0, 0])
    assert res["n_fixed"] == 2
    assert res["ratio"] == pytest.approx(ratio_sub)


def test_partial_fix_drop_order_and_min_fixed(drop_order_case):
    a, Q = drop_order_case["a"], drop_order_case["Q"]
    res = partial_fix(a, Q)
    np.testing.assert_array_equal(res["fixed_mask"], [True, False, False])
    assert res["n_fixed"] == 1 and res["integers"][0] == 0
    assert res["ratio"] == pytest.approx((0.98**2 / 0.01) / (0.02**2 / 0.01))

    # with min_fixed=2 no acceptable subset exists: nothing is fixed and the
    # full-set ratio (a tie) is reported
    res2 = partial_fix(a, Q, min_fixed=2)
    assert res2["n_fixed"] == 0 and not res2["fixed_mask"].any()
    assert res2["ratio"] == pytest.approx(1.0)


def test_partial_fix_validation(partial_case):
    with pytest.raises(AmbiguityError, match="min_fixed"):
        partial_fix(partial_case["a"], partial_case["Q"], min_fixed=0)
    with pytest.raises(AmbiguityError, match="min_fixed"):
        partial_fix(partial_case["a"], partial_case["Q"], min_fixed=4)
    with pytest.raises(AmbiguityError, match="size mismatch"):
        partial_fix(partial_case["a"][:2], partial_case["Q"])


def test_bootstrap_success_rate_closed_form_and_monte_carlo():
    """1-D: P = 2Φ(1/(2σ)) − 1 exactly; 2-D correlated: the product of conditional terms equals the
    frequency with which sequential rounding (bootstrapping) recovers the true integers."""
    import math
    from cdgps_cli.estimation.ambiguity import bootstrap_success_rate, ld_factorize, success_tail
    from scipy.stats import norm
    for s in (0.05, 0.2, 0.5):
        assert bootstrap_success_rate([s * s]) == pytest.approx(2 * norm.cdf(1 / (2 * s)) - 1, rel=1e-12)
    Q = np.array([[0.09, 0.05], [0.05, 0.06]])
    L, d = ld_factorize(Q)
    p = bootstrap_success_rate(d)
    rng = np.random.default_rng(5)
    e = rng.multivariate_normal([0, 0], Q, size=200_000)
    z1 = np.round(e[:, 1])                                   # ambiguity 1 first (d[1] is unconditional)
    z0 = np.round(e[:, 0] - Q[0, 1] / Q[1, 1] * (e[:, 1] - z1))
    freq = np.mean((z0 == 0) & (z1 == 0))
    assert abs(freq - p) < 4 * math.sqrt(p * (1 - p) / e.shape[0])
    assert success_tail(d, 0.0) == 0 and success_tail([1e-4, 1.0, 1e-4], 0.999) == 2
    assert success_tail([1.0], 0.999) == 1
    with pytest.raises(Exception):
        bootstrap_success_rate([0.0])


# ---- success-rate criterion in the batch fixing (issue 28 item 4)


def test_ratio_alone_fixes_an_imprecise_set_the_success_rate_refuses():
    """Floats 0.02 cycle from integers pass the ratio test by far, but with σ = 0.32 cycle per
    ambiguity bootstrapping succeeds only 0.886³ = 70 % of the time: not fixed with the criterion."""
    from cdgps_cli.estimation.ambiguity import resolve

    a, Q = np.array([0.02, -0.01, 3.03]), 0.1 * np.eye(3)
    plain = resolve(a, Q, 3.0)
    assert plain["n_fixed"] == 3 and plain["ratio"] > 3
    crit = resolve(a, Q, 3.0, min_success_rate=0.999)
    assert crit["n_fixed"] == 0 and not crit["accepted"]
    assert crit["success_rate"] == pytest.approx(math.erf(1 / (2 * math.sqrt(0.2))) ** 3, rel=1e-12)


def test_success_rate_keeps_the_precise_subset():
    from cdgps_cli.estimation.ambiguity import resolve

    a, Q = np.array([0.4, 1.02, -1.99]), np.diag([0.1, 1e-3, 1e-3])
    r = resolve(a, Q, 3.0, min_success_rate=0.999)
    assert r["partial"] and r["fixed_mask"].tolist() == [False, True, True]
    assert r["integers"][1:].tolist() == [1, -2] and r["success_rate"] >= 0.999
    r = resolve(a, Q, 3.0, partial=False, min_success_rate=0.999)
    assert r["n_fixed"] == 0


def test_success_rate_agrees_with_monte_carlo_bootstrapping():
    """The product of erf terms against counting correct bootstrapped roundings of simulated floats."""
    from cdgps_cli.estimation.ambiguity import _success_rate

    rng = np.random.default_rng(3)
    B = rng.standard_normal((3, 3))
    Q = 0.02 * (B @ B.T + 0.5 * np.eye(3))
    L = np.linalg.cholesky(Q)
    e = rng.standard_normal((200_000, 3)) @ L.T
    # bootstrapping in the original order, last ambiguity first: x_i|J = x_i − Q_iJ Q_JJ⁻¹ (x_J − z_J)
    Ld, d = ld_factorize(Q)
    z = np.zeros_like(e)
    for i in range(2, -1, -1):
        J = list(range(i + 1, 3))
        cond = e[:, i] - ((e[:, J] - z[:, J]) @ np.linalg.solve(Q[np.ix_(J, J)], Q[J, i]) if J else 0.0)
        z[:, i] = np.round(cond)
    ok = np.all(z == 0, axis=1)
    p_mc = ok.mean()
    p = float(np.prod([math.erf(1 / (2 * math.sqrt(2 * x))) for x in d]))
    assert p_mc == pytest.approx(p, abs=4e-3)
    assert _success_rate(Q) >= p - 1e-12          # decorrelation never lowers it


def test_z_matrix_and_size_reduction_match_the_elementwise_reference():
    """The numpy Z (column operations on int64) equals the Python-integer one, and the size
    reduction that searches each column with numpy records the operations of the element-by-element
    double loop (same L bit for bit)."""
    from cdgps_cli.estimation import ambiguity as amb

    def size_reduce_loop(L, ops):
        n = L.shape[0]
        for j in range(n - 2, -1, -1):
            for i in range(j + 2, n):
                if abs(L[i, j]) > 0.5:
                    amb._gauss(L, ops, None, i, j)

    rng = np.random.default_rng(3)
    for n in (2, 5, 12, 30):
        A = rng.normal(size=(n, n)) * np.geomspace(1, 10, n)
        L0, d0 = amb.ld_factorize(A @ A.T + 1e-3 * np.eye(n))
        L, d, ops = amb._reduce(L0, d0)
        assert np.array_equal(amb._z_matrix(ops, n), amb._z_matrix_exact(ops, n))
        Lr = np.array(L0, copy=True)
        for a in range(n):                      # a lower triangle with entries beyond 1/2 to reduce
            Lr[a + 1:, a] = rng.normal(scale=3.0, size=n - a - 1)
        L1, L2, ops1, ops2 = Lr.copy(), Lr.copy(), [], []
        amb._size_reduce(L1, ops1, None)
        size_reduce_loop(L2, ops2)
        assert ops1 == ops2 and np.array_equal(L1, L2)
        assert len(ops1) > 0 or n < 3


def test_symmetric_factorisation_and_tail_rate_equal_the_checked_ones():
    """ld_factorize_symmetric (rtk's per-epoch call, input already symmetrised) returns ld_factorize's
    factors bit for bit and still refuses an indefinite matrix; success_tail_rate gives success_tail's
    index and the tail's bootstrapped success rate."""
    from cdgps_cli.estimation.ambiguity import (bootstrap_success_rate, ld_factorize, ld_factorize_symmetric, success_tail,
                                                success_tail_rate)

    rng = np.random.default_rng(5)
    A = rng.normal(size=(9, 9))
    Q = A @ A.T * 0.02 + np.eye(9) * 1e-3
    Qs = 0.5 * (Q + Q.T)
    for got, want in zip(ld_factorize_symmetric(Qs), ld_factorize(Q)):
        assert np.array_equal(got, want)
    with pytest.raises(AmbiguityError):
        ld_factorize_symmetric(np.diag([1.0, -1.0, 2.0]))
    d = ld_factorize(Q)[1]
    for p in (0.5, 0.9, 0.999, 0.999999):
        k, rate = success_tail_rate(d, p)
        assert k == success_tail(d, p)
        assert rate == (pytest.approx(bootstrap_success_rate(d[k:]), rel=1e-12) if k < d.size else 0.0)


def test_search_reduced_equals_search_of_two():
    """rtk's unchecked search of the best two candidates returns search(..., 2)'s candidates and norms
    exactly, on reduced factors of random covariances of 1 to 25 ambiguities."""
    from cdgps_cli.estimation.ambiguity import decorrelate, ld_factorize, search, search_reduced

    rng = np.random.default_rng(12)
    for n in (1, 2, 5, 12, 25):
        A = rng.normal(size=(n, n))
        L, d, _ = decorrelate(*ld_factorize(A @ A.T * 0.05 + np.eye(n) * 1e-3))
        zs = rng.normal(size=n) * 0.4
        k = n // 3                                     # a tail, as rtk's partial sets
        for got, want in zip(search_reduced(L[k:, k:], d[k:], zs[k:]), search(L[k:, k:], d[k:], zs[k:], 2)):
            assert np.array_equal(got, want)


def test_resolve_on_an_empty_set_fixes_nothing_without_an_error():
    """Every ambiguity float (GLONASS alone): the shared policy gets no ambiguity, and answers that nothing is fixed."""
    for partial in (True, False):
        res = resolve(np.zeros(0), np.zeros((0, 0)), partial=partial)
        assert res["n_fixed"] == 0 and not res["accepted"] and not res["partial"]
        assert np.isnan(res["ratio"]) and res["fixed_mask"].size == 0
