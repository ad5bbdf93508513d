"""`cdgps estimate` on a GNSS run with INIT's solution reused, side by side with a tree that re-solves it (issue 28 item 1).

Before: ``estimate`` solved every rover's baseline again (float solution by Gauss-Newton, the
random-walk float filter when the config's displacement model is ``random_walk``, then the fixed
solution's iterations) only to arrive at INIT's fixed solution.  After: when INIT fixed every
integer, the solution is evaluated at INIT's position (design, residuals, covariance) and nothing is
solved again (``estimation/baseline._known_solution``).

For each case the RUN and INIT are made once (by this tree), then ``cdgps estimate`` runs as a whole
process with each tree (``--before PATH``: a checkout of the earlier commit, with its compiled
extensions), alternately, ``--repeats`` times; the medians are compared and the two STATES files
checked array by array (states and single-epoch series bit-identical; covariances to round-off).
Writes ``docs/benchmarks/estimate_reuse.json``.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_estimate_reuse.py --before /tmp/head [--repeats 3]``.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
OUT = ROOT / "docs" / "benchmarks" / "estimate_reuse.json"
GE = SHARED / "rinex-ge"
MS = SHARED / "real-pairs" / "mosaic-static"
GEO = SHARED / "rinex"


def _cases():
    ge_base = "[4157177.06580187, 671230.476590636, 4774767.03105544]"
    ms_base = "[-3817681.1213, 3562839.4311, 3650159.1593]"
    return {
        "Spirent 2 km, G+E L1+L2, static (600 epochs)": (
            [f'nav = ["{GE / "RINEX_GN_Spirent.23N"}", "{GE / "RINEX_EN_Spirent.23L"}"]',
             'signals = ["G:L1", "G:L2", "E:E1", "E:E5a"]'], "static",
            GE / "Base-static_MO_Spirent.obs", ge_base, GE / "Rover-static-2km-east_MO_Spirent.obs", []),
        "mosaic-static, GPS L1, random walk --smooth (301 epochs)": (
            [f'nav = ["{MS / "base.nav"}"]'], "random_walk", MS / "base.obs", ms_base, MS / "rover.obs", ["--smooth"]),
        "GEONET 3040-0759, GPS L1, static (120 epochs)": (
            [f'nav = ["{GEO / "30400920.05n"}"]'], "static", GEO / "30400920.05o", None, GEO / "07590920.05o", []),
    }


def _run(tree: Path, args, check=True):
    env = dict(os.environ, PYTHONPATH=str(tree))
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "cdgps_cli.cli.commands", "-q", *map(str, args)], env=env,
                       capture_output=True, text=True)
    if check and p.returncode != 0:
        raise SystemExit(f"{tree}: {' '.join(map(str, args))}\n{p.stderr[-2000:]}")
    return time.perf_counter() - t0


def _compare(a: Path, b: Path) -> dict:
    sys.path.insert(0, str(ROOT))
    from cdgps_cli.io.states import States  # noqa: PLC0415

    out = {}
    for topic in ("/cdgps/state", "/cdgps/kinematic"):
        sa, sb = States(a, topic=topic, diagnostics=False), States(b, topic=topic, diagnostics=False)
        for k in ("q", "xi", "sigma_q", "P_xi"):
            x, y = getattr(sa, k), getattr(sb, k)
            if x is None:
                continue
            x, y = np.asarray(x, float), np.asarray(y, float)
            out[f"{topic} {k}"] = {"identical": bool(np.array_equal(x, y, equal_nan=True)),
                                   "max_rel_diff": float(np.nanmax(np.abs(x - y)) / max(np.nanmax(np.abs(x)), 1e-300))}
    return out


def main() -> None:
    before = Path(sys.argv[sys.argv.index("--before") + 1])
    repeats = int(sys.argv[sys.argv.index("--repeats") + 1]) if "--repeats" in sys.argv else 3
    res = {"before_tree": str(before), "repeats": repeats, "load_average_1min_at_start": round(os.getloadavg()[0], 2),
           "cases": {}}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for name, (extra, model, base, base_xyz, rover, est_args) in _cases().items():
            cfg = tmp / "run.toml"
            cfg.write_text("\n".join(["[gnss]", 'master = "base"', *extra, "[gnss.displacement]", f'model = "{model}"',
                                      '[gnss.antennas."base"]', f'rinex = "{base}"',
                                      *([f"position_ecef_m = {base_xyz}"] if base_xyz else []),
                                      '[gnss.antennas."rover"]', f'rinex = "{rover}"', ""]))
            _run(ROOT, ["ingest", "--config", cfg, "-o", tmp / "run.mcap"])
            _run(ROOT, ["init", tmp / "run.mcap", "-o", tmp / "init.json"])
            times = {"before": [], "after": []}
            for _ in range(repeats):
                for key, tree in (("before", before), ("after", ROOT)):
                    times[key].append(_run(tree, ["estimate", tmp / "run.mcap", "--init", tmp / "init.json",
                                                  *est_args, "-o", tmp / f"{key}.mcap"]))
            row = {"estimate_s_before": statistics.median(times["before"]), "estimate_s_after": statistics.median(times["after"]),
                   "times_s": times, "identity": _compare(tmp / "before.mcap", tmp / "after.mcap")}
            row["speedup"] = row["estimate_s_before"] / row["estimate_s_after"]
            res["cases"][name] = row
            print(name, json.dumps({k: v for k, v in row.items() if k not in ("times_s", "identity")}),
                  "identical states:", all(v["identical"] for k, v in row["identity"].items() if k.endswith((" q", " xi"))),
                  flush=True)
    res["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    OUT.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
