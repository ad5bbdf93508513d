"""`cdgps track` on long IF files made from the bundled real samples (issue 29 item 6, the `track` row).

The real file ``../shared/data/if/L1_20211202_084700_4MHz_IQ.bin`` (0.5 s, 4 MHz complex baseband, int8
I/Q pairs of 2-bit levels, I − jQ; Pocket SDR) is repeated end to end, byte for byte, to 10 s, 60 s and
240 s.  The repetition keeps the C/A code phase continuous (0.5 s is 500 whole code periods) but not the
carrier phase or the navigation bits: at every 0.5 s seam each satellite's carrier phase jumps and a bit
may flip, as a strong phase step would; the loops see the same live-sky signals (real C/N0, Dopplers,
front-end noise) over and over.  The study measures memory and speed against the file's length, not
tracking quality (``track_memory.py`` uses a phase-continuous simulated file for that).

Each run is a fresh `cdgps track` process (:func:`track_memory.run_track`: acquisition of 32 PRNs,
every acquired satellite tracked, TRACK.mcap written); peak RSS and CPU time from ``os.wait4``, wall
time from the clock.  Real-time factor per channel = duration × channels / wall time (the channels run
one after the other on one core).

    python benchmarks/track_long.py [--durations 10,60,240] [--workdir /tmp]

Writes docs/benchmarks/track_long.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from cdgps_cli.config.options import TRACK_BLOCK_SAMPLES  # noqa: E402
from track_memory import run_track  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "if" / "L1_20211202_084700_4MHz_IQ.bin"
FS_HZ = 4e6


def tile(src: Path, dst: Path, duration_s: float) -> None:
    """``src`` repeated end to end (whole copies, then a prefix) to ``duration_s`` at 2 bytes per sample."""
    one = src.read_bytes()
    left = int(round(duration_s * FS_HZ)) * 2
    with open(dst, "wb") as fo:
        while left:
            chunk = one[:left]
            fo.write(chunk)
            left -= len(chunk)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--durations", default="10,60,240", help="file lengths, s (comma-separated)")
    ap.add_argument("--workdir", type=Path, default=None, help="where the IF files go (default: a temporary folder)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "track_long.json")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="track_long_", dir=args.workdir))
    load_start = os.getloadavg()
    rows = []
    try:
        for d in (float(v) for v in args.durations.split(",")):
            iq = work / f"if_{d:g}s.bin"
            tile(REAL, iq, d)
            r = {"duration_s": d, "file_mb": iq.stat().st_size / 2**20, **run_track(ROOT, iq, work / f"track_{d:g}.mcap")}
            if r.get("channels"):
                r["real_time_factor_per_channel"] = round(d * r["channels"] / r["wall_s"], 2)
                r["real_time_factor_per_channel_cpu"] = round(d * r["channels"] / r["cpu_s"], 2)
            rows.append(r)
            print(json.dumps(r), flush=True)
            iq.unlink()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    res = {"what": "peak RSS and time of a fresh `cdgps track` process on the real 0.5 s IF file repeated to each length",
           "source": str(REAL.relative_to(ROOT.parent)), "tiling": "byte-exact repetition: code phase continuous, "
           "carrier phase and navigation bits jump at each 0.5 s seam",
           "format": "int8-iq, 2-bit levels, 4 MHz, I - jQ", "block_samples": TRACK_BLOCK_SAMPLES,
           "machine": platform.machine(), "cpus": os.cpu_count(), "python": platform.python_version(),
           "numpy": np.__version__, "command": "python benchmarks/track_long.py " + " ".join(sys.argv[1:]),
           "load_average_1_5_15_min": {"start": [round(v, 2) for v in load_start],
                                       "end": [round(v, 2) for v in os.getloadavg()]},
           "runs": rows}
    if rows:
        rss = [r["peak_rss_mb"] for r in rows if r.get("exit") == 0]
        res["peak_rss_spread_mb"] = round(max(rss) - min(rss), 2) if rss else None
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
