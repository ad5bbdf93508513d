"""Integrity of cdgps MCAP files: every byte a computation uses is checked before it is used.

An MCAP file carries four kinds of CRC-32: per chunk (uncompressed records), per attachment, one
over the whole data section (in the Data End record) and one over the summary section and the
footer (in the Footer).  The ``mcap`` reader checks only the first one; :func:`verify_file` checks
the other two here (attachment CRCs are checked by :func:`cdgps_cli.io.mcap.read_mcap`), so that
together every byte of a file cdgps wrote is covered:

* data section, bytes ``[0, Data End)``: header, chunks (schemas, channels, messages), message
  indexes, attachments, metadata records;
* Data End record: its opcode and length are checked literally, its CRC is the stored value;
* summary section and footer up to the summary CRC: schemas and channels (topics and channel
  metadata come from here), statistics, chunk / attachment / metadata indexes, summary offsets;
* the closing magic bytes.

MCAP Metadata records have no CRC of their own, so :meth:`cdgps_cli.io.mcap.McapOut.metadata`
adds a key :data:`RECORD_SHA256_KEY` to each: the SHA-256 of the record's name and its other
key/value pairs in a canonical form (:func:`record_sha256`).  It is verified by
:func:`read_metadata`, the one function through which cdgps reads metadata (kinds, ``final_biases``,
GNSS ``kind``, ...).

Files whose CRC fields are 0 (the MCAP convention for "not computed"):

* a zero summary CRC is refused: topics, channel metadata and every index come from the summary;
* a zero data-section CRC is refused in a file whose header names cdgps as the writing library
  (every cdgps version writes it, so a zero there means a damaged field); in a file written by
  another tool (e.g. rewritten with the ``mcap`` Python writer, whose default leaves it 0) it is
  accepted with one warning on stderr, because the chunk CRCs, the attachment CRCs and the
  metadata records' own ``record_sha256`` still cover every value cdgps reads — and a metadata
  record without ``record_sha256`` is then refused.

Verification reads the file once, sequentially, in blocks (:data:`BLOCK_BYTES`).
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from cdgps_cli.core.errors import CdgpsError

try:                                  # zlib-ng's CRC-32 (carry-less multiply): the same values, ~10x faster
    from zlib_ng.zlib_ng import crc32 as _crc32
except ImportError:                   # (optional: zlib's)
    _crc32 = zlib.crc32

MAGIC = b"\x89MCAP0\r\n"
RECORD_SHA256_KEY = "record_sha256"
CDGPS_LIBRARY = "cdgps"
BLOCK_BYTES = 4 << 20

_OP_HEADER, _OP_FOOTER, _OP_DATA_END = 0x01, 0x02, 0x0F
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4            # opcode, length, summary_start, summary_offset_start, crc
_DATA_END_BYTES = 1 + 8 + 4                   # opcode, length, data_section_crc
_MIN_BYTES = 2 * len(MAGIC) + _FOOTER_BYTES + _DATA_END_BYTES + 1 + 8 + 8
_warned: set = set()


@dataclass
class Integrity:
    """What :func:`verify_file` found: the writing library and which CRCs it checked."""

    library: str
    data_section_crc_checked: bool
    summary_crc_checked: bool
    warnings: list = field(default_factory=list)
    metadata: dict = field(default_factory=dict)     # filled by open_verified (check_records)

    @property
    def ours(self) -> bool:
        return self.library.startswith(CDGPS_LIBRARY)


def record_sha256(name: str, data: dict) -> str:
    """SHA-256 (hex) of a metadata record's name and key/value pairs other than ``record_sha256``.

    Canonical form: UTF-8 JSON of ``[name, [[key, value], ...]]`` with the pairs sorted by key."""
    pairs = sorted([str(k), str(v)] for k, v in data.items() if k != RECORD_SHA256_KEY)
    text = json.dumps([name, pairs], ensure_ascii=False, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()


#: ranges at least this long are checked in parallel parts (zlib.crc32 and os.preadv release the GIL)
CRC_PARALLEL_MIN_BYTES = 32 << 20
_CRC_POLY = 0xEDB88320                 # CRC-32 (zlib's), reflected


def _gf2_mulmod(a: int, b: int) -> int:
    """a(x)·b(x) modulo the CRC-32 polynomial, both in the reflected bit order (x⁰ is bit 31)."""
    m, p = 1 << 31, 0
    while m:
        if a & m:
            p ^= b
        m >>= 1
        b = (b >> 1) ^ _CRC_POLY if b & 1 else b >> 1
    return p


def crc32_combine(crc1: int, crc2: int, len2: int) -> int:
    """CRC-32 of A‖B from crc1 = crc32(A), crc2 = crc32(B) and len(B) (bytes).

    The CRC register is linear over GF(2): feeding B after A multiplies A's register by x^(8·len2)
    modulo the polynomial; x^(8·len2) is built from the squares x^(2^k) (k ≥ 3), so the cost grows
    with log(len2), not len2."""
    factor, sq, n = 1 << 31, 1 << 30, int(len2) * 8        # x⁰, x¹ (reflected), bits to shift
    while n:
        if n & 1:
            factor = _gf2_mulmod(sq, factor)
        sq = _gf2_mulmod(sq, sq)
        n >>= 1
    return _gf2_mulmod(factor, crc1) ^ crc2


def _crc_part(fd: int, start: int, end: int, block: int) -> int:
    """CRC-32 of bytes ``[start, end)`` of descriptor ``fd`` by positioned reads (no shared offset)."""
    buf = bytearray(block)
    view, crc, pos = memoryview(buf), 0, start
    while pos < end:
        n = os.preadv(fd, [view[:min(end - pos, block)]], pos)
        if not n:
            raise EOFError
        crc = _crc32(view[:n], crc)
        pos += n
    return crc


def _crc_parallel(fd: int, start: int, end: int, block: int, parts: int) -> int:
    """CRC-32 of ``[start, end)`` as ``parts`` ranges checked in threads, joined by :func:`crc32_combine`
    (the same value as one pass)."""
    from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415

    bounds = [start + (end - start) * i // parts for i in range(parts + 1)]
    with ThreadPoolExecutor(parts) as ex:
        crcs = list(ex.map(lambda i: _crc_part(fd, bounds[i], bounds[i + 1], block), range(parts)))
    crc = crcs[0]
    for i in range(1, parts):
        crc = crc32_combine(crc, crcs[i], bounds[i + 1] - bounds[i])
    return crc


def _crc_range(fh, start: int, end: int, buf: bytearray) -> int:
    """CRC-32 of the file's bytes ``[start, end)``, read in blocks into ``buf`` (a long range: in
    parallel parts, one per core up to 4, the same value)."""
    parts = min(os.cpu_count() or 1, 4)
    if end - start >= CRC_PARALLEL_MIN_BYTES and parts > 1 and hasattr(os, "preadv"):
        return _crc_parallel(fh.fileno(), start, end, len(buf), parts)
    fh.seek(start)
    crc, left, view = 0, end - start, memoryview(buf)
    while left > 0:
        n = fh.readinto(view[:min(left, len(buf))])
        if not n:
            raise EOFError
        crc = _crc32(view[:n], crc)
        left -= n
    return crc


def _header_library(fh, path, limit: int) -> str:
    """The ``library`` string of the Header record (at offset 8)."""
    fh.seek(len(MAGIC))
    head = fh.read(9)
    if len(head) < 9 or head[0] != _OP_HEADER:
        raise CdgpsError(f"{path}: not a valid MCAP file (no Header record after the magic bytes)")
    length = struct.unpack("<Q", head[1:])[0]
    if length > min(limit, 1 << 20):
        raise CdgpsError(f"{path}: not a valid MCAP file (Header record length {length} is impossible)")
    body = fh.read(length)
    try:
        n = struct.unpack("<I", body[:4])[0]
        m = struct.unpack("<I", body[4 + n:8 + n])[0]
        if 8 + n + m != len(body):
            raise ValueError
        return body[8 + n:8 + n + m].decode("utf-8")
    except (struct.error, ValueError):
        raise CdgpsError(f"{path}: not a valid MCAP file (damaged Header record)") from None


def verify_file(fh, path: str | Path) -> Integrity:
    """Check the magic bytes, the footer, the summary CRC and the data-section CRC of an open file.

    Parameters
    ----------
    fh : binary file
        Opened for reading (seekable); its position is left anywhere.
    path : path
        Named in the messages.

    Returns
    -------
    Integrity

    Raises
    ------
    CdgpsError
        Naming ``path`` and the failing region (data section, summary, footer, ...).
    """
    size = os.fstat(fh.fileno()).st_size
    if size < _MIN_BYTES:
        raise CdgpsError(f"{path}: not a valid MCAP file (truncated or corrupt: {size} bytes)")
    fh.seek(0)
    if fh.read(len(MAGIC)) != MAGIC:
        raise CdgpsError(f"{path}: not a valid MCAP file (it does not start with the MCAP magic bytes)")
    foot_at = size - len(MAGIC) - _FOOTER_BYTES
    fh.seek(foot_at)
    tail = fh.read(_FOOTER_BYTES + len(MAGIC))
    if tail[_FOOTER_BYTES:] != MAGIC:
        raise CdgpsError(f"{path}: not a valid MCAP file (truncated or corrupt: it does not end with the MCAP magic bytes)")
    op, length, summary_start, _offsets, summary_crc = struct.unpack("<BQQQI", tail[:_FOOTER_BYTES])
    if op != _OP_FOOTER or length != _FOOTER_BYTES - 9:
        raise CdgpsError(f"{path}: damaged MCAP footer (opcode {op:#04x}, length {length})")
    if summary_start == 0:
        raise CdgpsError(f"{path}: MCAP file has no summary section (truncated or not written by a complete run)")
    data_end = summary_start - _DATA_END_BYTES
    if not len(MAGIC) < data_end <= foot_at - _DATA_END_BYTES:
        raise CdgpsError(f"{path}: damaged MCAP footer (summary start {summary_start} outside the file)")
    buf = bytearray(min(BLOCK_BYTES, size))
    if summary_crc == 0:
        raise CdgpsError(f"{path}: the MCAP summary has no CRC (summary_crc 0), so its channel topics and indexes "
                         f"cannot be checked; cdgps refuses such files (cdgps itself always writes it)")
    got = _crc_range(fh, summary_start, foot_at + _FOOTER_BYTES - 4, buf)
    if got != summary_crc:
        raise CdgpsError(f"{path}: the MCAP summary section fails its CRC check (stored {summary_crc:#010x}, "
                         f"computed {got:#010x}): the file is corrupt")
    fh.seek(data_end)
    rec = fh.read(_DATA_END_BYTES)
    op, length, data_crc = struct.unpack("<BQI", rec)
    if op != _OP_DATA_END or length != 4:
        raise CdgpsError(f"{path}: damaged MCAP Data End record (opcode {op:#04x}, length {length})")
    library = _header_library(fh, path, data_end)
    info = Integrity(library, data_crc != 0, True)
    if data_crc == 0:
        if info.ours:
            raise CdgpsError(f"{path}: the data-section CRC is 0 in a file written by {library!r}, which always "
                             f"writes it: the field is damaged (corrupt file)")
        info.warnings.append(f"{path}: written by {library or 'an unnamed library'!r} without a data-section CRC; "
                             f"read with the chunk and attachment CRCs and the metadata records' {RECORD_SHA256_KEY}")
        return info
    got = _crc_range(fh, 0, data_end, buf)
    if got != data_crc:
        raise DataSectionDamage(f"{path}: the MCAP data section fails its CRC check (stored {data_crc:#010x}, "
                                f"computed {got:#010x}): the file is corrupt")
    return info


class DataSectionDamage(CdgpsError):
    """The data-section CRC fails; :func:`cdgps_cli.io.mcap.open_verified` then says where (the
    damaged chunk's time span, or the attachment) from the summary, whose own CRC passed."""


def warn_once(info: Integrity) -> None:
    """Print the warnings of ``info`` on stderr, once per message per process."""
    for w in info.warnings:
        if w not in _warned:
            _warned.add(w)
            print(f"cdgps: warning: {w}", file=sys.stderr, flush=True)


def check_records(records, info: Integrity, path) -> dict:
    """Metadata records (``mcap`` Metadata objects) as ``{name: {key: value}}``, each verified.

    ``record_sha256`` is checked where present and removed from the returned values; it is
    required when the data-section CRC was not checked.  A name that appears twice is refused."""
    out: dict = {}
    for m in records:
        data = dict(m.metadata)
        if m.name in out:
            raise CdgpsError(f"{path}: metadata record {m.name!r} appears twice (corrupt or not a cdgps file)")
        stored = data.pop(RECORD_SHA256_KEY, None)
        if stored is None:                            # older cdgps files: covered by the data CRC
            if not info.data_section_crc_checked:
                raise CdgpsError(f"{path}: metadata record {m.name!r} carries no {RECORD_SHA256_KEY} and the file "
                                 f"has no data-section CRC: its values cannot be checked")
        elif stored != record_sha256(m.name, data):
            raise CdgpsError(f"{path}: metadata record {m.name!r} fails its {RECORD_SHA256_KEY} check "
                             f"(a value was changed): the file is corrupt")
        out[m.name] = data
    return out


def read_metadata(path: str | Path) -> dict:
    """Every metadata record of an MCAP file, after :func:`verify_file` and :func:`check_records`.

    Returns
    -------
    dict
        ``{record name: {key: value}}`` (values are strings, ``record_sha256`` removed).

    Raises
    ------
    CdgpsError
        Missing, unreadable, damaged or corrupt file (the message names it and the region).
    """
    from cdgps_cli.io.mcap import open_verified  # noqa: PLC0415 (mcap_io imports this module)

    with open_verified(path) as (reader, _fh, info, _summary):
        return info.metadata
