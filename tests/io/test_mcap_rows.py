"""``McapOut.write_rows`` (messages of numbers from one template per channel, issue 30) writes the
bytes of ``McapOut.write`` of the same payloads: objects of named numbers, arrays (also empty),
scalars, constants after them, rows with NaN or infinity (left out / refused as ``write`` does),
extreme floats, nullable arrays (their ``_valid`` companions) and keys holding ``null``; and the 3-D
scene from one skeleton (``McapOut.write_skeleton``) writes the bytes of ``write_raw`` of its dicts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.io.mcap import NULLABLE, McapOut, array_schema, message_schema, row_payload

LAYOUTS = {
    "state": ([("q", ["q0", "q1", "q2"]), ("sigma_q", ["q0", "q1", "q2"]), ("xi", 2), ("xidot", 0)], {"smoothed": True}),
    "flat": ([("C1_z", None), ("body_z", None), ("sigma_C1_z", None)], None),
    "empty_obj": ([("q", []), ("v", 1)], {"k": "text", "n": 3}),
    "null_key": ([("nullish", None), ("x", 2)], None),
    "ints": ([("r", 4), ("n", "int"), ("y", 2), ("z", None), ("w", 1)], None),
}


def _schema(name, layout, nullable_x=False):
    props = {}
    for k, shape in layout:
        props[k] = {"type": "number"} if shape is None else (
            {"type": "array", "items": {"type": "number"}} if isinstance(shape, int) else {"type": "object"})
    if nullable_x:
        return array_schema(name, {"x": NULLABLE})
    return message_schema(name, props)


def _values(rng, k, m):
    v = rng.normal(size=(k, m)) * 10.0 ** rng.integers(-12, 12, size=(k, m))
    v[rng.random((k, m)) < 0.02] = np.nan
    v[3, 0] = np.inf
    v[5, :] = -0.0
    v[6, :] = 1e-5
    return v


@pytest.mark.parametrize("scale", ["relative", "gps"])
@pytest.mark.parametrize("case", sorted(LAYOUTS) + ["nullable"])
def test_rows_are_the_bytes_of_write(tmp_path, case, scale):
    layout, tail = LAYOUTS.get(case, ([("x", 3)], None))
    m = sum(1 if s is None or s == "int" else (s if isinstance(s, int) else len(s)) for _, s in layout)
    rng = np.random.default_rng(len(case))
    t = (1.4e9 if scale == "gps" else 0.0) + np.cumsum(rng.random(2100))
    vals = _values(rng, len(t), m)
    if case == "ints":
        vals[:, 4] = np.round(vals[:, 4])
    if case == "nullable":
        vals[vals != vals] = 0.5                   # (NaN in a nullable array: write()'s companions)
        vals[3, 0] = np.nan
    out = {}
    for how in ("write", "rows"):
        p = tmp_path / f"{how}.mcap"
        with McapOut(p, time_scale=scale) as o:
            ch = o.channel("/c", _schema("S", layout, case == "nullable"))
            good = np.isfinite(vals).all(axis=1) | (case == "nullable")
            if how == "write":
                for ti, row in zip(t[good].tolist(), vals[good].tolist()):
                    o.write(ch, ti, row_payload(layout, row, tail))
            else:
                o.write_rows(ch, t[good], layout, vals[good], tail)
        out[how] = p.read_bytes()
    assert out["rows"] == out["write"]


def test_rows_with_missing_values_as_write(tmp_path):
    """Rows holding NaN take write()'s rule (scalars left out); a NaN in a plain array is refused alike."""
    layout = [("a", None), ("b", None)]
    vals = np.array([[1.0, np.nan], [2.0, 3.0]])
    for how in ("write", "rows"):
        with McapOut(tmp_path / f"{how}.mcap") as o:
            ch = o.channel("/c", message_schema("S", {"a": {"type": "number"}, "b": {"type": "number"}}))
            if how == "write":
                for ti, row in zip([0.0, 0.1], vals.tolist()):
                    o.write(ch, ti, row_payload(layout, row))
            else:
                o.write_rows(ch, [0.0, 0.1], layout, vals)
    assert (tmp_path / "rows.mcap").read_bytes() == (tmp_path / "write.mcap").read_bytes()
    with McapOut(tmp_path / "bad.mcap") as o, pytest.raises(ValueError, match="array field"):
        ch = o.channel("/c", message_schema("S", {"x": {"type": "array"}}))
        o.write_rows(ch, [0.0], [("x", 2)], np.array([[1.0, np.nan]]))


class _DictsOnly:
    """A scene seen through its dict messages only (``updates``): the writer's per-message path."""

    def __init__(self, scene):
        self._s = scene
        self.metadata, self.satellites = scene.metadata, None

    def fixed(self, ns):
        return self._s.fixed(ns)

    def updates(self, q, ns, t=None):
        return self._s.updates(q, ns, t)


@pytest.mark.parametrize("config, scale", [("testbed-1998.toml", 10.0), ("teague-1995-2dof.toml", 1.0),
                                           ("tower-120m-fe.toml", 50.0)])
def test_scene_from_its_skeleton_is_the_bytes_of_its_dicts(tmp_path, config, scale):
    """/cdgps/scene from ``skeleton`` + ``rows`` (McapOut.write_skeleton) is, byte for byte, the
    ``write_raw`` of every ``updates`` dict; epochs not drawn (NaN) are left out alike."""
    from cdgps_cli.analysis.scene import StructureScene
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.io.states import _write_scene


    cfg = load_config(Path(__file__).resolve().parents[2] / "configs" / config)
    rng = np.random.default_rng(2)
    q = rng.normal(size=(1500, len(cfg.coord_names))) * 10.0 ** rng.integers(-4, -1, size=(1500, 1))
    q[[3, 700, 1499]] = np.nan
    t = 50.0 + np.arange(1500) * 0.2
    scene = StructureScene(cfg, scale)
    out = {}
    for how, sc in (("dicts", _DictsOnly(scene)), ("skeleton", scene)):
        with McapOut(tmp_path / f"{how}.mcap") as o:
            out[how] = _write_scene(o, sc, t, q)
        out[how + "_bytes"] = (tmp_path / f"{how}.mcap").read_bytes()
    assert out["skeleton"] == out["dicts"] == 1497
    assert out["skeleton_bytes"] == out["dicts_bytes"]


def _residuals_per_message(out, ss, time_s, sel, chunk, nis_bounds=None):
    """The residual channel as written before issue 30's templates: a dict per message (reference)."""
    from cdgps_cli.io import states as st
    from cdgps_cli.io.packed_arrays import MEDIA_TYPE, PackedWriter

    N, res = len(time_s), ss.residual_m
    p_r = PackedWriter((N,) + tuple(res.shape[1:]), np.float32)
    R = np.empty((len(sel),) + tuple(res.shape[1:]))
    for a in range(0, N, chunk):
        rows = st._block(res, a, a + chunk)
        p_r.add(rows.astype(np.float32))
        s = slice(np.searchsorted(sel, a), np.searchsorted(sel, a + chunk))
        R[s] = np.asarray(rows, dtype=float)[sel[s] - a]
    nis_all, dof_all = np.asarray(ss.nis, dtype=float), np.asarray(ss.nis_dof, dtype=np.int64)
    out.attach(st.RESIDUAL_PACKED + "channels.json", st.json.dumps([list(c) for c in ss.residual_channels]).encode(),
               "application/json")
    ch = out.channel(st.RESIDUAL_TOPIC, st.RESIDUAL_SCHEMA if nis_bounds is None else st._RESIDUAL_BOUNDS_SCHEMA)
    ants, txs = [c[0] for c in ss.residual_channels], [c[1] for c in ss.residual_channels]
    used = ~np.isnan(R)
    every, nis = used.all(axis=1).tolist(), nis_all[sel]
    nis_list = [None if bad else v for bad, v in zip(np.isnan(nis).tolist(), nis.tolist())]
    dof = [int(d) for d in dof_all[sel].tolist()]
    bounds = None
    if nis_bounds is not None:
        lo, hi = nis_bounds(dof_all[sel])
        has = ~np.isnan(nis) & (np.asarray(dof) > 0)
        bounds = [None if not h else (a, b) for h, a, b in zip(has.tolist(), np.asarray(lo, dtype=float).tolist(),
                                                               np.asarray(hi, dtype=float).tolist())]
    for i, (t, r) in enumerate(zip(np.asarray(time_s, dtype=float)[sel].tolist(), R.tolist())):
        a, x = ants, txs
        if not every[i]:
            u = used[i].tolist()
            a, x, r = ([v for v, ok in zip(seq, u) if ok] for seq in (ants, txs, r))
        msg = {"antenna": a, "transmitter": x, "residual_m": r, "nis": nis_list[i], "nis_dof": dof[i]}
        if bounds is not None and bounds[i] is not None:
            msg["nis_lower95"], msg["nis_upper95"] = bounds[i]
        out.write(ch, t, msg)
    size, pieces = p_r.finish()
    out.attach_stream(st.RESIDUAL_PACKED + "residual_m", size, pieces, MEDIA_TYPE)
    out.attach_packed(st.RESIDUAL_PACKED + "nis", nis_all)
    out.attach_packed(st.RESIDUAL_PACKED + "nis_dof", dof_all)


@pytest.mark.parametrize("rate", [0.0, 2.0])
def test_residual_channel_as_a_dict_per_message(tmp_path, monkeypatch, rate):
    """/cdgps/residuals from templates (runs of epochs using every channel) is, byte for byte, the
    channel of a dict per message: NIS missing (left out), its 95 % bounds, dof 0, channels unused."""
    from cdgps_cli.io import states as st
    from cdgps_cli.pipeline.estimate_outputs import nis_bounds95

    from tests.io.test_states_stream import _structure

    ss = _structure()
    ss.nis_dof[30:40] = 0
    ss.residual_m[::3] = np.where(np.isnan(ss.residual_m[::3]), 0.001, ss.residual_m[::3])  # runs of full epochs
    got = {}
    for how in ("template", "reference"):
        with monkeypatch.context() as m:
            if how == "reference":
                m.setattr(st, "_write_residuals", _residuals_per_message)
            st.write_states(ss, tmp_path / f"{how}.mcap", {"x": "1"}, {}, preview_rate_hz=rate, nis_bounds=nis_bounds95)
        got[how] = (tmp_path / f"{how}.mcap").read_bytes()
    assert got["template"] == got["reference"]


@pytest.mark.parametrize("scale", ["relative", "gps"])
def test_residual_runs_of_the_same_channels_as_a_dict_per_message(tmp_path, monkeypatch, scale):
    """Runs of epochs using the same channels (some, none, all; one run per write_rows) give, byte for
    byte, the channel of a dict per message, in either time scale (issue 29: the 24 h GNSS pair)."""
    from cdgps_cli.io import states as st
    from cdgps_cli.pipeline.estimate_outputs import nis_bounds95

    from tests.io.test_states_stream import _structure

    ss = _structure()
    R = ss.residual_m
    R[np.isnan(R)] = 0.002
    R[10:60, 1] = np.nan                              # a run without channel 1
    R[60:64] = np.nan                                 # epochs without any channel
    R[64:70, ::2] = np.nan
    R[71, 0] = np.nan                                 # a single epoch
    ss.nis[65:68] = np.nan
    ss.nis_dof[66:69] = 0
    got = {}
    for how in ("runs", "reference"):
        with monkeypatch.context() as m:
            if how == "reference":
                m.setattr(st, "_write_residuals", _residuals_per_message)
            st.write_states(ss, tmp_path / f"{how}.mcap", {"x": "1"}, {}, preview_rate_hz=0.0, nis_bounds=nis_bounds95,
                            time_scale=scale)
        got[how] = (tmp_path / f"{how}.mcap").read_bytes()
    assert got["runs"] == got["reference"]
