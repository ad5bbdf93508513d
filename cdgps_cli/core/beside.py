"""One pure computation run beside the caller's own, on the machine's second core.

``cdgps rtk`` runs two independent filter passes (forward and backward) over the same epochs; on two
cores the backward pass can run while the forward one does. :func:`start` forks a child process that
computes ``fn()`` and sends its result back through a pipe (pickled), while the parent goes on; the
parent collects it with :meth:`Beside.result`. The child starts from the parent's memory as it is
at the fork (the inputs are not copied or pickled) and runs the same code on the same data, so the
result is the one ``fn()`` gives in the parent, bit for bit.

Before forking, glibc's freed heap pages are given back to the system (:func:`cdgps_cli.core.heap.trim`):
the child then shares fewer pages it might copy, and the two processes together hold less (a day's
``cdgps init``: 1,009 → 894 MiB summed over both at the peak, against 799 MiB for one process in turn).
:func:`both` runs two independent calls this way (a receiver pair's two receivers).

It runs ``fn()`` in the calling process instead (same result, one core) when:

* the platform has no ``fork`` or the process may use only one CPU (``os.sched_getaffinity``);
* the environment variable ``CDGPS_SERIAL`` is set (anything but ``""`` / ``"0"``);
* the fork fails, the child dies without an answer (killed, out of memory) or its answer does not
  unpickle: ``fn()`` is run again in the parent, so a lost child costs time, never a result.

An exception raised by ``fn()`` in the child is raised again by :meth:`Beside.result` in the parent
(the same type and message when it pickles, else a ``RuntimeError`` naming it). The child writes
nothing to the caller's files or streams: it leaves by ``os._exit`` without running ``atexit``
handlers or flushing the parent's buffers. If the parent stops before collecting (an exception,
Ctrl-C), :meth:`Beside.cancel` (also run by the context manager) kills and reaps the child.
"""

from __future__ import annotations

import os
import pickle
import signal
from typing import Callable

from cdgps_cli.core import heap

__all__ = ["start", "both", "Beside", "forking_allowed"]


def forking_allowed() -> bool:
    """True when :func:`start` forks: ``os.fork`` exists, two CPUs are usable, ``CDGPS_SERIAL`` unset."""
    if os.environ.get("CDGPS_SERIAL", "") not in ("", "0") or not hasattr(os, "fork"):
        return False
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    return cpus >= 2


class Beside:
    """A computation started by :func:`start`; :meth:`result` returns its value."""

    def __init__(self, fn: Callable[[], object], pid: int | None = None, fd: int | None = None):
        self._fn, self._pid, self._fd = fn, pid, fd
        self.forked = pid is not None

    def result(self):
        """The value of ``fn()`` (computed in the child, or here if there is none or it died)."""
        if self._pid is None:
            return self._fn()
        answer = self._receive()
        pid, self._pid = self._pid, None
        _, status = os.waitpid(pid, 0)
        if answer is None or not os.WIFEXITED(status) or os.WEXITSTATUS(status) != 0:
            self.forked = False
            return self._fn()                                     # the child died: compute it here
        ok, value = answer
        if ok:
            return value
        raise value

    def _receive(self):
        """The child's ``(ok, value)`` unpickled straight from the pipe (no copy of the whole message is
        held: a large result costs its own size once more while it arrives, not three times); None when
        the message is cut short (the child died) or does not unpickle."""
        try:
            with os.fdopen(self._fd, "rb", closefd=True) as pipe:
                self._fd = None
                return pickle.load(pipe)
        except Exception:                                         # cut short, or an error that does not unpickle
            return None

    def cancel(self) -> None:
        """Kill and reap the child if it is still running (nothing to do once collected)."""
        if self._pid is None:
            return
        pid, self._pid = self._pid, None
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.waitpid(pid, 0)
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> "Beside":
        return self

    def __exit__(self, *exc) -> None:
        self.cancel()


def _send(pipe, fn) -> None:
    """In the child: ``(True, fn())`` pickled straight into the pipe (a failure to pickle it part-way
    leaves a message the parent cannot read, so the parent computes ``fn()`` itself), or
    ``(False, error)`` when ``fn()`` raised (a ``RuntimeError`` naming it if the error does not pickle)."""
    try:
        value = fn()
    except Exception as exc:                                      # sent to the parent, raised there
        try:
            payload = pickle.dumps((False, exc), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:
            payload = pickle.dumps((False, RuntimeError(f"{type(exc).__name__}: {exc}")))
        pipe.write(payload)
        return
    pickle.dump((True, value), pipe, protocol=pickle.HIGHEST_PROTOCOL)


def both(first: Callable[[], object], second: Callable[[], object]) -> tuple:
    """``(first(), second())`` with ``first()`` computed beside (:func:`start`) while ``second()`` runs
    here: the values of the two calls in turn, bit for bit.  An error is the one the calls in turn
    would raise: ``first()``'s if it raises (``second()``'s own is then dropped), else ``second()``'s.
    Neither may rely on the other's side effects (give each its own list to append warnings to, and
    join them in order afterwards).  Without a second core they run in turn, ``first()`` first."""
    if not forking_allowed():
        return first(), second()
    job = start(first)
    with job:
        try:
            b = second()
        except Exception:
            try:
                job.result()
            except Exception as first_error:
                raise first_error from None                   # the calls in turn meet first()'s error first
            raise
        return job.result(), b


def start(fn: Callable[[], object]) -> Beside:
    """Start ``fn()`` (no arguments; a closure over its inputs) in a forked child when
    :func:`forking_allowed`, else defer it to :meth:`Beside.result` in this process."""
    if not forking_allowed():
        return Beside(fn)
    try:
        read_fd, write_fd = os.pipe()
    except OSError:
        return Beside(fn)
    heap.trim()           # the heap's freed pages back to the system first: the two processes hold less
    try:
        pid = os.fork()
    except OSError:
        os.close(read_fd)
        os.close(write_fd)
        return Beside(fn)
    if pid == 0:                                                  # the child: compute, send, leave
        code = 0
        try:
            os.close(read_fd)
            signal.signal(signal.SIGINT, signal.SIG_DFL)          # Ctrl-C ends the child quietly
            with os.fdopen(write_fd, "wb") as pipe:
                _send(pipe, fn)
        except BaseException:
            code = 1
        finally:
            os._exit(code)
    os.close(write_fd)
    return Beside(fn, pid, read_fd)
