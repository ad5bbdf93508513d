"""STATES.mcap (output of ``cdgps estimate``), any kind of estimate: the one writer
(:func:`write_states`, of a :class:`cdgps_cli.core.records.StateSeries`) and the one reader
(:class:`States`).  No numerics here: the stage functions that build the record — a structure's
modal states (pseudolite or GNSS run) in :mod:`cdgps_cli.pipeline.estimate_outputs`, GNSS
displacement states in :mod:`cdgps_cli.pipeline.gnss` — and CSV export and evaluation are in
:mod:`cdgps_cli.pipeline`.

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

Attachments: ``states.json`` (kind, coordinate names and units, the sizes of the state blocks,
the series), the output map C of q = C ξ (``arrays/output_map``), the packed arrays, ``init.json``,
and ``config.toml`` for a structure (``gnss_config.toml`` for GNSS displacement states).  Metadata
``cdgps.estimate``: RUN and INIT sha256, options, final biases, ``covariance``,
``json_channels_every_epochs`` (``kind = gnss`` for displacement states).  Files of the earlier
layouts are still read: without ``states.json`` (the description then comes from ``config.toml``,
which a GNSS estimate wrote as a structure-form displacement model), with ``.npy`` attachments and
every epoch in JSON, or JSON messages only.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from cdgps_cli.core import progress
from cdgps_cli.config.options import STATES_CHUNK_EPOCHS
from cdgps_cli.config.structure import StructureConfig, parse_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.records import CoordinateModel, Series, StateSeries
from cdgps_cli.io.states_layout import (COVARIANCE_CHOICES, DEFAULT_COVARIANCE, DEFAULT_PREVIEW_RATE_HZ,
                                        OUTPUT_MAP_PACKED, PACKED_PREFIX, RESIDUAL_PACKED, SERIES_ATTACHMENT,
                                        STATE_DELTA, STATES_FORMAT, STATES_KINDS)
from cdgps_cli.io.foxglove_schema import scene_update_schema
from cdgps_cli.io.mcap import (NULLABLE, CONFIG_ATTACHMENT, McapOut, Slot, array_schema, message_schema,
                               read_mcap, read_span, time_ns)

STATE_TOPIC = "/cdgps/state"
STATE_FILTERED_TOPIC = "/cdgps/state_filtered"
RESIDUAL_TOPIC = "/cdgps/residuals"
EVENT_TOPIC = "/cdgps/events"
INIT_ATTACHMENT = "init.json"
#: the STATES attachment listing every INIT of a GNSS estimate made from several (their file, window, sha256 and text)
INIT_WINDOWS_ATTACHMENT = "init_windows.json"
ESTIMATE_METADATA = "cdgps.estimate"
ANGLES_TOPIC = "/cdgps/angles_deg"
SCENE_TOPIC = "/cdgps/scene"
"""The structure drawn in 3-D (``foxglove.SceneUpdate``), one message per preview epoch."""
SCENE_FIXED_TOPIC = "/cdgps/scene_fixed"
"""The transmitters drawn in 3-D (``foxglove.SceneUpdate``), one message at the first epoch."""


def _state_schema(names, with_P: bool, with_rates: bool, nullable: bool, structure: bool = True) -> dict:
    obj = {"type": "object", "properties": {n: {"type": "number"} for n in names}}
    arrays = {"xi": NULLABLE if nullable else "number", **({"xidot": "number"} if with_rates else {}),
              **({"P_xi": "number"} if with_P else {})}
    s = array_schema("cdgps.StructureState" if with_rates and structure else "cdgps.DisplacementState", arrays,
                     {"smoothed": "boolean"})
    s["properties"]["q"] = dict(obj, description="generalized coordinates (m or rad)" if with_rates and structure
                                else "displacement from the nominal position, m (E, N, U per rover); a coordinate "
                                "without a solution at this epoch is left out")
    if with_rates and not structure:
        s["properties"]["xidot"]["description"] = "velocity of each displacement, m/s (constant-velocity model)"
    s["properties"]["sigma_q"] = dict(obj, description="1-sigma of q")
    return s


RESIDUAL_SCHEMA = array_schema("cdgps.Residuals", {"antenna": "string", "transmitter": "string", "residual_m": "number"},
                               {"nis": NULLABLE, "nis_dof": "integer"})
_RESIDUAL_BOUNDS_SCHEMA = array_schema("cdgps.Residuals", {"antenna": "string", "transmitter": "string",
                                                           "residual_m": "number"},
                                       {"nis": NULLABLE, "nis_dof": "integer", "nis_lower95": NULLABLE,
                                        "nis_upper95": NULLABLE})
for _k in ("nis_lower95", "nis_upper95"):
    _RESIDUAL_BOUNDS_SCHEMA["properties"][_k]["description"] = (
        f"{'2.5' if _k == 'nis_lower95' else '97.5'} % point of chi-square(nis_dof): the NIS's two-sided 95 % "
        "interval; left out where there is no NIS")
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


def _write_angles(out: McapOut, C: np.ndarray, angles, time_s, q: np.ndarray, P_pos: np.ndarray) -> None:
    """The :data:`ANGLES_TOPIC` messages: section angles and their 1-sigma, degrees.

    ``angles``: list of (name, expression, coefficients (n_q,)) as
    :func:`cdgps_cli.model.kinematics.section_angles` gives them (empty: no channel); ``C``: the
    output map (n_q, n_pos), so an angle's variance is a C P_pos Cᵀ aᵀ."""
    if not angles:
        return
    A = np.array([c for _, _, c in angles])                   # (n_angles, n_q)
    AU = A @ C                                                # (n_angles, n_pos)
    names = [n for n, _, _ in angles]
    sig_names = ["sigma_" + n for n in names]
    ch = out.channel(ANGLES_TOPIC, _angles_schema(angles),
                     {"units": "deg", "angles": json.dumps({n: e for n, e, _ in angles})})
    layout = [(k, None) for k in names + sig_names]
    times = np.asarray(time_s, dtype=float)
    for a in range(0, times.size, 1024):                      # blocks: no full-length temporaries
        b = min(a + 1024, times.size)
        deg = np.degrees(q[a:b] @ A.T)
        var = np.einsum("ai,nij,aj->na", AU, P_pos[a:b], AU)
        out.write_rows(ch, times[a:b], layout, np.hstack([deg, np.degrees(np.sqrt(np.maximum(var, 0.0)))]))


def _write_scene(out: McapOut, scene, time_s, q: np.ndarray, block: int = 64) -> int:
    """The :data:`SCENE_TOPIC` messages at the preview epochs ``time_s`` from the coordinates ``q``
    there (k, n_q), and the :data:`SCENE_FIXED_TOPIC` message at the first; returns how many.

    ``scene`` (:class:`cdgps_cli.analysis.scene.StructureScene` or the same methods) builds the
    message dicts: ``updates(q_block, stamps_ns, time_s_block)`` (None where nothing is drawn), ``fixed(stamp_ns)``
    (None: no such channel) and ``metadata`` (the channel metadata)."""
    times = np.asarray(time_s, dtype=float).tolist()
    if scene is None or not times:
        return 0
    schema = scene_update_schema()
    ns = [time_ns(t, out.time_scale) for t in times]
    fixed = scene.fixed(ns[0])
    if fixed is not None:
        out.write_raw(out.channel(SCENE_FIXED_TOPIC, schema, dict(scene.metadata)), times[0], fixed)
    ch = out.channel(SCENE_TOPIC, schema, dict(scene.metadata))
    if getattr(scene, "satellites", None) is None and hasattr(scene, "skeleton"):
        return _write_scene_rows(out, ch, scene, times, q)
    n = 0
    for a in range(0, len(times), block):          # small blocks: a message is ~10 kB of Python objects
        for t, msg in zip(times[a:a + block], scene.updates(q[a:a + block], ns[a:a + block], times[a:a + block])):
            if msg is not None:
                out.write_raw(ch, t, msg)
                n += 1
    return n


def _write_scene_rows(out: McapOut, ch: int, scene, times: list, q: np.ndarray, block: int = 1024) -> int:
    """The :data:`SCENE_TOPIC` messages of a scene without satellites from its one ``skeleton`` and
    the ``rows`` of numbers (the bytes of ``write_raw`` of its ``updates``; epochs not drawn left out)."""
    skeleton = scene.skeleton(Slot)
    t = np.asarray(times, dtype=float)
    n = 0
    for a in range(0, len(t), block):
        vals, ok = scene.rows(q[a:a + block])
        out.write_skeleton(ch, t[a:a + block][ok], skeleton, vals[ok])
        n += int(np.count_nonzero(ok))
    return n


def _is_identity(C: np.ndarray) -> bool:
    return C.shape[0] == C.shape[1] and np.array_equal(C, np.eye(C.shape[0]))


def coordinate_sigma(C: np.ndarray, P_pos: np.ndarray, block: int = 1024) -> np.ndarray:
    """1-σ of q = C x_pos from the position covariances (N, n_pos, n_pos) → (N, n_q).

    ``C``: the output map (n_q, n_pos) (a structure's mode shapes U).  σ_q² = Σ_ij C_qi C_qj P_ij
    is one matrix product per block of ``block`` epochs, P's rows (flattened) times the
    (n_pos², n_q) matrix of the products C_qi C_qj; each block is copied to a contiguous array
    first, so the numbers do not depend on the memory layout of ``P_pos`` (a strided view of the
    filter's (N, n, n) series or a contiguous array read back) and there is no full-size temporary.
    With C = I the diagonal itself (NaN where a displacement has no covariance)."""
    C = np.array(C, dtype=float, order="C")           # a fresh array: the products do not depend on where C came from
    if _is_identity(C):
        return np.sqrt(np.maximum(np.einsum("nii->ni", np.asarray(P_pos, dtype=float)), 0.0))
    nq, m = C.shape
    K = np.ascontiguousarray((C[:, :, None] * C[:, None, :]).reshape(nq, m * m).T)     # (m², n_q)
    out = np.empty((P_pos.shape[0], nq))
    for a in range(0, P_pos.shape[0], block):
        Pb = np.ascontiguousarray(P_pos[a:a + block], dtype=float).reshape(-1, m * m)
        out[a:a + block] = np.sqrt(np.maximum(Pb @ K, 0.0))
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


def series_derived(C: np.ndarray, x_pos: np.ndarray, P_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q = x_pos Cᵀ (N, n_q) and its 1-σ (N, n_q) from x_pos (N, n_pos) and P_pos (N, n_pos, n_pos):
    what the writer puts in the JSON channels and the reader returns (the same function on the same
    arrays)."""
    return series_q(C, x_pos), coordinate_sigma(C, P_pos)


def series_q(C: np.ndarray, x_pos: np.ndarray) -> np.ndarray:
    """q = x_pos Cᵀ (N, n_q) from x_pos (N, n_pos); with C = I a copy of x_pos (NaN stays in its own
    coordinate)."""
    C = np.asarray(C, dtype=float)
    if _is_identity(C):
        return np.array(x_pos, dtype=float)
    return np.ascontiguousarray(x_pos, dtype=float) @ C.T


def rows_q(C: np.ndarray, x_pos: np.ndarray) -> np.ndarray:
    """q = x_pos Cᵀ (k, n_q) computed row by row in a fixed order (:func:`cdgps_cli.core.rowmath.rows_matmul`),
    so a chunk of epochs gives the same bits as the whole record; with C = I a copy of x_pos."""
    from cdgps_cli.core.rowmath import rows_matmul  # noqa: PLC0415

    C = np.asarray(C, dtype=float)
    if _is_identity(C):
        return np.array(x_pos, dtype=float)
    return rows_matmul(x_pos, C.T)


def _from_triu(T: np.ndarray, m: int) -> np.ndarray:
    """The symmetric (N, m, m) matrices of their upper triangles (N, m(m+1)/2), row by row (``P_xi_triu``)."""
    i, j = np.triu_indices(m)
    if T.ndim != 2 or T.shape[1] != i.size:
        raise ValueError(f"P_xi_triu of shape {list(T.shape)}: expected (N, {i.size}) for {m} modes")
    P = np.empty((T.shape[0], m, m))
    P[:, i, j] = T
    P[:, j, i] = T
    return P


def _block(arr, a: int, b: int) -> np.ndarray:
    """Rows a … b−1 of ``arr`` as a copy; when ``arr`` is on disk (an array of
    :class:`cdgps_cli.io.scratch.DiskHistory`), the pages they came from are dropped from memory
    after (their values stay in the file), so reading a record costs the memory of a block."""
    from cdgps_cli.io.scratch import DiskHistory  # noqa: PLC0415

    rows = np.array(arr[a:b])
    DiskHistory.release(arr, a, b)
    return rows


class _LazyRows:
    """A series (N, ...) given block by block: ``shape`` and row slices ``[a:b]`` (what
    :func:`cdgps_cli.analysis.preview.anti_alias_decimate` reads).  ``block(c)`` makes the rows
    c·K … (c+1)·K−1 (K = ``chunk``); the last two blocks made are kept, so the preview filter's
    overlapping windows do not make a block twice in a row."""

    def __init__(self, shape: tuple, chunk: int, block):
        self.shape, self.chunk, self._block, self._kept = tuple(shape), chunk, block, {}

    def rows_of(self, c: int) -> np.ndarray:
        if c not in self._kept:
            if len(self._kept) >= 2:
                self._kept.pop(min(self._kept))
            self._kept[c] = self._block(c)
        return self._kept[c]

    def __getitem__(self, s: slice) -> np.ndarray:
        a, b, _ = s.indices(self.shape[0])
        if b <= a:
            return np.empty((0,) + self.shape[1:])
        K = self.chunk
        return np.concatenate([self.rows_of(c)[max(a - c * K, 0):b - c * K] for c in range(a // K, (b - 1) // K + 1)])


def _chunk_of(chunk_epochs: int) -> int:
    """Epochs per block of the streaming writer: a whole number of :data:`_PRODUCT_BLOCK` (q and σ_q
    are computed on the same 1024-epoch blocks however the record is cut: the same bits)."""
    return max(-(-int(chunk_epochs) // _PRODUCT_BLOCK), 1) * _PRODUCT_BLOCK


_PRODUCT_BLOCK = 1024


def _any_nan(x, npos: int, chunk: int) -> bool:
    """Any NaN among the positions ξ (the first npos columns of x, (N, n)) (read in blocks)."""
    return any(bool(np.isnan(_block(x, a, a + chunk)[:, :npos]).any()) for a in range(0, x.shape[0], chunk))


def _symmetric(P, npos: int, chunk: int) -> bool:
    """Every P_ξ (the leading npos × npos block of P, (N, n, n)) exactly symmetric (read in blocks)."""
    i, j = np.triu_indices(npos)
    for a in range(0, P.shape[0], chunk):
        Pb = _block(P[:, :npos, :npos], a, a + chunk)
        if not (Pb[:, i, j] == Pb[:, j, i]).all():
            return False
    return True


class _SeriesPass:
    """One state series read once, block by block: its packed arrays (:class:`PackedWriter`, the
    bytes of the whole-array packing) and what the JSON channels need at the kept epochs ``sel``
    (σ_q, P_ξ), so nothing of the record's length is held beyond the kept epochs."""

    def __init__(self, ss: StateSeries, ser: Series, topic: str, C: np.ndarray, sel: np.ndarray, chunk: int,
                 with_P_pos: bool, full: bool, want_P_sel: bool):
        from cdgps_cli.io.packed_arrays import PackedWriter  # noqa: PLC0415

        npos, N = ss.n_pos, len(ser.time_s)
        self.key = f"{PACKED_PREFIX}{topic}/"
        self.order: list = []                         # (name, PackedWriter) in the whole-record writer's order

        def packer(name, tail, dtype, delta=0):
            w = PackedWriter((N,) + tuple(tail), dtype, delta)
            self.order.append((self.key + name, w))
            return w

        extra = {k: np.asarray(v) for k, v in sorted(ser.extra.items())}
        p_t = packer("time_s", (), np.float64)
        p_xi = packer("xi", (npos,), ser.x.dtype, STATE_DELTA)
        rates = (ss.n_rate and ser.x.shape[1] >= npos + ss.n_rate       # (a series of positions only: none)
                 and (full or ss.kind == "displacement"))                # a displacement's velocity: always
        p_xd = packer("xidot", (ss.n_rate,), ser.x.dtype, STATE_DELTA) if rates else None
        p_sxd = packer("sigma_xidot", (ss.n_rate,), np.float64, STATE_DELTA) if rates and not full else None
        p_ex = {k: packer(k, v.shape[1:], v.dtype) for k, v in extra.items()}
        p_P = packer("P", ser.P.shape[1:], ser.P.dtype, STATE_DELTA) if full and ser.P.shape[1] > npos else None
        triu = with_P_pos and _symmetric(ser.P, npos, chunk)
        i, j = np.triu_indices(npos)
        if not with_P_pos:
            p_cov = packer("sigma_q", (C.shape[0],), np.float64, STATE_DELTA)
        elif triu:
            p_cov = packer("P_xi_triu", (i.size,), ser.P.dtype, STATE_DELTA)
        else:
            p_cov = packer("P_xi", (npos, npos), ser.P.dtype, STATE_DELTA)
        nq = C.shape[0]
        self.sq_sel = np.empty((len(sel), nq))
        self.P_sel = np.empty((len(sel), npos, npos)) if want_P_sel else None
        time_s = np.asarray(ser.time_s, dtype=float)
        for a in range(0, N, chunk):
            b = min(a + chunk, N)
            X = _block(ser.x, a, b)
            P = _block(ser.P, a, b) if p_P is not None else None          # (the whole P: --covariance full)
            P_pos = P[:, :npos, :npos] if P is not None else _block(ser.P[:, :npos, :npos], a, b)
            p_t.add(time_s[a:b])
            p_xi.add(X[:, :npos])
            if p_xd is not None:
                p_xd.add(X[:, npos:npos + ss.n_rate])
            if p_sxd is not None:
                r = slice(npos, npos + ss.n_rate)
                p_sxd.add(np.sqrt(np.einsum("kii->ki", _block(ser.P, a, b)[:, r, r])))
            for k, w in p_ex.items():
                w.add(_block(extra[k], a, b))
            if p_P is not None:
                p_P.add(P)
            sq = coordinate_sigma(C, P_pos)
            if not with_P_pos:
                p_cov.add(sq)
            else:
                p_cov.add(P_pos[:, i, j] if triu else P_pos)
            s = slice(np.searchsorted(sel, a), np.searchsorted(sel, b))
            self.sq_sel[s] = sq[sel[s] - a]
            if self.P_sel is not None:
                self.P_sel[s] = P_pos[sel[s] - a]

    def attach(self, out: McapOut) -> None:
        """The packed arrays, in order (each streamed from its temporary file)."""
        from cdgps_cli.io.packed_arrays import MEDIA_TYPE  # noqa: PLC0415

        for name, w in self.order:
            size, pieces = w.finish()
            out.attach_stream(name, size, pieces, MEDIA_TYPE)
        self.order = []

    def close(self) -> None:
        for _, w in self.order:
            w.close()


def _series_rows(ser: Series, C: np.ndarray, npos: int, nrate: int, chunk: int):
    """The lazy q (N, n_q) and motion ξ, ξ̇ (N, npos + nrate) of a series for the preview."""
    N = len(ser.time_s)

    def q_block(c):
        X = _block(ser.x, c * chunk, (c + 1) * chunk)[:, :npos]
        return np.concatenate([series_q(C, X[a:a + _PRODUCT_BLOCK]) for a in range(0, X.shape[0], _PRODUCT_BLOCK)]) \
            if X.shape[0] else np.empty((0, C.shape[0]))

    def x_block(c):
        return _block(ser.x, c * chunk, (c + 1) * chunk)[:, :npos + nrate]

    return _LazyRows((N, C.shape[0]), chunk, q_block), _LazyRows((N, npos + nrate), chunk, x_block)


def _write_state_messages(out: McapOut, ch: int, names, times, q, sq, X, P_sel, npos: int, nrate: int,
                          smoothed: bool) -> None:
    """The Foxglove JSON messages of one state series at the kept epochs: their times, coordinates
    ``q``, σ_q ``sq``, motion ``X`` (ξ, ξ̇; anti-aliased by :func:`write_states`'s ``preview``) and,
    with ``--covariance full``, P_ξ ``P_sel``."""
    with_P = P_sel is not None
    blocks = [q, sq, X[:, :npos]] + ([X[:, npos:npos + nrate]] if nrate else []) + \
        ([P_sel.reshape(len(times), -1)] if with_P else [])
    layout = [("q", list(names)), ("sigma_q", list(names)), ("xi", npos)] + ([("xidot", nrate)] if nrate else []) + \
        ([("P_xi", npos * npos)] if with_P else [])
    out.write_rows(ch, times, layout, np.hstack(blocks), {"smoothed": smoothed})


def _write_residuals(out: McapOut, ss: StateSeries, time_s, sel, chunk: int, nis_bounds=None) -> None:
    """Residuals, NIS and dof: every epoch packed (streamed), the JSON channel at the epochs ``sel`` (with
    the NIS's 95 % bounds when ``nis_bounds`` is given, see :func:`write_states`)."""
    from cdgps_cli.io.packed_arrays import MEDIA_TYPE, PackedWriter  # noqa: PLC0415

    # float32 (7 significant digits: nm on cm-level residuals) keeps the file within its RUN's size;
    # the JSON messages carry the float64 values
    N = len(time_s)
    res = ss.residual_m
    p_r = PackedWriter((N,) + tuple(res.shape[1:]), np.float32)
    R = np.empty((len(sel),) + tuple(res.shape[1:]))
    for a in range(0, N, chunk):
        rows = _block(res, a, a + chunk)
        p_r.add(rows.astype(np.float32))
        s = slice(np.searchsorted(sel, a), np.searchsorted(sel, a + chunk))
        R[s] = np.asarray(rows, dtype=float)[sel[s] - a]
    nis_all = np.asarray(ss.nis, dtype=float)
    dof_all = np.asarray(ss.nis_dof, dtype=np.int64)
    out.attach(RESIDUAL_PACKED + "channels.json", json.dumps([list(c) for c in ss.residual_channels]).encode(),
               "application/json")
    ch = out.channel(RESIDUAL_TOPIC, RESIDUAL_SCHEMA if nis_bounds is None else _RESIDUAL_BOUNDS_SCHEMA)
    ants = [c[0] for c in ss.residual_channels]
    txs = [c[1] for c in ss.residual_channels]
    used = ~np.isnan(R)
    nis = nis_all[sel]
    dof = [int(d) for d in dof_all[sel].tolist()]
    bounds = None
    if nis_bounds is not None:
        lo, hi = nis_bounds(dof_all[sel])
        has = ~np.isnan(nis) & (np.asarray(dof) > 0)
        bounds = [None if not h else (a, b) for h, a, b in zip(has.tolist(), np.asarray(lo, dtype=float).tolist(),
                                                               np.asarray(hi, dtype=float).tolist())]
    times = np.asarray(time_s, dtype=float)[sel]
    # epochs using every channel: one template (the channel names once), NIS and bounds as numbers (NaN: left out)
    layout = [("residual_m", len(ants)), ("nis", None), ("nis_dof", "int")]
    cols = [nis[:, None], np.asarray(dof, dtype=float)[:, None]]
    if bounds is not None:
        layout += [("nis_lower95", None), ("nis_upper95", None)]
        cols.append(np.array([b if b is not None else (np.nan, np.nan) for b in bounds], dtype=float).reshape(-1, 2))
    _write_residual_runs(out, ch, times, layout, R, np.hstack(cols), used, ants, txs)
    size, pieces = p_r.finish()
    out.attach_stream(RESIDUAL_PACKED + "residual_m", size, pieces, MEDIA_TYPE)
    out.attach_packed(RESIDUAL_PACKED + "nis", nis_all)
    out.attach_packed(RESIDUAL_PACKED + "nis_dof", dof_all)


def _write_residual_runs(out: McapOut, ch: int, times, layout, R, rest, used, ants, txs) -> None:
    """The residual messages, a run of epochs using the same channels at a time (one
    :meth:`McapOut.write_rows <cdgps_cli.io.mcap.McapOut.write_rows>` each: one template, no dict
    per message).  ``R`` (k, C): the residuals of every channel; ``rest`` (k, …) the other fields of
    ``layout``; ``used`` (k, C): the channels with a residual.  Each message is what
    :meth:`McapOut.write` gives for the payload of the used channels only (``antenna``,
    ``transmitter``, ``residual_m``, then the NIS fields, a NaN one left out), as it was written
    epoch by epoch before (``tests/io/test_states_residual_runs.py``)."""
    n_ch = used.shape[1]
    k = len(times)
    change = np.flatnonzero((used[1:] != used[:-1]).any(axis=1)) + 1 if k > 1 else np.empty(0, dtype=np.int64)
    cuts = [0, *change.tolist(), k] if k else [0]
    for a, b in zip(cuts[:-1], cuts[1:]):              # runs of epochs alike
        idx = np.flatnonzero(used[a])
        if idx.size == n_ch:
            out.write_rows(ch, times[a:b], layout, np.hstack([R[a:b], rest[a:b]]),
                           head={"antenna": ants, "transmitter": txs})
            continue
        picked = idx.tolist()
        run_layout = [("residual_m", idx.size)] + layout[1:]
        out.write_rows(ch, times[a:b], run_layout, np.hstack([R[a:b, idx], rest[a:b]]),
                       head={"antenna": [ants[j] for j in picked], "transmitter": [txs[j] for j in picked]})


def _description(ss: StateSeries) -> bytes:
    """The :data:`SERIES_ATTACHMENT` of ``ss`` (what the reader needs besides the arrays)."""
    return json.dumps({
        "format": STATES_FORMAT, "kind": ss.kind, "coord_names": list(ss.coord_names),
        "coord_units": list(ss.coord_units), "n_pos": ss.n_pos, "n_rate": int(ss.n_rate),
        "wavelength_m": float(ss.wavelength_m),
        "series": {t: {"smoothed": bool(v.smoothed), "extra": sorted(v.extra), "messages": bool(v.messages)}
                   for t, v in ss.series.items()},
    }, sort_keys=True, indent=1).encode()


def provenance(run_path: str | Path, init_text: str, run_sha256: str | None = None) -> dict:
    """The RUN and INIT part of the ``cdgps.estimate`` metadata: file name and sha256 of each
    (``run_sha256``: the RUN's, when the caller has already hashed it)."""
    if not run_sha256:
        from cdgps_cli.io.atomic import file_sha256  # noqa: PLC0415

        run_sha256 = file_sha256(run_path)          # (in blocks: a day's RUN is not read into memory)
    return {"run": Path(run_path).name, "run_sha256": run_sha256,
            "init_sha256": hashlib.sha256(init_text.encode()).hexdigest()}


def write_states(ss: StateSeries, out_path: str | Path, metadata: dict, attachments: dict, *,
                 time_scale: str = "relative", covariance: str = DEFAULT_COVARIANCE,
                 preview_rate_hz: float = DEFAULT_PREVIEW_RATE_HZ, angles=(), preview=None, scene=None,
                 nis_bounds=None, chunk_epochs: int | None = None) -> dict:
    """Write an estimate of any kind to STATES.mcap atomically; returns a summary.

    The stage functions building ``ss`` are :func:`cdgps_cli.pipeline.estimate_outputs.write_states`
    (a structure, pseudolite or GNSS run) and :func:`cdgps_cli.pipeline.gnss.gnss_estimate`
    (displacements); this module imports no numerics.

    The record is read a block of ``chunk_epochs`` epochs at a time (issue 29): its arrays may be on
    disk (:class:`cdgps_cli.io.scratch.DiskHistory`; the pages of a block are dropped once it is read),
    each packed array is streamed (:class:`cdgps_cli.io.packed_arrays.PackedWriter`) and the JSON
    channels take only their kept epochs, so the memory is that of a block and of the preview, not of
    the record.  The file is the same, byte for byte, as the whole-record writer's
    (``tests/io/test_states_stream.py``).

    Parameters
    ----------
    ss : StateSeries
        The estimate; ``ss.series[STATE_TOPIC]`` is the one reported.  Its arrays are read by row
        slices only (numpy arrays, or arrays on disk).
    out_path : path
    metadata : dict of str to str
        The ``cdgps.estimate`` metadata (provenance, options, final biases, …); the writer adds
        ``covariance``, ``arrays`` and ``json_channels_every_epochs``.
    attachments : dict of str to (bytes, str)
        Further attachments by name: content and media type (``config.toml``, ``init.json``, …).
    time_scale : {"relative", "gps"}
        Time scale of the series' ``time_s`` (:mod:`cdgps_cli.core.timescales`).
    covariance : {"modal", "full"}
        ``"modal"``: the position covariance P_ξ (n_pos×n_pos) per epoch of every series but the
        forward filter of a smoothed run (of it, its 1-σ of q only); ``"full"``: also the rates ξ̇
        of every epoch, the whole state covariance P of every series that has it, P_ξ of every
        series, and P_ξ in the JSON messages.
    preview_rate_hz : float
        Rate of the Foxglove JSON channels, Hz (0: every epoch); see :data:`DEFAULT_PREVIEW_RATE_HZ`.
    angles : list of (str, str, ndarray (n_q,))
        The :data:`ANGLES_TOPIC` channel's angles: name, expression, coefficients (rad per
        coordinate unit); empty: no such channel.
    preview : callable, optional
        ``preview(a, stride) -> a at epochs 0, stride, …`` for the motion in the JSON channels
        (q, ξ, ξ̇ and the angles), e.g. :func:`cdgps_cli.analysis.preview.anti_alias_decimate`
        (low-pass filtered first: no alias of a mode above the preview's Nyquist frequency); ``a``
        is given as an array-like of ``shape`` and row slices (made block by block); default: the
        samples themselves.  Sigmas, covariances and residuals are sampled.
    scene : optional
        Draws the structure in 3-D (:class:`cdgps_cli.analysis.scene.StructureScene`): the
        :data:`SCENE_TOPIC` channel from the preview's coordinates of the estimate (the same
        anti-aliased q as ``/cdgps/state``) and :data:`SCENE_FIXED_TOPIC` (transmitters); None: no
        such channels.
    nis_bounds : callable, optional
        ``nis_bounds(dof (k,)) -> (lower (k,), upper (k,))``: the NIS's two-sided 95 % chi-square
        interval per epoch, written beside ``nis`` in the residual messages as ``nis_lower95`` and
        ``nis_upper95`` (Foxglove plots NIS against its bounds); None: not written.
    chunk_epochs : int, optional
        Epochs read at a time (default :data:`~cdgps_cli.config.options.STATES_CHUNK_EPOCHS`; rounded up
        to a multiple of 1024; the file does not depend on it).
    """
    if covariance not in COVARIANCE_CHOICES:
        raise ValueError(f"covariance {covariance!r}: expected one of {', '.join(COVARIANCE_CHOICES)}")
    est = ss.series[STATE_TOPIC]
    names, C, full = list(ss.coord_names), np.asarray(ss.output_map, dtype=float), covariance == "full"
    chunk = _chunk_of(STATES_CHUNK_EPOCHS if chunk_epochs is None else chunk_epochs)
    time_s = np.asarray(est.time_s, dtype=float)
    stride = preview_stride(time_s, preview_rate_hz)
    sel = np.arange(0, len(time_s), stride)
    meta = dict(metadata, covariance=covariance, arrays="packed (cdgps_cli.io.packed_arrays), every epoch",
                json_channels_every_epochs=str(stride))
    if preview is not None and stride > 1:
        meta["json_channels_filter"] = "low-pass before decimation (cdgps_cli.analysis.preview)"
    npos, nrate = ss.n_pos, ss.n_rate
    with McapOut(out_path, time_scale=time_scale) as out, \
            progress.bar(len(ss.series) + 1, f"writing {Path(out_path).name}", "series") as bar:
        out.pack_in_background()            # (the small arrays: written where the whole-record writer wrote them)
        schema = _state_schema(names, full, nrate > 0, _any_nan(est.x, npos, chunk), ss.kind == "structure")
        for topic, ser in ss.series.items():
            with_P_pos = topic != STATE_FILTERED_TOPIC or full     # the forward filter of a smoothed run: its 1-σ
            sel_t = np.arange(0, len(ser.time_s), stride)
            sp = _SeriesPass(ss, ser, topic, C, sel_t, chunk, with_P_pos, full,
                             want_P_sel=(ser.messages and full) or (topic == STATE_TOPIC and bool(angles)))
            try:
                q_rows, x_rows = _series_rows(ser, C, npos, nrate, chunk)
                q_prev = None      # the preview's coordinates: filtered (or picked) once for the messages and angles
                if ser.messages or (topic == STATE_TOPIC and (angles or scene is not None)):
                    q_prev = _picked(q_rows, sel_t, stride, preview)
                if ser.messages:
                    X = _picked(x_rows, sel_t, stride, preview)
                    _write_state_messages(out, out.channel(topic, schema), names,
                                          np.asarray(ser.time_s, dtype=float)[sel_t], q_prev, sp.sq_sel, X,
                                          sp.P_sel if full else None, npos, nrate, bool(ser.smoothed))
                if topic == STATE_TOPIC:
                    _write_angles(out, C, angles, time_s[sel], q_prev, sp.P_sel)
                    if scene is not None:
                        _write_scene(out, scene, time_s[sel], q_prev)
                sp.attach(out)              # written before the next series: one series' arrays at a time
            finally:
                sp.close()
            bar.update()
        _write_residuals(out, ss, time_s, sel, chunk, nis_bounds)
        out.write_packed()
        bar.update()
        ch = out.channel(EVENT_TOPIC, event_schema(ss.events))
        for ev in ss.events:
            out.write(ch, ev["time_s"], {k: v for k, v in ev.items() if k != "time_s"})
        out.attach(SERIES_ATTACHMENT, _description(ss), "application/json")
        out.attach_packed(OUTPUT_MAP_PACKED, C)
        for name, (data, media) in attachments.items():
            out.attach(name, data, media)
        out.metadata(ESTIMATE_METADATA, meta)
    nis_ok = ss.nis_dof > 0
    return {"output": str(out_path), "epochs": int(len(time_s)), "start_s": float(time_s[0]),
            "end_s": float(time_s[-1]), "smoothed": bool(est.smoothed), "events": len(ss.events),
            "covariance": covariance, "json_channels_every_epochs": stride,
            "mean_nis_per_dof": float(np.nanmean(ss.nis[nis_ok] / ss.nis_dof[nis_ok])) if nis_ok.any() else None,
            "event_list": ss.events}


def _picked(rows: _LazyRows, sel: np.ndarray, stride: int, preview) -> np.ndarray:
    """A lazy series at the kept epochs ``sel``: through ``preview`` (anti-aliased) when the JSON
    channels are decimated, else the samples themselves."""
    if preview is not None and stride > 1:
        return preview(rows, stride)
    out = np.empty((len(sel),) + rows.shape[1:])
    K = rows.chunk
    for c in range(0, -(-rows.shape[0] // K)):
        s = slice(np.searchsorted(sel, c * K), np.searchsorted(sel, (c + 1) * K))
        out[s] = rows.rows_of(c)[sel[s] - c * K]
    return out


def _legacy_description(cfg: StructureConfig, meta: dict) -> dict:
    """The description of a file written before :data:`SERIES_ATTACHMENT` (from its config.toml:
    a structure's own, or the displacement model a GNSS estimate wrote in the structure form)."""
    names = list(cfg.coord_names)
    if meta.get("kind") == "gnss":
        return {"kind": "displacement", "coord_names": names, "coord_units": ["m"] * len(names),
                "n_pos": len(names), "n_rate": 0, "wavelength_m": cfg.wavelength_m, "output_map": np.eye(len(names))}
    return {"kind": "structure", "coord_names": names, "coord_units": [cfg.coord_unit(n) for n in names],
            "n_pos": cfg.n_modes, "n_rate": cfg.n_modes, "wavelength_m": cfg.wavelength_m,
            "output_map": np.asarray(cfg.mode_shapes, dtype=float)}


class States:
    """A STATES.mcap of any kind read back: coordinates, times, q, sigma_q, states, covariances, events.

    Attributes
    ----------
    kind : {"structure", "displacement"}
    cfg : StructureConfig or None
        The structure config (None for GNSS displacement states).
    coord_names, coord_units : list of str (n_q,)
    output_map : (n_q, n_pos) — q = C ξ; n_pos : int; wavelength_m : float (m)
    time_s : (N,) s
    q, sigma_q : (N, n_q) coordinate units (m or rad)
    xi : (N, n_pos); xidot : (N, n_rate) or None (no rates: a structure's files written without
        ``--covariance full`` since 2026-12-03, or before the packed arrays; GNSS displacements but those of
        the constant-velocity model, whose velocities are the rates, m/s)
    sigma_xidot : (N, n_rate) or None — 1σ of the rates (a constant-velocity displacement's, without
        ``--covariance full``; with it, from P)
    P_xi : (N, n_pos, n_pos) or None (the forward filter of a smoothed run, unless ``--covariance full``)
    P : (N, n, n) or None (only with ``--covariance full``)
    extra : dict of str to ndarray (N, ...) — the series' further arrays (e.g. ``n_sat``, ``pdop``)
    nis, nis_dof : (N,) or None (``diagnostics=False``)
    events : list of dict; metadata : dict (``cdgps.estimate``)
    """

    def __init__(self, path: str | Path, topic: str = STATE_TOPIC, diagnostics: bool = True):
        c = read_mcap(path, topics=[EVENT_TOPIC] if diagnostics else [])
        self.path = str(path)
        if "cdgps.ingest" in c.metadata:
            raise CdgpsError(f"{path}: this is a RUN.mcap (from 'cdgps ingest'), not a STATES.mcap from 'cdgps estimate'")
        if CONFIG_ATTACHMENT not in c.attachments and SERIES_ATTACHMENT not in c.attachments:
            raise CdgpsError(f"{path}: no {SERIES_ATTACHMENT} or config attachment; is this a STATES.mcap from "
                             f"'cdgps estimate'?")
        what = "STATES.mcap from 'cdgps estimate'"
        self.metadata = c.require_metadata(ESTIMATE_METADATA, what)
        if diagnostics:
            c.require_channels(RESIDUAL_TOPIC, EVENT_TOPIC, what=what)
        self._describe(c.attachments)
        self.xidot = self.sigma_xidot = self.P = None
        self.extra = {}
        key = f"{PACKED_PREFIX}{topic}/"
        if key + "time_s" in c.attachments:                # packed arrays (every epoch)
            self._read_packed(c.attachments, key, topic)
        elif key + "time_s.npy" in c.attachments:        # .npy attachments (older files)
            self._read_npy(c.attachments, key)
        else:                                             # messages only (oldest files)
            self._read_messages(topic)
        self.nis = self.nis_dof = None
        if diagnostics and topic in (STATE_TOPIC, STATE_FILTERED_TOPIC):    # (not the single-epoch solutions)
            self._read_diagnostics(c)
        ev = c.topics.get(EVENT_TOPIC)
        self.events = []
        if ev:
            for i, t in enumerate(ev.times()):
                self.events.append({"time_s": float(t), **{k: ev.scalars[k][i] for k in ev.scalars if k != "time_s"}})

    @property
    def config_name(self) -> str:
        """Name of the config the estimate was made with (the structure's, or the GNSS run's)."""
        return self.cfg.name if self.cfg is not None else self.metadata.get("config_name", "")

    @property
    def config_sha256(self) -> str:
        return self.cfg.sha256 if self.cfg is not None else self.metadata.get("config_sha256", "")

    def coordinate_model(self):
        """The structure config, or for states without one (GNSS displacements) their
        :class:`~cdgps_cli.core.records.CoordinateModel` (names and units, no modes, no gyros)."""
        if self.cfg is not None:
            return self.cfg
        return CoordinateModel(self.config_name, self.config_sha256, tuple(self.coord_names), tuple(self.coord_units))

    def _describe(self, att: dict) -> None:
        """kind, cfg, coordinates, output map and wavelength, from the description or the config."""
        cfg = None
        if CONFIG_ATTACHMENT in att:
            cfg = parse_config(att[CONFIG_ATTACHMENT].decode(), f"{self.path}:{CONFIG_ATTACHMENT}")
        if SERIES_ATTACHMENT in att:
            from cdgps_cli.io.packed_arrays import unpack  # noqa: PLC0415

            try:
                d = json.loads(att[SERIES_ATTACHMENT])
                d["output_map"] = unpack(att[OUTPUT_MAP_PACKED], f"{self.path}: {OUTPUT_MAP_PACKED}")
                if d["output_map"].shape != (len(d["coord_names"]), d["n_pos"]) or d["kind"] not in STATES_KINDS:
                    raise ValueError(f"output map of shape {list(d['output_map'].shape)} for {len(d['coord_names'])} "
                                     f"coordinates and {d['n_pos']} positions, kind {d['kind']!r}")
            except (KeyError, TypeError, ValueError) as exc:
                raise CdgpsError(f"{self.path}: damaged {SERIES_ATTACHMENT} / {OUTPUT_MAP_PACKED}: {exc}") from None
        else:
            d = _legacy_description(cfg, self.metadata)
        self.kind = d["kind"]
        self.cfg = cfg if self.kind == "structure" else None
        self.coord_names, self.coord_units = list(d["coord_names"]), list(d["coord_units"])
        self.output_map, self.n_pos, self.n_rate = d["output_map"], int(d["n_pos"]), int(d["n_rate"])
        self.wavelength_m = float(d["wavelength_m"])
        self._series = d.get("series", {})

    def require_structure(self, what: str) -> StructureConfig:
        """The structure config, or a CdgpsError saying ``what`` needs a structure's STATES."""
        if self.cfg is None:
            raise CdgpsError(f"{self.path}: {what} needs the STATES.mcap of a structure (modal states); this one "
                             f"holds {self.kind} states ({', '.join(self.coord_names)})")
        return self.cfg

    def _read_packed(self, att: dict, key: str, topic: str) -> None:
        from cdgps_cli.io.packed_arrays import unpack  # noqa: PLC0415

        npos = self.n_pos

        def get(name):
            return unpack(att[key + name], f"{self.path}: {key}{name}")
        try:
            self.time_s = get("time_s").astype(float, copy=False)
            N = self.time_s.shape[0]
            self.xi = get("xi").reshape(N, npos)
            if key + "xidot" in att:
                self.xidot = get("xidot").reshape(N, -1)
            if key + "sigma_xidot" in att:
                self.sigma_xidot = get("sigma_xidot").reshape(N, -1)
            self.P_xi = sigma_q = None
            if key + "P_xi_triu" in att:
                self.P_xi = _from_triu(get("P_xi_triu"), npos)
            elif key + "P_xi" in att:
                self.P_xi = get("P_xi").reshape(N, npos, npos)
            else:                                         # a forward filter stored with its 1-σ only
                sigma_q = get("sigma_q").reshape(N, -1)
            if key + "P" in att:
                self.P = get("P")
                if self.P.ndim != 3 or self.P.shape[0] != N:
                    raise ValueError(f"P of shape {list(self.P.shape)} for {N} epochs")
            for name in self._series.get(topic, {}).get("extra", []):
                self.extra[name] = get(name)
                if self.extra[name].shape[:1] != (N,):
                    raise ValueError(f"{name} of shape {list(self.extra[name].shape)} for {N} epochs")
        except (KeyError, ValueError) as exc:
            raise CdgpsError(f"{self.path}: damaged state arrays ({key}*): {exc}") from None
        if self.time_s.ndim != 1:
            raise CdgpsError(f"{self.path}: damaged state arrays ({key}time_s of shape {list(self.time_s.shape)})")
        if self.P_xi is None:
            self.q, self.sigma_q = series_q(self.output_map, self.xi), sigma_q
        else:
            self.q, self.sigma_q = series_derived(self.output_map, self.xi, self.P_xi)

    def _read_npy(self, att: dict, key: str) -> None:
        try:
            self.time_s = _npy_load(att[key + "time_s.npy"])
            self.q = _npy_load(att[key + "q.npy"])
            self.sigma_q = _npy_load(att[key + "sigma_q.npy"])
            self.xi = _npy_load(att[key + "xi.npy"])
            self.P_xi = _npy_load(att[key + "P_xi.npy"])
            for name in sorted(att):                      # a GNSS run's kinematic n_sat, pdop
                stem = name[len(key):-len(".npy")] if name.startswith(key) and name.endswith(".npy") else None
                if stem and stem not in ("time_s", "q", "sigma_q", "xi", "P_xi"):
                    self.extra[stem] = _npy_load(att[name])
        except (KeyError, ValueError, OSError) as exc:
            raise CdgpsError(f"{self.path}: damaged state arrays attachment: {exc}") from None

    def _read_messages(self, topic: str) -> None:
        tc = read_mcap(self.path, topics=[topic]).topics.get(topic)
        if tc is None:
            raise CdgpsError(f"{self.path}: no {topic} messages; is this a STATES.mcap from 'cdgps estimate'?")
        nm = self.n_pos
        self.time_s = tc.times()
        names = list(self.coord_names)
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


def diagnostics(path: str | Path, n_epochs: int) -> tuple:
    """``(nis (N,), nis_dof (N,) float, events)`` of a STATES.mcap, as :class:`States` reads them,
    without loading its state arrays (only the NIS attachments and the event messages are read)."""
    keep = (RESIDUAL_PACKED + "nis", RESIDUAL_PACKED + "nis_dof")
    c = read_mcap(path, topics=[EVENT_TOPIC], attachments=lambda name: name in keep)
    if keep[0] not in c.attachments:                     # (older files: from the residual messages)
        st = States(path)
        return st.nis, st.nis_dof, st.events
    c.require_channels(RESIDUAL_TOPIC, EVENT_TOPIC, what="STATES.mcap from 'cdgps estimate'")
    st = States.__new__(States)
    st.path, st.time_s = str(path), np.empty(n_epochs)
    st._read_diagnostics(c)
    ev = c.topics.get(EVENT_TOPIC)
    events = []
    if ev:
        for i, t in enumerate(ev.times()):
            events.append({"time_s": float(t), **{k: ev.scalars[k][i] for k in ev.scalars if k != "time_s"}})
    return st.nis, st.nis_dof, events


def _num(v) -> float:
    return float("nan") if v is None else v


class StatesChunks:
    """A STATES.mcap's description and one state series read in consecutive chunks of epochs.

    The same description as :class:`States` (``kind``, ``cfg``, ``coord_names``, ``coord_units``,
    ``output_map``, ``n_pos``, ``metadata``, :meth:`coordinate_model`), without loading the series:
    the file's integrity is checked as :func:`cdgps_cli.io.mcap.read_mcap` checks it, then only
    ``time_s`` and ``xi`` of ``topic`` are decompressed, in pieces, into unlinked temporary files
    (:class:`cdgps_cli.io.packed_arrays.PackedRows`), so memory does not grow with the record.
    Files of the earlier layouts (no packed arrays) are read whole by :class:`States` and cut.

    Parameters
    ----------
    path : path
    topic : str
        The series (default :data:`STATE_TOPIC`).

    Attributes
    ----------
    n_epochs : int
    """

    _describe = States._describe
    coordinate_model = States.coordinate_model
    require_structure = States.require_structure
    config_name = States.config_name
    config_sha256 = States.config_sha256

    def __init__(self, path: str | Path, topic: str = STATE_TOPIC, covariance: bool = False):
        from cdgps_cli.io.mcap import open_verified  # noqa: PLC0415
        from cdgps_cli.io.packed_arrays import PackedRows  # noqa: PLC0415
        from cdgps_cli.io.states_header import states_spans  # noqa: PLC0415

        self.path = str(path)
        self.has_P_xi = False
        self._arrays, self._whole = {}, None
        key = f"{PACKED_PREFIX}{topic}/"
        with open_verified(path) as (_reader, fh, info, summary):
            self.metadata, spans = states_spans(path, fh, info, summary)
            small = {n: read_span(fh, *spans[n])(spans[n][1]) for n in (CONFIG_ATTACHMENT, SERIES_ATTACHMENT,
                                                                     OUTPUT_MAP_PACKED) if n in spans}
            self._describe(small)
            if key + "time_s" not in spans:
                self._whole = States(path, topic, diagnostics=False)
                self.n_epochs = len(self._whole.time_s)
                self.has_P_xi = self._whole.P_xi is not None
                return
            names = ["time_s", "xi"]
            if covariance:          # the position covariance (its triangle, or whole), or a forward filter's σ_q
                names.append(next((n for n in ("P_xi_triu", "P_xi", "sigma_q") if key + n in spans), "P_xi_triu"))
                self.has_P_xi = names[-1] != "sigma_q"
                if self.kind == "displacement":     # a constant-velocity displacement's velocities and their σ
                    names += [n for n in ("xidot", "sigma_xidot") if key + n in spans]
            try:
                for name in names:
                    self._arrays[name] = PackedRows(read_span(fh, *spans[key + name]), spans[key + name][1],
                                                    f"{path}: {key}{name}")
            except (KeyError, ValueError) as exc:
                self.close()
                raise CdgpsError(f"{path}: damaged state arrays ({key}*): {exc}") from None
        t, xi = self._arrays["time_s"], self._arrays["xi"]
        self.n_epochs = t.n_rows
        if len(t.shape) != 1 or xi.shape[:1] != (t.n_rows,) or xi.m != self.n_pos:
            self.close()
            raise CdgpsError(f"{path}: damaged state arrays ({key}time_s of shape {list(t.shape)}, xi of shape "
                             f"{list(xi.shape)} for {self.n_pos} positions)")

    def close(self) -> None:
        """Remove the temporary files (also when the object is collected)."""
        for a in self._arrays.values():
            a.close()

    def __enter__(self) -> "StatesChunks":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def series(self, epochs: int):
        """Consecutive chunks of at most ``epochs`` epochs (a multiple of 1024), first to last, as dicts
        ``time_s`` (k,), ``q``, ``sigma_q`` (k, n_q), ``xi`` (k, n_pos) and ``P_xi`` (k, n_pos, n_pos)
        or None: the values :class:`States` gives, bit for bit (q and σ_q computed on the same
        1024-epoch blocks as the writer; the object must be opened with ``covariance=True``); and a
        displacement's ``xidot``, ``sigma_xidot`` (k, n_rate) where it has them (constant velocity), else None."""
        if epochs % _PRODUCT_BLOCK:
            raise ValueError(f"epochs {epochs!r}: expected a multiple of {_PRODUCT_BLOCK}")
        if self._whole is not None:
            w = self._whole
            for a in range(0, self.n_epochs, epochs):
                b = a + epochs
                yield {"time_s": w.time_s[a:b], "q": w.q[a:b], "sigma_q": w.sigma_q[a:b], "xi": w.xi[a:b],
                       "P_xi": None if w.P_xi is None else w.P_xi[a:b],
                       **{k: (None if getattr(w, k) is None or self.kind != "displacement" else getattr(w, k)[a:b])
                          for k in ("xidot", "sigma_xidot")}}
            return
        cov_name = next(n for n in ("P_xi_triu", "P_xi", "sigma_q") if n in self._arrays)
        rates = [n for n in ("xidot", "sigma_xidot") if n in self._arrays]
        parts = zip(self._arrays["time_s"].chunks(epochs), self._arrays["xi"].chunks(epochs),
                    self._arrays[cov_name].chunks(epochs), *(self._arrays[n].chunks(epochs) for n in rates))
        C = self.output_map
        for t, xi, cov, *rate_parts in parts:
            k = len(t)
            xi = xi.reshape(k, self.n_pos)
            try:
                P = (_from_triu(cov.reshape(k, -1), self.n_pos) if cov_name == "P_xi_triu"
                     else cov.reshape(k, self.n_pos, self.n_pos) if cov_name == "P_xi" else None)
            except ValueError as exc:
                raise CdgpsError(f"{self.path}: damaged state arrays ({cov_name}): {exc}") from None
            q = np.concatenate([series_q(C, xi[a:a + _PRODUCT_BLOCK]) for a in range(0, k, _PRODUCT_BLOCK)])
            yield {"time_s": t.astype(float, copy=False), "q": q, "xi": xi, "P_xi": P,
                   "sigma_q": cov.reshape(k, -1) if P is None else coordinate_sigma(C, P),
                   "xidot": None, "sigma_xidot": None, **{n: v.reshape(k, -1) for n, v in zip(rates, rate_parts)}}

    def chunks(self, epochs: int):
        """Consecutive chunks ``(time_s (k,), q (k, n_q))`` of at most ``epochs`` epochs, first to
        last; q = ξ Cᵀ by :func:`rows_q` (the same bits however the record is cut).  Every call
        starts again from the first epoch."""
        if self._whole is not None:
            w = self._whole
            for a in range(0, self.n_epochs, epochs):
                yield w.time_s[a:a + epochs], w.q[a:a + epochs]          # (as States reads them)
            return
        for t, xi in zip(self._arrays["time_s"].chunks(epochs), self._arrays["xi"].chunks(epochs)):
            yield t.astype(float, copy=False), rows_q(self.output_map, xi.reshape(len(t), self.n_pos))
