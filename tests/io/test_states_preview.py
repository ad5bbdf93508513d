"""Issue 29 item 5: the Foxglove preview of STATES.mcap is low-pass filtered before decimation and its
rate follows the config's highest mode, so every mode shows at its own frequency.

A 120 m tower (configs/tower-120m-fe.toml: modes at 0.26, 0.28, 1.64 and 1.76 Hz, 10 Hz epochs) moving
in its 1.64 Hz mode only: decimated to 1 Hz without a filter, that mode shows at |1.64 − 2·1| = 0.36 Hz.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.signal import periodogram

from cdgps_cli.analysis.preview import PASSBAND_FRACTION, anti_alias_decimate, preview_stride_for_modes
from cdgps_cli.config.structure import load_config
from cdgps_cli.core.records import Series, StateSeries
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.states import STATE_TOPIC, States, preview_stride, write_states
from cdgps_cli.pipeline.estimate_outputs import preview_rate_hz_for

TOWER = Path(__file__).resolve().parents[2] / "configs" / "tower-120m-fe.toml"


def _tower_states(duration_s: float = 600.0, seed: int = 4):
    """StateSeries of the tower: ξ₃ = 10 mm sine at its mode's frequency plus 0.1 mm white noise."""
    cfg = load_config(TOWER)
    n = cfg.n_modes
    T = cfg.sample_period_s
    t = np.arange(int(round(duration_s / T)) + 1) * T
    f3 = float(cfg.mode_frequency_hz[2])
    rng = np.random.default_rng(seed)
    x = np.zeros((t.size, 2 * n))
    x[:, :n] = 1e-4 * rng.standard_normal((t.size, n))
    x[:, 2] += 0.01 * np.sin(2 * np.pi * f3 * t)
    x[:, n + 2] = 0.01 * 2 * np.pi * f3 * np.cos(2 * np.pi * f3 * t)
    P = np.broadcast_to(np.eye(n) * 1e-8, (t.size, n, n)).copy()
    names = list(cfg.coord_names)
    ss = StateSeries("structure", names, [cfg.coord_unit(c) for c in names], np.asarray(cfg.mode_shapes, dtype=float),
                     n, {STATE_TOPIC: Series(t, x, P)}, [("a", "b")], np.zeros((t.size, 1)), np.ones(t.size),
                     np.ones(t.size, dtype=int), [], cfg.wavelength_m)
    return cfg, ss, f3


def _preview_psd(path, coord: str):
    c = read_mcap(path, topics=[STATE_TOPIC]).topics[STATE_TOPIC]
    t = c.times()
    q = np.array([m[coord] for m in c.scalars["q"]])
    f, p = periodogram(q - q.mean(), fs=1.0 / np.median(np.diff(t)), window="hann")
    return f, p


def _at(f, p, hz, half_width_hz=0.01):
    return p[np.abs(f - hz) <= half_width_hz].max()


def _floor(f, p, around_hz, lo=0.03, hi=0.1):
    d = np.abs(f - around_hz)
    return np.median(p[(d > lo) & (d < hi)])


@pytest.fixture(scope="module")
def tower():
    return _tower_states()


def test_preview_rate_from_the_highest_mode(tower):
    cfg, ss, f3 = tower
    t = ss.series[STATE_TOPIC].time_s
    rate = preview_rate_hz_for(cfg, t)
    k = preview_stride(t, rate)
    assert k == 2 and rate == pytest.approx(5.0)                  # 1.76 Hz mode: 1 Hz would alias it
    assert PASSBAND_FRACTION * rate / 2 >= max(cfg.mode_frequency_hz)
    assert preview_stride_for_modes(0.1, [0.28, 0.1], 10) == 10   # testbed: never below the 1 Hz default
    assert preview_stride_for_modes(0.1, [], 10) == 10


@pytest.mark.parametrize("rate", ["auto", 1.0])
def test_mode_at_its_own_frequency_and_no_alias(tower, tmp_path, rate):
    """auto: the 1.64 Hz mode at 1.64 Hz in the preview; 1 Hz asked for: the mode is filtered out, not
    folded to 0.36 Hz.  Either way nothing above the noise floor at the old alias frequency."""
    cfg, ss, f3 = tower
    t = ss.series[STATE_TOPIC].time_s
    hz = preview_rate_hz_for(cfg, t) if rate == "auto" else rate
    out = tmp_path / "s.mcap"
    write_states(ss, out, {}, {}, preview_rate_hz=hz, preview=anti_alias_decimate)
    coord = "qx-2"
    f, p = _preview_psd(out, coord)
    alias = abs(f3 - round(f3 / 1.0) * 1.0)                        # 0.36 Hz: where 1 Hz decimation put it
    assert alias == pytest.approx(0.36, abs=0.01)
    assert _at(f, p, alias) < 10 * _floor(f, p, alias)
    if rate == "auto":
        assert f[np.argmax(p)] == pytest.approx(f3, abs=0.005)
        assert _at(f, p, f3) > 1e4 * _floor(f, p, f3)
    # the packed arrays (what cdgps reads) keep every epoch, unfiltered
    st = States(out, diagnostics=False)
    np.testing.assert_array_equal(st.xi, ss.series[STATE_TOPIC].x[:, :cfg.n_modes])


def test_plain_decimation_aliases(tower, tmp_path):
    """What the preview did before (no filter, 1 Hz): the mode shows at 0.36 Hz (the test above can fail)."""
    cfg, ss, f3 = tower
    out = tmp_path / "s.mcap"
    write_states(ss, out, {}, {}, preview_rate_hz=1.0)
    f, p = _preview_psd(out, "qx-2")
    assert _at(f, p, 0.362) > 1e3 * _floor(f, p, 0.362)


def test_anti_alias_decimate_is_zero_phase_and_keeps_the_passband():
    t = np.arange(3000) * 0.1
    x = np.sin(2 * np.pi * 0.3 * t)[:, None]
    for k in (2, 5, 10):
        y = anti_alias_decimate(x, k)
        assert y.shape == (len(range(0, t.size, k)), 1)
        np.testing.assert_allclose(y[20:-20, 0], x[::k][20:-20, 0], atol=2e-3)   # no delay, passband gain 1
    np.testing.assert_array_equal(anti_alias_decimate(x, 1), x)


def test_anti_alias_decimate_keeps_missing_epochs_local():
    """A NaN epoch stays NaN in the preview and does not spread over the filter's length."""
    t = np.arange(3000) * 0.1
    x = np.sin(2 * np.pi * 0.3 * t)[:, None]
    x[1003] = np.nan
    y = anti_alias_decimate(x, 10)
    assert np.isfinite(y).all()                                  # 1003 is not a kept epoch
    x[1000] = np.nan
    y = anti_alias_decimate(x, 10)
    assert np.isnan(y[100, 0]) and np.isfinite(np.delete(y, 100)).all()
    np.testing.assert_allclose(y[25:75, 0], x[::10][25:75, 0], atol=2e-3)      # away from the run's ends


@pytest.mark.parametrize("stride", [2, 3, 5, 10, 25])
def test_preview_filter_is_scipys_design_and_decimation(stride):
    """The numpy design and decimation (issue 30: ``cdgps estimate`` without importing scipy.signal)
    equal scipy.signal's firwin / kaiserord taps and upfirdn's output (bit for bit on the machine of
    the change; 1e-13 allowed for another numpy's summation order)."""
    import math

    from scipy.signal import firwin, kaiserord, upfirdn

    from cdgps_cli.analysis import preview as pv

    nyq = 1.0 / stride
    numtaps, beta = kaiserord(pv.STOPBAND_DB, (1.0 - PASSBAND_FRACTION) * nyq)
    m = max(math.ceil((numtaps - 1) / (2 * stride)), 1)
    ref = firwin(2 * m * stride + 1, (1.0 + PASSBAND_FRACTION) / 2 * nyq, window=("kaiser", beta))
    h = pv.preview_filter(stride)
    np.testing.assert_allclose(h, ref, rtol=0, atol=1e-15)
    x = np.random.default_rng(stride).normal(size=(400 + stride, 3, 2))
    half = (h.size - 1) // 2
    padded = np.concatenate([np.repeat(x[:1], half, axis=0), x, np.repeat(x[-1:], half, axis=0)])
    y = upfirdn(h, padded, up=1, down=stride, axis=0)
    want = y[2 * half // stride:][:len(range(0, x.shape[0], stride))]
    np.testing.assert_allclose(pv.anti_alias_decimate(x, stride), want, rtol=0, atol=1e-13)


def test_preview_does_not_import_scipy_signal():
    import subprocess
    import sys

    code = ("import sys, numpy as np\nfrom cdgps_cli.analysis.preview import anti_alias_decimate\n"
            "anti_alias_decimate(np.random.default_rng(0).normal(size=(500, 2)), 10)\n"
            "print('scipy.signal' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "False"
