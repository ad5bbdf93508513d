"""The README's command chains run exactly as a user types them (CLI through files on disk)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
from click.testing import CliRunner

from cdgps_cli.cli import main
from cdgps_cli.run import read_run


def _cdgps(*args) -> str:
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, f"cdgps {' '.join(map(str, args))} exited {r.exit_code}: {r.output}"
    return r.output


def test_simulate_then_ingest_without_gyros(tmp_path, dof2_path, dof2_cfg, monkeypatch):
    """teague-1995-2dof has no gyros: the simulator's receiver.csv + gyro.csv ingest as they are."""
    assert not dof2_cfg.gyro_names
    monkeypatch.chdir(tmp_path)
    out = _cdgps("simulate", dof2_path, "--duration", 10, "--seed", 1, "--out", "run1")
    assert "no gyros" in out
    assert pd.read_csv("run1/gyro.csv").empty                      # the header, no rows
    out = _cdgps("ingest", "run1/receiver.csv", "run1/gyro.csv", "--config", dof2_path, "-o", "run1/run.mcap")
    assert "header only" in out
    run = read_run("run1/run.mcap")
    assert len(run.gyro) == 0 and len(run.phase) == len(pd.read_csv("run1/receiver.csv"))


def test_header_only_gyro_log_refused_when_the_config_has_gyros(tmp_path, testbed_path):
    _cdgps("simulate", testbed_path, "--duration", 2, "--seed", 1, "--out", tmp_path / "s")
    (tmp_path / "g.csv").write_text("time_s,gyro,rate_rad_s\n")
    r = CliRunner().invoke(main, ["ingest", str(tmp_path / "s/receiver.csv"), str(tmp_path / "g.csv"),
                                  "--config", str(testbed_path), "-o", str(tmp_path / "r.mcap")])
    assert r.exit_code == 2 and "no data rows" in r.output and not (tmp_path / "r.mcap").exists()
