"""select_ephemeris on row positions against the sub-frame version it replaced (the same rows, to the
bit, and the same errors) on every navigation file of the shared data, every satellite, times around
and between its toes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import NAV_SYSTEMS, read_rinex_nav
from cdgps_cli.io.ubx import read_ubx_log
from cdgps_cli.model.gps import orbits
from cdgps_cli.model.gps.orbits import select_ephemeris

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
NAV_FILES = ["real-pairs/geonet-car/SEPT2650.21P", "real-pairs/mosaic-static/base.nav",
             "real-pairs/ublox-walk/gnss_1730_convbin.nav", "rinex-ge/RINEX_GN_Spirent.23N", "rinex-ge/RINEX_EN_Spirent.23L",
             "rinex/07590920.05n", "rinex/14601736.18n", "rinex/30400920.05n"]


def _reference(nav, sat, t_gps_s, max_age_s):
    """The previous implementation's selection (sub-frames, pandas sort), for the rows it returns."""
    t1 = np.atleast_1d(np.asarray(t_gps_s, dtype=np.float64)).ravel()
    recs = nav[nav["sat"] == sat]
    h = recs["sv_health"].to_numpy()
    if sat.startswith("J"):                          # QZSS: its health bit 0 is not a ranging signal's (IS-QZSS-PNT)
        h = np.where(np.isfinite(h), h.astype(np.int64) // 2, h)
    healthy = recs[h == 0]
    if "transmit_gps_s" in healthy.columns:
        healthy = healthy.sort_values("transmit_gps_s", ascending=False, na_position="last", kind="stable")
    toe = healthy["toe_gps_s"].to_numpy()
    age = np.abs(t1[:, None] - toe[None, :])
    best = np.argmin(age, axis=1)
    assert np.all(age[np.arange(t1.size), best] <= max_age_s)
    return healthy.iloc[best].reset_index(drop=True)


def _navs():
    for rel in NAV_FILES:
        for sysc in NAV_SYSTEMS:
            try:
                nav = read_rinex_nav(SHARED / rel, systems=sysc)
            except CdgpsError:
                continue
            if len(nav):
                yield f"{rel}:{sysc}", nav
    yield "ublox-walk SFRBX", read_ubx_log(SHARED / "real-pairs" / "ublox-walk" / "gnss_1730.ubx")[2]


@pytest.mark.parametrize("name,nav", list(_navs()), ids=lambda x: x if isinstance(x, str) else "")
def test_same_rows_and_errors(name, nav):
    # duplicated uploads (same toe, other transmission time, one missing) exercise the tie order
    dup = nav[nav["sat"] == sorted(nav["sat"].unique())[0]].iloc[:4].copy()
    if "transmit_gps_s" in dup.columns:
        dup["transmit_gps_s"] = dup["transmit_gps_s"] + np.array([30.0, -30.0, np.nan, 0.0][: len(dup)])
    nav = pd.concat([nav, dup], ignore_index=True)
    compared = errors = 0
    for sat in sorted(nav["sat"].unique())[:5]:                 # a few per file: the test stays fast
        toes = np.sort(nav.loc[nav["sat"] == sat, "toe_gps_s"].to_numpy())
        max_age = orbits.MAX_EPHEMERIS_AGE_GLONASS_S if sat.startswith("R") else orbits.MAX_EPHEMERIS_AGE_S
        t = np.concatenate([toes, toes + 0.45 * max_age, toes - 0.45 * max_age, [toes[0] - 3 * max_age]])
        try:
            got = select_ephemeris(nav, sat, t)
        except CdgpsError as exc:
            assert "no healthy broadcast ephemeris for" in str(exc)
            errors += 1
            t = t[:-1]                                         # without the uncovered time
            try:
                got = select_ephemeris(nav, sat, t)
            except CdgpsError:
                continue
        pd.testing.assert_frame_equal(got, _reference(nav, sat, t, max_age), check_exact=True)
        pd.testing.assert_series_equal(select_ephemeris(nav, sat, float(t[1])), _reference(nav, sat, t[1], max_age).iloc[0],
                                       check_exact=True)
        compared += 1
    assert compared > 0 and errors > 0, name
    with pytest.raises(CdgpsError, match="no broadcast ephemeris for X99"):
        select_ephemeris(nav, "X99", 0.0)


@pytest.mark.parametrize("name,nav", list(_navs())[:6] + list(_navs())[-1:], ids=lambda x: x if isinstance(x, str) else "")
def test_select_ephemerides_one_take(name, nav):
    """All (satellite, time) pairs at once: the rows of select_ephemeris per satellite, in the pairs' order."""
    from cdgps_cli.model.gps.orbits import select_ephemerides

    sats_all = sorted(nav["sat"].unique())[:6]
    max_age = {s: orbits.MAX_EPHEMERIS_AGE_GLONASS_S if s.startswith("R") else orbits.MAX_EPHEMERIS_AGE_S for s in sats_all}
    good = []
    for s in sats_all:
        toe = np.sort(nav.loc[(nav["sat"] == s) & (nav["sv_health"] == 0), "toe_gps_s"].to_numpy())
        good += [(s, x) for x in np.concatenate([toe, toe + 0.3 * max_age[s]])]
    if not good:
        pytest.skip("no healthy records")
    rng = np.random.default_rng(1)
    pairs = [good[i] for i in rng.permutation(len(good))]
    sats = np.array([p[0] for p in pairs], dtype=object)
    t = np.array([p[1] for p in pairs])
    parts, order = [], []
    for sat, idx in pd.Series(sats).groupby(sats).indices.items():
        parts.append(select_ephemeris(nav, sat, t[idx]))
        order.append(idx)
    pos = np.empty(len(sats), dtype=np.int64)
    pos[np.concatenate(order)] = np.arange(len(sats))
    want = pd.concat(parts, ignore_index=True).iloc[pos].reset_index(drop=True)
    pd.testing.assert_frame_equal(select_ephemerides(nav, sats, t), want, check_exact=True)
    far = np.concatenate([t, [t.min() - 10 * 86400.0]])
    with pytest.raises(CdgpsError) as a:
        select_ephemerides(nav, np.concatenate([sats, [sats[0]]]), far)
    with pytest.raises(CdgpsError) as b:
        select_ephemeris(nav, sats[0], far[np.concatenate([sats, [sats[0]]]) == sats[0]])
    assert str(a.value) == str(b.value)
