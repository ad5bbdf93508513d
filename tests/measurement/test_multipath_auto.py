"""Automatic multipath (issue 11 item 5): detection of time-correlated residuals and the
Gauss–Markov σ, τ fitted to their autocovariance (:func:`fit_autocovariance`).

* the expected autocovariance sums of a demeaned Gauss–Markov + white stretch equal a dense
  (I − 11ᵀ/L) R (I − 11ᵀ/L) reference;
* synthetic Gauss–Markov + white series: σ and τ recovered, detected; white series: never detected;
* ``init`` with default options on a multipath run switches the model on (recorded, warned) and
  ``--multipath-sigma-m 0`` keeps it off; on a white run it stays off.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.core.records import memory_run
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.measurement.multipath import _expected_sums, fit_autocovariance
from cdgps_cli.sim.structure import SimOptions, simulate

from _shared import REPO_ROOT

DT = 0.1


def _gm(rng, n, C, sigma, tau):
    a = math.exp(-DT / tau)
    m = np.empty((n, C))
    m[0] = rng.normal(0, sigma, C)
    e = rng.normal(0, sigma * math.sqrt(1 - a * a), (n, C))
    for k in range(1, n):
        m[k] = a * m[k - 1] + e[k]
    return m


@pytest.mark.parametrize("L,a", [(7, 0.6), (30, 0.95), (25, 0.2)])
def test_expected_sums_equal_dense_reference(L, a):
    lags = np.array([0, 1, 3, 6])
    gm, wh = _expected_sums(np.array([L, L]), lags, a)
    i = np.arange(L)
    R = a ** np.abs(i[:, None] - i[None, :])
    M = np.eye(L) - 1.0 / L
    for name, cov, got in (("gm", M @ R @ M, gm), ("white", M @ M.T, wh)):
        ref = [np.trace(cov, offset=k) for k in lags]
        np.testing.assert_allclose(got, 2 * np.array(ref), rtol=1e-12, atol=1e-12, err_msg=name)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_gauss_markov_plus_white_recovered(seed):
    rng = np.random.default_rng(seed)
    n, C = 3000, 24
    y = _gm(rng, n, C, 0.015, 30.0) + rng.normal(0, 0.002, (n, C))
    fit = fit_autocovariance(y, np.zeros((n, C), dtype=int), DT)
    assert fit["detected"]
    # 24 channels × 10 correlation times: σ̂ scatters by ~6 %, τ̂ by ~12 % (measured on seeds 1–8)
    assert abs(fit["sigma_m"] / 0.015 - 1) < 0.2
    assert abs(fit["time_constant_s"] / 30.0 - 1) < 0.35
    # the white σ rests on γ₀ − γ₁, a small difference of large numbers: only its size is checked
    assert 0.0002 < fit["white_sigma_m"] < 0.005


@pytest.mark.parametrize("white", [0.002, 0.01, 0.02])
def test_white_noise_never_detected(white):
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        y = rng.normal(0, white, (600, 18))
        y[100:130, 3] = np.nan                       # a gap: two stretches on that channel
        seg = np.zeros(y.shape, dtype=int)
        fit = fit_autocovariance(y, seg, DT)
        assert not fit["detected"], (seed, fit)
        assert fit["raw_sigma_m"] < 0.5 * fit["white_sigma_m"]


def test_too_short_returns_none():
    assert fit_autocovariance(np.zeros((10, 2)), np.zeros((10, 2), dtype=int), DT) is None


@pytest.fixture(scope="module")
def tower():
    return load_config(REPO_ROOT / "configs" / "tower-120m-fe.toml")


def test_init_switches_multipath_on_by_default(tower):
    sim = simulate(tower, SimOptions(duration_s=30.0, seed=4, phase_sigma_m=0.002, multipath_sigma_m=0.015))
    run = memory_run(tower, sim.receiver)
    init = initialize(run, InitOptions())
    mp = init["multipath"]
    assert mp["evidence"]["detected"] and "residual autocovariance" in mp["source"]
    assert 0.005 < mp["sigma_m"] < 0.03 and 5.0 < mp["time_constant_s"] < 200.0
    assert any("time-correlated" in w for w in init["noise"]["warnings"])
    truth = {(r["antenna"], r["transmitter"]): r["bias_m"] for r in sim.truth["biases"]}
    assert init["n_fixed"] == len(init["biases"])
    for b in init["biases"]:
        assert abs(b["bias_m"] - truth[(b["antenna"], b["transmitter"])]) < 0.25 * tower.wavelength_m
    off = initialize(run, InitOptions(multipath_sigma_m=0.0))
    assert "multipath" not in off and not any("time-correlated" in w for w in off["noise"]["warnings"])


def test_init_white_run_unchanged(tower):
    sim = simulate(tower, SimOptions(duration_s=30.0, seed=4, phase_sigma_m=0.002, multipath_sigma_m=0.0))
    run = memory_run(tower, sim.receiver)
    assert "multipath" not in initialize(run, InitOptions())


def test_long_time_constant_fitted_at_the_stretch_limit_with_its_drift():
    # τ = 600 s on 60 s stretches: only σ²/τ shows; the fit stops at τ = ½ × 60 s with that drift
    rng = np.random.default_rng(7)
    n, C = 600, 24
    y = _gm(rng, n, C, 0.05, 600.0) + rng.normal(0, 0.002, (n, C))
    fit = fit_autocovariance(y, np.zeros((n, C), dtype=int), DT)
    assert fit["detected"]
    assert fit["time_constant_s"] == pytest.approx(30.0, rel=1e-9)
    drift = 0.05**2 / 600.0
    assert fit["sigma_m"] ** 2 / fit["time_constant_s"] == pytest.approx(drift, rel=0.5)


# --- multipath below the white noise (issue 32 item 3): it matters through the bias estimates


def test_mean_variance_ratio_against_dense_reference():
    from cdgps_cli.measurement.multipath import mean_variance_ratio
    n, tau, dt = 50, 3.0, 0.1
    a = math.exp(-dt / tau)
    R = a ** np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    dense = 0.004**2 * R.sum() / n**2 / (0.01**2 / n)
    assert mean_variance_ratio(0.004, tau, 0.01, dt, n) == pytest.approx(dense, rel=1e-12)
    assert mean_variance_ratio(0.0, tau, 0.01, dt, n) == 0.0
    # τ → 0: the Gauss–Markov samples are white, the ratio is (σ_mp/σ_w)²
    assert mean_variance_ratio(0.005, 1e-6, 0.01, dt, n) == pytest.approx(0.25)


def test_multipath_below_white_detected_when_it_matters():
    """5 mm Gauss–Markov (τ 30 s) under 1 cm white: σ_mp/σ_w ≈ 0.5 or below (the old gate), yet
    over 600 epochs it dominates the variance of a bias estimate, so it is detected."""
    rng = np.random.default_rng(3)
    y = _gm(rng, 600, 18, 0.005, 30.0) + rng.normal(0, 0.01, (600, 18))
    fit = fit_autocovariance(y, np.zeros(y.shape, dtype=int), DT)
    assert fit["detected"] and fit["bias_variance_ratio"] > 10


@pytest.mark.parametrize("seed", [1, 2])
def test_init_fixes_under_multipath_below_white(tower, seed):
    """Issue 32 item 3: before, 0 of 18 fixed (the white fit's bias σ were too small for the
    multipath, and the fix validation rejected the right integers)."""
    sim = simulate(tower, SimOptions(duration_s=120.0, seed=seed, phase_sigma_m=0.01, multipath_sigma_m=0.005))
    init = initialize(memory_run(tower, sim.receiver), InitOptions())
    assert "multipath" in init
    truth = {(r["antenna"], r["transmitter"]): r["bias_m"] for r in sim.truth["biases"]}
    assert init["n_fixed"] == len(init["biases"]) == 18, init["integer_fixing"]
    for b in init["biases"]:
        assert abs(b["bias_m"] - truth[(b["antenna"], b["transmitter"])]) < 1e-9 + 0.25 * tower.wavelength_m
