"""The closed loop's estimator (1998 paper, Sec. IV–V): the EKF of Eqs. 19–23 run one step at a time
at the control rate, from carrier phases whose biases are known from the initialization.

It is the engine's information-form Kalman step (:func:`cdgps_cli.estimation.kalman.predict` and
:func:`~cdgps_cli.estimation.kalman.update`) on the modal model, stepped by the caller between
control periods, so the regulator can use each estimate before the next measurement.  Numerics only.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import block_diag

from cdgps_cli.estimation.kalman import predict, update

#: prior σ of the estimator's initial modal state, per unit of ξ and ξ̇ (the loop starts from a
#: converged initialization: the estimate starts at the truth with this small covariance)
INITIAL_ESTIMATE_SIGMA = 1e-3


class LoopFilter:
    """The control loop's EKF as a step filter: one :meth:`update` per measurement epoch, one
    :meth:`predict` per control period, on the engine's Kalman step (:mod:`cdgps_cli.estimation.kalman`).

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
        self.xb = np.concatenate([x0, np.zeros(self.C)])
        self.Pb = np.diag(np.r_[np.full(self.n, INITIAL_ESTIMATE_SIGMA**2), np.full(self.C, self.prior_m**2 if self.C else 0.0)])

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
        h_bar, H = h_of(self.xb[:self.n])
        if self.C:
            H = np.hstack([H, np.eye(self.C)])
            h_bar = h_bar + self.xb[self.n:]
        self.x, self.P, nis = update(self.xb, self.Pb, z_m - h_bar, H, sigma)
        return self.x[:self.n], self.P[:self.n, :self.n], nis

    def predict(self, known):
        """Predict over one period; ``known`` (n,) is the modal state change of the firings commanded."""
        self.xb, self.Pb = predict(self.x, self.P, self.A, self.Q, np.concatenate([known, np.zeros(self.C)]))
