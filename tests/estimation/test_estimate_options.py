"""EstimateOptions are checked by the library before any work, each field named (issue 32)."""

from __future__ import annotations

import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.filter import EstimateOptions, estimate


@pytest.mark.parametrize("value", [1.5, 1.0, 0.5, 0.2, float("nan"), -1.0])
def test_nis_probability_outside_half_to_one_is_refused(value):
    """1.5 gave a NaN chi-square bound, so every NIS test passed silently."""
    with pytest.raises(CdgpsError, match="EstimateOptions.nis_probability"):
        estimate(None, {}, EstimateOptions(nis_probability=value))


def test_the_default_is_accepted_by_the_check():
    from cdgps_cli.estimation.filter import _check_options

    _check_options(EstimateOptions())
