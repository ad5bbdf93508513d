"""STATES over the whole record: INIT's window from the batch solution, the filter after it,
each epoch's data used exactly once, and one smoothed trajectory over the whole record.

Independent reference: the batch least-squares problem written out densely (unknowns x₁, the
whitened process noise ω₁…ω_{K−1} and the free biases; no prior on x₁: the batch's diffuse
start), solved by its normal equations, with the covariance of any epoch's state from the inverse
normal matrix.  On a linear model

* a window epoch's STATES value = that reference on the window's data;
* a filter epoch k's value = the reference on epochs 0…k (the filtered estimate is the batch
  solution's last epoch) — so the first post-window σ is the batch's propagated σ, not shrunk by a
  second use of the window's last epoch;
* with --smooth every epoch = the reference on the whole record;

on both the compiled-kernel and the numpy path of the filter.
"""

from __future__ import annotations

import contextlib
import os

import numpy as np
import pytest

from cdgps_cli.estimation import kernel as ekf_kernel
from cdgps_cli.config.structure import parse_config
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.estimation.filter import EstimateOptions, estimate, load_init_state
from cdgps_cli.measurement.phase import all_channels, phase_model
from cdgps_cli.core.records import memory_run
from cdgps_cli.sim.structure import SimOptions, simulate

from _linear_case import LINEAR_CONFIG, LIN_SIGMA

WINDOW = 25                 # epochs in INIT's window
DURATION_S = 9.8            # 50 epochs at 0.2 s


@contextlib.contextmanager
def kernel(enabled: bool):
    old = os.environ.get("CDGPS_NO_KERNEL")
    os.environ.pop("CDGPS_NO_KERNEL", None) if enabled else os.environ.__setitem__("CDGPS_NO_KERNEL", "1")
    try:
        yield
    finally:
        os.environ.pop("CDGPS_NO_KERNEL", None) if old is None else os.environ.__setitem__("CDGPS_NO_KERNEL", old)


def dense_reference(A, G, H, Y, free, K):
    """Normal-equation solution of the batch problem on epochs 0…K−1 (Y: data minus known biases,
    ``free``: channels whose bias is an unknown). Returns x (K, n), P (K, n, n), free biases."""
    n, r = A.shape[0], G.shape[1]
    C = H.shape[0]
    fidx = np.flatnonzero(free)
    nv = n + (K - 1) * r + fidx.size
    Phi = np.zeros((K, n, nv))                      # x_k = Phi_k v
    Phi[0, :, :n] = np.eye(n)
    for k in range(1, K):
        Phi[k] = A @ Phi[k - 1]
        Phi[k, :, n + (k - 1) * r:n + k * r] += G
    rows, rhs = [], []
    for k in range(K):
        for c in range(C):
            row = H[c] @ Phi[k]
            if free[c]:
                row[n + (K - 1) * r + int(np.flatnonzero(fidx == c)[0])] = 1.0
            rows.append(row / LIN_SIGMA)
            rhs.append(Y[k, c] / LIN_SIGMA)
    Th = np.array(rows)
    Nm = Th.T @ Th
    Nm[n:n + (K - 1) * r, n:n + (K - 1) * r] += np.eye((K - 1) * r)     # ω ~ N(0, I)
    Sig = np.linalg.inv(Nm)
    v = Sig @ (Th.T @ np.array(rhs))
    x = np.einsum("kiv,v->ki", Phi, v)
    P = np.einsum("kiv,vw,kjw->kij", Phi, Sig, Phi)
    return x, P, v[n + (K - 1) * r:]


@pytest.fixture(scope="module")
def case():
    cfg = parse_config(LINEAR_CONFIG, "<linear>")
    ant, tx = all_channels(cfg)
    n = cfg.n_states
    h0, H = phase_model(cfg, np.zeros(n), ant, tx, jacobian=True)
    h0, H = h0[0], H[0]
    sim = simulate(cfg, SimOptions(duration_s=DURATION_S, seed=11))
    N = len(sim.time_s)
    C = len(ant)
    Y = (sim.receiver["phase_cycles"].to_numpy() * cfg.wavelength_m).reshape(N, C)
    b0 = np.array([b["bias_m"] for b in sim.truth["biases"]])
    m = discrete_model(cfg)
    L = np.sqrt(np.diag(m.W))
    G = (m.Bw * L)[:, L > 0]
    return dict(cfg=cfg, sim=sim, run=memory_run(cfg, sim.receiver), H=H, Z=Y - h0, b0=b0, A=m.A, G=G,
                N=N, C=C, channels=cfg.channels)


def make_init(case, free):
    """INIT as 'cdgps init' writes it: the batch solution at the window end, the fixed biases known."""
    Zk = case["Z"] - np.where(free, 0.0, case["b0"])
    x, P, bf = dense_reference(case["A"], case["G"], case["H"], Zk, free, WINDOW)
    bias = case["b0"].copy()
    bias[free] = bf
    t_end = float(case["sim"].time_s[WINDOW - 1])
    return {"format": "cdgps.init/1", "config_sha256": case["cfg"].sha256, "sigma_m": LIN_SIGMA,
            "window": {"start_s": 0.0, "end_s": t_end, "epochs": WINDOW},
            "state": {"time_s": t_end, "x": x[-1].tolist(), "P": P[-1].tolist()},
            "options": {"process_noise": True},
            "biases": [{"antenna": a, "transmitter": t, "bias_m": float(bias[c]), "fixed": not bool(free[c]),
                        "segment_start_s": 0.0, "segment_end_s": t_end, "current": True}
                       for c, (a, t) in enumerate(case["channels"])]}, x, P


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


@pytest.mark.parametrize("compiled", [True, False])
def test_window_then_filter_equal_the_batch_over_the_record(case, compiled):
    if compiled and not ekf_kernel.available():
        pytest.skip("compiled kernel not available")
    free = np.zeros(case["C"], dtype=bool)
    init, xw, Pw = make_init(case, free)
    with kernel(compiled):
        res = estimate(case["run"], init, EstimateOptions())
    assert res.filter_path == ("c" if compiled else "numpy")
    N = case["N"]
    np.testing.assert_allclose(res.time_s, case["sim"].time_s, rtol=0, atol=1e-9)    # every epoch of the run
    assert res.window["start_s"] == 0.0 and res.window["epochs"] == WINDOW
    # window epochs: the batch solution on the window's data
    assert _rel(res.x[:WINDOW], xw) < 1e-8 and _rel(res.P[:WINDOW], Pw) < 1e-8
    assert np.all(res.nis_dof[:WINDOW] == 0)             # no filter update in the window
    Zk = case["Z"] - case["b0"]
    for k in (WINDOW, WINDOW + 1, WINDOW + 7, N - 1):
        x, P, _ = dense_reference(case["A"], case["G"], case["H"], Zk, free, k + 1)
        assert _rel(res.x[k], x[-1]) < 1e-8, k
        assert _rel(res.P[k], P[-1]) < 1e-8, k
    # the first post-window epoch: the batch's σ propagated one step and updated once
    x1, P1, _ = dense_reference(case["A"], case["G"], case["H"], Zk, free, WINDOW + 1)
    s_ref = np.sqrt(np.diag(P1[-1]))
    np.testing.assert_allclose(np.sqrt(np.diag(res.P[WINDOW])), s_ref, rtol=1e-8)
    assert np.all(res.nis_dof[WINDOW:] == case["C"])


@pytest.mark.parametrize("compiled", [True, False])
def test_smoothed_record_equals_the_batch_over_the_record(case, compiled):
    if compiled and not ekf_kernel.available():
        pytest.skip("compiled kernel not available")
    free = np.zeros(case["C"], dtype=bool)
    init, xw, Pw = make_init(case, free)
    with kernel(compiled):
        res = estimate(case["run"], init, EstimateOptions(smooth=True))
    x, P, _ = dense_reference(case["A"], case["G"], case["H"], case["Z"] - case["b0"], free, case["N"])
    print(f"\nwhole-record smoother vs dense batch: x {_rel(res.x, x):.1e}, P {_rel(res.P, P):.1e}")
    assert _rel(res.x, x) < 1e-8 and _rel(res.P, P) < 1e-8
    # the filtered series: the window's batch solution, then the filter
    assert _rel(res.x_filt[:WINDOW], xw) < 1e-8


def test_window_with_float_biases_estimates_them_with_the_states(case):
    """Biases INIT left float are unknowns of the window's batch again: the window's covariances
    are marginal over them (larger than with the biases known)."""
    free = np.zeros(case["C"], dtype=bool)
    free[[1, 6, 10]] = True
    init, xw, Pw = make_init(case, free)
    res = estimate(case["run"], init, EstimateOptions())
    assert res.window["free_biases"] == 3
    assert _rel(res.x[:WINDOW], xw) < 1e-8 and _rel(res.P[:WINDOW], Pw) < 1e-8
    _, P_known, _ = dense_reference(case["A"], case["G"], case["H"], case["Z"] - case["b0"],
                                    np.zeros(case["C"], dtype=bool), WINDOW)
    assert np.all(np.diagonal(Pw, axis1=1, axis2=2) >= np.diagonal(P_known, axis1=1, axis2=2))
    assert np.any(np.diagonal(Pw, axis1=1, axis2=2) > 1.01 * np.diagonal(P_known, axis1=1, axis2=2))


def test_hand_made_init_without_window_is_a_prior(case):
    """An INIT without a batch window (a prior at t0, e.g. from another source) is updated with
    t0's data as before, and STATES starts at t0."""
    free = np.zeros(case["C"], dtype=bool)
    init, _, _ = make_init(case, free)
    del init["window"]
    res = estimate(case["run"], init, EstimateOptions())
    assert res.window is None and res.time_s[0] == pytest.approx(init["state"]["time_s"])
    assert res.nis_dof[0] == case["C"]


def test_compiled_window_loops_equal_their_numpy_twins(case):
    """The window's epoch loops in C (issue 30: forward information filter, RTS pass from the prior
    information, first backward EKF, measurement model) equal the numpy loops to rounding, with
    float biases (p > n columns) in the state."""
    if not ekf_kernel.available():
        pytest.skip("compiled kernel not available")
    from cdgps_cli.estimation import window_smoother as W

    free = np.zeros(case["C"], dtype=bool)
    free[[2, 7]] = True
    init, _, _ = make_init(case, free)
    t0, x0, P0, _ = load_init_state(init, case["cfg"])
    win = W.batch_window(init, t0)
    ws_c = W.window_states(case["run"], init, win, x0, P0)
    with kernel(False):
        assert not W._compiled()
        ws_n = W.window_states(case["run"], init, win, x0, P0)
    assert ws_c.n_free_biases == ws_n.n_free_biases == 2
    for a, b in ((ws_c.z, ws_n.z), (ws_c.Pz, ws_n.Pz), (ws_c.Ybar, ws_n.Ybar), (ws_c.residual_m, ws_n.residual_m)):
        assert _rel(a, b) < 1e-12
