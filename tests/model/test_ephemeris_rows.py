"""ephemeris_rows + sat_position_rows (row positions and orbit constants, no DataFrame of N ephemerides)
against select_ephemerides + sat_position_ecef, which they replace in rtk_multi.receiver_geometry: the same
positions and clocks to the bit, and the same error, on the navigation files of the shared data (GPS,
Galileo, BeiDou with its GEOs, GLONASS, and all of them mixed in one table)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.gps.orbits import ephemeris_rows, sat_position_ecef, sat_position_rows, select_ephemerides
from tests.model.test_positions_at_reception import _navs, _rows

NAVS = list(_navs())


def _same(a, b) -> bool:
    return a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.skipif(not NAVS, reason="../shared/data navigation files absent")
@pytest.mark.parametrize("tgd,chunk", [(True, 65536), (False, 65536), (True, 7)])
def test_rows_give_sat_position_ecef_bit_for_bit(tgd, chunk, monkeypatch):
    from cdgps_cli.model.gps import orbits
    monkeypatch.setattr(orbits, "CHUNK_ROWS", chunk)        # the orbit after Kepler's equation, chunk by chunk
    rng = np.random.default_rng(5)
    navs = NAVS + [("all", pd.concat([n for _, n in NAVS], ignore_index=True))]
    for name, nav in navs:
        sats, t = _rows(nav, rng)
        eph, table = ephemeris_rows(nav, sats, t), select_ephemerides(nav, sats, t)
        for dt in (0.075, 0.0712345):
            want = sat_position_ecef(table, t - dt, apply_tgd=tgd)
            got = sat_position_rows(eph, t - dt, apply_tgd=tgd)
            assert _same(got[0], want[0]) and _same(got[1], want[1]), name
        only = np.flatnonzero(np.char.startswith(sats.astype(str), "G"))
        if only.size:                                  # a table without GLONASS: the one-block Kepler path
            e1 = ephemeris_rows(nav, sats[only], t[only])
            w1 = sat_position_ecef(select_ephemerides(nav, sats[only], t[only]), t[only] - 0.07, apply_tgd=tgd)
            g1 = sat_position_rows(e1, t[only] - 0.07, apply_tgd=tgd)
            assert _same(g1[0], w1[0]) and _same(g1[1], w1[1]), name


@pytest.mark.skipif(not NAVS, reason="../shared/data navigation files absent")
def test_uncovered_rows_raise_as_select_ephemerides():
    nav = NAVS[0][1]
    sat = sorted(nav["sat"].unique())[0]
    far = float(nav["toe_gps_s"].max()) + 86400.0
    with pytest.raises(CdgpsError) as a:
        select_ephemerides(nav, np.array([sat, sat], dtype=object), np.array([far, far]))
    with pytest.raises(CdgpsError) as b:
        ephemeris_rows(nav, np.array([sat, sat], dtype=object), np.array([far, far]))
    assert str(a.value) == str(b.value)
    e = ephemeris_rows(nav, np.array([], dtype=object), np.array([]))
    assert sat_position_rows(e, np.array([]))[0].shape == (0, 3)
    with pytest.raises(ValueError):
        sat_position_rows(e, np.array([1.0]))
