"""A GNSS ingest of long RINEX and u-blox UBX files, hour by hour, in bounded memory (issue 29).

A 10 Hz pair read whole held ≈ 3 GB for a day (the files' text or bytes, their tables and the messages built from
them).  When every receiver is plain RINEX 3 or an uncompressed UBX log — one file, or consecutive files of one record
that do not overlap (a day as hourly files) — (:func:`cdgps_cli.io.rinex_hours.rinex_hours`,
:func:`cdgps_cli.io.ubx_hours.ubx_hours`), the ingest reads each receiver's files one block of GPS time at a time
(:data:`cdgps_cli.io.gnss_archive.OBS_BLOCK_S`, the blocks of the RUN's observation archives): :func:`hourly_inputs`
returns the inputs and the generator of the blocks' tables that :func:`cdgps_cli.io.gnss_run.write_gnss_run_blocks`
writes as they come.  What the checks and the summaries need of the whole record is kept in thin tables
(:class:`ThinTables`: time, satellite, signal, whether a phase and a code are there, loss of lock — a UBX log's lock
times and half-cycle status —; ≈ 15 bytes a row, 18 for a UBX log), which become the receivers' ``raw`` and ``signals`` once the last
block is read, with the header the whole file's reading gives (:func:`~cdgps_cli.io.rinex_hours.join_obs_headers`,
:func:`~cdgps_cli.io.ubx_hours.join_ubx_infos` and the log's RXM-SFRBX ephemerides; several files joined by
:func:`~cdgps_cli.io.gnss_sequence.join_receivers`, as the whole reading joins them).

The RUN written is the one the whole-file ingest writes, byte for byte (``tests/io/test_gnss_hours.py``,
``tests/io/test_ubx_hours.py``).  Anything the blocks cannot give exactly as the whole file
(:class:`~cdgps_cli.io.rinex_hours.NotCut`) and every error is left to the whole-file ingest, which the caller then
runs: its errors are the ones users see.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

from cdgps_cli.config.structure import GnssConfig
from cdgps_cli.core.records import OBS_COLUMNS
from cdgps_cli.core import beside, heap
from cdgps_cli.config.options import HEADER_CHECK_EPOCHS
from cdgps_cli.core.signals import anchor_signal
from cdgps_cli.io import gnss_archive
from cdgps_cli.io import gnss_run as g
from cdgps_cli.io.log_sequence import expand_paths
from cdgps_cli.io.rinex import read_rinex_obs
from cdgps_cli.io.rinex_hours import NotCut, check_block, join_obs_headers, rinex_hours
from cdgps_cli.io.rinex_signals import SIGNAL_COLUMNS, first_of_repeated_epochs, read_rinex_signals, signal_attributes
from cdgps_cli.io.ubx import UBX_OBS_COLUMNS, empty_signal_table, read_ubx_block, sfrbx_frames, sfrbx_of_blocks
from cdgps_cli.io.ubx_frames import rtcm_station_arp
from cdgps_cli.io.ubx_hours import check_ubx_block, join_ubx_infos, ubx_hours

__all__ = ["hourly_inputs", "ThinTables", "NotCut"]

_THERE = "there"
"""A column of which the checks read only whether a value is there: kept as 0 (there) or NaN (none), float16."""
_THIN_RAW = {"time_gps_s": np.float64, "phase_cycles": _THERE, "pseudorange_m": _THERE, "lli": np.int8}
_THIN_SIGNALS = {"time_gps_s": np.float64, "phase_cycles": _THERE, "lli": np.int8}
_THIN_UBX = {"lock_time_ms": np.uint16, "half_cycle": np.int8}
"""(RXM-RAWX lock times are 16-bit: ms, capped at 64500.)"""
"""A UBX receiver's columns besides: its loss of lock comes from its lock times and half-cycle status."""


class ThinTables:
    """The columns of a receiver's tables that the ingest's checks and summaries read of the whole record, kept
    block by block in narrow types: ``raw`` (time, satellite, whether an L1 phase and a code are there — 0, or NaN where none — and LLI) and
    ``signals`` (time, satellite, signal, phase, LLI); a UBX receiver's (``ubx``) also their lock times and
    half-cycle status.  The satellite and signal columns become categoricals (their categories sorted)."""

    def __init__(self, codes: dict | None = None, ubx: bool = False):
        self._parts = {"raw": [], "signals": []}
        extra = _THIN_UBX if ubx else {}
        self._dtypes = {"raw": {**_THIN_RAW, **extra}, "signals": {**_THIN_SIGNALS, **extra}}
        self._codes: dict = new_codes() if codes is None else codes
        """table → text column → (text → code), shared by the tables of one receiver's files: the same categories,
        so that their frames join without becoming strings (:func:`new_codes`)."""

    def add(self, raw: pd.DataFrame, signals: pd.DataFrame | None) -> None:
        self._parts["raw"].append(self._thin(raw, self._dtypes["raw"], self._codes["raw"]))
        if signals is not None:
            self._parts["signals"].append(self._thin(signals, self._dtypes["signals"], self._codes["signals"]))

    @staticmethod
    def _thin(tab: pd.DataFrame, dtypes: dict, text: dict) -> dict:
        out = {c: _there(tab[c].to_numpy(dtype=np.float64)) if dt == _THERE else tab[c].to_numpy().astype(dt)
               for c, dt in dtypes.items()}
        for c, table in text.items():
            codes, uniques = pd.factorize(tab[c].to_numpy(dtype=object))
            glob = np.array([table.setdefault(u, len(table)) for u in uniques.tolist()], dtype=np.int32)
            out[c] = (glob[codes] if codes.size else np.zeros(0, dtype=np.int32)).astype(
                np.int16 if len(table) < 2**15 else np.int32)
        return out

    def frame(self, kind: str) -> pd.DataFrame | None:
        parts = self._parts[kind]
        if not parts:
            return None
        cols, text = {}, self._codes[kind]
        for c in list(parts[0]):
            v = np.concatenate([p.pop(c) for p in parts])
            if c in text:
                names = sorted(text[c])
                rank = np.empty(len(text[c]), dtype=np.int32)
                rank[[text[c][x] for x in names]] = np.arange(len(names), dtype=np.int32)
                v = pd.Categorical.from_codes(rank[v] if v.size else v, categories=names)
            cols[c] = v
        parts.clear()
        return pd.DataFrame(cols, copy=False)


def _there(v: np.ndarray) -> np.ndarray:
    """0 where ``v`` has a value, NaN where not (float16: :data:`_THERE`)."""
    out = np.zeros(v.size, dtype=np.float16)
    out[~np.isfinite(v)] = np.nan
    return out


def new_codes() -> dict:
    """Empty code tables of :class:`ThinTables` (one per table and text column)."""
    return {"raw": {"sat": {}}, "signals": {"sat": {}, "signal": {}}}


def hourly_inputs(cfg: GnssConfig, out_path, *, rinex: dict | None = None, ubx: dict | None = None, nav_paths=None,
                  master: str | None = None, progress=None, why: list | None = None, strict: bool = False):
    """(:class:`~cdgps_cli.io.gnss_run.IngestInputs`, the blocks' generator, the mapped files) of an ingest whose
    receivers are each plain RINEX 3 files or UBX logs — one, or consecutive files of one record that do not overlap (the
    parameters of :func:`cdgps_cli.pipeline.gnss_ingest.ingest_gnss`); None for any other ingest, or any error (the
    whole-file ingest then reads the files, and names it; ``why``, if given, gets the reason).  ``inputs.receivers``
    is filled as the generator ends; close the mapped files (``.close()``) when done."""
    say = progress or (lambda m: None)
    why = [] if why is None else why
    try:
        files, pieces, shared = g._ingest_files(cfg, rinex, ubx)
        master = master or cfg.master or (next(iter(files)) if len(files) == 1 else None)
        if not master or master not in files:
            why.append("no master")
            return None
        nav_list = expand_paths(list(cfg.nav), f"{cfg.path}: [gnss] nav") if nav_paths is None else \
            expand_paths([str(p) for p in nav_paths], "--nav")
        g._refuse_overwriting_an_input(Path(out_path), pieces, nav_list)
    except g.CdgpsError:
        why.append("an error in the inputs, named by the whole reading")
        return None
    hours = _Closer({})
    given = {n: list(ps) for n, ps in pieces.items()}
    for n in [master, *[n for n in files if n != master]]:
        cut = _cut_record(pieces[n], files[n][0], why)
        if cut is None:
            hours.close()
            return None
        hours.hours[n] = cut
        if len(cut) > 1:          # the files in time order, as the whole-file ingest puts them before writing
            pieces[n] = [given[n][h.order] for h in cut]
            files[n] = (files[n][0], g.pieces_text(pieces[n]))
    warnings: list[str] = list(shared)
    try:
        nav_ahead, glonass_k = g._glonass_nav(cfg.signals, nav_list)
        ahead = {} if nav_list else _sfrbx_ahead(hours.hours, files, say)
        nav, nav_source = g._ingest_nav(cfg, nav_list, nav_ahead, ahead, files, pieces, master, say, warnings)
    except (g.CdgpsError, NotCut):
        hours.close()
        why.append("an error in the navigation files, named by the whole reading")
        return None
    inp = g.IngestInputs(files, master, nav_list, {}, nav, {}, warnings, nav_source, pieces, None)
    keys = sorted({k for cut in hours.hours.values() for h in cut for k, *_ in h.blocks})
    return inp, g.Blocks(_blocks(cfg, inp, hours.hours, keys, given, glonass_k, say, strict), len(keys)), hours


def _cut_record(paths: list, kind: str, why: list) -> list | None:
    """The files of a receiver cut into blocks (:func:`~cdgps_cli.io.rinex_hours.rinex_hours`,
    :func:`~cdgps_cli.io.ubx_hours.ubx_hours`), in time order; None (the files read whole; the reason appended to
    ``why``) when one cannot be cut or two overlap (the whole reading joins them, an epoch repeated kept from the
    earlier file)."""
    cut = []
    for i, p in enumerate(paths):
        h = (ubx_hours if kind == "ubx" else rinex_hours)(p, gnss_archive.OBS_BLOCK_S, why)
        if h is None:
            for x in cut:
                x.close()
            return None
        h.order = i
        cut.append(h)
    cut.sort(key=lambda h: h.first_s)                   # (a stable sort: as join_tables orders them)
    if any(b.first_s <= a.last_s for a, b in zip(cut, cut[1:])):
        for x in cut:
            x.close()
        why.append(f"{Path(cut[0].path).name} …: files that overlap")
        return None
    return cut


class _Closer:
    def __init__(self, hours: dict):
        self.hours = hours

    def close(self) -> None:
        for cut in self.hours.values():
            for h in cut:
                h.close()


def _kind(cut: list) -> str:
    """``"ubx"`` or ``"rinex"``: the kind of a receiver's files (:func:`_cut_record`)."""
    return cut[0].kind


def _empty_tables(signals, kind: str = "rinex") -> tuple:
    """(raw rows, signal rows or None) of a receiver without an epoch in a block: its tables' columns, no rows."""
    if kind == "ubx":
        return g._raw_from_ubx(pd.DataFrame({c: np.zeros(0) for c in UBX_OBS_COLUMNS})), \
            (empty_signal_table() if signals else None)
    raw = g._raw_from_rinex(pd.DataFrame({c: np.zeros(0) for c in OBS_COLUMNS}))
    return raw, (pd.DataFrame({c: np.zeros(0) for c in SIGNAL_COLUMNS}) if signals else None)


def _checked(hours, j: int, info: dict, previous_last_s: float | None, strict: bool) -> float:
    """The last epoch (GPS s) of block ``j`` of a file, checked to be what the whole file's reading holds of it
    (:func:`~cdgps_cli.io.rinex_hours.check_block`, :func:`~cdgps_cli.io.ubx_hours.check_ubx_block`; NotCut)."""
    if hours.kind == "ubx":
        check_ubx_block(hours, j, info, previous_last_s, strict)
        return float(info["time_s"][-1])
    check_block(hours, j, info, previous_last_s)
    return info["time_last_obs_gps_s"]


def _blocks(cfg: GnssConfig, inp, hours: dict, keys: list, given: dict, glonass_k: dict, say, strict: bool = False):
    """For each block of GPS time: [(raw rows, signal rows or None)] per receiver (master first; a receiver's
    files' rows in that block joined); at the end the receivers (thin tables, the whole reading's header and
    joins) in ``inp.receivers`` and ``inp.joins``, the reading's warnings first in ``inp.warnings``.  NotCut or
    CdgpsError: the whole-file ingest must read them.  ``keys``: the block numbers, in time order; ``given``: each
    receiver's files as given (their order and
    spelling: the whole reading's joins name them so)."""
    l1_opt = anchor_signal(cfg.signals) is not None
    names = list(hours)
    index = {n: {} for n in names}
    for n, cut in hours.items():
        for f, h in enumerate(cut):
            for j, (k, *_) in enumerate(h.blocks):
                index[n].setdefault(k, []).append((f, j))
    attrs, notes = signal_attributes({n: [(h.kind, h.path, None if h.kind == "ubx" else (h.head, False))
                                          for h in hours[n]] for n in names}, cfg.signals or ())
    codes = {n: new_codes() for n in names}
    thin = {n: [ThinTables(codes[n], ubx=_kind(hours[n]) == "ubx") for _ in hours[n]] for n in names}
    infos: dict = {n: [[] for _ in hours[n]] for n in names}
    last: dict = {n: None for n in names}
    for n in names:
        say(f"reading {_kind(hours[n]).upper()} {inp.files[n][1]} ({n}) hour by hour …")
    first: dict = {n: [] for n in names}         # each receiver's first epochs' raw rows, at full precision
    for k in keys:
        block = []
        for n, parts in zip(names, _read_blocks(cfg, hours, index, k, l1_opt, glonass_k, attrs)):
            for f, j, (raw, sig, info) in parts:
                last[n] = _checked(hours[n][f], j, info, last[n], strict)
                infos[n][f].append(info)
                thin[n][f].add(raw, sig)
                _keep_first_epochs(first[n], raw)
            block.append(_joined(parts) if parts else _empty_tables(cfg.signals, _kind(hours[n])))
        yield block
        del block, parts
        heap.trim()           # (the block's freed pages back to the system: its memory does not add up block by block)
    joins, join_warnings = {}, []
    inp.first_rows = {n: g.first_epoch_rows(pd.concat(first[n], ignore_index=True).sort_values("time_gps_s", kind="stable"),
                                            HEADER_CHECK_EPOCHS) for n in names if first[n]}
    inp.receivers = {n: _receiver(cfg, inp, n, hours[n], given[n], infos[n], thin[n], l1_opt, joins, join_warnings)
                     for n in names}
    inp.joins = joins
    inp.integrity = g._ubx_integrity(inp.receivers, inp.files)
    join_warnings = [w for n in inp.files for w in join_warnings if w[0] == n]
    inp.warnings[0:0] = [w for _, w in join_warnings] + [w for n, rx in inp.receivers.items()
                                                          for w in g._receiver_warnings(n, inp.files[n][1], rx)] + notes
    inp.warnings += [w for n, rx in inp.receivers.items() for w in g.empty_epochs_warning(n, inp.files[n][1], rx)]


def _keep_first_epochs(kept: list, raw: pd.DataFrame) -> None:
    """Append to ``kept`` the rows of ``raw`` (a block of a receiver's raw table) while fewer than
    :data:`HEADER_CHECK_EPOCHS` epochs are kept: the record's first epochs at full precision (the thin tables keep
    pseudoranges as float32), for a rover's nominal position (:func:`cdgps_cli.io.gnss_run.first_epoch_rows`)."""
    have = sum(int(np.unique(r["time_gps_s"].to_numpy()).size) for r in kept)
    if have < HEADER_CHECK_EPOCHS and len(raw):
        kept.append(g.first_epoch_rows(raw, HEADER_CHECK_EPOCHS - have).copy())


def _joined(parts: list) -> tuple:
    """(raw rows, signal rows) of a receiver's block read from several files (in time order)."""
    if len(parts) == 1:
        return parts[0][2][:2]
    raw = pd.concat([p[2][0] for p in parts], ignore_index=True)
    sigs = [p[2][1] for p in parts]
    return raw, (None if sigs[0] is None else pd.concat(sigs, ignore_index=True))


def _read_blocks(cfg: GnssConfig, hours: dict, index: dict, k: int, l1_opt: bool, glonass_k: dict,
                 attrs: dict | None = None) -> list:
    """Each receiver's parts of block ``k``: [(file, block, (raw, signals, header summary))] (:func:`_read_block`;
    none where it has no epoch in it), the first receiver's read beside the others'
    (:func:`cdgps_cli.core.beside.both`: on a second core, the same tables bit for bit)."""
    def read(n):
        return [(f, j, _read_block(cfg, hours[n][f], j, l1_opt, glonass_k, (attrs or {}).get(n)))
                for f, j in index[n].get(k, [])]

    names = list(hours)
    if len(names) < 2:
        return [read(names[0])]
    first, rest = beside.both(lambda: read(names[0]), lambda: [read(n) for n in names[1:]])
    return [first, *rest]


def _read_block(cfg: GnssConfig, hours, j: int, l1_opt: bool, glonass_k: dict, attributes: dict | None = None) -> tuple:
    """(raw table, signal table or None, header summary) of block ``j`` of a file, read as a file of its own (a UBX
    log's: the summary of :func:`~cdgps_cli.io.ubx.read_ubx_block` but its tables)."""
    if hours.kind == "ubx":
        b = read_ubx_block(hours.path, hours.block_bytes(j), cfg.signals)
        sig = b.pop("signals")
        if sig is not None:
            sig = first_of_repeated_epochs(sig)[0]
        return g._raw_from_ubx(b.pop("obs")), sig, b
    read = hours.block_bytes(j)
    info, obs = read_rinex_obs(hours.path, gps_l1_optional=l1_opt, read=read)
    sig = None
    if cfg.signals:                  # an epoch's record written twice: its first (as the whole reading keeps)
        sig = first_of_repeated_epochs(read_rinex_signals(hours.path, cfg.signals, glonass_k, read=read,
                                                          attributes=attributes)[1])[0]
    return g._raw_from_rinex(obs), sig, info


def _receiver(cfg: GnssConfig, inp, n: str, cut: list, given: list, infos: list, thin: list, l1_opt: bool,
              joins: dict, join_warnings: list) -> g.GnssReceiver:
    """The receiver of its files from their blocks: each file's header joined from its blocks', the thin tables;
    several files joined as the whole reading joins them (:func:`~cdgps_cli.io.gnss_sequence.join_receivers` on the
    files in the order and spelling given: ``joins[n]`` and the warnings, as (n, text), appended; NotCut unless its
    order is the one the blocks were read in); the whole reading's refusals (a file without GPS L1 phase, a signal
    missing)."""
    rxs = []
    for h, inf, th in zip(cut, infos, thin):
        if not inf:
            raise NotCut("a file without epochs")
        raw = th.frame("raw")
        heap.trim()                  # (the blocks' parts, joined, freed: their pages back to the system)
        rx = _ubx_file(n, h, inf, raw) if h.kind == "ubx" else _rinex_file(n, h, inf, raw)
        if not l1_opt:
            g.refuse_no_l1_phase(h.path, h.kind, rx.header, raw)
        rxs.append(rx)
    if len(rxs) == 1:
        rx = rxs[0]
    else:
        if any(rx.info.get("truncated_tail_bytes") for rx in rxs[:-1]):
            raise NotCut("a frame cut by the file rotation")     # (the whole reading joins it again across the files)
        by_given = sorted(range(len(cut)), key=lambda i: cut[i].order)
        nav = _joined_sfrbx([infos[i] for i in by_given], [rxs[i] for i in by_given]) if _kind(cut) == "ubx" else None
        rx, joins[n], w, order = g.join_receivers(n, [rxs[i] for i in by_given], given, ubx_nav=nav)
        if [by_given[i] for i in order] != list(range(len(cut))):
            raise NotCut("the files' order")           # (e.g. files without GPS rows: the whole reading keeps theirs)
        join_warnings.extend((n, x) for x in w)
    if cfg.signals:
        tabs = [th.frame("signals") for th in thin]
        rx.signals = tabs[0] if len(tabs) == 1 else g.join_signal_tables(n, tabs, [given[h.order] for h in cut])
        heap.trim()
        g.refuse_absent_signals(cfg.signals, rx.signals, inp.files[n][1], n)
    return rx


def _rinex_file(n: str, h, inf: list, raw: pd.DataFrame) -> g.GnssReceiver:
    """The receiver of one RINEX file read block by block (``inf``: its blocks' header summaries)."""
    header, info = g.rinex_header_info(h.path, join_obs_headers(inf))
    return g.GnssReceiver(n, "rinex", h.path.name, header, raw, info, None)


def _ubx_file(n: str, h, inf: list, raw: pd.DataFrame) -> g.GnssReceiver:
    """The receiver of one UBX log read block by block (``inf``: its blocks' summaries,
    :func:`~cdgps_cli.io.ubx.read_ubx_block`): the read summary joined, the ephemerides of its RXM-SFRBX frames,
    the station position of its last RTCM 1005/1006, as :func:`~cdgps_cli.io.gnss_run.read_receiver_file` reads
    the whole log.  NotCut for a log without GPS L1 C/A (the whole reading refuses it, naming what it holds)."""
    if not len(raw):
        raise NotCut("no GPS L1 C/A measurements")
    info_u = join_ubx_infos([b["info"] for b in inf], [a for _, a, _, _ in h.blocks])
    nav, info_u["sfrbx"] = sfrbx_of_blocks(b"".join(b["sfrbx"] for b in inf), info_u["week"])
    info_u["rtcm_base"] = rtcm_station_arp([r for b in inf for r in b["rtcm_arp"]])
    header, info = g.ubx_header_info(h.path, n, info_u, raw)
    return g.GnssReceiver(n, "ubx", h.path.name, header, raw, info, nav)


def _joined_sfrbx(infos: list, rxs: list):
    """``ubx_nav`` of :func:`~cdgps_cli.io.gnss_sequence.join_receivers` for UBX logs read block by block
    (``infos``: each log's blocks' summaries, in the order of ``rxs``): their RXM-SFRBX frames in time order
    decoded as one stream, with the first log's week."""
    def nav(order: list) -> tuple:
        frames = b"".join(b["sfrbx"] for i in order for b in infos[i])
        return sfrbx_of_blocks(frames, rxs[order[0]].info.get("week"))
    return nav


def _sfrbx_ahead(hours: dict, files: dict, say) -> dict:
    """Before the blocks are read, when no navigation file is given: the receivers' ephemerides from their UBX
    logs' RXM-SFRBX frames (framed block by block; the logs in time order decoded as one stream, as the whole
    reading decodes them), as stand-ins for the receivers (``format``, ``nav``) that
    :func:`~cdgps_cli.io.gnss_run._ingest_nav` takes; {} when no receiver is a UBX log."""
    if not any(_kind(cut) == "ubx" for cut in hours.values()):
        return {}
    out = {}
    for n, cut in hours.items():
        nav = None
        if _kind(cut) == "ubx":
            say(f"reading the RXM-SFRBX frames of {files[n][1]} ({n}) …")
            frames = b"".join(sfrbx_frames(h.block_bytes(j)) for h in cut for j in range(len(h.blocks)))
            nav = sfrbx_of_blocks(frames, cut[0].first_week)[0]
        out[n] = SimpleNamespace(format=_kind(cut), nav=nav)
    return out
