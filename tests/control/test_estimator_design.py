"""The in-loop filter's process noise by the separation rule (estimator poles 3x faster than the
regulator's, mode by mode): the scalar steady-state filter in closed form, minimality of the scale,
the rigid-only regulator asking for nothing more than the config's W, and what it buys in the loop."""

import numpy as np
import pytest

from cdgps_cli.config.structure import channel_sigma_m
from cdgps_cli.control.estimator_design import loop_estimator
from cdgps_cli.pipeline.closed_loop import Disturbance, run_closed_loop
from cdgps_cli.control.design import PAPER_WEIGHTS, design_for_structure, rigid_only_gain
from cdgps_cli.control.estimator_design import estimator_error_matrix, separation_limits, _shortfall
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.control.estimator_design import loop_process_noise_scale
from cdgps_cli.measurement.phase import EpochPhaseModel, all_channels


@pytest.fixture(scope="module")
def tuned(testbed_cfg):
    d, poles = design_for_structure(testbed_cfg, qx=100.0, rigid_factor=0.3, rate_factor=0.1)
    return d, poles


def test_scalar_steady_state_filter_in_closed_form():
    """x' = a x + w, y = x + v: P̄ solves P̄ = a² P̄ r / (P̄ + r) + q and the error pole is a r / (P̄ + r)."""
    a, q, r = 0.95, 0.3, 0.5 ** 2
    # P̄² + P̄ (r − a² r − q) − q r = 0, positive root
    b = r - a * a * r - q
    P = 0.5 * (-b + np.sqrt(b * b + 4 * q * r))
    pole = estimator_error_matrix(np.array([[a]]), np.array([[q]]), np.array([[1.0]]), 0.5)
    assert pole[0, 0] == pytest.approx(a * r / (P + r), rel=1e-10)


def _loop_parts(cfg):
    model = discrete_model(cfg)
    ant, tx = all_channels(cfg)
    _, H = EpochPhaseModel(cfg, ant, tx)(np.zeros(model.A.shape[0]))
    sigma = channel_sigma_m(cfg, [(cfg.antenna_names[a], cfg.transmitter_names[t]) for a, t in zip(ant, tx)])
    return model, H, sigma


def test_scale_is_the_smallest_that_meets_the_rule(testbed_cfg, tuned):
    d, _ = tuned
    model, H, sigma = _loop_parts(testbed_cfg)
    names = list(testbed_cfg.mode_names)
    est = loop_estimator(testbed_cfg, d.K)
    s = est["scale"]
    assert s > 1.0                                          # the config's W is too slow for this regulator
    limits = separation_limits(model.A, model.B, d.K, model.T, names)
    assert "swing" not in limits                            # the jets cannot move it: exempt
    for mode, allowed in limits.items():                    # every constrained mode meets its limit
        t = est["estimator_settling_s"].get(mode)
        assert t is None or t <= allowed * (1 + 1e-9)
    assert _shortfall(model.A, s * model.Q, H, sigma, model.T, names, limits) <= 1.0
    assert _shortfall(model.A, 0.97 * s * model.Q, H, sigma, model.T, names, limits) > 1.0


def test_rigid_only_regulator_keeps_the_configs_process_noise(testbed_cfg, tuned):
    d, poles = tuned
    K = rigid_only_gain(testbed_cfg, d.A, d.B, poles["settling_time_s"]["closed_loop"]["rigid-body"])
    assert loop_estimator(testbed_cfg, K)["scale"] == 1.0


def test_bad_separation_is_refused(testbed_cfg, tuned):
    d, _ = tuned
    model, H, sigma = _loop_parts(testbed_cfg)
    with pytest.raises(CdgpsError, match="separation"):
        loop_process_noise_scale(model.A, model.B, d.K, model.Q, H, sigma, model.T, list(testbed_cfg.mode_names), -1.0)
    with pytest.raises(CdgpsError, match="process_noise_scale"):
        run_closed_loop(testbed_cfg, d.K, np.zeros(18), np.zeros((2, 9)), np.zeros((2, 36)), np.zeros((2, 18)),
                        process_noise_scale=0.0)


def test_faster_estimator_lowers_the_pulse_peak(testbed_cfg, tuned):
    """The Fig. 9 pulse, unknown to the filter: with the rule's W the regulator reacts sooner and the
    twist peak is lower than with the config's W (same noise, same gain)."""
    d, _ = tuned
    sim = testbed_cfg.simulation
    N = 90
    C = len(all_channels(testbed_cfg)[0])
    noise = np.random.default_rng(2).standard_normal((N, C)) * 0.01
    w = np.zeros((N, discrete_model(testbed_cfg).Bw.shape[1]))
    pulse = Disturbance(tuple(sim["pulse_thrusters"]), 5.0, 6.0, 1.4)
    U = np.asarray(testbed_cfg.mode_shapes)
    cols = [list(testbed_cfg.coord_names).index(c) for c in ("q5", "q8")]
    peak = {}
    for s in (1.0, loop_estimator(testbed_cfg, d.K)["scale"]):
        r = run_closed_loop(testbed_cfg, d.K, np.zeros(18), w, noise, np.zeros((N, 18)), pulse, process_noise_scale=s)
        peak[s] = np.abs(r.x_true[:, :9] @ U.T[:, cols]).max()
        # the coordinates' σ are U P Uᵀ's: q10 is the rigid mode alone, so its σ is |U| times the mode's
        rig = list(testbed_cfg.mode_frequency_hz).index(0.0)
        np.testing.assert_allclose(r.sigma_q_hat[:, 9], abs(U[9, rig]) * r.sigma_hat[:, rig], rtol=1e-10)
    s1, s2 = sorted(peak)
    assert peak[s2] < 0.9 * peak[s1]


def test_a_regulator_too_fast_for_the_filter_is_reported_not_refused(testbed_cfg):
    """The paper's weights on our Υ settle the vibration poles in 0.65 s: no process-noise scale makes
    the filter 3x faster, so met = False (the CLI warns), the closest scale is recorded and the filter
    keeps the config's W (a faster one only passes more noise: the slew test in
    tests/pipeline/test_closed_loop.py)."""
    d, _ = design_for_structure(testbed_cfg, **PAPER_WEIGHTS)
    est = loop_estimator(testbed_cfg, d.K)
    assert est["met"] is False and est["closest_scale"] > 1.0 and "NOT met" in est["rule"]
    assert est["scale"] == 1.0 and "the config's W is kept" in est["rule"]


def test_simulate_warns_when_the_rule_cannot_be_met(testbed_path, tmp_path):
    from click.testing import CliRunner

    from cdgps_cli.cli.commands import main

    g = tmp_path / "paper.json"
    assert CliRunner().invoke(main, ["-q", "control", "design", str(testbed_path), "-o", str(g)]).exit_code == 0
    r = CliRunner().invoke(main, ["simulate", str(testbed_path), "--scenario", "pulse", "--duration", "1",
                                  "--controller", str(g), "-o", str(tmp_path / "o")])
    assert r.exit_code == 0 and "in-loop estimator cannot be made 3x faster" in r.output, r.output


def test_a_filter_without_steady_state_is_a_clear_error_or_not_met():
    """A marginal mode the measurement does not see (H = 0 on a double integrator): the steady-state
    filter does not exist; the error matrix says so by name and the rule reports 'not met'."""
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    B = np.array([[0.005], [0.1]])
    H = np.zeros((1, 2))
    with pytest.raises(CdgpsError, match="no steady state"):
        estimator_error_matrix(A, np.eye(2) * 1e-4, H, 0.01)
    out = loop_process_noise_scale(A, B, np.array([[1.0, 1.0]]), np.eye(2) * 1e-4, H, 0.01, 0.1, ["m"])
    assert out["met"] is False


def test_bang_bang_slew_time_from_torque_and_inertia(testbed_cfg):
    """Independent check: the jets' torque about the vertical (r × F, arm 1 m) over the rigid mode's
    inertia (1 / shape², mass-normalized modes) gives the same minimum slew time."""
    from cdgps_cli.control.slew import bang_bang_slew_time_s

    cfg = testbed_cfg
    F = np.asarray(cfg.thruster_max_force_n, dtype=float)
    tau = np.cross(np.asarray(cfg.thruster_position_m), np.asarray(cfg.thruster_direction) * F[:, None])[:, 2]
    rigid = list(cfg.mode_frequency_hz).index(0.0)
    inertia = 1.0 / cfg.mode_shapes[cfg.rigid_index, rigid] ** 2            # kg m²
    for angle in (np.radians(-36.0), np.radians(36.0)):
        push = np.clip(np.sign(angle) * tau, 0.0, None).sum()              # N m
        expected = 2.0 * np.sqrt(abs(angle) / (push / inertia))
        assert bang_bang_slew_time_s(cfg, angle) == pytest.approx(expected, rel=1e-9)
    assert bang_bang_slew_time_s(cfg, np.radians(-36.0)) == pytest.approx(24.08, abs=0.01)
    full = bang_bang_slew_time_s(cfg, np.radians(-36.0))
    assert bang_bang_slew_time_s(cfg, np.radians(-36.0), 0.7) == pytest.approx(full / np.sqrt(0.7), rel=1e-12)
