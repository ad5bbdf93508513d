"""Niell's wet mapping function (model/gps/positioning.niell_wet_mapping): its limits, its latitude table and
interpolation, against the continued fraction written out here from Niell (1996), Table 4."""

import math

import numpy as np
import pytest

from cdgps_cli.model.gps.positioning import niell_hydrostatic_mapping, niell_wet_mapping

#: Niell (1996) Table 4, wet coefficients at 15, 30, 45, 60, 75° (typed again from the paper, not imported)
TABLE = {15: (5.8021897e-4, 1.4275268e-3, 4.3472961e-2), 30: (5.6794847e-4, 1.5138625e-3, 4.6729510e-2),
         45: (5.8118019e-4, 1.4572752e-3, 4.3908931e-2), 60: (5.9727542e-4, 1.5007428e-3, 4.4626982e-2),
         75: (6.1641693e-4, 1.7599082e-3, 5.4736038e-2)}


def _marini(el_deg: float, a: float, b: float, c: float) -> float:
    """m(ε) = (1 + a/(1 + b/(1 + c))) / (sin ε + a/(sin ε + b/(sin ε + c))), one value at a time."""
    s = math.sin(math.radians(el_deg))
    return (1 + a / (1 + b / (1 + c))) / (s + a / (s + b / (s + c)))


@pytest.mark.parametrize("lat", sorted(TABLE))
def test_at_the_table_latitudes_it_is_the_continued_fraction(lat):
    for el in (3.0, 5.0, 10.0, 15.0, 30.0, 60.0, 89.0):
        got = float(niell_wet_mapping(math.radians(el), math.radians(lat)))
        assert got == pytest.approx(_marini(el, *TABLE[lat]), rel=1e-13)


def test_between_the_rows_the_coefficients_are_interpolated_and_the_hemispheres_agree():
    mid = [(p + q) / 2 for p, q in zip(TABLE[30], TABLE[45])]
    got = niell_wet_mapping(math.radians(7.0), np.radians([37.5, -37.5]))
    np.testing.assert_allclose(got, _marini(7.0, *mid), rtol=1e-13)
    # beyond the table: its end rows
    assert float(niell_wet_mapping(math.radians(7.0), math.radians(5.0))) == pytest.approx(_marini(7.0, *TABLE[15]),
                                                                                          rel=1e-13)
    assert float(niell_wet_mapping(math.radians(7.0), math.radians(-88.0))) == pytest.approx(_marini(7.0, *TABLE[75]),
                                                                                            rel=1e-13)


def test_its_limits_and_its_place_between_the_flat_earth_and_the_hydrostatic_function():
    lat = math.radians(52.0)
    assert float(niell_wet_mapping(math.pi / 2, lat)) == pytest.approx(1.0, abs=1e-15)
    assert float(niell_wet_mapping(0.0, lat)) == 0.0 and float(niell_wet_mapping(-0.1, lat)) == 0.0
    el = np.radians([5.0, 10.0, 15.0, 20.0])
    wet, hyd = niell_wet_mapping(el, lat), niell_hydrostatic_mapping(el, lat, 0.0, 180.0)
    # a curved atmosphere maps less than 1/sin ε; the wet layer, lower and thinner, more than the hydrostatic one
    assert np.all(wet < 1.0 / np.sin(el)) and np.all(wet > hyd)
    assert 10.5 < wet[0] < 11.0                        # ≈ 10.7 at 5°
    high = np.radians(np.arange(30.0, 90.0, 5.0))
    np.testing.assert_allclose(niell_wet_mapping(high, lat) * np.sin(high), 1.0, atol=2e-3)
