"""BeiDou D1 broadcast ephemerides from u-blox RXM-SFRBX subframes (issue 14 item 1).

An independent encoder writes a known ephemeris into D1 subframes 1–3 from the field table of
BDS-ICD-B1I 3.0 (§5.2.4, Figures 5-5 to 5-7: each word's fields in transmission order, a field
longer than the rest of a word continuing in the next word), computes each BCH(15,11) codeword's
parity by polynomial long division over GF(2) (g(X) = X⁴ + X + 1), optionally interleaves the two
codewords of words 2–10 as transmitted, and wraps the ten 30-bit words in RXM-SFRBX frames; the
decoder returns the ephemeris within half a quantisation step, and the satellite positions of the
decoded and the original ephemeris agree.
"""

from __future__ import annotations

import itertools
import math
import struct

import pandas as pd
import pytest

from cdgps_cli.core.gps_time import bdt_to_gps_s
from cdgps_cli.io.sfrbx import GPS_PI, bch15_syndrome, sfrbx_ephemerides
from cdgps_cli.io.ubx_frames import split_stream
from cdgps_cli.model.gps.orbits import sat_position_ecef
from tests.io.test_sfrbx import _ubx_frame

# (field, bits) per word in transmission order; words 1: 26 data bits, 2-10: 22 data bits
HEAD = [("pre", 11), ("rev", 4), ("fraid", 3), ("sow", 8)]
LAYOUT = {
    1: [HEAD, [("sow", 12), ("sath1", 1), ("aodc", 5), ("urai", 4)], [("wn", 13), ("toc", 9)],
        [("toc", 8), ("tgd1", 10), ("tgd2", 4)], [("tgd2", 6), ("alpha0", 8), ("alpha1", 8)],
        [("alpha2", 8), ("alpha3", 8), ("beta0", 6)], [("beta0", 2), ("beta1", 8), ("beta2", 8), ("beta3", 4)],
        [("beta3", 4), ("a2", 11), ("a0", 7)], [("a0", 17), ("a1", 5)], [("a1", 17), ("aode", 5)]],
    2: [HEAD, [("sow", 12), ("dn", 10)], [("dn", 6), ("cuc", 16)], [("cuc", 2), ("m0", 20)], [("m0", 12), ("e", 10)],
        [("e", 22)], [("cus", 18), ("crc", 4)], [("crc", 14), ("crs", 8)], [("crs", 10), ("sqrta", 12)],
        [("sqrta", 20), ("toe_hi", 2)]],
    3: [HEAD, [("sow", 12), ("toe_lo", 10)], [("toe_lo", 5), ("i0", 17)], [("i0", 15), ("cic", 7)],
        [("cic", 11), ("omdot", 11)], [("omdot", 13), ("cis", 9)], [("cis", 9), ("idot", 13)], [("idot", 1), ("om0", 21)],
        [("om0", 11), ("w", 11)], [("w", 21), ("rev1", 1)]],
}
# (field, total bits, scale, signed, record column, semicircles→rad)
SCALES = [
    ("a0", 24, 2.0**-33, True, "af0_s", False), ("a1", 22, 2.0**-50, True, "af1_s_per_s", False),
    ("a2", 11, 2.0**-66, True, "af2_s_per_s2", False), ("tgd1", 10, 1e-10, True, "tgd_s", False),
    ("dn", 16, 2.0**-43, True, "delta_n_rad_per_s", True), ("cuc", 18, 2.0**-31, True, "cuc_rad", False),
    ("m0", 32, 2.0**-31, True, "m0_rad", True), ("e", 32, 2.0**-33, False, "e", False),
    ("cus", 18, 2.0**-31, True, "cus_rad", False), ("crc", 18, 2.0**-6, True, "crc_m", False),
    ("crs", 18, 2.0**-6, True, "crs_m", False), ("sqrta", 32, 2.0**-19, False, "sqrt_a_sqrt_m", False),
    ("i0", 32, 2.0**-31, True, "i0_rad", True), ("cic", 18, 2.0**-31, True, "cic_rad", False),
    ("omdot", 24, 2.0**-43, True, "omega_dot_rad_per_s", True), ("cis", 18, 2.0**-31, True, "cis_rad", False),
    ("idot", 14, 2.0**-43, True, "idot_rad_per_s", True), ("om0", 32, 2.0**-31, True, "omega0_rad", True),
    ("w", 32, 2.0**-31, True, "omega_rad", True),
]
# a MEO ephemeris in ICD units (semicircles for angles), loosely after C11 of 2020-06-25
EPH = {
    "a0": -4.4958642e-4, "a1": -2.41327e-11, "a2": 0.0, "tgd1": 2.3e-9, "dn": 1.2e-9 / math.pi, "cuc": -1.0e-6,
    "m0": 0.5123, "e": 1.8540481e-3, "cus": 9.69e-6, "crc": 173.609375, "crs": 21.640625, "sqrta": 5282.6338,
    "i0": 0.31307, "cic": 4.7e-8, "omdot": -6.53e-9 / math.pi, "cis": 3.6e-8, "idot": -1.7e-10 / math.pi,
    "om0": 0.6356, "w": -0.52604,
}
WN, TOE, TOC, SOW, AODE, AODC, URAI = 755, 345600, 345600, 345000, 1, 0, 2


def _gf2_remainder(bits: list[int], gen: list[int]) -> list[int]:
    """Remainder of a bit list (highest degree first) divided by ``gen`` over GF(2)."""
    r = list(bits)
    for k in range(len(r) - len(gen) + 1):
        if r[k]:
            for j, g in enumerate(gen):
                r[k + j] ^= g
    return r[-(len(gen) - 1):]


def _codeword(info11: list[int]) -> list[int]:
    return info11 + _gf2_remainder(info11 + [0, 0, 0, 0], [1, 0, 0, 1, 1])


def _field_values(fid: int) -> dict:
    q = {}
    for name, n, scale, signed, _, _ in SCALES:
        v = int(round(EPH[name] / scale))
        assert (-(1 << (n - 1)) <= v < (1 << (n - 1))) if signed else 0 <= v < (1 << n), name
        q[name] = (v & ((1 << n) - 1), n)
    toe = TOE // 8
    q.update({"pre": (0b11100010010, 11), "rev": (0, 4), "fraid": (fid, 3), "sow": (SOW + 6 * (fid - 1), 20),
              "sath1": (0, 1), "aodc": (AODC, 5), "urai": (URAI, 4), "wn": (WN, 13), "toc": (TOC // 8, 17),
              "tgd2": (0x3F5, 10), "alpha0": (7, 8), "alpha1": (1, 8), "alpha2": (255, 8), "alpha3": (254, 8),
              "beta0": (9, 8), "beta1": (3, 8), "beta2": (250, 8), "beta3": (251, 8), "aode": (AODE, 5),
              "toe_hi": (toe >> 15, 2), "toe_lo": (toe & 0x7FFF, 15), "rev1": (0, 1)})
    return q


def _encode(fid: int, interleave: bool) -> list[int]:
    values = _field_values(fid)
    used = dict.fromkeys(values, 0)
    words = []
    for k, word in enumerate(LAYOUT[fid]):
        bits = []
        for name, n in word:
            v, width = values[name]
            bits += [(v >> (width - 1 - used[name] - i)) & 1 for i in range(n)]
            used[name] += n
        if k == 0:
            tx = bits[:15] + _codeword(bits[15:26])
        else:
            c1, c2 = _codeword(bits[:11]), _codeword(bits[11:22])
            tx = [b for pair in zip(c1, c2) for b in pair] if interleave else bits + c1[11:] + c2[11:]
        words.append(int("".join(map(str, tx)), 2))
    names = {f for w in LAYOUT[fid] for f, _ in w}
    assert all(used[nm] == values[nm][1] for nm in names), used      # every field filled exactly
    return words


def _sfrbx(sv: int, words30: list[int]) -> bytes:
    return _ubx_frame(0x02, 0x13, bytes((3, sv, 0, 0, 10, 5, 2, 0)) + struct.pack("<10I", *words30))


def _stream(sv: int, interleave: bool = False, invert: bool = False, flip: tuple | None = None) -> bytes:
    """Subframes 1-3 as RXM-SFRBX frames; ``flip`` = (subframe, word index, bit) inverts one bit."""
    out = b""
    for fid in (1, 2, 3):
        w = [(x ^ 0x3FFFFFFF) if invert else x for x in _encode(fid, interleave)]
        if flip and flip[0] == fid:
            w[flip[1]] ^= 1 << flip[2]
        out += _sfrbx(sv, w)
    return out


def test_bch15_is_the_hamming_code_of_the_icd():
    # every 11-bit message encodes to a codeword with zero syndrome; distinct codewords differ in ≥ 3 bits
    cws = [int("".join(map(str, _codeword([(m >> (10 - i)) & 1 for i in range(11)]))), 2) for m in range(2048)]
    assert all(bch15_syndrome(c) == 0 for c in cws)
    assert min(bin(a ^ b).count("1") for a, b in itertools.combinations(cws[:200], 2)) == 3
    assert all(bch15_syndrome(cws[5] ^ (1 << k)) != 0 for k in range(15))


@pytest.mark.parametrize("interleave,invert", [(False, False), (True, False), (False, True)])
def test_encoded_d1_decodes_within_quantisation(interleave, invert):
    frames, _, _ = split_stream(_stream(11, interleave, invert))
    nav, st = sfrbx_ephemerides(frames, week_ref=WN + 1356)
    assert st["beidou_subframes"] == 3 and st["beidou_bch_failures"] == 0 and len(nav) == 1
    r = nav.iloc[0]
    assert r["sat"] == "C11" and r["week"] == WN and r["iode"] == AODE and r["iodc"] == AODC
    assert r["toe_sow_s"] == TOE and r["toe_gps_s"] == bdt_to_gps_s(WN, TOE) == (WN + 1356) * 604800 + TOE + 14
    assert r["toc_gps_s"] == r["toe_gps_s"] and r["transmit_gps_s"] == bdt_to_gps_s(WN, SOW) and r["sv_accuracy_m"] == 4.85
    for name, _, scale, _, col, semi in SCALES:
        got = r[col] / GPS_PI if semi else r[col]
        assert abs(got - EPH[name]) <= 0.5 * scale * (1 + 1e-9), col
    # the decoded orbit is the original one to the quantisation: positions within millimetres
    ref = pd.Series({col: EPH[name] * (GPS_PI if semi else 1.0) for name, _, _, _, col, semi in SCALES})
    ref = pd.concat([ref, r[["sat", "toe_gps_s", "toc_gps_s", "toe_sow_s"]]])
    t = r["toe_gps_s"] + 600.0 * pd.Series(range(-6, 7)).to_numpy()
    a, _ = sat_position_ecef(r, t)
    b, _ = sat_position_ecef(ref, t)
    assert abs(a - b).max() < 0.05


def test_a_flipped_bit_fails_bch_and_drops_the_subframe():
    frames, _, _ = split_stream(_stream(11, flip=(1, 4, 10)))       # a bit of word 5 of subframe 1
    nav, st = sfrbx_ephemerides(frames, week_ref=WN + 1356)
    assert st["beidou_bch_failures"] == 1 and st["beidou_subframes"] == 2 and len(nav) == 0


def test_geo_d2_frames_are_counted_not_decoded():
    frames, _, _ = split_stream(_stream(3))
    nav, st = sfrbx_ephemerides(frames, week_ref=WN + 1356)
    assert st["beidou_d2_frames"] == 3 and len(nav) == 0


def test_beidou_records_reach_the_run_of_a_ubx_pair(tmp_path):
    """A u-blox pair whose base log also carries BeiDou D1 subframes: ingest keeps the BeiDou record
    in the run's ephemerides next to the GPS ones (the same NAV_COLUMNS record)."""
    from click.testing import CliRunner

    from cdgps_cli.cli.commands import main
    from cdgps_cli.io.gnss_run import read_gnss_run
    from tests.io.test_sfrbx import _pair

    b, r = _pair(tmp_path)
    b.write_bytes(_stream(11) + b.read_bytes())
    run = tmp_path / "run.mcap"
    res = CliRunner().invoke(main, ["ingest", "--ubx", f"base={b}", "--ubx", f"rover={r}", "--master", "base", "-o", str(run)])
    assert res.exit_code == 0, res.output
    nav = read_gnss_run(run).nav
    assert sorted(nav["sat"]) == ["C11", "G06", "G07", "G11", "G29"]
    c = nav[nav["sat"] == "C11"].iloc[0]
    assert c["toe_gps_s"] == bdt_to_gps_s(WN, TOE) and c["week"] == WN and c["iode"] == AODE
    assert abs(c["sqrt_a_sqrt_m"] - EPH["sqrta"]) <= 2.0**-20
