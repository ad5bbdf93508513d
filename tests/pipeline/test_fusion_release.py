"""The fused path drops the pages of its on-disk history behind its passes (issue 29, helper
``fused29``): the sensors' residual summary read with the store's release equals the one read
without, and its releases cover every epoch."""

from __future__ import annotations

import numpy as np

from cdgps_cli.config.sensors import sensor_specs
from cdgps_cli.config.structure import load_config
from cdgps_cli.io.scratch import DiskHistory
from cdgps_cli.measurement.gnss_position import GnssPosition
from cdgps_cli.measurement.sensor import align_epochs
from cdgps_cli.model.fusion_dynamics import ModalDisturbance
from cdgps_cli.model.kinematics import antenna_positions
from cdgps_cli.pipeline.fusion import _sensor_summary, fusion_problem, run_fused, sensor_parts
from cdgps_cli.sim.sensors import disturbance_truth, simulate_sensor_logs
from cdgps_cli.sim.structure import SimOptions, simulate

CFG = load_config("configs/tower-fusion.toml")


def test_sensor_summary_with_releases_equals_without(tmp_path):
    sim = simulate(CFG, SimOptions(duration_s=1.5, seed=6, scenario="free"))
    t, nm = sim.time_s, CFG.n_modes
    logs = simulate_sensor_logs(CFG, sensor_specs(CFG), t, disturbance_truth(CFG, sim.x), seed=6)
    top = CFG.antenna_names.index("top")
    p = antenna_positions(CFG, sim.q)[:, top] - antenna_positions(CFG, np.zeros((1, 4)))[0, top]
    gnss = GnssPosition(CFG, "top", p[::10] + 0.01, align_epochs(t, t[::10]), 0.02)
    parts = sensor_parts(CFG, sensor_specs(CFG), logs, t, ("accel", "tilt", "gyro"), S=ModalDisturbance(CFG).S)
    model, dyn, P0, _ = fusion_problem(CFG, [("gnss", gnss)], parts, np.diag(np.r_[np.full(nm, 0.01), np.full(nm, 0.1)]))
    store = DiskHistory(tmp_path)
    r = run_fused(model, dyn, t, np.zeros(dyn.n), P0, max_iterations=1, store=store, chunk_epochs=16)
    ref = _sensor_summary(parts, r.x, r.rows)
    seen = []

    def release(arr, a, b):
        seen.append((a, b))
        store.release(arr, a, b)

    got = _sensor_summary(parts, r.x, r.rows, release=release, block=7)
    assert got == ref
    covered = np.zeros(len(t), bool)
    for a, b in seen:
        covered[a:b] = True
    assert covered.all() and len(seen) > len(t) // 7 - 1

