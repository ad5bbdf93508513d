"""Tracking speed against real time (issue 16 item 7) on the bundled 0.5 s of 4 MHz complex samples.

Measured in one run, CPU time of this process (``time.process_time``, one core), best of ``--repeat``
runs (the machine is shared; the best run is the least disturbed):

* one channel (PRN 31) tracked by the compiled loop (``cdgps_cli.tracking._trackcore.track``) and by the numpy
  reference path (``CDGPS_NO_KERNEL=1``);
* every acquired satellite of the file tracked one after the other (the receiver's channels);
* the acquisition search of 32 PRNs (the cold start), and acquisition + tracking together.

Each line prints the CPU time and the ratio "seconds of signal per second of CPU" (real-time factor).

    python benchmarks/tracking_speed.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.io.iq_samples import read_samples  # noqa: E402
from cdgps_cli.tracking import correlator  # noqa: E402
from cdgps_cli.tracking.acquisition import acquire  # noqa: E402
from cdgps_cli.tracking.channel import track  # noqa: E402

IQ = ROOT.parent / "shared" / "data" / "if" / "L1_20211202_084700_4MHz_IQ.bin"
FS = 4e6


def best_cpu(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


def with_kernel(enabled: bool, fn):
    old = os.environ.get("CDGPS_NO_KERNEL")
    os.environ["CDGPS_NO_KERNEL"] = "0" if enabled else "1"
    try:
        return fn()
    finally:
        if old is None:
            os.environ.pop("CDGPS_NO_KERNEL", None)
        else:
            os.environ["CDGPS_NO_KERNEL"] = old


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    x = read_samples(IQ, "int8-iq")
    duration_s = x.size / FS
    acq = [a for a in acquire(x, FS) if a.acquired]
    a31 = next(a for a in acq if a.prn == 31)

    def one():
        track(x, FS, a31.prn, a31.doppler_hz, a31.code_phase_chips)

    def channels():
        for a in acq:
            track(x, FS, a.prn, a.doppler_hz, a.code_phase_chips)

    def cold_start():
        found = [a for a in acquire(x, FS) if a.acquired]
        for a in found:
            track(x, FS, a.prn, a.doppler_hz, a.code_phase_chips)

    rows = []

    def row(label, cpu_s):
        rows.append({"run": label, "cpu_s": cpu_s, "real_time_factor": duration_s / cpu_s})
        print(f"{label:<48} {cpu_s * 1e3:8.1f} ms CPU   {duration_s / cpu_s:7.1f}× real time", flush=True)

    print(f"{duration_s:.3f} s of 4 MHz complex samples; kernel built: {correlator._trackcore is not None}")
    row("one channel, compiled loop", with_kernel(True, lambda: best_cpu(one, args.repeat)))
    row("one channel, numpy reference", with_kernel(False, lambda: best_cpu(one, max(1, args.repeat // 2))))
    row(f"all {len(acq)} channels, compiled loop", with_kernel(True, lambda: best_cpu(channels, args.repeat)))
    row("acquisition, 32 PRNs", best_cpu(lambda: acquire(x, FS), max(1, args.repeat // 2)))
    row(f"acquisition + {len(acq)} channels, compiled", with_kernel(True, lambda: best_cpu(cold_start, max(1, args.repeat // 2))))
    out = {"input": IQ.name, "duration_s": duration_s, "sample_rate_hz": FS, "machine": platform.machine(),
           "python": platform.python_version(), "repeat": args.repeat, "runs": rows}
    (ROOT / "docs" / "benchmarks" / "tracking-speed.json").write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
