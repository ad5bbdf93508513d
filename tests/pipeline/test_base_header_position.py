"""A base (master) whose header position is far from where its own pseudoranges put it is refused, naming the file.

The real Trimble NetR9 RINEX 3.02 base of tests/data/matrtklib-2018-static writes an APPROX POSITION 207 km from its
published position.  Before, `rtk` solved every rover against it (exit 0) and its warning blamed the rover's header;
`init` refused the pair as a 207 km baseline and suggested raising gnss.iono_threshold_km.
"""

import json

import pytest

from tests._shared import REPO_ROOT, run_cli

DATA = REPO_ROOT / "tests" / "data" / "matrtklib-2018-static"
BASE, ROVER, NAV = DATA / "base_60s.obs.gz", DATA / "rover_60s.obs.gz", DATA / "base.nav.gz"
BASE_XYZ = (-3937776.1063, 3354867.8075, 3718445.0835)


def test_rtk_refuses_the_base_header_and_takes_the_given_position(tmp_path):
    out = tmp_path / "x.pos"
    r = run_cli("rtk", "--base", BASE, "--rover", ROVER, "--nav", NAV, "--signals", "G:L1", "-o", out)
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert "base_60s.obs.gz (base): its header position (APPROX POSITION XYZ) is 206.8 km from its single-point" in r.output
    assert "--base-xyz" in r.output and not out.exists()
    r = run_cli("-q", "rtk", "--base", BASE, "--rover", ROVER, "--nav", NAV, "--signals", "G:L1", "--base-xyz", *BASE_XYZ,
                "-o", out)
    assert r.exit_code == 0, r.output


def test_init_refuses_the_master_header_and_takes_the_configs_position(tmp_path):
    cfg, run = tmp_path / "cfg.toml", tmp_path / "run.mcap"
    r = run_cli("-q", "config", "--rinex", f"base={BASE}", "--rinex", f"rover={ROVER}", "--nav", NAV, "--master", "base",
                "--signals", "G:L1,C:B1I", "-o", cfg)
    assert r.exit_code == 0, r.output
    assert run_cli("-q", "ingest", "--config", cfg, "-o", run).exit_code == 0
    r = run_cli("init", run, "-o", tmp_path / "init.json")
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert "the master's header position (APPROX POSITION XYZ) is 206.8 km" in r.output
    assert 'position_ecef_m in the config\'s [gnss.antennas."base"]' in r.output and "iono_threshold_km" not in r.output
    text = cfg.read_text()
    head, tail = text.split('[gnss.antennas."base"]')
    tail = tail.replace("# position_ecef_m = [x, y, z]", f"position_ecef_m = [{', '.join(map(str, BASE_XYZ))}]", 1)
    cfg.write_text(head + '[gnss.antennas."base"]' + tail)
    run2 = tmp_path / "run2.mcap"
    assert run_cli("-q", "ingest", "--config", cfg, "-o", run2).exit_code == 0
    r = run_cli("-q", "init", run2, "-o", tmp_path / "init2.json")
    assert r.exit_code == 0, r.output
    init = json.loads((tmp_path / "init2.json").read_text())
    assert init["rovers"]["rover"]["baseline_length_m"] == pytest.approx(6.8, abs=0.1)


def test_config_warns_of_the_master_header_and_says_nothing_of_a_good_one(tmp_path):
    cfg = tmp_path / "cfg.toml"
    r = run_cli("-q", "config", "--rinex", f"base={BASE}", "--rinex", f"rover={ROVER}", "--nav", NAV, "--master", "base",
                "--json", "-o", cfg)
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    [w] = [w for w in summary["warnings"] if "the master" in w]
    assert "206.8 km from its pseudorange single-point position" in w and 'position_ecef_m in [gnss.antennas."base"]' in w
    assert "#     base position: CHECK IT" in cfg.read_text()
    # the rover as master: its header is where its data are (6.8 m from the base) -> no warning, no comment
    r = run_cli("-q", "config", "--rinex", f"base={BASE}", "--rinex", f"rover={ROVER}", "--nav", NAV, "--master", "rover",
                "--json", "-o", cfg)
    assert r.exit_code == 0, r.output
    assert not [w for w in json.loads(r.stdout)["warnings"] if "the master" in w] and "CHECK IT" not in cfg.read_text()
    # without navigation files no single-point position can be made: nothing is said
    r = run_cli("-q", "config", "--rinex", f"base={BASE}", "--rinex", f"rover={ROVER}", "--master", "base", "--json",
                "-o", cfg)
    assert r.exit_code == 0, r.output
    assert not [w for w in json.loads(r.stdout)["warnings"] if "the master" in w]


def test_config_warns_of_a_header_thousands_of_km_off(tmp_path):
    """A master header with X's sign flipped (≈ 8,000 km off): the single-point fit seeded there keeps too few
    satellites above the mask, and is made again from the Earth's centre instead of staying silent."""
    sim = tmp_path / "sim"
    assert run_cli("-q", "simulate-gnss", "--duration", "60", "--seed", "1", "-o", sim).exit_code == 0
    lines = (sim / "base.rnx").read_text().splitlines(keepends=True)
    i = next(k for k, ln in enumerate(lines) if "APPROX POSITION XYZ" in ln)
    x = float(lines[i][:14])
    lines[i] = f"{-x:14.4f}" + lines[i][14:]
    (sim / "base.rnx").write_text("".join(lines))
    cfg = tmp_path / "c.toml"
    r = run_cli("-q", "config", "--rinex", f"base={sim / 'base.rnx'}", "--rinex", f"rover={sim / 'rover.rnx'}",
                "--nav", sim / "nav.rnx", "--master", "base", "--json", "-o", cfg)
    assert r.exit_code == 0, r.output
    [w] = [w for w in json.loads(r.stdout)["warnings"] if "the master" in w]
    assert " km from its pseudorange single-point position" in w and "CHECK IT" in cfg.read_text()


@pytest.mark.parametrize("how", ["no line", "zeros"])
def test_config_says_a_master_without_a_position_needs_one(tmp_path, how):
    """A master whose header has no APPROX POSITION XYZ line, or convbin's 0 0 0: `config` wrote the config and said
    nothing (exit 0), and only `ingest` refused it (a sweep of real files, session 30); it now warns, naming the file
    and position_ecef_m, and marks the master's comment."""
    import gzip

    lines = gzip.decompress(BASE.read_bytes()).decode().splitlines(keepends=True)
    k = next(i for i, ln in enumerate(lines) if ln[60:].strip() == "APPROX POSITION XYZ")
    if how == "no line":
        del lines[k]
    else:
        lines[k] = f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}{'':18}APPROX POSITION XYZ\n"
    base = tmp_path / "base.obs"
    base.write_text("".join(lines))
    cfg = tmp_path / "cfg.toml"
    r = run_cli("-q", "config", "--rinex", f"base={base}", "--rinex", f"rover={ROVER}", "--nav", NAV, "--master", "base",
                "--signals", "G:L1", "-o", cfg, "--json")
    assert r.exit_code == 0, r.output
    warn = json.loads(r.stdout)["warnings"]
    assert any(w.startswith(f"{base}: master base has no position") and "position_ecef_m" in w for w in warn), warn
    assert "base position: NONE" in cfg.read_text()
