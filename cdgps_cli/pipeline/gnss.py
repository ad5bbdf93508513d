"""``cdgps init`` / ``cdgps estimate`` / ``cdgps export`` on a GNSS RUN (docs/gnss-pipeline.md).

The unknowns are each rover antenna's east/north/up displacement from its nominal position
(``<rover>_e``, ``<rover>_n``, ``<rover>_u``, m, in the local frame at the nominal position), with
the master held at its known position.  Each rover is processed as one baseline from the master
with the static-baseline machinery of :mod:`cdgps_cli.estimation.baseline` (single differences, double
differences against a reference satellite with the correlated covariance ``D Σ Dᵀ``, reference
changes, one SD ambiguity per lock segment, LAMBDA with the ratio test and partial fixing);
correlations between the baselines of several rovers through the common master are neglected.

* :func:`gnss_init` — float DD solution (phase + code), LAMBDA integers, the fixed static
  solution → INIT.json (integers per ambiguity segment, ratio, static solution).
* :func:`gnss_estimate` — per-epoch displacement states with 1σ, using INIT's integers:

  - ``static``: the batch (fixed) solution at every epoch (its 1σ from the batch covariance);
  - ``constant_velocity``: as ``random_walk`` with the state [displacement, velocity] (white acceleration);
  - ``random_walk``: the engine's forward filter over the epochs on the DD phases with the fixed
    integers (:class:`~cdgps_cli.measurement.dd_displacement.SatelliteDDDisplacement`, random-walk
    dynamics, process noise ``σ²·Δt`` per component); ``--smooth`` adds the engine's
    Rauch-Tung-Striebel pass;

  plus, for both, the single-epoch (kinematic) solutions with the fixed integers (the series
  ``/cdgps/kinematic``, arrays only, readable as ``States(path, topic="/cdgps/kinematic")`` and
  exported by ``cdgps export --kinematic``), DD residuals, NIS, and events (slips from LLI / half-cycle flags /
  lock-time restarts, gaps, reference-satellite changes, unfixed ambiguities) → STATES.mcap.

STATES.mcap is written by the one STATES writer (:func:`cdgps_cli.io.states.write_states`) from a
:class:`~cdgps_cli.core.records.StateSeries` of kind ``displacement`` (x = q, output map C = I, no
rates), so ``cdgps export`` and ``cdgps evaluate`` read it like any other; the GNSS run config is
attached as ``gnss_config.toml``.
"""

from __future__ import annotations

import hashlib
import json
import math
import tempfile
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np
import pandas as pd

from cdgps_cli import __version__
from cdgps_cli.config.options import EPOCH_PAIRING_DEFAULTS, NIS_MISFIT_PER_DOF, STATES_CHUNK_EPOCHS
from cdgps_cli.io.atomic import write_atomic
from cdgps_cli.estimation.baseline import (BaselineOptions, Station, baseline_from_init, json_safe,
                                           known_phase_blocks, solve_static_baseline)
from cdgps_cli.estimation.model_filter import filter_numpy
from cdgps_cli.estimation.smoother import rts_smooth_indexed
from cdgps_cli.measurement.dd_displacement import SatelliteDDDisplacement, SDObservations
from cdgps_cli.measurement.channel_screen import without_unusable_channels
from cdgps_cli.measurement.phase_sign import without_reversed_l1_phases
from cdgps_cli.model.dynamics_models import RandomWalk
from cdgps_cli.model.gps.positioning import antenna_reference_point_m
from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.records import INIT_FORMAT, Series, StateSeries, init_kind

from cdgps_cli.io.gnss_run import INGEST_SPP_SOURCE, GnssRun, antennas_info
from cdgps_cli.pipeline.antenna_models import receiver_with_antenna_model
from cdgps_cli.pipeline.gnss_ingest import anchor_obs, signal_obs
from cdgps_cli.pipeline.gnss_multipath import (OnColumns, column_occupants, multipath_note, multipath_settings,
                                               seam_transition, state_columns)
from cdgps_cli.io import states as states_io
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.core.gps_time import gps_time_str
from cdgps_cli.io.states import (ESTIMATE_METADATA, INIT_ATTACHMENT, INIT_WINDOWS_ATTACHMENT, STATE_FILTERED_TOPIC,
                                  STATE_TOPIC, States)

__all__ = ["gnss_init", "gnss_estimate", "export_kinematic_csv", "KINEMATIC_TOPIC",
           "is_gnss_states"]

KINEMATIC_TOPIC = "/cdgps/kinematic"
GNSS_CONFIG_ATTACHMENT = "gnss_config.toml"


# ----------------------------------------------------------------------------------------------
# stations from the run


def _stations(run: GnssRun, notes: dict | None = None):
    """The solvers' :class:`Station` of every receiver of the run; a multi-signal run's tables less their channels
    that carry no usable phase (:func:`~cdgps_cli.measurement.channel_screen.without_unusable_channels`), as `rtk`
    reads them, with
    the warnings naming them in ``notes[receiver]``."""
    if len(run.nav) == 0:
        raise CdgpsError(f"{run.path}: the run has no broadcast ephemerides; ingest it again with --nav NAVFILE "
                         f"(or nav = [...] in the config)")
    if not run.rovers:
        raise CdgpsError(f"{run.path}: the run has only the master receiver {run.master!r}; a displacement solution "
                         f"needs at least one rover receiver (ingest two or more --rinex/--ubx files)")
    sigs = tuple(run.cfg.signals)
    stations = {}
    for n in run.receivers:
        rx = run_receiver(run, n)
        table, said = without_unusable_channels(signal_obs(rx) if sigs else None, f"{rx.file} ({n})")
        obs = anchor_obs(rx, sigs)
        if not sigs:                       # GPS L1 alone: its phases are the observations
            obs, l1_said = without_reversed_l1_phases(obs, f"{rx.file} ({n})")
            said = said + l1_said
        if notes is not None:
            notes[n] = said
        # a position the run holds (the config's, ingest's single-point one) is named as the solvers' a-priori source
        given = {"given_position_source": rx.info.get("position_source")} if _position_args(run, n) is not None else {}
        stations[n] = Station(n, dict(rx.header, path=rx.file, **given), obs, table)
    return stations


def run_receiver(run: GnssRun, name: str):
    """Receiver ``name`` of the run as every solver takes it: with its antenna calibration (``run.antennas``, from
    ``[gnss] antex`` at ingest) taken out of its signals, and out of its GPS L1 table where that table anchors the
    epochs (:func:`~cdgps_cli.core.signals.anchor_signal`); the receiver itself without a calibration.  The one
    place ``init``, ``estimate`` and ``estimate --structure`` (GPS L1 and signals alike) get their receivers."""
    from cdgps_cli.core.signals import anchor_signal  # noqa: PLC0415

    model = run.antennas.get(name)
    if model is None:
        return run.receivers[name]
    return receiver_with_antenna_model(run.receivers[name], run.nav, _antenna_xyz(run, name), model,
                                       raw=anchor_signal(run.cfg.signals) is None)


def _antenna_xyz(run: GnssRun, name: str) -> np.ndarray | None:
    """Where receiver ``name``'s satellites are seen from for its antenna model (the elevations and azimuths of its
    calibration; metres do not matter): its given position, its header's, else the master's (a rover placed by
    single-point positioning later is within kilometres of it); None without any."""
    if name not in run.antennas or run.antennas[name] is None:
        return None
    for n in (name, run.master):
        p = _position_args(run, n)
        h = run.receivers[n].header.get("approx_position_xyz_m")
        if p is None and h is not None and np.linalg.norm(np.asarray(h, dtype=float)) > 6.0e6:
            p = np.asarray(h, dtype=float)
        if p is not None:
            return p
    raise CdgpsError(f"{run.path}: {name}: no position to evaluate its antenna calibration at (no position_ecef_m, no "
                     f"RINEX header position, nor the master's)")


def _position_args(run: GnssRun, name: str):
    """Explicit position for the solver (None: let it take the header, or SPP for a rover)."""
    rx = run.receivers[name]
    src, pos = rx.info.get("position_source"), rx.info.get("position_ecef_m")
    a = run.cfg.antenna(name)
    if a is not None and a.position_ecef_m is not None:
        return np.asarray(a.position_ecef_m, dtype=np.float64)
    if src in ("config position_ecef_m", INGEST_SPP_SOURCE) and pos is not None:
        return np.asarray(pos, dtype=np.float64)        # (a rover placed at ingest: the same origin in every window)
    return None


def _check_master_position(run: GnssRun):
    if _position_args(run, run.master) is None:
        h = run.receivers[run.master].header.get("approx_position_xyz_m")
        if h is None or np.linalg.norm(np.asarray(h, dtype=float)) < 6.0e6:
            raise CdgpsError(f"{run.path}: master {run.master} has no position (no RINEX header APPROX POSITION XYZ, no "
                             f"position_ecef_m in the config); the master must be at a known position")


# ----------------------------------------------------------------------------------------------
# init


def _naming_run(exc: CdgpsError, run: GnssRun, what: str) -> CdgpsError:
    """``exc`` with the RUN file and ``what`` in front, unless its message already names the file
    (a solver's 'float solution: the normal equations are singular' named neither)."""
    text = str(exc)
    return exc if str(run.path) in text else CdgpsError(f"{run.path}: {what}: {text}")


def gnss_init(run: GnssRun, *, options: dict | None = None, progress=None) -> dict:
    """Float solution, LAMBDA integers and fixed static solution of every rover → INIT dict.

    ``options`` overrides :class:`~cdgps_cli.estimation.baseline.BaselineOptions` fields of the run config
    (e.g. ``ratio_threshold``, ``partial``, ``fix``).
    """
    say = progress or (lambda m: None)
    unlocked: dict = {}
    stations = _stations(run, unlocked)
    _check_master_position(run)
    opt = BaselineOptions.from_gnss_config(run.cfg, kinematic_series=False, **(options or {}))
    opt.validate()
    rovers, segments = {}, {}
    for r in run.rovers:
        say(f"baseline {run.master} → {r}: float, LAMBDA, fixed …")
        try:
            res = solve_static_baseline(stations[run.master], stations[r], run.nav, opt,
                                        master_xyz=_position_args(run, run.master), rover_xyz=_position_args(run, r),
                                        iono_threshold_km=run.cfg.iono_threshold_km,
                                        engine=True)
        except CdgpsError as exc:
            raise _naming_run(exc, run, f"baseline {run.master} → {r}") from None
        res = json_safe(res)
        sol = res["fixed"] or res["float"]
        amb = res["ambiguities"]
        res["warnings"] += (_moving_unfixed_warning(res, run.cfg.displacement)
                            + _static_misfit_warning(res, run.cfg.displacement)
                            + unlocked[run.master] + unlocked[r])
        segments[r] = amb["segments"]
        names = list(res["states"])
        rovers[r] = {
            "solution": res["solution"],
            "states": res["states"],
            "sigma": dict(zip(names, sol["sigma_enu_m"])),
            "nominal_ecef_m": res["rover_apriori_ecef_m"],
            "nominal_source": res["rover_apriori_source"],
            "rover_ecef_m": res["rover_ecef_m"],
            **({"rover_troposphere_ecef_m": res["rover_troposphere_ecef_m"]} if "rover_troposphere_ecef_m" in res else {}),
            "baseline_enu_from_master_m": res["baseline_enu_from_master_m"],
            "baseline_length_m": res["baseline_length_m"],
            "float": res["float"], "fixed": res["fixed"],
            "ratio": amb["ratio"], "ratio_full_set": amb["ratio_full_set"], "ratio_threshold": amb["ratio_threshold"],
            "success_rate": amb.get("success_rate"),
            "accepted": amb["accepted"], "partial": amb["partial"], "n_segments": amb["n_segments"],
            "n_fixed": amb["n_fixed"], "n_estimated": amb["n_estimated"],
            "n_half_cycle_excluded": amb["n_half_cycle_excluded"],
            **{k: amb[k] for k in ("n_float_glonass", "n_glonass_fixed_by_engine") if k in amb},
            "residuals": res["residuals"], "kinematic": res["kinematic"], "epochs": res["epochs"],
            "satellites": res["satellites"], "warnings": res["warnings"], "options": res["options"],
            "solver": res["solver"],
        }
    states = {k: v for r in rovers.values() for k, v in r["states"].items()}
    sigma = {k: v for r in rovers.values() for k, v in r["sigma"].items()}
    ratios = [r["ratio"] for r in rovers.values() if isinstance(r["ratio"], (int, float))]
    return {
        "format": INIT_FORMAT,
        "kind": "gnss",
        "cdgps_version": __version__,
        "run": Path(run.path).name,
        "config_name": run.cfg.name,
        "config_sha256": run.cfg.sha256,
        "displacement_model": run.cfg.displacement,
        "master": run.master,
        "master_ecef_m": _master_xyz(run).tolist(),
        "coordinates": list(states),
        "states": states,
        "sigma": sigma,
        "solution": {r: v["solution"] for r, v in rovers.items()},
        "n_fixed": int(sum(v["n_fixed"] for v in rovers.values())),
        "n_estimated": int(sum(v["n_estimated"] for v in rovers.values())),
        "ratio": min(ratios) if ratios else None,
        "biases": [b for r in rovers for b in gnss_biases(run.master, r, segments[r])],
        "rovers": rovers,
        "options": json_safe(asdict(opt)),
        **_signals_summary(run, rovers),
        **({"window": run.window} if run.window is not None else {}),
        **({"antennas": antennas_summary(run)} if run.antex is not None else {}),
    }


def antennas_summary(run: GnssRun) -> dict:
    """The antenna calibrations a run's observations are corrected by (:func:`~cdgps_cli.io.gnss_run.antennas_info`)."""
    return antennas_info(run.antex, run.antennas)


def n_fixed_with_glonass(ambiguities: dict) -> int:
    """Integers a solution fixed: ``n_fixed`` and the GLONASS DDs a glonass_fix solution fixed (counted apart)."""
    return int(ambiguities["n_fixed"]) + int(ambiguities.get("n_glonass_fixed_by_engine") or 0)


def _moving_unfixed_warning(res: dict, model: str) -> list:
    """A warning for a rover under a moving model with no integer fixed whose static float does not fit (unit
    variance above :data:`NIS_MISFIT_PER_DOF`): it moves, and neither its static displacement nor its σ describe
    it (a simulated 5 m wander under a 1 mm/√s walk: 69 m off, σ 2 cm, silently)."""
    uv = (res["float"] or {}).get("unit_variance")
    moving = (res["float"] or {}).get("moving_rover")
    if model == "static" or n_fixed_with_glonass(res["ambiguities"]):
        return []
    misfit = uv is not None and uv > NIS_MISFIT_PER_DOF
    # the float is all there is: its integers were not taken (the phase check, or a float that does not fit)
    if misfit and (res["float"] or {}).get("rejected_fix"):
        return [f"no integer fixed (the integers LAMBDA took were rejected, above), and the static float does not fit "
                f"the data (unit variance {uv:.3g}: the rover moves); its static displacement and sigma do not "
                f"describe it, and estimate's states from INIT's float ambiguities will not hold"]
    if moving is not None:
        return [f"no integer fixed, and the rover moves: its static float solution lands "
                f"{moving['static_float_apart_m']:.0f} m from its code's mean position, which INIT gives as its static "
                f"displacement (the mean over the record, to metres); 'cdgps estimate' refuses this INIT ('cdgps rtk' "
                f"gives a float solution that follows the rover)"]
    if not misfit:
        return []
    return [f"no integer fixed, and the static float does not fit the data (unit variance {uv:.3g}): the rover moves "
            f"more than its {model} model lets init's float follow ([gnss.displacement] sigma_m_per_sqrt_s); its static "
            f"displacement and sigma do not describe it, and estimate's states will not hold"]


#: a static solution whose DD phase unit variance exceeds this (its σ under half the residuals' spread) is said not
#: to fit: the real static pairs give 0.0001–1.5; an unflagged one-cycle slip on the real mosaic rover 5.3, a 1 ms
#: receiver clock jump in the M8P rover's codes 9.2 (both 0.8–1 m off with sub-millimetre σ)
STATIC_UNIT_VARIANCE_WARNING = 4.0


def _static_misfit_warning(res: dict, model: str) -> list:
    """A warning for a static solution (fixed, else float) whose DD phase residuals are far larger than its weights
    allow (unit variance above :data:`STATIC_UNIT_VARIANCE_WARNING`), naming the satellites with the largest
    residuals: a slip the receiver did not flag, a receiver clock jump, or a moving rover, which the solution and
    its σ do not describe."""
    sol = res["fixed"] or res["float"] or {}
    uv = sol.get("unit_variance")
    if model != "static" or uv is None or not uv > STATIC_UNIT_VARIANCE_WARNING:
        return []
    per = (res.get("residuals") or {}).get("per_satellite_rms_m") or {}
    worst = ", ".join(f"{k} {v * 1e3:.0f} mm" for k, v in sorted(per.items(), key=lambda kv: -kv[1])[:3])
    return [f"the {res['solution']} static solution does not fit its double differences (unit variance {uv:.3g}, "
            f"about 1 when it holds; largest residual rms: {worst}): a cycle slip the receiver did not flag, a "
            f"receiver clock jump or a rover that moves can put it decimetres to metres off while its sigma stays "
            f"millimetric; 'cdgps rtk' on the same files shows where the epochs disagree"]


def _signals_summary(run: GnssRun, rovers: dict) -> dict:
    """With ``[gnss] signals``: the frequency slots used (per signal its wavelength, m) and how DDs are
    formed, for INIT.json and the STATES metadata (empty without signals)."""
    if not run.cfg.signals:
        return {}
    lam = {}
    for v in rovers.values():
        for g, i in ((v.get("epochs") or {}).get("signals") or {}).items():
            lam.setdefault(g, i.get("wavelength_m"))
    return {"signals": list(run.cfg.signals), "wavelengths_m": lam,
            "dd_groups": "per constellation and frequency slot, own reference satellite; no inter-system or "
                         "inter-frequency DD; one ambiguity per satellite-signal lock segment; integers of all "
                         "groups fixed as one set (LAMBDA, ratio test, partial fixing)"
                         + (_glonass_groups(rovers) if any(str(g).startswith("R:") for g in run.cfg.signals) else "")}


def _glonass_groups(rovers: dict) -> str:
    """How the GLONASS (FDMA) groups were treated, for :func:`_signals_summary`."""
    if any((v.get("options") or {}).get("glonass_fix") for v in rovers.values()):
        return ("; GLONASS (FDMA) groups fixed too (glonass_fix, identical receivers): DD integers N_i − N_r in each "
                "satellite's own cycles (biases: dd_integer_cycles, fdma_channel), wavelength per satellite")
    return ("; GLONASS (FDMA) groups float: one bias (m) per lock segment, wavelength per satellite, "
            "never passed to LAMBDA")


def gnss_biases(master: str, rover: str, segments: list) -> list:
    """INIT's ``biases`` entries (:data:`cdgps_cli.core.records.INIT_FORMAT`) of one rover's ambiguity
    segments: SD ambiguities (rover − master) relative to each connected set's reference (pivot)
    segment, so that double differences against ``reference`` are integers; metres and cycles (each
    segment's own wavelength with ``[gnss] signals``, else GPS L1's)."""
    out = []
    for s in segments:
        lam = s.get("wavelength_m", GPS_L1_WAVELENGTH_M)
        fixed = bool(s["fixed"])
        cycles = s["integer"] if fixed else s["float_cycles"]
        out.append({
            "master": master, "rover": rover, "satellite": s["sat"], "reference": s.get("reference"),
            "bias_m": None if cycles is None else float(lam * cycles),
            "sigma_m": 0.0 if fixed else (None if s["sigma_cycles"] is None else float(lam * s["sigma_cycles"])),
            "integer_cycles": int(s["integer"]) if fixed else None, "fixed": fixed, "pivot": bool(s["pivot"]),
            "segment_start_s": s["first_gps_s"], "segment_end_s": s["last_gps_s"],
            **{k: v for k, v in s.items() if k not in _SEGMENT_MAPPED},
        })
    return out


#: fields of a solver's ambiguity segment that a ``biases`` entry holds under its own names; every other
#: field (n_epochs, half_cycle_flag, float_cycles, sigma_cycles, wavelength_m, signal, reason, …) is carried as is
_SEGMENT_MAPPED = {"sat", "reference", "fixed", "integer", "pivot", "first_gps_s", "last_gps_s"}
_BIAS_OWN = {"master", "rover", "satellite", "reference", "bias_m", "sigma_m", "integer_cycles", "fixed", "pivot",
             "segment_start_s", "segment_end_s"}


def rover_segments(init: dict, rover: str) -> list[dict]:
    """One rover's ambiguity segments in the solver's form (``sat``, ``first_gps_s``, ``last_gps_s``,
    ``fixed``, ``integer``, ``pivot``, …), from INIT's ``biases`` — the one record of them since
    INIT v2 — or, in an older INIT.json, from its legacy ``rovers[rover]["ambiguities"]`` list."""
    legacy = (init.get("rovers", {}).get(rover) or {}).get("ambiguities")
    if legacy is not None:
        return list(legacy)
    out = []
    for b in init.get("biases", []):
        if b.get("rover") != rover:
            continue
        try:
            seg = {"sat": str(b["satellite"]), "reference": b.get("reference"), "pivot": bool(b["pivot"]),
                   "fixed": bool(b["fixed"]), "integer": b.get("integer_cycles"),
                   "first_gps_s": float(b["segment_start_s"]), "last_gps_s": float(b["segment_end_s"])}
        except (KeyError, TypeError, ValueError):
            raise CdgpsError(f"INIT.json: biases entry of {rover}: expected satellite, pivot, fixed, "
                             "segment_start_s and segment_end_s") from None
        seg.update({k: v for k, v in b.items() if k not in _BIAS_OWN})
        out.append(seg)
    return out


def _master_xyz(run: GnssRun) -> np.ndarray:
    p = _position_args(run, run.master)
    if p is None:
        p = antenna_reference_point_m(run.receivers[run.master].header, f"{run.path}: master {run.master}")
    return p


def is_gnss_init(init: dict) -> bool:
    return init_kind(init) == "gnss"


# ----------------------------------------------------------------------------------------------
# per-epoch information of the DD phases with the fixed integers


def _group_use(d, use: np.ndarray) -> list:
    """``use`` split by signal group (one entry without ``[gnss] signals``)."""
    if getattr(d, "group", None) is None:
        return [use]
    return [use & (d.group == k) for k in range(len(d.group_names))]


def _epoch_information(w: dict, use: np.ndarray):
    """Per epoch: c = rᵀPr of the DD phases at the static solution (its NIS), dof, whether it has
    DDs (summed over the signal groups), and per group its usable rows and its reference row per
    epoch (−1: fewer than two usable rows); and the DD weight blocks of the usable rows (``known_phase_blocks``)."""
    d = w["data"]
    n_ep = d.t_label.size
    c = np.zeros(n_ep)
    dof = np.zeros(n_ep, dtype=np.int64)
    has = np.zeros(n_ep, dtype=bool)
    r = w["r_ph"]
    # every row usable (all ambiguities known): the solver's own phase weights, not formed again
    blocks, refs = known_phase_blocks(d, w["var_ph"], w["refs_ph"], w["blocks_ph"], use)
    for rows, p in blocks:
        ep = d.epoch[rows[:, 0]]
        rk = r[rows]
        c[ep] += np.einsum("ki,kij,kj->k", rk, p, rk)
        dof[ep] += rows.shape[1] - 1
        has[ep] = True
    return c, dof, has, list(zip(_group_use(d, use), refs)), blocks


def _random_walk(model: SatelliteDDDisplacement, t: np.ndarray, sigma_rw, p0_sigma: float, smooth: bool):
    """δx (displacement − static solution) by the engine: the forward filter
    (:func:`~cdgps_cli.estimation.model_filter.filter_numpy`, one update per epoch: the model is linear)
    with random-walk dynamics (A = I, Q = diag(σ²)Δt) from δx = 0 ± ``p0_sigma``, and the RTS
    smoother (:func:`~cdgps_cli.estimation.smoother.rts_smooth_indexed`) when ``smooth`` — what
    :func:`gnss_estimate` runs on one window (:func:`_dynamics_of`, :func:`_forward`).

    Returns smoothed (or filtered) x (N, 3), P (N, 3, 3), filtered x, P, and NIS (N,) (NaN: no DDs).
    """
    return _filtered(*_dynamics_of(model, "random_walk", sigma_rw, None, p0_sigma), t, smooth)


def _constant_velocity(model: SatelliteDDDisplacement, t: np.ndarray, accel_sigma: float, p0_sigma: float,
                       smooth: bool):
    """δx as :func:`_random_walk`, with constant-velocity dynamics instead: the state [δx, v] (E/N/U, m and m/s;
    :class:`~cdgps_cli.model.dynamics_models.ConstantVelocity`, each velocity a random walk of ``accel_sigma``
    m/s/√s, white acceleration), the DDs seeing δx only (the model stacked on the six states,
    :class:`~cdgps_cli.measurement.stacked.Stacked`), from δx = 0 ± ``p0_sigma`` and v = 0 ± ``p0_sigma`` per second.
    Returns the six states of each as :func:`_random_walk` its three (x (N, 6), P (N, 6, 6): [δx, v], m and m/s)."""
    xs, ps, xf, pf, nis = _filtered(*_dynamics_of(model, "constant_velocity", None, accel_sigma, p0_sigma), t, smooth)
    return np.asarray(xs), np.asarray(ps), np.asarray(xf), np.asarray(pf), nis


def _dynamics_of(dd: SatelliteDDDisplacement, model: str, sigma_rw, accel_sigma, p0_sigma: float,
                 multipath: tuple | None = None):
    """(measurement model, dynamics, prior covariance at the first epoch) of a moving rover's states: the random
    walk of the displacements (3 states, σ ``sigma_rw`` m/√s), or constant velocity [displacement, velocity] (6,
    ``accel_sigma`` m/s/√s) with the DDs seeing the displacements alone; the prior 0 ± ``p0_sigma``.  With
    ``multipath`` (n, σ m, τ s: ``dd`` on [δx, m] with n multipath columns, :mod:`cdgps_cli.pipeline.gnss_multipath`)
    n Gauss–Markov states follow, each from its stationary 0 ± σ."""
    if model == "random_walk":
        meas, dyn, P0 = dd, RandomWalk(3, sigma_rw), np.eye(3) * p0_sigma**2
    else:
        from cdgps_cli.measurement.stacked import Stacked  # noqa: PLC0415
        from cdgps_cli.model.dynamics_models import ConstantVelocity  # noqa: PLC0415
        dyn, P0 = ConstantVelocity(3, accel_sigma), np.eye(6) * p0_sigma**2
        meas = Stacked([("dd", dd)], n_state=6) if multipath is None else None
    if multipath is None:
        return meas, dyn, P0
    from cdgps_cli.model.dynamics_models import WithGaussMarkov  # noqa: PLC0415
    n_gm, sigma, tau = multipath
    nb = P0.shape[0]
    P = np.zeros((nb + n_gm, nb + n_gm))
    P[:nb, :nb] = P0
    P[nb:, nb:] = np.eye(n_gm) * sigma**2
    meas = dd if nb == 3 else OnColumns(dd, np.r_[0:3, nb:nb + n_gm], nb + n_gm)
    return meas, WithGaussMarkov(dyn, n_gm, sigma, tau), P


def _filtered(model, dyn, P0: np.ndarray, t: np.ndarray, smooth: bool):
    """The engine's forward filter of ``model`` under ``dyn`` from x = 0 ± ``P0`` (one update per epoch: the model is
    linear) and, when ``smooth``, its RTS pass: (x, P) smoothed (or filtered), (x, P) filtered, NIS (N,)."""
    fr = _forward(model, dyn, t, np.zeros(P0.shape[0]), P0)
    xf, pf = fr["x"], fr["P"]
    if not smooth:
        return xf, pf, xf, pf, fr["nis"]
    xs, ps = rts_smooth_indexed(np.array(xf), np.array(pf), *fr["transitions"])
    return xs, ps, xf, pf, fr["nis"]


def _forward(model, dyn, t: np.ndarray, x0: np.ndarray, P0: np.ndarray):
    """The engine's forward filter of ``model`` under ``dyn`` from the prior x0 ± P0 at the first epoch (one update
    per epoch: the model is linear): x, P filtered, NIS and the transitions into each epoch."""
    return filter_numpy(model, dyn, t, x0, P0, max_iterations=1, keep_rows=False)


#: the largest |integer| (cycles) an INIT's ambiguity may hold: 2³¹ cycles of 19 cm are 400,000 km, far beyond
#: any arc's double difference, and within the int64 arrays the solvers hold them in
INIT_INTEGER_LIMIT = 2**31


def _init_integer(v, what: str):
    """``v`` (an INIT integer: None, or an integral number within ±:data:`INIT_INTEGER_LIMIT`) as int or None;
    CdgpsError naming ``what`` otherwise."""
    if v is None:
        return None
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and float(v).is_integer()
    if not ok or abs(v) >= INIT_INTEGER_LIMIT:
        raise CdgpsError(f"INIT.json: {what}: expected an integer of at most ±{INIT_INTEGER_LIMIT} cycles, got {v!r}")
    return int(v)


def _integers_from_init(init: dict, r: str) -> dict:
    out = {}
    for s in rover_segments(init, r):
        try:
            key = (str(s["sat"]), float(s["first_gps_s"]))
            v = s.get("integer") if s.get("fixed") or s.get("pivot") else None
        except (KeyError, TypeError, ValueError):
            raise CdgpsError("INIT.json: malformed ambiguity segment (needs sat, first_gps_s, integer)") from None
        out[key] = _init_integer(v, f"biases entry {key[0]} of {r}: integer_cycles")
    return out


def _glonass_integers_from_init(init: dict, r: str) -> dict | None:
    """The GLONASS DD integers of rover ``r`` in an INIT whose GLONASS DDs the static engine fixed (glonass_fix),
    for :func:`~cdgps_cli.estimation.baseline.baseline_from_init`: ``{(satellite, first_gps_s): {"dd", "channel",
    "reference", "pivot"}}`` of every GLONASS segment (``dd`` None where not fixed); None when none was fixed.

    Whether they were fixed is read from both records INIT keeps of it, the rover's ``n_glonass_fixed_by_engine``
    and the entries' ``fixed_by_engine``, which must agree; every fixed entry must carry its integer, a pivot 0.
    CdgpsError otherwise (an INIT written before INIT held them, or edited): a GLONASS-float solution, 1.8 mm from
    the fixed one on the mosaic pair, is never given in its place."""
    segs = [s for s in rover_segments(init, r) if str(s["sat"]).startswith("R")]
    claimed = (init["rovers"][r] or {}).get("n_glonass_fixed_by_engine") or 0
    flagged = [s for s in segs if s.get("fixed_by_engine") and not s.get("pivot")]
    if not claimed and not flagged:
        return None
    if claimed and not any("dd_integer_cycles" in s for s in segs):
        raise CdgpsError(f"INIT.json: {r}'s GLONASS DDs were fixed by the static engine (glonass_fix), but this INIT "
                         f"does not carry their integers (no dd_integer_cycles: written before INIT held them); "
                         f"run 'cdgps init' again")
    if claimed != len(flagged):
        raise CdgpsError(f"INIT.json: rovers.{r}.n_glonass_fixed_by_engine = {claimed!r}, but {len(flagged)} GLONASS "
                         f"biases entries say fixed_by_engine: the two records of the glonass_fix integers disagree")
    out = {}
    for s in segs:
        what = f"biases entry {s['sat']} of {r}: dd_integer_cycles"
        v = _init_integer(s.get("dd_integer_cycles"), what)
        if v is None and s.get("fixed_by_engine") and not s.get("pivot"):
            raise CdgpsError(f"INIT.json: {what}: missing, but the entry says fixed_by_engine")
        if s.get("pivot") and v not in (None, 0):
            raise CdgpsError(f"INIT.json: {what}: {v} on a reference (pivot) entry, where it is 0 by definition")
        out[(str(s["sat"]), float(s["first_gps_s"]))] = {"dd": v, "channel": s.get("fdma_channel"),
                                                         "reference": s.get("reference"), "pivot": bool(s["pivot"])}
    return out


# ----------------------------------------------------------------------------------------------
# estimate


def _solution_from_init(init: dict, r: str) -> dict | None:
    """INIT's static solution of rover ``r`` for :func:`~cdgps_cli.estimation.baseline.baseline_from_init`
    (``solution``): its fixed ENU displacement (``enu_m``, None without a fixed block), its float one
    (``float_enu_m``), each segment's float value and σ (cycles), and, of a partially fixed solution, each float
    segment's value and σ in it (``solution_cycles``) with the fixed position's covariance (``cov_enu_m2``, m²)
    and the DD residuals they leave (``residuals``), a glonass_fix solution's GLONASS pivots' own arc values
    (``pivot_arc_cycles``); None without either block."""
    rov = init["rovers"].get(r) or {}
    fixed, flt = rov.get("fixed") or {}, rov.get("float") or {}
    if fixed.get("enu_m") is None and flt.get("enu_m") is None:
        return None
    keyed = [((str(s["sat"]), float(s["first_gps_s"])), s) for s in rover_segments(init, r)]
    floats = {k: (s.get("float_cycles"), s.get("sigma_cycles")) for k, s in keyed if not s.get("pivot")}
    at_solution = {k: (s["solution_cycles"], s.get("solution_sigma_cycles")) for k, s in keyed
                   if not s.get("pivot") and s.get("solution_cycles") is not None}
    pivot_arcs = {k: s["pivot_arc_cycles"] for k, s in keyed if s.get("pivot") and s.get("pivot_arc_cycles") is not None}
    return {"enu_m": _enu_from_init(fixed, f"rovers.{r}.fixed.enu_m"),
            "float_enu_m": _enu_from_init(flt, f"rovers.{r}.float.enu_m"),
            "float_cycles": floats, "solution_cycles": at_solution,
            "cov_enu_m2": _cov_from_init(fixed, f"rovers.{r}.fixed.cov_enu_m2"),
            "residuals": rov.get("residuals"), "pivot_arc_cycles": pivot_arcs}


def _cov_from_init(block: dict, key: str) -> np.ndarray | None:
    """``block["cov_enu_m2"]`` as a (3, 3) array (None when absent: an INIT written before it held it); CdgpsError
    naming ``key`` unless a symmetric 3 × 3 matrix of finite numbers with a positive diagonal (m²)."""
    v = block.get("cov_enu_m2")
    if v is None:
        return None
    try:
        c = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        c = np.zeros(0)
    if c.shape != (3, 3) or not np.all(np.isfinite(c)) or not np.all(np.diag(c) > 0) or not np.allclose(c, c.T):
        raise CdgpsError(f"INIT.json: {key}: expected a symmetric 3 x 3 covariance of finite numbers with a positive "
                         f"diagonal (m^2), got {v!r}")
    return c


def _enu_from_init(block: dict, key: str) -> list | None:
    """``block["enu_m"]`` as 3 floats (None when absent); CdgpsError naming ``key`` unless 3 finite numbers."""
    v = block.get("enu_m")
    if v is None:
        return None
    try:
        out = [float(x) for x in v]
    except (TypeError, ValueError):
        out = []
    if len(out) != 3 or not all(math.isfinite(x) for x in out):
        raise CdgpsError(f"INIT.json: {key}: expected 3 finite numbers (m), got {v!r}")
    return out


def _init_position(v, r: str) -> np.ndarray:
    """INIT's ``rover_troposphere_ecef_m`` of rover ``r``: three finite numbers (m), else CdgpsError."""
    try:
        x = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        x = np.zeros(0)
    if x.shape != (3,) or not np.all(np.isfinite(x)):
        raise CdgpsError(f"INIT.json: rovers.{r}.rover_troposphere_ecef_m: expected three finite ECEF "
                         f"coordinates (m), got {v!r}")
    return x


def solve_with_init_integers(run, init: dict, r: str, stations: dict):
    """Rover ``r``'s baseline with INIT's options, integers and fixed solution (no kinematic series), never
    solved again (:func:`~cdgps_cli.estimation.baseline.baseline_from_init`): evaluated at INIT's solution when
    every integer is fixed; with float (partially fixed, GLONASS) segments the static engine's float solution
    conditioned on INIT's integers for an engine INIT (a glonass_fix INIT's GLONASS DD integers too, and then
    only so), INIT's position with the float ambiguities at it for a batch one.

    Returns (baseline result, its working data ``_work``, INIT's rover entry, the BaselineOptions); raises CdgpsError when
    INIT's options are not valid or its nominal position is not this run's.
    """
    rov = init["rovers"][r]
    o = dict(rov.get("options") or {})
    o.setdefault("age_sigma_m_per_s", EPOCH_PAIRING_DEFAULTS["age_sigma_m_per_s"])   # an INIT before it was recorded
    try:
        opt = BaselineOptions(**{k: v for k, v in o.items() if k in BaselineOptions.__dataclass_fields__})
        opt = BaselineOptions(**{**asdict(opt), "kinematic_series": False})
        opt.validate()
    except (TypeError, CdgpsError) as exc:
        raise CdgpsError(f"INIT.json: bad options for {r} (rovers.{r}.options): {exc}") from None
    trop = rov.get("rover_troposphere_ecef_m")           # where init evaluated the rover's troposphere
    rover = stations[r] if trop is None else stations[r]._replace(troposphere_xyz_m=_init_position(trop, r))
    res = baseline_from_init(stations[run.master], rover, run.nav, opt,
                             master_xyz=_position_args(run, run.master), rover_xyz=_position_args(run, r),
                             integers=_integers_from_init(init, r), solution=_solution_from_init(init, r),
                             engine_init=rov.get("solver") == "static_engine",
                             glonass_integers=_glonass_integers_from_init(init, r))
    w = res.pop("_work")
    if not np.allclose(w["xr0"], rov["nominal_ecef_m"], atol=1e-6):
        raise CdgpsError(f"INIT.json: the nominal position of {r} differs from this run's")
    return res, w, rov, opt


class EstimateWindow(NamedTuple):
    """One INIT of ``cdgps estimate`` and the RUN read on its window: ``read()`` gives the run (read when its turn
    comes, dropped after it), ``source`` names the INIT (its file) in events and messages."""

    read: Callable
    init: dict
    init_text: str
    source: str | None = None


def gnss_estimate(run: GnssRun, init: dict, init_text: str, out_path: str | Path, *, smooth: bool = False,
                  progress=None, extra_options: dict | None = None) -> dict:
    """Per-epoch displacement states of every rover from INIT's integers → STATES.mcap (one INIT: see
    :func:`gnss_estimate_windows`)."""
    return gnss_estimate_windows([EstimateWindow(lambda: run, init, init_text)], out_path, smooth=smooth,
                                 progress=progress, extra_options=extra_options)


def gnss_estimate_windows(windows: list, out_path: str | Path, *, smooth: bool = False, progress=None,
                          extra_options: dict | None = None) -> dict:
    """Per-epoch displacement states of every rover from the integers of one or more INITs → one STATES.mcap.

    Each INIT (:class:`EstimateWindow`, in time order, made on windows of one RUN that do not overlap:
    ``cdgps init --start/--duration``) serves its own window, which is read and solved alone, so the memory is that
    of one window whatever the record's length (issue 29).  The random-walk and constant-velocity states are one
    filter over all the windows: each window starts from the previous window's last state, predicted over the seam
    and moved into the window's own origin (its static solution), and ``smooth`` runs the RTS pass over all of them;
    the static model's states are each window's static solution.  One INIT gives what it always gave, byte for
    byte."""
    say = progress or (lambda m: None)
    if not windows:
        raise CdgpsError("estimate: no INIT given")
    windows = _windows_in_order(windows)
    passes, carried, frames = [], {}, {}
    several = len(windows) > 1           # (one window: its rows stay in memory, as always; several: on disk)
    spill = _Scratch(out_path) if several else None
    for k, win in enumerate(windows):
        if several:
            say(f"window {k + 1} of {len(windows)}" + (f" ({win.source})" if win.source else "") + " …")
        try:
            passes.append(_forward_window(win, smooth, carried, frames, say, spill))
            if several:
                _return_freed_memory()
        except CdgpsError as exc:          # (several INITs: the one whose window failed is named)
            msg = str(exc)
            if several and win.source and not msg.startswith(win.source):
                msg = msg[len("INIT.json: "):] if msg.startswith("INIT.json: ") else msg
                raise CdgpsError(f"{win.source}: {msg}") from None
            raise
    return _write_windows(passes, windows, out_path, smooth, extra_options, say)


def _return_freed_memory() -> None:
    """Give the heap memory a window freed back to the system (glibc ``malloc_trim``; elsewhere nothing).  glibc
    serves allocations below its mmap threshold from the heap, and raises that threshold each time a large block is
    freed, so a window's arrays of a few MiB stay on the heap and its peak would otherwise add up over the windows
    (6 h of 10 Hz with multipath states: 510 MiB against 364 MiB)."""
    from cdgps_cli.core.heap import trim  # noqa: PLC0415

    trim()


def _windows_in_order(windows: list) -> list:
    """The windows in time order (by INIT's window); several must each have a window, none overlapping, and every
    rover the same nominal position in all of them (their states are offsets from it: a rover placed anew in each
    window, metres apart, would jump at each seam)."""
    if len(windows) == 1:
        return list(windows)
    spans = []
    for w in windows:
        span = init_window(w.init)
        if span is None:
            raise CdgpsError(f"{w.source or 'an INIT'}: an INIT of the whole record among several: each must be made "
                             f"on a window of the record ('cdgps init --start S --duration D')")
        spans.append(span)
    order = sorted(range(len(windows)), key=lambda k: spans[k][0])
    out = [windows[k] for k in order]
    for a, b in zip(order, order[1:]):
        if spans[b][0] < spans[a][1]:
            raise CdgpsError(f"{windows[a].source or 'an INIT'} and {windows[b].source or 'another'}: their windows "
                             f"overlap ({gps_time_str(spans[a][0])} – {gps_time_str(spans[a][1])} and "
                             f"{gps_time_str(spans[b][0])} – {gps_time_str(spans[b][1])}): each INIT must serve its own "
                             f"window of the record")
    first = out[0]
    for w in out[1:]:
        for r, rov in (first.init.get("rovers") or {}).items():
            other = ((w.init.get("rovers") or {}).get(r) or {}).get("nominal_ecef_m")
            mine = (rov or {}).get("nominal_ecef_m")
            for src, v in ((first.source, mine), (w.source, other)):
                if not (isinstance(v, list) and len(v) == 3 and all(isinstance(c, (int, float)) for c in v)):
                    raise CdgpsError(f"{src or 'an INIT'}: rovers.{r}.nominal_ecef_m: expected [x, y, z] in m (ECEF), "
                                     f"got {v!r}")
            if not np.allclose(other, mine, rtol=0, atol=1e-6):
                raise CdgpsError(f"{w.source or 'an INIT'}: rover {r}'s nominal position differs from that of "
                                 f"{first.source or 'the first INIT'} ({mine} and {other} m, ECEF): the windows' "
                                 f"states would be offsets from different points; give the rover a position "
                                 f"([gnss.antennas.\"{r}\"] position_ecef_m) or ingest the run again, which places it "
                                 f"once for every window")
    return out


class _Scratch:
    """Where several windows' rows and arrays wait for the passes after them: unlinked temporary files beside the
    output (nothing is left on disk, however the command ends)."""

    def __init__(self, out_path):
        self.dir = Path(out_path).resolve().parent
        self.out_path = out_path
        try:
            self.dir.mkdir(parents=True, exist_ok=True)     # (as the output's writer makes it)
        except OSError as exc:
            raise CdgpsError(f"{out_path}: cannot make its directory: {(exc.strerror or str(exc)).lower()}") from None

    def save(self, **arrays):
        """The arrays in a fresh unlinked file; returns it (``np.load`` after ``seek(0)``)."""
        try:
            fh = tempfile.TemporaryFile(prefix=".cdgps-estimate-", dir=self.dir)
            np.savez(fh, **arrays)
        except OSError as exc:
            raise CdgpsError(f"{self.out_path}: cannot write a scratch file in {self.dir}: "
                             f"{(exc.strerror or str(exc)).lower()}") from None
        return fh


def _load(fh):
    """The arrays :meth:`_Scratch.save` wrote (an ``np.load`` of the file, to use in a ``with``)."""
    fh.seek(0)
    return np.load(fh)


class _WindowPass(NamedTuple):
    """What one window leaves for the passes after it: its axis and arrays (:class:`_EstimateArrays`, states not yet
    smoothed; with several windows a namespace of its axis and scratch file, :func:`_spill_window`), per rover its forward track (None: static) and the inputs of its DD residuals, and what the
    STATES metadata and summary say of it."""

    a: "_EstimateArrays"
    tracks: dict
    residual_inputs: dict
    summary_rovers: dict
    events: list
    notes: list
    signals: dict
    run_info: SimpleNamespace


def _forward_window(win: EstimateWindow, smooth: bool, carried: dict, frames: dict, say, spill) -> _WindowPass:
    """One window: each rover's baseline at INIT's integers, its single-epoch solutions, and its forward filter from
    the state ``carried`` out of the previous window (updated here); the states held in the first window's origin
    (``frames``, per rover)."""
    run, init = win.read(), win.init
    _check_init_of_run(init, run)
    _check_moving_float_init(init)
    stations = _stations(run)
    _check_master_position(run)
    model = run.cfg.displacement
    per, events, noise, mps = {}, [], {}, {}
    for r in run.rovers:
        say(f"baseline {run.master} → {r}: INIT's solution and integers, {model} states …")
        res, w, rov, _ = solve_with_init_integers(run, init, r, stations)
        if run.cfg.phase_noise == "auto":
            noise[r] = phase_variance_factor(w.get("kinematic"))
            _scale_phase_variances(w, noise[r]["factor"])
        per[r] = (res, w, rov)
        events.extend(_events(r, run.master, res, w))
    signals = _signals_summary(run, {r: v[0] for r, v in per.items()})
    # common time axis: every matched epoch of any rover
    t_all = np.unique(np.concatenate([w["data"].t_label for _, w, _ in per.values()]))
    names = [f"{r}_{c}" for r in run.rovers for c in "enu"]
    a = _EstimateArrays(t_all, len(names), len(run.rovers), model != "static" and smooth,
                        rates=model == "constant_velocity")
    summary_rovers, tracks, residual_inputs = {}, {}, {}
    for j, r in enumerate(run.rovers):
        res, w, _ = per[r]
        sl = slice(3 * j, 3 * j + 3)
        idx = np.searchsorted(t_all, w["data"].t_label)
        frames.setdefault(r, np.asarray(w["x_final"], dtype=np.float64))
        track, groups, n_blind, mp = _rover_forward(a, w, sl, idx, model, run.cfg, res, carried.get(r), frames[r])
        if mp is not None:
            mps[r] = mp
        if track is not None:
            carried[r] = track.last()
        tracks[r] = track
        ri = _residual_inputs(w, groups)
        residual_inputs[r] = (ri if spill is None else _SpilledInputs(ri, spill), idx)
        a.kinematic(w["kinematic"], idx, sl, j)
        n_fix = n_fixed_with_glonass(res["ambiguities"])
        summary_rovers[r] = dict(_rover_summary(res, w, names[sl]), epochs=int(idx.size), n_fixed_with_glonass=n_fix,
                                 epochs_without_fixed_dd=n_blind if n_fix else int(idx.size),
                                 **({"phase_noise": noise[r]} if r in noise else {}),
                                 **({"multipath": mps[r]} if r in mps else {}))
        per[r] = None                    # (the rover's rows: what the later passes need is in residual_inputs)
    info = SimpleNamespace(cfg=run.cfg, master=run.master, rovers=list(run.rovers), path=run.path,
                           antennas=antennas_summary(run) if run.antex is not None else None, names=names,
                           window=init_window(init))
    out = _WindowPass(a, tracks, residual_inputs, summary_rovers, events,
                      [_phase_noise_note(r, v) for r, v in noise.items()]
                      + [multipath_note(r, v) for r, v in mps.items()], signals, info)
    return out if spill is None else _spill_window(out, spill)


_ARRAY_FIELDS = ("q", "P", "qf", "Pf", "kq", "kP", "kin_n", "kin_pdop", "nis_sum", "dof_tot")


def _spill_window(p: "_WindowPass", spill: "_Scratch") -> "_WindowPass":
    """A window's per-epoch arrays and filter tracks moved to a scratch file (several windows: one window's arrays
    in memory at a time); what stays is its axis and the tracks' small parts."""
    arrays = {f: getattr(p.a, f) for f in _ARRAY_FIELDS if getattr(p.a, f) is not None}
    for r, tr in p.tracks.items():
        if tr is not None:
            arrays[f"x:{r}"], arrays[f"P:{r}"] = tr.x, tr.P
    kept = SimpleNamespace(t=p.a.t, n=p.a.n, nq=p.a.nq, file=spill.save(**arrays), n_rovers=p.a.kin_n.shape[1],
                           filtered=p.a.qf is not None, nx=p.a.q.shape[1])
    tracks = {r: None if tr is None else tr._replace(x=None, P=None) for r, tr in p.tracks.items()}
    return p._replace(a=kept, tracks=tracks)


def _joined_arrays(passes: list, hist):
    """The windows' arrays on one axis (their axes one after the other): the first window's object when alone, else
    arrays on disk (``hist``: :class:`cdgps_cli.io.scratch.DiskHistory`) filled a window at a time."""
    if len(passes) == 1:
        return passes[0].a
    first = passes[0].a
    t = np.concatenate([p.a.t for p in passes])
    a = SimpleNamespace(t=t, n=t.size, nq=first.nq)
    n, nx, nr = t.size, first.nx, first.n_rovers
    shapes = {"q": (n, nx), "P": (n, nx, nx), "qf": (n, nx), "Pf": (n, nx, nx), "kq": (n, nx), "kP": (n, nx, nx),
              "kin_n": (n, nr), "kin_pdop": (n, nr), "nis_sum": (n,), "dof_tot": (n,)}
    for f, shape in shapes.items():
        keep = first.filtered or f not in ("qf", "Pf")
        setattr(a, f, hist.empty(shape, np.int64 if f in ("kin_n", "dof_tot") else np.float64) if keep else None)
    start = 0
    for p in passes:
        with _load(p.a.file) as z:
            for f in _ARRAY_FIELDS:
                if getattr(a, f) is not None:
                    getattr(a, f)[start:start + p.a.n] = z[f]
                    hist.release(getattr(a, f), start, start + p.a.n)
        start += p.a.n
    return a


def _track_arrays(passes: list, rover: str, hist) -> tuple:
    """A rover's filtered x (about the first window's origin) and P on the joined axis: its one window's own arrays,
    or the windows' (from their scratch files) on disk."""
    tracks = [p.tracks[rover] for p in passes]
    if len(tracks) == 1:
        return tracks[0].x, tracks[0].P
    nx = max(tr.n_state for tr in tracks)         # (windows with fewer multipath states: the rest padded, 0 ± 1)
    n = sum(tr.t.size for tr in tracks)
    xf, pf = hist.empty((n, nx)), hist.empty((n, nx, nx))
    start = 0
    for p, tr in zip(passes, tracks):
        with _load(p.a.file) as z:
            x, m, sl = z[f"x:{rover}"], tr.n_state, slice(start, start + tr.t.size)
            xf[sl] = _padded_rows(x if tr.shift is None else x + _padded(tr.shift, m), nx)
            pf[sl] = _padded_rows(z[f"P:{rover}"], nx)
        for arr in (xf, pf):
            hist.release(arr, start, start + tr.t.size)
        start += tr.t.size
    return xf, pf


def _padded_rows(v: np.ndarray, n: int) -> np.ndarray:
    """Per-epoch states (N, m) or covariances (N, m, m) with states m … n−1 added, decoupled, at 0 ± 1 (a window with
    fewer multipath states than the widest, in the arrays all windows share)."""
    m = v.shape[1]
    if m == n:
        return v
    if v.ndim == 2:
        out = np.zeros((v.shape[0], n))
        out[:, :m] = v
        return out
    out = np.zeros((v.shape[0], n, n))
    out[:, :m, :m] = v
    i = np.arange(m, n)
    out[:, i, i] = 1.0
    return out


def _padded_pair(A: np.ndarray, Q: np.ndarray, n: int) -> tuple:
    """A transition (A (m, m′), Q (m, m)) on ``n`` states: the padded states (0 ± 1, :func:`_padded_rows`) are not
    carried from the previous epoch's but given afresh (Q = 1), so they stay 0 ± 1 and apart from the others."""
    Ap, Qp = np.zeros((n, n)), np.zeros((n, n))
    Ap[:A.shape[0], :A.shape[1]] = A
    Qp[:Q.shape[0], :Q.shape[0]] = Q
    i = np.arange(A.shape[0], n)
    Qp[i, i] = 1.0
    return Ap, Qp


def _joined_transitions(tracks: list) -> tuple:
    """The transitions into every epoch of the windows' tracks on one axis: each window's own, and into each later
    window's first epoch the transition over the seam its forward filter took (padded to the widest window)."""
    n = max(tr.n_state for tr in tracks)
    pairs, pair_of = [], []
    for k, tr in enumerate(tracks):
        tp, to = tr.transitions
        of = np.asarray(to, dtype=np.int64) + len(pairs)
        pairs.extend(_padded_pair(np.asarray(A, dtype=np.float64), np.asarray(Q, dtype=np.float64), n)
                     if tr.n_state < n else (A, Q) for A, Q in tp)
        if k:
            pairs.append(_padded_pair(*tr.seam, n))
            of[0] = len(pairs) - 1
        pair_of.append(of)
    return pairs, np.concatenate(pair_of)


def _rows_in_chunks(n: int):
    """Row ranges of :data:`~cdgps_cli.config.options.STATES_CHUNK_EPOCHS` epochs covering ``n``."""
    return ((i, min(i + STATES_CHUNK_EPOCHS, n)) for i in range(0, n, STATES_CHUNK_EPOCHS))


def _final_states(a, passes: list, rover: str, smooth: bool, hist):
    """A moving rover's states on the joined axis ``a``: its windows' forward tracks, smoothed over all of them when
    ``smooth`` (in the first window's origin), with their filtered states beside; returns the states x (N, nx) about
    the first window's origin (in memory, or on disk with several windows)."""
    tracks = [p.tracks[rover] for p in passes]
    first, several = tracks[0], len(tracks) > 1
    xf, pf = _track_arrays(passes, rover, hist)
    if smooth:
        if several:                 # (on disk: the smoother's passes release what they have finished)
            xs, ps = hist.empty(xf.shape), hist.empty(pf.shape)
            for i, j in _rows_in_chunks(xf.shape[0]):
                xs[i:j], ps[i:j] = xf[i:j], pf[i:j]
                for arr in (xs, ps, xf, pf):
                    hist.release(arr, i, j)
            rts_smooth_indexed(xs, ps, *_joined_transitions(tracks), chunk=STATES_CHUNK_EPOCHS,
                               on_done=lambda i, j: [hist.release(arr, i, j) for arr in (xs, ps)])
        else:
            xs, ps = rts_smooth_indexed(np.array(xf), np.array(pf), *first.transitions)
    else:
        xs, ps = xf, pf
    cols = first.cols
    k = cols.size                       # (the rover's own states: multipath states after them are not written)
    for i, j in _rows_in_chunks(a.n) if several else [(0, a.n)]:
        a.q[i:j, cols] = first.origin + xs[i:j, :k]
        a.P[i:j, cols[:, None], cols] = ps[i:j, :k, :k]
        if a.qf is not None:
            a.qf[i:j, cols] = first.origin + xf[i:j, :k]
            a.Pf[i:j, cols[:, None], cols] = pf[i:j, :k, :k]
        for arr in (a.q, a.P, a.qf, a.Pf, xs, ps, xf, pf):
            if arr is not None:
                hist.release(arr, i, j)
    return xs


def _window_dx(xs, p: "_WindowPass", start: int, rover: str) -> np.ndarray:
    """A window's (``p``, its first epoch ``start`` on the joined axis) displacement of ``rover`` from its own static
    solution at the rover's epochs, from the states ``xs`` (about the first window's origin)."""
    tr = p.tracks[rover]
    _, idx = p.residual_inputs[rover]
    x = np.asarray(xs[start:start + p.a.n, :3])[idx]
    return x if tr.shift is None else x - tr.shift[:3]


def _joined_residuals(passes: list, n: int, states: dict, hist) -> tuple:
    """The DD residual columns (rover, satellite) of every window on the joined axis of ``n`` epochs (on disk with
    several windows): each rover's satellites in the order the windows first hold them; ``states``: each moving
    rover's states on the joined axis."""
    cols, index = [], {}
    for r in passes[0].run_info.rovers:
        for p in passes:
            for s_name in p.residual_inputs[r][0].sat_names:
                if (r, s_name) not in index:
                    index[(r, s_name)] = len(cols)
                    cols.append((r, s_name))
    vals = np.full((n, len(cols)), np.nan) if len(passes) == 1 else hist.empty((n, len(cols)))
    start = 0
    for p in passes:
        block = np.full((p.a.n, len(cols)), np.nan)
        for r in p.run_info.rovers:
            ri, idx = p.residual_inputs[r]
            ri = ri.load() if isinstance(ri, _SpilledInputs) else ri
            dx = _window_dx(states[r], p, start, r) if r in states else np.zeros((ri.n_epochs, 3))
            tab = _residual_table(ri, dx)
            for s_i, s_name in enumerate(ri.sat_names):
                block[idx, index[(r, s_name)]] = tab[:, s_i]
        vals[start:start + p.a.n] = block
        for arr in (vals, *states.values()):        # (a rover's states with multipath: 33 columns, 230 MB a 10 Hz day)
            hist.release(arr, start, start + p.a.n)
        start += p.a.n
    return cols, vals


def _kinematic_series(a, hist, several: bool) -> tuple:
    """The single-epoch solutions' series: (time, positions, covariances, satellite counts, PDOP) at the epochs with
    a solution of some rover; a rover without one there has no covariance either (on disk with several windows)."""
    nq = a.nq                                   # (single-epoch solutions: positions only, no velocities)
    have = np.zeros(a.n, dtype=bool)
    for i, j in _rows_in_chunks(a.n) if several else [(0, a.n)]:
        have[i:j] = ~np.all(np.isnan(a.kq[i:j]), axis=1)
        hist.release(a.kq, i, j)
    if not several:
        kP = a.kP.copy()
        kP[np.isnan(a.kq)] = np.nan
        return a.t[have], a.kq[have][:, :nq], kP[have][:, :nq, :nq], a.kin_n[have], a.kin_pdop[have]
    m = int(have.sum())
    kq, kP = hist.empty((m, nq)), hist.empty((m, nq, nq))
    kn, kd = hist.empty((m, a.kin_n.shape[1]), np.int64), hist.empty((m, a.kin_pdop.shape[1]))
    out = 0
    for i, j in _rows_in_chunks(a.n):
        h = have[i:j]
        c = np.array(a.kP[i:j])
        c[np.isnan(a.kq[i:j])] = np.nan
        k = int(h.sum())
        kq[out:out + k], kP[out:out + k] = a.kq[i:j][h][:, :nq], c[h][:, :nq, :nq]
        kn[out:out + k], kd[out:out + k] = a.kin_n[i:j][h], a.kin_pdop[i:j][h]
        for arr in (a.kq, a.kP, a.kin_n, a.kin_pdop):
            hist.release(arr, i, j)
        for arr in (kq, kP, kn, kd):
            hist.release(arr, out, out + k)
        out += k
    return a.t[have], kq, kP, kn, kd


def _window_events(passes: list, windows: list) -> list:
    """Every window's events, and where a later window begins the INIT that serves it, in time order."""
    events = [e for p in passes for e in p.events]
    for k in range(1, len(passes)):
        src = windows[k].source or f"INIT {k + 1}"
        for r in passes[k].run_info.rovers:
            events.append({"time_s": float(passes[k].a.t[0]), "antenna": r, "transmitter": "-",
                           "kind": "next window (INIT)", "action": f"integers and static solution of {src}"
                                                                    + ("; states carried over the seam"
                                                                       if passes[k].tracks.get(r) is not None else "")})
    events.sort(key=lambda e: (e["time_s"], e["antenna"], e["transmitter"], e["kind"]))
    return events


def _joined_summary(passes: list, windows: list) -> dict:
    """The STATES metadata's rover entries: one window's as always; several windows' first entry with the totals of
    epochs and integers and every window's own entry under ``windows``."""
    if len(passes) == 1:
        return passes[0].summary_rovers
    out = {}
    for r in passes[0].run_info.rovers:
        each = [dict(p.summary_rovers[r], window=dict(zip(("start_gps_s", "end_gps_s"), p.run_info.window or (None, None))),
                     init=w.source) for p, w in zip(passes, windows)]
        tot = {k: int(sum(e[k] for e in each)) for k in ("epochs", "n_fixed", "n_estimated", "n_fixed_with_glonass",
                                                          "epochs_without_fixed_dd", "kinematic_epochs")}
        kin = [(e["kinematic_epochs"], e["kinematic_rms_m"]) for e in each if e["kinematic_rms_m"]]
        n_kin = sum(n for n, _ in kin)          # the single-epoch scatter about each window's own static solution
        rms = ({c: math.sqrt(sum(n * v[c] ** 2 for n, v in kin) / n_kin) for c in "enu"} if n_kin else None)
        out[r] = dict(each[0], **tot, kinematic_rms_m=rms, kinematic_rms_pdop_le_max_m=None, windows=each)
        for k in ("window", "init", "multipath"):        # (multipath: each window's own, under windows)
            out[r].pop(k, None)
    return out


def _windows_noise_notes(passes: list) -> list:
    """``phase_noise = "auto"`` over several windows, said once per rover: the range of the windows' factors (each
    window scales its own phase variances)."""
    out = []
    for r in passes[0].run_info.rovers:
        f = [p.summary_rovers[r]["phase_noise"]["factor"] for p in passes if "phase_noise" in p.summary_rovers[r]]
        if f:
            out.append(f"{r}: phase_noise auto, each window its own factor: the phase variances scaled by "
                       f"{min(f):.3g} … {max(f):.3g} over its {len(f)} windows (rovers.{r}.windows[].phase_noise)")
        mp = [p.summary_rovers[r]["multipath"] for p in passes if "multipath" in p.summary_rovers[r]]
        if mp:
            out.append(_windows_multipath_note(r, mp))
    return out


def _windows_multipath_note(rover: str, mp: list) -> str:
    """Multipath states over several windows, said once per rover: each window's own (fitted with ``"auto"``), the
    states of a satellite two windows hold carried over their seam."""
    on = [m for m in mp if "sigma_m" in m]
    if not on:
        return f"{rover}: multipath {mp[0]['mode']}: no multipath states in any of its {len(mp)} windows"
    sig, tau = [1e3 * m["sigma_m"] for m in on], [m["time_constant_s"] for m in on]
    return (f"{rover}: multipath {mp[0]['mode']}: Gauss-Markov phase states in {len(on)} of its {len(mp)} windows, each "
            f"window its own (sigma {min(sig):.2f} … {max(sig):.2f} mm, tau {min(tau):.3g} … {max(tau):.3g} s; "
            f"rovers.{rover}.windows[].multipath); the state of a satellite seen on both sides of a seam goes on over it")


def _write_windows(passes: list, windows: list, out_path, smooth: bool, extra_options: dict | None, say) -> dict:
    """The windows' states on one axis, smoothed over all of them, their residuals and events → STATES.mcap (with
    several windows the joined arrays are on disk, beside the output, and read back a block at a time)."""
    from cdgps_cli.io.scratch import DiskHistory  # noqa: PLC0415

    info = passes[0].run_info
    model, names = info.cfg.displacement, info.names
    several = len(passes) > 1
    hist = DiskHistory(Path(out_path).resolve().parent, out_path)
    a = _joined_arrays(passes, hist)
    if np.any(np.diff(a.t) <= 0):
        raise CdgpsError("estimate: the INITs' windows overlap (each INIT must serve its own span of the record)")
    states = {r: _final_states(a, passes, r, smooth, hist) for r in info.rovers if passes[0].tracks.get(r) is not None}
    res_cols, residual_m = _joined_residuals(passes, a.n, states, hist)
    del states
    events = _window_events(passes, windows)
    summary_rovers = _joined_summary(passes, windows)
    say(f"writing {out_path} …")
    meta_extra = {"rovers": summary_rovers,
                  "options": {**passes[0].signals, **(extra_options or {}),
                              **({"antennas": info.antennas} if info.antennas is not None else {})}}
    inits = [(w.init, w.init_text, w.source) for w in windows]
    bands = {}
    if model == "random_walk":        # (before the kinematic series is drawn out of a.kP)
        for j, r in enumerate(info.rovers):
            bands[r] = random_walk_passband_hz(info.cfg.random_walk_sigma, a.kP[:, 3 * j:3 * j + 3, 3 * j:3 * j + 3],
                                               a.t, smooth)
            hist.release(a.kP, 0, a.n)
    out = _write_gnss_states(info, inits, out_path, names, a.t, a.q, a.P, a.qf, a.Pf, _kinematic_series(a, hist, several),
                             res_cols, residual_m, np.where(a.dof_tot > 0, a.nis_sum, np.nan), a.dof_tot,
                             events, smooth and model != "static", meta_extra)
    notes = passes[0].notes if not several else _windows_noise_notes(passes)
    for r, band in bands.items():
        if band is not None:
            summary_rovers[r]["random_walk_passband_hz"] = dict(zip("enu", band))
            notes.append(_passband_note(r, info.cfg.random_walk_sigma, band, smooth))
    blind = (_blind_warnings(summary_rovers, model) if not several else
             [f"{w.source or f'window {k + 1}'}: {text}" for k, (p, w) in enumerate(zip(passes, windows))
              for text in _blind_warnings(p.summary_rovers, model)])
    out.update({"displacement_model": model, "rovers": summary_rovers, "coordinates": names, "notes": notes,
                "warnings": blind + _misfit_warnings(out.get("mean_nis_per_dof"), model)
                + ([STATIC_SMOOTH_NOTE] if smooth and model == "static" else [])})
    if several:
        out["windows"] = len(passes)
    return out


def phase_variance_factor(kinematic: dict | None) -> dict:
    """``phase_noise = "auto"``: the scale of the phase variances the data show, f = Σ eᵀPe / Σ (m − 3) over every
    single-epoch solution (``kinematic``: :func:`~cdgps_cli.estimation.baseline._single_epoch_positions`' ``sse``
    and ``dof``; e its m DD phase residuals after the epoch's own fit, P their weights under the model): the unit
    variance of an epoch-by-epoch least squares, which a moving rover does not inflate (each epoch has its own
    position), unlike the residuals of the static solution.  Fewer than :data:`PHASE_NOISE_MIN_DOF` degrees of
    freedom (or no single-epoch solution): 1, the model's.

    Returns ``{"mode": "auto", "factor", "dof", "sigma_scale"}`` (σ_scale = √f)."""
    from cdgps_cli.config.options import PHASE_NOISE_MIN_DOF  # noqa: PLC0415

    sse = np.asarray((kinematic or {}).get("sse", []), dtype=np.float64)
    dof = np.asarray((kinematic or {}).get("dof", []), dtype=np.int64)
    n = int(dof.sum())
    f = float(sse.sum() / n) if n >= PHASE_NOISE_MIN_DOF and np.isfinite(sse).all() else 1.0
    f = f if f > 0 else 1.0
    return {"mode": "auto", "factor": f, "dof": n, "sigma_scale": float(np.sqrt(f)),
            **({} if n >= PHASE_NOISE_MIN_DOF else {"not_estimated": f"{n} degrees of freedom, fewer than "
                                                                     f"{PHASE_NOISE_MIN_DOF}: the model's variances"})}


def _scale_phase_variances(w: dict, f: float) -> None:
    """The estimators' phase variances of one rover's work (``w``) times ``f``: the SD variances, the DD weight
    blocks (÷ f) and the single-epoch solutions' covariances (× f; their positions do not move).  The static
    solution's covariance stays INIT's (a record's mean is limited by errors correlated over minutes, which the
    epoch-to-epoch scatter does not measure)."""
    if f == 1.0:
        return
    w["var_ph"] = w["var_ph"] * f
    if w.get("blocks_ph") is not None:
        w["blocks_ph"] = [(rows, p / f) for rows, p in w["blocks_ph"]]
    ka = w.get("kinematic")
    if ka is not None:
        ka["cov_m2"] = ka["cov_m2"] * f


def _phase_noise_note(rover: str, v: dict) -> str:
    """What ``phase_noise = "auto"`` found for a rover, said."""
    if "not_estimated" in v:
        return f"{rover}: phase_noise auto: {v['not_estimated']}"
    return (f"{rover}: phase_noise auto: the single-epoch solutions' DD phase residuals ({v['dof']} degrees of freedom) "
            f"scatter {v['sigma_scale']:.3g} × the model's σ (variance factor {v['factor']:.3g}); the per-epoch states, "
            f"their σ and NIS use the scaled variances (the static solution's σ is INIT's)")


def random_walk_passband_hz(sigma_rw, kin_cov_m2: np.ndarray, time_s: np.ndarray, smoothed: bool):
    """The frequencies (E, N, U; Hz) up to which random-walk states follow a motion, or None without single-epoch
    solutions: the −3 dB point of the steady-state filter of a random walk of rate σ_w (m/√s) observed every T s
    with noise σ_r (m, the median single-epoch σ of the axis), |H(jω)|² = K² / (ω² + K²) with K = σ_w / (σ_r √T)
    (Kalman–Bucy, the measurement's density σ_r² T), so f = K / 2π; smoothed (the forward and backward passes),
    |H|² squared, f = 0.644 K / 2π.  Faster motion is attenuated: a 0.2 Hz vibration through σ_w 1 mm/√s against
    σ_r 5 mm at 1 Hz comes out 2.5 % of its size (a real u-blox rover given 5 mm: 0.11 mm)."""
    sd = np.sqrt(np.diagonal(np.asarray(kin_cov_m2, float), axis1=1, axis2=2))       # (n, 3)
    ok = np.all(np.isfinite(sd) & (sd > 0), axis=1)
    t = np.asarray(time_s, float)
    if ok.sum() < 2 or t.size < 2:
        return None
    step = float(np.median(np.diff(t)))
    k = np.asarray(sigma_rw, float) / (np.median(sd[ok], axis=0) * np.sqrt(step))
    return [float(x) for x in (k * (np.sqrt(np.sqrt(2.0) - 1.0) if smoothed else 1.0) / (2 * np.pi))]


def _passband_note(rover: str, sigma_rw, band, smoothed: bool) -> str:
    """What a random walk's states can show of a vibration (:func:`random_walk_passband_hz`), said with the rover."""
    sig = sorted({f"{x * 1e3:g}" for x in np.atleast_1d(sigma_rw)})
    sig = sig[0] if len(sig) == 1 else " / ".join(f"{x * 1e3:g}" for x in np.atleast_1d(sigma_rw))
    return (f"{rover}: the random walk ({sig} mm/√s) follows motion up to about {band[0]:.3g} / {band[1]:.3g} / "
            f"{band[2]:.3g} Hz (E / N / U, −3 dB, {'smoothed' if smoothed else 'filtered'}); faster motion comes out "
            f"smaller (about {'(f/f_c)⁻²' if smoothed else '(f/f_c)⁻¹'} of its size above): for vibrations raise "
            f"[gnss.displacement] sigma_m_per_sqrt_s, or read the single-epoch series (export --kinematic)")


#: ``estimate --smooth`` on the static displacement model: nothing to smooth, said rather than ignored
STATIC_SMOOTH_NOTE = ("--smooth has no effect with [gnss.displacement] model = \"static\": its states are the static "
                      "solution at every epoch (STATES metadata smoothed = false); a random_walk or constant_velocity "
                      "model is smoothed")


#: ``estimate`` warns when more than this share of a moving rover's epochs have no double difference of fixed
#: ambiguities (its states there are the model's prediction alone): the real u-blox walk of 20181009 with 4 of
#: 590 integers fixed had none at any of its 2072 epochs, and its STATES held the static solution, ± 1 m, silently
BLIND_EPOCHS_SHARE = 0.1


def _blind_warnings(rovers: dict, model: str) -> list:
    """A warning per rover (random walk, constant velocity) with no integer fixed, or whose epochs mostly carry no
    DD of fixed ambiguities."""
    out = []
    for r, v in rovers.items():
        n, m = v["epochs_without_fixed_dd"], v["epochs"]
        if model != "static" and m and not v["n_fixed_with_glonass"]:
            out.append(f"{r}: none of its {v['n_estimated']} integers is fixed: its {model} states use the double "
                       f"differences with INIT's static float ambiguities taken as exact, which a rover that moves "
                       f"does not give (its states and sigma do not hold); cdgps rtk gives a float solution that "
                       f"follows it")
        elif model != "static" and m and n > BLIND_EPOCHS_SHARE * m:
            out.append(f"{r}: {n} of its {m} epochs have no double difference of fixed ambiguities ({v['n_fixed']} of "
                       f"{v['n_estimated']} integers fixed): its {model} states there are the model's prediction "
                       f"alone, not a measurement (cdgps rtk gives a float solution at such epochs)")
    return out


def _misfit_warnings(nis_per_dof: float | None, model: str) -> list:
    """A warning when the DDs' mean NIS per degree of freedom is far above 1 (:data:`NIS_MISFIT_PER_DOF`): the
    displacement model cannot follow the rover, or the integers are wrong, and the states' σ do not hold."""
    if nis_per_dof is None or not nis_per_dof > NIS_MISFIT_PER_DOF:
        return []
    noise = {"random_walk": "sigma_m_per_sqrt_s", "constant_velocity": "accel_sigma_m_per_s_per_sqrt_s (and "
             "init's sigma_m_per_sqrt_s)"}.get(model)
    return [f"the double differences' mean NIS per degree of freedom is {nis_per_dof:.3g} (about 1 when the model "
            f"holds): the {model} displacement model "
            + (f"or its process noise ([gnss.displacement] {noise}) " if noise else "")
            + "does not follow this rover, or its integers are wrong; the states and their sigma do not hold"]


def init_window(init: dict) -> tuple | None:
    """(start_gps_s, end_gps_s) of the window an INIT was made on (``cdgps init --start/--duration``; estimate reads
    the RUN in it: :func:`~cdgps_cli.io.gnss_run.read_gnss_run` ``window``), None for a whole-record INIT."""
    w = init.get("window") if isinstance(init, dict) else None
    if w is None:
        return None
    try:
        t0, t1 = float(w["start_gps_s"]), float(w["end_gps_s"])
    except (KeyError, TypeError, ValueError):
        raise CdgpsError("INIT.json: malformed window (expected start_gps_s and end_gps_s, GPS s)") from None
    if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
        raise CdgpsError(f"INIT.json: window {t0!r} – {t1!r}: expected finite GPS seconds, its end after its start")
    return t0, t1


def _check_moving_float_init(init: dict) -> None:
    """CdgpsError for a rover of INIT with no integer fixed whose static float lay far from its code's mean (INIT's
    ``float.moving_rover``: it moves, and INIT's float is that mean and the random-walk float's arcs): estimate's
    states take INIT's ambiguities as exact, which only integers can give a moving rover — its states would sit
    where that mean is, metres from the rover, with millimetre σ."""
    for r, rov in (init.get("rovers") or {}).items():
        moving = ((rov or {}).get("float") or {}).get("moving_rover")
        if moving is None or n_fixed_with_glonass(rov):
            continue
        apart = moving.get("static_float_apart_m") if isinstance(moving, dict) else None
        where = f"lands {apart:.0f} m" if isinstance(apart, (int, float)) else "lies far"
        raise CdgpsError(f"rover {r}: INIT fixed none of its integers and the rover moves (its static float solution "
                         f"{where} from its code's mean position): estimate's states take INIT's "
                         f"ambiguities as exact, which only fixed integers give a moving rover (its states would "
                         f"follow the code's mean, metres off, with millimetre sigma); use 'cdgps rtk' (a float "
                         f"filter that follows the rover), or give init data that fix its integers (more signals or "
                         f"systems, a longer record)")


def _check_init_of_run(init: dict, run: GnssRun) -> None:
    """CdgpsError unless INIT is a GNSS INIT made from this run (its config, master and rovers) and the run was read
    in INIT's window (:func:`init_window`)."""
    if not is_gnss_init(init):
        raise CdgpsError("INIT.json is not from 'cdgps init' on a GNSS run (kind "
                         f"{init.get('kind') if isinstance(init, dict) else None!r})")
    if init.get("config_sha256") != run.cfg.sha256 or set(init.get("rovers", {})) != set(run.rovers) \
            or init.get("master") != run.master:
        raise CdgpsError(f"INIT.json was made from another run (config {init.get('config_name')!r}, master "
                         f"{init.get('master')!r}, rovers {', '.join(init.get('rovers', {}))}) than {run.path} "
                         f"(config {run.cfg.name!r}, master {run.master!r}, rovers {', '.join(run.rovers)})")
    w = init_window(init)
    have = None if run.window is None else (run.window["start_gps_s"], run.window["end_gps_s"])
    if w != have:
        from cdgps_cli.core.gps_time import gps_time_str  # noqa: PLC0415

        def text(x):
            return "the whole record" if x is None else f"the window {gps_time_str(x[0])} – {gps_time_str(x[1])}"
        raise CdgpsError(f"INIT.json was made on {text(w)} of {run.path}, which was read on {text(have)}: read the "
                         f"run in INIT's window (read_gnss_run window=)")


class _EstimateArrays:
    """One window's per-epoch arrays on its common time axis (``t``, n epochs, nq = 3 per rover): the states q
    (n, nq) and covariances P (n, nq, nq), the filtered ones qf, Pf (random walk, smoothed), the single-epoch
    (kinematic) ones kq, kP with their satellite counts and PDOP per rover, and the NIS summed over the rovers
    with its degrees of freedom (the DD residual columns: :func:`_joined_residuals`)."""

    def __init__(self, t: np.ndarray, nq: int, n_rovers: int, filtered: bool, rates: bool = False):
        self.t = t
        self.n = n = t.size
        self.nq = nq
        nx = 2 * nq if rates else nq          # the positions, then (constant velocity) their velocities
        self.q, self.P = np.full((n, nx), np.nan), np.zeros((n, nx, nx))
        self.qf = np.full((n, nx), np.nan) if filtered else None
        self.Pf = np.zeros((n, nx, nx)) if filtered else None
        self.kq, self.kP = np.full((n, nx), np.nan), np.zeros((n, nx, nx))
        self.kin_n = np.zeros((n, n_rovers), dtype=np.int64)
        self.kin_pdop = np.full((n, n_rovers), np.nan)
        self.nis_sum, self.dof_tot = np.zeros(n), np.zeros(n, dtype=np.int64)

    def kinematic(self, ka: dict | None, idx, sl: slice, j: int) -> None:
        """Rover j's single-epoch positions (``w["kinematic"]``), where it has them."""
        if ka is None:
            return
        ki = idx[ka["epoch"]]
        self.kq[ki, sl] = ka["enu_m"]
        self.kP[ki, sl, sl] = ka["cov_m2"]
        self.kin_n[ki, j] = ka["n_sat"]
        self.kin_pdop[ki, j] = ka["pdop"]


def _displacement_dynamics(dd: SatelliteDDDisplacement, model: str, cfg, multipath: tuple | None = None):
    """:func:`_dynamics_of` with the run config's process noise and prior."""
    return _dynamics_of(dd, model, cfg.random_walk_sigma, cfg.accel_sigma_m_per_s_per_sqrt_s, cfg.initial_sigma_m,
                        multipath)


def _rover_model(w: dict, ptr: np.ndarray, idx, n: int, groups, model: str, cfg, use: np.ndarray, mp: dict | None):
    """A moving rover's (measurement model, dynamics, prior) on the window's axis of ``n`` epochs (its own at
    ``idx``): the DD phases of each signal group (``groups``) on the displacement states, and with multipath states
    (``mp``: :func:`~cdgps_cli.pipeline.gnss_multipath.multipath_settings`) one Gauss–Markov state per satellite and
    group, the white variances × its ``white_factor``."""
    d = w["data"]
    states = mp is not None and "sigma_m" in mp
    if states:
        col, n_gm = state_columns(d, use, mp["time_constant_s"])
        mp["states"] = n_gm                     # (said in the rover's summary)
    var = w["var_ph"] * mp["white_factor"] if states and mp["white_factor"] != 1.0 else w["var_ph"]
    obs = []
    for u, ref in groups:
        ref_all = np.full(n, -1, dtype=np.int64)
        ref_all[idx] = ref
        obs.append(SDObservations(w["r_ph"], var, ref_all, usable=u, **(
            {"ambiguity_col": col, "wavelength_m": 1.0} if states else {})))
    dd = SatelliteDDDisplacement(ptr, d.sat, d.sat_names, w["g"], obs, n_ambiguities=n_gm if states else 0)
    meas, dyn, P0 = _displacement_dynamics(dd, model, cfg, (n_gm, mp["sigma_m"], mp["time_constant_s"]) if states
                                           else None)
    if not states:
        return meas, dyn, P0, ([], [])
    return meas, dyn, P0, column_occupants(d, col, n_gm)


class _RoverTrack(NamedTuple):
    """A moving rover's forward filter over one window: its columns in the states (its own: positions, velocities),
    the window's origin (its static solution; zero velocities), the origin's offset from the first window's (None in
    the first window), the filtered x (N, n_state) about the window's origin and P (its own states, then its
    multipath states), the transitions into each epoch, the axis and dynamics, the number of states, the (signal,
    satellite) each multipath state holds first and last, and the transition (A, Q) over the seam into its first
    epoch (None in the first window; A rectangular when the windows' state counts differ)."""

    cols: np.ndarray
    origin: np.ndarray
    shift: np.ndarray | None
    x: np.ndarray
    P: np.ndarray
    transitions: tuple
    t: np.ndarray
    dyn: object
    n_state: int
    holds: tuple = ([], [])
    seam: tuple | None = None

    def in_frame(self) -> np.ndarray:
        """x about the first window's origin (the frame every window's states are smoothed in)."""
        return self.x if self.shift is None else self.x + _padded(self.shift, self.x.shape[1])

    def last(self) -> tuple:
        """(time, x about the first window's origin, P, the rover's own state count, the (signal, satellite) each
        multipath state holds last) of the last epoch: the next window's start."""
        return float(self.t[-1]), self.in_frame()[-1], self.P[-1], self.cols.size, self.holds[1]


def _padded(v: np.ndarray, n: int) -> np.ndarray:
    """``v`` with zeros after it to length ``n`` (an offset of the rover's own states, none of its multipath states)."""
    out = np.zeros(n)
    out[:v.size] = v
    return out


def _prior_from(carried: tuple | None, t0: float, dyn, P0: np.ndarray, shift: np.ndarray | None,
                holds_first: list = ()) -> tuple:
    """The prior (x about this window's origin, P) at its first epoch ``t0`` and the transition (A, Q) over the seam
    (None for the first window): x = 0 ± P0 for the first window; else the previous window's last state
    (``carried``, about the first window's origin) predicted over the seam
    (:func:`~cdgps_cli.pipeline.gnss_multipath.seam_transition`: a multipath state of a satellite both windows hold
    goes on, ``holds_first`` naming this window's)."""
    if carried is None:
        return np.zeros(P0.shape[0]), P0, None
    t_last, x_last, P_last, n_dyn, holds_last = carried
    A, Q = seam_transition(dyn, n_dyn, list(holds_last), list(holds_first), x_last.size, float(t0 - t_last))
    x = A @ x_last
    return (x if shift is None else x - _padded(shift, x.size)), A @ P_last @ A.T + Q, (A, Q)


def _rover_forward(a: _EstimateArrays, w: dict, sl: slice, idx, model: str, cfg, res: dict, carried, frame):
    """One rover's forward pass over a window into ``a`` (columns ``sl``; its own epochs at ``idx``, the other
    rovers' epochs predicted): the static model's states (the static solution at every epoch) or the moving models'
    forward filter from ``carried`` (:func:`_prior_from`; ``frame``: the first window's static solution).  Its NIS
    and degrees of freedom are added at its own epochs.  Returns its track (None: static), the signal groups
    (usable rows, references) and how many of its epochs have no DD of known ambiguities."""
    d, x_fin = w["data"], w["x_final"]
    known = w["known_seg"] | w.get("glonass_known", False)      # (a glonass_fix solution's GLONASS DDs too)
    fixed_any = n_fixed_with_glonass(res["ambiguities"]) > 0
    use = known[w["seg"]] if fixed_any else np.ones(w["seg"].size, dtype=bool)
    c, dof, has, groups, blocks = _epoch_information(w, use)
    mp = None if model == "static" else multipath_settings(cfg, w, blocks, _data_factor(cfg, w))
    del blocks
    w.pop("blocks_ph", None)            # the solver's phase weights, no longer needed (a day at 1 Hz: ≈ 60 MiB)
    track = None
    if model == "static":
        a.q[:, sl] = x_fin
        a.P[:, sl, sl] = w["q_final"]
        nis = np.where(has, c, np.nan)
    else:
        ptr = _pointers_on_axis(d.ptr, idx, a.n)
        meas, dyn, P0, holds = _rover_model(w, ptr, idx, a.n, groups, model, cfg, use, mp)
        nx = 6 if model == "constant_velocity" else 3          # (the rover's own states; multipath states after)
        cols = np.r_[np.arange(sl.start, sl.stop), a.nq + np.arange(sl.start, sl.stop)][:nx]
        origin = np.r_[x_fin, np.zeros(nx - 3)]               # (the velocities' origin: 0)
        shift = None if carried is None else np.r_[x_fin - frame, np.zeros(nx - 3)]
        x0, p0, seam = _prior_from(carried, float(a.t[0]), dyn, P0, shift, holds[0])
        fr = _forward(meas, dyn, a.t, x0, p0)
        track = _RoverTrack(cols, origin, shift, fr["x"], fr["P"], fr["transitions"], a.t, dyn, P0.shape[0], holds, seam)
        nis = fr["nis"][idx]
    a.dof_tot[idx] += np.where(has, dof, 0)
    a.nis_sum[idx] += np.where(has, np.nan_to_num(nis), 0.0)
    return track, groups, int(np.sum(~has)), mp


def _data_factor(cfg, w: dict) -> float:
    """The scale of the phase variances the data show that ``w["var_ph"]`` does not hold yet: 1 when ``phase_noise =
    "auto"`` scaled them, else the single-epoch solutions' unit variance (:func:`phase_variance_factor`) for
    ``multipath = "auto"`` to split."""
    if cfg.multipath != "auto" or cfg.phase_noise == "auto":
        return 1.0
    return phase_variance_factor(w.get("kinematic"))["factor"]


def _residual_inputs(w: dict, groups) -> SimpleNamespace:
    """What a rover's DD residual columns need once its states are final (:func:`_residual_table`)."""
    d = w["data"]
    return SimpleNamespace(epoch=d.epoch, n_epochs=int(d.t_label.size), sat=d.sat, sat_names=list(d.sat_names),
                           r_ph=w["r_ph"], g=w["g"], groups=groups)


class _SpilledInputs:
    """:func:`_residual_inputs` kept in a scratch file until the residual pass (several windows: the rows of one
    window at a time in memory); ``sat_names`` stays at hand, :meth:`load` gives the inputs back."""

    def __init__(self, ri: SimpleNamespace, scratch: "_Scratch"):
        self.sat_names, self.n_epochs, self.n_groups = ri.sat_names, ri.n_epochs, len(ri.groups)
        arrays = {"epoch": ri.epoch, "sat": ri.sat, "r_ph": ri.r_ph, "g": ri.g}
        for k, (u, ref) in enumerate(ri.groups):
            arrays[f"usable_{k}"], arrays[f"ref_{k}"] = u, ref
        self.file = scratch.save(**arrays)

    def load(self) -> SimpleNamespace:
        with _load(self.file) as z:
            groups = [(z[f"usable_{k}"], z[f"ref_{k}"]) for k in range(self.n_groups)]
            return SimpleNamespace(epoch=z["epoch"], n_epochs=self.n_epochs, sat=z["sat"], sat_names=self.sat_names,
                                   r_ph=z["r_ph"], g=z["g"], groups=groups)


def _residual_table(ri: SimpleNamespace, dx: np.ndarray) -> np.ndarray:
    """A rover's DD residuals (m) of the reported estimate (``dx`` (its epochs, 3) from its window's static solution)
    per epoch and satellite (``ri``: :func:`_residual_inputs`), each group's DDs against its own reference."""
    e = ri.r_ph - np.einsum("ic,ic->i", ri.g, dx[ri.epoch])
    tab = np.full((ri.n_epochs, len(ri.sat_names)), np.nan)
    for u, ref in ri.groups:
        ref_row = ref[ri.epoch]
        ok = u & (ref_row >= 0) & (np.arange(e.size) != ref_row)
        tab[ri.epoch[ok], ri.sat[ok]] = (e - e[np.maximum(ref_row, 0)])[ok]
    return tab


def _pointers_on_axis(ptr, idx, n: int) -> np.ndarray:
    """Epoch pointers (n + 1,) of a rover's rows (its pointers ``ptr``) on a common axis of ``n`` epochs, its own
    epochs at ``idx`` (increasing): an axis epoch it lacks holds no rows."""
    return np.asarray(ptr, dtype=np.int64)[np.searchsorted(idx, np.arange(n + 1), side="left")]


def _rover_summary(res: dict, w: dict, names: list) -> dict:
    """The STATES metadata's entry of one rover (``names``: its three coordinate names)."""
    kin = res["kinematic"]
    return {
        "solution": res["solution"], "n_fixed": res["ambiguities"]["n_fixed"],
        "n_estimated": res["ambiguities"]["n_estimated"],
        "static_enu_m": dict(zip(names, w["x_final"].tolist())),
        "static_sigma_m": dict(zip(names, np.sqrt(np.diag(w["q_final"])).tolist())),
        "kinematic_rms_m": kin["rms_about_static_m"] if kin else None,
        "kinematic_rms_pdop_le_max_m": (kin.get("pdop_le_max") or {}).get("rms_about_static_m") if kin else None,
        "kinematic_epochs": kin["n_epochs"] if kin else 0,
        "dd_phase_rms_m": res["residuals"]["dd_phase_rms_m"],
        "reference_changes": res["epochs"]["n_reference_changes"],
    }


def _events(rover: str, master: str, res: dict, w: dict) -> list:
    """Slips (LLI, half-cycle, lock-time restarts), gaps, resets, reference changes, float ambiguities."""
    d = w["data"]
    seg, segtab = w["seg"], w["segtab"]
    segs = res["ambiguities"]["segments"]
    ev = []
    _, first_idx = np.unique(seg, return_index=True)          # rows are in epoch order
    first_row = dict(zip(np.unique(seg).tolist(), first_idx.tolist()))
    reset = set(d.reset_epochs.tolist())
    seen_sat = set()
    order = np.lexsort((segtab["first_epoch"], segtab["sat"]))
    for k in order:
        k = int(k)
        s_name = d.sat_names[int(segtab["sat"][k])]
        t0 = float(d.t_label[segtab["first_epoch"][k]])
        info = segs[k]
        by_engine = bool(info.get("fixed_by_engine"))          # a GLONASS DD the engine fixed (glonass_fix)
        fix_txt = ("datum (pivot)" if info["pivot"] else
                   (f"fixed to {info['integer']}" if info["fixed"] else
                    f"GLONASS DD fixed to {info.get('dd_integer_cycles')} against {info.get('reference')}"
                    if by_engine else "float (not fixed)"))
        if s_name in seen_sat:
            i0 = first_row[k]
            if d.slip_rover[i0] or d.slip_base[i0]:
                who = rover if d.slip_rover[i0] else master
                if d.slip_rover[i0] and d.slip_base[i0]:
                    who = f"{rover}+{master}"
                kind = "slip (LLI bit 0 / lock-time restart)"
            elif d.slip[i0]:
                who, kind = f"{rover}/{master}", "slip no receiver flagged (init: the phases' epoch-to-epoch change)"
            elif int(segtab["first_epoch"][k]) in reset:
                who, kind = rover, "receiver reset (epoch flag 1)"
            else:
                who, kind = rover, "tracking gap / below mask"
            ev.append({"time_s": t0, "antenna": who, "transmitter": s_name, "kind": kind,
                       "action": f"new ambiguity, {fix_txt}"})
        elif by_engine:
            ev.append({"time_s": t0, "antenna": rover, "transmitter": s_name, "kind": "GLONASS DD fixed (glonass_fix)",
                       "action": f"{fix_txt} in the static solution; no per-epoch DD"})
        elif not (info["fixed"] or info["pivot"]):
            glo = "reason" in info                 # GLONASS (FDMA): float unless glonass_fix
            ev.append({"time_s": t0, "antenna": rover, "transmitter": s_name,
                       "kind": "GLONASS (FDMA) float bias" if glo else "ambiguity not fixed",
                       "action": "float bias (m) in the static solution; no per-epoch DD" if glo
                       else "float ambiguity (phase used, integer unknown)"})
        seen_sat.add(s_name)
        if info["half_cycle_flag"]:
            ev.append({"time_s": t0, "antenna": rover, "transmitter": s_name, "kind": "half-cycle unresolved (LLI bit 1)",
                       "action": "ambiguity kept float"})
    for ref in w.get("refs_ph", [w["ref_ph"]]):      # one reference per signal group
        ok = np.flatnonzero(ref >= 0)
        if not ok.size:
            continue
        rs = d.sat[ref[ok]]
        ch = np.flatnonzero(np.r_[True, rs[1:] != rs[:-1]])
        for i in ch:
            e = ok[i]
            ev.append({"time_s": float(d.t_label[e]), "antenna": rover, "transmitter": d.sat_names[int(rs[i])],
                       "kind": "reference satellite" if i == 0 else "reference change",
                       "action": f"DDs against {d.sat_names[int(rs[i])]}"})
    return ev


# ----------------------------------------------------------------------------------------------
# STATES.mcap


def _raised_walks_of(inits: list) -> dict:
    """:func:`_raised_walks` of every INIT (each window's rovers whose float walk was raised; the last window's σ where
    several raised one rover's)."""
    used = {}
    for one, _, _ in inits:
        used.update(_raised_walks(one).get("init_random_walk_sigma_used_m_per_sqrt_s", {}))
    return {"init_random_walk_sigma_used_m_per_sqrt_s": used} if used else {}


def _raised_walks(init: dict) -> dict:
    """``{"init_random_walk_sigma_used_m_per_sqrt_s": {rover: σ (3,)}}`` for the rovers whose random-walk float
    ``init`` solved at a σ raised above the config's (INIT's float ``random_walk_sigma_used_m_per_sqrt_s``), else {}:
    STATES say that their integers came from another walk than the one they were filtered with."""
    used = {r: v["float"]["random_walk_sigma_used_m_per_sqrt_s"] for r, v in (init.get("rovers") or {}).items()
            if (v.get("float") or {}).get("random_walk_sigma_used_m_per_sqrt_s") is not None}
    return {"init_random_walk_sigma_used_m_per_sqrt_s": used} if used else {}


def _write_gnss_states(run, inits: list, out_path, names, t, q, P, qf, Pf, kinematic: tuple,
                       res_cols, residual_m, nis, nis_dof, events, smoothed, meta_extra) -> dict:
    """The displacement states as a :class:`~cdgps_cli.core.records.StateSeries` (x = q, C = I)
    through the one STATES writer :func:`cdgps_cli.io.states.write_states`; the single-epoch
    solutions as the arrays-only series ``/cdgps/kinematic`` (with ``n_sat`` and ``pdop``).  ``inits``: the
    (INIT, its text, its source) of each window; the first is the INIT of the metadata's provenance and of
    ``init.json``, and several are listed in :data:`INIT_WINDOWS_ATTACHMENT` (their texts too)."""
    model = run.cfg.displacement
    init, init_text = inits[0][0], inits[0][1]
    biases = []
    for one, _, _ in inits:
        for r in run.rovers:
            for s in rover_segments(one, r):
                if s["fixed"] and s["integer"] is not None:
                    lam = s.get("wavelength_m", GPS_L1_WAVELENGTH_M)
                    biases.append({"antenna": r, "transmitter": s["sat"], "bias_m": lam * s["integer"],
                                   "from_gps_s": s["first_gps_s"]})
    meta = {"cdgps_version": __version__, "created_by": "cdgps estimate", "kind": "gnss", "config_name": run.cfg.name,
            "config_sha256": run.cfg.sha256, **states_io.provenance(run.path, init_text),
            "options": json.dumps({"smooth": bool(smoothed), "displacement_model": model,
                                   "random_walk_sigma_m_per_sqrt_s": list(run.cfg.random_walk_sigma) if model == "random_walk" else None,
                                   **({"accel_sigma_m_per_s_per_sqrt_s": run.cfg.accel_sigma_m_per_s_per_sqrt_s,
                                       "init_random_walk_sigma_m_per_sqrt_s": list(run.cfg.random_walk_sigma)}
                                      if model == "constant_velocity" else {}),
                                   **_raised_walks_of(inits),
                                   **meta_extra.get("options", {})},
                                  sort_keys=True),
            "final_biases": json.dumps(biases), "smoothed": str(bool(smoothed)).lower(), "displacement_model": model,
            "coordinates": ",".join(names), "master": run.master,
            "rovers": json.dumps(json_safe(meta_extra["rovers"]), sort_keys=True)}
    series = {STATE_TOPIC: Series(t, q, P, bool(smoothed))}
    if qf is not None:
        series[STATE_FILTERED_TOPIC] = Series(t, qf, Pf, False)
    kt, kq, kP, kin_n, kin_pdop = kinematic      # (:func:`_kinematic_series`)
    series[KINEMATIC_TOPIC] = Series(kt, kq, kP, False, {"n_sat": kin_n, "pdop": kin_pdop}, messages=False)
    ss = StateSeries("displacement", list(names), ["m"] * len(names), np.eye(len(names)), q.shape[1] - len(names),
                     series, list(res_cols), residual_m, nis, nis_dof, events, GPS_L1_WAVELENGTH_M)
    attachments = {GNSS_CONFIG_ATTACHMENT: (run.cfg.text.encode(), "application/toml"),
                   INIT_ATTACHMENT: (init_text.encode(), "application/json")}
    if len(inits) > 1:
        listed = [{"init": src, "window": one.get("window"), "init_sha256": hashlib.sha256(text.encode()).hexdigest(),
                   "text": text} for one, text, src in inits]
        attachments[INIT_WINDOWS_ATTACHMENT] = (json.dumps(listed, sort_keys=True).encode(), "application/json")
        meta["init_windows"] = json.dumps([{k: v for k, v in e.items() if k != "text"} for e in listed], sort_keys=True)
    # Foxglove channels at every epoch of a record at 1 Hz or slower; a faster one (a 10 Hz day: 864,000 epochs, whose
    # JSON messages took 390 MiB more to write) at the preview's rate, low-pass filtered before decimation
    from cdgps_cli.analysis.preview import anti_alias_decimate  # noqa: PLC0415
    from cdgps_cli.io.states_layout import DEFAULT_PREVIEW_RATE_HZ  # noqa: PLC0415
    from cdgps_cli.pipeline.estimate_outputs import nis_bounds95  # noqa: PLC0415

    out = states_io.write_states(ss, out_path, meta, attachments, time_scale="gps", preview_rate_hz=DEFAULT_PREVIEW_RATE_HZ,
                                 preview=anti_alias_decimate, nis_bounds=nis_bounds95)
    out.update({"start": gps_time_str(float(t[0])), "end": gps_time_str(float(t[-1])),
                "kinematic_epochs": int(kt.size)})
    return out


def is_gnss_states(path: str | Path) -> bool:
    c = read_mcap(path, topics=[])
    return c.metadata.get(ESTIMATE_METADATA, {}).get("kind") == "gnss"


def export_kinematic_csv(states_path: str | Path, out_csv: str | Path) -> dict:
    """The single-epoch (kinematic) solutions of a GNSS STATES.mcap as CSV: time_s, coordinates,
    sigma_<name>, named with their units as ``cdgps export``'s (``rover_e_m``, ``sigma_rover_e_m``;
    :mod:`cdgps_cli.io.coordinate_columns`), then n_sat_<rover> (the satellite signals used: one per satellite and
    signal) and pdop_<rover> (a ratio)."""
    from cdgps_cli.io.coordinate_columns import column_unit, coordinate_column, sigma_column  # noqa: PLC0415

    if not is_gnss_states(states_path):
        raise CdgpsError(f"{states_path}: --kinematic needs a STATES.mcap from 'cdgps estimate' on a GNSS run")
    st = States(states_path, topic=KINEMATIC_TOPIC, diagnostics=False)
    names = list(st.coord_names)
    units = [column_unit(st.coordinate_model(), n) for n in names]
    df = pd.DataFrame(st.q, columns=[coordinate_column(n, u) for n, u in zip(names, units)])
    for i, (nm, u) in enumerate(zip(names, units)):
        df[sigma_column(nm, u)] = st.sigma_q[:, i]
    rovers = list(dict.fromkeys(n.rsplit("_", 1)[0] for n in names))
    try:
        ns, pd_ = st.extra["n_sat"], st.extra["pdop"]
    except KeyError as exc:
        raise CdgpsError(f"{states_path}: damaged kinematic arrays: no {exc}") from None
    for j, r in enumerate(rovers):
        df[f"n_sat_{r}"] = ns[:, j].astype(int)
        df[f"pdop_{r}"] = pd_[:, j]
    df.insert(0, "time_s", np.round(st.time_s, 9))
    out = Path(out_csv)
    write_atomic(out, lambda p: df.to_csv(p, index=False, lineterminator="\n"))
    return {"output": str(out), "rows": int(len(df)), "columns": list(df.columns)}
