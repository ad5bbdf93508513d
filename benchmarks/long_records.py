#!/usr/bin/env python3
"""Every stage on long records of the testbed at 10 Hz: peak RSS and wall time per stage (issue 29 item 6).

For each ``--hours`` value simulates the testbed (configs/testbed-1998.toml, seed 1, 2 cm noise,
disturbance scale 1; cached in ``--workdir``/<hours>h/sim) and runs, each as a fresh ``cdgps`` process
under ``/usr/bin/time`` (peak RSS = the process's maximum resident set size)::

    ingest   cdgps ingest sim/receiver.csv sim/gyro.csv --config testbed -o run.mcap
    info     cdgps info run.mcap --json
    init     cdgps init run.mcap --start 0 --duration 60 -o init.json
    estimate cdgps estimate run.mcap --init init.json --smooth -o states.mcap
    spectra  cdgps spectra states.mcap --gyro run.mcap -o spectra
    export   cdgps export states.mcap -o states.csv
    evaluate cdgps evaluate --truth sim --estimate states.mcap --json
    report   cdgps report spectrum states.mcap --gyro run.mcap -o report

``--gnss-hours H [H ...]`` adds the GNSS rows (issue 29: a 24 h static pair at 1 Hz, target < 30 s for
the whole commands): ``cdgps simulate-gnss --duration 3600 H --rate-hz 1 --slips 30 --seed 1`` (cached in
``--workdir``/gnss-<H>h), then ``ingest --config``, ``init`` and ``estimate``, each its own process,
with their sum.  ``--gnss-before TREE`` runs each of those stages with an earlier source tree right
before this tree's (``--gnss-rounds`` times; the round with the least CPU is kept) and checks that
their RUN, init.json and STATES are byte-identical.  Without ``--hours`` the testbed rows already in
``--out`` are kept::

    git archive <before> | tar -x -C /tmp/before
    python benchmarks/long_records.py --hours --gnss-hours 1 24 --gnss-before /tmp/before --gnss-rounds 2 \
        --out docs/benchmarks/long_records.json

Each stage's record: wall s, CPU s (user + system), each per hour of record, peak RSS MiB (``/usr/bin/time``: one
process's), ``peak_tree_pss_mib`` (benchmarks/tree_memory.py: the proportional set sizes of the command and every
process it forks, summed, sampled every 0.1 s — what a command using two cores holds in all) with
``max_processes``, and the 1-minute load average when it
started (the machine may be shared: memory does not depend on the load, time does).  ``--stages``
runs some only (e.g. the cheap ones at 24 h); stages whose inputs are missing are skipped.  Writes
``--out`` (JSON) and prints a markdown table::

    python benchmarks/long_records.py --hours 1 6 --workdir /tmp/long --out docs/benchmarks/long_records.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "testbed-1998.toml"
sys.path.insert(0, str(Path(__file__).resolve().parent))
import tree_memory  # noqa: E402  (benchmarks/tree_memory.py)

CDGPS = [sys.executable, "-c", "from cdgps_cli.cli.commands import main; main()"]
STAGES = ("ingest", "info", "init", "estimate", "spectra", "export", "evaluate", "report")


def _args(stage: str, d: Path) -> tuple[list[str], list[Path]]:
    """The command line of a stage in the record's directory ``d`` and the inputs it needs."""
    sim, run, st = d / "sim", d / "run.mcap", d / "states.mcap"
    table = {
        "ingest": ([str(sim / "receiver.csv"), str(sim / "gyro.csv"), "--config", str(CONFIG), "-o", str(run)],
                   [sim / "receiver.csv"]),
        "info": (["--json", str(run)], [run]),
        "init": ([str(run), "--start", "0", "--duration", "60", "-o", str(d / "init.json")], [run]),
        "estimate": ([str(run), "--init", str(d / "init.json"), "--smooth", "-o", str(st)], [run, d / "init.json"]),
        "spectra": ([str(st), "--gyro", str(run), "-o", str(d / "spectra")], [st, run]),
        "export": ([str(st), "-o", str(d / "states.csv")], [st]),
        "evaluate": (["--truth", str(sim), "--estimate", str(st), "--json"], [st, sim / "truth.csv"]),
        "report": (["spectrum", str(st), "--gyro", str(run), "-o", str(d / "report")], [st, run]),
    }
    args, needs = table[stage]
    return [stage, *args], needs


def _timed(args: list[str], root: Path = ROOT, cwd: Path = ROOT) -> dict:
    """Run ``cdgps -q <args>`` (the package of source tree ``root``, in directory ``cwd``) under
    /usr/bin/time: wall s, CPU s, peak RSS MiB, exit code."""
    env = dict(os.environ, PYTHONPATH=str(root))
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as err:
        tree = tree_memory.measure(["/usr/bin/time", "-f", "__TIME__ %e %M %U %S", *CDGPS, "-q", *args],
                                   stdout=subprocess.DEVNULL, stderr=err, text=True, env=env, cwd=cwd)
        err.seek(0)
        p = subprocess.CompletedProcess(args, tree["exit"], "", err.read())
    wall = time.perf_counter() - t0
    line = [ln for ln in p.stderr.splitlines() if ln.startswith("__TIME__")]
    rss = float(line[-1].split()[2]) / 1024.0 if line else float("nan")
    cpu = sum(float(x) for x in line[-1].split()[3:5]) if line else float("nan")
    # (cpu_s: user + system CPU time, which a loaded machine changes far less than the wall time)
    out = {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "peak_rss_mib": round(rss, 1), "load_1min": round(load, 2),
           "exit": p.returncode, "peak_tree_pss_mib": tree["peak_tree_pss_mib"], "max_processes": tree["max_processes"] - 1}
    if p.returncode:
        out["stderr"] = p.stderr[-600:]
    return out


def simulate(d: Path, hours: float) -> float | None:
    if (d / "sim" / "receiver.csv").exists() and (d / "sim" / "truth.csv").exists():
        return None
    t0 = time.perf_counter()
    r = _timed(["simulate", str(CONFIG), "--duration", str(int(3600 * hours)), "--seed", "1", "--noise-m", "0.02",
                "--disturbance-scale", "1", "-o", str(d / "sim")])
    if r["exit"]:
        raise SystemExit(f"simulate {hours} h failed: {r.get('stderr')}")
    return time.perf_counter() - t0


def run_record(workdir: Path, hours: float, stages) -> dict:
    d = workdir / f"{hours:g}h"
    d.mkdir(parents=True, exist_ok=True)
    rec = {"hours": hours, "simulate_s": simulate(d, hours), "stages": {}}
    for stage in stages:
        args, needs = _args(stage, d)
        if not all(p.exists() for p in needs):
            rec["stages"][stage] = {"skipped": "inputs missing"}
            continue
        r = _timed(args)
        r["s_per_hour"] = round(r["wall_s"] / hours, 2)
        r["cpu_s_per_hour"] = round(r["cpu_s"] / hours, 2)
        rec["stages"][stage] = r
        print(f"  {hours:g} h {stage:9s} {r['wall_s']:8.1f} s {r['peak_rss_mib']:8.1f} MiB (load {r['load_1min']:.1f})"
              + ("" if not r["exit"] else f"  EXIT {r['exit']}"), file=sys.stderr, flush=True)
    rec["run_mcap_mib"] = round((d / "run.mcap").stat().st_size / 2**20, 1) if (d / "run.mcap").exists() else None
    return rec


GNSS_STAGES = ("ingest", "init", "estimate")


def _gnss_args(stage: str, d: Path) -> list[str]:
    """A GNSS stage's command line, run in its output directory (the same relative names for every tree,
    so that their outputs can be compared byte for byte)."""
    return {"ingest": ["ingest", "--config", str(d / "config.toml"), "-o", "run.mcap"],
            "init": ["init", "run.mcap", "-o", "init.json"],
            "estimate": ["estimate", "run.mcap", "--init", "init.json", "-o", "states.mcap"]}[stage]


def simulated_pair(d: Path, hours: float, rate_hz: float) -> Path:
    """``d``, holding ``cdgps simulate-gnss --duration 3600·hours --rate-hz RATE --slips 30 --seed 1`` (made once,
    then reused)."""
    if not (d / "config.toml").exists():
        r = _timed(["simulate-gnss", "--duration", str(int(3600 * hours)), "--rate-hz", f"{rate_hz:g}", "--slips",
                    "30", "--seed", "1", "-o", str(d)])
        if r["exit"]:
            raise SystemExit(f"simulate-gnss {hours} h failed: {r.get('stderr')}")
    return d


def gnss_pair(workdir: Path, hours: float, before: Path | None = None, rounds: int = 1) -> dict:
    """The GNSS row: a simulated static pair at 1 Hz through ingest, init and estimate, each its own
    process.  With ``before`` (a source tree of the earlier code, e.g. ``git archive <commit>``), each
    stage of that tree runs right before the same stage of this one (``rounds`` times, interleaved),
    in its own output directory; the outputs of the two are compared byte for byte."""
    d = simulated_pair(workdir / f"gnss-{hours:g}h", hours, 1.0)
    trees = ([("before", before)] if before else []) + [("after", ROOT)]
    runs = {name: {s: [] for s in GNSS_STAGES} for name, _ in trees}
    for _ in range(rounds):
        for stage in GNSS_STAGES:
            for name, tree in trees:
                out = d / name
                out.mkdir(exist_ok=True)
                r = _timed(_gnss_args(stage, d), root=tree, cwd=out)
                runs[name][stage].append(r)
                print(f"  GNSS {hours:g} h {name:6s} {stage:9s} {r['wall_s']:8.1f} s {r['cpu_s']:7.1f} s CPU "
                      f"{r['peak_rss_mib']:8.1f} MiB ({r['peak_tree_pss_mib']:.1f} MiB PSS over {r['max_processes']} "
                      f"process(es)) (load {r['load_1min']:.1f})"
                      + ("" if not r["exit"] else f"  EXIT {r['exit']}"), file=sys.stderr, flush=True)
    rec = {"hours": hours, "rate_hz": 1.0, "rounds": rounds}
    for name, _ in trees:
        # each stage: the round with the least CPU (the machine is shared; wall and load of that round)
        st = {s: dict(min(v, key=lambda r: r["cpu_s"]), wall_s_rounds=[r["wall_s"] for r in v],
                      cpu_s_rounds=[r["cpu_s"] for r in v]) for s, v in runs[name].items()}
        part = {"stages": st, "whole_commands_s": round(sum(x["wall_s"] for x in st.values()), 2),
                "cpu_s_whole_commands": round(sum(x["cpu_s"] for x in st.values()), 2),
                "peak_rss_mib": max(x["peak_rss_mib"] for x in st.values()),
                "peak_tree_pss_mib": max(x["peak_tree_pss_mib"] for x in st.values())}
        rec.update(part) if name == "after" else rec.update(before=part)
    if before:
        rec["outputs_identical"] = {f: (d / "before" / f).read_bytes() == (d / "after" / f).read_bytes()
                                    for f in ("run.mcap", "init.json", "states.mcap")}
    return rec


def machine() -> str:
    """The machine line of a benchmark's JSON."""
    return f"{platform.machine()}, {os.cpu_count()} cores (shared)"


def write_json(out: Path | None, result: dict) -> None:
    """A benchmark's result to ``out`` (JSON; its folder made), when given."""
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1) + "\n")


def table(records: list[dict]) -> str:
    hours = [r["hours"] for r in records]
    head = "| stage | " + " | ".join(f"{h:g} h: peak RSS MiB / s (s per h)" for h in hours) + " |"
    lines = [head, "|---" * (len(hours) + 1) + "|"]
    for stage in STAGES:
        cells = []
        for r in records:
            s = r["stages"].get(stage)
            cells.append("—" if not s or "skipped" in s else
                         f"{s['peak_rss_mib']:.0f} / {s['wall_s']:.1f} ({s['s_per_hour']:.1f})")
        lines.append(f"| {stage} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, nargs="*", default=[1.0, 6.0])
    ap.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES))
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/cdgps-long-records"))
    ap.add_argument("--out", type=Path)
    ap.add_argument("--gnss-hours", type=float, nargs="*", default=[],
                    help="also the GNSS pair rows (static pairs at 1 Hz of these lengths; the last is 'gnss_pair')")
    ap.add_argument("--gnss-before", type=Path, help="a source tree of the earlier code: its GNSS stages run "
                    "interleaved with this tree's, outputs compared (e.g. git archive <commit> | tar -x -C DIR)")
    ap.add_argument("--gnss-rounds", type=int, default=1)
    a = ap.parse_args()
    records = []
    # with no --hours, the testbed rows already in --out are kept (a GNSS-only run updates only its rows)
    old = json.loads(a.out.read_text()) if a.out and a.out.exists() and not a.hours else {}
    gnss = [gnss_pair(a.workdir, h, a.gnss_before, a.gnss_rounds) for h in a.gnss_hours]
    for h in [None, *a.hours]:                 # (None: the GNSS rows alone are written first)
        if h is not None:
            records.append(run_record(a.workdir, h, a.stages))
        result = {"config": "configs/testbed-1998.toml (10 Hz), seed 1, 2 cm noise, disturbance scale 1",
                  "machine": machine(),
                  "python": platform.python_version(), "records": records,
                  "note": "peak RSS: /usr/bin/time maximum resident set size of each cdgps process; load_1min: "
                          "the 1-minute load average when the stage started (times depend on it)"}
        result = {**old, **result, "records": old.get("records", records) if not a.hours else records}
        if gnss:
            result.update(gnss_pair=gnss[-1], gnss_pairs=gnss)
        write_json(a.out, result)
    print(table(records))


if __name__ == "__main__":
    main()
