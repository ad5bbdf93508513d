"""A multi-GNSS receiver's summary in ``ingest`` and ``info`` counts its configured signals too (found by session
23's data hunt: a real F9P with 28 satellites of four systems was summed up as "12 satellites", its GPS L1 ones):
``signal_satellites`` per system and ``signal_phase_rows`` in the RUN's receiver summary, printed after the GPS L1
counts; a GPS-L1-only run has neither."""

from __future__ import annotations

import json

import pytest

from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def test_info_counts_every_signal_of_a_multi_gnss_receiver(tmp_path):
    for args in (("config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={MOSAIC / 'rover.obs'}",
                  "--nav", MOSAIC / "base.nav", "--master", "base", "-o", tmp_path / "cfg.toml"),
                 ("ingest", "--config", tmp_path / "cfg.toml", "-o", tmp_path / "run.mcap")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, r.output
    r = run_cli("info", tmp_path / "run.mcap", "--json")
    assert r.exit_code == 0, r.output
    info = json.loads(r.stdout)
    receivers = info["gnss"]["receivers"]
    for rx in receivers:
        per = rx["signal_satellites"]
        assert set(per) == {"C", "E", "G", "R"} and per["G"] <= rx["satellites"], per
        assert rx["signal_phase_rows"] > rx["phase_rows"]
    text = run_cli("info", tmp_path / "run.mcap").output
    total = sum(receivers[0]["signal_satellites"].values())
    assert f"phases (GPS L1); all signals: {total} satellites (C " in text

