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
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from cdgps_cli.core import toml_text
from cdgps_cli.core.errors import CdgpsError, join_problems
from cdgps_cli.config.limits import config_range_problems
from cdgps_cli.config.schema import (GNSS_TABLES, STRUCTURE_TABLES, Field, optional_keys, required_keys,
                                     simulation_table)
from cdgps_cli.config.validate import AXES, INVALID, Context, Problems, array_tables, check_ref, check_table
from cdgps_cli.config.options import GNSS_DEFAULTS, GNSS_WEIGHTINGS  # noqa: F401 (GNSS_WEIGHTINGS re-exported)

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
# validation: the keys are declared in config/schema.py and judged by config/validate.py; the
# rules across keys are the short named checks below

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
#: [simulation] keys that name a coordinate or thrusters
_SIM_REFS = {"static_angle_coordinate": "coordinates", "pulse_thrusters": "thrusters"}
_SIM_TABLE = simulation_table(_SIM_DEFAULTS, _SIGNED_SIM_KEYS, _SIM_REFS)


def _entries(p: Problems, doc: dict, name: str, ctx: Context, required: bool = False) -> list[tuple[str, dict, dict]]:
    """``(key, table as given, checked values)`` of each entry of the array of tables ``[[name]]``."""
    fields = STRUCTURE_TABLES[name + "[]"]
    return [(f"{name}[{i}]", t, check_table(p, t, f"{name}[{i}]", fields, ctx, i))
            for i, t in enumerate(array_tables(p, doc, name, required))]


def _table(p: Problems, doc: dict, name: str, ctx: Context, fields: dict | None = None) -> tuple[dict, dict]:
    """``(table as given, checked values)`` of the table ``[name]`` (absent: empty)."""
    t = doc.get(name, {})
    vals = check_table(p, t, name, fields or STRUCTURE_TABLES[name], ctx)
    return (t if isinstance(t, dict) else {}), vals


def _unique(p: Problems, names: list, key: str) -> None:
    seen = set()
    for i, n in enumerate(names):
        if n in seen:
            p.add(f"{key}[{i}].name", f"duplicate name {n!r}")
        seen.add(n)


def _named(p: Problems, entries: list, key: str, ctx: Context) -> list:
    """The entries' names (each unique), known to later references as table ``key``."""
    names = [v["name"] for _, _, v in entries]
    _unique(p, names, key)
    ctx.names[key] = names
    return names


_AXIS_REFS = {part: Field("ref", {}, ref="coordinates", ref_kind=part) for part in ("translation", "rotation")}


def _section_axes(p: Problems, s: dict, key: str, part: str, ctx: Context, used: dict) -> tuple:
    """A section's ``translation`` or ``rotation`` table → sorted ((axis index, coordinate index), …);
    each coordinate drives at most one axis of one section."""
    tbl = s.get(part, {})
    if not isinstance(tbl, dict):
        p.add(f"{key}.{part}", "expected a table such as {x = \"q1\"}")
        return ()
    items = []
    for ax, ref in tbl.items():
        where = f"{key}.{part}.{ax}"
        if ax not in AXES:
            p.add(where, "expected an axis x, y or z")
            continue
        j = check_ref(p, where, ref, _AXIS_REFS[part], ctx)
        if j is not INVALID:
            if j in used:
                p.add(where, f"coordinate {ref!r} already drives {used[j]}")
            used[j] = where
            items.append((AXES.index(ax), j))
    return tuple(sorted(items))


def _sections(p: Problems, doc: dict, ctx: Context) -> list:
    used: dict[int, str] = {}
    out = [Section(v["name"], np.asarray(v["pivot_m"], dtype=float), _section_axes(p, s, key, "translation", ctx, used),
                   _section_axes(p, s, key, "rotation", ctx, used))
           for key, s, v in _entries(p, doc, "sections", ctx)]
    _unique(p, [s.name for s in out], "sections")
    ctx.names["sections"] = [s.name for s in out]
    return out


def _master(p: Problems, ants: list) -> list:
    """Indices of the master antennas (exactly one allowed), with the rules on them."""
    masters = [i for i, (_, _, v) in enumerate(ants) if v["master"]]
    for key, a, _ in ants:
        if a.get("master") is True and "sigma_m" in a:
            p.add(f"{key}.sigma_m", "the master is in every channel; give sigma_m on the rover antennas, "
                                    "transmitters or [[channel_sigma]] entries instead")
    if len(masters) != 1:
        p.add("antennas", f"exactly one antenna must have master = true, found {len(masters)}")
    if len(ants) < 2:
        p.add("antennas", "at least a master and one other antenna are required")
    return masters


def _transmitter_position(p: Problems, key: str, t: dict, v: dict) -> tuple[np.ndarray, bool]:
    """(position or direction, far field) of a transmitter: exactly one of position_m or direction."""
    if ("position_m" in t) == ("direction" in t):
        p.add(key, "give exactly one of position_m (near field, metres in the lab frame) or direction (far field, "
                   "unit vector toward the source)")
        return np.zeros(3), False
    if "position_m" in t:
        return (np.zeros(3) if v["position_m"] is None else v["position_m"]), False
    return (np.array([0.0, 0.0, 1.0]) if v["direction"] is None else v["direction"]), True


def _mode_frequency(p: Problems, key: str, m: dict, v: dict) -> float:
    """A mode's frequency, Hz: 0 for a rigid mode, positive otherwise."""
    f = v["frequency_hz"]
    if v["rigid"]:
        if f is not None and f < 0:
            p.add(f"{key}.frequency_hz", f"expected a non-negative number, got {m['frequency_hz']!r}")
        elif f is not None and f != 0.0:
            p.add(f"{key}.frequency_hz", "a rigid-body mode (rigid = true) must have frequency_hz = 0")
        return 0.0 if f is None or f < 0 else f
    if f is not None and f <= 0:
        p.add(f"{key}.frequency_hz", f"expected a positive number, got {m['frequency_hz']!r}"
                                     + (" (set rigid = true for a rigid-body mode)" if f == 0 else ""))
    return 1.0 if f is None or f <= 0 else f


def _mode_damping(p: Problems, key: str, m: dict, v: dict, f_hz: float) -> tuple[float, float]:
    """Envelope time constant τ (s) and damping ratio ζ of a [[modes]] entry (exactly one given).

    τ = 1/(ζ ω) with ω = 2π f (Table 1 of the 1998 paper); a rigid mode (f = 0) needs τ, the
    decay time constant of its rate, and has ζ = NaN.
    """
    has_tau, has_zeta = "time_constant_s" in m, "damping_ratio" in m
    if has_tau == has_zeta:
        p.add(key, "give exactly one of time_constant_s (envelope time constant τ, s) or damping_ratio "
                   "(ζ, with τ = 1/(ζ·2π·frequency_hz))" + (", not both" if has_tau else ""))
        return 1e9, float("nan")
    omega = 2 * np.pi * f_hz
    if has_tau:
        tau = 1e9 if v["time_constant_s"] is None else v["time_constant_s"]
        return tau, (float("nan") if v["rigid"] else 1.0 / (omega * tau))
    if v["rigid"]:
        p.add(f"{key}.damping_ratio", "a rigid-body mode has no damping ratio (frequency 0); give time_constant_s, "
                                      "the decay time constant of its rate")
        return 1e9, float("nan")
    zeta = v["damping_ratio"]
    if zeta is None:
        return 1e9, float("nan")
    if zeta >= 1.0:
        p.add(f"{key}.damping_ratio", f"expected 0 < ζ < 1 (an underdamped mode), got {zeta!r}")
        return 1e9, float("nan")
    return 1.0 / (zeta * omega), zeta


def _independent_shapes(p: Problems, U: np.ndarray) -> None:
    s = np.linalg.svd(U, compute_uv=False)
    if s.size and s.min() <= 1e-12 * max(s.max(), 1e-300):
        p.add("modes", "mode shapes are linearly dependent (U has deficient column rank)")


def _process_noise(p: Problems, pn: dict, v: dict, size: int, space: str):
    """(sigma (size,), covariance (size, size) or None) from [process_noise]: sigma | covariance | cholesky."""
    given = [k for k in ("sigma", "covariance", "cholesky") if k in pn]
    what = "modes" if space == "modal" else "coordinates"
    if len(given) != 1:
        p.add("process_noise", "give exactly one of sigma (diagonal W, one σ per %s), covariance (full W, "
              "%d×%d) or cholesky (lower-triangular L with W = L·Lᵀ)%s" % (what, size, size,
                                                                         f"; got {', '.join(given)}" if given else ""))
        return np.zeros(size), None
    M = v[given[0]]
    if M is None:
        return np.zeros(size), None
    if given[0] == "sigma":
        return M, None
    key = f"process_noise.{given[0]}"
    scale = max(float(np.max(np.abs(M))), 1e-300)
    if given[0] == "cholesky":
        upper = np.triu(M, 1)
        if np.any(upper != 0):
            i, j = np.argwhere(upper != 0)[0]
            p.add(key, f"expected a lower-triangular factor L (W = L·Lᵀ); entry [{i}][{j}] above the diagonal is "
                       f"{float(M[i, j])!r}")
            return np.zeros(size), None
        W = M @ M.T
    else:
        W = M
        asym = np.abs(W - W.T)
        if np.max(asym) > COV_SYMMETRY_REL_TOL * scale:
            i, j = np.unravel_index(np.argmax(asym), W.shape)
            p.add(key, f"expected a symmetric matrix; [{i}][{j}] = {float(W[i, j])!r} but [{j}][{i}] = "
                       f"{float(W[j, i])!r}")
            return np.zeros(size), None
        lam = np.linalg.eigvalsh(0.5 * (W + W.T))
        if lam.min() < -COV_PSD_REL_TOL * scale:
            p.add(key, f"expected a positive semi-definite covariance; its smallest eigenvalue is {lam.min():.6g}")
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


def _gyro_mounts(p: Problems, gyros: list) -> None:
    for key, g, _ in gyros:
        if "section" not in g and "rotation_rad" not in g:
            p.add(key, "a gyro needs a section (with rotation coordinates) or rotation_rad = {coordinate = [rx, ry, rz]} "
                       "(its mount's rotation per unit of each coordinate, e.g. FE mode-shape rotations)")


def _check_gyros_observe(p, sections, g_sec, g_axis, g_rot, rigid_index, U, coord_names, mode_names):
    """Refuse gyros that read nothing (all-zero row of G) or no mode (zero row of G·U)."""
    G = gyro_rate_map(sections, g_sec, g_axis, g_rot, rigid_index, len(coord_names))
    for g in range(G.shape[0]):
        key = f"gyros[{g}]"
        if not np.any(np.abs(G[g]) > 1e-12):
            if g_sec[g] >= 0 and not sections[g_sec[g]].rotation and not np.any(g_rot[g]):
                why = f"section {sections[g_sec[g]].name!r} has no rotation coordinates and no rotation_rad is given"
            else:
                why = "its axis is perpendicular to every rotation of its section / rotation_rad"
            p.add(key, f"the gyro reads nothing ({why}); expected a section with rotation = {{axis = coordinate}} "
                       "or rotation_rad = {coordinate = [rx, ry, rz]} with a component along the gyro's axis")
        elif U.size and not np.any(np.abs(G[g] @ U) > 1e-12 * np.abs(G[g]).max() * np.abs(U).max()):
            p.add(key, f"the gyro senses none of the modes ({', '.join(mode_names)}): the coordinates it reads "
                       "do not move in any mode shape")


def _channel_sigma(p: Problems, doc: dict, ctx: Context) -> list:
    """[[channel_sigma]] entries → [(antenna, transmitter, sigma_m)]; a channel at most once."""
    out, seen = [], set()
    a_names, t_names = ctx.names["rover_antennas"], ctx.names["transmitters"]
    for key, e, v in _entries(p, doc, "channel_sigma", ctx):
        a, t = e.get("antenna"), e.get("transmitter")
        if (a, t) in seen:
            p.add(key, f"channel {a}/{t} is given twice")
        seen.add((a, t))
        if v["sigma_m"] is not None and a in a_names and t in t_names and a != ctx.master:
            out.append((a, t, v["sigma_m"]))
    return out


def _point_names(p: Problems, p_names: list, a_names: list) -> None:
    for i, n in enumerate(p_names):
        if n in a_names:
            p.add(f"points[{i}].name", f"{n!r} is already an antenna name (antennas are points too)")


def _keys(table: str) -> tuple[set, set]:
    """(required, optional) keys of a table, from the one declaration in :mod:`cdgps_cli.config.schema`."""
    return required_keys(table), optional_keys(table)


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


def _toml(text: str, path: str) -> dict:
    try:
        return toml_text.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CdgpsError(f"{path}: not valid TOML: {exc}") from None


def _raise_problems(p: Problems, ranges: list, header: str) -> None:
    """All problems at once; a range problem only for keys the checks did not refuse themselves."""
    if p.problems:
        own = {q.split(":")[0] for q in p.problems[len(ranges):]}
        kept = [q for q in ranges if q.split(":")[0] not in own] + p.problems[len(ranges):]
        raise CdgpsError(join_problems(f"{p.path}: {header}", kept))


def parse_config(text: str, path: str = "<config>") -> StructureConfig:
    """Validate a structure-model TOML document given as text (see :func:`load_config`).

    Each table is judged by its declaration (:data:`cdgps_cli.config.schema.STRUCTURE_TABLES`), in
    an order where every table's references are known (coordinates before the sections that name
    them …); then the rules across keys.  Every problem is listed at once, naming file and key.
    """
    text = _strip_bom(text)
    doc = _toml(text, path)
    p = Problems(path)
    ranges = config_range_problems(doc)                 # plausible bounds (limits.py), first so that
    p.problems += ranges                                # later checks guarded by `not p.problems` skip
    p.keys(doc, "", *_keys(""))
    ctx = Context()
    r = SimpleNamespace()                               # the checked tables, in the order they are read
    _, r.model = _table(p, doc, "model", ctx)
    _read_frame(p, doc, ctx, r)
    _read_antennas_transmitters(p, doc, ctx, r)
    _read_modes(p, doc, ctx, r)
    _read_gyros(p, doc, ctx, r)
    _read_channels_points_thrusters(p, doc, ctx, r)
    _raise_problems(p, ranges, "invalid config")
    return StructureConfig(path=path, text=text, sha256=hashlib.sha256(text.encode("utf-8")).hexdigest(),
                           **_model_fields(r.model), **_frame_fields(r), **_antenna_transmitter_fields(r),
                           **_mode_fields(r), **_sensor_fields(r))


def _read_frame(p: Problems, doc: dict, ctx: Context, r: SimpleNamespace) -> None:
    """[[coordinates]], [body] and [[sections]] into ``r`` (coords, coord_names, body, rigid_index, sections)."""
    r.coords = _entries(p, doc, "coordinates", ctx, required=True)
    r.coord_names = _named(p, r.coords, "coordinates", ctx)
    ctx.coord_kinds = r.coord_kinds = [v["kind"] for _, _, v in r.coords]
    ctx.sizes["coordinates"] = r.n_q = len(r.coord_names)
    _, r.body = _table(p, doc, "body", ctx)
    r.rigid_index = r.body["rigid_rotation"]
    r.sections = _sections(p, doc, ctx)


def _read_antennas_transmitters(p: Problems, doc: dict, ctx: Context, r: SimpleNamespace) -> None:
    """[[antennas]] (one master) and [[transmitters]] (all near- or all far-field) into ``r``."""
    r.ants = _entries(p, doc, "antennas", ctx, required=True)
    r.a_names = _named(p, r.ants, "antennas", ctx)
    r.masters = _master(p, r.ants)
    r.txs = _entries(p, doc, "transmitters", ctx, required=True)
    r.t_names = _named(p, r.txs, "transmitters", ctx)
    r.t_pos, r.far = zip(*[_transmitter_position(p, key, t, v) for key, t, v in r.txs]) if r.txs else ((), ())
    if r.far and len(set(r.far)) > 1:
        p.add("transmitters", "mixing near-field (position_m) and far-field (direction) transmitters is not supported")


def _read_modes(p: Problems, doc: dict, ctx: Context, r: SimpleNamespace) -> None:
    """[[modes]] (frequency, damping, independent shapes) and [process_noise] (modal or coordinate space) into ``r``."""
    modes = _entries(p, doc, "modes", ctx, required=True)
    r.m_f = [_mode_frequency(p, key, m, v) for key, m, v in modes]
    r.m_tau, r.m_zeta = zip(*[_mode_damping(p, key, m, v, f) for (key, m, v), f in zip(modes, r.m_f)]) if modes else ((), ())
    r.m_names = _named(p, modes, "modes", ctx)
    r.U = np.array([v["shape"] for _, _, v in modes]).T if modes else np.zeros((r.n_q, 0))
    if modes and not p.problems:
        _independent_shapes(p, r.U)
    pn_given = doc.get("process_noise", {})
    space = pn_given.get("space", "modal") if isinstance(pn_given, dict) else "modal"
    r.pn_space = space if space in ("modal", "coordinates") else "modal"
    ctx.sizes["process_noise"] = len(r.m_names) if r.pn_space == "modal" else r.n_q
    pn, pn_vals = _table(p, doc, "process_noise", ctx)
    r.pn_sigma, r.pn_cov = _process_noise(p, pn, pn_vals, ctx.sizes["process_noise"], r.pn_space)


def _read_gyros(p: Problems, doc: dict, ctx: Context, r: SimpleNamespace) -> None:
    """[[gyros]] (mounts, and that they observe the rigid rotation) into ``r``."""
    gyros = _entries(p, doc, "gyros", ctx)
    _gyro_mounts(p, gyros)
    r.g_names = _named(p, gyros, "gyros", ctx)
    r.g_sec = [v["section"] for _, _, v in gyros]
    r.g_axis = [np.asarray(v["axis"], dtype=float) for _, _, v in gyros]
    r.g_rot = [v["rotation_rad"] for _, _, v in gyros]
    if r.g_names and not p.problems:
        _check_gyros_observe(p, r.sections, r.g_sec, r.g_axis, r.g_rot, r.rigid_index, r.U, r.coord_names, r.m_names)


def _read_channels_points_thrusters(p: Problems, doc: dict, ctx: Context, r: SimpleNamespace) -> None:
    """[[channel_sigma]], [[points]], [[thrusters]] and [simulation] into ``r`` (they name antennas and sections)."""
    ctx.master = r.a_names[r.masters[0]] if len(r.masters) == 1 else None
    ctx.names["rover_antennas"] = r.a_names
    r.channel_over = _channel_sigma(p, doc, ctx)
    r.points = _entries(p, doc, "points", ctx)
    _point_names(p, _named(p, r.points, "points", ctx), r.a_names)
    r.thrusters = _entries(p, doc, "thrusters", ctx)
    r.u_names = _named(p, r.thrusters, "thrusters", ctx)
    _, r.sim = _table(p, doc, "simulation", ctx, _SIM_TABLE)


def _ro(a, dtype=float) -> np.ndarray:
    """A read-only array of ``a``."""
    arr = np.array(a, dtype=dtype)
    arr.setflags(write=False)
    return arr


def _col(entries, name: str, dtype=float) -> np.ndarray:
    """Key ``name`` of every entry of an array of tables, as a read-only array."""
    return _ro([v[name] for _, _, v in entries], dtype)


def _vectors(entries, name: str) -> np.ndarray:
    """Key ``name`` (3 numbers) of every entry, read-only (n, 3)."""
    return _ro(np.reshape([v[name] for _, _, v in entries], (-1, 3)))


def _model_fields(model: dict) -> dict:
    return {k: model[k] for k in ("name", "description", "sample_period_s", "wavelength_m", "measurement_sigma_m",
                                  "multipath_sigma_m", "multipath_time_constant_s", "line_bias_calibrated")}


def _frame_fields(r: SimpleNamespace) -> dict:
    return {"coord_names": tuple(r.coord_names), "coord_kinds": tuple(r.coord_kinds),
            "coord_unit_labels": tuple(v["unit"] for _, _, v in r.coords), "body_origin_m": _ro(r.body["origin_m"]),
            "rigid_index": r.rigid_index, "sections": tuple(r.sections)}


def _antenna_transmitter_fields(r: SimpleNamespace) -> dict:
    ants = r.ants
    return {"antenna_names": tuple(r.a_names), "antenna_section": _col(ants, "section", int),
            "antenna_position_m": _vectors(ants, "position_m"),
            "antenna_displacement": _ro(np.reshape([v["displacement_m"] for _, _, v in ants], (-1, 3, r.n_q))),
            "antenna_receiver": tuple(v["receiver"] for _, _, v in ants),
            "antenna_line_bias_m": _col(ants, "line_bias_m"), "master_index": r.masters[0],
            "antenna_sigma_m": _col(ants, "sigma_m"),
            "transmitter_names": tuple(r.t_names), "transmitter_far_field": bool(r.far and r.far[0]),
            "transmitter_position_m": _ro(np.reshape(r.t_pos, (-1, 3))), "transmitter_sigma_m": _col(r.txs, "sigma_m"),
            "channel_sigma_overrides": tuple(r.channel_over)}


def _mode_fields(r: SimpleNamespace) -> dict:
    return {"mode_names": tuple(r.m_names), "mode_frequency_hz": _ro(r.m_f), "mode_time_constant_s": _ro(r.m_tau),
            "mode_damping_ratio": _ro(r.m_zeta), "mode_shapes": _ro(r.U), "process_noise_space": r.pn_space,
            "process_noise_sigma": _ro(r.pn_sigma),
            "process_noise_covariance": None if r.pn_cov is None else _ro(r.pn_cov)}


def _sensor_fields(r: SimpleNamespace) -> dict:
    """Gyros, points, thrusters and the [simulation] table."""
    return {"gyro_names": tuple(r.g_names), "gyro_section": _ro(r.g_sec, int), "gyro_axis": _ro(np.reshape(r.g_axis, (-1, 3))),
            "gyro_rotation": _ro(np.reshape(r.g_rot, (-1, 3, r.n_q))),
            "point_names": tuple(v["name"] for _, _, v in r.points), "point_section": _col(r.points, "section", int),
            "point_position_m": _vectors(r.points, "position_m"),
            "point_displacement": _ro(np.reshape([v["displacement_m"] for _, _, v in r.points], (-1, 3, r.n_q))),
            "thruster_names": tuple(r.u_names), "thruster_section": _col(r.thrusters, "section", int),
            "thruster_position_m": _vectors(r.thrusters, "position_m"),
            "thruster_direction": _vectors(r.thrusters, "direction"),
            "thruster_max_force_n": _col(r.thrusters, "max_force_n"), "simulation": r.sim}


# ============================================================================================
# GNSS run configs (real receivers: RINEX / UBX files, a master, rover displacement states)
# Format: docs/gnss-pipeline.md.  Additive: the structure-model schema above is unchanged.
# ============================================================================================

GNSS_DISPLACEMENT_MODELS = ("static", "random_walk", "constant_velocity")
# defaults of the GNSS solver settings: the [gnss] parser, GnssConfig and baseline.BaselineOptions all
# take them from here (RTKLIB-comparable: 15° mask, ratio 3, a = b = 3 mm, code/phase ratio 100, DTTOL)



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
    antenna_type: str | None = None
    """The antenna's type and radome as the ANTEX file (``[gnss] antex``) names them; None: its RINEX header's
    ``ANT # / TYPE``; ``"none"``: no model."""


@dataclass(frozen=True)
class GnssConfig:
    """A validated GNSS run config (``[gnss]`` table; docs/gnss-pipeline.md).

    The processing settings mirror :class:`~cdgps_cli.estimation.baseline.BaselineOptions` (see
    :meth:`cdgps_cli.estimation.baseline.BaselineOptions.from_gnss_config`); the displacement model says how the rover states evolve:
    ``static`` (one E/N/U displacement per rover for the whole run), ``random_walk`` (E/N/U
    displacements that wander with white-noise rates of ``random_walk_sigma`` m/√s) or ``constant_velocity``
    (E/N/U displacements and velocities, each velocity a random walk of ``accel_sigma_m_per_s_per_sqrt_s``: white
    acceleration; ``init`` resolves the integers with the random-walk float of ``random_walk_sigma``).
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
    glonass_fix: bool = GNSS_DEFAULTS["glonass_fix"]
    epoch_alignment: str = GNSS_DEFAULTS["epoch_alignment"]
    displacement: str = "static"
    random_walk_sigma: tuple = GNSS_DEFAULTS["random_walk_sigma"]
    initial_sigma_m: float = GNSS_DEFAULTS["initial_sigma_m"]
    accel_sigma_m_per_s_per_sqrt_s: float = GNSS_DEFAULTS["accel_sigma_m_per_s_per_sqrt_s"]
    phase_noise: str = GNSS_DEFAULTS["phase_noise"]
    """``estimate``'s per-epoch phase variances: ``"model"`` (sigma_a_m, sigma_b_m) or ``"auto"`` (scaled by the
    single-epoch solutions' residual unit variance, :func:`cdgps_cli.pipeline.gnss.phase_variance_factor`)."""
    multipath: str = GNSS_DEFAULTS["multipath"]
    """``estimate``'s per-epoch states: ``"off"`` (white phase errors), ``"auto"`` or ``"model"``: a Gauss–Markov
    multipath state per satellite and signal (:mod:`cdgps_cli.pipeline.gnss_multipath`)."""
    multipath_sigma_m: float | None = None
    """``multipath = "model"``: each satellite's single-difference phase multipath σ, m."""
    multipath_time_constant_s: float = GNSS_DEFAULTS["multipath_time_constant_s"]
    """``multipath = "model"``: its correlation time, s."""
    iono_threshold_km: float = GNSS_DEFAULTS["iono_threshold_km"]
    """With ``signals``: ``cdgps init`` refuses a baseline at least this long, km (the displacement path
    neglects the DD ionosphere; ``cdgps rtk`` estimates it)."""
    antex: str | None = None
    """ANTEX file whose calibrations of the receivers' antennas ``ingest`` keeps in the RUN (and ``baseline`` applies):
    each receiver's phase-centre model is taken out of its observations; None: no models."""
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
            "random_walk_sigma_m_per_sqrt_s": list(self.random_walk_sigma) if self.displacement != "static" else None,
            "accel_sigma_m_per_s_per_sqrt_s": (self.accel_sigma_m_per_s_per_sqrt_s
                                               if self.displacement == "constant_velocity" else None),
            "mask_deg": self.mask_deg, "ratio": self.ratio,
            "signals": list(self.signals) if self.signals else ["G:L1"],     # (no key: the GPS L1 path)
        }


def config_kind(text: str) -> str:
    """``"gnss"`` for a GNSS run config (``[gnss]`` table) or a baseline job (``[baseline]``),
    ``"structure"`` otherwise (also for text that is not valid TOML: its loader reports that)."""
    try:
        doc = toml_text.loads(_strip_bom(text))
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

    The ``[gnss]`` table, each ``[gnss.antennas.NAME]`` and ``[gnss.displacement]`` are judged by
    their declarations (:data:`cdgps_cli.config.schema.GNSS_TABLES`), then the rules across keys.
    ``base_dir`` resolves relative file paths (None: kept as written, e.g. for a config read
    back from a RUN.mcap, whose data are in the file).
    """
    text = _strip_bom(text)
    doc = _toml(text, path)
    p = Problems(path)
    for k in sorted(set(doc) - {"gnss"}):
        hint = " (a [baseline] job: only 'cdgps baseline' reads it; see docs/gnss-pipeline.md for the [gnss] form)" \
            if k == "baseline" else " (a GNSS run config has one [gnss] table)"
        p.add(k, "unknown top-level key" + hint)
        p.problems += _description_problems(doc[k], k)
    g = doc.get("gnss")
    if not isinstance(g, dict):
        p.add("gnss", "missing [gnss] table")
        raise CdgpsError(join_problems(f"{path}: invalid GNSS config", p.problems))
    ctx = Context()
    v = check_table(p, g, "gnss", GNSS_TABLES["gnss"], ctx)

    def resolve(f: str) -> str:
        if base_dir is None or Path(f).is_absolute():
            return f
        return os.path.normpath(str(Path(base_dir) / f))

    signals = _gnss_signals(g, p)
    if v["sigma_a_m"] == 0 and v["sigma_b_m"] == 0:
        p.add("gnss.sigma_a_m", "sigma_a_m and sigma_b_m cannot both be 0")
    if v["max_age_s"] < v["sync_tol_s"]:
        p.add("gnss.max_age_s", f"expected at least gnss.sync_tol_s ({v['sync_tol_s']:g} s), got {v['max_age_s']!r}")
    model, rw, init_sigma, accel, phase_noise, mp = _gnss_displacement(p, g.get("displacement", {}), ctx)
    ants = _gnss_antennas(p, g.get("antennas", {}), ctx, resolve)
    for a in ants:
        if a.antenna_type is not None and a.antenna_type.strip().lower() != "none" and not v["antex"]:
            p.add(f"gnss.antennas.{a.name}.antenna_type", f"{a.antenna_type!r}: no gnss.antex file to take its "
                                                          f"calibration from (give antex, or antenna_type = \"none\")")
    master = v["master"]
    if master is not None and ants and master not in [a.name for a in ants]:
        p.add("gnss.master", f"{master!r} is not one of gnss.antennas ({', '.join(a.name for a in ants)})")
    if p.problems:
        raise CdgpsError(join_problems(f"{path}: invalid GNSS config", p.problems))
    name = v["name"] or (Path(path).stem if path and not path.startswith("<") else "gnss-run")
    return GnssConfig(
        path=path, text=text, sha256=hashlib.sha256(text.encode("utf-8")).hexdigest(), name=name,
        description=v["description"], master=master, antennas=tuple(ants), nav=tuple(map(resolve, v["nav"])),
        mask_deg=v["mask_deg"], ratio=v["ratio"], partial=v["partial"], fix=v["fix"], weighting=v["weighting"],
        sigma_a_m=v["sigma_a_m"], sigma_b_m=v["sigma_b_m"], code_ratio=v["code_ratio"], troposphere=v["troposphere"],
        max_gap_s=v["max_gap_s"], sync_tol_s=v["sync_tol_s"], max_age_s=v["max_age_s"],
        code_correlation_s=v["code_correlation_s"], epoch_alignment=v["epoch_alignment"], displacement=model,
        random_walk_sigma=rw, initial_sigma_m=init_sigma, accel_sigma_m_per_s_per_sqrt_s=accel, phase_noise=phase_noise,
        multipath=mp[0], multipath_sigma_m=mp[1], multipath_time_constant_s=mp[2],
        min_success_rate=v["min_success_rate"], signals=signals,
        glonass_fix=v["glonass_fix"],
        iono_threshold_km=v["iono_threshold_km"], antex=resolve(v["antex"]) if v["antex"] else None,
    )


def _gnss_displacement(p: Problems, disp, ctx: Context) -> tuple[str, tuple, float, float, str]:
    """(model, random-walk σ (E, N, U) m/√s, initial σ m, white-acceleration σ m/s/√s, phase noise) of
    ``[gnss.displacement]``."""
    if not isinstance(disp, dict):
        p.add("gnss.displacement", "expected a table ([gnss.displacement])")
        disp = {}
    v = check_table(p, disp, "gnss.displacement", GNSS_TABLES["gnss.displacement"], ctx)
    rw = GNSS_DEFAULTS["random_walk_sigma"]
    if "sigma_m_per_sqrt_s" in disp:
        s = disp["sigma_m_per_sqrt_s"]
        if isinstance(s, (int, float)) and not isinstance(s, bool):
            s = [s, s, s]
        arr = p.vector("gnss.displacement.sigma_m_per_sqrt_s", s, 3)
        if arr is not INVALID and np.any(arr <= 0):
            p.add("gnss.displacement.sigma_m_per_sqrt_s", f"expected positive values (m/√s), got {s!r}")
        elif arr is not INVALID:
            rw = tuple(float(x) for x in arr)
        if disp.get("model", "static") == "static":
            p.add("gnss.displacement.sigma_m_per_sqrt_s", "only used with model = \"random_walk\" (a static "
                                                          "displacement has no process noise)")
    if "accel_sigma_m_per_s_per_sqrt_s" in disp and disp.get("model", "static") != "constant_velocity":
        p.add("gnss.displacement.accel_sigma_m_per_s_per_sqrt_s", "only used with model = \"constant_velocity\"")
    return (v["model"], rw, v["initial_sigma_m"], v["accel_sigma_m_per_s_per_sqrt_s"], v["phase_noise"],
            _gnss_multipath(p, disp, v))


def _gnss_multipath(p: Problems, disp: dict, v: dict) -> tuple:
    """``[gnss.displacement] multipath`` and its σ, τ: (mode, σ m or None, τ s), the rules across the keys checked."""
    mode, key = v["multipath"], "gnss.displacement.multipath"
    if mode != "off" and disp.get("model", "static") == "static":
        p.add(key, f"{mode!r} is only used with model = \"random_walk\" or \"constant_velocity\" (a static "
                   f"displacement takes the static solution)")
    given = [k for k in ("multipath_sigma_m", "multipath_time_constant_s") if k in disp]
    if mode == "model" and "multipath_sigma_m" not in disp:
        p.add(f"{key}_sigma_m", "needed with multipath = \"model\" (each satellite's phase multipath sigma, m)")
    for k in given if mode != "model" else ():
        p.add(f"gnss.displacement.{k}", f"only used with multipath = \"model\" (it is {mode!r})")
    tau = v["multipath_time_constant_s"]
    return mode, v["multipath_sigma_m"], GNSS_DEFAULTS["multipath_time_constant_s"] if tau is None else tau


def _gnss_antennas(p: Problems, at, ctx: Context, resolve) -> list:
    """The ``[gnss.antennas.NAME]`` tables: one observation file each, a position near the Earth."""
    if not isinstance(at, dict):
        p.add("gnss.antennas", "expected tables [gnss.antennas.NAME]")
        return []
    ants = []
    for an, a in at.items():
        key = f"gnss.antennas.{an}"
        if not isinstance(a, dict):
            p.add(key, "expected a table (rinex/ubx file, position_ecef_m)")
            continue
        v = check_table(p, a, key, GNSS_TABLES["gnss.antennas.*"], ctx)
        if v["rinex"] and v["ubx"]:
            p.add(key, "give one observation file: rinex or ubx, not both")
        pos = v["position_ecef_m"]
        if pos is not None and np.linalg.norm(pos) < 6.0e6:
            p.add(f"{key}.position_ecef_m", f"expected an ECEF position near the Earth's surface (m), got "
                                            f"{a['position_ecef_m']!r}")
            pos = None
        ants.append(GnssAntenna(str(an), resolve(v["rinex"]) if v["rinex"] else None,
                                resolve(v["ubx"]) if v["ubx"] else None,
                                tuple(float(x) for x in pos) if pos is not None else None, v["description"],
                                v["antenna_type"]))
    return ants


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


def _displacement_toml(displacement: str, sigma_m_per_sqrt_s, accel_sigma_m_per_s_per_sqrt_s) -> list[str]:
    """The ``[gnss.displacement]`` table of :func:`gnss_config_toml`: the model, its process noise, and a moving
    model's optional noise keys commented."""
    out = ["", "[gnss.displacement]",
           f"model = {_toml_str(displacement)}    # \"static\", \"random_walk\" or \"constant_velocity\" E/N/U "
           f"displacement of each rover"]
    if displacement != "static":
        sig = sigma_m_per_sqrt_s if sigma_m_per_sqrt_s is not None else 0.001
        sig_txt = repr(float(sig)) if np.isscalar(sig) else "[" + ", ".join(repr(float(x)) for x in sig) + "]"
        out.append(f"sigma_m_per_sqrt_s = {sig_txt}    # random-walk process noise per component, m/sqrt(s)"
                   + (" (init's float)" if displacement == "constant_velocity" else ""))
    if displacement == "constant_velocity":
        acc = (GNSS_DEFAULTS["accel_sigma_m_per_s_per_sqrt_s"] if accel_sigma_m_per_s_per_sqrt_s is None
               else float(accel_sigma_m_per_s_per_sqrt_s))
        out.append(f"accel_sigma_m_per_s_per_sqrt_s = {acc!r}    "
                   f"# white acceleration of each velocity, m/s/sqrt(s)")
    if displacement != "static":
        out.append('# phase_noise = "auto"    # the per-epoch states\' phase variances scaled to the single-epoch '
                   'residuals (default "model": sigma_a_m, sigma_b_m)')
        out.append('# multipath = "auto"    # Gauss-Markov phase multipath states per satellite, fitted to the data '
                   '(low-cost receivers: honest sigma; default "off")')
    return out


def gnss_config_toml(antennas: dict, nav=(), master: str | None = None, *, name: str | None = None,
                     description: str = "", displacement: str = "static", sigma_m_per_sqrt_s=None,
                     positions: dict | None = None, comments=(), options: dict | None = None,
                     accel_sigma_m_per_s_per_sqrt_s: float | None = None, antenna_types: dict | None = None) -> str:
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
    accel_sigma_m_per_s_per_sqrt_s : float, optional
        With ``displacement = "constant_velocity"``: its white acceleration (default: the defaults').
    antenna_types : dict, optional
        ``{name: antenna type and radome}`` of the receivers' headers, written as commented ``antenna_type`` keys
        beside a commented ``[gnss] antex`` (the ANTEX file that would take their calibrations out).
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
    if antenna_types:
        out.append('# antex = "igs20.atx"    # receiver antenna calibrations (ANTEX): each antenna\'s phase-centre offset '
                   'and variations taken out of its observations')
    out += _displacement_toml(displacement, sigma_m_per_sqrt_s, accel_sigma_m_per_s_per_sqrt_s)
    for an, (kind, path) in antennas.items():
        out += ["", f"[gnss.antennas.{_toml_str(an)}]"]
        if path is not None:
            out.append(f"{kind} = {_toml_str(path)}")
        pos = (positions or {}).get(an)
        if pos is not None:
            out.append("position_ecef_m = [" + ", ".join(f"{float(x):.4f}" for x in pos) + "]")
        elif kind == "rinex":
            out.append("# position_ecef_m = [x, y, z]    # the antenna's; default: the RINEX header APPROX POSITION XYZ"
                       + (" plus its ANTENNA: DELTA H/E/N" if an == master else ""))
        typ = (antenna_types or {}).get(an)
        if typ:
            out.append(f"# antenna_type = {_toml_str(' '.join(str(typ).split()))}    # its RINEX header's ANT # / TYPE "
                       f"(with [gnss] antex)")
    return "\n".join(out) + "\n"
