#!/usr/bin/env python3
"""Benchmark of the modal filter on a GNSS run (issue 13 item 3: "the modal filter ≥ 20× faster than
today's numpy path in the same run").

``cdgps simulate-gnss-structure`` of configs/gnss-tower.toml (default 1200 s at 1 Hz, seed 0) →
ingest → init; then :func:`cdgps_cli.pipeline.gnss_modal.gnss_modal_estimate` once, capturing the
filter's inputs (the satellite-DD model with its tables, the modal dynamics, the epochs, the start).
On those same inputs, in this process, best of ``--repeat``:

* **numpy** — :func:`cdgps_cli.estimation.model_filter.filter_numpy`: the iterated EKF that
  ``gnss_modal_estimate`` ran before (rows built per epoch, D Σ Dᵀ and its Cholesky factor per
  epoch, information-form update on the whitened rows; the same arithmetic, moved);
* **kernel** — :func:`cdgps_cli.estimation.model_filter.filter_dd_kernel`: every epoch's rows
  packed at once (vectorized) and the compiled whitened full-noise path ``_ekfcore.dd_span``;
  packing included in its time.

Both must agree (max |Δx| printed).  Single-threaded BLAS (cdgps's default).  Writes
docs/benchmarks/gnss_modal.json::

    python benchmarks/bench_gnss_modal.py [--duration 1200] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from click.testing import CliRunner  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.cli.commands import main  # noqa: E402
from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.estimation import kernel, model_filter  # noqa: E402
from cdgps_cli.io.gnss_run import read_gnss_run  # noqa: E402
from cdgps_cli.pipeline import gnss_modal  # noqa: E402


def _cli(*args):
    r = CliRunner().invoke(main, ["-q", *map(str, args)])
    if r.exit_code != 0:
        raise SystemExit(f"cdgps {' '.join(map(str, args))} failed:\n{r.output}")


def capture_inputs(tmp: Path, duration_s: float, seed: int):
    cfg = load_config(ROOT / "configs" / "gnss-tower.toml")
    gnss_modal.simulate_structure_gnss(tmp, cfg, duration_s=duration_s, seed=seed)
    _cli("ingest", "--config", tmp / "config.toml", "-o", tmp / "run.mcap")
    _cli("init", tmp / "run.mcap", "-o", tmp / "init.json")
    seen = {}
    real = gnss_modal.filter_dd_kernel if kernel.available() else gnss_modal.filter_numpy

    def spy(model, dyn, t, x0, P0, max_iterations=5, **kw):
        seen.update(model=model, dyn=dyn, t=t, x0=x0, P0=P0, it=max_iterations)
        return real(model, dyn, t, x0, P0, max_iterations, **kw)

    name = "filter_dd_kernel" if kernel.available() else "filter_numpy"
    setattr(gnss_modal, name, spy)
    text = (tmp / "init.json").read_text()
    gnss_modal.gnss_modal_estimate(read_gnss_run(tmp / "run.mcap"), json.loads(text), text, cfg, tmp / "states.mcap")
    setattr(gnss_modal, name, real)
    return seen


def best(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main_(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "gnss_modal.json"))
    a = ap.parse_args(argv)
    if not kernel.available():
        raise SystemExit("the compiled kernel is not available (pip install -e . with a C compiler)")
    with tempfile.TemporaryDirectory() as d:
        s = capture_inputs(Path(d), a.duration, a.seed)
    args = (s["model"], s["dyn"], s["t"], s["x0"], s["P0"], s["it"])
    gate = 6.0
    t_np, ref = best(lambda: model_filter.filter_numpy(*args, rows_hook=model_filter.outlier_gate(s["model"], gate, [])), a.repeat)
    t_k, got = best(lambda: model_filter.filter_dd_kernel(*args, outlier_sigma=gate), a.repeat)
    n = len(s["t"])
    rows = int(np.sum(ref["nis_dof"]))
    res = {"config": "gnss-tower", "duration_s": a.duration, "seed": a.seed, "epochs": n, "dd_rows": rows,
           "states": int(len(s["x0"])), "repeat": a.repeat,
           "numpy_s": t_np, "kernel_s": t_k, "speedup": t_np / t_k,
           "numpy_us_per_epoch": 1e6 * t_np / n, "kernel_us_per_epoch": 1e6 * t_k / n,
           "max_abs_dx": float(np.max(np.abs(got["x"] - ref["x"]))), "target_speedup": 20.0}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=2) + "\n")
    print(f"modal filter on {n} epochs ({rows} DD rows, {len(s['x0'])} states), best of {a.repeat}:")
    print(f"  numpy path   {t_np:8.3f} s  ({res['numpy_us_per_epoch']:7.1f} µs/epoch)")
    print(f"  kernel path  {t_k:8.3f} s  ({res['kernel_us_per_epoch']:7.1f} µs/epoch, packing included)")
    print(f"  speed-up     {res['speedup']:8.1f} ×  (target ≥ 20 ×); max |Δx| {res['max_abs_dx']:.2e}")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main_()
