"""``weighting = "equal"`` (phase variance a² + b² per receiver at every elevation) on the static engine
(issue 28 item 1): GNSS ``init`` and ``baseline`` no longer fall back to the batch solver for it.

On a short simulated pair (300 s, 1 Hz) the engine's equal-weighted solution has the batch's equal-weighted
integers and fixed position within the two models' known difference (their DD rows differ by ≈ 0.04 mm RMS:
satellite positions and clocks evaluated apart; measured here 0.007 mm), and it is not the elevation-weighted
solution (0.3 mm away on these data), so the option reaches the engine's rows."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from cdgps_cli.estimation.baseline import BaselineOptions, solve_static_baseline
from cdgps_cli.io.gnss_run import read_gnss_run
from cdgps_cli.pipeline import gnss
from tests._shared import run_cli


@pytest.fixture(scope="module")
def equal_run(tmp_path_factory):
    """A simulated pair whose run config asks for equal weighting: (directory, INIT dict)."""
    d = tmp_path_factory.mktemp("equal")
    assert run_cli("-q", "simulate-gnss", "--duration", "300", "--seed", "3", "-o", d).exit_code == 0
    cfg = d / "config.toml"
    text = cfg.read_text()
    assert 'weighting = "elevation"' in text
    cfg.write_text(text.replace('weighting = "elevation"', 'weighting = "equal"'))
    for args in (("ingest", "--config", cfg, "-o", d / "run.mcap"), ("init", d / "run.mcap", "-o", d / "init.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    return d, json.loads((d / "init.json").read_text())


def _solve(d, weighting: str, engine: bool) -> dict:
    run = read_gnss_run(d / "run.mcap")
    st = gnss._stations(run)
    opt = replace(BaselineOptions.from_gnss_config(run.cfg, kinematic_series=False), weighting=weighting)
    return solve_static_baseline(st[run.master], st["rover"], run.nav, opt, engine=engine,
                                 master_xyz=gnss._position_args(run, run.master),
                                 rover_xyz=gnss._position_args(run, "rover"))


def _integers(res: dict) -> list:
    return [s["integer"] for s in res["ambiguities"]["segments"]]


def test_init_with_equal_weighting_is_solved_on_the_engine(equal_run):
    d, init = equal_run
    rov = init["rovers"]["rover"]
    assert rov["options"]["weighting"] == "equal"
    assert rov["solver"] == "static_engine"
    eng = _solve(d, "equal", engine=True)
    assert eng["solver"] == "static_engine" and eng["options"]["weighting"] == "equal"
    assert rov["fixed"]["enu_m"] == eng["fixed"]["enu_m"]            # INIT's solution is that one


def test_engine_equal_weighting_agrees_with_the_batch_and_differs_from_elevation(equal_run):
    d, _ = equal_run
    eng, batch = _solve(d, "equal", engine=True), _solve(d, "equal", engine=False)
    elev = _solve(d, "elevation", engine=True)
    assert eng["solver"] == elev["solver"] == "static_engine" and batch["solver"] == "batch (engine not asked for)"
    assert eng["solution"] == batch["solution"] == "fixed"
    assert _integers(eng) == _integers(batch)
    fixed = lambda r: np.asarray(r["fixed"]["enu_m"])          # noqa: E731
    assert np.max(np.abs(fixed(eng) - fixed(batch))) < 4e-5            # 0.007 mm measured
    np.testing.assert_allclose(eng["fixed"]["sigma_enu_m"], batch["fixed"]["sigma_enu_m"], rtol=1e-6)
    assert np.max(np.abs(fixed(eng) - fixed(elev))) > 1e-4             # 0.31 mm: the weights reached the rows
    assert np.max(np.abs(np.subtract(eng["float"]["enu_m"], elev["float"]["enu_m"]))) > 1e-3     # 6.7 mm


def test_a_bad_weighting_is_refused_by_the_engine_and_by_rtk():
    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.estimation.static_engine import _static_options
    from cdgps_cli.pipeline.gnss_multi import validate_options
    assert _static_options({"weighting": "equal"})["weighting"] == "equal"
    with pytest.raises(CdgpsError, match="weighting = 'snr'"):
        _static_options({"weighting": "snr"})
    with pytest.raises(CdgpsError, match="weighting: expected 'elevation' or 'equal', got 'snr'"):
        validate_options({"weighting": "snr"})


def test_rtk_takes_the_weighting_too(equal_run, tmp_path):
    """rtk builds its rows with the same function (dd_signals.paired_sd_rows): its library options take the
    weighting too (the command has no flag for it), and it moves the static solution."""
    from cdgps_cli.pipeline.gnss_multi import rtk_from_files
    d, _ = equal_run
    xyz = {w: np.asarray(rtk_from_files(d / "base.rnx", d / "rover.rnx", [d / "nav.rnx"], tmp_path / f"{w}.csv",
                                        options={"mode": "static", "weighting": w})["static_xyz_m"])
           for w in ("elevation", "equal")}
    assert 1e-5 < np.max(np.abs(xyz["equal"] - xyz["elevation"])) < 5e-3, xyz
