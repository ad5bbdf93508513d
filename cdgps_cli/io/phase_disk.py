"""A RUN's phase table on disk, read a block of rows at a time (issue 29: ``estimate`` and ``init`` in
memory that does not grow with the record).

:func:`cdgps_cli.io.run.read_run` with ``on_disk=True`` gives a :class:`~cdgps_cli.core.records.Run`
whose ``phase`` is a :class:`DiskPhase`: each packed column of the RUN
(:data:`cdgps_cli.io.run.PHASE_PACKED`) is decompressed once, in pieces, into an unlinked temporary
file (row-major, its own dtype), and is then read back by row ranges (:class:`DiskColumn`) — a slice,
a boolean mask or sorted indices read only the blocks they touch, and ``min``/``max``/comparisons
run block by block.  The estimators use the same :class:`~cdgps_cli.core.table.Table` methods as on
a table in memory (``len``, columns, ``index_in``, ``names_not_in``, ``codes``), so they give the same
numbers; a whole column is only made when something asks for it as an array (``np.asarray``).
No numerics here.
"""

from __future__ import annotations

import os
import tempfile

import numpy as np

from cdgps_cli.core.table import Table
from cdgps_cli.io.scratch import DROP_CACHE_MIN_BYTES, DropBehind, forget_cached

__all__ = ["DiskColumn", "DiskPhase", "BLOCK_ROWS"]

BLOCK_ROWS = 1 << 18
"""Rows read at a time by the block-wise operations of :class:`DiskColumn` (2 MiB of float64)."""


class DiskColumn:
    """One column (R,) of numbers in a file, read by rows.

    Parameters
    ----------
    file : file object
        Holds the column's R values of ``dtype``, row-major, from offset 0 (kept open by the column).
    n : int
        R, its rows.
    dtype : numpy dtype
    """

    ndim = 1

    def __init__(self, file, n: int, dtype):
        self._file, self.n, self.dtype = file, int(n), np.dtype(dtype)

    @property
    def shape(self) -> tuple:
        return (self.n,)

    @property
    def size(self) -> int:
        return self.n

    def __len__(self) -> int:
        return self.n

    def read(self, a: int, b: int) -> np.ndarray:
        """Rows a … b−1 (clipped to the column) as a new array."""
        a, b = max(int(a), 0), min(int(b), self.n)
        out = np.empty(max(b - a, 0), dtype=self.dtype)
        if out.size:
            got = os.preadv(self._file.fileno(), [memoryview(out).cast("B")], a * self.dtype.itemsize)
            if got != out.nbytes:
                raise OSError(f"short read of a phase column's scratch file ({got} of {out.nbytes} bytes)")
            if got >= DROP_CACHE_MIN_BYTES:        # (a block: out of the page cache again, see column_file)
                forget_cached(self._file.fileno(), a * self.dtype.itemsize, got)
        return out

    def blocks(self, rows: int = BLOCK_ROWS):
        """``(start, values)`` of consecutive blocks of ``rows`` rows, first to last."""
        for a in range(0, self.n, rows):
            yield a, self.read(a, a + rows)

    def __getitem__(self, key):
        if isinstance(key, (int, np.integer)):
            k = int(key) + (self.n if key < 0 else 0)
            if not 0 <= k < self.n:
                raise IndexError(f"row {int(key)} of a column of {self.n}")
            return self.read(k, k + 1)[0]
        if isinstance(key, slice):
            a, b, step = key.indices(self.n)
            if step == 1:
                return self.read(a, b)
            return np.asarray(self)[key]
        key = np.asarray(key)
        if key.dtype == bool:
            if key.shape != (self.n,):
                raise IndexError(f"boolean mask of {key.shape} for a column of {self.n}")
            parts = [v[key[a:a + v.size]] for a, v in self._touched(key)]
            return np.concatenate(parts) if parts else np.empty(0, dtype=self.dtype)
        return self._take(key.astype(np.int64, copy=False))

    def _touched(self, mask: np.ndarray):
        """The blocks where ``mask`` selects a row."""
        for a in range(0, self.n, BLOCK_ROWS):
            if mask[a:a + BLOCK_ROWS].any():
                yield a, self.read(a, a + BLOCK_ROWS)

    def _take(self, idx: np.ndarray) -> np.ndarray:
        if idx.size == 0:
            return np.empty(idx.shape, dtype=self.dtype)
        idx = np.where(idx < 0, idx + self.n, idx)
        if idx.min() < 0 or idx.max() >= self.n:
            raise IndexError(f"rows outside a column of {self.n}")
        if idx.ndim == 1 and (idx.size < 2 or (np.diff(idx) >= 0).all()):     # ascending: the rows it spans
            lo, hi = int(idx[0]), int(idx[-1]) + 1
            out = np.empty(idx.size, dtype=self.dtype)
            for a in range(lo, hi, BLOCK_ROWS):
                i0, i1 = np.searchsorted(idx, [a, a + BLOCK_ROWS])
                if i1 > i0:
                    out[i0:i1] = self.read(a, a + BLOCK_ROWS)[idx[i0:i1] - a]
            return out
        return self.read(int(idx.min()), int(idx.max()) + 1)[idx - int(idx.min())]

    def _reduce(self, fn):
        if self.n == 0:
            return fn(np.empty(0, dtype=self.dtype))          # (numpy's own error for an empty column)
        return fn(np.array([fn(v) for _, v in self.blocks()], dtype=self.dtype))

    def min(self):
        return self._reduce(np.min)

    def max(self):
        return self._reduce(np.max)

    def _compare(self, op, other) -> np.ndarray:
        out = np.empty(self.n, dtype=bool)
        for a, v in self.blocks():
            out[a:a + v.size] = op(v, other)
        return out

    def __ge__(self, other):
        return self._compare(np.greater_equal, other)

    def __gt__(self, other):
        return self._compare(np.greater, other)

    def __le__(self, other):
        return self._compare(np.less_equal, other)

    def __lt__(self, other):
        return self._compare(np.less, other)

    def astype(self, dtype, copy: bool = True) -> np.ndarray:
        return np.asarray(self).astype(dtype, copy=False)

    def __array__(self, dtype=None, copy=None):
        whole = self.read(0, self.n)                          # (asked for as an array: the whole column)
        return whole if dtype is None else whole.astype(dtype, copy=False)


def column_file(chunks, n: int, dtype, what: str, dir=None) -> DiskColumn:
    """A :class:`DiskColumn` of the ``n`` rows given block by block (``chunks``: arrays of ``dtype``).

    The file's pages leave the page cache behind the writer, and a block's again after it is read
    (:class:`cdgps_cli.io.scratch.DropBehind`): the columns of a day's RUN (≈ 1.2 GB at 10 Hz) would
    otherwise take as much of the system's memory, and memory not used lately costs far more to
    touch than the few blocks' worth used again and again (the system time of reading the 24 h
    testbed RUN: 9.2 s before, against 0.06 s for 1 h)."""
    fh = tempfile.TemporaryFile(prefix=".cdgps-phase-", dir=dir)
    behind = DropBehind(fh)
    done = 0
    for block in chunks:
        block = np.ascontiguousarray(block, dtype=dtype).reshape(-1)
        fh.write(memoryview(block).cast("B"))
        behind.wrote(block.nbytes)
        done += block.size
    if done != n:
        fh.close()
        raise ValueError(f"{what}: {done} values for {n} rows")
    behind.close()
    col = DiskColumn(fh, n, dtype)
    col._behind = behind                           # (its bytes count in the scratch budget while the file lives)
    return col


class _Later:
    """A column made on first use (``make() -> DiskColumn``)."""

    def __init__(self, make):
        self.make = make


class DiskPhase(Table):
    """A RUN's phase table whose columns are :class:`DiskColumn` s (see the module docstring).

    Parameters
    ----------
    n : int
        Rows.
    numbers : dict of str to DiskColumn or callable
        Number columns (a callable makes its column on first use).
    names : dict of str to (DiskColumn or callable, list of str)
        Name columns as codes into their words, which must be sorted and distinct (the RUN's
        ``names.json``); the codes are checked against them when the column is made.
    order, categorical
        As :class:`~cdgps_cli.core.table.Table`.
    """

    def __init__(self, n: int, numbers: dict, names: dict, order, categorical=()):
        self._n = int(n)
        self._numbers = {k: v if isinstance(v, DiskColumn) else _Later(v) for k, v in numbers.items()}
        self._codes, self._words, self._lut = {}, {}, {}
        for k, (codes, words) in names.items():
            words = tuple(str(w) for w in words)
            if list(words) != sorted(set(words)):
                raise ValueError(f"name column {k!r}: names {list(words)} not sorted and distinct")
            self._words[k], self._lut[k] = words, None
            self._codes[k] = codes if isinstance(codes, DiskColumn) else _Later(codes)
            if isinstance(codes, DiskColumn):
                self._check_codes(k, codes)
        self._order = list(order)
        self._categorical = frozenset(categorical)

    def __len__(self) -> int:
        return self._n

    def _number(self, k: str):
        v = self._numbers[k]
        if isinstance(v, _Later):
            v = self._numbers[k] = v.make()
        return v

    def _code(self, k: str):
        c = self._codes[k]
        if isinstance(c, _Later):
            c = c.make()
            self._check_codes(k, c)
            self._codes[k] = c
        return c

    def index_in(self, column: str, vocabulary, rows=None) -> np.ndarray:
        """As :meth:`Table.index_in <cdgps_cli.core.table.Table.index_in>` (no ``rows``: the whole column read)."""
        codes, words = self.codes(column)
        where = {w: i for i, w in enumerate(vocabulary)}
        lut = np.array([where.get(w, -1) for w in words] or [-1], dtype=np.int64)
        return lut[np.asarray(codes) if rows is None else codes[rows]]

    def names_not_in(self, column: str, vocabulary, rows=None) -> list[str]:
        """As :meth:`Table.names_not_in <cdgps_cli.core.table.Table.names_not_in>` (no ``rows``: block by block)."""
        codes, words = self.codes(column)
        if rows is None:
            counts = sum((np.bincount(v, minlength=len(words)) for _, v in codes.blocks()), np.zeros(len(words), int))
        else:
            sel = codes[rows]
            counts = np.bincount(sel, minlength=len(words)) if sel.size else np.zeros(len(words), int)
        known = set(vocabulary)
        return sorted(words[i] for i in np.flatnonzero(counts).tolist() if words[i] not in known)

    def take(self, rows) -> Table:
        """The rows selected (a boolean mask or indices) as a :class:`Table` in memory."""
        return Table({k: self._number(k)[rows] for k in self._numbers},
                     {k: (self._code(k)[rows], self._words[k]) for k in self._codes},
                     self._order, self._categorical)

    def __repr__(self) -> str:
        return f"DiskPhase({len(self)} rows on disk; columns {', '.join(self._order)})"

