"""RINEX observation and navigation files: reading and validation.

Two readers, both returning plain pandas tables with units in the column names:

* :func:`read_rinex_obs` — RINEX 2.10/2.11 and 3.0x observation files → one row per epoch and
  GPS satellite with the L1 carrier phase, its loss-of-lock indicator (LLI), the L1 pseudorange
  and the L1 signal strength.
* :func:`read_rinex_nav` — RINEX 2 and 3 navigation files → one row per broadcast ephemeris
  (GPS, Galileo, BeiDou: the Kepler parameters of IS-GPS-200 subframes 1–3 and their equivalents;
  GLONASS: state vectors), Fortran ``D`` exponents handled.

Files may be plain, gzip (``.gz``), Unix-compress (``.Z``), bzip2 or zip compressed, and
observation files may be Hatanaka-compressed (Compact RINEX, ``.crx`` / ``.??d``); compressed
content is recognised from the bytes, not the name, and decompressed in memory with the
`hatanaka <https://pypi.org/project/hatanaka/>`_ package (the RNXCMP tools of Y. Hatanaka, GSI).

Every problem in the input raises :class:`~cdgps_cli.core.errors.CdgpsError` naming the file and, for a
malformed line, its 1-based line number (of the decompressed RINEX text for a compressed file).

Times are GPS seconds since the GPS epoch 1980-01-06 00:00:00 GPST (float64; at ~1.1e9 s a float64
resolves 0.24 µs, so epochs are exact to well below a millisecond).
"""

from __future__ import annotations

import math
import re
import warnings
import zlib
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import GPS_EPOCH, SECONDS_PER_WEEK, gps_seconds, gps_time_str  # noqa: F401  (__all__)
from cdgps_cli.core.gps_time import BDT_WEEK_OFFSET, GLONASST_MINUS_UTC_S, GPS_MINUS_BDT_S, glonasst_to_gps_s
from cdgps_cli.core.records import GLONASS_NAV_COLUMNS, NAV_COLUMNS, OBS_COLUMNS  # noqa: F401  (__all__)
from cdgps_cli.core.timescales import gps_minus_utc_s
from cdgps_cli.config.options import RINEX_BLOCK_EPOCHS
from cdgps_cli.io import rinex_body as _body
from cdgps_cli.io._fixed_width import Unsupported
from cdgps_cli.io.rinex_body import strict_float

__all__ = [
    "GPS_EPOCH",
    "SECONDS_PER_WEEK",
    "OBS_COLUMNS",
    "NAV_COLUMNS",
    "gps_seconds",
    "gps_time_str",
    "read_rinex_obs",
    "read_rinex_nav",
]

# GPS L1 tracking modes in order of preference (RINEX 3 attribute letters): C/A first, since the
# project's receivers track C/A; then the semi-codeless P(Y) variants and the L1C signal.
_L1_ATTRIBUTES = "CWPYXSLMN"
#: the RINEX 3 L1 phase, code and SNR types in that order of preference ({"L": ("L1C", "L1W", …), "C": …, "S": …})
_L1_TYPES = {k: tuple(f"{k}1{a}" for a in _L1_ATTRIBUTES) for k in "LCS"}
#: the system letters of satellite fields (:func:`_sat_id`)
_SYSTEM_LETTERS = frozenset("GRESJCIM")


# ----------------------------------------------------------------------------------------------
# reading and decompression
# ----------------------------------------------------------------------------------------------

#: leading bytes of the compressed files the RINEX readers open (gzip, Unix compress, bzip2, zip)
COMPRESSED_MAGIC = (b"\x1f\x8b", b"\x1f\x9d", b"BZh", b"PK\x03\x04")
_COMPRESSED_MAGIC = COMPRESSED_MAGIC


def _read_lines(path: str | Path) -> tuple[list[str], bool]:
    """Read a (possibly compressed) RINEX file; return its lines and whether it was compressed."""
    lines, compressed, _ = _read_text(path)
    return lines, compressed


def _read_text(path: str | Path) -> tuple[list[str], bool, bytes]:
    """:func:`_read_lines` plus the (decompressed) bytes the lines were split from (latin-1: line
    ``i`` is the bytes between the ``i``-th and ``i+1``-th LF, less a CR before the LF)."""
    data, compressed = _read_bytes(path)
    return _split_lines(data), compressed, data


def _as_path(path: str | Path) -> Path:
    """``path`` as a :class:`~pathlib.Path`: the object itself when it is one (``Path(path)`` would build
    an equal one anew, ≈ 7 µs a time, and a fresh one's ``str`` again)."""
    return path if isinstance(path, Path) else Path(path)


def _read_bytes(path: str | Path) -> tuple[bytes, bool]:
    """The (decompressed) bytes of a RINEX file and whether it was compressed."""
    p = _as_path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read: {exc.strerror or exc}") from None
    if not data:
        raise CdgpsError(f"{p}: empty file; expected a RINEX file")
    compressed = data.startswith(_COMPRESSED_MAGIC)
    head = data[:200].lstrip(b"\xef\xbb\xbf")
    crinex = not compressed and b"CRINEX VERS" in head.split(b"\n", 1)[0]
    if compressed or crinex:
        try:
            import hatanaka  # noqa: PLC0415 (only needed for compressed files)
        except ImportError:  # pragma: no cover - a declared dependency
            raise CdgpsError(f"{p}: compressed RINEX needs the 'hatanaka' package (pip install hatanaka)") from None
        try:
            with warnings.catch_warnings(record=True) as said:         # (crx2rnx's notes: said as cdgps warnings)
                warnings.simplefilter("always")
                data = hatanaka.decompress(data)
            notes = tuple(dict.fromkeys(str(w.message) for w in said))
        except (hatanaka.HatanakaException, ValueError, OSError, EOFError, zlib.error, RuntimeError) as exc:
            what = "Hatanaka (Compact RINEX)" if crinex else "compressed"
            msg = str(exc).strip().splitlines()
            raise CdgpsError(f"{p}: cannot decompress this {what} file: {msg[-1] if msg else type(exc).__name__}") from None
        if not data:
            raise CdgpsError(f"{p}: decompressed to nothing; truncated or corrupt compressed file")
    _refuse_a_value_cut_by_the_end(data, p)
    out = _with_the_last_blank_lines(_without_repeated_headers(data, p))
    if (compressed or crinex) and notes:
        out = out if isinstance(out, EndPadded) else EndPadded(out)
        out.decompress_notes = notes
    return out, compressed or crinex


#: a RINEX 2 epoch line: a date and time (yy mm dd hh mm ss.sssssss), then the flag and the number of satellites
_V2_EPOCH_LINE = re.compile(rb"^ [ \d]\d [ \d]\d [ \d]\d [ \d]\d [ \d]\d [ \d]\d\.\d{7}  [0-6][ \d]{2}\d")
#: bytes of a RINEX 2 file's end in which its last epoch line is looked for (64 satellites × 5 lines × 81 bytes)
_V2_TAIL_BYTES = 1 << 15


class EndPadded(bytes):
    """A RINEX observation file's bytes as the readers take them: given back the blank lines a RINEX 2 file's last
    satellite's record lacked (:func:`_with_the_last_blank_lines`; ``end_padded_lines`` says how many), or without the
    second headers of files joined one after the other (:func:`_without_repeated_headers`; ``repeated_headers``: the
    lines where they started), for the readers' header keys of the same names and the commands' warnings
    (:func:`end_padded_text`, :func:`repeated_headers_text`)."""

    end_padded_lines: int = 0
    repeated_headers: tuple = ()
    decompress_notes: tuple = ()


def repeated_headers_text(who: str, lines) -> str:
    """The warning for a file read without the second headers that started at ``lines``."""
    return (f"{who}: a second header at line(s) {', '.join(map(str, lines))} (recordings joined one after the other): "
            f"its observation types are the first header's; read on as one record")


def reading_notes(header: dict, who: str) -> list:
    """The warnings of how a reader took a file (its header's ``end_padded_lines``, ``repeated_headers`` and
    ``decompress_notes``, :func:`_noting_end_padding`): one place for every command that reads RINEX."""
    out = []
    if header.get("end_padded_lines"):
        out.append(end_padded_text(who, header["end_padded_lines"]))
    if header.get("repeated_headers"):
        out.append(repeated_headers_text(who, header["repeated_headers"]))
    if header.get("decompress_notes"):
        out.append(f"{who}: its Hatanaka decompression said: " + "; ".join(header["decompress_notes"]))
    return out


#: header lines that say how the records are laid out: a second header must repeat them to be read on
_LAYOUT_LABELS = (b"SYS / # / OBS TYPES", b"# / TYPES OF OBSERV")


def _layout(head: bytes) -> list:
    """A header's observation-type lines (their first 60 columns), in order."""
    return [ln[:60].rstrip() for ln in head.split(b"\n") if ln[60:80].rstrip() in _LAYOUT_LABELS]


def _in_event_block(data: bytes, start: int, v3: bool) -> bool:
    """Whether the line at ``start`` is one of the special records of an event (epoch flag 2–5: header lines a
    receiver writes within its records, RINEX 3 ``>`` … flag 4), counted by the last epoch line before it."""
    if v3:
        e = data.rfind(b"\n>", 0, start)
        if e < 0:
            return False
        e += 1
        flag, count = data[e + 31:e + 32], data[e + 32:e + 35]
    else:
        last = None
        for m in _V2_EPOCH_ANY.finditer(data, max(0, start - _V2_TAIL_BYTES), start):
            last = m
        if last is None:
            return False
        e = last.start()
        flag, count = data[e + 28:e + 29], data[e + 29:e + 32]
    try:
        f, n = int(flag), int(count)
    except ValueError:
        return False
    return 2 <= f <= 5 and data.count(b"\n", e, start) <= n


#: a RINEX 2 epoch line anywhere in a file (:data:`_V2_EPOCH_LINE` at a line start)
_V2_EPOCH_ANY = re.compile(rb"(?m)^ [ \d]\d [ \d]\d [ \d]\d [ \d]\d [ \d]\d [ \d]\d\.\d{7}  [0-6][ \d]{2}\d")


def _without_repeated_headers(data: bytes, path) -> bytes:
    """A RINEX file holding further headers after its first (files joined by ``cat``: a receiver or a software
    receiver restarted within one log; RTKLIB reads on) without them, an :class:`EndPadded` whose ``repeated_headers``
    lists the lines where they started (observation files: the readers' warning says them; a navigation file's
    records read the same either way).  A further header of another version or file type, or whose observation
    types are not the first's (the records would be read with the wrong columns), is refused naming its line; any
    other file is returned as it is."""
    if len(data) < 80 or data[60:80].rstrip() != b"RINEX VERSION / TYPE":
        return data
    head_end = data.find(b"END OF HEADER")
    k = data.find(b"RINEX VERSION / TYPE", head_end) if head_end > 0 else -1
    if k < 0:
        return data
    layout, parts, pos, starts = (data[:21].split(), _layout(data[:head_end])), [], 0, []
    v3 = data[:9].strip()[:1] not in (b"1", b"2")
    while k >= 0:
        start = data.rfind(b"\n", 0, k) + 1
        if k - start != 60 or _in_event_block(data, start, v3):    # (a label elsewhere, or an event's header lines)
            k = data.find(b"RINEX VERSION / TYPE", k + 1)
            continue
        line = data.count(b"\n", 0, start) + 1
        end = data.find(b"END OF HEADER", k)
        if end < 0:
            raise CdgpsError(f"{path}: line {line}: a second header (RINEX VERSION / TYPE) without its END OF HEADER")
        if (data[start:start + 21].split(), _layout(data[start:end])) != layout:
            raise CdgpsError(f"{path}: line {line}: a second header whose version, file type or observation types are "
                             f"not the first's (recordings joined into one file): give them as separate files (one "
                             f"after the other)")
        stop = data.find(b"\n", end)
        stop = len(data) if stop < 0 else stop + 1
        parts.append(data[pos:start])
        starts.append(line)
        pos = stop
        k = data.find(b"RINEX VERSION / TYPE", stop)
    out = EndPadded(b"".join(parts) + data[pos:])
    out.repeated_headers = tuple(starts)
    return out


def end_padded_text(who: str, n: int) -> str:
    """The warning for a RINEX 2 file read with ``n`` blank lines given back at its end."""
    return (f"{who}: the last satellite's record of its last epoch ends {n} line(s) short at the end of the file: "
            f"read as blank fields (a line of blank fields dropped with the file's trailing white space, as RTKLIB "
            f"reads it; were the file cut there, that satellite's last observation types are missing)")


def _with_the_last_blank_lines(data: bytes) -> bytes:
    """A RINEX 2 observation file whose last satellite's record lacks only its last continuation line(s), with those
    lines given back empty (an :class:`EndPadded`): a line of blank fields (an S5 the receiver did not track) carries
    no value, and a tool that strips trailing white space drops it with the file's last line (a real EUREF file of a
    GNSS library's test data: "announces 20 satellites × 3 lines but the file ends"; RTKLIB reads it).  Not where
    the last line is cut inside a value (no line end after it, and a length no whole line of 16-column fields has):
    the readers refuse that, as before.  A record missing a whole satellite, or any other file, is returned as it
    is.  Only the file's last :data:`_V2_TAIL_BYTES` are looked at."""
    if len(data) < 80 or data[60:80].rstrip() != b"RINEX VERSION / TYPE" or data[20:21] not in (b"O", b"o"):
        return data
    try:
        if float(data[:9]) >= 3:
            return data
    except ValueError:
        return data
    head_end = data.find(b"END OF HEADER")
    types = re.search(rb"^ *(\d+)[^\n]{0,54}# / TYPES OF OBSERV", data[:head_end], re.M) if head_end > 0 else None
    if types is None:
        return data
    per_sat = max(1, -(-int(types.group(1)) // 5))
    body_start = data.find(b"\n", head_end) + 1
    whole_end = data.endswith(b"\n")
    lines = data[max(body_start, len(data) - _V2_TAIL_BYTES):].split(b"\n")
    if whole_end:
        lines.pop()                                   # (the line end of the last line)
    elif len(lines[-1].rstrip(b"\r")) % 16 not in (0, 14, 15):
        return data                                   # the last line cut inside a value: refused by the readers
    for back in range(1, len(lines)):
        line = lines[-back].rstrip(b"\r")
        if not _V2_EPOCH_LINE.match(line):
            continue
        flag, nsat = int(line[28:29]), int(line[29:32])
        if flag > 1:
            return data                               # an event's special records: read as they are
        missing = -(-nsat // 12) - 1 + nsat * per_sat - (back - 1)
        if not 0 < missing < per_sat:
            return data
        out = EndPadded(data + (b"" if whole_end else b"\n") + b"\n" * missing)
        out.end_padded_lines = missing
        out.repeated_headers = getattr(data, "repeated_headers", ())
        return out
    return data


def _refuse_a_value_cut_by_the_end(data: bytes, path) -> None:
    """CdgpsError naming the file, line and epoch when a RINEX 3 observation file ends, without a line end, inside a
    value of its last record line (a logger stopped in the middle of a number): the readers would read the number
    cut short (the real mosaic rover cut 42 bytes into its last line: a static rover about 1000 km off, 0 % fixed,
    silently).  A record count the end of the file cuts is refused by the readers themselves (issue 29: a truncated
    file is refused naming the file and the time); other files pass."""
    if len(data) < 80 or data[60:80].rstrip() != b"RINEX VERSION / TYPE" or data[20:21] not in (b"O", b"o"):
        return
    try:
        if float(data[:9]) < 3:
            return
    except ValueError:
        return
    end = len(data)
    body = data.find(b"END OF HEADER")
    if body < 0 or data[end - 1:end] in (b"\n", b"\r") or not _last_line_cut_in_a_value(data, end):
        return
    i = data.rfind(b"\n>", body, end)
    line = data[i + 1:data.find(b"\n", i + 1)] if i >= 0 else b""
    try:
        if i < 0 or int(line[32:35]) > data.count(b"\n", i + 1, end):
            return                      # the epoch's record count is cut too: the readers name that, as before
    except ValueError:
        return
    lineno = data.count(b"\n", 0, end) + 1
    raise CdgpsError(f"{_where(path, lineno, False)}: the file ends inside a value of its last record line (epoch "
                     f"{line[2:29].decode('latin-1').strip() or '?'}): truncated file?")


def _last_line_cut_in_a_value(data: bytes, end: int) -> bool:
    """Whether the file ends without a line end inside a value of its last record line (a RINEX 3 record line is
    3 + 16 k characters, the last value's two flag characters possibly left blank): a logger stopped in the middle
    of a number, which would otherwise be read as a shorter one."""
    if end < len(data):                            # the file ends with a line end: the line is whole
        return False
    line = data[data.rfind(b"\n", 0, end) + 1:end].rstrip(b"\r")
    return len(line) > 3 and not line.startswith(b">") and (len(line) - 3) % 16 not in (0, 14, 15)


def _split_lines(data: bytes) -> list[str]:
    """The lines of ``data`` (latin-1, LF-separated, a CR before an LF and a leading BOM dropped)."""
    text = data.decode("latin-1")
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    if "\r" in text:
        lines = [ln[:-1] if ln.endswith("\r") else ln for ln in lines]
    if lines:
        lines[0] = lines[0].lstrip("\ufeff\xef\xbb\xbf")
    return lines


def _where(path, lineno: int, compressed: bool) -> str:
    return f"{path}, line {lineno}{' of the decompressed RINEX text' if compressed else ''}"


def _float_field(s: str) -> float:
    """A Fortran-style real (``D`` or ``E`` exponent); NaN for a blank field; ValueError if bad,
    including the tokens ``nan``, ``inf``, ``infinity`` and digit groups (``1_0``) that Python's
    ``float`` takes but RINEX never writes."""
    s = s.strip()
    if not s:
        return math.nan
    return strict_float(s.replace("D", "E").replace("d", "e"))


def _three_floats(body: str) -> tuple[float, float, float]:
    """Three reals of a 3F14.4 header field; split on blanks, as some writers use 15 columns."""
    parts = body[:60].split()
    if len(parts) != 3:
        raise ValueError(body)
    return tuple(_float_field(x) for x in parts)


def _parse_version_line(lines: list[str], path, compressed: bool, kind: str) -> tuple[float, str, str]:
    if not lines:
        raise CdgpsError(f"{path}: empty file; expected a RINEX {kind} file")
    first = lines[0]
    if first[60:80].strip() != "RINEX VERSION / TYPE":
        raise CdgpsError(
            f"{_where(path, 1, compressed)}: not a RINEX file: the first line must end with the label "
            f"'RINEX VERSION / TYPE' in columns 61-80 (got {first[:80]!r})"
        )
    try:
        version = float(first[:9])
    except ValueError:
        raise CdgpsError(f"{_where(path, 1, compressed)}: cannot read the RINEX version number from {first[:9]!r}") from None
    return version, first[20:21].upper(), first[40:41].upper()


#: the newest RINEX major version read, per kind of file: a 4.xx observation file is laid out as a 3.05 one (its new
#: header records, DOI, LICENSE OF USE, STATION INFORMATION, are passed over); 4.xx navigation records are not read
_RINEX_BELOW = {"observation": 5.0, "navigation": 5.0}


def _check_version(version: float, path, kind: str) -> None:
    below = _RINEX_BELOW[kind]
    if not (2.0 <= version < below):
        raise CdgpsError(
            f"{path}: RINEX version {version:.2f} is not supported for {kind} files (supported: 2.xx, i.e. 2.10/2.11, "
            f"{'3.xx and 4.xx' if below > 4 else 'and 3.xx'}); convert it with gfzrnx or teqc"
        )


def _range_note(exc: ValueError) -> str:
    """': month must be in 1..12' for a date or time field out of its range (datetime's or
    :func:`~cdgps_cli.core.gps_time.check_time_of_day`'s words), '' for a field that is no number."""
    text = str(exc)
    return f": {text}" if ("must be in" in text or "out of range" in text) else ""


def _sat_id(s: str, version: float) -> str:
    """Normalise a satellite field ('G05', 'G 5', ' 5' in RINEX 2) to 'G05'; ValueError if bad."""
    if len(s) == 3 and s[0] in _SYSTEM_LETTERS and "0" <= s[1] <= "9" and "0" <= s[2] <= "9":
        return s                                           # already 'G05' (what the steps below give it)
    s = s.rstrip()
    if len(s) < 2:
        raise ValueError(s)
    s = s.rjust(3)
    system = s[0] if s[0] != " " else ("G" if version < 3 else "")
    if system not in "GRESJCIM" or not system:
        raise ValueError(s)
    prn = s[1:3].strip()
    if not prn.isdigit():
        raise ValueError(s)
    return f"{system}{int(prn):02d}"


# ----------------------------------------------------------------------------------------------
# observation files
# ----------------------------------------------------------------------------------------------


class _ObsHeader:
    """Mutable header state, updated by the header and by event records (flags 3 and 4)."""

    def __init__(self, path, version: float, compressed: bool):
        self.path = path
        self.version = version
        self.compressed = compressed
        self.info: dict = {
            "path": str(path),
            "version": version,
            "file_type": "O",
            "satellite_system": None,
            "marker_name": None,
            "marker_number": None,
            "observer": None,
            "agency": None,
            "receiver_number": None,
            "receiver_type": None,
            "receiver_version": None,
            "antenna_number": None,
            "antenna_type": None,
            "approx_position_xyz_m": None,
            "antenna_delta_hen_m": None,
            "wavelength_factor_l1": None,
            "interval_s": None,
            "obs_types": {},
            "time_first_obs_gps_s": None,
            "time_first_obs": None,
            "time_last_obs_gps_s": None,
            "time_system": None,
            "leap_seconds": None,
            "rcv_clock_offset_applied": None,
            "signal_strength_unit": None,
            "scale_factors": {},
            "comments": [],
        }
        self._pending_types: tuple[str, int, list[str]] | None = None  # (system, count, types so far)
        self._pending_scale: tuple[str, int, int, list[str]] | None = None

    def error(self, lineno: int, what: str) -> CdgpsError:
        return CdgpsError(f"{_where(self.path, lineno, self.compressed)}: {what}")

    def apply(self, line: str, lineno: int) -> str:
        """Apply one header line; return its label."""
        label = line[60:80].strip()
        read = _HEADER_READERS.get(label)
        if read is not None:                               # a label the reader keeps something of
            self._read(read, line, label, lineno)
        return label

    def apply_header(self, lines: list[str]) -> int | None:
        """Apply the header lines ``lines[1:]`` (as :meth:`apply`, line by line) up to the first one
        labelled END OF HEADER; its index, None if there is none."""
        readers = _HEADER_READERS
        for i in range(1, len(lines)):
            line = lines[i]
            label = line[60:80].strip()
            read = readers.get(label)
            if read is not None:
                self._read(read, line, label, i + 1)
            elif label == "END OF HEADER":
                return i
        return None

    def _read(self, read, line: str, label: str, lineno: int) -> None:
        """``read`` (a :data:`_HEADER_READERS` method) of the header line ``line``; a malformed one is an
        error naming the file, line number and label."""
        try:
            read(self, line[:60], lineno)
        except CdgpsError:
            raise
        except (ValueError, IndexError):
            raise self.error(lineno, f"malformed header line '{label}': {line.rstrip()!r}") from None

    def _comment(self, body: str, lineno: int) -> None:
        self.info["comments"].append(body.rstrip())

    def _marker_name(self, body: str, lineno: int) -> None:
        self.info["marker_name"] = body.strip()

    def _marker_number(self, body: str, lineno: int) -> None:
        self.info["marker_number"] = body.strip()

    def _observer(self, body: str, lineno: int) -> None:
        self.info["observer"], self.info["agency"] = body[:20].strip(), body[20:60].strip()

    def _receiver(self, body: str, lineno: int) -> None:
        info = self.info
        info["receiver_number"] = body[:20].strip()
        info["receiver_type"] = body[20:40].strip()
        info["receiver_version"] = body[40:60].strip()

    def _antenna(self, body: str, lineno: int) -> None:
        self.info["antenna_number"] = body[:20].strip()
        self.info["antenna_type"] = body[20:40].strip()

    def _position(self, body: str, lineno: int) -> None:
        self.info["approx_position_xyz_m"] = _three_floats(body)

    def _delta_hen(self, body: str, lineno: int) -> None:
        self.info["antenna_delta_hen_m"] = _three_floats(body)

    def _wavelength_fact(self, body: str, lineno: int) -> None:
        nsat_list = body[12:18].strip()
        if not nsat_list or int(nsat_list) == 0:          # default factors (no satellite list)
            self.info["wavelength_factor_l1"] = int(body[:6])

    def _interval(self, body: str, lineno: int) -> None:
        self.info["interval_s"] = float(body[:10])

    def _first_obs(self, body: str, lineno: int) -> None:
        info = self.info
        y, mo, d, h, mi = (int(body[i : i + 6]) for i in (0, 6, 12, 18, 24))
        sec = float(body[30:43])
        info["time_system"] = body[48:51].strip() or None
        if info["time_system"] not in (None, *OBS_TIME_SYSTEMS):
            raise self.error(lineno, f"time system {info['time_system']!r} in 'TIME OF FIRST OBS' is not read (epochs "
                                     f"in {', '.join(OBS_TIME_SYSTEMS)} time are)")
        info["time_first_obs_gps_s"] = gps_seconds(y, mo, d, h, mi, sec)
        info["time_first_obs"] = f"{y:04d}-{mo:02d}-{d:02d} {h:02d}:{mi:02d}:{sec:010.7f}"

    def _leap_seconds(self, body: str, lineno: int) -> None:
        self.info["leap_seconds"] = int(body[:6])

    def _clock_applied(self, body: str, lineno: int) -> None:
        self.info["rcv_clock_offset_applied"] = bool(int(body[:6]))

    def _strength_unit(self, body: str, lineno: int) -> None:
        self.info["signal_strength_unit"] = body[:20].strip() or None

    def _types_v2(self, body: str, lineno: int) -> None:
        if self._pending_types is None or body[:6].strip():
            n = int(body[:6])
            self._pending_types = ("*", n, [])
        system, n, types = self._pending_types
        types.extend(body[6:60].split())
        if len(types) > n:
            raise self.error(lineno, f"'# / TYPES OF OBSERV' announces {n} types but lists {len(types)}")
        if len(types) == n:
            self.info["obs_types"] = {"*": list(types)}
            self._pending_types = None

    def _types_v3(self, body: str, lineno: int) -> None:
        if body[:1].strip():
            system = body[0].upper()
            n = int(body[3:6])
            self._pending_types = (system, n, [])
        elif self._pending_types is None:
            raise self.error(lineno, "continuation of 'SYS / # / OBS TYPES' without a first line")
        system, n, types = self._pending_types
        types.extend(body[7:60].split())
        if len(types) > n:
            raise self.error(lineno, f"'SYS / # / OBS TYPES' for {system} announces {n} types but lists {len(types)}")
        if len(types) == n:
            self.info["obs_types"][system] = _beidou_b1i_types(types, self.version, self.info) if system == "C" else list(types)
            self._pending_types = None

    def _scale_v3(self, body: str, lineno: int) -> None:
        if body[:1].strip():
            system = body[0].upper()
            factor = int(body[2:6])
            n = int(body[8:10]) if body[8:10].strip() else 0
            self._pending_scale = (system, factor, n, [])
        elif self._pending_scale is None:
            raise self.error(lineno, "continuation of 'SYS / SCALE FACTOR' without a first line")
        system, factor, n, types = self._pending_scale
        types.extend(body[10:60].split())
        if n == 0:
            self.info["scale_factors"].setdefault(system, {})["*"] = factor
            self._pending_scale = None
        elif len(types) >= n:
            of_system = self.info["scale_factors"].setdefault(system, {})
            for t in types:
                of_system[t] = factor
            self._pending_scale = None

    def finish(self, lineno: int) -> None:
        if self._pending_types is not None:
            raise self.error(lineno, f"observation types list incomplete ({len(self._pending_types[2])} of {self._pending_types[1]})")


def _beidou_b1i_types(types: list[str], version: float, info: dict) -> list[str]:
    """BeiDou observation types with B1I as RINEX 3.03 on names it (band 2): RINEX 3.02 named B1I band 1 ("C1I",
    "L1I", "C1Q", "C1X" …; a Trimble NetR9's 3.02 file), which 3.03 gave to B1C (attributes D, P, X).  Band-1 types
    with attribute I or Q, and X below 3.03, become band 2 unless the file also lists that name; the renames are
    noted in ``info["beidou_b1i_band1"]`` (RTKLIB reads both bands as B1)."""
    out, renamed = list(types), {}
    for i, t in enumerate(types):
        if len(t) == 3 and t[1] == "1" and (t[2] in "IQ" or (t[2] == "X" and version < 3.03)):
            new = f"{t[0]}2{t[2]}"
            if new not in types:
                out[i], renamed[t] = new, new
    if renamed:
        info["beidou_b1i_band1"] = renamed
    return out


_HEADER_READERS = {
    "COMMENT": _ObsHeader._comment, "MARKER NAME": _ObsHeader._marker_name,
    "MARKER NUMBER": _ObsHeader._marker_number, "OBSERVER / AGENCY": _ObsHeader._observer,
    "REC # / TYPE / VERS": _ObsHeader._receiver, "ANT # / TYPE": _ObsHeader._antenna,
    "APPROX POSITION XYZ": _ObsHeader._position, "ANTENNA: DELTA H/E/N": _ObsHeader._delta_hen,
    "WAVELENGTH FACT L1/2": _ObsHeader._wavelength_fact, "INTERVAL": _ObsHeader._interval,
    "TIME OF FIRST OBS": _ObsHeader._first_obs, "LEAP SECONDS": _ObsHeader._leap_seconds,
    "RCV CLOCK OFFS APPL": _ObsHeader._clock_applied, "SIGNAL STRENGTH UNIT": _ObsHeader._strength_unit,
    "# / TYPES OF OBSERV": _ObsHeader._types_v2, "SYS / # / OBS TYPES": _ObsHeader._types_v3,
    "SYS / SCALE FACTOR": _ObsHeader._scale_v3,
}
"""Header label → the :class:`_ObsHeader` method reading it (one look-up per line, not a chain of tests)."""


class _GpsL1Columns:
    """Where the GPS L1 phase / code / SNR sit in a record, for the current observation types."""

    def __init__(self, hdr: _ObsHeader, lineno: int):
        info = hdr.info
        v3 = hdr.version >= 3
        types = info["obs_types"].get("*" if not v3 else "G")
        if not types and v3 and info["obs_types"] and getattr(hdr, "gps_l1_optional", False):
            # a RINEX 3 file without GPS, read for a run anchored on another system: no GPS rows
            self.types, self.n, self.phase, self.code, self.snr = [], 0, None, None, None
            self.i_phase = self.i_code = self.i_snr = -1
            self.scale = {"phase": 1.0}
            info["l1_obs_types"] = None
            return
        if not types:
            if not info["obs_types"]:
                raise CdgpsError(f"{hdr.path}: the header lists no observation types ('# / TYPES OF OBSERV' or 'SYS / # / OBS TYPES')")
            systems = ", ".join(sorted(info["obs_types"]))
            raise CdgpsError(f"{hdr.path}: no GPS observation types in the header (this file has observation types for: {systems}); GPS L1 carrier phase is needed")
        self.types = types
        self.n = len(types)
        if not v3:
            phase = "L1" if "L1" in types else None
            code = next((c for c in ("C1", "P1") if c in types), None)
            snr = "S1" if "S1" in types else None
        else:
            phase = next((c for c in _L1_TYPES["L"] if c in types), None)
            attr = phase[2] if phase else "C"
            code = next((c for c in (f"C1{attr}", *_L1_TYPES["C"]) if c in types), None)
            snr = next((c for c in (f"S1{attr}", *_L1_TYPES["S"]) if c in types), None)
        if phase is None:
            where = "'# / TYPES OF OBSERV'" if not v3 else "'SYS / # / OBS TYPES' for G"
            raise CdgpsError(
                f"{hdr.path}: no GPS L1 carrier-phase observation type ({'L1' if not v3 else 'L1C/L1W/L1P/…'}) in {where}; "
                f"the file has: {' '.join(types)}. Carrier-phase differential GPS needs L1 phase."
            )
        self.phase, self.code, self.snr = phase, code, snr
        self.i_phase = types.index(phase)
        self.i_code = types.index(code) if code else -1
        self.i_snr = types.index(snr) if snr else -1
        scales = info["scale_factors"].get("G", {})
        default = scales.get("*", 1)
        self.scale = {k: float(scales.get(t, default)) for k, t in (("phase", phase), ("code", code), ("snr", snr)) if t}
        info["l1_obs_types"] = {"phase": phase, "pseudorange": code, "snr": snr}


def _obs_field(rec: str, k: int, col0: int) -> tuple[str, str, str]:
    c = col0 + 16 * k
    return rec[c : c + 14], rec[c + 14 : c + 15], rec[c + 15 : c + 16]


def _flag_digit(ch: str) -> int:
    if ch == "" or ch == " ":
        return 0
    if ch.isdigit():
        return int(ch)
    raise ValueError(ch)


#: read the body with the byte-level block-wise reader (False: line by line, the reference it is tested against)
FAST_PARSE = True


def read_rinex_obs(path: str | Path, *, gps_l1_optional: bool = False,
                   block_epochs: int = RINEX_BLOCK_EPOCHS, read: tuple[bytes, bool] | None = None) -> tuple[dict, pd.DataFrame]:
    """Read a RINEX 2.10/2.11 or 3.0x observation file (plain, compressed or Hatanaka).

    Parameters
    ----------
    path : str or Path
        The file.  Compression is recognised from its content: gzip, Unix compress (``.Z``),
        bzip2, zip and Hatanaka/Compact RINEX (``.crx``, ``.??d``) are decompressed in memory.

    Returns
    -------
    header : dict
        ``version``, ``marker_name``, ``marker_number``, ``receiver_type``/``_number``/``_version``,
        ``antenna_type``/``_number``, ``approx_position_xyz_m`` (ECEF, m, or None),
        ``antenna_delta_hen_m`` (height/east/north of the antenna reference point above the
        marker, m), ``interval_s``, ``obs_types`` (``{"*": [...]}`` in RINEX 2, one list per system
        letter in RINEX 3), ``l1_obs_types`` (which types fill the L1 columns),
        ``time_first_obs_gps_s`` / ``time_first_obs`` / ``time_system``, ``leap_seconds`` (or None),
        ``rcv_clock_offset_applied``, ``scale_factors``, ``comments``; and a summary of the data:
        ``n_epochs`` (observation epochs, flags 0 and 1), ``n_epochs_power_failure`` (flag 1),
        ``n_gps_epochs``, ``gps_satellites``, ``satellites_by_system`` and
        ``n_records_by_system`` (satellite-epoch records per system letter — only GPS rows are
        returned, the others are counted here), ``time_last_obs_gps_s``, and ``events`` (one dict
        per special record: ``line``, ``flag``, ``time_gps_s`` (NaN if blank), ``labels`` of the
        header lines it carried; flags 2 start moving, 3 new site occupation, 4 header
        information, 5 external event, 6 cycle-slip records).  Header lines inside flag-3/4 events
        (new marker name, position, observation types …) update the header for later epochs.  An epoch written
        twice in a row (the same time tag) is read once, the first record; ``repeated_epochs`` (only when there
        is one) lists each repeat's ``time_gps_s``, ``line`` and ``first_line``.  An epoch earlier than one before
        it is read, the table sorted by time (a time read twice keeping its first record), and listed in
        ``epochs_out_of_order`` (``time_gps_s``, ``line``, ``after_line``), as ``rtk`` reads such files.
    obs : DataFrame
        One row per observation epoch (flag 0 or 1) and GPS satellite with an L1 phase or
        pseudorange, sorted by time then satellite; columns :data:`OBS_COLUMNS`:

        ``time_gps_s`` (float64, GPS s since 1980-01-06, receiver time tag), ``sat`` ("G05"),
        ``phase_l1_cycles`` (float64, NaN if blank), ``lli_l1`` (int64 loss-of-lock indicator of
        the phase, 0 if blank; bit 0 = lost lock / possible slip, bit 1 = half-cycle ambiguity /
        opposite wavelength factor, bit 2 = under anti-spoofing or half-cycle slip possible),
        ``ssi_l1`` (int64 signal strength indicator 1-9 of the phase, 0 if blank),
        ``pseudorange_l1_m`` (float64, from C1/C1C, or P1/C1W… if there is no C/A code),
        ``snr_l1_dbhz`` (float64 from S1/S1C if the file has it, else NaN; RINEX 2 does not fix
        its unit, most receivers write dB-Hz), ``rx_clock_offset_s`` (float64 receiver clock
        offset from the epoch line, NaN if absent), ``epoch_flag`` (int64, 0 OK or 1 power
        failure since the previous epoch).

    gps_l1_optional : bool, default False
        Accept a RINEX 3 file without GPS observation types (a run anchored on another system,
        :func:`~cdgps_cli.core.signals.anchor_signal`): ``obs`` is then empty and the header's
        ``l1_obs_types`` None.
    block_epochs : int, default :data:`~cdgps_cli.config.options.RINEX_BLOCK_EPOCHS`
        Epochs whose records are converted at a time (memory of a block, not of the file, beyond
        the file's bytes); the result does not depend on it.
    read : (bytes, bool), optional
        The file's (decompressed) bytes and whether it was compressed, when already at hand (an hour of a long
        file with its header: :mod:`cdgps_cli.io.rinex_hours`); ``path`` then only names it.

    Raises
    ------
    CdgpsError
        Unreadable or non-RINEX file, unsupported version, a navigation file, no GPS L1 phase
        observation type (the message lists the types the file has), a malformed line (file and
        line number), a time system other than :data:`OBS_TIME_SYSTEMS` (epochs in BeiDou or GLONASS time are
        returned in GPS time, :func:`in_gps_time`).
    """
    p = _as_path(path)
    if block_epochs < 1:
        raise ValueError(f"block_epochs must be >= 1, got {block_epochs}")
    read = _read_bytes(p) if read is None else read
    if FAST_PARSE:
        data, compressed = read
        try:
            return _noting_end_padding(read[0], in_gps_time(*_read_obs_fast(p, data, compressed, gps_l1_optional,
                                                                              block_epochs)))
        except Unsupported:
            pass                      # the line-by-line reader: the same table, or the error naming the line
    lines, compressed = _split_lines(read[0]), read[1]
    return _noting_end_padding(read[0], in_gps_time(*_read_obs_lines(p, lines, compressed, gps_l1_optional)))


def _noting_end_padding(data: bytes, result: tuple) -> tuple:
    """A reader's (header, table) with ``end_padded_lines`` in the header when :func:`_with_the_last_blank_lines`
    gave the file back lines at its end."""
    n = getattr(data, "end_padded_lines", 0)
    if n:
        result[0]["end_padded_lines"] = int(n)
    for key in ("repeated_headers", "decompress_notes"):
        if getattr(data, key, ()):
            result[0][key] = list(getattr(data, key))
    return result


_COLUMN_INDEXES: dict = {}
_STR_ARRAY_TYPES: dict = {}


def _frame(columns: dict, copy: bool = False) -> pd.DataFrame:
    """``pd.DataFrame(columns, copy=copy)`` of 1-D arrays of one length (object arrays of str become
    pandas' str columns, as there), for a reader's table: built by ``DataFrame._from_arrays`` with a
    column index made once per column set, which skips the dict constructor's per-call set-up (≈ 30 %
    of building a table of a few rows; a 7 kB file's table).  Columns that are all numpy numbers,
    booleans, numpy str or str objects are handed over as pandas stores them (:func:`_stored_arrays`),
    without its per-column checks (``verify_integrity=False``: ≈ 100 µs instead of ≈ 250 µs for a
    9-column table); anything else goes through those checks.  Falls back to the constructor if the pandas at
    hand lacks that method or refuses the arrays."""
    names = tuple(columns)
    if len(names) == 0:
        return pd.DataFrame(columns, copy=copy)
    arrays = [np.array(v) if copy else v for v in columns.values()]
    idx = _COLUMN_INDEXES.get(names)
    if idx is None:
        idx = _COLUMN_INDEXES[names] = pd.DataFrame(columns=list(names)).columns   # the dtype the constructor gives
    try:
        stored = _stored_arrays(arrays)
        return pd.DataFrame._from_arrays(stored or arrays, columns=idx, index=pd.RangeIndex(len(arrays[0])),
                                         verify_integrity=stored is None)
    except (AttributeError, TypeError, ValueError):
        return pd.DataFrame(columns, copy=copy)


def _frame_as_given(columns: dict) -> pd.DataFrame:
    """``pd.DataFrame(columns, copy=False)``'s table of 1-D arrays of one length: each column its own block,
    holding the array it was given (numbers, booleans) or the str array made of it, as there; built from
    :func:`_stored_arrays` without the constructor's per-column checks (≈ 220 µs instead of ≈ 520 µs for a
    14-column table of 3842 rows).  Anything else, or a pandas without these internals: the constructor."""
    names = tuple(columns)
    stored = _stored_arrays(list(columns.values())) if names and _arrays_to_mgr is not None else None
    if stored is not None:
        idx = _COLUMN_INDEXES.get(names)
        if idx is None:
            idx = _COLUMN_INDEXES[names] = pd.DataFrame(columns=list(names)).columns
        try:
            mgr = _arrays_to_mgr(stored, idx, pd.RangeIndex(len(stored[0])), verify_integrity=False, consolidate=False)
            return pd.DataFrame._from_mgr(mgr, axes=mgr.axes)
        except (AttributeError, TypeError, ValueError):
            pass
    return pd.DataFrame(columns, copy=False)


try:                                            # the block manager of the dict constructor
    from pandas.core.internals.construction import arrays_to_mgr as _arrays_to_mgr
except ImportError:                             # pragma: no cover - another pandas: the constructor
    _arrays_to_mgr = None


def _stored_arrays(arrays: list) -> list | None:
    """The column arrays as the DataFrame constructor stores them (its ``sanitize_array``), or None
    when one is not a 1-D numpy array of numbers, booleans (kept as they are), of numpy str (``<U``) or
    of ``str`` objects only (the constructor's str extension array, made as it makes it; an object
    column holding anything else, or no rows, is left to the constructor's checks)."""
    out = []
    for a in arrays:
        if type(a) is not np.ndarray or a.ndim != 1:
            return None
        kind = a.dtype.kind
        if kind in "fiub" and a.dtype.isnative:
            out.append(a)
        elif kind == "U" or (kind == "O" and len(a) and _is_str_array(a)):
            made = _str_array(a)
            if made is None:
                return None
            out.append(made)
        else:
            return None
    return out


def _str_array(a: np.ndarray):
    """The str extension array the DataFrame constructor makes of a numpy str array or an object array
    holding only ``str`` (``StringDtype(na_value=nan)``'s array from the sequence, as pandas' object
    inference does); None when pandas does not infer a str dtype (``future.infer_string`` off, pandas < 3)."""
    if not _using_string_dtype():
        return None
    dtype = pd.StringDtype(na_value=np.nan)
    cls = _STR_ARRAY_TYPES.get(dtype.storage)
    if cls is None:
        cls = _STR_ARRAY_TYPES[dtype.storage] = dtype.construct_array_type()
    return cls._from_sequence(a, dtype=dtype)


try:                                            # pandas' own tests of what its constructor infers
    from pandas._config import using_string_dtype as _using_string_dtype
    from pandas._libs.lib import is_string_array as _is_string_array

    def _is_str_array(a: np.ndarray) -> bool:
        """Every element of the object array is a ``str`` (C loop)."""
        return bool(_is_string_array(a, skipna=False))
except ImportError:                             # pragma: no cover - another pandas: the constructor's checks
    def _using_string_dtype() -> bool:
        return False

    def _is_str_array(a: np.ndarray) -> bool:
        return False


def _obs_header(p: Path, lines: list[str], compressed: bool, gps_l1_optional: bool):
    """(header state, index of the END OF HEADER line, GPS L1 columns) of an observation file."""
    version, ftype, system = _parse_version_line(lines, p, compressed, "observation")
    if ftype != "O":
        kind = {"N": "navigation", "G": "GLONASS navigation", "H": "SBAS navigation", "M": "meteorological", "C": "clock"}.get(ftype, f"type {ftype!r}")
        raise CdgpsError(f"{p}: this is a RINEX {kind} file, not an observation file (RINEX VERSION / TYPE says {ftype!r})")
    _check_version(version, p, "observation")
    hdr = _ObsHeader(p, version, compressed)
    hdr.gps_l1_optional = gps_l1_optional
    hdr.info["satellite_system"] = system or "G"
    end = hdr.apply_header(lines)
    if end is None:
        raise CdgpsError(f"{p}: no 'END OF HEADER' line; truncated or not a RINEX observation file")
    hdr.finish(end + 1)
    return hdr, end, _GpsL1Columns(hdr, end + 1)


#: the time systems of observation epochs the readers take (RINEX 3.05 'TIME OF FIRST OBS'), all returned in GPS time:
#: Galileo's GST and QZSST keep GPS time to the second, BDT = GPST − 14 s, GLONASST = UTC(SU) + 3 h with UTC's leap
#: seconds (IRNSS time is not read)
OBS_TIME_SYSTEMS = ("GPS", "GAL", "QZS", "BDT", "GLO")
#: the time system of a file whose 'TIME OF FIRST OBS' names none: a GLONASS or a BeiDou file's own (RINEX 3.05 §5.4),
#: else GPS
_DEFAULT_TIME_SYSTEMS = {"R": "GLO", "C": "BDT"}


def _epoch_as_written(hdr: _ObsHeader, t_s: float) -> str:
    """'epoch 2024-01-01 00:04:10 GPST' of an epoch read at ``t_s`` (its calendar time as the file writes it, in the
    file's time system): where in a long file a malformed record lies, besides its line."""
    system = epoch_time_system(hdr.info)
    text = gps_time_str(t_s)
    return f"epoch {text if system == 'GPS' else text.replace(' GPST', ' ' + system)}"


def epoch_time_system(info: dict) -> str:
    """The time system of an observation file's epoch tags: its header's (``time_system``), else its satellite
    system's default (:data:`_DEFAULT_TIME_SYSTEMS`)."""
    return info.get("time_system") or _DEFAULT_TIME_SYSTEMS.get(info.get("satellite_system") or "G", "GPS")


def to_gps_time_s(t_s, system: str) -> np.ndarray:
    """GPS seconds of epoch tags ``t_s`` read in time system ``system`` (as :func:`gps_seconds` of their date and time
    fields): BDT + 14 s; GLONASST − 3 h + the leap seconds GPS − UTC in force; GPS, GST and QZSST as they are."""
    t = np.asarray(t_s, dtype=np.float64)
    if system == "BDT":
        return t + GPS_MINUS_BDT_S
    if system == "GLO":
        # the leap seconds in force at that UTC instant: the table is in GPS time, where a leap second that takes
        # effect at UTC u falls at u + the new count (one more than the count before it)
        utc = t - GLONASST_MINUS_UTC_S
        return glonasst_to_gps_s(t, gps_minus_utc_s(utc + gps_minus_utc_s(utc) + 1))
    return t


def in_gps_time(info: dict, obs: pd.DataFrame) -> tuple[dict, pd.DataFrame]:
    """An observation reader's (header, table) with every epoch time in GPS time (:func:`to_gps_time_s`): the table's
    ``time_gps_s``, the header's first and last epochs and the times of its events, repeated and out-of-order epochs;
    ``epochs_time_system`` names a conversion made.  A file in GPS, Galileo or QZSS time is returned as it is."""
    system = epoch_time_system(info)
    if system not in ("BDT", "GLO"):
        return info, obs
    obs["time_gps_s"] = to_gps_time_s(obs["time_gps_s"].to_numpy(), system)
    for key in ("time_first_obs_gps_s", "time_last_obs_gps_s"):
        if info.get(key) is not None:
            info[key] = float(to_gps_time_s(info[key], system))
    for key in ("events", "repeated_epochs", "epochs_out_of_order"):
        for ev in info.get(key) or ():
            ev["time_gps_s"] = float(to_gps_time_s(ev["time_gps_s"], system))
    info["epochs_time_system"] = f"{system} (converted to GPS time)"
    return info, obs


def _read_obs_lines(p: Path, lines: list[str], compressed: bool, gps_l1_optional: bool):
    """:func:`read_rinex_obs` line by line (the reference; every error names its line)."""
    hdr, end, cols = _obs_header(p, lines, compressed, gps_l1_optional)
    if hdr.version < 3:
        rows, summary = _parse_obs_v2(lines, end + 1, hdr, cols)
    else:
        rows, summary = _parse_obs_v3(lines, end + 1, hdr, cols)
    return _obs_result(p, hdr, summary, _rows_arrays(rows), None)


def _obs_result(p: Path, hdr: _ObsHeader, summary: dict, cols_arr: dict, sorted_info):
    """(header, table) from the summary and the row arrays (file order; sorted here unless
    ``sorted_info`` = (GPS satellites, number of GPS epochs) says they already are)."""
    info = hdr.info
    info.update(summary)
    # the fast reader's arrays are its own: the table takes them without a copy (half the peak memory)
    obs = _frame({name: cols_arr.pop(k) for k, name in _ROW_COLUMNS}, copy=sorted_info is None)   # OBS_COLUMNS' order
    if sorted_info is None:
        obs = obs.sort_values(["time_gps_s", "sat"], kind="stable").reset_index(drop=True)
        if info.get("epochs_out_of_order"):          # an epoch written again out of order: its first record
            obs = obs[~obs.duplicated(["time_gps_s", "sat"], keep="first")].reset_index(drop=True)
        info["gps_satellites"] = sorted(obs["sat"].unique().tolist())
        info["n_gps_epochs"] = int(obs["time_gps_s"].nunique())
    else:
        info["gps_satellites"], info["n_gps_epochs"] = sorted_info
    if len(obs) == 0 and info["n_epochs"] == 0:
        raise CdgpsError(f"{p}: no observation epochs after the header")
    return info, obs


def _split_header(data: bytes) -> tuple[list[str], int]:
    """(the header's lines, as :func:`_split_lines` gives them, up to END OF HEADER; the byte offset
    of the body); Unsupported if the first 'END OF HEADER' in the bytes is not that line's label."""
    at = data.find(b"END OF HEADER")
    if at < 0:
        raise Unsupported("no END OF HEADER")
    nl = data.find(b"\n", at)
    body_at = len(data) if nl < 0 else nl + 1
    head = _split_lines(data[:body_at])
    if head[-1][60:80].strip() != "END OF HEADER":
        raise Unsupported("END OF HEADER")
    return head, body_at


def _read_obs_fast(p: Path, data: bytes, compressed: bool, gps_l1_optional: bool, block_epochs: int):
    """:func:`read_rinex_obs` from the bytes: only the header is split into lines, the body is read
    by :mod:`cdgps_cli.io.rinex_body` in blocks of ``block_epochs`` epochs; Unsupported for a body
    that reader does not take exactly as the line-by-line one."""
    head, body_at = _split_header(data)
    hdr, end, cols = _obs_header(p, head, compressed, gps_l1_optional)
    lines = _body.BodyLines(data, body_at)
    layouts = [cols]
    if hdr.version >= 3:
        ep, sats_raw, events = _body.epochs_v3(lines), None, []
        ep["segment"] = np.zeros(ep["line"].size, dtype=np.int64)
        rec0 = ep["line"] + 1
    else:
        ep, sats_raw, events = _body.epochs_v2(lines, max(1, -(-cols.n // 5)), _event_reader(hdr, layouts))
        rec0, ep["line"] = ep["line"], ep["epoch_line"]
    obs_ep = (ep["flag"] != 6).nonzero()[0]               # (method calls: numpy's wrappers cost µs each)
    t = ep["time_gps_s"]
    t_obs = t[obs_ep]
    if obs_ep.size == 0 or (t_obs[1:] <= t_obs[:-1]).any():
        raise Unsupported("epoch order")          # (a repeated epoch: the line-by-line reader keeps the first)
    summary = {"n_epochs": int(obs_ep.size), "n_epochs_power_failure": int((ep["flag"] == 1).sum())}
    rows, by_sys, counts = _obs_blocks(lines, hdr, layouts, ep, rec0, obs_ep, sats_raw, block_epochs)
    del lines, sats_raw
    summary["satellites_by_system"] = {k: sorted(v) for k, v in sorted(by_sys.items())}
    summary["n_records_by_system"] = dict(sorted(counts.items()))
    summary["time_last_obs_gps_s"] = float(t[obs_ep[-1]])
    if hdr.version >= 3:
        events = [{"line": int(ep["line"][e]), "flag": 6, "time_gps_s": float(t[e]), "labels": []}
                  for e in (ep["flag"] == 6).nonzero()[0].tolist()]
    for ev in events:
        ev["line"] += end + 2                              # body line index -> file line number
    summary["events"] = events
    return _obs_result(p, hdr, summary, *rows)


class _Events:
    def __init__(self, events: list):
        self.events = events


def _event_reader(hdr: _ObsHeader, layouts: list):
    """The ``special`` callback of :func:`rinex_body.epochs_v2`: applies an event's header lines as
    the line-by-line reader does; flags 3/4 start a new layout (appended to ``layouts``).  Any error:
    Unsupported (the line-by-line reader then names the line)."""
    def special(texts, flag, t, i, events):
        try:
            _special_records(texts, 0, len(texts), hdr, flag, t, _Events(events), i)
            if flag in (3, 4):
                new, old = _GpsL1Columns(hdr, i), layouts[-1]
                same = (new.types, new.phase, new.code, new.snr, new.scale) == (old.types, old.phase, old.code, old.snr, old.scale)
                if same:                                  # e.g. a splice comment: the same layout goes on
                    return None
                layouts.append(new)
                return max(1, -(-new.n // 5))
        except CdgpsError:
            raise Unsupported("event") from None
        return None
    return special


def _obs_blocks(lines, hdr, layouts, ep, rec0, obs_ep, sats_raw, block_epochs):
    """The GPS rows of the observation epochs ``obs_ep``, converted ``block_epochs`` epochs at a
    time (and layout by layout): ((row arrays sorted by time and satellite, (GPS satellites, GPS
    epochs)), satellites by system, records by system)."""
    v3 = hdr.version >= 3
    names: dict[str, int] = {}
    by_sys: dict[str, set] = {}
    counts: dict[str, int] = {}
    chunks = []
    if not v3:                                             # v2: offset of each epoch's satellites in sats_raw
        sat_at = np.concatenate([[0], np.cumsum(ep["nsat"][obs_ep])])
    seg = ep["segment"][obs_ep]
    for s_i, cols in enumerate(layouts):
        where = (seg == s_i).nonzero()[0]
        if where.size == 0:
            continue
        per = 1 if v3 else max(1, -(-cols.n // 5))
        p1 = int(where[-1]) + 1
        for a in range(int(where[0]), p1, block_epochs):
            b = min(a + block_epochs, p1)
            e = obs_ep[a:b]
            n = ep["nsat"][e]
            e_rec = np.arange(a, b).repeat(n)                  # index into obs_ep of every record
            k = np.arange(e_rec.size) - (n.cumsum() - n).repeat(n)
            rec_line = rec0[e].repeat(n) + k * per
            if v3:
                raw = lines.gather(rec_line, 0, 3)
            else:
                txt = "".join(sats_raw[int(sat_at[a]):int(sat_at[b])])       # 3 characters each
                raw = np.frombuffer(txt.encode("latin-1"), dtype=np.uint8).reshape(-1, 3)
            if raw.shape[0] == 0:
                continue
            uniq, inv = _body.record_sats(raw, lambda x: _sat_id(x, hdr.version))
            uniq = uniq.tolist()
            for s, c in zip(uniq, np.bincount(inv, minlength=len(uniq)).tolist()):
                by_sys.setdefault(s[0], set()).add(s)
                counts[s[0]] = counts.get(s[0], 0) + c
            code = np.array([names.setdefault(s, len(names)) for s in uniq], dtype=np.int64)
            gps = np.array([s[0] == "G" for s in uniq])[inv].nonzero()[0]
            if gps.size:
                chunks.append(_gps_rows(lines, cols, rec_line[gps], e_rec[gps], code[inv[gps]], v3, per))
    return _sorted_rows(chunks, names, ep, obs_ep), by_sys, counts


def _gps_rows(lines, cols, rec_line, e_rec, code, v3, per) -> dict:
    """The rows of the GPS records starting at ``rec_line`` (epoch ``e_rec``, satellite ``code``)."""
    if cols.phase is None:
        raise Unsupported("GPS records without GPS observation types")
    ks = [cols.i_phase] + [k for k in (cols.i_code, cols.i_snr) if k >= 0]
    got = iter(_body.gps_fields_of(lines, rec_line, ks, v3))     # phase, then code and SNR where listed
    phase, ph_flags = next(got)
    nan = np.full(rec_line.size, np.nan)
    code_m = next(got)[0] if cols.i_code >= 0 else nan
    snr = next(got)[0] if cols.i_snr >= 0 else nan
    has_ph = ~np.isnan(phase)
    lli = _body.flag_values(ph_flags[:, 0], has_ph)
    ssi = _body.flag_values(ph_flags[:, 1], has_ph)
    phase, code_m, snr = _unscaled(cols, phase, code_m, snr)
    k = (has_ph | ~np.isnan(code_m)).nonzero()[0]
    return {"e": e_rec[k], "sat": code[k], "phase": phase[k], "lli": lli[k], "ssi": ssi[k],
            "code": code_m[k], "snr": snr[k]}


def _sorted_rows(chunks, names: dict, ep: dict, obs_ep) -> tuple[dict, tuple]:
    """Row arrays of the chunks sorted by (time, satellite) as the stable pandas sort does (times
    strictly increase over ``obs_ep``), and (GPS satellites, number of GPS epochs)."""
    if not chunks:
        return {k: np.asarray([], dtype=dt) for k, dt in _ROW_DTYPES.items()}, ([], 0)
    cat = chunks[0] if len(chunks) == 1 else {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
    chunks.clear()                                         # the blocks' arrays: freed before the table is built
    table = sorted(names)
    rank = np.empty(len(names), dtype=np.int64)
    rank[[names[s] for s in table]] = np.arange(len(table))
    key = cat["e"] * len(names) + rank[cat["sat"]]
    if (key[1:] < key[:-1]).any():
        order = np.argsort(key, kind="stable")
        cat = {k: v[order] for k, v in cat.items()}
    e = obs_ep[cat["e"]]
    present = np.bincount(cat["sat"], minlength=len(names)).nonzero()[0]     # np.unique's values, sorted
    sat_obj = np.array([None] * len(names), dtype=object)
    sat_obj[:] = [s for s, _ in sorted(names.items(), key=lambda kv: kv[1])]
    n_ep = int(np.count_nonzero(cat["e"][1:] != cat["e"][:-1]) + 1)
    del cat["e"]
    rows = {"t": ep["time_gps_s"][e], "sat": sat_obj[cat.pop("sat")], "phase": cat.pop("phase"),
            "lli": cat.pop("lli").astype(np.int64, copy=False), "ssi": cat.pop("ssi").astype(np.int64, copy=False),
            "code": cat.pop("code"), "snr": cat.pop("snr"), "clk": ep["clk"][e].astype(np.float64, copy=False),
            "flag": ep["flag"][e].astype(np.int64, copy=False)}
    gps_sats = sorted(sat_obj[present].tolist())
    return rows, (gps_sats, n_ep)


_ROW_DTYPES = {"t": np.float64, "sat": object, "phase": np.float64, "lli": np.int64, "ssi": np.int64,
               "code": np.float64, "snr": np.float64, "clk": np.float64, "flag": np.int64}
_ROW_COLUMNS = (("t", "time_gps_s"), ("sat", "sat"), ("phase", "phase_l1_cycles"), ("lli", "lli_l1"),
                ("ssi", "ssi_l1"), ("code", "pseudorange_l1_m"), ("snr", "snr_l1_dbhz"),
                ("clk", "rx_clock_offset_s"), ("flag", "epoch_flag"))


def _new_rows() -> dict:
    """Row accumulator: per-column lists of scalars (record by record) and ``"_chunks"``, the
    column arrays already done (bulk blocks and flushed scalars), in file order."""
    rows = {k: [] for k in _ROW_DTYPES}
    rows["_chunks"] = []
    return rows


def _flush_rows(rows: dict) -> None:
    """Move the scalar rows into one chunk of typed arrays (keeps file order with bulk chunks)."""
    if rows["t"]:
        rows["_chunks"].append({k: np.asarray(rows[k], dtype=dt) for k, dt in _ROW_DTYPES.items()})
        for k in _ROW_DTYPES:
            rows[k] = []


def _rows_arrays(rows: dict) -> dict:
    """Every row as one typed array per column, in the order the rows were added."""
    _flush_rows(rows)
    chunks = rows["_chunks"]
    if not chunks:
        return {k: np.asarray([], dtype=dt) for k, dt in _ROW_DTYPES.items()}
    return {k: np.concatenate([c[k] for c in chunks]).astype(dt, copy=False) for k, dt in _ROW_DTYPES.items()}


class _Summary:
    def __init__(self):
        self.n_epochs = 0
        self.n_power = 0
        self.by_system: dict[str, set] = {}
        self.records: dict[str, int] = {}
        self.events: list[dict] = []
        self.last_t = -math.inf
        self.last_line = 0
        self.repeated: list[dict] = []
        self.backwards: list[dict] = []
        self.times: list[float] = []          # (the line-by-line reader's: files the fast one does not take)
        self.first_line: dict = {}            # each epoch time read → the line of its first record

    def epoch_time(self, t: float, lineno: int, hdr: _ObsHeader) -> bool:
        """Whether the epoch at ``t`` (line ``lineno``) is read: False for one whose time was read before (a logger
        that wrote it twice, right after it or further on: the first record is kept, the repeat noted in
        ``repeated``).  An epoch earlier than the latest one before it and not read before is read and noted in
        ``backwards`` (the table is sorted by time)."""
        if t in self.first_line:
            self.repeated.append({"time_gps_s": t, "line": lineno, "first_line": self.first_line[t]})
            return False
        self.first_line[t] = lineno
        self.times.append(t)
        if t < self.last_t:
            self.backwards.append({"time_gps_s": t, "line": lineno, "after_line": self.last_line})
            return True
        self.last_t, self.last_line = t, lineno
        return True

    def sat(self, sat: str) -> None:
        self.by_system.setdefault(sat[0], set()).add(sat)
        self.records[sat[0]] = self.records.get(sat[0], 0) + 1

    def result(self) -> dict:
        # epochs read again out of order count once (a time's first record is kept)
        n_epochs = len(set(self.times)) if self.backwards else self.n_epochs
        return {
            "n_epochs": n_epochs,
            "n_epochs_power_failure": self.n_power,
            "satellites_by_system": {k: sorted(v) for k, v in sorted(self.by_system.items())},
            "n_records_by_system": dict(sorted(self.records.items())),
            "time_last_obs_gps_s": self.last_t if self.n_epochs else None,
            "events": self.events,
            **({"repeated_epochs": self.repeated} if self.repeated else {}),
            **({"epochs_out_of_order": self.backwards} if self.backwards else {}),
        }


def _append_row(rows, t, sat, rec_fields, cols: _GpsL1Columns, clk, flag):
    (pv, pl, ps), code, snr = rec_fields
    phase = _float_field(pv)
    pr = _float_field(code) if code is not None else math.nan
    s = _float_field(snr) if snr is not None else math.nan
    if math.isnan(phase) and math.isnan(pr):
        return
    sc = cols.scale
    rows["t"].append(t)
    rows["sat"].append(sat)
    rows["phase"].append(phase / sc["phase"] if sc["phase"] != 1 else phase)
    rows["lli"].append(_flag_digit(pl) if not math.isnan(phase) else 0)
    rows["ssi"].append(_flag_digit(ps) if not math.isnan(phase) else 0)
    rows["code"].append(pr / sc["code"] if "code" in sc and sc["code"] != 1 else pr)
    rows["snr"].append(s / sc["snr"] if "snr" in sc and sc["snr"] != 1 else s)
    rows["clk"].append(clk)
    rows["flag"].append(flag)


def _special_records(lines, i0, nrec, hdr: _ObsHeader, flag: int, t: float, summary: _Summary, lineno: int) -> int:
    """Consume ``nrec`` special-record lines (event flags 2-5); return the index after them."""
    if i0 + nrec > len(lines):
        raise hdr.error(lineno, f"event flag {flag} announces {nrec} special records but the file ends after {len(lines) - i0}")
    labels = []
    for j in range(i0, i0 + nrec):
        label = hdr.apply(lines[j], j + 1) if lines[j][60:80].strip() else ""
        labels.append(label)
    hdr.finish(i0 + nrec)
    summary.events.append({"line": lineno, "flag": flag, "time_gps_s": t, "labels": labels})
    return i0 + nrec


def _parse_obs_v2(lines: list[str], start: int, hdr: _ObsHeader, cols: _GpsL1Columns):
    rows = _new_rows()
    summary = _Summary()
    n_lines = len(lines)
    i = start
    while i < n_lines:
        line = lines[i]
        lineno = i + 1
        if not line.strip():
            i += 1
            continue
        try:
            flag = _flag_digit(line[28:29])
            nsat = int(line[29:32])
        except ValueError:
            raise hdr.error(lineno, f"expected an epoch line (' YY MM DD hh mm ss.sssssss  F NNN' with the event flag in column 29), got {line[:80]!r}") from None
        if flag > 6:
            raise hdr.error(lineno, f"event flag {flag} is not defined (0-6)")
        t = math.nan
        if line[:26].strip():
            try:
                yy, mo, dd, hh, mi = (int(line[k : k + 3]) for k in (0, 3, 6, 9, 12))
                sec = float(line[15:26])
                year = yy + (1900 if yy >= 80 else 2000) if yy < 100 else yy
                t = gps_seconds(year, mo, dd, hh, mi, sec)
            except ValueError as exc:
                raise hdr.error(lineno, f"malformed epoch date/time {line[:26]!r}{_range_note(exc)}") from None
        elif flag < 2:
            raise hdr.error(lineno, f"observation epoch line without a date/time: {line[:80]!r}")
        if 2 <= flag <= 5:
            i = _special_records(lines, i + 1, nsat, hdr, flag, t, summary, lineno)
            if flag in (3, 4):
                cols = _GpsL1Columns(hdr, lineno)
            continue
        # satellite list: 12 per line, continuation lines indented 32 columns
        sats_raw = []
        nlist = max(1, -(-nsat // 12))
        if i + nlist > n_lines:
            raise hdr.error(lineno, f"epoch announces {nsat} satellites but the file ends")
        for k in range(nlist):
            sl = lines[i + k]
            m = min(12, nsat - 12 * k)
            for j in range(m):
                sats_raw.append((sl[32 + 3 * j : 35 + 3 * j], i + k + 1))
        clk_field = line[68:]
        try:
            clk = _float_field(clk_field) if clk_field.strip() else math.nan
        except ValueError:
            raise hdr.error(lineno, f"malformed receiver clock offset {clk_field!r} (columns 69-80)") from None
        i += nlist
        per_sat = max(1, -(-cols.n // 5))
        if flag == 6:  # cycle-slip records: same layout as observations, not observations
            i += nsat * per_sat
            summary.events.append({"line": lineno, "flag": 6, "time_gps_s": t, "labels": []})
            continue
        if not summary.epoch_time(t, lineno, hdr):         # a repeated epoch: its records skipped
            i += nsat * per_sat
            continue
        summary.n_epochs += 1
        summary.n_power += flag == 1
        if i + nsat * per_sat > n_lines:
            raise hdr.error(lineno, f"epoch {gps_time_str(t)} announces {nsat} satellites × {per_sat} lines but the file ends")
        for s_raw, s_line in sats_raw:
            try:
                sat = _sat_id(s_raw, hdr.version)
            except ValueError:
                raise hdr.error(s_line, f"malformed satellite identifier {s_raw!r} in the epoch's satellite list") from None
            summary.sat(sat)
            if sat[0] == "G":
                rec_lines = lines[i : i + per_sat]
                try:
                    fields = _fields_v2(rec_lines, cols)
                    _append_row(rows, t, sat, fields, cols, clk, flag)
                except ValueError:
                    bad = _first_bad_line_v2(rec_lines, cols)
                    raise hdr.error(i + 1 + bad, f"malformed observation record for {sat} ({_epoch_as_written(hdr, t)}): "
                                                 f"{lines[i + bad].rstrip()!r}") from None
            i += per_sat
    return rows, summary.result()


def _fields_v2(rec_lines: list[str], cols: _GpsL1Columns):
    def get(k):
        ln = rec_lines[k // 5]
        return _obs_field(ln, k % 5, 0)

    ph = get(cols.i_phase)
    code = get(cols.i_code)[0] if cols.i_code >= 0 else None
    snr = get(cols.i_snr)[0] if cols.i_snr >= 0 else None
    return ph, code, snr


def _first_bad_line_v2(rec_lines, cols) -> int:
    for idx in (cols.i_phase, cols.i_code, cols.i_snr):
        if idx < 0:
            continue
        v, lli, ssi = _obs_field(rec_lines[idx // 5], idx % 5, 0)
        try:
            _float_field(v)
            _flag_digit(lli)
            _flag_digit(ssi)
        except ValueError:
            return idx // 5
    return 0


def _parse_obs_v3(lines: list[str], start: int, hdr: _ObsHeader, cols: _GpsL1Columns):
    """Epoch lines are walked here; the satellite records are collected and parsed afterwards in
    bulk (:func:`_records_v3_bulk`), which is ~10× faster than record by record on day-long
    1 Hz files.  Any record the bulk parser cannot read is parsed again record by record
    (:func:`_append_row`) so that the error names its line exactly as before."""
    rows = _new_rows()
    summary = _Summary()
    n_lines = len(lines)
    i = start
    # deferred records: per epoch (first record line index, count, t, clk, flag, cols)
    groups: list[list] = []
    cur = None
    while i < n_lines:
        line = lines[i]
        lineno = i + 1
        if not line.strip():
            i += 1
            continue
        if not line.startswith(">"):
            raise hdr.error(lineno, f"expected an epoch line starting with '>', got {line[:80]!r}")
        try:
            flag = _flag_digit(line[31:32])
            nsat = int(line[32:35])
        except ValueError:
            raise hdr.error(lineno, f"malformed epoch line (event flag in column 32, number of satellites in 33-35): {line[:80]!r}") from None
        if flag > 6:
            raise hdr.error(lineno, f"event flag {flag} is not defined (0-6)")
        t = math.nan
        if line[2:29].strip():
            try:
                year, mo, dd, hh, mi = (int(line[a:b]) for a, b in ((2, 6), (7, 9), (10, 12), (13, 15), (16, 18)))
                sec = float(line[18:29])
                t = gps_seconds(year, mo, dd, hh, mi, sec)
            except ValueError as exc:
                raise hdr.error(lineno, f"malformed epoch date/time {line[2:29]!r}{_range_note(exc)}") from None
        elif flag < 2:
            raise hdr.error(lineno, f"observation epoch line without a date/time: {line[:80]!r}")
        if 2 <= flag <= 5:
            i = _special_records(lines, i + 1, nsat, hdr, flag, t, summary, lineno)
            if flag in (3, 4):
                cols = _GpsL1Columns(hdr, lineno)
                cur = None
            continue
        if flag == 6:
            summary.events.append({"line": lineno, "flag": 6, "time_gps_s": t, "labels": []})
            i += 1 + nsat
            continue
        # the clock offset is F15.12 in columns 42-56; some writers shift it by a column, and
        # nothing else follows the satellite count, so read whatever stands after column 35
        clk_field = line[35:]
        try:
            clk = _float_field(clk_field) if clk_field.strip() else math.nan
        except ValueError:
            raise hdr.error(lineno, f"malformed receiver clock offset {clk_field.strip()!r} (columns 42-56)") from None
        if not summary.epoch_time(t, lineno, hdr):         # a repeated epoch: its records skipped
            i += 1 + nsat
            continue
        summary.n_epochs += 1
        summary.n_power += flag == 1
        if i + 1 + nsat > n_lines:
            raise hdr.error(lineno, f"epoch {gps_time_str(t)} announces {nsat} satellites but the file ends after {n_lines - i - 1} lines")
        if cur is None or cur[0] is not cols:
            cur = [cols, [], [], [], [], [], []]      # cols, first line index, count, t, clk, flag, epoch line no.
            groups.append(cur)
        cur[1].append(i + 1)
        cur[2].append(nsat)
        cur[3].append(t)
        cur[4].append(clk)
        cur[5].append(flag)
        cur[6].append(lineno)
        i += 1 + nsat
    for g in groups:
        _records_v3_bulk(lines, hdr, g, rows, summary)
    return rows, summary.result()


def _records_v3_bulk(lines, hdr: _ObsHeader, group, rows, summary) -> None:
    """Parse the satellite records of consecutive epochs sharing one observation-type layout."""
    cols, first, count, t_ep, clk_ep, flag_ep, ep_line = group
    first = np.asarray(first, dtype=np.int64)
    count = np.asarray(count, dtype=np.int64)
    n = int(count.sum())
    if n == 0:
        return
    offset = np.r_[0, np.cumsum(count)[:-1]]
    idx = np.repeat(first - offset, count) + np.arange(n)           # line index of every record
    recs = [lines[j] for j in idx.tolist()]
    # satellite identifiers (a few distinct values): validate each once
    ids = [r[0:3] for r in recs]
    cache: dict[str, str | None] = {}
    for raw in set(ids):
        try:
            cache[raw] = _sat_id(raw, hdr.version)
        except ValueError:
            cache[raw] = None
    if any(v is None for v in cache.values()):
        for k, raw in enumerate(ids):
            if cache[raw] is None:
                j = int(idx[k])
                if recs[k].startswith(">"):
                    e = int(np.searchsorted(first, j, side="right")) - 1
                    raise hdr.error(j + 1, f"epoch line where satellite {j - int(first[e]) + 1} of {int(count[e])} of the "
                                           f"epoch at line {ep_line[e]} was expected")
                raise hdr.error(j + 1, f"malformed satellite identifier {raw!r} at the start of an observation record")
    sats = np.array([cache[r] for r in ids], dtype=object)
    uniq, cnt = np.unique(sats.astype(str), return_counts=True)
    for sname, c in zip(uniq.tolist(), cnt.tolist()):
        summary.by_system.setdefault(sname[0], set()).add(sname)
        summary.records[sname[0]] = summary.records.get(sname[0], 0) + int(c)
    gps = np.flatnonzero(np.char.startswith(sats.astype(str), "G"))
    if gps.size == 0:
        return
    ep = np.repeat(np.arange(count.size), count)[gps]
    grecs = [recs[k] for k in gps.tolist()]
    width = 3 + 16 * max(cols.i_phase, cols.i_code, cols.i_snr) + 16
    # one byte per character (latin-1, as the text was decoded), truncated / NUL-padded to the
    # fields needed: a quarter of the memory of a 'U' array
    arr = np.array([r.encode("latin-1") for r in grecs], dtype=f"S{width}")
    chars = arr.view(np.uint8).reshape(len(grecs), width)

    def field(k):
        c = 3 + 16 * k
        f = np.ascontiguousarray(chars[:, c:c + 14]).view("S14").ravel()
        return f

    def to_float(f):
        st = np.char.strip(f)
        blank = st == b""
        v = np.where(blank, b"nan", st).astype(np.float64)
        if not np.all(np.isfinite(v) | blank) or np.any(np.char.count(st, b"_")):
            raise ValueError("non-finite token")            # 'NaN', 'inf': refused record by record
        return v

    def digit(k, off):
        ch = chars[:, 3 + 16 * k + off].astype(np.int64)
        out = np.where((ch == 32) | (ch == 0), 0, ch - 48)
        if np.any((out < 0) | (out > 9)):
            raise ValueError("flag digit")
        return out

    try:
        phase = to_float(field(cols.i_phase))
        code = to_float(field(cols.i_code)) if cols.i_code >= 0 else np.full(len(grecs), np.nan)
        snr = to_float(field(cols.i_snr)) if cols.i_snr >= 0 else np.full(len(grecs), np.nan)
        lli = digit(cols.i_phase, 14)
        ssi = digit(cols.i_phase, 15)
    except ValueError:
        # something the bulk parser does not take (e.g. a 'D' exponent): record by record, which
        # also reports a malformed record with its line exactly
        t_arr = np.asarray(t_ep, dtype=np.float64)
        for k, rec in enumerate(grecs):
            j = int(idx[gps[k]])
            sat = sats[gps[k]]
            e = int(ep[k])
            try:
                ph = _obs_field(rec, cols.i_phase, 3)
                cd = _obs_field(rec, cols.i_code, 3)[0] if cols.i_code >= 0 else None
                sn = _obs_field(rec, cols.i_snr, 3)[0] if cols.i_snr >= 0 else None
                _append_row(rows, float(t_arr[e]), sat, (ph, cd, sn), cols, clk_ep[e], flag_ep[e])
            except ValueError:
                raise hdr.error(j + 1, f"malformed observation record for {sat} "
                                       f"({_epoch_as_written(hdr, float(t_arr[e]))}): {rec.rstrip()[:120]!r}") from None
        return
    keep = ~(np.isnan(phase) & np.isnan(code))
    has_ph = ~np.isnan(phase)
    phase, code, snr = _unscaled(cols, phase, code, snr)
    lli = np.where(has_ph, lli, 0)
    ssi = np.where(has_ph, ssi, 0)
    k = np.flatnonzero(keep)
    e = ep[k]
    _flush_rows(rows)
    rows["_chunks"].append({
        "t": np.asarray(t_ep, dtype=np.float64)[e], "sat": sats[gps[k]], "phase": phase[k],
        "lli": lli[k].astype(np.int64), "ssi": ssi[k].astype(np.int64), "code": code[k], "snr": snr[k],
        "clk": np.asarray(clk_ep, dtype=np.float64)[e], "flag": np.asarray(flag_ep, dtype=np.int64)[e]})


# ----------------------------------------------------------------------------------------------
# navigation files
# ----------------------------------------------------------------------------------------------


_NAV_VALUES = NAV_COLUMNS[2:31]  # the 29 values after toc, in file order
# clock and orbit terms, week, health and TGD must be present; codes on L2, L2 P flag, IODC,
# transmission time and fit interval may be blank in some writers' files
_NAV_REQUIRED = tuple(range(20)) + (21, 24, 25)
NAV_KEPLER_SYSTEMS = ("G", "E", "C", "J")
"""Systems whose RINEX 3 Kepler ephemeris records :func:`read_rinex_nav` decodes (GPS-form
elements; Galileo: IODnav in ``iode``, data sources in ``codes_l2``, BGD E5a/E1 in ``tgd_s``;
BeiDou: see :func:`read_rinex_nav`)."""
NAV_SYSTEMS = NAV_KEPLER_SYSTEMS + ("R",)
"""Every system :func:`read_rinex_nav` decodes: the Kepler systems and GLONASS state vectors."""
_NAV_LINES = {"G": 8, "E": 8, "C": 8, "J": 8, "I": 8, "R": 4, "S": 4}


def qzss_fit_interval_h(flag) -> np.ndarray:
    """A QZSS record's fit interval, h, from its fit-interval flag (RINEX 3 writes QZSS's flag where GPS has
    hours): 0 → 2 h; 1 ("more than 2 hours", IS-QZSS-PNT) → NaN, not stated."""
    f = np.asarray(flag, dtype=np.float64)
    return np.where(f == 0, 2.0, np.nan)


def _kepler_table(records: list, p, compressed: bool) -> pd.DataFrame:
    """The Kepler records (GPS, Galileo, BeiDou, QZSS) as a :data:`NAV_COLUMNS` table: weeks unwrapped,
    toe and transmission time in GPS seconds (BeiDou: from BDT), impossible orbits refused."""
    df = pd.DataFrame(records, columns=["sat", "toc_gps_s", *_NAV_VALUES, "line"])
    if df.empty:
        return pd.DataFrame(columns=list(NAV_COLUMNS))
    bds = (df["sat"].str[0] == "C").to_numpy()
    # BeiDou: AODC is written where GPS has the fit interval, TGD2 where GPS has IODC
    df.loc[bds, "iodc"] = df.loc[bds, "fit_interval_h"]
    df.loc[bds, "fit_interval_h"] = np.nan
    qzss = (df["sat"].str[0] == "J").to_numpy()
    df.loc[qzss, "fit_interval_h"] = qzss_fit_interval_h(df.loc[qzss, "fit_interval_h"].to_numpy())
    week_off = np.where(bds, BDT_WEEK_OFFSET, 0)
    sec_off = np.where(bds, GPS_MINUS_BDT_S, 0.0)
    week = df["week"].to_numpy(dtype=float)
    toc = df["toc_gps_s"].to_numpy()
    toe_gps = (week + week_off) * SECONDS_PER_WEEK + df["toe_sow_s"].to_numpy() + sec_off
    # unwrap a week number written modulo 1024 (old receivers / converters): pick the one nearest toc
    shift = np.round((toc - toe_gps) / (1024 * SECONDS_PER_WEEK))
    week = week + 1024 * shift
    toe_gps = (week + week_off) * SECONDS_PER_WEEK + df["toe_sow_s"].to_numpy() + sec_off
    # toe may fall in the week next to toc's (toe is sent as seconds of week): nearest to toc
    toe_gps = toe_gps + SECONDS_PER_WEEK * np.round((toc - toe_gps) / SECONDS_PER_WEEK)
    df["week"] = week
    df["toe_gps_s"] = toe_gps
    tt = (week + week_off) * SECONDS_PER_WEEK + df["transmit_sow_s"].to_numpy() + sec_off
    df["transmit_gps_s"] = tt + SECONDS_PER_WEEK * np.round((toc - tt) / SECONDS_PER_WEEK)
    bad_e = (df["e"] < 0) | (df["e"] >= 1) | (df["sqrt_a_sqrt_m"] <= 0)
    if bad_e.any():
        r = df[bad_e].iloc[0]
        raise CdgpsError(f"{_where(p, int(r['line']), compressed)}: ephemeris record of {r['sat']} has an impossible orbit (e={r['e']}, sqrt(A)={r['sqrt_a_sqrt_m']})")
    for c in ("iode", "codes_l2", "l2p_data_flag", "sv_health", "iodc"):
        df[c] = df[c].fillna(-1).round().astype(np.int64)
    df["week"] = df["week"].astype(np.int64)
    df = df[list(NAV_COLUMNS)]
    df = df.drop_duplicates(subset=["sat", "toe_gps_s", "iode", "af0_s"], keep="first")
    return df.sort_values(["sat", "toe_gps_s", "transmit_gps_s"], kind="stable").reset_index(drop=True)


def _glonass_record(lines: list[str], i: int, v3: bool, p, compressed: bool) -> dict:
    """One GLONASS state-vector record (RINEX 3 'R', or RINEX 2 type G) starting at line index ``i``.

    First line: epoch t_b (UTC), −τ_n (s), γ_n, message frame time (s of the UTC week in RINEX 3,
    of the UTC day in RINEX 2); then X, Ẋ, Ẍ, health / Y, Ẏ, Ÿ, frequency number / Z, Ż, Z̈, age
    (km, km/s, km/s²).  t_b and the frame time are moved to GPS time with the leap seconds.
    """
    ln = lines[i]
    try:
        if v3:
            sat = _sat_id(ln[0:3], 3.0)
            y, mo, d, h, mi = (int(ln[a:b]) for a, b in ((4, 8), (9, 11), (12, 14), (15, 17), (18, 20)))
            sec, vals, cont = float(ln[21:23]), [ln[23 + 19 * k: 42 + 19 * k] for k in range(3)], 4
        else:
            sat = f"R{int(ln[0:2]):02d}"
            yy, mo, d, h, mi = (int(ln[a:b]) for a, b in ((3, 5), (6, 8), (9, 11), (12, 14), (15, 17)))
            y = yy + (1900 if yy >= 80 else 2000) if yy < 100 else yy
            sec, vals, cont = float(ln[17:22]), [ln[22 + 19 * k: 41 + 19 * k] for k in range(3)], 3
        vals = [_float_field(x) for x in vals]
        for k in range(1, 4):
            cl = lines[i + k]
            vals.extend(_float_field(cl[cont + 19 * q: cont + 19 * (q + 1)]) for q in range(4))
        t_utc = gps_seconds(y, mo, d, h, mi, sec)       # a month 13 or an hour 25: ValueError, named below
    except (ValueError, IndexError) as exc:
        note = _range_note(exc) if isinstance(exc, ValueError) else ""
        raise CdgpsError(f"{_where(p, i + 1, compressed)}: malformed GLONASS ephemeris record: {ln.rstrip()!r}{note}") from None
    if len(vals) < 14 or any(math.isnan(v) for v in vals[:14]):
        raise CdgpsError(f"{_where(p, i + 1, compressed)}: GLONASS ephemeris record of {sat} has blank required field(s)")
    leap = gps_minus_utc_s(t_utc + 18.0)
    toe = t_utc + leap
    period = SECONDS_PER_WEEK if v3 else 86400.0
    frame = math.floor(t_utc / period) * period + vals[2]
    frame += period * round((t_utc - frame) / period)
    rec = dict.fromkeys(NAV_COLUMNS, math.nan)
    rec.update({
        "sat": sat, "toc_gps_s": toe, "toe_gps_s": toe, "af0_s": vals[0], "af1_s_per_s": vals[1], "af2_s_per_s2": 0.0,
        "iode": -1, "codes_l2": -1, "l2p_data_flag": -1, "iodc": -1, "tgd_s": 0.0, "sv_health": int(vals[6]),
        "week": int(toe // SECONDS_PER_WEEK), "toe_sow_s": toe % SECONDS_PER_WEEK,
        "transmit_gps_s": frame + leap, "transmit_sow_s": (frame + leap) % SECONDS_PER_WEEK, "line": i + 1,
    })
    km = {"x_m": 3, "vx_m_per_s": 4, "ax_m_per_s2": 5, "y_m": 7, "vy_m_per_s": 8, "ay_m_per_s2": 9,
          "z_m": 11, "vz_m_per_s": 12, "az_m_per_s2": 13}
    rec.update({c: 1e3 * vals[k] for c, k in km.items()})
    rec["glonass_k"] = int(vals[10])
    return rec


def _nav_header(lines: list, p: Path, compressed: bool, version: float) -> tuple[dict, int]:
    """The header of a navigation file: (``attrs`` with version, leap seconds, ionosphere
    coefficients and comments; the index of its END OF HEADER line)."""
    attrs: dict = {"path": str(p), "version": version, "leap_seconds": None, "ion_alpha": None, "ion_beta": None, "comments": []}
    end = None
    for i in range(1, len(lines)):
        ln = lines[i]
        label = ln[60:80].strip()
        try:
            if label == "END OF HEADER":
                end = i
                break
            if label == "COMMENT":
                attrs["comments"].append(ln[:60].rstrip())
            elif label == "LEAP SECONDS":
                attrs["leap_seconds"] = int(ln[:6])
            elif label == "ION ALPHA":
                attrs["ion_alpha"] = [_float_field(ln[2 + 12 * k : 14 + 12 * k]) for k in range(4)]
            elif label == "ION BETA":
                attrs["ion_beta"] = [_float_field(ln[2 + 12 * k : 14 + 12 * k]) for k in range(4)]
            elif label == "IONOSPHERIC CORR" and ln[:4] in ("GPSA", "GPSB"):
                attrs["ion_alpha" if ln[:4] == "GPSA" else "ion_beta"] = [_float_field(ln[5 + 12 * k : 17 + 12 * k]) for k in range(4)]
        except ValueError:
            raise CdgpsError(f"{_where(p, i + 1, compressed)}: malformed header line '{label}': {ln.rstrip()!r}") from None
    if end is None:
        raise CdgpsError(f"{p}: no 'END OF HEADER' line; truncated or not a RINEX navigation file")
    return attrs, end


def _kepler_record(lines: list, i: int, nrec: int, sysc: str, version: float, p: Path, compressed: bool) -> list:
    """The Keplerian ephemeris record (GPS, Galileo, BeiDou) of ``nrec`` lines from line index ``i``:
    [sat, toc (GPS s), the 29 broadcast values, line number]; a malformed, truncated or incomplete
    record is an error naming the file and line."""
    v3 = version >= 3
    cont_col = 4 if v3 else 3
    ln = lines[i]
    lineno = i + 1
    try:
        if v3:
            sat = _sat_id(ln[0:3], version)
            y, mo, d, h, mi = (int(ln[a:b]) for a, b in ((4, 8), (9, 11), (12, 14), (15, 17), (18, 20)))
            sec = float(ln[21:23])
            first_vals = [ln[23 + 19 * k : 42 + 19 * k] for k in range(3)]
        else:
            sat = f"G{int(ln[0:2]):02d}"
            yy, mo, d, h, mi = (int(ln[a:b]) for a, b in ((3, 5), (6, 8), (9, 11), (12, 14), (15, 17)))
            y = yy + (1900 if yy >= 80 else 2000) if yy < 100 else yy
            sec = float(ln[17:22])
            first_vals = [ln[22 + 19 * k : 41 + 19 * k] for k in range(3)]
        toc = gps_seconds(y, mo, d, h, mi, sec) + (GPS_MINUS_BDT_S if sysc == "C" else 0.0)
        vals = [_float_field(s) for s in first_vals]
    except ValueError:
        raise CdgpsError(f"{_where(p, lineno, compressed)}: malformed first line of an ephemeris record: {ln.rstrip()!r}") from None
    for k in range(1, nrec):
        cl = lines[i + k]
        if v3 and cl[:1] in _NAV_LINES and cl[1:3].strip().isdigit():
            raise CdgpsError(f"{_where(p, i + k + 1, compressed)}: ephemeris record of {sat} starting at line {lineno} is truncated: a new record starts after {k} of {nrec} lines")
        try:
            vals.extend(_float_field(cl[cont_col + 19 * q : cont_col + 19 * (q + 1)]) for q in range(4))
        except ValueError:
            raise CdgpsError(f"{_where(p, i + k + 1, compressed)}: malformed broadcast-orbit line {k} of the {sat} record starting at line {lineno}: {cl.rstrip()!r}") from None
    vals = vals[:29]
    if any(math.isnan(vals[k]) for k in _NAV_REQUIRED):
        missing = [_NAV_VALUES[k] for k in _NAV_REQUIRED if math.isnan(vals[k])][:5]
        raise CdgpsError(f"{_where(p, lineno, compressed)}: ephemeris record of {sat} has blank required field(s): {', '.join(missing)}")
    return [sat, toc, *vals, lineno]


def _with_glonass(df: pd.DataFrame, glonass: list) -> pd.DataFrame:
    """The Keplerian table ``df`` and the GLONASS state-vector records in one table (NaN where a
    column is the other kind's), integer columns restored, duplicates dropped, sorted."""
    glo = pd.DataFrame(glonass, columns=[*NAV_COLUMNS, *GLONASS_NAV_COLUMNS])
    df = pd.concat([d for d in (df.reindex(columns=glo.columns), glo) if len(d)], ignore_index=True)
    for c in ("iode", "codes_l2", "l2p_data_flag", "sv_health", "iodc", "week", "line"):
        df[c] = df[c].fillna(-1).round().astype(np.int64)
    df = df.drop_duplicates(subset=["sat", "toe_gps_s", "iode", "af0_s"], keep="first")
    df = df.sort_values(["sat", "toe_gps_s", "transmit_gps_s"], kind="stable").reset_index(drop=True)
    return df


#: RINEX file types (RINEX VERSION / TYPE, column 21) that are surely no navigation file
_NOT_NAVIGATION = {"O": "observation", "M": "meteorological", "C": "clock"}


def nav_file_systems(path: str | Path) -> tuple[str, ...]:
    """Systems whose ephemerides a navigation file can hold, from its first line only: a RINEX 3 file
    its header system (all of :data:`NAV_SYSTEMS` for a mixed ``M`` file), RINEX 2 ``N`` GPS and
    ``G`` GLONASS.  Lets a reader skip a Galileo-only file when it wants GPS (instead of refusing it).

    Raises
    ------
    CdgpsError
        An observation, meteorological or clock file (``--nav`` given the wrong file: it was skipped
        unseen beside a navigation file that holds the systems wanted).
    """
    p = Path(path)
    lines, compressed = _read_lines(p)
    version, ftype, system = _parse_version_line(lines[:1], p, compressed, "navigation")
    if ftype in _NOT_NAVIGATION:
        raise CdgpsError(f"{p}: this is a RINEX {_NOT_NAVIGATION[ftype]} file, not a navigation file (RINEX VERSION / "
                         f"TYPE says {ftype!r})")
    if version >= 3:
        return NAV_SYSTEMS if system in ("M", " ", "") else (system,)
    return {"N": ("G",), "G": ("R",)}.get(ftype, ())


#: the RINEX 4 navigation messages read (``> EPH <sat> <type>``): the legacy ephemerides, laid out as in RINEX 3.05
_V4_EPHEMERIS_TYPES = {"G": ("LNAV",), "J": ("LNAV",), "E": ("INAV", "FNAV"), "C": ("D1", "D2"), "R": ("FDMA",)}


def _v4_record_start(lines: list, i: int) -> int:
    """The line after RINEX 4 navigation header line ``lines[i]`` (``> EPH G05 LNAV``) when the record below it is
    one this reader takes (:data:`_V4_EPHEMERIS_TYPES`), else the next ``>`` line (or the end): CNAV/CNV1–3
    ephemerides, SBAS, and the STO, EOP and ION messages are passed over."""
    f = lines[i][1:].split()
    if len(f) >= 3 and f[0] == "EPH" and f[2] in _V4_EPHEMERIS_TYPES.get(f[1][:1], ()):
        return i + 1
    i += 1
    while i < len(lines) and not lines[i].startswith(">"):
        i += 1
    return i


def _check_nav_kind(p: Path, version: float, ftype: str, system: str, systems: tuple) -> bool:
    """CdgpsError unless file ``p`` (its RINEX VERSION / TYPE: ``version``, ``ftype``, ``system``) is a navigation file
    whose ephemerides of ``systems`` can be read; whether it is a RINEX 2 GLONASS file (type ``G``) read for them."""
    glonass2 = version < 3 and ftype == "G" and "R" in systems
    if version < 3 and ftype in ("G", "H") and not glonass2:
        raise CdgpsError(f"{p}: this is a RINEX {version:.2f} {'GLONASS' if ftype == 'G' else 'SBAS'} navigation file; GPS broadcast ephemerides (a type N file) are needed")
    if ftype != "N" and not glonass2:
        kind = "observation" if ftype == "O" else f"type {ftype!r}"
        raise CdgpsError(f"{p}: this is a RINEX {kind} file, not a navigation file (RINEX VERSION / TYPE says {ftype!r})")
    _check_version(version, p, "navigation")
    bad_sys = [c for c in systems if c not in NAV_SYSTEMS]
    if bad_sys:
        raise CdgpsError(f"{p}: ephemerides of system(s) {', '.join(bad_sys)} cannot be read; supported: {', '.join(NAV_SYSTEMS)}")
    if version >= 3 and system not in ("G", "M", " ", "") and system not in systems:
        raise CdgpsError(f"{p}: RINEX {version:.2f} navigation file for system {system!r}; GPS ('G') or mixed ('M') ephemerides are needed")
    return glonass2


def read_rinex_nav(path: str | Path, systems=("G",)) -> pd.DataFrame:
    """Read the broadcast ephemerides of a RINEX 2, 3 or 4 navigation file.

    Parameters
    ----------
    path : str or Path
        A RINEX 2 GPS (type ``N``) or GLONASS (type ``G``) navigation file, or a RINEX 3
        navigation file (type ``N``; records of systems not asked for are skipped and counted), or a RINEX 4 one
        (its legacy ephemerides, :data:`_V4_EPHEMERIS_TYPES`; the other messages passed over).
        Compressed files are decompressed as in :func:`read_rinex_obs`.
    systems : sequence of str, default ("G",)
        System letters to read, among :data:`NAV_SYSTEMS`.  **BeiDou** records keep BDT's
        seconds of week in ``toe_sow_s``/``transmit_sow_s`` and the BDT week in ``week`` (the user
        algorithm needs them), while ``toc_gps_s``, ``toe_gps_s``, ``transmit_gps_s`` are GPS
        time (BDT + 14 s, week + 1356); ``iode`` = AODE, ``iodc`` = AODC, ``tgd_s`` = TGD1 (B1I),
        TGD2 is not kept.  **GLONASS** records (epoch in UTC, moved to GPS time with the leap
        seconds) add the columns :data:`~cdgps_cli.core.records.GLONASS_NAV_COLUMNS` (m, m/s,
        m/s²; NaN on other rows).

    Returns
    -------
    DataFrame
        One row per ephemeris record, sorted by satellite then toe, exact duplicates
        (same satellite, toe and IODE, as in merged broadcast files) removed; columns
        :data:`NAV_COLUMNS` (angles in rad, angular rates in rad/s, times in s, GPS seconds since
        1980-01-06 for ``toc_gps_s``/``toe_gps_s``/``transmit_gps_s``).  A RINEX 2 week number
        written modulo 1024 is unwrapped to the one nearest the record's toc.  ``attrs`` holds the
        header (``version``, ``leap_seconds``, ``ion_alpha``, ``ion_beta``, ``comments``) and
        ``n_records_by_system``.

    Raises
    ------
    CdgpsError
        Not a navigation file, a GLONASS/SBAS-only file, unsupported version, no GPS records,
        a malformed or truncated record (file and line number).
    """
    p = Path(path)
    lines, compressed = _read_lines(p)
    version, ftype, system = _parse_version_line(lines, p, compressed, "navigation")
    systems = tuple(systems)
    glonass2 = _check_nav_kind(p, version, ftype, system, systems)
    attrs, end = _nav_header(lines, p, compressed, version)
    v3 = version >= 3
    records: list[list] = []
    glonass: list[dict] = []
    counts: dict[str, int] = {}
    i = end + 1
    n = len(lines)
    while i < n:
        ln = lines[i]
        lineno = i + 1
        if not ln.strip():
            i += 1
            continue
        if ln.startswith(">") and version >= 4:       # RINEX 4: a record's header line; other messages passed over
            i = _v4_record_start(lines, i)
            continue
        if v3:
            sysc = ln[0:1]
            if sysc not in _NAV_LINES:
                raise CdgpsError(f"{_where(p, lineno, compressed)}: expected the first line of an ephemeris record ('G01 YYYY MM DD hh mm ss …'), got {ln[:80]!r}")
        else:
            sysc = "R" if glonass2 else "G"
        # RINEX 3.05 adds a fourth broadcast-orbit line to GLONASS records
        nrec = _NAV_LINES[sysc] + (1 if sysc == "R" and version >= 3.05 else 0)
        counts[sysc] = counts.get(sysc, 0) + 1
        if i + nrec > n:       # a cut file, whichever system's record it ends in
            raise CdgpsError(f"{_where(p, lineno, compressed)}: ephemeris record truncated: {nrec} lines expected, the file ends after {n - i}")
        if sysc not in systems:
            i += nrec
            continue
        if sysc == "R":
            glonass.append(_glonass_record(lines, i, v3, p, compressed))
        else:
            records.append(_kepler_record(lines, i, nrec, sysc, version, p, compressed))
        i += nrec
    if not records and not glonass:
        found = ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())) or "none"
        wanted = "GPS" if systems == ("G",) else "/".join(systems)
        raise CdgpsError(f"{p}: no {wanted} ephemeris records (records found by system: {found})")
    df = _kepler_table(records, p, compressed)
    if "R" in systems:
        df = _with_glonass(df, glonass)
    attrs["n_records_by_system"] = dict(sorted(counts.items()))
    df.attrs.update(attrs)
    return df


def _unscaled(cols, phase, code, snr):
    """Phase, code and SNR divided by the header's SYS / SCALE FACTOR (RINEX 3) where it is not 1."""
    sc = cols.scale
    if sc["phase"] != 1:
        phase = phase / sc["phase"]
    if "code" in sc and sc["code"] != 1:
        code = code / sc["code"]
    if "snr" in sc and sc["snr"] != 1:
        snr = snr / sc["snr"]
    return phase, code, snr
