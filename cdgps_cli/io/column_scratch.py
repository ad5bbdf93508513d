"""Columns of numbers kept on disk while a record streams: written by blocks of rows, read back a
column at a time (e.g. each mode's modal-filter output of ``cdgps spectra``, whose whole-record
periodogram is needed one mode at a time).

An unlinked temporary file (gone when closed or when the process ends), written and read with
``pwrite`` / ``pread`` — no memory mapping, so the pages do not count in the process's memory.
Column j occupies bytes ``[j N, (j + 1) N) × 8``: one read per column.
"""

from __future__ import annotations

import os
import tempfile

import numpy as np


class ColumnScratch:
    """(n_rows, n_cols) float64 on disk.

    Parameters
    ----------
    n_rows, n_cols : int
    """

    def __init__(self, n_rows: int, n_cols: int):
        self.n_rows, self.n_cols = int(n_rows), int(n_cols)
        self._file = tempfile.TemporaryFile()

    def write(self, row: int, block: np.ndarray) -> None:
        """Rows ``row … row + k − 1`` of every column from ``block`` (k, n_cols)."""
        block = np.asarray(block, dtype="<f8")
        if block.ndim != 2 or block.shape[1] != self.n_cols or row < 0 or row + block.shape[0] > self.n_rows:
            raise ValueError(f"block of shape {block.shape} at row {row}: expected (k, {self.n_cols}) within "
                             f"{self.n_rows} rows")
        fd = self._file.fileno()
        for j in range(self.n_cols):
            os.pwrite(fd, np.ascontiguousarray(block[:, j]).tobytes(), (j * self.n_rows + row) * 8)

    def column(self, j: int) -> np.ndarray:
        """Column j, (n_rows,) float64 (read-only)."""
        nbytes = self.n_rows * 8
        data = os.pread(self._file.fileno(), nbytes, j * nbytes)
        if len(data) != nbytes:
            raise ValueError(f"column {j}: {len(data)} of {nbytes} bytes on disk (not fully written)")
        return np.frombuffer(data, dtype="<f8")

    def close(self) -> None:
        self._file.close()
