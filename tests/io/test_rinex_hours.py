"""`io/rinex_hours`: a RINEX 3 observation file cut into blocks of GPS time by bisection on its epoch lines.

The independent check is a plain scan: every epoch line's offset and time, grouped by block number.  The blocks
found by bisection are that grouping, byte for byte, for blocks of many sizes (receiver clock offsets putting tags
just before and after the edges); the files the cut must leave to the whole reading are refused (None)."""

import gzip
import math

import pytest

from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.io.rinex_hours import join_obs_headers, rinex_hours
from tests._shared import run_cli


@pytest.fixture(scope="module")
def rover(tmp_path_factory):
    d = tmp_path_factory.mktemp("cut")
    assert run_cli("-q", "simulate-gnss", "--duration", "900", "--rate-hz", "1", "--seed", "6", "--raw-tags",
                   "--clock-offset-ms", "0.4,-0.7", "-o", d).exit_code == 0
    return d / "rover.rnx"


def _scan(path, block_s: float) -> list:
    """(block number, first byte, end byte, first epoch's GPS s) of each block, by reading every epoch line."""
    data = path.read_bytes()
    body = data.index(b"\n", data.index(b"END OF HEADER")) + 1
    starts, times = [], []
    at = body
    for line in data[body:].split(b"\n"):
        if line.startswith(b">"):
            f = line[2:29].split()
            starts.append(at)
            times.append(gps_seconds(int(f[0]), int(f[1]), int(f[2]), int(f[3]), int(f[4]), float(f[5])))
        at += len(line) + 1
    out = []
    for i, (a, t) in enumerate(zip(starts, times)):
        k = math.floor(t / block_s)
        if not out or out[-1][0] != k:
            out.append([k, a, None, t])
    for j in range(len(out)):
        out[j][2] = out[j + 1][1] if j + 1 < len(out) else len(data)
    return [tuple(b) for b in out]


@pytest.mark.parametrize("block_s", [1.0, 7.0, 60.0, 61.0, 300.0, 3600.0])
def test_blocks_are_the_plain_scans(rover, block_s):
    h = rinex_hours(rover, block_s)
    assert h is not None
    assert h.blocks == _scan(rover, block_s)
    assert h.first_s == h.blocks[0][3] and h.last_s >= h.blocks[-1][3]
    whole = rover.read_bytes()
    head = whole[:whole.index(b"\n", whole.index(b"END OF HEADER")) + 1]
    assert b"".join(h.block_bytes(j)[0][len(head):] for j in range(len(h.blocks))) == whole[len(head):]


def test_block_headers_join_to_the_files(rover):
    from cdgps_cli.io.rinex import read_rinex_obs  # noqa: PLC0415

    h = rinex_hours(rover, 61.0)
    infos = [read_rinex_obs(rover, read=h.block_bytes(j))[0] for j in range(len(h.blocks))]
    assert join_obs_headers(infos) == read_rinex_obs(rover)[0]


def _edited(tmp_path, rover, name, edit) -> object:
    p = tmp_path / name
    p.write_bytes(edit(rover.read_bytes()))
    return p


def test_what_is_left_to_the_whole_reading(tmp_path, rover):
    assert rinex_hours(_edited(tmp_path, rover, "z.rnx.gz", lambda b: gzip.compress(b, mtime=0)), 60.0) is None
    assert rinex_hours(_edited(tmp_path, rover, "cut.rnx", lambda b: b[:-30]), 60.0) is None      # no final line end
    glo = rover.read_text().replace("GPS         TIME OF FIRST OBS", "GLO         TIME OF FIRST OBS")
    assert "GLO         TIME OF FIRST OBS" in glo
    assert rinex_hours(_edited(tmp_path, rover, "glo.rnx", lambda b: glo.encode()), 60.0) is None
    v2 = b"     2.11           OBSERVATION DATA    G (GPS)             RINEX VERSION / TYPE\n" + b"x" * 300 + b"\n"
    assert rinex_hours(_edited(tmp_path, rover, "v2.rnx", lambda b: v2), 60.0) is None
    assert rinex_hours(tmp_path / "missing.rnx", 60.0) is None


def test_a_file_of_one_epoch(tmp_path, rover):
    text = rover.read_text()
    at = text.index("\n", text.index("END OF HEADER")) + 1
    one = text[:at] + ">" + text[at:].split(">")[1]
    h = rinex_hours(_edited(tmp_path, rover, "one.rnx", lambda b: one.encode()), 3600.0)
    assert h is not None and len(h.blocks) == 1 and h.first_s == h.last_s


def test_a_first_epoch_years_early_costs_one_bisection_per_block(tmp_path, rover, monkeypatch):
    """A first epoch tagged years before the others (a receiver's wrong year): the blocks are the plain scan's, found
    with one bisection per block that holds an epoch — not one per block of the years between (≈ 2.6 M of a
    minute: minutes of bisection before)."""
    from cdgps_cli.io import rinex_hours as rh  # noqa: PLC0415

    text = rover.read_text()
    at = text.index("\n", text.index("END OF HEADER")) + 1
    line = text[at:text.index("\n", at)]
    early = text[:at] + line.replace(line[2:6], str(int(line[2:6]) - 5), 1) + text[at + len(line):]
    p = _edited(tmp_path, rover, "early.rnx", lambda b: early.encode())
    calls = []
    real = rh._first_epoch_from
    monkeypatch.setattr(rh, "_first_epoch_from", lambda *a: calls.append(a[1]) or real(*a))
    h = rinex_hours(p, 60.0)
    assert h.blocks == _scan(p, 60.0) and len(calls) == len(h.blocks) - 1
