"""RXM-SFRBX of real u-blox receivers (io/sfrbx.py): GPS LNAV parity in the u-blox form, CNAV and
B-CNAV frames counted apart, BeiDou D1 ephemerides checked against the receiver's own pseudoranges.

tests/data/pygpsdata_testobsnavdata.log (pygnssutils tests, BSD-3): a u-blox F9-class receiver near
Manchester, GPS week 2414 (2026-04), 75 s of RXM-RAWX at 1 Hz with GPS, Galileo, BeiDou B1I and
GLONASS, and RXM-SFRBX of all four systems.  Independent checks: the parity equations of IS-GPS-200
Table 20-XIV written out here bit by bit; the decoded GPS, Galileo and BeiDou ephemerides explain the
receiver's pseudoranges (a least-squares position and one clock per epoch and system), which a BDT
offset error of 14 s would not.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.io.sfrbx import gps_words_from_sfrbx, sfrbx_ephemerides, subframe_id
from cdgps_cli.io.ubx import _decode_rawx_frames
from cdgps_cli.io.ubx_frames import split_stream
from cdgps_cli.model.gps.orbits import azimuth_elevation, ecef_to_geodetic, sat_position_at_reception
from cdgps_cli.model.gps.positioning import tropo_hydrostatic_m

LOG = Path(__file__).resolve().parents[1] / "data" / "pygpsdata_testobsnavdata.log"

# IS-GPS-200 Table 20-XIV: parity bit ← previous word's D29*/D30* ⊕ the listed source data bits
PARITY = ((29, (1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23)), (30, (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24)),
          (29, (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22)), (30, (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23)),
          (30, (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24)), (29, (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24)))

# pyubx2 tests/pygpsdata-ALL.log (BSD-3): its only RXM-SFRBX frame, G05 (u-blox M8), the ten dwords
ALL_LOG_G05 = (0x22C0502E, 0x92D16C80, 0x1789BCED, 0x98FF4950, 0x3F50000F, 0x284308F0, 0x24BD152A, 0xA35BC727,
               0x2DC7C349, 0xB57FF4E0)


def _parity_ok_bitwise(dword: int) -> bool:
    """Parity of a u-blox GPS dword: source data bits 29…6, parity 5…0, previous D29*/D30* in bits 31/30."""
    d = [(dword >> (29 - k)) & 1 for k in range(24)]                 # d1 … d24
    prev = {29: (dword >> 31) & 1, 30: (dword >> 30) & 1}
    par = [prev[p] ^ (sum(d[b - 1] for b in bits) & 1) for p, bits in PARITY]
    return par == [(dword >> (5 - k)) & 1 for k in range(6)]


@pytest.fixture(scope="module")
def log():
    ubx, _, _ = split_stream(LOG.read_bytes())
    ep, meas, bad = _decode_rawx_frames([(o, fr) for o, c, m, fr in ubx if (c, m) == (0x02, 0x15)])
    assert not bad and len(ep) == 75
    return ubx, ep, meas


def test_every_l1ca_subframe_passes_parity_in_the_ublox_form(log):
    ubx, *_ = log
    n = 0
    for _, c, m, fr in ubx:
        pl = fr[6:-2]
        if (c, m) != (0x02, 0x13) or pl[0] != 0 or pl[2] != 0:
            continue
        dw = np.frombuffer(pl[8:48], dtype="<u4").tolist()
        assert all(_parity_ok_bitwise(w) for w in dw)                  # the independent check
        words = gps_words_from_sfrbx(dw)
        assert words == [(w >> 6) & 0xFFFFFF for w in dw] and (words[0] >> 16) == 0x8B
        n += 1
    assert n == 40


def test_the_pygpsdata_all_frame_is_a_valid_subframe_4():
    """The frame our decoder used to reject: every word passes once D29*/D30* are taken from bits 31-30."""
    assert all(_parity_ok_bitwise(w) for w in ALL_LOG_G05)
    words = gps_words_from_sfrbx(list(ALL_LOG_G05))
    assert words is not None and subframe_id(words) == 4
    assert gps_words_from_sfrbx([ALL_LOG_G05[0] ^ (1 << 12), *ALL_LOG_G05[1:]]) is None   # a flipped bit


def test_frame_counts_of_the_real_log(log):
    ubx, ep, _ = log
    nav, st = sfrbx_ephemerides(ubx, int(ep["week"][0]))
    assert st["parity_failures"] == 0 and st["gps_subframes"] == 27 and st["gps_cnav_frames"] == 12
    assert st["beidou_subframes"] == 28 and st["beidou_bch_failures"] == 0 and st["beidou_cnav_frames"] == 0
    assert st["galileo_bad_pages"] == 0 and st["galileo_other_frames"] == 0 and st["galileo_words"] == 143
    assert st["other_systems"] == {"6": 491}
    assert sorted(nav["sat"]) == ["C29", "C30", "C36", "C47", "E05", "E15", "E27", "E30", "E34", "G01", "G02", "G22"]
    c = nav[nav["sat"].str[0] == "C"]
    assert (c["week"] == 1058).all() and (c["toe_sow_s"] == 136800.0).all()                 # BDT week 1058 = GPS 2414
    assert np.allclose(c["toe_gps_s"], (1058 + 1356) * 604800.0 + 136800.0 + 14.0)


def _pseudorange_fit(nav, ep, meas, bdt_error_s: float = 0.0):
    """Static position + a clock per epoch and system from the L1/E1/B1I/G1 pseudoranges (every 5th epoch)
    of the satellites with a decoded ephemeris (hydrostatic troposphere, no ionosphere); residuals per system."""
    letters = {0: "G", 2: "E", 3: "C", 6: "R"}
    nav = nav.copy()
    bds = nav["sat"].str[0] == "C"
    nav.loc[bds, ["toe_gps_s", "toc_gps_s"]] += bdt_error_s
    t_ep = ep["week"].astype(float) * 604800.0 + ep["rcvTow"]
    keep = np.isin(meas["gnssId"], list(letters)) & ((meas["trkStat"] & 1) == 1)
    keep &= (meas["sigId"] == 0) | ((meas["gnssId"] == 2) & (meas["sigId"] == 1))      # L1 C/A, E1, B1I, L1OF
    keep &= meas["epoch"] % 5 == 0                                      # every 5th epoch: 15 of 75
    m = meas[keep]
    sat = np.array([f"{letters[g]}{s:02d}" for g, s in zip(m["gnssId"], m["svId"])], dtype=object)
    use = np.isin(sat, nav["sat"].to_numpy())
    m, sat = m[use], sat[use]
    systems = sorted(set(s[0] for s in sat))
    col = 3 + m["epoch"] * len(systems) + np.array([systems.index(s[0]) for s in sat])
    x = np.array([3.8e6, -1.5e5, 5.1e6])
    for _ in range(8):
        model, u = np.empty(len(m)), np.empty((len(m), 3))
        lat, lon, h = ecef_to_geodetic(x)
        for s in np.unique(sat):
            k = np.flatnonzero(sat == s)
            g = sat_position_at_reception(nav, s, t_ep[m["epoch"][k]], x)
            el = azimuth_elevation(x, g.xyz_m)[1]
            model[k] = g.range_m - SPEED_OF_LIGHT_M_S * g.clock_s + tropo_hydrostatic_m(el, lat, h, t_ep[m["epoch"][k]])
            u[k] = (g.xyz_m - x) / g.range_m[:, None]
        a = np.zeros((len(m), 3 + len(ep) * len(systems)))
        a[:, :3] = -u
        a[np.arange(len(m)), col] = 1.0
        a = a[:, np.abs(a).sum(axis=0) > 0]
        res = m["prMes"] - model
        dx = np.linalg.lstsq(a, res, rcond=None)[0]
        x = x + dx[:3]
        if np.linalg.norm(dx[:3]) < 1e-3:
            break
    post = res - a @ dx
    return x, {c: float(np.sqrt(np.mean(post[[s[0] == c for s in sat]] ** 2))) for c in systems}, sat


def test_decoded_ephemerides_explain_the_receivers_pseudoranges(log):
    ubx, ep, meas = log
    nav, _ = sfrbx_ephemerides(ubx, int(ep["week"][0]))
    x, rms, sat = _pseudorange_fit(nav, ep, meas)
    lat, lon, h = ecef_to_geodetic(x)
    assert 53.0 < np.degrees(lat) < 54.0 and -3.0 < np.degrees(lon) < -1.5 and 0.0 < h < 300.0
    assert set(sat) >= {"C29", "C30", "C36", "C47"}
    assert rms["C"] < 2.0 and rms["G"] < 2.5 and rms["E"] < 3.0, rms          # no ionosphere model: metres
    _, rms_bad, _ = _pseudorange_fit(nav, ep, meas, bdt_error_s=14.0)           # BDT taken as GPST
    assert rms_bad["C"] > 20.0 * rms["C"], rms_bad


def test_galileo_fnav_frames_are_counted_apart(log):
    """A Galileo frame of sigId 3 (E5a F/NAV) is not an I/NAV page pair: counted apart, not as a bad page."""
    ubx, ep, _ = log
    inav = [f for f in ubx if (f[1], f[2]) == (0x02, 0x13) and f[3][6] == 2]
    off, c, m, fr = inav[0]
    pl = bytearray(fr[6:-2])
    pl[2] = 3
    body = bytes((0x02, 0x13)) + len(pl).to_bytes(2, "little") + bytes(pl)
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    frames = split_stream(b"\xb5\x62" + body + bytes((a, b)))[0]
    _, st = sfrbx_ephemerides(frames, int(ep["week"][0]))
    assert st["galileo_other_frames"] == 1 and st["galileo_bad_pages"] == 0 and st["galileo_words"] == 0
