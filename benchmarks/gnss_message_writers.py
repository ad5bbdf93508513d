#!/usr/bin/env python3
"""GNSS ``ingest``'s observation messages against their per-message reference, in one process (issue 29).

On a GNSS RUN.mcap (e.g. the 24 h simulated pair of ``benchmarks/long_records.py --gnss-hours 24``), the
observation messages (one per receiver and epoch) written by :func:`cdgps_cli.io.gnss_run._write_obs_messages`
(texts of a block of rows) and by ``McapOut.write`` of each epoch's payload (:func:`_obs_payload`, the
path before).

Rounds interleaved (reference, new, reference, new, …), each file written to a temporary directory and
compared byte for byte; the best CPU time of each is kept, with the load average::

    python benchmarks/gnss_message_writers.py /tmp/cdgps-long-records/gnss-24h/after/run.mcap --rounds 3 \
        --out docs/benchmarks/gnss_message_writers.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.io import gnss_run as g  # noqa: E402
from cdgps_cli.io.mcap import McapOut  # noqa: E402


def _obs_reference(out, ch, receivers) -> None:
    msgs = []
    for i, (n, rx) in enumerate(receivers.items()):
        r = rx.raw
        t = r["time_gps_s"].to_numpy()
        cuts = np.flatnonzero(np.r_[True, t[1:] != t[:-1], True])
        cols = {c: r[c].to_numpy() for c in (*g._NULLABLE_OBS, *g._INT_OBS)}
        cols["sat"] = r["sat"].to_numpy()
        p = (n, t, cuts, cols, r["epoch_flag"].to_numpy(), r["clock_offset_s"].to_numpy())
        msgs += [(float(t[a]), i, k, p, int(a), int(b)) for k, (a, b) in enumerate(zip(cuts[:-1], cuts[1:]))]
    msgs.sort(key=lambda m: m[:3])
    for t, _, _, p, a, b in msgs:
        out.write(ch, t, g._obs_payload(p, a, b))


def _timed(fn, path: Path) -> float:
    c0 = time.process_time()
    with McapOut(path, time_scale="gps") as out:
        fn(out)
    return time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    run = g.read_gnss_run(a.run)

    def obs_new(out):
        g._write_obs_messages(out, out.channel(g.GNSS_OBS_TOPIC, g.OBS_SCHEMA), run.receivers)

    def obs_ref(out):
        _obs_reference(out, out.channel(g.GNSS_OBS_TOPIC, g.OBS_SCHEMA), run.receivers)

    result = {"run": str(a.run), "rounds": a.rounds, "cases": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name, ref, new, n_msg in (("obs messages (ingest)", obs_ref, obs_new,
                                       sum(np.unique(rx.raw["time_gps_s"].to_numpy()).size for rx in run.receivers.values())),):
            cpu = {"reference": [], "new": []}
            loads = []
            for k in range(a.rounds):
                loads.append(round(os.getloadavg()[0], 2))
                for which, fn in (("reference", ref), ("new", new)):
                    cpu[which].append(round(_timed(fn, Path(tmp) / f"{which}.mcap"), 3))
                same = (Path(tmp) / "reference.mcap").read_bytes() == (Path(tmp) / "new.mcap").read_bytes()
                print(f"{name} round {k + 1}: reference {cpu['reference'][-1]:.2f} s, new {cpu['new'][-1]:.2f} s CPU, "
                      f"identical {same} (load {loads[-1]})", file=sys.stderr)
            result["cases"][name] = {"messages": int(n_msg), "cpu_s_reference": min(cpu["reference"]),
                                     "cpu_s_new": min(cpu["new"]), "cpu_s_rounds": cpu, "identical": same,
                                     "load_1min": loads}
    print(json.dumps(result, indent=1))
    if a.out:
        a.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
