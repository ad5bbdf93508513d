"""The base's observations interpolated to the rover's epochs (measurement/base_interpolation.py).

Closed-form cases: a base whose observation minus model is linear in time per satellite, plus a receiver clock
common to the satellites and not linear, interpolated to rover times between its epochs, must give each
satellite's linear truth up to a term common to the epoch's group (which its double differences cancel), and the
age ``|t − t₀|(1 − w)``; a slip, a half-cycle change, a missing row or a base epoch beyond the maximum age leave
the whole group on its nearest base epoch.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.measurement.base_interpolation import BASE_ROW_COLUMNS, base_rows, interpolate_base

LAM = 0.19029367279836487
XB = np.array([1.0e6, -2.0e6, 6.0e6])
TB = np.array([0.0, 5.0, 10.0])
SATS = ["G01", "G07", "G12"]
ALPHA = {"G01": 0.37, "G07": -2.11, "G12": 5.03}            # m: each satellite's offset (its ambiguity, in metres)
BETA = {"G01": 1.0e-3, "G07": -0.7e-3, "G12": 0.4e-3}       # m/s: each satellite's clock departing from its drift


def _clock_m(t):
    return 300.0 + 40.0 * t + 3.0 * t ** 2                  # the base receiver's clock: common, not linear


def _base(lli=None, phase_nan=()):
    rows = []
    for k, t in enumerate(TB):
        for i, s in enumerate(SATS):
            sat_xyz = np.array([2.0e7 + 1.0e3 * i, 1.0e7 - 7.0e2 * t, 1.5e7 + 2.5e3 * t * (i + 1)])
            clk, trop = 12.0 + 0.01 * t + i, 2.3 + 0.001 * t
            model = np.linalg.norm(sat_xyz - XB) - clk + trop
            obs_m = model + ALPHA[s] + BETA[s] * t + _clock_m(t)
            rows.append(dict(time_gps_s=t, sat=s, signal="G:L1", phase_cycles=obs_m / LAM, pseudorange_m=obs_m,
                             sx=sat_xyz[0], sy=sat_xyz[1], sz=sat_xyz[2], sat_clock_m=clk, trop_m=trop,
                             lli=(lli or {}).get((k, s), 0), wavelength_m=LAM))
    b = pd.DataFrame(rows)
    for k, s in phase_nan:
        b.loc[(b["time_gps_s"] == TB[k]) & (b["sat"] == s), "phase_cycles"] = np.nan
    return base_rows(b, TB, np.ones(TB.size, dtype=np.int64))


def _paired(b, times):
    """Rows of rover epochs at ``times``, each with its nearest base epoch's row (suffix _b)."""
    out = []
    for e, t in enumerate(times):
        b0 = int(np.argmin(np.abs(TB - t)))
        for s in SATS:
            out.append(dict(_ep=e, _bep=b0, sat=s, signal="G:L1", wavelength_m=LAM, t=t))
    m = pd.DataFrame(out)
    at0 = b[list(BASE_ROW_COLUMNS)].rename(columns={c: c + "_b" for c in BASE_ROW_COLUMNS[3:]})
    return m.merge(at0, on=["_bep", "sat", "signal"], how="left", sort=False)


def _run(b, times, max_age_s=30.0):
    m = _paired(b, times)
    return m, interpolate_base(m, b, TB, m["t"].to_numpy(), base_xyz_m=XB, sync_tol_s=0.025, max_age_s=max_age_s,
                               troposphere=True)


def _obs_minus_truth_m(m, phase):
    """Interpolated base phase (m) minus the row's t₀ model and its satellite's linear term at the rover's time."""
    model0 = (np.linalg.norm(m[["sx_b", "sy_b", "sz_b"]].to_numpy() - XB, axis=1) - m["sat_clock_m_b"].to_numpy()
              + m["trop_m_b"].to_numpy())
    lin = m["sat"].map(ALPHA).to_numpy() + m["sat"].map(BETA).to_numpy() * m["t"].to_numpy()
    return phase * LAM - model0 - lin


def test_a_linear_base_is_recovered_up_to_the_groups_common_clock():
    times = [2.0, 3.0, 7.0, 5.0]
    m, (phase, rng, age, done) = _run(_base(), times)
    assert done[:9].all() and not done[9:].any()              # the rover epoch at a base epoch: nothing to do
    left = _obs_minus_truth_m(m, phase).reshape(len(times), len(SATS))
    # what is left is the receiver clock's interpolation: the same for every satellite of the epoch
    np.testing.assert_allclose(left - left[:, :1], 0.0, atol=1e-6)
    w = np.array([0.4, 0.4, 0.4])                            # |t − t₀| / |t₁ − t₀| of the three bridged epochs
    t = np.array(times[:3])
    np.testing.assert_allclose(left[:3, 0], (1 - w) * _clock_m(np.array([0.0, 5.0, 5.0]))
                               + w * _clock_m(np.array([5.0, 0.0, 10.0])), atol=1e-6)
    assert not np.allclose(left[:3, 0], _clock_m(t))          # the clock is not linear: not its value at t
    np.testing.assert_allclose(age[:9], 1.2)                  # |t − t₀|(1 − w): 2 s × 0.6
    assert age[9:].tolist() == [0.0] * 3
    np.testing.assert_allclose((rng - m["pseudorange_m_b"].to_numpy()) / LAM,
                               phase - m["phase_cycles_b"].to_numpy(), atol=1e-9)


@pytest.mark.parametrize("case, lost", [
    ({"lli": {(1, "G07"): 1}}, [0, 1]),       # G07 slipped between 0 and 5 s: epochs interpolating across it
    ({"lli": {(2, "G07"): 1}}, [2]),          # between 5 and 10 s: only the epoch at 7 s
    ({"lli": {(1, "G12"): 2}}, [0, 1, 2]),    # half-cycle unresolved at 5 s only: a change on both sides
    ({"phase_nan": [(1, "G01")]}, [0, 1, 2]), # no phase at 5 s: t₁ of the first, t₀ of the other two
])
def test_a_slip_half_cycle_change_or_missing_row_keeps_the_whole_group_on_its_nearest_epoch(case, lost):
    times = [2.0, 3.0, 7.0]
    m, (phase, rng, age, done) = _run(_base(**case), times)
    by_epoch = done.reshape(len(times), len(SATS))
    assert (by_epoch.all(axis=1) | ~by_epoch.any(axis=1)).all()     # all of a group or none
    assert np.flatnonzero(~by_epoch.all(axis=1)).tolist() == lost
    kept = ~done
    np.testing.assert_array_equal(phase[kept], m["phase_cycles_b"].to_numpy()[kept])
    np.testing.assert_array_equal(age[kept], (m["t"].to_numpy() - TB[m["_bep"].to_numpy()])[kept])


def test_a_base_epoch_beyond_the_maximum_age_is_not_used():
    _, (_, _, age, done) = _run(_base(), [2.0, 7.0], max_age_s=2.5)      # t₁ is 3 s away
    assert not done.any() and age.tolist() == [2.0] * 3 + [2.0] * 3
    _, (_, _, _, done) = _run(_base(), [2.0, 7.0], max_age_s=3.0)
    assert done.all()


def test_base_rows_carry_a_slip_of_an_unused_epoch_to_the_next_used_one():
    b = pd.DataFrame({"time_gps_s": np.repeat(TB, 2), "sat": ["G01", "G07"] * 3, "signal": "G:L1",
                      "lli": [0, 0, 1, 0, 0, 0]})
    out = base_rows(b, TB, np.array([1, 0, 1]))
    assert out["_bep"].tolist() == [0, 0, 1, 1, 2, 2] and out["_row_b"].tolist() == list(range(6))
    assert out["lli"].tolist() == [0, 0, 1, 0, 1, 0]           # G01's flag at 5 s (serving no rover epoch) also at 10 s
    assert base_rows(b, TB, np.array([1, 1, 1]))["lli"].tolist() == [0, 0, 1, 0, 0, 0]


def test_no_interpolation_across_a_change_of_ephemeris():
    """With ``eph_row`` (the ephemeris of each row's model), a satellite whose ephemeris at t₁ is not the one at t₀
    keeps its group on the nearest epoch: M₁ − M₀ would hold the jump between the two ephemerides."""
    b = _base()
    b["eph_row"] = np.where((b["time_gps_s"] >= 5.0) & (b["sat"] == "G07"), 2, 1)     # G07's changes before 5 s
    m = _paired(b, [2.0, 3.0, 7.0])
    m["eph_row_b"] = np.where((m["_bep"] >= 1) & (m["sat"] == "G07"), 2, 1)
    _, _, _, done = interpolate_base(m, b, TB, m["t"].to_numpy(), base_xyz_m=XB, sync_tol_s=0.025, max_age_s=30.0,
                                     troposphere=True)
    # G07's ephemeris changes between 0 and 5 s (not between 5 and 10 s): the epochs at 2 and 3 s keep the nearest
    assert done.reshape(3, 3).all(axis=1).tolist() == [False, False, True]
    m0 = _paired(_base(), [2.0, 3.0, 7.0])
    assert interpolate_base(m0, _base(), TB, m0["t"].to_numpy(), base_xyz_m=XB, sync_tol_s=0.025, max_age_s=30.0,
                            troposphere=True)[3].all()          # without the column: every group, as before


def test_each_signal_group_is_interpolated_on_its_own_with_its_rows_wavelengths():
    """Two signal groups per rover epoch (GPS L1 and GLONASS G1, whose satellites have wavelengths of their own): a
    slip of R02 between 0 and 5 s keeps the GLONASS group of the epoch at 2 s on its nearest epoch and not its GPS
    group; at 7 s both groups are interpolated, each row with its own wavelength (every group recovers its
    satellites' linear truth up to a common term)."""
    lam_r = {"R01": 0.18713, "R02": 0.18740, "R03": 0.18768}           # FDMA: one per satellite
    to_r = dict(zip(SATS, lam_r))
    gps = _base()
    glo = _base().assign(signal="R:G1", sat=lambda d: d["sat"].map(to_r))
    glo["wavelength_m"] = glo["sat"].map(lam_r)
    glo["phase_cycles"] = glo["pseudorange_m"] / glo["wavelength_m"]
    glo.loc[(glo["time_gps_s"] == 5.0) & (glo["sat"] == "R02"), "lli"] = 1
    both = pd.concat([gps, glo], ignore_index=True).drop(columns=["_bep", "_row_b"])
    b = base_rows(both.sort_values(["time_gps_s", "signal", "sat"], kind="stable").reset_index(drop=True), TB,
                  np.ones(TB.size, dtype=np.int64))
    rows = [dict(_ep=e, _bep=int(np.argmin(np.abs(TB - t))), sat=s, signal=sig, t=t, truth=g,
                 wavelength_m=LAM if sig == "G:L1" else lam_r[s])
            for e, t in enumerate([2.0, 7.0]) for sig in ("G:L1", "R:G1")
            for g, s in ((g, g if sig == "G:L1" else to_r[g]) for g in SATS)]
    m = pd.DataFrame(rows)
    at0 = b[list(BASE_ROW_COLUMNS)].rename(columns={c: c + "_b" for c in BASE_ROW_COLUMNS[3:]})
    m = m.merge(at0, on=["_bep", "sat", "signal"], how="left", sort=False)
    phase, _, _, done = interpolate_base(m, b, TB, m["t"].to_numpy(), base_xyz_m=XB, sync_tol_s=0.025,
                                         max_age_s=30.0, troposphere=True)
    assert done.reshape(4, 3).all(axis=1).tolist() == [True, False, True, True]    # (2 s: GPS, GLONASS), (7 s: …)
    model0 = (np.linalg.norm(m[["sx_b", "sy_b", "sz_b"]].to_numpy() - XB, axis=1) - m["sat_clock_m_b"].to_numpy()
              + m["trop_m_b"].to_numpy())
    lin = (m["truth"].map(ALPHA) + m["truth"].map(BETA) * m["t"]).to_numpy()
    left = (phase * m["wavelength_m"].to_numpy() - model0 - lin).reshape(4, 3)[[0, 2, 3]]
    np.testing.assert_allclose(left - left[:, :1], 0.0, atol=1e-6)


# ------------------------------------------------------------------------------------------------------------------
# base_drift_m_per_s: how fast the base's observation minus its model departs from itself


def _drifting_base(rate_sigma_m_s: float, noise_m: float, seed: int = 2, n_sats: int = 8, n_ep: int = 600,
                   slips: dict | None = None) -> pd.DataFrame:
    """A 1 Hz base whose observation minus model is, per satellite, an offset + a constant rate drawn with σ
    ``rate_sigma_m_s`` + white noise ``noise_m`` + a common receiver clock; ``slips`` {(epoch, sat index): cycles}
    jumps the phase from that epoch on, flagged (LLI bit 0)."""
    rng = np.random.default_rng(seed)
    rate = rng.normal(0.0, rate_sigma_m_s, n_sats)
    offset = rng.normal(0.0, 5.0, n_sats)
    rows = []
    jump = np.zeros(n_sats)
    for k in range(n_ep):
        t = float(k)
        for i in range(n_sats):
            flagged = (slips or {}).get((k, i))
            if flagged:
                jump[i] += flagged * LAM
            sat_xyz = np.array([2.0e7 + 1.0e6 * i, 1.0e7 - 7.0e2 * t, 1.5e7 + 2.5e3 * t])
            clk, trop = 12.0 + 0.01 * t + i, 2.3 + 0.001 * t
            model = np.linalg.norm(sat_xyz - XB) - clk + trop
            obs_m = model + offset[i] + rate[i] * t + rng.normal(0.0, noise_m) + _clock_m(t) + jump[i]
            rows.append(dict(time_gps_s=t, sat=f"G{i + 1:02d}", signal="G:L1", phase_cycles=obs_m / LAM,
                             sx=sat_xyz[0], sy=sat_xyz[1], sz=sat_xyz[2], sat_clock_m=clk, trop_m=trop,
                             lli=1 if flagged else 0, wavelength_m=LAM, el_rad=0.8))
    return pd.DataFrame(rows), rate


def test_base_drift_is_the_spread_of_the_satellites_rates():
    from cdgps_cli.measurement.base_interpolation import base_drift_m_per_s
    b, rate = _drifting_base(0.01, 0.002)
    out = base_drift_m_per_s(b, XB, troposphere=True, max_age_s=30.0)
    # the epoch's mean out (the receiver clock): each channel keeps rate − mean rate, whose spread the lags show
    spread = float(np.std(rate - rate.mean()))
    assert out["estimate_m_per_s"] == pytest.approx(spread, rel=0.35), (out, spread)
    assert out["lags_s"][0] == 1.0 and max(out["lags_s"]) <= 30.0 and out["noise_m"] < 0.01


def test_base_drift_of_white_noise_alone_is_near_zero_whatever_the_slips():
    from cdgps_cli.measurement.base_interpolation import base_drift_m_per_s
    b, _ = _drifting_base(0.0, 0.003)
    out = base_drift_m_per_s(b, XB, troposphere=True, max_age_s=30.0)
    assert out["estimate_m_per_s"] < 2e-4 and out["noise_m"] == pytest.approx(0.003 * np.sqrt(2) * np.sqrt(7 / 8), rel=0.2)
    slipped, _ = _drifting_base(0.0, 0.003, slips={(100, 2): 1000, (350, 5): -77})
    again = base_drift_m_per_s(slipped, XB, troposphere=True, max_age_s=30.0)
    assert again["estimate_m_per_s"] < 2e-4
    unflagged = slipped.assign(lli=0)                    # the few differences across an unflagged jump: the MAD
    assert base_drift_m_per_s(unflagged, XB, troposphere=True, max_age_s=30.0)["estimate_m_per_s"] < 2e-4


def test_base_drift_needs_two_lags_within_the_maximum_age():
    from cdgps_cli.measurement.base_interpolation import base_drift_m_per_s
    b, _ = _drifting_base(0.01, 0.002, n_ep=80)
    sparse = b[(b["time_gps_s"] % 30) == 0]                       # a 30 s base: one lag within 30 s
    assert base_drift_m_per_s(sparse, XB, troposphere=True, max_age_s=30.0)["estimate_m_per_s"] is None
    assert base_drift_m_per_s(b.iloc[:20], XB, troposphere=True, max_age_s=30.0)["estimate_m_per_s"] is None
