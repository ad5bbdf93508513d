"""The RUN's phase table on disk (issue 29): ``read_run(..., on_disk=True)`` gives the same columns as
the table in memory; its columns answer slices, masks, indices, min/max and comparisons as numpy
does, in any block size; ``init`` and ``estimate --smooth`` on it give the same INIT and the same
STATES.mcap, byte for byte, as on the table in memory (as the command line now runs them)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import cdgps_cli.io.phase_disk as pd_mod
from cdgps_cli.estimation.filter import EstimateOptions, estimate
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.io.phase_disk import DiskPhase, column_file
from cdgps_cli.io.run import read_run, write_run
from cdgps_cli.io import scratch
from cdgps_cli.io.scratch import DiskHistory
from cdgps_cli.pipeline.estimate_outputs import write_states
from cdgps_cli.sim.structure import SimOptions, parse_slip, simulate, write_simulation


@pytest.fixture(scope="module")
def run_file(testbed_cfg, tmp_path_factory):
    sim = simulate(testbed_cfg, SimOptions(duration_s=40.0, seed=7, phase_sigma_m=0.02, disturbance_scale=1.0,
                                           slips=[parse_slip("a2:PL4:28.0:+2")]))
    d = tmp_path_factory.mktemp("phase_disk")
    write_simulation(sim, d)
    write_run(testbed_cfg, d / "receiver.csv", d / "run.mcap")
    return d / "run.mcap"


def test_columns_as_in_memory(run_file):
    mem, disk = read_run(run_file), read_run(run_file, on_disk=True)
    assert isinstance(disk.phase, DiskPhase) and len(disk.phase) == len(mem.phase)
    assert disk.phase.columns == mem.phase.columns
    for c in mem.phase.columns:
        a, b = mem.phase[c], disk.phase[c]
        assert np.asarray(b).dtype == a.dtype, c
        np.testing.assert_array_equal(np.asarray(b), a, err_msg=c)
    for c in ("antenna", "transmitter"):
        assert disk.phase.codes(c)[1] == mem.phase.codes(c)[1]
        assert disk.phase.names_not_in(c, ["a1"]) == mem.phase.names_not_in(c, ["a1"])
        np.testing.assert_array_equal(disk.phase.index_in(c, ["a2", "PL3"], slice(5, 900)),
                                      mem.phase.index_in(c, ["a2", "PL3"], slice(5, 900)))
    assert disk.gyro.columns == mem.gyro.columns and len(disk.gyro) == len(mem.gyro)
    np.testing.assert_array_equal(disk.phase.take(np.arange(3, 50))["phase_cycles"], mem.phase["phase_cycles"][3:50])


@pytest.mark.parametrize("block", [1, 7, 1 << 18])
def test_column_reads_as_numpy(block, monkeypatch):
    monkeypatch.setattr(pd_mod, "BLOCK_ROWS", block)
    rng = np.random.default_rng(0)
    x = rng.normal(size=1000)
    col = column_file(iter([x[:300], x[300:]]), x.size, float, "x")
    mask = rng.random(x.size) < 0.2
    idx = np.sort(rng.choice(x.size, 50, replace=False))
    for key in (slice(10, 500), slice(None), slice(990, 2000), slice(0, 0), slice(1, 100, 3), mask, idx, idx[::-1],
                np.array([], dtype=int), 5, -1):
        got = col[key]
        np.testing.assert_array_equal(got, x[key])
    assert col.min() == x.min() and col.max() == x.max()
    np.testing.assert_array_equal(col >= 0.1, x >= 0.1)
    np.testing.assert_array_equal((col <= 0.1) & (col > -1), (x <= 0.1) & (x > -1))
    with pytest.raises(ValueError, match="values for"):
        column_file(iter([x[:10]]), 11, float, "x")


def test_init_and_estimate_on_disk_as_in_memory(run_file, tmp_path):
    mem, disk = read_run(run_file), read_run(run_file, on_disk=True)
    i_mem = initialize(mem, InitOptions(start_s=0.0, duration_s=15.0))
    i_disk = initialize(disk, InitOptions(start_s=0.0, duration_s=15.0))
    i_mem.pop("elapsed_s", None), i_disk.pop("elapsed_s", None)
    assert json.dumps(i_mem, sort_keys=True) == json.dumps(i_disk, sort_keys=True)
    auto_mem, auto_disk = initialize(mem, InitOptions()), initialize(disk, InitOptions())     # the window chosen
    auto_mem.pop("elapsed_s", None), auto_disk.pop("elapsed_s", None)
    assert json.dumps(auto_mem, sort_keys=True) == json.dumps(auto_disk, sort_keys=True)
    text = json.dumps(i_mem)
    opt = EstimateOptions(smooth=True, keep_filtered_covariance="modal", keep_covariance="modal")
    r_mem = estimate(mem, i_mem, opt)
    r_disk = estimate(disk, i_mem, EstimateOptions(smooth=True, keep_filtered_covariance="modal",
                                                   keep_covariance="modal", history=DiskHistory(tmp_path),
                                                   chunk_epochs=37))
    write_states(r_mem, run_file, i_mem, text, tmp_path / "mem.mcap", opt.echo())
    write_states(r_disk, run_file, i_mem, text, tmp_path / "disk.mcap", opt.echo())
    assert (tmp_path / "mem.mcap").read_bytes() == (tmp_path / "disk.mcap").read_bytes()


@pytest.fixture
def one_cpu():
    """The test process on one CPU while it runs: the pages a drop takes out of the cache sit on the LRU lists of the
    CPU that wrote them, and a process moved between CPUs by a loaded machine may drop from another's."""
    if not hasattr(os, "sched_setaffinity"):
        yield
        return
    cpus = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(cpus)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, cpus)


@pytest.mark.skipif(not hasattr(os, "RWF_NOWAIT") or scratch._SYNC_FILE_RANGE is None,
                    reason="needs preadv RWF_NOWAIT and sync_file_range (Linux)")
def test_column_file_and_packed_rows_leave_the_page_cache(tmp_path, monkeypatch, one_cpu):
    """The scratch files of a RUN's columns (PackedRows' planes, then the column) are dropped from the
    page cache behind the writer, and a block read back leaves it again (issue 29: a day's columns
    no longer fill the system's memory); the values are the same."""
    from cdgps_cli.io.packed_arrays import PackedRows, pack

    monkeypatch.setattr(scratch, "SCRATCH_CACHE_BYTES", 0)           # (past the process's budget)

    def cached(fd, offset, nbytes):
        try:
            return os.preadv(fd, [bytearray(nbytes)], offset, os.RWF_NOWAIT) == nbytes
        except BlockingIOError:
            return False

    values = np.cumsum(np.random.default_rng(2).normal(size=3 << 17))        # 3 MiB of float64
    data = pack(values)
    rows = PackedRows(lambda k, _at=[0]: (data[_at[0]:_at[0] + k], _at.__setitem__(0, _at[0] + k))[0], len(data))
    assert not cached(rows._file.fileno(), 0, 4096) and not cached(rows._file.fileno(), 2 << 20, 4096)
    col = column_file(rows.chunks(1 << 16), values.size, np.float64, "t")
    rows.close()
    fd = col._file.fileno()
    # (in a loaded CI run one page of the three probed was once still cached: the kernel keeps a page it is still
    # handling; a writer that drops nothing leaves all three)
    assert sum(cached(fd, at, 4096) for at in range(0, values.nbytes, 1 << 20)) <= 1
    assert np.array_equal(col.read(0, 1 << 17), values[:1 << 17])              # 1 MiB: read, then dropped
    assert not cached(fd, 0, 4096)
    assert col[5] == values[5] and np.array_equal(np.asarray(col), values)
