"""Static mode of ``estimate``: declared rest segments (``--rest START:END``).

Inside a rest segment the process noise is multiplied by ``rest_process_noise_scale``² and, entering
it (when the estimated modal velocities pass their chi-square test), the modal position variances
are raised and the modal velocities observed as zero (a zero-velocity update); when the data
contradict the declaration the filter leaves static mode and tries again ``rest_retry_s`` later.

* linear model at rest (exact measurement model): the filter equals a textbook covariance-form
  Kalman filter with the same per-epoch Q and zero-velocity update, and the smoother a textbook RTS
  over the stored priors (independent implementation, 1e-9);
* the compiled kernel and the numpy path agree, also when a wrong declaration is broken;
* the testbed static test (Fig. 7, 2 mm noise): forward-filter angle noise below the paper's 0.02°
  and the mean within 0.1° of the survey, errors consistent with the filter's own sigma; without
  static mode the same run gives the kinematic figure;
* a declaration that starts while the structure still moves is detected, logged, and retried;
* option validation and echo.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from cdgps_cli.config.structure import load_config, parse_config
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.estimation.filter import (REST_ENTRY_POSITION_INFLATION, EstimateOptions, estimate, rest_mask,
                           validate_rest_segments, zero_velocity_update)
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.measurement.phase import all_channels, phase_model
from cdgps_cli.core.records import memory_run
from cdgps_cli.sim.structure import SimOptions, simulate

from _linear_case import LINEAR_CONFIG, LIN_SIGMA, _rel, textbook_rts
from _shared import REPO_ROOT as ROOT
from _shared import COMPILED, kernel

REST = ((8.0, 16.0), (24.0, float("inf")))


@pytest.fixture(scope="module")
def linear_rest():
    """The linear config with the structure at rest at ξ = 0 (no initial motion, no disturbance)."""
    text = LINEAR_CONFIG.replace("initial_modal_sigma = 0.2", "initial_modal_sigma = 0.0")
    assert text != LINEAR_CONFIG
    cfg = parse_config(text, "<linear at rest>")
    sim = simulate(cfg, SimOptions(duration_s=40.0, seed=4, disturbance_scale=0.0))
    assert np.abs(sim.x).max() == 0.0
    n = cfg.n_states
    rng = np.random.default_rng(2)
    M = rng.standard_normal((n, n))
    P0 = 0.02 * (M @ M.T / n + np.eye(n))
    x0 = np.linalg.cholesky(P0) @ rng.standard_normal(n)
    init = {"config_sha256": cfg.sha256, "sigma_m": LIN_SIGMA,
            "state": {"time_s": 0.0, "x": x0.tolist(), "P": P0.tolist()},
            "biases": [{"antenna": b["antenna"], "transmitter": b["transmitter"], "bias_m": b["bias_m"]}
                       for b in sim.truth["biases"]]}
    ant, tx = all_channels(cfg)
    h0, H = phase_model(cfg, np.zeros(n), ant, tx, jacobian=True)
    N = len(sim.time_s)
    Y = (sim.receiver["phase_cycles"].to_numpy() * cfg.wavelength_m).reshape(N, len(ant))
    b0 = np.array([b["bias_m"] for b in init["biases"]])
    run = memory_run(cfg, sim.receiver, name="<linear at rest>")
    return {"cfg": cfg, "sim": sim, "init": init, "run": run, "x0": x0, "P0": P0, "z": Y - b0 - h0[0], "H": H[0]}


def textbook_rest_kf(A, Q, Q_rest, H, R, z, x0, P0, at_rest, zupt_var, nm, inflation):
    """Covariance-form KF (Joseph) with Q_rest on the predictions into rest epochs and, at the first
    epoch of each rest stretch, the prior's modal position variances × (1 + inflation) and then the
    update "velocities = 0" (variances zupt_var), before the data."""
    N, p = len(z), len(x0)
    x, P = x0.copy(), P0.copy()
    xf, Pf, xp, Pp = np.empty((N, p)), np.empty((N, p, p)), np.empty((N, p)), np.empty((N, p, p))
    Hv = np.zeros((nm, p))
    Hv[:, nm:] = np.eye(nm)
    Rv = np.diag(zupt_var)
    for k in range(N):
        if k:
            x = A @ x
            P = A @ P @ A.T + (Q_rest if at_rest[k] else Q)
        entry = at_rest[k] and (k == 0 or not at_rest[k - 1])
        if entry:
            P = P.copy()
            P[np.arange(nm), np.arange(nm)] *= 1.0 + inflation
        xp[k], Pp[k] = x, P
        updates = [(Hv, Rv, np.zeros(nm))] if entry else []
        updates.append((H, R, z[k]))
        for Hk, Rk, zk in updates:
            S = Hk @ P @ Hk.T + Rk
            K = P @ Hk.T @ np.linalg.inv(S)
            x = x + K @ (zk - Hk @ x)
            IKH = np.eye(p) - K @ Hk
            P = IKH @ P @ IKH.T + K @ Rk @ K.T
        xf[k], Pf[k] = x, P
    return xf, Pf, xp, Pp


@pytest.mark.parametrize("path", ["c", "numpy"])
def test_linear_rest_equals_textbook(linear_rest, path):
    if path == "c" and not COMPILED:
        pytest.skip("cdgps_cli.estimation._ekfcore is not compiled")
    d = linear_rest
    cfg = d["cfg"]
    scale = 0.1
    with kernel(path == "c"):
        res = estimate(d["run"], d["init"], EstimateOptions(smooth=True, rest_segments_s=REST,
                                                            rest_process_noise_scale=scale))
    kinds = [e["kind"] for e in res.events]
    assert kinds == ["rest segment", "rest segment end", "rest segment"], res.events
    assert [e["time_s"] for e in res.events] == [8.0, 16.2, 24.0]
    m = discrete_model(cfg)
    Q = m.Bw @ m.W @ m.Bw.T
    at_rest = rest_mask(res.time_s, REST)
    nm = cfg.n_modes
    zupt_var = np.diag(Q)[nm:] * scale**2
    xf, Pf, xp, Pp = textbook_rest_kf(m.A, Q, Q * scale**2, d["H"], LIN_SIGMA**2 * np.eye(len(d["H"])), d["z"],
                                      d["x0"], d["P0"], at_rest, zupt_var, nm, REST_ENTRY_POSITION_INFLATION)
    xs, Ps = textbook_rts(m.A, xf, Pf, xp, Pp)
    print(f"\nlinear rest [{path}]: filter {_rel(res.x_filt, xf):.1e}, P {_rel(res.P_filt, Pf):.1e}; "
          f"smoother {_rel(res.x, xs):.1e}, P {_rel(res.P, Ps):.1e}")
    assert _rel(res.x_filt, xf) < 1e-9 and _rel(res.P_filt, Pf) < 1e-9
    assert _rel(res.x, xs) < 1e-9 and _rel(res.P, Ps) < 1e-9
    # and static mode does what it is for: at rest the smaller Q gives smaller errors than kinematic
    with kernel(path == "c"):
        kin = estimate(d["run"], d["init"], EstimateOptions())
    late = res.time_s >= 30.0
    assert np.sqrt(np.mean(res.x_filt[late, :nm] ** 2)) < 0.5 * np.sqrt(np.mean(kin.x[late, :nm] ** 2))


def same_events(a, b):
    """Event logs of the two paths: identical but for float details equal to rounding."""
    assert [{k: v for k, v in e.items() if not isinstance(v, float) or k == "time_s"} for e in a] == \
        [{k: v for k, v in e.items() if not isinstance(v, float) or k == "time_s"} for e in b]
    for ea, eb in zip(a, b):
        for k, v in ea.items():
            if isinstance(v, float) and k != "time_s":
                assert v == pytest.approx(eb[k], rel=1e-8), (k, ea, eb)


def test_zero_velocity_update_matches_joseph_textbook():
    rng = np.random.default_rng(7)
    nm, p = 3, 8                       # 3 modes + 2 bias states
    M = rng.standard_normal((p, p))
    P = M @ M.T + np.eye(p)
    x = rng.standard_normal(p)
    var = np.array([1e-4, 4e-4, 9e-4])
    x1, P1 = zero_velocity_update(x, P, nm, var)
    Hv = np.zeros((nm, p))
    Hv[:, nm:2 * nm] = np.eye(nm)
    S = Hv @ P @ Hv.T + np.diag(var)
    K = P @ Hv.T @ np.linalg.inv(S)
    np.testing.assert_allclose(x1, x - K @ (Hv @ x), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(P1, P - K @ Hv @ P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(P1, P1.T, rtol=0, atol=0)
    assert np.all(np.abs(x1[nm:2 * nm]) < np.abs(x[nm:2 * nm]))


# --------------------------------------------------------------------------------------------
# the testbed static test (1998 paper, Fig. 7)


@pytest.fixture(scope="module")
def static_case():
    tb = load_config(ROOT / "configs" / "testbed-1998-lumped.toml")
    sim = simulate(tb, SimOptions(duration_s=140.0, seed=5, scenario="static", phase_sigma_m=0.002))
    run = memory_run(tb, sim.receiver)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=60.0))
    rest = [s for s in sim.truth["segments"] if s["kind"] == "rest"][0]
    return {"tb": tb, "sim": sim, "run": run, "init": init, "rest": rest}


def _csv(tb, res, t0, t1=np.inf):
    U = np.asarray(tb.mode_shapes)
    c = U[tb.coord_names.index("q6")] + U[tb.rigid_index]
    sel = (res.time_s >= t0 - 1e-9) & (res.time_s <= t1 + 1e-9)
    ang = res.x[sel, :tb.n_modes] @ c
    sig = np.sqrt(np.einsum("i,nij,j->n", c, res.P[sel][:, :tb.n_modes, :tb.n_modes], c))
    return np.degrees(ang), np.degrees(sig)


def test_static_mode_meets_paper_figure(static_case):
    tb, rest = static_case["tb"], static_case["rest"]
    res = estimate(static_case["run"], static_case["init"], EstimateOptions(rest_segments_s=((rest["start_s"], np.inf),)))
    assert [e["kind"] for e in res.events] == ["rest segment"]
    ang, sig = _csv(tb, res, rest["start_s"])
    kin, _ = _csv(tb, estimate(static_case["run"], static_case["init"], EstimateOptions()), rest["start_s"])
    print(f"\nstatic, 2 mm: static mode mean {ang.mean():.4f}° std {ang.std():.4f}°; "
          f"kinematic std {kin.std():.4f}° (paper: < 0.02°, survey −1.4°)")
    assert abs(ang.mean() - (-1.4)) < 0.1
    assert ang.std() < 0.02                        # the paper's figure, forward filter
    assert ang.std() < 0.6 * kin.std()
    # honest sigma: errors against the true −1.4° within 3σ of the filter's own sigma
    assert np.mean(np.abs(ang - (-1.4)) < 3 * sig) > 0.95


def test_rest_declared_too_early_is_broken_and_retried(static_case):
    tb, rest = static_case["tb"], static_case["rest"]
    t_early = rest["start_s"] - 10.0                     # still settling
    res = estimate(static_case["run"], static_case["init"], EstimateOptions(rest_segments_s=((t_early, np.inf),)))
    kinds = [(e["time_s"], e["kind"]) for e in res.events]
    # at 70 s the structure still moves: refused (velocity test) or entered then broken (innovations)
    assert kinds[0][0] == t_early and kinds[0][1] in ("rest segment refused", "rest segment"), kinds
    assert kinds[-1][1] == "rest segment" and kinds[-1][0] >= t_early + 1.0 - 1e-9, kinds      # retried
    assert not any(e["kind"] in ("innovation outlier", "integrity failure") for e in res.events)
    # a retry enters only once the estimated modal velocities pass their chi-square test
    refused = [e for e in res.events if e["kind"] == "rest segment refused"]
    assert refused and all("modal velocities not zero" in e["action"] for e in refused), res.events
    assert all(e["velocity_nis"] > chi2.ppf(0.999, tb.n_modes) for e in refused)
    last = [e for e in res.events if e["kind"] == "rest segment"][-1]
    assert last["velocity_nis"] < chi2.ppf(0.999, tb.n_modes)
    ang, _ = _csv(tb, res, rest["start_s"] + 5.0)
    assert abs(ang.mean() - (-1.4)) < 0.1 and ang.std() < 0.02
    # without retries the rest of the segment stays kinematic
    once = estimate(static_case["run"], static_case["init"],
                    EstimateOptions(rest_segments_s=((t_early, np.inf),), rest_retry_s=0.0))
    assert [e["kind"] for e in once.events][-1] in ("rest segment refused", "rest segment broken")
    assert "to the segment's end" in once.events[-1]["action"]


@pytest.mark.skipif(not COMPILED, reason="cdgps_cli.estimation._ekfcore is not compiled")
@pytest.mark.parametrize("segments", [((80.0, 100.0), (110.0, 120.0)), ((70.0, np.inf),)])
def test_rest_kernel_equals_numpy(static_case, segments):
    opt = EstimateOptions(rest_segments_s=segments, smooth=True)
    with kernel(True):
        a = estimate(static_case["run"], static_case["init"], opt)
    with kernel(False):
        b = estimate(static_case["run"], static_case["init"], opt)
    assert a.filter_path == "c" and b.filter_path == "numpy"
    same_events(a.events, b.events)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-11)
    np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-13)
    np.testing.assert_allclose(a.x_filt, b.x_filt, rtol=0, atol=1e-11)
    np.testing.assert_allclose(a.nis, b.nis, rtol=1e-9)


# --------------------------------------------------------------------------------------------
# options


@pytest.mark.parametrize("segments, scale, retry, fragment", [
    (((5.0, 4.0),), 0.05, 5.0, "END must be after START"),
    (((float("nan"), 4.0),), 0.05, 5.0, "START must be a finite time"),
    (((float("-inf"), 4.0),), 0.05, 5.0, "START must be a finite time"),
    (((1.0, 2.0, 3.0),), 0.05, 5.0, "expected START:END"),
    (((1.0, 2.0),), 0.0, 5.0, "--rest-process-noise-scale"),
    (((1.0, 2.0),), float("nan"), 5.0, "--rest-process-noise-scale"),
    (((1.0, 2.0),), 0.05, -1.0, "--rest-retry-s"),
])
def test_rest_options_validated(linear_rest, segments, scale, retry, fragment):
    with pytest.raises(CdgpsError, match=fragment.replace("-", r"\-")):
        estimate(linear_rest["run"], linear_rest["init"],
                 EstimateOptions(rest_segments_s=segments, rest_process_noise_scale=scale, rest_retry_s=retry))


def test_rest_validation_lists_every_bad_segment():
    with pytest.raises(CdgpsError) as exc:
        validate_rest_segments(((5.0, 4.0), (1.0, 2.0), (float("nan"), 3.0)), 0.05)
    assert "5:4" in str(exc.value) and "nan" in str(exc.value) and "1:2" not in str(exc.value)


def test_rest_options_echoed_as_json():
    e = EstimateOptions(rest_segments_s=((80.0, float("inf")), (10.0, 20.0)), rest_process_noise_scale=0.1).echo()
    assert e["rest_segments_s"] == [[80.0, None], [10.0, 20.0]]
    assert e["rest_process_noise_scale"] == 0.1 and e["rest_retry_s"] == 1.0


# --------------------------------------------------------------------------------------------
# the smoother's priors are the filter's priors (exactness), also across breaks, refusals, lock
# restarts at those epochs, re-initializations inside a rest segment and bias states


@pytest.fixture()
def trace(monkeypatch):
    from cdgps_cli.estimation import filter as ekf_module

    rec: dict = {}
    monkeypatch.setattr(ekf_module, "_TRACE", rec)
    return rec


def prior_mismatches(rec) -> list:
    """Epochs where the filter's prior ≠ A P_{k−1} Aᵀ + Q_k + extra_q[k] (what the smoother assumes)."""
    A, Pf = rec["A"], rec["Pf"]
    bad = []
    priors = dict(rec.get("prior", {}))
    priors.update(rec.get("zupt", {}))  # at a zero-velocity update the prior is the P before it
    assert priors, "no prior recorded (numpy path?)"
    for k, Pp in sorted(priors.items()):
        if k == 0 or rec["no_link"][k - 1]:
            continue
        S = A @ Pf[k - 1] @ A.T + (rec["Q_rest"] if rec["at_rest"][k] else rec["Q"])
        for i, q in rec["extra_q"].get(k, ()):
            S[i, i] += q
        err = float(np.max(np.abs(S - Pp)) / np.max(np.abs(Pp)))
        if err > 1e-9:
            bad.append((k, err))
    return bad


def _with_lock_restart(tb, sim, t_slip):
    run = memory_run(tb, sim.receiver)
    ph = run.phase.frame()
    sel = (ph["antenna"] == "a1") & (ph["transmitter"] == "PL1") & (ph["time_s"] >= t_slip - 1e-9)
    ph.loc[sel, "lock"] = np.arange(int(sel.sum()))
    run.phase = ph
    return run


@pytest.mark.parametrize("biases", ["fixed", "states"])
@pytest.mark.parametrize("t_slip", [70.0, 73.9, 78.9])
def test_smoother_priors_equal_filter_priors(static_case, trace, biases, t_slip):
    """A lock restart on the first epoch of a declared rest (refused or entered), and later inside it."""
    tb, rest = static_case["tb"], static_case["rest"]
    run = _with_lock_restart(tb, static_case["sim"], t_slip)
    with kernel(False):
        res = estimate(run, static_case["init"], EstimateOptions(biases=biases, smooth=True,
                                                                rest_segments_s=((rest["start_s"] - 10.0, np.inf),)))
    kinds = {e["kind"] for e in res.events}
    assert {"rest segment refused", "rest segment broken"} & kinds and "rest segment" in kinds
    assert "innovation outlier" not in kinds, res.events        # the restart's inflation was kept
    assert prior_mismatches(trace) == []


@pytest.mark.parametrize("sigma_m, segments, reinit_after", [
    (0.002, ((65.0, np.inf),), 5),
    (0.003, ((60.0, 75.0),), 2),
    (0.002, ((80.0, 90.0), (100.0, 110.0)), 20),
])
def test_rest_with_reinitialization_kernel_equals_numpy(static_case, sigma_m, segments, reinit_after):
    """NIS failures inside rest segments (a 2–3 mm filter sigma on a settling structure) with the
    re-initialization flow: both paths count failures the same way and give the same result."""
    if not COMPILED:
        pytest.skip("cdgps_cli.estimation._ekfcore is not compiled")
    opt = EstimateOptions(sigma_m=sigma_m, rest_segments_s=segments, reinit_after_epochs=reinit_after, smooth=True)
    with kernel(True):
        a = estimate(static_case["run"], static_case["init"], opt)
    with kernel(False):
        b = estimate(static_case["run"], static_case["init"], opt)
    same_events(a.events, b.events)
    np.testing.assert_allclose(a.x_filt, b.x_filt, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)


def test_rest_reentered_after_reinitialization(static_case, trace):
    """A 1 mm filter sigma (half the data's noise) fails the NIS test all the time: the batch
    re-initialization restarts the filter inside the rest segment, which is then entered afresh."""
    with kernel(False):
        res = estimate(static_case["run"], static_case["init"],
                       EstimateOptions(sigma_m=0.001, rest_segments_s=((80.0, np.inf),), reinit_after_epochs=2,
                                       smooth=True))
    t = [(e["time_s"], e["kind"]) for e in res.events]
    reinit = [tt for tt, kk in t if kk == "re-initialization" and tt > 80.0]
    assert reinit, t
    assert any(kk in ("rest segment", "rest segment refused") and reinit[0] < tt < reinit[0] + 0.5 for tt, kk in t), t
    assert prior_mismatches(trace) == []


def test_rest_segment_outside_the_run_is_logged(static_case):
    res = estimate(static_case["run"], static_case["init"], EstimateOptions(rest_segments_s=((500.0, 600.0),)))
    assert [e["kind"] for e in res.events] == ["rest segment ignored"]
    assert "500–600 s" in res.events[0]["action"]


@pytest.mark.skipif(not COMPILED, reason="cdgps_cli.estimation._ekfcore is not compiled")
def test_rest_with_data_gaps_kernel_equals_numpy(static_case):
    """Every other epoch missing inside the rest segment: a NIS failure, an epoch without data, a
    failure again count as two in a row on both paths (re-initialization flow alike)."""
    tb = static_case["tb"]
    run = memory_run(tb, static_case["sim"].receiver)
    t = run.phase["time_s"]
    gap = np.isin(np.round(t, 1), np.round(np.arange(81.0, 140.0, 0.2), 1))
    run.phase = run.phase.take(~gap)
    opt = EstimateOptions(rest_segments_s=((80.0, np.inf),), sigma_m=0.0015, reinit_after_epochs=2)
    with kernel(True):
        a = estimate(run, static_case["init"], opt)
    with kernel(False):
        b = estimate(run, static_case["init"], opt)
    assert sum(e["kind"] == "integrity failure" for e in b.events) >= 2
    same_events(a.events, b.events)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)


def test_new_channel_bias_state_prior_exact(static_case, trace):
    """biases="states", a channel unknown to INIT appearing at 65 s: its bias state's restart is
    recorded as the variance actually added, so the smoother's prior is the filter's."""
    tb = static_case["tb"]
    run = memory_run(tb, static_case["sim"].receiver)
    ph = run.phase
    run.phase = ph.take(~((ph["antenna"] == "a1") & (ph["transmitter"] == "PL1") & (ph["time_s"] < 65.0)))
    init = dict(static_case["init"])
    init["biases"] = [b for b in init["biases"] if (b["antenna"], b["transmitter"]) != ("a1", "PL1")]
    with kernel(False):
        res = estimate(run, init, EstimateOptions(biases="states", smooth=True, rest_segments_s=((80.0, np.inf),)))
    assert any(e["kind"] == "new channel" for e in res.events)
    assert prior_mismatches(trace) == []


def test_huge_retry_is_not_a_crash(static_case):
    res = estimate(static_case["run"], static_case["init"],
                   EstimateOptions(rest_segments_s=((70.0, np.inf),), rest_retry_s=1e308))
    assert res.events[-1]["action"].endswith("to the segment's end")
