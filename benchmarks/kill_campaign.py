#!/usr/bin/env python3
"""Kill campaign (issue 12 item 4): every multi-file command killed at random moments over an
earlier output folder; the folder is then a complete old set, a complete new set, or mixed.

For each command (simulate, simulate-gnss, simulate-gnss-structure, spectra, report static,
report spectrum) the script builds the *old* set (one run into a folder) and the *new* set (the
same command with other options into a fresh folder), timing the new run.  Then, for each of
SIGTERM, SIGINT and SIGKILL and ``--cases`` moments, it copies the old folder, starts the new run
over it as a subprocess of the installed ``cdgps`` (``python -m cdgps_cli.cli.commands``), sends the signal
after the chosen delay and classifies what is left:

* ``old`` / ``new``: the visible files are byte for byte the old / the new set;
* ``mixed``: anything else (files of both, a set with a file missing);
* ``leftover``: a hidden entry (``.*``: staging or commit folder, ``.x.tmp<pid>``) in the output
  folder or its parent;
* ``finished``: the run ended before the signal (the delay was past its end);
* after a SIGKILL that left something, the same command is run once more into another copy-free
  rerun and ``cleaned`` counts how often no hidden entry was left afterwards (stale temporaries of
  dead processes are removed by the next write).

Moments, from a seeded generator (``--seed``): half at a uniform delay over 0-95 % of the timed
run (start-up, computation, writing), half at a uniform delay within the writing phase (from the
moment a hidden temporary appears, polled every 2 ms, over the writing time of the timed run);
``--source DIR`` kills the
cdgps_cli found in DIR instead (``git archive`` of an older commit, for the before/after counts)::

    python benchmarks/kill_campaign.py                     # 6 commands × 3 signals × 8 cases, ≈ 10 min
    python benchmarks/kill_campaign.py --cases 4 --only simulate,spectra
    python benchmarks/kill_campaign.py --json docs/benchmarks/kill_campaign.json
    git archive 29c1440 cdgps_cli | tar -x -C /tmp/before && python benchmarks/kill_campaign.py --source /tmp/before

Counts go in docs/hardening.md ("Output sets").
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
TOWER = ROOT / "configs" / "gnss-tower.toml"
SIGNALS = {"SIGTERM": signal.SIGTERM, "SIGINT": signal.SIGINT, "SIGKILL": signal.SIGKILL}


def _default_sigint() -> None:
    """In the child: SIGINT back to its default action (a benchmark started in the background by a
    shell inherits SIGINT ignored, and so would every cdgps it starts)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


#: how each cdgps is started; PYTHONPATH: where the cdgps_cli that is killed comes from (``--source``)
RUN = {"env": dict(os.environ, PYTHONPATH=str(ROOT)), "cwd": "/", "preexec_fn": _default_sigint}


def cdgps(*args, check=True, **kw):
    cmd = [sys.executable, "-m", "cdgps_cli.cli.commands", "-q", *map(str, args)]
    p = subprocess.run(cmd, capture_output=True, text=True, **RUN, **kw)
    if check and p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {p.stderr}")
    return p


def snapshot(d: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(d.iterdir())
            if p.is_file() and not p.name.startswith(".")}


def hidden(d: Path) -> list[str]:
    found = [p.name for p in d.iterdir() if p.name.startswith(".")] if d.exists() else []
    return found + [p.name for p in d.parent.iterdir() if p.name.startswith(f".{d.name}")]


def build_states(work: Path) -> Path:
    """A 120 s testbed run estimated by the CLI: STATES.mcap and RUN.mcap for spectra and reports."""
    sim = work / "base-sim"
    cdgps("simulate", TESTBED, "--duration", "120", "--seed", "7", "-o", sim)
    cdgps("ingest", sim / "receiver.csv", sim / "gyro.csv", "--config", TESTBED, "-o", work / "run.mcap")
    cdgps("init", work / "run.mcap", "-o", work / "init.json")
    cdgps("estimate", work / "run.mcap", "--init", work / "init.json", "-o", work / "states.mcap")
    return work


def commands(work: Path) -> dict:
    """name → (old arguments, new arguments); the output folder is appended as ``-o DIR``."""
    st, run = work / "states.mcap", work / "run.mcap"
    date = ("--date", "2026-01-01")
    return {
        "simulate": (["simulate", TESTBED, "--duration", "60", "--seed", "1"],
                     ["simulate", TESTBED, "--duration", "60", "--seed", "3"]),
        "simulate-gnss": (["simulate-gnss", "--duration", "900", "--seed", "1"],
                          ["simulate-gnss", "--duration", "900", "--seed", "3"]),
        "simulate-gnss-structure": (["simulate-gnss-structure", TOWER, "--duration", "120", "--seed", "1"],
                                    ["simulate-gnss-structure", TOWER, "--duration", "120", "--seed", "3"]),
        "spectra": (["spectra", st, "--gyro", run, "--pad", "2"], ["spectra", st, "--gyro", run]),
        "report static": (["report", "static", st, "--angle", "q6+q10", "--start", "60", "--end", "110",
                           "--survey-deg", "-1.4", *date],
                          ["report", "static", st, "--angle", "q6+q10", "--start", "60", "--end", "110",
                           "--survey-deg", "-1.0", *date]),
        "report spectrum": (["report", "spectrum", st, "--gyro", run, "--pad", "2", *date],
                            ["report", "spectrum", st, "--gyro", run, *date]),
    }


def wait_for_writing(p: subprocess.Popen, out: Path, limit_s: float = 120.0) -> float | None:
    """Poll (2 ms) until a hidden entry appears in ``out`` or beside it: the run started writing.
    Returns the time it took from now, or None if the process ended first."""
    t0 = time.monotonic()
    while p.poll() is None and time.monotonic() - t0 < limit_s:
        if hidden(out):
            return time.monotonic() - t0
        time.sleep(0.002)
    return None


def timed_run(args_new, out: Path) -> tuple[float, float]:
    """(whole run, writing phase) of one uninterrupted run, s."""
    t0 = time.monotonic()
    p = subprocess.Popen([sys.executable, "-m", "cdgps_cli.cli.commands", "-q", *map(str, args_new), "-o", str(out)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, **RUN)
    start = wait_for_writing(p, out)
    p.wait()
    total = time.monotonic() - t0
    if p.returncode != 0:
        raise SystemExit(f"{args_new} failed")
    return total, (total - start) if start is not None else 0.0


def one_case(args_new, old_dir: Path, work: Path, sig: int, moment: tuple, sets: dict) -> dict:
    """Kill one run over a copy of the old folder; ``moment`` = ("start", s after the start) or
    ("writing", s after the run began writing)."""
    out = work / "case" / "out"
    if out.parent.exists():
        shutil.rmtree(out.parent)
    out.parent.mkdir(parents=True)
    shutil.copytree(old_dir, out)
    p = subprocess.Popen([sys.executable, "-m", "cdgps_cli.cli.commands", "-q", *map(str, args_new), "-o", str(out)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, **RUN)
    if moment[0] == "writing":
        wait_for_writing(p, out)
    time.sleep(moment[1])
    finished = p.poll() is not None
    if not finished:
        p.send_signal(sig)
    p.wait()
    snap = snapshot(out) if out.exists() else {}
    state = "old" if snap == sets["old"] else "new" if snap == sets["new"] else "mixed"
    left = hidden(out)
    res = {"state": state, "leftover": bool(left), "finished": finished, "moment": [moment[0], round(moment[1], 4)]}
    if left and sig == signal.SIGKILL:                   # the next write cleans up after the dead one
        cdgps(*args_new, "-o", out)
        res["cleaned"] = not hidden(out) and snapshot(out) == sets["new"]
    if left:
        res["left"] = left
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=8, help="moments per command and signal")
    ap.add_argument("--seed", type=int, default=12)
    ap.add_argument("--only", default="", help="comma-separated command names")
    ap.add_argument("--json", type=Path, default=None, help="write the counts here")
    ap.add_argument("--source", type=Path, default=ROOT, help="folder holding the cdgps_cli to kill (default: this tree)")
    a = ap.parse_args()
    RUN["env"]["PYTHONPATH"] = str(a.source.resolve())
    rng = random.Random(a.seed)
    work = Path(tempfile.mkdtemp(prefix="cdgps-kill-"))
    try:
        build_states(work)
        table = {}
        for name, (old_args, new_args) in commands(work).items():
            if a.only and name not in a.only.split(","):
                continue
            old_dir, new_dir = work / f"{name}-old", work / f"{name}-new"
            cdgps(*old_args, "-o", old_dir)
            run_s, write_s = timed_run(new_args, new_dir)
            sets = {"old": snapshot(old_dir), "new": snapshot(new_dir)}
            assert sets["old"] != sets["new"], name
            for sname, sig in SIGNALS.items():
                counts = {"cases": 0, "old": 0, "new": 0, "mixed": 0, "leftover": 0, "finished": 0,
                          "kill_leftover_cleaned": 0}
                for i in range(a.cases):
                    moment = (("start", rng.uniform(0.0, 0.95) * run_s) if i % 2 == 0
                              else ("writing", rng.uniform(0.0, 1.0) * write_s))
                    r = one_case(new_args, old_dir, work, sig, moment, sets)
                    counts["cases"] += 1
                    counts[r["state"]] += 1
                    counts["leftover"] += r["leftover"]
                    counts["finished"] += r["finished"]
                    counts["kill_leftover_cleaned"] += bool(r.get("cleaned"))
                    if r["state"] == "mixed" or (r["leftover"] and sig != signal.SIGKILL):
                        print(f"  !! {name} {sname}: {r}", flush=True)
                    if r["leftover"] and sig == signal.SIGKILL:
                        print(f"  .. {name} {sname}: {r}", flush=True)
                table[f"{name} {sname}"] = {**counts, "run_s": round(run_s, 2), "writing_s": round(write_s, 3)}
                print(f"{name:<24} {sname:<8} {counts}", flush=True)
        total = {k: sum(v[k] for v in table.values()) for k in ("cases", "old", "new", "mixed", "leftover", "finished")}
        by_sig = {s: {k: sum(v[k] for n, v in table.items() if n.endswith(s)) for k in ("cases", "mixed", "leftover")}
                  for s in SIGNALS}
        print("total", total)
        print("by signal", by_sig)
        if a.json:
            a.json.parent.mkdir(parents=True, exist_ok=True)
            a.json.write_text(json.dumps({"cases_per_signal": a.cases, "seed": a.seed, "commands": table,
                                          "total": total, "by_signal": by_sig}, indent=2) + "\n")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
