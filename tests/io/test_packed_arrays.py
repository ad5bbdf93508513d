"""Packed arrays (cdgps_cli/io/packed_arrays.py): lossless round trip, determinism, compression,
and damaged bytes refused with the array named."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from cdgps_cli.io.packed_arrays import MAGIC, pack, pack_pieces, unpack


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Same shape and the same bytes (NaN payloads included)."""
    a = np.asarray(a, dtype=a.dtype.newbyteorder("<"))
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("arr", [
    np.random.default_rng(0).normal(size=(257, 3, 3)),
    np.arange(7, dtype=np.int64),
    np.array(3.25),
    np.zeros((0, 4)),
    np.zeros((3, 0)),
    np.array([True, False, True]),
    np.array([np.nan, -0.0, np.inf, 1e-310], dtype=">f8"),          # big-endian in, little-endian out
    np.random.default_rng(1).normal(size=(9, 2)).astype(np.float32),
    np.array([[1, -2], [3, 2**31 - 1]], dtype=np.int32),
    np.asfortranarray(np.random.default_rng(2).normal(size=(5, 4))),  # any memory layout
    np.random.default_rng(3).normal(size=(6, 8))[:, ::2],
])
def test_round_trip_is_bit_exact(arr):
    assert _same(arr, unpack(pack(arr)))
    assert b"".join(pack_pieces(arr)) == pack(arr)


def test_nan_payload_bits_survive():
    bits = np.array([0x7FF8000000000001, 0xFFF800000000BEEF], dtype=np.uint64)
    back = unpack(pack(bits.view(np.float64)))
    assert back.view(np.uint64).tolist() == bits.tolist()


def test_deterministic_and_compact_on_slow_series():
    t = np.round(np.arange(36_001) * 0.1, 9)                          # an hour of 10 Hz epochs
    assert pack(t) == pack(t.copy())
    assert len(pack(t)) < 0.02 * t.nbytes
    noise = np.random.default_rng(4).normal(size=10_000)               # noise stays about its size
    assert 0.7 * noise.nbytes < len(pack(noise)) < 1.01 * noise.nbytes


def test_refuses_what_it_cannot_hold():
    with pytest.raises(ValueError, match="bool, integer or float"):
        pack(np.array(["a", "b"]))
    with pytest.raises(ValueError, match="bool, integer or float"):
        pack(np.array([1 + 2j]))


def _header(data: bytes) -> tuple[dict, int]:
    (n,) = struct.unpack("<I", data[8:12])
    return json.loads(data[12:12 + n]), 12 + n


@pytest.mark.parametrize("damage, message", [
    (lambda d: b"NOTPACKD" + d[8:], "not a packed array"),
    (lambda d: d[:10], "not a packed array"),
    (lambda d: d[:8] + struct.pack("<I", 2**31) + d[12:], "header length"),
    (lambda d: d[:12] + b"[" + d[13:], "damaged header"),
    (lambda d: d[:-5], "damaged content|bytes of content"),
    (lambda d: d[:-3] + bytes(3), "damaged content|bytes of content"),
])
def test_damaged_bytes_are_a_named_error(damage, message):
    data = pack(np.random.default_rng(5).normal(size=(100, 3)))
    with pytest.raises(ValueError, match=message) as exc:
        unpack(damage(data), "STATES.mcap: attachment arrays/cdgps/state/xi")
    assert str(exc.value).startswith("STATES.mcap: attachment arrays/cdgps/state/xi:")


def test_header_and_content_must_agree():
    data = pack(np.zeros((10, 3)))
    head, end = _header(data)
    for bad in ({**head, "shape": [10, 4]}, {**head, "dtype": "<U4"}, {**head, "filter": "none"},
                {**head, "shape": [-1, 3]}):
        h = json.dumps(bad).encode()
        with pytest.raises(ValueError):
            unpack(MAGIC + struct.pack("<I", len(h)) + h + data[end:], "x")


@pytest.mark.parametrize("delta", [1, 2])
@pytest.mark.parametrize("arr", [
    np.random.default_rng(6).normal(size=(257, 3, 3)),
    np.array([np.nan, -0.0, np.inf, -np.inf, 1e-310, -1e308, 1e308, 0.0], dtype=">f8"),
    np.array([[0, 2**63 - 1], [-2**63, -1], [5, 7]], dtype=np.int64),           # wrap-around differences
    np.array([0, 2**64 - 1, 1, 2**63], dtype=np.uint64),
    np.random.default_rng(7).normal(size=(9, 2)).astype(np.float32),
    np.array([[1, -2], [3, 2**31 - 1]], dtype=np.int32),
    np.array([255, 0, 7], dtype=np.uint8),
    np.zeros((0, 4)), np.array(3.25), np.zeros((1, 3)),
])
def test_delta_round_trip_is_bit_exact(arr, delta):
    data = pack(arr, delta)
    assert _same(arr, unpack(data))
    assert _header(data)[0]["delta"] == delta
    assert b"".join(pack_pieces(arr, delta)) == data == pack(arr.copy(), delta)   # deterministic


def test_delta_zero_is_the_earlier_format():
    """No ``delta`` key when 0: the bytes of files written before the option."""
    a = np.random.default_rng(8).normal(size=(20, 3))
    assert pack(a, 0) == pack(a) and "delta" not in _header(pack(a))[0]


def test_delta_compacts_smooth_series_and_costs_little_on_noise():
    """Smooth series (a drift and a slow oscillation: the low mantissa bits follow the curve) shrink
    under differences; noise-like bits (a filter's covariance is close to that: docs/benchmarks/io.md)
    cost at most a few per cent more."""
    k = np.arange(20_000)[:, None]
    ramp = 1e-6 * (1.0 + 1e-4 * k + 0.0 * np.arange(10)[None, :])
    sizes = [len(pack(ramp, d)) for d in (0, 1, 2)]
    assert sizes[2] < 0.2 * sizes[0], sizes
    wave = 1e-6 * (1.0 + 0.5 * np.sin(2 * np.pi * k / 6000.0 + np.arange(10)[None, :]))
    sizes = [len(pack(wave, d)) for d in (0, 1, 2)]
    assert sizes[2] < sizes[1] < sizes[0], sizes
    noise = np.random.default_rng(9).normal(size=(20_000, 10))
    sizes = [len(pack(noise, d)) for d in (0, 1, 2)]
    assert max(sizes) < 1.05 * sizes[0], sizes


def test_delta_refused_for_bool_and_unknown_orders():
    with pytest.raises(ValueError, match="delta"):
        pack(np.array([True, False]), 1)
    with pytest.raises(ValueError, match="delta"):
        pack(np.zeros(3), 3)
    data = pack(np.zeros((4, 2)), 1)
    head, end = _header(data)
    h = json.dumps({**head, "delta": 5}).encode()
    with pytest.raises(ValueError, match="unsupported header"):
        unpack(MAGIC + struct.pack("<I", len(h)) + h + data[end:], "x")


def _plane_by_plane_reference(arr: np.ndarray) -> bytes:
    """The byte-shuffled content as the module docstring defines it, built the slow, obvious way:
    for each byte position, every column's bytes in epoch order."""
    a = np.asarray(arr, dtype=arr.dtype.newbyteorder("<"))
    n = a.shape[0] if a.ndim else 1
    octets = np.ascontiguousarray(a).reshape(n, -1).view(np.uint8).reshape(n, -1, a.dtype.itemsize)
    return b"".join(octets[:, c, b].tobytes() for b in range(a.dtype.itemsize) for c in range(octets.shape[1]))


@pytest.mark.parametrize("arr", [
    np.random.default_rng(4).normal(size=(301, 7)),
    np.random.default_rng(5).normal(size=(50, 3, 3)).astype(np.float32),
    np.arange(24, dtype=np.int16).reshape(4, 6),
    np.array([True, False, False, True]),
])
@pytest.mark.parametrize("delta", [0, 1, 2])
def test_fast_shuffle_paths_give_the_same_bytes(arr, delta, monkeypatch):
    """The epochs-last pack path, the plane-by-plane one (arrays over the size limit) and, without
    differences, an independent reference give the same bytes; the caller's array is left as it
    was; unpacking a column block at a time gives the array back."""
    import zstandard

    import cdgps_cli.io.packed_arrays as pa

    if delta and arr.dtype.kind == "b":
        return
    before = arr.copy()
    fast = pack(arr, delta)
    assert _same(before, arr)
    head = 12 + struct.unpack("<I", fast[8:12])[0]
    if not delta:
        assert zstandard.ZstdDecompressor().decompress(fast[head:]) == _plane_by_plane_reference(arr)
    monkeypatch.setattr(pa, "_TRANSPOSE_MAX_BYTES", 0)
    assert pack(arr, delta) == fast
    assert _same(before, arr)
    monkeypatch.setattr(pa, "_BLOCK_BYTES", 1)                 # one column per block
    assert _same(arr, unpack(fast))
