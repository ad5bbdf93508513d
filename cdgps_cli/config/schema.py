"""The config files' keys, declared once (issue 32 item 6): which tables exist, which keys each
table allows and requires, their types, bounds and meaning — the structure config
(:data:`STRUCTURE_TABLES`) and the GNSS run config (:data:`GNSS_TABLES`).

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
        "sigma_rad_s": _key(_NUM, "white noise of the gyro as a fused measurement, rad/s (default [simulation] gyro_noise_rad_s)"),
        "bias_sigma_rad_s": _key(_NUM, "prior sigma of its bias state, rad/s (default [simulation] gyro_bias_sigma_rad_s)"),
        "bias_drift_rad_s_per_sqrt_s": _key(_NUM, "random walk of its bias, rad/s/sqrt(s) "
                                                  "(default [simulation] gyro_bias_drift_rad_s_per_sqrt_s)"),
    },
    "accelerometers[]": {
        "name": _key(_STR, "accelerometer name", True),
        "point": _key(_STR, "antenna or [[points]] name it is attached to", True),
        "axes": _key({"oneOf": [{"type": "string", "enum": ["x", "y", "z"]},
                                {"type": "array", "items": {"type": "string", "enum": ["x", "y", "z"]}}]},
                     "sensitive axis or axes (body frame): \"x\" (uniaxial) or [\"x\", \"y\", \"z\"] (triaxial)", True),
        "sigma_m_s2": _key(_NUM, "white noise per axis, m/s^2", True),
        "bias_sigma_m_s2": _key(_NUM, "prior sigma of each axis's bias state, m/s^2 (0: no bias state)"),
        "bias_drift_m_s2_per_sqrt_s": _key(_NUM, "random walk of each bias, m/s^2/sqrt(s)"),
        "sample_period_s": _key(_NUM, "sample period of the log, s (default [model] sample_period_s)"),
        "rotation_rad": _key(_PER_COORD_VEC3, "rotation of the mount per unit coordinate (FE slopes), rad: "
                                              "the gravity a tilted axis feels"),
        "description": _key(_STR, "free text"),
    },
    "tilts[]": {
        "name": _key(_STR, "tilt meter (inclinometer) name", True),
        "axis": _key({"oneOf": [{"type": "string", "enum": ["x", "y", "z"]}, _VEC3]},
                     "rotation axis sensed: x, y, z of the body frame, or a 3-vector", True),
        "sigma_rad": _key(_NUM, "white noise, rad", True),
        "section": _key(_STR, "section it is mounted on"),
        "rotation_rad": _key(_PER_COORD_VEC3, "rotation vector of the mount per unit of each coordinate (FE slopes), rad"),
        "bias_sigma_rad": _key(_NUM, "prior sigma of its bias state, rad (0: no bias state)"),
        "bias_drift_rad_per_sqrt_s": _key(_NUM, "random walk of its bias, rad/sqrt(s)"),
        "sample_period_s": _key(_NUM, "sample period of the log, s (default [model] sample_period_s)"),
        "description": _key(_STR, "free text"),
    },
    "fusion": {
        "fuse": _key({"type": "array", "items": {"type": "string", "enum": ["gyro", "accel", "tilt"]}},
                     "sensor kinds fused with GNSS by 'estimate --structure' (opt-in; --fuse overrides)"),
        "hold_out": _key({"type": "array", "items": _STR},
                         "sensor names kept out of the fusion, as independent checks (--hold-out adds)"),
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
TOP_OPTIONAL = ("body", "sections", "gyros", "thrusters", "simulation", "channel_sigma", "points",
                "accelerometers", "tilts", "fusion")


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


# ---------------------------------------------------------------------------------------------
# GNSS run configs (docs/gnss-pipeline.md): one [gnss] table, its antennas and displacement model

_POS = {"type": "number", "exclusiveMinimum": 0}
_FILES = {"oneOf": [_STR, {"type": "array", "items": _STR}]}

#: table path ("gnss", "gnss.antennas.*": every antenna, "gnss.displacement") → key → (required, JSON Schema)
GNSS_TABLES: dict[str, dict[str, tuple[bool, dict]]] = {
    "gnss": {
        "name": _key(_STR, "run name (default: the file's name)"),
        "description": _key(_STR, "free text"),
        "master": _key(_STR, "the reference antenna (its position is held)"),
        "nav": _key(_FILES, "RINEX navigation file(s), relative to this file; globs allowed"),
        "mask_deg": _key({"type": "number", "minimum": 0, "exclusiveMaximum": 90}, "elevation mask, degrees"),
        "ratio": _key({"type": "number", "minimum": 1}, "LAMBDA ratio-test threshold"),
        "min_success_rate": _key({"type": "number", "minimum": 0, "exclusiveMaximum": 1},
                                 "bootstrapped success rate an integer set must reach besides the ratio test"),
        "partial": _key(_BOOL, "partial fixing when the full set fails the ratio test"),
        "fix": _key(_BOOL, "fix integers (false: float solution)"),
        "weighting": _key({"type": "string", "enum": ["elevation", "equal"]},
                          "phase variance a² + b²/sin²(el) or a² + b²"),
        "sigma_a_m": _key({"type": "number", "minimum": 0}, "phase noise a, m"),
        "sigma_b_m": _key({"type": "number", "minimum": 0}, "phase noise b (elevation term), m"),
        "code_ratio": _key(_POS, "code σ / phase σ"),
        "troposphere": _key(_BOOL, "a priori hydrostatic troposphere"),
        "max_gap_s": _key(_POS, "a longer gap in a satellite's phase starts a new ambiguity, s"),
        "sync_tol_s": _key({"type": "number", "exclusiveMinimum": 0, "maximum": 1},
                           "base and rover epochs this close are simultaneous, s"),
        "max_age_s": _key(_POS, "oldest base epoch bridged to a rover epoch, s (RTKLIB's maxage)"),
        "code_correlation_s": _key({"type": "number", "minimum": 0},
                                   "code errors as a Gauss-Markov process of this correlation time, s (0: white)"),
        "epoch_alignment": _key({"type": "string", "enum": ["geometry", "doppler"]},
                                "how receivers' epochs are brought to one instant"),
        "signals": _key({"type": "array", "items": _STR}, "signals to use, e.g. [\"G:L1\", \"E:E1\"]"),
        "iono_threshold_km": _key({"type": "number", "minimum": 0},
                                  "baselines longer than this estimate the ionosphere, km"),
        "sensors": _key(_FILES, "sensor CSV logs (accelerometer, tilt, gyro; units in the column names), "
                                "relative to this file; globs allowed"),
        "antennas": _key({"type": "object"}, "one table per antenna: [gnss.antennas.NAME]", True),
        "displacement": _key({"type": "object"}, "the rovers' motion model"),
    },
    "gnss.antennas.*": {
        "rinex": _key(_STR, "RINEX observation file (or a quoted glob of consecutive files), relative to this file"),
        "ubx": _key(_STR, "u-blox UBX log (or a quoted glob of consecutive files), relative to this file"),
        "position_ecef_m": _key(_VEC3, "nominal antenna position, ECEF m (default: the RINEX header's)"),
        "description": _key(_STR, "free text"),
    },
    "gnss.displacement": {
        "model": _key({"type": "string", "enum": ["static", "random_walk"]}, "static or random-walk E/N/U displacement"),
        "sigma_m_per_sqrt_s": _key({"oneOf": [_POS, {**_VEC3, "items": _POS}]},
                                   "random-walk rate, m/√s (one number or E, N, U)"),
        "initial_sigma_m": _key(_POS, "prior σ of the first epoch's position, m"),
    },
}


def gnss_keys(table: str) -> tuple[set, set]:
    """(required, optional) keys of a GNSS run config table (:data:`GNSS_TABLES`)."""
    keys = GNSS_TABLES[table]
    return {k for k, (r, _) in keys.items() if r}, {k for k, (r, _) in keys.items() if not r}


def gnss_json_schema() -> dict:
    """The JSON Schema of a GNSS run config (shape, types, ranges, descriptions)."""
    def table(name):
        keys = GNSS_TABLES[name]
        out = {"type": "object", "properties": {k: copy.deepcopy(v) for k, (_, v) in sorted(keys.items())},
               "additionalProperties": False}
        req = sorted(k for k, (r, _) in keys.items() if r)
        return {**out, "required": req} if req else out
    gnss = table("gnss")
    gnss["properties"]["antennas"] = {**gnss["properties"]["antennas"], "additionalProperties": table("gnss.antennas.*")}
    gnss["properties"]["displacement"] = {**table("gnss.displacement"),
                                          "description": gnss["properties"]["displacement"]["description"]}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            "$id": SCHEMA_ID.replace("structure-config", "gnss-config"),
            "title": "cdgps GNSS run config (TOML)",
            "description": "Real or simulated receiver files of a master and rovers, and the solver's settings "
                           "(docs/gnss-pipeline.md).",
            "type": "object", "properties": {"gnss": gnss}, "required": ["gnss"], "additionalProperties": False}
