#!/usr/bin/env python3
"""``estimate --smooth`` CPU per hour of record, 1 / 6 / 24 h testbed, two source trees interleaved
(issue 29 item 6: time per hour flat within 10 %), and the STATES message writers of the 24 h GNSS
pair (issue 29: the whole GNSS command < 30 s).

Testbed: the records of ``benchmarks/long_records.py --hours 1 6 24 --workdir W`` (``W``/<H>h/run.mcap,
init.json).  For each round and each record length, ``cdgps -q estimate run.mcap --init init.json
--smooth -o OUT`` of ``--before`` and then of this tree (the order alternates between rounds), each a
fresh process under ``/usr/bin/time``: wall, user and system CPU, peak RSS, the 1-minute load average
at its start; the STATES of the two trees are compared byte for byte.  Figures per hour of record and
the spread between 1 h and 24 h are computed from the round with the least CPU of each.

GNSS (``--gnss DIR``: ``DIR``/after/run.mcap, init.json of ``long_records.py --gnss-hours 24``):
``cdgps estimate`` of each tree in a process that times (process CPU) ``io.states.write_states`` and,
inside it, ``_write_residuals`` and ``_write_state_messages``; STATES compared byte for byte::

    git archive <main> | tar -x -C /tmp/main_tree     # (with the compiled .so files copied in)
    python benchmarks/estimate_per_hour.py --before /tmp/main_tree --workdir /tmp/lr_s7 --hours 1 6 24 \\
        --rounds 3 1 1 --gnss /tmp/gnss24d_long/gnss-24h --out docs/benchmarks/long_records_testbed_sink.json
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CLI = "from cdgps_cli.cli.commands import main; main()"

GNSS_TIMED = r"""
import json, sys, time
from cdgps_cli.io import states as S
spent = {}
def timed(name, fn):
    def w(*a, **k):
        t0 = time.process_time()
        try:
            return fn(*a, **k)
        finally:
            spent[name] = spent.get(name, 0.0) + time.process_time() - t0
    return w
S._write_residuals = timed("write_residuals_cpu_s", S._write_residuals)
S._write_state_messages = timed("write_state_messages_cpu_s", S._write_state_messages)
S.write_states = timed("write_states_cpu_s", S.write_states)
from cdgps_cli.cli.commands import main
sys.argv = ["cdgps", "-q", *sys.argv[1:]]
try:
    main()
except SystemExit as e:
    if e.code:
        raise
with open(OUT, "w") as fh:
    json.dump(spent, fh)
"""


def _run(tree: Path, args: list[str], code: str = CLI) -> dict:
    """One ``cdgps`` process of source tree ``tree`` under /usr/bin/time: wall, user, sys, RSS, load."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    load = os.getloadavg()[0]
    p = subprocess.run(["/usr/bin/time", "-f", "__TIME__ %e %U %S %M", sys.executable, "-c", code, *args],
                       capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    if p.returncode:
        raise SystemExit(f"{tree}: cdgps {' '.join(args)} failed:\n{p.stderr[-2000:]}")
    line = [ln for ln in p.stderr.splitlines() if ln.startswith("__TIME__")][-1].split()
    wall, user, sys_s, rss = float(line[1]), float(line[2]), float(line[3]), int(line[4])
    return {"wall_s": wall, "user_s": user, "sys_s": sys_s, "cpu_s": round(user + sys_s, 2),
            "peak_rss_mib": round(rss / 1024, 1), "load_1min": round(load, 2)}


def _testbed(trees: dict, workdir: Path, hours: list[int], rounds: list[int], scratch: Path) -> dict:
    out: dict = {}
    for h, n in zip(hours, rounds):
        d = workdir / f"{h}h"
        runs: dict = {name: [] for name in trees}
        for r in range(n):
            order = list(trees) if r % 2 == 0 else list(trees)[::-1]
            for name in order:
                st = scratch / f"{name}_{h}h.mcap"
                res = _run(trees[name], ["-q", "estimate", str(d / "run.mcap"), "--init", str(d / "init.json"),
                                         "--smooth", "-o", str(st)])
                runs[name].append(res)
                print(f"{h} h {name}: {res}", flush=True)
        names = list(trees)
        same = filecmp.cmp(scratch / f"{names[0]}_{h}h.mcap", scratch / f"{names[1]}_{h}h.mcap", shallow=False)
        best = {name: min(rs, key=lambda x: x["cpu_s"]) for name, rs in runs.items()}
        out[f"{h}h"] = {"runs": runs, "best": best, "states_identical": same,
                        "cpu_per_hour_s": {name: round(b["cpu_s"] / h, 3) for name, b in best.items()},
                        "sys_per_hour_s": {name: round(b["sys_s"] / h, 3) for name, b in best.items()}}
    if len(hours) > 1:
        lo, hi = f"{min(hours)}h", f"{max(hours)}h"
        out["growth_per_hour"] = {name: round(out[hi]["cpu_per_hour_s"][name] / out[lo]["cpu_per_hour_s"][name] - 1, 3)
                                  for name in trees}
    return out


def _gnss(trees: dict, d: Path, rounds: int, scratch: Path) -> dict:
    runs: dict = {name: [] for name in trees}
    for r in range(rounds):
        for name in (list(trees) if r % 2 == 0 else list(trees)[::-1]):
            st, timing = scratch / f"{name}_gnss.mcap", scratch / f"{name}_gnss.json"
            code = GNSS_TIMED.replace("OUT", repr(str(timing)))
            res = _run(trees[name], ["estimate", str(d / "after" / "run.mcap"), "--init", str(d / "after" / "init.json"),
                                     "-o", str(st)], code=code)
            res.update({k: round(v, 3) for k, v in json.loads(timing.read_text()).items()})
            runs[name].append(res)
            print(f"gnss {name}: {res}", flush=True)
    names = list(trees)
    same = filecmp.cmp(scratch / f"{names[0]}_gnss.mcap", scratch / f"{names[1]}_gnss.mcap", shallow=False)
    best = {name: min(rs, key=lambda x: x["write_states_cpu_s"]) for name, rs in runs.items()}
    return {"runs": runs, "best": best, "states_identical": same}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", type=Path, required=True, help="the source tree to compare with (e.g. main)")
    ap.add_argument("--workdir", type=Path, help="records of long_records.py (<H>h/run.mcap, init.json)")
    ap.add_argument("--hours", type=int, nargs="*", default=[1, 6, 24])
    ap.add_argument("--rounds", type=int, nargs="*", default=[3, 1, 1], help="rounds per record length")
    ap.add_argument("--gnss", type=Path, help="the GNSS pair's directory (after/run.mcap, after/init.json)")
    ap.add_argument("--gnss-rounds", type=int, default=2)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    trees = {"before": a.before.resolve(), "after": ROOT}
    result: dict = {"command": " ".join(["python", "benchmarks/estimate_per_hour.py", *sys.argv[1:]]),
                    "cpus": os.cpu_count(), "python": sys.version.split()[0]}
    with tempfile.TemporaryDirectory(prefix="cdgps-per-hour-") as tmp:
        if a.workdir is not None and a.hours:
            result["testbed_estimate_smooth"] = _testbed(trees, a.workdir, a.hours, a.rounds, Path(tmp))
        if a.gnss is not None:
            result["gnss_24h_estimate"] = _gnss(trees, a.gnss, a.gnss_rounds, Path(tmp))
    a.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({k: v for k, v in result.get("testbed_estimate_smooth", {}).items() if k != "runs"}, indent=1))


if __name__ == "__main__":
    main()
