#!/usr/bin/env python3
"""The receiver CSV reader against a bare ``pandas.read_csv`` of the same bytes (issue 29 item 4).

Times (best of ``--repeat``) of ``pandas.read_csv(path)`` alone, of
:func:`cdgps_cli.io.logs.read_receiver_log` (typed reading + every validation), and of the same with
the text reading it used before (``logs.FAST_PARSE = False``: every field read as text, then
converted), on a receiver log (default: a 1 h testbed record simulated with ``cdgps simulate``)::

    python benchmarks/csv_parse.py /tmp/long/1h/sim/receiver.csv --out docs/benchmarks/csv_parse.json
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import pandas as pd

from cdgps_cli.config.structure import load_config
from cdgps_cli.io import logs

ROOT = Path(__file__).resolve().parent.parent


def best(fn, repeat: int) -> float:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return min(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("receiver_csv", type=Path)
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "testbed-1998.toml")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    cfg = load_config(a.config)
    load = os.getloadavg()[0]
    bare = best(lambda: pd.read_csv(a.receiver_csv), a.repeat)
    typed = best(lambda: logs.read_receiver_log(a.receiver_csv, cfg), a.repeat)
    logs.FAST_PARSE = False
    text = best(lambda: logs.read_receiver_log(a.receiver_csv, cfg), a.repeat)
    res = {"file": a.receiver_csv.name, "mib": round(a.receiver_csv.stat().st_size / 2**20, 1),
           "rows": int(sum(1 for _ in open(a.receiver_csv)) - 1), "load_1min": round(load, 2),
           "bare_read_csv_s": round(bare, 3), "read_receiver_log_s": round(typed, 3),
           "text_reading_s": round(text, 3), "ratio_to_read_csv": round(typed / bare, 2),
           "text_ratio_to_read_csv": round(text / bare, 2), "pandas": pd.__version__}
    print(json.dumps(res, indent=1))
    if a.out:
        a.out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
