"""u-blox ESF-MEAS (a receiver's IMU: accelerometers and rate gyros) → the sensor-log tables of
:mod:`cdgps_cli.io.sensor_logs`.

UBX-ESF-MEAS (class 0x10, id 0x02; u-blox M8 / F9 interface descriptions, "ESF-MEAS" and "ESF
measurement data types") carries, little-endian:

====== ====== ================================================================================
offset format field
====== ====== ================================================================================
0      U4     timeTag, ms (the time tag of the measurement)
4      X2     flags: bits 0–1 timeMarkSent, bit 2 timeMarkEdge, bit 3 calibTtagValid,
              bits 11–15 numMeas
6      U2     id (the data provider)
8 + 4i X4     data i: bits 0–23 dataField (two's complement for the types below), bits 24–29 dataType
end    U4     calibTtag, ms (receiver local time, calibrated) — present only when calibTtagValid
====== ====== ================================================================================

The data types read (the others — wheel ticks, speed, temperature — are counted, not read):

=========== =================================== ====================== =====================
dataType    quantity                            scaling                column
=========== =================================== ====================== =====================
14, 13, 5   x-, y-, z-axis gyro angular rate    2⁻¹² deg/s             ``gyro_x_rad_s`` …
16, 17, 18  x-, y-, z-axis accelerometer        2⁻¹⁰ m/s²              ``accel_x_m_s2`` …
            specific force
=========== =================================== ====================== =====================

Time: the message's time tag in ms — ``calibTtag`` when the message has one, else ``timeTag`` — is
the receiver's local time, its estimate of GPS time of week (the receiver's 1 kHz clock mapped onto
GPS time; u-blox integration manuals, "Receiver local time").  It is placed in GPS seconds
(``week · 604800 + tow``, the receivers' time scale in a GNSS run) in the week that puts it nearest a
reference time (the GNSS run's first epoch), so a log across a week rollover stays in order.

Sensor names: the IMU's accelerometer triad is sensor ``<name>-accel`` and its gyro triad
``<name>-gyro`` (one name space with the structure config's ``[[accelerometers]]`` and ``[[gyros]]``);
a log with several data providers (``id``) gets ``<name><id>-accel`` … for each.  The IMU's axes are
its own x, y, z; the config's sensor axes say how they lie on the structure.

UBX-ESF-RAW (the IMU's raw samples) is not read: its ``sTtag`` is the sensor's own clock, with no
calibration to receiver time in the message.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.ubx_frames import split_stream

__all__ = ["ESF_MEAS", "ESF_TYPES", "WEEK_S", "has_esf_meas", "esf_tables", "read_esf_log", "receiver_imu_tables"]

ESF_MEAS = (0x10, 0x02)
#: UBX frame header (sync, class, id) of ESF-MEAS: a byte search finds whether a log has any
_ESF_MEAS_HEAD = b"\xb5\x62\x10\x02"
WEEK_S = 604800.0
_DEG = math.pi / 180.0
#: dataType → (kind, axis, scale to the column's unit, unit)
ESF_TYPES = {
    14: ("gyro", "x", 2.0**-12 * _DEG, "rad_s"),
    13: ("gyro", "y", 2.0**-12 * _DEG, "rad_s"),
    5: ("gyro", "z", 2.0**-12 * _DEG, "rad_s"),
    16: ("accel", "x", 2.0**-10, "m_s2"),
    17: ("accel", "y", 2.0**-10, "m_s2"),
    18: ("accel", "z", 2.0**-10, "m_s2"),
}
_UNIT = {"gyro": "rad_s", "accel": "m_s2"}


def has_esf_meas(data: bytes) -> bool:
    """Whether the bytes hold an ESF-MEAS frame header (a cheap test before framing a whole log)."""
    return data.find(_ESF_MEAS_HEAD) >= 0


def _decode(payload: bytes, offset: int, where: str):
    """(time tag ms, provider id, [(dataType, signed dataField)], calibrated?) of one ESF-MEAS payload."""
    if len(payload) < 8:
        raise CdgpsError(f"{where}, byte {offset}: ESF-MEAS payload of {len(payload)} bytes; expected 8 + 4·numMeas "
                         "(+ 4 with calibTtag)")
    time_tag = int.from_bytes(payload[0:4], "little")
    flags = int.from_bytes(payload[4:6], "little")
    calib = bool(flags & 0x8)
    n = flags >> 11
    want = 8 + 4 * n + (4 if calib else 0)
    if len(payload) != want:
        raise CdgpsError(f"{where}, byte {offset}: ESF-MEAS payload of {len(payload)} bytes; numMeas = {n} and "
                         f"calibTtagValid = {int(calib)} make {want}")
    words = np.frombuffer(payload, dtype="<u4", count=n, offset=8).astype(np.int64)
    field = words & 0xFFFFFF
    field = np.where(field & 0x800000, field - (1 << 24), field)
    types = (words >> 24) & 0x3F
    if calib:
        time_tag = int.from_bytes(payload[want - 4:want], "little")
    return time_tag, int.from_bytes(payload[6:8], "little"), list(zip(types.tolist(), field.tolist())), calib


def _gps_seconds(tow_ms: int, ref_s: float) -> float:
    """GPS seconds of a time of week (ms) in the week that puts it nearest ``ref_s``."""
    tow = tow_ms / 1000.0
    week = math.floor((ref_s - tow) / WEEK_S + 0.5)
    return week * WEEK_S + tow


def esf_tables(frames, where: str, ref_s: float, name: str = "imu") -> tuple[dict, dict]:
    """Sensor-log tables of the ESF-MEAS frames among ``frames`` ((offset, class, id, frame bytes),
    as :func:`cdgps_cli.io.ubx_frames.split_stream` gives them).

    Parameters
    ----------
    frames : list
    where : str
        The log's name for messages.
    ref_s : float
        Reference time, GPS s (the time tags are placed in the week nearest it).
    name : str
        Sensor name prefix (``<name>-accel``, ``<name>-gyro``).

    Returns
    -------
    tables : dict
        {kind: DataFrame with ``time_s`` (GPS s), ``sensor`` and ``<kind>_x|y|z_<unit>``} (kinds with
        samples only; an axis a message lacks is empty).
    info : dict
        ``messages`` (ESF-MEAS read), ``calibrated`` (of them with calibTtag), ``other_types``
        ({dataType: count} not read), ``providers`` (ids).

    Raises
    ------
    CdgpsError
        A payload whose length disagrees with its numMeas, a data type given twice in one message,
        or a sensor's time going back or repeating (naming the log and byte offset).
    """
    rows: dict = {"accel": [], "gyro": []}
    info = {"messages": 0, "calibrated": 0, "other_types": {}, "providers": []}
    for off, cls, mid, fr in frames:
        if (cls, mid) != ESF_MEAS:
            continue
        tag, pid, data, calib = _decode(fr[6:-2], off, where)
        info["messages"] += 1
        info["calibrated"] += calib
        if pid not in info["providers"]:
            info["providers"].append(pid)
        got: dict = {}
        for dtype, value in data:
            if dtype not in ESF_TYPES:
                info["other_types"][dtype] = info["other_types"].get(dtype, 0) + 1
                continue
            kind, axis, scale, _ = ESF_TYPES[dtype]
            if (kind, axis) in got:
                raise CdgpsError(f"{where}, byte {off}: ESF-MEAS has data type {dtype} ({kind} {axis}) twice")
            got[(kind, axis)] = value * scale
        for kind in rows:
            if any(k == kind for k, _ in got):
                rows[kind].append((off, tag, pid, [got.get((kind, a), np.nan) for a in "xyz"]))
    info["other_types"] = dict(sorted(info["other_types"].items()))
    several = len(info["providers"]) > 1
    out, bad = {}, []
    for kind, items in rows.items():
        if items:
            out[kind] = _table(kind, items, ref_s, name, several, bad)
    if bad:                                  # the first in the file
        off, msg = min(bad)
        raise CdgpsError(f"{where}, byte {off}: {msg}")
    return out, info


def _table(kind: str, items: list, ref_s: float, name: str, several: bool, bad: list) -> pd.DataFrame:
    """The table of one kind; (offset, message) of its first sample out of time order appended to ``bad``."""
    unit = _UNIT[kind]
    sensor = [f"{name}{pid if several else ''}-{kind}" for _, _, pid, _ in items]
    t = np.array([_gps_seconds(tag, ref_s) for _, tag, _, _ in items])
    df = pd.DataFrame({"time_s": t, "sensor": sensor})
    vals = np.array([v for *_, v in items], dtype=float)
    for j, a in enumerate("xyz"):
        df[f"{kind}_{a}_{unit}"] = vals[:, j]
    for s, g in df.groupby("sensor", sort=False):
        d = np.diff(g["time_s"].to_numpy())
        if np.any(d <= 0):
            i = int(g.index[np.flatnonzero(d <= 0)[0] + 1])
            prev = int(g.index[np.flatnonzero(d <= 0)[0]])
            bad.append((items[i][0], f"ESF-MEAS of sensor {s} at time tag {items[i][1]} ms is not after its previous "
                                     f"sample (byte {items[prev][0]}); its samples must be in time order, each time once"))
            break
    return df


def _first_gap(frames, n: int, stats: dict) -> str:
    """", first at byte K" for a log of UBX frames only (NMEA or RTCM between them leave gaps too)."""
    if stats["nmea_bytes"] or stats["rtcm_bytes"]:
        return ""
    pos = 0
    for off, _, _, fr in frames:
        if off > pos:
            break
        pos = off + len(fr)
    return f", first at byte {pos}" if pos < n else ""


def read_esf_log(path, ref_s: float, name: str = "imu", *, data: bytes | None = None,
                 strict: bool = True) -> tuple[dict, dict]:
    """Sensor-log tables of the ESF-MEAS messages of a UBX log (:func:`esf_tables`).

    ``strict``: a frame failing its checksum, a frame cut by the end of the file, or bytes outside any
    valid frame (a frame whose sync bytes were damaged is not seen as a frame at all) are refused
    (naming the offsets) — a sensor log given as such; a receiver's log read for its IMU passes
    False (its losses are the receiver's integrity report).  CdgpsError also when the log has no
    ESF-MEAS message.
    """
    try:
        data = open(path, "rb").read() if data is None else data
    except OSError as exc:
        raise CdgpsError(f"{path}: cannot read the sensor log: {exc.strerror or exc}") from None
    frames, _, stats = split_stream(data)
    if strict and (stats["bad_checksum_frames"] or stats["truncated_tail_bytes"] or stats["skipped_bytes"]):
        what = []
        if stats["skipped_bytes"] and not (stats["bad_checksum_frames"] or stats["truncated_tail_bytes"]):
            what.append(f"{stats['skipped_bytes']} byte(s) outside any valid frame{_first_gap(frames, len(data), stats)} "
                        "(e.g. a frame whose sync bytes were damaged: its samples would be lost)")
        if stats["bad_checksum_frames"]:
            what.append(f"{stats['bad_checksum_frames']} UBX frame(s) failing the checksum at byte(s) "
                        + ", ".join(map(str, stats["bad_frame_offsets"])))
        if stats["truncated_tail_bytes"]:
            what.append(f"a frame cut by the end of the file at byte {len(data) - stats['truncated_tail_bytes']}")
        raise CdgpsError(f"{path}: corrupt UBX sensor log: {'; '.join(what)}")
    tables, info = esf_tables(frames, str(path), ref_s, name)
    if not tables:
        found = "no ESF-MEAS message" if not info["messages"] else \
            f"{info['messages']} ESF-MEAS message(s) without accelerometer or gyro data (data types {info['other_types']})"
        raise CdgpsError(f"{path}: {found}; expected a u-blox log with UBX-ESF-MEAS accelerometer (data types 16–18) "
                         "or gyro (14, 13, 5) measurements")
    return tables, info


def receiver_imu_tables(ubx_files: dict, ref_s: float) -> tuple[list, dict]:
    """The IMU tables of receivers' UBX logs that hold ESF-MEAS messages (auto-detected: a log
    without any is not framed again).

    Parameters
    ----------
    ubx_files : dict
        {antenna: [paths]} of the UBX receiver logs; an antenna's IMU is sensor ``<antenna>-accel`` /
        ``<antenna>-gyro``.
    ref_s : float
        The run's first epoch, GPS s.

    Returns
    -------
    tables : list of (source, kind, table)
        For :func:`cdgps_cli.io.sensor_logs.sensor_attachments`.
    info : dict
        {antenna: {"files", "messages", "calibrated", "kinds", "other_types"}} of the logs with ESF-MEAS.
    """
    import gzip  # noqa: PLC0415

    tables, info = [], {}
    for ant, paths in ubx_files.items():
        mine: dict = {}
        for p in paths:
            try:
                data = open(p, "rb").read()
            except OSError as exc:
                raise CdgpsError(f"{p}: cannot read: {exc.strerror or exc}") from None
            if data[:2] == b"\x1f\x8b":
                data = gzip.decompress(data)
            if not has_esf_meas(data):
                continue
            frames, _, _ = split_stream(data)
            got, meta = esf_tables(frames, str(p), ref_s, ant)
            if not got:
                continue
            for k, df in got.items():
                mine.setdefault(k, []).append(df)
            a = info.setdefault(ant, {"files": [], "messages": 0, "calibrated": 0, "kinds": [], "other_types": {}})
            a["files"].append(str(p))
            a["messages"] += meta["messages"]
            a["calibrated"] += meta["calibrated"]
            a["kinds"] = sorted(set(a["kinds"]) | set(got))
            for t, c in meta["other_types"].items():
                a["other_types"][t] = a["other_types"].get(t, 0) + c
        for k, dfs in mine.items():     # an antenna's files joined (a time in two of them kept once)
            df = pd.concat(dfs, ignore_index=True).sort_values("time_s", kind="stable")
            df = df.drop_duplicates(["sensor", "time_s"]).reset_index(drop=True)
            tables.append((", ".join(info[ant]["files"]), k, df))
    return tables, info
