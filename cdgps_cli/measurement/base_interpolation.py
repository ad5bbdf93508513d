"""A base receiver's observations carried to the rover's epochs between two of its own (issue 28 item 2).

A rover epoch without a base epoch at its time is paired with the nearest base epoch within the maximum age
(:func:`~cdgps_cli.measurement.epoch_pairing.pair_epochs`).  Its single differences then carry what the base's
observation minus its model does over that age: above all the satellite clock's departure from its broadcast drift,
≈ 0.3 mm per second of age on a real 5 s CORS, which with the nearest epoch alone repeats at the base's rate (a
0.2 Hz sawtooth in the position of a 1 Hz rover against a 5 s CORS, in the band of a structure's modes).
:func:`interpolate_base` takes the base's observation minus its model linearly between the base epochs on both
sides of the rover's time instead; the rtk path (:func:`~cdgps_cli.measurement.dd_signals.paired_sd_rows`) and the
batch baseline solver (:mod:`cdgps_cli.estimation.baseline`) both call it on the rows of :func:`base_rows`, so the
two see the same numbers.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cdgps_cli.measurement.epoch_pairing import carry_base_slips, channel_index

__all__ = ["base_rows", "interpolate_base", "BASE_ROW_COLUMNS", "observation_model_m", "base_drift_m_per_s"]

#: Columns :func:`interpolate_base` reads of each base row (a geometry table of
#: :func:`~cdgps_cli.estimation.rtk_multi.receiver_geometry`, through :func:`base_rows`).
BASE_ROW_COLUMNS = ("_bep", "sat", "signal", "phase_cycles", "pseudorange_m", "sx", "sy", "sz", "sat_clock_m",
                    "trop_m", "lli")


def base_rows(base: pd.DataFrame, tb: np.ndarray, use_count: np.ndarray) -> pd.DataFrame:
    """The base's rows as the paired rows see them: ``_row_b`` (its row), ``_bep`` (its epoch's index in ``tb``)
    and ``lli`` with each loss-of-lock flag of an epoch that pairs with no rover epoch moved to the channel's next
    epoch that does, and a flag given once when a base epoch serves several rover epochs
    (:func:`~cdgps_cli.measurement.epoch_pairing.carry_base_slips`).

    Parameters
    ----------
    base : DataFrame
        The base's rows (``time_gps_s``, ``sat``, ``signal``, ``lli`` and what the caller reads later).
    tb : ndarray (n_b,)
        The base's distinct epoch times, GPS s, increasing (every row's time among them).
    use_count : ndarray of int (n_b,)
        How many rover epochs each base epoch serves.
    """
    bep = np.searchsorted(tb, base["time_gps_s"].to_numpy())
    lli = carry_base_slips(bep, channel_index(base["sat"].to_numpy(), base["signal"].to_numpy()),
                           base["lli"].to_numpy(dtype=np.int64), use_count)
    return base.assign(_row_b=np.arange(len(base)), _bep=bep, lli=lli)


def interpolate_base(m: pd.DataFrame, b: pd.DataFrame, tb: np.ndarray, time_s: np.ndarray, *, base_xyz_m,
                     sync_tol_s: float, max_age_s: float, troposphere: bool):
    """The base's phase and range of the paired rows ``m``, interpolated to the rover's time where it lies between
    two base epochs, and each row's effective age.

    The base's observation minus its model ``M = ρ − c·dt_sat (+ T)`` (range from ``base_xyz_m``, satellite clock
    and troposphere of each base epoch's own geometry) is taken linearly between the base epochs t₀ (the paired
    one, whose geometry the row keeps) and t₁ (the other side of the rover time t): the base phase becomes
    ``φ₀ + w [(φ₁ − φ₀) − (M₁ − M₀)/λ]``, ``w = |t − t₀| / |t₁ − t₀|``, and the range likewise.  Only where t₁ is
    within ``max_age_s`` of t and every row of the rover epoch's signal group has its satellite at t₁ with no slip
    or half-cycle change between (and a finite observation at both), from the same broadcast ephemeris as at t₀
    (when the rows carry ``eph_row``: across a change of ephemeris M₁ − M₀ holds the jump between the two, up to
    decimetres, which the observations do not): the receiver clock's part of the interpolation is then common to
    the group, and its double differences cancel it.  Such a row's age becomes
    ``|t − t₀| (1 − w)`` (zero at either base epoch).

    Parameters
    ----------
    m : DataFrame (N rows)
        Paired rows: ``_ep`` (the rover epoch), ``_bep`` (index of t₀ in ``tb``), ``sat``, ``signal``,
        ``wavelength_m`` and the base row at t₀: ``phase_cycles_b``, ``pseudorange_m_b``, ``sx_b``, ``sy_b``,
        ``sz_b``, ``sat_clock_m_b``, ``trop_m_b`` (m) and ``lli_b`` (as :func:`base_rows` gives it; NaN where the
        row has no base row there: never interpolated, nor its group).
    b : DataFrame
        Base rows of :func:`base_rows` with :data:`BASE_ROW_COLUMNS` (at least those at the epochs t₁), and
        ``eph_row`` when ``m`` has ``eph_row_b``.
    tb : ndarray (n_b,)
        The base's distinct epoch times, GPS s.
    time_s : ndarray (N,)
        Each row's rover time, GPS s.
    base_xyz_m : array_like (3,)
        Base position, ECEF m.
    sync_tol_s, max_age_s : float
        Tags within ``sync_tol_s`` are simultaneous (nothing to interpolate); t₁ at most ``max_age_s`` from t.
    troposphere : bool
        Whether the model includes the troposphere ``trop_m``.

    Returns
    -------
    phase_cycles_b, pseudorange_m_b, age_s : ndarray (N,)
        The base's phase (cycles) and range (m) for each row (t₀'s where not interpolated) and the age (s) its
        variance is to take (``t − t₀`` where not interpolated).
    interpolated : ndarray of bool (N,)
        The rows interpolated.
    """
    phase = m["phase_cycles_b"].to_numpy(dtype=float)
    rng = m["pseudorange_m_b"].to_numpy(dtype=float)
    b0 = m["_bep"].to_numpy()
    age = np.asarray(time_s, dtype=float) - tb[b0]
    b1, inside = _far_epochs(b0, age, tb, time_s, sync_tol_s, max_age_s)
    if not inside.any():
        return phase, rng, age, np.zeros(age.size, dtype=bool)
    o = _rows_at(b, m, np.where(inside, b1, -1), "eph_row_b" in m.columns)
    if o is None:                              # a repeated base row at t₁: no interpolation anywhere (the nearest)
        return phase, rng, age, np.zeros(age.size, dtype=bool)
    ok = _whole_groups(m, inside & _row_qualifies(m, o, age > 0, phase, rng))
    if not ok.any():
        return phase, rng, age, ok
    xb = np.asarray(base_xyz_m, dtype=np.float64)

    def model(sx, sy, sz, clk, tr):
        return observation_model_m(sx, sy, sz, clk, tr, xb, troposphere)

    k = np.flatnonzero(ok)
    m0 = model(*(m[c].to_numpy(dtype=float)[k] for c in ("sx_b", "sy_b", "sz_b", "sat_clock_m_b", "trop_m_b")))
    m1 = model(*(o[c].to_numpy(dtype=float)[k] for c in ("sx_1", "sy_1", "sz_1", "sat_clock_m_1", "trop_m_1")))
    w = np.abs(age[k]) / np.abs(tb[b1[k]] - tb[b0[k]])
    lam = m["wavelength_m"].to_numpy(dtype=float)[k]
    phase, rng, age = phase.copy(), rng.copy(), age.copy()
    phase[k] += w * ((o["phase_cycles_1"].to_numpy(dtype=float)[k] - phase[k]) - (m1 - m0) / lam)
    rng[k] += w * ((o["pseudorange_m_1"].to_numpy(dtype=float)[k] - rng[k]) - (m1 - m0))
    age[k] = np.abs(age[k]) * (1.0 - w)
    return phase, rng, age, ok


def observation_model_m(sx, sy, sz, clk, tr, base_xyz_m, troposphere: bool):
    """What the base observes of a satellite but for its clock and ambiguity, m: the range from ``base_xyz_m`` (ECEF
    m) to the satellite at (``sx``, ``sy``, ``sz``) minus its clock ``clk`` (m), plus the troposphere ``tr`` (m)
    when ``troposphere``."""
    xb = np.asarray(base_xyz_m, dtype=np.float64)
    return np.sqrt((sx - xb[0]) ** 2 + (sy - xb[1]) ** 2 + (sz - xb[2]) ** 2) - clk + (tr if troposphere else 0.0)


#: lags (in base epochs) at which :func:`base_drift_m_per_s` compares a channel with itself
DRIFT_LAG_STEPS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256)
#: differences a lag needs to count in :func:`base_drift_m_per_s`
DRIFT_MIN_DIFFERENCES = 30


def base_drift_m_per_s(base: pd.DataFrame, base_xyz_m, *, troposphere: bool, max_age_s: float,
                       mask_rad: float = 0.0) -> dict:
    """How fast the base's observation minus its model departs from itself, m per s of age: the σ a base
    observation carried to a rover epoch ``age`` seconds away gains (:func:`interpolate_base` where it cannot
    interpolate, the nearest epoch's alone).

    Per channel and epoch, u = λφ − M (M :func:`observation_model_m`: range, satellite clock, troposphere), less the
    mean of the epoch's channels of that signal (the receiver clock; epochs with three channels or more).  Along
    each arc (no loss of lock, one broadcast ephemeris, no gap beyond ``max_age_s``) the differences of u over
    :data:`DRIFT_LAG_STEPS` base epochs, whose time spans L stay within ``max_age_s``, have a robust variance s²(L)
    (1.4826 · MAD)²; s²(L) = c² + a² L² is fitted (relative residuals) and ``a`` is the drift.  What it holds: the
    satellite clocks' departure from their broadcast drift, the base position's error seen through each
    satellite's motion, ionosphere changes; the per-epoch noise goes to c.

    Parameters
    ----------
    base : DataFrame
        The base's geometry rows (:func:`~cdgps_cli.estimation.rtk_multi.receiver_geometry`: ``time_gps_s``,
        ``sat``, ``signal``, ``phase_cycles``, ``wavelength_m``, ``sx``/``sy``/``sz``, ``sat_clock_m``,
        ``trop_m``, ``lli``, ``el_rad``; ``eph_row`` when there).
    base_xyz_m : array_like (3,)
        Base position, ECEF m.
    troposphere : bool
        Whether the model includes ``trop_m``.
    max_age_s : float
        The longest age a base observation is carried over, s.
    mask_rad : float
        Rows below this elevation are left out.

    Returns
    -------
    dict
        ``estimate_m_per_s`` (None: fewer than two lags of :data:`DRIFT_MIN_DIFFERENCES` differences), ``lags_s``
        and ``sd_m`` (each lag's mean span and robust σ of the differences), ``noise_m`` (c).
    """
    none = {"estimate_m_per_s": None, "lags_s": [], "sd_m": [], "noise_m": None}
    ph = base["phase_cycles"].to_numpy(dtype=float)
    keep = np.isfinite(ph) & (base["el_rad"].to_numpy(dtype=float) >= mask_rad)
    if keep.sum() < DRIFT_MIN_DIFFERENCES:
        return none
    b = base[keep]
    u = b["wavelength_m"].to_numpy(dtype=float) * ph[keep] - observation_model_m(
        *(b[c].to_numpy(dtype=float) for c in ("sx", "sy", "sz", "sat_clock_m", "trop_m")), base_xyz_m, troposphere)
    t = b["time_gps_s"].to_numpy(dtype=float)
    ch = channel_index(b["sat"].to_numpy(), b["signal"].to_numpy())
    sig = pd.factorize(b["signal"].to_numpy())[0]
    grp = pd.factorize(pd.MultiIndex.from_arrays([t, sig]))[0]
    n_in = np.bincount(grp)
    u = u - (np.bincount(grp, weights=u) / n_in)[grp]           # the receiver clock out
    ok = n_in[grp] >= 3
    eph = b["eph_row"].to_numpy() if "eph_row" in b.columns else np.zeros(t.size, dtype=np.int64)
    order = np.lexsort((t, ch))                                 # by channel, then time
    o = order[ok[order]]
    t, u, ch, lli, eph = t[o], u[o], ch[o], b["lli"].to_numpy(dtype=np.int64)[o], eph[o]
    new = np.r_[True, (ch[1:] != ch[:-1]) | ((lli[1:] & 1) > 0) | (eph[1:] != eph[:-1]) | (np.diff(t) > max_age_s)]
    arc = np.cumsum(new)
    lags, sds = [], []
    for k in DRIFT_LAG_STEPS:
        if k >= t.size:
            break
        same = arc[k:] == arc[:-k]
        span = (t[k:] - t[:-k])[same]
        span_ok = span <= max_age_s
        if span_ok.sum() < DRIFT_MIN_DIFFERENCES:
            if span.size and np.median(span) > max_age_s:
                break
            continue
        d = (u[k:] - u[:-k])[same][span_ok]
        lags.append(float(np.mean(span[span_ok])))
        sds.append(1.4826 * float(np.median(np.abs(d - np.median(d)))))
    if len(lags) < 2:
        return dict(none, lags_s=lags, sd_m=sds)
    L, s2 = np.asarray(lags), np.asarray(sds) ** 2
    w = 1.0 / np.maximum(s2, 1e-12)                              # relative residuals
    (c2, a2), *_ = np.linalg.lstsq(np.c_[w, L**2 * w], np.ones(L.size), rcond=None)
    if a2 < 0 or c2 < 0:                                         # one term alone: the other at 0
        c2 = max(c2, 0.0)
        a2 = max(float(np.sum(w**2 * L**2 * (s2 - c2))) / float(np.sum(w**2 * L**4)), 0.0)
    return {"estimate_m_per_s": float(np.sqrt(a2)), "lags_s": lags, "sd_m": sds, "noise_m": float(np.sqrt(c2))}


def _far_epochs(b0, age, tb, time_s, sync_tol_s: float, max_age_s: float):
    """Each row's base epoch t₁ on the other side of its rover time (index into ``tb``, −1: none) and whether it is
    one to interpolate towards (the row not simultaneous with t₀, t₁ existing within ``max_age_s``)."""
    b1 = b0 + np.where(age > 0, 1, -1)
    inside = (np.abs(age) > sync_tol_s) & (b1 >= 0) & (b1 < tb.size)
    b1 = np.where(inside, b1, -1)
    inside &= np.abs(time_s - tb[np.clip(b1, 0, tb.size - 1)]) <= max_age_s
    return b1, inside


def _rows_at(b: pd.DataFrame, m: pd.DataFrame, b1, with_eph: bool) -> pd.DataFrame | None:
    """The base row at t₁ (epoch ``b1``, −1: none) of each row of ``m``, columns suffixed ``_1`` (missing: NaN);
    None when a base row is repeated there (the merge would not be row for row)."""
    cols = list(BASE_ROW_COLUMNS) + (["eph_row"] if with_eph and "eph_row" in b.columns else [])
    other = b[cols].rename(columns={c: c + "_1" for c in cols[3:]}).rename(columns={"_bep": "_b1"})
    o = pd.DataFrame({"_b1": b1, "sat": m["sat"].to_numpy(), "signal": m["signal"].to_numpy()})
    o = o.merge(other, on=["_b1", "sat", "signal"], how="left", sort=False)
    return o if len(o) == len(m) else None


def _row_qualifies(m: pd.DataFrame, o: pd.DataFrame, later, phase, rng) -> np.ndarray:
    """Whether each row may be interpolated by itself: finite observations and flags at t₀ (``m``) and t₁ (``o``),
    no loss of lock between them (the flag at the later of the two), the same half-cycle status and, when the rows
    carry it, the same ephemeris (M₁ − M₀ is then the satellite's motion, not a jump between ephemerides)."""
    lli0 = np.nan_to_num(m["lli_b"].to_numpy(dtype=float), nan=-1).astype(np.int64)
    lli1 = np.nan_to_num(o["lli_1"].to_numpy(dtype=float), nan=-1).astype(np.int64)
    ok = (lli0 >= 0) & (lli1 >= 0) & np.isfinite(phase) & np.isfinite(rng)
    ok &= np.isfinite(o["phase_cycles_1"].to_numpy(dtype=float)) & np.isfinite(o["pseudorange_m_1"].to_numpy(dtype=float))
    ok &= np.where(later, (lli1 & 1) == 0, (lli0 & 1) == 0)
    ok &= (lli1 & 2) == (lli0 & 2)
    if "eph_row_1" in o.columns:
        ok &= o["eph_row_1"].to_numpy(dtype=float) == m["eph_row_b"].to_numpy(dtype=float)
    return ok


def _whole_groups(m: pd.DataFrame, ok: np.ndarray) -> np.ndarray:
    """``ok`` kept only where every row of the rover epoch's signal group (``_ep``, ``signal``) has it."""
    sig_code = pd.factorize(m["signal"].to_numpy())[0].astype(np.int64)
    grp = np.unique(m["_ep"].to_numpy().astype(np.int64) * (int(sig_code.max()) + 1) + sig_code,
                    return_inverse=True)[1].ravel()
    return ok & (np.bincount(grp, weights=~ok, minlength=grp.max() + 1)[grp] == 0)


def base_age_noise(base: pd.DataFrame, pairs, base_xyz, opt: dict) -> dict:
    """The σ per second of base age of option ``age_noise`` (rtk's and the static engine's, so init's): "model",
    ``age_sigma_m_per_s``; "auto", the base's own drift (:func:`base_drift_m_per_s` over its rows above the mask)
    where it exceeds that, when some rover epoch of ``pairs`` is bridged (else nothing to weigh).  Returns
    ``{"mode", "sigma_m_per_s", "estimate_m_per_s"}``.

    Measured (GPS L1, docs/gnss-pipeline.md, session 20): a Crescent base of 2008 (RTKLIB's test data) 10 mm/s,
    its first rover epochs extrapolated 25–29 s and fixed 0.2 m off with σ 3–8 cm at 1.5 mm/s, none off at the
    estimate; mosaic 2.1, the u-blox M8P base 1.3 (1.5 kept), the Leica CORS GLW1 0.9."""
    floor = float(opt["age_sigma_m_per_s"])
    out = {"mode": opt["age_noise"], "sigma_m_per_s": floor, "estimate_m_per_s": None}
    if opt["age_noise"] != "auto" or not pairs.summary.get("bridged"):
        return out
    est = base_drift_m_per_s(base, base_xyz, troposphere=opt["troposphere"], max_age_s=float(opt["max_age_s"]),
                             mask_rad=np.radians(opt["mask_deg"]))["estimate_m_per_s"]
    out["estimate_m_per_s"] = est
    if est is not None and est > floor:
        out["sigma_m_per_s"] = est
    return out
