"""The compiled EKF kernel (``cdgps_cli.estimation._ekfcore`` through :mod:`cdgps_cli.estimation.kernel`) equals the numpy path.

* the C measurement model h(x), H(x) equals :class:`EpochPhaseModel` (1e-12) on the testbed (near
  field, sections, rigid angle; large angles), the 1995 model (far field) and a linear config
  (displacements only, no sections);
* ``estimate`` with the kernel and with ``CDGPS_NO_KERNEL=1`` agree (x, P, NIS, residuals, events,
  biases; filtered and smoothed) on runs with thruster commands, a new channel, an outage, a
  flagged slip, an unflagged slip (innovation outlier), a batch re-initialization, and on the
  far-field and linear models;
* the compiled RTS pass equals the numpy one, with the extra process noise and re-initialization
  boundaries of ``rts_smooth``;
* ``process_noise_scale``: validation, echo, and equality with a config whose process-noise sigma
  is scaled.

The kernel must have been built by ``pip install -e .`` (``test_kernel_is_built`` says so when it
was not); the comparisons switch paths with the environment variable, whatever the caller set.
"""

from __future__ import annotations

import os

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.estimation import kernel as ekf_kernel
from cdgps_cli.config.structure import load_config, parse_config
from cdgps_cli.estimation.filter import EstimateOptions, estimate, rts_smooth
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.measurement.phase import EpochPhaseModel, all_channels, phase_model
from cdgps_cli.core.records import Run
from cdgps_cli.sim.structure import SimOptions, parse_outage, parse_slip, simulate

from _linear_case import LINEAR_CONFIG, LIN_SIGMA

from _shared import COMPILED  # noqa: E402
needs_kernel = pytest.mark.skipif(not COMPILED, reason="cdgps_cli.estimation._ekfcore is not compiled")
from _shared import kernel  # noqa: E402

NO_ACTUATORS = pd.DataFrame({"time_s": pd.Series([], dtype=float), "actuator": pd.Series([], dtype=object),
                             "force_n": pd.Series([], dtype=float)})


def both_paths(run, init, opt):
    with kernel(False):
        rn = estimate(run, init, opt)
    with kernel(True):
        rc = estimate(run, init, opt)
    assert rn.filter_path == "numpy"
    assert rc.filter_path == ("c" if opt.biases == "fixed" else "numpy")
    return rc, rn


def _close(a, b, tol, what):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, what
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=what)
    ok = ~np.isnan(b)
    scale = max(float(np.max(np.abs(b[ok]), initial=0.0)), 1.0)
    diff = float(np.max(np.abs(a[ok] - b[ok]), initial=0.0))
    assert diff <= tol * scale, f"{what}: max difference {diff:.2e} (scale {scale:.2e})"
    return diff


def assert_same_result(rc, rn, tol=1e-9):
    """x, P, NIS (and dof), residuals, events, biases of two EstimateResults agree."""
    np.testing.assert_array_equal(rc.time_s, rn.time_s)
    assert rc.channels == rn.channels
    d = {"x": _close(rc.x, rn.x, tol, "x"), "P": _close(rc.P, rn.P, tol, "P"),
         "nis": _close(rc.nis, rn.nis, tol, "nis"), "residual": _close(rc.residual_m, rn.residual_m, tol, "residual")}
    np.testing.assert_array_equal(rc.nis_dof, rn.nis_dof)
    if rn.x_filt is not None:
        d["x_filt"] = _close(rc.x_filt, rn.x_filt, tol, "x_filt")
        d["P_filt"] = _close(rc.P_filt, rn.P_filt, tol, "P_filt")
    assert rc.smoothed == rn.smoothed
    assert len(rc.events) == len(rn.events)
    for ec, en in zip(rc.events, rn.events):
        assert ec.keys() == en.keys()
        for key, v in en.items():
            if isinstance(v, float):
                assert ec[key] == pytest.approx(v, rel=tol, abs=tol), (key, ec, en)
            else:
                assert ec[key] == v, (key, ec, en)
    assert rc.biases.keys() == rn.biases.keys()
    for c, b in rn.biases.items():
        assert (np.isnan(b) and np.isnan(rc.biases[c])) or rc.biases[c] == pytest.approx(b, rel=0, abs=tol)
    _same_noise(rc.noise, rn.noise, tol)
    return d


def _same_noise(a, b, tol):
    """The noise reports (σ used, the residual-based estimates, the adaptation) agree: floats to tol."""
    if isinstance(b, dict):
        assert isinstance(a, dict) and a.keys() == b.keys(), (a, b)
        for key in b:
            _same_noise(a[key], b[key], tol)
    elif isinstance(b, (list, tuple)):
        assert len(a) == len(b)
        for u, v in zip(a, b):
            _same_noise(u, v, tol)
    elif isinstance(b, float) and not isinstance(b, bool):
        assert (np.isnan(b) and np.isnan(a)) or a == pytest.approx(b, rel=tol, abs=tol), (a, b)
    else:
        assert a == b, (a, b)


# --------------------------------------------------------------------------------------------
# build and loader


def test_kernel_is_built():
    """`pip install -e .` compiles the extension (optional in setup.py, so a failed build is silent)."""
    if os.environ.get("CDGPS_NO_KERNEL", "") not in ("", "0"):
        pytest.skip("CDGPS_NO_KERNEL is set")
    assert COMPILED, ("cdgps_cli.estimation._ekfcore is missing or stale: rebuild with `pip install -e .` (needs a C "
                      "compiler and the Python headers), or set CDGPS_NO_KERNEL=1 to use the numpy path")
    assert ekf_kernel.available() and ekf_kernel.path_name() == "c"


@needs_kernel
def test_environment_variable_forces_numpy():
    with kernel(False):
        assert not ekf_kernel.available() and ekf_kernel.path_name() == "numpy"
    with kernel(True):
        assert ekf_kernel.available()


# --------------------------------------------------------------------------------------------
# measurement model


def _random_states(cfg, rng, qs):
    U = np.asarray(cfg.mode_shapes)
    q = np.vstack([qs, rng.uniform(-3, 3, (6, cfg.n_q))])
    xi = q @ np.linalg.pinv(U).T
    return np.hstack([xi, rng.normal(0, 1, xi.shape)])


@needs_kernel
@pytest.mark.parametrize("which", ["testbed", "dof2", "linear"])
def test_c_phase_models_equal_numpy(which, testbed_cfg, dof2_cfg, testbed_large_q, dof2_large_q):
    if which == "linear":
        cfg = parse_config(LINEAR_CONFIG, "<linear>")
        qs = np.random.default_rng(1).normal(0, 2, (5, cfg.n_q))
    else:
        cfg, qs = (testbed_cfg, testbed_large_q) if which == "testbed" else (dof2_cfg, dof2_large_q)
    rng = np.random.default_rng(13)
    xs = _random_states(cfg, rng, qs)
    ant, tx = all_channels(cfg)
    sub = rng.choice(len(ant), size=len(ant) // 2 + 3, replace=True)
    worst = 0.0
    for a, t in ((ant, tx), (ant[sub], tx[sub])):
        ref = EpochPhaseModel(cfg, a, t)
        fast = ekf_kernel.PhaseModel(cfg, a, t)
        for x in xs:
            h0, H0 = ref(x)
            h1, H1 = fast(x)
            assert H1.shape == H0.shape
            np.testing.assert_allclose(h1, h0, rtol=0, atol=1e-12)
            np.testing.assert_allclose(H1, H0, rtol=0, atol=1e-12)
            worst = max(worst, np.abs(h1 - h0).max(), np.abs(H1 - H0).max())
        # the initializer's batched C model (all states at once, h with or without H) against the numpy
        # phase_model, and with extra (multipath) state columns, which it ignores
        geometry = ekf_kernel.pack_geometry(cfg, a, t)
        h0, H0 = phase_model(cfg, xs, a, t, jacobian=True)
        h1, H1 = ekf_kernel.phase_model_batch(geometry, xs, jacobian=True)
        assert h1.shape == h0.shape and H1.shape == H0.shape
        np.testing.assert_allclose(h1, h0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(H1, H0, rtol=0, atol=1e-12)
        wide = np.hstack([xs, rng.normal(0, 1, (len(xs), 3))])
        np.testing.assert_array_equal(ekf_kernel.phase_model_batch(geometry, wide), h1)
    print(f"\nC model vs EpochPhaseModel ({which}): max difference {worst:.1e}")


@needs_kernel
def test_packed_geometry_is_checked(testbed_cfg):
    ant, tx = all_channels(testbed_cfg)
    gi, gf = ekf_kernel.pack_geometry(testbed_cfg, ant, tx)
    h, H = np.empty(len(ant)), np.empty((len(ant), testbed_cfg.n_modes))
    x = np.zeros(testbed_cfg.n_states)
    with pytest.raises(ValueError):
        ekf_kernel._ekfcore.phase_model(gi[:-1], gf, x, h, H)
    with pytest.raises(ValueError):
        ekf_kernel._ekfcore.phase_model(gi, gf, x[:-1], h, H)
    with pytest.raises(TypeError):
        ekf_kernel._ekfcore.phase_model(gi, gf, x.astype(np.float32), h, H)
    bad = gi.copy()
    bad[10] = 99                                       # an antenna on a section that does not exist
    with pytest.raises(ValueError):
        ekf_kernel._ekfcore.phase_model(bad, gf, x, h, H)


# --------------------------------------------------------------------------------------------
# the filter: C path = numpy path on eventful runs

EVENTFUL_SLIP = "a3:PL2:80.0:+3"
EVENTFUL_OUTAGE = "PL4:75:4"


@pytest.fixture(scope="module")
def eventful(testbed_text):
    """Testbed, 95 s: a thruster pulse at 70–71 s (after INIT), PL4 lost 75–79 s, a flagged slip at
    80 s, an unflagged 2-cycle jump on a5/PL3 at 85 s; INIT on 0–60 s without the a1/a2–PL6 biases
    (new channels at the first epoch)."""
    assert "pulse_time_s = 5.0" in testbed_text
    cfg = parse_config(testbed_text.replace("pulse_time_s = 5.0", "pulse_time_s = 70.0"), "<pulse at 70 s>")
    sim = simulate(cfg, SimOptions(duration_s=95.0, seed=11, scenario="pulse", phase_sigma_m=0.02,
                                   disturbance_scale=1.0, slips=[parse_slip(EVENTFUL_SLIP)],
                                   outages=[parse_outage(EVENTFUL_OUTAGE)]))
    rec = sim.receiver.copy()
    jump = (rec["time_s"] >= 85.0 - 1e-9) & (rec["antenna"] == "a5") & (rec["transmitter"] == "PL3")
    rec.loc[jump, "phase_cycles"] += 2
    assert sim.actuators is not None and len(sim.actuators)
    run = Run("<eventful>", cfg, rec.reset_index(drop=True), pd.DataFrame(), sim.actuators, {})
    init = initialize(run, InitOptions(start_s=0.0, duration_s=60.0))
    init["biases"] = [b for b in init["biases"] if not (b["transmitter"] == "PL6" and b["antenna"] in ("a1", "a2"))]
    return {"cfg": cfg, "run": run, "init": init, "rec": rec}


@needs_kernel
@pytest.mark.parametrize("smooth", [False, True])
def test_eventful_run_c_equals_numpy(eventful, smooth):
    rc, rn = both_paths(eventful["run"], eventful["init"], EstimateOptions(smooth=smooth))
    kinds = {e["kind"] for e in rn.events}
    assert {"new channel", "re-acquisition", "lock restart", "innovation outlier", "bias re-estimated"} <= kinds
    d = assert_same_result(rc, rn)
    print("\neventful run, C vs numpy: " + ", ".join(f"{k} {v:.1e}" for k, v in d.items()))


@needs_kernel
def test_kernel_hph_is_the_noise_estimates_term(eventful):
    """The kernel's H(x_k) P_k H(x_k)ᵀ (API 4) is the residual noise estimate's term as numpy forms
    it: the Jacobian at the filtered state (measurement.phase), the filtered covariance; written for
    the channels with a residual at the epochs the kernel ran, and nowhere else."""
    from cdgps_cli.estimation import filter as ekf_mod

    fp = ekf_mod._ForwardPass(eventful["run"], eventful["init"], EstimateOptions())
    fp.run()
    assert fp.kern is not None and fp.kern.epochs > 0
    kern = np.isfinite(fp.hph)
    assert kern.any() and not (kern & ~np.isfinite(fp.resid)).any()
    n_ker_rows = int(kern.any(axis=1).sum())
    assert 0 < n_ker_rows < int(np.isfinite(fp.resid).any(axis=1).sum())     # some epochs ran in Python
    ref = np.full_like(fp.hph, np.nan)
    ekf_mod._channel_noise_estimate(fp.cfg, fp.ant, fp.tx, fp.xs[:, :fp.n], fp.Ps, fp.resid, fp.n, ref)
    np.testing.assert_allclose(fp.hph[kern], ref[kern], rtol=1e-10, atol=0)
    # and the estimate from the kernel's term equals the all-numpy one
    sig_k, cnt_k = ekf_mod._channel_noise_estimate(fp.cfg, fp.ant, fp.tx, fp.xs[:, :fp.n], fp.Ps, fp.resid, fp.n,
                                                   fp.hph.copy())
    sig_n, cnt_n = ekf_mod._channel_noise_estimate(fp.cfg, fp.ant, fp.tx, fp.xs[:, :fp.n], fp.Ps, fp.resid, fp.n)
    np.testing.assert_array_equal(cnt_k, cnt_n)
    np.testing.assert_allclose(sig_k, sig_n, rtol=1e-12)


@needs_kernel
def test_reinitialization_c_equals_numpy(eventful):
    """Extra 6 cm noise from 86 s: persistent NIS failures, batch re-initialization on 86–92 s."""
    cfg = eventful["cfg"]
    rec = eventful["rec"].copy()
    rng = np.random.default_rng(0)
    sel = rec["time_s"] >= 86.0 - 1e-9
    rec.loc[sel, "phase_cycles"] += rng.standard_normal(int(sel.sum())) * 0.06 / cfg.wavelength_m
    run = Run("<reinit>", cfg, rec, pd.DataFrame(), eventful["run"].actuators, {})
    rc, rn = both_paths(run, eventful["init"], EstimateOptions(reinit_window_s=6.0, smooth=True))
    kinds = [e["kind"] for e in rn.events]
    assert "integrity failure" in kinds and "re-initialization" in kinds
    assert_same_result(rc, rn)


@needs_kernel
def test_far_field_c_equals_numpy(dof2_cfg):
    sim = simulate(dof2_cfg, SimOptions(duration_s=40.0, seed=4, phase_sigma_m=0.01, slips=[parse_slip("s3:S2:20.04:-2")]))
    run = Run("<dof2>", dof2_cfg, sim.receiver.reset_index(drop=True), pd.DataFrame(), NO_ACTUATORS, {})
    init = initialize(run, InitOptions(start_s=0.0, duration_s=2.4, process_noise=False))
    rc, rn = both_paths(run, init, EstimateOptions(smooth=True))
    assert any(e["kind"] == "lock restart" for e in rn.events)
    assert_same_result(rc, rn)


@needs_kernel
@pytest.mark.parametrize("biases", ["fixed", "states"])
def test_linear_model_c_equals_numpy(biases):
    """Displacement-only antennas (no sections, no rigid angle), a slip; biases="states" runs the numpy
    filter and the compiled smoother (with the slip's variance inflation)."""
    cfg = parse_config(LINEAR_CONFIG, "<linear>")
    sim = simulate(cfg, SimOptions(duration_s=40.0, seed=3, slips=[parse_slip("r2:S3:12.0:+3")]))
    n = cfg.n_states
    rng = np.random.default_rng(1)
    M = rng.standard_normal((n, n))
    P0 = 0.05 * (M @ M.T / n + np.eye(n))
    init = {"config_sha256": cfg.sha256, "sigma_m": LIN_SIGMA,
            "state": {"time_s": 0.0, "x": (sim.x[0] + 0.01).tolist(), "P": P0.tolist()},
            "biases": [{"antenna": b["antenna"], "transmitter": b["transmitter"], "bias_m": b["bias_m"]}
                       for b in sim.truth["biases"]]}
    run = Run("<linear>", cfg, sim.receiver.reset_index(drop=True), pd.DataFrame(), NO_ACTUATORS, {})
    rc, rn = both_paths(run, init, EstimateOptions(biases=biases, smooth=True))
    assert any(e["kind"] == "lock restart" for e in rn.events)
    assert_same_result(rc, rn)


# --------------------------------------------------------------------------------------------
# the smoother pass


@needs_kernel
@pytest.mark.parametrize("in_place", [False, True])
def test_compiled_rts_equals_numpy(in_place):
    rng = np.random.default_rng(3)
    p, nu, N = 7, 2, 60
    A = 0.95 * np.eye(p) + 0.1 * rng.standard_normal((p, p)) * (rng.random((p, p)) < 0.4)     # sparse
    Q = 0.01 * np.diag(rng.random(p) + 0.1)
    B = rng.standard_normal((p, nu))
    U_in = rng.standard_normal((N, nu))
    xf = rng.standard_normal((N, p))
    M = rng.standard_normal((N, p, p))
    Pf = M @ M.transpose(0, 2, 1) / p + 0.1 * np.eye(p)
    extra_q = {5: [(2, 0.3)], 17: [(0, 0.1), (4, 0.2), (0, 0.05)], N: [(1, 9.0)]}
    no_link = np.zeros(N, dtype=bool)
    no_link[30:34] = True
    with kernel(False):
        xs_n, Ps_n = rts_smooth(A, Q, B, U_in, xf.copy(), Pf.copy(), extra_q, no_link, in_place=in_place)
    with kernel(True):
        xf_c, Pf_c = xf.copy(), Pf.copy()
        xs_c, Ps_c = rts_smooth(A, Q, B, U_in, xf_c, Pf_c, extra_q, no_link, in_place=in_place)
    assert (xs_c is xf_c) == in_place
    if not in_place:
        np.testing.assert_array_equal(xf_c, xf)                   # inputs untouched
    np.testing.assert_allclose(xs_c, xs_n, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(Ps_c, Ps_n, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(xs_c[30:34], xf[30:34])         # not linked: left as filtered
    np.testing.assert_array_equal(xs_c[-1], xf[-1])


@needs_kernel
def test_compiled_rts_raises_on_indefinite_prediction():
    p, N = 3, 4
    xf = np.zeros((N, p))
    Pf = np.broadcast_to(np.eye(p), (N, p, p)).copy()
    with kernel(True), pytest.raises(np.linalg.LinAlgError):
        rts_smooth(np.eye(p), -2.0 * np.eye(p), np.zeros((p, 0)), np.zeros((N, 0)), xf, Pf)


# --------------------------------------------------------------------------------------------
# process_noise_scale


@pytest.fixture(scope="module")
def linear_run():
    cfg = parse_config(LINEAR_CONFIG, "<linear>")
    sim = simulate(cfg, SimOptions(duration_s=30.0, seed=5))
    n = cfg.n_states
    init = {"config_sha256": cfg.sha256, "sigma_m": LIN_SIGMA,
            "state": {"time_s": 0.0, "x": sim.x[0].tolist(), "P": (0.05 * np.eye(n)).tolist()},
            "biases": [{"antenna": b["antenna"], "transmitter": b["transmitter"], "bias_m": b["bias_m"]}
                       for b in sim.truth["biases"]]}
    return {"cfg": cfg, "sim": sim, "init": init,
            "run": Run("<linear>", cfg, sim.receiver.reset_index(drop=True), pd.DataFrame(), NO_ACTUATORS, {})}


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), True, "2"])
def test_process_noise_scale_validated(linear_run, bad):
    with pytest.raises(CdgpsError, match="process-noise-scale"):
        estimate(linear_run["run"], linear_run["init"], EstimateOptions(process_noise_scale=bad))


def test_process_noise_scale_echoed():
    assert EstimateOptions().echo()["process_noise_scale"] == 1.0
    assert EstimateOptions(process_noise_scale=2.5).echo()["process_noise_scale"] == 2.5


@pytest.mark.parametrize("path", ["c", "numpy"])
@pytest.mark.parametrize("biases", ["fixed", "states"])
def test_process_noise_scale_equals_scaled_config(linear_run, path, biases):
    """scale s on the options = the config's process-noise sigma × s (filter and smoother)."""
    if path == "c" and not COMPILED:
        pytest.skip("cdgps_cli.estimation._ekfcore is not compiled")
    text = LINEAR_CONFIG
    assert "sigma = [0.2, 0.3, 0.4]" in text
    cfg2 = parse_config(text.replace("sigma = [0.2, 0.3, 0.4]", "sigma = [0.6, 0.9, 1.2]"), "<linear ×3>")
    run2 = Run("<linear ×3>", cfg2, linear_run["run"].phase, pd.DataFrame(), NO_ACTUATORS, {})
    init2 = dict(linear_run["init"], config_sha256=cfg2.sha256)
    with kernel(path == "c"):
        a = estimate(linear_run["run"], linear_run["init"], EstimateOptions(biases=biases, smooth=True, process_noise_scale=3.0))
        b = estimate(run2, init2, EstimateOptions(biases=biases, smooth=True))
        one = estimate(linear_run["run"], linear_run["init"], EstimateOptions(biases=biases, smooth=True))
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.x_filt, b.x_filt, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.nis, b.nis, rtol=1e-12)
    assert np.max(np.abs(a.P - one.P)) > 1e-6                       # and it does change the estimate
