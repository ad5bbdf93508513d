"""Integer fixing with many ambiguity segments (issue 14 item 1): LAMBDA, partial fixing, init.

For each segment count (default 50 / 150 / 500) a base/rover pair shaped like the u-blox one of
the issue is simulated in process (20 min at 1 Hz, the default synthetic constellation, lock
segments from rising/setting satellites plus random LLI-flagged slips, ``cdgps simulate-gnss
--slips``), written as RINEX, ingested and initialized exactly as ``cdgps ingest`` + ``cdgps init``
do (``t_init_s``), and once more with a ratio threshold nothing passes, so that partial fixing
searches every nested subset (``t_init_partial_all_subsets_s``).  The float DD ambiguities and
their covariance handed to the integer fixing are captured and then resolved again, timed, by

* ``lambda_search`` + ``ratio_test`` (the full set),
* ``partial_fix`` forced through its nested subsets (ratio threshold 1.5 × the full set's, so
  that it fails and a few ambiguities are dropped: the path that kept the real 150-segment init
  from finishing), and with a threshold nothing passes (every nested subset searched: the upper
  bound of its cost), and
* the pre-issue-14 pure-Python implementation (``tests/estimation/lambda_legacy.py``) on the same
  problems, for the speed-up and to check the answers agree (skipped where it would take minutes:
  ``--legacy-max``).

Usage::

    python benchmarks/bench_lambda.py [--segments 50,150,500] [--json docs/benchmarks/lambda.json]

Single-threaded numpy is recommended for stable timings (``OMP_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "estimation"))

from cdgps_cli.estimation import ambiguity  # noqa: E402
from cdgps_cli.estimation import baseline
from cdgps_cli.config.structure import load_gnss_config  # noqa: E402
from cdgps_cli.pipeline.gnss import gnss_init  # noqa: E402
from cdgps_cli.io.gnss_run import read_gnss_run  # noqa: E402
from cdgps_cli.pipeline.gnss_ingest import ingest_gnss  # noqa: E402
from cdgps_cli.sim.gnss import simulate_gnss_pair  # noqa: E402

#: lock segments the default 20-minute scenario has without slips (rising/setting satellites),
#: measured: the slips asked for are the target minus these
BASE_SEGMENTS_HINT = 11


def simulated_init(out_dir: Path, n_segments: int, seed: int, duration_s: float) -> dict:
    """Simulate, ingest and init one pair with about ``n_segments`` ambiguity segments; return
    timings, the INIT summary and the captured float problem (a, Q) of the integer fixing."""
    captured = {}
    real_resolve = baseline.resolve

    def spy(a, Q, *args, **kw):
        captured["a"], captured["Q"] = np.array(a, dtype=float), np.array(Q, dtype=float)
        t0 = time.perf_counter()
        out = real_resolve(a, Q, *args, **kw)
        captured["t_fixing_s"] = time.perf_counter() - t0
        return out

    slips = max(n_segments - BASE_SEGMENTS_HINT, 0)
    t0 = time.perf_counter()
    simulate_gnss_pair(out_dir, duration_s=duration_s, seed=seed, n_slips=slips)
    t_sim = time.perf_counter() - t0
    cfg = load_gnss_config(out_dir / "config.toml")
    t0 = time.perf_counter()
    ingest_gnss(cfg, out_dir / "run.mcap")
    t_ingest = time.perf_counter() - t0
    baseline.resolve = spy
    try:
        t0 = time.perf_counter()
        run = read_gnss_run(out_dir / "run.mcap")
        res = gnss_init(run)
        t_init = time.perf_counter() - t0
    finally:
        baseline.resolve = real_resolve
    # the same init with a ratio threshold nothing passes: partial fixing searches every subset
    t0 = time.perf_counter()
    res_p = gnss_init(run, options={"ratio_threshold": 1e9})
    t_init_p = time.perf_counter() - t0
    rov_p = next(iter(res_p["rovers"].values()))
    rov = next(iter(res["rovers"].values()))
    return {"t_simulate_s": t_sim, "t_ingest_s": t_ingest, "t_init_s": t_init,
            "t_init_partial_all_subsets_s": t_init_p, "init_partial_solution": rov_p["solution"],
            "n_segments": rov["n_segments"],
            "n_estimated": rov["n_estimated"], "n_fixed": rov["n_fixed"], "ratio": rov["ratio"],
            "solution": rov["solution"], "t_fixing_in_init_s": captured.get("t_fixing_s"),
            "a": captured.get("a"), "Q": captured.get("Q")}


def timed(fn, repeat: int = 3):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--segments", default="50,150,500")
    ap.add_argument("--seed", type=int, default=14)
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--legacy-max", type=int, default=150,
                    help="run the pre-issue-14 implementation only up to this many ambiguities")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    import lambda_legacy  # tests/estimation/lambda_legacy.py

    rows = []
    for n_seg in [int(x) for x in args.segments.split(",")]:
        with tempfile.TemporaryDirectory() as tmp:
            r = simulated_init(Path(tmp), n_seg, args.seed, args.duration)
        a, Q = r.pop("a"), r.pop("Q")
        n = a.size
        t_full, (c_full, s_full) = timed(lambda: ambiguity.lambda_search(a, Q))
        ok, ratio = ambiguity.ratio_test(s_full)
        # force the nested subsets: a threshold the full set fails
        thr = ratio * 1.5 if np.isfinite(ratio) else 3.0
        t_part, pf = timed(lambda: ambiguity.partial_fix(a, Q, threshold=thr), repeat=1)
        row = dict(r, n_ambiguities=int(n), t_lambda_s=t_full, full_ratio=ratio, forced_threshold=thr,
                   t_partial_forced_s=t_part, partial_n_fixed=pf["n_fixed"], partial_ratio=pf["ratio"],
                   partial_searches=pf["subsets_searched"], partial_limited=pf["search_limited"])
        # every nested subset searched (nothing passes): the upper bound of partial fixing's cost
        t_worst, pw = timed(lambda: ambiguity.partial_fix(a, Q, threshold=1e9), repeat=1)
        row.update(t_partial_all_subsets_s=t_worst, all_subsets_searched=pw["subsets_searched"])
        if n <= args.legacy_max:
            t_old, (c_old, s_old) = timed(lambda: lambda_legacy.lambda_search(a, Q), repeat=1)
            t_old_p, pf_old = timed(lambda: lambda_legacy.partial_fix(a, Q, threshold=thr), repeat=1)
            t_old_w, _ = timed(lambda: lambda_legacy.partial_fix(a, Q, threshold=1e9), repeat=1)
            row.update(t_lambda_legacy_s=t_old, t_partial_forced_legacy_s=t_old_p, t_partial_all_subsets_legacy_s=t_old_w,
                       same_full=bool(np.array_equal(c_old, c_full) and np.allclose(s_old, s_full, rtol=1e-9)),
                       same_partial=bool(np.array_equal(pf_old["fixed_mask"], pf["fixed_mask"])
                                         and np.array_equal(pf_old["integers"], pf["integers"])))
        rows.append(row)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()
                          if k != "solution"}), flush=True)
    # growth exponent between consecutive sizes (t ∝ n^p)
    for key in ("t_init_s", "t_init_partial_all_subsets_s", "t_fixing_in_init_s", "t_lambda_s", "t_partial_forced_s", "t_partial_all_subsets_s"):
        for r0, r1 in zip(rows, rows[1:]):
            p = np.log(r1[key] / r0[key]) / np.log(r1["n_ambiguities"] / r0["n_ambiguities"])
            print(f"{key}: {r0['n_ambiguities']} → {r1['n_ambiguities']} ambiguities: exponent {p:.2f}")
    if args.json:
        out = {"machine": platform.platform(), "python": platform.python_version(), "numpy": np.__version__,
               "seed": args.seed, "duration_s": args.duration, "rows": rows}
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
