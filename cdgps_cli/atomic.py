"""Atomic file output: write under a temporary name in the target directory, rename when complete.

A failed or interrupted command therefore never leaves a half-written output behind, and an
existing file is replaced only by a complete new one.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Callable

from .errors import CdgpsError


def temporary_name(path: Path) -> Path:
    """The hidden temporary sibling used while ``path`` is being written."""
    return path.with_name(f".{path.name}.tmp{os.getpid()}")


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
    tmp = temporary_name(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
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
