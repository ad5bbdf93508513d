"""A modal structure model on GNSS double differences (docs/gnss-pipeline.md, "Modal structure
model on a GNSS run").

The structure path (``configs/*.toml``, docs/config-format.md) describes a structure by its
coordinates q = U ξ, its sections and antennas, and the modal dynamics of x = [ξ, ξ̇].  This module
runs that model on a GNSS RUN (RINEX/UBX receivers, broadcast ephemerides):

* **placement** — the structure frame is put on the Earth by :class:`StructurePlacement`: the
  master antenna's nominal structure position p_M(0) is the master receiver's position (ECEF), and
  the structure axes are the local east/north/up axes at the master turned about the vertical so
  that x points to ``x_axis_azimuth_deg`` (clockwise from north; the default 90° gives x = east,
  y = north, z = up);
* **integers** — fixed by the existing GNSS init (``cdgps init``: one baseline per rover receiver,
  random-walk or static float solution, LAMBDA), read from INIT.json; segments left float are not
  used, nor is a rover without any fixed integer (event ``no integer fixed``);
* **measurements** — for every rover antenna a, satellite j and the epoch's reference satellite r
  (chosen per rover among its fixed segments), the L1 DD with the integers removed,
  ``z = λ·DD − λ·N − (DD of the geometric ranges at the receivers' nominal positions)``, modelled in
  the far field (planar wavefront) as

      z = −(s_j − s_r)ᵀ [(p_a(q) − p_M(q)) − d_a] + ν

  where s are unit vectors from the master to the satellites in the structure frame at that epoch
  (from the broadcast ephemerides, time-varying) and d_a = the receiver's nominal (RINEX header /
  config) position relative to the master, in the structure frame (so a header position that is
  not exactly the structure's nominal position is accounted for).  Cov(ν) = D Σ Dᵀ per epoch over
  all rovers jointly: Σ has each receiver's undifferenced phase variance (the run's weighting,
  a² + b²/sin²el) and the master's variance enters every rover's single difference of the same
  satellite, so the DDs of different rovers are correlated through the common master;
* **filter** — an extended Kalman filter of x over the epochs (the discrete model of
  :mod:`cdgps_cli.model.dynamics` at the epoch spacing, process noise scaled to keep the config's noise
  density), measurement update in information form on the DDs whitened by the Cholesky factor of
  their covariance (R = I), iterated (Gauss-Newton) while the correction is large; prior x = 0 with
  the covariance of :func:`modal_prior_covariance` (the stationary spread of the modal process
  noise plus ``initial_sigma_xi``, ``initial_sigma_xidot``: the batch initialization's prior too); optional
  Rauch-Tung-Striebel smoother;
* **output** — STATES.mcap through :func:`cdgps_cli.io.states.write_states` (coordinates = the
  structure's q names, so ``cdgps export`` / ``cdgps evaluate`` work), DD residuals per antenna and
  satellite, NIS, and the GNSS events (slips, gaps, reference changes, unfixed ambiguities).

:func:`simulate_structure_gnss` simulates the structure's free motion (:func:`cdgps_cli.sim.structure.simulate`)
and the GPS L1 observations of every antenna's receiver (:func:`cdgps_cli.model.gps.positioning.simulate_static_pair`,
one independent receiver per antenna, the master moving too) as RINEX files with truth.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli import __version__
from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.io.coordinate_columns import coordinate_columns
from cdgps_cli.io.gnss_run import antennas_info
from cdgps_cli.config.options import (ESTIMATE_CHUNK_EPOCHS, MODAL_INIT_CODE_DD, MODAL_INITIAL_SIGMA_XI, MODAL_INITIAL_SIGMA_XIDOT,
                                      SCENE_EXAGGERATION, SCENE_SKY_STEP_S, SIM_MASTER_ECEF_M, X_AXIS_AZIMUTH_DEG)

from cdgps_cli.core.gps_time import gps_time_str
from cdgps_cli.measurement.differencing import joint_dd_covariance, sd_variance, select_reference
from cdgps_cli.measurement.model import SatelliteDDModal, dd_modal_h_and_H
from cdgps_cli.model.dynamics_models import ModalZOH
from cdgps_cli.estimation import kernel
from cdgps_cli.estimation.filter import EstimateOptions
from cdgps_cli.estimation.model_filter import filter_dd_kernel, filter_numpy, outlier_gate
from cdgps_cli.estimation.smoother import rts_smooth_indexed
from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.kinematics import antenna_positions
from cdgps_cli.pipeline.gnss import rover_segments

__all__ = ["StructurePlacement", "structure_to_ecef", "nominal_receiver_positions", "gnss_modal_estimate", "gnss_modal_init",
           "modal_batch_initialization", "apply_modal_record",
           "simulate_structure_gnss", "joint_dd_covariance"]


# ----------------------------------------------------------------------------------------------
# placement of the structure frame


@dataclass(frozen=True)
class StructurePlacement:
    """Where the structure frame is on the Earth.

    Attributes
    ----------
    master_ecef_m : tuple of 3 floats
        ECEF position of the master antenna's nominal position p_M(0), m.
    x_axis_azimuth_deg : float
        Azimuth of the structure x axis, degrees clockwise from north (90: x = east, y = north);
        z is the local vertical (up) at the master.
    """

    master_ecef_m: tuple
    x_axis_azimuth_deg: float = X_AXIS_AZIMUTH_DEG

    def rotation(self) -> np.ndarray:
        """R (3, 3): ECEF vector = R @ structure-frame vector."""
        lat, lon, _ = ecef_to_geodetic(np.asarray(self.master_ecef_m, dtype=np.float64))
        E = enu_matrix(lat, lon)                                  # rows: east, north, up in ECEF
        az = math.radians(self.x_axis_azimuth_deg)
        x_enu = np.array([math.sin(az), math.cos(az), 0.0])
        y_enu = np.array([-math.cos(az), math.sin(az), 0.0])
        R_enu = np.column_stack([x_enu, y_enu, [0.0, 0.0, 1.0]])  # structure → ENU
        return E.T @ R_enu


def structure_to_ecef(cfg: StructureConfig, placement: StructurePlacement, p_struct: np.ndarray) -> np.ndarray:
    """ECEF positions (…, 3) of structure-frame points (…, 3) under ``placement``."""
    p0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)))[0]
    pm0 = p0[cfg.master_index]
    return np.asarray(placement.master_ecef_m, float) + (np.asarray(p_struct, float) - pm0) @ placement.rotation().T


def nominal_receiver_positions(cfg: StructureConfig, placement: StructurePlacement) -> dict:
    """{antenna name: ECEF position at q = 0}."""
    p0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)))[0]
    x = structure_to_ecef(cfg, placement, p0)
    return {n: x[i] for i, n in enumerate(cfg.antenna_names)}


# ----------------------------------------------------------------------------------------------
# per-rover measurement tables from the GNSS machinery


def _rover_tables(run, init, r, stations, progress):
    from cdgps_cli.pipeline.gnss import _events, solve_with_init_integers  # noqa: PLC0415

    progress(f"baseline {run.master} → {r}: DDs with INIT's integers …")
    res, w, _, opt = solve_with_init_integers(run, init, r, stations)
    d = w["data"]
    n_fixed = res["ambiguities"]["n_fixed"]
    # only segments with a known integer (fixed, or the datum pivot of its set) enter; a rover without
    # any fixed integer is not used (its float ambiguities would bias the modal states)
    use = w["known_seg"][w["seg"]] if n_fixed else np.zeros(w["seg"].size, dtype=bool)
    # SD residual at the nominal rover position, m (the integers are removed by _set_integers)
    los = d.rover_sat_xyz - w["xr0"]
    rng = np.linalg.norm(los, axis=1)
    r_raw = d.y_phase_m - (rng + d.rover_clk_trop_m - d.base_model_m)
    rc = d.y_code_m - (rng + d.rover_clk_trop_m - d.base_model_m)      # SD code residual, m (NaN: missing)
    # undifferenced variances of each receiver (the run's weighting): σ²(el) = sd_variance(el, el) / 2
    va = 0.5 * sd_variance(d.el_rover, d.el_rover, sigma_a_m=opt.sigma_a_m, sigma_b_m=opt.sigma_b_m, weighting=opt.weighting)
    vm = 0.5 * sd_variance(d.el_base, d.el_base, sigma_a_m=opt.sigma_a_m, sigma_b_m=opt.sigma_b_m, weighting=opt.weighting)
    ev = _events(r, run.master, res, w)
    if not n_fixed:
        ev.append({"time_s": float(d.t_label[0]), "antenna": r, "transmitter": "", "kind": "no integer fixed",
                   "action": "receiver not used"})
    # only what the modal integers, the filter and the outputs read is kept (issue 29): not the baseline's
    # result, working arrays (weights, per-epoch blocks, residuals) nor the rest of its SD table
    tb = {"res": None, "w": {"known_seg": w["known_seg"]}, "d": _slim_data(d), "r_raw": r_raw, "rc": rc,
          "code_ratio": float(opt.code_ratio), "seg": w["seg"], "var_rover": va, "var_master": vm,
          "events": ev, "n_fixed": int(n_fixed), "n_estimated": int(res["ambiguities"]["n_estimated"]),
          "xr0": np.asarray(w["xr0"], float), "xm": np.asarray(w["xm"], float)}
    return _set_integers(tb, w["a_seg"], use)


#: the fields of a baseline's SD table (:class:`cdgps_cli.estimation.baseline._Data`) read after
#: :func:`_rover_tables`: by :func:`_set_integers`, the modal batch initialization, the filter and the outputs
_SETUP_DATA_FIELDS = ("ptr", "epoch", "sat", "sat_names", "t_label", "el_rover", "slip", "rover_sat_xyz")


def _slim_data(d) -> SimpleNamespace:
    """The baseline SD table ``d`` reduced to :data:`_SETUP_DATA_FIELDS` (the same arrays, not copies)."""
    return SimpleNamespace(**{k: getattr(d, k) for k in _SETUP_DATA_FIELDS})


def _set_integers(tb: dict, a_seg: np.ndarray, use: np.ndarray) -> dict:
    """The table's rows with the SD integers ``a_seg`` (cycles, per segment) removed: ``r0`` (m, each
    epoch's mean over the usable rows removed — the receiver clock difference, which cancels in the
    DDs), ``use`` (rows entering) and the reference row per epoch among them."""
    d = tb["d"]
    r0 = tb["r_raw"] - tb.get("lam_m", GPS_L1_WAVELENGTH_M) * np.asarray(a_seg)[tb["seg"]]
    cnt = np.bincount(d.epoch, weights=use.astype(float), minlength=d.t_label.size)
    mean = np.bincount(d.epoch, weights=np.where(use, r0, 0.0), minlength=d.t_label.size) / np.maximum(cnt, 1.0)
    ref = select_reference(d.ptr, d.sat, d.el_rover, d.slip, usable=use)
    return dict(tb, r0=r0 - mean[d.epoch], use=use, ref=ref, a_seg=np.asarray(a_seg, float))


INIT_WINDOW_S = 60.0            # default window of the modal batch initialization, s
INIT_WINDOW_GROWTH = 1.5        # a window whose integers are not all fixed is extended this many times …
INIT_WINDOW_MAX_FACTOR = 3.0    # … up to this multiple of the first window
MIN_INIT_EPOCHS = 10


def _init_window(t_all: np.ndarray, window_s: float) -> tuple[np.ndarray, float]:
    """The first epochs within ``window_s`` of the start on a regular grid (stops at the first gap)."""
    idx = np.flatnonzero(t_all < t_all[0] + window_s - 1e-9)
    dt = np.diff(t_all[idx])
    if dt.size == 0:
        raise CdgpsError("modal batch initialization: fewer than two epochs in the window")
    bad = np.flatnonzero(np.abs(dt - dt[0]) > 1e-6 * max(dt[0], 1.0))
    if bad.size:
        idx = idx[:bad[0] + 1]
    if idx.size < MIN_INIT_EPOCHS:
        raise CdgpsError(f"modal batch initialization: only {idx.size} regularly spaced epochs at the start "
                         f"(need {MIN_INIT_EPOCHS})")
    return idx, float(dt[0])


def modal_batch_initialization(cfg: StructureConfig, R, tabs, k_of, ant_idx, d_hdr, t_all, *,
                               window_s: float = INIT_WINDOW_S, options=None,
                               max_window_factor: float = INIT_WINDOW_MAX_FACTOR, code_dd: bool = MODAL_INIT_CODE_DD,
                               prior_cov=None):
    """Model-aided batch initialization of the modal state on the satellite DDs (the paper's method).

    On the first ``window_s`` seconds (extended ×INIT_WINDOW_GROWTH, up to INIT_WINDOW_MAX_FACTOR ×
    ``window_s`` and the end of the regular epochs, while not every integer is fixed and validated;
    ``windows_tried`` in the record then lists each attempt), every rover's DDs with *float* ambiguities (one per pair of
    satellite and reference segments, :class:`~cdgps_cli.measurement.model.SatelliteDDModal`) and
    the modal dynamics are solved by :func:`cdgps_cli.estimation.model_init.model_batch_init`
    (Gauss–Newton over [x₁, w, b], SRIF, LAMBDA + ratio + partial fixing, validation).  The fixed DD
    integers replace INIT's: per rover, a fixed DD ambiguity N of (satellite segment s_j, reference
    segment s_r) sets a(s_j) = a(s_r) + N on INIT's datum.  INIT's fixed segments that the window did
    not fix (other segments, or a partial fix) are kept when the window's references are INIT-known
    segments (the same datum).

    Returns
    -------
    tabs : list of dict
        The tables with the integers applied (:func:`_set_integers`).
    x1 : ndarray (2 n_m,)
        The batch trajectory's state at the first epoch (the filter's starting point).
    record : dict
        Window, counts, ratio, note, agreement with INIT's integers, per-segment floats/integers.
    """
    tried = []
    w_s = window_s
    while True:
        # the window grows (×INIT_WINDOW_GROWTH, up to INIT_WINDOW_MAX_FACTOR × the first) until
        # every DD integer is fixed and validated, as a recursive RTK engine keeps accumulating data
        # until its ratio test passes; a longer window can only add information
        try:
            idx_w, dt = _init_window(t_all, w_s)
            res_w, model, lam = _solve_window(cfg, R, tabs, k_of, ant_idx, d_hdr, idx_w, dt, options, code_dd, prior_cov)
        except CdgpsError as exc:           # (a longer window refused: the last solved one stands)
            if not tried:
                raise
            tried.append({"window_s": float(w_s), "refused": str(exc)})
            idx_w = None
        if idx_w is not None:
            idx, res = idx_w, res_w
            tried.append({"window_s": float(w_s), "epochs": int(idx.size), "n_segments": len(res.columns),
                          "n_fixed": int(res.fixed.sum()), "integer_fixing": res.note})
        longest = max(float(max_window_factor), 1.0) * window_s
        if res.fixed.all() or w_s >= longest - 1e-9 or (idx_w is not None and t_all[idx[-1]] < t_all[0] + w_s - 2 * dt):
            break
        w_s = min(w_s * INIT_WINDOW_GROWTH, longest)
    init_known = [np.asarray(tb["w"]["known_seg"], bool) & (tb["n_fixed"] > 0) for tb in tabs]
    segs, agree, n_cmp = [], 0, 0
    seg_ids = [_segment_satellites(tb) for tb in tabs]          # (satellite, first time) of every segment
    for i, col in enumerate(res.columns):
        a, sj, sr = model.segment_keys[col]
        if res.fixed[i] and init_known[a][sj] and init_known[a][sr]:
            n_cmp += 1
            agree += int(round(tabs[a]["a_seg"][sj] - tabs[a]["a_seg"][sr]) == res.integers[i])
        names, first_s = seg_ids[a]
        segs.append({"rover_slot": int(a), "satellite": names[sj], "reference": names[sr],
                     "first_s": float(first_s[sj]),
                     "segment": int(sj), "reference_segment": int(sr), "float_cycles": float(res.float_bias_m[i] / lam[a]),
                     "sigma_cycles": float(res.float_sigma_m[i] / lam[a]), "integer_cycles": int(res.integers[i]),
                     "fixed": bool(res.fixed[i]), **({"signal": tabs[a]["signal"]} if "signal" in tabs[a] else {})})
    record = {"method": "model-aided batch (Gauss–Newton over [x1, w, b] on the DDs, SRIF; LAMBDA, ratio, partial)",
              "window": {"start_s": float(t_all[idx[0]]), "end_s": float(t_all[idx[-1]]), "epochs": int(idx.size),
                         "interval_s": dt},
              "n_segments": len(res.columns), "n_fixed": int(res.fixed.sum()),
              "ratio": None if res.ratio is None else (float(res.ratio) if np.isfinite(res.ratio) else "inf"),
              "integer_fixing": res.note, "cost_per_dof": float(res.cost_per_dof), "iterations": int(res.iterations),
              "agree_with_init": {"compared": n_cmp, "equal": agree}, "x1": [float(v) for v in res.x[0]], "segments": segs}
    if len(tried) > 1:
        record["windows_tried"] = tried
    if tabs and "signal" in tabs[0]:     # signal path: no INIT integers for later segments → later windows
        record["later_segments"], record["later_windows"] = _later_windows(
            cfg, R, apply_modal_record(tabs, record), k_of, ant_idx, d_hdr, t_all, window_s, float(t_all[idx[-1]]) + 1e-6,
            code_dd, prior_cov)
    return apply_modal_record(tabs, record), res.x[0].copy(), record


def _solve_window(cfg, R, tabs, k_of, ant_idx, d_hdr, idx, dt, options=None, code_dd: bool = MODAL_INIT_CODE_DD,
                  prior_cov=None):
    """The batch initialization of every slot's DDs, all ambiguities float, on the epochs ``idx``
    (:func:`cdgps_cli.estimation.model_init.model_batch_init`, x₁'s prior ``prior_cov``, default
    :func:`modal_prior_covariance`): (result, its model, λ per slot).
    ``code_dd``: with the pseudorange DDs of the slots that have them (``rc``)."""
    from cdgps_cli.estimation.initializer import InitOptions  # noqa: PLC0415
    from cdgps_cli.estimation.model_init import model_batch_init  # noqa: PLC0415

    raw = [dict(tb, r0=tb["r_raw"], use=np.ones(tb["seg"].size, dtype=bool),
                ref=select_reference(tb["d"].ptr, tb["d"].sat, tb["d"].el_rover, tb["d"].slip)) for tb in tabs]
    model = SatelliteDDModal(cfg, R, raw, k_of, ant_idx, d_hdr, code=code_dd and all("rc" in tb for tb in tabs))
    lam = [tb.get("lam_m", GPS_L1_WAVELENGTH_M) for tb in tabs]
    res = model_batch_init(model, ModalZOH(cfg), idx, dt, lambda col: lam[model.segment_keys[col][0]], options or InitOptions(),
                           prior_cov=modal_prior_covariance(cfg) if prior_cov is None else prior_cov)
    return res, model, lam


def modal_prior_covariance(cfg: StructureConfig, sigma_xi: float = MODAL_INITIAL_SIGMA_XI,
                           sigma_xidot: float = MODAL_INITIAL_SIGMA_XIDOT) -> np.ndarray:
    """The prior covariance (2 n_m, 2 n_m) of the modal state [ξ, ξ̇] at the first epoch, about 0: the
    stationary covariance of the modal dynamics driven by the configured process noise (at the
    model's own sample period: the continuous process; a coarser zero-order hold would misstate a
    mode near its Nyquist frequency; none when a mode is undamped or rigid) plus diag(σ_ξ², σ_ξ̇²)
    for a record that does not start in the stationary state (a structure released, a storm).
    The batch initialization's regulariser (a mode the window cannot see, such as one at the GNSS
    Nyquist frequency, stays at its prior instead of taking any value) and the filter's start."""
    from cdgps_cli.estimation.model_init import stationary_covariance  # noqa: PLC0415

    nm = cfg.n_modes
    A, _, Q = ModalZOH(cfg).transition(cfg.sample_period_s)
    P = stationary_covariance(A, Q)
    broad = np.diag(np.r_[np.full(nm, float(sigma_xi) ** 2), np.full(nm, float(sigma_xidot) ** 2)])
    return broad if P is None else P + broad


def _later_windows(cfg, R, tabs, k_of, ant_idx, d_hdr, t_all, window_s: float, t_from: float,
                   code_dd: bool = MODAL_INIT_CODE_DD, prior_cov=None) -> tuple[list, list]:
    """Signal path: integers of the segments starting after the first window (rising satellites, slips).

    A window of ``window_s`` opens where the first segment not yet known and observed for at least
    half a window more (a new one, or one the previous window left float) is seen, and is solved as the first
    (all DD ambiguities float, :func:`_solve_window`); its fixed DD integers N of (s_j, s_r) are first
    checked where both segments are already known (a disagreement rejects the window), then chained
    onto the datum: a(s_j) = a(s_r) + N when only s_r is known (and a(s_r) = a(s_j) − N the other way).
    The next window opens after this one.  ``tabs`` carry the first window's integers (``use``,
    ``a_seg``).  Returns ([{rover_slot, segment, a_cycles}], [per-window summary])."""
    a_cur = [np.array(tb["a_seg"], float) for tb in tabs]
    names = [_segment_satellites(tb)[0] for tb in tabs]
    known = [np.isin(np.arange(a.size), tb["seg"][tb["use"]]) for a, tb in zip(a_cur, tabs)]
    first_t, last_t = [], []
    for a, tb in zip(a_cur, tabs):
        t_row = tb["d"].t_label[tb["d"].epoch]
        ft, lt = np.full(a.size, np.inf), np.full(a.size, -np.inf)
        np.minimum.at(ft, tb["seg"], t_row)
        np.maximum.at(lt, tb["seg"], t_row)
        first_t.append(ft)
        last_t.append(lt)
    later, windows = [], []
    while True:                   # unknown segments still observed after t_from (new ones, or left float)
        starts = np.concatenate([np.maximum(ft, t_from)[~kn & (lt >= t_from + window_s / 2)]
                                 for ft, lt, kn in zip(first_t, last_t, known)])
        if starts.size == 0:
            return later, windows
        k0 = int(np.searchsorted(t_all, starts.min()))
        try:
            idx, dt = _init_window(t_all[k0:], window_s)
            res, model, _ = _solve_window(cfg, R, tabs, k_of, ant_idx, d_hdr, idx + k0, dt, code_dd=code_dd,
                                          prior_cov=prior_cov)
        except CdgpsError as exc:
            windows.append({"start_s": float(t_all[k0]), "refused": str(exc)})
            t_from = float(t_all[k0]) + window_s
            continue
        fixed = [(model.segment_keys[c], int(n)) for c, f, n in zip(res.columns, res.fixed, res.integers) if f]
        both = [(k, n) for k, n in fixed if known[k[0]][k[1]] and known[k[0]][k[2]]]
        bad = sum(int(round(a_cur[s][j] - a_cur[s][r])) != n for (s, j, r), n in both)
        new = 0
        for _ in range(2 if not bad else 0):          # twice: a reference that became known in the first pass
            for (s, j, r), n in fixed:
                if known[s][r] != known[s][j]:
                    tgt, val = (j, a_cur[s][r] + n) if known[s][r] else (r, a_cur[s][j] - n)
                    a_cur[s][tgt], known[s][tgt] = val, True
                    later.append({"rover_slot": int(s), "segment": int(tgt), "a_cycles": float(val),
                                  "satellite": names[s][tgt], "first_s": float(first_t[s][tgt])})
                    new += 1
        windows.append({"start_s": float(t_all[idx[0] + k0]), "end_s": float(t_all[idx[-1] + k0]), "epochs": int(idx.size),
                        "integer_fixing": res.note, "checked": len(both), "disagree": int(bad), "new_segments": new})
        t_from = float(t_all[idx[-1] + k0]) + 1e-6


def apply_modal_record(tabs: list, record: dict) -> list:
    """The tables with a modal initialization's fixed DD integers applied (on INIT's datum: a fixed
    N of (s_j, s_r) sets a(s_j) = a(s_r) + N); INIT's fixed segments the window did not fix are
    kept while on the same datum (every window reference INIT-known)."""
    a_new = [np.array(tb["a_seg"], dtype=float) for tb in tabs]
    init_known = [np.asarray(tb["w"]["known_seg"], bool) & (tb["n_fixed"] > 0) for tb in tabs]
    known = [np.zeros(a.size, dtype=bool) for a in a_new]
    anchored = [True] * len(tabs)
    names = [_segment_satellites(tb) for tb in tabs]
    for sg in record["segments"]:
        a, sj, sr = sg["rover_slot"], sg["segment"], sg["reference_segment"]
        if not (0 <= a < len(tabs) and 0 <= sj < a_new[a].size and 0 <= sr < a_new[a].size):
            raise CdgpsError("INIT.json's modal_init does not match this run's lock segments")
        _check_segment_satellite(names[a], sj, sg.get("satellite"), sg.get("first_s"))
        _check_segment_satellite(names[a], sr, sg.get("reference"))
        if sg["fixed"]:
            a_new[a][sj] = float(tabs[a]["a_seg"][sr]) + int(sg["integer_cycles"])
            known[a][sj] = known[a][sr] = True
            anchored[a] = anchored[a] and bool(init_known[a][sr])
    for sg in record.get("later_segments", []):     # signal path: later windows' integers, on the datum
        a, sj = sg["rover_slot"], sg["segment"]
        if not (0 <= a < len(tabs) and 0 <= sj < a_new[a].size):
            raise CdgpsError("INIT.json's modal_init does not match this run's lock segments")
        _check_segment_satellite(names[a], sj, sg.get("satellite"), sg.get("first_s"))
        a_new[a][sj], known[a][sj] = float(sg["a_cycles"]), True
    out = []
    for a, tb in enumerate(tabs):
        # INIT's integers where the window's did not decide, while on the same datum
        keep = known[a] | (init_known[a] & anchored[a])
        out.append(_set_integers(tb, a_new[a], keep[tb["seg"]]))
    return out


def _segment_satellites(tb: dict) -> tuple[list, np.ndarray]:
    """The satellite (as the table names it) and the first time (s) of each lock segment of a modal table."""
    d, seg = tb["d"], np.asarray(tb["seg"])
    n = int(seg.max()) + 1 if seg.size else 0
    names, first_s = [""] * n, np.full(n, np.nan)
    segs, first = np.unique(seg, return_index=True)
    for k, i in zip(segs, first):
        names[int(k)] = str(d.sat_names[int(d.sat[i])])
        first_s[int(k)] = float(d.t_label[d.epoch[i]])
    return names, first_s


def _check_segment_satellite(table: tuple, seg: int, satellite, first_s=None) -> None:
    """CdgpsError when a stored modal_init segment names another satellite, or begins at another time, than this
    run's segment ``seg`` (the run's segments are not those INIT was made on: another INIT, or one made before its
    segments changed).  ``table``: :func:`_segment_satellites`' answer."""
    names, first = table
    if satellite is not None and names[seg] and names[seg] != str(satellite):
        raise CdgpsError(f"INIT.json's modal_init does not match this run's lock segments: its segment {seg} is "
                         f"{satellite}, this run's is {names[seg]} (run 'cdgps init --structure' again on this run)")
    if first_s is not None and not (isinstance(first_s, (int, float)) and np.isfinite(first_s)):
        raise CdgpsError(f"INIT.json's modal_init: segment {seg} ({satellite}) has first_s = {first_s!r}; expected a "
                         f"GPS time in seconds")
    if first_s is not None and np.isfinite(first[seg]) and abs(first[seg] - float(first_s)) > 1e-6:
        raise CdgpsError(f"INIT.json's modal_init does not match this run's lock segments: its segment {seg} "
                         f"({satellite}) begins at {gps_time_str(float(first_s))}, this run's at "
                         f"{gps_time_str(float(first[seg]))} (run 'cdgps init --structure' again on this run)")


def _stored_record(init: dict, cfg: StructureConfig, mapping: dict, x_axis_azimuth_deg: float):
    """INIT.json's ``modal_init`` when it was made for this structure, mapping and placement, else None."""
    rec = init.get("modal_init")
    if not isinstance(rec, dict) or "segments" not in rec:
        return None
    if rec.get("structure_sha256") != cfg.sha256 or rec.get("receivers") != mapping \
            or rec.get("x_axis_azimuth_deg") != float(x_axis_azimuth_deg):
        return None
    return rec


def gnss_modal_init(run, init: dict, cfg: StructureConfig, *, receivers: dict | None = None,
                    x_axis_azimuth_deg: float = X_AXIS_AZIMUTH_DEG, window_s: float = INIT_WINDOW_S, progress=None) -> dict:
    """``cdgps init --structure`` on a GNSS run: the modal batch initialization as INIT.json's
    ``modal_init`` (read back by :func:`gnss_modal_estimate` for the same structure, receiver mapping
    and azimuth).

    Parameters
    ----------
    run : GnssRun
    init : dict
        The GNSS INIT of :func:`cdgps_cli.pipeline.gnss.gnss_init` on that run (its datum and the
        integers of segments outside the window).
    cfg : StructureConfig
    receivers, x_axis_azimuth_deg : as :func:`gnss_modal_estimate`
    window_s : float
        The window at the run's start, s.

    Returns
    -------
    dict
        The record (window, counts, ratio, note, per-segment floats and integers, x1 at the window's
        first epoch) with ``structure``, ``structure_sha256``, ``receivers``, ``x_axis_azimuth_deg``;
        ``refused`` (the reason) instead of the record when the window cannot be solved.
    """
    say = progress or (lambda m: None)
    su = _modal_setup(run, init, cfg, receivers, x_axis_azimuth_deg, say)
    say(f"modal batch initialization on the first {window_s:g} s …")
    head = {"structure": cfg.name, "structure_sha256": cfg.sha256, "receivers": su.mapping,
            "x_axis_azimuth_deg": float(x_axis_azimuth_deg)}
    try:
        _, _, rec = modal_batch_initialization(cfg, su.R, su.tabs, su.k_of, su.ant_idx, su.d_hdr, su.t_all, window_s=window_s)
    except CdgpsError as exc:            # recorded, not fatal: estimate then uses the baselines' integers
        return {**head, "refused": str(exc)}
    return {**head, **rec}


_h_and_H = dd_modal_h_and_H            # (the model's home: cdgps_cli.measurement.model)


def _modal_setup(run, init: dict, cfg: StructureConfig, receivers, x_axis_azimuth_deg: float, say) -> SimpleNamespace:
    """Checks of the run, INIT and antenna mapping; the placement, every rover's SD table (with INIT's
    integers), the nominal offsets d_a and the common time axis."""
    from cdgps_cli.pipeline.gnss import _check_master_position, _master_xyz, _stations, is_gnss_init  # noqa: PLC0415

    if not is_gnss_init(init):
        raise CdgpsError("INIT.json is not from 'cdgps init' on a GNSS run")
    if init.get("config_sha256") != run.cfg.sha256 or set(init.get("rovers", {})) != set(run.rovers) \
            or init.get("master") != run.master:
        raise CdgpsError(f"INIT.json was made from another run than {run.path}")
    mapping = {a: (receivers or {}).get(a, a) for a in cfg.antenna_names}
    master_ant = cfg.antenna_names[cfg.master_index]
    if mapping[master_ant] != run.master:
        raise CdgpsError(f"the structure's master antenna {master_ant!r} maps to receiver {mapping[master_ant]!r}, "
                         f"but the run's master is {run.master!r}")
    rover_ants = [a for a in cfg.antenna_names if a != master_ant]
    missing = [f"{a} → {mapping[a]}" for a in rover_ants if mapping[a] not in run.rovers]
    if missing:
        raise CdgpsError(f"structure antenna(s) without a rover receiver in {run.path}: {', '.join(missing)} "
                         f"(rovers: {', '.join(run.rovers)})")
    unused = [r for r in run.rovers if r not in {mapping[a] for a in rover_ants}]
    stations = _stations(run)
    _check_master_position(run)
    xm = _master_xyz(run)
    placement = StructurePlacement(tuple(float(v) for v in xm), float(x_axis_azimuth_deg))
    R = placement.rotation()
    if run.cfg.signals:                  # one slot per rover and signal group
        tabs, slot_ants = _signal_slots(run, mapping, rover_ants, xm, say, init)
    else:                                # one slot per rover: GPS L1 with INIT's integers
        tabs, slot_ants = [_rover_tables(run, init, mapping[a], stations, say) for a in rover_ants], list(rover_ants)
    ant_idx = np.array([cfg.antenna_names.index(a) for a in slot_ants])
    m_idx = cfg.master_index
    # nominal receiver positions relative to the master, in the structure frame; mismatch to the model's
    p0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)))[0]
    d_hdr = np.array([(tb["xr0"] - xm) @ R for tb in tabs])
    mismatch = {a: float(np.linalg.norm(d_hdr[i] - (p0[ant_idx[i]] - p0[m_idx]))) for i, a in enumerate(slot_ants)}

    # common time axis
    t_all = np.unique(np.concatenate([tb["d"].t_label for tb in tabs]))
    n = t_all.size
    k_of = []
    for tb in tabs:
        m = np.full(n, -1, dtype=np.int64)
        m[np.searchsorted(t_all, tb["d"].t_label)] = np.arange(tb["d"].t_label.size)
        k_of.append(m)

    return SimpleNamespace(mapping=mapping, rover_ants=rover_ants, unused=unused, xm=xm, R=R, tabs=tabs, ant_idx=ant_idx,
                           d_hdr=d_hdr, mismatch=mismatch, t_all=t_all, k_of=k_of, slot_ants=slot_ants)


def _signal_options(tabs: list) -> dict:
    """The signal groups of a multi-signal estimate with their wavelengths (m), for the outputs' options."""
    lam = {tb["signal"]: tb["lam_m"] for tb in tabs if "signal" in tb}
    return {"signals": list(lam), "wavelengths_m": lam,
            "dd_groups": "per rover and signal, own reference satellite; integers fixed as one full set"} if lam else {}


def _final_biases(su, tabs: list, init: dict) -> tuple[dict, dict]:
    """``final_biases`` {(antenna, satellite): bias m} and the integer counts of the summary: INIT's fixed
    L1 integers per rover (GPS L1 path), or per signal slot the integers used (signal path)."""
    biases, counts = {}, {}
    if not su.tabs or "signal" not in su.tabs[0]:
        for i, a in enumerate(su.rover_ants):
            for s in sorted(rover_segments(init, su.mapping[a]), key=lambda s: s["first_gps_s"]):
                if s.get("fixed") and s.get("integer") is not None:
                    biases[(a, s["sat"])] = GPS_L1_WAVELENGTH_M * s["integer"]
            counts[a] = {"fixed": tabs[i]["n_fixed"], "estimated": tabs[i]["n_estimated"]}
        return biases, counts
    for a, tb in zip(su.slot_ants, tabs):
        d, used = tb["d"], np.unique(tb["seg"][tb["use"]])
        for sg in used:                       # the last used segment of each satellite wins (time order)
            biases[(a, d.sat_names[int(d.sat[np.flatnonzero(tb["seg"] == sg)[0]])])] = tb["lam_m"] * float(tb["a_seg"][sg])
        c = counts.setdefault(a, {"fixed": 0, "estimated": 0, "signals": {}})
        c["signals"][tb["signal"]] = {"fixed": int(used.size), "estimated": int(tb["n_estimated"])}
        c["fixed"] += int(used.size)
        c["estimated"] += int(tb["n_estimated"])
    return biases, counts


def init_segment_starts(init: dict | None, rover: str, signal: str) -> list:
    """(satellite, first s) of each of INIT's segments of ``rover`` in ``signal`` (its ``biases``)."""
    return [(str(b["satellite"]).split(":")[0], float(b["segment_start_s"])) for b in (init or {}).get("biases", [])
            if b.get("rover") == rover and b.get("signal") == signal and b.get("segment_start_s") is not None]


def _signal_slots(run, mapping: dict, rover_ants: list, xm: np.ndarray, say, init: dict | None = None) -> tuple[list, list]:
    """Per rover antenna and signal of ``[gnss] signals``, the SD table of that group
    (:func:`cdgps_cli.measurement.dd_signals.signal_sd_table`) in the form of :func:`_rover_tables`; no
    integer is known yet (the modal batch initialization fixes them).  Its segments also start where INIT's do
    (:func:`init_segment_starts`: INIT cut its arcs at slips no receiver flagged).  Returns (tables, antenna of
    each)."""
    from cdgps_cli.estimation.rtk_multi import receiver_geometry  # noqa: PLC0415
    from cdgps_cli.measurement.dd_signals import signal_sd_table  # noqa: PLC0415
    from cdgps_cli.pipeline.gnss import _position_args, run_receiver  # noqa: PLC0415
    from cdgps_cli.pipeline.gnss_ingest import signal_obs  # noqa: PLC0415   (UBX: slips from lock times)

    c = run.cfg
    if any(g.startswith("R:") for g in c.signals):
        raise CdgpsError("the modal structure path takes CDMA signals only (GPS, Galileo, BeiDou, QZSS); GLONASS (FDMA) is not supported")
    geo_m = receiver_geometry(signal_obs(run_receiver(run, run.master)), run.nav, xm)
    tabs, slot_ants = [], []
    for a in rover_ants:
        r = mapping[a]
        xr0 = _position_args(run, r)
        if xr0 is None:
            h = run.receivers[r].header.get("approx_position_xyz_m")
            if h is None:
                raise CdgpsError(f"{run.path}: rover {r} has no nominal position (RINEX header or config); the signal path needs one")
            xr0 = np.asarray(h, dtype=float)
        say(f"{run.master} → {r}: single differences of {', '.join(c.signals)} …")
        geo_r = receiver_geometry(signal_obs(run_receiver(run, r)), run.nav, xr0)
        for g in c.signals:
            d = signal_sd_table(geo_m[geo_m["signal"] == g], geo_r[geo_r["signal"] == g], xm, xr0,
                                mask_rad=math.radians(c.mask_deg), max_gap_s=c.max_gap_s, troposphere=c.troposphere,
                                sync_tol_s=c.sync_tol_s, segment_starts=init_segment_starts(init, r, g))
            if d.t_label.size == 0:
                raise CdgpsError(f"{run.path}: no common {g} observations of {run.master} and {r} above the {c.mask_deg:g}° mask")
            va = 0.5 * sd_variance(d.el_rover, d.el_rover, sigma_a_m=c.sigma_a_m, sigma_b_m=c.sigma_b_m, weighting=c.weighting)
            vm = 0.5 * sd_variance(d.el_base, d.el_base, sigma_a_m=c.sigma_a_m, sigma_b_m=c.sigma_b_m, weighting=c.weighting)
            n_seg = int(d.seg.max()) + 1
            tb = {"res": None, "w": {"known_seg": np.zeros(n_seg, dtype=bool), "seg": d.seg, "a_seg": np.zeros(n_seg)},
                  "d": d, "r_raw": d.r_raw_m, "rc": d.r_code_m, "code_ratio": float(c.code_ratio), "seg": d.seg,
                  "var_rover": va, "var_master": vm, "events": [], "n_fixed": 0,
                  "n_estimated": n_seg, "xr0": xr0, "xm": np.asarray(xm, float), "lam_m": d.lam_m, "signal": g}
            tabs.append(_set_integers(tb, np.zeros(n_seg), np.zeros(d.seg.size, dtype=bool)))
            slot_ants.append(a)
    return tabs, slot_ants


def gnss_modal_estimate(run, init: dict, init_text: str, cfg: StructureConfig, out_path, *,
                        receivers: dict | None = None, x_axis_azimuth_deg: float = X_AXIS_AZIMUTH_DEG, smooth: bool = False,
                        initial_sigma_xi: float = MODAL_INITIAL_SIGMA_XI, initial_sigma_xidot: float = MODAL_INITIAL_SIGMA_XIDOT,
                        max_iterations: int = 5, progress=None, extra_options: dict | None = None,
                        batch_init: bool = True, init_window_s: float = INIT_WINDOW_S,
                        outlier_sigma: float | None = None,
                        init_window_max_factor: float = INIT_WINDOW_MAX_FACTOR,
                        init_code_dd: bool = MODAL_INIT_CODE_DD,
                        scene_exaggeration: float | str = SCENE_EXAGGERATION, fuse=(), hold_out=(),
                        sensor_logs=None, history=None) -> dict:
    """Modal states of a structure from a GNSS RUN and its INIT (integers) → STATES.mcap.

    Parameters
    ----------
    run : GnssRun
        From :func:`cdgps_cli.io.gnss_run.read_gnss_run`.
    init : dict
        INIT.json of ``cdgps init`` on that run (its integers are used; float segments are not).
    init_text : str
        Its text (hashed into the output).
    cfg : StructureConfig
        The structure model (its transmitters are not used: the satellites replace them).
    out_path : path
        STATES.mcap to write.
    receivers : dict, optional
        ``{structure antenna name: receiver name}``; default: the same names.  The master
        antenna's receiver must be the run's master; every other antenna needs a rover receiver.
    x_axis_azimuth_deg : float
        Placement of the structure frame (:class:`StructurePlacement`); the master's position is
        the run's master position.
    smooth : bool
        Add the Rauch-Tung-Striebel smoother (``/cdgps/state``: smoothed, ``/cdgps/state_filtered``).
    initial_sigma_xi, initial_sigma_xidot : float
        Prior 1σ of the modal positions and rates about x = 0 at the first epoch (config units),
        added to the stationary spread of the process noise (:func:`modal_prior_covariance`).
    max_iterations : int
        Gauss-Newton iterations of the measurement update (while the correction exceeds 1e-9 of
        the state).
    batch_init : bool
        Model-aided batch initialization on the first ``init_window_s`` seconds
        (:func:`modal_batch_initialization`, on the prior of :func:`modal_prior_covariance`): its DD
        integers replace INIT's in the window; the filter starts from that same prior (x = 0), not
        from the batch's x₁, so that the window's data are not counted twice; False: INIT's integers.
    outlier_sigma : float, optional
        Outlier gate: a DD whose innovation exceeds this many σ is not used at that epoch (event
        ``outlier``); default :class:`cdgps_cli.estimation.filter.EstimateOptions`'s.
    scene_exaggeration : float or "auto"
        The 3-D scene's factor on the deformation (:func:`cdgps_cli.pipeline.estimate_outputs.scene_for`).
    fuse, hold_out, sensor_logs : optional
        Sensor kinds fused with the DDs (``gyro``, ``accel``, ``tilt``; issue 30), sensor names kept
        out, and the run's sensor logs {kind: table}, or a function returning them (read when the fused
        filter starts, after the GNSS set-up: issue 29) (:func:`cdgps_cli.pipeline.fusion.fuse_with_dd`):
        the filter then steps on the union of the GNSS epochs and the sensor samples, the state carries
        the held modal disturbance (with accelerometers) and the sensor biases, and the outputs'
        options and summary carry ``fusion`` (per sensor: samples, residual RMS, final bias).
    history : object, optional
        Where the fused filter keeps x, P for the smoother (:func:`cdgps_cli.pipeline.fusion.run_fused`:
        in memory by default; ``cdgps estimate`` gives a :class:`cdgps_cli.io.scratch.DiskHistory`).

    Returns
    -------
    dict
        The :func:`cdgps_cli.io.states.write_states` summary plus the placement, the antenna mapping,
        the nominal-position mismatches and the integer counts.
    """
    from cdgps_cli.pipeline.estimate_outputs import write_states  # noqa: PLC0415

    say = progress or (lambda m: None)
    if fuse:                    # (large arrays mapped on their own from here on: freed, they leave RSS; issue 29)
        from cdgps_cli.pipeline.fusion import map_large_blocks  # noqa: PLC0415

        map_large_blocks()
    su = _modal_setup(run, init, cfg, receivers, x_axis_azimuth_deg, say)
    mapping, rover_ants, xm, tabs, t_all = su.mapping, su.rover_ants, su.xm, su.tabs, su.t_all
    if not batch_init and not any(tb["n_fixed"] for tb in tabs):
        raise CdgpsError(f"INIT.json has no fixed integers for any rover ({', '.join(mapping[a] for a in rover_ants)}); "
                         f"the modal model needs fixed DD integers (run 'cdgps init' without --float-only, or with a "
                         f"longer span / random_walk displacement model)")

    nm = cfg.n_modes
    prior = modal_prior_covariance(cfg, initial_sigma_xi, initial_sigma_xidot)
    stored = _stored_record(init, cfg, mapping, x_axis_azimuth_deg) if batch_init else None
    tabs, init_record = _modal_integers(cfg, su, tabs, stored, batch_init, prior, init_window_s, init_window_max_factor,
                                        init_code_dd, say)
    su.tabs = tabs = _filter_tables(tabs)          # (the baselines' working arrays are let go here)
    model = SatelliteDDModal(cfg, su.R, tabs, su.k_of, su.ant_idx, su.d_hdr)
    sky = satellite_sky(model, t_all) if scene_exaggeration != 0 else None
    # the filter starts from the batch's prior itself, not from its x₁: it re-reads the window's data
    # once, as the batch did from that prior (x₁ and its posterior already hold them: counted twice)
    x0, P0 = np.zeros(2 * nm), prior
    say(f"modal EKF over {t_all.size} epochs, {len(rover_ants)} rover antenna(s), {nm} modes …")
    gate = EstimateOptions().outlier_sigma if outlier_sigma is None else float(outlier_sigma)
    fusion = None
    if fuse:
        fusion, model, t_all, fr = _fused_filter(cfg, model, t_all, sensor_logs, fuse, hold_out, x0, P0, smooth,
                                                 max_iterations, gate, say, history)
    else:
        fr = _filter_dd(model, cfg, t_all, x0, P0, max_iterations, gate, smooth)
    xf, Pf, meas, xs, Ps, nis, nis_dof, outliers = fr
    chans, resid = _dd_residuals(model, meas, xs, su.slot_ants, history)
    events = _modal_events(tabs, mapping, su.slot_ants, outliers, fusion.events if fusion is not None else [])
    biases, integers = _final_biases(su, tabs, init)
    res = SimpleNamespace(cfg=cfg, x=xs, P=Ps, smoothed=bool(smooth), x_filt=xf, P_filt=Pf, time_s=t_all,
                          channels=chans, residual_m=resid, nis=nis, nis_dof=nis_dof, events=events, biases=biases)
    options = {"model": "gnss-modal", "smooth": bool(smooth), "x_axis_azimuth_deg": float(x_axis_azimuth_deg),
               "master_ecef_m": list(map(float, xm)), "receivers": mapping,
               "initial_sigma_xi": initial_sigma_xi, "initial_sigma_xidot": initial_sigma_xidot,
               **({"batch_init_window_s": float(init_window_s)} if batch_init else {"batch_init": False}),
               "dd_covariance": "D Σ Dᵀ jointly over the rovers (common master)", "outlier_sigma": gate,
               **_signal_options(tabs), **({"fusion": fusion.summary} if fusion is not None else {}),
               **({"antennas": antennas_info(run.antex, run.antennas)} if run.antex is not None else {}),
               **(extra_options or {})}
    say(f"writing {out_path} …")
    out = write_states(res, run.path, init, init_text, out_path, options, scene_exaggeration=scene_exaggeration,
                       satellites=sky)
    return _modal_summary(out, cfg, su, x_axis_azimuth_deg, integers, init_record, fusion)


def _modal_summary(out: dict, cfg: StructureConfig, su, x_axis_azimuth_deg: float, integers: dict,
                   init_record: dict | None, fusion) -> dict:
    """``out`` (write_states' summary) with the placement (m, deg), the receivers, the nominal-position
    mismatches (m), the integer counts, the coordinates and the modal init / fusion records."""
    out.update({
        "placement": {"master_ecef_m": list(map(float, su.xm)), "x_axis_azimuth_deg": float(x_axis_azimuth_deg)},
        "receivers": su.mapping, "unused_receivers": su.unused,
        "nominal_mismatch_m": su.mismatch,
        "integers": integers,
        "coordinates": list(cfg.coord_names),
        **({"modal_init": init_record} if init_record is not None else {}),
        **({"fusion": fusion.summary} if fusion is not None else {}),
    })
    return out


#: what the filter, the sky, the residuals, the events and the summary read of a DD table
_FILTER_KEYS = ("ref", "use", "xm", "xr0", "r0", "var_rover", "var_master", "seg", "code_ratio", "events", "n_fixed",
                "n_estimated", "a_seg", "lam_m", "signal")


def _filter_tables(tabs: list) -> list:
    """The DD tables with the integers applied, holding only what the modal filter and the outputs read
    (:data:`_FILTER_KEYS`, and of the baseline data ``ptr``, ``sat``, ``sat_names``, ``rover_sat_xyz``):
    the baselines' results and working arrays (``res``, ``w``, the raw SD residuals, the rest of the
    SD table) are not kept through the filter (issue 29: ≈ 100–150 bytes per SD row)."""
    out = []
    for tb in tabs:
        d = tb["d"]
        slim = SimpleNamespace(ptr=d.ptr, sat=d.sat, sat_names=d.sat_names, rover_sat_xyz=d.rover_sat_xyz)
        out.append({**{k: tb[k] for k in _FILTER_KEYS if k in tb}, "d": slim})
    return out


def _modal_integers(cfg: StructureConfig, su, tabs: list, stored: dict | None, batch_init: bool, prior: np.ndarray, init_window_s: float,
                    init_window_max_factor: float, init_code_dd: bool, say) -> tuple[list, dict | None]:
    """The DD tables with the integers the filter uses (INIT.json's stored modal record, else the
    modal batch initialization on the first ``init_window_s`` s, else INIT's) and that record (None:
    INIT's integers without a batch); refused when no rover has a fixed integer."""
    init_record = None
    if stored is not None:
        say("modal batch initialization: INIT.json's (from 'cdgps init --structure')")
        tabs, init_record = apply_modal_record(tabs, stored), stored
    elif batch_init:
        say(f"modal batch initialization on the first {init_window_s:g} s …")
        try:
            tabs, _, init_record = modal_batch_initialization(cfg, su.R, tabs, su.k_of, su.ant_idx, su.d_hdr,
                                                               su.t_all, prior_cov=prior, window_s=init_window_s,
                                                               max_window_factor=init_window_max_factor,
                                                               code_dd=init_code_dd)
        except CdgpsError as exc:
            init_record = {"method": "INIT's integers (the modal batch initialization refused)", "refused": str(exc)}
            say(f"  modal batch initialization refused ({exc}); INIT's integers are used")
        else:
            say(f"  {init_record['integer_fixing']}; {init_record['agree_with_init']['equal']} of "
                f"{init_record['agree_with_init']['compared']} equal to INIT's")
    if not any(tb["use"].any() for tb in tabs):
        raise CdgpsError("no fixed DD integers for any rover (INIT.json's nor the modal batch initialization's); "
                         "try a longer span or 'cdgps init' without --float-only")
    return tabs, init_record


def _fused_filter(cfg: StructureConfig, model, t_all, sensor_logs, fuse, hold_out, x0, P0, smooth: bool,
                  max_iterations: int, gate: float, say, history):
    """The modal EKF on the DDs fused with the sensors (:func:`cdgps_cli.pipeline.fusion.fuse_with_dd`):
    ``(fusion, its DD model, its epochs (s), (x_filt, P_filt, rows, x, P, nis, nis_dof, outliers))``."""
    from cdgps_cli.pipeline.fusion import fuse_with_dd  # noqa: PLC0415

    fusion = fuse_with_dd(cfg, model, t_all, sensor_logs or {}, tuple(fuse), tuple(hold_out), x0, P0, smooth=smooth,
                          max_iterations=max_iterations, outlier_sigma=gate, say=say, store=history)
    fr = (fusion.x_filt, fusion.P_filt, fusion.dd_rows, fusion.x, fusion.P, fusion.nis, fusion.nis_dof,
          fusion.outliers_dd)
    return fusion, fusion.dd, fusion.t, fr


def satellite_sky(model: SatelliteDDModal, t_all, step_s: float = SCENE_SKY_STEP_S):
    """The directions toward the satellites the modal filter uses, for the 3-D scene
    (:class:`cdgps_cli.analysis.scene.SatelliteSky`): at the first epoch and then every ``step_s``
    seconds of ``t_all``, the structure-frame unit vector from the master toward each satellite whose
    DD rows enter (fixed integers) for any rover, from the same broadcast geometry as the measurements."""
    from cdgps_cli.analysis.scene import SatelliteSky  # noqa: PLC0415

    t = np.asarray(t_all, dtype=float)
    keep = np.unique(np.searchsorted(t, np.arange(t[0], t[-1] + step_s, step_s) if t.size else t))
    keep = keep[keep < t.size]
    names = sorted({tb["d"].sat_names[int(s)] for tb in model.tabs for s in np.unique(tb["d"].sat[tb["use"]])})
    col = {n: i for i, n in enumerate(names)}
    D = np.full((keep.size, len(names), 3), np.nan)
    slot = np.full(t.size, -1)
    slot[keep] = np.arange(keep.size)
    for a, tb in enumerate(model.tabs):
        d, k_of = tb["d"], np.asarray(model.k_of[a])
        table_k = np.full(len(d.ptr) - 1, -1)                  # table epoch -> model epoch
        table_k[k_of[k_of >= 0]] = np.flatnonzero(k_of >= 0)
        row_k = table_k[np.repeat(np.arange(len(d.ptr) - 1), np.diff(d.ptr))]
        rows = np.flatnonzero(tb["use"] & (row_k >= 0))
        rows = rows[slot[row_k[rows]] >= 0]
        u = (d.rover_sat_xyz[rows] - tb["xm"]) @ model.R
        D[slot[row_k[rows]], [col[d.sat_names[int(s)]] for s in d.sat[rows]]] = u / np.linalg.norm(u, axis=1, keepdims=True)
    return SatelliteSky(t[keep], tuple(names), D)


def _filter_dd(model, cfg: StructureConfig, t_all, x0, P0, max_iterations: int, gate: float, smooth: bool):
    """The modal EKF on the DDs alone (compiled kernel when built, numpy otherwise) [+ RTS smoother]:
    ``(x_filt, P_filt, rows per epoch, x, P, nis, nis_dof, outlier events)``."""
    outliers: list = []
    dyn = ModalZOH(cfg)
    if kernel.available():
        fr = filter_dd_kernel(model, dyn, t_all, x0, P0, max_iterations, outlier_sigma=gate, events=outliers)
    else:
        fr = filter_numpy(model, dyn, t_all, x0, P0, max_iterations,
                          rows_hook=outlier_gate(model, gate, outliers, t_all))
    xf, Pf = fr["x"], fr["P"]
    xs, Ps = rts_smooth_indexed(np.array(xf), np.array(Pf), *fr["transitions"]) if smooth else (xf, Pf)
    return xf, Pf, fr["rows"], xs, Ps, fr["nis"], fr["nis_dof"], outliers


def _dd_residuals(model, meas, xs, slot_ants, store=None) -> tuple[list, np.ndarray]:
    """DD residuals of the reported estimate ``xs``, per (antenna, satellite) channel: the sorted
    channels and the residuals (n, C), m (NaN where the channel was not used).  ``store``: where the
    residuals live (:class:`cdgps_cli.io.scratch.DiskHistory` for ``cdgps estimate``: on disk, made in
    one pass over ``meas`` (rows made when read) a block at a time, pages dropped behind)."""
    bound = _label_bound(model)
    if store is None or not getattr(store, "on_disk", False) or bound is None:
        chans = sorted({(slot_ants[a], s) for mk in meas if mk is not None for a, s in mk.labels})
        cidx = {c: i for i, c in enumerate(chans)}
        resid = np.full((len(meas), len(chans)), np.nan)
        for k, mk in enumerate(meas):
            if mk is None:
                continue
            h, _ = model.predict(xs[k], mk)
            cols = [cidx[(slot_ants[a], s)] for a, s in mk.labels]
            resid[k, cols] = mk.z_m - h
        return chans, resid
    # one pass: columns in order of first appearance (at most ``bound``), then sorted by channel
    n, block = len(meas), ESTIMATE_CHUNK_EPOCHS
    first = store.empty((n, bound))
    seen: dict = {}
    for a in range(0, n, block):
        b = min(a + block, n)
        first[a:b] = np.nan
        for k in range(a, b):
            mk = meas[k]
            if mk is None:
                continue
            h, _ = model.predict(xs[k], mk)
            cols = [seen.setdefault((slot_ants[i], s), len(seen)) for i, s in mk.labels]
            first[k, cols] = mk.z_m - h
        store.release(first, a, b)
        store.release(xs, a, b)
    chans = sorted(seen)
    order = [seen[c] for c in chans]
    resid = store.empty((n, len(chans)))
    for a in range(0, n, block):
        resid[a:a + block] = first[a:a + block][:, order]
        store.release(first, a, a + block)
        store.release(resid, a, a + block)
    return chans, resid


def _label_bound(model) -> int | None:
    """How many distinct (slot, satellite[/code]) labels ``model``'s rows can carry (None: unknown)."""
    tabs = getattr(model, "tabs", None)
    if tabs is None:
        return None
    return max(1, sum(len(tb["d"].sat_names) for tb in tabs) * (2 if getattr(model, "code", False) else 1))


def _modal_events(tabs, mapping: dict, slot_ants, outliers, sensor_events) -> list:
    """The DD tables' events (antennas by structure name), the outlier gate's and the fused sensors',
    in time order."""
    events = []
    for i, tb in enumerate(tabs):
        for ev in tb["events"]:
            e = dict(ev)
            if e["antenna"] == mapping[slot_ants[i]]:
                e["antenna"] = slot_ants[i]
            events.append(e)
    for e in outliers:
        events.append({"time_s": float(e["time_s"]), "antenna": slot_ants[e["label"][0]], "transmitter": e["label"][1],
                       "kind": "outlier", "action": f"DD not used at this epoch ({e['sigmas']:.1f} σ)"})
    events += sensor_events
    events.sort(key=lambda e: (e["time_s"], e["antenna"], e["transmitter"], e["kind"]))
    return events


# ----------------------------------------------------------------------------------------------
# simulation: a vibrating structure seen by GPS receivers


def simulate_structure_gnss(out_dir, cfg: StructureConfig, *, master_ecef_m=SIM_MASTER_ECEF_M,
                            x_axis_azimuth_deg: float = X_AXIS_AZIMUTH_DEG, receivers: dict | None = None, duration_s: float = 1200.0,
                            seed: int = 0, start_gps_s: float | None = None, random_walk_sigma: float = 0.01,
                            mask_deg: float = 10.0, code_sigma_m: float = 0.5, progress=None, signals=None,
                            gnss_interval_s: float | None = None) -> dict:
    """Simulate the structure's free motion and one GNSS receiver per antenna → RINEX + truth.

    ``signals`` (names of :mod:`cdgps_cli.core.signals`, ``G:L1`` among them; default None: the GPS L1
    simulator below): every receiver tracks them all (:func:`cdgps_cli.sim.gnss_signals.simulate_receiver_signals`,
    GPS, Galileo and BeiDou synthetic constellations of :func:`cdgps_cli.model.gps.positioning.synthetic_nav`,
    BeiDou with GEO and IGSO satellites and its records in BDT), the files are multi-signal RINEX 3 and the config lists
    the signals (``[gnss] signals``), so ingest keeps them; the truth gives the integers per signal.

    The motion is :func:`cdgps_cli.sim.structure.simulate` (scenario ``free``) at the config's sample
    period, which is also the receivers' epoch interval; every antenna (the master too) carries
    its own receiver (own clock, integers, fractional bias, elevation-dependent noise σ² = a² +
    b²/sin²el with a = b = 3 mm, white code noise), simulated by
    :func:`cdgps_cli.model.gps.positioning.simulate_static_pair` with the antenna's track as its moving rover.

    Writes ``<receiver>.rnx`` (header position = the antenna's nominal position), ``nav.rnx`` (a
    synthetic constellation), ``truth.csv`` (``time_s`` in GPS s and the structure's coordinates),
    ``truth.json`` and ``config.toml`` (a GNSS run config, random-walk displacement with
    ``random_walk_sigma`` for the init).  Returns a summary.

    ``gnss_interval_s`` (a multiple of the config's sample period; default: that period): the receivers'
    epoch interval, the structure simulated at its sample period (e.g. 100 Hz motion, 10 Hz GNSS).
    A config with sensors (``[[accelerometers]]``, ``[[tilts]]``, ``[[gyros]]``) also gets their logs
    (:func:`cdgps_cli.sim.sensors.simulate_sensor_logs`: noise, bias and bias drift as configured, each
    at its own sample period, time in GPS s) as ``accel.csv``, ``tilt.csv``, ``gyro.csv``, listed in the
    written config's ``sensors`` (so ``cdgps ingest --config`` attaches them) and their true biases in
    truth.json.
    """
    from cdgps_cli.io.atomic import output_set, write_atomic, write_bytes_atomic  # noqa: PLC0415
    from cdgps_cli.sim.gnss import previous_simulation_files  # noqa: PLC0415
    from cdgps_cli.core.gps_time import gps_seconds  # noqa: PLC0415
    from cdgps_cli.io.rinex_write import rinex_calendar, write_rinex_nav  # noqa: PLC0415
    from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: PLC0415

    say = progress or (lambda m: None)
    signals, step = _check_sim_args(cfg, duration_s, x_axis_azimuth_deg, master_ecef_m, signals, gnss_interval_s)
    out = Path(out_dir)
    mapping = {a: (receivers or {}).get(a, a) for a in cfg.antenna_names}
    sim = simulate(cfg, SimOptions(duration_s=duration_s, seed=seed, scenario="free"))
    n_truth, T_truth = sim.time_s.size, cfg.sample_period_s
    n, T = len(range(0, n_truth, step)), T_truth * step         # receiver epochs and interval
    if start_gps_s is None:
        start_gps_s = gps_seconds(2024, 1, 1)
    nav = _sim_nav(signals, start_gps_s, float(sim.time_s[-1]) + T, seed)
    placement = StructurePlacement(tuple(float(v) for v in master_ecef_m), float(x_axis_azimuth_deg))
    nominal = nominal_receiver_positions(cfg, placement)
    y, mo, d, hh, mi, ss = rinex_calendar(start_gps_s)
    stamp = f"{y:04d}{mo:02d}{d:02d} {hh:02d}{mi:02d}{int(ss):02d} UTC"
    with output_set(out, replaces=previous_simulation_files(out, "cdgps gnss structure simulation")) as dest:
        say(f"simulating {n} epochs of {len(mapping)} receivers …")
        rx_sim = SimpleNamespace(nav=nav, master_ecef_m=master_ecef_m, start_gps_s=start_gps_s, n=n, T=T, seed=seed,
                                 mask_deg=mask_deg, code_sigma_m=code_sigma_m, signals=signals, stamp=stamp)
        p_rx = antenna_positions(cfg, sim.q)[::step]             # (n, A, 3) structure frame, receiver epochs
        files, integers = _simulate_receivers(cfg, p_rx, placement.rotation(), nominal, mapping, rx_sim, dest)
        write_rinex_nav(dest.path("nav.rnx"), nav, comments=[f"synthetic ephemerides (seed {seed})"], created=stamp)
        sensor_files, sensor_truth = _simulate_sensors(cfg, sim, seed, start_gps_s, dest, say)
        truth = pd.DataFrame({"time_s": start_gps_s + sim.time_s,
                              **{c: sim.q[:, j] for j, c in enumerate(coordinate_columns(cfg))}})
        write_atomic(dest.path("truth.csv"), lambda pth: truth.to_csv(pth, index=False, lineterminator="\n", float_format="%.9f"))
        master_rx = mapping[cfg.antenna_names[cfg.master_index]]
        tj = {"kind": "cdgps gnss structure simulation", "cdgps_version": __version__, "config": cfg.name,
              "config_sha256": cfg.sha256, "seed": seed, "start_gps_s": start_gps_s, "start": gps_time_str(start_gps_s),
              "duration_s": float(sim.time_s[-1]), "interval_s": T, "epochs": int(n), "master": master_rx,
              **({"structure_interval_s": T_truth, "structure_epochs": int(n_truth)} if step > 1 else {}),
              **({"sensors": sensor_truth} if sensor_truth else {}),
              "receivers": mapping, "master_ecef_m": list(map(float, master_ecef_m)),
              "x_axis_azimuth_deg": float(x_axis_azimuth_deg),
              "nominal_ecef_m": {mapping[a]: list(map(float, v)) for a, v in nominal.items()},
              "coordinates": list(cfg.coord_names), "x0": sim.x[0].tolist(),
              "phase_noise": "sigma^2 = a^2 + b^2/sin^2(el) per receiver, a = b = 0.003 m", "code_sigma_m": code_sigma_m,
              **({"signals": list(signals), "integers": integers} if signals else {})}
        write_bytes_atomic(dest.path("truth.json"), (json.dumps(tj, indent=2) + "\n").encode())
        _write_sim_config(dest, cfg, mapping, files, master_rx, random_walk_sigma, signals, sensor_files)
    return {"output": str(out), "epochs": int(n), "files": files, "master": master_rx, "receivers": mapping,
            "placement": {"master_ecef_m": list(map(float, master_ecef_m)), "x_axis_azimuth_deg": float(x_axis_azimuth_deg)},
            "q_range": {c: [float(sim.q[:, j].min()), float(sim.q[:, j].max())] for j, c in enumerate(cfg.coord_names)},
            "integers": integers, **({"signals": list(signals)} if signals else {}),
            **({"sensor_logs": sensor_files} if sensor_files else {})}


def _check_sim_args(cfg: StructureConfig, duration_s: float, x_axis_azimuth_deg: float, master_ecef_m, signals,
                    gnss_interval_s: float | None) -> tuple:
    """Refuse every bad simulation argument at once (one :class:`CdgpsError` naming them all);
    ``(signals checked, receiver epoch interval in structure sample periods)``."""
    problems = []
    if not (np.isfinite(duration_s) and duration_s > 0):
        problems.append(f"duration_s must be a positive number of seconds, got {duration_s!r}")
    if not (np.isfinite(x_axis_azimuth_deg) and -360.0 <= x_axis_azimuth_deg <= 360.0):
        problems.append(f"x_axis_azimuth_deg must be in [-360, 360] degrees, got {x_axis_azimuth_deg!r}")
    xm = np.asarray(master_ecef_m, dtype=float)
    if xm.shape != (3,) or not np.all(np.isfinite(xm)) or not 6.0e6 < np.linalg.norm(xm) < 7.0e6:
        problems.append(f"master_ecef_m must be 3 finite ECEF coordinates near the Earth's surface, got {master_ecef_m!r}")
    signals = _check_sim_signals(signals, problems)
    T = cfg.sample_period_s
    step = 1 if gnss_interval_s is None else int(round(float(gnss_interval_s) / T))
    if gnss_interval_s is not None and (not np.isfinite(gnss_interval_s) or step < 1
                                        or abs(step * T - float(gnss_interval_s)) > 1e-9 * max(T, 1.0)):
        problems.append(f"gnss_interval_s must be a positive multiple of the config's sample_period_s {T:g} s, "
                        f"got {gnss_interval_s!r}")
    if problems:
        raise CdgpsError("simulate-gnss-structure: " + "; ".join(problems))
    return signals, step


def _sim_nav(signals, start_gps_s: float, span_s: float, seed: int):
    """Synthetic broadcast ephemerides over ``span_s`` seconds from ``start_gps_s`` (GPS s): the
    constellations of ``signals``, or GPS alone (the L1 simulator) when there are none."""
    if signals:
        from cdgps_cli.model.gps.positioning import synthetic_nav  # noqa: PLC0415

        return synthetic_nav({g[0] for g in signals}, start_gps_s, span_s, seed=seed)
    from cdgps_cli.model.gps.positioning import synthetic_gps_nav  # noqa: PLC0415

    return synthetic_gps_nav(start_gps_s, span_s, seed=seed)


def _simulate_receivers(cfg: StructureConfig, p_rx: np.ndarray, R: np.ndarray, nominal: dict, mapping: dict,
                        rx_sim: SimpleNamespace, dest) -> tuple[dict, dict]:
    """One RINEX observation file per antenna (``<receiver>.rnx`` in ``dest``) from the structure's
    antenna positions at the receiver epochs ``p_rx`` (n, A, 3), m, structure frame, and the
    structure-to-ECEF rotation ``R``:
    ``(files by receiver, true integers by receiver)``."""
    from cdgps_cli.io.rinex_write import write_rinex_obs  # noqa: PLC0415
    from cdgps_cli.model.gps.positioning import simulate_static_pair  # noqa: PLC0415

    c = rx_sim
    files, integers = {}, {}
    p0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)))[0]
    for i, a in enumerate(cfg.antenna_names):
        xa = nominal[a]
        lat, lon, _ = ecef_to_geodetic(xa)
        off_enu = ((p_rx[:, i, :] - p0[i]) @ R.T) @ enu_matrix(lat, lon).T   # displacement from the nominal position
        rx = mapping[a]
        hdr = {"marker_name": rx, "observer": "cdgps gnss_modal simulation", "agency": "simulated",
               "receiver_type": "CDGPS SIMULATOR", "receiver_version": __version__, "antenna_type": "SIMULATED",
               "approx_position_xyz_m": tuple(float(v) for v in xa), "interval_s": c.T,
               "comments": [f"structure {cfg.name}, antenna {a}: nominal position (q = 0)"]}
        files[rx] = f"{rx}.rnx"
        rx_seed = c.seed * 1000 + 17 * (i + 1)
        if c.signals:
            integers[rx] = _simulate_signal_receiver(dest.path(files[rx]), c.nav, xa, off_enu, c.start_gps_s, c.n, c.T,
                                                     c.signals, rx_seed, c.mask_deg, c.code_sigma_m, 5.0 - 2.0 * i,
                                                     hdr, c.stamp)
            continue
        s = simulate_static_pair(c.nav, np.asarray(c.master_ecef_m, float), xa, c.start_gps_s, c.n * c.T, c.T,
                                 seed=rx_seed, mask_rad=math.radians(c.mask_deg),
                                 phase_sigma_m=(0.003, 0.003), code_sigma_m=c.code_sigma_m,
                                 clock_drift_ms=(0.0, 5.0 - 2.0 * i), rover_offset_enu_m=off_enu)
        write_rinex_obs(dest.path(f"{rx}.rnx"), s["rover"], hdr, created=c.stamp)
        amb = s["ambiguities"]
        integers[rx] = {r_["sat"]: int(r_["n_cycles"]) for _, r_ in amb[amb["receiver"] == "rover"].iterrows()}
    return files, integers


def _write_sim_config(dest, cfg: StructureConfig, mapping: dict, files: dict, master_rx: str,
                      random_walk_sigma: float, signals, sensor_files) -> None:
    """``config.toml`` in ``dest``: the GNSS run config of the simulated files (random-walk displacement
    with ``random_walk_sigma`` m/√s, the signals and sensor logs when there are)."""
    from cdgps_cli.config.structure import gnss_config_toml  # noqa: PLC0415
    from cdgps_cli.io.atomic import write_bytes_atomic  # noqa: PLC0415

    text = gnss_config_toml({mapping[a]: ("rinex", files[mapping[a]]) for a in cfg.antenna_names}, ["nav.rnx"], master_rx,
                            name=f"simulated-{cfg.name}", description=f"structure {cfg.name} simulated by cdgps_cli.pipeline.gnss_modal",
                            displacement="random_walk", sigma_m_per_sqrt_s=random_walk_sigma,
                            options={**({"signals": list(signals)} if signals else {}),
                                     **({"sensors": sensor_files} if sensor_files else {})} or None)
    write_bytes_atomic(dest.path("config.toml"), text.encode())


def _simulate_sensors(cfg: StructureConfig, sim, seed: int, start_gps_s: float, dest, say) -> tuple[list, dict]:
    """The config's sensor logs (accel.csv, tilt.csv, gyro.csv in ``dest``) from the simulated truth:
    (file names, true biases per sensor); nothing for a config without sensors."""
    from cdgps_cli.config.sensors import sensor_specs  # noqa: PLC0415
    from cdgps_cli.io.sensor_logs import write_sensor_csv  # noqa: PLC0415
    from cdgps_cli.sim.sensors import disturbance_truth, simulate_sensor_logs  # noqa: PLC0415

    specs = sensor_specs(cfg)
    if not specs:
        return [], {}
    say(f"simulating {len(specs)} sensor log(s) …")
    logs = simulate_sensor_logs(cfg, specs, sim.time_s, disturbance_truth(cfg, sim.x), seed=seed, time_offset_s=start_gps_s)
    files = []
    for kind in ("accel", "tilt", "gyro", *sorted(set(logs) - {"accel", "tilt", "gyro", "_truth"})):   # (+ strain …)
        if kind in logs:
            write_sensor_csv(dest.path(f"{kind}.csv"), logs[kind])
            files.append(f"{kind}.csv")
    return files, logs["_truth"]


def _check_sim_signals(signals, problems: list):
    """None: the GPS L1 simulator (no signals in the config); else the tuple of signals (problems appended),
    simulated by the multi-signal simulator and listed in the config (also ``("G:L1",)`` alone)."""
    from cdgps_cli.core.signals import SIGNALS  # noqa: PLC0415
    from cdgps_cli.model.gps.positioning import SYNTHETIC_ORBITS  # noqa: PLC0415

    if signals is None:
        return None
    sig = tuple(dict.fromkeys(signals))
    bad = [g for g in sig if g not in SIGNALS]
    if bad:
        problems.append(f"unknown signal(s) {', '.join(bad)} (known: {', '.join(SIGNALS)})")
    elif any(g[0] not in SYNTHETIC_ORBITS for g in sig):
        problems.append(f"signals can be simulated for systems {', '.join(SYNTHETIC_ORBITS)} only, got {', '.join(sig)}")
    if "G:L1" not in sig:
        problems.append("signals must include G:L1 (the run's GPS L1 baselines give 'cdgps init' its integers)")
    return sig


def _simulate_signal_receiver(path, nav, xa, off_enu, start_gps_s, n, T, signals, seed, mask_deg, code_sigma_m,
                              drift_ms, hdr, stamp) -> dict:
    """One antenna's multi-signal receiver → RINEX 3 at ``path``; {signal: {satellite: first integer}}."""
    from cdgps_cli.io.rinex_write import write_rinex_obs_signals  # noqa: PLC0415
    from cdgps_cli.sim.gnss_signals import simulate_receiver_signals  # noqa: PLC0415

    s = simulate_receiver_signals(nav, xa, start_gps_s, n, T, signals, offset_enu_m=off_enu, seed=seed,
                                  mask_rad=math.radians(mask_deg), phase_sigma_m=(0.003, 0.003),
                                  code_sigma_m=code_sigma_m, clock_drift_ms=drift_ms)
    write_rinex_obs_signals(path, s["obs"], signals, hdr, created=stamp)
    amb = s["ambiguities"].drop_duplicates(["signal", "sat"])
    return {g: {r.sat: int(r.n_cycles) for r in amb[amb["signal"] == g].itertuples()} for g in signals}
