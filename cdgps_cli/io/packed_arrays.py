"""Packed arrays: one numpy array as compact, lossless bytes (an MCAP attachment's content).

Layout (all integers little-endian)::

    b"CDGPSPA1"                      8-byte magic
    uint32  header_length            bytes of the header that follows
    header                           UTF-8 JSON {"dtype": "<f8", "shape": [N, ...], "filter": "shuffle"[, "delta": k]}
    zstd frame                       the array's bytes, byte-shuffled

"shuffle": the array is viewed as (N, m) (N = first axis, usually epochs; m = the product of the
other axes), transposed so each of the m columns is contiguous in time, and its bytes regrouped by
byte position within an element (all first bytes, then all second bytes, …).  Slowly varying
numbers (times, standard deviations, lock counters, names' codes) then compress to a few percent;
noise-like float64 mantissas stay about their size.  Decoding inverts both steps exactly (same bits,
NaN payloads included).  The zstd level is fixed, so the same array gives the same bytes.

``"delta": k`` (k = 1 or 2; absent: 0): before the shuffle, each column's numbers, as the unsigned
integers of their bits (a float64 as a uint64), are replaced k times by their differences from
the previous epoch (the first row kept; arithmetic modulo 2^bits), then zigzag-coded (a small
negative difference becomes a small positive number).  For slowly varying series — the covariance
of a filter, whose consecutive matrices share their sign, exponent and leading mantissa bits — the
high bytes of the differences are zeros, which zstd then stores in almost nothing.  Decoding
inverts every step exactly (cumulative sums modulo 2^bits).

Any numeric dtype numpy writes in ``.npy`` without pickling (bool, integers, floats) is accepted.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np
import zstandard

MAGIC = b"CDGPSPA1"
MEDIA_TYPE = "application/x-cdgps-packed-array"
FILTER = "shuffle"
LEVEL = 3
_HEAD = struct.Struct("<I")
_MAX_HEADER = 4096


DELTA_ORDERS = (0, 1, 2)


def _unsigned(itemsize: int) -> np.dtype:
    return np.dtype(f"<u{itemsize}")


def _delta_encode(cols: np.ndarray, order: int, overwrite: bool = False, block: int = 256) -> np.ndarray:
    """(N, m) numbers → their bits' k-th differences along axis 0, zigzag-coded (unsigned, same size).

    In place when ``overwrite`` (``cols`` must then be writeable; any memory layout), else on one
    copy; ``block`` rows at a time from the end (so each block's previous rows are still the values
    being differenced, and the temporaries stay small)."""
    u = cols.view(_unsigned(cols.dtype.itemsize))
    if not overwrite:
        u = u.copy()
    n = u.shape[0]
    for _ in range(order):
        for end in range(n, 1, -block):
            start = max(end - block, 1)
            np.subtract(u[start:end], u[start - 1:end - 1], out=u[start:end])   # modulo 2^bits
    return _zigzag_in_place(u, block)


def _zigzag_in_place(u: np.ndarray, block: int) -> np.ndarray:
    """Map the signed differences held in unsigned ``u`` to zigzag order in place (0, -1, 1, -2 … →
    0, 1, 2, 3 …), ``block`` rows at a time; returns ``u``."""
    s = u.view(u.dtype.str.replace("u", "i"))
    bits = 8 * u.dtype.itemsize
    for a in range(0, u.shape[0], block):
        sign = s[a:a + block] >> (bits - 1)
        np.left_shift(s[a:a + block], 1, out=s[a:a + block])
        np.bitwise_xor(s[a:a + block], sign, out=s[a:a + block])
    return u


def _delta_decode(z: np.ndarray, order: int, dtype: np.dtype) -> np.ndarray:
    """Inverse of :func:`_delta_encode`: unsigned (N, m) → numbers of ``dtype``."""
    mask = z & 1
    np.negative(mask, out=mask)                               # 0 or all ones (modulo 2^bits)
    u = z >> 1
    u ^= mask
    del mask
    for _ in range(order):
        np.cumsum(u, axis=0, dtype=u.dtype, out=u)          # integer sums wrap modulo 2^bits
    return u.view(dtype)


_TRANSPOSE_MAX_BYTES = 64 << 20
"""Arrays up to this size are packed from one epochs-last copy (see :func:`_compressed_planes`)."""
_BLOCK_BYTES = 4 << 20
"""Size of the temporaries of :func:`unpack` (columns decoded a block at a time)."""


def _compressed_planes(arr: np.ndarray, delta: int = 0, overwrite: bool = False) -> list[bytes]:
    """zstd frame of arr's bytes as (N, m) byte planes (see the module docstring).

    Up to :data:`_TRANSPOSE_MAX_BYTES`: one copy of arr with the epochs last (m, N), differenced
    there in place, whose byte planes are then contiguous slices (3–4× faster than gathering each
    plane across the epochs).  Larger arrays plane by plane, with no copy beyond the differences
    (none with ``overwrite``)."""
    n = arr.shape[0] if arr.ndim else 1
    cols = np.asarray(arr).reshape(n, int(np.prod(arr.shape[1:], dtype=np.int64)))
    size = arr.dtype.itemsize
    cobj = zstandard.ZstdCompressor(level=LEVEL).compressobj(size=cols.nbytes)
    if cols.nbytes <= _TRANSPOSE_MAX_BYTES:
        by_column = np.array(cols.T, order="C")          # a copy even when cols.T is contiguous (m = 1)
        if delta:
            _delta_encode(by_column.T, delta, overwrite=True)
        octets = by_column.view(np.uint8).reshape(by_column.shape + (size,))
        parts = [cobj.compress(np.ascontiguousarray(octets[:, :, b])) for b in range(size)]
    else:
        cols = np.ascontiguousarray(cols)
        if delta:                       # in place on the caller's temporary, or on a copy made here
            mine = overwrite or not np.shares_memory(cols, arr)
            cols = _delta_encode(cols, delta, overwrite=mine and cols.flags.writeable)
        octets = cols.view(np.uint8).reshape(n, cols.shape[1], size)
        parts = [cobj.compress(np.ascontiguousarray(octets[:, :, b].T)) for b in range(size)]
    parts.append(cobj.flush())
    return parts


def pack(arr: np.ndarray, delta: int = 0) -> bytes:
    """The packed bytes of ``arr`` (see the module docstring); ``b"".join(pack_pieces(arr, delta))``."""
    return b"".join(pack_pieces(arr, delta))


def pack_pieces(arr: np.ndarray, delta: int = 0, overwrite: bool = False) -> list[bytes]:
    """The packed bytes of ``arr`` (see the module docstring) in pieces, to be written in order.

    Parameters
    ----------
    arr : ndarray
        Numeric (bool, integer or floating) array of any shape; its dtype is stored in
        little-endian form.
    delta : {0, 1, 2}
        Order of the differences along the first axis taken before the shuffle (integers and
        floats only; see the module docstring).
    overwrite : bool
        With ``delta``: ``arr`` is a temporary of the caller's that may be overwritten (then arrays
        over :data:`_TRANSPOSE_MAX_BYTES` are packed without a copy; smaller ones always from one).

    Returns
    -------
    list of bytes
    """
    arr = np.asarray(arr)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"packed arrays hold bool, integer or float numbers, not dtype {arr.dtype}")
    if delta not in DELTA_ORDERS or (delta and arr.dtype.kind == "b"):
        raise ValueError(f"delta {delta!r}: expected one of {DELTA_ORDERS} (0 for bool arrays)")
    arr = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    return [packed_header(arr.dtype, arr.shape, delta), *_compressed_planes(arr, delta, overwrite)]


def packed_header(dtype, shape, delta: int = 0) -> bytes:
    """The bytes before the zstd frame of a packed array of ``dtype`` (little-endian) and ``shape``."""
    head = {"dtype": np.dtype(dtype).newbyteorder("<").str, "filter": FILTER, "shape": [int(n) for n in shape],
            **({"delta": delta} if delta else {})}
    header = json.dumps(head, sort_keys=True).encode()
    return MAGIC + _HEAD.pack(len(header)) + header


def pack_planes(dtype, n: int, planes, write) -> None:
    """Write the packed bytes of a 1-D array of ``n`` numbers of ``dtype`` (no delta) given as its
    byte planes: ``planes`` yields, in order, the bytes of plane 0 (every number's first byte), then
    plane 1, … in pieces of any size; ``write`` takes the packed bytes as they come.  The bytes are
    :func:`pack`'s for the same array (zstd's output does not depend on how its input is cut), so a
    column far larger than memory is packed from the disk (``cdgps ingest``)."""
    dtype = np.dtype(dtype).newbyteorder("<")
    write(packed_header(dtype, (n,)))
    cobj = zstandard.ZstdCompressor(level=LEVEL).compressobj(size=n * dtype.itemsize)
    for piece in planes:
        out = cobj.compress(piece)
        if out:
            write(out)
    write(cobj.flush())


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
    dtype, shape, delta = _parse_header(bytes(data[12:12 + n_head]), what)
    size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    try:
        raw = zstandard.ZstdDecompressor().decompress(data[12 + n_head:], max_output_size=max(size, 1))
    except zstandard.ZstdError as exc:
        raise ValueError(f"{what}: damaged content ({exc})") from None
    if len(raw) != size:
        raise ValueError(f"{what}: {len(raw)} bytes of content for shape {list(shape)} of {dtype.str}")
    n = shape[0] if shape else 1
    m = int(np.prod(shape[1:], dtype=np.int64))
    cols = _from_planes(np.frombuffer(raw, dtype=np.uint8).reshape(dtype.itemsize, m, n))
    if delta:
        return _delta_decode(cols, delta, dtype).reshape(shape)
    return cols.view(dtype).reshape(shape)


def _from_planes(planes: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_byte_planes`: (size, m, N) byte planes → (N, m) unsigned integers of
    ``size`` bytes; a block of columns at a time (each interleaved contiguously, then transposed)."""
    size, m, n = planes.shape
    out = np.empty((n, m), dtype=_unsigned(size))
    step = max(_BLOCK_BYTES // max(n * size, 1), 1)
    for c in range(0, m, step):
        block = np.empty((min(step, m - c), n, size), dtype=np.uint8)
        for b in range(size):
            block[:, :, b] = planes[b, c:c + step]
        out[:, c:c + step] = block.view(out.dtype).reshape(block.shape[:2]).T
    return out


def _parse_header(head_bytes: bytes, what: str) -> tuple[np.dtype, tuple, int]:
    """dtype, shape and delta order of a packed array's JSON header (ValueError when damaged)."""
    try:
        head = json.loads(head_bytes)
        dtype = np.dtype(head["dtype"])
        shape = tuple(int(s) for s in head["shape"])
        filt = head["filter"]
        delta = head.get("delta", 0)
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{what}: damaged header ({exc})") from None
    if (filt != FILTER or dtype.kind not in "biuf" or any(s < 0 for s in shape) or delta not in DELTA_ORDERS
            or (delta and dtype.kind == "b")):
        raise ValueError(f"{what}: unsupported header {head}")
    return dtype, shape, delta


class PackedRows:
    """A packed array read back in consecutive blocks of rows (epochs), in bounded memory.

    The packed bytes hold the array's byte planes (plane, column, epoch), so no row can be decoded
    before the whole zstd frame is: the frame is decompressed once, in pieces, into an unlinked
    temporary file, and :meth:`chunks` then reads each block of rows from its ``size × m`` runs there
    and undoes the differences with the running sums carried from the block before (integer sums
    modulo 2^bits: the same bits as :func:`unpack`).  Memory: one block of rows and the
    decompressor's window, whatever the array's length.

    Parameters
    ----------
    read : callable (n) -> bytes
        Reads the next ``n`` bytes of the packed data (e.g. an attachment's span of an open file).
    length : int
        Bytes of packed data.
    what : str
        Named in error messages.
    """

    _PIECE = 1 << 20
    #: reads of the scratch file of at least this many bytes are dropped from the page cache after
    _DROP_READ = 1 << 16

    def __init__(self, read, length: int, what: str = "packed array"):
        import tempfile

        self.what = what
        first = read(min(length, 12))
        if len(first) < 12 or first[:8] != MAGIC:
            raise ValueError(f"{what}: not a packed array (no {MAGIC.decode()} magic)")
        (n_head,) = _HEAD.unpack(first[8:12])
        if n_head > _MAX_HEADER or 12 + n_head > length:
            raise ValueError(f"{what}: header length {n_head} is out of range")
        self.dtype, self.shape, self.delta = _parse_header(read(n_head), what)
        self.n_rows = self.shape[0] if self.shape else 1
        self.m = int(np.prod(self.shape[1:], dtype=np.int64))
        size = self.n_rows * self.m * self.dtype.itemsize
        self._file = tempfile.TemporaryFile()
        try:
            self._decompress(read, length - 12 - n_head, size)
        except (zstandard.ZstdError, ValueError) as exc:
            self.close()
            raise ValueError(f"{what}: damaged content ({exc})") from None
        self._file.flush()

    def _decompress(self, read, left: int, size: int) -> None:
        """The zstd frame (``left`` bytes from ``read``) into the temporary file, a piece at a time
        (compressed and decompressed pieces both bounded: a highly compressed array cannot expand
        into memory at once)."""
        class _Span:
            def read(self, n=-1):
                nonlocal left
                data = read(left if n is None or n < 0 else min(n, left))
                left -= len(data)
                return data

        from cdgps_cli.io.scratch import DropBehind  # noqa: PLC0415

        out = 0
        behind = DropBehind(self._file)            # (out of the page cache as written: see chunks)
        with zstandard.ZstdDecompressor().stream_reader(_Span(), read_size=self._PIECE, closefd=False) as z:
            while True:
                raw = z.read(self._PIECE)
                if not raw:
                    break
                out += len(raw)
                if out > size:
                    break
                self._file.write(raw)
                behind.wrote(len(raw))
        behind.close()
        self._behind = behind                      # (its bytes count in the scratch budget until close)
        if out != size or left:
            raise ValueError(f"{out if out <= size else 'more'} bytes of content for shape {list(self.shape)} "
                             f"of {self.dtype.str}")

    def close(self) -> None:
        self._file.close()
        self._behind = None

    def chunks(self, rows: int):
        """Blocks of up to ``rows`` consecutive rows, first to last: arrays (k, *shape[1:]) of the dtype.

        Each call starts again from the first row (several passes over the same array)."""
        if rows < 1:
            raise ValueError(f"rows {rows!r}: expected a positive number of rows per block")
        from cdgps_cli.io.scratch import forget_cached  # noqa: PLC0415

        size, n, m = self.dtype.itemsize, self.n_rows, self.m
        carry = [np.zeros(m, dtype=_unsigned(size)) for _ in range(self.delta)]
        fd = self._file.fileno()
        for a in range(0, n, rows):
            k = min(rows, n - a)
            block = np.empty((k, m, size), dtype=np.uint8)
            for b in range(size):
                for c in range(m):
                    block[:, c, b] = np.frombuffer(os.pread(fd, k, (b * m + c) * n + a), dtype=np.uint8)
                    if k >= self._DROP_READ:        # (read from the disk: not kept in the page cache either)
                        forget_cached(fd, (b * m + c) * n + a, k)
            u = block.view(_unsigned(size)).reshape(k, m)
            if self.delta:
                u = self._undo_delta(u, carry)
            yield u.view(self.dtype).reshape((k,) + self.shape[1:])

    def _undo_delta(self, z: np.ndarray, carry: list) -> np.ndarray:
        """:func:`_delta_decode` of one block, continuing the running sums of the blocks before."""
        mask = z & 1
        np.negative(mask, out=mask)
        u = z >> 1
        u ^= mask
        for level in range(self.delta):
            np.cumsum(u, axis=0, dtype=u.dtype, out=u)
            u += carry[level]                                  # modulo 2^bits, as the whole-array sums
            carry[level] = u[-1].copy()
        return u


class PackedWriter:
    """A packed array written from consecutive blocks of rows, in bounded memory: the same bytes as
    :func:`pack` of the whole array (issue 29: ``cdgps estimate`` writes STATES from a history on disk).

    The byte planes of :func:`pack` run over every epoch, so nothing can be compressed before the last
    row is given: :meth:`add` differences each block (carrying the previous rows of each order) and
    writes its bytes to their places in an unlinked temporary file laid out as the planes
    (plane, column, epoch); :meth:`finish` then compresses that file a piece at a time into a second
    one and gives the packed bytes' length and their pieces.  zstd's output does not depend on how
    its input is cut, so the bytes are those of :func:`pack` (``tests/io/test_packed_stream.py``).
    Memory: one block of rows and a piece of the file, whatever the array's length.

    Parameters
    ----------
    shape : tuple of int
        The whole array's shape (first axis: rows, e.g. epochs).
    dtype : numpy dtype
        Its numeric dtype (stored little-endian).
    delta : {0, 1, 2}
        As :func:`pack_pieces`.
    dir : path, optional
        Where the temporary files go (default: the system's temporary directory).
    """

    _PIECE = 1 << 20
    #: bytes of rows written between two page-cache drops of the plane file (:meth:`_drop_written`)
    _DROP_BYTES = 16 << 20

    def __init__(self, shape: tuple, dtype, delta: int = 0, dir=None):
        import tempfile

        self.dtype = np.dtype(dtype).newbyteorder("<")
        if self.dtype.kind not in "biuf":
            raise ValueError(f"packed arrays hold bool, integer or float numbers, not dtype {self.dtype}")
        if delta not in DELTA_ORDERS or (delta and self.dtype.kind == "b"):
            raise ValueError(f"delta {delta!r}: expected one of {DELTA_ORDERS} (0 for bool arrays)")
        self.shape, self.delta = tuple(int(s) for s in shape), delta
        if not self.shape:
            raise ValueError("PackedWriter: a 0-d array is packed whole (pack)")
        self.n = self.shape[0]
        self.m = int(np.prod(self.shape[1:], dtype=np.int64))
        self.done = 0
        self._carry: list = [None] * delta          # per order: the last row of that order's input
        self._file = tempfile.TemporaryFile(prefix=".cdgps-pack-", dir=dir)
        self._dropped, self._behind = 0, None       # rows out of the page cache (_drop_written)

    def add(self, rows: np.ndarray) -> None:
        """The next block of rows, (k, *shape[1:]) (converted to the dtype as :func:`pack` does)."""
        rows = np.asarray(rows)
        k = rows.shape[0] if rows.ndim else 0
        if rows.shape[1:] != self.shape[1:] or self.done + k > self.n:
            raise ValueError(f"rows of shape {list(rows.shape)} after {self.done} of {self.n} rows of shape "
                             f"{list(self.shape)}")
        if k == 0:
            return
        size = self.dtype.itemsize
        u = np.ascontiguousarray(rows.astype(self.dtype, copy=False).reshape(k, self.m)).view(_unsigned(size))
        if self.delta:
            u = self._differences(u)
        octets = u.view(np.uint8).reshape(k, self.m, size)
        fd, a = self._file.fileno(), self.done
        for b in range(size):
            plane = np.ascontiguousarray(octets[:, :, b].T)          # (m, k)
            for c in range(self.m):
                os.pwrite(fd, plane[c].tobytes(), (b * self.m + c) * self.n + a)
        self.done += k
        if (self.done - self._dropped) * self.m * size >= self._DROP_BYTES:
            self._drop_written()

    def _drop_written(self) -> None:
        """Take the rows written since the last call out of the page cache, in every (plane, column)
        run of the file (the pages wholly inside them; :func:`cdgps_cli.io.scratch.drop_cached`): the
        file is as large as the array (≈ 620 MB for a day's STATES of the testbed) and is read only
        by :meth:`finish`."""
        from cdgps_cli.io.scratch import Behind  # noqa: PLC0415

        if self._behind is None:
            self._behind = Behind(self._file.fileno())
        a, k = self._dropped, self.done - self._dropped
        self._behind.push([(j * self.n + a, k) for j in range(self.m * self.dtype.itemsize)],
                          fresh=k * self.m * self.dtype.itemsize)
        self._dropped = self.done

    def _differences(self, u: np.ndarray, block: int = 256) -> np.ndarray:
        """:func:`_delta_encode` of one block on one copy of it, continuing from the rows before it
        (the last row of each order's input is carried to the next block)."""
        d = u.copy()
        k = d.shape[0]
        for level in range(self.delta):
            last = d[-1].copy()
            for end in range(k, 1, -block):                           # from the end: rows still undifferenced
                start = max(end - block, 1)
                np.subtract(d[start:end], d[start - 1:end - 1], out=d[start:end])     # modulo 2^bits
            if self._carry[level] is not None:
                d[0] -= self._carry[level]
            self._carry[level] = last
        return _zigzag_in_place(d, block)

    def finish(self) -> tuple[int, object]:
        """``(length, pieces)``: the packed bytes' length and an iterator over them (header first).
        Every row must have been given.  The temporary files close when the pieces are consumed."""
        import tempfile

        if self.done != self.n:
            raise ValueError(f"PackedWriter: {self.done} of {self.n} rows given")
        head = {"dtype": self.dtype.str, "filter": FILTER, "shape": list(self.shape),
                **({"delta": self.delta} if self.delta else {})}
        header = json.dumps(head, sort_keys=True).encode()
        first = MAGIC + _HEAD.pack(len(header)) + header
        raw_size = self.n * self.m * self.dtype.itemsize
        from cdgps_cli.io.scratch import DropBehind, forget_cached  # noqa: PLC0415

        packed = tempfile.TemporaryFile(prefix=".cdgps-pack-", dir=None)
        behind = DropBehind(packed)                 # (both scratch files kept out of the page cache)
        cobj = zstandard.ZstdCompressor(level=LEVEL).compressobj(size=raw_size)
        fd = self._file.fileno()
        for at in range(0, raw_size, self._PIECE):
            piece = os.pread(fd, min(self._PIECE, raw_size - at), at)
            forget_cached(fd, at, len(piece))
            out = cobj.compress(piece)
            packed.write(out)
            behind.wrote(len(out))
        out = cobj.flush()
        packed.write(out)
        behind.wrote(len(out))
        behind.close()
        self._file.close()
        self._behind = None
        length = len(first) + packed.tell()
        packed.seek(0)

        def pieces(_behind=behind):                # (the packed file's bytes count until it is closed)
            try:
                yield first
                at = 0
                while True:
                    piece = packed.read(self._PIECE)
                    if not piece:
                        return
                    forget_cached(packed.fileno(), at, len(piece))
                    at += len(piece)
                    yield piece
            finally:
                packed.close()

        return length, pieces()

    def close(self) -> None:
        self._file.close()
        self._behind = None
