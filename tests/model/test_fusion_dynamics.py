"""The fusion dynamics (model/fusion_dynamics.py): the held disturbance as a state reproduces the modal
model's statistics; random-walk bias states."""

import numpy as np

from cdgps_cli.config.structure import load_config
from cdgps_cli.model.dynamics_models import ModalZOH
from cdgps_cli.model.fusion_dynamics import ModalDisturbance, WithRandomWalks, modal_acceleration_map


def test_disturbance_state_gives_the_modal_zoh_statistics():
    """[ξ, ξ̇] one step ahead: A_d x and A_d P A_dᵀ + B_d W_d B_dᵀ are ModalZOH's A x and A P Aᵀ + Q."""
    for path in ("configs/tower-fusion.toml", "configs/tower-120m-fe.toml", "configs/testbed-1998.toml"):
        cfg = load_config(path)
        md, mz = ModalDisturbance(cfg), ModalZOH(cfg)
        for dt in (cfg.sample_period_s, 0.37):
            A, _, Q = md.transition(dt)
            Az, _, Qz = mz.transition(dt)
            n2 = 2 * cfg.n_modes
            Bd = A[:n2, n2:]
            assert np.allclose(A[:n2, :n2], Az, atol=1e-12)
            assert np.allclose(Bd @ Q[n2:, n2:] @ Bd.T, Qz, rtol=1e-9, atol=1e-18)
            assert not A[n2:].any() and not Q[:n2].any()


def test_acceleration_map_and_random_walks():
    cfg = load_config("configs/tower-fusion.toml")
    acc = modal_acceleration_map(cfg)
    w = 2 * np.pi * np.asarray(cfg.mode_frequency_hz)
    assert np.allclose(np.diag(acc[:, :4]), -w**2) and np.allclose(np.diag(acc[:, 4:]), -2 * 0.01 * w)
    dyn = WithRandomWalks(ModalDisturbance(cfg), [1e-3, 0.0])
    A, B, Q = dyn.transition(0.04)
    assert dyn.n == 14 and np.allclose(A[12:, 12:], np.eye(2)) and np.allclose(np.diag(Q)[12:], [1e-6 * 0.04, 0.0])
