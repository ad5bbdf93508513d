"""Dynamics for fusing sensors that see the structure's acceleration (issue 30; architecture.md "Next").

An accelerometer reads q̈ = U ξ̈ with ξ̈ = −Λ ξ − C ξ̇ + d, where d is the modal-acceleration
disturbance that the modal model (:class:`cdgps_cli.model.dynamics_models.ModalZOH`) treats as white
process noise held over each step (zero-order hold).  Read at 100 Hz, d is most of what an
accelerometer sees; left as process noise, the accelerometer's error would be correlated with the
process noise and the filter would be overconfident.  :class:`ModalDisturbance` makes d a state:

    x = [ξ, ξ̇, d],   [ξ, ξ̇]_{k+1} = A [ξ, ξ̇]_k + B_d d_k,   d_{k+1} ~ N(0, W_d T/Δt)

(A, B_d the zero-order hold of the modal model over Δt, W_d = G W Gᵀ the config's process noise as
modal accelerations per its sample period T, scaled as :class:`ModalZOH` scales it), the exact
discrete model of the ZOH simulator (:func:`cdgps_cli.sim.structure.simulate`): the filter's
[ξ, ξ̇] statistics are those of :class:`ModalZOH`, and an accelerometer read at t_k sees d_k.
Modes with no process noise carry no d (their column of the selection S is dropped).

:class:`WithRandomWalks` appends random-walk states (sensor biases, σ per √s, 0: constant) to any
dynamics; :func:`fusion_dynamics` builds [ξ, ξ̇, (d), biases] for a list of measurement models that
declare ``extra_states``.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.model.dynamics import continuous_model, zoh
from cdgps_cli.model.dynamics_models import Dynamics, ModalZOH, _check_dt

__all__ = ["ModalDisturbance", "WithRandomWalks", "fusion_dynamics", "modal_acceleration_map"]


def modal_acceleration_map(cfg: StructureConfig) -> np.ndarray:
    """[−Λ, −C] (n_m, 2 n_m): ξ̈ = [−Λ, −C] [ξ, ξ̇] + (disturbance and inputs), 1/s², 1/s."""
    Ac, _, _ = continuous_model(cfg)
    nm = cfg.n_modes
    return Ac[nm:, :].copy()


class ModalDisturbance(Dynamics):
    """x = [ξ, ξ̇, d] (n = 2 n_m + r): the modal model with its held disturbance d (r modes) as states.

    Attributes
    ----------
    S : ndarray (n_m, r)
        Modes carrying a disturbance state: ξ̈ = −Λ ξ − C ξ̇ + S d.
    W_d : ndarray (r, r)
        Covariance of d per the config's sample period, (modal units / s²)².
    """

    def __init__(self, cfg: StructureConfig):
        self.cfg = cfg
        nm = cfg.n_modes
        self._Ac, Bc, Bwc = continuous_model(cfg)
        G = Bwc[nm:]
        Wd = G @ np.asarray(cfg.process_noise_W, float) @ G.T
        keep = np.diag(Wd) > 0
        self.S = np.eye(nm)[:, keep]
        self.W_d = Wd[np.ix_(keep, keep)]
        if keep.any() and np.linalg.eigvalsh(self.W_d).min() <= 1e-15 * np.abs(self.W_d).max():
            raise ValueError("ModalDisturbance: the process noise as modal accelerations is singular "
                             "(a disturbance state needs a positive-definite G W Gᵀ on the modes that carry noise)")
        self.r = int(keep.sum())
        self.n = 2 * nm + self.r
        self.n_u = Bc.shape[1]
        self._Bc = Bc
        self._cache: dict = {}

    def transition(self, dt_s: float):
        key = round(_check_dt(dt_s), 9)
        if key not in self._cache:
            nm2 = 2 * self.cfg.n_modes
            ins = np.hstack([self._Bc, np.vstack([np.zeros((nm2 // 2, self.r)), self.S])])
            A2, BB = zoh(self._Ac, ins, key)
            A = np.zeros((self.n, self.n))
            A[:nm2, :nm2], A[:nm2, nm2:] = A2, BB[:, self.n_u:]
            Q = np.zeros((self.n, self.n))
            Q[nm2:, nm2:] = self.W_d * (self.cfg.sample_period_s / key)
            B = np.vstack([BB[:, :self.n_u], np.zeros((self.r, self.n_u))])
            self._cache[key] = (A, B, Q)
        A, B, Q = self._cache[key]
        return A.copy(), B.copy(), Q.copy()


class WithRandomWalks(Dynamics):
    """The states of ``dyn`` followed by random walks of σ ``sigma_per_sqrt_s`` (units/√s each; 0: constant)."""

    def __init__(self, dyn: Dynamics, sigma_per_sqrt_s):
        s = np.asarray(sigma_per_sqrt_s, dtype=float).reshape(-1)
        if not np.all(np.isfinite(s) & (s >= 0)):
            raise ValueError(f"sigma_per_sqrt_s must be finite and ≥ 0, got {sigma_per_sqrt_s!r}")
        self.dyn, self.sigma = dyn, s
        self.n, self.n_u = dyn.n + s.size, dyn.n_u
        self._cache: dict = {}

    def transition(self, dt_s: float):
        dt = _check_dt(dt_s)
        key = round(dt, 9)
        if key not in self._cache:                     # (one per spacing: the filter asks every epoch)
            A, B, Q = self.dyn.transition(dt)
            n, m = self.n, self.dyn.n
            Aa, Qa = np.eye(n), np.zeros((n, n))
            Aa[:m, :m], Qa[:m, :m] = A, Q
            Qa[m:, m:] = np.diag(self.sigma**2 * dt)
            self._cache[key] = (Aa, np.vstack([B, np.zeros((self.sigma.size, B.shape[1]))]), Qa)
        return tuple(a.copy() for a in self._cache[key])


def fusion_dynamics(cfg: StructureConfig, models, disturbance: bool = True) -> tuple[Dynamics, list, np.ndarray]:
    """[ξ, ξ̇, (d), extra states of each model] for ``models`` (each with ``extra_states``: a list of
    (name, prior σ, random-walk σ per √s), in the order the models were placed).

    Returns
    -------
    dyn : Dynamics
    names : list of str
        Names of the extra states (after the modal ones and d).
    prior_sigma : ndarray
        Their prior σ.
    """
    base = ModalDisturbance(cfg) if disturbance else ModalZOH(cfg)
    extra = [e for m in models for e in getattr(m, "extra_states", ())]
    if not extra:
        return base, [], np.zeros(0)
    return (WithRandomWalks(base, [e[2] for e in extra]), [e[0] for e in extra],
            np.array([e[1] for e in extra], dtype=float))
