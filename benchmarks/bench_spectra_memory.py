#!/usr/bin/env python3
"""Peak memory and wall time of ``cdgps spectra`` on 1 h and 3 h of 10 Hz testbed STATES (issue 29).

For every record length (``--hours``) the STATES.mcap is made once in ``--workdir/h<hours>``
(``cdgps simulate`` seed 1, 2 cm noise, disturbance scale 1 → ``ingest`` → ``init`` on 0–60 s →
``estimate --smooth``; a ``states.mcap`` already there is used as it is), then

    cdgps --quiet spectra STATES.mcap -o OUT

(and with ``--gyro``: ``--gyro RUN.mcap``, the record's RUN ingested with its gyro log) runs in a
fresh process per source tree (``--tree LABEL=PATH``, default: this checkout as
``after``; e.g. ``--tree before=/tmp/oldsrc`` for an export of the commit before): wall time and
peak RSS (VmHWM of that process).  Each tree's psd.csv and peaks.json are compared with the first
tree's: byte-identical or not, the largest difference of a PSD value relative to its column's
maximum, and the largest relative difference of a mode figure.  Writes ``--out`` (JSON)::

    python benchmarks/bench_spectra_memory.py --workdir /tmp/specbench --hours 1 3 \\
        --tree before=/tmp/specbench/oldsrc --tree after=. --out docs/benchmarks/spectra_memory.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"

CLI = """
import sys, time
t = time.perf_counter()
from cdgps_cli.cli.commands import main
main({args!r}, standalone_mode=False)
dt = time.perf_counter() - t
with open('/proc/self/status') as fh:
    hwm = [int(l.split()[1]) / 1024.0 for l in fh if l.startswith('VmHWM:')][0]
print('__BENCH__', dt, hwm, file=sys.stderr)
"""


def _cli(args: list[str], tree: Path) -> tuple[float, float]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    p = subprocess.run([sys.executable, "-c", CLI.format(args=["--quiet", *map(str, args)])], capture_output=True,
                       text=True, cwd=tree, env=env)
    if p.returncode != 0:
        raise SystemExit(p.stderr)
    _, dt, rss = [ln for ln in p.stderr.splitlines() if ln.startswith("__BENCH__")][-1].split()
    return float(dt), float(rss)


def make_states(d: Path, hours: float) -> Path:
    """STATES.mcap of ``hours`` of 10 Hz testbed data in ``d`` (made once)."""
    states = d / "states.mcap"
    if states.exists():
        return states
    d.mkdir(parents=True, exist_ok=True)
    _cli(["simulate", CONFIG, "--duration", 3600 * hours, "--seed", 1, "--noise-m", 0.02, "--disturbance-scale", 1,
          "-o", d / "sim"], ROOT)
    _cli(["ingest", d / "sim" / "receiver.csv", "--config", CONFIG, "-o", d / "run.mcap"], ROOT)
    _cli(["init", d / "run.mcap", "--start", 0, "--duration", 60, "-o", d / "init.json"], ROOT)
    _cli(["estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "-o", states], ROOT)
    return states


def gyro_run(d: Path) -> Path | None:
    """RUN.mcap with the gyro log (``ingest receiver.csv gyro.csv``) of the record in ``d``, made once
    from ``d/sim``; None when neither is there."""
    run = d / "rungyro.mcap"
    if not run.exists() and (d / "sim" / "gyro.csv").exists():
        _cli(["ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", CONFIG, "-o", run], ROOT)
    return run if run.exists() else None


def compare(ref: Path, new: Path) -> dict:
    """psd.csv and peaks.json of ``new`` against ``ref``."""
    out = {}
    for name in ("psd.csv", "peaks.json"):
        out[f"{name}_byte_identical"] = (ref / name).read_bytes() == (new / name).read_bytes()
    a, b = pd.read_csv(ref / "psd.csv"), pd.read_csv(new / "psd.csv")
    scale = a.abs().max().replace(0, 1.0)
    out["psd_max_diff_of_column_max"] = float(((a - b).abs() / scale).max().max())
    pa, pb = json.loads((ref / "peaks.json").read_text()), json.loads((new / "peaks.json").read_text())
    rel: dict = {}
    for ma, mb in zip(pa["modes"], pb["modes"]):
        for k, x in ma.items():
            if isinstance(x, float) and isinstance(mb[k], float) and x != 0:
                rel[k] = max(rel.get(k, 0.0), abs(mb[k] - x) / abs(x))
    out["modes_max_rel_diff_by_figure"] = rel          # error_pct = 100 (f − f_model) / f_model: relative to a small number
    out["modes_seen_equal"] = [m["seen"] for m in pa["modes"]] == [m["seen"] for m in pb["modes"]]
    out["settings_equal"] = pa["settings"] == pb["settings"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1.0, 3.0])
    ap.add_argument("--workdir", type=Path, required=True, help="records are made (once) and kept here")
    ap.add_argument("--tree", action="append", default=None, metavar="LABEL=PATH",
                    help="a cdgps source tree to run (repeatable; default after=this checkout)")
    ap.add_argument("--out", type=Path, default=None, help="write the JSON here")
    ap.add_argument("--gyro", action="store_true",
                    help="also with --gyro (the record's RUN.mcap with the gyro log, ingested once from its sim/)")
    a = ap.parse_args()
    trees = [(t.split("=", 1)[0], Path(t.split("=", 1)[1]).resolve()) for t in (a.tree or [f"after={ROOT}"])]
    res = {"command": "cdgps --quiet spectra STATES.mcap -o OUT (fresh process; VmHWM)",
           "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
                      f"numpy {np.__version__}", "records": []}
    for h in a.hours:
        d = a.workdir / f"h{h:g}"
        states = make_states(d, h)
        rec = {"hours": h, "states_mcap_mib": states.stat().st_size / 2**20, "runs": {}}
        gyro = gyro_run(d) if a.gyro else None
        for extra, tag in [([], "")] + ([(["--gyro", gyro], "+gyro")] if gyro else []):
            for label, tree in trees:
                key = label + tag
                wall, peak = _cli(["spectra", states, *extra, "-o", d / f"spectra-{key}"], tree)
                rec["runs"][key] = {"wall_s": wall, "peak_rss_mib": peak}
                if label != trees[0][0]:
                    rec["runs"][key]["vs_" + trees[0][0] + tag] = compare(d / f"spectra-{trees[0][0]}{tag}",
                                                                          d / f"spectra-{key}")
                print(f"{h:g} h ({rec['states_mcap_mib']:.1f} MiB STATES) {key:>14}: {wall:6.2f} s, peak RSS "
                      f"{peak:6.0f} MiB", flush=True)
        res["records"].append(rec)
    text = json.dumps(res, indent=2) + "\n"
    if a.out:
        a.out.write_text(text)
    else:
        print(text)


if __name__ == "__main__":
    main()
