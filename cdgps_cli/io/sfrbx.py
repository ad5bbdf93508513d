"""GPS and Galileo broadcast ephemerides from the navigation data a u-blox receiver logs.

u-blox receivers log each navigation-data subframe they decode: RXM-SFRBX (class 0x02, id 0x13;
u-blox 8 and later) and the legacy RXM-SFRB (0x02, 0x11; u-blox 5/6).  This module turns the GPS
LNAV subframes 1–3 (IS-GPS-200 §20.3.2–20.3.3) into the same broadcast-ephemeris record the RINEX
navigation reader returns (:data:`cdgps_cli.core.records.NAV_COLUMNS`), so a u-blox pair needs no
separate navigation file.

* RXM-SFRBX, GPS L1 C/A (gnssId 0, sigId 0): ten 32-bit words, each holding one 30-bit navigation
  word in bits 29…0 (D1 at bit 29, D25–D30 the parity).  u-blox delivers the data bits
  polarity-corrected and the previous word's D29*, D30* in bits 31–30, so the parity (Table 20-XIV)
  is checked with those; failing that, with the previous word's last two bits and the data as they
  come or complemented by D30* (the IS-GPS-200 transmitted form).  A subframe with any word failing
  its parity is dropped and counted.  Frames of other GPS signals (sigId ≠ 0: L2C/L5 CNAV, no LNAV
  parity) are counted apart, not decoded.
* RXM-SFRB (legacy), GPS: ten 32-bit words of 24 data bits (parity already removed by the
  receiver, so no parity check is possible).

* RXM-SFRBX, Galileo (gnssId 2): an I/NAV page pair (E1-B or E5b-I) in eight words; word types
  1–5 (ephemeris, clock, SISA, BGD, health, GST week) give one record, see
  :func:`decode_galileo_words` for how its fields map onto the RINEX 3 Galileo layout.  A page
  pair failing its CRC-24Q is dropped and counted.  Frames of E5a (F/NAV) and E6 (C/NAV) — sigId
  other than 0, 1, 5 or not eight words — are counted apart, not decoded.
* RXM-SFRBX, BeiDou (gnssId 3): ten words, each one 30-bit D1 word in bits 29…0 (the two MSBs are
  padding; u-blox integration manuals, "BeiDou": words in the order received, secondary code
  removed).  Words are read in the ICD's logical layout — 22 information bits, then the 4 parity
  bits of each BCH(15,11) codeword — and, when that fails the check, as transmitted (the two
  codewords interleaved bit by bit), so either convention is read; inverted bits are recognised
  by the inverted preamble.  A subframe with a codeword failing BCH(15,11) (g(X) = X⁴ + X + 1) is
  dropped and counted (no single-bit correction: a corrupted word is never turned into a wrong
  value).  Subframes 1–3 of the D1 message (MEO/IGSO satellites) of one 30-s frame (SOW, SOW + 6,
  SOW + 12) give one record, :func:`decode_beidou_d1`.  GEO satellites broadcast D2: pages 1 and
  3–10 of subframe 1 of one 30 s cycle give one record, :func:`decode_beidou_d2` (checked against an
  encoder only: no real D2 log at hand).  Frames of other word counts (B-CNAV1/2/3 of B1C,
  B2a, B2b: not D1/D2).

GPS subframes of one satellite are combined when subframes 2 and 3 carry the same IODE and it
equals the 8 LSBs of subframe 1's IODC (IS-GPS-200 §20.3.4.4: a consistent data set).  The
10-bit week number is completed with the reference week given (the RXM-RAWX week of the log).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cdgps_cli.core.gps_time import bdt_to_gps_s
from cdgps_cli.core.records import GLONASS_NAV_COLUMNS, NAV_COLUMNS
from cdgps_cli.io.rinex import _frame, qzss_fit_interval_h
from cdgps_cli.io.sfrbx_glonass import glonass_frame

__all__ = ["GPS_PI", "URA_M", "BDS_PREAMBLE", "bch15_syndrome", "beidou_words_from_sfrbx", "decode_beidou_d1",
           "decode_beidou_d2", "decode_galileo_words", "decode_gps_subframes", "inav_word", "gps_words_from_sfrbx", "parity_ok", "sfrbx_ephemerides",
           "sfrbx_ephemerides_at"]

GPS_PI = 3.1415926535898
"""The value of π IS-GPS-200 fixes for converting semicircles to radians."""
URA_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0)
"""Nominal user range accuracy (m) of URA index 0…14 (IS-GPS-200 §20.3.3.3.1.3); index 15: no accuracy."""
PREAMBLE = 0x8B
SECONDS_PER_WEEK = 604800.0

# IS-GPS-200 Table 20-XIV: the data bits d1…d24 entering each parity bit D25…D30, and which of
# the previous word's D29*/D30* enters it
_PARITY = (
    (29, (1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23)),
    (30, (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24)),
    (29, (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22)),
    (30, (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23)),
    (30, (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24)),
    (29, (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24)),
)
_PARITY_MASKS = tuple((prev, sum(1 << (24 - b) for b in bits)) for prev, bits in _PARITY)


def parity_bits(data24: int, d29_prev: int, d30_prev: int) -> int:
    """The six parity bits D25…D30 (as an int, D25 the MSB) of 24 source data bits d1…d24
    (``data24``, d1 the MSB) after a word ending in D29*, D30*."""
    out = 0
    for prev, mask in _PARITY_MASKS:
        bit = (d29_prev if prev == 29 else d30_prev) ^ ((data24 & mask).bit_count() & 1)
        out = (out << 1) | bit
    return out


def parity_ok(word30: int, d29_prev: int, d30_prev: int) -> int | None:
    """The source data bits of a 30-bit word if its parity holds, else None.

    Tries the bits as given and complemented by D30* (IS-GPS-200: transmitted d_i = source d_i ⊕ D30*).
    """
    d = (word30 >> 6) & 0xFFFFFF
    p = word30 & 0x3F
    for data in ((d ^ 0xFFFFFF) if d30_prev else d, d):
        if parity_bits(data, d29_prev, d30_prev) == p:
            return data
    return None


def gps_words_from_sfrbx(dwrd: list[int]) -> list[int] | None:
    """The 24-bit source data words of an RXM-SFRBX GPS subframe (ten 30-bit words), or None when
    a word fails its parity.

    u-blox 8/9 receivers deliver the data bits already polarity-corrected (the source bits) and put
    the previous word's D29*, D30* — which every parity equation needs — in bits 31–30 of each word:
    that form is tried first (all 5 440 L1 C/A subframes of the real M8/F9/X20 logs checked pass it,
    none passes the chain below).  Otherwise the ICD chain: D29*, D30* from the previous word's bits
    1–0 (word 10 of the previous subframe has D29 = D30 = 0 by design, IS-GPS-200 §20.3.5.2), data as
    delivered or complemented by D30*.
    """
    out = []
    for w in dwrd:
        data = (w >> 6) & 0xFFFFFF
        if parity_bits(data, (w >> 31) & 1, (w >> 30) & 1) != w & 0x3F:
            break
        out.append(data)
    else:
        return out
    out = []
    d29 = d30 = 0
    for w in dwrd:
        w &= 0x3FFFFFFF
        data = parity_ok(w, d29, d30)
        if data is None:
            return None
        out.append(data)
        d29, d30 = (w >> 1) & 1, w & 1
    return out


def _dated(rec: dict, week: int, transmit_sow_s: float, toc_sow_s: float, toe_sow_s: float) -> dict:
    """``rec`` with ``transmit_gps_s``, ``toc_gps_s``, ``toe_gps_s`` (GPS s): seconds of the week
    of ``week``, toc and toe taken in the week nearest the transmission (a toe early in the next
    week is sent at the end of this one)."""
    rec["transmit_gps_s"] = week * SECONDS_PER_WEEK + transmit_sow_s
    rec["toc_gps_s"] = _nearest_week_s(week, transmit_sow_s, toc_sow_s)
    rec["toe_gps_s"] = _nearest_week_s(week, transmit_sow_s, toe_sow_s)
    return rec


def _nearest_week_s(week: int, transmit_sow_s: float, sow_s: float) -> float:
    """GPS s of the second of week ``sow_s`` in the week nearest the transmission at ``transmit_sow_s``
    of ``week`` (toc, toe: :func:`_dated`)."""
    base = week * SECONDS_PER_WEEK
    t_tx = base + transmit_sow_s
    return base + sow_s + SECONDS_PER_WEEK * round((t_tx - base - sow_s) / SECONDS_PER_WEEK)


def _gps_record_key(sf1: list[int], sf2: list[int], sf3: list[int], week_ref: int) -> tuple[float, int] | None:
    """(``toe_gps_s``, ``iode``) of the record :func:`decode_gps_subframes` makes of these subframes, read
    from the few words that hold them (None where it returns None): a record already kept under that key
    need not be decoded again."""
    w1, w2, w3 = sf1[1] & 0xFFFFFF, sf1[2] & 0xFFFFFF, sf1[7] & 0xFFFFFF
    iode = (sf2[2] & 0xFFFFFF) >> 16
    if (sf3[9] & 0xFFFFFF) >> 16 != iode or w3 >> 16 != iode:
        return None
    wn10 = w2 >> 14
    week = wn10 + 1024 * round((week_ref - wn10) / 1024)
    return _nearest_week_s(week, (w1 >> 7) * 6.0 - 6.0, ((sf2[9] & 0xFFFFFF) >> 8) * 16.0), iode


def _galileo_record_key(words: dict, week_ref: int) -> tuple[float, int] | None:
    """(``toe_gps_s``, ``iode``) of the record :func:`decode_galileo_words` makes of ``words`` (None where
    it returns None), from word types 1 and 5 and the IODnav of 2-4."""
    if not all(k in words for k in (1, 2, 3, 4, 5)):
        return None
    w1, w5 = _Word(words[1]), _Word(words[5])
    iod = w1.u(6, 10)
    if any(_Word(words[k]).u(6, 10) != iod for k in (2, 3, 4)):
        return None
    wn = w5.u(73, 12) + 1024
    week = wn + 4096 * round((week_ref - wn) / 4096)
    return _nearest_week_s(week, float(w5.u(85, 20)), w1.u(16, 14) * 60.0), iod


class _Fields:
    """Unsigned/two's-complement fields of a ``width``-bit message held as an int, bits numbered from 0."""

    def __init__(self, v: int, width: int):
        self.v, self.width = v, width

    def u(self, start: int, n: int) -> int:
        return (self.v >> (self.width - start - n)) & ((1 << n) - 1)

    def s(self, start: int, n: int) -> int:
        x = self.u(start, n)
        return x - (1 << n) if x >> (n - 1) else x


def _Bits(words24: list[int]) -> _Fields:
    """The 240 data bits of a GPS subframe (ten words of 24 bits)."""
    v = 0
    for w in words24:
        v = (v << 24) | (w & 0xFFFFFF)
    return _Fields(v, 240)


def subframe_id(words24: list[int]) -> int:
    """The subframe ID of the HOW (word 2 bits 20–22), 0 when word 1 lacks the preamble."""
    return (words24[1] >> 2) & 7 if (words24[0] >> 16) & 0xFF == PREAMBLE else 0


def decode_gps_subframes(sf1: list[int], sf2: list[int], sf3: list[int], sat: str, week_ref: int) -> dict | None:
    """One broadcast ephemeris from the 24-bit data words of GPS LNAV subframes 1, 2 and 3.

    Parameters
    ----------
    sf1, sf2, sf3 : list of 10 int
        Source data bits d1…d24 of each word (d1 the MSB).
    sat : str
        Satellite ("G05").
    week_ref : int
        A full GPS week near the data (the 10-bit week number is completed to the nearest).

    Returns
    -------
    dict or None
        The record with the keys of :data:`NAV_COLUMNS` (``line`` = −1), in the RINEX reader's
        units (s, m, rad, rad/s); None when the three subframes are not one data set (IODE/IODC).
    """
    b1, b2, b3 = _Bits(sf1), _Bits(sf2), _Bits(sf3)
    iodc = (b1.u(70, 2) << 8) | b1.u(168, 8)
    iode = b2.u(48, 8)
    if b3.u(216, 8) != iode or (iodc & 0xFF) != iode:
        return None
    wn10 = b1.u(48, 10)
    week = wn10 + 1024 * round((week_ref - wn10) / 1024)
    tow_sf1 = b1.u(24, 17) * 6.0 - 6.0          # HOW: TOW of the next subframe's start
    toc = b1.u(176, 16) * 16.0
    toe = b2.u(216, 16) * 16.0
    ura = b1.u(60, 4)
    rec = {
        "sat": sat,
        "af0_s": b1.s(216, 22) * 2.0**-31,
        "af1_s_per_s": b1.s(200, 16) * 2.0**-43,
        "af2_s_per_s2": b1.s(192, 8) * 2.0**-55,
        "iode": iode,
        "crs_m": b2.s(56, 16) * 2.0**-5,
        "delta_n_rad_per_s": b2.s(72, 16) * 2.0**-43 * GPS_PI,
        "m0_rad": b2.s(88, 32) * 2.0**-31 * GPS_PI,
        "cuc_rad": b2.s(120, 16) * 2.0**-29,
        "e": b2.u(136, 32) * 2.0**-33,
        "cus_rad": b2.s(168, 16) * 2.0**-29,
        "sqrt_a_sqrt_m": b2.u(184, 32) * 2.0**-19,
        "toe_sow_s": toe,
        "cic_rad": b3.s(48, 16) * 2.0**-29,
        "omega0_rad": b3.s(64, 32) * 2.0**-31 * GPS_PI,
        "cis_rad": b3.s(96, 16) * 2.0**-29,
        "i0_rad": b3.s(112, 32) * 2.0**-31 * GPS_PI,
        "crc_m": b3.s(144, 16) * 2.0**-5,
        "omega_rad": b3.s(160, 32) * 2.0**-31 * GPS_PI,
        "omega_dot_rad_per_s": b3.s(192, 24) * 2.0**-43 * GPS_PI,
        "idot_rad_per_s": b3.s(224, 14) * 2.0**-43 * GPS_PI,
        "codes_l2": b1.u(58, 2),
        "week": week,
        "l2p_data_flag": b1.u(72, 1),
        "sv_accuracy_m": URA_M[ura] if ura < len(URA_M) else 6144.0 * 2,
        "sv_health": b1.u(64, 6),
        "tgd_s": b1.s(160, 8) * 2.0**-31,
        "iodc": iodc,
        "transmit_sow_s": tow_sf1,
        "fit_interval_h": (float(qzss_fit_interval_h(b2.u(232, 1))) if sat[:1] == "J"
                           else 4.0 if b2.u(232, 1) == 0 else 6.0),
        "line": -1,
    }
    return _dated(rec, week, tow_sf1, toc, toe)


# ---------------------------------------------------------------------------------------------
# Galileo I/NAV (E1-B or E5b-I): word types 1-5, Galileo OS SIS ICD §4.3.5

def _sisa_m(index: int) -> float:
    """Signal-in-space accuracy (m) of a SISA index (Galileo OS SIS ICD Table 89); NaN: no accuracy."""
    if index < 50:
        return index * 0.01
    if index < 75:
        return 0.5 + (index - 50) * 0.02
    if index < 100:
        return 1.0 + (index - 75) * 0.04
    if index < 126:
        return 2.0 + (index - 100) * 0.16
    return float("nan")


def inav_word(dwrd: list[int]) -> tuple[int, int] | None:
    """The 128-bit I/NAV word of an RXM-SFRBX Galileo page pair, as (word type, int), or None.

    u-blox delivers the even page in words 0-3 (bit 0 even/odd = 0, page type, 112 data bits,
    6 tail bits, 8 pad bits) and the odd page in words 4-7 (even/odd = 1, page type, 16 data bits,
    64 reserved/SAR/spare bits, CRC-24Q, …).  The pair is accepted when the even/odd flags are
    right, neither page is an alert page and the CRC over even bits 0-113 + odd bits 0-81 holds.
    """
    from cdgps_cli.io.ubx_frames import crc24q  # noqa: PLC0415

    if len(dwrd) < 8:
        return None
    v = 0
    for w in dwrd[:8]:
        v = (v << 32) | (w & 0xFFFFFFFF)
    even, odd = v >> 128, v & ((1 << 128) - 1)

    def bits(x, start, n):
        return (x >> (128 - start - n)) & ((1 << n) - 1)

    if bits(even, 0, 1) != 0 or bits(odd, 0, 1) != 1 or bits(even, 1, 1) or bits(odd, 1, 1):
        return None
    covered = (bits(even, 0, 114) << 82) | bits(odd, 0, 82)          # 196 bits, padded to 200 in front
    if crc24q(covered.to_bytes(25, "big")) != bits(odd, 82, 24):
        return None
    word = (bits(even, 2, 112) << 16) | bits(odd, 2, 16)
    return word >> 122, word


def inav_words(dwrd: np.ndarray) -> list:
    """:func:`inav_word` of many page pairs at once.

    Parameters
    ----------
    dwrd : uint32 array, shape (m, 8)
        The eight data words of each RXM-SFRBX Galileo I/NAV payload.

    Returns
    -------
    list of (word type, int) or None
        One per row, as :func:`inav_word` gives it (flags, alert bits and CRC-24Q checked as bit
        columns, :func:`cdgps_cli.io.sfrbx_batch.inav_bits`).
    """
    from cdgps_cli.io.sfrbx_batch import inav_bits  # noqa: PLC0415 (it imports this module)

    m = len(dwrd)
    if not m:
        return []
    ok, bits = inav_bits(dwrd)
    words = np.packbits(bits, axis=1)
    out: list = [None] * m
    for i in np.flatnonzero(ok).tolist():
        w = int.from_bytes(words[i].tobytes(), "big")
        out[i] = (w >> 122, w)
    return out


def _Word(v: int) -> _Fields:
    """Fields of a 128-bit I/NAV word (the word type is bits 0-5)."""
    return _Fields(v, 128)


def decode_galileo_words(words: dict, sat: str, week_ref: int) -> dict | None:
    """One Galileo broadcast ephemeris from I/NAV word types 1-5 of one satellite.

    Parameters
    ----------
    words : dict
        Word type (1…5) → 128-bit word (:func:`inav_word`).
    sat : str
        Satellite ("E11").
    week_ref : int
        A GPS week near the data (GST week = GPS week − 1024; the 12-bit WN is completed).

    Returns
    -------
    dict or None
        A record with the keys of :data:`NAV_COLUMNS`, in the RINEX 3 Galileo layout where it
        fits: ``iode`` = IODnav, ``codes_l2`` = data sources (513: I/NAV, clock for E5b/E1),
        ``week`` = GST week + 1024 (continuous with GPS weeks, as RINEX writes it),
        ``sv_accuracy_m`` = SISA, ``sv_health`` = RINEX bit layout (E1-B DVS bit 0, E1-B HS bits
        1-2, E5b DVS bit 6, E5b HS bits 7-8); **``tgd_s`` = BGD(E1, E5b)** — the group delay an E1
        single-frequency user of the I/NAV clock subtracts, not RINEX's BGD(E1, E5a) slot —
        and ``iodc`` = IODnav.  None when the IODnav of words 1-4 differ or a word is missing.
    """
    if not all(k in words for k in (1, 2, 3, 4, 5)):
        return None
    w1, w2, w3, w4, w5 = (_Word(words[k]) for k in (1, 2, 3, 4, 5))
    iod = w1.u(6, 10)
    if any(w.u(6, 10) != iod for w in (w2, w3, w4)):
        return None
    wn = w5.u(73, 12) + 1024
    week = wn + 4096 * round((week_ref - wn) / 4096)
    tow = w5.u(85, 20)
    toe, toc = w1.u(16, 14) * 60.0, w4.u(54, 14) * 60.0
    health = (w5.u(72, 1) | (w5.u(69, 2) << 1) | (w5.u(71, 1) << 6) | (w5.u(67, 2) << 7))
    rec = {
        "sat": sat, "af0_s": w4.s(68, 31) * 2.0**-34, "af1_s_per_s": w4.s(99, 21) * 2.0**-46,
        "af2_s_per_s2": w4.s(120, 6) * 2.0**-59, "iode": iod,
        "crs_m": w3.s(104, 16) * 2.0**-5, "delta_n_rad_per_s": w3.s(40, 16) * 2.0**-43 * GPS_PI,
        "m0_rad": w1.s(30, 32) * 2.0**-31 * GPS_PI, "cuc_rad": w3.s(56, 16) * 2.0**-29,
        "e": w1.u(62, 32) * 2.0**-33, "cus_rad": w3.s(72, 16) * 2.0**-29, "sqrt_a_sqrt_m": w1.u(94, 32) * 2.0**-19,
        "toe_sow_s": toe, "cic_rad": w4.s(22, 16) * 2.0**-29, "omega0_rad": w2.s(16, 32) * 2.0**-31 * GPS_PI,
        "cis_rad": w4.s(38, 16) * 2.0**-29, "i0_rad": w2.s(48, 32) * 2.0**-31 * GPS_PI,
        "crc_m": w3.s(88, 16) * 2.0**-5, "omega_rad": w2.s(80, 32) * 2.0**-31 * GPS_PI,
        "omega_dot_rad_per_s": w3.s(16, 24) * 2.0**-43 * GPS_PI, "idot_rad_per_s": w2.s(112, 14) * 2.0**-43 * GPS_PI,
        "codes_l2": 513, "week": week, "l2p_data_flag": 0, "sv_accuracy_m": _sisa_m(w3.u(120, 8)),
        "sv_health": health, "tgd_s": w5.s(57, 10) * 2.0**-32, "iodc": iod, "transmit_sow_s": float(tow),
        "fit_interval_h": float("nan"), "line": -1,
    }
    return _dated(rec, week, float(tow), toc, toe)


# ---------------------------------------------------------------------------------------------
# BeiDou D1 (B1I, MEO/IGSO): subframes 1-3, BDS-ICD-B1I 3.0 §5.2

BDS_PREAMBLE = 0b11100010010
"""The 11-bit preamble of every BeiDou D1/D2 subframe."""
_BDS_GEO = frozenset((1, 2, 3, 4, 5, 59, 60, 61, 62, 63))
_BDS_GEO_BYTE = np.isin(np.arange(256), sorted(_BDS_GEO))
"""Whether a byte value (svId) is one of :data:`_BDS_GEO` (a look-up table)."""
_URAI_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0)


def _bch15_syndrome_division(codeword15: int) -> int:
    """:func:`bch15_syndrome` by polynomial long division (builds the table, and checks it in the tests)."""
    r = codeword15 & 0x7FFF
    for k in range(14, 3, -1):
        if r >> k & 1:
            r ^= 0b10011 << (k - 4)
    return r


def _bch15_table() -> np.ndarray:
    """Syndromes of all 2^15 codewords: the remainder is linear over GF(2), so each is the XOR of
    the remainders of its set bits."""
    v = np.arange(1 << 15, dtype=np.int32)
    table = np.zeros(1 << 15, dtype=np.int32)
    for k in range(15):
        table ^= ((v >> k) & 1) * _bch15_syndrome_division(1 << k)
    return table.astype(np.uint8)


_BCH15_TABLE = _bch15_table()
_BCH15_SYNDROME = _BCH15_TABLE.tolist()


def bch15_syndrome(codeword15: int) -> int:
    """Remainder of a 15-bit codeword (first bit = coefficient of X¹⁴) divided by g(X) = X⁴ + X + 1;
    0 for a valid BCH(15,11) codeword (a table look-up)."""
    return _BCH15_SYNDROME[codeword15 & 0x7FFF]


def _bch_ok(word30: int, first: bool) -> bool:
    """The codeword(s) of one word in the logical layout pass BCH(15,11)."""
    if first:
        return bch15_syndrome(word30 & 0x7FFF) == 0
    cw1 = ((word30 >> 19) & 0x7FF) << 4 | ((word30 >> 4) & 0xF)
    cw2 = ((word30 >> 8) & 0x7FF) << 4 | (word30 & 0xF)
    return bch15_syndrome(cw1) == 0 and bch15_syndrome(cw2) == 0


def _deinterleave(word30: int) -> int:
    """Transmitted order (codeword bits alternating, first codeword first) → logical layout
    (11 + 11 information bits, 4 + 4 parity bits)."""
    bits = [(word30 >> (29 - k)) & 1 for k in range(30)]
    c1, c2 = bits[0::2], bits[1::2]
    out = 0
    for b in c1[:11] + c2[:11] + c1[11:] + c2[11:]:
        out = out << 1 | b
    return out


def beidou_words_from_sfrbx(dwrd: list[int]) -> list[int] | None:
    """The ten 30-bit D1/D2 words of an RXM-SFRBX BeiDou subframe in the logical layout, or None
    when the preamble is absent or a BCH(15,11) codeword fails (in both word layouts)."""
    if len(dwrd) < 10:
        return None
    words = [w & 0x3FFFFFFF for w in dwrd[:10]]
    if words[0] >> 19 == BDS_PREAMBLE ^ 0x7FF:
        words = [w ^ 0x3FFFFFFF for w in words]
    if words[0] >> 19 != BDS_PREAMBLE or not _bch_ok(words[0], True):
        return None
    out = [words[0]]
    for w in words[1:]:
        if not _bch_ok(w, False):
            w = _deinterleave(w)
            if not _bch_ok(w, False):
                return None
        out.append(w)
    return out


class _D1(_Fields):
    """Fields of a 300-bit D1 subframe; ``u2``/``s2`` join a field split over two words."""

    def __init__(self, words30: list[int]):
        v = 0
        for w in words30:
            v = (v << 30) | w
        super().__init__(v, 300)

    def u2(self, a: int, na: int, b: int, nb: int) -> int:
        return self.u(a, na) << nb | self.u(b, nb)

    def s2(self, a: int, na: int, b: int, nb: int) -> int:
        x = self.u2(a, na, b, nb)
        n = na + nb
        return x - (1 << n) if x >> (n - 1) else x


def d1_subframe_id(words30: list[int]) -> tuple[int, int]:
    """(FraID, SOW s) of a D1 subframe in the logical layout."""
    f = _D1(words30)
    return f.u(15, 3), f.u2(18, 8, 30, 12)


def decode_beidou_d1(sf1: list[int], sf2: list[int], sf3: list[int], sat: str) -> dict | None:
    """One BeiDou broadcast ephemeris from D1 subframes 1, 2, 3 (BDS-ICD-B1I 3.0 §5.2.4).

    Parameters
    ----------
    sf1, sf2, sf3 : list of 10 int
        30-bit words in the logical layout (:func:`beidou_words_from_sfrbx`).
    sat : str
        Satellite ("C11").

    Returns
    -------
    dict or None
        The record with the keys of :data:`NAV_COLUMNS` in the RINEX reader's BeiDou layout
        (BDT week and seconds of week in ``week``/``toe_sow_s``/``transmit_sow_s``; GPS seconds in
        ``toc_gps_s``/``toe_gps_s``/``transmit_gps_s``; ``iode`` = AODE, ``iodc`` = AODC,
        ``tgd_s`` = TGD1, ``sv_health`` = SatH1), or None when the subframes are not 1, 2, 3 of
        one frame (SOW, SOW + 6, SOW + 12).
    """
    b1, b2, b3 = _D1(sf1), _D1(sf2), _D1(sf3)
    ids = [d1_subframe_id(w) for w in (sf1, sf2, sf3)]
    sow = ids[0][1]
    if [i for i, _ in ids] != [1, 2, 3] or ids[1][1] != sow + 6 or ids[2][1] != sow + 12:
        return None
    week = b1.u(60, 13)
    toc = b1.u2(73, 9, 90, 8) * 8.0
    toe = (b2.u(290, 2) << 15 | b3.u2(42, 10, 60, 5)) * 8.0
    urai = b1.u(48, 4)
    pi = GPS_PI
    rec = {
        "sat": sat, "af0_s": b1.s2(225, 7, 240, 17) * 2.0**-33, "af1_s_per_s": b1.s2(257, 5, 270, 17) * 2.0**-50,
        "af2_s_per_s2": b1.s(214, 11) * 2.0**-66, "iode": b1.u(287, 5),
        "crs_m": b2.s2(224, 8, 240, 10) * 2.0**-6, "delta_n_rad_per_s": b2.s2(42, 10, 60, 6) * 2.0**-43 * pi,
        "m0_rad": b2.s2(92, 20, 120, 12) * 2.0**-31 * pi, "cuc_rad": b2.s2(66, 16, 90, 2) * 2.0**-31,
        "e": b2.u2(132, 10, 150, 22) * 2.0**-33, "cus_rad": b2.s(180, 18) * 2.0**-31,
        "sqrt_a_sqrt_m": b2.u2(250, 12, 270, 20) * 2.0**-19, "toe_sow_s": toe,
        "cic_rad": b3.s2(105, 7, 120, 11) * 2.0**-31, "omega0_rad": b3.s2(211, 21, 240, 11) * 2.0**-31 * pi,
        "cis_rad": b3.s2(163, 9, 180, 9) * 2.0**-31, "i0_rad": b3.s2(65, 17, 90, 15) * 2.0**-31 * pi,
        "crc_m": b2.s2(198, 4, 210, 14) * 2.0**-6, "omega_rad": b3.s2(251, 11, 270, 21) * 2.0**-31 * pi,
        "omega_dot_rad_per_s": b3.s2(131, 11, 150, 13) * 2.0**-43 * pi,
        "idot_rad_per_s": b3.s2(189, 13, 210, 1) * 2.0**-43 * pi,
        "codes_l2": -1, "week": week, "l2p_data_flag": -1, "sv_accuracy_m": _URAI_M[urai] if urai < 15 else 12288.0,
        "sv_health": b1.u(42, 1), "tgd_s": b1.s(98, 10) * 1e-10, "iodc": b1.u(43, 5), "transmit_sow_s": float(sow),
        "fit_interval_h": float("nan"), "line": -1,
    }
    return _record_dates(rec, week, sow, toc, toe)


def d2_page_number(words30: list[int]) -> int:
    """Page number (Pnum, 4 bits) of a D2 subframe 1 page in the logical layout."""
    return _D1(words30).u(42, 4)


def _record_dates(rec: dict, week: int, sow: int, toc: float, toe: float) -> dict:
    """``rec`` with ``transmit_gps_s``, ``toc_gps_s``, ``toe_gps_s`` from BDT week, SOW, toc, toe (s)."""
    rec["transmit_gps_s"] = float(bdt_to_gps_s(week, sow))
    for key, sow_v in (("toc_gps_s", toc), ("toe_gps_s", toe)):
        rec[key] = _bdt_nearest_week_s(week, sow, sow_v)
    return rec


def _bdt_nearest_week_s(week: int, sow: int, sow_v: float) -> float:
    """GPS s of BDT second of week ``sow_v`` in the week nearest the transmission at ``sow`` of ``week``."""
    t_tx = float(bdt_to_gps_s(week, sow))
    t = float(bdt_to_gps_s(week, sow_v))
    return t + SECONDS_PER_WEEK * round((t_tx - t) / SECONDS_PER_WEEK)


def _beidou_record_key(sf1: list[int], sf2: list[int], sf3: list[int]) -> tuple[float, int] | None:
    """(``toe_gps_s``, ``iode``) of the record :func:`decode_beidou_d1` makes of these subframes (None where
    it returns None): a record already kept under that key need not be decoded again."""
    b1, b2, b3 = _D1(sf1), _D1(sf2), _D1(sf3)
    ids = [(b.u(15, 3), b.u2(18, 8, 30, 12)) for b in (b1, b2, b3)]   # d1_subframe_id
    sow = ids[0][1]
    if [i for i, _ in ids] != [1, 2, 3] or ids[1][1] != sow + 6 or ids[2][1] != sow + 12:
        return None
    toe = (b2.u(290, 2) << 15 | b3.u2(42, 10, 60, 5)) * 8.0
    return _bdt_nearest_week_s(b1.u(60, 13), sow, toe), b1.u(287, 5)


def decode_beidou_d2(pages: dict, sat: str) -> dict | None:
    """One BeiDou GEO ephemeris from D2 subframe 1, pages 1 and 3–10 (BDS-ICD-B1I 3.0 §5.3.3; the
    field positions are those of RTKLIB's ``decode_bds_d2``, bits counted from 0 in the 300-bit
    logical page: the 22 information bits of each word followed by its parity).

    Parameters
    ----------
    pages : dict
        Page number → ten 30-bit words in the logical layout (:func:`beidou_words_from_sfrbx`).
    sat : str
        Satellite ("C03").

    Returns
    -------
    dict or None
        The record (layout of :func:`decode_beidou_d1`), or None when a page is missing, a page is
        not of subframe 1, the SOWs are not those of one 30 s cycle (page 1 at SOW, page k ≥ 3 at
        SOW + 3(k − 1)) or toc ≠ toe.
    """
    if not all(k in pages for k in (1, *range(3, 11))):
        return None
    f = {k: _D1(pages[k]) for k in (1, *range(3, 11))}
    ids = {k: d1_subframe_id(pages[k]) for k in f}
    sow = ids[1][1]
    if any(i != 1 or d2_page_number(pages[k]) != k or s_ != sow + 3 * (k - 1) for k, (i, s_) in ids.items()):
        return None

    def joined(parts, signed):
        """Fields split over pages: (page, start, bits, …) msb part first → int."""
        v, n = 0, 0
        for k, a, na, *rest in parts:
            pieces = [(a, na), *zip(rest[::2], rest[1::2])]
            for st, nb in pieces:
                v, n = v << nb | f[k].u(st, nb), n + nb
        return v - (1 << n) if signed and v >> (n - 1) else v

    toc = f[1].u2(77, 5, 90, 12) * 8.0
    toe = f[7].u2(80, 2, 90, 15) * 8.0
    if toc != toe:
        return None
    pi, urai, week = GPS_PI, f[1].u(60, 4), f[1].u(64, 13)
    rec = {
        "sat": sat, "af0_s": f[3].s2(100, 12, 120, 12) * 2.0**-33,
        "af1_s_per_s": joined([(3, 132, 4), (4, 46, 6, 60, 12)], True) * 2.0**-50,
        "af2_s_per_s2": f[4].s2(72, 10, 90, 1) * 2.0**-66, "iode": f[4].u(91, 5),
        "crs_m": f[8].s(91, 18) * 2.0**-6, "delta_n_rad_per_s": f[4].s(96, 16) * 2.0**-43 * pi,
        "m0_rad": joined([(5, 50, 2, 60, 22, 90, 8)], True) * 2.0**-31 * pi,
        "cuc_rad": joined([(4, 120, 14), (5, 46, 4)], True) * 2.0**-31,
        "e": joined([(5, 124, 10), (6, 46, 6, 60, 16)], False) * 2.0**-33,
        "cus_rad": f[5].s2(98, 14, 120, 4) * 2.0**-31,
        "sqrt_a_sqrt_m": joined([(6, 76, 6, 90, 22, 120, 4)], False) * 2.0**-19, "toe_sow_s": toe,
        "cic_rad": joined([(6, 124, 10), (7, 46, 6, 60, 2)], True) * 2.0**-31,
        "omega0_rad": joined([(9, 51, 1, 60, 22, 90, 9)], True) * 2.0**-31 * pi,
        "cis_rad": f[7].s(62, 18) * 2.0**-31,
        "i0_rad": joined([(7, 105, 7, 120, 14), (8, 46, 6, 60, 5)], True) * 2.0**-31 * pi,
        "crc_m": f[8].s2(65, 17, 90, 1) * 2.0**-6,
        "omega_rad": joined([(9, 99, 13, 120, 14), (10, 46, 5)], True) * 2.0**-31 * pi,
        "omega_dot_rad_per_s": joined([(8, 109, 3, 120, 16), (9, 46, 5)], True) * 2.0**-43 * pi,
        "idot_rad_per_s": f[10].s2(51, 1, 60, 13) * 2.0**-43 * pi,
        "codes_l2": -1, "week": week, "l2p_data_flag": -1, "sv_accuracy_m": _URAI_M[urai] if urai < 15 else 12288.0,
        "sv_health": f[1].u(46, 1), "tgd_s": f[1].s(102, 10) * 1e-10, "iodc": f[1].u(47, 5),
        "transmit_sow_s": float(sow), "fit_interval_h": float("nan"), "line": -1,
    }
    return _record_dates(rec, week, sow, toc, toe)


def _beidou_d2_page(words: list[int], sat: str, latest: dict, recs: dict, stats: dict) -> None:
    """Keep a D2 subframe-1 page; decode when page 10 completes a cycle."""
    fid, _ = d1_subframe_id(words)
    if fid != 1:
        return
    pn = d2_page_number(words)
    if not 1 <= pn <= 10:
        return
    stats["beidou_d2_pages"] += 1
    have = latest.setdefault(sat + ":D2", {})
    have[pn] = words
    if pn == 10:
        rec = decode_beidou_d2(have, sat)
        if rec is not None and 0 <= rec["e"] < 1 and rec["sqrt_a_sqrt_m"] > 0:
            recs.setdefault((sat, rec["toe_gps_s"], rec["iode"]), rec)


def _beidou_frame(pl: bytes, sv: int, latest: dict, recs: dict, stats: dict, checked: list | None = None) -> None:
    """One RXM-SFRBX BeiDou payload: check, keep the subframe, decode when 1-3 of a frame are in
    (``checked``: its words when :func:`_checked_words` already passed them)."""
    if pl[4] != 10:
        stats["beidou_cnav_frames"] += 1
        return
    words = checked if checked is not None else beidou_words_from_sfrbx(np.frombuffer(pl[8:48], dtype="<u4").tolist())
    if words is None:
        stats["beidou_bch_failures"] += 1
        return
    if sv in _BDS_GEO:
        stats["beidou_d2_frames"] += 1
        _beidou_d2_page(words, f"C{sv:02d}", latest, recs, stats)
        return
    fid = (words[0] >> 12) & 7                              # FraID, bits 15-17: d1_subframe_id without its SOW
    if fid not in (1, 2, 3):
        return
    stats["beidou_subframes"] += 1
    sat = f"C{sv:02d}"
    have = latest.setdefault(sat, {})
    have[fid] = words
    if fid == 3 and all(k in have for k in (1, 2)):
        key = _beidou_record_key(have[1], have[2], have[3])
        if key is None or (sat, *key) in recs:             # not one frame, or a record already kept
            return
        rec = decode_beidou_d1(have[1], have[2], have[3], sat)
        if rec is not None and 0 <= rec["e"] < 1 and rec["sqrt_a_sqrt_m"] > 0:
            recs.setdefault((sat, rec["toe_gps_s"], rec["iode"]), rec)


_INAV_SIGNALS = frozenset((0, 1, 5))
_INAV_SIGNAL_BYTE = np.isin(np.arange(256), sorted(_INAV_SIGNALS))
"""Whether a byte value is one of :data:`_INAV_SIGNALS` (a look-up table: ``np.isin``'s set-up costs more)."""
"""RXM-SFRBX sigIds of Galileo I/NAV frames: E1-B (1) and E5b-I (5) on u-blox 9 and later, 0 on u-blox 8
(whose reserved byte is 0 and which tracks E1 only); E5a F/NAV and E6 C/NAV frames are counted apart."""
_SFRBX = (0x02, 0x13)
_LNAV_GNSS = {0: "G", 5: "J"}
"""RXM-SFRBX gnssIds whose L1 C/A frames (sigId 0) are LNAV subframes, with their satellites' RINEX letter: GPS and
QZSS (IS-QZSS-PNT: the GPS subframe layout, parity and week; u-blox svId 1–10 is the RINEX ``Jnn``)."""
_LNAV_COUNTERS = {"G": ("gps_subframes", "gps_cnav_frames"), "J": ("qzss_subframes", "qzss_cnav_frames")}
"""The counters of :func:`sfrbx_ephemerides` of each LNAV system: (subframes 1–3 decoded, frames of other signals)."""
_SFRB = (0x02, 0x11)


_PARITY_COLUMNS = tuple((31 if prev == 29 else 30, np.uint32(mask)) for prev, mask in _PARITY_MASKS)


def _gps_parity_passes(w: np.ndarray) -> np.ndarray:
    """Rows of ten RXM-SFRBX GPS words (uint32, shape (m, 10)) whose every word passes the parity
    in the u-blox form (D29*, D30* in bits 31-30): the first test of :func:`gps_words_from_sfrbx`."""
    data = (w >> 6) & 0xFFFFFF
    par = np.zeros(w.shape, np.uint32)
    for prev, mask in _PARITY_COLUMNS:
        bit = ((w >> prev) & 1) ^ (np.bitwise_count(data & mask) & 1).astype(np.uint32)
        par = (par << 1) | bit
    return (par == (w & 0x3F)).all(axis=1)


def _beidou_bch_passes(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows passing, words in the logical layout) of ten RXM-SFRBX BeiDou words (uint32, shape
    (m, 10)) that :func:`beidou_words_from_sfrbx` accepts without de-interleaving any word."""
    syn = _BCH15_TABLE
    w = w & 0x3FFFFFFF
    flip = (w[:, 0] >> 19) == (BDS_PREAMBLE ^ 0x7FF)
    w = np.where(flip[:, None], w ^ 0x3FFFFFFF, w)
    cw1 = ((w[:, 1:] >> 19) & 0x7FF) << 4 | ((w[:, 1:] >> 4) & 0xF)
    cw2 = ((w[:, 1:] >> 8) & 0x7FF) << 4 | (w[:, 1:] & 0xF)
    ok = ((w[:, 0] >> 19) == BDS_PREAMBLE) & (syn[w[:, 0] & 0x7FFF] == 0) \
        & (syn[cw1] == 0).all(axis=1) & (syn[cw2] == 0).all(axis=1)
    return ok, w


def _checked_words(frames: list) -> dict:
    """{frame index: words} (``frames``: (index, class, id, frame bytes)) of the RXM-SFRBX GPS and QZSS L1 C/A and BeiDou D1/D2 subframes of ``frames``
    that pass their checks as most do (GPS parity in the u-blox form, BeiDou BCH without
    de-interleaving), checked all at once: what :func:`gps_words_from_sfrbx` /
    :func:`beidou_words_from_sfrbx` return for them.  The others are left to those functions."""
    at: dict = {0: [], 3: []}
    rows: dict = {0: [], 3: []}
    for i, cls, mid, fr in frames:
        if (cls, mid) == _SFRBX and len(fr) == 56 and fr[10] == 10 and (fr[6] == 3 or (fr[6] in _LNAV_GNSS and fr[8] == 0)):
            g = 0 if fr[6] in _LNAV_GNSS else 3
            at[g].append(i)
            rows[g].append(fr[14:54])
    out = {}
    for g in (0, 3):
        if not at[g]:
            continue
        w = np.frombuffer(b"".join(rows[g]), dtype="<u4").reshape(len(at[g]), 10)
        if g == 0:
            ok, words = _gps_parity_passes(w), (w >> 6) & 0xFFFFFF
        else:
            ok, words = _beidou_bch_passes(w)
        good = np.flatnonzero(ok)
        out.update(zip(np.asarray(at[g])[good].tolist(), words[good].tolist()))
    return out


def _inav_pages(frames: list) -> dict:
    """{frame index: :func:`inav_word` result} of every RXM-SFRBX Galileo I/NAV page pair of
    ``frames`` ((index, class, id, frame bytes), as :func:`sfrbx_ephemerides` selects them), decoded together."""
    at, rows = [], []
    for i, cls, mid, fr in frames:
        if (cls, mid) == _SFRBX and len(fr) >= 16 and fr[6] == 2 and fr[10] == 8 and fr[8] in _INAV_SIGNALS \
                and len(fr) == 16 + 32:
            at.append(i)
            rows.append(fr[14:46])
    if not at:
        return {}
    dw = np.frombuffer(b"".join(rows), dtype="<u4").reshape(len(at), 8)
    return dict(zip(at, inav_words(dw)))


def _stateful_mask(x: np.ndarray, off: np.ndarray, end: np.ndarray, week_ref: int | None, glonass: bool,
                   stats: dict) -> np.ndarray:
    """Which RXM-SFRBX / RXM-SFRB frames (``x[off:end]``, log order) :func:`sfrbx_ephemerides` must look at
    one by one, in order; the others (wrong length, F/NAV and C/NAV, BeiDou B1C/B2a/B2b, GPS and QZSS CNAV, systems
    not decoded) only count, and are counted here into ``stats`` from their header bytes, all at once, as
    the frame-by-frame walk would count them."""
    n_pl = end - off - 8
    head = x[np.minimum(off[:, None] + np.arange(6, 11), x.size - 1)].astype(np.int64)
    head[n_pl < 3] = 0xFF                                  # too short to have gnssId … numWords
    is_x = x[off + 3] == 0x13
    gnss, sig, nw = head[:, 0], head[:, 2], head[:, 4]
    valid = is_x & (n_pl >= 8) & (n_pl == 8 + 4 * nw)
    inav_sig = _INAV_SIGNAL_BYTE[sig]                      # np.isin(sig, _INAV_SIGNALS): sig is a byte
    gal_other = valid & (gnss == 2) & ((nw != 8) | ~inav_sig)
    gal_kept = valid & (gnss == 2) & ~gal_other & (week_ref is not None)
    bds = valid & (gnss == 3)
    glo = valid & (gnss == 6) & glonass
    other = valid & ~gal_other & ~gal_kept & ~bds & ~glo & (gnss != 0) & (gnss != 5)
    gps = valid & ((gnss == 0) | (gnss == 5)) & (nw == 10)
    qzss_other = valid & (gnss == 5) & ((nw != 10) | (sig != 0))          # L1S (9 words), L2C, L5: not LNAV
    stats["galileo_other_frames"] += int(gal_other.sum())
    stats["beidou_cnav_frames"] += int((bds & (nw != 10)).sum())
    stats["gps_cnav_frames"] += int((gps & (gnss == 0) & (sig != 0)).sum())
    stats["qzss_cnav_frames"] += int(qzss_other.sum())
    if other.any():
        codes, first, count = np.unique(gnss[other], return_index=True, return_counts=True)
        for k in np.argsort(first, kind="stable").tolist():       # in order of first appearance
            key = str(int(codes[k]))
            stats["other_systems"][key] = stats["other_systems"].get(key, 0) + int(count[k])
    return ~is_x | gal_kept | (bds & (nw == 10)) | glo | (gps & (sig == 0))


BATCH = True
"""Decode GPS, Galileo and BeiDou D1 subframes all at once (:mod:`cdgps_cli.io.sfrbx_batch`); False: frame
by frame, in log order (the reference the batch decoding is tested against: the same table and counters)."""

_EMPTY_NAV: list = []


def _empty_nav() -> pd.DataFrame:
    """A copy of ``pd.DataFrame([], columns=NAV_COLUMNS)``, made once (building it costs about 1 ms)."""
    if not _EMPTY_NAV:
        _EMPTY_NAV.append(pd.DataFrame([], columns=list(NAV_COLUMNS)))
    return _EMPTY_NAV[0].copy(deep=True)


def sfrbx_ephemerides(frames: list, week_ref: int | None, *, glonass: bool = False) -> tuple[pd.DataFrame, dict]:
    """GPS, Galileo and BeiDou (D1) — and with ``glonass`` GLONASS — ephemerides from the RXM-SFRBX /
    RXM-SFRB frames of a log.

    Parameters
    ----------
    frames : list of (offset, class, id, frame bytes)
        Checksum-valid UBX frames (:func:`cdgps_cli.io.ubx_frames.split_stream`), in log order.
    week_ref : int or None
        Full GPS week of the log (RXM-RAWX); None: ephemerides cannot be dated and none are returned.
    glonass : bool
        Also decode GLONASS strings 1–4 (:mod:`cdgps_cli.io.sfrbx_glonass`); the table then has the
        :data:`~cdgps_cli.core.records.GLONASS_NAV_COLUMNS` too (as ``read_rinex_nav(..., systems=(…, "R"))``).

    Returns
    -------
    nav : DataFrame
        Columns :data:`NAV_COLUMNS`, one row per distinct (sat, toe, IODE), sorted like the RINEX
        reader's table.
    stats : dict
        ``sfrbx_frames``, ``gps_subframes`` (1–3 decoded), ``parity_failures`` (subframes dropped),
        ``galileo_words``, ``galileo_bad_pages``, ``galileo_other_frames`` (F/NAV, C/NAV: not decoded),
        ``beidou_subframes`` (D1 1–3 kept),
        ``beidou_bch_failures`` (subframes dropped), ``beidou_d2_frames`` (GEO frames),
        ``beidou_d2_pages`` (D2 subframe-1 pages 1–10 kept),
        ``beidou_cnav_frames`` (not ten words: B1C/B2a/B2b, not decoded), ``gps_cnav_frames``
        (sigId ≠ 0: L2C/L5, not decoded), ``qzss_subframes`` (QZSS LNAV 1–3 decoded: gnssId 5, as GPS),
        ``qzss_cnav_frames`` (QZSS frames other than L1 C/A LNAV — L1S, L2C, L5 —, not decoded), ``glonass_strings``, ``glonass_hamming_failures``,
        ``glonass_unknown_slot`` (with ``glonass``), ``other_systems`` (gnssId → frames: not decoded
        here), ``ephemerides``.
    """
    blob = b"".join(fr for _, _, _, fr in frames)
    size = np.fromiter((len(fr) for _, _, _, fr in frames), np.int64, len(frames))
    end = np.cumsum(size)
    return sfrbx_ephemerides_at(blob, end - size, end, week_ref, glonass=glonass)


def sfrbx_ephemerides_at(data: bytes, off: np.ndarray, end: np.ndarray, week_ref: int | None, *,
                         glonass: bool = False) -> tuple[pd.DataFrame, dict]:
    """:func:`sfrbx_ephemerides` of the checksum-valid UBX frames ``data[off[k]:end[k]]`` (int64 arrays, log
    order), as the framer finds them in a log's bytes; the frames only counted never become Python objects."""
    x = np.frombuffer(data, np.uint8)
    stats = _new_stats(glonass)
    off, end = np.asarray(off, np.int64), np.asarray(end, np.int64)
    mid = x[off + 3]
    sel = (x[off + 2] == 2) & ((mid == 0x13) | (mid == 0x11))
    off, end = off[sel], end[sel]
    stats["sfrbx_frames"] = int(off.size)
    if not off.size:
        return _empty_nav(), stats
    keep = _stateful_mask(x, off, end, week_ref, glonass, stats)
    if BATCH:
        return _batch_ephemerides(data, x, off[keep], end[keep], week_ref, stats)
    off, end = off[keep].tolist(), end[keep].tolist()
    recs: dict[tuple, dict] = {}
    glo_recs: dict[tuple, dict] = {}
    latest: dict[str, dict] = {}
    gps, qzss, gal, bds, glo = [], [], [], [], []
    for a, b in zip(off, end):                             # kept SFRBX frames are well formed (_stateful_mask)
        f = (a, 2, data[a + 3], data[a:b])
        g = data[a + 6] if f[2] == 0x13 else 0
        (gps if g == 0 else qzss if g == 5 else gal if g == 2 else bds if g == 3 else glo).append(f)
    _gps_frames(gps, _checked_words(gps), week_ref, latest, recs, stats)
    _gps_frames(qzss, _checked_words(qzss), week_ref, latest, recs, stats, letter="J")
    if gal:
        _galileo_frames(gal, _inav_pages(gal), week_ref, latest, recs, stats)
    checked = _checked_words(bds)
    for i, _, _, fr in bds:
        _beidou_frame(fr[6:-2], fr[7], latest, recs, stats, checked.get(i))
    for _, _, _, fr in glo:
        glonass_frame(fr[6:-2], latest, glo_recs, stats, week_ref)
    nav = _nav_table(recs, glo_recs)
    stats["ephemerides"] = int(len(nav))
    return nav, stats


def _batch_ephemerides(data: bytes, x: np.ndarray, off: np.ndarray, end: np.ndarray, week_ref: int | None,
                       stats: dict) -> tuple[pd.DataFrame, dict]:
    """:func:`sfrbx_ephemerides_at` of the frames :func:`_stateful_mask` keeps, GPS, Galileo and BeiDou D1
    decoded all at once (:mod:`cdgps_cli.io.sfrbx_batch`), GLONASS frame by frame."""
    from cdgps_cli.io import sfrbx_batch  # noqa: PLC0415 (it imports this module)

    latest: dict[str, dict] = {}
    parts, d2 = sfrbx_batch.records(data, off, end, week_ref, latest, stats)
    glo_recs: dict[tuple, dict] = {}
    is_glo = (x[off + 3] == 0x13) & (x[np.minimum(off + 6, x.size - 1)] == 6)
    for a, b in zip(off[is_glo].tolist(), end[is_glo].tolist()):
        glonass_frame(data[a + 6:b - 2], latest, glo_recs, stats, week_ref)
    nav = _nav_table({}, glo_recs, _columns_table(parts, d2))
    stats["ephemerides"] = int(len(nav))
    return nav, stats


def _columns_table(parts: list, d2: list) -> pd.DataFrame:
    """:func:`_records_table` of records given as column arrays (``parts``, each NAV_COLUMNS → array) and
    as dicts (``d2``)."""
    if d2:
        parts = [*parts, {c: np.array([r[c] for r in d2]) for c in NAV_COLUMNS}]
    if not parts:
        return _empty_nav()
    cols = {c: np.concatenate([p[c] for p in parts]) if len(parts) > 1 else parts[0][c] for c in NAV_COLUMNS}
    order = np.lexsort((cols["transmit_gps_s"], cols["toe_gps_s"], cols["sat"].astype(str)))
    for c in NAV_COLUMNS:
        cols[c] = cols[c][order].astype(np.int64 if c in _NAV_INT_COLUMNS else cols[c].dtype, copy=False)   # fresh: no copy
    return _frame(cols)                                    # pd.DataFrame(cols, columns=list(NAV_COLUMNS))'s table


def _new_stats(glonass: bool) -> dict:
    """The counters of :func:`sfrbx_ephemerides`, zero."""
    stats = {"sfrbx_frames": 0, "gps_subframes": 0, "parity_failures": 0, "galileo_words": 0, "galileo_bad_pages": 0,
             "beidou_subframes": 0, "beidou_bch_failures": 0, "beidou_d2_frames": 0, "beidou_d2_pages": 0,
             "beidou_cnav_frames": 0, "galileo_other_frames": 0,
             "gps_cnav_frames": 0, "qzss_subframes": 0, "qzss_cnav_frames": 0, "other_systems": {}, "ephemerides": 0}
    if glonass:
        stats.update({"glonass_strings": 0, "glonass_hamming_failures": 0, "glonass_unknown_slot": 0})
    return stats


def _gps_words(cls_mid: tuple, pl: bytes, checked: list | None, stats: dict) -> tuple[int, list | None]:
    """(svId, 24-bit data words or None) of a GPS RXM-SFRBX L1 C/A (parity checked; a failure counted)
    or legacy RXM-SFRB payload (None also for an SFRB of a length or svId not decoded)."""
    if cls_mid == _SFRBX:
        words = checked if checked is not None else gps_words_from_sfrbx(np.frombuffer(pl[8:48], dtype="<u4").tolist())
        if words is None:
            stats["parity_failures"] += 1
        return pl[1], words
    if len(pl) != 42 or not 1 <= pl[1] <= 32:
        return pl[1], None
    return pl[1], [w & 0xFFFFFF for w in np.frombuffer(pl[2:42], dtype="<u4").tolist()]


def _gps_frames(frames: list, checked: dict, week_ref: int | None, latest: dict, recs: dict, stats: dict,
                letter: str = "G") -> None:
    """The LNAV subframes of GPS (RXM-SFRBX L1 C/A and RXM-SFRB) or, ``letter`` ``"J"``, of QZSS (RXM-SFRBX L1
    C/A), in log order, into ``recs``: each satellite's latest subframes 1-3 decoded whenever they change
    (:func:`decode_gps_subframes`)."""
    decoded: set = set()
    for i, cls, mid, fr in frames:
        sv, words = _gps_words((cls, mid), fr[6:-2], checked.get(i), stats)
        if words is None:
            continue
        sid = subframe_id(words)
        if sid not in (1, 2, 3) or not 1 <= sv <= 32:
            continue
        stats[_LNAV_COUNTERS[letter][0]] += 1
        sat = f"{letter}{sv:02d}"
        have = latest.setdefault(sat, {})
        have[sid] = words
        if week_ref is None or not all(k in have for k in (1, 2, 3)):
            continue
        seen = (sat, tuple(have[1]), tuple(have[2]), tuple(have[3]))
        if seen in decoded:                                # the same three subframes: the same record
            continue
        decoded.add(seen)
        key = _gps_record_key(have[1], have[2], have[3], week_ref)
        if key is None or (sat, *key) in recs:             # not one data set, or a record already kept
            continue
        rec = decode_gps_subframes(have[1], have[2], have[3], sat, week_ref)
        if rec is not None and 0 <= rec["e"] < 1 and rec["sqrt_a_sqrt_m"] > 0:
            recs.setdefault((sat, rec["toe_gps_s"], rec["iode"]), rec)


def _galileo_frames(frames: list, inav: dict, week_ref: int, latest: dict, recs: dict, stats: dict) -> None:
    """The Galileo I/NAV page pairs (checked and extracted in ``inav``, log order) into ``recs``: each
    satellite's latest word types 1-5 decoded whenever they change (:func:`decode_galileo_words`)."""
    decoded: set = set()
    for i, _, _, fr in frames:
        got = inav[i]
        if got is None:
            stats["galileo_bad_pages"] += 1
            continue
        wtype, word = got
        sv = fr[7]
        if not (1 <= wtype <= 5 and 1 <= sv <= 36):
            continue
        stats["galileo_words"] += 1
        sat = f"E{sv:02d}"
        have = latest.setdefault(sat, {})
        have[wtype] = word
        seen = (sat, *(have.get(k) for k in (1, 2, 3, 4, 5)))
        if seen in decoded:                                # the same five words: the same record
            continue
        decoded.add(seen)
        key = _galileo_record_key(have, week_ref)
        if key is None or (sat, *key) in recs:             # incomplete or mixed, or a record already kept
            continue
        rec = decode_galileo_words(have, sat, week_ref)
        if rec is not None and 0 <= rec["e"] < 1 and rec["sqrt_a_sqrt_m"] > 0:
            recs.setdefault((sat, rec["toe_gps_s"], rec["iode"]), rec)


_NAV_INT_COLUMNS = ("iode", "codes_l2", "l2p_data_flag", "sv_health", "iodc", "week", "line")


def _nav_table(recs: dict, glo_recs: dict, nav: pd.DataFrame | None = None) -> pd.DataFrame:
    """The records as the table :func:`sfrbx_ephemerides` returns (integer columns int64, sorted by
    satellite, toe, transmission time; GLONASS columns when there are GLONASS records); ``nav``: the
    table of the records but GLONASS, already made (``recs`` then unused)."""
    if nav is None:
        nav = _records_table(list(recs.values()), list(NAV_COLUMNS)) if recs else _empty_nav()
    if glo_recs:
        glo = _records_table(list(glo_recs.values()), [*NAV_COLUMNS, *GLONASS_NAV_COLUMNS])
        nav = pd.concat([d for d in (nav.reindex(columns=glo.columns), glo) if len(d)], ignore_index=True)
        for c in _NAV_INT_COLUMNS:
            nav[c] = nav[c].astype(np.int64)
        nav = nav.sort_values(["sat", "toe_gps_s", "transmit_gps_s"], kind="stable").reset_index(drop=True)
    return nav


def _records_table(rows: list, columns: list) -> pd.DataFrame:
    """``rows`` (dicts) as a table of ``columns``, integer columns int64, sorted by satellite, toe and
    transmission time (stable), as ``pd.DataFrame(rows, columns=columns)`` then ``sort_values`` gives it."""
    cols = {c: np.array([r.get(c) for r in rows]) for c in columns}
    if any(v.dtype == object for c, v in cols.items() if c != "sat"):       # a key missing (None): pandas' way
        nav = pd.DataFrame(rows, columns=columns)
        for c in _NAV_INT_COLUMNS:
            nav[c] = nav[c].astype(np.int64)
        return nav.sort_values(["sat", "toe_gps_s", "transmit_gps_s"], kind="stable").reset_index(drop=True)
    order = np.lexsort((cols["transmit_gps_s"], cols["toe_gps_s"], cols["sat"].astype(str)))  # stable, NaN last
    for c in columns:
        cols[c] = cols[c][order].astype(np.int64 if c in _NAV_INT_COLUMNS else cols[c].dtype)
    return pd.DataFrame(cols, columns=columns)
