"""Poles of a discrete system in the z and s planes, with frequency, damping and settling time.

A discrete pole z maps to s = ln(z) / T (principal branch).  For s = −σ ± jω_d:
natural frequency ω_n = |s| (reported in Hz as ω_n / 2π), damping ratio ζ = σ / |s| (1 for a real
pole, not defined at s = 0) and 2 % settling time ln(1/0.02) / σ (infinite when σ ≤ 0).  Each pole
is attributed to the mode whose amplitude and rate carry the largest share of its eigenvector.
"""

from __future__ import annotations

import math

import numpy as np

from cdgps_cli.control.lqr import SETTLING_FRACTION


def pole_table(M, sample_period_s: float, mode_names) -> list[dict]:
    """One row per eigenvalue of M with Im z ≥ 0 (conjugates omitted), sorted by mode then frequency.

    Parameters
    ----------
    M : array_like, shape (2 n_m, 2 n_m)
        Discrete state matrix with state [ξ, ξ̇] (A or A − B K).
    sample_period_s : float
        Sample period, s.
    mode_names : sequence of str, length n_m

    Returns
    -------
    list of dict
        ``mode``, ``z_re``, ``z_im``, ``z_abs``, ``s_re_1_s``, ``s_im_rad_s``, ``frequency_hz``
        (natural), ``damping_ratio`` (None for s = 0), ``settling_time_s`` (None when not decaying).
    """
    w, V = np.linalg.eig(np.asarray(M, float))
    nm = len(mode_names)
    rows = []
    for z, v in zip(w, V.T):
        if z.imag < -1e-12:
            continue
        share = np.abs(v[:nm]) ** 2 + np.abs(v[nm:]) ** 2
        rows.append(_pole_row(complex(z), sample_period_s, mode_names[int(np.argmax(share))]))
    order = {n: i for i, n in enumerate(mode_names)}
    rows.sort(key=lambda r: (order[r["mode"]], r["frequency_hz"], r["z_re"]))
    return rows


def _pole_row(z: complex, T: float, mode: str) -> dict:
    s = complex(np.log(z)) / T if z != 0 else complex(-math.inf, 0.0)
    wn = abs(s)
    sigma = -s.real
    return {
        "mode": mode,
        "z_re": z.real, "z_im": abs(z.imag), "z_abs": abs(z),
        "s_re_1_s": s.real, "s_im_rad_s": abs(s.imag),
        "frequency_hz": wn / (2 * math.pi),
        "damping_ratio": (sigma / wn) if wn > 0 else None,
        "settling_time_s": (math.log(1.0 / SETTLING_FRACTION) / sigma) if sigma > 0 else None,
    }


def slowest_settling_by_mode(rows: list[dict]) -> dict:
    """Longest 2 % settling time per mode, s (None when a pole of the mode does not decay)."""
    out: dict = {}
    for r in rows:
        t = r["settling_time_s"]
        prev = out.get(r["mode"], 0.0)
        out[r["mode"]] = None if (t is None or prev is None) else max(prev, t)
    return out
