"""Phase multipath in a moving rover's per-epoch states (``[gnss.displacement] multipath``).

A low-cost receiver's carrier-phase errors are not white: multipath from the antenna's surroundings changes with the
satellite's geometry over tens of seconds (the u-blox M8P pair's single-epoch DD residuals: autocorrelation 0.93 at
1 s, 0.32 at 60 s).  A random walk or constant-velocity filter that takes them as white follows them as motion and
reports a σ several times below its error.  Here each satellite's single-difference phase of each signal group
carries a first-order Gauss–Markov state m (metres)::

    m_{k+1} = a m_k + w_k,   a = exp(−Δt/τ),   w_k ~ N(0, σ²(1 − a²)),   m ~ N(0, σ²) when first seen

appended to the rover's states (:class:`~cdgps_cli.model.dynamics_models.WithGaussMarkov`), and a DD phase of
satellite i against the reference j sees m_i − m_j beside the displacement
(:class:`~cdgps_cli.measurement.dd_displacement.SatelliteDDDisplacement`'s ambiguity columns with λ = 1 m).

``multipath = "auto"`` fits σ, τ and the white part from the data: every epoch is solved alone from its known DD
phases (one position per epoch, every signal group), and the residual DD series of each (group, reference,
satellite) pair go to the pooled autocovariance fit of :func:`cdgps_cli.measurement.multipath.fit_autocovariance`
(a Gauss–Markov process plus white noise; Ljung–Box detection).  The fit gives the split of the variance into its
correlated share f_mp = σ_mp² / (σ_mp² + σ_w²); the total is the phase variances as the rover's states use them
(``phase_noise``), so the states' white variances are those × (1 − f_mp) and σ² = f_mp × their median.  Where no
time correlation is detected the states are the white-noise ones, unchanged.  ``multipath = "model"`` takes σ and τ
from the config and leaves the white variances as they are.

Cost: the state grows by one per satellite and signal group seen in the window (GPS L1 over an hour: ≈ 12–16), and
the smoother keeps the full covariance of every epoch; with several INITs (one STATES over windows) it is refused.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.estimation.baseline import known_phase_blocks

__all__ = ["single_epoch_dd_residuals", "multipath_settings", "multipath_note", "state_columns", "OnColumns"]


def single_epoch_dd_residuals(w: dict, use: np.ndarray) -> tuple[np.ndarray, np.ndarray, list]:
    """The DD phase residuals of every epoch solved alone: each epoch's displacement from its known DD phases (rows
    ``use``; every signal group, weighted as the solver weights them), then each DD's residual at it.

    Returns (residual (n_epochs, C) m, NaN where the pair is not seen or the epoch has no solution; the bias segment
    (n_epochs, C), all 0: the residuals carry no ambiguity; the C channel keys (group, reference satellite,
    satellite))."""
    d = w["data"]
    n_ep = d.t_label.size
    blocks, _ = known_phase_blocks(d, w["var_ph"], w["refs_ph"], w["blocks_ph"], use)
    nmat, rhs = np.zeros((n_ep, 3, 3)), np.zeros((n_ep, 3))
    for rows, p in blocks:
        gk, rk = w["g"][rows], w["r_ph"][rows]
        ep = d.epoch[rows[:, 0]]
        pg = p @ gk
        nmat[ep] += np.swapaxes(gk, 1, 2) @ pg
        rhs[ep] += (np.swapaxes(pg, 1, 2) @ rk[:, :, None])[:, :, 0]
    solved = np.linalg.matrix_rank(nmat) == 3
    dx = np.zeros((n_ep, 3))
    dx[solved] = np.linalg.solve(nmat[solved], rhs[solved][:, :, None])[:, :, 0]
    group = getattr(d, "group", None)
    keys, vals, eps = [], [], []
    for rows, p in blocks:
        ep = d.epoch[rows[:, 0]]
        ok = solved[ep]
        rows, ep = rows[ok], ep[ok]
        e = w["r_ph"][rows] - np.einsum("kic,kc->ki", w["g"][rows], dx[ep])
        # DDs against the block's first row: a pair keeps its identity while that row's satellite stays first
        others = rows[:, 1:].ravel()
        keys.append(np.stack([np.zeros(others.size, dtype=np.int64) if group is None else group[others],
                              np.repeat(d.sat[rows[:, 0]], rows.shape[1] - 1), d.sat[others]], axis=1))
        vals.append((e[:, 1:] - e[:, :1]).ravel())
        eps.append(np.repeat(ep, rows.shape[1] - 1))
    if not keys or not sum(k.shape[0] for k in keys):
        return np.full((n_ep, 0), np.nan), np.zeros((n_ep, 0), dtype=np.int64), []
    uniq, col = np.unique(np.concatenate(keys), axis=0, return_inverse=True)
    resid = np.full((n_ep, uniq.shape[0]), np.nan)
    resid[np.concatenate(eps), col.ravel()] = np.concatenate(vals)
    return resid, np.zeros(resid.shape, dtype=np.int64), [tuple(int(v) for v in k) for k in uniq]


def multipath_settings(cfg, w: dict, use: np.ndarray) -> dict | None:
    """The multipath states of one rover's window under ``cfg`` (a :class:`~cdgps_cli.config.structure.GnssConfig`;
    ``w`` its baseline work, ``use`` its rows of known ambiguity): None with ``multipath = "off"``; else a dict
    (JSON-ready) with ``mode``, and when states are added ``sigma_m``, ``time_constant_s`` and ``white_factor`` (what
    the white phase variances are multiplied by); with ``"auto"`` also the fit (``fit``: what
    :func:`~cdgps_cli.measurement.multipath.fit_autocovariance` found) and ``detected`` (False: no states)."""
    if cfg.multipath == "off":
        return None
    if cfg.multipath == "model":
        return {"mode": "model", "sigma_m": float(cfg.multipath_sigma_m),
                "time_constant_s": float(cfg.multipath_time_constant_s), "white_factor": 1.0}
    from cdgps_cli.measurement.multipath import fit_autocovariance  # noqa: PLC0415

    resid, seg, keys = single_epoch_dd_residuals(w, use)
    fit = fit_autocovariance(resid, seg, float(w["data"].interval_s)) if keys else None
    if fit is None or not fit["detected"]:
        why = "no DD series long enough" if fit is None else "no time correlation detected (Ljung-Box)"
        return {"mode": "auto", "detected": False, "why": why, **({"fit": _fit_echo(fit)} if fit else {})}
    v_mp, v_w = fit["raw_sigma_m"] ** 2, fit["white_sigma_m"] ** 2
    share = v_mp / (v_mp + v_w)
    var = np.asarray(w["var_ph"])[use]
    return {"mode": "auto", "detected": True, "sigma_m": float(np.sqrt(share * np.median(var))),
            "time_constant_s": float(fit["time_constant_s"]), "white_factor": float(1.0 - share),
            "correlated_share": float(share), "fit": _fit_echo(fit)}


def multipath_note(rover: str, mp: dict) -> str:
    """What the multipath states of a rover are (or why there are none), said in one line."""
    if "sigma_m" not in mp:
        return f"{rover}: multipath auto: no multipath states ({mp['why']}); the phase errors taken as white"
    src = ("fitted to the single-epoch DD phase residuals: " + f"{mp['correlated_share']:.0%} of their variance "
           f"correlated, the white phase variances × {mp['white_factor']:.3g}") if mp["mode"] == "auto" else "given"
    return (f"{rover}: multipath {mp['mode']}: a Gauss-Markov phase state per satellite and signal, sigma "
            f"{mp['sigma_m'] * 1e3:.2f} mm, tau {mp['time_constant_s']:.3g} s ({src})")


def _fit_echo(fit: dict) -> dict:
    """The fit's figures for the summary: DD σ of its two parts (m), τ (s), Ljung–Box, the channels' runs."""
    return {"dd_sigma_m": fit["raw_sigma_m"], "dd_white_sigma_m": fit["white_sigma_m"],
            "time_constant_s": fit["raw_time_constant_s"], "ljung_box_q": fit["ljung_box_q"],
            "ljung_box_limit": fit["ljung_box_limit"], "runs": fit["runs"]}


def state_columns(d, use: np.ndarray) -> tuple[np.ndarray, int]:
    """Each SD row's multipath state: one per (signal group, satellite) among the rows ``use``, numbered in that
    order; (column (N,) int, −1 for the other rows; the number of states)."""
    group = getattr(d, "group", None)
    g = np.zeros(d.sat.size, dtype=np.int64) if group is None else np.asarray(group, dtype=np.int64)
    key = g * (int(d.sat.max(initial=0)) + 1) + d.sat
    uniq, inv = np.unique(key[use], return_inverse=True)
    col = np.full(d.sat.size, -1, dtype=np.int64)
    col[use] = inv.ravel()
    return col, int(uniq.size)


class OnColumns:
    """A measurement model seen on columns ``cols`` of a larger state of ``n_state`` (e.g. the DDs on [δx, m] under
    constant velocity's [δx, v, m]): its rows as they are, H placed into those columns."""

    def __init__(self, model, cols: np.ndarray, n_state: int):
        self.model, self.cols, self.n_state = model, np.asarray(cols, dtype=np.int64), int(n_state)
        self.n_epochs, self.segment_keys = model.n_epochs, model.segment_keys

    def rows(self, k: int):
        return self.model.rows(k)

    def predict(self, x, rows):
        h, H = self.model.predict(np.asarray(x, dtype=float)[self.cols], rows)
        full = np.zeros((H.shape[0], self.n_state))
        full[:, self.cols] = H
        return h, full
