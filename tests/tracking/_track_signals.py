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


def track_pieces(prn, doppler_hz, code_phase_chips, cn0_dbhz, seconds, configs, *, phase_fn=None, seed=0,
                 fs=2.2e6, piece_s=0.5):
    """Generate a static-Doppler C/A signal (plus ``phase_fn(t)`` rad) piecewise and track it with every
    config ``(label, TrackOptions, aid per update or None)``; returns per label the run_updates rows and
    the true phase at mid-block (rad), so long signals fit in memory."""
    from cdgps_cli.tracking.channel import initial_state, run_updates

    g = np.random.default_rng(seed)
    code = ca_code(prn).astype(float)
    n_ms = int(round(fs * 1e-3))
    m, per = int(round(seconds * 1e3)), int(round(piece_s * 1e3))
    states = {lab: initial_state(doppler_hz + 2.0, code_phase_chips) for lab, _, _ in configs}
    outs = {lab: [] for lab, _, _ in configs}
    sigma = math.sqrt(fs / 10 ** (cn0_dbhz / 10) / 2)
    for k0 in range(0, m, per):
        k1 = min(m, k0 + per)
        t = np.arange(k0 * n_ms, k1 * n_ms) / fs
        chips = code_phase_chips + t * CHIP_RATE_HZ * (1 + doppler_hz / L1_HZ)
        ph = 2 * np.pi * doppler_hz * t + (0.0 if phase_fn is None else phase_fn(t))
        x = code[np.floor(chips).astype(np.int64) % 1023] * np.exp(1j * ph)
        x += sigma * g.standard_normal(2 * t.size).view(np.complex128)
        for lab, opt, aid in configs:
            outs[lab].append(run_updates(x, fs, prn, states[lab], opt, None if aid is None else aid[k0:k1]))
    tm = (np.arange(m) + 0.5) * n_ms / fs
    truth = 2 * np.pi * doppler_hz * tm + (0.0 if phase_fn is None else phase_fn(tm))
    return {lab: np.vstack(v) for lab, v in outs.items()}, truth


def nco_error_rad(rows, truth, fs=2.2e6):
    """NCO phase at mid-block minus the truth, shifted by the multiple of π (Costas) nearest its median."""
    from cdgps_cli.tracking.channel import OUT_FIELDS

    T = round(fs * 1e-3) / fs
    nco = 2 * np.pi * (rows[:, OUT_FIELDS.index("carrier_phase_cycles")] + rows[:, OUT_FIELDS.index("doppler_hz")] * T / 2)
    e = nco - truth
    return e - np.pi * np.round(np.median(e) / np.pi)
