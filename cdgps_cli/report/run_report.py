"""`cdgps report run`: one self-contained HTML page for one estimated run (issue 33 item 1).

What was run first (provenance: software, config digest, the commands and options that made each
input, the files' sha256), then a summary table, then the figures: the section angles and every
generalized coordinate (or GNSS displacement) with its ±1σ band, NIS over time against its χ²
bounds, NEES when the simulator's truth is given, the residuals per channel, the PSDs vs the gyros
with the identified modes and damping, the MAC matrix of the identified shapes against the config's
and the mode shapes drawn on the structure, and, with ``--angle``, the static-survey statistics.

The record is read a block of epochs at a time (:mod:`cdgps_cli.report.run_scan`), and every time
series is drawn from its min/max envelope per plot bin (:mod:`cdgps_cli.report.envelope`), so a
day-long record's page is as small and as fast as a minute's.  Written atomically as one output
set: ``index.html`` (figures embedded as base64 PNG; no script, no network) and ``report.json``.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import numpy as np

from cdgps_cli.config.options import STATES_CHUNK_EPOCHS
from cdgps_cli.core.gps_time import gps_time_str
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.atomic import output_set, write_bytes_atomic
from cdgps_cli.io.provenance import provenance_rows, report_provenance, value_text
from cdgps_cli.io.states import INIT_WINDOWS_ATTACHMENT
from cdgps_cli.report import run_figures as figs
from cdgps_cli.report.envelope import DEFAULT_BINS
from cdgps_cli.report.mac import mac_matrix
from cdgps_cli.report.run_data import KINEMATIC_TOPIC, StatesBlocks
from cdgps_cli.report.run_scan import CHI2_LOWER, CHI2_UPPER, read_truth, scan_series, scan_states
from cdgps_cli.report.sensor_reports import (_CSS, _fmt, _html_table, _json_clean, _mpl, _png, check_gyro_run, plot_fdd,
                                             plot_psd, plot_static, spectra_result, static_statistics)

RUN_REPORT_FILES = ("index.html", "report.json")

_PAGE_CSS = _CSS + """
nav.toc{background:#f7f7f7;border:1px solid #ddd;padding:0.6em 1.2em;margin:1em 0}nav.toc ol{margin:0.3em 0}
figcaption .src{color:#555;font-size:0.95em}h2{border-bottom:1px solid #ddd;padding-bottom:0.2em;margin-top:1.8em}
table.kv td,table.kv th{text-align:left}
@media print{nav.toc{display:none}figure{break-inside:avoid}body{max-width:none}}"""


class _Page:
    """Sections, each with its HTML and figures, numbered as they are added."""

    def __init__(self):
        self.sections, self.figures, self.captions = [], {}, {}

    def section(self, key: str, title: str, body: str = "") -> None:
        self.sections.append([key, title, body])

    def text(self, body: str) -> None:
        self.sections[-1][2] += body

    def figure(self, name: str, fig, caption: str, source: str) -> None:
        plt = _mpl()
        data = _png(fig)
        plt.close(fig)
        n = len(self.figures) + 1
        self.figures[name] = data
        self.captions[name] = f"{caption} Source: {source}"
        b64 = base64.b64encode(data).decode()
        self.text(f"<figure id='fig-{html.escape(name)}'><img alt='Figure {n}: {html.escape(name)}' "
                  f"src='data:image/png;base64,{b64}'><figcaption><b>Figure {n}.</b> {html.escape(caption)} "
                  f"<span class='src'>Source: {html.escape(source)}</span></figcaption></figure>")

    def html(self, title: str, subtitle: str) -> str:
        toc = "".join(f"<li><a href='#{k}'>{html.escape(t)}</a></li>" for k, t, _ in self.sections)
        body = "".join(f"<section id='{k}'><h2>{html.escape(t)}</h2>{b}</section>" for k, t, b in self.sections)
        return (f"<!doctype html><html lang='en'><head><meta charset='utf-8'>"
                f"<meta name='viewport' content='width=device-width, initial-scale=1'>"
                f"<title>{html.escape(title)}</title><style>{_PAGE_CSS}</style></head><body>"
                f"<h1>{html.escape(title)}</h1><p>{html.escape(subtitle)}</p>"
                f"<nav class='toc'><b>Contents</b><ol>{toc}</ol></nav>{body}</body></html>\n")

    def write(self, out_dir, title: str, subtitle: str, data: dict) -> None:
        """``index.html`` (this page) and ``report.json`` (``data``) into ``out_dir``, as one output set."""
        with output_set(out_dir, replaces=RUN_REPORT_FILES) as dest:
            write_bytes_atomic(dest.path("index.html"), self.html(title, subtitle).encode())
            write_bytes_atomic(dest.path("report.json"), (json.dumps(_json_clean(data), indent=2) + "\n").encode())


def _display_unit(unit: str) -> tuple[str, float]:
    """The unit a coordinate is plotted in and the factor from its own: rad → deg, m → mm."""
    return {"rad": ("deg", float(np.degrees(1.0))), "m": ("mm", 1e3)}.get(unit, (unit, 1.0))


def run_report(states, out_dir: str | Path, run=None, truth_dir: str | Path | None = None,
               spectra_opt=None, angle: str | None = None, survey_deg: float | None = None,
               date: str | None = None, n_bins: int = DEFAULT_BINS,
               chunk_epochs: int = STATES_CHUNK_EPOCHS, spectra: bool = True) -> dict:
    """Write ``index.html`` and ``report.json`` for the estimate ``states``.

    Parameters
    ----------
    states : :class:`~cdgps_cli.report.run_data.StatesBlocks`
    out_dir : output directory (the two files replace an earlier set as a whole)
    run : :class:`~cdgps_cli.io.run.Run` or None — the gyro log (``--gyro``)
    truth_dir : `cdgps simulate` folder or None — NEES and errors (``--truth``)
    spectra_opt : :class:`~cdgps_cli.analysis.spectra.SpectraOptions` or None (defaults)
    angle : str or None — angle expression of the static-survey section (``--angle``), e.g. ``q6+q10``
    survey_deg : float or None — its surveyed value, degrees
    date : str or None — ``--date`` (:mod:`cdgps_cli.io.provenance`)
    spectra : bool — False: no spectra, modes, MAC or mode shapes (``--no-spectra``)
    n_bins : int — envelope bins across a figure
    chunk_epochs : int — epochs read at a time

    Returns
    -------
    dict — what report.json holds (summary, statistics, modes, provenance, captions).
    """
    from cdgps_cli.analysis.spectra import SpectraOptions  # noqa: PLC0415

    check_gyro_run(states, run)
    if angle is not None and states.cfg is None:
        raise CdgpsError(f"--angle: {states.path} holds {states.kind} states ({', '.join(states.coord_names)}); "
                         "the static-survey section needs a structure's STATES.mcap")
    opt = spectra_opt or SpectraOptions()
    if spectra and states.cfg is not None and opt.coords:
        bad = [c for c in opt.coords if c not in states.coord_names]
        if bad:                                     # an option error, not a record the spectra cannot use
            raise CdgpsError(f"--coords: unknown coordinate(s) {', '.join(bad)} (known: {', '.join(states.coord_names)})")
    if spectra and not 0 <= opt.overlap < 1:        # was a "No spectra" note on a page that exits 0 (fault campaign)
        raise CdgpsError(f"--overlap {opt.overlap:g}: expected a fraction of a segment in [0, 1)")
    options = {"--gyro": None if run is None else run.path, "--truth": None if truth_dir is None else str(truth_dir),
               "--angle": angle, "--survey-deg": survey_deg, "--no-spectra": None if spectra else True,
               "--date": date, **opt.command_line()}
    prov = report_provenance("cdgps report run", options, states, run, date)
    prov["settings"] = opt.settings()
    truth = None if truth_dir is None else read_truth(truth_dir, states)
    static = None
    if angle is not None:                           # first: a bad expression fails before the long pass
        from cdgps_cli.io.states import States  # noqa: PLC0415

        static = static_statistics(States(states.path, diagnostics=False), run, angle, survey_deg)
    scan = scan_states(states, truth, n_bins, chunk_epochs)
    spectra = _spectra(states, run, opt, chunk_epochs) if spectra else None
    page = _Page()
    data = {"provenance": prov}
    _provenance_section(page, prov, states, run)
    _summary_section(page, data, states, scan, spectra, static)
    _time_sections(page, states, scan, chunk_epochs)
    _consistency_section(page, states, scan)
    _residual_section(page, states, scan)
    if spectra is not None:
        _spectra_sections(page, data, states, spectra)
    if static is not None:
        _static_section(page, data, static, survey_deg, angle, run)
    data["captions"] = dict(page.captions)
    title = f"Run report: {Path(states.path).name} ({states.config_name})"
    sub = (f"{scan.n_epochs} epochs, {_span_text(scan)}, sampled every {scan.period_s:g} s; "
           f"{states.kind} states; report date {prov['date']}.")
    page.write(out_dir, title, sub, data)
    return data


def _span_text(scan) -> str:
    """The record's span: run seconds, or on the GPS time scale (≥ 10⁶ s) its start and duration."""
    if scan.start_s >= 1e6:
        return f"{scan.end_s - scan.start_s:g} s from {gps_time_str(scan.start_s)} (GPS time {scan.start_s:.1f} s)"
    return f"{scan.start_s:g}–{scan.end_s:g} s"


def _spectra(states, run, opt, chunk_epochs):
    """Spectra of a structure's states (None for GNSS displacements or a record too short for them:
    the reason is then in ``error``).  A ``--segment-s`` the user gave that the record cannot take is
    an option error (exit 2), not a note: only the default segment falls back to the note."""
    if states.cfg is None:
        return None
    try:
        res, gnames = spectra_result(states, run, opt, chunk_epochs)
    except CdgpsError as exc:
        if ("gyro" in str(exc) and "config" in str(exc)) or opt.segment_s is not None:
            raise
        return {"error": str(exc)}
    return {"res": res, "gyros": gnames}


# ----------------------------------------------------------------------------- sections

def _stage_rows(states, run) -> list[list[str]]:
    """What made each input, as recorded in the inputs themselves."""
    meta = states.metadata
    rows = []
    if run is not None:
        rm = dict(getattr(run, "metadata", {}) or {})
        files = ", ".join(f"{k}={v}" for k, v in sorted(rm.items())
                          if not k.endswith("sha256") and k not in ("created_by", "cdgps_version"))
        rows.append(["RUN.mcap", f"{rm.get('created_by', 'cdgps ingest')} (cdgps {rm.get('cdgps_version', '?')}): {files}"])
    init = states.init or {}
    if init:
        io = init.get("options", {})
        made = [f"cdgps init on {Path(str(init.get('run', '?'))).name}, {_init_window_text(init.get('window'))}",
                _init_fixing_text(init)]
        windows = _init_windows(meta)
        rows.append(["INIT.json of the first window (attached to the STATES)" if windows else
                     "INIT.json (attached to the STATES)",
                     "; ".join(x for x in made if x) + "; options: "
                     + "; ".join(f"{k} = {v}" for k, v in sorted(io.items())
                                 if v is not None and not isinstance(v, (dict, list)))])
        if windows:
            rows.append([f"the {len(windows)} windows' INITs ({INIT_WINDOWS_ATTACHMENT} attached)",
                         "; ".join(f"{k + 1}. {Path(str(w.get('init', '?'))).name}, "
                                   f"{_init_window_text(w.get('window'))}, sha256 {str(w.get('init_sha256', '?'))[:12]}…"
                                   for k, w in enumerate(windows))])
    try:
        eo = json.loads(meta.get("options", "{}"))
    except ValueError:
        eo = {}
    rows.append(["STATES.mcap", f"{meta.get('created_by', 'cdgps estimate')} (cdgps {meta.get('cdgps_version', '?')}) "
                 f"on {meta.get('run', '?')}, smoothed {meta.get('smoothed', '?')}, covariance "
                 f"{meta.get('covariance', '?')}; options: "
                 + "; ".join(f"{k} = {value_text(v)}" for k, v in sorted(eo.items()) if v is not None)])
    return rows


def _init_windows(meta: dict) -> list:
    """The INITs of a STATES made from several (``init_windows`` metadata: each one's file, window, sha256), else []."""
    try:
        got = json.loads(meta.get("init_windows") or "[]")
    except ValueError:
        return []
    return [w for w in got if isinstance(w, dict)] if isinstance(got, list) else []


def _init_window_text(w) -> str:
    """INIT's window as the provenance table says it: a structure INIT's ``start_s``–``end_s``, a GNSS INIT's
    ``start_s`` and ``duration_s`` (seconds from the record's first epoch), or the whole record (none)."""
    def num(x) -> str:                  # seconds to the microsecond, without an exponent or float noise
        return np.format_float_positional(round(float(x), 6), trim="-")
    if not isinstance(w, dict) or not w:
        return "the whole record"
    if w.get("end_s") is not None:
        return f"window {num(w.get('start_s', 0))}–{num(w['end_s'])} s"
    dur = w.get("duration_s")
    return f"window from {num(w.get('start_s', 0))} s" + (f" for {num(dur)} s" if dur is not None else " to the end")


def _init_fixing_text(init: dict) -> str:
    """What INIT fixed: a structure INIT's ``integer_fixing``, a GNSS INIT's integers per rover."""
    if init.get("integer_fixing"):
        return str(init["integer_fixing"])
    rovers = init.get("rovers") if isinstance(init.get("rovers"), dict) else {}
    return ", ".join(f"{r}: {v.get('n_fixed', '?')} of {v.get('n_estimated', '?')} integers fixed"
                     for r, v in rovers.items() if isinstance(v, dict))


def _provenance_section(page: _Page, prov: dict, states, run) -> None:
    rows = provenance_rows(prov)
    table = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in rows)
    stages = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in _stage_rows(states, run))
    page.section("provenance", "What was run (provenance)",
                 f"<table class='prov'><tr><th>what</th><th>value</th></tr>{table}</table>"
                 f"<p class='note'>How each input was made, as recorded in its own metadata:</p>"
                 f"<table class='prov'><tr><th>input</th><th>made by</th></tr>{stages}</table>")


def _nis_side_text(nis_per_dof: float, lo: float, multipath_states: bool = False) -> str:
    """What a pooled NIS outside its bound says of the σ: below it, the measurement model's variances exceed the
    data's scatter (the σ are conservative: a geodetic receiver under the default 3 mm + 3 mm / sin el weights);
    above it, the model misses something (noise, motion, a wrong integer) and the σ are too small."""
    if nis_per_dof < lo:
        return (f"; below it: the observations scatter less than their weights say (about {1 / np.sqrt(nis_per_dof):.1f}"
                f"× less in σ; the weights: the INIT's options sigma_a_m, sigma_b_m, or [gnss.displacement] phase_noise "
                f"= \"auto\"). That says nothing of errors correlated over minutes (multipath), which the NIS of each "
                f"epoch cannot see: a static solution's σ from a long record, and a random walk's on a low-cost "
                f"receiver, can be several times too small all the same"
                + ("; here the states carry multipath states (the row below), which model them" if multipath_states
                   else ""))
    return "; above it: the model or its noise misses something in these data, and the σ shown are too small"


def _rover_summaries(states) -> dict:
    """A GNSS STATES' rover summaries (``rovers`` metadata), the entries that are tables; {} elsewhere."""
    try:
        rovers = json.loads(states.metadata.get("rovers") or "{}")
    except (ValueError, TypeError):
        return {}
    return {k: v for k, v in rovers.items() if isinstance(v, dict)} if isinstance(rovers, dict) else {}


def _has_multipath_states(states) -> bool:
    """Whether some rover's states (or some window's) carried multipath states."""
    for r in _rover_summaries(states).values():
        found = [r.get("multipath")] + [w.get("multipath") for w in r.get("windows") or [] if isinstance(w, dict)]
        if any(isinstance(m, dict) and "sigma_m" in m for m in found):
            return True
    return False


def _multipath_text(states) -> str:
    """Each rover's Gauss–Markov phase multipath states as the STATES' rover summary records them (``multipath``:
    pipeline/gnss_multipath.py), or "" when no rover has the key (``multipath = "off"``)."""
    parts = []
    for name, r in sorted(_rover_summaries(states).items()):
        wins = [w.get("multipath") for w in r.get("windows") or [] if isinstance(w, dict)]
        if any(isinstance(m, dict) and "sigma_m" in m for m in wins):
            on = [m for m in wins if isinstance(m, dict) and "sigma_m" in m]
            parts.append(f"{name}: {on[0].get('mode', '?')}, in {len(on)} of its {len(wins)} windows, each its own: σ "
                         f"{1e3 * min(m['sigma_m'] for m in on):.2f} … {1e3 * max(m['sigma_m'] for m in on):.2f} mm, "
                         f"τ {min(m['time_constant_s'] for m in on):.3g} … {max(m['time_constant_s'] for m in on):.3g} s")
            continue
        mp = r.get("multipath")
        if not isinstance(mp, dict):
            continue
        if "sigma_m" not in mp:
            parts.append(f"{name}: {mp.get('mode', '?')}, none ({mp.get('why', '?')}; the phase errors taken as white)")
            continue
        how = (f", {100 * mp['correlated_share']:.0f} % of the single-epoch DD residuals' variance correlated, the white "
               f"variances × {mp['white_factor']:.3g}" if "correlated_share" in mp else ", given")
        parts.append(f"{name}: {mp.get('mode', '?')}, one Gauss-Markov state per satellite and signal, σ "
                     f"{1e3 * mp['sigma_m']:.2f} mm, τ {mp['time_constant_s']:.3g} s{how}")
    return "; ".join(parts)


def _summary_section(page: _Page, data: dict, states, scan, spectra, static) -> None:
    rows = [["epochs", f"{scan.n_epochs} ({_span_text(scan)}, every {scan.period_s:g} s)"],
            ["config", f"{states.config_name} (sha256 {str(states.config_sha256)[:16]}…)"]]
    ns = scan.nis_stats
    summary = {"epochs": scan.n_epochs, "start_s": scan.start_s, "end_s": scan.end_s, "period_s": scan.period_s,
               "nis": ns, "nees": scan.nees_stats or None}
    if ns.get("epochs"):
        lo, hi = ns["pooled_interval95_if_independent"]
        ok = lo <= ns["pooled_per_dof"] <= hi
        rows.append(["NIS per dof (pooled) vs its 95 % bound", f"{ns['pooled_per_dof']:.3f} in [{lo:.3f}, {hi:.3f}]: "
                     + ("consistent" if ok else f"outside (the bound pools {ns['epochs']} epochs as if independent)"
                        + _nis_side_text(ns["pooled_per_dof"], lo, _has_multipath_states(states)))])
        rows.append(["epochs with NIS inside its 95 % χ² interval", f"{100 * ns['fraction_in_interval95']:.1f} % "
                     f"(expected 95 %) of {ns['epochs']}"])
    if scan.nees_stats:
        ne = scan.nees_stats
        lo, hi = ne["interval95_single"]
        rows.append([f"NEES mean (dof {ne['dof']}) vs the 95 % interval of one epoch",
                     f"{ne['mean']:.2f} in [{lo:.2f}, {hi:.2f}]; {100 * ne['fraction_in_interval95']:.1f} % of "
                     f"{ne['epochs']} epochs inside"])
    mp = _multipath_text(states)
    if mp:
        rows.append(["phase multipath states ([gnss.displacement] multipath)", mp])
    init = states.init or {}
    if "n_fixed" in init:
        total = init.get("n_estimated") or len(init.get("biases", []))
        rows.append(["integers fixed (INIT)", f"{init['n_fixed']}" + (f" of {total}" if total else "")
                     + (f", ratio {init['ratio']:.3g}" if isinstance(init.get("ratio"), (int, float)) else "")])
        summary["integers_fixed"] = init["n_fixed"]
    if scan.resid_sums is not None:
        rms = scan.resid_sums.rms()
        if np.isfinite(rms).any():
            w = int(np.nanargmax(rms))
            all_rms = float(np.sqrt(np.nansum(scan.resid_sums.ss) / max(scan.resid_sums.n.sum(), 1)))
            rows.append(["residual RMS, all channels / largest channel",
                         f"{all_rms:.2f} mm / {rms[w]:.2f} mm ({'/'.join(states.channels[w])})"])
            summary["residual_rms_mm"] = all_rms
    if spectra is not None and "res" in spectra:
        modes = spectra["res"]["modes"]
        seen = [m for m in modes if m["seen"]]
        rows.append(["modes identified", f"{len(seen)} of {len(modes)}: " + ", ".join(
            f"{m['mode']} {m['gps_hz']:.3f} Hz ζ {_fmt(m['damping'], '.3f')}" for m in seen)])
        summary["modes_seen"] = len(seen)
    if static is not None:
        d = static[0]
        rows.append([f"static survey {d['angle']}", f"mean {d['mean_deg']:.4f}°, noise {d['noise_rms_deg']:.4f}° RMS"
                     + ("" if d["error_deg"] is None else f", error {d['error_deg']:+.4f}° vs survey")])
    page.section("summary", "Summary", _html_table(rows, ["quantity", "value"]).replace("<table>", "<table class='kv'>", 1))
    page.text(_coordinate_table(states, scan, summary))
    data["summary"] = summary


def _coordinate_table(states, scan, summary: dict) -> str:
    names, units = list(states.coord_names), list(states.coord_units)
    mean, std = scan.q_sums.mean(), scan.q_sums.std()
    sig = scan.sigma_sums.mean() if scan.sigma_sums is not None and scan.sigma_sums.n.any() else np.full(len(names), np.nan)
    err = scan.error_sums.rms() if scan.error_sums is not None else None
    rows, coords = [], {}
    for i, n in enumerate(names):
        u, f = _display_unit(units[i])
        lo, hi = np.nanmin(scan.q.lo[:, i]) * f, np.nanmax(scan.q.hi[:, i]) * f
        # the RMS about the mean is at most half the range (a constant, a static model's: 0, not the sums' rounding)
        std[i] = min(std[i], 0.5 * (hi - lo) / f) if np.isfinite(hi - lo) else std[i]
        row = [n, u, f"{mean[i] * f:.4g}", f"{std[i] * f:.4g}", f"{lo:.4g}", f"{hi:.4g}", _fmt(sig[i] * f, ".3g")]
        if err is not None:
            row.append(_fmt(err[i] * f, ".3g"))
        rows.append(row)
        coords[n] = {"unit": units[i], "mean": mean[i], "rms_about_mean": std[i], "min": lo / f, "max": hi / f,
                     "mean_sigma": sig[i], **({"rms_error": err[i]} if err is not None else {})}
    summary["coordinates"] = coords
    header = ["coordinate", "unit", "mean", "RMS about mean", "min", "max", "mean 1σ"] + (["RMS error vs truth"]
                                                                                         if err is not None else [])
    return ("<p class='note'>Every coordinate over the whole record (every epoch; angles in degrees, "
            "lengths in mm):</p>" + _html_table(rows, header))


def _span(scan, env=None, what: str = "the minimum and maximum") -> str:
    bins = (env or scan.q).n_bins
    per = max(int(np.ceil(scan.n_epochs / bins)), 1)
    return (f"every epoch of the record ({scan.n_epochs}), drawn as {what} of each of "
            f"{bins} bins of {'up to ' if per > 1 else ''}{per} epoch{'s' if per > 1 else ''}")


def _time_sections(page: _Page, states, scan, chunk_epochs: int = STATES_CHUNK_EPOCHS) -> None:
    src = f"{Path(states.path).name}: the state series (ξ and P_ξ of /cdgps/state, packed arrays); {_span(scan)}."
    page.section("time", "Time histories with ±1σ")
    smoothed = states.metadata.get("smoothed") == "true"
    kind = "smoothed (RTS)" if smoothed else "forward-filter"
    if scan.angles is not None:
        fig = figs.time_history(scan.angles, scan.angle_names, ["deg"] * len(scan.angle_names),
                                "Section angles (small-angle sums of the coordinates)", states.has_covariance,
                                sigma_mean=scan.angle_sigma_sums.mean() if scan.angle_sigma_sums.n.any() else None)
        page.figure("angles", fig, f"Section angles, degrees: the {kind} estimate and its ±1σ band "
                    f"(σ from a P_ξ aᵀ of the angle's coefficients a). Expressions: "
                    + ", ".join(f"{n} = {e}" for n, e in zip(scan.angle_names, scan.angle_expr)) + ".", src)
    units, scale = zip(*(_display_unit(u) for u in states.coord_units))
    structure = states.cfg is not None
    title = ("Every generalized coordinate with its ±1σ band" if structure else
             "Displacement of each rover from its nominal position (east, north, up) with its ±1σ band")
    fig = figs.time_history(scan.q, list(states.coord_names), list(units), title, states.has_covariance,
                            np.array(scale), scan.sigma_sums.mean() * np.array(scale) if scan.sigma_sums.n.any()
                            else None, cols=2 if structure else 3)
    what = "generalized coordinate" if structure else "displacement (east, north, up per rover)"
    page.figure("coordinates", fig, f"Every {what} ({kind}), each in its unit (rad shown in deg, m in mm), with "
                f"the ±1σ band from the estimate's covariance.{_fix_text(states)}", src)
    if scan.extra:
        fig = figs.extra_figure(scan.extra, {})
        page.figure("extra", fig, "The series' further arrays (e.g. satellites used and PDOP of GNSS solutions), "
                    "minimum–maximum per bin.", src)
    if KINEMATIC_TOPIC in states.series_names:
        _kinematic_figures(page, states, scan.q.n_bins, chunk_epochs)


def _kinematic_figures(page: _Page, states, n_bins: int, chunk_epochs: int) -> None:
    """A GNSS run's single-epoch solutions (each epoch alone, with the fixed integers) and the
    satellites and PDOP of each epoch."""
    with StatesBlocks(states.path, KINEMATIC_TOPIC) as kin:
        sc = scan_series(kin, n_bins, chunk_epochs)
    units, scale = zip(*(_display_unit(u) for u in kin.coord_units))
    src = (f"{Path(states.path).name}: the single-epoch series {KINEMATIC_TOPIC} (packed arrays); "
           f"{sc.n_epochs} epochs, minimum and maximum per bin.")
    fig = figs.time_history(sc.q, list(kin.coord_names), list(units), "Single-epoch solutions (each epoch on its own, "
                            "with the fixed integers) and their ±1σ", kin.has_covariance, np.array(scale),
                            sc.sigma_sums.mean() * np.array(scale) if sc.sigma_sums.n.any() else None, cols=3)
    page.figure("kinematic", fig, "Each epoch's own solution with the fixed integers (no filter between epochs): "
                "what the filtered estimate above smooths; its scatter is the measurement noise.", src)
    if sc.extra:
        page.figure("satellites", figs.extra_figure(sc.extra, {"n_sat": "1", "pdop": "1"}),
                    "Satellite signals used (n_sat: the single differences of fixed integers in each epoch's own "
                    "solution, one per satellite and signal, so a satellite of two signals counts twice) and the "
                    "position dilution of precision (PDOP) of that solution, minimum–maximum per bin.", src)


def _fix_text(states) -> str:
    """The integer ambiguities each rover's estimate used (INIT.json attached to the STATES): fixed or
    float, how many, the ratio test; from several INITs, each window's (the STATES' rover summary)."""
    windows = _window_fix_text(states)
    if windows:
        return windows
    rovers = (states.init or {}).get("rovers") or {}
    parts = []
    for name, r in sorted(rovers.items()):
        if isinstance(r, dict) and "solution" in r:
            ratio = r.get("ratio")
            parts.append(f"{name}: {str(r['solution']).upper()} ({r.get('n_fixed', '?')} of {r.get('n_estimated', '?')} "
                         f"ambiguities fixed" + (f", ratio {ratio:.3g}" if isinstance(ratio, (int, float)) else "") + ")")
    return (" Integers (from the INIT the estimate started from): " + "; ".join(parts) + ".") if parts else ""


def _window_fix_text(states) -> str:
    """Each window's integers per rover of a STATES made from several INITs (``rovers.<r>.windows``), else ""."""
    parts = []
    for name, r in sorted(_rover_summaries(states).items()):
        wins = r.get("windows")
        if isinstance(wins, list) and len(wins) > 1:
            each = ", ".join(f"{Path(str(w.get('init', '?'))).name} {w.get('solution', '?')} "
                             f"({w.get('n_fixed', '?')} of {w.get('n_estimated', '?')})" for w in wins if isinstance(w, dict))
            parts.append(f"{name}: {each}")
    return (" Integers (each window's INIT): " + "; ".join(parts) + ".") if parts else ""


def _consistency_section(page: _Page, states, scan) -> None:
    page.section("consistency", "Filter consistency: NIS and NEES")
    ns = scan.nis_stats
    if not ns.get("epochs"):
        page.text("<p>No NIS in this file (a run that is all INIT window, or a file without diagnostics).</p>")
    else:
        fig = figs.chi2_history(scan.nis, scan.nis_bounds, "NIS / dof [1]", "Normalized innovation squared per epoch")
        page.figure("nis", fig, f"Normalized innovation squared of each epoch divided by its degrees of freedom: "
                    f"grey the minimum–maximum and blue the mean of each bin, dashed red the {100 * (CHI2_UPPER - CHI2_LOWER):g} % "
                    f"χ² interval for the epoch's dof (divided by the dof). {100 * ns['fraction_in_interval95']:.1f} % of "
                    f"{ns['epochs']} epochs are inside (95 % expected for a consistent filter); pooled NIS/dof "
                    f"{ns['pooled_per_dof']:.3f}.",
                    f"{Path(states.path).name}: arrays/cdgps/residuals/nis and nis_dof (every epoch); bounds "
                    f"χ²(0.025, dof) and χ²(0.975, dof) by cdgps_cli.estimation.chi2.")
    if scan.nees is not None:
        ne = scan.nees_stats
        fig = figs.chi2_history(scan.nees, None, f"NEES [1] (dof {ne['dof']})", "Normalized estimation error squared "
                                "against the simulator's truth", const_bounds=ne["interval95_single"])
        page.figure("nees", fig, f"NEES of the modal positions ξ against the simulator's truth (ξ_true = C⁺ q_true): "
                    f"grey min–max and blue mean per bin, dashed red the 95 % χ² interval for {ne['dof']} dof. "
                    f"Mean {ne['mean']:.2f}, {100 * ne['fraction_in_interval95']:.1f} % of {ne['epochs']} epochs inside.",
                    f"{Path(states.path).name}: ξ and P_ξ of /cdgps/state; truth.csv of --truth.")
    elif ns.get("epochs"):
        page.text("<p class='note'>NEES needs the true state: give <code>--truth</code> the folder of "
                  "<code>cdgps simulate</code> for a simulated run.</p>")


def _residual_section(page: _Page, states, scan) -> None:
    if scan.resid is None:
        return
    page.section("residuals", "Residuals per channel")
    rms = scan.resid_sums.rms()
    fig = figs.residual_figure(scan.resid, rms, states.channels)
    page.figure("residuals", fig, "Post-fit measurement residual of every channel (antenna/transmitter): left "
                "its RMS over the record, right its RMS in each time bin (the colour scale stops at the 99th "
                "percentile). A channel that stands out over a stretch points at multipath, a slip or a bad "
                "antenna position.", f"{Path(states.path).name}: arrays/cdgps/residuals/residual_m (every epoch, "
                f"float32) and channels.json; {_span(scan, scan.resid, 'the RMS')}.")


def _spectra_sections(page: _Page, data: dict, states, spectra: dict) -> None:
    page.section("modes", "Spectra and modes")
    if "error" in spectra:
        page.text(f"<p>No spectra: {html.escape(spectra['error'])}</p>")
        return
    res, gnames, cfg = spectra["res"], spectra["gyros"], states.cfg
    st = res["settings"]
    welch = (f"Welch: Hann window, {st['segments']} segments of {st['segment_s']:.0f} s, "
             f"{100 * st['overlap']:g} % overlap, resolution {st['resolution_hz']:.4f} Hz.")
    rows, header = _mode_rows(res["modes"])
    page.text(_html_table(rows, header) + "<p class='note'>GPS Hz and ζ: maximum-likelihood single-mode fit to "
              "the modal filter's periodogram (σ: 1-σ from the Fisher information); MAC: FDD singular vector vs "
              "the model's shape; seen: frequency within the tolerance and MAC high enough.</p>")
    src = f"{Path(states.path).name}: q of every epoch (read in blocks), " + (
        "the gyro rates of --gyro" if gnames else "no gyro log (--gyro)") + "; cdgps_cli.analysis.spectra."
    page.figure("psd", plot_psd(res, cfg, gnames), ("GPS- and gyro-derived angle PSDs about each gyro axis"
                if gnames else "PSDs of the estimated coordinates") + f", model mode frequencies dashed. {welch}", src)
    page.figure("fdd", plot_fdd(res, cfg), f"Frequency-domain decomposition: the three largest singular values of "
                f"the standardized cross-spectral matrix; dashed grey the model's modes, red the identified. {welch}",
                src)
    fs = res.get("fdd_shapes") or {}
    vec = fs.get("vectors") or {}
    if vec:
        nums = sorted(vec)
        A = np.column_stack([vec[k] for k in nums])
        B = np.asarray(fs["model"])
        live = [j for j in range(B.shape[1]) if np.linalg.norm(B[:, j]) > 0 and cfg.mode_frequency_hz[j] > 0]
        M = mac_matrix(A, B[:, live])
        data["mac"] = {"identified_modes": nums, "model_modes": [j + 1 for j in live], "matrix": M.tolist()}
        lab = lambda j: f"{j} {cfg.mode_names[j - 1]}"  # noqa: E731
        page.figure("mac", figs.mac_figure(M, [lab(k) for k in nums], [lab(j + 1) for j in live]),
                    "Modal assurance criterion between each identified shape (the FDD singular vector at the mode's "
                    "peak) and every model shape of the config: 1 on the diagonal and 0 elsewhere is a perfect "
                    "match; a large off-diagonal value means two modes the data cannot tell apart.",
                    src + " Shapes compared on the standardized coordinates " + ", ".join(fs["coordinates"]) + ".")
        _mode_shape_figure(page, cfg, res, fs, src)
    data["modes"] = res["modes"]
    data["spectra_settings"] = st


def _mode_rows(modes: list) -> tuple[list, list]:
    rows = []
    for m in sorted(modes, key=lambda m: (m["model_hz"], m["number"])):
        rows.append([m["number"], m["mode"], f"{m['model_hz']:.4f}", _fmt(m["gps_hz"]), _fmt(m.get("gps_hz_sigma")),
                     _fmt(m["gyro_hz"]), _fmt(m["error_pct"], "+.2f"), _fmt(m["damping"]), _fmt(m.get("damping_sigma")),
                     f"{m['model_damping']:.4f}", _fmt(m["mac"], ".2f"), "yes" if m["seen"] else "no"])
    return rows, ["#", "mode", "model Hz", "GPS Hz", "σ Hz", "gyro Hz", "error %", "ζ", "σ ζ", "model ζ", "MAC", "seen"]


def _mode_shape_figure(page: _Page, cfg, res, fs, src) -> None:
    from cdgps_cli.model.points import select_points  # noqa: PLC0415

    pts = select_points(cfg, "all")
    U = np.asarray(cfg.mode_shapes, dtype=float)
    sel = [list(cfg.coord_names).index(n) for n in fs["coordinates"]]
    shapes = []
    for m in sorted(res["modes"], key=lambda m: m["model_hz"]):
        j = m["number"] - 1
        q_id = None
        v = fs["vectors"].get(m["number"])
        if v is not None:
            v = v * np.exp(-1j * np.angle(v[np.argmax(np.abs(v))]))     # the largest entry made real
            q_id = np.zeros(cfg.n_q)
            q_id[sel] = np.real(v) * np.asarray(fs["scales"])
        hz = "" if m["gps_hz"] is None else f", identified {m['gps_hz']:.3f} Hz"
        shapes.append((f"{m['number']} {m['mode']} ({m['model_hz']:.3f} Hz{hz})", U[:, j], q_id))
    page.figure("shapes", figs.mode_shape_figure(cfg, pts, shapes),
                "Each mode drawn on the structure (the config's antennas and points): open grey circles at rest, "
                "blue dots displaced by the config's mode shape, orange crosses by the identified shape (FDD "
                "singular vector, scaled to match), exaggerated to 12 % of the structure's size, seen along the "
                "two lab axes the mode moves most.", src + " Geometry and shapes from the config attached to the STATES.")


def _static_section(page: _Page, data: dict, static, survey_deg, angle, run) -> None:
    d, t, a, sig, g_angle = static
    page.section("static", f"Static survey: {angle}")
    rows = [["mean (GPS)", f"{d['mean_deg']:.4f}°"], ["survey", _fmt(survey_deg) + ("°" if survey_deg is not None else "")],
            ["error", _fmt(d["error_deg"], "+.4f") + ("°" if d["error_deg"] is not None else "")],
            ["noise RMS (detrended)", f"{d['noise_rms_deg']:.4f}°"],
            ["estimated σ (mean)", _fmt(d["estimated_sigma_deg"]) + ("°" if d["estimated_sigma_deg"] is not None else "")],
            ["GPS drift", f"{d['drift_deg_per_min']:+.4f}°/min"],
            ["gyro drift", _fmt(d["gyro_drift_deg_per_min"], "+.4f") + ("°/min" if d["gyro_drift_deg_per_min"] is not None else "")],
            ["rest segment", f"{d['start_s']:.1f}–{d['end_s']:.1f} s ({d['segment']}, {d['samples']} samples)"]]
    page.text(_html_table(rows, ["quantity", "value"]) + f"<p class='note'>{html.escape(d['static_mode']['statement'])}</p>")
    page.figure("static", plot_static(t, a, sig, survey_deg, angle, g_angle, d["gyro"] or ()),
                f"The {angle} angle on the rest segment with its ±1σ band, mean and survey; below, "
                + ("the gyro-integrated angle minus GPS." if d["gyro"] else "the GPS estimate minus its linear fit."),
                "the same computation as `cdgps report static` (cdgps_cli.report.sensor_reports.static_statistics) "
                "on every epoch of the rest segment.")
    data["static"] = d
