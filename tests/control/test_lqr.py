"""LQR design: closed forms, python-control's dlqr, Riccati residuals, cost by simulation, refusals."""

import math

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.control.design import PAPER_WEIGHTS, design_for_structure, weights_for
from cdgps_cli.control.lqr import check_weights, design_lqr, paper_weights
from cdgps_cli.control.poles import pole_table
from cdgps_cli.core.errors import CdgpsError


@pytest.fixture(scope="module")
def testbed(repo_root):
    return load_config(repo_root / "configs" / "testbed-1998-lumped.toml")


@pytest.mark.parametrize("a,b,q,r", [(1.0, 1.0, 1.0, 1.0), (1.2, 0.5, 3.0, 0.1), (0.9, 2.0, 0.01, 5.0),
                                     (-1.5, 1.0, 2.0, 1.0)])
def test_scalar_riccati_closed_form(a, b, q, r):
    """Scalar DARE: b² p² + (r(1 − a²) − q b²) p − q r = 0, positive root; k = a b p / (r + b² p)."""
    c1 = r * (1 - a * a) - q * b * b
    p = (-c1 + math.sqrt(c1 * c1 + 4 * b * b * q * r)) / (2 * b * b)
    d = design_lqr([[a]], [[b]], [[q]], [[r]], 0.1)
    assert d.P[0, 0] == pytest.approx(p, rel=1e-12)
    assert d.K[0, 0] == pytest.approx(a * b * p / (r + b * b * p), rel=1e-12)
    assert abs(a - b * d.K[0, 0]) < 1


def test_paper_weights_shape_and_values(testbed):
    Qx, Qu = paper_weights(testbed.mode_frequency_hz, len(testbed.thruster_names))
    star = np.array([5000.0] * 8 + [50.0])          # rigid-body mode last in the testbed config
    np.testing.assert_array_equal(np.diag(Qx), np.concatenate([star, 0.01 * star]))
    np.testing.assert_array_equal(Qu, np.eye(24))


def test_testbed_gain_matches_python_control(testbed):
    control = pytest.importorskip("control")
    d, _ = design_for_structure(testbed)
    K, S, E = control.dlqr(d.A, d.B, d.Qx, d.Qu)
    np.testing.assert_allclose(d.K, K, rtol=0, atol=1e-10 * np.abs(K).max())
    np.testing.assert_allclose(d.P, S, rtol=0, atol=1e-10 * np.abs(S).max())
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(d.closed_loop)), np.sort_complex(E), atol=1e-9)


def _random_stabilizable(seed, n, m):
    g = np.random.default_rng(seed)
    A = g.normal(size=(n, n)) * 0.6
    B = g.normal(size=(n, m))
    C = g.normal(size=(n, n))
    return A, B, C @ C.T + np.eye(n) * 1e-3, np.eye(m) * (0.5 + seed)


@pytest.mark.parametrize("case", ["double_integrator", "unstable_oscillator", "random_1", "random_2"])
def test_riccati_residual_and_cost_by_simulation(case):
    """Residual of the DARE is at round-off, and the simulated cost from x0 equals x0ᵀ P x0."""
    T = 0.1
    if case == "double_integrator":
        A, B, Q, R = np.array([[1, T], [0, 1]]), np.array([[T * T / 2], [T]]), np.eye(2), np.eye(1)
    elif case == "unstable_oscillator":
        w = 2 * np.pi
        A = np.array([[math.cos(w * T), math.sin(w * T)], [-math.sin(w * T), math.cos(w * T)]]) * 1.05
        B, Q, R = np.array([[0.0], [T]]), np.diag([1.0, 0.0]), np.eye(1) * 0.01
    else:
        A, B, Q, R = _random_stabilizable(int(case[-1]), 5, 2)
    d = design_lqr(A, B, Q, R, T)
    assert d.riccati_residual < 1e-10
    x0 = np.linspace(1.0, -1.0, A.shape[0])
    cost = _simulated_cost(A, B, Q, R, d.K, x0)
    assert cost == pytest.approx(x0 @ d.P @ x0, rel=1e-9)
    assert _simulated_cost(A, B, Q, R, d.K * 1.05, x0) > cost      # any other gain costs more
    assert _simulated_cost(A, B, Q, R, d.K * 0.95, x0) > cost


def _simulated_cost(A, B, Q, R, K, x0):
    """Σ xᵀQx + uᵀRu under u = −K x, summed until the state has decayed to round-off."""
    x, cost = x0.copy(), 0.0
    for _ in range(50000):
        u = -K @ x
        cost += x @ Q @ x + u @ R @ u
        x = A @ x + B @ u
        if x @ x < 1e-30:
            return cost
    raise AssertionError("closed loop did not decay")


def test_closed_loop_is_stable_and_rigid_body_settles_in_tens_of_seconds(testbed):
    d, poles = design_for_structure(testbed, **PAPER_WEIGHTS)
    assert np.abs(np.linalg.eigvals(d.closed_loop)).max() < 1
    settle = poles["settling_time_s"]
    assert settle["open_loop"]["rigid-body"] is None            # the open-loop angle does not decay
    assert 15 < settle["closed_loop"]["rigid-body"] < 60       # paper: about 30 s
    for mode, t in settle["closed_loop"].items():
        assert settle["open_loop"][mode] is None or t <= settle["open_loop"][mode] + 1e-6


def test_zero_weight_on_rigid_body_is_refused_by_name(testbed):
    n = 2 * testbed.n_modes
    q = np.full(n, 5000.0)
    q[testbed.n_modes - 1] = 0.0        # rigid-body angle
    q[n - 1] = 0.0                      # rigid-body rate
    with pytest.raises(CdgpsError, match=r"rigid-body.*undetectable"):
        design_for_structure(testbed, qx=q)


def test_uncontrollable_unstable_mode_is_refused():
    A = np.diag([1.1, 0.5])
    B = np.array([[0.0], [1.0]])
    with pytest.raises(CdgpsError, match="thrusters cannot move"):
        design_lqr(A, B, np.eye(2), np.eye(1), 0.1, ["a", "b"])


@pytest.mark.parametrize("Qx,Qu,words", [
    (np.diag([1.0, np.nan]), np.eye(1), "Qx: every entry must be a finite"),
    (np.diag([1.0, -1.0]), np.eye(1), "Qx: must be positive semi-definite"),
    (np.eye(3), np.eye(1), r"Qx: expected shape \(2, 2\)"),
    (np.eye(2), np.zeros((1, 1)), "Qu: must be positive definite"),
    (np.array([[1.0, 2.0], [0.0, 1.0]]), np.eye(1), "Qx: must be symmetric"),
])
def test_bad_weights_are_named(Qx, Qu, words):
    with pytest.raises(CdgpsError, match=words):
        check_weights(Qx, Qu, 2, 1)


def test_weight_options_are_checked(testbed):
    with pytest.raises(CdgpsError, match="qx: expected one number or 18"):
        weights_for(testbed, qx=[1.0, 2.0])
    with pytest.raises(CdgpsError, match="qu: expected one number or 24"):
        weights_for(testbed, qu=[1.0, 2.0])
    Qx, Qu = weights_for(testbed, qx=100.0, qu=2.0, rigid_factor=0.01)
    assert Qx[0, 0] == 100.0 and Qx[8, 8] == 1.0 and Qu[3, 3] == 2.0


def test_pole_table_recovers_a_known_continuous_pole():
    zeta, f, T = 0.05, 0.2, 0.1
    wn = 2 * np.pi * f
    s = complex(-zeta * wn, wn * math.sqrt(1 - zeta**2))
    Ac = np.array([[0.0, 1.0], [-wn * wn, -2 * zeta * wn]])
    from scipy.linalg import expm

    rows = pole_table(expm(Ac * T), T, ["m"])
    assert len(rows) == 1
    r = rows[0]
    assert r["frequency_hz"] == pytest.approx(f, rel=1e-10)
    assert r["damping_ratio"] == pytest.approx(zeta, rel=1e-10)
    assert r["settling_time_s"] == pytest.approx(math.log(50) / (zeta * wn), rel=1e-10)
    assert complex(r["z_re"], r["z_im"]) == pytest.approx(np.exp(s * T), abs=1e-12)


def test_darex_example_1_published_solution():
    """Benner, Laub & Mehrmann (1995), 'A collection of benchmark examples for the numerical solution of
    algebraic Riccati equations II: discrete-time case', Example 1: X = (1 + √5)/2 · Q."""
    A = np.array([[4.0, 3.0], [-4.5, -3.5]])
    B = np.array([[1.0], [-1.0]])
    Q = np.array([[9.0, 6.0], [6.0, 4.0]])
    d = design_lqr(A, B, Q, np.eye(1), 1.0)
    np.testing.assert_allclose(d.P, (1 + math.sqrt(5)) / 2 * Q, rtol=1e-12)
    assert d.riccati_residual < 1e-13
