"""A long u-blox UBX log read hour by hour, in bounded memory (issue 29).

A day of a 10 Hz u-blox receiver is ≈ 1–2 GB of RXM-RAWX frames; read whole, the log's bytes and its decoded
measurements are all in memory at once.  This module cuts a plain (uncompressed) UBX log into the byte ranges of
its RXM-RAWX epochs in each block of GPS time (:data:`cdgps_cli.io.gnss_archive.OBS_BLOCK_S`, the blocks of a
RUN's observation archives) without reading it: the first RXM-RAWX frame of each block is found by bisection on
byte offsets, each probe reading a few kilobytes and resynchronising on the next frame whose sync word, class,
length and Fletcher checksum are those of an RXM-RAWX frame.  Each block — from one block's first RXM-RAWX frame to
the next block's, with the other frames between (RXM-SFRBX, NAV, NMEA, RTCM) — is then read by the same decoding as
a whole log (:func:`cdgps_cli.io.ubx.read_ubx_block`), and the blocks' summaries are joined
(:func:`join_ubx_infos`) into what the whole log's reading gives; the RXM-SFRBX frames of every block are kept (a
few bytes a second) and decoded once at the end, in log order, as the whole reading decodes them.

Only what is read exactly as whole is read so (:class:`~cdgps_cli.io.rinex_hours.NotCut` otherwise, and the log is
read whole, which also counts and names what it loses): every block must be clean — no frame failing its checksum,
no undecodable RXM-RAWX, no bytes skipped, no truncated tail, no bad RTCM frame —, its epochs in time order and in
their block, and without ESF-MEAS sensor messages (the sensor tables read the log whole).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cdgps_cli.io.rinex_hours import NotCut, cut_or_none, jump_blocks, read_span
from cdgps_cli.io.ubx_frames import MAX_OFFSETS_SHOWN, _Fletcher, _rtcm_at

__all__ = ["UbxHours", "ubx_hours", "check_ubx_block", "join_ubx_infos", "LOSS_COUNTS"]

_HEAD = b"\xb5\x62\x02\x15"
"""Sync word, class and id of an RXM-RAWX frame."""
_PROBE = 1 << 14
"""Bytes a probe reads at a time (an RXM-RAWX frame is at most 8 + 16 + 32·255 bytes)."""
_MAX_FRAME = 8 + 16 + 32 * 255
_BACK = 1 << 20
"""Bytes :meth:`_Probe.last` looks back at a time."""

LOSS_COUNTS = ("bad_checksum_frames", "undecodable_frames", "truncated_tail_bytes", "skipped_bytes",
               "bad_crc_rtcm_frames")
"""A block's read-summary counters that must all be zero for it to be read as the whole log reads it."""


@dataclass
class UbxHours:
    """A plain UBX log cut into blocks of GPS time: ``blocks`` [(block number k, first byte, end byte, its first
    epoch's GPS s)], in log order, each holding the RXM-RAWX epochs with ``floor(t / block_s) == k`` (the first
    block from the log's first byte, each block to the next one's first RXM-RAWX frame)."""

    path: Path
    blocks: list
    block_s: float
    first_s: float
    last_s: float
    order: int = 0
    """The log's place in the list it was given in (a record of several logs, :mod:`cdgps_cli.io.gnss_hours`)."""
    kind: str = "ubx"
    first_week: int = 0
    """The GPS week field of its first RXM-RAWX frame (the week the whole reading decodes its RXM-SFRBX frames in)."""

    def block_bytes(self, j: int) -> bytes:
        """The bytes of block ``j``, read from the log."""
        return read_span(self.path, *self.blocks[j][1:3])

    def close(self) -> None:
        """(Nothing is held open between blocks: kept for the callers' symmetry.)"""


def _fletcher_ok(frame: bytes) -> bool:
    """Whether a whole UBX frame's two checksum bytes are the 8-bit Fletcher sums of its class, id, length and
    payload: CK_A = Σ x_j and CK_B = Σ (n − j)·x_j over those n bytes (mod 256), vectorised."""
    x = np.frombuffer(frame, dtype=np.uint8)[2:-2].astype(np.int64)
    ck_a = int(x.sum()) & 0xFF
    ck_b = int(np.arange(x.size, 0, -1, dtype=np.int64) @ x) & 0xFF
    return frame[-2] == ck_a and frame[-1] == ck_b


def _rawx_frame_at(buf: bytes, i: int) -> int | None:
    """Length of the RXM-RAWX frame at ``buf[i]`` when one is there, whole and valid (its announced length that of
    its measurement count, its checksum right); 0 when ``buf`` ends before its end; None when not one."""
    if len(buf) < i + 18:
        return 0
    n = int.from_bytes(buf[i + 4:i + 6], "little")
    if n < 16 or (n - 16) % 32 or buf[i + 6 + 11] != (n - 16) // 32:
        return None
    if len(buf) < i + 8 + n:
        return 0
    return 8 + n if _fletcher_ok(buf[i:i + 8 + n]) else None


def _time_s(buf: bytes, i: int) -> float:
    """GPS s (week·604800 + rcvTow) of the RXM-RAWX frame at ``buf[i]``."""
    tow, week = struct.unpack_from("<dH", buf, i + 6)
    return week * 604800.0 + tow


class _Probe:
    """Finds the first valid RXM-RAWX frame at or after a byte offset of an open log."""

    def __init__(self, fh, size: int):
        self.fh, self.size = fh, size

    def at_or_after(self, at: int) -> tuple[int, float]:
        """(offset, GPS s) of the first RXM-RAWX frame starting at or after ``at``; (size, inf) when none."""
        pos = max(at, 0)
        while pos < self.size:
            self.fh.seek(pos)
            buf = self.fh.read(_PROBE + _MAX_FRAME)      # (a frame starting in the first _PROBE bytes is all in it)
            i = 0
            while 0 <= (i := buf.find(_HEAD, i)) < _PROBE:
                if _rawx_frame_at(buf, i):
                    return pos + i, _time_s(buf, i)
                i += 1
            pos += _PROBE
        return self.size, math.inf

    def first_from(self, t_s: float, end: int) -> int:
        """Offset of the first RXM-RAWX frame whose time is ≥ ``t_s`` (frames in time order), by bisection."""
        a, b = 0, end
        while b - a > 1:
            mid = (a + b) // 2
            if self.at_or_after(mid)[1] >= t_s:
                b = mid
            else:
                a = mid
        e, t = self.at_or_after(a)
        while e < end and t < t_s:              # (a ≤ the answer: walk the few frames left)
            e, t = self.at_or_after(e + 1)
        return e

    def last(self) -> tuple[int, float]:
        """(offset, GPS s) of the log's last RXM-RAWX frame, looking back from the end a window at a time (a long
        tail without one is not read at once); (size, inf) when none."""
        end = self.size
        while end > 0:
            start = max(0, end - _BACK)
            self.fh.seek(start)
            buf = self.fh.read(min(self.size, end + _MAX_FRAME) - start)
            i, found = 0, None
            while 0 <= (i := buf.find(_HEAD, i)) < end - start:
                if _rawx_frame_at(buf, i):
                    found = i
                i += 1
            if found is not None:
                return start + found, _time_s(buf, found)
            end = start
        return self.size, math.inf


def ubx_hours(path: str | Path, block_s: float, why: list | None = None) -> UbxHours | None:
    """The log cut into blocks of ``block_s`` seconds of GPS time, or None when it cannot be (compressed, no
    RXM-RAWX frame, epochs out of order at the ends; ``why``, if given, gets the reason).  Opening errors are the
    reader's own (None: the whole reading names them)."""
    return cut_or_none(_cut, path, block_s, why)


def _cut(p: Path, block_s: float) -> UbxHours:
    try:
        size = p.stat().st_size
        fh = open(p, "rb")
    except OSError:
        raise NotCut("cannot be opened") from None
    with fh:
        if fh.read(2) == b"\x1f\x8b":
            raise NotCut("compressed")
        probe = _Probe(fh, size)
        e0, t0 = probe.at_or_after(0)
        e1, t1 = probe.last()
        if not (math.isfinite(t0) and math.isfinite(t1)) or t1 < t0:
            raise NotCut("its RXM-RAWX epochs")
        blocks = _blocks(probe, t0, t1, block_s)
        fh.seek(e0 + 14)
        week = int.from_bytes(fh.read(2), "little")
    return UbxHours(p, blocks, block_s, t0, t1, first_week=week)


def _blocks(probe: _Probe, t0: float, t1: float, block_s: float) -> list:
    """The blocks of a log whose first and last RXM-RAWX epochs are at ``t0`` and ``t1`` (GPS s), the first from the
    log's first byte (:func:`~cdgps_cli.io.rinex_hours.jump_blocks`)."""
    return jump_blocks(lambda t_s: probe.first_from(t_s, probe.size), lambda at: probe.at_or_after(at)[1], 0,
                       probe.size, t0, t1, block_s)


def check_ubx_block(hours: UbxHours, j: int, block: dict, previous_last_s: float | None, strict: bool = False) -> None:
    """NotCut unless block ``j`` (``block``: :func:`cdgps_cli.io.ubx.read_ubx_block` of its bytes) is what the whole
    log's reading holds of it: a block but the log's last ends in whole frames (no truncated tail; after its last
    frame NMEA sentences only, so that a framing of the whole log leaves it where the next block begins), no
    ESF-MEAS message, every epoch in the block and after the previous block's last (``previous_last_s``, GPS s);
    with ``strict`` (``ingest --strict``), nothing lost or skipped (:data:`LOSS_COUNTS`: the whole reading refuses
    it, naming the losses)."""
    k, a, cut, _ = hours.blocks[j]
    info, t = block["info"], block["time_s"]
    if strict and any(int(info.get(c) or 0) for c in LOSS_COUNTS):
        raise NotCut("data lost or skipped, with --strict")
    if j < len(hours.blocks) - 1 and (info["truncated_tail_bytes"] or not block["clean_tail"]
                                      or _frame_across(hours.path, cut)):
        raise NotCut(f"data lost or skipped at the end of the block before byte {cut}")
    if not np.isfinite(t).all() or (np.floor(t / hours.block_s) != k).any():
        raise NotCut(f"an epoch outside its block (byte {a})")
    if info["message_counts"].get("ESF-MEAS"):
        raise NotCut("ESF-MEAS sensor messages")
    if previous_last_s is not None and not float(t[0]) > previous_last_s:
        raise NotCut(f"epochs out of order between blocks (byte {a})")


_OFFSETS = ("bad_frame_offsets", "undecodable_frame_offsets", "bad_rtcm_offsets")


def _frame_across(path: Path, cut: int) -> bool:
    """Whether a whole UBX frame (right checksum) or RTCM 3 frame (right CRC) starts before byte ``cut`` of the log
    and ends after it: a framing of the whole log would read it, and not the frames the block after the cut begins
    with (e.g. a frame carrying frames in its payload)."""
    lo = max(0, cut - 8 - 0xFFFF)
    with open(path, "rb") as fh:
        fh.seek(lo)
        buf = fh.read(cut + 8 + 0xFFFF - lo)
    at, checksum = cut - lo, _Fletcher(buf)
    i = 0
    while 0 <= (i := buf.find(b"\xb5\x62", i)) < at:
        end = i + 8 + int.from_bytes(buf[i + 4:i + 6], "little") if i + 6 <= len(buf) else 0
        if at < end <= len(buf) and checksum(i + 2, end - 2) == buf[end - 2:end]:
            return True
        i += 1
    i = max(0, at - 6 - 0x3FF)
    while 0 <= (i := buf.find(b"\xd3", i)) < at:
        end, _, ok = _rtcm_at(buf, i)
        if ok and end > at:
            return True
        i += 1
    return False


def join_ubx_infos(infos: list, starts: list) -> dict:
    """The read summary of the whole log (:func:`cdgps_cli.io.ubx.read_ubx_log`'s ``info`` but ``sfrbx`` and
    ``rtcm_base``) from its blocks' (:func:`check_ubx_block`), in log order (``starts``: their first bytes in the
    log): the counts summed, the satellites joined, the week the first block's, the leap seconds the last block's
    that knows them, the first few byte offsets of the losses counted in the log."""
    out = dict(infos[0])
    for k in _OFFSETS:
        out[k] = [o + a for i, a in zip(infos, starts) for o in i[k]][:MAX_OFFSETS_SHOWN]
    out["message_counts"] = _summed([i["message_counts"] for i in infos], key=str)
    out["signal_counts"] = _summed([i["signal_counts"] for i in infos], key=str)
    for k in ("n_frames", "n_epochs", "n_clock_resets", "nmea_bytes", "nmea_sentences", "rtcm_bytes", *LOSS_COUNTS):
        out[k] = sum(int(i[k]) for i in infos)
    out["gps_satellites"] = sorted(set().union(*(i["gps_satellites"] for i in infos)))
    out["leap_seconds"] = next((i["leap_seconds"] for i in reversed(infos) if i["leap_seconds"] is not None), None)
    out["rtcm_frames"] = {str(k): v for k, v in _summed([{int(t): c for t, c in i["rtcm_frames"].items()}
                                                         for i in infos], key=int).items()}
    return out


def _summed(dicts: list, key) -> dict:
    total: dict = {}
    for d in dicts:
        for k, v in d.items():
            total[k] = total.get(k, 0) + int(v)
    return dict(sorted(total.items(), key=lambda kv: key(kv[0])))

