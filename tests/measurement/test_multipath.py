"""Gauss–Markov multipath states (issue 11 item 5): batch, filter and smoother against independent
references, and σ_mp = 0 leaving today's results unchanged.

* batch: the SRIF solution with a multipath state per channel equals a dense generalized least
  squares in which the multipath is not a state but part of the noise covariance
  (blocks σ_mp² a^|k−l| per channel + white σ_c²), on a short window;
* filter/RTS: ``estimate`` with INIT's multipath model equals a textbook covariance-form EKF and RTS
  smoother on the augmented state [x; m] written here;
* σ_mp = 0 (explicitly) gives exactly today's INIT and filter outputs.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.estimation.filter import EstimateOptions, estimate
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.initializer import InitOptions, _Problem, initialize, window_data
from cdgps_cli.measurement.phase import EpochPhaseModel, channel_indices
from cdgps_cli.measurement.multipath import MultipathModel, from_init, model_from
from cdgps_cli.core.records import memory_run
from cdgps_cli.sim.structure import SimOptions, simulate

from _shared import REPO_ROOT

TOWER = REPO_ROOT / "configs" / "tower-120m-fe.toml"
MP = MultipathModel(0.015, 30.0)


@pytest.fixture(scope="module")
def tower():
    return load_config(TOWER)


@pytest.fixture(scope="module")
def short_sim(tower):
    sim = simulate(tower, SimOptions(duration_s=6.0, seed=3, phase_sigma_m=0.002, multipath_sigma_m=0.015))
    return sim, memory_run(tower, sim.receiver)


def _dense_gls(prob: _Problem, x_lin: np.ndarray):
    """GLS of the linearized batch with the multipath in the noise covariance (not as states).

    Unknowns θ = [x₁, ω₁…ω_{N−1}, b]; returns the trajectory (N, n_dyn), b (m), the multipath's
    conditional mean (N, C), and the covariances of x_N and b."""
    nd, mp = prob.n_dyn, prob.mp
    wd = prob.wd
    N, C = wd.y_m.shape
    model = discrete_model(prob.cfg)
    A = model.A
    G = prob.G[:nd, :prob.G.shape[1] - C]              # the structure's whitened noise input
    r, m = G.shape[1], prob.free.size
    h, Hd = prob._predict(x_lin[:, :nd], jacobian=True)
    ytil = prob.y - h + np.einsum("kci,ki->kc", Hd, x_lin[:, :nd])
    nv = nd + (N - 1) * r + m
    Phi = np.zeros((N, nd, nd + (N - 1) * r))          # x_k = Φ_k [x₁; ω]
    Phi[0, :, :nd] = np.eye(nd)
    for k in range(1, N):
        Phi[k] = A @ Phi[k - 1]
        Phi[k, :, nd + (k - 1) * r:nd + k * r] += G
    F = np.zeros((C, N, nv))                           # observations ordered (channel, epoch)
    for c in range(C):
        F[c, :, :nd + (N - 1) * r] = np.einsum("ki,kij->kj", Hd[:, c], Phi)
        F[c, np.arange(N), nd + (N - 1) * r + prob.bias_index[:, c]] = 1.0
    F = F.reshape(C * N, nv)
    y = ytil.T.reshape(-1)
    a = mp.transition(prob.cfg.sample_period_s)
    lag = np.abs(np.subtract.outer(np.arange(N), np.arange(N)))
    Sm = np.kron(np.eye(C), mp.sigma_m**2 * a**lag)    # multipath covariance
    S = Sm + np.diag(np.repeat(prob.sig_c**2, N))
    Si = np.linalg.inv(S)
    Nmat = F.T @ Si @ F
    Nmat[nd:nd + (N - 1) * r, nd:nd + (N - 1) * r] += np.eye((N - 1) * r)
    Cov = np.linalg.inv(Nmat)
    th = Cov @ (F.T @ Si @ y)
    xs = np.einsum("kij,j->ki", Phi, th[:nd + (N - 1) * r])
    m_hat = (Sm @ Si @ (y - F @ th)).reshape(C, N).T
    J = np.zeros((nd + m, nv))                          # [x_N; b] = J θ
    J[:nd] = Phi[-1].reshape(nd, -1) @ np.eye(nd + (N - 1) * r, nv)
    J[nd:, nd + (N - 1) * r:] = np.eye(m)
    return xs, th[nd + (N - 1) * r:], m_hat, J @ Cov @ J.T


def test_batch_with_gauss_markov_states_equals_dense_gls(tower, short_sim):
    sim, run = short_sim
    wd = window_data(run, 0.0, 3.0)
    C = len(wd.channels)
    sig_c = np.linspace(0.0018, 0.0025, C)            # per-channel white σ, as the noise estimate gives
    prob = _Problem(tower, wd, sig_c, True, mp=MP)
    assert prob.n == prob.n_dyn + C
    N = len(wd.time_s)
    k0 = int(round(wd.time_s[0] / tower.sample_period_s))
    x_lin = np.zeros((N, prob.n))
    x_lin[:, :prob.n_dyn] = sim.x[k0:k0 + N] + 1e-3   # linearize near (not at) the truth
    lp = prob.linear_problem(x_lin, 0.0, x_lin[0], 0.0, np.zeros(prob.free.size))
    sol = prob.solve(lp)
    xs, b, m_hat, P = _dense_gls(prob, x_lin)
    nd = prob.n_dyn
    scale_x = np.max(np.abs(xs))
    assert np.max(np.abs(sol.x[:, :nd] - xs)) < 1e-8 * max(scale_x, 1.0)
    assert np.max(np.abs(sol.b - b)) < 1e-8
    assert np.max(np.abs(sol.x[:, nd:] - m_hat)) < 1e-8
    Pz = sol.P_end
    idx = np.r_[np.arange(nd), prob.n + np.arange(prob.free.size)]
    Ps = Pz[np.ix_(idx, idx)]
    assert np.max(np.abs(Ps - P)) < 1e-8 * np.max(np.abs(P))
    # and the nonlinear cost at the solution matches the linear one (same priors on both sides)
    assert prob.cost(sol.x, sol.b, sol.w) == pytest.approx(sol.cost, rel=1e-3, abs=1.0)


def _hand_init(cfg, sim, run, mp: MultipathModel | None):
    ant_tx = {(r["antenna"], r["transmitter"]): r["bias_m"] for r in sim.truth["biases"]}
    n = cfg.n_states
    rng = np.random.default_rng(5)
    P0 = np.diag(np.full(n, 1e-4))
    x0 = sim.x[0] + rng.standard_normal(n) * 1e-2
    init = {"config_sha256": cfg.sha256, "sigma_m": 0.002,
            "state": {"time_s": float(sim.time_s[0]), "x": x0.tolist(), "P": P0.tolist()},
            "biases": [{"antenna": a, "transmitter": t, "bias_m": b, "current": True} for (a, t), b in ant_tx.items()]}
    if mp is not None:
        names = [f"{a}/{t}" for a, t in ant_tx]
        C = len(names)
        init["multipath"] = dict(mp.echo(), channels=names, x_m=(rng.standard_normal(C) * 0.005).tolist(),
                                 P_m2=(np.eye(C) * 0.8 * mp.sigma_m**2).tolist(),
                                 cross_P=(np.zeros((n, C)) + 1e-7).tolist())
    return init


def _textbook(cfg, run, init, chans, mp):
    """Covariance-form EKF (prediction, Kalman gain, Joseph update) and RTS on [x; m]."""
    model = discrete_model(cfg)
    n, C, T = cfg.n_states, len(chans), cfg.sample_period_s
    p = n + C
    a = math.exp(-T / mp.time_constant_s)
    A = np.eye(p)
    A[:n, :n] = model.A
    A[n:, n:] *= a
    Q = np.zeros((p, p))
    Q[:n, :n] = model.Q
    Q[n:, n:] = np.eye(C) * mp.sigma_m**2 * (1 - a * a)
    ph = run.phase.frame()
    times = np.unique(ph["time_s"].to_numpy())
    N = len(times)
    col = {c: i for i, c in enumerate(chans)}
    Y = np.full((N, C), np.nan)
    k_of = np.rint((ph["time_s"].to_numpy() - times[0]) / T).astype(int)
    for k, a_, t_, v in zip(k_of, ph["antenna"], ph["transmitter"], ph["phase_cycles"]):
        Y[k, col[(a_, t_)]] = v * cfg.wavelength_m
    bias = {(b["antenna"], b["transmitter"]): b["bias_m"] for b in init["biases"]}
    bvec = np.array([bias[c] for c in chans])
    ant, tx = channel_indices(cfg, [c[0] for c in chans], [c[1] for c in chans])
    hm = EpochPhaseModel(cfg, ant, tx)
    rec = init["multipath"]
    where = {s: i for i, s in enumerate(rec["channels"])}
    j = [where[f"{a_}/{t_}"] for a_, t_ in chans]
    x = np.r_[init["state"]["x"], np.asarray(rec["x_m"])[j]]
    P = np.zeros((p, p))
    P[:n, :n] = init["state"]["P"]
    P[n:, n:] = np.asarray(rec["P_m2"])[np.ix_(j, j)]
    P[:n, n:] = np.asarray(rec["cross_P"])[:, j]
    P[n:, :n] = P[:n, n:].T
    R = init["sigma_m"] ** 2 * np.eye(C)
    xf, Pf = np.empty((N, p)), np.empty((N, p, p))
    for k in range(N):
        if k:
            x, P = A @ x, A @ P @ A.T + Q
        h, Hx = hm(x[:n])
        H = np.hstack([Hx, np.eye(C)])
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ (Y[k] - h - bvec - x[n:])
        IKH = np.eye(p) - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        xf[k], Pf[k] = x, P
    xs, Ps = xf.copy(), Pf.copy()
    for k in range(N - 2, -1, -1):
        Pp = A @ Pf[k] @ A.T + Q
        Gk = Pf[k] @ A.T @ np.linalg.inv(Pp)
        xs[k] = xf[k] + Gk @ (xs[k + 1] - A @ xf[k])
        Ps[k] = Pf[k] + Gk @ (Ps[k + 1] - Pp) @ Gk.T
    return xf, Pf, xs, Ps


def test_filter_and_rts_with_gauss_markov_states_equal_textbook(tower, short_sim):
    sim, run = short_sim
    init = _hand_init(tower, sim, run, MP)
    opt = EstimateOptions(smooth=True, adapt_sigma=False, outlier_sigma=1e6, reinit_after_epochs=10**6)
    res = estimate(run, init, opt)
    assert res.filter_path == "numpy"
    assert res.noise["multipath"]["sigma_m"] == MP.sigma_m
    xf, Pf, xs, Ps = _textbook(tower, run, init, res.channels, MP)
    n = tower.n_states
    assert len(res.time_s) == len(xf)
    assert np.max(np.abs(res.x_filt - xf[:, :n])) < 1e-8
    assert np.max(np.abs(res.P_filt - Pf[:, :n, :n])) < 1e-10
    assert np.max(np.abs(res.x - xs[:, :n])) < 1e-8
    assert np.max(np.abs(res.P - Ps[:, :n, :n])) < 1e-10
    # the multipath states matter: without them the same data give another trajectory
    plain = dict(init)
    plain.pop("multipath")
    res0 = estimate(run, plain, opt)
    assert np.max(np.abs(res0.x - res.x)) > 1e-4


def test_zero_multipath_sigma_gives_todays_outputs(tower):
    sim = simulate(tower, SimOptions(duration_s=20.0, seed=2, phase_sigma_m=0.002))
    run = memory_run(tower, sim.receiver)
    a = initialize(run, InitOptions())
    b = initialize(run, InitOptions(multipath_sigma_m=0.0, multipath_time_constant_s=30.0))
    for d in (a, b):
        d.pop("elapsed_s")
    assert "multipath" not in b
    b_opts = b.pop("options")
    a_opts = a.pop("options")
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert {k: v for k, v in b_opts.items() if not k.startswith("multipath_")} == a_opts
    assert "multipath_sigma_m" not in a_opts        # INIT.json of a default run is unchanged
    ra, rb = estimate(run, a), estimate(run, dict(b, options=b_opts))
    assert np.array_equal(ra.x, rb.x) and np.array_equal(ra.P, rb.P)
    assert "multipath" not in ra.noise


def test_init_records_the_model_and_estimate_uses_it(tower):
    sim = simulate(tower, SimOptions(duration_s=25.0, seed=4, phase_sigma_m=0.002, multipath_sigma_m=0.015))
    run = memory_run(tower, sim.receiver)
    init = initialize(run, InitOptions(multipath_sigma_m=0.015, multipath_time_constant_s=30.0, starts=2))
    mp = init["multipath"]
    C = len(mp["channels"])
    assert (mp["sigma_m"], mp["time_constant_s"]) == (0.015, 30.0)
    assert len(mp["x_m"]) == C and np.array(mp["P_m2"]).shape == (C, C)
    assert np.array(mp["cross_P"]).shape == (tower.n_states, C)
    # the window-end multipath estimate follows the simulated multipath (truth = data − model − bias − white)
    assert np.all(np.diag(np.array(mp["P_m2"])) < mp["sigma_m"] ** 2)
    assert from_init(init) == MultipathModel(0.015, 30.0)
    res = estimate(run, json.loads(json.dumps(init)), EstimateOptions())
    assert res.filter_path == "numpy" and res.noise["multipath"]["time_constant_s"] == 30.0
    assert res.window is not None and np.isfinite(res.x).all()


def test_model_bounds_and_bad_init_records(tower, tmp_path):
    assert model_from(tower) == MultipathModel(0.0, 30.0)          # the bundled configs: off
    assert model_from(tower, 0.01, 12.0) == MultipathModel(0.01, 12.0)
    with pytest.raises(CdgpsError, match="multipath_sigma_m"):
        model_from(tower, -0.01)
    with pytest.raises(CdgpsError, match="multipath_time_constant_s"):
        model_from(tower, 0.01, 0.0)
    with pytest.raises(CdgpsError, match="INIT.json: multipath"):
        from_init({"multipath": {"sigma_m": True, "time_constant_s": 30.0}})
    with pytest.raises(CdgpsError, match="INIT.json: multipath.time_constant_s"):
        from_init({"multipath": {"sigma_m": 0.01, "time_constant_s": -3}})
    text = TOWER.read_text().replace("line_bias_calibrated = true",
                                     "line_bias_calibrated = true\nmultipath_sigma_m = -0.5", 1)
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(CdgpsError, match="model.multipath_sigma_m"):
        load_config(bad)
    good = tmp_path / "good.toml"
    good.write_text(text.replace("multipath_sigma_m = -0.5", "multipath_sigma_m = 0.015\nmultipath_time_constant_s = 20"))
    cfg = load_config(good)
    assert model_from(cfg) == MultipathModel(0.015, 20.0)
    assert cfg.summary()["multipath_sigma_m"] == 0.015
    assert "multipath_sigma_m" not in tower.summary()


def test_cli_init_option_echoed_and_estimate_uses_it(tower, tmp_path):
    from click.testing import CliRunner

    from cdgps_cli.cli.commands import main
    from cdgps_cli.io.run import write_run
    from cdgps_cli.sim.structure import write_simulation

    sim = simulate(tower, SimOptions(duration_s=25.0, seed=6, phase_sigma_m=0.002, multipath_sigma_m=0.015))
    write_simulation(sim, tmp_path)
    mcap = tmp_path / "run.mcap"
    write_run(tower, tmp_path / "receiver.csv", mcap, tmp_path / "gyro.csv" if tower.gyro_names else None)
    out = tmp_path / "INIT.json"
    r = CliRunner().invoke(main, ["init", str(mcap), "--starts", "2", "--multipath-sigma-m", "0.015",
                                  "--multipath-tau-s", "30", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "multipath Gauss–Markov σ 15.00 mm τ 30 s" in r.output
    init = json.loads(out.read_text())
    assert init["multipath"]["sigma_m"] == 0.015 and init["options"]["multipath_time_constant_s"] == 30.0
    r = CliRunner().invoke(main, ["estimate", str(mcap), "--init", str(out), "-o", str(tmp_path / "s.mcap")])
    assert r.exit_code == 0, r.output
    assert "multipath: Gauss–Markov state per channel, σ 15.00 mm, τ 30 s" in r.output
    r = CliRunner().invoke(main, ["init", str(mcap), "--multipath-tau-s", "0", "-o", str(tmp_path / "x.json")])
    assert r.exit_code == 2 and "--multipath-tau-s" in r.output and "Traceback" not in r.output
