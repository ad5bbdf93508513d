"""MCAP containers shared by every stage (RUN.mcap from ingest, later STATES.mcap).

Layout written by :class:`McapOut`:

* zstd-compressed chunks, chunk, attachment, data-section and summary CRCs, full summary and indexes;
* JSON-schema channels (schema encoding ``jsonschema``, message encoding ``json``) so Foxglove can
  open the file; one message per epoch per topic, the epoch's channels as arrays, with a
  ``timestamp {sec, nsec}`` field (log time = publish time = that timestamp, Unix time: see
  :mod:`cdgps_cli.core.timescales`) and ``time_s`` in the file's own time scale (GPS s or run s);
* every schema is one Foxglove's JSON-schema decoder accepts (one ``type`` per property: boolean,
  string, number, integer, object, or an array of one of those) and every message is valid
  against it: no ``null`` anywhere.  A missing number in an array (a satellite without C/N0) is
  written as 0 with ``false`` at its place in the parallel boolean array ``<field>_valid``; a
  missing scalar or object member is left out of the message (:meth:`McapOut.write` does both
  for the fields the schema declares that way; readers turn them back into NaN);
* attachments (e.g. the structure config ``config.toml``; large ``.npy`` arrays are streamed to
  the file by :meth:`McapOut.attach_npy` instead of being built in memory) and metadata records.

Files are written under a temporary name in the target directory and renamed when complete, so a
failed run never leaves a half-written output.  Every metadata record carries its own
``record_sha256``.  Readers go through :func:`open_verified`: summary and data-section CRCs
(:mod:`cdgps_cli.io.mcap_integrity`), chunk and attachment CRCs and the records' checksums are
verified before any value is used, and any corruption or truncation is a :class:`CdgpsError`
naming the file.
"""

from __future__ import annotations

import bisect
import contextlib
import io
import json
import os
import re
import struct
import zlib
from itertools import accumulate
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import orjson
import zstandard
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.opcode import Opcode
from mcap.records import AttachmentIndex

from cdgps_cli.core import progress
from cdgps_cli.io.atomic import (is_no_room, link_anonymous, open_anonymous, output_error, remove_stale_temporaries,
                                 temporary_name)
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.table import Table
from cdgps_cli.io.mcap_integrity import (RECORD_SHA256_KEY, DataSectionDamage, check_records, record_sha256,
                                         verify_file, warn_once)
from cdgps_cli.core.timescales import RELATIVE_EPOCH_UTC, TIME_SCALES, unix_ns, unix_ns_list

# mcap.writer is imported where a file is written (McapOut): it loads importlib.metadata, ≈ 20 ms that
# readers (`cdgps info`, `export`, `spectra`) need not pay (benchmarks/startup.py)
if TYPE_CHECKING:
    from mcap.writer import Writer

INFO_METADATA = "cdgps.info"
"""Metadata record :class:`McapOut` writes into every file: ``format`` (:data:`INFO_FORMAT`),
``topics`` (JSON: per topic with messages ``messages``, ``start_s``, ``end_s``, ``median_period_s``,
:func:`time_summary` of the messages' ``time_s``) and what the writer adds
(:attr:`McapOut.info_extra`, e.g. ``structure`` in a RUN, :func:`cdgps_cli.io.run.write_run`).
``cdgps info`` answers from it and the summary section without reading the messages
(:func:`cdgps_cli.io.run.run_info`)."""
INFO_FORMAT = "1"
PHASE_TOPIC = "/cdgps/phase"
GYRO_TOPIC = "/cdgps/gyro"
ACTUATOR_TOPIC = "/cdgps/actuators"
CONFIG_ATTACHMENT = "config.toml"

TIMESTAMP_SCHEMA = {"type": "object", "description": "log time, UTC (Unix time)",
                    "properties": {"sec": {"type": "integer", "minimum": 0, "description": "s since 1970-01-01"},
                                   "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
                    "required": ["sec", "nsec"]}
_TS = TIMESTAMP_SCHEMA
NULLABLE = "number|null"
"""Field type of :func:`array_schema` for a number that may be missing (NaN): in an array, a
``number`` array plus its boolean ``<field>_valid`` array; as a scalar, a ``number`` that is left
out of the messages where it is missing."""
VALID_SUFFIX = "_valid"


def time_summary(time_s, sources=None) -> dict:
    """``start_s``, ``end_s`` (min, max; None when empty) and ``median_period_s``
    (:func:`cdgps_cli.core.time_format.median_spacing_s`) of a topic's message times, s."""
    from cdgps_cli.core.time_format import median_spacing_s  # noqa: PLC0415

    t = np.asarray(time_s, dtype=float)
    start, end = (float(np.min(t)), float(np.max(t))) if t.size else (None, None)
    return {"start_s": start, "end_s": end, "median_period_s": median_spacing_s(t, sources)}


def message_schema(title: str, properties: dict, description: str | None = None) -> dict:
    """JSON schema of a message: ``timestamp``, ``time_s`` and ``properties``, both required."""
    props = {"timestamp": TIMESTAMP_SCHEMA,
             "time_s": {"type": "number", "description": "seconds in the file's time scale (channel metadata time_scale)"}}
    props.update(properties)
    s = {"title": title, "type": "object", "properties": props, "required": ["timestamp", "time_s"]}
    if description:
        s["description"] = description
    return s


def array_schema(title: str, fields: dict[str, str], scalars: dict[str, str] | None = None) -> dict:
    """JSON schema of an epoch message: ``timestamp``, ``time_s``, scalars and per-channel arrays.

    Types are JSON-schema type names; :data:`NULLABLE` (``"number|null"``) marks a number that may be
    missing (an array field then gets its ``<field>_valid`` companion, see :meth:`McapOut.write`).
    """
    props = {}
    for k, t in (scalars or {}).items():
        props[k] = {"type": "number", "description": "left out where missing"} if t == NULLABLE else {"type": t}
    for k, t in fields.items():
        props[k] = {"type": "array", "items": {"type": "number" if t == NULLABLE else t}}
        if t == NULLABLE:
            props[k]["description"] = f"0 where {k}{VALID_SUFFIX} is false (missing)"
            props[k + VALID_SUFFIX] = {"type": "array", "items": {"type": "boolean"},
                                       "description": f"whether {k} holds a value at this index"}
    return message_schema(title, props)


def _nullable_fields(schema: dict) -> tuple[frozenset, frozenset]:
    """(array fields with a ``_valid`` companion, all other number / object fields) of a schema."""
    props = schema.get("properties", {})
    arrays = frozenset(k for k in props if k + VALID_SUFFIX in props and props[k].get("type") == "array")
    others = frozenset(k for k, v in props.items()
                       if k not in arrays and v.get("type") in ("number", "integer", "object", "string", "boolean"))
    return arrays, others


def _drop_missing(v):
    """An object member / scalar without its NaN or None entries (objects recursively)."""
    if isinstance(v, dict):
        return {k: _drop_missing(x) for k, x in v.items() if not _missing(x)}
    return v


def _missing(v) -> bool:
    return v is None or (isinstance(v, float) and v != v)


def _holds_missing(v) -> bool:
    """Whether a None, NaN or infinity is anywhere in ``v`` (dicts and lists, recursively)."""
    if isinstance(v, dict):
        return any(_holds_missing(x) for x in v.values())
    if isinstance(v, (list, tuple)):
        return any(_holds_missing(x) for x in v)
    return v is None or (isinstance(v, float) and not np.isfinite(v))


_COMPACT_JSON = json.JSONEncoder(separators=(",", ":"), allow_nan=False)


def json_bytes(obj) -> bytes:
    """Compact JSON of ``obj`` (numpy numbers as numbers); NaN and infinity come out as ``null``.

    orjson (its float text is the shortest that reads back to the same double, as ``json`` writes
    it, in a few times less time; exponents may be written differently, e.g. ``0.00001`` for
    ``1e-05``); what orjson refuses (keys that are not strings, integers beyond 64 bits) through
    ``json``, which refuses what it always did."""
    try:
        return orjson.dumps(obj, option=orjson.OPT_SERIALIZE_NUMPY)
    except TypeError:
        return json.dumps(obj, separators=(",", ":")).encode()
"""``json.dumps(…, separators=(",", ":"), allow_nan=False)`` without building an encoder per message."""


def _plain_json(msg: dict, payload: dict) -> bytes | None:
    """``msg`` followed by ``payload`` as compact JSON when no value is missing (None or NaN at any
    depth), else None: then :meth:`McapOut._encode` applies the schema's rules.  When it returns
    bytes, they are the bytes ``_encode`` would give (nothing to drop or replace)."""
    data = json_bytes({**msg, **payload})
    return None if b"null" in data else data        # a None, NaN or infinity somewhere (or the word in a string)


def _with_validity(payload: dict, field: str) -> None:
    """Replace missing elements of ``payload[field]`` by 0 and set ``payload[field + '_valid']``."""
    vals = payload.get(field)
    if vals is None:
        return
    vals = vals.tolist() if isinstance(vals, np.ndarray) else list(vals)
    # (x == x: False for NaN only; the test of _missing without a call per element)
    valid = [x is not None and (x == x if isinstance(x, float) else True) for x in vals]
    payload[field] = vals if all(valid) else [x if ok else 0.0 for x, ok in zip(vals, valid)]
    payload[field + VALID_SUFFIX] = valid


PHASE_SCHEMA = array_schema(
    "cdgps.DifferentialPhase",
    {"receiver": "string", "antenna": "string", "transmitter": "string", "phase_cycles": "number",
     "lock": "integer", "snr_dbhz": "number|null"},
    {"master": "string"},
)
GYRO_SCHEMA = array_schema("cdgps.RateGyro", {"gyro": "string", "rate_rad_s": "number"})
ACTUATOR_SCHEMA = array_schema("cdgps.ThrusterCommand", {"actuator": "string", "force_n": "number"})


def time_ns(time_s: float, time_scale: str = "relative") -> int:
    """Payload seconds → log time, integer Unix nanoseconds (:func:`cdgps_cli.core.timescales.unix_ns`)."""
    return unix_ns(time_s, time_scale)


def timestamp(time_s: float, time_scale: str = "relative") -> dict:
    ns = time_ns(time_s, time_scale)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


_OPCODE_ATTACHMENT = int(Opcode.ATTACHMENT)
_OPCODE_MESSAGE = int(Opcode.MESSAGE)
_FRAME_MESSAGES = True
"""Messages framed by :meth:`McapOut._frame` (False: each through the mcap library's ``add_message``,
the reference the framing is tested against)."""
_WRITER_INTERNALS = ("flush", "stream", "enable_data_crcs", "data_section_crc", "statistics",
                     "index_types", "attachment_indexes")


def _streaming_supported(writer: Writer, fh) -> bool:
    """Whether :meth:`McapOut.attach_stream` can write past the mcap Writer (its private state is as
    expected: mcap-python ≥ 1.1, writing to our own file handle)."""
    if not all(hasattr(writer, "_Writer__" + a) for a in _WRITER_INTERNALS):
        return False
    return writer._Writer__stream is fh and hasattr(writer._Writer__statistics, "attachment_count")


_OPCODE_MESSAGE_INDEX = int(Opcode.MESSAGE_INDEX)
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")        # opcode, record length, channel, sequence, log time, publish time
_MESSAGE_HEAD_BYTES = _MESSAGE_HEAD.size
_CHUNK_INTERNALS = ("chunk_builder", "chunk_size", "statistics", "finalize_chunk", "index_types")


def row_payload(layout, row: list, tail: dict | None = None, head: dict | None = None) -> dict:
    """The payload :meth:`McapOut.write_rows` writes for one row (a list of floats; ``layout`` as
    there)."""
    payload, at = dict(head or {}), 0
    for key, shape in layout:
        if shape is None or shape == "int":
            payload[key] = row[at] if shape is None or row[at] != row[at] else int(row[at])
            at += 1
        elif isinstance(shape, int):
            payload[key] = row[at:at + shape]
            at += shape
        else:
            payload[key] = dict(zip(shape, row[at:at + len(shape)]))
            at += len(shape)
    payload.update(tail or {})
    return payload


def _comma_groups(seps: list, int_cols) -> list[tuple[int, int]]:
    """The columns of a :meth:`McapOut.write_rows` template as runs (c0, c1) written together: the
    numbers of one array (only ``,`` between them) form one run, every other column (an object
    member, a scalar, an integer) its own."""
    m, out, c = len(seps) - 1, [], 0
    ints = set(int_cols)
    while c < m:
        d = c + 1
        while d < m and seps[d] == b"," and c not in ints and d not in ints:
            d += 1
        out.append((c, d))
        c = d
    return out


def _group_texts(rows: np.ndarray, c0: int, c1: int, integer: bool) -> list[bytes]:
    """Per row of ``rows`` (k, m), finite: the JSON text of columns c0 … c1−1 joined by commas (the
    number texts of :func:`json_bytes`; ``integer``: one column written as an integer)."""
    if integer:
        return [b"%d" % v for v in rows[:, c0].tolist()]
    if c1 == c0 + 1:
        return orjson.dumps(rows[:, c0].tolist())[1:-1].split(b",") if rows.shape[0] else []
    if not rows.shape[0]:
        return []
    return orjson.dumps(rows[:, c0:c1].tolist())[2:-2].split(b"],[")


def _row_template(layout, tail: dict | None, head: dict | None = None) -> list | None:
    """The bytes between the numbers of a :meth:`McapOut.write_rows` message after its ``time_s``:
    m + 1 pieces for m numbers; None when a key or constant would hold the word ``null`` (then
    :meth:`McapOut.write` takes another encoder)."""
    keys = list(head or {}) + [k for k, _ in layout] + list(tail or {})
    if len(set(keys)) < len(keys) or any(isinstance(s, list) and len(set(s)) < len(s) for _, s in layout):
        return None                                       # a repeated key: the dict keeps the last
    seps, pending = [], (b"," + orjson.dumps(head)[1:-1] if head else b"")
    for key, shape in layout:
        k = orjson.dumps(key)
        if shape is None or shape == "int":
            seps.append(pending + b"," + k + b":")
            pending = b""
        elif isinstance(shape, int):
            if shape == 0:
                pending += b"," + k + b":[]"
                continue
            seps.append(pending + b"," + k + b":[")
            seps.extend([b","] * (shape - 1))
            pending = b"]"
        else:
            if not shape:
                pending += b"," + k + b":{}"
                continue
            names = [orjson.dumps(str(n)) for n in shape]
            seps.append(pending + b"," + k + b":{" + names[0] + b":")
            seps.extend(b"," + n + b":" for n in names[1:])
            pending = b"}"
    end = orjson.dumps(tail or {})[1:-1]
    seps.append(pending + (b"," + end if end else b"") + b"}")
    return None if any(b"null" in p for p in seps) else seps


class Slot:
    """A number left open in a message skeleton (:meth:`McapOut.write_skeleton`): column ``i`` of
    the rows, or (``i`` = -1, -2) the seconds / nanoseconds of the message's log time."""

    __slots__ = ("i",)

    def __init__(self, i: int):
        self.i = int(i)


_SLOT_MARK = "\ue000"                 # (a private-use character: no text of a message holds it)
_SLOT_TEXT = re.compile(rb'"\xee\x80\x80(-?\d+)\xee\x80\x80"')


def _skeleton_template(skeleton: dict) -> tuple[list, list]:
    """(n + 1 byte pieces, n slot indices) of ``skeleton``'s compact JSON around its :class:`Slot` leaves."""
    found = []

    def mark(v):
        if not isinstance(v, Slot):
            raise TypeError(f"{type(v).__name__} in a message skeleton")
        found.append(v.i)
        return f"{_SLOT_MARK}{v.i}{_SLOT_MARK}"

    data = orjson.dumps(skeleton, default=mark)
    parts = _SLOT_TEXT.split(data)
    pieces, slots = parts[0::2], [int(i) for i in parts[1::2]]
    if slots != found or any(b"null" in p or _SLOT_MARK.encode() in p for p in pieces):
        raise ValueError("message skeleton: a missing value or a text holding the slot mark")
    return pieces, slots


def _framing_supported(writer: Writer) -> bool:
    """Whether :meth:`McapOut._add` can frame messages into the mcap Writer's open chunk itself (its
    private state is as expected: mcap-python 1.x with chunking); else each message goes through
    ``Writer.add_message`` (the same bytes, ≈ 20 µs more per message)."""
    if not all(hasattr(writer, "_Writer__" + a) for a in _CHUNK_INTERNALS):
        return False
    cb = writer._Writer__chunk_builder
    return (cb is not None and hasattr(cb, "message_indices") and hasattr(cb, "num_messages")
            and hasattr(getattr(cb, "record_writer", None), "_buffer")
            and hasattr(writer._Writer__statistics, "channel_message_counts"))


def _packed_index_class():
    """``mcap.records.MessageIndex`` whose entries are written with one ``struct`` call (the bytes of
    its own ``write``, which makes two calls per entry)."""
    from mcap.records import MessageIndex  # noqa: PLC0415

    class PackedMessageIndex(MessageIndex):
        def write(self, stream) -> None:
            flat = [v for entry in self.records for v in entry]
            stream.write(struct.pack("<BQHI", _OPCODE_MESSAGE_INDEX, 6 + 8 * len(flat), self.channel_id, 8 * len(flat)))
            stream.write(struct.pack(f"<{len(flat)}Q", *flat))

    return PackedMessageIndex


_MESSAGES_PER_BLOCK = 4096
"""Messages whose rows :meth:`McapOut.write_table` turns into Python lists at a time (the lists of a
whole hour's phase table took ~250 MB)."""


def _column_rows(df, c: str):
    """``rows(a, b)``: rows a … b−1 of column ``c`` of a DataFrame or a
    :class:`~cdgps_cli.core.table.Table` as a list (a Table's name column from its codes, so no
    whole-length array of names is made)."""
    if isinstance(df, Table) and _is_name_column(df, c):
        codes, words = df.codes(c)
        return lambda a, b: [words[k] for k in codes[a:b].tolist()]
    col = np.asarray(df[c])
    return lambda a, b: col[a:b].tolist()


class _Named:
    """``[i]``: row i's name of a Table's name column, from its codes (no array of names made)."""

    def __init__(self, codes, words):
        self.codes, self.words = codes, words

    def __getitem__(self, i):
        return self.words[self.codes[i]]


def _column_values(df, c: str):
    """Column ``c`` indexable by row (a Table's name column through its codes)."""
    if isinstance(df, Table) and _is_name_column(df, c):
        return _Named(*df.codes(c))
    return np.asarray(df[c])


def _is_name_column(table, c: str) -> bool:
    try:
        table.codes(c)
        return True
    except KeyError:
        return False


class McapOut:
    """Atomic MCAP writer (context manager).

    Examples
    --------
    >>> with McapOut("run.mcap") as out:                        # doctest: +SKIP
    ...     ch = out.channel("/cdgps/phase", PHASE_SCHEMA)
    ...     out.write(ch, 0.1, {"phase_cycles": [0.25]})
    """

    def __init__(self, path: str | Path, profile: str = "cdgps", time_scale: str = "relative"):
        if time_scale not in TIME_SCALES:
            raise ValueError(f"time_scale {time_scale!r}: expected one of {', '.join(TIME_SCALES)}")
        self.path = Path(path)
        self.tmp = temporary_name(self.path)
        self.profile = profile
        self.time_scale = time_scale
        self._schemas: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._nullable: dict[int, tuple] = {}
        self._index_class = None                 # set on entering: McapOut._frame's message index records
        self._packer = None                      # pack_in_background: the worker, and what it packs
        self._deferred: list = []
        self._topic: dict[int, str] = {}
        self._times: dict[int, array] = {}       # per channel: each message's time_s (for INFO_METADATA)
        self._sources: dict[int, list] = {}      # per channel: each message's scalar ``receiver`` (or None)
        self.info_extra: dict[str, str] = {}
        """Further entries of the :data:`INFO_METADATA` record (e.g. a RUN's gaps and channels)."""

    def __enter__(self) -> "McapOut":
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            remove_stale_temporaries(self.path)         # left by a SIGKILLed writer
            # an unnamed file where the system has them: a SIGKILL leaves nothing behind
            self._fh = open_anonymous(self.path.parent)
            self._anonymous = self._fh is not None
            if self._fh is None:
                self._fh = open(self.tmp, "wb")
        except OSError as exc:
            raise CdgpsError(f"{self.path}: cannot write: {exc.strerror}") from None
        from mcap.writer import CompressionType, Writer  # noqa: PLC0415  (see the module imports)

        self.writer = Writer(self._fh, compression=CompressionType.ZSTD, enable_crcs=True,
                             enable_data_crcs=True, chunk_size=1 << 20)
        self._chunk_size = 1 << 20
        self._index_class = _packed_index_class() if _FRAME_MESSAGES and _framing_supported(self.writer) else None
        try:
            self.writer.start(profile=self.profile, library="cdgps")
        except OSError as err:                  # full disk already at the header
            self._fh.close()
            self.tmp.unlink(missing_ok=True)
            raise output_error(self.path, err) from None
        return self

    def channel(self, topic: str, schema: dict, metadata: dict | None = None) -> int:
        """Register a channel; its metadata also records the time scale (``time_scale``,
        ``time_origin_utc`` for relative runs) and that log times are Unix time."""
        title = schema["title"]
        data = json.dumps(schema, sort_keys=True).encode()
        if title not in self._schemas:
            self._schemas[title] = (self.writer.register_schema(name=title, encoding="jsonschema", data=data), data)
        elif self._schemas[title][1] != data:
            raise ValueError(f"schema {title!r} registered twice with different contents")
        meta = {"time_scale": self.time_scale, "log_time": "UTC, ns since 1970-01-01 (Unix time)"}
        if self.time_scale == "relative":
            meta["time_origin_utc"] = RELATIVE_EPOCH_UTC
        meta.update(metadata or {})
        cid = self.writer.register_channel(topic=topic, message_encoding="json",
                                           schema_id=self._schemas[title][0], metadata=meta)
        self._seq[cid] = 0
        self._nullable[cid] = _nullable_fields(schema)
        self._topic[cid] = topic
        self._times[cid] = array("d")
        return cid

    def write(self, channel_id: int, time_s: float, payload: dict) -> None:
        """Write one message at payload time ``time_s`` (the file's time scale; log time in Unix ns).

        Missing values (None or NaN) are encoded as the channel's schema says: arrays with a
        ``<field>_valid`` companion get 0 there and ``false`` in the companion; scalars and object
        members are left out.  Anything else that is missing is an error (no ``null`` is written).
        """
        ns = time_ns(time_s, self.time_scale)
        msg = {"timestamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}, "time_s": float(time_s)}
        arrays, others = self._nullable[channel_id]
        data = None if arrays.intersection(payload) else _plain_json(msg, payload)
        if data is None:
            data = self._encode(msg, payload, arrays, others, time_s)
        self._add(channel_id, ns, data)
        self._note(channel_id, msg["time_s"], payload.get("receiver"))

    def write_rows(self, channel_id: int, time_s, layout, values, tail: dict | None = None,
                   head: dict | None = None) -> None:
        """Write one message per row of ``values`` (k, m): the bytes of :meth:`write` of
        :func:`row_payload` ``(layout, row, tail)`` at ``time_s[i]``, built from one template per
        channel (no dict per message; rows with a NaN or infinity go through :meth:`write`, which
        applies the schema's rules for missing values).

        Parameters
        ----------
        channel_id : int
        time_s : array-like (k,)
            Payload times, s (the file's time scale).
        layout : list of (str, list of str or int)
            The payload's fields in order, each taking the next values of a row: a list of names, a
            JSON object of those names; an int n, an array of n numbers (0: an empty array); None,
            one number; ``"int"``, one integer (the value as ``int``).
        values : ndarray (k, m)
            Float rows; m the total width of ``layout``.
        tail, head : dict, optional
            Constant fields written after them (e.g. ``{"smoothed": True}``), and before them.
        """
        times = np.asarray(time_s, dtype=float).tolist()
        values = np.asarray(values, dtype=float)
        keys = {k for k, _ in layout} | set(tail or {}) | set(head or {})
        # arrays with a _valid companion, a receiver, a key holding the word null: write()'s own ways
        plain = not (self._nullable[channel_id][0] & keys or "receiver" in keys)
        seps = (_row_template(layout, tail, head) if plain else None) or ()
        widths = [1 if s is None or s == "int" else (s if isinstance(s, int) else len(s)) for _, s in layout]
        int_cols = [c for c, (_, s) in zip(np.cumsum([0] + widths).tolist(), layout) if s == "int"]
        finite = np.isfinite(values).all(axis=1).tolist() if values.size else [True] * len(times)
        fmt = b'{"timestamp":{"sec":%d,"nsec":%d},"time_s":%s' + b"%s".join(p.replace(b"%", b"%%") for p in seps)
        groups = _comma_groups(seps, int_cols) if seps else []
        fmt_g = b'{"timestamp":{"sec":%d,"nsec":%d},"time_s":%s' + \
            b"%s".join(seps[c].replace(b"%", b"%%") for c in [c for c, _ in groups] + [len(seps) - 1]) if seps else b""
        # rows whose number texts are held at a time: about 16k numbers (memory of a block, not of the record)
        block = max(64, min(2048, (1 << 14) // max(values.shape[1] if values.ndim == 2 else 1, 1)))
        for a in range(0, len(times), block):
            rows, tb = values[a:a + block], times[a:a + block]
            t_texts = orjson.dumps(tb)[1:-1].split(b",")
            if seps and all(finite[a:a + block]):          # (every row by the template: the numbers at once)
                stamps = unix_ns_list(tb, self.time_scale)
                singles = [c0 for c0, c1 in groups if c1 == c0 + 1 and c0 not in int_cols]   # (their texts at once)
                flat = orjson.dumps(rows[:, singles].ravel().tolist())[1:-1].split(b",") if singles and len(tb) else []
                where = {c: j for j, c in enumerate(singles)}
                cols = [flat[where[c0]::len(singles)] if c0 in where else _group_texts(rows, c0, c1, c0 in int_cols)
                        for c0, c1 in groups]
                self._add_many(channel_id, stamps,
                               [fmt_g % (ns // 1_000_000_000, ns % 1_000_000_000, tt, *g)
                                for ns, tt, g in zip(stamps, t_texts, zip(*cols) if cols else [()] * len(tb))], tb)
                continue
            texts = orjson.dumps(rows.ravel().tolist())[1:-1].split(b",") if rows.size else []
            m = rows.shape[1] if rows.ndim == 2 else 0
            for c in int_cols:
                for i, v in enumerate(rows[:, c].tolist()):
                    texts[i * m + c] = b"%d" % v if v == v and abs(v) != np.inf else b"null"
            stamps, datas, kept = [], [], []
            for i, t in enumerate(tb):
                if not (seps and finite[a + i]):
                    self._add_many(channel_id, stamps, datas, kept)         # (what came before, in order)
                    stamps, datas, kept = [], [], []
                    self.write(channel_id, t, row_payload(layout, rows[i].tolist(), tail, head))
                    continue
                ns = time_ns(t, self.time_scale)
                stamps.append(ns)
                datas.append(fmt % (ns // 1_000_000_000, ns % 1_000_000_000, t_texts[i], *texts[i * m:(i + 1) * m]))
                kept.append(t)
            self._add_many(channel_id, stamps, datas, kept)

    def write_skeleton(self, channel_id: int, time_s, skeleton: dict, values) -> None:
        """Write, at each time ``time_s[i]``, the bytes of :meth:`write_raw` of ``skeleton`` with its
        :class:`Slot` leaves filled in: ``Slot(j)`` by ``values[i, j]``, ``Slot(-1)`` / ``Slot(-2)`` by
        the seconds / nanoseconds of the message's log time (one template, no dict per message).

        ``values`` (k, m) must be finite (a ValueError, as :meth:`write_raw` gives for a missing value)."""
        times = np.asarray(time_s, dtype=float).tolist()
        values = np.asarray(values, dtype=float)
        if values.size and not np.isfinite(values).all():
            raise ValueError(f"messages on {self._topic[channel_id]}: a missing value (NaN or infinity)")
        pieces, slots = _skeleton_template(skeleton)
        fmt = b"%s".join(p.replace(b"%", b"%%") for p in pieces)
        block = 256                                        # rows whose number texts are held at a time
        for a in range(0, len(times), block):
            rows = values[a:a + block]
            m = rows.shape[1] if rows.ndim == 2 else 0
            texts = orjson.dumps(rows.ravel().tolist())[1:-1].split(b",") if rows.size else []
            tb = times[a:a + block]
            stamps = [time_ns(t, self.time_scale) for t in tb]
            datas = []
            for i, ns in enumerate(stamps):
                row = texts[i * m:(i + 1) * m] + [b"%d" % (ns % 1_000_000_000), b"%d" % (ns // 1_000_000_000)]
                datas.append(fmt % tuple([row[j] for j in slots]))   # (-1: seconds, -2: nanoseconds)
            self._add_many(channel_id, stamps, datas, tb)

    def write_raw(self, channel_id: int, time_s: float, payload: dict) -> None:
        """Write ``payload`` exactly as given (no ``timestamp`` / ``time_s`` added: a message of a
        well-known schema such as ``foxglove.SceneUpdate``) at log time ``time_s`` (the file's time
        scale).  A missing value (None, NaN, infinity) anywhere is a ValueError: no ``null`` is written."""
        data = json_bytes(payload)
        if b"null" in data and _holds_missing(payload):    # (else the word in a text)
            raise ValueError(f"message at {time_s!r} s on {self._topic[channel_id]}: a missing value (None, NaN or "
                             "infinity)")
        self._add(channel_id, time_ns(time_s, self.time_scale), data)
        self._note(channel_id, float(time_s), None)

    def _note(self, channel_id: int, time_s: float, receiver) -> None:
        """Remember a message's time (and scalar ``receiver``) for :data:`INFO_METADATA`."""
        times = self._times[channel_id]
        src = self._sources.get(channel_id)
        scalar = None if isinstance(receiver, list) or _missing(receiver) else receiver
        if src is None and scalar is not None:
            src = self._sources[channel_id] = [None] * len(times)
        if src is not None:
            src.append(scalar)
        times.append(time_s)

    def _write_info(self) -> None:
        """The :data:`INFO_METADATA` record: per topic with messages its span and sampling period
        (what ``cdgps info`` shows, without reading the messages back), plus :attr:`info_extra`."""
        topics: dict[str, dict] = {}
        for cid, times in self._times.items():
            if len(times):
                t, src = topics.setdefault(self._topic[cid], {"t": [], "src": []}), self._sources.get(cid)
                t["t"].append(np.frombuffer(times, dtype=float))
                t["src"].append(src if src is not None else [None] * len(times))
        out = {}
        for topic, d in sorted(topics.items()):
            t = np.concatenate(d["t"])
            src = [s for part in d["src"] for s in part]
            out[topic] = {"messages": int(t.size), **time_summary(t, src if any(s is not None for s in src) else None)}
        self.metadata(INFO_METADATA, {"format": INFO_FORMAT, "topics": json.dumps(out, sort_keys=True),
                                      **self.info_extra})

    def _add(self, channel_id: int, ns: int, data: bytes) -> None:
        """Add one message (log and publish time ``ns``, the channel's next sequence number)."""
        if self._index_class is None:
            self.writer.add_message(channel_id=channel_id, log_time=ns, publish_time=ns, data=data,
                                    sequence=self._seq[channel_id])
            self._seq[channel_id] += 1
            return
        self._frame(channel_id, ns, data)

    def write_encoded(self, channel_id: int, times_s: list, stamps_ns: list, datas: list,
                      receivers: list | None = None) -> None:
        """Write messages already encoded (each ``datas[i]`` the bytes :meth:`write` would give for
        its payload at ``times_s[i]``, log time ``stamps_ns[i]`` = :func:`time_ns` of it), in order;
        ``receivers[i]``: the payload's scalar ``receiver`` (for :data:`INFO_METADATA`), or None."""
        self._add_many(channel_id, stamps_ns, datas, times_s, receivers)

    def _add_many(self, channel_id: int, stamps_ns: list, datas: list, times_s: list,
                  receivers: list | None = None) -> None:
        """:meth:`_add` and :meth:`_note` (with ``receivers[i]``, or none) of messages of one channel
        in a row: the same bytes, the file statistics updated once and the chunk's state held in locals."""
        if not stamps_ns:
            return
        if self._index_class is None:
            for i, (ns, data, t) in enumerate(zip(stamps_ns, datas, times_s)):
                self._add(channel_id, ns, data)
                self._note(channel_id, t, None if receivers is None else receivers[i])
            return
        w = self.writer
        st, cb, limit, pack = w._Writer__statistics, w._Writer__chunk_builder, self._chunk_size, _MESSAGE_HEAD.pack
        lo, hi = min(stamps_ns), max(stamps_ns)
        if st.message_count == 0 or lo < st.message_start_time:
            st.message_start_time = lo
        if hi > st.message_end_time:
            st.message_end_time = hi
        st.channel_message_counts[channel_id] += len(stamps_ns)
        st.message_count += len(stamps_ns)
        seq = self._seq[channel_id]
        lens = list(map(len, datas))
        ends = list(accumulate([ln + _MESSAGE_HEAD_BYTES for ln in lens]))     # each message's end, from the first's start
        n, i, base = len(datas), 0, 0
        while i < n:                                   # the messages up to the one that fills the chunk, at once
            buf = cb.record_writer._buffer
            at0 = buf.tell()
            j = min(bisect.bisect_right(ends, limit - at0 + base, i) + 1, n)  # (the one ending past the limit too)
            offsets = [at0 - base + e for e in [base, *ends[i:j - 1]]]
            at = at0 - base + ends[j - 1]
            base = ends[j - 1]
            seg = stamps_ns[i:j]
            lo_seg, hi_seg = min(seg), max(seg)        # (as message by message: the first of a chunk sets its start)
            if cb.num_messages == 0 or lo_seg < cb.message_start_time:
                cb.message_start_time = lo_seg
            if hi_seg > cb.message_end_time:
                cb.message_end_time = hi_seg
            index = cb.message_indices.get(channel_id)
            if index is None:
                index = cb.message_indices[channel_id] = self._index_class(channel_id=channel_id, records=[])
            index.records.extend(zip(seg, offsets))
            cb.num_messages += j - i
            parts = [b""] * (2 * (j - i))
            parts[::2] = [pack(_OPCODE_MESSAGE, 22 + ln, channel_id, k, ns, ns)
                          for k, (ns, ln) in enumerate(zip(seg, lens[i:j]), seq)]
            parts[1::2] = datas[i:j]
            buf.write(b"".join(parts))
            seq += j - i
            if at > limit:
                w._Writer__finalize_chunk()            # (a new buffer and indexes: this message filled the chunk)
            i = j
        self._seq[channel_id] = seq
        self._note_many(channel_id, times_s, receivers)

    def _note_many(self, channel_id: int, times_s: list, receivers: list | None) -> None:
        """:meth:`_note` of messages in a row (``receivers`` None: none holds a scalar ``receiver``)."""
        src = self._sources.get(channel_id)
        if receivers is not None:
            if set(map(type, receivers)) == {str}:      # (names: no list, none missing; no Python work per message)
                scalars = list(receivers)
            else:
                scalars = [None if isinstance(r, list) or _missing(r) else r for r in receivers]
            if src is None and any(r is not None for r in scalars):
                src = self._sources[channel_id] = [None] * len(self._times[channel_id])
            if src is not None:
                src.extend(scalars)
        elif src is not None:
            src.extend([None] * len(times_s))
        self._times[channel_id].extend(times_s)

    def _frame(self, channel_id: int, ns: int, data: bytes) -> None:
        """What ``Writer.add_message`` does for a chunked file, without its per-message objects: the
        file statistics, the chunk's time span and message index, the Message record appended to the
        chunk's buffer, and the chunk finished once it exceeds its size (the same bytes;
        ``tests/io/test_mcap_framing.py``)."""
        w = self.writer
        st, cb = w._Writer__statistics, w._Writer__chunk_builder
        if st.message_count == 0 or ns < st.message_start_time:
            st.message_start_time = ns
        if ns > st.message_end_time:
            st.message_end_time = ns
        st.channel_message_counts[channel_id] += 1
        st.message_count += 1
        if cb.num_messages == 0 or ns < cb.message_start_time:
            cb.message_start_time = ns
        if ns > cb.message_end_time:
            cb.message_end_time = ns
        index = cb.message_indices.get(channel_id)
        if index is None:
            index = cb.message_indices[channel_id] = self._index_class(channel_id=channel_id, records=[])
        buf = cb.record_writer._buffer
        at = buf.tell()
        index.records.append((ns, at))
        cb.num_messages += 1
        seq = self._seq[channel_id]
        self._seq[channel_id] = seq + 1
        buf.write(_MESSAGE_HEAD.pack(_OPCODE_MESSAGE, 22 + len(data), channel_id, seq, ns, ns))
        buf.write(data)
        if at + _MESSAGE_HEAD_BYTES + len(data) > self._chunk_size:
            w._Writer__finalize_chunk()

    @staticmethod
    def _encode(msg: dict, payload: dict, arrays, others, time_s) -> bytes:
        """The message's JSON with missing values encoded as the schema says (see :meth:`write`)."""
        for k, v in payload.items():
            if k in arrays:
                msg[k] = v
                _with_validity(msg, k)
            elif k in others or not isinstance(v, list):
                if not _missing(v):
                    msg[k] = _drop_missing(v)
            else:
                if None in v:
                    raise ValueError(f"message at {time_s!r} s: missing values in array field {k!r} whose schema "
                                     f"has no {VALID_SUFFIX} companion")
                msg[k] = v
        data = json_bytes(msg)
        if b"null" not in data:
            return data
        try:                                            # NaN left somewhere, or the word in a text: the strict encoder
            data = _COMPACT_JSON.encode(msg).encode()
        except ValueError:
            bad = [k for k, v in msg.items() if isinstance(v, list) and any(_missing(x) for x in v)]
            raise ValueError(f"message at {time_s!r} s: missing values in array field(s) {', '.join(bad) or '?'} "
                             f"whose schema has no {VALID_SUFFIX} companion") from None
        return data

    def write_table(self, channel_id: int, df, array_columns: list[str],
                    scalar_columns: list[str] = ()) -> int:
        """Write a long table (a DataFrame or a :class:`~cdgps_cli.core.table.Table`, sorted by
        ``time_s``) as one message per distinct time.

        Returns the number of messages written.
        """
        if len(df) == 0:
            return 0
        t = np.asarray(df["time_s"])
        cuts = np.flatnonzero(np.r_[True, t[1:] != t[:-1], True])
        cols = {c: _column_rows(df, c) for c in array_columns}
        scal = {c: _column_values(df, c) for c in scalar_columns}
        bar = progress.bar(len(cuts) - 1, f"writing {self.path.name}", "msg")
        for i in range(0, len(cuts) - 1, _MESSAGES_PER_BLOCK):    # Python lists of a block of rows at a time
            block = cuts[i:i + _MESSAGES_PER_BLOCK + 1]
            r0, r1 = int(block[0]), int(block[-1])
            lists = {c: rows(r0, r1) for c, rows in cols.items()}      # NaN: encoded by write() per the schema
            for a, b in zip(block[:-1].tolist(), block[1:].tolist()):
                payload = {c: scal[c][a] for c in scalar_columns}
                payload.update({c: lists[c][a - r0:b - r0] for c in array_columns})
                self.write(channel_id, t[a], payload)
            bar.update(len(block) - 1)
        bar.close()
        return len(cuts) - 1

    def attach(self, name: str, data: bytes, media_type: str = "text/plain") -> None:
        self.writer.add_attachment(create_time=0, log_time=0, name=name, media_type=media_type, data=data)

    def attach_packed(self, name: str, arr: np.ndarray, delta: int = 0, overwrite: bool = False) -> None:
        """Attach ``arr`` as a packed array (:mod:`cdgps_cli.io.packed_arrays`: byte-shuffled,
        zstd-compressed, lossless; media type ``application/x-cdgps-packed-array``); ``delta``:
        order of the epoch-to-epoch differences taken first (0, 1 or 2); ``overwrite``: ``arr`` is
        a temporary the packing may overwrite (:func:`cdgps_cli.io.packed_arrays.pack_pieces`)."""
        from cdgps_cli.io.packed_arrays import MEDIA_TYPE, pack_pieces  # noqa: PLC0415

        if self._packer is not None:
            self._deferred.append((name, self._packer.submit(pack_pieces, arr, delta, overwrite)))
            return
        pieces = pack_pieces(arr, delta, overwrite)
        self.attach_stream(name, sum(len(p) for p in pieces), pieces, MEDIA_TYPE)

    def pack_in_background(self) -> None:
        """From now on :meth:`attach_packed` packs in a worker thread (numpy's copies and zstd release
        the GIL, so the packing overlaps what the caller does next, e.g. building JSON messages);
        the attachments are written, in the order given, by :meth:`write_packed` or on closing.
        The arrays given must not change until then."""
        from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415

        if self._packer is None:
            self._packer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cdgps-pack")

    def write_packed(self) -> None:
        """Write the attachments packed in the background so far, in the order they were given."""
        from cdgps_cli.io.packed_arrays import MEDIA_TYPE  # noqa: PLC0415

        while self._deferred:
            name, fut = self._deferred.pop(0)
            pieces = fut.result()
            self.attach_stream(name, sum(len(p) for p in pieces), pieces, MEDIA_TYPE)

    def attach_npy(self, name: str, arr: np.ndarray, media_type: str = "application/x-npy",
                   chunk_bytes: int = 1 << 20) -> None:
        """Attach ``arr`` in ``.npy`` format (the bytes of ``np.save``), streamed to the file.

        Neither the ``.npy`` bytes nor the attachment record are built in memory: the array is
        written in pieces of about ``chunk_bytes`` (a C-ordered copy of a few rows at a time when it
        is not contiguous), so a large (N, n, n) slice costs no full-size copy.  The file is the same,
        byte for byte, as ``attach(name, <np.save bytes>, media_type)``.
        """
        arr = np.asanyarray(arr)
        if arr.dtype.hasobject:
            raise ValueError("object arrays cannot be attached as .npy")
        d = np.lib.format.header_data_from_array_1_0(arr)
        head = io.BytesIO()
        try:
            np.lib.format.write_array_header_1_0(head, d)
        except ValueError:                                   # header too long for format 1.0
            np.lib.format.write_array_header_2_0(head, d)
        src = arr.T if d["fortran_order"] else arr           # np.save writes Fortran arrays as-is
        n_rows = src.shape[0] if src.ndim else 1
        row_bytes = max(src.nbytes // max(n_rows, 1), 1)
        step = max(chunk_bytes // row_bytes, 1)

        def pieces():
            yield head.getvalue()
            if src.ndim == 0:
                yield src.tobytes()
                return
            for i in range(0, n_rows, step):
                block = np.ascontiguousarray(src[i:i + step])
                if block.nbytes:
                    yield memoryview(block).cast("B")

        self.attach_stream(name, len(head.getvalue()) + src.nbytes, pieces(), media_type)

    def attach_stream(self, name: str, size: int, pieces, media_type: str = "text/plain") -> None:
        """Attach ``size`` bytes given as an iterable of bytes-like ``pieces``, written as they come.

        Writes the same attachment record, CRCs and index entry as :meth:`attach`, without holding
        the data: the mcap library builds every record in memory (several copies of an attachment),
        so large attachments go straight to the file here.  Falls back to :meth:`attach` when the
        installed mcap writer does not have the internals this relies on.
        """
        w = self.writer
        if not _streaming_supported(w, self._fh):
            data = b"".join(bytes(p) for p in pieces)
            if len(data) != size:
                raise ValueError(f"attachment {name!r}: expected {size} bytes, got {len(data)}")
            self.attach(name, data, media_type)
            return
        w._Writer__flush()                     # records built so far go out first (as add_attachment does)
        fh = self._fh
        offset = fh.tell()
        name_b, media_b = name.encode(), media_type.encode()
        body_len = 8 + 8 + 4 + len(name_b) + 4 + len(media_b) + 8 + size + 4
        head = (struct.pack("<BQ", _OPCODE_ATTACHMENT, body_len) + struct.pack("<QQ", 0, 0)
                + struct.pack("<I", len(name_b)) + name_b + struct.pack("<I", len(media_b)) + media_b
                + struct.pack("<Q", size))
        data_crcs = bool(w._Writer__enable_data_crcs)
        section_crc = w._Writer__data_section_crc

        def put(b):
            nonlocal section_crc
            fh.write(b)
            if data_crcs:
                section_crc = zlib.crc32(b, section_crc)

        put(head)
        crc = zlib.crc32(head[9:])
        written = 0
        for p in pieces:
            crc = zlib.crc32(p, crc)
            put(p)
            written += len(p)
        if written != size:
            raise ValueError(f"attachment {name!r}: expected {size} bytes, got {written}")
        put(struct.pack("<I", crc))
        w._Writer__data_section_crc = section_crc
        w._Writer__statistics.attachment_count += 1
        from mcap.writer import IndexType  # noqa: PLC0415

        if w._Writer__index_types & IndexType.ATTACHMENT:
            w._Writer__attachment_indexes.append(AttachmentIndex(
                offset=offset, length=9 + body_len, create_time=0, log_time=0, data_size=size,
                name=name, media_type=media_type))

    def metadata(self, name: str, data: dict) -> None:
        """Write a metadata record (values as strings) with its own ``record_sha256``
        (:func:`cdgps_cli.io.mcap_integrity.record_sha256`: MCAP metadata records have no CRC)."""
        if RECORD_SHA256_KEY in data:
            raise ValueError(f"metadata {name!r}: the key {RECORD_SHA256_KEY!r} is reserved")
        rec = {str(k): str(v) for k, v in data.items()}
        rec[RECORD_SHA256_KEY] = record_sha256(name, rec)
        self.writer.add_metadata(name=name, data=rec)

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                self.write_packed()              # attachments still packing in the background
                self._write_info()
                self.writer.finish()
                if self._anonymous:
                    link_anonymous(self._fh, self.path)
            self._fh.close()
            if exc_type is None and not self._anonymous:
                os.replace(self.tmp, self.path)
        except OSError as err:                  # full disk, file-size limit while finishing
            raise output_error(self.path, err) from None
        finally:
            if self._packer is not None:
                self._packer.shutdown(wait=True, cancel_futures=True)
                self._deferred.clear()
            if not self._fh.closed:             # (an array that could not be packed)
                self._fh.close()
            if self.tmp.exists():
                self.tmp.unlink()
        if isinstance(exc, OSError) and is_no_room(exc):   # the same while writing messages
            raise output_error(self.path, exc) from None


class TopicColumns:
    """Messages of one topic accumulated column-wise while reading (memory-lean).

    ``scalars[name]`` holds one value per message (None where a message lacks the key);
    array fields are appended to one flat growing buffer per field (8-byte floats, None → NaN;
    strings as 4-byte integer codes into a per-field vocabulary), so a million elements cost
    8 MB and no per-message objects; :meth:`column` returns their concatenation as numpy;
    ``counts`` is the array length of each message.
    """

    def __init__(self):
        self.scalars: dict[str, list] = {}
        self._buf: dict[str, array] = {}
        self._vocab: dict[str, dict] = {}
        self.counts: list[int] = []

    def add(self, msg: dict) -> None:
        n = None
        count = len(self.counts)
        for k, v in msg.items():
            if isinstance(v, list):
                n = len(v) if n is None else n
                if not v:
                    continue
                buf = self._buf.get(k)
                if isinstance(v[0], str):
                    if buf is None:
                        buf = self._buf[k] = array("i")
                        self._vocab[k] = {}
                    elif k not in self._vocab:
                        raise ValueError(f"field {k!r}: strings after numbers")
                    vocab = self._vocab[k]
                    try:
                        buf.extend([vocab.setdefault(e, len(vocab)) for e in v])
                    except TypeError:                         # unhashable element
                        raise ValueError(f"field {k!r}: mixed array elements") from None
                else:
                    if buf is None:
                        buf = self._buf[k] = array("d")
                    elif k in self._vocab:
                        raise ValueError(f"field {k!r}: numbers after strings")
                    size = len(buf)
                    try:
                        buf.extend(v)
                    except TypeError:                         # None (→ NaN), nested or mixed lists
                        del buf[size:]                        # extend stops part way: undo
                        vals = np.array(v, dtype=float)
                        if vals.ndim != 1:
                            raise ValueError(f"field {k!r}: nested arrays are not supported") from None
                        buf.frombytes(vals.tobytes())
            elif k != "timestamp":
                col = self.scalars.get(k)
                if col is None:
                    col = self.scalars[k] = [None] * count      # a key first seen now: backfill
                col.append(v)
        for k, col in self.scalars.items():
            if len(col) == count:                             # a key this message lacks
                col.append(None)
        self.counts.append(0 if n is None else n)

    def __len__(self) -> int:
        return len(self.counts)

    def times(self) -> np.ndarray:
        return np.asarray(self.scalars.get("time_s", []), dtype=float)

    def column(self, name: str) -> np.ndarray:
        """Concatenation of an array field over all messages (object array for strings).

        Numbers whose ``<name>_valid`` companion is false come back as NaN (as ``null`` elements
        of files written before the companions did).
        """
        buf = self._buf.get(name)
        if not buf:
            return np.array([], dtype=float)
        if name in self._vocab:
            words = np.empty(len(self._vocab[name]), dtype=object)
            for w, i in self._vocab[name].items():
                words[i] = w
            return words[np.frombuffer(buf, dtype=np.int32)]
        out = np.frombuffer(buf, dtype=float).copy()          # a copy: the buffer may still grow
        valid = self._buf.get(name + VALID_SUFFIX)
        if valid is not None and name + VALID_SUFFIX not in self._vocab:
            if len(valid) != out.size:
                raise ValueError(f"field {name!r}: {out.size} values but {len(valid)} {name}{VALID_SUFFIX} flags")
            out[np.frombuffer(valid, dtype=float) == 0.0] = np.nan
        return out

    def table(self, array_columns: list[str], scalar_columns: list[str] = ()) -> Table:
        """Long table: one row per array element, scalars repeated (inverse of write_table).

        Columns time_s, the scalars, then the arrays; a string field is a name column, a field
        never seen an empty number column.

        Raises
        ------
        ValueError
            A scalar field that mixes strings with other values on rows of the table.
        """
        counts = np.asarray(self.counts, dtype=np.int64)
        numbers = {"time_s": np.repeat(self.times(), counts)}
        names = {}
        used = counts > 0                                     # messages that give rows
        for c in scalar_columns:                              # one value per message, then repeated
            vals = [v for v, u in zip(self.scalars.get(c, [None] * len(counts)), used.tolist()) if u]
            if vals and all(isinstance(v, str) for v in vals):
                words, codes = np.unique(np.array(vals, dtype=str), return_inverse=True)
                names[c] = (np.repeat(codes, counts[used]), words.tolist())
            else:
                try:
                    per_message = np.array([np.nan if v is None else v for v in vals], dtype=float)
                except (TypeError, ValueError):
                    raise ValueError(f"field {c!r}: strings mixed with other values") from None
                numbers[c] = np.repeat(per_message, counts[used])
        for c in array_columns:
            if c in self._vocab and self._buf.get(c):
                words = sorted(self._vocab[c], key=self._vocab[c].get)
                names[c] = (np.frombuffer(self._buf[c], dtype=np.int32).copy(), words)
            else:
                numbers[c] = self.column(c)
        return Table(numbers, names, ["time_s", *scalar_columns, *array_columns])


@dataclass
class McapContents:
    """What :func:`read_mcap` returns: messages per topic (column-wise), attachments and metadata."""

    path: str
    topics: dict            # topic → TopicColumns (log-time order)
    attachments: dict       # name → bytes
    metadata: dict          # name → dict[str, str]
    schemas: dict           # topic → (schema name, encoding)
    message_encoding: dict  # topic → encoding
    channel_metadata: dict = field(default_factory=dict)  # topic → dict[str, str] (e.g. time_scale)
    channels: frozenset = frozenset()   # every topic registered in the file (also those without messages)
    attachment_offsets: dict = field(default_factory=dict)  # name → (offset, length, data size) of those left on disk

    def has_attachment(self, name: str) -> bool:
        """Whether the file holds the attachment ``name`` (in memory or left on disk)."""
        return name in self.attachments or name in self.attachment_offsets

    def attachment(self, name: str) -> bytes:
        """The attachment ``name``'s data: from memory, or read from the file now (one record, its CRC checked:
        :func:`read_mcap`'s ``attachments`` left it there, issue 29); KeyError when the file has none."""
        if name in self.attachments:
            return self.attachments[name]
        offset, length, size = self.attachment_offsets[name]
        with open(self.path, "rb") as fh:
            return attachment_at(fh, offset, length, size, name, self.path)

    def require_channels(self, *topics: str, what: str = "cdgps file") -> None:
        """Refuse the file unless every topic in ``topics`` has a channel (a CdgpsError naming them)."""
        missing = [t for t in topics if t not in self.channels]
        if missing:
            raise CdgpsError(f"{self.path}: no {', '.join(missing)} channel; expected in a {what} "
                             f"(damaged or not written by cdgps)")

    def require_metadata(self, name: str, what: str = "cdgps file") -> dict:
        """The metadata record ``name``, or a CdgpsError naming the file and the record."""
        if name not in self.metadata:
            raise CdgpsError(f"{self.path}: no {name!r} metadata record; expected in a {what} "
                             f"(damaged or not written by cdgps)")
        return self.metadata[name]


def _check_attachment_crcs(fh, summary, path, zero_ok: bool = True) -> None:
    """Validate every attachment's CRC-32 (the mcap library writes it but does not check it);
    a CRC of 0 ("not computed") is refused unless ``zero_ok`` (the data-section CRC covered it)."""
    for idx in summary.attachment_indexes:
        fh.seek(idx.offset)
        raw = fh.read(idx.length)
        if len(raw) != idx.length or len(raw) < 13:
            raise CdgpsError(f"{path}: attachment {idx.name!r} is truncated")
        content = raw[9:]                      # opcode (1) + record length (8)
        stored = struct.unpack("<I", content[-4:])[0]
        if stored == 0 and not zero_ok:
            raise CdgpsError(f"{path}: attachment {idx.name!r} has no CRC and the file no data-section CRC: "
                             f"its bytes cannot be checked")
        if stored != 0 and zlib.crc32(content[:-4]) != stored:
            raise CdgpsError(f"{path}: attachment {idx.name!r} fails its CRC check (corrupt file)")


def _message_count(summary, topics) -> int | None:
    """Messages of ``topics`` (None: all) from the summary's statistics (for progress only)."""
    st = summary.statistics
    if st is None or topics == []:
        return None if st is None else 0
    if topics is None:
        return int(st.message_count)
    want = {cid for cid, ch in summary.channels.items() if ch.topic in topics}
    return int(sum(n for cid, n in st.channel_message_counts.items() if cid in want))


class _InputBoundedFile:
    """A read-only view of an open file whose ``read(n)`` never asks for more than the bytes left.

    The mcap reader allocates a record from its length field; a flipped length (2**63) then asks
    for exabytes (MemoryError / OverflowError).  Clamped to the file size, such a read comes back
    short and the reader reports the truncation it sees."""

    def __init__(self, fh):
        self._fh = fh
        self._size = os.fstat(fh.fileno()).st_size

    def __getattr__(self, name):                  # seek, tell, seekable, ...: the file's own
        return getattr(self._fh, name)

    def read(self, n: int = -1) -> bytes:
        left = max(self._size - self._fh.tell(), 0)
        return self._fh.read(left if n is None or n < 0 else min(n, left))

    def readinto(self, b) -> int:
        left = max(self._size - self._fh.tell(), 0)
        view = memoryview(b).cast("B")
        return self._fh.readinto(view[:left] if len(view) > left else view)


#: what the mcap reader and its decompressors raise on damaged bytes (zstd/lz4 data errors,
#: lengths past the file, a decompressed size that cannot be allocated)
_CORRUPT_MCAP_ERRORS = (McapError, EOFError, ValueError, KeyError, IndexError, struct.error, OSError,
                        UnicodeDecodeError, MemoryError, OverflowError, zstandard.ZstdError)


@contextlib.contextmanager
def open_verified(path: str | Path):
    """Open an MCAP file for reading after checking its integrity
    (:func:`cdgps_cli.io.mcap_integrity.verify_file`: magic, footer, summary and data-section CRCs).

    Yields ``(reader, fh, integrity, summary)``; ``integrity.metadata`` holds the metadata records,
    each verified (:func:`~cdgps_cli.io.mcap_integrity.check_records`).  Any damage met inside the
    block, or while opening, becomes a CdgpsError naming the file.
    """
    p = Path(path)
    if not p.is_file():
        raise CdgpsError(f"{p}: no such file")
    try:
        with open(p, "rb") as raw:
            fh = _InputBoundedFile(raw)
            try:
                info = verify_file(fh, p)
            except DataSectionDamage as exc:
                raise CdgpsError(f"{exc}{_where_damaged(fh, p)}") from None
            warn_once(info)
            fh.seek(0)
            reader = make_reader(fh, validate_crcs=True)
            summary = reader.get_summary()
            if summary is None:
                raise CdgpsError(f"{p}: MCAP file has no summary section (truncated or not written by a complete run)")
            info.metadata = check_records(reader.iter_metadata(), info, p)
            yield reader, fh, info, summary
    except CdgpsError:
        raise
    except _CORRUPT_MCAP_ERRORS as exc:
        raise CdgpsError(f"{p}: not a valid MCAP file (truncated or corrupt): {type(exc).__name__}: "
                         f"{str(exc)[:200]}") from None


def _is_foxglove(schema) -> bool:
    """A channel of one of Foxglove's own message schemas (``foxglove.*``, e.g. the 3-D scene)."""
    return schema is not None and schema.name.startswith("foxglove.")


def _where_damaged(fh, path) -> str:
    """Where a data section that fails its CRC is damaged, from the summary (its own CRC passed):
    ``"; damaged: the chunk of the messages logged at … (byte N)"`` for the first chunk whose header,
    decompression or CRC fails, or the attachment whose CRC fails; "" when neither says (issue 29:
    bad input mid-stream names the file and the time)."""
    try:
        fh.seek(0)
        summary = make_reader(fh, validate_crcs=False).get_summary()
    except Exception:  # noqa: BLE001 (the summary was checked; anything else: no more to say)
        return ""
    if summary is None:
        return ""

    def fail(what: str) -> CdgpsError:
        return CdgpsError(what)

    scales = {(ch.metadata or {}).get("time_scale", "relative") for ch in summary.channels.values()}
    for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        try:
            records_at, crc = _chunk_header(fh, ci, fail)
            _check_chunk(fh, records_at, ci.compressed_size, ci, crc, {}, fail)
        except CdgpsError:
            return f"; damaged: the chunk of the messages logged {_log_span(ci, scales)} (byte {ci.chunk_start_offset})"
    try:
        _check_attachment_crcs(fh, summary, path)
    except CdgpsError as exc:
        return f"; damaged: {str(exc).split(': ', 1)[-1]}"
    return ""


def _log_span(ci, scales: set) -> str:
    """A chunk's log-time span in words: run seconds for a relative run, else UTC."""
    a, b = ci.message_start_time, ci.message_end_time
    if scales == {"relative"}:
        return f"at {a / 1e9:g}–{b / 1e9:g} s of the run"
    import datetime as dt  # noqa: PLC0415

    def utc(ns):
        return dt.datetime.fromtimestamp(ns / 1e9, dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    return f"from {utc(a)} to {utc(b)}"


def read_mcap(path: str | Path, topics: list[str] | None = None, attachments=None) -> McapContents:
    """Read an MCAP file, every byte checked before any value is used (:func:`open_verified`,
    chunk and attachment CRCs, each metadata record's ``record_sha256``).

    ``topics`` None: every channel but those of Foxglove's own schemas (``foxglove.*``, nested
    messages that do not fit :class:`TopicColumns`; read them with the ``mcap`` reader).
    ``attachments(name) -> bool``, when given, chooses the attachments kept in memory (every one's
    CRC is still checked); the others are left on disk, read one at a time by :meth:`McapContents.attachment`.

    Raises
    ------
    CdgpsError
        If the file is missing, not an MCAP file, truncated or fails a check.
    """
    p = Path(path)
    cols: dict = {}
    schemas, encodings, chan_meta = {}, {}, {}
    with open_verified(p) as (reader, fh, info, summary):
        if topics is None:          # every cdgps channel; a Foxglove message (foxglove.SceneUpdate) is not a column set
            topics = [ch.topic for ch in summary.channels.values()
                      if not _is_foxglove(summary.schemas.get(ch.schema_id))]
        messages = reader.iter_messages(topics=topics) if topics != [] else ()
        for schema, channel, message in progress.iterate(messages, f"reading {p.name}",
                                                          _message_count(summary, topics), "msg"):
            acc = cols.get(channel.topic)
            if acc is None:
                acc = cols[channel.topic] = TopicColumns()
                schemas[channel.topic] = (schema.name if schema else "", schema.encoding if schema else "")
                encodings[channel.topic] = channel.message_encoding
                chan_meta[channel.topic] = dict(channel.metadata or {})
            acc.add(json.loads(message.data))
        if not info.data_section_crc_checked:      # (else every attachment's bytes are in the checked section)
            _check_attachment_crcs(fh, summary, p, zero_ok=False)
        keep = attachments or (lambda name: True)
        left = {a.name: (a.offset, a.length, a.data_size) for a in summary.attachment_indexes if not keep(a.name)}
        attachments = {a.name: attachment_at(fh, a.offset, a.length, a.data_size, a.name, p)
                       for a in summary.attachment_indexes if keep(a.name)}
        channels = frozenset(ch.topic for ch in summary.channels.values())
    return McapContents(str(p), cols, attachments, info.metadata, schemas, encodings, chan_meta, channels, left)


_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_MESSAGE = int(Opcode.CHUNK), int(Opcode.MESSAGE_INDEX), int(Opcode.MESSAGE)
_CHUNK_HEAD = struct.Struct("<BQQQQI")        # opcode, length, message start/end time, uncompressed size, crc


@dataclass
class IndexCounts:
    """What :func:`check_indexes` read from the message indexes: per channel id the number of
    messages and the first and last log time (Unix ns)."""

    messages: dict
    first_ns: dict
    last_ns: dict


def check_indexes(fh, summary, path, chunk_crcs: bool = False) -> IndexCounts:
    """Check the summary's indexes and statistics against the file without decoding a message.

    Every chunk index must point at a Chunk record inside the data section whose header (times,
    sizes, compression) it repeats, chunks must not overlap, and each chunk's Message Index records
    must sit where the chunk index says, name known channels and list offsets inside the chunk and
    log times inside its time range; the Statistics record must agree with all of them (message,
    chunk, channel, schema, attachment and metadata counts; per-channel counts; first and last log
    time).  With ``chunk_crcs`` every chunk is also decompressed and its CRC checked, and each
    indexed offset must hold a Message record of that channel and log time (the check the data-section
    CRC makes redundant for a file that has one: cdgps then leaves it to ``cdgps info --deep``).

    Parameters
    ----------
    fh : binary file
        The open, already verified file (:func:`open_verified`).
    summary : mcap Summary
    path : path
        Named in the errors.
    chunk_crcs : bool
        Decompress every chunk and check its CRC and message offsets.

    Raises
    ------
    CdgpsError
        Naming the file and the inconsistent record.
    """
    def bad(what: str) -> CdgpsError:
        return CdgpsError(f"{path}: MCAP index check failed: {what} (corrupt file)")

    st = summary.statistics
    if st is None:
        raise bad("no Statistics record in the summary")
    size = os.fstat(fh.fileno()).st_size
    fh.seek(size - 8 - 4 - 8 - 8)
    data_end = struct.unpack("<Q", fh.read(8))[0] - 13          # footer's summary start − Data End record
    counts: dict = {}
    first: dict = {}
    last: dict = {}
    prev_end = len(b"\x89MCAP0\r\n")
    for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        start, end = ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length
        if start < prev_end or end + ci.message_index_length > data_end:
            raise bad(f"chunk at byte {start} overlaps another record or lies outside the data section")
        prev_end = end + ci.message_index_length
        records_at, crc = _chunk_header(fh, ci, bad)
        fh.seek(end)
        found = _message_indexes(fh.read(ci.message_index_length), end, ci, summary, bad)
        if chunk_crcs:
            _check_chunk(fh, records_at, ci.compressed_size, ci, crc, found, bad)
        for cid, (log_ns, _offsets) in found.items():
            if log_ns.size:
                counts[cid] = counts.get(cid, 0) + int(log_ns.size)
                first[cid] = min(first.get(cid, log_ns.min()), log_ns.min())
                last[cid] = max(last.get(cid, log_ns.max()), log_ns.max())
    _check_statistics(st, summary, counts, first, last, bad)
    return IndexCounts(counts, {k: int(v) for k, v in first.items()}, {k: int(v) for k, v in last.items()})


def _chunk_header(fh, ci, bad) -> tuple:
    """Check a Chunk record's header against its chunk index; returns (offset of its compressed
    records, its CRC)."""
    comp = ci.compression.encode()
    fh.seek(ci.chunk_start_offset)
    head = fh.read(_CHUNK_HEAD.size + 4 + len(comp) + 8)
    if len(head) < _CHUNK_HEAD.size + 4 + len(comp) + 8:
        raise bad(f"chunk at byte {ci.chunk_start_offset} is truncated")
    op, length, t0, t1, usize, crc = _CHUNK_HEAD.unpack_from(head)
    n = struct.unpack_from("<I", head, _CHUNK_HEAD.size)[0]
    rec_len = struct.unpack_from("<Q", head, _CHUNK_HEAD.size + 4 + len(comp))[0]
    if (op != _OP_CHUNK or length != ci.chunk_length - 9 or (t0, t1) != (ci.message_start_time, ci.message_end_time)
            or usize != ci.uncompressed_size or n != len(comp) or head[_CHUNK_HEAD.size + 4:][:n] != comp
            or rec_len != ci.compressed_size or len(head) + rec_len != ci.chunk_length):
        raise bad(f"chunk at byte {ci.chunk_start_offset} differs from its chunk index")
    return ci.chunk_start_offset + len(head), crc


def _check_statistics(st, summary, counts: dict, first: dict, last: dict, bad) -> None:
    """The Statistics record against the message indexes (counts, first and last log time) and the summary."""
    total = sum(counts.values())
    stated = {cid: int(k) for cid, k in st.channel_message_counts.items() if k}
    if stated != counts or st.message_count != total:
        raise bad(f"Statistics counts ({st.message_count} messages, per channel {stated}) differ from the "
                  f"message indexes ({total}, {counts})")
    expected = {"chunk_count": len(summary.chunk_indexes), "channel_count": len(summary.channels),
                "schema_count": len(summary.schemas), "attachment_count": len(summary.attachment_indexes),
                "metadata_count": len(summary.metadata_indexes)}
    for k, v in expected.items():
        if getattr(st, k) != v:
            raise bad(f"Statistics {k} {getattr(st, k)} but the summary lists {v}")
    if total and (st.message_start_time, st.message_end_time) != (min(first.values()), max(last.values())):
        raise bad("Statistics message start/end times differ from the message indexes")


def _message_indexes(raw: bytes, at: int, ci, summary, bad) -> dict:
    """Parse a chunk's Message Index records: ``{channel id: (log times, offsets)}`` (uint64 arrays)."""
    out, pos, where = {}, 0, {}
    while pos < len(raw):
        if len(raw) - pos < 15 or raw[pos] != _OP_MESSAGE_INDEX:
            raise bad(f"damaged message index at byte {at + pos}")
        length, cid, nbytes = struct.unpack_from("<QHI", raw, pos + 1)
        if length != 2 + 4 + nbytes or nbytes % 16 or pos + 9 + length > len(raw) or cid in out:
            raise bad(f"damaged message index at byte {at + pos}")
        if cid not in summary.channels:
            raise bad(f"message index at byte {at + pos} names channel {cid}, which the summary does not list")
        pairs = np.frombuffer(raw, dtype="<u8", count=nbytes // 8, offset=pos + 15).reshape(-1, 2)
        log_ns, offsets = pairs[:, 0], pairs[:, 1]
        if log_ns.size and (log_ns.min() < ci.message_start_time or log_ns.max() > ci.message_end_time
                            or offsets.max() >= ci.uncompressed_size):
            raise bad(f"message index at byte {at + pos} lists messages outside its chunk")
        where[cid] = at + pos
        out[cid] = (log_ns, offsets)
        pos += 9 + length
    if where != dict(ci.message_index_offsets):
        raise bad(f"the chunk index of the chunk at byte {ci.chunk_start_offset} does not match its message indexes")
    return out


def _check_chunk(fh, records_at: int, rec_len: int, ci, crc: int, found: dict, bad) -> None:
    """Decompress one chunk, check its CRC and that every indexed offset holds a Message record of
    the indexed channel and log time."""
    fh.seek(records_at)
    comp = fh.read(rec_len)
    try:
        if ci.compression == "zstd":
            data = zstandard.ZstdDecompressor().decompress(comp, max_output_size=ci.uncompressed_size)
        elif ci.compression == "":
            data = comp
        else:                                               # another writer's lz4 (as the mcap reader)
            import lz4.frame  # noqa: PLC0415

            data = lz4.frame.decompress(comp)
    except Exception as exc:  # noqa: BLE001 (any decompressor error is damage)
        raise bad(f"chunk at byte {ci.chunk_start_offset} does not decompress ({type(exc).__name__})") from None
    if len(data) != ci.uncompressed_size or (crc != 0 and zlib.crc32(data) != crc):
        raise bad(f"chunk at byte {ci.chunk_start_offset} fails its CRC check")
    buf = np.frombuffer(data, dtype=np.uint8)
    for cid, (log_ns, offsets) in found.items():
        off = offsets.astype(np.int64)
        if off.size == 0:
            continue
        if (off + 9 + 14 > buf.size).any() or (buf[off] != _OP_MESSAGE).any():
            raise bad(f"message index of the chunk at byte {ci.chunk_start_offset} points outside its Message records")
        ch = buf[off + 9].astype(np.uint16) | (buf[off + 10].astype(np.uint16) << 8)
        t = np.zeros(off.size, dtype=np.uint64)
        for k in range(8):
            t |= buf[off + 15 + k].astype(np.uint64) << np.uint64(8 * k)
        if (ch != cid).any() or (t != log_ns).any():
            raise bad(f"message index of the chunk at byte {ci.chunk_start_offset} disagrees with its Message records")


def read_attachment(fh, summary, name: str, path) -> bytes:
    """The data of the attachment ``name`` (the last of that name, as :func:`read_mcap` keeps),
    read through its index entry alone; its record framing and CRC (when not 0) are checked."""
    idx = [a for a in summary.attachment_indexes if a.name == name][-1]
    return attachment_at(fh, idx.offset, idx.length, idx.data_size, name, path)


def attachment_at(fh, offset: int, record_length: int, data_size: int, name: str, path) -> bytes:
    """The data of the attachment record ``name`` at byte ``offset`` of the open file ``fh`` (``record_length`` bytes
    of record and ``data_size`` of data, as its index entry says); its framing, name and CRC (when not 0) checked — a
    CdgpsError naming the file and the attachment otherwise (e.g. a file changed since it was verified)."""
    fh.seek(offset)
    raw = fh.read(record_length)
    try:
        op, length, _lt, _ct, n = struct.unpack_from("<BQQQI", raw)
        pos = 1 + 8 + 8 + 8 + 4
        got_name = raw[pos:pos + n].decode("utf-8")
        pos += n
        m = struct.unpack_from("<I", raw, pos)[0]
        pos += 4 + m
        size = struct.unpack_from("<Q", raw, pos)[0]
        pos += 8
        data, stored = raw[pos:pos + size], struct.unpack_from("<I", raw, pos + size)[0]
    except (struct.error, UnicodeDecodeError):
        raise CdgpsError(f"{path}: attachment {name!r} is truncated or damaged (corrupt file)") from None
    if (op != int(Opcode.ATTACHMENT) or length + 9 != record_length or len(raw) != record_length or got_name != name
            or size != data_size
            or pos + size + 4 != len(raw)):
        raise CdgpsError(f"{path}: attachment {name!r} differs from its index entry (corrupt file)")
    if stored != 0 and zlib.crc32(raw[9:pos + size]) != stored:
        raise CdgpsError(f"{path}: attachment {name!r} fails its CRC check (corrupt file)")
    return data


def attachment_spans(fh, summary, path) -> dict:
    """Where each attachment's content is in an open MCAP file: name → (offset, length), bytes.

    Read from the attachment index and each record's header (no content is read), so one large
    attachment can then be read in pieces (:func:`read_span`).  A header that disagrees with its
    index (lengths past the record) is a CdgpsError naming the file and the attachment."""
    spans = {}
    for idx in summary.attachment_indexes:
        fh.seek(idx.offset + 9 + 16)                   # opcode, record length, log and create times
        try:
            (n_name,) = struct.unpack("<I", fh.read(4))
            fh.seek(n_name, os.SEEK_CUR)
            (n_media,) = struct.unpack("<I", fh.read(4))
            fh.seek(n_media, os.SEEK_CUR)
            (n_data,) = struct.unpack("<Q", fh.read(8))
        except struct.error:
            raise CdgpsError(f"{path}: attachment {idx.name!r} is truncated") from None
        start = fh.tell()
        if start + n_data + 4 != idx.offset + idx.length:
            raise CdgpsError(f"{path}: attachment {idx.name!r}: its record disagrees with the attachment index "
                             f"(corrupt file)")
        spans[idx.name] = (start, n_data)
    return spans


def read_span(fh, offset: int, length: int):
    """A ``read(n)`` over ``length`` bytes of ``fh`` from ``offset`` (each call reads on from where
    the last stopped; never past the span)."""
    pos = [offset]
    end = offset + length

    def read(n: int) -> bytes:
        n = max(min(n, end - pos[0]), 0)
        data = os.pread(fh.fileno(), n, pos[0])
        pos[0] += len(data)
        return data
    return read
