"""Fuzz: receiver, gyro and actuator CSV logs (cdgps_cli/io/logs.py).

Property: any mutation of a valid log gives a validated table or a CdgpsError naming the file (a
value problem also names the line); the file is never modified.  Plus one end-to-end property:
``cdgps ingest`` on a mutated receiver log exits 0 or 2 and leaves no RUN.mcap after an error.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.logs import read_actuator_log, read_gyro_log, read_receiver_log

from fuzz_support import ANY_TEXT, DOF2, NUMBER_TEXT, TESTBED, byte_mutation, check_command, check_reader, cli, \
    fuzz_settings, scratch, sha256

READERS = {"receiver": read_receiver_log, "gyro": read_gyro_log, "actuators": read_actuator_log}


@functools.cache
def _testbed_cfg():
    return load_config(TESTBED)


@st.composite
def field_mutation(draw, text: str):
    """(description, mutated text): one field of one row (header included) replaced by odd text."""
    lines = text.splitlines(keepends=True)
    i = draw(st.integers(0, min(len(lines) - 1, 40)))
    fields = lines[i].rstrip("\r\n").split(",")
    j = draw(st.integers(0, len(fields) - 1))
    fields[j] = draw(st.one_of(NUMBER_TEXT, ANY_TEXT))
    return f"line {i + 1} field {j} = {fields[j]!r}", "".join(lines[:i] + [",".join(fields) + "\n"] + lines[i + 1:])


@st.composite
def text_mutation(draw, text: str):
    """(description, bytes): a line-ending, BOM, encoding or whitespace change of the whole file."""
    kind = draw(st.sampled_from(["crlf", "cr", "bom", "latin1", "spaces", "no-final-newline", "blank-lines", "gzip-name"]))
    if kind == "crlf":
        return kind, text.replace("\n", "\r\n").encode()
    if kind == "cr":
        return kind, text.replace("\n", "\r").encode()
    if kind == "bom":
        return kind, ("\ufeff" + text).encode()
    if kind == "latin1":
        k = draw(st.integers(0, len(text) - 1))
        return kind, (text[:k] + "é" + text[k:]).encode("latin-1")
    if kind == "spaces":
        return kind, text.replace(",", " , ").encode()
    if kind == "no-final-newline":
        return kind, text.rstrip("\n").encode()
    if kind == "blank-lines":
        return kind, text.replace("\n", "\n\n", 3).encode()
    return kind, b"\x1f\x8b" + text.encode()


def _logs(base):
    return {"receiver": base / "tsim" / "receiver.csv", "gyro": base / "tsim" / "gyro.csv",
            "actuators": base / "tsim" / "actuators.csv"}


def _check(kind, data: bytes, cfg, value_change: bool):
    with scratch() as d:
        f = d / f"{kind}.csv"
        f.write_bytes(data)
        df = check_reader(lambda: READERS[kind](f, cfg), f, *(("line", "column") if value_change else ()))
        if df is not None:
            assert list(df.columns)[0] == "time_s" and np.all(np.isfinite(df["time_s"].to_numpy()))
            assert np.all(np.diff(df["time_s"].to_numpy()) >= 0)


@pytest.mark.parametrize("kind", list(READERS))
@fuzz_settings(25)
@given(data=st.data())
def test_byte_mutations(base, kind, data):
    raw = _logs(base)[kind].read_bytes()
    _, mutated = data.draw(byte_mutation(raw))
    _check(kind, mutated, _testbed_cfg(), value_change=False)


@pytest.mark.parametrize("kind", list(READERS))
@fuzz_settings(25)
@given(data=st.data())
def test_field_mutations(base, kind, data):
    _, mutated = data.draw(field_mutation(_logs(base)[kind].read_text()))
    _check(kind, mutated.encode(), _testbed_cfg(), value_change=True)


@fuzz_settings(12)
@given(data=st.data())
def test_whole_file_changes(base, data):
    kind = data.draw(st.sampled_from(list(READERS)))
    _, mutated = data.draw(text_mutation(_logs(base)[kind].read_text()))
    _check(kind, mutated, _testbed_cfg(), value_change=False)


@fuzz_settings(8)
@given(data=st.data())
def test_ingest_of_a_mutated_log(base, data):
    """End to end: exit 0 or a clean exit 2 naming the log; no RUN.mcap after an error."""
    raw = (base / "sim" / "receiver.csv").read_text()
    _, mutated = data.draw(st.one_of(field_mutation(raw).map(lambda m: (m[0], m[1].encode())), byte_mutation(raw.encode())))
    with scratch() as d:
        f, out = d / "receiver.csv", d / "RUN.mcap"
        f.write_bytes(mutated)
        before = {f: sha256(f), DOF2: sha256(DOF2)}
        r = cli("ingest", f, "--config", DOF2, "-o", out)
        check_command(r, before, [out], str(f))


def test_unclosed_quote_names_the_line(base, tmp_path):
    """Found by this suite: pandas' tokenizer message ("EOF inside string starting at row 1") gave
    no line; the quote is on line 2 of the file (the first data row)."""
    lines = (base / "tsim" / "gyro.csv").read_text().splitlines(keepends=True)
    f = tmp_path / "gyro.csv"
    f.write_text(lines[0] + '"' + "".join(lines[1:]))
    with pytest.raises(CdgpsError, match=rf"{f}, line 2: malformed CSV"):
        read_gyro_log(f, _testbed_cfg())
