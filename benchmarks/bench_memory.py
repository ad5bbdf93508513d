#!/usr/bin/env python3
"""Peak memory of ``cdgps estimate --smooth`` on hours of 10 Hz testbed data (issue 4: < 500 MB at 1 h;
issue 29: flat in the record length).

For each ``--hours`` value (several may be given) simulates (seed 1, 2 cm noise, disturbance scale 1),
ingests and initializes once (cached in ``--workdir``/<hours>h), then runs

1. ``cdgps estimate RUN.mcap --init INIT.json --smooth -o STATES.mcap`` in a fresh process: wall time
   and peak RSS (VmHWM of that process);
2. the same steps instrumented in a fresh process with exactly the CLI's options (read, filter +
   smooth, write): per stage the time, the current RSS at its end and the peak RSS so far.

Prints a table (``--json`` for a JSON object; ``--out FILE`` also writes it, with the per-hour
slope of the peak and of the time).  No other output is written outside ``--workdir``::

    python benchmarks/bench_memory.py                      # ≈ 1 min after the first setup
    python benchmarks/bench_memory.py --hours 1 3 6 --workdir /tmp/estmem --out docs/benchmarks/estimate_memory.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"

RSS = """
def _status(key):
    with open('/proc/self/status') as fh:
        for line in fh:
            if line.startswith(key + ':'):
                return int(line.split()[1]) / 1024.0
    return float('nan')
"""

CLI = RSS + """
import sys, time
t = time.perf_counter()
from cdgps_cli.cli.commands import main
main({args!r}, standalone_mode=False)
print('__BENCH__', time.perf_counter() - t, _status('VmHWM'), file=sys.stderr)
"""

STAGES = RSS + """
import json, sys, time
def mark(name, t0):
    print('__STAGE__', json.dumps([name, time.perf_counter() - t0, _status('VmRSS'), _status('VmHWM')]), file=sys.stderr)
    return time.perf_counter()
t = time.perf_counter()
from cdgps_cli.estimation.filter import EstimateOptions, estimate
from cdgps_cli.io.run import read_run
from cdgps_cli.io.scratch import DiskHistory
from cdgps_cli.pipeline.estimate_outputs import write_states
t = mark('import', t)
run = read_run({run!r})
t = mark('read RUN.mcap', t)
text = open({init!r}).read()
init = json.loads(text)
opt = EstimateOptions(smooth=True, keep_filtered_covariance='modal', keep_covariance='modal',
                      history=DiskHistory({workdir!r}))    # as the CLI (--covariance modal)
res = estimate(run, init, opt)
t = mark('filter + smooth', t)
write_states(res, {run!r}, init, text, {out!r}, opt.echo())
t = mark('write STATES.mcap', t)
"""


def _py(code: str) -> str:
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    if p.returncode != 0:
        raise SystemExit(p.stderr)
    return p.stderr


def _cli(args: list[str]) -> tuple[float, float]:
    err = _py(CLI.format(args=["--quiet", *args]))
    _, dt, rss = [ln for ln in err.splitlines() if ln.startswith("__BENCH__")][-1].split()
    return float(dt), float(rss)


def setup(d: Path, hours: float, seed: int) -> dict:
    d.mkdir(parents=True, exist_ok=True)
    tag = d / f"setup-{hours:g}h-seed{seed}.json"
    if tag.exists() and (d / "run.mcap").exists() and (d / "init.json").exists():
        return json.loads(tag.read_text())
    t0 = time.perf_counter()
    _cli(["simulate", str(CONFIG), "--duration", str(3600 * hours), "--seed", str(seed), "--noise-m", "0.02",
          "--disturbance-scale", "1", "-o", str(d / "sim")])
    _cli(["ingest", str(d / "sim" / "receiver.csv"), "--config", str(CONFIG), "-o", str(d / "run.mcap")])
    _cli(["init", str(d / "run.mcap"), "--start", "0", "--duration", "60", "-o", str(d / "init.json")])
    info = {"hours": hours, "seed": seed, "setup_s": time.perf_counter() - t0}
    tag.write_text(json.dumps(info))
    return info


def measure(d: Path) -> dict:
    run, init = d / "run.mcap", d / "init.json"
    wall, peak = _cli(["estimate", str(run), "--init", str(init), "--smooth", "-o", str(d / "states.mcap")])
    err = _py(STAGES.format(run=str(run), init=str(init), out=str(d / "states2.mcap"), workdir=str(d)))
    stages = []
    for ln in err.splitlines():
        if ln.startswith("__STAGE__"):
            name, s, rss, hwm = json.loads(ln.split(" ", 1)[1])
            stages.append({"stage": name, "s": s, "rss_mib": rss, "peak_rss_mib_so_far": hwm})
    same = (d / "states.mcap").read_bytes() == (d / "states2.mcap").read_bytes()
    return {"estimate_smooth_wall_s": wall, "estimate_smooth_peak_rss_mib": peak,
            "states_mcap_mib": (d / "states.mcap").stat().st_size / 2**20,
            "run_mcap_mib": run.stat().st_size / 2**20, "byte_identical_rerun": same, "stages": stages}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1.0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workdir", type=Path, default=None, help="keep the simulated data here (reused next time)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for h in a.hours:
            d = (a.workdir or Path(tmp)) / f"h{h:g}"
            rows.append({**setup(d, h, a.seed), **measure(d)})
            if a.workdir is None:
                for f in d.glob("*.mcap"):
                    f.unlink()
    res = {"command": "cdgps estimate RUN.mcap --init INIT.json --smooth -o STATES.mcap",
           "config": "configs/testbed-1998-lumped.toml (10 Hz)", "runs": rows,
           "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "machine": platform.machine(),
                       "load_average_1min_at_end": os.getloadavg()[0]}}
    if len(rows) > 1:
        hs = [r["hours"] for r in rows]
        res["peak_rss_mib_per_hour"] = float(_slope(hs, [r["estimate_smooth_peak_rss_mib"] for r in rows]))
        res["wall_s_per_hour"] = [r["estimate_smooth_wall_s"] / r["hours"] for r in rows]
    if a.out:
        a.out.write_text(json.dumps(res, indent=1) + "\n")
    if a.json:
        print(json.dumps(res, indent=2))
        return
    for r in rows:
        print(f"{r['hours']:g} h, RUN {r['run_mcap_mib']:.1f} MiB → STATES {r['states_mcap_mib']:.1f} MiB: "
              f"cdgps estimate --smooth {r['estimate_smooth_wall_s']:.1f} s, peak RSS "
              f"{r['estimate_smooth_peak_rss_mib']:.0f} MiB (byte-identical rerun: {r['byte_identical_rerun']})")
        for st in r["stages"]:
            print(f"    {st['stage']:20s} {st['s']:6.2f} s   RSS {st['rss_mib']:6.0f} MiB   peak so far "
                  f"{st['peak_rss_mib_so_far']:6.0f} MiB")
    if "peak_rss_mib_per_hour" in res:
        print(f"peak RSS grows {res['peak_rss_mib_per_hour']:.0f} MiB per hour of record")


def _slope(x, y) -> float:
    """Least-squares slope of y over x."""
    x, y = [float(v) for v in x], [float(v) for v in y]
    mx, my = sum(x) / len(x), sum(y) / len(y)
    return sum((a - mx) * (b - my) for a, b in zip(x, y)) / sum((a - mx) ** 2 for a in x)


if __name__ == "__main__":
    main()
