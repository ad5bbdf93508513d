"""The one batch initializer engine (cdgps_cli/estimation/batch_init.py) under its two wrappers.

The same testbed window (a flagged slip: two bias segments on one channel; an outage: channels absent)
is posed twice: by the pseudolite wrapper (:class:`initializer._Problem`: rows divided by each
channel's σ, each row touching one bias) and by the measurement-model wrapper
(:class:`model_init.ModelProblem` on :class:`PseudoliteSD`: compact rows per epoch, whitened by the
epoch's noise, the biases solved about their window means through E).  Both must give the same cost,
the same linearized solution — checked against the dense normal equations of Eq. (13)–(15) — and the
same Gauss–Newton solution.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.core.records import memory_run
from cdgps_cli.estimation.batch_init import BatchProblem, InitOptions
from cdgps_cli.estimation.batch_solver import dense_solve
from cdgps_cli.estimation.initializer import _Problem, window_data
from cdgps_cli.estimation.model_init import ModelProblem
from cdgps_cli.measurement.model import PseudoliteSD
from cdgps_cli.model.dynamics_models import ModalZOH
from cdgps_cli.sim.structure import SimOptions, parse_outage, parse_slip, simulate

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def window():
    cfg = load_config(ROOT / "configs" / "testbed-1998-lumped.toml")
    sim = simulate(cfg, SimOptions(duration_s=5.0, seed=11, phase_sigma_m=0.005,
                                   slips=[parse_slip("a2:PL3:1.5:+2")], outages=[parse_outage("PL5:2.0:0.5")]))
    wd = window_data(memory_run(cfg, sim.receiver), 0.0, 3.0)
    sig = np.linspace(0.004, 0.008, len(wd.channels))            # a different σ per channel
    pl = _Problem(cfg, wd, sig, True)
    model = PseudoliteSD(cfg, wd.y_m, wd.ant, wd.tx, sig, wd.segment)
    mp = ModelProblem(model, ModalZOH(cfg), range(len(wd.time_s)), cfg.sample_period_s)
    rng = np.random.default_rng(0)
    N = len(wd.time_s)
    x = sim.x[:N] + 1e-3 * rng.standard_normal(sim.x[:N].shape)
    tb = {(b["antenna"], b["transmitter"]): b["bias_m"] for b in sim.truth["biases"]}
    b = np.array([tb[(s["antenna"], s["transmitter"])] for s in wd.segments]) + 0.01 * rng.standard_normal(len(wd.segments))
    return wd, pl, mp, x, b


def test_the_window_has_a_slip_and_an_outage(window):
    wd, pl, mp, *_ = window
    # 36 channels, the slip's second segment, and a new segment on each of PL5's 6 channels after its outage
    assert len(wd.segments) == len(wd.channels) + 1 + 6 and np.isnan(wd.y_m).any()
    assert isinstance(pl, BatchProblem) and isinstance(mp, BatchProblem)
    assert mp.columns == list(range(len(wd.segments))) and pl.free.size == mp.free.size == len(wd.segments)


def test_both_wrappers_have_the_same_cost(window):
    _, pl, mp, x, b = window
    w = np.random.default_rng(1).standard_normal((len(x) - 1, pl.G.shape[1]))
    np.testing.assert_allclose(mp.A, pl.A, rtol=1e-14)
    np.testing.assert_allclose(mp.G, pl.G, rtol=1e-14)
    assert mp.cost(x, b - mp.b_offset, w) == pytest.approx(pl.cost(x, b, w), rel=1e-10)
    np.testing.assert_allclose(mp.full_bias(b - mp.b_offset), pl.full_bias(b), rtol=1e-14)


def test_both_wrappers_linearize_to_the_same_solution_as_the_dense_equations(window):
    _, pl, mp, x, b = window
    lp_pl = pl.linear_problem(x, 0.0, x[0], 0.0, b)
    lp_mp = mp.linear_problem(x, 0.0, x[0], 0.0, b - mp.b_offset)
    assert lp_pl.E is None and lp_mp.E is not None          # the two incidence paths of the solver
    s_pl, s_mp, d_mp = pl.solve(lp_pl), mp.solve(lp_mp), dense_solve(lp_mp)
    np.testing.assert_allclose(s_mp.x, d_mp.x, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(s_mp.b, d_mp.b, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(s_pl.x, s_mp.x, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(s_pl.b, mp.b_offset + s_mp.b, rtol=1e-9, atol=1e-9)
    assert s_pl.cost == pytest.approx(s_mp.cost, rel=1e-8)
    n = pl.n
    np.testing.assert_allclose(s_pl.P_end[:n, :n], s_mp.P_end[:n, :n], rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(s_pl.P_end[n:, n:], s_mp.P_end[n:, n:], rtol=1e-6, atol=1e-14)


def test_both_wrappers_reach_the_same_gauss_newton_solution(window):
    _, pl, mp, x, b = window
    opt = InitOptions(step_tol_m=1e-9)
    g_pl = pl.gauss_newton(x, b, opt.max_iterations, opt)
    g_mp = mp.gauss_newton(x, b - mp.b_offset, opt.max_iterations, opt)
    assert g_pl.converged and g_mp.converged
    np.testing.assert_allclose(g_mp.x, g_pl.x, atol=1e-8)
    np.testing.assert_allclose(mp.full_bias(g_mp.b), pl.full_bias(g_pl.b), atol=1e-8)
    assert g_mp.cost == pytest.approx(g_pl.cost, rel=1e-8)
