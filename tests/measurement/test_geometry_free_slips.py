"""Slips from the epoch-to-epoch change of a satellite's geometry-free phase combination
(measurement/slips.geometry_free_slips): analytic cases."""

import numpy as np

from cdgps_cli.measurement.slips import geometry_free_slips

L1, L2 = 0.190293672798365, 0.244210213424568       # GPS L1 and L2 wavelengths, m


def _rows(n_ep=10, rng=None):
    """Two satellites, two signals each, ``n_ep`` epochs: the same range on both signals (it cancels), phases in m."""
    rng = rng or np.random.default_rng(3)
    epoch = np.repeat(np.arange(n_ep), 4)
    sat = np.tile(["G05", "G05", "G07", "G07"], n_ep)
    code = np.tile([0, 1, 0, 1], n_ep)
    rng_m = np.repeat(2.0e7 + 700.0 * np.arange(n_ep), 4) + np.tile([0, 0, 1.2e5, 1.2e5], n_ep)
    phase = rng_m + np.tile([3 * L1, -5 * L2, 11 * L1, 2 * L2], n_ep) + rng.normal(0, 0.002, 4 * n_ep)
    return epoch, sat, code, phase


def test_a_one_cycle_slip_on_one_signal_flags_both_rows_of_its_satellite_at_that_epoch():
    epoch, sat, code, phase = _rows()
    phase[(sat == "G05") & (code == 0) & (epoch >= 6)] += L1            # +1 cycle of L1 from epoch 6: 19 cm
    found = geometry_free_slips(epoch, sat, code, phase)
    np.testing.assert_array_equal(np.flatnonzero(found), np.flatnonzero((sat == "G05") & (epoch == 6)))
    assert not geometry_free_slips(*_rows()).any()                        # 2 mm noise: none


def test_one_cycle_on_both_signals_is_found_and_77_60_is_not():
    epoch, sat, code, phase = _rows()
    g = (sat == "G07") & (epoch >= 4)
    phase[g & (code == 0)] += L1
    phase[g & (code == 1)] += L2                                          # λ1 − λ2 = −5.4 cm: just beyond 5 cm
    assert np.flatnonzero(geometry_free_slips(epoch, sat, code, phase)).tolist() == np.flatnonzero(
        (sat == "G07") & (epoch == 4)).tolist()
    epoch, sat, code, phase = _rows()
    phase[g & (code == 0)] += 77 * L1
    phase[g & (code == 1)] += 60 * L2                                     # 77 λ1 = 60 λ2: the combination keeps
    assert abs(77 * L1 - 60 * L2) < 1e-9 and not geometry_free_slips(epoch, sat, code, phase).any()


def test_a_known_slip_keeps_its_partners_ambiguity_and_noise_raises_the_threshold():
    epoch, sat, code, phase = _rows()
    slipped = (sat == "G05") & (code == 0) & (epoch >= 6)
    phase[slipped] += L1
    flagged = (sat == "G05") & (code == 0) & (epoch == 6)                 # the receiver flagged its L1
    assert not geometry_free_slips(epoch, sat, code, phase, flagged=flagged).any()
    epoch, sat, code, phase = _rows()
    phase[(sat == "G05") & (code == 0) & (epoch >= 6)] += 0.06            # a 6 cm step
    assert geometry_free_slips(epoch, sat, code, phase, np.full(phase.size, 0.002 ** 2)).any()
    # phases of 1 cm σ: the difference of two combinations has σ 2 cm; 6σ = 12 cm is not reached
    assert not geometry_free_slips(epoch, sat, code, phase, np.full(phase.size, 0.01 ** 2)).any()


def test_one_signal_or_a_gap_compares_nothing():
    epoch, sat, code, phase = _rows()
    one = code == 0
    assert not geometry_free_slips(epoch[one], sat[one], code[one], phase[one] + (epoch[one] >= 5) * 1.0).any()
    keep = epoch != 5                                                     # no epoch 5: 4 and 6 are not consecutive
    e, s, c, p = epoch[keep], sat[keep], code[keep], phase[keep].copy()
    p[(s == "G05") & (c == 0) & (e >= 6)] += L1
    assert not geometry_free_slips(e, s, c, p).any()
