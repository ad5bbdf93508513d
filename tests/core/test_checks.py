"""core/checks.header_position_m: a RINEX header's APPROX POSITION XYZ is used only when it is a position."""

import numpy as np
import pytest

from cdgps_cli.core.checks import header_position_m

GEONET_3040_M = [-3911641.4, 3299780.6, 3707432.8]         # about 6.37e6 m from the centre


def test_a_plausible_header_position_is_returned_as_float64():
    pos = header_position_m({"approx_position_xyz_m": GEONET_3040_M})
    assert pos.dtype == np.float64 and pos.tolist() == GEONET_3040_M


@pytest.mark.parametrize("value", [None, [0.0, 0.0, 0.0], [1e6, 1e6, 1e6], [np.nan, 1e7, 0.0], [7e6, 0.0]])
def test_missing_zero_inside_the_earth_non_finite_or_short_is_none(value):
    header = {} if value is None else {"approx_position_xyz_m": value}
    assert header_position_m(header) is None
