"""`cdgps ingest` reads u-blox ESF-MEAS IMU data (issue 30 item 2): a UBX sensor log given with
--sensor-log NAME=FILE.ubx, and the IMU inside a --ubx receiver log (auto-detected); a corrupt UBX
sensor log exits 2 naming the file and byte offset, with no output written."""

import json
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.sensor_logs import read_sensor_csv, sensor_logs_from_attachments
from tests.io.test_ubx_esf import esf

ROOT = Path(__file__).resolve().parents[2]
TOWER = ROOT / "configs" / "tower-fusion.toml"
RAWX = ROOT / ".." / "shared" / "data" / "ubx" / "pygpsdata-RXMRAWX.log"
WEEK_S = 604800.0


def run_cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("esf")
    r = run_cli("-q", "simulate-gnss-structure", TOWER, "--duration", "3", "--gnss-interval", "0.1", "--seed", "1", "-o", d)
    assert r.exit_code == 0, r.output
    return d


def to_esf(acc) -> bytes:
    """The accelerometer's samples as ESF-MEAS frames (data types 16–18, 2^-10 m/s², calibTtag = GPS
    time of week in ms)."""
    out = []
    for t, *v in acc[["time_s", "accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].itertuples(index=False):
        tow_ms = int(round((t % WEEK_S) * 1000))
        out.append(esf(0, [(16 + j, int(round(x * 1024))) for j, x in enumerate(v)], calib_ms=tow_ms))
    return b"".join(out)


def test_ubx_sensor_log_attached(sim, tmp_path):
    _, acc = read_sensor_csv(sim / "accel.csv")
    acc = acc[acc["sensor"] == "acc-top"].reset_index(drop=True)
    (tmp_path / "imu.ubx").write_bytes(to_esf(acc))
    out = tmp_path / "run.mcap"
    r = run_cli("ingest", "--config", sim / "config.toml", "--sensor-log", f"mast={tmp_path / 'imu.ubx'}",
                "--sensor-log", sim / "tilt.csv", "-o", out, "--json")
    assert r.exit_code == 0, r.output
    logs = sensor_logs_from_attachments(read_mcap(out, topics=[]).attachments)
    assert set(logs) == {"accel", "tilt"}
    got = logs["accel"]
    assert set(got["sensor"]) == {"mast-accel"} and len(got) == len(acc) == 301
    np.testing.assert_allclose(got["time_s"], acc["time_s"], rtol=0, atol=1e-6)      # ms tags; the CSV carries float ulps
    for a in "xyz":
        np.testing.assert_allclose(got[f"accel_{a}_m_s2"], acc[f"accel_{a}_m_s2"], rtol=0, atol=2.0**-11 + 1e-12)


def test_corrupt_ubx_sensor_log_exit_2(sim, tmp_path):
    bad = bytearray(esf(0, [(16, 1)], calib_ms=1000) * 3)
    bad[24 + 10] ^= 0xFF
    (tmp_path / "imu.ubx").write_bytes(bytes(bad))
    out = tmp_path / "run.mcap"
    r = run_cli("ingest", "--config", sim / "config.toml", "--sensor-log", tmp_path / "imu.ubx", "-o", out)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "imu.ubx: corrupt UBX sensor log: 1 UBX frame(s) failing the checksum at byte(s) 24" in r.output
    assert not out.exists()


def test_receiver_log_imu_auto_detected(tmp_path):
    """ESF-MEAS frames inside a receiver's RXM-RAWX log (a real one, 2024-08-13 14:09:53–14:10:06
    GPST) become sensors A-accel and A-gyro of the run."""
    tow0 = 2 * 86400 + 14 * 3600 + 9 * 60 + 53                       # Tuesday 14:09:53 GPS time of week, s
    imu = b"".join(esf(0, [(16, 10), (17, 20), (18, 10035)], calib_ms=(tow0 + i) * 1000) +
                   esf(0, [(14, 4096), (13, 0), (5, -4096)], calib_ms=(tow0 + i) * 1000 + 5) for i in range(5))
    log = tmp_path / "a.ubx"
    log.write_bytes(RAWX.read_bytes() + imu)
    out = tmp_path / "run.mcap"
    r = run_cli("ingest", "--ubx", f"A={log}", "-o", out, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["receiver_imu"]["A"]["messages"] == 10 and s["receiver_imu"]["A"]["kinds"] == ["accel", "gyro"]
    logs = sensor_logs_from_attachments(read_mcap(out, topics=[]).attachments)
    assert set(logs["accel"]["sensor"]) == {"A-accel"} and set(logs["gyro"]["sensor"]) == {"A-gyro"}
    first_epoch_s = (datetime(2024, 8, 13, 14, 9, 53) - datetime(1980, 1, 6)).total_seconds()    # GPST
    np.testing.assert_array_equal(logs["accel"]["time_s"], first_epoch_s + np.arange(5))
    np.testing.assert_allclose(logs["gyro"].iloc[0, 2:].to_numpy(float), np.radians([1.0, 0.0, -1.0]))
