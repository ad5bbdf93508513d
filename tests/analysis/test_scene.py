"""Issue 33 item 2: the structure drawn in 3-D (analysis/scene.py) and its foxglove.SceneUpdate schema.

The scene's nodes move as the model's kinematics say (antennas exactly where
:func:`~cdgps_cli.model.kinematics.antenna_positions` puts them at true scale), the deformation is
magnified by the exaggeration and the rigid-body rotation is not, and every message is valid
against the schema (``jsonschema``) that passes Foxglove's decoder rules.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from jsonschema import validators

from cdgps_cli.analysis.scene import (FRAME_ID, StructureScene, _direction_quaternion, auto_exaggeration,
                                      drawn_positions, scene_geometry)
from cdgps_cli.config.structure import load_config
from cdgps_cli.io.foxglove_schema import ENTITY_FIELDS, SCENE_UPDATE_SCHEMA_NAME, scene_update_schema
from cdgps_cli.io.mcap import McapOut
from cdgps_cli.io.mcap_check import foxglove_schema_problems, path_name_problems
from cdgps_cli.model.kinematics import antenna_positions

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _validator():
    schema = scene_update_schema()
    cls = validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema)


def _edges(geom, pairs):
    return {tuple(sorted((geom.names[a], geom.names[b]))) for a, b in pairs.tolist()}


def test_schema_is_foxgloves_scene_update_and_passes_the_decoder_rules():
    s = scene_update_schema()
    assert s["title"] == SCENE_UPDATE_SCHEMA_NAME == "foxglove.SceneUpdate"
    assert foxglove_schema_problems(s) == [] and path_name_problems(s) == []
    entity = s["properties"]["entities"]["items"]
    assert entity["title"] == "foxglove.SceneEntity" and entity["required"] == list(ENTITY_FIELDS)
    line = entity["properties"]["lines"]["items"]
    assert [(a["title"], a["const"]) for a in line["properties"]["type"]["oneOf"]] == [
        ("LINE_STRIP", 0), ("LINE_LOOP", 1), ("LINE_LIST", 2)]
    assert entity["properties"]["models"]["items"]["properties"]["data"]["contentEncoding"] == "base64"
    s["title"] = "changed"                                        # a fresh copy each call
    assert scene_update_schema()["title"] == "foxglove.SceneUpdate"


def test_skeleton_and_spokes_follow_the_configs():
    tb = scene_geometry(load_config(CONFIGS / "testbed-1998.toml"))
    # the beams C1–C2–C3 (C2's pivot is the body origin: the pivot is kept), antennas on spokes
    assert _edges(tb, tb.skeleton) == {("pivot:C1", "pivot:C2"), ("pivot:C2", "pivot:C3")}
    assert ("a1", "pivot:C1") in _edges(tb, tb.spokes) and ("a6", "pivot:C3") in _edges(tb, tb.spokes)
    assert len(tb.spokes) == 7 and tb.kinds[tb.names.index("master")] == "master"
    tower = scene_geometry(load_config(CONFIGS / "tower-120m-fe.toml"))
    # FE nodes (no sections): one mast from the foundation to the top, in height order
    adj = {}
    for a, b in tower.skeleton.tolist():
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, []).append(a)
    assert all(len(v) <= 2 for v in adj.values())               # a path, not a star
    z = tower.position_m[:, 2]
    ends = [k for k, v in adj.items() if len(v) == 1]
    assert sorted(z[ends].tolist()) == [0.0, 120.0] and len(tower.skeleton) == len(tower.names) - 1
    gt = scene_geometry(load_config(CONFIGS / "gnss-tower.toml"))
    # the master antenna sits at the body origin: it is the node kept there
    assert _edges(gt, gt.skeleton) == {("base", "pivot:top")} and len(gt.spokes) == 2


@pytest.mark.parametrize("name", ["testbed-1998", "tower-120m-fe", "gnss-tower"])
def test_drawn_positions_are_the_kinematics_and_exaggerate_only_the_deformation(name):
    cfg = load_config(CONFIGS / f"{name}.toml")
    g = scene_geometry(cfg)
    rng = np.random.default_rng(1)
    q = 0.05 * rng.standard_normal((5, cfg.n_q))
    p1 = drawn_positions(cfg, g, q, 1.0)
    ants = [g.names.index(a) for a in cfg.antenna_names]
    np.testing.assert_allclose(p1[:, ants], antenna_positions(cfg, q), rtol=0, atol=1e-12)
    p0, p30 = drawn_positions(cfg, g, q, 0.0), drawn_positions(cfg, g, q, 30.0)
    np.testing.assert_allclose(p30 - p0, 30.0 * (p1 - p0), rtol=1e-12, atol=1e-9)
    assert np.abs(p1 - p0).max() > 1e-3                       # the deformation is there
    if cfg.rigid_index is not None:                            # the rigid rotation alone: at true scale
        qr = np.zeros_like(q)
        qr[:, cfg.rigid_index] = 0.7
        np.testing.assert_allclose(drawn_positions(cfg, g, qr, 100.0), drawn_positions(cfg, g, qr, 1.0), atol=1e-12)


def test_auto_exaggeration_steps_and_scale():
    tower = load_config(CONFIGS / "tower-120m-fe.toml")
    g = scene_geometry(tower)
    xi = np.zeros((50, tower.n_modes))
    xi[:, 0] = 0.01 * np.sin(np.arange(50))
    q = xi @ np.asarray(tower.mode_shapes).T
    k = auto_exaggeration(tower, g, q, 0.05)
    d = np.linalg.norm(drawn_positions(tower, g, q, 1.0) - drawn_positions(tower, g, q, 0.0), axis=-1)
    big = np.percentile(d.max(axis=1), 99)
    mantissa = k / 10 ** np.floor(np.log10(k))
    assert mantissa in (1.0, 2.0, 5.0) and k > 1
    assert k * big <= 0.05 * g.size_m < 2.5 * k * big          # the largest 1-2-5 step at or below the target
    tb = load_config(CONFIGS / "testbed-1998.toml")
    assert auto_exaggeration(tb, scene_geometry(tb), np.full((3, tb.n_q), 0.2), 0.05) == 1.0   # large: true scale
    assert auto_exaggeration(tb, scene_geometry(tb), np.zeros((3, tb.n_q)), 0.05) == 1.0


def test_messages_are_valid_scene_updates_and_nan_epochs_are_skipped():
    cfg = load_config(CONFIGS / "testbed-1998.toml")
    v = _validator()
    sc = StructureScene(cfg, 10.0)
    q = 0.01 * np.ones((3, cfg.n_q))
    q[1, 3] = np.nan
    msgs = sc.updates(q, [10**9, 2 * 10**9, 3 * 10**9 + 5])
    assert msgs[1] is None
    for m in (msgs[0], msgs[2], sc.fixed(10**9)):
        assert not list(v.iter_errors(m)), list(v.iter_errors(m))[:2]
        json.dumps(m, allow_nan=False)
    e = msgs[2]["entities"][0]
    assert e["frame_id"] == FRAME_ID and e["timestamp"] == {"sec": 3, "nsec": 5} and e["id"] == "structure"
    assert len(e["spheres"]) == len(cfg.antenna_names) and {t["text"] for t in e["texts"]} == set(cfg.antenna_names)
    beams = e["lines"][0]                                            # two beams, LINE_LIST over 3 pivots
    assert beams["type"] == 2 and len(beams["points"]) == 3 and len(beams["indices"]) == 4
    ends = sorted(tuple(sorted((beams["points"][a]["x"], beams["points"][b]["x"])))
                  for a, b in zip(beams["indices"][::2], beams["indices"][1::2]))
    assert np.allclose(ends, [(-4.0, 0.0), (0.0, 4.0)], atol=0.5)   # C1–C2 and C2–C3 (x of the pivots, moved)
    # spheres where the model puts the antennas (exaggerated), rounded to 1 mm on the 8 m testbed
    g = sc.geometry
    p = drawn_positions(cfg, g, q[2:], 10.0)[0]
    got = np.array([[s["pose"]["position"][a] for a in "xyz"] for s in e["spheres"]])
    assert sc.decimals == 3 and sc.metadata["resolution_m"] == "0.001"
    np.testing.assert_allclose(got, p[[g.names.index(a) for a in cfg.antenna_names]], atol=0.51e-3)
    fixed = sc.fixed(10**9)["entities"][0]
    assert len(fixed["cubes"]) == len(cfg.transmitter_names) and fixed["arrows"] == []
    assert StructureScene(cfg, 10.0, transmitters=False).fixed(0) is None
    with pytest.raises(ValueError, match="exaggeration"):
        StructureScene(cfg, 0.0)


def test_far_field_transmitters_are_arrows_along_their_directions():
    for u in ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.3, -0.5, 0.8]):
        q = _direction_quaternion(u)
        x, y, z, w = q["x"], q["y"], q["z"], q["w"]
        turned = [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)]      # R(q) e_x
        np.testing.assert_allclose(turned, np.asarray(u) / np.linalg.norm(u), atol=1e-12)
    cfg = load_config(CONFIGS / "gnss-tower.toml")                 # its one far-field "GPS" direction
    m = StructureScene(cfg, 1.0).fixed(0)
    assert len(m["entities"][0]["arrows"]) == 1 and not list(_validator().iter_errors(m))


def test_write_raw_refuses_missing_values(tmp_path):
    with McapOut(tmp_path / "s.mcap") as out:
        ch = out.channel("/s", scene_update_schema())
        out.write_raw(ch, 1.0, {"deletions": [], "entities": [], "note": "null"})      # the word in a text is fine
        for bad in (float("nan"), None, float("inf")):
            with pytest.raises(ValueError, match="missing value"):
                out.write_raw(ch, 2.0, {"deletions": [], "entities": [{"x": [1.0, bad]}]})


def _turned_x(q):
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    return np.array([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)])      # R(q) e_x


def test_satellite_arrows_start_at_the_master_and_follow_the_sky():
    """A GNSS run's satellites: one arrow per satellite used at the epoch (NaN: not used, no arrow),
    from the master antenna as drawn, along its direction, named at the tip; the sky's epoch is the
    latest at or before the message's; every message still valid against the schema."""
    from cdgps_cli.analysis.scene import SatelliteSky

    cfg = load_config(CONFIGS / "gnss-tower.toml")
    up, east = np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, 0.8])
    D = np.array([[up, east], [up, [np.nan] * 3]])
    sky = SatelliteSky(np.array([0.0, 10.0]), ("G01", "E05"), D)
    np.testing.assert_array_equal(sky.at([-1.0, 0.0, 9.9, 10.0, 99.0])[:, 1, 0], [0.6, 0.6, 0.6, np.nan, np.nan])
    sc = StructureScene(cfg, 1.0, transmitters=False, satellites=sky)
    q = 0.01 * np.ones((2, cfg.n_q))
    msgs = sc.updates(q, [10**9, 2 * 10**9], [5.0, 12.0])
    v = _validator()
    for m in msgs:
        assert not list(v.iter_errors(m)), list(v.iter_errors(m))[:2]
    first, second = (m["entities"][1] for m in msgs)
    assert first["id"] == "satellites" and [t["text"] for t in first["texts"]] == ["G01", "E05"]
    assert [t["text"] for t in second["texts"]] == ["G01"] and len(second["arrows"]) == 1
    g = sc.geometry
    master = drawn_positions(cfg, g, q[:1], 1.0)[0][g.kinds.index("master")]
    for arrow, u in zip(first["arrows"], (up, east)):
        np.testing.assert_allclose([arrow["pose"]["position"][a] for a in "xyz"], master, atol=0.51 * 10.0 ** -sc.decimals)
        np.testing.assert_allclose(_turned_x(arrow["pose"]["orientation"]), u, atol=1e-5)
    assert "satellites" not in [e["id"] for e in sc.updates(q, [10**9, 2 * 10**9])[0]["entities"]]   # no times: none


def test_satellite_sky_takes_the_used_rows_of_each_rover():
    """satellite_sky (pipeline/gnss_modal.py) maps the rows the filter uses to (epoch, satellite)
    directions in the structure frame, every step_s; rows not used, and rovers' missing epochs, draw nothing."""
    from types import SimpleNamespace

    from cdgps_cli.pipeline.gnss_modal import satellite_sky

    R = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])      # ECEF -> structure: a quarter turn
    xm = np.array([10.0, 0.0, 0.0])
    sats = np.array([[10.0, 0.0, 5.0], [13.0, 4.0, 0.0], [10.0, 3.0, 4.0]])
    d = SimpleNamespace(ptr=np.array([0, 2, 4, 5]), sat=np.array([0, 1, 0, 2, 2]), sat_names=["G01", "G02", "G03"],
                        rover_sat_xyz=sats[[0, 1, 0, 2, 2]])
    tb = {"d": d, "use": np.array([True, False, True, False, True]), "xm": xm}
    model = SimpleNamespace(tabs=[tb], k_of=[np.array([0, -1, 1, 2])], R=R)      # model epoch 1: the rover has none
    sky = satellite_sky(model, np.array([0.0, 1.0, 2.0, 3.0]), step_s=1.0)
    assert sky.names == ("G01", "G03") and sky.time_s.tolist() == [0.0, 1.0, 2.0, 3.0]
    u = lambda s: (sats[s] - xm) @ R / np.linalg.norm(sats[s] - xm)           # noqa: E731
    np.testing.assert_allclose(sky.direction[0, 0], u(0))                      # G02 is not used anywhere
    assert np.isnan(sky.direction[1]).all()                                    # no rows at model epoch 1
    np.testing.assert_allclose(sky.direction[2, 0], u(0))
    assert np.isnan(sky.direction[2, 1]).all()                                 # G03 not used at that epoch
    np.testing.assert_allclose(sky.direction[3, 1], u(2))
    assert satellite_sky(model, np.array([0.0, 1.0, 2.0, 3.0]), step_s=2.0).time_s.tolist() == [0.0, 2.0]
