"""Tests for cdgps_cli.measurement.differencing: DD operator and covariance (against brute force), reference satellites,
ambiguity segments and datum, batched weights."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.measurement.differencing import (
    ambiguity_datum,
    ambiguity_segments,
    dd_covariance,
    dd_operator,
    dd_weight,
    dd_weight_blocks,
    double_differences,
    epoch_pointers,
    projected_weight,
    sd_variance,
    select_reference,
)

D2R = np.pi / 180.0


# ----------------------------------------------------------------------------------------------
# operator and covariance


def test_dd_operator_rows():
    d = dd_operator(4, 2)
    np.testing.assert_array_equal(d, [[1, 0, -1, 0], [0, 1, -1, 0], [0, 0, -1, 1]])
    np.testing.assert_array_equal(d @ np.ones(4), 0.0)
    with pytest.raises(ValueError):
        dd_operator(1, 0)
    with pytest.raises(ValueError):
        dd_operator(3, 3)


def _brute_force_dd_cov(var_rover, var_base, ref):
    """Covariance of DDs built from the undifferenced observations, element by element.

    u = [rover_0..n-1, base_0..n-1], independent; DD_j = (u_i − u_{n+i}) − (u_ref − u_{n+ref})."""
    n = len(var_rover)
    cov_u = np.diag(np.r_[var_rover, var_base])
    others = [i for i in range(n) if i != ref]
    ops = []
    for i in others:
        row = np.zeros(2 * n)
        row[i] += 1.0
        row[n + i] -= 1.0
        row[ref] -= 1.0
        row[n + ref] += 1.0
        ops.append(row)
    a = np.array(ops)
    out = np.zeros((n - 1, n - 1))
    for j in range(n - 1):
        for k in range(n - 1):
            out[j, k] = sum(a[j, p] * a[k, q] * cov_u[p, q] for p in range(2 * n) for q in range(2 * n))
    return out


@pytest.mark.parametrize("ref", [0, 3, 5])
def test_dd_covariance_matches_brute_force_elevation_weights(ref):
    el_r = np.array([15.0, 22.0, 37.0, 55.0, 71.0, 88.0]) * D2R
    el_b = el_r + 0.01 * D2R
    var = sd_variance(el_r, el_b, sigma_a_m=0.003, sigma_b_m=0.003)
    a2 = b2 = 0.003**2
    var_r = a2 + b2 / np.sin(el_r) ** 2
    var_b = a2 + b2 / np.sin(el_b) ** 2
    np.testing.assert_allclose(var, var_r + var_b, rtol=1e-14)
    np.testing.assert_allclose(dd_covariance(var, ref), _brute_force_dd_cov(var_r, var_b, ref), rtol=1e-12, atol=0)


def test_dd_covariance_equal_weights_is_2sigma2_I_plus_ones():
    sigma = 0.004
    var = sd_variance(np.full(5, 0.3), np.full(5, 0.4), sigma_a_m=sigma, sigma_b_m=0.0, weighting="equal")
    np.testing.assert_allclose(var, 2 * sigma**2)
    c = dd_covariance(var, 1)
    np.testing.assert_allclose(c, 2 * sigma**2 * (np.eye(4) + np.ones((4, 4))), rtol=1e-14)


def test_dd_covariance_monte_carlo():
    rng = np.random.default_rng(1)
    var_r = np.array([1.0, 2.0, 0.5, 3.0])
    var_b = np.array([0.7, 1.1, 0.2, 0.9])
    u_r = rng.normal(size=(200_000, 4)) * np.sqrt(var_r)
    u_b = rng.normal(size=(200_000, 4)) * np.sqrt(var_b)
    sd = u_r - u_b
    dd = sd @ dd_operator(4, 2).T
    np.testing.assert_allclose(np.cov(dd.T), dd_covariance(var_r + var_b, 2), rtol=0.02, atol=0.02)


def test_sd_variance_rejects_unknown_weighting():
    with pytest.raises(ValueError, match="weighting"):
        sd_variance([0.5], [0.5], weighting="snr")


def test_dd_weight_is_reference_free_and_equals_projected_form():
    var = np.array([1e-4, 3e-5, 7e-5, 2e-4, 5e-5])
    p0 = projected_weight(var)
    for ref in range(5):
        p = dd_weight(var, ref)
        np.testing.assert_allclose(p, p0, rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(p @ np.ones(5), 0.0, atol=1e-6)
    w = np.linalg.eigvalsh(p0)
    assert np.sum(w > 1e-9 * w.max()) == 4 and w.min() > -1e-9 * w.max()
    # a DD least-squares solution equals an SD solution with one clock parameter per epoch
    rng = np.random.default_rng(2)
    g = rng.normal(size=(5, 3))
    y = rng.normal(size=5)
    d = dd_operator(5, 3)
    c = dd_covariance(var, 3)
    x_dd = np.linalg.solve((d @ g).T @ np.linalg.solve(c, d @ g), (d @ g).T @ np.linalg.solve(c, d @ y))
    ga = np.c_[g, np.ones(5)]
    x_sd = np.linalg.solve(ga.T @ (ga / var[:, None]), ga.T @ (y / var))[:3]
    np.testing.assert_allclose(x_dd, x_sd, rtol=1e-10)


def test_dd_weight_blocks_match_single_epoch_weights():
    # epochs with 4, 3, 1 and 5 rows; one unusable row in the last epoch
    ep = np.array([0, 0, 0, 0, 1, 1, 1, 2, 3, 3, 3, 3, 3])
    ptr = epoch_pointers(ep)
    np.testing.assert_array_equal(ptr, [0, 4, 7, 8, 13])
    var = np.linspace(1e-5, 4e-5, ep.size)
    usable = np.ones(ep.size, dtype=bool)
    usable[10] = False
    ref = np.array([1, 6, -1, 12])
    blocks = dd_weight_blocks(ptr, var, ref, usable=usable)
    seen = set()
    for rows, p in blocks:
        for k in range(rows.shape[0]):
            r = rows[k]
            seen.update(r.tolist())
            pos = int(np.flatnonzero(r == ref[ep[r[0]]])[0])
            np.testing.assert_allclose(p[k], dd_weight(var[r], pos), rtol=1e-10, atol=1e-3)
    assert seen == {0, 1, 2, 3, 4, 5, 6, 8, 9, 11, 12}
    with pytest.raises(ValueError, match="reference row"):
        dd_weight_blocks(ptr, var, np.array([1, 6, -1, 10]), usable=usable)


def test_epoch_pointers_requires_sorted_rows():
    with pytest.raises(ValueError):
        epoch_pointers([0, 2, 1])
    np.testing.assert_array_equal(epoch_pointers([0, 0, 2], 4), [0, 2, 2, 3, 3])


# ----------------------------------------------------------------------------------------------
# reference satellite


def _rows(epochs: list[dict]):
    """epochs: [{sat: elevation_deg}] → sorted arrays ep, sat, el."""
    ep, sat, el = [], [], []
    for k, e in enumerate(epochs):
        for s in sorted(e):
            ep.append(k)
            sat.append(s)
            el.append(e[s] * D2R)
    return np.array(ep), np.array(sat), np.array(el)


def test_reference_kept_while_visible_then_highest_when_it_sets():
    epochs = [
        {1: 40, 2: 60, 3: 20},
        {1: 45, 2: 58, 3: 25},
        {1: 70, 2: 55, 3: 30},   # 1 is now higher, but 2 stays reference (no needless change)
        {1: 72, 3: 33},          # 2 has set → highest (1)
        {1: 74, 2: 50, 3: 36},   # 2 is back, 1 stays
        {3: 40},                 # single satellite: no DD
    ]
    ep, sat, el = _rows(epochs)
    ptr = epoch_pointers(ep)
    ref = select_reference(ptr, sat, el)
    ref_sat = [int(sat[r]) if r >= 0 else None for r in ref]
    assert ref_sat == [2, 2, 2, 1, 1, None]


def test_reference_changes_when_it_slips():
    epochs = [{1: 40, 2: 60, 3: 20}, {1: 45, 2: 58, 3: 25}, {1: 50, 2: 57, 3: 30}, {1: 55, 2: 56, 3: 35}]
    ep, sat, el = _rows(epochs)
    slip = np.zeros(ep.size, dtype=bool)
    slip[(ep == 2) & (sat == 2)] = True      # the reference slips at epoch 2
    ref = select_reference(epoch_pointers(ep), sat, el, slip)
    assert [int(sat[r]) for r in ref] == [2, 2, 1, 1]
    # only usable rows may serve
    usable = sat != 2
    ref = select_reference(epoch_pointers(ep), sat, el, usable=usable)
    assert [int(sat[r]) for r in ref] == [1, 1, 1, 1]


def _random_rows(rng, n_epochs, n_sats, p_slip, p_unusable, p_missing, round_el):
    """Epoch rows of random satellites (in random order, sometimes a satellite twice) with elevations
    rounded to ``round_el`` degrees (ties), slips and unusable rows."""
    ep, sat = [], []
    for k in range(n_epochs):
        seen = rng.permutation(n_sats)[: max(0, n_sats - rng.binomial(n_sats, p_missing))]
        if seen.size and rng.random() < 0.05:
            seen = np.r_[seen, seen[:1]]                     # a satellite twice in one epoch
        ep += [k] * seen.size
        sat += seen.tolist()
    ep, sat = np.array(ep, dtype=np.int64), np.array(sat, dtype=np.int64)
    el = np.round(rng.uniform(5, 85, ep.size) / round_el) * round_el * D2R
    return ep, sat, el, rng.random(ep.size) < p_slip, rng.random(ep.size) >= p_unusable


@pytest.mark.parametrize("seed", range(12))
def test_reference_rows_are_the_epoch_by_epoch_loops(seed):
    """The blockwise choice gives the rows of the rule applied epoch by epoch (the former code), with ties,
    duplicated satellites, slips, unusable rows, empty epochs and references lasting past the look-ahead."""
    from cdgps_cli.measurement.differencing import REFERENCE_LOOKAHEAD, _select_reference_loop

    rng = np.random.default_rng(seed)
    n_epochs = int(rng.choice([1, 3, 40, REFERENCE_LOOKAHEAD * 5 + 7]))
    p_slip = [0.0, 0.002, 0.05, 0.9][seed % 4]
    ep, sat, el, slip, usable = _random_rows(rng, n_epochs, int(rng.integers(1, 9)), p_slip,
                                             [0.0, 0.1, 0.5][seed % 3], [0.0, 0.2][seed % 2], [0.001, 5.0][seed % 2])
    ptr = epoch_pointers(ep, n_epochs)                     # epochs without rows too
    want = _select_reference_loop(ptr, sat, el, slip, usable)
    np.testing.assert_array_equal(select_reference(ptr, sat, el, slip, usable=usable), want)
    np.testing.assert_array_equal(select_reference(ptr, sat, el), _select_reference_loop(
        ptr, sat, el, np.zeros(sat.size, bool), np.ones(sat.size, bool)))


def test_reference_with_nan_elevations_follows_the_loop():
    ep, sat, el = _rows([{1: 40, 2: 60, 3: 20}, {1: 45, 2: 58, 3: 25}])
    el[1] = np.nan
    ptr = epoch_pointers(ep)
    from cdgps_cli.measurement.differencing import _select_reference_loop

    np.testing.assert_array_equal(select_reference(ptr, sat, el),
                                  _select_reference_loop(ptr, sat, el, np.zeros(6, bool), np.ones(6, bool)))


def test_double_differences_against_reference_rows():
    epochs = [{1: 40, 2: 60, 3: 20}, {1: 72, 3: 33}]
    ep, sat, el = _rows(epochs)
    ptr = epoch_pointers(ep)
    ref = select_reference(ptr, sat, el)
    vals = np.array([10.0, 20.0, 35.0, 100.0, 130.0])
    dd = double_differences(ptr, ref, vals)
    np.testing.assert_array_equal(dd["epoch"], [0, 0, 1])
    np.testing.assert_array_equal(sat[dd["row"]], [1, 3, 3])
    np.testing.assert_array_equal(sat[dd["ref_row"]], [2, 2, 1])
    np.testing.assert_array_equal(dd["value"], [-10.0, 15.0, 30.0])
    # same as D @ SD per epoch
    d0 = dd_operator(3, 1) @ vals[:3]
    np.testing.assert_array_equal(dd["value"][:2], d0)
    # vector values (design rows)
    dd2 = double_differences(ptr, ref, np.c_[vals, 2 * vals])
    np.testing.assert_array_equal(dd2["value"][:, 1], 2 * dd["value"])


def test_reference_change_leaves_the_solution_unchanged():
    """A static 2-D position from SD data with a clock per epoch: the DD normal equations built with
    any reference sequence are identical (the ambiguity-free part of the reference-change problem)."""
    rng = np.random.default_rng(5)
    epochs = [{1: 30, 2: 60, 3: 45, 4: 20}, {1: 35, 2: 61, 3: 44}, {1: 40, 3: 43, 4: 25}, {2: 62, 3: 41, 4: 30}]
    ep, sat, el = _rows(epochs)
    ptr = epoch_pointers(ep)
    g = rng.normal(size=(ep.size, 2))
    y = g @ np.array([0.3, -0.1]) + 1e3 * rng.normal(size=ptr.size - 1)[ep]   # + clocks
    var = sd_variance(el, el)

    def solve(ref):
        n = np.zeros((2, 2))
        b = np.zeros(2)
        for rows, p in dd_weight_blocks(ptr, var, ref):
            n += np.einsum("kic,kij,kjd->cd", g[rows], p, g[rows])
            b += np.einsum("kic,kij,kj->c", g[rows], p, y[rows])
        return np.linalg.solve(n, b)

    ref_a = select_reference(ptr, sat, el)
    ref_b = np.array([ptr[k] for k in range(ptr.size - 1)])     # always the first row
    assert not np.array_equal(ref_a, ref_b)
    np.testing.assert_allclose(solve(ref_a), [0.3, -0.1], atol=1e-9)
    np.testing.assert_allclose(solve(ref_b), solve(ref_a), atol=1e-9)


# ----------------------------------------------------------------------------------------------
# ambiguity segments and datum


def test_segments_from_lli_gaps_and_resets():
    # sat 1 every epoch 0..9 with a slip at 4; sat 2 epochs 0..3 and 6..9 (gap); sat 3 0..9, reset at 7
    ep, sat, slip = [], [], []
    for k in range(10):
        for s in (1, 2, 3):
            if s == 2 and k in (4, 5):
                continue
            ep.append(k)
            sat.append(s)
            slip.append(s == 1 and k == 4)
    ep, sat, slip = np.array(ep), np.array(sat), np.array(slip)
    t = 1000.0 + 30.0 * np.arange(10)
    seg, tab = ambiguity_segments(ep, sat, slip, epoch_time_s=t, reset_epochs=[7], max_gap_s=45.0)
    got = sorted(zip(tab["sat"].tolist(), tab["first_epoch"].tolist(), tab["last_epoch"].tolist(), tab["n_rows"].tolist()))
    assert got == [(1, 0, 3, 4), (1, 4, 6, 3), (1, 7, 9, 3), (2, 0, 3, 4), (2, 6, 6, 1), (2, 7, 9, 3),
                   (3, 0, 6, 7), (3, 7, 9, 3)]
    # no gap limit by default, but sats 1 and 3 have rows in sat 2's missing epochs: sat 2 alone was missing,
    # and it starts a new segment all the same
    _, tab_d = ambiguity_segments(ep, sat, slip, epoch_time_s=t, reset_epochs=[7])
    got_d = sorted(zip(tab_d["sat"].tolist(), tab_d["first_epoch"].tolist(), tab_d["last_epoch"].tolist(),
                       tab_d["n_rows"].tolist()))
    assert got_d == got
    # epochs 4 and 5 without any row (a receiver that wrote no phase there): every segment goes on across them
    keep = (ep < 4) | (ep > 5)
    _, tab_w = ambiguity_segments(ep[keep], sat[keep], np.zeros(keep.sum(), bool), epoch_time_s=t)
    assert sorted(zip(tab_w["sat"].tolist(), tab_w["first_epoch"].tolist(), tab_w["last_epoch"].tolist())) == \
        [(1, 0, 9), (2, 0, 9), (3, 0, 9)]
    _, tab_s = ambiguity_segments(ep[keep], sat[keep], np.zeros(keep.sum(), bool), epoch_time_s=t, max_gap_s=45.0)
    assert tab_s["sat"].size == 6                      # an explicit limit shorter than the gap cuts every one
    # each row's segment is consistent with the table
    for i in range(ep.size):
        s = seg[i]
        assert tab["sat"][s] == sat[i] and tab["first_epoch"][s] <= ep[i] <= tab["last_epoch"][s]
    # no gap limit and own outages not cut join sat 2 across its 2-epoch outage; without times, epoch indices decide
    _, tab2 = ambiguity_segments(ep, sat, slip, epoch_time_s=t, max_gap_s=np.inf, own_outages=False)
    assert np.sum(tab2["sat"] == 2) == 1
    _, tab3 = ambiguity_segments(ep, sat, slip)
    assert np.sum(tab3["sat"] == 2) == 2
    seg0, tab0 = ambiguity_segments([], [], [])
    assert seg0.size == 0 and tab0["sat"].size == 0


def test_datum_one_pivot_per_connected_set():
    # epochs 0-1: segments 0,1,2 ; epochs 2-3: segments 3,4 (no overlap with the first set)
    ep = np.array([0, 0, 0, 1, 1, 1, 2, 2, 3, 3])
    seg = np.array([0, 1, 2, 0, 1, 2, 3, 4, 3, 4])
    pivots, comp = ambiguity_datum(ep, seg, 5)
    assert len(pivots) == 2
    assert comp[0] == comp[1] == comp[2] != comp[3] == comp[4]
    assert set(pivots.tolist()) <= {0, 1, 2, 3, 4} and comp[pivots[0]] != comp[pivots[1]]
    # the pivot is the longest ambiguity of its set
    seg2 = np.array([0, 1, 2, 0, 1, 5, 3, 4, 3, 4])
    pivots2, _ = ambiguity_datum(ep, seg2, 6)
    assert 0 in pivots2 or 1 in pivots2


def test_a_half_cycle_flag_that_comes_or_goes_starts_a_new_segment():
    """rtk's rule in the segments (a u-blox rover: LLI bit 1 on a satellite's first two rows after a slip, then
    clear without a slip flag): the flagged rows are a segment of their own (kept float), the rest is one
    fixable segment; a flag that comes back starts a third; without ``half``, one segment."""
    ep = np.arange(10)
    sat = np.zeros(10, dtype=int)
    slip = np.zeros(10, dtype=bool)
    half = np.array([True, True] + [False] * 5 + [True] + [False] * 2)
    seg, tab = ambiguity_segments(ep, sat, slip, epoch_time_s=ep.astype(float), half=half)
    assert seg.tolist() == [0, 0, 1, 1, 1, 1, 1, 2, 3, 3]
    assert tab["n_rows"].tolist() == [2, 5, 1, 2]
    seg, _ = ambiguity_segments(ep, sat, slip, epoch_time_s=ep.astype(float))
    assert set(seg.tolist()) == {0}
