"""Tests for cdgps_cli.measurement.phase: h(q), h(x), their Jacobians, near/far field, channel order."""

from __future__ import annotations

import re
from math import sqrt

import numpy as np
import pytest

from cdgps_cli.config.structure import parse_config
from cdgps_cli.measurement.phase import all_channels, channel_indices, phase_model, phase_model_q

RTOL = 1e-6


def assert_jacobian_close(J, Jfd):
    scale = max(np.max(np.abs(Jfd)), 1.0)
    err = np.max(np.abs(J - Jfd))
    assert err <= RTOL * scale, f"max |J − J_fd| = {err:.3e} (scale {scale:.3e})"


def _cfg_and_q(which, testbed_cfg, dof2_cfg, testbed_large_q, dof2_large_q):
    return (testbed_cfg, testbed_large_q) if which == "testbed" else (dof2_cfg, dof2_large_q)


def _modal_states(cfg, q_target: np.ndarray, rng) -> np.ndarray:
    """Modal states x = [ξ, ξ̇] whose q = Uξ is the least-squares fit to large-angle targets."""
    U = np.asarray(cfg.mode_shapes)
    xi = q_target @ np.linalg.pinv(U).T
    return np.hstack([xi, rng.normal(0, 1, xi.shape)])


# --------------------------------------------------------------------------------------------
# channels


def test_all_channels_rover_major(testbed_cfg, dof2_cfg):
    ant, tx = all_channels(testbed_cfg)
    assert len(ant) == 36
    names = [(testbed_cfg.antenna_names[a], testbed_cfg.transmitter_names[t]) for a, t in zip(ant, tx)]
    assert names[:7] == [("a1", f"PL{i}") for i in range(1, 7)] + [("a2", "PL1")]
    assert names == testbed_cfg.channels
    assert testbed_cfg.master_index not in ant
    ant, tx = all_channels(dof2_cfg)
    assert [(dof2_cfg.antenna_names[a], dof2_cfg.transmitter_names[t]) for a, t in zip(ant, tx)][:5] == \
        [("s2", "S1"), ("s2", "S2"), ("s2", "S3"), ("s2", "S4"), ("s3", "S1")]
    a, t = channel_indices(dof2_cfg, ["s4", "s2"], ["S3", "S1"])
    assert list(a) == [3, 1] and list(t) == [2, 0]


# --------------------------------------------------------------------------------------------
# Jacobians vs central differences (large angles)


@pytest.mark.parametrize("which", ["testbed", "dof2"])
def test_phase_model_q_jacobian(which, testbed_cfg, dof2_cfg, testbed_large_q, dof2_large_q, central_diff):
    cfg, qs = _cfg_and_q(which, testbed_cfg, dof2_cfg, testbed_large_q, dof2_large_q)
    ant, tx = all_channels(cfg)
    h, dh = phase_model_q(cfg, qs, ant, tx, jacobian=True)
    assert h.shape == (len(qs), len(ant)) and dh.shape == (len(qs), len(ant), cfg.n_q)
    np.testing.assert_array_equal(h, phase_model_q(cfg, qs, ant, tx))
    for k, q in enumerate(qs):
        assert_jacobian_close(dh[k], central_diff(lambda v: phase_model_q(cfg, v[None], ant, tx)[0], q))
    assert np.max(np.abs(dh)) > 0.5


@pytest.mark.parametrize("which", ["testbed", "dof2"])
def test_phase_model_x_jacobian(which, testbed_cfg, dof2_cfg, testbed_large_q, dof2_large_q, central_diff):
    cfg, qs = _cfg_and_q(which, testbed_cfg, dof2_cfg, testbed_large_q, dof2_large_q)
    rng = np.random.default_rng(1)
    xs = _modal_states(cfg, qs, rng)
    U = np.asarray(cfg.mode_shapes)
    q_fit = xs[:, :cfg.n_modes] @ U.T
    if cfg.rigid_index is not None:       # the rigid angle is reachable exactly
        np.testing.assert_allclose(q_fit[:, cfg.rigid_index], qs[:, cfg.rigid_index], atol=1e-12)
        assert abs(q_fit[0, cfg.rigid_index]) == pytest.approx(2.5)
    else:
        np.testing.assert_allclose(q_fit, qs, atol=1e-9)
    ant, tx = all_channels(cfg)
    h, H = phase_model(cfg, xs, ant, tx, jacobian=True)
    assert H.shape == (len(xs), len(ant), cfg.n_states)
    np.testing.assert_allclose(h, phase_model_q(cfg, q_fit, ant, tx), atol=1e-12)
    np.testing.assert_array_equal(H[:, :, cfg.n_modes:], 0.0)     # h does not depend on rates
    for k, x in enumerate(xs):
        assert_jacobian_close(H[k], central_diff(lambda v: phase_model(cfg, v[None], ant, tx)[0], x))


# --------------------------------------------------------------------------------------------
# near field vs far field


def _as_near_field(text: str, distance: float) -> str:
    """Replace every far-field `direction = [..]` of a transmitter by `position_m` at `distance`
    metres along the (normalized) direction."""
    def repl(m):
        v = np.array([float(s) for s in m.group(1).split(",")])
        v = v / np.linalg.norm(v) * distance
        return "position_m = [" + ", ".join(repr(float(e)) for e in v) + "]"
    out, n = re.subn(r"direction = \[([^\]]*)\]", repl, text)
    assert n == 4
    return out


def test_far_field_is_limit_of_near_field(dof2_cfg, dof2_text, dof2_large_q):
    near = parse_config(_as_near_field(dof2_text, 1e7), "near.toml")
    assert not near.transmitter_far_field and dof2_cfg.transmitter_far_field
    ant, tx = all_channels(dof2_cfg)
    h_far, H_far = phase_model_q(dof2_cfg, dof2_large_q, ant, tx, jacobian=True)
    h_near, H_near = phase_model_q(near, dof2_large_q, ant, tx, jacobian=True)
    assert np.max(np.abs(h_far)) > 1.0               # metre-level differential ranges
    np.testing.assert_allclose(h_near, h_far, atol=1e-5, rtol=0)
    np.testing.assert_allclose(H_near, H_far, atol=1e-5, rtol=0)
    # at only 100 m the planar-wavefront approximation is visibly off (the comparison discriminates)
    closer = parse_config(_as_near_field(dof2_text, 100.0), "near100.toml")
    assert np.max(np.abs(phase_model_q(closer, dof2_large_q, ant, tx) - h_far)) > 1e-3


def test_far_field_hand_computed(dof2_cfg):
    """q1 = π/2: m → (0, 1, 0), s2 → (0, −1, 0); h(s2, S1) = −s·(p_s2 − p_m) = 2·0.433013."""
    ant, tx = channel_indices(dof2_cfg, ["s2", "s3"], ["S1", "S4"])
    h = phase_model_q(dof2_cfg, np.array([[np.pi / 2, 0.0]]), ant, tx)[0]
    s1 = np.array([0.25, 0.433013, 0.866025])
    s1 /= np.linalg.norm(s1)
    s4 = np.array([-0.719846, 0.604023, 0.342020])
    s4 /= np.linalg.norm(s4)
    assert h[0] == pytest.approx(-s1 @ np.array([0.0, -2.0, 0.0]), abs=1e-12)
    assert h[1] == pytest.approx(-s4 @ np.array([0.0, 0.0, -2.0]), abs=1e-12)


def test_near_field_hand_computed(testbed_cfg):
    """q5 = q10 = π/2.  Rx(π/2): (x, y, z) → (x, −z, y); Rz(π/2): (x, y, z) → (−y, x, z).
    a3 (0, 1, 0.05) → (0, −0.05, 1) → (0.05, 0, 1); master (0, 0, 0.2) → (0, −0.2, 0) → (0.2, 0, 0).
    PL1 = (0.5, 1, 13.5): h = |(0.45, 1, 12.5)| − |(0.3, 1, 13.5)|."""
    q = np.zeros((1, 10))
    q[0, 4] = np.pi / 2
    q[0, 9] = np.pi / 2
    ant, tx = channel_indices(testbed_cfg, ["a3"], ["PL1"])
    h = phase_model_q(testbed_cfg, q, ant, tx)
    expected = sqrt(0.45**2 + 1.0 + 12.5**2) - sqrt(0.3**2 + 1.0 + 13.5**2)
    assert h[0, 0] == pytest.approx(expected, abs=1e-12)


def test_near_field_at_rest_hand_computed(testbed_cfg):
    """q = 0: a1 = (−4, 1, 0.05), master (0, 0, 0.2), PL4 = (18, −4, 3)."""
    ant, tx = channel_indices(testbed_cfg, ["a1"], ["PL4"])
    h = phase_model_q(testbed_cfg, np.zeros((1, 10)), ant, tx)
    expected = sqrt(22.0**2 + 5.0**2 + 2.95**2) - sqrt(18.0**2 + 4.0**2 + 2.8**2)
    assert h[0, 0] == pytest.approx(expected, abs=1e-12)
