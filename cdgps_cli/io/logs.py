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
import gzip
import lzma
import re
from collections import Counter
from contextlib import nullcontext
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
    def __init__(self, path):
        self.path = path
        self.items: list[str] = []
        self.first_row: int | None = None             # the first row with a problem
        self.time_s: np.ndarray | None = None         # the rows' times, once read (named in the message)

    def rows(self, mask: np.ndarray, what: str, values=None) -> None:
        idx = np.flatnonzero(mask)
        if idx.size == 0:
            return
        self.first_row = int(idx[0]) if self.first_row is None else min(self.first_row, int(idx[0]))
        shown = idx[:_MAX_LINES_PER_PROBLEM]
        for i in shown:
            extra = f" (got {values[i]!r})" if values is not None else ""
            self.items.append(f"{self.path}, line {i + 2}: {what}{extra}")
        if idx.size > shown.size:
            self.items.append(f"{self.path}: … and {idx.size - shown.size} more lines with: {what}")

    def add(self, msg: str) -> None:
        self.items.append(f"{self.path}: {msg}")

    def when(self) -> str:
        """``, the first at time_s T s`` (or ``after`` the last readable time before it): where in the
        record a problem is (a day of hourly logs: which hour)."""
        if self.first_row is None or self.time_s is None or self.first_row >= self.time_s.size:
            return ""
        t = self.time_s[:self.first_row + 1]
        ok = np.flatnonzero(np.isfinite(t) & (t >= 0))
        if ok.size == 0:
            return ""
        return f", the first at time_s {t[ok[-1]]:g} s" if ok[-1] == self.first_row else \
            f", the first after time_s {t[ok[-1]]:g} s"

    def raise_if_any(self) -> None:
        if self.items:
            head = f"{self.path}: invalid log ({len(self.items)} problem{'s' if len(self.items) > 1 else ''}{self.when()})"
            raise CdgpsError(head + "\n  - " + "\n  - ".join(self.items))


def _parser_error_line(msg: str) -> str:
    """``", line N"`` (1-based, header = line 1) from a pandas tokenizer message, which counts
    ``line N`` from 1 but ``row N`` (an unclosed quote) from 0; empty if it names neither."""
    m = re.search(r"\b(line|row) (\d+)", msg)
    if not m:
        return ""
    return f", line {int(m.group(2)) + (1 if m.group(1) == 'row' else 0)}"


def _read_table(path: str | Path, columns: tuple, numeric: tuple, optional_numeric: tuple = (),
                allow_empty: bool = False) -> tuple[pd.DataFrame, _Problems]:
    p = Path(path)
    probs = _Problems(str(p))
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
    if FAST_PARSE and all(h == h.strip() for h in head.split(",")):
        fast = _fast_table(p, opener, columns, numeric, optional_numeric, allow_empty)
        if fast is not None:
            probs.time_s = fast["time_s"].to_numpy() if "time_s" in fast else None
            return fast, probs
    try:
        with progress.reading(p) as raw, (nullcontext(raw) if opener is open else opener(raw, "rb")) as fh:
            df = pd.read_csv(fh, dtype=str, keep_default_na=False, na_filter=False, engine="c")
    except pd.errors.ParserError as exc:
        raise CdgpsError(f"{p}{_parser_error_line(str(exc))}: malformed CSV: {str(exc).strip()}") from None
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


FAST_PARSE = True
"""Read a log with typed columns first (:func:`_fast_table`); the text reading below only when that
finds something to report (tests/io/test_log_fast_path.py compares the two)."""


def _fast_table(p: Path, opener, columns: tuple, numeric: tuple, optional_numeric: tuple,
                allow_empty: bool) -> pd.DataFrame | None:
    """The table of a valid log read with typed columns (issue 29 item 4: numbers parsed by pandas' C
    reader as floats, names as categoricals), or None when the log has anything the text reading
    reports (a value that is not a number, empty or NaN where a number is required, a value outside
    its bounds, an empty or padded name, a malformed line): that reading then gives the messages.
    For a valid log both give the same table, bit for bit (the same float parser)."""
    kinds = {c: (float if c in numeric or c in optional_numeric else "category") for c in columns}
    try:
        with progress.reading(p) as raw, (nullcontext(raw) if opener is open else opener(raw, "rb")) as fh:
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
    return not probs.items


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


def _check_time(df: pd.DataFrame, probs: _Problems) -> None:
    t = df["time_s"].to_numpy()
    probs.rows(np.isinf(t), "column time_s: not finite")
    probs.rows(t < 0, "column time_s: negative time", t)
    back = np.r_[False, np.diff(t) < 0]
    probs.rows(back, "time goes backwards (rows must be in time order)", t)


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


def read_receiver_log(path: str | Path, cfg: StructureConfig) -> pd.DataFrame:
    """Read and validate a receiver log against a structure config.

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
    df, probs = _read_table(path, RECEIVER_COLUMNS, ("time_s", "phase_cycles", "lock"), ("snr_dbhz",))
    _check_time(df, probs)
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
    probs.rows(_duplicated_rows(df), "duplicate row (same time_s, antenna and transmitter as an earlier row)")
    probs.raise_if_any()
    df["lock"] = df["lock"].astype(np.int64)
    return df


def _duplicated_rows(df: pd.DataFrame) -> np.ndarray:
    """Rows repeating an earlier row's (time_s, antenna, transmitter).  With categorical names (the
    typed reading) the key is numeric: the time's bits and the pair of name codes."""
    a, x = df["antenna"], df["transmitter"]
    if isinstance(a.dtype, pd.CategoricalDtype) and isinstance(x.dtype, pd.CategoricalDtype):
        t = df["time_s"].to_numpy(dtype=float)
        n_x = len(x.cat.categories) + 1
        a_codes, x_codes = a.cat.codes.to_numpy(), x.cat.codes.to_numpy()

        def dup(r0: int, r1: int) -> np.ndarray:
            pair = a_codes[r0:r1].astype(np.int64) * n_x + x_codes[r0:r1]
            # (+0.0: -0.0 and 0.0 one key, as in the text reading)
            return pd.DataFrame({"t": t[r0:r1] + 0.0, "p": pair}).duplicated().to_numpy()

        if t.size < 2 or not (t[1:] >= t[:-1]).all():            # (times out of order: one table, as before)
            return dup(0, t.size)
        # times in order: a repeated row has its time, so blocks cut between times find the same rows
        # (with the temporaries of a block: the whole table's hash peaked at ~75 bytes a row)
        out = np.zeros(t.size, dtype=bool)
        r0 = 0
        while r0 < t.size:
            r1 = min(r0 + _DUP_BLOCK_ROWS, t.size)
            if r1 < t.size:
                r1 = int(np.searchsorted(t, t[r1], side="left"))      # the block ends before a time's first row
                r1 = r1 if r1 > r0 else int(np.searchsorted(t, t[r0], side="right"))
            out[r0:r1] = dup(r0, r1)
            r0 = r1
        return out
    key = pd.DataFrame({"t": df["time_s"], "a": a, "x": x})
    return key.duplicated().to_numpy()


_DUP_BLOCK_ROWS = 1 << 20
"""Rows per block of the duplicate-row check on a log in time order."""


def _read_named_series(path, columns: tuple, value: str, allowed: list, what: str,
                       allow_empty: bool = False) -> pd.DataFrame:
    """A ``time_s,<name>,<value>`` log: times in order, names from the config, no duplicate rows
    (``allow_empty``: a header without rows is an empty table instead of an error)."""
    name = columns[1]
    df, probs = _read_table(path, columns, ("time_s", value), allow_empty=allow_empty)
    _check_time(df, probs)
    _check_names(df, name, allowed, probs, what)
    probs.rows(df.duplicated(["time_s", name]).to_numpy(), f"duplicate row (same time_s and {name} as an earlier row)")
    probs.raise_if_any()
    return df


def read_gyro_log(path: str | Path, cfg: StructureConfig) -> pd.DataFrame:
    """Read and validate a gyro log (``time_s,gyro,rate_rad_s``).

    A header-only log (what ``cdgps simulate`` writes for a structure without gyros) is accepted,
    as an empty table, when the config declares no gyros; with gyros in the config it is an error."""
    return _read_named_series(path, GYRO_COLUMNS, "rate_rad_s", list(cfg.gyro_names), "gyro",
                              allow_empty=not cfg.gyro_names)


def read_actuator_log(path: str | Path, cfg: StructureConfig) -> pd.DataFrame:
    """Read and validate an actuator log (``time_s,actuator,force_n``)."""
    return _read_named_series(path, ACTUATOR_COLUMNS, "force_n", list(cfg.thruster_names), "actuator")
