"""Structure-model configuration: TOML file → validated :class:`StructureConfig`.

The format is documented in ``docs/config-format.md``.  Loading validates everything up front and
raises one :class:`~cdgps_cli.errors.CdgpsError` that lists every problem found, each naming the
file, the key (as a dotted path such as ``modes[3].frequency_hz``) and what was expected.

Frames
------
* Lab frame N: x, y horizontal, z up (metres).
* Body frame B: origin ``body.origin_m`` in N, rotated about N's z axis by the rigid-body
  coordinate (``body.rigid_rotation``), if any.
* Section frames: each rigid section rotates about its pivot ``pivot_m`` (in B) by the angles of
  its ``rotation`` table (applied as ``Rz @ Ry @ Rx``) and translates by its ``translation``
  coordinates along B's axes.
"""

from __future__ import annotations

import hashlib
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import CdgpsError, join_problems
from .units import GPS_L1_WAVELENGTH_M

AXES = ("x", "y", "z")
COORD_KINDS = {"translation": "m", "rotation": "rad", "modal": "1"}


@dataclass(frozen=True)
class Section:
    """A rigid section of the structure.

    Attributes
    ----------
    name : str
    pivot_m : ndarray, shape (3,)
        Rotation centre in the body frame, metres.
    translation : tuple of (axis_index, coordinate_index)
        Coordinates that translate the section along body axes.
    rotation : tuple of (axis_index, coordinate_index)
        Coordinates that rotate the section about its pivot (applied Rz @ Ry @ Rx).
    """

    name: str
    pivot_m: np.ndarray
    translation: tuple
    rotation: tuple


@dataclass(frozen=True)
class StructureConfig:
    """A validated structure model.  Arrays are read-only numpy arrays.

    Shapes use ``n_q`` generalized coordinates, ``n_m`` modes, ``n_a`` antennas (master
    included), ``n_t`` transmitters, ``n_g`` gyros, ``n_u`` thrusters.
    """

    path: str
    text: str
    sha256: str
    name: str
    description: str
    sample_period_s: float
    wavelength_m: float
    measurement_sigma_m: float
    line_bias_calibrated: bool
    coord_names: tuple
    coord_kinds: tuple
    body_origin_m: np.ndarray
    rigid_index: int | None
    sections: tuple
    antenna_names: tuple
    antenna_section: np.ndarray          # (n_a,) int, -1 = fixed to the body frame
    antenna_position_m: np.ndarray       # (n_a, 3) nominal position in B
    antenna_displacement: np.ndarray     # (n_a, 3, n_q) linear displacement per coordinate
    antenna_receiver: tuple
    antenna_line_bias_m: np.ndarray      # (n_a,)
    master_index: int
    transmitter_names: tuple
    transmitter_far_field: bool
    transmitter_position_m: np.ndarray   # (n_t, 3) (near field) or unit directions (far field)
    mode_names: tuple
    mode_frequency_hz: np.ndarray        # (n_m,)
    mode_time_constant_s: np.ndarray     # (n_m,)
    mode_shapes: np.ndarray              # (n_q, n_m) = U
    process_noise_space: str             # "modal" or "coordinates"
    process_noise_sigma: np.ndarray
    gyro_names: tuple
    gyro_section: np.ndarray             # (n_g,)
    gyro_axis: np.ndarray                # (n_g, 3) unit vector in the section frame
    thruster_names: tuple
    thruster_section: np.ndarray         # (n_u,)
    thruster_position_m: np.ndarray      # (n_u, 3) in B
    thruster_direction: np.ndarray       # (n_u, 3) unit force direction in B
    thruster_max_force_n: np.ndarray     # (n_u,)
    simulation: dict = field(default_factory=dict)

    @property
    def n_q(self) -> int:
        return len(self.coord_names)

    @property
    def n_modes(self) -> int:
        return len(self.mode_names)

    @property
    def n_states(self) -> int:
        return 2 * self.n_modes

    @property
    def rover_indices(self) -> np.ndarray:
        """Indices of the non-master antennas, in config order."""
        return np.array([i for i in range(len(self.antenna_names)) if i != self.master_index])

    @property
    def rover_names(self) -> tuple:
        return tuple(self.antenna_names[i] for i in self.rover_indices)

    @property
    def channels(self) -> list[tuple[str, str]]:
        """All (antenna, transmitter) channels the model can measure, rover-major."""
        return [(a, t) for a in self.rover_names for t in self.transmitter_names]

    def coord_unit(self, name: str) -> str:
        return COORD_KINDS[self.coord_kinds[self.coord_names.index(name)]]

    def summary(self) -> dict:
        """A JSON-ready echo of the model's key settings (for outputs and ``--json``)."""
        return {
            "name": self.name,
            "path": self.path,
            "config_sha256": self.sha256,
            "sample_period_s": self.sample_period_s,
            "wavelength_m": self.wavelength_m,
            "measurement_sigma_m": self.measurement_sigma_m,
            "coordinates": list(self.coord_names),
            "modes": [
                {"name": n, "frequency_hz": float(f), "time_constant_s": float(t)}
                for n, f, t in zip(self.mode_names, self.mode_frequency_hz, self.mode_time_constant_s)
            ],
            "antennas": list(self.antenna_names),
            "master": self.antenna_names[self.master_index],
            "transmitters": list(self.transmitter_names),
            "far_field": self.transmitter_far_field,
            "gyros": list(self.gyro_names),
            "thrusters": len(self.thruster_names),
        }


# --------------------------------------------------------------------------------------------
# validation helpers

_SIM_DEFAULTS = {
    "phase_sigma_m": 0.01,
    "multipath_sigma_m": 0.0,
    "multipath_time_constant_s": 30.0,
    "snr_dbhz": 45.0,
    "initial_modal_sigma": 0.5,
    "initial_rigid_sigma_rad": 0.3,
    "disturbance_scale": 0.2,
    "gyro_noise_rad_s": 0.002,
    "gyro_bias_sigma_rad_s": 0.002,
    "gyro_bias_drift_rad_s_per_sqrt_s": 2.0e-5,
    "gyro_sample_period_s": 0.0,
    "static_rest_after_s": 60.0,
    "static_settle_s": 20.0,
    "static_angle_coordinate": "",
    "static_angle_deg": 0.0,
    "pulse_time_s": 5.0,
    "pulse_duration_s": 1.0,
    "pulse_thrusters": [],
    "pulse_force_n": 1.4,
}


class _Checker:
    """Collects problems while walking the TOML document."""

    def __init__(self, path: str):
        self.path = path
        self.problems: list[str] = []

    def add(self, key: str, msg: str) -> None:
        self.problems.append(f"{key}: {msg}")

    def keys(self, table: dict, key: str, required: set, optional: set) -> None:
        if not isinstance(table, dict):
            self.add(key, "expected a table")
            return
        for k in sorted(set(table) - required - optional):
            self.add(f"{key}.{k}" if key else k, f"unknown key (allowed: {', '.join(sorted(required | optional))})")
        for k in sorted(required - set(table)):
            self.add(f"{key}.{k}" if key else k, "missing required key")

    def number(self, table, key, name, default=None, positive=False, nonneg=False):
        full = f"{key}.{name}" if key else name
        if name not in table:
            return default
        v = table[name]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            self.add(full, f"expected a finite number, got {v!r}")
            return default
        if positive and v <= 0:
            self.add(full, f"expected a positive number, got {v!r}")
            return default
        if nonneg and v < 0:
            self.add(full, f"expected a non-negative number, got {v!r}")
            return default
        return float(v)

    def string(self, table, key, name, default=None):
        full = f"{key}.{name}" if key else name
        if name not in table:
            return default
        v = table[name]
        if not isinstance(v, str) or not v:
            self.add(full, f"expected a non-empty string, got {v!r}")
            return default
        return v

    def vector(self, table, key, name, size, default=None, unit=False):
        full = f"{key}.{name}" if key else name
        if name not in table:
            return default
        v = table[name]
        ok = isinstance(v, list) and all(
            isinstance(e, (int, float)) and not isinstance(e, bool) and np.isfinite(e) for e in v
        )
        if not ok or (size is not None and len(v) != size):
            want = f"{size} finite numbers" if size is not None else "a list of finite numbers"
            got = f"{len(v)} values" if isinstance(v, list) else repr(v)
            self.add(full, f"expected {want}, got {got}")
            return default
        arr = np.asarray(v, dtype=float)
        if unit:
            n = np.linalg.norm(arr)
            if n == 0:
                self.add(full, "expected a non-zero direction vector")
                return default
            arr = arr / n
        return arr


def _table_list(chk: _Checker, doc: dict, name: str, required: bool) -> list:
    v = doc.get(name, [])
    if not isinstance(v, list) or not all(isinstance(e, dict) for e in v):
        chk.add(name, "expected an array of tables ([[%s]])" % name)
        return []
    if required and not v:
        chk.add(name, f"at least one [[{name}]] entry is required")
    return v


def _unique(chk: _Checker, names: list, key: str) -> None:
    seen = set()
    for i, n in enumerate(names):
        if n in seen:
            chk.add(f"{key}[{i}].name", f"duplicate name {n!r}")
        seen.add(n)


def load_config(path: str | Path) -> StructureConfig:
    """Load and validate a structure-model TOML file.

    Parameters
    ----------
    path : str or Path
        The TOML file.

    Returns
    -------
    StructureConfig

    Raises
    ------
    CdgpsError
        If the file cannot be read or parsed, or if any key is unknown, missing or invalid; the
        message lists every problem with its key.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read config: {exc.strerror}") from None
    return parse_config(raw.decode("utf-8", errors="replace"), str(p))


def parse_config(text: str, path: str = "<config>") -> StructureConfig:
    """Validate a structure-model TOML document given as text (see :func:`load_config`)."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CdgpsError(f"{path}: not valid TOML: {exc}") from None
    chk = _Checker(path)
    top_allowed = {"model", "body", "coordinates", "sections", "antennas", "transmitters", "modes",
                   "process_noise", "gyros", "thrusters", "simulation"}
    chk.keys(doc, "", {"model", "coordinates", "antennas", "transmitters", "modes", "process_noise"},
             top_allowed - {"model", "coordinates", "antennas", "transmitters", "modes", "process_noise"})

    # [model]
    model = doc.get("model", {}) if isinstance(doc.get("model", {}), dict) else {}
    chk.keys(model, "model", {"name", "sample_period_s", "measurement_sigma_m"},
             {"description", "wavelength_m", "line_bias_calibrated"})
    name = chk.string(model, "model", "name", "unnamed")
    description = model.get("description", "") if isinstance(model.get("description", ""), str) else ""
    dt = chk.number(model, "model", "sample_period_s", 0.1, positive=True)
    wavelength = chk.number(model, "model", "wavelength_m", GPS_L1_WAVELENGTH_M, positive=True)
    sigma = chk.number(model, "model", "measurement_sigma_m", 0.01, positive=True)
    lbc = model.get("line_bias_calibrated", True)
    if not isinstance(lbc, bool):
        chk.add("model.line_bias_calibrated", f"expected true or false, got {lbc!r}")
        lbc = True

    # [[coordinates]]
    coords = _table_list(chk, doc, "coordinates", True)
    coord_names, coord_kinds = [], []
    for i, c in enumerate(coords):
        key = f"coordinates[{i}]"
        chk.keys(c, key, {"name", "kind"}, {"description"})
        coord_names.append(chk.string(c, key, "name", f"?{i}"))
        kind = c.get("kind", "modal")
        if kind not in COORD_KINDS:
            chk.add(f"{key}.kind", f"expected one of {sorted(COORD_KINDS)}, got {kind!r}")
            kind = "modal"
        coord_kinds.append(kind)
    _unique(chk, coord_names, "coordinates")
    n_q = len(coord_names)
    cindex = {n: i for i, n in enumerate(coord_names)}

    def coord_ref(value, key, kind=None):
        if not isinstance(value, str) or value not in cindex:
            chk.add(key, f"expected the name of a coordinate ({', '.join(coord_names)}), got {value!r}")
            return None
        j = cindex[value]
        if kind and coord_kinds[j] != kind:
            chk.add(key, f"coordinate {value!r} is a {coord_kinds[j]}, expected a {kind}")
        return j

    # [body]
    body = doc.get("body", {})
    chk.keys(body, "body", set(), {"origin_m", "rigid_rotation"})
    body = body if isinstance(body, dict) else {}
    origin = chk.vector(body, "body", "origin_m", 3, np.zeros(3))
    rigid_index = None
    if "rigid_rotation" in body:
        rigid_index = coord_ref(body["rigid_rotation"], "body.rigid_rotation", "rotation")

    # [[sections]]
    sections = []
    sec_tables = _table_list(chk, doc, "sections", False)
    used_coords: dict[int, str] = {}
    for i, s in enumerate(sec_tables):
        key = f"sections[{i}]"
        chk.keys(s, key, {"name", "pivot_m"}, {"translation", "rotation"})
        sname = chk.string(s, key, "name", f"?{i}")
        pivot = chk.vector(s, key, "pivot_m", 3, np.zeros(3))
        parts = {}
        for part in ("translation", "rotation"):
            tbl = s.get(part, {})
            if not isinstance(tbl, dict):
                chk.add(f"{key}.{part}", "expected a table such as {x = \"q1\"}")
                tbl = {}
            items = []
            for ax, ref in tbl.items():
                if ax not in AXES:
                    chk.add(f"{key}.{part}.{ax}", "expected an axis x, y or z")
                    continue
                j = coord_ref(ref, f"{key}.{part}.{ax}", "translation" if part == "translation" else "rotation")
                if j is not None:
                    if j in used_coords:
                        chk.add(f"{key}.{part}.{ax}", f"coordinate {ref!r} already drives {used_coords[j]}")
                    used_coords[j] = f"{key}.{part}.{ax}"
                    items.append((AXES.index(ax), j))
            parts[part] = tuple(sorted(items))
        sections.append(Section(sname, pivot, parts["translation"], parts["rotation"]))
    _unique(chk, [s.name for s in sections], "sections")
    sindex = {s.name: i for i, s in enumerate(sections)}

    def section_ref(tbl, key):
        if "section" not in tbl:
            return -1
        v = tbl["section"]
        if v not in sindex:
            chk.add(f"{key}.section", f"expected the name of a section ({', '.join(sindex) or 'none defined'}), got {v!r}")
            return -1
        return sindex[v]

    # [[antennas]]
    ants = _table_list(chk, doc, "antennas", True)
    a_names, a_sec, a_pos, a_disp, a_rx, a_lb, masters = [], [], [], [], [], [], []
    for i, a in enumerate(ants):
        key = f"antennas[{i}]"
        chk.keys(a, key, {"name", "position_m"}, {"section", "receiver", "master", "line_bias_m", "displacement_m"})
        a_names.append(chk.string(a, key, "name", f"?{i}"))
        a_sec.append(section_ref(a, key))
        a_pos.append(chk.vector(a, key, "position_m", 3, np.zeros(3)))
        a_rx.append(chk.string(a, key, "receiver", "rx1"))
        a_lb.append(chk.number(a, key, "line_bias_m", 0.0))
        m = a.get("master", False)
        if not isinstance(m, bool):
            chk.add(f"{key}.master", f"expected true or false, got {m!r}")
        elif m:
            masters.append(i)
        disp = np.zeros((3, n_q))
        dtbl = a.get("displacement_m", {})
        if not isinstance(dtbl, dict):
            chk.add(f"{key}.displacement_m", "expected a table {coordinate = [dx, dy, dz]}")
            dtbl = {}
        for ref, vec in dtbl.items():
            j = coord_ref(ref, f"{key}.displacement_m.{ref}")
            v = chk.vector(dtbl, f"{key}.displacement_m", ref, 3)
            if j is not None and v is not None:
                disp[:, j] = v
        a_disp.append(disp)
    _unique(chk, a_names, "antennas")
    if len(masters) != 1:
        chk.add("antennas", f"exactly one antenna must have master = true, found {len(masters)}")
    if len(ants) < 2:
        chk.add("antennas", "at least a master and one other antenna are required")

    # [[transmitters]]
    txs = _table_list(chk, doc, "transmitters", True)
    t_names, t_pos, far = [], [], []
    for i, t in enumerate(txs):
        key = f"transmitters[{i}]"
        chk.keys(t, key, {"name"}, {"position_m", "direction", "description"})
        t_names.append(chk.string(t, key, "name", f"?{i}"))
        if ("position_m" in t) == ("direction" in t):
            chk.add(key, "give exactly one of position_m (near field, metres in the lab frame) or direction (far field, unit vector toward the source)")
            t_pos.append(np.zeros(3))
            far.append(False)
        elif "position_m" in t:
            t_pos.append(chk.vector(t, key, "position_m", 3, np.zeros(3)))
            far.append(False)
        else:
            t_pos.append(chk.vector(t, key, "direction", 3, np.array([0.0, 0.0, 1.0]), unit=True))
            far.append(True)
    _unique(chk, t_names, "transmitters")
    if far and len(set(far)) > 1:
        chk.add("transmitters", "mixing near-field (position_m) and far-field (direction) transmitters is not supported")

    # [[modes]]
    modes = _table_list(chk, doc, "modes", True)
    m_names, m_f, m_tau, shapes = [], [], [], []
    for i, m in enumerate(modes):
        key = f"modes[{i}]"
        chk.keys(m, key, {"name", "frequency_hz", "time_constant_s", "shape"}, {"description", "rigid"})
        m_names.append(chk.string(m, key, "name", f"?{i}"))
        rigid = m.get("rigid", False)
        if not isinstance(rigid, bool):
            chk.add(f"{key}.rigid", f"expected true or false, got {rigid!r}")
            rigid = False
        if rigid:
            f = chk.number(m, key, "frequency_hz", 0.0, nonneg=True)
            if f is not None and f != 0.0:
                chk.add(f"{key}.frequency_hz", "a rigid-body mode (rigid = true) must have frequency_hz = 0")
        else:
            f = chk.number(m, key, "frequency_hz", 1.0, positive=True)
            if "frequency_hz" in m and m["frequency_hz"] == 0:
                chk.problems[-1] += " (set rigid = true for a rigid-body mode)"
        m_f.append(f if f is not None else 1.0)
        m_tau.append(chk.number(m, key, "time_constant_s", 1e9, positive=True))
        shapes.append(chk.vector(m, key, "shape", n_q, np.zeros(n_q)))
    _unique(chk, m_names, "modes")
    U = np.array(shapes).T if shapes else np.zeros((n_q, 0))
    if shapes and not chk.problems:
        s = np.linalg.svd(U, compute_uv=False)
        if s.size and s.min() <= 1e-12 * max(s.max(), 1e-300):
            chk.add("modes", "mode shapes are linearly dependent (U has deficient column rank)")

    # [process_noise]
    pn = doc.get("process_noise", {})
    chk.keys(pn, "process_noise", {"space", "sigma"}, set())
    pn = pn if isinstance(pn, dict) else {}
    space = pn.get("space", "modal")
    if space not in ("modal", "coordinates"):
        chk.add("process_noise.space", f"expected \"modal\" or \"coordinates\", got {space!r}")
        space = "modal"
    size = len(m_names) if space == "modal" else n_q
    pn_sigma = chk.vector(pn, "process_noise", "sigma", size, np.zeros(size))
    if pn_sigma is not None and np.any(pn_sigma < 0):
        chk.add("process_noise.sigma", "expected non-negative values")

    # [[gyros]]
    g_names, g_sec, g_axis = [], [], []
    for i, g in enumerate(_table_list(chk, doc, "gyros", False)):
        key = f"gyros[{i}]"
        chk.keys(g, key, {"name", "section", "axis"}, {"description"})
        g_names.append(chk.string(g, key, "name", f"?{i}"))
        g_sec.append(section_ref(g, key))
        ax = g.get("axis")
        if ax in AXES:
            g_axis.append(np.eye(3)[AXES.index(ax)])
        else:
            v = chk.vector(g, key, "axis", 3, None, unit=True) if isinstance(ax, list) else None
            if v is None and not isinstance(ax, list):
                chk.add(f"{key}.axis", f"expected x, y, z or a 3-vector, got {ax!r}")
            g_axis.append(v if v is not None else np.array([0.0, 0.0, 1.0]))
    _unique(chk, g_names, "gyros")

    # [[thrusters]]
    u_names, u_sec, u_pos, u_dir, u_max = [], [], [], [], []
    for i, u in enumerate(_table_list(chk, doc, "thrusters", False)):
        key = f"thrusters[{i}]"
        chk.keys(u, key, {"name", "position_m", "direction"}, {"section", "max_force_n"})
        u_names.append(chk.string(u, key, "name", f"?{i}"))
        u_sec.append(section_ref(u, key))
        u_pos.append(chk.vector(u, key, "position_m", 3, np.zeros(3)))
        u_dir.append(chk.vector(u, key, "direction", 3, np.array([1.0, 0.0, 0.0]), unit=True))
        u_max.append(chk.number(u, key, "max_force_n", np.inf, positive=True))
    _unique(chk, u_names, "thrusters")

    # [simulation]
    sim = dict(_SIM_DEFAULTS)
    st = doc.get("simulation", {})
    chk.keys(st, "simulation", set(), set(_SIM_DEFAULTS))
    if isinstance(st, dict):
        for k, v in st.items():
            if k not in _SIM_DEFAULTS:
                continue
            d = _SIM_DEFAULTS[k]
            if isinstance(d, str):
                if not isinstance(v, str):
                    chk.add(f"simulation.{k}", f"expected a string, got {v!r}")
                    continue
                if v and k == "static_angle_coordinate" and v not in cindex:
                    chk.add(f"simulation.{k}", f"expected a coordinate name, got {v!r}")
            elif isinstance(d, list):
                if not isinstance(v, list) or not all(isinstance(e, str) and e in u_names for e in v):
                    chk.add(f"simulation.{k}", f"expected a list of thruster names ({', '.join(u_names) or 'none defined'})")
                    continue
            else:
                v = chk.number(st, "simulation", k, d, nonneg=(k != "static_angle_deg"))
            sim[k] = v

    if chk.problems:
        raise CdgpsError(join_problems(f"{path}: invalid config", chk.problems))

    def ro(a, dtype=float):
        arr = np.array(a, dtype=dtype)
        arr.setflags(write=False)
        return arr

    return StructureConfig(
        path=path,
        text=text,
        sha256=hashlib.sha256(text.encode("utf-8")).hexdigest(),
        name=name,
        description=description,
        sample_period_s=dt,
        wavelength_m=wavelength,
        measurement_sigma_m=sigma,
        line_bias_calibrated=lbc,
        coord_names=tuple(coord_names),
        coord_kinds=tuple(coord_kinds),
        body_origin_m=ro(origin),
        rigid_index=rigid_index,
        sections=tuple(sections),
        antenna_names=tuple(a_names),
        antenna_section=ro(a_sec, int),
        antenna_position_m=ro(np.reshape(a_pos, (-1, 3))),
        antenna_displacement=ro(np.reshape(a_disp, (-1, 3, n_q))),
        antenna_receiver=tuple(a_rx),
        antenna_line_bias_m=ro(a_lb),
        master_index=masters[0],
        transmitter_names=tuple(t_names),
        transmitter_far_field=bool(far and far[0]),
        transmitter_position_m=ro(np.reshape(t_pos, (-1, 3))),
        mode_names=tuple(m_names),
        mode_frequency_hz=ro(m_f),
        mode_time_constant_s=ro(m_tau),
        mode_shapes=ro(U),
        process_noise_space=space,
        process_noise_sigma=ro(pn_sigma),
        gyro_names=tuple(g_names),
        gyro_section=ro(g_sec, int),
        gyro_axis=ro(np.reshape(g_axis, (-1, 3))),
        thruster_names=tuple(u_names),
        thruster_section=ro(u_sec, int),
        thruster_position_m=ro(np.reshape(u_pos, (-1, 3))),
        thruster_direction=ro(np.reshape(u_dir, (-1, 3))),
        thruster_max_force_n=ro(u_max),
        simulation=sim,
    )


# ============================================================================================
# GNSS run configs (real receivers: RINEX / UBX files, a master, rover displacement states)
# Format: docs/gnss-pipeline.md.  Additive: the structure-model schema above is unchanged.
# ============================================================================================

GNSS_DISPLACEMENT_MODELS = ("static", "random_walk")
GNSS_WEIGHTINGS = ("elevation", "equal")
# defaults of the GNSS solver settings: the [gnss] parser, GnssConfig and baseline.BaselineOptions all
# take them from here (RTKLIB-comparable: 15° mask, ratio 3, a = b = 3 mm, code/phase ratio 100, DTTOL)
GNSS_DEFAULTS = {"mask_deg": 15.0, "ratio": 3.0, "weighting": "elevation", "sigma_a_m": 0.003,
                 "sigma_b_m": 0.003, "code_ratio": 100.0, "sync_tol_s": 0.025,
                 "random_walk_sigma": (0.001, 0.001, 0.001), "initial_sigma_m": 1.0}

_GNSS_KEYS = {
    "name": "string", "description": "string", "master": "string", "nav": "list of file paths",
    "mask_deg": "number", "ratio": "number", "partial": "bool", "fix": "bool", "weighting": "string",
    "sigma_a_m": "number", "sigma_b_m": "number", "code_ratio": "number", "troposphere": "bool",
    "max_gap_s": "number", "sync_tol_s": "number", "antennas": "table", "displacement": "table",
}
_GNSS_ANTENNA_KEYS = {"rinex", "ubx", "position_ecef_m", "description"}
_GNSS_DISPLACEMENT_KEYS = {"model", "sigma_m_per_sqrt_s", "initial_sigma_m"}


@dataclass(frozen=True)
class GnssAntenna:
    """One receiver antenna of a GNSS run config.

    Attributes
    ----------
    name : str
        Antenna name; the rover coordinates are ``<name>_e``, ``<name>_n``, ``<name>_u``.
    rinex, ubx : str or None
        Observation file (RINEX or u-blox UBX), resolved against the config file's directory;
        None when the files come from the command line.
    position_ecef_m : tuple of 3 floats or None
        Nominal (a priori) antenna position, ECEF m; None: the RINEX header APPROX POSITION XYZ
        (a rover without one gets a pseudorange single-point position).
    description : str
    """

    name: str
    rinex: str | None = None
    ubx: str | None = None
    position_ecef_m: tuple | None = None
    description: str = ""


@dataclass(frozen=True)
class GnssConfig:
    """A validated GNSS run config (``[gnss]`` table; docs/gnss-pipeline.md).

    The processing settings mirror :class:`~cdgps_cli.baseline.BaselineOptions` (see
    :meth:`baseline_options`); the displacement model says how the rover states evolve:
    ``static`` (one E/N/U displacement per rover for the whole run) or ``random_walk`` (E/N/U
    displacements that wander with white-noise rates of ``random_walk_sigma`` m/√s).
    """

    path: str
    text: str
    sha256: str
    name: str
    description: str
    master: str | None
    antennas: tuple
    nav: tuple
    mask_deg: float = GNSS_DEFAULTS["mask_deg"]
    ratio: float = GNSS_DEFAULTS["ratio"]
    partial: bool = True
    fix: bool = True
    weighting: str = GNSS_DEFAULTS["weighting"]
    sigma_a_m: float = GNSS_DEFAULTS["sigma_a_m"]
    sigma_b_m: float = GNSS_DEFAULTS["sigma_b_m"]
    code_ratio: float = GNSS_DEFAULTS["code_ratio"]
    troposphere: bool = True
    max_gap_s: float | None = None
    sync_tol_s: float = GNSS_DEFAULTS["sync_tol_s"]
    displacement: str = "static"
    random_walk_sigma: tuple = GNSS_DEFAULTS["random_walk_sigma"]
    initial_sigma_m: float = GNSS_DEFAULTS["initial_sigma_m"]

    def antenna(self, name: str) -> GnssAntenna | None:
        return next((a for a in self.antennas if a.name == name), None)

    @property
    def antenna_names(self) -> tuple:
        return tuple(a.name for a in self.antennas)

    def baseline_options(self, **overrides):
        """The solver settings as :class:`~cdgps_cli.baseline.BaselineOptions`."""
        from .baseline import BaselineOptions  # noqa: PLC0415 (baseline imports the GNSS stack)

        kw = dict(mask_deg=self.mask_deg, ratio_threshold=self.ratio, partial=self.partial, fix=self.fix,
                  weighting=self.weighting, sigma_a_m=self.sigma_a_m, sigma_b_m=self.sigma_b_m,
                  code_ratio=self.code_ratio, troposphere=self.troposphere, max_gap_s=self.max_gap_s,
                  sync_tol_s=self.sync_tol_s, motion=self.displacement, random_walk_sigma=tuple(self.random_walk_sigma),
                  initial_sigma_m=self.initial_sigma_m)
        kw.update(overrides)
        return BaselineOptions(**kw)

    def summary(self) -> dict:
        return {
            "name": self.name, "path": self.path, "config_sha256": self.sha256, "master": self.master,
            "antennas": list(self.antenna_names), "nav": list(self.nav), "displacement": self.displacement,
            "random_walk_sigma_m_per_sqrt_s": list(self.random_walk_sigma) if self.displacement == "random_walk" else None,
            "mask_deg": self.mask_deg, "ratio": self.ratio,
        }


def config_kind(text: str) -> str:
    """``"gnss"`` for a GNSS run config (``[gnss]`` table) or a baseline job (``[baseline]``),
    ``"structure"`` otherwise (also for text that is not valid TOML: its loader reports that)."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        return "structure"
    return "gnss" if ("gnss" in doc or "baseline" in doc) and "model" not in doc else "structure"


def load_gnss_config(path: str | Path) -> GnssConfig:
    """Load and validate a GNSS run config file (relative file paths: against its directory)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read config: {exc.strerror}") from None
    return parse_gnss_config(raw.decode("utf-8", errors="replace"), str(p), base_dir=p.resolve().parent)


def parse_gnss_config(text: str, path: str = "<config>", base_dir: str | Path | None = None) -> GnssConfig:
    """Validate a GNSS run config given as text; every problem is listed with its key.

    ``base_dir`` resolves relative file paths (None: kept as written, e.g. for a config read
    back from a RUN.mcap, whose data are in the file).
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CdgpsError(f"{path}: not valid TOML: {exc}") from None
    chk = _Checker(path)
    for k in sorted(set(doc) - {"gnss"}):
        hint = " (a [baseline] job: only 'cdgps baseline' reads it; see docs/gnss-pipeline.md for the [gnss] form)" \
            if k == "baseline" else " (a GNSS run config has one [gnss] table)"
        chk.add(k, "unknown top-level key" + hint)
    g = doc.get("gnss")
    if not isinstance(g, dict):
        chk.add("gnss", "missing [gnss] table")
        raise CdgpsError(join_problems(f"{path}: invalid GNSS config", chk.problems))
    for k in sorted(set(g) - set(_GNSS_KEYS)):
        chk.add(f"gnss.{k}", f"unknown key (allowed: {', '.join(sorted(_GNSS_KEYS))})")

    def resolve(v: str) -> str:
        if base_dir is None or Path(v).is_absolute():
            return v
        import os  # noqa: PLC0415

        return os.path.normpath(str(Path(base_dir) / v))

    def flag(name, default):
        v = g.get(name, default)
        if not isinstance(v, bool):
            chk.add(f"gnss.{name}", f"expected true or false, got {v!r}")
            return default
        return v

    name = chk.string(g, "gnss", "name", Path(path).stem if path and not path.startswith("<") else "gnss-run")
    description = chk.string(g, "gnss", "description", "")
    master = chk.string(g, "gnss", "master", None)
    nav = []
    if "nav" in g:
        v = g["nav"]
        if isinstance(v, str):
            v = [v]
        if not isinstance(v, list):
            chk.add("gnss.nav", f"expected a list of navigation file paths, got {v!r}")
        else:
            for i, e in enumerate(v):
                if not isinstance(e, str) or not e:
                    chk.add(f"gnss.nav[{i}]", f"expected a file path string, got {e!r}")
                else:
                    nav.append(resolve(e))
    mask = chk.number(g, "gnss", "mask_deg", GNSS_DEFAULTS["mask_deg"])
    if mask is not None and not 0.0 <= mask < 90.0:
        chk.add("gnss.mask_deg", f"expected an elevation mask in [0, 90) degrees, got {mask!r}")
    ratio = chk.number(g, "gnss", "ratio", GNSS_DEFAULTS["ratio"])
    if ratio is not None and ratio < 1.0:
        chk.add("gnss.ratio", f"expected a ratio-test threshold >= 1, got {ratio!r}")
    weighting = chk.string(g, "gnss", "weighting", GNSS_DEFAULTS["weighting"])
    if weighting not in GNSS_WEIGHTINGS:
        chk.add("gnss.weighting", f"expected one of {', '.join(GNSS_WEIGHTINGS)}, got {weighting!r}")
    sa = chk.number(g, "gnss", "sigma_a_m", GNSS_DEFAULTS["sigma_a_m"], nonneg=True)
    sb = chk.number(g, "gnss", "sigma_b_m", GNSS_DEFAULTS["sigma_b_m"], nonneg=True)
    if sa == 0 and sb == 0:
        chk.add("gnss.sigma_a_m", "sigma_a_m and sigma_b_m cannot both be 0")
    code_ratio = chk.number(g, "gnss", "code_ratio", GNSS_DEFAULTS["code_ratio"], positive=True)
    max_gap = chk.number(g, "gnss", "max_gap_s", None, positive=True)
    sync = chk.number(g, "gnss", "sync_tol_s", GNSS_DEFAULTS["sync_tol_s"], positive=True)
    if sync is not None and sync > 1.0:
        chk.add("gnss.sync_tol_s", f"expected at most 1 s, got {sync!r}")

    # [gnss.displacement]
    disp = g.get("displacement", {})
    model, rw, init_sigma = "static", GNSS_DEFAULTS["random_walk_sigma"], GNSS_DEFAULTS["initial_sigma_m"]
    if not isinstance(disp, dict):
        chk.add("gnss.displacement", "expected a table ([gnss.displacement])")
        disp = {}
    for k in sorted(set(disp) - _GNSS_DISPLACEMENT_KEYS):
        chk.add(f"gnss.displacement.{k}", f"unknown key (allowed: {', '.join(sorted(_GNSS_DISPLACEMENT_KEYS))})")
    model = disp.get("model", "static")
    if model not in GNSS_DISPLACEMENT_MODELS:
        chk.add("gnss.displacement.model", f"expected one of {', '.join(repr(m) for m in GNSS_DISPLACEMENT_MODELS)}, got {model!r}")
        model = "static"
    if "sigma_m_per_sqrt_s" in disp:
        v = disp["sigma_m_per_sqrt_s"]
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            v = [v, v, v]
        arr = chk.vector({"s": v}, "gnss.displacement", "s", 3, None)
        if arr is None:
            chk.problems[-1] = chk.problems[-1].replace("gnss.displacement.s:", "gnss.displacement.sigma_m_per_sqrt_s:")
        elif np.any(arr <= 0):
            chk.add("gnss.displacement.sigma_m_per_sqrt_s", f"expected positive values (m/√s), got {v!r}")
        else:
            rw = tuple(float(x) for x in arr)
        if disp.get("model", "static") == "static":
            chk.add("gnss.displacement.sigma_m_per_sqrt_s", "only used with model = \"random_walk\" (a static displacement has no process noise)")
    init_sigma = chk.number(disp, "gnss.displacement", "initial_sigma_m", 1.0, positive=True)

    # [gnss.antennas.NAME]
    ants = []
    at = g.get("antennas", {})
    if not isinstance(at, dict):
        chk.add("gnss.antennas", "expected tables [gnss.antennas.NAME]")
        at = {}
    for an, a in at.items():
        key = f"gnss.antennas.{an}"
        if not isinstance(a, dict):
            chk.add(key, "expected a table (rinex/ubx file, position_ecef_m)")
            continue
        for k in sorted(set(a) - _GNSS_ANTENNA_KEYS):
            chk.add(f"{key}.{k}", f"unknown key (allowed: {', '.join(sorted(_GNSS_ANTENNA_KEYS))})")
        rinex = chk.string(a, key, "rinex", None)
        ubx = chk.string(a, key, "ubx", None)
        if rinex and ubx:
            chk.add(key, "give one observation file: rinex or ubx, not both")
        pos = chk.vector(a, key, "position_ecef_m", 3, None)
        if pos is not None and np.linalg.norm(pos) < 6.0e6:
            chk.add(f"{key}.position_ecef_m", f"expected an ECEF position near the Earth's surface (m), got {a['position_ecef_m']!r}")
            pos = None
        ants.append(GnssAntenna(str(an), resolve(rinex) if rinex else None, resolve(ubx) if ubx else None,
                                tuple(float(x) for x in pos) if pos is not None else None,
                                a.get("description", "") if isinstance(a.get("description", ""), str) else ""))
    if master is not None and ants and master not in [a.name for a in ants]:
        chk.add("gnss.master", f"{master!r} is not one of gnss.antennas ({', '.join(a.name for a in ants)})")

    if chk.problems:
        raise CdgpsError(join_problems(f"{path}: invalid GNSS config", chk.problems))
    return GnssConfig(
        path=path, text=text, sha256=hashlib.sha256(text.encode("utf-8")).hexdigest(), name=name,
        description=description or "", master=master, antennas=tuple(ants), nav=tuple(nav),
        mask_deg=mask, ratio=ratio, partial=flag("partial", True), fix=flag("fix", True), weighting=weighting,
        sigma_a_m=sa, sigma_b_m=sb, code_ratio=code_ratio, troposphere=flag("troposphere", True),
        max_gap_s=max_gap, sync_tol_s=sync, displacement=model, random_walk_sigma=rw, initial_sigma_m=init_sigma,
    )


def _toml_str(s: str) -> str:
    return '"' + str(s).replace("\\", "\\\\").replace('"', '\\"') + '"'


def gnss_config_toml(antennas: dict, nav=(), master: str | None = None, *, name: str | None = None,
                     description: str = "", displacement: str = "static", sigma_m_per_sqrt_s=None,
                     positions: dict | None = None, comments=(), options: dict | None = None) -> str:
    """Text of a GNSS run config (the format :func:`parse_gnss_config` reads).

    Parameters
    ----------
    antennas : dict
        ``{name: (kind, path)}`` with kind ``"rinex"`` or ``"ubx"`` (path None: no file entry).
    nav : sequence of str
        Navigation file paths, written as given.
    master : str, optional
        Default: the first antenna.
    positions : dict, optional
        ``{name: (x, y, z)}`` nominal ECEF positions to write (others: from the RINEX header).
    comments : sequence of str
        Comment lines written at the top.
    options : dict, optional
        Extra ``[gnss]`` keys (mask_deg, ratio, …), written in this order.
    """
    master = master or next(iter(antennas), None)
    out = [f"# {c}" if c else "#" for c in comments]
    if out:
        out.append("")
    out += ["[gnss]", f"name = {_toml_str(name or '-'.join(antennas) or 'gnss-run')}"]
    if description:
        out.append(f"description = {_toml_str(description)}")
    if master:
        out.append(f"master = {_toml_str(master)}")
    out.append("nav = [" + ", ".join(_toml_str(p) for p in nav) + "]")
    opts = {"mask_deg": 15.0, "ratio": 3.0, "partial": True, "weighting": "elevation", "troposphere": True}
    opts.update(options or {})
    notes = {"mask_deg": "elevation mask at every receiver, degrees", "ratio": "LAMBDA ratio-test threshold",
             "partial": "partial fixing when the full set fails the ratio test",
             "weighting": 'phase variance a^2 + b^2/sin^2(el) ("elevation") or a^2 + b^2 ("equal")',
             "troposphere": "a priori hydrostatic troposphere (Saastamoinen x Niell), as RTKLIB"}
    for k, v in opts.items():
        val = ("true" if v else "false") if isinstance(v, bool) else (_toml_str(v) if isinstance(v, str) else repr(float(v)))
        out.append(f"{k} = {val}" + (f"    # {notes[k]}" if k in notes else ""))
    out += ["", "[gnss.displacement]",
            f"model = {_toml_str(displacement)}    # \"static\" or \"random_walk\" E/N/U displacement of each rover"]
    if displacement == "random_walk":
        sig = sigma_m_per_sqrt_s if sigma_m_per_sqrt_s is not None else 0.001
        sig_txt = repr(float(sig)) if np.isscalar(sig) else "[" + ", ".join(repr(float(x)) for x in sig) + "]"
        out.append(f"sigma_m_per_sqrt_s = {sig_txt}    # random-walk process noise per component, m/sqrt(s)")
    for an, (kind, path) in antennas.items():
        out += ["", f"[gnss.antennas.{_toml_str(an)}]"]
        if path is not None:
            out.append(f"{kind} = {_toml_str(path)}")
        pos = (positions or {}).get(an)
        if pos is not None:
            out.append("position_ecef_m = [" + ", ".join(f"{float(x):.4f}" for x in pos) + "]")
        elif kind == "rinex":
            out.append("# position_ecef_m = [x, y, z]    # default: the RINEX header APPROX POSITION XYZ")
    return "\n".join(out) + "\n"
