"""Acquisition: detection probability vs C/N0 and false-alarm rate on simulated samples (issue 16 item 1).

Signals: one GPS L1 C/A satellite in complex baseband at 4 MHz (the bundled file's rate), a Doppler
uniform in ±4.5 kHz, a code phase uniform in [0, 1023) chips, 50 bit/s navigation bits with a random
first edge, complex white noise at the C/N0 given; ``acquisition.acquire`` searches that PRN over
±5 kHz in 250 Hz bins with K = 5, 10, 20 ms of non-coherent integration at the default false-alarm
probability (1e-4 per PRN).  A detection counts when the PRN is declared acquired with its Doppler
within 250 Hz and its code phase within 1 chip of the truth.  False alarms: noise alone searched for
all 32 PRNs, at P_fa = 1e-2 (to see the calibration in few trials) and the default 1e-4.

    python benchmarks/tracking_acquisition.py [--trials 40]

Writes docs/benchmarks/tracking-acquisition.json.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.tracking.acquisition import acquire  # noqa: E402
from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, ca_code  # noqa: E402
from cdgps_cli.tracking.channel import L1_HZ  # noqa: E402

FS = 4e6
CN0S = (30.0, 32.0, 34.0, 36.0, 38.0, 40.0, 42.0)
KS = (5, 10, 20)
PRN = 11


def signal(rng, cn0_dbhz, ms, prn=PRN):
    """(samples, Doppler Hz, code phase at the first sample in chips); no signal when cn0_dbhz is None."""
    n = int(FS * ms * 1e-3)
    t = np.arange(n) / FS
    noise = math.sqrt(FS / 2) * rng.standard_normal(2 * n).view(np.complex128)   # unit noise density
    dop, code0 = rng.uniform(-4500, 4500), rng.uniform(0, 1023)
    if cn0_dbhz is None:
        return noise, dop, code0
    chips = code0 + t * CHIP_RATE_HZ * (1 + dop / L1_HZ)
    bits = np.where(np.floor((t + rng.uniform(0, 0.02)) / 0.02) % 2 == 0, 1.0, -1.0) * rng.choice([-1.0, 1.0], 1)
    amp = math.sqrt(10 ** (cn0_dbhz / 10))
    x = amp * ca_code(prn)[np.floor(chips).astype(np.int64) % 1023] * bits * np.exp(2j * np.pi * dop * t
                                                                                    + 1j * rng.uniform(0, 6.3))
    return x + noise, dop, code0


def detection(trials, seed=1):
    rows = []
    rng = np.random.default_rng(seed)
    for k in KS:
        for cn0 in CN0S:
            hits = 0
            for _ in range(trials):
                x, dop, code0 = signal(rng, cn0, k)
                a = acquire(x, FS, [PRN], noncoherent_ms=k)[0]
                dc = abs((a.code_phase_chips - code0 + 511.5) % 1023 - 511.5)
                hits += bool(a.acquired and abs(a.doppler_hz - dop) < 250 and dc < 1.0)
            rows.append({"noncoherent_ms": k, "cn0_dbhz": cn0, "trials": trials, "detected": hits,
                         "p_detection": hits / trials})
            print(rows[-1], flush=True)
    return rows


def false_alarms(trials, seed=2):
    rng = np.random.default_rng(seed)
    res = []
    for pfa in (1e-2, 1e-4):
        n = 0
        for _ in range(trials):
            x, _, _ = signal(rng, None, 10)
            n += sum(a.acquired for a in acquire(x, FS, range(1, 33), false_alarm=pfa))
        res.append({"false_alarm_set": pfa, "prn_searches": 32 * trials, "false_alarms": n,
                    "rate": n / (32 * trials)})
        print(res[-1], flush=True)
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--noise-trials", type=int, default=20)
    args = ap.parse_args()
    t0 = time.process_time()
    out = {"fs_hz": FS, "detection": detection(args.trials), "false_alarms": false_alarms(args.noise_trials)}
    out["cpu_s"] = time.process_time() - t0
    path = ROOT / "docs" / "benchmarks" / "tracking-acquisition.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
