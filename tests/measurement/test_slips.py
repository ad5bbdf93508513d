"""Unflagged cycle slips as steps in a channel's residuals (:mod:`cdgps_cli.measurement.slips`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

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
