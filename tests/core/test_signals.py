"""Signal table of core/signals.py: frequencies from the ICDs, wavelengths c/f, GLONASS FDMA."""

import pytest

from cdgps_cli.core.signals import SIGNALS, wavelength_m


def test_frequencies_and_wavelengths():
    assert SIGNALS["G:L1"].frequency_hz == 1575.42e6
    assert SIGNALS["G:L2"].frequency_hz == 1227.60e6
    assert SIGNALS["E:E5a"].frequency_hz == 1176.45e6
    assert SIGNALS["E:E5b"].frequency_hz == 1207.14e6
    assert abs(SIGNALS["C:B1I"].frequency_hz - 1561.098e6) < 1
    assert abs(wavelength_m("G:L1") - 0.190293673) < 1e-9
    assert abs(wavelength_m("R:G1", -7) - 299792458.0 / (1602e6 - 7 * 0.5625e6)) < 1e-12


def test_glonass_needs_frequency_number():
    with pytest.raises(ValueError, match="frequency number"):
        wavelength_m("R:G2")
    with pytest.raises(ValueError, match="unknown signal"):
        wavelength_m("G:L9")
