"""`cdgps report rtk`: one self-contained HTML page for an RTK solution file (RTKLIB ``.pos``).

Reads a ``.pos`` file — written by ``cdgps rtk`` or by RTKLIB's ``rnx2rtkp``/``rtkpost`` (lat/lon/
height, ECEF or ENU-baseline form; :func:`cdgps_cli.io.solution_formats.read_pos`) — and draws the
rover's east/north/up displacement about its median fixed position with every epoch coloured by its
solution quality (fix, float, single), the ±1σ the file gives (ENU and lat/lon/height forms), the
satellites used and the ratio test, each as min/max envelopes per plot bin
(:mod:`cdgps_cli.report.envelope`).  Provenance first: the file's sha256 and the ``%`` header lines
in which the solver names its program, options and input files.  Written atomically: ``index.html``
and ``report.json``.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_time_str
from cdgps_cli.io.provenance import _file, provenance_rows, report_date, software
from cdgps_cli.io.solution_formats import Q_FIX, Q_FLOAT, Q_SINGLE, read_pos
from cdgps_cli.report.envelope import DEFAULT_BINS, EnvelopeBins, envelope_line
from cdgps_cli.report.run_report import _Page
from cdgps_cli.report.sensor_reports import _html_table, _mpl

QUALITY = {Q_FIX: ("fix", "tab:green"), Q_FLOAT: ("float", "tab:orange"), Q_SINGLE: ("single", "tab:red")}
#: epochs of any other quality flag (RTKLIB: 3 SBAS, 4 DGPS, 6 PPP), drawn as one class
OTHER_QUALITY = ("other", "tab:gray")


def quality_classes(q: np.ndarray) -> list:
    """[(label, colour, mask (n,))] of the quality classes present in ``q``: fix, float, single, then
    every other flag together (so that each epoch is drawn)."""
    out = [(label, colour, q == k) for k, (label, colour) in QUALITY.items()]
    out.append((*OTHER_QUALITY, ~np.isin(q, list(QUALITY))))
    return [c for c in out if c[2].any()]


def pos_enu(sol: dict) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """East, north, up (n, 3) in m about the median position of the fixed epochs (of all epochs when
    none is fixed), their 1-σ (n, 3) or None (an ECEF file's σ are not along E/N/U), and the
    reference point's ECEF position (m)."""
    from cdgps_cli.model.gps.orbits import ecef_to_enu, geodetic_to_ecef  # noqa: PLC0415

    c, frame = sol["coords"], sol["frame"]
    use = sol["q"] == Q_FIX if np.any(sol["q"] == Q_FIX) else np.ones(len(c), bool)
    if frame == "enu":
        ref = np.median(c[use], axis=0)
        return c - ref, sol["sd"][:, :3], ref
    xyz = geodetic_to_ecef(np.radians(c[:, 0]), np.radians(c[:, 1]), c[:, 2]) if frame == "llh" else c
    ref = np.median(xyz[use], axis=0)
    enu = ecef_to_enu(xyz, ref)
    sd = sol["sd"][:, [1, 0, 2]] if frame == "llh" else None          # (sdn, sde, sdu) → E, N, U
    return enu, sd, ref


def _reference_text(ref, frame: str) -> str:
    """The reference point of :func:`pos_enu` as the caption says it: ECEF metres, or, for a file of east / north /
    up baselines (``--pos-frame enu``), those from the base."""
    if frame == "enu":
        return f"east {ref[0]:.3f}, north {ref[1]:.3f}, up {ref[2]:.3f} m from the base"
    return f"ECEF {ref[0]:.3f}, {ref[1]:.3f}, {ref[2]:.3f} m"


def _in_time_order(sol: dict) -> tuple[dict, bool]:
    """``sol`` (:func:`~cdgps_cli.io.solution_formats.read_pos`) with its epochs in time order, and whether the file
    gave them in decreasing order (RTKLIB writes a backward solution, ``pos1-soltype=backward``, from its last epoch)."""
    t = np.asarray(sol["time_gps_s"])
    if t.size < 2 or not np.all(np.diff(t) < 0):
        return sol, False
    return {k: (v[::-1] if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == t.size else v)
            for k, v in sol.items()}, True


def rtk_report(pos_path: str | Path, out_dir: str | Path, date: str | None = None, n_bins: int = DEFAULT_BINS) -> dict:
    """Write ``index.html`` and ``report.json`` for the solution file ``pos_path``; returns the summary."""
    sol = read_pos(pos_path)
    n = len(sol["time_gps_s"])
    if n == 0:
        raise CdgpsError(f"{pos_path}: no solution epochs (only header lines)")
    sol, descending = _in_time_order(sol)
    t = sol["time_gps_s"]
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise CdgpsError(f"{pos_path}: epoch {k + 2} is not after epoch {k + 1} (times must increase, or all "
                         f"decrease as in RTKLIB's backward solution)")
    when = report_date([pos_path], date)
    prov = {"command": "cdgps report rtk", "options": {"--date": date}, "inputs": [_file("solution (.pos)", pos_path)],
            "software": software(), "date": when["date"], "date_source": when["source"]}
    enu, sd, ref = pos_enu(sol)
    summary = _summary(sol, enu)
    if descending:
        summary["file_epoch_order"] = "descending (RTKLIB's backward solution), read in time order"
    page = _Page()
    rows = provenance_rows(prov) + [["solution header", "\n".join(sol["header"])]]
    page.section("provenance", "What was run (provenance)", "<table class='prov'><tr><th>what</th><th>value</th></tr>"
                 + "".join(f"<tr><td>{_esc(k)}</td><td style='white-space:pre-wrap'>{_esc(v)}</td></tr>" for k, v in rows)
                 + "</table>")
    page.section("summary", "Summary", _html_table(_summary_rows(summary), ["quantity", "value"])
                 .replace("<table>", "<table class='kv'>", 1))
    src = (f"{Path(pos_path).name}: every epoch ({n}"
           + ("; the file lists them from the last, as RTKLIB writes a backward solution" if descending else "")
           + f"), drawn as the minimum and maximum of each of "
           f"{min(n_bins, n)} bins per quality class.")
    page.section("enu", "Displacement, satellites and ratio")
    colours = "green fix, orange float, red single" + ("" if np.isin(sol["q"], list(QUALITY)).all()
                                                        else ", dark grey any other flag")
    band = ", with the ±1σ the file gives (grey)." if sd is not None else "."
    page.figure("enu", enu_figure(t, enu, sd, sol["q"], n_bins),
                "East, north and up displacement of the rover about the median position of its fixed epochs "
                f"({_reference_text(ref, sol['frame'])}), mm, each epoch coloured by its solution "
                f"quality ({colours}){band}", src)
    page.figure("quality", quality_figure(t, sol["ns"], sol["ratio"], sol["q"], n_bins, ratio_threshold(sol["header"])),
                "Satellites used and the ratio test of the integer fix (log scale; an epoch without one is left out).",
                src)
    data = {"provenance": prov, "summary": summary, "captions": dict(page.captions)}
    title = f"RTK solution report: {Path(pos_path).name}"
    sub = (f"{n} epochs over {t[-1] - t[0]:g} s from {gps_time_str(t[0])} (GPS time {t[0]:.1f} s); {sol['frame']} "
           f"solution file; "
           f"report date {prov['date']}.")
    page.write(out_dir, title, sub, data)
    return data


def _esc(v) -> str:
    return html.escape(str(v))


def _summary(sol: dict, enu: np.ndarray) -> dict:
    q, n = sol["q"], len(sol["q"])
    out = {"epochs": n, "duration_s": float(sol["time_gps_s"][-1] - sol["time_gps_s"][0]),
           "fraction": {QUALITY.get(k, (str(k),))[0]: float(np.mean(q == k)) for k in sorted(set(q.tolist()))},
           "satellites_median": float(np.median(sol["ns"]))}
    fixed = q == Q_FIX
    if fixed.any():
        out["fixed_scatter_mm"] = dict(zip("enu", (1e3 * np.std(enu[fixed], axis=0)).tolist()))
        r = sol["ratio"][fixed]
        out["ratio_median_fixed"] = float(np.median(r[np.isfinite(r)])) if np.isfinite(r).any() else None
    return out


def _summary_rows(s: dict) -> list:
    rows = [["epochs", f"{s['epochs']} over {s['duration_s']:g} s"],
            ["solution quality", ", ".join(f"{k} {100 * v:.1f} %" for k, v in s["fraction"].items())],
            ["satellites (median)", f"{s['satellites_median']:g}"]]
    if "fixed_scatter_mm" in s:
        e = s["fixed_scatter_mm"]
        rows.append(["scatter of the fixed epochs (1σ) E / N / U", f"{e['e']:.1f} / {e['n']:.1f} / {e['u']:.1f} mm"])
    if s.get("ratio_median_fixed") is not None:
        rows.append(["ratio test, median over the fixed epochs", f"{s['ratio_median_fixed']:.3g}"])
    return rows


def _envelope(t: np.ndarray, v: np.ndarray, n_bins: int) -> EnvelopeBins:
    env = EnvelopeBins(len(t), v.shape[1], n_bins)
    env.add(0, t, v)
    return env


def _rel_time(t: np.ndarray) -> tuple[np.ndarray, str]:
    from cdgps_cli.report.run_figures import _time_axis  # noqa: PLC0415

    return _time_axis(t)


def enu_figure(t, enu, sd, q, n_bins: int):
    """E, N, U (mm) against time, coloured by solution quality, with the ±1σ band (grey) when known."""
    plt = _mpl()
    H = 0.9 + 3 * 1.7
    fig, axes = plt.subplots(3, 1, figsize=(10.0, H), sharex=True)
    handles = {}
    for i, (ax, name) in enumerate(zip(axes, ("east", "north", "up"))):
        if sd is not None:
            band_env = EnvelopeBins(len(t), 1, n_bins)
            band_env.add(0, t, 1e3 * enu[:, i:i + 1], 1e3 * (enu[:, i:i + 1] - sd[:, i:i + 1]),
                         1e3 * (enu[:, i:i + 1] + sd[:, i:i + 1]))
            x, _ = _rel_time(band_env.centre_s())
            handles["±1σ (file)"] = ax.fill_between(x, band_env.band_lo[:, 0], band_env.band_hi[:, 0], color="0.8", lw=0)
        for label, colour, sel in quality_classes(q):
            v = np.where(sel, 1e3 * enu[:, i], np.nan)[:, None]
            env = _envelope(t, v, n_bins)
            x, xlabel = _rel_time(env.centre_s())
            xs, ys = envelope_line(x, env.lo[:, 0], env.hi[:, 0])
            handles[label], = ax.plot(xs, ys, ".-", color=colour, lw=0.6, ms=2.0)
        ax.set_ylabel(f"{name} [mm]")
    axes[-1].set_xlabel(xlabel)
    fig.suptitle("Rover displacement about its median fixed position, by solution quality", fontsize=10,
                 y=1 - 0.12 / H, va="top")
    fig.legend(list(handles.values()), list(handles), loc="upper center", ncol=len(handles), fontsize=8,
               frameon=False, bbox_to_anchor=(0.5, 1 - 0.36 / H))
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.6 / H))
    return fig


def ratio_threshold(header: list) -> float | None:
    """The ratio-test threshold a solver names in its header (``cdgps rtk``: ``ratio 3``; RTKLIB:
    ``% ar ratio  : 3.0`` style lines are not standard, so only the first form is read), or None."""
    import re  # noqa: PLC0415

    for line in header:
        m = re.search(r"\bratio\s+([0-9.]+)\b", line)
        if m and line.startswith("% program"):
            return float(m.group(1))
    return None


def quality_figure(t, ns, ratio, q, n_bins: int, threshold: float | None = None):
    """Satellites used (min–max per bin) and the ratio test (log scale, with the header's threshold)
    against time."""
    plt = _mpl()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10.0, 4.6), sharex=True)
    env = _envelope(t, np.asarray(ns, dtype=float)[:, None], n_bins)
    x, xlabel = _rel_time(env.centre_s())
    xs, ys = envelope_line(x, env.lo[:, 0], env.hi[:, 0])
    a1.plot(xs, ys, color="tab:blue", lw=0.8)
    a1.set_ylabel("satellites [1]")
    from matplotlib.ticker import MaxNLocator  # noqa: PLC0415

    a1.yaxis.set_major_locator(MaxNLocator(integer=True))
    lo, hi = np.nanmin(ns), np.nanmax(ns)
    a1.set_ylim(lo - 0.6, hi + 0.6)
    r = np.where(np.isfinite(ratio) & (ratio > 0), ratio, np.nan)[:, None]
    env = _envelope(t, r, n_bins)
    xs, ys = envelope_line(x, env.lo[:, 0], env.hi[:, 0])
    a2.plot(xs, ys, color="tab:purple", lw=0.8)
    a2.set_yscale("log")
    if threshold is not None:
        a2.axhline(threshold, color="tab:red", ls="--", lw=0.9, label=f"threshold {threshold:g} (header)")
        a2.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize=8, frameon=False)
    a2.set_ylabel("ratio test [1]")
    a2.set_xlabel(xlabel)
    fig.tight_layout()
    return fig
