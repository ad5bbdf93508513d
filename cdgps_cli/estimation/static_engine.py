"""The static baseline on the one engine (issue 28 item 1): DD rows of
:class:`~cdgps_cli.measurement.dd_signals.DDGroupModel` (the one DD builder; its whole-run layout
:class:`~cdgps_cli.measurement.dd_signals.RunDDModel`, the same numbers), the static model through
:func:`~cdgps_cli.estimation.driver.drive` (:func:`static_filter`, the random-walk float).

State: rover offset from ``origin`` (3, m) and one SD ambiguity per lock arc (cycles; an arc is a
satellite's signal between slips and outages, :func:`arc_columns`), all sized up front.  With no process
noise the filter's final state is the batch least-squares solution with the same prior (the information adds up epoch by
epoch): :func:`static_least_squares` forms it from every epoch at once and is what :func:`static_baseline` solves
with (a day at 1 Hz: 0.9 s against the filter's 7 s); the filter and :func:`static_normal_equations` (the per-epoch
whitened rows at the answer) are its independent checks.
Options: :func:`options_from_baseline` maps BaselineOptions (refusing by name what the engine does
not implement).  ``baseline`` and GNSS ``init`` solve here through
:func:`~cdgps_cli.estimation.baseline.solve_static_baseline` (``engine=True``), which renders the result
(:func:`arc_table`, :func:`arc_integers`, the states) in its JSON forms.
"""

import math
from typing import NamedTuple

import numpy as np

from cdgps_cli.core import progress
from cdgps_cli.estimation.driver import EpochGrid, GridDynamics, RecordingSink, drive
from cdgps_cli.estimation.kalman import StepFilter, positive_definite
from cdgps_cli.config.options import (FIXED_PHASE_UNIT_VARIANCE_MAX, FIXED_PHASE_WINDOW_S,
                                      FIXED_PHASE_WINDOW_UNIT_VARIANCE_MAX, GNSS_DEFAULTS, GNSS_WEIGHTINGS, IONO_WEIGHTED_MIN_SIGMA_M,
                                      MOVING_ROVER_FLOAT_M, MULTI_GNSS_DEFAULTS, ORIGIN_MOVE_SIGMAS,
                                      RANDOM_WALK_MAX_RAISES, RANDOM_WALK_RAISE_FACTOR, UNCHECKED_FIX_NIS_MAX)
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.dd_signals import DDGroupModel, RunDDModel, epoch_groups, paired_sd_rows
from cdgps_cli.measurement.differencing import ambiguity_datum, ambiguity_segments
from cdgps_cli.measurement.base_interpolation import base_age_noise
from cdgps_cli.measurement.code_steps import code_clock_steps, without_code_steps  # noqa: F401 (code_clock_steps: API)
from cdgps_cli.measurement.epoch_fit import grouped_epoch_fit
from cdgps_cli.measurement.epoch_pairing import channel_index, pair_epochs
from cdgps_cli.measurement.slips import geometry_free_slips, slip_events, time_differenced_slips
from cdgps_cli.model.dynamics_models import Dynamics, Static, WithConstants
from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix


def arc_columns(rows, times_s=None, *, max_gap_s: float | None = None, n_pos: int = 3) -> np.ndarray:
    """State column (N,) of each SD row's ambiguity, numbered from ``n_pos`` in order of first appearance.

    One column per (satellite, signal) lock arc, cut by the batch solver's rule
    (:func:`~cdgps_cli.measurement.differencing.ambiguity_segments`, the one home of that rule and its
    default): a new arc at a slip flag or a half-cycle flag that comes or goes and, with ``times_s`` (n_ep,)
    the epochs' times (s), where the channel was missing from an epoch that has other rows (a satellite that
    sets and rises again, a tracking outage) or after a gap longer than ``max_gap_s`` (None: no limit; an
    epoch without any row cuts no arc).  Without ``times_s``: slips and half-cycle flags only.
    """
    n = rows["sats"].size
    if n == 0:
        return np.empty(0, dtype=np.int64)
    channel = channel_index(rows["sats"], rows["code"])
    if times_s is None:                    # rows in time order; no gap limit
        step = np.arange(n)
        seg, tab = ambiguity_segments(step, channel, rows["slip"], epoch_time_s=step.astype(float), max_gap_s=np.inf,
                                      half=rows.get("half"), own_outages=False)
    else:
        epoch = np.searchsorted(rows["ptr"], np.arange(n), side="right") - 1
        seg, tab = ambiguity_segments(epoch, channel, rows["slip"], epoch_time_s=times_s, max_gap_s=max_gap_s,
                                      half=rows.get("half"))
    first = np.full(tab["sat"].size, n, dtype=np.int64)
    np.minimum.at(first, seg, np.arange(n))
    rank = np.empty(first.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    return n_pos + rank[seg]


def _groups(rows, cols, k):
    """Epoch k's signal groups with their ambiguity columns (no ionosphere column)."""
    out = []
    for g in epoch_groups(rows, k):
        a, b = g["rows"]                          # the group's rows in the run's columns
        out.append(dict(g, amb_col=cols[a:b], iono_col=np.full(b - a, -1)))
    return out


def _model(rows, cols, base_xyz_m, origin_xyz_m, iono_cols=None):
    """The DD model of ``rows`` with ambiguity columns ``cols``: :class:`RunDDModel` (whole-block layout) when
    the rows carry :func:`paired_sd_rows`' group layout, else DDGroupModel over :func:`_groups` (the same rows);
    with ``iono_cols`` (N,) (:func:`iono_columns`) DDGroupModel with each row's SD ionosphere in that column."""
    if iono_cols is not None:
        def groups(k):
            return [dict(g, iono_col=iono_cols[g["rows"][0]:g["rows"][1]]) for g in _groups(rows, cols, k)]
        return DDGroupModel(groups, base_xyz_m, origin_xyz_m)
    if rows.get("groups") is not None:
        return RunDDModel(rows, cols, base_xyz_m, origin_xyz_m)
    return DDGroupModel(lambda k: _groups(rows, cols, k), base_xyz_m, origin_xyz_m)


def iono_columns(rows, n_state: int) -> tuple[np.ndarray, int]:
    """Each SD row's ionosphere column (N,): one SD slant ionosphere (m at L1, constant over the record) per
    satellite, numbered from ``n_state`` in order of first appearance; and the number of satellites."""
    sats, first, inverse = np.unique(rows["sats"], return_index=True, return_inverse=True)
    rank = np.empty(sats.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(sats.size)
    return n_state + rank[inverse.ravel()], int(sats.size)


def static_prior(rows, cols, n_state: int, sigma_pos_m: float, sigma_amb_cycles: float, *, n_iono: int = 0,
                 sigma_iono_m: float = 0.0):
    """x0 (n,) and P0 (n, n): offset 0, each arc's ambiguity at its first row's (phase − code)/λ (the rows' codes
    without the clock steps they took alone: :func:`~cdgps_cli.measurement.code_steps.without_code_steps`, else
    every arc begun after a 1 ms step sat 10⁶ cycles from those before, and σ 30 cycles pulled the M8P pair's
    float 0.5 m), and the last ``n_iono`` states (SD ionosphere, m) 0 ± ``sigma_iono_m``."""
    x0 = np.zeros(n_state)
    first = np.unique(cols, return_index=True)[1]
    x0[cols[first]] = (rows["phase_sd_m"][first] - rows["code_sd_m"][first]) / rows["lam_m"][first]
    x0[cols[first]] = np.round(x0[cols[first]])
    P0 = np.diag(np.r_[np.full(3, sigma_pos_m**2), np.full(n_state - 3 - n_iono, sigma_amb_cycles**2),
                       np.full(n_iono, sigma_iono_m**2)])
    return x0, P0


def static_filter(rows, times_s, base_xyz_m, origin_xyz_m, *, sigma_pos_m: float = 100.0,
                  sigma_amb_cycles: float = 1e3, max_iterations: int = 2, cols=None, sigma_iono_m: float = 0.0):
    """Static float solution over every epoch through :func:`drive`; ``cols`` (N,) the rows' ambiguity
    columns (default: :func:`arc_columns` of ``rows`` and ``times_s`` with the default gap limit); with
    ``sigma_iono_m`` > 0 one SD ionosphere per satellite after the arcs (:func:`iono_columns`), 0 ± that σ.

    Returns
    -------
    x : ndarray (n,)      [offset (3, m), arc ambiguities (cycles), SD ionospheres (m) if any]
    P : ndarray (n, n)
    cols : ndarray (N,)   ambiguity column of each SD row
    """
    cols = arc_columns(rows, times_s) if cols is None else cols
    n = 3 + (int(cols.max()) - 2 if cols.size else 0)
    iono_cols, n_iono = iono_columns(rows, n) if sigma_iono_m > 0 else (None, 0)
    x0, P0 = static_prior(rows, cols, n + n_iono, sigma_pos_m, sigma_amb_cycles, n_iono=n_iono,
                          sigma_iono_m=sigma_iono_m)
    n += n_iono
    model = _model(rows, cols, base_xyz_m, origin_xyz_m, iono_cols)
    # only the last state is kept (a whole record's x, P per epoch: 86400 × 90² × 8 B = 5.6 GB for a 24 h pair)
    ctx = _long_filter(Static(n), model, times_s, x0, P0,
                       lambda: RecordingSink(len(times_s), n, history=False, keep_rows=False), max_iterations,
                       "static baseline (filter)")
    return ctx.step.x, ctx.step.P, cols


def _long_filter(dyn, model, times_s, x0, P0, sink, max_iterations: int, what: str):
    """:func:`drive` over every epoch, each update in covariance form (O(n² m) an epoch for ≈ 90 states and ≈ 10 DD
    rows; the information form is O(n³)); where its last P is no longer positive definite (the covariance form
    subtracts: over a long record, from a prior of 10³ cycles down to 10⁻⁴, rounding builds up — a 6 h 10 Hz
    random-walking rover's 50 DD ambiguities came out with three eigenvalues of −3·10⁻⁸ cycles², and LAMBDA could
    not start), the record is filtered again in information form, which only adds.  ``sink`` makes a fresh sink."""
    for form in ("covariance", "information"):
        with progress.bar(len(times_s), what + ("" if form == "covariance" else " again, information form"),
                          unit="epoch") as bar:
            ctx = drive(GridDynamics(dyn, times_s), [model], EpochGrid(np.asarray(times_s, float)),
                        StepFilter(x0, P0, form=form), sink=sink(), max_iterations=max_iterations, progress=bar)
        if form == "information" or positive_definite(ctx.step.P):
            return ctx
    raise AssertionError("unreachable")


def static_least_squares(rows, cols, n_state: int, base_xyz_m, origin_xyz_m, *, sigma_pos_m: float = 100.0,
                         sigma_amb_cycles: float = 1e3, tol_m: float = 1e-7, max_iterations: int = 8,
                         chunk_pairs: int = 1 << 19, sigma_iono_m: float = 0.0):
    """The static float solution as one batch: what :func:`static_filter` converges to, at O(N) cost.

    With no process noise the filter's information adds up epoch by epoch, so its final state is the
    least-squares solution of every epoch's DDs with :func:`static_prior`'s prior; here the normal equations
    of all epochs are formed at once and solved by Gauss–Newton on the offset (the DDs are linear in the
    ambiguities; two or three steps from an a-priori position metres off).  Each signal group's SDs (phase, then code)
    are weighted as their DDs are, ``W = Σ⁻¹ − Σ⁻¹11ᵀΣ⁻¹/(1ᵀΣ⁻¹1)`` (:class:`~cdgps_cli.measurement.dd_signals.GroupRows`),
    so a group of rows ``a_i`` (position part ``g_i = −los_i/ρ_i``, λ_i in the arc's column for a phase row)
    adds ``Σ w_i a_i a_iᵀ − (Σ w_i a_i)(Σ w_i a_i)ᵀ / Σ w_i``; the arcs' block of those sums is O(m²) per group,
    summed in chunks of ``chunk_pairs`` (bounded memory).  The filter, which linearizes each epoch at its
    running estimate, and :func:`static_normal_equations` at the answer agree with it to < 10⁻⁷ m and 10⁻⁶
    cycles in every DD of arcs on the Spirent G+E L1+L2 pair (tests/estimation/test_static_engine.py); on
    short float records (GEONET's 120 epochs) the filter's float position is up to 3·10⁻⁵ m from it.

    Parameters
    ----------
    rows : dict
        :func:`~cdgps_cli.measurement.dd_signals.paired_sd_rows` (with its ``groups`` layout).
    cols : ndarray (N,)
        Ambiguity column of each row (:func:`arc_columns`).
    n_state : int
        3 + number of arcs.
    base_xyz_m, origin_xyz_m : array_like (3,)
        Base position and the offset's origin, ECEF m.
    sigma_pos_m, sigma_amb_cycles : float
        :func:`static_prior`'s σ.
    tol_m : float
        Stop when the offset moves by less, m.
    max_iterations : int
        Gauss–Newton steps at most.
    chunk_pairs : int
        Row pairs of the arcs' block summed at once.
    sigma_iono_m : float
        > 0: the ionosphere-weighted model, one SD slant ionosphere (m at L1, constant) per satellite after the
        arcs (:func:`iono_columns`), 0 ± this σ; its phase rows take −μ I and its code rows +μ I, μ = (f_L1/f)²
        (the terms :func:`_iono_block` and :func:`_normal_equations` add).  0: the ionosphere neglected.

    Returns
    -------
    x : ndarray (n_state + n_iono,)
        [offset (3, m), arc ambiguities (cycles), SD ionospheres (m; none when ``sigma_iono_m`` is 0)].
    P : ndarray (n_state + n_iono, n_state + n_iono)
        Its covariance, N⁻¹.
    """
    iono_cols, n_iono = iono_columns(rows, n_state) if sigma_iono_m > 0 else (None, 0)
    n_state += n_iono
    x0, P0 = static_prior(rows, cols, n_state, sigma_pos_m, sigma_amb_cycles, n_iono=n_iono, sigma_iono_m=sigma_iono_m)
    info0 = np.diag(1.0 / np.diag(P0))
    g = _batch_rows(rows, cols, base_xyz_m, iono_cols)
    amb_info = _arc_block(g, n_state, chunk_pairs)
    if iono_cols is not None:
        amb_info += _iono_block(g, n_state, chunk_pairs)
    origin = np.asarray(origin_xyz_m, dtype=float)
    p_lin = np.zeros(3)
    for _ in range(max(1, int(max_iterations))):
        nmat, rhs = _normal_equations(g, n_state, origin, p_lin)
        nmat += info0 + amb_info
        rhs += info0 @ x0
        # equilibrated (the offset's information is ~1e10 times the arcs' prior) and factored by numpy's LAPACK:
        # rtk's path imports no scipy (its start-up time)
        d = 1.0 / np.sqrt(np.diag(nmat))
        lower = np.linalg.cholesky(nmat * d[:, None] * d[None, :])
        inv_lower = np.linalg.solve(lower, np.eye(n_state))
        x = d * (inv_lower.T @ (inv_lower @ (d * rhs)))
        step = float(np.max(np.abs(x[:3] - p_lin)))
        p_lin = x[:3].copy()
        if step < tol_m:
            break
    P = (inv_lower.T @ inv_lower) * d[:, None] * d[None, :]
    return x, 0.5 * (P + P.T)


def _batch_rows(rows, cols, base_xyz_m, iono_cols=None) -> dict:
    """The rows of every signal group (≥ 2 satellites) of the run, group after group: ambiguity column, λ,
    satellite positions, base range, SD phase and code, their weights 1/σ², the group of each row and each
    group's first row and weight sums; with ``iono_cols`` (N,) also each row's ionosphere column and μ."""
    lay = rows["groups"]
    size = (lay["stop"] - lay["start"]).astype(np.int64)
    first = np.cumsum(size) - size
    idx = np.arange(int(size.sum())) - np.repeat(first - lay["start"], size)
    los_b = rows["sat_base_xyz"][idx] - np.asarray(base_xyz_m, dtype=float)
    wp, wc = 1.0 / rows["var_phase"][idx], 1.0 / rows["var_code"][idx]
    nonempty = size.size > 0
    iono = {} if iono_cols is None else {"ion": np.asarray(iono_cols)[idx], "mu": rows["mu"][idx]}
    return {**iono, "amb": np.asarray(cols)[idx], "lam": rows["lam_m"][idx], "sx": np.ascontiguousarray(rows["sat_xyz"][idx]),
            "base_rng": np.sqrt(np.einsum("ij,ij->i", los_b, los_b)), "zp": rows["phase_sd_m"][idx],
            "zc": rows["code_sd_m"][idx], "wp": wp, "wc": wc, "gid": np.repeat(np.arange(size.size), size),
            "first": first, "size": size,
            "sp": np.add.reduceat(wp, first) if nonempty else np.zeros(0),
            "sc": np.add.reduceat(wc, first) if nonempty else np.zeros(0)}


def _arc_block(g: dict, n_state: int, chunk_pairs: int) -> np.ndarray:
    """The arcs' block of the normal matrix (it does not depend on the offset): Σ w λ² on each row's column
    less, per group, (w_i λ_i)(w_j λ_j)/Σw over every pair of its rows, summed in chunks of groups."""
    out = np.bincount(g["amb"], weights=g["wp"] * g["lam"] ** 2, minlength=n_state).astype(float)
    wl = g["wp"] * g["lam"]
    nmat = _group_pairs(g, g["sp"], g["amb"], wl, g["amb"], wl, n_state, chunk_pairs)
    nmat[np.diag_indices(n_state)] += out
    return nmat


def _group_pairs(g: dict, s: np.ndarray, col_l, a_l, col_r, a_r, n_state: int, chunk_pairs: int) -> np.ndarray:
    """(n_state, n_state): −Σ over the row pairs (i, j) of each group of ``a_l[i] a_r[j] / s[group]`` at
    (``col_l[i]``, ``col_r[j]``), summed in chunks of about ``chunk_pairs`` pairs (as :func:`_arc_block`)."""
    nmat = np.zeros(n_state * n_state)
    size, first, gid = g["size"], g["first"], g["gid"]
    cum = np.cumsum(size * size)
    j0 = 0
    while j0 < size.size:
        done = int(cum[j0 - 1]) if j0 else 0
        j1 = max(j0 + 1, int(np.searchsorted(cum, done + chunk_pairs, side="right")))
        r = np.arange(first[j0], first[j1 - 1] + size[j1 - 1])
        rep = size[gid[r]]
        i = np.repeat(r, rep)
        j = first[gid[i]] + np.arange(i.size) - np.repeat(np.cumsum(rep) - rep, rep)
        nmat += np.bincount(col_l[i] * n_state + col_r[j], weights=-(a_l[i] * a_r[j]) / s[gid[i]],
                            minlength=n_state * n_state)
        j0 = j1
    return nmat.reshape(n_state, n_state)


def _iono_block(g: dict, n_state: int, chunk_pairs: int) -> np.ndarray:
    """The normal matrix's terms in the ionosphere columns that do not depend on the offset: a phase row's
    constants ``λ e_N − μ e_I``, a code row's ``μ e_I``, each group weighted as its DDs (:func:`_arc_block`'s
    ``Σ w a aᵀ − (Σ w a)(Σ w a)ᵀ/Σw``, less the arcs' block that function forms)."""
    amb, ion, lam, mu, wp, wc = g["amb"], g["ion"], g["lam"], g["mu"], g["wp"], g["wc"]
    nmat = np.bincount(ion * n_state + ion, weights=(wp + wc) * mu**2, minlength=n_state * n_state).reshape(n_state, n_state)
    nmat += _group_pairs(g, g["sp"], ion, wp * mu, ion, wp * mu, n_state, chunk_pairs)
    nmat += _group_pairs(g, g["sc"], ion, wc * mu, ion, wc * mu, n_state, chunk_pairs)
    cross = np.bincount(amb * n_state + ion, weights=-wp * lam * mu, minlength=n_state * n_state).reshape(n_state, n_state)
    cross += _group_pairs(g, g["sp"], amb, wp * lam, ion, -wp * mu, n_state, chunk_pairs)
    return nmat + cross + cross.T


def _normal_equations(g: dict, n_state: int, origin, p_lin) -> tuple[np.ndarray, np.ndarray]:
    """The offset's rows and columns of the normal matrix and the right-hand side, linearized at ``p_lin``
    (the arcs' block: :func:`_arc_block`; the ionosphere's, with ``g["ion"]``: :func:`_iono_block`)."""
    los = g["sx"] - (origin + p_lin)
    rng = np.sqrt(np.einsum("ij,ij->i", los, los))
    gv = -los / rng[:, None]                                       # ∂ρ/∂offset
    base = g["base_rng"] + gv @ p_lin
    nmat, rhs = np.zeros((n_state, n_state)), np.zeros(n_state)
    first, gid = g["first"], g["gid"]
    for key, wkey, skey, phase in (("zp", "wp", "sp", True), ("zc", "wc", "sc", False)):
        w, s = g[wkey], g[skey]
        y = g[key] - rng + base                                    # = g·offset (+ λN for phase) when linear
        wg = w[:, None] * gv
        sum_g = np.add.reduceat(wg, first, axis=0) if first.size else np.zeros((0, 3))
        sum_y = np.add.reduceat(w * y, first) if first.size else np.zeros(0)
        mean_g, mean_y = sum_g / s[:, None], sum_y / s
        nmat[:3, :3] += wg.T @ gv - sum_g.T @ mean_g
        rhs[:3] += wg.T @ y - sum_g.T @ mean_y
        if phase:
            wl = w * g["lam"]
            v = wl[:, None] * (gv - mean_g[gid])                   # (R, 3): into each row's arc column
            for c in range(3):
                nmat[c, 3:] += np.bincount(g["amb"], weights=v[:, c], minlength=n_state)[3:]
            rhs[3:] += np.bincount(g["amb"], weights=wl * (y - mean_y[gid]), minlength=n_state)[3:]
        if "ion" in g:                                             # the ionosphere: −μ in phase, +μ in code
            wm = (-w if phase else w) * g["mu"]
            v = wm[:, None] * (gv - mean_g[gid])
            for c in range(3):
                nmat[c, 3:] += np.bincount(g["ion"], weights=v[:, c], minlength=n_state)[3:]
            rhs[3:] += np.bincount(g["ion"], weights=wm * (y - mean_y[gid]), minlength=n_state)[3:]
    nmat[3:, :3] = nmat[:3, 3:].T
    return nmat, rhs


def epoch_phase_misfit(rows, cols, arcs_m, known, base_xyz_m, origin_xyz_m, offset_m, *, iterations: int = 2):
    """Each epoch's carrier phases alone, with the ambiguities known, solved for a free position: the weighted
    residual sum of squares and its degrees of freedom per epoch (the fixed solution's check that does not depend
    on a motion model).

    Only rows whose arc is ``known`` take part; each signal group is weighted as its DDs (:func:`_batch_rows`'
    ``W = Σ⁻¹ − Σ⁻¹11ᵀΣ⁻¹/1ᵀΣ⁻¹1``: the SD arcs' common value drops out), and the offset of each epoch is solved
    by Gauss–Newton from ``offset_m``.

    Parameters
    ----------
    rows : dict
        :func:`~cdgps_cli.measurement.dd_signals.paired_sd_rows` with its ``groups`` layout.
    cols : ndarray (N,)
        Each row's arc column.
    arcs_m : ndarray (n_state,)
        λ N of every arc column (m; only the known ones are read).
    known : ndarray (n_state,) bool
        Arc columns whose ambiguity is known.
    base_xyz_m, origin_xyz_m, offset_m : array_like (3,)
        Base position, the offset's origin and the offset to start from, ECEF m.

    Returns
    -------
    chi2 : ndarray (n_epochs,)
        Weighted residual sum of squares of each epoch's phases at its own position.
    dof : ndarray (n_epochs,) int
        DDs less 3; ≤ 0 where the epoch does not determine a position (its chi2 is then 0).
    """
    n_ep = rows["ptr"].size - 1
    lay = rows["groups"]
    size = (lay["stop"] - lay["start"]).astype(np.int64)
    first = np.cumsum(size) - size
    idx = np.arange(int(size.sum())) - np.repeat(first - lay["start"], size)
    gid = np.repeat(np.arange(size.size), size)
    g_epoch = np.searchsorted(lay["ptr"], np.arange(size.size), side="right") - 1
    use = np.asarray(known, bool)[np.asarray(cols)[idx]]
    idx, gid = idx[use], gid[use]
    count = np.bincount(gid, minlength=size.size)
    keep = count[gid] >= 2                                         # a group needs two known rows to form a DD
    idx, gid = idx[keep], gid[keep]
    w = 1.0 / rows["var_phase"][idx]
    ep = g_epoch[gid]
    z = rows["phase_sd_m"][idx] - np.asarray(arcs_m)[np.asarray(cols)[idx]]
    los_b = rows["sat_base_xyz"][idx] - np.asarray(base_xyz_m, float)
    base_rng = np.sqrt(np.einsum("ij,ij->i", los_b, los_b))
    dof = np.bincount(g_epoch, weights=np.maximum(np.bincount(gid, minlength=size.size) - 1, 0),
                      minlength=n_ep).astype(np.int64) - 3
    pos = np.tile(np.asarray(origin_xyz_m, float) + np.asarray(offset_m, float), (n_ep, 1))
    ok = dof > 0
    for _ in range(iterations + 1):                 # Gauss–Newton on each epoch's position; χ² at the last
        los = rows["sat_xyz"][idx] - pos[ep]
        rng = np.sqrt(np.einsum("ij,ij->i", los, los))
        fit = grouped_epoch_fit(z - (rng - base_rng), w, -los / rng[:, None], gid, ep, size.size, n_ep, usable=ok)
        ok = fit.ok
        pos[ok] += fit.step[ok]
    chi2 = fit.chi2
    return chi2, np.where(ok, dof, 0)


def fixed_phase_check(rows, cols, fixed_pairs, x_fix, base_xyz_m, origin_xyz_m, times_s=None) -> dict | None:
    """The fixed integers' check by the phases alone: :func:`epoch_phase_misfit` of the arcs the fixed DDs
    ``fixed_pairs`` ((arc, reference arc) columns) tie together, at their values in ``x_fix`` (cycles), each epoch's
    position free.

    Returns ``unit_variance`` (Σχ² / Σdof over the record), ``n_dd`` (Σdof + 3 per epoch used), ``epochs``, and with
    ``times_s`` (n_epochs,) ``window_unit_variance``: the largest Σχ² / Σdof over windows of
    :data:`~cdgps_cli.config.options.FIXED_PHASE_WINDOW_S` with at least :data:`_WINDOW_MIN_DOF` DDs to spare (a wrong
    integer on a short arc, which the record's mean dilutes), or None without such a window.  None when no epoch has
    phases of known arcs to spare (or the rows carry no group layout)."""
    if not len(fixed_pairs) or rows.get("groups") is None or base_xyz_m is None:
        return None
    known = np.zeros(x_fix.size, dtype=bool)
    known[np.asarray(fixed_pairs, dtype=np.int64).ravel()] = True
    lam_m = np.zeros(x_fix.size)
    lam_m[cols] = rows["lam_m"]
    chi2, dof = epoch_phase_misfit(rows, cols, lam_m * x_fix, known, base_xyz_m, origin_xyz_m, x_fix[:3])
    used = dof > 0
    if not used.any():
        return None
    out = {"unit_variance": float(chi2.sum() / dof.sum()), "n_dd": int(dof.sum() + 3 * used.sum()),
           "epochs": int(used.sum())}
    if times_s is not None:
        t = np.asarray(times_s, float)
        win = np.floor((t - t[0]) / FIXED_PHASE_WINDOW_S).astype(np.int64)
        c2, df = np.bincount(win, weights=chi2), np.bincount(win, weights=dof)
        ok = df >= _WINDOW_MIN_DOF
        out["window_unit_variance"] = float((c2[ok] / df[ok]).max()) if ok.any() else None
    return out


def fixed_phase_rejects(check: dict | None) -> bool:
    """Whether :func:`fixed_phase_check`'s figures reject the integers: the record's unit variance above
    :data:`~cdgps_cli.config.options.FIXED_PHASE_UNIT_VARIANCE_MAX`, or a window's above
    :data:`~cdgps_cli.config.options.FIXED_PHASE_WINDOW_UNIT_VARIANCE_MAX`."""
    if check is None:
        return False
    win = check.get("window_unit_variance")
    return check["unit_variance"] > FIXED_PHASE_UNIT_VARIANCE_MAX or (
        win is not None and win > FIXED_PHASE_WINDOW_UNIT_VARIANCE_MAX)


def fixed_integers_rejected(check: dict | None, float_nis_per_row: float | None) -> str | None:
    """Why fixed integers are not taken, or None: ``"phase_check"`` when :func:`fixed_phase_rejects` says so;
    ``"float_nis"`` when the phases cannot judge them (``check`` None: no epoch has phases of fixed arcs to
    spare) and the float's NIS per row is above :data:`~cdgps_cli.config.options.UNCHECKED_FIX_NIS_MAX`."""
    if fixed_phase_rejects(check):
        return "phase_check"
    if check is None and float_nis_per_row is not None and float_nis_per_row > UNCHECKED_FIX_NIS_MAX:
        return "float_nis"
    return None


#: the fewest DDs to spare a window of fixed_phase_check needs to be judged
_WINDOW_MIN_DOF = 20


class EnuRandomWalk(Dynamics):
    """An ECEF offset (3, m) whose east/north/up components (the local frame at ``origin_xyz_m``) are random
    walks of σ ``sigma_enu`` (m/√s, three or one): Q = Rᵀ diag(σ²) R Δt, R the ECEF → ENU rotation."""

    identity_transition = True

    def __init__(self, sigma_enu, origin_xyz_m):
        self.n, self.n_u = 3, 0
        s = np.broadcast_to(np.asarray(sigma_enu, dtype=float), (3,))
        R = enu_matrix(*ecef_to_geodetic(np.asarray(origin_xyz_m, dtype=float))[:2])
        self._Q1 = R.T @ np.diag(s**2) @ R

    def transition(self, dt_s: float):
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be a positive number of seconds, got {dt_s!r}")
        return np.eye(3), np.zeros((3, 0)), self._Q1 * float(dt_s)


def random_walk_float(rows, cols, times_s, base_xyz_m, origin_xyz_m, x_static, *, sigma_rw, initial_sigma_m: float,
                      sigma_amb_cycles: float = 1e3, max_iterations: int = 2, sigma_iono_m: float = 0.0):
    """Float arc ambiguities of a rover whose position random-walks, through :func:`drive`.

    State [offset (3, m), arc ambiguities (cycles)]: the offset a random walk of σ ``sigma_rw`` (m/√s, per
    east/north/up component or one for all; :class:`EnuRandomWalk`), the ambiguities constants
    (:class:`~cdgps_cli.model.dynamics_models.WithConstants`), from the offset of ``x_static`` (the static
    float solution) ± ``initial_sigma_m`` and :func:`static_prior`'s ambiguities ± ``sigma_amb_cycles``.
    Constants are not moved by a smoother: their filtered estimate at the last epoch is their posterior given
    every epoch (what an RTS pass would give).  The ambiguities' prior stays (as :func:`static_filter`'s): the SD
    arcs' common mode per signal is known only through it, and it is ≈ 10⁻⁶ of the DD information.  With
    ``sigma_iono_m`` > 0, one constant SD ionosphere per satellite (:func:`iono_columns`), 0 ± that σ, is
    estimated beside them and the arcs' (a, Q) are its marginal.

    Returns
    -------
    RandomWalkFloat
        ``a`` (n_arc,) cycles, ``Q`` (n_arc, n_arc) cycles² and ``nis_per_row``: the filter's NIS summed over the
        record per SD row used (each epoch's NIS has one degree of freedom per DD, a row fewer per signal group,
        so a walk that holds the rover's motion gives a little under 1; the real static pairs 0.1–1.3).  Far above
        (p9's walker: 8 900, the GEONET car: 2.7·10⁵ at 1 mm/√s) the walk does not hold the motion, and the
        arcs' Q is too small by about as much.
    """
    n_arc_state = x_static.size
    iono_cols, n_iono = iono_columns(rows, n_arc_state) if sigma_iono_m > 0 else (None, 0)
    n = n_arc_state + n_iono
    x0, P0 = static_prior(rows, cols, n, initial_sigma_m, sigma_amb_cycles, n_iono=n_iono, sigma_iono_m=sigma_iono_m)
    x0[:3] = x_static[:3]
    dyn = WithConstants(EnuRandomWalk(sigma_rw, origin_xyz_m), n - 3)
    model = _model(rows, cols, base_xyz_m, origin_xyz_m, iono_cols)
    ctx = _long_filter(dyn, model, times_s, x0, P0, lambda: RecordingSink(len(times_s), n, history=False),
                       max_iterations, "static baseline (random-walk filter)")
    n_rows = int(ctx.nis_dof.sum())
    return RandomWalkFloat(ctx.step.x[3:n_arc_state].copy(), ctx.step.P[3:n_arc_state, 3:n_arc_state].copy(),
                           float(np.nansum(ctx.nis) / n_rows) if n_rows else math.nan)


class RandomWalkFloat(NamedTuple):
    """:func:`random_walk_float`'s answer: the arcs' float ``a`` (cycles), ``Q`` (cycles²) and the filter's
    ``nis_per_row`` (its NIS per SD row over the record); from :func:`random_walk_float_that_holds`, also the
    walk's σ used (``sigma_m_per_sqrt_s``, (3,) E/N/U) and every σ tried with its NIS per row (``tried``)."""

    a: np.ndarray
    Q: np.ndarray
    nis_per_row: float
    sigma_m_per_sqrt_s: tuple = ()
    tried: tuple = ()


def random_walk_float_that_holds(rows, cols, times_s, base_xyz_m, origin_xyz_m, x_static, *, sigma_rw, **kw):
    """:func:`random_walk_float` at σ ``sigma_rw``, and while its NIS per row is above
    :data:`~cdgps_cli.config.options.UNCHECKED_FIX_NIS_MAX` (the walk does not hold the rover's motion and the
    arcs' Q is too small by about as much) again at σ × :data:`~cdgps_cli.config.options.RANDOM_WALK_RAISE_FACTOR`,
    at most :data:`~cdgps_cli.config.options.RANDOM_WALK_MAX_RAISES` times, and only while each raise at least halves
    the NIS (a misfit the walk does not cause, e.g. one code blunder, stays whatever σ: raising stops at once).
    Returns the first float that holds; else, when a raise did not help, the float before it; else the one of the
    lowest NIS; as a :class:`RandomWalkFloat` with its σ and every (σ, NIS per row) tried."""
    sigma = np.broadcast_to(np.asarray(sigma_rw, dtype=float), (3,))
    tried, floats = [], []
    for _ in range(RANDOM_WALK_MAX_RAISES + 1):
        floats.append(random_walk_float(rows, cols, times_s, base_xyz_m, origin_xyz_m, x_static, sigma_rw=sigma, **kw))
        tried.append((tuple(float(v) for v in sigma), floats[-1].nis_per_row))
        if not floats[-1].nis_per_row > UNCHECKED_FIX_NIS_MAX:
            break
        if len(tried) > 1 and not tried[-1][1] < 0.5 * tried[-2][1]:
            k = len(tried) - 2                    # the last raise did not help: the σ before it
            return floats[k]._replace(sigma_m_per_sqrt_s=tried[k][0], tried=tuple(tried))
        sigma = sigma * RANDOM_WALK_RAISE_FACTOR
    k = len(tried) - 1 if not floats[-1].nis_per_row > UNCHECKED_FIX_NIS_MAX else int(np.nanargmin([t[1] for t in tried]))
    return floats[k]._replace(sigma_m_per_sqrt_s=tried[k][0], tried=tuple(tried))


class _Ctx:
    def __init__(self, x):
        self.x = x


def static_normal_equations(rows, n_epochs: int, base_xyz_m, origin_xyz_m, x_lin, x0, P0, cols=None):
    """The batch answer: N = P0⁻¹ + Σ_k (B H)ᵀ(B H), x = x_lin + N⁻¹ (P0⁻¹ (x0 − x_lin) + Σ_k (B H)ᵀ B (z − h)),
    every epoch linearized at ``x_lin`` (one Gauss–Newton step); ``cols`` as :func:`static_filter`'s
    (default: slips only)."""
    cols = arc_columns(rows) if cols is None else cols
    info = np.linalg.inv(P0)
    Nm, rhs = info.copy(), info @ (x0 - x_lin)
    model = _model(rows, cols, base_xyz_m, origin_xyz_m)
    for k in range(n_epochs):
        model.prepare(k, _Ctx(x_lin))
        r = model.rows(k)
        if r is None:
            continue
        h, H = model.predict(x_lin, r)
        BH, Br = r.whiten(H), r.whiten(r.z_m - h)
        Nm += BH.T @ BH
        rhs += BH.T @ Br
    return x_lin + np.linalg.solve(Nm, rhs), np.linalg.inv(Nm)


def dd_of_arcs(rows, cols, n_state: int, glonass_fix: bool = False):
    """DD operator (n_dd, n_state) on the arc ambiguities: per signal and per connected set of its arcs (arcs
    seen in a common epoch are connected; a gap that every satellite's arc ends in leaves two sets, whose SD
    ambiguities have no common datum), every arc minus the set's reference arc (the one with the most rows,
    preferring arcs without a half-cycle flag); the (arc, reference arc) column pairs; and which DDs are
    integers that may be fixed (n_dd,) bool: not when either arc has a half-cycle flag, nor for a signal whose
    wavelength differs between satellites (GLONASS FDMA: an SD ambiguity difference in cycles of two
    wavelengths is no integer) unless ``glonass_fix`` (identical receivers: the arcs' DD in cycles is fixed as
    an integer, as ``rtk --glonass-fix`` does; :func:`static_baseline` then gives the arcs rtk's prior, see
    there).  Without ``rows["ptr"]`` (epoch bounds) a signal's arcs are taken as one set."""
    D, pairs, fixable = [], [], []
    half = np.zeros(n_state, dtype=bool)
    if "half" in rows:
        half[cols[rows["half"]]] = True
    for c in np.unique(rows["code"]):
        sel = rows["code"] == c
        fdma = np.ptp(rows["lam_m"][sel]) > 0 and not glonass_fix
        for arcs, counts in _connected_arc_sets(rows, cols, sel):
            ref = int(arcs[np.lexsort((-counts, half[arcs]))[0]])
            for a in arcs:
                if a == ref:
                    continue
                d = np.zeros(n_state)
                d[a], d[ref] = 1.0, -1.0
                D.append(d)
                pairs.append((int(a), ref))
                fixable.append(not (fdma or half[a] or half[ref]))
    return np.array(D).reshape(-1, n_state), pairs, np.array(fixable, dtype=bool)


def _connected_arc_sets(rows, cols, sel):
    """The arcs (columns) of the rows ``sel`` grouped into sets connected through common epochs
    (:func:`~cdgps_cli.measurement.differencing.ambiguity_datum`'s components), each as (arcs ascending, their
    row counts), the sets in order of their smallest column."""
    arcs, inverse, counts = np.unique(cols[sel], return_inverse=True, return_counts=True)
    if "ptr" not in rows or arcs.size < 2:
        return [(arcs, counts)]
    epoch = (np.searchsorted(rows["ptr"], np.arange(sel.size), side="right") - 1)[sel]
    _, comp = ambiguity_datum(epoch, inverse.ravel(), arcs.size)
    return [(arcs[comp == k], counts[comp == k]) for k in range(int(comp.max()) + 1)]


def condition_on_integers(x, P, D, ints):
    """The state conditioned on integer combinations of it, ``D x = ints`` (the fixed solution).

    Parameters
    ----------
    x : ndarray (n,)        float state [offset (3, m), arc ambiguities (cycles)]
    P : ndarray (n, n)      its covariance
    D : ndarray (m, n)      linearly independent DD operators on the arc ambiguities (m may be 0)
    ints : ndarray (m,)     their integers, cycles

    Returns
    -------
    x_fix : ndarray (n,), P_fix : ndarray (n, n)   copies of x, P when m = 0.
    """
    if not len(ints):
        return x.copy(), P.copy()
    Pxa = P @ D.T
    G = np.linalg.solve(D @ P @ D.T, Pxa.T).T
    return x - G @ (D @ x - ints), P - G @ Pxa.T


def static_fix(x, P, rows, cols, *, ratio: float, partial: bool = True, min_success_rate: float | None = None,
               amb=None, glonass_fix: bool = False, base_xyz_m=None, origin_xyz_m=None, times_s=None,
               float_nis_per_row: float | None = None):
    """Integers of the static float solution by the shared policy on the DDs of :func:`dd_of_arcs`: with
    ``partial``, :func:`~cdgps_cli.estimation.ambiguity.resolve_cascaded` (the largest subset that passes, then
    the rest conditioned on it, again, until a stage fixes nothing); else the full set only
    (:func:`~cdgps_cli.estimation.ambiguity.resolve`).  The position is conditioned on every integer fixed.

    Returns
    -------
    dict
        ``offset_m`` (3,) fixed (float when nothing fixed), ``cov_m2`` (3, 3), ``resolution`` (resolve's
        dict, its ``fixed_mask`` / ``integers`` over all DDs: the ones not fixable stay float), ``pairs``
        (the DDs' column pairs), ``dd_float`` (n_dd,) cycles.

    Integers are then checked (:func:`fixed_integers_rejected`): by the phases alone
    (:func:`fixed_phase_check`), or, when no epoch has phases of fixed arcs to spare, by the float's own
    consistency: ``float_nis_per_row`` (a moving rover's random-walk float, :class:`RandomWalkFloat`) above
    :data:`~cdgps_cli.config.options.UNCHECKED_FIX_NIS_MAX` means the walk did not hold the motion, its Q is too
    small, and integers nothing else can check are not taken.  Rejected integers leave the float, with
    ``rejected_n_fixed`` and ``rejected_by`` (``"phase_check"`` or ``"float_nis"``) in ``resolution``.
    """
    from cdgps_cli.estimation.ambiguity import resolve, resolve_cascaded
    D, pairs, fixable = dd_of_arcs(rows, cols, x.size, glonass_fix)
    if amb is None:
        a, Qa = D @ x, D @ P @ D.T
    else:                                   # (a, Q) of the arcs from another float (random walk)
        a, Qa = D[:, 3:] @ amb[0], D[:, 3:] @ amb[1] @ D[:, 3:].T
    with progress.bar(int(fixable.sum()) if partial else 1, "integer fixing (LAMBDA)", unit="subset") as bar:
        solve = resolve_cascaded if partial else resolve
        res = solve(a[fixable], Qa[np.ix_(fixable, fixable)], ratio, min_success_rate=min_success_rate,
                    progress=lambda done, total: bar.update_to(done), **({} if partial else {"partial": False}))
    m = np.zeros(a.size, dtype=bool)
    m[fixable] = res["fixed_mask"]
    ints = np.zeros(a.size, dtype=np.int64)
    ints[fixable] = res["integers"]
    res = {**res, "fixed_mask": m, "integers": ints}
    x_fix, P_fix = condition_on_integers(x, P, D[m], ints[m])
    check = fixed_phase_check(rows, cols, [pairs[i] for i in np.flatnonzero(m)], x_fix, base_xyz_m, origin_xyz_m,
                              times_s)
    res["phase_check"] = check
    res["float_nis_per_row"] = float_nis_per_row
    why = fixed_integers_rejected(check, float_nis_per_row) if m.any() else None
    if why is not None:
        res.update(fixed_mask=np.zeros(a.size, dtype=bool), integers=np.zeros(a.size, dtype=np.int64), n_fixed=0,
                   accepted=False, partial=False, rejected_n_fixed=int(m.sum()), rejected_by=why)
        x_fix, P_fix = x.copy(), P.copy()
    return {"offset_m": x_fix[:3].copy(), "cov_m2": P_fix[:3, :3].copy(), "resolution": res, "pairs": pairs,
            "dd_float": a, "state_fixed": x_fix, "cov_fixed": P_fix}


#: options the static engine does not honour yet: refused by name rather than silently ignored
_NOT_YET = {"fix_and_hold": "fix-and-hold is a kinematic (rtk) option"}
#: rtk's options the engine has not (a caller's tables are solved as they are): refused by name, with why
_RTK_ONLY = {**dict.fromkeys(("tropo_threshold_km", "tropo_initial_m", "tropo_sigma_m", "tropo_rw_m_per_sqrt_s"),
                             "the static engine does not estimate zenith wet delays: 'cdgps rtk' does"),
             **dict.fromkeys(("antex", "base_antenna", "rover_antenna"),
                             "antenna models are taken out of the observation tables before: 'cdgps rtk --antex'")}


def static_option_names() -> set:
    """The option keys :func:`static_baseline` knows."""
    return set(_option_defaults())


def _option_defaults() -> dict:
    """The engine's options and their defaults (the rtk options' own, :data:`MULTI_GNSS_DEFAULTS`, and these)."""
    return {"partial": GNSS_DEFAULTS["partial"], **{k: v for k, v in MULTI_GNSS_DEFAULTS.items() if k not in _RTK_ONLY},
            "fix_and_hold": False,           # rtk's default holds; a static batch has nothing to hold
            "code_noise": "model",           # baseline / init weight the codes as modelled (rtk: "auto")
            "motion": "static", "random_walk_sigma": GNSS_DEFAULTS["random_walk_sigma"],
            "initial_sigma_m": GNSS_DEFAULTS["initial_sigma_m"],
            "max_gap_s": None,               # arcs: ambiguity_segments' gap limit (None: its default)
            "iono_weighted": False,          # the float LAMBDA sees with an SD ionosphere per satellite (see there)
            "segment_starts": None}          # [(satellite "G05:L1", time s)]: arcs start there (INIT's), no search


def _static_options(options: dict | None) -> dict:
    """Defaults merged with ``options``; CdgpsError naming an unknown key or one the engine does not honour."""
    opt = _option_defaults()
    for key in sorted(set(options or {}) & set(_RTK_ONLY)):
        raise CdgpsError(f"static baseline: option {key} = {options[key]!r} is not supported ({_RTK_ONLY[key]})")
    unknown = sorted(set(options or {}) - set(opt))
    if unknown:
        raise CdgpsError(f"static baseline: unknown option(s) {', '.join(unknown)}; known: {', '.join(sorted(opt))}")
    opt.update(options or {})
    for key, why in _NOT_YET.items():
        if opt[key]:
            raise CdgpsError(f"static baseline: option {key} = {opt[key]!r} is not supported ({why})")
    if opt["motion"] not in ("static", "random_walk"):
        raise CdgpsError(f"static baseline: option motion = {opt['motion']!r}; expected 'static' or 'random_walk'")
    if opt["weighting"] not in GNSS_WEIGHTINGS:
        raise CdgpsError(f"static baseline: option weighting = {opt['weighting']!r}; expected "
                         f"{' or '.join(repr(w) for w in GNSS_WEIGHTINGS)}")
    return opt


#: BaselineOptions fields the engine honours, and their engine option names
_HONOURED = {"mask_deg": "mask_deg", "ratio_threshold": "ratio", "partial": "partial", "fix": "fix",
             "sigma_a_m": "sigma_a_m", "sigma_b_m": "sigma_b_m", "code_ratio": "code_ratio",
             "troposphere": "troposphere", "sync_tol_s": "sync_tol_s", "max_age_s": "max_age_s",
             "code_correlation_s": "code_correlation_s", "min_success_rate": "min_success_rate",
             "motion": "motion", "random_walk_sigma": "random_walk_sigma", "initial_sigma_m": "initial_sigma_m",
             "glonass_fix": "glonass_fix", "max_gap_s": "max_gap_s", "weighting": "weighting"}
#: BaselineOptions fields the engine does not implement: only this value is accepted (the engine's behaviour)
_FIXED_VALUE = {"epoch_alignment": "geometry", "kinematic_series": False}


def options_from_baseline(bopt) -> dict:
    """:class:`~cdgps_cli.estimation.baseline.BaselineOptions` → :func:`static_baseline` options.

    Fields in ``_HONOURED`` are mapped (``weighting`` too: the SD rows' variance, :func:`paired_sd_rows`;
    ``age_sigma_m_per_s`` as option ``age_noise`` "model" with that σ, or "auto" when None); a field in
    ``_FIXED_VALUE`` set otherwise raises CdgpsError naming it; the remaining ones (``max_iterations``, the batch's
    Gauss–Newton cap, which the engine's one pass has no equivalent of; the kinematic-series settings, which the
    caller renders) must keep their defaults, else CdgpsError naming them.
    """
    from dataclasses import fields
    out = {}
    for f in fields(bopt):
        v = getattr(bopt, f.name)
        if f.name == "age_sigma_m_per_s":        # None: the engine finds it from the base ("auto"); else as given
            out.update({} if v is None else {"age_noise": "model", "age_sigma_m_per_s": float(v)})
        elif f.name in _HONOURED:
            out[_HONOURED[f.name]] = v
        elif f.name in _FIXED_VALUE:
            if v != _FIXED_VALUE[f.name]:
                raise CdgpsError(f"static baseline: option {f.name} = {v!r} is not supported by the static engine "
                                 f"(only {_FIXED_VALUE[f.name]!r})")
        elif (tuple(v) if isinstance(v, list) else v) != f.default:        # a JSON list for a tuple default
            raise CdgpsError(f"static baseline: option {f.name} = {v!r} is not supported by the static engine "
                             f"(only its default {f.default!r})")
    return out


def static_baseline(base, rover, base_xyz_m, rover_xyz0_m, options: dict | None = None, *,
                    arcs_check=None) -> dict | str:
    """Static baseline on the one engine: rtk's epoch pairing and SD rows, :func:`static_least_squares` (what
    :func:`static_filter` converges to), :func:`static_fix`.

    Parameters
    ----------
    base, rover : DataFrame
        :func:`~cdgps_cli.estimation.rtk_multi.receiver_geometry` tables.
    base_xyz_m, rover_xyz0_m : array_like (3,)
        Known base position and the rover's a-priori position (the offset's origin), ECEF m.
    options : dict
        Keys of :data:`~cdgps_cli.config.options.MULTI_GNSS_DEFAULTS` (``ratio``, ``partial``,
        ``min_success_rate``, ``fix`` (False: float only, ``resolution`` None), the weights (``weighting``,
        ``sigma_a_m``, ``sigma_b_m``, ``code_ratio``) and the mask are used; ``glonass_fix``: the GLONASS DDs fixed too, between identical receivers); an unknown key, or
        ``fix_and_hold`` set, raises CdgpsError, as does a
        multi-signal baseline at or above ``iono_threshold_km`` (the DD ionosphere is neglected, as ``init``'s).

    Returns
    -------
    dict
        ``offset_m`` (3,) fixed (float when nothing is fixed) ECEF offset from ``rover_xyz0_m``, m;
        ``cov_m2`` (3, 3); ``float_offset_m`` (3,), ``float_cov_m2`` (3, 3); ``resolution``
        (:func:`~cdgps_cli.estimation.ambiguity.resolve`'s dict); ``pairs``; ``epochs_used``; ``epoch_pairing``;
        ``age_noise`` (:func:`~cdgps_cli.measurement.base_interpolation.base_age_noise` of option ``age_noise``: the
        σ per second of base age the rows were weighed with).  Or a string: what ``arcs_check`` returned.

    Other Parameters
    ----------------
    arcs_check : callable, optional
        Called with the :func:`arc_table` (and ``unflagged_slips``, ``age_noise``) before the filter runs; when it
        returns a string, nothing is solved and that string is returned (a caller that cannot use these arcs skips
        the solve).
    """
    opt = _static_options(options)
    pairs, rows, age_noise = _paired_rows(base, rover, opt, base_xyz_m, weigh_age=True)
    del base, rover          # the geometry tables (a long record's largest) are not held through the check and solve
    times = pairs.rover_time_s
    if np.unique(rows["code"]).size > 1:           # multi-signal: the DD ionosphere is neglected (as init's)
        from cdgps_cli.estimation.baseline import check_iono_rule
        check_iono_rule("base", "rover", float(np.linalg.norm(np.subtract(rover_xyz0_m, base_xyz_m))),
                        opt["iono_threshold_km"])
    rows, slips = _with_unflagged_slips(rows, times, opt, base_xyz_m, rover_xyz0_m)
    cols = arc_columns(rows, times, max_gap_s=opt["max_gap_s"])
    rows, code_steps = without_code_steps(rows, cols)      # a clock jump in the codes alone: out of every row
    if arcs_check is not None:
        why = arcs_check(dict(arc_table(rows, cols, times), unflagged_slips=slips, age_noise=age_noise))
        if isinstance(why, str):
            return why
    # the arcs' prior σ: rtk's (amb_sigma_cycles) — 1e3 cycles left P of a 24 h pair (σ down to 1e-4 m) too
    # ill-conditioned to factor (LinAlgError after 68323 epochs); with GLONASS DDs fixed, (λ_i − λ_r)·N_r enters
    # each FDMA DD, so the SD arcs' common mode must be known to a few cycles, which this prior also gives
    sigma_amb = {"sigma_amb_cycles": opt["amb_sigma_cycles"]}
    n_state = 3 + (int(cols.max()) - 2 if cols.size else 0)
    x, P = static_least_squares(rows, cols, n_state, base_xyz_m, rover_xyz0_m, **sigma_amb)    # a day at 1 Hz: ≈ 1 s
    sigma_iono, lambda_float, rw = _lambda_float(rows, cols, times, x, opt, (base_xyz_m, rover_xyz0_m), sigma_amb)
    if not opt["fix"]:
        f = {"offset_m": x[:3].copy(), "cov_m2": P[:3, :3].copy(), "resolution": None, "pairs": [], "dd_float": None,
             "state_fixed": x, "cov_fixed": P}
    else:
        f = static_fix(x, P, rows, cols, ratio=opt["ratio"], partial=opt["partial"],
                       min_success_rate=opt["min_success_rate"], amb=lambda_float, glonass_fix=opt["glonass_fix"],
                       base_xyz_m=base_xyz_m, origin_xyz_m=rover_xyz0_m, times_s=times,
                       float_nis_per_row=None if rw is None else rw.nis_per_row)
    moving = None
    if rw is not None and not (f["resolution"] or {}).get("accepted", False):     # nothing fixed: the float is all
        moving = _code_mean_of_moving_rover(rows, cols, (x, P), (base_xyz_m, rover_xyz0_m), sigma_amb)
    if moving is not None:
        x, P = _moving_float_state(moving, rw, x.size)
        f = {**f, "offset_m": x[:3].copy(), "cov_m2": P[:3, :3].copy(), "state_fixed": x, "cov_fixed": P}
    steps = dict(code_steps)
    steps["time_s"], steps["signal"] = times[steps["epoch"]], [rows["names"][k] for k in steps["code"]]
    return {**f, "random_walk": rw, "moving_rover": None if moving is None else moving[2], "lambda_float": lambda_float, "iono_sigma_m": sigma_iono, "unflagged_slips": slips,
            "code_clock_steps": steps, "age_noise": age_noise,
            "float_offset_m": x[:3], "float_cov_m2": P[:3, :3], "epochs_used": int(times.size),
            "epoch_pairing": pairs.summary, "state": x, "cov": P, "arcs": arc_table(rows, cols, times),
            "arc_integers": arc_integers(f, x.size)}


def unflagged_slips(rows, base_xyz_m, origin_xyz_m, *, moving: bool) -> np.ndarray:
    """(N,) bool: rows where a slip that no receiver flagged starts a new arc
    (:func:`~cdgps_cli.measurement.slips.time_differenced_slips` of the SD phases at ``origin_xyz_m``); for a
    ``moving`` rover a second pass along the trajectory the first one's displacements sum to (centred on the
    origin), where the lines of sight are the rover's own."""
    n = rows["sats"].size
    if n == 0:
        return np.zeros(0, dtype=bool)
    # the epochs that have rows, numbered in order: a change is taken across an epoch without any row (which cuts no
    # arc), so a slip there is not missed
    epoch = np.unique(np.searchsorted(rows["ptr"], np.arange(n), side="right") - 1, return_inverse=True)[1].ravel()
    channel = channel_index(rows["sats"], rows["code"])
    rng_b = np.linalg.norm(rows["sat_base_xyz"] - np.asarray(base_xyz_m, float), axis=1)
    pos = np.tile(np.asarray(origin_xyz_m, float), (int(epoch.max()) + 1, 1))
    for _ in range(2 if moving else 1):
        los = rows["sat_xyz"] - pos[epoch]
        rng = np.sqrt(np.einsum("ij,ij->i", los, los))
        found, disp = time_differenced_slips(epoch, channel, rows["code"], rows["phase_sd_m"], rng - rng_b,
                                             rows["var_phase"], los / rng[:, None], flagged=rows["slip"])
        trajectory = np.cumsum(disp, axis=0)
        pos = np.asarray(origin_xyz_m, float) + trajectory - trajectory.mean(axis=0)
    # and where a satellite's two signals moved apart (an epoch too poor in satellites for the test above)
    known = rows["slip"] | found
    return found | (geometry_free_slips(epoch, rows["sats"], rows["code"], rows["phase_sd_m"], rows["var_phase"],
                                             flagged=known) & ~known)


def _with_unflagged_slips(rows, times_s, opt: dict, base_xyz_m, origin_xyz_m) -> tuple[dict, dict]:
    """(the SD rows with a slip flag where one no receiver flagged starts a new arc, :func:`~cdgps_cli.measurement.slips.slip_events` of those):
    found by :func:`unflagged_slips`, or, with ``opt["segment_starts"]`` (a given solution's, INIT's), where it cut."""
    if opt["segment_starts"] is None:
        found = unflagged_slips(rows, base_xyz_m, origin_xyz_m, moving=opt["motion"] != "static")
    else:
        found = _rows_at(rows, times_s, opt["segment_starts"]) & ~rows["slip"]
    if found.any():
        rows = dict(rows, slip=rows["slip"] | found)
    return rows, slip_events(rows, found, times_s)


def _rows_at(rows, times_s, keys) -> np.ndarray:
    """(N,) bool: the row of each (satellite and band as INIT names it, "G05:L1", or "G05" for GPS L1 alone; time s:
    the nearest epoch within half a step) of ``keys``."""
    out = np.zeros(rows["sats"].size, dtype=bool)
    times_s = np.asarray(times_s, float)
    if not len(keys) or not times_s.size or not out.size:
        return out
    n_ep = times_s.size
    epoch = np.searchsorted(rows["ptr"], np.arange(out.size), side="right") - 1
    channel = channel_index(rows["sats"], rows["code"])
    first = np.unique(channel, return_index=True)[1]               # one row of each channel: its name
    band = [str(n).split(":")[1] for n in rows["names"]]
    of_name = {}
    for c, i in enumerate(first):
        name = f"{rows['sats'][i]}:{band[rows['code'][i]]}"
        of_name[name] = c
        if name.endswith(":L1"):                                   # a GPS L1-only solution names satellites alone
            of_name.setdefault(name[:-3], c)
    t = np.array([float(k[1]) for k in keys])
    c = np.array([of_name.get(str(k[0]), -1) for k in keys], dtype=np.int64)
    e = np.clip(np.searchsorted(times_s, t), 1, max(n_ep - 1, 1)) if n_ep > 1 else np.zeros(t.size, dtype=np.int64)
    if n_ep > 1:
        e = np.where(np.abs(times_s[e - 1] - t) <= np.abs(times_s[e] - t), e - 1, e)
    half = 0.5 * float(np.median(np.diff(times_s))) if n_ep > 1 else np.inf
    ok = (c >= 0) & (np.abs(times_s[e] - t) <= half)
    key = channel.astype(np.int64) * n_ep + epoch
    order = np.argsort(key, kind="stable")
    want = c[ok] * n_ep + e[ok]
    at = np.minimum(np.searchsorted(key[order], want), out.size - 1)
    hit = key[order][at] == want
    out[order[at[hit]]] = True
    return out


def iono_weighting_sigma_m(opt: dict, base_xyz_m, rover_xyz0_m) -> float:
    """The prior σ (m) of each satellite's SD slant ionosphere in the float that LAMBDA sees, with ``iono_weighted``:
    ``iono_sigma_m_per_km`` × the baseline's length when that reaches
    :data:`~cdgps_cli.config.options.IONO_WEIGHTED_MIN_SIGMA_M`; else 0 (the ionosphere neglected).

    Off by default (measured, session 21): on the GPS L1+L2 car (5.3 km, DD ionosphere 2–3 cm) it turned a partial
    fix with 5 wrong integers into a full one with 8 wrong (both caught by :func:`fixed_phase_check`); on the real
    pairs it fixed the same integers at lower ratios (GEONET L1 3.5 km: 157 → 44) and, at a 50° mask, nothing."""
    if not opt.get("iono_weighted"):
        return 0.0
    sigma = opt["iono_sigma_m_per_km"] * float(np.linalg.norm(np.subtract(rover_xyz0_m, base_xyz_m))) / 1e3
    return float(sigma) if sigma >= IONO_WEIGHTED_MIN_SIGMA_M else 0.0


def _lambda_float(rows, cols, times, x, opt: dict, xyz: tuple, sigma_amb: dict) -> tuple:
    """The float LAMBDA sees when it is not the static least squares' ``x``: (the DD ionosphere's weighting σ, m;
    the arcs' (a, Q) — of the ionosphere-weighted least squares, or of the random walk that holds the rover, else
    None; that random walk's :class:`RandomWalkFloat` or None).  ``xyz``: (base, rover origin) ECEF m."""
    base_xyz_m, rover_xyz0_m = xyz
    n_state = x.size
    sigma_iono = iono_weighting_sigma_m(opt, base_xyz_m, rover_xyz0_m)
    if opt["motion"] == "random_walk" and n_state > 3:
        rw = random_walk_float_that_holds(rows, cols, times, base_xyz_m, rover_xyz0_m, x,
                                          sigma_rw=opt["random_walk_sigma"], initial_sigma_m=opt["initial_sigma_m"],
                                          sigma_iono_m=sigma_iono, **(sigma_amb if opt["glonass_fix"] else {}))
        return sigma_iono, rw, rw
    if sigma_iono > 0 and n_state > 3:
        xi, Pi = static_least_squares(rows, cols, n_state, base_xyz_m, rover_xyz0_m, sigma_iono_m=sigma_iono,
                                      **sigma_amb)
        return sigma_iono, (xi[3:n_state], Pi[3:n_state, 3:n_state]), None      # (xi: with its ionosphere columns)
    return sigma_iono, None, None


def _code_mean_of_moving_rover(rows, cols, static: tuple, xyz: tuple, sigma_amb: dict) -> tuple | None:
    """For a rover under a motion model whose integers were not fixed: (its code's least-squares offset (3,) m, that
    offset's covariance (3, 3) m² scaled by the code's unit variance, and what the INIT says of it) when the static
    float ``static`` = (x, P) lies more than :data:`MOVING_ROVER_FLOAT_M` from it and more than
    :data:`ORIGIN_MOVE_SIGMAS` times their joint 3-D σ — the rover moves, and its static float, which a float INIT
    reports, is nowhere (a 30 m walk: 774 m away) — else None (as ``rtk`` places a moving rover; a static rover seen
    through a 40° mask for a minute has a static float tens of metres from its code's with a σ as large, and is not
    taken for a moving one).  The code's unit variance is its DD residuals' at that offset: a rover that moves
    tens of metres leaves residuals of that size, so its mean's σ is metres, not the centimetres of a static code."""
    x, P = static
    base_xyz_m, rover_xyz0_m = xyz
    xc, Pc = static_least_squares(_code_only_rows(rows), cols, x.size, base_xyz_m, rover_xyz0_m, **sigma_amb)
    apart = float(np.linalg.norm(x[:3] - xc[:3]))
    sigma3 = float(np.sqrt(max(np.trace(P[:3, :3]) + np.trace(Pc[:3, :3]), 0.0)))
    if not (np.all(np.isfinite(xc[:3])) and apart > max(MOVING_ROVER_FLOAT_M, ORIGIN_MOVE_SIGMAS * sigma3)):
        return None
    uv = _code_unit_variance(rows, cols, base_xyz_m, rover_xyz0_m, xc[:3])
    return (xc[:3].copy(), Pc[:3, :3] * max(1.0, uv),
            {"static_float_apart_m": apart, "code_unit_variance": uv})


def _code_unit_variance(rows, cols, base_xyz_m, origin_xyz_m, offset_m) -> float:
    """The unit variance of the DD code residuals at ``offset_m`` (ECEF m from ``origin_xyz_m``): each signal group's
    SD residuals weighted as their DDs (``Σ w r² − (Σ w r)²/Σ w``), summed, over the DDs less the three coordinates."""
    g = _batch_rows(rows, cols, base_xyz_m)
    if not g["first"].size:
        return math.nan
    los = g["sx"] - (np.asarray(origin_xyz_m, dtype=float) + offset_m)
    r = g["zc"] - np.sqrt(np.einsum("ij,ij->i", los, los)) + g["base_rng"]
    w, first = g["wc"], g["first"]
    chi2 = float(np.sum(np.add.reduceat(w * r * r, first) - np.add.reduceat(w * r, first) ** 2 / g["sc"]))
    dof = int(np.sum(g["size"] - 1)) - 3
    return chi2 / dof if dof > 0 else math.nan


def _moving_float_state(moving: tuple, rw: "RandomWalkFloat", n_state: int) -> tuple:
    """The float state (n_state,) and covariance of a moving rover nothing was fixed for: its code's mean position
    (:func:`_code_mean_of_moving_rover`) and the random-walk float's arcs (the static float's arcs fit no position)."""
    x = np.zeros(n_state)
    P = np.zeros((n_state, n_state))
    x[:3], P[:3, :3] = moving[0], moving[1]
    x[3:], P[3:, 3:] = rw.a, rw.Q
    return x, P


def _paired_rows(base, rover, opt: dict, base_xyz_m, *, weigh_age: bool = False) -> tuple:
    """rtk's epoch pairing of the two geometry tables and their SD rows (the mask at both receivers, as the
    batch's; a bridged rover epoch's base observations interpolated to its time, as rtk's and the batch's), and
    with ``weigh_age`` :func:`~cdgps_cli.measurement.base_interpolation.base_age_noise` of option ``age_noise``,
    whose σ the rows' age variance takes (as rtk's; else None and ``age_sigma_m_per_s`` as it is).  CdgpsError when
    no satellite is common."""
    pairs = pair_epochs(rover["time_gps_s"].to_numpy(), base["time_gps_s"].to_numpy(),
                        sync_tol_s=opt["sync_tol_s"], max_age_s=opt["max_age_s"])
    age_noise = base_age_noise(base, pairs, base_xyz_m, opt) if weigh_age else None
    if age_noise is not None:
        opt = {**opt, "age_sigma_m_per_s": age_noise["sigma_m_per_s"]}
    rows = paired_sd_rows(base, rover, pairs, opt, mask_rover=True, base_xyz_m=base_xyz_m)
    if rows["sats"].size == 0:
        raise CdgpsError("no common observations: no satellite observed at both receivers above the mask")
    return pairs, rows, age_noise


def static_float_offset(base, rover, base_xyz_m, rover_xyz0_m, options: dict | None = None) -> tuple:
    """The rover's static float offset from ``rover_xyz0_m`` and its covariance, ((3,) ECEF m, (3, 3) m²):
    :func:`static_baseline`'s float solution without its checks (the DD ionosphere neglected whatever the baseline's
    length) or its fixing, for a caller that only needs to know where the rover is to a metre (rtk's a-priori
    position); and a function giving the same least squares on the code alone (the phase rows' variance
    :data:`_UNUSED_VARIANCE_M2`), as the same pair: the rover's mean position when it moves (the phase of a moving
    rover fits no static position: a walk of 40 m put the static float 789 m away).  The covariance says whether
    the data determine the offset at all (two satellites over ten minutes: σ of tens of metres, the prior's
    ``sigma_pos_m`` of :func:`static_least_squares` bounding it).  ``options`` as :func:`static_baseline`'s."""
    opt = _static_options(options)
    pairs, rows, _ = _paired_rows(base, rover, opt, base_xyz_m)
    cols = arc_columns(rows, pairs.rover_time_s, max_gap_s=opt["max_gap_s"])
    n_state = 3 + (int(cols.max()) - 2 if cols.size else 0)

    def solve(r):
        x, P = static_least_squares(r, cols, n_state, base_xyz_m, rover_xyz0_m, sigma_amb_cycles=opt["amb_sigma_cycles"])
        return x[:3].copy(), P[:3, :3].copy()
    return (*solve(rows),
            lambda: solve(_code_only_rows(rows)))


def _code_only_rows(rows) -> dict:
    """SD rows whose phases take no part in a least squares (each phase row's variance :data:`_UNUSED_VARIANCE_M2`):
    the same normal equations on the code alone."""
    return dict(rows, var_phase=np.full_like(rows["var_phase"], _UNUSED_VARIANCE_M2))


#: a row's variance (m²) that leaves it out of a least squares (its weight ≈ 10⁻¹² of a metre-σ code row's)
_UNUSED_VARIANCE_M2 = 1e12


def arc_table(rows, cols, times_s) -> dict:
    """Per state column from 3 (one per arc): ``sat`` (n_arc,) str, ``signal`` str, ``first_s`` (first epoch, GPS s),
    ``lam_m``, and ``first_dd_s``: the first epoch where the arc is in a double difference (a signal group of at
    least two satellites, :func:`~cdgps_cli.measurement.dd_signals.paired_sd_rows`' ``groups``), NaN for an arc
    that never is (its rows are alone in their epochs' groups: no information but the prior's).  Without the
    group layout ``first_dd_s`` is ``first_s``."""
    times_s = np.asarray(times_s, float)
    first = np.unique(cols, return_index=True)[1]          # cols are numbered in order of first appearance
    epoch = np.searchsorted(rows["ptr"], first, side="right") - 1
    table = {"sat": rows["sats"][first].astype(str), "signal": rows["names"][rows["code"][first]].astype(str),
             "first_s": times_s[epoch], "lam_m": rows["lam_m"][first]}
    lay = rows.get("groups")
    if lay is None:
        table["first_dd_s"] = table["first_s"].copy()
        return table
    in_dd = np.zeros(cols.size + 1, dtype=np.int64)
    np.add.at(in_dd, lay["start"], 1)
    np.add.at(in_dd, lay["stop"], -1)
    rows_dd = np.flatnonzero(np.cumsum(in_dd[:-1]) > 0)
    arcs_dd, first_dd = np.unique(cols[rows_dd], return_index=True)
    first_dd_s = np.full(first.size, np.nan)
    first_dd_s[np.searchsorted(cols[first], arcs_dd)] = times_s[np.searchsorted(rows["ptr"], rows_dd[first_dd],
                                                                                side="right") - 1]
    table["first_dd_s"] = first_dd_s
    return table


def arc_integers(fix: dict, n_state: int) -> np.ndarray:
    """(n_state,) integer of each arc relative to its signal's reference arc (the reference 0), NaN where not
    fixed (and for the first three, position, entries)."""
    out = np.full(n_state, np.nan)
    res = fix["resolution"]
    if res is None:
        return out
    for (a, ref), ok, k in zip(fix["pairs"], res["fixed_mask"], res["integers"]):
        out[ref] = 0.0
        if ok:
            out[a] = float(k)
    return out
