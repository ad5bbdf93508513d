"""The batch baseline (and GNSS init) fix integers with a success-rate criterion besides the ratio test
(issue 28 item 4), recorded in the result, with one default for every GNSS command."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.config.options import GNSS_DEFAULTS, MULTI_GNSS_DEFAULTS
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.baseline import BaselineOptions

G = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "rinex"


def test_one_default_for_batch_and_rtk():
    assert BaselineOptions().min_success_rate == GNSS_DEFAULTS["min_success_rate"] == MULTI_GNSS_DEFAULTS["min_success_rate"]


@pytest.mark.parametrize("value", [1.0, 1.5, -0.1, float("nan")])
def test_a_rate_outside_zero_one_is_refused(value):
    with pytest.raises(CdgpsError, match="min_success_rate must be a probability"):
        BaselineOptions(min_success_rate=value).validate()


def _baseline(tmp_path, *extra):
    if not G.exists():
        pytest.skip("../shared/data/rinex absent")
    return CliRunner().invoke(main, ["-q", "baseline", "--rinex", f"A={G / '07590920.05o'}", "--rinex",
                                     f"B={G / '30400920.05o'}", "--nav", str(G / "07590920.05n"), "--master", "B",
                                     "-o", str(tmp_path / "b.json"), *extra])


def test_geonet_records_the_success_rate_and_the_flag_is_checked(tmp_path):
    r = _baseline(tmp_path)
    assert r.exit_code == 0, r.output
    amb = json.loads((tmp_path / "b.json").read_text())["ambiguities"]
    assert amb["n_fixed"] == 6 and amb["success_rate"] > 0.999999 and amb["min_success_rate"] == 0.999
    r = _baseline(tmp_path, "--min-success-rate", "1")
    assert r.exit_code == 2 and "--min-success-rate must be a probability" in r.stderr, r.output


def test_the_gnss_run_config_carries_it_to_init():
    """One option for every GNSS command: [gnss] min_success_rate reaches the batch (init) options."""
    from cdgps_cli.config.structure import parse_gnss_config

    base = '[gnss]\nmaster = "A"\n{}\n[gnss.antennas.A]\nrinex = "a.obs"\n[gnss.antennas.B]\nrinex = "b.obs"\n'
    cfg = parse_gnss_config(base.format("min_success_rate = 0.99"))
    assert cfg.min_success_rate == 0.99 and BaselineOptions.from_gnss_config(cfg).min_success_rate == 0.99
    assert parse_gnss_config(base.format("")).min_success_rate == GNSS_DEFAULTS["min_success_rate"]
    with pytest.raises(CdgpsError, match="gnss.min_success_rate: expected a probability"):
        parse_gnss_config(base.format("min_success_rate = 1.0"))
