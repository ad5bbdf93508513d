"""Fuzz: receiver files — RINEX observation and navigation (rinex.py), u-blox UBX (ubx.py).

Property: any mutation of a real receiver file (tests/data, shipped with the repository) gives
parsed tables or a CdgpsError naming the file; the file is never modified.  For UBX, whose frames
carry a checksum, a byte flipped inside an RXM-RAWX frame is never silent: either an error or the
same result with the bad frame counted (``bad_checksum_frames`` / ``undecodable_frames``), and with
``strict=True`` always an error.
"""

from __future__ import annotations

import functools

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
from cdgps_cli.io.ubx import read_ubx_rawx

from fuzz_support import DATA, byte_mutation, check_reader, fuzz_settings, scratch

OBS = ["demo.10o", "demo3.10o", "14601736.18o", "P433_lli_subset.crx"]
NAV = ["14601736.18n", "brdc1820_subset.10n"]
UBX = DATA / "pygpsdata-RXMRAWX.log"


def _data(name: str) -> bytes:
    p = DATA / name
    if not p.exists():
        pytest.skip(f"{p} not present")
    raw = p.read_bytes()
    return raw[:60_000]                  # a large file: its header and first epochs are enough


@st.composite
def line_mutation(draw, data: bytes):
    """A text file with one line replaced, duplicated or removed, or one fixed-width field blanked."""
    lines = data.splitlines(keepends=True)
    i = draw(st.integers(0, len(lines) - 1))
    kind = draw(st.sampled_from(["drop", "dup", "blank-field", "garbage"]))
    if kind == "drop":
        new = []
    elif kind == "dup":
        new = [lines[i], lines[i]]
    elif kind == "blank-field":
        a = draw(st.integers(0, 79))
        b = draw(st.integers(a, 80))
        ln = bytearray(lines[i])
        ln[a:b] = b" " * len(ln[a:b])
        new = [bytes(ln)]
    else:
        new = [draw(st.binary(max_size=90)) + b"\n"]
    return kind, b"".join(lines[:i] + new + lines[i + 1:])


def _mutations(data: bytes):
    return st.one_of(byte_mutation(data), line_mutation(data))


@pytest.mark.parametrize("name", OBS)
@fuzz_settings(12)
@given(data=st.data())
def test_rinex_obs(name, data):
    _, raw = data.draw(_mutations(_data(name)))
    with scratch() as d:
        f = d / name
        f.write_bytes(raw)
        res = check_reader(lambda: read_rinex_obs(f), f)
        if res is not None:
            header, obs = res
            assert isinstance(header, dict) and isinstance(obs, pd.DataFrame)


@pytest.mark.parametrize("name", NAV)
@fuzz_settings(12)
@given(data=st.data())
def test_rinex_nav(name, data):
    _, raw = data.draw(_mutations(_data(name)))
    with scratch() as d:
        f = d / name
        f.write_bytes(raw)
        res = check_reader(lambda: read_rinex_nav(f), f)
        if res is not None:
            assert isinstance(res, pd.DataFrame)


@fuzz_settings(15)
@given(data=st.data())
def test_ubx_any_mutation(data):
    _, raw = data.draw(byte_mutation(_data(UBX.name)))
    with scratch() as d:
        f = d / "rx.ubx"
        f.write_bytes(raw)
        check_reader(lambda: read_ubx_rawx(f), f)


def _rawx_frames(raw: bytes) -> list[tuple[int, int]]:
    """(start, end) byte offsets of the RXM-RAWX frames (class 0x02, id 0x15) of a clean log."""
    out, k = [], 0
    while (k := raw.find(b"\xb5\x62\x02\x15", k)) >= 0:
        n = int.from_bytes(raw[k + 4:k + 6], "little")
        out.append((k, k + 6 + n + 2))
        k += 6 + n + 2
    return out


@functools.cache
def _clean_ubx():
    with scratch() as d:
        (d / "clean.ubx").write_bytes(_data(UBX.name))
        return read_ubx_rawx(d / "clean.ubx")


@fuzz_settings(12)
@given(data=st.data())
def test_ubx_flip_inside_a_rawx_frame_is_never_silent(data):
    raw = _data(UBX.name)
    frames = _rawx_frames(raw)
    assert frames, "no RXM-RAWX frame in the test log"
    start, end = data.draw(st.sampled_from(frames))
    i = data.draw(st.integers(start + 2, end - 1))          # class, id, length, payload or checksum
    x = data.draw(st.integers(1, 255))
    b = bytearray(raw)
    b[i] ^= x
    with scratch() as d:
        bad = d / "bad.ubx"
        bad.write_bytes(bytes(b))
        info0, obs0 = _clean_ubx()
        with pytest.raises(CdgpsError, match="bad.ubx"):
            read_ubx_rawx(bad, strict=True)
        res = check_reader(lambda: read_ubx_rawx(bad), bad)
        if res is None:
            return
        info, obs = res
        reported = info["bad_checksum_frames"] + info["undecodable_frames"] + (info["truncated_tail_bytes"] > 0)
        assert reported > 0, f"flip at {i} ^ {x:#04x} in the frame at {start} not reported: {info}"
        assert info["n_epochs"] < info0["n_epochs"] or obs.equals(obs0)
        assert np.all(np.isin(obs["time_gps_s"].to_numpy(), obs0["time_gps_s"].to_numpy()))
