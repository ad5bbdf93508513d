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

from .atomic import write_bytes_atomic
from .errors import CdgpsError
from .expressions import parse_expression
from .kinematics import gyro_matrix


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


def _save_fig(fig, path: Path) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    data = buf.getvalue()
    _atomic_bytes(path, data)
    return data


def _out_dir(out: str | Path) -> Path:
    p = Path(out)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot create output directory: {exc.strerror}") from None
    return p


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
    g = run.gyro
    if g is None or len(g) == 0:
        return np.zeros(0), np.zeros((0, 0)), []
    names = [n for n in run.cfg.gyro_names if n in set(g["gyro"])]
    wide = g.pivot_table(index="time_s", columns="gyro", values="rate_rad_s")
    wide = wide[names].interpolate(limit_direction="both")
    return wide.index.to_numpy(dtype=float), wide.to_numpy(dtype=float), names


# ----------------------------------------------------------------------------- spectra

def run_spectra(states, run, opt, out_dir: str | Path) -> dict:
    """Compute spectra and write psd.csv, peaks.json, psd.png, fdd.png into ``out_dir``."""
    from .spectra import compute_spectra

    cfg = states.cfg
    gt, gr, gnames = (np.zeros(0), None, [])
    if run is not None:
        if run.cfg.sha256 != cfg.sha256:
            raise CdgpsError("the gyro RUN.mcap was ingested with a different structure config than the states")
        gt, gr, gnames = _gyro_table(run)
        if len(gnames) != len(cfg.gyro_names):
            gr = None if not gnames else gr
    res = compute_spectra(cfg, states.time_s, states.q, gt if gr is not None else None, gr, opt)
    out = _out_dir(out_dir)
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
    _atomic_bytes(out / "psd.csv", float_csv(df, "%.7g").encode())
    peaks = _json_clean({"modes": res["modes"], "settings": res["settings"], "states": str(states.path),
                         "config": cfg.name, "config_sha256": cfg.sha256, "gyros": gnames})
    _atomic_bytes(out / "peaks.json", (json.dumps(peaks, indent=2) + "\n").encode())
    plt = _mpl()
    pngs = {}
    for name, fig in (("psd.png", plot_psd(res, cfg, gnames)), ("fdd.png", plot_fdd(res, cfg))):
        pngs[name] = _save_fig(fig, out / name)
        plt.close(fig)
    return {"out_dir": str(out), "files": ["psd.csv", "peaks.json", *pngs], "modes": peaks["modes"],
            "settings": peaks["settings"], "pngs": pngs, "gyros": gnames}


def _mark_modes(ax, res, cfg, label=True):
    """Model frequencies as dashed lines with short staggered labels (mode numbers of the config)."""
    order = {n: i + 1 for i, n in enumerate(cfg.mode_names)}
    lo, hi = ax.get_ylim()
    logy = ax.get_yscale() == "log"
    for k, m in enumerate(sorted(res["modes"], key=lambda m: m["model_hz"])):
        ax.axvline(m["model_hz"], color="0.5", ls="--", lw=0.7, zorder=0)
        if label:
            frac = 0.97 - 0.07 * (k % 3)
            y = lo * (hi / lo) ** frac if logy else lo + (hi - lo) * frac
            ax.text(m["model_hz"], y, str(order[m["mode"]]), ha="center", va="top", fontsize=7, color="0.3",
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "0.7", "lw": 0.5})


def _mode_key(cfg, res) -> str:
    order = {n: i + 1 for i, n in enumerate(cfg.mode_names)}
    return "model modes: " + ", ".join(f"{order[m['mode']]} {m['mode']} ({m['model_hz']:g} Hz)" for m in res["modes"])


def _plot_index(f: np.ndarray, fmin: float, fmax: float, points: int = 2000) -> np.ndarray:
    """Indices of ~``points`` log-spaced frequencies in [fmin, fmax] (plots only; data files keep all)."""
    sel = np.flatnonzero((f >= fmin) & (f <= fmax))
    if sel.size <= points:
        return sel
    want = np.geomspace(f[sel[0]], f[sel[-1]], points)
    return np.unique(sel[0] + np.searchsorted(f[sel], want).clip(0, sel.size - 1))


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
            if i == 0:
                ax.legend(loc="lower left", fontsize=7)
        for j in range(n, rows * cols):
            axes[j // cols][j % cols].axis("off")
        for ax in axes[-1]:
            ax.set_xlabel("frequency [Hz]")
        fig.suptitle(f"{cfg.name}: GPS- and gyro-based spectra (dashed: model mode frequencies)", fontsize=10)
        fig.text(0.5, 0.005, _mode_key(cfg, res), ha="center", va="bottom", fontsize=7, wrap=True)
    else:
        fig, ax = plt.subplots(figsize=(10, 4.5))
        for k, v in res["psd"].items():
            if k.startswith("gps_q") or (k.startswith("gps_") and k[4:] in cfg.coord_names):
                name = k[4:]
                ax.loglog(f[sel], v[sel], lw=0.9, label=f"{name} [{cfg.coord_unit(name)}²/Hz]")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("PSD [unit²/Hz]")
        _mark_modes(ax, res, cfg)
        ax.legend(fontsize=7, ncol=2, loc="lower left")
        ax.set_title(f"{cfg.name}: PSDs of the estimated coordinates (dashed: model modes)")
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
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("singular value [1/Hz, standardized]")
    ax.set_title("Frequency-domain decomposition of the cross-spectral matrix (dashed: model, red: identified)")
    ax.legend(fontsize=7, loc="lower left")
    fig.text(0.5, 0.005, _mode_key(cfg, res), ha="center", va="bottom", fontsize=7, wrap=True)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return fig


# ----------------------------------------------------------------------------- HTML / markdown

_CSS = """body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1000px;margin:2em auto;
padding:0 1em;color:#222}table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;
text-align:right}th{background:#f4f4f4}td:first-child,th:first-child{text-align:left}img{max-width:100%}
.ok{color:#17692b}.bad{color:#b00020}code{background:#f4f4f4;padding:1px 4px}"""


def _html_page(title: str, sections: list[tuple[str, str]], figures: dict[str, bytes]) -> str:
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"]
    for head, body in sections:
        parts.append(f"<h2>{html.escape(head)}</h2>{body}")
    for name, data in figures.items():
        b64 = base64.b64encode(data).decode()
        parts.append(f"<figure><img alt='{html.escape(name)}' src='data:image/png;base64,{b64}'>"
                     f"<figcaption>{html.escape(name)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _html_table(rows: list[list], header: list[str]) -> str:
    out = ["<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
    for r in rows:
        out.append("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in r) + "</tr>")
    return "".join(out) + "</table>"


def _md_table(rows: list[list], header: list[str]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


def _fmt(v, spec=".4f"):
    return "–" if v is None else format(v, spec)


def _write_report(out: Path, title: str, md: str, data: dict, sections, figures) -> None:
    _atomic_bytes(out / "report.md", md.encode())
    _atomic_bytes(out / "report.json", (json.dumps(_json_clean(data), indent=2) + "\n").encode())
    _atomic_bytes(out / "report.html", _html_page(title, sections, figures).encode())


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


def static_report(states, run, angle: str, survey_deg: float | None, out_dir: str | Path,
                  start_s: float | None = None, end_s: float | None = None, gyro: str | None = None) -> dict:
    """The static sensor test (1998 paper Sec. VI.A, Fig. 7) on the rest segment."""
    cfg = states.cfg
    coef = parse_expression(angle, cfg.coord_names)
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
        raise CdgpsError(f"the segment {t0:g}–{t1:g} s has fewer than 10 estimates")
    t = t_all[sel]
    a = np.degrees(a_all[sel])
    sig = None
    if hasattr(states, "P_xi"):
        U = np.asarray(cfg.mode_shapes)
        v = coef @ U
        sig = np.degrees(np.sqrt(np.einsum("i,nij,j->n", v, states.P_xi[sel], v)))
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
    out = _out_dir(out_dir)
    plt = _mpl()
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    ax1.plot(t, a, lw=0.9, label="GPS estimate")
    if g_angle is not None:
        ax1.plot(t, g_angle, lw=0.9, label="gyro (integrated, initialized by GPS)")
    if survey_deg is not None:
        ax1.axhline(survey_deg, color="k", ls="--", lw=0.8, label=f"survey {survey_deg:g}°")
    ax1.set_ylabel(f"{angle} [deg]")
    ax1.legend(fontsize=8)
    ax1.set_title(f"Static sensor test: {angle} on {t[0]:.1f}–{t[-1]:.1f} s")
    if g_angle is not None:
        ax2.plot(t, g_angle - a, lw=0.9, color="tab:purple")
        ax2.set_ylabel("gyro − GPS [deg]")
    else:
        ax2.plot(t, resid, lw=0.9, color="tab:purple")
        ax2.set_ylabel("GPS − linear fit [deg]")
    ax2.set_xlabel("time [s]")
    fig.tight_layout()
    png = _save_fig(fig, out / "static.png")
    plt.close(fig)
    rows = [["mean (GPS)", f"{mean:.4f}°"], ["survey", "–" if survey_deg is None else f"{survey_deg:.4f}°"],
            ["error", _fmt(data["error_deg"]) + ("°" if data["error_deg"] is not None else "")],
            ["noise RMS (detrended)", f"{data['noise_rms_deg']:.4f}°"],
            ["GPS drift", f"{data['drift_deg_per_min']:.4f}°/min"],
            ["gyro drift", "–" if data["gyro_drift_deg_per_min"] is None else f"{data['gyro_drift_deg_per_min']:.4f}°/min"],
            ["segment", f"{data['start_s']:.1f}–{data['end_s']:.1f} s ({how}, {data['samples']} samples)"]]
    md = (f"# Static sensor test: `{angle}`\n\n{_md_table(rows, ['quantity', 'value'])}\n\n"
          f"Gyro(s): {', '.join(data['gyro']) if data['gyro'] else 'none matching the angle'}.\n\n![static](static.png)\n")
    _write_report(out, f"Static sensor test: {angle}", md, data,
                  [("Result", _html_table(rows, ["quantity", "value"]))], {"static.png": png})
    return data


# ----------------------------------------------------------------------------- spectrum report

def spectrum_report(states, run, opt, out_dir: str | Path) -> dict:
    """The dynamic sensor test (Sec. VI.B): PSD figure and identified modes vs the model."""
    s = run_spectra(states, run, opt, out_dir)        # validates and computes before creating out_dir
    out = Path(out_dir)
    pngs = s["pngs"]
    rows = []
    for m in s["modes"]:
        rows.append([m["mode"], f"{m['model_hz']:.4f}", _fmt(m["gps_hz"]), _fmt(m.get("gps_hz_sigma")),
                     _fmt(m["gyro_hz"]), _fmt(m["error_pct"], "+.2f"), _fmt(m["damping"]), _fmt(m.get("damping_sigma")),
                     f"{m['model_damping']:.4f}", _fmt(m["mac"], ".2f"), "yes" if m["seen"] else "no"])
    header = ["mode", "model Hz", "GPS Hz", "σ Hz", "gyro Hz", "error %", "damping", "σ damping", "model damping", "MAC", "seen"]
    seen = sum(1 for m in s["modes"] if m["seen"])
    st = s["settings"]
    text = (f"{seen} of {len(s['modes'])} elastic modes identified within {opt.seen_pct:g}% of the model "
            f"(frequency and damping by a maximum-likelihood single-mode fit "
            f"to the modal filter's periodogram, σ = 1-σ; FDD/PSD segment {st['segment_s']:.0f} s, resolution "
            f"{st['resolution_hz']:.4f} Hz; {st['duration_s']:.0f} s of data).")
    md = (f"# Spectrum sensor test\n\n{text}\n\n{_md_table(rows, header)}\n\n![psd](psd.png)\n\n![fdd](fdd.png)\n")
    data = {"modes": s["modes"], "settings": st, "seen": seen, "summary": text}
    _write_report(out, "Spectrum sensor test", md, data,
                  [("Identified modes", f"<p>{html.escape(text)}</p>" + _html_table(rows, header))], pngs)
    return data
