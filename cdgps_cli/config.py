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
