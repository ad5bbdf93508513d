"""DD measurement model of measurement/dd_signals.py: Jacobian against finite differences, noise D Σ Dᵀ."""

import numpy as np

from cdgps_cli.measurement.dd_signals import epoch_rows


def _case(iono: bool):
    rng = np.random.default_rng(4)
    base = np.array([4157177.0, 671230.0, 4774767.0])
    origin = base + np.array([-320.0, 1978.0, 0.0])
    sat = base + rng.normal(size=(5, 3)) * 1.2e7 + np.array([1.5e7, 0, 1.5e7])
    n = 3 + 5 + (5 if iono else 0)
    g = {"sat_xyz": sat, "ref": 2, "lam_m": 0.19, "mu": 1.6, "phase_sd_m": rng.normal(size=5), "code_sd_m": rng.normal(size=5),
         "var_phase": np.full(5, 1e-5), "var_code": np.full(5, 0.1), "amb_col": np.arange(3, 8),
         "iono_col": np.arange(8, 13) if iono else np.full(5, -1)}
    return rng.normal(size=n), [g], base, origin, n


def test_jacobian_matches_finite_differences():
    for iono in (False, True):
        x, groups, base, origin, n = _case(iono)
        r0, H, _ = epoch_rows(x, groups, base, origin, n)
        for j in range(n):
            h = 1e-2 if j < 3 else 1e-4   # metres on ranges of 2e7 m: rounding ~1e-9 m
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            fd = -(epoch_rows(xp, groups, base, origin, n)[0] - epoch_rows(xm, groups, base, origin, n)[0]) / (2 * h)
            assert np.allclose(H[:, j], fd, atol=1e-6), (iono, j)


def test_noise_is_dd_covariance_and_ref_has_no_row():
    x, groups, base, origin, n = _case(False)
    r, H, L = epoch_rows(x, groups, base, origin, n)
    assert r.shape == (8,) and H.shape == (8, n)
    C = L @ L.T
    assert np.allclose(C[:4, :4], 1e-5 * (np.eye(4) + np.ones((4, 4))))
    assert np.allclose(C[:4, 4:], 0)
    # the reference satellite's ambiguity enters every phase row with −λ
    assert np.allclose(H[:4, 3 + 2], -0.19)
