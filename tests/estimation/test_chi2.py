"""cdgps_cli/estimation/chi2.py: chi-square quantiles without scipy, against scipy and closed forms."""
import math
from statistics import NormalDist

import numpy as np
import pytest
from scipy.stats import chi2

from cdgps_cli.estimation.chi2 import chi2_quantile

PROBABILITIES = np.array([1e-9, 1e-3, 0.025, 0.1, 0.5, 0.9, 0.975, 0.99, 0.999, 0.9999, 1 - 1e-9])


def test_equal_to_scipy_over_the_range_the_tests_use():
    p, k = np.meshgrid(PROBABILITIES, np.r_[0.5, 1.5, np.arange(1, 301)])
    ours, ref = chi2_quantile(p, k), chi2.ppf(p, k)
    assert ours.shape == p.shape
    np.testing.assert_allclose(ours, ref, rtol=5e-14, atol=0)


def test_two_degrees_of_freedom_is_an_exponential():
    """χ²₂ is the exponential with mean 2: x = −2 ln(1 − p)."""
    for p in PROBABILITIES:
        assert chi2_quantile(p, 2) == pytest.approx(-2.0 * math.log1p(-p), rel=2e-15, abs=0)


def test_one_degree_of_freedom_is_a_squared_normal():
    """χ²₁ = z², so x = Φ⁻¹((1 + p)/2)² (Python's own normal quantile, not scipy)."""
    for p in PROBABILITIES[1:-1]:
        z = NormalDist().inv_cdf((1.0 + p) / 2.0)
        assert chi2_quantile(p, 1) == pytest.approx(z * z, rel=1e-12)


def test_large_dof_and_tiny_probabilities():
    for p, k in ((0.999, 1e4), (0.5, 1e5), (1e-300, 0.01), (1e-12, 0.5), (0.3, 0.01)):
        ref = chi2.ppf(p, k)
        assert chi2_quantile(p, k) == pytest.approx(ref, rel=1e-12, abs=1e-300), (p, k)


def test_edges_as_scipy():
    got = chi2_quantile([0.0, 1.0, -0.1, 1.1, np.nan, 0.5, 0.5], [3, 3, 3, 3, 3, 0, -1])
    np.testing.assert_array_equal(got, chi2.ppf([0.0, 1.0, -0.1, 1.1, np.nan, 0.5, 0.5], [3, 3, 3, 3, 3, 0, -1]))
    assert isinstance(chi2_quantile(0.999, 4), float)


def test_scalar_arguments_give_the_array_paths_numbers():
    """A filter's per-epoch call (two scalars, numpy or Python) takes a path without arrays: the same value, of the
    same type, as one element of the array path, edges included."""
    probs = [0.0, 1e-9, 0.025, 0.5, 0.975, 0.999, 1.0, -0.1, 1.1, float("nan")]
    dofs = [0, -1, 1, 2, 3.5, 7, 40, 300]
    grid = chi2_quantile(np.array(probs)[:, None], np.array(dofs, dtype=float)[None, :])
    for i, p in enumerate(probs):
        for j, k in enumerate(dofs):
            for pp, kk in ((p, k), (np.float64(p), np.int64(k) if float(k).is_integer() else np.float64(k))):
                got = chi2_quantile(pp, kk)
                assert isinstance(got, np.float64)
                assert got == grid[i, j] or (np.isnan(got) and np.isnan(grid[i, j])), (p, k, got, grid[i, j])
