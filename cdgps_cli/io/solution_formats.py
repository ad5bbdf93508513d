"""Position solutions in the formats people already use: RTKLIB ``.pos``, NMEA GGA, GeoJSON.

The writers take the solution already in the frame they write (the caller converts ECEF to
geodetic or ENU: ``io`` holds no numerics) and return text; :func:`read_pos` reads RTKLIB ``.pos``
files (ours and RTKLIB's: ``rnx2rtkp``/``rtkpost`` output in lat/lon/height, ECEF or ENU-baseline
form, calendar GPST or week/seconds time), so solutions can be compared epoch by epoch.

RTKLIB ``.pos`` layout (RTKLIB manual, appendix "Solution file"): ``%`` header lines, the last of
them naming the columns; per epoch the time, three coordinates, ``Q`` (1 fix, 2 float, 5 single),
``ns`` (satellites), three σ (m) and three signed square roots of the covariances
(``sign(c)·√|c|``, m), the differential age (s) and the ratio.  ``rtkplot`` and ``pos2kml`` read
this layout.  NMEA GGA (NMEA 0183 v4): quality 4 = RTK fixed, 5 = RTK float; the altitude
written is the ellipsoidal height with a geoid separation of 0 (no geoid model is applied — said
in the header comment of the other formats, and by the ``M,0.000,M`` fields here).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from pathlib import Path

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import GPS_EPOCH, check_time_of_day
from cdgps_cli.core.timescales import gps_minus_utc_s

__all__ = ["POS_FRAMES", "pos_text", "nmea_gga_text", "geojson_text", "csv_text", "read_pos", "finite_or", "Q_FIX",
           "Q_FLOAT", "Q_SINGLE"]

Q_FIX, Q_FLOAT, Q_SINGLE = 1, 2, 5
#: coordinate frames of a .pos file: column names of the coordinates and of their σ / covariance roots
POS_FRAMES = {
    "llh": (("latitude(deg)", "longitude(deg)", "height(m)"),
            ("sdn(m)", "sde(m)", "sdu(m)", "sdne(m)", "sdeu(m)", "sdun(m)")),
    "xyz": (("x-ecef(m)", "y-ecef(m)", "z-ecef(m)"),
            ("sdx(m)", "sdy(m)", "sdz(m)", "sdxy(m)", "sdyz(m)", "sdzx(m)")),
    "enu": (("e-baseline(m)", "n-baseline(m)", "u-baseline(m)"),
            ("sde(m)", "sdn(m)", "sdu(m)", "sden(m)", "sdnu(m)", "sdue(m)")),
}
# the covariance pairs of each frame's last three σ columns, as indices into its coordinate order
_COV_PAIRS = {"llh": ((0, 1), (1, 2), (2, 0)), "xyz": ((0, 1), (1, 2), (2, 0)), "enu": ((0, 1), (1, 2), (2, 0))}


def _csv_column(values: np.ndarray, float_format: str) -> list[str] | None:
    """One column's fields as ``pandas.DataFrame.to_csv(float_format=...)`` writes them: floats by
    ``float_format``, NaN as an empty field, integers and booleans as ``str``; None for anything else
    (infinite values, other dtypes: the caller falls back to pandas)."""
    kind = values.dtype.kind
    if kind == "f":
        if np.isinf(values).any():
            return None
        return [float_format % v if v == v else "" for v in values.tolist()]
    if kind in "iu":
        return list(map(str, values.tolist()))
    if kind == "b":
        return ["True" if v else "False" for v in values.tolist()]
    return None


def csv_text(columns: dict, float_format: str = "%.4f") -> str:
    """A CSV table (header line of the column names, one line per row, ``\\n`` line ends) byte for byte
    as ``pandas.DataFrame(columns).to_csv(index=False, float_format=float_format)`` writes it, without
    pandas' per-call set-up (a few ms a run: the rtk command's output).  ``columns``: name → 1-D array,
    all of one length; names without quotes, commas or line breaks.  Columns of other kinds (strings,
    infinite values) and one-column tables (pandas quotes an empty field there) are written by pandas itself."""
    cols = [np.asarray(v) for v in columns.values()]
    fields = [_csv_column(c, float_format) for c in cols]
    if len(cols) < 2 or len({c.shape for c in cols}) > 1 or cols[0].ndim != 1 or any(f is None for f in fields) or any(not isinstance(k, str) or any(ch in k for ch in ',"\n\r') for k in columns):
        import io  # noqa: PLC0415

        import pandas as pd  # noqa: PLC0415  (rare: the general writer)

        buf = io.StringIO()
        pd.DataFrame(columns).to_csv(buf, index=False, float_format=float_format)
        return buf.getvalue()
    lines = [",".join(columns)]
    lines += map(",".join, zip(*fields))
    return "\n".join(lines) + "\n"


def _calendar(t_gps_s: float) -> str:
    ms = int(round(t_gps_s * 1000.0))
    d = GPS_EPOCH + _dt.timedelta(milliseconds=ms)
    return d.strftime("%Y/%m/%d %H:%M:%S.") + f"{d.microsecond // 1000:03d}"


def _signed_root(c):
    return np.sign(c) * np.sqrt(np.abs(c))


#: the largest ratio a .pos line gives, as RTKLIB caps it (its fixed-width column; a held static fix reaches 10⁵)
POS_RATIO_MAX = 999.9


def pos_text(time_gps_s, coords, q, ns, cov, age_s, ratio, *, frame: str, header: list[str],
             velocity_neu=None) -> str:
    """An RTKLIB ``.pos`` file.

    Parameters
    ----------
    time_gps_s : array_like (n,)
        Epoch times, GPS s.
    coords : array_like (n, 3)
        Latitude and longitude (degrees) and height (m); or ECEF x, y, z (m); or east, north, up
        of the baseline (m) — by ``frame``.
    q, ns : array_like of int (n,)
        Solution quality (:data:`Q_FIX`, :data:`Q_FLOAT`, :data:`Q_SINGLE`) and satellites used.
    cov : array_like (n, 3, 3)
        Covariance of the coordinates, m² (for ``llh``: of north, east, up).
    age_s, ratio : array_like (n,)
        Differential age (s) and the ratio test value (0 where none; written at most :data:`POS_RATIO_MAX`).
    frame : {"llh", "xyz", "enu"}
    header : list of str
        Lines for the ``%`` header (program, inputs, options, reference position …).
    velocity_neu : tuple of array_like, optional
        The velocity in the local north, east, up axes (n, 3; m/s) and its covariance (n, 3, 3; m²/s²),
        written as RTKLIB's nine velocity columns after ``ratio`` (``vn ve vu`` and ``sdvn sdve sdvu sdvne
        sdveu sdvun``, its ``out-outvel`` layout).
    """
    if frame not in POS_FRAMES:
        raise ValueError(f"frame: expected one of {', '.join(POS_FRAMES)}, got {frame!r}")
    names, sd_names = POS_FRAMES[frame]
    c = np.asarray(coords, dtype=float)
    P = np.asarray(cov, dtype=float)
    sd = np.sqrt(np.abs(np.stack([P[:, i, i] for i in range(3)], axis=1)))
    cr = np.stack([_signed_root(P[:, i, j]) for i, j in _COV_PAIRS[frame]], axis=1)
    out = [f"% {h}" for h in header]
    out.append("%")
    if frame == "xyz":      # RTKLIB's readers (pos2kml, rtkplot) tell an ECEF file by this comment's "(x/y/z-ecef="
        out.append("% (x/y/z-ecef=WGS84,Q=1:fix,2:float,5:single,ns=# of satellites)")
    else:
        out.append("% (Q=1:fix,2:float,5:single,ns=# of satellites; " +
                   ("lat/lon/height=WGS84/ellipsoidal" if frame == "llh" else "e/n/u-baseline=WGS84") + ")")
    vel = _velocity_fields(velocity_neu, c.shape[0])
    out.append(f"%  GPST                  {names[0]:>14s} {names[1]:>14s} {names[2]:>14s}   Q  ns "
               + " ".join(f"{n:>8s}" for n in sd_names) + "  age(s)  ratio" + (_POS_VELOCITY_HEAD if vel else ""))
    fmt = "{:14.9f} {:14.9f} {:10.4f}" if frame == "llh" else "{:14.4f} {:14.4f} {:14.4f}"
    for k in range(c.shape[0]):
        out.append(f"{_calendar(float(time_gps_s[k]))} " + fmt.format(*c[k]) + f" {int(q[k]):3d} {int(ns[k]):3d} "
                   + " ".join(f"{_unsigned_zero(v, 4):8.4f}" for v in (*sd[k], *cr[k]))
                   + f" {_unsigned_zero(age_s[k], 2):6.2f} {min(float(ratio[k]), POS_RATIO_MAX):6.1f}"
                   + (vel[k] if vel else ""))
    return "\n".join(out) + "\n"


#: RTKLIB's velocity column heads (``out-outvel``), after ``ratio``
_POS_VELOCITY_HEAD = ("    vn(m/s)    ve(m/s)    vu(m/s)      sdvn     sdve     sdvu    sdvne    sdveu    sdvun")


def _velocity_fields(velocity_neu, n: int) -> list[str] | None:
    """Each epoch's velocity columns of a ``.pos`` line (:func:`pos_text`), or None without a velocity."""
    if velocity_neu is None:
        return None
    v, C = (np.asarray(a, dtype=float) for a in velocity_neu)
    if v.shape != (n, 3) or C.shape != (n, 3, 3):
        raise ValueError(f"velocity_neu: expected shapes ({n}, 3) and ({n}, 3, 3), got {v.shape} and {C.shape}")
    sd = np.sqrt(np.abs(np.stack([C[:, i, i] for i in range(3)], axis=1)))
    cr = np.stack([_signed_root(C[:, i, j]) for i, j in ((0, 1), (1, 2), (2, 0))], axis=1)
    return [" " + " ".join(f"{_unsigned_zero(x, 5):10.5f}" for x in v[k]) + " "
            + f"{_unsigned_zero(sd[k, 0], 5):9.5f} " + " ".join(f"{_unsigned_zero(x, 5):8.5f}" for x in (*sd[k, 1:], *cr[k]))
            for k in range(n)]


def _unsigned_zero(value, decimals: int) -> float:
    """``value``, or +0.0 when it rounds to zero at ``decimals`` (no ``-0.00`` in the files)."""
    v = float(value)
    return 0.0 if round(v, decimals) == 0 else v


#: the longest NMEA 0183 sentence, ``$`` to the checksum included: the standard's 82 characters count the CR LF
#: (a real M8P run wrote 463 of 1201 GGA sentences of 81, which casters and receivers that hold to it refuse)
NMEA_MAX_CHARS = 80
#: decimals of the minutes of latitude and longitude in GGA (RTKLIB's: 1e-7 min ≈ 0.2 mm)
GGA_MINUTE_DECIMALS = 7


def _dm(deg: float, width: int, decimals: int) -> tuple[str, bool]:
    a = abs(deg)
    d = int(a)
    m = round((a - d) * 60.0, decimals)
    if m >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:0{width}d}{m:0{3 + decimals}.{decimals}f}", deg >= 0


def _nmea(body: str) -> str:
    x = 0
    for ch in body.encode("ascii"):
        x ^= ch
    return f"${body}*{x:02X}"


def _gga(utc, lat_deg, lon_deg, q, ns, height_m, age_s) -> str:
    """One GGA sentence of at most :data:`NMEA_MAX_CHARS`: minutes with :data:`GGA_MINUTE_DECIMALS`
    decimals, fewer where the height, the age and the longitude's degrees would not fit otherwise (6: 1.8 mm).
    The age of the differential data is the time between the rover epoch and its base epoch, whichever came
    first (NMEA's field is a time since, never negative; RTKLIB's combined mode writes the sign)."""
    age = _unsigned_zero(abs(float(age_s)), 1)
    for decimals in range(GGA_MINUTE_DECIMALS, 2, -1):
        lat, north = _dm(lat_deg, 2, decimals)
        lon, east = _dm(lon_deg, 3, decimals)
        s = _nmea(f"GPGGA,{utc:%H%M%S}.{utc.microsecond // 10000:02d},{lat},{'N' if north else 'S'},{lon},"
                  f"{'E' if east else 'W'},{q},{ns:02d},,{_unsigned_zero(height_m, 3):.3f},M,0.0,M,{age:.1f},0000")
        if len(s) <= NMEA_MAX_CHARS:
            break
    return s


def nmea_gga_text(time_gps_s, lat_deg, lon_deg, height_m, q, ns, age_s) -> str:
    """NMEA GGA sentences (UTC = GPS − leap seconds; quality 4 RTK fixed, 5 float, 1 single), each at
    most :data:`NMEA_MAX_CHARS` characters and CR LF: minutes of latitude and longitude with 7 decimals (as
    RTKLIB) where they fit, else 6, the height (ellipsoidal, geoid separation 0.0) in mm, HDOP empty (not
    computed), the differential age in 0.1 s (its magnitude) and station 0000."""
    gga_q = {Q_FIX: 4, Q_FLOAT: 5, Q_SINGLE: 1}
    out = []
    for k in range(len(time_gps_s)):
        t = float(time_gps_s[k])
        utc = GPS_EPOCH + _dt.timedelta(milliseconds=int(round((t - int(gps_minus_utc_s(t))) * 1000.0)))
        out.append(_gga(utc, float(lat_deg[k]), float(lon_deg[k]), gga_q.get(int(q[k]), 0), min(int(ns[k]), 99),
                        float(height_m[k]), float(age_s[k])))
    return "\r\n".join(out) + "\r\n"


def geojson_text(time_gps_s, lat_deg, lon_deg, height_m, q, ns, sigma_enu_m, *, properties: dict,
                 velocity_enu=None) -> str:
    """A GeoJSON FeatureCollection of one Point per epoch ([lon, lat, h], WGS84), with the epoch's
    ``time_gps_s``, ``q``, ``ns`` and ``sigma_e_m``/``sigma_n_m``/``sigma_u_m``; with ``velocity_enu``
    (the velocity (n, 3) and its σ (n, 3) in the local east, north, up axes, m/s) also ``ve_m_s`` … and
    ``sigma_ve_m_s`` …."""
    sig = np.asarray(sigma_enu_m, dtype=float)
    feats = [{"type": "Feature",
              "geometry": {"type": "Point", "coordinates": [round(float(lon_deg[k]), 10), round(float(lat_deg[k]), 10),
                                                            round(float(height_m[k]), 4)]},
              "properties": {"time_gps_s": float(time_gps_s[k]), "q": int(q[k]), "ns": int(ns[k]),
                             "sigma_e_m": round(float(sig[k, 0]), 5), "sigma_n_m": round(float(sig[k, 1]), 5),
                             "sigma_u_m": round(float(sig[k, 2]), 5), **_velocity_properties(velocity_enu, k)}}
             for k in range(len(time_gps_s))]
    return json.dumps({"type": "FeatureCollection", "properties": properties, "features": feats}, indent=1) + "\n"


def _velocity_properties(velocity_enu, k: int) -> dict:
    """Epoch ``k``'s velocity properties of a GeoJSON point (:func:`geojson_text`); none without a velocity."""
    if velocity_enu is None:
        return {}
    v, sd = velocity_enu
    return {**{f"v{a}_m_s": round(float(v[k, i]), 5) for i, a in enumerate("enu")},
            **{f"sigma_v{a}_m_s": round(float(sd[k, i]), 5) for i, a in enumerate("enu")}}


def _pos_time(fields: list[str], path, lineno) -> tuple[float, int]:
    """GPS seconds of a data line's time and the number of fields it takes."""
    try:
        if "/" in fields[0]:
            y, mo, d = (int(x) for x in fields[0].split("/"))
            hh, mm, ss = fields[1].split(":")
            check_time_of_day(int(hh), int(mm), float(ss))      # 00:59:61 is damage, not 01:00:01
            base = (_dt.datetime(y, mo, d, int(hh), int(mm)) - GPS_EPOCH).total_seconds()
            return base + float(ss), 2
        return int(fields[0]) * 604800.0 + float(fields[1]), 2
    except (ValueError, IndexError) as exc:
        note = f" ({exc})" if "must be in" in str(exc) else ""
        raise CdgpsError(f"{path}, line {lineno}: expected a time 'YYYY/MM/DD hh:mm:ss.sss' or 'week seconds', "
                         f"got {' '.join(fields[:2])!r}{note}") from None


def read_pos(path) -> dict:
    """An RTKLIB ``.pos`` file (GPST times; lat/lon/height, ECEF or ENU-baseline coordinates).

    Returns
    -------
    dict
        ``frame`` ("llh", "xyz" or "enu"), ``time_gps_s`` (n,), ``coords`` (n, 3), ``q`` (n,),
        ``ns`` (n,), ``sd`` (n, 6; the σ and covariance-root columns as written), ``age_s`` (n,),
        ``ratio`` (n,), ``header`` (the ``%`` lines).

    Raises
    ------
    CdgpsError
        Naming the file and line: no column header, a UTC/JST time scale, a malformed line.
    """
    p = Path(path)
    try:
        lines = p.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read ({exc.strerror})") from None
    header = [ln for ln in lines if ln.startswith("%")]
    cols = next((ln for ln in reversed(header) if "Q" in ln.split() and "ns" in ln.split()), None)
    if cols is None:
        raise CdgpsError(f"{p}: not an RTKLIB .pos file: no '%' header line naming the columns (… Q  ns …)")
    if "UTC" in cols or "JST" in cols:
        raise CdgpsError(f"{p}: times in UTC/JST are not read; write the solution in GPST (RTKLIB out-timesys=gpst)")
    frame = "llh" if "latitude(deg)" in cols else "xyz" if "x-ecef(m)" in cols else "enu" if "e-baseline(m)" in cols else None
    if frame is None:
        raise CdgpsError(f"{p}: the column header names no coordinates RTKLIB writes (latitude(deg), x-ecef(m), "
                         f"e-baseline(m)): {cols!r}")
    rows = []
    n_fields = len(cols.lstrip("%").split()) + 1          # the time label (GPST) heads two fields
    for i, ln in enumerate(lines, 1):
        if not ln.strip() or ln.startswith("%"):
            continue
        f = ln.split()
        t, k = _pos_time(f, p, i)
        if len(f) < n_fields:
            raise CdgpsError(f"{p}, line {i}: {len(f)} fields, the column header promises {n_fields} "
                             f"({' '.join(cols.lstrip('%').split()[-2:])} last); is the file cut short?")
        try:
            v = [float(x) for x in f[k:k + 13]]
        except ValueError:
            raise CdgpsError(f"{p}, line {i}: expected numbers after the time, got {' '.join(f[k:k + 13])!r}") from None
        if len(v) < 13:
            raise CdgpsError(f"{p}, line {i}: expected 13 values after the time (coordinates, Q, ns, 6 σ, age, "
                             f"ratio), got {len(v)}")
        if not all(math.isfinite(c) for c in v[:3]):
            raise CdgpsError(f"{p}, line {i}: expected finite coordinates, got {' '.join(f[k:k + 3])!r}")
        if not all(c >= 0 and c.is_integer() for c in v[3:5]):
            raise CdgpsError(f"{p}, line {i}: expected whole numbers >= 0 for Q and ns, got {' '.join(f[k + 3:k + 5])!r}")
        rows.append([t, *v])
    a = np.array(rows, dtype=float).reshape(-1, 14)
    return {"frame": frame, "time_gps_s": a[:, 0], "coords": a[:, 1:4], "q": a[:, 4].astype(int),
            "ns": a[:, 5].astype(int), "sd": a[:, 6:12], "age_s": a[:, 12], "ratio": a[:, 13], "header": header}


def finite_or(value, default: float) -> float:
    """``value`` if finite, else ``default`` (ratios of unfixed epochs are NaN)."""
    return float(value) if value is not None and math.isfinite(value) else default
