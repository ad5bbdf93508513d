"""QZSS LNAV subframes from RXM-SFRBX (gnssId 5, L1 C/A) and the QZSS health rule.

Real: a u-blox ZED-F9P log of 40 s at Hiroshima (tests/data/qzsl6tool-f9p-hiroshima) whose SFRBX frames hold QZSS
subframes: the four QZSS ephemerides decoded from them put the log's own QZSS pseudoranges within 3.6 m (mean,
each satellite) of the position and clock its GPS pseudoranges give — a wrong field would be kilometres off.

QZSS broadcasts on L1 C/A the GPS LNAV subframes (IS-QZSS-PNT: layout, parity, week and scale factors of
IS-GPS-200), so the GPS encoder of test_sfrbx.py makes them: the same subframes sent as GPS and as QZSS give the
same record but for the satellite (``G07`` / ``J02``) and the fit interval (QZSS's flag 0 is 2 h).  The batch
decoding equals the frame-by-frame walk on a log holding both.  A QZSS record flagged only in the least
significant health bit (not a ranging signal's; RTKLIB ignores it too) is healthy, as in the real mosaic pair's
navigation file, whose J02, J03 and J07 records all carry ``sv_health`` 1.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.io import sfrbx
from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.io.ubx_frames import split_stream
from cdgps_cli.model.gps.orbits import healthy_ephemeris, select_ephemeris
from tests.io.test_sfrbx import EPH, _encode_subframe, _sfrbx, _with_parity

MOSAIC_NAV = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real-pairs" / "mosaic-static" / "base.nav"
F9P_HIROSHIMA = Path(__file__).resolve().parents[1] / "data" / "qzsl6tool-f9p-hiroshima" / "20230919-114418.ubx"


def _subframes(gnss: int, sv: int, tow0: int, sig: int = 0) -> bytes:
    f = dict(EPH, iodc_msb=EPH["iodc"] >> 8, iodc_lsb=EPH["iodc"] & 0xFF)
    return b"".join(_sfrbx(sv, _with_parity(_encode_subframe(s, f, tow0 + s)), gnss, sig) for s in (1, 2, 3))


def _decode(data: bytes, batch: bool):
    old = sfrbx.BATCH
    try:
        sfrbx.BATCH = batch
        return sfrbx.sfrbx_ephemerides(split_stream(data)[0], week_ref=2345)
    finally:
        sfrbx.BATCH = old


def test_qzss_subframes_decode_as_the_same_gps_subframes_do():
    tow0 = 216000 // 6 - 20
    data = _subframes(0, 7, tow0) + _subframes(5, 2, tow0) + _subframes(5, 3, tow0, sig=4)   # J03: L2C, not LNAV
    for batch in (False, True):
        nav, st = _decode(data, batch)
        assert st["gps_subframes"] == 3 and st["qzss_subframes"] == 3 and st["qzss_cnav_frames"] == 3
        assert st["parity_failures"] == 0 and st["other_systems"] == {}
        assert nav["sat"].tolist() == ["G07", "J02"]
        g, j = nav.iloc[0], nav.iloc[1]
        assert g["fit_interval_h"] == 4.0 and j["fit_interval_h"] == 2.0
        same = [c for c in nav.columns if c not in ("sat", "fit_interval_h")]
        pd.testing.assert_series_equal(g[same], j[same], check_names=False)
    walk, batch = _decode(data, False), _decode(data, True)
    assert walk[1] == batch[1] and walk[0].equals(batch[0])


def test_the_least_significant_qzss_health_bit_is_ignored_and_the_others_are_not():
    sats = np.array(["G01", "G01", "J02", "J02", "J02", "J02"], dtype=object)
    assert healthy_ephemeris(sats, [0, 1, 0, 1, 2, 63]).tolist() == [True, False, True, True, False, False]
    nav = pd.DataFrame({"sat": ["J02", "J02"], "sv_health": [1.0, 3.0], "toe_gps_s": [1000.0, 1100.0]})
    assert select_ephemeris(nav, "J02", 1090.0)["toe_gps_s"] == 1000.0      # the nearer toe is unhealthy (bit 2)


def test_the_real_mosaic_pairs_qzss_records_are_usable():
    if not MOSAIC_NAV.exists():
        import pytest

        pytest.skip("../shared/data/real-pairs absent")
    nav = read_rinex_nav(MOSAIC_NAV, systems=("J",))
    assert set(nav["sat"]) == {"J02", "J03", "J07"} and (nav["sv_health"] == 1).all()
    assert healthy_ephemeris(nav["sat"].to_numpy(), nav["sv_health"].to_numpy()).all()
    assert (nav["fit_interval_h"] == 2.0).all()                              # the files' flag 0


def test_qzss_records_written_and_read_again_are_the_same(tmp_path):
    if not MOSAIC_NAV.exists():
        import pytest

        pytest.skip("../shared/data/real-pairs absent")
    from cdgps_cli.io.rinex_write import write_rinex_nav

    nav = read_rinex_nav(MOSAIC_NAV, systems=("G", "J"))
    write_rinex_nav(tmp_path / "x.rnx", nav)                  # (QZSS's fit interval written back as its flag)
    assert "J02 2024 06 24 09 00 00" in (tmp_path / "x.rnx").read_text()
    back = read_rinex_nav(tmp_path / "x.rnx", systems=("G", "J"))
    cols = [c for c in nav.columns if c != "line"]
    assert nav[cols].reset_index(drop=True).equals(back[cols].reset_index(drop=True))


def test_the_real_f9p_logs_qzss_ephemerides_explain_its_qzss_pseudoranges():
    from cdgps_cli.estimation.rtk_multi import receiver_geometry
    from cdgps_cli.io.ubx import read_ubx_log, read_ubx_signals
    from cdgps_cli.model.gps.positioning import spp_spread

    info, _, nav = read_ubx_log(F9P_HIROSHIMA)
    st = info["sfrbx"]                       # 12 L2C frames and 148 L1S frames (nine words) counted, not decoded
    assert st["qzss_subframes"] == 16 and st["qzss_cnav_frames"] == 160 and st["parity_failures"] == 0
    assert "5" not in st["other_systems"]
    qzss = nav[nav["sat"].str.startswith("J")]
    assert qzss["sat"].tolist() == ["J02", "J03", "J04", "J07"] and (qzss["sv_health"] == 0).all()
    assert (np.abs(qzss["sqrt_a_sqrt_m"] ** 2 - 42_164e3) < 100e3).all()          # IGSO / GEO semi-major axes
    tab = read_ubx_signals(F9P_HIROSHIMA, ["G:L1", "J:L1"])
    gps = tab[tab["signal"] == "G:L1"]
    x = spp_spread(gps["sat"].to_numpy(), gps["time_gps_s"].to_numpy(), gps["pseudorange_m"].to_numpy(), nav)
    g = receiver_geometry(tab, nav, x)
    res = (g["pseudorange_m"] - np.linalg.norm(g[["sx", "sy", "sz"]].to_numpy() - x, axis=1) + g["sat_clock_m"]
           - g["trop_m"])
    g = g.assign(res=res - g["time_gps_s"].map(res[g["signal"] == "G:L1"].groupby(g["time_gps_s"]).median()))
    per_sat = g[g["signal"] == "J:L1"].groupby("sat")["res"].agg(["mean", "std", "size"])
    assert per_sat.index.tolist() == ["J02", "J03", "J04", "J07"] and (per_sat["size"] == 36).all()
    assert (per_sat["mean"].abs() < 6.0).all() and (per_sat["std"] < 1.0).all(), per_sat     # m (3.6 m at most)
