"""`cdgps report control`: the 1998 paper's control experiments (Figs. 6, 10, 11, 12) as a report.

Reads the GAINS.json of the design and simulation folders written by ``cdgps simulate`` (open loop,
and with ``--controller``: closed loop on the GPS estimate, optionally with full-state feedback and
without vibration control), computes the figures of merit of :mod:`cdgps_cli.control.metrics` and
writes report.md, report.json and a self-contained report.html with the figures.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.control.metrics import (ARRIVED_WITHIN_DEG, BACK_FRACTION, PULSE_BACK_S, coordinate_checks,
                                      pulse_metrics, slew_metrics)
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.provenance import _file, report_date, software
from cdgps_cli.io.atomic import output_set
from cdgps_cli.io.gains_file import gain_sha256, read_gains
from cdgps_cli.io.sim_truth import read_truth_folder, require_columns
from cdgps_cli.report.sensor_reports import REPORT_FILES, _fmt, _html_table, _md_table, _mpl, _save_fig, _write_report

#: internal angles plotted and measured (Figs. 10–12): the longitudinal twists of this model
INTERNAL_ANGLES = ("q2", "q5", "q8")
#: the testbed's rotations about the vertical (Fig. 4; Sec. VI.A's centre-section vertical angle is q6 + q10):
#: Fig. 11b's text calls q2, q5, q8 "vertical axis rotations", so the slew figure shows both triples
VERTICAL_ANGLES = ("q3", "q6", "q9")
RIGID_ANGLE = "q10"
ROLES = ("open", "closed", "full_state", "no_vibration")
#: every file the report may write (replaced as one set, cdgps_cli.io.atomic.output_set)
CONTROL_REPORT_FILES = (*REPORT_FILES, "poles.png", "pulse.png", "slew.png", "coordinates.png")
ROLE_LABEL = {"open": "open loop", "closed": "closed loop (GPS estimate)",
              "full_state": "closed loop (true state)", "no_vibration": "no vibration control (GPS estimate)"}


_UNITS = ("rad", "m", "1")          # the unit suffixes of coordinate columns (cdgps_cli.io.coordinate_columns)


def _bare(table: pd.DataFrame, stems) -> pd.DataFrame:
    """``table`` with each column ``<stem>_<unit>`` (since issue 32) renamed to its bare ``<stem>``; a
    bare column of an older file is kept as it is (the suffixed one preferred when a file has both)."""
    renamed = {}
    for stem in stems:
        c = next((f"{stem}_{u}" for u in _UNITS if f"{stem}_{u}" in table.columns), None)
        if c is not None:
            renamed[c] = stem
    return table.drop(columns=[n for n in renamed.values() if n in table.columns]).rename(columns=renamed)


def _coordinate_stems(truth: dict) -> list[str]:
    """The coordinates of a simulation (truth.json's ``coordinates``; the plotted angles for older files)."""
    return list(truth.get("coordinates") or (RIGID_ANGLE, *INTERNAL_ANGLES))


def read_simulation(folder: str | Path, role: str) -> dict:
    """truth.json, truth.csv (:func:`~cdgps_cli.io.sim_truth.read_truth_folder`) and controller.csv
    (closed loop) of a ``cdgps simulate`` folder, checked complete and of the loop ``role`` wants."""
    option = f"--{role.replace('_', '-')}"
    sim = read_truth_folder(folder, option)
    d, truth = sim.folder, sim.info
    files = [sim.json_path, sim.csv_path]
    ctrl = None
    if (d / "controller.csv").exists():
        try:
            ctrl = pd.read_csv(d / "controller.csv")
        except ValueError as exc:
            raise CdgpsError(f"{d / 'controller.csv'}: not a readable CSV ({exc})") from None
        files.append(d / "controller.csv")
    if (role == "open") == ("controller" in truth):
        want = "an open-loop run (simulate without --controller)" if role == "open" else \
            "a closed-loop run (simulate with --controller)"
        raise CdgpsError(f"{option} {d}: expected {want}")
    stems = _coordinate_stems(truth)
    q = _bare(sim.table, stems)                          # q10_rad, or a bare q10 (files before issue 32)
    if ctrl is not None:                                 # q10_hat_rad, q10_hat_sigma_rad, q10_ref_rad …
        ctrl = _bare(ctrl, [f"{n}_{w}" for n in stems for w in ("hat", "hat_sigma", "ref")])
    require_columns(q, ("time_s", RIGID_ANGLE, *INTERNAL_ANGLES), sim.csv_path)
    _check_complete(sim.csv_path, q)
    if ctrl is not None:
        _check_complete(d / "controller.csv", ctrl)
        if len(ctrl) != len(q) or not np.array_equal(ctrl["time_s"].to_numpy(), q["time_s"].to_numpy()):
            raise CdgpsError(f"{d / 'controller.csv'}: {len(ctrl)} rows, truth.csv {len(q)}: expected the same epochs "
                             "(time_s) in both; is one of them cut short?")
    return {"folder": str(d), "truth": truth, "q": q, "controller": ctrl, "files": [str(f) for f in files]}


def _check_complete(path: Path, table: pd.DataFrame) -> None:
    """Every cell numeric and finite, time_s increasing: a file cut mid-row or emptied is refused by name
    (issue 32: a cut truth.csv ended in an IndexError)."""
    if "time_s" not in table.columns or len(table) == 0:
        raise CdgpsError(f"{path}: expected a time_s column and at least one row")
    values = table.apply(pd.to_numeric, errors="coerce").to_numpy(dtype=float)
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        cell = table.iat[row, col]
        got = "an empty cell" if pd.isna(cell) else repr(str(cell))
        raise CdgpsError(f"{path}: line {row + 2}, column {table.columns[col]!r}: expected a finite number, got "
                         f"{got} (is the file cut short?)")
    if not np.all(np.diff(values[:, list(table.columns).index("time_s")]) > 0):
        raise CdgpsError(f"{path}: time_s must increase from row to row")


def _scenario(runs: dict) -> str:
    kinds = {r["truth"]["scenario"] for r in runs.values()}
    if len(kinds) != 1:
        raise CdgpsError(f"the runs are of different scenarios: {', '.join(sorted(kinds))}")
    return kinds.pop()


def _deg(run: dict, name: str) -> np.ndarray:
    return np.degrees(run["q"][name].to_numpy())


def control_report(gains_path: str | Path, runs: dict, out_dir: str | Path, date: str | None = None) -> dict:
    """Write the report; ``runs`` maps a role (:data:`ROLES`) to a simulation folder."""
    if "closed" not in runs:
        raise CdgpsError("--closed: the closed-loop run (simulate --controller) is required")
    gains = read_gains(gains_path)
    sims = {role: read_simulation(folder, role) for role, folder in runs.items()}
    scenario = _scenario(sims)
    for role, s in sims.items():
        if s["truth"]["config_sha256"] != gains.get("config", {}).get("sha256"):
            raise CdgpsError(f"--{role.replace('_', '-')} {s['folder']}: simulated with another config than "
                             f"{gains_path} was designed for")
        used = s["truth"].get("controller", {}).get("gains_k_sha256")
        if role != "open" and used is not None and used != gain_sha256(gains["K"]):
            raise CdgpsError(f"--{role.replace('_', '-')} {s['folder']}: simulated with another gain K than the one in "
                             f"{gains_path} (truth.json controller.gains_k_sha256 {used[:12]}…); give the GAINS.json "
                             "that run used")
    if scenario == "pulse":
        data, rows, header, figures, captions = _pulse_section(sims)
    elif scenario == "slew":
        data, rows, header, figures, captions = _slew_section(sims)
    else:
        raise CdgpsError(f"the runs are of scenario {scenario!r}; the control report covers pulse and slew")
    from cdgps_cli.report import control_coordinates as cc

    names = [n for n in sims["closed"]["q"].columns if n != "time_s"]
    seg = data["slew"] if scenario == "slew" else data["pulse"]
    checked = cc.checked_limits(scenario, seg, sims["closed"]["truth"].get("coordinates") or {}, sims["closed"]["q"])
    limits = cc.coordinate_limits(scenario, sims, names, checked)
    figures[cc.COORDINATES_PNG] = cc.coordinates_figure(sims, "closed", limits, cc.coordinate_units(gains, names),
                                                        ROLE_LABEL["closed"])
    captions[cc.COORDINATES_PNG] = cc.coordinates_caption(scenario, limits, ROLE_LABEL["closed"])
    data["coordinate_limits"] = {n: [{"half_width": v[0], "centre": v[1], "from_s": v[2], "statement": v[3]}
                                     for v in bands] for n, bands in limits.items()}
    plt = _mpl()
    from cdgps_cli.report.control_figures import pole_figure

    captions["poles.png"] = ("Open-loop (×) and closed-loop (+) poles of the design in the z plane, with a zoom "
                             "near z = 1 (from GAINS.json).")
    inputs = [_file("GAINS.json", gains_path)]
    for role, s in sims.items():
        inputs += [_file(f"--{role.replace('_', '-')}", f) for f in s["files"]]
    when = report_date([i["path"] for i in inputs], date)
    data.update({"scenario": scenario, "provenance": {
        "command": "cdgps report control", "options": {"gains": str(gains_path), **{f"--{r.replace('_', '-')}": str(v)
                                                                                    for r, v in runs.items()},
                                                       "--date": date},
        "inputs": inputs, "software": software(), "date": when["date"], "date_source": when["source"]}})
    data["coordinates"], k_rows, k_header, k_note = _coordinate_section(sims, scenario, data)
    data["coordinate_limit_sources"] = {n: None if c is None else c["source"] for n, c in checked.items()}
    c_rows, c_header = _controller_rows(sims)
    data["controllers"] = {role: s["truth"]["controller"] for role, s in sims.items() if role != "open"}
    title = f"Control experiment: {scenario}"
    md = (f"# {title}\n\n{_md_table(rows, header)}\n\n{data['definitions']}\n\n"
          f"## Every coordinate\n\n{_md_table(k_rows, k_header)}\n\n{k_note}\n\n"
          f"## Controller\n\n{_md_table(c_rows, c_header)}\n")
    with output_set(out_dir, replaces=CONTROL_REPORT_FILES) as dest:
        pole_figure(gains["poles"], dest.path("poles.png"), "LQR poles (Fig. 6 style)")
        figures = {"poles.png": dest.path("poles.png").read_bytes(),
                   **{k: _save_fig(f, dest.path(k)) for k, f in figures.items()}}
        plt.close("all")
        _write_report(dest, title, md, data,
                      [("Result", _html_table(rows, header) + f"<p class='note'>{data['definitions']}</p>"),
                       ("Every coordinate", _html_table(k_rows, k_header) + f"<p class='note'>{k_note}</p>"),
                       ("Controller", _html_table(c_rows, c_header))],
                      figures, captions)
    return data


def _coordinate_section(sims, scenario: str, data: dict):
    """Every generalized coordinate, q10 included, per closed-loop run, against the limit
    :func:`cdgps_cli.report.control_coordinates.checked_limits` gives it (the value, where it comes from, from
    when it applies), with :func:`cdgps_cli.control.metrics.coordinate_checks`."""
    from cdgps_cli.report.control_coordinates import checked_limits  # noqa: PLC0415

    seg = data["slew"] if scenario == "slew" else data["pulse"]
    checks, lims = {}, {}
    for role, s in sims.items():
        kinds = s["truth"].get("coordinates")
        if role == "open" or not kinds:
            continue
        lims = checked_limits(scenario, seg, kinds, s["q"])
        t = s["q"]["time_s"].to_numpy()
        checks[role] = {}
        for n, c in lims.items():            # one call per coordinate: each has its own start and centre
            after = c["from_s"] if c else seg["start_s"]
            centre = c["centre"] if c else 0.0
            checks[role].update(coordinate_checks(t, {n: s["q"][n].to_numpy() - centre}, kinds, after,
                                                  {n: c["limit"]} if c else None))
    names = list(lims)
    header = ["run", *names, "all within"]
    rows = [["limit", *(_limit_cell(lims[n], scenario) for n in names), ""]]
    rows += [[ROLE_LABEL[role], *(_check_cell(c[k]) for k in names),
              "yes" if all(v["within"] is not False for v in c.values()) else "no"] for role, c in checks.items()]
    if not checks:
        return checks, [], header, "The simulations predate the per-coordinate kinds in truth.json: not checked."
    groups = {}
    for n, c in lims.items():
        if c is not None:
            groups.setdefault((c["source"], c["from_s"]), []).append(n)
    when = "the command" if scenario == "slew" else f"{PULSE_BACK_S:g} s after the pulse's end (the paper's 'within 3 s')"
    note = (f"Largest |value − centre| (truth) from {when} unless the limit row says otherwise; degrees for rotations, "
            "millimetres for translations; ✗: over its limit; —: the run ends before the check starts. Where each "
            "limit comes from: " + "; ".join(f"{', '.join(ns)}: {src}" for (src, _), ns in groups.items()) + ".")
    return checks, rows, header, note


def _limit_cell(c, scenario: str) -> str:
    if c is None:
        return "none"
    about = "" if c["centre"] == 0.0 else (f" of {np.degrees(c['centre']):+g}°" if scenario == "slew" else " of its start")
    return f"≤ {c['limit']:.3g}{'°' if c['unit'] == 'deg' else ' mm'}{about} from {c['from_s']:g} s"


def _check_cell(c: dict) -> str:
    if c["max_abs"] is None:
        return "—"
    return f"{c['max_abs']:.2f}" + (" ✗" if c["within"] is False else "")


def _controller_rows(sims):
    """One row per closed-loop run: what its truth.json says the controller was."""
    header = ["run", "weights", "feedback", "vibration control", "slew reference", "filter W scale (rule)",
              "multipath states", "saturated jet-periods", "NIS per dof"]
    rows = []
    for role, s in sims.items():
        c = s["truth"].get("controller")
        if role == "open" or c is None:
            continue
        scale = c.get("estimator_process_noise_scale")
        met = c.get("estimator_rule_met")
        rows.append([ROLE_LABEL[role], c.get("weight_set", "—"), c.get("feedback", "—"), "yes" if c.get("vibration_control", True) else "no",
                     c.get("slew_reference", "—"),
                     "—" if scale is None else f"{scale:.3g}" + ("" if met is None else (" (met)" if met else " (not met)")),
                     "yes" if c.get("estimator_multipath") else "no",
                     _fmt(c.get("saturated_fraction"), ".1%"), _fmt(c.get("estimator_nis_per_dof"), ".2f")])
    return rows, header


def _pulse_section(sims):
    if "open" not in sims:
        raise CdgpsError("--open: the pulse report compares with the open-loop run (simulate --scenario pulse)")
    seg = next(s for s in sims["closed"]["truth"]["segments"] if s["kind"] == "pulse")
    t = sims["closed"]["q"]["time_s"].to_numpy()
    opened = {k: _deg(sims["open"], k) for k in INTERNAL_ANGLES}
    metrics = {}
    for role in ("closed", "full_state"):
        if role in sims:
            metrics[role] = pulse_metrics(t, opened, {k: _deg(sims[role], k) for k in INTERNAL_ANGLES},
                                          seg["start_s"], seg["end_s"])
    rows = []
    for role, m in metrics.items():
        for k, v in m.items():
            rows.append([ROLE_LABEL[role], k, f"{v['open_first_peak_deg']:.2f}", f"{v['closed_peak_deg']:.2f}",
                         _fmt(v["peak_ratio"], ".3f"), _fmt(v["closed_back_within_s_after_pulse"], ".1f"),
                         f"{v['open_tail_peak_to_peak_deg']:.1f}"])
    header = ["feedback", "angle", "open-loop first peak (°)", "closed-loop peak (°)", "ratio",
              f"back within {100 * BACK_FRACTION:g}% of the open-loop peak (s after pulse)", "open-loop p-p, last 10 s (°)"]
    plt = _mpl()
    fig, axes = plt.subplots(1, 1 + len(metrics), figsize=(5 * (1 + len(metrics)), 3.8), sharey=True)
    for ax, role in zip(np.atleast_1d(axes), ["open", *metrics]):
        for k in INTERNAL_ANGLES:
            ax.plot(t, _deg(sims[role], k), lw=1, label=k)
        ax.axvspan(seg["start_s"], seg["end_s"], color="0.85", label="pulse")
        ax.set_title(ROLE_LABEL[role])
        ax.set_xlabel("time (s)")
    np.atleast_1d(axes)[0].set_ylabel("angle (deg)")
    np.atleast_1d(axes)[0].legend(fontsize=8)
    fig.tight_layout()
    caps = {"pulse.png": f"Longitudinal-twist angles q2, q5, q8 (true) after the zero-momentum pulse "
                         f"({', '.join(seg['thrusters'])}, {seg['force_n']:g} N, shaded), open and closed loop (Fig. 10)."}
    data = {"pulse": seg, "metrics": metrics,
            "definitions": "Open-loop first peak: the largest |angle| up to the first zero crossing after the pulse "
                           "starts; closed-loop peak: the largest |angle| after the pulse starts; back: from when the "
                           f"angle stays within {100 * BACK_FRACTION:g}% of its open-loop first peak to the end. "
                           "Angles are the simulator's truth."}
    return data, rows, header, {"pulse.png": fig}, caps


def _slew_section(sims):
    seg = next(s for s in sims["closed"]["truth"]["segments"] if s["kind"] == "slew")
    cmd, t0 = seg["command_deg"], seg["start_s"]
    metrics, rows = {}, []
    for role in ("closed", "full_state", "no_vibration"):
        if role not in sims:
            continue
        s = sims[role]
        m = slew_metrics(s["q"]["time_s"].to_numpy(), _deg(s, RIGID_ANGLE), {k: _deg(s, k) for k in INTERNAL_ANGLES}, cmd, t0)
        c = s["controller"]
        if c is not None and all(f"{k}_hat" in c.columns for k in (RIGID_ANGLE, *INTERNAL_ANGLES)):
            # the paper's Fig. 11 figures are "as measured by GPS": the same metrics on the estimate
            m["estimated"] = slew_metrics(c["time_s"].to_numpy(), np.degrees(c[f"{RIGID_ANGLE}_hat"].to_numpy()),
                                          {k: np.degrees(c[f"{k}_hat"].to_numpy()) for k in INTERNAL_ANGLES}, cmd, t0)
        metrics[role] = m
        e = m.get("estimated")
        rows.append([ROLE_LABEL[role], _fmt(m["arrived_s_after_command"], ".1f"), f"{m['final_error_deg']:+.3f}",
                     f"{m['final_peak_to_peak_deg']:.3f}", *(f"{m['internal_max_deg'][k]:.2f}" for k in INTERNAL_ANGLES),
                     "—" if e is None else _fmt(e["arrived_s_after_command"], ".1f"),
                     "—" if e is None else f"{max(e['internal_max_deg'].values()):.2f}"])
    header = ["run", f"within {ARRIVED_WITHIN_DEG:g}° of the command (s after it)", "final error (°)",
              "final p-p, last 10 s (°)", *(f"largest {k} (°, absolute)" for k in INTERNAL_ANGLES),
              f"as estimated: within {ARRIVED_WITHIN_DEG:g}° (s)", "as estimated: largest internal angle (°)"]
    plt = _mpl()
    shown = [r for r in ("closed", "no_vibration") if r in sims]
    vertical = [k for k in VERTICAL_ANGLES if k in sims["closed"]["q"].columns]
    fig, axes = plt.subplots(2 + bool(vertical), len(shown), figsize=(5.5 * len(shown), 6.5 + 3 * bool(vertical)),
                             squeeze=False, sharex=True)
    for j, role in enumerate(shown):
        s = sims[role]
        t = s["q"]["time_s"].to_numpy()
        ax = axes[0, j]
        ax.plot(t, _deg(s, RIGID_ANGLE), lw=1.2, label="q10 (true)")
        if s["controller"] is not None:
            c = s["controller"]
            ax.plot(c["time_s"], np.degrees(c["q10_hat"]), lw=0.8, ls="--", label="q10 (GPS estimate)")
            ax.plot(c["time_s"], np.degrees(c["q10_ref"]), lw=0.8, color="0.4", label="reference")
        ax.axhspan(cmd - ARRIVED_WITHIN_DEG, cmd + ARRIVED_WITHIN_DEG, color="0.9")
        ax.set_title(ROLE_LABEL[role])
        ax.set_ylabel("rigid-body angle (deg)")
        ax.legend(fontsize=8)
        for k in INTERNAL_ANGLES:
            axes[1, j].plot(t, _deg(s, k), lw=1, label=k)
        axes[1, j].set_ylabel("internal angles (deg)")
        axes[1, j].legend(fontsize=8)
        for k in vertical:
            axes[2, j].plot(t, _deg(s, k), lw=1, label=k)
        if vertical:
            axes[2, j].set_ylabel("vertical-axis rotations (deg)")
            axes[2, j].legend(fontsize=8)
        axes[-1, j].set_xlabel("time (s)")
    fig.tight_layout()
    caps = {"slew.png": f"Slew from {sims['closed']['truth']['segments'][0].get('rigid_angle_deg', 0):g}° to {cmd:g}° "
                        f"commanded at {t0:g} s: rigid-body angle (top; band ±{ARRIVED_WITHIN_DEG:g}° about the command) "
                        f"the internal angles {', '.join(INTERNAL_ANGLES)} (middle; Fig. 11b's labels) and the sections' "
                        f"rotations about the vertical {', '.join(vertical) or '(none)'} (bottom), with and without "
                        f"vibration control (Figs. 11–12)."}
    data = {"slew": seg, "metrics": metrics,
            "definitions": f"Within: from when the true rigid-body angle stays within {ARRIVED_WITHIN_DEG:g}° of the "
                           f"command to the end; final error and peak-to-peak over the last 10 s; internal maxima "
                           f"after the command. Angles are the simulator's truth; the 'as estimated' columns are the "
                           f"same measures on the estimate the controller used (controller.csv), the paper's "
                           f"'as measured by GPS'."}
    return data, rows, header, {"slew.png": fig}, caps
