"""``drive`` over a streaming EpochSource (cdgps_cli/estimation/driver.py, issue 29):

* a model and dynamics fed block by block from a :class:`BlockSource` (times and measurements read
  through an injected ``read(a, b)``, nothing kept between blocks) give exactly the arrays of the
  same filter over an :class:`EpochGrid` with whole arrays, for block lengths 1, 7 and N, with a
  second model at another rate, with hooks that jump ahead;
* the reader is asked for each block once, in order, never for more than one block's epochs, and
  every block reaches ``load`` even when a hook jumps over it;
* a source whose blocks end early is refused (ValueError naming the epoch).
"""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.estimation.driver import (BlockSource, EpochBlock, EpochGrid, EpochSource, GridDynamics, Hook,
                                         RecordingSink, drive)
from cdgps_cli.measurement.model import MeasurementModel, Rows
from tests.estimation.test_driver import _Dyn  # the constant-velocity dynamics of the driver tests


class _Whole(MeasurementModel):
    """z_k = C x_k + noise from a whole (N, m) array (NaN: no rows at k)."""

    def __init__(self, C, z, sigma):
        self.C, self.z, self.sigma = np.atleast_2d(C), z, np.asarray(sigma, float)

    def rows(self, k):
        zk = self.z[k]
        if np.isnan(zk).any():
            return None
        m = self.C.shape[0]
        return Rows(zk.copy(), [("s", i) for i in range(m)], np.full(m, -1), sigma_m=self.sigma.copy())

    def predict(self, x, rows):
        return self.C @ x, self.C


class _Streamed(_Whole):
    """The same rows from the loaded block's ``data[name]`` only (no whole array)."""

    def __init__(self, C, name, sigma):
        super().__init__(C, None, sigma)
        self.name, self.start, self.loads = name, 0, []

    def load(self, block: EpochBlock) -> None:
        self.z, self.start = block.data[self.name], block.start
        self.loads.append((block.start, block.stop))

    def rows(self, k):
        return _Whole.rows(self, k - self.start)


class _Jump(Hook):
    """After epoch ``at``, go on at ``to`` (a batch re-initialization)."""

    def __init__(self, at, to):
        self.at, self.to = at, to

    def after(self, ctx, k, k_next):
        return self.to if k == self.at else k_next


def _record(N=53, seed=2):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.05, 0.15, N))
    za = rng.normal(size=(N, 1))
    zb = rng.normal(size=(N, 1))
    zb[np.arange(N) % 3 != 0] = np.nan           # a sensor of a third of the rate
    return t, za, zb


def _run(source, models, dyn, hooks=(), N=53):
    sink = RecordingSink(N, 2)
    ctx = drive(dyn, models, source, (np.zeros(2), np.eye(2)), hooks=hooks, sink=sink)
    return sink, ctx


@pytest.mark.parametrize("block", [1, 7, 53, 1000])
@pytest.mark.parametrize("jump", [False, True])
def test_block_source_equals_the_grid_exactly(block, jump):
    t, za, zb = _record()
    N = t.size
    hooks = [_Jump(10, 31)] if jump else []
    ref, rctx = _run(EpochGrid(t), [_Whole([[1.0, 0.0]], za, [0.1]), _Whole([[0.0, 1.0]], zb, [0.3])],
                     GridDynamics(_Dyn(), t), hooks, N)
    asked = []

    def read(a, b):
        asked.append((a, b))
        return t[a:b].copy(), {"a": za[a:b].copy(), "b": zb[a:b].copy()}

    src = BlockSource(N, read, block)
    assert isinstance(src, EpochSource) and isinstance(EpochGrid(t), EpochSource)
    ma, mb = _Streamed([[1.0, 0.0]], "a", [0.1]), _Streamed([[0.0, 1.0]], "b", [0.3])
    got, gctx = _run(src, [ma, mb], GridDynamics(_Dyn()), hooks, N)
    assert np.array_equal(got.x, ref.x) and np.array_equal(got.P, ref.P)
    assert np.array_equal(gctx.nis, rctx.nis, equal_nan=True) and np.array_equal(gctx.nis_dof, rctx.nis_dof)
    assert np.array_equal(got.pair_of, ref.pair_of)
    assert not np.array_equal(got.x[5], np.zeros(2))                     # (it did filter)
    # each block read once, in order, one block's epochs at a time, all of them loaded
    starts = list(range(0, N, block))
    assert asked == [(a, min(a + block, N)) for a in starts]
    assert ma.loads == mb.loads == asked


def test_grid_blocks_are_the_sink_chunks_and_start_at_the_chunk_of_k0():
    t = np.arange(10) * 0.5
    g = EpochGrid(t, 4)
    assert [(b.start, b.stop) for b in g.blocks()] == [(0, 4), (4, 8), (8, 10)]
    assert [(b.start, b.stop) for b in g.blocks(5)] == [(4, 8), (8, 10)]
    assert [(b.start, b.stop) for b in EpochGrid(t).blocks()] == [(0, 10)]


def test_k0_in_a_later_block_runs_from_there():
    t, za, zb = _record()
    N = t.size
    x0, P0 = np.array([0.3, -0.1]), np.eye(2) * 2.0
    ref = RecordingSink(N, 2)
    drive(GridDynamics(_Dyn(), t), [_Whole([[1.0, 0.0]], za, [0.1])], EpochGrid(t), (x0, P0), sink=ref, k0=24)
    got = RecordingSink(N, 2)
    src = BlockSource(N, lambda a, b: (t[a:b], {"a": za[a:b]}), 8)
    drive(GridDynamics(_Dyn()), [_Streamed([[1.0, 0.0]], "a", [0.1])], src, (x0, P0), sink=got, k0=24)
    assert np.array_equal(got.x, ref.x) and np.array_equal(got.P, ref.P)


def test_blocks_ending_early_are_refused():
    t, za, _ = _record()
    src = BlockSource(t.size, lambda a, b: (t[a:b], {"a": za[a:b]}), 8)
    src.n_epochs = t.size + 5                 # claims more epochs than its blocks give
    src.blocks = lambda start=0, _b=src.blocks: (blk for blk in _b(start) if blk.start < 48)
    with pytest.raises(ValueError, match="epoch 48"):
        drive(GridDynamics(_Dyn()), [_Streamed([[1.0, 0.0]], "a", [0.1])], src, (np.zeros(2), np.eye(2)),
              sink=RecordingSink(t.size + 5, 2))
