"""A u-blox log read twice by one command (its signals, then its ephemerides) is framed and decoded
once; a changed file is decoded again; what callers get cannot alter what the next caller gets."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.io import ubx

LOG = Path(__file__).resolve().parents[3] / "shared" / "data" / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"


@pytest.fixture
def counted(monkeypatch):
    calls = []
    real = ubx.split_stream_spans

    def split(data):
        calls.append(len(data))
        return real(data)

    monkeypatch.setattr(ubx, "split_stream_spans", split)
    ubx._LAST_DECODED.clear()
    yield calls
    ubx._LAST_DECODED.clear()


def test_signals_then_log_frame_once(tmp_path, counted):
    path = tmp_path / LOG.name
    shutil.copyfile(LOG, path)
    sig = ubx.read_ubx_signals(path, ["G:L1", "E:E1"])
    info, obs, nav = ubx.read_ubx_log(path)
    assert len(counted) == 1
    ubx._LAST_DECODED.clear()
    info2, obs2, nav2 = ubx.read_ubx_log(path)                       # from scratch: the same
    assert len(counted) == 2
    assert info == info2
    pd.testing.assert_frame_equal(obs, obs2, check_exact=True)
    pd.testing.assert_frame_equal(nav, nav2, check_exact=True)
    pd.testing.assert_frame_equal(sig, ubx.read_ubx_signals(path, ["G:L1", "E:E1"]), check_exact=True)


def test_changed_file_is_decoded_again(tmp_path, counted):
    path = tmp_path / LOG.name
    data = LOG.read_bytes()
    path.write_bytes(data)
    n1 = len(ubx.read_ubx_log(path)[1])
    path.write_bytes(data[: len(data) // 2])                            # another size: read again
    n2 = len(ubx.read_ubx_log(path)[1])
    assert len(counted) == 2 and 0 < n2 < n1


def test_callers_cannot_alter_the_memory(tmp_path, counted):
    path = tmp_path / LOG.name
    shutil.copyfile(LOG, path)
    info, _, _ = ubx.read_ubx_log(path)
    info["bad_rtcm_offsets"].append(123)
    info["message_counts"].clear()
    again, _, _ = ubx.read_ubx_log(path)
    assert again["bad_rtcm_offsets"] == [] and again["message_counts"]
    (_, off, end), _, _, _, epochs, meas, _, t = ubx._decoded_rawx(path, False)
    for a in (epochs, meas, t, off, end):
        with pytest.raises(ValueError):
            a[:1] = a[1:2]
    assert np.all(np.diff(t) > 0)


def test_the_memory_knows_the_file_not_its_name(tmp_path, counted):
    """A symlink to the log is the same file (decoded once); another file moved over the log's name with
    the same size and modification time is another file (decoded again)."""
    import os

    path = tmp_path / LOG.name
    shutil.copyfile(LOG, path)
    link = tmp_path / "link.ubx"
    link.symlink_to(path)
    n1 = len(ubx.read_ubx_log(path)[1])
    info, obs, _ = ubx.read_ubx_log(link)
    assert len(counted) == 1 and len(obs) == n1 and info["path"] == str(link)
    data = bytearray(LOG.read_bytes())
    cut = len(data) // 2
    data[cut:] = bytes(len(data) - cut)                                 # the second half zeroed: fewer epochs
    other = tmp_path / "other.ubx"
    other.write_bytes(bytes(data))
    st = path.stat()
    os.utime(other, ns=(st.st_atime_ns, st.st_mtime_ns))
    os.replace(other, path)
    n2 = len(ubx.read_ubx_log(path)[1])
    assert len(counted) == 2 and 0 < n2 < n1
