"""PackedWriter (issue 29): a packed array written from blocks of rows is the same bytes as
:func:`pack` of the whole array, for every block cutting, delta order and dtype; misuse refused."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.io.packed_arrays import PackedWriter, pack, unpack


def _streamed(arr: np.ndarray, delta: int, rows: int) -> bytes:
    w = PackedWriter(arr.shape, arr.dtype, delta)
    for a in range(0, arr.shape[0], rows):
        w.add(arr[a:a + rows])
    n, pieces = w.finish()
    data = b"".join(pieces)
    assert len(data) == n
    return data


ARRAYS = [
    np.random.default_rng(0).normal(size=(257, 3, 3)).cumsum(axis=0),
    np.arange(1000, dtype=np.int64) ** 2,
    np.random.default_rng(1).normal(size=(300, 5)).astype(np.float32),
    np.array([np.nan, -0.0, np.inf, 1e-310, 5.0], dtype=">f8"),
    np.zeros((0, 4)),
    np.random.default_rng(2).integers(-5, 5, size=(40, 2)).astype(np.int32),
]


@pytest.mark.parametrize("arr", ARRAYS)
@pytest.mark.parametrize("delta", [0, 1, 2])
@pytest.mark.parametrize("rows", [1, 3, 64, 10_000])
def test_streamed_bytes_are_those_of_pack(arr, delta, rows):
    data = _streamed(arr, delta, rows)
    assert data == pack(arr, delta)
    assert unpack(data).tobytes() == arr.astype(arr.dtype.newbyteorder("<")).tobytes()


def test_large_array_in_pieces_bigger_than_one():
    arr = np.random.default_rng(4).normal(size=(40_000, 45)).cumsum(axis=0)       # 14 MB of planes
    assert _streamed(arr, 2, 4096) == pack(arr, 2)


def test_bool_rows_and_misuse():
    arr = np.array([True, False, True, True])
    assert _streamed(arr, 0, 3) == pack(arr)
    with pytest.raises(ValueError, match="delta"):
        PackedWriter((4,), bool, 1)
    w = PackedWriter((4, 2), float)
    with pytest.raises(ValueError, match="rows of shape"):
        w.add(np.zeros((5, 2)))
    w.add(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="3 of 4 rows"):
        w.finish()
    w.close()


@pytest.mark.parametrize("drop_bytes", [1, 5000, 1 << 16])
def test_plane_file_dropped_from_the_page_cache_as_written_gives_the_same_bytes(monkeypatch, drop_bytes):
    """The plane file leaves the page cache every ``_DROP_BYTES`` of rows (issue 29): the same bytes,
    whatever the cutting; a block's pages are out of the cache once it is dropped (Linux)."""
    import os

    from cdgps_cli.io import scratch

    monkeypatch.setattr(PackedWriter, "_DROP_BYTES", drop_bytes)
    monkeypatch.setattr(scratch, "SCRATCH_CACHE_BYTES", 0)           # (past the process's budget)
    arr = np.random.default_rng(3).normal(size=(20_000, 3, 3)).cumsum(axis=0)
    for delta in (0, 2):
        assert _streamed(arr, delta, 4096) == pack(arr, delta)
    if not hasattr(os, "RWF_NOWAIT") or scratch._SYNC_FILE_RANGE is None:
        return
    w = PackedWriter(arr.shape, arr.dtype, 0)
    w.add(arr[:16384])                                # (being written …)
    w.add(arr[16384:18000])                           # (… and dropped from the cache)
    fd = w._file.fileno()
    try:
        got = os.preadv(fd, [bytearray(4096)], 8192, os.RWF_NOWAIT)     # (plane 0, column 0, rows 8192 …)
    except BlockingIOError:
        got = 0
    assert got < 4096
    w.close()
