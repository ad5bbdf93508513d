"""Noise estimation: variance factors with redundancy numbers, against textbook LS and brute force."""

import numpy as np
import pytest

from cdgps_cli.estimation.batch_solver import LinearProblem, srif_solve
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.noise import leverage_per_channel, prior_sigma_m, variance_factors


def _textbook(rng, N=400, groups=(0.002, 0.01), p=6):
    """y = Xβ + e, two channels (column groups) with different σ; textbook hat matrix."""
    C = len(groups)
    X = rng.standard_normal((N * C, p))
    sig = np.repeat(np.asarray(groups)[None, :], N, axis=0).ravel()
    return X, sig


def test_leverage_hutchinson_matches_exact_hat_matrix():
    rng = np.random.default_rng(1)
    N, C, p = 50, 3, 8
    X = rng.standard_normal((N * C, p))
    Hhat = X @ np.linalg.solve(X.T @ X, X.T)
    exact = np.diag(Hhat).reshape(N, C).sum(axis=0)

    def fitted(eps):
        e = eps.ravel()
        return (Hhat @ e).reshape(N, C)

    est = leverage_per_channel(fitted, np.ones((N, C), bool), probes=400)
    assert exact.sum() == pytest.approx(p)
    np.testing.assert_allclose(est, exact, atol=0.35)


def test_variance_factors_recover_known_sigma_with_redundancy():
    """Heavy fit (p/N large): the naive RMS is biased low by sqrt(1 − p/n); σ̂ with redundancy is not."""
    rng = np.random.default_rng(2)
    N, C, p = 40, 2, 30
    sig_true = np.array([0.002, 0.01])
    est, naive = [], []
    for _ in range(200):
        X = rng.standard_normal((N * C, p))
        s = np.tile(sig_true, N)
        y = rng.standard_normal(N * C) * s
        W = 1 / s
        Xw, yw = X * W[:, None], y * W
        beta = np.linalg.lstsq(Xw, yw, rcond=None)[0]
        e = (y - X @ beta).reshape(N, C)
        Hhat = Xw @ np.linalg.solve(Xw.T @ Xw, Xw.T)
        lev = np.diag(Hhat).reshape(N, C).sum(axis=0)
        vf = variance_factors(e, sig_true, lev)
        est.append(vf["sigma_m"] ** 2)
        naive.append(vf["rms_m"] ** 2)
    np.testing.assert_allclose(np.mean(est, axis=0) / sig_true**2, 1.0, atol=0.05)
    # naive RMS: biased low, most in the precise channel, which carries most of the leverage
    naive_ratio = np.mean(naive, axis=0) / sig_true**2
    assert naive_ratio[0] < 0.5 and np.mean(naive_ratio) < 0.75


def test_leave_one_out_identity_of_redundancy():
    """Brute force: the leave-one-out prediction error equals e_i / (1 − h_ii) (textbook identity)."""
    rng = np.random.default_rng(3)
    n, p = 30, 5
    X = rng.standard_normal((n, p))
    y = rng.standard_normal(n)
    beta = np.linalg.lstsq(X, y, rcond=None)[0]
    e = y - X @ beta
    h = np.diag(X @ np.linalg.solve(X.T @ X, X.T))
    for i in range(n):
        keep = np.arange(n) != i
        bi = np.linalg.lstsq(X[keep], y[keep], rcond=None)[0]
        assert y[i] - X[i] @ bi == pytest.approx(e[i] / (1 - h[i]), rel=1e-9)


def test_batch_leverage_equals_brute_force_unit_responses():
    """The batch solver's hat-matrix trace per channel (Hutchinson) against the exact diagonal from
    unit-vector responses (one solve per observation) on a small dynamic problem with process noise."""
    rng = np.random.default_rng(4)
    N, C, n = 12, 3, 2
    A = np.array([[1.0, 0.1], [-0.1, 1.0]])
    G = np.array([[0.0], [0.05]])
    H = rng.standard_normal((N, C, n))
    bi = np.tile(np.arange(C), (N, 1))

    def fitted(eps):
        lp = LinearProblem(A=A, Bw_L=G, H=H, y=eps, bias_index=bi, n_bias=C, sigma_m=1.0,
                           x1_mean=np.zeros(n), x1_sqrt_info=np.zeros((n, n)), b_mean=np.zeros(C),
                           b_sqrt_info=np.zeros((C, C)))
        sol = srif_solve(lp)
        return np.einsum("nci,ni->nc", H, sol.x) + sol.b[bi]

    exact = np.zeros(C)
    for k in range(N):
        for c in range(C):
            u = np.zeros((N, C))
            u[k, c] = 1.0
            exact[c] += fitted(u)[k, c]
    est = leverage_per_channel(fitted, np.ones((N, C), bool), probes=600)
    np.testing.assert_allclose(est, exact, atol=0.4)
    assert np.all(exact > 1.0) and np.all(exact < N)

    # all probes as one solve with a right-hand side per probe: the same probes, the same estimate
    def fitted_many(eps):
        K = eps.shape[2]
        lp = LinearProblem(A=A, Bw_L=G, H=H, y=eps, bias_index=bi, n_bias=C, sigma_m=1.0,
                           x1_mean=np.zeros((n, K)), x1_sqrt_info=np.zeros((n, n)), b_mean=np.zeros((C, K)),
                           b_sqrt_info=np.zeros((C, C)))
        sol = srif_solve(lp)
        return np.einsum("nci,nik->nck", H, sol.x) + sol.b[bi]

    many = leverage_per_channel(fitted_many, np.ones((N, C), bool), probes=600, batched=True)
    np.testing.assert_allclose(many, est, rtol=1e-11, atol=1e-12)


def test_prior_sigma_vector_and_override(testbed_cfg):
    ch = list(testbed_cfg.channels)[:5]
    np.testing.assert_array_equal(prior_sigma_m(testbed_cfg, ch), testbed_cfg.measurement_sigma_m)
    np.testing.assert_array_equal(prior_sigma_m(testbed_cfg, ch, 0.003), 0.003)
    with pytest.raises(CdgpsError, match="--sigma-m"):
        prior_sigma_m(testbed_cfg, ch, -1.0)


# ---------------------------------------------------------------------------------------------
# end to end on the testbed (config σ 2 cm; data at another level)

from cdgps_cli.estimation.filter import EstimateOptions, estimate  # noqa: E402
from cdgps_cli.estimation.initializer import InitOptions, initialize  # noqa: E402
from cdgps_cli.core.records import memory_run  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402


def test_init_estimates_sigma_and_filter_is_consistent(testbed_cfg):
    """Data at 5 mm, config says 2 cm: INIT's σ̂ recovers 5 mm (warned), and the filter's NIS/dof
    and the NEES of the modal positions against the truth are near 1 (they were ~0.06 with the config's σ)."""
    cfg = testbed_cfg
    sim = simulate(cfg, SimOptions(duration_s=40.0, seed=5, phase_sigma_m=0.005))
    run = memory_run(cfg, sim.receiver)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=20.0))
    assert init["sigma_m"] == pytest.approx(0.005, rel=0.1)
    assert any("estimated from the data" in w for w in init["noise"]["warnings"])
    assert init["n_fixed"] == len(init["biases"])
    res = estimate(run, init, EstimateOptions())
    ok = res.nis_dof > 0
    nis = float(np.mean(res.nis[ok] / res.nis_dof[ok]))
    assert 0.8 < nis < 1.25
    nm = cfg.n_modes
    U = np.asarray(cfg.mode_shapes)
    k = np.rint(res.time_s / cfg.sample_period_s).astype(int)
    err = res.x[:, :nm] @ U.T - sim.q[k]
    var = np.einsum("qi,nij,qj->nq", U, res.P[:, :nm, :nm], U)
    nees_per_coord = float(np.mean(err[1:] ** 2 / var[1:]))
    assert 0.6 < nees_per_coord < 1.5, nees_per_coord
    # an explicit σ is used as given (no estimate)
    fixed = initialize(run, InitOptions(start_s=0.0, duration_s=20.0, sigma_m=0.02))
    assert fixed["sigma_m"] == 0.02 and fixed["noise"]["source"] == "--sigma-m"


def test_unflagged_slip_in_window_is_refused_naming_the_channel(testbed_cfg):
    cfg = testbed_cfg
    sim = simulate(cfg, SimOptions(duration_s=20.0, seed=6, phase_sigma_m=0.005))
    rx = sim.receiver.copy()
    ant, tx = cfg.rover_names[1], cfg.transmitter_names[2]
    sel = (rx["antenna"] == ant) & (rx["transmitter"] == tx) & (rx["time_s"] >= 10.0)
    rx.loc[sel, "phase_cycles"] += 3.0                # a 3-cycle slip, lock counter untouched
    # (issue 32: found as a residual step before the noise estimate, so the message says what it is)
    with pytest.raises(CdgpsError, match=f"--start/--duration: unflagged cycle slip.*{ant}/{tx} at 10 s"):
        initialize(memory_run(cfg, rx), InitOptions(start_s=0.0, duration_s=20.0))


def test_filter_adapts_sigma_from_innovations(testbed_cfg):
    """INIT made with a σ 4× too large (--sigma-m 2 cm on 5 mm data): the filter's innovation-based
    estimate finds ≈ 5 mm and its second pass is consistent (NIS/dof ≈ 1, was ≈ 1/16)."""
    cfg = testbed_cfg
    sim = simulate(cfg, SimOptions(duration_s=40.0, seed=8, phase_sigma_m=0.005))
    run = memory_run(cfg, sim.receiver)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=20.0, sigma_m=0.02))
    res = estimate(run, init, EstimateOptions())
    first = res.noise["first_pass"]
    assert first["mean_nis_per_dof"] < 0.15 and first["adapt"]
    assert first["innovation_sigma_m"] == pytest.approx(0.005, rel=0.15)
    assert res.noise["source"].startswith("innovation-adapted")
    assert 0.8 < res.noise["mean_nis_per_dof"] < 1.25 and not res.noise["adapt"]
    # given explicitly, σ is used as is
    fixed = estimate(run, init, EstimateOptions(sigma_m=0.02))
    assert fixed.noise["source"] == "--sigma-m" and "first_pass" not in fixed.noise


# --- SNR weighting of the prior σ (issue 11 item 5 b)

def test_snr_factor_formula_and_threshold():
    from cdgps_cli.measurement.noise import SNR_SPREAD_MIN_DB, snr_sigma_factor
    # σ² ∝ 10^(−SNR/10): 10 dB less → σ × √10, relative to the median channel
    f = snr_sigma_factor([45.0, 45.0, 35.0, np.nan, 48.0])
    np.testing.assert_allclose(f, [1.0, 1.0, 10 ** 0.5, 1.0, 10 ** (-0.15)], rtol=1e-12)
    assert snr_sigma_factor([45.0, 45.0 + SNR_SPREAD_MIN_DB / 2, 44.5]) is None     # equal enough: unchanged
    assert snr_sigma_factor([np.nan, 30.0]) is None


def test_init_prior_follows_snr_only_when_it_varies():
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.core.records import memory_run
    from cdgps_cli.estimation.initializer import InitOptions, initialize
    from cdgps_cli.sim.structure import SimOptions, simulate
    from _shared import REPO_ROOT

    cfg = load_config(REPO_ROOT / "configs" / "tower-120m-fe.toml")
    sim = simulate(cfg, SimOptions(duration_s=30.0, seed=2, phase_sigma_m=0.002))
    base = initialize(memory_run(cfg, sim.receiver), InitOptions())
    assert "snr_weighting" not in base["noise"]                 # simulated C/N₀: 45 ± 1 dB on every channel
    ph = sim.receiver.copy()
    ant = cfg.antenna_names[1]
    low = ph["antenna"] == ant
    rng = np.random.default_rng(0)
    extra = 0.002 * np.sqrt(10.0 - 1.0)                          # total σ = 2 mm × √10 on that antenna
    ph.loc[low, "phase_cycles"] += rng.normal(0, extra, int(low.sum())) / cfg.wavelength_m
    ph.loc[low, "snr_dbhz"] -= 10.0
    init = initialize(memory_run(cfg, ph), InitOptions())
    sw = init["noise"]["snr_weighting"]
    per = {p["channel"]: p for p in init["noise"]["per_channel"]}
    for name, p in per.items():
        ratio = p["prior_sigma_m"] / cfg.measurement_sigma_m
        expect = 10 ** ((sw["snr_ref_dbhz"] - sw["snr_dbhz"][name]) / 20)
        assert ratio == pytest.approx(expect, rel=1e-9)
        # the estimated σ agrees with the SNR model's (independently: the noise added above)
        assert p["sigma_m"] / (0.002 * (10 ** 0.5 if name.startswith(ant + "/") else 1.0)) == pytest.approx(1.0, abs=0.25)


def test_correlated_variance_factor_against_ar1_samples():
    """(1+ρ)/(1−ρ) is the large-N ratio of the variance of the mean of AR(1) samples to that of white
    samples of the same variance (checked by simulation), 1 for white noise, refused below 0."""
    import math
    import pytest
    from cdgps_cli.measurement.noise import correlated_variance_factor
    assert correlated_variance_factor(1.0, 0.0) == 1.0
    f = correlated_variance_factor(1.0, 5.0)
    rho = math.exp(-1 / 5)
    assert f == pytest.approx((1 + rho) / (1 - rho))
    rng = np.random.default_rng(0)
    n, trials = 2000, 2000
    e = np.empty((trials, n))
    e[:, 0] = rng.normal(size=trials)
    w = rng.normal(size=(trials, n)) * math.sqrt(1 - rho ** 2)
    for k in range(1, n):
        e[:, k] = rho * e[:, k - 1] + w[:, k]
    ratio = e.mean(axis=1).var() / (1.0 / n)
    assert ratio == pytest.approx(f, rel=0.1)
    assert correlated_variance_factor(1.0, 60.0) == pytest.approx(120.0, rel=0.01)
    with pytest.raises(ValueError):
        correlated_variance_factor(1.0, -1.0)


# ----------------------------------------------------------------------------------------------
# code_noise_factor: the variance of 30 s means of the code-minus-carrier against the model's


def _cmc_channels(rng, n_ch=8, n=1800, step=1.0, sigma=0.5, rho=0.0, slips=()):
    """Rows of ``n_ch`` channels, ``n`` epochs each: code = ambiguity·λ-like offset + quadratic ionosphere +
    AR(1) error (σ, lag-1 correlation ρ), phase = offset; a slip at epoch k of channel c jumps the offset."""
    t, ch, code, phase, slip = [], [], [], [], []
    for c in range(n_ch):
        tt = np.arange(n) * step
        e = np.empty(n)
        e[0] = rng.normal() * sigma
        w = rng.normal(size=n) * sigma * np.sqrt(1 - rho ** 2)
        for k in range(1, n):
            e[k] = rho * e[k - 1] + w[k]
        offset = np.full(n, rng.uniform(-1e3, 1e3))
        s = np.zeros(n, dtype=bool)
        for cc, k in slips:
            if cc == c:
                offset[k:] += 37.0 * 0.19
                s[k] = True
        iono = 2e-6 * (tt - 900.0) ** 2 + 1e-3 * tt
        t.append(tt); ch.append(np.full(n, c)); phase.append(offset - iono); code.append(offset + iono + e); slip.append(s)
    return [np.concatenate(a) for a in (t, ch, code, phase, slip)]


def _factor(t, ch, code, phase, slip, var, **kw):
    from cdgps_cli.measurement.noise import code_noise_factor

    return code_noise_factor(t, ch, code, phase, slip, var, **{"window_s": 30.0, "chunk_s": 300.0, "min_windows": 10, **kw})


def test_code_noise_factor_white_codes_at_their_model_give_one():
    """White errors of the modelled σ: the 30 s means scatter as σ²/30, factor ≈ 1 (± 3 √(2/n)), whatever the
    offsets, the ionosphere's quadratic and the slips (a slip starts a new arc)."""
    rng = np.random.default_rng(1)
    t, ch, code, phase, slip = _cmc_channels(rng, slips=((2, 700), (5, 1234)))
    f, n = _factor(t, ch, code, phase, slip, np.full(t.size, 0.25))
    assert n >= 400 and abs(f - 1.0) < 3 * np.sqrt(2 / n), (f, n)


def test_code_noise_factor_scales_with_the_variance_against_the_model():
    rng = np.random.default_rng(2)
    t, ch, code, phase, slip = _cmc_channels(rng, sigma=1.0)
    f, n = _factor(t, ch, code, phase, slip, np.full(t.size, 0.25))         # errors of σ 1 m, model 0.5 m
    assert abs(f / 4.0 - 1.0) < 3 * np.sqrt(2 / n), (f, n)


def test_code_noise_factor_of_correlated_codes_is_the_variance_of_their_mean():
    """AR(1) errors (ρ = e^(−1/10): τ = 10 s) against a white model of the same σ: the factor is the variance
    of a 30-sample mean of AR(1) over that of white samples, 1 + 2 Σ_{k<30} (1 − k/30) ρ^k (brute force)."""
    rng = np.random.default_rng(3)
    rho = np.exp(-1 / 10)
    t, ch, code, phase, slip = _cmc_channels(rng, n_ch=16, sigma=0.5, rho=rho)
    f, n = _factor(t, ch, code, phase, slip, np.full(t.size, 0.25))
    k = np.arange(1, 30)
    want = 1 + 2 * np.sum((1 - k / 30) * rho ** k)                            # 12.3
    assert abs(f / want - 1.0) < 0.25, (f, want, n)


def test_code_noise_factor_without_enough_windows_is_nan():
    rng = np.random.default_rng(4)
    t, ch, code, phase, slip = _cmc_channels(rng, n_ch=1, n=200)
    f, n = _factor(t, ch, code, phase, slip, np.full(t.size, 0.25))
    assert np.isnan(f) and n < 10
    f, n = _factor(t[:1], ch[:1], code[:1], phase[:1], slip[:1], np.full(1, 0.25))
    assert np.isnan(f) and n == 0


# ------------------------------------------------------------------------------------------------------------------
# effective_sample_size: what a serially correlated series is worth in independent samples


def _ess_by_lags(z) -> float:
    """The same sum, lag by lag (a direct loop, not the FFT)."""
    z = np.asarray(z, dtype=float) - np.mean(z)
    v = float(np.dot(z, z))
    s = 0.0
    for k in range(1, z.size // 2):
        r = float(np.dot(z[:-k], z[k:])) / v
        if r <= 0:
            break
        s += r
    return z.size / (1 + 2 * s)


def test_effective_sample_size_of_white_and_ar1_series():
    from cdgps_cli.measurement.noise import effective_sample_size
    rng = np.random.default_rng(3)
    white = rng.standard_normal(20_000)
    assert effective_sample_size(white) == pytest.approx(20_000, rel=0.1)
    rho = 0.9                                       # AR(1): n (1 − ρ) / (1 + ρ) = n / 19
    ar = np.zeros(20_000)
    e = rng.standard_normal(ar.size)
    for k in range(1, ar.size):
        ar[k] = rho * ar[k - 1] + e[k]
    assert effective_sample_size(ar) == pytest.approx(20_000 * (1 - rho) / (1 + rho), rel=0.25)
    for z in (white[:777], ar[:1500], np.sin(np.arange(300) / 20.0)):
        assert effective_sample_size(z) == pytest.approx(_ess_by_lags(z), rel=1e-9)


def test_effective_sample_size_edge_cases():
    from cdgps_cli.measurement.noise import effective_sample_size
    assert effective_sample_size([]) == 0.0
    assert effective_sample_size(np.full(50, 2.5)) == 50.0
    assert effective_sample_size([1.0]) == 1.0
