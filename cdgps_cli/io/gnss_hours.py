"""A GNSS ingest of long RINEX files, hour by hour, in bounded memory (issue 29).

A 10 Hz pair read whole held ≈ 3 GB for a day (the files' text, their tables and the messages built from them).
When every receiver is one plain RINEX 3 file (:func:`cdgps_cli.io.rinex_hours.rinex_hours`), the ingest reads
each receiver's file one block of GPS time at a time (:data:`cdgps_cli.io.gnss_archive.OBS_BLOCK_S`, the blocks of
the RUN's observation archives): :func:`hourly_inputs` returns the inputs and the generator of the blocks' tables
that :func:`cdgps_cli.io.gnss_run.write_gnss_run_blocks` writes as they come.  What the checks and the summaries
need of the whole record is kept in thin tables (:class:`ThinTables`: time, satellite, signal, whether a phase and
a code are there, loss of lock; ≈ 20 bytes a row), which become the receivers' ``raw`` and ``signals`` once the last
block is read, with the header the whole file's reading gives (:func:`~cdgps_cli.io.rinex_hours.join_obs_headers`).

The RUN written is the one the whole-file ingest writes, byte for byte (``tests/io/test_gnss_hours.py``).  Anything
the blocks cannot give exactly as the whole file (:class:`~cdgps_cli.io.rinex_hours.NotCut`) and every error is
left to the whole-file ingest, which the caller then runs: its errors are the ones users see.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.config.structure import GnssConfig
from cdgps_cli.core.records import OBS_COLUMNS
from cdgps_cli.core import beside, heap
from cdgps_cli.core.signals import anchor_signal
from cdgps_cli.io import gnss_archive
from cdgps_cli.io import gnss_run as g
from cdgps_cli.io.log_sequence import expand_paths
from cdgps_cli.io.rinex import read_rinex_obs
from cdgps_cli.io.rinex_hours import NotCut, check_block, join_obs_headers, rinex_hours
from cdgps_cli.io.rinex_signals import SIGNAL_COLUMNS, read_rinex_signals

__all__ = ["hourly_inputs", "ThinTables", "NotCut"]

_THIN_RAW = {"time_gps_s": np.float64, "phase_cycles": np.float32, "pseudorange_m": np.float32, "lli": np.int8}
_THIN_SIGNALS = {"time_gps_s": np.float64, "phase_cycles": np.float32, "lli": np.int8}


class ThinTables:
    """The columns of a receiver's tables that the ingest's checks and summaries read of the whole record, kept
    block by block in narrow types: ``raw`` (time, satellite, L1 phase and code — NaN where none — and LLI) and
    ``signals`` (time, satellite, signal, phase, LLI).  The satellite and signal columns become categoricals (their
    categories sorted)."""

    def __init__(self):
        self._parts = {"raw": [], "signals": []}
        self._codes: dict = {"sat": {}, "signal": {}}

    def add(self, raw: pd.DataFrame, signals: pd.DataFrame | None) -> None:
        self._parts["raw"].append(self._thin(raw, _THIN_RAW, ("sat",)))
        if signals is not None:
            self._parts["signals"].append(self._thin(signals, _THIN_SIGNALS, ("sat", "signal")))

    def _thin(self, tab: pd.DataFrame, dtypes: dict, text: tuple) -> dict:
        out = {c: tab[c].to_numpy().astype(dt) for c, dt in dtypes.items()}
        for c in text:
            codes, uniques = pd.factorize(tab[c].to_numpy(dtype=object))
            table = self._codes[c]
            glob = np.array([table.setdefault(u, len(table)) for u in uniques.tolist()], dtype=np.int32)
            out[c] = glob[codes] if codes.size else np.zeros(0, dtype=np.int32)
        return out

    def frame(self, kind: str) -> pd.DataFrame | None:
        parts = self._parts[kind]
        if not parts:
            return None
        cols = {}
        for c in list(parts[0]):
            v = np.concatenate([p.pop(c) for p in parts])
            if c in self._codes:
                names = sorted(self._codes[c])
                rank = np.empty(len(self._codes[c]), dtype=np.int32)
                rank[[self._codes[c][x] for x in names]] = np.arange(len(names), dtype=np.int32)
                v = pd.Categorical.from_codes(rank[v] if v.size else v, categories=names)
            cols[c] = v
        parts.clear()
        return pd.DataFrame(cols, copy=False)


def hourly_inputs(cfg: GnssConfig, out_path, *, rinex: dict | None = None, ubx: dict | None = None, nav_paths=None,
                  master: str | None = None, progress=None):
    """(:class:`~cdgps_cli.io.gnss_run.IngestInputs`, the blocks' generator, the mapped files) of an ingest whose
    receivers are each one plain RINEX 3 file (the parameters of
    :func:`cdgps_cli.pipeline.gnss_ingest.ingest_gnss`); None for any other ingest, or any error (the whole-file
    ingest then reads the files, and names it).  ``inputs.receivers`` is filled as the generator ends; close the
    mapped files (``.close()``) when done."""
    say = progress or (lambda m: None)
    try:
        files, pieces = g._ingest_files(cfg, rinex, ubx)
        master = master or cfg.master or (next(iter(files)) if len(files) == 1 else None)
        if (not master or master not in files or any(k != "rinex" or len(pieces[n]) != 1 for n, (k, _) in files.items())):
            return None
        nav_list = expand_paths(list(cfg.nav), f"{cfg.path}: [gnss] nav") if nav_paths is None else \
            expand_paths([str(p) for p in nav_paths], "--nav")
        g._refuse_overwriting_an_input(Path(out_path), pieces, nav_list)
    except g.CdgpsError:
        return None
    order = [master, *[n for n in files if n != master]]
    hours = {}
    for n in order:
        h = rinex_hours(pieces[n][0], gnss_archive.OBS_BLOCK_S)
        if h is None:
            for x in hours.values():
                x.close()
            return None
        hours[n] = h
    warnings: list[str] = []
    try:
        nav_ahead, glonass_k = g._glonass_nav(cfg.signals, nav_list)
        nav, nav_source = g._ingest_nav(cfg, nav_list, nav_ahead, {}, files, pieces, master, say, warnings)
    except g.CdgpsError:
        for x in hours.values():
            x.close()
        return None
    inp = g.IngestInputs(files, master, nav_list, {}, nav, {}, warnings, nav_source, pieces, None)
    return inp, _blocks(cfg, inp, hours, glonass_k, say), _Closer(hours)


class _Closer:
    def __init__(self, hours: dict):
        self.hours = hours

    def close(self) -> None:
        for h in self.hours.values():
            h.close()


def _empty_tables(signals) -> tuple:
    raw = g._raw_from_rinex(pd.DataFrame({c: np.zeros(0) for c in OBS_COLUMNS}))
    return raw, (pd.DataFrame({c: np.zeros(0) for c in SIGNAL_COLUMNS}) if signals else None)


def _blocks(cfg: GnssConfig, inp, hours: dict, glonass_k: dict, say):
    """For each block of GPS time: [(raw rows, signal rows or None)] per receiver (master first); at the end the
    receivers (thin tables, the whole file's header) in ``inp.receivers``, their warnings first in
    ``inp.warnings``.  NotCut or CdgpsError: the whole-file ingest must read them."""
    l1_opt = anchor_signal(cfg.signals) is not None
    names = list(hours)
    index = {n: {k: j for j, (k, *_) in enumerate(h.blocks)} for n, h in hours.items()}
    keys = sorted({k for ix in index.values() for k in ix})
    thin = {n: ThinTables() for n in names}
    infos: dict = {n: [] for n in names}
    last: dict = {n: None for n in names}
    for n in names:
        say(f"reading RINEX {hours[n].path} ({n}) hour by hour …")
    for k in keys:
        block = []
        for n, got in zip(names, _read_blocks(cfg, hours, index, k, l1_opt, glonass_k)):
            if got is None:
                block.append(_empty_tables(cfg.signals))
                continue
            raw, sig, info = got
            check_block(hours[n], index[n][k], info, last[n])
            last[n] = info["time_last_obs_gps_s"]
            infos[n].append(info)
            thin[n].add(raw, sig)
            block.append((raw, sig))
        yield block
        del block
        heap.trim()           # (the block's freed pages back to the system: its memory does not add up block by block)
    inp.receivers = {n: _receiver(cfg, n, hours[n].path, infos[n], thin[n], l1_opt) for n in names}
    inp.warnings[0:0] = [w for n, rx in inp.receivers.items() for w in g._receiver_warnings(n, inp.files[n][1], rx)]


def _read_blocks(cfg: GnssConfig, hours: dict, index: dict, k: int, l1_opt: bool, glonass_k: dict) -> list:
    """Each receiver's block ``k`` (:func:`_read_block`; None where it has no epoch in it), the first receiver's
    read beside the others' (:func:`cdgps_cli.core.beside.both`: on a second core, the same tables bit for bit)."""
    def read(n):
        j = index[n].get(k)
        return None if j is None else _read_block(cfg, hours[n], j, l1_opt, glonass_k)

    names = list(hours)
    if len(names) < 2:
        return [read(names[0])]
    first, rest = beside.both(lambda: read(names[0]), lambda: [read(n) for n in names[1:]])
    return [first, *rest]


def _read_block(cfg: GnssConfig, hours, j: int, l1_opt: bool, glonass_k: dict) -> tuple:
    """(raw table, signal table or None, header summary) of block ``j`` of a file, read as a file of its own."""
    read = hours.block_bytes(j)
    info, obs = read_rinex_obs(hours.path, gps_l1_optional=l1_opt, read=read)
    sig = read_rinex_signals(hours.path, cfg.signals, glonass_k, read=read)[1] if cfg.signals else None
    return g._raw_from_rinex(obs), sig, info


def _receiver(cfg: GnssConfig, n: str, p: Path, infos: list, thin: ThinTables, l1_opt: bool) -> g.GnssReceiver:
    """The receiver of the whole file from its blocks: the joined header, the thin tables; the whole-file reading's
    refusals (no GPS L1 phase, a signal missing)."""
    if not infos:
        raise NotCut("no epochs")
    header, info = g.rinex_header_info(p, join_obs_headers(infos))
    raw = thin.frame("raw")
    heap.trim()                  # (the blocks' parts, joined, freed: their pages back to the system)
    if not l1_opt:
        g.refuse_no_l1_phase(p, "rinex", header, raw)
    rx = g.GnssReceiver(n, "rinex", p.name, header, raw, info, None)
    if cfg.signals:
        rx.signals = thin.frame("signals")
        heap.trim()
        g.refuse_absent_signals(cfg.signals, rx.signals, p, n)
    return rx
