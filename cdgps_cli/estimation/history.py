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

import numpy as np

__all__ = ["MemoryHistory"]


class MemoryHistory:
    """Arrays in memory (``np.empty``); :meth:`release` does nothing."""

    on_disk = False

    @staticmethod
    def empty(shape: tuple, dtype=np.float64) -> np.ndarray:
        return np.empty(shape, dtype=dtype)

    @staticmethod
    def release(arr: np.ndarray, start: int, stop: int) -> None:
        return None
