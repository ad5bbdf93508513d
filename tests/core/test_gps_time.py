"""`core.gps_time.distinct_times`: ``np.unique`` of time tags, without a sort when they do not decrease.

The independent check is ``np.unique`` itself, on random tags in order with repeats (a record's rows), out of
order, with NaN, infinities, signed zeros, one or no element: the same values, bit for bit."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cdgps_cli.core.gps_time import distinct_times, nominal_interval_s


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), max_size=40), st.booleans())
def test_distinct_times_is_np_unique(values, in_order):
    t = np.array(values, dtype=np.float64)
    if in_order:
        t = np.sort(t)
    assert _same(distinct_times(t), np.unique(t))


@pytest.mark.parametrize("t", [[], [1.0], [0.0, -0.0, 0.0], [-0.0, 0.0], [1.0, 1.0, 2.0, 2.0, 2.5],
                               [1e9 + 0.1 * k for k in range(50) for _ in range(7)]])
def test_distinct_times_cases(t):
    t = np.array(t, dtype=np.float64)
    assert _same(distinct_times(t), np.unique(t))


def test_an_hours_rows_at_10_hz():
    t = np.repeat(1.4e9 + np.arange(36_000) * 0.1, 10)          # (an hour at 10 Hz, 10 rows an epoch)
    assert _same(distinct_times(t), np.unique(t)) and nominal_interval_s(t) == 0.1
    assert math.isnan(nominal_interval_s([5.0, 5.0]))


def test_spans_meet_within_the_base_age():
    """The one rule `rtk`, `config` and the baseline use for "no common epochs" (each had its own)."""
    from cdgps_cli.core.gps_time import spans_meet, time_span
    assert time_span([]) is None and time_span([5.0, 1.0, 3.0]) == (1.0, 5.0)
    assert spans_meet((0.0, 10.0), (40.0, 50.0), 30.0) and spans_meet((40.0, 50.0), (0.0, 10.0), 30.0)
    assert not spans_meet((0.0, 10.0), (40.5, 50.0), 30.0) and not spans_meet((40.5, 50.0), (0.0, 10.0), 30.0)
    assert not spans_meet(None, (0.0, 1.0), 30.0)
