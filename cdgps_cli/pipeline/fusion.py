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
  RTS smoother (:func:`cdgps_cli.estimation.smoother.rts_smooth_indexed`) over it: each distinct
  transition (A, Q) stored once, x and P on the given store (on disk for ``cdgps estimate``: memory
  of a chunk for x, P, whatever the record's length) and smoothed backwards in blocks.
"""

from __future__ import annotations

from array import array
from collections.abc import Sequence
from types import SimpleNamespace

import numpy as np

from cdgps_cli.config.sensors import FUSABLE_KINDS
from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core import heap
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.history import MemoryHistory
from cdgps_cli.estimation.model_filter import filter_numpy
from cdgps_cli.config.options import ESTIMATE_CHUNK_EPOCHS
from cdgps_cli.estimation.smoother import rts_smooth_indexed
from cdgps_cli.measurement.registry import model_from_spec
from cdgps_cli.measurement.sensor import align_epochs, place
from cdgps_cli.measurement.stacked import Stacked
from cdgps_cli.model.fusion_dynamics import ModalDisturbance, fusion_dynamics

__all__ = ["common_time_axis", "sensor_parts", "fusion_problem", "run_fused", "parse_fuse", "SYNC_TOL_S"]

#: a sensor sample this close to a GNSS epoch is at that epoch, s
SYNC_TOL_S = 1e-4


def parse_fuse(text: str | None, option: str = "--fuse") -> tuple:
    """``"gyro,accel"`` → ("gyro", "accel"); ``None`` (option absent) → (). CdgpsError naming ``option``
    for an unknown kind, a kind given twice, an empty item or an empty value (``--fuse ""`` would
    otherwise read as if the option were absent)."""
    if text is None:
        return ()
    items = [k.strip() for k in text.split(",")]
    expected = f"expected a comma-separated list of {', '.join(FUSABLE_KINDS)}"
    if not any(items) or not all(items):
        raise CdgpsError(f"{option} {text!r}: {'empty' if not any(items) else 'an empty item'}; {expected} "
                         f"(leave {option} out to fuse nothing)")
    bad = [k for k in items if k not in FUSABLE_KINDS]
    if bad:
        raise CdgpsError(f"{option} {text}: unknown sensor kind(s) {', '.join(bad)} ({expected})")
    twice = sorted({k for k in items if items.count(k) > 1})
    if twice:
        raise CdgpsError(f"{option} {text}: {', '.join(twice)} given twice; {expected}, each kind once")
    return tuple(items)


def release_freed_heap() -> bool:
    """Give the heap pages freed by the set-up (RUN read, GNSS modal set-up, sensor logs) back to the
    system before the fused filter starts (glibc ``malloc_trim``, :func:`cdgps_cli.core.heap.trim`;
    elsewhere nothing): the filter's arrays then do not sit on top of them.  15-min tower-fusion run: peak
    RSS 321.6 → 251.5 MiB (issue 29, docs/record-length.md).  Arithmetic unchanged.  True when the call
    was made."""
    return heap.trim()


MMAP_THRESHOLD_BYTES = heap.MMAP_THRESHOLD_BYTES
map_large_blocks = heap.map_large_blocks
"""(:func:`cdgps_cli.core.heap.map_large_blocks`, where it lives: the fused run's set-up calls it.)"""


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


def check_fusion_choice(cfg: StructureConfig, specs, fuse, hold_out=()) -> None:
    """CdgpsError naming the option unless every ``hold_out`` name is a sensor of ``specs`` (the
    config's), every kind in ``fuse`` has one, and not every fused sensor is held out (a kind whose
    sensors are all held out is allowed: the [fusion] fuse/hold_out of a config may say so)."""
    unknown = [h for h in hold_out if h not in {s.name for s in specs}]
    if unknown:
        raise CdgpsError(f"--hold-out: {', '.join(unknown)} is not a sensor of config {cfg.name!r} "
                         f"(sensors: {', '.join(s.name for s in specs) or 'none'})")
    lacking = [k for k in fuse if not any(s.kind == k for s in specs)]
    if lacking:
        raise CdgpsError(f"--fuse {','.join(fuse)}: config {cfg.name!r} has no {', '.join(lacking)} sensor "
                         f"([[accelerometers]], [[tilts]], [[strains]], [[gyros]]; docs/config-format.md)")
    if fuse and all(s.name in hold_out for s in specs if s.kind in fuse):
        raise CdgpsError(f"--hold-out {','.join(hold_out)}: every {'/'.join(fuse)} sensor is held out, so --fuse "
                         f"{','.join(fuse)} would fuse no sensor at all; expected at least one sensor of a fused kind "
                         "left in (or leave --fuse out)")


def sensor_parts(cfg: StructureConfig, specs, logs: dict, t_common, fuse, hold_out=(), S=None) -> list:
    """[(name, model)] of the fused sensors: kinds in ``fuse``, names not in ``hold_out``; ``logs``
    {kind: DataFrame with time_s, sensor and the kind's columns}; S the accelerometers' disturbance
    selection (None: state [ξ, ξ̇])."""
    check_fusion_choice(cfg, specs, fuse, hold_out)
    n_core = 2 * cfg.n_modes + (0 if S is None else S.shape[1])
    parts = []
    for sp in specs:
        if sp.kind not in fuse or sp.name in hold_out:
            continue
        df = logs.get(sp.kind)
        rows = None if df is None else df[df["sensor"] == sp.name]
        if rows is None or rows.empty:
            raise CdgpsError(f"--fuse {sp.kind}: no log of sensor {sp.name!r} in the run (ingest its log: "
                             f"'ingest --sensor-log', the GNSS config's sensors key, or a structure run's gyro CSV), or keep it out with --hold-out {sp.name}")
        probe = model_from_spec(cfg, sp, np.zeros((1, len(sp.axes))), [0], n_core, S=S)
        missing = [f for f in probe.fields if f not in rows.columns]
        if missing:
            raise CdgpsError(f"sensor {sp.name}: its log has no column(s) {', '.join(missing)}")
        k_of = align_epochs(t_common, rows["time_s"].to_numpy(float), SYNC_TOL_S)
        if not np.any(k_of >= 0):
            raise CdgpsError(f"sensor {sp.name}: no sample of its log ({rows['time_s'].min():.3f} – "
                             f"{rows['time_s'].max():.3f} s) falls within the GNSS epochs ({t_common[0]:.3f} – "
                             f"{t_common[-1]:.3f} s, GPS s); keep it out with --hold-out {sp.name}")
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


def run_fused(model, dyn, time_s, x0, P0, smooth: bool = True, max_iterations: int = 5, rows_hook=None,
              store=None, chunk_epochs: int = ESTIMATE_CHUNK_EPOCHS, keep: int | None = None, gate_events=None):
    """Forward filter and (``smooth``) RTS smoother over the stacked model.

    Parameters
    ----------
    store : object, optional
        Where the forward pass keeps x (N, n) and P (N, n, n) for the smoother
        (:class:`~cdgps_cli.estimation.history.MemoryHistory` by default; ``cdgps estimate`` gives the
        disk-backed :class:`cdgps_cli.io.scratch.DiskHistory`); pages released every ``chunk_epochs``.
    keep : int, optional
        The leading states whose covariance is returned (the modal states); None: all n.
    gate_events : list, optional
        The list ``rows_hook`` appends its drops to (:func:`~cdgps_cli.estimation.model_filter.outlier_gate`,
        the only hook that changes rows): the rows are then not kept per epoch but made again when
        read (:class:`GatedRows`: the same rows, memory of none).

    Returns
    -------
    SimpleNamespace
        ``x``, ``x_filt`` (N, n); ``P``, ``P_filt`` (N, keep, keep) (``x``, ``P`` reported: smoothed
        or filtered), arrays of ``store`` (on disk with a DiskHistory); ``nis``, ``nis_dof``, ``rows`` (a list, or :class:`GatedRows`).
    """
    fr = filter_numpy(model, dyn, np.asarray(time_s, float), x0, P0, max_iterations, rows_hook=rows_hook,
                      store=store, chunk_epochs=chunk_epochs, keep_rows=gate_events is None)
    if gate_events is not None:
        fr["rows"] = GatedRows(model, fr["had_rows"], gate_events)
    xh, Ph = fr["x"], fr["P"]
    N, n = xh.shape
    m = n if keep is None else int(keep)
    chunk = max(int(chunk_epochs), 1)
    store = store if store is not None else MemoryHistory()
    release = store.release
    # the reported series live on the store too (on disk for ``cdgps estimate``: the STATES writer
    # reads them back a block at a time), copied a chunk at a time, pages dropped behind
    x_filt, P_filt = store.empty((N, n)), store.empty((N, m, m))
    for a in range(0, N, chunk):
        x_filt[a:a + chunk] = xh[a:a + chunk]
        P_filt[a:a + chunk] = Ph[a:a + chunk, :m, :m]
        for arr in (xh, Ph, x_filt, P_filt):
            release(arr, a, a + chunk)
    if not smooth:
        return SimpleNamespace(x=x_filt, P=P_filt, x_filt=x_filt, P_filt=P_filt, nis=fr["nis"],
                               nis_dof=fr["nis_dof"], rows=fr["rows"])
    P_s = store.empty((N, m, m))

    def done(a, b):
        P_s[a:b] = Ph[a:b, :m, :m]
        release(P_s, a, b)
        release(Ph, a + 1, b)                 # (epoch a is read again by the pass below it)
        release(xh, a + 1, b)

    rts_smooth_indexed(xh, Ph, *fr["transitions"], chunk=chunk, on_done=done)
    release(Ph, 0, N)
    release(xh, 0, N)                         # the smoothed states: the store's array itself (smoothed in place)
    return SimpleNamespace(x=xh, P=P_s, x_filt=x_filt, P_filt=P_filt, nis=fr["nis"], nis_dof=fr["nis_dof"],
                           rows=fr["rows"])


class GatedRows(Sequence):
    """The rows each epoch's update used, made again when read: ``model.rows(k)`` with the outlier
    gate's drops at k replayed in their order (``events``: ``{"epoch", "label"}``, the worst first, as
    :func:`~cdgps_cli.estimation.model_filter.outlier_gate` made them), None where the epoch had none
    (``had_rows`` (N,) bool).  The same arrays as the rows kept in memory, without keeping them."""

    def __init__(self, model, had_rows: np.ndarray, events: list):
        self.model, self.had_rows = model, np.asarray(had_rows, dtype=bool)
        self.drops: dict = {}
        for e in events:
            self.drops.setdefault(int(e["epoch"]), []).append(e["label"])

    def __len__(self) -> int:
        return self.had_rows.size

    def __getitem__(self, k):
        if not self.had_rows[k]:
            return None
        rows = self.model.rows(int(k))
        for label in self.drops.get(int(k), ()):
            i = rows.labels.index(label)
            rows = rows.subset(np.delete(np.arange(rows.z_m.size), i))
        return rows


def fusion_choice(cfg: StructureConfig, fuse_option: str | None, hold_out_option=()) -> tuple[tuple, tuple]:
    """(kinds fused, sensors held out): ``--fuse`` (or the config's ``[fusion] fuse``: opt-in, empty by
    default) and ``--hold-out`` added to ``[fusion] hold_out``, checked against the config's sensors
    (:func:`check_fusion_choice`)."""
    from cdgps_cli.config.sensors import fusion_settings  # noqa: PLC0415

    st = fusion_settings(cfg)
    kinds = parse_fuse(fuse_option) if fuse_option is not None else st["fuse"]
    held = tuple(dict.fromkeys(tuple(st["hold_out"]) + tuple(hold_out_option)))
    if held and not kinds:
        raise CdgpsError("--hold-out needs --fuse (or [fusion] fuse in the structure config)")
    if kinds:                                    # before the run is filtered, not after
        from cdgps_cli.config.sensors import sensor_specs  # noqa: PLC0415

        check_fusion_choice(cfg, sensor_specs(cfg), kinds, held)
    return kinds, held


class PartRows(Sequence):
    """The rows of stacked part ``part`` per epoch (:func:`_dd_rows` of ``rows[k]``), made when read:
    a list of them would hold every epoch's rows in memory."""

    def __init__(self, rows, part: int = 0):
        self.rows, self.part = rows, part

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, k):
        return _dd_rows(self.rows[k], self.part)


def _dd_rows(rows, part: int = 0):
    """The rows of stacked part ``part`` (the GNSS DDs) of one epoch's stacked rows, or None."""
    if rows is None:
        return None
    p, local, subs = rows.context
    sel = np.flatnonzero(p == part)
    if sel.size == 0:
        return None
    sub, mine = subs[sel[0]], local[sel]
    return sub if mine.size == sub.z_m.size and np.all(mine == np.arange(sub.z_m.size)) else sub.subset(mine)


def fuse_with_dd(cfg: StructureConfig, dd, t_gnss, logs: dict, fuse, hold_out, x0, P0, *, smooth: bool,
                 max_iterations: int, outlier_sigma: float, say=None, store=None):
    """The GNSS modal estimate with the sensors fused (``cdgps estimate --structure --fuse``).

    ``dd`` is the run's :class:`~cdgps_cli.measurement.model.SatelliteDDModal` on the GNSS epochs
    ``t_gnss``; ``logs`` {kind: table}, or a function returning it (called here, after the GNSS set-up:
    the tables are then not held through it, and are let go once the sensors' models are made); it is re-indexed onto the common time axis of the GNSS epochs and the fused sensors'
    samples, stacked with the sensors, filtered (outlier gate on every row) and smoothed.

    Returns
    -------
    SimpleNamespace
        ``t`` (N,), ``dd`` (the re-indexed DD model), ``x``, ``P``, ``x_filt``, ``P_filt`` (modal states
        [ξ, ξ̇] only), ``nis``, ``nis_dof``, ``dd_rows`` (the DD rows used per epoch), ``outliers_dd``
        (events labelled (slot, satellite)), ``events`` (sensor outliers), ``summary`` (JSON-ready).
    """
    from cdgps_cli.config.sensors import sensor_specs  # noqa: PLC0415
    from cdgps_cli.estimation.model_filter import outlier_gate  # noqa: PLC0415
    from cdgps_cli.measurement.model import SatelliteDDModal  # noqa: PLC0415

    all_specs = sensor_specs(cfg)
    specs = [s for s in all_specs if s.kind in fuse and s.name not in hold_out]
    used = {s.name for s in specs}
    logs = logs() if callable(logs) else logs
    times = [g.loc[g["sensor"].isin(used), "time_s"].to_numpy(float) for k, g in logs.items() if k in fuse]
    t = common_time_axis(t_gnss, times)
    kk = align_epochs(t, t_gnss, SYNC_TOL_S)
    k_of = [np.where(kk >= 0, ko[np.maximum(kk, 0)], -1) for ko in dd.k_of]
    dd2 = SatelliteDDModal(cfg, dd.R, dd.tabs, k_of, dd.ant_idx, dd.d_hdr)
    accel = any(s.kind == "accel" for s in specs)
    S = ModalDisturbance(cfg).S if accel else None
    parts = sensor_parts(cfg, all_specs, logs, t, fuse, hold_out, S=S)
    del logs, times                              # (the parts hold what the filter reads of them)
    model, dyn, P0f, names = fusion_problem(cfg, [("gnss", dd2)], parts, P0, disturbance=accel)
    x0f = np.zeros(dyn.n)
    x0f[:x0.size] = x0
    events: list = []
    if say:
        say(f"fused EKF over {t.size} epochs ({t_gnss.size} GNSS), {len(parts)} sensor(s), {dyn.n} states …")
    nm2 = 2 * cfg.n_modes
    release_freed_heap()
    r = run_fused(model, dyn, t, x0f, P0f, smooth, max_iterations, rows_hook=outlier_gate(model, outlier_sigma, events, t),
                  store=store, keep=nm2, gate_events=events)
    dd_rows = PartRows(r.rows, 0)
    out_dd = [dict(e, label=tuple(e["label"][1:])) for e in events if e["label"][0] == "gnss"]
    out_s = [{"time_s": e["time_s"], "antenna": e["label"][0], "transmitter": e["label"][2], "kind": "outlier",
              "action": f"sensor reading not used at this epoch ({e['sigmas']:.1f} σ)"} for e in events if e["label"][0] != "gnss"]
    summary = {"fused": list(fuse), "hold_out": list(hold_out), "epochs": int(t.size), "gnss_epochs": int(t_gnss.size),
               "added_states": names,
               "sensors": _sensor_summary(parts, r.x, r.rows, release=None if store is None else store.release),
               "disturbance_states": bool(accel),
               "gyro_independent_check": "gyro" not in fuse or any(s.kind == "gyro" and s.name in hold_out
                                                                 for s in all_specs)}
    return SimpleNamespace(t=t, dd=dd2, x=r.x[:, :nm2], P=r.P[:, :nm2, :nm2], x_filt=r.x_filt[:, :nm2],
                           P_filt=r.P_filt[:, :nm2, :nm2], nis=r.nis, nis_dof=r.nis_dof, dd_rows=dd_rows,
                           outliers_dd=out_dd, events=out_s, summary=summary)


def _sensor_summary(parts, x, rows, release=None, block: int = ESTIMATE_CHUNK_EPOCHS) -> dict:
    """Per fused sensor: samples, RMS residual of the reported estimate per field, final bias per field
    (one pass over ``rows``: made again per epoch when they are :class:`GatedRows`).  ``release``: the
    store's (:meth:`cdgps_cli.io.scratch.DiskHistory.release`), the pages of ``x`` read are dropped
    every ``block`` epochs behind the pass (issue 29: else all of x on disk is back in memory)."""
    res = [{f: array("d") for f in m.fields} for _, m in parts]     # (8 bytes a residual, not a float object)
    count = [0] * len(parts)
    for k, rk in enumerate(rows):
        if release is not None and k and k % block == 0:
            release(x, k - block, k)
        for p, (_, m) in enumerate(parts, start=1):
            sub = _dd_rows(rk, p)
            if sub is None:
                continue
            count[p - 1] += 1
            h, _ = m.predict(x[k], sub)
            for (_, f), z, hh in zip(sub.labels, sub.z_m, h):
                res[p - 1][f].append(z - hh)
    out = {}
    for (name, m), r, n in zip(parts, res, count):
        out[name] = {"kind": m.kind, "samples": n,
                     "residual_rms": {f: float(np.sqrt(np.mean(np.square(np.frombuffer(v))))) if v else None for f, v in r.items()},
                     "sigma": {f: float(s) for f, s in zip(m.fields, m.sigma)},
                     "final_bias": ({f: float(x[-1, m.bias_offset + j]) for j, f in enumerate(m.fields)}
                                    if m.extra_states else {})}
    if release is not None:
        release(x, 0, len(x))
    return out


def run_gyro_table(run) -> dict:
    """{"gyro": table} in the sensor-log format (``time_s``, ``sensor``, ``gyro_<axis>_rad_s``) from a
    structure RUN's gyro topic (long table time_s, gyro, rate_rad_s): each gyro's rate in the column
    its measurement model reads (:class:`cdgps_cli.measurement.gyro.RateGyro` fields); empty: no gyros."""
    import pandas as pd  # noqa: PLC0415

    from cdgps_cli.config.sensors import sensor_specs  # noqa: PLC0415

    g = run.gyro.frame() if hasattr(run.gyro, "frame") else run.gyro
    if g is None or not len(g):
        return {}
    cfg = run.cfg
    out = pd.DataFrame({"time_s": g["time_s"].to_numpy(float), "sensor": g["gyro"].astype(str).to_numpy()})
    rate = g["rate_rad_s"].to_numpy(float)
    for sp in sensor_specs(cfg):
        if sp.kind != "gyro":
            continue
        field = model_from_spec(cfg, sp, np.zeros((1, 1)), [0], 2 * cfg.n_modes).fields[0]
        if field not in out:
            out[field] = np.nan
        sel = (out["sensor"] == sp.name).to_numpy()
        out.loc[sel, field] = rate[sel]
    return {"gyro": out.sort_values(["time_s", "sensor"], kind="stable").reset_index(drop=True)}


def _refuse_pseudolite_options(run, opt, fuse) -> None:
    """CdgpsError naming what the fused pseudolite filter does not (yet) take."""
    bad = [k for k in fuse if k != "gyro"]
    if bad:
        raise CdgpsError(f"--fuse {','.join(fuse)}: a structure (pseudolite) run carries gyro logs only; "
                         f"{', '.join(bad)} fusion is on GNSS runs with --structure")
    for flag, on in (("--biases states", opt.biases != "fixed"), ("--rest", bool(opt.rest_segments_s) or opt.rest_auto)):
        if on:
            raise CdgpsError(f"--fuse gyro on a structure run: {flag} is not available with fusion (fixed biases, no "
                             "static mode)")
    if len(run.actuators):
        raise CdgpsError(f"--fuse gyro: {run.path} has thruster commands; the fused filter's dynamics have no known "
                         "inputs yet (estimate without --fuse)")


def fuse_with_pseudolite(run, init: dict, opt, fuse, hold_out=()):
    """``cdgps estimate --fuse gyro`` on a pseudolite (testbed) run: the single differences of INIT's
    fixed biases stacked with the rate gyros (bias states, random walk as configured) on the modal
    state, through the one driver (:func:`run_fused`: forward filter with the outlier gate on every
    row, RTS smoother), from INIT's state at its window end.

    The set-up (epoch grid, phases, channels, σ per channel, INIT's state and biases) is the pseudolite
    filter's (:class:`cdgps_cli.estimation.filter._ForwardPass`); its integrity hooks (lock restarts,
    re-bias, batch re-initialization, rest) are not run: a channel whose lock restarts is left out
    from then on (its bias no longer trusted).

    Returns
    -------
    EstimateResult
        Modal states only (the gyro biases in ``fusion["sensors"]``), epochs from INIT's window end;
        its ``fusion`` attribute is the JSON-ready summary (``gyro_independent_check`` …).
    """
    from cdgps_cli.config.sensors import sensor_specs  # noqa: PLC0415
    from cdgps_cli.estimation.filter import EstimateResult, _ForwardPass  # noqa: PLC0415
    from cdgps_cli.estimation.model_filter import outlier_gate  # noqa: PLC0415
    from cdgps_cli.measurement.model import PseudoliteSD  # noqa: PLC0415

    cfg = run.cfg
    _refuse_pseudolite_options(run, opt, fuse)
    fp = _ForwardPass(run, init, opt)                        # set-up only
    n = 2 * cfg.n_modes
    logs = run_gyro_table(run)
    all_specs = sensor_specs(cfg)
    used = {s.name for s in all_specs if s.kind in fuse and s.name not in hold_out}
    times = [g.loc[g["sensor"].isin(used), "time_s"].to_numpy(float) for g in logs.values()]
    t = common_time_axis(fp.grid, times)
    kk = align_epochs(t, fp.grid, SYNC_TOL_S)
    y = np.full((t.size, fp.C), np.nan)
    y[kk >= 0] = fp.Y[kk[kk >= 0]] - fp.bias                   # channels without INIT's bias: NaN, not used
    after = np.cumsum(fp.EVENT >= 2, axis=0) > 0               # from a lock restart on: the bias is not trusted
    y[kk >= 0] = np.where(after[kk[kk >= 0]], np.nan, y[kk >= 0])
    phase = PseudoliteSD(cfg, y, fp.ant, fp.tx, fp.sig_c)
    parts = sensor_parts(cfg, all_specs, logs, t, fuse, hold_out)
    model, dyn, P0, names = fusion_problem(cfg, [("phase", phase)], parts, fp.P[:n, :n], disturbance=False)
    x0 = np.zeros(dyn.n)
    x0[:n] = fp.x[:n]
    events: list = []
    r = run_fused(model, dyn, t, x0, P0, opt.smooth, 1, rows_hook=outlier_gate(model, opt.outlier_sigma, events, t),
                  store=opt.history, chunk_epochs=opt.chunk_epochs, keep=n, gate_events=events)
    resid = _phase_residuals(phase, r.x_filt, r.rows, fp.C)
    ev = [{"time_s": e["time_s"], "antenna": e["label"][1] if e["label"][0] == "phase" else e["label"][0],
           "transmitter": e["label"][2], "kind": "outlier",
           "action": f"{'phase' if e['label'][0] == 'phase' else 'sensor reading'} not used at this epoch "
                     f"({e['sigmas']:.1f} σ)"} for e in events]
    fusion = {"fused": list(fuse), "hold_out": list(hold_out), "epochs": int(t.size), "phase_epochs": int(fp.N),
              "added_states": names, "sensors": _sensor_summary(parts, r.x, r.rows), "disturbance_states": False,
              "gyro_independent_check": "gyro" not in fuse or any(s.kind == "gyro" and s.name in hold_out
                                                                for s in all_specs)}
    res = EstimateResult(cfg, t, r.x[:, :n], r.P[:, :n, :n], r.x_filt[:, :n] if opt.smooth else None,
                         r.P_filt[:, :n, :n] if opt.smooth else None, list(fp.chans), resid, r.nis, r.nis_dof,
                         events=ev, biases={c: float(b) for c, b in zip(fp.chans, fp.bias) if np.isfinite(b)},
                         smoothed=bool(opt.smooth), filter_path="numpy",
                         noise={"sigma_m": float(np.sqrt(np.mean(fp.sig_c**2))), "source": fp.sigma_source})
    res.fusion = fusion
    return res


def _phase_residuals(phase, x, rows, C: int) -> np.ndarray:
    """(N, C) post-fit residuals of the single differences at the filtered states (NaN: not used)."""
    out = np.full((len(rows), C), np.nan)
    for k, rk in enumerate(rows):
        sub = _dd_rows(rk, 0)
        if sub is None:
            continue
        h, _ = phase.predict(x[k], sub)
        out[k, sub.context] = sub.z_m - h
    return out
