"""The OUTDIR lock of `cdgps batch`: one batch at a time writes a campaign folder.

``OUTDIR/.cdgps-batch.lock`` is created exclusively (``O_CREAT | O_EXCL``, atomic on local file
systems and on NFSv3+) and holds the holder's pid, host, process start time and start date.  A second
batch finds it and is refused (exit 2), naming the file and its holder.  A lock left by a process that
no longer runs on this host (killed with SIGKILL, a crashed machine rebooted) is stale: it is taken
over with a warning.  A lock of another host cannot be checked from here: it is refused, and the
message says how to remove it once no batch runs there any more.
"""

from __future__ import annotations

import json
import os
import socket
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from cdgps_cli.io.atomic import pid_alive
from cdgps_cli.core.errors import CdgpsError

from cdgps_cli.pipeline.batch import LOCK_FILE
#: a lock file that cannot be read (its holder died between creating and writing it) is stale after
#: this long; younger, it is taken as a lock being written right now
UNREADABLE_STALE_S = 60.0


class OutdirLocked(CdgpsError):
    """Another batch holds the OUTDIR lock."""


@dataclass
class OutdirLock:
    """A held lock; :meth:`release` removes the file if it is still this process's."""

    path: Path
    holder: dict

    def release(self) -> None:
        if _read(self.path) == self.holder:
            try:
                self.path.unlink()
            except FileNotFoundError:
                pass


def _start_ticks(pid: int) -> int | None:
    """The start time of process ``pid`` in clock ticks since boot (Linux), to tell a reused pid."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return int(f.read().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def _read(path: Path) -> dict | None:
    try:
        d = json.loads(path.read_text())
        return d if isinstance(d, dict) else None
    except (OSError, ValueError):
        return None


def holder_state(holder: dict | None, path: Path) -> str:
    """``"alive"``, ``"dead"`` (stale, same host) or ``"unknown"`` (another host: cannot be checked)."""
    if holder is None:
        try:
            age = time.time() - path.stat().st_mtime
        except FileNotFoundError:
            return "dead"
        return "dead" if age > UNREADABLE_STALE_S else "alive"
    if holder.get("host") != socket.gethostname():
        return "unknown"
    pid = holder.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return "dead"
    if not pid_alive(pid):
        return "dead"
    start = holder.get("start_ticks")
    if start is not None and _start_ticks(pid) not in (None, start):
        return "dead"                  # the pid was reused by another process
    return "alive"


def _describe(holder: dict | None) -> str:
    if holder is None:
        return "a batch that is writing it now (unreadable)"
    return f"pid {holder.get('pid')} on host {holder.get('host')} since {holder.get('since')}"


def acquire(outdir: str | Path, warn=None) -> OutdirLock:
    """Take the OUTDIR lock (OUTDIR is created if needed).

    Parameters
    ----------
    outdir : the campaign folder
    warn : callable(str) or None, told when a stale lock is taken over

    Raises
    ------
    OutdirLocked
        When another live batch (or one on another host) holds it; names the file and the holder.
    """
    out = Path(outdir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CdgpsError(f"{outdir}: cannot create the campaign folder: {exc.strerror or exc}") from None
    path = out / LOCK_FILE
    me = {"pid": os.getpid(), "host": socket.gethostname(), "start_ticks": _start_ticks(os.getpid()),
          "since": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")}
    for _ in range(5):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            holder = _read(path)
            state = holder_state(holder, path)
            if state == "dead" and _take_over(path, holder):
                if warn is not None:
                    warn(f"{path}: stale lock of {_describe(holder)} (that process is gone); taken over")
                continue
            if state == "dead":
                continue                # another batch took it over first: look again
            hint = ("if no batch runs there any more, remove the file" if state == "unknown"
                    else "wait for it to finish, or choose another -o OUTDIR")
            raise OutdirLocked(f"{path}: OUTDIR is locked by another cdgps batch, {_describe(holder)}; {hint}") from None
        except OSError as exc:
            raise CdgpsError(f"{path}: cannot create the batch lock: {exc.strerror or exc}") from None
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(me) + "\n")
            f.flush()
            os.fsync(f.fileno())
        return OutdirLock(path, me)
    raise OutdirLocked(f"{path}: OUTDIR lock taken and released repeatedly by other batches; try again")


def _take_over(path: Path, holder: dict | None) -> bool:
    """Move a stale lock aside (atomic rename: of two batches taking it over, one succeeds) and
    remove it; put it back if it changed in between (a live batch's new lock)."""
    aside = path.with_name(f"{LOCK_FILE}.stale-{os.getpid()}")
    try:
        os.rename(path, aside)
    except FileNotFoundError:
        return False
    if _read(aside) != holder:
        try:
            os.link(aside, path)        # back, unless a newer lock is there already
        except OSError:
            pass
        aside.unlink(missing_ok=True)
        return False
    aside.unlink(missing_ok=True)
    return True
