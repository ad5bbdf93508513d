"""MemoryHistory (cdgps_cli/estimation/history.py): small arrays are ``np.empty``; large ones an
anonymous mapping of their own (base pages), C-contiguous, writable, of the shape and dtype asked,
zero-filled, and freed with the array."""

from __future__ import annotations

import gc
import mmap
import weakref

import numpy as np

from cdgps_cli.estimation.history import SMALL_PAGES_BYTES, MemoryHistory


def _mapping(arr):
    """The object at the bottom of ``arr``'s bases (an mmap for a large MemoryHistory array)."""
    buf = arr.base
    while isinstance(buf, (np.ndarray, memoryview)):
        buf = buf.base if isinstance(buf, np.ndarray) else buf.obj
    return buf


def test_small_arrays_are_numpy_and_large_ones_a_mapping_of_their_own():
    small = MemoryHistory.empty((4, 3))
    assert small.base is None and small.shape == (4, 3)
    n = SMALL_PAGES_BYTES // (8 * 3 * 3) + 1
    big = MemoryHistory.empty((n, 3, 3))
    assert isinstance(_mapping(big), mmap.mmap)
    assert big.shape == (n, 3, 3) and big.dtype == np.float64 and big.flags.c_contiguous and big.flags.writeable
    assert not big.any()                                  # (anonymous pages: zero until written)
    big[-1] = 7.0
    assert big[-1, 2, 2] == 7.0
    ints = MemoryHistory.empty((SMALL_PAGES_BYTES // 4,), np.int32)
    assert ints.dtype == np.int32 and ints.size == SMALL_PAGES_BYTES // 4


def test_the_mapping_goes_with_the_array():
    arr = MemoryHistory.empty((SMALL_PAGES_BYTES // 8,))
    buf = _mapping(arr)
    ref = weakref.ref(buf)
    del arr, buf
    gc.collect()
    assert ref() is None


def _resident_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * mmap.PAGESIZE


def test_a_large_array_is_resident_when_made_where_the_platform_can_populate():
    """The history is populated in one call (MAP_POPULATE), not faulted in page by page by the filter."""
    import pytest

    if not hasattr(mmap, "MAP_POPULATE"):
        pytest.skip("no MAP_POPULATE on this platform")
    nbytes = 64 << 20
    before = _resident_bytes()
    arr = MemoryHistory.empty((nbytes // 8,))
    grown = _resident_bytes() - before
    assert grown > 0.9 * nbytes, grown                   # resident before any write
    assert not arr[:: 4096 // 8].any()                   # (still zero-filled)
