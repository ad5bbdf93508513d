"""RINEX 3.04 writers: GPS L1 observation files and GPS navigation files.

The counterparts of :func:`~cdgps_cli.io.rinex.read_rinex_obs` and
:func:`~cdgps_cli.io.rinex.read_rinex_nav`, written from the same tables, so that simulated
receivers (``cdgps simulate-gnss``) produce files any RINEX tool reads and our own readers read
back unchanged (a tested round trip):

* :func:`write_rinex_obs` — one GPS receiver, observation types ``C1C L1C S1C`` (pseudorange,
  carrier phase with its LLI and signal-strength digit, C/N0), epoch flags 0/1, the receiver
  clock offset on the epoch line when known;
* :func:`write_rinex_obs_signals` — one multi-GNSS, multi-frequency receiver (``M: MIXED``), per
  signal of :mod:`cdgps_cli.core.signals` the code and phase types of its first tracking attribute
  (``G:L2`` → ``C2X L2X``, ``E:E5a`` → ``C5Q L5Q``);
* :func:`write_rinex_nav` — GPS (and Galileo: ``M: MIXED``) broadcast ephemerides (the 29 values of each record, ``D19.12``
  style with an ``E`` exponent, which RINEX allows).

Resolution: phases and pseudoranges are written with 3 decimals (1 mcycle ≈ 0.19 mm, 1 mm),
epoch times with 7 (0.1 µs), ephemeris values with 13 significant digits.  Files are written
atomically (temporary name, then rename).
"""

from __future__ import annotations

import datetime as _dt
import math
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli import __version__
from cdgps_cli.io.atomic import write_atomic
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import GPS_EPOCH, GPS_MINUS_BDT_S
from cdgps_cli.core.records import NAV_COLUMNS

__all__ = ["write_rinex_obs", "write_rinex_obs_signals", "write_rinex_nav", "rinex_calendar"]


def _hl(body: str, label: str) -> str:
    """One header line: 60 columns of content and the label in columns 61-80."""
    if len(body) > 60:
        raise ValueError(f"RINEX header field too long for {label!r}: {body!r}")
    return f"{body:<60}{label:<20}"


def _created(created: str | None) -> str:
    if created:
        return created[:20]
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%d %H%M%S") + " UTC"


def rinex_calendar(t_gps_s: float) -> tuple[int, int, int, int, int, float]:
    """GPS seconds → (year, month, day, hour, minute, seconds) in GPS time (0.1 µs rounding)."""
    t = round(float(t_gps_s), 7)
    whole = math.floor(t)
    frac = round(t - whole, 7)
    if frac >= 1.0:
        whole += 1
        frac = 0.0
    d = GPS_EPOCH + _dt.timedelta(seconds=int(whole))
    return d.year, d.month, d.day, d.hour, d.minute, d.second + frac


def _field(v: float, what: str) -> str:
    if not np.isfinite(v):
        return " " * 14
    s = f"{v:14.3f}"
    if len(s) > 14:
        raise CdgpsError(f"cannot write {what} {v!r} in a RINEX F14.3 field (too large)")
    return s


def write_rinex_obs(path: str | Path, obs: pd.DataFrame, header: dict | None = None, *, created: str | None = None) -> dict:
    """Write one GPS receiver's L1 observations as a RINEX 3.04 observation file.

    Parameters
    ----------
    path : str or Path
        Output file (written atomically).
    obs : DataFrame
        Rows as returned by :func:`~cdgps_cli.io.rinex.read_rinex_obs` (:data:`~cdgps_cli.io.rinex.OBS_COLUMNS`;
        ``time_gps_s``, ``sat`` and ``phase_l1_cycles`` are required, the others default to blank
        or 0).  Rows are sorted by time and satellite before writing.
    header : dict, optional
        ``marker_name``, ``marker_number``, ``observer``, ``agency``, ``receiver_number``,
        ``receiver_type``, ``receiver_version``, ``antenna_number``, ``antenna_type``,
        ``approx_position_xyz_m`` (ECEF m; omitted if None), ``antenna_delta_hen_m``,
        ``interval_s``, ``comments`` (list of str).
    created : str, optional
        File creation stamp of the PGM / RUN BY / DATE line, ``YYYYMMDD HHMMSS UTC`` (default:
        now; give one for reproducible files).

    Returns
    -------
    dict
        ``path``, ``epochs``, ``records`` (satellite-epoch lines), ``first_gps_s``, ``last_gps_s``.

    Raises
    ------
    CdgpsError
        No rows, a satellite that is not GPS, a value too large for its field, or the file
        cannot be written.
    """
    h = dict(header or {})
    if len(obs) == 0:
        raise CdgpsError(f"{path}: no observations to write")
    o = obs.sort_values(["time_gps_s", "sat"], kind="stable")
    sats = o["sat"].astype(str).to_numpy()
    bad = [s for s in np.unique(sats) if len(s) != 3 or s[0] != "G" or not s[1:].isdigit()]
    if bad:
        raise CdgpsError(f"{path}: only GPS satellites ('G05') can be written, got {', '.join(bad[:5])}")
    n = len(o)

    def col(name, default):
        return o[name].to_numpy() if name in o.columns else np.full(n, default)

    t = o["time_gps_s"].to_numpy(dtype=np.float64)
    phase = col("phase_l1_cycles", np.nan).astype(np.float64)
    code = col("pseudorange_l1_m", np.nan).astype(np.float64)
    snr = col("snr_l1_dbhz", np.nan).astype(np.float64)
    lli = col("lli_l1", 0).astype(np.int64)
    ssi = col("ssi_l1", 0).astype(np.int64)
    clk = col("rx_clock_offset_s", np.nan).astype(np.float64)
    flag = col("epoch_flag", 0).astype(np.int64)
    if np.any((lli < 0) | (lli > 9)) or np.any((ssi < 0) | (ssi > 9)):
        raise CdgpsError(f"{path}: LLI and signal-strength digits must be 0-9")
    # a signal-strength digit from C/N0 where none is given (RINEX 3: 1 ≤ 12 dBHz … 9 ≥ 54 dBHz)
    ssi = np.where((ssi == 0) & np.isfinite(snr), np.clip(np.floor(np.nan_to_num(snr) / 6.0), 1, 9), ssi).astype(np.int64)

    types = ["C1C", "L1C", "S1C"]
    first = rinex_calendar(t[0])
    last = rinex_calendar(t[-1])
    ts = h.get("time_system") or "GPS"
    lines = [
        _hl(f"{'3.04':>9}{'':11}{'OBSERVATION DATA':<20}{'G: GPS':<20}", "RINEX VERSION / TYPE"),
        _hl(f"{('cdgps ' + __version__)[:20]:<20}{'cdgps':<20}{_created(created):<20}",
            "PGM / RUN BY / DATE"),
    ]
    lines += _station_lines(h)
    lines.append(_hl(f"G  {len(types):3d}" + "".join(f" {ty}" for ty in types), "SYS / # / OBS TYPES"))
    lines.append(_hl("DBHZ", "SIGNAL STRENGTH UNIT"))
    if h.get("interval_s"):
        lines.append(_hl(f"{float(h['interval_s']):10.3f}", "INTERVAL"))
    lines += _time_lines(first, last, ts)
    if np.isfinite(clk).any():
        lines.append(_hl(f"{0:6d}", "RCV CLOCK OFFS APPL"))
    lines.append(_hl("G L1C", "SYS / PHASE SHIFT"))
    lines.append(_hl("", "GLONASS COD/PHS/BIS"))
    lines.append(_hl("", "END OF HEADER"))

    # observation records, then epoch lines in front of each epoch's records
    for name, v in (("phase", phase), ("pseudorange", code), ("C/N0", snr)):
        fin = v[np.isfinite(v)]
        if fin.size and np.max(np.abs(fin)) >= 1e10:
            raise CdgpsError(f"{path}: a {name} value is too large for a RINEX F14.3 field: {np.max(np.abs(fin))!r}")
    recs = [
        f"{s}{_field(c, 'pseudorange')}  {_field(p, 'phase')}{(str(li) if li else ' ') if np.isfinite(p) else ' '}"
        f"{(str(si) if si else ' ') if np.isfinite(p) else ' '}{_field(q, 'C/N0')}".rstrip()
        for s, c, p, li, si, q in zip(sats.tolist(), code.tolist(), phase.tolist(), lli.tolist(), ssi.tolist(), snr.tolist())
    ]
    cuts = np.flatnonzero(np.r_[True, t[1:] != t[:-1], True])
    body = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        y, mo, d, hh, mi, sec = rinex_calendar(t[a])
        ck = clk[a]
        ctext = f"{'':6}{ck:15.12f}" if np.isfinite(ck) else ""
        body.append(f"> {y:4d} {mo:02d} {d:02d} {hh:02d} {mi:02d}{sec:11.7f}  {int(flag[a]):1d}{b - a:3d}{ctext}")
        body.extend(recs[a:b])
    text = "\n".join(lines + body) + "\n"
    write_atomic(path, lambda p: p.write_text(text, encoding="ascii"))
    return {"path": str(path), "epochs": int(cuts.size - 1), "records": int(n), "first_gps_s": float(t[0]),
            "last_gps_s": float(t[-1])}


def _time_lines(first, last, ts: str) -> list:
    """TIME OF FIRST OBS / TIME OF LAST OBS lines of calendar tuples ``first``, ``last``."""
    return [_hl(f"{c[0]:6d}{c[1]:6d}{c[2]:6d}{c[3]:6d}{c[4]:6d}{c[5]:13.7f}{'':5}{ts:<3}", label)
            for c, label in ((first, "TIME OF FIRST OBS"), (last, "TIME OF LAST OBS"))]


def write_rinex_obs_signals(path: str | Path, obs: pd.DataFrame, signals, header: dict | None = None, *,
                            created: str | None = None) -> dict:
    """Write one receiver's multi-GNSS, multi-frequency observations as a RINEX 3.04 file.

    Parameters
    ----------
    path : str or Path
        Output file (written atomically).
    obs : DataFrame
        ``time_gps_s``, ``sat``, ``signal`` (names of :mod:`cdgps_cli.core.signals`), ``phase_cycles``,
        ``pseudorange_m``; optional ``lli`` (0–9) and ``snr_dbhz``.  One row per epoch, satellite and signal.
    signals : sequence of str
        The signals of the file, in the order of their observation types (code ``C``, phase ``L``,
        C/N0 ``S`` of each, with the signal's first tracking attribute).
    header, created : as :func:`write_rinex_obs`.

    Returns
    -------
    dict
        ``path``, ``epochs``, ``records``, ``first_gps_s``, ``last_gps_s``, ``obs_types`` ({system: [types]}).
    """
    from cdgps_cli.core.signals import signal as _signal  # noqa: PLC0415

    h = dict(header or {})
    if len(obs) == 0:
        raise CdgpsError(f"{path}: no observations to write")
    sigs = [_signal(g) for g in dict.fromkeys(signals)]
    types: dict = {}
    for g in sigs:
        types.setdefault(g.system, []).extend(f"{k}{g.band}{g.attributes[0]}" for k in "CLS")
    unknown = sorted(set(obs["signal"]) - {g.name for g in sigs})
    if unknown:
        raise CdgpsError(f"{path}: rows of signal(s) {', '.join(unknown)} not in the signals to write")
    o = obs.sort_values(["time_gps_s", "sat"], kind="stable")
    t_all = o["time_gps_s"].to_numpy(dtype=np.float64)
    ts = h.get("time_system") or "GPS"
    lines = [_hl(f"{'3.04':>9}{'':11}{'OBSERVATION DATA':<20}{'M: MIXED':<20}", "RINEX VERSION / TYPE"),
             _hl(f"{('cdgps ' + __version__)[:20]:<20}{'cdgps':<20}{_created(created):<20}", "PGM / RUN BY / DATE")]
    lines += _station_lines(h)
    for c, ty in types.items():
        for i in range(0, len(ty), 13):
            head = f"{c}  {len(ty):3d}" if i == 0 else " " * 6
            lines.append(_hl(head + "".join(f" {x}" for x in ty[i:i + 13]), "SYS / # / OBS TYPES"))
    lines.append(_hl("DBHZ", "SIGNAL STRENGTH UNIT"))
    if h.get("interval_s"):
        lines.append(_hl(f"{float(h['interval_s']):10.3f}", "INTERVAL"))
    lines += _time_lines(rinex_calendar(t_all[0]), rinex_calendar(t_all[-1]), ts)
    lines += [_hl("", "END OF HEADER")]
    # one record per (epoch, satellite): its system's types, each 16 columns (F14.3, LLI, SSI)
    sats = o["sat"].astype(str).to_numpy()
    slot = {(g.system, g.name): types[g.system].index(f"C{g.band}{g.attributes[0]}") for g in sigs}
    col = np.array([slot[(s[0], g)] for s, g in zip(sats, o["signal"].to_numpy())])
    n = len(o)
    snr = (o["snr_dbhz"] if "snr_dbhz" in o.columns else pd.Series(np.full(n, np.nan))).to_numpy(dtype=np.float64)
    lli = (o["lli"] if "lli" in o.columns else pd.Series(np.zeros(n))).to_numpy().astype(np.int64)
    ssi = np.where(np.isfinite(snr), np.clip(np.floor(np.nan_to_num(snr) / 6.0), 1, 9), 0).astype(np.int64)
    fields = zip(o["pseudorange_m"].to_numpy(dtype=np.float64).tolist(), o["phase_cycles"].to_numpy(dtype=np.float64).tolist(),
                 lli.tolist(), ssi.tolist(), snr.tolist())
    new_rec = np.r_[True, (t_all[1:] != t_all[:-1]) | (sats[1:] != sats[:-1])]
    recs, rec_t = [], []
    for k, (pr, ph, li, si, q) in enumerate(fields):
        if new_rec[k]:
            recs.append([sats[k]] + [" " * 16] * len(types[sats[k][0]]))
            rec_t.append(t_all[k])
        r, c = recs[-1], col[k] + 1
        r[c] = _field(pr, "pseudorange") + "  "
        r[c + 1] = _field(ph, "phase") + (str(li) if li else " ") + (str(si) if si else " ")
        r[c + 2] = _field(q, "C/N0") + "  "
    rec_t = np.asarray(rec_t)
    cuts = np.flatnonzero(np.r_[True, rec_t[1:] != rec_t[:-1], True])
    body = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        y, mo, d, hh, mi, sec = rinex_calendar(float(rec_t[a]))
        body.append(f"> {y:4d} {mo:02d} {d:02d} {hh:02d} {mi:02d}{sec:11.7f}  0{b - a:3d}")
        body += ["".join(r).rstrip() for r in recs[a:b]]
    n_rec = len(recs)
    text = "\n".join(lines + body) + "\n"
    write_atomic(path, lambda p: p.write_text(text, encoding="ascii"))
    return {"path": str(path), "epochs": int(np.unique(t_all).size), "records": n_rec, "first_gps_s": float(t_all[0]),
            "last_gps_s": float(t_all[-1]), "obs_types": types}


def _station_lines(h: dict) -> list:
    """Header lines from COMMENT to ANTENNA: DELTA H/E/N of the header dict ``h``."""
    lines = []
    for c in h.get("comments") or []:
        lines.append(_hl(str(c)[:60], "COMMENT"))
    lines.append(_hl(str(h.get("marker_name") or "UNKNOWN")[:60], "MARKER NAME"))
    if h.get("marker_number"):
        lines.append(_hl(str(h["marker_number"])[:20], "MARKER NUMBER"))
    lines.append(_hl("GEODETIC", "MARKER TYPE"))
    lines.append(_hl(f"{str(h.get('observer') or '')[:20]:<20}{str(h.get('agency') or '')[:40]:<40}", "OBSERVER / AGENCY"))
    lines.append(_hl(f"{str(h.get('receiver_number') or '')[:20]:<20}{str(h.get('receiver_type') or '')[:20]:<20}"
                     f"{str(h.get('receiver_version') or '')[:20]:<20}", "REC # / TYPE / VERS"))
    lines.append(_hl(f"{str(h.get('antenna_number') or '')[:20]:<20}{str(h.get('antenna_type') or '')[:20]:<20}", "ANT # / TYPE"))
    pos = h.get("approx_position_xyz_m")
    if pos is not None:
        x, y, z = (float(v) for v in pos)
        lines.append(_hl(f"{x:14.4f}{y:14.4f}{z:14.4f}", "APPROX POSITION XYZ"))
    dh = h.get("antenna_delta_hen_m") or (0.0, 0.0, 0.0)
    lines.append(_hl(f"{float(dh[0]):14.4f}{float(dh[1]):14.4f}{float(dh[2]):14.4f}", "ANTENNA: DELTA H/E/N"))
    return lines


def _d19(v: float) -> str:
    """A broadcast-orbit value in 19 columns (``±d.dddddddddddddE±ee``)."""
    if not np.isfinite(v):
        return " " * 19
    s = f"{v: .12E}"
    if len(s) != 19:
        raise CdgpsError(f"cannot write {v!r} in a 19-column RINEX navigation field")
    return s


_ORBIT_LINES = (
    ("iode", "crs_m", "delta_n_rad_per_s", "m0_rad"),
    ("cuc_rad", "e", "cus_rad", "sqrt_a_sqrt_m"),
    ("toe_sow_s", "cic_rad", "omega0_rad", "cis_rad"),
    ("i0_rad", "crc_m", "omega_rad", "omega_dot_rad_per_s"),
    ("idot_rad_per_s", "codes_l2", "week", "l2p_data_flag"),
    ("sv_accuracy_m", "sv_health", "tgd_s", "iodc"),
    ("transmit_sow_s", "fit_interval_h"),
)
# BeiDou (RINEX 3.04 Table A14): TGD2 where GPS has IODC (not kept: written blank), AODC where GPS has
# the fit interval; week, toe and transmission time in BDT (``week``/``toe_sow_s``/``transmit_sow_s``)
_BEIDOU_ORBIT_LINES = _ORBIT_LINES[:5] + (("sv_accuracy_m", "sv_health", "tgd_s", "_blank"), ("transmit_sow_s", "iodc"))


def write_rinex_nav(path: str | Path, nav: pd.DataFrame, *, leap_seconds: int | None = None,
                    comments=(), created: str | None = None) -> dict:
    """Write broadcast ephemerides (GPS, Galileo, BeiDou, QZSS Kepler records) as a RINEX 3.04 navigation file.

    Parameters
    ----------
    path : str or Path
        Output file (written atomically).
    nav : DataFrame
        Ephemerides with the columns of :data:`~cdgps_cli.io.rinex.NAV_COLUMNS` (``line`` and the
        derived GPS-second columns other than ``toc_gps_s`` are not needed).  Integer fields
        stored as −1 (blank in the source file) are written blank.
    leap_seconds : int, optional
        GPS − UTC, s, for the LEAP SECONDS header line.
    comments : sequence of str
        COMMENT lines.
    created : str, optional
        As for :func:`write_rinex_obs`.

    Returns
    -------
    dict
        ``path``, ``records``, ``satellites``.
    """
    if len(nav) == 0:
        raise CdgpsError(f"{path}: no ephemerides to write")
    missing = [c for c in NAV_COLUMNS if c not in nav.columns and c not in ("line", "toe_gps_s", "transmit_gps_s")]
    if missing:
        raise CdgpsError(f"{path}: the ephemeris table lacks {', '.join(missing)}")
    sys_field = "G: GPS" if set(nav["sat"].astype(str).str[0]) <= {"G"} else "M: MIXED"
    lines = [
        _hl(f"{'3.04':>9}{'':11}{'N: GNSS NAV DATA':<20}{sys_field:<20}", "RINEX VERSION / TYPE"),
        _hl(f"{('cdgps ' + __version__)[:20]:<20}{'cdgps':<20}{_created(created):<20}",
            "PGM / RUN BY / DATE"),
    ]
    for c in comments:
        lines.append(_hl(str(c)[:60], "COMMENT"))
    if leap_seconds is not None:
        lines.append(_hl(f"{int(leap_seconds):6d}", "LEAP SECONDS"))
    lines.append(_hl("", "END OF HEADER"))
    ints = {"iode", "codes_l2", "l2p_data_flag", "sv_health", "iodc"}
    n = nav.sort_values(["sat", "toc_gps_s"], kind="stable")
    for r in n.itertuples(index=False):
        rr = r._asdict()
        bds = str(rr["sat"]).startswith("C")
        lines_ = _BEIDOU_ORBIT_LINES if bds else _ORBIT_LINES
        rr["_blank"] = math.nan
        if str(rr["sat"]).startswith("J"):       # QZSS: RINEX 3 holds the fit-interval flag (0: 2 h, 1: longer)
            rr["fit_interval_h"] = 0.0 if rr["fit_interval_h"] == 2.0 else 1.0
        # BeiDou: the epoch of toc in BDT (GPST − 14 s), as read_rinex_nav expects
        y, mo, d, hh, mi, sec = rinex_calendar(rr["toc_gps_s"] - (GPS_MINUS_BDT_S if bds else 0.0))
        if abs(sec - round(sec)) > 1e-6:
            raise CdgpsError(f"{path}: toc of {rr['sat']} is not a whole second ({rr['toc_gps_s']!r})")
        lines.append(f"{rr['sat']} {y:4d} {mo:02d} {d:02d} {hh:02d} {mi:02d} {int(round(sec)):02d}"
                     + "".join(_d19(float(rr[k])) for k in ("af0_s", "af1_s_per_s", "af2_s_per_s2")))
        for keys in lines_:
            vals = []
            for k in keys:
                v = float(rr[k])
                if k in ints and v == -1:
                    v = math.nan
                vals.append(_d19(v))
            lines.append(("    " + "".join(vals)).rstrip())
    text = "\n".join(lines) + "\n"
    write_atomic(path, lambda p: p.write_text(text, encoding="ascii"))
    return {"path": str(path), "records": int(len(n)), "satellites": sorted(n["sat"].unique().tolist())}

