"""io/mcap.json_bytes: the JSON text of every MCAP message (orjson, with the json module for what
orjson refuses) reads back to exactly the values given, as the json module's text does."""

import json
import math
import struct

import numpy as np
import pytest

from cdgps_cli.io.mcap import McapOut, json_bytes, message_schema, read_mcap

EDGES = [0.0, -0.0, 1.0, -1.5, 0.1, 1e-05, 2.3456e-05, 1e-07, 5e-324, 2.2250738585072014e-308,
         1.7976931348623157e308, 1e16, 1e15, 123456789.123, 12345678901234567.0, 1 / 3, math.pi * 1e-9]


def _same_bits(a: float, b: float) -> bool:
    return struct.pack("<d", a) == struct.pack("<d", b)


def test_floats_read_back_bit_for_bit_as_the_json_module_s():
    rng = np.random.default_rng(11)
    vals = EDGES + rng.normal(0, 0.01, 20000).tolist() + (rng.standard_cauchy(20000) * 1e3).tolist() + \
        np.ldexp(rng.random(20000), rng.integers(-1070, 1020, 20000)).tolist()
    back = json.loads(json_bytes(vals))
    ref = json.loads(json.dumps(vals))
    assert len(back) == len(vals)
    assert all(_same_bits(a, b) and _same_bits(a, c) for a, b, c in zip(vals, back, ref))


def test_structure_keys_order_numpy_values_and_missing_values():
    obj = {"b": 1, "a": [True, None, "x"], "n": {"q1": np.float64(0.25)}, "i": np.int64(3), "t": (1, 2)}
    assert json_bytes(obj) == b'{"b":1,"a":[true,null,"x"],"n":{"q1":0.25},"i":3,"t":[1,2]}'
    assert json_bytes([float("nan"), float("inf")]) == b"[null,null]"       # McapOut.write encodes these first


def test_what_orjson_refuses_goes_through_the_json_module():
    assert json_bytes({1: 2.5}) == b'{"1":2.5}'                          # a key that is not a string
    assert json_bytes([2**70]) == b"[1180591620717411303424]"            # beyond 64 bits
    with pytest.raises(TypeError):
        json_bytes({"x": object()})


def test_messages_with_missing_values_and_the_word_null(tmp_path):
    """A NaN in a scalar is left out, a NaN in an array without a _valid companion is refused, and
    a text that contains "null" is written as given (the strict encoder's path)."""
    schema = message_schema("X", {"v": {"type": "number"}, "note": {"type": "string"}, "a": {"type": "array"}})
    with McapOut(tmp_path / "x.mcap") as out:
        ch = out.channel("/x", schema)
        out.write(ch, 0.5, {"v": float("nan"), "note": "nullable"})
        out.write(ch, 1.0, {"v": 2.5e-05, "note": "ok", "a": [1e-07]})
        with pytest.raises(ValueError, match="missing values in array field"):
            out.write(ch, 1.5, {"a": [1.0, float("nan")]})
    tc = read_mcap(tmp_path / "x.mcap").topics["/x"]
    assert tc.scalars["note"] == ["nullable", "ok"] and tc.scalars["v"] == [None, 2.5e-05]
    assert tc.column("a").tolist() == [1e-07]
