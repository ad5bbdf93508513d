"""Discrete linear quadratic regulator on the modal model (Teague, How & Parkinson 1998, Sec. V).

The regulator minimizes Eq. (24),

    J = Σ_k  x_kᵀ Q_x x_k + u_kᵀ Q_u u_k,

over the discrete model x_{k+1} = A x_k + B u_k of Eq. (4), with the state x = [ξ, ξ̇] (modal
amplitudes, then modal rates) and u the thruster forces in newtons.  The gain is u_k = −K x_k with
K = (Q_u + Bᵀ P B)⁻¹ Bᵀ P A and P the stabilizing solution of the discrete algebraic Riccati
equation (scipy.linalg.solve_discrete_are).

The paper's weights are Q_x* = 5000 diag(1, …, 1, 0.01) (0.01 on the rigid-body mode),
Q_x = diag(Q_x*, 0.01 Q_x*) and Q_u = I (:func:`paper_weights`).  Its thruster force model Υ is not
published; B here comes from the config's thruster geometry by virtual work
(:func:`cdgps_cli.model.kinematics.thruster_forcing`).

Functions are pure: arrays in, arrays and records out, no files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_discrete_are

from cdgps_cli.core.errors import CdgpsError

#: the paper's state weight on every elastic mode's amplitude (Sec. V)
PAPER_STATE_WEIGHT = 5000.0
#: relative weight of the rigid-body mode inside Q_x* (Sec. V: the last entry 0.01)
PAPER_RIGID_FACTOR = 0.01
#: relative weight of the modal rates, Q_x = diag(Q_x*, 0.01 Q_x*) (Sec. V)
PAPER_RATE_FACTOR = 0.01
#: settling is counted to 2 % of the initial amplitude: exp(−σ t) = 0.02
SETTLING_FRACTION = 0.02
#: an eigenvalue with |z| above 1 − this is treated as not asymptotically stable when testing
#: stabilizability and detectability (the rigid-body angle sits exactly at z = 1)
MARGINAL_TOLERANCE = 1e-9
#: largest weight entry accepted: beyond it Bᵀ P B overflows double precision in the Riccati solver
#: (``--qx 1e308`` ended in a traceback, issue 32); only the ratio of Q_x to Q_u matters
WEIGHT_MAX = 1e100


@dataclass(frozen=True)
class LqrDesign:
    """A discrete LQR design; n states, m inputs.

    Attributes
    ----------
    A, B : ndarray, shape (n, n), (n, m)
        The discrete model the gain was designed on.
    Qx, Qu : ndarray, shape (n, n), (m, m)
        State and input weights of Eq. (24).
    K : ndarray, shape (m, n)
        Feedback gain, u = −K x (N per unit state).
    P : ndarray, shape (n, n)
        Stabilizing solution of the discrete algebraic Riccati equation.
    sample_period_s : float
        Sample period of A and B, s.
    riccati_residual : float
        ‖AᵀPA − P − AᵀPB (Q_u + BᵀPB)⁻¹ BᵀPA + Q_x‖_F / max(1, ‖P‖_F), dimensionless.
    """

    A: np.ndarray
    B: np.ndarray
    Qx: np.ndarray
    Qu: np.ndarray
    K: np.ndarray
    P: np.ndarray
    sample_period_s: float
    riccati_residual: float

    @property
    def closed_loop(self) -> np.ndarray:
        """A − B K, shape (n, n)."""
        return self.A - self.B @ self.K


def paper_weights(mode_frequency_hz, n_inputs: int, *, state_weight: float = PAPER_STATE_WEIGHT,
                  rigid_factor: float = PAPER_RIGID_FACTOR, rate_factor: float = PAPER_RATE_FACTOR):
    """The weights of Sec. V for a model with these modes.

    Parameters
    ----------
    mode_frequency_hz : array_like, shape (n_m,)
        Mode frequencies, Hz; a mode of frequency 0 is a rigid-body mode and gets ``rigid_factor``.
    n_inputs : int
        Number of thrusters m.
    state_weight, rigid_factor, rate_factor : float
        Q_x* = state_weight · diag(1 or rigid_factor); Q_x = diag(Q_x*, rate_factor · Q_x*).

    Returns
    -------
    Qx : ndarray, shape (2 n_m, 2 n_m)
    Qu : ndarray, shape (m, m), the identity.
    """
    f = np.asarray(mode_frequency_hz, dtype=float)
    star = state_weight * np.where(f == 0.0, rigid_factor, 1.0)
    return np.diag(np.concatenate([star, rate_factor * star])), np.eye(int(n_inputs))


def check_weights(Qx, Qu, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate the weights: shapes, finite, symmetric, Q_x ⪰ 0 and Q_u ≻ 0; every problem listed.

    Raises
    ------
    CdgpsError
        Naming ``Qx`` / ``Qu`` and what was expected.
    """
    problems = []
    out = []
    for name, M, size, strict in (("Qx", Qx, n, False), ("Qu", Qu, m, True)):
        M = np.asarray(M, dtype=float)
        out.append(M)
        if M.shape != (size, size):
            problems.append(f"{name}: expected shape ({size}, {size}), got {M.shape}")
            continue
        if not np.all(np.isfinite(M)):
            problems.append(f"{name}: every entry must be a finite number")
            continue
        if size and np.abs(M).max() > WEIGHT_MAX:
            problems.append(f"{name}: entries up to {np.abs(M).max():.3g}, expected at most {WEIGHT_MAX:g} in magnitude "
                            "(the gain depends only on the ratio of Qx to Qu: scale both down)")
            continue
        if not np.allclose(M, M.T, rtol=1e-12, atol=0.0):
            problems.append(f"{name}: must be symmetric")
            continue
        low = float(np.linalg.eigvalsh(M).min()) if size else 0.0
        scale = max(1.0, float(np.abs(M).max()))
        if strict and not low > 1e-12 * scale:
            problems.append(f"{name}: must be positive definite (smallest eigenvalue {low:.3g})")
        elif not strict and low < -1e-12 * scale:
            problems.append(f"{name}: must be positive semi-definite (smallest eigenvalue {low:.3g}); "
                            "negative weights are not allowed")
    if problems:
        raise CdgpsError("invalid LQR weights:\n  - " + "\n  - ".join(problems))
    return out[0], out[1]


def _pbh_rank_deficient(A: np.ndarray, M: np.ndarray, z: complex, stack_rows: bool) -> bool:
    """True when [zI − A, M] (or [zI − A; M]) loses rank: the PBH test at eigenvalue z."""
    n = A.shape[0]
    E = z * np.eye(n) - A
    T = np.vstack([E, M]) if stack_rows else np.hstack([E, M])
    s = np.linalg.svd(T, compute_uv=False)
    scale = max(1.0, float(np.abs(A).max()), float(np.abs(M).max()) if M.size else 0.0)
    return len(s) < n or s[n - 1] <= 1e-9 * scale


def unstable_uncovered_modes(A, B, Qx) -> tuple[list[complex], list[complex]]:
    """Eigenvalues with |z| ≥ 1 that the inputs cannot move, and those Q_x does not see.

    An LQR exists with a stabilizing gain if and only if (A, B) is stabilizable and (Q_x^{1/2}, A) is
    detectable; both are tested eigenvalue by eigenvalue (Popov–Belevitch–Hautus).

    Returns
    -------
    unreachable, unseen : list of complex
        Eigenvalues of A on or outside the unit circle failing each test.
    """
    A = np.asarray(A, float)
    w, V = np.linalg.eigh(np.asarray(Qx, float))
    C = (np.sqrt(np.clip(w, 0.0, None))[:, None] * V.T)
    unreachable, unseen = [], []
    for z in np.linalg.eigvals(A):
        if abs(z) < 1.0 - MARGINAL_TOLERANCE:
            continue
        if _pbh_rank_deficient(A, np.asarray(B, float), z, stack_rows=False):
            unreachable.append(complex(z))
        if _pbh_rank_deficient(A, C, z, stack_rows=True):
            unseen.append(complex(z))
    return unreachable, unseen


def design_lqr(A, B, Qx, Qu, sample_period_s: float, state_names=None) -> LqrDesign:
    """Discrete LQR gain for x_{k+1} = A x_k + B u_k (Eq. 4) and the cost of Eq. (24).

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
        Discrete model (N per thruster column).
    Qx, Qu : array_like, shape (n, n), (m, m)
        Weights, validated by :func:`check_weights`.
    sample_period_s : float
        Sample period of the model, s (> 0).
    state_names : sequence of str, optional
        Names of the states, used in the message when a mode cannot be stabilized or is not weighted.

    Returns
    -------
    LqrDesign

    Raises
    ------
    CdgpsError
        Invalid weights, an unstable or marginal mode the thrusters cannot move, or one the weights
        leave undetectable (e.g. zero weight on the rigid-body angle and rate).
    """
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    n, m = A.shape[0], B.shape[1]
    if A.shape != (n, n) or B.shape[0] != n or not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
        raise CdgpsError(f"LQR model: expected a finite square A and B with {n} rows, got {A.shape} and {B.shape}")
    if not (np.isfinite(sample_period_s) and sample_period_s > 0):
        raise CdgpsError(f"LQR model: sample period must be positive, got {sample_period_s!r} s")
    Qx, Qu = check_weights(Qx, Qu, n, m)
    unreachable, unseen = unstable_uncovered_modes(A, B, Qx)
    if unreachable or unseen:
        raise CdgpsError(_uncovered_message(A, unreachable, unseen, state_names))
    try:
        P = solve_discrete_are(A, B, Qx, Qu)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise CdgpsError(f"no LQR gain: the Riccati equation could not be solved with these weights ({exc}); "
                         "bring Qx and Qu closer in scale (--qx, --qu)") from None
    if not np.all(np.isfinite(P)):
        raise CdgpsError("no LQR gain: the Riccati solution overflowed with these weights; "
                         "bring Qx and Qu closer in scale (--qx, --qu)")
    P = 0.5 * (P + P.T)
    G = Qu + B.T @ P @ B
    K = np.linalg.solve(G, B.T @ P @ A)
    res = A.T @ P @ A - P - A.T @ P @ B @ K + Qx
    residual = float(np.linalg.norm(res) / max(1.0, np.linalg.norm(P)))
    return LqrDesign(A=A, B=B, Qx=Qx, Qu=Qu, K=K, P=P, sample_period_s=float(sample_period_s),
                     riccati_residual=residual)


def _uncovered_message(A, unreachable, unseen, state_names) -> str:
    lines = []
    for what, zs, fix in (("the thrusters cannot move", unreachable, "add or re-aim thrusters"),
                          ("the weights Qx leave undetectable", unseen,
                           "give its amplitude or rate a positive weight (--qx)")):
        for z in zs:
            lines.append(f"eigenvalue z = {z.real:.6f}{z.imag:+.6f}j ({_dominant_state(A, z, state_names)}): "
                         f"{what}; {fix}")
    return "no stabilizing LQR gain exists:\n  - " + "\n  - ".join(lines)


def _dominant_state(A, z, state_names) -> str:
    w, V = np.linalg.eig(A)
    v = np.abs(V[:, int(np.argmin(np.abs(w - z)))])
    i = int(np.argmax(v))
    return f"mostly {state_names[i]}" if state_names is not None else f"mostly state {i}"
