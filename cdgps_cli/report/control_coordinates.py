"""Every generalized coordinate's limit, with where it comes from, and the closed-loop time history
of each against it, for `cdgps report control` (issues 31 and 33).

One table of limits (:func:`checked_limits`) feeds both the report's "Every coordinate" check
(:func:`cdgps_cli.control.metrics.coordinate_checks`) and the figure, so what is drawn is what is
checked. On the testbed (1998 paper, Sec. VI):

* q2, q5, q8 (the internal rotations): 1°, the paper's bound (Sec. VI.D, Fig. 11b);
* q3, q6, q9 (the other rotations): 1° too, ours: the paper states no limit for them;
* q1, q4, q7 (translations): 17.5 mm, ours (what 1° gives at the 1 m arm): the paper states none;
* q10 (the rigid-body angle): slew, within 0.5° of the command from 30 s after it (the paper's "within
  30 s", "final angle within 0.5°"); pulse, within 1° of its value at the pulse start (ours: the paper's
  "returned to the initial configuration" gives no number).

Checked from the slew command, or from 3 s after the pulse's end (the paper's "within 3 s"). After a
pulse, q2, q5, q8 also show the band of the report's "back within" measure (10 % of the open-loop
first peak, from the pulse start).

Each panel: the true value (simulator), the controller's estimate with its ±1σ band and the
reference it tracked (controller.csv), the open-loop run when given, and the limits.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cdgps_cli.control.metrics import (ARRIVED_WITHIN_DEG, BACK_FRACTION, PULSE_BACK_S, ROTATION_LIMIT_DEG,
                                      SLEW_DONE_S, TRANSLATION_LIMIT_MM, first_peak_deg)

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


#: where each limit comes from: (short, for a panel title; long, for the report's note)
SOURCE_PAPER_INTERNAL = ("paper, Sec. VI.D", "the paper's bound on the internal rotations (Sec. VI.D, Fig. 11b: "
                         "'within 1°')")
SOURCE_OURS_ROTATION = ("ours; the paper states none", "ours: the paper's 1° for the internal rotations applied "
                        "to this rotation, for which the paper states no limit")
SOURCE_OURS_TRANSLATION = ("ours; the paper states none", "ours: the displacement 1° gives at the 1 m arm; the "
                           "paper states no limit for the translations")
SOURCE_PAPER_SLEW = ("paper, Sec. VI.D", f"the paper's slew 'within {SLEW_DONE_S:g} s', 'final angle within "
                     f"{ARRIVED_WITHIN_DEG:g}°' (Sec. VI.D)")
SOURCE_OURS_PULSE_RIGID = ("ours; the paper states none", "ours: the paper says the structure 'returned to the "
                           "initial configuration within 3 s' (Sec. VI.C) with no number for the rigid-body angle; "
                           "1° as for the other rotations, about its value at the pulse start")


def _source(name: str, kind: str, scenario: str) -> tuple[str, str]:
    from cdgps_cli.report.control import INTERNAL_ANGLES, RIGID_ANGLE  # noqa: PLC0415

    if name == RIGID_ANGLE:
        return SOURCE_PAPER_SLEW if scenario == "slew" else SOURCE_OURS_PULSE_RIGID
    if kind == "translation":
        return SOURCE_OURS_TRANSLATION
    return SOURCE_PAPER_INTERNAL if name in INTERNAL_ANGLES else SOURCE_OURS_ROTATION


def checked_limits(scenario: str, seg: dict, kinds: dict, q) -> dict:
    """The limit each coordinate is checked against, and where it comes from.

    Parameters
    ----------
    scenario : str
        ``"pulse"`` or ``"slew"``.
    seg : dict
        The run's pulse or slew segment (truth.json): ``start_s``, ``end_s``, ``command_deg`` (slew).
    kinds : dict
        Coordinate name -> kind (truth.json ``coordinates``): ``"rotation"``, ``"translation"``, other.
    q : pandas.DataFrame
        The run's truth.csv with bare names (``time_s``, ``q1`` …), SI units.

    Returns
    -------
    dict
        Name -> None (a kind without a limit) or ``{"limit", "unit" ("deg" or "mm"), "centre" (rad or m),
        "from_s", "source", "source_short"}``: the coordinate must stay within ``limit`` of ``centre`` from
        ``from_s`` on.
    """
    from cdgps_cli.report.control import RIGID_ANGLE  # noqa: PLC0415

    after = seg["start_s"] if scenario == "slew" else seg["end_s"] + PULSE_BACK_S
    out = {}
    for n, kind in kinds.items():
        if n not in q.columns:
            continue
        if kind not in ("rotation", "translation"):
            out[n] = None
            continue
        limit, unit = (ROTATION_LIMIT_DEG, "deg") if kind == "rotation" else (TRANSLATION_LIMIT_MM, "mm")
        centre, from_s = 0.0, after
        if n == RIGID_ANGLE and scenario == "slew":
            limit, centre, from_s = ARRIVED_WITHIN_DEG, float(np.radians(seg["command_deg"])), seg["start_s"] + SLEW_DONE_S
        elif n == RIGID_ANGLE:
            t = q["time_s"].to_numpy()
            centre = float(np.interp(seg["start_s"], t, q[n].to_numpy()))
        short, long = _source(n, kind, scenario)
        out[n] = {"limit": float(limit), "unit": unit, "centre": centre, "from_s": float(from_s),
                  "source": long, "source_short": short}
    return out


def coordinate_limits(scenario: str, sims: dict, names: list, checked: dict) -> dict:
    """``{name: [(half_width, centre, from_s, text), …]}`` in the coordinate's own unit (rad or m): the
    checked limit (:func:`checked_limits`) and, after a pulse, the "back within" band of q2, q5, q8."""
    out = {n: [] for n in names}
    for n in names:
        c = checked.get(n)
        if c is not None:
            half = np.radians(c["limit"]) if c["unit"] == "deg" else c["limit"] / 1e3
            about = "" if c["centre"] == 0.0 else (" about the command" if scenario == "slew" else " about the pulse start")
            out[n].append((float(half), c["centre"], c["from_s"],
                           f"±{c['limit']:.3g}{'°' if c['unit'] == 'deg' else ' mm'}{about} from {c['from_s']:g} s "
                           f"({c['source_short']})"))
    if scenario == "pulse" and "open" in sims:
        seg = next(s for s in sims["closed"]["truth"]["segments"] if s["kind"] == "pulse")
        from cdgps_cli.report.control import INTERNAL_ANGLES  # noqa: PLC0415

        t = sims["open"]["q"]["time_s"].to_numpy()
        for n in (n for n in names if n in INTERNAL_ANGLES):
            peak = first_peak_deg(t, sims["open"]["q"][n].to_numpy(), seg["start_s"])     # (any unit: |x| max)
            if peak > 0:
                out[n].append((BACK_FRACTION * peak, 0.0, seg["start_s"],
                               f"±{100 * BACK_FRACTION:g} % of the open-loop first peak, from the pulse"))
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
    H = 1.1 + 1.7 * rows
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
        bands = limits.get(n) or []
        if not bands:
            ax.set_title(f"{n}: no limit (not a rotation or translation)", fontsize=8, loc="left")
        for k, (half, centre, t0, text) in enumerate(bands):
            lo, hi = f * (centre - half), f * (centre + half)
            colour, key = ("tab:red", "checked limit") if k == 0 else ("tab:purple", "'back within' band")
            ax.fill_between([t0, t[-1]], [lo, lo], [hi, hi], color=colour, alpha=0.10, lw=0)
            for v in (lo, hi):
                h, = ax.plot([t0, t[-1]], [v, v], color=colour, lw=0.8, ls="--" if k == 0 else ":")
            handles[key] = h
        if bands:
            ax.set_title(f"{n}: {bands[0][3]}", fontsize=7, loc="left")
        ax.set_ylabel(f"{n} [{u}]", fontsize=8)
        ax.tick_params(labelsize=7)
    for j in range(len(names), rows * 2):
        axes[j // 2][j % 2].axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"Every generalized coordinate, {label}, against the limit it is checked against", fontsize=10,
                 y=1 - 0.12 / H, va="top")
    fig.legend(list(handles.values()), list(handles), loc="upper center", ncol=min(len(handles), 4), fontsize=8,
               frameon=False, bbox_to_anchor=(0.5, 1 - 0.36 / H))
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.8 / H))
    return fig


def coordinates_caption(scenario: str, limits: dict, label: str) -> str:
    text = (f"Every generalized coordinate of the {label} run: true value (blue, simulator truth.csv), the "
            f"controller's estimate with its ±1σ band (orange, controller.csv) and the reference it tracked "
            f"(dotted), the open-loop run (grey) when given; angles in degrees, lengths in mm. "
            "Dashed red: the limit the 'Every coordinate' table checks, from when it applies; each panel's title "
            "gives it and whether it is the paper's or ours (the table's note gives the sources in full). ")
    if scenario == "pulse" and any(len(v) > 1 for v in limits.values()):
        text += (f"Dotted purple (q2, q5, q8): the band of the 'back within' measure, {100 * BACK_FRACTION:g} % of the "
                 "open-loop first peak, from the pulse. ")
    unlimited = [n for n, v in limits.items() if not v]
    if unlimited:
        text += f"No limit: {', '.join(unlimited)} (neither a rotation nor a translation)."
    return text.rstrip()
