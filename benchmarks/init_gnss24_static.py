"""`cdgps init` on the 24 h GNSS static pair at 1 Hz: this tree against earlier ones, interleaved
(issue 29: the static engine's filter loop).

Each round runs ``init`` once per tree, the earlier trees first, each in a fresh process that records
its own CPU (user + system, ``resource.getrusage``), wall time and peak RSS (``ru_maxrss``), the CPU
spent inside ``static_engine.static_filter`` (the engine's filter: 86 400 epochs of ≈ 90 states), and
the load average before it started.  Each earlier tree's init.json is compared with this tree's: every
integer and string equal, and the largest absolute / relative difference of the numbers (the float and
fixed ENU, σ, ratio).  Writes ``docs/benchmarks/long_records_gnss24_static.json``.

Run (a few minutes; the 24 h run.mcap from ``benchmarks/long_records.py --gnss-hours 24``)::

    PYTHONPATH=. python benchmarks/init_gnss24_static.py <24 h run.mcap> --before /tmp/main_s7 \
        --before <a copy of the branch's base> --rounds 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "long_records_gnss24_static.json"

_CHILD = r"""
import json, os, resource, sys, time
tree, run, out = sys.argv[1:4]
sys.path.insert(0, tree)
from cdgps_cli.estimation import static_engine as se
spent = []
real = se.static_filter
def timed(*a, **k):
    t0 = time.process_time()
    try:
        return real(*a, **k)
    finally:
        spent.append(time.process_time() - t0)
se.static_filter = timed
from cdgps_cli.cli.commands import main
load = os.getloadavg()[0]
w0 = time.perf_counter()
sys.argv = ["cdgps", "-q", "init", run, "-o", out]
try:
    main()
except SystemExit as e:
    if e.code:
        raise
ru = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"user_s": ru.ru_utime, "system_s": ru.ru_stime, "cpu_s": ru.ru_utime + ru.ru_stime,
                  "wall_s": time.perf_counter() - w0, "peak_rss_mib": ru.ru_maxrss / 1024,
                  "static_filter_cpu_s": sum(spent), "load_1min_before": load}))
"""


def _run(tree: Path, run: Path, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    p = subprocess.run([sys.executable, "-c", _CHILD, str(tree), str(run), str(out)], env=env,
                       cwd=tempfile.gettempdir(), capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{tree}: init failed\n{p.stderr[-2000:]}")
    r = json.loads(p.stdout.strip().splitlines()[-1])
    return {k: round(v, 3) for k, v in r.items()}


def _walk(a, b, path: str, out: dict) -> None:
    """Every number's largest abs / rel difference by path ([] for list items); other values must be equal."""
    if isinstance(a, dict):
        if set(a) != set(b):
            out.setdefault("mismatch", []).append(f"{path}: keys {sorted(set(a) ^ set(b))}")
            return
        for k in a:
            _walk(a[k], b[k], f"{path}/{k}", out)
    elif isinstance(a, list):
        if len(a) != len(b):
            out.setdefault("mismatch", []).append(f"{path}: length {len(a)} != {len(b)}")
            return
        for x, y in zip(a, b):
            _walk(x, y, f"{path}[]", out)
    elif isinstance(a, float) and isinstance(b, float):
        d = abs(a - b)
        if d > 0:
            o = out.setdefault("numbers", {}).setdefault(path, [0.0, 0.0])
            o[0], o[1] = max(o[0], d), max(o[1], d / max(abs(a), 1e-300))
    elif a != b:
        out.setdefault("mismatch", []).append(f"{path}: {a!r} != {b!r}")


def compare(before: Path, after: Path) -> dict:
    out: dict = {}
    _walk(json.loads(before.read_text()), json.loads(after.read_text()), "", out)
    nums = {p: {"max_abs": float(f"{d:.3g}"), "max_rel": float(f"{r:.3g}")}
            for p, (d, r) in sorted(out.get("numbers", {}).items())}
    return {"identical": not nums and not out.get("mismatch"), "other_values_equal": not out.get("mismatch"),
            "mismatches": out.get("mismatch", [])[:20], "numbers": nums}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="the 24 h pair's run.mcap")
    ap.add_argument("--before", type=Path, action="append", required=True,
                    help="an earlier tree (with its .so files); repeat for several, each run before this tree")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=OUT, help=f"the JSON written (default {OUT.relative_to(ROOT)})")
    args = ap.parse_args()
    trees = {f"before_{i}": t for i, t in enumerate(args.before)} | {"after": ROOT}
    res = {"run": str(args.run), "trees": {k: str(t) for k, t in trees.items()}, "rounds": []}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for i in range(args.rounds):
            rnd = {}
            for key, tree in trees.items():
                rnd[key] = _run(tree, args.run.resolve(), tmp / f"{key}.json")
                print(i, key, rnd[key], flush=True)
            res["rounds"].append(rnd)
        res["init_json_vs_after"] = {key: compare(tmp / f"{key}.json", tmp / "after.json")
                                     for key in trees if key != "after"}
    res["least_cpu"] = {key: min((r[key] for r in res["rounds"]), key=lambda r: r["cpu_s"]) for key in trees}
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(res["least_cpu"], indent=1))
    print("init.json other values equal:", {k: v["other_values_equal"] for k, v in res["init_json_vs_after"].items()},
          "; wrote", args.out)


if __name__ == "__main__":
    main()
