# TEMPORARY: the hand-checked parsers before the declarative validator (issue 32 item 6), for the golden comparison.
"""Structure-model configuration: TOML file → validated :class:`StructureConfig`.

The format is documented in ``docs/config-format.md``.  Loading validates everything up front and
raises one :class:`~cdgps_cli.core.errors.CdgpsError` that lists every problem found, each naming the
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

from cdgps_cli.core.errors import CdgpsError, join_problems
from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.config.limits import config_range_problems
from cdgps_cli.config.schema import gnss_keys, optional_keys, required_keys
from cdgps_cli.config.options import GNSS_DEFAULTS

AXES = ("x", "y", "z")
COORD_KINDS = {"translation": "m", "rotation": "rad", "modal": "1"}
COORD_UNIT_LABELS = {"translation": "m", "rotation": "rad", "modal": "modal amplitude"}
# a covariance is accepted as symmetric / positive semi-definite within these relative tolerances
COV_SYMMETRY_REL_TOL = 1e-9
COV_PSD_REL_TOL = 1e-10


def covariance_factor(W: np.ndarray) -> np.ndarray:
    """Square factor L with L Lᵀ = W for a symmetric positive semi-definite W (n, n).

    Cholesky when W is positive definite; otherwise V·sqrt(max(λ, 0)) from its eigen-decomposition.
    """
    W = np.asarray(W, dtype=float)
    try:
        return np.linalg.cholesky(W)
    except np.linalg.LinAlgError:
        lam, V = np.linalg.eigh(0.5 * (W + W.T))
        return V * np.sqrt(np.maximum(lam, 0.0))


def channel_sigma_m(cfg: "StructureConfig", channels) -> np.ndarray:
    """Prior carrier-phase noise σ (m, 1-σ) of each channel, from the config.

    The one place that turns the config's noise keys into per-channel values.  Precedence per
    channel: its ``[[channel_sigma]]`` entry, else the rover antenna's ``sigma_m``, else the
    transmitter's ``sigma_m``, else ``[model] measurement_sigma_m``.

    Parameters
    ----------
    cfg : StructureConfig
    channels : sequence of (antenna, transmitter) name pairs, length C

    Returns
    -------
    ndarray, shape (C,), metres
    """
    over = {(a, t): s for a, t, s in cfg.channel_sigma_overrides}
    ant = {n: i for i, n in enumerate(cfg.antenna_names)}
    tx = {n: i for i, n in enumerate(cfg.transmitter_names)}
    sa = cfg.antenna_sigma_m if cfg.antenna_sigma_m is not None else np.full(len(ant), np.nan)
    st = cfg.transmitter_sigma_m if cfg.transmitter_sigma_m is not None else np.full(len(tx), np.nan)
    out = np.empty(len(channels))
    for c, (a, t) in enumerate(channels):
        if a not in ant or t not in tx:
            raise CdgpsError(f"channel {a}/{t}: not an antenna/transmitter pair of config {cfg.name!r}")
        if (a, t) in over:
            out[c] = over[(a, t)]
        elif np.isfinite(sa[ant[a]]):
            out[c] = sa[ant[a]]
        elif np.isfinite(st[tx[t]]):
            out[c] = st[tx[t]]
        else:
            out[c] = cfg.measurement_sigma_m
    return out


def scalar_sigma_m(sigma_m: np.ndarray) -> float:
    """One σ (m) for estimators that weight every channel alike: the value itself when all channels
    agree (bit-identical to the config's ``measurement_sigma_m``), else the RMS over the channels."""
    sigma_m = np.asarray(sigma_m, dtype=float)
    if np.all(sigma_m == sigma_m[0]):
        return float(sigma_m[0])
    return float(np.sqrt(np.mean(sigma_m**2)))


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
    multipath_sigma_m: float             # first-order Gauss–Markov phase error per channel (0 = not modelled)
    multipath_time_constant_s: float     # … its correlation time
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
    process_noise_sigma: np.ndarray      # (n_w,) sqrt of the diagonal of W
    gyro_names: tuple
    gyro_section: np.ndarray             # (n_g,)
    gyro_axis: np.ndarray                # (n_g, 3) unit vector in the section frame
    thruster_names: tuple
    thruster_section: np.ndarray         # (n_u,)
    thruster_position_m: np.ndarray      # (n_u, 3) in B
    thruster_direction: np.ndarray       # (n_u, 3) unit force direction in B
    thruster_max_force_n: np.ndarray     # (n_u,)
    simulation: dict = field(default_factory=dict)
    # FE-model extensions (defaults keep configs built in code working)
    coord_unit_labels: tuple = ()        # (n_q,) human unit label per coordinate ("" = from the kind)
    mode_damping_ratio: np.ndarray | None = None   # (n_m,) ζ as given or derived (NaN for rigid modes)
    process_noise_covariance: np.ndarray | None = None   # (n_w, n_w) W; None = diag(sigma²)
    gyro_rotation: np.ndarray | None = None   # (n_g, 3, n_q) rotation vector of the gyro mount per unit coordinate
    antenna_sigma_m: np.ndarray | None = None        # (n_a,) NaN = not given
    transmitter_sigma_m: np.ndarray | None = None    # (n_t,) NaN = not given
    channel_sigma_overrides: tuple = ()   # ((antenna, transmitter, sigma_m), ...)
    point_names: tuple = ()              # named points ([[points]]) for 'export --points'
    point_section: np.ndarray | None = None        # (n_p,) int
    point_position_m: np.ndarray | None = None     # (n_p, 3)
    point_displacement: np.ndarray | None = None   # (n_p, 3, n_q)

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
        """Short unit code of a coordinate's kind: ``"m"``, ``"rad"`` or ``"1"`` (modal)."""
        return COORD_KINDS[self.coord_kinds[self.coord_names.index(name)]]

    def coord_unit_label(self, name: str) -> str:
        """Unit of a coordinate for people: its ``unit`` key, else ``m``, ``rad`` or, for a modal
        coordinate, ``modal amplitude`` (the scale of its mode shape, e.g. m at the antenna where
        the shape is 1)."""
        i = self.coord_names.index(name)
        label = self.coord_unit_labels[i] if i < len(self.coord_unit_labels) else ""
        return label or COORD_UNIT_LABELS[self.coord_kinds[i]]

    @property
    def process_noise_W(self) -> np.ndarray:
        """Process-noise covariance W (n_w, n_w): the config's full matrix or diag(sigma²)."""
        if self.process_noise_covariance is not None:
            return np.array(self.process_noise_covariance, dtype=float)
        return np.diag(np.asarray(self.process_noise_sigma, dtype=float) ** 2)

    @property
    def process_noise_factor(self) -> np.ndarray:
        """A square factor L of W = L Lᵀ (n_w, n_w): diag(sigma), or Cholesky / eigen factor."""
        if self.process_noise_covariance is None:
            return np.diag(np.asarray(self.process_noise_sigma, dtype=float))
        return covariance_factor(self.process_noise_W)

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
                {"name": n, "frequency_hz": float(f), "time_constant_s": float(t),
                 "damping_ratio": None if f == 0 else float(1.0 / (2 * np.pi * f * t))}
                for n, f, t in zip(self.mode_names, self.mode_frequency_hz, self.mode_time_constant_s)
            ],
            "antennas": list(self.antenna_names),
            "master": self.antenna_names[self.master_index],
            "transmitters": list(self.transmitter_names),
            "far_field": self.transmitter_far_field,
            "gyros": list(self.gyro_names),
            "thrusters": len(self.thruster_names),
        } | ({"multipath_sigma_m": self.multipath_sigma_m,          # only when modelled (outputs
              "multipath_time_constant_s": self.multipath_time_constant_s}  # without it stay as they were)
             if self.multipath_sigma_m > 0 else {})


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
    "slew_from_deg": 14.0,
    "slew_to_deg": -22.0,
    "slew_time_s": 5.0,
}


#: [simulation] numbers that may be negative (angles)
_SIGNED_SIM_KEYS = {"static_angle_deg", "slew_from_deg", "slew_to_deg"}


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
        bad = next((c for c in v if not c.isprintable()), None)
        if bad is not None:        # a NUL or newline in a name breaks every file that carries it (issue 32)
            self.add(full, f"expected printable characters, got {v!r} (contains U+{ord(bad):04X})")
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


def _mode_damping(chk: _Checker, m: dict, key: str, rigid: bool, f_hz: float) -> tuple[float, float]:
    """Envelope time constant τ (s) and damping ratio ζ of a [[modes]] entry (exactly one given).

    τ = 1/(ζ ω) with ω = 2π f (Table 1 of the 1998 paper); a rigid mode (f = 0) needs τ, the
    decay time constant of its rate, and has ζ = NaN.
    """
    has_tau, has_zeta = "time_constant_s" in m, "damping_ratio" in m
    if has_tau == has_zeta:
        chk.add(key, "give exactly one of time_constant_s (envelope time constant τ, s) or damping_ratio "
                     "(ζ, with τ = 1/(ζ·2π·frequency_hz))" + (", not both" if has_tau else ""))
        return 1e9, float("nan")
    omega = 2 * np.pi * f_hz
    if has_tau:
        tau = chk.number(m, key, "time_constant_s", 1e9, positive=True)
        return tau, (float("nan") if rigid else 1.0 / (omega * tau))
    if rigid:
        chk.add(f"{key}.damping_ratio", "a rigid-body mode has no damping ratio (frequency 0); give time_constant_s, the decay time constant of its rate")
        return 1e9, float("nan")
    zeta = chk.number(m, key, "damping_ratio", None, positive=True)
    if zeta is None:
        return 1e9, float("nan")
    if zeta >= 1.0:
        chk.add(f"{key}.damping_ratio", f"expected 0 < ζ < 1 (an underdamped mode), got {zeta!r}")
        return 1e9, float("nan")
    return 1.0 / (zeta * omega), zeta


def _square_matrix(chk: _Checker, tbl: dict, key: str, size: int):
    """A size×size list of lists of finite numbers, or None (with a problem recorded)."""
    v = tbl[key.rsplit(".", 1)[1]]
    ok = (isinstance(v, list) and len(v) == size and all(
        isinstance(r, list) and len(r) == size and all(
            isinstance(e, (int, float)) and not isinstance(e, bool) and np.isfinite(e) for e in r) for r in v))
    if not ok:
        got = f"{len(v)} rows" if isinstance(v, list) else repr(v)
        chk.add(key, f"expected a {size}×{size} matrix (a list of {size} rows of {size} finite numbers), got {got}")
        return None
    return np.array(v, dtype=float)


def _process_noise(chk: _Checker, pn: dict, size: int, space: str):
    """(sigma (size,), covariance (size, size) or None) from [process_noise]: sigma | covariance | cholesky."""
    given = [k for k in ("sigma", "covariance", "cholesky") if k in pn]
    what = "modes" if space == "modal" else "coordinates"
    if len(given) != 1:
        chk.add("process_noise", "give exactly one of sigma (diagonal W, one σ per %s), covariance (full W, "
                "%d×%d) or cholesky (lower-triangular L with W = L·Lᵀ)%s" % (what, size, size,
                                                                           f"; got {', '.join(given)}" if given else ""))
        return np.zeros(size), None
    if given[0] == "sigma":
        sig = chk.vector(pn, "process_noise", "sigma", size, np.zeros(size))
        if sig is not None and np.any(sig < 0):
            chk.add("process_noise.sigma", "expected non-negative values")
        return sig, None
    key = f"process_noise.{given[0]}"
    M = _square_matrix(chk, pn, key, size)
    if M is None:
        return np.zeros(size), None
    scale = max(float(np.max(np.abs(M))), 1e-300)
    if given[0] == "cholesky":
        upper = np.triu(M, 1)
        if np.any(upper != 0):
            i, j = np.argwhere(upper != 0)[0]
            chk.add(key, f"expected a lower-triangular factor L (W = L·Lᵀ); entry [{i}][{j}] above the diagonal is {float(M[i, j])!r}")
            return np.zeros(size), None
        W = M @ M.T
    else:
        W = M
        asym = np.abs(W - W.T)
        if np.max(asym) > COV_SYMMETRY_REL_TOL * scale:
            i, j = np.unravel_index(np.argmax(asym), W.shape)
            chk.add(key, f"expected a symmetric matrix; [{i}][{j}] = {float(W[i, j])!r} but [{j}][{i}] = {float(W[j, i])!r}")
            return np.zeros(size), None
        lam = np.linalg.eigvalsh(0.5 * (W + W.T))
        if lam.min() < -COV_PSD_REL_TOL * scale:
            chk.add(key, f"expected a positive semi-definite covariance; its smallest eigenvalue is {lam.min():.6g}")
            return np.zeros(size), None
        W = 0.5 * (W + W.T)
    return np.sqrt(np.maximum(np.diag(W), 0.0)), W


def gyro_rate_map(sections, gyro_section, gyro_axis, gyro_rotation, rigid_index, n_q) -> np.ndarray:
    """Small-angle rate-gyro map G, shape (n_g, n_q): rate_rad_s = G @ dq/dt.

    A single-axis gyro with unit axis a reads a · ω, where ω (rad/s) is the sum of its section's
    rotation rates about the section axes, its own mode-shape rotations ``rotation_rad`` (rotation
    vector per unit coordinate, body frame) times the coordinate rates, and the rigid-body rate
    about the vertical.
    """
    G = np.zeros((len(gyro_axis), n_q))
    for g, (s, a) in enumerate(zip(gyro_section, gyro_axis)):
        if s >= 0:
            for axis, j in sections[s].rotation:
                G[g, j] += a[axis]
        if gyro_rotation is not None and len(gyro_rotation):
            G[g] += np.asarray(a) @ np.asarray(gyro_rotation[g])
        if rigid_index is not None:
            G[g, rigid_index] += a[2]
    return G


def _check_gyros_observe(chk, sections, g_sec, g_axis, g_rot, rigid_index, U, coord_names, mode_names):
    """Refuse gyros that read nothing (all-zero row of G) or no mode (zero row of G·U)."""
    G = gyro_rate_map(sections, g_sec, g_axis, g_rot, rigid_index, len(coord_names))
    for g in range(G.shape[0]):
        key = f"gyros[{g}]"
        if not np.any(np.abs(G[g]) > 1e-12):
            if g_sec[g] >= 0 and not sections[g_sec[g]].rotation and not np.any(g_rot[g]):
                why = f"section {sections[g_sec[g]].name!r} has no rotation coordinates and no rotation_rad is given"
            else:
                why = "its axis is perpendicular to every rotation of its section / rotation_rad"
            chk.add(key, f"the gyro reads nothing ({why}); expected a section with rotation = {{axis = coordinate}} "
                         "or rotation_rad = {coordinate = [rx, ry, rz]} with a component along the gyro's axis")
        elif U.size and not np.any(np.abs(G[g] @ U) > 1e-12 * np.abs(G[g]).max() * np.abs(U).max()):
            chk.add(key, f"the gyro senses none of the modes ({', '.join(mode_names)}): the coordinates it reads "
                         "do not move in any mode shape")


def _channel_sigma(chk: _Checker, doc: dict, a_names, masters, t_names) -> list:
    """[[channel_sigma]] entries → [(antenna, transmitter, sigma_m)]."""
    out, seen = [], set()
    master = a_names[masters[0]] if len(masters) == 1 else None
    for i, e in enumerate(_table_list(chk, doc, "channel_sigma", False)):
        key = f"channel_sigma[{i}]"
        chk.keys(e, key, *_keys("channel_sigma[]"))
        a, t = e.get("antenna"), e.get("transmitter")
        if "antenna" in e and (a not in a_names or a == master):
            chk.add(f"{key}.antenna", f"expected a rover antenna ({', '.join(n for n in a_names if n != master)}), got {a!r}")
        if "transmitter" in e and t not in t_names:
            chk.add(f"{key}.transmitter", f"expected a transmitter ({', '.join(t_names)}), got {t!r}")
        sig = chk.number(e, key, "sigma_m", None, positive=True)
        if (a, t) in seen:
            chk.add(key, f"channel {a}/{t} is given twice")
        seen.add((a, t))
        if sig is not None and a in a_names and t in t_names and a != master:
            out.append((a, t, sig))
    return out


def _keys(table: str) -> tuple[set, set]:
    """(required, optional) keys of a table, from the one declaration in :mod:`cdgps_cli.config.schema`."""
    return required_keys(table), optional_keys(table)


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


def _strip_bom(text: str) -> str:
    """TOML text without a leading UTF-8 byte-order mark (editors on Windows write one; TOML
    parsers refuse it as an invalid statement at line 1)."""
    return text[1:] if text.startswith("\ufeff") else text


def _description_problems(node, key: str = "") -> list[str]:
    """``KEY: expected a string`` for every ``description`` in the document that is not a string
    (a description is free text, never read as a number, list or table)."""
    out = []
    if isinstance(node, dict):
        for k, v in node.items():
            full = f"{key}.{k}" if key else k
            if k == "description" and not isinstance(v, str):
                out.append(f"{full}: expected a string (free text in quotes), got {v!r}")
            else:
                out += _description_problems(v, full)
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _description_problems(v, f"{key}[{i}]")
    return out


def parse_config(text: str, path: str = "<config>") -> StructureConfig:
    """Validate a structure-model TOML document given as text (see :func:`load_config`)."""
    text = _strip_bom(text)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CdgpsError(f"{path}: not valid TOML: {exc}") from None
    chk = _Checker(path)
    ranges = config_range_problems(doc)                 # plausible bounds (limits.py), first so that
    chk.problems += ranges                              # later checks guarded by `not chk.problems` skip
    chk.problems += _description_problems(doc)
    chk.keys(doc, "", *_keys(""))

    # [model]
    model = doc.get("model", {}) if isinstance(doc.get("model", {}), dict) else {}
    chk.keys(model, "model", *_keys("model"))
    name = chk.string(model, "model", "name", "unnamed")
    description = model.get("description", "") if isinstance(model.get("description", ""), str) else ""
    dt = chk.number(model, "model", "sample_period_s", 0.1, positive=True)
    wavelength = chk.number(model, "model", "wavelength_m", GPS_L1_WAVELENGTH_M, positive=True)
    sigma = chk.number(model, "model", "measurement_sigma_m", 0.01, positive=True)
    mp_sigma = chk.number(model, "model", "multipath_sigma_m", 0.0, nonneg=True)
    mp_tau = chk.number(model, "model", "multipath_time_constant_s", 30.0, positive=True)
    lbc = model.get("line_bias_calibrated", True)
    if not isinstance(lbc, bool):
        chk.add("model.line_bias_calibrated", f"expected true or false, got {lbc!r}")
        lbc = True

    # [[coordinates]]
    coords = _table_list(chk, doc, "coordinates", True)
    coord_names, coord_kinds, coord_units = [], [], []
    for i, c in enumerate(coords):
        key = f"coordinates[{i}]"
        chk.keys(c, key, *_keys("coordinates[]"))
        coord_names.append(chk.string(c, key, "name", f"?{i}"))
        coord_units.append(chk.string(c, key, "unit", ""))
        kind = c.get("kind", "modal")
        if not isinstance(kind, str) or kind not in COORD_KINDS:
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
    chk.keys(body, "body", *_keys("body"))
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
        chk.keys(s, key, *_keys("sections[]"))
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
        if not isinstance(v, str) or v not in sindex:
            chk.add(f"{key}.section", f"expected the name of a section ({', '.join(sindex) or 'none defined'}), got {v!r}")
            return -1
        return sindex[v]

    # [[antennas]]
    ants = _table_list(chk, doc, "antennas", True)
    a_names, a_sec, a_pos, a_disp, a_rx, a_lb, masters, a_sig = [], [], [], [], [], [], [], []

    def per_coordinate_vectors(tbl, key, name, what):
        """A {coordinate = [x, y, z]} table → (3, n_q) array (zeros where not given)."""
        out = np.zeros((3, n_q))
        dtbl = tbl.get(name, {})
        if not isinstance(dtbl, dict):
            chk.add(f"{key}.{name}", f"expected a table {what}")
            return out
        for ref in dtbl:
            j = coord_ref(ref, f"{key}.{name}.{ref}")
            v = chk.vector(dtbl, f"{key}.{name}", ref, 3)
            if j is not None and v is not None:
                out[:, j] = v
        return out
    for i, a in enumerate(ants):
        key = f"antennas[{i}]"
        chk.keys(a, key, *_keys("antennas[]"))
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
        a_sig.append(chk.number(a, key, "sigma_m", np.nan, positive=True))
        if m is True and "sigma_m" in a:
            chk.add(f"{key}.sigma_m", "the master is in every channel; give sigma_m on the rover antennas, "
                                      "transmitters or [[channel_sigma]] entries instead")
        a_disp.append(per_coordinate_vectors(a, key, "displacement_m", "{coordinate = [dx, dy, dz]} (m per unit coordinate)"))
    _unique(chk, a_names, "antennas")
    if len(masters) != 1:
        chk.add("antennas", f"exactly one antenna must have master = true, found {len(masters)}")
    if len(ants) < 2:
        chk.add("antennas", "at least a master and one other antenna are required")

    # [[transmitters]]
    txs = _table_list(chk, doc, "transmitters", True)
    t_names, t_pos, far, t_sig = [], [], [], []
    for i, t in enumerate(txs):
        key = f"transmitters[{i}]"
        chk.keys(t, key, *_keys("transmitters[]"))
        t_names.append(chk.string(t, key, "name", f"?{i}"))
        t_sig.append(chk.number(t, key, "sigma_m", np.nan, positive=True))
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
    m_names, m_f, m_tau, m_zeta, shapes = [], [], [], [], []
    for i, m in enumerate(modes):
        key = f"modes[{i}]"
        chk.keys(m, key, *_keys("modes[]"))
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
        tau, zeta = _mode_damping(chk, m, key, rigid, m_f[-1])
        m_tau.append(tau)
        m_zeta.append(zeta)
        shapes.append(chk.vector(m, key, "shape", n_q, np.zeros(n_q)))
    _unique(chk, m_names, "modes")
    U = np.array(shapes).T if shapes else np.zeros((n_q, 0))
    if shapes and not chk.problems:
        s = np.linalg.svd(U, compute_uv=False)
        if s.size and s.min() <= 1e-12 * max(s.max(), 1e-300):
            chk.add("modes", "mode shapes are linearly dependent (U has deficient column rank)")

    # [process_noise]
    pn = doc.get("process_noise", {})
    chk.keys(pn, "process_noise", *_keys("process_noise"))
    pn = pn if isinstance(pn, dict) else {}
    space = pn.get("space", "modal")
    if space not in ("modal", "coordinates"):
        chk.add("process_noise.space", f"expected \"modal\" or \"coordinates\", got {space!r}")
        space = "modal"
    size = len(m_names) if space == "modal" else n_q
    pn_sigma, pn_cov = _process_noise(chk, pn, size, space)

    # [[gyros]]
    g_names, g_sec, g_axis, g_rot = [], [], [], []
    for i, g in enumerate(_table_list(chk, doc, "gyros", False)):
        key = f"gyros[{i}]"
        chk.keys(g, key, *_keys("gyros[]"))
        g_names.append(chk.string(g, key, "name", f"?{i}"))
        g_sec.append(section_ref(g, key))
        g_rot.append(per_coordinate_vectors(g, key, "rotation_rad", "{coordinate = [rx, ry, rz]} (rad per unit coordinate)"))
        if "section" not in g and "rotation_rad" not in g:
            chk.add(key, "a gyro needs a section (with rotation coordinates) or rotation_rad = {coordinate = [rx, ry, rz]} (its mount's rotation per unit of each coordinate, e.g. FE mode-shape rotations)")
        ax = g.get("axis")
        if ax in AXES:
            g_axis.append(np.eye(3)[AXES.index(ax)])
        else:
            v = chk.vector(g, key, "axis", 3, None, unit=True) if isinstance(ax, list) else None
            if v is None and not isinstance(ax, list):
                chk.add(f"{key}.axis", f"expected x, y, z or a 3-vector, got {ax!r}")
            g_axis.append(v if v is not None else np.array([0.0, 0.0, 1.0]))
    _unique(chk, g_names, "gyros")
    if g_names and not chk.problems:
        _check_gyros_observe(chk, sections, g_sec, g_axis, g_rot, rigid_index, U, coord_names, m_names)

    channel_over = _channel_sigma(chk, doc, a_names, masters, t_names)
    p_names, p_sec, p_pos, p_disp = [], [], [], []
    for i, pt in enumerate(_table_list(chk, doc, "points", False)):
        key = f"points[{i}]"
        chk.keys(pt, key, *_keys("points[]"))
        p_names.append(chk.string(pt, key, "name", f"?{i}"))
        p_sec.append(section_ref(pt, key))
        p_pos.append(chk.vector(pt, key, "position_m", 3, np.zeros(3)))
        p_disp.append(per_coordinate_vectors(pt, key, "displacement_m", "{coordinate = [dx, dy, dz]} (m per unit coordinate)"))
    _unique(chk, p_names, "points")
    for i, n in enumerate(p_names):
        if n in a_names:
            chk.add(f"points[{i}].name", f"{n!r} is already an antenna name (antennas are points too)")

    # [[thrusters]]
    u_names, u_sec, u_pos, u_dir, u_max = [], [], [], [], []
    for i, u in enumerate(_table_list(chk, doc, "thrusters", False)):
        key = f"thrusters[{i}]"
        chk.keys(u, key, *_keys("thrusters[]"))
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
                    bad = [e for e in v if not (isinstance(e, str) and e in u_names)] if isinstance(v, list) else v
                    chk.add(f"simulation.{k}", f"unknown thruster name(s) {bad!r}: expected a list of thruster names "
                                               f"({', '.join(u_names) or 'none defined'})")
                    continue
            else:
                v = chk.number(st, "simulation", k, d, nonneg=(k not in _SIGNED_SIM_KEYS))
            sim[k] = v

    if chk.problems:
        own = {q.split(":")[0] for q in chk.problems[len(ranges):]}    # a key the checker refused itself
        kept = [q for q in ranges if q.split(":")[0] not in own] + chk.problems[len(ranges):]
        raise CdgpsError(join_problems(f"{path}: invalid config", kept))

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
        multipath_sigma_m=mp_sigma,
        multipath_time_constant_s=mp_tau,
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
        process_noise_covariance=None if pn_cov is None else ro(pn_cov),
        coord_unit_labels=tuple(coord_units),
        mode_damping_ratio=ro(m_zeta),
        gyro_rotation=ro(np.reshape(g_rot, (-1, 3, n_q))),
        antenna_sigma_m=ro(a_sig),
        transmitter_sigma_m=ro(t_sig),
        channel_sigma_overrides=tuple(channel_over),
        point_names=tuple(p_names),
        point_section=ro(p_sec, int),
        point_position_m=ro(np.reshape(p_pos, (-1, 3))),
        point_displacement=ro(np.reshape(p_disp, (-1, 3, n_q))),
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

# the keys of each table, from the one declaration (config/schema.py, also published as a JSON Schema)
_GNSS_KEYS = set().union(*gnss_keys("gnss"))
_GNSS_ANTENNA_KEYS = set().union(*gnss_keys("gnss.antennas.*"))
_GNSS_DISPLACEMENT_KEYS = set().union(*gnss_keys("gnss.displacement"))


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

    The processing settings mirror :class:`~cdgps_cli.estimation.baseline.BaselineOptions` (see
    :meth:`cdgps_cli.estimation.baseline.BaselineOptions.from_gnss_config`); the displacement model says how the rover states evolve:
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
    max_age_s: float = GNSS_DEFAULTS["max_age_s"]
    code_correlation_s: float = GNSS_DEFAULTS["code_correlation_s"]
    min_success_rate: float = GNSS_DEFAULTS["min_success_rate"]
    epoch_alignment: str = GNSS_DEFAULTS["epoch_alignment"]
    displacement: str = "static"
    random_walk_sigma: tuple = GNSS_DEFAULTS["random_walk_sigma"]
    initial_sigma_m: float = GNSS_DEFAULTS["initial_sigma_m"]
    iono_threshold_km: float = GNSS_DEFAULTS["iono_threshold_km"]
    """With ``signals``: ``cdgps init`` refuses a baseline at least this long, km (the displacement path
    neglects the DD ionosphere; ``cdgps rtk`` estimates it)."""
    signals: tuple = ()
    """Multi-GNSS signals kept at ingest (``G:L1``, ``G:L2``, ``E:E1``, ``E:E5a`` …; names of
    :mod:`cdgps_cli.core.signals`); empty: GPS L1 only (the raw tables)."""

    def antenna(self, name: str) -> GnssAntenna | None:
        return next((a for a in self.antennas if a.name == name), None)

    @property
    def antenna_names(self) -> tuple:
        return tuple(a.name for a in self.antennas)

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
        doc = tomllib.loads(_strip_bom(text))
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
    text = _strip_bom(text)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CdgpsError(f"{path}: not valid TOML: {exc}") from None
    chk = _Checker(path)
    chk.problems += [q for q in _description_problems(doc) if not q.startswith("gnss.description:")]  # checked below
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
    signals = _gnss_signals(g, chk)
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
    max_age = chk.number(g, "gnss", "max_age_s", GNSS_DEFAULTS["max_age_s"], positive=True)
    code_corr = chk.number(g, "gnss", "code_correlation_s", GNSS_DEFAULTS["code_correlation_s"])
    if code_corr is not None and code_corr < 0:
        chk.add("gnss.code_correlation_s", f"expected a correlation time >= 0 s, got {code_corr!r}")
    if max_age is not None and sync is not None and max_age < sync:
        chk.add("gnss.max_age_s", f"expected at least gnss.sync_tol_s ({sync:g} s), got {max_age!r}")
    iono_km = chk.number(g, "gnss", "iono_threshold_km", GNSS_DEFAULTS["iono_threshold_km"], positive=True)
    min_sr = chk.number(g, "gnss", "min_success_rate", GNSS_DEFAULTS["min_success_rate"])
    if min_sr is not None and not 0.0 <= min_sr < 1.0:
        chk.add("gnss.min_success_rate", f"expected a probability in [0, 1), got {min_sr!r}")
    align = chk.string(g, "gnss", "epoch_alignment", GNSS_DEFAULTS["epoch_alignment"])
    if align not in ("geometry", "doppler"):
        chk.add("gnss.epoch_alignment", f"expected \"geometry\" or \"doppler\", got {align!r}")

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
        max_gap_s=max_gap, sync_tol_s=sync, max_age_s=max_age, code_correlation_s=code_corr, epoch_alignment=align,
        displacement=model, random_walk_sigma=rw, initial_sigma_m=init_sigma,
        min_success_rate=GNSS_DEFAULTS["min_success_rate"] if min_sr is None else min_sr,
        signals=signals, iono_threshold_km=iono_km,
    )


def _gnss_signals(g: dict, chk) -> tuple:
    """``[gnss] signals``: a non-empty list of known, distinct signal names (problems added to ``chk``)."""
    from cdgps_cli.core.signals import SIGNALS  # noqa: PLC0415

    if "signals" not in g:
        return ()
    v = g["signals"]
    if not isinstance(v, list) or not v or not all(isinstance(e, str) for e in v):
        chk.add("gnss.signals", f"expected a non-empty list of signal names (e.g. [\"G:L1\", \"E:E1\"]), got {v!r}")
        return ()
    bad = [e for e in v if e not in SIGNALS]
    if bad:
        chk.add("gnss.signals", f"unknown signal(s) {', '.join(map(repr, bad))}; known: {', '.join(SIGNALS)}")
    if len(set(v)) != len(v):
        chk.add("gnss.signals", f"a signal is listed twice: {v!r}")
    return tuple(v)


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
    opts = {k: GNSS_DEFAULTS[k] for k in ("mask_deg", "ratio", "partial", "weighting", "troposphere", "max_age_s",
                                          "min_success_rate")}
    opts.update(options or {})
    notes = {"mask_deg": "elevation mask at every receiver, degrees", "ratio": "LAMBDA ratio-test threshold",
             "partial": "partial fixing when the full set fails the ratio test",
             "weighting": 'phase variance a^2 + b^2/sin^2(el) ("elevation") or a^2 + b^2 ("equal")',
             "troposphere": "a priori hydrostatic troposphere (Saastamoinen x Niell), as RTKLIB",
             "signals": "multi-GNSS signals kept at ingest (system:slot)",
             "max_age_s": "oldest base (master) epoch bridged to a rover epoch, s (RTKLIB's maxage)",
             "min_success_rate": "bootstrapped success rate an integer set must reach besides the ratio test"}
    for k, v in opts.items():
        val = ("true" if v else "false") if isinstance(v, bool) else (_toml_str(v) if isinstance(v, str) else
                                                                   "[" + ", ".join(map(_toml_str, v)) + "]" if isinstance(v, (list, tuple))
                                                                   else repr(float(v)))
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
