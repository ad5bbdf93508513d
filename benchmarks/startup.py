"""Process start-up of `cdgps` commands (issues 28 item 6, 29 item 3, 30): what each command imports
and what its whole process costs, against interpreter floors, in one run.

For each source tree (``--tree NAME=PATH``, e.g. ``before=/tmp/before after=.``) and each command:

* imports: one ``python -X importtime`` run; the top cumulative modules (µs) and the cumulative cost of
  the big third-party packages (numpy, pandas, scipy, matplotlib, dask, mcap) when loaded;
* process: wall and CPU (user + system, of the child) of the whole command, in interleaved rounds
  (floor, tree A, tree B, floor, ...; the machine is shared), after one untimed warm-up that writes
  the bytecode caches (a user's environment: PYTHONDONTWRITEBYTECODE is removed); medians.

Commands: ``cdgps --help``; ``cdgps rtk`` on the mosaic-static pair, GPS L1; ``cdgps estimate`` on the
testbed hour (configs/testbed-1998.toml simulated, ingested and initialised once, as
benchmarks/bench_driver.py does); ``cdgps info`` on that RUN, or on ``--info-run`` (e.g. the 24 h RUN of
benchmarks/long_records.py).  Floors: ``python -c pass``, ``import numpy``, ``import numpy, pandas``.

    python benchmarks/startup.py --tree before=/tmp/before --tree after=. --repeat 5 \\
        --info-run /tmp/long/run-24h.mcap --out docs/benchmarks/startup.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
MOSAIC = ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
MOSAIC_XYZ = ("-3817681.1213", "3562839.4311", "3650159.1593")
PACKAGES = ("numpy", "pandas", "scipy", "matplotlib", "dask", "mcap")
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    ENV.setdefault(_var, "1")


def commands(d: Path, info_run: Path | None) -> dict[str, list[str]]:
    """cdgps arguments of each timed command (``-q``: no progress on stderr)."""
    return {
        "help": ["--help"],
        "rtk_mosaic_gps_l1": ["-q", "rtk", "--base", str(MOSAIC / "base.obs"), "--rover", str(MOSAIC / "rover.obs"),
                              "--nav", str(MOSAIC / "base.nav"), "--signals", "G:L1", "--base-xyz", *MOSAIC_XYZ,
                              "-o", str(d / "rtk.csv")],
        "estimate_testbed_1h": ["-q", "estimate", str(d / "run.mcap"), "--init", str(d / "init.json"),
                                "-o", str(d / "states.mcap")],
        "info": ["-q", "info", str(info_run or d / "run.mcap")],
    }


FLOORS = {"python": "pass", "numpy": "import numpy", "numpy_pandas": "import numpy, pandas"}


#: the working directory of every child: neutral, so that ``python -c`` (which puts the working directory
#: first on sys.path) imports cdgps from the tree on PYTHONPATH, not from where the script was started
CWD = Path(tempfile.gettempdir())


def _argv(tree: Path, args: list[str], importtime: bool = False) -> tuple[list[str], dict]:
    code = f"import sys; from cdgps_cli.cli.commands import main; sys.argv = ['cdgps'] + {args!r}; main()"
    return [sys.executable] + (["-X", "importtime"] if importtime else []) + ["-c", code], dict(ENV, PYTHONPATH=str(tree))


def timed(argv: list[str], env: dict) -> dict:
    """Wall and child CPU seconds of one process (it must succeed)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    p = subprocess.run(argv, env=env, capture_output=True, text=True, cwd=CWD)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise SystemExit(f"{argv[-1][:200]} failed:\n{p.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu}


_LINE = re.compile(r"^import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)$")


def import_profile(tree: Path, args: list[str], top: int = 10) -> dict:
    """Top-level modules by cumulative import time and the big packages' cumulative times (µs)."""
    argv, env = _argv(tree, args, importtime=True)
    p = subprocess.run(argv, env=env, capture_output=True, text=True, cwd=CWD)
    if p.returncode != 0:
        raise SystemExit(f"{argv[-1][:200]} failed:\n{p.stderr[-2000:]}")
    rows = [m.groups() for m in map(_LINE.match, p.stderr.splitlines()) if m]
    total = sum(int(cum) for _, cum, ind, _ in rows if len(ind) == 1)
    tops = sorted(((int(cum), name) for _, cum, ind, name in rows if len(ind) == 1), reverse=True)[:top]
    pk = {name: int(cum) for _, cum, _, name in rows if name in PACKAGES}
    return {"total_import_us": total, "top_cumulative_us": [[n, c] for c, n in tops], "packages_us": pk,
            "modules_loaded": len(rows)}


def setup(d: Path) -> None:
    """The testbed hour: RUN.mcap and INIT.json (as bench_driver.py)."""
    from bench_driver import setup as driver_setup
    driver_setup(d, 1.0, 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tree", action="append", default=[], help="NAME=PATH of a source tree (repeatable)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--info-run", type=Path, help="RUN.mcap for `cdgps info` (default: the testbed hour)")
    ap.add_argument("--only", nargs="+", help="command names to time (default: all)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "startup.json")
    a = ap.parse_args()
    trees = [(n, Path(p).resolve()) for n, p in (t.split("=", 1) for t in (a.tree or ["after=" + str(ROOT)]))]
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        setup(d)
        cmds = {k: v for k, v in commands(d, a.info_run).items() if not a.only or k in a.only}
        for name, tree in trees:                       # warm-up: bytecode caches, page cache
            for args in cmds.values():
                timed(*_argv(tree, args))
        imports = {name: {c: import_profile(tree, args) for c, args in cmds.items()} for name, tree in trees}
        runs, loads = [], []
        for _ in range(a.repeat):
            loads.append(os.getloadavg()[0])
            row = {f"floor_{k}": timed([sys.executable, "-c", code], ENV) for k, code in FLOORS.items()}
            for c, args in cmds.items():
                for name, tree in trees:
                    row[f"{name}:{c}"] = timed(*_argv(tree, args))
            runs.append(row)
    med = {k: {m: statistics.median(r[k][m] for r in runs) for m in ("wall_s", "cpu_s")} for k in runs[0]}
    res = {"what": __doc__.split("\n")[0], "repeat": a.repeat, "loads_1min_per_round": loads,
           "medians": med, "imports_us": imports, "per_round": runs,
           "trees": {n: str(p) for n, p in trees}, "info_run": str(a.info_run) if a.info_run else "testbed hour",
           "machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                       "load_at_end": list(os.getloadavg())},
           "date": time.strftime("%Y-%m-%d %H:%M"),
           "command": "python benchmarks/startup.py " + " ".join(sys.argv[1:])}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    for k, v in med.items():
        print(f"{k:34s} wall {v['wall_s']:.3f} s  cpu {v['cpu_s']:.3f} s")
    print(f"loads {loads}; wrote {a.out}")


if __name__ == "__main__":
    main()
