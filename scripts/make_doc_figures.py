#!/usr/bin/env python3
"""Figures of docs/method.md, from the outputs of `make demo` (scripts/demo.sh).

Usage: scripts/make_doc_figures.py DEMO_DIR OUT_DIR   (scripts/make_doc_figures.sh runs the demo first)

Writes, deterministically (same demo outputs → same bytes):

* ``static.png``  — the static sensor test figure of ``cdgps report static`` (1998 Fig. 7 analogue);
* ``psd.png``, ``fdd.png`` — the spectrum report's figures (1998 Fig. 8 analogue; FDD);
* ``dof2_estimate.png`` — the 1995 two-hub model: batch window, then the EKF, estimate vs truth
  and the error with its ±3σ band (1995 Figs. 5–6 analogue).

The report figures are copied at a reduced width (900 px) so that the page stays light.
"""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.report.sensor_reports import _mpl  # noqa: E402  (the reports' plot settings)
from cdgps_cli.io.coordinate_columns import coordinate_table  # noqa: E402
from cdgps_cli.io.states import States  # noqa: E402

WIDTH_PX = 900


def _png(fig_or_path, out: Path) -> None:
    from PIL import Image

    if isinstance(fig_or_path, Path):
        im = Image.open(fig_or_path)
    else:
        buf = io.BytesIO()
        fig_or_path.savefig(buf, format="png", metadata={"Software": None})
        im = Image.open(io.BytesIO(buf.getvalue()))
    im = im.convert("RGB")
    if im.width > WIDTH_PX:
        im = im.resize((WIDTH_PX, round(im.height * WIDTH_PX / im.width)), Image.LANCZOS)
    im = im.quantize(colors=128, method=Image.MEDIANCUT, dither=Image.NONE)
    im.save(out, format="PNG", optimize=True)
    print(f"wrote {out} ({out.stat().st_size // 1024} KiB)")


def dof2_figure(states_mcap: Path, truth_dir: Path, init_end_s: float):
    plt = _mpl()
    st = States(states_mcap, diagnostics=False)
    truth, _ = coordinate_table(pd.read_csv(truth_dir / "truth.csv.xz"), st.cfg)   # bare or q1_m … names
    names = list(st.cfg.coord_names)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for i, n in enumerate(names):
        c = f"C{i}"
        ax1.plot(truth["time_s"], np.degrees(truth[n]), color="k", lw=0.7, alpha=0.6,
                 label="truth" if i == 0 else None)
        ax1.plot(st.time_s, np.degrees(st.q[:, i]), color=c, lw=1.0, label=f"{n} estimate")
        tq = np.interp(st.time_s, truth["time_s"], truth[n])
        err = np.degrees(st.q[:, i] - tq)
        s3 = 3 * np.degrees(st.sigma_q[:, i])
        ax2.fill_between(st.time_s, -s3, s3, color=c, alpha=0.15, lw=0)
        ax2.plot(st.time_s, err, color=c, lw=0.9, label=f"{n} error (band: ±3σ)")
    for ax in (ax1, ax2):
        ax.axvspan(0, init_end_s, color="0.85", zorder=0)
    ax1.text(init_end_s / 2, ax1.get_ylim()[1], "batch\nwindow", ha="center", va="top", fontsize=8)
    ax1.set_ylabel("angle [deg]")
    ax1.legend(fontsize=8, ncol=3, loc="lower right")
    ax1.set_title("1995 two-hub model: batch initialization on 2.4 s (20 epochs), then the EKF")
    ax2.set_ylabel("estimate − truth [deg]")
    ax2.set_xlabel("time [s]")
    ax2.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return fig


def main(demo: Path, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    _png(demo / "static" / "report" / "static.png", out / "static.png")
    _png(demo / "free" / "report" / "psd.png", out / "psd.png")
    _png(demo / "free" / "report" / "fdd.png", out / "fdd.png")
    fig = dof2_figure(demo / "dof2" / "states.mcap", ROOT / "data" / "teague-1995", 2.4)
    _png(fig, out / "dof2_estimate.png")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(Path(sys.argv[1]), Path(sys.argv[2]))
