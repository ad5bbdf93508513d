"""Vectorised reading of fixed-width numeric fields (RINEX observation records) from text lines.

The text's lines are joined once into a byte buffer; a field (column, width) of many lines is
gathered as a ``(rows, width)`` byte array and converted in numpy.  A decimal field ``[+-]ddd.ddd``
is read exactly as Python's ``float()`` reads it: the digits form an integer ``N < 10**14`` (exact in
float64) and the value is ``N / 10**k`` (k digits after the point), one correctly rounded division,
i.e. the double nearest the decimal number, which is what ``float()`` returns.  Anything else
(exponents, tabs, non-ASCII, a malformed number) raises :class:`Unsupported`: the caller then reads
that file with its line-by-line parser, which gives the same values or the same error.
"""

from __future__ import annotations

import math
import re

import numpy as np

__all__ = ["Unsupported", "LineBuffer", "decimal_fields", "flag_digits", "windows"]

_SPACE, _DOT, _PLUS, _MINUS = 32, 46, 43, 45
_PAD = 64             # blanks after the last line: any field of up to this width can be sliced
_POW10_INT = 10 ** np.arange(16, dtype=np.int64)
_POW10_FLOAT = 10.0 ** np.arange(16)


class Unsupported(Exception):
    """A field the vectorised reader does not take; read the file line by line instead."""


def windows(buf: np.ndarray, width: int) -> np.ndarray:
    """Every run of ``width`` consecutive bytes of the contiguous 1-D uint8 array ``buf`` (``len(buf) >= width``), as a
    read-only (len - width + 1, width) view: ``sliding_window_view(buf, width)``'s array, made directly
    (≈ 3 µs instead of ≈ 45 µs: a small file's fields are gathered several times)."""
    return np.ndarray((buf.size - width + 1, width), dtype=np.uint8, buffer=buf, strides=(1, 1))


class LineBuffer:
    """Text lines joined into one byte buffer, with each line's start and length.

    Parameters
    ----------
    lines : list of str
        Lines without their newline (latin-1 text: one byte per character).
    """

    def __init__(self, lines: list[str]):
        self.buf = np.frombuffer(("\n".join(lines) + " " * _PAD).encode("latin-1"), dtype=np.uint8)
        self.length = np.fromiter(map(len, lines), dtype=np.int64, count=len(lines))
        self.start = np.zeros(len(lines), dtype=np.int64)
        np.cumsum(self.length[:-1] + 1, out=self.start[1:])

    @classmethod
    def from_bytes(cls, data: bytes, lines: list[str]) -> "LineBuffer":
        """The buffer of ``lines`` split from ``data`` (latin-1, LF-separated, a CR before an LF
        dropped) without joining them again; Unsupported if the lines are not those of ``data``."""
        self = cls.__new__(cls)
        raw = np.frombuffer(data, dtype=np.uint8)
        lf = np.flatnonzero(raw == 10)
        n = len(lines)
        if lf.size < n - 1:
            raise Unsupported("line count")
        self.start = np.concatenate([[0], lf[:n - 1] + 1]).astype(np.int64)
        end = np.concatenate([lf, [raw.size]])[:n]
        cr = (end > self.start) & (raw[np.maximum(end - 1, 0)] == 13)
        self.length = end - self.start - cr
        if n and (self.length[-1] != len(lines[-1]) or self.length[n // 2] != len(lines[n // 2])):
            raise Unsupported("lines")
        self.buf = np.concatenate([raw, np.full(_PAD, _SPACE, dtype=np.uint8)])
        return self

    def gather(self, line: np.ndarray, col, width: int) -> np.ndarray:
        """Bytes ``[col, col + width)`` of lines ``line`` (n,), as (n, width) uint8; columns past
        a line's end read as blanks (as a slice of a short line is shorter, and blank).  ``col``: one
        column, or one per line (n,)."""
        if width > _PAD:
            raise ValueError(f"field width {width} > {_PAD}")
        start = np.minimum(self.start[line] + col, self.buf.size - width)
        out = windows(self.buf, width)[start]                       # (n, width) copy
        room = self.length[line] - col                              # characters of the field on its line
        short = np.flatnonzero(room < width)
        if short.size:
            room = room[short]
            out[short] = np.where(np.arange(width)[None, :] >= room[:, None], np.uint8(_SPACE), out[short])
        return out


#: character classes of the F14.3 layout's integer part: blank 0, sign 1, digit 2, anything else 9
_RANK = np.full(256, 9, dtype=np.int8)
_RANK[_SPACE] = 0
_RANK[[_PLUS, _MINUS]] = 1
_RANK[48:58] = 2


def _f14_3(f: np.ndarray) -> np.ndarray | None:
    """The fields of ``f`` (n, 14) when every non-blank one is RINEX's F14.3 (point in column 11, three
    digits after it, blanks / a sign / digits before it, in that order), else None.  The digits are
    accumulated column by column (Horner, float64: integers < 2**53, exact) before the one division."""
    cols = np.ascontiguousarray(f.T)                     # (14, n): one contiguous row per column
    body = cols[0] != _SPACE
    for c in range(1, 14):
        body |= cols[c] != _SPACE
    ok = cols[10] == _DOT
    whole = np.zeros(f.shape[0])
    prev = np.zeros(f.shape[0], dtype=np.int8)
    signs = np.zeros(f.shape[0], dtype=np.int8)
    neg = cols[0] == _MINUS
    for c in range(10):
        rank = _RANK[cols[c]]
        ok &= (rank != 9) & (rank >= prev)
        signs += rank == 1
        neg |= cols[c] == _MINUS
        whole = whole * 10.0 + np.where(rank == 2, cols[c] - np.uint8(48), np.uint8(0))
        prev = rank
    for c in (11, 12, 13):
        d = cols[c] - np.uint8(48)                       # wraps above 9 for anything but a digit
        ok &= d <= 9
        whole = whole * 10.0 + d
    ok &= signs <= 1
    if not np.all(ok | ~body):
        return None
    value = whole / 1000.0
    value = np.where(neg, -value, value)
    value[~body] = np.nan
    return value


_SMALL = 256         # fewer fields than this: Python's float, one at a time (numpy's per-call cost dominates)
_DECIMAL = re.compile(rb" *[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+) *")
"""What a number field may hold: blanks around an optionally signed decimal number."""
_DECIMAL_BYTES = b"0123456789+-. "


def _few_decimals(f: np.ndarray) -> np.ndarray:
    """:func:`decimal_fields` of a few fields: the same values (``float`` of the same decimal) and the
    same refusals (only blanks around an optionally signed decimal number, :data:`_DECIMAL`).  With no
    byte but digits, signs, dots and blanks, ``float`` takes exactly what :data:`_DECIMAL` matches (it
    strips the blanks; no exponent, ``inf``/``nan`` or ``_`` can be spelled), so each field is one
    ``float`` call; an all-blank field is NaN."""
    raw, w = f.tobytes(), f.shape[1]                     # one bytes object, sliced: no bytes() per row
    if raw.translate(None, _DECIMAL_BYTES):              # any other byte: a field that is not a number
        raise Unsupported("number")
    blank, nan, out = b" " * w, math.nan, []
    try:
        for field in ([raw[i:i + w] for i in range(0, len(raw), w)] if w else [b""] * f.shape[0]):
            out.append(nan if field == blank else float(field))
    except ValueError:
        raise Unsupported("number") from None
    return np.array(out, dtype=np.float64).reshape(f.shape[0])


def decimal_fields(f: np.ndarray) -> np.ndarray:
    """The numbers of the (n, w) byte fields ``f`` (w ≤ 14), NaN for blank fields, exactly as
    ``float(field) if field.strip() else nan``; :class:`Unsupported` for anything but blanks around
    an optionally signed decimal number."""
    if f.shape[0] <= _SMALL:
        return _few_decimals(f)
    if f.shape[1] == 14:
        value = _f14_3(f)
        if value is not None:
            return value
    digit = (f >= 48) & (f <= 57)
    dot, sign = f == _DOT, (f == _PLUS) | (f == _MINUS)
    body = f != _SPACE
    if np.any(body & ~(digit | dot | sign)):
        raise Unsupported("character")
    n, w = f.shape
    cols = np.arange(w)
    first = np.where(body.any(axis=1), body.argmax(axis=1), w)
    last = w - 1 - body[:, ::-1].argmax(axis=1)
    inner = (cols[None, :] >= first[:, None]) & (cols[None, :] <= last[:, None])
    blank = first == w
    lead = np.zeros((n, w), dtype=bool)
    lead[~blank, first[~blank]] = True
    n_digits = digit.sum(axis=1)
    if (np.any(inner & ~body) or np.any(sign & ~lead) or np.any(dot.sum(axis=1) > 1)
            or np.any(~blank & (n_digits == 0))):
        raise Unsupported("number")
    right = np.cumsum(digit[:, ::-1], axis=1)[:, ::-1] - digit          # digits right of each column
    whole = np.where(digit, (f.astype(np.int64) - 48) * _POW10_INT[right], 0).sum(axis=1)
    k = np.where(dot.any(axis=1), right[np.arange(n), dot.argmax(axis=1)], 0)
    value = whole.astype(np.float64) / _POW10_FLOAT[k]
    neg = (f[np.arange(n), np.minimum(first, w - 1)] == _MINUS) & ~blank
    value = np.where(neg, -value, value)
    value[blank] = np.nan
    return value


def flag_digits(ch: np.ndarray) -> np.ndarray:
    """A flag column (n,) of bytes as ``int(c) if c.strip().isdigit() else 0``; Unsupported for
    non-ASCII bytes (``isdigit`` is true of superscript digits, which ``int`` refuses)."""
    if (ch >= 128).any():
        raise Unsupported("flag")
    return _DIGIT_VALUE[ch]


_DIGIT_VALUE = np.zeros(256, dtype=np.int64)
_DIGIT_VALUE[48:58] = np.arange(10)
"""A byte's digit value, 0 for any other byte (:func:`flag_digits`' look-up table)."""
