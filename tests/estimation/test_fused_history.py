"""The fused path's history (issue 29, helper `fusedisk`): each distinct transition (A, Q) stored once
with a per-epoch number, the smoother over it equal to the one over expanded (N, n, n) arrays, and
the fused filter's x, P on disk (smoothed backwards in blocks) equal to the run in memory: exact
array equality."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.config.sensors import sensor_specs
from cdgps_cli.config.structure import load_config
from cdgps_cli.estimation.driver import RecordingSink
from cdgps_cli.estimation.smoother import rts_smooth_indexed, rts_smooth_transitions
from cdgps_cli.io.scratch import DiskHistory
from cdgps_cli.measurement.gnss_position import GnssPosition
from cdgps_cli.measurement.sensor import align_epochs
from cdgps_cli.model.fusion_dynamics import ModalDisturbance
from cdgps_cli.model.kinematics import antenna_positions
from cdgps_cli.pipeline.fusion import fusion_problem, run_fused, sensor_parts
from cdgps_cli.sim.sensors import disturbance_truth, simulate_sensor_logs
from cdgps_cli.sim.structure import SimOptions, simulate

CFG = load_config("configs/tower-fusion.toml")


def _random_case(N=60, n=4, seed=3):
    rng = np.random.default_rng(seed)
    xf = rng.standard_normal((N, n))
    L = rng.standard_normal((N, n, n)) * 0.3
    Pf = L @ L.transpose(0, 2, 1) + 0.1 * np.eye(n)
    pairs = []
    for _ in range(3):
        A = np.eye(n) + 0.05 * rng.standard_normal((n, n))
        M = 0.1 * rng.standard_normal((n, n))
        pairs.append((A, M @ M.T + 0.01 * np.eye(n)))
    pair_of = np.r_[-1, np.repeat([0, 1, 0, 2, 2, 1], [10, 7, 15, 1, 20, 6])]
    return xf, Pf, pairs, pair_of


def test_sink_stores_each_transition_once_and_expands_to_the_per_epoch_arrays():
    xf, Pf, pairs, pair_of = _random_case()
    sink = RecordingSink(len(pair_of), 4)
    for k in range(1, len(pair_of)):
        A, Q = pairs[pair_of[k]]
        sink.transition(k, A.copy(), Q.copy())
    assert len(sink.pairs) == 3 and sink.pair_of[0] == -1
    As = np.array([np.zeros((4, 4))] + [pairs[i][0] for i in pair_of[1:]])
    Qs = np.array([np.zeros((4, 4))] + [pairs[i][1] for i in pair_of[1:]])
    assert np.array_equal(sink.A, As) and np.array_equal(sink.Q, Qs)
    # an epoch unequal to the previous one (NaN ≠ NaN) starts a stretch of its own even with equal bytes
    s2 = RecordingSink(3, 1)
    nan = np.array([[np.nan]])
    s2.transition(1, nan, nan)
    s2.transition(2, nan, nan)
    assert s2.pair_of[1] != s2.pair_of[2]


@pytest.mark.parametrize("chunk", [None, 1, 4, 9, 1000])
def test_indexed_smoother_equals_the_expanded_one(chunk):
    xf, Pf, pairs, pair_of = _random_case()
    As = np.array([np.zeros((4, 4))] + [pairs[i][0] for i in pair_of[1:]])
    Qs = np.array([np.zeros((4, 4))] + [pairs[i][1] for i in pair_of[1:]])
    ref_x, ref_P = rts_smooth_transitions(xf, Pf, As, Qs)
    done = []
    x, P = rts_smooth_indexed(xf.copy(), Pf.copy(), pairs, pair_of, chunk=chunk,
                              on_done=lambda a, b: done.append((a, b)))
    assert np.array_equal(x, ref_x) and np.array_equal(P, ref_P)
    assert not np.array_equal(x, xf)                                # (it did smooth)
    covered = np.zeros(len(xf), bool)
    for a, b in done:
        covered[a:b] = True
    assert covered.all() and done[-1][0] == 0


class CountingDisk(DiskHistory):
    made = 0

    def empty(self, shape, dtype=np.float64):
        CountingDisk.made += 1
        return super().empty(shape, dtype)


def test_fused_run_on_disk_in_blocks_equals_the_run_in_memory(tmp_path):
    sim = simulate(CFG, SimOptions(duration_s=3.0, seed=4, scenario="free"))
    t, nm = sim.time_s, CFG.n_modes
    logs = simulate_sensor_logs(CFG, sensor_specs(CFG), t, disturbance_truth(CFG, sim.x), seed=4)
    top = CFG.antenna_names.index("top")
    p = antenna_positions(CFG, sim.q)[:, top] - antenna_positions(CFG, np.zeros((1, 4)))[0, top]
    rng = np.random.default_rng(1)
    gnss = GnssPosition(CFG, "top", p[::10] + rng.standard_normal((t[::10].size, 3)) * 0.02, align_epochs(t, t[::10]), 0.02)
    P0m = np.diag(np.r_[np.full(nm, 0.01), np.full(nm, 0.1)])
    parts = sensor_parts(CFG, sensor_specs(CFG), logs, t, ("accel", "tilt"), S=ModalDisturbance(CFG).S)
    model, dyn, P0, _ = fusion_problem(CFG, [("gnss", gnss)], parts, P0m)
    ref = run_fused(model, dyn, t, np.zeros(dyn.n), P0, max_iterations=1)
    CountingDisk.made = 0
    got = run_fused(model, dyn, t, np.zeros(dyn.n), P0, max_iterations=1, store=CountingDisk(tmp_path),
                    chunk_epochs=37, keep=2 * nm)
    # the history's x and P, then the reported x_filt, P_filt and smoothed P on disk (the smoothed x is
    # the history's, smoothed in place), nothing left behind
    assert CountingDisk.made == 5 and not list(tmp_path.iterdir())
    for name in ("x", "P", "x_filt", "P_filt"):
        assert isinstance(getattr(got, name), np.memmap), name
    for name in ("x", "x_filt", "nis", "nis_dof"):
        assert np.array_equal(getattr(got, name), getattr(ref, name), equal_nan=True), name
    for name in ("P", "P_filt"):
        assert np.array_equal(getattr(got, name), getattr(ref, name)[:, :2 * nm, :2 * nm]), name
    assert not np.array_equal(got.x, got.x_filt)


def test_gated_rows_made_again_equal_the_rows_kept():
    """With a tight outlier gate (several drops in one epoch), the rows the fused path makes again
    from the model and the gate's events are the rows the updates used, array for array."""
    from cdgps_cli.estimation.model_filter import outlier_gate
    from cdgps_cli.pipeline.fusion import GatedRows

    sim = simulate(CFG, SimOptions(duration_s=2.0, seed=5, scenario="free"))
    t, nm = sim.time_s, CFG.n_modes
    logs = simulate_sensor_logs(CFG, sensor_specs(CFG), t, disturbance_truth(CFG, sim.x), seed=5)
    top = CFG.antenna_names.index("top")
    p = antenna_positions(CFG, sim.q)[:, top] - antenna_positions(CFG, np.zeros((1, 4)))[0, top]
    gnss = GnssPosition(CFG, "top", p[::10] + 0.02, align_epochs(t, t[::10]), 0.02)
    P0m = np.diag(np.r_[np.full(nm, 0.01), np.full(nm, 0.1)])
    parts = sensor_parts(CFG, sensor_specs(CFG), logs, t, ("accel", "tilt", "gyro"), S=ModalDisturbance(CFG).S)
    model, dyn, P0, _ = fusion_problem(CFG, [("gnss", gnss)], parts, P0m)
    ev_a, ev_b = [], []
    ref = run_fused(model, dyn, t, np.zeros(dyn.n), P0, max_iterations=1, rows_hook=outlier_gate(model, 0.7, ev_a, t))
    got = run_fused(model, dyn, t, np.zeros(dyn.n), P0, max_iterations=1, rows_hook=outlier_gate(model, 0.7, ev_b, t),
                    gate_events=ev_b)
    assert isinstance(got.rows, GatedRows) and len(got.rows) == len(ref.rows)
    per_epoch = np.bincount([e["epoch"] for e in ev_b])
    assert per_epoch.max() >= 2 and any(r is None for r in ref.rows)
    for k, (a, b) in enumerate(zip(ref.rows, got.rows)):
        assert (a is None) == (b is None), k
        if a is not None:
            assert a.labels == b.labels and np.array_equal(a.z_m, b.z_m) and np.array_equal(a.covariance(), b.covariance())
    assert np.array_equal(got.x, ref.x) and ev_a == ev_b
