"""Peak memory of the static engine's filter (``static_engine.static_filter``) on the golden cases, this tree
against an earlier one (issue 28 item 1).

Before: the filter's ``driver.drive`` used the default sink, which keeps every epoch's state and covariance
(x (N, n), P (N, n, n), zero-filled up front: 3.3 GB on a 24 h 1 Hz pair with 66 arcs) although only the
last is used.  After: a sink that keeps only the last state.  For each case and tree a fresh process builds
the engine's SD rows, then measures ``static_filter`` alone with ``tracemalloc`` (peak bytes allocated
through Python during the call) and saves x and P; the two trees' x and P must be bit for bit equal.
Writes ``docs/benchmarks/static_engine_memory.json``.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/static_engine_memory.py --before /tmp/main_a28``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "static_engine_memory.json"
CASES = ("spirent_ge_dual_init", "mosaic_gps_glonass_init", "geonet_gps_l1l2_init")

_CHILD = r"""
import sys, tracemalloc, numpy as np
tree, case, out = sys.argv[1:4]
sys.path.insert(0, tree)
sys.path.insert(1, {root!r})
from tests.estimation.test_static_engine import _geometries
from cdgps_cli.estimation import static_engine as se
from cdgps_cli.measurement.dd_signals import paired_sd_rows
from cdgps_cli.measurement.epoch_pairing import pair_epochs
g, mx, rx = _geometries(case)
opt = se._static_options({{}})
pairs = pair_epochs(g[1]["time_gps_s"].to_numpy(), g[0]["time_gps_s"].to_numpy(), sync_tol_s=opt["sync_tol_s"],
                    max_age_s=opt["max_age_s"])
rows = paired_sd_rows(g[0], g[1], pairs, opt)
tracemalloc.start()
x, P, cols = se.static_filter(rows, pairs.rover_time_s, mx, rx)
peak = tracemalloc.get_traced_memory()[1]
np.save(out, np.r_[x, P.ravel()])
print(pairs.rover_time_s.size, x.size, peak)
"""


def _measure(tree: Path, case: str, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    r = subprocess.run([sys.executable, "-c", _CHILD.format(root=str(ROOT)), str(tree), case, str(out)], env=env,
                       capture_output=True, text=True, check=True)
    n_ep, n_state, peak = (int(v) for v in r.stdout.split())
    return {"epochs": n_ep, "states": n_state, "peak_mib": round(peak / 2**20, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True, help="a source tree of the earlier code")
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            before = _measure(a.before, case, Path(tmp) / "before.npy")
            after = _measure(ROOT, case, Path(tmp) / "after.npy")
            same = bool(np.array_equal(np.load(Path(tmp) / "before.npy"), np.load(Path(tmp) / "after.npy")))
            rows.append({"case": case, "epochs": after["epochs"], "states": after["states"],
                         "peak_mib_before": before["peak_mib"], "peak_mib_after": after["peak_mib"],
                         "x_P_identical": same})
            print(json.dumps(rows[-1]))
            if not same:
                raise SystemExit(f"{case}: the filter's x, P differ between the trees")
    a.out.write_text(json.dumps({"benchmark": "static_engine_memory", "before": str(a.before), "cases": rows},
                                indent=1) + "\n")


if __name__ == "__main__":
    main()
