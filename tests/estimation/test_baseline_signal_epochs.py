"""The batch's signal rows are taken at every common epoch, not only where the first signal (GPS L1) has a
satellite with a phase and an ephemeris (a real F9P pair, whose GPS ephemerides begin 34 min into the record, lost
its first 40 of 964 epochs in ``init`` — and the static engine, which kept them, could then not serve: "segment
C19:B1I … is no arc of the engine").

The real mosaic pair with the rover's GPS L1 phases blanked for its first minute (codes kept), GPS L1 + Galileo
E1: every one of its 301 epochs is used (Galileo carries the first minute), the static engine serves, and the
fixed position is within 1 mm of the unedited pair's."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data absent")


def _blank_gps_l1_phase(text: str, epochs: int, types=("L1C",)) -> str:
    """The RINEX 3 text with these observables (L1C: the phase) of every GPS satellite blank in its first
    ``epochs`` epochs."""
    lines = text.splitlines()
    head = next(ln for ln in lines if ln.startswith("G") and "SYS / # / OBS TYPES" in ln)
    cols = [head[7:60].split().index(t) for t in types]
    n = 0
    for i, ln in enumerate(lines):
        if ln.startswith(">"):
            n += 1
        elif 0 < n <= epochs and ln.startswith("G"):
            for k in cols:
                a, b = 3 + 16 * k, 3 + 16 * (k + 1)
                ln = ln[:a].ljust(a) + " " * 16 + ln[b:]
            lines[i] = ln
    return "\n".join(lines) + "\n"


def _init(d: Path, rover: Path, signals: str = '"G:L1", "E:E1"') -> dict:
    (d / "run.toml").write_text("\n".join([
        "[gnss]", 'master = "base"', f'nav = ["{MOSAIC / "base.nav"}"]', f'signals = [{signals}]',
        '[gnss.antennas."base"]', f'rinex = "{MOSAIC / "base.obs"}"', '[gnss.antennas."rover"]',
        f'rinex = "{rover}"']) + "\n")
    for args in (("ingest", "--config", d / "run.toml", "-o", d / "run.mcap"),
                 ("init", d / "run.mcap", "-o", d / "init.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    return json.loads((d / "init.json").read_text())["rovers"]["rover"]


def test_epochs_without_the_first_signal_are_used(tmp_path):
    for sub in ("plain", "blank"):
        (tmp_path / sub).mkdir()
    plain = _init(tmp_path / "plain", MOSAIC / "rover.obs")
    edited = tmp_path / "rover_blank.obs"
    edited.write_text(_blank_gps_l1_phase((MOSAIC / "rover.obs").read_text(), 60))
    blank = _init(tmp_path / "blank", edited)
    assert plain["epochs"]["n_epochs_used"] == 301
    assert blank["epochs"]["n_epochs_used"] == 301, blank["epochs"]["n_epochs_used"]       # was 241
    assert blank["solver"] == "static_engine", blank["solver"]
    assert blank["solution"] == "fixed"
    dx = [a - b for a, b in zip(blank["fixed"]["enu_m"], plain["fixed"]["enu_m"])]
    assert max(abs(v) for v in dx) < 1e-3, dx


def _rename_gps(text: str, epochs: int, names: dict) -> str:
    """The RINEX 3 text with the GPS satellites of its first ``epochs`` epochs renamed (``names``: old → new)."""
    lines = text.splitlines()
    n = 0
    for i, ln in enumerate(lines):
        if ln.startswith(">"):
            n += 1
        elif 0 < n <= epochs and ln[:3] in names:
            lines[i] = names[ln[:3]] + ln[3:]
    return "\n".join(lines) + "\n"


def test_epochs_whose_clock_is_not_measured_are_left_out(tmp_path):
    """GPS L1 + GLONASS G1 with the rover's GPS satellites renamed for a minute to numbers without an ephemeris:
    no code with an ephemeris gives its clock there (GLONASS codes do not serve it), so the GLONASS rows of that
    minute are not used — with the clock interpolated they were (the review found 6.8 µs of clock error in such a
    minute on this pair; metres on a receiver whose clock drifts or jumps) — and a warning counts the epochs."""
    gps = ["G05", "G07", "G11", "G13", "G14", "G15", "G18", "G20", "G22", "G24", "G29", "G30"]
    spare = ["G01", "G02", "G03", "G04", "G08", "G09", "G10", "G12", "G16", "G17", "G19", "G21"]   # no ephemeris
    edited = tmp_path / "rover_renamed.obs"
    edited.write_text(_rename_gps((MOSAIC / "rover.obs").read_text(), 60, dict(zip(gps, spare))))
    (tmp_path / "run").mkdir()
    rov = _init(tmp_path / "run", edited, '"G:L1", "R:G1"')
    assert rov["epochs"]["n_epochs_used"] == 241, rov["epochs"]["n_epochs_used"]
    assert any("rover: 60 epoch(s) without a code from a satellite with an ephemeris" in w for w in rov["warnings"]), \
        rov["warnings"]
