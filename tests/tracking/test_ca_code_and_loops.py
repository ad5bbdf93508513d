"""C/A codes against IS-GPS-200 Table 3-Ia and the Gold-code correlation property; loop filters
against the closed-form noise bandwidth (numerical integration of |H|²), GNSS-SDR's published impulse
responses (B_n = 5 Hz, T = 1 ms) and their loop types."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.tracking.ca_code import ca_code, first_chips_octal, sampled_code
from cdgps_cli.tracking.loops import A3, B3, BN_OVER_W0_3, LoopFilter, pll2_bandwidth_hz, pll2_gains

#: IS-GPS-200, Table 3-Ia: the first 10 chips of each C/A code, octal (PRN 1-32)
FIRST_10_CHIPS_OCTAL = [
    "1440", "1620", "1710", "1744", "1133", "1455", "1131", "1454", "1626", "1504", "1642", "1750", "1764",
    "1772", "1775", "1776", "1156", "1467", "1633", "1715", "1746", "1763", "1063", "1706", "1743", "1761",
    "1770", "1774", "1127", "1453", "1625", "1712"]


@pytest.mark.parametrize("prn", range(1, 33))
def test_first_ten_chips_match_the_interface_specification(prn):
    assert first_chips_octal(prn) == FIRST_10_CHIPS_OCTAL[prn - 1]


def test_gold_code_balance_and_correlation_values():
    """Each code has 512 chips of one sign and 511 of the other; every periodic auto- and
    cross-correlation value is one of −65, −1, 63 (the three-valued Gold property)."""
    allowed = {-65, -1, 63}
    codes = {p: ca_code(p).astype(np.int64) for p in (1, 2, 7, 19, 31)}
    for p, c in codes.items():
        assert sorted(np.unique(c, return_counts=True)[1].tolist()) == [511, 512]
        f = np.fft.fft(c)
        auto = np.rint(np.fft.ifft(f * np.conj(f)).real).astype(int)
        assert auto[0] == 1023 and set(auto[1:].tolist()) <= allowed
        for q, d in codes.items():
            if q > p:
                cross = np.rint(np.fft.ifft(f * np.conj(np.fft.fft(d))).real).astype(int)
                assert set(cross.tolist()) <= allowed


def test_sampled_code_and_bad_prn():
    s = sampled_code(3, 4.092e6, 8, code_phase_chips=1.0)        # 4 samples per chip
    np.testing.assert_array_equal(s, np.repeat(ca_code(3)[1:3], 4))
    with pytest.raises(CdgpsError, match="PRN 1-32"):
        ca_code(33)


@pytest.mark.parametrize("bn,zeta", [(3.0, 0.707), (15.0, 0.707), (10.0, 1.0)])
def test_second_order_noise_bandwidth_by_integration(bn, zeta):
    k1, tau1 = pll2_gains(bn, zeta)
    assert pll2_bandwidth_hz(k1, tau1) == pytest.approx(bn, rel=1e-12)
    H2 = lambda f: abs(k1 * (tau1 * 2j * math.pi * f + 1) / ((2j * math.pi * f) ** 2 + k1 * tau1 * 2j * math.pi * f + k1)) ** 2  # noqa: E731
    assert quad(H2, 0, np.inf, limit=400)[0] == pytest.approx(bn, rel=1e-6)


#: GNSS-SDR's unit test of its tracking loop filter (src/tests/unit-tests/signal-processing-blocks/tracking/
#: tracking_loop_filter_test.cc, tests FirstOrderLoop, SecondOrderLoop, ThirdOrderLoop, the filter output
#: without the NCO's integrator): B_n = 5 Hz, T = 1 ms, a unit impulse at the third update, outputs within 1e-4
GNSS_SDR_IMPULSE = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
GNSS_SDR_EXPECTED = {1: [0.0, 0.0, 20.0, 0.0, 0.0, 0.0],
                     2: [0.0, 0.0, 13.37778, 0.0889, 0.0889, 0.0889],
                     3: [0.0, 0.0, 15.31877, 0.04494, 0.04520, 0.04546]}


@pytest.mark.parametrize("order", [1, 2, 3])
def test_loop_filters_reproduce_the_gnss_sdr_test_vectors(order):
    filt = LoopFilter(5.0, 1e-3, order)
    got = [filt.update(e) for e in GNSS_SDR_IMPULSE]
    assert got == pytest.approx(GNSS_SDR_EXPECTED[order], abs=1e-4)


def test_third_order_noise_bandwidth_by_integration():
    bn = 18.0
    w0 = bn / BN_OVER_W0_3

    def H2(f):
        s = 2j * math.pi * f
        G = (B3 * w0 * s * s + A3 * w0 * w0 * s + w0**3) / s**3
        return abs(G / (1 + G)) ** 2

    assert quad(H2, 1e-9, np.inf, limit=800)[0] == pytest.approx(bn, rel=0.01)


def _closed_loop(filt, phase_in, T):
    """Phase-locked loop with an ideal discriminator (error = input − NCO phase, rad)."""
    nco, out = 0.0, []
    for p in phase_in:
        err = p - nco
        out.append(err)
        nco += filt.update(err) * T
    return np.array(out)


def test_second_order_loop_tracks_a_frequency_step_and_third_order_a_ramp():
    T = 1e-3
    t = np.arange(4000) * T
    err2 = _closed_loop(LoopFilter(15.0, T, 2), 2 * math.pi * 5.0 * t, T)             # 5 Hz step
    assert abs(err2[-500:]).max() < 1e-6                                               # type 2: no error
    ramp = 2 * math.pi * 0.5 * 20.0 * t**2                                             # 20 Hz/s
    err2r = _closed_loop(LoopFilter(15.0, T, 2), ramp, T)
    k1, _ = pll2_gains(15.0)
    assert err2r[-1] == pytest.approx(2 * math.pi * 20.0 / k1, rel=0.02)              # constant lag ω̇/ωn²
    err3 = _closed_loop(LoopFilter(18.0, T, 3), ramp, T)
    assert abs(err3[-500:]).max() < 1e-4                                               # type 3: no error


def test_loop_filter_refuses_bad_settings():
    with pytest.raises(CdgpsError, match="order"):
        LoopFilter(10.0, 1e-3, 4)
    with pytest.raises(CdgpsError, match="positive"):
        LoopFilter(-1.0, 1e-3, 2)


def test_compiled_correlator_equals_numpy():
    from cdgps_cli.tracking import correlator

    if not correlator.kernel_available():
        pytest.skip("cdgps_cli.tracking._trackcore not built")
    g = np.random.default_rng(1)
    x = g.normal(size=4000) + 1j * g.normal(size=4000)
    code = ca_code(5)
    for args in ((0.3, 1234.5, 4e6, 100.25, 1.023e6 * (1 + 1e-6), 0.25), (-7.9, -4321.0, 4e6, 1022.9, 1.023e6, 0.5)):
        got = correlator.correlate(x, code, *args)
        ref = correlator.correlate_numpy(x, code, *args)
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
