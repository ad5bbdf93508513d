"""Multi-GNSS, multi-frequency RTK baseline on the engine: static or random-walk rover position,
per-group double differences (:mod:`cdgps_cli.measurement.dd_signals`), integers by the one
policy :func:`cdgps_cli.estimation.ambiguity.resolve` (full set of all groups' DD ambiguities).

State: rover ECEF offset (3, m; dynamics :class:`~cdgps_cli.model.dynamics_models.Static` or
:class:`~cdgps_cli.model.dynamics_models.RandomWalk`), one SD ambiguity per (signal, satellite)
lock arc (cycles; Static), and for long baselines one SD slant ionosphere per satellite (m at L1;
RandomWalk).  Ionosphere model by baseline length: below ``iono_threshold_km`` (default 10 km) the
DD ionosphere is neglected (short-baseline model: each frequency fixed directly); above it, it is
estimated ("ionosphere-estimating", prior σ ``iono_sigma_m_per_km`` × length).  GLONASS (FDMA)
groups are kept float unless ``glonass_fix`` (identical receivers only).

The filter is the engine's: each pass (forward, backward) is one
:func:`~cdgps_cli.estimation.driver.drive` over the paired epochs with the dynamics
:class:`_RtkDynamics`, the DD measurement model :class:`~cdgps_cli.measurement.dd_signals.DDGroupModel`
(the single differences whitened as their double differences) and the ambiguity policy as the hook
:class:`_AmbiguityHook` (new and re-biased ambiguity columns, integers by LAMBDA with the ratio and
success-rate tests, fix-and-hold); the step is :class:`~cdgps_cli.estimation.kalman.StepFilter`'s
iterated update in numpy only (scipy's import stays off `cdgps rtk`'s start-up).  In combined mode the
two passes are independent until :func:`_combine`: the backward one runs in a child process forked
beside the forward one (:mod:`cdgps_cli.core.beside`; the same bits, serial with ``CDGPS_SERIAL=1``
or on one CPU).
"""

from __future__ import annotations

from bisect import bisect_left

import numpy as np
import pandas as pd

from cdgps_cli.config.options import (default_direction, CODE_NOISE_CHUNK_S, CODE_NOISE_MIN_FACTOR, CODE_NOISE_MIN_WINDOWS, CODE_NOISE_WINDOW_S,
                                     MULTI_GNSS_DEFAULTS)
from cdgps_cli.core import beside
from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.signals import signal, SYSTEM_NAMES
from cdgps_cli.estimation.ambiguity import (AmbiguityError, SearchLimitError, _reduce, _z_matrix, ld_factorize_symmetric,
                                            ratio_test, search_reduced, success_tail_rate)
from cdgps_cli.estimation.chi2 import chi2_quantile
from cdgps_cli.estimation.driver import EpochGrid, Hook, drive
from cdgps_cli.estimation.kalman import NUMPY_INVERSE, StepFilter
from cdgps_cli.measurement.code_steps import without_code_steps
from cdgps_cli.measurement.dd_signals import DDGroupModel, backward_slips, channel_index, epoch_groups, paired_sd_rows
from cdgps_cli.measurement.differencing import sd_variance
from cdgps_cli.measurement.epoch_pairing import pair_epochs, without_dd
from cdgps_cli.measurement.base_interpolation import base_age_noise  # noqa: F401 (rtk_multi.base_age_noise: API)
from cdgps_cli.measurement.noise import code_noise_factor, effective_sample_size
from cdgps_cli.measurement.slips import geometry_free_slips, slip_events
from cdgps_cli.model.dynamics_models import ConstantVelocity, RandomWalk, Static
from cdgps_cli.model.gps.orbits import OMEGA_E_GPS, azimuth_elevation, ecef_to_geodetic, ephemeris_rows, sat_position_rows
from cdgps_cli.model.gps.positioning import ephemeris_coverage, niell_wet_mapping, tropo_hydrostatic_m

__all__ = ["receiver_geometry", "troposphere_at_epochs", "receivers_code_noise", "solve_rtk", "check_common_signals",
           "reported_positions", "position_nees",
           "RTK_MODES"]

#: motion models of the rover on the one engine: random-walk position, position + velocity, one position
RTK_MODES = ("kinematic", "constant-velocity", "static")

def check_common_signals(base: pd.DataFrame, rover: pd.DataFrame, names, nav, where: dict) -> None:
    """CdgpsError when a signal is not observed by both receivers or a system has no ephemeris."""
    present = {who: set(df["signal"].unique().tolist()) for who, df in (("base", base), ("rover", rover))}  # one pass each
    for name in names:
        for who in ("base", "rover"):
            if name not in present[who]:
                held = (f"present: {', '.join(sorted(present[who]))}" if present[who] else
                        f"it holds none of {', '.join(names)}; --signals auto takes every signal both files hold")
                raise CdgpsError(f"{where[who]} ({who}): no {name} phase observations; the receivers must share "
                                 f"every signal asked for ({held})")
    have = set(nav["sat"].str[0])
    for sysc in sorted({signal(n).system for n in names}):
        if sysc not in have:
            raise CdgpsError(f"the navigation data ({where['nav']}) have no {SYSTEM_NAMES[sysc]} ephemerides "
                             f"('{sysc}' records); {SYSTEM_NAMES[sysc]} signals were asked for")


def receiver_geometry(obs: pd.DataFrame, nav: pd.DataFrame, rx_xyz_m) -> pd.DataFrame:
    """Satellite positions at transmission (ECEF of reception) per row, from the row's own pseudorange.

    τ = P/c − clk_rx + dt_sat, clk_rx the epoch's median clock from the nominal position (so no
    iteration on the receiver position is needed); adds ``sx, sy, sz`` (m), ``sat_clock_m`` (c·dt_sat at
    transmission, m), ``el_rad``, ``trop_m`` and ``eph_row`` (the row of ``nav`` whose ephemeris gave them: two
    rows' models are comparable only from one ephemeris).  Observations
    of satellites without a healthy ephemeris covering them are dropped; ``attrs["dropped"]`` counts
    them per satellite.  Rows without a pseudorange of their own are dropped too; ``attrs["no_code"]``
    counts them per signal.  CdgpsError when none is left.
    """
    has_code, usable = _geometry_mask(obs, nav)
    no_code = obs["signal"].to_numpy()[~has_code]
    dropped = obs.loc[has_code & ~usable].groupby("sat")["time_gps_s"].nunique().to_dict()
    df = obs[usable].copy()
    if df.empty:
        raise CdgpsError(f"no observation is covered by the navigation data (satellites without a healthy "
                         f"ephemeris covering their epochs: {' '.join(sorted(dropped)) or 'none'})")
    group, at_first = _first_of_pairs(df["time_gps_s"].to_numpy(), df["sat"].to_numpy())
    first = df.iloc[at_first]                   # df.drop_duplicates(["time_gps_s", "sat"]): the first row of each pair
    clk = np.zeros(len(first))
    t = first["time_gps_s"].to_numpy()
    tau = first["pseudorange_m"].to_numpy() / SPEED_OF_LIGHT_M_S
    eph = ephemeris_rows(nav, first["sat"].to_numpy(), t)        # every row's ephemeris, selected once
    for _ in range(2):
        xyz, clk = sat_position_rows(eph, t - tau + clk)           # all satellites and epochs at once
    rx = np.asarray(rx_xyz_m, dtype=float)
    rng = np.linalg.norm(xyz - rx, axis=1)
    c_rx = _group_median(first["pseudorange_m"].to_numpy() / SPEED_OF_LIGHT_M_S + clk - rng / SPEED_OF_LIGHT_M_S, t)
    tau = tau - c_rx + clk
    xyz, clk = sat_position_rows(eph, t - c_rx - tau)
    th = OMEGA_E_GPS * tau
    c, s = np.cos(th), np.sin(th)
    rot = np.stack([c * xyz[:, 0] + s * xyz[:, 1], -s * xyz[:, 0] + c * xyz[:, 1], xyz[:, 2]], axis=-1)
    _, el = azimuth_elevation(rx, rot)
    lat, _, h = ecef_to_geodetic(rx)
    trop = tropo_hydrostatic_m(el, lat, h, t)
    # every row gets its (epoch, satellite) pair's geometry: df.merge(geometry, on=[time, sat], how="left")'s table
    out = df.reset_index(drop=True)
    out.attrs = {}                              # the merge's table keeps none of the reader's notes
    for name, v in (("sx", rot[:, 0]), ("sy", rot[:, 1]), ("sz", rot[:, 2]), ("sat_clock_m", SPEED_OF_LIGHT_M_S * clk),
                    ("el_rad", el), ("trop_m", trop), ("eph_row", eph.rows)):
        out[name] = v[group]
    out.attrs["dropped"] = {k: int(v) for k, v in sorted(dropped.items())}
    out.attrs["no_code"] = {str(k): int(v) for k, v in zip(*np.unique(no_code, return_counts=True))} if no_code.size else {}
    return out


def geometry_rows(obs: pd.DataFrame, nav: pd.DataFrame) -> pd.DataFrame:
    """The rows of ``obs`` :func:`receiver_geometry` keeps: those with a pseudorange of their own and a healthy
    ephemeris covering them (a caller that must see the same rows without their geometry)."""
    return obs[_geometry_mask(obs, nav)[1]]


def _geometry_mask(obs: pd.DataFrame, nav: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(rows with a pseudorange, rows with one and a healthy ephemeris covering them) of ``obs``, (N,) bool each."""
    has_code = np.isfinite(obs["pseudorange_m"].to_numpy(dtype=np.float64))
    usable = np.zeros(len(obs), dtype=bool)
    usable[has_code] = ephemeris_coverage(nav, obs["sat"].to_numpy()[has_code],
                                          obs["time_gps_s"].to_numpy(dtype=np.float64)[has_code])
    return has_code, usable


def troposphere_at_epochs(geometry: pd.DataFrame, time_s: np.ndarray, xyz_m: np.ndarray) -> pd.DataFrame:
    """``geometry`` (:func:`receiver_geometry`) with ``trop_m`` evaluated at each epoch's own position.

    :func:`receiver_geometry` evaluates the troposphere at one position for the whole record; the
    hydrostatic delay changes by about 0.3 mm per metre of height (times the mapping), so a rover that
    climbs, or whose a-priori position is metres off, needs it where it is at each epoch, as RTKLIB
    evaluates it at its current estimate.  The elevation stays the table's (a kilometre moves it by
    less than 0.01°).

    Parameters
    ----------
    geometry : DataFrame
        Rows with ``time_gps_s`` and ``el_rad``.
    time_s : ndarray (n,)
        Sorted epoch times, GPS s.
    xyz_m : ndarray (n, 3)
        ECEF position (m) of each epoch; rows of an epoch without one (not in ``time_s`` or NaN) keep
        their ``trop_m``.
    """
    t = geometry["time_gps_s"].to_numpy()
    k = np.clip(np.searchsorted(time_s, t), 0, max(time_s.size - 1, 0))
    at = (time_s.size > 0) & (time_s[k] == t) if time_s.size else np.zeros(t.size, dtype=bool)
    lat, _, h = ecef_to_geodetic(np.asarray(xyz_m, dtype=float))
    at &= np.isfinite(h[k]) if time_s.size else at
    out = geometry.copy()
    trop = out["trop_m"].to_numpy().copy()
    trop[at] = tropo_hydrostatic_m(out["el_rad"].to_numpy()[at], lat[k[at]], h[k[at]], t[at])
    out["trop_m"] = trop
    return out


def _first_of_pairs(t, sats):
    """The (time, satellite) pairs of rows ``t`` (N,), ``sats`` (N,) in order of first appearance:
    each row's pair index (N,) and the row of each pair's first appearance (the rows
    ``drop_duplicates`` keeps, in their order).  Times are compared exactly, as a merge on them does."""
    t_code = pd.factorize(t)[0]
    s_code, s_names = pd.factorize(sats)
    group = pd.factorize(t_code.astype(np.int64) * max(len(s_names), 1) + s_code)[0]
    # codes are numbered in order of first appearance: a row is its pair's first exactly when its code
    # exceeds every code before it
    at_first = np.flatnonzero(group > np.r_[-1, np.maximum.accumulate(group)[:-1]]) if group.size else group
    return group, at_first


def _group_median(values, keys):
    """Median of the finite ``values`` (N,) of each equal ``keys`` (N,), given back for every element:
    pandas' ``Series.groupby(keys).transform("median")`` (the same numbers: the middle element, or
    the mean of the two middle ones), in numpy."""
    uk, inv = np.unique(keys, return_inverse=True)
    inv = inv.reshape(-1)
    counts = np.bincount(inv, minlength=uk.size)
    start = np.cumsum(counts) - counts
    sv = values[np.lexsort((values, inv))]
    lo, hi = sv[start + (counts - 1) // 2], sv[start + counts // 2]
    return np.where(counts % 2 == 1, lo, (lo + hi) / 2)[inv]


def _few(sats) -> str:
    """Satellite names, sorted, the first 12 and the count."""
    s = sorted(set(np.asarray(sats).astype(str).tolist()))
    return " ".join(s[:12]) + (f" … ({len(s)})" if len(s) > 12 else "") if s else "no satellite"


class _State:
    """Ambiguity / ionosphere columns appearing and vanishing with the satellites (``index``: key → column)
    of the filter ``step`` (a :class:`~cdgps_cli.estimation.kalman.StepFilter`: ``x``, ``P`` are its own)."""

    def __init__(self, n_pos, step=None):
        self.n_motion = n_pos
        self.keys = [("pos", i) for i in range(n_pos)]
        self.index = {k: i for i, k in enumerate(self.keys)}
        self.step = step if step is not None else StepFilter(np.zeros(n_pos), np.eye(n_pos) * 1e4, NUMPY_INVERSE)
        self.fix_products = (None, None, None, None)    # _fix's (Ts, P, Ts P, Ts P Tsᵀ), for _hold

    @property
    def x(self):
        return self.step.x

    @x.setter
    def x(self, value):
        self.step.x = value

    @property
    def P(self):
        return self.step.P

    @P.setter
    def P(self, value):
        self.step.P = value

    def keep(self, wanted):
        idx = [i for i, k in enumerate(self.keys) if k[0] == "pos" or k in wanted]
        if len(idx) == len(self.keys):
            return
        self.keys = [self.keys[i] for i in idx]
        self.index = {k: i for i, k in enumerate(self.keys)}
        self.x, self.P = self.x[idx], self.P[np.ix_(idx, idx)]

    def add(self, key, value, var):
        self.index[key] = len(self.keys)
        self.keys.append(key)
        self.x = np.append(self.x, value)
        n = len(self.x)
        P = np.zeros((n, n))
        P[:-1, :-1] = self.P
        P[-1, -1] = var
        self.P = P

    def col(self, key):
        return self.index[key]


def _amb_key(g, j):
    """State key of row ``j``'s SD ambiguity: signal, satellite, and whether its half cycle is
    unresolved (a flag that comes or goes starts a new ambiguity)."""
    return ("N", g["signal"], g["sats"][j], bool(g["half"][j]))


def _amb_keys(rows) -> list:
    """:func:`_amb_key` of every row of :func:`~cdgps_cli.measurement.dd_signals.paired_sd_rows`, once for the run."""
    names = [str(n) for n in rows["names"]]
    return [("N", names[c], s, h) for c, s, h in zip(rows["code"].tolist(), rows["sats"].tolist(), rows["half"].tolist())]


def _groups_with_keys(rows, k, amb_keys, slip_rows):
    """:func:`~cdgps_cli.measurement.dd_signals.epoch_groups` of epoch ``k``, each group with its
    rows' ambiguity keys (``amb_keys``, :func:`_amb_keys`) and ``slip_at``, the positions of its
    slipped rows (``slip_rows``: the run's, ascending list)."""
    groups = epoch_groups(rows, k)
    for g in groups:
        a, b = g["rows"]
        g["amb_keys"] = amb_keys[a:b]
        g["slip_at"] = [r - a for r in slip_rows[bisect_left(slip_rows, a):bisect_left(slip_rows, b)]]
    return groups


#: the state keys of the base's and the rover's zenith wet delays (m), in that order
WET_KEYS = (("T", "base"), ("T", "rover"))


def _prepare_state(st, groups, opt, iono):
    keys = [g["amb_keys"] if "amb_keys" in g else [_amb_key(g, j) for j in range(len(g["sats"]))] for g in groups]
    wanted = {k for ks in keys for k in ks}
    if iono:
        wanted |= {("I", s) for g in groups for s in g["sats"]}
    wet = opt.get("wet_estimated", False)
    if wet:
        wanted |= set(WET_KEYS)
    for g, ks in zip(groups, keys):
        for j in (g["slip_at"] if "slip_at" in g else np.flatnonzero(g["slip"])):
            if ks[j] in st.index:
                wanted.discard(ks[j])
    st.keep(wanted)
    if wet and WET_KEYS[0] not in st.index:
        for key in WET_KEYS:                      # RTKLIB's start: 0.15 ± 0.3 m at each receiver
            st.add(key, float(opt["tropo_initial_m"]), float(opt["tropo_sigma_m"]) ** 2)
    wet_col = np.array([st.index[k] for k in WET_KEYS], dtype=np.int64) if wet else None
    for g, ks in zip(groups, keys):
        g["wet_col"] = wet_col
        est = None
        for j, s in enumerate(g["sats"]):
            if ks[j] not in st.index:
                est = (g["phase_sd_m"] - g["code_sd_m"]) / g["lam_m"] if est is None else est
                st.add(ks[j], est[j], (opt["amb_sigma_cycles"]) ** 2)
            if iono and ("I", s) not in st.index:
                st.add(("I", s), 0.0, iono ** 2)
    for g, ks in zip(groups, keys):
        g["amb_col"] = np.array([st.index[k] for k in ks], dtype=np.int64)
        g["iono_col"] = (np.array([st.index[("I", s)] for s in g["sats"]], dtype=np.int64) if iono
                         else np.full(len(ks), -1, dtype=np.int64))


def _decorrelated(L, d):
    """:func:`~cdgps_cli.estimation.ambiguity.decorrelate`'s ``(L, d, Z)``, with ``Z`` None when the
    reduction made no operation (Z = I: most epochs, once Z is carried), without forming it."""
    Lr, dl, ops = _reduce(L, d)
    return Lr, dl, (_z_matrix(ops, dl.shape[0]) if len(ops) else None)


class _CarriedDecorrelation:
    """LAMBDA's integer transformation Z of the DD ambiguities, carried from one epoch to the next.

    Reducing ~30 DD ambiguities from scratch takes ~800 adjacent swaps each epoch, while their
    covariance changes little between epochs: starting from the previous epoch's Z, ``Zᵀ Q Z`` needs
    a few.  The integer least-squares solution does not depend on the unimodular Z (``a = Z⁻ᵀ z``,
    exact integer arithmetic), so the integers — and the fixed positions — are those of the reduction
    from scratch; the ratio agrees to rounding (~1e-12 relative).  Z restarts from the identity when
    the set of DD ambiguities (signal, satellites, reference) changes, or if its entries grow large.
    """

    MAX_ENTRY = 2**20

    def __init__(self):
        self.keys, self.Z, self.Zinv = None, None, None
        self.last_fix = None          # (Ts, integers) of the last accepted fix, for fix-and-hold
        self.fixed_keys = None        # the DD set (:func:`_dd_set`'s keys) of the last accepted whole-set fix

    def _update(self, keys, Qa):
        """Carry Z to this epoch's ``Qa``; the reduced factors ``(L, d)`` of ``Zᵀ Qa Z`` when they are
        at hand (None when Z had to restart)."""
        n = Qa.shape[0]
        if keys != self.keys:
            eye = np.eye(n, dtype=np.int64)
            self.keys, self.Z, self.Zinv = keys, eye, eye
        Q = self.Z.T @ Qa @ self.Z
        L, d, Z1 = _decorrelated(*ld_factorize_symmetric(0.5 * (Q + Q.T)))
        if Z1 is None:
            return L, d
        eye = np.eye(n, dtype=np.int64)
        if np.array_equal(Z1, eye):
            return L, d
        Z = self.Z @ Z1
        Zinv = np.rint(np.linalg.inv(Z)).astype(np.int64)
        if np.abs(Z).max() < self.MAX_ENTRY and np.array_equal(Z @ Zinv, eye):
            self.Z, self.Zinv = Z, Zinv
            return L, d                      # decorrelate's factors are those of Z1ᵀ Q Z1 = (Z Z1)ᵀ Qa (Z Z1)
        self.Z, self.Zinv = eye, eye         # start again from scratch
        return None

    def _reduced(self, keys, Qa):
        """``Zᵀ`` and the reduced factors ``L``, ``d`` of ``Zᵀ Qa Z`` (Z carried, else reduced here)."""
        factors = self._update(keys, Qa)
        Zt = self.Z.T
        if factors is not None:
            return (Zt, *factors)
        Q = Zt @ Qa @ Zt.T                   # Z restarted (or a caller's Z): reduce here
        L, d, Z1 = _decorrelated(*ld_factorize_symmetric(0.5 * (Q + Q.T)))
        return (Zt if Z1 is None else (self.Z @ Z1).T), L, d

    def resolve(self, keys, a, Qa, threshold, min_success_rate):
        """Integers of the DD ambiguities ``a`` (n,) cycles, covariance ``Qa`` (n, n) cycles², in the
        decorrelated space ``z = Zᵀ a``: the longest tail of z whose bootstrapped success rate is at
        least ``min_success_rate`` (:func:`~cdgps_cli.estimation.ambiguity.success_tail`: the whole
        set when it qualifies, else a partial set), accepted when it also passes the ratio test.
        The tail's own factors are the tail of the reduced ``L``, ``d`` (``d[i]`` is conditioned on
        ``i+1 …``), so the integer search runs on them directly.

        Returns ``accepted``, ``ratio``, ``success_rate`` (of the set tried), ``partial``, ``rows``
        ((m, n) integer rows of Zᵀ fixed) and ``integers`` (m,)."""
        try:
            Zt, L, d = self._reduced(keys, Qa)
        except AmbiguityError:               # the carried Z made Zᵀ Qa Z too ill-conditioned: from scratch
            n = Qa.shape[0]
            self.Z = self.Zinv = np.eye(n, dtype=np.int64)
            try:
                Zt, L, d = self._reduced(keys, Qa)
            except AmbiguityError:
                return {"accepted": False, "ratio": np.nan, "success_rate": 0.0, "rows": None, "integers": None,
                        "partial": False}
        z = Zt @ a
        k, rate = success_tail_rate(d, min_success_rate)
        n = len(z)
        out = {"accepted": False, "ratio": np.nan, "success_rate": rate, "rows": None, "integers": None, "partial": 0 < k < n}
        if n - k < 1:
            return out
        offset = np.floor(z[k:] + 0.5)
        try:
            zn, sq = search_reduced(L[k:, k:], d[k:], z[k:] - offset)
        except SearchLimitError:
            return out
        accepted, out["ratio"] = ratio_test(sq, threshold)
        if accepted:
            out.update(accepted=True, rows=Zt[k:], integers=(zn[0] + offset).astype(np.int64))
        return out


def _fix(st, groups, opt, carried):
    """DD ambiguities of every fixable group, resolved as one set (partially when only part of it
    reaches the success rate): the fixed position (or None), the number of (decorrelated)
    ambiguities fixed, the ratio, the fixed position's covariance (3, 3; m², or None) and whether only
    part of the set was fixed.

    When the set fails and holds arcs that were in no accepted fix yet (a satellite just risen, an arc just
    restarted by a slip or a base gap), it is resolved again without them (they stay float): a new arc's float
    takes its value from the float position, and one biased arc then failed the ratio of the whole set and lost
    the fix of every arc already fixed (RTKLIB demo5's ``arfilter``; a real mosaic pair lost two epochs when one
    base phase of C02 B2I was missing for one epoch)."""
    got = _dd_set(st, groups, opt)
    if got is None:
        return None, 0, np.nan, None, False
    res = carried.resolve(got["keys"], got["a"], got["Qa"], opt["ratio"], opt["min_success_rate"])
    new_arcs = (_arcs_of(got["keys"]) - _arcs_of(carried.fixed_keys)
                if not res["accepted"] and carried.fixed_keys else set())
    if new_arcs:
        known = _dd_set(st, groups, opt, leave_out=new_arcs)
        if known is not None and known["a"].size >= ARC_FILTER_MIN_DD:
            again = carried.resolve(known["keys"], known["a"], known["Qa"], opt["ratio"], opt["min_success_rate"])
            if again["accepted"]:
                got, res = known, again
    if not res["accepted"]:
        return None, 0, res["ratio"], None, False
    Ts = _dd_rows_on_state(res["rows"], got["plus"], got["ref_cols"], got["sizes"], len(st.x))   # the fixed combinations
    TsP = Ts @ st.P
    Qs = TsP @ Ts.T
    m = st.n_motion                                   # position, and velocity in constant-velocity mode
    Pxs = st.P[:m] @ Ts.T
    sol = np.linalg.solve(Qs, np.column_stack([Ts @ st.x - res["integers"], Pxs.T]))   # one factorisation, m + 1 columns
    dx = Pxs @ sol[:, 0]
    cov = st.P[:m, :m] - Pxs @ sol[:, 1:]
    carried.last_fix = (Ts, res["integers"])
    if not res["partial"]:
        carried.fixed_keys = got["keys"]
    st.fix_products = (Ts, st.P, TsP, Qs)
    return st.x[:m] - dx, len(res["integers"]), res["ratio"], 0.5 * (cov + cov.T), res["partial"]


#: the fewest DD ambiguities the set without the new arcs must hold to be tried (:func:`_fix`): on a real u-blox walk
#: a retry kept 4, then 3, held them (their ratio grew into the thousands under fix-and-hold) and the float then
#: jumped 6 m when the geometry changed; RTKLIB demo5 asks 4 satellites to fix and 5 to hold
ARC_FILTER_MIN_DD = 6


def _dd_set(st, groups, opt, leave_out=frozenset()) -> dict | None:
    """The DD ambiguities LAMBDA is given at this epoch: per fixable group, its SD ambiguity columns less the
    reference's (``plus``, ``ref_cols``, ``sizes``: the DD operator T by indexing), their float values ``a`` = T x and
    covariance ``Qa`` = T P Tᵀ (the same numbers as the products: each entry one difference of two terms), the
    decorrelation's ``keys`` (:func:`_arcs_of` gives the SD arcs taking part).  Arcs in ``leave_out`` stay float (a
    group whose reference is one of them with it).  None when nothing is fixable."""
    plus, ref_cols, sizes, keys = [], [], [], []
    for g in groups:
        if g["signal"].startswith("R:") and not opt["glonass_fix"]:
            continue
        ref = g["ref"]
        out = g["half"] if not leave_out else g["half"] | np.array([k in leave_out for k in g["amb_keys"]])
        if out[ref]:
            continue                                  # the reference's half cycle unresolved (or its arc left out)
        use = ~out                                    # DDs of satellites with an unresolved half cycle stay float
        use[ref] = False
        n_use = int(np.count_nonzero(use))
        if not n_use:
            continue
        plus.append(g["amb_col"][use])
        ref_cols.append(g["amb_col"][ref])
        sizes.append(n_use)
        if "amb_keys" not in g:
            keys.append((g["signal"], tuple(g["sats"]), ref, tuple(np.flatnonzero(g["half"]))))
        else:                      # the half flags are in the arcs' keys; the arcs left out are named (a third item)
            keys.append((tuple(g["amb_keys"]), ref) if not leave_out
                        else (tuple(g["amb_keys"]), ref, tuple(np.flatnonzero(out).tolist())))
    if not plus:
        return None
    plus = np.concatenate(plus) if len(plus) > 1 else plus[0]
    ref_cols, sizes = np.array(ref_cols), np.array(sizes)
    minus = np.repeat(ref_cols, sizes)
    a = st.x[plus] - st.x[minus]
    TP = st.P[plus] - st.P[minus]
    Qa = TP[:, plus] - TP[:, minus]
    return {"plus": plus, "ref_cols": ref_cols, "sizes": sizes, "keys": tuple(keys), "a": a, "Qa": 0.5 * (Qa + Qa.T)}


def _arcs_of(keys) -> set:
    """The SD arcs (state keys) a DD set of :func:`_dd_set`'s ``keys`` fixes: each group's reference and the arcs
    whose half cycle is resolved and that were not left out (a set of groups without arc keys: none)."""
    arcs = set()
    for key in keys or ():
        if not isinstance(key[0], tuple):
            continue
        amb, ref, out = key[0], key[1], set(key[2]) if len(key) > 2 else set()
        arcs.update(k for j, k in enumerate(amb) if (j == ref or not k[3]) and j not in out)
    return arcs


def _dd_rows_on_state(rows, plus, ref_cols, sizes, n_state):
    """``rows @ T`` (rows: (m, p) integers) for the DD operator T (p, n_state) of groups of ``sizes``
    DDs, row i +1 at column ``plus[i]`` and −1 at its group's reference column ``ref_cols[g]``,
    without forming T: the ``plus`` columns (all distinct) are ``rows``' columns, a reference column
    minus the sum of its group's (integers: the same numbers as the product)."""
    Ts = np.zeros((rows.shape[0], n_state))
    Ts[:, plus] = rows
    Ts[:, ref_cols] = -np.add.reduceat(rows, np.cumsum(sizes) - sizes, axis=1)
    return Ts


#: a DD's linearization error (m) below which rtk's update does not relinearize (:meth:`~cdgps_cli.measurement.
#: dd_signals.DDGroupModel.linear_within`): a micron, against millimetres of phase noise.  A second pass at each epoch
#: moved the positions of the real pairs by 10-30 nm and cost 7 % of the whole command
RTK_LINEARIZATION_TOL_M = 1e-6


#: largest 3-D σ (m, √trace of the covariance) of a position reported fixed: integers held on too few satellites
#: or with too weak a geometry do not set the position to centimetres (a u-blox rover that lost the phase of six
#: of ten satellites for one epoch kept three held integers: σ_up 0.3 m, 16 cm off); such an epoch is float
MAX_FIXED_SIGMA_M = 0.1

#: epochs a single released ambiguity (:func:`_one_to_release`) has to be fixed again in before every ambiguity
#: is released (:meth:`_AmbiguityHook._check_release`)
RELEASE_RECOVERY_EPOCHS = 20

#: variance of the fix-and-hold pseudo-measurement of a fixed integer combination, cycles² (RTKLIB's VAR_HOLDAMB)
HOLD_VARIANCE_CYCLES2 = 0.001


_EYES: dict = {}


def _eye(n: int) -> np.ndarray:
    """``np.eye(n)``, kept per size (read only)."""
    e = _EYES.get(("eye", n))
    if e is None:
        e = _EYES[("eye", n)] = np.eye(n)
        e.flags.writeable = False
    return e


def _hold_variance(n: int) -> np.ndarray:
    """``HOLD_VARIANCE_CYCLES2 * np.eye(n)``, kept per size (read only)."""
    e = _EYES.get(("hold", n))
    if e is None:
        e = _EYES[("hold", n)] = HOLD_VARIANCE_CYCLES2 * np.eye(n)
        e.flags.writeable = False
    return e


def _hold(st, fix) -> None:
    """Fix-and-hold: the fixed integer combinations ``Ts x = integers`` as measurements of variance
    :data:`HOLD_VARIANCE_CYCLES2` (RTKLIB ``holdamb``), so the float ambiguities keep the integers.
    ``fix`` is ``(Ts, integers)``; the products ``Ts P``, ``Ts P Tsᵀ`` :func:`_fix` left in
    ``st.fix_products`` are reused while they are of this ``Ts`` and the state's covariance is still
    theirs (the same numbers as forming them again)."""
    Ts, ints = fix
    Ts_fix, P_fix, TsP, Qs = st.fix_products
    if Ts is not Ts_fix or st.P is not P_fix:     # the state changed since the fix: form them
        TsP = Ts @ st.P
        Qs = TsP @ Ts.T
    S = Qs + _hold_variance(len(ints))
    K = np.linalg.solve(S, TsP).T
    st.x = st.x + K @ (ints - Ts @ st.x)
    P = st.P - K @ Ts @ st.P
    st.P = 0.5 * (P + P.T)


def solve_rtk(base: pd.DataFrame, rover: pd.DataFrame, base_xyz_m, rover_xyz0_m, *, options: dict | None = None,
              progress=None, code_noise: dict | None = None) -> dict:
    """Epoch-by-epoch multi-GNSS RTK (kinematic) or static solution.

    Parameters
    ----------
    base, rover : DataFrame
        :func:`receiver_geometry` tables (``time_gps_s``, ``sat``, ``signal``, ``phase_cycles``,
        ``pseudorange_m``, ``lli``, ``wavelength_m``, ``sx/sy/sz``, ``el_rad``).
    base_xyz_m, rover_xyz0_m : array_like (3,)
        Known base position and the rover's a-priori position, ECEF m.
    options : dict
        Keys of :data:`cdgps_cli.config.options.MULTI_GNSS_DEFAULTS`.
    code_noise : dict, optional
        :func:`receivers_code_noise` of these observations and options, when the caller has it (a second
        solve of the same files); found here otherwise.

    Returns
    -------
    dict
        ``time_gps_s`` (n,), ``float_xyz_m`` / ``fixed_xyz_m`` (n, 3; NaN rows where not fixed),
        ``fixed`` (n,) bool, ``n_dd_ambiguities`` (n,), ``ratio`` (n,), ``iono_model``, ``last_xyz_m``
        (the last epoch's fixed, else float, position), ``static_xyz_m`` (static mode: the solution from every epoch,
        the forward pass's last epoch, or the backward pass's first; None in the kinematic modes),
        ``float_cov_m2`` / ``fixed_cov_m2`` (n, 3, 3; ECEF, m²; NaN where not fixed), ``n_satellites`` (n,),
        ``epoch_pairing`` (the summary of :func:`~cdgps_cli.measurement.epoch_pairing.pair_epochs`: rover
        epochs used, bridged, dropped with reasons) and ``base_age_s`` (n,; rover − base time, s); in
        constant-velocity mode the velocity too, ``float_vel_m_s`` / ``fixed_vel_m_s`` (n, 3; ECEF, m/s) and
        ``float_vel_cov_m2_s2`` / ``fixed_vel_cov_m2_s2`` (n, 3, 3), fixed where the position is.
    """
    opt = {**MULTI_GNSS_DEFAULTS, **(options or {})}
    if opt["fix_and_hold"] and not int(opt["hold_after_fixes"]) >= 1:     # the run counter starts at 0: nothing to hold yet
        raise CdgpsError(f"invalid rtk options: hold_after_fixes: expected >= 1 consecutive fixed epochs, "
                         f"got {opt['hold_after_fixes']!r}")
    base_xyz = np.asarray(base_xyz_m, float)
    origin = np.asarray(rover_xyz0_m, float)
    length_km = np.linalg.norm(origin - base_xyz) / 1e3
    iono = opt["iono_sigma_m_per_km"] * length_km if length_km >= opt["iono_threshold_km"] else 0.0
    opt["tropo_threshold_km"] = wet_threshold_km(opt)
    opt["wet_estimated"] = opt["rover_elevation"] = length_km >= opt["tropo_threshold_km"]
    pairs = _paired_epochs(base, rover, opt)
    times = pairs.rover_time_s
    code_noise = receivers_code_noise(base, rover, opt) if code_noise is None else code_noise
    opt["code_variance_factor"] = code_noise["factor"]
    age_noise = base_age_noise(base, pairs, base_xyz, opt)
    opt["age_sigma_m_per_s"] = age_noise["sigma_m_per_s"]
    rows = paired_sd_rows(base, rover, pairs, opt, mask_rover=True,    # the mask at both receivers, as RTKLIB's
                          base_xyz_m=base_xyz)
    if opt["wet_estimated"]:
        rows = _with_wet_mapping(rows, base_xyz, origin)
    rows, code_steps = without_code_steps(rows)     # a clock jump in the codes alone: new arcs start from the code
    rows, gf_found = _with_geometry_free_slips(rows)
    n_ep = times.size
    if not rows["groups"]["start"].size:                     # no epoch has a group of two satellites
        raise CdgpsError(f"no double differences: no epoch of the {n_ep} paired has two satellites of one signal "
                         f"observed at both receivers above the {opt['mask_deg']:g}° mask")
    direction = opt["direction"] or default_direction(opt["mode"])
    res = _epochs_with_dd(_passes(rows, times, direction, opt, base_xyz, origin, iono, progress))
    times, age_s, summary = times[res["with_dd"]], pairs.age_s[res["with_dd"]], without_dd(pairs.summary, res["without_dd"])
    ok = res["fixed"]
    last = _solution_at(res, -1)
    return {"time_gps_s": times, "float_xyz_m": res["float_xyz"], "fixed_xyz_m": np.where(ok[:, None], res["fixed_xyz"], np.nan),
            "fixed": ok, "n_dd_ambiguities": res["n_fixed"], "ratio": res["ratio"],
            "iono_model": "estimated" if iono else "neglected (short baseline)", "baseline_km": length_km,
            "wet_troposphere": _wet_summary(res, opt),
            "last_xyz_m": last, "static_xyz_m": _all_epochs_solution(res, direction) if opt["mode"] == "static" else None, "epoch_pairing": {**summary, "interpolated": rows["interpolated_epochs"]},
            "base_age_s": age_s,
            "float_cov_m2": res["float_cov"], "fixed_cov_m2": np.where(ok[:, None, None], res["fixed_cov"], np.nan),
            "n_satellites": res["ns"], "direction": direction, "fixes_rejected": int(res.get("rejected", 0)),
            "static_every_line_all_epochs": res.get("every_line_all_epochs"),
            "partial_fixes": int(res["partial"].sum()), "wrong_fix_resets": int(res["wrong_fix_resets"].sum()),
            "code_noise": code_noise, "age_noise": age_noise,
            "code_clock_steps": {"time_gps_s": times[code_steps["epoch"]].tolist(), "step_m": code_steps["step_m"].tolist(),
                                 "signal": [rows["names"][k] for k in code_steps["code"]]},
            "ambiguities_released": int(res["released"].sum()),
            "unflagged_slips": _slip_events(rows, gf_found, pairs.rover_time_s),
            "float_variance": res.get("float_variance"),
            **_velocities(res, ok)}


def reported_positions(res: dict) -> tuple[np.ndarray, np.ndarray]:
    """The position each epoch of a :func:`solve_rtk` solution reports and its covariance: fixed where it is fixed,
    else float (ECEF m (n, 3); m² (n, 3, 3))."""
    fixed = np.asarray(res["fixed"], dtype=bool)
    return (np.where(fixed[:, None], res["fixed_xyz_m"], res["float_xyz_m"]),
            np.where(fixed[:, None, None], res["fixed_cov_m2"], res["float_cov_m2"]))


def position_nees(xyz, cov, truth_xyz) -> np.ndarray:
    """Normalised estimation error squared of positions ``xyz`` (n, 3) with covariances ``cov`` (n, 3, 3) against the
    truth (3,) or (n, 3): eᵀ P⁻¹ e per epoch (n,); 3 on average when the covariances hold."""
    err = np.asarray(xyz, float) - np.asarray(truth_xyz, float)
    return np.einsum("ni,ni->n", err, np.linalg.solve(np.asarray(cov, float), err[:, :, None])[:, :, 0])


def wet_threshold_km(opt: dict) -> float:
    """The baseline length from which the zenith wet delays are estimated: ``tropo_threshold_km``, or when None the
    ionosphere's ``iono_threshold_km``."""
    t = opt.get("tropo_threshold_km")
    return float(opt["iono_threshold_km"] if t is None else t)


def _with_wet_mapping(rows: dict, base_xyz, rover_xyz) -> dict:
    """``rows`` (:func:`~cdgps_cli.measurement.dd_signals.paired_sd_rows` with ``el_rover`` and ``el_base_wet``) with
    each row's Niell wet mapping factor at the base (``mw_b``, at the base's elevation at the instant its observation
    stands for: an interpolated one's, the rover's time) and at the rover (``mw_r``), each at its receiver's
    latitude."""
    lat_b, lat_r = (float(ecef_to_geodetic(np.asarray(p, float))[0]) for p in (base_xyz, rover_xyz))
    rows = dict(rows)
    return dict(rows, mw_b=niell_wet_mapping(rows.pop("el_base_wet"), lat_b),
                mw_r=niell_wet_mapping(rows.pop("el_rover"), lat_r))


def _wet_summary(res: dict, opt) -> dict:
    """The JSON summary's word on the zenith wet delays: neglected (short baseline), or estimated with the prior and
    process noise used and the last epoch's estimates (m) and σ (m) at each receiver."""
    if not opt["wet_estimated"]:
        return {"model": "neglected (short baseline)", "threshold_km": opt["tropo_threshold_km"]}
    last = res.get("wet_last") or {}
    return {"model": "estimated", "threshold_km": opt["tropo_threshold_km"], "initial_m": opt["tropo_initial_m"],
            "sigma_m": opt["tropo_sigma_m"], "rw_m_per_sqrt_s": opt["tropo_rw_m_per_sqrt_s"], **last}


def _solution_at(res: dict, k: int) -> np.ndarray:
    """A pass's position at epoch ``k``: fixed where it is fixed, else float (ECEF m (3,))."""
    return res["fixed_xyz"][k] if res["fixed"][k] else res["float_xyz"][k]


def _all_epochs_solution(res: dict, direction: str) -> np.ndarray:
    """Static mode's solution from every epoch (ECEF m (3,)): the forward pass's last epoch (forward), the backward
    pass's first (backward), every epoch's (combined, :func:`_static_smoothed`; where the passes' solutions from every
    epoch disagreed, the last epoch's combination)."""
    return _solution_at(res, 0 if direction == "backward" else -1)


def _epochs_with_dd(res: dict) -> dict:
    """The passes' per-epoch results (:func:`_passes`) at the epochs that held a double difference (``ns`` > 0),
    their mask as ``with_dd`` (n,) bool, and the count of the others as ``without_dd``."""
    keep = res["ns"] > 0
    n = keep.size
    out = {k: (v[keep] if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == n else v) for k, v in res.items()}
    return dict(out, with_dd=keep, without_dd=int(n - keep.sum()))


def _velocities(res: dict, ok) -> dict:
    """Constant-velocity mode's velocity of a solution (ECEF, m/s; covariance m²/s²; fixed: NaN where not fixed),
    as ``float_vel_m_s``, ``float_vel_cov_m2_s2``, ``fixed_vel_m_s``, ``fixed_vel_cov_m2_s2``; no keys in the
    other modes."""
    if "float_vel" not in res:
        return {}
    return {"float_vel_m_s": res["float_vel"], "float_vel_cov_m2_s2": res["float_vel_cov"],
            "fixed_vel_m_s": np.where(ok[:, None], res["fixed_vel"], np.nan),
            "fixed_vel_cov_m2_s2": np.where(ok[:, None, None], res["fixed_vel_cov"], np.nan)}


def _paired_epochs(base: pd.DataFrame, rover: pd.DataFrame, opt: dict):
    """:func:`~cdgps_cli.measurement.epoch_pairing.pair_epochs` of the two tables; CdgpsError for bad pairing
    options, no common epoch (with the drop reasons) or no common satellite."""
    try:
        pairs = pair_epochs(rover["time_gps_s"].to_numpy(), base["time_gps_s"].to_numpy(),
                            sync_tol_s=opt["sync_tol_s"], max_age_s=opt["max_age_s"])
    except ValueError as exc:
        raise CdgpsError(f"invalid rtk options: {exc}") from None
    if pairs.rover_time_s.size == 0:
        ps = pairs.summary
        raise CdgpsError(f"no common epochs: none of the rover's {ps['rover_epochs']} epochs has a base epoch within "
                         f"max_age_s = {opt['max_age_s']:g} s (" + "; ".join(f"{n} {r}" for r, n in ps["dropped"].items())
                         + f"; the base has {ps['base_epochs']} epochs)")
    common = set(map(str, base["sat"].unique())) & set(map(str, rover["sat"].unique()))
    if not common:
        raise CdgpsError(f"no common satellites: the base observes {_few(base['sat'])}, the rover {_few(rover['sat'])} "
                         f"(signals asked for); a double difference needs satellites observed at both receivers")
    return pairs


def _with_geometry_free_slips(rows) -> tuple[dict, np.ndarray]:
    """(``rows`` with a slip flag where a satellite's geometry-free phase combination jumped between consecutive
    epochs, the rows so flagged): :func:`~cdgps_cli.measurement.slips.geometry_free_slips`; the same ``rows`` when none,
    or one signal."""
    n = rows["sats"].size
    if n == 0 or len(rows["names"]) < 2:
        return rows, np.zeros(n, dtype=bool)
    epoch = np.searchsorted(rows["ptr"], np.arange(n), side="right") - 1
    found = geometry_free_slips(epoch, rows["sats"], rows["code"], rows["phase_sd_m"], rows["var_phase"],
                                flagged=rows["slip"]) & ~rows["slip"]
    return (dict(rows, slip=rows["slip"] | found) if found.any() else rows), found


def _slip_events(rows, found, times_s) -> dict:
    """:func:`~cdgps_cli.measurement.slips.slip_events` as the JSON summary's lists (``time_gps_s``)."""
    ev = slip_events(rows, found, times_s)
    return {"sat": ev["sat"].tolist(), "signal": ev["signal"].tolist(), "time_gps_s": ev["time_s"].tolist()}


def _passes(rows, times, direction: str, opt, base_xyz, origin, iono, progress) -> dict:
    """The forward pass, the backward pass (slip flags moved by :func:`backward_slips`), or both on two cores
    and :func:`_combine`d, per ``direction``."""
    n_ep = times.size
    back_rows = dict(rows, slip=backward_slips(rows)) if direction != "forward" else None

    def backward(bar=None):
        return _filter_pass(back_rows, times, range(n_ep - 1, -1, -1), opt, base_xyz, origin, iono, bar)

    if direction == "backward":
        return backward(progress)
    if direction == "forward":
        return _filter_pass(rows, times, range(n_ep), opt, base_xyz, origin, iono, progress)
    with beside.start(backward) as job:       # the two passes are independent: the backward one on the second core
        fwd = _filter_pass(rows, times, range(n_ep), opt, base_xyz, origin, iono, progress)
        bwd = job.result()
    out = _combine(fwd, bwd) if opt["mode"] != "static" else _static_smoothed(fwd, bwd)
    if "wet_last" in fwd:
        out["wet_last"] = fwd["wet_last"]          # (the forward pass's last state: every epoch's information)
    return _with_float_variance_factor(out, fwd, bwd) if not opt["fix"] else dict(out, float_variance=None)


#: the per-epoch results of a pass that hold its position (static mode: no velocity)
_POSITION_KEYS = ("float_xyz", "fixed_xyz", "float_cov", "fixed_cov")


def _static_smoothed(f: dict, b: dict) -> dict:
    """Static mode's passes combined: the smoother of a constant position, which at every epoch is the solution
    from every epoch.  Both passes hold one: the forward pass at its last epoch with a DD, the backward pass at its
    first.  Combined as :func:`_combine` combines an epoch, they are given to every epoch when that combination is
    fixed (both fixed and agreeing, or one fixed agreeing with the other's float); otherwise (the two disagree, or
    neither is fixed) each epoch is :func:`_combine`'s own combination of the two passes, as for a moving rover, and
    ``rejected`` counts its epochs.  The other per-epoch columns (satellites, ratio, integers fixed) are
    :func:`_combine`'s.

    (Combining each epoch's two partial solutions always, as for a moving rover, fixed at most the epochs where the
    two partial static solutions agreed within their formal σ: on a real F9P pair 648 of 829 epochs, where two static
    solutions from hours of data differ by 2.5 cm in height, while RTKLIB's combined static run fixed 828.  Going
    float at every epoch when the two solutions from every epoch disagree (a review: 9.4 mm apart, formal σ 1 mm, on
    the real car's last 48 s) was worse than either pass: the per-epoch combination fixes 40 of those 48.)"""
    out = dict(_combine(f, b), every_line_all_epochs=False)
    kf, kb = (np.flatnonzero(p["ns"] > 0) for p in (f, b))
    if not (kf.size and kb.size):
        return out
    n = f["ns"].size
    one = _combine(*({k: (v[[i]] if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == n else v)
                      for k, v in p.items()} for p, i in ((f, kf[-1]), (b, kb[0]))))
    if not one["fixed"][0]:
        return out
    for key in _POSITION_KEYS:
        out[key][:] = one[key][0]
    out.update(fixed=np.ones(n, dtype=bool), rejected=0, every_line_all_epochs=True)
    return out


def receivers_code_noise(base: pd.DataFrame, rover: pd.DataFrame, opt: dict) -> dict:
    """The code variance factor of option ``code_noise``: "model", 1; "auto", the larger of the base's and the
    rover's :func:`~cdgps_cli.measurement.noise.code_noise_factor` over their rows above the mask (at least 1:
    codes better than their model keep it, as does an estimate within 3σ of 1 or below
    :data:`~cdgps_cli.config.options.CODE_NOISE_MIN_FACTOR`; a receiver without enough full windows counts 1).
    Returns
    ``{"mode", "factor", "base", "rover", "windows"}`` (the receivers' estimates, NaN where not made)."""
    if opt["code_noise"] == "model":
        return {"mode": "model", "factor": 1.0, "base": np.nan, "rover": np.nan, "windows": {"base": 0, "rover": 0}}
    got, windows = {}, {}
    for who, g in (("base", base), ("rover", rover)):
        el = g["el_rad"].to_numpy(dtype=np.float64)
        above = el >= np.radians(opt["mask_deg"])
        var = 0.5 * opt["code_ratio"] ** 2 * sd_variance(el[above], el[above], sigma_a_m=opt["sigma_a_m"],
                                                          sigma_b_m=opt["sigma_b_m"], weighting=opt["weighting"])
        ch = channel_index(g["sat"].to_numpy()[above], g["signal"].to_numpy()[above])
        got[who], windows[who] = code_noise_factor(
            g["time_gps_s"].to_numpy()[above], ch, g["pseudorange_m"].to_numpy(dtype=np.float64)[above],
            (g["phase_cycles"].to_numpy(dtype=np.float64) * g["wavelength_m"].to_numpy(dtype=np.float64))[above],
            (g["lli"].to_numpy(dtype=np.int64)[above] & 1) > 0, var, window_s=CODE_NOISE_WINDOW_S,
            chunk_s=CODE_NOISE_CHUNK_S, min_windows=CODE_NOISE_MIN_WINDOWS)
    # an estimate within 3σ of 1 (relative σ √(2/n) for n windows), or below 1.5 (σ × 1.22), is the model's own
    # variance: no factor (white codes at their model give 0.97-1.23 on 480 windows)
    known = [f for who, f in got.items()
             if np.isfinite(f) and f > max(CODE_NOISE_MIN_FACTOR, 1.0 + 3.0 * np.sqrt(2.0 / windows[who]))]
    return {"mode": "auto", "factor": float(max([1.0, *known])), **got, "windows": windows}


def _filter_pass(rows, times, order, opt, base_xyz, origin, iono, progress) -> dict:
    """One Kalman pass over the epochs in ``order`` (forward or backward) on the engine's driver
    (:func:`~cdgps_cli.estimation.driver.drive`): the dynamics :class:`_RtkDynamics`, the DD model
    :class:`~cdgps_cli.measurement.dd_signals.DDGroupModel`, the hook :class:`_AmbiguityHook` (new
    and re-biased ambiguity columns, integer fixing, fix-and-hold) and the sink :class:`_FloatSink`.
    Per epoch (in time order) the float and fixed positions (ECEF, m) and covariances, the DD
    ambiguities fixed, whether only a partial set was (the position is then kept as float), the
    ratio and the satellites used."""
    order = np.asarray(list(order), dtype=np.int64)
    n_ep = times.size
    out = {"float_xyz": np.full((n_ep, 3), np.nan), "fixed_xyz": np.full((n_ep, 3), np.nan),
           "float_cov": np.full((n_ep, 3, 3), np.nan), "fixed_cov": np.full((n_ep, 3, 3), np.nan),
           "n_fixed": np.zeros(n_ep, dtype=np.int64), "ratio": np.full(n_ep, np.nan),
           "partial": np.zeros(n_ep, dtype=bool), "ns": np.zeros(n_ep, dtype=np.int64),
           "wrong_fix_resets": np.zeros(n_ep, dtype=bool), "released": np.zeros(n_ep, dtype=bool),
           "held": np.zeros(n_ep, dtype=bool)}
    if _n_motion(opt) == 6:                        # constant-velocity mode: the velocity too (ECEF, m/s)
        out.update({key: np.full(out[like].shape, np.nan) for key, like in _VELOCITY_KEYS.items()})
    st = _State(_n_motion(opt))
    amb_keys, slip_rows = _amb_keys(rows), np.flatnonzero(rows["slip"]).tolist()
    # (the wrong-fix test, epoch_nis, predicts at the state before the update, as the update's first iteration)
    model = DDGroupModel(lambda i: _groups_with_keys(rows, order[i], amb_keys, slip_rows), base_xyz, origin,
                         linearization_tol_m=RTK_LINEARIZATION_TOL_M, remember_last=True)
    source = EpochGrid(times[order])
    # the passes step |Δt| (:class:`_RtkDynamics`): a backward pass's velocity state is minus the rover's
    v_sign = -1.0 if n_ep > 1 and order[1] < order[0] else 1.0
    hook = _AmbiguityHook(st, model, order, opt, iono, out, progress, v_sign)
    dyn, sink = _RtkDynamics(st, source.time_s, opt, iono), _FloatSink(order, origin, out, v_sign)
    # the first epoch relinearizes up to 4 times (the a-priori position may be metres off), the others at most
    # twice: once when the rover moved less than √(tol·ρ_min) ≈ 4 m from the prediction (its DDs linear to a micron)
    drive(dyn, [model], EpochGrid(source.time_s[:1]), st.step, hooks=[hook], sink=sink, max_iterations=4)
    drive(dyn, [model], source, st.step, hooks=[hook], sink=sink, max_iterations=2, k0=1)
    out["fixed"] = np.isfinite(out["fixed_xyz"][:, 0])
    if WET_KEYS[0] in st.index:
        cols = [st.index[key] for key in WET_KEYS]
        out["wet_last"] = {"zenith_wet_m": dict(zip(("base", "rover"), st.x[cols].tolist())),
                           "zenith_wet_sigma_m": dict(zip(("base", "rover"), np.sqrt(np.diag(st.P)[cols]).tolist()))}
    return out


#: constant-velocity mode's velocity arrays of a pass (ECEF, m/s; covariance m²/s²) → the position arrays they mirror
_VELOCITY_KEYS = {"float_vel": "float_xyz", "float_vel_cov": "float_cov", "fixed_vel": "fixed_xyz",
                  "fixed_vel_cov": "fixed_cov"}


def _n_motion(opt) -> int:
    """Motion states of the rover: position (3), and velocity (3) in constant-velocity mode."""
    return 6 if opt["mode"] == "constant-velocity" else 3


def _motion_model(opt):
    """The rover's dynamics for ``mode`` (:data:`RTK_MODES`)."""
    if opt["mode"] == "static":
        return Static(3)
    if opt["mode"] == "constant-velocity":
        return ConstantVelocity(3, opt["accel_sigma_m_per_s_per_sqrt_s"])
    return RandomWalk(3, opt["kinematic_sigma_m_per_sqrt_s"])


class _RtkDynamics:
    """Prediction of the rtk state between the drive's epochs: the rover's motion states by
    :func:`_motion_model` (static, random-walk or constant-velocity position), each SD ionosphere a
    random walk, ambiguities constant; A and Q sized to the state's columns of the moment (|Δt|: a
    backward pass runs the same model; A is the identity but in constant-velocity mode)."""

    def __init__(self, st, time_s, opt, iono):
        self.st, self.time_s, self.iono = st, time_s, iono
        self.motion = _motion_model(opt)
        self.identity = self.motion.identity_transition
        self.iono_q = opt["iono_rw_m_per_sqrt_s"] ** 2
        self.wet_q = float(opt["tropo_rw_m_per_sqrt_s"]) ** 2 if opt.get("wet_estimated", False) else 0.0
        self._by_dt = {}

    #: step lengths whose transition :meth:`_transition` keeps (a record's few distinct spacings: a 10 Hz
    #: record's time tags differ by 4 values around 0.1 s, one after the other)
    MAX_KEPT_STEPS = 64

    def _transition(self, dt):
        """The motion model's (A, B, Q) over ``dt`` s, kept per step length (the arrays are only read)."""
        got = self._by_dt.get(dt)
        if got is None:
            if len(self._by_dt) >= self.MAX_KEPT_STEPS:
                self._by_dt.clear()
            got = self._by_dt[dt] = self.motion.transition(dt)
        return got

    def step_into(self, k):
        dt = abs(float(self.time_s[k] - self.time_s[k - 1]))
        n, m = len(self.st.keys), self.motion.n
        A_m, _, Q_m = self._transition(dt)
        Q = np.zeros((n, n))
        Q[:m, :m] = Q_m
        if self.iono:
            ion = [j for j, key in enumerate(self.st.keys) if key[0] == "I"]
            Q[ion, ion] = self.iono_q * dt
        if self.wet_q:
            wet = [self.st.index[key] for key in WET_KEYS if key in self.st.index]
            Q[wet, wet] = self.wet_q * dt
        if self.identity:
            return None, Q, None
        A = np.eye(n)
        A[:m, :m] = A_m
        return A, Q, None


class _FloatSink:
    """The drive's sink: each epoch's float position (ECEF, m) and its covariance, in time order; in
    constant-velocity mode the velocity (m/s, ``v_sign`` × the state's) and its covariance too."""

    def __init__(self, order, origin, out, v_sign=1.0):
        self.order, self.origin, self.out, self.v_sign = order, origin, out, v_sign

    def write(self, i, x, P):
        k = self.order[i]
        self.out["float_xyz"][k] = self.origin + x[:3]
        self.out["float_cov"][k] = P[:3, :3]
        if "float_vel" in self.out:
            self.out["float_vel"][k] = self.v_sign * x[3:6]
            self.out["float_vel_cov"][k] = P[3:6, 3:6]

    def release_before(self, i):
        return None


def epoch_nis(model, rows, x, P, phase_only: bool = False) -> tuple[float, int]:
    """NIS of an epoch's DDs at the state ``x`` (n,), ``P`` (n, n) before their update, and its degrees of
    freedom (one fewer than the SDs per group and kind); ``phase_only``: of the DD phases alone.

    The wrong-fix test of held integers takes the phases alone: a wrong integer leaves a DD phase residual
    of a sizeable part of a cycle, while the codes, even when the position is metres off, add little against
    their noise (a one-cycle wrong fix planted 2 m off on the mosaic pair: the codes added 5 to a phase NIS
    of 27 over 8 more degrees of freedom, which would have delayed the detection by 30 epochs), and a real
    receiver's code multipath, taken as white, sets the test off every few minutes (a u-blox M8P pair: DD
    code residuals of 1.5–5 m against one reference while every phase residual stayed below a quarter
    cycle).  Rows whitened as in
    :class:`~cdgps_cli.measurement.dd_signals.GroupRows` (noise ``I − u uᵀ`` per group; ν and H have no
    component along u, so ``S = H P Hᵀ + I`` gives the DD statistic).
    """
    M = int(rows.context["M"])
    h, H = model.predict(x, rows)
    k = M if phase_only else rows.z_m.size
    B = rows.B[:k, :k]                         # block-diagonal: the phase blocks, then the code blocks
    nu = B @ (rows.z_m[:k] - h[:k])
    Hw = B @ H[:k]
    S = Hw @ P @ Hw.T + _eye(k)
    return float(nu @ np.linalg.solve(S, nu)), k - len(model.groups) * (1 if phase_only else 2)


_CHI2_KEPT: dict = {}


def _chi2_quantile(probability, dof):
    """:func:`~cdgps_cli.estimation.chi2.chi2_quantile` of a scalar ``probability`` and ``dof``, kept per pair (the
    wrong-fix test asks the same few at every held epoch)."""
    key = (probability, dof)
    q = _CHI2_KEPT.get(key)
    if q is None:
        if len(_CHI2_KEPT) >= 4096:
            _CHI2_KEPT.clear()
        q = _CHI2_KEPT[key] = chi2_quantile(probability, dof)
    return q


def _released(P, cols, var_cycles2) -> np.ndarray:
    """``P`` with the ambiguity columns ``cols`` back to float: variance ``var_cycles2``, no correlation
    with the other states (a copy)."""
    P = P.copy()
    P[cols, :] = 0.0
    P[:, cols] = 0.0
    P[cols, cols] = var_cycles2
    return P


def _float_ambiguities(st, var_cycles2) -> None:
    """Wrong-fix recovery: every ambiguity column back to float (:func:`_released`); the next epochs'
    phases and codes re-estimate them and the integer search starts again."""
    amb = np.array([j for j, key in enumerate(st.keys) if key[0] == "N"], dtype=np.int64)
    if amb.size:
        st.P = _released(st.P, amb, var_cycles2)


def _one_to_release(model, rows, x, P, cols, var_cycles2, probability) -> int | None:
    """The one ambiguity column among ``cols`` whose release (:func:`_released`) brings the epoch's DDs
    (:func:`epoch_nis`) back within χ²(``probability``) of their degrees of freedom (one fewer), the release
    that explains them best; None when no single one does.

    A held fix contradicted by one epoch is most often one channel that slipped by whole or half
    cycles without a loss-of-lock flag (u-blox receivers flag half-cycle slips late, or not at all),
    not a wrong integer set: releasing that channel alone keeps the others' integers, so the position
    stays fixed instead of floating for minutes while every ambiguity converges again (RTKLIB drops
    such an outlier from its update)."""
    best, best_nis, dof1 = None, np.inf, None
    for c in cols.tolist():
        nis, dof = epoch_nis(model, rows, x, _released(P, np.array([c]), var_cycles2), phase_only=True)
        if nis < best_nis:
            best, best_nis, dof1 = c, nis, dof - 1
    if best is None or dof1 < 1 or best_nis > chi2_quantile(probability, dof1):
        return None
    return best


class _AmbiguityHook(Hook):
    """The rtk ambiguity policy as driver hooks: ``prepared`` opens a column per new ambiguity (and
    ionosphere) and re-biases slipped channels (:func:`_prepare_state`); ``gate`` keeps the state
    before the update and ``updated`` checks a held fix against the epoch (wrong-fix detection:
    while integers are held, an epoch whose NIS exceeds χ²(``wrong_fix_probability``) of its DD
    degrees of freedom contradicts them — the ambiguities go back to float and the epoch is updated
    again); ``after`` fixes the DD integers (:func:`_fix`, the policy of
    :meth:`_CarriedDecorrelation.resolve`), records the fixed (or, for a partial set, improved float)
    position and holds the integers (fix-and-hold)."""

    def __init__(self, st, model, order, opt, iono, out, progress, v_sign=1.0):
        self.st, self.model, self.order, self.opt, self.iono, self.out = st, model, order, opt, iono, out
        self.v_sign = v_sign                       # the rover's velocity per velocity state (-1: a backward pass)
        self.progress, self.carried, self.run = progress, _CarriedDecorrelation(), 0
        self.holding, self.prior, self.resets, self.released_at = False, None, 0, None

    def prepared(self, ctx, i):
        _prepare_state(self.st, self.model.groups, self.opt, self.iono)

    def gate(self, ctx, i, model, rows):
        if (self.holding or self.released_at is not None) and self.opt["wrong_fix_probability"] > 0:
            self.prior = (self.st.x.copy(), self.st.P.copy())
        return rows

    def updated(self, ctx, i, model, rows, nis):
        if self.prior is None:
            return
        prior, self.prior = self.prior, None
        p = self.opt["wrong_fix_probability"]
        nis, dof = epoch_nis(model, rows, *prior, phase_only=True)
        if dof < 1 or nis <= _chi2_quantile(p, dof):
            return
        self.st.x, self.st.P = prior                  # the held integers contradict this epoch: undo, float, again
        var = self.opt["amb_sigma_cycles"] ** 2
        cols = np.unique(np.concatenate([g["amb_col"] for g in self.model.groups]))
        one = None if self.released_at is not None else _one_to_release(model, rows, self.st.x, self.st.P, cols, var, p)
        if one is None:          # not one channel, or a second contradiction before the first was fixed: all float
            _float_ambiguities(self.st, var)
            self.resets += 1
            self.out["wrong_fix_resets"][self.order[i]] = True
            self.released_at = None
        else:                                         # one channel slipped unflagged: only its ambiguity
            self.st.P = _released(self.st.P, np.array([one]), var)
            self.out["released"][self.order[i]] = True
            self.released_at = i
        self.st.step.update(model, rows, 2)
        self.run, self.holding, self.carried = 0, False, _CarriedDecorrelation()

    def _check_release(self, i, k):
        """After one ambiguity was released (:func:`_one_to_release`) the phase test goes on at every epoch
        (:meth:`updated`) until the set is fixed again.  A second contradiction before that, or no fix within
        :data:`RELEASE_RECOVERY_EPOCHS` epochs, means the rest of the held set was wrong too (a wrong fix can
        look like one slipped channel for an epoch, its error then lingering in every other ambiguity):
        every ambiguity goes back to float.  Fixed again in time, the release stands."""
        if self.released_at is None:
            return
        if self.run:
            self.released_at = None
        elif i - self.released_at >= RELEASE_RECOVERY_EPOCHS:
            _float_ambiguities(self.st, self.opt["amb_sigma_cycles"] ** 2)
            self.carried, self.released_at = _CarriedDecorrelation(), None
            self.resets += 1
            self.out["wrong_fix_resets"][k] = True

    def after(self, ctx, i, i_next):
        st, groups, opt, out, k = self.st, self.model.groups, self.opt, self.out, self.order[i]
        fx, n, ratio, fx_cov, partial = (_fix(st, groups, opt, self.carried) if (groups and opt["fix"])
                                         else (None, 0, np.nan, None, False))
        origin = self.model.origin
        if fx is not None and not partial and fx_cov[:3, :3].trace() > MAX_FIXED_SIGMA_M ** 2:
            partial = True                         # integers fixed, but too few or too weak to set the position
        if fx is not None:                         # part of the set: a better float, not a fixed position
            kind = "float" if partial else "fixed"
            out[f"{kind}_xyz"][k], out[f"{kind}_cov"][k] = origin + fx[:3], fx_cov[:3, :3]
            if f"{kind}_vel" in out:
                out[f"{kind}_vel"][k], out[f"{kind}_vel_cov"][k] = self.v_sign * fx[3:6], fx_cov[3:6, 3:6]
        self.run = self.run + 1 if (fx is not None and not partial) else 0
        self._check_release(i, k)
        self.holding = bool(opt["fix_and_hold"] and self.run >= opt["hold_after_fixes"])
        out["held"][k] = self.holding and self.released_at is None
        if self.holding:
            _hold(st, self.carried.last_fix)
        out["n_fixed"][k], out["ratio"][k], out["partial"][k] = n, ratio, partial
        out["ns"][k] = len({key[2] for g in groups for key in g["amb_keys"]} if groups and "amb_keys" in groups[0]
                           else {s for g in groups for s in g["sats"]})
        if self.progress is not None:
            self.progress(i + 1, self.order.size)
        return i_next


#: χ²(3) at 0.999: forward and backward fixed positions farther apart than this disagree
_CHI2_3_999 = 16.266


#: the probability of the test that the two passes' floats disagree more than their σ allow
FLOAT_VARIANCE_PROBABILITY = 0.99
#: fewer epochs where both passes have a float: no test, the factor stays 1
FLOAT_VARIANCE_MIN_EPOCHS = 10


def float_variance_factor(xf, Pf, xb, Pb) -> dict:
    """The variance factor of the float positions, from the two passes' disagreement.

    ``xf``, ``xb`` (n, 3) m and ``Pf``, ``Pb`` (n, 3, 3) m²: the forward and backward passes' float positions and
    covariances, in time order.  Over the epochs where both hold one, d_k = x_f,k − x_b,k and the mean of
    d_kᵀ (P_f,k + P_b,k)⁻¹ d_k / 3 (``disagreement``).  The forward pass at epoch k holds the data up to k, the
    backward pass the data from k: when both covariances hold, their errors are independent but for epoch k's own
    measurements and the mean is about 1.  Errors correlated over minutes (code multipath on a u-blox pair, which a
    filter of white code errors averages as if it were noise) make them disagree by more than their σ.  The mean is
    judged by the whitened differences' worth in independent samples m (:func:`~cdgps_cli.measurement.noise.
    effective_sample_size`, the least of the three components: a float converging over minutes is worth a few
    samples per ten minutes): when it exceeds the :data:`FLOAT_VARIANCE_PROBABILITY` quantile of χ²(3m)/(3m)
    (``threshold``), ``factor`` is the mean, else 1.  A lower bound: errors common to both passes (a bias of the
    whole record) do not show in d, and the shared epoch k makes d smaller.

    Measured (GPS L1 unless said, float only; docs/gnss-pipeline.md, session 20): u-blox M8P 14.8 (m 4.7, threshold
    2.08; the passes' NEES per DoF 45 / 33), F9P G+E+C 2.67 (2.14; NEES 2.5 / 1.7): scaled; mosaic 1.27, simulated
    white-noise pairs 0.67 and 1.50 (threshold 2.0–2.1; NEES 0.94–1.15), GEONET 0.23: factor 1.

    Returns ``{"factor", "disagreement", "independent_samples", "threshold", "epochs"}`` (None where not made)."""
    ok = np.all(np.isfinite(xf), axis=1) & np.all(np.isfinite(xb), axis=1)
    ok &= np.all(np.isfinite(Pf), axis=(1, 2)) & np.all(np.isfinite(Pb), axis=(1, 2))
    out = {"factor": 1.0, "disagreement": None, "independent_samples": None, "threshold": None, "epochs": int(ok.sum())}
    if ok.sum() < FLOAT_VARIANCE_MIN_EPOCHS:
        return out
    d = (xf - xb)[ok]
    try:
        w = np.linalg.solve(np.linalg.cholesky((Pf + Pb)[ok]), d[:, :, None])[:, :, 0]     # whitened: I if they hold
    except np.linalg.LinAlgError:
        return out
    k = float(np.mean(np.einsum("mi,mi->m", w, w))) / 3.0
    m = min(effective_sample_size(w[:, i]) for i in range(3))
    dof = 3.0 * m
    limit = float(chi2_quantile(FLOAT_VARIANCE_PROBABILITY, dof)) / dof
    out.update(disagreement=k, independent_samples=m, threshold=limit, factor=k if k > limit else 1.0)
    return out


def _with_float_variance_factor(out: dict, f: dict, b: dict) -> dict:
    """The combined solution ``out`` (:func:`_combine` of passes ``f``, ``b``) with its float positions' covariance
    multiplied by :func:`float_variance_factor` (its result as ``float_variance`` in it): the σ a float epoch
    reports then holds what the two passes' disagreement shows.  After the combination: its checks of a fix
    against the other pass's float keep the filters' own covariance (a wider one would let wrong fixes through).

    Made for float-only runs (:func:`_passes`).  With fixing on, the floats left are a few epochs where one pass
    has just lost its integers while the other holds a converged float: their disagreement is not the combined
    float's error (the real M8P pair: its 29 float epochs' error / σ RMS 0.5 / 1.5 / 1.1 as reported, 0.3 / 0.9 /
    0.6 scaled by their disagreement 2.9), and the solution is left as the passes give it."""
    free = ~(f["fixed"] | f["held"] | b["fixed"] | b["held"])[:, None]     # epochs where neither float is tied to integers
    fv = float_variance_factor(np.where(free, f["float_xyz"], np.nan), f["float_cov"],
                               np.where(free, b["float_xyz"], np.nan), b["float_cov"])
    out["float_variance"] = fv
    if fv["factor"] > 1.0:
        out["float_cov"] = out["float_cov"] * fv["factor"]
    return out


def _combine(f: dict, b: dict) -> dict:
    """Forward and backward passes combined per epoch (RTKLIB's combined mode, with a check):
    fixed where both are fixed and agree (their weighted mean), or one is fixed and either holds its
    integers (``held``: fixed for ``hold_after_fixes`` epochs in a row, each epoch's DD phases tested
    against them since — the validation over time) or agrees with the other's float; where the two
    fixes disagree (χ² of the difference over 0.999 of χ²(3)) one of them is wrong and the epoch is
    float.  Floats are combined as a weighted mean too.

    A fresh fix of one pass is checked against the other's float, whose σ is honest on a static real
    rover but not on a moving u-blox one (error / σ 2.4–4.5 RMS on jdesbonnet 20181009: code errors
    correlated beyond the code-noise window); a held fix needs no such check (20181009: 800 → 1353
    fixed epochs, RTKLIB 927, the 386 of 391 newly fixed epochs RTKLIB fixes too within 5 cm of its
    fix, the other five where RTKLIB's isolated fixes jump off its own float track), while the M8P
    pair's wrong fresh fixes (a multipath wave, 5–6 cm off, within 10 epochs of a release) stay rejected.

    Both passes' estimates at epoch k hold epoch k's measurements, so they are not independent:
    their weighted mean is kept, but not the covariance of a merge of independent estimates, which
    counts epoch k twice (R/(n+1) for n measurements of a static point, and in kinematic mode, where
    epoch k's phases set the position, about half the true variance).  The covariance reported is
    the better pass's: conservative by at most the share of epoch k.  (The two-filter smoother on the
    position alone — the forward estimate with the backward pass's prediction to k — counts k once
    but drops the backward pass's ambiguities: a kinematic float σ of 3 cm became 0.7 m; the exact
    combination needs both passes' full states at every epoch.)"""
    n = f["fixed"].size
    out = {k: np.array(v, copy=True) for k, v in f.items()}
    out["rejected"] = 0
    floor = np.eye(3) * 1e-6                                  # 1 mm²: fixed covariances are optimistic

    def merge(xa, Pa, xb, Pb):                                # (m, 3), (m, 3, 3) each: weighted means
        K = Pa @ np.linalg.inv(Pa + Pb)
        return xa + (K @ (xb - xa)[:, :, None])[:, :, 0]

    def agree(xa, Pa, xb, Pb):
        d = xa - xb
        return np.einsum("mi,mi->m", d, np.linalg.solve(Pa + Pb + floor, d[:, :, None])[:, :, 0]) <= _CHI2_3_999

    def smaller(Pa, Pb):                                      # the covariance of least trace (the first when equal)
        return np.where((np.trace(Pa, axis1=1, axis2=2) <= np.trace(Pb, axis1=1, axis2=2))[:, None, None], Pa, Pb)

    pairs = [("xyz", "cov"), ("vel", "vel_cov")] if "float_vel" in f else [("xyz", "cov")]
    for x, c in pairs:           # the velocity (constant-velocity mode) combined as the position, epoch by epoch
        out[f"float_{x}"] = merge(f[f"float_{x}"], f[f"float_{c}"], b[f"float_{x}"], b[f"float_{c}"])
        out[f"float_{c}"] = smaller(f[f"float_{c}"], b[f"float_{c}"])
        out[f"fixed_{x}"][:], out[f"fixed_{c}"][:] = np.nan, np.nan
    ff, fb = f["fixed"], b["fixed"]
    both = np.flatnonzero(ff & fb)
    ok = agree(f["fixed_xyz"][both], f["fixed_cov"][both], b["fixed_xyz"][both], b["fixed_cov"][both])
    k = both[ok]
    for x, c in pairs:
        out[f"fixed_{x}"][k] = merge(f[f"fixed_{x}"][k], f[f"fixed_{c}"][k], b[f"fixed_{x}"][k], b[f"fixed_{c}"][k])
        out[f"fixed_{c}"][k] = smaller(f[f"fixed_{c}"][k], b[f"fixed_{c}"][k])
    out["rejected"] += int(both.size - k.size)
    for src, other, one in ((f, b, ff & ~fb), (b, f, fb & ~ff)):   # one pass fixed: agrees with the other's float?
        i = np.flatnonzero(one)
        ok = src["held"][i] | agree(src["fixed_xyz"][i], src["fixed_cov"][i], other["float_xyz"][i],
                                    other["float_cov"][i])
        for x, c in pairs:
            out[f"fixed_{x}"][i[ok]], out[f"fixed_{c}"][i[ok]] = src[f"fixed_{x}"][i[ok]], src[f"fixed_{c}"][i[ok]]
        out["rejected"] += int(i.size - ok.sum())
    fr, br = f["ratio"], b["ratio"]
    out["ratio"] = np.where(np.isfinite(fr) | np.isfinite(br), np.fmax(fr, br), np.nan)
    out["n_fixed"] = np.maximum(f["n_fixed"], b["n_fixed"])
    out["partial"] = f["partial"] & b["partial"]
    out["fixed"] = np.isfinite(out["fixed_xyz"][:, 0])
    out["wrong_fix_resets"] = f["wrong_fix_resets"] | b["wrong_fix_resets"]
    out["released"] = f["released"] | b["released"]
    out["held"] = f["held"] | b["held"]
    return out
