"""The acquisition's constant-false-alarm detector: its threshold against the analytic K = 1 case and a
Monte-Carlo of Gamma cells, its false-alarm rate on noise alone, and a weak (38 dB-Hz) signal found."""

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.tracking.acquisition import acquire, detection_threshold

from _track_signals import ca_signal


def test_threshold_of_one_block_is_the_exponential_quantile():
    # one block: cells/mean are exponential, P(max of N > γ) ≈ N e^{−γ} → γ = ln(N / P_fa)
    assert detection_threshold(1, 1000, 1e-3) == pytest.approx(math.log(1000 / 1e-3), rel=1e-9)


def test_threshold_against_a_monte_carlo_of_gamma_cells():
    rng = np.random.default_rng(0)
    k, cells, pfa = 5, 1000, 0.1
    g = detection_threshold(k, cells, pfa)
    mx = np.max(rng.gamma(k, 1.0 / k, size=(3000, cells)), axis=1)
    assert np.mean(mx > g) == pytest.approx(1 - (1 - pfa / cells) ** cells, abs=0.02)


def test_false_alarm_rate_on_noise_alone():
    rng = np.random.default_rng(5)
    fs, n = 2.2e6, 0
    for _ in range(3):
        x = rng.standard_normal(2 * int(fs * 5e-3)).view(np.complex128)
        n += sum(a.acquired for a in acquire(x, fs, range(1, 33), noncoherent_ms=5, false_alarm=0.2))
    assert 5 <= n <= 35            # 96 searches at 0.2: 19 ± 4 expected (the union bound: at most)
    x = rng.standard_normal(2 * int(fs * 10e-3)).view(np.complex128)
    assert not any(a.acquired for a in acquire(x, fs, range(1, 33)))


def test_a_38_dbhz_signal_is_found():
    x, _ = ca_signal(19, -2710.0, 612.3, 38.0, 0.011, seed=4, fs=2.2e6)
    a = acquire(x, 2.2e6, [19, 20])
    assert a[0].acquired and abs(a[0].doppler_hz + 2710.0) < 30.0
    assert abs((a[0].code_phase_chips - 612.3 + 511.5) % 1023 - 511.5) < 1.0
    assert not a[1].acquired and a[1].peak_to_noise < a[1].threshold < a[0].peak_to_noise


def test_false_alarm_must_be_a_probability():
    with pytest.raises(CdgpsError, match="false_alarm"):
        detection_threshold(10, 100, 1.5)


IQ_FILE = Path(__file__).resolve().parents[3] / "shared" / "data" / "if" / "L1_20211202_084700_4MHz_IQ.bin"


@pytest.mark.skipif(not IQ_FILE.exists(), reason="../shared/data/if not present")
def test_the_real_file_read_in_a_wrong_format_finds_no_satellite_and_names_the_peaks(tmp_path):
    r = CliRunner().invoke(main, ["-q", "track", str(IQ_FILE), "--format", "int16-iq", "--fs", "4000000",
                                  "-o", str(tmp_path / "t.mcap")])
    assert r.exit_code == 2 and "no satellite acquired" in r.output and "strongest peaks: PRN" in r.output
    assert "× noise (threshold" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "t.mcap").exists()


def test_a_weak_peak_beside_a_strong_satellite_is_taken_for_its_cross_correlation():
    from cdgps_cli.tracking.acquisition import reject_cross_correlation

    # PRN slots: strong at bin 20; 12 dB below in the next bin (rejected); 6 dB below in the same bin
    # (kept: a real weak satellite); 12 dB below two bins away (kept); a non-detection stays one
    bins = [20, 21, 20, 22, 20]
    pnr = [52.0, 4.3, 13.8, 4.3, 3.0]
    assert reject_cross_correlation(bins, pnr, [True, True, True, True, False]) == [True, False, True, True, False]
