"""The z-plane pole figure of an LQR design, in the style of Fig. 6 of the 1998 paper."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from cdgps_cli.io.atomic import write_bytes_atomic


def pole_figure(poles: dict, path: str | Path, title: str) -> None:
    """Open-loop (×) and closed-loop (+) poles in the first quadrant of the z plane, with the unit
    circle and a zoom on the region near z = 1 where the lightly damped poles sit; PNG written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10.5, 5.0), dpi=110)
    th = np.linspace(0, np.pi / 2, 400)
    for ax, zoom in zip(axes, (False, True)):
        ax.plot(np.cos(th), np.sin(th), color="0.6", lw=0.8, label="unit circle")
        for key, marker, colour, label in (("open_loop", "x", "tab:red", "open loop"),
                                           ("closed_loop", "+", "tab:blue", "closed loop (LQR)")):
            z = np.array([[r["z_re"], r["z_im"]] for r in poles[key]])
            ax.plot(z[:, 0], z[:, 1], marker, color=colour, ms=9, mew=1.6, ls="none", label=label)
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
        ax.set_xlabel("Re z")
        ax.set_ylabel("Im z")
        if zoom:
            near = np.array([[r["z_re"], r["z_im"]] for k in ("open_loop", "closed_loop") for r in poles[k]
                             if r["z_re"] > 0.9])
            left = min(0.99, float(near[:, 0].min()) if near.size else 0.99)
            top = max(0.02, float(near[:, 1].max()) if near.size else 0.02)
            ax.set_xlim(left - 0.1 * (1.0 - left), 1.0 + 0.1 * (1.0 - left))
            ax.set_ylim(-0.02 * top, 1.1 * top)
            ax.set_aspect("auto")
            ax.set_title("near z = 1 (rigid-body and lightly damped modes)")
        else:
            ax.set_xlim(0, 1.05)
            ax.set_ylim(0, 1.05)
            ax.set_title("first quadrant")
            ax.legend(loc="lower left", fontsize=8)
    fig.suptitle(title)
    fig.text(0.01, 0.01, "× open-loop poles, + closed-loop poles of u = −K x (discrete LQR, Eq. 24); "
             "conjugates omitted.", fontsize=8)
    fig.tight_layout(rect=(0, 0.04, 1, 0.95))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())
