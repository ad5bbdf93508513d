"""Tests for cdgps_cli.model.dynamics: continuous model, ZOH discretization, Table 1 modes, noise."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad_vec
from scipy.linalg import expm

from cdgps_cli.config.structure import parse_config
from cdgps_cli.model.dynamics import continuous_model, discrete_model, modal_damping, zoh

# Table 1 of Teague, How & Parkinson (1998): frequency (Hz), time constant (s)
TABLE1 = {"pendulum": (0.059, 20.0), "swing": (0.160, 130.0), "bending-1": (0.132, 200.0),
          "twist-1": (0.085, 45.0), "twist-2": (0.138, 35.0), "bending-2": (0.135, 140.0),
          "bending-3": (0.23, 50.0), "bending-4": (0.28, 25.0)}
RIGID_TAU = 140.0


def _expected_Ac(cfg) -> np.ndarray:
    """A_c = [[0, I], [−diag(ω²), −diag(c)]] built from the config values (c = 2/τ, rigid 1/τ)."""
    nm = cfg.n_modes
    f = np.asarray(cfg.mode_frequency_hz)
    tau = np.asarray(cfg.mode_time_constant_s)
    c = np.where(f == 0, 1.0 / tau, 2.0 / tau)
    Ac = np.zeros((2 * nm, 2 * nm))
    Ac[:nm, nm:] = np.eye(nm)
    Ac[nm:, :nm] = -np.diag((2 * np.pi * f) ** 2)
    Ac[nm:, nm:] = -np.diag(c)
    return Ac


def _zoh_integral_quad(Ac, T) -> np.ndarray:
    """∫₀ᵀ e^{A_c s} ds by adaptive quadrature (independent of the block-exponential trick)."""
    val, err = quad_vec(lambda s: expm(Ac * s), 0.0, T, epsabs=1e-13, epsrel=1e-12)
    return val


def _match_eigenvalues(actual: np.ndarray, expected: np.ndarray, tol: float) -> None:
    actual = list(actual)
    assert len(actual) == len(expected)
    for e in expected:
        d = [abs(a - e) for a in actual]
        i = int(np.argmin(d))
        assert d[i] < tol, f"eigenvalue {e} not found (closest {actual[i]})"
        actual.pop(i)


@pytest.mark.parametrize("which", ["testbed", "dof2"])
def test_continuous_model_structure(which, testbed_cfg, dof2_cfg):
    cfg = testbed_cfg if which == "testbed" else dof2_cfg
    Ac, Bc, Bwc = continuous_model(cfg)
    np.testing.assert_allclose(Ac, _expected_Ac(cfg), rtol=1e-14, atol=0)
    nm = cfg.n_modes
    assert Bc.shape == (2 * nm, len(cfg.thruster_names))
    np.testing.assert_array_equal(Bc[:nm], 0.0)
    np.testing.assert_array_equal(Bwc[:nm], 0.0)


def test_modal_damping_values(testbed_cfg):
    c = modal_damping(testbed_cfg)
    for name, cc in zip(testbed_cfg.mode_names, c):
        if name == "rigid-body":
            assert cc == pytest.approx(1.0 / RIGID_TAU)
        else:
            assert cc == pytest.approx(2.0 / TABLE1[name][1])


@pytest.mark.parametrize("which", ["testbed", "dof2"])
def test_zoh_matches_matrix_exponential(which, testbed_cfg, dof2_cfg):
    cfg = testbed_cfg if which == "testbed" else dof2_cfg
    T = cfg.sample_period_s
    m = discrete_model(cfg)
    assert m.T == pytest.approx(T)
    Ac, Bc, Bwc = continuous_model(cfg)
    np.testing.assert_allclose(m.A, expm(_expected_Ac(cfg) * T), rtol=0, atol=1e-12)
    integral = _zoh_integral_quad(Ac, T)
    np.testing.assert_allclose(m.B, integral @ Bc, rtol=0, atol=1e-11)
    np.testing.assert_allclose(m.Bw, integral @ Bwc, rtol=0, atol=1e-11)
    assert np.max(np.abs(m.Bw)) > 1e-3


def test_testbed_state_matrix_singular_and_B_nonzero(testbed_cfg):
    """The rigid mode makes A_c singular (a zero eigenvalue), so the inverse formula is unusable;
    the thruster input matrix is non-trivial."""
    Ac, Bc, _ = continuous_model(testbed_cfg)
    assert np.linalg.matrix_rank(Ac) == Ac.shape[0] - 1
    m = discrete_model(testbed_cfg)
    assert m.B.shape == (18, 24)
    assert np.max(np.abs(m.B)) > 1e-4


def test_zoh_inverse_formula_when_invertible(dof2_cfg):
    """1995 model has no rigid mode: ∫₀ᵀ e^{A_c s} ds = A_c⁻¹ (e^{A_c T} − I)."""
    Ac, _, Bwc = continuous_model(dof2_cfg)
    T = dof2_cfg.sample_period_s
    m = discrete_model(dof2_cfg)
    Bw = np.linalg.solve(Ac, (expm(Ac * T) - np.eye(4)) @ Bwc)
    np.testing.assert_allclose(m.Bw, Bw, rtol=0, atol=1e-12)


def test_zoh_generic_input(dof2_cfg):
    """zoh() on an arbitrary input matrix and an other period, against the inverse formula."""
    Ac, _, _ = continuous_model(dof2_cfg)
    Bc = np.random.default_rng(2).normal(size=(4, 3))
    A, B = zoh(Ac, Bc, 0.7)
    np.testing.assert_allclose(A, expm(Ac * 0.7), atol=1e-12)
    np.testing.assert_allclose(B, np.linalg.solve(Ac, (A - np.eye(4)) @ Bc), atol=1e-12)
    m = discrete_model(dof2_cfg, T=0.7)
    np.testing.assert_allclose(m.A, A, atol=1e-14)
    assert m.T == 0.7


@pytest.mark.parametrize("which", ["testbed", "dof2"])
def test_discrete_eigenvalues(which, testbed_cfg, dof2_cfg):
    """eig(A) = exp(λ T), λ the roots of s² + c s + ω² per mode."""
    cfg = testbed_cfg if which == "testbed" else dof2_cfg
    T = cfg.sample_period_s
    expected = []
    for f, tau in zip(cfg.mode_frequency_hz, cfg.mode_time_constant_s):
        w = 2 * np.pi * f
        c = 1.0 / tau if f == 0 else 2.0 / tau
        expected.extend(np.exp(np.roots([1.0, c, w * w]).astype(complex) * T))
    _match_eigenvalues(np.linalg.eigvals(discrete_model(cfg).A), np.array(expected), 1e-10)


def test_table1_frequencies_and_time_constants_reproduced(testbed_cfg):
    """From the discrete eigenvalues μ: λ = log μ / T, |λ|/2π = Table 1 frequency and
    −Re λ = 1/τ (envelope decays as e^{−t/τ}); the rigid mode gives μ = 1 and e^{−T/τ}."""
    T = testbed_cfg.sample_period_s
    lam = np.log(np.linalg.eigvals(discrete_model(testbed_cfg).A).astype(complex)) / T
    osc = lam[lam.imag > 1e-9]
    got = sorted(zip(np.abs(osc) / (2 * np.pi), -osc.real))
    want = sorted((f, 1.0 / tau) for f, tau in TABLE1.values())
    assert len(got) == 8
    for (fg, dg), (fw, dw) in zip(got, want):
        assert fg == pytest.approx(fw, rel=1e-9)
        assert dg == pytest.approx(dw, rel=1e-9)
    real = np.sort(lam[np.abs(lam.imag) <= 1e-9].real)
    np.testing.assert_allclose(real, [-1.0 / RIGID_TAU, 0.0], atol=1e-9)


@pytest.mark.parametrize("which", ["testbed", "dof2"])
def test_process_noise_covariance(which, testbed_cfg, dof2_cfg):
    cfg = testbed_cfg if which == "testbed" else dof2_cfg
    m = discrete_model(cfg)
    np.testing.assert_array_equal(m.W, np.diag(np.asarray(cfg.process_noise_sigma) ** 2))
    np.testing.assert_allclose(m.Q, m.Bw @ m.W @ m.Bw.T, atol=1e-18)
    np.testing.assert_allclose(m.Q, m.Q.T, rtol=0, atol=1e-15 * np.max(np.abs(m.Q)))
    ev = np.linalg.eigvalsh(0.5 * (m.Q + m.Q.T))
    assert ev.min() >= -1e-12 * ev.max()
    assert ev.max() > 0


def test_testbed_noise_is_modal(testbed_cfg):
    _, _, Bwc = continuous_model(testbed_cfg)
    np.testing.assert_array_equal(Bwc, np.vstack([np.zeros((9, 9)), np.eye(9)]))


def _dof2_noise_checks(cfg):
    """Coordinate-space process noise: B_wc = [0; U⁺], so U·(modal acceleration) = the coordinate
    acceleration; discrete Bw = ∫ e^{A_c s} ds [0; U⁺]."""
    U = np.asarray(cfg.mode_shapes)
    Ac, _, Bwc = continuous_model(cfg)
    np.testing.assert_allclose(U @ Bwc[2:], np.eye(2), atol=1e-12)
    np.testing.assert_array_equal(Bwc[:2], 0.0)
    m = discrete_model(cfg)
    G = np.linalg.inv(U)
    np.testing.assert_allclose(m.Bw, _zoh_integral_quad(Ac, cfg.sample_period_s) @ np.vstack([np.zeros((2, 2)), G]),
                               atol=1e-12)
    # a constant coordinate acceleration a over one short period moves q by ≈ a T²/2
    Ts = 1e-3
    ms = discrete_model(cfg, T=Ts)
    a = np.array([0.3, -0.1])
    np.testing.assert_allclose(U @ (ms.Bw @ a)[:2], a * Ts**2 / 2, rtol=1e-4)
    np.testing.assert_allclose(U @ (ms.Bw @ a)[2:], a * Ts, rtol=1e-4)


def test_dof2_noise_in_coordinate_space(dof2_cfg):
    _dof2_noise_checks(dof2_cfg)


def test_coordinate_noise_with_non_orthogonal_shapes(dof2_text):
    """With the shipped (orthogonal, symmetric) shapes U⁺ = U = Uᵀ; use shapes where they differ."""
    text = dof2_text.replace("shape = [0.525731, 0.850651]", "shape = [1.0, 2.0]", 1)
    text = text.replace("shape = [0.850651, -0.525731]", "shape = [0.5, -0.3]", 1)
    cfg = parse_config(text, "skewed.toml")
    U = np.asarray(cfg.mode_shapes)
    assert not np.allclose(np.linalg.pinv(U), U.T)
    _dof2_noise_checks(cfg)
