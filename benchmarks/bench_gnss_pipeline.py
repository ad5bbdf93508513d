#!/usr/bin/env python3
"""Speed benchmark of the GNSS pipeline on a day of 1 Hz data from two receivers (issue 6, point 8).

1. ``cdgps simulate-gnss --duration 86400 --rate-hz 1 --slips 30`` writes the pair as RINEX 3 files
   (master + rover 3.3 km apart, synthetic 36-satellite constellation, receiver clocks with
   millisecond-stepped tags, random LLI-flagged slips) with the truth (not timed);
2. ``cdgps ingest`` → RUN.mcap, ``cdgps init`` → INIT.json, ``cdgps estimate`` → STATES.mcap, each
   run as its own process and timed by the wall clock (interpreter start included), with its
   peak memory; target: ingest + init + estimate < 120 s on the 2-core development machine;
3. checks: every integer against the simulator's truth, the displacement against the truth
   (``cdgps evaluate``); the load average before and after is recorded (other jobs share the
   machine, so the times are upper bounds for an idle one).

Writes ``docs/benchmarks/gnss_pipeline.json`` (``--out``); the files go to ``build/bench_gnss``
(``--work``).  ``python benchmarks/bench_gnss_pipeline.py [--hours 24] [--rate-hz 1]
[--slips 30] [--model static|random_walk] [--seed 1]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from cdgps_cli.pipeline.gnss import rover_segments  # noqa: E402
CDGPS = [sys.executable, "-m", "cdgps_cli.cli.commands"]


def peak_mib_of(args: list, cwd: Path) -> tuple[float, float, str]:
    """Run and measure wall time and peak RSS of the child (resource usage of this one process)."""
    t = time.perf_counter()
    p = subprocess.Popen(CDGPS + ["-q", *map(str, args)], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)))
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    out = p.stdout.read().decode()
    err = p.stderr.read().decode()
    if os.waitstatus_to_exitcode(status) != 0:
        sys.stderr.write(err)
        raise SystemExit(f"cdgps {args[0]} failed")
    return wall, ru.ru_maxrss / 1024.0, out


def check_integers(init: dict, truth: dict, rover: str, master: str) -> int:
    """Wrong integers of INIT against the simulator's ambiguities (SD segment − its set's pivot)."""
    amb = truth["ambiguities"]

    def integer(rx, sat, t):
        rows = [a for a in amb if a["receiver"] == rx and a["sat"] == sat and a["from_gps_s"] <= t + 1e-6]
        lock = max((a for a in rows if a["kind"] == "lock"), key=lambda a: a["from_gps_s"])
        return lock["cycles"] + sum(a["cycles"] for a in rows if a["kind"] == "slip" and a["from_gps_s"] > lock["from_gps_s"] - 1e-6)

    def sd(sat, t):
        return integer(rover, sat, t) - integer(master, sat, t)

    segs = rover_segments(init, rover)  # INIT v2 keeps them in "biases"
    pivots = [s for s in segs if s["pivot"]]
    wrong = 0
    for s in segs:
        if s["pivot"] or not s["fixed"]:
            continue
        # the pivot of its connected set: the one whose difference is an integer (one set here)
        p = pivots[0]
        wrong += int(s["integer"] != sd(s["sat"], s["first_gps_s"]) - sd(p["sat"], p["first_gps_s"]))
    return wrong


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--rate-hz", type=float, default=1.0)
    ap.add_argument("--slips", type=int, default=30)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--model", choices=["static", "random_walk"], default="static")
    ap.add_argument("--work", type=Path, default=ROOT / "build" / "bench_gnss")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "gnss_pipeline.json")
    a = ap.parse_args()
    w = a.work
    if w.exists():
        shutil.rmtree(w)
    w.mkdir(parents=True)
    sim_args = ["simulate-gnss", "--duration", a.hours * 3600.0, "--rate-hz", a.rate_hz, "--slips", a.slips,
                "--seed", a.seed, "-o", w]
    if a.model == "random_walk":
        sim_args += ["--random-walk", "0.0005"]
    load0 = os.getloadavg()
    t_sim, m_sim, _ = peak_mib_of(sim_args, ROOT)
    print(f"simulate {a.hours:g} h at {a.rate_hz:g} Hz (RINEX written): {t_sim:.1f} s, {m_sim:.0f} MiB")
    stages = {}
    load_before = os.getloadavg()
    for name, args in (("ingest", ["ingest", "--config", w / "config.toml", "-o", w / "run.mcap"]),
                       ("init", ["init", w / "run.mcap", "-o", w / "init.json"]),
                       ("estimate", ["estimate", w / "run.mcap", "--init", w / "init.json", "-o", w / "states.mcap"]
                        + (["--smooth"] if a.model == "random_walk" else []))):
        t, m, _ = peak_mib_of(args, ROOT)
        stages[name] = {"wall_s": round(t, 2), "peak_rss_mib": round(m)}
        print(f"{name:>9}: {t:6.1f} s, {m:5.0f} MiB")
    load_after = os.getloadavg()
    total = sum(s["wall_s"] for s in stages.values())
    init = json.loads((w / "init.json").read_text())
    truth = json.loads((w / "truth.json").read_text())
    rover, master = truth["rover"], truth["master"]
    rov = init["rovers"][rover]
    wrong = check_integers(init, truth, rover, master)
    _, _, ev = peak_mib_of(["evaluate", "--truth", w, "--estimate", w / "states.mcap", "--json"], ROOT)
    ev = json.loads(ev)
    sizes = {f: (w / f).stat().st_size for f in ("base.rnx", "rover.rnx", "run.mcap", "states.mcap")}
    out = {
        "data": {"hours": a.hours, "rate_hz": a.rate_hz, "epochs": rov["epochs"]["n_epochs_common"],
                 "satellites": len(rov["satellites"]), "dd_phases": rov["residuals"]["n_dd_phase"],
                 "slips_requested": a.slips, "slips_simulated": sum(1 for x in truth["ambiguities"] if x["kind"] == "slip"),
                 "displacement_model": a.model, "seed": a.seed, "file_bytes": sizes},
        "simulate_s": round(t_sim, 2),
        "stages": stages,
        "ingest_init_estimate_s": round(total, 2),
        "target_s": 120,
        "result": {"solution": rov["solution"], "n_fixed": rov["n_fixed"], "n_estimated": rov["n_estimated"],
                   "wrong_integers": wrong, "ratio": rov["ratio"], "reference_changes": rov["epochs"]["n_reference_changes"],
                   "rms_error_m": ev["rms_error"], "within_3sigma_fraction": ev["within_3sigma_fraction"]},
        "load_average": {"before_simulation": [round(x, 2) for x in load0], "before_ingest": [round(x, 2) for x in load_before],
                         "after_estimate": [round(x, 2) for x in load_after]},
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform()},
    }
    print(f"ingest + init + estimate: {total:.1f} s (target < 120 s); {rov['n_fixed']}/{rov['n_estimated']} integers "
          f"fixed, {wrong} wrong; RMS error (mm) " + ", ".join(f"{k} {v * 1e3:.3f}" for k, v in ev["rms_error"].items())
          + f"; load average {load_before[0]:.2f} → {load_after[0]:.2f} on {os.cpu_count()} CPUs")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {a.out}")
    return 0 if wrong == 0 and total < 120 else 1


if __name__ == "__main__":
    sys.exit(main())
