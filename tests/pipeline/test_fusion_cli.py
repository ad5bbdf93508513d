"""GNSS + sensors end to end through the commands (issue 30): simulate-gnss-structure writes the sensor
logs, ingest attaches them to the RUN, estimate --structure --fuse fuses them with the carrier-phase
double differences (100 Hz accelerometers, 10 Hz GNSS), spectra says what was fused."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.sensor_logs import read_sensor_csv, sensor_logs_from_attachments
from cdgps_cli.io.states import States

ROOT = Path(__file__).resolve().parents[2]
TOWER = ROOT / "configs" / "tower-fusion.toml"


def run_cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def fused(tmp_path_factory):
    d = tmp_path_factory.mktemp("fusion")
    steps = (("simulate-gnss-structure", TOWER, "--duration", "20", "--gnss-interval", "0.1", "--seed", "2", "-o", d),
             ("ingest", "--config", d / "config.toml", "-o", d / "run.mcap"),
             ("init", d / "run.mcap", "-o", d / "init.json"),
             ("estimate", d / "run.mcap", "--init", d / "init.json", "--structure", TOWER, "--smooth", "-o", d / "gnss.mcap"),
             ("estimate", d / "run.mcap", "--init", d / "init.json", "--structure", TOWER, "--smooth", "--fuse", "accel,gyro",
              "--hold-out", "acc-mid", "-o", d / "fused.mcap"))
    for args in steps:
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    return d


def test_simulated_logs_and_run_attachments(fused):
    kind, acc = read_sensor_csv(fused / "accel.csv")
    assert kind == "accel" and set(acc["sensor"]) == {"acc-top", "acc-mid"} and (acc["sensor"] == "acc-top").sum() == 2001
    tj = json.loads((fused / "truth.json").read_text())
    assert tj["interval_s"] == 0.1 and tj["structure_interval_s"] == 0.01 and "acc-top" in tj["sensors"]
    logs = sensor_logs_from_attachments(read_mcap(fused / "run.mcap", topics=[]).attachments)
    assert set(logs) == {"accel", "tilt", "gyro"} and np.allclose(logs["accel"]["accel_x_m_s2"], acc["accel_x_m_s2"])


def test_run_sensor_logs_read_alone_equal_those_of_all_attachments(fused):
    """``estimate --fuse`` reads the logs after the GNSS set-up, only the sensors/ attachments (issue 29)."""
    from cdgps_cli.io.sensor_logs import read_run_sensor_logs

    ref = sensor_logs_from_attachments(read_mcap(fused / "run.mcap", topics=[]).attachments)
    got = read_run_sensor_logs(fused / "run.mcap")
    assert sorted(got) == sorted(ref) and all(got[k].equals(ref[k]) for k in ref)


def test_fused_states_and_summary(fused):
    g, f = States(fused / "gnss.mcap"), States(fused / "fused.mcap")
    assert g.time_s.size == 201 and f.time_s.size == 2001
    opts = json.loads(f.metadata["options"])["fusion"]
    assert opts["fused"] == ["accel", "gyro"] and opts["hold_out"] == ["acc-mid"] and not opts["gyro_independent_check"]
    assert set(opts["sensors"]) == {"acc-top", "gyro-top"}
    ev = {}
    for name in ("gnss", "fused"):
        r = run_cli("evaluate", "--truth", fused, "--estimate", fused / f"{name}.mcap", "--json")
        assert r.exit_code == 0, r.output
        ev[name] = json.loads(r.stdout)
    assert ev["fused"]["rms_error"]["q4"] < 0.5 * ev["gnss"]["rms_error"]["q4"]        # the 5 Hz mode
    assert 0.5 < ev["fused"]["nees"]["mean"] / ev["fused"]["nees"]["dof"] < 2.0


def test_spectra_says_the_gyro_is_fused(fused):
    r = run_cli("spectra", fused / "fused.mcap", "-o", fused / "sp")
    assert r.exit_code == 0, r.output
    assert "no longer an independent check" in r.output
    assert json.loads((fused / "sp" / "peaks.json").read_text())["fusion"]["gyros_independent_check"] is False


@pytest.mark.parametrize("args,message", [
    (("--fuse", "accel,wind"), "--fuse accel,wind: unknown sensor kind(s) wind"),
    (("--fuse", "accel", "--hold-out", "nope"), "--hold-out: nope is not a sensor"),
    (("--hold-out", "acc-top"), "--hold-out needs --fuse"),
])
def test_bad_fuse_options(fused, tmp_path, args, message):
    out = tmp_path / "x.mcap"
    r = run_cli("estimate", fused / "run.mcap", "--init", fused / "init.json", "--structure", TOWER, *args, "-o", out)
    assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output, r.output
    assert not out.exists()


def test_bad_sensor_log_refused_at_ingest(fused, tmp_path):
    bad = tmp_path / "accel.csv"
    bad.write_text("time_s,sensor,accel_x_m_s2\n1388102400.0,acc-top,0.1\n1388102400.0,acc-top,oops\n")
    out = tmp_path / "run.mcap"
    r = run_cli("ingest", "--config", fused / "config.toml", "--sensor-log", bad, "-o", out)
    assert r.exit_code == 2 and "line 3: column accel_x_m_s2" in r.output, r.output
    assert not out.exists()
    bad.write_text("time_s,sensor,accel_x_m_s2,speed_m_s\n1,a,0.1,2\n")
    r = run_cli("ingest", "--config", fused / "config.toml", "--sensor-log", bad, "-o", out)
    assert r.exit_code == 2 and "speed_m_s" in r.output and not out.exists()
