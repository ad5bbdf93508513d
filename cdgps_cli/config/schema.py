"""The config files' keys, declared once (issue 32 item 6): which tables exist, which keys each
table allows and requires, their kinds, signs, sizes, defaults and meaning — the structure config
(:data:`STRUCTURE_TABLES`) and the GNSS run config (:data:`GNSS_TABLES`).

Each key is a :class:`Field`.  :func:`cdgps_cli.config.validate.check_table` judges a table by
these declarations (types, signs, vector and matrix sizes, references to other tables' names,
required keys, defaults; every message names the file and the key path), the plausible ranges
come from :data:`cdgps_cli.config.limits.CONFIG_BOUNDS`, and :func:`structure_json_schema` turns
both into a JSON Schema (draft 2020-12) published as ``docs/schema/structure-config.schema.json``:
editors that read JSON Schema for TOML (Even Better TOML / Taplo, with a ``#:schema`` comment on the
first line or an association in the settings) then complete and check a config as it is typed.
Rules across keys (exactly one master, one of two keys, shapes independent …) are the short named
checks of :func:`cdgps_cli.config.structure.parse_config`.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

from cdgps_cli.config.limits import CONFIG_BOUNDS, GNSS_MULTIPATH_SIGMA, GNSS_MULTIPATH_TAU, MASK_DEG, Bound
from cdgps_cli.config.options import GNSS_DEFAULTS
from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M

SCHEMA_ID = "https://cdgps.invalid/schema/structure-config.schema.json"

_STR = {"type": "string"}
_NUM = {"type": "number"}
_BOOL = {"type": "boolean"}
_VEC3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
_NUMS = {"type": "array", "items": {"type": "number"}}
_MATRIX = {"type": "array", "items": {"type": "array", "items": {"type": "number"}}}
_PER_COORD_VEC3 = {"type": "object", "additionalProperties": _VEC3}
_AXES_TO_COORD = {"type": "object", "properties": {a: _STR for a in "xyz"}, "additionalProperties": False}


@dataclass(frozen=True)
class Field:
    """One config key: how :mod:`cdgps_cli.config.validate` judges it and its JSON Schema.

    Attributes
    ----------
    kind : str
        ``name`` (non-empty printable string), ``text`` (any string), ``number``, ``flag``,
        ``enum`` (one of ``choices``), ``vector`` (``size`` finite numbers; ``unit``: a direction,
        normalised), ``matrix`` (``size`` × ``size``), ``ref`` (a name of table ``ref``, a
        coordinate of kind ``ref_kind``), ``names`` (a list of names of ``ref``),
        ``per_coordinate`` (``{coordinate = [x, y, z]}``, described as ``what``), ``axis``
        (x, y, z or a 3-vector), ``paths`` (one file path or a list), ``axes``, ``tables``,
        ``table``, ``signals``, ``rates`` (judged by cross-field checks).
    schema : dict
        JSON Schema of the value, with its description.
    required : bool
    default
        Value when the key is absent (``"?{i}"``: formatted with the entry's index; a callable:
        called with the validation context).
    sign : str
        ``positive`` or ``nonneg`` (numbers; ``nonneg`` also for a vector's elements).
    expect : str
        A number's range in words: the bounds of ``schema`` (minimum, exclusiveMaximum …) are then
        checked too, the message saying ``expected <expect>``.
    size : int or str
        A vector's or matrix's size, or the name of a size known when it is checked
        (``coordinates``: the number of coordinates; ``process_noise``: W's size).
    cross : bool
        Judged (also its type) by a named cross-field check in :mod:`cdgps_cli.config.structure`.
    """

    kind: str
    schema: dict
    required: bool = False
    default: object = None
    sign: str = ""
    size: object = None
    unit: bool = False
    choices: tuple = ()
    ref: str = ""
    ref_kind: str = ""
    allow_empty: bool = False
    what: str = ""
    expect: str = ""
    cross: bool = False

    def __iter__(self):
        """``required, schema`` (the pair this declaration used to be)."""
        yield self.required
        yield self.schema


def _key(schema: dict, text: str, required: bool = False, kind: str = "", **spec) -> Field:
    """A key of JSON Schema ``schema`` described by ``text``; its kind from the schema unless given."""
    if not kind:
        kind = {"string": "name", "number": "number", "boolean": "flag"}.get(schema.get("type"), "")
        if "enum" in schema:
            kind, spec = "enum", {**spec, "choices": tuple(schema["enum"])}
    return Field(kind, {**schema, "description": text}, required, **spec)


def _text(text: str = "free text") -> Field:
    return _key(_STR, text, kind="text", default="")


def _vec3(text: str, required: bool = False, **spec) -> Field:
    return _key(_VEC3, text, required, kind="vector", size=3, **spec)


def _ref(target: str, text: str, default=None, **spec) -> Field:
    return _key(_STR, text, kind="ref", ref=target, default=default, **spec)


_DISPLACEMENT = "{coordinate = [dx, dy, dz]} (m per unit coordinate)"


def _zeros(size: str):
    """A default of zeros whose length is known when the table is checked."""
    import numpy as np

    return lambda ctx: np.zeros(ctx.sizes[size])


#: table path ("" = top level, "name[]" = an array of tables) → key → Field
STRUCTURE_TABLES: dict[str, dict[str, Field]] = {
    "model": {
        "name": _key(_STR, "model name, echoed in outputs", True, default="unnamed"),
        "description": _text(),
        "sample_period_s": _key(_NUM, "T of the discrete model and the logs, s", True, default=0.1, sign="positive"),
        "wavelength_m": _key(_NUM, "carrier wavelength, m (default GPS L1, 0.190294 m)",
                             default=GPS_L1_WAVELENGTH_M, sign="positive"),
        "measurement_sigma_m": _key(_NUM, "prior carrier-phase noise (1 sigma, m) of every channel not given its own",
                                    True, default=0.01, sign="positive"),
        "line_bias_calibrated": _key(_BOOL, "antenna line biases are known, so integers can be fixed (default true)",
                                     default=True),
        "multipath_sigma_m": _key(_NUM, "Gauss-Markov multipath sigma per channel, m (0: not modelled)",
                                  default=0.0, sign="nonneg"),
        "multipath_time_constant_s": _key(_NUM, "its correlation time, s (default 30)", default=30.0, sign="positive"),
    },
    "coordinates[]": {
        "name": _key(_STR, "coordinate name (q1, ...); the state vector follows the table order", True, default="?{i}"),
        "kind": _key({"type": "string", "enum": ["translation", "rotation", "modal"]},
                     "translation (m), rotation (rad) or modal (an FE modal amplitude)", True, default="modal"),
        "unit": _key(_STR, "label for people, e.g. 'm at the top (x)'", default=""),
        "description": _text(),
    },
    "body": {
        "origin_m": _vec3("origin of the body frame in the lab frame, m (default 0)", default=(0.0, 0.0, 0.0)),
        "rigid_rotation": _ref("coordinates", "name of the rotation coordinate that turns the whole body about the "
                               "vertical", ref_kind="rotation"),
    },
    "sections[]": {
        "name": _key(_STR, "section name", True, default="?{i}"),
        "pivot_m": _vec3("rotation centre in the body frame, m", True, default=(0.0, 0.0, 0.0)),
        "translation": _key(_AXES_TO_COORD, "coordinates translating the section along x, y, z", kind="axes",
                            cross=True),
        "rotation": _key(_AXES_TO_COORD, "coordinates rotating the section about x, y, z at its pivot (Rz Ry Rx)",
                         kind="axes", cross=True),
    },
    "antennas[]": {
        "name": _key(_STR, "antenna name", True, default="?{i}"),
        "position_m": _vec3("nominal position in the body frame, m", True, default=(0.0, 0.0, 0.0)),
        "section": _ref("sections", "section it is fixed to (omitted: the body)", default=-1),
        "receiver": _key(_STR, "receiver label", default="rx1"),
        "master": _key(_BOOL, "the common master of every differential measurement (exactly one antenna)",
                       default=False),
        "line_bias_m": _key(_NUM, "calibrated electrical-length term of the antenna, m", default=0.0),
        "displacement_m": _key(_PER_COORD_VEC3, "linear displacement per unit of each coordinate (FE mode shapes), m",
                               kind="per_coordinate", what=_DISPLACEMENT, default=lambda ctx: _zeros3(ctx)),
        "sigma_m": _key(_NUM, "prior phase noise of every channel of this rover antenna, m", default=float("nan"),
                        sign="positive"),
    },
    "transmitters[]": {
        "name": _key(_STR, "transmitter name", True, default="?{i}"),
        "position_m": _vec3("near field (pseudolite): position in the lab frame, m"),
        "direction": _vec3("far field: unit vector toward the source", unit=True),
        "description": _text(),
        "sigma_m": _key(_NUM, "prior phase noise of every channel of this transmitter, m", default=float("nan"),
                        sign="positive"),
    },
    "modes[]": {
        "name": _key(_STR, "mode name", True, default="?{i}"),
        "frequency_hz": _key(_NUM, "natural frequency, Hz (0 only for a rigid mode)", True),
        "shape": _key(_NUMS, "one value per coordinate: a column of U with q = U xi", True, kind="vector",
                      size="coordinates", default=_zeros("coordinates")),
        "description": _text(),
        "rigid": _key(_BOOL, "the rigid-body mode", default=False),
        "time_constant_s": _key(_NUM, "envelope time constant tau, s (zeta = 1/(omega tau)); or damping_ratio",
                                sign="positive"),
        "damping_ratio": _key(_NUM, "modal damping ratio zeta, 0 < zeta < 1; or time_constant_s", sign="positive"),
    },
    "process_noise": {
        "space": _key({"type": "string", "enum": ["modal", "coordinates"]},
                      "white noise on each modal acceleration, or on each coordinate's", True, default="modal"),
        "sigma": _key(_NUMS, "one sigma per mode (or coordinate): W = diag(sigma^2)", kind="vector",
                      size="process_noise", sign="nonneg"),
        "covariance": _key(_MATRIX, "the full W, a list of rows", kind="matrix", size="process_noise"),
        "cholesky": _key(_MATRIX, "a lower-triangular L with W = L L^T", kind="matrix", size="process_noise"),
    },
    "channel_sigma[]": {
        "antenna": _ref("rover_antennas", "rover antenna of the channel", required=True),
        "transmitter": _ref("transmitters", "transmitter of the channel", required=True),
        "sigma_m": _key(_NUM, "prior phase noise of that channel, m", True, sign="positive"),
        "description": _text(),
    },
    "gyros[]": {
        "name": _key(_STR, "gyro name", True, default="?{i}"),
        "axis": _key({"oneOf": [{"type": "string", "enum": ["x", "y", "z"]}, _VEC3]},
                     "sensitive axis: x, y, z of the section / body frame, or a 3-vector", True, kind="axis",
                     default=(0.0, 0.0, 1.0)),
        "description": _text(),
        "section": _ref("sections", "section the gyro is mounted on", default=-1),
        "rotation_rad": _key(_PER_COORD_VEC3, "rotation vector of the mount per unit of each coordinate (FE), rad",
                             kind="per_coordinate", what="{coordinate = [rx, ry, rz]} (rad per unit coordinate)",
                             default=lambda ctx: _zeros3(ctx)),
        "sigma_rad_s": _key(_NUM, "white noise of the gyro as a fused measurement, rad/s (default [simulation] "
                                  "gyro_noise_rad_s)", sign="positive"),
        "bias_sigma_rad_s": _key(_NUM, "prior sigma of its bias state, rad/s (default [simulation] "
                                       "gyro_bias_sigma_rad_s)", sign="nonneg"),
        "bias_drift_rad_s_per_sqrt_s": _key(_NUM, "random walk of its bias, rad/s/sqrt(s) "
                                                  "(default [simulation] gyro_bias_drift_rad_s_per_sqrt_s)", sign="nonneg"),
    },
    # the fused sensors' tables: judged by cdgps_cli.config.sensors (the structure parser checks their names only)
    "accelerometers[]": {
        "name": _key(_STR, "accelerometer name", True),
        "point": _key(_STR, "antenna or [[points]] name it is attached to", True),
        "axes": _key({"oneOf": [{"type": "string", "enum": ["x", "y", "z"]},
                                {"type": "array", "items": {"type": "string", "enum": ["x", "y", "z"]}}]},
                     "sensitive axis or axes (body frame): \"x\" (uniaxial) or [\"x\", \"y\", \"z\"] (triaxial)", True,
                     kind="axes", cross=True),
        "sigma_m_s2": _key(_NUM, "white noise per axis, m/s^2", True, sign="positive"),
        "bias_sigma_m_s2": _key(_NUM, "prior sigma of each axis's bias state, m/s^2 (0: no bias state)", sign="nonneg"),
        "bias_drift_m_s2_per_sqrt_s": _key(_NUM, "random walk of each bias, m/s^2/sqrt(s)", sign="nonneg"),
        "sample_period_s": _key(_NUM, "sample period of the log, s (default [model] sample_period_s)", sign="positive"),
        "rotation_rad": _key(_PER_COORD_VEC3, "rotation of the mount per unit coordinate (FE slopes), rad: "
                                              "the gravity a tilted axis feels", kind="per_coordinate",
                             what="{coordinate = [rx, ry, rz]} (rad per unit coordinate)", cross=True),
        "description": _text(),
    },
    "tilts[]": {
        "name": _key(_STR, "tilt meter (inclinometer) name", True),
        "axis": _key({"oneOf": [{"type": "string", "enum": ["x", "y", "z"]}, _VEC3]},
                     "rotation axis sensed: x, y, z of the body frame, or a 3-vector", True, kind="axis", cross=True),
        "sigma_rad": _key(_NUM, "white noise, rad", True, sign="positive"),
        "section": _key(_STR, "section it is mounted on", kind="name", cross=True),
        "rotation_rad": _key(_PER_COORD_VEC3, "rotation vector of the mount per unit of each coordinate (FE slopes), rad",
                             kind="per_coordinate", what="{coordinate = [rx, ry, rz]} (rad per unit coordinate)",
                             cross=True),
        "bias_sigma_rad": _key(_NUM, "prior sigma of its bias state, rad (0: no bias state)", sign="nonneg"),
        "bias_drift_rad_per_sqrt_s": _key(_NUM, "random walk of its bias, rad/sqrt(s)", sign="nonneg"),
        "sample_period_s": _key(_NUM, "sample period of the log, s (default [model] sample_period_s)", sign="positive"),
        "description": _text(),
    },
    "strains[]": {
        "name": _key(_STR, "strain gauge name", True),
        "point_a": _key(_STR, "antenna or [[points]] name at one end of the gauge", True),
        "point_b": _key(_STR, "antenna or [[points]] name at the other end", True),
        "sigma_strain": _key(_NUM, "white noise, strain (dimensionless)", True, sign="positive"),
        "bias_sigma_strain": _key(_NUM, "prior sigma of its bias (zero drift) state, strain (0: no bias state)",
                                  sign="nonneg"),
        "bias_drift_strain_per_sqrt_s": _key(_NUM, "random walk of its bias, strain/sqrt(s)", sign="nonneg"),
        "sample_period_s": _key(_NUM, "sample period of the log, s (default [model] sample_period_s)", sign="positive"),
        "description": _text(),
    },
    "fusion": {
        "fuse": _key({"type": "array", "items": {"type": "string", "enum": ["gyro", "accel", "tilt", "strain"]}},
                     "sensor kinds fused with GNSS by 'estimate --structure' (opt-in; --fuse overrides)",
                     kind="names", cross=True),
        "hold_out": _key({"type": "array", "items": _STR},
                         "sensor names kept out of the fusion, as independent checks (--hold-out adds)",
                         kind="names", cross=True),
    },
    "points[]": {
        "name": _key(_STR, "point name (not an antenna name)", True, default="?{i}"),
        "position_m": _vec3("nominal position in the body frame, m", True, default=(0.0, 0.0, 0.0)),
        "section": _ref("sections", "section it is fixed to", default=-1),
        "displacement_m": _key(_PER_COORD_VEC3, "FE translations at the point per unit coordinate, m",
                               kind="per_coordinate", what=_DISPLACEMENT, default=lambda ctx: _zeros3(ctx)),
        "description": _text(),
    },
    "thrusters[]": {
        "name": _key(_STR, "thruster name", True, default="?{i}"),
        "position_m": _vec3("position in the body frame, m", True, default=(0.0, 0.0, 0.0)),
        "direction": _vec3("force direction in the body frame", True, unit=True, default=(1.0, 0.0, 0.0)),
        "section": _ref("sections", "section it is mounted on", default=-1),
        "max_force_n": _key(_NUM, "largest force, N", default=float("inf"), sign="positive"),
    },
}


def _zeros3(ctx):
    import numpy as np

    return np.zeros((3, ctx.sizes["coordinates"]))


#: the top level: which tables are required (arrays of tables are marked "[]" in STRUCTURE_TABLES)
TOP_REQUIRED = ("model", "coordinates", "antennas", "transmitters", "modes", "process_noise")
TOP_OPTIONAL = ("body", "sections", "gyros", "thrusters", "simulation", "channel_sigma", "points",
                "accelerometers", "tilts", "strains", "fusion")


def simulation_table(defaults: dict, signed=(), refs=None) -> dict[str, Field]:
    """``[simulation]`` keys from the simulator's defaults: a number (non-negative unless in
    ``signed``), a string or a list of names each; ``refs``: key → the table whose names it holds."""
    refs = refs or {}

    def field(k, v):
        if isinstance(v, str):
            return Field("ref", _STR, ref=refs[k], allow_empty=True) if k in refs else Field("text", _STR)
        if isinstance(v, list):
            return Field("names", {"type": "array", "items": _STR}, ref=refs.get(k, ""))
        return Field("number", _NUM, sign="" if k in signed else "nonneg")
    out = {}
    for k, v in defaults.items():
        f = field(k, v)
        out[k] = Field(f.kind, {**f.schema, "description": f"simulator setting (default {v!r})", "default": v},
                       default=v, sign=f.sign, ref=f.ref, allow_empty=f.allow_empty)
    return out


def required_keys(table: str) -> set[str]:
    """Keys ``table`` must have ("" for the top level)."""
    if table == "":
        return set(TOP_REQUIRED)
    return {k for k, f in STRUCTURE_TABLES[table].items() if f.required}


def optional_keys(table: str) -> set[str]:
    """Keys ``table`` may have besides the required ones."""
    if table == "":
        return set(TOP_OPTIONAL)
    return {k for k, f in STRUCTURE_TABLES[table].items() if not f.required}


def _apply_bound(schema: dict, b: Bound) -> None:
    schema["exclusiveMinimum" if b.lo_open else "minimum"] = b.lo
    schema["exclusiveMaximum" if b.hi_open else "maximum"] = b.hi


def _bound_schema(b: Bound) -> dict:
    """The JSON Schema of a number within ``b``."""
    schema = {"type": "number"}
    _apply_bound(schema, b)
    return schema


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

#: table path ("gnss", "gnss.antennas.*": every antenna, "gnss.displacement") → key → Field (defaults:
#: cdgps_cli.config.options.GNSS_DEFAULTS; ``expect``: what the JSON Schema's bounds mean, for the message)
GNSS_TABLES: dict[str, dict[str, Field]] = {
    "gnss": {
        "name": _key(_STR, "run name (default: the file's name)"),
        "description": _key(_STR, "free text", default=""),
        "master": _key(_STR, "the reference antenna (its position is held)"),
        "nav": _key(_FILES, "RINEX navigation file(s), relative to this file; globs allowed", kind="paths",
                    what="navigation file paths", default=()),
        "mask_deg": _key(_bound_schema(MASK_DEG), "elevation mask, degrees",
                         default=GNSS_DEFAULTS["mask_deg"], expect=f"an elevation mask in {MASK_DEG.text()}"),
        "ratio": _key({"type": "number", "minimum": 1}, "LAMBDA ratio-test threshold", default=GNSS_DEFAULTS["ratio"],
                      expect="a ratio-test threshold >= 1"),
        "min_success_rate": _key({"type": "number", "minimum": 0, "exclusiveMaximum": 1},
                                 "bootstrapped success rate an integer set must reach besides the ratio test",
                                 default=GNSS_DEFAULTS["min_success_rate"], expect="a probability in [0, 1)"),
        "partial": _key(_BOOL, "partial fixing when the full set fails the ratio test", default=True),
        "glonass_fix": _key(_BOOL, "GLONASS double differences fixed as integers (identical receivers only; "
                            "else float)", default=GNSS_DEFAULTS["glonass_fix"]),
        "fix": _key(_BOOL, "fix integers (false: float solution)", default=True),
        "weighting": _key({"type": "string", "enum": ["elevation", "equal"]},
                          "phase variance a² + b²/sin²(el) or a² + b²", default=GNSS_DEFAULTS["weighting"]),
        "sigma_a_m": _key({"type": "number", "minimum": 0}, "phase noise a, m", default=GNSS_DEFAULTS["sigma_a_m"],
                          sign="nonneg"),
        "sigma_b_m": _key({"type": "number", "minimum": 0}, "phase noise b (elevation term), m",
                          default=GNSS_DEFAULTS["sigma_b_m"], sign="nonneg"),
        "code_ratio": _key(_POS, "code σ / phase σ", default=GNSS_DEFAULTS["code_ratio"], sign="positive"),
        "troposphere": _key(_BOOL, "a priori hydrostatic troposphere", default=True),
        "max_gap_s": _key(_POS, "a longer gap in a satellite's phase starts a new ambiguity, s", sign="positive"),
        "sync_tol_s": _key({"type": "number", "exclusiveMinimum": 0, "maximum": 1},
                           "base and rover epochs this close are simultaneous, s", default=GNSS_DEFAULTS["sync_tol_s"],
                           sign="positive", expect="at most 1 s"),
        "max_age_s": _key(_POS, "oldest base epoch bridged to a rover epoch, s (RTKLIB's maxage)",
                          default=GNSS_DEFAULTS["max_age_s"], sign="positive"),
        "code_correlation_s": _key({"type": "number", "minimum": 0},
                                   "code errors as a Gauss-Markov process of this correlation time, s (0: white)",
                                   default=GNSS_DEFAULTS["code_correlation_s"], expect="a correlation time >= 0 s"),
        "epoch_alignment": _key({"type": "string", "enum": ["geometry", "doppler"]},
                                "how receivers' epochs are brought to one instant",
                                default=GNSS_DEFAULTS["epoch_alignment"]),
        "signals": _key({"type": "array", "items": _STR}, "signals to use, e.g. [\"G:L1\", \"E:E1\"]", kind="signals",
                        cross=True),
        "iono_threshold_km": _key({"type": "number", "minimum": 0},
                                  "baselines longer than this estimate the ionosphere, km",
                                  default=GNSS_DEFAULTS["iono_threshold_km"], sign="positive"),
        "antex": _key(_STR, "ANTEX file of the receiver antennas' phase-centre calibrations (igs20.atx …), relative to "
                            "this file: each antenna's model is taken out of its observations (default: none)"),
        "sensors": _key(_FILES, "sensor CSV logs (accelerometer, tilt, gyro; units in the column names), "
                                "relative to this file; globs allowed", kind="paths", what="sensor log paths",
                        default=()),
        "antennas": _key({"type": "object"}, "one table per antenna: [gnss.antennas.NAME] (a config of settings "
                         "only has none)", kind="tables", cross=True),
        "displacement": _key({"type": "object"}, "the rovers' motion model", kind="table", cross=True),
    },
    "gnss.antennas.*": {
        "rinex": _key(_STR, "RINEX observation file (or a quoted glob of consecutive files), relative to this file"),
        "ubx": _key(_STR, "u-blox UBX log (or a quoted glob of consecutive files), relative to this file"),
        "position_ecef_m": _vec3("nominal antenna position, ECEF m (default: the RINEX header's)"),
        "antenna_type": _key(_STR, "antenna type and radome as the ANTEX file names them (\"TRM59800.80 SCIT\"; "
                                   "default: the RINEX header's ANT # / TYPE); \"none\": no model for this antenna"),
        "description": _text(),
    },
    "gnss.displacement": {
        "model": _key({"type": "string", "enum": ["static", "random_walk", "constant_velocity"]},
                      "static, random-walk or constant-velocity E/N/U displacement", default="static"),
        "sigma_m_per_sqrt_s": _key({"oneOf": [_POS, {**_VEC3, "items": _POS}]},
                                   "random-walk rate, m/√s (one number or E, N, U)", kind="rates", cross=True),
        "initial_sigma_m": _key(_POS, "prior σ of the first epoch's position, m", default=1.0, sign="positive"),
        "accel_sigma_m_per_s_per_sqrt_s": _key(_POS, "constant_velocity: white-acceleration density of each E/N/U "
                                                     "velocity, m/s/√s", default=GNSS_DEFAULTS["accel_sigma_m_per_s_per_sqrt_s"],
                                               sign="positive"),
        "phase_noise": _key({"type": "string", "enum": ["model", "auto"]},
                            "estimate's per-epoch states: the phase variances as modelled (sigma_a_m, sigma_b_m), or "
                            "\"auto\": scaled by the unit variance of the single-epoch solutions' DD phase residuals "
                            "(honest σ where the model is far from the receivers' noise)",
                            default=GNSS_DEFAULTS["phase_noise"]),
        "multipath": _key({"type": "string", "enum": ["off", "auto", "model"]},
                          "estimate's per-epoch states: phase errors white (\"off\"), or a first-order Gauss-Markov "
                          "multipath state per satellite and signal, its sigma and time constant fitted to the "
                          "single-epoch solutions' DD phase residuals (\"auto\") or given (\"model\": "
                          "multipath_sigma_m, multipath_time_constant_s)", default=GNSS_DEFAULTS["multipath"]),
        "multipath_sigma_m": _key(_bound_schema(GNSS_MULTIPATH_SIGMA), "multipath = \"model\": the stationary sigma "
                                  "of each satellite's single-difference phase multipath, m",
                                  expect=f"a multipath sigma in {GNSS_MULTIPATH_SIGMA.text()}"),
        "multipath_time_constant_s": _key(_bound_schema(GNSS_MULTIPATH_TAU), "multipath = \"model\": its correlation "
                                          "time, s (default 30)",
                                          expect=f"a correlation time in {GNSS_MULTIPATH_TAU.text()}"),
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
