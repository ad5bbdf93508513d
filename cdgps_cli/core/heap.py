"""glibc's heap controls (``malloc_trim``, ``mallopt``), the one place that loads them.

Long records free large arrays between stages; glibc keeps freed heap pages in the process unless told
otherwise. The fused run, the batch workers and their settings all use these calls; on a platform
without glibc (not Linux, or musl) every function here does nothing and says so by its return value.
"""

from __future__ import annotations

import functools
import sys

__all__ = ["M_TRIM_THRESHOLD", "M_MMAP_THRESHOLD", "MMAP_THRESHOLD_BYTES", "available", "trim", "set_option",
           "map_large_blocks"]

#: ``mallopt`` parameter numbers (malloc.h)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3


def _glibc(name: str):
    """The C library's function ``name``, or None where there is no glibc (or not Linux)."""
    if not sys.platform.startswith("linux"):
        return None
    return _libc_function(name)


@functools.lru_cache(maxsize=None)
def _libc_function(name: str):
    """The C library's function ``name`` or None, looked up once per process (``find_library`` and
    loading the library cost ~2 ms, and :func:`trim` runs before every fork of core/beside.py)."""
    import ctypes  # noqa: PLC0415
    import ctypes.util  # noqa: PLC0415

    try:
        return getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), name)
    except (OSError, AttributeError):              # not glibc (musl …)
        return None


def available() -> bool:
    """True where glibc's ``mallopt`` can be called."""
    return _glibc("mallopt") is not None


def trim() -> bool:
    """``malloc_trim(0)``: give the heap's free pages back to the system. True when the call was made."""
    fn = _glibc("malloc_trim")
    if fn is None:
        return False
    fn(0)
    return True


def set_option(param: int, value: int) -> bool:
    """``mallopt(param, value)`` for the rest of the process. True when glibc accepted it."""
    fn = _glibc("mallopt")
    return fn is not None and bool(fn(int(param), int(value)))


#: blocks at least this large are mapped on their own and unmapped when freed, bytes (glibc's default
#: starting value; fixed, so that glibc does not raise it as large blocks are freed)
MMAP_THRESHOLD_BYTES = 128 * 1024


def map_large_blocks(threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's mmap threshold at ``threshold_bytes`` for the rest of the process (:func:`set_option`; elsewhere
    nothing).  glibc otherwise raises the threshold to the size of each mapped block freed, so after the first large
    arrays every array of the record's size comes from the heap, whose freed pages stay in RSS between steps (issue
    29); fixed, each array at least that large is its own mapping, returned to the system when freed.  Arithmetic
    unchanged.  True when the call was made."""
    return set_option(M_MMAP_THRESHOLD, threshold_bytes)
