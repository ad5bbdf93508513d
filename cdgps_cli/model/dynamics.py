"""Modal structural dynamics (Teague, How & Parkinson 1998, Eq. 4–7).

Continuous model with x = [ξ, ξ̇] (modal coordinates and rates), q = U ξ:

    ξ̈ + C ξ̇ + Λ ξ = Uᵀ Υ u + w          A_c = [[0, I], [−Λ, −C]],  B_c = [[0], [Uᵀ Υ]]

with Λ = diag(ω_i²) and modal damping C = diag(2 ζ_i ω_i) = diag(2/τ_i) for elastic modes
(ζ = 1/(ω τ), Table 1, so that the envelope decays as exp(−t/τ)) and C = 1/τ for a rigid-body
mode (its rate decays with time constant τ).  The discrete model x_{k+1} = A x_k + B u_k + B_w w_k
holds u and w constant over the sample (zero-order hold), so w is a modal (or coordinate)
acceleration in the units of the config, as in both papers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cdgps_cli.model.kinematics import thruster_forcing

if TYPE_CHECKING:  # annotations only: the config reader (TOML, schema) is not on the rtk path
    from cdgps_cli.config.structure import StructureConfig


@dataclass(frozen=True)
class DiscreteModel:
    """Discrete-time modal model; shapes use n = 2·n_m states, n_u inputs, n_w noise inputs."""

    A: np.ndarray        # (n, n)
    B: np.ndarray        # (n, n_u)
    Bw: np.ndarray       # (n, n_w)
    W: np.ndarray        # (n_w, n_w) process-noise covariance
    Q: np.ndarray        # (n, n) = Bw W Bwᵀ
    T: float             # sample period, s


def modal_damping(cfg: StructureConfig) -> np.ndarray:
    """Diagonal of C (1/s), shape (n_m,)."""
    tau = np.asarray(cfg.mode_time_constant_s, dtype=float)
    rigid = np.asarray(cfg.mode_frequency_hz) == 0.0
    return np.where(rigid, 1.0 / tau, 2.0 / tau)


def continuous_model(cfg: StructureConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A_c (n, n), B_c (n, n_u) and the noise input matrix B_wc (n, n_w) of Eq. (6)–(7)."""
    nm = cfg.n_modes
    w = 2 * np.pi * np.asarray(cfg.mode_frequency_hz, dtype=float)
    Ac = np.zeros((2 * nm, 2 * nm))
    Ac[:nm, nm:] = np.eye(nm)
    Ac[nm:, :nm] = -np.diag(w**2)
    Ac[nm:, nm:] = -np.diag(modal_damping(cfg))
    U = np.asarray(cfg.mode_shapes)
    Ups = thruster_forcing(cfg)
    Bc = np.vstack([np.zeros((nm, Ups.shape[1])), U.T @ Ups])
    if cfg.process_noise_space == "modal":
        G = np.eye(nm)
    else:                                   # noise on coordinate accelerations: ξ̈ = U⁺ q̈
        G = np.linalg.pinv(U)
    Bwc = np.vstack([np.zeros((nm, G.shape[1])), G])
    return Ac, Bc, Bwc


def zoh(Ac: np.ndarray, Bc: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretization: A = e^{A_c T}, B = ∫₀ᵀ e^{A_c s} ds B_c."""
    from scipy.linalg import expm  # noqa: PLC0415  (scipy's import is a tenth of a second: not on paths that never discretize)

    n, m = Bc.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = Ac
    M[:n, n:] = Bc
    E = expm(M * T)
    return E[:n, :n], E[:n, n:]


def discrete_model(cfg: StructureConfig, T: float | None = None) -> DiscreteModel:
    """Discretize the config's model at period T (default: the config's sample period)."""
    T = cfg.sample_period_s if T is None else float(T)
    Ac, Bc, Bwc = continuous_model(cfg)
    nu = Bc.shape[1]
    A, BB = zoh(Ac, np.hstack([Bc, Bwc]), T)
    B, Bw = BB[:, :nu], BB[:, nu:]
    W = cfg.process_noise_W                 # diag(sigma²) or the config's full covariance
    return DiscreteModel(A=A, B=B, Bw=Bw, W=W, Q=Bw @ W @ Bw.T, T=T)
