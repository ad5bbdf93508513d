"""The dynamics interface of the estimation engine (../shared/design/architecture.md, "The engine").

A dynamics model gives, for a step of ``dt_s`` seconds, the discrete transition of its state x:

    x_{k+1} = A x_k + B u_k + w_k,     w_k ~ N(0, Q)

through ``transition(dt_s) -> (A, B, Q)``.  Implementations:

* :class:`ModalZOH` — the structure's modal model (Eq. 4–7, :func:`cdgps_cli.model.dynamics.discrete_model`)
  held over ``dt_s`` (zero-order hold); the config's process noise is defined per its sample period,
  so Q is scaled by ``sample_period_s / dt_s`` to keep its density at another spacing;
* :class:`RandomWalk` — each of n coordinates walks with σ (units/√s, one or per coordinate):
  A = I, Q = diag(σ²) dt;
* :class:`Static` — A = I, Q = 0;
* :class:`ConstantVelocity` — positions and velocities of n axes, the velocities random walks of σ
  (units/s/√s: white acceleration): A = [[I, dt I], [0, I]], Q = σ² [[dt³/3, dt²/2], [dt²/2, dt]] ⊗ I;
* :class:`WithConstants` — another model's states followed by constants (e.g. ambiguities):
  A = diag(A_d, I), B = [B_d; 0], Q = diag(Q_d, 0);
* :class:`WithGaussMarkov` — another model's states followed by first-order Gauss–Markov states (e.g. a phase
  multipath error per satellite, :mod:`cdgps_cli.measurement.multipath`): A = diag(A_d, a I), a = exp(−dt/τ),
  Q = diag(Q_d, σ²(1 − a²) I) (the stationary variance σ² kept over every step).

``noise_factor(dt_s)`` gives G with G Gᵀ = Q (the square-root form the batch solver takes).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cdgps_cli.model.dynamics import discrete_model

if TYPE_CHECKING:  # annotations only: the config reader (TOML, schema) is not on the rtk path
    from cdgps_cli.config.structure import StructureConfig

__all__ = ["Dynamics", "ModalZOH", "RandomWalk", "Static", "ConstantVelocity", "WithConstants", "WithGaussMarkov"]


class Dynamics:
    """Interface: ``n`` states, ``n_u`` inputs, ``transition(dt_s)`` and ``noise_factor(dt_s)``;
    ``identity_transition``: A is the identity for every step (a filter may then skip A P Aᵀ);
    ``zero_process_noise``: Q is zero for every step (with the identity a filter may skip the prediction)."""

    n: int
    n_u: int
    identity_transition: bool = False
    zero_process_noise: bool = False

    def transition(self, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
        """(A (n, n), B (n, n_u), Q (n, n)) for a step of ``dt_s`` seconds."""
        raise NotImplementedError

    def noise_factor(self, dt_s: float) -> np.ndarray:
        """G (n, r) with G Gᵀ = Q(dt_s), r ≤ n (columns of zero noise dropped)."""
        _, _, Q = self.transition(dt_s)
        vals, vecs = np.linalg.eigh(0.5 * (Q + Q.T))
        keep = vals > 1e-300 * max(1.0, float(vals.max(initial=0.0)))
        return vecs[:, keep] * np.sqrt(vals[keep])


def _check_dt(dt_s: float) -> float:
    dt = float(dt_s)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt_s must be a positive number of seconds, got {dt_s!r}")
    return dt


class ModalZOH(Dynamics):
    """The structure's modal model x = [ξ, ξ̇] (n = 2 n_m) discretized at dt_s (cached per spacing)."""

    def __init__(self, cfg: StructureConfig):
        self.cfg = cfg
        self.n = 2 * cfg.n_modes
        self._cache: dict = {}
        self.n_u = discrete_model(cfg).B.shape[1]

    def _model(self, dt_s: float):
        key = round(_check_dt(dt_s), 9)
        if key not in self._cache:
            self._cache[key] = discrete_model(self.cfg, T=key)
        return self._cache[key]

    def transition(self, dt_s: float):
        dm = self._model(dt_s)
        return dm.A, dm.B, dm.Q * (self.cfg.sample_period_s / float(dt_s))

    def noise_factor(self, dt_s: float) -> np.ndarray:
        """G = B_w W^{1/2} √(T/dt) on the noise inputs with non-zero σ (W diagonal), else the generic factor."""
        dm = self._model(dt_s)
        W = np.asarray(dm.W, dtype=float)
        if np.count_nonzero(W - np.diag(np.diag(W))):
            return super().noise_factor(dt_s)
        L = np.sqrt(np.diag(W))
        keep = L > 0
        return (dm.Bw * L)[:, keep] * np.sqrt(self.cfg.sample_period_s / float(dt_s))


class RandomWalk(Dynamics):
    """n coordinates, each a random walk of σ ``sigma_per_sqrt_s`` (units/√s): one σ for all, or one
    per coordinate (shape (n,), e.g. east/north/up of a GNSS rover)."""

    def __init__(self, n: int, sigma_per_sqrt_s):
        s = np.asarray(sigma_per_sqrt_s, dtype=float)
        if s.ndim > 1 or (s.ndim == 1 and s.size != int(n)) or not np.all(np.isfinite(s) & (s >= 0)):
            raise ValueError(f"sigma_per_sqrt_s must be ≥ 0 (one number or {int(n)}), got {sigma_per_sqrt_s!r}")
        self.n, self.n_u = int(n), 0
        self.sigma = float(s) if s.ndim == 0 else s.copy()
        self.identity_transition = True
        self.zero_process_noise = bool(np.all(s == 0))

    def transition(self, dt_s: float):
        dt = _check_dt(dt_s)
        return np.eye(self.n), np.zeros((self.n, 0)), np.eye(self.n) * self.sigma**2 * dt

    def noise_factor(self, dt_s: float) -> np.ndarray:
        dt = _check_dt(dt_s)
        G = np.eye(self.n) * self.sigma * np.sqrt(dt)
        return G[:, np.broadcast_to(np.asarray(self.sigma) > 0, (self.n,))]


class Static(RandomWalk):
    """n constant coordinates (a random walk of σ = 0)."""

    def __init__(self, n: int):
        super().__init__(n, 0.0)


class ConstantVelocity(Dynamics):
    """``n_axes`` positions followed by their velocities (n = 2 n_axes); each velocity a random walk of
    σ ``accel_sigma_per_sqrt_s`` (units/s/√s, i.e. white acceleration of that density)."""

    def __init__(self, n_axes: int, accel_sigma_per_sqrt_s: float):
        s = float(accel_sigma_per_sqrt_s)
        if not (np.isfinite(s) and s >= 0):
            raise ValueError(f"accel_sigma_per_sqrt_s must be a number >= 0, got {accel_sigma_per_sqrt_s!r}")
        self.n_axes, self.sigma = int(n_axes), s
        self.n, self.n_u = 2 * self.n_axes, 0

    def transition(self, dt_s: float):
        dt = _check_dt(dt_s)
        eye = np.eye(self.n_axes)
        A = np.block([[eye, dt * eye], [np.zeros_like(eye), eye]])
        Q = self.sigma**2 * np.kron(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]), eye)
        return A, np.zeros((self.n, 0)), Q


class WithConstants(Dynamics):
    """The states of ``dyn`` followed by ``n_const`` constants (e.g. ambiguities estimated with them)."""

    def __init__(self, dyn: Dynamics, n_const: int):
        self.dyn, self.n_const = dyn, int(n_const)
        self.n, self.n_u = dyn.n + self.n_const, dyn.n_u

    @property
    def identity_transition(self) -> bool:
        return self.dyn.identity_transition

    @property
    def zero_process_noise(self) -> bool:
        return bool(getattr(self.dyn, "zero_process_noise", False))

    def transition(self, dt_s: float):
        A, B, Q = self.dyn.transition(dt_s)
        n, m = self.n, self.dyn.n
        Aa, Qa = np.eye(n), np.zeros((n, n))
        Aa[:m, :m], Qa[:m, :m] = A, Q
        return Aa, np.vstack([B, np.zeros((self.n_const, B.shape[1]))]), Qa

    def noise_factor(self, dt_s: float) -> np.ndarray:
        G = self.dyn.noise_factor(dt_s)
        return np.vstack([G, np.zeros((self.n_const, G.shape[1]))])


class WithGaussMarkov(Dynamics):
    """The states of ``dyn`` followed by ``n_gm`` first-order Gauss–Markov states of stationary σ ``sigma`` (their
    unit, e.g. m) and time constant ``tau_s`` (s), independent of each other and of ``dyn``'s noise."""

    def __init__(self, dyn: Dynamics, n_gm: int, sigma: float, tau_s: float):
        s, tau = float(sigma), float(tau_s)
        if not (np.isfinite(s) and s >= 0):
            raise ValueError(f"sigma must be a number >= 0, got {sigma!r}")
        if not (np.isfinite(tau) and tau > 0):
            raise ValueError(f"tau_s must be a positive number of seconds, got {tau_s!r}")
        self.dyn, self.n_gm, self.sigma, self.tau_s = dyn, int(n_gm), s, tau
        self.n, self.n_u = dyn.n + self.n_gm, dyn.n_u

    def transition(self, dt_s: float):
        dt = _check_dt(dt_s)
        A, B, Q = self.dyn.transition(dt)
        m = self.dyn.n
        Aa, Qa = np.zeros((self.n, self.n)), np.zeros((self.n, self.n))
        Aa[:m, :m], Qa[:m, :m] = A, Q
        i = np.arange(m, self.n)
        Aa[i, i] = np.exp(-dt / self.tau_s)
        Qa[i, i] = self.sigma**2 * -np.expm1(-2.0 * dt / self.tau_s)
        return Aa, np.vstack([B, np.zeros((self.n_gm, B.shape[1]))]), Qa
