"""The float positions' variance factor of ``rtk``'s combined passes (rtk_multi.float_variance_factor): the forward
and backward floats' disagreement against their σ, judged by what the slowly converging floats are worth in
independent samples; the real-data check (the car of ../shared/data/real-pairs/geonet-car) is in
tests/pipeline/test_rtk_float_variance_real.py."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.estimation.chi2 import chi2_quantile
from cdgps_cli.estimation.rtk_multi import FLOAT_VARIANCE_MIN_EPOCHS, FLOAT_VARIANCE_PROBABILITY, float_variance_factor
from cdgps_cli.measurement.noise import effective_sample_size

SIGMA = np.array([0.02, 0.03, 0.05])                    # m: each pass's float σ (E, N, U as x, y, z)


def _slow(rng, n: int, scale: float, rho: float = 0.995) -> np.ndarray:
    """(n, 3) errors of a float that wanders slowly: AR(1) per axis, stationary σ = scale · SIGMA."""
    e = np.zeros((n, 3))
    e[0] = rng.standard_normal(3)
    w = rng.standard_normal((n, 3)) * np.sqrt(1 - rho**2)
    for k in range(1, n):
        e[k] = rho * e[k - 1] + w[k]
    return e * SIGMA * scale


def _passes(seed: int, scale: float, n: int = 1200):
    rng = np.random.default_rng(seed)
    truth = np.array([1.0, 2.0, 3.0])
    P = np.broadcast_to(np.diag(SIGMA**2), (n, 3, 3)).copy()
    return truth + _slow(rng, n, scale), P, truth + _slow(rng, n, scale), P.copy()


def test_honest_floats_keep_their_sigma():
    for seed in range(6):
        fv = float_variance_factor(*_passes(seed, 1.0))
        assert fv["factor"] == 1.0, (seed, fv)
        assert 0.2 < fv["disagreement"] < fv["threshold"]


def test_floats_three_times_worse_than_their_sigma_are_scaled_by_the_disagreement():
    xf, Pf, xb, Pb = _passes(11, 3.0)
    fv = float_variance_factor(xf, Pf, xb, Pb)
    d = xf - xb                                         # independently: the mean of dᵀ(Pf + Pb)⁻¹d / 3, by inverses
    z2 = np.array([dk @ np.linalg.inv(a + b) @ dk for dk, a, b in zip(d, Pf, Pb)])
    assert fv["disagreement"] == pytest.approx(z2.mean() / 3, rel=1e-12)
    assert fv["factor"] == fv["disagreement"] and 4.0 < fv["factor"] < 20.0        # 9 expected
    w = d / np.sqrt(2 * SIGMA**2)                       # the whitened differences (diagonal covariances)
    m = min(effective_sample_size(w[:, i]) for i in range(3))
    assert fv["independent_samples"] == pytest.approx(m, rel=1e-9)
    assert fv["threshold"] == pytest.approx(chi2_quantile(FLOAT_VARIANCE_PROBABILITY, 3 * m) / (3 * m), rel=1e-12)
    assert 2 < m < 60                                   # 1200 epochs of a float correlated over 200 s: a few samples


def test_epochs_without_both_floats_are_left_out_and_too_few_are_no_test():
    xf, Pf, xb, Pb = _passes(11, 3.0)
    ref = float_variance_factor(xf, Pf, xb, Pb)
    xf2, xb2 = np.vstack([np.full((5, 3), np.nan), xf]), np.vstack([xb[:1], xb])
    Pf2, Pb2 = np.concatenate([Pf[:5], Pf]), np.concatenate([np.full((1, 3, 3), np.nan), Pb])
    xb2, Pb2 = np.vstack([xb[:4], xb2]), np.concatenate([Pb[:4], Pb2])      # 5 rows more, each with a NaN
    out = float_variance_factor(xf2, Pf2, xb2, Pb2)
    assert out["epochs"] == xf.shape[0] and out["disagreement"] == pytest.approx(ref["disagreement"], rel=1e-12)
    few = float_variance_factor(xf[:FLOAT_VARIANCE_MIN_EPOCHS - 1], Pf[:9], xb[:9], Pb[:9])
    assert few == {"factor": 1.0, "disagreement": None, "independent_samples": None, "threshold": None,
                   "epochs": FLOAT_VARIANCE_MIN_EPOCHS - 1}
    singular = float_variance_factor(xf, np.zeros_like(Pf), xb, np.zeros_like(Pb))
    assert singular["factor"] == 1.0 and singular["disagreement"] is None


def test_false_alarms_near_the_tests_probability_and_a_doubled_sigma_found():
    """Floats whose σ hold are scaled in about 1 % of records (the test's 0.99, judged by the samples they are
    worth); floats twice as wrong as their σ almost always."""
    false = np.mean([float_variance_factor(*_passes(s, 1.0))["factor"] > 1 for s in range(200)])
    found = np.mean([float_variance_factor(*_passes(1000 + s, 2.0))["factor"] > 1 for s in range(100)])
    assert false <= 0.03 and found >= 0.9, (false, found)
