"""Tests for cdgps_cli.model.kinematics: exact large-angle positions, Jacobians, gyro and thruster maps."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.config.structure import parse_config
from cdgps_cli.model.kinematics import antenna_positions, gyro_matrix, point_positions, thruster_forcing

RTOL = 1e-6


def Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def Ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def assert_jacobian_close(J, Jfd):
    scale = max(np.max(np.abs(Jfd)), 1.0)
    err = np.max(np.abs(J - Jfd))
    assert err <= RTOL * scale, f"max |J − J_fd| = {err:.3e} (scale {scale:.3e})"


# --------------------------------------------------------------------------------------------
# Jacobians vs central differences


@pytest.mark.parametrize("which", ["testbed", "dof2"])
def test_antenna_jacobian_matches_finite_differences(which, testbed_cfg, dof2_cfg, testbed_large_q,
                                                    dof2_large_q, central_diff):
    cfg, qs = (testbed_cfg, testbed_large_q) if which == "testbed" else (dof2_cfg, dof2_large_q)
    p, J = antenna_positions(cfg, qs, jacobian=True)
    assert p.shape == (len(qs), len(cfg.antenna_names), 3)
    assert J.shape == (len(qs), len(cfg.antenna_names), 3, cfg.n_q)
    for k, q in enumerate(qs):
        Jfd = central_diff(lambda v: antenna_positions(cfg, v[None])[0], q)
        assert_jacobian_close(J[k], Jfd)
        np.testing.assert_allclose(p[k], antenna_positions(cfg, q[None])[0], atol=1e-14)
    assert np.max(np.abs(J)) > 0.5          # not a trivial comparison


def test_point_jacobian_with_displacement_and_unattached_points(testbed_cfg, testbed_large_q, central_diff):
    """Points fixed to the body frame (section −1) and a linear displacement table on top of the
    section motion, under a large rigid rotation."""
    cfg = testbed_cfg
    rng = np.random.default_rng(3)
    section = np.array([-1, 0, 1, 2, -1])
    pos = rng.uniform(-4, 4, (5, 3))
    disp = rng.normal(0, 0.1, (5, 3, cfg.n_q))
    for q in testbed_large_q[:3]:
        _, J = point_positions(cfg, q[None], section, pos, disp, jacobian=True)
        Jfd = central_diff(lambda v: point_positions(cfg, v[None], section, pos, disp)[0], q)
        assert_jacobian_close(J[0], Jfd)


GIMBAL_CONFIG = """
[model]
name = "gimbal"
sample_period_s = 0.1
measurement_sigma_m = 0.01

[body]
origin_m = [10.0, -20.0, 3.0]
rigid_rotation = "psi"

[[coordinates]]
name = "tx"
kind = "translation"
[[coordinates]]
name = "ty"
kind = "translation"
[[coordinates]]
name = "tz"
kind = "translation"
[[coordinates]]
name = "ax"
kind = "rotation"
[[coordinates]]
name = "ay"
kind = "rotation"
[[coordinates]]
name = "az"
kind = "rotation"
[[coordinates]]
name = "psi"
kind = "rotation"

[[sections]]
name = "G"
pivot_m = [1.0, 2.0, 0.5]
translation = { x = "tx", y = "ty", z = "tz" }
rotation = { z = "az", x = "ax", y = "ay" }

[[antennas]]
name = "base"
position_m = [0.0, 0.0, 0.0]
master = true

[[antennas]]
name = "g1"
section = "G"
position_m = [2.0, 2.5, 1.0]

[[antennas]]
name = "g2"
section = "G"
position_m = [0.5, 1.0, -0.5]

[[transmitters]]
name = "S"
direction = [0.0, 0.0, 1.0]

[[modes]]
name = "m"
frequency_hz = 1.0
time_constant_s = 10.0
shape = [1, 0, 0, 0, 0, 0, 0]

[process_noise]
space = "modal"
sigma = [0.1]
"""


def test_three_axis_section_rotation_order_and_jacobian(central_diff):
    """p = o + Rz(ψ) (c + t + Rz(az) Ry(ay) Rx(ax) (r − c)), checked by hand and by differences."""
    cfg = parse_config(GIMBAL_CONFIG, "gimbal.toml")
    q = np.array([0.1, -0.2, 0.3, 1.1, -0.7, 2.2, 2.5])
    t, (ax, ay, az, psi) = q[:3], q[3:]
    o, c = np.array([10.0, -20.0, 3.0]), np.array([1.0, 2.0, 0.5])
    p = antenna_positions(cfg, q[None])[0]
    for i, r in ((1, np.array([2.0, 2.5, 1.0])), (2, np.array([0.5, 1.0, -0.5]))):
        expected = o + Rz(psi) @ (c + t + Rz(az) @ Ry(ay) @ Rx(ax) @ (r - c))
        np.testing.assert_allclose(p[i], expected, atol=1e-12)
    np.testing.assert_allclose(p[0], o, atol=1e-12)        # unattached point at the body origin
    _, J = antenna_positions(cfg, q[None], jacobian=True)
    assert_jacobian_close(J[0], central_diff(lambda v: antenna_positions(cfg, v[None])[0], q))


# --------------------------------------------------------------------------------------------
# analytic checks


def test_testbed_nominal_positions_at_zero(testbed_cfg):
    p = antenna_positions(testbed_cfg, np.zeros((1, 10)))[0]
    np.testing.assert_allclose(p, np.asarray(testbed_cfg.antenna_position_m) + testbed_cfg.body_origin_m, atol=1e-15)
    names = testbed_cfg.antenna_names
    np.testing.assert_allclose(p[names.index("master")], [0.0, 0.0, 0.2])
    np.testing.assert_allclose(p[names.index("a1")], [-4.0, 1.0, 0.05])
    np.testing.assert_allclose(p[names.index("a6")], [4.0, -1.0, 0.05])


def test_dof2_nominal_positions_at_zero(dof2_cfg):
    p = antenna_positions(dof2_cfg, np.zeros((1, 2)))[0]
    np.testing.assert_allclose(p, [[1, 0, 0], [-1, 0, 0], [0, 1, -2], [0, -1, -2]], atol=1e-15)


def test_nominal_positions_include_body_origin(testbed_text):
    text = testbed_text.replace("origin_m = [0.0, 0.0, 0.0]", "origin_m = [1.5, -2.0, 3.25]", 1)
    assert text != testbed_text
    cfg = parse_config(text, "moved.toml")
    p = antenna_positions(cfg, np.zeros((1, 10)))[0]
    np.testing.assert_allclose(p, np.asarray(cfg.antenna_position_m) + [1.5, -2.0, 3.25], atol=1e-14)


@pytest.mark.parametrize("theta", [0.3, 2.5, -3.0, np.pi])
def test_pure_rigid_rotation_rotates_about_vertical(testbed_cfg, theta):
    q = np.zeros((1, 10))
    q[0, 9] = theta
    p = antenna_positions(testbed_cfg, q)[0]
    r = np.asarray(testbed_cfg.antenna_position_m)
    c, s = np.cos(theta), np.sin(theta)
    expected = np.column_stack([c * r[:, 0] - s * r[:, 1], s * r[:, 0] + c * r[:, 1], r[:, 2]])
    np.testing.assert_allclose(p, expected, atol=1e-14)


def test_pure_rigid_rotation_about_offset_origin(testbed_text):
    text = testbed_text.replace("origin_m = [0.0, 0.0, 0.0]", "origin_m = [5.0, 6.0, 1.0]", 1)
    cfg = parse_config(text, "moved.toml")
    q = np.zeros((1, 10))
    q[0, 9] = 2.5
    p = antenna_positions(cfg, q)[0]
    expected = np.array([5.0, 6.0, 1.0]) + np.asarray(cfg.antenna_position_m) @ Rz(2.5).T
    np.testing.assert_allclose(p, expected, atol=1e-13)


def test_dof2_hub_rotations_are_exact(dof2_cfg):
    q = np.array([[2.0, -2.9]])
    p = antenna_positions(dof2_cfg, q)[0]
    np.testing.assert_allclose(p[0], Rz(2.0) @ [1, 0, 0], atol=1e-14)
    np.testing.assert_allclose(p[1], Rz(2.0) @ [-1, 0, 0], atol=1e-14)
    np.testing.assert_allclose(p[2], Rz(-2.9) @ [0, 1, -2], atol=1e-14)
    np.testing.assert_allclose(p[3], Rz(-2.9) @ [0, -1, -2], atol=1e-14)


def test_section_twist_about_pivot(testbed_cfg):
    """q8 = 0.5 rad twists C3 about its pivot (4, 0, 0): a5 = (4, 1, 0.05) → (4, cos−0.05 sin, sin+0.05 cos)."""
    q = np.zeros((1, 10))
    q[0, 7] = 0.5
    q[0, 6] = 0.1             # plus a lateral translation of C3
    p = antenna_positions(testbed_cfg, q)[0]
    a5 = testbed_cfg.antenna_names.index("a5")
    c, s = np.cos(0.5), np.sin(0.5)
    np.testing.assert_allclose(p[a5], [4.0, c - 0.05 * s + 0.1, s + 0.05 * c], atol=1e-14)
    # other sections do not move
    a1 = testbed_cfg.antenna_names.index("a1")
    np.testing.assert_allclose(p[a1], [-4.0, 1.0, 0.05], atol=1e-15)


# --------------------------------------------------------------------------------------------
# gyros and thrusters


def test_gyro_matrix_testbed(testbed_cfg):
    G = gyro_matrix(testbed_cfg)
    assert G.shape == (6, 10)
    names = testbed_cfg.gyro_names
    expected = np.zeros((6, 10))
    expected[names.index("g1"), 1] = 1        # C1 x: q̇2
    expected[names.index("g2"), [2, 9]] = 1   # C1 z: q̇3 + q̇10
    expected[names.index("g3"), 4] = 1        # C2 x: q̇5
    expected[names.index("g4"), [5, 9]] = 1   # C2 z: q̇6 + q̇10
    expected[names.index("g5"), [5, 9]] = 1
    expected[names.index("g6"), 7] = 1        # C3 x: q̇8
    np.testing.assert_array_equal(G, expected)
    qdot = np.random.default_rng(0).normal(size=10)
    assert G[names.index("g4")] @ qdot == pytest.approx(qdot[5] + qdot[9], abs=1e-15)


def test_dof2_has_no_gyros(dof2_cfg):
    assert gyro_matrix(dof2_cfg).shape == (0, 2)


def test_pulse_thrusters_generalized_force(testbed_cfg):
    """Fig. 9: zero net force and zero torque on the rigid-body coordinate, q5 pushed positive,
    q8 negative (each thruster on a 1 m arm: ±2 N·m per newton)."""
    cfg = testbed_cfg
    Ups = thruster_forcing(cfg)
    assert Ups.shape == (10, 24)
    cols = [cfg.thruster_names.index(n) for n in cfg.simulation["pulse_thrusters"]]
    assert len(cols) == 4
    F = Ups[:, cols].sum(axis=1)
    assert F[9] == pytest.approx(0.0, abs=1e-12)          # rigid body q10
    assert F[4] > 0 and F[4] == pytest.approx(2.0)        # q5 (centre twist)
    assert F[7] < 0 and F[7] == pytest.approx(-2.0)       # q8 (end twist)
    assert F[1] == pytest.approx(0.0, abs=1e-12)          # q2 only through the beam
    np.testing.assert_allclose(F[[0, 2, 3, 5, 6, 8]], 0.0, atol=1e-12)
    # net linear force of the four thrusters is zero
    assert np.asarray(cfg.thruster_direction)[cols].sum(axis=0) == pytest.approx([0, 0, 0])


def test_horizontal_thruster_torques_rigid_coordinate(testbed_cfg):
    """a1+x: r = (−4, 1, 0), F = (1, 0, 0) → torque about z = −1 on q10 and on q3 (about C1's pivot)."""
    cfg = testbed_cfg
    Ups = thruster_forcing(cfg)
    k = cfg.thruster_names.index("a1+x")
    expected = np.zeros(10)
    expected[2] = -1.0
    expected[9] = -1.0
    np.testing.assert_allclose(Ups[:, k], expected, atol=1e-12)
    k = cfg.thruster_names.index("a5+z")            # (4, 1, 0) up on C3: +1 on q8 only
    expected = np.zeros(10)
    expected[7] = 1.0
    np.testing.assert_allclose(Ups[:, k], expected, atol=1e-12)


def test_dof2_has_no_thrusters(dof2_cfg):
    assert thruster_forcing(dof2_cfg).shape == (2, 0)
