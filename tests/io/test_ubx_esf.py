"""u-blox ESF-MEAS → sensor-log tables (cdgps_cli.io.ubx_esf): frames built with pyubx2 as the test
vector (scaling, units, axes, time tags in GPS s), the real ESF-MEAS log of pyubx2's tests, and bad
frames refused naming the file and byte offset."""

import math
from pathlib import Path

import numpy as np
import pytest
from pyubx2 import SET, UBXMessage

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.sensor_logs import read_sensor_log, sensor_attachments
from cdgps_cli.io.ubx_esf import WEEK_S, read_esf_log, receiver_imu_tables

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "ubx" / "pygpsdata-ESF.log"
WEEK = 2300
REF_S = WEEK * WEEK_S + 345_600.0            # a Thursday 00:00 GPS


def esf(tag_ms, data, calib_ms=None, pid=0) -> bytes:
    """One ESF-MEAS frame via pyubx2: ``data`` [(dataType, signed value)]; ``calib_ms`` the calibTtag
    (pyubx2 writes it as one more data word: its low 24 bits as dataField, the rest as dataType)."""
    kw = {"timeTag": tag_ms, "numMeas": len(data), "id": pid, "calibTtagValid": int(calib_ms is not None)}
    words = [(t, v & 0xFFFFFF) for t, v in data]
    if calib_ms is not None:
        words.append((calib_ms >> 24, calib_ms & 0xFFFFFF))
    for i, (t, f) in enumerate(words, start=1):
        kw[f"dataField_{i:02d}"], kw[f"dataType_{i:02d}"] = f, t
    return UBXMessage("ESF", "ESF-MEAS", SET, **kw).serialize()


def test_scaling_units_axes_and_time(tmp_path):
    tow = 345_600_010                     # ms: calibTtag beyond 2^24, so its high bits are used
    log = (esf(1, [(16, -1024), (17, 512), (18, 10240)], calib_ms=tow)
           + esf(2, [(14, 4096), (13, -2048), (5, 1), (12, 2825)], calib_ms=tow + 5)
           + esf(tow + 20, [(16, 1), (18, -(1 << 23))]))            # no calibTtag: the timeTag
    p = tmp_path / "imu.ubx"
    p.write_bytes(log)
    tabs, info = read_esf_log(p, REF_S, "top")
    assert info["messages"] == 3 and info["calibrated"] == 2 and info["other_types"] == {12: 1}
    acc, gyr = tabs["accel"], tabs["gyro"]
    assert list(acc.columns) == ["time_s", "sensor", "accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]
    assert list(gyr.columns) == ["time_s", "sensor", "gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]
    assert set(acc["sensor"]) == {"top-accel"} and set(gyr["sensor"]) == {"top-gyro"}
    np.testing.assert_array_equal(acc["time_s"], [REF_S + 0.010, REF_S + 0.030])
    np.testing.assert_array_equal(gyr["time_s"], [REF_S + 0.015])
    np.testing.assert_array_equal(acc.iloc[0, 2:].to_numpy(float), [-1.0, 0.5, 10.0])                  # 2^-10 m/s²
    assert acc["accel_x_m_s2"][1] == 2.0**-10 and acc["accel_z_m_s2"][1] == -8192.0 and math.isnan(acc["accel_y_m_s2"][1])
    np.testing.assert_allclose(gyr.iloc[0, 2:].to_numpy(float), np.radians([1.0, -0.5, 2.0**-12]), rtol=1e-15)  # 2^-12 °/s


def test_week_nearest_the_reference(tmp_path):
    """A tag just before the week's end, read with a reference just after the rollover, lands in the
    previous week (a record across a rollover stays in order)."""
    p = tmp_path / "imu.ubx"
    p.write_bytes(esf(0, [(16, 1)], calib_ms=604_799_900) + esf(0, [(16, 2)], calib_ms=100))
    tabs, _ = read_esf_log(p, (WEEK + 1) * WEEK_S + 5.0)
    np.testing.assert_allclose(tabs["accel"]["time_s"], [(WEEK + 1) * WEEK_S - 0.1, (WEEK + 1) * WEEK_S + 0.1])


def test_real_esf_log():
    """pyubx2's ESF-MEAS test log (a real receiver's IMU output, several captures concatenated): its
    first 16 messages are 8 accelerometer and 8 gyro samples at 10 Hz; the specific force's norm is
    g within 3 %; the file's 17th message (a gyro sample) goes back in time and is refused naming its byte offset."""
    data = REAL.read_bytes()
    head = data[:544]
    tabs, info = read_esf_log(REAL, 0.0, data=head)
    acc, gyr = tabs["accel"], tabs["gyro"]
    assert len(acc) == len(gyr) == 8 and info["other_types"] == {12: 8} and info["calibrated"] == 16
    np.testing.assert_allclose(np.diff(acc["time_s"]), 0.1, atol=0.0015)
    g = np.linalg.norm(acc.iloc[:, 2:].to_numpy(float), axis=1)
    assert np.all(np.abs(g / 9.80665 - 1) < 0.03)
    assert np.all(np.abs(gyr.iloc[:, 2:].to_numpy(float)) < 0.05)       # rad/s: at rest within sensor bias
    with pytest.raises(CdgpsError, match=r"pygpsdata-ESF.log, byte 544: ESF-MEAS of sensor imu-gyro at time tag 75227 ms is not after"):
        read_esf_log(REAL, 0.0)


@pytest.mark.parametrize("mutate,message", [
    (lambda b: b[:10] + bytes([b[10] ^ 0xFF]) + b[11:], r"failing the checksum at byte\(s\) 0"),
    (lambda b: b + b[:12], "cut by the end of the file at byte 24"),
    # a damaged sync byte: the frame is not seen as one (was: its sample silently dropped; fault campaign esf_ubx)
    (lambda b: b + bytes([b[0] ^ 0xD5]) + b[1:], r"24 byte\(s\) outside any valid frame, first at byte 24"),
])
def test_corrupt_frames_refused_with_offset(tmp_path, mutate, message):
    p = tmp_path / "bad.ubx"
    p.write_bytes(mutate(esf(0, [(16, 1)], calib_ms=1000)))
    with pytest.raises(CdgpsError, match=message) as e:
        read_esf_log(p, 0.0)
    assert str(p) in str(e.value)


def test_bad_payload_and_repeated_time_name_offset(tmp_path):
    good = esf(0, [(16, 1)], calib_ms=1000)
    # numMeas says 2 but one data word: re-frame a payload of the wrong length (checksum valid)
    payload = bytearray(good[6:-2])
    payload[4:6] = (2 << 11 | 0x8).to_bytes(2, "little")
    body = bytes([0x10, 0x02]) + len(payload).to_bytes(2, "little") + bytes(payload)
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    p = tmp_path / "bad.ubx"
    p.write_bytes(good + b"\xb5\x62" + body + bytes([a, b]))
    with pytest.raises(CdgpsError, match=r"bad.ubx, byte 24: ESF-MEAS payload of 16 bytes; numMeas = 2 and calibTtagValid = 1 make 20"):
        read_esf_log(p, 0.0)
    p.write_bytes(good + good)
    with pytest.raises(CdgpsError, match=r"bad.ubx, byte 24: .* time tag 1000 ms is not after its previous sample \(byte 0\)"):
        read_esf_log(p, 0.0)
    p.write_bytes(esf(0, [(11, 5)]))
    with pytest.raises(CdgpsError, match="without accelerometer or gyro data"):
        read_esf_log(p, 0.0)


def test_sensor_log_dispatch_and_receiver_logs(tmp_path):
    """--sensor-log NAME=FILE.ubx reads the IMU (time tags need the run's time); a receiver's UBX log
    is scanned for ESF-MEAS (none: not framed) and its IMU named after the antenna."""
    p = tmp_path / "imu.ubx"
    p.write_bytes(esf(0, [(16, 1024), (17, 0), (18, 0)], calib_ms=345_600_000))
    [(kind, df)] = read_sensor_log(f"mast={p}", REF_S)
    assert kind == "accel" and list(df["sensor"]) == ["mast-accel"] and df["accel_x_m_s2"][0] == 1.0
    with pytest.raises(CdgpsError, match="needs the GNSS run's time"):
        read_sensor_log(p)
    att = sensor_attachments([p], REF_S)
    assert list(att) == ["sensors/accel.csv"] and b"imu-accel" in att["sensors/accel.csv"]
    other = tmp_path / "rx.ubx"
    other.write_bytes(b"\xb5\x62\x01\x07" + bytes(100))
    tables, info = receiver_imu_tables({"top": [p], "base": [other]}, REF_S)
    assert [(k, list(d["sensor"])) for _, k, d in tables] == [("accel", ["top-accel"])] and list(info) == ["top"]
