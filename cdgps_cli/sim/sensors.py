"""Simulated logs of the fusable sensors (accelerometers, tilt meters, rate gyros) from a structure
truth (issue 30 item 2).

The truth is the modal state of :func:`cdgps_cli.sim.structure.simulate` (zero-order hold at the
config's sample period); :func:`disturbance_truth` recovers the held modal-acceleration disturbance
d_k of each step from x_{k+1} = A x_k + B_d d_k (exact for the free scenario), so that an
accelerometer reads what the structure did over [t_k, t_{k+1}).  Each sensor of the config
(:func:`cdgps_cli.config.sensors.sensor_specs`) is read at its own sample period (a multiple of the
structure's) with, per axis, white noise σ, an initial bias N(0, bias σ²) and a bias random walk
(bias drift), in the units of its column names.  Pure computation: the CSV is written by the caller.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.registry import model_from_spec
from cdgps_cli.model.fusion_dynamics import ModalDisturbance

__all__ = ["disturbance_truth", "simulate_sensor_logs", "LOG_COLUMNS"]

#: the first columns of every sensor log
LOG_COLUMNS = ("time_s", "sensor")


def disturbance_truth(cfg: StructureConfig, x: np.ndarray) -> np.ndarray:
    """[ξ, ξ̇, d] (N, 2 n_m + r) of a ZOH trajectory x (N, 2 n_m) at the config's sample period (the
    last epoch's d, unknown, is 0)."""
    dyn = ModalDisturbance(cfg)
    A, _, _ = dyn.transition(cfg.sample_period_s)
    n2 = 2 * cfg.n_modes
    Bd = A[:n2, n2:]
    d = np.zeros((x.shape[0], dyn.r))
    if dyn.r and x.shape[0] > 1:
        resid = x[1:] - x[:-1] @ A[:n2, :n2].T
        d[:-1] = np.linalg.lstsq(Bd, resid.T, rcond=None)[0].T
    return np.hstack([x, d])


def simulate_sensor_logs(cfg: StructureConfig, specs, time_s, x_aug, seed: int = 0, time_offset_s: float = 0.0) -> dict:
    """Every sensor's log from the truth.

    Parameters
    ----------
    cfg : StructureConfig
    specs : list of SensorSpec
    time_s : ndarray (N,)
        Truth epochs (the config's sample period), s.
    x_aug : ndarray (N, 2 n_m + r)
        Truth [ξ, ξ̇, d] (:func:`disturbance_truth`).
    seed : int
    time_offset_s : float
        Added to the logs' time stamps (e.g. the GPS time of the first epoch).

    Returns
    -------
    dict
        {kind: DataFrame with ``time_s``, ``sensor`` and the kind's columns (units in the names;
        empty for an axis a sensor lacks)}, and ``"_truth"``: {sensor: {initial and final bias per column}}.
    """
    T = cfg.sample_period_s
    S = ModalDisturbance(cfg).S
    n_core = x_aug.shape[1]
    out, truth = {}, {}
    for i, sp in enumerate(specs):
        step = int(round(sp.sample_period_s / T))
        if step < 1 or abs(step * T - sp.sample_period_s) > 1e-9 * max(T, 1.0):
            raise CdgpsError(f"{cfg.path}: sensor {sp.name}: sample_period_s {sp.sample_period_s:g} s is not a multiple of "
                             f"the structure's sample_period_s {T:g} s")
        rng = np.random.default_rng([int(seed), 30, i])
        idx = np.arange(0, len(time_s), step)
        m = model_from_spec(cfg, sp, np.zeros((1, len(sp.axes))), [0], n_core, S=S, bias=False)
        clean = x_aug[idx] @ m.M.T
        na = clean.shape[1]
        b0 = rng.standard_normal(na) * (sp.bias_sigma or 0.0)
        walk = np.cumsum(rng.standard_normal((idx.size, na)) * sp.bias_drift * np.sqrt(step * T), axis=0)
        bias = b0 + walk - walk[0]
        vals = clean + bias + rng.standard_normal((idx.size, na)) * sp.sigma
        df = pd.DataFrame({"time_s": np.round(time_s[idx] + time_offset_s, 9), "sensor": sp.name,
                           **{f: np.round(vals[:, j], 12) for j, f in enumerate(m.fields)}})
        out.setdefault(sp.kind, []).append(df)
        truth[sp.name] = {"kind": sp.kind, "samples": int(idx.size),
                          **{f"initial_bias_{f}": float(bias[0, j]) for j, f in enumerate(m.fields)},
                          **{f"final_bias_{f}": float(bias[-1, j]) for j, f in enumerate(m.fields)}}
    logs = {k: pd.concat(v, ignore_index=True).sort_values(["time_s", "sensor"], kind="stable").reset_index(drop=True)
            for k, v in out.items()}
    return {**logs, "_truth": truth}
