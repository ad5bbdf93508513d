"""Spectra and modal identification (1998 paper Sec. VI.B, Fig. 8): :mod:`cdgps_cli.analysis.spectra`.

Checks against closed forms that do not depend on the code under test (Parseval for a sinusoid,
the white-noise level, scipy's Welch, the exact SDOF spectrum, MAC algebra), then end to end on
simulator truth of the testbed.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import csd, welch

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.kinematics import gyro_matrix
from cdgps_cli.sim.structure import SimOptions, simulate
from cdgps_cli.analysis.spectra import (SpectraOptions, _parabolic, compute_spectra, cross_spectral_matrix, efdd, mac,
                               sdof_expected_periodogram, sdof_whittle_fit)

FS = 10.0
T = 1.0 / FS


def grid(n: int) -> np.ndarray:
    """A regular 10 Hz time grid, rounded like the simulator's and the filter's."""
    return np.round(np.arange(n) * T, 9)


def sdof_psd(f, fn, zeta, A=1.0):
    return A / ((fn**2 - f**2) ** 2 + (2 * zeta * fn * f) ** 2)


# ----------------------------------------------------------------------------- (a) PSD levels

@pytest.mark.parametrize("A,f0", [(1.0, 0.23), (0.02, 0.085), (3.0, 1.7)])
def test_sinusoid_power_and_peak(testbed_cfg, A, f0):
    """A·sin(2π f0 t): ∫PSD df = A²/2 (Parseval) and the PSD peaks at f0."""
    n = 6000
    t = grid(n)
    q = np.zeros((n, testbed_cfg.n_q))
    q[:, 1] = A * np.sin(2 * np.pi * f0 * t + 0.3)
    res = compute_spectra(testbed_cfg, t, q, opt=SpectraOptions(coords=("q2",)))
    f, p = res["f_hz"], res["psd"]["gps_q2"]
    df = f[1] - f[0]
    assert df == pytest.approx(FS / res["settings"]["nfft"], rel=1e-9)
    assert f[0] > 0 and f[-1] == pytest.approx(FS / 2)
    assert np.sum(p) * df == pytest.approx(A**2 / 2, rel=0.01)
    assert abs(f[np.argmax(p)] - f0) <= df
    # the PSD is in the coordinate's units² / Hz: scaling the signal scales it by the square
    res2 = compute_spectra(testbed_cfg, t, 10 * q, opt=SpectraOptions(coords=("q2",)))
    np.testing.assert_allclose(res2["psd"]["gps_q2"], 100 * p, rtol=1e-6, atol=1e-9 * 100 * p.max())


def test_white_noise_level(testbed_cfg):
    """White noise of variance σ² sampled at fs has a one-sided PSD of 2σ²/fs."""
    rng = np.random.default_rng(1)
    n = 12000
    sig = np.array([0.01, 0.003, 2.0])
    q = np.zeros((n, testbed_cfg.n_q))
    q[:, [0, 4, 8]] = rng.standard_normal((n, 3)) * sig
    res = compute_spectra(testbed_cfg, grid(n), q, opt=SpectraOptions(coords=("q1", "q5", "q9")))
    f = res["f_hz"]
    inner = (f > 0.05) & (f < 4.95)
    for name, s in zip(("q1", "q5", "q9"), sig):
        level = np.mean(res["psd"][f"gps_{name}"][inner])
        assert level == pytest.approx(2 * s**2 / FS, rel=0.03), name
    assert set(res["settings"]["coordinates"]) == {"q1", "q5", "q9"}


# ----------------------------------------------------------------------------- (b) CSD matrix

@pytest.mark.parametrize("nperseg,overlap,nfft", [(256, 0.5, 1024), (300, 0.0, 300), (500, 0.75, 2048), (333, 0.5, 1333)])
def test_cross_spectral_matrix_matches_scipy(nperseg, overlap, nfft):
    rng = np.random.default_rng(nperseg)
    n = 4000
    e = rng.standard_normal((n, 3))
    x = np.column_stack([e[:, 0], 0.6 * e[:, 0] + 0.8 * e[:, 1], np.convolve(e[:, 2], np.ones(5) / 5, "same")]) + [3.0, -1.0, 0.5]
    f, G = cross_spectral_matrix(x, FS, nperseg, overlap, nfft)
    kw = dict(fs=FS, window="hann", nperseg=nperseg, noverlap=int(nperseg * overlap), nfft=nfft, detrend="constant")
    for i in range(3):
        fw, pw = welch(x[:, i], **kw)
        np.testing.assert_allclose(f, fw)
        np.testing.assert_allclose(G[:, i, i].real, pw, rtol=1e-10, atol=1e-14 * pw.max())
        np.testing.assert_allclose(G[:, i, i].imag, 0, atol=1e-14 * pw.max())
        for j in range(3):
            _, pij = csd(x[:, i], x[:, j], **kw)            # scipy: conj(X_i) X_j
            np.testing.assert_allclose(np.abs(G[:, i, j]), np.abs(pij), rtol=1e-9, atol=1e-13 * pw.max())
            np.testing.assert_allclose(G[:, i, j], np.conj(pij), rtol=1e-9, atol=1e-13 * pw.max())
    # Hermitian, positive semi-definite at every frequency
    np.testing.assert_allclose(G, np.conj(np.swapaxes(G, 1, 2)), atol=1e-14 * np.abs(G).max())
    ev = np.linalg.eigvalsh(G)
    assert ev.min() >= -1e-12 * ev.max()


def test_cross_spectral_matrix_coherent_pair_rank_one():
    """Two scaled copies of one signal: G has rank one (second singular value ~ 0)."""
    rng = np.random.default_rng(4)
    s = rng.standard_normal(3000)
    f, G = cross_spectral_matrix(np.column_stack([s, -2.5 * s]), FS, 256, 0.5, 512)
    sv = np.linalg.svd(G, compute_uv=False)
    assert np.all(sv[1:, 1] <= 1e-10 * sv[1:, 0])
    np.testing.assert_allclose(G[1:, 1, 1].real, 6.25 * G[1:, 0, 0].real, rtol=1e-9)


# ----------------------------------------------------------------------------- (c) GPS vs gyro

def test_gyro_angle_psd_matches_gps_and_coherence(testbed_cfg):
    """θ(t) = Σ sinusoids, gyro rate = its exact derivative: rate PSD/(2πf)² equals the angle PSD
    near the tones, and the GPS–gyro coherence is ~1 there (independent noise elsewhere)."""
    cfg = testbed_cfg
    rng = np.random.default_rng(11)
    n = 9000
    t = grid(n)
    tones = {1: [(0.01, 0.085), (0.004, 0.23)], 5: [(0.02, 0.16), (0.003, 0.28)]}   # q2 (g1), q6 (g4, g5)
    q = np.zeros((n, cfg.n_q))
    qd = np.zeros((n, cfg.n_q))
    for c, comps in tones.items():
        for a, f0 in comps:
            w = 2 * np.pi * f0
            q[:, c] += a * np.sin(w * t + f0)
            qd[:, c] += a * w * np.cos(w * t + f0)
    G = gyro_matrix(cfg)
    rate = qd @ G.T + 2e-5 * rng.standard_normal((n, G.shape[0]))
    q_est = q + 2e-5 * rng.standard_normal(q.shape)
    res = compute_spectra(cfg, t, q_est, t, rate, SpectraOptions())
    f = res["f_hz"]
    checks = {"g1": [0.085, 0.23], "g4": [0.16, 0.28], "g5": [0.16, 0.28]}
    for g, freqs in checks.items():
        pg, pr, coh = res["psd"][f"gps_{g}"], res["psd"][f"gyro_{g}"], res["psd"][f"coherence_{g}"]
        for f0 in freqs:
            near = np.abs(f - f0) <= 2 * (f[1] - f[0])
            np.testing.assert_allclose(pr[near], pg[near], rtol=0.05, err_msg=f"{g} at {f0} Hz")
            assert np.all(coh[near] > 0.99), (g, f0, coh[near])
        # away from the tones the two noises are independent
        quiet = (f > 1.0) & (f < 4.0)
        assert np.median(coh[quiet]) < 0.3
    # the gyro angle PSD is exactly rate-PSD / (2πf)²
    nper, nfft = int(round(res["settings"]["segment_s"] * FS)), res["settings"]["nfft"]
    fw, pw = welch(rate[:, 0], fs=FS, window="hann", nperseg=nper, noverlap=nper // 2, nfft=nfft)
    keep = fw > 0
    np.testing.assert_allclose(res["psd"]["gyro_g1"], pw[keep] / (2 * np.pi * fw[keep]) ** 2, rtol=1e-9)


# ----------------------------------------------------------------------------- (d) SDOF fit

def sdof_series(n, fs, fn, zeta, rng, burn_s=3000.0):
    """A stationary single-mode response: ZOH-discretized oscillator driven by white acceleration."""
    from scipy.signal import cont2discrete, lfilter, ss2tf

    w = 2 * np.pi * fn
    Ad, Bd, *_ = cont2discrete((np.array([[0, 1], [-w * w, -2 * zeta * w]]), np.array([[0], [1.0]]),
                                np.eye(2), np.zeros((2, 1))), 1 / fs)
    b, a = ss2tf(Ad, Bd, np.array([[1.0, 0.0]]), np.zeros((1, 1)))
    burn = int(burn_s * fs)
    return lfilter(b[0], a, rng.standard_normal(n + burn))[burn:]


@pytest.mark.parametrize("n,fn,zeta", [(3000, 0.16, 0.0077), (11400, 0.059, 0.135), (2048, 1.3, 0.05)])
def test_expected_periodogram_closed_form_matches_the_sum(n, fn, zeta):
    """Independent check of the closed form: (2/fs) Σ_{|τ|<n} (1 − |τ|/n) c(τ) cos(2πkτ/n) summed directly."""
    fs, var = 10.0, 2.5
    tau = np.arange(n) / fs
    w = 2 * np.pi * fn
    wd = w * np.sqrt(1 - zeta**2)
    c = var * np.exp(-zeta * w * tau) * (np.cos(wd * tau) + zeta / np.sqrt(1 - zeta**2) * np.sin(wd * tau))
    k = np.arange(1, n // 2, max(n // 400, 1))
    t = np.arange(1, n)
    brute = np.array([(2 / fs) * (c[0] + 2 * np.sum((1 - t / n) * c[1:] * np.cos(2 * np.pi * kk * t / n))) for kk in k])
    closed = sdof_expected_periodogram(n, fs, k, var, fn, zeta, floor=0.0)
    np.testing.assert_allclose(closed, brute, rtol=1e-9, atol=1e-12 * np.abs(brute).max())
    # and the floor is additive
    np.testing.assert_allclose(sdof_expected_periodogram(n, fs, k, var, fn, zeta, floor=0.3) - closed, 0.3, atol=1e-12)


def test_expected_periodogram_is_the_mean_periodogram():
    """Monte Carlo: the average periodogram of many simulated records equals the closed form
    (including the leakage that broadens a peak narrower than the resolution)."""
    rng = np.random.default_rng(11)
    n, fs, fn, zeta = 1200, 10.0, 0.5, 0.004           # bandwidth 0.004 Hz < resolution fs/n = 0.0083 Hz
    k = np.arange(40, 80)
    acc = np.zeros(k.size)
    runs = 400
    for _ in range(runs):
        y = sdof_series(n, fs, fn, zeta, rng, burn_s=600.0)
        acc += (2 * np.abs(np.fft.rfft(y)) ** 2 / (fs * n))[k]
    mean = acc / runs
    var = np.var(sdof_series(200000, fs, fn, zeta, rng, burn_s=600.0))
    expect = sdof_expected_periodogram(n, fs, k, var, fn, zeta)
    peak = np.argmax(expect)
    # ±4 standard errors of a 400-record mean of exponential variables, plus 3 % for the variance estimate
    assert np.all(np.abs(mean - expect) < 4 * expect / np.sqrt(runs) + 0.03 * expect), np.max(np.abs(mean / expect - 1))
    assert mean[peak] == pytest.approx(expect[peak], rel=0.25)


@pytest.mark.parametrize("fn,zeta,n", [(0.23, 0.02, 6000), (0.16, 0.0077, 11400)])
def test_sdof_whittle_fit_unbiased_and_sigma_calibrated(fn, zeta, n):
    """Maximum-likelihood fit on simulated single-mode records: the frequency is unbiased, the
    damping is not biased by the record's resolution (the second case has a half-power bandwidth of
    only 2.8 bins), and the reported σ(fn) matches the scatter."""
    fs = 10.0
    rng = np.random.default_rng(int(fn * 1000))
    out = []
    for _ in range(40):
        y = sdof_series(n, fs, fn, zeta, rng) + 0.05 * rng.standard_normal(n)
        out.append(sdof_whittle_fit(y, fs, fn * 1.01, zeta * 1.5, max(5 * 2 * zeta * fn, 0.05 * fn, 20 * fs / n)))
    fhat, zhat, sf, sz = np.array(out, dtype=float).T
    assert abs(np.mean(fhat) - fn) < 3.5 * np.std(fhat) / np.sqrt(len(fhat))
    # ζ̂ is right-skewed when the bandwidth is a few bins (its median sits below ζ), so test the mean
    assert abs(np.mean(zhat) - zeta) < 3 * np.std(zhat) / np.sqrt(len(zhat)), (np.mean(zhat) / zeta, np.median(zhat) / zeta)
    assert 0.75 < np.median(zhat) / zeta < 1.2, np.median(zhat) / zeta
    assert 0.65 < np.sqrt(np.mean(((fhat - fn) / sf) ** 2)) < 1.5
    assert 0.6 < np.sqrt(np.mean(((zhat - zeta) / sz) ** 2)) < 1.6


def test_sdof_whittle_fit_too_few_bins():
    y = np.random.default_rng(0).standard_normal(500)
    assert sdof_whittle_fit(y, 10.0, 0.5, 0.02, 0.05) == (None, None, None, None)


@pytest.mark.parametrize("fn,zeta", [(0.23, 0.02), (0.135, 0.0084), (0.059, 0.135)])
def test_efdd_exact_bell(fn, zeta):
    """EFDD on an exact SDOF singular-value bell: the correlation function's zero crossings and
    logarithmic decrement give fn and ζ."""
    f = np.fft.rfftfreq(2**16, T)
    sv = sdof_psd(f, fn, zeta)
    vecs = np.tile([0.0, 1.0, 0.0], (len(f), 1))
    vecs[np.abs(f - fn) < 10 * zeta * fn] = [1.0, 0.0, 0.0]        # the mode's shape only around its peak
    f_id, z_id, nbins = efdd(f, sv, vecs, int(np.argmax(sv)))
    assert f_id == pytest.approx(fn, rel=0.01)
    assert z_id == pytest.approx(zeta, rel=0.05)
    assert nbins > 3


# ----------------------------------------------------------------------------- (e) MAC

def test_mac_properties():
    rng = np.random.default_rng(5)
    a, b = rng.standard_normal(9), rng.standard_normal(9)
    c = rng.standard_normal(9) + 1j * rng.standard_normal(9)
    assert mac(a, a) == pytest.approx(1.0)
    assert mac(a, -3.7 * a) == pytest.approx(1.0)                      # scale invariant
    assert mac(c, (0.3 - 2j) * c) == pytest.approx(1.0)                # complex scale invariant
    assert mac(a, b) == pytest.approx(mac(b, a))                       # symmetric
    assert mac(c, a) == pytest.approx(mac(a, c))
    assert 0.0 <= mac(a, b) <= 1.0 and 0.0 <= mac(c, b) <= 1.0
    cos = a @ b / np.linalg.norm(a) / np.linalg.norm(b)
    assert mac(a, b) == pytest.approx(cos**2)                         # real vectors: cos² of the angle
    e = np.eye(4)
    assert mac(e[0], e[1]) == 0.0                                      # orthogonal
    assert mac(np.zeros(4), e[0]) == 0.0                               # degenerate: no NaN
    assert mac(e[0] + e[1], e[0]) == pytest.approx(0.5)


def test_model_mode_shapes_mac(testbed_cfg):
    """The testbed's model modes: MAC matrix has a unit diagonal and is symmetric."""
    U = np.asarray(testbed_cfg.mode_shapes)
    M = np.array([[mac(U[:, i], U[:, j]) for j in range(U.shape[1])] for i in range(U.shape[1])])
    np.testing.assert_allclose(np.diag(M), 1.0)
    np.testing.assert_allclose(M, M.T)


# ----------------------------------------------------------------------------- (f) end to end

@pytest.fixture(scope="module")
def truth_1200(testbed_cfg):
    r = simulate(testbed_cfg, SimOptions(duration_s=1200, seed=7))
    g = r.gyro.pivot_table(index="time_s", columns="gyro", values="rate_rad_s")[list(testbed_cfg.gyro_names)]
    res = compute_spectra(testbed_cfg, r.time_s, r.q, g.index.to_numpy(), g.to_numpy(), SpectraOptions())
    return r, res


CLUSTER = ("bending-1", "bending-2", "twist-2")          # 0.132, 0.135, 0.138 Hz


def test_truth_1200s_modes_identified(truth_1200, record_property):
    r, res = truth_1200
    modes = {m["mode"]: m for m in res["modes"]}
    assert len(modes) == 8 and "rigid-body" not in modes
    for name, m in modes.items():
        record_property(f"{name}_error_pct", float(round(m["error_pct"], 3)))
        if name == "pendulum":
            continue
        assert m["seen"], m
        assert abs(m["error_pct"]) < 2.0, (name, m["error_pct"])
        assert m["mac"] >= 0.8, (name, m["mac"])
    for name in CLUSTER:
        assert modes[name]["mac"] >= 0.8, (name, modes[name]["mac"])
    # The heavily damped pendulum (ζ = 0.135, half-power bandwidth 0.016 Hz): with seed 7 its
    # frequency comes out +5.5 % (0.0622 Hz vs 0.059), just outside the 5 % "seen" band.  This is
    # scatter, not bias: over 30 seeds the error is −0.6 ± 2.9 % (1σ); the same fit on the exact
    # modal coordinate gives +4.1 % for this seed.  So only a statistical bound is asserted.
    p = modes["pendulum"]
    assert abs(p["error_pct"]) < 9.0 and p["mac"] >= 0.9
    assert p["damping"] == pytest.approx(p["model_damping"], rel=0.5)
    # gyros see every mode that has a rotation at a gyro axis, and agree with GPS there
    for name in ("pendulum", "twist-1", "twist-2", "bending-3", "bending-4"):
        m = modes[name]
        assert m["gyro"] is not None and m["coherence"] > 0.99, m
        assert abs(m["gyro_hz"] - m["gps_hz"]) / m["model_hz"] < 0.05, m


def test_truth_1200s_outputs_well_formed(truth_1200):
    r, res = truth_1200
    st = res["settings"]
    assert st["sample_rate_hz"] == pytest.approx(FS)
    assert st["duration_s"] == pytest.approx(1200.1)
    assert st["segment_s"] == pytest.approx(300.0)                     # duration / 4
    assert st["segments"] == 7                                         # 50 % overlap
    assert st["resolution_hz"] == pytest.approx(1.44 / 300, rel=1e-3)
    f = res["f_hz"]
    assert np.all(np.diff(f) > 0)
    for k, v in res["psd"].items():
        assert v.shape == f.shape, k
        if k.startswith("coherence_"):
            assert np.all((v >= -1e-12) & (v <= 1 + 1e-12)), k
        else:
            assert np.all(np.isfinite(v) & (v >= 0)), k
    assert res["fdd_sv"].shape == (len(f), 3)
    assert np.all(np.diff(res["fdd_sv"], axis=1) <= 1e-12 * res["fdd_sv"].max())   # sorted singular values
    # fmax restricts the outputs only
    res2 = compute_spectra(r.cfg, r.time_s[:3000], r.q[:3000], opt=SpectraOptions(fmax_hz=1.0))
    assert res2["f_hz"][-1] <= 1.0


def test_short_60s_run_clear_result(testbed_cfg):
    """One minute (601 epochs): no crash, every mode reported with flags and the coarse resolution
    stated (segment 15 s → 0.096 Hz, wider than the mode spacing)."""
    r = simulate(testbed_cfg, SimOptions(duration_s=60, seed=7))
    g = r.gyro.pivot_table(index="time_s", columns="gyro", values="rate_rad_s")
    res = compute_spectra(testbed_cfg, r.time_s, r.q, g.index.to_numpy(), g.to_numpy(), SpectraOptions())
    assert len(res["modes"]) == 8
    assert res["settings"]["segment_s"] == pytest.approx(15.0, rel=0.01)
    assert res["settings"]["resolution_hz"] == pytest.approx(0.096, rel=0.01)
    for m in res["modes"]:
        assert isinstance(m["seen"], bool)
        if m["gps_hz"] is not None:
            assert np.isfinite(m["gps_hz"]) and np.isfinite(m["error_pct"])
            assert m["damping_resolution_limited"] in (True, False)
    # the close cluster cannot be separated by FDD at this resolution
    assert not all(m["seen"] for m in res["modes"] if m["mode"] in CLUSTER)


def test_bad_inputs(testbed_cfg):
    r = simulate(testbed_cfg, SimOptions(duration_s=30, seed=1))
    t, q = r.time_s, r.q
    with pytest.raises(CdgpsError, match="unknown coordinate.*q99"):
        compute_spectra(testbed_cfg, t, q, opt=SpectraOptions(coords=("q2", "q99")))
    t2 = t.copy()
    t2[40] += 0.03
    with pytest.raises(CdgpsError, match="regular"):
        compute_spectra(testbed_cfg, t2, q)
    with pytest.raises(CdgpsError, match="regular"):                      # a missing epoch
        compute_spectra(testbed_cfg, np.delete(t, 40), np.delete(q, 40, axis=0))
    with pytest.raises(CdgpsError, match="too short"):
        compute_spectra(testbed_cfg, t[:10], q[:10])
    for opt, option in ((SpectraOptions(overlap=1.0), "--overlap 1:"), (SpectraOptions(pad=0), "--pad 0:"),
                        (SpectraOptions(segment_s=-1.0), "--segment-s -1:")):
        with pytest.raises(CdgpsError, match=option) as e:          # each names its own option only
            compute_spectra(testbed_cfg, t, q, opt=opt)
        assert str(e.value).count("--") == 1


# ----------------------------------------------------------------------------- regressions (defects found, now fixed)

def test_nan_in_states_is_a_user_error(testbed_cfg):
    """Was: numpy LinAlgError 'SVD did not converge' (a traceback in the CLI)."""
    r = simulate(testbed_cfg, SimOptions(duration_s=30, seed=1))
    q = r.q.copy()
    q[100, 3] = np.nan
    with pytest.raises(CdgpsError, match="non-finite.*q4 at 10 s"):
        compute_spectra(testbed_cfg, r.time_s, q)
    q[100, 3] = np.inf
    with pytest.raises(CdgpsError, match="non-finite"):
        compute_spectra(testbed_cfg, r.time_s, q)


def test_decreasing_time_message(testbed_cfg):
    """Was: 'segment must be positive, pad ≥ 1, 0 ≤ overlap < 1' (negative period → negative segment)."""
    r = simulate(testbed_cfg, SimOptions(duration_s=30, seed=1))
    with pytest.raises(CdgpsError, match="not increasing"):
        compute_spectra(testbed_cfg, r.time_s[::-1], r.q)
    t = r.time_s.copy()
    t[50] = t[49]                                            # a repeated epoch
    with pytest.raises(CdgpsError, match="not increasing"):
        compute_spectra(testbed_cfg, t, r.q)


def test_gyro_blind_mode_has_no_gyro_frequency(truth_1200):
    """The swing mode moves only the translations q1, q4, q7 (|G·φ| ~ 1e-16): no gyro can see it.
    Was: assigned gyro g2 by 'weights.max() > 0' and given gyro_hz 0.1492 Hz from the flank of the
    bending peaks."""
    _, res = truth_1200
    swing = next(m for m in res["modes"] if m["mode"] == "swing")
    assert swing["gyro_hz"] is None and swing["gyro"] is None, swing
    assert swing["seen"]                                     # GPS still sees it


def test_parabolic_refinement_stays_within_half_a_bin():
    """Was: the vertex of the parabola was returned even at a non-peak index (band edge), far outside the bin."""
    f = np.arange(50) * 0.01
    y = np.exp(-((f - 0.1) ** 2) / 0.02)            # log-concave, decreasing at index 20
    assert _parabolic(f, y, 20) == f[20]
    y2 = sdof_psd(f, 0.2013, 0.05)                  # a true local maximum near bin 20: refined within half a bin
    i = int(np.argmax(y2))
    assert abs(_parabolic(f, y2, i) - 0.2013) < abs(f[i] - 0.2013) + 1e-12
    assert abs(_parabolic(f, y2, i) - f[i]) <= 0.005 + 1e-12


def test_gyro_frequency_within_its_search_band(truth_1200):
    _, res = truth_1200
    band = res["settings"]["band_pct"] / 100
    for m in res["modes"]:
        if m["gyro_hz"] is not None:
            assert abs(m["gyro_hz"] - m["gps_hz"]) <= band * m["gps_hz"] + 1e-9, m


def test_reported_frequency_sigma_is_calibrated(testbed_cfg):
    """gps_hz_sigma is the 1σ of gps_hz (Fisher information of the Whittle likelihood, no tuning):
    on simulated runs the normalized error (gps_hz − model)/σ has an RMS near 1."""
    z = []
    for seed in range(100, 112):
        r = simulate(testbed_cfg, SimOptions(duration_s=600, seed=seed))
        res = compute_spectra(testbed_cfg, r.time_s, r.q, opt=SpectraOptions())
        z += [(m["gps_hz"] - m["model_hz"]) / m["gps_hz_sigma"] for m in res["modes"]]
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.5 < rms < 1.5, rms
    assert np.mean(np.abs(z) > 3) < 0.03



@pytest.mark.parametrize("nperseg,overlap,nfft", [(256, 0.5, 1024), (333, 0.5, 1333), (500, 0.75, 2048)])
def test_welch_psd_and_coherence_match_scipy(nperseg, overlap, nfft):
    from scipy.signal import coherence
    from cdgps_cli.analysis.spectra import coherence_msc, welch_psd

    rng = np.random.default_rng(nperseg + 1)
    e = rng.standard_normal((4000, 2))
    x, y = e[:, 0] + 2.0, 0.7 * e[:, 0] + 0.5 * e[:, 1]
    kw = dict(fs=FS, window="hann", nperseg=nperseg, noverlap=int(nperseg * overlap), nfft=nfft)
    f, p = welch_psd(x, FS, nperseg, overlap, nfft)
    fw, pw = welch(x, detrend="constant", **kw)
    np.testing.assert_allclose(f, fw)
    np.testing.assert_allclose(p, pw, rtol=1e-10, atol=1e-14 * pw.max())
    _, c = coherence_msc(x, y, FS, nperseg, overlap, nfft)
    _, cw = coherence(x, y, **kw)
    np.testing.assert_allclose(c, cw, rtol=1e-9, atol=1e-12)
