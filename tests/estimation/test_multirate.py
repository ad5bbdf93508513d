"""Multi-rate fusion in the engine's forward filter and RTS smoother (issue 30 item 2): a 100 Hz
accelerometer and 10 Hz GNSS positions stacked (epochs where only some models have rows), the
dynamics stepping at the fastest rate.  Checked against the dense batch solution of the same linear
Gaussian problem (the smoothed mean and covariance are the batch posterior's)."""

import numpy as np

from cdgps_cli.config.structure import parse_config
from cdgps_cli.estimation.model_filter import filter_numpy
from cdgps_cli.estimation.smoother import rts_smooth_transitions
from cdgps_cli.measurement.accelerometer import Accelerometer
from cdgps_cli.measurement.gnss_position import GnssPosition
from cdgps_cli.measurement.sensor import align_epochs, place
from cdgps_cli.measurement.stacked import Stacked
from cdgps_cli.model.fusion_dynamics import ModalDisturbance, fusion_dynamics
from tests.measurement.test_sensors import ONE_MODE


def _case(seed=0, offset_s=0.0, n_acc=61):
    cfg = parse_config(ONE_MODE.replace("sample_period_s = 0.001", "sample_period_s = 0.01"))
    t_acc = np.round(np.arange(n_acc) * 0.01, 9)
    t_gnss = np.round(t_acc[::10] + offset_s, 9)
    t = np.unique(np.r_[t_acc, t_gnss])
    base = ModalDisturbance(cfg)
    rng = np.random.default_rng(seed)
    acc = Accelerometer(cfg, "top", "top", "x", rng.standard_normal((t_acc.size, 1)) * 0.05, align_epochs(t, t_acc),
                        0.01, bias_sigma_m_s2=0.02, bias_drift_m_s2_per_sqrt_s=1e-3, disturbance=base.S)
    gn = GnssPosition(cfg, "top", rng.standard_normal((t_gnss.size, 3)) * 0.02, align_epochs(t, t_gnss), 0.02,
                      n_core=base.n)
    n = place([gn, acc], base.n)
    dyn, names, prior = fusion_dynamics(cfg, [gn, acc])
    assert dyn.n == n and names == ["top_bias_accel_x_m_s2"]
    model = Stacked([("gnss", gn), ("accel", acc)], n)
    x0 = np.zeros(n)
    P0 = np.diag(np.r_[0.05**2, 0.5**2, base.W_d.diagonal(), prior**2])
    return cfg, t, dyn, model, x0, P0


def _batch(t, dyn, model, x0, P0):
    """Dense batch posterior: unknowns θ = [x_0, e_1 … e_{N−1}], x_k = A_k x_{k−1} + G_k e_k, e ~ N(0, I)."""
    n, N = x0.size, t.size
    maps = [np.hstack([np.eye(n)])]                 # x_k = Φ_k θ, built column block by column block
    Gs = []
    for k in range(1, N):
        A, _, _ = dyn.transition(t[k] - t[k - 1])
        G = dyn.noise_factor(t[k] - t[k - 1])
        Gs.append(G)
        prev = maps[-1]
        maps.append(np.hstack([A @ prev, G]))
    p = maps[-1].shape[1]
    Phi = [np.hstack([m, np.zeros((n, p - m.shape[1]))]) for m in maps]
    rows_A, rows_b = [np.linalg.cholesky(np.linalg.inv(P0)).T @ Phi[0]], [np.linalg.cholesky(np.linalg.inv(P0)).T @ x0]
    col = n
    for G in Gs:                                     # e ~ N(0, I)
        E = np.zeros((G.shape[1], p))
        E[:, col:col + G.shape[1]] = np.eye(G.shape[1])
        rows_A.append(E)
        rows_b.append(np.zeros(G.shape[1]))
        col += G.shape[1]
    for k in range(N):
        r = model.rows(k)
        if r is None:
            continue
        _, H = model.predict(np.zeros(n), r)         # linear in x (no section rotations here)
        rows_A.append(r.whiten(H @ Phi[k]))
        rows_b.append(r.whiten(r.z_m))
    Aw, bw = np.vstack(rows_A), np.concatenate(rows_b)
    info = Aw.T @ Aw
    theta = np.linalg.solve(info, Aw.T @ bw)
    cov = np.linalg.inv(info)
    return np.array([F @ theta for F in Phi]), np.array([F @ cov @ F.T for F in Phi])


def test_multirate_smoother_equals_batch():
    cfg, t, dyn, model, x0, P0 = _case()
    out = filter_numpy(model, dyn, t, x0, P0, max_iterations=1)
    assert out["nis_dof"][0] == 4 and out["nis_dof"][1] == 1 and out["nis_dof"][10] == 4   # GNSS every 10th epoch
    xs, Ps = rts_smooth_transitions(out["x"], out["P"], out["A"], out["Q"])
    xb, Pb = _batch(t, dyn, model, x0, P0)
    assert np.allclose(xs, xb, atol=1e-8 * np.abs(xb).max() + 1e-12)
    assert np.allclose(Ps, Pb, atol=1e-8 * np.abs(Pb).max())
    assert np.allclose(out["x"][-1], xb[-1], atol=1e-8 * np.abs(xb).max())   # the last filtered = smoothed


def test_multirate_unaligned_times_smoother_equals_batch():
    """GNSS epochs 3 ms off the accelerometer grid: the dynamics step on the union of the times
    (transitions of two spacings), the smoother one pass per stretch."""
    cfg, t, dyn, model, x0, P0 = _case(seed=1, offset_s=0.003, n_acc=41)
    assert t.size == 41 + 5                              # the union of the two time axes
    out = filter_numpy(model, dyn, t, x0, P0, max_iterations=1)
    xs, Ps = rts_smooth_transitions(out["x"], out["P"], out["A"], out["Q"])
    xb, Pb = _batch(t, dyn, model, x0, P0)
    assert np.allclose(xs, xb, atol=1e-8 * np.abs(xb).max() + 1e-12)
    assert np.allclose(Ps, Pb, atol=1e-8 * np.abs(Pb).max())


def test_stacked_rows_block_noise_and_labels():
    cfg, t, dyn, model, x0, P0 = _case()
    r = model.rows(0)
    assert [lb[0] for lb in r.labels] == ["gnss"] * 3 + ["accel"]
    assert r.labels[3] == ("accel", "top", "accel_x_m_s2") and r.sigma_m is not None
    sub = r.subset([1, 3])
    h, H = model.predict(np.ones(model.n_state) * 0.01, sub)
    hf, Hf = model.predict(np.ones(model.n_state) * 0.01, r)
    assert np.allclose(h, hf[[1, 3]]) and np.allclose(H, Hf[[1, 3]])
