"""Native CSV log formats: reading and validation.

Receiver log (one row per epoch and channel)::

    time_s,receiver,master,antenna,transmitter,phase_cycles,lock,snr_dbhz

``phase_cycles`` is the accumulated differential carrier phase of ``antenna`` minus ``master`` for
``transmitter`` (λ·phase_cycles = |p_tx − p_antenna| − |p_tx − p_master| + bias + noise); ``lock``
counts epochs since lock (0 = new lock or slip); ``snr_dbhz`` may be empty.

Gyro log: ``time_s,gyro,rate_rad_s``.  Actuator log: ``time_s,actuator,force_n`` (a thruster's
commanded force from ``time_s`` until its next row; 0 before its first row).

Files ending in ``.gz``, ``.xz`` or ``.bz2`` are decompressed on the fly.  Every reader validates the whole file and raises one :class:`CdgpsError` naming the file, the
line (1-based, the header is line 1) and the problem, listing at most a few lines per kind of problem.
"""

from __future__ import annotations

import bz2
import io
import gzip
import lzma
import re
from collections import Counter
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.core import progress
from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.limits import LOG_BOUNDS

RECEIVER_COLUMNS = ("time_s", "receiver", "master", "antenna", "transmitter", "phase_cycles", "lock", "snr_dbhz")
GYRO_COLUMNS = ("time_s", "gyro", "rate_rad_s")
ACTUATOR_COLUMNS = ("time_s", "actuator", "force_n")
_MAX_LINES_PER_PROBLEM = 5
_MAX_LOCK = 2.0 ** 53       # epochs since lock: exact as float64 and as int64
_MAX_HEADER_BYTES = 4096    # a header of the known columns is < 100 bytes; longer is not a log of ours


def _check_header_line(p: Path, raw: bytes, columns: tuple) -> None:
    """Refuse, in time linear in ``raw`` (at most ``_MAX_HEADER_BYTES + 1`` bytes), a first line that
    cannot be a header: CR-only line endings (the whole file would read as one line) or no line end."""
    expected = f"expected the header {','.join(columns)}"
    if b"\r" in raw.rstrip(b"\r\n"):
        raise CdgpsError(f"{p}, line 1: line endings are CR only (classic Mac); convert to LF or CRLF; {expected}")
    if len(raw) > _MAX_HEADER_BYTES:
        raise CdgpsError(f"{p}, line 1: first line longer than {_MAX_HEADER_BYTES} bytes, not a header; {expected}")


def _not_utf8(p: Path, opener) -> str:
    """The message for a log that is not UTF-8: the line and byte offset of the first invalid byte
    (of the decompressed text), found in one pass over the file."""
    import codecs  # noqa: PLC0415

    dec = codecs.getincrementaldecoder("utf-8")()
    line, offset = 1, 0
    try:
        with opener(p, "rb") as fh:
            while chunk := fh.read(1 << 20):
                try:
                    dec.decode(chunk)
                except UnicodeDecodeError as exc:
                    pending = len(exc.object) - len(chunk)      # bytes the decoder held back from before
                    at = exc.start - pending
                    line += chunk.count(b"\n", 0, max(at, 0))
                    bad = exc.object[exc.start]
                    return (f"{p}, line {line}: not UTF-8 text (byte {bad:#04x} at offset {offset + at}); "
                            f"expected a UTF-8 (or ASCII) CSV log")
                line += chunk.count(b"\n")
                offset += len(chunk)
    except (OSError, EOFError, lzma.LZMAError):
        pass
    return f"{p}: not a UTF-8 text file"


class _Problems:
    """The problems found in one block of a log's rows (row ``i`` of the block is row ``row0 + i`` of
    the file, line ``row0 + i + 2``).  :class:`LogProblems` gathers the blocks of a file."""

    def __init__(self, path, row0: int = 0):
        self.path = path
        self.row0 = row0
        self.kinds: dict[str, list] = {}              # what -> [the lines shown, rows with it]
        self.calls: list[str] = []                    # every check made, in order (with or without rows)
        self.first_row: int | None = None             # the block's first row with a problem
        self.time_s: np.ndarray | None = None         # the block's times, once read (named in the message)

    def rows(self, mask: np.ndarray, what: str, values=None) -> None:
        if what not in self.kinds and what not in self.calls:
            self.calls.append(what)
        idx = np.flatnonzero(mask)
        if idx.size == 0:
            return
        self.first_row = int(idx[0]) if self.first_row is None else min(self.first_row, int(idx[0]))
        shown, n = self.kinds.setdefault(what, [[], 0])
        for i in idx[:max(_MAX_LINES_PER_PROBLEM - len(shown), 0)]:
            extra = f" (got {values[i]!r})" if values is not None else ""
            shown.append(f"{self.path}, line {self.row0 + i + 2}: {what}{extra}")
        self.kinds[what][1] = n + int(idx.size)

    def when(self, last_ok_s: float | None = None) -> str:
        """``, the first at time_s T s`` (or ``after`` the last readable time before it, from an
        earlier block when this one has none): where in the record a problem is (a day of hourly
        logs: which hour)."""
        if self.first_row is None or self.time_s is None or self.first_row >= self.time_s.size:
            return ""
        t = self.time_s[:self.first_row + 1]
        ok = np.flatnonzero(np.isfinite(t) & (t >= 0))
        if ok.size == 0:
            return "" if last_ok_s is None else f", the first after time_s {last_ok_s:g} s"
        return f", the first at time_s {t[ok[-1]]:g} s" if ok[-1] == self.first_row else \
            f", the first after time_s {t[ok[-1]]:g} s"

    def last_ok_s(self) -> float | None:
        """The block's last finite, non-negative time (None: none)."""
        if self.time_s is None:
            return None
        ok = np.flatnonzero(np.isfinite(self.time_s) & (self.time_s >= 0))
        return float(self.time_s[ok[-1]]) if ok.size else None

    def raise_if_any(self) -> None:
        probs = LogProblems(self.path)
        probs.merge(self)
        probs.raise_if_any()


class LogProblems:
    """The problems of a whole log, gathered block by block (:meth:`merge`): the same message as
    one reading of the whole file — each kind of problem in the order the checks run, its first
    few lines, the count of the others, and the time of the first."""

    def __init__(self, path):
        self.path = path
        self.order: list[str] = []
        self.kinds: dict[str, list] = {}
        self._when: str | None = None
        self._last_ok: float | None = None

    def merge(self, block: _Problems) -> None:
        """Add a block's problems (blocks in file order)."""
        for j, what in enumerate(block.calls):      # each block's checks run in the one order: merge it
            if what in self.order:
                continue
            later = next((self.order.index(w) for w in block.calls[j + 1:] if w in self.order), len(self.order))
            self.order.insert(later, what)
        for what, (shown, n) in block.kinds.items():
            mine = self.kinds.setdefault(what, [[], 0])
            mine[0].extend(shown[:max(_MAX_LINES_PER_PROBLEM - len(mine[0]), 0)])
            mine[1] += n
        if block.kinds and self._when is None:
            self._when = block.when(self._last_ok)
        last = block.last_ok_s()
        self._last_ok = last if last is not None else self._last_ok

    def __bool__(self) -> bool:
        return bool(self.kinds)

    def items(self) -> list[str]:
        out = []
        for what in self.order:
            if what in self.kinds:
                shown, n = self.kinds[what]
                out.extend(shown)
                if n > len(shown):
                    out.append(f"{self.path}: … and {n - len(shown)} more lines with: {what}")
        return out

    def raise_if_any(self) -> None:
        items = self.items()
        if items:
            head = (f"{self.path}: invalid log ({len(items)} problem{'s' if len(items) > 1 else ''}"
                    f"{self._when or ''})")
            raise CdgpsError(head + "\n  - " + "\n  - ".join(items))


def _parser_error_line(msg: str) -> str:
    """``", line N"`` (1-based, header = line 1) from a pandas tokenizer message, which counts
    ``line N`` from 1 but ``row N`` (an unclosed quote) from 0; empty if it names neither."""
    m = re.search(r"\b(line|row) (\d+)", msg)
    if not m:
        return ""
    return f", line {int(m.group(2)) + (1 if m.group(1) == 'row' else 0)}"


def _shift_lines(msg: str, lines: int) -> str:
    """A pandas tokenizer message about a block of a file (its header, then the block's lines) with
    its ``line N`` / ``row N`` counted in the file: ``lines`` is the number of the file's lines
    between the header and the block."""
    if not lines:
        return msg
    return re.sub(r"\b(line|row) (\d+)", lambda m: f"{m.group(1)} {int(m.group(2)) + lines}", msg)


LOG_BLOCK_BYTES = 4 << 20
"""Bytes of CSV text parsed at a time by :func:`log_blocks` (about 90,000 receiver log rows): the
memory of ``cdgps ingest`` does not grow with the record (issue 29); peak RSS of ``cdgps ingest``
of a 1 h testbed record: 144 / 181 / 243 / 280 MiB with blocks of 4 / 8 / 16 / 32 MiB, the time
the same (the JSON messages dominate it)."""


def _header(p: Path, columns: tuple):
    """The log's opener, its header line (raw bytes) and whether the typed reading applies; header
    problems are a CdgpsError."""
    opener = {".gz": gzip.open, ".xz": lzma.open, ".bz2": bz2.open}.get(p.suffix, open)
    try:
        with opener(p, "rb") as fh:
            raw = fh.readline(_MAX_HEADER_BYTES + 1)
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except (EOFError, lzma.LZMAError):
        raise CdgpsError(f"{p}: truncated or corrupt compressed file") from None
    _check_header_line(p, raw, columns)
    try:
        head = raw.decode("utf-8").strip().lstrip("\ufeff")
    except UnicodeDecodeError:
        raise CdgpsError(_not_utf8(p, opener)) from None
    if not head:
        raise CdgpsError(f"{p}, line 1: empty file; expected the header {','.join(columns)}")
    header = [h.strip() for h in head.split(",")]
    counts = Counter(header)
    missing = [c for c in columns if c not in counts]
    unknown = [c for c in header if c not in columns][:_MAX_LINES_PER_PROBLEM]
    dup = sorted(c for c, k in counts.items() if k > 1)
    if missing or unknown or dup:
        msg = []
        if missing:
            msg.append(f"missing column(s) {', '.join(missing)}")
        if unknown:
            msg.append(f"unknown column(s) {', '.join(unknown)}")
        if dup:
            msg.append(f"duplicate column(s) {', '.join(dup)}")
        raise CdgpsError(f"{p}, line 1: " + "; ".join(msg) + f"; expected the header {','.join(columns)}")
    return opener, raw, FAST_PARSE and all(h == h.strip() for h in head.split(","))


def _whole_file(p: Path, opener):
    """The log opened for pandas (decompressed), with a progress bar over its bytes."""
    @contextmanager
    def source():
        with progress.reading(p) as raw, (nullcontext(raw) if opener is open else opener(raw, "rb")) as fh:
            yield fh
    return source


def _text_pieces(p: Path, opener, header: bytes, block_bytes: int):
    """``(lines_before, source)`` of consecutive pieces of the log's text after the header, each
    about ``block_bytes`` of whole lines, as pandas sources (the header, then the piece's lines);
    ``lines_before``: the file's lines between the header and the piece."""
    lines = 0
    try:
        with progress.reading(p) as raw, (nullcontext(raw) if opener is open else opener(raw, "rb")) as fh:
            fh.readline(_MAX_HEADER_BYTES + 1)
            rest = b""
            while True:
                data = fh.read(block_bytes)
                if not data:
                    break
                data = rest + data
                cut = data.rfind(b"\n") + 1
                if cut == 0:
                    rest = data
                    continue
                piece, rest = data[:cut], data[cut:]
                yield lines, (lambda b=header + piece: nullcontext(io.BytesIO(b)))
                lines += piece.count(b"\n")
            if rest:
                yield lines, (lambda b=header + rest: nullcontext(io.BytesIO(b)))
    except (EOFError, OSError, lzma.LZMAError) as exc:
        raise CdgpsError(f"{p}: cannot read: {exc}") from None


def log_blocks(path: str | Path, columns: tuple, numeric: tuple, optional_numeric: tuple = (),
               allow_empty: bool = False, block_bytes: int | None = LOG_BLOCK_BYTES):
    """Read a log a block of rows at a time: ``(table, problems)`` per block (the typed reading
    when it finds nothing to report, else the text reading, which reports), then, after the last
    block, an empty file is an error.  ``problems`` is the block's :class:`_Problems` (rows of the
    file); ``block_bytes`` None: the whole file is one block."""
    p = Path(path)
    opener, raw, fast = _header(p, columns)
    pieces = [(0, _whole_file(p, opener))] if block_bytes is None else _text_pieces(p, opener, raw, block_bytes)
    rows = 0
    for lines, source in pieces:
        df, probs = _parse_block(p, opener, source, lines, rows, columns, numeric, optional_numeric,
                                 allow_empty or block_bytes is not None, fast)
        rows += len(df)
        yield df, probs
    if rows == 0 and not allow_empty:
        raise CdgpsError(f"{p}: no data rows after the header")


def _parse_block(p: Path, opener, source, lines: int, row0: int, columns: tuple, numeric: tuple,
                 optional_numeric: tuple, allow_empty: bool, fast: bool) -> tuple[pd.DataFrame, _Problems]:
    probs = _Problems(str(p), row0)
    if lines:
        _check_first_line(p, source, lines)
    if fast:
        table = _fast_table(p, source, columns, numeric, optional_numeric, allow_empty)
        if table is not None:
            probs.time_s = table["time_s"].to_numpy() if "time_s" in table else None
            return table, probs
    try:
        with source() as fh:
            df = pd.read_csv(fh, dtype=str, keep_default_na=False, na_filter=False, engine="c")
    except pd.errors.ParserError as exc:
        msg = _shift_lines(str(exc), lines)
        raise CdgpsError(f"{p}{_parser_error_line(msg)}: malformed CSV: {msg.strip()}") from None
    except UnicodeDecodeError:
        raise CdgpsError(_not_utf8(p, opener)) from None
    except (EOFError, OSError, lzma.LZMAError) as exc:
        raise CdgpsError(f"{p}: cannot read: {exc}") from None
    df.columns = [c.strip() for c in df.columns]
    if len(df) == 0 and not allow_empty:
        raise CdgpsError(f"{p}: no data rows after the header")
    out = {}
    for c in progress.iterate(columns, f"checking {p.name}", unit="column"):
        col = df[c].astype(str).str.strip()     # every column is text (dtype=str): object or pandas>=3 str dtype
        if c in numeric or c in optional_numeric:
            empty = col.to_numpy() == ""
            vals = pd.to_numeric(col.where(~empty, "nan"), errors="coerce").to_numpy(dtype=float)
            literal_nan = col.str.lower().isin(["nan", "+nan", "-nan"]).to_numpy()
            bad = np.isnan(vals) & ~empty & ~literal_nan
            probs.rows(bad, f"column {c}: not a number", col.to_numpy())
            if c in numeric:
                probs.rows(empty, f"column {c}: empty value")
                probs.rows(literal_nan, f"column {c}: NaN value")
            _check_bounds(c, vals, col.to_numpy(), probs)
            out[c] = vals
            if c == "time_s":
                probs.time_s = vals
        else:
            v = col.to_numpy()
            probs.rows(v == "", f"column {c}: empty value")
            out[c] = v
    return pd.DataFrame(out, columns=list(columns)), probs


def _check_first_line(p: Path, source, lines: int) -> None:
    """A block's first line with more fields than the header is malformed, as in the whole file
    (pandas would take a first data line with one more field as having an index column): the
    tokenizer's message for it, counted in the file."""
    with source() as fh:
        header = fh.readline()
        first = b""
        while not first.strip(b"\r\n"):
            line = fh.readline()
            if not line:
                return
            first += line
    try:
        pd.read_csv(io.BytesIO(header + header + first), dtype=str, keep_default_na=False, na_filter=False,
                    engine="c")
    except pd.errors.ParserError as exc:
        msg = _shift_lines(str(exc), lines - 1)
        if "Expected" in msg:
            raise CdgpsError(f"{p}{_parser_error_line(msg)}: malformed CSV: {msg.strip()}") from None
    except (ValueError, UnicodeDecodeError):
        return


FAST_PARSE = True
"""Read a log with typed columns first (:func:`_fast_table`); the text reading below only when that
finds something to report (tests/io/test_log_fast_path.py compares the two)."""


def _fast_table(p: Path, source, columns: tuple, numeric: tuple, optional_numeric: tuple,
                allow_empty: bool) -> pd.DataFrame | None:
    """The table of a valid log (or block of one, opened by ``source()``) read with typed columns
    (issue 29 item 4: numbers parsed by pandas' C reader as floats, names as categoricals), or None
    when it has anything the text reading reports (a value that is not a number, empty or NaN where
    a number is required, a value outside its bounds, an empty or padded name, a malformed line):
    that reading then gives the messages.  For a valid log both give the same table, bit for bit
    (the same float parser)."""
    kinds = {c: (float if c in numeric or c in optional_numeric else "category") for c in columns}
    try:
        with source() as fh:
            df = pd.read_csv(fh, dtype=kinds, keep_default_na=False, engine="c",
                             na_values={c: [""] for c in optional_numeric})
    except (ValueError, TypeError, UnicodeDecodeError, EOFError, OSError, lzma.LZMAError):
        return None                                   # (pandas' ParserError is a ValueError)
    if len(df) == 0 and not allow_empty:
        return None
    out = {}
    for c in columns:
        col = df[c]
        if c in kinds and kinds[c] is float:
            vals = col.to_numpy(dtype=float)
            if (c in numeric and np.isnan(vals).any()) or not _within_bounds(c, vals):
                return None
            out[c] = vals
        else:
            words = [str(w) for w in col.cat.categories]
            if any(w == "" or w != w.strip() for w in words) or col.isna().any():
                return None
            out[c] = col                              # (categorical: the checks below work on its codes)
    return pd.DataFrame(out, columns=list(columns))


def _within_bounds(c: str, vals: np.ndarray) -> bool:
    """No value :func:`_check_bounds` would report."""
    probs = _Problems("")
    _check_bounds(c, vals, vals, probs)
    return not probs.kinds


def _check_bounds(c: str, vals: np.ndarray, text: np.ndarray, probs: _Problems) -> None:
    """Rows whose column ``c`` is infinite or outside its plausible range (limits.LOG_BOUNDS); for
    ``time_s`` only the upper bound (infinite and negative times have their own messages)."""
    b = LOG_BOUNDS.get(c)
    if b is None:
        return
    with np.errstate(invalid="ignore"):
        if c == "time_s":
            bad = np.isfinite(vals) & (vals > b.hi)
        else:
            bad = np.isinf(vals) | (np.isfinite(vals) & ((vals < b.lo) | (vals > b.hi)))
    probs.rows(bad, f"column {c}: outside the plausible range {b.text()}", text)


class _Carry:
    """What the checks of a block need from the blocks before it: the last time (time order) and
    the duplicate keys of the rows at that time (a repeated row has its time)."""

    def __init__(self):
        self.last_t: float | None = None
        self.tail: pd.DataFrame | None = None
        self.ids: dict = {}                           # name -> number, for the duplicate keys

    def name_ids(self, col: pd.Series) -> np.ndarray:
        """Each row's name as a number (the same name, the same number in every block)."""
        if isinstance(col.dtype, pd.CategoricalDtype):
            codes, words = col.cat.codes.to_numpy(), col.cat.categories
        else:
            codes, words = pd.factorize(col.to_numpy())
        lut = np.array([self.ids.setdefault(str(w), len(self.ids)) for w in words] or [0], dtype=np.int64)
        return lut[codes]

    def duplicated(self, key: pd.DataFrame) -> np.ndarray:
        """Rows of ``key`` (the block's) repeating an earlier row's key (of this block, or of the
        rows before it at the same time)."""
        n_tail = 0 if self.tail is None else len(self.tail)
        both = key if not n_tail else pd.concat([self.tail, key], ignore_index=True)
        dup = both.duplicated().to_numpy()[n_tail:]
        t = both["t"].to_numpy()
        if t.size:
            same = np.flatnonzero(t != t[-1])
            self.tail = both.iloc[(int(same[-1]) + 1 if same.size else 0):].reset_index(drop=True)
        return dup


def _check_time(df: pd.DataFrame, probs: _Problems, carry: _Carry) -> None:
    t = df["time_s"].to_numpy()
    probs.rows(np.isinf(t), "column time_s: not finite")
    probs.rows(t < 0, "column time_s: negative time", t)
    prev = np.nan if carry.last_t is None else carry.last_t
    back = np.diff(np.r_[prev, t]) < 0
    probs.rows(back, "time goes backwards (rows must be in time order)", t)
    if t.size:
        carry.last_t = float(t[-1])


def _check_names(df, col, allowed, probs, what):
    if isinstance(df[col].dtype, pd.CategoricalDtype):          # (the typed reading: by its few names)
        cats = df[col].cat.categories
        unknown = np.flatnonzero(~cats.isin(allowed))
        if unknown.size:
            codes = df[col].cat.codes.to_numpy()
            probs.rows(np.isin(codes, unknown), f"column {col}: {what} not in the config (known: {', '.join(allowed)})",
                       df[col].to_numpy())
        return
    v = df[col].to_numpy()
    bad = ~pd.Series(v).isin(allowed).to_numpy() & (v != "")
    probs.rows(bad, f"column {col}: {what} not in the config (known: {', '.join(allowed)})", v)


RECEIVER_NUMERIC = ("time_s", "phase_cycles", "lock")


def _check_receiver(df: pd.DataFrame, probs: _Problems, cfg: StructureConfig, carry: _Carry) -> None:
    """Every check of a receiver log's rows (a block of them, after ``carry``'s)."""
    _check_time(df, probs, carry)
    ph = df["phase_cycles"].to_numpy()
    probs.rows(np.isinf(ph), "column phase_cycles: infinite phase")
    lock = df["lock"].to_numpy()
    badlock = ~np.isnan(lock) & ~((lock >= 0) & (lock <= _MAX_LOCK) & (lock == np.round(lock)))
    probs.rows(badlock, f"column lock: expected a non-negative integer up to {_MAX_LOCK:.0f}", lock)
    _check_names(df, "antenna", list(cfg.rover_names), probs, "antenna")
    _check_names(df, "transmitter", list(cfg.transmitter_names), probs, "transmitter")
    master = cfg.antenna_names[cfg.master_index]
    m = df["master"]
    if isinstance(m.dtype, pd.CategoricalDtype) and list(m.cat.categories) == [master]:
        pass                                                     # (the typed reading: every row names it)
    else:
        probs.rows(m.to_numpy() != master, f"column master: expected the config's master antenna {master!r}", m.to_numpy())
    # (+0.0: -0.0 and 0.0 one key)
    key = pd.DataFrame({"t": df["time_s"].to_numpy(dtype=float) + 0.0,
                        "p": carry.name_ids(df["antenna"]) * (1 << 32) + carry.name_ids(df["transmitter"])})
    probs.rows(carry.duplicated(key), "duplicate row (same time_s, antenna and transmitter as an earlier row)")


def _check_named_series(df: pd.DataFrame, probs: _Problems, carry: _Carry, name: str, allowed: list,
                        what: str) -> None:
    """Every check of a ``time_s,<name>,<value>`` log's rows (a block of them)."""
    _check_time(df, probs, carry)
    _check_names(df, name, allowed, probs, what)
    key = pd.DataFrame({"t": df["time_s"].to_numpy(dtype=float), "p": carry.name_ids(df[name])})
    probs.rows(carry.duplicated(key), f"duplicate row (same time_s and {name} as an earlier row)")


def _log_spec(kind: str, cfg: StructureConfig) -> tuple:
    """(columns, numeric, optional numeric, allow_empty, check) of a log kind."""
    if kind == "receiver":
        return (RECEIVER_COLUMNS, RECEIVER_NUMERIC, ("snr_dbhz",), False,
                lambda df, probs, carry: _check_receiver(df, probs, cfg, carry))
    if kind == "gyro":
        allowed = list(cfg.gyro_names)
        return (GYRO_COLUMNS, ("time_s", "rate_rad_s"), (), not cfg.gyro_names,
                lambda df, probs, carry: _check_named_series(df, probs, carry, "gyro", allowed, "gyro"))
    if kind == "actuator":
        allowed = list(cfg.thruster_names)
        return (ACTUATOR_COLUMNS, ("time_s", "force_n"), (), False,
                lambda df, probs, carry: _check_named_series(df, probs, carry, "actuator", allowed, "actuator"))
    raise ValueError(f"log kind {kind!r}: expected receiver, gyro or actuator")


def valid_blocks(path: str | Path, kind: str, cfg: StructureConfig, block_bytes: int | None = LOG_BLOCK_BYTES):
    """A native log read and validated a block of rows at a time (:data:`LOG_BLOCK_BYTES`; None:
    the whole file at once): yields each block's table (columns as :func:`read_receiver_log`'s,
    ``lock`` int64) while no problem has been found; after the last block, the problems of the
    whole file (each named by file, line and time, as one reading of the file names them) are one
    CdgpsError.  A caller writing the blocks as they come writes to a temporary output (atomic).

    Parameters
    ----------
    path : path
    kind : {"receiver", "gyro", "actuator"}
    cfg : StructureConfig
    block_bytes : int or None
    """
    columns, numeric, optional, allow_empty, check = _log_spec(kind, cfg)
    probs, carry = LogProblems(str(Path(path))), _Carry()
    for df, block in log_blocks(path, columns, numeric, optional, allow_empty, block_bytes):
        check(df, block, carry)
        probs.merge(block)
        if not probs:
            if "lock" in df:
                df["lock"] = df["lock"].astype(np.int64)
            yield df
    probs.raise_if_any()


def _whole(path, kind: str, cfg: StructureConfig) -> pd.DataFrame:
    blocks = list(valid_blocks(path, kind, cfg, block_bytes=None))
    return blocks[0]


def read_receiver_log(path: str | Path, cfg: StructureConfig) -> pd.DataFrame:
    """Read and validate a receiver log against a structure config (the whole file at once;
    ``cdgps ingest`` streams it with :func:`valid_blocks`).

    Returns
    -------
    DataFrame
        Columns of :data:`RECEIVER_COLUMNS`; ``phase_cycles``, ``snr_dbhz`` (NaN when empty) and
        ``time_s`` float64, ``lock`` int64.

    Raises
    ------
    CdgpsError
        Missing or unknown columns, non-numeric values, NaN phase, time going backwards,
        duplicate (time, antenna, transmitter) rows, names unknown to the config.
    """
    return _whole(path, "receiver", cfg)


def read_gyro_log(path: str | Path, cfg: StructureConfig) -> pd.DataFrame:
    """Read and validate a gyro log (``time_s,gyro,rate_rad_s``).

    A header-only log (what ``cdgps simulate`` writes for a structure without gyros) is accepted,
    as an empty table, when the config declares no gyros; with gyros in the config it is an error."""
    return _whole(path, "gyro", cfg)


def read_actuator_log(path: str | Path, cfg: StructureConfig) -> pd.DataFrame:
    """Read and validate an actuator log (``time_s,actuator,force_n``)."""
    return _whole(path, "actuator", cfg)
