"""GNSS + accelerometer fusion end to end in the library (short records): the simulator's sensor logs,
the fused filter and smoother are consistent (NEES, NIS) and beat GNSS alone above 1 Hz."""

import numpy as np
import pytest

from cdgps_cli.config.sensors import sensor_specs
from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.gnss_position import GnssPosition
from cdgps_cli.measurement.sensor import align_epochs
from cdgps_cli.measurement.stacked import Stacked
from cdgps_cli.model.dynamics_models import ModalZOH
from cdgps_cli.model.fusion_dynamics import ModalDisturbance
from cdgps_cli.model.kinematics import antenna_positions
from cdgps_cli.pipeline.fusion import common_time_axis, fusion_problem, parse_fuse, run_fused, sensor_parts
from cdgps_cli.sim.sensors import disturbance_truth, simulate_sensor_logs
from cdgps_cli.sim.structure import SimOptions, simulate

CFG = load_config("configs/tower-fusion.toml")


@pytest.fixture(scope="module")
def case():
    sim = simulate(CFG, SimOptions(duration_s=20.0, seed=4, scenario="free"))
    x_aug = disturbance_truth(CFG, sim.x)
    specs = sensor_specs(CFG)
    logs = simulate_sensor_logs(CFG, specs, sim.time_s, x_aug, seed=4)
    return sim, x_aug, specs, logs


def test_disturbance_truth_reproduces_the_trajectory(case):
    sim, x_aug, _, _ = case
    A, _, _ = ModalDisturbance(CFG).transition(CFG.sample_period_s)
    assert np.allclose(x_aug[1:, :8], x_aug[:-1] @ A[:8].T, atol=1e-12)


def test_sensor_logs_columns_rates_and_bias(case):
    sim, _, specs, logs = case
    assert set(logs) == {"accel", "tilt", "gyro", "_truth"}
    acc = logs["accel"]
    assert list(acc.columns) == ["time_s", "sensor", "accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]
    assert (acc["sensor"] == "acc-top").sum() == sim.time_s.size and acc[acc["sensor"] == "acc-mid"]["accel_y_m_s2"].isna().all()
    assert len(logs["tilt"]) == len(sim.time_s[::10]) and list(logs["tilt"].columns) == ["time_s", "sensor", "tilt_y_rad"]
    assert list(logs["gyro"].columns) == ["time_s", "sensor", "gyro_y_rad_s"]
    # the z axis sees no motion: its mean is the bias (prior σ 0.01 m/s²), its spread the noise
    z = acc[acc["sensor"] == "acc-top"]["accel_z_m_s2"].to_numpy()
    tr = logs["_truth"]["acc-top"]
    assert abs(z.mean() - tr["initial_bias_accel_z_m_s2"]) < 5e-4 and abs(z.std() - 0.002) < 3e-4


def test_fused_beats_gnss_alone_and_is_consistent(case):
    sim, x_aug, specs, logs = case
    t, x, nm = sim.time_s, sim.x, CFG.n_modes
    top = CFG.antenna_names.index("top")
    p = antenna_positions(CFG, sim.q)[:, top] - antenna_positions(CFG, np.zeros((1, 4)))[0, top]
    rng = np.random.default_rng(1)
    gnss = GnssPosition(CFG, "top", p[::10] + rng.standard_normal((t[::10].size, 3)) * 0.02, align_epochs(t, t[::10]), 0.02)
    amp = CFG.simulation["initial_modal_sigma"]
    P0m = np.diag(np.r_[np.full(nm, amp**2), (amp * 2 * np.pi * np.asarray(CFG.mode_frequency_hz)) ** 2])
    alone = run_fused(Stacked([("gnss", gnss)], 2 * nm), ModalZOH(CFG), t, np.zeros(2 * nm), P0m, max_iterations=1)
    parts = sensor_parts(CFG, specs, logs, t, ("accel",), S=ModalDisturbance(CFG).S)
    assert [n for n, _ in parts] == ["acc-top", "acc-mid"]
    model, dyn, P0, names = fusion_problem(CFG, [("gnss", gnss)], parts, P0m)
    assert names[:4] == ["d_bend-1", "d_bend-2", "d_bend-3", "d_bend-4"] and len(names) == 8
    fused = run_fused(model, dyn, t, np.zeros(dyn.n), P0, max_iterations=1)
    U = np.asarray(CFG.mode_shapes)
    e_a = (alone.x[:, :nm] - x[:, :nm]) @ U.T @ np.ones(4)
    e_f = (fused.x[:, :nm] - x[:, :nm]) @ U.T @ np.ones(4)
    assert np.sqrt(np.mean(e_f[500:] ** 2)) < 0.5 * np.sqrt(np.mean(e_a[500:] ** 2))
    e = fused.x_filt[500:, :8] - x[500:]
    nees = np.einsum("ki,ki->k", e, np.linalg.solve(fused.P_filt[500:, :8, :8], e[..., None])[..., 0]).mean() / 8
    assert 0.6 < nees < 1.6
    assert 0.8 < np.nansum(fused.nis) / fused.nis_dof.sum() < 1.2


def test_hold_out_and_missing_logs(case):
    _, _, specs, logs = case
    t = np.arange(10) * 0.01
    parts = sensor_parts(CFG, specs, logs, t, ("accel", "tilt", "gyro"), hold_out=("acc-mid", "gyro-top"))
    assert [n for n, _ in parts] == ["acc-top", "tilt-top"]
    with pytest.raises(CdgpsError, match="--hold-out: nope"):
        sensor_parts(CFG, specs, logs, t, ("accel",), hold_out=("nope",))
    with pytest.raises(CdgpsError, match="no log of sensor 'tilt-top'"):
        sensor_parts(CFG, specs, {k: v for k, v in logs.items() if k != "tilt"}, t, ("tilt",))
    with pytest.raises(CdgpsError, match="has no tilt sensor"):
        sensor_parts(load_config("configs/gnss-tower.toml"), [], logs, t, ("tilt",))
    with pytest.raises(CdgpsError, match="sensor acc-top: no sample of its log"):
        sensor_parts(CFG, specs, logs, t + 1000.0, ("accel",))
    with pytest.raises(CdgpsError, match="--fuse accel,wind: unknown sensor kind"):
        parse_fuse("accel,wind")
    assert parse_fuse("gyro, accel") == ("gyro", "accel") and parse_fuse(None) == ()
    for text, msg in (("", "--fuse '': empty"), (" , ", "--fuse ' , ': empty"), ("accel,,gyro", "an empty item"),
                      ("gyro, accel,gyro", "--fuse gyro, accel,gyro: gyro given twice")):
        with pytest.raises(CdgpsError, match="expected a comma-separated list of gyro") as e:
            parse_fuse(text)
        assert msg in str(e.value), text


def test_common_time_axis():
    t = common_time_axis([0.0, 0.1, 0.2], [np.arange(0, 0.25, 0.05) + 1e-6, np.array([-1.0, 5.0])])
    assert np.allclose(t, [0.0, 0.05, 0.1, 0.15, 0.2], atol=2e-6) and t[2] == 0.1     # 0.1 + 1e-6 merged into the GNSS epoch


def test_fusion_choice_config_and_options():
    from cdgps_cli.config.structure import parse_config
    from cdgps_cli.pipeline.fusion import fusion_choice

    text = open("configs/tower-fusion.toml").read()
    assert fusion_choice(CFG, None) == ((), ())                                  # opt-in: nothing by default
    assert fusion_choice(CFG, "accel", ("acc-mid",)) == (("accel",), ("acc-mid",))
    cfg = parse_config(text + '\n[fusion]\nfuse = ["accel", "gyro"]\nhold_out = ["gyro-top"]\n')
    assert fusion_choice(cfg, None, ("acc-mid",)) == (("accel", "gyro"), ("gyro-top", "acc-mid"))
    assert fusion_choice(cfg, "tilt") == (("tilt",), ("gyro-top",))              # --fuse replaces [fusion] fuse
    with pytest.raises(CdgpsError, match=r"fusion.fuse: a kind given twice in \['accel', 'accel'\]"):  # (was read as accel)
        fusion_choice(parse_config(text + '\n[fusion]\nfuse = ["accel", "accel"]\n', "t.toml"), None)
    with pytest.raises(CdgpsError, match="--hold-out needs --fuse"):
        fusion_choice(CFG, None, ("acc-mid",))
    with pytest.raises(CdgpsError, match=r"--hold-out acc-top,acc-mid: every accel sensor is held out, so --fuse "
                                         r"accel would fuse no sensor at all"):      # (ran a fused filter of no sensor)
        fusion_choice(CFG, "accel", ("acc-top", "acc-mid"))


def test_fusion_choice_checks_the_config_sensors_before_the_run_is_filtered():
    """An unknown --hold-out name or a fused kind the config lacks is refused by fusion_choice itself
    (was: only in sensor_parts, after the modal batch initialization and setup of a long run)."""
    from cdgps_cli.pipeline.fusion import fusion_choice

    with pytest.raises(CdgpsError, match=r"--hold-out: nope is not a sensor of config 'tower-fusion'"):
        fusion_choice(CFG, "accel", ("nope",))
    with pytest.raises(CdgpsError, match=r"--fuse accel: config 'gnss-tower' has no accel sensor"):
        fusion_choice(load_config("configs/gnss-tower.toml"), "accel")
