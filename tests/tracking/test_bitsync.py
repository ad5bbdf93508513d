"""Navigation-bit synchronization against synthetic signals whose bits change at known code epochs,
and on the real samples (every edge found is a code epoch of the satellite)."""

import math

import numpy as np
import pytest

from cdgps_cli.tracking.bitsync import bit_sync
from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, ca_code
from cdgps_cli.tracking.channel import L1_HZ, TrackOptions, track


def _bits_signal(prn, doppler_hz, code_phase_chips, cn0_dbhz, seconds, fs=2.2e6, seed=0):
    """C/A signal whose ±1 data bits change only at code epochs, every 20 periods (random bits)."""
    g = np.random.default_rng(seed)
    t = np.arange(int(fs * seconds)) / fs
    rate = CHIP_RATE_HZ * (1 + doppler_hz / L1_HZ)
    chips = code_phase_chips + rate * t
    bits = g.choice([-1.0, 1.0], size=int(chips[-1] // 20460) + 2)
    x = ca_code(prn)[np.floor(chips).astype(np.int64) % 1023] * bits[np.floor(chips / 20460).astype(np.int64)]
    x = x * np.exp(1j * (2 * np.pi * doppler_hz * t + 0.4))
    sigma = math.sqrt(fs / 10 ** (cn0_dbhz / 10) / 2)
    first_edge_s = (20460 - code_phase_chips) / rate
    return x + sigma * g.standard_normal(2 * t.size).view(np.complex128), first_edge_s % (20460 / rate)


@pytest.mark.parametrize("code_phase", [100.0, 520.0, 600.0, 1000.0])     # edges late, mid, mid, early in a block
def test_bit_edge_is_the_code_epoch_where_the_data_change(code_phase):
    x, truth = _bits_signal(5, -1500.0, code_phase, 42.0, 0.8, seed=int(code_phase))
    r = track(x, 2.2e6, 5, -1500.0, code_phase, TrackOptions())
    got = bit_sync(r)
    assert got["bit_changes"] >= 10 and got["bit_sync_fraction"] == 1.0
    assert got["bit_edge_s"] == pytest.approx(truth, abs=0.05 / CHIP_RATE_HZ)          # within 0.05 chip


def test_no_edge_without_data_changes():
    r = {"i_prompt": np.ones(500), "pll": np.ones(500, bool), "time_s": np.arange(500) * 1e-3,
         "code_phase_chips": np.full(500, 10.0), "doppler_hz": np.zeros(500)}
    assert bit_sync(r) == {"bit_edge_s": None, "bit_changes": 0, "bit_sync_fraction": None}


def test_real_satellites_bit_edges_are_code_epochs(tmp_path):
    """On the real file every locked satellite's sign changes agree on one epoch, and that epoch is one of
    the satellite's code epochs (code phase at the edge ≈ 0 chip, carried by its Doppler)."""
    from pathlib import Path

    from cdgps_cli.io.iq_samples import read_samples
    from cdgps_cli.tracking.receiver import track_all

    path = Path(__file__).resolve().parents[3] / "shared" / "data" / "if" / "L1_20211202_084700_4MHz_IQ.bin"
    if not path.exists():
        pytest.skip("../shared data not present")
    res = track_all(read_samples(path, "int8-iq", "minus"), 4e6)
    locked = [s for s in res["satellites"] if s["phase_lock"]]
    assert len(locked) >= 3
    for s in locked:
        assert s["bit_changes"] >= 5 and s["bit_sync_fraction"] == 1.0
        chips = (s["code_phase_chips"] + s["bit_edge_s"] * CHIP_RATE_HZ * (1 + s["doppler_hz"] / L1_HZ)) % 1023
        assert min(chips, 1023 - chips) < 0.1, (s["prn"], chips)
