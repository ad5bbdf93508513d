"""Alban et al. (2003) on real samples: PLL phase jitter vs loop bandwidth against the thermal-noise
formula, and an aided narrow loop through dynamics that break the unaided one (issue 16 item 5, part).

On the bundled Pocket SDR file (0.5 s, real front-end noise and oscillator):
  1. for each noise bandwidth B_n the PLL tracks the strongest satellite unaided; the phase jitter is
     the standard deviation of the Costas discriminator after pull-in, against
     σ = sqrt(B_n / (C/N0) · (1 + 1 / (2 T C/N0))) rad with the measured C/N0 and T = 1 ms;
  2. a known line-of-sight motion is injected into the samples (multiplied by e^{jφ(t)}, φ from a
     sinusoidal line-of-sight acceleration of 0.5 g at 2 Hz) and tracked by a 3 Hz loop unaided and aided
     (the aid: dφ/dt / 2π per update, as an inertial sensor would give), and by a 15 Hz unaided loop.

    python benchmarks/tracking_aiding.py
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.io.iq_samples import read_samples  # noqa: E402
from cdgps_cli.tracking.acquisition import acquire  # noqa: E402
from cdgps_cli.tracking.channel import L1_HZ, TrackOptions, track  # noqa: E402

IQ = ROOT.parent / "shared" / "data" / "if" / "L1_20211202_084700_4MHz_IQ.bin"
FS = 4e6
T = 1e-3
C_M_S = 299792458.0


def jitter(r, skip_ms=100):
    """Tracking jitter (rad) of the PLL after ``skip_ms``: the NCO phase against a reference, a cubic
    fitted to the per-update phase measurements NCO + discriminator (unbiased, 1 ms noisy) — the
    satellite's line-of-sight phase over 0.4 s is smooth; the oscillator's own phase noise is not, and
    counts here as tracking error, as it does for the loop.  Also the median C/N0 (dB-Hz)."""
    pll = np.flatnonzero(r["pll"])
    sel = pll[pll >= pll[0] + skip_ms]
    disc = np.arctan(r["q_prompt"][sel] / r["i_prompt"][sel])
    nco = 2 * np.pi * (r["carrier_phase_cycles"][sel] + r["doppler_hz"][sel] * T / 2)   # mid-block phase
    t = r["time_s"][sel]
    meas = nco + disc
    ref = np.polyval(np.polyfit(t - t.mean(), meas, 3), t - t.mean())
    return float(np.std(nco - ref)), float(np.nanmedian(r["cn0_dbhz"][sel]))


def dynamics_jitter(r, phi_at, skip_ms=100):
    """As :func:`jitter` after removing the injected phase (known) from NCO and measurement."""
    pll = np.flatnonzero(r["pll"])
    sel = pll[pll >= pll[0] + skip_ms]
    disc = np.arctan(r["q_prompt"][sel] / r["i_prompt"][sel])
    nco = 2 * np.pi * (r["carrier_phase_cycles"][sel] + r["doppler_hz"][sel] * T / 2) - phi_at[sel]
    t = r["time_s"][sel]
    ref = np.polyval(np.polyfit(t - t.mean(), nco + disc, 3), t - t.mean())
    return float(np.std(nco - ref))


def thermal_rad(bn, cn0_dbhz):
    c = 10 ** (cn0_dbhz / 10)
    return math.sqrt(bn / c * (1 + 1 / (2 * T * c)))


def lock_fraction(r, skip_ms=100):
    pll = np.flatnonzero(r["pll"])
    sel = pll[pll >= pll[0] + skip_ms][::20]
    return float(np.mean(r["phase_lock"][sel] > 0.8))


def main():
    x = read_samples(IQ, "int8-iq")
    acq = sorted([a for a in acquire(x, FS) if a.acquired], key=lambda a: -a.peak_ratio)
    a = acq[0]
    rows = []
    for bn in (3.0, 5.0, 10.0, 15.0, 20.0):
        r = track(x, FS, a.prn, a.doppler_hz, a.code_phase_chips, TrackOptions(pll_bn_hz=bn))
        s, cn0 = jitter(r)
        rows.append({"bn_hz": bn, "jitter_deg": math.degrees(s), "thermal_deg": math.degrees(thermal_rad(bn, cn0)),
                     "cn0_dbhz": cn0, "lock_fraction": lock_fraction(r)})
        print(rows[-1], flush=True)

    t = np.arange(x.size) / FS
    acc, f_mot = 0.5 * 9.80665, 2.0                       # line-of-sight acceleration amplitude (m/s²) and rate
    w = 2 * np.pi * f_mot
    pos = -acc / w**2 * np.sin(w * t)                      # m, starts at rest-like
    vel = -acc / w * np.cos(w * t)
    phi = 2 * np.pi * pos * L1_HZ / C_M_S                  # rad
    moved = x * np.exp(1j * phi)
    upd = np.arange(int(x.size / (FS * T))) * T
    aid = np.interp(upd + T / 2, t, vel) * L1_HZ / C_M_S   # Hz per update (mid-block)
    dyn = []
    for label, bn, use_aid in (("3 Hz unaided", 3.0, False), ("3 Hz aided", 3.0, True), ("15 Hz unaided", 15.0, False)):
        r = track(moved, FS, a.prn, a.doppler_hz, a.code_phase_chips,
                  TrackOptions(pll_bn_hz=bn), aid_doppler_hz=aid if use_aid else None)
        s = dynamics_jitter(r, np.interp(upd + T / 2, t, phi))
        dyn.append({"run": label, "jitter_deg": math.degrees(s), "lock_fraction": lock_fraction(r)})
        print(dyn[-1], flush=True)
    out = {"prn": a.prn, "bandwidth": rows, "dynamics": {"acceleration_m_s2": acc, "frequency_hz": f_mot, "runs": dyn}}
    (ROOT / "docs" / "benchmarks" / "tracking-aiding.json").write_text(json.dumps(out, indent=2) + "\n")
    print("\n| B_n (Hz) | measured jitter (°) | thermal formula (°) | ratio | C/N0 (dB-Hz) | lock |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['bn_hz']:g} | {r['jitter_deg']:.2f} | {r['thermal_deg']:.2f} | {r['jitter_deg'] / r['thermal_deg']:.2f} | "
              f"{r['cn0_dbhz']:.1f} | {100 * r['lock_fraction']:.0f} % |")
    print("\n| run | jitter (°) | lock |")
    print("|---|---|---|")
    for r in dyn:
        print(f"| {r['run']} | {r['jitter_deg']:.2f} | {100 * r['lock_fraction']:.0f} % |")


if __name__ == "__main__":
    main()
