"""The observation archives of a GNSS RUN.mcap: each receiver's table in blocks of GPS time (issue 29).

A receiver's raw table (:data:`cdgps_cli.io.gnss_run.RAW_COLUMNS`) and its multi-signal table are stored as
zstd-compressed numpy archives, one per block of :data:`OBS_BLOCK_S` seconds of GPS time (aligned on multiples of
it, so every receiver's blocks cover the same hours), plus a small JSON index of the blocks
(``<prefix>/blocks.json``: the block span, and per block its attachment name, rows and first and last time tag).
Each block's name holds its number and its hour (``gnss/obs/0/2_2024-01-01T02h.npz.zst``: an error naming a damaged
block names the hour of the record it held).  A stage reads the whole table (the blocks joined: the same table as
one archive of it) or a window of GPS time, decoding only the blocks it overlaps
(:class:`~cdgps_cli.io.mcap.McapContents` leaves the others on disk).
RUNs written before the blocks (one ``<prefix>.npz.zst`` per receiver) are read as one block.

In each archive a text column ``c`` is ``<c>_index`` (int16) and ``<c>_names``; a numeric column is stored in its
narrow dtype and read back as float64 or int64.
"""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pandas as pd

from cdgps_cli.core.errors import CdgpsError

__all__ = ["OBS_BLOCK_S", "block_bounds", "TableBlocks", "pack_blocks", "pack_table", "has_table", "read_table", "table_span"]

OBS_BLOCK_S = 3600.0
"""Span of one archive block, GPS s (an hour: 36,000 epochs of a 10 Hz receiver; blocks start at multiples of it)."""


def pack_table(tab: pd.DataFrame, text_cols: tuple, dtypes: dict) -> bytes:
    """Columns of ``tab`` as one zstd-compressed numpy archive: each text column as ``<c>_index`` (int16) and
    ``<c>_names``, each numeric column ``c`` of ``dtypes`` in its dtype."""
    import zstandard  # noqa: PLC0415

    arrays = {}
    for c in text_cols:
        codes, names = pd.factorize(tab[c], sort=True)
        arrays[c + "_index"], arrays[c + "_names"] = codes.astype(np.int16), np.array(list(names), dtype="U8")
    for c, dt in dtypes.items():
        arrays[c] = tab[c].to_numpy().astype(dt)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    arrays.clear()                                  # (the arrays are in the archive: not held while compressing)
    with buf.getbuffer() as archive:                # (no copy of the archive)
        return zstandard.ZstdCompressor(level=3).compress(archive)


def block_bounds(time_s: np.ndarray, block_s: float | None = None) -> list:
    """Row ranges (start, stop) of ``time_s`` (GPS s, in row order) that fall in one block of ``block_s`` seconds
    each (default :data:`OBS_BLOCK_S`; a new range wherever the block number changes); one empty range for an
    empty table."""
    if time_s.size == 0:
        return [(0, 0)]
    k = np.floor(time_s / (OBS_BLOCK_S if block_s is None else block_s))
    cuts = np.flatnonzero(k[1:] != k[:-1]) + 1
    edges = np.r_[0, cuts, time_s.size].tolist()
    return list(zip(edges[:-1], edges[1:]))


class TableBlocks:
    """The archives of one table written block by block, as its rows come (:func:`pack_blocks` of a whole table;
    an ingest reading a long file hour by hour, :mod:`cdgps_cli.io.rinex_hours`): the same attachments either way.

    ``add(tab, submit)`` takes the rows of one block (none: nothing is written) and returns [(attachment name,
    ``submit(pack_table, …)``)]: ``submit(fn, *args)`` packs it (a thread pool's, returning a future; or a plain
    call).  ``finish(submit)`` returns the attachments left: an empty table's one empty block, then the index
    ``<prefix>/blocks.json`` as (name, JSON bytes)."""

    def __init__(self, prefix: str, text_cols: tuple, dtypes: dict):
        self.prefix, self.text_cols, self.dtypes = prefix, text_cols, dtypes
        self.blocks: list = []
        self._empty = None

    def add(self, tab: pd.DataFrame, submit) -> list:
        if not len(tab):
            self._empty = tab.iloc[:0]
            return []
        t = tab["time_gps_s"].to_numpy()
        name = f"{self.prefix}/{len(self.blocks)}_{_hour_label(float(t[0]))}.npz.zst"
        self.blocks.append({"name": name, "rows": int(t.size), "first_gps_s": float(t.min()),
                            "last_gps_s": float(t.max())})
        return [(name, submit(pack_table, tab, self.text_cols, self.dtypes))]

    def finish(self, submit) -> list:
        out = []
        if not self.blocks:
            name = f"{self.prefix}/0_empty.npz.zst"
            self.blocks.append({"name": name, "rows": 0, "first_gps_s": None, "last_gps_s": None})
            out.append((name, submit(pack_table, self._empty, self.text_cols, self.dtypes)))
        index = json.dumps({"block_s": OBS_BLOCK_S, "blocks": self.blocks}).encode()
        return out + [(f"{self.prefix}/blocks.json", index)]


def pack_blocks(tab: pd.DataFrame, prefix: str, text_cols: tuple, dtypes: dict, submit) -> list:
    """The attachments of ``tab`` in blocks of :data:`OBS_BLOCK_S` (:class:`TableBlocks`): [(name, bytes or
    ``submit``'s future)], the blocks, then the index."""
    tb = TableBlocks(prefix, text_cols, dtypes)
    out = [a for lo, hi in block_bounds(tab["time_gps_s"].to_numpy()) for a in tb.add(tab.iloc[lo:hi], submit)]
    return out + tb.finish(submit)


def _hour_label(t_gps_s: float) -> str:
    """'2024-01-01T02h': the GPS hour of a block, in its attachment's name (so a message naming a damaged block names
    the hour of the record it held)."""
    from cdgps_cli.core.gps_time import gps_time_str  # noqa: PLC0415

    day, clock = gps_time_str(math.floor(t_gps_s / OBS_BLOCK_S) * OBS_BLOCK_S).split()[:2]
    return f"{day}T{clock[:2]}h"


def has_table(contents, prefix: str) -> bool:
    """Whether a RUN's contents hold the table ``prefix`` (its block index, or one archive of a RUN before blocks)."""
    return contents.has_attachment(f"{prefix}/blocks.json") or contents.has_attachment(f"{prefix}.npz.zst")


def _block_list(contents, prefix: str, what: str) -> list:
    """The blocks of table ``prefix`` as [(attachment name, first s or None, last s or None)]."""
    if not contents.has_attachment(f"{prefix}/blocks.json"):
        return [(f"{prefix}.npz.zst", None, None)]          # a RUN written before the blocks: one archive
    try:
        index = json.loads(contents.attachment(f"{prefix}/blocks.json"))
        out = [(str(b["name"]), b["first_gps_s"], b["last_gps_s"]) for b in index["blocks"]]
    except (ValueError, KeyError, TypeError) as exc:
        raise CdgpsError(f"{what}: damaged block index {prefix}/blocks.json: {exc}") from None
    missing = [n for n, _, _ in out if not contents.has_attachment(n)]
    if missing or not out:
        raise CdgpsError(f"{what}: observation block(s) {', '.join(missing) or '(none listed)'} missing (damaged file)")
    return out


def _overlaps(first, last, window) -> bool:
    if window is None or first is None or last is None:
        return window is None or first is None
    return last >= window[0] and first < window[1]


def _block_arrays(data: bytes, what: str, text_cols: tuple, dtypes: dict, optional: tuple, keep) -> dict:
    """One archive's columns (text as object arrays, numbers in their stored dtype); CdgpsError when damaged."""
    import zstandard  # noqa: PLC0415

    try:
        z = np.load(io.BytesIO(zstandard.ZstdDecompressor().decompress(data)), allow_pickle=False)
        out = {c: np.asarray(z[c + "_names"], dtype=object)[z[c + "_index"].astype(np.int64)] for c in text_cols}
        for c in [c for c in dtypes if keep is None or c in keep] + [c for c in optional if c in z.files]:
            out[c] = z[c]
    except (KeyError, ValueError, OSError, zstandard.ZstdError) as exc:
        raise CdgpsError(f"{what}: damaged observation arrays: {exc}") from None
    return out


def read_table(contents, prefix: str, what: str, text_cols: tuple, dtypes: dict, columns: list,
               optional: tuple = (), keep=None, window=None) -> pd.DataFrame:
    """The table ``prefix`` of a RUN (its blocks joined in order; floats as float64, integers as int64; the
    ``optional`` numeric columns when stored; ``keep``: only these numeric columns, else all).  ``window`` (t0, t1),
    GPS s: only the rows with t0 ≤ time_gps_s < t1, from the blocks that overlap it.  CdgpsError when damaged."""
    parts = []
    for name, first, last in _block_list(contents, prefix, what):
        if not _overlaps(first, last, window):
            continue
        arrays = _block_arrays(contents.attachment(name), f"{what}:{name}", text_cols, dtypes, optional, keep)
        if window is not None:
            t = arrays["time_gps_s"]
            rows = (t >= window[0]) & (t < window[1])
            if not rows.all():
                arrays = {c: v[rows] for c, v in arrays.items()}
        parts.append(arrays)
    if not parts:                                            # a window with no block: the table's columns, no rows
        name = _block_list(contents, prefix, what)[0][0]
        arrays = _block_arrays(contents.attachment(name), f"{what}:{name}", text_cols, dtypes, optional, keep)
        parts.append({c: v[:0] for c, v in arrays.items()})
    if any(set(p) != set(parts[0]) for p in parts):
        raise CdgpsError(f"{what}: observation blocks with different columns (damaged file)")
    df = {}
    for c in list(parts[0]):                                 # (each block's column let go once joined)
        v = np.concatenate([p.pop(c) for p in parts]) if len(parts) > 1 else parts[0].pop(c)
        df[c] = v if c in text_cols else v.astype(np.float64 if v.dtype.kind == "f" else np.int64, copy=False)
    if keep is not None:
        columns = [c for c in columns if c in keep or c in text_cols]
    extra = [c for c in optional if c in df]
    # copy=False: the columns become the frame's blocks as they are (no second, consolidated copy of the table)
    return pd.DataFrame(df, columns=columns + extra, copy=False)



def table_span(contents, prefix: str, what: str) -> tuple | None:
    """(first, last) time tag of table ``prefix`` (GPS s), from its block index (a RUN before the blocks: its time
    column decoded); None when it has no rows."""
    blocks = [(a, b) for _, a, b in _block_list(contents, prefix, what) if a is not None]
    if contents.has_attachment(f"{prefix}/blocks.json"):
        return (min(a for a, _ in blocks), max(b for _, b in blocks)) if blocks else None
    t = read_table(contents, prefix, what, ("sat",), {"time_gps_s": np.float64}, ["time_gps_s", "sat"],
                   keep=("time_gps_s",))["time_gps_s"].to_numpy()
    return (float(t.min()), float(t.max())) if t.size else None
