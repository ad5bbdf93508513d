#!/usr/bin/env python3
"""Peak memory of a command and every process it forks, summed (what the machine must hold).

``/usr/bin/time``'s maximum resident set size is one process's: a command that forks a child to use
a second core (``cdgps_cli.core.beside``) holds the two at once, and their sum is what has to fit.
This samples, every ``--every-s`` seconds, the proportional set size (``Pss`` of
``/proc/PID/smaps_rollup``: pages shared by a parent and its forked child counted once, split between
them) and the resident set size of the command's process and all its descendants, and reports the
largest sums seen::

    python benchmarks/tree_memory.py [--every-s 0.1] -- cdgps -q init run.mcap -o init.json

prints one JSON line on stderr: ``wall_s``, ``exit``, ``peak_tree_pss_mib``, ``peak_tree_rss_mib``,
``max_processes``, ``samples``.  A sample can miss a short peak between two samples; the figures
are a floor.  Linux only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time


def _children(pid: int) -> list[int]:
    kids = []
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                kids += [int(x) for x in f.read().split()]
    except OSError:
        pass
    return kids


def _tree(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo += _children(p)
    return out


def _kib(pid: int) -> tuple[int, int]:
    """(Pss, Rss) of one process, KiB; (0, 0) once it is gone."""
    pss = rss = 0
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                if line.startswith("Pss:"):
                    pss = int(line.split()[1])
                elif line.startswith("Rss:"):
                    rss = int(line.split()[1])
    except OSError:
        pass
    return pss, rss


def measure(cmd: list[str], every_s: float = 0.1, **popen) -> dict:
    """Run ``cmd`` to its end, sampling its process tree; the peaks (MiB) and its wall time (s)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, **popen)
    peak_pss = peak_rss = 0
    most = samples = 0
    while proc.poll() is None:
        pids = _tree(proc.pid)
        sizes = [_kib(p) for p in pids]
        peak_pss = max(peak_pss, sum(s[0] for s in sizes))
        peak_rss = max(peak_rss, sum(s[1] for s in sizes))
        most, samples = max(most, len(pids)), samples + 1
        time.sleep(every_s)
    return {"wall_s": round(time.perf_counter() - t0, 3), "exit": proc.returncode,
            "peak_tree_pss_mib": round(peak_pss / 1024, 1), "peak_tree_rss_mib": round(peak_rss / 1024, 1),
            "max_processes": most, "samples": samples}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--every-s", type=float, default=0.1, help="sampling interval, s [0.1]")
    ap.add_argument("cmd", nargs=argparse.REMAINDER, help="-- the command and its arguments")
    a = ap.parse_args()
    cmd = a.cmd[1:] if a.cmd[:1] == ["--"] else a.cmd
    if not cmd:
        ap.error("no command given (put it after --)")
    res = measure(cmd, a.every_s)
    print(json.dumps(res), file=sys.stderr)
    sys.exit(res["exit"])


if __name__ == "__main__":
    main()
