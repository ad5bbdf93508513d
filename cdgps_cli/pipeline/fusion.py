"""GNSS fused with accelerometers, tilt meters and gyros on the structure's modal state (issue 30).

The mapping from (structure config, sensor logs, GNSS measurement models) to the engine's pieces:

* :func:`common_time_axis` — the filter's epochs: the union of the GNSS epochs and the sensors'
  samples within the GNSS span (the dynamics step at the fastest rate; an epoch carries the rows of
  the models sampled there, :class:`cdgps_cli.measurement.stacked.Stacked`);
* :func:`sensor_parts` — the measurement model of each fused sensor (kinds ``fuse``, names in
  ``hold_out`` left out as independent checks) from its log;
* :func:`fusion_problem` — the stacked model, the dynamics [ξ, ξ̇, d, biases]
  (:func:`cdgps_cli.model.fusion_dynamics.fusion_dynamics`) and the prior of the added states
  (d: its per-step covariance; biases: their prior σ);
* :func:`run_fused` — forward filter (:func:`cdgps_cli.estimation.model_filter.filter_numpy`) and
  RTS smoother (:func:`cdgps_cli.estimation.smoother.rts_smooth_transitions`) over it.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from cdgps_cli.config.sensors import FUSABLE_KINDS
from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.model_filter import filter_numpy
from cdgps_cli.estimation.smoother import rts_smooth_transitions
from cdgps_cli.measurement.registry import model_from_spec
from cdgps_cli.measurement.sensor import align_epochs, place
from cdgps_cli.measurement.stacked import Stacked
from cdgps_cli.model.fusion_dynamics import ModalDisturbance, fusion_dynamics

__all__ = ["common_time_axis", "sensor_parts", "fusion_problem", "run_fused", "parse_fuse", "SYNC_TOL_S"]

#: a sensor sample this close to a GNSS epoch is at that epoch, s
SYNC_TOL_S = 1e-4


def parse_fuse(text: str | None, option: str = "--fuse") -> tuple:
    """``"gyro,accel"`` → ("gyro", "accel"); CdgpsError naming ``option`` for an unknown kind."""
    if not text:
        return ()
    kinds = tuple(dict.fromkeys(k.strip() for k in text.split(",") if k.strip()))
    bad = [k for k in kinds if k not in FUSABLE_KINDS]
    if bad:
        raise CdgpsError(f"{option} {text}: unknown sensor kind(s) {', '.join(bad)} (expected a comma-separated list of "
                         f"{', '.join(FUSABLE_KINDS)})")
    return kinds


def common_time_axis(t_gnss, sensor_times, tol_s: float = SYNC_TOL_S) -> np.ndarray:
    """The union of the GNSS epochs and the sensor samples within their span (samples within
    ``tol_s`` of an epoch merged into it), sorted, s."""
    t = np.asarray(t_gnss, dtype=float)
    extra = [np.asarray(s, float) for s in sensor_times if len(s)]
    if not extra:
        return t.copy()
    s = np.unique(np.concatenate(extra))
    s = s[(s >= t[0] - tol_s) & (s <= t[-1] + tol_s)]
    allt = np.unique(np.concatenate([t, s]))
    keep = np.r_[True, np.diff(allt) > tol_s]
    return allt[keep]


def sensor_parts(cfg: StructureConfig, specs, logs: dict, t_common, fuse, hold_out=(), S=None) -> list:
    """[(name, model)] of the fused sensors: kinds in ``fuse``, names not in ``hold_out``; ``logs``
    {kind: DataFrame with time_s, sensor and the kind's columns}; S the accelerometers' disturbance
    selection (None: state [ξ, ξ̇])."""
    unknown = [h for h in hold_out if h not in {s.name for s in specs}]
    if unknown:
        raise CdgpsError(f"--hold-out: {', '.join(unknown)} is not a sensor of config {cfg.name!r} "
                         f"(sensors: {', '.join(s.name for s in specs) or 'none'})")
    n_core = 2 * cfg.n_modes + (0 if S is None else S.shape[1])
    parts = []
    for sp in specs:
        if sp.kind not in fuse or sp.name in hold_out:
            continue
        df = logs.get(sp.kind)
        rows = None if df is None else df[df["sensor"] == sp.name]
        if rows is None or rows.empty:
            raise CdgpsError(f"--fuse {sp.kind}: no log of sensor {sp.name!r} in the run (ingest its CSV with the "
                             f"GNSS config's sensors key), or keep it out with --hold-out {sp.name}")
        probe = model_from_spec(cfg, sp, np.zeros((1, len(sp.axes))), [0], n_core, S=S)
        missing = [f for f in probe.fields if f not in rows.columns]
        if missing:
            raise CdgpsError(f"sensor {sp.name}: its log has no column(s) {', '.join(missing)}")
        k_of = align_epochs(t_common, rows["time_s"].to_numpy(float), SYNC_TOL_S)
        parts.append((sp.name, model_from_spec(cfg, sp, rows[probe.fields].to_numpy(float), k_of, n_core, S=S)))
    return parts


def fusion_problem(cfg: StructureConfig, gnss_parts: list, sensor_parts_: list, P0_modal, disturbance: bool = True):
    """(model, dyn, P0, state names of the added states) of GNSS parts on [ξ, ξ̇] and sensor parts
    (placed after the core states, in order)."""
    core = ModalDisturbance(cfg) if disturbance else None
    n_core = 2 * cfg.n_modes + (core.r if core else 0)
    models = [m for _, m in sensor_parts_]
    n = place(models, n_core)
    dyn, names, prior = fusion_dynamics(cfg, models, disturbance=disturbance)
    if dyn.n != n:
        raise AssertionError("fusion state layout")
    P0 = np.zeros((n, n))
    k = 2 * cfg.n_modes
    P0[:k, :k] = P0_modal
    if core is not None:
        P0[k:n_core, k:n_core] = core.W_d
    P0[n_core:, n_core:] = np.diag(prior**2)
    d_names = [f"d_{cfg.mode_names[i]}" for i in np.flatnonzero(core.S.any(axis=1))] if core else []
    return Stacked(list(gnss_parts) + list(sensor_parts_), n), dyn, P0, d_names + names


def run_fused(model, dyn, time_s, x0, P0, smooth: bool = True, max_iterations: int = 5, rows_hook=None):
    """Forward filter and (``smooth``) RTS smoother over the stacked model: SimpleNamespace with ``x``,
    ``P`` (reported: smoothed or filtered), ``x_filt``, ``P_filt``, ``nis``, ``nis_dof``, ``rows``."""
    fr = filter_numpy(model, dyn, np.asarray(time_s, float), x0, P0, max_iterations, rows_hook=rows_hook)
    xs, Ps = rts_smooth_transitions(fr["x"], fr["P"], fr["A"], fr["Q"]) if smooth else (fr["x"], fr["P"])
    return SimpleNamespace(x=xs, P=Ps, x_filt=fr["x"], P_filt=fr["P"], nis=fr["nis"], nis_dof=fr["nis_dof"], rows=fr["rows"])


