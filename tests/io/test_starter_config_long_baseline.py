"""``cdgps config`` on a pair at or beyond ``gnss.iono_threshold_km`` apart warns that ``init`` and ``baseline`` will
refuse the baseline (it wrote a config whose own comment said to run init, which then exited 2).  The positions are
where init places the antennas: a rover header more than a kilometre off its single-point position is not believed
(a review found the first version warning of a rover whose header alone was 12 km off, which init then solved)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests._shared import run_cli

MASTER = np.array([-3959400.631, 3385704.533, 3667523.111])


def _pair(tmp_path, offset_m):
    d = tmp_path / "sim"
    rover = ",".join(f"{v:.3f}" for v in MASTER + np.asarray(offset_m))
    master = ",".join(f"{v:.3f}" for v in MASTER)
    r = run_cli("-q", "simulate-gnss", "--duration", "30", "--seed", "2", "--master-xyz", master, "--rover-xyz", rover,
                "-o", d)
    assert r.exit_code == 0, r.output
    return d


def _config(tmp_path, d, rover_file=None):
    r = run_cli("-q", "config", "--rinex", f"base={d / 'base.rnx'}", "--rinex", f"rover={rover_file or d / 'rover.rnx'}",
                "--nav", d / "nav.rnx", "--master", "base", "-o", tmp_path / "c.toml", "--json")
    assert r.exit_code == 0, r.output
    return [w for w in json.loads(r.stdout)["warnings"] if "refuse this baseline" in w]


def test_config_says_init_refuses_a_long_baseline(tmp_path):
    d = _pair(tmp_path, (9000.0, -7000.0, 2000.0))                       # 11.6 km
    said = _config(tmp_path, d)
    assert len(said) == 1 and said[0].startswith("rover: 11.6 km from base") and said[0] in (tmp_path / "c.toml").read_text()


def test_a_short_baseline_or_a_rover_header_alone_far_says_nothing(tmp_path):
    d = _pair(tmp_path, (3000.0, 1000.0, 500.0))                         # 3.2 km
    assert _config(tmp_path, d) == []
    lines = (d / "rover.rnx").read_text().splitlines(keepends=True)      # the rover's header 12 km off: init uses its
    i = next(k for k, ln in enumerate(lines) if ln[60:].strip() == "APPROX POSITION XYZ")   # single-point position
    x, y, z = (float(v) for v in lines[i][:42].split())
    lines[i] = f"{x + 12_000.0:14.4f}{y:14.4f}{z:14.4f}".ljust(60) + "APPROX POSITION XYZ\n"
    moved = tmp_path / "rover_header_off.rnx"
    moved.write_text("".join(lines))
    assert _config(tmp_path, d, moved) == []


def test_config_says_a_navigation_file_of_another_day(tmp_path):
    """A navigation file whose ephemerides cover none of the observations (another day) was taken by ``config`` with
    nothing said, where ``ingest`` and ``rtk`` refuse it; now a warning names both spans."""
    from tests._shared import REPO_ROOT
    other = REPO_ROOT.parent / "shared" / "data" / "rinex" / "30400920.05n"
    if not other.exists():
        pytest.skip("../shared/data/rinex absent")
    d = _pair(tmp_path, (3000.0, 1000.0, 500.0))
    assert not [w for w in _warnings(tmp_path, d, d / "nav.rnx") if "cover none of the observations" in w]
    said = [w for w in _warnings(tmp_path, d, other) if "cover none of the observations" in w]
    assert len(said) == 1 and said[0].startswith(f"{other}: its ephemerides (toe 2005-") and "(2024-01-01" in said[0]


def _warnings(tmp_path, d, nav) -> list:
    r = run_cli("-q", "config", "--rinex", f"base={d / 'base.rnx'}", "--rinex", f"rover={d / 'rover.rnx'}", "--nav", nav,
                "--master", "base", "-o", tmp_path / "n.toml", "--json")
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)["warnings"]
