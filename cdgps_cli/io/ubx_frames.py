"""Framing of a receiver's byte stream: u-blox UBX frames, NMEA 0183 sentences, RTCM 3 frames.

A u-blox log recorded from the receiver's port mixes the three protocols, and a serial link or a
bad card adds corrupt bytes.  :func:`split_stream` walks the stream once, at each position taking
the earliest candidate start of any of them and accepting it only when its own check passes:

* UBX: sync ``0xB5 0x62``, class, id, 16-bit little-endian length, payload, 8-bit Fletcher
  checksum over class … payload (u-blox interface description, "UBX checksum");
* NMEA: ``$`` talker+sentence ``,`` … ``*hh`` CR LF, XOR checksum of the characters between ``$``
  and ``*``, at most :data:`NMEA_MAX_CHARS` characters (NMEA 0183 says 82, but u-blox receivers in
  their high-precision NMEA mode write longer GGA sentences: 92 characters in a real all-band log);
* RTCM 3: preamble ``0xD3``, 6 reserved bits (zero), 10-bit length, payload whose first 12 bits
  are the message type, CRC-24Q over preamble … payload (RTCM 10403.x §4).

A candidate that fails its check costs one byte (two for a UBX sync) and the search resumes; the
bytes outside accepted frames are counted.  Every candidate's check is bounded (UBX checksums come
from prefix sums in O(1), an RTCM CRC covers at most 1 029 bytes, an NMEA sentence :data:`NMEA_MAX_CHARS`), so the
walk is linear in the stream's length whatever its content.

:func:`split_stream` computes that walk with numpy (every UBX checksum and NMEA sentence at once,
the chain of accepted frames by pointer doubling, RTCM CRCs only where the walk meets them);
``_split_stream_walk`` is the walk itself in Python, the reference the tests compare it with.  Where
the optional C extension ``cdgps_cli.io._ubxcore`` is built (``setup.py``, as the estimation kernels),
:func:`split_stream` runs that same walk compiled, in one linear pass (about 10× faster than numpy on
the walk log); the numpy path stays the fallback, and the tests check all three give the same result.
"""

from __future__ import annotations

import re

import numpy as np

try:  # the optional compiled walk (setup.py builds it; absent, the numpy path below gives the same)
    from cdgps_cli.io import _ubxcore
except ImportError:  # pragma: no cover
    _ubxcore = None
#: False: :func:`split_stream` takes the numpy path even where the compiled walk is built (tests, benchmarks)
USE_COMPILED = True

__all__ = ["NMEA_MAX_CHARS", "RTCM_MAX_PAYLOAD", "crc24q", "split_stream", "split_stream_spans"]


UBX_SYNC = b"\xb5\x62"
RTCM_PREAMBLE = 0xD3
RTCM_MAX_PAYLOAD = 1023
MAX_OFFSETS_SHOWN = 5
#: longest NMEA sentence accepted, characters from ``$`` to LF: NMEA 0183's 82 leaves out the
#: high-precision GGA of u-blox receivers (92 in ../shared/data/real-pairs/ublox-walk); 128 bounds it
NMEA_MAX_CHARS = 128
_NMEA = re.compile(rb"\$[A-Z][A-Z0-9]{1,5},[\x20-\x7e]{0,%d}?\*([0-9A-Fa-f]{2})\r?\n" % (NMEA_MAX_CHARS - 13))


def _crc24q_table() -> list[int]:
    poly = 0x1864CFB
    table = []
    for i in range(256):
        c = i << 16
        for _ in range(8):
            c <<= 1
            if c & 0x1000000:
                c ^= poly
        table.append(c & 0xFFFFFF)
    return table


_CRC24Q = _crc24q_table()


def crc24q(data: bytes) -> int:
    """CRC-24Q (polynomial 0x1864CFB, initial value 0, no reflection) of ``data``, as RTCM 3 uses."""
    crc = 0
    table = _CRC24Q
    for b in data:
        crc = ((crc << 8) & 0xFFFFFF) ^ table[(crc >> 16) ^ b]
    return crc


class _Fletcher:
    """UBX 8-bit Fletcher checksums of any byte range of a stream, each in O(1).

    With prefix sums (mod 256) S_i = Σ_{j<i} x_j and T_i = Σ_{j<i} j·x_j, the checksum over bytes
    a..b−1 is CK_A = S_b − S_a and CK_B = Σ (b−j)·x_j = b·CK_A − (T_b − T_a) (mod 256), so a
    stream full of false sync words announcing long frames costs O(1) per candidate.
    """

    def __init__(self, data: bytes):
        x = np.frombuffer(data, dtype=np.uint8)
        idx = np.tile(np.arange(256, dtype=np.uint8), -(-x.size // 256))[:x.size]     # j mod 256
        self._s = b"\0" + np.cumsum(x, dtype=np.uint8).tobytes()          # bytes: fast int indexing
        self._t = b"\0" + np.cumsum(idx * x, dtype=np.uint8).tobytes()

    def __call__(self, a: int, b: int) -> bytes:
        """Checksum over ``data[a:b]`` (class, id, length and payload of a frame)."""
        ck_a = (self._s[b] - self._s[a]) & 0xFF
        ck_b = (b * ck_a - (self._t[b] - self._t[a])) & 0xFF
        return bytes((ck_a, ck_b))


def _nmea_at(data: bytes, k: int) -> int:
    """End of a complete NMEA sentence with a correct checksum starting at ``data[k]`` (0: none)."""
    m = _NMEA.match(data, k)
    if m is None:
        return 0
    x = 0
    for c in data[k + 1 : m.start(1) - 1]:
        x ^= c
    return m.end() if x == int(m.group(1), 16) else 0


def _rtcm_at(data: bytes, k: int) -> tuple[int, int, bool]:
    """An RTCM 3 frame at ``data[k]``: (end, message type, CRC correct); end 0 if not framed."""
    n = len(data)
    if k + 6 > n or data[k + 1] & 0xFC:
        return 0, 0, False
    length = ((data[k + 1] & 0x03) << 8) | data[k + 2]
    end = k + 6 + length
    if length < 2 or end > n:
        return 0, 0, False
    ok = crc24q(data[k : k + 3 + length]) == int.from_bytes(data[k + 3 + length : end], "big")
    mtype = (data[k + 3] << 4) | (data[k + 4] >> 4)
    return end, mtype, ok


class _Next:
    """Next occurrence of a marker at or after a position, cached (the stream is walked forward
    only, so all finds together read the stream about once per marker)."""

    def __init__(self, data: bytes, marker: bytes):
        self.data, self.marker, self.at = data, marker, -1

    def from_(self, pos: int) -> int:
        if self.at < pos and self.at != len(self.data) + 1:
            k = self.data.find(self.marker, pos)
            self.at = len(self.data) + 1 if k < 0 else k
        return self.at


def _split_stream_walk(data: bytes) -> tuple[list, list, dict]:
    """:func:`split_stream` as a walk over the stream in Python (the reference the vectorised one
    is tested against).

    Same parameters, returns and statistics as :func:`split_stream`.
    """
    n = len(data)
    stats = {"bad_checksum_frames": 0, "bad_frame_offsets": [], "truncated_tail_bytes": 0, "skipped_bytes": 0,
             "nmea_sentences": 0, "nmea_bytes": 0, "rtcm_frames": {}, "rtcm_bytes": 0, "bad_crc_rtcm_frames": 0,
             "bad_rtcm_offsets": []}
    ubx: list = []
    rtcm: list = []
    checksum = _Fletcher(data)
    next_ubx, next_nmea, next_rtcm = (_Next(data, UBX_SYNC).from_, _Next(data, b"$").from_,
                                      _Next(data, bytes((RTCM_PREAMBLE,))).from_)
    pos = 0   # first byte not yet accounted for
    scan = 0  # where the search for the next candidate resumes

    def accept(k: int, end: int) -> None:
        nonlocal pos, scan
        stats["skipped_bytes"] += k - pos
        pos = scan = end

    def bad(key: str, okey: str, k: int) -> None:
        stats[key] += 1
        if len(stats[okey]) < MAX_OFFSETS_SHOWN:
            stats[okey].append(k)

    while True:
        ku, kn, kr = next_ubx(scan), next_nmea(scan), next_rtcm(scan)
        k = min(ku, kn, kr)
        if k >= n:
            stats["skipped_bytes"] += n - pos
            break
        if k == ku:
            if k + 6 > n:
                stats["skipped_bytes"] += k - pos
                stats["truncated_tail_bytes"] = n - k
                break
            length = int.from_bytes(data[k + 4 : k + 6], "little")
            end = k + 8 + length
            if end > n:
                if data.find(UBX_SYNC, k + 2) < 0:
                    stats["skipped_bytes"] += k - pos
                    stats["truncated_tail_bytes"] = n - k
                    break
                bad("bad_checksum_frames", "bad_frame_offsets", k)
                scan = k + 2
            elif checksum(k + 2, k + 6 + length) != data[k + 6 + length : end]:
                bad("bad_checksum_frames", "bad_frame_offsets", k)
                scan = k + 2
            else:
                ubx.append((k, data[k + 2], data[k + 3], data[k:end]))
                accept(k, end)
        elif k == kn:
            end = _nmea_at(data, k)
            if end:
                stats["nmea_sentences"] += 1
                stats["nmea_bytes"] += end - k
                accept(k, end)
            else:
                scan = k + 1
        else:
            end, mtype, ok = _rtcm_at(data, k)
            if end and ok:
                stats["rtcm_frames"][mtype] = stats["rtcm_frames"].get(mtype, 0) + 1
                stats["rtcm_bytes"] += end - k
                rtcm.append((k, mtype, data[k:end]))
                accept(k, end)
            else:
                if end and not ok and _plausible_rtcm_type(mtype):
                    bad("bad_crc_rtcm_frames", "bad_rtcm_offsets", k)
                scan = k + 1
    stats["rtcm_frames"] = dict(sorted(stats["rtcm_frames"].items()))
    return ubx, rtcm, stats


def _new_stats() -> dict:
    return {"bad_checksum_frames": 0, "bad_frame_offsets": [], "truncated_tail_bytes": 0, "skipped_bytes": 0,
            "nmea_sentences": 0, "nmea_bytes": 0, "rtcm_frames": {}, "rtcm_bytes": 0, "bad_crc_rtcm_frames": 0,
            "bad_rtcm_offsets": []}


def _ubx_candidates(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every UBX sync word of the stream ``x`` (uint8), its frame's end and its status.

    Returns
    -------
    start, end : int64 arrays, shape (m,)
        Byte offset of each ``0xB5 0x62`` and of the byte after its checksum (as announced).
    status : int8 array, shape (m,)
        0: checksum correct; 1: checksum wrong, or the announced end runs past the stream while a
        later sync follows; 2: the stream ends inside the frame (a truncated tail: the walk stops).
    """
    n = x.size
    start = np.flatnonzero(x[:-1] == 0xB5)
    start = start[x[start + 1] == 0x62]
    status = np.full(start.size, 1, np.int8)
    end = np.full(start.size, n + 1, np.int64)
    head = start + 6 <= n
    status[~head] = 2
    k = start[head]
    end[head] = k + 8 + (x[k + 4].astype(np.int64) | (x[k + 5].astype(np.int64) << 8))
    over = head & (end > n)
    if start.size and over[-1]:
        status[-1] = 2                                     # no later sync: a truncated tail
    fit = np.flatnonzero(head & ~over)
    if fit.size:
        # uint32 sums wrap mod 2^32, a multiple of 256, and numpy sums uint32 ~10x faster than uint8
        s = np.empty(n + 1, np.uint32)                     # S_i = sum of x_j, j < i
        s[0] = 0
        s[1:] = x                                          # widen first: a cumsum that casts is slower
        np.cumsum(s, dtype=np.uint32, out=s)
        a, b = start[fit] + 2, end[fit] - 2                # checksum over class ... payload
        ck_a = (s[b] - s[a]) & 0xFF
        # CK_B = sum over i in [a, b) of (S_{i+1} - S_a) = sum of S[a+1 : b+1] - (b - a) S_a
        ck_b = (_segment_sums(s, a + 1, b + 1) - (b - a).astype(np.uint32) * s[a]) & 0xFF
        ok = (ck_a == x[b]) & (ck_b == x[b + 1])
        status[fit[ok]] = 0
    return start, end, status


MAX_LAYERS = 8
#: rounds of RTCM 3 checks in the gaps of the chain before :func:`split_stream` walks the stream instead
MAX_RTCM_ROUNDS = 8


def _segment_sums(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sums (uint32, wrapping) of ``v[lo:hi]`` for many segments, ``lo`` sorted, ``lo < hi <= v.size - 1``.

    Disjoint segments are summed together by one ``np.add.reduceat``; overlapping ones (a false sync
    word inside a frame announces a frame of its own) go to later layers of disjoint segments, and
    past :data:`MAX_LAYERS` layers to one prefix sum of ``v``.
    """
    out = np.zeros(lo.size, np.uint32)
    todo = np.arange(lo.size)
    for _ in range(MAX_LAYERS):
        if not todo.size:
            return out
        layer = todo[_chain(lo[todo], hi[todo], np.zeros(todo.size, bool))]
        idx = np.empty(2 * layer.size, np.int64)
        idx[0::2], idx[1::2] = lo[layer], hi[layer]
        out[layer] = np.add.reduceat(v, idx, dtype=np.uint32)[0::2]
        left = np.ones(todo.size, bool)
        left[np.searchsorted(todo, layer)] = False
        todo = todo[left]
    if todo.size:
        c = np.zeros(v.size + 1, np.uint32)
        np.cumsum(v, dtype=np.uint32, out=c[1:])
        out[todo] = c[hi[todo]] - c[lo[todo]]
    return out


_HEX = np.full(256, -1, np.int16)
for _i, _c in enumerate(b"0123456789"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEX[_c] = _HEX[_c - 32] = 10 + _i
_ALNUM = np.zeros(256, bool)
_ALNUM[np.frombuffer(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789", np.uint8)] = True


def _nmea_sentences(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end of every ``$`` of the stream that begins an NMEA sentence :data:`_NMEA`
    matches with a correct checksum (the test of :func:`_nmea_at`, for all of them at once).

    The sentence can only end at the first LF after its ``$`` (nothing before its end is an LF),
    so its checksum star sits 3 bytes before that LF, or 4 after a CR.
    """
    n = x.size
    k = np.flatnonzero(x == 0x24).astype(np.int64)
    k = k[k + 8 <= n]
    k = k[(x[k + 1] >= 0x41) & (x[k + 1] <= 0x5A)]
    win = np.zeros((k.size, 7), np.uint8)                 # bytes k+2 .. k+8: talker tail and comma
    for j in range(7):
        win[:, j] = x[np.minimum(k + 2 + j, n - 1)]
    talk = np.argmin(_ALNUM[win], axis=1)                  # first byte not in [A-Z0-9]
    keep = (talk >= 1) & (talk <= 5) & (win[np.arange(k.size), talk] == 0x2C)
    k, comma = k[keep], k[keep] + 2 + talk[keep]
    lf = np.flatnonzero(x == 0x0A)
    i = np.searchsorted(lf, comma + 1)
    has = i < lf.size
    k, comma, e = k[has], comma[has], lf[i[has]]
    star = e - 3 - (x[e - 1] == 0x0D)
    keep = (star >= comma + 1) & (star - comma - 1 <= NMEA_MAX_CHARS - 13)
    k, star, e = k[keep], star[keep], e[keep]
    keep = (x[star] == 0x2A) & (_HEX[x[star + 1]] >= 0) & (_HEX[x[star + 2]] >= 0)
    k, star, e = k[keep], star[keep], e[keep]
    if not k.size:
        return k, k
    lens = star - k - 1                                    # bytes between $ and * (>= 3)
    first = np.concatenate(([0], np.cumsum(lens)[:-1]))
    idx = np.repeat(k + 1 - first, lens) + np.arange(int(lens.sum()))
    body = x[idx]
    printable = np.logical_and.reduceat((body >= 0x20) & (body <= 0x7E), first)
    check = np.bitwise_xor.reduceat(body, first)
    ok = printable & (check == _HEX[x[star + 1]] * 16 + _HEX[x[star + 2]])
    return k[ok], e[ok] + 1


def _chain(start: np.ndarray, end: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """Indices of the items the walk accepts: the first item, then each time the first item
    starting at or after the previous one's end, up to a stopping item (``start`` sorted).

    Pointer doubling: after step j the marked set holds the first 2^(j+1) items of the walk.
    """
    m = start.size
    if not m:
        return np.zeros(0, np.int64)
    succ = np.append(np.searchsorted(start, end), m)       # m: none
    succ[:m][stop] = m
    marked = np.zeros(m + 1, bool)
    marked[0] = True
    for _ in range(int(m).bit_length() + 1):
        marked[succ[np.flatnonzero(marked)]] = True
        succ = succ[succ]
    return np.flatnonzero(marked[:m])


def _inside(q: np.ndarray, a: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Whether each position ``q`` lies inside one of the disjoint spans [a, e) (a sorted)."""
    if not a.size:
        return np.zeros(q.size, bool)
    j = np.searchsorted(a, q, side="right") - 1
    return (j >= 0) & (q < e[np.maximum(j, 0)])


def split_stream(data: bytes) -> tuple[list, list, dict]:
    """Split a receiver's byte stream into UBX frames, RTCM 3 frames and NMEA sentences (the compiled walk
    where it is built, else :func:`_split_stream_numpy`; same parameters and returns)."""
    if _ubxcore is not None and USE_COMPILED and getattr(_ubxcore, "API", None) == 1:
        return _split_stream_compiled(data)
    return _split_stream_numpy(data)


def split_stream_spans(data: bytes) -> tuple[np.ndarray, np.ndarray, list, dict]:
    """:func:`split_stream` with the UBX frames as spans: (start, end) int64 arrays of the checksum-valid UBX
    frames ``data[start:end]`` (from the compiled walk where built, without making a Python object per frame),
    the RTCM 3 frames and the counters as :func:`split_stream` gives them."""
    if _ubxcore is not None and USE_COMPILED and getattr(_ubxcore, "API", None) == 1:
        spans, rtcm, stats = _walk_compiled(data)
        return spans[:, 0].copy(), spans[:, 1].copy(), rtcm, stats
    ubx, rtcm, stats = _split_stream_numpy(data)
    start = np.fromiter((f[0] for f in ubx), np.int64, len(ubx))
    return start, start + np.fromiter((len(f[3]) for f in ubx), np.int64, len(ubx)), rtcm, stats


def _split_stream_compiled(data: bytes) -> tuple[list, list, dict]:
    """:func:`split_stream` by the compiled walk of ``cdgps_cli.io._ubxcore`` (the Python walk in C)."""
    spans, rtcm, stats = _walk_compiled(data)
    return [(k, data[k + 2], data[k + 3], data[k:j]) for k, j in spans.tolist()], rtcm, stats


def _walk_compiled(data: bytes) -> tuple[np.ndarray, list, dict]:
    """The compiled walk: (UBX frame spans, shape (m, 2) int64; RTCM 3 frames; counters)."""
    ubx, rtcm, counts, bad_u, bad_r = _ubxcore.walk(data)
    stats = _new_stats()
    for key, v in zip(("bad_checksum_frames", "truncated_tail_bytes", "skipped_bytes", "nmea_sentences", "nmea_bytes",
                       "rtcm_bytes", "bad_crc_rtcm_frames"), counts):
        stats[key] = v
    stats["bad_frame_offsets"], stats["bad_rtcm_offsets"] = bad_u, bad_r
    spans = np.frombuffer(ubx, np.int64).reshape(-1, 2)
    r = np.frombuffer(rtcm, np.int64).reshape(-1, 3).tolist()
    types: dict = {}
    for _, _, t in r:
        types[t] = types.get(t, 0) + 1
    stats["rtcm_frames"] = dict(sorted(types.items()))
    return spans, [(k, t, data[k:j]) for k, j, t in r], stats


def _split_stream_numpy(data: bytes) -> tuple[list, list, dict]:
    """Split a receiver's byte stream into UBX frames, RTCM 3 frames and NMEA sentences, with numpy.

    The walk described in the module docstring, computed with numpy: every UBX candidate's
    checksum at once (prefix sums), every NMEA candidate's sentence at once, then the chain of
    accepted frames by pointer doubling.  RTCM 3 candidates (a CRC-24Q each) are tested only where
    the walk would meet them (outside accepted frames), repeating the chain until none is left
    untested; the result is the walk's, frame for frame and count for count.

    Parameters
    ----------
    data : bytes
        The whole log.

    Returns
    -------
    ubx : list of (offset, class, id, frame bytes)
        Checksum-valid UBX frames (frame bytes from the sync word to the checksum).
    rtcm : list of (offset, message type, frame bytes)
        CRC-valid RTCM 3 frames (preamble to CRC).
    stats : dict
        ``bad_checksum_frames`` and ``bad_frame_offsets`` (first few): UBX candidates failing the
        checksum, or whose announced length runs past the end while a later sync follows;
        ``truncated_tail_bytes`` (a UBX frame cut by the end of the stream); ``bad_crc_rtcm_frames``
        and ``bad_rtcm_offsets``: RTCM 3 frames failing CRC-24Q; ``nmea_sentences``, ``nmea_bytes``
        (complete sentences, checksums correct); ``rtcm_frames`` (dict message type -> count) and
        ``rtcm_bytes``; ``skipped_bytes``: every other byte outside accepted frames (noise, corrupt
        frames, sentences with a wrong checksum).
    """
    x = np.frombuffer(data, np.uint8)
    n = x.size
    u_start, u_end, u_status = _ubx_candidates(x)
    n_start, n_end = _nmea_sentences(x)
    r_cand = np.flatnonzero(x == RTCM_PREAMBLE).astype(np.int64)
    r_tested = np.zeros(r_cand.size, bool)
    r_end = np.zeros(r_cand.size, np.int64)
    r_type = np.zeros(r_cand.size, np.int64)
    r_ok = np.zeros(r_cand.size, bool)
    u_item = u_status != 1
    for _ in range(MAX_RTCM_ROUNDS):
        kind = np.concatenate((np.zeros(int(u_item.sum()), np.int8), np.ones(n_start.size, np.int8),
                               np.full(int(r_ok.sum()), 2, np.int8)))
        start = np.concatenate((u_start[u_item], n_start, r_cand[r_ok]))
        end = np.concatenate((u_end[u_item], n_end, r_end[r_ok]))
        stop = np.concatenate((u_status[u_item] == 2, np.zeros(n_start.size + int(r_ok.sum()), bool)))
        order = np.argsort(start, kind="stable")
        kind, start, end, stop = kind[order], start[order], end[order], stop[order]
        acc = _chain(start, end, stop)
        last_stop = acc.size and stop[acc[-1]]
        limit = start[acc[-1]] if last_stop else n
        frames = acc[:-1] if last_stop else acc
        a, e = start[frames], end[frames]
        gap = ~r_tested & (r_cand < limit) & ~_inside(r_cand, a, e)
        if not gap.any():
            break
        for i in np.flatnonzero(gap).tolist():
            r_end[i], r_type[i], r_ok[i] = _rtcm_at(data, int(r_cand[i]))
            r_ok[i] = bool(r_ok[i] and r_end[i])
            r_tested[i] = True
    else:                  # RTCM frames found in gaps keep moving the chain (contrived input): walk
        return _split_stream_walk(data)
    return _collect(data, kind[frames], a, e, limit, n, u_start, u_status, r_cand, r_tested, r_end, r_type, r_ok)


def _collect(data, kind, a, e, limit, n, u_start, u_status, r_cand, r_tested, r_end, r_type, r_ok):
    """The lists and counters of :func:`split_stream` from the accepted spans ``[a, e)`` of each
    ``kind`` (0 UBX, 1 NMEA, 2 RTCM) and the place ``limit`` where the walk stopped."""
    stats = _new_stats()
    ub = (kind == 0)
    ubx = [(k, data[k + 2], data[k + 3], data[k:j]) for k, j in zip(a[ub].tolist(), e[ub].tolist())]
    nm = kind == 1
    stats["nmea_sentences"] = int(nm.sum())
    stats["nmea_bytes"] = int((e[nm] - a[nm]).sum())
    rt = kind == 2
    rtcm = []
    types: dict = {}
    for k, j in zip(a[rt].tolist(), e[rt].tolist()):
        t = int(r_type[np.searchsorted(r_cand, k)])
        rtcm.append((k, t, data[k:j]))
        types[t] = types.get(t, 0) + 1
    stats["rtcm_frames"] = dict(sorted(types.items()))
    stats["rtcm_bytes"] = int((e[rt] - a[rt]).sum())
    stats["skipped_bytes"] = int(limit - (e - a).sum())
    if limit < n:
        stats["truncated_tail_bytes"] = int(n - limit)
    bad = u_start[(u_status == 1) & (u_start < limit) & ~_inside(u_start, a, e)]
    stats["bad_checksum_frames"] = int(bad.size)
    stats["bad_frame_offsets"] = bad[:MAX_OFFSETS_SHOWN].tolist()
    plaus = ((r_type >= 1001) & (r_type <= 1300)) | ((r_type >= 4001) & (r_type <= 4095))
    badr = r_cand[r_tested & ~r_ok & (r_end > 0) & plaus & (r_cand < limit) & ~_inside(r_cand, a, e)]
    stats["bad_crc_rtcm_frames"] = int(badr.size)
    stats["bad_rtcm_offsets"] = badr[:MAX_OFFSETS_SHOWN].tolist()
    return ubx, rtcm, stats


def _plausible_rtcm_type(mtype: int) -> bool:
    """Message numbers RTCM 10403 assigns (1001–1300) or leaves to vendors (4001–4095): a framed
    candidate with such a type failing its CRC is counted as a corrupt RTCM frame; any other
    failing candidate is noise (a random 0xD3 byte)."""
    return 1001 <= mtype <= 1300 or 4001 <= mtype <= 4095


def _bits(frame: bytes, start: int, n: int, signed: bool = False) -> int:
    """Bits ``start`` … ``start+n−1`` (MSB first, 0 = first payload bit) of an RTCM 3 frame's payload."""
    payload = frame[3:-3]
    v = int.from_bytes(payload, "big") >> (8 * len(payload) - start - n)
    v &= (1 << n) - 1
    return v - (1 << n) if signed and v >> (n - 1) else v


def rtcm_station_arp(rtcm: list) -> dict | None:
    """The reference station's antenna reference point from RTCM 3 messages 1005/1006.

    Parameters
    ----------
    rtcm : list of (offset, message type, frame bytes)
        CRC-valid RTCM 3 frames (:func:`split_stream`).

    Returns
    -------
    dict or None
        From the last 1005/1006 message: ``message`` (1005 or 1006), ``station_id``,
        ``arp_ecef_m`` ([x, y, z]: DF025–DF027, 38-bit signed, 0.0001 m), ``antenna_height_m``
        (DF028, 1006 only, else None), ``count`` (1005/1006 messages in the log) and ``distinct``
        (distinct positions among them); None when the log has neither message.
    """
    found = [(t, f) for _, t, f in rtcm if t in (1005, 1006) and len(f) - 6 >= (21 if t == 1006 else 19)]
    if not found:
        return None
    positions = set()
    for t, f in found:
        positions.add(tuple(_bits(f, s, 38, True) for s in (34, 74, 114)))
    t, f = found[-1]
    xyz = [_bits(f, s, 38, True) * 1e-4 for s in (34, 74, 114)]
    return {"message": int(t), "station_id": _bits(f, 12, 12), "arp_ecef_m": xyz,
            "antenna_height_m": _bits(f, 152, 16) * 1e-4 if t == 1006 else None,
            "count": len(found), "distinct": len(positions)}
