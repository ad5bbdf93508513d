"""The structure config's fusable sensors (issue 30): ``[[accelerometers]]``, ``[[tilts]]``, ``[[strains]]``, the
``[[gyros]]`` as measurements (their noise keys) and ``[fusion]`` (docs/config-format.md).

Keys are declared in :data:`cdgps_cli.config.schema.STRUCTURE_TABLES` (so the structure parser already
accepts them and the JSON Schema lists them); this module reads their values from the validated
config's text into :class:`SensorSpec` records, with messages naming the file and key.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass

import numpy as np

from cdgps_cli.config.schema import STRUCTURE_TABLES
from cdgps_cli.config.structure import AXES, StructureConfig
from cdgps_cli.core import toml_text
from cdgps_cli.core.errors import CdgpsError

__all__ = ["SensorSpec", "sensor_specs", "fusion_settings", "FUSABLE_KINDS"]

FUSABLE_KINDS = ("gyro", "accel", "tilt", "strain")


@dataclass(frozen=True)
class SensorSpec:
    """One sensor of the config.

    Attributes
    ----------
    kind : str
        ``accel``, ``tilt`` or ``gyro``.
    name : str
    axes : tuple
        Axis names (``x``, ``y``, ``z``) or 3-vectors.
    sigma : float
        White noise in the sensor's unit (m/s², rad, rad/s).
    bias_sigma : float or None
        Prior σ of the bias states (None: no bias state).
    bias_drift : float
        Their random walk, unit/√s.
    sample_period_s : float
    point : str or None
        Accelerometers: the antenna or ``[[points]]`` name; strain gauges: the gauge's first end.
    section : int
        Section index (−1: body).
    rotation_rad : ndarray (3, n_q) or None
    point_b : str or None
        Strain gauges: the gauge's other end.
    """

    kind: str
    name: str
    axes: tuple
    sigma: float
    bias_sigma: float | None
    bias_drift: float
    sample_period_s: float
    point: str | None = None
    section: int = -1
    rotation_rad: np.ndarray | None = None
    point_b: str | None = None


class _Reader:
    def __init__(self, cfg: StructureConfig):
        self.cfg, self.problems = cfg, []

    def num(self, t: dict, key: str, name: str, default=None, positive=False):
        if name not in t:
            if default is None:
                self.problems.append(f"{key}.{name}: missing required key")
            return default
        v = t[name]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0 or (positive and v == 0):
            self.problems.append(f"{key}.{name}: expected a {'positive' if positive else 'non-negative'} finite number, got {v!r}")
            return default if default is not None else 1.0
        return float(v)

    def axes(self, v, key: str) -> tuple:
        items = [v] if isinstance(v, str) or (isinstance(v, list) and v and not isinstance(v[0], (str, list))) else v
        out = []
        for a in items if isinstance(items, list) else [items]:
            if isinstance(a, str) and a in AXES:
                out.append(a)
            elif isinstance(a, list) and len(a) == 3 and all(isinstance(e, (int, float)) and not isinstance(e, bool) for e in a) \
                    and np.linalg.norm(a) > 0:
                out.append(tuple(float(e) for e in a))
            else:
                self.problems.append(f"{key}: expected x, y, z, a non-zero 3-vector or a list of them, got {v!r}")
                return ("x",)
        if len(set(out)) != len(out):
            self.problems.append(f"{key}: an axis is given twice in {v!r}")
        return tuple(out)

    def section(self, t: dict, key: str) -> int:
        if "section" not in t:
            return -1
        names = [s.name for s in self.cfg.sections]
        if t["section"] not in names:
            self.problems.append(f"{key}.section: expected the name of a section ({', '.join(names) or 'none defined'}), "
                                 f"got {t['section']!r}")
            return -1
        return names.index(t["section"])

    def rotation(self, t: dict, key: str):
        if "rotation_rad" not in t:
            return None
        out = np.zeros((3, self.cfg.n_q))
        tbl = t["rotation_rad"]
        for ref, v in (tbl.items() if isinstance(tbl, dict) else []):
            ok = isinstance(v, list) and len(v) == 3 and all(isinstance(e, (int, float)) and not isinstance(e, bool) for e in v)
            if ref not in self.cfg.coord_names or not ok:
                self.problems.append(f"{key}.rotation_rad.{ref}: expected a coordinate name = [rx, ry, rz], got {v!r}")
                continue
            out[:, self.cfg.coord_names.index(ref)] = v
        return out

    def bias(self, t: dict, key: str, prior: str, drift: str, prior_default=0.0, drift_default=0.0):
        b = self.num(t, key, prior, prior_default)
        return (b if b else None), self.num(t, key, drift, drift_default)

    def keys(self, t: dict, key: str, table: str) -> None:
        allowed = STRUCTURE_TABLES[table]
        for k in sorted(set(t) - set(allowed)):
            self.problems.append(f"{key}.{k}: unknown key (allowed: {', '.join(sorted(allowed))})")
        if "name" in allowed and not (isinstance(t.get("name"), str) and t["name"]):
            self.problems.append(f"{key}.name: expected a non-empty string, got {t.get('name', 'nothing')!r}")

    def tables(self, doc: dict, table: str) -> list:
        """``[[table]]`` entries of ``doc``; a problem (and none) unless it is an array of tables."""
        v = doc.get(table, [])
        if isinstance(v, list) and all(isinstance(e, dict) for e in v):
            return v
        self.problems.append(f"{table}: expected an array of tables ([[{table}]]), got {type(v).__name__} {v!r:.60}")
        return []


def _doc(cfg: StructureConfig) -> dict:
    try:
        return toml_text.loads(cfg.text.lstrip("\ufeff"))
    except tomllib.TOMLDecodeError as exc:          # (load_config already parsed it)
        raise CdgpsError(f"{cfg.path}: not valid TOML: {exc}") from None


def sensor_specs(cfg: StructureConfig) -> list[SensorSpec]:
    """Every accelerometer, tilt meter, strain gauge and gyro of the config as a :class:`SensorSpec`
    (config order: accelerometers, tilt meters, strain gauges, then gyros); CdgpsError listing every bad key."""
    doc, rd, out = _doc(cfg), _Reader(cfg), []
    T = cfg.sample_period_s
    for i, a in enumerate(rd.tables(doc, "accelerometers")):
        key = f"accelerometers[{i}]"
        rd.keys(a, key, "accelerometers[]")
        point = a.get("point")
        if point not in cfg.antenna_names and point not in cfg.point_names:
            rd.problems.append(f"{key}.point: {point!r} is not an antenna or [[points]] name "
                               f"(antennas: {', '.join(cfg.antenna_names)}; points: {', '.join(cfg.point_names) or 'none'})")
        b, d = rd.bias(a, key, "bias_sigma_m_s2", "bias_drift_m_s2_per_sqrt_s")
        out.append(SensorSpec("accel", str(a.get("name")), rd.axes(a.get("axes"), f"{key}.axes"),
                              rd.num(a, key, "sigma_m_s2", positive=True), b, d,
                              rd.num(a, key, "sample_period_s", T, positive=True), point=str(point),
                              section=-1, rotation_rad=rd.rotation(a, key)))
    for i, t in enumerate(rd.tables(doc, "tilts")):
        key = f"tilts[{i}]"
        rd.keys(t, key, "tilts[]")
        b, d = rd.bias(t, key, "bias_sigma_rad", "bias_drift_rad_per_sqrt_s")
        out.append(SensorSpec("tilt", str(t.get("name")), rd.axes(t.get("axis"), f"{key}.axis"),
                              rd.num(t, key, "sigma_rad", positive=True), b, d,
                              rd.num(t, key, "sample_period_s", T, positive=True), section=rd.section(t, key),
                              rotation_rad=rd.rotation(t, key)))
        if "section" not in t and "rotation_rad" not in t:
            rd.problems.append(f"{key}: a tilt meter needs a section (with rotation coordinates) or rotation_rad")
    for i, g in enumerate(rd.tables(doc, "strains")):
        key = f"strains[{i}]"
        rd.keys(g, key, "strains[]")
        ends = [g.get("point_a"), g.get("point_b")]
        for end, p in zip(("point_a", "point_b"), ends):
            if p not in cfg.antenna_names and p not in cfg.point_names:
                rd.problems.append(f"{key}.{end}: {p!r} is not an antenna or [[points]] name "
                                   f"(antennas: {', '.join(cfg.antenna_names)}; points: {', '.join(cfg.point_names) or 'none'})")
        if ends[0] == ends[1]:
            rd.problems.append(f"{key}: point_a and point_b are the same point ({ends[0]!r}); a gauge has two ends")
        b, d = rd.bias(g, key, "bias_sigma_strain", "bias_drift_strain_per_sqrt_s")
        out.append(SensorSpec("strain", str(g.get("name")), ("gauge",), rd.num(g, key, "sigma_strain", positive=True), b, d,
                              rd.num(g, key, "sample_period_s", T, positive=True), point=str(ends[0]),
                              point_b=str(ends[1])))
    sim = cfg.simulation
    gp = sim.get("gyro_sample_period_s", 0.0) or T
    for i, g in enumerate(doc.get("gyros", [])):
        key = f"gyros[{i}]"
        b, d = rd.bias(g, key, "bias_sigma_rad_s", "bias_drift_rad_s_per_sqrt_s", sim["gyro_bias_sigma_rad_s"],
                       sim["gyro_bias_drift_rad_s_per_sqrt_s"])
        out.append(SensorSpec("gyro", cfg.gyro_names[i], (tuple(cfg.gyro_axis[i]),),
                              rd.num(g, key, "sigma_rad_s", sim["gyro_noise_rad_s"], positive=True), b, d, gp))
    names = [s.name for s in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        rd.problems.append(f"sensors: duplicate name(s) {', '.join(dup)} (accelerometers, tilts and gyros share one name space)")
    if rd.problems:
        raise CdgpsError(f"{cfg.path}: invalid sensor config:\n  " + "\n  ".join(rd.problems))
    return out


def fusion_settings(cfg: StructureConfig) -> dict:
    """``[fusion]``: {"fuse": tuple of kinds, "hold_out": tuple of sensor names} (empty by default: opt-in)."""
    f = _doc(cfg).get("fusion", {})
    fuse, hold = f.get("fuse", []), f.get("hold_out", [])
    bad = [k for k in fuse if k not in FUSABLE_KINDS] if isinstance(fuse, list) else [fuse]
    if not bad and len(set(fuse)) != len(fuse):
        raise CdgpsError(f"{cfg.path}: fusion.fuse: a kind given twice in {fuse!r}; expected each kind once")
    if bad or not isinstance(hold, list) or not all(isinstance(h, str) for h in hold):
        raise CdgpsError(f"{cfg.path}: fusion: expected fuse = a list of {', '.join(FUSABLE_KINDS)} and hold_out = a "
                         f"list of sensor names, got fuse = {fuse!r}, hold_out = {hold!r}")
    return {"fuse": tuple(fuse), "hold_out": tuple(hold)}
