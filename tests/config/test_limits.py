"""cdgps_cli.config.limits: one home for a range that the options, the configs and the libraries share."""

from __future__ import annotations

import pytest

from cdgps_cli.config.limits import MASK_DEG, OPTION_BOUNDS, Bound, check_option
from cdgps_cli.config.schema import gnss_json_schema
from cdgps_cli.core.errors import CdgpsError


def test_a_bound_open_at_its_top_refuses_its_top_and_says_so():
    b = Bound(0.0, 90.0, "deg", hi_open=True)
    assert b.contains(0.0) and b.contains(89.999) and not b.contains(90.0) and not b.contains(-1e-9)
    assert b.text() == "[0, 90) deg"
    assert Bound(0.0, 1.0, lo_open=True).text() == "(0, 1]"


@pytest.mark.parametrize("mask", [-5.0, 90.0, 95.0])
def test_the_elevation_mask_has_one_range_everywhere(mask):
    """The --mask-deg option, the GNSS config's schema, the baseline options and the rtk options refuse
    the same masks, with the same range in their words."""
    from cdgps_cli.estimation.baseline import BaselineOptions
    from cdgps_cli.pipeline.gnss_multi import validate_options

    assert OPTION_BOUNDS["mask_deg"] is MASK_DEG
    with pytest.raises(CdgpsError, match=r"\[0, 90\) deg"):
        check_option("mask_deg", "--mask-deg", mask)
    prop = gnss_json_schema()["properties"]["gnss"]["properties"]["mask_deg"]
    assert prop["minimum"] == MASK_DEG.lo and prop["exclusiveMaximum"] == MASK_DEG.hi
    with pytest.raises(CdgpsError, match=r"mask_deg must be in \[0, 90\) deg"):
        BaselineOptions(mask_deg=mask).validate()
    with pytest.raises(CdgpsError, match=r"mask_deg: expected a value in \[0, 90\) deg"):
        validate_options({"mask_deg": mask})


def test_a_mask_of_zero_is_accepted_everywhere():
    from cdgps_cli.estimation.baseline import BaselineOptions

    check_option("mask_deg", "--mask-deg", 0.0)
    BaselineOptions(mask_deg=0.0).validate()
