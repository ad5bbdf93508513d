"""GLONASS strings from u-blox RXM-SFRBX (io/sfrbx_glonass.py) on two real logs and an independent
Hamming encoder.

* tests/data/ublox-glo.log (gpsd test/daemon, BSD-2): u-blox SPG 5.10 (M10), Moscow, 2023-06-28 per its
  header comment; NAV-PVT, NAV-TIMEGPS, NAV-SAT and 584 GLONASS RXM-SFRBX frames.
* tests/data/pygpsdata_testobsnavdata.log (pygnssutils, BSD-3): RXM-RAWX with GLONASS L1OF and 491
  GLONASS frames (see tests/io/test_sfrbx_real.py).

Checks: every real string passes the Hamming check (a wrong bit layout would pass 1 in 256); the
encoder here builds the check bits from the parity-check matrix column by column; the decoded records
give the date of the log's header, the receiver's own azimuth/elevation (NAV-SAT, whole degrees) and
its own GLONASS pseudoranges, which an 18 s leap-second error would not.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.core.gps_time import gps_time_str
from cdgps_cli.io.sfrbx import sfrbx_ephemerides
from cdgps_cli.io.sfrbx_glonass import glonass_string
from cdgps_cli.io.ubx import _decode_rawx_frames
from cdgps_cli.io.ubx_frames import split_stream
from cdgps_cli.model.gps.orbits import azimuth_elevation, ecef_to_geodetic, geodetic_to_ecef, sat_position_at_reception
from cdgps_cli.model.gps.positioning import tropo_hydrostatic_m

DATA = Path(__file__).resolve().parents[1] / "data"


def _encode(data77: list[int]) -> list[int]:
    """Three u-blox words of a string with data bits b9…b85 = ``data77`` (b85 first; b85 must be 0):
    the Hamming column of data bit i is its position among the integers ≥ 3 that are not powers of
    two; β_j (bit j) is the parity of the data bits whose column has bit j − 1 set; β8 the parity of all."""
    bits = dict(zip(range(85, 8, -1), data77))
    cols = [c for c in range(3, 200) if c & (c - 1)][:77]
    for j in range(7):
        bits[j + 1] = sum(bits[i] for i, c in zip(range(9, 86), cols) if c >> j & 1) % 2
    bits[8] = (sum(bits[i] for i in range(9, 86)) + sum(bits[j] for j in range(1, 8))) % 2
    v = sum(bits[i] << (i - 1) for i in range(1, 86)) << 11
    return [(v >> 64) & 0xFFFFFFFF, (v >> 32) & 0xFFFFFFFF, v & 0xFFFFFFFF, 0]


def test_encoded_strings_pass_and_single_flips_fail():
    gen = np.random.default_rng(1)
    for _ in range(20):
        data = [0] + gen.integers(0, 2, 76).tolist()
        w = _encode(data)
        s = glonass_string(w)
        assert s is not None and [(s >> (i - 1)) & 1 for i in range(85, 8, -1)] == data
        for bit in gen.choice(85, 5, replace=False):
            flipped = list(w)
            pos = 11 + int(bit)                                            # a bit of the 85 in the 96
            flipped[2 - pos // 32] ^= 1 << (pos % 32)
            assert glonass_string(flipped) is None


def _frames(name):
    return split_stream((DATA / name).read_bytes())[0]


def test_gpsd_m10_log_strings_and_sky_positions():
    ubx = _frames("ublox-glo.log")
    nav, st = sfrbx_ephemerides(ubx, 2268, glonass=True)
    assert st["glonass_strings"] == 584 and st["glonass_hamming_failures"] == 0
    assert sorted(nav["sat"]) == ["R02", "R03", "R11", "R12"] and set(nav["glonass_k"]) == {-4, 5, 0, -1}
    assert all(gps_time_str(t).startswith("2023-06-28") for t in nav["toe_gps_s"])        # the header's date
    t_gps, pos, sky = {}, {}, []
    for _, c, m, fr in ubx:
        pl = fr[6:-2]
        if (c, m) == (0x01, 0x20):                                          # NAV-TIMEGPS
            itow, _, week = struct.unpack_from("<IiH", pl, 0)
            t_gps[itow] = week * 604800.0 + itow / 1000.0
        elif (c, m) == (0x01, 0x07):                                        # NAV-PVT
            lon, lat, h = struct.unpack_from("<iii", pl, 24)
            pos[struct.unpack_from("<I", pl, 0)[0]] = geodetic_to_ecef(np.radians(lat * 1e-7), np.radians(lon * 1e-7), h * 1e-3)
        elif (c, m) == (0x01, 0x35):                                        # NAV-SAT, every 10th second
            itow = struct.unpack_from("<I", pl, 0)[0]
            if (itow // 1000) % 10:
                continue
            for k in range(pl[5]):
                g, sv, _, el = struct.unpack_from("<BBBb", pl, 8 + 12 * k)
                if g == 6 and f"R{sv:02d}" in set(nav["sat"]) and el > 5:
                    sky.append((itow, f"R{sv:02d}", el, struct.unpack_from("<h", pl, 12 + 12 * k)[0]))
    d_el, d_az = [], []
    for itow, sat, el, az in sky:
        if itow not in t_gps or itow not in pos:
            continue
        g = sat_position_at_reception(nav, sat, np.array([t_gps[itow]]), pos[itow])
        a, e = azimuth_elevation(pos[itow], g.xyz_m)
        d_el.append(np.degrees(e[0]) - el)
        d_az.append((np.degrees(a[0]) - az + 180.0) % 360.0 - 180.0)
    assert len(d_el) > 100
    assert np.abs(d_el).max() < 1.0 and np.abs(d_az).max() < 2.0            # NAV-SAT gives whole degrees


@pytest.fixture(scope="module")
def f9():
    ubx = _frames("pygpsdata_testobsnavdata.log")
    ep, meas, _ = _decode_rawx_frames([(o, fr) for o, c, m, fr in ubx if (c, m) == (0x02, 0x15)])
    nav, st = sfrbx_ephemerides(ubx, int(ep["week"][0]), glonass=True)
    return nav, st, ep, meas


def _glonass_residuals(nav, ep, meas, x):
    """G1 pseudorange residuals at the known position ``x``, one receiver clock per epoch (median),
    per satellite (mean, scatter about it)."""
    t_ep = ep["week"].astype(float) * 604800.0 + ep["rcvTow"]
    m = meas[(meas["gnssId"] == 6) & (meas["sigId"] == 0) & ((meas["trkStat"] & 1) == 1)]
    lat, lon, h = ecef_to_geodetic(x)
    res, epo, sat = [], [], []
    for sv in np.unique(m["svId"]):
        if f"R{sv:02d}" not in set(nav["sat"]):
            continue                                                        # tracked, no complete frame
        mm = m[m["svId"] == sv]
        g = sat_position_at_reception(nav, f"R{sv:02d}", t_ep[mm["epoch"]], x)
        el = azimuth_elevation(x, g.xyz_m)[1]
        res.append(mm["prMes"] - (g.range_m - SPEED_OF_LIGHT_M_S * g.clock_s + tropo_hydrostatic_m(el, lat, h, t_ep[mm["epoch"]])))
        epo.append(mm["epoch"])
        sat += [sv] * len(mm)
    res, epo, sat = np.concatenate(res), np.concatenate(epo), np.array(sat)
    clock = {e: np.median(res[epo == e]) for e in np.unique(epo)}
    post = res - np.array([clock[e] for e in epo])
    return {s: (post[sat == s].mean(), post[sat == s].std()) for s in np.unique(sat)}


def test_f9_glonass_records_explain_its_pseudoranges(f9):
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from test_sfrbx_real import _pseudorange_fit  # noqa: PLC0415

    nav, st, ep, meas = f9
    assert st["glonass_strings"] == 491 and st["glonass_hamming_failures"] == 0
    glo = nav[nav["sat"].str[0] == "R"]
    assert len(glo) == 8 and glo["glonass_k"].between(-7, 6).all()
    x, _, _ = _pseudorange_fit(nav[nav["sat"].str[0] != "R"], ep, meas)      # position from G, E, C
    per_sat = _glonass_residuals(nav, ep, meas, x)
    assert len(per_sat) == 8
    # L1 only, no ionosphere model, FDMA inter-frequency biases: metre-level scatter, tens of m offsets
    assert all(sd < 5.0 and abs(mean) < 40.0 for mean, sd in per_sat.values()), per_sat
    late = nav.copy()
    late.loc[late["sat"].str[0] == "R", ["toe_gps_s", "toc_gps_s"]] += 18.0              # leap seconds forgotten
    bad = _glonass_residuals(late, ep, meas, x)
    assert max(sd for _, sd in bad.values()) > 300.0
