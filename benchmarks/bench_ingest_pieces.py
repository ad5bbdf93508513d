#!/usr/bin/env python3
"""``cdgps ingest`` of one file against the same record cut into N consecutive files (issue 29 item 2).

Simulates (cached in ``--workdir``) a GNSS base + rover pair (RINEX 3, 1 Hz) and a testbed
receiver CSV (10 Hz), cuts each into ``--pieces`` files of equal span, and runs ``cdgps ingest``
on the whole files and on the pieces (given as a quoted glob), each in a fresh process: the fastest of
``--repeat`` alternating runs: wall time and peak RSS (VmHWM).  Checks that both RUNs carry identical messages (the data are the same;
only the provenance records differ, docs/gnss-pipeline.md) and writes the table as JSON::

    python benchmarks/bench_ingest_pieces.py --json docs/benchmarks/ingest_pieces.json
    python benchmarks/bench_ingest_pieces.py --gnss-s 600 --csv-s 120 --pieces 4     # quick
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"

CLI = """
import sys, time
t = time.perf_counter()
from cdgps_cli.cli.commands import main
main({args!r}, standalone_mode=False)
with open('/proc/self/status') as fh:
    hwm = [int(x.split()[1]) / 1024.0 for x in fh if x.startswith('VmHWM:')][0]
print('__BENCH__', time.perf_counter() - t, hwm, file=sys.stderr)
"""

_MAIN = "import sys; from cdgps_cli.cli.commands import main; main(sys.argv[1:])"


def _run(args) -> dict:
    p = subprocess.run([sys.executable, "-c", CLI.format(args=[str(a) for a in args])], capture_output=True, text=True,
                       env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    if p.returncode:
        raise SystemExit(f"cdgps {' '.join(map(str, args))} failed:\n{p.stderr}")
    line = [x for x in p.stderr.splitlines() if x.startswith("__BENCH__")][-1].split()
    return {"wall_s": round(float(line[1]), 3), "peak_rss_mb": round(float(line[2]), 1)}


def _messages(path: Path) -> list:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        return [(ch.topic, m.log_time, m.data) for _, ch, m in make_reader(fh).iter_messages(log_time_order=False)]


def _setup(work: Path, gnss_s: float, csv_s: float, n: int) -> None:
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs
    from cdgps_cli.core.gps_time import gps_seconds

    g = work / "gnss"
    if not (g / "config.toml").exists():
        subprocess.run([sys.executable, "-c", _MAIN, "-q", "simulate-gnss", "--duration", str(gnss_s), "--start",
                        "2024-01-06T23:30:00", "-o", str(g)], check=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    t0 = gps_seconds(2024, 1, 6, 23, 30)
    for name in ("base", "rover"):
        text = (g / f"{name}.rnx").read_text()
        for i in range(n):
            a, b = t0 + i * gnss_s / n, t0 + (i + 1) * gnss_s / n
            (g / f"{name}_{i:02d}.rnx").write_text(edit_rinex3_obs(text, keep=lambda t, a=a, b=b: a <= t < b))
    c = work / "csv"
    if not (c / "receiver.csv").exists():
        subprocess.run([sys.executable, "-c", _MAIN, "-q", "simulate", str(TESTBED), "--duration", str(csv_s),
                        "-o", str(c)], check=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    lines = (c / "receiver.csv").read_text().splitlines(keepends=True)
    t = [float(x.split(",", 1)[0]) for x in lines[1:]]
    for i in range(n):
        a, b = i * csv_s / n, (i + 1) * csv_s / n if i < n - 1 else float("inf")
        (c / f"receiver_{i:02d}.csv").write_text(lines[0] + "".join(x for x, ti in zip(lines[1:], t) if a <= ti < b))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gnss-s", type=float, default=3600.0, help="GNSS pair span, s (1 Hz)")
    ap.add_argument("--csv-s", type=float, default=600.0, help="testbed CSV span, s (10 Hz)")
    ap.add_argument("--pieces", type=int, default=6)
    ap.add_argument("--repeat", type=int, default=3, help="runs of each command, alternating (the fastest is kept)")
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    a = ap.parse_args(argv)
    work = a.workdir or Path(tempfile.mkdtemp(prefix="cdgps-pieces-"))
    work.mkdir(parents=True, exist_ok=True)
    _setup(work, a.gnss_s, a.csv_s, a.pieces)
    g, c = work / "gnss", work / "csv"
    cases = {
        "gnss_rinex_pair": (["ingest", "--config", g / "config.toml", "-o", g / "whole.mcap"],
                            ["ingest", "--rinex", f"base={g}/base_*.rnx", "--rinex", f"rover={g}/rover_*.rnx",
                             "--nav", g / "nav.rnx", "--master", "base", "-o", g / "pieces.mcap"],
                            g / "whole.mcap", g / "pieces.mcap"),
        "testbed_receiver_csv": (["ingest", c / "receiver.csv", "--config", TESTBED, "-o", c / "whole.mcap"],
                                 ["ingest", f"{c}/receiver_*.csv", "--config", TESTBED, "-o", c / "pieces.mcap"],
                                 c / "whole.mcap", c / "pieces.mcap"),
    }
    out = {"command": "python benchmarks/bench_ingest_pieces.py " + " ".join(argv or sys.argv[1:]),
           "machine": platform.platform(), "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
           "gnss_s": a.gnss_s, "csv_s": a.csv_s, "pieces": a.pieces, "cases": {}}
    for name, (whole, pieces, pw, pp) in cases.items():
        runs_w, runs_p = [], []
        for _ in range(a.repeat):          # alternating, so that a busy spell hits both alike
            runs_w.append(_run(["-q", *whole]))
            runs_p.append(_run(["-q", *pieces]))
        w, p = (min(r, key=lambda x: x["wall_s"]) for r in (runs_w, runs_p))
        w["all_wall_s"], p["all_wall_s"] = [x["wall_s"] for x in runs_w], [x["wall_s"] for x in runs_p]
        same = _messages(pw) == _messages(pp)
        out["cases"][name] = {"whole": w, "pieces": p, "messages_identical": same}
        print(f"{name:<22} whole {w['wall_s']:7.2f} s {w['peak_rss_mb']:7.1f} MB   {a.pieces} pieces {p['wall_s']:7.2f} s "
              f"{p['peak_rss_mb']:7.1f} MB   messages identical: {same}")
        if not same:
            raise SystemExit(f"{name}: the pieces' RUN differs from the whole file's")
    if a.json:
        a.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
