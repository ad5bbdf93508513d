#!/usr/bin/env python3
"""Wall time, peak memory and page size of ``cdgps report run`` against the record's length (issue 33).

For every record length (``--hours``, e.g. ``0.0833 1 6``) the STATES.mcap of 10 Hz testbed data is
made once in ``--workdir/h<hours>`` exactly as ``benchmarks/bench_spectra_memory.py`` makes it (a
``states.mcap`` already there is used as it is), then

    cdgps --quiet report run STATES.mcap -o OUT --date 2026-12-04

runs in a fresh process: wall time, peak RSS (VmHWM), the size of index.html and of each embedded
figure.  The page's time histories are min/max envelopes over a fixed number of bins, so its size
should not grow with the record; the time is the record's reading and the spectra.  Writes ``--out``::

    python benchmarks/bench_run_report.py --workdir /tmp/runreport --hours 0.0833 1 6 \\
        --out docs/benchmarks/run_report.json
"""

from __future__ import annotations

import argparse
import base64
import importlib.util
import json
import platform
import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _spectra_bench():
    spec = importlib.util.spec_from_file_location("bench_spectra_memory", ROOT / "benchmarks" / "bench_spectra_memory.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", type=Path, required=True)
    ap.add_argument("--hours", type=float, nargs="+", default=[0.0833, 1.0])
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    sb = _spectra_bench()
    records = []
    for h in a.hours:
        d = a.workdir / f"h{h:g}"
        states = sb.make_states(d, h)
        out = d / "run-report"
        wall, rss = sb._cli(["report", "run", states, "-o", out, "--date", "2026-12-04"], ROOT)
        page = (out / "index.html").read_text()
        figs = {m.group(1): len(base64.b64decode(m.group(2))) for m in
                re.finditer(r"<figure id='fig-([^']+)'><img[^>]*src='data:image/png;base64,([^']+)'", page)}
        summary = json.loads((out / "report.json").read_text())["summary"]
        records.append({"hours": h, "epochs": summary["epochs"], "states_mcap_mib": states.stat().st_size / 2**20,
                        "wall_s": wall, "peak_rss_mib": rss, "index_html_kib": len(page.encode()) / 1024,
                        "figure_png_kib": {k: v / 1024 for k, v in figs.items()}})
        print(json.dumps(records[-1]), file=sys.stderr)
    result = {"command": "cdgps --quiet report run STATES.mcap -o OUT --date 2026-12-04 (fresh process; VmHWM)",
              "machine": f"{platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}",
              "records": records}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
