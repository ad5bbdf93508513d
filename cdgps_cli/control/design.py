"""The regulator of a structure config: its discrete model, the paper's (or given) weights, the
gain and the open- and closed-loop poles, as one record (what GAINS.json holds)."""

from __future__ import annotations

import numpy as np

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.options import CONTROL_TUNED_WEIGHTS, CONTROL_WEIGHTS
from cdgps_cli.control.lqr import (PAPER_RATE_FACTOR, PAPER_RIGID_FACTOR, PAPER_STATE_WEIGHT, LqrDesign, design_lqr,
                                  paper_weights)
from cdgps_cli.control.poles import pole_table, slowest_settling_by_mode

#: the paper's literal weights (Sec. V) as keyword arguments of :func:`design_for_structure`
PAPER_WEIGHTS = {"qx": PAPER_STATE_WEIGHT, "rigid_factor": PAPER_RIGID_FACTOR, "rate_factor": PAPER_RATE_FACTOR}
#: the named weight sets of ``cdgps control design --weights`` (state weight W, f_rigid, f_rate; Q_u = I)
WEIGHT_SETS = {"paper": PAPER_WEIGHTS, "tuned": dict(CONTROL_TUNED_WEIGHTS)}


def weights_for(cfg: StructureConfig, qx=None, qu=None, rigid_factor: float | None = None,
                rate_factor: float | None = None, weights: str = CONTROL_WEIGHTS) -> tuple[np.ndarray, np.ndarray]:
    """Q_x and Q_u from the options.

    Parameters
    ----------
    cfg : StructureConfig
    qx : None, float or sequence of float
        None: the named set's state weight W in the paper's form Q_x* = W·diag(1, …, 1, f_rigid),
        Q_x = diag(Q_x*, f_rate·Q_x*).  One number: that W.  A sequence: the whole diagonal of Q_x,
        length 2 n_m (amplitudes, then rates).
    qu : None, float or sequence of float
        None: I.  One number: that multiple of I.  A sequence: the diagonal, one entry per thruster.
    rigid_factor, rate_factor : float, optional
        f_rigid and f_rate (None: the named set's; ignored for a full diagonal).
    weights : {"paper", "tuned"}
        The named set (:data:`WEIGHT_SETS`) the other options start from; default
        :data:`cdgps_cli.config.options.CONTROL_WEIGHTS`, the paper's.
    """
    n, m = 2 * cfg.n_modes, len(cfg.thruster_names)
    if m == 0:
        raise CdgpsError("the config defines no [[thrusters]]: there is nothing to control with")
    if weights not in WEIGHT_SETS:
        raise CdgpsError(f"weights: expected one of {', '.join(WEIGHT_SETS)}, got {weights!r}")
    base = WEIGHT_SETS[weights]
    rigid_factor = base["rigid_factor"] if rigid_factor is None else rigid_factor
    rate_factor = base["rate_factor"] if rate_factor is None else rate_factor
    for name, v in (("rigid_factor", rigid_factor), ("rate_factor", rate_factor)):
        if not (np.isfinite(v) and v >= 0):
            raise CdgpsError(f"{name}: expected a finite number >= 0, got {v!r}")
    q = np.atleast_1d(np.asarray(base["qx"] if qx is None else qx, dtype=float))
    if q.size == 1:
        Qx, Qu = paper_weights(cfg.mode_frequency_hz, m, state_weight=float(q[0]), rigid_factor=rigid_factor,
                               rate_factor=rate_factor)
    elif q.size == n:
        Qx, Qu = np.diag(q), np.eye(m)
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


def weight_set_name(cfg: StructureConfig, Qx: np.ndarray, Qu: np.ndarray) -> str:
    """The named set (:data:`WEIGHT_SETS`) whose Q_x and Q_u these are exactly, else ``"custom"``."""
    for name in WEIGHT_SETS:
        Qx_set, Qu_set = weights_for(cfg, weights=name)
        if np.array_equal(Qx, Qx_set) and np.array_equal(Qu, Qu_set):
            return name
    return "custom"


def state_names(cfg: StructureConfig) -> list[str]:
    """Names of x = [ξ, ξ̇]: the mode names, then ``<mode> rate``."""
    return [*cfg.mode_names, *(f"{n} rate" for n in cfg.mode_names)]


def design_for_structure(cfg: StructureConfig, qx=None, qu=None, rigid_factor: float | None = None,
                         rate_factor: float | None = None, weights: str = CONTROL_WEIGHTS) -> tuple[LqrDesign, dict]:
    """LQR design on the config's model discretized at its sample period, with the weights of
    :func:`weights_for` (by default the paper's).

    Returns
    -------
    design : LqrDesign
    poles : dict
        ``open_loop`` and ``closed_loop`` pole tables (:func:`cdgps_cli.control.poles.pole_table`) and
        ``settling_time_s`` per mode, open and closed loop.
    """
    model = discrete_model(cfg)
    Qx, Qu = weights_for(cfg, qx, qu, rigid_factor, rate_factor, weights)
    d = design_lqr(model.A, model.B, Qx, Qu, model.T, state_names(cfg))
    names = list(cfg.mode_names)
    ol, cl = pole_table(d.A, d.sample_period_s, names), pole_table(d.closed_loop, d.sample_period_s, names)
    return d, {"open_loop": ol, "closed_loop": cl,
               "settling_time_s": {"open_loop": slowest_settling_by_mode(ol),
                                   "closed_loop": slowest_settling_by_mode(cl)}}


def rigid_only_gain(cfg: StructureConfig, A: np.ndarray, B: np.ndarray, target_settling_s: float) -> np.ndarray:
    """The low-bandwidth regulator of the paper's Fig. 12: feedback of the rigid-body mode only.

    An LQR on the rigid-body amplitude and rate alone (weights w·diag(1, 0.01), Q_u = I), with w chosen
    by bisection so that the rigid-body pole settles (2 %) in ``target_settling_s``; the gain has zero
    columns for every elastic state, so A − B K is block triangular and the vibration poles stay
    where they are open loop.

    Returns
    -------
    ndarray, shape (m, n)
    """
    from cdgps_cli.control.poles import pole_table

    rigid = [i for i, f in enumerate(cfg.mode_frequency_hz) if f == 0.0]
    if len(rigid) != 1:
        raise CdgpsError("--no-vibration-control: needs exactly one rigid-body mode (frequency 0) in the config")
    nm = cfg.n_modes
    idx = [rigid[0], nm + rigid[0]]
    Ar, Br = A[np.ix_(idx, idx)], B[idx]
    T = cfg.sample_period_s

    def settle(w):
        d = design_lqr(Ar, Br, w * np.diag([1.0, PAPER_RATE_FACTOR]), np.eye(B.shape[1]), T)
        t = max(r["settling_time_s"] or np.inf for r in pole_table(d.closed_loop, T, ["rigid"]))
        return t, d.K

    lo, hi = -8.0, 8.0                                   # log10 of the weight
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        t, _ = settle(10.0**mid)
        lo, hi = (mid, hi) if t > target_settling_s else (lo, mid)
    _, Kr = settle(10.0**hi)
    K = np.zeros((B.shape[1], A.shape[0]))
    K[:, idx] = Kr
    return K
