"""Where the forward filter keeps its per-epoch history (x_k, P_k) for the smoother.

The filter asks its ``history`` (:class:`cdgps_cli.estimation.filter.EstimateOptions`) for the arrays
(``empty(shape, dtype)``) and tells it which epochs it is done with (``release(arr, start, stop)``,
rows of the first axis), every ``chunk_epochs`` epochs forward and backward.  :class:`MemoryHistory`
(the default) keeps them in memory and releases nothing; the command line gives a disk-backed one
(:class:`cdgps_cli.io.scratch.DiskHistory`), so the memory of ``cdgps estimate --smooth`` is that of a
chunk, not of the record.  The numbers are the same either way (the chunks only decide when pages
are dropped).
"""

from __future__ import annotations

import mmap

import numpy as np

__all__ = ["MemoryHistory", "SMALL_PAGES_BYTES"]

#: arrays of at least this many bytes get an anonymous mapping of base pages, populated (:meth:`MemoryHistory.empty`)
SMALL_PAGES_BYTES = 4 << 20


class MemoryHistory:
    """Arrays in memory (``np.empty``); :meth:`release` does nothing."""

    on_disk = False

    @staticmethod
    def empty(shape: tuple, dtype=np.float64) -> np.ndarray:
        """``np.empty``; from :data:`SMALL_PAGES_BYTES` on, an anonymous mapping of its own (base
        pages: numpy asks the kernel for transparent huge pages on large arrays, and on a busy
        machine their first touch waits for memory compaction — about half of a cold
        ``estimate()`` on the testbed hour; the values are the same), its pages populated at once
        (``MAP_POPULATE`` where the platform has it): the history is written in full by the filter
        anyway, and one populating call costs about half of faulting its base pages in one by one
        (93 MB of covariances on the testbed hour: ≈ 0.07 s against ≈ 0.14 s; ``estimate()``'s CPU
        time 0.66 → 0.59 s)."""
        nbytes = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        if nbytes < SMALL_PAGES_BYTES:
            return np.empty(shape, dtype=dtype)
        flags = mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS | getattr(mmap, "MAP_POPULATE", 0)
        return np.frombuffer(mmap.mmap(-1, nbytes, flags=flags), dtype=dtype).reshape(shape)

    @staticmethod
    def release(arr: np.ndarray, start: int, stop: int) -> None:
        return None
