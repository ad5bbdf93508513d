"""Atomic file output: write under a temporary name in the target directory, rename when complete.

A failed or interrupted command therefore never leaves a half-written output behind, and an
existing file is replaced only by a complete new one.  Commands that write several files replace
them as a set (:func:`output_set`); SIGTERM cleans up like SIGINT (:func:`sigterm_raises`).
See docs/hardening.md, "Output sets".
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import stat
import sys
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

from cdgps_cli.core.errors import CdgpsError


def temporary_name(path: Path) -> Path:
    """The hidden temporary sibling used while ``path`` is being written."""
    return path.with_name(f".{path.name}.tmp{os.getpid()}")


def open_anonymous(directory: Path):
    """An unnamed file in ``directory`` (Linux ``O_TMPFILE``), opened for binary writing, or None
    where the system or file system has none.  Nothing is left if the process is killed, even by
    SIGKILL; :func:`link_anonymous` gives it its name when it is complete."""
    flag = getattr(os, "O_TMPFILE", None)
    if flag is None or not os.path.isdir("/proc/self/fd"):
        return None
    try:
        fd = os.open(directory, flag | os.O_WRONLY, 0o666)   # the umask applies, as for open()
    except OSError:                     # EOPNOTSUPP, EISDIR (old kernels), EINVAL: a named temporary then
        return None
    return os.fdopen(fd, "wb")


def refuse_special_file(path: str | Path, option: str = "") -> None:
    """Refuse an output path where a device, pipe or socket is (``/dev/null``, ``/dev/stdout``, a FIFO):
    the rename that makes a write atomic would replace the device node itself by a regular file (as root,
    ``-o /dev/full`` replaced /dev/full).

    Raises
    ------
    CdgpsError
        Naming the option, the path and what is there; nothing has been written.
    """
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return
    kind = ("a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode)
            else "a pipe (FIFO)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    raise CdgpsError(f"{option + ' ' if option else ''}{path} is {kind}: cdgps writes a complete new file and renames "
                     f"it into place, which would replace it (refused, nothing written); give a regular file path")


def link_anonymous(fh, path: Path) -> None:
    """Give the complete unnamed file ``fh`` (:func:`open_anonymous`) the name ``path``, replacing
    what is there: linked under its hidden temporary name, then renamed (atomic), so a reader never
    sees a partial file and the temporary exists only for the instant between the two calls."""
    refuse_special_file(path)
    fh.flush()
    tmp = temporary_name(path)
    tmp.unlink(missing_ok=True)
    proc = os.open("/proc/self/fd", os.O_RDONLY)
    try:        # linkat(…, AT_SYMLINK_FOLLOW): with a src_dir_fd Python calls linkat, not link (which gives EXDEV)
        os.link(str(fh.fileno()), tmp, src_dir_fd=proc, follow_symlinks=True)
    finally:
        os.close(proc)
    os.replace(tmp, path)


#: errno of a write that failed for lack of room, not for a wrong path or permission
_NO_ROOM = {errno.ENOSPC: "no space left on the device",
            errno.EFBIG: "file too large (the file system's or this process's file-size limit, ulimit -f)",
            errno.EDQUOT: "disk quota exceeded"}


def is_no_room(exc: OSError) -> bool:
    """Whether an OSError is a full device, a file-size limit or an exhausted quota."""
    return exc.errno in _NO_ROOM


def output_error(path: str | Path, exc: OSError) -> CdgpsError:
    """The user-facing error of a failed write of ``path`` (the full-disk cases explained)."""
    if exc.errno in _NO_ROOM:
        return CdgpsError(f"{path}: cannot write: {_NO_ROOM[exc.errno]}; nothing was written there "
                          f"(free some space or choose another output)")
    return CdgpsError(f"{path}: cannot write: {exc.strerror or exc}")


def write_atomic(path: str | Path, writer: Callable[[Path], None]) -> None:
    """Call ``writer(tmp_path)``, then rename the temporary file to ``path``.

    Raises
    ------
    CdgpsError
        If the directory cannot be created or the file cannot be written.
    """
    path = Path(path)
    refuse_special_file(path)
    tmp = temporary_name(path)
    with sigterm_raises():
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            remove_stale_temporaries(path)
            writer(tmp)
            os.replace(tmp, path)
        except OSError as exc:
            raise output_error(path, exc) from None
        finally:
            if tmp.exists():
                tmp.unlink()


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    write_atomic(path, lambda p: p.write_bytes(data))


def file_sha256(path: str | Path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB blocks."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def path_for_config(path: str | Path, relative_to: str | Path | None) -> str:
    """How a config file written into ``relative_to`` names ``path``: relative to that directory
    when possible (another drive on Windows: not), else absolute."""
    path = Path(path).resolve()
    if relative_to is not None:
        try:
            return os.path.relpath(path, Path(relative_to).resolve())
        except ValueError:
            pass
    return str(path)


def _identity(path: Path) -> tuple | None:
    try:
        st = path.stat()
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def refuse_input_overwrite(outputs, inputs) -> None:
    """Refuse to write any output that is, or (an output directory) contains, one of the inputs.

    Parameters
    ----------
    outputs, inputs : iterable of (option, path, is_directory)
        ``option`` names where the path came from (e.g. ``-o``, ``RUN_MCAP``) for the message.
        The same file is recognised however it is spelt (``d/./f``, ``..``, a symlink, a hard link:
        same device and inode).  A directory output refuses every input inside it, since the
        command may replace any file there.

    Raises
    ------
    CdgpsError
        Naming the option and both paths; nothing has been written.
    """
    ins = [(opt, Path(p), _identity(Path(p))) for opt, p, _ in inputs]
    for out_opt, out_path, is_dir in outputs:
        out = Path(out_path)
        out_id = _identity(out)
        for in_opt, in_path, in_id in ins:
            if in_id is None:
                continue
            same = out_id is not None and out_id == in_id
            inside = is_dir and out_id is not None and any(_identity(d) == out_id for d in in_path.resolve().parents)
            if same or inside:
                how = "is the same file as" if same else "is a folder containing"
                raise CdgpsError(f"{out_opt} {out_path} {how} the input {in_opt} {in_path}: writing it would overwrite an "
                                 f"input (refused, nothing written); choose another output path")


def refuse_output_collisions(outputs) -> None:
    """Refuse an empty output path, one where a device or pipe is (:func:`refuse_special_file`), and two
    outputs of one command that are the same file.

    Parameters
    ----------
    outputs : iterable of (option, path, is_directory)
        As for :func:`refuse_input_overwrite`.  Paths are compared after resolving ``.``, ``..``
        and symlinks, so ``-o g.json --figure ./g.json`` is caught before anything is written
        (issue 32: the figure used to replace the gains file).

    Raises
    ------
    CdgpsError
        Naming both options and the path; nothing has been written.
    """
    seen: dict[str, str] = {}
    for opt, path, _ in outputs:
        if not str(path).strip():
            raise CdgpsError(f"{opt}: expected a file or folder path, got an empty string")
        refuse_special_file(path, opt)
        key = os.path.realpath(path)
        if key in seen:
            raise CdgpsError(f"{opt} {path} is the same path as {seen[key]}: the second output would replace the "
                             f"first (refused, nothing written); give each output its own path")
        seen[key] = f"{opt} {path}"


# ----------------------------------------------------------------------------- signals
#
# SIGINT raises KeyboardInterrupt, so the ``finally`` blocks below remove every hidden temporary.
# SIGTERM kills at once by default and left them behind; while cdgps writes, it raises
# :class:`Terminated` instead, through the same cleanup path.  SIGKILL cannot be caught: what it
# leaves is a hidden temporary named with the dead process's id, removed by the next write there.


class Terminated(BaseException):
    """Raised by SIGTERM while cdgps handles it (a BaseException, like KeyboardInterrupt, so that
    ``except Exception`` does not swallow it)."""


#: exit status of a command ended by SIGTERM (128 + 15, as a shell reports a killed program)
TERMINATED_EXIT = 143

#: exit status of a command ended by Ctrl-C (SIGINT: 128 + 2, as a shell reports it)
INTERRUPTED_EXIT = 130


def _raise_terminated(signum, frame):
    signal.signal(signal.SIGTERM, signal.SIG_DFL)      # a second SIGTERM kills at once
    raise Terminated()


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def sigterm_raises():
    """While active, SIGTERM raises :class:`Terminated` (in the main thread, and only if SIGTERM
    still has its default action: a handler of an embedding program is left alone)."""
    installed = False
    if _in_main_thread() and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _raise_terminated)
        installed = True
    try:
        yield
    finally:
        if installed and signal.getsignal(signal.SIGTERM) is _raise_terminated:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextmanager
def signals_deferred():
    """SIGINT and SIGTERM that arrive inside the block take effect when it ends (main thread only;
    elsewhere Python handlers never interrupt the block anyway)."""
    if not _in_main_thread():
        yield
        return
    pending: list[int] = []
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    sigs = [s for s, h in saved.items() if h is not None]     # None: a handler not set from Python, left alone
    for s in sigs:
        signal.signal(s, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for s in sigs:
            signal.signal(s, saved[s])
        for s in pending:
            signal.raise_signal(s)


# ----------------------------------------------------------------------------- stale temporaries

def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` may exist (on this host); another user's counts as alive."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True                      # another user's process (or not ours to judge): leave it
    return True


def remove_stale_temporaries(path: str | Path) -> None:
    """Remove ``.<name>.tmp<pid>`` siblings of ``path`` (files, or the folders of :func:`output_set`)
    whose process no longer exists (left by SIGKILL or a power cut); those of running processes are
    left alone."""
    path = Path(path)
    prefix = f".{path.name}.tmp"
    try:
        entries = list(path.parent.iterdir()) if path.parent.is_dir() else []
    except OSError:
        return
    for p in entries:
        tail = p.name[len(prefix):]
        if p.name.startswith(prefix) and tail.isdigit() and not pid_alive(int(tail)):
            try:
                if p.is_dir() and not p.is_symlink():       # a folder set's staging or swapped-out old folder
                    shutil.rmtree(p)
                else:
                    p.unlink()
            except OSError:
                pass


# ----------------------------------------------------------------------------- output sets
#
# A command that writes several files writes them all into a hidden staging folder inside the
# output folder (``.cdgps-new-<pid>-<random>``: same file system, so every move is a rename).  Only
# when every file is complete does it commit, with SIGINT/SIGTERM deferred and the folder locked
# (flock) against another cdgps committing there:
#
# 1. the staging folder is renamed ``.cdgps-commit-<pid>-<random>`` and holds a journal
#    (``.cdgps-set.json``: the new files and the old files to remove);
# 2. old files of the command's set that the new set does not have are removed;
# 3. each new file is renamed over its old version;
# 4. the emptied commit folder is removed.
#
# An exception or SIGINT/SIGTERM before step 1 removes the staging folder: the old set is left
# untouched.  SIGKILL before step 1 leaves the staging folder; SIGKILL during steps 2-4 (a few
# renames) leaves the commit folder with its journal: the next cdgps write of a set into that
# folder removes the former and finishes (rolls forward) the latter, so the folder then holds the
# complete new set.  Files that are not in the command's set (a user's notes, another command's
# outputs) are never touched.

SET_JOURNAL = ".cdgps-set.json"
_STAGING = ".cdgps-new-"
_COMMIT = ".cdgps-commit-"


@contextmanager
def _folder_lock(folder: Path, required: bool = True):
    """flock on ``folder`` for the block (not POSIX: no lock; ``required=False``: none either when
    the folder cannot be opened, e.g. a parent folder without read permission)."""
    try:
        import fcntl
    except ImportError:                                   # not POSIX: no lock
        yield
        return
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        if required:
            raise
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _roll_forward(out: Path, commit: Path) -> None:
    """Steps 2-4 of a commit (idempotent: a commit interrupted anywhere can be run again)."""
    try:
        journal = json.loads((commit / SET_JOURNAL).read_text())
    except (OSError, ValueError):                         # no journal: step 4 was under way
        shutil.rmtree(commit, ignore_errors=True)
        return
    for name in journal["remove"]:
        p = out / name
        if p.is_symlink() or p.is_file():
            p.unlink()
    for name in journal["files"]:
        if (commit / name).exists():
            os.replace(commit / name, out / name)
    shutil.rmtree(commit, ignore_errors=True)


def recover_output_folder(out: str | Path) -> list[str]:
    """Clean up after a killed cdgps in ``out``: finish interrupted commits, remove the staging
    folders of processes that no longer exist.  Call with the folder locked.  Returns what was done."""
    out = Path(out)
    done = []
    try:
        entries = sorted(out.iterdir())
    except OSError:
        return done
    for p in entries:
        if p.name.startswith(_COMMIT) and p.is_dir():     # a committer holds the lock: none is running
            _roll_forward(out, p)
            done.append(f"finished {p.name}")
        elif p.name.startswith(_STAGING) and p.is_dir():
            pid = p.name[len(_STAGING):].split("-")[0]
            if pid.isdigit() and not pid_alive(int(pid)):
                shutil.rmtree(p, ignore_errors=True)
                done.append(f"removed {p.name}")
    return done


class OutputSet:
    """Where the files of one output set are written: :meth:`path` gives the staging path of a
    file, :attr:`out` the folder it ends up in."""

    def __init__(self, out: Path, staging: Path, reaper=None):
        self.out = out
        self.staging = staging
        self.reaper = reaper          # (process, pipe) of the watcher of a swap's staging folder, or None

    def path(self, name: str) -> Path:
        """Staging path of output file ``name`` (a plain file name)."""
        if not name or "/" in name or os.sep in name or name.startswith(".") or name in (SET_JOURNAL,):
            raise CdgpsError(f"{self.out}: cannot write {name!r} there: an output file name must be a plain, "
                             f"visible file name (no folder, not starting with a dot)")
        return self.staging / name

    def final(self, name: str) -> Path:
        """Where ``name`` will be once the set is committed."""
        return self.out / name

    def names(self) -> list[str]:
        """The files written so far (visible regular files in the staging folder)."""
        return sorted(p.name for p in self.staging.iterdir() if p.is_file() and not p.name.startswith("."))


def _commit(s: OutputSet, replaces) -> None:
    new = s.names()
    for name in new:
        if (s.out / name).is_dir() and not (s.out / name).is_symlink():
            raise CdgpsError(f"{s.out / name}: is a folder, where this command writes a file; nothing was "
                             f"replaced (move the folder or choose another output)")
    remove = sorted(set(replaces) - set(new))
    (s.staging / SET_JOURNAL).write_text(json.dumps({"files": new, "remove": remove}) + "\n")
    with _folder_lock(s.out), signals_deferred():
        commit = s.staging.with_name(_COMMIT + s.staging.name[len(_STAGING):])
        os.replace(s.staging, commit)
        _roll_forward(s.out, commit)


@contextmanager
def output_set(out_dir: str | Path, replaces=()):
    """Write a set of files into ``out_dir`` as a whole (see the comments above).

    Parameters
    ----------
    out_dir : path
        Output folder (created, with its parents, if missing; not left behind if the command fails).
    replaces : iterable of str
        Every file name the command may write.  On success, those the new set lacks are removed
        from ``out_dir`` (e.g. ``actuators.csv`` of an earlier pulse simulation); files with any
        other name are kept untouched.

    Yields
    ------
    OutputSet
        Write each file at ``OutputSet.path(name)``.

    Raises
    ------
    CdgpsError
        If the folder cannot be created or a file cannot be written (the message names the file's
        final path); the earlier set is then untouched.
    """
    out = Path(out_dir)
    created = not out.exists()
    with sigterm_raises():
        real, staging = _swap_staging(out, created)
        if staging is None:
            staging = _inner_staging(out, created)
        s = OutputSet(out, staging, _start_reaper(staging) if real is not None else None)
        ok = False
        try:
            yield s
            if real is not None:
                _commit_swap(s, real, replaces)
            else:
                _commit(s, replaces)
            ok = True
        except CdgpsError as exc:
            raise CdgpsError(str(exc).replace(str(s.staging), str(out))) from None
        except OSError as exc:
            name = Path(exc.filename).name if exc.filename else "an output"
            raise output_error(out / name, exc) from None
        finally:
            if s.staging.exists():
                shutil.rmtree(s.staging, ignore_errors=True)
            _release_reaper(s.reaper)
            if created and not ok and out.is_dir():
                try:
                    out.rmdir()                        # only if still empty
                except OSError:
                    pass


def _inner_staging(out: Path, created: bool) -> Path:
    """The staging folder inside ``out`` of the journaled commit (created, like ``out``, if missing)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CdgpsError(f"{out}: cannot create output directory: {exc.strerror or exc}") from None
    try:
        with _folder_lock(out):
            recover_output_folder(out)
        return Path(tempfile.mkdtemp(prefix=f"{_STAGING}{os.getpid()}-", dir=out))
    except OSError as exc:
        raise CdgpsError(f"{out}: cannot write into the output directory: {exc.strerror or exc}") from None


# ----------------------------------------------------------------------------- folder swap
#
# Where the system allows it (Linux renameat2), a set is staged in a hidden sibling of the output
# folder, ``.<name>.tmp<pid>``, and the two folders are exchanged in one step (RENAME_EXCHANGE):
# every reader, and every kill, sees the whole old folder or the whole new one.  Entries of the old
# folder outside the command's set are hard-linked into the new one first (sub-folders re-created,
# their files linked), so they stay; the old folder, now at the sibling's name, is then removed.
# SIGKILL cannot be caught: a small watcher process (:func:`_start_reaper`, /bin/sh), told "done"
# when the set is in, removes the sibling if the command dies first — before the exchange the
# incomplete new set, after it the old folder — so nothing is left; where it could not run, the
# next write there removes the sibling (its process no longer exists).  The
# journaled commit inside the folder (above) stays the path where a swap is not possible: another
# system, a file system without RENAME_EXCHANGE or hard links, a mount point, this process's own
# current folder, no write permission on the parent.

_AT_FDCWD = -100
_RENAME_EXCHANGE = 2
_renameat2 = None


def _exchange_function():
    """libc's ``renameat2`` (glibc 2.28+), or None (another system or libc)."""
    global _renameat2
    if _renameat2 is None:
        _renameat2 = False
        if sys.platform.startswith("linux"):
            import ctypes

            try:
                fn = ctypes.CDLL(None, use_errno=True).renameat2
            except (OSError, AttributeError):
                return None
            fn.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
            fn.restype = ctypes.c_int
            _renameat2 = fn
    return _renameat2 or None


def exchange_paths(a: Path, b: Path) -> bool:
    """Atomically exchange two existing paths (Linux ``renameat2(RENAME_EXCHANGE)``).

    Returns
    -------
    bool
        False, with nothing changed, where the system or the file system has no such call.

    Raises
    ------
    OSError
        For any other failure (permissions, a path that vanished).
    """
    fn = _exchange_function()
    if fn is None:
        return False
    import ctypes

    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    e = ctypes.get_errno()
    if e in (errno.EINVAL, errno.ENOSYS, errno.EXDEV, errno.EOPNOTSUPP, errno.EBUSY):
        return False
    raise OSError(e, os.strerror(e), str(b))


#: the watcher: waits on the pipe; without "d" (its command died) it removes the staging path
_REAPER_SCRIPT = 'IFS= read -r done <&"$2"; [ "$done" = d ] || rm -rf -- "$1"'


def _start_reaper(path: Path):
    """A watcher that removes ``path`` if this process dies before :func:`_release_reaper` (its own
    session, so a signal to the command's process group leaves it running); None where it cannot
    be started (the next write removes what a killed command left)."""
    import subprocess

    try:
        r, w = os.pipe()
    except OSError:
        return None
    try:
        proc = subprocess.Popen(["/bin/sh", "-c", _REAPER_SCRIPT, "cdgps-reaper", str(path), str(r)], pass_fds=(r,),
                                start_new_session=True, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
    except OSError:
        os.close(w)
        return None
    finally:
        os.close(r)
    return proc, w


def _release_reaper(reaper) -> None:
    """Tell the watcher the command is done with its staging path (it then exits, removing nothing)."""
    import subprocess

    if reaper is None:
        return
    proc, w = reaper
    try:
        os.write(w, b"d")
    except OSError:
        pass
    finally:
        os.close(w)
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        pass


def _swap_staging(out: Path, created: bool) -> tuple[Path | None, Path | None]:
    """(the real output folder, its hidden sibling staging folder), or (None, None) where the set
    must use the journaled commit inside the folder instead."""
    if _exchange_function() is None:
        return None, None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CdgpsError(f"{out}: cannot create output directory: {exc.strerror or exc}") from None
    real = out.resolve()                                  # a symlink given as -o: its target is swapped
    if not created and (not real.is_dir() or os.path.ismount(real)):
        return None, None
    cwd = Path.cwd().resolve()
    if real == cwd or real in cwd.parents:                # keep this process's (and its shell's) folder
        return None, None
    staging = temporary_name(real)
    try:
        if not created:
            with _folder_lock(real):
                recover_output_folder(real)               # a journaled commit of an earlier version
        remove_stale_temporaries(real)
        staging.mkdir()
    except OSError:
        return None, None
    return real, staging


def _link_tree(src: Path, dst: Path) -> None:
    """``dst`` as a copy of entry ``src`` made of hard links (folders re-created, symlinks copied)."""
    if src.is_symlink():
        os.symlink(os.readlink(src), dst)
    elif src.is_dir():
        dst.mkdir()
        for p in src.iterdir():
            _link_tree(p, dst / p.name)
        shutil.copystat(src, dst)
    else:
        os.link(src, dst, follow_symlinks=False)


def _commit_swap(s: OutputSet, real: Path, replaces) -> None:
    """Swap the staged set in for the folder ``real`` (falls back to the journaled commit)."""
    new = s.names()
    for name in new:
        if (real / name).is_dir() and not (real / name).is_symlink():
            raise CdgpsError(f"{s.out / name}: is a folder, where this command writes a file; nothing was "
                             f"replaced (move the folder or choose another output)")
    with _folder_lock(real.parent, required=False), signals_deferred():
        if not real.exists():
            try:
                os.rename(s.staging, real)                # a new folder: appears complete
                return
            except OSError:
                if not real.is_dir():
                    raise
        swapped = _swap_in(s, real, set(new) | set(replaces))
    if swapped:
        shutil.rmtree(s.staging, ignore_errors=True)      # the old folder, now at the sibling's name
        return
    inner = real / f"{_STAGING}{os.getpid()}-{os.urandom(4).hex()}"
    os.rename(s.staging, inner)
    s.staging = inner
    _commit(s, replaces)


def _swap_in(s: OutputSet, real: Path, own: set) -> bool:
    """Link the entries of ``real`` outside ``own`` into the staging folder and exchange the two;
    False (staging as it was) where a link or the exchange is not possible."""
    kept = []
    try:
        for p in sorted(real.iterdir()):
            if p.name not in own:
                _link_tree(p, s.staging / p.name)
                kept.append(p.name)
        shutil.copystat(real, s.staging)                  # the folder's permissions (and ACLs) too
        if exchange_paths(s.staging, real):
            return True
    except OSError:
        pass
    for name in kept:
        q = s.staging / name
        if q.is_dir() and not q.is_symlink():
            shutil.rmtree(q, ignore_errors=True)
        else:
            q.unlink(missing_ok=True)
    return False
