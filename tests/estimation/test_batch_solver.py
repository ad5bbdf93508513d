"""Linear batch problem (Teague, How & Parkinson 1998, Eq. 13–15): O(N) SRIF vs the dense Θ form.

* :func:`srif_solve` against :func:`dense_solve` on random small problems (shared / known biases,
  absent measurements, with and without priors, with and without process noise) and on a real
  linearization of the testbed;
* the SRIF's covariance of z_N = [x_N; b] against the inverse of the dense information matrix,
  built here independently of :mod:`cdgps_cli.estimation.batch_solver` and marginalized onto z_N;
* both forms of pooling the bias-only rows (Gram / square root) and the fallback between them;
* the O(N) structure (QR count and sizes, memory) without timing asserts.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from scipy.linalg import expm

from cdgps_cli.estimation import batch_solver as batch
from cdgps_cli.estimation import compiled
from cdgps_cli.estimation.batch_solver import LinearProblem, dense_solve, srif_solve
from cdgps_cli.estimation.initializer import _Problem, window_data
from cdgps_cli.core.records import Run
from cdgps_cli.sim.structure import SimOptions, parse_slip, simulate

RTOL = 1e-8


def _rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


def random_problem(rng, n=5, r=2, C=4, N=12, prior=False, nan_frac=0.1, known=True, shared=True, slip=True,
                   h_cols=None):
    """A well-posed random LinearProblem.

    Channel c has bias ``chan_bias[c]``: some channels share one bias, one may be known (−1), and one
    channel may start a new bias parameter half way (a slip).  ~nan_frac of the measurements are
    absent.  A is a slightly damped rotation-like matrix so that A^N stays well conditioned.
    ``h_cols``: H is non-zero only in its first h_cols columns (as the modal model, whose phases do
    not depend on the rates), which lets the SRIF split off bias-only rows when C > h_cols.
    """
    S = rng.standard_normal((n, n))
    A = expm(0.3 * (S - S.T) - 0.02 * np.eye(n) + 0.02 * rng.standard_normal((n, n)))
    G = 0.3 * rng.standard_normal((n, r))
    H = rng.standard_normal((N, C, n))
    if h_cols is not None:
        H[:, :, h_cols:] = 0.0
    chan_bias = list(range(C))
    if shared and C >= 3:
        chan_bias[2] = chan_bias[1]                 # channels 1 and 2 share a bias
    if known and C >= 4:
        chan_bias[3] = -1                           # channel 3: bias known (already in y)
    free = sorted({b for b in chan_bias if b >= 0})
    remap = {b: i for i, b in enumerate(free)}
    bias_index = np.array([[remap[b] if b >= 0 else -1 for b in chan_bias]] * N, dtype=np.int64)
    m = len(free)
    if slip and N >= 4:
        bias_index[N // 2:, 0] = m                  # channel 0 slips half way: a new bias parameter
        m += 1
    y = rng.standard_normal((N, C))
    absent = rng.random((N, C)) < nan_frac
    absent[0, :] = False                            # keep every bias segment observed
    absent[N // 2, :] = False
    y[absent] = np.nan
    if prior:
        x1_mean = rng.standard_normal(n)
        x1_sqrt_info = np.triu(rng.standard_normal((n, n))) + 2 * np.eye(n)
        b_mean = rng.standard_normal(m)
        b_sqrt_info = np.triu(rng.standard_normal((m, m))) + 2 * np.eye(m)
    else:
        x1_mean, x1_sqrt_info = np.zeros(n), np.zeros((n, n))
        b_mean, b_sqrt_info = np.zeros(m), np.zeros((m, m))
    return LinearProblem(A=A, Bw_L=G, H=H, y=y, bias_index=bias_index, n_bias=m, sigma_m=0.1 + rng.random(),
                         x1_mean=x1_mean, x1_sqrt_info=x1_sqrt_info, b_mean=b_mean, b_sqrt_info=b_sqrt_info)


def dense_information(prob: LinearProblem):
    """Independent dense form: Θ rows and priors → information matrix Λ and vector η over
    v = (x₁, ω₁…ω_{N−1}, b), plus the map T with z_N = [x_N; b] = T v."""
    A, G = prob.A, prob.Bw_L
    N, C, n = prob.H.shape
    m, r = prob.n_bias, G.shape[1]
    nv = n + (N - 1) * r + m
    ib = n + (N - 1) * r
    Phi = np.hstack([np.eye(n), np.zeros((n, (N - 1) * r))])    # ∂x_k/∂(x₁, ω)
    Lam = np.zeros((nv, nv))
    eta = np.zeros(nv)
    for k in range(N):
        if k:
            Phi = A @ Phi
            Phi[:, n + (k - 1) * r:n + k * r] += G
        for c in range(C):
            if np.isnan(prob.y[k, c]):
                continue
            row = np.zeros(nv)
            row[:ib] = prob.H[k, c] @ Phi
            if prob.bias_index[k, c] >= 0:
                row[ib + prob.bias_index[k, c]] = 1.0
            Lam += np.outer(row, row) / prob.sigma_m**2
            eta += row * prob.y[k, c] / prob.sigma_m**2
    Lam[n:ib, n:ib] += np.eye((N - 1) * r)
    Sx = prob.x1_sqrt_info.T @ prob.x1_sqrt_info
    Sb = prob.b_sqrt_info.T @ prob.b_sqrt_info
    Lam[:n, :n] += Sx
    eta[:n] += Sx @ prob.x1_mean
    Lam[ib:, ib:] += Sb
    eta[ib:] += Sb @ prob.b_mean
    T = np.zeros((n + m, nv))
    T[:n, :ib] = Phi
    T[n:, ib:] = np.eye(m)
    return Lam, eta, T


def _assert_agree(s, d, rtol=RTOL):
    assert _rel(s.x, d.x) < rtol, _rel(s.x, d.x)
    assert _rel(s.b, d.b) < rtol, _rel(s.b, d.b)
    if d.w.size:
        assert _rel(s.w, d.w) < rtol, _rel(s.w, d.w)
    assert s.w.shape == d.w.shape
    assert abs(s.cost - d.cost) <= rtol * max(abs(d.cost), 1.0), (s.cost, d.cost)


CASES = [(seed, n, r, C, N, prior)
         for seed, (n, r, C, N) in enumerate([(4, 0, 3, 5), (4, 1, 4, 8), (5, 2, 5, 12), (6, 2, 3, 30), (6, 0, 5, 20),
                                              (5, 1, 3, 17), (4, 2, 4, 30), (6, 1, 5, 6)])
         for prior in (False, True)]


@pytest.mark.parametrize("seed,n,r,C,N,prior", CASES)
def test_srif_matches_dense_random(seed, n, r, C, N, prior):
    rng = np.random.default_rng(1000 + seed)
    prob = random_problem(rng, n=n, r=r, C=C, N=N, prior=prior)
    s = srif_solve(prob)
    d = dense_solve(prob)
    assert not s.rank_deficient
    assert s.x.shape == (N, n) and s.w.shape == (N - 1, r) and s.b.shape == (prob.n_bias,)
    _assert_agree(s, d)
    # and the independent dense information form gives the same minimizer
    Lam, eta, T = dense_information(prob)
    v = np.linalg.solve(Lam, eta)
    np.testing.assert_allclose(T @ v, np.concatenate([s.x[-1], s.b]), rtol=0, atol=1e-8 * np.abs(T @ v).max())


# more channels than state columns seen by the measurements (the testbed: 36 channels, 9 of 18
# states): each epoch's rows split into state rows and bias-only rows (pooled as Gram or square root)
WIDE_CASES = [(seed, n, r, C, N, hc, prior, nan, slip)
              for seed, (n, r, C, N, hc) in enumerate([(6, 2, 9, 15, 3), (4, 1, 7, 30, 2), (6, 0, 8, 12, 3),
                                                       (5, 2, 12, 40, 1)])
              for prior in (False, True) for nan, slip in ((0.0, False), (0.15, True))]


@pytest.mark.parametrize("seed,n,r,C,N,hc,prior,nan,slip", WIDE_CASES)
@pytest.mark.parametrize("square_root", [None, False, True])
def test_srif_matches_dense_more_channels_than_states(seed, n, r, C, N, hc, prior, nan, slip, square_root):
    rng = np.random.default_rng(2000 + seed)
    prob = random_problem(rng, n=n, r=r, C=C, N=N, prior=prior, nan_frac=nan, h_cols=hc, slip=slip,
                          shared=slip, known=slip)
    s = srif_solve(prob, square_root=square_root)
    d = dense_solve(prob)
    assert not s.rank_deficient
    _assert_agree(s, d)
    Lam, _, T = dense_information(prob)
    P_ref = T @ np.linalg.solve(Lam, T.T)
    assert _rel(s.P_end, P_ref) < 1e-8, _rel(s.P_end, P_ref)


@pytest.mark.parametrize("square_root", [False, True])
@pytest.mark.parametrize("seed,n,r,C,N,prior", CASES[::3])
def test_srif_forms_agree(seed, n, r, C, N, prior, square_root):
    """The Gram and the square-root pooling of the bias-only rows give the same solution."""
    rng = np.random.default_rng(1000 + seed)
    prob = random_problem(rng, n=n, r=r, C=C, N=N, prior=prior)
    _assert_agree(srif_solve(prob, square_root=square_root), dense_solve(prob))


@pytest.mark.parametrize("seed,n,r,C,N,prior", CASES)
def test_srif_covariance_is_inverse_marginal_information(seed, n, r, C, N, prior):
    """P_end = T Λ⁻¹ Tᵀ (the marginal of [x_N; b] in the dense normal matrix of Eq. 15)."""
    rng = np.random.default_rng(1000 + seed)
    prob = random_problem(rng, n=n, r=r, C=C, N=N, prior=prior)
    s = srif_solve(prob)
    Lam, _, T = dense_information(prob)
    P_ref = T @ np.linalg.solve(Lam, T.T)
    assert s.P_end is not None
    assert _rel(s.P_end, P_ref) < 1e-8, _rel(s.P_end, P_ref)
    np.testing.assert_allclose(s.P_end, s.P_end.T, rtol=0, atol=1e-12 * np.abs(s.P_end).max())
    # R_end is its square-root information: R_endᵀ R_end = P_end⁻¹
    assert _rel(s.R_end.T @ s.R_end, np.linalg.inv(P_ref)) < 1e-7


def test_covariance_by_brute_force_sensitivity():
    """Brute force, no information matrix: z_N is linear in the data, so with zero priors and
    no process noise (r = 0) Cov(z_N) = σ² J Jᵀ with J = ∂z_N/∂y by finite differences."""
    rng = np.random.default_rng(7)
    prob = random_problem(rng, n=4, r=0, C=4, N=9, nan_frac=0.15)
    s0 = srif_solve(prob)
    z0 = np.concatenate([s0.x[-1], s0.b])
    cols = []
    for k, c in zip(*np.nonzero(~np.isnan(prob.y))):
        y = prob.y.copy()
        y[k, c] += 1.0                               # exact for a linear map
        s = srif_solve(LinearProblem(**{**prob.__dict__, "y": y}))
        cols.append(np.concatenate([s.x[-1], s.b]) - z0)
    J = np.array(cols).T
    assert _rel(s0.P_end, prob.sigma_m**2 * J @ J.T) < 1e-8


def test_noise_free_data_recovered_exactly():
    """Data generated by the model with known x₁, ω, b: both solvers return them (zero priors)."""
    rng = np.random.default_rng(3)
    prob = random_problem(rng, n=5, r=2, C=5, N=25, nan_frac=0.2)
    N, C, n = prob.H.shape
    x = np.empty((N, n))
    x[0] = rng.standard_normal(n)
    w = rng.standard_normal((N - 1, 2)) * 1e-3
    for k in range(1, N):
        x[k] = prob.A @ x[k - 1] + prob.Bw_L @ w[k - 1]
    b = rng.standard_normal(prob.n_bias)
    y = np.einsum("nci,ni->nc", prob.H, x) + np.where(prob.bias_index >= 0, b[np.maximum(prob.bias_index, 0)], 0.0)
    y[np.isnan(prob.y)] = np.nan
    # ω has a unit prior, so w is recovered only approximately: make it negligible by scaling σ
    prob = LinearProblem(**{**prob.__dict__, "y": y, "sigma_m": 1e-6})
    for sol in (srif_solve(prob), dense_solve(prob)):
        np.testing.assert_allclose(sol.b, b, atol=1e-7)
        np.testing.assert_allclose(sol.x, x, atol=1e-7)


def test_unobserved_bias_is_rank_deficient():
    """A bias parameter with no measurement: the SRIF flags it (init turns this into 'not observable')."""
    rng = np.random.default_rng(5)
    p = random_problem(rng, n=4, r=1, C=3, N=10)
    m = p.n_bias + 1                                 # one extra bias that no epoch uses
    prob = LinearProblem(**{**p.__dict__, "n_bias": m, "b_mean": np.zeros(m), "b_sqrt_info": np.zeros((m, m))})
    s = srif_solve(prob)
    assert s.rank_deficient and s.P_end is None
    assert np.all(np.isfinite(s.x)) and np.all(np.isfinite(s.b))
    # with a prior on it the problem is regular again and matches the dense solution
    Sb = np.zeros((m, m))
    Sb[-1, -1] = 1.0
    prob2 = LinearProblem(**{**prob.__dict__, "b_sqrt_info": Sb})
    s2 = srif_solve(prob2)
    assert not s2.rank_deficient
    _assert_agree(s2, dense_solve(prob2))
    assert s2.P_end[-1, -1] == pytest.approx(1.0)


def test_short_windows_two_and_three_epochs():
    for N in (2, 3):
        rng = np.random.default_rng(40 + N)
        prob = random_problem(rng, n=4, r=1, C=5, N=N, nan_frac=0.0, prior=True, slip=False)
        _assert_agree(srif_solve(prob), dense_solve(prob))


# ---------------------------------------------------------------------------------------------
# a real linearization: the testbed (18 states, 9 noise inputs, 36 channels) over 3 s


@pytest.fixture(scope="module")
def testbed_lin(testbed_cfg):
    sim = simulate(testbed_cfg, SimOptions(duration_s=4.0, seed=11, phase_sigma_m=0.01,
                                           slips=[parse_slip("a5:PL6:1.5:-2")]))
    run = Run("<memory>", testbed_cfg, sim.receiver.reset_index(drop=True), sim.gyro, None, {})
    wd = window_data(run, 0.0, 3.0)
    prob = _Problem(testbed_cfg, wd, 0.02, True)
    N = len(wd.time_s)
    rng = np.random.default_rng(0)
    # linearize about a perturbed truth trajectory and perturbed biases (a Gauss–Newton iterate)
    x = sim.x[:N] + 1e-3 * rng.standard_normal(sim.x[:N].shape)
    tb = {(b["antenna"], b["transmitter"]): b["bias_m"] for b in sim.truth["biases"]}
    b = np.array([tb[(s["antenna"], s["transmitter"])] for s in wd.segments]) + 0.01 * rng.standard_normal(len(wd.segments))
    return prob.linear_problem(x, 0, x[0], 0, b), sim, wd, prob


def test_testbed_linearization_srif_matches_dense(testbed_lin):
    lp, sim, wd, prob = testbed_lin
    N, C, n = lp.H.shape
    assert (N, C, n) == (31, 36, 18) and lp.Bw_L.shape == (18, 9)
    assert lp.n_bias == 37                           # 36 channels + the slip's second segment
    s = srif_solve(lp)
    d = dense_solve(lp)
    assert not s.rank_deficient
    _assert_agree(s, d, rtol=1e-7)
    Lam, _, T = dense_information(lp)
    P_ref = T @ np.linalg.solve(Lam, T.T)
    assert _rel(s.P_end, P_ref) < 1e-6
    # one step from a point 1 mm / 1 cm off: consistent with the truth
    tb = {(b["antenna"], b["transmitter"]): b["bias_m"] for b in sim.truth["biases"]}
    slip = sim.truth["slips"][0]
    truth_b = np.array([tb[(sg["antenna"], sg["transmitter"])] for sg in wd.segments])
    later = [i for i, sg in enumerate(wd.segments) if sg["start_s"] > 0]
    assert len(later) == 1 and wd.segments[later[0]]["start_s"] == pytest.approx(1.5)
    assert (wd.segments[later[0]]["antenna"], wd.segments[later[0]]["transmitter"]) == ("a5", "PL6")
    truth_b[later[0]] = slip["bias_m"]
    # 3 s is a short window (float biases good to a few cm): check the errors against P_end
    # (the problem is whitened per channel: biases in units of their channel's σ; prob.solve → metres)
    sm = prob.solve(lp)
    np.testing.assert_allclose(sm.b, s.b * prob.free_sig, rtol=1e-12)
    sig = np.sqrt(np.diag(sm.P_end)[n:])
    assert np.max(np.abs(sm.b - truth_b) / sig) < 5.0


def test_motionless_linearization_falls_back_to_square_root(testbed_cfg):
    """About a motionless trajectory (a cold start's first iterate) a constant rigid-angle offset and
    a bias pattern are indistinguishable: R_end is singular.  The Gram pooling of the bias-only rows
    cannot show that (its condition number is squared); the default solve notices the ill
    conditioning and repeats the solve in square-root form, which flags the rank deficiency."""
    sim = simulate(testbed_cfg, SimOptions(duration_s=3.0, seed=1, phase_sigma_m=0.01))
    run = Run("<memory>", testbed_cfg, sim.receiver.reset_index(drop=True), sim.gyro, None, {})
    wd = window_data(run, 0.0, 3.0)
    prob = _Problem(testbed_cfg, wd, 0.02, True)
    x = prob.propagate(np.zeros(prob.n))
    lp = prob.linear_problem(x, 0.0, x[0], 0.0, prob.initial_biases(x))
    ref = srif_solve(lp, square_root=True)
    assert ref.rank_deficient and ref.P_end is None
    s = srif_solve(lp)
    assert s.rank_deficient
    np.testing.assert_allclose(s.x, ref.x, rtol=0, atol=1e-9 * np.abs(ref.x).max())
    np.testing.assert_allclose(s.b, ref.b, rtol=0, atol=1e-9 * np.abs(ref.b).max())
    try:
        g = srif_solve(lp, square_root=False)
    except np.linalg.LinAlgError:
        return
    assert not g.rank_deficient                      # the Gram form misses it: hence the fallback


# ---------------------------------------------------------------------------------------------
# O(N) structure, no timing


def _count_qr(monkeypatch):
    shapes = {"epoch": [], "other": []}
    orig_r, orig_inplace = batch._qr_r, batch._qr_inplace

    def spy_r(M):
        shapes["other"].append(M.shape)
        return orig_r(M)

    def spy_inplace(M):
        shapes["epoch"].append(M.shape)
        return orig_inplace(M)

    monkeypatch.setattr(batch, "_qr_r", spy_r)
    monkeypatch.setattr(batch, "_qr_inplace", spy_inplace)
    return shapes


@pytest.mark.parametrize("square_root", [False, True])
@pytest.mark.parametrize("C,h_cols", [(5, None), (12, 3)])
def test_linear_structure_qr_count_and_size(monkeypatch, square_root, C, h_cols):
    """One fused time + measurement QR per epoch after the first, of a size independent of N; the
    other QRs (first epoch, final assembly, and in square-root form the compressions of the
    bias-only rows, about one per thousand rows) have a bounded size too.  (The numpy epoch loop,
    whose LAPACK calls can be counted; the compiled loop is its twin, see test_compiled_forward_*.)"""
    sizes = {}
    for N in (20, 200):
        shapes = _count_qr(monkeypatch)
        monkeypatch.setenv("CDGPS_NO_KERNEL", "1")
        rng = np.random.default_rng(9)
        prob = random_problem(rng, n=6, r=2, C=C, N=N, nan_frac=0.0, h_cols=h_cols)
        srif_solve(prob, square_root=square_root)
        monkeypatch.undo()
        assert len(shapes["epoch"]) == N - 1
        assert len(shapes["other"]) <= 3 + (N * C) // 1000
        assert max(a for a, _ in shapes["other"]) <= 1024 + 2 * C + prob.n_bias + 6
        q = C if h_cols is None else h_cols
        assert set(shapes["epoch"]) == {(2 + 6 + q, 2 + 6 + prob.n_bias + 1)}
        sizes[N] = max(a * b for a, b in shapes["epoch"])
    assert sizes[20] == sizes[200]


def test_linear_memory():
    """Peak allocated memory grows linearly with N (the dense Θ form would grow like N²)."""
    peaks = {}
    for N in (500, 2000):
        rng = np.random.default_rng(2)
        prob = random_problem(rng, n=6, r=2, C=5, N=N, nan_frac=0.0, slip=False)
        tracemalloc.start()
        srif_solve(prob)
        peaks[N] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peaks[2000] / peaks[500] < 6.0, peaks


def _with_incidence(prob: LinearProblem, mix: np.ndarray | None = None) -> LinearProblem:
    """The same problem with its bias incidence as a general E (N, C, m); ``mix`` (C, C) mixes the
    rows of every epoch (as whitening by a full noise covariance does)."""
    N, C, _ = prob.H.shape
    E = np.zeros((N, C, prob.n_bias))
    k, c = np.nonzero(prob.bias_index >= 0)
    E[k, c, prob.bias_index[k, c]] = 1.0
    H, y = prob.H, prob.y
    if mix is not None:
        H = np.einsum("ij,kjn->kin", mix, H)
        E = np.einsum("ij,kjm->kim", mix, E)
        y = np.einsum("ij,kj->ki", mix, y)
    return LinearProblem(A=prob.A, Bw_L=prob.Bw_L, H=H, y=y, bias_index=np.full((N, C), -1), n_bias=prob.n_bias,
                         sigma_m=prob.sigma_m, x1_mean=prob.x1_mean, x1_sqrt_info=prob.x1_sqrt_info,
                         b_mean=prob.b_mean, b_sqrt_info=prob.b_sqrt_info, E=E)


@pytest.mark.parametrize("seed,h_cols,square_root", [(0, None, True), (1, 2, True), (2, 2, False), (3, 3, None)])
def test_srif_general_incidence_matches_dense_and_one_hot(seed, h_cols, square_root):
    """Rows with a general bias incidence E (whitened full noise): the SRIF equals the dense Θ
    solve, and with E one-hot (no mixing) equals the bias_index path."""
    rng = np.random.default_rng(100 + seed)
    prob = random_problem(rng, n=4, r=1, C=5, N=14, prior=bool(seed % 2), nan_frac=0.0, h_cols=h_cols)
    one_hot = _with_incidence(prob)
    _assert_agree(srif_solve(one_hot, square_root=square_root), srif_solve(prob, square_root=square_root))
    mix = np.tril(rng.standard_normal((5, 5))) + 3 * np.eye(5)
    mixed = _with_incidence(prob, mix)
    _assert_agree(srif_solve(mixed, square_root=square_root), dense_solve(mixed))


# ---------------------------------------------------------------------------------------------
# several right-hand sides at once (the Hutchinson probes of init's noise estimate)


@pytest.mark.parametrize("square_root", [None, False, True])
@pytest.mark.parametrize("h_cols,prior,full", [(None, False, False), (2, True, False), (3, False, False),
                                               (None, True, True), (2, False, True)])
def test_several_right_hand_sides_equal_separate_solves(square_root, h_cols, prior, full):
    rng = np.random.default_rng(77 + (h_cols or 0) + 10 * prior + 100 * full)
    prob = random_problem(rng, n=5, r=2, C=6, N=25, prior=prior, h_cols=h_cols)
    if full:                                        # a general bias incidence (whitened full noise)
        E = np.zeros(prob.H.shape[:2] + (prob.n_bias,))
        k, c = np.nonzero(prob.bias_index >= 0)
        E[k, c, prob.bias_index[k, c]] = 1.0
        E += 0.1 * rng.standard_normal(E.shape) * (prob.bias_index >= 0)[..., None]
        prob = LinearProblem(**{**prob.__dict__, "E": E})
    K = 4
    present = np.isfinite(prob.y)
    Y = np.where(present[..., None], rng.standard_normal(prob.y.shape + (K,)), np.nan)
    X1 = rng.standard_normal((prob.A.shape[0], K)) if prior else np.zeros((prob.A.shape[0], K))
    B = rng.standard_normal((prob.n_bias, K)) if prior else np.zeros((prob.n_bias, K))
    many = srif_solve(LinearProblem(**{**prob.__dict__, "y": Y, "x1_mean": X1, "b_mean": B}), square_root=square_root)
    assert many.x.shape == prob.H.shape[:1] + (prob.A.shape[0], K) and many.b.shape == (prob.n_bias, K)
    assert np.isnan(many.cost)
    for j in range(K):
        one = srif_solve(LinearProblem(**{**prob.__dict__, "y": Y[:, :, j], "x1_mean": X1[:, j], "b_mean": B[:, j]}),
                         square_root=square_root)
        np.testing.assert_allclose(many.x[:, :, j], one.x, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(many.b[:, j], one.b, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(many.w[:, :, j], one.w, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(many.R_end, one.R_end, rtol=1e-12, atol=1e-12)
        # and one against the dense reference (Eq. 13–15)
        if j == 0 and not full:
            _assert_agree(one, dense_solve(LinearProblem(**{**prob.__dict__, "y": Y[:, :, j], "x1_mean": X1[:, j],
                                                            "b_mean": B[:, j]})))


# ---------------------------------------------------------------------------------------------
# the compiled epoch loop (kernel.srif_forward) against its numpy twin (_forward_numpy)

needs_kernel = pytest.mark.skipif(not compiled.available(), reason="compiled kernel not built or disabled")


def _forward_both(prob: LinearProblem, monkeypatch, square_root: bool):
    """_forward's outputs (state rows, ω rows, pooled bias-only information) by the kernel and by numpy."""
    n, r, m = prob.A.shape[0], prob.Bw_L.shape[1], prob.n_bias
    K = 1 if prob.y.ndim == 2 else prob.y.shape[2]
    Ainv = np.linalg.inv(prob.A)
    AG = np.hstack([-(Ainv @ prob.Bw_L), Ainv])
    out = []
    for no_kernel in ("0", "1"):
        monkeypatch.setenv("CDGPS_NO_KERNEL", no_kernel)
        pool = batch._BiasRows(m, square_root, K)
        X, smooth = batch._forward(prob, AG, pool)
        S = pool.sqrt()
        out.append((X, smooth, S.T @ S))           # S is defined up to an orthogonal factor: compare SᵀS
    monkeypatch.delenv("CDGPS_NO_KERNEL")
    return out


def _random_twin_case(seed: int):
    rng = np.random.default_rng(500 + seed)
    n, r, C, N = [(4, 0, 3, 9), (5, 2, 5, 30), (6, 2, 12, 40), (4, 1, 7, 2), (6, 3, 4, 25), (5, 2, 9, 33)][seed]
    prob = random_problem(rng, n=n, r=r, C=C, N=N, prior=bool(seed % 2), h_cols=3 if C > 6 else None)
    if seed == 4:                                   # several right-hand sides
        Y = np.where(np.isfinite(prob.y)[..., None], rng.standard_normal(prob.y.shape + (3,)), np.nan)
        prob = LinearProblem(**{**prob.__dict__, "y": Y, "x1_mean": np.zeros((n, 3)), "b_mean": np.zeros((prob.n_bias, 3))})
    if seed == 5:                                   # a general bias incidence (whitened full noise)
        prob = _with_incidence(prob, np.tril(rng.standard_normal((C, C))) + 3 * np.eye(C))
    return prob


@needs_kernel
@pytest.mark.parametrize("square_root", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_compiled_forward_equals_numpy_twin(monkeypatch, seed, square_root):
    """The compiled epoch loop writes the same state rows and ω rows as the numpy loop (LAPACK dgeqrf,
    same Householder sign convention) and leaves the same bias-only information, to 1e-12."""
    prob = _random_twin_case(seed)
    (Xc, sc, Ic), (Xn, sn, In) = _forward_both(prob, monkeypatch, square_root)
    r = prob.Bw_L.shape[1]
    np.testing.assert_allclose(Xc, np.triu(Xn, r), rtol=0, atol=1e-12 * np.abs(Xn).max())
    np.testing.assert_allclose(sc, np.triu(sn), rtol=0, atol=1e-12 * max(np.abs(sn).max(initial=0.0), 1.0))
    np.testing.assert_allclose(Ic, In, rtol=0, atol=1e-12 * np.abs(In).max())


@needs_kernel
@pytest.mark.parametrize("seed", range(6))
def test_compiled_srif_solution_equals_numpy(monkeypatch, seed):
    """Whole solves (trajectory, process noise, biases, cost, information at the end) agree to 1e-12."""
    prob = _random_twin_case(seed)
    sols = []
    for no_kernel in ("0", "1"):
        monkeypatch.setenv("CDGPS_NO_KERNEL", no_kernel)
        sols.append(srif_solve(prob))
    c, d = sols
    for a, b in ((c.x, d.x), (c.w, d.w), (c.b, d.b), (c.R_end, d.R_end)):
        assert _rel(a, b) < 1e-12, _rel(a, b)
    assert np.isnan(c.cost) and np.isnan(d.cost) or abs(c.cost - d.cost) <= 1e-12 * abs(d.cost)


@needs_kernel
def test_compiled_forward_on_testbed_linearization(monkeypatch, testbed_lin):
    """The init's case (18 states, 9 noise inputs, 36 channels reduced to 9 rows, 36 biases)."""
    lp = testbed_lin[0]
    (Xc, sc, Ic), (Xn, sn, In) = _forward_both(lp, monkeypatch, False)
    r = lp.Bw_L.shape[1]
    assert _rel(Xc, np.triu(Xn, r)) < 1e-12 and _rel(sc, np.triu(sn)) < 1e-12 and _rel(Ic, In) < 1e-12


@needs_kernel
@pytest.mark.parametrize("square_root", [False, True])
@pytest.mark.parametrize("case", ["identity", "shared_known_absent", "slip_k3"])
def test_compiled_row_split_equals_numpy_twin(monkeypatch, case, square_root):
    """The per-epoch QR split of the measurement rows (kernel.reduce_rows vs _split_rows_numpy, LAPACK):
    the filter's rows and the pooled bias-only information to 1e-12, for one bias per channel (Qᵀ E a
    column permutation in numpy), shared / known biases with absent rows (a general incidence, handled
    row by row), and a slip with three right-hand sides."""
    rng = np.random.default_rng({"identity": 1, "shared_known_absent": 2, "slip_k3": 3}[case])
    kw = {"identity": dict(known=False, shared=False, slip=False, nan_frac=0.0),
          "shared_known_absent": dict(slip=False, nan_frac=0.2), "slip_k3": dict(nan_frac=0.05)}[case]
    prob = random_problem(rng, n=6, r=2, C=11, N=40, h_cols=4, **kw)
    K = 3 if case == "slip_k3" else 1
    if K > 1:
        Y = np.where(np.isfinite(prob.y)[..., None], rng.standard_normal(prob.y.shape + (K,)), np.nan)
        prob = LinearProblem(**{**prob.__dict__, "y": Y})
    out = []
    for no_kernel in ("0", "1"):
        monkeypatch.setenv("CDGPS_NO_KERNEL", no_kernel)
        pool = batch._BiasRows(prob.n_bias, square_root, K)
        meas = batch._measurement_rows(prob, 2, pool)
        S = pool.sqrt()
        out.append((meas, S.T @ S))
    (mc, Ic), (mn, In) = out
    assert mc.shape == mn.shape == (40, 4, 2 + 6 + prob.n_bias + K)
    np.testing.assert_allclose(mc, mn, rtol=0, atol=1e-12 * np.abs(mn).max())
    np.testing.assert_allclose(Ic, In, rtol=0, atol=1e-12 * np.abs(In).max())


@needs_kernel
@pytest.mark.parametrize("r,K", [(2, 1), (3, 4), (0, 1)])
def test_compiled_smoother_equals_numpy_twin(r, K):
    """The smoother's backward pass (kernel.srif_smooth vs _smooth_numpy) on random ω rows: x and ω to 1e-12."""
    rng = np.random.default_rng(40 + r + K)
    N, n, m = 30, 5, 4
    ncol = r + n + m + K
    smooth = rng.standard_normal((N - 1, r, ncol))
    smooth[:, :, :r] = np.triu(smooth[:, :, :r]) + 3 * np.eye(r)      # R_w: the unit prior keeps it regular
    S = rng.standard_normal((n, n))
    Ainv = expm(0.2 * (S - S.T))
    AG = np.hstack([-(Ainv @ rng.standard_normal((n, r))), Ainv])
    z = rng.standard_normal((n + m, K)) if K > 1 else rng.standard_normal(n + m)
    xc, wc = compiled.srif_smooth(smooth, AG, z, N, m)
    xn, wn = batch._smooth_numpy(smooth, AG, Ainv, z, n, m, r)
    assert xc.shape == xn.shape and wc.shape == wn.shape
    np.testing.assert_allclose(xc, xn, rtol=0, atol=1e-12 * np.abs(xn).max())
    if r:
        np.testing.assert_allclose(wc, wn, rtol=0, atol=1e-12 * np.abs(wn).max())
