"""Packed arrays: one numpy array as compact, lossless bytes (an MCAP attachment's content).

Layout (all integers little-endian)::

    b"CDGPSPA1"                      8-byte magic
    uint32  header_length            bytes of the header that follows
    header                           UTF-8 JSON {"dtype": "<f8", "shape": [N, ...], "filter": "shuffle"}
    zstd frame                       the array's bytes, byte-shuffled

"shuffle": the array is viewed as (N, m) (N = first axis, usually epochs; m = the product of the
other axes), transposed so each of the m columns is contiguous in time, and its bytes regrouped by
byte position within an element (all first bytes, then all second bytes, …).  Slowly varying
numbers (times, standard deviations, lock counters, names' codes) then compress to a few percent;
noise-like float64 mantissas stay about their size.  Decoding inverts both steps exactly (same bits,
NaN payloads included).  The zstd level is fixed, so the same array gives the same bytes.

Any numeric dtype numpy writes in ``.npy`` without pickling (bool, integers, floats) is accepted.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import zstandard

MAGIC = b"CDGPSPA1"
MEDIA_TYPE = "application/x-cdgps-packed-array"
FILTER = "shuffle"
LEVEL = 3
_HEAD = struct.Struct("<I")
_MAX_HEADER = 4096


def _compressed_planes(arr: np.ndarray) -> list[bytes]:
    """zstd frame of arr's bytes as (N, m) byte planes (see the module docstring), built one plane
    at a time (no full-size copy of arr)."""
    n = arr.shape[0] if arr.ndim else 1
    cols = np.ascontiguousarray(arr).reshape(n, int(np.prod(arr.shape[1:], dtype=np.int64)))
    octets = cols.view(np.uint8).reshape(n, cols.shape[1], arr.dtype.itemsize)
    cobj = zstandard.ZstdCompressor(level=LEVEL).compressobj(size=cols.nbytes)
    parts = [cobj.compress(np.ascontiguousarray(octets[:, :, b].T)) for b in range(arr.dtype.itemsize)]
    parts.append(cobj.flush())
    return parts


def pack(arr: np.ndarray) -> bytes:
    """The packed bytes of ``arr`` (see the module docstring); ``b"".join(pack_pieces(arr))``."""
    return b"".join(pack_pieces(arr))


def pack_pieces(arr: np.ndarray) -> list[bytes]:
    """The packed bytes of ``arr`` (see the module docstring) in pieces, to be written in order.

    Parameters
    ----------
    arr : ndarray
        Numeric (bool, integer or floating) array of any shape; its dtype is stored in
        little-endian form.

    Returns
    -------
    list of bytes
    """
    arr = np.asarray(arr)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"packed arrays hold bool, integer or float numbers, not dtype {arr.dtype}")
    arr = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    header = json.dumps({"dtype": arr.dtype.str, "filter": FILTER, "shape": list(arr.shape)},
                        sort_keys=True).encode()
    return [MAGIC + _HEAD.pack(len(header)) + header, *_compressed_planes(arr)]


def unpack(data: bytes, what: str = "packed array") -> np.ndarray:
    """The array packed by :func:`pack`.

    Parameters
    ----------
    data : bytes
    what : str
        Name used in error messages (e.g. ``"STATES.mcap: attachment arrays/cdgps/state/xi"``).

    Raises
    ------
    ValueError
        If the bytes are not a packed array, or their header and content disagree.
    """
    data = memoryview(data)
    if bytes(data[:8]) != MAGIC or len(data) < 12:
        raise ValueError(f"{what}: not a packed array (no {MAGIC.decode()} magic)")
    (n_head,) = _HEAD.unpack(data[8:12])
    if n_head > _MAX_HEADER or 12 + n_head > len(data):
        raise ValueError(f"{what}: header length {n_head} is out of range")
    try:
        head = json.loads(bytes(data[12:12 + n_head]))
        dtype = np.dtype(head["dtype"])
        shape = tuple(int(s) for s in head["shape"])
        filt = head["filter"]
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{what}: damaged header ({exc})") from None
    if filt != FILTER or dtype.kind not in "biuf" or any(s < 0 for s in shape):
        raise ValueError(f"{what}: unsupported header {head}")
    size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    try:
        raw = zstandard.ZstdDecompressor().decompress(data[12 + n_head:], max_output_size=max(size, 1))
    except zstandard.ZstdError as exc:
        raise ValueError(f"{what}: damaged content ({exc})") from None
    if len(raw) != size:
        raise ValueError(f"{what}: {len(raw)} bytes of content for shape {list(shape)} of {dtype.str}")
    n = shape[0] if shape else 1
    m = int(np.prod(shape[1:], dtype=np.int64))
    planes = np.frombuffer(raw, dtype=np.uint8).reshape(dtype.itemsize, m, n)
    cols = np.ascontiguousarray(planes.transpose(2, 1, 0)).view(dtype)
    return cols.reshape(shape)
