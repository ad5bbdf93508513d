#!/usr/bin/env python3
"""Cross-check of ``cdgps spectra`` modal identification against an established OMA package (pyOMA2).

For each seed: a 20-minute free-vibration testbed run through the full pipeline, exactly as a user
runs it (``cdgps simulate`` → ``ingest`` → ``init`` → ``estimate --smooth`` → ``spectra --gyro``,
each a subprocess); then pyOMA2 (PyPI ``pyoma-2``) on the same estimated coordinates q1…q9 read from
STATES.mcap:

* SSI-cov (covariance-driven stochastic subspace identification): data standardized per channel,
  decimated 10 → 2 Hz (pyOMA2 ``decimate_data(q=5)``), ``br=80`` block rows (40 s of lags, > 2
  periods of the 0.059 Hz mode), model orders 2…60 step 2, pyOMA2's stability labels.  pyOMA2's own
  ``mpe(sel_freq=…, order_in="find_min")`` matches poles to a frequency with an *absolute* ±rtol Hz
  window (0.05 Hz by default, wider than the 0.132/0.135/0.138 Hz cluster), so the mode pairing is
  done here instead: for each model mode, pyOMA2's stable poles within ±8 % of the model frequency
  whose shape has MAC ≥ 0.8 with the model shape; frequency and damping are their medians over the
  model orders (a stabilization-diagram estimate).
* EFDD (pyOMA2 ``EFDD``, Welch 1024-sample segments at 2 Hz, ``mpe(sel_freq=model, DF1=0.01,
  DF2=0.02, MAClim=0.85)``): first-singular-value peak picking, shown for reference — it cannot
  separate the close cluster by construction.
* The same SSI-cov on the simulator truth q over the same span: the identification scatter of a
  20-minute record without any GPS estimation error.

Then (``--synthetic N``) both methods on N records of exact stationary modal responses (each mode an
independent SDOF process with the model's f and ζ, q = U ξ, same length): the bias of each
estimator against known values, with no transient, no GPS and no model mismatch.

Writes docs/spectra-accuracy.md (tables + how it was produced) and prints the tables::

    python benchmarks/oma_crosscheck.py                      # seeds 7,1,2,3,4,5,6,8 + 10 synthetic (≈ 8 min)
    python benchmarks/oma_crosscheck.py --seeds 7 --workdir /tmp/oma
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.io.coordinate_columns import coordinate_table  # noqa: E402
from cdgps_cli.analysis.spectra import mac  # noqa: E402
from cdgps_cli.io.states import States  # noqa: E402

CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"
DECIMATE = 5
BR = 80
ORDMAX = 60
STEP = 2
BAND = 0.08
MAC_MIN = 0.8
DEFAULT_SEEDS = "7,1,2,3,4,5,6,8"
DEFAULT_SYNTHETIC = 10


def cdgps(*args) -> str:
    cmd = [sys.executable, "-m", "cdgps_cli.cli.commands", "--quiet", *map(str, args)]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{p.stderr}")
    return p.stdout


def pipeline(d: Path, seed: int, duration: float) -> dict:
    d.mkdir(parents=True, exist_ok=True)
    if not (d / "spectra" / "peaks.json").exists():
        cdgps("simulate", CONFIG, "--duration", duration, "--seed", seed, "--scenario", "free", "-o", d / "sim")
        cdgps("ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", CONFIG, "-o", d / "run.mcap")
        cdgps("init", d / "run.mcap", "-o", d / "init.json")
        cdgps("estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "-o", d / "states.mcap")
        cdgps("spectra", d / "states.mcap", "--gyro", d / "run.mcap", "-o", d / "spectra")
    return json.loads((d / "spectra" / "peaks.json").read_text())


def pyoma_ssi(Y: np.ndarray, fs: float, Um: np.ndarray, fm: np.ndarray) -> list[dict]:
    """pyOMA2 SSI-cov on standardized Y; each model mode paired with stable poles by frequency and MAC."""
    from pyoma2.algorithms import SSI
    from pyoma2.setup import SingleSetup

    ss = SingleSetup(Y, fs=fs)
    ss.decimate_data(q=DECIMATE)
    alg = SSI(name="SSIcov", method="cov", br=BR, ordmax=ORDMAX, step=STEP)
    ss.add_algorithms(alg)
    ss.run_all()
    r = alg.result
    Fn, Xi, Phi, Lab = r.Fn_poles, r.Xi_poles, r.Phi_poles, r.Lab
    out = []
    for j in range(len(fm)):
        cand = []
        for o in range(Fn.shape[1]):
            for i in range(Fn.shape[0]):
                f = Fn[i, o]
                if Lab[i, o] != 1 or not np.isfinite(f) or abs(f - fm[j]) > BAND * fm[j]:
                    continue
                m = mac(Phi[i, o], Um[:, j].astype(complex))
                if m >= MAC_MIN:
                    cand.append((f, Xi[i, o], m))
        if cand:
            c = np.array(cand)
            out.append({"hz": float(np.median(c[:, 0])), "damping": float(np.median(c[:, 1])),
                        "mac": float(np.median(c[:, 2])), "poles": len(c)})
        else:
            out.append({"hz": None, "damping": None, "mac": None, "poles": 0})
    return out


def pyoma_efdd(Y: np.ndarray, fs: float, Um: np.ndarray, fm: np.ndarray) -> list[dict]:
    from pyoma2.algorithms import EFDD
    from pyoma2.setup import SingleSetup

    ss = SingleSetup(Y, fs=fs)
    ss.decimate_data(q=DECIMATE)
    alg = EFDD(name="EFDD", nxseg=1024, method_SD="per", pov=0.5)
    ss.add_algorithms(alg)
    ss.run_all()
    ss.mpe("EFDD", sel_freq=[float(f) for f in fm], DF1=0.01, DF2=0.02, cm=1, MAClim=0.85, sppk=1, npmax=15)
    r = alg.result
    return [{"hz": float(r.Fn[j]), "damping": float(r.Xi[j]), "mac": mac(r.Phi[:, j], Um[:, j].astype(complex)),
             "resolution_hz": float(r.freq[1] - r.freq[0])} for j in range(len(fm))]


def stationary_modes(cfg, n: int, rng) -> np.ndarray:
    """Exact stationary modal responses: each elastic mode an independent SDOF process (ZOH-discretized,
    white modal acceleration, 2000 s burn-in), q = U ξ.  No transient, no GPS, no other error."""
    from scipy.signal import cont2discrete, lfilter, ss2tf

    T = cfg.sample_period_s
    burn = int(round(2000 / T))
    U = np.asarray(cfg.mode_shapes)
    xi = np.zeros((n, U.shape[1]))
    for j, (f, tau) in enumerate(zip(cfg.mode_frequency_hz, cfg.mode_time_constant_s)):
        if f <= 0:
            continue
        w, z = 2 * np.pi * f, 1.0 / (2 * np.pi * f * tau)
        Ad, Bd, *_ = cont2discrete((np.array([[0, 1], [-w * w, -2 * z * w]]), np.array([[0], [1.0]]), np.eye(2),
                                    np.zeros((2, 1))), T)
        b, a = ss2tf(Ad, Bd, np.array([[1.0, 0.0]]), np.zeros((1, 1)))
        xi[:, j] = lfilter(b[0], a, rng.standard_normal(n + burn))[burn:]
        xi[:, j] /= xi[:, j].std()
    return xi @ U.T


def synthetic_check(cfg, runs: int, n: int) -> dict:
    """cdgps compute_spectra and pyOMA2 SSI-cov on the same exact stationary data (known f, ζ)."""
    from cdgps_cli.analysis.spectra import SpectraOptions, compute_spectra

    rng = np.random.default_rng(2024)
    sel = [i for i in range(cfg.n_q) if i != cfg.rigid_index]
    elastic = [j for j, f in enumerate(cfg.mode_frequency_hz) if f > 0]
    fm = np.asarray(cfg.mode_frequency_hz)[elastic]
    zm = 1.0 / (2 * np.pi * fm * np.asarray(cfg.mode_time_constant_s)[elastic])
    t = np.round(np.arange(n) * cfg.sample_period_s, 9)
    rows = {k: [] for k in ("cd_f", "cd_z", "ssi_f", "ssi_z", "cd_seen")}
    for _ in range(runs):
        q = stationary_modes(cfg, n, rng)
        res = compute_spectra(cfg, t, q, opt=SpectraOptions())
        Y = q[:, sel]
        std = Y.std(axis=0)
        ssi = pyoma_ssi(Y / std, 1.0 / cfg.sample_period_s, np.asarray(cfg.mode_shapes)[np.ix_(sel, elastic)] / std[:, None], fm)
        rows["cd_f"].append([m["error_pct"] for m in res["modes"]])
        rows["cd_z"].append([m["damping"] / zm[k] if m["damping"] else np.nan for k, m in enumerate(res["modes"])])
        rows["cd_seen"].append([m["seen"] for m in res["modes"]])
        rows["ssi_f"].append([np.nan if x["hz"] is None else 100 * (x["hz"] - fm[k]) / fm[k] for k, x in enumerate(ssi)])
        rows["ssi_z"].append([np.nan if x["damping"] is None else x["damping"] / zm[k] for k, x in enumerate(ssi)])
    A = {k: np.array(v, dtype=float) for k, v in rows.items()}
    out = []
    for k, j in enumerate(elastic):
        def col(name):
            v = A[name][:, k]
            return v[np.isfinite(v)]
        out.append({"mode": cfg.mode_names[j], "model_hz": float(fm[k]), "model_damping": float(zm[k]),
                    "cdgps_err_mean": float(np.mean(col("cd_f"))), "cdgps_err_sd": float(np.std(col("cd_f"), ddof=1)),
                    "ssi_err_mean": float(np.mean(col("ssi_f"))) if col("ssi_f").size else None,
                    "ssi_err_sd": float(np.std(col("ssi_f"), ddof=1)) if col("ssi_f").size > 1 else None,
                    "ssi_found": int(col("ssi_f").size),
                    "cdgps_damping_ratio_median": float(np.median(col("cd_z"))),
                    "cdgps_damping_ratio_iqr": [float(x) for x in np.percentile(col("cd_z"), [25, 75])],
                    "ssi_damping_ratio_median": float(np.median(col("ssi_z"))) if col("ssi_z").size else None,
                    "ssi_damping_ratio_iqr": [float(x) for x in np.percentile(col("ssi_z"), [25, 75])] if col("ssi_z").size else None,
                    "cdgps_seen": int(A["cd_seen"][:, k].sum())})
    return {"runs": runs, "seconds": n * cfg.sample_period_s, "modes": out}


def synthetic_table(syn: dict) -> str:
    head = ("| mode | model Hz | model ζ | cdgps err % mean ± sd | SSI err % mean ± sd (found) | cdgps ζ / model: median [IQR] "
            "| SSI ζ / model: median [IQR] | cdgps seen |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for m in syn["modes"]:
        si = "–" if m["ssi_err_mean"] is None else f"{m['ssi_err_mean']:+.2f} ± {m['ssi_err_sd'] or 0:.2f} ({m['ssi_found']}/{syn['runs']})"
        sz = "–" if m["ssi_damping_ratio_median"] is None else (
            f"{m['ssi_damping_ratio_median']:.2f} [{m['ssi_damping_ratio_iqr'][0]:.2f}, {m['ssi_damping_ratio_iqr'][1]:.2f}]")
        lines.append(f"| {m['mode']} | {m['model_hz']:.3f} | {m['model_damping']:.4f} | {m['cdgps_err_mean']:+.2f} ± {m['cdgps_err_sd']:.2f} "
                     f"| {si} | {m['cdgps_damping_ratio_median']:.2f} [{m['cdgps_damping_ratio_iqr'][0]:.2f}, "
                     f"{m['cdgps_damping_ratio_iqr'][1]:.2f}] | {sz} | {m['cdgps_seen']}/{syn['runs']} |")
    return "\n".join(lines)


def err(v, ref):
    return None if v is None else 100.0 * (v - ref) / ref


def f4(v, spec=".4f"):
    return "–" if v is None else format(v, spec)


def analyse_seed(d: Path, seed: int, duration: float, cfg) -> dict:
    t = time.perf_counter()
    peaks = pipeline(d, seed, duration)
    t_pipe = time.perf_counter() - t
    st = States(d / "states.mcap", diagnostics=False)
    sel = [i for i in range(cfg.n_q) if i != cfg.rigid_index]
    elastic = [j for j, f in enumerate(cfg.mode_frequency_hz) if f > 0]
    fm = np.asarray(cfg.mode_frequency_hz)[elastic]
    zm = 1.0 / (2 * np.pi * fm * np.asarray(cfg.mode_time_constant_s)[elastic])
    Y = st.q[:, sel]
    std = Y.std(axis=0)
    Um = np.asarray(cfg.mode_shapes)[np.ix_(sel, elastic)] / std[:, None]
    t = time.perf_counter()
    ssi = pyoma_ssi(Y / std, 1.0 / cfg.sample_period_s, Um, fm)
    t_ssi = time.perf_counter() - t
    efdd = pyoma_efdd(Y / std, 1.0 / cfg.sample_period_s, Um, fm)
    # SSI on the truth over the same epochs
    truth, _ = coordinate_table(pd.read_csv(d / "sim" / "truth.csv"), cfg)   # q1_m, q2_rad … → bare names
    tt = np.rint(truth["time_s"].to_numpy() * 1e6).astype(np.int64)
    keep = np.isin(tt, np.rint(st.time_s * 1e6).astype(np.int64))
    Yt = truth[[cfg.coord_names[i] for i in sel]].to_numpy()[keep]
    stdt = Yt.std(axis=0)
    ssi_truth = pyoma_ssi(Yt / stdt, 1.0 / cfg.sample_period_s, np.asarray(cfg.mode_shapes)[np.ix_(sel, elastic)] / stdt[:, None], fm)
    modes = []
    pk = {m["mode"]: m for m in peaks["modes"]}
    for k, j in enumerate(elastic):
        name = cfg.mode_names[j]
        c = pk[name]
        modes.append({"mode": name, "model_hz": float(fm[k]), "model_damping": float(zm[k]),
                      "cdgps_hz": c["gps_hz"], "cdgps_err_pct": c["error_pct"], "cdgps_damping": c["damping"],
                      "cdgps_damping_sigma": c.get("damping_sigma"),
                      "cdgps_mac": c["mac"], "cdgps_seen": c["seen"], "cdgps_sigma_hz": c.get("gps_hz_sigma"),
                      "cdgps_damping_limited": c.get("damping_resolution_limited"),
                      "ssi_hz": ssi[k]["hz"], "ssi_err_pct": err(ssi[k]["hz"], fm[k]), "ssi_damping": ssi[k]["damping"],
                      "ssi_mac": ssi[k]["mac"], "ssi_poles": ssi[k]["poles"],
                      "efdd_hz": efdd[k]["hz"], "efdd_err_pct": err(efdd[k]["hz"], fm[k]), "efdd_damping": efdd[k]["damping"],
                      "efdd_mac": efdd[k]["mac"],
                      "ssi_truth_hz": ssi_truth[k]["hz"], "ssi_truth_err_pct": err(ssi_truth[k]["hz"], fm[k]),
                      "ssi_truth_damping": ssi_truth[k]["damping"]})
    return {"seed": seed, "modes": modes, "pipeline_s": round(t_pipe, 1), "pyoma_ssi_s": round(t_ssi, 2),
            "epochs": int(len(st.time_s)), "span_s": [float(st.time_s[0]), float(st.time_s[-1])],
            "settings": peaks["settings"], "efdd_resolution_hz": efdd[0]["resolution_hz"]}


def detail_table(r: dict) -> str:
    head = ("| mode | model Hz | model ζ | cdgps Hz | err % | cdgps ζ | MAC | pyOMA2 SSI Hz | err % | SSI ζ | MAC "
            "| pyOMA2 EFDD Hz | err % | EFDD ζ | MAC | SSI on truth Hz | err % | ζ |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for m in r["modes"]:
        lines.append("| " + " | ".join([
            m["mode"], f"{m['model_hz']:.3f}", f"{m['model_damping']:.4f}",
            f4(m["cdgps_hz"]), f4(m["cdgps_err_pct"], "+.2f"), f4(m["cdgps_damping"]), f4(m["cdgps_mac"], ".2f"),
            f4(m["ssi_hz"]), f4(m["ssi_err_pct"], "+.2f"), f4(m["ssi_damping"]), f4(m["ssi_mac"], ".2f"),
            f4(m["efdd_hz"]), f4(m["efdd_err_pct"], "+.2f"), f4(m["efdd_damping"]), f4(m["efdd_mac"], ".2f"),
            f4(m["ssi_truth_hz"]), f4(m["ssi_truth_err_pct"], "+.2f"), f4(m["ssi_truth_damping"])]) + " |")
    return "\n".join(lines)


def summary_table(results: list[dict]) -> tuple[str, dict]:
    names = [m["mode"] for m in results[0]["modes"]]
    head = ("| mode | model Hz | model ζ | cdgps err % mean ± sd | SSI err % mean ± sd | SSI-on-truth err % mean ± sd "
            "| mean abs(cdgps − SSI) % | cdgps ζ / model (median) | SSI ζ / model (median) | cdgps seen |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    summ = {}

    def ms(v):
        v = [x for x in v if x is not None]
        return (np.mean(v), np.std(v, ddof=1) if len(v) > 1 else 0.0, len(v)) if v else (None, None, 0)

    for k, name in enumerate(names):
        rows = [r["modes"][k] for r in results]
        ce, se, te = ms([m["cdgps_err_pct"] for m in rows]), ms([m["ssi_err_pct"] for m in rows]), ms([m["ssi_truth_err_pct"] for m in rows])
        diff = [abs(m["cdgps_hz"] - m["ssi_hz"]) / m["model_hz"] * 100 for m in rows if m["cdgps_hz"] and m["ssi_hz"]]
        cz = [m["cdgps_damping"] / m["model_damping"] for m in rows if m["cdgps_damping"]]
        sz = [m["ssi_damping"] / m["model_damping"] for m in rows if m["ssi_damping"]]
        seen = sum(bool(m["cdgps_seen"]) for m in rows)

        def fmt(t):
            return "–" if t[0] is None else f"{t[0]:+.2f} ± {t[1]:.2f} (n={t[2]})"
        lines.append(f"| {name} | {rows[0]['model_hz']:.3f} | {rows[0]['model_damping']:.4f} | {fmt(ce)} | {fmt(se)} | {fmt(te)} "
                     f"| {np.mean(diff):.2f} | {np.median(cz):.2f} | {np.median(sz) if sz else float('nan'):.2f} | {seen}/{len(rows)} |")
        summ[name] = {"cdgps_err_mean": ce[0], "cdgps_err_sd": ce[1], "ssi_err_mean": se[0], "ssi_err_sd": se[1],
                      "ssi_truth_err_mean": te[0], "ssi_truth_err_sd": te[1], "mean_abs_cdgps_minus_ssi_pct": float(np.mean(diff)),
                      "cdgps_damping_ratio_median": float(np.median(cz)), "ssi_damping_ratio_median": float(np.median(sz)) if sz else None,
                      "cdgps_seen": seen, "runs": len(rows)}
    return "\n".join(lines), summ


def findings(results: list[dict], summ: dict, syn: dict | None) -> str:
    """Statements computed from the numbers (so they stay true when the script is rerun)."""
    allm = [m for r in results for m in r["modes"]]
    both = [m for m in allm if m["ssi_hz"] is not None and m["ssi_truth_hz"] is not None]
    gps_effect = [abs(m["ssi_hz"] - m["ssi_truth_hz"]) / m["model_hz"] * 100 for m in both]

    def rms(v):
        v = [x for x in v if x is not None]
        return float(np.sqrt(np.mean(np.square(v)))) if v else float("nan")
    non_pend = [m for m in allm if m["mode"] != "pendulum"]
    lines = [
        f"* **GPS estimation error is negligible for the modes.** pyOMA2 SSI-cov on the *estimated* coordinates and on "
        f"the *true* coordinates give frequencies that differ by {np.mean(gps_effect):.2f} % on average "
        f"(max {np.max(gps_effect):.2f} %, {len(gps_effect)} mode-runs): the 1 cm phase noise after the filter and smoother "
        f"does not limit the identification; the record length does.",
        f"* **Frequencies: no bias, scatter comparable to SSI.** RMS frequency error over all seeds, the pendulum excluded: "
        f"cdgps {rms([m['cdgps_err_pct'] for m in non_pend]):.2f} %, pyOMA2 SSI-cov {rms([m['ssi_err_pct'] for m in non_pend]):.2f} % "
        f"(same data), SSI on truth {rms([m['ssi_truth_err_pct'] for m in non_pend]):.2f} %. Pendulum (ζ = 0.135, half-power "
        f"bandwidth 0.016 Hz): cdgps {rms([m['cdgps_err_pct'] for m in allm if m['mode'] == 'pendulum']):.2f} %, "
        f"SSI {rms([m['ssi_err_pct'] for m in allm if m['mode'] == 'pendulum']):.2f} % RMS, SSI on truth "
        f"{rms([m['ssi_truth_err_pct'] for m in allm if m['mode'] == 'pendulum']):.2f} % — a heavily damped mode scatters by "
        f"percents in 20 minutes whatever the method. cdgps's own 1-σ for it (Fisher information of its likelihood) has a "
        f"median of {np.median([100 * m['cdgps_sigma_hz'] / m['model_hz'] for m in allm if m['mode'] == 'pendulum' and m['cdgps_sigma_hz']]):.2f} %"
        f", so a 2 % tolerance is about ±{2 / np.median([100 * m['cdgps_sigma_hz'] / m['model_hz'] for m in allm if m['mode'] == 'pendulum' and m['cdgps_sigma_hz']]):.1f} σ; "
        f"within 2 %: cdgps {sum(1 for m in allm if m['mode'] == 'pendulum' and m['cdgps_err_pct'] is not None and abs(m['cdgps_err_pct']) <= 2)}"
        f"/{sum(1 for m in allm if m['mode'] == 'pendulum')} runs, every other mode "
        f"{sum(1 for m in non_pend if m['cdgps_err_pct'] is not None and abs(m['cdgps_err_pct']) <= 2)}/{len(non_pend)} mode-runs.",
    ]
    zs = [(m["cdgps_hz"] - m["model_hz"]) / m["cdgps_sigma_hz"] for m in allm
          if m.get("cdgps_hz") is not None and m.get("cdgps_sigma_hz")]
    if zs:
        lines.append(f"* **cdgps's frequency 1-σ is calibrated**: RMS of (identified − model) / σ over {len(zs)} mode-runs = "
                     f"{rms(zs):.2f} (1 expected).")
    seen_txt = ", ".join(f"{n} {v['cdgps_seen']}/{v['runs']}" for n, v in summ.items() if v["cdgps_seen"] < v["runs"])
    ssi_found = {n: sum(1 for r in results for m in r["modes"] if m["mode"] == n and m["ssi_hz"] is not None) for n in summ}
    lines.append(
        "* **Close cluster (0.132 / 0.135 / 0.138 Hz).** cdgps identifies a frequency for every mode in every run (modal "
        "filter + single-mode fit); \"seen\" also needs the FDD singular vector to match the model shape (MAC ≥ 0.6): "
        f"seen in {seen_txt + ' runs' if seen_txt else 'every run'}"
        f"{', every other mode in every run' if seen_txt else ''}. pyOMA2 SSI-cov found a stable pole with MAC ≥ {MAC_MIN} "
        f"for twist-2 in {ssi_found.get('twist-2', 0)}/{len(results)} runs, bending-1 {ssi_found.get('bending-1', 0)}/{len(results)}, "
        f"bending-2 {ssi_found.get('bending-2', 0)}/{len(results)}. pyOMA2 EFDD (first singular value only) returns the same "
        "peak for the cluster — see its MACs in the seed table.")
    dz = {n: (v["cdgps_damping_ratio_median"], v["ssi_damping_ratio_median"]) for n, v in summ.items()}
    low = [n for n, (c, q) in dz.items() if c < 0.8 and q is not None and 0.85 <= q <= 1.25]
    lines.append(
        "* **Damping is much less certain than frequency** (median ratio identified / model, cdgps vs SSI: "
        + ", ".join(f"{n} {c:.2f} vs {'–' if q is None else format(q, '.2f')}" for n, (c, q) in dz.items()) + "). "
        + (f"cdgps's median reads low for {', '.join(low)}, where SSI's does not; cdgps's own 1-σ of ζ there is large "
           "(median " + ", ".join(
               f"{n} {np.median([m['cdgps_damping_sigma'] / m['model_damping'] * 100 for m in allm if m['mode'] == n and m.get('cdgps_damping_sigma')]):.0f} %"
               for n in low) + " of the model's ζ; 8 runs give a median to about ±1.25·σ/√8)" + (
               "; on exact stationary data (below) the same estimator's median ratio is " + ", ".join(
                   f"{n} {m['cdgps_damping_ratio_median']:.2f}" for n, m in
                   ((n, next(mm for mm in syn['modes'] if mm['mode'] == n)) for n in low)) if syn else "") + "." if low else ""))
    if syn:
        sm = {m["mode"]: m for m in syn["modes"]}
        low_s = [n for n, m in sm.items() if m["cdgps_damping_ratio_median"] < 0.8 and m["ssi_damping_ratio_median"] is not None
                 and 0.85 <= m["ssi_damping_ratio_median"] <= 1.25]
        lines.append(
            f"* **On exact stationary data** (table below: {syn['runs']} runs, {syn['seconds']:.0f} s, no transient, no GPS) "
            "cdgps damping median ratio / SSI: " + ", ".join(
                f"{n} {m['cdgps_damping_ratio_median']:.2f} / {'–' if m['ssi_damping_ratio_median'] is None else format(m['ssi_damping_ratio_median'], '.2f')}"
                for n, m in sm.items()) + ". "
            + (f"The low damping of {', '.join(low_s)} persists there, so it comes from the cdgps estimator, not from "
               "the data or the GPS." if low_s else "No systematic low damping there (the likelihood models the record's "
               "finite resolution, so lightly damped modes are not biased)."))
    return "\n".join(lines)


def write_doc(path: Path, results: list[dict], summ_md: str, summ: dict, syn: dict | None, args, elapsed: float) -> None:
    import scipy

    first = results[0]
    s = first["settings"]
    try:
        from importlib.metadata import version
        pv = version("pyoma-2")
    except Exception:  # pragma: no cover
        pv = "?"
    seeds = ", ".join(str(r["seed"]) for r in results)
    cmd = "python benchmarks/oma_crosscheck.py" + ("" if args.seeds == DEFAULT_SEEDS else f" --seeds {args.seeds}") + (
        "" if args.synthetic == DEFAULT_SYNTHETIC else f" --synthetic {args.synthetic}")
    syn_md = ""
    if syn:
        syn_md = f"""
## Exact stationary data: cdgps vs SSI against known frequency and damping

{syn['runs']} runs of {syn['seconds']:.0f} s (the length the spectra see above): every elastic mode an independent
stationary SDOF process with the model's frequency and damping (ZOH-discretized, white modal acceleration, 2000 s
burn-in, unit variance), q = U ξ — no initial transient, no disturbance mismatch, no GPS. cdgps is
`compute_spectra` with its defaults; SSI-cov as above.

{synthetic_table(syn)}
"""
    text = f"""# Accuracy of `cdgps spectra` modal identification, cross-checked with pyOMA2

Generated by `{cmd}` ({time.strftime('%Y-%m-%d')}, {elapsed / 60:.1f} min on a {os.cpu_count()}-CPU machine;
Python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, pyOMA2 {pv} — installed
with `pip install pyoma-2`, a benchmark-only dependency, not a dependency of cdgps).

## What was run

For each seed ({seeds}): a {args.duration / 60:g}-minute free-vibration run of the 1998 testbed model
(`configs/testbed-1998-lumped.toml`, 10 Hz, config defaults: 1 cm white phase noise, disturbance 0.2 × process noise,
random modal initial conditions) through the whole pipeline as a user runs it, each stage a `cdgps` subprocess:

```sh
cdgps simulate configs/testbed-1998-lumped.toml --duration {args.duration:g} --seed SEED --scenario free -o sim
cdgps ingest sim/receiver.csv sim/gyro.csv --config configs/testbed-1998-lumped.toml -o run.mcap
cdgps init run.mcap -o init.json
cdgps estimate run.mcap --init init.json --smooth -o states.mcap
cdgps spectra states.mcap --gyro run.mcap -o spectra        # → peaks.json: the "cdgps" columns
```

The estimate starts at the end of the 60 s INIT window, so the spectra see {first['epochs']} epochs
({first['span_s'][0]:g}–{first['span_s'][1]:g} s). cdgps settings (defaults): Welch/FDD segment
{s['segment_s']:.0f} s, {s['segments']} segments, Hann, 50 % overlap, 4× zero padding, resolution {s['resolution_hz']:.4f} Hz;
frequency and damping (with their 1-σ) from the single-mode maximum-likelihood (debiased Whittle) fit to the
periodogram of the modal-filter output over the whole record, MAC from FDD.

**pyOMA2** on the same estimated coordinates q1…q9 read from `states.mcap` (the rigid-body q10 excluded, as in
cdgps), each channel standardized:

* **SSI-cov** (`pyoma2.algorithms.SSI(method="cov", br={BR}, ordmax={ORDMAX}, step={STEP})`) after
  `decimate_data(q={DECIMATE})` (10 → 2 Hz; the highest mode is 0.28 Hz). pyOMA2's own
  `mpe(sel_freq, order_in="find_min")` matches a pole to a selected frequency within an *absolute*
  ±`rtol` Hz (0.05 Hz by default) — wider than the 0.132 / 0.135 / 0.138 Hz cluster — so the pairing
  with the model is done in the benchmark: for each model mode, pyOMA2's *stable* poles (its `Lab == 1`)
  within ±{BAND * 100:g} % of the model frequency whose mode shape has MAC ≥ {MAC_MIN} with the model shape;
  frequency and damping are the medians over the model orders where such a pole exists ("–": none).
* **EFDD** (`pyoma2.algorithms.EFDD(nxseg=1024, method_SD="per")`, resolution {first['efdd_resolution_hz']:.4f} Hz,
  `mpe(sel_freq=model frequencies, DF1=0.01, DF2=0.02, MAClim=0.85)`): peak picking on the first singular
  value — it cannot separate the close cluster by construction (its twist-2 / bending-2 MACs show it).
* **SSI on truth**: the same SSI-cov on the simulator's true coordinates over the same epochs — the
  identification scatter of a {args.duration / 60:g}-minute record with no GPS estimation error at all.

Errors are (identified − model) / model. ζ is the modal damping ratio; the model's is 1 / (2π f τ).

## Seed {first['seed']}: every method on the same data

{detail_table(first)}

## All seeds ({seeds}): bias and scatter

{summ_md}

## Findings

{findings(results, summ, syn)}
{syn_md}
Raw per-seed numbers: rerun with `--json FILE`.
"""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default=DEFAULT_SEEDS, help="comma-separated; the first gets the detailed table")
    ap.add_argument("--synthetic", type=int, default=DEFAULT_SYNTHETIC, help="runs of the exact-stationary check (0: skip)")
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--workdir", type=Path, default=None, help="keep / reuse pipeline outputs here")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "spectra-accuracy.md")
    ap.add_argument("--json", type=Path, default=None, help="also write the raw results as JSON")
    args = ap.parse_args(argv)
    os.environ["TQDM_DISABLE"] = "1"
    try:
        import pyoma2.algorithms  # noqa: F401
        import pyoma2.setup  # noqa: F401
    except ImportError:
        raise SystemExit("pyOMA2 is needed: pip install pyoma-2")
    logging.disable(logging.INFO)                  # pyOMA2 logs every step at INFO
    cfg = load_config(CONFIG)
    tmp = None
    if args.workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="oma_")
        work = Path(tmp.name)
    else:
        work = args.workdir
    t0 = time.perf_counter()
    results = []
    for seed in [int(s) for s in args.seeds.split(",")]:
        r = analyse_seed(work / f"seed{seed}", seed, args.duration, cfg)
        results.append(r)
        print(f"seed {seed}: pipeline {r['pipeline_s']:.0f} s, pyOMA2 SSI {r['pyoma_ssi_s']:.1f} s", flush=True)
        for m in r["modes"]:
            print(f"  {m['mode']:<10} model {m['model_hz']:.3f}  cdgps {f4(m['cdgps_hz'])} ({f4(m['cdgps_err_pct'], '+.2f')}%) "
                  f"ζ {f4(m['cdgps_damping'])}  SSI {f4(m['ssi_hz'])} ({f4(m['ssi_err_pct'], '+.2f')}%) ζ {f4(m['ssi_damping'])}"
                  f"  truth-SSI {f4(m['ssi_truth_err_pct'], '+.2f')}%  model ζ {m['model_damping']:.4f}", flush=True)
    summ_md, summ = summary_table(results)
    print(summ_md)
    syn = None
    if args.synthetic > 0:
        syn = synthetic_check(cfg, args.synthetic, results[0]["epochs"])
        print(synthetic_table(syn))
    print(findings(results, summ, syn))
    elapsed = time.perf_counter() - t0
    write_doc(args.out, results, summ_md, summ, syn, args, elapsed)
    if args.json:
        args.json.write_text(json.dumps({"results": results, "summary": summ, "synthetic": syn}, indent=2, default=float) + "\n")
    print(f"wrote {args.out} ({elapsed / 60:.1f} min)")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
