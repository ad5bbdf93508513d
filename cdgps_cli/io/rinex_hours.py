"""A long RINEX 3 observation file read hour by hour, in bounded memory (issue 29).

A day of a 10 Hz receiver is ≈ 0.4 GB of RINEX text per antenna; read whole, with its tables, an ingest of a pair
held ≈ 3 GB.  This module cuts a plain (uncompressed) RINEX 3 file into the byte ranges of its epochs in each block
of GPS time (:data:`cdgps_cli.io.gnss_archive.OBS_BLOCK_S`, the blocks of a RUN's observation archives), without
reading the file into memory: the file is mapped, and the first epoch of each block is found by bisection on the
epoch lines' time tags.  Each block is then read as a file of its own (the header's bytes, then the block's
records) by the same readers that read whole files (:func:`cdgps_cli.io.rinex.read_rinex_obs`,
:func:`cdgps_cli.io.rinex_signals.read_rinex_signals` with ``read=``), and the blocks' header summaries are joined
(:func:`join_obs_headers`) into what the whole file's reading gives.

Only what can be cut so is cut (:func:`rinex_hours` returns None otherwise, and the file is read whole): the blocks
are checked as they are read (:func:`check_block`) — epochs in time order and each in its block, no special records
(a header record inside the body changes what follows it), epochs in GPS time.
"""

from __future__ import annotations

import math
import mmap
from dataclasses import dataclass
from pathlib import Path

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import COMPRESSED_MAGIC, _ObsHeader, _parse_version_line, _split_lines, epoch_time_system
from cdgps_cli.io.rinex_signals import _epoch_time

__all__ = ["RinexHours", "rinex_hours", "join_obs_headers", "check_block", "NotCut", "cut_or_none", "jump_blocks"]

class NotCut(Exception):
    """A file (or one of its blocks) that cannot be read block by block exactly as whole (the reason): it is read
    whole."""


@dataclass
class RinexHours:
    """A plain RINEX 3 observation file cut into blocks of GPS time.

    ``head``: the header's bytes (through END OF HEADER's line); ``blocks``: [(block number k, first byte, end
    byte, its first epoch's GPS s)] of the body, in file order, each holding the epochs with
    ``floor(t / block_s) == k``."""

    path: Path
    head: bytes
    blocks: list
    block_s: float
    first_s: float
    """GPS s of the first epoch line (:func:`rinex_hours` takes only files whose epochs are in GPS time)."""
    last_s: float
    """GPS s of the last epoch line."""
    order: int = 0
    """The file's place in the list it was given in (a record of several files, :mod:`cdgps_cli.io.gnss_hours`)."""
    kind: str = "rinex"

    def block_bytes(self, j: int) -> tuple[bytes, bool]:
        """The ``read=`` argument of the readers for block ``j``: the header and that block's records (read from
        the file, not through a mapping: sequential reads, and no mapped pages left in the process)."""
        return self.head + read_span(self.path, *self.blocks[j][1:3]), False

    def close(self) -> None:
        """(Nothing is held open between blocks: kept for the callers' symmetry.)"""


def read_span(path: Path, a: int, b: int) -> bytes:
    """Bytes ``a`` to ``b`` of a file; NotCut when it no longer holds them (it changed since it was cut)."""
    with open(path, "rb") as fh:
        fh.seek(a)
        data = fh.read(b - a)
    if len(data) != b - a:
        raise NotCut("the file changed")
    return data


def _advise(m: mmap.mmap, what: str, *span) -> None:
    """``m.madvise(mmap.<what>, *span)`` where the platform has it (a hint: memory, never results)."""
    flag = getattr(mmap, what, None)
    if flag is not None and hasattr(m, "madvise"):
        try:
            m.madvise(flag, *span)
        except OSError:
            pass


def _epoch_time_s(line: bytes) -> float | None:
    """GPS s of a RINEX 3 epoch line (``> 2024 01 01 00 00  0.0000000  0 17``) as the readers compute it
    (:func:`cdgps_cli.io.rinex_signals._epoch_time`), None when it is not one."""
    try:
        return _epoch_time(line.decode("latin-1"), 2, "", 0)
    except CdgpsError:
        return None


def _epoch_at_or_after(m: mmap.mmap, at: int, lo: int, end: int) -> int:
    """Byte offset of the first epoch line starting at or after ``at`` (``end`` if none); ``lo``: the body's start."""
    if at <= lo:
        return lo if m[lo:lo + 1] == b">" else _next_epoch(m, lo, end)
    return _next_epoch(m, at - 1, end)


def _next_epoch(m: mmap.mmap, at: int, end: int) -> int:
    i = m.find(b"\n>", at, end)
    return end if i < 0 else i + 1


def _line(m: mmap.mmap, at: int, end: int) -> bytes:
    nl = m.find(b"\n", at, end)
    return m[at:(end if nl < 0 else nl)]


def _first_epoch_from(m: mmap.mmap, t_s: float, lo: int, end: int) -> int:
    """Byte offset of the first epoch line whose time is ≥ ``t_s`` (epochs in time order), by bisection on bytes."""
    a, b = lo, end
    while b - a > 1:
        mid = (a + b) // 2
        e = _epoch_at_or_after(m, mid, lo, end)
        t = _epoch_time_s(_line(m, e, end)) if e < end else math.inf
        if t is None:
            raise NotCut(f"epoch line at byte {e}")
        if t >= t_s:
            b = mid
        else:
            a = mid
    e = _epoch_at_or_after(m, a, lo, end)
    while e < end:                              # (a ≤ the answer: walk the few epochs left)
        t = _epoch_time_s(_line(m, e, end))
        if t is None:
            raise NotCut(f"epoch line at byte {e}")
        if t >= t_s:
            return e
        e = _next_epoch(m, e, end)
    return end


def rinex_hours(path: str | Path, block_s: float, why: list | None = None) -> RinexHours | None:
    """The file cut into blocks of ``block_s`` seconds of GPS time, or None when it is not a plain RINEX 3
    observation file with its epochs in GPS time (it is then read whole; ``why``, if given, gets the reason, e.g.
    "rover.obs.gz: compressed").  Opening errors are the readers' own (None: the whole reading names them)."""
    return cut_or_none(_cut_file, path, block_s, why)


def cut_or_none(cut, path, block_s: float, why: list | None):
    """``cut(Path(path), block_s)``, or None when it raises NotCut (its reason appended to ``why`` as
    ``"<file name>: <reason>"``)."""
    p = Path(path)
    try:
        return cut(p, block_s)
    except NotCut as exc:
        if why is not None:
            why.append(f"{p.name}: {exc}")
        return None


def _cut_file(p: Path, block_s: float) -> RinexHours:
    try:
        with open(p, "rb") as fh:
            if fh.read(4).startswith(COMPRESSED_MAGIC):
                raise NotCut("compressed")
            if p.stat().st_size < 200:
                raise NotCut("too short to cut")
            m = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        _advise(m, "MADV_RANDOM")            # (the bisection's probes: no read-ahead mapped around each)
    except (OSError, ValueError):
        raise NotCut("cannot be mapped") from None
    try:
        return _cut(p, m, block_s)
    finally:
        m.close()                            # (the probes' pages with it)


def _cut(p: Path, m: mmap.mmap, block_s: float) -> RinexHours:
    at = m.find(b"END OF HEADER")
    nl = m.find(b"\n", at) if at >= 0 else -1
    if nl < 0:
        raise NotCut("no END OF HEADER")
    head = m[:nl + 1]
    system = _epoch_time_system(p, head)
    if system != "GPS":
        raise NotCut(f"epochs in {system} time")
    lo, end = nl + 1, len(m)
    if m[end - 1:end] != b"\n":
        raise NotCut("no line end at the end")      # (a file cut short: the whole reading refuses it, naming the line)
    e0 = _epoch_at_or_after(m, lo, lo, end)
    e1 = m.rfind(b"\n>", lo - 1, end)               # (lo − 1: the header's last line end, before a first epoch)
    t0 = _epoch_time_s(_line(m, e0, end)) if e0 < end else None
    t1 = _epoch_time_s(_line(m, e1 + 1, end)) if e1 >= 0 else None
    if t0 is None or t1 is None or t1 < t0:
        raise NotCut("epochs")
    if e0 > lo:
        raise NotCut("the body does not begin with an epoch line")
    return RinexHours(p, bytes(head), _blocks(m, lo, end, t0, t1, block_s), block_s, t0, t1)


def _blocks(m: mmap.mmap, lo: int, end: int, t0: float, t1: float, block_s: float) -> list:
    """The blocks of a body (bytes ``lo`` to ``end``) whose first and last epochs are at ``t0`` and ``t1`` (GPS s)
    (:func:`jump_blocks`)."""
    def time_at(at: int) -> float:
        t = _epoch_time_s(_line(m, at, end))
        return math.nan if t is None else t

    return jump_blocks(lambda t_s: _first_epoch_from(m, t_s, lo, end), time_at, lo, end, t0, t1, block_s)


def jump_blocks(first_from, time_at, lo: int, end: int, t0: float, t1: float, block_s: float) -> list:
    """[(block number, first byte, end byte, first epoch's GPS s)] of a file's records from byte ``lo`` to ``end``,
    its first and last epochs at ``t0`` and ``t1``: one search for each block that holds an epoch
    (``first_from(t_s)``: the offset of the first epoch at or after ``t_s``; ``time_at(offset)``: that epoch's
    time), from one block's first epoch straight to the next — a first epoch a year early costs no search per hour
    between.  NotCut when the epochs are not in time order."""
    blocks, a, t, k1 = [], lo, t0, math.floor(t1 / block_s)
    while True:
        k = math.floor(t / block_s)
        b = first_from((k + 1) * block_s) if k < k1 else end
        if b <= a:
            raise NotCut("epochs out of time order")
        blocks.append((k, a, b, t))
        if b >= end:
            return blocks
        a, t = b, time_at(b)
        if not math.isfinite(t) or math.floor(t / block_s) <= k:
            raise NotCut("epochs out of time order")


def _epoch_time_system(p: Path, head: bytes) -> str:
    """The time system of the epochs of a RINEX 3 observation file, from its header as the readers parse it
    (:func:`cdgps_cli.io.rinex.epoch_time_system`: TIME OF FIRST OBS, else the file's system's own); NotCut for a
    header the readers would not take as one of a RINEX 3 observation file (the whole reading names what)."""
    try:
        lines = _split_lines(head)
        version, ftype, system = _parse_version_line(lines, p, False, "observation")
        if ftype != "O" or version < 3:
            raise NotCut("RINEX 2" if ftype == "O" else "not an observation file")
        hdr = _ObsHeader(p, version, False)
        hdr.info["satellite_system"] = system or "G"
        hdr.apply_header(lines)
    except (CdgpsError, ValueError, IndexError):
        raise NotCut("its header") from None
    return epoch_time_system(hdr.info)


def check_block(hours: RinexHours, j: int, info: dict, previous_last_s: float | None) -> None:
    """NotCut unless block ``j`` read as a file (``info``: its header summary) is what the whole file's reading
    holds of that block: no special records (a header record inside the body changes what follows it), no epoch
    repeated or out of order, its first and last epochs in the block (so all are: they are in order), after the
    previous block's last (``previous_last_s``, GPS s)."""
    k, a, _, first = hours.blocks[j]
    if info.get("events") or info.get("repeated_epochs") or info.get("epochs_out_of_order"):
        raise NotCut("special records or epochs out of order")
    last = info.get("time_last_obs_gps_s")
    if last is None or math.floor(first / hours.block_s) != k or math.floor(last / hours.block_s) != k:
        raise NotCut(f"an epoch outside its block (byte {a})")
    if previous_last_s is not None and not first > previous_last_s:
        raise NotCut(f"epochs out of order between blocks (byte {a})")


_SUMMED = ("n_epochs", "n_epochs_power_failure", "n_gps_epochs")


def join_obs_headers(infos: list) -> dict:
    """The header of the whole file (:func:`cdgps_cli.io.rinex.read_rinex_obs`) from its blocks' headers, read in
    order: the counts summed, the satellites joined, the last epoch the last block's."""
    out = dict(infos[0])
    for k in _SUMMED:
        out[k] = sum(int(i[k]) for i in infos)
    out["gps_satellites"] = sorted(set().union(*(i["gps_satellites"] for i in infos)))
    systems = sorted(set().union(*(i["satellites_by_system"] for i in infos)))
    out["satellites_by_system"] = {s: sorted(set().union(*(i["satellites_by_system"].get(s, ()) for i in infos)))
                                   for s in systems}
    counts = sorted(set().union(*(i["n_records_by_system"] for i in infos)))
    out["n_records_by_system"] = {s: sum(int(i["n_records_by_system"].get(s, 0)) for i in infos) for s in counts}
    out["time_last_obs_gps_s"] = infos[-1]["time_last_obs_gps_s"]
    return out
