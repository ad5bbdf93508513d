"""Draw the 3-D scene of a STATES.mcap at a few instants with matplotlib, from its own SceneUpdate messages.

A check of what Foxglove's 3-D panel shows (``/cdgps/scene``, ``/cdgps/scene_fixed``): lines, spheres,
cubes, arrows and labels drawn from the decoded messages, nothing recomputed from the model.

Usage: python scripts/scene_figure.py STATES.mcap -o scene.png [--instants 4] [--no-transmitters]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from mcap.reader import make_reader  # noqa: E402

SCENE, FIXED = "/cdgps/scene", "/cdgps/scene_fixed"


def _messages(path):
    scene, fixed, exaggeration = [], None, ""
    with open(path, "rb") as fh:
        for _, ch, m in make_reader(fh).iter_messages(topics=[SCENE, FIXED]):
            (scene.append((m.log_time, json.loads(m.data))) if ch.topic == SCENE
             else None)
            if ch.topic == FIXED:
                fixed = json.loads(m.data)
            exaggeration = ch.metadata.get("exaggeration", exaggeration)
    return scene, fixed, exaggeration


def _xyz(p):
    return p["x"], p["y"], p["z"]


def _draw(ax, update, alpha=1.0, labels=True):
    for e in update["entities"]:
        for line in e["lines"]:
            pts = [_xyz(p) for p in line["points"]]
            if line["indices"]:
                pts = [pts[i] for i in line["indices"]]
            c = tuple(line["color"][k] for k in "rgba")
            pairs = zip(pts[::2], pts[1::2]) if line["type"] == 2 else zip(pts[:-1], pts[1:])
            for a, b in pairs:
                ax.plot(*zip(a, b), color=c, lw=2, alpha=alpha)
        for s in e["spheres"]:
            ax.scatter(*_xyz(s["pose"]["position"]), s=40, color=tuple(s["color"][k] for k in "rgb"), alpha=alpha,
                       depthshade=False)
        for c in e["cubes"]:
            ax.scatter(*_xyz(c["pose"]["position"]), s=60, marker="s", color=tuple(c["color"][k] for k in "rgb"))
        for a in e["arrows"]:
            x, y, z = _xyz(a["pose"]["position"])
            q = a["pose"]["orientation"]
            # +x turned by the quaternion
            ux = 1 - 2 * (q["y"] ** 2 + q["z"] ** 2)
            uy = 2 * (q["x"] * q["y"] + q["w"] * q["z"])
            uz = 2 * (q["x"] * q["z"] - q["w"] * q["y"])
            L = a["shaft_length"] + a["head_length"]
            ax.quiver(x, y, z, ux * L, uy * L, uz * L, color="grey")
        if labels:
            for t in e["texts"]:
                ax.text(*_xyz(t["pose"]["position"]), t["text"], fontsize=7)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("states")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--instants", type=int, default=4)
    ap.add_argument("--no-transmitters", action="store_true", help="leave /cdgps/scene_fixed out (far away)")
    a = ap.parse_args(argv)
    scene, fixed, k = _messages(a.states)
    picks = [scene[round(i * (len(scene) - 1) / max(a.instants - 1, 1))] for i in range(a.instants)]
    fig = plt.figure(figsize=(3.2 * a.instants, 3.6))
    for i, (ns, upd) in enumerate(picks):
        ax = fig.add_subplot(1, a.instants, i + 1, projection="3d")
        _draw(ax, scene[0][1], alpha=0.15, labels=False)          # the first instant, faint: the motion since
        _draw(ax, upd)
        if fixed is not None and not a.no_transmitters:
            _draw(ax, fixed)
        ax.set_title(f"t = {(ns - scene[0][0]) / 1e9:.0f} s", fontsize=9)
        ax.set_xlabel("x (m)", fontsize=7)
        ax.set_ylabel("y (m)", fontsize=7)
        ax.set_zlabel("z (m)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_box_aspect((1, 1, 1))
        _equal(ax)
    fig.suptitle(f"{Path(a.states).name}: /cdgps/scene as decoded (deformation x{k}; faint: first instant)", fontsize=9)
    fig.tight_layout()
    fig.savefig(a.output, dpi=130)


def _equal(ax) -> None:
    lims = [ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()]
    c = [(lo + hi) / 2 for lo, hi in lims]
    r = max(hi - lo for lo, hi in lims) / 2
    ax.set_xlim3d(c[0] - r, c[0] + r)
    ax.set_ylim3d(c[1] - r, c[1] + r)
    ax.set_zlim3d(c[2] - r, c[2] + r)


if __name__ == "__main__":
    main()
