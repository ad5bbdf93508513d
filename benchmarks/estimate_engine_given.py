#!/usr/bin/env python3
"""Peak RSS and CPU of ``cdgps estimate`` on an INIT the static engine conditions (``baseline._engine_given``).

A fully fixed INIT is evaluated at its position; an engine INIT that leaves a segment float (partially fixed,
GLONASS float or glonass_fix) gets the engine's float solution conditioned on its integers, so the engine's
receiver geometry is built in ``estimate`` too.  This measures that case on a long simulated pair:
``cdgps simulate-gnss --duration 3600 H --rate-hz 1 --slips 30 --seed 1`` (cached in ``--workdir``), ``ingest``,
``init`` (this tree), then one non-pivot integer withdrawn from INIT (as
``tests/pipeline/test_estimate_from_init.py`` does), and ``estimate`` of that INIT by the ``--before`` tree and this
one, each a fresh process under ``/usr/bin/time`` (long_records.py's ``_timed``), ``--rounds`` interleaved rounds
(the order alternating), STATES checked byte-identical::

    git archive <before> | tar -x -C /tmp/before     # with the .so files copied in
    python benchmarks/estimate_engine_given.py --before /tmp/before --hours 24 --rounds 2 \\
        --out docs/benchmarks/estimate_engine_given.json
"""

from __future__ import annotations

import argparse
import filecmp
import json
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from long_records import ROOT, _timed  # noqa: E402


def _prepare(d: Path, hours: float) -> Path:
    """The pair, its RUN and INIT (cached), and INIT with one integer withdrawn: that INIT's path."""
    d.mkdir(parents=True, exist_ok=True)
    steps = [("simulate-gnss", d / "config.toml", ["simulate-gnss", "--duration", str(int(3600 * hours)), "--rate-hz",
                                                   "1", "--slips", "30", "--seed", "1", "-o", str(d)]),
             ("ingest", d / "run.mcap", ["ingest", "--config", str(d / "config.toml"), "-o", str(d / "run.mcap")]),
             ("init", d / "init.json", ["init", str(d / "run.mcap"), "-o", str(d / "init.json")])]
    for name, made, args in steps:
        if not made.exists():
            r = _timed(args, cwd=d)          # not a source tree's directory: python -c puts the cwd first
            if r["exit"]:
                raise SystemExit(f"{name} failed: {r.get('stderr')}")
    init = json.loads((d / "init.json").read_text())
    b = next(b for b in init["biases"] if not b["pivot"] and b.get("fixed"))
    b.update(fixed=False, integer_cycles=None)
    out = d / "init_partial.json"
    out.write_text(json.dumps(init))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", type=Path, required=True, help="source tree to compare with (its cdgps_cli)")
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/estimate_engine_given"))
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    d = a.workdir / f"gnss-{a.hours:g}h"
    init = _prepare(d, a.hours)
    trees = {"before": a.before.resolve(), "after": ROOT}
    rounds = []
    for k in range(a.rounds):
        order = ("before", "after") if k % 2 == 0 else ("after", "before")
        rec = {}
        for tag in order:
            rec[tag] = _timed(["estimate", str(d / "run.mcap"), "--init", str(init), "-o", str(d / f"states_{tag}.mcap")],
                              root=trees[tag], cwd=d)
            if rec[tag]["exit"]:
                raise SystemExit(f"estimate ({tag}) failed: {rec[tag].get('stderr')}")
        rec["states_identical"] = filecmp.cmp(d / "states_before.mcap", d / "states_after.mcap", shallow=False)
        rounds.append(rec)
        print(f"round {k + 1}: " + ", ".join(f"{t} {rec[t]['peak_rss_mib']:.0f} MiB {rec[t]['cpu_s']:.1f} s CPU "
                                             f"(load {rec[t]['load_1min']:.1f})" for t in order)
              + f"; STATES identical: {rec['states_identical']}")
    res = {"what": "cdgps estimate of a simulated pair's INIT with one integer withdrawn (baseline._engine_given)",
           "hours": a.hours, "before_tree": str(a.before), "machine": platform.node(), "rounds": rounds,
           "peak_rss_mib": {t: [r[t]["peak_rss_mib"] for r in rounds] for t in trees},
           "cpu_s": {t: [r[t]["cpu_s"] for r in rounds] for t in trees},
           "states_identical": all(r["states_identical"] for r in rounds)}
    if a.out:
        a.out.write_text(json.dumps(res, indent=1) + "\n")
    if not res["states_identical"]:
        raise SystemExit("STATES differ between the trees")


if __name__ == "__main__":
    main()
