"""sat_positions_at_reception (all satellites at once, ephemerides selected once) against one
sat_position_at_reception call per satellite, which it replaces in the receiver-clock and geometry
loops: the same positions, clocks, ranges and travel times to the bit, and the same errors, on the
navigation files of the shared data (GPS, Galileo, BeiDou with its GEOs, GLONASS)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import NAV_SYSTEMS, read_rinex_nav
from cdgps_cli.model.gps import orbits
from cdgps_cli.model.gps.orbits import (
    reception_ephemeris,
    sat_position_at_reception,
    sat_positions_at_reception,
)

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
NAV_FILES = ["real-pairs/geonet-car/SEPT2650.21P", "real-pairs/mosaic-static/base.nav",
             "rinex-ge/RINEX_GN_Spirent.23N", "rinex-ge/RINEX_EN_Spirent.23L", "rinex/07590920.05n"]
RX = np.array([-3961904.0, 3348993.0, 3698211.0])


def _navs():
    for rel in NAV_FILES:
        try:
            nav = read_rinex_nav(SHARED / rel, systems="".join(NAV_SYSTEMS))
        except CdgpsError:
            continue
        if len(nav):
            yield rel, nav


def _rows(nav, rng):
    """Rows of every satellite at times near its healthy toes, shuffled together."""
    sats, t = [], []
    for sat in sorted(nav["sat"].unique()):
        toe = nav.loc[(nav["sat"] == sat) & (nav["sv_health"] == 0), "toe_gps_s"].to_numpy()
        if toe.size == 0:
            continue
        tt = np.sort(rng.choice(toe, 40) + rng.uniform(-900.0, 900.0, 40))
        sats += [sat] * tt.size
        t.append(np.round(tt))
    order = rng.permutation(len(sats))
    return np.array(sats, dtype=object)[order], np.concatenate(t)[order]


def _reference(nav, sats, t, rx, clock):
    out = [np.empty((t.size, 3)), np.empty(t.size), np.empty(t.size), np.empty(t.size)]
    for sat in sorted(set(sats)):
        idx = np.flatnonzero(sats == sat)
        g = sat_position_at_reception(nav, sat, t[idx], rx[idx] if rx.ndim == 2 else rx, rx_clock_s=clock[idx])
        for a, v in zip(out, g):
            a[idx] = v
    return out


@pytest.mark.parametrize("chunk", [orbits.CHUNK_ROWS, 50])
@pytest.mark.parametrize("rel,nav", list(_navs()), ids=lambda x: x if isinstance(x, str) else "")
def test_same_bits_as_one_call_per_satellite(rel, nav, chunk, monkeypatch):
    monkeypatch.setattr(orbits, "CHUNK_ROWS", chunk)          # 50: several satellites' runs, and one each
    rng = np.random.default_rng(7)
    sats, t = _rows(nav, rng)
    clock = rng.uniform(-5e-3, 5e-3, t.size)
    for rx in (RX, RX + rng.normal(0.0, 50.0, (t.size, 3))):
        ref = _reference(nav, sats, t, rx, clock)
        eph = reception_ephemeris(nav, sats, t)
        for got in (sat_positions_at_reception(nav, sats, t, rx, rx_clock_s=clock),
                    sat_positions_at_reception(nav, sats, t, rx, rx_clock_s=clock, ephemeris=eph)):
            for a, b in zip(ref, got):
                np.testing.assert_array_equal(a, b)


def test_same_error_for_an_uncovered_satellite():
    nav = read_rinex_nav(SHARED / "rinex" / "07590920.05n")
    sats = np.array(sorted(nav["sat"].unique())[:3], dtype=object)
    toe = [nav.loc[nav["sat"] == s, "toe_gps_s"].iloc[0] for s in sats]
    t = np.array([toe[0], toe[1], nav["toe_gps_s"].max() + 9e4])
    with pytest.raises(CdgpsError) as want:
        sat_position_at_reception(nav, sats[2], t[2:], RX)
    with pytest.raises(CdgpsError) as got:
        sat_positions_at_reception(nav, sats, t, RX)
    assert str(got.value) == str(want.value)


def test_reception_geometry_with_a_shared_selection():
    """Two receivers' geometry of the same rows from one ephemeris selection: the same bits as each
    selecting its own (what baseline._prepare could do for the master and the rover)."""
    from cdgps_cli.model.gps.positioning import reception_geometry  # noqa: PLC0415

    nav = read_rinex_nav(SHARED / "real-pairs" / "mosaic-static" / "base.nav", systems="".join(NAV_SYSTEMS))
    rng = np.random.default_rng(3)
    sats, t = _rows(nav, rng)
    eph = reception_ephemeris(nav, sats, t)
    for rx in (RX, RX + 3000.0):
        tt = t - rng.uniform(-1e-3, 1e-3, t.size)
        a = reception_geometry(nav, sats, t, tt, rx)
        b = reception_geometry(nav, sats, t, tt, rx, ephemeris=eph)
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])


@pytest.mark.parametrize("kernel", [True, False], ids=["kernel", "numpy"])
@pytest.mark.parametrize("rel,nav", list(_navs()), ids=lambda x: x if isinstance(x, str) else "")
def test_a_row_gives_the_same_bits_whatever_rows_come_with_it(rel, nav, kernel, monkeypatch):
    """Each row's light time, Kepler equation and GLONASS integration stop on its own tests, so a row's position,
    clock, range and travel time do not depend on the other rows of the call: all rows at once, every satellite's
    first half alone, and single rows give the same bits (a window of a record gives the whole record's values,
    issue 29; before, a satellite's rows iterated in lockstep and GLONASS took the call's longest step count).
    Independent of the code: the rows alone, one call each."""
    if not kernel:
        monkeypatch.setenv("CDGPS_NO_KERNEL", "1")
    rng = np.random.default_rng(17)
    sats, t = _rows(nav, rng)
    clock = rng.uniform(-5e-3, 5e-3, t.size)
    rx = RX + rng.normal(0.0, 50.0, (t.size, 3))
    whole = sat_positions_at_reception(nav, sats, t, rx, rx_clock_s=clock)
    half = np.flatnonzero(t < np.median(t))                  # a window of every satellite's rows
    part = sat_positions_at_reception(nav, sats[half], t[half], rx[half], rx_clock_s=clock[half])
    for a, b in zip(whole, part):
        assert a[half].tobytes() == b.tobytes()
    for i in rng.choice(t.size, 12, replace=False):          # rows alone, by both functions
        alone = sat_positions_at_reception(nav, sats[i:i + 1], t[i:i + 1], rx[i:i + 1], rx_clock_s=clock[i:i + 1])
        single = sat_position_at_reception(nav, sats[i], t[i:i + 1], rx[i], rx_clock_s=clock[i:i + 1])
        for a, b, c in zip(whole, alone, single):
            assert a[i:i + 1].tobytes() == b.tobytes() == c.tobytes()
