"""Multi-GNSS, multi-frequency observations of a RINEX 2/3 file, one row per epoch, satellite and signal.

:func:`read_rinex_signals` returns a long table with a ``signal`` column (names of
:mod:`cdgps_cli.core.signals`): phase (cycles), pseudorange (m), LLI of the phase, and the wavelength
of that row (m, per satellite for GLONASS), for the signals asked for.  The observation codes used
for each signal are chosen per file from the header (the first attribute of the signal's preference
list the file has) and reported in ``header["signal_codes"]``.  The header parser is the one of
:mod:`cdgps_cli.io.rinex`.
"""

from __future__ import annotations

import math
import re
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import check_time_of_day, gps_seconds, gps_time_str
from cdgps_cli.core.signals import SIGNALS, SYSTEM_NAMES, glonass_frequency_hz, signal
from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.io.rinex import _ObsHeader, _parse_version_line, _range_note, _read_text, _sat_id
from cdgps_cli.io._fixed_width import LineBuffer, Unsupported, decimal_fields, flag_digits
from cdgps_cli.io.rinex import _as_path, _frame, _noting_end_padding, _read_bytes, _split_header, _split_lines, in_gps_time
from cdgps_cli.io import rinex_body
from cdgps_cli.io.rinex_body import BodyLines, distinct, epochs_v3, strict_float

__all__ = ["phase_attributes_in_file", "signal_attributes", "read_rinex_signals", "SIGNAL_COLUMNS", "first_of_repeated_epochs", "repeated_epochs_text",
           "out_of_order_text", "glonass_without_frequency_text"]

SIGNAL_COLUMNS = ("time_gps_s", "sat", "signal", "phase_cycles", "pseudorange_m", "lli", "wavelength_m")


def first_of_repeated_epochs(df: pd.DataFrame) -> tuple[pd.DataFrame, np.ndarray, int]:
    """A signal table whose epochs a logger wrote more than once, each (time, satellite, signal) kept once (the first
    record): (the table, the repeated epochs' times (GPS s), the rows dropped)."""
    dup = df.duplicated(["time_gps_s", "sat", "signal"], keep="first").to_numpy()
    if not dup.any():
        return df, np.zeros(0), 0
    return df[~dup].reset_index(drop=True), np.unique(df["time_gps_s"].to_numpy()[dup]), int(dup.sum())


def repeated_epochs_text(who: str, times_s, n_rows: int | None = None, lines=None) -> str:
    """The one wording of epochs a logger wrote more than once (kept once, the first record): ``who`` the file and
    receiver, ``times_s`` the repeated epochs (GPS s), and the observations dropped or the repeats' lines."""
    times_s = np.asarray(times_s, float)
    what = (f"{n_rows} repeated observations dropped" if n_rows is not None
            else f"line{'s' if len(lines) > 1 else ''} {', '.join(str(x) for x in list(lines)[:5])}"
                 f"{' …' if len(lines) > 5 else ''}")
    return (f"{who}: {times_s.size} epoch(s) written more than once, the first record used ({what}; first at GPS "
            f"{times_s[0]:.3f} s)")


def glonass_without_frequency_text(who: str, sats) -> str:
    """The one wording of GLONASS satellites left out for want of a frequency number (:func:`_check_slots`)."""
    return (f"{who}: GLONASS satellite(s) {' '.join(sats)} left out: no frequency number (the header has no GLONASS "
            f"SLOT / FRQ # of them and no navigation record gives one; without an ephemeris no solver could use them)")


def out_of_order_text(who: str, n_epochs: int, first_s: float) -> str:
    """The one wording of epochs a file holds out of time order (read in time order)."""
    return (f"{who}: {n_epochs} epoch(s) written out of time order (first: {gps_time_str(first_s)}, after a later one), "
            f"read in time order")


class EpochTimes:
    """A file's observation epochs (``t``: GPS s, sorted, distinct), kept in a table's attrs: compared by identity,
    so pandas' attrs checks (concat compares the inputs' attrs) never compare arrays."""

    __slots__ = ("t",)

    def __init__(self, t: np.ndarray):
        self.t = t


def _codes(types: list[str], name: str, v3: bool, prefer: str | None = None):
    """(phase type, code type) of signal ``name`` among a system's ``types``, or None; RINEX 2: the code types
    after the first that ``types`` lists follow (a record's pseudorange is the first of them it fills: GLONASS L2
    with C2 where a mixed file's P2, listed for GPS, is blank).  RINEX 3: the attribute ``prefer`` when the types
    list its phase (:func:`~cdgps_cli.core.signals.common_attributes`), else the first of the signal's."""
    sig = signal(name)
    if not v3:
        if not sig.rinex2 or sig.rinex2[0] not in types:
            return None
        codes = [c for c in sig.rinex2[1:] if c in types]
        return (sig.rinex2[0], *codes) if codes else (sig.rinex2[0], None)
    for a in ((prefer,) if prefer and f"L{sig.band}{prefer}" in types else ()) + tuple(sig.attributes):
        if f"L{sig.band}{a}" in types:
            code = f"C{sig.band}{a}" if f"C{sig.band}{a}" in types else None
            return f"L{sig.band}{a}", code
    return None


_SLOT = re.compile(r"R\s?(\d{1,2})\s*([+-]?\d{1,2})")


def _glonass_slots(lines, end, path) -> dict:
    """'GLONASS SLOT / FRQ #' header lines → {"R01": k}.  Entries are matched by pattern, not by
    column, as some writers pack them without the separating blank ("R11 -5R19 +3")."""
    out = {}
    for i, ln in enumerate(lines[1:end], start=2):
        if "GLONASS SLOT / FRQ #" in ln and ln[60:80].strip() == "GLONASS SLOT / FRQ #":   # one C search first
            body = ln[4:60]
            found = _SLOT.findall(body)
            if body.strip() and not found:
                raise CdgpsError(f"{path}:{i}: malformed 'GLONASS SLOT / FRQ #' line {ln[:60].rstrip()!r} "
                                 "(expected entries like 'R01  1 R02 -4')")
            out.update({f"R{int(prn):02d}": int(k) for prn, k in found})
    return out


def _columns(hdr: _ObsHeader, names, path, attributes: dict | None = None) -> dict:
    """{signal: (system key, phase index, code index, (phase type, code type, further code types…), further code
    indices)} for the signals of the request (the further codes: RINEX 2's, a row's pseudorange the first of them it
    fills; the header's ``signal_codes`` lists them all)."""
    v3 = hdr.version >= 3
    out = {}
    missing = []
    for name in names:
        sig = signal(name)
        key = sig.system if v3 else "*"
        types = hdr.info["obs_types"].get(key, [])
        if not v3 and (not sig.rinex2 or (sig.system == "E" and hdr.info["satellite_system"] not in ("M", "E"))):
            types = []                         # (RINEX 2.11 Galileo: in a mixed or a Galileo file only)
        pc = _codes(types, name, v3, (attributes or {}).get(name))
        if pc is None:
            missing.append(f"{name} ({SYSTEM_NAMES[sig.system]}: phase L{sig.band}{'/'.join(sig.attributes)}; "
                           f"the file has {' '.join(types) or 'no ' + SYSTEM_NAMES[sig.system] + ' types'})")
            continue
        out[name] = (key, types.index(pc[0]), types.index(pc[1]) if pc[1] else -1, tuple(pc),
                     tuple(types.index(c) for c in pc[2:]))
    if missing:
        raise CdgpsError(f"{path}: signal(s) asked for but absent from the observation types: " + "; ".join(missing))
    return out


def _value(rec: str, k: int, col0: int) -> tuple[float, int]:
    c = col0 + 16 * k
    f = rec[c:c + 14]
    lli = rec[c + 14:c + 15]
    v = strict_float(f) if f.strip() else math.nan
    return v, (int(lli) if lli.strip().isdigit() else 0)


def _observation_header(path: str | Path, read: tuple[bytes, bool] | None = None):
    """The file's lines, its parsed observation header, the index of its END OF HEADER line and the
    (decompressed) bytes of the lines; ``read``: the file's (decompressed) bytes and whether it was
    compressed, when already read (:func:`cdgps_cli.io.rinex._read_bytes`)."""
    p = _as_path(path)
    if read is None:
        lines, compressed, data = _read_text(p)
    else:
        data, compressed = read
        lines = _split_lines(data)
    version, ftype, system = _parse_version_line(lines, p, compressed, "observation")
    if ftype != "O":
        raise CdgpsError(f"{p}: not a RINEX observation file (type {ftype!r})")
    hdr = _ObsHeader(p, version, compressed)
    hdr.info["satellite_system"] = system or "G"          # RINEX 2: blank means GPS
    end = hdr.apply_header(lines)
    if end is None:
        raise CdgpsError(f"{p}: no 'END OF HEADER' line")
    return lines, hdr, end, data


_GALILEO_SAT = re.compile(r"E[ 0-9]\d")


_V2_EPOCH = re.compile(r" [ \d]\d [ \d]\d [ \d]\d [ \d]\d [ \d]\d [ \d]\d\.\d{7}  [01][ \d]{2}\d")


def _lists_galileo(lines, end: int) -> bool:
    """Whether a RINEX 2 body names a Galileo satellite in the satellite list (columns 33–68 and its continuation
    lines) of an observation epoch (flag 0 or 1; an event record's comment or marker name may hold such letters)."""
    i = end + 1
    while i < len(lines):
        ln = lines[i]
        if not _V2_EPOCH.match(ln):
            i += 1
            continue
        nsat = int(ln[29:32])
        sats = "".join(lines[k][32:68] for k in range(i, min(i + 1 + (nsat - 1) // 12, len(lines))))
        if _GALILEO_SAT.search(sats):
            return True
        i += 1 + (nsat - 1) // 12
    return False


def signals_in_file(path: str | Path) -> list[str]:
    """The signals of :data:`~cdgps_cli.core.signals.SIGNALS` whose carrier phase the observation
    file's header lists (RINEX 3 ``SYS / # / OBS TYPES``, RINEX 2 ``# / TYPES OF OBSERV``), in the
    table's order."""
    lines, hdr, end, _ = _observation_header(path)
    v3 = hdr.version >= 3
    # RINEX 2's types serve every system of the file (read here: GPS, GLONASS, Galileo): GPS and GLONASS in a mixed
    # ("M") file and Galileo when its epochs list a Galileo satellite (RINEX 2.11), its own system else (a GPS-only
    # file holds no GLONASS signal)
    v2_systems = (("G", "R") + (("E",) if _lists_galileo(lines, end) else ()) if hdr.info["satellite_system"] == "M"
                  else (hdr.info["satellite_system"],))
    out = []
    for name, sig in SIGNALS.items():
        if not v3 and (sig.system not in v2_systems or not sig.rinex2):
            continue
        if _codes(hdr.info["obs_types"].get(sig.system if v3 else "*", []), name, v3) is not None:
            out.append(name)
    return out


def signals_by_file(files: list, signals) -> list | None:
    """The signals of ``signals`` each of a receiver's RINEX files lists, when the files hold them system by system
    (no system in two files, every file some): one receiver's observations written a file per system, as gnss-sdr
    writes them; None otherwise (consecutive files, each read with every signal)."""
    from cdgps_cli.core.signals import signal  # noqa: PLC0415

    if len(files) < 2:
        return None
    held = [[x for x in signals if x in set(signals_in_file(p))] for p in files]
    systems = [{signal(x).system for x in h} for h in held]
    if any(not h for h in held) or len(set().union(*systems)) != sum(len(x) for x in systems):
        return None
    return held


def phase_attributes_in_file(path: str | Path, signals, read: tuple[bytes, bool] | None = None) -> dict:
    """{signal: the tracking attributes of its phase types that a RINEX 3 observation file's header lists (a string
    of letters, "" for none)} for ``signals``; every value None for a RINEX 2 file (its ``L2`` may be either family).
    ``read``: the header's (decompressed) bytes and whether the file was compressed, when already at hand (an hour
    of a long file: :class:`~cdgps_cli.io.rinex_hours.RinexHours`'s ``head``); without it, a plain file's header
    alone is read (:func:`_plain_header`), a compressed file whole."""
    _, hdr, _, _ = _observation_header(path, read if read is not None else _plain_header(path))
    out = {}
    for name in signals:
        sig = signal(name)
        types = hdr.info["obs_types"].get(sig.system, []) if hdr.version >= 3 else None
        out[name] = None if types is None else "".join(a for a in sig.attributes if f"L{sig.band}{a}" in types)
    return out


#: bytes read at a time while looking for a plain RINEX file's END OF HEADER
_HEADER_CHUNK = 1 << 16


def _plain_header(path) -> tuple[bytes, bool] | None:
    """(a plain — uncompressed, not Hatanaka — RINEX file's bytes through its END OF HEADER line, False), read a chunk
    at a time; None for any other file, or a header not found in its first MiB (the readers then read it whole)."""
    from cdgps_cli.io.rinex import COMPRESSED_MAGIC  # noqa: PLC0415

    try:
        with open(path, "rb") as f:
            data = f.read(_HEADER_CHUNK)
            if data.startswith(COMPRESSED_MAGIC) or b"CRINEX VERS" in data[:100]:      # (Hatanaka: its reader's)
                return None
            while b"END OF HEADER" not in data and len(data) < (1 << 20):
                more = f.read(_HEADER_CHUNK)
                if not more:
                    break
                data += more
    except OSError:
        return None
    end = data.find(b"END OF HEADER")
    if end < 0:
        return None
    stop = data.find(b"\n", end)
    return (data if stop < 0 else data[:stop + 1]), False


def _receiver_attributes(files: list, signals) -> dict:
    """{signal: the attributes every one of a receiver's files that lists the signal lists (None: none of them says,
    RINEX 2; "": none lists it)}; ``files``: [(kind, path, read or None)], ``"ubx"`` logs by
    :data:`~cdgps_cli.io.ubx.UBX_ATTRIBUTES`.  (A file without the signal's types at all does not narrow it: a
    receiver whose systems are in files of their own, as gnss-sdr writes them.)"""
    from cdgps_cli.io.ubx import UBX_ATTRIBUTES  # noqa: PLC0415

    out: dict = {s: None for s in signals}
    listed: set = set()
    for kind, path, read in files:
        held = ({s: UBX_ATTRIBUTES.get(s) for s in signals} if kind == "ubx"
                else phase_attributes_in_file(path, signals, read))
        for s, a in held.items():
            if a == "" and len(files) > 1:
                out[s] = "" if out[s] is None and s not in listed else out[s]
            elif a is not None:
                out[s] = a if out[s] is None or s not in listed else "".join(c for c in out[s] if c in a)
                listed.add(s)
    return out


def signal_attributes(receivers: dict, signals) -> tuple[dict, list]:
    """The attribute each receiver reads each RINEX 3 signal with: one family at every receiver
    (:func:`~cdgps_cli.core.signals.common_attributes`), among the attributes all of a receiver's files list.
    ``receivers``: name → [(kind, path, read or None)], ``"rinex"`` or ``"ubx"``, each file and, for a RINEX file,
    its header's bytes when at hand (:func:`phase_attributes_in_file`).  Returns ({receiver: {signal: attribute or
    None}}, the warnings naming each signal whose receivers share no family: each satellite's bias between the
    signals stays in its double differences)."""
    from cdgps_cli.core.signals import common_attributes  # noqa: PLC0415

    out: dict = {n: {} for n in receivers}
    if not signals:                                # (the GPS L1 path: no header read for nothing)
        return out, []
    held = {n: _receiver_attributes(fs, signals) for n, fs in receivers.items()}
    warnings = []
    for s in signals:
        picks, one_family = common_attributes(s, {n: h.get(s) for n, h in held.items()})
        for n, a in picks.items():
            out[n][s] = a
        if not one_family:
            band = signal(s).band
            warnings.append(f"{s}: the receivers track different signals on this carrier ("
                            + ", ".join(f"{n} L{band}{a}" for n, a in picks.items() if a) + "): each satellite's "
                            f"bias between them stays in the double differences (centimetres, not cycles)")
    return out, warnings


def phase_systems_in_file(path: str | Path) -> set[str]:
    """The systems (RINEX letters) whose carrier phase a RINEX 3 observation file's header lists (``SYS / # / OBS
    TYPES`` with an ``L`` type); a RINEX 2 file: none (its types are not per system)."""
    _, hdr, _, _ = _observation_header(path)
    if hdr.version < 3:
        return set()
    return {sys for sys, types in hdr.info["obs_types"].items() if any(str(t).startswith("L") for t in types)}


def read_rinex_signals(path: str | Path, signals, glonass_k: dict | None = None,
                       read: tuple[bytes, bool] | None = None, attributes: dict | None = None) -> tuple[dict, pd.DataFrame]:
    """Read the phases and ranges of ``signals`` (e.g. ``["G:L1", "G:L2", "E:E1", "E:E5a"]``).

    Parameters
    ----------
    path : str or Path
        RINEX 3.0x observation file (any system) or RINEX 2 (GPS and GLONASS L1/L2, GPS L5, RINEX 2.11 Galileo
        E1/E5a/E5b; GLONASS frequency
        numbers then come from ``glonass_k``, RINEX 2 headers have none).
    signals : sequence of str
        Signal names of :data:`cdgps_cli.core.signals.SIGNALS`.
    glonass_k : dict, optional
        GLONASS frequency numbers from elsewhere ({"R01": 1}, e.g. the navigation records'
        ``glonass_k``), used for satellites the header's ``GLONASS SLOT / FRQ #`` lines do not list.
    read : (bytes, bool), optional
        The file's (decompressed) bytes and whether it was compressed, when already at hand (an hour of a long
        file with its header: :mod:`cdgps_cli.io.rinex_hours`); ``path`` then only names it.
    attributes : dict, optional
        {signal: tracking attribute} to read a RINEX 3 signal's phase and code with, when the header lists it (the
        attribute of one family at every receiver: :func:`signal_attributes`); else the first the header lists.

    Returns
    -------
    header : dict
        The RINEX header (as :func:`cdgps_cli.io.rinex.read_rinex_obs`) plus ``signal_codes``
        ({signal: [phase type, code type]}) and ``glonass_slots`` ({sat: k}).
    obs : DataFrame
        Columns :data:`SIGNAL_COLUMNS`; rows with a phase value, epochs of flag 0/1 only.  ``attrs["file_epochs"]``:
        how many distinct observation epochs the file holds, those without a phase of ``signals`` too, and
        ``attrs["file_epoch_times"]`` (:class:`EpochTimes`) which (the vectorised readers; absent from the
        line-by-line one's).

    Raises
    ------
    CdgpsError
        A signal absent from the header (file, what was expected, what the file has), GLONASS
        signals without ``GLONASS SLOT / FRQ #`` for an observed satellite, a malformed line.
    """
    p = _as_path(path)
    read = _read_bytes(p) if read is None else read
    if FAST_PARSE:
        try:
            return _noting_end_padding(read[0], in_gps_time(*_read_bytes_v3(p, list(signals), glonass_k, read,
                                                                            attributes)))
        except Unsupported:
            pass
    lines, hdr, end, data = _observation_header(p, read)           # the bytes read (and decompressed) once
    cols = _columns(hdr, list(signals), p, attributes)
    slots = {**(glonass_k or {}), **_glonass_slots(lines, end, p)}
    df = _observations(lines, end + 1, hdr, cols, p, data, slots)
    info = dict(hdr.info)
    info["signal_codes"] = {k: list(v[3]) for k, v in cols.items()}
    info["glonass_slots"] = slots
    return _noting_end_padding(read[0], in_gps_time(info, df))


def _rinex2_by_first_line(data: bytes) -> bool:
    """The bytes begin with a RINEX VERSION / TYPE line of a version below 3 (False when unsure)."""
    if data[60:80].rstrip() != b"RINEX VERSION / TYPE":
        return False
    try:
        return float(data[:9]) < 3
    except ValueError:
        return False


def _read_bytes_v3(p: Path, signals: list, glonass_k, read: tuple[bytes, bool] | None = None,
                   attributes: dict | None = None) -> tuple[dict, pd.DataFrame]:
    """:func:`read_rinex_signals` of a RINEX 3 file from its bytes (``read``: the (decompressed) bytes and
    whether the file was compressed): only the header is split into lines, the body is walked by
    :mod:`cdgps_cli.io.rinex_body`; Unsupported where the line-based readers must decide (RINEX 2, an
    odd body, a malformed record)."""
    data, compressed = _read_bytes(p) if read is None else read
    if _rinex2_by_first_line(data):
        raise Unsupported("RINEX 2")                       # told by the first line: no header split for nothing
    head, body_at = _split_header(data)
    version, ftype, system = _parse_version_line(head, p, compressed, "observation")
    if ftype != "O" or version < 3 or not signals:
        raise Unsupported("not a RINEX 3 observation file")
    hdr = _ObsHeader(p, version, compressed)
    hdr.info["satellite_system"] = system or "G"          # as the line-by-line reader's header
    end = hdr.apply_header(head)
    cols = _columns(hdr, signals, p, attributes)
    slots = {**(glonass_k or {}), **_glonass_slots(head, end, p)}
    lines = BodyLines(data, body_at)
    try:
        ep = epochs_v3(lines, events="skip")
    except CdgpsError:
        raise Unsupported("epoch") from None
    obs = (ep["flag"] <= 1).nonzero()[0]
    try:
        df = _table(lines, hdr, cols, p, slots, ep["time_gps_s"][obs], ep["line"][obs] + 1, ep["nsat"][obs], 1, None)
    except CdgpsError:
        raise Unsupported("record") from None
    df.attrs["file_epoch_times"] = EpochTimes(np.unique(ep["time_gps_s"][obs]))
    df.attrs["file_epochs"] = int(df.attrs["file_epoch_times"].t.size)
    info = dict(hdr.info)
    info["signal_codes"] = {k: list(v[3]) for k, v in cols.items()}
    info["glonass_slots"] = slots
    return info, df


#: read records with the vectorised reader (False: line by line, the reference it is tested against)
FAST_PARSE = True


def _observations(lines, start, hdr, cols, path, data: bytes | None = None, slots: dict | None = None) -> pd.DataFrame:
    """The table of :func:`read_rinex_signals` (columns :data:`SIGNAL_COLUMNS`, sorted by time,
    signal name, satellite, stable over the file's order: record, then signal).

    The vectorised reader first; a file it does not take (or a malformed one) is read line by line,
    which gives the same table or the error naming the line."""
    if FAST_PARSE and cols:
        try:
            return _fast_table(lines, start, hdr, cols, path, data, slots or {})
        except (Unsupported, CdgpsError):
            pass
    rows = _parse_v3(lines, start, cols, path) if hdr.version >= 3 else _parse_v2(lines, start, hdr, cols, path)
    df = pd.DataFrame(rows, columns=list(SIGNAL_COLUMNS[:-1]))
    df["wavelength_m"] = _wavelengths(df, slots or {}, path)
    times = df["time_gps_s"].to_numpy()
    df = df.sort_values(["time_gps_s", "signal", "sat"], kind="stable").reset_index(drop=True)
    return _without_unknown_slots(_noting_time_order(df, times))


def _noting_time_order(df: pd.DataFrame, times) -> pd.DataFrame:
    """``df`` (sorted by time) with ``attrs["epochs_out_of_order"]`` = (count, GPS s of the first) of the
    epochs whose time, in file order ``times``, is earlier than the one before (a file's epochs swapped:
    read in time order, the caller warns), when there are any."""
    t = np.asarray(times, dtype=np.float64)
    if t.size > 1:
        # an epoch whose time is below one read before it and was not itself read before (a time written again is a
        # repeat, :func:`first_of_repeated_epochs`' to say, not an epoch out of order)
        first = np.zeros(t.size, dtype=bool)
        first[np.unique(t, return_index=True)[1]] = True
        back = np.flatnonzero(first[1:] & (t[1:] < np.maximum.accumulate(t)[:-1])) + 1
    else:
        back = np.empty(0, dtype=np.int64)
    if back.size:
        df.attrs["epochs_out_of_order"] = (int(np.unique(t[back]).size), float(t[back[0]]))
    return df


def _wavelengths(df: pd.DataFrame, slots: dict, path) -> np.ndarray:
    lam = np.empty(len(df))
    for name, idx in df.groupby("signal").indices.items():
        sig = signal(name)
        if not sig.fdma_step_hz:
            lam[idx] = sig.wavelength_m
            continue
        sats = df["sat"].to_numpy()[idx]
        _check_slots(set(sats), slots, path)
        lam[idx] = [SPEED_OF_LIGHT_M_S / glonass_frequency_hz(sig, slots[s]) if s in slots else np.nan for s in sats]
    return lam


def _epoch_time(line: str, a: int, path, lineno) -> float:
    """GPS seconds of an epoch line (``a`` = 2: RINEX 3 ``> yyyy mm dd hh mm ss.sssssss``; 1: RINEX 2,
    two-digit year): :func:`~cdgps_cli.core.gps_time.gps_seconds`'s value, the day's seconds looked up
    once per date (:func:`_day_seconds`)."""
    try:
        if a == 2:   # RINEX 3
            day = _day_seconds(2, line[2:12])
            h, mi, sec = int(line[13:15]), int(line[16:18]), float(line[18:29])
        else:
            day = _day_seconds(1, line[1:9])
            h, mi, sec = int(line[10:12]), int(line[13:15]), float(line[15:26])
        check_time_of_day(h, mi, sec)
        return float(day + h * 3600 + mi * 60) + sec
    except ValueError as exc:
        raise CdgpsError(f"{path}:{lineno}: malformed epoch line {line[:60]!r}{_range_note(exc)}") from None


@lru_cache(maxsize=4096)
def _day_seconds(a: int, date: str) -> int:
    """GPS seconds of 00:00 of an epoch line's date field (``a`` = 2: ``yyyy mm dd``; 1: ``yy mm dd``),
    an integer (ValueError when malformed)."""
    if a == 2:
        y, mo, d = int(date[0:4]), int(date[5:7]), int(date[8:10])
    else:
        yy, mo, d = int(date[0:2]), int(date[3:5]), int(date[6:8])
        y = yy + (1900 if yy >= 80 else 2000)
    return int(gps_seconds(y, mo, d))


def _epoch_counts(line: str, col: int, path, lineno: int) -> tuple[int, int]:
    """(epoch flag, number of satellites or special records) of an epoch line; the flag is at
    ``col`` (RINEX 3: 31, RINEX 2: 28), the count in the next three columns."""
    try:
        return int(line[col:col + 1] or 0), int(line[col + 1:col + 4])
    except ValueError:
        raise CdgpsError(f"{path}:{lineno}: malformed epoch line {line[:60]!r} (flag and satellite count "
                         f"expected in columns {col + 1}–{col + 4})") from None


def _truncated(path, lineno: int, nsat: int, left: int) -> CdgpsError:
    return CdgpsError(f"{path}:{lineno}: the epoch announces {nsat} satellites but the file ends after "
                      f"{left} more lines (truncated file?)")


def _parse_v3(lines, i, cols, path) -> list:
    rows = []
    while i < len(lines):
        ln = lines[i]
        if not ln.strip():
            i += 1
            continue
        if not ln.startswith(">"):
            raise CdgpsError(f"{path}:{i + 1}: expected an epoch line starting with '>', got {ln[:60]!r}")
        flag, nsat = _epoch_counts(ln, 31, path, i + 1)
        if i + 1 + nsat > len(lines):
            raise _truncated(path, i + 1, nsat, len(lines) - i - 1)
        if flag > 1:
            i += 1 + nsat
            continue
        t = _epoch_time(ln, 2, path, i + 1)
        for r_off, rec in enumerate(lines[i + 1:i + 1 + nsat]):
            sat = rec[0:3].replace(" ", "0")
            if not sat:
                raise CdgpsError(f"{path}:{i + 2 + r_off}: blank line where the epoch's satellite record "
                                 f"{r_off + 1} of {nsat} was expected")
            if rec.startswith(">"):
                raise CdgpsError(f"{path}:{i + 2 + r_off}: an epoch line where satellite record {r_off + 1} of "
                                 f"{nsat} of the epoch at line {i + 1} was expected (the epoch announces more "
                                 f"satellites than it holds)")
            _check_satellite(rec[0:3], 3, path, i + 2 + r_off, "at the start of an observation record")
            for name, (key, ip, ic, _, _) in cols.items():
                if sat[0] != key:
                    continue
                try:
                    ph, lli = _value(rec, ip, 3)
                    pr = _value(rec, ic, 3)[0] if ic >= 0 else math.nan
                except ValueError:
                    raise CdgpsError(f"{path}:{i + 2 + r_off}: malformed observation record {rec[:40]!r}") from None
                if not math.isnan(ph):
                    rows.append((t, sat, name, ph, pr, lli))
        i += 1 + nsat
    return rows


def _parse_v2(lines, i, hdr, cols, path) -> list:
    n_types = len(hdr.info["obs_types"]["*"])
    per = math.ceil(n_types / 5)
    rows = []
    while i < len(lines):
        ln = lines[i]
        if not ln.strip():
            i += 1
            continue
        flag, nsat = _epoch_counts(ln, 28, path, i + 1)
        n_rec = nsat if flag > 1 else nsat * per       # special records: one line each
        if i + math.ceil(nsat / 12) + n_rec > len(lines):
            raise _truncated(path, i + 1, nsat, len(lines) - i - 1)
        sats = "".join(lines[i + k][32:68] for k in range(math.ceil(nsat / 12)))
        epoch_line = i + 1
        i += math.ceil(nsat / 12)
        if flag > 1:
            i += nsat
            continue
        t = _epoch_time(ln, 1, path, epoch_line)
        for j in range(nsat):
            _check_satellite(sats[3 * j:3 * j + 3], 2, path, epoch_line + j // 12,
                             f"(satellite {j + 1} of the {nsat} the epoch line announces)")
            sat = sats[3 * j:3 * j + 3].replace(" ", "0")
            sat = "G" + sat[1:] if sat[0] in "0G" else sat
            rec = "".join(lines[i + k].rstrip("\n").ljust(80) for k in range(per))
            i += per
            for name, (_, ip, ic, _, more) in cols.items():
                if signal(name).system != sat[0]:
                    continue
                try:
                    ph, lli = _value(rec, ip, 0)
                    pr = _value(rec, ic, 0)[0] if ic >= 0 else math.nan
                    for k in more:                          # the next code type the record fills
                        if math.isnan(pr):
                            pr = _value(rec, k, 0)[0]
                except ValueError:
                    bad = i - per + _bad_field(rec, (ip, ic, *more)) // 5
                    raise CdgpsError(f"{path}:{bad + 1}: malformed observation record of {sat}: "
                                     f"{lines[bad][:80]!r}") from None
                if not math.isnan(ph):
                    rows.append((t, sat, name, ph, pr, lli))
    return rows


def _is_satellite(raw: str, version: int) -> bool:
    try:
        _sat_id(raw, version)
    except ValueError:
        return False
    return True


def _check_satellite(raw: str, version: int, path, lineno: int, where: str) -> None:
    """Refuse a satellite field that is no system letter and number (garbage, a short satellite list):
    its records would be skipped as another system's, unseen."""
    try:
        _sat_id(raw, version)
    except ValueError:
        raise CdgpsError(f"{path}:{lineno}: malformed satellite identifier {raw!r} {where} (a system letter "
                         f"G, R, E, S, J, C or I and a two-digit number expected)") from None


def _bad_field(rec: str, fields) -> int:
    """The first of the observation indices ``fields`` whose value or LLI ``_value`` refuses."""
    for k in fields:
        if k >= 0:
            try:
                _value(rec, k, 0)
            except ValueError:
                return k
    return fields[0]


def _walk_v3(lines, i, path):
    """Epochs of a RINEX 3 body: (times (n_ep,), first record line (n_ep,), records (n_ep,)) of the
    epochs of flag 0/1; Unsupported where the line-by-line reader would stop."""
    times, first, count = [], [], []
    n = len(lines)
    while i < n:
        ln = lines[i]
        if not ln.strip():
            i += 1
            continue
        if ln[0] != ">":
            raise Unsupported("epoch line")
        flag, nsat = _epoch_counts(ln, 31, path, i + 1)
        if i + 1 + nsat > n:
            raise Unsupported("truncated")
        if flag <= 1:
            times.append(_epoch_time(ln, 2, path, i + 1))
            first.append(i + 1)
            count.append(nsat)
        i += 1 + nsat
    return times, first, count


def _walk_v2(lines, i, hdr, path):
    """As :func:`_walk_v3` for RINEX 2, plus the satellite of every record (list of str) and the
    number of lines per record."""
    per = math.ceil(len(hdr.info["obs_types"]["*"]) / 5)
    times, first, count, sats_all = [], [], [], []
    seen: dict = {}
    n = len(lines)
    while i < n:
        ln = lines[i]
        if not ln.strip():
            i += 1
            continue
        flag, nsat = _epoch_counts(ln, 28, path, i + 1)
        n_head = math.ceil(nsat / 12)
        if i + n_head + (nsat if flag > 1 else nsat * per) > n:
            raise Unsupported("truncated")
        sats = "".join(lines[i + k][32:68] for k in range(n_head))
        i += n_head
        if flag > 1:
            i += nsat
            continue
        times.append(_epoch_time(ln, 1, path, i))
        first.append(i)
        count.append(nsat)
        names = seen.get((sats, nsat))                     # consecutive epochs mostly list the same satellites
        if names is None:
            names = seen[(sats, nsat)] = _v2_satellites(sats, nsat)
        sats_all.extend(names)
        i += nsat * per
    return times, first, count, sats_all, per


def _v2_satellites(sats: str, nsat: int) -> list:
    """The ``nsat`` satellite names of a RINEX 2 epoch's satellite list (3 characters each, blanks read as
    0, no system letter or 0 read as GPS); Unsupported when the list is shorter."""
    names = []
    for j in range(nsat):
        sat = sats[3 * j:3 * j + 3].replace(" ", "0")
        if not sat or not _is_satellite(sats[3 * j:3 * j + 3], 2):
            raise Unsupported("satellite list")
        names.append("G" + sat[1:] if sat[0] in "0G" else sat)
    return names


def _fast_table(lines, start, hdr, cols, path, data: bytes | None, slots: dict) -> pd.DataFrame:
    """:func:`_observations` by the vectorised reader (Unsupported: use the line-by-line one)."""
    if hdr.version >= 3:
        times, first, count = _walk_v3(lines, start, path)
        per, sats_v2 = 1, None
    else:
        times, first, count, sats_v2, per = _walk_v2(lines, start, hdr, path)
    buf = LineBuffer(lines) if data is None else LineBuffer.from_bytes(data, lines)
    df = _table(buf, hdr, cols, path, slots, times, first, count, per, sats_v2)
    df.attrs["file_epoch_times"] = EpochTimes(np.unique(np.asarray(times, dtype=np.float64)))
    df.attrs["file_epochs"] = int(df.attrs["file_epoch_times"].t.size)
    return df


def _table(buf, hdr, cols, path, slots, times, first, count, per, sats_v2) -> pd.DataFrame:
    """The table of the records of the epochs at ``times`` whose first record line (index into
    ``buf``, a :class:`LineBuffer` or :class:`BodyLines`) is ``first`` and that have ``count``
    records of ``per`` lines each (RINEX 2: the records' satellites ``sats_v2``)."""
    v3 = hdr.version >= 3
    count = np.asarray(count, dtype=np.int64)
    n_rec = int(count.sum())
    if n_rec == 0:
        raise Unsupported("no records")
    first = np.asarray(first, dtype=np.int64)
    offset = np.concatenate([[0], count.cumsum()[:-1]])         # (array methods: numpy's wrappers cost µs each)
    rec_line = first.repeat(count) + per * (np.arange(n_rec) - offset.repeat(count))   # first line of every record
    t_rec = np.asarray(times, dtype=np.float64).repeat(count)
    sat_names, sat_code = _record_satellites(buf, rec_line, per, v3, sats_v2)
    sat_obj = np.array(sat_names + [None], dtype=object)[:-1]
    rows_of, lines_of, cols_of, n_of = [], [], [], []
    of_system: dict = {}                                   # the records of each system, found once
    for name, (key, ip, ic, _, more) in cols.items():
        system = key if v3 else signal(name).system
        if system not in of_system:
            of_system[system] = np.array([x[:1] == system for x in sat_names])[sat_code].nonzero()[0]
        rows = of_system[system]
        rows_of.append(rows)
        for k in (ip, ic, *more):
            if k >= 0:
                line, col = _field_place(rec_line[rows], k, v3)
                lines_of.append(line)
                cols_of.append(col)
                n_of.append(rows.size)
    # every field of every signal at once: one gather, one conversion
    f = buf.gather(np.concatenate(lines_of), np.array(cols_of, dtype=np.int64).repeat(n_of), 15)
    values, flags = decimal_fields(f[:, :14]), flag_digits(f[:, 14])
    parts, at = [], 0
    for s_i, (rows, (_, _, ic, _, more)) in enumerate(zip(rows_of, cols.values())):
        ph, lli = values[at:at + rows.size], flags[at:at + rows.size]
        at += rows.size
        if ic >= 0:
            pr = values[at:at + rows.size]
            at += rows.size
        else:
            pr = np.full(rows.size, math.nan)
        for _k in more:                                   # RINEX 2: the next code type where a record left one blank
            pr = np.where(np.isnan(pr), values[at:at + rows.size], pr)
            at += rows.size
        ok = ~np.isnan(ph)
        parts.append((rows[ok], s_i, ph[ok], pr[ok], lli[ok]))
    names = np.array(list(cols), dtype=object)
    rows = np.concatenate([p[0] for p in parts])
    if rows.size == 0:
        raise Unsupported("no observation")       # the line-by-line reader's empty table (object columns)
    sig = np.arange(len(parts)).repeat([p[0].size for p in parts])         # each row's signal index
    order = (rows * len(cols) + sig).argsort(kind="stable")
    rows, sig = rows[order], sig[order]
    rank_of = {n: r for r, n in enumerate(sorted(cols))}
    sig_rank = np.array([rank_of[n] for n in cols], dtype=np.int64)    # signal index -> rank of its name
    t = t_rec[rows]
    final = np.lexsort((sat_code[rows], sig_rank[sig], t))                # stable: file order among equals
    rows, sig = rows[final], sig[final]
    take = order[final]                                                   # into the parts, concatenated
    sat_c = sat_code[rows]
    lam = _wavelength_array(sat_c, sat_names, sig, list(cols), slots, path)
    df = _frame({
        "time_gps_s": t[final], "sat": sat_obj[sat_c], "signal": names[sig],
        "phase_cycles": np.concatenate([p[2] for p in parts])[take],
        "pseudorange_m": np.concatenate([p[3] for p in parts])[take],
        "lli": np.concatenate([p[4] for p in parts])[take], "wavelength_m": lam})
    return _without_unknown_slots(_noting_time_order(df, times))


def _record_satellites(buf, rec_line: np.ndarray, per: int, v3: bool, sats_v2) -> tuple[list, np.ndarray]:
    """(the records' satellite names, sorted; each record's index into them (n,)): RINEX 3 from the first
    3 bytes of the records starting at ``rec_line`` (blanks read as 0; Unsupported for a blank record
    line or a non-ASCII byte), RINEX 2 from ``sats_v2`` (Unsupported for a record line longer than 80
    characters)."""
    if not v3:
        rec_lines = rec_line[:, None] + np.arange(per)
        if np.any(buf.length[rec_lines] > 80):
            raise Unsupported("long record line")
        sat_names, sat_code = distinct(sats_v2)                        # str of <= 3 characters
        return sat_names, sat_code.ravel()
    if (buf.length[rec_line] == 0).any():
        raise Unsupported("blank record")
    sat_bytes = buf.gather(rec_line, 0, 3)
    if rec_line.size <= rinex_body.FEW_RECORDS:
        sat_names, sat_code = _few_v3_satellites(sat_bytes)
    else:
        if np.any(sat_bytes >= 128):
            raise Unsupported("satellite")
        sat_bytes[sat_bytes == 32] = 48
        code = (sat_bytes[:, 0].astype(np.int32) << 16) | (sat_bytes[:, 1].astype(np.int32) << 8) | sat_bytes[:, 2]
        uniq, sat_code = distinct(code)                                 # ASCII, 3 bytes: the str order
        sat_names = [bytes([u >> 16, (u >> 8) & 255, u & 255]).decode("ascii") for u in uniq]
        sat_code = sat_code.ravel()
    if not all(_is_satellite(x, 3) for x in sat_names):
        raise Unsupported("satellite")                                  # the line-by-line reader names it
    return sat_names, sat_code


def _few_v3_satellites(sat_bytes: np.ndarray) -> tuple[list, np.ndarray]:
    """:func:`_record_satellites` of a few RINEX 3 records' satellite fields (n, 3), as 3-byte strings
    (their order is the order of the integer codes of the numpy path), without numpy's per-call set-up."""
    blob = sat_bytes.tobytes()
    if not blob.isascii():
        raise Unsupported("satellite")
    blob = blob.replace(b" ", b"0")
    fields = [blob[i:i + 3] for i in range(0, len(blob), 3)]
    uniq = sorted(set(fields))
    where = {u: i for i, u in enumerate(uniq)}
    return [u.decode("ascii") for u in uniq], np.array([where[f] for f in fields], dtype=np.intp)


def _wavelength_array(sat_code: np.ndarray, sat_names: list, sig: np.ndarray, names: list, slots: dict, path) -> np.ndarray:
    """:func:`_wavelengths` on arrays: ``sat_code`` (n,) index into ``sat_names``, ``sig`` (n,) index
    into ``names``.  A (signal, satellite) table of wavelengths, then one look-up per row: a CDMA
    signal's for every satellite, an FDMA one's for the satellites it has rows of, signals in name
    order (the first with a satellite lacking its frequency number raises)."""
    sigs = [signal(n) for n in names]
    table = np.empty((len(names), len(sat_names)), dtype=np.float64)
    fdma = sorted((j for j, sg in enumerate(sigs) if sg.fdma_step_hz), key=lambda j: names[j])
    if fdma:
        has = np.zeros(table.shape, dtype=bool)
        has[sig, sat_code] = True
    for i, sg in enumerate(sigs):
        if i not in fdma:
            table[i] = sg.wavelength_m
    for i in fdma:
        present = [(c, sat_names[c]) for c in has[i].nonzero()[0].tolist()]
        _check_slots({s for _, s in present}, slots, path)
        for c, s in present:
            table[i, c] = SPEED_OF_LIGHT_M_S / glonass_frequency_hz(sigs[i], slots[s]) if s in slots else np.nan
    return table[sig, sat_code]


def _check_slots(sats: set, slots: dict, path) -> list:
    """The GLONASS satellites of ``sats`` without a frequency number in ``slots`` (sorted): their rows are left out
    (:func:`_without_unknown_slots`) when ``slots`` has any — numbers from the header or from the navigation
    records, which give one to every satellite with an ephemeris, so these have none and no solver could use them;
    CdgpsError naming them when it has none (no source at all)."""
    absent = sorted(set(sats) - set(slots))
    if absent and not slots:
        raise CdgpsError(f"{path}: GLONASS frequency numbers absent for {' '.join(absent)} "
                         "(header line 'GLONASS SLOT / FRQ #' expected, or a GLONASS navigation record of "
                         "the satellite); FDMA phases need them")
    return absent


def _without_unknown_slots(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` less its rows of no wavelength (GLONASS satellites without a frequency number, :func:`_check_slots`),
    named in ``attrs["glonass_without_frequency"]`` (sorted satellites) when there are any."""
    lam = df["wavelength_m"].to_numpy(dtype=np.float64)
    bad = ~np.isfinite(lam)
    if not bad.any():
        return df
    attrs = dict(df.attrs)
    out = df[~bad].reset_index(drop=True)
    out.attrs = {**attrs, "glonass_without_frequency": sorted(set(df["sat"].to_numpy()[bad].tolist()))}
    return out


def _field_place(rec_line: np.ndarray, k: int, v3: bool):
    """(line (n,), column) of observation ``k`` of the records starting at ``rec_line``."""
    if v3:
        return rec_line, 3 + 16 * k
    return rec_line + k // 5, 16 * (k % 5)
