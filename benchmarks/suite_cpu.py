"""CPU-time profile of the test suite, per test file and per test (issue: keep `make test` under ~5 min).

Runs the whole suite once, serially (no xdist), niced, with ``_suite_cpu_plugin`` recording CPU seconds
(user + system, children included) per test item with its fixture setup/teardown; writes the totals,
every file's CPU seconds (the unit ``--dist loadfile`` balances) and the slowest tests to
``docs/benchmarks/suite_cpu.json``. CPU rather than wall time: the machine is shared, wall time is not
a property of the suite.

    python benchmarks/suite_cpu.py                 # run the suite (~10 min of CPU on 2 loaded cores)
    python benchmarks/suite_cpu.py --raw rows.json # summarise rows of an earlier run, no rerun
    python benchmarks/suite_cpu.py --label x --out /tmp/x.json -- tests/core  # a part of the suite
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "suite_cpu.json"
FILE_LIMIT_CPU_S = 60.0          # a file above this makes one loadfile worker the suite's tail


def run_suite(raw: Path, pytest_args: list) -> dict:
    """Run pytest serially with the plugin (on ``pytest_args``, the whole suite if empty); returns the whole run's CPU seconds and the load average."""
    env = dict(os.environ, SUITE_CPU_RAW=str(raw),
               PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "benchmarks"), os.environ.get("PYTHONPATH", "")]))
    load = os.getloadavg()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(["nice", "-n", "10", sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                    "-p", "_suite_cpu_plugin", *pytest_args], cwd=ROOT, env=env, check=False)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"process_cpu_s": round(cpu, 1), "load_average_at_start": [round(v, 2) for v in load]}


def summarise(rows: list, top: int = 40) -> dict:
    """Totals, CPU seconds per file (descending) and the ``top`` slowest tests."""
    per_file: dict = collections.defaultdict(float)
    for nodeid, cpu_s, _ in rows:
        per_file[nodeid.split("::")[0]] += cpu_s
    files = sorted(per_file.items(), key=lambda kv: -kv[1])
    tests = sorted(rows, key=lambda r: -r[1])[:top]
    return {"tests": len(rows), "tests_cpu_s": round(sum(r[1] for r in rows), 1),
            "tests_wall_s": round(sum(r[2] for r in rows), 1),
            "files_over_limit": [f for f, c in files if c > FILE_LIMIT_CPU_S],
            "per_file_cpu_s": {f: round(c, 2) for f, c in files},
            "slowest_tests_cpu_s": {n: round(c, 2) for n, c, _ in tests}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--raw", type=Path, help="rows [nodeid, cpu_s, wall_s] of an earlier run (no rerun)")
    ap.add_argument("--label", default="current", help="key of this profile in the output file")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("pytest_args", nargs="*", help="test files or options for pytest (default: the whole suite)")
    a = ap.parse_args()
    run_info: dict = {}
    if a.raw is None:
        a.raw = Path(tempfile.mkdtemp()) / "rows.json"
        run_info = run_suite(a.raw, a.pytest_args)
    result = {**run_info, **summarise(json.loads(a.raw.read_text(encoding="utf-8")))}
    doc = json.loads(a.out.read_text(encoding="utf-8")) if a.out.exists() else {}
    doc.setdefault("machine", {"python": platform.python_version(), "cores": os.cpu_count()})
    doc[a.label] = result
    a.out.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    print(f"{a.label}: {result['tests']} tests, {result['tests_cpu_s']} s CPU; "
          f"files over {FILE_LIMIT_CPU_S:.0f} s: {result['files_over_limit'] or 'none'}")


if __name__ == "__main__":
    main()
