"""``cdgps ingest`` of native CSV logs a block of rows at a time (issue 29 item 1).

A log (one file, or consecutive files of one record) is read and validated in blocks
(:func:`cdgps_cli.io.logs.valid_blocks`), cut into whole epochs (the rows of a time never straddle
two blocks: :class:`_Epochs`), joined across files (:class:`_Join`: the rule of
:func:`cdgps_cli.io.log_sequence.join_tables`, kept epoch by epoch) and handed to a sink that writes
the RUN's messages as they come and keeps the columns the RUN stores as attachments on disk
(:class:`PlaneColumn`, :class:`RowColumn`), packed or copied into the file at the end.  In memory:
a block, plus per-epoch times and per-channel summaries.  The RUN is the same file, byte for byte,
as the whole-record writing (tests/io/test_run_stream.py).  No numerics here: the per-channel lock
rule comes in as ``channel_counter`` (:class:`cdgps_cli.pipeline.ingest.ChannelCounter`).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.table import Table

__all__ = ["PlaneColumn", "RowColumn", "Vocabulary", "concat_tables", "read_pieces", "scratch_file", "stream_log", "unique_sorted",
           "write_scratch"]

_PIECE_BYTES = 8 << 20
"""Bytes read back from a scratch file at a time."""


def scratch_file(dir_) -> object:
    where = str(dir_) if dir_ is not None and Path(dir_).is_dir() else None
    try:
        return tempfile.TemporaryFile(prefix=".cdgps-ingest-", dir=where)
    except OSError as exc:
        raise CdgpsError(f"{where or tempfile.gettempdir()}: cannot make the ingest's scratch files: "
                         f"{exc.strerror}") from None


def write_scratch(fh, data, dir_) -> None:
    try:
        fh.write(data)
    except OSError as exc:
        raise CdgpsError(f"{dir_ or tempfile.gettempdir()}: cannot write the ingest's scratch files: "
                         f"{exc.strerror or exc}") from None


def read_pieces(fh, piece: int = _PIECE_BYTES):
    fh.flush()
    fh.seek(0)
    while chunk := fh.read(piece):
        yield chunk


class PlaneColumn:
    """A column of numbers appended a block at a time and kept on disk as its byte planes (one
    unlinked temporary file per byte of a number): what a packed array
    (:func:`cdgps_cli.io.packed_arrays.pack_planes`) is made of."""

    def __init__(self, dtype, dir_=None):
        self.dtype = np.dtype(dtype).newbyteorder("<")
        self.dir, self.n = dir_, 0
        self._files = [scratch_file(dir_) for _ in range(self.dtype.itemsize)]

    def append(self, values) -> None:
        v = np.ascontiguousarray(values, dtype=self.dtype)
        octets = v.view(np.uint8).reshape(-1, self.dtype.itemsize)
        for b, fh in enumerate(self._files):
            write_scratch(fh, np.ascontiguousarray(octets[:, b]), self.dir)
        self.n += v.size

    def planes(self):
        """The bytes of plane 0, then plane 1, … in pieces."""
        for fh in self._files:
            yield from read_pieces(fh)

    def close(self) -> None:
        for fh in self._files:
            fh.close()


class RowColumn:
    """A column of numbers appended a block at a time, kept on disk as they are (one unlinked
    temporary file); read back in pieces, each optionally mapped (``lut``) and cast."""

    def __init__(self, dtype, dir_=None):
        self.dtype = np.dtype(dtype).newbyteorder("<")
        self.dir, self.n = dir_, 0
        self._file = scratch_file(dir_)

    def append(self, values) -> None:
        v = np.ascontiguousarray(values, dtype=self.dtype)
        write_scratch(self._file, v, self.dir)
        self.n += v.size

    def pieces(self, lut: np.ndarray | None = None, dtype=None):
        """The column in pieces (arrays), mapped by ``lut`` and cast to ``dtype``."""
        step = max(_PIECE_BYTES // self.dtype.itemsize, 1) * self.dtype.itemsize
        for chunk in read_pieces(self._file, step):
            v = np.frombuffer(chunk, dtype=self.dtype)
            v = v if lut is None else lut[v]
            yield v if dtype is None else v.astype(dtype, copy=False)

    def planes(self, lut: np.ndarray, dtype):
        """The byte planes of the column mapped by ``lut`` and cast to ``dtype`` (one pass per plane)."""
        size = np.dtype(dtype).itemsize
        for b in range(size):
            for v in self.pieces(lut, np.dtype(dtype).newbyteorder("<")):
                yield np.ascontiguousarray(v.view(np.uint8).reshape(-1, size)[:, b])

    def close(self) -> None:
        self._file.close()


def concat_tables(a: Table | None, b: Table, name_columns, categorical=()) -> Table:
    """Rows of ``a`` then ``b`` (same columns; the name columns' words merged)."""
    if a is None or not len(a):
        return b
    numbers, names = {}, {}
    for c in b.columns:
        if c in name_columns:
            (ca, wa), (cb, wb) = a.codes(c), b.codes(c)
            words = sorted(set(wa) | set(wb))
            where = {w: i for i, w in enumerate(words)}
            la = np.array([where[w] for w in wa] or [0], dtype=np.int32)
            lb = np.array([where[w] for w in wb] or [0], dtype=np.int32)
            names[c] = (np.concatenate([la[ca], lb[cb]]), words)
        else:
            numbers[c] = np.concatenate([a[c], b[c]])
    return Table(numbers, names, b.columns, categorical)


class Vocabulary:
    """Names given numbers in the order first seen (the same name, the same number in every
    block); at the end, the sorted names and the map from those numbers to their sorted places."""

    def __init__(self):
        self.ids: dict[str, int] = {}

    def of(self, table: Table, column: str) -> np.ndarray:
        codes, words = table.codes(column)
        lut = np.array([self.ids.setdefault(w, len(self.ids)) for w in words] or [0], dtype=np.int32)
        return lut[codes]

    def sorted(self) -> tuple[list[str], np.ndarray]:
        words = sorted(self.ids)
        where = {w: i for i, w in enumerate(words)}
        lut = np.zeros(max(len(words), 1), dtype=np.int32)
        for w, i in self.ids.items():
            lut[i] = where[w]
        return words, lut


# ------------------------------------------------------------------------------------------------
# whole epochs


class _Epochs:
    """Blocks of rows (in time order) → blocks of whole epochs: the rows of the last time of a
    block wait for the next one."""

    def __init__(self, name_columns, categorical=()):
        self.names, self.categorical = set(name_columns), categorical
        self.pending: Table | None = None

    def add(self, tab: Table) -> Table | None:
        tab = concat_tables(self.pending, tab, self.names, self.categorical)
        t = tab["time_s"]
        if not t.size:
            self.pending = None
            return None
        k = int(np.searchsorted(t, t[-1], side="left"))
        self.pending = tab.take(slice(k, None))
        return tab.take(slice(0, k)) if k else None

    def flush(self) -> Table | None:
        out, self.pending = self.pending, None
        return out


def unique_sorted(t: np.ndarray) -> np.ndarray:
    """The distinct values of a non-decreasing array."""
    return t[np.r_[True, t[1:] != t[:-1]]] if t.size else t


# ------------------------------------------------------------------------------------------------
# one record from consecutive files


def _mix(x: np.ndarray) -> np.ndarray:
    """A 64-bit mixing function (splitmix64's finalizer), element-wise, wrapping."""
    x = x ^ (x >> np.uint64(30))
    x = x * np.uint64(0xBF58476D1CE4E5B9)
    x = x ^ (x >> np.uint64(27))
    x = x * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _epoch_digests(tab: Table, vocab: dict, name_columns) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(epochs, rows per epoch, digest per epoch) of whole epochs: equal digests ⇔ the same rows in
    the same order (names as text, numbers by value: NaN equals NaN, −0.0 equals 0.0)."""
    t = tab["time_s"]
    h = np.zeros(t.size, dtype=np.uint64)
    for j, c in enumerate(tab.columns):
        if c in name_columns:
            codes, words = tab.codes(c)
            lut = np.array([vocab.setdefault(w, len(vocab)) for w in words] or [0], dtype=np.uint64)
            v = lut[codes]
        else:
            x = np.asarray(tab[c])
            if x.dtype.kind == "f":
                x = np.where(np.isnan(x), np.nan, x.astype(np.float64) + 0.0)
            v = x.astype(np.float64 if x.dtype.kind == "f" else np.int64).view(np.uint64)
        h = _mix(h ^ _mix(v + np.uint64(j + 1)))
    starts = np.flatnonzero(np.r_[True, t[1:] != t[:-1]])
    pos = np.arange(t.size) - np.repeat(starts, np.diff(np.r_[starts, t.size]))
    d = np.add.reduceat(_mix(h + pos.astype(np.uint64)), starts) if t.size else h
    return t[starts], np.diff(np.r_[starts, t.size]), d


class _Join:
    """The files of one record joined in time order, epoch by epoch, as
    :func:`cdgps_cli.io.log_sequence.join_tables` joins their tables: an epoch a later file repeats
    is kept from the earlier file, an epoch inside an earlier file's span that it lacks is an error,
    gaps between files and repeated epochs are reported (identical rows or not, by their digests)."""

    def __init__(self, names: list[str], first_epochs: list[float], name_columns, time_text=lambda t: f"{t:g} s"):
        self.names, self.starts, self.name_columns = names, first_epochs, set(name_columns)
        self.time_text = time_text
        self.kept: list[np.ndarray] = []                # epochs kept, per file (time order)
        self.seen = np.array([], dtype=np.float64)
        self.prev_name, self.prev_last = None, -np.inf
        self.files: list[dict] = []                   # per file: what the report needs
        self.vocab: dict = {}
        self.digests: list = []                       # (epochs, rows, digest) of kept epochs later files may repeat
        self.error: str | None = None                 # the first file not consecutive (raised at the end)

    def start(self, i: int, later_first: float) -> None:
        """File ``i`` (of the names) begins; ``later_first``: the first epoch of the files after it."""
        self.i, self.later_first = i, later_first
        self.cur = {"file": self.names[i], "epochs": [], "used": [], "dup_t": [], "dup_rows": [], "dup_d": [],
                    "first_used": None, "prev_name": self.prev_name, "prev_last": self.prev_last}

    def filter(self, tab: Table) -> Table | None:
        """The rows of whole epochs ``tab`` to keep (None: none, or an error is pending)."""
        t = tab["time_s"]
        self.cur["epochs"].append(unique_sorted(t))
        if self.error is not None:
            return None
        if t.size and t[0] <= self.prev_last:
            k = np.searchsorted(self.seen, t)
            dup = (k < self.seen.size) & (self.seen[np.minimum(k, max(self.seen.size - 1, 0))] == t) \
                if self.seen.size else np.zeros(t.size, dtype=bool)
            inside = ~dup & (t <= self.prev_last)
            if inside.any():
                self.error = (f"{self.names[self.i]}: epoch {self.time_text(float(t[np.flatnonzero(inside)[0]]))} lies "
                              f"inside the span of the earlier file {self.prev_name} (up to "
                              f"{self.time_text(self.prev_last)}), which does not have it: the files are not "
                              f"consecutive pieces of one record")
                return None
            if dup.any():
                e, r, d = _epoch_digests(tab.take(dup), self.vocab, self.name_columns)
                self.cur["dup_t"].append(e)
                self.cur["dup_rows"].append(r)
                self.cur["dup_d"].append(d)
                tab = tab.take(~dup)
                t = tab["time_s"]
        if not t.size:
            return None
        if self.cur["first_used"] is None:
            self.cur["first_used"] = float(t[0])
        self.cur["used"].append(unique_sorted(t))
        if t[-1] >= self.later_first:
            later = t >= self.later_first
            self.digests.append(_epoch_digests(tab.take(later) if not later.all() else tab, self.vocab,
                                               self.name_columns))
        return tab

    def finish_file(self) -> None:
        """File done: record what the report needs."""
        cur = self.cur
        cur["epochs"] = np.concatenate(cur["epochs"]) if cur["epochs"] else np.array([])
        used = np.concatenate(cur["used"]) if cur["used"] else np.array([])
        cur["epochs_used"] = int(used.size)
        if cur["dup_t"]:
            cur["identical"] = self._same_as_kept(np.concatenate(cur["dup_t"]), np.concatenate(cur["dup_rows"]),
                                                  np.concatenate(cur["dup_d"]))
        for k in ("used", "dup_rows", "dup_d"):
            del cur[k]
        cur["dup_t"] = np.concatenate(cur["dup_t"]) if cur["dup_t"] else None
        self.files.append(cur)
        if used.size and self.error is None:
            self.seen = np.concatenate([self.seen, used])
            self.prev_last, self.prev_name = float(self.seen[-1]), cur["file"]

    def _same_as_kept(self, t: np.ndarray, rows: np.ndarray, d: np.ndarray) -> bool:
        if not self.digests:
            return False
        kt = np.concatenate([x[0] for x in self.digests])
        kr = np.concatenate([x[1] for x in self.digests])
        kd = np.concatenate([x[2] for x in self.digests])
        k = np.searchsorted(kt, t)
        if (k >= kt.size).any() or not (kt[np.minimum(k, kt.size - 1)] == t).all():
            return False
        return bool((kr[k] == rows).all() and (kd[k] == d).all())

    def report(self, interval_s: float, what: str):
        """The :class:`cdgps_cli.io.log_sequence.JoinReport` of the files joined, as ``join_tables``
        words it."""
        from cdgps_cli.io.log_sequence import JoinReport, _gap  # noqa: PLC0415

        rep = JoinReport()
        pre = f"{what}: " if what else ""
        for f in self.files:
            epochs = np.unique(f["epochs"])
            if f["dup_t"] is not None:
                t_rep = np.unique(f["dup_t"])
                earlier = sorted({e["file"] for e in rep.files if e["epochs_used"] and e["last_s"] is not None
                                  and e["last_s"] >= t_rep[0] and e["first_s"] <= t_rep[-1]})
                rep.overlaps.append({"file": f["file"], "earlier_file": ", ".join(earlier), "start_s": float(t_rep[0]),
                                     "end_s": float(t_rep[-1]), "epochs": int(t_rep.size),
                                     "identical": bool(f["identical"])})
                rep.warnings.append(f"{pre}{f['file']} repeats {t_rep.size} epoch(s) of {', '.join(earlier)} "
                                    f"({self.time_text(float(t_rep[0]))} – {self.time_text(float(t_rep[-1]))}); "
                                    + ("the rows are identical; kept once" if f["identical"] else
                                       f"the rows DIFFER; kept those of {', '.join(earlier)}"))
            if f["epochs_used"] and f["prev_name"] is not None:
                _gap(rep, f["prev_name"], f["file"], f["prev_last"], f["first_used"], interval_s, self.time_text, pre)
            rep.files.append({"file": f["file"], "first_s": float(epochs[0]) if epochs.size else None,
                              "last_s": float(epochs[-1]) if epochs.size else None, "epochs": int(epochs.size),
                              "epochs_used": int(f["epochs_used"])})
        return rep


# ------------------------------------------------------------------------------------------------
# a log, one file or many


def first_epoch(path: str | Path) -> float:
    """The time of a log's first data row (−inf when it is not a number: the file is read first
    and its problems reported; +inf for a log without rows), for ordering consecutive files."""
    import bz2  # noqa: PLC0415
    import gzip  # noqa: PLC0415
    import lzma  # noqa: PLC0415

    p = Path(path)
    opener = {".gz": gzip.open, ".xz": lzma.open, ".bz2": bz2.open}.get(p.suffix, open)
    try:
        with opener(p, "rb") as fh:
            fh.readline(4097)
            for _ in range(1000):
                line = fh.readline(1 << 16)
                if not line:
                    return np.inf
                if line.strip(b"\r\n"):
                    return float(line.split(b",", 1)[0].strip().strip(b'"'))
    except (OSError, EOFError, ValueError, lzma.LZMAError):
        pass
    return -np.inf


def stream_log(paths: list, kind: str, cfg, sink, name_columns, categorical, joins: dict, key: str,
               period_s: float | None = None, sampled: bool = True, block_bytes: int | None = None) -> None:
    """Read the log of ``kind`` given as one file or as consecutive files (``paths``), validated
    block by block, and give ``sink.add`` its whole epochs in time order (several files: joined by
    the rule of :func:`cdgps_cli.io.log_sequence.join_tables`, the files of another rate or receiver
    refused).  ``paths`` is reordered in place to time order; ``joins[key]`` gets the report and
    warnings when there are several files.

    ``period_s``: the record's sample period (None: the median spacing of the data); ``sampled``
    False: an event log (no rate to compare, no gaps)."""
    from cdgps_cli.io.logs import LOG_BLOCK_BYTES, valid_blocks  # noqa: PLC0415

    block_bytes = LOG_BLOCK_BYTES if block_bytes is None else block_bytes

    def tables(path):
        for df in valid_blocks(path, kind, cfg, block_bytes):
            yield Table.from_frame(df, name_columns=name_columns, categorical=categorical)

    if len(paths) == 1:
        ep = _Epochs(name_columns, categorical)
        for tab in tables(paths[0]):
            if (whole := ep.add(tab)) is not None:
                sink.add(whole)
        if (rest := ep.flush()) is not None:
            sink.add(rest)
        return
    _stream_files(paths, tables, sink, name_columns, categorical, joins, key, period_s, sampled)


def _stream_files(paths: list, tables, sink, name_columns, categorical, joins: dict, key: str, period_s,
                  sampled: bool) -> None:
    """:func:`stream_log` of several files (``tables(path)``: a file's validated blocks)."""
    from cdgps_cli.core.gps_time import nominal_interval_s  # noqa: PLC0415

    given = list(paths)
    names = [Path(p).name if len({Path(q).name for q in paths}) == len(paths) else str(p) for p in paths]
    firsts = [first_epoch(p) for p in paths]
    order = sorted(range(len(paths)), key=lambda i: (firsts[i], i))
    join = _Join(names, firsts, name_columns)
    receivers: dict = {}
    refused: list = []                  # (as the whole-file join: validation, then rate, receivers, join)
    for pos, i in enumerate(order):
        later = min((firsts[j] for j in order[pos + 1:]), default=np.inf)
        join.start(i, later)
        ep = _Epochs(name_columns, categorical)

        def give(tab):
            if tab is not None and (kept := join.filter(tab)) is not None and not refused:
                sink.add(kept)

        for tab in tables(paths[i]):
            if "receiver" in tab.columns and not refused:
                refused += _other_receivers(paths[i], tab, receivers)
            give(ep.add(tab))
        give(ep.flush())
        join.finish_file()
    epochs = {i: f["epochs"] for i, f in zip(order, join.files)}
    dts = [nominal_interval_s(epochs[i]) for i in range(len(paths))]
    ref = next((i for i, dt in enumerate(dts) if np.isfinite(dt)), None)
    for p, dt in zip(given, dts):
        if sampled and ref is not None and np.isfinite(dt) and abs(dt - dts[ref]) > 1e-6 * max(dts[ref], 1.0):
            raise CdgpsError(f"{p}: epoch interval {dt:g} s differs from {dts[ref]:g} s in {given[ref]}; the files of one "
                             f"record must have one rate")
    if refused or join.error:
        raise CdgpsError(refused[0] if refused else join.error)
    period = (period_s or nominal_interval_s(np.concatenate(list(epochs.values())))) if sampled else float("nan")
    rep = join.report(period, key)
    paths[:] = [paths[i] for i in order]
    joins[key] = {"report": rep.as_dict(), "warnings": rep.warnings}


def _other_receivers(path, tab: Table, seen: dict) -> list:
    """The refusal (a list of one message, or none) of an antenna measured by another receiver than
    in an earlier file (or earlier in this one), naming the file, antenna and both receivers."""
    a, aw = tab.codes("antenna")
    r, rw = tab.codes("receiver")
    pair = a.astype(np.int64) * max(len(rw), 1) + r
    _, first = np.unique(pair, return_index=True)
    for k in np.sort(first).tolist():
        antenna, receiver = aw[a[k]], rw[r[k]]
        prev = seen.setdefault(antenna, (receiver, path))
        if prev[0] != receiver:
            return [f"{path}: antenna {antenna} is measured by receiver {receiver!r}, by {prev[0]!r} in "
                    f"{prev[1]}; the files of one record must be one receiver's log per antenna"]
    return []


def npy_header(dtype, n: int) -> bytes:
    """The ``.npy`` header ``np.save`` writes for a 1-D array of ``n`` numbers of ``dtype``."""
    import io  # noqa: PLC0415

    head = io.BytesIO()
    d = {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False, "shape": (int(n),)}
    np.lib.format.write_array_header_1_0(head, d)
    return head.getvalue()


def names_json(words) -> bytes:
    return json.dumps(list(words)).encode()
