"""The one reader of a simulator's truth folder (truth.json + truth.csv), shared by the run report,
the control report, evaluate and the IF-sample simulator."""

from __future__ import annotations

import lzma
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.sim_truth import check_truth_config, read_truth_folder, require_columns, truth_coordinates
from cdgps_cli.report.control import INTERNAL_ANGLES, RIGID_ANGLE, read_simulation
from cdgps_cli.report.run_scan import read_truth
from cdgps_cli.sim.if_samples import read_structure_truth
from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    cfg = load_config(ROOT / "configs" / "testbed-1998.toml")
    d = tmp_path_factory.mktemp("sim")
    write_simulation(simulate(cfg, SimOptions(duration_s=3.0, seed=5)), d)
    states = SimpleNamespace(config_sha256=cfg.sha256, config_name=cfg.name, path="STATES.mcap",
                             coordinate_model=lambda: cfg, coord_names=cfg.coord_names)
    return cfg, d, states


def _xz_only(src: Path, dst: Path) -> Path:
    dst.mkdir()
    shutil.copy(src / "truth.json", dst / "truth.json")
    (dst / "truth.csv.xz").write_bytes(lzma.compress((src / "truth.csv").read_bytes()))
    return dst


def test_both_reports_read_the_same_truth(sim, tmp_path):
    """The run report and the control report give the same coordinates from one folder, and both
    read a folder whose table is compressed (as evaluate always did: one reader)."""
    cfg, d, states = sim
    for folder in (d, _xz_only(d, tmp_path / "xz")):
        run = read_truth(folder, states)
        ctl = read_simulation(folder, "open")
        assert np.array_equal(run["us"], np.rint(ctl["q"]["time_s"].to_numpy() * 1e6).astype(np.int64))
        for name in (RIGID_ANGLE, *INTERNAL_ANGLES):
            k = cfg.coord_names.index(name)
            assert np.array_equal(run["q"][:, k], ctl["q"][name].to_numpy())
        t, q = read_structure_truth(folder, cfg)
        assert np.array_equal(q, run["q"]) and np.array_equal(np.rint(t * 1e6), run["us"])
    assert Path(read_simulation(tmp_path / "xz", "open")["files"][1]).name == "truth.csv.xz"


def test_unreadable_folder_names_option_and_folder(tmp_path):
    with pytest.raises(CdgpsError, match=r"--closed .*nowhere: not a `cdgps simulate` folder"):
        read_truth_folder(tmp_path / "nowhere", "--closed")
    (tmp_path / "truth.json").write_text("[1, 2]")
    (tmp_path / "truth.csv").write_text("time_s\n0\n")
    with pytest.raises(CdgpsError, match=r"truth.json: expected a JSON object"):
        read_truth_folder(tmp_path, "--truth")


def test_another_config_and_missing_columns_are_refused(sim, tmp_path):
    cfg, d, states = sim
    truth = read_truth_folder(d, "--truth")
    check_truth_config(truth, cfg.sha256, cfg.name, "S.mcap")            # its own config: accepted
    with pytest.raises(CdgpsError, match=r"--truth .*simulated with config 'testbed-1998'.*S.mcap estimates config 'x'"):
        check_truth_config(truth, "0" * 64, "x", "S.mcap")
    with pytest.raises(CdgpsError, match=r"truth.csv: missing column\(s\) nope, zz"):
        require_columns(truth.table, ["time_s", "nope", "zz"], truth.csv_path)
    cut = tmp_path / "cut"
    cut.mkdir()
    shutil.copy(d / "truth.json", cut / "truth.json")
    (cut / "truth.csv").write_text("time_s,q1_m\n0.0,0.0\n")
    with pytest.raises(CdgpsError, match=r"cut/truth.csv: missing column\(s\) q2_rad, q3_rad"):
        truth_coordinates(read_truth_folder(cut), cfg)
