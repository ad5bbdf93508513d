"""The IF sample simulator against its own truth and independent checks: acquisition finds the set
Doppler and code phase, the loops' carrier phase follows the geometric phase to a few mm, the
measured C/N0 is the set one, the oscillator's Allan variances are the power-law formulas, the
shared oscillator cancels between two antennas, quantization and determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.sim import if_samples as S
from cdgps_cli.tracking.acquisition import acquire
from cdgps_cli.tracking.ca_code import ca_code, sampled_code
from cdgps_cli.tracking.channel import track

FS = 4e6
CODES = {p: ca_code(p) for p in (3, 11, 17, 24)}
LAMBDA_M = S.C_M_S / S.L1_HZ


def _txs():
    return [S.Transmitter("A", 3, (10.0, 0.0, 3.0), cn0_dbhz=45.0, frequency_offset_hz=1234.0,
                          code_offset_chips=S.CHIPS_PER_BIT + 20 * 300.3, carrier_phase_cycles=0.2),
            S.Transmitter("B", 17, (-4.0, 8.0, 5.0), cn0_dbhz=42.0, frequency_offset_hz=-2100.0,
                          code_offset_chips=1.5 * S.CHIPS_PER_BIT + 20 * 17.7)]


def _moving(seconds, amp_m=0.05, f_hz=0.8, offset=(0.0, 0.0, 0.0)):
    """Knot positions (K, 3) of an antenna swinging along x."""
    t = np.arange(int(round(seconds / S.KNOT_S)) + 2) * S.KNOT_S
    p = np.tile(np.asarray(offset, float), (t.size, 1))
    p[:, 0] += amp_m * np.sin(2 * np.pi * f_hz * t)
    return p


def _samples(txs, pos, seconds, clock_s=None, seed=1, opt=None):
    opt = opt or S.IfOptions(fs_hz=FS)
    delay = np.stack([S.line_of_sight_range_m(tx, pos) / S.C_M_S for tx in txs], axis=1)
    if clock_s is not None:
        delay = delay + clock_s[:, None]
    n = int(round(seconds * opt.fs_hz))
    raw = np.concatenate(list(S.antenna_blocks(delay, txs, CODES, n, opt, np.random.default_rng(seed))))
    x = raw[0::2].astype(float) + (-1j if opt.iq_sign == "minus" else 1j) * raw[1::2]
    return x, delay


def test_acquisition_finds_the_simulated_doppler_and_code_phase():
    txs = _txs()
    x, delay = _samples(txs, _moving(0.012), 0.012)
    acq = {a.prn: a for a in acquire(x, FS, [3, 17, 24])}
    for j, tx in enumerate(txs):
        tr = S.truth_at(tx, delay[:, j], np.array([0.0]))
        a = acq[tx.prn]
        assert a.acquired
        assert abs(a.doppler_hz - tr["doppler_hz"][0]) <= 30.0     # fine search: 10 Hz steps, 5 ms coherent
        assert abs((a.code_phase_chips - tr["code_phase_chips"][0] + 511.5) % 1023 - 511.5) < 0.3
    assert not acq[24].acquired


def test_generated_signal_matches_an_independent_replica():
    """Direct correlation with sampled_code and a carrier built from the truth: the prompt amplitude is
    A·n (the set C/N0) and the phase is the truth's, over 20 one-ms blocks of one navigation bit."""
    tx = S.Transmitter("A", 11, (3.0, 4.0, 12.0), cn0_dbhz=50.0, frequency_offset_hz=500.0,
                       code_offset_chips=S.CHIPS_PER_BIT)                  # a bit starts at t ≈ 0
    x, delay = _samples([tx], _moving(0.02), 0.02)
    n = int(FS * 1e-3)
    t = np.arange(x.size) / FS
    tr = S.truth_at(tx, delay[:, 0], t)
    replica = sampled_code(11, FS, x.size, tr["code_phase_chips"][0], S.CHIP_RATE_HZ * (1 + 500.0 / S.L1_HZ))
    p = (x * replica * np.exp(-2j * np.pi * tr["carrier_phase_cycles"])).reshape(-1, n).sum(axis=1)
    step = S.QUANTIZER_STEP[8]
    amp = np.abs(p.mean()) * step / n                                      # back to noise-σ units
    assert amp == pytest.approx(S.amplitude(50.0, FS), rel=0.03)
    assert abs(np.angle(p.mean() * np.sign(p.mean().real))) < 0.05        # data bit ±1 only


@pytest.fixture(scope="module")
def tracked():
    txs = _txs()
    pos = _moving(0.5)
    x, delay = _samples(txs, pos, 0.5)
    acq = {a.prn: a for a in acquire(x, FS, [3, 17])}
    out = {}
    for j, tx in enumerate(txs):
        a = acq[tx.prn]
        out[tx.name] = (track(x, FS, tx.prn, a.doppler_hz, a.code_phase_chips), tx, delay[:, j])
    return out


def _phase_error_m(r, tx, delay, start=300):
    """Tracked minus true carrier phase (m) after the pull-in, with the constant (integer or half
    cycle, and the NCO's arbitrary start) removed."""
    t = r["time_s"][start:]
    err = r["carrier_phase_cycles"][start:] - S.truth_at(tx, delay, t)["carrier_phase_cycles"]
    err -= np.round(np.median(err) * 2) / 2
    return (err - np.median(err)) * LAMBDA_M


@pytest.mark.parametrize("name", ["A", "B"])
def test_tracked_carrier_phase_follows_the_truth_to_a_few_mm(tracked, name):
    r, tx, delay = tracked[name]
    e = _phase_error_m(r, tx, delay)
    # thermal jitter of a 15 Hz PLL: 0.65 mm at 45 dB-Hz, 0.9 mm at 42 dB-Hz (1σ)
    assert np.std(e) < 2e-3 and np.abs(e).max() < 6e-3
    assert np.mean(r["phase_lock"][300:] > 0.8) > 0.95


@pytest.mark.parametrize("name", ["A", "B"])
def test_measured_cn0_is_the_set_one(tracked, name):
    r, tx, _ = tracked[name]
    assert np.nanmedian(r["cn0_dbhz"][300::20]) == pytest.approx(tx.cn0_dbhz, abs=1.5)


def _allan_variance(x_s, step_s, m):
    """Overlapping Allan variance at τ = m·step from time errors x (s)."""
    d = x_s[2 * m:] - 2 * x_s[m:-m] + x_s[:-2 * m]
    return np.mean(d * d) / (2 * (m * step_s) ** 2)


@pytest.mark.parametrize("kind,h,expected", [
    ("white FM", {"h0": 1e-20}, lambda tau: 1e-20 / (2 * tau)),
    ("flicker FM", {"h_minus1": 1e-21}, lambda tau: 2 * math.log(2) * 1e-21),
    ("random-walk FM", {"h_minus2": 1e-22}, lambda tau: 2 * math.pi**2 / 3 * 1e-22 * tau),
])
def test_oscillator_allan_variance_follows_the_power_law(kind, h, expected):
    step, n = 1e-3, 400_000
    for seed in (0, 1):
        x = S.clock_error_s(S.Oscillator(**h), n, step, np.random.default_rng(seed))
        for m in (10, 100):
            ratio = _allan_variance(x, step, m) / expected(m * step)
            assert 0.8 < ratio < 1.25, (kind, seed, m, ratio)


def test_shared_oscillator_cancels_in_the_difference():
    """Two antennas 1 m apart, one noisy oscillator: each antenna's tracked phase wanders by cycles
    against the geometric phase, their difference follows the geometric difference to mm."""
    tx = S.Transmitter("A", 11, (6.0, 2.0, 9.0), cn0_dbhz=48.0, frequency_offset_hz=800.0)
    n_knots = int(0.5 / S.KNOT_S) + 2
    clock = S.clock_error_s(S.Oscillator(h_minus2=5e-18, frequency_offset=3e-7), n_knots, S.KNOT_S, np.random.default_rng(5))
    pos_m, pos_a = _moving(0.5, amp_m=0.0), _moving(0.5, amp_m=0.04, offset=(1.0, 0.0, 0.0))
    res = []
    for seed, pos in ((1, pos_m), (2, pos_a)):
        x, delay = _samples([tx], pos, 0.5, clock_s=clock, seed=seed)
        a = acquire(x, FS, [11])[0]
        r = track(x, FS, 11, a.doppler_hz, a.code_phase_chips)
        geometric = np.stack([S.line_of_sight_range_m(tx, pos) / S.C_M_S], axis=1)[:, 0]
        res.append((r, delay[:, 0], geometric))
    t = res[0][0]["time_s"][300:]
    wander = []
    for r, _, geometric in res:
        err = r["carrier_phase_cycles"][300:] - S.truth_at(tx, geometric, t)["carrier_phase_cycles"]
        wander.append(np.ptp(err - np.polyval(np.polyfit(t, err, 1), t)))    # beyond the frequency offset
    assert min(wander) > 0.2, wander              # ≥ 38 mm of oscillator phase at each antenna, 20× the bound below
    (ra, da, ga), (rb, db, gb) = res[1], res[0]
    sd = ra["carrier_phase_cycles"][300:] - rb["carrier_phase_cycles"][300:]
    sd_true = (S.truth_at(tx, ga, t)["carrier_phase_cycles"] - S.truth_at(tx, gb, t)["carrier_phase_cycles"])
    e = sd - sd_true
    e -= np.round(np.median(e) * 2) / 2
    e = (e - np.median(e)) * LAMBDA_M
    assert np.std(e) < 2e-3 and np.abs(e).max() < 8e-3


def test_quantizer_levels():
    x = np.linspace(-10, 10, 2001)
    assert set(np.unique(S.quantize(x, 1))) == {-1, 1}
    assert set(np.unique(S.quantize(x, 2))) == {-3, -1, 1, 3}
    assert S.quantize(x, 7).min() == -127 and S.quantize(x, 7).max() == 127
    q8 = S.quantize(x, 8)
    assert q8.min() == -127 and q8.max() == 127 and np.all(q8 == -S.quantize(-x, 8))
    assert np.all(S.quantize(x, 3) == -S.quantize(-x - 1e-12, 3))              # mid-rise: odd symmetric


def test_two_bit_quantization_costs_about_half_a_db():
    """Max's optimum 2-bit quantizer loses 0.55 dB of C/N0 (Gaussian input); measured on the prompt."""
    txs = _txs()[:1]
    pos = _moving(0.3)
    out = []
    for bits in (8, 2):
        x, _ = _samples(txs, pos, 0.3, opt=S.IfOptions(fs_hz=FS, bits=bits), seed=4)
        a = acquire(x, FS, [3])[0]
        r = track(x, FS, 3, a.doppler_hz, a.code_phase_chips)
        out.append(np.nanmean(r["cn0_dbhz"][200::20]))
    assert 0.1 < out[0] - out[1] < 1.2


def test_same_seed_same_bytes_other_seed_other_bytes():
    txs = _txs()
    delay = np.stack([S.line_of_sight_range_m(tx, _moving(0.01)) / S.C_M_S for tx in txs], axis=1)
    opt = S.IfOptions(fs_hz=FS, block_s=0.003)
    a = b"".join(b.tobytes() for b in S.antenna_blocks(delay, txs, CODES, 40_000, opt, np.random.default_rng(3)))
    b = b"".join(b.tobytes() for b in S.antenna_blocks(delay, txs, CODES, 40_000, opt, np.random.default_rng(3)))
    c = b"".join(b.tobytes() for b in S.antenna_blocks(delay, txs, CODES, 40_000, opt, np.random.default_rng(4)))
    one = b"".join(b.tobytes() for b in S.antenna_blocks(delay, txs, CODES, 40_000, S.IfOptions(fs_hz=FS, block_s=1.0),
                                                          np.random.default_rng(3)))
    assert a == b != c and len(a) == 80_000
    assert one[:8000] == a[:8000]           # the first block of 3 ms is the same noise, whatever the blocking


@pytest.mark.parametrize("kw,words", [
    ({"fs_hz": 1e6}, "fs_hz"), ({"fs_hz": 4.0001e6}, "whole number of samples per millisecond"),
    ({"bits": 9}, "bits"), ({"iq_sign": "x"}, "iq_sign"), ({"if_hz": 1.5e6}, "if_hz"),
])
def test_bad_options_are_refused(kw, words):
    with pytest.raises(CdgpsError, match=words):
        S.IfOptions(**kw).check()


def test_bad_oscillator_is_refused():
    with pytest.raises(CdgpsError, match="h_minus2"):
        S.Oscillator(h_minus2=-1.0).check()
    with pytest.raises(CdgpsError, match="100 ppm"):
        S.Oscillator(frequency_offset=1e-3).check()
