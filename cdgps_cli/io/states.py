"""STATES.mcap (output of ``cdgps estimate``): the writer and the reader (no numerics: the stage
functions — writing an estimate, CSV export, evaluation against truth — are in
:mod:`cdgps_cli.pipeline.estimate_outputs`).

Every epoch of every series is stored as packed arrays (lossless, compact; the layout is in
:mod:`cdgps_cli.io.states_layout`), which :class:`States` reads.  Beside them, the Foxglove
channels (JSON schema / JSON, ``timestamp {sec, nsec}``) hold one message every
``json_channels_every_epochs`` epochs (``--foxglove-rate-hz``, default 1 Hz; 0: every epoch):

* ``/cdgps/state`` — the estimate (smoothed when ``--smooth``): ``q`` and ``sigma_q`` as objects
  keyed by coordinate name (so Foxglove plots ``/cdgps/state.q.q10`` directly), the modal state
  ``xi``, ``xidot``, ``smoothed``, and with ``--covariance full`` the modal-position covariance
  ``P_xi`` (row-major n_m×n_m);
* ``/cdgps/state_filtered`` — the forward filter, only when smoothing;
* ``/cdgps/angles_deg`` — the section angles reports speak of, in degrees, as flat numbers with
  plain names so Foxglove's Plot panel plots ``/cdgps/angles_deg.C2_z`` (q6+q10 on the testbed)
  by name: one per section and axis it rotates about (small-angle sum of its rotation coordinate
  and, about z, the rigid-body rotation), ``body_z`` for the rigid-body rotation, each with its
  1-sigma ``sigma_<name>``; the expressions are in the schema's descriptions and the channel's
  metadata (given by the caller: :func:`cdgps_cli.model.kinematics.section_angles`); absent when the model has no rotations;
* ``/cdgps/residuals`` — per channel post-fit residual (m), the epoch's NIS (left out where
  there is none) and its dof;
* ``/cdgps/events`` — slips, re-acquisitions, outliers, integrity failures and their actions
  (every event).

``time_s`` is the run's time scale (run seconds, or GPS s for a structure on a GNSS run); log
times are Unix time (:mod:`cdgps_cli.core.timescales`).  No message holds ``null``
(:mod:`cdgps_cli.io.mcap`).

Attachments: ``config.toml``, ``init.json``, the packed arrays.  Metadata ``cdgps.estimate``: RUN
and INIT sha256, options, final biases, ``covariance``, ``json_channels_every_epochs``.  Files
of the earlier layouts (``.npy`` attachments with every epoch in JSON, or JSON messages only) are
still read.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from cdgps_cli import __version__
from cdgps_cli.core import progress
from cdgps_cli.config.structure import StructureConfig, parse_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.states_layout import (COVARIANCE_CHOICES, DEFAULT_COVARIANCE, DEFAULT_PREVIEW_RATE_HZ, PACKED_PREFIX,
                               RESIDUAL_PACKED)
from cdgps_cli.io.mcap import NULLABLE, CONFIG_ATTACHMENT, McapOut, array_schema, message_schema, read_mcap

STATE_TOPIC = "/cdgps/state"
STATE_FILTERED_TOPIC = "/cdgps/state_filtered"
RESIDUAL_TOPIC = "/cdgps/residuals"
EVENT_TOPIC = "/cdgps/events"
INIT_ATTACHMENT = "init.json"
ESTIMATE_METADATA = "cdgps.estimate"
ANGLES_TOPIC = "/cdgps/angles_deg"


def _state_schema(cfg: StructureConfig, with_P: bool = True) -> dict:
    obj = {"type": "object", "properties": {n: {"type": "number"} for n in cfg.coord_names}}
    arrays = {"xi": "number", "xidot": "number", **({"P_xi": "number"} if with_P else {})}
    s = array_schema("cdgps.StructureState", arrays,
                     {"smoothed": "boolean"})
    s["properties"]["q"] = dict(obj, description="generalized coordinates (m or rad)")
    s["properties"]["sigma_q"] = dict(obj, description="1-sigma of q")
    return s


RESIDUAL_SCHEMA = array_schema("cdgps.Residuals", {"antenna": "string", "transmitter": "string", "residual_m": "number"},
                               {"nis": NULLABLE, "nis_dof": "integer"})
_EVENT_FIELDS = {"antenna": {"type": "string"}, "transmitter": {"type": "string"}, "kind": {"type": "string"},
                 "action": {"type": "string"},
                 "velocity_nis": {"type": "number", "description": "rest test statistic (rest events only)"}}
EVENT_SCHEMA = message_schema("cdgps.Event", _EVENT_FIELDS)


def _json_type(v) -> str | None:
    if isinstance(v, (bool, np.bool_)):
        return "boolean"
    if isinstance(v, (int, np.integer)):
        return "integer"
    if isinstance(v, (float, np.floating)):
        return "number"
    if isinstance(v, str):
        return "string"
    return None


def event_schema(events: list[dict]) -> dict:
    """:data:`EVENT_SCHEMA` plus any further detail field the events carry (its JSON type from the
    values: number when integers and floats mix), so every field is declared for Foxglove."""
    extra: dict[str, set] = {}
    for ev in events:
        for k, v in ev.items():
            if k != "time_s" and k not in _EVENT_FIELDS and v is not None and not (isinstance(v, float) and v != v):
                extra.setdefault(k, set()).add(_json_type(v))
    if not extra:
        return EVENT_SCHEMA
    props = dict(_EVENT_FIELDS)
    for k, types in sorted(extra.items()):
        if None in types:
            raise ValueError(f"event field {k!r}: values of an unsupported type")
        t = types.pop() if len(types) == 1 else ("number" if types <= {"integer", "number"} else None)
        if t is None:
            raise ValueError(f"event field {k!r}: values of mixed types {sorted(types)}")
        props[k] = {"type": t}
    return message_schema("cdgps.Event", props)


def _angles_schema(angles) -> dict:
    props = {}
    for name, expr, _ in angles:
        props[name] = {"type": "number", "description": f"{expr}, degrees"}
        props["sigma_" + name] = {"type": "number", "description": f"1-sigma of {expr}, degrees"}
    return message_schema("cdgps.AnglesDeg", props, "section angles in degrees (small-angle sums of coordinates)")


def _write_angles(out: McapOut, cfg: StructureConfig, angles, time_s, q: np.ndarray, P_xi: np.ndarray) -> None:
    """The :data:`ANGLES_TOPIC` messages: section angles and their 1-sigma, degrees.

    ``angles``: list of (name, expression, coefficients (n_q,)) as
    :func:`cdgps_cli.model.kinematics.section_angles` gives them (empty: no channel)."""
    if not angles:
        return
    A = np.array([c for _, _, c in angles])                   # (n_angles, n_q)
    AU = A @ np.asarray(cfg.mode_shapes)                      # (n_angles, n_m)
    names = [n for n, _, _ in angles]
    sig_names = ["sigma_" + n for n in names]
    ch = out.channel(ANGLES_TOPIC, _angles_schema(angles),
                     {"units": "deg", "angles": json.dumps({n: e for n, e, _ in angles})})
    times = np.asarray(time_s, dtype=float)
    for a in range(0, times.size, 1024):                      # blocks: no full-length temporaries
        b = min(a + 1024, times.size)
        deg = np.degrees(q[a:b] @ A.T).tolist()
        var = np.einsum("ai,nij,aj->na", AU, P_xi[a:b], AU)
        sig = np.degrees(np.sqrt(np.maximum(var, 0.0))).tolist()
        for k, t in enumerate(times[a:b].tolist()):
            msg = dict(zip(names, deg[k]))
            msg.update(zip(sig_names, sig[k]))
            out.write(ch, t, msg)


def coordinate_sigma(cfg: StructureConfig, P_xi: np.ndarray, block: int = 1024) -> np.ndarray:
    """1-σ of q = U ξ from the modal-position covariances (N, n_m, n_m) → (N, n_q).

    Computed on contiguous blocks of ``block`` epochs: the same numbers whatever the memory layout
    of ``P_xi`` (a strided view of the filter's (N, n, n) series or a contiguous array read back),
    and no full-size temporary."""
    U = np.asarray(cfg.mode_shapes)
    out = np.empty((P_xi.shape[0], U.shape[0]))
    for a in range(0, P_xi.shape[0], block):
        Pb = np.ascontiguousarray(P_xi[a:a + block], dtype=float)
        out[a:a + block] = np.sqrt(np.maximum(np.einsum("qi,nij,qj->nq", U, Pb, U), 0.0))
    return out


def _npy_load(data: bytes) -> np.ndarray:
    import io

    return np.load(io.BytesIO(data), allow_pickle=False)


def preview_stride(time_s: np.ndarray, rate_hz: float) -> int:
    """Every how many epochs the JSON channels get a message (1: every epoch) for ``rate_hz``."""
    if rate_hz < 0 or not np.isfinite(rate_hz):
        raise ValueError(f"preview rate {rate_hz!r} Hz: expected a finite rate ≥ 0 (0: every epoch)")
    t = np.asarray(time_s, dtype=float)
    if rate_hz == 0 or t.size < 2:
        return 1
    period_s = float(np.median(np.diff(t)))
    return max(int(round(1.0 / (rate_hz * period_s))), 1) if period_s > 0 else 1


def series_derived(cfg: StructureConfig, xi: np.ndarray, P_xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q = ξ Uᵀ (N, n_q) and its 1-σ (N, n_q) from ξ (N, n_m) and P_ξ (N, n_m, n_m): what the
    writer puts in the JSON channels and the reader returns (the same function on the same arrays)."""
    return series_q(cfg, xi), coordinate_sigma(cfg, P_xi)


def series_q(cfg: StructureConfig, xi: np.ndarray) -> np.ndarray:
    """q = ξ Uᵀ (N, n_q) from ξ (N, n_m)."""
    return np.ascontiguousarray(xi, dtype=float) @ np.asarray(cfg.mode_shapes).T


def _triu(P: np.ndarray, block: int = 1024) -> np.ndarray | None:
    """(N, m(m+1)/2) upper triangles of exactly symmetric (N, m, m) matrices, else None."""
    i, j = np.triu_indices(P.shape[1])
    for a in range(0, P.shape[0], block):
        Pb = P[a:a + block]
        if not (Pb[:, i, j] == Pb[:, j, i]).all():
            return None
    return P[:, i, j]


def _from_triu(T: np.ndarray, m: int) -> np.ndarray:
    """Inverse of :func:`_triu`: symmetric (N, m, m)."""
    i, j = np.triu_indices(m)
    if T.ndim != 2 or T.shape[1] != i.size:
        raise ValueError(f"P_xi_triu of shape {list(T.shape)}: expected (N, {i.size}) for {m} modes")
    P = np.empty((T.shape[0], m, m))
    P[:, i, j] = T
    P[:, j, i] = T
    return P


def _attach_series(out: McapOut, topic: str, time_s, X: np.ndarray, P: np.ndarray, P_xi: np.ndarray,
                   sigma_q: np.ndarray, with_P_xi: bool, full: bool) -> None:
    """The packed arrays of one state series (:mod:`cdgps_cli.io.states_layout`)."""
    nm = P_xi.shape[1]
    key = f"{PACKED_PREFIX}{topic}/"
    out.attach_packed(key + "time_s", np.asarray(time_s, dtype=float))
    out.attach_packed(key + "xi", np.ascontiguousarray(X[:, :nm]))
    out.attach_packed(key + "xidot", np.ascontiguousarray(X[:, nm:2 * nm]))
    if full and P.shape[1] > nm:
        out.attach_packed(key + "P", P)
    if not with_P_xi:
        out.attach_packed(key + "sigma_q", sigma_q)
        return
    T = _triu(P_xi)
    if T is None:
        out.attach_packed(key + "P_xi", P_xi)
    else:
        out.attach_packed(key + "P_xi_triu", T)


def _write_state_messages(out: McapOut, ch: int, names, sel, time_s, X, q, sq, P_xi, nm, smoothed,
                          with_P: bool) -> None:
    """The Foxglove JSON messages of one state series at the epochs ``sel``."""
    for k in sel.tolist():
        msg = {"q": dict(zip(names, q[k].tolist())), "sigma_q": dict(zip(names, sq[k].tolist())),
               "xi": X[k, :nm].tolist(), "xidot": X[k, nm:2 * nm].tolist()}
        if with_P:
            msg["P_xi"] = P_xi[k].ravel().tolist()
        msg["smoothed"] = smoothed
        out.write(ch, time_s[k], msg)


def _write_residuals(out: McapOut, res, sel) -> None:
    """Residuals, NIS and dof: every epoch packed, the JSON channel at the epochs ``sel``."""
    # float32 (7 significant digits: nm on cm-level residuals) keeps the file within its RUN's size;
    # the JSON messages carry the float64 values
    out.attach_packed(RESIDUAL_PACKED + "residual_m", np.asarray(res.residual_m, dtype=np.float32))
    out.attach_packed(RESIDUAL_PACKED + "nis", np.asarray(res.nis, dtype=float))
    out.attach_packed(RESIDUAL_PACKED + "nis_dof", np.asarray(res.nis_dof, dtype=np.int64))
    out.attach(RESIDUAL_PACKED + "channels.json", json.dumps([list(c) for c in res.channels]).encode(),
               "application/json")
    ch = out.channel(RESIDUAL_TOPIC, RESIDUAL_SCHEMA)
    ants = [c[0] for c in res.channels]
    txs = [c[1] for c in res.channels]
    for k in sel.tolist():
        r = res.residual_m[k]
        used = ~np.isnan(r)
        out.write(ch, res.time_s[k], {"antenna": [a for a, u in zip(ants, used) if u],
                                      "transmitter": [x for x, u in zip(txs, used) if u],
                                      "residual_m": r[used].tolist(),
                                      "nis": None if np.isnan(res.nis[k]) else float(res.nis[k]),
                                      "nis_dof": int(res.nis_dof[k])})


def write_states(res, run_path: str | Path, init: dict, init_text: str,
                 out_path: str | Path, options: dict, covariance: str = DEFAULT_COVARIANCE,
                 preview_rate_hz: float = DEFAULT_PREVIEW_RATE_HZ, angles=()) -> dict:
    """Write STATES.mcap atomically; returns a summary.

    The stage function is :func:`cdgps_cli.pipeline.estimate_outputs.write_states`, which gives
    the section angles of the structure (this module imports no numerics).

    Parameters
    ----------
    res
        The estimate (:class:`cdgps_cli.estimation.filter.EstimateResult` or the same fields).
    run_path, init, init_text, options
        Provenance recorded in the ``cdgps.estimate`` metadata.
    out_path : path
    covariance : {"modal", "full"}
        ``"modal"``: the modal-position covariance P_ξ (n_m×n_m) per epoch; ``"full"``: also the
        whole state covariance P (n×n) of the estimate (and of the forward filter when it was
        kept whole), and P_ξ in the JSON messages.
    preview_rate_hz : float
        Rate of the Foxglove JSON channels, Hz (0: every epoch); see :data:`DEFAULT_PREVIEW_RATE_HZ`.
    angles : list of (str, str, ndarray (n_q,))
        The :data:`ANGLES_TOPIC` channel's angles: name, expression, coefficients (rad per
        coordinate unit); empty: no such channel.
    """
    if covariance not in COVARIANCE_CHOICES:
        raise ValueError(f"covariance {covariance!r}: expected one of {', '.join(COVARIANCE_CHOICES)}")
    cfg = res.cfg
    nm = cfg.n_modes
    names = list(cfg.coord_names)
    stride = preview_stride(res.time_s, preview_rate_hz)
    sel = np.arange(0, len(res.time_s), stride)
    meta = {"cdgps_version": __version__, "created_by": "cdgps estimate", "config_name": cfg.name,
            "config_sha256": cfg.sha256, "run": Path(run_path).name,
            "run_sha256": hashlib.sha256(Path(run_path).read_bytes()).hexdigest(),
            "init_sha256": hashlib.sha256(init_text.encode()).hexdigest(),
            "options": json.dumps(options, sort_keys=True),
            "measurement_noise": json.dumps(getattr(res, "noise", {}) or {}, sort_keys=True),
            "final_biases": json.dumps([{"antenna": a, "transmitter": t, "bias_m": b}
                                        for (a, t), b in res.biases.items()]),
            "smoothed": str(res.smoothed).lower(),
            # where the filter ran in static mode (report static says when its segment did not)
            "rest_active_s": json.dumps(getattr(res, "rest_active_s", [])),
            "rest_detection": json.dumps(getattr(res, "rest_detection", None)),
            "covariance": covariance, "arrays": "packed (cdgps_cli.io.packed_arrays), every epoch",
            "json_channels_every_epochs": str(stride)}
    window = getattr(res, "window", None)
    if window:
        # epochs start_s … end_s come from INIT's batch solution (not from the filter)
        meta["window"] = json.dumps(window, sort_keys=True)
    from cdgps_cli.io.gnss_run import run_kind  # noqa: PLC0415 (a structure estimated on a GNSS run: GPS time)

    time_scale = "gps" if run_kind(run_path) == "gnss" else "relative"
    time_s = np.asarray(res.time_s, dtype=float)
    series = [(STATE_TOPIC, res.x, res.P, res.smoothed)]
    if res.smoothed:
        series.append((STATE_FILTERED_TOPIC, res.x_filt, res.P_filt, False))
    with McapOut(out_path, time_scale=time_scale) as out, \
            progress.bar(len(series) + 1, f"writing {Path(out_path).name}", "series") as bar:
        schema = _state_schema(cfg, with_P=covariance == "full")
        for topic, X, P, smoothed in series:
            P_xi = P[:, :nm, :nm]                                 # a view: no full-size copy
            q, sq = series_derived(cfg, X[:, :nm], P_xi)          # as the reader computes them
            _attach_series(out, topic, time_s, X, P, P_xi, sq, with_P_xi=topic == STATE_TOPIC or covariance == "full",
                           full=covariance == "full")
            _write_state_messages(out, out.channel(topic, schema), names, sel, time_s, X, q, sq, P_xi, nm,
                                  smoothed, covariance == "full")
            if topic == STATE_TOPIC:
                _write_angles(out, cfg, angles, time_s[sel], q[sel], P_xi[sel])
            del q, sq, P_xi
            bar.update()
        _write_residuals(out, res, sel)
        bar.update()
        ch = out.channel(EVENT_TOPIC, event_schema(res.events))
        for ev in res.events:
            body = {k: v for k, v in ev.items() if k != "time_s"}
            out.write(ch, ev["time_s"], body)
        out.attach(CONFIG_ATTACHMENT, cfg.text.encode(), "application/toml")
        out.attach(INIT_ATTACHMENT, init_text.encode(), "application/json")
        out.metadata(ESTIMATE_METADATA, meta)
    nis_ok = res.nis_dof > 0
    return {"output": str(out_path), "epochs": int(len(res.time_s)), "start_s": float(res.time_s[0]),
            "end_s": float(res.time_s[-1]), "smoothed": res.smoothed, "events": len(res.events),
            "window": window or None, "covariance": covariance, "json_channels_every_epochs": stride,
            "mean_nis_per_dof": float(np.nanmean(res.nis[nis_ok] / res.nis_dof[nis_ok])) if nis_ok.any() else None,
            "event_list": res.events}


class States:
    """A STATES.mcap read back: config, times, q, sigma_q, modal state, covariances, events.

    Attributes
    ----------
    time_s : (N,) s
    q, sigma_q : (N, n_q) coordinate units (m or rad)
    xi : (N, n_m); xidot : (N, n_m) or None (files before the packed arrays)
    P_xi : (N, n_m, n_m) or None (the forward filter of a smoothed run, unless ``--covariance full``)
    P : (N, n, n) or None (only with ``--covariance full``)
    nis, nis_dof : (N,) or None (``diagnostics=False``)
    events : list of dict; metadata : dict (``cdgps.estimate``)
    """

    def __init__(self, path: str | Path, topic: str = STATE_TOPIC, diagnostics: bool = True):
        c = read_mcap(path, topics=[EVENT_TOPIC] if diagnostics else [])
        self.path = str(path)
        if "cdgps.ingest" in c.metadata:
            raise CdgpsError(f"{path}: this is a RUN.mcap (from 'cdgps ingest'), not a STATES.mcap from 'cdgps estimate'")
        if CONFIG_ATTACHMENT not in c.attachments:
            raise CdgpsError(f"{path}: no config attachment; is this a STATES.mcap from 'cdgps estimate'?")
        what = "STATES.mcap from 'cdgps estimate'"
        c.require_metadata(ESTIMATE_METADATA, what)
        if diagnostics:
            c.require_channels(RESIDUAL_TOPIC, EVENT_TOPIC, what=what)
        self.cfg = parse_config(c.attachments[CONFIG_ATTACHMENT].decode(), f"{path}:{CONFIG_ATTACHMENT}")
        self.xidot = self.P = None
        key = f"{PACKED_PREFIX}{topic}/"
        if key + "time_s" in c.attachments:                # packed arrays (every epoch)
            self._read_packed(c.attachments, key)
        elif key + "time_s.npy" in c.attachments:        # .npy attachments (older files)
            self._read_npy(c.attachments, key)
        else:                                             # messages only (oldest files)
            self._read_messages(topic)
        self.metadata = c.metadata[ESTIMATE_METADATA]
        self.nis = self.nis_dof = None
        if diagnostics:
            self._read_diagnostics(c)
        ev = c.topics.get(EVENT_TOPIC)
        self.events = []
        if ev:
            for i, t in enumerate(ev.times()):
                self.events.append({"time_s": float(t), **{k: ev.scalars[k][i] for k in ev.scalars if k != "time_s"}})

    def _read_packed(self, att: dict, key: str) -> None:
        from cdgps_cli.io.packed_arrays import unpack  # noqa: PLC0415

        nm = self.cfg.n_modes
        try:
            self.time_s = unpack(att[key + "time_s"], f"{self.path}: {key}time_s").astype(float, copy=False)
            N = self.time_s.shape[0]
            self.xi = unpack(att[key + "xi"], f"{self.path}: {key}xi").reshape(N, nm)
            self.xidot = unpack(att[key + "xidot"], f"{self.path}: {key}xidot").reshape(N, -1)
            self.P_xi = sigma_q = None
            if key + "P_xi_triu" in att:
                self.P_xi = _from_triu(unpack(att[key + "P_xi_triu"], f"{self.path}: {key}P_xi_triu"), nm)
            elif key + "P_xi" in att:
                self.P_xi = unpack(att[key + "P_xi"], f"{self.path}: {key}P_xi").reshape(N, nm, nm)
            else:                                         # a forward filter stored with its 1-σ only
                sigma_q = unpack(att[key + "sigma_q"], f"{self.path}: {key}sigma_q").reshape(N, -1)
            if key + "P" in att:
                self.P = unpack(att[key + "P"], f"{self.path}: {key}P")
                if self.P.ndim != 3 or self.P.shape[0] != N:
                    raise ValueError(f"P of shape {list(self.P.shape)} for {N} epochs")
        except (KeyError, ValueError) as exc:
            raise CdgpsError(f"{self.path}: damaged state arrays ({key}*): {exc}") from None
        if self.time_s.ndim != 1:
            raise CdgpsError(f"{self.path}: damaged state arrays ({key}time_s of shape {list(self.time_s.shape)})")
        if self.P_xi is None:
            self.q, self.sigma_q = series_q(self.cfg, self.xi), sigma_q
        else:
            self.q, self.sigma_q = series_derived(self.cfg, self.xi, self.P_xi)

    def _read_npy(self, att: dict, key: str) -> None:
        try:
            self.time_s = _npy_load(att[key + "time_s.npy"])
            self.q = _npy_load(att[key + "q.npy"])
            self.sigma_q = _npy_load(att[key + "sigma_q.npy"])
            self.xi = _npy_load(att[key + "xi.npy"])
            self.P_xi = _npy_load(att[key + "P_xi.npy"])
        except (KeyError, ValueError, OSError) as exc:
            raise CdgpsError(f"{self.path}: damaged state arrays attachment: {exc}") from None

    def _read_messages(self, topic: str) -> None:
        tc = read_mcap(self.path, topics=[topic]).topics.get(topic)
        if tc is None:
            raise CdgpsError(f"{self.path}: no {topic} messages; is this a STATES.mcap from 'cdgps estimate'?")
        nm = self.cfg.n_modes
        self.time_s = tc.times()
        names = list(self.cfg.coord_names)
        nan = float("nan")                            # a coordinate left out (no solution): NaN
        self.q = np.array([[_num(m.get(n, nan)) for n in names] for m in tc.scalars["q"]], dtype=float)
        self.sigma_q = np.array([[_num(m.get(n, nan)) for n in names] for m in tc.scalars["sigma_q"]], dtype=float)
        N = len(self.time_s)
        self.xi = tc.column("xi").reshape(N, nm)
        self.P_xi = tc.column("P_xi").reshape(N, nm, nm)

    def _read_diagnostics(self, c) -> None:
        """NIS and its dof per epoch: packed arrays, or the residual messages of older files."""
        from cdgps_cli.io.packed_arrays import unpack  # noqa: PLC0415

        N = len(self.time_s)
        if RESIDUAL_PACKED + "nis" in c.attachments:
            try:
                self.nis = unpack(c.attachments[RESIDUAL_PACKED + "nis"], f"{self.path}: {RESIDUAL_PACKED}nis")
                self.nis_dof = unpack(c.attachments[RESIDUAL_PACKED + "nis_dof"],
                                      f"{self.path}: {RESIDUAL_PACKED}nis_dof").astype(float)
            except (KeyError, ValueError) as exc:
                raise CdgpsError(f"{self.path}: damaged residual arrays ({RESIDUAL_PACKED}*): {exc}") from None
            if self.nis.shape != (N,) or self.nis_dof.shape != (N,):
                raise CdgpsError(f"{self.path}: {self.nis.size} NIS value(s) for {N} epoch(s) (damaged file)")
            return
        res = read_mcap(self.path, topics=[RESIDUAL_TOPIC]).topics.get(RESIDUAL_TOPIC)
        if len(res or ()) != N:
            raise CdgpsError(f"{self.path}: {len(res or ())} {RESIDUAL_TOPIC} message(s) for {N} epoch(s); "
                             f"'cdgps estimate' writes one per epoch (damaged file)")
        # NIS is left out of a message without one (the window's epochs): all of them on a run that is
        # one INIT window, so the column may be missing altogether
        nis = res.scalars.get("nis") or [None] * len(res.scalars["nis_dof"])
        self.nis = np.array([np.nan if v is None else v for v in nis], dtype=float)
        self.nis_dof = np.asarray(res.scalars["nis_dof"], dtype=float)


def _num(v) -> float:
    return float("nan") if v is None else v
