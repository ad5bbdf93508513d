"""The one forward driver (cdgps_cli/estimation/driver.py): its epoch order, its hooks, its sinks.

* a GNSS modal model through ``drive`` (what ``filter_numpy`` is now) equals the plain loop the
  engine's filter was before (predict, rows, gate, iterated update), bit for bit, with and without the
  outlier gate;
* two models in one epoch (sequential updates) equal one stacked update (independent noise) to
  rounding, and a model with no rows at an epoch (another rate) is skipped;
* hooks are called in the documented order, ``after`` can jump ahead, ``gate`` can drop the rows;
* a HistorySink on disk releases the chunks behind the filter and holds what the memory sink holds.
The pseudolite filter through ``drive`` is tests/estimation/test_estimate_golden.py (bit-identical
STATES to the stack before the driver).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from cdgps_cli.estimation.driver import EpochGrid, GridDynamics, HistorySink, Hook, RecordingSink, RowsGate, drive
from cdgps_cli.estimation.kalman import StepFilter
from cdgps_cli.estimation.model_filter import filter_numpy, outlier_gate
from cdgps_cli.io.scratch import DiskHistory
from cdgps_cli.measurement.model import MeasurementModel, Rows

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "estimation"))
sys.path.insert(0, str(ROOT / "tests" / "measurement"))
from test_model_filter import _case  # noqa: E402


def _plain_loop(model, dyn, time_s, x0, P0, max_iterations=5, rows_hook=None):
    """The engine's forward filter as it was written before the driver (the reference)."""
    n, ns = len(time_s), len(x0)
    xs, Ps, nis = np.zeros((n, ns)), np.zeros((n, ns, ns)), np.full(n, np.nan)
    step = StepFilter(x0, P0)
    for k in range(n):
        if k:
            A, _, Q = dyn.transition(float(time_s[k] - time_s[k - 1]))
            step.predict(A, Q)
        mk = model.rows(k)
        if mk is not None and rows_hook is not None:
            mk = rows_hook(k, mk, step.x, step.P)
        if mk is not None:
            nis[k] = step.update(model, mk, max_iterations)
        xs[k], Ps[k] = step.x, step.P
    return xs, Ps, nis


def test_gnss_modal_through_drive_is_the_plain_loop_bit_for_bit():
    for outlier in (None, (30, 2)):
        model, dyn, t, x0, P0 = _case(outlier=outlier)
        for gate in (False, True):
            ev1, ev2 = [], []
            hook1 = outlier_gate(model, 4.0, ev1, t) if gate else None
            hook2 = outlier_gate(model, 4.0, ev2, t) if gate else None
            xs, Ps, nis = _plain_loop(model, dyn, t, x0, P0, rows_hook=hook1)
            got = filter_numpy(model, dyn, t, x0, P0, rows_hook=hook2)
            np.testing.assert_array_equal(got["x"], xs)
            np.testing.assert_array_equal(got["P"], Ps)
            np.testing.assert_array_equal(got["nis"], nis)
            assert ev1 == ev2
            assert (len(ev1) > 0) == (gate and outlier is not None)


class _Linear(MeasurementModel):
    """z_k = C x_k + noise at the epochs where ``every`` divides k (a sensor of its own rate)."""

    def __init__(self, C, z, sigma, every=1):
        self.C, self.z, self.sigma, self.every = np.atleast_2d(C), z, np.asarray(sigma, float), every
        self.n_epochs, self.n_state, self.segment_keys = len(z), self.C.shape[1], []

    def rows(self, k):
        if k % self.every:
            return None
        m = self.C.shape[0]
        return Rows(self.z[k], [("s", i) for i in range(m)], np.full(m, -1), sigma_m=self.sigma.copy())

    def predict(self, x, rows):
        return self.C @ x, self.C


class _Dyn:
    identity_transition = False

    def transition(self, dt_s):
        A = np.array([[1.0, dt_s], [0.0, 1.0]])
        Q = np.array([[dt_s**3 / 3, dt_s**2 / 2], [dt_s**2 / 2, dt_s]]) * 0.01
        return A, None, Q


def test_two_models_sequential_equal_one_stacked_update_and_multi_rate():
    rng = np.random.default_rng(1)
    N = 60
    t = np.arange(N) * 0.1
    za = rng.normal(size=(N, 1))
    zb = rng.normal(size=(N, 1))
    a = _Linear([[1.0, 0.0]], za, [0.1])
    b = _Linear([[0.0, 1.0]], zb, [0.3], every=1)
    both = _Linear([[1.0, 0.0], [0.0, 1.0]], np.hstack([za, zb]), [0.1, 0.3])
    x0, P0 = np.zeros(2), np.eye(2)
    s1, s2 = RecordingSink(N, 2), RecordingSink(N, 2)
    c1 = drive(GridDynamics(_Dyn(), t), [a, b], EpochGrid(t), (x0, P0), sink=s1)
    c2 = drive(GridDynamics(_Dyn(), t), [both], EpochGrid(t), (x0, P0), sink=s2)
    np.testing.assert_allclose(s1.x, s2.x, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(s1.P, s2.P, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(c1.nis, c2.nis, rtol=1e-9)          # the NIS adds over independent blocks
    np.testing.assert_array_equal(c1.nis_dof, c2.nis_dof)
    # a velocity sensor at a tenth of the rate: no rows in between, dof 1 there
    slow = _Linear([[0.0, 1.0]], zb, [0.3], every=10)
    c3 = drive(GridDynamics(_Dyn(), t), [a, slow], EpochGrid(t), (x0, P0), sink=RecordingSink(N, 2))
    assert list(np.flatnonzero(c3.nis_dof == 2)) == list(range(0, N, 10))
    assert (c3.nis_dof[np.arange(N) % 10 != 0] == 1).all()


class _Recorder(Hook):
    def __init__(self, log, jump_at=None, drop_at=None):
        self.log, self.jump_at, self.drop_at = log, jump_at, drop_at

    def before_rows(self, ctx, k):
        self.log.append(("before_rows", k))

    def prepared(self, ctx, k):
        self.log.append(("prepared", k))

    def gate(self, ctx, k, model, rows):
        self.log.append(("gate", k))
        return None if k == self.drop_at else rows

    def updated(self, ctx, k, model, rows, nis):
        self.log.append(("updated", k))

    def after(self, ctx, k, k_next):
        self.log.append(("after", k))
        return k + 3 if k == self.jump_at else k_next


def test_hook_order_jump_and_drop():
    N = 8
    t = np.arange(N, dtype=float)
    m = _Linear([[1.0, 0.0]], np.zeros((N, 1)), [0.1])
    log: list = []
    sink = RecordingSink(N, 2)
    ctx = drive(GridDynamics(_Dyn(), t), [m], EpochGrid(t), (np.zeros(2), np.eye(2)),
                [_Recorder(log, jump_at=2, drop_at=6)], sink)
    seen = sorted({k for _, k in log})
    assert seen == [0, 1, 2, 5, 6, 7]                         # 3 and 4 skipped by the jump
    assert log[:5] == [("before_rows", 0), ("prepared", 0), ("gate", 0), ("updated", 0), ("after", 0)]
    assert ("updated", 6) not in log and ctx.nis_dof[6] == 0 and np.isnan(ctx.nis[6])
    assert np.all(sink.x[3:5] == 0.0)                          # never written


def test_history_sink_on_disk_releases_and_equals_memory(tmp_path):
    rng = np.random.default_rng(2)
    N = 50
    t = np.arange(N) * 0.1
    m = _Linear([[1.0, 0.0]], rng.normal(size=(N, 1)), [0.1])
    released = []

    class Spy(DiskHistory):
        def release(self, arr, start, stop):
            released.append((start, stop))
            return super().release(arr, start, stop)

    disk = HistorySink(N, 2, Spy(tmp_path), chunk_epochs=16)
    mem = HistorySink(N, 2)
    drive(GridDynamics(_Dyn(), t), [m], EpochGrid(t, 16), (np.zeros(2), np.eye(2)), sink=disk)
    drive(GridDynamics(_Dyn(), t), [m], EpochGrid(t), (np.zeros(2), np.eye(2)), sink=mem)
    assert disk.on_disk and not mem.on_disk
    np.testing.assert_array_equal(np.asarray(disk.xs), mem.xs)
    np.testing.assert_array_equal(np.asarray(disk.Ps), mem.Ps)
    np.testing.assert_array_equal(disk.nis, mem.nis)
    assert (0, 48) in released and all(b % 16 == 0 for _, b in released)


def test_rows_gate_adapts_a_rows_hook():
    calls = []

    def fn(k, rows, x, P):
        calls.append(k)
        return rows

    class Ctx:
        x, P = np.zeros(2), np.eye(2)

    r = Rows(np.zeros(1), [("a", 0)], np.full(1, -1), sigma_m=np.ones(1))
    assert RowsGate(fn).gate(Ctx(), 4, None, r) is r and calls == [4]


def test_static_dynamics_skips_the_prediction_bit_for_bit():
    """A Static dynamics (identity, no process noise) is not predicted at all (A and Q None from
    GridDynamics) and a transition is built once per step length: x, P, NIS and the recorded (A, Q) are
    those of the same filter with the prediction P + 0 done every epoch; a bad step length still raises."""
    from cdgps_cli.model.dynamics_models import Static, WithConstants
    import pytest

    class _Plain:                                   # Static without its flags: predicted every epoch
        def __init__(self, n):
            self.n, self.n_u, self.identity_transition = n, 0, False
            self.calls = 0

        def transition(self, dt_s):
            self.calls += 1
            return np.eye(self.n), np.zeros((self.n, 0)), np.zeros((self.n, self.n))

    rng = np.random.default_rng(3)
    N = 40
    t = np.r_[np.arange(20) * 1.0, 20.5 + np.arange(20) * 1.0]          # two step lengths
    z = rng.normal(size=(N, 1))
    model = _Linear([[1.0, 0.5]], z, [0.1])
    x0, P0 = np.zeros(2), np.eye(2)
    runs = []
    for dyn in (Static(2), WithConstants(Static(1), 1), _Plain(2)):
        g = GridDynamics(dyn, t)
        if not isinstance(dyn, _Plain):
            assert g.still and g.step_into(1) == (None, None, None)
        sink = RecordingSink(N, 2)
        ctx = drive(g, [model], EpochGrid(t), (x0, P0), sink=sink, max_iterations=2)
        runs.append((sink.x, sink.P, ctx.nis, sink.A, sink.Q))
    assert runs[2][0].any() and runs[2][1].any()
    for r in runs[:2]:
        for a, b in zip(r, runs[2]):
            assert np.array_equal(a, b)
    cached = _Plain(2)
    drive(GridDynamics(cached, t), [model], EpochGrid(t), (x0, P0), sink=RecordingSink(N, 2))
    assert cached.calls == 3                        # 1.0 s, 1.5 s, then 1.0 s again
    with pytest.raises(ValueError, match="dt_s"):
        GridDynamics(Static(2), np.array([0.0, 1.0, 1.0])).step_into(2)
