"""The batch initialization over the measurement-model interface (cdgps_cli/estimation/model_init.py) on
satellite DDs of the modal state, with and without pseudorange DDs.

An analytic case: satellites that do not move during the window.  A constant rigid yaw ψ then moves
every DD by a constant, −(s_j − s_r)ᵀ J_a ψ — exactly a pattern of DD biases — so the phase DDs alone
cannot separate the yaw from the integers at first order (Gauss–Newton drifts along that pattern and
the window is refused, or the float ambiguities spread over cycles along it).  Pseudorange DDs have no ambiguity: they see the yaw directly and the same
window fixes every integer to its true value.  The data are made by the model (true x₁, integers,
noise drawn from the model's D Σ Dᵀ)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M as LAM
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.initializer import InitOptions
from cdgps_cli.estimation.model_init import ModelProblem, model_batch_init
from cdgps_cli.measurement.model import SatelliteDDModal
from cdgps_cli.model.dynamics_models import ModalZOH
from cdgps_cli.model.kinematics import antenna_positions

ROOT = Path(__file__).resolve().parents[2]
TOWER = ROOT / "configs" / "gnss-tower.toml"
XM = np.array([-3978242.4, 3382841.2, 3649902.8])


def _static_sky_case(seed: int, n_ep: int = 60, n_sat: int = 5, var_m2: float = 2e-5, code_ratio: float = 100.0):
    """SD tables of the tower's two rovers seeing ``n_sat`` fixed satellites; the truth (x₁, DD integers)."""
    cfg = load_config(TOWER)
    gen = np.random.default_rng(seed)
    dirs = gen.normal(size=(n_sat, 3))
    dirs[:, 2] = np.abs(dirs[:, 2]) + 0.5                       # above the horizon (structure z = up, R = I)
    u = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    x1 = np.array([0.012, -0.009, 0.01, 0.004, 0.006, 0.0])     # sway (m), yaw 0.01 rad (3 cm at the rovers), rates
    A, _, _ = ModalZOH(cfg).transition(1.0)
    xs = [x1]
    for _ in range(n_ep - 1):
        xs.append(A @ xs[-1])
    q = np.asarray(xs)[:, :cfg.n_modes] @ np.asarray(cfg.mode_shapes).T
    p = antenna_positions(cfg, q)
    rov = [i for i in range(len(cfg.antenna_names)) if i != cfg.master_index]
    p0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)))[0]
    d_hdr = p0[rov] - p0[cfg.master_index]                      # nominal = header positions
    rel = p[:, rov, :] - p[:, [cfg.master_index], :] - d_hdr[None]   # (n_ep, n_rov, 3) displacement, m
    n_sd = gen.integers(-40, 40, size=(len(rov), n_sat))        # SD integers of each rover and satellite
    noise_m = gen.normal(size=(2, n_ep, n_sat)) * np.sqrt(var_m2)          # master phase, code (÷ ratio)
    tabs = []
    for a in range(len(rov)):
        nrow = n_ep * n_sat
        geo = -np.einsum("si,ki->ks", u, rel[:, a, :])          # −u_jᵀ rel_a: the SD signal (m)
        e_r = gen.normal(size=(2, n_ep, n_sat)) * np.sqrt(var_m2)
        r0 = geo + LAM * n_sd[a] + e_r[0] + noise_m[0]
        rc = geo + code_ratio * (e_r[1] + noise_m[1])
        d = SimpleNamespace(ptr=np.arange(0, nrow + 1, n_sat), sat=np.tile(np.arange(n_sat), n_ep),
                            sat_names=[f"G{j + 1:02d}" for j in range(n_sat)], rover_sat_xyz=np.tile(XM + u * 2.0e7, (n_ep, 1)))
        tabs.append({"d": d, "use": np.ones(nrow, dtype=bool), "r0": r0.reshape(-1), "rc": rc.reshape(-1),
                     "code_ratio": code_ratio, "var_rover": np.full(nrow, var_m2), "var_master": np.full(nrow, var_m2),
                     "ref": np.arange(n_ep) * n_sat, "xm": XM, "seg": np.tile(np.arange(n_sat), n_ep) + 10 * a})
    k_of = [np.arange(n_ep) for _ in rov]
    truth = {(a, 10 * a + j, 10 * a): int(n_sd[a, j] - n_sd[a, 0]) for a in range(len(rov)) for j in range(1, n_sat)}
    return cfg, tabs, k_of, np.array(rov), d_hdr, x1, truth


def _solve(cfg, tabs, k_of, ant, d_hdr, code: bool):
    model = SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr, code=code)
    return model, model_batch_init(model, ModalZOH(cfg), np.arange(60), 1.0, LAM, InitOptions())


@pytest.mark.parametrize("seed", [0, 2])
def test_code_dds_fix_a_window_the_phase_alone_cannot_solve(seed):
    """Phase DDs alone: Gauss–Newton drifts along the yaw/bias pattern and the window is refused;
    with the pseudorange DDs every integer is fixed (ratio ≥ 3) and equals the truth."""
    cfg, tabs, k_of, ant, d_hdr, x1, truth = _static_sky_case(seed)
    with pytest.raises(CdgpsError, match="did not converge|not observable"):
        _solve(cfg, tabs, k_of, ant, d_hdr, code=False)
    model, res = _solve(cfg, tabs, k_of, ant, d_hdr, code=True)
    assert res.fixed.all() and res.ratio >= InitOptions().ratio_threshold, res.note
    assert {model.segment_keys[c]: int(n) for c, n in zip(res.columns, res.integers)} == truth
    assert np.max(res.float_sigma_m) < 0.5 * LAM                # the code pins the float ambiguities
    # the fixed solution's yaw (the direction the phase alone could not place): the truth within 1 mrad
    assert abs(res.x[0][2] - x1[2]) < 1e-3


@pytest.mark.parametrize("seed", [4])
def test_phase_alone_is_refused_or_spread_over_cycles_code_pins_it(seed):
    """Whatever the phase alone does on this geometry (refused, or converged with the yaw seen only
    through second-order terms and float ambiguities spread over more than a cycle), with the code
    every float ambiguity is within ½ cycle and every integer is fixed and right."""
    cfg, tabs, k_of, ant, d_hdr, _, truth = _static_sky_case(seed)
    try:
        _, phase = _solve(cfg, tabs, k_of, ant, d_hdr, code=False)
        assert np.max(phase.float_sigma_m) > 1.0 * LAM
    except CdgpsError as exc:
        assert "did not converge" in str(exc) or "not observable" in str(exc)
    model, both = _solve(cfg, tabs, k_of, ant, d_hdr, code=True)
    assert np.max(both.float_sigma_m) < 0.5 * LAM and both.fixed.all()
    assert {model.segment_keys[c]: int(n) for c, n in zip(both.columns, both.integers)} == truth


def test_large_integers_give_the_same_solution():
    """Raw DDs carry λ·N of 1e5–1e6 m (receivers' arbitrary integers): the window's solution must not
    depend on them (the biases are solved about their window means: no cancellation of 1e5 m terms
    in the cost, whose rounding would stall Gauss–Newton).  Adding 10⁶-cycle SD integers shifts the
    fixed DD integers by exactly their DDs and leaves the trajectory unchanged."""
    cfg, tabs, k_of, ant, d_hdr, _, truth = _static_sky_case(3)
    gen = np.random.default_rng(9)
    big = [dict(tb) for tb in tabs]
    shift = {}
    for a, tb in enumerate(big):
        n_add = gen.integers(-3_000_000, 3_000_000, size=5)
        tb["r0"] = tb["r0"] + LAM * np.tile(n_add, 60)
        shift.update({(a, 10 * a + j, 10 * a): int(n_add[j] - n_add[0]) for j in range(1, 5)})
    m0, r0 = _solve(cfg, tabs, k_of, ant, d_hdr, code=True)
    m1, r1 = _solve(cfg, big, k_of, ant, d_hdr, code=True)
    assert r0.fixed.all() and r1.fixed.all()
    got0 = {m0.segment_keys[c]: int(n) for c, n in zip(r0.columns, r0.integers)}
    got1 = {m1.segment_keys[c]: int(n) for c, n in zip(r1.columns, r1.integers)}
    assert got0 == truth and got1 == {k: truth[k] + shift[k] for k in truth}
    np.testing.assert_allclose(r1.x, r0.x, atol=1e-8)
    assert abs(r1.cost - r0.cost) < 1e-6 * r0.cost


def test_the_cost_is_smooth_in_the_state_with_large_integers():
    """The cost is smooth in the trajectory; evaluated in floating point with 10⁶-cycle integers in the
    data it must stay so to 1e-11 of its value over micrometre changes (else Gauss–Newton's acceptance
    test, J_new ≤ J (1 + 1e-12), rejects the last small steps at random and the window 'does not
    converge').  Solving the biases about their window means keeps z − h(x) − E b free of the
    cancellation of 1e5–1e6 m terms."""
    cfg, tabs, k_of, ant, d_hdr, x1, _ = _static_sky_case(3)
    gen = np.random.default_rng(9)
    for tb in tabs:
        tb["r0"] = tb["r0"] + LAM * np.tile(gen.integers(-3_000_000, 3_000_000, size=5), 60)
    model = SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr, code=True)
    prob = ModelProblem(model, ModalZOH(cfg), np.arange(60), 1.0)
    b = prob.initial_biases(prob.propagate(x1))
    w = np.zeros((59, prob.G.shape[1]))
    d = gen.normal(size=x1.size)
    t = np.linspace(-1e-6, 1e-6, 41)
    J = np.array([prob.cost(prob.propagate(x1 + ti * d), b, w) for ti in t])
    fit = np.polyval(np.polyfit(t / t[-1], J, 4), t / t[-1])       # smooth: a low-order polynomial
    assert np.max(np.abs(J - fit)) < 1e-11 * J.mean(), np.max(np.abs(J - fit)) / J.mean()
