"""Channels whose carrier phase is flagged lost-lock at most epochs (measurement/slips.unlocked_channels)."""

import numpy as np
import pandas as pd

from cdgps_cli.measurement.slips import unlocked_channels, without_unlocked_channels


def test_share_and_minimum_epochs():
    # channel 0: 30 rows, 16 flagged (53 %); channel 1: 30 rows, 15 flagged (50 %: not above); channel 2: 10 rows, all
    # flagged but fewer than 20; channel 3: half-cycle flags (bit 1) only
    ch = np.repeat([0, 1, 2, 3], [30, 30, 10, 30])
    lli = np.concatenate([np.r_[np.ones(16), np.zeros(14)], np.r_[np.ones(15), np.zeros(15)], np.ones(10),
                          np.full(30, 2)]).astype(np.int64)
    bad, share = unlocked_channels(ch, lli)
    np.testing.assert_array_equal(bad, ch == 0)
    np.testing.assert_allclose(share[[0, 30, 60, 70]], [16 / 30, 0.5, 1.0, 0.0])
    assert not unlocked_channels(ch, lli, share=0.6)[0].any()
    np.testing.assert_array_equal(unlocked_channels(ch, lli, min_epochs=10)[0], (ch == 0) | (ch == 2))


def test_the_table_less_those_channels_and_a_warning_naming_them():
    t = pd.DataFrame({"sat": ["C03"] * 25 + ["C03"] * 25 + ["G05"] * 25,
                      "signal": ["C:B2I"] * 25 + ["C:B1I"] * 25 + ["G:L1"] * 25,
                      "lli": [1] * 24 + [0] + [0] * 25 + [1] + [0] * 24})
    kept, notes = without_unlocked_channels(t, "rover.obs (rover)")
    assert len(kept) == 50 and not ((kept["sat"] == "C03") & (kept["signal"] == "C:B2I")).any()
    assert notes == ["rover.obs (rover): C:B2I C03 (96 %): their carrier phase is flagged lost-lock at more than 50 % of "
                     "their epochs (in brackets), each flag a new ambiguity: they carry no phase and are not used"]
    same, none = without_unlocked_channels(t[t["signal"] != "C:B2I"], "x")
    assert none == [] and len(same) == 50
