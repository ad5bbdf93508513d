"""The structure config's keys, declared once (issue 32 item 6): which tables exist, which keys each
table allows and requires, their types, bounds and meaning.

:func:`cdgps_cli.config.structure.parse_config` takes its allowed and required key sets from
:data:`STRUCTURE_TABLES` (so an unknown key and a missing one are judged by this table), the
plausible ranges come from :data:`cdgps_cli.config.limits.CONFIG_BOUNDS`, and
:func:`structure_json_schema` turns both into a JSON Schema (draft 2020-12) published as
``docs/schema/structure-config.schema.json``: editors that read JSON Schema for TOML (Even Better
TOML / Taplo, with a ``#:schema`` comment on the first line or an association in the settings)
then complete and check a config as it is typed.  The schema is the shape only: cross-key rules
(exactly one master, shapes independent, coordinate names that exist …) stay in ``parse_config``,
whose messages name file and key.
"""

from __future__ import annotations

import copy

from cdgps_cli.config.limits import CONFIG_BOUNDS, Bound

SCHEMA_ID = "https://cdgps.invalid/schema/structure-config.schema.json"

_STR = {"type": "string"}
_NUM = {"type": "number"}
_BOOL = {"type": "boolean"}
_VEC3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
_NUMS = {"type": "array", "items": {"type": "number"}}
_MATRIX = {"type": "array", "items": {"type": "array", "items": {"type": "number"}}}
_PER_COORD_VEC3 = {"type": "object", "additionalProperties": _VEC3}
_AXES_TO_COORD = {"type": "object", "properties": {a: _STR for a in "xyz"}, "additionalProperties": False}


def _key(schema: dict, text: str, required: bool = False) -> tuple[bool, dict]:
    return required, {**schema, "description": text}


#: table path ("" = top level, "name[]" = an array of tables) → key → (required, JSON Schema of the value)
STRUCTURE_TABLES: dict[str, dict[str, tuple[bool, dict]]] = {
    "model": {
        "name": _key(_STR, "model name, echoed in outputs", True),
        "description": _key(_STR, "free text"),
        "sample_period_s": _key(_NUM, "T of the discrete model and the logs, s", True),
        "wavelength_m": _key(_NUM, "carrier wavelength, m (default GPS L1, 0.190294 m)"),
        "measurement_sigma_m": _key(_NUM, "prior carrier-phase noise (1 sigma, m) of every channel not given its own", True),
        "line_bias_calibrated": _key(_BOOL, "antenna line biases are known, so integers can be fixed (default true)"),
        "multipath_sigma_m": _key(_NUM, "Gauss-Markov multipath sigma per channel, m (0: not modelled)"),
        "multipath_time_constant_s": _key(_NUM, "its correlation time, s (default 30)"),
    },
    "coordinates[]": {
        "name": _key(_STR, "coordinate name (q1, ...); the state vector follows the table order", True),
        "kind": _key({"type": "string", "enum": ["translation", "rotation", "modal"]},
                     "translation (m), rotation (rad) or modal (an FE modal amplitude)", True),
        "unit": _key(_STR, "label for people, e.g. 'm at the top (x)'"),
        "description": _key(_STR, "free text"),
    },
    "body": {
        "origin_m": _key(_VEC3, "origin of the body frame in the lab frame, m (default 0)"),
        "rigid_rotation": _key(_STR, "name of the rotation coordinate that turns the whole body about the vertical"),
    },
    "sections[]": {
        "name": _key(_STR, "section name", True),
        "pivot_m": _key(_VEC3, "rotation centre in the body frame, m", True),
        "translation": _key(_AXES_TO_COORD, "coordinates translating the section along x, y, z"),
        "rotation": _key(_AXES_TO_COORD, "coordinates rotating the section about x, y, z at its pivot (Rz Ry Rx)"),
    },
    "antennas[]": {
        "name": _key(_STR, "antenna name", True),
        "position_m": _key(_VEC3, "nominal position in the body frame, m", True),
        "section": _key(_STR, "section it is fixed to (omitted: the body)"),
        "receiver": _key(_STR, "receiver label"),
        "master": _key(_BOOL, "the common master of every differential measurement (exactly one antenna)"),
        "line_bias_m": _key(_NUM, "calibrated electrical-length term of the antenna, m"),
        "displacement_m": _key(_PER_COORD_VEC3, "linear displacement per unit of each coordinate (FE mode shapes), m"),
        "sigma_m": _key(_NUM, "prior phase noise of every channel of this rover antenna, m"),
    },
    "transmitters[]": {
        "name": _key(_STR, "transmitter name", True),
        "position_m": _key(_VEC3, "near field (pseudolite): position in the lab frame, m"),
        "direction": _key(_VEC3, "far field: unit vector toward the source"),
        "description": _key(_STR, "free text"),
        "sigma_m": _key(_NUM, "prior phase noise of every channel of this transmitter, m"),
    },
    "modes[]": {
        "name": _key(_STR, "mode name", True),
        "frequency_hz": _key(_NUM, "natural frequency, Hz (0 only for a rigid mode)", True),
        "shape": _key(_NUMS, "one value per coordinate: a column of U with q = U xi", True),
        "description": _key(_STR, "free text"),
        "rigid": _key(_BOOL, "the rigid-body mode"),
        "time_constant_s": _key(_NUM, "envelope time constant tau, s (zeta = 1/(omega tau)); or damping_ratio"),
        "damping_ratio": _key(_NUM, "modal damping ratio zeta, 0 < zeta < 1; or time_constant_s"),
    },
    "process_noise": {
        "space": _key({"type": "string", "enum": ["modal", "coordinates"]},
                      "white noise on each modal acceleration, or on each coordinate's", True),
        "sigma": _key(_NUMS, "one sigma per mode (or coordinate): W = diag(sigma^2)"),
        "covariance": _key(_MATRIX, "the full W, a list of rows"),
        "cholesky": _key(_MATRIX, "a lower-triangular L with W = L L^T"),
    },
    "channel_sigma[]": {
        "antenna": _key(_STR, "rover antenna of the channel", True),
        "transmitter": _key(_STR, "transmitter of the channel", True),
        "sigma_m": _key(_NUM, "prior phase noise of that channel, m", True),
        "description": _key(_STR, "free text"),
    },
    "gyros[]": {
        "name": _key(_STR, "gyro name", True),
        "axis": _key({"oneOf": [{"type": "string", "enum": ["x", "y", "z"]}, _VEC3]},
                     "sensitive axis: x, y, z of the section / body frame, or a 3-vector", True),
        "description": _key(_STR, "free text"),
        "section": _key(_STR, "section the gyro is mounted on"),
        "rotation_rad": _key(_PER_COORD_VEC3, "rotation vector of the mount per unit of each coordinate (FE), rad"),
    },
    "points[]": {
        "name": _key(_STR, "point name (not an antenna name)", True),
        "position_m": _key(_VEC3, "nominal position in the body frame, m", True),
        "section": _key(_STR, "section it is fixed to"),
        "displacement_m": _key(_PER_COORD_VEC3, "FE translations at the point per unit coordinate, m"),
        "description": _key(_STR, "free text"),
    },
    "thrusters[]": {
        "name": _key(_STR, "thruster name", True),
        "position_m": _key(_VEC3, "position in the body frame, m", True),
        "direction": _key(_VEC3, "force direction in the body frame", True),
        "section": _key(_STR, "section it is mounted on"),
        "max_force_n": _key(_NUM, "largest force, N"),
    },
}

#: the top level: which tables are required (arrays of tables are marked "[]" in STRUCTURE_TABLES)
TOP_REQUIRED = ("model", "coordinates", "antennas", "transmitters", "modes", "process_noise")
TOP_OPTIONAL = ("body", "sections", "gyros", "thrusters", "simulation", "channel_sigma", "points")


def simulation_table(defaults: dict) -> dict[str, tuple[bool, dict]]:
    """``[simulation]`` keys from the simulator's defaults (a number, a string or a list of names each)."""
    def kind(v):
        if isinstance(v, str):
            return _STR
        if isinstance(v, list):
            return {"type": "array", "items": _STR}
        return _NUM
    return {k: (False, {**kind(v), "description": f"simulator setting (default {v!r})", "default": v})
            for k, v in defaults.items()}


def required_keys(table: str) -> set[str]:
    """Keys ``table`` must have ("" for the top level)."""
    if table == "":
        return set(TOP_REQUIRED)
    return {k for k, (req, _) in STRUCTURE_TABLES[table].items() if req}


def optional_keys(table: str) -> set[str]:
    """Keys ``table`` may have besides the required ones."""
    if table == "":
        return set(TOP_OPTIONAL)
    return {k for k, (req, _) in STRUCTURE_TABLES[table].items() if not req}


def _apply_bound(schema: dict, b: Bound) -> None:
    schema["exclusiveMinimum" if b.lo_open else "minimum"] = b.lo
    schema["maximum"] = b.hi


def _bounded(path: str, schema: dict) -> dict:
    """``schema`` with the CONFIG_BOUNDS of ``path`` (``table.key``) as minimum/maximum, also on
    vector items (``[]``), matrix items (``[][]``) and per-coordinate vectors (``.*[]``)."""
    out = copy.deepcopy(schema)
    for suffix, walk in (("", ()), ("[]", ("items",)), ("[][]", ("items", "items")),
                         (".*[]", ("additionalProperties", "items"))):
        b = CONFIG_BOUNDS.get(path + suffix)
        if b is None:
            continue
        node = out
        for step in walk:
            node = node[step]
        _apply_bound(node, b)
    return out


def _table_schema(name: str, keys: dict) -> dict:
    base = name[:-2] if name.endswith("[]") else name
    props = {k: _bounded(f"{name}.{k}", s) for k, (_, s) in sorted(keys.items())}
    table = {"type": "object", "properties": props, "additionalProperties": False}
    req = sorted(k for k, (r, _) in keys.items() if r)
    if req:
        table["required"] = req
    return {"type": "array", "items": table} if name.endswith("[]") else {**table, "title": base}


def structure_json_schema(simulation_defaults: dict) -> dict:
    """The JSON Schema of a structure config (shape, types, bounds, descriptions).

    Parameters
    ----------
    simulation_defaults : dict
        The simulator's ``[simulation]`` defaults (:data:`cdgps_cli.config.structure._SIM_DEFAULTS`).
    """
    tables = dict(STRUCTURE_TABLES, simulation=simulation_table(simulation_defaults))
    props = {(n[:-2] if n.endswith("[]") else n): _table_schema(n, keys) for n, keys in tables.items()}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": SCHEMA_ID,
            "title": "cdgps structure config (TOML)",
            "description": "A flexible structure instrumented with GNSS antennas: coordinates, sections, antennas, "
                           "transmitters, modes, process noise, gyros, points, thrusters (docs/config-format.md).",
            "type": "object", "properties": dict(sorted(props.items())), "required": list(TOP_REQUIRED),
            "additionalProperties": False}
