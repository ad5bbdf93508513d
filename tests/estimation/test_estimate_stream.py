"""The filter's history on disk, in chunks (issue 29): the same numbers as the whole record in memory.

``estimate`` with a :class:`cdgps_cli.io.scratch.DiskHistory` and a small ``chunk_epochs`` (several
chunks forward and backward) against the in-memory path (:class:`~cdgps_cli.estimation.history.MemoryHistory`,
one chunk): exact equality of every array of the result, for the compiled and the numpy filter,
fixed biases and bias states, a slip, a rest segment, with and without smoothing; STATES written
from both byte for byte; the chunked RTS pass against one pass; the scratch files leave nothing on
disk and their pages leave memory when released.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.config.options import ESTIMATE_CHUNK_EPOCHS
from cdgps_cli.estimation import kernel as ekf_kernel
from cdgps_cli.estimation.filter import EstimateOptions, estimate
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.estimation.smoother import rts_smooth
from cdgps_cli.io.run import read_run, write_run
from cdgps_cli.io.scratch import DiskHistory
from cdgps_cli.pipeline.estimate_outputs import write_states
from cdgps_cli.sim.structure import SimOptions, parse_slip, simulate, write_simulation

CHUNK = 37              # epochs: 300 filter epochs → 9 chunks, cuts not aligned with anything


@pytest.fixture(scope="module")
def case(testbed_cfg, tmp_path_factory):
    """45 s of the testbed at 10 Hz with a slip at 32 s, as a RUN.mcap; INIT on 0–15 s (its window
    joins the STATES)."""
    sim = simulate(testbed_cfg, SimOptions(duration_s=45.0, seed=5, phase_sigma_m=0.02, disturbance_scale=1.0,
                                           slips=[parse_slip("a2:PL4:32.0:+2")]))
    d = tmp_path_factory.mktemp("stream")
    write_simulation(sim, d)
    write_run(testbed_cfg, d / "receiver.csv", d / "run.mcap")
    run = read_run(d / "run.mcap")
    init = initialize(run, InitOptions(start_s=0.0, duration_s=15.0))
    return {"run": run, "init": init, "run_file": d / "run.mcap"}


def _same(a, b, what):
    if a is None or b is None:
        assert a is None and b is None, what
        return
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, what
    np.testing.assert_array_equal(a, b, err_msg=what)


def _assert_identical(mem, disk, modal: bool):
    nm = mem.cfg.n_modes
    for name in ("time_s", "x", "x_filt", "residual_m", "nis", "nis_dof"):
        _same(getattr(mem, name), getattr(disk, name), name)
    P = mem.P[:, :nm, :nm] if modal else mem.P
    _same(np.ascontiguousarray(P), disk.P, "P")
    _same(mem.P_filt, disk.P_filt, "P_filt")
    assert mem.events == disk.events and mem.biases == disk.biases and mem.window == disk.window
    assert json.dumps(mem.noise, sort_keys=True) == json.dumps(disk.noise, sort_keys=True)
    assert (mem.smoothed, mem.filter_path, mem.rest_active_s) == (disk.smoothed, disk.filter_path, disk.rest_active_s)


@pytest.mark.parametrize("kind", ["kernel-smooth", "kernel-filter", "numpy-smooth", "states-smooth", "rest-smooth"])
def test_disk_history_in_chunks_equals_memory(case, kind, tmp_path, monkeypatch):
    if kind.startswith("numpy"):
        monkeypatch.setenv("CDGPS_NO_KERNEL", "1")
    base = dict(smooth=kind.endswith("smooth"), keep_filtered_covariance="modal")
    if kind.startswith("states"):
        base["biases"] = "states"
    if kind.startswith("rest"):
        base["rest_segments_s"] = ((20.0, 26.0),)
    mem = estimate(case["run"], case["init"], EstimateOptions(**base))
    assert mem.filter_path == ("c" if kind.startswith(("kernel", "rest")) and ekf_kernel.available() else "numpy")
    disk = estimate(case["run"], case["init"], EstimateOptions(**base, history=DiskHistory(tmp_path),
                                                                chunk_epochs=CHUNK))
    _assert_identical(mem, disk, modal=False)
    modal = estimate(case["run"], case["init"], EstimateOptions(**base, history=DiskHistory(tmp_path),
                                                                 chunk_epochs=CHUNK, keep_covariance="modal"))
    _assert_identical(mem, modal, modal=True)
    assert list(tmp_path.iterdir()) == []                # the scratch files are unlinked from the start
    if kind == "kernel-smooth":
        assert any(e["kind"] == "lock restart" for e in mem.events)
        assert len(mem.time_s) > 5 * CHUNK


def test_states_byte_identical(case, tmp_path):
    """STATES.mcap from the chunked disk path (modal covariance, as `cdgps estimate` runs it) equals,
    byte for byte, the one written from the whole-record in-memory result."""
    init, text = case["init"], json.dumps(case["init"])
    run_file = case["run_file"]
    opt = EstimateOptions(smooth=True, keep_filtered_covariance="modal")
    mem = estimate(case["run"], init, opt)
    disk = estimate(case["run"], init, EstimateOptions(smooth=True, keep_filtered_covariance="modal",
                                                       history=DiskHistory(tmp_path), chunk_epochs=CHUNK,
                                                       keep_covariance="modal"))
    assert opt.echo() == EstimateOptions(smooth=True, keep_filtered_covariance="modal", chunk_epochs=CHUNK,
                                         keep_covariance="modal").echo()    # not in the STATES metadata
    write_states(mem, run_file, init, text, tmp_path / "mem.mcap", opt.echo())
    write_states(disk, run_file, init, text, tmp_path / "disk.mcap", opt.echo())
    assert (tmp_path / "mem.mcap").read_bytes() == (tmp_path / "disk.mcap").read_bytes()


def test_chunk_default_in_options():
    assert EstimateOptions().chunk_epochs == ESTIMATE_CHUNK_EPOCHS > 1000


@pytest.mark.parametrize("chunk", [1, 4, 7, 1000])
def test_chunked_rts_equals_one_pass(chunk):
    """Reverse chunks over piecewise Q, extra variances and unlinked epochs: the same bits as one pass per
    stretch; every epoch reported final exactly when it no longer changes."""
    rng = np.random.default_rng(3)
    N, p = 40, 4
    A = np.eye(p) + 0.05 * rng.standard_normal((p, p))
    Q, Q2 = 0.01 * np.eye(p), 0.001 * np.eye(p)
    B, U = rng.standard_normal((p, 1)), rng.standard_normal((N, 1))
    xf = rng.standard_normal((N, p))
    L = rng.standard_normal((N, p, p))
    Pf = L @ L.transpose(0, 2, 1) + np.eye(p)
    extra = {9: [(1, 0.5)], 23: [(0, 0.1), (2, 0.2)]}
    no_link = np.zeros(N, dtype=bool)
    no_link[15:18] = True
    segs = [(0, 12, Q), (12, 30, Q2), (30, N - 1, Q)]
    x1, P1 = rts_smooth(A, Q, B, U, xf, Pf, extra, no_link, q_segments=segs)
    xw, Pw = xf.copy(), Pf.copy()
    seen = np.zeros(N, dtype=int)

    def done(a, b):
        _same(xw[a:b], x1[a:b], f"x {a}:{b}")
        _same(Pw[a:b], P1[a:b], f"P {a}:{b}")
        seen[a:b] += 1

    rts_smooth(A, Q, B, U, xw, Pw, extra, no_link, in_place=True, q_segments=segs, chunk=chunk, on_done=done)
    _same(xw, x1, "x")
    _same(Pw, P1, "P")
    assert (seen >= 1).all()
    x0, P0 = rts_smooth(A, Q, B, U, xf, Pf, extra, no_link)
    x3, P3 = rts_smooth(A, Q, B, U, xf, Pf, extra, no_link, chunk=chunk)
    _same(x3, x0, "x one Q")
    _same(P3, P0, "P one Q")


def _rss_kib() -> int:
    with open("/proc/self/status") as fh:
        return next(int(ln.split()[1]) for ln in fh if ln.startswith("VmRSS:"))


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")
def test_disk_history_release_drops_pages_keeps_values(tmp_path):
    h = DiskHistory(tmp_path)
    a = h.empty((4096, 32, 32))                          # 32 MiB
    assert isinstance(a, np.memmap) and a.flags.c_contiguous and list(tmp_path.iterdir()) == []
    before = _rss_kib()
    a[:] = np.arange(a.shape[0], dtype=float)[:, None, None]
    touched = _rss_kib()
    h.release(a, 0, a.shape[0])
    assert touched - before > 24 * 1024 and _rss_kib() < before + 4 * 1024
    assert a[4095, 3, 3] == 4095.0 and a[17, 0, 1] == 17.0      # read back from the file
    view = a[:, :4, :4]
    h.release(view, 10, 20)                              # views and partial ranges: no error
    assert view[15, 0, 0] == 15.0


def test_disk_history_directory_missing_uses_tmp(tmp_path):
    h = DiskHistory(tmp_path / "not-yet")
    assert h.dir is None
    assert h.empty((3, 2)).shape == (3, 2)
    assert not (tmp_path / "not-yet").exists()


def test_cli_estimate_leaves_no_scratch(case, tmp_path):
    """`cdgps estimate` writes its history beside the output and leaves only STATES.mcap there."""
    from click.testing import CliRunner

    from cdgps_cli.cli.commands import main

    src = tmp_path / "init.json"
    src.write_text(json.dumps(case["init"]))
    out = tmp_path / "out"
    out.mkdir()
    r = CliRunner().invoke(main, ["--quiet", "estimate", str(case["run_file"]), "--init", str(src),
                                  "--smooth", "-o", str(out / "states.mcap")])
    assert r.exit_code == 0, r.output
    assert sorted(os.listdir(out)) == ["states.mcap"]


@pytest.mark.parametrize("no_kernel", ["0", "1"])
def test_no_thruster_log_zero_row_equals_zero_array(case, no_kernel, monkeypatch):
    """Without actuator messages the inputs are one broadcast row of zeros (no (N, n_thrusters) array);
    the numbers equal those with the explicit zero array (compiled and numpy paths)."""
    import cdgps_cli.estimation.filter as filt

    monkeypatch.setenv("CDGPS_NO_KERNEL", no_kernel)
    assert len(case["run"].actuators) == 0
    opt = EstimateOptions(smooth=True, keep_filtered_covariance="modal")
    lean = estimate(case["run"], case["init"], opt)
    original = filt._ForwardPass._thruster_inputs
    seen = {}

    def explicit(self):
        original(self)
        seen["broadcast"] = self.U_in.strides[0] == 0
        self.U_in = np.zeros(self.U_in.shape)

    monkeypatch.setattr(filt._ForwardPass, "_thruster_inputs", explicit)
    full = estimate(case["run"], case["init"], opt)
    assert seen["broadcast"]
    _assert_identical(full, lean, modal=False)


def test_phase_rows_in_blocks_equal_whole(case, monkeypatch):
    """Y, LOCK and everything after them are the same when the phase rows are read in small blocks
    (also with INIT's time inside a block, so a block's rows are partly kept)."""
    import cdgps_cli.estimation.filter as filt

    opt = EstimateOptions(smooth=True, keep_filtered_covariance="modal")
    whole = estimate(case["run"], case["init"], opt)
    assert len(case["run"].phase) < filt.PHASE_BLOCK_ROWS
    monkeypatch.setattr(filt, "PHASE_BLOCK_ROWS", 1001)
    blocks = estimate(case["run"], case["init"], opt)
    _assert_identical(whole, blocks, modal=False)


def test_disk_history_full_disk_is_a_cdgps_error(tmp_path, monkeypatch):
    """No room for the history: a CdgpsError naming the directory and the size (not a SIGBUS later)."""
    import errno

    from cdgps_cli.core.errors import CdgpsError

    def no_room(fd, offset, size):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "posix_fallocate", no_room)
    with pytest.raises(CdgpsError, match=r"cannot make a scratch file of \d+ MiB.*no space left"):
        DiskHistory(tmp_path).empty((1024, 64, 64))
    assert list(tmp_path.iterdir()) == []


# --- issue 29: the filter's (N, C) arrays on the disk history too, read back in blocks ---------------

def test_noise_sum_in_blocks_equals_whole():
    """filter_sigma_estimate by blocks of rows gives the same bits as the whole-array sums."""
    from cdgps_cli.measurement.noise import filter_sigma_estimate

    rng = np.random.default_rng(3)
    e = rng.normal(scale=0.02, size=(5003, 36))
    h = rng.uniform(1e-6, 1e-4, size=e.shape)
    e[rng.random(e.shape) < 0.2] = np.nan
    h[rng.random(e.shape) < 0.1] = np.nan
    whole = filter_sigma_estimate(e, h)
    for block in (1, 37, 4096, 10_000):
        s, c = filter_sigma_estimate(e, h, block_rows=block)
        np.testing.assert_array_equal(s, whole[0])
        np.testing.assert_array_equal(c, whole[1])
    s0, c0 = filter_sigma_estimate(e[:0], h[:0], block_rows=8)
    assert s0.shape == (36,) and np.isnan(s0).all() and (c0 == 0).all()


def test_lock_events_by_groups_and_blocks_equal_whole(monkeypatch):
    """lock_events over column groups, rows copied in blocks with pages released, equals one column
    at a time over the whole arrays."""
    import cdgps_cli.estimation.filter as F

    rng = np.random.default_rng(4)
    N, C = 900, 11
    Y = rng.normal(size=(N, C))
    Y[rng.random(Y.shape) < 0.15] = np.nan
    LOCK = np.cumsum(rng.random((N, C)) > 0.02, axis=0).astype(np.int32)
    LOCK[rng.random(LOCK.shape) < 0.01] = 0
    ref = F.lock_events(Y, LOCK, group=1)
    assert (ref > 0).sum() > C                        # first sightings and restarts
    seen = []
    monkeypatch.setattr(F, "PHASE_BLOCK_ROWS", 64 << 5)   # blocks of 64 rows
    got = F.lock_events(Y, LOCK, release=lambda arr, a, b: seen.append((a, b)), group=4)
    np.testing.assert_array_equal(got, ref)
    assert (0, 64) in seen and max(b for _, b in seen) >= N


def test_filter_arrays_on_disk_history(case, tmp_path, monkeypatch):
    """With a DiskHistory the phase, residual, H P Hᵀ and input arrays (N, C) are on it (memmaps)
    and the sink releases them behind the filter; the result is the in-memory one."""
    import cdgps_cli.estimation.filter as F

    kept = {}
    orig = F._finish

    def spy(fp, provisional=False):
        kept.update(Y=fp.Y, resid=fp.resid_all, hph=fp.hph, also=fp.sink.also)
        return orig(fp, provisional)

    released = []
    monkeypatch.setattr(F, "_finish", spy)
    monkeypatch.setattr(DiskHistory, "release", staticmethod(
        lambda arr, a, b, _r=DiskHistory.release: (released.append((arr.shape, a, b)), _r(arr, a, b))[1]))
    opt = dict(smooth=True, keep_filtered_covariance="modal", adapt_sigma=False)
    disk = estimate(case["run"], case["init"], EstimateOptions(**opt, history=DiskHistory(tmp_path),
                                                                chunk_epochs=CHUNK))
    for name in ("Y", "resid", "hph"):
        assert isinstance(kept[name], np.memmap), name
    assert kept["Y"] is kept["also"][0] and len(kept["also"]) == 4
    N, C = kept["hph"].shape
    assert any(s == (N, C) and b >= CHUNK for s, a, b in released)
    mem = estimate(case["run"], case["init"], EstimateOptions(**opt))
    _assert_identical(mem, disk, modal=False)
