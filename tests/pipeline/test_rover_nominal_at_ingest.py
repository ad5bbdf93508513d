"""A rover with no position (a u-blox log; a RINEX header without APPROX POSITION XYZ, no config position): each
window's `init` placed it at that window's own pseudorange single-point position, so the displacement states of the
windows of one run referred to points metres apart (a sweep of the real M8P pair's 5-minute windows: E/N/U jumping by
a metre between windows of a static antenna; `cdgps batch` sessions the same).  `ingest` now places it once, at the
single-point position of its record's first epochs, and every window refers to that point.

Checks: the nominal of every window's INIT and of the whole record's is the RUN's, bit for bit; the static solutions
of the windows then agree within centimetres in E/N/U (as their absolute positions always did); the hour-by-hour
and the whole-file ingest record the same point (the RUNs byte-identical); a run ingested from the same files with
the position given keeps it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.config.structure import load_gnss_config
from cdgps_cli.io import gnss_archive, gnss_hours
from cdgps_cli.io.gnss_run import INGEST_SPP_SOURCE, read_gnss_run
from cdgps_cli.pipeline import gnss_ingest
from tests._shared import run_cli


def _without_header_position(path) -> None:
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(ln for ln in lines if "APPROX POSITION XYZ" not in ln))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("nominal")
    r = run_cli("-q", "simulate-gnss", "--duration", "600", "--seed", "6", "-o", d)
    assert r.exit_code == 0, r.output
    _without_header_position(d / "rover.rnx")
    r = run_cli("ingest", "--config", d / "config.toml", "-o", d / "run.mcap")
    assert r.exit_code == 0, r.output
    assert "the pseudorange single-point position of its first epochs" in r.output and "is its nominal position" in r.output
    return d


def test_every_window_and_the_whole_record_refer_to_the_runs_point(run):
    rx = read_gnss_run(run / "run.mcap").receivers["rover"]
    assert rx.info["position_source"] == INGEST_SPP_SOURCE
    nominal = np.asarray(rx.info["position_ecef_m"])
    truth = json.loads((run / "truth.json").read_text())
    off = np.linalg.norm(nominal - np.asarray(truth["rover_mean_ecef_m"]))
    assert 0.0 < off < 30.0                                                # a single-point position: metres
    enu = {}
    for start, dur in ((0, 300), (300, 300), (None, None)):
        out = run / f"init_{start}.json"
        args = ["init", run / "run.mcap", "-o", out] + ([] if start is None else ["--start", start, "--duration", dur])
        r = run_cli("-q", *args)
        assert r.exit_code == 0, r.output
        rov = json.loads(out.read_text())["rovers"]["rover"]
        assert np.array_equal(np.asarray(rov["nominal_ecef_m"]), nominal)            # bit for bit, every window
        assert rov["nominal_source"] == INGEST_SPP_SOURCE
        enu[start] = np.asarray(rov["fixed"]["enu_m"])
    assert np.abs(enu[0] - enu[300]).max() < 0.01 and np.abs(enu[0] - enu[None]).max() < 0.01


def test_the_hour_by_hour_and_the_whole_file_ingest_place_it_alike(run, tmp_path, monkeypatch):
    monkeypatch.setattr(gnss_archive, "OBS_BLOCK_S", 60.0)                 # many blocks: the first epochs span two
    cfg = load_gnss_config(run / "config.toml")
    said = []
    gnss_ingest.ingest_gnss(cfg, tmp_path / "hours.mcap", progress=said.append)
    assert any("hour by hour" in m for m in said)
    monkeypatch.setattr(gnss_hours, "hourly_inputs", lambda *a, **k: None)
    gnss_ingest.ingest_gnss(cfg, tmp_path / "whole.mcap")
    assert (tmp_path / "hours.mcap").read_bytes() == (tmp_path / "whole.mcap").read_bytes()


def test_a_given_position_is_kept(run, tmp_path):
    text = (run / "config.toml").read_text().replace(
        '[gnss.antennas."rover"]', '[gnss.antennas."rover"]\nposition_ecef_m = [-3976219.0, 3382372.0, 3652513.0]')
    cfg = tmp_path / "c.toml"
    cfg.write_text(text.replace('rinex = "', f'rinex = "{run}/').replace('nav = ["', f'nav = ["{run}/'))
    r = run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output
    rx = read_gnss_run(tmp_path / "run.mcap").receivers["rover"]
    assert rx.info["position_source"] == "config position_ecef_m"
    assert rx.info["position_ecef_m"] == [-3976219.0, 3382372.0, 3652513.0]


def test_when_the_first_epochs_place_nothing_the_windows_are_said_to_differ(run, tmp_path, monkeypatch):
    """No single-point position from the first epochs (a cold-start log: too few satellites with an ephemeris): the
    windows then each place the rover themselves, metres apart (a review), and the warning says so and how to fix it
    (position_ecef_m); the RUN holds no position for it."""
    from cdgps_cli.core.errors import CdgpsError

    def none(*a, **k):
        raise CdgpsError("no solution")

    monkeypatch.setattr(gnss_ingest, "_raw_single_point", none)
    s = gnss_ingest.ingest_gnss(load_gnss_config(run / "config.toml"), tmp_path / "run.mcap")
    (w,) = [x for x in s["warnings"] if x.startswith("rover: no nominal position")]
    assert "windows of this run" in w and "refer to points metres apart" in w and "position_ecef_m" in w
    assert read_gnss_run(tmp_path / "run.mcap").receivers["rover"].info["position_source"] is None
