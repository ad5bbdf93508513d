"""The closed loop's estimator (1998 paper, Sec. IV–V): the EKF of Eqs. 19–23 run one step at a time
at the control rate, from carrier phases whose biases are known from the initialization.

It is the engine's forward filter step (:class:`cdgps_cli.estimation.kalman.StepFilter`: predict, and
the information-form update through the measurement-model interface, not iterated) on the modal
model, stepped by the caller between control periods, so the regulator can use each estimate before
the next measurement.  Numerics only.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import block_diag

from cdgps_cli.estimation.kalman import StepFilter
from cdgps_cli.measurement.model import MeasurementModel, Rows

#: prior σ of the estimator's initial modal state, per unit of ξ and ξ̇ (the loop starts from a
#: converged initialization: the estimate starts at the truth with this small covariance)
INITIAL_ESTIMATE_SIGMA = 1e-3


class _LoopPhases(MeasurementModel):
    """The loop's measurement model: every channel's phase h(x) = h_of(ξ) (+ its multipath state).

    Parameters
    ----------
    h_of : callable
        ``h_of(x) -> (h (C,), H (C, n))`` on the modal state.
    n : int
        Modal states.
    n_mp : int
        Multipath states (0, or one per channel after the modal states).
    """

    def __init__(self, h_of, n: int, n_mp: int):
        self.h_of, self.n, self.n_mp = h_of, n, n_mp
        self.n_state = n + n_mp

    def predict(self, x, rows):
        h, H = self.h_of(x[:self.n])
        if self.n_mp:
            H = np.hstack([H, np.eye(self.n_mp)])
            h = h + x[self.n:]
        return h, H


class LoopFilter:
    """The control loop's EKF as a step filter: one :meth:`update` per measurement epoch, one
    :meth:`predict` per control period, on the engine's step (:class:`~cdgps_cli.estimation.kalman.StepFilter`).

    The state is the structure's n modal states, plus C first-order Gauss–Markov phase-error states
    (one per channel, :mod:`cdgps_cli.measurement.multipath`) when ``multipath`` is active — the
    augmentation the estimation pipeline makes with ``[model] multipath_sigma_m``.

    Parameters
    ----------
    A : ndarray, shape (n, n)
        Discrete transition of the modal state over one period.
    Q : ndarray, shape (n, n)
        Process-noise covariance per period (the loop passes the config's, scaled).
    C : int
        Number of phase channels.
    multipath : MultipathModel or None
    T : float
        Period, s.
    """

    def __init__(self, A, Q, C: int, multipath, T: float):
        self.n = A.shape[0]
        self.C = C if (multipath is not None and multipath.active) else 0
        if self.C:                     # m_{k+1} = a m_k + √q ω_k per channel (cdgps_cli.measurement.multipath)
            self.A = block_diag(A, np.eye(C) * multipath.transition(T))
            self.Q = block_diag(Q, np.eye(C) * multipath.process_variance_m2(T))
            self.prior_m = multipath.sigma_m
        else:
            self.A, self.Q = A, Q

    def start(self, x0):
        """Estimate at the truth with covariance (INITIAL_ESTIMATE_SIGMA)² I; multipath at its stationary prior."""
        P0 = np.diag(np.r_[np.full(self.n, INITIAL_ESTIMATE_SIGMA**2), np.full(self.C, self.prior_m**2 if self.C else 0.0)])
        self.step = StepFilter(np.concatenate([x0, np.zeros(self.C)]), P0)

    def update(self, z_m, h_of, sigma):
        """The update with one epoch's phases.

        Parameters
        ----------
        z_m : ndarray, shape (C,)
            Carrier phase of every channel, biases removed, m.
        h_of : callable
            ``h_of(x) -> (h (C,), H (C, n))``, the phase model and its Jacobian at the modal state x.
        sigma : ndarray, shape (C,)
            Phase σ per channel, m.

        Returns
        -------
        x : ndarray, shape (n,)
            The structure's estimate after the update.
        P : ndarray, shape (n, n)
            Its covariance.
        nis : float
            Normalized innovation squared of the epoch.
        """
        z = np.asarray(z_m, dtype=float)
        rows = Rows(z, [], np.full(z.size, -1), sigma_m=np.broadcast_to(np.asarray(sigma, dtype=float), z.shape))
        nis = self.step.update(_LoopPhases(h_of, self.n, self.C), rows, max_iterations=1)
        return self.step.x[:self.n], self.step.P[:self.n, :self.n], nis

    def predict(self, known):
        """Predict over one period; ``known`` (n,) is the modal state change of the firings commanded."""
        self.step.predict(self.A, self.Q, np.concatenate([known, np.zeros(self.C)]))
