"""Independent checks of the sensor models (accelerometer, tilt meter, rate gyro, GNSS position)."""

import numpy as np

from cdgps_cli.config.structure import load_config, parse_config
from cdgps_cli.measurement.accelerometer import Accelerometer
from cdgps_cli.measurement.gnss_position import GnssPosition
from cdgps_cli.measurement.gyro import RateGyro
from cdgps_cli.measurement.sensor import align_epochs, place
from cdgps_cli.measurement.tilt import TiltMeter
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.model.kinematics import antenna_positions, gyro_matrix

ONE_MODE = """
[model]
name = "one-mode"
sample_period_s = 0.001
measurement_sigma_m = 0.003
[[coordinates]]
name = "q"
kind = "modal"
[[antennas]]
name = "base"
position_m = [0.0, 0.0, 0.0]
master = true
[[antennas]]
name = "top"
position_m = [0.0, 0.0, 10.0]
displacement_m = { q = [0.8, 0.0, 0.0] }
[[transmitters]]
name = "GPS"
direction = [0.0, 0.0, 1.0]
[[modes]]
name = "m1"
frequency_hz = 2.0
damping_ratio = 0.02
shape = [1.0]
[process_noise]
space = "modal"
sigma = [0.01]
"""


def _one():
    return parse_config(ONE_MODE)


def test_accel_single_mode_amplitude():
    """ξ = A cos ωt with the shape 0.8 m at the point: the acceleration amplitude is 0.8 ω² A."""
    cfg = _one()
    acc = Accelerometer(cfg, "a", "top", "x", np.zeros((1, 1)), [0], 1e-3, gravity_m_s2=0.0)
    w = 2 * np.pi * 2.0
    A = 0.05
    r = acc.rows(0)
    h, _ = acc.predict(np.array([A, 0.0]), r)            # at the extreme: ξ̇ = 0, ξ̈ = −ω² A
    assert np.isclose(h[0], -0.8 * w**2 * A, rtol=1e-12)


def test_accel_matches_second_difference_of_motion():
    """Free vibration integrated at 1 kHz: the model's acceleration at each epoch equals the second
    difference of the point's position (to O(Δt²))."""
    cfg = _one()
    dm = discrete_model(cfg)
    x = np.empty((400, 2))
    x[0] = [0.03, 0.1]
    for k in range(1, 400):
        x[k] = dm.A @ x[k - 1]
    p = antenna_positions(cfg, x[:, :1] @ np.asarray(cfg.mode_shapes).T)[:, 1, 0]
    dt = cfg.sample_period_s
    a_fd = (p[2:] - 2 * p[1:-1] + p[:-2]) / dt**2
    acc = Accelerometer(cfg, "a", "top", "x", np.zeros((1, 1)), [0], 1e-3)
    a_model = np.array([acc.predict(x[k], acc.rows(0))[0][0] for k in range(1, 399)])
    assert np.max(np.abs(a_model - a_fd)) < 1e-4 * np.max(np.abs(a_fd))


def test_accel_disturbance_and_bias_columns():
    cfg = _one()
    acc = Accelerometer(cfg, "a", "top", ["x", "z"], np.zeros((1, 2)), [0], 1e-3, bias_sigma_m_s2=0.01,
                        disturbance=np.eye(1))
    assert acc.n_core == 3 and acc.n_state == 5
    h, H = acc.predict(np.array([0.0, 0.0, 2.0, 0.1, -0.2]), acc.rows(0))
    assert np.allclose(h, [0.8 * 2.0 + 0.1, -0.2])           # d enters through the shape; z reads only its bias
    assert np.allclose(H[:, 3:], np.eye(2))


def test_accel_gravity_tilt_term():
    """A horizontal x axis on a mount turned by θ about y reads −g θ."""
    cfg = _one()
    rot = np.zeros((3, 1))
    rot[1, 0] = 0.01                                          # θ_y = 0.01 rad per unit ξ
    acc = Accelerometer(cfg, "a", "top", "x", np.zeros((1, 1)), [0], 1e-3, rotation_rad=rot)
    acc0 = Accelerometer(cfg, "a", "top", "x", np.zeros((1, 1)), [0], 1e-3, rotation_rad=rot, gravity_m_s2=0.0)
    x = np.array([0.5, 0.0])
    dh = acc.predict(x, acc.rows(0))[0][0] - acc0.predict(x, acc0.rows(0))[0][0]
    assert np.isclose(dh, -9.80665 * 0.01 * 0.5)


def test_tilt_reads_section_rotation_and_gyro_is_its_rate():
    """Testbed section C1 rotates about x by q2: a tilt meter there reads q2; the gyro map's rate
    equals the time derivative of the tilt (finite differences of a simulated free motion)."""
    cfg = load_config("configs/testbed-1998.toml")
    sec = [s.name for s in cfg.sections].index("C1")
    tilt = TiltMeter(cfg, "t", "x", np.zeros((1, 1)), [0], 1e-4, section=sec)
    U = np.asarray(cfg.mode_shapes)
    rng = np.random.default_rng(1)
    xi = rng.standard_normal(cfg.n_modes) * 0.01
    q = U @ xi
    h, _ = tilt.predict(np.r_[xi, np.zeros(cfg.n_modes)], tilt.rows(0))
    assert np.isclose(h[0], q[cfg.coord_names.index("q2")])
    # rate: a gyro on the same mount and axis as the tilt meter (gyro_matrix of the config's gyros)
    g = gyro_matrix(cfg)
    gy = RateGyro(cfg, list(cfg.gyro_names), np.zeros((1, len(cfg.gyro_names))), [0], 1e-3)
    xdot = rng.standard_normal(cfg.n_modes) * 0.01
    hg, _ = gy.predict(np.r_[xi, xdot], gy.rows(0))
    assert np.allclose(hg, g @ U @ xdot)
    dm = discrete_model(cfg, 1e-3)
    x0 = np.r_[xi, xdot]
    x1 = dm.A @ x0
    t0 = TiltMeter(cfg, "t", "z", np.zeros((1, 1)), [0], 1e-4, section=sec)
    rate_fd = (t0.predict(x1, t0.rows(0))[0] - t0.predict(x0, t0.rows(0))[0]) / 1e-3
    assert np.allclose(rate_fd, t0.M[:, :cfg.n_modes] @ (x0[cfg.n_modes:] + x1[cfg.n_modes:]) / 2, rtol=1e-3, atol=1e-9)


def test_gnss_position_is_antenna_displacement():
    cfg = load_config("configs/testbed-1998.toml")
    a = cfg.antenna_names[-1]
    m = GnssPosition(cfg, a, np.zeros((1, 3)), [0], 0.02)
    xi = np.random.default_rng(2).standard_normal(cfg.n_modes) * 0.05
    q = np.asarray(cfg.mode_shapes) @ xi
    p = antenna_positions(cfg, np.stack([q, 0 * q]))
    h, _ = m.predict(np.r_[xi, 0 * xi], m.rows(0))
    assert np.allclose(h, p[0, -1] - p[1, -1])


def test_multirate_rows_and_placement():
    t = np.round(np.arange(0, 1.0, 0.01), 9)
    ts = t[::10]
    k_of = align_epochs(t, ts)
    assert np.count_nonzero(k_of >= 0) == ts.size and k_of[10] == 1 and k_of[11] == -1
    cfg = _one()
    a1 = Accelerometer(cfg, "a1", "top", "x", np.zeros((t.size, 1)), np.arange(t.size), 1e-3, 0.01, 1e-4)
    a2 = TiltMeter(cfg, "t1", "y", np.zeros((ts.size, 1)), k_of, 1e-4, bias_sigma_rad=1e-3)
    n = place([a1, a2], 2)
    assert n == 4 and a1.bias_offset == 2 and a2.bias_offset == 3 and a2.n_state == 4
    assert a2.rows(11) is None and a2.rows(10) is not None
