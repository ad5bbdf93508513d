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

``multipath = "auto"`` fits σ, τ and the white part from the data: every epoch with at least :data:`MIN_FIT_DOF`
degrees of freedom is solved alone from its known DD phases (one position per epoch, every signal group), and the
residual DD series of each (group, reference, satellite) pair go to the pooled autocovariance fit of
:func:`cdgps_cli.measurement.multipath.fit_autocovariance` (a Gauss–Markov process plus white noise; Ljung–Box
detection).  The fit gives the correlated share f of the variance; the total is the SD phase variances times the
scale the data show (the single-epoch solutions' unit variance, whatever ``phase_noise`` says), so the white
variances become × (1 − f) and σ² = f × the mean SD variance of the fitted DDs' rows.  Where no time correlation is
detected the states are the white-noise ones, unchanged.  ``multipath = "model"`` takes σ and τ from the config and
leaves the white variances as they are.

A state is one arc of a (group, satellite) that forms DDs, and is taken again by a later arc once the process has
forgotten the earlier one (:data:`FORGET_TIME_CONSTANTS`), so the state count follows the satellites in view
(:func:`state_columns`).  With several INITs (one STATES over windows) each window has its own states, and a
satellite's state goes on over a seam (:func:`seam_transition`).  The smoother keeps the full covariance of every
epoch: memory grows with the state count.
"""

from __future__ import annotations

import numpy as np

__all__ = ["single_epoch_dd_residuals", "multipath_settings", "multipath_note", "state_columns", "column_occupants",
           "seam_transition", "OnColumns"]


#: the fewest degrees of freedom (DDs − 3) of an epoch whose single-epoch residuals enter the fit: with 3 DDs they
#: are 0 by construction, with 4 one number shared by all (a 45° mask left 941 of 1200 such epochs, τ fitted 20 s
#: instead of 57 s)
MIN_FIT_DOF = 2
#: a satellite's multipath state is given to another satellite only this many time constants after its last DD:
#: the Gauss–Markov process has forgotten it by then (correlation exp(−10) ≈ 5e-5), so the state count follows the
#: satellites in view, not every satellite of the record
FORGET_TIME_CONSTANTS = 10.0
#: the largest share of the phase variance given to the multipath states: the fit may find no white part at all
#: (non-negative least squares at its bound: the F9P's 15 s log, 99.7 %), but a carrier phase always has some, and a
#: DD covariance of zero cannot be factored; so the white σ stays at least 3 % of the total
MAX_CORRELATED_SHARE = 0.999


def _epoch_solutions(d, w: dict, blocks: list) -> tuple[np.ndarray, np.ndarray]:
    """Each epoch's displacement from its known DD phases alone (``blocks``: every signal group's weight blocks),
    (n_epochs, 3) m, and whether it was solved: at least :data:`MIN_FIT_DOF` degrees of freedom and full rank."""
    n_ep = d.t_label.size
    nmat, rhs = np.zeros((n_ep, 3, 3)), np.zeros((n_ep, 3))
    n_dd = np.zeros(n_ep, dtype=np.int64)
    for rows, p in blocks:
        gk, rk = w["g"][rows], w["r_ph"][rows]
        ep = d.epoch[rows[:, 0]]
        pg = p @ gk
        nmat[ep] += np.swapaxes(gk, 1, 2) @ pg
        rhs[ep] += (np.swapaxes(pg, 1, 2) @ rk[:, :, None])[:, :, 0]
        n_dd[ep] += rows.shape[1] - 1
    solved = (n_dd - 3 >= MIN_FIT_DOF) & (np.linalg.matrix_rank(nmat) == 3)
    dx = np.zeros((n_ep, 3))
    dx[solved] = np.linalg.solve(nmat[solved], rhs[solved][:, :, None])[:, :, 0]
    return dx, solved


def single_epoch_dd_residuals(w: dict, blocks: list) -> tuple[np.ndarray, np.ndarray, list, float]:
    """The DD phase residuals of every epoch solved alone: each epoch's displacement from its known DD phases
    (``blocks``: the DD weight blocks of the rows of known ambiguity, every signal group, as
    :func:`~cdgps_cli.estimation.baseline.known_phase_blocks` gives them), then each DD's residual at it.  Epochs
    with fewer than :data:`MIN_FIT_DOF` degrees of freedom are left out.

    Returns (residual (n_epochs, C) m, NaN where the pair is not seen or the epoch is left out; the bias segment
    (n_epochs, C), all 0: the residuals carry no ambiguity; the C channel keys (group, reference satellite,
    satellite); the mean over those residuals of their two rows' SD variances' mean (var_i + var_ref)/2, m² (NaN:
    none))."""
    d = w["data"]
    n_ep = d.t_label.size
    dx, solved = _epoch_solutions(d, w, blocks)
    group = getattr(d, "group", None)
    var = np.asarray(w["var_ph"], dtype=np.float64)
    keys, vals, eps, pair_var = [], [], [], []
    for rows, _ in blocks:
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
        pair_var.append((0.5 * (var[rows[:, 1:]] + var[rows[:, :1]])).ravel())
    if not keys or not sum(k.shape[0] for k in keys):
        return np.full((n_ep, 0), np.nan), np.zeros((n_ep, 0), dtype=np.int64), [], float("nan")
    uniq, col = np.unique(np.concatenate(keys), axis=0, return_inverse=True)
    resid = np.full((n_ep, uniq.shape[0]), np.nan)
    resid[np.concatenate(eps), col.ravel()] = np.concatenate(vals)
    return (resid, np.zeros(resid.shape, dtype=np.int64), [tuple(int(v) for v in k) for k in uniq],
            float(np.mean(np.concatenate(pair_var))))


def multipath_settings(cfg, w: dict, blocks: list, data_factor: float = 1.0) -> dict | None:
    """The multipath states of one rover's window under ``cfg`` (a :class:`~cdgps_cli.config.structure.GnssConfig`;
    ``w`` its baseline work, ``blocks`` the DD weight blocks of its rows of known ambiguity): None with ``multipath = "off"``; else a dict
    (JSON-ready) with ``mode``, and when states are added ``sigma_m``, ``time_constant_s`` and ``white_factor`` (what
    the white phase variances are multiplied by); with ``"auto"`` also the fit (``fit``: what
    :func:`~cdgps_cli.measurement.multipath.fit_autocovariance` found) and ``detected`` (False: no states).

    ``"auto"`` splits the phase variance the data show: ``data_factor`` × ``w["var_ph"]`` (the unit variance of the
    single-epoch solutions when ``phase_noise = "model"`` left the variances as modelled; 1 when they are scaled
    already), its correlated share f from the fit: σ² = f × the mean SD variance of the fitted DDs' rows, the white
    variances × data_factor × (1 − f)."""
    if cfg.multipath == "off":
        return None
    if cfg.multipath == "model":
        return {"mode": "model", "sigma_m": float(cfg.multipath_sigma_m),
                "time_constant_s": float(cfg.multipath_time_constant_s), "white_factor": 1.0}
    from cdgps_cli.measurement.multipath import fit_autocovariance  # noqa: PLC0415

    resid, seg, keys, mean_var = single_epoch_dd_residuals(w, blocks)
    fit = fit_autocovariance(resid, seg, float(w["data"].interval_s)) if keys else None
    if fit is None or not fit["detected"]:
        why = "no DD series long enough" if fit is None else "no time correlation detected (Ljung-Box)"
        return {"mode": "auto", "detected": False, "why": why, **({"fit": _fit_echo(fit)} if fit else {})}
    v_mp, v_w = fit["raw_sigma_m"] ** 2, fit["white_sigma_m"] ** 2
    share = min(v_mp / (v_mp + v_w), MAX_CORRELATED_SHARE)
    total = float(data_factor) * mean_var
    return {"mode": "auto", "detected": True, "sigma_m": float(np.sqrt(share * total)),
            "time_constant_s": float(fit["time_constant_s"]), "white_factor": float(data_factor * (1.0 - share)),
            "correlated_share": float(share), "sd_phase_sigma_m": float(np.sqrt(total)),
            "data_factor": float(data_factor), "fit": _fit_echo(fit)}


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


def state_columns(d, use: np.ndarray, tau_s: float) -> tuple[np.ndarray, int]:
    """Each SD row's multipath state: one per arc of a (signal group, satellite) among the rows ``use`` that form a DD
    (another usable row of the group at the epoch), an arc ending where the satellite's DDs stop for more than
    :data:`FORGET_TIME_CONSTANTS` × ``tau_s``; a state is taken again by a later arc once that long has passed after
    its arc (the earliest free one; else a new state).  Returns (column (N,) int, −1 for the other rows; the number
    of states: the most arcs at once, not every satellite of the record)."""
    group = getattr(d, "group", None)
    g = np.zeros(d.sat.size, dtype=np.int64) if group is None else np.asarray(group, dtype=np.int64)
    n_groups = int(g.max(initial=0)) + 1
    count = np.zeros((d.t_label.size, n_groups), dtype=np.int64)
    np.add.at(count, (d.epoch[use], g[use]), 1)
    in_dd = use & (count[d.epoch, g] >= 2)
    key = g * (int(d.sat.max(initial=0)) + 1) + d.sat
    t = np.asarray(d.t_label, dtype=np.float64)[d.epoch]
    gap = FORGET_TIME_CONSTANTS * float(tau_s)
    arcs = []                                        # (start, end, rows)
    for k in np.unique(key[in_dd]):
        rows = np.flatnonzero(in_dd & (key == k))
        rows = rows[np.argsort(t[rows], kind="stable")]
        cut = np.flatnonzero(np.diff(t[rows]) > gap) + 1
        arcs += [(float(t[r[0]]), float(t[r[-1]]), r) for r in np.split(rows, cut)]
    col = np.full(d.sat.size, -1, dtype=np.int64)
    free_at = []                                     # per state: when its last arc's process is forgotten
    for start, end, rows in sorted(arcs, key=lambda a: (a[0], int(a[2][0]))):
        ready = [c for c, f in enumerate(free_at) if f <= start]
        c = min(ready, key=lambda c: (free_at[c], c)) if ready else len(free_at)
        if c == len(free_at):
            free_at.append(0.0)
        free_at[c] = end + gap
        col[rows] = c
    return col, len(free_at)


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


def column_occupants(d, col: np.ndarray, n: int) -> tuple[list, list]:
    """Which (signal, satellite) each of the ``n`` states holds first and last in the window (``col``:
    :func:`state_columns`' rows → states), named so that another window's states can be matched to them (a window's
    satellite and group indices are its own): two lists of ``(signal, satellite name)``."""
    names = list(getattr(d, "group_names", ("",)) or ("",))
    g = getattr(d, "group", None)
    first, last = [None] * n, [None] * n
    rows = np.flatnonzero(col >= 0)
    rows = rows[np.argsort(d.epoch[rows], kind="stable")]
    for r in rows:                      # (in time order: the last write of a state is its last occupant)
        key = (names[int(g[r])] if g is not None else names[0], str(d.sat_names[int(d.sat[r])]))
        c = int(col[r])
        if first[c] is None:
            first[c] = key
        last[c] = key
    return first, last


def seam_transition(dyn, n_dyn: int, prev_last: list, next_first: list, n_prev: int, dt_s: float):
    """(A (n_next, n_prev), Q (n_next, n_next)) from the last epoch of a window (its ``n_prev`` states: ``n_dyn`` of
    the rover, then multipath states last held by ``prev_last``) to the first of the next (dynamics ``dyn`` over
    ``dt_s``; multipath states first held by ``next_first``, none without them): the rover's own transition; a
    multipath state of a (signal, satellite) the previous window held goes on as its Gauss–Markov process, any other
    starts from its stationary prior."""
    A_full, _, Q_full = dyn.transition(float(dt_s))
    n_next = A_full.shape[0]
    A, Q = np.zeros((n_next, n_prev)), np.zeros((n_next, n_next))
    A[:n_dyn, :n_dyn], Q[:n_dyn, :n_dyn] = A_full[:n_dyn, :n_dyn], Q_full[:n_dyn, :n_dyn]
    held = {k: n_dyn + i for i, k in enumerate(prev_last) if k is not None}
    for j, key in enumerate(next_first):
        c = n_dyn + j
        if key in held:
            A[c, held[key]], Q[c, c] = A_full[c, c], Q_full[c, c]
        else:
            Q[c, c] = dyn.sigma**2
    return A, Q
