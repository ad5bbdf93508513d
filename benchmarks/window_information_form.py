#!/usr/bin/env python3
"""Why INIT's window smoother keeps its information form (estimation/window_smoother.py) → docs/window-information-form.md.

The window's states are the batch solution (Teague, How & Parkinson 1998 Eq. 9–15), which has no
prior on the first state and none on the biases INIT left float: a diffuse start.  The engine's
forward filter (:class:`cdgps_cli.estimation.kalman.StepFilter`) is in covariance form and needs a
prior (x₀, P₀); the engine's smoother (:func:`cdgps_cli.estimation.smoother.rts_smooth_transitions`)
needs the filtered covariance at every epoch.  This script measures how close the engine gets to
the batch with a broad prior P₀ = s² I, against the window smoother's information form, both
compared with the batch written out densely (tests/estimation/test_window_smoother.py's
``dense_reference``, its linear case: 25 window epochs, 3 float biases).

Usage::

    python benchmarks/window_information_form.py [--json docs/benchmarks/window-information-form.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
for p in (ROOT, ROOT / "tests", ROOT / "tests" / "estimation"):
    sys.path.insert(0, str(p))

from cdgps_cli.estimation import kalman  # noqa: E402
from cdgps_cli.estimation.smoother import rts_smooth_transitions  # noqa: E402
from cdgps_cli.estimation.window_smoother import window_states  # noqa: E402

import test_window_smoother as tw  # noqa: E402  (the test's linear case and dense batch reference)
from _linear_case import LIN_SIGMA  # noqa: E402


def engine_covariance_form(c, free, s_prior):
    """The engine's StepFilter from x₀ = 0, P₀ = s² I on z = [x; free biases], then its RTS smoother."""
    A, G, H = c["A"], c["G"], c["H"]
    n, C = A.shape[0], H.shape[0]
    fidx = np.flatnonzero(free)
    p = n + fidx.size
    Az, Qz, Hz = np.eye(p), np.zeros((p, p)), np.zeros((C, p))
    Az[:n, :n], Qz[:n, :n], Hz[:, :n] = A, G @ G.T, H
    Hz[fidx, n + np.arange(fidx.size)] = 1.0
    Z = c["Z"][:tw.WINDOW] - np.where(free, 0.0, c["b0"])
    step = kalman.StepFilter(np.zeros(p), s_prior**2 * np.eye(p))
    xf, Pf = np.empty((tw.WINDOW, p)), np.empty((tw.WINDOW, p, p))
    for k in range(tw.WINDOW):
        if k:
            step.predict(Az, Qz)
        step.x, step.P, _ = kalman.update(step.x, step.P, Z[k] - Hz @ step.x, Hz, LIN_SIGMA)
        xf[k], Pf[k] = step.x, step.P
    xs, Ps = rts_smooth_transitions(xf, Pf, np.broadcast_to(Az, Pf.shape), np.broadcast_to(Qz, Pf.shape))
    return xs[:, :n], Ps[:, :n, :n]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    c = tw.case.__wrapped__()                       # the pytest fixture's function
    free = np.zeros(c["C"], dtype=bool)
    free[[1, 4, 6]] = True
    init, x_ref, P_ref = tw.make_init(c, free)
    t_end = init["window"]["end_s"]
    ws = window_states(c["run"], init, (0.0, t_end), np.array(init["state"]["x"]), np.array(init["state"]["P"]))
    rows = [{"form": "information (window_smoother)", "rel_err_x": tw._rel(ws.x, x_ref), "rel_err_P": tw._rel(ws.P, P_ref)}]
    for s in (1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e8):
        try:
            xs, Ps = engine_covariance_form(c, free, s)
            rows.append({"form": f"covariance (engine), s = {s:g}", "rel_err_x": tw._rel(xs, x_ref),
                         "rel_err_P": tw._rel(Ps, P_ref)})
        except np.linalg.LinAlgError as exc:
            rows.append({"form": f"covariance (engine), s = {s:g}", "error": str(exc)})
    for r in rows:
        print(json.dumps(r))
    if args.json:
        Path(args.json).write_text(json.dumps({"window_epochs": tw.WINDOW, "free_biases": int(free.sum()),
                                               "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
