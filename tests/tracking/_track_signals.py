"""Synthetic complex-baseband GPS L1 C/A signals for the tracking tests (imported as ``_track_signals``)."""

from __future__ import annotations

import math

import numpy as np

from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, ca_code
from cdgps_cli.tracking.channel import L1_HZ

FS = 4e6


def ca_signal(prn, doppler_hz, code_phase_chips, cn0_dbhz, seconds, seed=0, doppler_rate_hz_s=0.0, bits=True, fs=FS):
    """Complex baseband C/A signal (unit amplitude) plus complex white noise at the given C/N0."""
    g = np.random.default_rng(seed)
    n = int(fs * seconds)
    t = np.arange(n) / fs
    phase = 2 * np.pi * (doppler_hz * t + 0.5 * doppler_rate_hz_s * t * t)
    fd = doppler_hz + doppler_rate_hz_s * t
    chips = code_phase_chips + t * CHIP_RATE_HZ + np.cumsum(fd / L1_HZ * CHIP_RATE_HZ / fs)
    code = ca_code(prn)[np.floor(chips).astype(np.int64) % 1023].astype(float)
    data = np.where((np.floor(t / 0.02).astype(int) % 3) == 1, -1.0, 1.0) if bits else 1.0
    noise_var = fs / 10 ** (cn0_dbhz / 10)                         # per complex sample, for unit carrier power
    noise = g.normal(0, math.sqrt(noise_var / 2), n) + 1j * g.normal(0, math.sqrt(noise_var / 2), n)
    return code * data * np.exp(1j * (phase + 0.7)) + noise, phase + 0.7
