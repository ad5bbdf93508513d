"""Figures of the run report: time histories with ±σ bands, NIS/NEES against χ² bounds, residuals
per channel, the MAC matrix and the mode shapes drawn on the structure.

Every time series is drawn from its envelope (:mod:`cdgps_cli.report.envelope`): the band of the
±1σ extremes per bin, shaded, under one line through the estimate's extremes per bin, so a day-long
record draws as fast as a minute.  Legends sit above the panels, outside the data; axis labels carry
units; sizes are for a printed A4 page (10 in wide at 110 dpi).
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.report.envelope import EnvelopeBins, envelope_line
from cdgps_cli.report.sensor_reports import _mpl

WIDTH_IN = 10.0
BAND = {"color": "tab:blue", "alpha": 0.22, "lw": 0}
LINE = {"color": "tab:blue", "lw": 0.8}


def _time_axis(t: np.ndarray) -> tuple[np.ndarray, str]:
    """Times from the record's first epoch in s, min or h (whichever keeps the tick labels short),
    and the axis label (a record on the GPS time scale would otherwise read 1.4×10⁹ s)."""
    t0 = float(np.nanmin(t)) if t.size else 0.0
    rel = t - t0
    what = "time" if t0 == 0 else "time from the first epoch"
    span = float(np.nanmax(rel)) if t.size else 0.0
    if span > 3 * 3600:
        return rel / 3600.0, f"{what} [h]"
    if span > 3 * 60:
        return rel / 60.0, f"{what} [min]"
    return rel, f"{what} [s]"


def _head(fig, height_in: float, title: str, handles, labels) -> float:
    """Title and legend in a strip above the panels (outside the data); returns the top of the
    panels' area as a figure fraction (for ``tight_layout(rect=…)``)."""
    fig.suptitle(title, fontsize=10, y=1 - 0.12 / height_in, va="top")
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, 1 - 0.36 / height_in))
    return 1 - 0.55 / height_in


def time_history(env: EnvelopeBins, names: list, units: list, title: str, has_band: bool, scale=None,
                 sigma_mean=None, cols: int = 2):
    """Small multiples, one panel per series: the ±1σ band (shaded) and the estimate (line), both
    as per-bin envelopes.  ``scale`` (n,) multiplies every value (e.g. to degrees or mm);
    ``sigma_mean`` (n,), in the plotted unit, is written above each panel."""
    plt = _mpl()
    n = len(names)
    cols = 1 if n == 1 else cols
    rows = int(np.ceil(n / cols))
    H = 0.9 + 1.55 * rows
    fig, axes = plt.subplots(rows, cols, figsize=(WIDTH_IN, H), squeeze=False, sharex=True)
    t, xlabel = _time_axis(env.centre_s())
    scale = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
    handles = []
    for i in range(n):
        ax = axes[i // cols][i % cols]
        band = None
        lo, hi = env.lo[:, i] * scale[i], env.hi[:, i] * scale[i]
        if has_band:
            band = ax.fill_between(t, env.band_lo[:, i] * scale[i], env.band_hi[:, i] * scale[i], **BAND)
        x, y = envelope_line(t, lo, hi)
        line, = ax.plot(x, y, **LINE)
        ax.set_ylabel(f"{names[i]} [{units[i]}]", fontsize=8)
        if sigma_mean is not None and np.isfinite(sigma_mean[i]):
            ax.set_title(f"mean 1σ {sigma_mean[i]:.3g} {units[i]}", loc="right", fontsize=7, color="0.35", pad=2)
        ax.tick_params(labelsize=7)
        if not handles:
            handles = [line] + ([band] if band is not None else [])
    for j in range(n, rows * cols):
        axes[j // cols][j % cols].axis("off")
    for ax in axes[-1]:
        ax.set_xlabel(xlabel)
    labels = ["estimate (min–max per bin)"] + (["±1σ band (extremes per bin)"] if has_band else [])
    top = _head(fig, H, title, handles, labels)
    fig.tight_layout(rect=(0, 0, 1, top))
    return fig


def chi2_history(env: EnvelopeBins, bounds: EnvelopeBins | None, ylabel: str, title: str, const_bounds=None):
    """A consistency statistic over time (log scale): its per-bin min–max (grey), per-bin mean
    (blue) and the 95 % χ² interval (dashed: per epoch from its dof, or ``const_bounds``)."""
    plt = _mpl()
    fig, ax = plt.subplots(figsize=(WIDTH_IN, 3.4))
    t, xlabel = _time_axis(env.centre_s())
    lo, hi = env.lo[:, 0], env.hi[:, 0]
    pos = np.isfinite(lo) & (hi > 0)
    floor = np.nanmin(lo[pos & (lo > 0)]) if np.any(pos & (lo > 0)) else 1e-3
    env_h = ax.fill_between(t, np.where(lo > 0, lo, floor), hi, color="0.75", lw=0, label="min–max per bin")
    m_h, = ax.plot(t, env.mean()[:, 0], color="tab:blue", lw=0.9, label="mean per bin")
    handles = [env_h, m_h]
    if bounds is not None:
        b_h, = ax.plot(t, bounds.lo[:, 0], color="tab:red", ls="--", lw=0.9, label="95 % χ² interval")
        ax.plot(t, bounds.hi[:, 1], color="tab:red", ls="--", lw=0.9)
        handles.append(b_h)
    if const_bounds is not None:
        b_h = ax.axhline(const_bounds[0], color="tab:red", ls="--", lw=0.9, label="95 % χ² interval")
        ax.axhline(const_bounds[1], color="tab:red", ls="--", lw=0.9)
        handles.append(b_h)
    ax.set_yscale("log")
    from matplotlib.ticker import FuncFormatter  # noqa: PLC0415

    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))     # 0.5, 1, 2 rather than 5×10⁻¹
    ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}" if f"{v:g}"[0] in "235" else ""))
    ax.tick_params(axis="y", which="minor", labelsize=7)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10, pad=22)
    ax.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=len(handles), fontsize=8,
              frameon=False)
    fig.tight_layout()
    return fig


def residual_figure(env: EnvelopeBins, rms_mm: np.ndarray, channels: list):
    """Left: RMS residual per channel over the record (mm); right: RMS per channel and time bin
    (colour, mm), channels in the same order."""
    plt = _mpl()
    n = len(channels)
    h = max(3.0, 0.16 * n + 1.2)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(WIDTH_IN, h), width_ratios=(1, 3), sharey=True)
    labels = [f"{a}/{x}" for a, x in channels]
    y = np.arange(n)
    a1.barh(y, rms_mm, color="tab:blue", height=0.7)
    a1.set_yticks(y, labels, fontsize=6 if n > 24 else 7)
    a1.invert_yaxis()
    a1.set_xlabel("RMS residual [mm]")
    a1.set_title("whole record", fontsize=9)
    t, xlabel = _time_axis(env.centre_s())
    rms_bins = np.ma.masked_invalid(np.sqrt(env.mean()).T)      # (channels, bins), mm; unused: blank
    edges = np.concatenate([[t[0]], 0.5 * (t[1:] + t[:-1]), [t[-1]]]) if t.size > 1 else np.array([t[0] - 0.5, t[0] + 0.5])
    vmax = float(np.percentile(rms_bins.compressed(), 99)) if rms_bins.count() else 1.0
    im = a2.pcolormesh(edges, np.arange(n + 1) - 0.5, rms_bins, cmap="viridis", vmin=0, vmax=max(vmax, 1e-6),
                       shading="flat", rasterized=True)
    a2.grid(False)
    a2.set_xlabel(xlabel)
    a2.set_title("RMS per time bin (white: channel not used)", fontsize=9)
    cb = fig.colorbar(im, ax=a2, pad=0.01)
    cb.set_label("RMS residual [mm]")
    fig.tight_layout()
    return fig


def extra_figure(envs: dict, units: dict):
    """The further arrays of a series (satellites, PDOP) over time: min–max per bin."""
    plt = _mpl()
    names = sorted(envs)
    fig, axes = plt.subplots(len(names), 1, figsize=(WIDTH_IN, 0.8 + 1.6 * len(names)), squeeze=False, sharex=True)
    for ax, name in zip(axes[:, 0], names):
        env = envs[name]
        t, xlabel = _time_axis(env.centre_s())
        for j in range(env.lo.shape[1]):
            x, y = envelope_line(t, env.lo[:, j], env.hi[:, j])
            ax.plot(x, y, lw=0.8)
        ax.set_ylabel(f"{name} [{units.get(name, '1')}]")
        finite = np.concatenate([env.lo[np.isfinite(env.lo)], env.hi[np.isfinite(env.hi)]])
        if finite.size and np.all(finite == np.round(finite)):          # counts: whole-number ticks
            from matplotlib.ticker import MaxNLocator  # noqa: PLC0415

            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
            ax.set_ylim(finite.min() - 0.6, finite.max() + 0.6)
    axes[-1, 0].set_xlabel(xlabel)
    fig.tight_layout()
    return fig


def mac_figure(mac: np.ndarray, row_labels: list, col_labels: list):
    """The MAC matrix as a grey-scale image with its values written in each cell."""
    plt = _mpl()
    r, c = mac.shape
    fig, ax = plt.subplots(figsize=(min(WIDTH_IN, 1.6 + 0.62 * c), 1.3 + 0.45 * r))
    im = ax.imshow(mac, cmap="Greys", vmin=0, vmax=1, aspect="auto")
    for i in range(r):
        for j in range(c):
            ax.text(j, i, f"{mac[i, j]:.2f}", ha="center", va="center", fontsize=7,
                    color="white" if mac[i, j] > 0.6 else "black")
    ax.set_xticks(range(c), col_labels, rotation=40, ha="right", fontsize=7)
    ax.set_yticks(range(r), row_labels, fontsize=7)
    ax.set_xlabel("model mode shape (config)")
    ax.set_ylabel("identified shape (FDD)")
    ax.grid(False)
    cb = fig.colorbar(im, ax=ax, pad=0.02)
    cb.set_label("MAC [1]")
    fig.tight_layout()
    return fig


def _view_axes(d: np.ndarray) -> tuple[int, int]:
    """The two lab axes along which the displacements ``d`` (P, 3) are largest, in axis order."""
    big = np.argsort(-np.abs(d).max(axis=0), kind="stable")[:2]
    return tuple(sorted(int(i) for i in big))


def mode_shape_figure(cfg, pts, shapes: list):
    """Each mode drawn on the structure: the sections' pivots (grey squares) joined to their points,
    the points' nominal positions (grey circles) and displaced by the
    mode (blue: the config's shape; orange: the identified one, when there is one), exaggerated so
    that the largest displacement is 12 % of the structure's size, in the view of the two lab axes
    the mode moves most along.  ``shapes``: list of (title, model q (n_q,), identified q or None)."""
    from cdgps_cli.model.kinematics import point_positions  # noqa: PLC0415

    plt = _mpl()
    n = len(shapes)
    cols = 3 if n > 2 else n
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(WIDTH_IN, 0.9 + 2.7 * rows), squeeze=False)
    p0 = point_positions(cfg, np.zeros((1, cfg.n_q)), pts.section, pts.position_m, pts.displacement)[0]
    size = float(np.max(np.ptp(p0, axis=0))) or 1.0
    handles = {}
    for k, (title, q_model, q_id) in enumerate(shapes):
        ax = axes[k // cols][k % cols]
        J = point_positions(cfg, np.zeros((1, cfg.n_q)), pts.section, pts.position_m, pts.displacement,
                            jacobian=True)[1][0]                     # (P, 3, n_q)
        d_m = J @ q_model
        ia, ib = _view_axes(d_m)
        g = 0.12 * size / max(float(np.abs(d_m).max()), 1e-12)
        for k, sec in enumerate(pts.section):                     # the structure: each point on its section's pivot
            if sec >= 0:
                c = cfg.sections[sec].pivot_m
                ax.plot([c[ia], p0[k, ia]], [c[ib], p0[k, ib]], color="0.8", lw=1.2, zorder=0)
        pivots = np.array([s.pivot_m for s in cfg.sections]).reshape(-1, 3)
        if pivots.size:
            handles["section pivot"] = ax.scatter(pivots[:, ia], pivots[:, ib], s=18, marker="s", color="0.75", zorder=1)
        handles["nominal"] = ax.scatter(p0[:, ia], p0[:, ib], s=14, facecolors="none", edgecolors="0.55", lw=0.8)
        dm = p0 + g * d_m
        handles["model shape (config)"] = ax.scatter(dm[:, ia], dm[:, ib], s=12, color="tab:blue")
        for a, b in zip(p0, dm):
            ax.plot([a[ia], b[ia]], [a[ib], b[ib]], color="tab:blue", lw=0.6)
        if q_id is not None:
            d_i = J @ q_id
            # the identified shape is scaled and signed to best match the model's (least squares)
            s = float(np.vdot(d_i.ravel(), d_m.ravel()) / max(np.vdot(d_i.ravel(), d_i.ravel()), 1e-300))
            di = p0 + g * s * d_i
            handles["identified shape (FDD)"] = ax.scatter(di[:, ia], di[:, ib], s=12, marker="x",
                                                           color="tab:orange", lw=1.0)
        ax.set_title(title, fontsize=8)
        ax.set_xlabel(f"{'xyz'[ia]} [m]", fontsize=7)
        ax.set_ylabel(f"{'xyz'[ib]} [m]", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_aspect("equal", adjustable="datalim")
    for j in range(n, rows * cols):
        axes[j // cols][j % cols].axis("off")
    top = _head(fig, 0.9 + 2.7 * rows, "Mode shapes on the structure", list(handles.values()), list(handles))
    fig.tight_layout(rect=(0, 0, 1, top))
    return fig
