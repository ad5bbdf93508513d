"""DiskHistory.release on short ranges (issue 29, helper ``fused29``): released a few rows at a time,
as the fused smoother's short stretches do, every page of the array leaves memory (the pages at the
ends of each range too) and every value comes back when read."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.io import scratch
from cdgps_cli.io.scratch import DiskHistory

pytestmark = pytest.mark.skipif(not Path("/proc/self/smaps").exists(), reason="needs /proc/self/smaps (Linux)")


def _mapping_rss_kib(arr: np.ndarray) -> int:
    """Resident kiB of the mapping that holds ``arr``'s first byte (/proc/self/smaps)."""
    addr = arr.__array_interface__["data"][0]
    inside = False
    with open("/proc/self/smaps") as fh:
        for ln in fh:
            head = ln.split()[0]
            if "-" in head and ":" not in head:
                lo, hi = (int(v, 16) for v in head.split("-"))
                inside = lo <= addr < hi
            elif inside and head == "Rss:":
                return int(ln.split()[1])
    raise AssertionError("mapping not found")


@pytest.mark.parametrize("shape, step", [((4096, 8, 8), 3), ((4096, 18), 2), ((1500, 18, 18), 5)])
def test_release_in_short_ranges_drops_every_page_and_keeps_values(tmp_path, shape, step):
    h = DiskHistory(tmp_path)
    a = h.empty(shape)
    a[:] = np.arange(shape[0], dtype=float).reshape((-1,) + (1,) * (len(shape) - 1))
    full = _mapping_rss_kib(a)
    assert full >= a.nbytes // 1024 - 8
    n = shape[0]
    for top in range(n, 0, -step):                    # latest first, a few rows at a time (the smoother's order)
        h.release(a, max(top - step, 0), top)
    assert _mapping_rss_kib(a) <= 8                   # (rows of 144 and 512 bytes: no range holds a whole page)
    assert np.array_equal(a[:, ...].reshape(n, -1)[:, 0], np.arange(n, dtype=float))     # read back from the file


def test_release_keeps_the_other_rows_of_an_end_page_written(tmp_path):
    h = DiskHistory(tmp_path)
    a = h.empty((100, 8, 8))                          # 512-byte rows: 8 to a page
    a[:] = 1.0
    a[10:12] = 2.0
    h.release(a, 9, 10)                               # the page of rows 8 … 15 leaves memory …
    a[13] = 3.0                                       # … and comes back when written
    h.release(a, 12, 13)
    assert a[10, 0, 0] == 2.0 and a[13, 7, 7] == 3.0 and a[9, 1, 1] == 1.0 and a[99, 7, 7] == 1.0
    h.release(a, 95, 200)                             # (past the end: up to the end)
    assert a[99, 0, 0] == 1.0


def test_stretches_read_and_written_then_released_leave_memory(tmp_path):
    """The smoother's order: short stretches of rows, latest first, each read and written in place and
    then released but for its lowest row (read again by the stretch below).  Reading next to released
    rows maps the file's pages around them again (the kernel's fault-around): those leave too."""
    h = DiskHistory(tmp_path)
    n = 12001
    a = h.empty((n, 18, 18))                          # 2592-byte rows, 30 MiB
    for c in range(0, n, 4096):
        a[c:c + 4096] = 1.0
        h.release(a, c, c + 4096)
    rng = np.random.default_rng(0)
    b = n - 1
    while b > 0:
        lo = max(b - int(rng.integers(2, 25)), 0)
        a[lo:b + 1] *= 2.0
        h.release(a, lo + 1, b + 1)
        b = lo
    assert _mapping_rss_kib(a) < a.nbytes // 1024 // 4          # (without the widening: ≈ 2/3 of it stays)
    assert a[0, 0, 0] == 2.0 and a[n - 1, 17, 17] == 2.0 and np.all(a[5000] == 2.0)


def _cached(fd: int, offset: int, nbytes: int) -> bool:
    """Whether bytes offset … offset + nbytes of the file are all in the page cache (a read that must
    not wait for the disk: ``RWF_NOWAIT``)."""
    buf = bytearray(nbytes)
    try:
        return os.preadv(fd, [buf], offset, os.RWF_NOWAIT) == nbytes
    except BlockingIOError:
        return False


@pytest.mark.skipif(not hasattr(os, "RWF_NOWAIT") or scratch._SYNC_FILE_RANGE is None,
                    reason="needs preadv RWF_NOWAIT and sync_file_range (Linux)")
def test_release_of_a_chunk_takes_its_pages_out_of_the_page_cache(tmp_path, monkeypatch):
    """A release of at least DROP_CACHE_MIN_BYTES starts writing the rows to disk, and the next such
    release drops them from the page cache (the file of a day's history no longer fills the system's
    memory); shorter ones leave the cache alone; every value comes back when read."""
    monkeypatch.setattr(scratch, "SCRATCH_CACHE_BYTES", 0)           # (past the process's budget)
    h = DiskHistory(tmp_path)
    a = h.empty((3000, 18, 18))                       # 2592-byte rows, 7.4 MiB
    a[:] = np.arange(3000, dtype=float)[:, None, None]
    fd, row = scratch._FDS[a._mmap], a.strides[0]
    assert _cached(fd, 0, a.nbytes)
    h.release(a, 2990, 3000)                          # 25 kB: unmapped, still cached
    assert _cached(fd, 2990 * row // 4096 * 4096, 4096)
    h.release(a, 0, 1000)                             # 2.5 MiB: being written …
    h.release(a, 1000, 1500)                          # … and dropped at the next release
    assert not _cached(fd, 4096, 4096) and not _cached(fd, 900 * row, 4096)
    assert _cached(fd, 2000 * row, 4096)              # (the rows not released stay)
    assert np.array_equal(a[:, 3, 4], np.arange(3000, dtype=float))


def test_drop_cached_keeps_the_values_of_a_file_written_by_write(tmp_path):
    path = tmp_path / "f"
    data = np.random.default_rng(1).bytes(3 << 20)
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        scratch.drop_cached(fh.fileno(), 0, len(data))
        scratch.drop_cached(fh.fileno(), 0, 0)        # (nothing)
    assert path.read_bytes() == data


@pytest.mark.skipif(not hasattr(os, "RWF_NOWAIT"), reason="needs preadv RWF_NOWAIT (Linux)")
def test_under_the_budget_releases_leave_the_page_cache_alone(tmp_path, monkeypatch):
    """Until the scratch files pass SCRATCH_CACHE_BYTES nothing is written or dropped (a short record
    costs no disk writes); past it, they are."""
    monkeypatch.setattr(scratch, "SCRATCH_CACHE_BYTES", 6 << 20)
    monkeypatch.setattr(scratch, "_PUSHED", [0])
    h = DiskHistory(tmp_path)
    a = h.empty((3000, 18, 18))
    a[:] = 1.0
    fd, row = scratch._FDS[a._mmap], a.strides[0]
    h.release(a, 0, 1000)
    h.release(a, 1000, 2000)                          # 5 MiB pushed: under the budget
    assert _cached(fd, 0, 2000 * row // 4096 * 4096) and not scratch.over_budget()
    h.release(a, 2000, 3000)                          # 7.4 MiB: past it, rows 2000 … being written
    h.release(a, 0, 1000)                             # (and dropped at the next push)
    assert scratch.over_budget() and not _cached(fd, 2100 * row, 4096)


def test_bytes_pushed_again_count_once(monkeypatch):
    """The budget counts the bytes of a file once: a prefix released again and again (HistorySink) or a
    backward sweep; ``fresh`` gives the count of scattered ranges (PackedWriter's planes)."""
    monkeypatch.setattr(scratch, "SCRATCH_CACHE_BYTES", 1 << 60)
    monkeypatch.setattr(scratch, "_PUSHED", [0])
    forward, backward, planes = scratch.Behind(-1), scratch.Behind(-1), scratch.Behind(-1)
    for b in range(10, 101, 10):
        forward.push([(0, b)])
    assert scratch._PUSHED[0] == 100
    for b in range(100, 0, -10):
        backward.push([(b - 10, 10)])
        backward.push([(b - 10, 10)])
    assert scratch._PUSHED[0] == 200
    planes.push([(j * 1000, 10) for j in range(5)], fresh=50)
    assert scratch._PUSHED[0] == 250


@pytest.mark.skipif(not Path("/proc/self/fd").exists(), reason="needs /proc/self/fd (Linux)")
def test_the_descriptor_kept_for_page_cache_drops_closes_with_the_array(tmp_path):
    import gc

    h = DiskHistory(tmp_path)
    before = len(list(Path("/proc/self/fd").iterdir()))
    arrays = [h.empty((100, 18)) for _ in range(5)]
    views = [a[10:] for a in arrays]
    del arrays
    gc.collect()
    assert len(list(Path("/proc/self/fd").iterdir())) > before       # (the views keep their files)
    del views
    gc.collect()
    assert len(list(Path("/proc/self/fd").iterdir())) == before


def test_the_budget_counts_the_scratch_files_still_open(tmp_path, monkeypatch):
    """A scratch file's bytes leave the budget with the file (a long-lived process, e.g. a batch of
    estimates, does not end up dropping every later file behind)."""
    import gc

    from cdgps_cli.io.phase_disk import column_file

    monkeypatch.setattr(scratch, "SCRATCH_CACHE_BYTES", 1 << 60)
    monkeypatch.setattr(scratch, "_PUSHED", [0])
    h = DiskHistory(tmp_path)
    a = h.empty((2000, 18, 18))
    h.release(a, 0, 1000)
    col = column_file([np.zeros(300_000)], 300_000, np.float64, "c")
    assert scratch._PUSHED[0] == 1000 * a.strides[0] + 2_400_000
    del a
    gc.collect()
    assert scratch._PUSHED[0] == 2_400_000
    del col
    gc.collect()
    assert scratch._PUSHED[0] == 0
