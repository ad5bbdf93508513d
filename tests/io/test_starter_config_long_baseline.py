"""``cdgps config`` on a pair whose header positions lie at or beyond ``gnss.iono_threshold_km`` apart warns that
``init`` will refuse the baseline (it wrote a config whose own comment said to run init, which then exited 2)."""

from __future__ import annotations

import json

import pytest

from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def _rover_at(tmp_path, dx_m: float):
    lines = (MOSAIC / "rover.obs").read_text().splitlines(keepends=True)
    i = next(k for k, ln in enumerate(lines) if ln[60:].strip() == "APPROX POSITION XYZ")
    x, y, z = (float(v) for v in lines[i][:42].split())
    lines[i] = f"{x + dx_m:14.4f}{y:14.4f}{z:14.4f}".ljust(60) + "APPROX POSITION XYZ\n"
    p = tmp_path / f"rover_{int(dx_m)}.obs"
    p.write_text("".join(lines))
    return p


@pytest.mark.parametrize("dx_m, said", [(12_000.0, True), (5_000.0, False)])
def test_config_says_init_refuses_a_long_baseline(tmp_path, dx_m, said):
    r = run_cli("-q", "config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={_rover_at(tmp_path, dx_m)}",
                "--nav", MOSAIC / "base.nav", "--master", "base", "--signals", "G:L1", "-o", tmp_path / "c.toml", "--json")
    assert r.exit_code == 0, r.output
    warned = [w for w in json.loads(r.stdout)["warnings"] if "'cdgps init' refuses this baseline" in w]
    assert len(warned) == int(said), warned
    if said:
        assert warned[0].startswith("rover: 12.0 km from base (their header positions)") and warned[0] in (tmp_path / "c.toml").read_text()
