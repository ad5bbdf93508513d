"""RUN.mcap: the ingested, validated recording that every later stage reads, of either kind.

What both kinds share is here: the ``cdgps.ingest`` metadata (:func:`ingest_metadata`: version,
config name/sha256/path, every input's name and sha256, ``kind``), the kind of a file
(:func:`run_kind`, :func:`contents_kind`), reading a RUN of any kind (:func:`read_any_run`) and
``cdgps info`` (:func:`run_info`).  The per-kind parts differ in what they store:

* ``structure`` — native receiver/gyro/actuator CSV logs: :func:`write_run` (the library form of
  ``cdgps ingest``) and :func:`read_run` (tables plus the embedded structure config, so later
  stages need no ``--config``), here;
* ``gnss`` — RINEX/UBX receivers and broadcast ephemerides: :mod:`cdgps_cli.io.gnss_run`
  (``write_gnss_run``, ``read_gnss_run``).
"""

from __future__ import annotations

import io
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cdgps_cli import __version__
from cdgps_cli.io.atomic import file_sha256
from cdgps_cli.config.structure import StructureConfig, parse_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.records import Run
from cdgps_cli.core.table import Deferred, Table
from cdgps_cli.core.time_format import format_time, time_scale
from cdgps_cli.core.timescales import unix_ns
from cdgps_cli.io.mcap import (ACTUATOR_SCHEMA, ACTUATOR_TOPIC, CONFIG_ATTACHMENT, GYRO_SCHEMA, GYRO_TOPIC, INFO_FORMAT,
                      INFO_METADATA, PHASE_SCHEMA, PHASE_TOPIC, McapOut, TopicColumns, check_indexes, read_mcap,
                      read_span, time_summary)

PHASE_ARRAYS = ["receiver", "antenna", "transmitter", "phase_cycles", "lock", "snr_dbhz"]
GYRO_ARRAYS = "arrays/cdgps/gyro/"
PHASE_PACKED = "arrays/cdgps/phase/"
"""Attachment prefix of the phase table as packed arrays (:mod:`cdgps_cli.io.packed_arrays`), one
per column, one row per table row: ``time_s`` (s), ``phase_cycles`` (cycles), ``lock`` (int64),
``snr_dbhz`` (NaN where missing), and ``<name>_code`` (int32) for the name columns receiver,
master, antenna and transmitter, indexing the sorted names listed in ``names.json``.  The same
table as the ``/cdgps/phase`` messages, read without decoding them (files written before these
attachments are read from the messages)."""
PHASE_NAME_COLUMNS = ("receiver", "master", "antenna", "transmitter")
PHASE_COLUMNS = ["time_s", "receiver", "master", "antenna", "transmitter", "phase_cycles", "lock", "snr_dbhz"]


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def _gyro_from_attachments(att: dict) -> Table | None:
    try:
        t = np.load(io.BytesIO(att[GYRO_ARRAYS + "time_s.npy"]), allow_pickle=False)
        r = np.load(io.BytesIO(att[GYRO_ARRAYS + "rate_rad_s.npy"]), allow_pickle=False)
        i = np.load(io.BytesIO(att[GYRO_ARRAYS + "gyro_index.npy"]), allow_pickle=False)
        names = [str(n) for n in json.loads(att[GYRO_ARRAYS + "gyro_names.json"])]
        return Table({"time_s": t, "rate_rad_s": r}, {"gyro": (i, names)}, ["time_s", "gyro", "rate_rad_s"])
    except (KeyError, ValueError, OSError, TypeError):
        return None


INGEST_METADATA = "cdgps.ingest"
INFO_STRUCTURE_KEY = "structure"
"""Key of a structure RUN's :data:`~cdgps_cli.io.mcap.INFO_METADATA` record: JSON ``{"gaps": [...],
"channels": [...]}`` (:func:`epoch_gaps` and the ``channel_summary`` given to :func:`write_run`),
what ``cdgps info`` shows of the phase table without decoding it."""
RUN_KINDS = ("structure", "gnss")


def ingest_metadata(kind: str, cfg, inputs: dict, **extra) -> dict:
    """The ``cdgps.ingest`` metadata record of a RUN of ``kind`` (both kinds write it this way).

    Parameters
    ----------
    kind : {"structure", "gnss"}
    cfg : StructureConfig or GnssConfig
        The config embedded in the run (its name, sha256 and file name are recorded).
    inputs : dict of str to path
        Input files by key: each gives ``<key>`` (file name) and ``<key>_sha256``.
    **extra : str
        Further entries of the record (after the common ones, before the inputs).
    """
    if kind not in RUN_KINDS:
        raise ValueError(f"run kind {kind!r}: expected one of {', '.join(RUN_KINDS)}")
    meta = {"cdgps_version": __version__, "created_by": "cdgps ingest", **({"kind": kind} if kind == "gnss" else {}),
            "config_name": cfg.name, "config_sha256": cfg.sha256,
            "config_path": cfg.path if str(cfg.path).startswith("<") else Path(cfg.path).name, **extra}
    for k, p in inputs.items():
        meta[k] = Path(p).name
        meta[k + "_sha256"] = file_sha256(Path(p))
    return meta


def contents_kind(contents) -> str | None:
    """``"gnss"``, ``"structure"`` or None (not a RUN) of MCAP contents (:func:`~cdgps_cli.io.mcap.read_mcap`)."""
    meta = contents.metadata.get(INGEST_METADATA)
    if (meta or {}).get("kind") == "gnss" or "gnss/receivers.json" in contents.attachments:
        return "gnss"
    return None if meta is None else "structure"


def run_kind(path: str | Path) -> str | None:
    """``"gnss"``, ``"structure"`` or None (no ``cdgps.ingest`` record: not a RUN) of an MCAP file.
    Reads only the metadata records, through :func:`cdgps_cli.io.mcap_integrity.read_metadata`
    (CRCs and the records' checksums verified: a damaged file is a CdgpsError naming it)."""
    from cdgps_cli.io.mcap_integrity import read_metadata  # noqa: PLC0415

    meta = read_metadata(path).get(INGEST_METADATA)
    if meta is None:
        return None
    return "gnss" if meta.get("kind") == "gnss" else "structure"


def read_any_run(path: str | Path, phase: bool = True):
    """A RUN.mcap of either kind: :class:`~cdgps_cli.core.records.Run` (structure; ``phase`` as
    :func:`read_run`) or :class:`~cdgps_cli.io.gnss_run.GnssRun`."""
    if run_kind(path) == "gnss":
        from cdgps_cli.io.gnss_run import read_gnss_run  # noqa: PLC0415

        return read_gnss_run(path)
    return read_run(path, phase=phase)


def _attach_phase_packed(out: McapOut, phase) -> None:
    """The phase table as :data:`PHASE_PACKED` attachments, from the columns ``phase``
    (:class:`_PhaseSink`) kept on disk while the messages were written."""
    phase.attach_packed(out)


_PHASE_DEFERRED = ("receiver", "master", "snr_dbhz")
"""Phase columns :func:`read_run` decodes on first use (``cdgps estimate`` reads none of them)."""
_PHASE_DTYPES = {"time_s": float, "phase_cycles": float, "lock": np.int64, "snr_dbhz": float}


def _phase_from_packed(att: dict, path) -> Table | None:
    """The phase table from the :data:`PHASE_PACKED` attachments (None when the file has none);
    the columns of :data:`_PHASE_DEFERRED` are decoded on first use (their bytes are already
    CRC-checked; damage found then is the same CdgpsError)."""
    from cdgps_cli.io.packed_arrays import unpack  # noqa: PLC0415

    if PHASE_PACKED + "names.json" not in att:
        return None
    what = f"{path}: attachment {PHASE_PACKED}"

    def damaged(exc: Exception) -> CdgpsError:
        return CdgpsError(f"{path}: damaged phase arrays ({PHASE_PACKED}*): {exc}")

    def column(source: dict, key: str, n: int | None = None, dtype=None) -> np.ndarray:
        try:
            arr = unpack(source[PHASE_PACKED + key], what + key)
            if n is not None and arr.shape != (n,):
                raise ValueError(f"{what}{key}: {list(arr.shape)} values for {n} rows")
            return arr if dtype is None else arr.astype(dtype, copy=False)
        except (KeyError, TypeError, ValueError) as exc:
            raise damaged(exc) from None

    def later(key: str, n: int, dtype=None) -> Deferred:
        # only this column's bytes stay with the table (not every attachment's: the RUN's size in memory)
        one = {k: att[k] for k in (PHASE_PACKED + key,) if k in att}
        return Deferred(lambda: column(one, key, n, dtype))

    try:
        names = json.loads(att[PHASE_PACKED + "names.json"])
        words = {c: [str(w) for w in names[c]] for c in PHASE_NAME_COLUMNS}
        missing = [k for k in (*_PHASE_DTYPES, *(c + "_code" for c in PHASE_NAME_COLUMNS)) if PHASE_PACKED + k not in att]
        if missing:
            raise KeyError(f"no {', '.join(missing)}")
    except (KeyError, TypeError, ValueError) as exc:
        raise damaged(exc) from None
    t = column(att, "time_s", dtype=float)
    if t.ndim != 1:
        raise damaged(ValueError(f"{what}time_s: shape {list(t.shape)}"))
    n = t.size
    numbers = {c: later(c, n, dt) if c in _PHASE_DEFERRED else column(att, c, n, dt)
               for c, dt in _PHASE_DTYPES.items() if c != "time_s"}
    codes = {c: (later(c + "_code", n) if c in _PHASE_DEFERRED else column(att, c + "_code", n), words[c])
             for c in PHASE_NAME_COLUMNS}
    try:
        return Table({"time_s": t, **numbers}, codes, PHASE_COLUMNS, categorical=PHASE_NAME_COLUMNS)
    except ValueError as exc:                      # repeated names, codes outside them
        raise damaged(exc) from None


def epoch_gaps(time_s: np.ndarray, period_s: float) -> list[dict]:
    """Gaps between consecutive distinct epochs longer than 1.5 sample periods."""
    t = np.unique(time_s)
    if t.size < 2:
        return []
    dt = np.diff(t)
    idx = np.flatnonzero(dt > 1.5 * period_s)
    return [{"start_s": float(t[i]), "end_s": float(t[i + 1]), "missing_epochs": int(round(dt[i] / period_s)) - 1}
            for i in idx]


def write_run(cfg: StructureConfig, receiver_csv: str | Path, out_path: str | Path,
              gyro_csv: str | Path | None = None, actuator_csv: str | Path | None = None,
              channel_counter=None, block_bytes: int | None = None) -> dict:
    """Validate native CSV logs and write one self-contained RUN.mcap, a block of rows at a time.

    The logs are read, validated and written in blocks (:mod:`cdgps_cli.io.log_stream`): the
    messages as they come, the packed phase columns and the gyro arrays from scratch files at the
    end, so memory does not grow with the record (issue 29); the file is the one the whole-record
    writing gave, byte for byte.  A problem anywhere is one CdgpsError naming the file, line and
    time, and leaves no output (the file is written atomically).

    Parameters
    ----------
    cfg : StructureConfig
        Structure model the logs refer to (embedded as an attachment).
    receiver_csv, gyro_csv, actuator_csv : path, glob pattern, or list of them
        Native logs (see :mod:`cdgps_cli.io.logs`); gyro and actuator logs are optional.  Several
        files (a list, or a pattern matching several) are consecutive pieces of one record (hourly
        files): each is validated, and they are joined in time order by their first epoch
        (:func:`cdgps_cli.io.log_stream.stream_log`; the summary's ``joins`` and ``warnings`` say how).
    out_path : path
        Output MCAP; written atomically.
    channel_counter : callable, optional
        ``channel_counter(sample_period_s)`` → an object with ``add(phase_block)`` (blocks of the
        phase table in time order) and ``result()`` (each channel's ``lock_restarts_s`` …:
        :class:`cdgps_cli.pipeline.ingest.ChannelCounter`, the one lock-segment rule); the
        summary's ``lock_restarts`` counts them (None without it).
    block_bytes : int, optional
        Bytes of CSV text read at a time (default :data:`cdgps_cli.io.logs.LOG_BLOCK_BYTES`).

    Returns
    -------
    dict
        Summary: counts, time span, gaps, channels, lock restarts.
    """
    from cdgps_cli.io.log_sequence import expand_paths  # noqa: PLC0415

    given = {"receiver_csv": receiver_csv, "gyro_csv": gyro_csv, "actuator_csv": actuator_csv}
    files = {k: expand_paths([v] if isinstance(v, (str, Path)) else list(v), k.upper())
             for k, v in given.items() if v is not None and (isinstance(v, (str, Path)) or len(v))}
    sources = {key: Path(p) for k, ps in files.items() for key, p in input_keys(k, ps)}
    out_path = Path(out_path)
    for k, p in sources.items():
        if p.resolve() == out_path.resolve():
            raise CdgpsError(f"{out_path}: the output would overwrite the input {k}")
    made = [d for d in [out_path.parent, *out_path.parent.parents] if not d.exists()]
    try:
        return _write_run(cfg, files, out_path, channel_counter, block_bytes)
    except BaseException:
        for d in made:                              # (folders made for an output not written)
            try:
                d.rmdir()
            except OSError:
                break
        raise


def _write_run(cfg: StructureConfig, files: dict, out_path: Path, channel_counter, block_bytes) -> dict:
    from cdgps_cli.io.log_stream import stream_log  # noqa: PLC0415 (pandas)

    joins: dict = {}
    with McapOut(out_path, time_scale="relative") as out:     # time_s: run seconds (cdgps_cli.core.timescales)
        where = out_path.parent
        phase = _PhaseSink(out, cfg, channel_counter, where)
        gyro = act = None
        try:
            stream_log(files["receiver_csv"], "receiver", cfg, phase, PHASE_NAME_COLUMNS, PHASE_NAME_COLUMNS, joins,
                       "receiver_csv", cfg.sample_period_s, block_bytes=block_bytes)
            _attach_phase_packed(out, phase)               # the same table, read without decoding
            if "gyro_csv" in files:         # (a header-only log of a config without gyros: no topic)
                gyro = _SeriesSink(out, GYRO_TOPIC, GYRO_SCHEMA, {"units": "rad/s"}, "gyro", "rate_rad_s", where,
                                   arrays=True)
                stream_log(files["gyro_csv"], "gyro", cfg, gyro, ["gyro"], [], joins, "gyro_csv", None,
                           block_bytes=block_bytes)
                gyro.attach_arrays()        # the gyro log also as .npy arrays (fast reading by spectra and reports)
            if "actuator_csv" in files:
                act = _SeriesSink(out, ACTUATOR_TOPIC, ACTUATOR_SCHEMA, {"units": "N"}, "actuator", "force_n", where,
                                  arrays=False)
                stream_log(files["actuator_csv"], "actuator", cfg, act, ["actuator"], [], joins, "actuator_csv", None,
                           sampled=False, block_bytes=block_bytes)
        finally:
            for sink in (phase, gyro, act):
                if sink is not None:
                    sink.close()
        out.attach(CONFIG_ATTACHMENT, cfg.text.encode("utf-8"), "application/toml")
        # the files in time order (the metadata keys receiver_csv[0], [1] … follow it)
        sources = {key: Path(p) for k, ps in files.items() for key, p in input_keys(k, ps)}
        out.metadata(INGEST_METADATA, ingest_metadata("structure", cfg, sources, sample_period_s=repr(cfg.sample_period_s)))
        gaps = epoch_gaps(phase.epochs(), cfg.sample_period_s)
        chans = None if phase.counter is None else phase.counter.result()
        out.info_extra[INFO_STRUCTURE_KEY] = json.dumps({"gaps": gaps, **({} if chans is None else {"channels": chans})})
    return {
        "output": str(out_path),
        "config": cfg.name,
        "config_sha256": cfg.sha256,
        "phase_rows": phase.rows, "phase_messages": phase.messages,
        "gyro_rows": 0 if gyro is None else gyro.rows, "gyro_messages": 0 if gyro is None else gyro.messages,
        "actuator_rows": 0 if act is None else act.rows, "actuator_messages": 0 if act is None else act.messages,
        "start_s": phase.first_t, "end_s": phase.last_t,
        "gaps": gaps,
        "channels": len(phase.pairs),
        "lock_restarts": None if chans is None else sum(len(c["lock_restarts_s"]) for c in chans),
        **({"joins": {k: j["report"] for k, j in joins.items()},
            "warnings": [w for j in joins.values() for w in j["warnings"]]} if joins else {}),
    }


class _PhaseSink:
    """The receiver log's whole epochs, as they come: their ``/cdgps/phase`` messages written, the
    columns of the packed phase arrays kept on disk (names as numbers in the order first seen,
    sorted at the end), the epochs, the channels' summary (``counter``) and counts."""

    _NUMBERS = {"time_s": "<f8", "phase_cycles": "<f8", "lock": "<i8", "snr_dbhz": "<f8"}

    def __init__(self, out: McapOut, cfg: StructureConfig, channel_counter, where: Path):
        from cdgps_cli.io.log_stream import PlaneColumn, RowColumn, Vocabulary  # noqa: PLC0415

        self.out = out
        self.ch = out.channel(PHASE_TOPIC, PHASE_SCHEMA, {"units": "cycles", "wavelength_m": repr(cfg.wavelength_m)})
        self.counter = None if channel_counter is None else channel_counter(cfg.sample_period_s)
        self.vocab = {c: Vocabulary() for c in PHASE_NAME_COLUMNS}
        self.codes = {c: RowColumn(np.int32, where) for c in PHASE_NAME_COLUMNS}
        self.numbers = {c: PlaneColumn(dt, where) for c, dt in self._NUMBERS.items()}
        self._epochs: list = []
        self.rows = self.messages = 0
        self.pairs: set = set()
        self.first_t = self.last_t = None

    def add(self, tab: Table) -> None:
        from cdgps_cli.io.log_stream import unique_sorted  # noqa: PLC0415

        self.messages += self.out.write_table(self.ch, tab, PHASE_ARRAYS, ["master"])
        for c in PHASE_NAME_COLUMNS:
            self.codes[c].append(self.vocab[c].of(tab, c))
        for c, col in self.numbers.items():
            col.append(tab[c])
        if self.counter is not None:
            self.counter.add(tab)
        t = tab["time_s"]
        self._epochs.append(unique_sorted(t))
        a, aw = tab.codes("antenna")
        x, xw = tab.codes("transmitter")
        for k in np.unique(a.astype(np.int64) * len(xw) + x).tolist():
            self.pairs.add((aw[k // len(xw)], xw[k % len(xw)]))
        self.rows += len(tab)
        self.first_t = float(t[0]) if self.first_t is None else self.first_t
        self.last_t = float(t[-1])

    def epochs(self) -> np.ndarray:
        return np.concatenate(self._epochs) if self._epochs else np.array([], dtype=float)

    def attach_packed(self, out: McapOut) -> None:
        """The :data:`PHASE_PACKED` attachments, packed from the scratch columns."""
        names = {}
        for col in PHASE_NAME_COLUMNS:
            words, lut = self.vocab[col].sorted()
            names[col] = words
            _attach_planes(out, f"{PHASE_PACKED}{col}_code", np.int32, self.codes[col].n,
                           self.codes[col].planes(lut, np.int32))
        out.attach(PHASE_PACKED + "names.json", json.dumps(names, sort_keys=True).encode(), "application/json")
        for c, col in self.numbers.items():
            _attach_planes(out, PHASE_PACKED + c, col.dtype, col.n, col.planes())

    def close(self) -> None:
        for col in [*self.codes.values(), *self.numbers.values()]:
            col.close()


def _attach_planes(out: McapOut, name: str, dtype, n: int, planes) -> None:
    """Attach the packed array of ``n`` numbers given as byte planes (compressed into a scratch
    file first: the attachment's length comes before its bytes)."""
    from cdgps_cli.io.log_stream import read_pieces, scratch_file, write_scratch  # noqa: PLC0415
    from cdgps_cli.io.packed_arrays import MEDIA_TYPE, pack_planes  # noqa: PLC0415

    with scratch_file(out.path.parent) as tmp:
        pack_planes(dtype, n, planes, lambda b: write_scratch(tmp, b, out.path.parent))
        size = tmp.tell()
        out.attach_stream(name, size, read_pieces(tmp), MEDIA_TYPE)


class _SeriesSink:
    """A ``time_s,<name>,<value>`` log's whole epochs, as they come: their messages written (the
    channel registered with the first), and with ``arrays`` the columns of the gyro arrays kept
    on disk (:data:`GYRO_ARRAYS`, written by :meth:`attach_arrays`)."""

    def __init__(self, out: McapOut, topic: str, schema: dict, meta: dict, name: str, value: str, where: Path,
                 arrays: bool):
        from cdgps_cli.io.log_stream import RowColumn, Vocabulary  # noqa: PLC0415

        self.out, self.name, self.value = out, name, value
        self.topic = (topic, schema, meta)
        self.ch = None if arrays else out.channel(topic, schema, meta)   # (an actuator topic even without rows)
        self.rows = self.messages = 0
        self.vocab = Vocabulary()
        self.cols = {"time_s": RowColumn("<f8", where), value: RowColumn("<f8", where),
                     "codes": RowColumn(np.int32, where)} if arrays else {}

    def add(self, tab: Table) -> None:
        if self.ch is None:
            self.ch = self.out.channel(*self.topic)
        self.messages += self.out.write_table(self.ch, tab, [self.name, self.value])
        if self.cols:
            self.cols["time_s"].append(tab["time_s"])
            self.cols[self.value].append(tab[self.value])
            self.cols["codes"].append(self.vocab.of(tab, self.name))
        self.rows += len(tab)

    def attach_arrays(self) -> None:
        """The :data:`GYRO_ARRAYS` attachments (``.npy`` as ``np.save`` writes them), when the log has rows."""
        from cdgps_cli.io.log_stream import names_json, npy_header  # noqa: PLC0415

        if not self.rows:
            return
        words, lut = self.vocab.sorted()
        for key, col, args in (("time_s.npy", self.cols["time_s"], ()), ("rate_rad_s.npy", self.cols[self.value], ()),
                               ("gyro_index.npy", self.cols["codes"], (lut.astype(np.int64), np.dtype("<i8")))):
            dtype = args[1] if args else col.dtype
            head = npy_header(dtype, col.n)
            pieces = (memoryview(np.ascontiguousarray(v)).cast("B") for v in col.pieces(*args))
            self.out.attach_stream(GYRO_ARRAYS + key, len(head) + col.n * dtype.itemsize,
                                   _chain([head], pieces), "application/x-npy")
        self.out.attach(GYRO_ARRAYS + "gyro_names.json", names_json(words), "application/json")

    def close(self) -> None:
        for col in self.cols.values():
            col.close()


def _chain(*parts):
    for p in parts:
        yield from p


def input_keys(key: str, paths: list) -> list:
    """Metadata keys of a log's files: ``key`` for one file, ``key[0]``, ``key[1]`` … (time order) for several."""
    return [(key, paths[0])] if len(paths) == 1 else [(f"{key}[{i}]", p) for i, p in enumerate(paths)]


def read_run(path: str | Path, phase: bool = True, on_disk: bool = False) -> Run:
    """Read a RUN.mcap written by :func:`write_run` (CRCs validated).

    With ``phase=False`` only the gyro and actuator topics are decoded (the phase table is empty).
    With ``on_disk=True`` the phase table stays on disk and is read a block of rows at a time
    (:class:`cdgps_cli.io.phase_disk.DiskPhase`; the same values), so memory does not grow with the
    record (issue 29: ``cdgps estimate`` and ``cdgps init``); files without the packed phase arrays
    are read into memory as before.
    """
    if on_disk and phase:
        try:
            run = _read_run_on_disk(path)
        except _NoScratch as exc:              # (no room for the scratch files: the table in memory, said)
            print(f"cdgps: warning: {path}: cannot write the phase table's scratch files ({exc}); it is read "
                  f"into memory", file=sys.stderr, flush=True)
            run = None
        if run is not None:
            return run
    want_phase = phase
    # without the phase table its packed arrays are not kept in memory (spectra, reports: the gyro log only)
    c = read_mcap(path, topics=[ACTUATOR_TOPIC],
                  attachments=None if want_phase else (lambda name: not name.startswith(PHASE_PACKED)))
    if "cdgps.estimate" not in c.metadata:
        c.require_metadata(INGEST_METADATA, "RUN.mcap from 'cdgps ingest'")
    if contents_kind(c) == "gnss":
        raise CdgpsError(f"{path}: this is a GNSS run (RINEX/UBX receivers, docs/gnss-pipeline.md), not a structure run; "
                         f"it is processed by 'cdgps init' and 'cdgps estimate' into displacement states")
    if "cdgps.estimate" in c.metadata:
        raise CdgpsError(f"{path}: this is a STATES.mcap (from 'cdgps estimate'), not a RUN.mcap from 'cdgps ingest'")
    if CONFIG_ATTACHMENT not in c.attachments:
        raise CdgpsError(f"{path}: no {CONFIG_ATTACHMENT} attachment; is this a RUN.mcap from 'cdgps ingest'?")
    c.require_channels(PHASE_TOPIC, what="RUN.mcap from 'cdgps ingest'")
    cfg = parse_config(c.attachments[CONFIG_ATTACHMENT].decode("utf-8"), f"{path}:{CONFIG_ATTACHMENT}")
    phase = _phase_from_packed(c.attachments, path) if want_phase else None
    gyro = _gyro_from_attachments(c.attachments)
    wanted = (([PHASE_TOPIC] if want_phase and phase is None else [])
              + ([GYRO_TOPIC] if gyro is None and GYRO_TOPIC in c.channels else []))   # (no gyro log: no re-read)
    if wanted:                                               # a RUN.mcap written before the packed arrays
        c.topics.update(read_mcap(path, topics=wanted).topics)
    if want_phase and phase is None and PHASE_TOPIC not in c.topics:
        raise CdgpsError(f"{path}: no {PHASE_TOPIC} messages; is this a RUN.mcap from 'cdgps ingest'?")
    if phase is None:
        phase = _phase_table(c.topics.get(PHASE_TOPIC, TopicColumns()), path)
    if gyro is None:
        gyro = c.topics.get(GYRO_TOPIC, TopicColumns()).table(["gyro", "rate_rad_s"])
    act = c.topics.get(ACTUATOR_TOPIC, TopicColumns()).table(["actuator", "force_n"])
    return Run(str(path), cfg, phase, gyro, act, c.metadata.get(INGEST_METADATA, {}))


def _read_run_on_disk(path: str | Path) -> Run | None:
    """:func:`read_run` with the phase table on disk (None: the file has no packed phase arrays)."""
    from cdgps_cli.io.mcap import _check_attachment_crcs, attachment_spans, open_verified  # noqa: PLC0415

    with open_verified(path) as (_reader, fh, info, summary):
        if not info.data_section_crc_checked:
            _check_attachment_crcs(fh, summary, path, zero_ok=False)
        spans = attachment_spans(fh, summary, path)
        if PHASE_PACKED + "names.json" not in spans or "cdgps.estimate" in info.metadata:
            return None
        names_json = read_span(fh, *spans[PHASE_PACKED + "names.json"])(spans[PHASE_PACKED + "names.json"][1])
    # the other topics and attachments (small) as read_run reads them, without the phase arrays
    c = read_mcap(path, topics=[ACTUATOR_TOPIC], attachments=lambda name: not name.startswith(PHASE_PACKED))
    c.require_metadata(INGEST_METADATA, "RUN.mcap from 'cdgps ingest'")
    if contents_kind(c) == "gnss":
        return None                                            # (read_run names it)
    if CONFIG_ATTACHMENT not in c.attachments:
        raise CdgpsError(f"{path}: no {CONFIG_ATTACHMENT} attachment; is this a RUN.mcap from 'cdgps ingest'?")
    c.require_channels(PHASE_TOPIC, what="RUN.mcap from 'cdgps ingest'")
    cfg = parse_config(c.attachments[CONFIG_ATTACHMENT].decode("utf-8"), f"{path}:{CONFIG_ATTACHMENT}")
    phase = _phase_on_disk(path, spans, names_json)
    gyro = _gyro_from_attachments(c.attachments)
    if gyro is None:
        if GYRO_TOPIC in c.channels:
            c.topics.update(read_mcap(path, topics=[GYRO_TOPIC], attachments=lambda name: False).topics)
        gyro = c.topics.get(GYRO_TOPIC, TopicColumns()).table(["gyro", "rate_rad_s"])
    act = c.topics.get(ACTUATOR_TOPIC, TopicColumns()).table(["actuator", "force_n"])
    return Run(str(path), cfg, phase, gyro, act, c.metadata.get(INGEST_METADATA, {}))


class _NoScratch(Exception):
    """A scratch file of :func:`_phase_on_disk` could not be written (full disk, file-size limit)."""


def _phase_on_disk(path, spans: dict, names_json: bytes):
    """The :data:`PHASE_PACKED` columns as a :class:`~cdgps_cli.io.phase_disk.DiskPhase`: each
    decompressed in pieces into a scratch file (the columns of :data:`_PHASE_DEFERRED` on first use);
    damage is the same CdgpsError as :func:`_phase_from_packed`'s."""
    from cdgps_cli.io.packed_arrays import PackedRows  # noqa: PLC0415
    from cdgps_cli.io.phase_disk import BLOCK_ROWS, DiskPhase, column_file  # noqa: PLC0415

    what = f"{path}: attachment {PHASE_PACKED}"

    def damaged(exc: Exception) -> CdgpsError:
        return CdgpsError(f"{path}: damaged phase arrays ({PHASE_PACKED}*): {exc}")

    def column(key: str, n: int | None, dtype):
        try:
            with open(path, "rb") as fh:
                rows = PackedRows(read_span(fh, *spans[PHASE_PACKED + key]), spans[PHASE_PACKED + key][1], what + key)
            try:
                if len(rows.shape) != 1 or (n is not None and rows.n_rows != n):
                    raise ValueError(f"{what}{key}: {list(rows.shape)} values for {n} rows")
                return column_file(rows.chunks(BLOCK_ROWS), rows.n_rows, dtype, what + key)
            finally:
                rows.close()
        except OSError as exc:                     # writing the scratch files (reading the RUN was checked)
            raise _NoScratch(exc.strerror or str(exc)) from None
        except (KeyError, TypeError, ValueError) as exc:
            raise damaged(exc) from None

    try:
        names = json.loads(names_json)
        words = {c: [str(w) for w in names[c]] for c in PHASE_NAME_COLUMNS}
        missing = [k for k in (*_PHASE_DTYPES, *(c + "_code" for c in PHASE_NAME_COLUMNS)) if PHASE_PACKED + k not in spans]
        if missing:
            raise KeyError(f"no {', '.join(missing)}")
    except (KeyError, TypeError, ValueError) as exc:
        raise damaged(exc) from None
    t = column("time_s", None, float)
    n = t.n

    def later(key, dtype):
        return lambda: column(key, n, dtype)

    numbers = {c: later(c, dt) if c in _PHASE_DEFERRED else column(c, n, dt)
               for c, dt in _PHASE_DTYPES.items() if c != "time_s"}
    codes = {c: (later(c + "_code", np.int32) if c in _PHASE_DEFERRED else column(c + "_code", n, np.int32), words[c])
             for c in PHASE_NAME_COLUMNS}
    try:
        return DiskPhase(n, {"time_s": t, **numbers}, codes, PHASE_COLUMNS, categorical=PHASE_NAME_COLUMNS)
    except ValueError as exc:                      # names not sorted, codes outside them
        raise damaged(exc) from None


def _phase_table(tc: TopicColumns, path="RUN.mcap") -> Table:
    """The phase table from decoded ``/cdgps/phase`` messages (the columns of :class:`Run`)."""
    try:
        t = tc.table(PHASE_ARRAYS, ["master"])
        if not len(t):
            return Table({c: np.array([], dtype=np.int64 if c == "lock" else float) for c in PHASE_COLUMNS})
        numbers = {"time_s": t["time_s"], "phase_cycles": t["phase_cycles"].astype(float),
                   "lock": t["lock"].astype(np.int64), "snr_dbhz": t["snr_dbhz"].astype(float)}
        names = {c: t.codes(c) for c in PHASE_NAME_COLUMNS}
        return Table(numbers, names, PHASE_COLUMNS, categorical=PHASE_NAME_COLUMNS)
    except (KeyError, ValueError) as exc:        # e.g. a name field holding numbers, fields of other lengths
        raise CdgpsError(f"{path}: damaged {PHASE_TOPIC} messages: {exc}") from None


def run_info(path: str | Path, gnss_common_epochs=None, channel_summary=None, gnss_lock_summary=None,
             deep: bool = False) -> dict:
    """Summary of a RUN.mcap (or any cdgps MCAP) for ``cdgps info``: topics, counts, span, sampling,
    gaps, channels, slips.

    The answer comes from the summary section and the metadata records (:data:`~cdgps_cli.io.mcap.INFO_METADATA`,
    written by every cdgps writer) without decoding a message, after the same integrity checks as
    every reader (:func:`~cdgps_cli.io.mcap.open_verified`: magic, footer, summary and data-section
    CRCs, metadata checksums) plus :func:`~cdgps_cli.io.mcap.check_indexes` (chunk and message
    indexes against the statistics and the record; chunk CRCs too when the file has no data-section
    CRC).  GNSS runs and files written before the record are read message by message (a note on
    stderr for the latter).  ``deep``: always decode every message (chunk CRCs, JSON of each
    message), and refuse a file whose record disagrees with its messages.

    The model's counts come from functions the stage :func:`cdgps_cli.pipeline.gnss_ingest.run_info`
    passes (``io`` imports no numerics): ``channel_summary(phase, sample_period_s)`` each
    structure channel's rows, span and lock restarts (the one lock-segment rule; without it
    ``channels`` and ``slips`` are left out); for a GNSS run ``gnss_common_epochs`` and
    ``gnss_lock_summary`` (see :func:`cdgps_cli.io.gnss_run.gnss_run_info`)."""
    if not deep:
        info = summary_info(path, channel_summary is not None)
        if info is not None:
            return info
    info, record = _decoded_info(path, gnss_common_epochs, channel_summary, gnss_lock_summary)
    if record is not None:
        info["topics"] = sorted(info["topics"] + _foxglove_topics(path, record), key=lambda t: t["topic"])
    if deep and record is not None:
        _compare_record(path, info, record)
    elif record is None and "gnss" not in info:        # (GNSS runs are always read message by message)
        print(f"cdgps: note: {path}: written by an older cdgps, without a {INFO_METADATA} record: read message "
              f"by message (slow); a file written by this version is answered from its summary",
              file=sys.stderr, flush=True)
    return info


def _topic_entry(topic: str, schema, encoding: str, count: int, span: dict, scale: str) -> dict:
    return {"topic": topic, "schema": schema[0], "schema_encoding": schema[1], "message_encoding": encoding,
            "messages": count, "start_s": span["start_s"], "end_s": span["end_s"], "time_scale": scale,
            "start": format_time(span["start_s"], scale), "end": format_time(span["end_s"], scale),
            "median_period_s": span["median_period_s"]}


def _slips(chans: list) -> list:
    out = [{"antenna": ch["antenna"], "transmitter": ch["transmitter"], "time_s": t, "kind": kind}
           for ch in chans for t, kind in zip(ch["lock_restarts_s"], ch["lock_restart_kinds"])]
    out.sort(key=lambda r: (r["time_s"], r["antenna"], r["transmitter"]))
    return out


def _foxglove_topics(path, record: dict) -> list:
    """Topic entries of the channels :func:`~cdgps_cli.io.mcap.read_mcap` leaves out (Foxglove's own
    schemas, e.g. STATES' 3-D scene, whose messages hold no ``time_s``): every message decoded
    (JSON), counted, and its first and last log times checked against the ``INFO_METADATA`` record,
    whose span (in the file's time scale) they then take."""
    from mcap.reader import make_reader  # noqa: PLC0415

    spans = _record_json(path, record, "topics")
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        chans = {cid: ch for cid, ch in summary.channels.items()
                 if summary.schemas[ch.schema_id].name.startswith("foxglove.")}
        seen: dict = {}
        for _, ch, m in reader.iter_messages(topics=sorted({c.topic for c in chans.values()})):
            try:
                json.loads(m.data)
            except ValueError:
                raise CdgpsError(f"{path}: {ch.topic}: message {m.sequence} is not JSON (corrupt file)") from None
            n, lo, hi = seen.get(ch.topic, (0, m.log_time, m.log_time))
            seen[ch.topic] = (n + 1, min(lo, m.log_time), max(hi, m.log_time))
    out = []
    for cid, ch in sorted(chans.items()):
        if ch.topic not in seen:
            continue
        s, (n, lo, hi) = spans.get(ch.topic), seen[ch.topic]
        scale = (ch.metadata or {}).get("time_scale", "relative")
        try:
            ok = s["messages"] == n and unix_ns(s["start_s"], scale) == lo and unix_ns(s["end_s"], scale) == hi
        except (KeyError, TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise CdgpsError(f"{path}: the {INFO_METADATA} record disagrees with the decoded messages of {ch.topic} "
                             "(corrupt file)")
        sc = summary.schemas[ch.schema_id]
        out.append(_topic_entry(ch.topic, (sc.name, sc.encoding), ch.message_encoding, n, s, scale))
    return out


def _decoded_info(path, gnss_common_epochs, channel_summary, gnss_lock_summary) -> tuple:
    """:func:`run_info` from every message decoded; also the file's INFO_METADATA record (or None)."""
    c = read_mcap(path)
    record = c.metadata.get(INFO_METADATA)
    info = {"file": str(path), "topics": [], "metadata": c.metadata,
            "attachments": sorted(c.attachments)}
    for topic, msgs in sorted(c.topics.items()):
        t = msgs.times()
        info["topics"].append(_topic_entry(topic, c.schemas[topic], c.message_encoding[topic], len(msgs),
                                           time_summary(t, msgs.scalars.get("receiver")), time_scale(c, topic, t)))
    from cdgps_cli.io.gnss_run import gnss_run_info  # noqa: PLC0415 (GNSS runs: docs/gnss-pipeline.md)

    if contents_kind(c) == "gnss":
        info["gnss"] = gnss_run_info(path, c, gnss_common_epochs, gnss_lock_summary)
        if GNSS_INFO_ATTACHMENT in c.attachments and gnss_lock_summary is not None and gnss_common_epochs is not None:
            _compare_gnss_record(path, info["gnss"], c.attachments[GNSS_INFO_ATTACHMENT])
    if PHASE_TOPIC in c.topics and CONFIG_ATTACHMENT in c.attachments:
        cfg = parse_config(c.attachments[CONFIG_ATTACHMENT].decode("utf-8"), f"{path}:{CONFIG_ATTACHMENT}")
        phase = c.topics[PHASE_TOPIC].table(PHASE_ARRAYS, ["master"])
        info["config"] = cfg.summary()
        info["gaps"] = epoch_gaps(phase["time_s"], cfg.sample_period_s)
        if channel_summary is not None:
            info["channels"] = channel_summary(phase, cfg.sample_period_s)
            info["slips"] = _slips(info["channels"])
    return info, record


def summary_info(path, want_channels: bool = True) -> dict | None:
    """:func:`run_info` from the summary and metadata records (with ``channels`` and ``slips`` when
    ``want_channels``); None when the file cannot answer so (no INFO_METADATA record of this format,
    a GNSS run, a structure part missing).  Imports neither pandas nor the numerics, so
    ``cdgps info`` starts fast."""
    from cdgps_cli.io.mcap import open_verified, read_attachment  # noqa: PLC0415

    with open_verified(path) as (_reader, fh, integrity, summary):
        meta = integrity.metadata
        record = meta.get(INFO_METADATA)
        names = {a.name for a in summary.attachment_indexes}
        if record is None or record.get("format") != INFO_FORMAT:
            return None
        gnss = (meta.get(INGEST_METADATA) or {}).get("kind") == "gnss" or "gnss/receivers.json" in names
        if gnss and GNSS_INFO_ATTACHMENT not in names:
            return None                                      # GNSS runs before their info record: decoded
        idx = check_indexes(fh, summary, path, chunk_crcs=not integrity.data_section_crc_checked)
        spans = _record_json(path, record, "topics")
        by_topic: dict = {}
        for cid in sorted(idx.messages):
            by_topic.setdefault(summary.channels[cid].topic, []).append(cid)
        _check_spans(path, spans, by_topic, idx, summary)
        channel_meta = {t: dict(summary.channels[cids[0]].metadata or {}) for t, cids in by_topic.items()}
        view = _MetaView(channel_meta, meta)
        info = {"file": str(path), "topics": [], "metadata": meta, "attachments": sorted(names)}
        for topic, cids in sorted(by_topic.items()):
            ch = summary.channels[cids[0]]
            sc = summary.schemas.get(ch.schema_id)
            span = spans[topic]
            ends = [v for v in (span["start_s"], span["end_s"]) if v is not None]
            info["topics"].append(_topic_entry(topic, (sc.name, sc.encoding) if sc else ("", ""), ch.message_encoding,
                                               sum(idx.messages[c] for c in cids), span,
                                               time_scale(view, topic, np.array(ends, dtype=float))))
        if gnss:
            from cdgps_cli.config.structure import parse_gnss_config  # noqa: PLC0415

            text = read_attachment(fh, summary, CONFIG_ATTACHMENT, path)
            cfg = parse_gnss_config(text.decode("utf-8"), f"{path}:{CONFIG_ATTACHMENT}")
            info["gnss"] = {"config": cfg.summary(), **_gnss_record(fh, summary, path)}
        if PHASE_TOPIC in by_topic and CONFIG_ATTACHMENT in names:
            part = _record_json(path, record, INFO_STRUCTURE_KEY) if INFO_STRUCTURE_KEY in record else {}
            if "gaps" not in part or (want_channels and "channels" not in part):
                return None
            text = read_attachment(fh, summary, CONFIG_ATTACHMENT, path)
            cfg = parse_config(text.decode("utf-8"), f"{path}:{CONFIG_ATTACHMENT}")
            info["config"] = cfg.summary()
            info["gaps"] = part["gaps"]
            if want_channels:
                info["channels"] = part["channels"]
                info["slips"] = _slips(part["channels"])
    return info


GNSS_INFO_ATTACHMENT = "gnss/info.json"
"""(:data:`cdgps_cli.io.gnss_run.GNSS_INFO_ATTACHMENT`, named here: this module does not import that one.)"""


def _compare_gnss_record(path, decoded: dict, recorded: bytes) -> None:
    """CdgpsError when the GNSS info ``ingest`` recorded differs from the one computed from the decoded run (``info``
    answers from the record: it must say what the observations say)."""
    from cdgps_cli.io.gnss_run import gnss_info_json  # noqa: PLC0415

    want = {"config": decoded["config"], **json.loads(gnss_info_json(decoded))}
    try:
        got = {"config": decoded["config"], **json.loads(recorded)}
    except (ValueError, TypeError):
        got = None
    if got != want:
        keys = sorted(k for k in set(want) | set(got or {}) if (got or {}).get(k) != want.get(k))
        raise CdgpsError(f"{path}: its {GNSS_INFO_ATTACHMENT} record differs from its observations decoded "
                         f"({', '.join(keys) or 'not JSON'}) (corrupt or altered file)")


def _gnss_record(fh, summary, path) -> dict:
    """The GNSS part of ``info`` as ``ingest`` recorded it (:func:`cdgps_cli.io.gnss_run.gnss_info`)."""
    from cdgps_cli.io.mcap import read_attachment  # noqa: PLC0415

    try:
        out = json.loads(read_attachment(fh, summary, GNSS_INFO_ATTACHMENT, path))
    except ValueError:
        out = None
    if not isinstance(out, dict) or not isinstance(out.get("receivers"), list):
        raise CdgpsError(f"{path}: damaged {GNSS_INFO_ATTACHMENT} attachment (corrupt file)")
    return out


@dataclass
class _MetaView:
    """What :func:`~cdgps_cli.core.time_format.time_scale` reads of MCAP contents."""

    channel_metadata: dict
    metadata: dict


def _record_json(path, record: dict, key: str):
    try:
        return json.loads(record[key])
    except (KeyError, TypeError, ValueError):
        raise CdgpsError(f"{path}: damaged {INFO_METADATA} metadata record (key {key!r}) (corrupt file)") from None


def _check_spans(path, spans, by_topic: dict, idx, summary) -> None:
    """The record's topics against the message indexes: same topics, counts, first and last log time."""
    def bad(what):
        return CdgpsError(f"{path}: the {INFO_METADATA} record disagrees with the message indexes: {what} (corrupt file)")

    if not isinstance(spans, dict) or set(spans) != set(by_topic):
        raise bad(f"topics {sorted(spans) if isinstance(spans, dict) else spans!r} vs {sorted(by_topic)}")
    for topic, cids in by_topic.items():
        s = spans[topic]
        scale = (summary.channels[cids[0]].metadata or {}).get("time_scale", "relative")
        try:
            ok = (s["messages"] == sum(idx.messages[c] for c in cids)
                  and unix_ns(s["start_s"], scale) == min(idx.first_ns[c] for c in cids)
                  and unix_ns(s["end_s"], scale) == max(idx.last_ns[c] for c in cids)
                  and (s["median_period_s"] is None or isinstance(s["median_period_s"], float)))
        except (KeyError, TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise bad(f"topic {topic}")


def _compare_record(path, info: dict, record: dict) -> None:
    """``info --deep``: the INFO_METADATA record must say what the decoded messages say."""
    spans = _record_json(path, record, "topics")
    got = {t["topic"]: {"messages": t["messages"], "start_s": t["start_s"], "end_s": t["end_s"],
                        "median_period_s": t["median_period_s"]} for t in info["topics"]}
    part = _record_json(path, record, INFO_STRUCTURE_KEY) if INFO_STRUCTURE_KEY in record else None
    same = spans == got and (part is None or (part.get("gaps") == info.get("gaps")
                                              and part.get("channels", info.get("channels")) == info.get("channels")))
    if not same:
        raise CdgpsError(f"{path}: the {INFO_METADATA} record disagrees with the decoded messages (corrupt file)")
