"""Spectra outputs and the static / spectrum sensor-test reports (1998 paper Sec. VI.A–B).

Every report directory gets ``report.md``, ``report.json`` and a self-contained ``report.html``
(figures embedded as base64 PNG) that opens in any browser; every file is written atomically.
"""

from __future__ import annotations

import base64
import html
import io
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.config.options import STATES_CHUNK_EPOCHS
from cdgps_cli.io.atomic import OutputSet, output_set, write_bytes_atomic
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.expressions import parse_expression
from cdgps_cli.model.kinematics import gyro_matrix
from cdgps_cli.io.provenance import provenance_rows, report_provenance


def _structure_config(states, what: str):
    """The structure config of ``states`` (a :class:`~cdgps_cli.io.states.States`), or a CdgpsError:
    modes, gyros and angles belong to a structure, not to GNSS displacement states."""
    if states.cfg is None:
        raise CdgpsError(f"{states.path}: {what} needs the STATES.mcap of a structure (modal states); this one holds "
                         f"{getattr(states, 'kind', 'other')} states ({', '.join(states.coord_names)})")
    return states.cfg


def _coordinate_model(states):
    """The structure config of ``states``, or the coordinates-only model of GNSS displacement
    states (:meth:`cdgps_cli.io.states.States.coordinate_model`: PSDs and FDD, no modes)."""
    return states.cfg if states.cfg is not None else states.coordinate_model()


def _mpl():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": 110, "font.size": 9, "axes.grid": True, "grid.alpha": 0.3,
                         "svg.hashsalt": "cdgps", "path.simplify": True})
    return plt


_atomic_bytes = write_bytes_atomic


def float_csv(df: pd.DataFrame, float_format: str = "%.7g") -> str:
    """CSV text of an all-numeric frame: the same bytes as ``df.to_csv(index=False,
    lineterminator="\\n", float_format=...)`` (NaN written as an empty field), about 4× faster."""
    a = df.to_numpy(dtype=float)
    row = ",".join([float_format] * a.shape[1]) + "\n"
    body = "".join(row % tuple(r) for r in a.tolist())
    if np.isnan(a).any():
        body = re.sub(r"(?<![^,\n])nan(?![^,\n])", "", body)
    return ",".join(map(str, df.columns)) + "\n" + body


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def _save_fig(fig, path: Path) -> bytes:
    data = _png(fig)
    _atomic_bytes(path, data)
    return data


def _json_clean(o):
    if isinstance(o, dict):
        return {k: _json_clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_json_clean(v) for v in o]
    if isinstance(o, (np.floating, float)):
        return None if not np.isfinite(o) else float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def _gyro_table(run) -> tuple[np.ndarray, np.ndarray, list]:
    """The gyro log as distinct times (T,), rates (T, G) of the config's gyros that are in it (a gap
    linearly interpolated over the row positions, the ends held: pandas' ``interpolate(limit_direction=
    "both")``) and their names.  Built with numpy from the table's codes (the pandas pivot of a day's
    log peaked near 1 GB; the same numbers, ``tests/report/test_sensor_reports.py``)."""
    if run.gyro is None or len(run.gyro) == 0:
        return np.zeros(0), np.zeros((0, 0)), []
    codes, words = run.gyro.codes("gyro")
    present = set(np.asarray(words, dtype=object)[np.unique(codes)].tolist())
    names = [n for n in run.cfg.gyro_names if n in present]
    times, row = np.unique(np.asarray(run.gyro["time_s"], dtype=float), return_inverse=True)
    rate = np.asarray(run.gyro["rate_rad_s"], dtype=float)
    wide = np.full((times.size, len(names)), np.nan)
    for j, name in enumerate(names):
        mine = codes == words.index(name)
        wide[row[mine], j] = rate[mine]
        bad = np.isnan(wide[:, j])
        if bad.any() and not bad.all():
            pos = np.arange(times.size)
            wide[bad, j] = np.interp(pos[bad], pos[~bad], wide[~bad, j])
    return times, wide, names


# ----------------------------------------------------------------------------- spectra

#: every file each command may write (its output set, replaced as a whole: cdgps_cli.io.atomic.output_set)
SPECTRA_FILES = ("psd.csv", "peaks.json", "psd.png", "fdd.png")
REPORT_FILES = ("report.md", "report.json", "report.html")
STATIC_REPORT_FILES = (*REPORT_FILES, "static.png")
SPECTRUM_REPORT_FILES = (*SPECTRA_FILES, *REPORT_FILES)


def run_spectra(states, run, opt, out_dir: str | Path, dest: OutputSet | None = None,
                chunk_epochs: int = STATES_CHUNK_EPOCHS) -> dict:
    """Compute spectra and write psd.csv, peaks.json, psd.png, fdd.png into ``out_dir``.

    The four files replace an earlier set there as a whole (:func:`cdgps_cli.io.atomic.output_set`),
    or go into ``dest``, the output set of a larger command (the spectrum report).  ``states``: a
    :class:`~cdgps_cli.io.states.States` (whole record in memory) or a
    :class:`~cdgps_cli.io.states.StatesChunks`, read in chunks of ``chunk_epochs`` epochs (the
    numbers do not depend on it)."""
    res, gnames = spectra_result(states, run, opt, chunk_epochs)
    if dest is None:
        with output_set(out_dir, replaces=SPECTRA_FILES) as own:
            return _write_spectra(states, res, gnames, own)
    return _write_spectra(states, res, gnames, dest)


def check_gyro_run(states, run) -> None:
    """The gyro RUN.mcap (``--gyro``) must have been ingested with the config ``states`` estimates; a
    CdgpsError naming both files and both configs otherwise."""
    if run is not None and run.cfg is not None and states.config_sha256 and run.cfg.sha256 != states.config_sha256:
        raise CdgpsError(f"--gyro {run.path}: ingested with config {run.cfg.name!r} (sha256 {run.cfg.sha256[:12]}…), "
                         f"but {states.path} estimates config {states.config_name!r} (sha256 "
                         f"{states.config_sha256[:12]}…); give the RUN.mcap of the same structure")


def spectra_result(states, run, opt, chunk_epochs: int = STATES_CHUNK_EPOCHS) -> tuple[dict, list]:
    """The spectra of ``states`` (and the gyros of ``run``, or None): ``(result, gyro names)``, the
    result of :func:`cdgps_cli.analysis.spectra.spectra_of_chunks`; nothing written."""
    from cdgps_cli.analysis.spectra import compute_spectra, spectra_of_chunks

    cfg = _coordinate_model(states)
    gt, gr, gnames = (np.zeros(0), None, [])
    if run is not None:
        check_gyro_run(states, run)
        gt, gr, gnames = _gyro_table(run)
        if len(gnames) != len(cfg.gyro_names):
            gr = None if not gnames else gr
    gyro = (gt if gr is not None else None, gr)
    if hasattr(states, "chunks"):
        from cdgps_cli.io.column_scratch import ColumnScratch  # noqa: PLC0415

        res = spectra_of_chunks(cfg, lambda: states.chunks(chunk_epochs), states.n_epochs, *gyro, opt,
                                columns=ColumnScratch)          # the modal series on disk, a mode at a time
    else:
        res = compute_spectra(cfg, states.time_s, states.q, *gyro, opt)
    return res, gnames


def _write_spectra(states, res: dict, gnames: list, dest: OutputSet) -> dict:
    cfg = _coordinate_model(states)
    f = res["f_hz"]
    df = pd.DataFrame({"frequency_hz": f})
    units = {"rad": "_rad2_hz", "m": "_m2_hz", "1": "_1_hz"}
    for k, v in res["psd"].items():
        if k.startswith("coherence_"):
            col = k
        elif k.startswith("gps_") and k[4:] in cfg.coord_names:
            col = k + units[cfg.coord_unit(k[4:])]
        else:
            col = k + "_rad2_hz"
        df[col] = v
    for i in range(res["fdd_sv"].shape[1]):
        df[f"fdd_singular_value_{i + 1}_1_hz"] = res["fdd_sv"][:, i]      # of the standardized CSD
    _atomic_bytes(dest.path("psd.csv"), float_csv(df, "%.7g").encode())
    fusion = fusion_note(states)
    peaks = _json_clean({"modes": res["modes"], "peaks": res.get("peaks", []), "settings": res["settings"],
                         "states": str(states.path),
                         "config": cfg.name, "config_sha256": cfg.sha256, "gyros": gnames,
                         **({"fusion": fusion} if fusion else {})})
    _atomic_bytes(dest.path("peaks.json"), (json.dumps(peaks, indent=2) + "\n").encode())
    plt = _mpl()
    pngs = {}
    for name, fig in (("psd.png", plot_psd(res, cfg, gnames)), ("fdd.png", plot_fdd(res, cfg))):
        pngs[name] = _save_fig(fig, dest.path(name))
        plt.close(fig)
    return {"out_dir": str(dest.out), "files": ["psd.csv", "peaks.json", *pngs], "modes": peaks["modes"],
            "peaks": peaks["peaks"], "settings": peaks["settings"], "pngs": pngs, "gyros": gnames, **({"fusion": fusion} if fusion else {})}


def fusion_note(states) -> dict | None:
    """What the states fused (``estimate --fuse``, issue 30) and whether the gyros are still an
    independent check of the spectra: {fused, hold_out, gyros_independent_check, note}, or None."""
    try:
        opts = json.loads(states.metadata.get("options", "{}"))
    except (ValueError, TypeError, AttributeError):
        return None
    f = opts.get("fusion") if isinstance(opts, dict) else None
    if not isinstance(f, dict) or not f.get("fused"):
        return None
    independent = bool(f.get("gyro_independent_check", True))
    held = list(f.get("hold_out", []))
    if not independent:
        note = ("the gyros are fused into these states: they are no longer an independent check of the spectra "
                "(keep one out with 'estimate --hold-out NAME')")
    else:
        note = f"fused: {', '.join(f['fused'])}" + (f"; held out as independent checks: {', '.join(held)}" if held else "")
    return {"fused": list(f["fused"]), "hold_out": held, "gyros_independent_check": independent, "note": note}


def _mark_modes(ax, res, cfg, label=True):
    """Model frequencies as dashed lines with short staggered labels (mode numbers of the config)."""
    lo, hi = ax.get_ylim()
    logy = ax.get_yscale() == "log"
    for k, m in enumerate(sorted(res["modes"], key=lambda m: m["model_hz"])):
        ax.axvline(m["model_hz"], color="0.5", ls="--", lw=0.7, zorder=0)
        if label:
            frac = 0.97 - 0.07 * (k % 3)
            y = lo * (hi / lo) ** frac if logy else lo + (hi - lo) * frac
            ax.text(m["model_hz"], y, str(m["number"]), ha="center", va="top", fontsize=7, color="0.3",
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "0.7", "lw": 0.5})


def _mode_key(cfg, res) -> str:
    """Mode numbers of the figure's labels with names and frequencies, in frequency order (none: a motion model
    without modes, e.g. a GNSS random walk)."""
    if not res["modes"]:
        return "no model modes (the states' motion model has none): the peaks are found in the spectra alone"
    return "model modes: " + ", ".join(f"{m['number']} {m['mode']} ({m['model_hz']:g} Hz)"
                                       for m in sorted(res["modes"], key=lambda m: m["model_hz"]))


def _plain_log_ticks(ax) -> None:
    """Frequency tick labels as plain numbers (0.03, 0.1, 0.2, …) instead of 3×10⁻²; minor ticks
    labelled at 2, 3 and 5 × 10ⁿ only when the axis spans less than two decades."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    lo, hi = ax.get_xlim()
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    if hi / lo < 100:
        def minor(v, _):
            lead = v / 10 ** np.floor(np.log10(v))
            return f"{v:g}" if np.isclose(lead, (2, 3, 5)).any() else ""
        ax.xaxis.set_minor_formatter(FuncFormatter(minor))
    else:
        ax.xaxis.set_minor_formatter(NullFormatter())


def _plot_index(f: np.ndarray, fmin: float, fmax: float, points: int = 2000) -> np.ndarray:
    """Indices of ~``points`` log-spaced frequencies in [fmin, fmax] (plots only; data files keep all)."""
    sel = np.flatnonzero((f >= fmin) & (f <= fmax))
    if sel.size <= points:
        return sel
    want = np.geomspace(f[sel[0]], f[sel[-1]], points)
    return np.unique(sel[0] + np.searchsorted(f[sel], want).clip(0, sel.size - 1))


def peak_amplitude(p: dict) -> tuple[float, float | None, str, bool]:
    """A spectral peak's amplitude as the summary, the figure and the report show it: (value, its σ or None, unit,
    whether from the whole-record fit) — the fit and its σ for a steady sinusoid, else the PSD's amplitude; metres
    in mm, a dimensionless coordinate without a unit."""
    scale, unit = (1e3, "mm") if p.get("unit") == "m" else (1.0, "" if p.get("unit") in (None, "1") else p["unit"])
    fit = bool(p.get("steady", True)) and p.get("amplitude_sigma") is not None
    value = p["amplitude"] if fit else p.get("amplitude_psd", p["amplitude"])
    return value * scale, (p["amplitude_sigma"] * scale if fit else None), unit, fit


#: spectral peaks labelled in a PSD figure at most (more: their triangles alone)
MAX_LABELLED_PEAKS = 6


def _mark_peaks(ax, res: dict, colour: dict, fmin: float, fmax: float) -> None:
    """Each spectral peak (``res["peaks"]``) as a triangle on its coordinate's PSD, in the line's colour; labelled
    with its frequency and amplitude (mm for metres) when the states have no model modes and the peaks are few."""
    shown = [p for p in res.get("peaks", []) if fmin <= p["frequency_hz"] <= fmax and p["coordinate"] in colour]
    # labelled where nothing else marks the spectrum (no model modes) and they stay few; else the triangles alone
    # (every figure in peaks.json)
    label = not res["modes"] and len(shown) <= MAX_LABELLED_PEAKS
    top = max([p["psd_peak"] for p in shown], default=1.0)
    stacked: dict = {}                      # labels of peaks at about one frequency, one above the other
    for p in shown:
        f0 = p["frequency_hz"]
        ax.plot([f0], [p["psd_peak"] * 1.6], marker="v", ms=6, color=colour[p["coordinate"]], ls="none")
        if not label:
            continue
        amp, _, unit, _ = peak_amplitude(p)
        value = f"{amp:.2f} mm" if unit == "mm" else f"{amp:.3g}"
        k = stacked.setdefault(round(float(np.log10(f0)), 1), [])
        ax.annotate(f"{p['coordinate']}: {f0:.3f} Hz, {value}", (f0, top * 2.0), xytext=(6, 2 + 10 * len(k)),
                    textcoords="offset points", fontsize=7, color=colour[p["coordinate"]])
        k.append(p)
    if stacked:
        lo, hi = ax.get_ylim()
        ax.set_ylim(lo, max(hi, top * 2.0 * 10 ** (0.25 * max(len(v) for v in stacked.values()))))


def plot_psd(res, cfg, gnames) -> bytes:
    """Fig. 8 style: GPS- vs gyro-derived angle PSDs (rad²/Hz), log-log, model modes marked."""
    plt = _mpl()
    f = res["f_hz"]
    fmin = max(f[0], 0.01)
    fmax = min(f[-1], 2.0)
    sel = _plot_index(f, fmin, fmax)
    if gnames:
        n = len(gnames)
        cols = 2 if n > 1 else 1
        rows = int(np.ceil(n / cols))
        fig, axes = plt.subplots(rows, cols, figsize=(10, 2.8 * rows), squeeze=False, sharex=True)
        for i, g in enumerate(gnames):
            ax = axes[i // cols][i % cols]
            ax.loglog(f[sel], res["psd"][f"gps_{g}"][sel], label="GPS (estimated angle)", lw=1.0)
            ax.loglog(f[sel], res["psd"][f"gyro_{g}"][sel], label="gyro (rate PSD / (2πf)²)", lw=1.0, alpha=0.85)
            ax.set_title(f"gyro {g}: angle seen by the gyro axis", fontsize=9)
            ax.set_ylabel("PSD [rad²/Hz]")
            _mark_modes(ax, res, cfg)
        for j in range(n, rows * cols):
            axes[j // cols][j % cols].axis("off")
        for ax in axes[-1]:
            ax.set_xlabel("frequency [Hz]")
            _plain_log_ticks(ax)
        fig.suptitle(f"{cfg.name}: GPS- and gyro-based spectra (dashed: model mode frequencies)", fontsize=10)
        fig.legend(*axes[0][0].get_legend_handles_labels(), loc="upper center", bbox_to_anchor=(0.5, 0.975),
                   ncol=2, fontsize=8, frameon=False)     # one legend for every panel, outside the data
        fig.text(0.5, 0.005, _mode_key(cfg, res), ha="center", va="bottom", fontsize=7, wrap=True)
        fig.tight_layout(rect=(0, 0.03, 1, 0.955))
        return fig
    else:
        fig, ax = plt.subplots(figsize=(10, 4.5))
        colour = {}
        for k, v in res["psd"].items():
            if k.startswith("gps_q") or (k.startswith("gps_") and k[4:] in cfg.coord_names):
                name = k[4:]
                line, = ax.loglog(f[sel], v[sel], lw=0.9, label=f"{name} [{cfg.coord_unit(name)}²/Hz]")
                colour[name] = line.get_color()
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("PSD [unit²/Hz]")
        _plain_log_ticks(ax)
        _mark_modes(ax, res, cfg)
        _mark_peaks(ax, res, colour, fmin, fmax)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
        ax.set_title(f"{cfg.name}: PSDs of the estimated coordinates (dashed: model modes; ▼ spectral peaks)")
        fig.text(0.5, 0.005, _mode_key(cfg, res), ha="center", va="bottom", fontsize=7, wrap=True)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    return fig


def plot_fdd(res, cfg):
    plt = _mpl()
    f = res["f_hz"]
    fm = [m["model_hz"] for m in res["modes"]] or [0.1]
    sel = _plot_index(f, max(f[0], min(fm) / 2), min(f[-1], max(fm) * 3))
    fig, ax = plt.subplots(figsize=(10, 4.2))
    for i in range(res["fdd_sv"].shape[1]):
        ax.loglog(f[sel], res["fdd_sv"][sel, i], lw=0.9, label=f"singular value {i + 1}")
    for m in res["modes"]:
        if m["gps_hz"] is not None and m["seen"]:
            ax.axvline(m["gps_hz"], color="tab:red", lw=0.8, alpha=0.6)
    _mark_modes(ax, res, cfg)
    _plain_log_ticks(ax)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("singular value [1/Hz, standardized]")
    ax.set_title("Frequency-domain decomposition of the cross-spectral matrix (dashed: model, red: identified)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.text(0.5, 0.005, _mode_key(cfg, res), ha="center", va="bottom", fontsize=7, wrap=True)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return fig


# ----------------------------------------------------------------------------- HTML / markdown

_CSS = """body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1000px;margin:2em auto;
padding:0 1em;color:#222}table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;
text-align:right}th{background:#f4f4f4}td:first-child,th:first-child{text-align:left}img{max-width:100%}
.ok{color:#17692b}.bad{color:#b00020}code{background:#f4f4f4;padding:1px 4px}
figure{margin:1.5em 0}figcaption{font-size:0.92em;color:#333;margin-top:0.4em;line-height:1.4}
table.prov td,table.prov th{text-align:left;vertical-align:top;font-size:0.88em}
table.prov td:last-child{overflow-wrap:anywhere}td.t,th.t{text-align:left}
p.note{font-size:0.92em;color:#333}"""


def _caption_label(i: int, name: str) -> str:
    return f"Figure {i} ({name})."


def _html_page(title: str, sections: list[tuple[str, str]], figures: dict[str, bytes],
               captions: dict[str, str] | None = None, after: list[tuple[str, str]] = ()) -> str:
    """A self-contained page: sections, then the figures (numbered, with their captions), then
    the ``after`` sections (provenance)."""
    captions = captions or {}
    parts = [f"<!doctype html><html lang='en'><head><meta charset='utf-8'>"
             f"<meta name='viewport' content='width=device-width, initial-scale=1'><title>{html.escape(title)}</title>"
             f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"]
    for head, body in sections:
        parts.append(f"<h2>{html.escape(head)}</h2>{body}")
    for i, (name, data) in enumerate(figures.items(), 1):
        b64 = base64.b64encode(data).decode()
        cap = f"<b>{html.escape(_caption_label(i, name))}</b> {html.escape(captions.get(name, ''))}"
        parts.append(f"<figure><img alt='{html.escape(name)}' src='data:image/png;base64,{b64}'>"
                     f"<figcaption>{cap}</figcaption></figure>")
    for head, body in after:
        parts.append(f"<h2>{html.escape(head)}</h2>{body}")
    parts.append("</body></html>")
    return "\n".join(parts)


def _md_figures(figures: dict, captions: dict[str, str]) -> str:
    return "\n\n".join(f"![{name}]({name})\n\n*{_caption_label(i, name)} {captions.get(name, '')}*"
                        for i, name in enumerate(figures, 1))


def _provenance_md(p: dict) -> str:
    rows = [[k, v.replace("|", "\\|")] for k, v in provenance_rows(p)]
    return "## Provenance\n\n" + _md_table(rows, ["what", "value"]) + "\n"


def _provenance_html(p: dict) -> str:
    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in provenance_rows(p))
    return f"<table class='prov'><tr><th>what</th><th>value</th></tr>{rows}</table>"


def _is_text(v) -> bool:
    """A cell that is words (left-aligned), not a number with or without a unit (right-aligned)."""
    return not re.match(r"^[-+–]?\d|^–$", str(v).strip())


def _html_table(rows: list[list], header: list[str]) -> str:
    text_cols = [bool(rows) and all(_is_text(r[j]) for r in rows) for j in range(len(header))]
    cls = [" class='t'" if t else "" for t in text_cols]
    out = ["<table><tr>" + "".join(f"<th{c}>{html.escape(h)}</th>" for h, c in zip(header, cls)) + "</tr>"]
    for r in rows:
        out.append("<tr>" + "".join(f"<td{c}>{html.escape(str(v))}</td>" for v, c in zip(r, cls)) + "</tr>")
    return "".join(out) + "</table>"


def _md_table(rows: list[list], header: list[str]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


def _fmt(v, spec=".4f"):
    return "–" if v is None else format(v, spec)


def _write_report(dest: OutputSet, title: str, md: str, data: dict, sections, figures, captions=None) -> None:
    """report.md (``md`` + figure captions + provenance), report.json (``data``, with its
    ``provenance`` and ``captions``) and report.html."""
    captions = captions or {}
    prov = data.get("provenance")
    md = md.rstrip("\n") + "\n\n" + _md_figures(figures, captions) + "\n"
    after = []
    if prov is not None:
        md += "\n" + _provenance_md(prov)
        after.append(("Provenance", _provenance_html(prov)))
    data["captions"] = dict(captions)
    _atomic_bytes(dest.path("report.md"), md.encode())
    _atomic_bytes(dest.path("report.json"), (json.dumps(_json_clean(data), indent=2) + "\n").encode())
    _atomic_bytes(dest.path("report.html"), _html_page(title, sections, figures, captions, after).encode())


# ----------------------------------------------------------------------------- static report

def detect_rest(time_s: np.ndarray, angle_rad: np.ndarray, window_s: float = 10.0,
                max_std_deg: float | None = None, min_length_s: float = 10.0) -> tuple[float, float]:
    """Longest span where the angle's rolling standard deviation stays quiet.

    Quiet means below ``max_std_deg``; by default the larger of 0.05° and four times the 5th
    percentile of the rolling standard deviation (i.e. a few times the estimate's own noise).
    """
    T = float(np.median(np.diff(time_s)))
    w = max(int(round(window_s / T)), 3)
    s = pd.Series(np.degrees(angle_rad)).rolling(w, center=True, min_periods=w // 2).std().to_numpy()
    if max_std_deg is None:
        finite = s[np.isfinite(s)]
        max_std_deg = max(0.05, 4.0 * float(np.percentile(finite, 5))) if finite.size else 0.05
    quiet = s < max_std_deg
    best = (0, -1)
    k = 0
    n = len(quiet)
    while k < n:
        if quiet[k]:
            j = k
            while j + 1 < n and quiet[j + 1]:
                j += 1
            if j - k > best[1] - best[0]:
                best = (k, j)
            k = j + 1
        else:
            k += 1
    if best[1] < 0 or (time_s[best[1]] - time_s[best[0]]) < min_length_s:
        raise CdgpsError(f"no rest segment found (angle rolling std over {window_s:g} s never stays below "
                         f"{max_std_deg:g}° for {min_length_s:g} s); give --start/--end")
    # trim half a window at each end (the rolling window straddles the transition)
    a = min(best[0] + w // 2, best[1])
    return float(time_s[a]), float(time_s[best[1]])


def plot_static(t, a, sig, survey_deg, angle: str, g_angle=None, gyro_names=()):
    """Fig. 7 style, two panels sharing time: the GPS estimate on its own scale (±1σ band, mean,
    survey) and, below, the gyro-integrated angle minus GPS with its linear fit (or, without a
    gyro, the GPS estimate minus its linear fit).  ``t`` in s, angles in degrees."""
    plt = _mpl()
    minutes = (t - t[0]) / 60.0
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True, height_ratios=(3, 2))
    # the axis is the estimate's (and the survey's): a σ band wider than that is clipped and says so
    span = [float(np.min(a)), float(np.max(a))] + ([survey_deg] if survey_deg is not None else [])
    lo, hi = min(span), max(span)
    pad = 0.15 * max(hi - lo, 1e-4)
    lo, hi = lo - pad, hi + pad + 0.3 * (hi - lo + 2 * pad)        # headroom for the legend
    if sig is not None:
        wide = bool(np.any(a - sig < lo) or np.any(a + sig > hi))
        label = f"estimated ±1σ (mean {np.mean(sig):.4f}°{', beyond this axis' if wide else ''})"
        ax1.fill_between(t, a - sig, a + sig, color="tab:blue", alpha=0.15, lw=0, label=label)
    ax1.plot(t, a, lw=0.9, color="tab:blue", label="GPS estimate")
    ax1.axhline(float(np.mean(a)), color="tab:blue", ls=":", lw=1.0, label=f"GPS mean {np.mean(a):.4f}°")
    if survey_deg is not None:
        ax1.axhline(survey_deg, color="k", ls="--", lw=0.9, label=f"survey {survey_deg:g}°")
    ax1.set_ylim(lo, hi)
    ax1.set_ylabel(f"{angle}, GPS [deg]")
    ax1.legend(fontsize=8, loc="upper right", ncol=2, framealpha=0.9)
    ax1.set_title(f"Static sensor test: {angle} on {t[0]:.1f}–{t[-1]:.1f} s")
    if g_angle is not None:
        d = g_angle - a
        pd_ = np.polyfit(minutes, d, 1)
        ax2.plot(t, d, lw=0.9, color="tab:purple", label=f"gyro ({', '.join(gyro_names)}) − GPS")
        ax2.plot(t, np.polyval(pd_, minutes), color="k", ls="--", lw=0.8, label=f"linear fit: {pd_[0]:+.3f}°/min")
        ax2.set_ylabel("gyro − GPS [deg]")
    else:
        p = np.polyfit(minutes, a, 1)
        ax2.plot(t, a - np.polyval(p, minutes), lw=0.9, color="tab:purple", label="GPS − its linear fit")
        ax2.set_ylabel("GPS − linear fit [deg]")
    ax2.axhline(0.0, color="0.4", lw=0.6)
    ax2.legend(fontsize=8, loc="lower left")
    ax2.set_xlabel("time [s]")
    fig.tight_layout()
    return fig


def _static_caption(data: dict, smoothed: bool | None, no_gyro: str = "no gyro") -> str:
    how = {"detected": "detected", "given": "given (--start/--end)"}[data["segment"]]
    kind = {True: "smoothed", False: "forward-filter"}.get(smoothed, "")
    text = (f"Static sensor test (1998 paper Fig. 7): the {data['angle']} angle on the {how} rest segment "
            f"{data['start_s']:.1f}–{data['end_s']:.1f} s ({data['samples']} {kind} estimates). Top: the GPS "
            f"estimate on its own scale")
    est = data["estimated_sigma_deg"]
    if est is not None:
        text += f", its estimated ±1σ band (shaded, from the estimate's covariance; mean σ {est:.4f}°"
        ratio = est / data["noise_rms_deg"] if data["noise_rms_deg"] > 0 else float("inf")
        text += (f", {ratio:.1f}× the scatter about the fit: the estimator's σ is pessimistic here)" if ratio > 2
                 else f", {1 / ratio:.1f}× smaller than the scatter about the fit: the estimator's σ is optimistic here)"
                 if ratio < 0.5 else ")")
    text += f", its mean {data['mean_deg']:.4f}° (dotted)"
    text += f" and the survey {data['survey_deg']:g}° (dashed). " if data["survey_deg"] is not None else ". "
    if data["gyro"]:
        text += (f"Bottom: the angle integrated from the rate of gyro {', '.join(data['gyro'])} (mean of the rates), "
                 f"started at the GPS estimate at {data['start_s']:.1f} s, minus the GPS estimate; dashed: its "
                 f"linear fit. The gyro drifts by {data['gyro_minus_gps_end_deg']:+.3f}° over the segment, the GPS "
                 f"estimate by {data['drift_deg_per_min']:+.4f}°/min.")
    else:
        text += (f"Bottom: the GPS estimate minus its linear fit (drift {data['drift_deg_per_min']:+.4f}°/min): "
                 f"the noise whose RMS is in the table (gyro: {no_gyro}).")
    return text


def _angle_series(states, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Times (N,) and the angle q·coef (N,) of a STATES read in chunks (only these two series are kept)."""
    from cdgps_cli.config.options import STATES_CHUNK_EPOCHS  # noqa: PLC0415

    t, a = [], []
    for ch in states.series(STATES_CHUNK_EPOCHS):
        t.append(ch["time_s"])
        a.append(ch["q"] @ coef)
    return (np.concatenate(t), np.concatenate(a)) if t else (np.empty(0), np.empty(0))


def _segment_covariance(states, sel: np.ndarray) -> np.ndarray:
    """P_ξ at the epochs ``sel`` (a mask over all epochs) of a STATES read in chunks."""
    from cdgps_cli.config.options import STATES_CHUNK_EPOCHS  # noqa: PLC0415

    out, a = [], 0
    for ch in states.series(STATES_CHUNK_EPOCHS):
        k = len(ch["time_s"])
        m = sel[a:a + k]
        if m.any():
            out.append(ch["P_xi"][m])
        a += k
    return np.concatenate(out) if out else np.empty((0, states.n_pos, states.n_pos))


def static_statistics(states, run, angle: str, survey_deg: float | None, start_s: float | None = None,
                      end_s: float | None = None, gyro: str | None = None):
    """The static sensor test's numbers on the rest segment (what :func:`static_report` reports).

    Returns
    -------
    ``(data, t, a, sig, g_angle)``: the statistics dict (no provenance), the segment's times (s),
    the angle (deg), its 1-σ (deg, or None), the gyro-integrated angle (deg, or None).
    """
    from cdgps_cli.core.checks import require_finite

    for name, v in (("survey_deg", survey_deg), ("start_s", start_s), ("end_s", end_s)):
        require_finite(v, name)
    cfg = _structure_config(states, "the static report")
    coef = parse_expression(angle, cfg.coord_names)
    chunked = hasattr(states, "series")             # StatesChunks: the angle's series, then the segment's P_ξ
    if chunked:
        t_all, a_all = _angle_series(states, coef)
    else:
        a_all = states.q @ coef
        t_all = states.time_s
    if start_s is None and end_s is None:
        t0, t1 = detect_rest(t_all, a_all)
        how = "detected"
    else:
        t0 = float(t_all[0]) if start_s is None else float(start_s)
        t1 = float(t_all[-1]) if end_s is None else float(end_s)
        how = "given"
        if t1 <= t0:
            raise CdgpsError(f"--end ({t1:g}) must be after --start ({t0:g})")
    sel = (t_all >= t0 - 1e-9) & (t_all <= t1 + 1e-9)
    if sel.sum() < 10:
        where = "the detected rest segment" if how == "detected" else "the segment given by --start/--end"
        raise CdgpsError(f"{where}, {t0:g}–{t1:g} s, has fewer than 10 estimates ({int(sel.sum())}; the states "
                         f"span {float(t_all[0]):g}–{float(t_all[-1]):g} s)")
    t = t_all[sel]
    a = np.degrees(a_all[sel])
    sig = None
    if getattr(states, "has_P_xi", False) if chunked else hasattr(states, "P_xi"):
        U = np.asarray(cfg.mode_shapes)
        v = coef @ U
        P_sel = _segment_covariance(states, sel) if chunked else states.P_xi[sel]
        sig = np.degrees(np.sqrt(np.einsum("i,nij,j->n", v, P_sel, v)))
    minutes = (t - t[0]) / 60.0
    p = np.polyfit(minutes, a, 1)
    resid = a - np.polyval(p, minutes)
    mean = float(np.mean(a))
    data = {"angle": angle, "coefficients": dict(zip(cfg.coord_names, coef.tolist())), "segment": how,
            "start_s": float(t[0]), "end_s": float(t[-1]), "samples": int(sel.sum()),
            "mean_deg": mean, "survey_deg": survey_deg,
            "error_deg": None if survey_deg is None else mean - survey_deg,
            "noise_rms_deg": float(np.std(resid)), "drift_deg_per_min": float(p[0]),
            "estimated_sigma_deg": None if sig is None else float(np.mean(sig)),
            "gyro": None, "gyro_drift_deg_per_min": None, "gyro_noise_rms_deg": None,
            "config": cfg.name, "states": str(states.path)}
    from cdgps_cli.estimation.rest import static_mode_coverage

    data["static_mode"] = static_mode_coverage(getattr(states, "metadata", {}) or {}, t)
    g_angle = None
    if run is not None and len(run.gyro):
        G = gyro_matrix(cfg)
        names = list(cfg.gyro_names)
        if gyro:
            if gyro not in names:
                raise CdgpsError(f"--gyro-name {gyro!r} is not a gyro of the config ({', '.join(names)})")
            use = [names.index(gyro)]
        else:
            use = [i for i in range(len(names)) if np.allclose(G[i], coef, atol=1e-9)]
        if use:
            gt, gr, gnames = _gyro_table(run)
            cols = [gnames.index(names[i]) for i in use if names[i] in gnames]
            if cols:
                rate = np.interp(t, gt, gr[:, cols].mean(axis=1))
                inc = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
                g_angle = a[0] + np.degrees(inc)          # initialized from GPS
                pg = np.polyfit(minutes, g_angle, 1)
                data.update(gyro=[names[i] for i in use], gyro_drift_deg_per_min=float(pg[0]),
                            gyro_noise_rms_deg=float(np.std(g_angle - np.polyval(pg, minutes))),
                            gyro_minus_gps_end_deg=float(g_angle[-1] - a[-1]))
    return data, t, a, sig, g_angle


def static_report(states, run, angle: str, survey_deg: float | None, out_dir: str | Path,
                  start_s: float | None = None, end_s: float | None = None, gyro: str | None = None,
                  date: str | None = None) -> dict:
    """The static sensor test (1998 paper Sec. VI.A, Fig. 7) on the rest segment.

    ``date`` is the report's date (``--date``; see :mod:`cdgps_cli.io.provenance` for the default)."""
    data, t, a, sig, g_angle = static_statistics(states, run, angle, survey_deg, start_s, end_s, gyro)
    how, mean = data["segment"], data["mean_deg"]
    data["provenance"] = report_provenance(
        "cdgps report static", {"--angle": angle, "--survey-deg": survey_deg, "--start": start_s, "--end": end_s,
                                "--gyro": None if run is None else run.path, "--gyro-name": gyro, "--date": date},
        states, run, date)
    smoothed = {"true": True, "false": False}.get(getattr(states, "metadata", {}).get("smoothed"))
    plt = _mpl()
    fig = plot_static(t, a, sig, survey_deg, angle, g_angle, data["gyro"] or ())
    png = _png(fig)
    plt.close(fig)
    rows = [["mean (GPS)", f"{mean:.4f}°"], ["survey", "–" if survey_deg is None else f"{survey_deg:.4f}°"],
            ["error", _fmt(data["error_deg"]) + ("°" if data["error_deg"] is not None else "")],
            ["noise RMS (detrended)", f"{data['noise_rms_deg']:.4f}°"],
            ["estimated σ (mean over the segment)", _fmt(data["estimated_sigma_deg"]) + ("°" if sig is not None else "")],
            ["GPS drift", f"{data['drift_deg_per_min']:.4f}°/min"],
            ["gyro drift", "–" if data["gyro_drift_deg_per_min"] is None else f"{data['gyro_drift_deg_per_min']:.4f}°/min"],
            ["segment", f"{data['start_s']:.1f}–{data['end_s']:.1f} s ({how}, {data['samples']} samples)"]]
    no_gyro = "no gyro log given (--gyro)" if run is None else "none whose axis matches the angle"
    note = (f"Gyro(s): {', '.join(data['gyro']) if data['gyro'] else no_gyro}. Mean, noise and "
            f"drift are of the GPS estimate on the segment; noise RMS is the scatter about a straight-line fit "
            f"(drift = its slope), to compare with the estimated σ the estimator reports; gyro drift is the slope "
            f"of the gyro-integrated angle.")
    sm_line = data["static_mode"]["statement"]
    sm_warn = data["static_mode"]["active_fraction"] != 1.0        # not on the whole segment, or not known
    md = (f"# Static sensor test: `{angle}`\n\n" + (f"> **{sm_line}**\n\n" if sm_warn else f"{sm_line}\n\n")
          + f"{_md_table(rows, ['quantity', 'value'])}\n\n{note}\n")
    caps = {"static.png": _static_caption(data, smoothed, no_gyro)}
    sm_html = (f"<p class='bad'><strong>{html.escape(sm_line)}</strong></p>" if sm_warn
               else f"<p>{html.escape(sm_line)}</p>")
    with output_set(out_dir, replaces=STATIC_REPORT_FILES) as dest:
        _atomic_bytes(dest.path("static.png"), png)
        _write_report(dest, f"Static sensor test: {angle}", md, data,
                      [("Static mode", sm_html),
                       ("Result", _html_table(rows, ["quantity", "value"]) + f"<p class='note'>{html.escape(note)}</p>")],
                      {"static.png": png}, caps)
    return data


# ----------------------------------------------------------------------------- spectrum report

def _spectrum_captions(s: dict, cfg) -> dict[str, str]:
    st = s["settings"]
    welch = (f"Welch estimates: Hann window, {st['segments']} segments of {st['segment_s']:.0f} s, "
             f"{100 * st['overlap']:g} % overlap, resolution {st['resolution_hz']:.4f} Hz, {st['duration_s']:.0f} s of data.")
    marks = ("Dashed grey lines: the model's mode frequencies, labelled with the mode numbers of the table's # "
             "column (the key below the panels lists them in frequency order).")
    fm = max((m["model_hz"] for m in s["modes"]), default=0.0)
    if s["gyros"]:
        psd = (f"Power spectral densities (rad²/Hz, log-log) of the angle about each gyro's axis, as in the 1998 "
               f"paper's Fig. 8: from the GPS estimate (blue: the gyro's axis applied to the estimated coordinates) "
               f"and from the gyro (orange: the rate PSD divided by (2πf)²). {marks} Above the highest mode "
               f"({fm:g} Hz) the structure has no modelled motion and the curves part: each shows its own noise "
               f"(the gyro's rate noise, the estimator's attenuated measurement noise). {welch}")
    else:
        psd = (f"Power spectral densities (log-log) of the estimated coordinates, each in its unit²/Hz (no gyro "
               f"log was given). {marks} {welch}")
    fdd = (f"Frequency-domain decomposition: the three largest singular values of the cross-spectral matrix of "
           f"the estimated coordinates {', '.join(st['coordinates'])}, each standardized to unit variance. "
           f"Dashed grey: model mode frequencies (mode numbers as in the table); solid red: the frequency "
           f"identified for each seen mode. {welch}")
    return {"psd.png": psd, "fdd.png": fdd}


_SPECTRUM_NOTE = ("#: the mode's number in the config (for the testbed: Table 1 of the 1998 paper), as labelled in "
                  "the figures; rows in order of model frequency. GPS Hz and ζ (damping ratio): maximum-likelihood "
                  "single-mode fit to the modal filter's periodogram; σ: their 1-σ from the Fisher information. "
                  "gyro Hz: peak of the gyro-derived PSD within the search band (–: no peak there, or the mode is "
                  "not seen by any gyro). error %: GPS vs model frequency. MAC: FDD singular vector vs the model's "
                  "mode shape. seen: within {pct:g} % of the model and MAC ≥ {mac:g}.")


def spectrum_report(states, run, opt, out_dir: str | Path, date: str | None = None,
                    chunk_epochs: int = STATES_CHUNK_EPOCHS) -> dict:
    """The dynamic sensor test (Sec. VI.B): PSD figure and identified modes vs the model.

    ``date`` is the report's date (``--date``; see :mod:`cdgps_cli.io.provenance` for the default)."""
    opts = {"--gyro": None if run is None else run.path, **opt.command_line(), "--date": date}
    prov = report_provenance("cdgps report spectrum", opts, states, run, date)     # checks --date first
    prov["settings"] = opt.settings()
    with output_set(out_dir, replaces=SPECTRUM_REPORT_FILES) as dest:      # one set: spectra and report
        s = run_spectra(states, run, opt, out_dir, dest=dest, chunk_epochs=chunk_epochs)
        pngs = s["pngs"]
        rows = []
        modes = sorted(s["modes"], key=lambda m: (m["model_hz"], m["number"]))
        for m in modes:
            rows.append([m["number"], m["mode"], f"{m['model_hz']:.4f}", _fmt(m["gps_hz"]), _fmt(m.get("gps_hz_sigma")),
                         _fmt(m["gyro_hz"]), _fmt(m["error_pct"], "+.2f"), _fmt(m["damping"]), _fmt(m.get("damping_sigma")),
                         f"{m['model_damping']:.4f}", _fmt(m["mac"], ".2f"), "yes" if m["seen"] else "no"])
        header = ["#", "mode", "model Hz", "GPS Hz", "σ Hz", "gyro Hz", "error %", "ζ", "σ ζ", "model ζ", "MAC", "seen"]
        seen = sum(1 for m in s["modes"] if m["seen"])
        st = s["settings"]
        text = (f"{seen} of {len(s['modes'])} elastic modes identified within {opt.seen_pct:g}% of the model "
                f"(frequency and damping ratio ζ by a maximum-likelihood single-mode fit "
                f"to the modal filter's periodogram, with 1-σ uncertainties; FDD/PSD segment {st['segment_s']:.0f} s, "
                f"resolution {st['resolution_hz']:.4f} Hz; {st['duration_s']:.0f} s of data).")
        if not s["modes"]:                    # a GNSS random walk's states: the peaks are the spectrum's findings
            text = (f"The states' motion model has no modes (nothing to identify against); {len(s['peaks'])} spectral "
                    f"peak(s) below (FDD/PSD segment {st['segment_s']:.0f} s, resolution {st['resolution_hz']:.4f} Hz; "
                    f"{st['duration_s']:.0f} s of data).")
        note = _SPECTRUM_NOTE.format(pct=opt.seen_pct, mac=opt.min_mac)
        if not s["gyros"]:
            note += " No gyro log was given (--gyro), so the gyro column is empty."
        shared = {}
        for m in modes:
            if m["gyro_hz"] is not None:
                shared.setdefault((m["gyro"], round(m["gyro_hz"], 6)), []).append(str(m["number"]))
        shared = [f"modes {', '.join(v)} ({k[1]:.4f} Hz, gyro {k[0]})" for k, v in shared.items() if len(v) > 1]
        if shared:
            note += (" The gyro found one peak for " + "; ".join(shared) + ": these modes are closer together than "
                     "the search band, and the gyro column gives no separate frequency for each.")
        p_rows, p_header, p_text = _peak_rows(s["peaks"], st)
        md = (f"# Spectrum sensor test\n\n{text}\n\n{_md_table(rows, header)}\n\n{note}\n\n## Spectral peaks\n\n"
              f"{p_text}\n\n{_md_table(p_rows, p_header)}\n")
        data = {"modes": modes, "peaks": s["peaks"], "settings": st, "seen": seen, "summary": text, "provenance": prov}
        _write_report(dest, "Spectrum sensor test", md, data,
                      [("Identified modes", f"<p>{html.escape(text)}</p>" + _html_table(rows, header)
                        + f"<p class='note'>{html.escape(note)}</p>"),
                       ("Spectral peaks", f"<p>{html.escape(p_text)}</p>" + _html_table(p_rows, p_header))],
                      pngs, _spectrum_captions(s, _coordinate_model(states)))
    return data


def _peak_rows(peaks: list, settings: dict) -> tuple[list, list, str]:
    """(rows, header, words) of the spectrum report's table of spectral peaks (``peaks.json``'s ``peaks``)."""
    rows = []
    for p in peaks:
        amp, sigma, unit, fit = peak_amplitude(p)
        scale = 1e3 if unit == "mm" else 1.0
        rows.append([p["coordinate"], f"{p['frequency_hz']:.4f}", f"{amp:.3g}" if fit else "–", _fmt(sigma, ".2g"),
                     f"{p['amplitude_psd'] * scale:.3g}" if "amplitude_psd" in p else "–", unit, f"{p['ratio']:.0f}",
                     "yes" if p.get("steady", True) else "no"])
    header = ["coordinate", "Hz", "amplitude (fit)", "σ", "amplitude (PSD)", "unit", "× floor", "steady"]
    text = (f"{len(peaks)} peak(s) standing at least 10 times above the power law fitted to the spectrum around them, "
            f"whatever the motion model: the frequency from the Welch PSD (resolution {settings['resolution_hz']:.4f} Hz), "
            f"the amplitude from a least-squares sinusoid over the whole record ({settings['duration_s']:.0f} s) with its "
            f"1-σ, and from the PSD's main lobe; 'steady' no where the fit is under 3 σ (a resonance excited at random "
            f"or decaying, which no one sinusoid describes).") if peaks else \
        "No spectral peak stands 10 times above the spectrum around it."
    return rows, header, text
