"""Every GPS LNAV, Galileo I/NAV and BeiDou D1 subframe of a u-blox log decoded at once (numpy).

:func:`cdgps_cli.io.sfrbx.sfrbx_ephemerides_at` walks a log's RXM-SFRBX / RXM-SFRB frames in order,
keeping each satellite's latest subframes (GPS 1-3, Galileo word types 1-5, BeiDou D1 1-3) and
decoding them whenever a set is complete; a record is kept under (satellite, toe, IODE) the first
time a set decodes to a valid one.  This module gives the same records without a Python step per
frame:

* the checks (GPS parity, Galileo CRC-24Q, BeiDou BCH) run over all frames of a system as arrays;
  the few frames the array checks do not pass go through the per-frame functions of
  :mod:`cdgps_cli.io.sfrbx` (ICD parity chain, de-interleaved BeiDou words), as the walk does;
* "each satellite's latest subframe of each type at every frame" is a running maximum of frame
  numbers per satellite (:func:`latest_of_type`), so the sets the walk would decode are the rows of
  one integer table;
* the fields of all distinct sets come from one product of their bits with a table of powers of
  two (exact: every field is an integer below 2^53), then the same float operations, in the same
  order, as the scalar decoders (:func:`~cdgps_cli.io.sfrbx.decode_gps_subframes`,
  :func:`~cdgps_cli.io.sfrbx.decode_galileo_words`, :func:`~cdgps_cli.io.sfrbx.decode_beidou_d1`):
  the values are bit-identical;
* of the valid records, the first (log order) of each (satellite, toe, IODE) is kept.

BeiDou D2 (GEO) pages and GLONASS strings stay with the frame-by-frame code (few frames).
``tests/io/test_sfrbx_batch.py`` shows the table and counters equal to the frame-by-frame walk's
on every UBX log at hand and on encoded logs.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.gps_time import bdt_to_gps_s
from cdgps_cli.io import sfrbx as sf
from cdgps_cli.io.ubx_frames import _CRC24Q

W_S = 604800.0
"""Seconds per week."""


def _crc24q_byte_tables(n: int) -> np.ndarray:
    """(n, 256) int64: the CRC-24Q (initial value 0) of an n-byte message whose only non-zero byte is
    byte k with value v.  The CRC is linear over GF(2), so a message's CRC is the XOR over its bytes of
    ``table[k, byte_k]``.  Row n-1 is the byte-wise table; each earlier row is the next one carried
    through one more zero byte."""
    table = np.array(_CRC24Q, dtype=np.int64)
    out = np.empty((n, 256), np.int64)
    out[n - 1] = table
    for k in range(n - 2, -1, -1):
        c = out[k + 1]
        out[k] = ((c << 8) & 0xFFFFFF) ^ table[c >> 16]
    return out


_INAV_CRC = _crc24q_byte_tables(25)
"""CRC-24Q contributions of each byte of the 25 bytes an I/NAV page pair's CRC covers."""
_URA = np.array(sf.URA_M, dtype=np.float64)
_URAI = np.array(sf._URAI_M, dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# bit fields of many messages at once

class FieldTable:
    """Unsigned / two's-complement fields of messages made of ``blocks`` blocks of ``width`` bits.

    ``spec``: name → (signed, pieces), pieces ((block, first bit, bits), …) most significant first
    (a field split over words or subframes, as ``_D1.u2`` joins it; a piece at most 32 bits).
    :meth:`values` reads every piece of every row at once from a 64-bit big-endian window starting at
    the piece's byte (integer shifts and masks only, so exact).
    """

    def __init__(self, spec: dict, width: int, blocks: int):
        self.names = list(spec)
        self.nbytes = -(-width * blocks // 8)
        byte, shift, mask, up, first = [], [], [], [], []
        self.nbits = np.zeros(len(spec), np.int64)
        self.signed = np.zeros(len(spec), bool)
        for j, (signed, pieces) in enumerate(spec.values()):
            first.append(len(byte))
            n = sum(p[2] for p in pieces)
            below = n
            for block, start, nb in pieces:
                a = block * width + start
                below -= nb
                byte.append(a // 8)
                shift.append(64 - a % 8 - nb)
                mask.append((1 << nb) - 1)
                up.append(below)
            self.nbits[j], self.signed[j] = n, signed
        self.at = np.array(byte, np.int64)[:, None] + np.arange(8)
        self.shift = np.array(shift, np.uint64)
        self.mask = np.array(mask, np.uint64)
        self.up = np.array(up, np.uint64)
        self.first = np.array(first, np.int64)

    def values(self, bits: np.ndarray) -> dict:
        """{name: int64 array} of the rows of ``bits`` (uint8 0/1, shape (m, width·blocks))."""
        m = len(bits)
        packed = np.zeros((m, self.nbytes + 8), np.uint8)
        packed[:, :self.nbytes] = np.packbits(bits, axis=1)
        win = np.ascontiguousarray(packed[:, self.at]).view(">u8").reshape(m, len(self.at))
        v = ((win >> self.shift) & self.mask) << self.up
        v = np.bitwise_or.reduceat(v, self.first, axis=1).astype(np.int64) if m else np.zeros((0, len(self.names)), np.int64)
        half = np.int64(1) << (self.nbits - 1)
        v = np.where(self.signed & (v >= half), v - (half << 1), v)
        return {name: v[:, j] for j, name in enumerate(self.names)}


def _f(signed: bool, *pieces) -> tuple:
    """A :class:`FieldTable` entry: (signed, ((block, first bit, bits), …))."""
    return signed, pieces


def latest_of_type(sat: np.ndarray, typ: np.ndarray, k: int) -> np.ndarray:
    """Row number of the latest row (at or before each row) of the same ``sat`` with ``typ`` = 0…k-1.

    Parameters
    ----------
    sat, typ : int arrays, shape (n,)
        Satellite and message type (0…k-1) of each row, rows in log order.

    Returns
    -------
    int64 array, shape (n, k)
        −1 where that satellite has had no row of that type yet.
    """
    n = sat.size
    order = sat.argsort(kind="stable")                     # by satellite, log order within
    s = sat[order]
    base = np.zeros(n, np.int64)
    if n:
        base[1:] = (s[1:] != s[:-1]).cumsum() * (n + 1)    # per satellite, above every earlier one's
    t = typ[order]
    out = np.empty((n, k), np.int64)
    for j in range(k):
        v = np.where(t == j, base + order, base - 1)
        out[order, j] = np.maximum.accumulate(v) - base
    return out


def first_per_key(sat: np.ndarray, toe: np.ndarray, iode: np.ndarray) -> np.ndarray:
    """Indices (ascending) of the first row of each distinct (sat, toe, iode)."""
    m = sat.size
    if m < 2:
        return np.arange(m)
    o = np.lexsort((np.arange(m), iode, toe, sat))
    new = np.ones(m, bool)
    so, to, io = sat[o], toe[o], iode[o]                   # sat, iode integers: np.diff(x) != 0 is x[1:] != x[:-1]
    new[1:] = (so[1:] != so[:-1]) | (to[1:] != to[:-1]) | (io[1:] != io[:-1])
    first = o[new]
    first.sort()
    return first


def _nearest_week_s(week: np.ndarray, transmit_sow_s: np.ndarray, sow_s: np.ndarray) -> np.ndarray:
    """:func:`cdgps_cli.io.sfrbx._nearest_week_s` of arrays (the same float operations)."""
    base = week * W_S
    t_tx = base + transmit_sow_s
    return base + sow_s + W_S * ((t_tx - base - sow_s) / W_S).round()


def _full_week(wn: np.ndarray, week_ref: int, modulus: int) -> np.ndarray:
    """``wn + modulus·round((week_ref − wn)/modulus)``: a truncated week number completed (Python's round)."""
    return wn + modulus * ((week_ref - wn) / modulus).round().astype(np.int64)


def _kept(sat_no: np.ndarray, prefix: str, cols: dict, ok: np.ndarray) -> dict:
    """The valid records (decodable, 0 ≤ e < 1, √a > 0), the first of each (sat, toe, IODE) in order."""
    valid = (ok & (cols["e"] >= 0) & (cols["e"] < 1) & (cols["sqrt_a_sqrt_m"] > 0)).nonzero()[0]
    keep = valid[first_per_key(sat_no[valid], cols["toe_gps_s"][valid], cols["iode"][valid])]
    out = {"sat": np.array([f"{prefix}{v:02d}" for v in sat_no[keep].tolist()], dtype="<U3")}
    for c in sf.NAV_COLUMNS[1:]:
        v = cols[c]
        out[c] = v[keep] if isinstance(v, np.ndarray) else np.full(keep.size, v)
    return out


# ---------------------------------------------------------------------------------------------
# GPS LNAV subframes 1-3 (decode_gps_subframes)

_GPS = FieldTable({
    "iodc": _f(False, (0, 70, 2), (0, 168, 8)), "iode": _f(False, (1, 48, 8)), "iode3": _f(False, (2, 216, 8)),
    "wn10": _f(False, (0, 48, 10)), "tow": _f(False, (0, 24, 17)), "toc": _f(False, (0, 176, 16)),
    "toe": _f(False, (1, 216, 16)), "ura": _f(False, (0, 60, 4)),
    "af0": _f(True, (0, 216, 22)), "af1": _f(True, (0, 200, 16)), "af2": _f(True, (0, 192, 8)),
    "crs": _f(True, (1, 56, 16)), "dn": _f(True, (1, 72, 16)), "m0": _f(True, (1, 88, 32)),
    "cuc": _f(True, (1, 120, 16)), "e": _f(False, (1, 136, 32)), "cus": _f(True, (1, 168, 16)),
    "sqrta": _f(False, (1, 184, 32)), "cic": _f(True, (2, 48, 16)), "omega0": _f(True, (2, 64, 32)),
    "cis": _f(True, (2, 96, 16)), "i0": _f(True, (2, 112, 32)), "crc": _f(True, (2, 144, 16)),
    "omega": _f(True, (2, 160, 32)), "omegadot": _f(True, (2, 192, 24)), "idot": _f(True, (2, 224, 14)),
    "codes_l2": _f(False, (0, 58, 2)), "l2p": _f(False, (0, 72, 1)), "health": _f(False, (0, 64, 6)),
    "tgd": _f(True, (0, 160, 8)), "fit": _f(False, (1, 232, 1)),
}, 240, 3)


def _kepler_lsb(f: dict, toe) -> dict:
    """The orbit's Keplerian fields in SI units from their raw integers, with the scale factors (LSBs) that GPS LNAV
    (IS-GPS-200 Table 20-III) and Galileo I/NAV (OS SIS ICD Table 60) share; ``toe`` (s of week) placed in the
    column order of the ephemeris table."""
    pi = sf.GPS_PI
    return {"crs_m": f["crs"] * 2.0**-5, "delta_n_rad_per_s": f["dn"] * 2.0**-43 * pi,
            "m0_rad": f["m0"] * 2.0**-31 * pi, "cuc_rad": f["cuc"] * 2.0**-29, "e": f["e"] * 2.0**-33,
            "cus_rad": f["cus"] * 2.0**-29, "sqrt_a_sqrt_m": f["sqrta"] * 2.0**-19, "toe_sow_s": toe,
            "cic_rad": f["cic"] * 2.0**-29, "omega0_rad": f["omega0"] * 2.0**-31 * pi, "cis_rad": f["cis"] * 2.0**-29,
            "i0_rad": f["i0"] * 2.0**-31 * pi, "crc_m": f["crc"] * 2.0**-5, "omega_rad": f["omega"] * 2.0**-31 * pi,
            "omega_dot_rad_per_s": f["omegadot"] * 2.0**-43 * pi, "idot_rad_per_s": f["idot"] * 2.0**-43 * pi}


def gps_columns(bits: np.ndarray, week_ref: int, qzss: bool = False) -> tuple[dict, np.ndarray]:
    """:func:`~cdgps_cli.io.sfrbx.decode_gps_subframes` of many sets: (column → array, set decodable).

    ``bits``: uint8 0/1, shape (m, 720): the 240 data bits of subframes 1, 2, 3 of each set; ``qzss``: QZSS sets
    (their fit-interval flag read as QZSS's, :func:`~cdgps_cli.io.rinex.qzss_fit_interval_h`)."""
    f = _GPS.values(bits)
    iode = f["iode"]
    ok = (f["iode3"] == iode) & ((f["iodc"] & 0xFF) == iode)
    week = _full_week(f["wn10"], week_ref, 1024)
    tow_sf1 = f["tow"] * 6.0 - 6.0
    toc, toe = f["toc"] * 16.0, f["toe"] * 16.0
    ura = f["ura"]
    cols = {
        "af0_s": f["af0"] * 2.0**-31, "af1_s_per_s": f["af1"] * 2.0**-43, "af2_s_per_s2": f["af2"] * 2.0**-55,
        "iode": iode, **_kepler_lsb(f, toe),
        "codes_l2": f["codes_l2"], "week": week, "l2p_data_flag": f["l2p"],
        "sv_accuracy_m": np.where(ura < _URA.size, _URA[np.minimum(ura, _URA.size - 1)], 6144.0 * 2),
        "sv_health": f["health"], "tgd_s": f["tgd"] * 2.0**-31, "iodc": f["iodc"], "transmit_sow_s": tow_sf1,
        "fit_interval_h": sf.qzss_fit_interval_h(f["fit"]) if qzss else np.where(f["fit"] == 0, 4.0, 6.0), "line": -1,
        "transmit_gps_s": week * W_S + tow_sf1, "toc_gps_s": _nearest_week_s(week, tow_sf1, toc),
        "toe_gps_s": _nearest_week_s(week, tow_sf1, toe),
    }
    return cols, ok


def _words24_bits(words: np.ndarray) -> np.ndarray:
    """uint8 0/1 (m, 240): the 24 data bits of each of ten words (uint32, shape (m, 10))."""
    b = np.ascontiguousarray(words, dtype=">u4").view(np.uint8).reshape(len(words), 10, 4)[:, :, 1:]
    return np.unpackbits(b.reshape(len(words), 30), axis=1)


def gps_records(x: np.ndarray, off: np.ndarray, week_ref: int | None, stats: dict, letter: str = "G") -> dict | None:
    """The GPS records of the RXM-SFRBX L1 C/A and RXM-SFRB frames starting at ``off`` (log order, as
    :func:`~cdgps_cli.io.sfrbx._stateful_mask` keeps them) — or, ``letter`` ``"J"``, the QZSS records of its
    RXM-SFRBX L1 C/A frames — with the walk's counters; None: no record."""
    m = off.size
    is_x = x[off + 3] == 0x13
    legacy = ~is_x                                         # RXM-SFRB: ten dwords after chn, svid
    at = off[:, None] + np.where(legacy, 8, 14)[:, None] + np.arange(40)
    raw = x[np.minimum(at, x.size - 1)] if legacy.any() else x[at]
    w = np.ascontiguousarray(raw).view("<u4").reshape(m, 10)
    sv = x[off + 7].astype(np.int64)
    n_pl = np.zeros(m, np.int64)
    if legacy.any():
        n_pl = (x[off + 4].astype(np.int64) | (x[off + 5].astype(np.int64) << 8))
    good = np.where(is_x, sf._gps_parity_passes(w), (n_pl == 42) & (sv >= 1) & (sv <= 32))
    words = np.where(is_x[:, None], (w >> 6) & 0xFFFFFF, w & 0xFFFFFF)
    for i in (is_x & ~good).nonzero()[0].tolist():         # the ICD parity chain, frame by frame
        got = sf.gps_words_from_sfrbx(w[i].tolist())
        if got is None:
            stats["parity_failures"] += 1
        else:
            words[i], good[i] = got, True
    sid = np.where((words[:, 0] >> 16) & 0xFF == sf.PREAMBLE, (words[:, 1] >> 2) & 7, 0)
    use = (good & (sid >= 1) & (sid <= 3) & (sv >= 1) & (sv <= 32)).nonzero()[0]
    stats[sf._LNAV_COUNTERS[letter][0]] += int(use.size)
    if week_ref is None or not use.size:
        return None
    last = latest_of_type(sv[use], sid[use].astype(np.int64) - 1, 3)
    sets = last[(last >= 0).all(axis=1)]         # distinct: each holds its own frame
    if not len(sets):
        return None
    bits = _words24_bits(words[use])
    cols, ok = gps_columns(bits[sets].reshape(len(sets), 720), week_ref, qzss=letter == "J")
    return _kept(sv[use][sets[:, 0]], letter, cols, ok)


# ---------------------------------------------------------------------------------------------
# Galileo I/NAV word types 1-5 (decode_galileo_words)

_GAL = FieldTable({
    "iod1": _f(False, (0, 6, 10)), "iod2": _f(False, (1, 6, 10)), "iod3": _f(False, (2, 6, 10)),
    "iod4": _f(False, (3, 6, 10)), "wn": _f(False, (4, 73, 12)), "tow": _f(False, (4, 85, 20)),
    "toe": _f(False, (0, 16, 14)), "toc": _f(False, (3, 54, 14)),
    "h72": _f(False, (4, 72, 1)), "h69": _f(False, (4, 69, 2)), "h71": _f(False, (4, 71, 1)), "h67": _f(False, (4, 67, 2)),
    "af0": _f(True, (3, 68, 31)), "af1": _f(True, (3, 99, 21)), "af2": _f(True, (3, 120, 6)),
    "crs": _f(True, (2, 104, 16)), "dn": _f(True, (2, 40, 16)), "m0": _f(True, (0, 30, 32)),
    "cuc": _f(True, (2, 56, 16)), "e": _f(False, (0, 62, 32)), "cus": _f(True, (2, 72, 16)),
    "sqrta": _f(False, (0, 94, 32)), "cic": _f(True, (3, 22, 16)), "omega0": _f(True, (1, 16, 32)),
    "cis": _f(True, (3, 38, 16)), "i0": _f(True, (1, 48, 32)), "crc": _f(True, (2, 88, 16)),
    "omega": _f(True, (1, 80, 32)), "omegadot": _f(True, (2, 16, 24)), "idot": _f(True, (1, 112, 14)),
    "sisa": _f(False, (2, 120, 8)), "bgd": _f(True, (4, 57, 10)),
}, 128, 5)


def _sisa_m(index: np.ndarray) -> np.ndarray:
    """:func:`cdgps_cli.io.sfrbx._sisa_m` of an int array (the same float operations)."""
    return np.where(index < 50, index * 0.01, np.where(index < 75, 0.5 + (index - 50) * 0.02, np.where(    # np.select's
        index < 100, 1.0 + (index - 75) * 0.04, np.where(index < 126, 2.0 + (index - 100) * 0.16, np.nan))))


def galileo_columns(bits: np.ndarray, week_ref: int) -> tuple[dict, np.ndarray]:
    """:func:`~cdgps_cli.io.sfrbx.decode_galileo_words` of many sets (``bits``: (m, 640), word types 1-5)."""
    f = _GAL.values(bits)
    iod = f["iod1"]
    ok = (f["iod2"] == iod) & (f["iod3"] == iod) & (f["iod4"] == iod)
    week = _full_week(f["wn"] + 1024, week_ref, 4096)
    tow = f["tow"].astype(np.float64)
    toe, toc = f["toe"] * 60.0, f["toc"] * 60.0
    cols = {
        "af0_s": f["af0"] * 2.0**-34, "af1_s_per_s": f["af1"] * 2.0**-46, "af2_s_per_s2": f["af2"] * 2.0**-59,
        "iode": iod, **_kepler_lsb(f, toe),
        "codes_l2": 513, "week": week, "l2p_data_flag": 0, "sv_accuracy_m": _sisa_m(f["sisa"]),
        "sv_health": f["h72"] | (f["h69"] << 1) | (f["h71"] << 6) | (f["h67"] << 7),
        "tgd_s": f["bgd"] * 2.0**-32, "iodc": iod, "transmit_sow_s": tow, "fit_interval_h": float("nan"), "line": -1,
        "transmit_gps_s": week * W_S + tow, "toc_gps_s": _nearest_week_s(week, tow, toc),
        "toe_gps_s": _nearest_week_s(week, tow, toe),
    }
    return cols, ok


def inav_bits(dwrd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(page pair accepted, the 128 bits of its I/NAV word as uint8 0/1 (m, 128)) of RXM-SFRBX Galileo
    payload words (uint32, shape (m, 8)): :func:`~cdgps_cli.io.sfrbx.inav_word`'s checks as bit columns,
    the CRC-24Q over the rows' 25 bytes side by side."""
    m = len(dwrd)
    bits = np.unpackbits(np.ascontiguousarray(dwrd, dtype=">u4").view(np.uint8).reshape(m, 32), axis=1)
    even, odd = bits[:, :128], bits[:, 128:]
    flags = (even[:, 0] == 0) & (odd[:, 0] == 1) & (even[:, 1] == 0) & (odd[:, 1] == 0)
    covered = np.packbits(np.concatenate((np.zeros((m, 4), np.uint8), even[:, :114], odd[:, :82]), axis=1), axis=1)
    crc = np.bitwise_xor.reduce(_INAV_CRC[np.arange(25), covered], axis=1)
    sent = np.packbits(odd[:, 82:106], axis=1).astype(np.int64)
    ok = flags & (crc == (sent[:, 0] << 16 | sent[:, 1] << 8 | sent[:, 2]))
    return ok, np.concatenate((even[:, 2:114], odd[:, 2:18]), axis=1)


def galileo_records(x: np.ndarray, off: np.ndarray, week_ref: int, stats: dict) -> dict | None:
    """The Galileo records of the I/NAV page pairs starting at ``off`` (log order), with the walk's counters."""
    dw = np.ascontiguousarray(x[off[:, None] + np.arange(14, 46)]).view("<u4").reshape(off.size, 8)
    ok, bits = inav_bits(dw)
    stats["galileo_bad_pages"] += int(off.size - ok.sum())
    wtype = bits[:, :6].astype(np.int64) @ (1 << np.arange(5, -1, -1))
    sv = x[off + 7].astype(np.int64)
    use = (ok & (wtype >= 1) & (wtype <= 5) & (sv >= 1) & (sv <= 36)).nonzero()[0]
    stats["galileo_words"] += int(use.size)
    if not use.size:
        return None
    last = latest_of_type(sv[use], wtype[use] - 1, 5)
    sets = last[(last >= 0).all(axis=1)]         # distinct: each holds its own frame
    if not len(sets):
        return None
    cols, ok_set = galileo_columns(bits[use][sets].reshape(len(sets), 640), week_ref)
    return _kept(sv[use][sets[:, 0]], "E", cols, ok_set)


# ---------------------------------------------------------------------------------------------
# BeiDou D1 subframes 1-3 (decode_beidou_d1); D2 pages frame by frame

_BDS = FieldTable({
    "sow1": _f(False, (0, 18, 8), (0, 30, 12)), "sow2": _f(False, (1, 18, 8), (1, 30, 12)),
    "sow3": _f(False, (2, 18, 8), (2, 30, 12)),
    "week": _f(False, (0, 60, 13)), "toc": _f(False, (0, 73, 9), (0, 90, 8)),
    "toe": _f(False, (1, 290, 2), (2, 42, 10), (2, 60, 5)), "urai": _f(False, (0, 48, 4)),
    "af0": _f(True, (0, 225, 7), (0, 240, 17)), "af1": _f(True, (0, 257, 5), (0, 270, 17)),
    "af2": _f(True, (0, 214, 11)), "iode": _f(False, (0, 287, 5)),
    "crs": _f(True, (1, 224, 8), (1, 240, 10)), "dn": _f(True, (1, 42, 10), (1, 60, 6)),
    "m0": _f(True, (1, 92, 20), (1, 120, 12)), "cuc": _f(True, (1, 66, 16), (1, 90, 2)),
    "e": _f(False, (1, 132, 10), (1, 150, 22)), "cus": _f(True, (1, 180, 18)),
    "sqrta": _f(False, (1, 250, 12), (1, 270, 20)), "cic": _f(True, (2, 105, 7), (2, 120, 11)),
    "omega0": _f(True, (2, 211, 21), (2, 240, 11)), "cis": _f(True, (2, 163, 9), (2, 180, 9)),
    "i0": _f(True, (2, 65, 17), (2, 90, 15)), "crc": _f(True, (1, 198, 4), (1, 210, 14)),
    "omega": _f(True, (2, 251, 11), (2, 270, 21)), "omegadot": _f(True, (2, 131, 11), (2, 150, 13)),
    "idot": _f(True, (2, 189, 13), (2, 210, 1)), "health": _f(False, (0, 42, 1)),
    "tgd": _f(True, (0, 98, 10)), "iodc": _f(False, (0, 43, 5)),
}, 300, 3)


def _bdt_nearest_week_s(week: np.ndarray, sow: np.ndarray, sow_v: np.ndarray) -> np.ndarray:
    """:func:`cdgps_cli.io.sfrbx._bdt_nearest_week_s` of arrays."""
    t_tx = bdt_to_gps_s(week, sow)
    t = bdt_to_gps_s(week, sow_v)
    return t + W_S * ((t_tx - t) / W_S).round()


def beidou_columns(bits: np.ndarray) -> tuple[dict, np.ndarray]:
    """:func:`~cdgps_cli.io.sfrbx.decode_beidou_d1` of many sets (``bits``: (m, 900), D1 subframes 1-3 in
    the logical layout; their FraIDs are 1, 2, 3 by construction)."""
    f = _BDS.values(bits)
    sow = f["sow1"]
    ok = (f["sow2"] == sow + 6) & (f["sow3"] == sow + 12)
    week = f["week"]
    toc, toe = f["toc"] * 8.0, f["toe"] * 8.0
    urai = f["urai"]
    pi = sf.GPS_PI
    cols = {
        "af0_s": f["af0"] * 2.0**-33, "af1_s_per_s": f["af1"] * 2.0**-50, "af2_s_per_s2": f["af2"] * 2.0**-66,
        "iode": f["iode"], "crs_m": f["crs"] * 2.0**-6, "delta_n_rad_per_s": f["dn"] * 2.0**-43 * pi,
        "m0_rad": f["m0"] * 2.0**-31 * pi, "cuc_rad": f["cuc"] * 2.0**-31, "e": f["e"] * 2.0**-33,
        "cus_rad": f["cus"] * 2.0**-31, "sqrt_a_sqrt_m": f["sqrta"] * 2.0**-19, "toe_sow_s": toe,
        "cic_rad": f["cic"] * 2.0**-31, "omega0_rad": f["omega0"] * 2.0**-31 * pi, "cis_rad": f["cis"] * 2.0**-31,
        "i0_rad": f["i0"] * 2.0**-31 * pi, "crc_m": f["crc"] * 2.0**-6, "omega_rad": f["omega"] * 2.0**-31 * pi,
        "omega_dot_rad_per_s": f["omegadot"] * 2.0**-43 * pi, "idot_rad_per_s": f["idot"] * 2.0**-43 * pi,
        "codes_l2": -1, "week": week, "l2p_data_flag": -1,
        "sv_accuracy_m": np.where(urai < 15, _URAI[np.minimum(urai, 14)], 12288.0),
        "sv_health": f["health"], "tgd_s": f["tgd"] * 1e-10, "iodc": f["iodc"],
        "transmit_sow_s": sow.astype(np.float64), "fit_interval_h": float("nan"), "line": -1,
        "transmit_gps_s": bdt_to_gps_s(week, sow), "toc_gps_s": _bdt_nearest_week_s(week, sow, toc),
        "toe_gps_s": _bdt_nearest_week_s(week, sow, toe),
    }
    return cols, ok


def _words30_bits(words: np.ndarray) -> np.ndarray:
    """uint8 0/1 (m, 300): the 30 bits of each of ten words (uint32, shape (m, 10))."""
    b = np.unpackbits(np.ascontiguousarray(words, dtype=">u4").view(np.uint8), axis=1).reshape(len(words), 10, 32)
    return b[:, :, 2:].reshape(len(words), 300)


def beidou_records(x: np.ndarray, off: np.ndarray, latest: dict, d2_recs: dict, stats: dict) -> dict | None:
    """The BeiDou D1 records of the ten-word RXM-SFRBX BeiDou frames starting at ``off`` (log order), with
    the walk's counters; GEO frames (D2 pages) go frame by frame into ``d2_recs`` (their ``latest``)."""
    w = np.ascontiguousarray(x[off[:, None] + np.arange(14, 54)]).view("<u4").reshape(off.size, 10)
    good, words = sf._beidou_bch_passes(w)
    words = words.astype(np.int64)
    for i in (~good).nonzero()[0].tolist():                 # de-interleaved words, frame by frame
        got = sf.beidou_words_from_sfrbx(w[i].tolist())
        if got is None:
            stats["beidou_bch_failures"] += 1
        else:
            words[i], good[i] = got, True
    sv = x[off + 7].astype(np.int64)
    geo = sf._BDS_GEO_BYTE[sv]                             # np.isin(sv, _BDS_GEO): sv is a byte
    for i in (good & geo).nonzero()[0].tolist():
        stats["beidou_d2_frames"] += 1
        sf._beidou_d2_page(words[i].tolist(), f"C{int(sv[i]):02d}", latest, d2_recs, stats)
    fid = (words[:, 0] >> 12) & 7
    use = (good & ~geo & (fid >= 1) & (fid <= 3)).nonzero()[0]
    stats["beidou_subframes"] += int(use.size)
    if not use.size:
        return None
    last = latest_of_type(sv[use], fid[use] - 1, 3)
    sets = last[(fid[use] == 3) & (last[:, 0] >= 0) & (last[:, 1] >= 0)]
    if not len(sets):
        return None
    bits = _words30_bits(words[use])
    cols, ok = beidou_columns(bits[sets].reshape(len(sets), 900))
    return _kept(sv[use][sets[:, 0]], "C", cols, ok)


# ---------------------------------------------------------------------------------------------

def records(data: bytes, off: np.ndarray, end: np.ndarray, week_ref: int | None, latest: dict,
            stats: dict) -> tuple[list, list]:
    """(column dicts of the GPS, QZSS, Galileo and BeiDou D1 records, BeiDou D2 records as dicts) of the frames
    ``data[off:end]`` that :func:`~cdgps_cli.io.sfrbx._stateful_mask` keeps, but GLONASS (log order)."""
    x = np.frombuffer(data, np.uint8)
    is_x = x[off + 3] == 0x13
    g = np.where(is_x, x[np.minimum(off + 6, x.size - 1)], 0)
    parts: list = []
    d2: dict = {}
    sel = off[g == 0]
    if sel.size:
        parts.append(gps_records(x, sel, week_ref, stats))
    sel = off[g == 5]
    if sel.size:
        parts.append(gps_records(x, sel, week_ref, stats, "J"))
    sel = off[g == 2]
    if sel.size:
        parts.append(galileo_records(x, sel, week_ref, stats))
    sel = off[g == 3]
    if sel.size:
        parts.append(beidou_records(x, sel, latest, d2, stats))
    return [p for p in parts if p is not None and p["sat"].size], list(d2.values())
