"""u-blox UBX binary logs: GPS L1 C/A carrier phase from RXM-RAWX messages.

:func:`read_ubx_rawx` frames the log itself (sync ``0xB5 0x62``, length, 8-bit Fletcher
checksum), so that a corrupt frame costs only that frame: after a checksum failure the search for
the next frame resumes two bytes on, not after the (possibly corrupt) announced length.  Frames
that pass the checksum are decoded with `pyubx2 <https://pypi.org/project/pyubx2/>`_, the
reference Python implementation of the UBX protocol.  Bytes between frames (NMEA sentences,
RTCM 3 messages, noise) are skipped and counted.

RXM-RAWX (u-blox 8 / M8T, F9P/F9T and later) carries, per signal: pseudorange, carrier phase,
Doppler, C/N0, lock time and the tracking status bits (pseudorange valid, carrier phase valid,
half-cycle valid, half-cycle subtracted).  Only GPS L1 C/A (gnssId 0, sigId 0) rows are returned;
the other signals are counted in ``info``.

The legacy RXM-RAW message (u-blox 4/5/6, e.g. LEA-4T/LEA-6T) is refused: it has no lock time and
no half-cycle status, so a carrier phase that still carries the navigation-bit half-cycle
ambiguity cannot be told from a resolved one — a silent half-cycle error breaks integer ambiguity
resolution — and slips are flagged only by a per-epoch LLI.
"""

from __future__ import annotations

import gzip
import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import CdgpsError

__all__ = ["INTEGRITY_COUNTS", "UBX_OBS_COLUMNS", "integrity_line", "integrity_problems", "integrity_record", "read_ubx_rawx"]

UBX_OBS_COLUMNS = (
    "time_gps_s",
    "sat",
    "phase_l1_cycles",
    "pseudorange_l1_m",
    "doppler_l1_hz",
    "snr_l1_dbhz",
    "lock_time_ms",
    "cp_valid",
    "pr_valid",
    "half_cycle_resolved",
    "sub_half_subtracted",
    "pr_std_m",
    "cp_std_cycles",
    "clock_reset",
)
"""Columns of the table returned by :func:`read_ubx_rawx`."""

_SYNC = b"\xb5\x62"
_RAWX = (0x02, 0x15)
_GNSS = {0: "GPS", 1: "SBAS", 2: "Galileo", 3: "BeiDou", 4: "IMES", 5: "QZSS", 6: "GLONASS", 7: "NavIC"}
_MAX_SHOWN = 5


def _checksum(frame: bytes) -> bytes:
    """UBX 8-bit Fletcher checksum over class, id, length and payload."""
    arr = np.frombuffer(frame, dtype=np.uint8).astype(np.int64)
    a = int(arr.sum()) & 0xFF
    b = int(np.dot(np.arange(arr.size, 0, -1, dtype=np.int64), arr)) & 0xFF
    return bytes((a, b))


def _msg_name(cls: int, mid: int) -> str:
    try:
        from pyubx2 import UBX_MSGIDS  # noqa: PLC0415

        return UBX_MSGIDS.get(bytes((cls, mid)), f"UBX-0x{cls:02X}-0x{mid:02X}")
    except ImportError:  # pragma: no cover
        return f"UBX-0x{cls:02X}-0x{mid:02X}"


def _signal_name(gnss: int, sig: int) -> str:
    try:
        from pyubx2 import SIGID  # noqa: PLC0415

        s = SIGID.get((gnss, sig))
    except ImportError:  # pragma: no cover
        s = None
    return f"{_GNSS.get(gnss, f'gnss{gnss}')} {s or f'sig{sig}'}"


_NMEA = re.compile(rb"\$[A-Z][A-Z0-9]{1,5},[\x20-\x7e]{0,79}?\*([0-9A-Fa-f]{2})\r?\n")

INTEGRITY_COUNTS = {
    "n_frames": "frames read",
    "bad_checksum_frames": "failing the checksum",
    "undecodable_frames": "RXM-RAWX frames with a valid checksum but undecodable",
    "skipped_bytes": "bytes skipped between frames",
    "truncated_tail_bytes": "bytes of a truncated frame at the end",
}
"""The integrity counters of a UBX log (keys of the reader's ``info``) and how they are worded.
All but ``n_frames`` mean lost data: they are reported at ingest, kept in the RUN and shown by
``cdgps info``; ``cdgps ingest --strict`` refuses a log where any is non-zero."""


def _nmea_bytes(seg: bytes) -> int:
    """Bytes of ``seg`` that are complete NMEA 0183 sentences with a correct checksum."""
    n = 0
    for m in _NMEA.finditer(seg):
        body = m.group(0)[1 : m.start(1) - m.start(0) - 1]
        x = 0
        for c in body:
            x ^= c
        if x == int(m.group(1), 16):
            n += m.end() - m.start()
    return n


def _frames(data: bytes):
    """Split a log into checksum-valid UBX frames.

    Returns
    -------
    frames : list of (offset, class, id, frame bytes)
    stats : dict
        ``bad_checksum_frames``, ``bad_frame_offsets``, ``truncated_tail_bytes``;
        ``nmea_bytes`` (complete NMEA sentences between frames, checksums correct) and
        ``skipped_bytes`` (every other byte outside valid frames: noise, RTCM, corrupt frames).
    """
    stats = {"bad_checksum_frames": 0, "bad_frame_offsets": [], "truncated_tail_bytes": 0, "skipped_bytes": 0,
             "nmea_bytes": 0}
    n = len(data)
    pos = 0        # first byte not yet accounted for
    scan = 0       # where the search for the next sync resumes
    frames = []

    def skip(a: int, b: int) -> None:
        if b > a:
            nm = _nmea_bytes(data[a:b]) if b"$" in data[a:b] else 0
            stats["nmea_bytes"] += nm
            stats["skipped_bytes"] += b - a - nm

    while True:
        k = data.find(_SYNC, scan)
        if k < 0:
            skip(pos, n)
            break
        if k + 6 > n:
            skip(pos, k)
            stats["truncated_tail_bytes"] = n - k
            break
        length = int.from_bytes(data[k + 4 : k + 6], "little")
        end = k + 8 + length
        if end > n:
            # either a frame cut by the end of the log, or a corrupt length: look for a later
            # sync; if none gives a valid frame the rest is a truncated tail
            if data.find(_SYNC, k + 2) < 0:
                skip(pos, k)
                stats["truncated_tail_bytes"] = n - k
                break
            stats["bad_checksum_frames"] += 1
            stats["bad_frame_offsets"].append(k)
            scan = k + 2
            continue
        body = data[k + 2 : k + 6 + length]
        if _checksum(body) != data[k + 6 + length : end]:
            stats["bad_checksum_frames"] += 1
            stats["bad_frame_offsets"].append(k)
            scan = k + 2
            continue
        skip(pos, k)
        frames.append((k, data[k + 2], data[k + 3], data[k:end]))
        pos = scan = end
    return frames, stats


def integrity_problems(info: dict) -> list[str]:
    """The non-zero loss counters of a UBX read summary, worded (empty: nothing was lost).

    ``info`` is the ``info`` of :func:`read_ubx_rawx` (also as stored in a RUN); counters it
    lacks count as zero.
    """
    out = []
    offsets = {"bad_checksum_frames": "bad_frame_offsets", "undecodable_frames": "undecodable_frame_offsets"}
    for key, word in INTEGRITY_COUNTS.items():
        v = int(info.get(key) or 0)
        if key == "n_frames" or not v:
            continue
        text = f"{v} {word}"
        if key == "bad_checksum_frames":
            text = f"{v} frame(s) failing the checksum"
        elif key == "undecodable_frames":
            text = f"{v} RXM-RAWX frame(s) with a valid checksum but undecodable"
        offs = list(info.get(offsets.get(key, ""), None) or [])
        if offs:
            text += f" (byte offsets {', '.join(map(str, offs))}{' …' if v > len(offs) else ''})"
        out.append(text)
    return out


def integrity_line(info: dict) -> str:
    """One line of counters for ``cdgps info``: ``14 frames read, 0 failing the checksum, …``."""
    return ", ".join(f"{int(info.get(k) or 0)} {w}" for k, w in INTEGRITY_COUNTS.items())


def integrity_record(info: dict) -> str:
    """The counters as one metadata value: ``n_frames=14 bad_checksum_frames=0 …``."""
    return " ".join(f"{k}={int(info.get(k) or 0)}" for k in INTEGRITY_COUNTS)


def read_ubx_rawx(path: str | Path, *, strict: bool = False) -> tuple[dict, pd.DataFrame]:
    """Read GPS L1 C/A raw measurements from the RXM-RAWX messages of a u-blox UBX log.

    Parameters
    ----------
    path : str or Path
        A binary UBX log (may also contain NMEA/RTCM; may be gzip-compressed).
    strict : bool, default False
        Raise when any integrity counter but ``n_frames`` is non-zero (a frame failing the
        checksum or with an impossible length, an undecodable RXM-RAWX payload, bytes skipped
        between frames, a truncated tail) instead of skipping the data and counting it in
        ``info``; the message names the file and every count.

    Returns
    -------
    info : dict
        ``path``; ``message_counts`` (UBX message name → count, e.g. ``{"RXM-RAWX": 14}``);
        ``n_frames``; ``n_epochs`` (RXM-RAWX messages); ``week`` (first epoch's GPS week);
        ``leap_seconds`` (GPS−UTC from the receiver, None if never marked valid);
        ``signal_counts`` (e.g. ``{"GPS L1_C/A": 62, "Galileo E1_C": 70, …}``);
        ``gps_satellites``; ``n_clock_resets``; and the integrity counters
        (:data:`INTEGRITY_COUNTS`, :func:`integrity_problems`): ``bad_checksum_frames`` and
        ``bad_frame_offsets`` (byte offsets, first few) of skipped corrupt frames;
        ``undecodable_frames`` and ``undecodable_frame_offsets`` (RXM-RAWX frames whose checksum
        is valid but whose payload cannot be decoded, e.g. a measurement count longer than the
        frame); ``truncated_tail_bytes`` (an incomplete frame cut by the end of the log, skipped);
        ``skipped_bytes`` (bytes outside valid frames that are not NMEA sentences: noise, RTCM,
        and the bytes of corrupt frames); ``nmea_bytes`` (NMEA sentences with correct checksums
        between frames: expected in a receiver's output, not a loss).
    obs : DataFrame
        One row per RXM-RAWX epoch and GPS satellite tracked on L1 C/A, sorted by time then
        satellite; columns :data:`UBX_OBS_COLUMNS`:

        ``time_gps_s`` (float64, week·604800 + rcvTow: the receiver's local time tag, GPS s since
        1980-01-06), ``sat`` ("G05"), ``phase_l1_cycles`` (cpMes, float64; NaN unless
        ``cp_valid``), ``pseudorange_l1_m`` (prMes; NaN unless ``pr_valid``), ``doppler_l1_hz``
        (doMes), ``snr_l1_dbhz`` (cno, float64), ``lock_time_ms`` (locktime, int64: carrier phase
        lock time, capped at 64500 ms), ``cp_valid``, ``pr_valid``, ``half_cycle_resolved``
        (trkStat "half cycle valid"), ``sub_half_subtracted`` (trkStat "half cycle subtracted
        from phase") — bools —, ``pr_std_m`` (0.01·2^prStd m), ``cp_std_cycles``
        (0.004·cpStd cycles), ``clock_reset`` (bool, recStat clkReset of the epoch).

    Raises
    ------
    CdgpsError
        Unreadable file; no UBX frames; no RXM-RAWX messages (the message lists what the log
        contains, and explains why legacy RXM-RAW logs are refused); RXM-RAWX without any GPS L1
        C/A measurement; epochs going backwards; with ``strict``, any corrupt frame.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read: {exc.strerror or exc}") from None
    if data[:2] == b"\x1f\x8b":
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as exc:
            raise CdgpsError(f"{p}: cannot decompress this gzip file: {exc}") from None
    if not data:
        raise CdgpsError(f"{p}: empty file; expected a u-blox UBX binary log")
    frames, stats = _frames(data)
    counts: dict[str, int] = {}
    for _, cls, mid, _ in frames:
        name = _msg_name(cls, mid)
        counts[name] = counts.get(name, 0) + 1
    if not frames:
        extra = f" ({stats['bad_checksum_frames']} candidate frames failed the checksum)" if stats["bad_checksum_frames"] else ""
        raise CdgpsError(f"{p}: no valid UBX frames found in {len(data)} bytes{extra}; expected a u-blox UBX binary log with RXM-RAWX messages")
    rawx = [(off, fr) for off, cls, mid, fr in frames if (cls, mid) == _RAWX]
    found = ", ".join(f"{k} ×{v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))
    if stats["nmea_bytes"]:
        found += f", and {stats['nmea_bytes']} bytes of NMEA sentences"
    if stats["skipped_bytes"]:
        found += f", and {stats['skipped_bytes']} bytes of other non-UBX data"
    if not rawx:
        if counts.get("RXM-RAW"):
            raise CdgpsError(
                f"{p}: no RXM-RAWX messages; this is a legacy u-blox raw log with {counts['RXM-RAW']} RXM-RAW messages "
                f"(u-blox 4/5/6 receivers; found: {found}). RXM-RAW is not supported: it has no carrier lock time and no "
                "half-cycle status, so a phase still carrying the half-cycle ambiguity cannot be told from a resolved one "
                "(a silent half-cycle error breaks integer ambiguity resolution) and slips are flagged only by a per-epoch "
                "LLI. Record RXM-RAWX with a u-blox M8T, F9P/F9T or later receiver."
            )
        raise CdgpsError(f"{p}: no RXM-RAWX messages (found: {found}); carrier-phase logging needs RXM-RAWX enabled on the receiver")

    from pyubx2 import UBXReader  # noqa: PLC0415
    from pyubx2.exceptions import UBXMessageError, UBXParseError, UBXTypeError  # noqa: PLC0415

    cols: dict[str, list] = {c: [] for c in UBX_OBS_COLUMNS}
    signals: dict[str, int] = {}
    undecodable = 0
    undecodable_offsets: list[int] = []
    undecodable_reasons: list[str] = []
    n_resets = 0
    leap = None
    week0 = None
    last_t = -np.inf
    last_off = 0
    n_epochs = 0
    for off, fr in rawx:
        try:
            msg = UBXReader.parse(fr)
        except (UBXParseError, UBXMessageError, UBXTypeError, ValueError, IndexError, struct.error) as exc:
            undecodable += 1
            undecodable_offsets.append(off)
            if len(undecodable_reasons) < _MAX_SHOWN:
                undecodable_reasons.append(f"byte {off}: {exc}")
            continue
        t = float(msg.week) * 604800.0 + float(msg.rcvTow)
        if t < last_t:
            raise CdgpsError(f"{p}, byte {off}: RXM-RAWX epoch (week {msg.week}, rcvTow {msg.rcvTow} s) is earlier than the previous one (byte {last_off}); epochs must be in time order")
        last_t, last_off = t, off
        n_epochs += 1
        if week0 is None:
            week0 = int(msg.week)
        if getattr(msg, "leapSec", 0):
            leap = int(msg.leapS)
        reset = bool(getattr(msg, "clkReset", 0))
        n_resets += reset
        for i in range(1, int(msg.numMeas) + 1):
            sfx = f"_{i:02d}"
            gnss = int(getattr(msg, "gnssId" + sfx))
            sig = int(getattr(msg, "sigId" + sfx))
            name = _signal_name(gnss, sig)
            signals[name] = signals.get(name, 0) + 1
            if gnss != 0 or sig != 0:
                continue
            cp_ok = bool(getattr(msg, "cpValid" + sfx))
            pr_ok = bool(getattr(msg, "prValid" + sfx))
            cols["time_gps_s"].append(t)
            cols["sat"].append(f"G{int(getattr(msg, 'svId' + sfx)):02d}")
            cols["phase_l1_cycles"].append(float(getattr(msg, "cpMes" + sfx)) if cp_ok else np.nan)
            cols["pseudorange_l1_m"].append(float(getattr(msg, "prMes" + sfx)) if pr_ok else np.nan)
            cols["doppler_l1_hz"].append(float(getattr(msg, "doMes" + sfx)))
            cols["snr_l1_dbhz"].append(float(getattr(msg, "cno" + sfx)))
            cols["lock_time_ms"].append(int(getattr(msg, "locktime" + sfx)))
            cols["cp_valid"].append(cp_ok)
            cols["pr_valid"].append(pr_ok)
            cols["half_cycle_resolved"].append(bool(getattr(msg, "halfCyc" + sfx)))
            cols["sub_half_subtracted"].append(bool(getattr(msg, "subHalfCyc" + sfx)))
            cols["pr_std_m"].append(0.01 * 2.0 ** int(getattr(msg, "prStd" + sfx)))
            cols["cp_std_cycles"].append(0.004 * int(getattr(msg, "cpStd" + sfx)))
            cols["clock_reset"].append(reset)
    if strict:
        problems = integrity_problems(dict(stats, undecodable_frames=undecodable,
                                               undecodable_frame_offsets=undecodable_offsets[:_MAX_SHOWN]))
        if problems:
            why = f"; undecodable: {'; '.join(undecodable_reasons)}" if undecodable_reasons else ""
            raise CdgpsError(f"{p}: corrupt UBX data: {', '.join(problems)}{why} (refused by --strict)")
    if n_epochs == 0:
        raise CdgpsError(f"{p}: none of the {len(rawx)} RXM-RAWX messages could be decoded ({'; '.join(undecodable_reasons)})")
    obs = pd.DataFrame(
        {
            "time_gps_s": np.asarray(cols["time_gps_s"], dtype=np.float64),
            "sat": np.asarray(cols["sat"], dtype=object),
            "phase_l1_cycles": np.asarray(cols["phase_l1_cycles"], dtype=np.float64),
            "pseudorange_l1_m": np.asarray(cols["pseudorange_l1_m"], dtype=np.float64),
            "doppler_l1_hz": np.asarray(cols["doppler_l1_hz"], dtype=np.float64),
            "snr_l1_dbhz": np.asarray(cols["snr_l1_dbhz"], dtype=np.float64),
            "lock_time_ms": np.asarray(cols["lock_time_ms"], dtype=np.int64),
            "cp_valid": np.asarray(cols["cp_valid"], dtype=bool),
            "pr_valid": np.asarray(cols["pr_valid"], dtype=bool),
            "half_cycle_resolved": np.asarray(cols["half_cycle_resolved"], dtype=bool),
            "sub_half_subtracted": np.asarray(cols["sub_half_subtracted"], dtype=bool),
            "pr_std_m": np.asarray(cols["pr_std_m"], dtype=np.float64),
            "cp_std_cycles": np.asarray(cols["cp_std_cycles"], dtype=np.float64),
            "clock_reset": np.asarray(cols["clock_reset"], dtype=bool),
        },
        columns=list(UBX_OBS_COLUMNS),
    )
    if obs.empty:
        sig = ", ".join(f"{k} ×{v}" for k, v in sorted(signals.items(), key=lambda kv: -kv[1]))
        raise CdgpsError(f"{p}: {n_epochs} RXM-RAWX epochs but no GPS L1 C/A measurements (signals found: {sig or 'none'})")
    dup = obs.duplicated(["time_gps_s", "sat"])
    if dup.any():
        r = obs[dup].iloc[0]
        raise CdgpsError(f"{p}: GPS satellite {r['sat']} appears twice in the RXM-RAWX epoch at GPS time {r['time_gps_s']:.3f} s")
    obs = obs.sort_values(["time_gps_s", "sat"], kind="stable").reset_index(drop=True)
    info = {
        "path": str(p),
        "message_counts": dict(sorted(counts.items())),
        "n_frames": len(frames),
        "n_epochs": n_epochs,
        "week": week0,
        "leap_seconds": leap,
        "signal_counts": dict(sorted(signals.items())),
        "gps_satellites": sorted(obs["sat"].unique().tolist()),
        "n_clock_resets": int(n_resets),
        "bad_checksum_frames": stats["bad_checksum_frames"],
        "bad_frame_offsets": stats["bad_frame_offsets"][:_MAX_SHOWN],
        "undecodable_frames": undecodable,
        "undecodable_frame_offsets": undecodable_offsets[:_MAX_SHOWN],
        "truncated_tail_bytes": stats["truncated_tail_bytes"],
        "skipped_bytes": stats["skipped_bytes"],
        "nmea_bytes": stats["nmea_bytes"],
    }
    return info, obs
