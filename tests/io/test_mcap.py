"""io/mcap.McapOut: attachments packed in a background thread (what STATES.mcap uses) are written in
the order given, read back exactly, deterministically, and an error leaves neither a file nor a
thread."""

import threading

import numpy as np
import pytest

from cdgps_cli.io.mcap import McapOut, message_schema, read_mcap
from cdgps_cli.io.packed_arrays import unpack


def _arrays():
    rng = np.random.default_rng(7)
    return {"a": rng.normal(size=(5000, 9)), "b": np.arange(1000, dtype=np.int64),
            "c": rng.normal(size=3).astype(np.float32)}


def _write(path, background: bool, fail_at=None, flush_each=False):
    with McapOut(path) as out:
        if background:
            out.pack_in_background()
        ch = out.channel("/x", message_schema("X", {"v": {"type": "number"}}))
        for i, (name, arr) in enumerate(_arrays().items()):
            out.attach_packed(name, arr, delta=1 if name == "a" else 0)
            out.write(ch, float(i), {"v": float(i)})
            if flush_each:
                out.write_packed()
            if fail_at == i:
                raise RuntimeError("stop")


def _pack_threads():
    return [t for t in threading.enumerate() if t.name.startswith("cdgps-pack")]


@pytest.mark.parametrize("flush_each", [False, True])
def test_background_packing_reads_back_the_same_arrays_in_the_order_given(tmp_path, flush_each):
    _write(tmp_path / "bg.mcap", True, flush_each=flush_each)
    _write(tmp_path / "fg.mcap", False)
    for f in ("bg.mcap", "fg.mcap"):
        c = read_mcap(tmp_path / f)
        assert list(c.attachments) == ["a", "b", "c"], f
        for name, arr in _arrays().items():
            got = unpack(c.attachments[name], name)
            assert got.dtype == arr.dtype and np.array_equal(got, arr), (f, name)
        assert c.topics["/x"].times().tolist() == [0.0, 1.0, 2.0]
    assert not _pack_threads()
    _write(tmp_path / "bg2.mcap", True, flush_each=flush_each)                  # deterministic
    assert (tmp_path / "bg.mcap").read_bytes() == (tmp_path / "bg2.mcap").read_bytes()


def test_an_error_inside_the_block_leaves_no_file_and_no_thread(tmp_path):
    with pytest.raises(RuntimeError, match="stop"):
        _write(tmp_path / "x.mcap", True, fail_at=1)
    assert list(tmp_path.iterdir()) == [] and not _pack_threads()


def test_an_array_that_cannot_be_packed_is_an_error_on_closing_and_leaves_no_file(tmp_path):
    with pytest.raises(ValueError, match="packed arrays hold bool, integer or float"):
        with McapOut(tmp_path / "y.mcap") as out:
            out.pack_in_background()
            out.attach_packed("bad", np.array(["text"], dtype=object))
    assert list(tmp_path.iterdir()) == [] and not _pack_threads()


def test_a_writer_killed_by_sigkill_leaves_nothing(tmp_path):
    """McapOut writes into an unnamed (O_TMPFILE) file and names it only when complete: a SIGKILL
    mid-write leaves no hidden temporary beside the output (issue 32: `.run.mcap.tmpNNNN` was left)."""
    import os
    import subprocess
    import sys

    code = ("import os, signal\nfrom cdgps_cli.io.mcap import McapOut\n"
            f"with McapOut({str(tmp_path / 'x.mcap')!r}) as out:\n"
            "    ch = out.channel('/t', {'title': 't', 'type': 'object', 'properties': {'v': {'type': 'number'}}})\n"
            "    out.write(ch, 0.0, {'v': 1.0})\n"
            "    os.kill(os.getpid(), signal.SIGKILL)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == -9, p.stderr
    if not hasattr(os, "O_TMPFILE"):
        return                                   # a named temporary then, removed by the next write
    assert sorted(q.name for q in tmp_path.iterdir()) == []
