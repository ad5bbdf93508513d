"""McapOut frames messages into the mcap Writer's chunks itself (``McapOut._frame``, issue 30): the
file is the same, byte for byte, as when every message goes through the mcap library's
``Writer.add_message`` (``cdgps_cli.io.mcap._FRAME_MESSAGES = False``), across chunk boundaries,
channels registered between messages, log times out of order, attachments and metadata between
messages, and for a whole STATES.mcap."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader

from cdgps_cli.analysis.preview import anti_alias_decimate
from cdgps_cli.io import mcap as mcap_io
from cdgps_cli.io import states
from cdgps_cli.io.mcap import McapOut, array_schema, message_schema, read_mcap

from tests.io.test_states_stream import ANGLES, _structure


def _write(path, frame: bool, monkeypatch) -> bytes:
    monkeypatch.setattr(mcap_io, "_FRAME_MESSAGES", frame)
    rng = np.random.default_rng(4)
    with McapOut(path) as out:
        assert (out._index_class is not None) == frame
        a = out.channel("/a", message_schema("A", {"v": {"type": "number"}}))
        for i in range(300):
            out.write(a, 0.1 * i, {"v": float(rng.normal())})
        out.attach("note.txt", b"between messages")
        b = out.channel("/b", array_schema("B", {"x": "number|null"}))
        for i in range(900):                       # ~3 kB messages: the chunk of 1 MiB fills twice
            x = rng.normal(size=400)
            x[i % 7] = np.nan
            t = 30.0 + 0.05 * i - (0.5 if i % 11 == 0 else 0.0)       # log times out of order
            out.write(b, t, {"x": x.tolist()})
            if i % 97 == 0:
                out.write_raw(a, t, {"raw": i})
        out.metadata("m", {"k": "v"})
        out.write(a, 0.0, {"v": 1.5})
    return path.read_bytes()


def test_framed_messages_are_the_libraries_bytes(tmp_path, monkeypatch):
    ref = _write(tmp_path / "ref.mcap", False, monkeypatch)
    got = _write(tmp_path / "got.mcap", True, monkeypatch)
    assert got == ref
    with open(tmp_path / "got.mcap", "rb") as fh:              # the library reads it back, CRCs checked
        msgs = list(make_reader(fh, validate_crcs=True).iter_messages(topics=["/b"]))
    assert len(msgs) == 900 and msgs[0][2].sequence == 0 and msgs[-1][2].sequence == 899
    assert read_mcap(tmp_path / "got.mcap").topics["/b"] is not None


@pytest.mark.parametrize("case", ["modal", "full"])
def test_states_framed_as_the_library(tmp_path, monkeypatch, case):
    ss = _structure()
    kw = dict(covariance=case, preview_rate_hz=2.0 if case == "modal" else 0.0, angles=ANGLES,
              preview=anti_alias_decimate)
    out = {}
    for frame in (False, True):
        monkeypatch.setattr(mcap_io, "_FRAME_MESSAGES", frame)
        p = tmp_path / f"{frame}.mcap"
        states.write_states(ss, p, {"x": "1"}, {"init.json": (b"{}", "application/json")}, **kw)
        out[frame] = p.read_bytes()
    assert out[True] == out[False]


def test_rows_framed_in_blocks_as_the_library(tmp_path, monkeypatch):
    """``write_rows`` frames a block of messages at once (``McapOut._add_many``): across chunk
    boundaries, with rows through ``write`` between them, the library's bytes."""
    rng = np.random.default_rng(8)
    vals = rng.normal(size=(3000, 120))
    vals[::97, 105] = np.nan                      # through write(): a scalar left out
    layout = [("x", 100), ("s", None)] + [(f"k{i}", None) for i in range(19)]
    props = {"x": {"type": "array"}, **{k: {"type": "number"} for k, _ in layout[1:]}}
    got = {}
    for frame in (False, True):
        monkeypatch.setattr(mcap_io, "_FRAME_MESSAGES", frame)
        p = tmp_path / f"{frame}.mcap"
        with McapOut(p) as out:
            ch = out.channel("/r", message_schema("R", props))
            out.write_rows(ch, 10.0 + np.arange(3000) * 0.1, layout, np.hstack([vals[:, :100], vals[:, 100:]]))
        got[frame] = p.read_bytes()
    assert len(got[True]) > 3 << 20 and got[True] == got[False]
