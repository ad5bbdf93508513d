"""Acquisition and tracking on synthetic signals of known Doppler, code phase and C/N0, an
independent time-domain correlation on the real Pocket SDR samples, and `cdgps track` end to end."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.iq_samples import read_samples
from cdgps_cli.tracking.acquisition import acquire
from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, sampled_code
from cdgps_cli.tracking.channel import L1_HZ, track

from _track_signals import FS, ca_signal as _signal

IQ_FILE = Path(__file__).resolve().parents[3] / "shared" / "data" / "if" / "L1_20211202_084700_4MHz_IQ.bin"
needs_if = pytest.mark.skipif(not IQ_FILE.exists(), reason="../shared/data/if not present")


def test_acquisition_finds_a_synthetic_satellite():
    x, _ = _signal(7, 1234.0, 345.6, 45.0, 0.012)
    res = {a.prn: a for a in acquire(x, FS, [7, 8])}
    a = res[7]
    assert a.acquired and abs(a.doppler_hz - 1234.0) <= 25.0
    assert abs((a.code_phase_chips - 345.6 + 511.5) % 1023 - 511.5) < 0.5
    assert not res[8].acquired


def test_tracking_a_synthetic_satellite_recovers_doppler_phase_and_cn0():
    x, phase = _signal(11, -1800.0, 100.2, 45.0, 0.4, seed=3, doppler_rate_hz_s=5.0)
    a = next(a for a in acquire(x, FS, [11]) if a.acquired)
    r = track(x, FS, 11, a.doppler_hz, a.code_phase_chips)
    tail = slice(300, None)
    t = r["time_s"][tail]
    assert np.abs(r["doppler_hz"][tail] - (-1800.0 + 5.0 * t)).max() < 3.0
    # carrier phase at block starts = the signal's phase, modulo the Costas half cycle
    err = (r["carrier_phase_cycles"][tail] - phase[(t * FS).astype(int)] / (2 * np.pi)) * 2
    err = (err - np.round(np.median(err))) / 2                                        # cycles
    assert np.abs(err - np.median(err)).max() < 0.05
    assert np.nanmedian(r["cn0_dbhz"][tail]) == pytest.approx(45.0, abs=2.0)
    assert np.mean(r["phase_lock"][tail] > 0.8) > 0.95
    assert np.abs((r["code_phase_chips"][-1] - (100.2 + t[-1] * CHIP_RATE_HZ * (1 + (-1800 + 2.5 * t[-1]) / L1_HZ))
                   + 511.5) % 1023 - 511.5) < 0.1


@needs_if
def test_acquisition_agrees_with_a_time_domain_correlation_on_real_samples():
    """Independent check: direct correlation over every half-chip code phase at the found Doppler."""
    x = read_samples(IQ_FILE, "int8-iq", max_samples=int(FS * 0.01))
    a = next(a for a in acquire(x, FS, [26]) if a.acquired)
    t = np.arange(x.size) / FS
    wiped = x * np.exp(-2j * np.pi * a.doppler_hz * t)
    phases = np.arange(0, 1023, 0.5)
    power = np.empty(phases.size)
    for i, p in enumerate(phases):
        c = sampled_code(26, FS, x.size, p)
        blocks = (wiped * c).reshape(10, -1).sum(axis=1)
        power[i] = np.sum(np.abs(blocks) ** 2)
    best = phases[int(np.argmax(power))]
    assert abs((best - a.code_phase_chips + 511.5) % 1023 - 511.5) <= 0.5


def _run(*args):
    return CliRunner().invoke(main, ["-q", *map(str, args)])


@needs_if
def test_track_command_on_the_real_file(tmp_path):
    out = tmp_path / "track.mcap"
    r = _run("track", IQ_FILE, "--format", "int8-iq", "--fs", "4000000", "--if", "0", "-o", out, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    locked = [x for x in s["satellites"] if x["phase_lock"]]
    assert len(locked) >= 3
    for x in s["satellites"]:
        assert {"prn", "doppler_hz", "code_phase_chips", "cn0_dbhz", "phase_lock"} <= set(x)
        assert abs(x["doppler_hz"]) < 5000 and 30 < x["cn0_dbhz"] < 60
    from cdgps_cli.io.mcap import read_mcap

    m = read_mcap(out)
    assert "/cdgps/track" in m.topics


@pytest.mark.parametrize("setup,args,words", [
    ("odd", ["--format", "int8-iq", "--fs", "4000000"], "not a whole number of int8-iq samples"),
    ("noise", ["--format", "int8-iq", "--fs", "4000000"], "no satellite acquired"),
    ("noise", ["--format", "int8-iq", "--fs", "1000"], "--fs"),
    ("short", ["--format", "int8-iq", "--fs", "4000000"], "at least 20 ms"),
])
def test_bad_input_is_named(tmp_path, setup, args, words):
    f = tmp_path / "x.bin"
    g = np.random.default_rng(0)
    n = {"odd": 80001, "noise": 2 * 40000 * 2, "short": 2 * 40000}[setup]
    f.write_bytes(g.integers(-3, 4, n).astype(np.int8).tobytes())
    r = _run("track", f, *args, "-o", tmp_path / "t.mcap")
    assert r.exit_code == 2 and words in r.output, r.output
    assert not (tmp_path / "t.mcap").exists()


@needs_if
def test_a_prn_that_is_not_visible_is_named(tmp_path):
    r = _run("track", IQ_FILE, "--format", "int8-iq", "--fs", "4000000", "--prn", "1", "--duration", "0.05",
             "-o", tmp_path / "t.mcap")
    assert r.exit_code == 2 and "not acquired: PRN 1" in r.output, r.output


def test_aiding_keeps_a_narrow_loop_locked_through_dynamics():
    """Alban et al. 2003: with the line-of-sight Doppler fed forward, a 3 Hz loop holds lock through
    a 0.5 g, 2 Hz line-of-sight acceleration that the same loop unaided cannot follow."""
    from cdgps_cli.tracking.channel import TrackOptions

    fs = 2.2e6                                                        # 2.15 chips per sample
    x, _ = _signal(9, 900.0, 50.0, 48.0, 1.2, seed=5, bits=False, fs=fs)   # a 3 Hz loop settles in ~1 s
    t = np.arange(x.size) / fs
    acc, w = 0.5 * 9.80665, 2 * np.pi * 2.0
    phi = 2 * np.pi * (-acc / w**2 * np.sin(w * t)) * L1_HZ / 299792458.0
    vel = -acc / w * np.cos(w * t)
    upd = np.arange(int(x.size / 2200)) * 1e-3
    aid = np.interp(upd + 5e-4, t, vel) * L1_HZ / 299792458.0
    moved = x * np.exp(1j * phi)
    a = next(a for a in acquire(x, fs, [9]) if a.acquired)
    opt = TrackOptions(pll_bn_hz=3.0, pull_in_s=0.1)
    aided = track(moved, fs, 9, a.doppler_hz, a.code_phase_chips, opt, aid_doppler_hz=aid)
    unaided = track(moved, fs, 9, a.doppler_hz, a.code_phase_chips, opt)
    after = slice(800, None, 20)
    assert np.mean(aided["phase_lock"][after] > 0.8) == 1.0
    assert np.mean(unaided["phase_lock"][after] > 0.8) < 0.6


@needs_if
def test_receiver_takes_an_external_doppler_per_channel():
    """track_all(aids={prn: …}): the channel starts from the acquired Doppler minus the first aid and
    feeds the aid forward — the same run as track() given those; an aid for a PRN not acquired is named."""
    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.tracking.receiver import track_all

    x = read_samples(IQ_FILE, "int8-iq", max_samples=int(FS * 0.15))
    m = x.size // 4000
    aid = 3.0 + 2.0 * np.sin(np.arange(m) * 0.01)                        # Hz per update
    t = np.arange(x.size) / FS
    moved = x * np.exp(1j * 2 * np.pi * np.interp(t, np.arange(m) * 1e-3, np.cumsum(aid) * 1e-3))
    res = track_all(moved, FS, [31], aids={31: aid})
    a = next(a for a in res["acquisition"] if a["prn"] == 31)
    ref = track(moved, FS, 31, a["doppler_hz"] - aid[0], a["code_phase_chips"], aid_doppler_hz=aid)
    for k in ("doppler_hz", "carrier_phase_cycles", "i_prompt"):
        np.testing.assert_array_equal(res["tracks"][31][k], ref[k])
    with pytest.raises(CdgpsError, match=r"aids: given for PRN 5, not acquired \(acquired: 31\)"):
        track_all(moved, FS, [31], aids={5: aid})
