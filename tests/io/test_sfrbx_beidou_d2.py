"""BeiDou D2 (GEO) ephemerides from u-blox RXM-SFRBX: subframe 1, pages 1 and 3–10 (BDS-ICD-B1I 3.0 §5.3).

No real u-blox log with GEO frames is at hand (the two real BeiDou logs are from the UK, where no GEO
is up), so the decoder is checked against an encoder: the ICD's page layout written here word by word
(each word's fields in transmission order, a field continuing in the next word or page), BCH(15,11)
parity by GF(2) long division (the D1 test's encoder), the record of a synthetic GEO satellite
(model/gps/positioning.synthetic_beidou_nav, C03 at 110.5° E) as the source; the decoded record gives
the same satellite position through the GEO algorithm.
"""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.io.sfrbx import GPS_PI, sfrbx_ephemerides
from cdgps_cli.io.ubx_frames import split_stream
from cdgps_cli.model.gps.orbits import sat_position_ecef
from cdgps_cli.model.gps.positioning import synthetic_beidou_nav
from tests.io.test_sfrbx_beidou import _codeword, _sfrbx

HEAD = [("pre", 11), ("rev", 4), ("fraid", 3), ("sow", 8)]
W2 = [("sow", 12), ("pnum", 4)]
# per page: words 2–5 (22 information bits each); words 6–10 carry no ephemeris field (zeros here)
PAGES = {
    1: [W2 + [("sath1", 1), ("aodc", 5)], [("urai", 4), ("wn", 13), ("toc", 5)], [("toc", 12), ("tgd1", 10)],
        [("tgd2", 10), ("res", 12)]],
    2: [W2 + [("res", 6)], [("res", 22)], [("res", 22)], [("res", 22)]],                 # ionosphere: not used
    3: [W2 + [("res", 6)], [("res", 22)], [("res", 10), ("a0", 12)], [("a0", 12), ("a1", 4), ("res", 6)]],
    4: [W2 + [("a1", 6)], [("a1", 12), ("a2", 10)], [("a2", 1), ("aode", 5), ("dn", 16)], [("cuc", 14), ("res", 8)]],
    5: [W2 + [("cuc", 4), ("m0", 2)], [("m0", 22)], [("m0", 8), ("cus", 14)], [("cus", 4), ("e", 10), ("res", 8)]],
    6: [W2 + [("e", 6)], [("e", 16), ("sqrta", 6)], [("sqrta", 22)], [("sqrta", 4), ("cic", 10), ("res", 8)]],
    7: [W2 + [("cic", 6)], [("cic", 2), ("cis", 18), ("toe", 2)], [("toe", 15), ("i0", 7)], [("i0", 14), ("res", 8)]],
    8: [W2 + [("i0", 6)], [("i0", 5), ("crc", 17)], [("crc", 1), ("crs", 18), ("omdot", 3)], [("omdot", 16), ("res", 6)]],
    9: [W2 + [("omdot", 5), ("om0", 1)], [("om0", 22)], [("om0", 9), ("w", 13)], [("w", 14), ("res", 8)]],
    10: [W2 + [("w", 5), ("idot", 1)], [("idot", 13), ("res", 9)], [("res", 22)], [("res", 22)]],
}
# field: (bits, scale, signed, record column, semicircles → rad)
FIELDS = {
    "a0": (24, 2.0**-33, True, "af0_s", False), "a1": (22, 2.0**-50, True, "af1_s_per_s", False),
    "a2": (11, 2.0**-66, True, "af2_s_per_s2", False), "tgd1": (10, 1e-10, True, "tgd_s", False),
    "dn": (16, 2.0**-43, True, "delta_n_rad_per_s", True), "cuc": (18, 2.0**-31, True, "cuc_rad", False),
    "m0": (32, 2.0**-31, True, "m0_rad", True), "e": (32, 2.0**-33, False, "e", False),
    "cus": (18, 2.0**-31, True, "cus_rad", False), "crc": (18, 2.0**-6, True, "crc_m", False),
    "crs": (18, 2.0**-6, True, "crs_m", False), "sqrta": (32, 2.0**-19, False, "sqrt_a_sqrt_m", False),
    "i0": (32, 2.0**-31, True, "i0_rad", True), "cic": (18, 2.0**-31, True, "cic_rad", False),
    "omdot": (24, 2.0**-43, True, "omega_dot_rad_per_s", True), "cis": (18, 2.0**-31, True, "cis_rad", False),
    "idot": (14, 2.0**-43, True, "idot_rad_per_s", True), "om0": (32, 2.0**-31, True, "omega0_rad", True),
    "w": (32, 2.0**-31, True, "omega_rad", True),
}
T0 = gps_seconds(2024, 1, 1)


@pytest.fixture(scope="module")
def geo():
    nav = synthetic_beidou_nav(T0, 3600.0, seed=3)
    rec = nav[nav["sat"] == "C03"].iloc[1].copy()
    rec[["crs_m", "crc_m", "cus_rad", "cuc_rad", "cis_rad", "cic_rad"]] = (-12.3, 48.5, 3.1e-6, -2.2e-6, 4.0e-8, -9.0e-8)
    rec[["delta_n_rad_per_s", "idot_rad_per_s", "af2_s_per_s2"]] = (1.1e-9, -2.0e-10, 3.0e-19)
    return rec


def _values(rec, page: int, sow0: int) -> dict:
    q = {}
    for name, (n, scale, signed, col, semi) in FIELDS.items():
        v = int(round(float(rec[col]) / (GPS_PI if semi else 1.0) / scale))
        assert (-(1 << (n - 1)) <= v < (1 << (n - 1))) if signed else 0 <= v < (1 << n), name
        q[name] = (v & ((1 << n) - 1), n)
    q.update({"pre": (0b11100010010, 11), "rev": (0, 4), "fraid": (1, 3), "sow": (sow0 + 3 * (page - 1), 20),
              "pnum": (page, 4), "sath1": (0, 1), "aodc": (int(rec["iodc"]), 5), "urai": (0, 4),
              "wn": (int(rec["week"]), 13), "toc": (int(rec["toe_sow_s"]) // 8, 17), "toe": (int(rec["toe_sow_s"]) // 8, 17),
              "tgd2": (0, 10), "aode": (int(rec["iode"]), 5)})
    return q


def _page(rec, page: int, sow0: int) -> list[int]:
    """The ten 30-bit words (logical layout) of one D2 page."""
    values = _values(rec, page, sow0)
    used = {}                                   # bits of each field already sent on earlier pages
    for q in range(1, page):
        for word in PAGES[q]:
            for name, n in word:
                used[name] = used.get(name, 0) + n
    used = {k: v for k, v in used.items() if k in FIELDS}
    words = []
    for k, word in enumerate([HEAD] + PAGES[page] + [[("res", 22)]] * 5):
        bits = []
        for name, n in word:
            if name == "res":
                bits += [0] * n
                continue
            v, width = values[name]
            u = used.get(name, 0)
            bits += [(v >> (width - 1 - u - i)) & 1 for i in range(n)]
            used[name] = u + n
        tx = bits[:15] + _codeword(bits[15:26]) if k == 0 else bits + _codeword(bits[:11])[11:] + _codeword(bits[11:22])[11:]
        words.append(int("".join(map(str, tx)), 2))
    return words


def _stream(rec, sv=3, pages=range(1, 11), flip=None, sow0=None) -> bytes:
    sow0 = int(rec["transmit_sow_s"]) if sow0 is None else sow0
    out = b""
    for p in pages:
        w = _page(rec, p, sow0)
        if flip and flip[0] == p:
            w[flip[1]] ^= 1 << flip[2]
        out += _sfrbx(sv, w)
    return out


def test_every_field_fills_its_width():
    widths = {}
    for words in PAGES.values():
        for word in words:
            assert sum(n for _, n in word) == 22
            for name, n in word:
                widths[name] = widths.get(name, 0) + n
    assert all(widths[f] == FIELDS[f][0] for f in FIELDS)
    assert widths["toc"] == widths["toe"] == 17


def test_d2_pages_decode_to_the_geo_record(geo):
    frames, _, _ = split_stream(_stream(geo))
    nav, st = sfrbx_ephemerides(frames, week_ref=int(geo["week"]) + 1356)
    assert st["beidou_d2_frames"] == 10 and st["beidou_d2_pages"] == 10 and st["beidou_bch_failures"] == 0
    assert len(nav) == 1 and nav["sat"].iloc[0] == "C03"
    got = nav.iloc[0]
    for name, (n, scale, _, col, semi) in FIELDS.items():
        assert abs(got[col] - geo[col]) <= 0.5 * scale * (GPS_PI if semi else 1.0) * (1 + 1e-9), name
    for col in ("toe_gps_s", "toc_gps_s", "week", "toe_sow_s", "iode", "iodc"):
        assert got[col] == geo[col], col
    t = float(geo["toe_gps_s"]) + np.array([-1800.0, 0.0, 1800.0])
    x_src, c_src = sat_position_ecef(geo, t)
    x_dec, c_dec = sat_position_ecef(got, t)
    assert np.abs(x_dec - x_src).max() < 0.5 and np.abs(c_dec - c_src).max() < 1e-9
    assert np.linalg.norm(x_src[1]) == pytest.approx(42_164e3, rel=2e-3)                  # a GEO radius


def test_a_missing_page_or_a_broken_cycle_gives_no_record(geo):
    for stream in (_stream(geo, pages=[1, 3, 4, 5, 6, 7, 9, 10]),                          # page 8 lost
                   _stream(geo, pages=[1, 3, 4]) + _stream(geo, pages=[5, 6, 7, 8, 9, 10], sow0=int(geo["transmit_sow_s"]) + 30)):
        nav, _ = sfrbx_ephemerides(split_stream(stream)[0], week_ref=int(geo["week"]) + 1356)
        assert len(nav) == 0


def test_a_flipped_bit_drops_the_page(geo):
    frames, _, _ = split_stream(_stream(geo, flip=(6, 3, 12)))
    nav, st = sfrbx_ephemerides(frames, week_ref=int(geo["week"]) + 1356)
    assert st["beidou_bch_failures"] == 1 and st["beidou_d2_pages"] == 9 and len(nav) == 0
