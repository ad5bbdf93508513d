"""The dynamics interface (cdgps_cli/model/dynamics_models.py) against the discrete model it wraps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.model.dynamics_models import ModalZOH, RandomWalk, Static, WithConstants

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", ["gnss-tower.toml", "testbed-1998-lumped.toml"])
def test_modal_zoh_is_the_discrete_model_with_density_kept(name):
    cfg = load_config(ROOT / "configs" / name)
    dyn = ModalZOH(cfg)
    for dt in (cfg.sample_period_s, 2.5 * cfg.sample_period_s):
        A, B, Q = dyn.transition(dt)
        dm = discrete_model(cfg, T=dt)
        np.testing.assert_array_equal(A, dm.A)
        np.testing.assert_array_equal(B, dm.B)
        np.testing.assert_allclose(Q, dm.Q * cfg.sample_period_s / dt, rtol=1e-14)
        G = dyn.noise_factor(dt)
        np.testing.assert_allclose(G @ G.T, Q, rtol=1e-12, atol=1e-15 * np.abs(Q).max())
    with pytest.raises(ValueError, match="dt_s"):
        dyn.transition(0.0)


def test_random_walk_and_static():
    A, B, Q = RandomWalk(3, 0.01).transition(4.0)
    np.testing.assert_array_equal(A, np.eye(3))
    assert B.shape == (3, 0)
    np.testing.assert_allclose(Q, np.eye(3) * 4e-4)
    G = RandomWalk(3, 0.01).noise_factor(4.0)
    np.testing.assert_allclose(G @ G.T, Q)
    A, _, Q = Static(2).transition(1.0)
    np.testing.assert_array_equal(Q, np.zeros((2, 2)))
    assert Static(2).noise_factor(1.0).shape == (2, 0)
    with pytest.raises(ValueError, match="sigma"):
        RandomWalk(2, -1.0)


def test_random_walk_with_one_sigma_per_coordinate():
    dyn = RandomWalk(3, (0.001, 0.002, 0.0))
    _, _, Q = dyn.transition(2.0)
    np.testing.assert_allclose(Q, np.diag([2e-6, 8e-6, 0.0]), rtol=1e-15)
    G = dyn.noise_factor(2.0)
    assert G.shape == (3, 2)                                   # the zero-noise coordinate has no column
    np.testing.assert_allclose(G @ G.T, Q, rtol=1e-15, atol=1e-20)
    with pytest.raises(ValueError, match="sigma"):
        RandomWalk(3, (0.001, 0.002))
    with pytest.raises(ValueError, match="sigma"):
        RandomWalk(2, (0.001, float("nan")))


def test_with_constants_appends_constant_states():
    dyn = WithConstants(RandomWalk(3, (0.001, 0.002, 0.003)), 4)
    A, B, Q = dyn.transition(3.0)
    A0, _, Q0 = RandomWalk(3, (0.001, 0.002, 0.003)).transition(3.0)
    assert dyn.n == 7 and B.shape == (7, 0)
    np.testing.assert_array_equal(A, np.eye(7))
    np.testing.assert_array_equal(Q[:3, :3], Q0)
    assert not Q[3:].any() and not Q[:, 3:].any()
    G = dyn.noise_factor(3.0)
    np.testing.assert_allclose(G @ G.T, Q, rtol=1e-15, atol=1e-20)


def test_gauss_markov_states_keep_their_stationary_variance_and_match_the_multipath_model():
    from cdgps_cli.measurement.multipath import MultipathModel
    from cdgps_cli.model.dynamics_models import ConstantVelocity, WithGaussMarkov

    base = ConstantVelocity(3, 0.2)
    dyn = WithGaussMarkov(base, 4, 0.007, 34.0)
    assert (dyn.n, dyn.n_u) == (10, 0)
    mp = MultipathModel(0.007, 34.0)
    for dt in (0.1, 1.0, 5.0, 300.0):
        A, B, Q = dyn.transition(dt)
        Ab, _, Qb = base.transition(dt)
        np.testing.assert_array_equal(A[:6, :6], Ab)
        np.testing.assert_array_equal(Q[:6, :6], Qb)
        assert not A[:6, 6:].any() and not A[6:, :6].any() and not Q[:6, 6:].any()
        np.testing.assert_allclose(np.diag(A)[6:], mp.transition(dt), rtol=1e-15)
        np.testing.assert_allclose(np.diag(Q)[6:], mp.process_variance_m2(dt), rtol=1e-14)
        # σ² stays σ² over a step: a² σ² + q = σ² (the stationary process)
        np.testing.assert_allclose(np.diag(A)[6:] ** 2 * 0.007**2 + np.diag(Q)[6:], 0.007**2, rtol=1e-13)
        assert B.shape == (10, 0)
    # two steps are one step of their sum (a Markov process sampled at any spacing)
    A1, _, Q1 = dyn.transition(2.0)
    A2, _, Q2 = dyn.transition(3.0)
    A5, _, Q5 = dyn.transition(5.0)
    np.testing.assert_allclose((A2 @ A1)[6:, 6:], A5[6:, 6:], rtol=1e-14)
    np.testing.assert_allclose((A2 @ Q1 @ A2.T + Q2)[6:, 6:], Q5[6:, 6:], rtol=1e-13)
    for bad in ((-1.0, 30.0), (0.01, 0.0), (np.nan, 30.0)):
        with pytest.raises(ValueError):
            WithGaussMarkov(RandomWalk(3, 0.001), 2, *bad)
