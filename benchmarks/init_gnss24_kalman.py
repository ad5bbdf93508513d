"""`cdgps init` on the 24 h GNSS static pair at 1 Hz, before / after the static engine's compiled per-epoch
update (issue 29: ``kalman.iterated_update_covariance`` on RunDDModel rows in ``_ekfcore.sd_update``).

Each round runs, per tree (the earlier tree first), ``/usr/bin/time -v cdgps -q init`` (wall, user, system,
peak RSS, the 1-min load average before it), then a child that runs the same init with a wall clock around
``static_engine.static_filter`` (86 400 epochs of ≈ 90 states).  Once per tree, a child profiles
``static_filter`` with cProfile (its slowest functions by own time).  The two INIT files must be byte-identical
(their SHA-256 and :func:`init_gnss24_static.compare`'s number-by-number walk are recorded).  Every process
runs from the temporary directory with ``PYTHONPATH`` naming its tree and bytecode caching on.  Writes
``docs/benchmarks/long_records_gnss24_kalman.json``.

Run (about 5 minutes; the 24 h run.mcap from ``benchmarks/long_records.py --gnss-hours 24``)::

    PYTHONPATH=. python benchmarks/init_gnss24_kalman.py <24 h run.mcap> --before /tmp/main_s8 --rounds 2
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "long_records_gnss24_kalman.json"
sys.path.insert(0, str(Path(__file__).resolve().parent))
from init_gnss24_static import compare  # noqa: E402

_CHILD = r"""
import cProfile, json, os, pstats, sys, time
tree, run, out, profile = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4] == "1"
sys.path.insert(0, tree)
from cdgps_cli.estimation import static_engine as se
spent, prof = [], cProfile.Profile()
real = se.static_filter
def timed(*a, **k):
    t0 = time.perf_counter()
    if profile:
        prof.enable()
    try:
        return real(*a, **k)
    finally:
        if profile:
            prof.disable()
        spent.append(time.perf_counter() - t0)
se.static_filter = timed
from cdgps_cli.cli.commands import main
load = os.getloadavg()[0]
sys.argv = ["cdgps", "-q", "init", run, "-o", out]
try:
    main()
except SystemExit as e:
    if e.code:
        raise
res = {"static_filter_wall_s": round(sum(spent), 3), "load_1min_before": load}
if profile:
    st = pstats.Stats(prof)
    rows = sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:14]
    res["top_tottime"] = [[f"{os.path.basename(f)}:{line}({fn})", nc, round(tt, 3), round(ct, 3)]
                          for (f, line, fn), (cc, nc, tt, ct, _) in rows]
print(json.dumps(res))
"""


def _env(tree: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _time_v(tree: Path, run: Path, out: Path) -> dict:
    """``/usr/bin/time -v cdgps -q init``: wall, user, system (s), peak RSS (MiB), the load before."""
    load = os.getloadavg()[0]
    venv = Path(sys.executable).with_name("cdgps")          # the console script of this interpreter's venv
    cdgps = str(venv) if venv.exists() else shutil.which("cdgps")
    p = subprocess.run(["/usr/bin/time", "-v", cdgps, "-q", "init", str(run), "-o", str(out)], env=_env(tree),
                       cwd=tempfile.gettempdir(), capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{tree}: init failed\n{p.stderr[-2000:]}")

    def field(name):
        return re.search(rf"{re.escape(name)}: (.+)", p.stderr).group(1).strip()
    h_m_s = [float(x) for x in field("Elapsed (wall clock) time (h:mm:ss or m:ss)").split(":")]
    wall = sum(v * 60 ** i for i, v in enumerate(reversed(h_m_s)))
    return {"wall_s": round(wall, 2), "user_s": float(field("User time (seconds)")),
            "system_s": float(field("System time (seconds)")),
            "peak_rss_mib": round(int(field("Maximum resident set size (kbytes)")) / 1024, 1), "load_1min_before": load}


def _child(tree: Path, run: Path, out: Path, profile: bool) -> dict:
    p = subprocess.run([sys.executable, "-c", _CHILD, str(tree), str(run), str(out), "1" if profile else "0"],
                       env=_env(tree), cwd=tempfile.gettempdir(), capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{tree}: init failed\n{p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="the 24 h pair's run.mcap")
    ap.add_argument("--before", type=Path, required=True, help="the tree before (with its .so files)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=OUT, help=f"the JSON written (default {OUT.relative_to(ROOT)})")
    args = ap.parse_args()
    trees = {"before": args.before.resolve(), "after": ROOT}
    run = args.run.resolve()
    res = {"run": str(run), "trees": {k: str(t) for k, t in trees.items()}, "rounds": []}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for i in range(args.rounds):
            rnd = {}
            for key, tree in trees.items():
                rnd[key] = {"time_v": _time_v(tree, run, tmp / f"{key}.json"),
                            "static_filter": _child(tree, run, tmp / f"{key}_child.json", False)}
                print(i, key, rnd[key], flush=True)
            res["rounds"].append(rnd)
        res["cprofile_static_filter"] = {key: _child(tree, run, tmp / f"{key}_prof.json", True) for key, tree in trees.items()}
        digest = {key: hashlib.sha256((tmp / f"{key}.json").read_bytes()).hexdigest() for key in trees}
        res["init_json"] = {"sha256": digest, "byte_identical": digest["before"] == digest["after"],
                            "walk": compare(tmp / "before.json", tmp / "after.json")}
    best = {key: {"init_wall_s": min(r[key]["time_v"]["wall_s"] for r in res["rounds"]),
                  "init_user_s": min(r[key]["time_v"]["user_s"] for r in res["rounds"]),
                  "peak_rss_mib": max(r[key]["time_v"]["peak_rss_mib"] for r in res["rounds"]),
                  "static_filter_wall_s": min(r[key]["static_filter"]["static_filter_wall_s"] for r in res["rounds"]),
                  "static_filter_cprofile_s": res["cprofile_static_filter"][key]["static_filter_wall_s"]}
            for key in trees}
    res["best"] = best
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(best, indent=1), "\nINIT byte-identical:", res["init_json"]["byte_identical"], "; wrote", args.out)


if __name__ == "__main__":
    main()
