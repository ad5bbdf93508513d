"""GNSS RUN.mcap: raw receiver observations (RINEX / u-blox UBX) and broadcast ephemerides.

:func:`ingest_gnss` is the library form of ``cdgps ingest --rinex/--ubx … --nav …``; it reads and
checks the files and writes one self-contained RUN.mcap (atomic, zstd chunks, CRCs, the GNSS run
config attached, sha256 of every input in the metadata).  Differencing is a processing step
(``cdgps init`` / ``cdgps estimate``): the run stores the observations *as recorded*, per
receiver, satellite and epoch.  :func:`read_gnss_run` loads it back;
:func:`cdgps_cli.pipeline.gnss_ingest.processing_obs` turns a receiver's raw table into the
observation table of the solvers (RINEX LLI kept, u-blox lock times and half-cycle flags converted
to LLI bits by the one lock-segment rule, :mod:`cdgps_cli.measurement.channels`).

Layout (format details in docs/gnss-pipeline.md):

* topic ``/cdgps/gnss/obs`` — one JSON message per receiver and epoch (``time_s`` = the receiver's
  time tag, GPS seconds since 1980-01-06; log time = the same instant in UTC, Unix ns, see
  :mod:`cdgps_cli.core.timescales`): ``receiver``, ``epoch_flag``, ``clock_offset_s`` (left out when
  the epoch has none) and per satellite ``sat``, ``phase_cycles``, ``pseudorange_m``,
  ``snr_dbhz``, ``doppler_hz`` (each with its boolean ``<field>_valid`` array: 0 and false where
  the observation is missing), ``lli``, ``half_cycle``, ``lock_time_ms``;
* topic ``/cdgps/gnss/ephemeris`` — one message per broadcast ephemeris record (time_s = toc,
  GPS s; fields the record lacks, e.g. a blank fit interval, are left out);
* attachments ``gnss/receivers.json`` (names, formats, source files, headers, read summaries),
  ``gnss/obs/<k>/<b>_<hour>.npz.zst`` (receiver k's raw table as zstd-compressed numpy arrays, one per hour of
  GPS time, written after that hour's messages, :mod:`cdgps_cli.io.gnss_archive`; the indexes
  ``gnss/obs/<k>/blocks.json`` after the last hour: the fast path every later stage reads), ``gnss/info.json``,
  ``gnss/ephemeris.json`` (the ephemeris table), ``config.toml`` (the GNSS run config); with ``[gnss] signals``
  also ``gnss/signals/<k>/…`` (every asked-for signal of the receiver,
  :data:`~cdgps_cli.io.rinex_signals.SIGNAL_COLUMNS`), in the same blocks;
* metadata ``cdgps.ingest`` with ``kind = gnss``, the master, the inputs and their sha256.
"""

from __future__ import annotations

import json
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import orjson
import pandas as pd

from cdgps_cli.core import beside, progress
from cdgps_cli.core.checks import header_position_m
from cdgps_cli.core.signals import anchor_signal
from cdgps_cli.io import gnss_archive
from cdgps_cli.io.atomic import path_for_config
from cdgps_cli.config.structure import GnssConfig, gnss_config_toml, parse_gnss_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.timescales import unix_ns_list
from cdgps_cli.io.mcap import CONFIG_ATTACHMENT, VALID_SUFFIX, McapOut, array_schema, message_schema, read_mcap
from cdgps_cli.io.run import INGEST_METADATA, contents_kind, epoch_gaps, ingest_metadata, input_keys, run_kind
from cdgps_cli.core.constants import MAX_EPHEMERIS_AGE_S
from cdgps_cli.core.gps_time import gps_time_str, spans_meet, time_span
from cdgps_cli.core.records import GLONASS_NAV_COLUMNS, NAV_COLUMNS
from cdgps_cli.io.antex import header_antenna_type, model_from_json, model_to_json
from cdgps_cli.io.gnss_sequence import join_receivers, join_signal_tables, merge_signal_tables, pieces_text
from cdgps_cli.io.log_sequence import expand_paths, one_file_for_two_receivers
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs, reading_notes
from cdgps_cli.io.rinex_signals import out_of_order_text, repeated_epochs_text
from cdgps_cli.io.ubx import INTEGRITY_COUNTS, integrity_problems, integrity_record, skipped_line
from cdgps_cli.core.gps_time import distinct_times, nominal_interval_s, sampling_interval_s

__all__ = [
    "GNSS_OBS_TOPIC", "GNSS_EPHEMERIS_TOPIC", "RAW_COLUMNS", "GnssReceiver", "GnssRun", "is_gnss_run",
    "IngestInputs", "read_ingest_inputs", "nominal_positions", "write_gnss_run", "read_gnss_run", "SOLVER_COLUMNS", "run_kind", "gnss_run_info", "default_config_text",
]

GNSS_OBS_TOPIC = "/cdgps/gnss/obs"
GNSS_EPHEMERIS_TOPIC = "/cdgps/gnss/ephemeris"
RECEIVERS_ATTACHMENT = "gnss/receivers.json"
GNSS_INFO_ATTACHMENT = "gnss/info.json"
"""What ``cdgps info`` says of the run's receivers (:func:`gnss_info`), written by ``ingest``: answered from it, the
observations are not decoded (issue 29 item 3)."""
EPHEMERIS_ATTACHMENT = "gnss/ephemeris.json"
ANTENNAS_ATTACHMENT = "gnss/antennas.json"
"""The receivers' antenna calibrations of ``[gnss] antex`` (:func:`antennas_json`), written by ``ingest`` when the
config names an ANTEX file: ``init`` and ``estimate`` take them out of the observations, as ingested."""
OBS_PREFIX = "gnss/obs/{}"
SIGNALS_PREFIX = "gnss/signals/{}"

RAW_COLUMNS = {
    "time_gps_s": "receiver time tag, GPS s",
    "sat": "satellite (G05)",
    "phase_cycles": "L1 carrier phase, cycles (NaN: none)",
    "pseudorange_m": "L1 C/A pseudorange, m (NaN: none)",
    "snr_dbhz": "C/N0, dB-Hz (NaN: none)",
    "doppler_hz": "Doppler, Hz (UBX; NaN in RINEX)",
    "lli": "RINEX loss-of-lock indicator (bit 0 slip, bit 1 half-cycle); -1: not recorded (UBX)",
    "ssi": "RINEX signal-strength digit 0-9 (0: blank)",
    "half_cycle": "1: half-cycle ambiguity unresolved (UBX trkStat) / flagged (RINEX LLI bit 1), else 0",
    "sub_half": "UBX: half a cycle subtracted from the phase (1/0); -1 in RINEX",
    "lock_time_ms": "UBX carrier lock time, ms (capped at 64500); -1: not recorded (RINEX)",
    "cp_std_cycles": "UBX carrier-phase standard deviation, cycles (NaN in RINEX)",
    "pr_std_m": "UBX pseudorange standard deviation, m (NaN in RINEX)",
    "epoch_flag": "RINEX epoch flag (0 OK, 1 power failure); 0 for UBX",
    "clock_offset_s": "receiver clock offset from the RINEX epoch line, s (NaN: none)",
    "clock_reset": "UBX recStat clkReset of the epoch (1/0); -1 in RINEX",
}
"""Columns of a receiver's raw table (:attr:`GnssReceiver.raw`) and what they hold."""

_DTYPES = {"time_gps_s": np.float64, "phase_cycles": np.float64, "pseudorange_m": np.float64,
           "snr_dbhz": np.float32, "doppler_hz": np.float32, "lli": np.int8, "ssi": np.int8, "half_cycle": np.int8,
           "sub_half": np.int8, "lock_time_ms": np.int32, "cp_std_cycles": np.float32, "pr_std_m": np.float32,
           "epoch_flag": np.int8, "clock_offset_s": np.float64, "clock_reset": np.int8}

OBS_SCHEMA = array_schema(
    "cdgps.GnssObservations",
    {"sat": "string", "phase_cycles": "number|null", "pseudorange_m": "number|null", "snr_dbhz": "number|null",
     "doppler_hz": "number|null", "lli": "integer", "half_cycle": "integer", "lock_time_ms": "integer"},
    {"receiver": "string", "epoch_flag": "integer", "clock_offset_s": "number|null"},
)
EPHEMERIS_SCHEMA = message_schema("cdgps.GpsEphemeris", {
    **{c: {"type": "string" if c == "sat" else "number"} for c in NAV_COLUMNS}},
    "one broadcast ephemeris record (RINEX nav); time_s = toc, GPS s; fields the record lacks are left out")


@dataclass
class GnssReceiver:
    """One receiver of a GNSS run: ``format`` (rinex/ubx), ``file`` (name), ``header`` (RINEX
    header dict, or a minimal one for UBX), ``raw`` (:data:`RAW_COLUMNS`), ``info`` (read summary)."""

    name: str
    format: str
    file: str
    header: dict
    raw: pd.DataFrame
    info: dict
    nav: pd.DataFrame | None = None
    """UBX: GPS ephemerides decoded from the log's RXM-SFRBX subframes (None for RINEX)."""
    signals: pd.DataFrame | None = None
    """With ``[gnss] signals``: the receiver's multi-signal table (:func:`~cdgps_cli.io.rinex_signals.read_rinex_signals`)."""


@dataclass
class GnssRun:
    """A GNSS RUN.mcap read back."""

    path: str
    cfg: GnssConfig
    master: str
    receivers: dict
    nav: pd.DataFrame
    metadata: dict
    antennas: dict = field(default_factory=dict)
    """{receiver: :class:`~cdgps_cli.io.antex.AntennaModel` or None (no model)} of :data:`ANTENNAS_ATTACHMENT`; empty:
    the run was ingested without an ANTEX file."""
    antex: str | None = None
    """The ANTEX file the calibrations came from, as the config named it (None: none)."""
    window: dict | None = None
    """The window of the record read (:func:`read_gnss_run` ``window``/``window_s``): ``start_s`` and ``duration_s``
    (from the record's first epoch), ``start_gps_s`` and ``end_gps_s`` (GPS s; a rover's rows t with start ≤ t < end)
    and ``master_margin_s`` (the master's rows read that much wider on each side: the epochs the rover's pair with);
    None: the whole record."""
    record_last_gps_s: float | None = None
    """With a window: the record's last epoch (GPS s; the latest of every receiver's tables)."""

    @property
    def window_past_the_end_note(self) -> str | None:
        """A note when the window asked for ends after the record's last epoch (its data are shorter than asked):
        said by ``init``; None otherwise or without a window."""
        w, last = self.window or {}, self.record_last_gps_s
        if not w or last is None or not w["end_gps_s"] > last + 1.0:
            return None
        return (f"{self.path}: the window ends {w['end_gps_s'] - last:.0f} s after the record's last epoch "
                f"({gps_time_str(last)}): it holds {max(last - w['start_gps_s'], 0.0):.0f} s of data, not the "
                f"{w['duration_s']:g} s asked for")

    @property
    def rovers(self) -> list:
        return [n for n in self.receivers if n != self.master]


# ----------------------------------------------------------------------------------------------
# reading receiver files into raw tables


def _json_safe(v):
    if isinstance(v, dict):
        return {str(k): _json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_safe(x) for x in v]
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return None if not math.isfinite(float(v)) else float(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def _raw_from_rinex(obs: pd.DataFrame) -> pd.DataFrame:
    n = len(obs)
    lli = obs["lli_l1"].to_numpy(dtype=np.int64)
    return pd.DataFrame({
        "time_gps_s": obs["time_gps_s"].to_numpy(dtype=np.float64),
        "sat": obs["sat"].to_numpy(dtype=object),
        "phase_cycles": obs["phase_l1_cycles"].to_numpy(dtype=np.float64),
        "pseudorange_m": obs["pseudorange_l1_m"].to_numpy(dtype=np.float64),
        "snr_dbhz": obs["snr_l1_dbhz"].to_numpy(dtype=np.float64),
        "doppler_hz": np.full(n, np.nan),
        "lli": lli,
        "ssi": obs["ssi_l1"].to_numpy(dtype=np.int64),
        "half_cycle": ((lli >> 1) & 1).astype(np.int64),
        "sub_half": np.full(n, -1, dtype=np.int64),
        "lock_time_ms": np.full(n, -1, dtype=np.int64),
        "cp_std_cycles": np.full(n, np.nan),
        "pr_std_m": np.full(n, np.nan),
        "epoch_flag": obs["epoch_flag"].to_numpy(dtype=np.int64),
        "clock_offset_s": obs["rx_clock_offset_s"].to_numpy(dtype=np.float64),
        "clock_reset": np.full(n, -1, dtype=np.int64),
    }, copy=False)


def _raw_from_ubx(obs: pd.DataFrame) -> pd.DataFrame:
    n = len(obs)
    return pd.DataFrame({
        "time_gps_s": obs["time_gps_s"].to_numpy(dtype=np.float64),
        "sat": obs["sat"].to_numpy(dtype=object),
        "phase_cycles": obs["phase_l1_cycles"].to_numpy(dtype=np.float64),
        "pseudorange_m": obs["pseudorange_l1_m"].to_numpy(dtype=np.float64),
        "snr_dbhz": obs["snr_l1_dbhz"].to_numpy(dtype=np.float64),
        "doppler_hz": obs["doppler_l1_hz"].to_numpy(dtype=np.float64),
        "lli": np.full(n, -1, dtype=np.int64),
        "ssi": np.zeros(n, dtype=np.int64),
        "half_cycle": (~obs["half_cycle_resolved"].to_numpy(dtype=bool)).astype(np.int64),
        "sub_half": obs["sub_half_subtracted"].to_numpy(dtype=bool).astype(np.int64),
        "lock_time_ms": obs["lock_time_ms"].to_numpy(dtype=np.int64),
        "cp_std_cycles": obs["cp_std_cycles"].to_numpy(dtype=np.float64),
        "pr_std_m": obs["pr_std_m"].to_numpy(dtype=np.float64),
        "epoch_flag": np.zeros(n, dtype=np.int64),
        "clock_offset_s": np.full(n, np.nan),
        "clock_reset": obs["clock_reset"].to_numpy(dtype=bool).astype(np.int64),
    }, copy=False)


def empty_epochs_warning(n: str, path, rx: GnssReceiver) -> list[str]:
    """A RINEX receiver's observation epochs (its header's ``n_epochs``: flags 0 and 1) that hold no row of the run's
    tables (no satellite at all, or none of the kept systems and signals): not in the run, said with how many (a
    sweep of real files found an epoch of no satellite dropped unsaid, where ``rtk`` counts it)."""
    n_file = rx.header.get("n_epochs") if isinstance(rx.header, dict) and rx.format == "rinex" else None
    overlaps = ((rx.info or {}).get("join") or {}).get("overlaps") if isinstance(rx.info, dict) else None
    if not n_file or overlaps:      # (files that overlap: their summed count less the repeats is a union only of the
        return []                   # epochs that hold observations)
    times = [rx.raw["time_gps_s"].to_numpy(dtype=np.float64)]
    if rx.signals is not None:
        times.append(rx.signals["time_gps_s"].to_numpy(dtype=np.float64))
    held = int(np.unique(np.concatenate(times)).size)
    if held >= int(n_file):
        return []
    return [f"{path} ({n}): {int(n_file) - held} of its {int(n_file)} observation epochs hold no observation of the "
            f"signals kept (no satellite, or only other systems' or signals'): not in the run"]


def _receiver_warnings(n: str, path, rx: GnssReceiver) -> list[str]:
    """What a receiver's file lacks or holds out of place: codes missing (:func:`_missing_code_warning`), epochs
    written twice and epochs out of time order (the RINEX reader's ``repeated_epochs`` / ``epochs_out_of_order``)."""
    out = [w for w in [_missing_code_warning(n, path, rx)] if w]
    header = rx.header if isinstance(rx.header, dict) else {}
    rep, back = header.get("repeated_epochs"), header.get("epochs_out_of_order")
    if rep:
        out.append(repeated_epochs_text(f"{path} ({n})", [r["time_gps_s"] for r in rep], lines=[r["line"] for r in rep]))
    if back:
        out.append(out_of_order_text(f"{path} ({n})", len(back), back[0]["time_gps_s"]))
    out.extend(reading_notes(header, f"{path} ({n})"))
    return out


def _read_single_files(files: dict, pieces: dict, say, strict: bool, l1_opt: bool) -> dict:
    """The receivers, each given as one file: the first read beside the others
    (:func:`cdgps_cli.core.beside.both`: on a second core, the same tables bit for bit; its error, if
    any, raised first, as when read in turn)."""
    single = [(n, kind) for n, (kind, _) in files.items()]
    for n, kind in single:
        say(f"reading {kind.upper()} {files[n][1]} ({n}) …")

    def read(n, kind):
        return read_receiver_file(n, kind, pieces[n][0], strict=strict, gps_l1_optional=l1_opt)

    if len(single) < 2:
        return {n: read(n, kind) for n, kind in single}
    first = single[0]
    rest = beside.both(lambda: read(*first), lambda: [read(n, kind) for n, kind in single[1:]])
    return dict(zip((n for n, _ in single), [rest[0], *rest[1]]))


def read_receiver_file(name: str, kind: str, path: str | Path, *, strict: bool = False,
                       data: bytes | None = None, gps_l1_optional: bool = False) -> GnssReceiver:
    """Read one RINEX observation file or UBX log into a :class:`GnssReceiver` (raw table).

    ``strict``: a UBX log with any corrupt or skipped data is an error (see
    :func:`~cdgps_cli.io.ubx.read_ubx_rawx`); without it the losses are counted in ``info``.
    ``data``: a UBX log's bytes already read (consecutive files joined; ``path`` names it).
    ``gps_l1_optional``: a run anchored on another system's signal
    (:func:`~cdgps_cli.core.signals.anchor_signal`): a RINEX 3 file without GPS, or without GPS L1
    phase, gives an empty GPS L1 table instead of an error.

    Raises
    ------
    CdgpsError
        The reader's errors (file and line), and a file without any GPS L1 carrier phase.
    """
    p = Path(path)
    if kind == "rinex":
        hdr, obs = read_rinex_obs(p, gps_l1_optional=gps_l1_optional)
        raw = _raw_from_rinex(obs)
        header, info = rinex_header_info(p, hdr)
    elif kind == "ubx":
        from cdgps_cli.io.ubx import read_ubx_log  # noqa: PLC0415

        info_u, obs, sf_nav = read_ubx_log(p, strict=strict, data=data)
        raw = _raw_from_ubx(obs)
        header, info = ubx_header_info(p, name, info_u, raw)
    else:  # pragma: no cover - the CLI only passes these two
        raise ValueError(kind)
    if not gps_l1_optional:
        refuse_no_l1_phase(p, kind, header, raw)
    return GnssReceiver(name, kind, p.name, header, raw, info, sf_nav if kind == "ubx" else None)


def ubx_header_info(p: Path, name: str, info_u: dict, raw: pd.DataFrame) -> tuple[dict, dict]:
    """(the receiver's header, its read summary ``info``) of a UBX log's read summary
    (:func:`~cdgps_cli.io.ubx.read_ubx_log`'s ``info``) and raw table: the station position of its RTCM
    1005/1006 messages, the nominal interval of its epochs."""
    base = info_u.get("rtcm_base")
    header = {"path": str(p), "format": "UBX RXM-RAWX", "marker_name": name,
              "approx_position_xyz_m": base["arp_ecef_m"] if base else None,
              "position_source": f"RTCM {base['message']} ARP (station {base['station_id']})" if base else None,
              "receiver_type": "u-blox (RXM-RAWX)", "interval_s": sampling_interval_s(raw["time_gps_s"].to_numpy())}
    return _json_safe(header), _json_safe(info_u)


def rinex_header_info(p: Path, hdr: dict) -> tuple[dict, dict]:
    """(the receiver's header, its read summary ``info``) of a RINEX observation file's header as read
    (:func:`~cdgps_cli.io.rinex.read_rinex_obs`); CdgpsError for a file of another type."""
    if hdr.get("file_type") not in (None, "O"):
        raise CdgpsError(f"{p}: not an observation file")
    header = _json_safe(hdr)
    info = {k: header.get(k) for k in ("version", "marker_name", "receiver_type", "antenna_type", "interval_s",
                                       "n_epochs", "n_epochs_power_failure", "gps_satellites",
                                       "satellites_by_system", "l1_obs_types")}
    return header, info


def refuse_no_l1_phase(p: Path, kind: str, header: dict, raw: pd.DataFrame) -> None:
    """CdgpsError naming the file when its raw table holds no GPS L1 carrier phase."""
    if len(raw) and np.isfinite(raw["phase_cycles"].to_numpy()).any():
        return
    what = "a valid carrier phase (cpValid) in any RXM-RAWX epoch" if kind == "ubx" else \
        f"a value in its L1 phase column ({(header.get('l1_obs_types') or {}).get('phase', 'L1')})"
    raise CdgpsError(f"{p}: no GPS L1 carrier-phase observations: no satellite has {what}; carrier-phase "
                     f"differential GPS needs L1 phase at every receiver")


# ----------------------------------------------------------------------------------------------
# slips from the receivers' own flags


# ----------------------------------------------------------------------------------------------
# writing


_SIGNAL_DTYPES = {"time_gps_s": np.float64, "phase_cycles": np.float64, "pseudorange_m": np.float64, "lli": np.int8,
                  "wavelength_m": np.float64}
_SIGNAL_UBX_DTYPES = {"lock_time_ms": np.int32, "half_cycle": np.int8}
"""Columns of a UBX receiver's signal table (:func:`~cdgps_cli.io.ubx.read_ubx_signals`): loss of lock
comes from the lock times at processing."""
_SIGNAL_COLUMNS = ["time_gps_s", "sat", "signal", "phase_cycles", "pseudorange_m", "lli", "wavelength_m"]


def _signal_dtypes(signals: pd.DataFrame) -> dict:
    """The stored dtypes of a signal table's numeric columns (a UBX log's lock times and half-cycle status too)."""
    ubx = all(c in signals for c in _SIGNAL_UBX_DTYPES)
    return {**_SIGNAL_DTYPES, **(_SIGNAL_UBX_DTYPES if ubx else {})}


class _ReceiverArchives:
    """Receiver ``i``'s observation archives (:class:`~cdgps_cli.io.gnss_archive.TableBlocks`): its raw table and, when
    it has one, its signal table, written as their rows come."""

    def __init__(self, i: int):
        self.i = i
        self.obs = gnss_archive.TableBlocks(OBS_PREFIX.format(i), ("sat",), _DTYPES)
        self.sig = None

    def add(self, raw: pd.DataFrame, signals: pd.DataFrame | None, submit) -> list:
        out = _add_blocks(self.obs, raw, submit)
        if signals is not None:
            if self.sig is None:
                self.sig = gnss_archive.TableBlocks(SIGNALS_PREFIX.format(self.i), ("sat", "signal"),
                                                    _signal_dtypes(signals))
            out += _add_blocks(self.sig, signals, submit)
        return out

    def finish(self, submit) -> list:
        return self.obs.finish(submit) + (self.sig.finish(submit) if self.sig is not None else [])


def _add_blocks(tb, tab: pd.DataFrame, submit) -> list:
    """``tab``'s rows added to ``tb`` block by block (:func:`~cdgps_cli.io.gnss_archive.block_bounds`)."""
    return [a for lo, hi in gnss_archive.block_bounds(tab["time_gps_s"].to_numpy()) for a in tb.add(tab.iloc[lo:hi], submit)]


def _pack_receiver(rx: GnssReceiver, i: int, submit) -> list:
    """The attachments of receiver ``i``'s tables, in blocks (:class:`_ReceiverArchives`): [(name, bytes or a future
    of them)]."""
    arch = _ReceiverArchives(i)
    return arch.add(rx.raw, rx.signals, submit) + arch.finish(submit)


def _time_sorted(tab: pd.DataFrame | None) -> bool:
    t = tab["time_gps_s"].to_numpy() if tab is not None else np.zeros(0)
    return bool((t[1:] >= t[:-1]).all())


def record_blocks(receivers: dict):
    """The receivers' tables in blocks of GPS time (:data:`~cdgps_cli.io.gnss_archive.OBS_BLOCK_S`), as a long
    file's hours are read (:mod:`cdgps_cli.io.rinex_hours`): :class:`Blocks` of, for each block in time order,
    [(its raw rows, its signal rows or None)] per receiver.  A table not in time order: one block of everything (its archives are still
    cut by hour, and its messages put in time order, by the writer)."""
    tabs = [(rx.raw, rx.signals) for rx in receivers.values()]
    if not all(_time_sorted(r) and _time_sorted(g) for r, g in tabs):
        return Blocks([tabs], 1)
    bounds = [[_numbered(t) if t is not None else None for t in pair] for pair in tabs]
    keys = sorted({k for pair in bounds for b in pair if b is not None for k in b}) or [None]
    return Blocks(([tuple(None if t is None else t.iloc[slice(*b.get(k, (0, 0)))] for t, b in zip(pair, pb))
                    for pair, pb in zip(tabs, bounds)] for k in keys), len(keys))


def _numbered(tab: pd.DataFrame) -> dict:
    """Block number → (first row, end row) of a table in time order."""
    t = tab["time_gps_s"].to_numpy()
    return {math.floor(float(t[lo]) / gnss_archive.OBS_BLOCK_S): (lo, hi)
            for lo, hi in gnss_archive.block_bounds(t) if hi > lo}


def _raw_table(c, i: int, what: str, columns=None, window=None) -> pd.DataFrame:
    """Receiver ``i``'s raw table of a RUN's contents (``columns``: only these numeric ones; ``window``: GPS s)."""
    return gnss_archive.read_table(c, OBS_PREFIX.format(i), what, ("sat",), _DTYPES, list(RAW_COLUMNS), keep=columns,
                                   window=window)


def _signal_table(c, i: int, what: str, window=None) -> pd.DataFrame:
    """Receiver ``i``'s multi-signal table of a RUN's contents (``window``: GPS s)."""
    return gnss_archive.read_table(c, SIGNALS_PREFIX.format(i), what, ("sat", "signal"), _SIGNAL_DTYPES,
                                   _SIGNAL_COLUMNS, optional=tuple(_SIGNAL_UBX_DTYPES), window=window)


def _nullable(values: np.ndarray) -> list:
    lst = values.tolist()
    if values.dtype.kind == "f" and np.isnan(values).any():
        return [None if x != x else x for x in lst]
    return lst



def default_config_text(files: dict, nav_paths, master: str | None, signals=None) -> str:
    """A GNSS run config for files given only on the command line (static model, defaults; ``signals``: the
    ``[gnss] signals`` key, none for GPS L1 alone)."""
    sig = list(signals or ())
    return gnss_config_toml({n: (k, None) for n, (k, _) in files.items()}, [], master,
                            options={"signals": sig} if sig and sig != ["G:L1"] else None,
                            comments=["GNSS run config generated by 'cdgps ingest' (no --config given): defaults,",
                                      "static rover displacements; files and navigation data came from the command line."])


def system_list(systems) -> str:
    """'GPS, Galileo' for ('G', 'E')."""
    from cdgps_cli.core.signals import SYSTEM_NAMES  # noqa: PLC0415

    return ", ".join(SYSTEM_NAMES.get(c, c) for c in systems) or "no system"


def merge_nav(nav_paths, systems=("G",)) -> pd.DataFrame:
    """Read and merge navigation files (exact duplicates removed), as ``cdgps baseline`` does;
    ``systems``: the systems whose records are read (a file without any of them is skipped while
    another file has them; every system must be found in some file)."""
    from cdgps_cli.io.rinex import nav_file_systems  # noqa: PLC0415

    holding = [p for p in nav_paths if set(nav_file_systems(p)) & set(systems)]
    if nav_paths and not holding:       # e.g. only a Galileo file (RINEX_EN) where GPS is wanted
        raise CdgpsError(f"the navigation files ({', '.join(f'{Path(p).name}: {system_list(nav_file_systems(p))}' for p in nav_paths)}) "
                         f"hold no ephemerides of {system_list(systems)}, which are needed")
    if tuple(systems) == ("G",):
        return _merge_nav_tables([read_rinex_nav(p) for p in holding])
    tabs = [read_rinex_nav(p, systems=tuple(systems)) for p in holding]
    nav = _merge_nav_tables(tabs)
    have = set(nav["sat"].astype(str).str[0])
    missing = [c for c in systems if c not in have]
    if missing:
        why = ("the config's signals need them (a run of other systems alone lists only theirs, e.g. "
               "signals = [\"E:E1\", \"E:E5a\"]: its first signal then fixes the epochs and clocks)")
        raise CdgpsError(f"the navigation data ({', '.join(map(str, nav_paths))}) have no ephemerides of system(s) "
                         f"{system_list(missing)}; {why}")
    return nav


def _nav_systems(signals, nav_list) -> tuple:
    """Systems whose ephemerides the signals need (GPS first when the GPS L1 tables anchor the epochs,
    :func:`~cdgps_cli.core.signals.anchor_signal`; a run of other systems only needs none of GPS)."""
    from cdgps_cli.core.signals import SYSTEM_NAMES, anchor_signal, signal  # noqa: PLC0415
    from cdgps_cli.io.rinex import NAV_SYSTEMS  # noqa: PLC0415

    own = sorted({signal(g).system for g in signals} - {"G"})
    systems = (["G"] if anchor_signal(signals) is None or any(signal(g).system == "G" for g in signals) else []) + own
    bad = [c for c in systems if c not in NAV_SYSTEMS]
    if bad:
        raise CdgpsError(f"signals of {', '.join(SYSTEM_NAMES[c] for c in bad)} cannot be ingested yet: broadcast "
                         f"ephemerides are read for {', '.join(SYSTEM_NAMES[c] for c in NAV_SYSTEMS)} only")
    return tuple(systems)


def _glonass_nav(signals, nav_list) -> tuple:
    """With GLONASS signals: the navigation data read ahead for their frequency numbers, as
    (nav table or None, {sat: k}).  A navigation error is left for the regular read after the
    observation files (whose errors come first); (None, {}) without GLONASS signals."""
    if not nav_list or not any(str(g).startswith("R:") for g in signals):
        return None, {}
    try:
        nav = merge_nav(nav_list, _nav_systems(signals, nav_list))
    except CdgpsError:
        return None, {}
    if "glonass_k" not in nav.columns:
        return nav, {}
    k = nav.dropna(subset=["glonass_k"]).groupby("sat")["glonass_k"].first()
    return nav, {str(sat): int(v) for sat, v in k.items()}


def _read_signal_tables(signals, receivers: dict, files: dict, say, glonass_k: dict | None = None,
                        pieces: dict | None = None, warnings: list | None = None) -> None:
    """Every receiver's table of ``signals`` (RINEX, or a UBX log's RXM-RAWX: :func:`~cdgps_cli.io.ubx.read_ubx_signals`);
    CdgpsError naming the file when a receiver lacks one of them (the receivers must share every
    signal asked for).  ``glonass_k``: GLONASS frequency numbers of the navigation records, for
    RINEX files whose header lacks ``GLONASS SLOT / FRQ #`` (UBX logs carry freqId)."""
    from cdgps_cli.io.rinex_signals import (first_of_repeated_epochs, glonass_without_frequency_text,  # noqa: PLC0415
                                            read_rinex_signals, signal_attributes)
    from cdgps_cli.io.ubx import read_ubx_signals  # noqa: PLC0415

    glonass_k = dict(glonass_k or {})
    attrs, notes = signal_attributes({n: [(files[n][0], q, None) for q in ((pieces or {}).get(n) or [files[n][1]])]
                                      for n in receivers}, signals)
    if warnings is not None:
        warnings.extend(notes)
    order = sorted(receivers, key=lambda n: files[n][0] != "ubx")      # u-blox logs first: their GLONASS numbers
    for n in order:
        rx = receivers[n]
        kind, p = files[n]
        say(f"reading signals {', '.join(signals)} of {p} ({n}) …")
        paths = (pieces or {}).get(n) or [p]
        rejoined = kind == "ubx" and len(paths) > 1 and isinstance(rx.info, dict) and "record_problems" in rx.info
        if rejoined:                 # the raw table is the one byte stream's (_rejoin_cut_frames): the signals too
            from cdgps_cli.io.gnss_sequence import ubx_bytes  # noqa: PLC0415

            tabs, paths = [read_ubx_signals(pieces_text(paths), signals,
                                            data=b"".join(ubx_bytes(q) for q in paths))], [pieces_text(paths)]
        else:
            split = (rx.info.get("signals_by_file") if isinstance(rx.info, dict) else None) or [signals] * len(paths)
            tabs = [read_ubx_signals(q, signals) if kind == "ubx"
                    else read_rinex_signals(q, sub, glonass_k, attributes=attrs[n])[1] for q, sub in zip(paths, split)]
        if kind == "ubx":             # RXM-RAWX's freqId: the numbers a RINEX file without its slots needs
            for t in tabs:
                for sat, k in glonass_numbers(t).items():
                    glonass_k.setdefault(sat, k)
        for q, t in zip(paths, tabs):
            unknown = t.attrs.get("glonass_without_frequency")
            if unknown and warnings is not None:
                warnings.append(glonass_without_frequency_text(f"{q} ({n})", unknown))
        by_system = isinstance(rx.info, dict) and rx.info.get("signals_by_file")
        tab = tabs[0] if len(tabs) == 1 else merge_signal_tables(tabs) if by_system else join_signal_tables(n, tabs, paths)
        tab = first_of_repeated_epochs(tab)[0]        # an epoch written twice: the first (the L1 reader's warning says)
        refuse_absent_signals(signals, tab, p, n)
        rx.signals = tab


def glonass_numbers(tab: pd.DataFrame) -> dict:
    """{satellite: GLONASS frequency number k} of a signal table's GLONASS rows (their wavelengths: f = c/λ =
    f₀ + k Δf), e.g. a u-blox log's, whose RXM-RAWX carries each satellite's freqId."""
    from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S  # noqa: PLC0415
    from cdgps_cli.core.signals import signal  # noqa: PLC0415

    out = {}
    glo = tab[tab["signal"].astype(str).str.startswith("R:").to_numpy()]
    for (sat, name), lam in glo.groupby(["sat", "signal"], observed=True)["wavelength_m"].first().items():
        sg = signal(str(name))
        k = int(round((SPEED_OF_LIGHT_M_S / float(lam) - sg.frequency_hz) / sg.fdma_step_hz))
        if -7 <= k <= 6:
            out.setdefault(str(sat), k)
    return out


def refuse_absent_signals(signals, tab: pd.DataFrame, p, n: str) -> None:
    """CdgpsError naming the file when its signal table lacks one of ``signals`` (every receiver must have each)."""
    have = set(tab["signal"])
    absent = [g for g in signals if g not in have]
    if absent:
        raise CdgpsError(f"{p} ({n}): no {', '.join(absent)} phase observations; the receivers must share every "
                         f"signal of [gnss] signals (this file has: {', '.join(sorted(have)) or 'none'})")


def _merge_nav_tables(navs) -> pd.DataFrame:
    """Ephemeris tables merged (exact duplicates removed), sorted as the RINEX reader's."""
    nav = pd.concat(navs, ignore_index=True)
    nav = nav.drop_duplicates(subset=["sat", "toe_gps_s", "iode", "af0_s"], keep="first")
    return nav.sort_values(["sat", "toe_gps_s", "transmit_gps_s"], kind="stable").reset_index(drop=True)


def rovers_given(receivers: dict, master: str) -> bool:
    """Whether any receiver but the master is in the run (a pair, which ``cdgps init`` can process)."""
    return any(n != master for n in receivers)


def span_text(t) -> str:
    t = np.asarray(t, dtype=np.float64)
    return f"{gps_time_str(float(t.min()))} – {gps_time_str(float(t.max()))}" if t.size else "no epochs"


@dataclass
class IngestInputs:
    """The inputs of a GNSS ingest, read and checked for what needs no model (:func:`read_ingest_inputs`).

    ``files``: antenna → (kind ``"rinex"``/``"ubx"``, path); ``master``; ``nav_list``: navigation
    file paths; ``receivers``: antenna → :class:`GnssReceiver` (master first); ``nav``: merged
    ephemerides or None; ``integrity``: per UBX receiver; ``warnings``: list of str (appended to
    by the later checks, in order).
    """

    files: dict
    master: str
    nav_list: list
    receivers: dict
    nav: pd.DataFrame | None
    integrity: dict
    warnings: list
    nav_source: str = ""
    pieces: dict | None = None
    """Antenna → its files in time order (several: one record joined, :mod:`cdgps_cli.io.gnss_sequence`)."""
    joins: dict | None = None
    """Antenna with several files → how they joined (files, gaps, overlaps; GPS s)."""
    first_rows: dict | None = None
    """Antenna → the raw rows (full precision) of its record's first :data:`~cdgps_cli.config.options.
    HEADER_CHECK_EPOCHS` epochs, for the nominal position of a rover without one (set by the hour-by-hour reading,
    whose receivers keep thin tables; the whole reading's receivers hold every row)."""
    antennas: dict | None = None
    """With ``[gnss] antex``: what :func:`antennas_info` says of the calibrations the run keeps (set by the ingest's
    checks); None: none."""


def read_ingest_inputs(cfg: GnssConfig, out_path: str | Path, *, rinex: dict | None = None, ubx: dict | None = None,
                       nav_paths=None, master: str | None = None, progress=None, strict: bool = False) -> IngestInputs:
    """Resolve and read the receiver and navigation files of a GNSS ingest.

    The stage is :func:`cdgps_cli.pipeline.gnss_ingest.ingest_gnss` (parameters documented there),
    which then checks the ephemeris coverage and the common epochs (model computations) and
    writes the run with :func:`write_gnss_run`.
    """
    say = progress or (lambda m: None)
    files, pieces, shared = _ingest_files(cfg, rinex, ubx)
    master = master or cfg.master or (next(iter(files)) if len(files) == 1 else None)
    if not master:
        raise CdgpsError(f"--master is required: which of {', '.join(files)} is the reference receiver at a known position")
    if master not in files:
        raise CdgpsError(f"master {master!r} is not one of the receivers given: {', '.join(files)}")
    nav_list = expand_paths(list(cfg.nav), f"{cfg.path}: [gnss] nav") if nav_paths is None else \
        expand_paths([str(p) for p in nav_paths], "--nav")
    _refuse_overwriting_an_input(Path(out_path), pieces, nav_list)
    warnings: list[str] = list(shared)
    receivers, joins = _read_receivers(cfg, files, pieces, say, strict, warnings)
    # master first, then the others in the given order
    receivers = {master: receivers[master], **{n: r for n, r in receivers.items() if n != master}}
    integrity = _ubx_integrity(receivers, files)
    for n, rx in receivers.items():
        warnings += _receiver_warnings(n, files[n][1], rx)
    nav_ahead, glonass_k = _glonass_nav(cfg.signals, nav_list)
    if cfg.signals:
        _read_signal_tables(cfg.signals, receivers, files, say, glonass_k, pieces, warnings)
    for n, rx in receivers.items():
        warnings += empty_epochs_warning(n, files[n][1], rx)
    nav, nav_source = _ingest_nav(cfg, nav_list, nav_ahead, receivers, files, pieces, master, say, warnings)
    return IngestInputs(files, master, nav_list, receivers, nav, integrity, warnings, nav_source, pieces, joins)


def _ingest_files(cfg: GnssConfig, rinex: dict | None, ubx: dict | None) -> tuple[dict, dict, list]:
    """The receivers' files of an ingest: (antenna → (kind, file or the text of its pieces), antenna → the files
    its patterns expand to, the warning of a file given to two antennas), from --rinex/--ubx or else the config's [gnss.antennas.NAME] tables; CdgpsError for an
    antenna given twice, one without a file, or none at all."""
    files: dict = {}
    if rinex or ubx:
        for kind, d in (("rinex", rinex or {}), ("ubx", ubx or {})):
            for n, p in d.items():
                if n in files:
                    raise CdgpsError(f"antenna {n!r} is given twice (--rinex/--ubx)")
                files[n] = (kind, p)
        opt = "--{} " + "{}"
    else:
        for a in cfg.antennas:
            if a.rinex or a.ubx:
                files[a.name] = ("rinex", a.rinex) if a.rinex else ("ubx", a.ubx)
        missing = [a.name for a in cfg.antennas if not (a.rinex or a.ubx)]
        if missing:
            raise CdgpsError(f"{cfg.path}: no observation file for antenna(s) {', '.join(missing)}; give rinex/ubx in "
                             f"[gnss.antennas.NAME] or --rinex/--ubx NAME=FILE")
        opt = f"{cfg.path}: [gnss.antennas.{{1}}] {{0}}"
    pieces = {n: expand_paths([p] if isinstance(p, (str, Path)) else list(p), opt.format(k, n))
              for n, (k, p) in files.items()}
    shared = one_file_for_two_receivers({opt.format(k, n): pieces[n] for n, (k, _) in files.items()})
    files = {n: (k, pieces[n][0] if len(pieces[n]) == 1 else pieces_text(pieces[n])) for n, (k, _) in files.items()}
    if not files:
        raise CdgpsError("no receiver files: give --rinex NAME=FILE / --ubx NAME=FILE, or list them in the config's "
                         "[gnss.antennas.NAME] tables")
    return files, pieces, shared


def _files_by_system(exc: CdgpsError, kind: str, paths: list, signals) -> list:
    """Each file's signals when a receiver's RINEX files hold its systems side by side (a file per system, as gnss-sdr
    writes them: :func:`~cdgps_cli.io.rinex_signals.signals_by_file`; looked at only once a file failed to read as a
    piece of one record); else the reading error ``exc`` is raised."""
    from cdgps_cli.io.rinex_signals import signals_by_file  # noqa: PLC0415

    split = signals_by_file(paths, list(signals)) if kind == "rinex" and signals else None
    if split is None:
        raise exc
    return split


def _merged_by_system(n: str, kind: str, paths: list, split: list, l1_opt: bool, strict: bool) -> tuple:
    """A receiver from its files of one system each (:func:`~cdgps_cli.io.gnss_sequence.merge_systems`): each read
    without needing GPS L1, the merged record then holding GPS L1 phase unless the run's epochs are anchored on
    another signal.  (receiver, join record, warnings)."""
    from cdgps_cli.io.gnss_sequence import merge_systems  # noqa: PLC0415

    rxs = [read_receiver_file(n, kind, q, gps_l1_optional=True, strict=strict) for q in paths]
    rx, join, said = merge_systems(n, rxs, paths, split)
    if not l1_opt:
        refuse_no_l1_phase(Path(paths[0]), kind, rx.header, rx.raw)
    return rx, join, said


def _refuse_overwriting_an_input(out_path: Path, pieces: dict, nav_list: list) -> None:
    """CdgpsError when the output is one of the receivers' or navigation files."""
    for n, ps in pieces.items():
        for p in ps:
            if Path(p).resolve() == out_path.resolve():
                raise CdgpsError(f"{out_path}: the output would overwrite the input file of {n}")
    for p in nav_list:
        if Path(p).resolve() == out_path.resolve():
            raise CdgpsError(f"{out_path}: the output would overwrite the navigation file {p}")


def _read_receivers(cfg: GnssConfig, files: dict, pieces: dict, say, strict: bool, warnings: list) -> tuple[dict, dict]:
    """Each antenna's receiver (its consecutive files joined in time order: ``files`` and ``pieces`` updated to that
    order) and the joins' records; the joins' warnings appended to ``warnings``."""
    from cdgps_cli.core.signals import anchor_signal  # noqa: PLC0415

    receivers, joins = {}, {}
    l1_opt = anchor_signal(cfg.signals) is not None       # epochs and clocks from another signal: GPS L1 not needed
    if all(len(ps) == 1 for ps in pieces.values()):
        receivers = _read_single_files(files, pieces, say, strict, l1_opt)
    for n, (kind, p) in files.items():
        if n in receivers:
            continue
        say(f"reading {kind.upper()} {p} ({n}) …")
        if len(pieces[n]) == 1:
            receivers[n] = read_receiver_file(n, kind, pieces[n][0], strict=strict, gps_l1_optional=l1_opt)
            continue
        try:                   # (a receiver's files of one system each: merged, once they fail as pieces in time)
            rxs = [read_receiver_file(n, kind, q, gps_l1_optional=l1_opt) for q in pieces[n]]   # (--strict: below)
            receivers[n], joins[n], w, order = join_receivers(n, rxs, pieces[n])
        except CdgpsError as exc:
            split = _files_by_system(exc, kind, pieces[n], cfg.signals)
            receivers[n], joins[n], w = _merged_by_system(n, kind, pieces[n], split, l1_opt, strict)
            warnings.extend(w)
            continue
        pieces[n] = [pieces[n][i] for i in order]
        files[n] = (kind, pieces_text(pieces[n]))
        if kind == "ubx":
            _rejoin_cut_frames(n, receivers[n], joins[n], pieces[n], w)
        if strict:
            _refuse_lost_data(n, receivers[n], pieces[n])
        warnings.extend(w)
    return receivers, joins


def _ingest_nav(cfg: GnssConfig, nav_list: list, nav_ahead, receivers: dict, files: dict, pieces: dict, master: str,
                say, warnings: list) -> tuple:
    """The run's broadcast ephemerides and where they come from: the navigation files, else the UBX logs' RXM-SFRBX
    subframes (CdgpsError when a UBX-only pair has neither), else none (a warning: ``init`` needs them)."""
    nav = None
    sf_navs = [rx.nav for rx in receivers.values() if rx.nav is not None and len(rx.nav)]
    nav_source = ",".join(Path(p).name for p in nav_list)
    if not nav_list and sf_navs:
        say(f"using {sum(len(x) for x in sf_navs)} broadcast ephemerides decoded from the UBX logs' RXM-SFRBX subframes …")
        nav = _merge_nav_tables(sf_navs)
        nav_source = "RXM-SFRBX:" + ",".join(Path(q).name for n, rx in receivers.items()
                                             if rx.nav is not None and len(rx.nav) for q in pieces[n])
    elif not nav_list and rovers_given(receivers, master) and all(rx.format == "ubx" for rx in receivers.values()):
        raise CdgpsError(
            "no broadcast ephemerides: no navigation file was given and none of the UBX logs ("
            + ", ".join(Path(files[n][1]).name for n in receivers) + ") has GPS RXM-SFRBX subframes 1-3 of a satellite "
            "it observed; enable UBX-RXM-SFRBX output on the receivers, or give --nav with the RINEX navigation file "
            "of that day")
    if nav_list:
        say(f"reading {len(nav_list)} navigation file(s) …")
        nav = nav_ahead if nav_ahead is not None else merge_nav(nav_list, _nav_systems(cfg.signals, nav_list))
    elif not sf_navs:               # SFRBX ephemerides are a navigation source (issue 28)
        warnings.append("no navigation file: the run has no ephemerides, and 'cdgps init' needs them "
                        "(ingest again with --nav, or list nav files in the config)")
    return nav, nav_source


_LOSS_OFFSETS = ("bad_frame_offsets", "undecodable_frame_offsets", "bad_rtcm_offsets")
#: a gap between two u-blox logs of one receiver at most this many sampling intervals (or twice the log's own longest
#: spacings): the epoch a cut frame held, not a log missing between them
MAX_CUT_GAP_STEPS = 2.5


def _rejoin_cut_frames(name: str, rx: GnssReceiver, join: dict, paths: list, warnings: list) -> None:
    """A UBX frame cut in two by a logger's file rotation (a file ending in a truncated frame whose
    rest begins the next file) is joined again: the files, consecutive bytes of one log (no file
    repeats another's epochs), are read once more as one byte stream, and the record becomes that
    stream's — what the single log would have given.  Kept only when the stream loses less than the
    files one by one; the losses left (``info["record_problems"]``) name the file and byte."""
    files = rx.info.get("files") or []
    if join["overlaps"] or not any(f.get("truncated_tail_bytes") for f in files[:-1]):
        return
    # a frame cut by a rotation leaves an epoch missing at that boundary, a gap like the log's own; a longer one is a
    # log missing between the two files, whose bytes are not each other's continuation (joined, they made a frame
    # that fails its checksum): then no file is joined again
    t = np.unique(rx.raw["time_gps_s"].to_numpy(dtype=np.float64))
    own = float(np.percentile(np.diff(t), 99)) if t.size > 2 else 0.0
    limit = max(MAX_CUT_GAP_STEPS * sampling_interval_s(t), 2.0 * own)
    if any(g["gap_s"] > limit for g in join["gaps"]):
        return
    from cdgps_cli.io.gnss_sequence import ubx_bytes  # noqa: PLC0415

    parts = [ubx_bytes(p) for p in paths]
    one = read_receiver_file(name, "ubx", pieces_text(paths), data=b"".join(parts))

    def lost(info):
        return sum(int(info.get(k) or 0) for k in INTEGRITY_COUNTS if k != "n_frames")

    if lost(one.info) >= lost(rx.info):
        return
    starts = np.cumsum([0] + [len(b) for b in parts])
    where = {k: [f"{Path(paths[i]).name} byte {o - starts[i]}" for o in one.info.get(k) or []
                 for i in [int(np.searchsorted(starts, o, side="right")) - 1]] for k in _LOSS_OFFSETS}
    cut = [f"{Path(paths[i]).name} → {Path(paths[i + 1]).name}" for i, f in enumerate(files[:-1])
           if f.get("truncated_tail_bytes")]
    keep = {k: rx.info[k] for k in ("files", "join") if k in rx.info}
    rx.raw, rx.nav = one.raw, one.nav
    # (``record_problems``, present only here, also tells the signal tables to read this one stream)
    rx.info = {**one.info, **keep, "path": rx.info.get("path"), "record_problems": integrity_problems({**one.info, **where})}
    for f in rx.info["files"]:
        f["problems"] = []
    t = np.unique(one.raw["time_gps_s"].to_numpy())
    for g in [g for g in join["gaps"] if ((t > g["start_s"]) & (t < g["end_s"])).any()]:   # epochs found again
        join["gaps"].remove(g)
        warnings[:] = [w for w in warnings if f"between {g['after']} (last epoch" not in w
                       or f"and {g['before']} (first epoch" not in w]
    join["frames_joined_across_files"] = cut
    warnings.append(f"{name}: UBX frame(s) cut by the file rotation ({', '.join(cut)}) joined again: the files were "
                    f"read as one byte stream")


def _refuse_lost_data(name: str, rx: GnssReceiver, paths: list) -> None:
    """``--strict`` on a UBX record of several files: the first file with lost data (time order) is
    refused, naming it, its span and the losses."""
    if rx.info.get("record_problems"):
        raise CdgpsError(f"{pieces_text(paths)} ({name}): corrupt UBX data: {', '.join(rx.info['record_problems'])} "
                         f"(refused by --strict)")
    for f, p in zip(rx.info.get("files") or [], paths):
        if f.get("problems"):
            raise CdgpsError(f"{p} ({name}, epochs {gps_time_str(f['first_s'])} – {gps_time_str(f['last_s'])}): corrupt "
                             f"UBX data: {', '.join(f['problems'])} (refused by --strict)")


def first_epoch_rows(raw: pd.DataFrame, n_epochs: int) -> pd.DataFrame:
    """The rows of a receiver's raw table at its first ``n_epochs`` distinct time tags (its record's first epochs)."""
    t = raw["time_gps_s"].to_numpy(dtype=np.float64)
    tags = np.unique(t)
    if tags.size <= n_epochs:
        return raw
    return raw[t <= tags[n_epochs - 1]]


#: the position source of a rover placed at ingest by its pseudoranges (no config position, no header position)
INGEST_SPP_SOURCE = "pseudorange single-point position of its first epochs (ingest)"


def nominal_positions(cfg: GnssConfig, inp: IngestInputs, single_point=None) -> dict:
    """Antenna → (source, ECEF position m as list) or (None, None): the config's ``position_ecef_m``,
    else the RINEX header's APPROX POSITION XYZ, else for a rover ``single_point(name)`` (ECEF m or None: its
    pseudorange single-point position, :func:`cdgps_cli.pipeline.gnss_ingest.first_epochs_position`), the origin of
    its displacement states in every window of the run.  Appends the warnings (and raises for a master
    without a position while there are rovers)."""
    receivers, master, files, warnings = inp.receivers, inp.master, inp.files, inp.warnings
    pos_src = {}
    for n, rx in receivers.items():
        a = cfg.antenna(n)
        if a is not None and a.position_ecef_m is not None:
            pos_src[n] = ("config position_ecef_m", list(a.position_ecef_m))
        elif header_position_m(rx.header) is not None:
            pos_src[n] = (_header_position_source(rx.header, n == master), header_position_m(rx.header).tolist())
        else:
            pos_src[n] = (None, None)
    rovers = [n for n in receivers if n != master]
    if pos_src[master][0] is None:
        msg = (f"master {master} ({files[master][1]}) has no position: no usable RINEX header APPROX POSITION XYZ and no "
               f"position_ecef_m in [gnss.antennas.\"{master}\"]; the master must be at a known position")
        if rovers:
            raise CdgpsError(msg)
        warnings.append(msg + " (needed once rovers are added)")
    for n in rovers:
        if pos_src[n][0] is None:
            x = single_point(n) if single_point is not None else None
            if x is not None:
                pos_src[n] = (INGEST_SPP_SOURCE, [float(v) for v in x])
                warnings.append(f"{n}: no nominal position (header or config): the pseudorange single-point position "
                                f"of its first epochs ({' '.join(f'{v:.1f}' for v in x)}, good to a few metres) is its "
                                f"nominal position, and the displacement states of every window of the run refer to it")
            else:
                warnings.append(f"{n}: no nominal position (header or config), and none from its first epochs' "
                                f"pseudoranges (too few satellites with an ephemeris there): each 'cdgps init' places "
                                f"it at the single-point position of the epochs it reads, so windows of this run "
                                f"(init --start, batch sessions) refer to points metres apart; write its "
                                f"position_ecef_m in the config to give them one")
    return pos_src


def _header_position_source(header: dict, master: bool) -> str:
    """What a receiver's header position is: the master's antenna is its marker plus a non-zero ANTENNA: DELTA H/E/N
    (``positioning.antenna_reference_point_m``, where init and estimate put it); the position recorded is the
    marker's."""
    src = header.get("position_source") or "RINEX header APPROX POSITION XYZ"
    d = header.get("antenna_delta_hen_m")
    if master and d is not None and any(float(v) != 0.0 for v in d):
        src += f", the marker (the antenna: its ANTENNA: DELTA H/E/N {' '.join(f'{float(v):g}' for v in d)} m from it)"
    return src


def write_gnss_run(cfg: GnssConfig, out_path: str | Path, inp: IngestInputs, pos_src: dict, common: dict,
                   lock: dict, extra_attachments: dict | None = None, extra_inputs: dict | None = None) -> dict:
    """Write the GNSS RUN.mcap (atomically) of checked inputs; returns the ingest summary.

    ``pos_src``: from :func:`nominal_positions`; ``common``: rover → its common-epoch counts with
    the master (:func:`cdgps_cli.model.gps.epoch_align.common_epochs` plus the epoch counts);
    ``lock``: receiver → its lock counters per satellite
    (:func:`cdgps_cli.pipeline.gnss_ingest.lock_summary`, the one lock-segment rule);
    ``extra_attachments`` {name: bytes} (e.g. the sensor logs, :mod:`cdgps_cli.io.sensor_logs`) and
    ``extra_inputs`` {metadata key: path} of the files they came from (hashed like the others).
    The observations are written block by block (:func:`record_blocks`), as :func:`write_gnss_run_blocks` writes
    those of a long file read hour by hour: the same bytes.
    """
    return write_gnss_run_blocks(cfg, out_path, inp, list(inp.receivers), record_blocks(inp.receivers),
                                 lambda: (pos_src, common, lock, extra_attachments), extra_inputs)


class Blocks:
    """An iterable of a record's blocks (:func:`write_gnss_run_blocks`) that knows how many it holds (the progress
    bar's total)."""

    def __init__(self, items, n: int):
        self.items, self.n = items, n

    def __iter__(self):
        return iter(self.items)

    def __len__(self) -> int:
        return self.n


def write_gnss_run_blocks(cfg: GnssConfig, out_path: str | Path, inp: IngestInputs, names: list, blocks, finish,
                          extra_inputs: dict | None = None) -> dict:
    """:func:`write_gnss_run` of observations that come block by block.

    ``names``: the receivers, master first; ``blocks``: :class:`Blocks` (an iterable with a length), for each block
    of GPS time in time order, of [(raw rows, signal rows or None)] per receiver of ``names`` (:func:`record_blocks`; an ingest reading long files hour by hour fills
    ``inp.receivers`` as it goes).  ``finish()``, called once every block is written, returns (``pos_src``,
    ``common``, ``lock``, ``extra_attachments``) as :func:`write_gnss_run` takes them (its checks may raise: the
    output is then not written).
    """
    files, master, nav_list, nav = inp.files, inp.master, inp.nav_list, inp.nav
    out_path = Path(out_path)
    pieces = inp.pieces or {n: [p] for n, (_, p) in files.items()}
    inputs = {**{k: p for n, (kind, _) in files.items() for k, p in input_keys(f"{kind}:{n}", pieces[n])},
              **{f"nav[{i}]": p for i, p in enumerate(nav_list)}, **(extra_inputs or {})}
    with McapOut(out_path, time_scale="gps") as out:
        n_eph = _write_ephemerides(out, nav, inp.nav_source)
        ch = out.channel(GNSS_OBS_TOPIC, OBS_SCHEMA, {"units": "cycles, m, dB-Hz, Hz, ms"})
        n_msg = _write_observations(out, ch, names, blocks)
        pos_src, common, lock, extra_attachments = finish()
        receivers = inp.receivers
        rx_json = [{"name": n, "format": rx.format, "file": rx.file, "header": rx.header, "info": rx.info,
                    "position_source": pos_src[n][0], "position_ecef_m": pos_src[n][1]} for n, rx in receivers.items()]
        out.attach(RECEIVERS_ATTACHMENT, json.dumps(_json_safe(rx_json), indent=1).encode(), "application/json")
        out.attach(GNSS_INFO_ATTACHMENT, gnss_info_json(gnss_info(
            cfg, master, receivers, nav, {n: c["pairing"] for n, c in common.items()} if common is not None else None,
            lock, pos_src, inp.antennas)), "application/json")
        out.attach(CONFIG_ATTACHMENT, cfg.text.encode("utf-8"), "application/toml")
        for name, data in (extra_attachments or {}).items():
            out.attach(name, data, "text/csv" if name.endswith(".csv") else "application/octet-stream")
        out.metadata(INGEST_METADATA, _ingest_meta(cfg, inp, inputs))
    summary = {
        "output": str(out_path), "kind": "gnss", "config": cfg.name, "config_sha256": cfg.sha256, "master": master,
        "displacement_model": cfg.displacement,
        "receivers": [_receiver_summary(n, rx, lock[n], pos_src[n]) for n, rx in receivers.items()],
        "common_epochs": common,
        "ephemerides": n_eph, "ephemeris_satellites": int(nav["sat"].nunique()) if nav is not None else 0,
        "messages": n_msg, "warnings": inp.warnings, "integrity": inp.integrity,
    }
    if inp.joins:
        summary["joins"] = inp.joins
    if inp.antennas is not None:
        summary["antennas"] = inp.antennas
    return summary


def _ingest_meta(cfg: GnssConfig, inp: IngestInputs, inputs: dict) -> dict:
    """The RUN's ingest metadata record: inputs hashed, master, receivers, model, signals, UBX integrity, and where
    the ephemerides came from when not from navigation files."""
    meta = ingest_metadata("gnss", cfg, inputs, master=inp.master, receivers=",".join(inp.receivers),
                           displacement_model=cfg.displacement, **({"signals": ",".join(cfg.signals)} if cfg.signals else {}))
    for n, (kind, p) in inp.files.items():
        if n in inp.integrity:
            meta[f"{kind}:{n}_integrity"] = integrity_record(inp.receivers[n].info)
    if inp.nav is not None and not inp.nav_list:
        meta["ephemeris_source"] = inp.nav_source
    return meta


def _write_ephemerides(out: McapOut, nav: pd.DataFrame | None, nav_source: str) -> int:
    """The ephemeris messages and their table's attachment; how many."""
    if nav is None:
        return 0
    ch_e = out.channel(GNSS_EPHEMERIS_TOPIC, EPHEMERIS_SCHEMA, {"source": nav_source})
    n_eph = 0
    for rec in nav.to_dict(orient="records"):
        out.write(ch_e, float(rec["toc_gps_s"]), {k: _json_safe(v) for k, v in rec.items()})
        n_eph += 1
    cols = NAV_COLUMNS + (GLONASS_NAV_COLUMNS if "x_m" in nav.columns else ())   # GLONASS state vectors
    tab = {c: _json_safe(nav[c].tolist()) for c in cols}
    out.attach(EPHEMERIS_ATTACHMENT, json.dumps(tab).encode(), "application/json")
    return n_eph


def _write_observations(out: McapOut, ch: int, names: list, blocks) -> int:
    """Each block's observation messages (:func:`_write_obs_tables`), then its archives; the archives' indexes
    after the last block.  A block's archives are packed in a worker thread while its messages are built (numpy's
    copies and zstd release the GIL).  Returns the number of messages."""
    archives = [_ReceiverArchives(i) for i in range(len(names))]
    n_msg = 0
    bar = progress.bar(len(blocks), f"writing {out.path.name}", "block")
    try:
        for block in blocks:
            # a pool per block: no thread is left while the next block is read (its reading may fork, core/beside.py)
            with ThreadPoolExecutor(max_workers=1, thread_name_prefix="cdgps-archive") as pool:
                packed = [a for arch, (raw, sig) in zip(archives, block) for a in arch.add(raw, sig, pool.submit)]
                n_msg += _write_obs_tables(out, ch, {n: raw for n, (raw, _) in zip(names, block)})
                _attach_packed(out, packed)
            bar.update(1)
        _attach_packed(out, [a for arch in archives for a in arch.finish(lambda f, *a: f(*a))])
    except BaseException:
        bar.close(done=False)              # (no "done" line for work that stopped)
        raise
    bar.close()
    return n_msg


def _attach_packed(out: McapOut, packed: list) -> None:
    for name, data in packed:
        if isinstance(data, bytes):
            out.attach(name, data, "application/json")
        else:
            out.attach(name, data.result(), "application/x-npz+zstd")


def ubx_loss_warning(name: str, record: dict) -> str | None:
    """The warning of a UBX receiver's integrity record (``file``, ``n_frames``, ``problems``: one entry of
    :func:`_ubx_integrity`), None for a clean log; ``ingest`` and ``config`` say it alike."""
    if not record.get("problems"):
        return None
    return (f"{record['file']} ({name}): corrupt UBX data, skipped: {', '.join(record['problems'])}; "
            f"{record['n_frames']} frames read (the run lacks what was lost; 'ingest --strict' refuses such a log)")


def _ubx_integrity(receivers: dict, files: dict) -> dict:
    """Per UBX receiver: ``file`` (as given), the integrity counters of its read summary and
    ``problems`` (the worded losses; empty for a clean log)."""
    out = {}
    for n, rx in receivers.items():
        if rx.format != "ubx":
            continue
        per_file = rx.info.get("files")
        problems = rx.info["record_problems"] if "record_problems" in rx.info else integrity_problems(rx.info) \
            if not per_file else [
            f"{f['file']} (last epoch {gps_time_str(f['last_s'])}): {q}" for f in per_file for q in f.get("problems") or []]
        out[n] = {"file": files[n][1], **{k: int(rx.info.get(k) or 0) for k in INTEGRITY_COUNTS},
                  "problems": problems, "other_protocols": skipped_line(rx.info)}
    return out


def _missing_code_warning(name: str, path: str, rx: GnssReceiver) -> str | None:
    """A warning when a receiver has L1 phase but no L1 pseudorange at all (``cdgps init`` needs them)."""
    raw = rx.raw
    ph = np.isfinite(raw["phase_cycles"].to_numpy())
    if not ph.any() or np.isfinite(raw["pseudorange_m"].to_numpy()[ph]).any():    # (no GPS L1 at all: another anchor)
        return None
    types = (rx.header.get("l1_obs_types") or {}) if rx.format == "rinex" else {}
    if rx.format == "rinex" and not types.get("pseudorange"):
        what = f"no GPS L1 pseudorange observation type (C1C/C1/P1/…) in its header (L1 phase: {types.get('phase') or 'L1'})"
    elif rx.format == "rinex":
        what = f"its L1 pseudorange column ({types['pseudorange']}) is empty wherever there is L1 phase"
    else:
        what = "no valid pseudorange (prValid) with any L1 phase"
    return (f"{name} ({path}): L1 carrier phase but no L1 pseudoranges — {what}; ingested, but 'cdgps init' needs "
            f"L1 pseudoranges at every receiver (its clock offset per epoch, i.e. the true reception times) and will "
            f"refuse this run")


def _receiver_summary(n, rx: GnssReceiver, lock: dict, pos) -> dict:
    tab = rx.raw if len(rx.raw) or rx.signals is None else rx.signals     # a file without GPS: its signal rows
    t = tab["time_gps_s"].to_numpy()
    ph = np.isfinite(tab["phase_cycles"].to_numpy(dtype=float))
    tu = distinct_times(t)
    interval = sampling_interval_s(tu)
    return {"name": n, "format": rx.format, "file": rx.file, "epochs": int(tu.size),
            "first": gps_time_str(float(tu[0])), "last": gps_time_str(float(tu[-1])),
            "first_gps_s": float(tu[0]), "last_gps_s": float(tu[-1]),
            # the interval it samples at (a base logging with gaps: 1 s, not its median spacing of 3 s), as the solvers
            "interval_s": interval, "gaps": gaps_summary(tu, interval),
            "satellites": int(tab["sat"].nunique()),
            "rows": int(len(t)), "phase_rows": int(ph.sum()),
            "slips": int(sum(v["slips"] for v in lock.values())),
            "half_cycle_rows": int(sum(v["half_cycle_rows"] for v in lock.values())),
            "arcs": int(sum(v["arcs"] for v in lock.values())),
            "position_source": pos[0], "position_ecef_m": pos[1], **_signal_summary(rx, tab)}


def gaps_summary(times_s: np.ndarray, interval_s: float | None) -> dict | None:
    """A GNSS receiver's epoch gaps summed up: how many (:func:`~cdgps_cli.io.run.epoch_gaps`' rule, a structure
    run's: spacings over 1.5 intervals), the epochs they miss and the longest, s; None with fewer than two epochs."""
    if interval_s is None or not interval_s > 0 or times_s.size < 2:
        return None
    gaps = epoch_gaps(times_s, interval_s)
    return {"count": len(gaps), "missing_epochs": int(sum(g["missing_epochs"] for g in gaps)),
            "longest_s": max((g["end_s"] - g["start_s"] for g in gaps), default=0.0)}


def _signal_summary(rx: GnssReceiver, counted) -> dict:
    """``signal_satellites`` ({system: satellites with a phase of a configured signal}) and ``signal_phase_rows``
    of the receiver's signal table, when it has one beside the GPS L1 table the other counts are of (so a
    multi-GNSS receiver is not summed up by its GPS L1 alone); nothing otherwise."""
    sig = rx.signals
    if sig is None or sig is counted or not len(sig):
        return {}
    ph = np.isfinite(sig["phase_cycles"].to_numpy(dtype=float))
    sats = np.unique(sig["sat"].to_numpy()[ph].astype(str))
    systems, counts = np.unique(np.array([x[0] for x in sats], dtype="U1"), return_counts=True)
    return {"signal_satellites": {str(k): int(v) for k, v in zip(systems, counts)}, "signal_phase_rows": int(ph.sum())}


_OBS_MESSAGES_PER_BLOCK = 4096
"""Messages whose rows :func:`_write_obs_messages` turns into Python lists at a time (the lists of a
day's pair took ~0.5 GB: issue 29)."""
_NULLABLE_OBS = ("phase_cycles", "pseudorange_m", "snr_dbhz", "doppler_hz")
_INT_OBS = ("lli", "half_cycle", "lock_time_ms")


def _write_obs_messages(out: McapOut, ch: int, receivers: dict) -> int:
    """:func:`_write_obs_tables` of the receivers' raw tables (each ``receivers`` value has ``.raw``)."""
    bar = progress.bar(None, f"writing {out.path.name}", "msg")
    n = _write_obs_tables(out, ch, {name: rx.raw for name, rx in receivers.items()}, bar)
    bar.close()
    return n


def _write_obs_tables(out: McapOut, ch: int, raws: dict, bar=None) -> int:
    """One message per receiver and epoch of the raw tables (``raws``: receiver name → its rows), in time order
    across receivers; ``bar``, if given, counts them.

    The bytes of :meth:`McapOut.write` of each epoch's payload (:func:`_obs_payload`), made from the
    texts of a block of messages' values (one orjson call per column and block, no dict per message;
    issue 29: 10 s of a day's ingest went to the dicts) and put together for the whole block at once
    (:func:`_obs_texts`); a message whose text would hold ``null`` (a value the schema has no place for,
    e.g. an infinity) goes through :meth:`McapOut.write`."""
    per = []
    for n, r in raws.items():
        t = r["time_gps_s"].to_numpy()
        cuts = np.flatnonzero(np.r_[True, t[1:] != t[:-1], True]) if t.size else np.zeros(1, dtype=np.int64)
        cols = {c: r[c].to_numpy() for c in (*_NULLABLE_OBS, *_INT_OBS)}
        cols["sat"] = r["sat"].to_numpy()
        flag = r["epoch_flag"].to_numpy()
        clk = r["clock_offset_s"].to_numpy()
        per.append((n, t, cuts, cols, flag, clk))
    times, ii_all, kk_all = _obs_order(per)
    for start in range(0, len(times), _OBS_MESSAGES_PER_BLOCK):
        part = slice(start, start + _OBS_MESSAGES_PER_BLOCK)
        part_times, ii, kk = times[part].tolist(), ii_all[part], kk_all[part]
        stamps = unix_ns_list(part_times, out.time_scale)
        blob = _obs_texts(per, part_times, stamps, ii, kk)
        datas = blob.split(b"\r")
        if len(datas) != len(part_times) + 1:
            raise AssertionError("observation messages: a carriage return in a message's text")
        datas.pop()
        names = [per[i][0] for i in ii.tolist()]
        nulls = [m for m, d in enumerate(datas) if b"null" in d] if b"null" in blob else []
        at = 0
        for m in nulls:                    # write()'s own rules for what the schema cannot hold
            out.write_encoded(ch, part_times[at:m], stamps[at:m], datas[at:m], names[at:m])
            i, k = int(ii[m]), int(kk[m])
            cuts = per[i][2]
            out.write(ch, part_times[m], _obs_payload(per[i], int(cuts[k]), int(cuts[k + 1])))
            at = m + 1
        out.write_encoded(ch, part_times[at:], stamps[at:], datas[at:], names[at:])
        if bar is not None:
            bar.update(len(part_times))
    return len(times)


def _obs_order(per: list) -> tuple:
    """(time, receiver, epoch) of the messages of the receivers ``per`` (as in :func:`_write_obs_tables`) in
    time order, then receiver and epoch (the order of the tuples' sort): arrays."""
    if not per:
        return np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    times = np.concatenate([np.asarray(p[1], dtype=float)[p[2][:-1]] for p in per])
    ii = np.concatenate([np.full(len(p[2]) - 1, i, dtype=np.int64) for i, p in enumerate(per)])
    kk = np.concatenate([np.arange(len(p[2]) - 1, dtype=np.int64) for p in per])
    if np.isnan(times).any():                       # (NaN: as the tuples' sort puts it)
        order = sorted(zip(times.tolist(), ii.tolist(), kk.tolist()))
        return (np.array([t for t, _, _ in order], dtype=float), np.array([i for _, i, _ in order], dtype=np.int64),
                np.array([k for _, _, k in order], dtype=np.int64))
    o = np.lexsort((kk, ii, times))
    return times[o], ii[o], kk[o]


def _obs_texts(per: list, part_times: list, stamps: list, ii: np.ndarray, kk: np.ndarray) -> bytes:
    """The JSON texts of the messages of a block, each followed by a carriage return (which no orjson text
    holds), in one bytes (message m: receiver ``per[ii[m]]``, its epoch ``kk[m]``, at ``part_times[m]``, log time
    ``stamps[m]`` ns).  Each field's texts of a receiver's messages, its key's words in front, come from one
    orjson text of its values split at the commas between messages (:func:`_message_texts`); the ``_valid``
    companion of a field with no missing value is a text per row count.  The pieces of all messages are laid
    out in one object array (a row per message) and joined at once: no Python work per message and field
    (issue 29)."""
    ncol = 5 + 2 * len(_NULLABLE_OBS) + len(_INT_OBS) + 1
    tabs, row0, n_rows = [], {}, 0
    for i in np.unique(ii).tolist():
        n, _, cuts, cols, flag, clk = per[i]
        ks = kk[ii == i]
        k0, k1 = int(ks.min()), int(ks.max()) + 1
        c = cuts[k0:k1 + 1]
        a = c[:-1]
        lo, hi = int(c[0]), int(c[-1])
        rel = c - lo
        m = k1 - k0
        every = np.arange(m + 1)
        A = np.empty((m, ncol), dtype=object)
        A[:, 3] = _message_texts(flag[a].astype(np.int64), every, b',"receiver":' + orjson.dumps(n) + b',"epoch_flag":')
        cv = clk[a].astype(float)
        fin = np.isfinite(cv)
        if fin.all():
            A[:, 4] = _message_texts(cv, every, b',"clock_offset_s":')
        else:
            A[:, 4] = b""
            if fin.any():
                A[fin, 4] = _message_texts(cv[fin], np.arange(int(fin.sum()) + 1), b',"clock_offset_s":')
        col, last = 5, len(cols) - 1
        for f, (name, v) in enumerate(cols.items()):
            v = v[lo:hi]
            missing = np.isnan(v) if (name in _NULLABLE_OBS and v.dtype.kind == "f") else None
            vals = v if missing is None or not missing.any() else np.where(missing, 0.0, v)
            A[:, col] = _message_texts(vals, rel, (b',"' if col == 5 else b'],"') + orjson.dumps(name)[1:-1] + b'":[',
                                       b"]}\r" if f == last else b"")
            col += 1
            if name in _NULLABLE_OBS:
                pre = b'],"' + orjson.dumps(name + VALID_SUFFIX)[1:-1] + b'":['
                if missing is None or not missing.any():        # all true: the text of the row count
                    counts = np.diff(rel)
                    lut = np.empty(int(counts.max()) + 1, dtype=object)
                    for k in np.unique(counts).tolist():
                        lut[k] = pre + b",".join([b"true"] * k)
                    A[:, col] = lut[counts]
                else:
                    A[:, col] = _message_texts(~missing, rel, pre)
                col += 1
        row0[i] = n_rows - k0
        n_rows += m
        tabs.append(A)
    rows = np.array([row0[i] for i in ii.tolist()], dtype=np.int64) + kk
    A = np.concatenate(tabs)[rows] if len(tabs) > 1 else tabs[0][rows]
    every = np.arange(len(stamps) + 1)
    ns = np.array(stamps, dtype=object)
    A[:, 0] = _message_texts((ns // 1_000_000_000).tolist(), every, b'{"timestamp":{"sec":')
    A[:, 1] = _message_texts((ns % 1_000_000_000).tolist(), every, b',"nsec":')
    A[:, 2] = _message_texts(part_times, every, b'},"time_s":')
    return b"".join(A.ravel().tolist())


_ORJSON_NUMPY = frozenset("<f8 <i8 <i4 |b1 =f8 =i8 =i4".split())


def _message_texts(values, cuts: np.ndarray, prefix: bytes = b"", suffix: bytes = b"") -> list:
    """``prefix`` + the JSON text of each message's values without the brackets + ``suffix`` (message m:
    ``values[cuts[m]:cuts[m+1]]``, none empty; ``values`` a list or 1-D array): one orjson text of all the
    values (each value's text is the same alone or in a list, and a float64, int or bool array's the same as
    its list's), split at the commas between messages; a value holding a comma: each message on its own."""
    if isinstance(values, np.ndarray):
        values = values if values.dtype.str in _ORJSON_NUMPY and values.flags.c_contiguous else values.tolist()
    text = orjson.dumps(values, option=orjson.OPT_SERIALIZE_NUMPY)
    n = len(values)
    if b"\n" not in text and b"\n" not in prefix + suffix:
        if len(cuts) == n + 1:                                # a message per value: split at every comma
            if text.count(b",") == n - 1:
                return (prefix + text[1:-1].replace(b",", suffix + b"\n" + prefix) + suffix).split(b"\n")
        else:
            commas = np.flatnonzero(np.frombuffer(text, dtype=np.uint8) == ord(","))
            if commas.size == n - 1:
                b = bytearray(text)
                np.frombuffer(b, dtype=np.uint8)[commas[cuts[1:-1] - 1]] = ord("\n")
                body = bytes(b[1:-1])
                if prefix or suffix:
                    body = prefix + body.replace(b"\n", suffix + b"\n" + prefix) + suffix
                return body.split(b"\n")
    if isinstance(values, np.ndarray):
        values = values.tolist()
    return [prefix + orjson.dumps(values[i:j])[1:-1] + suffix for i, j in zip(cuts[:-1].tolist(), cuts[1:].tolist())]


def _obs_payload(p: tuple, a: int, b: int) -> dict:
    """The payload of the observation message of rows a … b−1 of a receiver (``p`` as in
    :func:`_write_obs_messages`), for :meth:`McapOut.write`."""
    n, _, _, cols, flag, clk = p
    payload = {"receiver": n, "epoch_flag": int(flag[a]),
               "clock_offset_s": None if not np.isfinite(clk[a]) else float(clk[a])}
    payload.update({c: (_nullable(v[a:b]) if c in _NULLABLE_OBS else v[a:b].tolist()) for c, v in cols.items()})
    return payload


# ----------------------------------------------------------------------------------------------
# reading back


def is_gnss_run(contents) -> bool:
    """Whether MCAP contents (:func:`~cdgps_cli.io.mcap.read_mcap`) are a GNSS RUN
    (:func:`cdgps_cli.io.run.contents_kind`)."""
    return contents_kind(contents) == "gnss"


SOLVER_COLUMNS = tuple(c for c in RAW_COLUMNS if c not in ("doppler_hz", "sub_half", "cp_std_cycles", "pr_std_m",
                                                              "clock_reset"))
"""The raw columns ``init`` and ``estimate`` read (:func:`cdgps_cli.pipeline.gnss_ingest.processing_obs`,
``anchor_obs``, the epoch and clock checks): :func:`read_gnss_run` ``columns=`` leaves the others
(≈ 33 MiB per receiver of a day at 1 Hz) undecoded."""


def read_gnss_run(path: str | Path, contents=None, columns=None, window=None, window_s=None) -> GnssRun:
    """Read a GNSS RUN.mcap written by :func:`ingest_gnss` (CRCs validated; attachments only).

    ``columns``: the receivers' raw tables hold only these of :data:`RAW_COLUMNS` (e.g.
    :data:`SOLVER_COLUMNS`; the time, satellite and what a stage reads), None: all.  ``window`` (t0, t1), GPS s:
    the receivers' tables hold only the rows with t0 ≤ time_gps_s < t1, decoded from the archive blocks that
    overlap it (:mod:`cdgps_cli.io.gnss_archive`); None: the whole record.  ``window_s`` (start_s, duration_s):
    the same, from start_s seconds after the record's first epoch (its earliest time tag of any receiver; duration_s
    None: to the record's last epoch).  A window holding no observation of a receiver is refused, naming the
    receiver and its record's span."""
    c = contents if contents is not None else read_mcap(path, topics=[], attachments=_not_a_table)
    if not is_gnss_run(c):
        raise CdgpsError(f"{path}: not a GNSS RUN.mcap (no {RECEIVERS_ATTACHMENT}); is this a run from "
                         f"'cdgps ingest --rinex/--ubx'?")
    for k in (CONFIG_ATTACHMENT, RECEIVERS_ATTACHMENT):
        if k not in c.attachments:
            raise CdgpsError(f"{path}: no {k} attachment; is this a GNSS RUN.mcap from 'cdgps ingest'?")
    cfg = parse_gnss_config(c.attachments[CONFIG_ATTACHMENT].decode("utf-8"), f"{path}:{CONFIG_ATTACHMENT}")
    try:
        rx_json = json.loads(c.attachments[RECEIVERS_ATTACHMENT])
    except ValueError as exc:
        raise CdgpsError(f"{path}: damaged {RECEIVERS_ATTACHMENT}: {exc}") from None
    meta = c.require_metadata(INGEST_METADATA, "GNSS RUN.mcap from 'cdgps ingest'")
    if any(k.startswith("nav[") for k in meta) and EPHEMERIS_ATTACHMENT not in c.attachments:
        raise CdgpsError(f"{path}: no {EPHEMERIS_ATTACHMENT} attachment although the run was ingested with "
                         f"navigation files (damaged file)")
    named_master = meta.get("master") or cfg.master or (rx_json[0].get("name") if rx_json else None)
    record_last = None
    if window is not None or window_s is not None:
        window, record_last = _record_window(c, path, len(rx_json), cfg, window, window_s)
    receivers = {rj["name"]: _read_receiver(c, path, cfg, i, rj, columns, window, rj.get("name") == named_master)
                 for i, rj in enumerate(rx_json)}
    nav = _nav_table(c, path)
    master = meta.get("master") or cfg.master or next(iter(receivers))
    if master not in receivers:
        raise CdgpsError(f"{path}: the master {master!r} has no observations in the run")
    antex, antennas = _antennas(c, path, receivers)
    return GnssRun(str(path), cfg, master, receivers, nav, meta, antennas=antennas, antex=antex, window=window,
                   record_last_gps_s=record_last)


def antennas_json(antex, models: dict) -> bytes:
    """:data:`ANTENNAS_ATTACHMENT`'s bytes: the ANTEX file's name and each receiver's calibration (None: no model)."""
    return json.dumps({"antex": str(antex), "receivers": {n: None if m is None else model_to_json(m)
                                                          for n, m in models.items()}}, indent=1).encode()


def _antennas(c, path, receivers: dict) -> tuple:
    """(the ANTEX file's name, {receiver: AntennaModel or None}) of :data:`ANTENNAS_ATTACHMENT`; (None, {}) without
    it.  CdgpsError naming the attachment when it is damaged or names a receiver the run has not."""
    if ANTENNAS_ATTACHMENT not in c.attachments:
        return None, {}
    where = f"{path}: {ANTENNAS_ATTACHMENT}"
    try:
        doc = json.loads(c.attachments[ANTENNAS_ATTACHMENT])
        got = doc["receivers"]
        antex = str(doc["antex"])
    except (ValueError, KeyError, TypeError) as exc:
        raise CdgpsError(f"{where}: damaged ({type(exc).__name__}: {exc})") from None
    if not isinstance(got, dict) or set(got) - set(receivers):
        raise CdgpsError(f"{where}: damaged (expected a calibration or null per receiver of the run: "
                         f"{', '.join(receivers)})")
    return antex, {n: None if got.get(n) is None else model_from_json(got[n], f"{where}: {n}") for n in receivers}


def _read_receiver(c, path, cfg: GnssConfig, i: int, rj: dict, columns, window, master: bool) -> GnssReceiver:
    """Receiver ``i`` of a RUN's contents (``rj``: its entry of :data:`RECEIVERS_ATTACHMENT`), its tables read whole
    or in ``window`` (:func:`_receiver_rows`)."""
    key, skey = OBS_PREFIX.format(i), SIGNALS_PREFIX.format(i)
    if not gnss_archive.has_table(c, key):
        raise CdgpsError(f"{path}: no {key} attachments (observations of {rj.get('name')})")
    if cfg.signals and not gnss_archive.has_table(c, skey):
        raise CdgpsError(f"{path}: no {skey} attachments (signals of {rj.get('name')}) although the config lists signals")
    rows = None if window is None else _receiver_rows(window, master)
    raw = _raw_table(c, i, str(path), columns, rows)
    sig = _signal_table(c, i, str(path), rows) if cfg.signals else None
    if window is not None:
        anchor = anchor_signal(cfg.signals)
        if anchor is None or sig is None:          # the GPS L1 table anchors the epochs (or the only table)
            _check_window_rows(path, rj.get("name"), raw if sig is None or len(raw) else sig, window,
                               gnss_archive.table_span(c, key if len(raw) or sig is None else skey, str(path)))
        else:                                      # the first signal's rows anchor them (a run of other systems)
            _check_window_rows(path, rj.get("name"), sig[sig["signal"].to_numpy() == anchor], window,
                               gnss_archive.table_span(c, skey, str(path)))
    return GnssReceiver(rj["name"], rj["format"], rj["file"], rj["header"], raw,
                        dict(rj.get("info") or {}, position_source=rj.get("position_source"),
                             position_ecef_m=rj.get("position_ecef_m")), signals=sig)


def _nav_table(c, path) -> pd.DataFrame:
    """The RUN's ephemeris table (:data:`EPHEMERIS_ATTACHMENT`; no rows without one)."""
    nav = pd.DataFrame(columns=list(NAV_COLUMNS))
    if EPHEMERIS_ATTACHMENT not in c.attachments:
        return nav
    try:
        tab = json.loads(c.attachments[EPHEMERIS_ATTACHMENT])
        nav = pd.DataFrame({k: tab[k] for k in NAV_COLUMNS + (GLONASS_NAV_COLUMNS if "x_m" in tab else ())})
    except (ValueError, KeyError) as exc:
        raise CdgpsError(f"{path}: damaged {EPHEMERIS_ATTACHMENT}: {exc}") from None
    ints = ("iode", "codes_l2", "l2p_data_flag", "sv_health", "iodc", "week", "line")
    for col in ints:
        nav[col] = nav[col].fillna(-1).astype(np.int64)
    for col in [c for c in NAV_COLUMNS + GLONASS_NAV_COLUMNS if c in nav.columns]:
        if col not in ("sat", *ints):
            nav[col] = nav[col].astype(np.float64)
    return nav


def _record_window(c, path, n_receivers: int, cfg: GnssConfig, window, window_s) -> tuple:
    """(:attr:`GnssRun.window`, the record's last epoch GPS s or None): the window (and the master's margin,
    :func:`_receiver_rows`) of ``window`` (t0, t1) GPS s or ``window_s`` (start_s, duration_s or None: to the
    record's end) from the record's first epoch (the earliest of every receiver's tables, from their block indexes);
    CdgpsError for a window that is not one (naming the field)."""
    spans = [s for s in (gnss_archive.table_span(c, p.format(i), str(path)) for i in range(n_receivers)
                         for p in ((OBS_PREFIX, SIGNALS_PREFIX) if cfg.signals else (OBS_PREFIX,))) if s is not None]
    first = min((s[0] for s in spans), default=0.0)
    last = max((s[1] for s in spans), default=0.0)
    names, vals = (("start_s", "duration_s"), window_s) if window_s is not None else (("start_gps_s", "end_gps_s"), window)
    for k, v in zip(names, vals):
        if not (v is None and k == "duration_s") and not (isinstance(v, (int, float)) and math.isfinite(v)):
            raise CdgpsError(f"{path}: window {k}: expected a finite number of seconds, got {v!r}")
    if window_s is not None:
        start, duration = float(window_s[0]), window_s[1]
        if start < 0 or (duration is not None and duration <= 0):
            raise CdgpsError(f"{path}: window start_s {start:g}, duration_s {duration}: expected start_s ≥ 0 and "
                             f"duration_s > 0 (seconds from the record's first epoch)")
        if spans and start > last - first:
            raise CdgpsError(f"{path}: window start_s {start:g}: past the record's end (the record: "
                             f"{gps_time_str(first)} – {gps_time_str(last)}, {last - first:g} s from its first epoch)")
        t0 = first + start
        t1 = t0 + float(duration) if duration is not None else max(math.nextafter(last, math.inf), t0 + 1e-3)
    else:
        t0, t1 = float(window[0]), float(window[1])
        if not t1 > t0:
            raise CdgpsError(f"{path}: window {t0!r} – {t1!r} GPS s: expected its end after its start")
    return ({"start_s": t0 - first, "duration_s": t1 - t0, "start_gps_s": t0, "end_gps_s": t1,
             "master_margin_s": float(cfg.max_age_s + cfg.sync_tol_s)}, (last if spans else None))


def _receiver_rows(window: dict, master: bool) -> tuple:
    """The time tags (t0, t1) GPS s a receiver's rows are read in: the window itself for a rover (its epochs decide,
    as in the epoch pairing), widened by ``master_margin_s`` (gnss.max_age_s + gnss.sync_tol_s) on each side for the
    master, so that every rover epoch of the window finds the master epochs it pairs with or is bridged across, as
    in the whole record (a master tagged 4 ms before the rover pairs its epoch before the window's start)."""
    m = window["master_margin_s"] if master else 0.0
    return window["start_gps_s"] - m, window["end_gps_s"] + m


class EmptyWindow(CdgpsError):
    """A window of a GNSS run that holds no observation of one of its receivers (:func:`read_gnss_run`)."""


def record_span(path: str | Path) -> tuple[float, float]:
    """(first, last) epoch of a GNSS run's record, GPS s: the earliest and latest time tag of every receiver's tables,
    from their block indexes (the observations are not decoded)."""
    c = read_mcap(path, topics=[], attachments=_not_a_table)
    if not is_gnss_run(c):
        raise CdgpsError(f"{path}: not a GNSS RUN.mcap (no {RECEIVERS_ATTACHMENT}); is this a run from "
                         f"'cdgps ingest --rinex/--ubx'?")
    cfg = parse_gnss_config(c.attachments[CONFIG_ATTACHMENT].decode("utf-8"), f"{path}:{CONFIG_ATTACHMENT}")
    n = len(json.loads(c.attachments[RECEIVERS_ATTACHMENT]))
    window, last = _record_window(c, path, n, cfg, None, (0.0, None))
    return float(window["start_gps_s"]), float(last if last is not None else window["start_gps_s"])


def _check_window_rows(path, name, tab: pd.DataFrame, window: dict, span) -> None:
    """:class:`EmptyWindow` when receiver ``name``'s table read in ``window`` has no row (naming its record's span)."""
    if len(tab):
        return
    rec = f"{gps_time_str(span[0])} – {gps_time_str(span[1])}" if span else "no observations"
    raise EmptyWindow(f"{path}: the window {gps_time_str(window['start_gps_s'])} – {gps_time_str(window['end_gps_s'])} "
                     f"({window['start_s']:g} s after the record's first epoch, {window['duration_s']:g} s long) holds "
                     f"no observation of {name} (its record: {rec})")


def _not_a_table(name: str) -> bool:
    """The attachments :func:`read_gnss_run` keeps in memory: all but the receivers' table blocks (read one at a
    time, :meth:`~cdgps_cli.io.mcap.McapContents.attachment`)."""
    return not (name.startswith(("gnss/obs/", "gnss/signals/")) and name.endswith(".npz.zst"))


def _pairing_info(pairing: dict | None) -> dict:
    """``common_epochs`` (rover → epochs used) and ``epoch_pairing`` (rover → the pairing summary:
    used, bridged, dropped with reasons) from rover → summary."""
    if pairing is None:
        return {"common_epochs": None, "epoch_pairing": None}
    return {"common_epochs": {n: int(p["used"]) for n, p in pairing.items()}, "epoch_pairing": pairing}


def gnss_run_info(path: str | Path, contents, common_epochs=None, lock_summary=None) -> dict:
    """The GNSS part of ``cdgps info`` (:func:`gnss_info`) of a run decoded.

    ``common_epochs``: a function of the :class:`GnssRun` giving rover → its epoch pairing with the
    master (a summary with ``used``, ``bridged``, ``dropped`` …); ``lock_summary``: a function of a :class:`GnssReceiver` and the run's
    signals giving its lock counters per satellite (:func:`cdgps_cli.pipeline.gnss_ingest.run_info` passes both: epoch
    alignment and the lock-segment rule are model computations); None: recorded as None / {}."""
    run = read_gnss_run(path, contents)
    locks = {n: lock_summary(r, run.cfg.signals) for n, r in run.receivers.items()} if lock_summary else {}
    positions = {n: (r.info.get("position_source"), r.info.get("position_ecef_m")) for n, r in run.receivers.items()}
    info = gnss_info(run.cfg, run.master, run.receivers, run.nav, common_epochs(run) if common_epochs else None,
                     locks, positions, antennas_info(run.antex, run.antennas) if run.antex is not None else None)
    # JSON-safe as the record ingest wrote (NaN -> null: the interval of a one-epoch receiver), so that info from
    # the record and info --deep print the same
    return {"config": info["config"], **json.loads(gnss_info_json(info))}


def antennas_info(antex, models: dict) -> dict:
    """What ``info``, INIT, STATES and ``baseline`` say of the antenna calibrations used: ``antex`` the ANTEX file
    and ``receivers`` {receiver: its antenna type and radome as that file writes them, None: no model}."""
    return {"antex": str(antex), "receivers": {n: None if m is None else " ".join(m.name.split())
                                               for n, m in models.items()}}


def gnss_info(cfg: GnssConfig, master: str, receivers: dict, nav, pairing: dict | None, locks: dict,
              positions: dict, antennas: dict | None = None) -> dict:
    """The GNSS part of ``cdgps info``: config, master, receivers with lock counters (``locks``: name → per satellite),
    epoch pairing (``pairing``: rover → its summary, or None), ephemerides.  ``ingest`` writes it into the RUN
    (:data:`GNSS_INFO_ATTACHMENT`), from which ``info`` answers without decoding the observations; ``info --deep``
    computes it again from the decoded run and refuses a file whose record differs.  ``antennas``: the run's antenna
    calibrations (:func:`antennas_info`), None: none (the key is then left out)."""
    rx = []
    for n, r in receivers.items():
        lock = locks.get(n, {})
        s = _receiver_summary(n, r, lock, positions[n])
        s["lock"] = lock
        s["epochs_time_system"] = r.header.get("epochs_time_system")     # a file's epochs in BDT or GLONASS time
        s["beidou_b1i_band1"] = r.header.get("beidou_b1i_band1")         # a RINEX 3.02 file's B1I types, renamed
        if r.format == "ubx":
            s["integrity"] = {**{k: int(r.info.get(k) or 0) for k in INTEGRITY_COUNTS},
                              "problems": integrity_problems(r.info)}
        rx.append(s)
    rovers = [n for n in receivers if n != master]
    has_nav = nav is not None and len(nav) > 0
    return {
        "config": cfg.summary(), "master": master, "rovers": rovers,
        "coordinates": [f"{r}_{c}" for r in rovers for c in "enu"],
        "receivers": rx, **_pairing_info(pairing),
        "ephemerides": int(len(nav)) if has_nav else 0, "ephemeris_satellites": int(nav["sat"].nunique()) if has_nav else 0,
        "ephemeris_toe": [gps_time_str(float(nav["toe_gps_s"].min())), gps_time_str(float(nav["toe_gps_s"].max()))]
        if has_nav else None,
        **({"antennas": antennas} if antennas is not None else {}),
    }


def gnss_info_json(info: dict) -> bytes:
    """The bytes of :data:`GNSS_INFO_ATTACHMENT`: :func:`gnss_info` as JSON, its ``config`` left out (the config's
    summary names the path it is read from: ``info`` reads it from the run's config attachment)."""
    return json.dumps(_json_safe({k: v for k, v in info.items() if k != "config"})).encode()


# ----------------------------------------------------------------------------------------------
# starter configs from the files' headers


def _disjoint_spans_notes(master: str, receivers: dict, paths: dict, comments: list, warnings: list | None) -> None:
    """A warning and a comment for each rover whose record shares no time with the master's (two logs of different
    days: ``ingest`` refuses the pair, "no common epochs"); receivers given as glob patterns are not judged from the
    first file read here."""
    from cdgps_cli.io.log_sequence import is_pattern  # noqa: PLC0415
    from cdgps_cli.config.options import EPOCH_PAIRING_DEFAULTS  # noqa: PLC0415

    def span(n):
        return None if is_pattern(str(paths[n])) else time_span(receivers[n].raw["time_gps_s"].to_numpy(dtype=np.float64))

    age = float(EPOCH_PAIRING_DEFAULTS["max_age_s"])
    m = span(master)
    for n in receivers:
        r = span(n) if n != master else None
        if m is None or r is None or spans_meet(m, r, age):
            continue
        said = (f"{paths[n]} ({n}) spans {gps_time_str(r[0])} – {gps_time_str(r[1])} and the master {paths[master]} "
                f"{gps_time_str(m[0])} – {gps_time_str(m[1])}: no common epochs; 'cdgps ingest' refuses the pair")
        comments.append(f"    {n}: NO EPOCH IN COMMON with the master {master} (its span: {gps_time_str(r[0])} – "
                        f"{gps_time_str(r[1])})")
        if warnings is not None:
            warnings.append(said)


def _first_file(p, what: str):
    """The file a starter config reads the header of: ``p``, or the first (by name) of the files a quoted glob
    pattern names (the config keeps the pattern: ``ingest`` joins the files in time order)."""
    from cdgps_cli.io.log_sequence import is_pattern  # noqa: PLC0415

    return expand_paths([str(p)], what)[0] if is_pattern(str(p)) else p


def _pattern_comment(p, what: str, comments: list) -> None:
    """A starter config's comment line saying that antenna file ``p`` is a quoted glob pattern: how many files it
    matches, the header described above being the first's (``ingest`` joins them all)."""
    from cdgps_cli.io.log_sequence import is_pattern  # noqa: PLC0415

    if is_pattern(str(p)):
        n = len(expand_paths([str(p)], what))
        comments.append(f"    the first of {n} files matching {p!r} (ingest joins them in time order into one record)")


def _rinex_comments(n: str, p, comments: list) -> GnssReceiver:
    """A starter config's comment lines on antenna ``n``'s RINEX file ``p`` (marker, receiver, antenna, span, header
    position); returns the file read (GPS L1)."""
    rx = read_receiver_file(n, "rinex", p, gps_l1_optional=True)       # (a file of other systems: the run's signals say)
    h = rx.header
    t = np.unique(rx.raw["time_gps_s"].to_numpy())
    if t.size == 0:                                   # no GPS L1 phase: the epochs of the signals the file holds
        from cdgps_cli.io.rinex_signals import read_rinex_signals, signals_in_file  # noqa: PLC0415
        sigs = [s for s in signals_in_file(p) if not s.startswith("R:")]    # (GLONASS slots may be the nav's only)
        try:
            t = np.unique(read_rinex_signals(p, sigs)[1]["time_gps_s"].to_numpy()) if sigs else t
        except CdgpsError:
            pass
    pos = header_position_m(h)
    span = f"{t.size} epochs {span_text(t)} sampled every {sampling_interval_s(t):g} s" if t.size else "epochs: see ingest"
    comments.append(f"{n}: {Path(p).name}, RINEX {float(h.get('version') or 0):.2f}, marker {h.get('marker_name') or '?'}, receiver "
                    f"{h.get('receiver_type') or '?'}, antenna {h.get('antenna_type') or '?'}, {span},")
    comments.append(f"    header position {('(' + ', '.join(f'{v:.4f}' for v in pos) + ')') if pos is not None else 'none'}")
    return rx


def _ubx_comments(n: str, p, comments: list, warnings: list | None):
    """A starter config's comment lines on antenna ``n``'s u-blox log ``p`` (span, satellites, SFRBX ephemerides,
    RTCM 1005/1006 position); what the log lost into ``warnings``.  Returns the log read."""
    rx = read_receiver_file(n, "ubx", p)
    lost = ubx_loss_warning(n, {"file": str(p), "n_frames": int(rx.info.get("n_frames") or 0),
                                "problems": integrity_problems(rx.info)})
    if lost and warnings is not None:
        warnings.append(lost)
    t = np.unique(rx.raw["time_gps_s"].to_numpy())
    base = rx.info.get("rtcm_base")
    sf = rx.info.get("sfrbx") or {}
    comments.append(f"{n}: {Path(p).name}, u-blox RXM-RAWX, {t.size} epochs {span_text(t)}, GPS satellites "
                    f"{', '.join(rx.info.get('gps_satellites') or [])}; {int(sf.get('ephemerides') or 0)} broadcast "
                    f"ephemerides from RXM-SFRBX")
    if base:
        extra = f", {base['distinct']} distinct positions in {base['count']} messages: the last is used" \
            if base["distinct"] > 1 else ""
        comments.append(f"    position: RTCM {base['message']} antenna reference point of station "
                        f"{base['station_id']} ({', '.join(f'{v:.4f}' for v in base['arp_ecef_m'])}){extra}")
    return rx


def _master_header_comments(found, master: str, comments: list, warnings: list | None) -> None:
    """A master header check's (warning, comment) ``found`` (None: nothing to say) into a starter config's comments
    and warnings."""
    if not found:
        return
    import textwrap  # noqa: PLC0415
    comments += textwrap.wrap(f"{master} position: CHECK IT — {found[1]}", 112, initial_indent="    ",
                              subsequent_indent="      ")
    if warnings is not None:
        warnings.append(found[0])




def _nav_day_note(path, toe_s: np.ndarray, receivers: dict, comments: list, warnings: list | None) -> None:
    """A starter config's warning (and comment) when navigation file ``path`` covers none of the receivers'
    observations (its ephemerides' toe ± :data:`MAX_EPHEMERIS_AGE_S`): a file of another day, which ``ingest`` and
    ``rtk`` refuse; ``config`` said nothing of it."""
    spans = [(float(t.min()), float(t.max())) for t in (rx.raw["time_gps_s"].to_numpy(dtype=float)
                                                        for rx in receivers.values()) if t.size]
    if not toe_s.size or not spans:
        return
    lo, hi = float(np.min(toe_s)) - MAX_EPHEMERIS_AGE_S, float(np.max(toe_s)) + MAX_EPHEMERIS_AGE_S
    if any(a <= hi and b >= lo for a, b in spans):
        return
    first, last = min(a for a, _ in spans), max(b for _, b in spans)
    said = (f"{path}: its ephemerides (toe {span_text(toe_s)}) cover none of the observations ({gps_time_str(first)} – "
            f"{gps_time_str(last)}): a navigation file of another day, which 'cdgps ingest' and 'cdgps rtk' refuse; "
            f"give the navigation file of the observations' day")
    comments.append(f"    {said}")
    if warnings is not None:
        warnings.append(said)


def _nav_comments(nav_paths, receivers: dict, comments: list, warnings: list | None) -> None:
    """A starter config's comment line on each navigation file (its ephemerides per system, their toe span), and
    :func:`_nav_day_note`'s warning when it covers none of the ``receivers``' observations."""
    from cdgps_cli.io.rinex import NAV_SYSTEMS  # noqa: PLC0415

    for p in nav_paths:
        nav = read_rinex_nav(p, systems=NAV_SYSTEMS)
        per = nav["sat"].astype(str).str[0].value_counts()
        what = ", ".join(f"{int(per[c])} {system_list(c)}" for c in NAV_SYSTEMS if c in per) or "no"
        comments.append(f"nav {Path(p).name}: {what} ephemerides of {nav['sat'].nunique()} satellites, toe "
                        f"{span_text(nav['toe_gps_s'])}")
        _nav_day_note(p, nav["toe_gps_s"].to_numpy(dtype=float), receivers, comments, warnings)


def _receiver_positions(paths: dict, receivers: dict, master: str, positions: dict, nav_paths,
                        receiver_position=None) -> dict:
    """Where ``init`` places each antenna (ECEF m, or None): the master's configured position (RTCM, single-point)
    or header; each other receiver's by ``receiver_position(name, path, receiver, nav_paths)`` (a header far off
    its single-point position replaced by it), else its header's."""
    where = {n: (receiver_position(n, paths[n], rx, nav_paths) if receiver_position is not None
                 else header_position_m(rx.header)) for n, rx in receivers.items() if n != master}
    where[master] = positions.get(master, header_position_m(receivers[master].header) if master in receivers else None)
    return where


def _long_baseline_notes(master: str, positions: dict, comments: list, warnings: list | None) -> None:
    """A starter config's warning (and comment) for each rover whose position lies at or beyond
    ``gnss.iono_threshold_km`` from the master's (their headers' or RTCM positions): ``init`` refuses such a baseline
    (its static solution neglects the DD ionosphere and the wet delays), ``rtk`` estimates them."""
    from cdgps_cli.config.options import GNSS_DEFAULTS  # noqa: PLC0415

    limit_km = float(GNSS_DEFAULTS["iono_threshold_km"])
    xm = positions.get(master)
    if xm is None:
        return
    for n, x in positions.items():
        if n == master or x is None:
            continue
        km = float(np.linalg.norm(np.subtract(x, xm))) / 1e3
        if km >= limit_km:
            said = (f"{n}: {km:.1f} km from {master} (where init places them: the files' positions, a header off by "
                    f"more than a kilometre replaced by the single-point position), at or above gnss.iono_threshold_km "
                    f"= {limit_km:g} km: 'cdgps init' and 'cdgps baseline' refuse this baseline (their static solution "
                    f"neglects the DD ionosphere and the wet delays); 'cdgps rtk' estimates them")
            comments.append(f"    {said}")
            if warnings is not None:
                warnings.append(said)


def starter_gnss_config(rinex: dict, ubx: dict | None = None, nav_paths=(), master: str | None = None, *,
                        displacement: str = "static", sigma_m_per_sqrt_s=None, relative_to: Path | None = None,
                        name: str | None = None, notes: list | None = None, warnings: list | None = None,
                        master_position=None, master_header_check=None, receiver_position=None, signals=None) -> str:
    """Text of a GNSS run config for the given files; the headers are read and summarised in
    comments (marker, receiver, antenna, span, header position); ``signals`` (names) become ``[gnss] signals``
    unless they are GPS L1 alone (the GPS L1 path, no key).  The master defaults to a UBX log with an RTCM
    1005/1006 station position (a receiver that broadcasts its position is a base station), else the first RINEX
    antenna with a header position (said in ``notes``);
    paths are written relative to ``relative_to``.  A UBX master's ``position_ecef_m`` is the
    RTCM 1005/1006 antenna reference point, else the mean single-point position (said in the
    comments and appended to ``notes``).  A UBX log that lost data (bad checksums, skipped bytes, a cut
    frame) is named in ``warnings`` as ``ingest`` names it.  ``master_header_check(name, path, receiver, nav_paths)``:
    a RINEX master's header position checked against its data ((a warning, a comment), or None), said in
    ``warnings`` and in the comments.  The text is parsed back and its positions checked."""
    ubx = ubx or {}
    if not rinex and not ubx:
        raise CdgpsError("give at least one receiver file (--rinex/--ubx ANTENNA=FILE)")
    both = set(rinex) & set(ubx)
    if both:
        raise CdgpsError(f"antenna(s) {', '.join(sorted(both))} given both as --rinex and --ubx")
    if warnings is not None:
        warnings += one_file_for_two_receivers({f"--{k} {n}": expand_paths([str(p)], f"--{k} {n}")
                                                for k, d in (("rinex", rinex), ("ubx", ubx)) for n, p in d.items()})

    def rel(p):
        return path_for_config(p, relative_to)

    comments = ["GNSS run config (format: docs/gnss-pipeline.md), written by 'cdgps config' from the files' headers.",
                "Run:  cdgps ingest --config THIS_FILE -o run.mcap && cdgps init run.mcap -o init.json &&",
                "      cdgps estimate run.mcap --init init.json -o states.mcap && cdgps export states.mcap -o states.csv", ""]
    files = {}
    with_pos = []
    rinex_rx = {}
    for n, p in rinex.items():
        rinex_rx[n] = _rinex_comments(n, _first_file(p, f"--rinex {n}"), comments)
        _pattern_comment(p, f"--rinex {n}", comments)
        if header_position_m(rinex_rx[n].header) is not None:
            with_pos.append(n)
        files[n] = ("rinex", rel(p))
    positions: dict = {}
    ubx_rx = {}
    for n, p in ubx.items():
        ubx_rx[n] = _ubx_comments(n, _first_file(p, f"--ubx {n}"), comments, warnings)
        _pattern_comment(p, f"--ubx {n}", comments)
        base = ubx_rx[n].info.get("rtcm_base")
        if base:
            positions[n] = tuple(base["arp_ecef_m"])
            with_pos.append(n)
        files[n] = ("ubx", rel(p))
    _nav_comments(nav_paths, rinex_rx | ubx_rx, comments, warnings)
    rtcm = [n for n in ubx_rx if n in positions]          # a log with RTCM 1005/1006: a base station by its role
    chosen = rtcm[0] if rtcm else (with_pos[0] if with_pos else next(iter(files)))
    if master is None and notes is not None and len(files) > 1:
        why = ("its log broadcasts its position (RTCM 1005/1006): a base station" if chosen in rtcm else
               "the first RINEX file with a header position" if chosen in with_pos else "the first receiver given")
        notes.append(f"master {chosen}: {why}; give --master to choose another")
    master = master or chosen
    if master not in files:
        raise CdgpsError(f"master {master!r} is not one of the receivers given: {', '.join(files)}")
    if master in ubx_rx and master not in positions:
        if master_position is None:
            raise CdgpsError(f"{ubx[master]}: no base position for master {master}: the log has no RTCM 1005/1006 "
                             f"message; write position_ecef_m in the config yourself")
        positions[master] = master_position(master, ubx[master], ubx_rx[master], nav_paths, ubx_rx)
        comments.append(f"    {master} position: NOT surveyed — the log has no RTCM 1005/1006; the mean single-point "
                        f"position from its L1 pseudoranges (metre level). Replace it by the surveyed position.")
        if notes is not None:
            notes.append(f"{master} ({Path(ubx[master]).name}): no RTCM 1005/1006 base position in the log; "
                         f"position_ecef_m is the mean single-point position (metre level), not a surveyed one")
    if master in rinex_rx and master not in with_pos:
        said = (f"{rinex[master]}: master {master} has no position (no usable APPROX POSITION XYZ in its header): write "
                f"its surveyed position_ecef_m in the config before 'cdgps ingest', which refuses a master without one")
        comments.append(f"    {master} position: NONE — write position_ecef_m below")
        if warnings is not None:
            warnings.append(said)
    _disjoint_spans_notes(master, rinex_rx | ubx_rx, {n: p for n, p in (rinex | ubx).items()}, comments, warnings)
    header_off = None
    if master in rinex_rx and master in with_pos and master_header_check is not None:
        header_off = master_header_check(master, rinex[master], rinex_rx[master], nav_paths)
        _master_header_comments(header_off, master, comments, warnings)
    if not header_off:                  # (a master header known to be off says nothing of the baselines' lengths)
        where = _receiver_positions(rinex | ubx, rinex_rx | ubx_rx, master, positions, nav_paths, receiver_position)
        _long_baseline_notes(master, where, comments, warnings)
    sig = list(signals or ())
    text = gnss_config_toml(files, [rel(p) for p in nav_paths], master, name=name or "-".join(files),
                            displacement=displacement, sigma_m_per_sqrt_s=sigma_m_per_sqrt_s, comments=comments,
                            positions=positions or None,
                            options={"signals": sig} if sig and sig != ["G:L1"] else None,
                            antenna_types={n: header_antenna_type(rx.header) for n, rx in rinex_rx.items()})
    cfg = parse_gnss_config(text, "<starter config>")         # it must load, and say what was written
    for n, pos in positions.items():
        back = cfg.antenna(n).position_ecef_m
        if back is None or max(abs(a - b) for a, b in zip(back, pos)) > 5e-5:
            raise CdgpsError(f"internal error: the starter config does not read back {n}'s position {pos} (got {back})")
    return text
