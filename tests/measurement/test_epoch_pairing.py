"""measurement/epoch_pairing: the rover drives; base epochs matched within a tolerance or bridged up
to a maximum age; every rover epoch used or counted with its reason (checked against a brute-force
nearest-neighbour search)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cdgps_cli.config.options import EPOCH_PAIRING_DEFAULTS
from cdgps_cli.measurement.epoch_pairing import (DROP_REASONS, age_variance_m2, carry_base_slips, pair_epochs)


def test_millisecond_tags_pair_as_simultaneous():
    # u-blox pair: base .990/.991 s, rover .991/.992 s; GEONET: .999 s against whole seconds
    t = 1.4e9 + np.arange(100.0)
    rover = t - 0.009 + 0.001 * (np.arange(100) % 2)
    base = t - 0.010 + 0.001 * (np.arange(100) // 7 % 2)
    p = pair_epochs(rover, base)
    assert p.summary["used"] == p.summary["simultaneous"] == 100 and p.summary["dropped"] == {}
    np.testing.assert_array_equal(p.base_index, np.arange(100))
    np.testing.assert_array_equal(p.rover_time_s, rover)
    p = pair_epochs(t - 0.001, t)
    assert p.summary["simultaneous"] == 100


def test_gappy_and_low_rate_base_is_bridged_with_reasons():
    rover = 1000.0 + np.arange(0, 200, 0.1)                 # 10 Hz rover, 200 s
    base = np.r_[1010.0:1060.0:5.0, 1130.0:1150.0:1.0]     # 5 s base, then a 70 s gap, then 1 Hz, then ends
    p = pair_epochs(rover, base, max_age_s=30.0)
    s = p.summary
    assert s["rover_epochs"] == 2000
    assert s["used"] + sum(s["dropped"].values()) == 2000
    assert "before the first base epoch" not in s["dropped"]      # 1000–1010 s is within 30 s of 1010
    assert s["dropped"]["after the last base epoch"] == int(np.sum(rover > 1149.0 + 30.0 + 1e-9))
    gap = (rover > 1055.0 + 30.0 + 1e-9) & (rover < 1130.0 - 30.0 - 1e-9)
    assert s["dropped"]["in a base gap (no base epoch within the maximum age)"] == int(gap.sum())
    assert np.all(np.abs(p.age_s) <= 30.0) and s["max_age_s"] == pytest.approx(np.abs(p.age_s).max())
    assert s["bridged"] + s["simultaneous"] == s["used"] and s["simultaneous"] == 10 + 20
    assert set(s["dropped"]) <= set(DROP_REASONS)


_MS = st.integers(0, 500_000).map(lambda i: i / 1000.0)     # times on a 1 ms grid (no ties made by rounding)


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(st.lists(_MS, min_size=0, max_size=60), st.lists(_MS, min_size=1, max_size=60),
       st.floats(0.001, 0.5), st.floats(0.5, 60))
def test_nearest_base_epoch_as_brute_force(rover, base, tol, max_age):
    p = pair_epochs(rover, base, sync_tol_s=tol, max_age_s=max_age)
    tr, tb = np.unique(rover), np.unique(base)
    used = []
    for i, t in enumerate(tr):
        if i and t - tr[i - 1] < 1e-6:
            continue
        d = np.abs(tb - t)
        k = int(np.flatnonzero(d == d.min())[0])          # the nearest; the earlier on a tie
        if d[k] <= max_age:
            used.append((i, k))
    assert [(int(a), int(b)) for a, b in zip(p.rover_index, p.base_index)] == used
    np.testing.assert_array_equal(p.age_s, tr[p.rover_index] - tb[p.base_index])
    assert p.summary["used"] + sum(p.summary["dropped"].values()) == p.summary["rover_epochs"] == tr.size


def test_bad_limits_are_named():
    with pytest.raises(ValueError, match="max_age_s"):
        pair_epochs([1.0], [1.0], max_age_s=0.0)
    with pytest.raises(ValueError, match="sync_tol_s"):
        pair_epochs([1.0], [1.0], sync_tol_s=float("nan"))
    with pytest.raises(ValueError, match="max_age_s: expected ≥ sync_tol_s"):
        pair_epochs([1.0], [1.0], sync_tol_s=0.5, max_age_s=0.1)


def test_no_base_epochs_drops_every_rover_epoch():
    p = pair_epochs([1.0, 2.0], [])
    assert p.summary["used"] == 0 and sum(p.summary["dropped"].values()) == 2


def test_age_variance_is_rtklib_clock_stability_term():
    c = 299792458.0
    v = age_variance_m2([0.0, 0.02, -2.0, 10.0])
    assert v[0] == v[1] == 0.0                              # simultaneous
    assert v[2] == pytest.approx((5e-12 * c * 2.0) ** 2) and v[3] == pytest.approx((5e-12 * c * 10.0) ** 2)
    assert EPOCH_PAIRING_DEFAULTS["age_sigma_m_per_s"] == pytest.approx(1.499e-3, rel=1e-3)


def test_base_slips_of_unused_epochs_move_to_the_next_used_one():
    # base epochs 0..5; epochs 1, 2 unused; a slip of G05 at epoch 2 and of G07 at epoch 1
    ep = np.array([0, 0, 1, 1, 2, 2, 3, 3, 4, 4])
    key = np.array(["G05", "G07"] * 5)
    lli = np.zeros(10, dtype=np.int64)
    lli[4] = 1          # G05 at epoch 2
    lli[3] = 1          # G07 at epoch 1
    use = np.array([1, 0, 0, 2, 1])
    out = carry_base_slips(ep, key, lli, use)
    assert out.tolist() == [0, 0, 0, 1, 1, 0, 1, 1, 0, 0]
    assert carry_base_slips(ep, key, lli, np.ones(5, int)).tolist() == lli.tolist()


def test_rows_for_pairs_replicates_a_shared_base_epoch():
    from cdgps_cli.measurement.epoch_pairing import rows_for_pairs
    row_epoch = np.array([0, 0, 1, 2, 2, 3])          # base rows: epochs 0,0,1,2,2,3
    pair_epoch = np.array([0, 0, 2, 2, 2])            # 5 rover epochs: base 0 twice, base 2 three times
    take, pair, first = rows_for_pairs(row_epoch, pair_epoch)
    want = [(r, p) for p, e in enumerate(pair_epoch) for r in np.flatnonzero(row_epoch == e)]
    assert sorted(zip(take.tolist(), pair.tolist())) == sorted(want)
    assert [(t, p) for t, p, f in zip(take, pair, first) if f] == [(0, 0), (1, 0), (3, 2), (4, 2)]
    with pytest.raises(ValueError, match="non-decreasing"):
        rows_for_pairs(row_epoch, [2, 1])
