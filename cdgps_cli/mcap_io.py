"""MCAP containers shared by every stage (RUN.mcap from ingest, later STATES.mcap).

Layout written by :class:`McapOut`:

* zstd-compressed chunks, chunk and data-section CRCs, full summary and indexes;
* JSON-schema channels (schema encoding ``jsonschema``, message encoding ``json``) so Foxglove can
  open the file; one message per epoch per topic, the epoch's channels as arrays, with a
  ``timestamp {sec, nsec}`` field (log time = publish time = that timestamp);
* attachments (e.g. the structure config ``config.toml``) and metadata records.

Files are written under a temporary name in the target directory and renamed when complete, so a
failed run never leaves a half-written output.  Readers always validate CRCs and turn any
corruption or truncation into a :class:`CdgpsError`.
"""

from __future__ import annotations

import json
import os
import struct
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from .atomic import temporary_name
from .errors import CdgpsError

PHASE_TOPIC = "/cdgps/phase"
GYRO_TOPIC = "/cdgps/gyro"
ACTUATOR_TOPIC = "/cdgps/actuators"
CONFIG_ATTACHMENT = "config.toml"

_TS = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}


def array_schema(title: str, fields: dict[str, str], scalars: dict[str, str] | None = None) -> dict:
    """JSON schema of an epoch message: ``timestamp``, ``time_s``, scalars and per-channel arrays."""
    props = {"timestamp": _TS, "time_s": {"type": "number", "description": "seconds"}}
    for k, t in (scalars or {}).items():
        props[k] = {"type": t}
    for k, t in fields.items():
        props[k] = {"type": "array", "items": {"type": t} if t != "number|null" else {"type": ["number", "null"]}}
    return {"title": title, "type": "object", "properties": props}


PHASE_SCHEMA = array_schema(
    "cdgps.DifferentialPhase",
    {"receiver": "string", "antenna": "string", "transmitter": "string", "phase_cycles": "number",
     "lock": "integer", "snr_dbhz": "number|null"},
    {"master": "string"},
)
GYRO_SCHEMA = array_schema("cdgps.RateGyro", {"gyro": "string", "rate_rad_s": "number"})
ACTUATOR_SCHEMA = array_schema("cdgps.ThrusterCommand", {"actuator": "string", "force_n": "number"})


def time_ns(time_s: float) -> int:
    """Seconds → integer nanoseconds (log time); rounds to the nearest nanosecond."""
    return int(round(float(time_s) * 1e9))


def timestamp(time_s: float) -> dict:
    ns = time_ns(time_s)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _clean(v):
    """JSON-safe scalar (NaN → null)."""
    return None if isinstance(v, float) and v != v else v


class McapOut:
    """Atomic MCAP writer (context manager).

    Examples
    --------
    >>> with McapOut("run.mcap") as out:                        # doctest: +SKIP
    ...     ch = out.channel("/cdgps/phase", PHASE_SCHEMA)
    ...     out.write(ch, 0.1, {"phase_cycles": [0.25]})
    """

    def __init__(self, path: str | Path, profile: str = "cdgps"):
        self.path = Path(path)
        self.tmp = temporary_name(self.path)
        self.profile = profile
        self._schemas: dict[str, int] = {}
        self._seq: dict[int, int] = {}

    def __enter__(self) -> "McapOut":
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.tmp, "wb")
        except OSError as exc:
            raise CdgpsError(f"{self.path}: cannot write: {exc.strerror}") from None
        self.writer = Writer(self._fh, compression=CompressionType.ZSTD, enable_crcs=True,
                             enable_data_crcs=True, chunk_size=1 << 20)
        self.writer.start(profile=self.profile, library="cdgps")
        return self

    def channel(self, topic: str, schema: dict, metadata: dict | None = None) -> int:
        title = schema["title"]
        if title not in self._schemas:
            self._schemas[title] = self.writer.register_schema(
                name=title, encoding="jsonschema", data=json.dumps(schema, sort_keys=True).encode())
        cid = self.writer.register_channel(topic=topic, message_encoding="json",
                                           schema_id=self._schemas[title], metadata=metadata or {})
        self._seq[cid] = 0
        return cid

    def write(self, channel_id: int, time_s: float, payload: dict) -> None:
        ns = time_ns(time_s)
        msg = {"timestamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}, "time_s": float(time_s)}
        msg.update(payload)
        data = json.dumps(msg, separators=(",", ":"), allow_nan=False).encode()
        self.writer.add_message(channel_id=channel_id, log_time=ns, publish_time=ns, data=data,
                                sequence=self._seq[channel_id])
        self._seq[channel_id] += 1

    def write_table(self, channel_id: int, df: pd.DataFrame, array_columns: list[str],
                    scalar_columns: list[str] = ()) -> int:
        """Write a long table (sorted by ``time_s``) as one message per distinct time.

        Returns the number of messages written.
        """
        if len(df) == 0:
            return 0
        t = df["time_s"].to_numpy()
        cuts = np.flatnonzero(np.r_[True, t[1:] != t[:-1], True])
        cols = {c: df[c].to_numpy() for c in array_columns}
        lists = {}
        for c, v in cols.items():
            if v.dtype.kind == "f" and np.isnan(v).any():
                lists[c] = [_clean(x) for x in v.tolist()]
            else:
                lists[c] = v.tolist()
        scal = {c: df[c].to_numpy() for c in scalar_columns}
        for a, b in zip(cuts[:-1], cuts[1:]):
            payload = {c: scal[c][a] for c in scalar_columns}
            payload.update({c: lists[c][a:b] for c in array_columns})
            self.write(channel_id, t[a], payload)
        return len(cuts) - 1

    def attach(self, name: str, data: bytes, media_type: str = "text/plain") -> None:
        self.writer.add_attachment(create_time=0, log_time=0, name=name, media_type=media_type, data=data)

    def metadata(self, name: str, data: dict) -> None:
        self.writer.add_metadata(name=name, data={k: str(v) for k, v in data.items()})

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                self.writer.finish()
            self._fh.close()
            if exc_type is None:
                os.replace(self.tmp, self.path)
        finally:
            if self.tmp.exists():
                self.tmp.unlink()


class TopicColumns:
    """Messages of one topic accumulated column-wise while reading (memory-lean).

    ``scalars[name]`` holds one value per message (None where a message lacks the key);
    array fields are kept as numpy chunks — strings as integer codes into a per-field vocabulary —
    and concatenated on demand by :meth:`column`; ``counts`` is the array length of each message.
    """

    def __init__(self):
        self.scalars: dict[str, list] = {}
        self._chunks: dict[str, list] = {}
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
                if isinstance(v[0], str):
                    vocab = self._vocab.setdefault(k, {})
                    arr = np.fromiter((vocab.setdefault(e, len(vocab)) for e in v), dtype=np.int32, count=len(v))
                else:
                    arr = np.array(v, dtype=float)            # None → NaN
                self._chunks.setdefault(k, []).append(arr)
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
        """Concatenation of an array field over all messages (object array for strings)."""
        chunks = self._chunks.get(name)
        if not chunks:
            return np.array([], dtype=float)
        flat = np.concatenate(chunks)
        if name in self._vocab:
            words = np.empty(len(self._vocab[name]), dtype=object)
            for w, i in self._vocab[name].items():
                words[i] = w
            return words[flat]
        return flat

    def table(self, array_columns: list[str], scalar_columns: list[str] = ()) -> pd.DataFrame:
        """Long table: one row per array element, scalars repeated (inverse of write_table)."""
        counts = np.asarray(self.counts, dtype=np.int64)
        out = {"time_s": np.repeat(self.times(), counts)}
        for c in scalar_columns:
            out[c] = np.repeat(np.array(self.scalars.get(c, []), dtype=object), counts)
        for c in array_columns:
            out[c] = self.column(c)
        return pd.DataFrame(out)


@dataclass
class McapContents:
    """What :func:`read_mcap` returns: messages per topic (column-wise), attachments and metadata."""

    path: str
    topics: dict            # topic → TopicColumns (log-time order)
    attachments: dict       # name → bytes
    metadata: dict          # name → dict[str, str]
    schemas: dict           # topic → (schema name, encoding)
    message_encoding: dict  # topic → encoding


def _check_attachment_crcs(fh, summary, path) -> None:
    """Validate every attachment's CRC-32 (the mcap library writes it but does not check it)."""
    for idx in summary.attachment_indexes:
        fh.seek(idx.offset)
        raw = fh.read(idx.length)
        if len(raw) != idx.length or len(raw) < 13:
            raise CdgpsError(f"{path}: attachment {idx.name!r} is truncated")
        content = raw[9:]                      # opcode (1) + record length (8)
        stored = struct.unpack("<I", content[-4:])[0]
        if stored != 0 and zlib.crc32(content[:-4]) != stored:
            raise CdgpsError(f"{path}: attachment {idx.name!r} fails its CRC check (corrupt file)")


def read_mcap(path: str | Path, topics: list[str] | None = None) -> McapContents:
    """Read an MCAP file with CRC validation.

    Raises
    ------
    CdgpsError
        If the file is missing, not an MCAP file, truncated or fails a CRC check.
    """
    p = Path(path)
    if not p.is_file():
        raise CdgpsError(f"{p}: no such file")
    cols: dict = {}
    schemas, encodings = {}, {}
    try:
        with open(p, "rb") as fh:
            reader = make_reader(fh, validate_crcs=True)
            summary = reader.get_summary()
            if summary is None:
                raise CdgpsError(f"{p}: MCAP file has no summary section (truncated or not written by a complete run)")
            for schema, channel, message in (reader.iter_messages(topics=topics) if topics != [] else ()):
                acc = cols.get(channel.topic)
                if acc is None:
                    acc = cols[channel.topic] = TopicColumns()
                    schemas[channel.topic] = (schema.name if schema else "", schema.encoding if schema else "")
                    encodings[channel.topic] = channel.message_encoding
                acc.add(json.loads(message.data))
            _check_attachment_crcs(fh, summary, p)
            attachments = {a.name: bytes(a.data) for a in reader.iter_attachments()}
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    except CdgpsError:
        raise
    except (McapError, EOFError, ValueError, KeyError, struct.error, OSError, UnicodeDecodeError) as exc:
        raise CdgpsError(f"{p}: not a valid MCAP file (truncated or corrupt): {type(exc).__name__}: {exc}") from None
    return McapContents(str(p), cols, attachments, metadata, schemas, encodings)
