#!/usr/bin/env python3
"""RINEX and UBX reading against ``pandas.read_csv`` of the same bytes (issue 29 item 4).

For every RINEX observation file of the shared data: :func:`cdgps_cli.io.rinex_signals.read_rinex_signals`
(every signal the file's header lists; the vectorised reader, and the line-by-line one it replaced,
``FAST_PARSE = False``) and :func:`cdgps_cli.io.rinex.read_rinex_obs` (the GPS L1 table of
``init``/``ingest``) against ``pandas.read_csv`` of the same file after its header
(whitespace-separated, every token typed: the C tokenizer over the same bytes).  For every u-blox
log: :func:`cdgps_cli.io.ubx.read_ubx_log` (framing, checksums, RXM-RAWX decode, SFRBX ephemerides)
against ``pandas.read_csv`` of a CSV of the same number of bytes (the decoded observation table,
repeated); a binary log holds ~4× the observations of a CSV of its size, so this peer is generous.
The UBX reader is timed with the compiled framing walk (``cdgps_cli.io._ubxcore``, when built) and
with the numpy framer it falls back to.

Rounds are interleaved (ours, peer, ours, ...); each call's wall and thread-CPU time are taken, and
each figure is the median (and, ``*_min_s``, the least) of at least ``--repeat`` rounds, more for calls
of milliseconds (0.5 s of the quickest call, at most 400); the ratios are ours / read_csv (< 1: faster):
``ratio_to_read_csv`` of the median wall times, ``cpu_ratio_to_read_csv`` of the median thread CPU,
``min_ratio_to_read_csv`` / ``cpu_min_ratio_to_read_csv`` of the least ones.  ``read_rinex_obs`` is timed on its byte-level block-wise
reader and on the line-by-line one (``rinex.FAST_PARSE = False``) it replaced.  ``--day`` also
simulates a 24 h 1 Hz RINEX 3 file (``cdgps simulate-gnss``, not timed) and measures the peak RSS
(``resource``, one child process per reader) and time of ``read_rinex_obs`` on it, both readers, and
of ``pandas.read_csv``.  Writes ``docs/benchmarks/parse.json``::

    PYTHONPATH=. python benchmarks/bench_parse.py --repeat 7 [--day]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io import rinex, rinex_signals, ubx, ubx_frames

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
OUT = ROOT / "docs" / "benchmarks" / "parse.json"
GLO_K = {f"R{i:02d}": 0 for i in range(1, 33)}


def _time(fn) -> tuple[float, float]:
    """(wall s, thread CPU s) of one call."""
    t, c = time.perf_counter(), time.thread_time()
    fn()
    return time.perf_counter() - t, time.thread_time() - c


def interleaved(fns: dict, repeat: int, min_total_s: float = 0.0) -> dict:
    """Wall and thread-CPU time (s) of each callable, the callables taking turns ``repeat`` times, or more
    (up to 400) so that each round of the quickest one adds to ``min_total_s``: a millisecond call's
    median needs many rounds on a loaded machine.  {name: median wall, name_cpu: median thread CPU,
    name_min / name_cpu_min: the least of each} (thread CPU: what other processes' load inflates
    least; the minimum: what they inflate least of all)."""
    warm = {k: _time(fn)[0] for k, fn in fns.items()}     # warm-up: imports, caches
    rounds = min(400, max(repeat, int(min_total_s / max(min(warm.values()), 1e-4))))
    times = {k: [] for k in fns}
    for _ in range(rounds):
        for k, fn in fns.items():
            times[k].append(_time(fn))
    out = {}
    for k, v in times.items():
        wall, cpu = [w for w, _ in v], [c for _, c in v]
        out[k] = statistics.median(wall)
        out[k.removesuffix("_s") + "_cpu_s"] = statistics.median(cpu)
        out[k.removesuffix("_s") + "_min_s"] = min(wall)
        out[k.removesuffix("_s") + "_cpu_min_s"] = min(cpu)
    out["rounds"] = rounds
    return out


def _ratios(t: dict, ours: str, peer: str, prefix: str = "") -> dict:
    """ours / peer of the median wall, median CPU, least wall and least CPU times of :func:`interleaved`."""
    o, p = ours.removesuffix("_s"), peer.removesuffix("_s")
    return {f"{prefix}ratio_to_read_csv": round(t[ours] / t[peer], 3),
            f"{prefix}cpu_ratio_to_read_csv": round(t[o + "_cpu_s"] / t[p + "_cpu_s"], 3),
            f"{prefix}min_ratio_to_read_csv": round(t[o + "_min_s"] / t[p + "_min_s"], 3),
            f"{prefix}cpu_min_ratio_to_read_csv": round(t[o + "_cpu_min_s"] / t[p + "_cpu_min_s"], 3)}


def _obs_line_by_line(path):
    rinex.FAST_PARSE = False
    try:
        return rinex.read_rinex_obs(path, gps_l1_optional=True)
    finally:
        rinex.FAST_PARSE = True


_CHILD = """
import resource, sys, time
import pandas as pd
from cdgps_cli.io import rinex
what, path = sys.argv[1], sys.argv[2]
t = time.perf_counter()
if what == "read_csv":
    pd.read_csv(path, sep=r"\\s+", header=None, skiprows=int(sys.argv[3]), names=range(12), engine="c")
else:
    rinex.FAST_PARSE = what == "read_rinex_obs"
    rinex.read_rinex_obs(path)
print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""


def day_case(work: Path) -> dict:
    """Peak RSS (MiB) and time (s) of reading a simulated 24 h 1 Hz RINEX 3 file, one child each."""
    subprocess.run([sys.executable, "-m", "cdgps_cli.cli.commands", "-q", "simulate-gnss", "--duration", "86400",
                    "-o", str(work)], check=True, capture_output=True)
    path = work / "base.rnx"
    skip = next(i for i, ln in enumerate(path.open(encoding="latin-1")) if "END OF HEADER" in ln) + 1
    row = {"file": "simulate-gnss --duration 86400 (base.rnx)", "bytes": path.stat().st_size,
           "load_average_1min": round(os.getloadavg()[0], 2)}
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for what in ("read_rinex_obs", "line_by_line", "read_csv", "read_rinex_obs", "line_by_line", "read_csv"):
        out = subprocess.run([sys.executable, "-c", _CHILD, what, str(path), str(skip)], check=True,
                             capture_output=True, text=True, env=env).stdout.split()
        row.setdefault(what, []).append({"s": round(float(out[0]), 3), "peak_rss_mib": round(float(out[1]), 1)})
    return row


def _slow(path, names):
    rinex_signals.FAST_PARSE = False
    try:
        return rinex_signals.read_rinex_signals(path, names, glonass_k=GLO_K)
    finally:
        rinex_signals.FAST_PARSE = True


def rinex_case(path: Path, repeat: int) -> dict:
    names = rinex_signals.signals_in_file(path)
    text = path.read_text(encoding="latin-1").split("\n")
    skip = next(i for i, ln in enumerate(text) if ln[60:].strip() == "END OF HEADER") + 1
    width = max(len(ln.split()) for ln in text[skip:]) + 1
    fns = {"read_rinex_signals_s": lambda: rinex_signals.read_rinex_signals(path, names, glonass_k=GLO_K),
           "read_csv_s": lambda: pd.read_csv(path, sep=r"\s+", header=None, skiprows=skip, names=range(width),
                                             encoding="latin-1", engine="c"),
           "line_by_line_s": lambda: _slow(path, names)}
    try:
        rinex.read_rinex_obs(path, gps_l1_optional=True)
        fns["read_rinex_obs_s"] = lambda: rinex.read_rinex_obs(path, gps_l1_optional=True)
        fns["read_rinex_obs_line_by_line_s"] = lambda: _obs_line_by_line(path)
    except Exception:                                   # noqa: BLE001 (a file that reader refuses: not timed)
        pass
    t = interleaved(fns, repeat, min_total_s=0.5)
    row = {"bytes": path.stat().st_size, "signals": names, **{k: round(v, 5) for k, v in t.items()},
           **_ratios(t, "read_rinex_signals_s", "read_csv_s"),
           "line_by_line_ratio_to_read_csv": round(t["line_by_line_s"] / t["read_csv_s"], 3)}
    if "read_rinex_obs_s" in t:
        row.update(_ratios(t, "read_rinex_obs_s", "read_csv_s", "read_rinex_obs_"))
        row["read_rinex_obs_line_by_line_ratio_to_read_csv"] = round(t["read_rinex_obs_line_by_line_s"] / t["read_csv_s"], 3)
    return row


def ubx_case(path: Path, tmp: Path, repeat: int) -> dict:
    _, obs, _ = ubx.read_ubx_log(path)
    size = path.stat().st_size
    one = obs.to_csv(index=False)
    head, body = one.split("\n", 1)
    csv = tmp / (path.name + ".csv")
    reps = max(1, -(-size // max(len(body), 1)))
    data = (head + "\n" + body * reps).encode()
    data = data[:data.rfind(b"\n", 0, max(size, len(head) + 2)) + 1]
    csv.write_bytes(data)
    def read(compiled=True):
        ubx._LAST_DECODED.clear()                          # no memory of the previous round's decode
        ubx_frames.USE_COMPILED = compiled                 # False: the numpy framer (no _ubxcore built)
        try:
            return ubx.read_ubx_log(path)
        finally:
            ubx_frames.USE_COMPILED = True

    t = interleaved({"read_ubx_log_s": read, "read_csv_s": lambda: pd.read_csv(csv),
                     "read_ubx_log_numpy_framer_s": lambda: read(False)}, repeat, min_total_s=0.5)
    return {"bytes": size, "csv_bytes": len(data), "rawx_rows": len(obs), "csv_rows": data.count(b"\n") - 1,
            "compiled_walk": getattr(ubx_frames, "_ubxcore", None) is not None, **{k: round(v, 5) for k, v in t.items()},
            **_ratios(t, "read_ubx_log_s", "read_csv_s"),
            "numpy_framer_ratio_to_read_csv": round(t["read_ubx_log_numpy_framer_s"] / t["read_csv_s"], 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--only", choices=("rinex", "ubx"), help="measure one part; the other is kept from --out")
    ap.add_argument("--day", action="store_true", help="also the 24 h RINEX file's peak RSS (simulated, ~1 min)")
    a = ap.parse_args()
    res = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "pandas": pd.__version__,
                       "load_average_1min_at_start": round(os.getloadavg()[0], 2)},
           "repeat": a.repeat, "timing": "median (and *_min_s: least) wall and thread-CPU time of interleaved rounds after one "
                                         "warm-up: at least --repeat rounds, more for files read in milliseconds (0.5 s of the "
                                         "quickest call, <= 400)", "rinex": {}, "ubx": {}}
    if a.only and a.out.exists():
        kept = json.loads(a.out.read_text())
        res[{"ubx": "rinex", "rinex": "ubx"}[a.only]] = kept.get({"ubx": "rinex", "rinex": "ubx"}[a.only], {})
    obs = sorted(p for p in SHARED.rglob("*") if p.is_file() and p.name.lower().endswith(("o", ".obs")))
    for p in obs if a.only != "ubx" else ():
        res["rinex"][str(p.relative_to(SHARED))] = row = rinex_case(p, a.repeat)
        print(p.name, json.dumps({k: v for k, v in row.items() if k != "signals"}), flush=True)
    logs = sorted([*(SHARED / "real-pairs" / "ublox-walk").glob("*.ubx"), *(SHARED / "ubx").glob("*")])
    with tempfile.TemporaryDirectory() as d:
        for p in logs if a.only != "rinex" else ():
            try:
                row = ubx_case(p, Path(d), a.repeat)
            except CdgpsError as exc:                      # no RXM-RAWX (legacy RXM-RAW, ESF only): refused
                row = {"bytes": p.stat().st_size, "refused": str(exc).split(": ", 1)[1][:120]}
            res["ubx"][str(p.relative_to(SHARED))] = row
            print(p.name, json.dumps(row), flush=True)
    if a.day:
        with tempfile.TemporaryDirectory() as d:
            res["rinex_24h_memory"] = day_case(Path(d))
        print(json.dumps(res["rinex_24h_memory"]), flush=True)
    elif a.out.exists():
        res["rinex_24h_memory"] = json.loads(a.out.read_text()).get("rinex_24h_memory", {})
    res["worst_rinex_obs_ratio_to_read_csv"] = max(
        (r["read_rinex_obs_ratio_to_read_csv"] for r in res["rinex"].values() if "read_rinex_obs_ratio_to_read_csv" in r), default=None)
    res["worst_rinex_signals_ratio_to_read_csv"] = max(
        (r["ratio_to_read_csv"] for r in res["rinex"].values()), default=None)
    ratios = [r["ratio_to_read_csv"] for part in ("rinex", "ubx") for r in res[part].values() if "ratio_to_read_csv" in r]
    res["worst_ratio_to_read_csv"] = max(ratios)
    for kind in ("cpu_", "min_", "cpu_min_"):                # the same, of thread CPU and of the least times
        res[f"worst_{kind}ratio_to_read_csv"] = max(
            (r[f"{pre}{kind}ratio_to_read_csv"] for part in ("rinex", "ubx") for r in res[part].values()
             for pre in ("", "read_rinex_obs_") if f"{pre}{kind}ratio_to_read_csv" in r), default=None)
    res["machine"]["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print("worst ratio (median wall, median CPU, least wall, least CPU)", res["worst_ratio_to_read_csv"],
          res["worst_cpu_ratio_to_read_csv"], res["worst_min_ratio_to_read_csv"], res["worst_cpu_min_ratio_to_read_csv"],
          "wrote", a.out)


if __name__ == "__main__":
    main()
