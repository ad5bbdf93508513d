"""The engine's step (estimation/kalman.py): the iterated update is the Gauss–Newton minimizer of
the one-epoch MAP cost, checked against scipy's least squares on a nonlinear model; predict/update
compose as the textbook Kalman filter; both noise kinds give the same step for the same R."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from cdgps_cli.estimation.kalman import StepFilter, iterated_update, update
from cdgps_cli.measurement.model import MeasurementModel, Rows


class _Ranges(MeasurementModel):
    """Ranges from a 2-D point x to fixed anchors: h_i = |x − a_i|, nonlinear."""

    def __init__(self, anchors):
        self.a = np.asarray(anchors, float)
        self.n_state = 2

    def predict(self, x, rows):
        d = x[None, :] - self.a
        r = np.linalg.norm(d, axis=1)
        return r, d / r[:, None]


def _rows(z, sigma=None, chol=None):
    return Rows(np.asarray(z, float), [], np.full(len(z), -1), sigma_m=sigma, chol_m=chol)


def test_iterated_update_is_the_map_estimate():
    model = _Ranges([[0.0, 0.0], [10.0, 0.0], [0.0, 7.0]])
    truth = np.array([3.0, 4.0])
    xbar, Pbar = np.array([4.5, 2.0]), np.diag([4.0, 9.0])
    sigma = np.array([0.05, 0.1, 0.08])
    z = model.predict(truth, None)[0] + np.array([0.03, -0.05, 0.02])
    x, P, nis = iterated_update(model, _rows(z, sigma), xbar, Pbar, max_iterations=20)
    Li = np.linalg.cholesky(np.linalg.inv(Pbar)).T          # ‖x − x̄‖² in P̄⁻¹ as a residual block
    ref = least_squares(lambda v: np.r_[Li @ (v - xbar), (z - model.predict(v, None)[0]) / sigma], xbar,
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    # the iteration stops at a step ≤ 1e-9·max(1, |x|) (≈ 5e-9 here); Gauss–Newton with non-zero residuals
    # converges linearly, so the distance left is of that order
    np.testing.assert_allclose(x, ref.x, rtol=0, atol=1e-8)
    assert np.max(np.abs(x - xbar)) > 1.0                   # the update moved far: a real nonlinear solve
    _, H = model.predict(x, None)                           # P⁺ = (P̄⁻¹ + HᵀR⁻¹H)⁻¹ at the solution
    np.testing.assert_allclose(P, np.linalg.inv(np.linalg.inv(Pbar) + H.T @ (H / sigma[:, None]**2)), rtol=1e-8)
    h0, H0 = model.predict(xbar, None)                      # NIS at the prior linearization
    S = H0 @ Pbar @ H0.T + np.diag(sigma**2)
    assert nis == pytest.approx((z - h0) @ np.linalg.solve(S, z - h0), rel=1e-10)


class _CountingRanges(_Ranges):
    """:class:`_Ranges` that counts its linearizations and says a step shorter than ``linear_m`` is linear enough."""

    def __init__(self, anchors, linear_m):
        super().__init__(anchors)
        self.calls, self.linear_m = 0, linear_m

    def predict(self, x, rows):
        self.calls += 1
        return super().predict(x, rows)

    def linear_within(self, dx):
        return float(np.linalg.norm(dx)) <= self.linear_m


@pytest.mark.parametrize("form", ["information", "covariance"])
def test_a_model_that_calls_its_step_linear_stops_the_iteration(form):
    """A model's ``linear_within`` ends the Gauss–Newton loop after a step it calls linear (a 1 cm step: one
    linearization, the extended Kalman update's numbers exactly); longer steps are relinearized as before (to the
    MAP estimate)."""
    anchors = [[0.0, 0.0], [10.0, 0.0], [0.0, 7.0]]
    truth, sigma = np.array([3.0, 4.0]), np.array([0.05, 0.1, 0.08])
    z = _Ranges(anchors).predict(truth, None)[0] + np.array([0.03, -0.05, 0.02])
    for xbar, linear_m, calls in ((np.array([3.01, 3.99]), 0.1, 1), (np.array([4.5, 2.0]), 1e-4, None)):
        Pbar = np.diag([4.0, 9.0])
        said = _CountingRanges(anchors, linear_m)
        x = StepFilter(xbar, Pbar, form=form)
        x.update(said, _rows(z, sigma), max_iterations=20)
        ekf = StepFilter(xbar, Pbar, form=form)
        ekf.update(_Ranges(anchors), _rows(z, sigma), max_iterations=1)
        full = StepFilter(xbar, Pbar, form=form)
        full.update(_Ranges(anchors), _rows(z, sigma), max_iterations=20)
        if calls == 1:                                   # a 1 cm step: stopped at once, the EKF's numbers
            assert said.calls == 1
            np.testing.assert_array_equal(x.x, ekf.x)
            np.testing.assert_array_equal(x.P, ekf.P)
        else:                                # a 2.5 m step: relinearized until a step is under 0.1 mm (the MAP)
            assert said.calls > 2
            np.testing.assert_allclose(x.x, full.x, rtol=0, atol=1e-6)


def test_steps_compose_as_the_textbook_filter_for_both_noise_kinds():
    g = np.random.default_rng(5)
    n, p = 4, 6
    A = np.eye(n) + 0.1 * g.normal(size=(n, n))
    Q = 0.01 * np.eye(n)
    H = g.normal(size=(p, n))
    M = g.normal(size=(p, p))
    R = M @ M.T + 0.5 * np.eye(p)
    L = np.linalg.cholesky(R)
    x, P = g.normal(size=n), np.eye(n)
    step = StepFilter(x, P)
    for _ in range(10):
        u = g.normal(size=n)
        step.predict(A, Q, u)
        x, P = A @ x + u, A @ P @ A.T + Q
        z = H @ g.normal(size=n) + L @ g.normal(size=p)
        xs, Ps = step.x.copy(), step.P.copy()
        nis = step.update(_Linear(H), _rows(z, chol=L), max_iterations=3)
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        v = z - H @ x
        x, P = x + K @ v, (np.eye(n) - K @ H) @ P
        np.testing.assert_allclose(step.x, x, rtol=0, atol=1e-10)
        np.testing.assert_allclose(step.P, P, rtol=0, atol=1e-10)
        assert nis == pytest.approx(v @ np.linalg.solve(S, v), rel=1e-9)
        x1, P1, nis1 = update(xs, Ps, z - H @ xs, H, noise_chol=L)   # rows linearized at x̄
        np.testing.assert_allclose(x1, step.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(P1, step.P, rtol=0, atol=1e-12)
        assert nis1 == pytest.approx(nis, rel=1e-12)


class _Linear(MeasurementModel):
    def __init__(self, H):
        self.H = H
        self.n_state = H.shape[1]

    def predict(self, x, rows):
        return self.H @ x, self.H


def test_identity_transition_skips_a_p_at_with_the_same_numbers():
    """A random walk's A is the identity: the filter's predict without A P Aᵀ gives the same bytes
    (filter_numpy on a random-walk displacement, the dynamics flag on and off)."""
    import numpy as np

    from cdgps_cli.estimation.kalman import StepFilter
    from cdgps_cli.estimation.model_filter import filter_numpy
    from cdgps_cli.model.dynamics_models import ModalZOH, RandomWalk, Static, WithConstants

    rng = np.random.default_rng(5)
    P = rng.normal(size=(4, 4))
    P = P @ P.T
    Q = np.diag(rng.random(4))
    a, b = StepFilter(rng.normal(size=4), P), None
    b = StepFilter(a.x.copy(), P.copy())
    a.predict(None, Q)
    b.predict(np.eye(4), Q)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)
    assert RandomWalk(3, 0.01).identity_transition and Static(2).identity_transition
    assert WithConstants(RandomWalk(3, 0.01), 4).identity_transition

    class Linear:                                   # z = x + noise on 3 coordinates
        def __init__(self, z):
            self.z = z

        def rows(self, k):
            from cdgps_cli.measurement.model import Rows
            return Rows(self.z[k], ["e", "n", "u"], np.full(3, -1), sigma_m=np.full(3, 0.01))

        def predict(self, x, rows):
            return x.copy(), np.eye(3)

    z = rng.normal(size=(50, 3)) * 0.01
    t = np.arange(50.0)
    dyn = RandomWalk(3, 0.001)
    on = filter_numpy(Linear(z), dyn, t, np.zeros(3), np.eye(3))
    dyn.identity_transition = False
    off = filter_numpy(Linear(z), dyn, t, np.zeros(3), np.eye(3))
    assert np.array_equal(on["x"], off["x"]) and np.array_equal(on["P"], off["P"])
    assert not ModalZOH.identity_transition


def test_numpy_inverse_linalg_gives_the_lapack_update():
    """`NUMPY_INVERSE` (the numpy-only linear algebra `cdgps rtk` steps with, to keep scipy off its
    start-up) gives the default LAPACK-Cholesky update to rounding: state, covariance and NIS."""
    from cdgps_cli.estimation.kalman import NUMPY_INVERSE

    model = _Ranges([[0.0, 0.0], [10.0, 0.0], [0.0, 7.0]])
    xbar, Pbar = np.array([4.5, 2.0]), np.array([[4.0, 0.5], [0.5, 9.0]])
    sigma = np.array([0.05, 0.1, 0.08])
    z = model.predict(np.array([3.0, 4.0]), None)[0] + np.array([0.03, -0.05, 0.02])
    for it in (1, 2, 20):
        ref = iterated_update(model, _rows(z, sigma), xbar, Pbar, it)
        got = iterated_update(model, _rows(z, sigma), xbar, Pbar, it, NUMPY_INVERSE)
        np.testing.assert_allclose(got[0], ref[0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got[1], ref[1], rtol=1e-10, atol=1e-15)
        assert got[2] == pytest.approx(ref[2], rel=1e-10)
    step = StepFilter(xbar, Pbar, NUMPY_INVERSE)
    step.update(model, _rows(z, sigma), 20)
    np.testing.assert_allclose(step.x, iterated_update(model, _rows(z, sigma), xbar, Pbar, 20)[0], rtol=1e-12)


class _Linear(MeasurementModel):
    """h = H x (plus a small quadratic term when ``curv``: the iteration relinearizes)."""

    def __init__(self, H, curv=0.0):
        self.H, self.curv, self.n_state = H, curv, H.shape[1]

    def predict(self, x, rows):
        return self.H @ x + self.curv * (self.H @ x) ** 2, self.H * (1.0 + 2.0 * self.curv * (self.H @ x))[:, None]


@pytest.mark.parametrize("seed", range(6))
def test_covariance_form_equals_the_information_form(seed):
    from cdgps_cli.estimation.kalman import iterated_update_covariance
    g = np.random.default_rng(100 + seed)
    n, m = 30 + seed, 4 + seed
    M = g.normal(size=(n, n))
    Pbar = M @ M.T / n + np.diag(np.r_[np.full(3, 1e-2), np.full(n - 3, 1.0)])
    xbar = g.normal(size=n)
    model = _Linear(g.normal(size=(m, n)), curv=0.01 * (seed % 2))
    C = g.normal(size=(m, m))
    rows = _rows(g.normal(size=m), chol=np.linalg.cholesky(C @ C.T + np.eye(m))) if seed % 3 == 0 \
        else _rows(g.normal(size=m), sigma=g.uniform(0.5, 2.0, m))
    for its in (1, 2, 5):
        x1, P1, nis1 = iterated_update(model, rows, xbar, Pbar, its)
        x2, P2, nis2 = iterated_update_covariance(model, rows, xbar, Pbar, its)
        scale = np.max(np.abs(P1))
        assert np.max(np.abs(P2 - P1)) <= 1e-12 * scale * n
        assert np.max(np.abs(x2 - x1)) <= 1e-12 * max(1.0, np.max(np.abs(x1))) * n
        assert nis2 == pytest.approx(nis1, rel=1e-11)
    step = StepFilter(xbar, Pbar, form="covariance")        # the StepFilter option selects it
    step.update(model, rows, 2)
    np.testing.assert_allclose(step.x, iterated_update(model, rows, xbar, Pbar, 2)[0], rtol=1e-11, atol=1e-12)
    with pytest.raises(ValueError, match="form"):
        StepFilter(xbar, Pbar, form="joseph")


@pytest.mark.parametrize("seed", range(6))
def test_covariance_form_fast_path_equals_the_dense_update(seed, monkeypatch):
    """The covariance form's fast path (H's non-zero columns only, P⁺ = P̄ − Vᵀ V) gives the dense
    covariance-form update (``sparse=False``) to 1e-12 on random cases whose H has zero columns (as the
    static engine's: position + the epoch's arcs of ≈ 90 states), for 1, 2 and 5 iterations, with a diagonal
    and a full noise; P⁺ exactly symmetric.  The fast path must have been taken (counted), and H without a
    zero column takes the dense form (bit for bit)."""
    from cdgps_cli.estimation import kalman
    taken = []
    real = kalman._tri_solve_upper_t
    monkeypatch.setattr(kalman, "_tri_solve_upper_t", lambda c, b: taken.append(1) or real(c, b))
    g = np.random.default_rng(200 + seed)
    n, m = 40 + 10 * seed, 6 + 2 * seed
    M = g.normal(size=(n, n))
    Pbar = M @ M.T / n + np.diag(np.r_[np.full(3, 1e-2), np.full(n - 3, 1.0)])
    Pbar = 0.5 * (Pbar + Pbar.T)
    xbar = g.normal(size=n)
    H = np.zeros((m, n))
    act = np.r_[0, 1, 2, 3 + np.sort(g.choice(n - 3, 5 + seed, replace=False))]
    H[:, act] = g.normal(size=(m, act.size))
    model = _Linear(H, curv=0.01 * (seed % 2))
    C = g.normal(size=(m, m))
    rows = _rows(g.normal(size=m), chol=np.linalg.cholesky(C @ C.T + np.eye(m))) if seed % 2 == 0 \
        else _rows(g.normal(size=m), sigma=g.uniform(0.5, 2.0, m))
    for its in (1, 2, 5):
        x1, P1, nis1 = kalman.iterated_update_covariance(model, rows, xbar, Pbar, its, sparse=False)
        n_taken = len(taken)
        x2, P2, nis2 = kalman.iterated_update_covariance(model, rows, xbar, Pbar, its, sparse=True)
        assert len(taken) > n_taken                          # the fast path ran
        assert np.max(np.abs(P2 - P1)) <= 1e-12 * np.max(np.abs(P1))
        assert np.max(np.abs(x2 - x1)) <= 1e-12 * max(1.0, np.max(np.abs(x1)))
        assert nis2 == pytest.approx(nis1, rel=1e-12)
        assert np.array_equal(P2, P2.T)
    full = _Linear(g.normal(size=(m, n)))                    # no zero column: the dense form itself
    n_taken = len(taken)
    dense = kalman.iterated_update_covariance(full, rows, xbar, Pbar, 2, sparse=False)
    got = kalman.iterated_update_covariance(full, rows, xbar, Pbar, 2, sparse=True)
    assert len(taken) == n_taken
    assert np.array_equal(got[0], dense[0]) and np.array_equal(got[1], dense[1]) and got[2] == dense[2]


def test_fast_path_would_fail_on_a_wrong_update(monkeypatch):
    """The check above can fail: a fast path that drops the rank-m correction's last row is caught."""
    from cdgps_cli.estimation import kalman
    real = kalman._tri_solve_upper_t
    monkeypatch.setattr(kalman, "_tri_solve_upper_t", lambda c, b: real(c, b)[:-1])
    g = np.random.default_rng(7)
    n, m = 30, 5
    Pbar = np.eye(n) * 2.0
    H = np.zeros((m, n))
    H[:, :8] = g.normal(size=(m, 8))
    rows = _rows(g.normal(size=m), sigma=np.ones(m))
    P1 = kalman.iterated_update_covariance(_Linear(H), rows, np.zeros(n), Pbar, 1, sparse=False)[1]
    P2 = kalman.iterated_update_covariance(_Linear(H), rows, np.zeros(n), Pbar, 1, sparse=True)[1]
    assert np.max(np.abs(P2 - P1)) > 1e-6
