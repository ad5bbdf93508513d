"""The regulator of a structure config: its discrete model, the paper's (or given) weights, the
gain and the open- and closed-loop poles, as one record (what GAINS.json holds)."""

from __future__ import annotations

import numpy as np

from ..config import StructureConfig
from ..dynamics import discrete_model
from ..errors import CdgpsError
from .lqr import LqrDesign, design_lqr, paper_weights
from .poles import pole_table, slowest_settling_by_mode


def weights_for(cfg: StructureConfig, qx=None, qu=None) -> tuple[np.ndarray, np.ndarray]:
    """Q_x and Q_u from the options.

    Parameters
    ----------
    cfg : StructureConfig
    qx : None, float or sequence of float
        None: the paper's Q_x (Sec. V).  One number: the paper's form with that state weight in place of
        5000.  A sequence: the whole diagonal of Q_x, length 2 n_m (amplitudes, then rates).
    qu : None, float or sequence of float
        None: I.  One number: that multiple of I.  A sequence: the diagonal, one entry per thruster.
    """
    n, m = 2 * cfg.n_modes, len(cfg.thruster_names)
    if m == 0:
        raise CdgpsError("the config defines no [[thrusters]]: there is nothing to control with")
    Qx, Qu = paper_weights(cfg.mode_frequency_hz, m)
    if qx is not None:
        q = np.atleast_1d(np.asarray(qx, dtype=float))
        if q.size == 1:
            Qx, _ = paper_weights(cfg.mode_frequency_hz, m, state_weight=float(q[0]))
        elif q.size == n:
            Qx = np.diag(q)
        else:
            raise CdgpsError(f"qx: expected one number or {n} numbers (the diagonal: {cfg.n_modes} amplitudes, "
                             f"then {cfg.n_modes} rates), got {q.size}")
    if qu is not None:
        q = np.atleast_1d(np.asarray(qu, dtype=float))
        if q.size == 1:
            Qu = float(q[0]) * np.eye(m)
        elif q.size == m:
            Qu = np.diag(q)
        else:
            raise CdgpsError(f"qu: expected one number or {m} numbers (one per thruster), got {q.size}")
    return Qx, Qu


def state_names(cfg: StructureConfig) -> list[str]:
    """Names of x = [ξ, ξ̇]: the mode names, then ``<mode> rate``."""
    return [*cfg.mode_names, *(f"{n} rate" for n in cfg.mode_names)]


def design_for_structure(cfg: StructureConfig, qx=None, qu=None) -> tuple[LqrDesign, dict]:
    """LQR design on the config's model discretized at its sample period.

    Returns
    -------
    design : LqrDesign
    poles : dict
        ``open_loop`` and ``closed_loop`` pole tables (:func:`cdgps_cli.control.poles.pole_table`) and
        ``settling_time_s`` per mode, open and closed loop.
    """
    model = discrete_model(cfg)
    Qx, Qu = weights_for(cfg, qx, qu)
    d = design_lqr(model.A, model.B, Qx, Qu, model.T, state_names(cfg))
    names = list(cfg.mode_names)
    ol, cl = pole_table(d.A, d.sample_period_s, names), pole_table(d.closed_loop, d.sample_period_s, names)
    return d, {"open_loop": ol, "closed_loop": cl,
               "settling_time_s": {"open_loop": slowest_settling_by_mode(ol),
                                   "closed_loop": slowest_settling_by_mode(cl)}}
