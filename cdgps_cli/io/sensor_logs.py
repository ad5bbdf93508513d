"""Sensor CSV logs (accelerometers, tilt meters, rate gyros) and their place in a GNSS RUN.mcap.

Format (docs/file-formats.md, written by ``cdgps simulate-gnss-structure``): one CSV per sensor kind,
long format, units in the column names —

* ``time_s`` — GPS seconds (the receivers' time scale);
* ``sensor`` — the sensor's name in the structure config (``[[accelerometers]]``, ``[[tilts]]``,
  ``[[gyros]]``; a column ``gyro`` is read as ``sensor``, as the structure simulator's gyro.csv);
* the readings, ``<kind>_<axis>_<unit>``: ``accel_x_m_s2`` … (m/s²), ``tilt_y_rad`` (rad),
  ``gyro_z_rad_s`` (rad/s); empty for an axis a sensor lacks.  The reader takes any kind whose
  columns follow this pattern (a new sensor needs no change here; the fusion matches the kind to the
  structure config's sensors).

:func:`read_sensor_csv` checks a file (its kind from the column names; every other column refused;
finite increasing times per sensor; numbers or empty cells) and :func:`sensor_attachments` /
:func:`sensor_logs_from_attachments` carry the tables into and out of the RUN as attachments
``sensors/<kind>.csv`` (canonical CSV text, so the same inputs give the same bytes).
:func:`read_sensor_log` also takes a u-blox UBX log, whose ESF-MEAS messages (a receiver's IMU)
give accelerometer and gyro tables of this format (:mod:`cdgps_cli.io.ubx_esf`).
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.core.errors import CdgpsError

__all__ = ["SENSOR_KINDS", "UNITS", "SENSOR_ATTACHMENT", "read_sensor_csv", "read_sensor_log", "sensor_log_file", "sensor_attachments", "sensor_logs_from_attachments", "read_run_sensor_logs",
           "write_sensor_csv"]

#: units a reading's column may end with (m/s², rad/s, rad, m, m/s, 1 for a ratio such as strain)
UNITS = ("m_s2", "rad_s", "rad", "m", "m_s", "1")
#: a reading's column: <kind>_<axis>_<unit> (any kind: the reader needs no change for a new sensor)
_COLUMN = re.compile(r"^([a-z]+)_([a-z0-9]+)_(" + "|".join(UNITS) + r")$")
#: the kinds of the shipped sensors (documentation; the reader takes any kind)
SENSOR_KINDS = ("accel", "tilt", "gyro", "strain")
SENSOR_ATTACHMENT = "sensors/{}.csv"
_PREFIX = "sensors/"


def _kind_of(cols: list, where: str) -> str:
    found = [_COLUMN.match(c) for c in cols]
    kinds = {m.group(1) for m in found if m}
    bad = [c for c, m in zip(cols, found) if not m]
    if bad or len(kinds) != 1:
        raise CdgpsError(f"{where}: expected columns time_s, sensor and the readings of one sensor kind, "
                         f"<kind>_<axis>_<unit> with unit {', '.join(UNITS)} (e.g. accel_x_m_s2, tilt_y_rad, "
                         f"gyro_z_rad_s), got {', '.join(cols) or 'none'}")
    return kinds.pop()


def _check_table(df: pd.DataFrame, where: str, parsed: bool = False) -> tuple[str, pd.DataFrame]:
    """(kind, table) of a table read as text (``parsed``: already read as numbers by :func:`_numeric_table`)."""
    if "gyro" in df.columns and "sensor" not in df.columns:
        df = df.rename(columns={"gyro": "sensor"})
    if list(df.columns[:2]) != ["time_s", "sensor"]:
        raise CdgpsError(f"{where}: the first columns must be time_s, sensor; got {', '.join(map(str, df.columns[:2]))}")
    kind = _kind_of([str(c) for c in df.columns[2:]], where)
    out = df if parsed else pd.DataFrame({"time_s": pd.to_numeric(df["time_s"], errors="coerce"),
                                          "sensor": df["sensor"].astype(str)})
    for c in df.columns[2:]:
        if parsed:
            if not np.all(np.isfinite(df[c].dropna().to_numpy())):
                raise CdgpsError(f"{where}: column {c}: non-finite value")
            continue
        v = pd.to_numeric(df[c], errors="coerce")
        bad = np.flatnonzero(v.isna().to_numpy() & df[c].notna().to_numpy())
        if bad.size or not np.all(np.isfinite(v.dropna().to_numpy())):
            line = int(bad[0]) + 2 if bad.size else "?"
            raise CdgpsError(f"{where}: line {line}: column {c}: expected a finite number or an empty cell, "
                             f"got {df[c].iloc[bad[0]]!r}" if bad.size else f"{where}: column {c}: non-finite value")
        out[c] = v.astype(float)
    t = out["time_s"].to_numpy()
    if not np.all(np.isfinite(t)):
        line = int(np.flatnonzero(~np.isfinite(t))[0]) + 2
        raise CdgpsError(f"{where}: line {line}: time_s must be a finite number of GPS seconds")
    for name, g in out.groupby("sensor", sort=False):
        d = np.diff(g["time_s"].to_numpy())
        if np.any(d <= 0):
            line = int(g.index[np.flatnonzero(d <= 0)[0] + 1]) + 2
            raise CdgpsError(f"{where}: line {line}: sensor {name}: time_s must increase (sample after sample)")
    if out.empty:
        raise CdgpsError(f"{where}: no samples")
    return kind, out


def read_sensor_csv(path: str | Path) -> tuple[str, pd.DataFrame]:
    """(kind, table) of a sensor CSV log; CdgpsError naming the file, line and column."""
    p = Path(path)
    try:
        tab = _numeric_table(p.read_bytes())
        if tab is not None:
            return _check_table(tab, str(p), parsed=True)
        df = pd.read_csv(p, dtype=str, keep_default_na=False, na_values=[""])
    except FileNotFoundError:
        raise CdgpsError(f"{p}: sensor log not found") from None
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise CdgpsError(f"{p}: cannot read the sensor log as CSV: {exc}") from None
    return _check_table(df, str(p))


def _csv_text(df: pd.DataFrame) -> str:
    """Canonical CSV text: times to the nanosecond (%.9f, as truth.csv), readings to 12 significant digits."""
    out = df.copy()
    out["time_s"] = [f"{v:.9f}" for v in out["time_s"].to_numpy(float)]
    return out.to_csv(index=False, lineterminator="\n", float_format="%.12g")


def write_sensor_csv(path, df: pd.DataFrame) -> None:
    """Write a sensor log (atomically), the canonical text of :func:`read_sensor_csv`'s format."""
    from cdgps_cli.io.atomic import write_bytes_atomic  # noqa: PLC0415

    write_bytes_atomic(Path(path), _csv_text(df).encode())


def _ubx_path(spec: str) -> tuple[str, str] | None:
    """(sensor name prefix, path) when ``spec`` is a UBX log (``NAME=FILE`` or ``FILE``, read by its
    first bytes: the UBX sync 0xB5 0x62, or a .ubx name); None for a CSV log."""
    name, path = "imu", spec
    head, sep, tail = spec.partition("=")
    if sep and re.fullmatch(r"[A-Za-z0-9_.-]+", head) and not Path(spec).exists():
        name, path = head, tail
    try:
        with open(path, "rb") as f:
            first = f.read(2)
    except OSError:
        first = b""
    return (name, path) if first == b"\xb5\x62" or path.lower().endswith(".ubx") else None


def sensor_log_file(spec: str | Path) -> str:
    """The file of a ``--sensor-log`` value (``NAME=FILE.ubx`` or ``FILE``)."""
    ubx = _ubx_path(str(spec))
    return str(spec) if ubx is None else ubx[1]


def read_sensor_log(spec: str | Path, ref_s: float | None = None) -> list:
    """[(kind, table)] of a sensor log: a CSV (:func:`read_sensor_csv`), or a u-blox UBX log whose
    ESF-MEAS messages give an IMU's accelerometer and gyro tables (``[NAME=]FILE``, sensors
    ``NAME-accel``, ``NAME-gyro``, NAME default ``imu``; :mod:`cdgps_cli.io.ubx_esf`), its time tags
    placed in GPS seconds in the week nearest ``ref_s`` (GPS s; the GNSS run's first epoch)."""
    ubx = _ubx_path(str(spec))
    if ubx is None:
        return [read_sensor_csv(spec)]
    from cdgps_cli.io.ubx_esf import read_esf_log  # noqa: PLC0415

    if ref_s is None:
        raise CdgpsError(f"{ubx[1]}: a UBX sensor log needs the GNSS run's time (its ESF-MEAS time tags are GPS "
                         "time of week): give it with the receiver files it belongs to")
    tables, _ = read_esf_log(ubx[1], ref_s, ubx[0])
    return [(k, _check_table(df, f"{ubx[1]} (ESF-MEAS {k})")[1]) for k, df in tables.items()]


def sensor_attachments(paths, ref_s: float | None = None, tables=()) -> dict:
    """{attachment name: CSV bytes} of the sensor logs ``paths`` (CSV, or UBX ESF-MEAS: :func:`read_sensor_log`
    with ``ref_s``) and of ``tables`` [(source, kind, table)] read elsewhere (a receiver log's IMU):
    one table per kind (two sources of one kind are joined; a sensor in two sources refused)."""
    by_kind: dict = {}
    for p in paths:
        for kind, df in read_sensor_log(p, ref_s):
            by_kind.setdefault(kind, []).append((str(p), df))
    for src, kind, df in tables:
        by_kind.setdefault(kind, []).append((str(src), df))
    out = {}
    for kind, items in by_kind.items():
        seen: dict = {}
        for p, df in items:
            for s in df["sensor"].unique():
                if s in seen:
                    raise CdgpsError(f"{p}: sensor {s} is also in {seen[s]} (one file per sensor's log)")
                seen[s] = p
        df = pd.concat([d for _, d in items], ignore_index=True)
        df = df.sort_values(["time_s", "sensor"], kind="stable").reset_index(drop=True)
        out[SENSOR_ATTACHMENT.format(kind)] = _csv_text(df).encode()
    return out


def sensor_logs_from_attachments(attachments: dict, where: str = "RUN.mcap") -> dict:
    """{kind: table} of a RUN's ``sensors/<kind>.csv`` attachments (empty: the run has none)."""
    out = {}
    for name, data in attachments.items():
        if not name.startswith(_PREFIX):
            continue
        tab = _numeric_table(data)
        if tab is not None:
            kind, tab = _check_table(tab, f"{where}:{name}", parsed=True)
        else:                                 # anything unusual: the text reading, which names the cell
            try:
                df = pd.read_csv(io.BytesIO(data), dtype=str, keep_default_na=False, na_values=[""])
            except (ValueError, pd.errors.ParserError) as exc:
                raise CdgpsError(f"{where}: damaged attachment {name}: {exc}") from None
            kind, tab = _check_table(df, f"{where}:{name}")
        out[kind] = tab
    return out


def read_run_sensor_logs(path: str | Path) -> dict:
    """{kind: table} of the sensor logs attached to the RUN at ``path`` (:func:`sensor_logs_from_attachments`),
    only the ``sensors/`` attachments kept in memory (every attachment's CRC still checked)."""
    from cdgps_cli.io.mcap import read_mcap  # noqa: PLC0415

    c = read_mcap(path, topics=[], attachments=lambda name: name.startswith(_PREFIX))
    return sensor_logs_from_attachments(c.attachments, str(path))


#: an empty cell of a CSV line: a comma followed by a comma or the line's end
_EMPTY_CELL = re.compile(rb",(?=,|\r?\n|\Z)")


def _numeric_table(data: bytes):
    """The table of a sensor CSV parsed straight to floats (no text column per reading: a fraction of
    the memory and time of the text reading, issue 29), or None when the text reading must decide
    (a header not ``time_s, sensor|gyro, …``, a cell that is not a number, or a NaN that is not an
    empty cell, e.g. the word ``nan``).  Values equal the text reading's (pandas' one float parser)."""
    head = data[:data.find(b"\n")].decode("utf-8", "replace").strip().split(",")
    if len(head) < 3 or head[0] != "time_s" or head[1] not in ("sensor", "gyro") or len(set(head)) != len(head):
        return None
    try:
        df = pd.read_csv(io.BytesIO(data), dtype={c: np.float64 for c in head if c != head[1]} | {head[1]: str},
                         keep_default_na=False, na_values=[""])
    except (ValueError, pd.errors.ParserError):
        return None
    if list(df.columns) != head or df[head[1]].isna().any():
        return None
    if int(df[head[2:] + ["time_s"]].isna().to_numpy().sum()) != len(_EMPTY_CELL.findall(data)):
        return None
    return df
