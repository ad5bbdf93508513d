"""The ``foxglove.SceneUpdate`` JSON schema, generated here from a compact table of its messages.

Foxglove's 3-D panel draws a channel whose schema is named ``foxglove.SceneUpdate``; with the
``json`` message encoding its schema is the JSON schema of that message
(``schemas/jsonschema/SceneUpdate.json`` of github.com/foxglove/foxglove-sdk, formerly
foxglove/schemas).  :func:`scene_update_schema` builds an equivalent schema from the message
definitions below (field names, types, enumerations and required fields as in the SDK's schema of
August 2026; the descriptions are ours and short; the optional lineage fields ``message_id`` and
``lineage`` of a deletion are left out: cdgps never writes them).  It passes the checker of
:mod:`cdgps_cli.io.mcap_check` (Foxglove's JSON-schema decoder rules) and is what the STATES writer
registers for its scene channel (:mod:`cdgps_cli.io.states`), so every message it writes is
validated against it by the tests (``jsonschema``).

Times are ``{sec, nsec}`` objects (Unix time), colours ``{r, g, b, a}`` in [0, 1], lengths in the
frame's unit (metres).
"""

from __future__ import annotations

import copy

SCENE_UPDATE_SCHEMA_NAME = "foxglove.SceneUpdate"
"""Schema name Foxglove's 3-D panel recognises (exactly this)."""


def _num(desc: str | None = None) -> dict:
    return {"type": "number", **({"description": desc} if desc else {})}


def _obj(title: str, props: dict, required=None, desc: str | None = None) -> dict:
    s = {"title": title, "type": "object", "properties": props}
    if desc:
        s["description"] = desc
    if required:
        s["required"] = list(required)
    return s


def _time(desc: str) -> dict:
    return {"type": "object", "title": "time", "description": desc,
            "properties": {"sec": {"type": "integer", "minimum": 0},
                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}


def _duration(desc: str) -> dict:
    return {"type": "object", "title": "duration", "description": desc,
            "properties": {"sec": {"type": "integer"},
                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}


def _enum(title: str, names: list[str], desc: str) -> dict:
    return {"title": title, "description": desc, "oneOf": [{"title": n, "const": i} for i, n in enumerate(names)]}


def _array(items: dict, desc: str) -> dict:
    return {"type": "array", "items": items, "description": desc}


def _vector3(desc: str) -> dict:
    return _obj("foxglove.Vector3", {a: _num() for a in "xyz"}, "xyz", desc)


def _point3() -> dict:
    return _obj("foxglove.Point3", {a: _num() for a in "xyz"}, "xyz", "point")


def _color(desc: str = "colour, components in [0, 1]") -> dict:
    return _obj("foxglove.Color", {c: _num() for c in "rgba"}, "rgba", desc)


def _pose(desc: str) -> dict:
    return _obj("foxglove.Pose", {"position": _vector3("position"),
                                  "orientation": _obj("foxglove.Quaternion", {a: _num() for a in "xyzw"}, "xyzw",
                                                      "orientation")},
                ["position", "orientation"], desc)


def _primitives() -> dict:
    """The primitive arrays of a scene entity, by field name."""
    arrow = _obj("foxglove.ArrowPrimitive", {
        "pose": _pose("tail position; identity orientation points along +x"), "shaft_length": _num(),
        "shaft_diameter": _num(), "head_length": _num(), "head_diameter": _num(), "color": _color()},
        ["pose", "shaft_length", "shaft_diameter", "head_length", "head_diameter", "color"], "arrow")
    cube = _obj("foxglove.CubePrimitive", {"pose": _pose("centre"), "size": _vector3("edge lengths"),
                                           "color": _color()}, ["pose", "size", "color"], "box")
    sphere = _obj("foxglove.SpherePrimitive", {"pose": _pose("centre"), "size": _vector3("diameters"),
                                               "color": _color()}, ["pose", "size", "color"], "ellipsoid")
    cylinder = _obj("foxglove.CylinderPrimitive", {
        "pose": _pose("centre"), "size": _vector3("bounding box"), "bottom_scale": _num(), "top_scale": _num(),
        "color": _color()}, ["pose", "size", "bottom_scale", "top_scale", "color"], "cylinder or cone")
    line = _obj("foxglove.LinePrimitive", {
        "type": _enum("foxglove.LineType", ["LINE_STRIP", "LINE_LOOP", "LINE_LIST"], "how points are joined"),
        "pose": _pose("origin of the points"), "thickness": _num(), "scale_invariant": {"type": "boolean"},
        "points": _array(_point3(), "vertices"), "color": _color(),
        "colors": _array(_color(), "per-vertex colours (empty: color)"),
        "indices": _array({"type": "integer", "minimum": 0}, "vertex indices (empty: all in order)")},
        ["type", "pose", "thickness", "scale_invariant", "points", "color", "colors", "indices"], "lines")
    triangles = _obj("foxglove.TriangleListPrimitive", {
        "pose": _pose("origin of the points"), "points": _array(_point3(), "vertices"), "color": _color(),
        "colors": _array(_color(), "per-vertex colours"),
        "indices": _array({"type": "integer", "minimum": 0}, "vertex indices")},
        ["pose", "points", "color", "colors", "indices"], "triangles")
    text = _obj("foxglove.TextPrimitive", {
        "pose": _pose("anchor"), "billboard": {"type": "boolean"}, "font_size": _num(),
        "scale_invariant": {"type": "boolean"}, "color": _color(), "text": {"type": "string"}},
        ["pose", "billboard", "font_size", "scale_invariant", "color", "text"], "text label")
    model = _obj("foxglove.ModelPrimitive", {
        "pose": _pose("origin"), "scale": _vector3("scale factors"), "color": _color(),
        "override_color": {"type": "boolean"}, "url": {"type": "string"}, "media_type": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"}},
        ["pose", "scale", "color", "override_color", "url", "media_type", "data"], "3-D model")
    return {"arrows": arrow, "cubes": cube, "spheres": sphere, "cylinders": cylinder, "lines": line,
            "triangles": triangles, "texts": text, "models": model}


ENTITY_FIELDS = ("timestamp", "frame_id", "id", "lifetime", "frame_locked", "metadata", "arrows", "cubes", "spheres",
                 "cylinders", "lines", "triangles", "texts", "models")
"""Fields of a ``foxglove.SceneEntity``, all required by the schema."""


def scene_update_schema() -> dict:
    """The JSON schema of ``foxglove.SceneUpdate`` (a fresh dict each call)."""
    return copy.deepcopy(_SCHEMA)


def _build() -> dict:
    entity_props = {
        "timestamp": _time("time of the entity"),
        "frame_id": {"type": "string", "description": "frame of reference"},
        "id": {"type": "string", "description": "an entity replaces the earlier one of the same id on the topic"},
        "lifetime": _duration("shown this long after timestamp; zero: until replaced or deleted"),
        "frame_locked": {"type": "boolean", "description": "follow frame_id as it moves (true) or stay put (false)"},
        "metadata": _array(_obj("foxglove.KeyValuePair", {"key": {"type": "string"}, "value": {"type": "string"}},
                                ["key", "value"], "key and value"), "further key/value pairs"),
    }
    entity_props.update({k: _array(v, k) for k, v in _primitives().items()})
    entity = _obj("foxglove.SceneEntity", entity_props, ENTITY_FIELDS, "an element of the 3-D scene")
    deletion = _obj("foxglove.SceneEntityDeletion", {
        "timestamp": _time("entities older than this are deleted"),
        "type": _enum("foxglove.SceneEntityDeletionType", ["MATCHING_ID", "ALL"], "what is deleted"),
        "id": {"type": "string", "description": "the entity deleted (MATCHING_ID)"}},
        ["timestamp", "type", "id"], "removal of entities")
    return _obj(SCENE_UPDATE_SCHEMA_NAME, {"deletions": _array(deletion, "entities to remove"),
                                           "entities": _array(entity, "entities to add or replace")},
                ["deletions", "entities"], "an update to the entities of a 3-D scene")


_SCHEMA = _build()
