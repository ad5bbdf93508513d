"""`solve_rtk`'s own cost per epoch (CPU time, files already read), this source tree against another.

Issue 28 item 1 moved rtk's filter onto the engine's driver; this measures that the solver did not
get slower per epoch.  Each case (the real mosaic pair GPS L1, the Spirent GPS+Galileo L1+L2 set,
the geonet-car G+E L1 kinematic run) reads and prepares its files once per process, then times
``solve_rtk`` (process CPU time, one BLAS thread) ``--reps`` times.  With ``--compare TREE`` the
same child runs with ``PYTHONPATH=TREE`` (e.g. an export of the commit before the change),
interleaved with this tree's child ``--rounds`` times; per side the minimum and the median over all
runs are written, with the load average, to ``docs/benchmarks/rtk_solver.json``.

    python benchmarks/bench_rtk_solver.py --compare /tmp/base_tree [--rounds 3] [--reps 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
OUT = ROOT / "docs" / "benchmarks" / "rtk_solver.json"

_CAR = SHARED / "real-pairs" / "geonet-car"
_GE = SHARED / "rinex-ge"
_MOS = SHARED / "real-pairs" / "mosaic-static"
CASES = {
    "mosaic-static GPS L1": (_MOS / "base.obs", _MOS / "rover.obs", [_MOS / "base.nav"],
                             [-3817681.1213, 3562839.4311, 3650159.1593], ["G:L1"]),
    "Spirent 2 km static G+E L1+L2": (_GE / "Base-static_MO_Spirent.obs", _GE / "Rover-static-2km-east_MO_Spirent.obs",
                                      [_GE / "RINEX_GN_Spirent.23N", _GE / "RINEX_EN_Spirent.23L"],
                                      [4157177.06580187, 671230.476590636, 4774767.03105544], ["G:L1", "G:L2", "E:E1", "E:E5a"]),
    "geonet-car G+E L1": (_CAR / "3034265G.21O", _CAR / "SEPT265G.21O", [_CAR / "SEPT2650.21P"],
                          [-3959400.631, 3385704.533, 3667523.111], ["G:L1", "E:E1"]),
}


def child(case: str, reps: int) -> dict:
    """In this process's source tree: read the case through `rtk_from_files` once per rep with
    ``solve_rtk`` timed (CPU); its ms per epoch and the fixed epochs."""
    import cdgps_cli.pipeline.gnss_multi as gm

    base, rover, nav, xyz, sig = CASES[case]
    solve, runs = gm.solve_rtk, []

    def timed(*a, **k):
        t = time.process_time()
        res = solve(*a, **k)
        runs.append(1e3 * (time.process_time() - t) / res["time_gps_s"].size)
        return res

    gm.solve_rtk = timed
    out = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench_rtk_solver_{os.getpid()}.csv"
    try:
        for _ in range(reps):
            s = gm.rtk_from_files(base, rover, nav, out, base_xyz_m=xyz, options={"signals": tuple(sig)})
    finally:
        gm.solve_rtk = solve
        out.unlink(missing_ok=True)
    return {"ms_per_epoch": runs, "epochs": s["epochs"], "fixed_epochs": s["fixed_epochs"]}


def _run_child(tree: Path, case: str, reps: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    p = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", case, "--reps", str(reps)],
                       capture_output=True, text=True, env=env, cwd=str(ROOT.parent), timeout=1800)
    if p.returncode != 0:
        raise SystemExit(f"{tree}: {case}: {p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--compare", type=Path, default=None, help="another source tree (PYTHONPATH) to time alike")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(a.child, a.reps)))
        return
    trees = {"this": ROOT, **({"compare": a.compare.resolve()} if a.compare else {})}
    runs = {c: {k: [] for k in trees} for c in CASES}
    facts, load = {c: {} for c in CASES}, [os.getloadavg()[0]]
    for _ in range(a.rounds):
        for case in CASES:
            for name, tree in trees.items():
                r = _run_child(tree, case, a.reps)
                runs[case][name] += r["ms_per_epoch"]
                facts[case][name] = {"epochs": r["epochs"], "fixed_epochs": r["fixed_epochs"]}
                load.append(os.getloadavg()[0])
    res = {"trees": {k: str(v) for k, v in trees.items()}, "rounds": a.rounds, "reps": a.reps,
           "load_average_1min": {"min": min(load), "max": max(load)}, "cases": {}}
    for case in CASES:
        res["cases"][case] = {name: {**facts[case][name], "solver_cpu_ms_per_epoch_min": round(min(v), 3),
                                     "solver_cpu_ms_per_epoch_median": round(statistics.median(v), 3), "runs": len(v)}
                              for name, v in runs[case].items()}
        print(case, json.dumps(res["cases"][case]))
    OUT.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
