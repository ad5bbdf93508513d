"""Sensor CSV logs (io/sensor_logs.py): kinds from the column names, refusals that name file, line and
column, canonical attachments."""

import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.sensor_logs import read_sensor_csv, sensor_attachments, sensor_logs_from_attachments


def _write(path, text):
    path.write_text(text)
    return path


def test_kinds_and_round_trip(tmp_path):
    a = _write(tmp_path / "a.csv", "time_s,sensor,accel_x_m_s2,accel_z_m_s2\n10.0,s1,0.5,\n10.01,s1,0.25,1e-3\n")
    g = _write(tmp_path / "g.csv", "time_s,gyro,gyro_y_rad_s\n10.0,g1,0.001\n")          # the structure simulator's column
    s = _write(tmp_path / "s.csv", "time_s,sensor,strain_x_1\n10.0,st,1e-6\n")           # any kind with a known unit
    assert read_sensor_csv(a)[0] == "accel" and read_sensor_csv(g)[0] == "gyro" and read_sensor_csv(s)[0] == "strain"
    att = sensor_attachments([a, g])
    assert sorted(att) == ["sensors/accel.csv", "sensors/gyro.csv"]
    assert att == sensor_attachments([a, g])                                             # deterministic bytes
    logs = sensor_logs_from_attachments(att)
    assert list(logs["accel"].columns) == ["time_s", "sensor", "accel_x_m_s2", "accel_z_m_s2"]
    assert pd.isna(logs["accel"]["accel_z_m_s2"][0]) and logs["accel"]["time_s"][1] == 10.01


@pytest.mark.parametrize("text,message", [
    ("time_s,sensor,accel_x_m_s2\n1,a,x\n", "line 2: column accel_x_m_s2"),
    ("time_s,sensor,accel_x_m_s2,tilt_y_rad\n1,a,1,2\n", "one sensor kind"),
    ("time_s,sensor,accel_x_mps2\n1,a,1\n", "accel_x_mps2"),
    ("sensor,time_s,accel_x_m_s2\na,1,1\n", "first columns must be time_s, sensor"),
    ("time_s,sensor,accel_x_m_s2\n1,a,1\n1,a,2\n", "line 3: sensor a: time_s must increase"),
    ("time_s,sensor,accel_x_m_s2\nnan,a,1\n", "line 2: time_s"),
])
def test_refusals_name_the_place(tmp_path, text, message):
    p = _write(tmp_path / "bad.csv", text)
    with pytest.raises(CdgpsError, match="bad.csv") as e:
        read_sensor_csv(p)
    assert message in str(e.value)


def test_one_sensor_in_two_files_is_refused(tmp_path):
    a = _write(tmp_path / "a.csv", "time_s,sensor,accel_x_m_s2\n1,s1,0.5\n")
    b = _write(tmp_path / "b.csv", "time_s,sensor,accel_x_m_s2\n2,s1,0.5\n")
    with pytest.raises(CdgpsError, match="sensor s1 is also in"):
        sensor_attachments([a, b])


def _text_reading(data: bytes):
    """The reading before issue 29's numeric one: every cell as text, then numbers (the reference)."""
    import io

    from cdgps_cli.io.sensor_logs import _check_table

    return _check_table(pd.read_csv(io.BytesIO(data), dtype=str, keep_default_na=False, na_values=[""]), "ref")


@pytest.mark.parametrize("text,fast", [
    ("time_s,sensor,accel_x_m_s2,accel_z_m_s2\n10.000000001,s1,0.1,\n10.01,s2,,1e-3\n10.02,s1,-3.3e-7,2\n", True),
    ("time_s,gyro,gyro_y_rad_s\n10.0,g1,0.001\n10.1,g1,0.30000000000000004\n", True),
    ("time_s,sensor,tilt_x_rad\n10.0,1,nan\n", False),          # the word nan: the text reading decides (refused)
    ("time_s,sensor,tilt_x_rad\n10.0,a,x\n", False),            # not a number: the text reading names the cell
])
def test_numeric_reading_equals_the_text_reading(text, fast):
    """Sensor logs are parsed straight to floats (issue 29: memory and time of a long fused run); the
    tables are equal to the text reading's, value for value, and anything unusual goes the old way."""
    from cdgps_cli.io.sensor_logs import _numeric_table

    data = text.encode()
    assert (_numeric_table(data) is not None) == fast
    try:
        ref = _text_reading(data)
    except CdgpsError as exc:
        with pytest.raises(CdgpsError, match="finite number"):
            sensor_logs_from_attachments({"sensors/x.csv": data})
        assert "finite number" in str(exc)
        return
    kind, got = next(iter(sensor_logs_from_attachments({"sensors/x.csv": data}).items()))
    assert kind == ref[0] and list(got.columns) == list(ref[1].columns)
    for c in got.columns:
        a, b = got[c].to_numpy(), ref[1][c].to_numpy()
        assert a.dtype == b.dtype and (list(a) == list(b) if a.dtype == object else
                                       (a.tobytes() == b.tobytes()))
