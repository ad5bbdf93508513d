#!/usr/bin/env python3
"""Benchmark of ``cdgps estimate``: forward EKF rate, smoother cost, one hour end to end.

(a) Forward filter epochs/s on the testbed (18 states, 36 measurements per epoch), 10 min of 10 Hz
    data after a 60 s INIT window, against FilterPy's ``ExtendedKalmanFilter`` on the same model and
    data: F = A, Q = B_w W B_wᵀ, R = σ² I, ``HJacobian``/``Hx`` from ``EpochPhaseModel`` with the INIT
    biases subtracted from the measurement (FilterPy calls HJacobian and Hx separately at the same
    state; the model is evaluated once and h is cached, so both filters evaluate it once per epoch).
    Also FilterPy with a trivial precomputed h/H (the filter mechanics alone) and the measurement
    model alone.  Both filters run on the same data and must agree (max |Δx| printed).  cdgps runs its
    compiled kernel (``cdgps_cli.estimation._ekfcore``) when it is built, and is also timed on its pure-numpy path
    (``CDGPS_NO_KERNEL=1``); the report says which path the headline figure used.
(b) Smoother: ``rts_smooth`` on the filtered arrays vs the forward filter time, and
    estimate(smooth=True) vs estimate(smooth=False).
(c) One hour of 10 Hz data end to end (``cdgps estimate --smooth``: read RUN.mcap, filter, smooth,
    write STATES.mcap) in a subprocess: wall time and peak RSS; a second instrumented subprocess gives
    the stage breakdown (peak RSS is cumulative: the peak reached by the end of that stage).

Targets (issue 4): (a) ≥ 4× FilterPy, (b) smoother ≤ 2× filter, (c) peak RSS < 500 MB.  Timings are
best-of-``--repeat`` in this process (the machine may be shared), with a single-threaded BLAS for
every filter (cdgps's own default; set before numpy is imported).  Writes
docs/benchmarks/estimate.json and prints a table.  Needs FilterPy (``pip install filterpy``)::

    python benchmarks/bench_estimate.py                 # full (≈ 2–3 min)
    python benchmarks/bench_estimate.py --quick         # smoke: 2 min of data, 10 min "hour"
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# the BLAS setting cdgps_cli applies on import, here before numpy is imported by anyone, so that
# FilterPy and both cdgps paths run with the same (single-threaded) BLAS
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.estimation import kernel as ekf_kernel  # noqa: E402
from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.model.dynamics import discrete_model  # noqa: E402
from cdgps_cli.estimation.filter import EstimateOptions, estimate, rts_smooth  # noqa: E402
from cdgps_cli.estimation.initializer import InitOptions, initialize  # noqa: E402
from cdgps_cli.measurement.phase import EpochPhaseModel, channel_indices  # noqa: E402
from cdgps_cli.io.run import Run  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402

CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"
SIGMA = 0.02          # the config's measurement sigma; simulated with the same noise


def best_of(fn, repeat):
    """(best wall time, last result) over ``repeat`` calls."""
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def numpy_path(fn):
    """Call fn with cdgps forced onto its pure-numpy path (CDGPS_NO_KERNEL=1)."""
    old = os.environ.get("CDGPS_NO_KERNEL")
    os.environ["CDGPS_NO_KERNEL"] = "1"
    try:
        return fn()
    finally:
        if old is None:
            del os.environ["CDGPS_NO_KERNEL"]
        else:
            os.environ["CDGPS_NO_KERNEL"] = old


def filterpy_run(cfg, init, Z, hmodel, precomputed=None, sigma_m=SIGMA):
    """FilterPy EKF over Z (N, C) = λ·phase − INIT bias; returns the filtered states (N, n)."""
    from filterpy.kalman import ExtendedKalmanFilter

    m = discrete_model(cfg)
    N, C = Z.shape
    n = cfg.n_states
    f = ExtendedKalmanFilter(dim_x=n, dim_z=C)
    f.F = m.A
    f.Q = m.Q
    f.R = np.diag(np.broadcast_to(np.asarray(sigma_m, dtype=float) ** 2, (C,)).copy())   # scalar or per channel
    f.x = np.array(init["state"]["x"], dtype=float)
    f.P = np.array(init["state"]["P"], dtype=float)
    xs = np.empty((N, n))
    if precomputed is None:
        cache = {}

        def HJacobian(x):
            h, H = hmodel(x)
            cache["h"] = h
            return H

        def Hx(x):
            return cache["h"]

        for k in range(N):
            if k:
                f.predict()
            f.update(Z[k], HJacobian, Hx)
            xs[k] = f.x
    else:
        hs, Hs = precomputed
        for k in range(N):
            if k:
                f.predict()
            f.update(Z[k], lambda x, k=k: Hs[k], lambda x, k=k: hs[k])
            xs[k] = f.x
    return xs


def part_ab(minutes: float, repeat: int, seed: int) -> dict:
    cfg = load_config(CONFIG)
    sim = simulate(cfg, SimOptions(duration_s=60.0 + 60.0 * minutes, seed=seed, phase_sigma_m=SIGMA,
                                   disturbance_scale=1.0))
    acts = pd.DataFrame({"time_s": pd.Series([], dtype=float), "actuator": pd.Series([], dtype=object),
                         "force_n": pd.Series([], dtype=float)})
    run = Run("<bench>", cfg, sim.receiver.reset_index(drop=True), sim.gyro, acts, {})
    init = initialize(run, InitOptions(start_s=0.0, duration_s=60.0))
    # the filter alone: INIT without its "window" entry, i.e. its state is a prior at the window end,
    # as FilterPy takes it (estimate() would otherwise also recompute the window's 601 batch states
    # and report them, and skip the update at the window end, so neither time nor states compared)
    init = {k: v for k, v in init.items() if k != "window"}
    path = ekf_kernel.path_name()
    t_ours, res = best_of(lambda: estimate(run, init, EstimateOptions()), repeat)
    N = len(res.time_s)
    assert res.events == [], res.events
    assert res.filter_path == path
    t_np, res_np = numpy_path(lambda: best_of(lambda: estimate(run, init, EstimateOptions()), repeat))
    assert res_np.filter_path == "numpy"

    # the same data for FilterPy: Z = λ·phase − bias, channels in the filter's order
    chans = res.channels
    ph = run.phase.take(run.phase["time_s"] >= res.time_s[0] - 1e-9)
    C = len(chans)
    assert len(ph) == N * C and list(zip(ph["antenna"][:C], ph["transmitter"][:C])) == chans
    bias = {(b["antenna"], b["transmitter"]): b["bias_m"] for b in init["biases"] if b["current"]}
    Z = ph["phase_cycles"].reshape(N, C) * cfg.wavelength_m - np.array([bias[c] for c in chans])
    ant, tx = channel_indices(cfg, [c[0] for c in chans], [c[1] for c in chans])
    hmodel = EpochPhaseModel(cfg, ant, tx)

    # the σ cdgps used, per channel (INIT's per-channel estimate, or the innovation-based re-run's)
    sig = np.array([pc["sigma_m"] for pc in res.noise["per_channel"]])
    t_fp, xs_fp = best_of(lambda: filterpy_run(cfg, init, Z, hmodel, sigma_m=sig), repeat)
    pre = ([], [])
    for k in range(N):
        h, H = hmodel(res.x[k])
        pre[0].append(h)
        pre[1].append(H)
    t_fp_triv, _ = best_of(lambda: filterpy_run(cfg, init, Z, hmodel, precomputed=pre, sigma_m=sig), repeat)
    t_model, _ = best_of(lambda: [hmodel(res.x[k]) for k in range(N)], repeat)

    # (b) smoother
    m = discrete_model(cfg)
    U_in = np.zeros((N, m.B.shape[1]))
    t_rts, _ = best_of(lambda: rts_smooth(m.A, m.Q, m.B, U_in, res.x, res.P), repeat)
    t_both, res_s = best_of(lambda: estimate(run, init, EstimateOptions(smooth=True)), repeat)
    t_both_np, res_s_np = numpy_path(lambda: best_of(lambda: estimate(run, init, EstimateOptions(smooth=True)), repeat))
    return {
        "data": {"minutes": minutes, "epochs": N, "states": res.x.shape[1], "measurements_per_epoch": C,
                 "seed": seed, "phase_sigma_m": SIGMA},
        "forward_filter": {
            "cdgps_path": path,
            "cdgps_s": t_ours, "cdgps_epochs_per_s": N / t_ours,
            "cdgps_numpy_path_s": t_np, "cdgps_numpy_path_epochs_per_s": N / t_np,
            "max_abs_state_difference_kernel_vs_numpy_path": float(np.max(np.abs(res.x - res_np.x))),
            "max_abs_covariance_difference_kernel_vs_numpy_path": float(np.max(np.abs(res.P - res_np.P))),
            "filterpy_s": t_fp, "filterpy_epochs_per_s": N / t_fp,
            "ratio_cdgps_over_filterpy": t_fp / t_ours,
            "ratio_cdgps_numpy_path_over_filterpy": t_fp / t_np,
            "filterpy_trivial_h_s": t_fp_triv, "filterpy_trivial_h_epochs_per_s": N / t_fp_triv,
            "measurement_model_only_epochs_per_s": N / t_model,
            "max_abs_state_difference_cdgps_vs_filterpy": float(np.max(np.abs(xs_fp - res.x))),
            "target_ratio": 4.0,
        },
        "smoother": {
            "path": path,
            "rts_smooth_s": t_rts, "ratio_rts_over_filter": t_rts / t_ours,
            "estimate_smooth_s": t_both, "ratio_estimate_smooth_over_filter": t_both / t_ours,
            "estimate_smooth_numpy_path_s": t_both_np,
            "ratio_estimate_smooth_over_filter_numpy_path": t_both_np / t_np,
            "max_abs_smoothed_state_difference_kernel_vs_numpy_path": float(np.max(np.abs(res_s.x - res_s_np.x))),
            "target_ratio": 2.0,
        },
    }


PEAK_RSS = """
def peak_rss_mib():
    # VmHWM: peak RSS of this process image.  (ru_maxrss is not used: Linux carries the parent's
    # high-water mark over fork/exec into the child's ru_maxrss, which would count the benchmark's own
    # memory.)
    try:
        with open('/proc/self/status') as fh:
            for line in fh:
                if line.startswith('VmHWM:'):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
"""


def run_measured(code: str) -> tuple[float, float, str]:
    """Run a Python snippet in a fresh process; return (seconds, peak RSS MiB, stderr)."""
    wrapped = (
        "import sys, time\n"
        f"{PEAK_RSS}\n"
        "__t = time.perf_counter()\n"
        f"{code}\n"
        "print('__BENCH__', time.perf_counter() - __t, peak_rss_mib(), file=sys.stderr)\n"
    )
    p = subprocess.run([sys.executable, "-c", wrapped], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    if p.returncode != 0:
        raise SystemExit(p.stderr)
    line = [ln for ln in p.stderr.splitlines() if ln.startswith("__BENCH__")][-1]
    _, dt, rss = line.split()
    return float(dt), float(rss), p.stderr


def cli_code(args: list[str]) -> str:
    return f"from cdgps_cli.cli.commands import main\nmain({args!r}, standalone_mode=False)"


STAGES = """
import json
def mark(name, t0):
    print('__STAGE__', name, time.perf_counter() - t0, peak_rss_mib(), file=sys.stderr)
    return time.perf_counter()
t = time.perf_counter()
t = mark('python start', __t)
from cdgps_cli.estimation.filter import EstimateOptions, estimate
from cdgps_cli.io.run import read_run
from cdgps_cli.pipeline.estimate_outputs import write_states
t = mark('import', t)
run = read_run({run!r})
t = mark('read RUN.mcap', t)
text = open({init!r}).read()
init = json.loads(text)
opt = EstimateOptions(smooth=False)
res = estimate(run, init, opt)
t = mark('filter', t)
del res
opt = EstimateOptions(smooth=True)
res = estimate(run, init, opt)
t = mark('filter + smooth', t)
write_states(res, {run!r}, init, text, {out!r}, opt.echo())
t = mark('write STATES.mcap', t)
"""


def part_c(hours: float, seed: int) -> dict:
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        t0 = time.perf_counter()
        run_measured(cli_code(["--quiet", "simulate", str(CONFIG), "--duration", str(3600 * hours), "--seed", str(seed),
                               "--noise-m", str(SIGMA), "--disturbance-scale", "1", "-o", str(d / "sim")]))
        run_measured(cli_code(["--quiet", "ingest", str(d / "sim" / "receiver.csv"), "--config", str(CONFIG),
                               "-o", str(d / "run.mcap")]))
        run_measured(cli_code(["--quiet", "init", str(d / "run.mcap"), "--start", "0", "--duration", "60",
                               "-o", str(d / "init.json")]))
        setup_s = time.perf_counter() - t0
        wall, rss, _ = run_measured(cli_code(["--quiet", "estimate", str(d / "run.mcap"), "--init", str(d / "init.json"),
                                              "--smooth", "-o", str(d / "states.mcap")]))
        epochs = int(round(3600 * hours / 0.1)) + 1 - 600
        states_mib = (d / "states.mcap").stat().st_size / 2**20
        run_mib = (d / "run.mcap").stat().st_size / 2**20
        _, _, err = run_measured(STAGES.format(run=str(d / "run.mcap"), init=str(d / "init.json"),
                                               out=str(d / "states2.mcap")))
        stages = []
        for ln in err.splitlines():
            if ln.startswith("__STAGE__"):
                parts = ln.split()
                stages.append({"stage": " ".join(parts[1:-2]), "s": float(parts[-2]), "peak_rss_mib_so_far": float(parts[-1])})
    return {"hours": hours, "epochs": epochs, "path": ekf_kernel.path_name(), "run_mcap_mib": round(run_mib, 1), "states_mcap_mib": round(states_mib, 1),
            "estimate_smooth_wall_s": wall, "estimate_smooth_peak_rss_mib": rss, "setup_s": setup_s,
            "stages": stages, "target_peak_rss_mib": 500}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="data for (a) and (b), minutes after INIT")
    ap.add_argument("--hours", type=float, default=1.0, help="data for (c)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="smoke run: 2 min for (a)/(b), 10 min for (c), 1 repeat")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "estimate.json")
    a = ap.parse_args()
    if a.quick:
        a.minutes, a.hours, a.repeat = 2.0, 1.0 / 6.0, 1
    e2e = part_c(a.hours, a.seed)            # first, while this process is small
    res = part_ab(a.minutes, a.repeat, a.seed)
    res["end_to_end"] = e2e
    import filterpy
    res["machine"] = {"python": platform.python_version(), "numpy": np.__version__, "filterpy": filterpy.__version__,
                      "cpus": os.cpu_count(), "platform": platform.platform(),
                      "load_average_at_end": list(os.getloadavg())}
    res["date"] = time.strftime("%Y-%m-%d")
    res["command"] = "python benchmarks/bench_estimate.py" + (" --quick" if a.quick else "")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=2) + "\n")

    f, s, e = res["forward_filter"], res["smoother"], res["end_to_end"]
    dd = res["data"]
    print(f"(a) forward filter, testbed, {dd['epochs']} epochs ({dd['minutes']:g} min), {dd['states']} states, "
          f"{dd['measurements_per_epoch']} measurements/epoch")
    print(f"    {'cdgps estimate (filter only), ' + f['cdgps_path'] + ' path':38s} {f['cdgps_epochs_per_s']:9.0f} epochs/s  "
          f"({f['cdgps_s']:.3f} s)")
    print(f"    {'cdgps estimate (filter only), numpy path':38s} {f['cdgps_numpy_path_epochs_per_s']:9.0f} epochs/s  "
          f"({f['cdgps_numpy_path_s']:.3f} s; max |Δx| vs {f['cdgps_path']} "
          f"{f['max_abs_state_difference_kernel_vs_numpy_path']:.1e})")
    print(f"    {'FilterPy EKF, EpochPhaseModel h/H':38s} {f['filterpy_epochs_per_s']:9.0f} epochs/s  ({f['filterpy_s']:.2f} s)")
    print(f"    {'FilterPy EKF, precomputed h/H':38s} {f['filterpy_trivial_h_epochs_per_s']:9.0f} epochs/s")
    print(f"    {'measurement model alone':38s} {f['measurement_model_only_epochs_per_s']:9.0f} epochs/s")
    print(f"    ratio cdgps ({f['cdgps_path']} path) / FilterPy = {f['ratio_cdgps_over_filterpy']:.2f}× (target ≥ 4×: "
          f"{'met' if f['ratio_cdgps_over_filterpy'] >= 4 else 'NOT met'}); max |Δx| = "
          f"{f['max_abs_state_difference_cdgps_vs_filterpy']:.1e}")
    print(f"(b) smoother ({s['path']} path): rts_smooth {s['rts_smooth_s']:.3f} s = {s['ratio_rts_over_filter']:.2f}× the "
          f"filter; estimate --smooth {s['ratio_estimate_smooth_over_filter']:.2f}× (target ≤ 2×: "
          f"{'met' if s['ratio_estimate_smooth_over_filter'] <= 2 else 'NOT met'}); numpy path "
          f"{s['ratio_estimate_smooth_over_filter_numpy_path']:.2f}×")
    print(f"(c) {e['hours']:g} h end to end ({e['epochs']} epochs, RUN {e['run_mcap_mib']} MiB → STATES "
          f"{e['states_mcap_mib']} MiB): {e['estimate_smooth_wall_s']:.1f} s, peak RSS "
          f"{e['estimate_smooth_peak_rss_mib']:.0f} MiB (target < 500: "
          f"{'met' if e['estimate_smooth_peak_rss_mib'] < 500 else 'NOT met'})")
    for st in e["stages"]:
        print(f"    {st['stage']:22s} {st['s']:6.2f} s   peak so far {st['peak_rss_mib_so_far']:6.0f} MiB")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
