"""``unix_ns_list`` (issue 29: the log times of a block of messages at once) gives the integers of
``unix_ns`` one by one: halves of a nanosecond (rounded to even alike), leap seconds, negative and
non-finite times (the same error), both time scales."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.core.timescales import unix_ns, unix_ns_list


def _cases():
    rng = np.random.default_rng(0)
    leaps = np.array([46828800.0, 1167264017.0, 1167264018.0, 1167264017.5])       # around GPS leap seconds
    return [rng.uniform(0, 2e9, 20000), rng.uniform(-1e5, 1e5, 20000), np.round(rng.uniform(0, 1.5e9, 5000) * 2) / 2,
            np.arange(0, 8640, 0.1) + 1.4e9, np.round(rng.uniform(0, 1e6, 5000), 9) + 0.5e-9, leaps,
            np.array([]), np.array([5e9, 1.0])]


@pytest.mark.parametrize("scale", ["relative", "gps"])
def test_the_integers_of_unix_ns(scale):
    for t in _cases():
        assert unix_ns_list(t, scale) == [unix_ns(v, scale) for v in t.tolist()]
        assert unix_ns_list(t.tolist(), scale) == [unix_ns(v, scale) for v in t.tolist()]


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_as_unix_ns(bad):
    with pytest.raises(Exception) as one:
        unix_ns(bad, "relative")
    with pytest.raises(one.type):
        unix_ns_list([1.0, bad], "relative")
    with pytest.raises(ValueError):
        unix_ns_list([1.0], "tai")
