"""The HTML index of a `cdgps batch` campaign: one row per session, mode trends with 1σ, GNSS position trends with
1σ, failures.

Written next to batch.json (its numbers, as a page): ``OUTDIR/index.html`` and, when some session
identified modes, ``OUTDIR/trends.png`` (frequency and damping ratio of each mode against the
session time, error bars 1σ; a stiffness change shows as a frequency drift); when GNSS sessions estimated static
positions, ``OUTDIR/positions.png`` (each rover's E/N/U against the session time: a settlement shows as a drift).
"""

from __future__ import annotations

import html
from pathlib import Path

from cdgps_cli.io.atomic import write_atomic, write_bytes_atomic


def _f(v, fmt=".4f") -> str:
    return "–" if v is None else (v if isinstance(v, str) else format(v, fmt))


def write_index(summary: dict, out: Path) -> None:
    """Write ``out/index.html`` (and ``out/trends.png``) from the batch.json content ``summary``.

    A figure that cannot be drawn (values matplotlib refuses) is left out with its reason on the page:
    the index of a finished campaign is always written.
    """
    has_png = any(len(t["sessions"]) > 0 for t in summary["trends"])
    why = None
    if has_png:
        try:
            write_atomic(out / "trends.png", lambda p: _trend_figure(summary["trends"], p))
        except (ValueError, TypeError, OverflowError, RuntimeError) as exc:
            has_png, why = False, f"trends.png not drawn: {type(exc).__name__}: {exc}"
    positions = summary.get("position_trends") or []
    pos_png = any(len(t["sessions"]) > 0 for t in positions)
    if pos_png:
        try:
            write_atomic(out / "positions.png", lambda p: _position_figure(positions, p))
        except (ValueError, TypeError, OverflowError, RuntimeError) as exc:
            pos_png, why = False, (why + "; " if why else "") + f"positions.png not drawn: {type(exc).__name__}: {exc}"
    write_bytes_atomic(out / "index.html", _page(summary, has_png, out, why, pos_png).encode())


def _slope(fit, note) -> str:
    """A trend cell: slope ± σ, or why there is none (\"not enough spread: …\")."""
    if fit is None:
        return html.escape(note or "–")
    return f"{fit['slope_per_day']:+.3g} ± {fit['slope_sigma_per_day']:.2g}"


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and v == v and abs(v) != float("inf")


def _session_axis(trends: list) -> dict:
    """Session name → its x position: the session time as a datetime when every session has one (so
    sessions are spaced as recorded), else the session name (evenly spaced, manifest order)."""
    from datetime import datetime, timezone

    def utc(text: str) -> datetime:          # naive UTC, so that dates and times with a zone mix
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
        return t.astimezone(timezone.utc).replace(tzinfo=None) if t.tzinfo else t

    pts = [p for t in trends for p in t["sessions"]]
    try:
        return {p["session"]: utc(p["time"]) for p in pts}
    except (AttributeError, TypeError, ValueError):
        return {p["session"]: p["session"] for p in pts}


def _trend_figure(trends: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_f, ax_d) = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    when = _session_axis(trends)
    for t in trends:
        pts = [p for p in t["sessions"] if _finite(p["gps_hz"])]
        ax_f.errorbar([when[p["session"]] for p in pts], [p["gps_hz"] for p in pts],
                      yerr=[p["gps_hz_sigma"] if _finite(p["gps_hz_sigma"]) else 0 for p in pts], fmt="o-", capsize=3,
                      label=f"{t['mode']} (model {_f(t['model_hz'], '.3f')} Hz)")
        dp = [p for p in pts if _finite(p["damping"])]
        ax_d.errorbar([when[p["session"]] for p in dp], [p["damping"] for p in dp],
                      yerr=[p["damping_sigma"] if _finite(p["damping_sigma"]) else 0 for p in dp], fmt="o-", capsize=3)
    ax_f.set_ylabel("frequency (Hz)")
    ax_d.set_ylabel("damping ratio ζ")
    ax_d.set_xlabel("session time (UTC)")
    # beside the axes, not over the curves (the modes span the whole frequency axis)
    ax_f.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    ax_f.set_title("Identified modes across sessions (1σ error bars)")
    fig.autofmt_xdate()
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=90, metadata={"Software": None})
    plt.close(fig)


def _position_figure(trends: list, path: Path) -> None:
    """The GNSS rovers' static positions against the session time, one panel per axis (E, N, U), mm about each
    coordinate's first session, 1σ error bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    when = _session_axis(trends)
    axes = [c[-1] for c in dict.fromkeys(t["coordinate"] for t in trends)]
    axes = [a for a in "enu" if a in axes] or ["e"]
    fig, ax = plt.subplots(len(axes), 1, figsize=(11, 2.6 * len(axes) + 1), sharex=True, squeeze=False)
    for t in trends:
        pts = [p for p in t["sessions"] if _finite(p["value_m"])]
        if not pts or t["coordinate"][-1] not in axes:
            continue
        a = ax[axes.index(t["coordinate"][-1])][0]
        v0 = pts[0]["value_m"]
        a.errorbar([when[p["session"]] for p in pts], [(p["value_m"] - v0) * 1e3 for p in pts],
                   yerr=[p["sigma_m"] * 1e3 if _finite(p["sigma_m"]) else 0 for p in pts], fmt="o-", capsize=3,
                   label=t["rover"])
    for a, name in zip(ax[:, 0], axes):
        a.set_ylabel(f"{ {'e': 'east', 'n': 'north', 'u': 'up'}[name]} (mm)")
        a.grid(alpha=0.3)
    ax[0][0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    ax[0][0].set_title("Static positions across sessions, about each rover's first session (1σ error bars)")
    ax[-1][0].set_xlabel("session time (UTC)")
    fig.autofmt_xdate()
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=90, metadata={"Software": None})
    plt.close(fig)


def _plus_minus(v: float, sigma: float) -> str:
    """``v ± σ`` with both to the σ's second significant digit (``+416 ± 150``, ``+0.123 ± 0.023``)."""
    import math

    d = max(0, 1 - math.floor(math.log10(sigma))) if _finite(sigma) and sigma > 0 else 3
    return f"{v:+.{d}f} ± {sigma:.{d}f}"


def _position_cell(s: dict) -> str:
    """A GNSS session's static positions, mm ± 1σ, per rover (–: not a GNSS session)."""
    parts = []
    for r, v in (s.get("rovers") or {}).items():
        enu, sig = v.get("static_enu_m") or {}, v.get("static_sigma_m") or {}
        xs = [f"{c[-1].upper()} {_f(None if x is None else x * 1e3, '+.2f')}"
              + (f"±{_f(sig[c] * 1e3, '.2f')}" if _finite(sig.get(c)) else "") for c, x in enu.items()]
        parts.append(f"{html.escape(r)}: " + " ".join(xs))
    return "<br>".join(parts) or "–"


def _row(cells, tag="td") -> str:
    return "<tr>" + "".join(f"<{tag}>{c}</{tag}>" for c in cells) + "</tr>"


def _page(summary: dict, has_png: bool, out: Path, why: str | None = None, pos_png: bool = False) -> str:
    e = html.escape
    c = summary["counts"]
    rows = []
    for s in summary["sessions"]:
        rep = Path(s["folder"]) / "report" / "report.html"
        name = (f'<a href="{e(str(rep.relative_to(out)))}">{e(s["session"])}</a>' if rep.is_file() else e(s["session"]))
        seen = [m for m in s.get("modes", []) if m["seen"]]
        fixed = "–" if "integers_fixed" not in s else f"{s['integers_fixed']} of {s['integers']}"
        noise = None if s.get("noise_sigma_m") is None else s["noise_sigma_m"] * 1000
        modes = ", ".join(f"{e(m['mode'])} {_f(m['gps_hz'])}±{_f(m['gps_hz_sigma'])}" for m in seen) or "–"
        rows.append(_row([name, e(s["time"] or "–"), e(s["status"]), f"{s['elapsed_s']:.1f}", fixed,
                          _f(s.get("nis_per_dof"), ".3f"), _f(noise, ".2f"), modes, _position_cell(s),
                          e(s.get("error", ""))]))
    trend_rows = []
    for t in summary["trends"]:
        ft, dt = t["frequency_trend_hz"], t["damping_trend"]
        trend_rows.append(_row([e(t["mode"]), _f(t["model_hz"]), str(len(t["sessions"])),
                                _slope(ft, t.get("frequency_trend_hz_note")),
                                "–" if ft is None else f"{ft['chi2_per_dof']:.2f}",
                                _slope(dt, t.get("damping_trend_note"))]))
    positions = summary.get("position_trends") or []
    pos_rows = [_row([e(t["coordinate"]), str(len(t["sessions"])),
                      html.escape(t.get("trend_m_note") or "–") if t["trend_m"] is None else
                      _plus_minus(t["trend_m"]["slope_per_day"] * 1e3, t["trend_m"]["slope_sigma_per_day"] * 1e3),
                      "–" if t["trend_m"] is None else f"{t['trend_m']['chi2_per_dof']:.2f}"]) for t in positions]
    fail = "".join(f"<li><b>{e(f['session'])}</b>: <pre>{e(f['error'])}</pre></li>" for f in summary["failures"])
    mode_part = (f"""<p>Weighted least-squares line through each mode's frequency (and damping ratio) against the session time,
weights 1/σ²; the slope's σ is from those weights (χ²/dof ≫ 1: the scatter exceeds the stated σ).</p>
<table>{_row(['mode', 'model Hz', 'sessions', 'frequency slope (Hz/day)', 'χ²/dof', 'damping slope (1/day)'], 'th')}
{''.join(trend_rows)}</table>
{'<p><img src="trends.png" alt="mode trends"></p>' if has_png else ''}""" if trend_rows or not positions else
                 "<p>No session identified modes (GNSS displacement sessions: their positions' trends are below).</p>")
    pos_part = "" if not positions else f"""<h2>Position trends</h2>
<p>Weighted least-squares line through each GNSS rover's static position (its session's INIT and STATES), about the
nominal position of the rover's first session (a session of a run with another nominal is moved there), against
the session time, weights 1/σ²; the slope's σ is from those weights. χ²/dof ≫ 1: the sessions scatter more than their
σ say — the σ of a static solution does not hold errors correlated over minutes (multipath), which on a low-cost
receiver can move a session's position by centimetres.</p>
<table>{_row(['coordinate', 'sessions', 'slope (mm/day ± 1σ)', 'χ²/dof'], 'th')}{''.join(pos_rows)}</table>
{'<p><img src="positions.png" alt="static positions across sessions"></p>' if pos_png else ''}"""
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>cdgps batch: {e(Path(summary['manifest']).name)}</title>
<style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;
padding:3px 8px;font-size:13px}}pre{{white-space:pre-wrap;margin:0}}</style></head><body>
<h1>cdgps batch</h1>
<p>Manifest {e(summary['manifest'])}; {c['sessions']} sessions: {', '.join(f'{v} {e(k)}' for k, v in c.items() if k != 'sessions')};
{summary['workers']} workers, {summary['elapsed_s']:.1f} s ({e(summary['started'])} – {e(summary['finished'])}).
Numbers in <a href="batch.json">batch.json</a>.</p>
<h2>Sessions</h2>
<table>{_row(['session', 'time (UTC)', 'status', 'task time (s)', 'integers fixed', 'NIS/dof', 'noise σ (mm)',
              'modes identified (Hz ± 1σ)', 'static E/N/U from the nominal (mm ± 1σ)', 'error'], 'th')}{''.join(rows)}</table>
<h2>Mode trends</h2>
{mode_part}
{pos_part}{f'<p>{e(why)}</p>' if why else ''}
<h2>Failures</h2>
{f'<ul>{fail}</ul>' if fail else '<p>none</p>'}
</body></html>
"""
