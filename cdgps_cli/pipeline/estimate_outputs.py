"""What is done with a structure estimate: written to STATES.mcap, exported as CSV, evaluated.

* :func:`write_states` — the ``cdgps estimate`` output: :func:`cdgps_cli.io.states.write_states`
  with the structure's section angles (:func:`cdgps_cli.model.kinematics.section_angles`) for the
  ``/cdgps/angles_deg`` channel;
* :func:`export_csv` — ``cdgps export``: coordinates, their 1-σ and, on request, displacements of
  named points (:mod:`cdgps_cli.model.points`; a structure's STATES only);
* :func:`evaluate` — ``cdgps evaluate``: RMS error, NEES, NIS and bias errors against simulator truth
  (any kind of STATES: NEES on the positions ξ through the output map).

The file formats are in :mod:`cdgps_cli.io.states` (which imports no numerics); this module is the
stage layer that joins them with the model.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cdgps_cli import __version__
from cdgps_cli.config.options import SCENE_AUTO_FRACTION, SCENE_EXAGGERATION, SCENE_EXAGGERATION_MAX
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.records import Series, StateSeries
from cdgps_cli.io import states as states_io
from cdgps_cli.io.atomic import write_atomic
from cdgps_cli.io.coordinate_columns import column_unit, coordinate_column, sigma_column
from cdgps_cli.io.mcap import CONFIG_ATTACHMENT
from cdgps_cli.io.sim_truth import check_truth_config, read_truth_folder, truth_coordinates
from cdgps_cli.io.states import ESTIMATE_METADATA, INIT_ATTACHMENT, STATE_FILTERED_TOPIC, STATE_TOPIC
from cdgps_cli.io.states_layout import DEFAULT_COVARIANCE, DEFAULT_PREVIEW_RATE_HZ

__all__ = ["structure_series", "write_states", "scene_for", "nis_bounds95", "export_csv", "evaluate"]


def structure_series(res) -> StateSeries:
    """The :class:`~cdgps_cli.core.records.StateSeries` of a structure estimate ``res``
    (:class:`cdgps_cli.estimation.filter.EstimateResult` or the same fields): q = U ξ, x = [ξ, ξ̇, …],
    the smoother's and the forward filter's series when smoothed."""
    cfg = res.cfg
    series = {STATE_TOPIC: Series(res.time_s, res.x, res.P, bool(res.smoothed))}
    if res.smoothed:
        series[STATE_FILTERED_TOPIC] = Series(res.time_s, res.x_filt, res.P_filt, False)
    names = list(cfg.coord_names)
    return StateSeries("structure", names, [cfg.coord_unit(n) for n in names], np.asarray(cfg.mode_shapes, dtype=float),
                       cfg.n_modes, series, list(res.channels), res.residual_m, res.nis, res.nis_dof, res.events,
                       cfg.wavelength_m)


def write_states(res, run_path: str | Path, init: dict, init_text: str, out_path: str | Path, options: dict,
                 covariance: str = DEFAULT_COVARIANCE, preview_rate_hz: float | None = None,
                 run_sha256: str | None = None, scene_exaggeration: float | str = SCENE_EXAGGERATION,
                 satellites=None) -> dict:
    """Write the structure estimate ``res`` to STATES.mcap atomically; returns the writer's summary.

    Parameters
    ----------
    res
        The estimate (:class:`cdgps_cli.estimation.filter.EstimateResult` or the same fields).
    run_path, init, init_text, options
        Provenance recorded in the ``cdgps.estimate`` metadata.
    out_path : path
    covariance, preview_rate_hz
        As :func:`cdgps_cli.io.states.write_states`; the section angles of ``res.cfg``
        (:func:`cdgps_cli.model.kinematics.section_angles`) make its ``/cdgps/angles_deg`` channel.
        The preview's motion is low-pass filtered before decimation
        (:func:`cdgps_cli.analysis.preview.anti_alias_decimate`); ``preview_rate_hz`` None: the rate
        from the config's highest mode (:func:`preview_rate_hz_for`).
    run_sha256 : str, optional
        The RUN's sha256 when the caller has it (``cdgps estimate`` hashed the RUN to check the
        INIT pairing); else the RUN is hashed here.
    scene_exaggeration : float or "auto"
        Factor on the deformation drawn in the 3-D scene channel (:func:`scene_for`); 0: no scene.
    satellites : SatelliteSky, optional
        A GNSS run's satellite directions, drawn as arrows in the scene
        (:class:`cdgps_cli.analysis.scene.SatelliteSky`).
    """
    from cdgps_cli.model.kinematics import section_angles  # noqa: PLC0415
    from cdgps_cli.io.run import run_kind  # noqa: PLC0415 (a structure estimated on a GNSS run: GPS time)

    cfg = res.cfg
    meta = {"cdgps_version": __version__, "created_by": "cdgps estimate", "config_name": cfg.name,
            "config_sha256": cfg.sha256, **states_io.provenance(run_path, init_text, run_sha256),
            "options": json.dumps(options, sort_keys=True),
            "measurement_noise": json.dumps(getattr(res, "noise", {}) or {}, sort_keys=True),
            "final_biases": json.dumps([{"antenna": a, "transmitter": t, "bias_m": b}
                                        for (a, t), b in res.biases.items()]),
            "smoothed": str(res.smoothed).lower(),
            # where the filter ran in static mode (report static says when its segment did not)
            "rest_active_s": json.dumps(getattr(res, "rest_active_s", [])),
            "rest_detection": json.dumps(getattr(res, "rest_detection", None))}
    window = getattr(res, "window", None)
    if window:
        # epochs start_s … end_s come from INIT's batch solution (not from the filter)
        meta["window"] = json.dumps(window, sort_keys=True)
    attachments = {CONFIG_ATTACHMENT: (cfg.text.encode(), "application/toml"),
                   INIT_ATTACHMENT: (init_text.encode(), "application/json")}
    from cdgps_cli.analysis.preview import anti_alias_decimate  # noqa: PLC0415

    if preview_rate_hz is None:
        preview_rate_hz = preview_rate_hz_for(cfg, res.time_s)
    ss = structure_series(res)
    gnss = run_kind(run_path) == "gnss"             # the config's transmitters stand for satellites: not drawn
    scene = scene_for(cfg, ss, preview_rate_hz, scene_exaggeration, transmitters=not gnss, satellites=satellites)
    out = states_io.write_states(ss, out_path, meta, attachments, time_scale="gps" if gnss else "relative",
                                 covariance=covariance, preview_rate_hz=preview_rate_hz, angles=section_angles(cfg),
                                 preview=anti_alias_decimate, scene=scene, nis_bounds=nis_bounds95)
    out["window"] = window or None
    out["scene_exaggeration"] = scene.exaggeration if scene is not None else 0.0
    return out


def nis_bounds95(dof):
    """Two-sided 95 % chi-square interval of the NIS per epoch: (2.5 %, 97.5 %) points for ``dof``
    (NaN where dof ≤ 0); written beside the NIS in STATES.mcap's residual messages."""
    from cdgps_cli.estimation.chi2 import chi2_quantile  # noqa: PLC0415

    d = np.asarray(dof, dtype=float)
    return np.atleast_1d(chi2_quantile(0.025, d)), np.atleast_1d(chi2_quantile(0.975, d))


def scene_for(cfg, ss: StateSeries, preview_rate_hz: float, exaggeration: float | str, transmitters: bool = True,
              satellites=None):
    """The 3-D scene of a structure estimate (:class:`cdgps_cli.analysis.scene.StructureScene`),
    or None when ``exaggeration`` is 0; ``transmitters``: draw the config's transmitters (not on a
    GNSS run, where ``satellites``, a :class:`~cdgps_cli.analysis.scene.SatelliteSky`, replace them).

    ``"auto"``: :func:`cdgps_cli.analysis.scene.auto_exaggeration` on the estimate at the preview
    epochs (:data:`SCENE_AUTO_FRACTION` of the structure's size)."""
    from cdgps_cli.analysis.scene import StructureScene, auto_exaggeration, scene_geometry  # noqa: PLC0415

    if isinstance(exaggeration, str):
        if exaggeration.strip().lower() != "auto":
            raise CdgpsError(f"--scene-exaggeration {exaggeration!r}: expected a factor >= 0 or 'auto'")
        est = ss.series[STATE_TOPIC]
        stride = states_io.preview_stride(np.asarray(est.time_s, dtype=float), preview_rate_hz)
        q = states_io.series_q(ss.output_map, est.x[::stride, :ss.n_pos])
        exaggeration = auto_exaggeration(cfg, scene_geometry(cfg), q, SCENE_AUTO_FRACTION)
    exaggeration = float(exaggeration)
    if not 0 <= exaggeration <= SCENE_EXAGGERATION_MAX:
        raise CdgpsError(f"--scene-exaggeration {exaggeration:g}: expected a factor in [0, {SCENE_EXAGGERATION_MAX:g}] "
                         "(0: no 3-D scene) or 'auto'")
    return StructureScene(cfg, exaggeration, transmitters=transmitters, satellites=satellites) if exaggeration > 0 else None


def preview_rate_hz_for(cfg, time_s) -> float:
    """Foxglove preview rate, Hz, for a structure: at least :data:`DEFAULT_PREVIEW_RATE_HZ`, and high
    enough that the config's highest mode lies in the preview filter's passband
    (:func:`cdgps_cli.analysis.preview.preview_stride_for_modes`): an epoch rate divided by a whole stride."""
    from cdgps_cli.analysis.preview import preview_stride_for_modes  # noqa: PLC0415

    t = np.asarray(time_s, dtype=float)
    period_s = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    if not period_s > 0:
        return DEFAULT_PREVIEW_RATE_HZ
    default = states_io.preview_stride(t, DEFAULT_PREVIEW_RATE_HZ)
    return 1.0 / (period_s * preview_stride_for_modes(period_s, cfg.mode_frequency_hz, default))


def export_csv(states_path: str | Path, out_csv: str | Path, points: str | None = None) -> dict:
    """Write time_s, one column per coordinate ``<name>_<unit>`` and ``sigma_<name>_<unit>`` for each
    (:mod:`cdgps_cli.io.coordinate_columns`; lines up with truth.csv); a constant-velocity GNSS displacement's
    velocities follow, ``<rover>_ve_m_s`` … and ``sigma_<rover>_ve_m_s`` … (m/s).

    ``points`` (e.g. ``"antennas"``, ``"all"``, ``"a120,top"``; see
    :func:`cdgps_cli.model.points.select_points`) adds the lab-frame displacement of those points and its
    1-σ from J U P_ξ Uᵀ Jᵀ: columns ``<point>_d{x,y,z}_m`` and ``sigma_<point>_d{x,y,z}_m``.
    """
    from cdgps_cli.config.options import STATES_CHUNK_EPOCHS  # noqa: PLC0415
    from cdgps_cli.io.states import StatesChunks  # noqa: PLC0415

    with StatesChunks(states_path, covariance=True) as st:          # a chunk of epochs at a time (issue 29)
        names = list(st.coord_names)
        bad, first_bad = 0, None
        for ch in st.series(STATES_CHUNK_EPOCHS):                    # first: a bad record writes nothing
            nonfinite = ~np.isfinite(ch["q"]).all(axis=1) | ~np.isfinite(ch["sigma_q"]).all(axis=1)
            if nonfinite.any() and first_bad is None:
                first_bad = float(ch["time_s"][np.flatnonzero(nonfinite)[0]])
            bad += int(nonfinite.sum())
        if bad:
            raise CdgpsError(f"{states_path}: {bad} of {st.n_epochs} epoch(s) with non-finite states or sigmas "
                             f"(first at {first_bad:g} s); nothing written")
        pts = None
        if points is not None:
            from cdgps_cli.model.points import select_points

            pts = select_points(st.require_structure("--points"), points)      # before writing: a bad name leaves no file
        out = Path(out_csv)
        written = {"rows": 0, "columns": None}

        def write(p):
            with open(p, "w", newline="") as fh:
                for ch in st.series(STATES_CHUNK_EPOCHS):
                    df = _export_frame(st, names, pts, ch)
                    df.to_csv(fh, index=False, header=written["rows"] == 0, lineterminator="\n")
                    written["rows"] += len(df)
                    written["columns"] = list(df.columns)

        write_atomic(out, write)
    return {"output": str(out), "rows": int(written["rows"]), "columns": written["columns"],
            "points": list(pts.names) if pts is not None else []}


def _export_frame(st, names: list, pts, ch: dict):
    """The CSV rows of one chunk of epochs (as the whole-record export made them)."""
    import pandas as pd  # noqa: PLC0415 (not on the path of `cdgps estimate`)

    model = st.coordinate_model()
    units = [column_unit(model, n) for n in names]
    df = pd.DataFrame(ch["q"], columns=[coordinate_column(n, u) for n, u in zip(names, units)])
    for i, (n, u) in enumerate(zip(names, units)):
        df[sigma_column(n, u)] = ch["sigma_q"][:, i]
    if ch.get("xidot") is not None:              # a constant-velocity displacement's velocities, m/s
        from cdgps_cli.io.coordinate_columns import velocity_name  # noqa: PLC0415
        for i, n in enumerate(names):
            df[coordinate_column(velocity_name(n), "m_s")] = ch["xidot"][:, i]
        for i, n in enumerate(names):
            df[sigma_column(velocity_name(n), "m_s")] = ch["sigma_xidot"][:, i]
    if pts is not None:
        from cdgps_cli.model.points import point_columns  # noqa: PLC0415

        df = pd.concat([df, pd.DataFrame(point_columns(st.cfg, pts, ch["xi"], ch["P_xi"]))], axis=1)
    df.insert(0, "time_s", np.round(ch["time_s"], 9))
    return df


def evaluate(truth_dir: str | Path, states_path: str | Path, converge_s: float = 1.0) -> dict:
    """Compare a STATES.mcap with simulator truth (truth.csv, truth.json).

    Returns RMS error per coordinate (after ``converge_s`` from the first estimate), NEES on the
    modal positions with its chi-square 95% interval, NIS statistics, convergence time and bias errors.
    """
    from scipy.stats import chi2

    from cdgps_cli.core.checks import require_finite

    require_finite(converge_s, "converge_s", nonnegative=True)
    sim = read_truth_folder(truth_dir, "--truth")
    tj = sim.info
    from cdgps_cli.io.states import StatesChunks, diagnostics  # noqa: PLC0415

    with StatesChunks(states_path, covariance=True) as st:         # a chunk of epochs at a time (issue 29)
        names = list(st.coord_names)
        check_truth_config(sim, st.config_sha256, st.config_name, states_path)    # first: it explains missing columns
        truth = truth_coordinates(sim, st.coordinate_model(), names)    # q1_rad, or a bare q1 (older files)
        del sim
        nis_all, dof_all, events = diagnostics(states_path, st.n_epochs)
        tt = np.rint(truth["time_s"].to_numpy() * 1e6).astype(np.int64)
        te = np.rint(np.concatenate([c["time_s"] for c in st.series(_EVAL_CHUNK)] or [np.empty(0)]) * 1e6).astype(np.int64)
        common, it, ie = np.intersect1d(tt, te, return_indices=True)
        if common.size == 0:
            raise CdgpsError("no common epochs between truth and estimate")
        qt = truth[names].to_numpy()[it]
        del truth, tt
        per = _matched_rows(st, ie, qt, converge_s)
    time, bad, inside, nees, after, sq_err = (per[k] for k in ("time", "bad", "inside", "nees", "after", "sq_err"))
    if after.sum() < 2:
        raise CdgpsError(f"{states_path}: {common.size} epoch(s) in common with the truth "
                         f"({time[0]:g}–{time[-1]:g} s), {int(after.sum())} after the first {converge_s:g} s "
                         "(--converge-s): too short to evaluate; estimate a longer run")
    if bad.any():
        raise CdgpsError(f"{states_path}: {int(bad.sum())} epoch(s) with non-finite states or sigmas "
                         f"(first at {time[np.flatnonzero(bad)[0]]:g} s)")
    nm = st.n_pos
    rms = np.sqrt(sq_err / after.sum())
    lo, hi = chi2.ppf(0.025, nm), chi2.ppf(0.975, nm)
    na = int(after.sum())
    # time-averaged NEES: 95% interval of the mean of na chi2(nm) samples (if independent)
    mlo, mhi = chi2.ppf(0.025, na * nm) / na, chi2.ppf(0.975, na * nm) / na
    # convergence: first epoch from which the NEES stays below its 99.9% bound for a full second
    bound = chi2.ppf(0.999, nm)
    T = float(np.median(np.diff(time))) if time.size > 1 else 1.0
    w = max(int(round(1.0 / T)), 1)
    ok = nees <= bound
    run_ok = np.convolve(ok.astype(int), np.ones(w, dtype=int), mode="valid") == w
    first = np.flatnonzero(run_ok)
    conv_t = float(time[first[0]] - time[0]) if first.size else None
    out = {
        "epochs": int(common.size), "start_s": float(time[0]), "end_s": float(time[-1]),
        "rms_error": {n: float(v) for n, v in zip(names, rms)},
        "rms_error_units": {n: (st.cfg.coord_unit_label(n) if st.cfg is not None else u)
                            for n, u in zip(names, st.coord_units)},
        "rms_error_deg": {n: float(np.degrees(v)) for n, v, u in zip(names, rms, st.coord_units) if u == "rad"},
        "within_3sigma_fraction": float(np.mean(inside[after])),
        "convergence_definition": "first time from which the NEES stays below its 99.9% chi-square bound for 1 s",
        "convergence_s": conv_t,
        "nees": {"dof": nm, "mean": float(np.mean(nees[after])), "interval95_single": [float(lo), float(hi)],
                 "fraction_in_interval": float(np.mean((nees[after] >= lo) & (nees[after] <= hi))),
                 "interval95_mean_if_independent": [float(mlo), float(mhi)]},
    }
    if nis_all is not None and ((dof_all > 0) & np.isfinite(nis_all)).any():
        ok = (dof_all > 0) & np.isfinite(nis_all)
        r = nis_all[ok] / dof_all[ok]
        inside_nis = (nis_all[ok] >= chi2.ppf(0.025, dof_all[ok])) & (nis_all[ok] <= chi2.ppf(0.975, dof_all[ok]))
        out["nis"] = {"mean_per_dof": float(np.mean(r)), "fraction_in_interval95": float(np.mean(inside_nis))}
    # bias errors: final biases vs truth (latest segment per channel)
    if "final_biases" not in st.metadata:
        raise CdgpsError(f"{states_path}: metadata {ESTIMATE_METADATA!r} has no final_biases (damaged or not a "
                         f"STATES.mcap from 'cdgps estimate')")
    try:
        fb = json.loads(st.metadata["final_biases"])
    except json.JSONDecodeError as exc:
        raise CdgpsError(f"{states_path}: metadata final_biases is not valid JSON ({exc.msg}): corrupt file") from None
    tb = {(b["antenna"], b["transmitter"]): b["bias_m"] for b in tj.get("biases", [])}
    for s in tj.get("slips", []):
        if s["time_s"] <= time[-1] + 1e-9:
            tb[(s["antenna"], s["transmitter"])] = s["bias_m"]
    errs = [(b["antenna"], b["transmitter"], b["bias_m"] - tb[(b["antenna"], b["transmitter"])])
            for b in fb if (b["antenna"], b["transmitter"]) in tb and b["bias_m"] is not None and np.isfinite(b["bias_m"])]
    if errs:
        e = np.array([x[2] for x in errs])
        out["bias_error"] = {"rms_m": float(np.sqrt(np.mean(e**2))), "max_abs_m": float(np.max(np.abs(e))),
                             "wrong_integers": int(np.sum(np.abs(e) > st.wavelength_m / 2)), "channels": len(errs)}
    out["events"] = len(events)
    return out


_EVAL_CHUNK = 16384
"""Epochs of STATES read at a time by :func:`evaluate` (a multiple of 1024: the same bits as the whole record)."""


def _matched_rows(st, ie: np.ndarray, qt: np.ndarray, converge_s: float) -> dict:
    """Per epoch in common with the truth (``ie``: their STATES rows, ascending; ``qt``: the truth
    there), read a chunk of STATES at a time: time, non-finite, within 3σ, NEES and after
    ``converge_s`` (1-D, (M,)), and the sum of the squared errors after it, (n_q,), added row after
    row as ``np.mean(err ** 2, axis=0)`` adds them (the same bits)."""
    M = ie.size
    xi_t = np.concatenate([qt[a:a + 1024] @ np.linalg.pinv(st.output_map).T for a in range(0, M, 1024)])
    out = {"time": np.empty(M), "bad": np.empty(M, dtype=bool), "inside": np.empty(M, dtype=bool),
           "nees": np.empty(M), "after": np.empty(M, dtype=bool)}
    sq_err = np.zeros(qt.shape[1])
    t_start = None
    a = 0
    for ch in st.series(_EVAL_CHUNK):
        k = len(ch["time_s"])
        j0, j1 = np.searchsorted(ie, [a, a + k])
        rows = ie[j0:j1] - a
        a += k
        if j1 == j0:
            continue
        time = ch["time_s"][rows]
        qe, se = ch["q"][rows], ch["sigma_q"][rows]
        err = qe - qt[j0:j1]
        t_start = time[0] if t_start is None else t_start
        after = time >= t_start + converge_s - 1e-9
        d = ch["xi"][rows] - xi_t[j0:j1]
        out["time"][j0:j1] = time
        out["after"][j0:j1] = after
        out["bad"][j0:j1] = ~np.isfinite(qe).all(axis=1) | ~np.isfinite(se).all(axis=1)
        out["inside"][j0:j1] = np.all(np.abs(err) <= 3 * se + 1e-12, axis=1)
        out["nees"][j0:j1] = np.einsum("ni,ni->n", d, np.linalg.solve(ch["P_xi"][rows], d[..., None])[..., 0])
        sq_err = np.add.reduce(np.vstack([sq_err[None], err[after] ** 2]), axis=0)
    out["sq_err"] = sq_err
    return out
