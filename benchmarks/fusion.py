#!/usr/bin/env python3
"""GNSS fused with accelerometers on a tower with modes from 0.05 to 5 Hz (issue 30 targets) →
docs/benchmarks/fusion.json (and a paragraph in docs/adding-a-sensor.md).

Per seed (library functions: the simulator, the measurement models, the engine's filter and smoother):

* truth — configs/tower-fusion.toml simulated at 100 Hz (free vibration, the config's process noise
  at scale 1, :func:`cdgps_cli.sim.structure.simulate`), its held disturbance recovered
  (:func:`cdgps_cli.sim.sensors.disturbance_truth`), the two accelerometers' logs at 100 Hz with
  noise, bias and bias drift as configured (:func:`cdgps_cli.sim.sensors.simulate_sensor_logs`);
* GNSS — the top antenna's position at 10 Hz with 2 cm white noise per axis (position domain,
  :class:`cdgps_cli.measurement.gnss_position.GnssPosition`);
* GNSS alone — the modal model (:class:`~cdgps_cli.model.dynamics_models.ModalZOH`) stepping at
  100 Hz, GNSS rows every 10th epoch, RTS smoothed;
* fused — GNSS + both accelerometers (:func:`cdgps_cli.pipeline.fusion.fusion_problem`: state
  [ξ, ξ̇, d, accelerometer biases]), RTS smoothed;
* errors of the top's x displacement (smoothed − truth): RMS in the band above 1 Hz, below 0.1 Hz
  (drift) and overall (FFT band split, after the first ``--settle`` seconds); NEES per dof of the
  modal states [ξ, ξ̇] (filtered and smoothed) and NIS per dof of the fused filter;
* modes — ``spectra``'s identification (:func:`cdgps_cli.analysis.spectra.compute_spectra`) on the
  fused and GNSS-alone estimates of the first ``--spectra-seeds`` seeds: error of each mode's
  frequency, %.

Example::

    python benchmarks/fusion.py                       # 20 seeds × 300 s (≈ 10–20 min on a loaded machine)
    python benchmarks/fusion.py --seeds 2 --duration 60 --out /tmp/fusion.json
    python benchmarks/fusion.py --dd-only 3 --dd-duration 120     # carrier-phase chain → fusion_dd.json

``--dd-only``: the same tower through the commands on simulated carrier phase (10 Hz receivers, 3 mm
phase noise, the modal model on the double differences), GNSS alone vs ``estimate --fuse accel``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.analysis.spectra import SpectraOptions, compute_spectra  # noqa: E402
from cdgps_cli.config.sensors import sensor_specs  # noqa: E402
from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.measurement.gnss_position import GnssPosition  # noqa: E402
from cdgps_cli.measurement.sensor import align_epochs  # noqa: E402
from cdgps_cli.measurement.stacked import Stacked  # noqa: E402
from cdgps_cli.model.dynamics_models import ModalZOH  # noqa: E402
from cdgps_cli.model.fusion_dynamics import ModalDisturbance  # noqa: E402
from cdgps_cli.model.kinematics import antenna_positions  # noqa: E402
from cdgps_cli.pipeline.fusion import fusion_problem, run_fused, sensor_parts  # noqa: E402
from cdgps_cli.sim.sensors import disturbance_truth, simulate_sensor_logs  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402

CONFIG = ROOT / "configs" / "tower-fusion.toml"
GNSS_SIGMA_M = 0.02
GNSS_STEP = 10                       # 10 Hz of the 100 Hz structure


def _band_rms(e: np.ndarray, fs: float, lo: float, hi: float) -> float:
    """RMS of the part of e (N,) between lo and hi Hz (FFT mask, mean removed only for lo > 0)."""
    E = np.fft.rfft(e)
    f = np.fft.rfftfreq(e.size, 1.0 / fs)
    E[(f < lo) | (f > hi)] = 0.0
    return float(np.sqrt(np.mean(np.fft.irfft(E, e.size) ** 2)))


def _prior(cfg) -> np.ndarray:
    """The simulator's initial-state distribution (free scenario) as the filters' prior covariance."""
    nm = cfg.n_modes
    amp = cfg.simulation["initial_modal_sigma"]
    w = 2 * np.pi * np.asarray(cfg.mode_frequency_hz)
    return np.diag(np.r_[np.full(nm, amp**2), (amp * w) ** 2])


def _nees(x, P, truth, nm2) -> float:
    e = x[:, :nm2] - truth[:, :nm2]
    Pm = P[:, :nm2, :nm2]
    return float(np.mean(np.einsum("ki,ki->k", e, np.linalg.solve(Pm, e[..., None])[..., 0])) / nm2)


def one_seed(cfg, specs, seed: int, duration_s: float, settle_s: float, spectra: bool) -> dict:
    sim = simulate(cfg, SimOptions(duration_s=duration_s, seed=seed, scenario="free"))
    t, x = sim.time_s, sim.x
    nm, nm2 = cfg.n_modes, 2 * cfg.n_modes
    x_aug = disturbance_truth(cfg, x)
    logs = simulate_sensor_logs(cfg, specs, t, x_aug, seed=seed)
    top = cfg.antenna_names.index("top")
    p = antenna_positions(cfg, sim.q)[:, top, :]
    p0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)))[0, top]
    rng = np.random.default_rng([seed, 7])
    tg = t[::GNSS_STEP]
    zg = p[::GNSS_STEP] - p0 + rng.standard_normal((tg.size, 3)) * GNSS_SIGMA_M
    gnss = GnssPosition(cfg, "top", zg, align_epochs(t, tg), GNSS_SIGMA_M)
    P0m = _prior(cfg)
    t0 = time.perf_counter()
    alone = run_fused(Stacked([("gnss", gnss)], nm2), ModalZOH(cfg), t, np.zeros(nm2), P0m, max_iterations=1)
    t_alone = time.perf_counter() - t0
    S = ModalDisturbance(cfg).S
    parts = sensor_parts(cfg, specs, logs, t, ("accel",), S=S)
    model, dyn, P0, names = fusion_problem(cfg, [("gnss", gnss)], parts, P0m)
    t0 = time.perf_counter()
    fused = run_fused(model, dyn, t, np.zeros(dyn.n), P0, max_iterations=1)
    t_fused = time.perf_counter() - t0
    U = np.asarray(cfg.mode_shapes)
    Jx = np.asarray(cfg.antenna_displacement)[top, 0]          # x displacement per coordinate at the top
    keep = t >= settle_s
    fs = 1.0 / cfg.sample_period_s
    out = {"seed": seed, "epochs": int(t.size), "filter_smoother_s": {"gnss_alone": t_alone, "fused": t_fused}}
    for name, r in (("gnss_alone", alone), ("fused", fused)):
        e = ((r.x[:, :nm] - x[:, :nm]) @ U.T @ Jx)[keep]
        out[name] = {"rms_above_1hz_m": _band_rms(e, fs, 1.0, fs / 2), "rms_below_0p1hz_m": _band_rms(e, fs, 0.0, 0.1),
                     "rms_m": float(np.sqrt(np.mean(e**2))),
                     "nees_per_dof_filtered": _nees(r.x_filt[keep], r.P_filt[keep], x[keep], nm2),
                     "nees_per_dof_smoothed": _nees(r.x[keep], r.P[keep], x[keep], nm2),
                     "nis_per_dof": float(np.nansum(r.nis) / r.nis_dof.sum())}
    out["state"] = ["xi", "xi_dot"] + names
    bias_err = {}
    for name, m in parts:
        tr = logs["_truth"][name]
        for j, f in enumerate(m.fields):
            bias_err[f"{name}:{f}"] = float(fused.x[-1, m.bias_offset + j] - tr[f"final_bias_{f}"])
    out["final_bias_error_m_s2"] = bias_err
    if spectra:
        opt = SpectraOptions()
        for name, r in (("gnss_alone", alone), ("fused", fused)):
            sp = compute_spectra(cfg, t, r.x[:, :nm] @ U.T, opt=opt)
            out[name]["modes"] = [{"mode": m["mode"], "model_hz": m["model_hz"], "identified_hz": m["gps_hz"],
                                   "error_pct": m["error_pct"], "seen": m["seen"]} for m in sp["modes"]]
        sp = compute_spectra(cfg, t, x[:, :nm] @ U.T, opt=opt)
        out["truth_modes"] = [{"mode": m["mode"], "identified_hz": m["gps_hz"], "error_pct": m["error_pct"]}
                              for m in sp["modes"]]
    return out


def summarize(runs: list) -> dict:
    def stat(key, sub):
        v = np.array([r[key][sub] for r in runs])
        return {"mean": float(v.mean()), "min": float(v.min()), "max": float(v.max())}
    s = {k: {m: stat(k, m) for m in ("rms_above_1hz_m", "rms_below_0p1hz_m", "rms_m", "nees_per_dof_filtered",
                                      "nees_per_dof_smoothed", "nis_per_dof")} for k in ("gnss_alone", "fused")}
    ratio = np.array([r["gnss_alone"]["rms_above_1hz_m"] / r["fused"]["rms_above_1hz_m"] for r in runs])
    low = np.array([r["fused"]["rms_below_0p1hz_m"] / r["gnss_alone"]["rms_below_0p1hz_m"] for r in runs])
    s["improvement_above_1hz"] = {"mean": float(ratio.mean()), "min": float(ratio.min()), "max": float(ratio.max())}
    s["fused_over_gnss_below_0p1hz"] = {"mean": float(low.mean()), "min": float(low.min()), "max": float(low.max())}
    nees = [r["fused"]["nees_per_dof_smoothed"] for r in runs]
    s["fused_nees_per_dof_in_0p8_1p25"] = int(sum(0.8 <= v <= 1.25 for v in nees))
    return s


def summarize_modes(runs: list) -> dict:
    """Largest |frequency error| (%) of each mode over the spectra seeds, fused, GNSS alone and the truth."""
    out = {}
    for key in ("fused", "gnss_alone"):
        ms = [m for r in runs for m in r[key]["modes"]]
        out[key] = {n: (max(abs(m["error_pct"]) for m in ms if m["mode"] == n and m["error_pct"] is not None)
                        if any(m["mode"] == n and m["error_pct"] is not None for m in ms) else None)
                    for n in dict.fromkeys(m["mode"] for m in ms)}
    tm = [m for r in runs for m in r["truth_modes"]]
    out["truth"] = {n: max(abs(m["error_pct"]) for m in tm if m["mode"] == n and m["error_pct"] is not None)
                    for n in dict.fromkeys(m["mode"] for m in tm)}
    return out


def dd_seed(seed: int, duration_s: float, settle_s: float, work: Path) -> dict:
    """The carrier-phase chain through the commands: simulate-gnss-structure (10 Hz receivers, 3 mm phase,
    100 Hz sensors), ingest, init, estimate --structure with and without --fuse accel; errors of the top's
    x displacement at the GNSS epochs (so both on the same 10 Hz samples: band 1–5 Hz) and evaluate's NEES."""
    import subprocess  # noqa: PLC0415

    import pandas as pd  # noqa: PLC0415

    from cdgps_cli.io.states import States  # noqa: PLC0415
    from cdgps_cli.pipeline.estimate_outputs import evaluate  # noqa: PLC0415

    d = work / f"dd{seed}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cdgps = [sys.executable, "-m", "cdgps_cli.cli.commands"]
    steps = [["simulate-gnss-structure", str(CONFIG), "--duration", str(duration_s), "--gnss-interval", "0.1",
              "--seed", str(seed), "-o", str(d)],
             ["ingest", "--config", str(d / "config.toml"), "-o", str(d / "run.mcap")],
             ["init", str(d / "run.mcap"), "-o", str(d / "init.json")],
             ["estimate", str(d / "run.mcap"), "--init", str(d / "init.json"), "--structure", str(CONFIG), "--smooth",
              "-o", str(d / "gnss.mcap")],
             ["estimate", str(d / "run.mcap"), "--init", str(d / "init.json"), "--structure", str(CONFIG), "--smooth",
              "--fuse", "accel", "-o", str(d / "fused.mcap")]]
    wall = []
    for st in steps:
        t0 = time.perf_counter()
        subprocess.run(cdgps + ["-q"] + st, check=True, env=env, cwd=ROOT)
        wall.append(time.perf_counter() - t0)
    cfg = load_config(CONFIG)
    from cdgps_cli.io.coordinate_columns import coordinate_table

    truth, _ = coordinate_table(pd.read_csv(d / "truth.csv"), cfg)      # q columns named with their units
    jx = np.asarray(cfg.antenna_displacement)[cfg.antenna_names.index("top"), 0]
    g = States(d / "gnss.mcap")
    t_g = g.time_s
    tq = truth["time_s"].to_numpy()
    q_true = truth[list(cfg.coord_names)].to_numpy()
    out = {"seed": seed, "wall_s": dict(zip(["simulate", "ingest", "init", "estimate_gnss", "estimate_fused"], wall))}
    for name in ("gnss", "fused"):
        st = States(d / f"{name}.mcap")
        k = np.searchsorted(st.time_s, t_g)
        q_est = st.q[k]
        e = (q_est - q_true[np.searchsorted(tq, t_g)]) @ jx
        keep = t_g >= t_g[0] + settle_s
        ev = evaluate(d, d / f"{name}.mcap", converge_s=settle_s)
        out[name] = {"epochs": int(st.time_s.size), "rms_above_1hz_m": _band_rms(e[keep], 10.0, 1.0, 5.0),
                     "rms_below_0p1hz_m": _band_rms(e[keep], 10.0, 0.0, 0.1), "rms_m": float(np.sqrt(np.mean(e[keep] ** 2))),
                     "nees_per_dof": ev["nees"]["mean"] / ev["nees"]["dof"]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--duration", type=float, default=300.0, help="record length per seed, s")
    ap.add_argument("--settle", type=float, default=30.0, help="errors and NEES after this many seconds")
    ap.add_argument("--spectra-seeds", type=int, default=2, help="further seeds, longer records, for the modes")
    ap.add_argument("--spectra-duration", type=float, default=1200.0, help="their record length, s")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "fusion.json"))
    ap.add_argument("--dd-only", type=int, default=0, metavar="SEEDS",
                    help="instead: the carrier-phase chain through the commands on SEEDS seeds → --dd-out")
    ap.add_argument("--dd-duration", type=float, default=120.0)
    ap.add_argument("--dd-out", default=str(ROOT / "docs" / "benchmarks" / "fusion_dd.json"))
    a = ap.parse_args()
    if a.dd_only:
        import tempfile  # noqa: PLC0415

        with tempfile.TemporaryDirectory() as tmp:
            runs = []
            for seed in range(a.dd_only):
                r = dd_seed(seed, a.dd_duration, a.settle, Path(tmp))
                runs.append(r)
                print(f"DD seed {seed}: 1-5 Hz {r['gnss']['rms_above_1hz_m'] * 1e3:.3f} → {r['fused']['rms_above_1hz_m'] * 1e3:.3f} mm, "
                      f"below 0.1 Hz {r['gnss']['rms_below_0p1hz_m'] * 1e3:.3f} → {r['fused']['rms_below_0p1hz_m'] * 1e3:.3f} mm, "
                      f"NEES/dof {r['gnss']['nees_per_dof']:.3f} → {r['fused']['nees_per_dof']:.3f}, wall {r['wall_s']}", flush=True)
        doc = {"benchmark": "benchmarks/fusion.py --dd-only", "config": "configs/tower-fusion.toml",
               "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%MZ"),
               "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "load_1min": os.getloadavg()[0]},
               "settings": {"seeds": a.dd_only, "duration_s": a.dd_duration, "settle_s": a.settle,
                            "gnss": "simulated L1 carrier phase + code, 10 Hz, sigma^2 = a^2 + b^2/sin^2 el, a = b = 3 mm",
                            "fused": "accel (both accelerometers, 100 Hz)",
                            "errors": "top x displacement at the GNSS epochs (10 Hz), band 1-5 Hz and below 0.1 Hz"},
               "summary": {k: {m: float(np.mean([r[k][m] for r in runs])) for m in
                               ("rms_above_1hz_m", "rms_below_0p1hz_m", "rms_m", "nees_per_dof")} for k in ("gnss", "fused")},
               "runs": runs}
        Path(a.dd_out).write_text(json.dumps(doc, indent=1) + "\n")
        print(json.dumps(doc["summary"], indent=1))
        return
    cfg = load_config(CONFIG)
    specs = [s for s in sensor_specs(cfg) if s.kind == "accel"]
    runs = []
    for seed in range(a.seeds):
        r = one_seed(cfg, specs, seed, a.duration, a.settle, False)
        runs.append(r)
        print(f"seed {seed}: above 1 Hz {r['gnss_alone']['rms_above_1hz_m'] * 1e3:.2f} → {r['fused']['rms_above_1hz_m'] * 1e3:.3f} mm, "
              f"below 0.1 Hz {r['gnss_alone']['rms_below_0p1hz_m'] * 1e3:.2f} → {r['fused']['rms_below_0p1hz_m'] * 1e3:.2f} mm, "
              f"NEES/dof {r['fused']['nees_per_dof_filtered']:.3f} (filtered) {r['fused']['nees_per_dof_smoothed']:.3f} "
              f"(smoothed), NIS/dof {r['fused']['nis_per_dof']:.3f}, {r['filter_smoother_s']['fused']:.1f} s", flush=True)
    spectra_runs = []
    for seed in range(1000, 1000 + a.spectra_seeds):
        r = one_seed(cfg, specs, seed, a.spectra_duration, a.settle, True)
        spectra_runs.append(r)
        print(f"spectra seed {seed}: fused " + ", ".join(f"{m['mode']} {m['error_pct']:+.3f} %" for m in r["fused"]["modes"])
              + "; GNSS alone " + ", ".join(f"{m['mode']} {m['error_pct']:+.3f} %" if m["error_pct"] is not None else f"{m['mode']} -"
                                          for m in r["gnss_alone"]["modes"]), flush=True)
    doc = {"benchmark": "benchmarks/fusion.py", "config": "configs/tower-fusion.toml",
           "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%MZ"),
           "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "load_1min": os.getloadavg()[0]},
           "settings": {"seeds": a.seeds, "duration_s": a.duration, "settle_s": a.settle, "gnss_sigma_m": GNSS_SIGMA_M,
                        "gnss_rate_hz": 100.0 / GNSS_STEP, "accelerometers": [s.name for s in specs],
                        "accelerometer_rate_hz": 1.0 / specs[0].sample_period_s,
                        "gnss_model": "position domain (top antenna, x y z), white"},
           "summary": summarize(runs), "modes": summarize_modes(spectra_runs),
           "settings_modes": {"seeds": list(range(1000, 1000 + a.spectra_seeds)), "duration_s": a.spectra_duration},
           "runs": runs, "spectra_runs": spectra_runs}
    Path(a.out).write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc["summary"], indent=1))


if __name__ == "__main__":
    main()
