#!/usr/bin/env python3
"""Accuracy of ``cdgps estimate`` on simulated truth, over several seeds → docs/estimate-accuracy.md.

Per seed (library functions, the same code as the CLI; runs built in memory, STATES written to a
temporary directory where ``evaluate`` is used):

* testbed consistency — 120 s free vibration, 2 cm phase noise (= the filter's σ), full process noise
  (disturbance scale 1), INIT on 0–60 s, filter on 60–120 s: NEES of the modal positions (mean, share
  of epochs in the per-epoch 95% interval), NIS per dof, share of epochs with all coordinates within
  3σ, RMS of the rigid angle; the same with ``--biases states`` (final bias errors);
* convergence — INIT state perturbed by 3σ in every state plus 2° on the rigid angle, covariance ×100:
  time until all coordinate errors are within 3σ (the filter's own σ) for 1 s, time until they are
  within 3σ of the unperturbed filter's σ for 1 s, and ``evaluate``'s NEES convergence time;
* the 1995 model — 60 s free run, 1 cm noise, INIT on 2.4 s without process noise: q1, q2 RMS error
  (deg, after 1 s) with biases fixed and as states;
* static test (Fig. 7) — scenario static, 2 mm noise, INIT on 0–60 s: mean and std of q6+q10 over the
  rest segment, with the filter σ from INIT (2 cm) and with σ = 2 mm, next to the steady-state
  prediction of the filter's own model; smoothed; in static mode (``--rest`` from the rest start,
  forward and smoothed; and declared 10 s early, during settling);
* cycle slip a3:PL2 +3 cycles at 80 s (same seed, so the INIT applies): time back within 3σ,
  time to the bias re-fix, final bias error (fixed and states); the same jump without a lock-counter
  reset (caught by the innovation test);
* outage of PL4 70–80 s: share of coordinate errors within 3σ during / after, max |error|/σ,
  NIS/dof after, re-acquired bias errors, re-initializations.

Example::

    python benchmarks/estimate_accuracy.py               # 5 seeds (≈ 3–6 min)
    python benchmarks/estimate_accuracy.py --seeds 2 --out /tmp/acc.md
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.linalg import solve_discrete_are, solve_discrete_lyapunov

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.model.dynamics import discrete_model  # noqa: E402
from cdgps_cli.estimation.filter import EstimateOptions, estimate  # noqa: E402
from cdgps_cli.estimation.initializer import InitOptions, initialize  # noqa: E402
from cdgps_cli.measurement.phase import all_channels, phase_model  # noqa: E402
from cdgps_cli.core.records import memory_run  # noqa: E402
from cdgps_cli.io.run import write_run  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, parse_outage, parse_slip, simulate, write_simulation  # noqa: E402
from cdgps_cli.pipeline.estimate_outputs import evaluate, write_states  # noqa: E402

TB = load_config(ROOT / "configs" / "testbed-1998-lumped.toml")
D2 = load_config(ROOT / "configs" / "teague-1995-2dof.toml")
SLIP = "a3:PL2:80.0:+3"
OUTAGE = "PL4:70:10"


def errors(cfg, sim, res):
    U = np.asarray(cfg.mode_shapes)
    nm = cfg.n_modes
    k = np.rint(res.time_s / cfg.sample_period_s).astype(int)
    err = res.x[:, :nm] @ U.T - sim.q[k]
    sig = np.sqrt(np.maximum(np.einsum("qi,nij,qj->nq", U, res.P[:, :nm, :nm], U), 0.0))
    return err, sig, res.time_s


def settle(t, ok, t_from, hold_s=1.0):
    w = int(round(hold_s / float(np.median(np.diff(t)))))
    for i in np.flatnonzero(t >= t_from - 1e-9):
        if i + w <= len(ok) and ok[i:i + w].all():
            return float(t[i] - t_from)
    return float("nan")


def truth_bias(sim):
    b = {(r["antenna"], r["transmitter"]): r["bias_m"] for r in sim.truth["biases"]}
    for s in sim.truth["slips"]:
        b[(s["antenna"], s["transmitter"])] = s["bias_m"]
    return b


def evaluate_result(sim, res, init, d: Path, name: str) -> dict:
    """write_simulation + RUN + STATES for one result and run ``evaluate`` on them."""
    sub = d / name
    write_simulation(sim, sub)
    write_run(sim.cfg, sub / "receiver.csv", sub / "run.mcap")
    write_states(res, sub / "run.mcap", init, json.dumps(init), sub / "states.mcap", {})
    return evaluate(sub, sub / "states.mcap")


def testbed_seed(seed: int, d: Path) -> dict:
    out = {}
    kw = dict(duration_s=120.0, seed=seed, phase_sigma_m=0.02, disturbance_scale=1.0)
    sim = simulate(TB, SimOptions(**kw))
    run = memory_run(TB, sim.receiver)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=60.0))
    out["init_fixed"] = init["n_fixed"]
    res = estimate(run, init, EstimateOptions())
    ev = evaluate_result(sim, res, init, d, f"free{seed}")
    out["nees_mean"] = ev["nees"]["mean"]
    out["nees_in95"] = ev["nees"]["fraction_in_interval"]
    out["nis_per_dof"] = ev["nis"]["mean_per_dof"]
    out["nis_in95"] = ev["nis"]["fraction_in_interval95"]
    out["within3"] = ev["within_3sigma_fraction"]
    out["rms_q10_deg"] = ev["rms_error_deg"]["q10"]
    out["rms_q6_deg"] = ev["rms_error_deg"]["q6"]
    out["events_free"] = len(res.events)
    rs = estimate(run, init, EstimateOptions(biases="states"))
    tb = truth_bias(sim)
    out["states_bias_max_mm"] = 1000 * max(abs(rs.biases[c] - tb[c]) for c in TB.channels)
    e, s, t = errors(TB, sim, rs)
    out["states_within3"] = float(np.mean(np.all(np.abs(e) <= 3 * s, axis=1)))

    # convergence from a perturbed INIT
    x0 = np.asarray(init["state"]["x"])
    P0 = np.asarray(init["state"]["P"])
    rng = np.random.default_rng(seed)
    U = np.asarray(TB.mode_shapes)
    j = int(np.flatnonzero(np.asarray(TB.mode_frequency_hz) == 0)[0])
    x = x0 + 3 * np.sqrt(np.diag(P0)) * rng.choice([-1.0, 1.0], x0.size)
    x[j] += np.radians(2.0) / U[TB.rigid_index, j]
    bad = dict(init, state=dict(init["state"], x=x.tolist(), P=(100 * P0).tolist()))
    rp = estimate(run, bad, EstimateOptions())
    e, s, t = errors(TB, sim, rp)
    _, s0, _ = errors(TB, sim, res)
    out["conv_own_s"] = settle(t, np.all(np.abs(e) <= 3 * s, axis=1), t[0])
    out["conv_nominal_s"] = settle(t, np.all(np.abs(e) <= 3 * s0, axis=1), t[0])
    out["conv_nees_s"] = evaluate_result(sim, rp, bad, d, f"pert{seed}")["convergence_s"]

    # cycle slip (same seed: identical data before 80 s, so the INIT applies)
    sl = parse_slip(SLIP)
    sim_s = simulate(TB, SimOptions(**kw, slips=[sl]))
    run_s = memory_run(TB, sim_s.receiver)
    tb_s = truth_bias(sim_s)
    for mode in ("fixed", "states"):
        r = estimate(run_s, init, EstimateOptions(biases=mode))
        e, s, t = errors(TB, sim_s, r)
        out[f"slip_{mode}_back_s"] = settle(t, np.all(np.abs(e) <= 3 * s, axis=1), sl.time_s)
        out[f"slip_{mode}_bias_mm"] = 1000 * (r.biases[(sl.antenna, sl.transmitter)] - tb_s[(sl.antenna, sl.transmitter)])
        out[f"slip_{mode}_event_ok"] = bool(r.events and r.events[0]["time_s"] == sl.time_s
                                            and r.events[0]["kind"] == "lock restart")
        refix = [ev["time_s"] for ev in r.events if ev["kind"] == "bias re-estimated"]
        out[f"slip_{mode}_refix_s"] = (refix[0] - sl.time_s) if refix else float("nan")
        after = t >= sl.time_s
        out[f"slip_{mode}_within3_after"] = float(np.mean(np.abs(e[after]) <= 3 * s[after]))
    rec = sim.receiver.copy()
    sel = (rec["time_s"] >= 90.0 - 1e-9) & (rec["antenna"] == "a5") & (rec["transmitter"] == "PL3")
    rec.loc[sel, "phase_cycles"] += 2
    r = estimate(memory_run(TB, rec), init, EstimateOptions())
    mine = [ev for ev in r.events if (ev["antenna"], ev["transmitter"]) == ("a5", "PL3")]
    out["unflagged_detected_s"] = (mine[0]["time_s"] - 90.0) if mine and mine[0]["kind"] == "innovation outlier" else float("nan")
    out["unflagged_bias_mm"] = 1000 * (r.biases[("a5", "PL3")] - tb[("a5", "PL3")] - 2 * TB.wavelength_m)
    out["unflagged_other_events"] = len(r.events) - len(mine)

    # outage
    o = parse_outage(OUTAGE)
    sim_o = simulate(TB, SimOptions(**kw, outages=[o]))
    run_o = memory_run(TB, sim_o.receiver)
    tb_o = truth_bias(sim_o)
    t_back = o.start_s + o.duration_s
    for mode in ("fixed", "states"):
        r = estimate(run_o, init, EstimateOptions(biases=mode))
        e, s, t = errors(TB, sim_o, r)
        during = (t >= o.start_s) & (t < t_back)
        after = t >= t_back
        out[f"out_{mode}_during"] = float(np.mean(np.abs(e[during]) <= 3 * s[during]))
        out[f"out_{mode}_after"] = float(np.mean(np.abs(e[after]) <= 3 * s[after]))
        out[f"out_{mode}_after_joint"] = float(np.mean(np.all(np.abs(e[after]) <= 3 * s[after], axis=1)))
        out[f"out_{mode}_max_ratio"] = float(np.max(np.abs(e) / s))
        out[f"out_{mode}_nis_after"] = float(np.nanmean(r.nis[after] / r.nis_dof[after]))
        out[f"out_{mode}_bias_max_mm"] = 1000 * max(abs(r.biases[(a, o.transmitter)] - tb_o[(a, o.transmitter)])
                                                   for a in TB.rover_names)
        out[f"out_{mode}_reinit"] = sum(ev["kind"] == "re-initialization" for ev in r.events)
    return out


def csv_prediction(sigma_filter: float, sigma_true: float) -> float:
    """Steady-state std (deg) of q6+q10 at rest predicted from the filter's own model (DARE + Lyapunov)."""
    m = discrete_model(TB)
    U = np.asarray(TB.mode_shapes)
    ant, tx = all_channels(TB)
    xr = np.zeros(TB.n_states)
    xr[:TB.n_modes] = np.linalg.pinv(U) @ np.radians(np.r_[np.zeros(9), -1.4])
    H = phase_model(TB, xr, ant, tx, jacobian=True)[1][0]
    Pp = solve_discrete_are(m.A.T, H.T, m.Q, sigma_filter**2 * np.eye(len(ant)))
    Pu = np.linalg.inv(np.linalg.inv(Pp) + H.T @ H / sigma_filter**2)
    K = Pu @ H.T / sigma_filter**2
    Pe = solve_discrete_lyapunov((np.eye(TB.n_states) - K @ H) @ m.A, sigma_true**2 * K @ K.T)
    c = U[5] + U[9]
    return float(np.degrees(np.sqrt(c @ Pe[:9, :9] @ c)))


def single_epoch_ls_csv_std(sigma: float) -> float:
    U = np.asarray(TB.mode_shapes)
    ant, tx = all_channels(TB)
    xr = np.zeros(TB.n_states)
    xr[:TB.n_modes] = np.linalg.pinv(U) @ np.radians(np.r_[np.zeros(9), -1.4])
    Hq = phase_model(TB, xr, ant, tx, jacobian=True)[1][0][:, :9]
    c = U[5] + U[9]
    return float(np.degrees(np.sqrt(sigma**2 * c @ np.linalg.inv(Hq.T @ Hq) @ c)))


def static_seed(seed: int) -> dict:
    sim = simulate(TB, SimOptions(duration_s=140.0, seed=seed, scenario="static", phase_sigma_m=0.002))
    run = memory_run(TB, sim.receiver)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=60.0))
    rest = [s for s in sim.truth["segments"] if s["kind"] == "rest"][0]
    out = {}
    U = np.asarray(TB.mode_shapes)
    t_rest = rest["start_s"]
    c = U[5] + U[9]
    for label, sm, smooth, segs in (("default", None, False, ()), ("2mm", 0.002, False, ()),
                                    ("smoothed", None, True, ()),
                                    ("rest", None, False, ((t_rest, np.inf),)),
                                    ("rest_smoothed", None, True, ((t_rest, np.inf),)),
                                    ("rest_early", None, False, ((t_rest - 10.0, np.inf),))):
        r = estimate(run, init, EstimateOptions(sigma_m=sm, smooth=smooth, rest_segments_s=segs))
        sel = (r.time_s >= rest["start_s"] - 1e-9) & (r.time_s <= rest["end_s"] + 1e-9)
        ang = np.degrees(r.x[sel, :9] @ c)
        sig = np.degrees(np.sqrt(np.einsum("i,nij,j->n", c, r.P[sel][:, :9, :9], c)))
        out[f"{label}_mean"] = float(ang.mean())
        out[f"{label}_std"] = float(ang.std())
        out[f"{label}_within_3sigma"] = float(np.mean(np.abs(ang + 1.4) < 3 * sig))
        out[f"{label}_events"] = len(r.events)
        out[f"{label}_broken"] = sum(e["kind"] in ("rest segment broken", "rest segment refused") for e in r.events)
    return out


def dof2_seed(seed: int) -> dict:
    sim = simulate(D2, SimOptions(duration_s=60.0, seed=seed, phase_sigma_m=0.01))
    run = memory_run(D2, sim.receiver)
    out = {}
    try:
        init = initialize(run, InitOptions(start_s=0.0, duration_s=2.4, process_noise=False))
    except Exception as exc:  # noqa: BLE001 - reported in the table
        return {"init": f"failed: {exc}"}
    out["init"] = init["integer_fixing"]
    tb = truth_bias(sim)
    for mode in ("fixed", "states"):
        r = estimate(run, init, EstimateOptions(biases=mode))
        e, s, t = errors(D2, sim, r)
        a = t >= t[0] + 1.0
        rms = np.degrees(np.sqrt(np.mean(e[a] ** 2, axis=0)))
        out[f"{mode}_q1"], out[f"{mode}_q2"] = float(rms[0]), float(rms[1])
        out[f"{mode}_bias_max_mm"] = 1000 * max(abs(r.biases[c] - tb[c]) for c in D2.channels)
        out[f"{mode}_events"] = len(r.events)
    return out


def fmt(v, spec=".3f"):
    if isinstance(v, float) and np.isnan(v):
        return "–"
    return format(v, spec)


def table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def summary_row(label, vals, spec=".3f"):
    v = np.array(vals, dtype=float)
    return [label, *[fmt(x, spec) for x in v], fmt(float(np.nanmean(v)), spec), fmt(float(np.nanmin(v)), spec),
            fmt(float(np.nanmax(v)), spec)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "estimate-accuracy.md")
    ap.add_argument("--static-seeds", type=int, default=30,
                    help="extra seeds (after the others) for the static-mode distribution (0: none)")
    a = ap.parse_args()
    seeds = list(range(a.first_seed, a.first_seed + a.seeds))
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        tbr = [testbed_seed(s, Path(d)) for s in seeds]
    st = [static_seed(s) for s in seeds]
    st_extra, st_refused = [], []
    for s_ in range(seeds[-1] + 1, seeds[-1] + 1 + a.static_seeds):
        try:
            st_extra.append(static_seed(s_))
        except Exception as exc:  # noqa: BLE001 - an INIT refusal is reported, not a crash
            st_refused.append((s_, str(exc).split(":")[0]))
    d2 = [dof2_seed(s) for s in seeds]
    elapsed = time.perf_counter() - t0
    hdr = ["figure", *[f"seed {s}" for s in seeds], "mean", "min", "max"]

    def col(rows, key):
        return [r.get(key, float("nan")) for r in rows]

    md = ["# Accuracy of `cdgps estimate` on simulated truth\n",
          f"Produced by `python benchmarks/estimate_accuracy.py --seeds {a.seeds}` on {datetime.date.today()} "
          f"({elapsed:.0f} s, Python {platform.python_version()}); seeds {seeds[0]}–{seeds[-1]}. Every run is "
          "simulated, initialized with `initialize` (batch + LAMBDA) on its own data and filtered with "
          "`estimate`; the slip and outage runs reuse the free-vibration run's seed, so their data before the "
          "injected event — and hence the INIT — are identical. σ means the filter's own reported 1-σ.\n"]

    md.append("## Testbed: consistency (120 s free vibration, 2 cm noise = filter σ, disturbance = process noise; "
              "INIT 0–60 s, filter 60–120 s)\n")
    md.append(table(hdr, [
        summary_row("NEES mean (dof 9)", col(tbr, "nees_mean"), ".2f"),
        summary_row("NEES: share of epochs in the 95% interval", col(tbr, "nees_in95")),
        summary_row("NIS per dof", col(tbr, "nis_per_dof")),
        summary_row("NIS: share in the 95% interval", col(tbr, "nis_in95")),
        summary_row("all 10 coordinates within 3σ (share of epochs)", col(tbr, "within3")),
        summary_row("RMS error q10 (deg)", col(tbr, "rms_q10_deg"), ".4f"),
        summary_row("RMS error q6 (deg)", col(tbr, "rms_q6_deg"), ".4f"),
        summary_row("events (free run)", col(tbr, "events_free"), ".0f"),
        summary_row("biases=states: max final bias error (mm)", col(tbr, "states_bias_max_mm"), ".2f"),
        summary_row("biases=states: all coordinates within 3σ", col(tbr, "states_within3")),
    ]))
    md.append("\nTargets: NEES mean within 0.6–1.5 × dof and ≥ 85% of epochs in the per-epoch 95% interval; "
              "NIS per dof 0.8–1.2; bias states within 1 cm.\n")

    md.append("## Convergence from a perturbed INIT (3σ on every state + 2° on the rigid angle, P × 100)\n")
    md.append(table(hdr, [
        summary_row("within 3σ (own σ), held 1 s: time (s)", col(tbr, "conv_own_s"), ".2f"),
        summary_row("within 3σ of the unperturbed filter's σ, held 1 s (s)", col(tbr, "conv_nominal_s"), ".2f"),
        summary_row("`evaluate` convergence: NEES < 99.9% bound for 1 s (s)", col(tbr, "conv_nees_s"), ".2f"),
    ]))
    md.append("\nThe paper: the EKF converged within 0.5–1 s. With 36 measurements per epoch the first update "
              "already brings the positions within 3σ of the (inflated) covariance; reaching the accuracy of the "
              "unperturbed filter takes a few seconds because the rates and the ×100 covariance are relearned "
              "through the dynamics.\n")

    md.append("## 1995 two-hub model (60 s, 1 cm noise, INIT on 2.4 s without process noise)\n")
    md.append(table(hdr, [
        summary_row("q1 RMS (deg), biases fixed", col(d2, "fixed_q1")),
        summary_row("q2 RMS (deg), biases fixed", col(d2, "fixed_q2")),
        summary_row("q1 RMS (deg), biases as states", col(d2, "states_q1")),
        summary_row("q2 RMS (deg), biases as states", col(d2, "states_q2")),
        summary_row("biases as states: max final bias error (mm)", col(d2, "states_bias_max_mm"), ".2f"),
    ]))
    md.append("\nINIT outcomes: " + "; ".join(f"seed {s}: {r.get('init')}" for s, r in zip(seeds, d2))
              + ". Paper figure: errors below 0.3°.\n")

    p20, p2 = csv_prediction(0.02, 0.002), csv_prediction(0.002, 0.002)
    md.append("## Static test (Fig. 7): 2 mm noise, rest at the surveyed q6+q10 = −1.4° (rest segment 80–140 s)\n")
    md.append(table(hdr, [
        summary_row("mean q6+q10 (deg), filter σ 2 cm (INIT's)", col(st, "default_mean"), ".4f"),
        summary_row("std q6+q10 (deg), filter σ 2 cm", col(st, "default_std"), ".4f"),
        summary_row("mean q6+q10 (deg), filter σ 2 mm", col(st, "2mm_mean"), ".4f"),
        summary_row("std q6+q10 (deg), filter σ 2 mm", col(st, "2mm_std"), ".4f"),
        summary_row("mean q6+q10 (deg), smoothed (--smooth), σ 2 cm", col(st, "smoothed_mean"), ".4f"),
        summary_row("std q6+q10 (deg), smoothed (--smooth), σ 2 cm", col(st, "smoothed_std"), ".4f"),
        summary_row("**static mode** (--rest 80:) mean q6+q10 (deg), forward filter", col(st, "rest_mean"), ".4f"),
        summary_row("**static mode** std q6+q10 (deg), forward filter", col(st, "rest_std"), ".4f"),
        summary_row("static mode: share of epochs with |error| < 3σ (filter's own σ)", col(st, "rest_within_3sigma"), ".3f"),
        summary_row("static mode + --smooth: mean q6+q10 (deg)", col(st, "rest_smoothed_mean"), ".4f"),
        summary_row("static mode + --smooth: std q6+q10 (deg)", col(st, "rest_smoothed_std"), ".4f"),
        summary_row("rest declared 10 s early (--rest 70:): std q6+q10 (deg), forward", col(st, "rest_early_std"), ".4f"),
        summary_row("rest declared 10 s early: rest refused or broken (events)", [float(v) for v in col(st, "rest_early_broken")], ".0f"),
    ]))
    md.append(f"\nPaper: mean −1.48° (survey −1.4°, within 0.1°), noise < 0.02° rms. The mean is met (errors "
              f"of a few thousandths of a degree) in every mode. **In static mode** (`--rest 80:`: zero-velocity "
              f"update and position-variance raise entering the rest segment, process noise × 0.05² inside it) the forward filter's noise is "
              f"{np.mean(col(st, 'rest_std')):.4f}° on average (max {np.max(col(st, 'rest_std')):.4f}°, "
              f"{sum(v < 0.02 for v in col(st, 'rest_std'))} of {len(st)} seeds below 0.02°), with errors inside "
              f"the filter's own 3σ in {100 * np.mean(col(st, 'rest_within_3sigma')):.1f} % of epochs (its σ is "
              f"conservative here: it weights the data at INIT's 2 cm, the data have 2 mm); a rest "
              f"declared 10 s too early (during settling) is refused or broken by the data and retried, and ends at "
              f"{np.mean(col(st, 'rest_early_std')):.4f}°. The kinematic filter (no `--rest`) does not reach the "
              f"figure with `configs/testbed-1998-lumped.toml`, and does what its model predicts: the steady-state "
              f"std of q6+q10 predicted from the filter's own gain (DARE) with a structure at rest and 2 mm "
              f"white noise is {p20:.4f}° with σ = 2 cm and {p2:.4f}° with σ = 2 mm, and a single-epoch least "
              f"squares from the 36 measurements gives {single_epoch_ls_csv_std(0.002):.4f}° — the config's "
              f"pseudolite geometry and its 0.5 modal process noise (which keeps the filter close to single-epoch) "
              f"set the floor. Reaching 0.02° needs about 10× less process-noise variance relative to R "
              f"(a tuning/geometry matter, not a code defect). The RTS smoother (`--smooth`, post-processing, "
              f"as the static report is usually run) averages both ways: "
              f"{np.mean(col(st, 'smoothed_std')):.4f}° on average, "
              f"{sum(v < 0.02 for v in col(st, 'smoothed_std'))} of {len(st)} seeds below 0.02°. Lowering the "
              f"process noise for the whole run (`--process-noise-scale`) does not help here: the filter then cannot "
              f"follow the settling motion before the rest segment and rings (tried 0.1–0.2 with σ 2 cm, "
              f"0.01–0.05 with σ 2 mm).\n")

    if a.static_seeds:
        ex = seeds[-1] + 1
        md.append(f"### Static mode over {a.static_seeds} more seeds ({ex}–{ex + a.static_seeds - 1})\n")
        md.append("| figure | runs | mean | max | runs below 0.02° |\n|---|---|---|---|---|")
        for label, key in (("kinematic forward filter", "default_std"), ("kinematic + --smooth", "smoothed_std"),
                           ("static mode (--rest 80:), forward", "rest_std"),
                           ("static mode + --smooth", "rest_smoothed_std"),
                           ("rest declared 10 s early (--rest 70:), forward", "rest_early_std")):
            v = np.array(col(st_extra, key))
            md.append(f"| std q6+q10 (deg), {label} | {v.size} | {v.mean():.4f} | {v.max():.4f} | {int((v < 0.02).sum())} |")
        md.append("\nMean q6+q10 error, static mode: max |mean + 1.4°| = "
                  f"{np.max(np.abs(np.array(col(st_extra, 'rest_mean')) + 1.4)):.4f}°. "
                  + (f"INIT refused (biases not observable: too little motion in 0–60 s) on seed(s) "
                     f"{', '.join(str(s_) for s_, _ in st_refused)}. " if st_refused else "")
                  + "A declaration made 10 s early is mostly refused until the estimated modal velocities pass "
                  "their test; on the slowest settling runs the velocities pass while a slow creep remains "
                  "(below the filter's 2 cm sigma), hence the larger maxima in that row.\n")

    md.append(f"## Cycle slip {SLIP} (after the INIT window)\n")
    md.append(table(hdr, [
        summary_row("event at the slip epoch (1 = yes), fixed", [float(v) for v in col(tbr, "slip_fixed_event_ok")], ".0f"),
        summary_row("back within 3σ, held 1 s (s after the slip), fixed", col(tbr, "slip_fixed_back_s"), ".2f"),
        summary_row("bias re-fixed (s after the slip), fixed", col(tbr, "slip_fixed_refix_s"), ".2f"),
        summary_row("final bias error (mm), fixed", col(tbr, "slip_fixed_bias_mm"), ".3f"),
        summary_row("coordinate errors within 3σ after the slip, fixed", col(tbr, "slip_fixed_within3_after")),
        summary_row("back within 3σ (s), biases as states", col(tbr, "slip_states_back_s"), ".2f"),
        summary_row("final bias error (mm), biases as states", col(tbr, "slip_states_bias_mm"), ".2f"),
        summary_row("unflagged 2-cycle jump a5/PL3 at 90 s: detected after (s)", col(tbr, "unflagged_detected_s"), ".2f"),
        summary_row("unflagged jump: final bias error (mm)", col(tbr, "unflagged_bias_mm"), ".3f"),
    ]))
    md.append("\nA lock restart drops the channel's bias at once (the other 35 channels carry the estimate), "
              "re-estimates it from the prediction over 10 epochs and re-fixes the integer.\n")

    md.append(f"## Outage {OUTAGE} (all six channels of PL4 lost for 10 s)\n")
    md.append(table(hdr, [
        summary_row("coordinate errors within 3σ during, fixed", col(tbr, "out_fixed_during")),
        summary_row("coordinate errors within 3σ after, fixed", col(tbr, "out_fixed_after")),
        summary_row("all coordinates jointly within 3σ after, fixed", col(tbr, "out_fixed_after_joint")),
        summary_row("max error/σ over the run (any coordinate), fixed", col(tbr, "out_fixed_max_ratio"), ".2f"),
        summary_row("NIS per dof after, fixed", col(tbr, "out_fixed_nis_after")),
        summary_row("re-acquired bias max error (mm), fixed", col(tbr, "out_fixed_bias_max_mm"), ".3f"),
        summary_row("re-initializations, fixed", col(tbr, "out_fixed_reinit"), ".0f"),
        summary_row("coordinate errors within 3σ after, states", col(tbr, "out_states_after")),
        summary_row("re-acquired bias max error (mm), states", col(tbr, "out_states_bias_max_mm"), ".2f"),
        summary_row("re-initializations, states", col(tbr, "out_states_reinit"), ".0f"),
    ]))
    md.append("\nShares of coordinate errors are over (epoch, coordinate) pairs; \"jointly\" requires all 10 "
              "coordinates of an epoch within 3σ (≈ 97% expected for a consistent filter).\n")
    md.append("## Raw numbers\n\n```json\n" + json.dumps({"seeds": seeds, "testbed": tbr, "static": st, "dof2": d2},
                                                         indent=1, default=float) + "\n```\n")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    # sections written by other benchmarks (between their markers, e.g. rest_detection.py) are kept
    if a.out.exists():
        old = a.out.read_text()
        for m in re.finditer(r"<!-- (\S+): begin -->.*?<!-- \1: end -->\n", old, re.S):
            md.insert(len(md) - 1, m.group(0))
    a.out.write_text("\n".join(md))
    print("\n".join(md[:-1]))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
