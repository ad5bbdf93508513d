"""EKF and RTS smoother (Teague, How & Parkinson 1998 Eq. 16–23): ``cdgps_cli.estimation.filter.estimate``.

* fast single-epoch kinematics / measurement model equal the vectorized reference (1e-12);
* filter math, independently: on a config whose h(x) is exactly linear the filter equals a
  textbook covariance-form Kalman filter (Joseph update) and the RTS smoother equals the batch
  least-squares solution of :func:`cdgps_cli.estimation.batch_solver.srif_solve` with the same prior;
* testbed truth: NEES / NIS consistency, convergence from a perturbed INIT, the 1995 model's
  q1/q2 accuracy, the static test of Fig. 7, cycle slips (flagged and unflagged), a transmitter
  outage, a transmitter first seen after INIT, bias states;
* ``lock_events`` on a hand-made matrix;
* integrity: re-initialization after persistent NIS failures (no unset epochs, smoothing across it),
  STATES with an innovation-outlier event read back.

The slip / outage / late-transmitter runs reuse the free-vibration run's seed, so their data before
the injected event are identical (checked) and one batch INIT serves them all.

Figures are printed (``pytest -s``) so a run shows what the filter reaches.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.linalg import solve_discrete_are, solve_discrete_lyapunov

from cdgps_cli.estimation.batch_solver import LinearProblem, srif_solve
from cdgps_cli.config.structure import load_config, parse_config
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.estimation.filter import EstimateOptions, estimate, lock_events
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.model.kinematics import EpochGeometry, antenna_positions
from cdgps_cli.measurement.phase import EpochPhaseModel, all_channels, phase_model
from cdgps_cli.core.records import memory_run
from cdgps_cli.io.run import read_run, write_run
from cdgps_cli.sim.structure import SimOptions, parse_outage, parse_slip, simulate, write_simulation
from cdgps_cli.pipeline.estimate_outputs import write_states, evaluate

ROOT = Path(__file__).resolve().parents[2]
from _linear_case import LIN_SIGMA, LIN_SLIP, LINEAR_CONFIG, _rel, textbook_kf, textbook_rts  # noqa: E402
TESTBED_PATH = ROOT / "configs" / "testbed-1998-lumped.toml"
DOF2_PATH = ROOT / "configs" / "teague-1995-2dof.toml"


# --------------------------------------------------------------------------------------------
# helpers




def file_run(cfg, sim, out_dir):
    """simulate → receiver.csv/truth → RUN.mcap → read_run (the real pipeline)."""
    write_simulation(sim, out_dir)
    write_run(cfg, out_dir / "receiver.csv", out_dir / "run.mcap")
    return read_run(out_dir / "run.mcap")


def coord_errors(cfg, sim, res):
    """Coordinate errors (N, n_q), 1-σ (N, n_q) and times of an EstimateResult against truth."""
    U = np.asarray(cfg.mode_shapes)
    nm = cfg.n_modes
    k = np.rint(res.time_s / cfg.sample_period_s).astype(int)
    err = res.x[:, :nm] @ U.T - sim.q[k]
    sig = np.sqrt(np.maximum(np.einsum("qi,nij,qj->nq", U, res.P[:, :nm, :nm], U), 0.0))
    return err, sig, res.time_s


def settle_time(t, ok, t_from, hold_s=1.0):
    """Seconds from t_from to the first epoch from which ``ok`` holds for ``hold_s`` (None: never)."""
    T = float(np.median(np.diff(t)))
    w = int(round(hold_s / T))
    for i in np.flatnonzero(t >= t_from - 1e-9):
        if i + w <= len(ok) and ok[i:i + w].all():
            return float(t[i] - t_from)
    return None


def truth_bias(sim, t_end=np.inf):
    """(antenna, transmitter) → bias (m) of the segment current at t_end (slips / re-acquisitions)."""
    b = {(r["antenna"], r["transmitter"]): r["bias_m"] for r in sim.truth["biases"]}
    for s in sim.truth["slips"]:
        if s["time_s"] <= t_end + 1e-9:
            b[(s["antenna"], s["transmitter"])] = s["bias_m"]
    return b


@pytest.fixture(scope="module")
def tb():
    return load_config(TESTBED_PATH)


@pytest.fixture(scope="module")
def d2():
    return load_config(DOF2_PATH)


# --------------------------------------------------------------------------------------------
# fast single-epoch models = vectorized reference


def _modal(cfg, q, rng):
    U = np.asarray(cfg.mode_shapes)
    xi = q @ np.linalg.pinv(U).T
    return np.hstack([xi, rng.normal(0, 1, xi.shape)])


@pytest.mark.parametrize("which", ["testbed", "dof2"])
def test_epoch_geometry_equals_antenna_positions(which, testbed_cfg, dof2_cfg, testbed_large_q, dof2_large_q):
    cfg, qs = (testbed_cfg, testbed_large_q) if which == "testbed" else (dof2_cfg, dof2_large_q)
    geo = EpochGeometry(cfg)
    rng = np.random.default_rng(3)
    qs = np.vstack([qs, rng.uniform(-3, 3, (5, cfg.n_q))])        # also fully random large states
    p_ref, J_ref = antenna_positions(cfg, qs, jacobian=True)
    for k, q in enumerate(qs):
        p, J = geo.positions(q)
        np.testing.assert_allclose(p, p_ref[k], rtol=0, atol=1e-12)
        np.testing.assert_allclose(J, J_ref[k], rtol=0, atol=1e-12)
        np.testing.assert_allclose(geo.positions(q, jacobian=False), p_ref[k], rtol=0, atol=1e-12)


@pytest.mark.parametrize("which", ["testbed", "dof2"])
def test_epoch_phase_model_equals_phase_model(which, testbed_cfg, dof2_cfg, testbed_large_q, dof2_large_q):
    cfg, qs = (testbed_cfg, testbed_large_q) if which == "testbed" else (dof2_cfg, dof2_large_q)
    rng = np.random.default_rng(5)
    xs = _modal(cfg, qs, rng)
    ant, tx = all_channels(cfg)
    # all channels, and a shuffled subset with repeats (the filter's channel list is arbitrary)
    sub = rng.choice(len(ant), size=len(ant) // 2 + 3, replace=True)
    for a, t in ((ant, tx), (ant[sub], tx[sub])):
        model = EpochPhaseModel(cfg, a, t)
        h_ref, H_ref = phase_model(cfg, xs, a, t, jacobian=True)
        for k, x in enumerate(xs):
            h, H = model(x)
            np.testing.assert_allclose(h, h_ref[k], rtol=0, atol=1e-12)
            np.testing.assert_allclose(H, H_ref[k], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------------------------
# filter math on an exactly linear model



@pytest.fixture(scope="module")
def linear():
    """Linear config, a 40 s simulation (one run without, one with a cycle slip), a hand-made INIT
    (state perturbed from truth by a draw from P0, biases = truth), and the exact linear model."""
    cfg = parse_config(LINEAR_CONFIG, "<linear>")
    n = cfg.n_states
    ant, tx = all_channels(cfg)
    h0, H = phase_model(cfg, np.zeros(n), ant, tx, jacobian=True)
    h0, H = h0[0], H[0]
    rng = np.random.default_rng(1)
    xr = rng.standard_normal((4, n))
    assert np.abs(phase_model(cfg, xr, ant, tx) - (h0 + xr @ H.T)).max() < 1e-14     # really linear
    out = {"cfg": cfg, "h0": h0, "H": H}
    for key, slips in (("clean", []), ("slip", [parse_slip(LIN_SLIP)])):
        sim = simulate(cfg, SimOptions(duration_s=40.0, seed=3, slips=slips))
        M = rng.standard_normal((n, n))
        P0 = 0.05 * (M @ M.T / n + np.eye(n))
        x0 = sim.x[0] + np.linalg.cholesky(P0) @ rng.standard_normal(n)
        init = {"config_sha256": cfg.sha256, "sigma_m": LIN_SIGMA,
                "state": {"time_s": 0.0, "x": x0.tolist(), "P": P0.tolist()},
                "biases": [{"antenna": b["antenna"], "transmitter": b["transmitter"], "bias_m": b["bias_m"]}
                           for b in sim.truth["biases"]]}
        N = len(sim.time_s)
        ph = sim.receiver
        assert list(zip(ph.antenna[:len(ant)], ph.transmitter[:len(ant)])) == cfg.channels
        Y = (ph["phase_cycles"].to_numpy() * cfg.wavelength_m).reshape(N, len(ant))
        out[key] = {"sim": sim, "run": memory_run(cfg, sim.receiver), "init": init, "x0": x0, "P0": P0, "Y": Y,
                    "b0": np.array([init["biases"][c]["bias_m"] for c in range(len(ant))])}
    return out


@pytest.mark.parametrize("no_kernel", ["", "1"])
def test_linear_filter_equals_textbook_kalman(linear, no_kernel, monkeypatch):
    """Both forward paths: the compiled kernel (when built) and the numpy path, whose every epoch is
    the engine's step (kalman.StepFilter.predict, kalman.update)."""
    monkeypatch.setenv("CDGPS_NO_KERNEL", no_kernel)
    cfg, H, h0 = linear["cfg"], linear["H"], linear["h0"]
    d = linear["clean"]
    res = estimate(d["run"], d["init"], EstimateOptions(smooth=True))
    assert res.events == []
    if no_kernel:
        assert res.filter_path == "numpy"
    m = discrete_model(cfg)
    z = d["Y"] - d["b0"] - h0
    xf, Pf, _, _, nis = textbook_kf(m.A, m.Bw @ m.W @ m.Bw.T, H, LIN_SIGMA**2 * np.eye(len(h0)), z, d["x0"], d["P0"])
    print(f"\nlinear KF: max |Δx|/max|x| {_rel(res.x_filt, xf):.1e}, max |ΔP|/max|P| {_rel(res.P_filt, Pf):.1e}")
    assert _rel(res.x_filt, xf) < 1e-9
    assert _rel(res.P_filt, Pf) < 1e-9
    np.testing.assert_allclose(res.nis, nis, rtol=1e-8)
    assert np.all(res.nis_dof == len(h0))
    # post-fit residuals are y − h(x̂) − b for a linear h
    np.testing.assert_allclose(res.residual_m, z - xf @ H.T, rtol=0, atol=1e-9)


def test_linear_smoother_equals_batch_least_squares(linear):
    """RTS smoother = argmin of the batch cost with prior x₁ ~ N(x0, P0), known biases (SRIF)."""
    cfg, H, h0 = linear["cfg"], linear["H"], linear["h0"]
    d = linear["clean"]
    res = estimate(d["run"], d["init"], EstimateOptions(smooth=True))
    assert res.smoothed
    m = discrete_model(cfg)
    N = len(res.time_s)
    L = np.linalg.cholesky(d["P0"])
    prob = LinearProblem(A=m.A, Bw_L=m.Bw @ np.sqrt(m.W), H=np.broadcast_to(H, (N,) + H.shape).copy(),
                         y=d["Y"] - d["b0"] - h0, bias_index=np.full((N, len(h0)), -1), n_bias=0,
                         sigma_m=LIN_SIGMA, x1_mean=d["x0"], x1_sqrt_info=np.linalg.inv(L),
                         b_mean=np.zeros(0), b_sqrt_info=np.zeros((0, 0)))
    sol = srif_solve(prob)
    print(f"\nlinear RTS vs SRIF batch: max rel diff {_rel(res.x, sol.x):.1e}")
    assert _rel(res.x, sol.x) < 1e-8
    # last epoch: smoothed = filtered, and its covariance is the batch's marginal covariance
    np.testing.assert_allclose(res.x[-1], res.x_filt[-1], rtol=0, atol=1e-15)
    assert _rel(res.P[-1], sol.P_end) < 1e-8
    # smoothing never increases the variance
    assert np.all(np.diagonal(res.P, axis1=1, axis2=2) <= np.diagonal(res.P_filt, axis1=1, axis2=2) * (1 + 1e-9))


def test_linear_bias_states_with_slip_equal_textbook(linear):
    """biases="states" (1995 variant): augmented textbook KF, the lock restart's variance
    inflation at the slip epoch, and a textbook RTS pass that knows about that inflation."""
    cfg, H, h0 = linear["cfg"], linear["H"], linear["h0"]
    d = linear["slip"]
    opt = EstimateOptions(biases="states", smooth=True)
    res = estimate(d["run"], d["init"], opt)
    C, n = len(h0), cfg.n_states
    slip = parse_slip(LIN_SLIP)
    c_slip = cfg.channels.index((slip.antenna, slip.transmitter))
    k_slip = int(round(slip.time_s / cfg.sample_period_s))
    assert [(e["time_s"], e["antenna"], e["transmitter"], e["kind"]) for e in res.events] == \
        [(slip.time_s, slip.antenna, slip.transmitter, "lock restart")]
    m = discrete_model(cfg)
    A = np.eye(n + C)
    A[:n, :n] = m.A
    Q = np.zeros((n + C, n + C))
    Q[:n, :n] = m.Bw @ m.W @ m.Bw.T
    Q[n:, n:] = np.eye(C) * opt.bias_process_sigma_m**2
    Ha = np.hstack([H, np.eye(C)])
    x0 = np.concatenate([d["x0"], d["b0"]])
    P0 = np.zeros((n + C, n + C))
    P0[:n, :n] = d["P0"]
    P0[n:, n:] = np.eye(C) * LIN_SIGMA**2
    q_slip = (opt.restart_sigma_cycles * cfg.wavelength_m) ** 2
    xf, Pf, xp, Pp, nis = textbook_kf(A, Q, Ha, LIN_SIGMA**2 * np.eye(C), d["Y"] - h0, x0, P0,
                                      inflate={k_slip: [(n + c_slip, q_slip)]})
    assert _rel(res.x_filt, xf[:, :n]) < 1e-9
    assert _rel(res.P_filt, Pf[:, :n, :n]) < 1e-9
    np.testing.assert_allclose(res.nis, nis, rtol=1e-8)
    xs, Ps = textbook_rts(A, xf, Pf, xp, Pp)
    assert _rel(res.x, xs[:, :n]) < 1e-8
    assert _rel(res.P, Ps[:, :n, :n]) < 1e-8
    # final bias states: the slipped channel took the 3-cycle jump
    tb = truth_bias(d["sim"])
    fb = np.array([res.biases[c] for c in cfg.channels])
    np.testing.assert_allclose(fb, xf[-1, n:], rtol=0, atol=1e-12)
    assert np.max(np.abs(fb - np.array([tb[c] for c in cfg.channels]))) < 0.01


# --------------------------------------------------------------------------------------------
# testbed truth: consistency (NEES, NIS) and convergence


@pytest.fixture(scope="module")
def testbed_free(tb, tmp_path_factory):
    """120 s free vibration, 2 cm phase noise (the filter's sigma), full process noise; INIT on 0–60 s."""
    d = tmp_path_factory.mktemp("tb_free")
    sim = simulate(tb, SimOptions(duration_s=120.0, seed=11, phase_sigma_m=0.02, disturbance_scale=1.0))
    run = file_run(tb, sim, d)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=60.0))
    assert init["n_fixed"] == 36
    return {"dir": d, "sim": sim, "run": run, "init": init}


def test_testbed_nees_nis_consistent(testbed_free):
    f = testbed_free
    res = estimate(f["run"], f["init"], EstimateOptions())
    assert res.events == []
    init_text = json.dumps(f["init"])
    write_states(res, f["dir"] / "run.mcap", f["init"], init_text, f["dir"] / "states.mcap", {})
    ev = evaluate(f["dir"], f["dir"] / "states.mcap")
    nees, nis = ev["nees"], ev["nis"]
    dof = nees["dof"]
    print(f"\ntestbed NEES mean {nees['mean']:.2f} (dof {dof}), {100 * nees['fraction_in_interval']:.1f}% in the 95% "
          f"interval; NIS/dof {nis['mean_per_dof']:.3f}; within 3σ {100 * ev['within_3sigma_fraction']:.1f}%")
    assert dof == 9
    assert 0.6 * dof <= nees["mean"] <= 1.5 * dof
    assert nees["fraction_in_interval"] >= 0.85
    assert 0.8 <= nis["mean_per_dof"] <= 1.2
    assert 0.90 <= nis["fraction_in_interval95"] <= 0.99
    assert ev["within_3sigma_fraction"] >= 0.95
    assert ev["bias_error"]["rms_m"] == 0.0 and ev["bias_error"]["wrong_integers"] == 0


def test_convergence_from_perturbed_init_within_1s(tb, testbed_free):
    """INIT state off by 3σ in every state plus 2° on the rigid angle, covariance ×100 (as a prior at
    the window end: without INIT's window, so the STATES are the filter's from there)."""
    f = testbed_free
    init = {k: v for k, v in f["init"].items() if k != "window"}
    x0 = np.asarray(init["state"]["x"])
    P0 = np.asarray(init["state"]["P"])
    rng = np.random.default_rng(2)
    U = np.asarray(tb.mode_shapes)
    j_rigid = int(np.flatnonzero(np.asarray(tb.mode_frequency_hz) == 0)[0])
    x = x0 + 3 * np.sqrt(np.diag(P0)) * rng.choice([-1.0, 1.0], x0.size)
    x[j_rigid] += np.radians(2.0) / U[tb.rigid_index, j_rigid]
    bad = dict(init, state=dict(init["state"], x=x.tolist(), P=(100 * P0).tolist()))
    res = estimate(f["run"], bad, EstimateOptions())
    nominal = estimate(f["run"], init, EstimateOptions())
    assert res.events == []
    err, sig, t = coord_errors(tb, f["sim"], res)
    e0, s0, _ = coord_errors(tb, f["sim"], nominal)
    ok = np.all(np.abs(err) <= 3 * sig, axis=1)
    t_conv = settle_time(t, ok, t[0])
    t_nom = settle_time(t, np.all(np.abs(err) <= 3 * s0, axis=1), t[0])
    print(f"\nperturbed INIT: within 3σ (own σ) for 1 s from {t_conv} s; within 3σ of the unperturbed filter's σ "
          f"from {t_nom} s")
    assert t_conv is not None and t_conv <= 1.0
    # after 1 s: as consistent as the unperturbed filter
    after = t >= t[0] + 1.0
    assert np.mean(np.abs(err[after]) <= 3 * sig[after]) >= 0.99
    # the initial error is forgotten: after 10 s the two runs agree to a small fraction of σ
    late = t >= t[0] + 10.0
    forgot = np.max(np.abs(res.x[late] - nominal.x[late]) / np.sqrt(np.diagonal(nominal.P[late], axis1=1, axis2=2)))
    print(f"  after 10 s the perturbed and nominal runs differ by at most {forgot:.3f} σ")
    assert forgot < 0.25


def test_bias_states_final_biases_within_1cm(tb, testbed_free):
    f = testbed_free
    res = estimate(f["run"], f["init"], EstimateOptions(biases="states"))
    tb_b = truth_bias(f["sim"])
    errs = np.array([res.biases[c] - tb_b[c] for c in tb.channels])
    print(f"\nbiases=states: final bias errors max {1000 * np.max(np.abs(errs)):.2f} mm")
    assert np.max(np.abs(errs)) < 0.01
    err, sig, t = coord_errors(tb, f["sim"], res)
    assert np.mean(np.abs(err) <= 3 * sig) >= 0.99


# --------------------------------------------------------------------------------------------
# the 1995 two-hub model


@pytest.fixture(scope="module")
def dof2_run(d2):
    sim = simulate(d2, SimOptions(duration_s=60.0, seed=4, phase_sigma_m=0.01))
    run = memory_run(d2, sim.receiver)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=2.4, process_noise=False))
    return {"sim": sim, "run": run, "init": init}


@pytest.mark.parametrize("biases", ["fixed", "states"])
def test_dof2_q1_q2_rms_below_0_3_deg(d2, dof2_run, biases):
    res = estimate(dof2_run["run"], dof2_run["init"], EstimateOptions(biases=biases))
    err, sig, t = coord_errors(d2, dof2_run["sim"], res)
    after = t >= t[0] + 1.0
    rms = np.degrees(np.sqrt(np.mean(err[after] ** 2, axis=0)))
    print(f"\n1995 model, INIT on 2.4 s without process noise, biases={biases}: RMS q1 {rms[0]:.3f}°, q2 {rms[1]:.3f}° "
          f"(integers: {dof2_run['init']['integer_fixing']})")
    assert np.all(rms < 0.3)
    assert np.mean(np.abs(err[after]) <= 3 * sig[after]) >= 0.97
    if biases == "states":
        tb_b = truth_bias(dof2_run["sim"])
        assert max(abs(res.biases[c] - tb_b[c]) for c in d2.channels) < 0.01


# --------------------------------------------------------------------------------------------
# static test (Fig. 7): 2 mm noise, structure at rest at the surveyed −1.4°


@pytest.fixture(scope="module")
def static_run(tb):
    sim = simulate(tb, SimOptions(duration_s=140.0, seed=5, scenario="static", phase_sigma_m=0.002))
    run = memory_run(tb, sim.receiver)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=60.0))
    rest = [s for s in sim.truth["segments"] if s["kind"] == "rest"][0]
    return {"sim": sim, "run": run, "init": init, "rest": rest}


def _csv_angle_stats(tb, res, rest):
    U = np.asarray(tb.mode_shapes)
    q = res.x[:, :tb.n_modes] @ U.T
    sel = (res.time_s >= rest["start_s"] - 1e-9) & (res.time_s <= rest["end_s"] + 1e-9)
    csv = np.degrees(q[sel, tb.coord_names.index("q6")] + q[sel, tb.rigid_index])
    return float(csv.mean()), float(csv.std())


def _steady_state_csv_std_deg(tb, sigma_filter, sigma_true):
    """Predicted std of q6+q10 for a structure at rest: steady-state gain (DARE) of the filter's
    model with R = sigma_filter², error driven by white phase noise sigma_true and no disturbance."""
    m = discrete_model(tb)
    U = np.asarray(tb.mode_shapes)
    ant, tx = all_channels(tb)
    xr = np.zeros(tb.n_states)
    xr[:tb.n_modes] = np.linalg.pinv(U) @ np.radians(np.r_[np.zeros(9), -1.4])
    H = phase_model(tb, xr, ant, tx, jacobian=True)[1][0]
    R = sigma_filter**2 * np.eye(len(ant))
    Pp = solve_discrete_are(m.A.T, H.T, m.Q, R)
    Pu = np.linalg.inv(np.linalg.inv(Pp) + H.T @ H / sigma_filter**2)
    K = Pu @ H.T / sigma_filter**2
    F = (np.eye(tb.n_states) - K @ H) @ m.A
    Pe = solve_discrete_lyapunov(F, sigma_true**2 * K @ K.T)
    c = U[tb.coord_names.index("q6")] + U[tb.rigid_index]
    return float(np.degrees(np.sqrt(c @ Pe[:tb.n_modes, :tb.n_modes] @ c)))


@pytest.mark.parametrize("sigma_m", [None, 0.002])
def test_static_angle_mean_and_noise(tb, static_run, sigma_m):
    res = estimate(static_run["run"], static_run["init"], EstimateOptions(sigma_m=sigma_m))
    assert res.events == []
    mean, std = _csv_angle_stats(tb, res, static_run["rest"])
    sig_f = sigma_m or static_run["init"]["sigma_m"]
    predicted = _steady_state_csv_std_deg(tb, sig_f, 0.002)
    print(f"\nstatic, filter sigma {sig_f} m: q6+q10 mean {mean:.4f}° (survey −1.4°), std {std:.4f}° "
          f"(steady-state prediction {predicted:.4f}°; paper: < 0.02°)")
    assert abs(mean - (-1.4)) < 0.1
    assert abs(std / predicted - 1) < 0.3          # the filter does what its model predicts
    assert std < 0.06


@pytest.mark.xfail(strict=True, reason=(
    "the kinematic filter (no --rest) does not reach the paper's < 0.02° rms at 2 mm noise with "
    "configs/testbed-1998-lumped.toml: its pseudolite geometry gives a single-epoch least-squares std of "
    "0.052° for q6+q10 and the 0.5 modal process noise keeps the filter close to single-epoch (steady "
    "state 0.032° with σ=2 cm, 0.046° with σ=2 mm); static mode (--rest, tests/estimation/test_filter_rest.py) does"))
def test_static_angle_noise_paper_figure(tb, static_run):
    res = estimate(static_run["run"], static_run["init"], EstimateOptions())
    assert _csv_angle_stats(tb, res, static_run["rest"])[1] < 0.02


# --------------------------------------------------------------------------------------------
# cycle slips, outages, channels first seen after INIT

SLIP = "a3:PL2:80.0:+3"
OUTAGE = "PL4:70:10"


def same_seed_variant(tb, testbed_free, t_change, **extra):
    """testbed_free's simulation (same seed, duration, noise) with slips / outages added: the data
    before ``t_change`` are identical, so testbed_free's INIT (window 0–60 s) applies unchanged."""
    base = testbed_free["sim"]
    sim = simulate(tb, SimOptions(duration_s=120.0, seed=11, phase_sigma_m=0.02, disturbance_scale=1.0, **extra))
    a = base.receiver[base.receiver["time_s"] < t_change - 1e-9].reset_index(drop=True)
    b = sim.receiver[sim.receiver["time_s"] < t_change - 1e-9].reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b)
    np.testing.assert_array_equal(base.q, sim.q)
    return sim


@pytest.fixture(scope="module")
def slip_run(tb, testbed_free):
    sim = same_seed_variant(tb, testbed_free, 80.0, slips=[parse_slip(SLIP)])
    return {"sim": sim, "run": memory_run(tb, sim.receiver), "init": testbed_free["init"]}


def test_cycle_slip_detected_and_recovered(tb, slip_run):
    s = parse_slip(SLIP)
    res = estimate(slip_run["run"], slip_run["init"], EstimateOptions())
    ev = [(e["time_s"], e["antenna"], e["transmitter"], e["kind"]) for e in res.events]
    assert ev[0] == (s.time_s, s.antenna, s.transmitter, "lock restart")
    assert all(e[1:3] == (s.antenna, s.transmitter) for e in ev)
    assert ev[1][3] == "bias re-estimated" and "integer re-fixed" in res.events[1]["action"]
    err, sig, t = coord_errors(tb, slip_run["sim"], res)
    ok = np.all(np.abs(err) <= 3 * sig, axis=1)
    t_rec = settle_time(t, ok, s.time_s)
    b = res.biases[(s.antenna, s.transmitter)] - truth_bias(slip_run["sim"])[(s.antenna, s.transmitter)]
    print(f"\nslip {SLIP}: back within 3σ (1 s hold) {t_rec} s after the slip; bias re-fixed at "
          f"{ev[1][0]:g} s; final bias error {1000 * b:.3f} mm")
    assert t_rec is not None and t_rec <= 2.0
    assert abs(b) < 1e-3
    after = t >= s.time_s
    assert np.mean(np.abs(err[after]) <= 3 * sig[after]) >= 0.99


def test_cycle_slip_bias_states(tb, slip_run):
    s = parse_slip(SLIP)
    res = estimate(slip_run["run"], slip_run["init"], EstimateOptions(biases="states"))
    assert [(e["time_s"], e["kind"]) for e in res.events] == [(s.time_s, "lock restart")]
    tb_b = truth_bias(slip_run["sim"])
    assert max(abs(res.biases[c] - tb_b[c]) for c in tb.channels) < 0.01
    err, sig, t = coord_errors(tb, slip_run["sim"], res)
    assert settle_time(t, np.all(np.abs(err) <= 3 * sig, axis=1), s.time_s) <= 2.0


@pytest.fixture(scope="module")
def unflagged_slip(tb, slip_run, tmp_path_factory):
    """The slip run's data plus a 2-cycle jump on a5/PL3 at 90 s that the lock counter does not show."""
    rec = slip_run["sim"].receiver.copy()
    sel = (rec["time_s"] >= 90.0 - 1e-9) & (rec["antenna"] == "a5") & (rec["transmitter"] == "PL3")
    rec.loc[sel, "phase_cycles"] += 2
    d = tmp_path_factory.mktemp("unflagged")
    rec.to_csv(d / "receiver.csv", index=False)
    write_run(tb, d / "receiver.csv", d / "run.mcap")
    res = estimate(read_run(d / "run.mcap"), slip_run["init"], EstimateOptions())
    return {"dir": d, "res": res}


def test_unflagged_slip_caught_by_innovation_test(tb, slip_run, unflagged_slip):
    res = unflagged_slip["res"]
    mine = [e for e in res.events if (e["antenna"], e["transmitter"]) == ("a5", "PL3")]
    assert [(e["time_s"], e["kind"]) for e in mine] == [(90.0, "innovation outlier"), (91.0, "bias re-estimated")]
    assert mine[0]["normalized_innovation"] > 6
    assert "integer re-fixed" in mine[1]["action"]
    truth = truth_bias(slip_run["sim"])[("a5", "PL3")] + 2 * tb.wavelength_m
    assert abs(res.biases[("a5", "PL3")] - truth) < 1e-3


def test_states_with_outlier_event_reads_back(tb, slip_run, unflagged_slip):
    """Regression: events with different keys (the outlier event's ``normalized_innovation``) were read
    back column-wise and misaligned (IndexError in States / export / evaluate)."""
    from cdgps_cli.io.states import States
    d = unflagged_slip["dir"]
    init = slip_run["init"]
    write_states(unflagged_slip["res"], d / "run.mcap", init, json.dumps(init), d / "states.mcap", {})
    st = States(d / "states.mcap")
    events = unflagged_slip["res"].events
    assert [(e["time_s"], e["kind"], e["antenna"]) for e in st.events] == \
        [(e["time_s"], e["kind"], e["antenna"]) for e in events]
    for got, want in zip(st.events, events):
        assert got.get("normalized_innovation") == want.get("normalized_innovation")


@pytest.fixture(scope="module")
def outage_run(tb, testbed_free):
    sim = same_seed_variant(tb, testbed_free, 70.0, outages=[parse_outage(OUTAGE)])
    return {"sim": sim, "run": memory_run(tb, sim.receiver), "init": testbed_free["init"]}


@pytest.mark.parametrize("biases", ["fixed", "states"])
def test_transmitter_outage_no_divergence(tb, outage_run, biases):
    o = parse_outage(OUTAGE)
    t_back = o.start_s + o.duration_s
    res = estimate(outage_run["run"], outage_run["init"], EstimateOptions(biases=biases))
    kinds = [e["kind"] for e in res.events]
    assert "integrity failure" not in kinds and "re-initialization" not in kinds
    reacq = [e for e in res.events if e["kind"] == "re-acquisition"]
    assert len(reacq) == 6 and all(e["transmitter"] == o.transmitter and e["time_s"] == t_back for e in reacq)
    if biases == "fixed":
        refix = [e for e in res.events if e["kind"] == "bias re-estimated"]
        assert len(refix) == 6 and all("integer re-fixed" in e["action"] for e in refix)
    err, sig, t = coord_errors(tb, outage_run["sim"], res)
    during = (t >= o.start_s) & (t < t_back)
    after = t >= t_back
    tb_b = truth_bias(outage_run["sim"])
    b_err = np.array([res.biases[(a, o.transmitter)] - tb_b[(a, o.transmitter)] for a in tb.rover_names])
    nis_after = np.nanmean(res.nis[after] / res.nis_dof[after])
    frac_after = np.mean(np.abs(err[after]) <= 3 * sig[after], axis=0)
    print(f"\noutage {OUTAGE}, biases={biases}: within 3σ during {100 * np.mean(np.abs(err[during]) <= 3 * sig[during]):.1f}%, "
          f"after {100 * frac_after.mean():.1f}% (worst coordinate {100 * frac_after.min():.1f}%, all coordinates "
          f"jointly {100 * np.mean(np.all(np.abs(err[after]) <= 3 * sig[after], axis=1)):.1f}%), NIS/dof after "
          f"{nis_after:.3f}, re-acquired bias errors max {1000 * np.max(np.abs(b_err)):.2f} mm")
    assert np.max(np.abs(err) / sig) < 5.0                              # no divergence at any epoch
    assert np.mean(np.abs(err[during]) <= 3 * sig[during]) >= 0.97
    assert frac_after.min() >= 0.97
    assert 0.8 <= nis_after <= 1.2
    assert np.max(np.abs(b_err)) < (1e-3 if biases == "fixed" else 0.01)


def test_transmitter_first_seen_after_init(tb, testbed_free):
    """PL6 absent until 65 s, so unknown to INIT (its biases removed from testbed_free's INIT):
    its channels start as new channels, get their integers fixed, the estimate stays consistent."""
    sim = same_seed_variant(tb, testbed_free, 0.0, outages=[parse_outage("PL6:0:65")])
    init = dict(testbed_free["init"])
    init["biases"] = [b for b in init["biases"] if b["transmitter"] != "PL6"]
    assert len(init["biases"]) == 30
    res = estimate(memory_run(tb, sim.receiver), init, EstimateOptions())
    new = [e for e in res.events if e["kind"] == "new channel"]
    assert len(new) == 6 and all(e["transmitter"] == "PL6" and e["time_s"] == 65.0 for e in new)
    fixed = [e for e in res.events if e["kind"] == "bias re-estimated"]
    assert len(fixed) == 6 and all("integer re-fixed" in e["action"] for e in fixed)
    tb_b = truth_bias(sim)
    assert max(abs(res.biases[c] - tb_b[c]) for c in tb.channels) < 1e-3
    err, sig, t = coord_errors(tb, sim, res)
    assert np.mean(np.abs(err) <= 3 * sig) >= 0.98


# regression: channels unknown to INIT get a diffuse bias-state prior (was: bias 0, variance σ²)
def test_bias_states_with_many_channels_unknown_to_init(tb, testbed_free):
    init = dict(testbed_free["init"])
    init["biases"] = [b for b in init["biases"] if b["transmitter"] in ("PL1", "PL2")]
    run = memory_run(tb, testbed_free["sim"].receiver)
    fixed = estimate(run, init, EstimateOptions())
    assert [e["kind"] for e in fixed.events].count("new channel") == 24          # the reference behaviour
    res = estimate(run, init, EstimateOptions(biases="states"))
    kinds = [e["kind"] for e in res.events]
    err, sig, t = coord_errors(tb, testbed_free["sim"], res)
    assert "re-initialization" not in kinds and "integrity failure" not in kinds
    assert np.mean(np.abs(err) <= 3 * sig, axis=0).min() >= 0.98


# --------------------------------------------------------------------------------------------
# lock_events


def test_lock_events_hand_made():
    nan = np.nan
    # channels (columns):
    # 0 continuous lock; 1 lock counter back to 0 (slip); 2 gap with the counter continuing (no event);
    # 3 gap then lock 0 (re-acquisition); 4 gap, counter jumps (re-acquisition); 5 never present;
    # 6 first seen at epoch 2; 7 counter decreases without reaching 0 (slip)
    Y = np.array([
        [0.1, 0.1, 0.1, 0.1, 0.1, nan, nan, 0.1],
        [0.2, 0.2, 0.2, 0.2, 0.2, nan, nan, 0.2],
        [0.3, 0.3, nan, nan, nan, nan, 0.3, 0.3],
        [0.4, 0.4, nan, 0.4, 0.4, nan, 0.4, 0.4],
        [0.5, 0.5, 0.5, 0.5, 0.5, nan, 0.5, 0.5],
    ])
    LOCK = np.array([
        [5, 5, 5, 0, 3, -1, -1, 5],
        [6, 6, 6, 1, 4, -1, -1, 6],
        [7, 0, -1, -1, -1, -1, 0, 2],
        [8, 1, -1, 0, 9, -1, 1, 3],
        [9, 2, 9, 1, 10, -1, 2, 4],
    ])
    expected = np.array([
        [1, 1, 1, 1, 1, 0, 0, 1],
        [0, 0, 0, 0, 0, 0, 0, 0],
        [0, 2, 0, 0, 0, 0, 1, 2],
        [0, 0, 0, 3, 3, 0, 0, 0],
        [0, 0, 0, 0, 0, 0, 0, 0],
    ])
    got = lock_events(Y, LOCK)
    assert got.dtype == np.int8
    np.testing.assert_array_equal(got, expected)
    # a gap whose returning counter is 0 is a re-acquisition (3), not a slip (2)
    got = lock_events(np.array([[1.0], [nan], [1.0]]), np.array([[4], [-1], [0]]))
    np.testing.assert_array_equal(got[:, 0], [1, 0, 3])


# --------------------------------------------------------------------------------------------
# integrity failure → batch re-initialization (1995 paper, Fig. 7)


REINIT_OPT = EstimateOptions(reinit_window_s=10.0)


@pytest.fixture(scope="module")
def reinit_case(tb, testbed_free):
    """testbed_free's data with 6 cm of extra white noise on every channel from 100 s: the NIS test
    fails persistently and the filter re-initializes on 10 s windows (twice, before the run ends)."""
    sim = testbed_free["sim"]
    rec = sim.receiver.copy()
    rng = np.random.default_rng(0)
    sel = rec["time_s"] >= 100.0 - 1e-9
    rec.loc[sel, "phase_cycles"] += rng.standard_normal(int(sel.sum())) * 0.06 / tb.wavelength_m
    run = memory_run(tb, rec)
    res = estimate(run, testbed_free["init"], REINIT_OPT)
    return {"sim": sim, "run": run, "init": testbed_free["init"], "res": res}


def test_reinitialization_triggered_and_logged(reinit_case):
    res = reinit_case["res"]
    kinds = [e["kind"] for e in res.events]
    assert "integrity failure" in kinds and "re-initialization" in kinds
    first = next(e for e in res.events if e["kind"] == "integrity failure")
    assert 100.0 <= first["time_s"] <= 102.5 and "batch re-initialization" in first["action"]
    restart = next(e for e in res.events if e["kind"] == "re-initialization")
    assert "filter restarted" in restart["action"]


def _gap_epochs(res):
    """Epochs between each integrity failure and the restart the filter reports."""
    t = res.time_s
    sel = np.zeros(len(t), dtype=bool)
    fails = [e["time_s"] for e in res.events if e["kind"] == "integrity failure"]
    restarts = [e["time_s"] for e in res.events if e["kind"] == "re-initialization"]
    for a, b in zip(fails, restarts):
        sel |= (t > a + 1e-9) & (t < b - 1e-9)
    return sel


def test_reinitialization_leaves_no_unset_epochs(tb, reinit_case):
    """Regression: epochs between the failure and the restart kept np.empty contents (q = 0, σ = 0)."""
    res = reinit_case["res"]
    gap = _gap_epochs(res)
    assert gap.sum() > 50
    err, sig, t = coord_errors(tb, reinit_case["sim"], res)
    assert np.all(np.isfinite(res.x)) and np.all(sig[gap] > 0)
    assert np.all(np.linalg.eigvalsh(res.P[gap]) > 0)
    assert np.mean(np.abs(err[gap]) <= 3 * sig[gap]) >= 0.9


def test_reinitialization_then_smoothing(tb, reinit_case):
    """Regression: smoothing across the unset epochs raised LinAlgError (singular P̄ = Q)."""
    res = estimate(reinit_case["run"], reinit_case["init"], EstimateOptions(reinit_window_s=10.0, smooth=True))
    err, sig, t = coord_errors(tb, reinit_case["sim"], res)
    assert np.all(np.isfinite(res.x))
    assert np.mean(np.abs(err) <= 3 * sig) >= 0.9
