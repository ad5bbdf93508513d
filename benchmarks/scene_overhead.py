#!/usr/bin/env python3
"""Bytes and seconds the 3-D scene channel (/cdgps/scene, foxglove.SceneUpdate) adds to STATES.mcap
→ docs/benchmarks/scene_overhead.json (issue 33 item 2; quoted in docs/file-formats.md).

Per case, the command line as a user runs it: simulate → ingest → init → ``estimate`` twice on the
same RUN and INIT, with ``--scene-exaggeration 0`` (no scene: the file as before the channel) and
with the default (``auto``); the STATES sizes and the wall time of each estimate (best of
``--repeats``).  Cases: the demo's testbed free vibration (20 min, smoothed), an hour of it, and the
120 m FE tower of the demo (10 min; its Foxglove rate is 5 Hz, the scene's too).

Example::

    python benchmarks/scene_overhead.py            # ≈ 2–3 min
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CASES = [("testbed free 20 min (demo)", "testbed-1998.toml", 1200, ["--scenario", "free", "--noise-m", "0.02",
                                                                      "--disturbance-scale", "1"], ["--smooth"]),
         ("testbed free 1 h", "testbed-1998.toml", 3600, ["--scenario", "free", "--noise-m", "0.02",
                                                           "--disturbance-scale", "1"], ["--smooth"]),
         ("120 m FE tower 10 min (demo)", "tower-120m-fe.toml", 600, [], [])]


def _cdgps(*args) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    subprocess.run([sys.executable, "-m", "cdgps_cli.cli.commands", "-q", *map(str, args)], check=True, env=env,
                   cwd=ROOT)


def _timed(repeats: int, *args) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        _cdgps(*args)
        best = min(best, time.perf_counter() - t)
    return best


def one_case(tmp: Path, name: str, config: str, duration_s: int, sim_args: list, est_args: list, repeats: int) -> dict:
    cfg = ROOT / "configs" / config
    d = tmp / config.split(".")[0] / str(duration_s)
    _cdgps("simulate", cfg, "--duration", duration_s, "--seed", 7, *sim_args, "-o", d / "sim")
    gyro = [d / "sim" / "gyro.csv"] if (d / "sim" / "gyro.csv").exists() else []
    _cdgps("ingest", d / "sim" / "receiver.csv", *gyro, "--config", cfg, "-o", d / "run.mcap")
    _cdgps("init", d / "run.mcap", "-o", d / "init.json")
    base = ["estimate", d / "run.mcap", "--init", d / "init.json", *est_args]
    t0 = _timed(repeats, *base, "--scene-exaggeration", "0", "-o", d / "none.mcap")
    t1 = _timed(repeats, *base, "-o", d / "scene.mcap")
    s0, s1 = (d / "none.mcap").stat().st_size, (d / "scene.mcap").stat().st_size
    from mcap.reader import make_reader  # noqa: PLC0415

    with open(d / "scene.mcap", "rb") as fh:
        summary = make_reader(fh).get_summary()
    counts = summary.statistics.channel_message_counts
    msgs = {ch.topic: counts.get(cid, 0) for cid, ch in summary.channels.items()}
    meta = next(ch.metadata for ch in summary.channels.values() if ch.topic == "/cdgps/scene")
    return {"case": name, "config": config, "duration_s": duration_s, "states_bytes_without_scene": s0,
            "states_bytes_with_scene": s1, "overhead_bytes": s1 - s0, "overhead_fraction": round((s1 - s0) / s0, 4),
            "scene_messages": msgs.get("/cdgps/scene", 0), "bytes_per_scene_message": round((s1 - s0) / max(msgs.get("/cdgps/scene", 1), 1), 1),
            "exaggeration": meta.get("exaggeration"), "resolution_m": meta.get("resolution_m"),
            "estimate_s_without_scene": round(t0, 3), "estimate_s_with_scene": round(t1, 3)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("-o", "--output", default=str(ROOT / "docs" / "benchmarks" / "scene_overhead.json"))
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        rows = [one_case(Path(tmp), *c, a.repeats) for c in CASES]
    out = {"benchmark": "benchmarks/scene_overhead.py", "date": datetime.datetime.now(datetime.timezone.utc).isoformat(
        timespec="seconds"), "machine": platform.platform(), "python": platform.python_version(),
        "load_1min": os.getloadavg()[0], "cases": rows}
    Path(a.output).write_text(json.dumps(out, indent=1) + "\n")
    for r in rows:
        print(f"{r['case']}: {r['states_bytes_without_scene'] / 2**20:.2f} → {r['states_bytes_with_scene'] / 2**20:.2f} MiB "
              f"(+{100 * r['overhead_fraction']:.1f} %, {r['scene_messages']} messages, x{r['exaggeration']}); estimate "
              f"{r['estimate_s_without_scene']:.2f} → {r['estimate_s_with_scene']:.2f} s")


if __name__ == "__main__":
    main()
