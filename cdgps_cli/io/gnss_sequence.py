"""A receiver's consecutive RINEX files or UBX logs (hourly, daily) read as one :class:`GnssReceiver`.

Each file is read and checked by its reader (errors name the file and line / byte); the files are
then checked to be of one receiver (:func:`check_same_receiver`) and joined in time order by
:func:`cdgps_cli.io.log_sequence.join_tables` (repeated epochs kept once, gaps reported).  Times
are GPS seconds since 1980-01-06 (RINEX calendar dates and UBX week + time of week alike), so a
day boundary or a GPS week rollover between (or inside) the files is continuous.

What must agree between the files, and why (a mismatch is a CdgpsError naming the file and both
values): the RINEX ``receiver_type``, ``marker_name`` and ``antenna_type`` (another receiver,
site or antenna is not the same record: other clock, biases and phase centre), the L1 observation
codes ingested (``l1_obs_types``: another tracking mode of L1 has another phase bias), and the
epoch interval of every file with two epochs or more (the lock-segment rule and the gap report
use one interval per record).  What may differ, with a warning: the RINEX version, the other
observation types (not ingested; with ``[gnss] signals`` every file is checked to have them), the
header's approximate position (the first file's is used).
"""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_time_str, sampling_interval_s
from cdgps_cli.io.log_sequence import join_tables

__all__ = ["check_same_receiver", "refuse_another_receiver", "join_receivers", "pieces_text", "join_signal_tables", "ubx_bytes",
           "ubx_sequence_ephemerides", "merge_systems", "merge_signal_tables", "refuse_spans_apart",
           "systems_merged_text"]

_MUST_AGREE = ("receiver_type", "marker_name", "antenna_type", "l1_obs_types")
_MAY_DIFFER = ("version", "obs_types", "approx_position_xyz_m")
"""Header fields that may differ between a record's files (a warning; the first file's are kept,
but a UBX record's position is that of its last RTCM 1005/1006 message)."""
_SUMMED = ("n_epochs", "n_epochs_power_failure", "n_gps_epochs", "n_frames", "bad_checksum_frames",
           "undecodable_frames", "skipped_bytes", "truncated_tail_bytes", "nmea_bytes", "nmea_sentences",
           "rtcm_bytes", "bad_crc_rtcm_frames", "n_clock_resets")


def pieces_text(paths) -> str:
    """A receiver's files for the messages: the file, or ``first … last (N files)``."""
    paths = [str(p) for p in paths]
    return paths[0] if len(paths) == 1 else f"{paths[0]} … {paths[-1]} ({len(paths)} files)"


def _interval(rx) -> float:
    return sampling_interval_s(rx.raw["time_gps_s"].to_numpy())


def check_same_receiver(name: str, rxs: list, paths: list) -> list[str]:
    """Refuse files of ``name`` that are not of one receiver; the warnings for harmless differences.

    Parameters
    ----------
    name : str
        The antenna.
    rxs : list of GnssReceiver
        One per file, in time order.
    paths : list of str
        The files, in the same order.

    Raises
    ------
    CdgpsError
        The file, what differs and both values (see the module docstring for what must agree).
    """
    first, p0 = rxs[0], paths[0]
    warnings = []
    dts = [_interval(rx) for rx in rxs]
    i0 = next((i for i, d in enumerate(dts) if math.isfinite(d)), None)
    dt0, p_dt0 = (math.nan, p0) if i0 is None else (dts[i0], paths[i0])
    refuse_another_receiver(name, [rx.header for rx in rxs], paths)
    for rx, p, dt in zip(rxs[1:], paths[1:], dts[1:]):
        if math.isfinite(dt) and math.isfinite(dt0) and abs(dt - dt0) > 1e-6 * max(dt0, 1.0):
            raise CdgpsError(f"{p} ({name}): epoch interval {dt:g} s differs from {dt0:g} s in {p_dt0}; the files of one "
                             f"record must have one rate (resample them to one interval first)")
        diff = [k for k in _MAY_DIFFER if first.header.get(k) != rx.header.get(k)]
        if diff:
            warnings.append(f"{name}: {p} differs from {p0} in {', '.join(diff)} (not used: the first file's header "
                            f"is kept)")
    return warnings


def refuse_another_receiver(name: str, headers: list, paths: list, fields=_MUST_AGREE) -> None:
    """CdgpsError when the headers of a receiver's files (in time order, ``paths`` alike) differ in one of
    ``fields`` (default: the receiver, marker, antenna and L1 observation codes): another receiver, site or
    antenna, or another tracking mode of a signal, is not one record."""
    h0, p0 = headers[0], paths[0]
    for h, p in zip(headers[1:], paths[1:]):
        for k in fields:
            a, b = h0.get(k), h.get(k)
            if a != b:
                raise CdgpsError(f"{p} ({name}): {k} {b!r} differs from {a!r} in {p0}; the files of one antenna must be "
                                 f"one receiver's record (same receiver, marker, antenna and observation codes)")


def _merged_info(infos: list[dict], reps: dict) -> dict:
    """The read summary of the joined record: the first file's, counters summed over the files,
    satellite lists united, and ``files`` (each file's name, span and counters)."""
    out = dict(infos[0])
    for k in _SUMMED:
        if any(k in i for i in infos):
            out[k] = int(sum(int(i.get(k) or 0) for i in infos))
    for k in ("gps_satellites",):
        if any(k in i for i in infos):
            out[k] = sorted(set().union(*[set(i.get(k) or []) for i in infos]))
    for k in ("message_counts", "signal_counts"):
        if any(k in i for i in infos):
            tot: dict = {}
            for i in infos:
                for m, c in (i.get(k) or {}).items():
                    tot[m] = tot.get(m, 0) + int(c)
            out[k] = dict(sorted(tot.items()))
    bases = [i.get("rtcm_base") for i in infos if i.get("rtcm_base")]
    if "rtcm_base" in out:
        out["rtcm_base"] = bases[-1] if bases else None
    out.update(reps)
    return out


def join_receivers(name: str, rxs: list, paths: list, ubx_nav=None) -> tuple:
    """One :class:`~cdgps_cli.io.gnss_run.GnssReceiver` of a receiver's consecutive files.

    Parameters
    ----------
    name : str
        The antenna.
    rxs : list of GnssReceiver
        One per file (as read, any order).
    paths : list of str
        The files, in the order of ``rxs``.
    ubx_nav : callable, optional
        A UBX record's (ephemerides, decoder counters) from the files in time order (``ubx_nav(order)``, the
        files' indices in time order), when its RXM-SFRBX frames are already at hand (a record read hour by
        hour, :mod:`cdgps_cli.io.gnss_hours`); default: :func:`ubx_sequence_ephemerides` frames the files again.

    Returns
    -------
    receiver : GnssReceiver
        The joined record: the raw tables in time order (an epoch repeated by a later file kept
        from the earlier file only), the first file's header with the summed epoch counts, the
        read summaries merged (``info["files"]``: per file its name, span, epochs; ``info["join"]``:
        the gaps and overlaps between files); a UBX record's ephemerides decoded from the RXM-SFRBX
        subframes of all its files in time order (:func:`ubx_sequence_ephemerides`).
    join : dict
        ``files``, ``gaps``, ``overlaps`` (:class:`~cdgps_cli.io.log_sequence.JoinReport`), times in GPS s.
    warnings : list of str
    order : list of int
        The files' indices in time order.
    """
    pieces = [(Path(p).name if len({Path(q).name for q in paths}) == len(paths) else str(p), rx.raw)
              for p, rx in zip(paths, rxs)]
    t_all = np.concatenate([rx.raw["time_gps_s"].to_numpy(dtype=np.float64) for rx in rxs])
    raw, rep, order = join_tables(pieces, "time_gps_s", sampling_interval_s(t_all), gps_time_str, what=name)
    rxs_o, paths_o = [rxs[i] for i in order], [str(paths[i]) for i in order]
    warnings = check_same_receiver(name, rxs_o, paths_o) + rep.warnings
    rx0 = rxs_o[0]
    header = dict(rx0.header)
    repeated = sum(o["epochs"] for o in rep.overlaps)
    for k in ("n_epochs", "n_gps_epochs", "n_epochs_power_failure"):
        if k in header:
            header[k] = int(sum(int(r.header.get(k) or 0) for r in rxs_o)) - (repeated if k != "n_epochs_power_failure" else 0)
    if "time_last_obs_gps_s" in header:
        header["time_last_obs_gps_s"] = rxs_o[-1].header.get("time_last_obs_gps_s")
    if rx0.format == "ubx":
        header["interval_s"] = sampling_interval_s(raw["time_gps_s"].to_numpy())
        base = next((r.info["rtcm_base"] for r in reversed(rxs_o) if r.info.get("rtcm_base")), None)
        if base:            # the station position of the last RTCM 1005/1006, as for one log
            header["approx_position_xyz_m"] = list(base["arp_ecef_m"])
            header["position_source"] = f"RTCM {base['message']} ARP (station {base['station_id']})"
    header["files"] = [Path(p).name for p in paths_o]
    join = rep.as_dict()
    info = _merged_info([r.info for r in rxs_o], {"files": join["files"], "join": {"gaps": join["gaps"],
                                                                                  "overlaps": join["overlaps"]}})
    for k in ("n_epochs", "n_gps_epochs"):
        if k in info:
            info[k] = header[k] if k in header else info[k] - repeated
    if rx0.format == "ubx":
        from cdgps_cli.io.ubx import integrity_problems  # noqa: PLC0415

        for f, r in zip(info["files"], rxs_o):
            f["problems"] = integrity_problems(r.info)
            f["truncated_tail_bytes"] = int(r.info.get("truncated_tail_bytes") or 0)
        for k in ("bad_frame_offsets", "undecodable_frame_offsets", "bad_rtcm_offsets"):
            info[k] = []                    # byte offsets are per file: see info["files"][i]["problems"]
    nav = None
    if rx0.format == "ubx":
        nav, info["sfrbx"] = (ubx_sequence_ephemerides(paths_o, rx0.info.get("week")) if ubx_nav is None
                              else ubx_nav(order))
    out = type(rx0)(rx0.name, rx0.format, pieces_text([Path(p).name for p in paths_o]), header, raw, info, nav)
    return out, join, warnings, order


def merge_systems(name: str, rxs: list, paths: list, split: list) -> tuple:
    """One :class:`~cdgps_cli.io.gnss_run.GnssReceiver` of a receiver's RINEX files that hold its systems side by side
    (a file per system, as gnss-sdr writes them: ``split``, each file's signals,
    :func:`~cdgps_cli.io.rinex_signals.signals_by_file`): the raw tables' rows merged epoch by epoch (in time order,
    the files' order within an epoch), the header of the first file with rows in its raw (GPS L1) table (else the first), its epoch count
    that of the union; ``info["signals_by_file"]`` keeps ``split`` for the signal tables.  Returns (receiver, join
    record, warnings).  CdgpsError when their spans do not meet or they are not of one receiver."""
    refuse_spans_apart(name, paths, split, [rx.raw["time_gps_s"].to_numpy() for rx in rxs])
    refuse_another_receiver(name, [rx.header for rx in rxs], paths, ("marker_name", "receiver_type", "antenna_type"))
    raw = pd.concat([rx.raw for rx in rxs], ignore_index=True)
    raw = raw.iloc[np.argsort(raw["time_gps_s"].to_numpy(), kind="stable")].reset_index(drop=True)
    lead = next((i for i, rx in enumerate(rxs) if len(rx.raw)), 0)
    rx0 = rxs[lead]
    header = dict(rx0.header)
    header["files"] = [Path(p).name for p in paths]
    if "n_epochs" in header:
        header["n_epochs"] = int(np.unique(raw["time_gps_s"].to_numpy()).size)
    info = _merged_info([rx0.info, *[r.info for i, r in enumerate(rxs) if i != lead]],
                        {"files": [{"file": Path(p).name, "signals": list(sub)} for p, sub in zip(paths, split)],
                         "join": {"gaps": [], "overlaps": []}})
    info["signals_by_file"] = [list(sub) for sub in split]
    said = [systems_merged_text(name, paths, split)]
    out = type(rx0)(rx0.name, rx0.format, pieces_text([Path(p).name for p in paths]), header, raw, info, None)
    return out, {"files": info["files"], "gaps": [], "overlaps": []}, said


def refuse_spans_apart(name: str, paths: list, split: list, times: list) -> None:
    """CdgpsError when a receiver's files of one system each (``split``: each file's signals) do not cover one span
    (``times``: each file's epoch times, GPS s; a file without any counts for none): such files are written over the
    same time."""
    spans = [(float(np.min(t)), float(np.max(t))) for t in times if len(t)]
    if spans and max(a for a, _ in spans) > min(b for _, b in spans):
        raise CdgpsError(f"{pieces_text(paths)} ({name}): each file holds other systems ("
                         + "; ".join(f"{Path(p).name}: {', '.join(sub)}" for p, sub in zip(paths, split))
                         + ") but their spans do not meet: a receiver's files of one system each cover the same time")


def systems_merged_text(name: str, paths: list, split: list) -> str:
    """The warning that a receiver's files of one system each (``split``: each file's signals) were merged."""
    return (f"{pieces_text([Path(p).name for p in paths])} ({name}): one receiver's systems in files of their own ("
            + "; ".join(f"{Path(p).name}: {', '.join(sub)}" for p, sub in zip(paths, split)) + "): merged epoch by epoch")


def merge_signal_tables(tables: list) -> pd.DataFrame:
    """The signal tables of a receiver's files of one system each (:func:`merge_systems`), merged epoch by epoch."""
    tab = pd.concat(tables, ignore_index=True)
    tab = tab.iloc[np.argsort(tab["time_gps_s"].to_numpy(), kind="stable")].reset_index(drop=True)
    tab.attrs = {}
    return tab


def ubx_sequence_ephemerides(paths, week_ref) -> tuple:
    """Ephemerides of the RXM-SFRBX subframes of consecutive UBX logs read as one stream (in the
    given order), so that an ephemeris whose subframes 1–3 straddle two files is decoded as from one
    log; (nav table, decoder counters) of :func:`cdgps_cli.io.sfrbx.sfrbx_ephemerides`.

    The files were read (and checked) by :func:`cdgps_cli.io.ubx.read_ubx_log` before; this frames
    them again (only the ephemeris decoding needs frames across the files' boundaries)."""
    from cdgps_cli.io.sfrbx import sfrbx_ephemerides  # noqa: PLC0415
    from cdgps_cli.io.ubx_frames import split_stream  # noqa: PLC0415

    frames = []
    for p in paths:
        frames.extend(split_stream(ubx_bytes(p))[0])
    return sfrbx_ephemerides(frames, week_ref, glonass=True)


def ubx_bytes(path) -> bytes:
    """A UBX log's bytes (gzip decompressed)."""
    data = Path(path).read_bytes()
    return gzip.decompress(data) if data[:2] == b"\x1f\x8b" else data


def join_signal_tables(name: str, tables: list, paths: list) -> pd.DataFrame:
    """The multi-signal tables of a receiver's files (in the files' time order) joined as the raw
    tables are: an epoch a later file repeats is taken from the earlier file."""
    tab, _, _ = join_tables([(str(p), t) for p, t in zip(paths, tables)], "time_gps_s", math.nan, gps_time_str, what=name)
    return tab
