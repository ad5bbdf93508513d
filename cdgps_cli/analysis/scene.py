"""The structure drawn in 3-D: ``foxglove.SceneUpdate`` messages of a structure estimate (no I/O).

What is drawn, from the structure config alone (:func:`scene_geometry`):

* the **skeleton**: the shortest tree (minimum spanning tree of the nominal distances) joining the
  body origin, the section pivots and the points fixed to the body frame (antennas and named
  ``[[points]]`` without a section, e.g. finite-element nodes) — the testbed's beams C1–C2–C3, a
  tower's mast from its foundation to its top;
* **spokes** from each section pivot to the antennas and named points carried by that section;
* **antennas** as spheres (the master in red) with their names, named points as small spheres;
* in one message of its own (:meth:`StructureScene.fixed`): **pseudolites** as cubes at their
  positions, or far-field transmitters as arrows from the body origin along their directions;
* on a GNSS run, **satellites** (:class:`SatelliteSky`, from the run's broadcast geometry): an arrow
  from the master antenna, as drawn, toward each satellite used at that epoch, with its name at the tip
  (entity ``satellites`` of every ``/cdgps/scene`` message).

Every node moves as the model says (:func:`cdgps_cli.model.kinematics.point_positions`, q = U ξ).
The motion is drawn exaggerated: with q_r the coordinates with only the rigid-body rotation kept
(all zero without one),

    p_drawn = p(q_r) + k · (p(q) − p(q_r)),

so the structure turns as a whole at true scale and its deformation is magnified k times
(``estimate --scene-exaggeration``).  Drawn positions are rounded to about :data:`RESOLUTION` of
the structure's size (1 mm on the 8 m testbed) to keep the messages small.
:func:`cdgps_cli.io.states.write_states` writes the messages (topics ``/cdgps/scene`` and
``/cdgps/scene_fixed``) at the anti-aliased preview epochs (:mod:`cdgps_cli.analysis.preview`);
their schema is :mod:`cdgps_cli.io.foxglove_schema`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdgps_cli.model.kinematics import point_positions

FRAME_ID = "cdgps_lab"
"""Frame of every scene entity: the structure's lab frame (x, y, z as the config, metres)."""
RESOLUTION = 1e-4
"""Drawn positions are rounded to about this fraction of the structure's size (the nearest power of
ten of a metre, at most 0.1 mm): 1 mm on the 8 m testbed, 1 cm on the 120 m tower — invisible at
any zoom that shows the structure, and fewer digits to store."""

_COLORS = {"skeleton": (0.25, 0.45, 0.85, 1.0), "spoke": (0.55, 0.7, 0.95, 1.0), "antenna": (1.0, 0.6, 0.1, 1.0),
           "master": (0.9, 0.15, 0.15, 1.0), "point": (0.2, 0.7, 0.9, 1.0), "label": (1.0, 1.0, 1.0, 1.0),
           "pseudolite": (0.2, 0.75, 0.3, 1.0), "direction": (0.6, 0.6, 0.6, 0.8),
           "satellite": (0.95, 0.85, 0.25, 0.9)}
_IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


@dataclass(frozen=True)
class SceneGeometry:
    """The nodes and lines drawn for a structure (nominal, body frame).

    Attributes
    ----------
    names : tuple of str (P,)
        ``origin``, ``pivot:<section>``, antenna names, named points.
    kinds : tuple of str (P,)
        ``origin``, ``pivot``, ``master``, ``antenna`` or ``point``.
    section : ndarray of int (P,)
        Section per node, -1: the body frame.
    position_m : ndarray (P, 3)
        Nominal body-frame positions, m.
    displacement : ndarray (P, 3, n_q)
        Linear displacement per coordinate (FE mode shapes), m per coordinate unit.
    skeleton, spokes : ndarray of int (E, 2), (S, 2)
        Node pairs joined by a line.
    size_m : float
        Extent of the structure (largest nominal distance between nodes, at least 1 m).
    """

    names: tuple
    kinds: tuple
    section: np.ndarray
    position_m: np.ndarray
    displacement: np.ndarray
    skeleton: np.ndarray
    spokes: np.ndarray
    size_m: float


@dataclass(frozen=True)
class SatelliteSky:
    """Directions toward the satellites a GNSS structure run used, epoch by epoch (structure frame).

    Attributes
    ----------
    time_s : ndarray (M,)
        Epochs, s (the record's time scale), increasing.
    names : tuple of str (S,)
        Satellites (``G05``, ``E11`` …).
    direction : ndarray (M, S, 3)
        Unit vectors from the master antenna toward each satellite, structure frame; NaN where the
        satellite was not used at that epoch.
    """

    time_s: np.ndarray
    names: tuple
    direction: np.ndarray

    def at(self, time_s) -> np.ndarray:
        """The directions (k, S, 3) at the latest epoch at or before each time (the first before it)."""
        j = np.searchsorted(self.time_s, np.asarray(time_s, dtype=float), side="right") - 1
        return self.direction[np.clip(j, 0, len(self.time_s) - 1)]


def scene_geometry(cfg) -> SceneGeometry:
    """The nodes, skeleton and spokes of ``cfg`` (a :class:`~cdgps_cli.config.structure.StructureConfig`)."""
    n_q = cfg.n_q
    names, kinds, sec, pos, disp = ["origin"], ["origin"], [-1], [np.zeros(3)], [np.zeros((3, n_q))]
    for s, section in enumerate(cfg.sections):
        names.append(f"pivot:{section.name}")
        kinds.append("pivot")
        sec.append(s)
        pos.append(np.asarray(section.pivot_m, dtype=float))
        disp.append(np.zeros((3, n_q)))
    for i, name in enumerate(cfg.antenna_names):
        names.append(name)
        kinds.append("master" if i == cfg.master_index else "antenna")
        sec.append(int(cfg.antenna_section[i]))
        pos.append(np.asarray(cfg.antenna_position_m[i], dtype=float))
        disp.append(np.asarray(cfg.antenna_displacement[i], dtype=float))
    for i, name in enumerate(cfg.point_names):
        names.append(name)
        kinds.append("point")
        sec.append(int(cfg.point_section[i]))
        pos.append(np.asarray(cfg.point_position_m[i], dtype=float))
        disp.append(np.asarray(cfg.point_displacement[i], dtype=float))
    section = np.array(sec, dtype=int)
    position = np.array(pos, dtype=float).reshape(-1, 3)
    # pivots first, the origin last: a pivot at the origin (the testbed's C2) is the node kept
    frame_nodes = [k for k in range(len(names)) if kinds[k] == "pivot"] + \
        [k for k in range(len(names)) if kinds[k] not in ("origin", "pivot") and section[k] < 0] + [0]
    skeleton = _spanning_tree(position, frame_nodes)
    spokes = [(1 + s, k) for k in range(len(names)) if kinds[k] not in ("origin", "pivot")
              for s in [section[k]] if s >= 0 and np.linalg.norm(position[k] - position[1 + s]) > 1e-3]
    d = np.linalg.norm(position[:, None] - position[None], axis=-1)
    return SceneGeometry(tuple(names), tuple(kinds), section, position, np.array(disp).reshape(-1, 3, n_q),
                         np.array(skeleton, dtype=int).reshape(-1, 2), np.array(spokes, dtype=int).reshape(-1, 2),
                         max(float(d.max()), 1.0))


def _spanning_tree(position: np.ndarray, nodes: list[int], same_m: float = 1e-3) -> list[tuple[int, int]]:
    """Edges of the minimum spanning tree (Prim, ties to the lower index) over ``nodes``; nodes
    within ``same_m`` of an earlier one are the same place and get no edge of their own."""
    keep = []
    for k in nodes:
        if all(np.linalg.norm(position[k] - position[j]) > same_m for j in keep):
            keep.append(k)
    if len(keep) < 2:
        return []
    p = position[keep]
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    inside = np.zeros(len(keep), dtype=bool)
    inside[0] = True
    best, parent = d[0].copy(), np.zeros(len(keep), dtype=int)
    edges = []
    for _ in range(len(keep) - 1):
        j = int(np.argmin(np.where(inside, np.inf, best)))
        edges.append((keep[int(parent[j])], keep[j]))
        inside[j] = True
        closer = d[j] < best
        best = np.where(closer, d[j], best)
        parent = np.where(closer, j, parent)
    return edges


def drawn_positions(cfg, geom: SceneGeometry, q: np.ndarray, exaggeration: float) -> np.ndarray:
    """Lab-frame positions of the nodes as drawn, (N, P, 3) m: p(q_r) + k (p(q) − p(q_r)).

    Parameters
    ----------
    cfg : StructureConfig
    geom : SceneGeometry
    q : ndarray (N, n_q)
        Coordinates (m or rad as the config declares).
    exaggeration : float
        k, the factor on the deformation (1: true scale).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    p = point_positions(cfg, q, geom.section, geom.position_m, geom.displacement)
    q_r = np.zeros_like(q)
    if cfg.rigid_index is not None:
        q_r[:, cfg.rigid_index] = q[:, cfg.rigid_index]
    p_r = point_positions(cfg, q_r, geom.section, geom.position_m, geom.displacement)
    return p_r + float(exaggeration) * (p - p_r)


def auto_exaggeration(cfg, geom: SceneGeometry, q: np.ndarray, fraction: float) -> float:
    """The exaggeration that draws the largest deformation about ``fraction`` of the structure's size.

    The deformation is the 99th percentile over the epochs of ``q`` (k, n_q) of the largest node
    displacement |p(q) − p(q_r)|; the factor is the largest of 1, 2, 5, 10, 20, … that keeps it at or
    below ``fraction`` · size, and never below 1 (a structure that moves visibly is drawn at true scale).
    """
    q = np.asarray(q, dtype=float)
    q = q[np.isfinite(q).all(axis=1)] if q.ndim == 2 else q
    if q.size == 0:
        return 1.0
    largest = np.concatenate([                                # blocks: memory does not grow with the record
        np.linalg.norm(drawn_positions(cfg, geom, q[a:a + 4096], 1.0) - drawn_positions(cfg, geom, q[a:a + 4096], 0.0),
                       axis=-1).max(axis=1) for a in range(0, len(q), 4096)])
    big = float(np.percentile(largest, 99))
    if not big > 0:
        return 1.0
    target = fraction * geom.size_m / big
    k = 1.0
    for decade in range(0, 9):
        for m in (1.0, 2.0, 5.0):
            if m * 10.0 ** decade <= target:
                k = m * 10.0 ** decade
    return k


def _xyz(v) -> dict:
    return {"x": v[0], "y": v[1], "z": v[2]}


def _rgba(name: str) -> dict:
    return dict(zip("rgba", _COLORS[name]))


def _stamp(ns: int) -> dict:
    return {"sec": int(ns) // 1_000_000_000, "nsec": int(ns) % 1_000_000_000}


def _pose(v) -> dict:
    return {"position": _xyz(v), "orientation": dict(_IDENTITY)}


def _entity(ns, entity_id: str, stamp: dict | None = None, **primitives) -> dict:
    e = {"timestamp": _stamp(ns) if stamp is None else stamp, "frame_id": FRAME_ID, "id": entity_id, "lifetime": {"sec": 0, "nsec": 0},
         "frame_locked": False, "metadata": []}
    for k in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"):
        e[k] = primitives.get(k, [])
    return e


def _line_list(pairs: np.ndarray, color: str) -> tuple[dict, list]:
    """One LINE_LIST (type 2) through the node pairs, 3 px wide at any zoom: the primitive without its
    points, and the nodes whose positions are its points (each once; ``indices`` pair them up)."""
    nodes = list(dict.fromkeys(pairs.ravel().tolist()))
    where = {k: i for i, k in enumerate(nodes)}
    head = {"type": 2, "pose": _pose((0.0, 0.0, 0.0)), "thickness": 3.0, "scale_invariant": True,
            "color": _rgba(color), "colors": [], "indices": [where[k] for k in pairs.ravel().tolist()]}
    return head, nodes


class StructureScene:
    """The scene of one structure: :meth:`updates` per epoch block, :meth:`fixed` once.

    Parameters
    ----------
    cfg : StructureConfig
    exaggeration : float
        Factor on the deformation (> 0).
    transmitters : bool
        Draw the config's transmitters (:meth:`fixed`); not on a GNSS run, where the satellites
        replace them.
    satellites : SatelliteSky, optional
        A GNSS run's satellite directions: arrows from the master antenna in every :meth:`updates`
        message given its epochs' times.
    """

    def __init__(self, cfg, exaggeration: float, transmitters: bool = True, satellites: SatelliteSky | None = None):
        if not (exaggeration > 0 and np.isfinite(exaggeration)):
            raise ValueError(f"scene exaggeration {exaggeration!r}: expected a finite factor > 0")
        self.cfg = cfg
        self.exaggeration = float(exaggeration)
        self.transmitters = bool(transmitters)
        self.satellites = satellites
        self.geometry = scene_geometry(cfg)
        self.decimals = min(max(int(round(-np.log10(RESOLUTION * self.geometry.size_m))), 0), 4)
        self._constant_parts()
        self.metadata = {"frame_id": FRAME_ID, "exaggeration": f"{self.exaggeration:g}",
                         "drawn": "p(q_r) + exaggeration * (p(q) - p(q_r)); q_r: the rigid-body rotation only",
                         "nodes": ",".join(self.geometry.names), "size_m": f"{self.geometry.size_m:.6g}",
                         "resolution_m": f"{10.0 ** -self.decimals:g}"}

    def updates(self, q: np.ndarray, stamps_ns, time_s=None) -> list:
        """SceneUpdate messages (dicts) at the epochs of ``q`` (k, n_q), log times ``stamps_ns`` (Unix
        ns); None where q is not finite.  ``time_s`` (k,): the epochs' times, for the satellite arrows
        (drawn when the scene has :attr:`satellites` and the times are given).  (Constant parts are
        shared between messages: read-only.)"""
        P, lifted = self._drawn(q)
        ok = np.isfinite(P.reshape(len(P), -1)).all(axis=1).tolist()
        sky = [None] * len(P) if self.satellites is None or time_s is None else self.satellites.at(time_s)
        out = []
        for frame, good, ns, zs, dirs in zip(P.tolist(), ok, stamps_ns, lifted.tolist(), sky):
            if not good:
                out.append(None)
                continue
            msg = self._structure_message(frame, _stamp(ns), zs)
            if dirs is not None:
                msg["entities"].append(self._satellite_entity(ns, frame[self._master], dirs))
            out.append(msg)
        return out

    def skeleton(self, slot) -> dict:
        """The :meth:`updates` message of an epoch without satellites, its numbers given by
        ``slot(i)``: column i of :meth:`rows`, ``slot(-1)`` / ``slot(-2)`` the log time's seconds and
        nanoseconds (a writer fills in the numbers instead of serialising a dict per epoch)."""
        n = len(self.geometry.names)
        frame = [[slot(3 * k), slot(3 * k + 1), slot(3 * k + 2)] for k in range(n)]
        zs = [slot(3 * n + j) for j in range(len(self._labelled))]
        return self._structure_message(frame, {"sec": slot(-1), "nsec": slot(-2)}, zs)

    def rows(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The numbers of :meth:`skeleton` at the epochs of ``q`` (k, n_q): (k, 3 P + labels) drawn node
        positions then label heights, m; and which epochs are drawn (finite; :meth:`updates` gives None
        at the others)."""
        P, lifted = self._drawn(q)
        flat = P.reshape(len(P), -1)
        return np.hstack([flat, lifted]), np.isfinite(flat).all(axis=1)

    def _drawn(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Node positions as drawn (k, P, 3) and label heights (k, labels), rounded to the scene's resolution."""
        P = np.round(drawn_positions(self.cfg, self.geometry, q, self.exaggeration), self.decimals)
        return P, np.round(P[:, self._labelled, 2] + self._lift, self.decimals)

    def _structure_message(self, frame, stamp: dict, zs) -> dict:
        """The SceneUpdate of the structure from node positions ``frame`` (P × [x, y, z]) and label heights ``zs``."""
        xyz = [{"x": x, "y": y, "z": z} for x, y, z in frame]
        lines = [dict(head, points=[xyz[k] for k in idx]) for head, idx in self._lines]
        spheres = [{"pose": {"position": xyz[k], "orientation": _IDENTITY}, **rest} for k, rest in self._spheres]
        texts = [{"pose": {"position": {"x": xyz[k]["x"], "y": xyz[k]["y"], "z": z}, "orientation": _IDENTITY},
                  **rest} for (k, rest), z in zip(self._texts, zs)]
        return {"deletions": [], "entities": [_entity(None, "structure", stamp, lines=lines, spheres=spheres,
                                                      texts=texts)]}

    def _satellite_entity(self, ns: int, master_xyz, dirs: np.ndarray) -> dict:
        """The ``satellites`` entity: arrows from the master antenna (as drawn) along ``dirs`` (S, 3),
        the satellites not used (NaN) left out, each named at its tip."""
        L, m = self.geometry.size_m, np.asarray(master_xyz, dtype=float)
        arrows, texts = [], []
        for name, u in zip(self.satellites.names, dirs):
            if not np.isfinite(u).all():
                continue
            turn = {k: round(v, 6) for k, v in _direction_quaternion(u).items()}     # 1e-6: invisible, half the bytes
            arrows.append({"pose": {"position": _xyz(m.tolist()), "orientation": turn},
                           "shaft_length": round(0.5 * L, 3), "shaft_diameter": round(0.005 * L, 3),
                           "head_length": round(0.1 * L, 3), "head_diameter": round(0.02 * L, 3),
                           "color": _rgba("satellite")})
            texts.append(_label(np.round(m + 0.65 * L * np.asarray(u, dtype=float), self.decimals), name))
        return _entity(ns, "satellites", arrows=arrows, texts=texts)

    def _constant_parts(self) -> None:
        """What every :meth:`updates` message shares: line heads and node lists, sphere sizes and
        colours, labels."""
        g = self.geometry
        self._lines = [_line_list(pairs, c) for pairs, c in ((g.skeleton, "skeleton"), (g.spokes, "spoke")) if len(pairs)]
        r = round(0.02 * g.size_m, 3)
        shown = [k for k, kind in enumerate(g.kinds) if kind in ("master", "antenna", "point")]
        self._spheres = []
        for k in shown:
            d = round(r * (2.0 if g.kinds[k] != "point" else 1.2), 4)
            self._spheres.append((k, {"size": {"x": d, "y": d, "z": d}, "color": _rgba(g.kinds[k])}))
        self._labelled = [k for k in shown if g.kinds[k] != "point"]
        self._master = g.kinds.index("master") if "master" in g.kinds else 0
        self._lift = round(3.0 * r, 4)
        self._texts = [(k, {"billboard": True, "font_size": 14.0, "scale_invariant": True, "color": _rgba("label"),
                            "text": g.names[k]}) for k in self._labelled]

    def fixed(self, stamp_ns: int) -> dict | None:
        """The transmitters: pseudolites as cubes, far-field directions as arrows from the body origin
        (None without transmitters)."""
        cfg = self.cfg
        if not (self.transmitters and len(cfg.transmitter_names)):
            return None
        T = np.asarray(cfg.transmitter_position_m, dtype=float).reshape(-1, 3)
        L = self.geometry.size_m
        if cfg.transmitter_far_field:
            origin = np.asarray(cfg.body_origin_m, dtype=float).tolist()
            arrows = [{"pose": {"position": _xyz(origin), "orientation": _direction_quaternion(u)},
                       "shaft_length": round(0.8 * L, 3), "shaft_diameter": round(0.01 * L, 3),
                       "head_length": round(0.2 * L, 3), "head_diameter": round(0.03 * L, 3),
                       "color": _rgba("direction")} for u in T]
            texts = [_label(np.asarray(origin) + 1.05 * L * u / np.linalg.norm(u), n) for u, n in
                     zip(T, cfg.transmitter_names)]
            prims = {"arrows": arrows, "texts": texts}
        else:
            s = round(0.03 * L, 3)
            prims = {"cubes": [{"pose": _pose(p.tolist()), "size": {"x": s, "y": s, "z": s}, "color": _rgba("pseudolite")}
                               for p in T],
                     "texts": [_label(p + np.array([0.0, 0.0, 1.5 * s]), n) for p, n in zip(T, cfg.transmitter_names)]}
        return {"deletions": [], "entities": [_entity(stamp_ns, "transmitters", **prims)]}


def _label(at: np.ndarray, text: str) -> dict:
    return {"pose": _pose([round(float(v), 4) for v in at]), "billboard": True, "font_size": 14.0,
            "scale_invariant": True, "color": _rgba("label"), "text": str(text)}


def _direction_quaternion(u) -> dict:
    """Unit quaternion turning +x onto the direction ``u``."""
    u = np.asarray(u, dtype=float) / np.linalg.norm(u)
    x = np.array([1.0, 0.0, 0.0])
    c = float(np.dot(x, u))
    if c < -1.0 + 1e-12:                                   # opposite: half a turn about z
        return {"x": 0.0, "y": 0.0, "z": 1.0, "w": 0.0}
    u0, u1, u2 = (float(v) for v in u)
    # x × u as numpy.cross evaluates it (a1·b2 − a2·b1, a2·b0 − a0·b2, a0·b1 − a1·b0 with a = x): the same
    # products and differences bit for bit, signed zeros too, without its per-call axis handling (a STATES
    # file turns an arrow per satellite and preview epoch)
    axis = (0.0 * u2 - 0.0 * u1, 0.0 * u0 - 1.0 * u2, 1.0 * u1 - 0.0 * u0)
    qv = np.array([*axis, 1.0 + c])
    qv /= np.linalg.norm(qv)
    return dict(zip("xyzw", [float(v) for v in qv]))
