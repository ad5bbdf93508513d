"""A real rover whose BeiDou B2I of three satellites is flagged lost-lock at 98 % of its epochs
(tests/data/matrtklib-2018-static): `rtk` with every signal the files share fixed none of 60 epochs; without those
channels, which carry no phase, it fixes all 60.  `init` leaves them out as `rtk` does and says so."""

import json

from cdgps_cli.measurement import slips
from tests._shared import REPO_ROOT, run_cli

DATA = REPO_ROOT / "tests" / "data" / "matrtklib-2018-static"
BASE, ROVER, NAV = DATA / "base_60s.obs.gz", DATA / "rover_60s.obs.gz", DATA / "base.nav.gz"
BASE_XYZ = (-3937776.1063, 3354867.8075, 3718445.0835)
NAMED = "C:B2I C03 (98 %), C:B2I C04 (98 %), C:B2I C17 (98 %): their carrier phase is flagged lost-lock"


def _rtk(tmp_path):
    r = run_cli("rtk", "--base", BASE, "--rover", ROVER, "--nav", NAV, "--base-xyz", *BASE_XYZ, "-o", tmp_path / "x.pos",
                "--json")
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def test_rtk_leaves_the_unlocked_channels_out_and_fixes(tmp_path):
    s = _rtk(tmp_path)
    assert "C:B2I" in s["signals"] and s["fixed_epochs"] == s["epochs"] == 60
    assert any(NAMED in w for w in s["warnings"])


def test_with_them_no_epoch_fixes(tmp_path, monkeypatch):
    screen = slips.unlocked_channels
    monkeypatch.setattr(slips, "unlocked_channels", lambda c, lli, **k: screen(c, lli, share=1.0))
    s = _rtk(tmp_path)
    assert s["fixed_epochs"] == 0 and not any("lost-lock" in w for w in s["warnings"])


def test_init_leaves_them_out_and_says_so(tmp_path):
    cfg, run = tmp_path / "cfg.toml", tmp_path / "run.mcap"
    assert run_cli("-q", "config", "--rinex", f"base={BASE}", "--rinex", f"rover={ROVER}", "--nav", NAV, "--master", "base",
                   "-o", cfg).exit_code == 0
    head, tail = cfg.read_text().split('[gnss.antennas."base"]')
    tail = tail.replace("# position_ecef_m = [x, y, z]", f"position_ecef_m = [{', '.join(map(str, BASE_XYZ))}]", 1)
    cfg.write_text(head + '[gnss.antennas."base"]' + tail)
    assert run_cli("-q", "ingest", "--config", cfg, "-o", run).exit_code == 0
    r = run_cli("-q", "init", run, "-o", tmp_path / "init.json")
    assert r.exit_code == 0, r.output
    rover = json.loads((tmp_path / "init.json").read_text())["rovers"]["rover"]
    assert any(NAMED in w for w in rover["warnings"]) and rover["n_fixed"] > 0
    base = next(ln for ln in run_cli("info", run).output.splitlines() if "base_60s.obs.gz:" in ln)
    assert base.endswith("; BeiDou B1I as RINEX 3.02 names it (C1I read as C2I, L1I read as L2I, S1I read as S2I)")
