#!/usr/bin/env python3
"""Foundation benchmark: one hour of the testbed at 10 Hz (36 channels, ~1.3 M phase rows).

Measures wall time and peak resident memory of ``cdgps simulate`` and ``cdgps ingest``, each in its
own process (so peak memory is that command's), and of reading the RUN.mcap back.  Targets (issue 2):
each under 10 s and under 1 GB.  Writes docs/benchmarks/foundation.json and prints a table.
"""

from __future__ import annotations

import json
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"


def run_measured(args: list[str]) -> tuple[float, float]:
    """Run a Python snippet-in-subprocess; return (seconds, peak RSS MiB) of that child."""
    code = (
        "import resource, sys, time, runpy\n"
        "t = time.perf_counter()\n"
        "from cdgps_cli.cli.commands import main\n"
        "try:\n"
        f"    main({args!r}, standalone_mode=False)\n"
        "finally:\n"
        "    dt = time.perf_counter() - t\n"
        "    print('__BENCH__', dt, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, file=sys.stderr)\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    if p.returncode != 0:
        raise SystemExit(p.stderr)
    line = [ln for ln in p.stderr.splitlines() if ln.startswith("__BENCH__")][-1]
    _, dt, rss = line.split()
    return float(dt), float(rss)


def main() -> None:
    hours = float(sys.argv[1]) if len(sys.argv) > 1 else 1.0
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        sim_s, sim_mb = run_measured(["--quiet", "simulate", str(CONFIG), "--duration", str(3600 * hours),
                                      "--seed", "1", "-o", str(d / "sim")])
        rows = sum(1 for _ in open(d / "sim" / "receiver.csv")) - 1
        ing_s, ing_mb = run_measured(["--quiet", "ingest", str(d / "sim" / "receiver.csv"), str(d / "sim" / "gyro.csv"),
                                      "--config", str(CONFIG), "-o", str(d / "run.mcap")])
        rd_s, rd_mb = run_measured(["--quiet", "info", str(d / "run.mcap"), "--json"])
        mcap_mb = (d / "run.mcap").stat().st_size / 2**20
        csv_mb = (d / "sim" / "receiver.csv").stat().st_size / 2**20
    res = {
        "hours": hours, "phase_rows": rows, "receiver_csv_mib": round(csv_mb, 1), "run_mcap_mib": round(mcap_mb, 1),
        "simulate_s": round(sim_s, 2), "simulate_peak_mib": round(sim_mb), "ingest_s": round(ing_s, 2),
        "ingest_peak_mib": round(ing_mb), "info_s": round(rd_s, 2), "info_peak_mib": round(rd_mb),
        "targets": {"simulate_s": 10, "ingest_s": 10, "peak_mib": 1024},
        "machine": {"python": platform.python_version(), "cpus": __import__("os").cpu_count(), "platform": platform.platform()},
    }
    out = ROOT / "docs" / "benchmarks"
    out.mkdir(parents=True, exist_ok=True)
    (out / "foundation.json").write_text(json.dumps(res, indent=2) + "\n")
    print(f"{rows} phase rows ({csv_mb:.0f} MiB CSV → {mcap_mb:.1f} MiB MCAP)")
    for k in ("simulate", "ingest", "info"):
        print(f"  {k:9s} {res[k + '_s']:6.2f} s   peak {res[k + '_peak_mib']:5d} MiB")
    ok = sim_s < 10 and ing_s < 10 and max(sim_mb, ing_mb) < 1024
    print("targets met" if ok else "TARGETS MISSED")


if __name__ == "__main__":
    main()
