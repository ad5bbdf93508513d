"""Alban et al. (2003) reproduced on synthetic GPS L1 C/A signals (issue 16 item 5).

A complex-baseband signal of known truth — C/A code, a static Doppler, an optional injected
line-of-sight phase φ(t) and oscillator phase noise, white noise at a known C/N0 — is generated in
0.5 s pieces and tracked by several channel configurations at once (the channel state carries over
between pieces), so long runs fit in memory.  The tracking error is the NCO phase at mid-block
(carrier phase at the block start + f·T/2) minus the true phase there, modulo the Costas half cycle.

Studies (``--only`` picks some):

* ``jitter``: phase jitter vs loop bandwidth B_n against σ = sqrt(B_n/(C/N0)·(1 + 1/(2T·C/N0))):
  static (100 s: the thermal check, target within 10 %), and under 0.5 g at 2 Hz line-of-sight dynamics
  unaided, aided by the exact Doppler, and aided by a consumer-grade accelerometer (bias, noise, 30 Hz
  bandwidth);
* ``tones``: tracking transfer |φ_NCO/φ_in| by injecting phase tones 0.5–70 Hz: unaided 3 and 15 Hz,
  aided 3 Hz with a 30 Hz and a 100 Hz sensor — the aided loop's −3 dB tracking bandwidth;
* ``oscillator``: jitter, slips and lock vs B_n with TCXO / high-quality TCXO / OCXO phase noise
  (2 seeds × 10 s), against thermal + ∫ S_φ(f)|1 − H(j2πf)|² df; the lowest bandwidth holding lock;
* ``shared``: four satellites sharing one oscillator (TCXO, TCXO-HQ), narrow channel loops with a
  shared clock loop (:mod:`cdgps_cli.tracking.shared_clock`) against independent loops;
* ``slips``: cycle slips (half-cycle jumps of the 20 ms mean error) in 20 s vs B_n, aided and unaided,
  for 0.5 g line-of-sight dynamics at 2 Hz and at 0.5 Hz, 40 dB-Hz.

    python benchmarks/tracking_paper.py [--only jitter,tones,oscillator,shared,slips]

Writes docs/benchmarks/tracking-paper.json and docs/figures/tracking-*.png.
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

from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, ca_code  # noqa: E402
from cdgps_cli.tracking.channel import L1_HZ, OUT_FIELDS, TrackOptions, initial_state, run_updates  # noqa: E402
from cdgps_cli.tracking.inertial import GRADES, InertialGrade, accelerometer_doppler_aid_hz  # noqa: E402
from cdgps_cli.tracking.loops import pll2_response  # noqa: E402
from cdgps_cli.tracking.oscillator import OSCILLATORS, carrier_phase_noise_rad, pll_jitter_rad  # noqa: E402
from cdgps_cli.tracking.shared_clock import SharedClockReceiver  # noqa: E402
from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M, STANDARD_GRAVITY_M_S2  # noqa: E402

FS = 2.2e6                       # 2.15 samples per chip; 2200 per 1 ms update
N_MS = 2200
T = 1e-3
PRN, DOPPLER_HZ, CODE0 = 7, 1234.0, 200.0
LAMBDA_M = GPS_L1_WAVELENGTH_M
G = STANDARD_GRAVITY_M_S2
BANDWIDTHS = (3.0, 5.0, 10.0, 15.0, 20.0)
COL = {k: i for i, k in enumerate(OUT_FIELDS)}


# ------------------------------------------------------------------------------------------ signal

class Motion:
    """Line-of-sight displacement towards the satellite d(t) (m) as a sum of sinusoids
    d = Σ a_i sin(2π f_i t + p_i): phase 2π d/λ; its velocity and acceleration are analytic."""

    def __init__(self, amps_m, freqs_hz, phases_rad=None):
        self.a = np.atleast_1d(np.asarray(amps_m, float))
        self.f = np.atleast_1d(np.asarray(freqs_hz, float))
        self.p = np.zeros_like(self.a) if phases_rad is None else np.asarray(phases_rad, float)

    def _sum(self, t, order):
        w = 2 * np.pi * self.f
        out = np.zeros_like(t)
        for a, wi, p in zip(self.a, w, self.p):
            arg = wi * t + p
            out += a * wi**order * (np.sin, np.cos, lambda z: -np.sin(z))[order](arg)
        return out

    def phase_rad(self, t):
        return 2 * np.pi / LAMBDA_M * self._sum(t, 0)

    def velocity(self, t):
        return self._sum(t, 1)

    def acceleration(self, t):
        return self._sum(t, 2)


def sinusoidal_dynamics(acc_g, freq_hz):
    """LOS acceleration acc_g·g·sin(2π f t) ... as a displacement −A/ω² sin(ωt)."""
    w = 2 * np.pi * freq_hz
    return Motion([-acc_g * G / w**2], [freq_hz])


def run(duration_s, cn0_dbhz, configs, *, motion=None, osc_phase=None, seed=0, chunk_s=0.5):
    """Generate the signal piecewise and track it with every config.

    configs : list of (label, TrackOptions, aid array per update or None)
    osc_phase : (phase_rad at 10 kHz instants, 1e-4) or None
    Returns per label the (m, len(OUT_FIELDS)) outputs and the true mid-block phase (m,).
    """
    rng = np.random.default_rng(seed)
    code = ca_code(PRN).astype(np.float64)
    m = int(round(duration_s / T))
    per = int(round(chunk_s / T))
    states = {lab: initial_state(DOPPLER_HZ + 2.0, CODE0) for lab, _, _ in configs}
    outs = {lab: [] for lab, _, _ in configs}
    sigma = math.sqrt(FS / 10 ** (cn0_dbhz / 10) / 2)
    for k0 in range(0, m, per):
        k1 = min(m, k0 + per)
        t = np.arange(k0 * N_MS, k1 * N_MS) / FS
        chips = CODE0 + t * CHIP_RATE_HZ * (1 + DOPPLER_HZ / L1_HZ)
        ph = 2 * np.pi * DOPPLER_HZ * t
        if motion is not None:
            ph = ph + motion.phase_rad(t)
        if osc_phase is not None:
            ph = ph + np.interp(t, np.arange(osc_phase[0].size) * osc_phase[1], osc_phase[0])
        x = code[np.floor(chips).astype(np.int64) % 1023] * np.exp(1j * ph)
        x += sigma * rng.standard_normal(2 * t.size).view(np.complex128)
        for lab, opt, aid in configs:
            outs[lab].append(run_updates(x, FS, PRN, states[lab], opt, None if aid is None else aid[k0:k1]))
    tm = np.arange(m) * T + T / 2
    truth = 2 * np.pi * DOPPLER_HZ * tm
    if motion is not None:
        truth = truth + motion.phase_rad(tm)
    if osc_phase is not None:
        truth = truth + np.interp(tm, np.arange(osc_phase[0].size) * osc_phase[1], osc_phase[0])
    return {lab: np.vstack(v) for lab, v in outs.items()}, truth


def tracking_error_rad(out, truth):
    """NCO phase at mid-block minus truth, shifted by the nearest multiple of π (Costas) at the start."""
    nco = 2 * np.pi * (out[:, COL["carrier_phase_cycles"]] + out[:, COL["doppler_hz"]] * T / 2)
    e = nco - truth
    return e - np.pi * np.round(np.median(e[-1000:]) / np.pi)


def slips(err_rad, settle_ms):
    """Half-cycle slips: changes of round(20 ms mean error / π) after settling."""
    e = err_rad[settle_ms:]
    e = e[: e.size // 20 * 20].reshape(-1, 20).mean(axis=1)
    return int(np.count_nonzero(np.diff(np.round(e / np.pi))))


def lock_fraction(out, settle_ms):
    i, q = out[settle_ms:, COL["i_prompt"]], out[settle_ms:, COL["q_prompt"]]
    n = i.size // 20 * 20
    i, q = i[:n].reshape(-1, 20), q[:n].reshape(-1, 20)
    return float(np.mean((np.sum(i * i - q * q, 1) / np.sum(i * i + q * q, 1)) > 0.8))


def thermal_rad(bn, cn0_dbhz):
    c = 10 ** (cn0_dbhz / 10)
    return math.sqrt(bn / c * (1 + 1 / (2 * T * c)))


def effective_cn0_dbhz(out, cn0_dbhz):
    """C/N0 after correlation losses (code alignment): A² = E|P|² − 2σ², σ² = N·fs/(2 C/N0) per component."""
    p2 = np.mean(out[:, COL["i_prompt"]] ** 2 + out[:, COL["q_prompt"]] ** 2)
    noise = N_MS * FS / 10 ** (cn0_dbhz / 10)
    return cn0_dbhz + 10 * math.log10((p2 - noise) / N_MS**2)


def consumer_aid(motion, m, grade: InertialGrade, seed):
    """Doppler aid per update (mid-block) from a LOS accelerometer of ``grade`` sampled at 1 kHz."""
    tm = np.arange(m) * T + T / 2
    return accelerometer_doppler_aid_hz(motion.acceleration(tm), T, grade, np.random.default_rng(seed),
                                        v0_m_s=float(motion.velocity(tm[:1])[0]), wavelength_m=LAMBDA_M)


# ------------------------------------------------------------------------------------------ studies

def study_jitter():
    cn0 = 45.0
    res = {"cn0_dbhz": cn0, "static": [], "dynamics": []}
    configs = [(f"{bn:g}", TrackOptions(pll_bn_hz=bn), None) for bn in BANDWIDTHS]
    outs, truth = run(100.0, cn0, configs, seed=11)
    for bn in BANDWIDTHS:
        o = outs[f"{bn:g}"]
        err = tracking_error_rad(o, truth)
        settle = 2000
        e = err[settle:]
        cn0e = effective_cn0_dbhz(o[settle:], cn0)
        row = {"bn_hz": bn, "jitter_deg": math.degrees(np.std(e)), "thermal_deg": math.degrees(thermal_rad(bn, cn0)),
               "thermal_effective_deg": math.degrees(thermal_rad(bn, cn0e)), "cn0_effective_dbhz": cn0e,
               "slips": slips(err, settle)}
        row["ratio"] = row["jitter_deg"] / row["thermal_effective_deg"]
        res["static"].append(row)
        print("jitter static", row, flush=True)
    motion = sinusoidal_dynamics(0.5, 2.0)
    grade = GRADES["consumer"]
    m = 20000
    aid = consumer_aid(motion, m, grade, seed=5)
    exact = motion.velocity(np.arange(m) * T + T / 2) / LAMBDA_M
    configs = [(f"{bn:g} unaided", TrackOptions(pll_bn_hz=bn), None) for bn in BANDWIDTHS]
    configs += [(f"{bn:g} aided", TrackOptions(pll_bn_hz=bn), aid) for bn in BANDWIDTHS]
    configs += [(f"{bn:g} exact aid", TrackOptions(pll_bn_hz=bn), exact) for bn in BANDWIDTHS]
    outs, truth = run(20.0, cn0, configs, motion=motion, seed=12)
    for bn in BANDWIDTHS:
        for kind in ("unaided", "aided", "exact aid"):
            o = outs[f"{bn:g} {kind}"]
            err = tracking_error_rad(o, truth)
            e = err[2000:]
            row = {"bn_hz": bn, "loop": kind, "jitter_deg": math.degrees(np.std(e)),
                   "thermal_deg": math.degrees(thermal_rad(bn, cn0)), "slips": slips(err, 2000),
                   "lock_fraction": lock_fraction(o, 2000)}
            res["dynamics"].append(row)
            print("jitter dynamics", row, flush=True)
    res["dynamics_spec"] = {"acceleration_g": 0.5, "frequency_hz": 2.0, "aid": f"{grade.name} accelerometer",
                            "grade": grade.__dict__}
    return res


TONES_HZ = np.array([0.5, 1, 2, 3, 5, 8, 12, 20, 30, 40, 50, 70])


def study_tones():
    cn0, dur, settle = 55.0, 10.0, 2000
    amp_rad = 0.04
    rng = np.random.default_rng(3)
    motion = Motion(np.full(TONES_HZ.size, amp_rad * LAMBDA_M / (2 * np.pi)), TONES_HZ, rng.uniform(0, 2 * np.pi, TONES_HZ.size))
    m = int(dur / T)
    sensors = {"30 Hz": InertialGrade("30 Hz consumer", 0.0, GRADES["consumer"].accel_noise_m_s2_per_rthz, 0, 0, 30.0),
               "100 Hz": InertialGrade("100 Hz tactical", 0.0, GRADES["tactical"].accel_noise_m_s2_per_rthz, 0, 0, 100.0)}
    configs = [("3 Hz unaided", TrackOptions(pll_bn_hz=3.0), None), ("15 Hz unaided", TrackOptions(pll_bn_hz=15.0), None)]
    for name, g in sensors.items():
        configs.append((f"3 Hz aided, {name} sensor", TrackOptions(pll_bn_hz=3.0), consumer_aid(motion, m, g, seed=9)))
    outs, truth = run(dur, cn0, configs, motion=motion, seed=13)
    tm = np.arange(m) * T + T / 2
    sel = slice(settle, None)
    basis = [np.ones(m - settle), tm[sel] - tm[sel].mean()]
    for f in TONES_HZ:
        basis += [np.sin(2 * np.pi * f * tm[sel]), np.cos(2 * np.pi * f * tm[sel])]
    A = np.stack(basis, axis=1)
    res = {"tones_hz": TONES_HZ.tolist(), "amplitude_rad": amp_rad, "cn0_dbhz": cn0, "runs": []}
    for lab, _, _ in configs:
        o = outs[lab]
        nco = 2 * np.pi * (o[:, COL["carrier_phase_cycles"]] + o[:, COL["doppler_hz"]] * T / 2) - 2 * np.pi * DOPPLER_HZ * tm
        c_out = np.linalg.lstsq(A, nco[sel], rcond=None)[0][2:]
        tin = motion.phase_rad(tm[sel]) - np.mean(motion.phase_rad(tm[sel]))
        c_in = np.linalg.lstsq(A, tin, rcond=None)[0][2:]
        zo = c_out[0::2] + 1j * c_out[1::2]
        zi = c_in[0::2] + 1j * c_in[1::2]
        gain = np.abs(zo / zi)
        res["runs"].append({"run": lab, "gain": gain.tolist(), "bandwidth_3db_hz": _crossing(TONES_HZ, gain),
                            "slips": slips(tracking_error_rad(o, truth), settle)})
        print("tones", lab, np.round(gain, 3), res["runs"][-1]["bandwidth_3db_hz"], flush=True)
    return res


def _crossing(f, gain, level=1 / math.sqrt(2)):
    """First frequency (log-interpolated) where the gain falls below ``level``; None if it never does."""
    below = np.flatnonzero(gain < level)
    if below.size == 0:
        return None
    i = below[0]
    if i == 0:
        return float(f[0])
    x0, x1, y0, y1 = math.log(f[i - 1]), math.log(f[i]), gain[i - 1], gain[i]
    return float(math.exp(x0 + (level - y0) * (x1 - x0) / (y1 - y0)))


OSC_BANDWIDTHS = (2.0, 3.0, 5.0, 8.0, 10.0, 15.0, 20.0)


def study_oscillator():
    cn0, dur, settle = 45.0, 10.0, 2000
    res = {"cn0_dbhz": cn0, "duration_s": dur, "seeds": 2, "oscillators": []}
    for osc in OSCILLATORS.values():
        rows = {bn: {"jitter_deg": [], "slips": 0, "lock": []} for bn in OSC_BANDWIDTHS}
        for seed in (1, 2):
            phase = carrier_phase_noise_rad(osc, 1e-4, int(dur / 1e-4) + 10, np.random.default_rng(100 + seed))
            configs = [(f"{bn:g}", TrackOptions(pll_bn_hz=bn), None) for bn in OSC_BANDWIDTHS]
            outs, truth = run(dur, cn0, configs, osc_phase=(phase, 1e-4), seed=20 + seed)
            for bn in OSC_BANDWIDTHS:
                o = outs[f"{bn:g}"]
                err = tracking_error_rad(o, truth)
                r = rows[bn]
                r["slips"] += slips(err, settle)
                r["jitter_deg"].append(math.degrees(np.std(err[settle:])))
                r["lock"].append(lock_fraction(o, settle))
        table = []
        for bn in OSC_BANDWIDTHS:
            r = rows[bn]
            pred = math.degrees(math.hypot(thermal_rad(bn, cn0), pll_jitter_rad(osc, bn)))
            table.append({"bn_hz": bn, "jitter_deg": float(np.mean(r["jitter_deg"])), "predicted_deg": pred,
                          "oscillator_only_deg": math.degrees(pll_jitter_rad(osc, bn)),
                          "slips": r["slips"], "lock_fraction": float(np.min(r["lock"]))})
            print("oscillator", osc.name, table[-1], flush=True)
        holding = [row["bn_hz"] for row in table if row["slips"] == 0 and row["lock_fraction"] >= 0.9]
        res["oscillators"].append({"name": osc.name, "h": [osc.h0, osc.h_m1, osc.h_m2], "rows": table,
                                   "lowest_bn_holding_lock_hz": min(holding) if holding else None})
    return res


SHARED_SATS = ((3, 1200.0, 100.0), (17, -2400.0, 600.0), (22, 300.0, 900.0), (28, 2900.0, 400.0))
SHARED_CONFIGS = {
    "TCXO-HQ": [("independent 3 Hz", 3.0, None), ("3 Hz + shared 15 Hz clock", 3.0, 15.0),
                ("2 Hz + shared 15 Hz clock", 2.0, 15.0)],
    "TCXO": [("independent 3 Hz", 3.0, None), ("independent 20 Hz", 20.0, None),
             ("3 Hz + shared 30 Hz clock", 3.0, 30.0), ("3 Hz + shared 60 Hz clock", 3.0, 60.0)],
}


def study_shared():
    """Four satellites, one oscillator: per channel jitter, slips and lock of each configuration."""
    cn0, dur, settle, per = 45.0, 10.0, 2000, 500
    res = {"cn0_dbhz": cn0, "duration_s": dur, "satellites": [s[0] for s in SHARED_SATS], "oscillators": []}
    codes = [ca_code(p).astype(np.float64) for p, _, _ in SHARED_SATS]
    sigma = math.sqrt(FS / 10 ** (cn0 / 10) / 2)
    m = int(dur / T)
    for name, configs in SHARED_CONFIGS.items():
        osc = OSCILLATORS[name]
        phase = carrier_phase_noise_rad(osc, 1e-4, int(dur / 1e-4) + 10, np.random.default_rng(200))
        tgrid = np.arange(phase.size) * 1e-4
        rng = np.random.default_rng(40)
        starts = [(p, d + 2.0, c) for p, d, c in SHARED_SATS]
        rxs, indep = {}, {}
        for lab, bn, clk in configs:
            opt = TrackOptions(pll_bn_hz=bn)
            if clk is None:
                indep[lab] = (opt, [initial_state(d, c) for _, d, c in starts])
            else:
                rxs[lab] = SharedClockReceiver(FS, starts, opt, clock_bn_hz=clk)
        outs = {lab: [[] for _ in SHARED_SATS] for lab, _, _ in configs}
        for k0 in range(0, m, per):
            t = np.arange(k0 * N_MS, min(m, k0 + per) * N_MS) / FS
            osc_t = np.interp(t, tgrid, phase)
            x = sigma * rng.standard_normal(2 * t.size).view(np.complex128)
            for code, (p, d, c) in zip(codes, SHARED_SATS):
                chips = c + t * CHIP_RATE_HZ * (1 + d / L1_HZ)
                x += code[np.floor(chips).astype(np.int64) % 1023] * np.exp(1j * (2 * np.pi * d * t + osc_t))
            for lab, (opt, states) in indep.items():
                for i, (p, _, _) in enumerate(SHARED_SATS):
                    outs[lab][i].append(run_updates(x, FS, p, states[i], opt))
            for lab, rx in rxs.items():
                rows, _ = rx.run(x)
                for i in range(len(SHARED_SATS)):
                    outs[lab][i].append(rows[i])
        tm = np.arange(m) * T + T / 2
        osc_m = np.interp(tm, tgrid, phase)
        table = []
        for lab, bn, clk in configs:
            jit, sl, lk = [], 0, []
            for i, (p, d, c) in enumerate(SHARED_SATS):
                o = np.vstack(outs[lab][i])
                err = tracking_error_rad(o, 2 * np.pi * d * tm + osc_m)
                jit.append(math.degrees(np.std(err[settle:])))
                sl += slips(err, settle)
                lk.append(lock_fraction(o, settle))
            row = {"run": lab, "channel_bn_hz": bn, "clock_bn_hz": clk, "jitter_deg_max": max(jit),
                   "jitter_deg_mean": float(np.mean(jit)), "slips": sl, "lock_fraction_min": min(lk)}
            if clk is not None:
                row["predicted_deg"] = math.degrees(math.sqrt(thermal_rad(bn, cn0) ** 2 + thermal_rad(clk, cn0) ** 2 / len(SHARED_SATS)
                                                              + pll_jitter_rad(osc, clk) ** 2))
            else:
                row["predicted_deg"] = math.degrees(math.hypot(thermal_rad(bn, cn0), pll_jitter_rad(osc, bn)))
            table.append(row)
            print("shared", name, row, flush=True)
        res["oscillators"].append({"name": name, "rows": table})
    return res


def study_slips():
    cn0, dur, settle = 40.0, 20.0, 2000
    res = {"cn0_dbhz": cn0, "duration_s": dur, "cases": []}
    m = int(dur / T)
    for acc_g, f_hz in ((0.5, 2.0), (0.5, 0.5)):
        motion = sinusoidal_dynamics(acc_g, f_hz)
        aid = consumer_aid(motion, m, GRADES["consumer"], seed=7)
        configs = [(f"{bn:g} unaided", TrackOptions(pll_bn_hz=bn), None) for bn in BANDWIDTHS]
        configs += [(f"{bn:g} aided", TrackOptions(pll_bn_hz=bn), aid) for bn in BANDWIDTHS]
        outs, truth = run(dur, cn0, configs, motion=motion, seed=30)
        for bn in BANDWIDTHS:
            row = {"acceleration_g": acc_g, "frequency_hz": f_hz, "bn_hz": bn}
            for kind in ("unaided", "aided"):
                o = outs[f"{bn:g} {kind}"]
                row[f"slips_{kind}"] = slips(tracking_error_rad(o, truth), settle)
                row[f"lock_{kind}"] = lock_fraction(o, settle)
            res["cases"].append(row)
            print("slips", row, flush=True)
    return res


# ------------------------------------------------------------------------------------------ figures

def figures(res, figdir: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figdir.mkdir(parents=True, exist_ok=True)
    if "jitter" in res:
        j = res["jitter"]
        fig, ax = plt.subplots(figsize=(6, 4))
        bn = np.linspace(2, 22, 100)
        ax.plot(bn, [math.degrees(thermal_rad(b, j["cn0_dbhz"])) for b in bn], "k-", label="thermal formula")
        ax.plot([r["bn_hz"] for r in j["static"]], [r["jitter_deg"] for r in j["static"]], "ko", label="static (100 s)")
        labels = {"aided": "aided (consumer accelerometer)", "exact aid": "aided (exact Doppler)", "unaided": "unaided"}
        for kind, mk in (("exact aid", "x"), ("aided", "s"), ("unaided", "^")):
            rows = [r for r in j["dynamics"] if r["loop"] == kind]
            if rows:
                ax.plot([r["bn_hz"] for r in rows], [r["jitter_deg"] for r in rows], mk, label=f"0.5 g at 2 Hz, {labels[kind]}")
        ax.set_yscale("log")
        ax.set_xlabel("PLL noise bandwidth B_n (Hz)")
        ax.set_ylabel("phase jitter (deg)")
        ax.set_title(f"PLL jitter, {j['cn0_dbhz']:g} dB-Hz")
        ax.set_ylim(0.3, 600)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
        fig.tight_layout()
        fig.savefig(figdir / "tracking-jitter.png", dpi=110)
        plt.close(fig)
    if "tones" in res:
        t = res["tones"]
        fig, ax = plt.subplots(figsize=(6, 4))
        f = np.logspace(-0.5, 2, 200)
        for r, mk in zip(t["runs"], "os^v"):
            ax.semilogx(t["tones_hz"], 20 * np.log10(r["gain"]), mk, label=r["run"])
        for bn in (3.0, 15.0):
            ax.semilogx(f, 20 * np.log10(np.abs(pll2_response(f, bn))), "k:", lw=0.8)
        for bw in (30.0, 100.0):
            h = pll2_response(f, 3.0)
            lp = 1 / (1 + 1j * f / bw)
            ax.semilogx(f, 20 * np.log10(np.abs(h + lp * (1 - h))), "k--", lw=0.8)
        ax.axhline(-3, color="grey", lw=0.6)
        ax.set_ylim(-30, 6)
        ax.set_xlabel("injected phase tone (Hz)")
        ax.set_ylabel("tracking gain |φ_NCO / φ_in| (dB)")
        ax.set_title("Tracking transfer by tone injection (lines: theory)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(figdir / "tracking-tones.png", dpi=110)
        plt.close(fig)
    if "oscillator" in res:
        o = res["oscillator"]
        fig, ax = plt.subplots(figsize=(6, 4))
        for osc, mk in zip(o["oscillators"], "os^"):
            rows = osc["rows"]
            line, = ax.plot([r["bn_hz"] for r in rows if not r["slips"]], [r["jitter_deg"] for r in rows if not r["slips"]],
                            mk, label=f"{osc['name']} measured")
            slipped = [r for r in rows if r["slips"]]
            if slipped:
                ax.plot([r["bn_hz"] for r in slipped], [r["jitter_deg"] for r in slipped], mk, mfc="none",
                        color=line.get_color(), label=f"{osc['name']} with cycle slips")
            ax.plot([r["bn_hz"] for r in rows], [r["predicted_deg"] for r in rows], "-", color=line.get_color(), lw=0.8,
                    label=f"{osc['name']} thermal + oscillator")
        ax.axhline(15, color="grey", lw=0.6)
        ax.set_yscale("log")
        ax.set_xlabel("PLL noise bandwidth B_n (Hz)")
        ax.set_ylabel("phase jitter (deg)")
        ax.set_title(f"Oscillator phase noise, {o['cn0_dbhz']:g} dB-Hz (grey: 15°, 3σ = 45°)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(figdir / "tracking-oscillator.png", dpi=110)
        plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="jitter,tones,oscillator,shared,slips")
    ap.add_argument("--figures-only", action="store_true", help="redraw the figures from docs/benchmarks/tracking-paper.json")
    args = ap.parse_args()
    studies = {"jitter": study_jitter, "tones": study_tones, "oscillator": study_oscillator, "shared": study_shared,
               "slips": study_slips}
    path = ROOT / "docs" / "benchmarks" / "tracking-paper.json"
    res = json.loads(path.read_text()) if path.exists() else {}
    for name in ([] if args.figures_only else args.only.split(",")):
        t0 = time.process_time()
        res[name] = studies[name]()
        res[name]["cpu_s"] = time.process_time() - t0
        path.write_text(json.dumps(res, indent=2) + "\n")
    figures(res, ROOT / "docs" / "figures")


if __name__ == "__main__":
    main()
