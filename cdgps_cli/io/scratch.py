"""Scratch arrays on disk: per-epoch histories too large to keep in memory (issue 29).

:class:`DiskHistory` hands out numpy arrays backed by anonymous temporary files (``np.memmap`` over
a file that is unlinked as soon as it is opened, in ``dir`` — the output's directory — or the
system's temporary directory).  Nothing is left on disk afterwards, whether the command ends, fails
or is killed: the space is returned when the last array over it is garbage-collected.

The forward filter writes its x_k, P_k into such arrays and the smoother reads them back in reverse
chunks (:mod:`cdgps_cli.estimation.filter`); :meth:`DiskHistory.release` drops the pages of the
epochs done with from the process (``madvise(MADV_DONTNEED)``: a shared file mapping keeps its
data in the file and the page cache), so the resident memory stays that of one chunk.  The object
is the ``history`` of :class:`cdgps_cli.estimation.filter.EstimateOptions`; the in-memory twin is
:class:`cdgps_cli.estimation.history.MemoryHistory`.  No numerics here.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import mmap
import os
import tempfile
import weakref
from pathlib import Path

import numpy as np

from cdgps_cli.config.options import SCRATCH_CACHE_BYTES
from cdgps_cli.core.errors import CdgpsError

__all__ = ["Behind", "DiskHistory", "FAULT_AROUND_BYTES", "DROP_CACHE_MIN_BYTES", "DropBehind", "drop_cached",
           "forget_cached", "over_budget"]

#: how far from a read page fault Linux maps a file's cached pages as well (``fault_around_bytes``,
#: 64 KiB by default): :meth:`DiskHistory.release` drops that much more on each side of its rows
FAULT_AROUND_BYTES = 64 * 1024

#: a release of at least this many bytes (a chunk of 4096 epochs of an 18-state x: 576 KiB) also takes its pages out of the page cache (:func:`drop_cached`);
#: shorter ones (the fused smoother's stretches of a few epochs) only unmap them
DROP_CACHE_MIN_BYTES = 1 << 18

# every scratch mapping's file descriptor (a duplicate, closed with the mapping) and its Behind
_FDS: "weakref.WeakKeyDictionary[mmap.mmap, int]" = weakref.WeakKeyDictionary()
_BEHIND: "weakref.WeakKeyDictionary[mmap.mmap, Behind]" = weakref.WeakKeyDictionary()


def _libc_sync_file_range():
    """glibc's ``sync_file_range`` (Linux), or None (Python's os module has no binding)."""
    try:
        fn = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True).sync_file_range
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return fn


_SYNC_FILE_RANGE = _libc_sync_file_range()
_START = 2                      # SYNC_FILE_RANGE_WRITE: start writing, do not wait
_SYNC_ALL = 1 | 2 | 4           # SYNC_FILE_RANGE_WAIT_BEFORE | _WRITE | _WAIT_AFTER


def drop_cached(fd: int, offset: int, nbytes: int) -> None:
    """Write bytes ``offset`` … ``offset + nbytes`` of file ``fd`` to disk and take their pages out of
    the page cache (``sync_file_range`` then ``posix_fadvise(POSIX_FADV_DONTNEED)``; pages still
    mapped somewhere, or not wholly inside the range, stay).  The values stay in the file and come
    back from the disk when next read (the kernel never drops a page it has not written).

    Why: a scratch file written once and read once much later (the forward filter's history, read
    back by the smoother) otherwise holds page cache for its whole length — gigabytes on a day's
    record — and memory the system has not used lately costs far more to touch than memory just
    given back (on a virtual machine whose balloon takes free pages back from the guest, the first
    write of each such page faults in the host too: ``estimate --smooth`` then spent 1.0 s of system
    time per hour of record at 24 h against 0.4–0.8 s at 1 h).  Dropped behind, the same few chunks'
    worth of pages is used again and again.  Where the platform has neither call, nothing happens."""
    if nbytes <= 0:
        return
    if _SYNC_FILE_RANGE is not None and _SYNC_FILE_RANGE(fd, offset, nbytes, _SYNC_ALL) != 0:
        return                                  # (not written: leave the pages, the kernel writes them later)
    forget_cached(fd, offset, nbytes)


def forget_cached(fd: int, offset: int, nbytes: int) -> None:
    """Take the clean pages of bytes ``offset`` … ``offset + nbytes`` of ``fd`` out of the page cache
    (``POSIX_FADV_DONTNEED``; e.g. after reading them, see :func:`drop_cached`), once the process's
    scratch files are past their budget (:func:`over_budget`)."""
    if nbytes > 0 and over_budget() and hasattr(os, "posix_fadvise"):
        os.posix_fadvise(fd, offset, nbytes, os.POSIX_FADV_DONTNEED)


_PUSHED = [0]                   # bytes written to the scratch files still open (as Behind.push was told)


def over_budget() -> bool:
    """Whether the scratch files open now hold more than
    :data:`cdgps_cli.config.options.SCRATCH_CACHE_BYTES` (as :meth:`Behind.push` was told; a file's
    bytes stop counting when its :class:`Behind` goes, with the file): only then are their pages
    written and dropped (under it, a short record's scratch files never reach the disk, as before)."""
    return _PUSHED[0] > SCRATCH_CACHE_BYTES


class Behind:
    """Ranges of a file written to disk and dropped from the page cache one step behind the writer,
    once the process's scratch files are past their budget (:func:`over_budget`): :meth:`push`
    starts writing the new ranges (without waiting) and drops the ranges of the previous push
    (:func:`drop_cached`: by then written, or nearly), so the disk works while the writer computes;
    :meth:`settle` drops what is pending now.  (The disk here writes ≈ 170 MB/s: dropping the
    scratch of a one-hour record too would cost more wall time than the page cache it saves.)

    Parameters
    ----------
    fd : int
        The file's descriptor.
    """

    def __init__(self, fd: int):
        self.fd, self.pending = fd, []
        self.lo = self.hi = 0                       # the bytes pushed so far (a forward or backward sweep)
        self.counted, self._into = 0, _PUSHED       # of them in _PUSHED (taken out when this goes)

    def __del__(self):
        self._into[0] -= self.counted

    def push(self, ranges, fresh: int | None = None) -> None:
        """``ranges``: (offset, nbytes) pairs just written (nothing done under :func:`over_budget`).
        ``fresh``: how many of their bytes are new to the file (None: the range of a sweep forward or
        backward, where bytes pushed again, e.g. a released prefix, count once)."""
        ranges = [(int(o), int(n)) for o, n in ranges if n > 0]
        new = 0 if fresh is None else int(fresh)
        for o, n in ranges if fresh is None else ():
            if self.hi <= self.lo:
                self.lo = self.hi = o
            new += max(min(o + n, self.lo) - o, 0) + max(o + n - max(o, self.hi), 0)
            self.lo, self.hi = min(self.lo, o), max(self.hi, o + n)
        self.counted += new
        self._into[0] += new
        if not over_budget():
            return
        if _SYNC_FILE_RANGE is not None:
            for o, n in ranges:
                _SYNC_FILE_RANGE(self.fd, o, n, _START)
        self.settle()
        self.pending = ranges

    def settle(self) -> None:
        for o, n in self.pending:
            drop_cached(self.fd, o, n)
        self.pending = []


class DropBehind:
    """A scratch file written from its start, front to back (``fh.write``), whose bytes leave the
    page cache behind the writer (:class:`Behind`) every ``step`` bytes: call :meth:`wrote` after
    each write and :meth:`close` after the last (the file's object is flushed first).

    Parameters
    ----------
    fh : file object
        Open for writing, at offset 0.
    step : int
        Bytes written between two pushes.
    """

    def __init__(self, fh, step: int = 8 * DROP_CACHE_MIN_BYTES):
        self.fh, self.step, self.done, self.pushed = fh, int(step), 0, 0
        self.behind = Behind(fh.fileno())

    def wrote(self, nbytes: int) -> None:
        self.done += int(nbytes)
        if self.done - self.pushed >= self.step:
            self._push()

    def _push(self) -> None:
        self.fh.flush()
        self.behind.push([(self.pushed, self.done - self.pushed)])
        self.pushed = self.done

    def close(self) -> None:
        """Drop every byte written so far (waiting for the last ones to be written)."""
        self._push()
        self.behind.settle()


def _reserve(fd: int, nbytes: int) -> None:
    """Give the file its ``nbytes`` of disk now (``posix_fallocate``): a full disk is an OSError
    here, not a SIGBUS when a page of the mapping is first written.  Where the file system cannot
    reserve, the file is only extended (sparse)."""
    try:
        os.posix_fallocate(fd, 0, nbytes)
    except OSError as exc:
        if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
            raise
        os.ftruncate(fd, nbytes)
    except AttributeError:                    # (no posix_fallocate on this platform)
        os.ftruncate(fd, nbytes)


class DiskHistory:
    """Arrays over unlinked temporary files in ``dir`` (None: the system's temporary directory).

    Parameters
    ----------
    dir : path, optional
        Where the temporary files go (the output's directory keeps them on the disk the output is
        written to).
    output : path, optional
        The output these files serve, named in the error when one cannot be made.
    """

    on_disk = True

    def __init__(self, dir: str | Path | None = None, output: str | Path | None = None):
        # (a directory that does not exist yet, e.g. the output's before it is written: the system's)
        self.dir = str(dir) if dir is not None and Path(dir).is_dir() else None
        self.output = None if output is None else str(output)

    def empty(self, shape: tuple, dtype=np.float64) -> np.ndarray:
        """An uninitialized C-contiguous array of ``shape`` and ``dtype`` on disk (writable)."""
        nbytes = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        if nbytes == 0:
            return np.empty(shape, dtype=dtype)
        try:
            with tempfile.TemporaryFile(prefix=".cdgps-history-", dir=self.dir) as fh:
                _reserve(fh.fileno(), nbytes)
                # the mapping holds its own descriptor: the file lives as long as the array
                arr = np.memmap(fh, dtype=dtype, mode="r+", shape=shape)
                fd = os.dup(fh.fileno())        # (release's page-cache drops; closed with the mapping)
                _FDS[arr._mmap], _BEHIND[arr._mmap] = fd, Behind(fd)
                weakref.finalize(arr._mmap, os.close, fd)
                return arr
        except OSError as exc:
            where = self.dir or tempfile.gettempdir()
            serves = f"{self.output}: " if self.output else ""
            raise CdgpsError(f"{serves}cannot make a scratch file of {nbytes / 2**20:.0f} MiB in {where} for the "
                             f"filter's history: {(exc.strerror or str(exc)).lower()}") from None

    @staticmethod
    def release(arr: np.ndarray, start: int, stop: int) -> None:
        """Drop rows ``start`` … ``stop``−1 of ``arr`` (first axis) from memory; their values stay
        in the file and come back when read.  Every page holding any of those rows is dropped, the
        two at the ends too: the mapping is a shared one of the file, so the other rows on those
        pages keep their values (in the file) and come back when next read.  (Dropping only the pages
        wholly inside the rows kept every page of a run of short ranges resident: the fused smoother's
        stretches of 2–25 epochs, ≈ 4 MiB per minute of a 100 Hz record, issue 29.)  The range is
        widened by :data:`FAULT_AROUND_BYTES` on each side: a read of a row next to released ones maps
        the file's cached pages around it again (the kernel's fault-around), which would otherwise stay."""
        mm = getattr(arr, "_mmap", None)
        if mm is None or arr.ndim == 0:
            return
        start, stop = max(int(start), 0), min(int(stop), arr.shape[0])      # (rows past the end: none)
        if stop <= start:
            return
        row = arr.strides[0]
        mapped = np.frombuffer(mm, dtype=np.uint8, count=1)           # the mapping's first byte
        origin = arr.__array_interface__["data"][0] - mapped.__array_interface__["data"][0]
        del mapped
        page = mmap.PAGESIZE
        a = max(origin + start * row - FAULT_AROUND_BYTES, 0) // page * page
        b = min(-(-(origin + stop * row + FAULT_AROUND_BYTES) // page) * page, len(mm))
        if b > a:
            mm.madvise(mmap.MADV_DONTNEED, a, b - a)
        behind = _BEHIND.get(mm)
        if behind is not None and (stop - start) * row >= DROP_CACHE_MIN_BYTES:
            behind.push([(origin + start * row, (stop - start) * row)])
