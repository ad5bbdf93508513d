"""Fixtures shared by the report tests."""

import pytest

from _report_pipeline import pipeline
from cdgps_cli.sim.structure import SimOptions


@pytest.fixture(scope="session")
def testbed_free_run(tmp_path_factory):
    """300 s free vibration of the lumped testbed, seed 7 (states over the whole record: the 60 s INIT
    window, the filter after it), shared by the spectrum-report and run-report tests; read only."""
    return pipeline(tmp_path_factory.mktemp("free"), SimOptions(duration_s=300, seed=7))
