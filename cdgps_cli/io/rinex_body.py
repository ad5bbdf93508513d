"""Byte-level, block-wise reading of a RINEX observation body (the fast path of ``read_rinex_obs``).

The body is never split into Python strings: its line starts are found once in the (decompressed)
bytes, the epoch lines are walked (RINEX 3: vectorised; RINEX 2: one Python step per epoch) and the
satellite records are converted block by block of epochs with :mod:`cdgps_cli.io._fixed_width`, so
the memory beyond the file's bytes is a few bytes per line plus one block's fields.

Anything this reader does not take exactly as the line-by-line reader of :mod:`cdgps_cli.io.rinex`
does (a blank or malformed line, an event record of flags 2–5, an exponent, epochs out of order, a
truncated file, ...) raises :class:`~cdgps_cli.io._fixed_width.Unsupported`: the caller then reads
the file line by line, which gives the same table or the error naming the line.
"""

from __future__ import annotations

import datetime as _dt
import math
import re

import numpy as np

from cdgps_cli.core.gps_time import SECOND_MAX
from cdgps_cli.io._fixed_width import Unsupported, decimal_fields, windows

__all__ = ["BodyLines", "epochs_v3", "epochs_v2", "record_sats", "distinct", "gps_fields_of", "strict_float"]

_GPS_EPOCH_ORDINAL = _dt.date(1980, 1, 6).toordinal()
_POW10 = 10 ** np.arange(8, dtype=np.int64)
_INT = re.compile(rb" *[0-9]+ *")


def strict_float(s) -> float:
    """``float(s)`` of a finite decimal number (str or bytes); ValueError for anything else
    (``nan``, ``inf``, ``1_0``: tokens Python's ``float`` takes but RINEX does not write)."""
    v = float(s)
    if not math.isfinite(v) or (b"_" in s if isinstance(s, bytes) else "_" in s):
        raise ValueError(s)
    return v


class BodyLines:
    """The lines of a RINEX body inside the file's bytes: start and length (CR before LF dropped).

    Parameters
    ----------
    data : bytes
        The whole (decompressed) file.
    offset : int
        Byte offset of the body's first line.
    """

    def __init__(self, data: bytes, offset: int):
        raw = np.frombuffer(data, dtype=np.uint8)
        if raw.size - offset <= FEW_BYTES:
            self.start, self.length = _few_line_bounds(data, offset)
            self.data, self.buf, self.n = data, raw, self.start.size
            return
        lf = np.flatnonzero(raw[offset:] == 10)
        lf += offset
        n = lf.size + (lf.size == 0 or lf[-1] + 1 < raw.size)      # text ending in LF: no line after it
        self.start = np.empty(n, dtype=np.int64)
        self.start[0] = offset
        self.start[1:] = lf[:n - 1] + 1
        end = np.empty(n, dtype=np.int64)
        end[:lf.size] = lf[:n]
        end[lf.size:] = raw.size
        if offset >= raw.size:
            n = 0
            self.start, end = self.start[:0], end[:0]
        self.length = end - self.start
        self.length -= (self.length > 0) & (raw[np.maximum(end - 1, 0)] == 13)
        self.data = data
        self.buf = raw
        self.n = n

    def gather(self, line: np.ndarray, col: int, width: int) -> np.ndarray:
        """Bytes ``[col, col + width)`` of lines ``line`` as (n, width) uint8, blanks past a line's end;
        ``col``: one column, or one per line (n,)."""
        size = self.buf.size
        if size < width:
            raise Unsupported("short file")
        if line.size <= FEW_FIELDS:
            return self._gather_few(line, col, width)
        first = self.start[line] + col
        out = windows(self.buf, width)[np.minimum(first, size - width)]
        room = self.length[line] - col                    # characters of the field on its line
        short = np.flatnonzero(room < width)
        if short.size:
            keep = np.arange(width)[None, :] < room[short, None]
            at = np.minimum(first[short, None] + np.arange(width)[None, :], size - 1)
            out[short] = np.where(keep, self.buf[at], np.uint8(32))
        return out

    def _gather_few(self, line: np.ndarray, col, width: int) -> np.ndarray:
        """:meth:`gather` of a few fields, sliced from the bytes one by one (numpy's per-call set-up
        costs more): each field is the line's bytes from ``col`` up to its end, at most ``width``
        (none when the line ends before ``col``), padded with blanks."""
        start = self.start[line]
        first = start + col
        stop = np.minimum(start + self.length[line], first + width)
        data = self.data
        fields = [data[a:b].ljust(width) for a, b in zip(first.tolist(), stop.tolist())]
        return np.frombuffer(bytearray(b"".join(fields)), dtype=np.uint8).reshape(line.size, width)

    def text(self, i: int) -> str:
        """Line ``i`` as str (latin-1)."""
        s = int(self.start[i])
        return self.data[s:s + int(self.length[i])].decode("latin-1")


FEW_BYTES = 4096
"""A body of at most this many bytes: :class:`BodyLines` finds its lines in Python (numpy's per-call set-up
costs more)."""


def _few_line_bounds(data: bytes, offset: int) -> tuple[np.ndarray, np.ndarray]:
    """(start, length) int64 arrays of the lines of ``data`` from ``offset``, as :class:`BodyLines`' numpy
    path finds them: LF-separated, none after a final LF, a CR before the LF (or the end) not counted."""
    starts, lengths = [], []
    size, at = len(data), offset
    while at < size:
        end = data.find(b"\n", at)
        stop = size if end < 0 else end
        starts.append(at)
        lengths.append(stop - at - (stop > at and data[stop - 1] == 13))
        at = size if end < 0 else end + 1
    return np.array(starts, dtype=np.int64), np.array(lengths, dtype=np.int64)


FEW_FIELDS = 64
"""At most this many fields: :meth:`BodyLines.gather` slices them from the bytes in Python."""


def _ints(f: np.ndarray) -> np.ndarray:
    """Unsigned integers of the byte fields ``f`` (n, w) as ``int`` reads them: blanks around one
    run of ≥ 1 digits; Unsupported otherwise (signs, inner blanks: the line-by-line reader decides)."""
    if f.shape[0] <= 16:                                    # a few: Python's int (numpy's per-call cost dominates)
        raw, w = f.tobytes(), f.shape[1]                    # one bytes object, sliced: no bytes() per row
        fields = [raw[i:i + w] for i in range(0, len(raw), w)] if w else [b""] * f.shape[0]
        if not all(_INT.fullmatch(x) for x in fields):
            raise Unsupported("integer")
        return np.array([int(x) for x in fields], dtype=np.int64)
    digit = (f >= 48) & (f <= 57)
    n_dig = digit.sum(axis=1)
    w = f.shape[1]
    last = w - 1 - np.argmax(digit[:, ::-1], axis=1)
    first = np.argmax(digit, axis=1)
    if np.any(~digit & (f != 32)) or np.any(n_dig == 0) or np.any(last - first + 1 != n_dig):
        raise Unsupported("integer")
    power = np.clip(last[:, None] - np.arange(w)[None, :], 0, 7)
    return (np.where(digit, f.astype(np.int64) - 48, 0) * _POW10[power]).sum(axis=1)


#: the date and time fields of a RINEX 3 epoch line (year, month, day, hour, minute): columns
_DATE_FIELDS = ((2, 6), (7, 9), (10, 12), (13, 15), (16, 18))


def _date_ints(g: np.ndarray) -> tuple[np.ndarray, ...]:
    """(year, month, day, hour, minute) of RINEX 3 epoch lines ``g`` (n, ≥ 18 bytes) in one :func:`_ints`
    call: each field right-aligned in 4 columns behind blanks (blanks around the digits change neither
    what ``int`` takes nor its value)."""
    f = np.full((g.shape[0], 5, 4), 32, dtype=np.uint8)
    for j, (a, b) in enumerate(_DATE_FIELDS):
        f[:, j, 4 - (b - a):] = g[:, a:b]
    return tuple(_ints(f.reshape(-1, 4)).reshape(-1, 5).T)


FEW_DATES = 16
"""At most this many epochs: :func:`_gps_seconds` in Python (numpy's per-call set-up costs more)."""


def _gps_seconds(y, mo, d, h, mi, sec) -> np.ndarray:
    """``gps_seconds`` on arrays, to the bit: float(whole seconds) + float(seconds of minute)."""
    if len(y) <= FEW_DATES:
        return _few_gps_seconds(y, mo, d, h, mi, sec)
    ymd = y * 10000 + mo * 100 + d
    if ymd.size <= 64:                                     # a few epochs: a dict (np.unique's set-up costs more)
        uniq, inv = list(dict.fromkeys(ymd.tolist())), None
    else:
        uniq, inv = np.unique(ymd, return_inverse=True)
        uniq = uniq.tolist()
    try:
        days = np.array([_dt.date(u // 10000, u // 100 % 100, u % 100).toordinal() for u in uniq],
                        dtype=np.int64) - _GPS_EPOCH_ORDINAL
    except ValueError:
        raise Unsupported("date") from None
    if np.any((h < 0) | (h > 23)) or np.any((mi < 0) | (mi > 59)) or np.any((sec < 0) | (sec >= SECOND_MAX)):
        raise Unsupported("time of day")                   # the reference path names the line and field
    if inv is None:
        where = {u: i for i, u in enumerate(uniq)}
        inv = np.array([where[u] for u in ymd.tolist()], dtype=np.int64)
    whole = days[inv.ravel()] * 86400 + h * 3600 + mi * 60
    return whole.astype(np.float64) + sec


def _few_gps_seconds(y, mo, d, h, mi, sec) -> np.ndarray:
    """:func:`_gps_seconds` of a few epochs, one by one: the same values (integer whole seconds, then one
    float addition) and refusals; the arguments arrays, or lists of Python ints / floats."""
    days: dict = {}
    out = []
    for yy, mm, dd, hh, mn, ss in zip(*(a if isinstance(a, list) else np.asarray(a).tolist() for a in (y, mo, d, h, mi, sec))):
        if (yy, mm, dd) not in days:
            try:
                days[yy, mm, dd] = _dt.date(yy, mm, dd).toordinal() - _GPS_EPOCH_ORDINAL
            except ValueError:
                raise Unsupported("date") from None
        if not (0 <= hh <= 23 and 0 <= mn <= 59 and 0 <= ss < SECOND_MAX):
            raise Unsupported("time of day")
        out.append(float(days[yy, mm, dd] * 86400 + hh * 3600 + mn * 60) + ss)
    return np.array(out, dtype=np.float64)


def _clocks(lines: BodyLines, ep: np.ndarray, col: int) -> np.ndarray:
    """Receiver clock offset of epoch lines ``ep``: what stands after column ``col``, NaN if blank."""
    data, nan, clk = lines.data, math.nan, []
    for s, n in zip(lines.start[ep].tolist(), lines.length[ep].tolist()):
        field = data[s + col:s + n] if n > col else b""
        if field.strip():
            try:
                clk.append(strict_float(field))
            except ValueError:
                raise Unsupported("clock") from None
        else:
            clk.append(nan)
    return np.array(clk, dtype=np.float64)


def _blank_from(lines: BodyLines, i: int) -> bool:
    """Whether lines ``i`` to the end are blank (the line-by-line readers skip blank lines)."""
    return lines.n - i <= 64 and all(not lines.text(j).strip() for j in range(i, lines.n))


def epochs_v3(lines: BodyLines, events: str = "refuse") -> dict:
    """The epochs of a RINEX 3 body: arrays over epoch lines ``line``, ``flag``, ``nsat``,
    ``time_gps_s``, ``clk``.  ``events="refuse"``: flags 0, 1 and 6 only (Unsupported for anything
    else); ``"skip"``: flags 2-5 too, their time and clock NaN (their lines are skipped), and the
    flag column must hold a digit."""
    if lines.n == 0:
        raise Unsupported("empty body")
    ep = (lines.buf[lines.start] == 62).nonzero()[0]       # '>' (a blank line reads LF or the next byte)
    ep = ep[lines.length[ep] > 0]
    if ep.size == 0 or ep[0] != 0:
        raise Unsupported("epoch line")
    if ep.size <= FEW_EPOCHS:
        return _few_epochs_v3(lines, ep, events)
    f = lines.gather(ep, 0, 35)
    if events == "skip" and np.any((f[:, 31] < 48) | (f[:, 31] > 57)):
        raise Unsupported("event flag")
    flag = np.where(f[:, 31] == 32, 0, f[:, 31].astype(np.int64) - 48)
    if np.any((flag < 0) | (flag > 6) | (((flag > 1) & (flag < 6)) if events == "refuse" else False)):
        raise Unsupported("event flag")
    nsat = _ints(f[:, 32:35])
    nxt = ep + 1 + nsat
    if not (np.array_equal(nxt[:-1], ep[1:]) and nxt[-1] <= lines.n and _blank_from(lines, int(nxt[-1]))):
        raise Unsupported("layout")                         # blank lines, truncation, stray '>' ...
    timed = np.flatnonzero((flag <= 1) | (flag == 6)) if events == "skip" else np.arange(ep.size)
    g = f[timed]
    if np.any(g[:, 1] != 32) or np.any(g[:, [6, 9, 12, 15, 29, 30]] != 32):
        raise Unsupported("epoch line")
    y, mo, d, h, mi = _date_ints(g)
    sec = decimal_fields(np.ascontiguousarray(g[:, 18:29]))
    if np.any(np.isnan(sec)):
        raise Unsupported("seconds")
    t = np.full(ep.size, np.nan)
    t[timed] = _gps_seconds(y, mo, d, h, mi, sec)
    clk = np.full(ep.size, np.nan)
    if events == "refuse":
        clk = _clocks(lines, ep, 35)
    return {"line": ep, "flag": flag, "nsat": nsat, "time_gps_s": t, "clk": clk}


FEW_EPOCHS = 8
"""At most this many epoch lines: :func:`epochs_v3` reads them one by one in Python (numpy's per-call
set-up costs more than the lines; the same arrays and refusals)."""
_V3_BLANK_COLUMNS = (1, 6, 9, 12, 15, 29, 30)


def _few_epochs_v3(lines: BodyLines, ep: np.ndarray, events: str) -> dict:
    """:func:`epochs_v3` of a few epoch lines ``ep`` (body line indices, the first 0), line by line."""
    if lines.buf.size < 35:
        raise Unsupported("short file")                    # as BodyLines.gather
    data = lines.data
    f = [data[s:s + min(n, 35)].ljust(35) for s, n in zip(lines.start[ep].tolist(), lines.length[ep].tolist())]
    if events == "skip" and not all(48 <= x[31] <= 57 for x in f):
        raise Unsupported("event flag")
    flag = [0 if x[31] == 32 else x[31] - 48 for x in f]
    if not all(0 <= v <= 6 and not (events == "refuse" and 1 < v < 6) for v in flag):
        raise Unsupported("event flag")
    if not all(_INT.fullmatch(x[32:35]) for x in f):
        raise Unsupported("integer")
    nsat = [int(x[32:35]) for x in f]
    at = ep.tolist()
    nxt = [a + 1 + n for a, n in zip(at, nsat)]
    if not (nxt[:-1] == at[1:] and nxt[-1] <= lines.n and _blank_from(lines, nxt[-1])):
        raise Unsupported("layout")
    timed = [k for k, v in enumerate(flag) if v <= 1 or v == 6] if events == "skip" else list(range(len(f)))
    g = [f[k] for k in timed]
    if any(x[c] != 32 for x in g for c in _V3_BLANK_COLUMNS):
        raise Unsupported("epoch line")
    fields = [x[a:b] for x in g for a, b in _DATE_FIELDS]
    if not all(_INT.fullmatch(v) for v in fields):
        raise Unsupported("integer")
    ymdhm = [int(v) for v in fields]
    sec = decimal_fields(np.frombuffer(b"".join(x[18:29] for x in g), np.uint8).reshape(len(g), 11)).tolist()
    if any(math.isnan(v) for v in sec):
        raise Unsupported("seconds")
    t = np.full(ep.size, np.nan)
    if g:                     # at most FEW_EPOCHS <= FEW_DATES: _gps_seconds' Python path, on the lists themselves
        t[timed] = _few_gps_seconds(*(ymdhm[j::5] for j in range(5)), sec)
    clk = _clocks(lines, ep, 35) if events == "refuse" else np.full(ep.size, np.nan)
    return {"line": ep, "flag": np.array(flag, dtype=np.int64), "nsat": np.array(nsat, dtype=np.int64),
            "time_gps_s": t, "clk": clk}


def epochs_v2(lines: BodyLines, per: int, special=None) -> tuple[dict, list, list]:
    """The epochs of a RINEX 2 body, one Python step per epoch (the satellite lists sit on the epoch
    lines): as :func:`epochs_v3` with ``line`` the first record line, ``epoch_line`` the epoch line
    and ``segment`` (the index of the observation-type layout in force); the raw satellite fields
    (3 characters, blank-padded) of every record of the flag-0/1 epochs, in file order; the events in file order
    (flag 6 here, flags 2-5 by ``special(texts, flag, t, epoch_index) -> new lines per record or None``,
    which applies their header lines; without it they are Unsupported)."""
    out = {k: [] for k in ("line", "flag", "nsat", "time_gps_s", "clk", "epoch_line", "segment")}
    sats: list[str] = []
    events: list[dict] = []
    dates: dict[str, tuple] = {}                  # an epoch line's date fields, read once per date
    sat_lists: dict[tuple, list] = {}             # a satellite-list line's fields, once per distinct list
    i, n, segment = 0, lines.n, 0
    while i < n:
        ln = lines.text(i)
        if not ln.strip():
            if _blank_from(lines, i):
                break
            raise Unsupported("blank line")
        try:
            ch, nsat = ln[28:29], int(ln[29:32])
            flag = 0 if ch in ("", " ") else int(ch)
            when = None
            if ln[:26].strip():
                date = dates.get(ln[:9])
                if date is None:
                    date = dates[ln[:9]] = (int(ln[0:3]), int(ln[3:6]), int(ln[6:9]))
                when = date + (int(ln[9:12]), int(ln[12:15]), float(ln[15:26]))
        except ValueError:
            raise Unsupported("epoch line") from None
        if flag > 6 or nsat < 0 or (when is None and flag < 2) or (when is not None and min(when) < 0):
            raise Unsupported("epoch line")
        if 2 <= flag <= 5:
            if special is None or i + 1 + nsat > n:
                raise Unsupported("event")
            t = math.nan if when is None else float(_gps_seconds(*(np.array([v]) for v in _year(when)))[0])
            new_per = special([lines.text(j) for j in range(i + 1, i + 1 + nsat)], flag, t, i, events)
            if new_per is not None:
                per, segment = new_per, segment + 1
            i += 1 + nsat
            continue
        try:
            clk = strict_float(ln[68:]) if ln[68:].strip() else math.nan
        except ValueError:
            raise Unsupported("clock") from None
        n_head = max(1, -(-nsat // 12))
        if when is None or i + n_head + nsat * per > n:
            raise Unsupported("truncated")
        if flag != 6:
            for k in range(n_head):
                sl = ln if k == 0 else lines.text(i + k)
                m = min(12, nsat - 12 * k)
                fields = sat_lists.get((sl[32:68], m))
                if fields is None:
                    fields = sat_lists[(sl[32:68], m)] = [sl[32 + 3 * j:35 + 3 * j].ljust(3) for j in range(m)]
                sats.extend(fields)
        out["line"].append(i + n_head)
        out["flag"].append(flag)
        out["nsat"].append(nsat)
        out["time_gps_s"].append(when)
        out["clk"].append(clk)
        out["epoch_line"].append(i)
        out["segment"].append(segment)
        if flag == 6:
            events.append({"line": i, "flag": 6, "time_gps_s": len(out["line"]) - 1, "labels": []})
        i += n_head + nsat * per
    if not out["line"]:
        raise Unsupported("no epochs")
    ymdhm = np.array([t[:5] for t in out["time_gps_s"]], dtype=np.int64)
    yy = ymdhm[:, 0]
    ymdhm[:, 0] = np.where(yy < 100, yy + np.where(yy >= 80, 1900, 2000), yy)   # as _year
    sec = np.array([t[5] for t in out["time_gps_s"]], dtype=np.float64)
    res = {k: np.asarray(v) for k, v in out.items() if k != "time_gps_s"}
    res["time_gps_s"] = _gps_seconds(*ymdhm.T, sec)
    res["clk"] = res["clk"].astype(np.float64)
    for ev in events:
        if ev["flag"] == 6:                       # the epoch's time, now computed
            ev["time_gps_s"] = float(res["time_gps_s"][ev["time_gps_s"]])
    return res, sats, events


def _year(when: tuple) -> tuple:
    """(year, month, day, hour, minute, second) of a RINEX 2 epoch's fields (two-digit year: 1980-2079)."""
    yy = when[0]
    return (yy + (1900 if yy >= 80 else 2000) if yy < 100 else yy, *when[1:])


FEW_RECORDS = 256
"""At most this many values: :func:`distinct` by a dict (np.unique's set-up costs more)."""


def distinct(values) -> tuple[list, np.ndarray]:
    """(the distinct values, sorted, as a list; each value's index among them): ``np.unique(values,
    return_inverse=True)`` of an int array or of a list of str of at most 3 characters (as "U3")."""
    if len(values) > FEW_RECORDS:
        arr = np.array(values, dtype="U3") if isinstance(values, list) else np.asarray(values)
        uniq, inv = np.unique(arr, return_inverse=True)
        return uniq.tolist(), inv.ravel()
    vals = values.tolist() if isinstance(values, np.ndarray) else values
    uniq = sorted(set(vals))
    where = {u: i for i, u in enumerate(uniq)}
    return uniq, np.array([where[v] for v in vals], dtype=np.intp)


def record_sats(raw: np.ndarray, sat_id) -> tuple[np.ndarray, np.ndarray]:
    """Satellite names of records from their 3-byte fields ``raw`` (n, 3): (names (k,) object, the
    index of each record's name (n,)); each distinct field is checked once with ``sat_id``
    (Unsupported where it refuses)."""
    if raw.shape[0] <= FEW_RECORDS:
        return _few_record_sats(raw, sat_id)
    if np.any(raw >= 128):
        raise Unsupported("satellite")
    code = (raw[:, 0].astype(np.int32) << 16) | (raw[:, 1].astype(np.int32) << 8) | raw[:, 2]
    uniq, inv = distinct(code)
    names = []
    for u in uniq:
        s = bytes([u >> 16, (u >> 8) & 255, u & 255]).decode("latin-1")
        try:
            names.append(sat_id(s))
        except ValueError:
            raise Unsupported("satellite") from None
    return np.array(names, dtype=object), inv


def _few_record_sats(raw: np.ndarray, sat_id) -> tuple[np.ndarray, np.ndarray]:
    """:func:`record_sats` of a few records, on the fields as bytes (3 bytes each: their order is the order
    of the integer codes :func:`record_sats` sorts), without numpy's per-call set-up."""
    blob = raw.tobytes()
    if not blob.isascii():
        raise Unsupported("satellite")
    fields = [blob[i:i + 3] for i in range(0, len(blob), 3)]
    uniq = sorted(set(fields))
    where = {u: i for i, u in enumerate(uniq)}
    names = []
    for u in uniq:
        try:
            names.append(sat_id(u.decode("latin-1")))
        except ValueError:
            raise Unsupported("satellite") from None
    return np.array(names, dtype=object), np.array([where[f] for f in fields], dtype=np.intp)


def gps_fields_of(lines: BodyLines, rec_line: np.ndarray, ks: list, v3: bool) -> list[tuple[np.ndarray, np.ndarray]]:
    """Observations ``ks`` of the records starting at lines ``rec_line`` (RINEX 2: observation k on the
    record's line k // 5), each as (values (n,) float64, NaN if blank; the LLI and SSI bytes (n, 2)
    uint8): one gather and one conversion for all of them (each field converted alone: the values of
    one call per observation; Unsupported when any field is malformed)."""
    n = rec_line.size
    if v3:
        line = np.concatenate([rec_line] * len(ks))       # np.tile's values, without its Python wrapper
        col = np.array([3 + 16 * k for k in ks], dtype=np.int64).repeat(n)
    else:
        line = np.concatenate([rec_line + k // 5 for k in ks])
        col = np.array([16 * (k % 5) for k in ks], dtype=np.int64).repeat(n)
    f = lines.gather(line, col, 16)
    values = decimal_fields(f[:, :14])
    return [(values[j * n:(j + 1) * n], f[j * n:(j + 1) * n, 14:16]) for j in range(len(ks))]


#: a flag byte's value (a digit's, 0 for a blank) and whether it is one (blank or digit): look-up tables
_FLAG_VALUE = np.zeros(256, dtype=np.int64)
_FLAG_VALUE[48:58] = np.arange(10)
_FLAG_OK = np.zeros(256, dtype=bool)
_FLAG_OK[[32, *range(48, 58)]] = True


def flag_values(ch: np.ndarray, use: np.ndarray) -> np.ndarray:
    """LLI / SSI bytes (n,) as ints where ``use``, 0 elsewhere; Unsupported for a used byte that is
    neither a blank nor a digit.  By two 256-entry tables (a few numpy calls: a small file's cost)."""
    if not (_FLAG_OK[ch] | ~use).all():
        raise Unsupported("flag")
    return _FLAG_VALUE[ch] * use
