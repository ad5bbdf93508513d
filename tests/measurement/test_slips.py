"""Unflagged cycle slips as steps in a channel's residuals (:mod:`cdgps_cli.measurement.slips`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cdgps_cli.measurement.slips import local_steps, residual_steps, robust_sigma

LAM, DT = 0.19029367279836487, 0.1


def test_local_steps_equal_direct_means():
    e = np.random.default_rng(1).normal(size=13)
    step, scale = local_steps(e, 4)
    for k in range(1, 13):
        lo, hi = max(k - 4, 0), min(k + 4, 13)
        assert step[k - 1] == pytest.approx(e[k:hi].mean() - e[lo:k].mean())
        assert scale[k - 1] == pytest.approx(math.sqrt(1 / (k - lo) + 1 / (hi - k)))


@pytest.mark.parametrize("k,cycles", [(1, 0.5), (37, 1.0), (300, -2.0), (598, 0.5), (599, 20.0)])
def test_step_found_at_its_epoch(k, cycles):
    rng = np.random.default_rng(k)
    r = rng.normal(0, 0.01, (600, 6))
    r[k:, 2] += cycles * LAM
    seg = np.zeros(r.shape, dtype=int)
    found = residual_steps(r, seg, LAM, DT)
    assert [(s.channel, s.epoch) for s in found] == [(2, k)]
    assert found[0].step_m == pytest.approx(cycles * LAM, abs=0.03)
    assert robust_sigma(r[:, 2]) == pytest.approx(0.01, rel=0.2)


def test_white_noise_and_multipath_give_no_step():
    rng = np.random.default_rng(5)
    n, C = 1200, 36
    a = math.exp(-DT / 30.0)
    m = np.empty((n, C))
    m[0] = rng.normal(0, 0.03, C)
    for i in range(1, n):
        m[i] = a * m[i - 1] + rng.normal(0, 0.03 * math.sqrt(1 - a * a), C)
    seg = np.zeros((n, C), dtype=int)
    for r in (rng.normal(0, 0.02, (n, C)), m + rng.normal(0, 0.002, (n, C))):
        assert residual_steps(r, seg, LAM, DT) == []


def test_segments_and_gaps_are_separate_stretches():
    r = np.random.default_rng(2).normal(0, 0.01, (400, 2))
    seg = np.zeros(r.shape, dtype=int)
    seg[200:, 0] = 1                       # a flagged slip: a new segment, its jump is no step
    r[200:, 0] += 3 * LAM
    r[100:110, 1] = np.nan                 # a gap with a jump across it: no step either
    r[110:, 1] += LAM
    seg[110:, 1] = 2
    assert residual_steps(r, seg, LAM, DT) == []


def _td_scene(seed=0, n_ep=300, n_sat=8, sigma_m=0.003, moving=True):
    """Single-difference phases of a rover under ``n_sat`` satellites in two signal groups (each with its own
    clock term per epoch), satellites' lines of sight turning slowly, the rover wandering (metres per epoch) or
    still, white noise of ``sigma_m``: (rows' arrays, the true displacements (n_ep, 3))."""
    rng = np.random.default_rng(seed)
    az = rng.uniform(0, 2 * np.pi, n_sat)
    el = rng.uniform(0.3, 1.4, n_sat)
    t = np.arange(n_ep)
    az_t = az[None, :] + 1e-4 * t[:, None]
    los = np.stack([np.cos(el) * np.sin(az_t), np.cos(el) * np.cos(az_t), np.sin(el) * np.ones_like(az_t)], axis=-1)
    pos = np.cumsum(rng.normal(0, 2.0 if moving else 0.0, (n_ep, 3)), axis=0)
    clock = rng.normal(0, 5.0, (n_ep, 2))
    group = np.tile(np.arange(n_sat) % 2, (n_ep, 1))
    phase = -np.einsum("kjc,kc->kj", los, pos) + clock[t[:, None], group] + rng.normal(0, sigma_m, (n_ep, n_sat))
    epoch, channel = np.meshgrid(t, np.arange(n_sat), indexing="ij")
    rows = {"epoch": epoch.ravel(), "channel": channel.ravel(), "group": group.ravel(), "phase_m": phase.ravel(),
            "range_m": np.zeros(n_ep * n_sat), "var_m2": np.full(n_ep * n_sat, sigma_m**2 / 2),
            "los": los.reshape(-1, 3)}
    return rows, np.diff(pos, axis=0, prepend=pos[:1])


def _td(rows, **kw):
    from cdgps_cli.measurement.slips import time_differenced_slips
    return time_differenced_slips(rows["epoch"], rows["channel"], rows["group"], rows["phase_m"], rows["range_m"],
                                  rows["var_m2"], rows["los"], **kw)


@pytest.mark.parametrize("moving", [False, True])
def test_time_differenced_slips_find_each_slip_at_its_epoch(moving):
    """One cycle (L1, 0.19 m) on channel 3 from epoch 120 and a half cycle on channel 6 from epoch 200, on a rover
    still or moving metres an epoch (the displacement is fitted), 10 satellites: those two rows are flagged, with at
    most two others of their epochs whose w values tie, none elsewhere; the fitted
    displacements are each epoch's least squares (brute force, 1e-9 m) and the true ones within their noise; a slip
    already flagged is not found again."""
    rows, disp = _td_scene(moving=moving, n_sat=10)
    for ch, k, size in ((3, 120, 0.1903), (6, 200, 0.0951)):
        rows["phase_m"][(rows["channel"] == ch) & (rows["epoch"] >= k)] += size
    found, step = _td(rows)
    want = ((rows["channel"] == 3) & (rows["epoch"] == 120)) | ((rows["channel"] == 6) & (rows["epoch"] == 200))
    assert found[want].all() and np.isin(rows["epoch"][found], [120, 200]).all()
    assert found.sum() <= 6                        # channels tied with the slip's (TD_SLIP_TIE) cut with it: ≤ 2 each
    assert np.sqrt(np.mean((step[1:] - disp[1:]) ** 2)) < 0.02        # this weak geometry's noise: 1 cm rms
    for k in (50, 120, 250):                       # each epoch's fit is the least squares of its changes (brute force)
        now, before = rows["epoch"] == k, rows["epoch"] == k - 1
        live = ~found[now]
        y = (rows["phase_m"][now] - rows["phase_m"][before])[live]
        A = np.column_stack([-rows["los"][now], rows["group"][now] == 0, rows["group"][now] == 1])[live].astype(float)
        np.testing.assert_allclose(step[k], np.linalg.lstsq(A, y, rcond=None)[0][:3], atol=1e-9)
    again, _ = _td(rows, flagged=found)
    assert not again.any()


def test_time_differenced_slips_white_noise_flags_nothing():
    """20 records of white noise (2 400 epoch pairs each) with no slip: nothing flagged at 6σ; with too few
    satellites to spare (4 in two groups: redundancy 4 − 2 − 3 < 2) a slip is not judged."""
    for seed in range(20):
        found, _ = _td(_td_scene(seed=seed, n_ep=300)[0])
        assert not found.any(), seed
    rows, _ = _td_scene(n_sat=4)
    rows["phase_m"][(rows["channel"] == 1) & (rows["epoch"] >= 50)] += 0.19
    assert not _td(rows)[0].any()
    one, _ = _td_scene(n_ep=1)                     # one epoch: no change to fit
    found, step = _td(one)
    assert not found.any() and step.shape == (1, 3)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.integers(0, 7), st.integers(2, 98), st.sampled_from([-3, -1, -0.5, 0.5, 1, 2, 7]))
def test_a_slip_the_geometry_lets_the_test_see_is_found_where_it_is(seed, ch, k, cycles):
    """Any channel, epoch and size, under 8 satellites: when the slip's expected w value |s|·√(w(1 − h)) (h its
    leverage in that epoch's fit) reaches 12 (the 6σ threshold, with room for the record's noise scale and for
    channels that tie with it), its row is flagged, with others of its epoch whose w values tie with it (three
    within 2 % were seen, where cutting the top two alone missed the slip; at most m − 3 of the epoch's m rows) and
    none elsewhere; below that, no other epoch is touched.  (The geometry decides: a channel of leverage 0.945 shows
    5.5 % of a half-cycle slip in its residual, an expected w value of 7.)  400 random cases: 1–4 rows flagged
    (5 in the weakest geometry hypothesis found), none missed, none elsewhere."""
    from cdgps_cli.measurement.slips import _td_residuals
    rows, _ = _td_scene(seed=seed, n_ep=100)
    at = (rows["epoch"] == k)
    n_ep, m = 100, int(at.sum())
    g = -rows["los"][at]
    _, _, _, lev = _td_residuals(np.zeros(m), 1.0 / (2 * rows["var_m2"][at]), g, rows["group"][at],
                                 np.zeros(m, dtype=np.int64), np.ones(m, dtype=bool), 1)
    j = int(np.flatnonzero(rows["channel"][at] == ch)[0])
    expected_w = abs(cycles * LAM) * np.sqrt((1 - lev[j]) / (2 * rows["var_m2"][at][j]))
    rows["phase_m"][(rows["channel"] == ch) & (rows["epoch"] >= k)] += cycles * LAM
    found, _ = _td(rows)
    slip = (rows["channel"] == ch) & (rows["epoch"] == k)
    assert (rows["epoch"][found] == k).all() and found.sum() <= m - 3
    if expected_w >= 12.0:
        assert found[slip].all(), expected_w
