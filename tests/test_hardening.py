"""Issue 12 hardening: readers linear in their input, values what they claim to be."""

from __future__ import annotations

import time

import pytest

from cdgps_cli.errors import CdgpsError
from cdgps_cli.logs import read_receiver_log

HEADER = b"time_s,receiver,master,antenna,transmitter,phase_cycles,lock,snr_dbhz\n"
ROW = b"0.0,rx1,master,a1,PL1,0.797688,0,46.5\n"


def _ten_mb(kind: str) -> bytes:
    if kind == "cr_only":
        return (HEADER + ROW * 270_000).replace(b"\n", b"\r")
    if kind == "long_line":
        return b"x" * 10_000_000
    return b"time_s," * 1_430_000 + b"\n" + ROW      # huge header


@pytest.mark.parametrize("kind,words", [("cr_only", "CR only"), ("long_line", "longer than"), ("huge_header", "longer than")])
def test_ten_megabyte_adversarial_csv_fails_fast_and_clearly(tmp_path, testbed_cfg, kind, words):
    p = tmp_path / "receiver.csv"
    p.write_bytes(_ten_mb(kind))
    assert p.stat().st_size >= 10_000_000
    t0 = time.perf_counter()
    with pytest.raises(CdgpsError) as e:
        read_receiver_log(p, testbed_cfg)
    elapsed = time.perf_counter() - t0
    assert words in str(e.value) and "line 1" in str(e.value) and str(p) in str(e.value)
    assert len(str(e.value)) < 500
    assert elapsed < 1.0, elapsed      # was 78.6 s at 438 KB (quadratic header check)


@pytest.mark.parametrize("lock", ["1e20", "inf", "-1", "1.5"])
def test_lock_out_of_range_is_refused_with_line(tmp_path, testbed_cfg, lock):
    p = tmp_path / "receiver.csv"
    p.write_bytes(HEADER + ROW + ROW.replace(b"PL1", b"PL2").replace(b",0,", f",{lock},".encode()))
    with pytest.raises(CdgpsError, match=r"line 3: column lock: expected a non-negative integer"):
        read_receiver_log(p, testbed_cfg)


def test_crlf_log_still_reads(tmp_path, testbed_cfg):
    p = tmp_path / "receiver.csv"
    p.write_bytes((HEADER + ROW).replace(b"\n", b"\r\n"))
    assert len(read_receiver_log(p, testbed_cfg)) == 1
