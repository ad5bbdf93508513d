"""``simulate-gnss-structure`` refuses a receiver interval (or duration) that leaves fewer than 2 epochs."""

from __future__ import annotations

from pathlib import Path

import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.sim.structure import check_receiver_epochs
from tests._shared import run_cli

ROOT = Path(__file__).resolve().parents[2]


def test_epoch_count_and_its_bounds():
    assert check_receiver_epochs(20.0, 0.1) == 201
    assert check_receiver_epochs(20.0, 0.1, 0.1) == 201
    assert check_receiver_epochs(20.0, 0.1, 1.0) == 21
    assert check_receiver_epochs(20.0, 0.1, 20.0) == 2            # the first and the last epoch
    with pytest.raises(CdgpsError, match=r"--gnss-interval 20.1 s: leaves 1 receiver epoch\(s\) in --duration 20 s"):
        check_receiver_epochs(20.0, 0.1, 20.1)
    with pytest.raises(CdgpsError, match=r"--duration 0.04 s at the config's sample_period_s 0.1 s: leaves 1"):
        check_receiver_epochs(0.04, 0.1)


def test_cli_refuses_an_interval_longer_than_the_duration(tmp_path):
    out = tmp_path / "sim"
    r = run_cli("-q", "simulate-gnss-structure", ROOT / "configs" / "gnss-tower.toml", "--duration", "20",
                "--gnss-interval", "1e9", "-o", out)
    assert r.exit_code == 2, r.output
    assert "--gnss-interval 1e+09 s: leaves 1 receiver epoch(s)" in r.output and "Traceback" not in r.output
    assert not out.exists()
