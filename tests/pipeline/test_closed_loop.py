"""Closed loop: exact pulse response, the Kalman step, open-loop equivalence, estimator consistency,
pulse rejection, the rigid-only regulator, and the `simulate --controller` command."""

import json

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from scipy.linalg import expm

from cdgps_cli.cli.commands import main
from cdgps_cli.pipeline.closed_loop import Disturbance, run_closed_loop, simulate_closed_loop
from cdgps_cli.control.design import design_for_structure, rigid_only_gain
from cdgps_cli.control.propagation import PulseResponse
from cdgps_cli.model.dynamics import continuous_model, discrete_model, zoh
from cdgps_cli.estimation.kalman import predict, update
from cdgps_cli.measurement.phase import all_channels
from cdgps_cli.sim.structure import SimOptions, simulate


@pytest.fixture(scope="module")
def design(testbed_cfg):
    return design_for_structure(testbed_cfg, qx=50.0, weights="tuned")


def test_full_period_pulse_is_the_zoh_input_matrix(testbed_cfg):
    Ac, Bc, _ = continuous_model(testbed_cfg)
    T = testbed_cfg.sample_period_s
    _, B = zoh(Ac, Bc, T)
    resp = PulseResponse(Ac, Bc, T)
    for j in (0, 7, 23):
        np.testing.assert_allclose(resp([j], [0.0], [T], [1.0]), B[:, j], rtol=0, atol=1e-12 * np.abs(B).max())


def test_partial_pulse_matches_matrix_exponential(testbed_cfg):
    """A pulse on [a, b] inside the period: e^{A_c (T − b)} · (ZOH input over b − a) · F (independent)."""
    Ac, Bc, _ = continuous_model(testbed_cfg)
    T, a, b, F = 0.1, 0.0231, 0.0817, 1.4
    _, Bab = zoh(Ac, Bc, b - a)
    ref = expm(Ac * (T - b)) @ Bab[:, 5] * F + expm(Ac * (T - 0.05)) @ zoh(Ac, Bc, 0.05)[1][:, 11] * 0.7
    got = PulseResponse(Ac, Bc, T)([5, 11], [a, 0.0], [b, 0.05], [F, 0.7])
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_kalman_update_matches_the_textbook_covariance_form():
    g = np.random.default_rng(4)
    n, p = 5, 8
    M = g.normal(size=(n, n))
    Pb = M @ M.T + np.eye(n)
    xb, H, r, s = g.normal(size=n), g.normal(size=(p, n)), g.normal(size=p), 0.5 + g.random(p)
    R = np.diag(s**2)
    S = H @ Pb @ H.T + R
    K = Pb @ H.T @ np.linalg.inv(S)
    x_ref, P_ref = xb + K @ r, (np.eye(n) - K @ H) @ Pb
    x, P, nis = update(xb, Pb, r, H, s)
    np.testing.assert_allclose(x, x_ref, atol=1e-12)
    np.testing.assert_allclose(P, P_ref, atol=1e-12)
    assert nis == pytest.approx(r @ np.linalg.solve(S, r), rel=1e-10)
    x2, P2, nis2 = update(xb, Pb, r, H, noise_chol=np.diag(s))          # full-noise path, same R
    np.testing.assert_allclose(x2, x, atol=1e-12)
    assert nis2 == pytest.approx(nis, rel=1e-12)
    A, Q = np.eye(n) * 0.9, np.eye(n) * 0.1
    xp, Pp = predict(x, P, A, Q, np.ones(n))
    np.testing.assert_allclose(xp, A @ x + 1)
    np.testing.assert_allclose(Pp, A @ P @ A.T + Q)


def _inputs(cfg, N, seed=1, sigma=0.01):
    g = np.random.default_rng(seed)
    C = len(all_channels(cfg)[0])
    return g.standard_normal((N, C)) * sigma, np.zeros((N, discrete_model(cfg).Bw.shape[1]))


def test_zero_gain_reproduces_the_open_loop_simulator(testbed_cfg):
    """K = 0 with the Fig. 9 pulse: the loop's exact pulse propagation equals simulate()'s ZOH one."""
    opt = SimOptions(duration_s=12.0, scenario="pulse", disturbance_scale=0.0, seed=3)
    ref = simulate(testbed_cfg, opt)
    sim = testbed_cfg.simulation
    noise, w = _inputs(testbed_cfg, len(ref.time_s))
    pulse = Disturbance(tuple(sim["pulse_thrusters"]), sim["pulse_time_s"],
                        sim["pulse_time_s"] + sim["pulse_duration_s"], sim["pulse_force_n"])
    n = ref.x.shape[1]
    r = run_closed_loop(testbed_cfg, np.zeros((24, n)), ref.x[0], w, noise, np.zeros((len(ref.time_s), n)), pulse)
    np.testing.assert_allclose(r.x_true, ref.x, rtol=0, atol=1e-12 * np.abs(ref.x).max())


def test_estimator_in_the_loop_is_consistent(testbed_cfg, design):
    """NEES of the in-loop EKF near its dof, NIS per dof near 1, when the true measurement noise and
    disturbance are the filter's own (σ and W of the config)."""
    N = 300
    sigma = testbed_cfg.measurement_sigma_m
    noise, w = _inputs(testbed_cfg, N, seed=7, sigma=sigma)
    w = np.random.default_rng(8).standard_normal(w.shape) * np.asarray(testbed_cfg.process_noise_sigma)
    d, _ = design
    n = d.A.shape[0]
    x0 = np.zeros(n)
    x0[:9] = 0.05
    r = run_closed_loop(testbed_cfg, d.K, x0, w, noise, np.zeros((N, n)))
    e = (r.x_true - r.x_hat) / r.sigma_hat
    assert 0.6 < np.mean(e[50:] ** 2) < 1.5              # per-state normalized error (diagonal NEES)
    assert 0.8 < np.mean(r.nis[50:]) / noise.shape[1] < 1.2


def test_closed_loop_rejects_the_pulse(testbed_cfg, design):
    sim = testbed_cfg.simulation
    N = 120
    noise, w = _inputs(testbed_cfg, N)
    pulse = Disturbance(tuple(sim["pulse_thrusters"]), 5.0, 6.0, 1.4)
    d, _ = design
    n = d.A.shape[0]
    U = np.asarray(testbed_cfg.mode_shapes)
    cols = [list(testbed_cfg.coord_names).index(c) for c in ("q5", "q8")]
    peaks = []
    for K in (np.zeros_like(d.K), d.K):
        r = run_closed_loop(testbed_cfg, K, np.zeros(n), w, noise, np.zeros((N, n)), pulse)
        peaks.append(np.abs(r.x_true[:, :9] @ U.T[:, cols]).max())
        firings = r.firings
    assert peaks[1] < 0.5 * peaks[0]
    assert all(f <= 1.4 for *_, f, _src in firings)


def test_rigid_only_gain_leaves_vibration_poles_open_loop(testbed_cfg, design):
    d, poles = design
    target = poles["settling_time_s"]["closed_loop"]["rigid-body"]
    K = rigid_only_gain(testbed_cfg, d.A, d.B, target)
    cl = np.sort_complex(np.linalg.eigvals(d.A - d.B @ K))
    elastic = [i for i, f in enumerate(testbed_cfg.mode_frequency_hz) if f > 0]
    idx = elastic + [9 + i for i in elastic]
    ol = np.linalg.eigvals(d.A[np.ix_(idx, idx)])
    for z in ol:
        assert np.min(np.abs(cl - z)) < 1e-9
    from cdgps_cli.control.poles import pole_table

    rows = [r for r in pole_table(d.A - d.B @ K, 0.1, list(testbed_cfg.mode_names)) if r["mode"] == "rigid-body"]
    assert max(r["settling_time_s"] for r in rows) == pytest.approx(target, rel=1e-3)


# ---- the command ---------------------------------------------------------------------------------


def _run(*args):
    return CliRunner().invoke(main, ["-q", *map(str, args)])


@pytest.fixture(scope="module")
def gains_path(tmp_path_factory, testbed_path):
    p = tmp_path_factory.mktemp("cl") / "gains.json"
    assert _run("control", "design", testbed_path, "--weights", "tuned", "--qx", "50", "-o", p).exit_code == 0
    return p


def test_simulate_with_controller_writes_native_logs(gains_path, testbed_path, testbed_cfg, tmp_path):
    args = ["simulate", testbed_path, "--scenario", "slew", "--controller", gains_path, "--duration", "8"]
    r = _run(*args, "-o", tmp_path / "a")
    assert r.exit_code == 0, r.output
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert files == ["actuators.csv", "controller.csv", "gyro.csv", "receiver.csv", "truth.csv", "truth.json"]
    act = pd.read_csv(tmp_path / "a" / "actuators.csv")
    assert set(act["actuator"]) <= set(testbed_cfg.thruster_names) and act["force_n"].max() <= 1.4
    ctrl = pd.read_csv(tmp_path / "a" / "controller.csv")
    assert {"time_s", "q10_hat_rad", "q10_hat_sigma_rad", "q10_ref_rad", "nis"} <= set(ctrl.columns)
    assert (ctrl["q10_hat_sigma_rad"] > 0).all()
    truth = json.loads((tmp_path / "a" / "truth.json").read_text())
    assert truth["controller"]["feedback"] == "gps" and truth["segments"][1]["kind"] == "slew"
    assert truth["controller"]["estimator_process_noise_scale"] >= 1.0
    assert _run(*args, "-o", tmp_path / "b").exit_code == 0
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f


def test_actuator_log_joins_a_jets_abutting_firings(testbed_cfg):
    """A control firing that runs into the disturbance pulse on the same jet is one firing in the log
    (one row per change of force); a change of force without a gap is one row with the new force."""
    from cdgps_cli.pipeline.closed_loop import actuator_log

    j, k = 4, 7
    log = actuator_log(testbed_cfg, [(j, 4.95, 5.0, 1.4, "control"), (j, 5.0, 6.0, 1.4, "disturbance"),
                                     (j, 6.0, 6.2, 1.4, "control"), (k, 1.0, 1.1, 1.4, "control"),
                                     (k, 1.1, 1.3, 0.7, "disturbance"), (k, 2.0, 2.1, 1.4, "control")])
    names = testbed_cfg.thruster_names
    assert log.values.tolist() == [[1.0, names[k], 1.4], [1.1, names[k], 0.7], [1.3, names[k], 0.0],
                                   [2.0, names[k], 1.4], [2.1, names[k], 0.0],
                                   [4.95, names[j], 1.4], [6.2, names[j], 0.0]]


def test_closed_loop_pulse_logs_are_ingested(testbed_path, tmp_path):
    """The pulse's jets are often firing under control when the pulse takes them over (seed 1 of the
    default design: a3+z and a4-z at 5.0 s); the logs must still pass `cdgps ingest`."""
    out, gains = tmp_path / "p", tmp_path / "g.json"
    assert _run("control", "design", testbed_path, "-o", gains).exit_code == 0
    assert _run("simulate", testbed_path, "--scenario", "pulse", "--duration", "8", "--seed", "1",
                "--disturbance-scale", "0.05", "--controller", gains, "-o", out).exit_code == 0
    act = pd.read_csv(out / "actuators.csv")
    assert not act.duplicated(["time_s", "actuator"]).any()
    r = _run("ingest", out / "receiver.csv", out / "gyro.csv", "--actuators", out / "actuators.csv",
             "--config", testbed_path, "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("extra,words", [
    (["--scenario", "slew"], "needs a controller"),
    (["--no-vibration-control"], "need --controller"),
    (["--scenario", "free", "--controller", "{gains}"], "runs the pulse or slew scenario"),
    (["--scenario", "pulse", "--controller", "{gains}", "--random-slips", "2"], "slips and outages"),
])
def test_bad_closed_loop_options(gains_path, testbed_path, tmp_path, extra, words):
    extra = [str(gains_path) if e == "{gains}" else e for e in extra]
    r = _run("simulate", testbed_path, *extra, "--duration", "2", "-o", tmp_path / "o")
    assert r.exit_code == 2 and words in r.output, r.output
    assert not (tmp_path / "o").exists()


def test_gains_of_another_config_are_refused(gains_path, tmp_path, testbed_text):
    other = tmp_path / "other.toml"
    other.write_text(testbed_text.replace('pulse_force_n = 1.4', 'pulse_force_n = 1.3'))
    r = _run("simulate", other, "--scenario", "pulse", "--controller", gains_path, "--duration", "2", "-o", tmp_path / "o")
    assert r.exit_code == 2 and "designed for config" in r.output
    assert not (tmp_path / "o").exists()


def test_gains_with_other_thruster_names_are_refused(gains_path, testbed_path, tmp_path):
    doc = json.loads(gains_path.read_text())
    doc["thruster_names"][0] = "zz1"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    r = _run("simulate", testbed_path, "--scenario", "pulse", "--controller", bad, "--duration", "2", "-o", tmp_path / "o")
    assert r.exit_code == 2 and "thruster_names" in r.output and "zz1" in r.output, r.output
    assert "Traceback" not in r.output and not (tmp_path / "o").exists()


def test_unknown_pulse_thruster_is_named(testbed_path, testbed_text, tmp_path):
    import re

    cfg = tmp_path / "unk.toml"
    cfg.write_text(re.sub(r"pulse_thrusters = \[[^]]*\]", 'pulse_thrusters = ["zz9", "a4-z"]', testbed_text, count=1))
    r = _run("control", "design", cfg, "-o", tmp_path / "g.json")
    assert r.exit_code == 2 and "simulation.pulse_thrusters" in r.output and "zz9" in r.output, r.output
    assert not (tmp_path / "g.json").exists()


def test_shaped_step_is_the_profiles_rigid_shape_without_feed_forward(testbed_cfg):
    from cdgps_cli.control.slew import slew_reference

    t = np.arange(600) * 0.1
    x0 = np.zeros(18)
    x0[8] = np.radians(14.0) / testbed_cfg.mode_shapes[9, 8]
    prof, ff = slew_reference(testbed_cfg, t, x0, "profile")
    shaped, none = slew_reference(testbed_cfg, t, x0, "shaped-step")
    assert none is None and ff is not None
    np.testing.assert_array_equal(shaped[:, [8, 17]], prof[:, [8, 17]])
    others = [i for i in range(18) if i not in (8, 17)]
    assert not shaped[:, others].any() and prof[:, others].any()


@pytest.mark.parametrize("feedback", ["gps", "truth"])
def test_slew_is_planned_from_the_state_the_controller_feeds_back(testbed_cfg, design, feedback):
    """The planner sees the estimate (or, with full-state feedback, the truth) at the planning epochs,
    and the reference from those epochs on is its plan."""
    N, n = 30, 18
    noise, w = _inputs(testbed_cfg, N)
    seen = {}

    def planner(x_fb):
        k = len(seen)
        seen[k] = x_fb.copy()
        ref = np.full((N, n), float(k + 1))
        return ref, None

    d, _ = design
    r = run_closed_loop(testbed_cfg, d.K, np.zeros(n), w, noise, np.zeros((N, n)), estimator=feedback,
                        planner=planner, plan_epochs=(0, 12))
    want = r.x_hat if feedback == "gps" else r.x_true
    np.testing.assert_array_equal(seen[0], want[0])
    np.testing.assert_array_equal(seen[1], want[12])
    assert (r.x_ref[:12] == 1.0).all() and (r.x_ref[12:] == 2.0).all()


def test_multipath_states_make_the_loop_filter_consistent(testbed_cfg, design):
    """Phase errors with a 1.5 cm, 30 s Gauss–Markov part plus the config's white σ, disturbance the
    filter's own W: with the multipath states the per-state normalized error and the NIS per dof are
    near 1; without them the filter is overconfident (both well above 1)."""
    from scipy.signal import lfilter

    from cdgps_cli.measurement.multipath import MultipathModel

    N, C = 400, len(all_channels(testbed_cfg)[0])
    mp = MultipathModel(0.015, 30.0)
    g = np.random.default_rng(1)
    e = g.standard_normal((N, C)) * np.sqrt(mp.process_variance_m2(0.1))
    e[0] = g.standard_normal(C) * mp.sigma_m
    noise = lfilter([1.0], [1.0, -mp.transition(0.1)], e, axis=0) + \
        g.standard_normal((N, C)) * testbed_cfg.measurement_sigma_m
    w = g.standard_normal((N, 9)) * np.asarray(testbed_cfg.process_noise_sigma)
    d, _ = design
    x0 = np.zeros(18)
    x0[:9] = 0.05
    stats = {}
    for model in (None, mp):
        r = run_closed_loop(testbed_cfg, d.K, x0, w, noise, np.zeros((N, 18)), multipath=model)
        stats[model is not None] = (np.mean(((r.x_true - r.x_hat) / r.sigma_hat)[50:] ** 2), np.mean(r.nis[50:]) / C)
    assert 0.7 < stats[True][0] < 1.3 and 0.85 < stats[True][1] < 1.15
    assert stats[False][0] > 1.6 and stats[False][1] > 1.25


def _pulse_peaks_deg(cfg, K, pwpf, duration_s=20.0):
    """Largest |q2, q5, q8| (deg) in the first 10 s and the last 5 s of a pulse with full-state feedback."""
    from cdgps_cli.measurement.phase import all_channels
    from cdgps_cli.model.dynamics import discrete_model

    sim, model = cfg.simulation, discrete_model(cfg)
    N, n = int(round(duration_s / model.T)), model.A.shape[0]
    pulse = Disturbance(tuple(sim["pulse_thrusters"]), sim["pulse_time_s"],
                        sim["pulse_time_s"] + sim["pulse_duration_s"], sim["pulse_force_n"])
    r = run_closed_loop(cfg, K, np.zeros(n), np.zeros((N, model.Bw.shape[1])),
                        np.zeros((N, len(all_channels(cfg)[0]))), np.zeros((N, n)), pulse, estimator="truth",
                        pwpf=pwpf)
    idx = [list(cfg.coord_names).index(c) for c in ("q2", "q5", "q8")]
    q = np.degrees(r.x_true[:, :cfg.n_modes] @ np.asarray(cfg.mode_shapes).T)[:, idx]
    return np.abs(q[:100]).max(), np.abs(q[-50:]).max()


def test_paper_weights_diverge_only_through_the_modulators_windup(testbed_cfg):
    """The paper's weights (the design default) are stable as a linear loop and through the default
    PWPF (T_m = 0.85 s) with its input limit; without the limit the saturated requests wind its filter
    up, the jets stay on for seconds after the request reverses and the loop diverges (docs/control.md)."""
    from cdgps_cli.control.modulation import PwpfParams

    paper, _ = design_for_structure(testbed_cfg)
    assert np.abs(np.linalg.eigvals(paper.closed_loop)).max() < 1
    _, late = _pulse_peaks_deg(testbed_cfg, paper.K, PwpfParams(anti_windup=False))
    assert late > 20.0                                   # grows: open-loop peak is about 30 deg
    first, late = _pulse_peaks_deg(testbed_cfg, paper.K, PwpfParams())
    assert first < 6.0 and late < 0.5
    tuned, _ = design_for_structure(testbed_cfg, weights="tuned")
    first, late = _pulse_peaks_deg(testbed_cfg, tuned.K, PwpfParams())
    assert first < 10.0 and late < 1.0


def _slew_and_pulse(cfg, gains, seed):
    """(slew: s after the command to within 0.5 deg, largest |q2, q5, q8| after it, deg;
    pulse: closed-loop peak of q5, q8 over the open-loop first peak), GPS estimate in the loop."""
    from cdgps_cli.control.metrics import pulse_metrics, slew_metrics

    deg = lambda s, k: np.degrees(s.q[:, list(cfg.coord_names).index(k)])  # noqa: E731
    sim = cfg.simulation
    opt = SimOptions(duration_s=45.0, scenario="slew", seed=seed, disturbance_scale=0.05)
    c, _ = simulate_closed_loop(cfg, opt, gains)
    m = slew_metrics(c.time_s, deg(c, "q10"), {k: deg(c, k) for k in ("q2", "q5", "q8")}, sim["slew_to_deg"],
                     sim["slew_time_s"])
    opt = SimOptions(duration_s=20.0, scenario="pulse", seed=seed, disturbance_scale=0.05)
    o = simulate(cfg, opt)
    c, _ = simulate_closed_loop(cfg, opt, gains)
    seg = next(s for s in c.truth["segments"] if s["kind"] == "pulse")
    p = pulse_metrics(o.time_s, {k: deg(o, k) for k in ("q5", "q8")}, {k: deg(c, k) for k in ("q5", "q8")},
                      seg["start_s"], seg["end_s"])
    return m["arrived_s_after_command"], max(m["internal_max_deg"].values()), max(v["peak_ratio"] for v in p.values())


def test_the_papers_weights_run_the_experiments_with_the_gps_estimate(testbed_cfg):
    """The default design (the paper's weights) in the full loop, seed 1: the slew arrives within 0.5 deg
    by 30 s and the pulse peak stays under a third of the open loop's.  Needs the modulator's input limit
    (without it the loop diverges) and the config's W when the separation rule cannot be met (with the
    rule's closest scale, 1000, the slew took 51 s)."""
    d, poles = design_for_structure(testbed_cfg)
    gains = {"A": d.A, "B": d.B, "K": d.K, "poles": poles, "config": {"sha256": testbed_cfg.sha256}}
    arrived, internal, ratio = _slew_and_pulse(testbed_cfg, gains, seed=1)
    assert arrived is not None and arrived < 30.0
    assert internal < 1.5 and ratio < 1 / 3


def _fig9_pulse(cfg):
    sim = cfg.simulation
    return Disturbance(tuple(sim["pulse_thrusters"]), 2.0, 3.0, sim["pulse_force_n"])


def test_an_estimator_told_of_the_pulse_follows_it_exactly(testbed_cfg):
    """Noise-free phases, no disturbance, exact start, K = 0: with the pulse's firings in its time
    update (Eq. 18) the EKF's prediction is the truth, so its estimate stays on it; without them the
    pulse is an unknown disturbance and the estimate lags it (the lag the pulse decomposition measures)."""
    model = discrete_model(testbed_cfg)
    N, n = 50, model.A.shape[0]
    noise, w = _inputs(testbed_cfg, N, sigma=0.0)
    err = {}
    for known in (False, True):
        r = run_closed_loop(testbed_cfg, np.zeros((24, n)), np.zeros(n), w, noise, np.zeros((N, n)),
                            _fig9_pulse(testbed_cfg), pulse_known=known)
        err[known] = np.abs(r.x_hat - r.x_true).max() / np.abs(r.x_true).max()
    assert err[True] < 1e-9
    assert err[False] > 1e-2


def test_ideal_actuator_holds_each_request_clipped_for_the_period(testbed_cfg, design):
    d, _ = design
    model = discrete_model(testbed_cfg)
    N, n, T = 40, model.A.shape[0], model.T
    noise, w = _inputs(testbed_cfg, N)
    r = run_closed_loop(testbed_cfg, d.K, np.zeros(n), w, noise, np.zeros((N, n)), _fig9_pulse(testbed_cfg),
                        estimator="truth", actuator="ideal")
    ctrl = [f for f in r.firings if f[4] == "control"]
    assert ctrl and all(abs((b - a) - T) < 1e-9 and 0 < f <= 1.4 for _j, a, b, f, _s in ctrl)
    k, j = divmod(int(np.argmax(r.command_n)), r.command_n.shape[1])
    held = [f for jj, a, _b, f, _s in ctrl if jj == j and abs(a - k * T) < 1e-9]
    assert held == [min(r.command_n[k, j], 1.4)]
    from cdgps_cli.core.errors import CdgpsError

    with pytest.raises(CdgpsError, match="actuator: expected 'pwpf' or 'ideal'"):
        run_closed_loop(testbed_cfg, d.K, np.zeros(n), w, noise, np.zeros((N, n)), actuator="ideal-ish")


def test_the_papers_ekf_as_written_brings_the_pulse_to_one_third():
    """Tuned weights, seed 1, GPS estimate in the loop: with the pulse in the EKF's time update (Eq. 18)
    and the paper's W (scale 1) the q5/q8 peak ratio is about one third (0.31; true state 0.26); with
    the pulse unknown to the EKF it lags and the peak is 0.44 (docs/testbed-model.md, decomposition),
    on configs/testbed-1998.toml, the model of benchmarks/paper.py."""
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.control.metrics import pulse_metrics

    from tests._shared import REPO_ROOT

    testbed_cfg = load_config(REPO_ROOT / "configs" / "testbed-1998.toml")
    d, poles = design_for_structure(testbed_cfg, weights="tuned")
    gains = {"A": d.A, "B": d.B, "K": d.K, "poles": poles, "config": {"sha256": testbed_cfg.sha256}}
    deg = lambda s: {k: np.degrees(s.q[:, list(testbed_cfg.coord_names).index(k)]) for k in ("q5", "q8")}  # noqa: E731
    opt = SimOptions(duration_s=20.0, scenario="pulse", seed=1, disturbance_scale=0.05)   # benchmarks/paper.py's
    o = deg(simulate(testbed_cfg, opt))
    ratio = {}
    for name, kw in {"unknown": {}, "eq18": {"pulse_known": True, "estimator_noise_scale": 1.0}}.items():
        c, _ = simulate_closed_loop(testbed_cfg, opt, gains, **kw)
        seg = next(s for s in c.truth["segments"] if s["kind"] == "pulse")
        p = pulse_metrics(c.time_s, o, deg(c), seg["start_s"], seg["end_s"])
        ratio[name] = max(v["peak_ratio"] for v in p.values())
    assert ratio["eq18"] < 1 / 3 + 0.01                  # 0.314
    assert ratio["unknown"] > ratio["eq18"] + 0.08       # 0.438
