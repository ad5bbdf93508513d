"""GLONASS ephemerides (strings 1–4 of the L1OF/L2OF navigation message) from u-blox RXM-SFRBX.

A GLONASS RXM-SFRBX frame (gnssId 6, ``freqId`` = k + 7, ``svId`` = slot, 255 when unknown) carries
one 85-bit string in the top 85 bits of its first three words (bit 85, the idle chip, is bit 31
of word 0; 11 pad bits follow); the fourth word holds superframe/frame numbers and is not used.
This layout was established on real logs: every one of the 1 075 strings of the two real logs at
hand (gpsd's ublox-glo.log, pygnssutils' testobsnavdata) passes the Hamming check there.

* :func:`glonass_string` — the string as an int (bit i of the ICD at bit i − 1), or None when the
  idle chip is not 0 or the Hamming (85, 77) check fails: check bits β1…β7 (string bits 1–7) each
  cover the data bits b9…b85 whose Hamming position (the data bits numbered 3, 5, 6, 7, 9, … —
  the integers that are not powers of two) has bit j set; β8 (bit 8) makes the whole string's
  parity even.  No single-error correction (a corrupted string is dropped, never used).
* :func:`decode_glonass_strings` — strings 1–4 of one frame → a record of the navigation table
  (:data:`~cdgps_cli.core.records.NAV_COLUMNS` + :data:`~cdgps_cli.core.records.GLONASS_NAV_COLUMNS`,
  the RINEX reader's GLONASS layout: ``af0_s`` = −τ_n, ``af1_s_per_s`` = γ_n, PZ-90 state in m,
  t_b in GPS seconds).  Fields per GLONASS ICD edition 5.1 Table 4.5 (sign-magnitude numbers):
  string 1 t_k, x', x'', x; string 2 B_n, t_b, y', y'', y; string 3 γ_n, l_n, z', z'', z; string 4
  τ_n, N_T (day within the four-year interval), n (slot).  The date of t_b (Moscow time, UTC + 3 h)
  is N_T in the four-year interval nearest the reference GPS week.
"""

from __future__ import annotations

import datetime as dt

import numpy as np

from cdgps_cli.core.gps_time import GLONASST_MINUS_UTC_S, SECONDS_PER_WEEK, gps_seconds
from cdgps_cli.core.records import GLONASS_NAV_COLUMNS, NAV_COLUMNS
from cdgps_cli.core.timescales import gps_minus_utc_s

__all__ = ["glonass_string", "decode_glonass_strings", "glonass_frame"]


def _hamming_position() -> dict[int, int]:
    """Hamming codeword position of each data bit b9…b85 (the non-powers of two from 3 up)."""
    out, k = {}, 3
    for i in range(9, 86):
        while k & (k - 1) == 0:
            k += 1
        out[i] = k
        k += 1
    return out


_POS = _hamming_position()
_CHECK_MASKS = tuple(sum(1 << (i - 1) for i in range(9, 86) if _POS[i] >> j & 1) for j in range(7))


def glonass_string(dwrd: list[int]) -> int | None:
    """The 85-bit string of a GLONASS RXM-SFRBX frame (bit i of the ICD at bit i − 1), or None when
    its idle chip is 1 or its Hamming check fails."""
    if len(dwrd) < 3:
        return None
    v = ((dwrd[0] & 0xFFFFFFFF) << 64 | (dwrd[1] & 0xFFFFFFFF) << 32 | (dwrd[2] & 0xFFFFFFFF)) >> 11
    if v >> 84:
        return None
    for j, mask in enumerate(_CHECK_MASKS):
        if ((v >> j) & 1) ^ (bin(v & mask).count("1") & 1):
            return None
    return v if bin(v).count("1") % 2 == 0 else None


def _u(s: int, hi: int, lo: int) -> int:
    """Bits hi…lo (ICD numbering, 85 = first transmitted) of string ``s``."""
    return (s >> (lo - 1)) & ((1 << (hi - lo + 1)) - 1)


def _sm(s: int, hi: int, lo: int) -> int:
    """Sign-magnitude field hi…lo (the sign in bit hi)."""
    v = _u(s, hi - 1, lo)
    return -v if _u(s, hi, hi) else v


def _axis(s: int) -> tuple[float, float, float]:
    """(position m, velocity m/s, acceleration m/s²) of strings 1–3 (bits 35–9, 64–41, 40–36; km units)."""
    return _sm(s, 35, 9) * 2.0**-11 * 1e3, _sm(s, 64, 41) * 2.0**-20 * 1e3, _sm(s, 40, 36) * 2.0**-30 * 1e3


def decode_glonass_strings(strings: dict, sat: str, k: int, week_ref: int) -> dict | None:
    """One GLONASS record from strings 1–4 of one frame (``strings``: number → 85-bit int).

    Parameters
    ----------
    strings : dict
        String number (1…4) → string (:func:`glonass_string`).
    sat : str
        Satellite ("R07").
    k : int
        Frequency number (RXM-SFRBX ``freqId`` − 7).
    week_ref : int
        A GPS week near the data (picks the four-year interval of N_T).

    Returns
    -------
    dict or None
        The record (keys of ``NAV_COLUMNS`` and ``GLONASS_NAV_COLUMNS``), or None when a string is
        missing, N_T is 0, or string 4's slot number is not the satellite's.
    """
    if not all(m in strings for m in (1, 2, 3, 4)):
        return None
    s1, s2, s3, s4 = (strings[m] for m in (1, 2, 3, 4))
    n_t, slot = _u(s4, 26, 16), _u(s4, 15, 11)
    if n_t == 0 or slot != int(sat[1:]):
        return None
    t_ref = week_ref * SECONDS_PER_WEEK + 0.5 * SECONDS_PER_WEEK
    start = min((dt.date(y, 1, 1) for y in range(1996, 2101, 4)),
                key=lambda d: abs(gps_seconds(d.year, 1, 1) + (n_t - 1) * 86400.0 - t_ref))
    day = start + dt.timedelta(days=n_t - 1)
    t_day_msk = gps_seconds(day.year, day.month, day.day)            # the Moscow-time date, as calendar seconds
    t_b_utc = t_day_msk + _u(s2, 76, 70) * 900.0 - GLONASST_MINUS_UTC_S
    leap = float(gps_minus_utc_s(t_b_utc + 18.0))
    toe = t_b_utc + leap
    t_k = _u(s1, 76, 72) * 3600.0 + _u(s1, 71, 66) * 60.0 + _u(s1, 65, 65) * 30.0
    frame = t_day_msk + t_k - GLONASST_MINUS_UTC_S + leap
    frame += 86400.0 * round((toe - frame) / 86400.0)
    (x, vx, ax), (y, vy, ay), (z, vz, az) = _axis(s1), _axis(s2), _axis(s3)
    rec = dict.fromkeys((*NAV_COLUMNS, *GLONASS_NAV_COLUMNS), float("nan"))
    week = int(toe // SECONDS_PER_WEEK)
    rec.update({
        "sat": sat, "toc_gps_s": toe, "toe_gps_s": toe, "af0_s": -_sm(s4, 80, 59) * 2.0**-30,
        "af1_s_per_s": _sm(s3, 79, 69) * 2.0**-40, "af2_s_per_s2": 0.0, "iode": -1, "codes_l2": -1,
        "l2p_data_flag": -1, "iodc": -1, "tgd_s": 0.0, "sv_health": _u(s2, 80, 80) | _u(s3, 65, 65), "week": week,
        "toe_sow_s": toe - week * SECONDS_PER_WEEK, "transmit_gps_s": frame,
        "transmit_sow_s": frame % SECONDS_PER_WEEK, "line": -1,
        "x_m": x, "y_m": y, "z_m": z, "vx_m_per_s": vx, "vy_m_per_s": vy, "vz_m_per_s": vz,
        "ax_m_per_s2": ax, "ay_m_per_s2": ay, "az_m_per_s2": az, "glonass_k": int(k),
    })
    return rec


def glonass_frame(pl: bytes, latest: dict, recs: dict, stats: dict, week_ref: int | None) -> None:
    """One RXM-SFRBX GLONASS payload: check, keep the string, decode when strings 1–4 came in a row
    (one frame: strings are sent in order every 2 s)."""
    sv, k = pl[1], pl[3] - 7
    if not 1 <= sv <= 24 or not -7 <= k <= 6 or pl[4] < 3:
        stats["glonass_unknown_slot"] += 1
        return
    s = glonass_string(np.frombuffer(pl[8:20], dtype="<u4").tolist())
    if s is None:
        stats["glonass_hamming_failures"] += 1
        return
    m = _u(s, 84, 81)
    stats["glonass_strings"] += 1
    sat = f"R{sv:02d}"
    have = latest.setdefault(sat, {})
    in_row = m == 1 or have.get(0) == m - 1               # key 0: the number of the string before
    if m == 1:
        have.clear()
    have[0] = m
    if not in_row or not 1 <= m <= 4:
        return
    have[m] = s
    if m == 4 and week_ref is not None:
        rec = decode_glonass_strings(have, sat, k, week_ref)
        if rec is not None:
            recs.setdefault((sat, rec["toe_gps_s"], rec["iode"]), rec)
