#!/usr/bin/env python3
"""I/O of ``cdgps estimate`` against its filter (issue 13 item 5), one hour of 10 Hz testbed data.

Simulates the hour (seed 1, 2 cm noise, disturbance scale 1), ingests it and initializes on its
first 60 s (cached in ``--workdir``), then runs ``cdgps estimate RUN.mcap --init INIT.json [--smooth]
-o STATES.mcap`` as its own process, ``--repeat`` times each.  Inside that process the library
calls the command makes are timed by wrappers (``read_run``, ``estimate`` — the filter's own time,
with the INIT window and, with ``--smooth``, the smoother — and ``write_states``); the process
itself is timed from outside (interpreter start to exit).  Each run gives

* ``process_s``: the whole command, wall clock;
* ``stages_s``: import (cdgps and its dependencies), read RUN.mcap, filter, write STATES.mcap,
  and the rest (option checks, hashing the RUN for the INIT pairing, …);
* ``ratio_process_over_filter`` = process_s / filter — the target is ≤ 2, measured in one run;

and the file sizes: RUN.mcap, STATES.mcap (targets: STATES ≤ RUN by default).  The best run (least
``process_s``) of each case is the headline; all runs are kept.  Writes ``--out`` (JSON) and prints a
table::

    python benchmarks/bench_io.py                          # ≈ 2 min after the first setup
    python benchmarks/bench_io.py --hours 0.25 --repeat 1 --out /tmp/io.json

``--label`` names the code measured (e.g. ``before`` on a checkout of the previous commit, whose
``benchmarks/`` gets this file copied in: the script measures the tree it lives in).
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

CLI = """
import json, sys, time
t0 = time.perf_counter()
from cdgps_cli.cli.commands import main                 # what the console script imports first
import cdgps_cli.estimation.filter as E, cdgps_cli.io.run as R, cdgps_cli.io.states as S
stages = {{"import": time.perf_counter() - t0}}
imported_in_filter = []
def timed(mod, name, key):
    f = getattr(mod, name)
    def wrapper(*a, **k):
        before = set(sys.modules)
        t = time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            stages[key] = stages.get(key, 0.0) + time.perf_counter() - t
            if key == "filter":
                imported_in_filter.extend(sorted(set(sys.modules) - before))
    setattr(mod, name, wrapper)
timed(R, "read_run", "read RUN.mcap")
timed(E, "estimate", "filter")
timed(S, "write_states", "write STATES.mcap")
main({args!r}, standalone_mode=False)
stages["inside"] = time.perf_counter() - t0
print("__IO__", json.dumps(stages), file=sys.stderr)
print("__FILTER_IMPORTS__", json.dumps(imported_in_filter), file=sys.stderr)
"""


def compile_bytecode() -> None:
    """Compile this tree's ``cdgps_cli`` into its ``__pycache__`` directories (git-ignored) once.

    An installed package has its bytecode; this tree (an editable install, and environments with
    ``PYTHONDONTWRITEBYTECODE=1``) would otherwise compile ≈ 50 modules in every timed process
    (≈ 0.1 s), which is not the command's cost.  (Numpy, scipy, pandas… have theirs from pip.)"""
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "cdgps_cli")], check=True, cwd=ROOT)


def _python(code: str) -> tuple[float, str]:
    """Run code in a fresh interpreter (this tree first on the path); (wall s, stderr)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env)
    wall = time.perf_counter() - t
    if p.returncode != 0:
        raise SystemExit(p.stderr)
    return wall, p.stderr


def _cli(args: list[str]) -> None:
    _python(f"from cdgps_cli.cli.commands import main\nmain({['--quiet', *args]!r}, standalone_mode=False)")


def setup(d: Path, hours: float, seed: int) -> dict:
    """Simulated hour, RUN.mcap and INIT.json in d (reused when already there)."""
    d.mkdir(parents=True, exist_ok=True)
    tag = d / f"setup-{hours:g}h-seed{seed}.json"
    if tag.exists() and (d / "run.mcap").exists() and (d / "init.json").exists():
        return json.loads(tag.read_text())
    t0 = time.perf_counter()
    _cli(["simulate", str(CONFIG), "--duration", str(3600 * hours), "--seed", str(seed), "--noise-m", "0.02",
          "--disturbance-scale", "1", "-o", str(d / "sim")])
    t1 = time.perf_counter()
    _cli(["ingest", str(d / "sim" / "receiver.csv"), "--config", str(CONFIG), "-o", str(d / "run.mcap")])
    t2 = time.perf_counter()
    _cli(["init", str(d / "run.mcap"), "--start", "0", "--duration", "60", "-o", str(d / "init.json")])
    info = {"hours": hours, "seed": seed, "simulate_s": t1 - t0, "ingest_s": t2 - t1,
            "init_s": time.perf_counter() - t2}
    tag.write_text(json.dumps(info))
    return info


def run_estimate(d: Path, smooth: bool, out: Path) -> dict:
    """One `cdgps estimate` process: its wall time, the stages inside it, the STATES size."""
    args = ["--quiet", "estimate", str(d / "run.mcap"), "--init", str(d / "init.json"),
            *(["--smooth"] if smooth else []), "-o", str(out)]
    wall, err = _python(CLI.format(args=args))
    stages = json.loads([ln for ln in err.splitlines() if ln.startswith("__IO__")][-1].split(" ", 1)[1])
    in_filter = json.loads([ln for ln in err.splitlines() if ln.startswith("__FILTER_IMPORTS__")][-1].split(" ", 1)[1])
    inside = stages.pop("inside")
    stages["interpreter start and exit"] = wall - inside
    stages["other (option checks, RUN hash for the INIT pairing, …)"] = inside - sum(
        v for k, v in stages.items() if k != "interpreter start and exit")
    return {"process_s": wall, "stages_s": stages, "ratio_process_over_filter": wall / stages["filter"],
            "states_mib": out.stat().st_size / 2**20, "load_average_1min": os.getloadavg()[0],
            # modules first imported inside the timed filter call (their import time counts as filter)
            "modules_imported_during_filter": in_filter}


def measure(d: Path, repeat: int) -> dict:
    cases = {}
    for smooth in (False, True):
        runs = []
        for i in range(repeat):
            out = d / f"states{'-smooth' if smooth else ''}-{i}.mcap"
            runs.append(run_estimate(d, smooth, out))
        same = len({(d / f"states{'-smooth' if smooth else ''}-{i}.mcap").read_bytes() for i in range(repeat)}) == 1
        best = min(runs, key=lambda r: r["process_s"])
        cases["estimate --smooth" if smooth else "estimate"] = {"best": best, "runs": runs,
                                                                 "byte_identical_reruns": same}
    return cases


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workdir", type=Path, default=None, help="keep the simulated data here (reused next time)")
    ap.add_argument("--label", default="after", help="name of the code measured (recorded in the output)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "io.json")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = a.workdir or Path(tmp)
        res = {"label": a.label, "setup": setup(d, a.hours, a.seed)}
        compile_bytecode()
        res["bytecode"] = "cdgps_cli precompiled into its __pycache__, as an installed package has it"
        res["run_mcap_mib"] = (d / "run.mcap").stat().st_size / 2**20
        res["cases"] = measure(d, a.repeat)
    res["machine"] = {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform(),
                      "load_average_at_end": list(os.getloadavg())}
    res["date"] = time.strftime("%Y-%m-%d %H:%M")
    res["command"] = "python benchmarks/bench_io.py " + " ".join(sys.argv[1:])
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=2) + "\n")
    print(f"{a.label}: {a.hours:g} h of 10 Hz testbed data, RUN.mcap {res['run_mcap_mib']:.1f} MiB "
          f"(ingest {res['setup']['ingest_s']:.1f} s); load average at end {res['machine']['load_average_at_end'][0]:.1f}")
    for name, c in res["cases"].items():
        b = c["best"]
        print(f"  cdgps {name}: {b['process_s']:.2f} s = {b['ratio_process_over_filter']:.2f}× the filter "
              f"(target ≤ 2×); STATES.mcap {b['states_mib']:.1f} MiB (RUN {res['run_mcap_mib']:.1f} MiB); "
              f"byte-identical reruns: {c['byte_identical_reruns']}")
        for k, v in b["stages_s"].items():
            print(f"      {k:58s} {v:6.2f} s")
        print(f"      (load average {b['load_average_1min']:.1f}; modules first imported inside the filter call: "
              f"{', '.join(b['modules_imported_during_filter']) or 'none'})")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
