"""The compiled tracking loop (cdgps_cli.tracking._trackcore.track) against its numpy reference, and the
channel run in pieces against one run (the loop state carries everything)."""

import numpy as np
import pytest
from _shared import kernel
from _track_signals import ca_signal

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.tracking import correlator
from cdgps_cli.tracking.channel import OUT_FIELDS, TrackOptions, initial_state, run_updates

FS = 2.5e6
needs_kernel = pytest.mark.skipif(not correlator.kernel_available(), reason="cdgps_cli.tracking._trackcore not built")


def _run(x, opt, aid=None, pieces=1):
    st = initial_state(-1500.0, 300.4)
    n = int(FS * 1e-3)
    m = x.size // n
    cuts = np.linspace(0, m, pieces + 1).astype(int)
    parts = [run_updates(x[a * n:b * n], FS, 13, st, opt, None if aid is None else aid[a:b])
             for a, b in zip(cuts[:-1], cuts[1:])]
    return np.vstack(parts), st


@needs_kernel
@pytest.mark.parametrize("opt", [
    TrackOptions(pll_bn_hz=5.0, pull_in_s=0.02, wide_pll_s=0.03),               # FLL, wide PLL, then narrow
    TrackOptions(pll_bn_hz=18.0, pll_order=3, pull_in_s=0.03, spacing_chips=0.3),
])
def test_kernel_equals_numpy_over_every_output(opt):
    x, _ = ca_signal(13, -1490.0, 300.0, 44.0, 0.12, seed=2, doppler_rate_hz_s=30.0, fs=FS)
    aid = 20.0 * np.sin(np.arange(120) * 0.05)
    with kernel(True):
        got, st_k = _run(x, opt, aid)
    with kernel(False):
        ref, st_n = _run(x, opt, aid)
    assert got.shape == (120, len(OUT_FIELDS))
    scale = np.maximum(np.abs(ref).max(axis=0), 1.0)
    np.testing.assert_allclose(got / scale, ref / scale, rtol=0, atol=1e-9)
    np.testing.assert_allclose(st_k, st_n, rtol=1e-9, atol=1e-9)
    assert got[:, OUT_FIELDS.index("pll")].sum() == 120 - round(opt.pull_in_s * 1e3)


@pytest.mark.parametrize("use_kernel", [True, False])
def test_tracking_in_pieces_equals_one_run(use_kernel):
    if use_kernel and not correlator.kernel_available():
        pytest.skip("cdgps_cli.tracking._trackcore not built")
    x, _ = ca_signal(13, -1500.0, 300.4, 45.0, 0.06, seed=4, fs=FS)
    opt = TrackOptions(pll_bn_hz=10.0, pull_in_s=0.01, wide_pll_s=0.01)
    with kernel(use_kernel):
        one, st1 = _run(x, opt)
        three, st3 = _run(x, opt, pieces=3)
    np.testing.assert_array_equal(one, three)
    np.testing.assert_array_equal(st1, st3)
    np.testing.assert_allclose(np.diff(one[:, 0]), 1e-3, rtol=1e-12)


def test_run_updates_refuses_bad_state_aid_and_order():
    x = np.zeros(int(FS * 0.005), dtype=complex)
    with pytest.raises(CdgpsError, match="aid_doppler_hz: expected one value per 1 ms update \\(5\\)"):
        run_updates(x, FS, 1, initial_state(0.0, 0.0), aid_doppler_hz=np.zeros(4))
    with pytest.raises(CdgpsError, match="state: expected a float64 vector"):
        run_updates(x, FS, 1, np.zeros(3))
    with pytest.raises(CdgpsError, match="pll_order"):
        run_updates(x, FS, 1, initial_state(0.0, 0.0), TrackOptions(pll_order=1))
