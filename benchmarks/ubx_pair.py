#!/usr/bin/env python3
"""Long u-blox UBX base/rover logs at 10 Hz for ``cdgps ingest --ubx`` in bounded memory (issue 29).

For each ``--hours`` value a simulated pair is made (or reused) by ``benchmarks/long_records.py``'s
:func:`simulated_pair` (``cdgps simulate-gnss --rate-hz RATE --slips 30 --seed 1``: RINEX 3 obs files of a
master and a rover, ``nav.rnx`` and ``config.toml``, in ``--workdir``/<hours>h), and each receiver's RINEX
file is converted into ``<name>.ubx``: one RXM-RAWX frame (class 0x02, id 0x15) per epoch, GPS L1 C/A
(gnssId 0, sigId 0): prMes and cpMes the RINEX C1C and L1C, doMes 0, cno 45, prStdev 5, cpStdev 2,
doStdev 3, trkStat 0b0111 (pr, cp and half cycle valid; a blank value clears its bit), locktime the ms
since the satellite's lock started (its first epoch, an epoch after a gap in its track, or a RINEX LLI
bit 0), capped at 64500; the header's leapS 18, recStat 1 (leap seconds valid), version 1: byte for byte
the frames of ``tests/io/test_ubx_signals.py::_rawx_log`` (tracks without gaps), built vectorised (numpy
structured arrays; Fletcher-8 checksums from wrapping uint8 cumulative sums) an hour of epochs at a time (the
RINEX read hour by hour, :mod:`cdgps_cli.io.rinex_hours`): a day at 10 Hz (864,000 epochs per receiver) in
bounded memory.  ``--nmea`` puts a GPGGA sentence after the first frame of each GPS second, as u-blox logs do.

Beside the logs, ``ubx.toml`` is the pair's ``config.toml`` with each antenna's ``rinex = …`` replaced
by ``ubx = …`` and its position (the RINEX header's, which the UBX log does not carry) written out as
``position_ecef_m`` (nav: the simulated RINEX nav file).  ``--check`` compares the GPS L1 rows read back
(:func:`cdgps_cli.io.ubx.read_ubx_log` against :func:`cdgps_cli.io.rinex.read_rinex_obs`: time, sat,
phase, pseudorange); ``--measure`` runs ``cdgps ingest --config`` on the UBX and RINEX configs, each under
``/usr/bin/time -v`` with ``CDGPS_SERIAL=1`` (peak RSS, wall s), of this source tree or ``--tree``'s::

    python benchmarks/ubx_pair.py --hours 0.05 --check
    python benchmarks/ubx_pair.py --hours 1 3 --nmea --measure --workdir /tmp/ubxlong --json /tmp/ubxlong/ubx.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
import tomllib
from functools import reduce
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from long_records import simulated_pair  # noqa: E402  (benchmarks/long_records.py)

ROOT = HERE.parent
CDGPS = [sys.executable, "-c", "from cdgps_cli.cli.commands import main; main()"]
WEEK_S, LEAP_S, LOCK_CAP_MS = 604800.0, 18, 64500
# sync, class, id, length, then the 16-byte RXM-RAWX header <dHbBBB2x
HEAD = np.dtype([("sync", "u1", 2), ("cls", "u1"), ("id", "u1"), ("len", "<u2"), ("rcvTow", "<f8"), ("week", "<u2"),
                 ("leapS", "i1"), ("numMeas", "u1"), ("recStat", "u1"), ("version", "u1"), ("res", "u1", 2)])
MEAS = np.dtype([("prMes", "<f8"), ("cpMes", "<f8"), ("doMes", "<f4"), ("gnssId", "u1"), ("svId", "u1"),  # <ddfBBBBHBBBBBx
                 ("sigId", "u1"), ("freqId", "u1"), ("locktime", "<u2"), ("cno", "u1"), ("prStdev", "u1"),
                 ("cpStdev", "u1"), ("doStdev", "u1"), ("trkStat", "u1"), ("res", "u1")])
assert HEAD.itemsize == 22 and MEAS.itemsize == 32


def rawx_frames(t, sv, pr, cp, lock_ms) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The RXM-RAWX frames of rows sorted by time then satellite, one frame per time: (the frames' bytes
    (uint8), each frame's end offset, each frame's time)."""
    first = np.flatnonzero(np.r_[True, t[1:] != t[:-1]])
    num = np.diff(np.r_[first, len(t)])
    if num.max(initial=0) > 255:
        raise ValueError("more than 255 measurements in an epoch")
    te, flen = t[first], 8 + 16 + 32 * num
    start = np.r_[0, np.cumsum(flen)[:-1]]
    out = np.zeros(int(flen.sum()), np.uint8)
    h = np.zeros(len(te), HEAD)
    week = np.floor(te / WEEK_S)
    h["sync"], h["cls"], h["id"], h["len"] = (0xB5, 0x62), 0x02, 0x15, 16 + 32 * num
    h["rcvTow"], h["week"], h["leapS"], h["numMeas"], h["recStat"], h["version"] = te - week * WEEK_S, week, LEAP_S, num, 1, 1
    hb = h.view(np.uint8).reshape(-1, HEAD.itemsize)
    for j in range(HEAD.itemsize):
        out[start + j] = hb[:, j]
    m = np.zeros(len(t), MEAS)
    m["prMes"], m["cpMes"], m["svId"], m["locktime"] = np.nan_to_num(pr), np.nan_to_num(cp), sv, lock_ms
    m["cno"], m["prStdev"], m["cpStdev"], m["doStdev"] = 45, 5, 2, 3
    m["trkStat"] = np.isfinite(pr) * 1 + np.isfinite(cp) * 6                    # pr valid; cp and half cycle valid
    pos = np.repeat(start + HEAD.itemsize, num) + 32 * (np.arange(len(t)) - np.repeat(first, num))
    mb = m.view(np.uint8).reshape(-1, MEAS.itemsize)
    for j in range(MEAS.itemsize):
        out[pos + j] = mb[:, j]
    # Fletcher-8 over class..payload, bytes lo+1 .. hi: a = Σx, b = Σ(running a), all mod 256 (uint8 wraps)
    s1 = np.cumsum(out, dtype=np.uint8)
    s2 = np.cumsum(s1, dtype=np.uint8)
    lo, hi = start + 1, start + flen - 3
    out[hi + 1] = s1[hi] - s1[lo]
    out[hi + 2] = s2[hi] - s2[lo] - (hi - lo).astype(np.uint8) * s1[lo]
    return out, start + flen, te


class LockTimes:
    """RXM-RAWX lock times carried across chunks: per svId the lock's start time and the last epoch seen."""

    def __init__(self):
        self.start = np.full(256, np.nan)
        self.last = np.full(256, -2, np.int64)
        self.epochs = 0                                      # epochs before the chunk

    def __call__(self, t, sv, lli) -> np.ndarray:
        first = np.r_[True, t[1:] != t[:-1]]
        ep = self.epochs + np.cumsum(first) - 1              # global epoch number of each row
        self.epochs += int(first.sum())
        o = np.lexsort((ep, sv))                             # by satellite, then epoch
        s, e, to = sv[o], ep[o], t[o]
        head = np.r_[True, s[1:] != s[:-1]]
        prev = np.where(head, self.last[s], np.r_[-2, e[:-1]])
        restart = (prev != e - 1) | ((lli[o] & 1) != 0)
        st = np.where(restart, to, np.where(head, self.start[s], np.nan))
        fill = np.maximum.accumulate(np.where(np.isnan(st), 0, np.arange(len(st))))
        st = st[fill]                                        # each track's start, carried forward
        tail = np.r_[s[1:] != s[:-1], True]
        self.start[s[tail]], self.last[s[tail]] = st[tail], e[tail]
        lock = np.empty(len(t), np.int64)
        lock[o] = np.minimum(LOCK_CAP_MS, np.rint((to - st) * 1000.0)).astype(np.int64)
        return lock


def gga(t_gps: float, lat_deg: float, lon_deg: float, h_m: float, n_sat: int) -> bytes:
    """An NMEA GPGGA sentence (fix quality 1) at GPS time ``t_gps`` (UTC = GPS − 18 s)."""
    cs = int(((t_gps - LEAP_S) % 86400.0) * 100)
    hms = f"{cs // 360000:02d}{cs // 6000 % 60:02d}{cs % 6000 // 100:02d}.{cs % 100:02d}"
    la, lo = abs(lat_deg), abs(lon_deg)
    body = (f"GPGGA,{hms},{int(la):02d}{la % 1 * 60:08.5f},{'NS'[lat_deg < 0]},{int(lo):03d}{lo % 1 * 60:08.5f},"
            f"{'EW'[lon_deg < 0]},1,{min(n_sat, 99):02d},0.8,{h_m:.3f},M,0.000,M,,")
    return f"${body}*{reduce(lambda a, c: a ^ ord(c), body, 0):02X}\r\n".encode()


def rinex_hour_tables(path: Path):
    """(header, obs) of each hour of a RINEX obs file (the whole file when it cannot be cut)."""
    from cdgps_cli.io.rinex import read_rinex_obs
    from cdgps_cli.io.rinex_hours import rinex_hours
    hours = rinex_hours(path, 3600.0)
    if hours is None:
        yield read_rinex_obs(path)
        return
    for j in range(len(hours.blocks)):
        yield read_rinex_obs(path, read=hours.block_bytes(j))


def write_ubx(rinex: Path, out: Path, position_m, nmea: bool) -> dict:
    """``rinex`` (obs) → ``out`` (UBX RXM-RAWX, GGA at 1 Hz with ``nmea``), hour by hour; a summary."""
    from cdgps_cli.model.gps.orbits import ecef_to_geodetic
    lat, lon, h = (float(np.squeeze(v)) for v in ecef_to_geodetic(np.asarray(position_m, float)))
    lat, lon = float(np.degrees(lat)), float(np.degrees(lon))
    locks, n_ep, n_rows, last_sec = LockTimes(), 0, 0, None
    with open(out, "wb") as fh:
        for _, obs in rinex_hour_tables(rinex):
            t = obs["time_gps_s"].to_numpy(np.float64)
            codes, sats = pd.factorize(obs["sat"])
            sv = np.array([int(s[1:]) for s in sats], np.uint8)[codes]
            lock = locks(t, sv, obs["lli_l1"].to_numpy(np.int64))
            buf, ends, te = rawx_frames(t, sv, obs["pseudorange_l1_m"].to_numpy(np.float64),
                                        obs["phase_l1_cycles"].to_numpy(np.float64), lock)
            n_ep, n_rows = n_ep + len(te), n_rows + len(t)
            if not nmea:
                fh.write(buf)
                continue
            sec = np.floor(te)
            new = np.flatnonzero(sec != np.r_[np.nan if last_sec is None else last_sec, sec[:-1]])
            last_sec, prev, num = sec[-1], 0, np.diff(np.r_[0, ends]) // 32
            for k in new.tolist():
                fh.write(buf[prev:ends[k]])
                fh.write(gga(float(te[k]), lat, lon, h, int(num[k])))
                prev = int(ends[k])
            fh.write(buf[prev:])
    return {"epochs": n_ep, "measurements": n_rows, "mb": round(out.stat().st_size / 1e6, 2)}


def make_ubx_pair(d: Path, nmea: bool) -> dict:
    """``<antenna>.ubx`` for each antenna of ``d/config.toml`` and ``d/ubx.toml``; a summary per antenna."""
    from cdgps_cli.model.gps.positioning import antenna_reference_point_m
    text = (d / "config.toml").read_text()
    cfg = tomllib.loads(text)["gnss"]
    summary = {}
    for name, ant in cfg["antennas"].items():
        rinex = d / ant["rinex"]
        hdr = next(rinex_hour_tables(rinex))[0]        # (the first hour's header: the file's)
        pos = antenna_reference_point_m(hdr, rinex.name) if name == cfg["master"] else hdr["approx_position_xyz_m"]
        pos = [float(v) for v in pos]
        t0 = time.perf_counter()
        summary[name] = write_ubx(rinex, d / f"{name}.ubx", pos, nmea)
        summary[name]["write_s"] = round(time.perf_counter() - t0, 1)
        text = re.sub(rf'^rinex = "{re.escape(ant["rinex"])}"$',
                      f'ubx = "{name}.ubx"\nposition_ecef_m = [{", ".join(map(repr, pos))}]', text, count=1, flags=re.M)
    (d / "ubx.toml").write_text(text.replace("# GNSS run config written by", "# UBX logs by benchmarks/ubx_pair.py; "
                                             "from the GNSS run config written by", 1))
    return summary


def check(d: Path) -> dict:
    """Each antenna's GPS L1 rows of its UBX log against its RINEX file's: time, sat, phase, pseudorange."""
    from cdgps_cli.io.rinex import read_rinex_obs
    from cdgps_cli.io.ubx import read_ubx_log
    res = {}
    for name, ant in tomllib.loads((d / "config.toml").read_text())["gnss"]["antennas"].items():
        info, u, _ = read_ubx_log(d / f"{name}.ubx", strict=True)
        _, r = read_rinex_obs(d / ant["rinex"])
        same = len(u) == len(r) and (u["sat"].to_numpy() == r["sat"].to_numpy()).all()
        res[name] = {"rows": len(u), "same_rows": bool(same), "max_dt_s": float(np.abs(u["time_gps_s"] - r["time_gps_s"]).max()),
                     "phase_equal": bool(np.array_equal(u["phase_l1_cycles"], r["phase_l1_cycles"], equal_nan=True)),
                     "pr_equal": bool(np.array_equal(u["pseudorange_l1_m"], r["pseudorange_l1_m"], equal_nan=True)),
                     "lock_restarts": int((u.groupby("sat")["lock_time_ms"].diff() < 0).sum()),
                     "rinex_lli_slips": int(((r["lli_l1"] & 1) != 0).sum()),
                     "nmea_bytes": info.get("nmea_bytes"), "skipped_bytes": info.get("skipped_bytes")}
    return res


def hourly_files(d: Path) -> str:
    """The pair's UBX logs cut at each hour's first RXM-RAWX frame (:func:`cdgps_cli.io.ubx_hours.ubx_hours`) into
    ``hours/<name>_<HH>.ubx``, as a logger rotating hourly writes them, with ``hours/ubx.toml`` naming them by a
    glob; returns that config's path relative to ``d``."""
    from cdgps_cli.io.ubx_hours import ubx_hours  # noqa: PLC0415

    out = d / "hours"
    out.mkdir(exist_ok=True)
    for name in ("base", "rover"):
        h = ubx_hours(d / f"{name}.ubx", 3600.0)
        with open(d / f"{name}.ubx", "rb") as fh:
            for j, (_, a, b, _) in enumerate(h.blocks):
                fh.seek(a)
                (out / f"{name}_{j:02d}.ubx").write_bytes(fh.read(b - a))
    text = (d / "ubx.toml").read_text().replace('nav = ["nav.rnx"]', 'nav = ["../nav.rnx"]')
    for name in ("base", "rover"):
        text = text.replace(f'ubx = "{name}.ubx"', f'ubx = "{name}_*.ubx"')
    (out / "ubx.toml").write_text(text)
    return "hours/ubx.toml"


def measure(d: Path, config: str, tree: Path = ROOT) -> dict:
    """``cdgps ingest --config d/config -o d/run-<config>.mcap`` (the package of source tree ``tree``) under
    /usr/bin/time -v, CDGPS_SERIAL=1."""
    out = d / f"run-{config.replace('/', '-').removesuffix('.toml')}.mcap"
    env = dict(os.environ, CDGPS_SERIAL="1", PYTHONPATH=str(tree))
    t0 = time.perf_counter()
    p = subprocess.run(["/usr/bin/time", "-v", *CDGPS, "-q", "ingest", "--config", str(d / config), "-o", str(out),
                        "--json"], capture_output=True, text=True, env=env, cwd=(d / config).parent)
    wall = time.perf_counter() - t0
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    r = {"exit": p.returncode, "wall_s": round(wall, 1), "peak_rss_mib": round(int(rss[1]) / 1024, 1) if rss else None,
         "load_1min": round(os.getloadavg()[0], 2)}
    if p.returncode:
        r["stderr"] = p.stderr[-800:]
    else:
        r["reading"] = json.loads(p.stdout).get("reading")       # hour by hour, or whole and why
    return r


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hours", type=float, nargs="+", required=True)
    ap.add_argument("--rate-hz", type=float, default=10.0)
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/ubxlong"))
    ap.add_argument("--nmea", action="store_true", help="a GPGGA sentence once a second between the frames")
    ap.add_argument("--force", action="store_true", help="rewrite the UBX logs even if ubx.toml exists")
    ap.add_argument("--check", action="store_true", help="compare the UBX logs read back with the RINEX files")
    ap.add_argument("--measure", action="store_true", help="time 'cdgps ingest' of the UBX and the RINEX configs")
    ap.add_argument("--tree", type=Path, default=ROOT, help="--measure the cdgps of this source tree [this one]")
    ap.add_argument("--json", type=Path, help="write the results here")
    ap.add_argument("--hourly-files", action="store_true",
                    help="with --measure, also the UBX logs cut into one file per hour (hours/ubx.toml)")
    a = ap.parse_args()
    results = []
    for hours in a.hours:
        d = simulated_pair(a.workdir / f"{hours:g}h", hours, a.rate_hz)
        rec = {"hours": hours, "rate_hz": a.rate_hz, "dir": str(d)}
        if a.force or not (d / "ubx.toml").exists():
            rec["ubx"] = make_ubx_pair(d, a.nmea)            # (--nmea only when the logs are written)
        rec["file_mb"] = {p.name: round(p.stat().st_size / 1e6, 1) for p in sorted(d.glob("*.ubx")) + sorted(d.glob("*.rnx"))}
        if a.check:
            rec["check"] = check(d)
        if a.measure:
            configs = ["ubx.toml", "config.toml"] + ([hourly_files(d)] if a.hourly_files else [])
            rec["ingest"] = {cfg: measure(d, cfg, a.tree.resolve()) for cfg in configs}
        print(json.dumps(rec), flush=True)
        results.append(rec)
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"machine": f"{os.cpu_count()} cores, {platform.processor() or platform.machine()}",
                                      "date": time.strftime("%Y-%m-%d"), "records": results}, indent=1) + "\n")
    for rec in results:
        for cfg, r in (rec.get("ingest") or {}).items():
            print(f"| {rec['hours']:g} h | {cfg} | {r.get('peak_rss_mib')} MiB | {r.get('wall_s')} s | "
                  f"{(r.get('reading') or {}).get('hour_by_hour')} | load {r.get('load_1min')} |")


if __name__ == "__main__":
    main()
