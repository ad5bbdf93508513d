"""The closed-loop time history of every generalized coordinate against its stated limit, for
`cdgps report control` (issue 33 item 1).

The limits are the ones the control report itself states (:mod:`cdgps_cli.control.metrics`), drawn
where they apply and named in each panel's title:

* pulse: the sections' vertical-axis rotations (q2, q5, q8 on the testbed:
  :data:`cdgps_cli.report.control.INTERNAL_ANGLES`) must come back within :data:`BACK_FRACTION` of the
  open-loop run's first peak (±, from the pulse start);
* slew: the rigid-body angle must arrive within :data:`ARRIVED_WITHIN_DEG` of the command (±, from the
  command).

Every other coordinate (the yaws q3, q6, q9, the translations) has no stated limit: its panel says
so and shows the open-loop run beside it, so a controller that excites a coordinate it does not
measure itself by is seen.

Each panel: the true value (simulator), the controller's estimate with its ±1σ band and the
reference it tracked (controller.csv), the open-loop run when given, and the limit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cdgps_cli.control.metrics import ARRIVED_WITHIN_DEG, BACK_FRACTION, first_peak_deg

#: every coordinate figure's file name in the control report's output set
COORDINATES_PNG = "coordinates.png"


def coordinate_units(gains: dict, names: list) -> dict:
    """Each coordinate's unit (``rad`` or ``m``) from the config the gain was designed for, when that
    file is still where GAINS.json says and has the same sha256; else None per coordinate."""
    from cdgps_cli.config.structure import load_config  # noqa: PLC0415

    c = gains.get("config") or {}
    path = c.get("path")
    try:
        cfg = load_config(path) if path and Path(path).is_file() else None
    except Exception:                                         # a config that no longer parses: no units
        cfg = None
    if cfg is None or cfg.sha256 != c.get("sha256"):
        return {n: None for n in names}
    return {n: cfg.coord_unit(n) if n in cfg.coord_names else None for n in names}


def coordinate_limits(scenario: str, sims: dict, names: list) -> dict:
    """``{name: (half_width, centre, from_s, text) or None}`` in the coordinate's own unit (rad or m)."""
    closed = sims["closed"]
    out = {n: None for n in names}
    if scenario == "pulse" and "open" in sims:
        seg = next(s for s in closed["truth"]["segments"] if s["kind"] == "pulse")
        from cdgps_cli.report.control import INTERNAL_ANGLES  # noqa: PLC0415

        t = sims["open"]["q"]["time_s"].to_numpy()
        for n in (n for n in names if n in INTERNAL_ANGLES):
            peak = first_peak_deg(t, sims["open"]["q"][n].to_numpy(), seg["start_s"])     # (any unit: |x| max)
            if peak > 0:
                out[n] = (BACK_FRACTION * peak, 0.0, seg["start_s"],
                          f"±{100 * BACK_FRACTION:g} % of the open-loop first peak, from the pulse")
    elif scenario == "slew":
        seg = next(s for s in closed["truth"]["segments"] if s["kind"] == "slew")
        rigid = _rigid_name(names)
        if rigid is not None:
            out[rigid] = (np.radians(ARRIVED_WITHIN_DEG), np.radians(seg["command_deg"]), seg["start_s"],
                          f"±{ARRIVED_WITHIN_DEG:g}° about the command, from the command")
    return out


def _rigid_name(names: list) -> str | None:
    from cdgps_cli.report.control import RIGID_ANGLE  # noqa: PLC0415

    return RIGID_ANGLE if RIGID_ANGLE in names else None


def _scale(unit: str | None) -> tuple[float, str]:
    return {"rad": (float(np.degrees(1.0)), "deg"), "m": (1e3, "mm")}.get(unit, (1.0, "rad or m"))


def coordinates_figure(sims: dict, role: str, limits: dict, units: dict, label: str):
    """Small multiples, one panel per coordinate, of the ``role`` run (see the module docstring)."""
    from cdgps_cli.report.sensor_reports import _mpl  # noqa: PLC0415

    plt = _mpl()
    s = sims[role]
    q, c = s["q"], s["controller"]
    names = [n for n in q.columns if n != "time_s"]
    t = q["time_s"].to_numpy()
    rows = int(np.ceil(len(names) / 2))
    H = 0.9 + 1.7 * rows
    fig, axes = plt.subplots(rows, 2, figsize=(10.0, H), squeeze=False, sharex=True)
    handles = {}
    for i, n in enumerate(names):
        ax = axes[i // 2][i % 2]
        f, u = _scale(units.get(n))
        if "open" in sims and role != "open" and n in sims["open"]["q"]:
            o = sims["open"]["q"]
            handles["open loop (true)"], = ax.plot(o["time_s"], f * o[n], color="0.7", lw=0.9)
        if c is not None and f"{n}_hat" in c.columns:
            tc = c["time_s"].to_numpy()
            est, sd = f * c[f"{n}_hat"].to_numpy(), f * c.get(f"{n}_hat_sigma", 0.0 * c[f"{n}_hat"]).to_numpy()
            handles["estimate ±1σ (controller)"] = ax.fill_between(tc, est - sd, est + sd, color="tab:orange",
                                                                   alpha=0.25, lw=0)
            handles["estimate (controller)"], = ax.plot(tc, est, color="tab:orange", lw=0.8, ls="--")
            if f"{n}_ref" in c.columns:
                handles["reference"], = ax.plot(tc, f * c[f"{n}_ref"].to_numpy(), color="k", lw=0.7, ls=":")
        handles["true value (simulator)"], = ax.plot(t, f * q[n].to_numpy(), color="tab:blue", lw=1.0)
        lim = limits.get(n)
        if lim is None:
            ax.set_title(f"{n}: no limit stated" + (" (open loop in grey)" if "open" in sims else ""), fontsize=8,
                         loc="left")
        else:
            half, centre, t0, text = lim
            lo, hi = f * (centre - half), f * (centre + half)
            ax.fill_between([t0, t[-1]], [lo, lo], [hi, hi], color="tab:red", alpha=0.12, lw=0)
            for v in (lo, hi):
                h, = ax.plot([t0, t[-1]], [v, v], color="tab:red", lw=0.8, ls="--")
            handles["stated limit"] = h
            ax.set_title(f"{n}: limit {text}", fontsize=8, loc="left")
        ax.set_ylabel(f"{n} [{u}]", fontsize=8)
        ax.tick_params(labelsize=7)
    for j in range(len(names), rows * 2):
        axes[j // 2][j % 2].axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"Every generalized coordinate, {label}, against its stated limit", fontsize=10,
                 y=1 - 0.12 / H, va="top")
    fig.legend(list(handles.values()), list(handles), loc="upper center", ncol=len(handles), fontsize=8,
               frameon=False, bbox_to_anchor=(0.5, 1 - 0.36 / H))
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.6 / H))
    return fig


def coordinates_caption(scenario: str, limits: dict, label: str) -> str:
    stated = [n for n, v in limits.items() if v is not None]
    text = (f"Every generalized coordinate of the {label} run: true value (blue, simulator truth.csv), the "
            f"controller's estimate with its ±1σ band (orange, controller.csv) and the reference it tracked "
            f"(dotted), the open-loop run (grey) when given; angles in degrees, lengths in mm. ")
    if stated:
        text += (f"Dashed red: the limit the report states ({', '.join(stated)}): "
                 + ("back within "
                    f"{100 * BACK_FRACTION:g} % of the open-loop first peak after the pulse"
                    if scenario == "pulse" else f"the rigid-body angle within ±{ARRIVED_WITHIN_DEG:g}° of the command")
                 + ". ")
    text += "A panel titled 'no limit stated' has no criterion in the report; it is shown so no coordinate goes unseen."
    return text
