#!/usr/bin/env python3
"""Where GNSS ``init`` / ``estimate`` spend time and peak memory: the batch tables (``baseline._prepare``,
``_segments``/``_weights``), the static engine (``_run_engine``), and the rest (issue 29; render28).

Runs the stage in this process on a RUN (and INIT for estimate), wrapping those functions: each wrapped call
records its CPU s (process time) and the peak RSS reached while it ran (Linux: ``/proc/self/clear_refs``
resets the high-water mark before the call, ``VmHWM`` read after; the RSS already held when it starts counts
in that peak, given separately as ``rss_before_mib``)::

    python benchmarks/profile_baseline_stages.py init run.mcap --out /tmp/init.json
    python benchmarks/profile_baseline_stages.py estimate run.mcap --init init.json --out /tmp/states.mcap
"""

from __future__ import annotations

import argparse
import functools
import json
import resource
import time
from pathlib import Path


def _rss_mib(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _reset_peak() -> None:
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


RECORD: list[dict] = []
STACK: list[list[float]] = []          # running peak of each wrapped call in progress (nested calls)


def _wrap(mod, name: str) -> None:
    f = getattr(mod, name, None)
    if f is None:
        return

    @functools.wraps(f)
    def g(*a, **k):
        before = _rss_mib("VmRSS")
        if STACK:                          # the caller's peak so far, before the mark is reset
            STACK[-1][0] = max(STACK[-1][0], _rss_mib("VmHWM"))
        _reset_peak()
        STACK.append([before])
        c0, w0 = time.process_time(), time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            peak = max(STACK.pop()[0], _rss_mib("VmHWM"))
            if STACK:
                STACK[-1][0] = max(STACK[-1][0], peak)
            RECORD.append({"function": f"{mod.__name__.split('.')[-1]}.{name}", "depth": len(STACK),
                           "cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0,
                           "rss_before_mib": before, "rss_after_mib": _rss_mib("VmRSS"), "peak_mib": peak})
    setattr(mod, name, g)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stage", choices=("init", "estimate"))
    ap.add_argument("run")
    ap.add_argument("--init")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    from cdgps_cli.estimation import baseline
    from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, read_gnss_run
    from cdgps_cli.pipeline import gnss
    from cdgps_cli.estimation import rtk_multi, static_engine
    for name in ("_prepare", "_segments", "_weights", "_run_engine", "_engine_solution", "_known_solution",
                 "_single_epoch_positions", "_residual_summary"):
        _wrap(baseline, name)
    _wrap(rtk_multi, "receiver_geometry")
    for name in ("paired_sd_rows", "static_filter", "random_walk_float", "static_fix"):
        _wrap(static_engine, name)
    c0, w0 = time.process_time(), time.perf_counter()
    run = read_gnss_run(a.run, columns=SOLVER_COLUMNS)
    read = {"function": "read_gnss_run", "cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0,
            "peak_mib": _rss_mib("VmHWM")}
    if a.stage == "init":
        res = gnss.gnss_init(run)
        Path(a.out).write_text(json.dumps(res))
    else:
        text = Path(a.init).read_text()
        gnss.gnss_estimate(run, json.loads(text), text, a.out)
    total = {"function": "whole (in process)", "cpu_s": time.process_time(), "wall_s": time.perf_counter() - w0,
             "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    print(f"{a.stage}: function, depth, CPU s, wall s, RSS before / after / peak MiB")
    for r in [read, *RECORD, total]:
        print(f"  {r['function']:32s} {r.get('depth', 0)} {r['cpu_s']:7.2f} {r['wall_s']:7.2f} "
              f"{r.get('rss_before_mib', float('nan')):7.0f} {r.get('rss_after_mib', float('nan')):7.0f} "
              f"{r['peak_mib']:7.0f}")


if __name__ == "__main__":
    main()
