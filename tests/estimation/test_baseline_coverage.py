"""A row is used only where a broadcast ephemeris covers its epoch's label and its own time tag (baseline._covered):
a rover tagged 5 ms before an ephemeris window opens (13:59:59.995 against a toe of 16:00) stopped ``init`` with
"no healthy broadcast ephemeris" when the receiver clock was evaluated at the tag; the row now goes, as ``rtk``
drops it, with the same warning as any uncovered row."""

from __future__ import annotations

import numpy as np
import pandas as pd

from cdgps_cli.estimation.baseline import COVERAGE_MARGIN_S, _covered

TOE = 16 * 3600.0


def _nav():
    return pd.DataFrame({"sat": ["G03", "G03", "G05"], "toe_gps_s": [TOE, TOE + 7200.0, TOE - 7200.0],
                         "sv_health": [0, 0, 0]})


def test_a_tag_just_before_the_window_is_not_covered():
    start = TOE - 7200.0                                     # G03's window opens here
    label = np.array([start, start, start + 10.0, start])
    tag = np.array([start - 0.005, start + 2.0, start + 9.995, start])
    sats = np.array(["G03", "G03", "G03", "G05"], dtype=object)
    assert _covered(_nav(), sats, label, tag).tolist() == [False, True, True, True]


def test_the_margin_is_what_the_window_loses():
    start = TOE - 7200.0
    t = start + np.array([COVERAGE_MARGIN_S - 1e-3, COVERAGE_MARGIN_S, COVERAGE_MARGIN_S + 1e-3])
    assert _covered(_nav(), np.array(["G03"] * 3, dtype=object), t, t).tolist() == [False, True, True]
