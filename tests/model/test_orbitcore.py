"""The compiled orbit kernel (cdgps_cli.model.gps._orbitcore) against the numpy functions it replaces, bit for bit:
sat_positions_at_reception (light time and Kepler's equation, each row on its own, rows kept across light-time
iterations), sat_position_rows (each row on its own), and the kernel's own memory of earlier calls (a row keeps its steps
and its orbit only where that gives the values of a fresh evaluation).  The equality rests on numpy's float64
sin/cos being libm's (as on this project's machines) and on numpy's arctan2 being applied to the kernel's output."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.model.gps import orbits
from cdgps_cli.model.gps.positioning import synthetic_nav
from tests.model.test_positions_at_reception import RX, _navs, _rows

pytestmark = pytest.mark.skipif(not orbits.kernel_available(), reason="compiled orbit kernel not built")
NAVS = list(_navs())


def _synthetic():
    """GPS, Galileo and BeiDou (GEO, IGSO, MEO) records over two hours, and rows of every satellite."""
    t0 = 1_300_000_000.0
    nav = synthetic_nav("GEC", t0, 7200.0, seed=4)
    sats = np.array(sorted(nav["sat"].unique()), dtype=object)
    t = t0 + np.arange(0.0, 7200.0, 7.0)
    return nav, np.repeat(sats, t.size), np.tile(t, sats.size)


def _both(monkeypatch, fn):
    """fn() with the kernel and with numpy (CDGPS_NO_KERNEL=1)."""
    got = fn()
    monkeypatch.setenv("CDGPS_NO_KERNEL", "1")
    assert not orbits.kernel_available()
    want = fn()
    monkeypatch.delenv("CDGPS_NO_KERNEL")
    return got, want


def _assert_same(got, want):
    for a, b in zip(got, want):
        assert a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("chunk", [orbits.CHUNK_ROWS, 37])
def test_positions_at_reception_kernel_is_numpy(chunk, monkeypatch):
    monkeypatch.setattr(orbits, "CHUNK_ROWS", chunk)
    rng = np.random.default_rng(11)
    cases = [(rel, nav, *_rows(nav, rng)) for rel, nav in NAVS] + [("synthetic GEC", *_synthetic())]
    for name, nav, sats, t in cases:
        clock = rng.uniform(-1e-3, 1e-3, t.size)
        for rx in (RX, RX + rng.normal(0.0, 30.0, (t.size, 3))):
            for tgd in (True, False):
                got, want = _both(monkeypatch, lambda: orbits.sat_positions_at_reception(
                    nav, sats, t, rx, rx_clock_s=clock, apply_tgd=tgd))
                _assert_same(got, want)


def test_position_rows_kernel_is_numpy(monkeypatch):
    rng = np.random.default_rng(12)
    nav, sats, t = _synthetic()
    navs = [(nav, sats, t)] + [(n, *_rows(n, rng)) for _, n in NAVS]
    if NAVS:
        mixed = pd.concat([n for _, n in NAVS], ignore_index=True)
        navs.append((mixed, *_rows(mixed, rng)))
    for nav, sats, t in navs:
        eph = orbits.ephemeris_rows(nav, sats, t)
        for dt in (0.075, 0.0712345):
            got, want = _both(monkeypatch, lambda: orbits.sat_position_rows(eph, t - dt))
            _assert_same(got, want)


def test_kept_rows_give_a_fresh_evaluation():
    """Rows evaluated again at the same times or at partly changed times (each row a block of its own, as
    sat_positions_at_reception calls the kernel): what the kernel keeps from the first call gives the numpy values
    of the second."""
    nav, sats, t = _synthetic()
    eph = orbits.reception_ephemeris(nav, sats, t)
    kc = orbits._packed_constants(eph.kepler)
    rows = np.ascontiguousarray(eph.nav_rows)
    tt = t[eph.order] - 0.07
    k = {f: v[rows] for f, v in eph.kepler.items()}
    n = tt.size
    rng = np.random.default_rng(5)
    each = np.arange(n, dtype=np.int64)
    moved = tt.copy()
    moved[rng.random(n) < 0.3] += 3e-3
    for t2 in (tt, moved):
        state = orbits._core_state(n, n)
        xyz, clk = np.zeros((n, 3)), np.zeros(n)
        orbits._core_kepler(kc, rows, tt, each, state, False, True, xyz, clk)
        state = state[:4] + (np.ones(n, dtype=np.uint8),)
        orbits._core_kepler(kc, rows, t2, each, state, True, True, xyz, clk)
        _assert_same((xyz, clk), orbits._kepler_rows(k, t2, True))


def test_azimuth_elevation_and_niell_kernel_is_numpy(monkeypatch):
    """The rotation to east/north/up (einsum's sums) and the Niell mapping of one receiver, in C: the same bits,
    at satellites all around (below the horizon too) and receivers north and south, high and below the ellipsoid."""
    from cdgps_cli.model.gps.orbits import azimuth_elevation, elevation, geodetic_to_ecef  # noqa: PLC0415
    from cdgps_cli.model.gps.positioning import (  # noqa: PLC0415
        day_of_year, niell_hydrostatic_mapping, tropo_hydrostatic_m)

    rng = np.random.default_rng(13)
    for n in (1, 2, 7, 5000):
        sat = rng.normal(0.0, 1.6e7, (n, 3))
        t = 1_300_000_000.0 + rng.uniform(0.0, 4e7, n)
        for lat, lon, h in ((0.8, 2.4, 40.0), (-0.6, -1.0, 2500.0), (0.1, 0.3, -30.0), (-1.4, 3.0, 0.0)):
            rx = geodetic_to_ecef(lat, lon, h)
            got, want = _both(monkeypatch, lambda: azimuth_elevation(rx, sat))
            _assert_same(got, want)
            _assert_same(_both(monkeypatch, lambda: (elevation(rx, sat),))[0], want[1:])
            el = np.r_[want[1][:-1], 1e-6] if n > 1 else want[1]
            got, want = _both(monkeypatch, lambda: (niell_hydrostatic_mapping(el, lat, h, day_of_year(t)),
                                                    tropo_hydrostatic_m(el, lat, h, t)))
            _assert_same(got, want)


@pytest.mark.skipif(orbits._orbitcore is None, reason="compiled orbit kernel not built")
def test_every_entry_refuses_an_ephemeris_row_out_of_range():
    """The four entry points that index the ephemeris table check every row first (IndexError, no read
    outside the table)."""
    core = orbits._orbitcore
    kc = np.zeros((2, len(orbits._CORE_FIELDS)))
    n = 3
    for bad in (-1, 2):
        rows = np.array([0, bad, 1], dtype=np.int64)
        t, ek, z = np.zeros(n), np.zeros(n), np.zeros(n)
        calls = {
            "newton": lambda: core.newton(kc, rows, t, ek, np.empty(n, dtype=np.uint8)),
            "anomaly_trig": lambda: core.anomaly_trig(kc, rows, ek, *(np.empty(n) for _ in range(4))),
            "orbit": lambda: core.orbit(kc, rows, t, z, z, z, np.empty((n, 3)), np.empty(n), False, 1.0, 0.0),
            "anomaly": lambda: core.anomaly(kc, rows, t, np.array([0], dtype=np.int64), np.ones(1, dtype=np.uint8),
                                            *orbits._core_state(n, 1)[:4], False),
        }
        for name, call in calls.items():
            with pytest.raises(IndexError, match="ephemeris row is out of range"):
                call()
