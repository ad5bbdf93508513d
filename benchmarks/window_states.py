#!/usr/bin/env python3
"""STATES over the whole record: consistency of INIT's window epochs and of the first filter epoch,
before and after the change that stopped the filter from using the window's last epoch twice
→ docs/window-states.md.

Per seed (library functions, the code of the CLI): the testbed, 90 s free vibration with phase
noise equal to the config's σ (2 cm) and the true disturbance equal to the filter's process noise
(disturbance scale 1), so that the σ are not off for another reason (issue 11 item 4),
``cdgps init`` with its automatic window (0–60 s), then ``cdgps estimate``

* *after* (this code): INIT as written, STATES from the window start; the window's epochs are the
  batch solution, the filter starts from INIT's state at 60 s without re-using that epoch;
* *before*: the same INIT without its ``window`` entry, which is how ``estimate`` treated every INIT
  before: the state at 60 s taken as a prior and updated with the 60 s data again.

Figures: σ of every coordinate at 60 s and at 60.1 s over INIT's σ (min–max over coordinates and
seeds); (error/σ)² per coordinate (mean over coordinates, epochs and seeds) over the window epochs
and at the first filter output; the modal-position NEES per dof over the window epochs.

Example::

    python benchmarks/window_states.py --seeds 20          # ≈ 3–5 min
"""

from __future__ import annotations

import argparse
import datetime
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.estimation.filter import EstimateOptions, estimate  # noqa: E402
from cdgps_cli.estimation.initializer import InitOptions, initialize  # noqa: E402
from cdgps_cli.core.records import memory_run  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402
from cdgps_cli.io.states import coordinate_sigma  # noqa: E402


def one_seed(cfg, seed: int) -> dict:
    sim = simulate(cfg, SimOptions(duration_s=90.0, seed=seed, phase_sigma_m=cfg.measurement_sigma_m,
                                   disturbance_scale=1.0))
    run = memory_run(cfg, sim.receiver)
    init = initialize(run, InitOptions())
    t0 = init["state"]["time_s"]
    U = np.asarray(cfg.mode_shapes)
    nm = cfg.n_modes
    P_init = np.asarray(init["state"]["P"])
    s_init = np.sqrt(np.einsum("qi,ij,qj->q", U, P_init[:nm, :nm], U))
    out = {"seed": seed, "window_end_s": t0}
    for label, ini in (("after", init), ("before", {k: v for k, v in init.items() if k != "window"})):
        res = estimate(run, ini, EstimateOptions())
        k_of = {round(float(t), 6): i for i, t in enumerate(sim.time_s)}
        rows = np.array([k_of[round(float(t), 6)] for t in res.time_s])
        q = res.x[:, :nm] @ U.T
        sq = coordinate_sigma(cfg.mode_shapes, res.P[:, :nm, :nm])
        z2 = ((q - sim.q[rows]) / sq) ** 2
        i0 = int(np.argmin(np.abs(res.time_s - t0)))
        r = {"epochs": len(res.time_s), "ratio_t0": sq[i0] / s_init, "ratio_t1": sq[i0 + 1] / s_init,
             "z2_first_output": z2[0] if label == "before" else z2[i0 + 1], "z2_t0": z2[i0]}
        if label == "after":
            win = res.time_s <= t0 + 1e-9
            xi_t = sim.x[rows][:, :nm]
            d = res.x[:, :nm] - xi_t
            nees = np.einsum("ni,ni->n", d, np.linalg.solve(res.P[:, :nm, :nm], d[..., None])[..., 0])
            r.update(z2_window=z2[win], nees_window=nees[win] / nm, epochs_window=int(win.sum()))
        out[label] = r
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default=str(ROOT / "docs" / "window-states.md"))
    a = ap.parse_args()
    cfg = load_config(ROOT / "configs" / "testbed-1998-lumped.toml")
    t_start = time.time()
    rs = []
    for s in range(1, a.seeds + 1):
        rs.append(one_seed(cfg, s))
        print(f"seed {s}: done ({time.time() - t_start:.0f} s)", file=sys.stderr)

    def rng(key, label):
        v = np.concatenate([r[label][key] for r in rs])
        return f"{v.min():.3f}–{v.max():.3f}"

    def mean(key, label):
        return f"{np.mean(np.concatenate([np.ravel(r[label][key]) for r in rs])):.3f}"

    lines = [
        "# STATES over the whole record: the window's epochs and the first filter epoch",
        "",
        f"Produced by `python benchmarks/window_states.py --seeds {a.seeds}` on {datetime.date.today()} "
        f"({platform.machine()}, Python {platform.python_version()}), {time.time() - t_start:.0f} s.",
        "",
        "Testbed (`configs/testbed-1998-lumped.toml`), 90 s free vibration, phase noise 2 cm = the config's σ, "
        "true disturbance = the filter's process noise (disturbance scale 1), "
        f"{a.seeds} seeds; `init` with its automatic window (0–60 s), `estimate` without smoothing. "
        "*before*: INIT's state at 60 s taken as a prior and updated with the 60 s data a second time "
        "(how `estimate` treated every INIT until this change; reproduced by removing INIT's `window`); "
        "*after*: the window's epochs from the batch solution, the filter from INIT's state without "
        "re-using the 60 s data.",
        "",
        "| quantity | before | after | expected |",
        "|---|---|---|---|",
        f"| STATES epochs | {rs[0]['before']['epochs']} (60–90 s) | {rs[0]['after']['epochs']} (0–90 s) | 901 |",
        f"| σ at 60 s / INIT's σ (min–max over coordinates, seeds) | {rng('ratio_t0', 'before')} | "
        f"{rng('ratio_t0', 'after')} | 1 |",
        f"| σ at 60.1 s / INIT's σ | {rng('ratio_t1', 'before')} | {rng('ratio_t1', 'after')} | ≈ 1 (one step of process noise, one epoch of data) |",
        f"| (error/σ)² at the first filter output (60 s before, 60.1 s after), mean over coordinates and seeds "
        f"| {mean('z2_first_output', 'before')} | {mean('z2_first_output', 'after')} | 1 |",
        f"| (error/σ)² at 60 s (INIT's state, the window end) | {mean('z2_t0', 'before')} | {mean('z2_t0', 'after')} | 1 |",
        f"| (error/σ)² over the window's epochs (0–60 s) | – | {mean('z2_window', 'after')} | 1 |",
        f"| modal NEES / dof over the window's epochs | – | {mean('nees_window', 'after')} | 1 |",
        "",
        f"(error/σ)² at the first output pools {len(rs) * cfg.n_q} values (10 coordinates × {a.seeds} "
        "seeds) per row, so its sampling scatter is about ±0.1 around 1 for independent draws (less independent "
        "here: the coordinates' errors are correlated).",
        "",
        "Independent check of the same property (tests/estimation/test_window_smoother.py): on a linear model the window's "
        "states and covariances, every filter epoch and the whole smoothed record equal a dense normal-equation "
        "batch solution over the corresponding epochs (relative difference < 1e-8), on the compiled-kernel "
        "and the numpy path; in particular the first post-window σ is the batch's propagated σ.",
    ]
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
