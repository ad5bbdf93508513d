"""Static short-baseline estimation from two receivers' L1 carrier phase with integer ambiguities.

Model (one master receiver at a known position, one static rover)::

    λ·SD_L  = SD(ρ − c·dt_sat + T) + c·Δdt_rx(epoch) + λ·a_seg + ε     (phase, m)
    SD_P    = SD(ρ − c·dt_sat + T) + c·Δdt_rx(epoch) + ε_P             (pseudorange, float only)

where SD is rover minus master, ρ the geometric range at each receiver's true reception time
(time tag − its clock, from :func:`~cdgps_cli.model.gps.positioning.estimate_receiver_clock`), T the a priori
hydrostatic troposphere, and ``a_seg`` the SD ambiguity of the satellite's lock segment.  Double
differences remove Δdt_rx; their correlated covariance enters through the per-epoch weights
``P = Dᵀ(DΣDᵀ)⁻¹D`` of :mod:`cdgps_cli.measurement.differencing`.

Unknowns: the rover's displacement from its a priori (RINEX header) position in the local
east-north-up frame at that position (``<rover>_e``, ``<rover>_n``, ``<rover>_u``, m) and one
ambiguity per SD segment (cycles) except one datum pivot per connected set.

Steps (:func:`solve_static_baseline`):

1. float solution: weighted least squares over all epochs with phase and pseudorange DDs,
   Gauss-Newton iterations of the linearization (the header position is only decimetre-level);
   normal equations accumulated epoch by epoch (cost linear in the number of epochs);
2. LAMBDA (:func:`~cdgps_cli.estimation.ambiguity.lambda_search`) on the float DD ambiguities with the
   ratio test, partial fixing (:func:`~cdgps_cli.estimation.ambiguity.partial_fix`) if the full set fails;
3. fixed solution from the L1 **phase only**, fixed integers removed from the unknowns
   (unfixed ambiguities stay float), iterated to convergence;
4. kinematic check: every epoch solved alone from its phase DDs with the fixed integers;
   E/N/U RMS of those single-epoch positions about the static solution.
"""

from __future__ import annotations

import math
import time
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy.linalg import cho_factor, cho_solve

from cdgps_cli.estimation.ambiguity import AmbiguityError, fix_integers
from cdgps_cli.io.atomic import path_for_config
from cdgps_cli.config.structure import GNSS_DEFAULTS, GNSS_WEIGHTINGS
from cdgps_cli.measurement.differencing import (
    ambiguity_datum,
    ambiguity_segments,
    dd_weight_blocks,
    double_differences,
    epoch_pointers,
    sd_variance,
    select_reference,
)
from cdgps_cli.model.gps.orbits import SPEED_OF_LIGHT, ecef_to_geodetic, enu_matrix
from cdgps_cli.core.errors import CdgpsError, join_problems
from cdgps_cli.model.gps.positioning import (
    L1_WAVELENGTH_M,
    ephemeris_coverage,
    estimate_receiver_clock,
    match_epochs,
    nominal_interval_s,
    reception_geometry,
    spp_static,
)
from cdgps_cli.io.rinex import gps_time_str, read_rinex_nav, read_rinex_obs

__all__ = [
    "BaselineOptions",
    "Station",
    "solve_static_baseline",
    "load_stations",
    "baseline_from_files",
    "load_baseline_job",
    "format_summary",
    "starter_job_toml",
    "json_safe",
]

LAMBDA_L1 = L1_WAVELENGTH_M


@dataclass(frozen=True)
class BaselineOptions:
    """Settings of :func:`solve_static_baseline` (defaults follow RTKLIB's where it has one).

    Attributes
    ----------
    mask_deg : float
        Elevation mask at both receivers, degrees.
    ratio_threshold : float
        LAMBDA ratio-test threshold (second-best / best squared norm).
    partial : bool
        Try partial fixing (drop the least precise ambiguities) when the full set fails.
    fix : bool
        Resolve integers at all (False: float solution only).
    weighting : {"elevation", "equal"}
        Undifferenced phase variance a² + b²/sin²(el), or a² + b² at all elevations.
    sigma_a_m, sigma_b_m : float
        a and b of the phase error model, m (RTKLIB ``stats-errphase``/``errphaseel``: 3 mm).
    code_ratio : float
        Pseudorange / phase standard-deviation ratio (RTKLIB ``stats-errratio``: 100).
    troposphere : bool
        Apply the a priori hydrostatic troposphere (Saastamoinen + Niell) at both receivers.
    max_iterations : int
        Gauss-Newton iteration cap (float and fixed solutions each).
    sync_tol_s : float
        Largest time-tag difference of matched epochs, s.
    max_gap_s : float or None
        Largest gap within one ambiguity segment, s (None: 1.5 × the epoch interval).
    min_sats_kinematic : int
        Satellites with known ambiguities needed for a single-epoch position.
    kinematic_max_pdop : float
        The kinematic scatter is also reported over the epochs whose PDOP (of the DD geometry)
        is at most this (the last minutes of the GEONET hour have 5 satellites and PDOP > 20).
    kinematic_series : bool
        Include the per-epoch kinematic positions in the result.
    motion : {"static", "random_walk"}
        Rover motion assumed by the float solution that feeds LAMBDA: one position for the whole
        span (batch least squares), or a position per epoch that random-walks with
        ``random_walk_sigma`` m/√s per east/north/up component (:func:`_float_random_walk`).
        The fixed solution reported is the static one in both cases.
    random_walk_sigma : tuple of 3 floats
        Random-walk rate of the rover's E/N/U position, m/√s (``motion="random_walk"``).
    initial_sigma_m : float
        Prior σ of the first epoch's position about the static float solution, m
        (``motion="random_walk"``).
    """

    mask_deg: float = GNSS_DEFAULTS["mask_deg"]
    ratio_threshold: float = GNSS_DEFAULTS["ratio"]
    partial: bool = True
    fix: bool = True
    weighting: str = GNSS_DEFAULTS["weighting"]
    sigma_a_m: float = GNSS_DEFAULTS["sigma_a_m"]
    sigma_b_m: float = GNSS_DEFAULTS["sigma_b_m"]
    code_ratio: float = GNSS_DEFAULTS["code_ratio"]
    troposphere: bool = True
    max_iterations: int = 10
    sync_tol_s: float = GNSS_DEFAULTS["sync_tol_s"]
    max_gap_s: float | None = None
    min_sats_kinematic: int = 4
    kinematic_max_pdop: float = 10.0
    kinematic_series: bool = True
    motion: str = "static"
    random_walk_sigma: tuple = GNSS_DEFAULTS["random_walk_sigma"]
    initial_sigma_m: float = GNSS_DEFAULTS["initial_sigma_m"]

    def validate(self) -> None:
        """Raise :class:`CdgpsError` listing every invalid setting."""
        p = []
        if not (math.isfinite(self.mask_deg) and 0.0 <= self.mask_deg < 90.0):
            p.append(f"mask_deg must be in [0, 90) degrees, got {self.mask_deg!r}")
        if not (math.isfinite(self.ratio_threshold) and self.ratio_threshold >= 1.0):
            p.append(f"ratio threshold must be a number >= 1, got {self.ratio_threshold!r}")
        if self.weighting not in GNSS_WEIGHTINGS:
            p.append(f"weighting must be 'elevation' or 'equal', got {self.weighting!r}")
        for k in ("sigma_a_m", "sigma_b_m"):
            v = getattr(self, k)
            if not (math.isfinite(v) and v >= 0.0):
                p.append(f"{k} must be >= 0, got {v!r}")
        if not self.sigma_a_m > 0 and not self.sigma_b_m > 0:
            p.append("sigma_a_m and sigma_b_m cannot both be 0")
        if not (math.isfinite(self.code_ratio) and self.code_ratio > 0):
            p.append(f"code_ratio must be > 0, got {self.code_ratio!r}")
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            p.append(f"max_iterations must be an integer >= 1, got {self.max_iterations!r}")
        if not (math.isfinite(self.sync_tol_s) and 0.0 < self.sync_tol_s <= 1.0):
            p.append(f"sync_tol_s must be in (0, 1] s, got {self.sync_tol_s!r}")
        if self.max_gap_s is not None and not (math.isfinite(self.max_gap_s) and self.max_gap_s > 0):
            p.append(f"max_gap_s must be > 0 s, got {self.max_gap_s!r}")
        if not (math.isfinite(self.kinematic_max_pdop) and self.kinematic_max_pdop > 0):
            p.append(f"kinematic_max_pdop must be > 0, got {self.kinematic_max_pdop!r}")
        if self.motion not in ("static", "random_walk"):
            p.append(f"motion must be 'static' or 'random_walk', got {self.motion!r}")
        rw = tuple(self.random_walk_sigma) if isinstance(self.random_walk_sigma, (tuple, list)) else ()
        if len(rw) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in rw):
            p.append(f"random_walk_sigma must be three positive numbers (m/√s), got {self.random_walk_sigma!r}")
        if not (math.isfinite(self.initial_sigma_m) and self.initial_sigma_m > 0):
            p.append(f"initial_sigma_m must be > 0, got {self.initial_sigma_m!r}")
        if not (isinstance(self.min_sats_kinematic, int) and self.min_sats_kinematic >= 4):
            p.append(f"min_sats_kinematic must be an integer >= 4, got {self.min_sats_kinematic!r}")
        if p:
            raise CdgpsError(join_problems("invalid baseline options", p))


class Station(NamedTuple):
    """One receiver: a name, the RINEX header dict and the observation table of
    :func:`~cdgps_cli.io.rinex.read_rinex_obs`."""

    name: str
    header: dict
    obs: pd.DataFrame


# ----------------------------------------------------------------------------------------------
# preparation: epochs, clocks, single differences, geometry
# ----------------------------------------------------------------------------------------------


def _header_position(st: Station):
    pos = st.header.get("approx_position_xyz_m")
    if pos is None:
        return None
    pos = np.asarray(pos, dtype=np.float64)
    if pos.shape != (3,) or not np.all(np.isfinite(pos)) or np.linalg.norm(pos) < 6.0e6:
        return None
    return pos


def _where(st: Station) -> str:
    return f"{st.name} ({st.header.get('path', '?')})"


def _span(t) -> str:
    t = np.asarray(t, dtype=np.float64)
    return f"{gps_time_str(float(t.min()))} – {gps_time_str(float(t.max()))}" if t.size else "no epochs"


class _Data(NamedTuple):
    """Single-difference table and everything the estimator needs."""

    ptr: np.ndarray            # (n_ep+1,)
    epoch: np.ndarray          # (N,) epoch index
    sat: np.ndarray            # (N,) satellite index
    sat_names: list
    t_label: np.ndarray        # (n_ep,) nominal epoch time, GPS s
    y_phase_m: np.ndarray      # (N,) λ·(L_rover − L_master)
    y_code_m: np.ndarray       # (N,) P_rover − P_master (NaN if either is missing)
    base_model_m: np.ndarray   # (N,) ρ − c·dt_sat + T at the master
    rover_sat_xyz: np.ndarray  # (N, 3) satellite position for the rover's reception
    rover_clk_trop_m: np.ndarray  # (N,) −c·dt_sat + T at the rover
    el_rover: np.ndarray
    el_base: np.ndarray
    az_rover: np.ndarray
    slip: np.ndarray           # (N,) LLI bit 0 at either receiver
    half: np.ndarray           # (N,) LLI bit 1 at either receiver
    slip_rover: np.ndarray     # (N,) LLI bit 0 at the rover
    slip_base: np.ndarray      # (N,) LLI bit 0 at the master
    reset_epochs: np.ndarray
    interval_s: float
    info: dict


def _prepare(master: Station, rover: Station, nav: pd.DataFrame, opt: BaselineOptions,
             master_xyz, rover_xyz, warnings: list) -> _Data:
    mask = math.radians(opt.mask_deg)
    for st in (master, rover):
        o = st.obs
        if len(o) == 0 or not np.isfinite(o["phase_l1_cycles"].to_numpy(dtype=float)).any():
            raise CdgpsError(f"{_where(st)}: no GPS L1 carrier-phase observations; a carrier-phase baseline needs L1 phase "
                             f"at both receivers")
    tm = np.unique(master.obs["time_gps_s"].to_numpy())
    tr = np.unique(rover.obs["time_gps_s"].to_numpy())
    interval = nominal_interval_s(tm)
    tol = opt.sync_tol_s if not math.isfinite(interval) else min(opt.sync_tol_s, interval / 3.0)
    im, ir = match_epochs(tm, tr, tol_s=tol)
    if im.size == 0:
        raise CdgpsError(f"no common epochs: master {master.name} has {tm.size} epochs ({_span(tm)}), rover {rover.name} "
                         f"has {tr.size} ({_span(tr)}); time tags must agree within {tol * 1e3:g} ms")
    q = 10.0 ** math.floor(math.log10(interval)) / 10.0 if math.isfinite(interval) and interval > 0 else 1e-3
    t_label = np.round(tm[im] / q) * q
    n_ep = im.size

    # per receiver: rows in matched epochs with an ephemeris, epoch index, clocks
    per = {}
    for st, t_all, idx in ((master, tm, im), (rover, tr, ir)):
        o = st.obs
        ep_of_tag = np.full(t_all.size, -1, dtype=np.int64)
        ep_of_tag[idx] = np.arange(n_ep)
        k = ep_of_tag[np.searchsorted(t_all, o["time_gps_s"].to_numpy())]
        o = o[k >= 0].copy()
        o["ep"] = k[k >= 0]
        cov = ephemeris_coverage(nav, o["sat"].to_numpy(), t_label[o["ep"].to_numpy()])
        if not cov.any():
            tn = nav["toe_gps_s"].to_numpy()
            raise CdgpsError(f"the navigation data does not cover the observations of {_where(st)}: observations "
                             f"{_span(t_label)}, broadcast ephemerides with toe {_span(tn)} "
                             f"(each is used within ±2 h of its toe); give the navigation file(s) of that day")
        dropped = o.loc[~cov, "sat"].value_counts()
        if len(dropped):
            warnings.append(f"{st.name}: {int(dropped.sum())} observations of {', '.join(sorted(dropped.index))} have no "
                            f"healthy broadcast ephemeris within ±2 h and are not used")
        o = o[cov]
        ep = o["ep"].to_numpy()
        pos = master_xyz if st is master else rover_xyz
        clk = estimate_receiver_clock(ep, o["sat"].to_numpy(), o["time_gps_s"].to_numpy(),
                                      o["pseudorange_l1_m"].to_numpy(), nav, pos, n_epochs=n_ep,
                                      troposphere=opt.troposphere, what=_where(st))
        o["t_true"] = o["time_gps_s"].to_numpy() - clk[ep]
        per[st.name] = (o, clk)
    om, clk_m = per[master.name]
    orv, clk_r = per[rover.name]
    om = om[np.isfinite(om["phase_l1_cycles"].to_numpy())]
    orv = orv[np.isfinite(orv["phase_l1_cycles"].to_numpy())]
    j = pd.merge(orv, om, on=["ep", "sat"], suffixes=("_r", "_b"), how="inner", sort=True)
    if len(j) == 0:
        raise CdgpsError(f"no satellite has L1 phase at both {master.name} and {rover.name} in any of the {n_ep} common epochs")
    sat_r = j["sat"].to_numpy()
    ep = j["ep"].to_numpy()
    gb = reception_geometry(nav, sat_r, t_label[ep], j["t_true_b"].to_numpy(), master_xyz, troposphere=opt.troposphere)
    gr = reception_geometry(nav, sat_r, t_label[ep], j["t_true_r"].to_numpy(), rover_xyz, troposphere=opt.troposphere)
    keep = (gb["el_rad"] >= mask) & (gr["el_rad"] >= mask)
    below = pd.Series(sat_r[~keep]).value_counts()
    # epochs with fewer than two satellites form no double difference
    cnt = np.bincount(ep[keep], minlength=n_ep)
    keep &= cnt[ep] >= 2
    if keep.sum() < 2:
        raise CdgpsError(f"no double differences: fewer than two common satellites above the {opt.mask_deg:g}° mask "
                         f"at every common epoch ({n_ep} epochs, {_span(t_label)})")
    sel = np.flatnonzero(keep)
    names = sorted(set(sat_r[sel].tolist()))
    sat_idx = {s: i for i, s in enumerate(names)}
    lli_r = j["lli_l1_r"].to_numpy()[sel]
    lli_b = j["lli_l1_b"].to_numpy()[sel]
    reset = set(np.unique(j["ep"].to_numpy()[(j["epoch_flag_r"].to_numpy() == 1) | (j["epoch_flag_b"].to_numpy() == 1)]).tolist())
    ep_sel = ep[sel]
    data = _Data(
        ptr=epoch_pointers(ep_sel, n_ep),
        epoch=ep_sel,
        sat=np.array([sat_idx[s] for s in sat_r[sel]], dtype=np.int64),
        sat_names=names,
        t_label=t_label,
        y_phase_m=LAMBDA_L1 * (j["phase_l1_cycles_r"].to_numpy()[sel] - j["phase_l1_cycles_b"].to_numpy()[sel]),
        y_code_m=j["pseudorange_l1_m_r"].to_numpy()[sel] - j["pseudorange_l1_m_b"].to_numpy()[sel],
        base_model_m=(gb["range_m"] - SPEED_OF_LIGHT * gb["sat_clock_s"] + gb["trop_m"])[sel],
        rover_sat_xyz=gr["sat_xyz_m"][sel],
        rover_clk_trop_m=(-SPEED_OF_LIGHT * gr["sat_clock_s"] + gr["trop_m"])[sel],
        el_rover=gr["el_rad"][sel],
        el_base=gb["el_rad"][sel],
        az_rover=gr["az_rad"][sel],
        slip=((lli_r & 1) | (lli_b & 1)).astype(bool),
        half=((lli_r & 2) | (lli_b & 2)).astype(bool),
        slip_rover=(lli_r & 1).astype(bool),
        slip_base=(lli_b & 1).astype(bool),
        reset_epochs=np.array(sorted(reset), dtype=np.int64),
        interval_s=interval,
        info={
            "n_epochs_master": int(tm.size),
            "n_epochs_rover": int(tr.size),
            "n_epochs_common": int(n_ep),
            "n_epochs_used": int(np.unique(ep_sel).size),
            "interval_s": interval,
            "first_epoch": gps_time_str(float(t_label[0])),
            "last_epoch": gps_time_str(float(t_label[-1])),
            "max_tag_difference_ms": float(np.max(np.abs(tm[im] - tr[ir])) * 1e3),
            "rx_clock_ms": {
                master.name: [float(np.min(clk_m) * 1e3), float(np.max(clk_m) * 1e3)],
                rover.name: [float(np.min(clk_r) * 1e3), float(np.max(clk_r) * 1e3)],
            },
            "below_mask_sd_rows": {str(k): int(v) for k, v in below.items()},
        },
    )
    return data


# ----------------------------------------------------------------------------------------------
# least squares
# ----------------------------------------------------------------------------------------------


def _rover_model(d: _Data, rover_xyz: np.ndarray, r_enu: np.ndarray):
    """SD model (m) and ENU design (N, 3) at a rover position."""
    los = d.rover_sat_xyz - rover_xyz
    rng = np.linalg.norm(los, axis=1)
    e_enu = (los / rng[:, None]) @ r_enu.T
    return rng + d.rover_clk_trop_m - d.base_model_m, -e_enu


def _center(epoch: np.ndarray, r: np.ndarray, n_ep: int, usable=None) -> np.ndarray:
    """Subtract each epoch's mean residual (over ``usable`` rows).

    SD residuals carry the receivers' clock difference (up to ~10³ km); P·1 = 0 removes it
    exactly in theory, but only to ~1e-16 relative in floating point, so it is removed first."""
    w = np.ones(r.size) if usable is None else np.asarray(usable, dtype=float)
    rr = np.where(w > 0, r, 0.0)
    cnt = np.bincount(epoch, weights=w, minlength=n_ep)
    mean = np.bincount(epoch, weights=rr * w, minlength=n_ep) / np.maximum(cnt, 1.0)
    return r - mean[epoch]


def _accumulate(blocks, g, r, col, n_par: int, lam: float):
    """Normal equations Σ_k [G λE]ᵀ P_k [G λE] and right side from per-epoch DD weight blocks.

    ``col[i]`` is the parameter index (≥ 3) of row i's ambiguity, or −1 (known / datum)."""
    nmat = np.zeros((n_par, n_par))
    rhs = np.zeros(n_par)
    size = n_par + 1
    for rows, p in blocks:
        gk = g[rows]                       # (K, n, 3)
        rk = r[rows]                       # (K, n)
        pg = np.einsum("kij,kjc->kic", p, gk)
        pr = np.einsum("kij,kj->ki", p, rk)
        nmat[:3, :3] += np.einsum("kic,kid->cd", gk, pg)
        rhs[:3] += np.einsum("kic,ki->c", gk, pr)
        if col is None:
            continue
        c = col[rows]
        cc = np.where(c >= 0, c, n_par)    # dummy slot for rows without an unknown ambiguity
        lin = (cc[:, :, None] * size + cc[:, None, :]).ravel()
        nmat += (np.bincount(lin, weights=(lam * lam * p).ravel(), minlength=size * size)
                 .reshape(size, size)[:n_par, :n_par])
        flat_c = cc.ravel()
        for q in range(3):  # cross terms λ·(P G)[i, q] at (ambiguity of row i, q); c >= 3, so x block untouched
            v = np.bincount(flat_c, weights=lam * pg[:, :, q].ravel(), minlength=size)[:n_par]
            nmat[:, q] += v
            nmat[q, :] += v
        rhs += np.bincount(flat_c, weights=lam * pr.ravel(), minlength=size)[:n_par]
    return nmat, rhs


def _solve(nmat, rhs, what: str):
    try:
        cf = cho_factor(nmat, lower=False, check_finite=True)
    except np.linalg.LinAlgError:
        raise CdgpsError(f"{what}: the normal equations are singular (too few satellites or epochs for the unknowns)") from None
    return cf, cho_solve(cf, rhs)


def _quad(blocks, r) -> tuple[float, int]:
    """Σ rᵀ P r and the number of DDs."""
    s, m = 0.0, 0
    for rows, p in blocks:
        rk = r[rows]
        s += float(np.einsum("ki,kij,kj->", rk, p, rk))
        m += rows.shape[0] * (rows.shape[1] - 1)
    return s, m


def _float_random_walk(d: _Data, blocks_ph, blocks_code, g, r_ph, r_cd, col, n_amb: int, opt: BaselineOptions):
    """Float ambiguities (and covariance) for a rover whose position random-walks.

    Model per epoch k (SD rows, DD weights P_k of :func:`~cdgps_cli.measurement.differencing.dd_weight_blocks`; phase
    and code): ``r = G δx_k + λ E_k a + ε`` with ``δx_k = δx_{k−1} + w_k``,
    ``w_k ~ N(0, diag(σ²)·Δt)`` and constant ambiguities ``a``.  The positions are eliminated by a
    Kalman filter run *conditionally on a*: its estimate is affine in a (``m_k + M_k a``), its
    covariance does not depend on a, and the prediction-error decomposition of the likelihood
    accumulates ``aᵀJa − 2hᵀa``, so ``â = J⁻¹h`` and ``Cov(â) = J⁻¹`` are the float ambiguities
    of the exact joint (positions + ambiguities) least-squares problem.  Per epoch the innovation
    weight is ``W = P − PG(P⁻¹_pred + GᵀPG)⁻¹GᵀP`` (Woodbury); everything is expressed through
    GᵀPG, GᵀPr and the active ambiguity columns, so an epoch costs O(n_amb²).

    ``r_ph``/``r_cd``/``g`` are the residuals and design at the static float solution (the
    linearization point), ``col`` the parameter index (≥ 3) of each row's ambiguity or −1.

    Returns
    -------
    da : ndarray (n_amb,)
        Correction to the ambiguities behind ``r_ph``, cycles.
    q_aa : ndarray (n_amb, n_amb)
        Their covariance, cycles².
    """
    lam = LAMBDA_L1
    n_ep = d.t_label.size
    N = np.zeros((n_ep, 3, 3))
    b = np.zeros((n_ep, 3))
    has = np.zeros(n_ep, dtype=bool)
    ph = {}
    for rows, p in blocks_ph:
        ep = d.epoch[rows[:, 0]]
        gk, rk = g[rows], r_ph[rows]
        pg = np.einsum("kij,kjc->kic", p, gk)
        pr = np.einsum("kij,kj->ki", p, rk)
        N[ep] += np.einsum("kic,kid->kcd", gk, pg)
        b[ep] += np.einsum("kic,ki->kc", gk, pr)
        has[ep] = True
        cc = col[rows] - 3
        for i in range(rows.shape[0]):
            a_ok = cc[i] >= 0
            if a_ok.any():
                ph[int(ep[i])] = (cc[i][a_ok], lam * pg[i][a_ok].T, lam * pr[i][a_ok], lam * lam * p[i][np.ix_(a_ok, a_ok)])
    for rows, p in blocks_code:
        ep = d.epoch[rows[:, 0]]
        gk, rk = g[rows], r_cd[rows]
        pg = np.einsum("kij,kjc->kic", p, gk)
        N[ep] += np.einsum("kic,kid->kcd", gk, pg)
        b[ep] += np.einsum("kic,kij,kj->kc", gk, p, rk)
        has[ep] = True
    q = np.asarray(opt.random_walk_sigma, dtype=np.float64) ** 2
    m = np.zeros(3)
    M = np.zeros((3, n_amb))
    P = np.eye(3) * opt.initial_sigma_m**2
    J = np.zeros((n_amb, n_amb))
    h = np.zeros(n_amb)
    t = d.t_label
    inv = np.linalg.inv
    for k in range(n_ep):
        if k:
            P = P + np.diag(q * max(t[k] - t[k - 1], 0.0))
        if not has[k]:
            continue
        Nk = N[k]
        Pn = inv(inv(P) + Nk)
        gpu = b[k] - Nk @ m
        gpb = Nk @ M
        bpu = M.T @ gpu
        bpb = M.T @ gpb
        a = ph.get(k)
        if a is not None:
            cols, cr, fr, lr = a
            gpb[:, cols] += cr
            mtc = M.T @ cr
            bpb[:, cols] += mtc
            bpb[cols, :] += mtc.T
            bpb[np.ix_(cols, cols)] += lr
            bpu[cols] += fr - cr.T @ m
        T = Pn @ gpb
        J += bpb - gpb.T @ T
        h += bpu - T.T @ gpu
        m = m + Pn @ gpu
        M = M - T
        P = 0.5 * (Pn + Pn.T)
    J = 0.5 * (J + J.T)
    try:
        cf = cho_factor(J, lower=False, check_finite=True)
    except np.linalg.LinAlgError:
        raise CdgpsError("random-walk float solution: the ambiguities are not separable from the rover's motion "
                         "(too few epochs per lock segment for the random-walk rate); lower random_walk sigma") from None
    return cho_solve(cf, h), cho_solve(cf, np.eye(n_amb))


def solve_static_baseline(master: Station, rover: Station, nav: pd.DataFrame, options: BaselineOptions | None = None,
                          *, master_xyz=None, rover_xyz=None, integers: dict | None = None,
                          keep_work: bool = False) -> dict:
    """Static baseline from two receivers' RINEX observations (see the module docstring).

    Parameters
    ----------
    master, rover : Station
        The reference receiver (held at ``master_xyz``) and the static rover.
    nav : DataFrame
        GPS broadcast ephemerides covering the span (:func:`~cdgps_cli.io.rinex.read_rinex_nav`).
    options : BaselineOptions, optional
    master_xyz : array_like, shape (3,), optional
        Master position, ECEF m (default: its RINEX header APPROX POSITION XYZ).
    rover_xyz : array_like, shape (3,), optional
        Rover a priori position, ECEF m; the ENU frame and the displacement states refer to it
        (default: its header position, else a pseudorange single-point position).
    integers : dict, optional
        Integer DD ambiguities to use instead of resolving them (e.g. from ``cdgps init``):
        ``{(sat, first_epoch_gps_s): integer or None}`` per SD segment as listed in the result's
        ``ambiguities.segments`` (``sat``, ``first_gps_s``, ``integer``); the segments and datum
        pivots of these data must be the same (else :class:`CdgpsError`).  None: LAMBDA.
    keep_work : bool
        Also return the internal arrays under ``"_work"`` (not JSON: SD rows, geometry,
        ambiguities, weights, single-epoch solutions), for the GNSS pipeline's estimators.

    Returns
    -------
    dict
        JSON-ready result: ``states`` (``<rover>_e/_n/_u`` of the reported solution, m),
        ``solution`` ("fixed", "partially fixed" or "float"), ``float`` / ``fixed`` blocks
        (ENU displacement, 1σ, ECEF position, baseline from the master), ``ambiguities``
        (counts, ratio, acceptance, per-segment table), ``residuals`` (DD phase RMS),
        ``kinematic`` (single-epoch scatter), ``epochs``, ``satellites``, ``warnings``,
        ``options``, ``timing_s``.

    Raises
    ------
    CdgpsError
        Missing phase, missing master position, navigation data not covering the span, no
        common epochs or satellites, singular normal equations.
    """
    t_start = time.perf_counter()
    opt = options or BaselineOptions()
    opt.validate()
    warnings: list[str] = []
    xm = _header_position(master) if master_xyz is None else np.asarray(master_xyz, dtype=np.float64)
    if xm is None:
        raise CdgpsError(f"{_where(master)}: the RINEX header has no usable APPROX POSITION XYZ; the master (reference) "
                         f"receiver must be at a known position")
    xr0 = _header_position(rover) if rover_xyz is None else np.asarray(rover_xyz, dtype=np.float64)
    rover_pos_source = "RINEX header APPROX POSITION XYZ" if rover_xyz is None else "given"
    if xr0 is None:
        o = rover.obs
        tt = o["time_gps_s"].to_numpy()
        _, ep = np.unique(tt, return_inverse=True)
        ok = ephemeris_coverage(nav, o["sat"].to_numpy(), tt)
        xr0, _ = spp_static(ep[ok], o["sat"].to_numpy()[ok], tt[ok], o["pseudorange_l1_m"].to_numpy()[ok], nav,
                            x0_ecef_m=xm, what=_where(rover))
        rover_pos_source = "pseudorange single-point position (no header position)"
        warnings.append(f"{rover.name}: no APPROX POSITION XYZ in the header; a priori position from pseudoranges")
    t0 = time.perf_counter()
    d = _prepare(master, rover, nav, opt, xm, xr0, warnings)
    t_prep = time.perf_counter() - t0

    lat, lon, _ = ecef_to_geodetic(xr0)
    r_enu = enu_matrix(lat, lon)
    n_ep = d.t_label.size

    # ambiguities: segments, datum, reference satellites, weights
    seg, segtab = ambiguity_segments(d.epoch, d.sat, d.slip, epoch_time_s=d.t_label, max_gap_s=opt.max_gap_s,
                                     reset_epochs=d.reset_epochs)
    n_seg = segtab["sat"].size
    pivots, comp = ambiguity_datum(d.epoch, seg, n_seg)
    is_pivot = np.zeros(n_seg, dtype=bool)
    is_pivot[pivots] = True
    seg_half = np.bincount(seg, weights=d.half.astype(float), minlength=n_seg) > 0
    free = np.flatnonzero(~is_pivot)                   # parameters: segments that are not pivots
    par_of_seg = np.full(n_seg, -1, dtype=np.int64)
    par_of_seg[free] = 3 + np.arange(free.size)
    n_par = 3 + free.size
    var_ph = sd_variance(d.el_rover, d.el_base, sigma_a_m=opt.sigma_a_m, sigma_b_m=opt.sigma_b_m, weighting=opt.weighting)
    var_code = var_ph * opt.code_ratio**2
    ref_ph = select_reference(d.ptr, d.sat, d.el_rover, d.slip)
    blocks_ph = dd_weight_blocks(d.ptr, var_ph, ref_ph)
    code_ok = np.isfinite(d.y_code_m)
    ref_code = select_reference(d.ptr, d.sat, d.el_rover, usable=code_ok)
    blocks_code = dd_weight_blocks(d.ptr, var_code, ref_code, usable=code_ok)
    y_code = np.where(code_ok, d.y_code_m, 0.0)

    # ---- float solution (phase + code) ----
    # start the SD ambiguities from code-minus-phase (keeps the numbers small), relative to the pivots
    cmp_ = np.where(code_ok, (d.y_phase_m - y_code) / LAMBDA_L1, np.nan)
    a0 = pd.Series(cmp_).groupby(seg).mean().reindex(range(n_seg)).fillna(0.0).to_numpy()
    a_seg = np.round(a0 - a0[pivots][comp])
    a_seg[is_pivot] = 0.0
    x_enu = np.zeros(3)
    col = par_of_seg[seg]
    it_float = 0
    t0 = time.perf_counter()
    for it_float in range(1, opt.max_iterations + 1):
        xr = xr0 + r_enu.T @ x_enu
        model, g = _rover_model(d, xr, r_enu)
        r_ph = _center(d.epoch, d.y_phase_m - model - LAMBDA_L1 * a_seg[seg], n_ep)
        r_cd = _center(d.epoch, y_code - model, n_ep, code_ok)
        n1, b1 = _accumulate(blocks_ph, g, r_ph, col, n_par, LAMBDA_L1)
        n2, b2 = _accumulate(blocks_code, g, r_cd, None, n_par, LAMBDA_L1)
        nmat, rhs = n1 + n2, b1 + b2
        cf, dx = _solve(nmat, rhs, "float solution")
        x_enu = x_enu + dx[:3]
        a_seg[free] += dx[3:]
        if np.max(np.abs(dx[:3])) < 1e-5 and (dx.size == 3 or np.max(np.abs(dx[3:])) < 1e-4):
            break
    q_float = cho_solve(cf, np.eye(n_par))
    t_float = time.perf_counter() - t0
    model, g = _rover_model(d, xr0 + r_enu.T @ x_enu, r_enu)
    r_ph = _center(d.epoch, d.y_phase_m - model - LAMBDA_L1 * a_seg[seg], n_ep)
    r_cd = _center(d.epoch, y_code - model, n_ep, code_ok)
    sq_ph, n_dd_ph = _quad(blocks_ph, r_ph)
    sq_cd, n_dd_cd = _quad(blocks_code, r_cd)
    dof_float = n_dd_ph + n_dd_cd - n_par
    float_block = {
        "enu_m": x_enu.tolist(),
        "sigma_enu_m": np.sqrt(np.diag(q_float)[:3]).tolist(),
        "iterations": it_float,
        "unit_variance": (sq_ph + sq_cd) / dof_float if dof_float > 0 else None,
    }
    x_float = x_enu.copy()

    # ---- integer ambiguity resolution ----
    t0 = time.perf_counter()
    a_float = a_seg[free].copy()
    q_aa = q_float[3:, 3:]
    if opt.motion == "random_walk" and free.size:
        da, q_aa = _float_random_walk(d, blocks_ph, blocks_code, g, r_ph, r_cd, col, n_par - 3, opt)
        a_float = a_float + da
        float_block["motion"] = "random_walk"
        float_block["random_walk_sigma_m_per_sqrt_s"] = list(opt.random_walk_sigma)
    fixable = ~seg_half[free]
    fixed_mask = np.zeros(free.size, dtype=bool)
    integers_fix = np.zeros(free.size, dtype=np.int64)
    ratio = None
    ratio_full = None
    accepted = False
    partial_used = False
    if integers is not None:
        given = {(str(k[0]), round(float(k[1]), 3)): v for k, v in integers.items()}
        keys = [(d.sat_names[int(segtab["sat"][k])], round(float(d.t_label[segtab["first_epoch"][k]]), 3)) for k in range(n_seg)]
        unknown = [f"{k[0]} from {gps_time_str(k[1])}" for k in keys if k not in given]
        extra = [f"{k[0]} from {gps_time_str(k[1])}" for k in given if k not in set(keys)]
        if unknown or extra:
            raise CdgpsError(f"the given integers do not match the ambiguity segments of these data ({n_seg} segments): "
                             + (f"no integer for {', '.join(unknown[:5])}" if unknown else "")
                             + ("; " if unknown and extra else "")
                             + (f"integers for segments these data do not have: {', '.join(extra[:5])}" if extra else ""))
        for k in range(n_seg):
            v = given[keys[k]]
            if is_pivot[k]:
                if v not in (0, None):
                    raise CdgpsError(f"the given integers use another datum: segment {keys[k][0]} from "
                                     f"{gps_time_str(keys[k][1])} is a pivot (0) here, given {v}")
                continue
            j = par_of_seg[k] - 3
            if v is not None:
                fixed_mask[j] = True
                integers_fix[j] = int(v)
        accepted = bool(fixed_mask.any())
    elif opt.fix and fixable.sum() >= 1:
        fi = np.flatnonzero(fixable)
        try:
            fx = fix_integers(a_float[fi], q_aa[np.ix_(fi, fi)], opt.ratio_threshold, opt.partial)
            ratio_full, ratio, partial_used = fx["full_ratio"], fx["ratio"], fx["partial"]
            accepted = bool(fx["fixed_mask"].any())
            fixed_mask[fi[fx["fixed_mask"]]] = True
            integers_fix[fi[fx["fixed_mask"]]] = fx["integers"][fx["fixed_mask"]]
        except AmbiguityError as exc:
            warnings.append(f"integer ambiguity resolution failed: {exc}")
    t_lambda = time.perf_counter() - t0
    n_fixed = int(fixed_mask.sum())

    # ---- fixed solution (L1 phase only) ----
    t0 = time.perf_counter()
    fixed_block = None
    a_fix = a_seg.copy()
    known_seg = is_pivot.copy()
    if n_fixed:
        fsegs = free[fixed_mask]
        a_fix[fsegs] = integers_fix[fixed_mask]
        known_seg[fsegs] = True
        unk = np.flatnonzero(~known_seg)
        par2 = np.full(n_seg, -1, dtype=np.int64)
        par2[unk] = 3 + np.arange(unk.size)
        n_par2 = 3 + unk.size
        col2 = par2[seg]
        x_fix = x_float.copy()
        it_fix = 0
        for it_fix in range(1, opt.max_iterations + 1):
            xr = xr0 + r_enu.T @ x_fix
            model, g = _rover_model(d, xr, r_enu)
            r_ph = _center(d.epoch, d.y_phase_m - model - LAMBDA_L1 * a_fix[seg], n_ep)
            nmat, rhs = _accumulate(blocks_ph, g, r_ph, col2, n_par2, LAMBDA_L1)
            cf2, dx = _solve(nmat, rhs, "fixed solution")
            x_fix = x_fix + dx[:3]
            a_fix[unk] += dx[3:]
            if np.max(np.abs(dx[:3])) < 1e-6 and (dx.size == 3 or np.max(np.abs(dx[3:])) < 1e-5):
                break
        xr = xr0 + r_enu.T @ x_fix
        model, g = _rover_model(d, xr, r_enu)
        r_ph = _center(d.epoch, d.y_phase_m - model - LAMBDA_L1 * a_fix[seg], n_ep)
        q_fix = cho_solve(cf2, np.eye(n_par2))
        sq, n_dd = _quad(blocks_ph, r_ph)
        dof = n_dd - n_par2
        fixed_block = {
            "enu_m": x_fix.tolist(),
            "sigma_enu_m": np.sqrt(np.diag(q_fix)[:3]).tolist(),
            "iterations": it_fix,
            "unit_variance": sq / dof if dof > 0 else None,
            "observations": "L1 carrier phase only",
        }
        x_final, final_kind = x_fix, ("fixed" if n_fixed == free.size else "partially fixed")
    else:
        xr = xr0 + r_enu.T @ x_float
        model, g = _rover_model(d, xr, r_enu)
        r_ph = _center(d.epoch, d.y_phase_m - model - LAMBDA_L1 * a_seg[seg], n_ep)
        x_final, final_kind = x_float, "float"
    t_fixed = time.perf_counter() - t0

    # DD phase residuals of the reported solution
    dd_res = double_differences(d.ptr, ref_ph, r_ph)
    res_v = dd_res["value"]
    residuals = {
        "dd_phase_rms_m": float(np.sqrt(np.mean(res_v**2))) if res_v.size else None,
        "dd_phase_max_abs_m": float(np.max(np.abs(res_v))) if res_v.size else None,
        "n_dd_phase": int(res_v.size),
        "n_dd_code": int(n_dd_cd),
        "per_satellite_rms_m": {
            d.sat_names[s]: float(np.sqrt(np.mean(res_v[d.sat[dd_res["row"]] == s] ** 2)))
            for s in np.unique(d.sat[dd_res["row"]])
        },
    }

    # ---- single-epoch (kinematic) positions with the fixed integers ----
    t0 = time.perf_counter()
    kin = None
    if n_fixed:
        usable = known_seg[seg]
        ref_k = select_reference(d.ptr, d.sat, d.el_rover, d.slip, usable=usable)
        blocks_k = dd_weight_blocks(d.ptr, var_ph, ref_k, usable=usable)
        ep_list, enu_list, ns_list, pdop_list, cov_list = [], [], [], [], []
        for rows, p in blocks_k:
            if rows.shape[1] < opt.min_sats_kinematic:
                continue
            gk, rk = g[rows], r_ph[rows]
            nk = np.einsum("kic,kij,kjd->kcd", gk, p, gk)
            bk = np.einsum("kic,kij,kj->kc", gk, p, rk)
            ck = np.linalg.inv(nk)
            dk = np.einsum("kcd,kd->kc", ck, bk)
            gc = gk - gk.mean(axis=1, keepdims=True)       # geometry with the clock eliminated
            pdop = np.sqrt(np.trace(np.linalg.inv(np.einsum("kic,kid->kcd", gc, gc)), axis1=1, axis2=2))
            ep_list.append(d.epoch[rows[:, 0]])
            enu_list.append(x_final + dk)
            ns_list.append(np.full(rows.shape[0], rows.shape[1]))
            pdop_list.append(pdop)
            cov_list.append(ck)
        if ep_list:
            ep_k = np.concatenate(ep_list)
            enu_k = np.concatenate(enu_list)
            ns_k = np.concatenate(ns_list)
            pd_k = np.concatenate(pdop_list)
            cov_k = np.concatenate(cov_list)
            o = np.argsort(ep_k)
            ep_k, enu_k, ns_k, pd_k, cov_k = ep_k[o], enu_k[o], ns_k[o], pd_k[o], cov_k[o]
            dev = enu_k - x_final

            def _stats(m):
                dv = dev[m]
                return {
                    "n_epochs": int(m.sum()),
                    "rms_about_static_m": dict(zip(("e", "n", "u"), np.sqrt(np.mean(dv**2, axis=0)).tolist())),
                    "std_m": dict(zip(("e", "n", "u"), np.std(enu_k[m], axis=0).tolist())),
                    "mean_minus_static_m": dict(zip(("e", "n", "u"), np.mean(dv, axis=0).tolist())),
                    "max_abs_deviation_m": dict(zip(("e", "n", "u"), np.max(np.abs(dv), axis=0).tolist())),
                }

            kin = _stats(np.ones(ep_k.size, dtype=bool))
            kin["min_satellites"] = opt.min_sats_kinematic
            kin["pdop_range"] = [float(pd_k.min()), float(pd_k.max())]
            good = pd_k <= opt.kinematic_max_pdop
            if good.any() and not good.all():
                kin["pdop_le_max"] = dict(_stats(good), max_pdop=opt.kinematic_max_pdop)
            if opt.kinematic_series:
                kin["epochs"] = [
                    {"time": gps_time_str(float(d.t_label[e])), "time_gps_s": float(d.t_label[e]), "n_sat": int(n),
                     "pdop": float(pp), "e_m": float(v[0]), "n_m": float(v[1]), "u_m": float(v[2])}
                    for e, v, n, pp in zip(ep_k, enu_k, ns_k, pd_k)
                ]
    t_kin = time.perf_counter() - t0

    # ---- report ----
    names = [f"{rover.name}_{c}" for c in ("e", "n", "u")]
    xr_final = xr0 + r_enu.T @ x_final
    latm, lonm, _ = ecef_to_geodetic(xm)
    base_enu = enu_matrix(latm, lonm) @ (xr_final - xm)

    def _block(b, x):
        if b is None:
            return None
        xx = xr0 + r_enu.T @ np.asarray(x)
        b = dict(b)
        b["states"] = dict(zip(names, b["enu_m"]))
        b["rover_ecef_m"] = xx.tolist()
        return b

    seg_rows = []
    for k in range(n_seg):
        p_idx = par_of_seg[k] - 3
        seg_rows.append({
            "sat": d.sat_names[int(segtab["sat"][k])],
            "first": gps_time_str(float(d.t_label[segtab["first_epoch"][k]])),
            "last": gps_time_str(float(d.t_label[segtab["last_epoch"][k]])),
            "n_epochs": int(segtab["n_rows"][k]),
            "pivot": bool(is_pivot[k]),
            "half_cycle_flag": bool(seg_half[k]),
            "float_cycles": None if is_pivot[k] else float(a_float[p_idx]),
            "sigma_cycles": None if is_pivot[k] else float(math.sqrt(q_aa[p_idx, p_idx])),
            "fixed": bool(is_pivot[k] or (p_idx >= 0 and fixed_mask[p_idx])),
            "integer": (0 if is_pivot[k] else (int(integers_fix[p_idx]) if fixed_mask[p_idx] else None)),
            "first_gps_s": float(d.t_label[segtab["first_epoch"][k]]),
            "last_gps_s": float(d.t_label[segtab["last_epoch"][k]]),
        })
    sats_info = []
    for s, nm in enumerate(d.sat_names):
        m = d.sat == s
        sats_info.append({"sat": nm, "n_epochs": int(m.sum()),
                          "elevation_deg": [float(np.degrees(d.el_rover[m].min())), float(np.degrees(d.el_rover[m].max()))],
                          "slips": int(d.slip[m].sum()), "segments": int(np.sum(segtab["sat"] == s))})
    ref_ep = np.flatnonzero(ref_ph >= 0)
    ref_sat = d.sat[ref_ph[ref_ep]]
    starts = np.flatnonzero(np.r_[True, np.diff(ref_sat) != 0])
    ref_list = [{"sat": d.sat_names[int(ref_sat[i])], "from": gps_time_str(float(d.t_label[ref_ep[i]]))} for i in starts]
    n_ref_changes = int(starts.size - 1) if starts.size else 0
    total = time.perf_counter() - t_start
    result = {
        "kind": "cdgps static baseline",
        "master": master.name,
        "rover": rover.name,
        "solution": final_kind,
        "states": dict(zip(names, x_final.tolist())),
        "state_units": "m (rover displacement from its a priori position, local east/north/up at that position)",
        "master_ecef_m": xm.tolist(),
        "rover_apriori_ecef_m": xr0.tolist(),
        "rover_apriori_source": rover_pos_source,
        "rover_ecef_m": xr_final.tolist(),
        "baseline_enu_from_master_m": base_enu.tolist(),
        "baseline_length_m": float(np.linalg.norm(xr_final - xm)),
        "float": _block(float_block, x_float),
        "fixed": _block(fixed_block, x_final) if fixed_block else None,
        "ambiguities": {
            "n_segments": int(n_seg),
            "n_pivots": int(pivots.size),
            "n_estimated": int(free.size),
            "n_fixed": n_fixed,
            "n_half_cycle_excluded": int(np.sum(seg_half[free])),
            "ratio": ratio,
            "ratio_full_set": ratio_full,
            "ratio_threshold": opt.ratio_threshold,
            "accepted": bool(accepted),
            "partial": partial_used,
            "segments": seg_rows,
        },
        "residuals": residuals,
        "kinematic": kin,
        "epochs": dict(d.info, n_reference_changes=n_ref_changes, reference_satellites=ref_list),
        "satellites": sats_info,
        "warnings": warnings,
        "options": asdict(opt),
        "timing_s": {"prepare": t_prep, "float": t_float, "lambda": t_lambda, "fixed": t_fixed, "kinematic": t_kin,
                     "total": total},
    }
    if keep_work:
        kin_arrays = None
        if kin is not None:
            kin_arrays = {"epoch": ep_k, "enu_m": enu_k, "cov_m2": cov_k, "n_sat": ns_k, "pdop": pd_k}
        result["_work"] = {
            "data": d, "seg": seg, "segtab": segtab, "is_pivot": is_pivot, "seg_half": seg_half,
            "known_seg": known_seg if n_fixed else is_pivot.copy(), "a_seg": a_fix if n_fixed else a_seg,
            "var_ph": var_ph, "ref_ph": ref_ph, "xr0": xr0, "xm": xm, "r_enu": r_enu, "x_final": np.asarray(x_final),
            "q_final": (q_fix[:3, :3] if n_fixed else q_float[:3, :3]), "r_ph": r_ph, "g": g, "kinematic": kin_arrays,
        }
    return result


# ----------------------------------------------------------------------------------------------
# files, job configs, summaries
# ----------------------------------------------------------------------------------------------


def load_stations(rinex: dict, nav_paths) -> tuple[dict, pd.DataFrame]:
    """Read RINEX observation files (``{name: path}``) and navigation files into Stations and one
    ephemeris table (duplicates across files removed)."""
    if not nav_paths:
        raise CdgpsError("no navigation file given (--nav): GPS broadcast ephemerides are needed for satellite positions")
    stations = {}
    for name, path in rinex.items():
        h, o = read_rinex_obs(path)
        stations[name] = Station(name, h, o)
    navs = [read_rinex_nav(p) for p in nav_paths]
    nav = pd.concat(navs, ignore_index=True)
    nav = nav.drop_duplicates(subset=["sat", "toe_gps_s", "iode", "af0_s"], keep="first")
    nav = nav.sort_values(["sat", "toe_gps_s", "transmit_gps_s"], kind="stable").reset_index(drop=True)
    return stations, nav


def baseline_from_files(rinex: dict, nav_paths, master: str, options: BaselineOptions | None = None,
                        positions: dict | None = None) -> dict:
    """Read the files and solve (:func:`solve_static_baseline`); ``rinex`` maps exactly two station
    names to observation files, ``master`` is one of them; ``positions`` optionally gives
    ``{name: ECEF m}`` instead of the RINEX header positions."""
    if len(rinex) != 2:
        raise CdgpsError(f"a baseline needs exactly two RINEX observation files (NAME=PATH), got {len(rinex)}: "
                         f"{', '.join(rinex) or 'none'}")
    if master not in rinex:
        raise CdgpsError(f"master {master!r} is not one of the stations given: {', '.join(rinex)}")
    (options or BaselineOptions()).validate()
    stations, nav = load_stations(rinex, nav_paths)
    rover = next(n for n in rinex if n != master)
    pos = positions or {}
    res = solve_static_baseline(stations[master], stations[rover], nav, options, master_xyz=pos.get(master),
                                rover_xyz=pos.get(rover))
    res["inputs"] = {"rinex": {k: str(v) for k, v in rinex.items()}, "nav": [str(p) for p in nav_paths]}
    return res


_JOB_KEYS = {
    "name": str, "description": str, "master": str, "nav": list, "rinex": dict, "mask_deg": (int, float),
    "ratio": (int, float), "partial": bool, "weighting": str, "troposphere": bool, "sigma_a_m": (int, float),
    "sigma_b_m": (int, float), "code_ratio": (int, float), "max_gap_s": (int, float),
}


def load_baseline_job(path) -> dict:
    """Read a baseline job file: a GNSS run config (``[gnss]`` table, docs/gnss-pipeline.md) with
    two RINEX antennas, or the older form with one ``[baseline]`` table (docs/geonet.md).

    Relative file paths are taken relative to the job file's directory.

    Returns
    -------
    dict
        ``name``, ``master``, ``rinex`` ({name: Path}), ``nav`` ([Path]), ``options``
        (:class:`BaselineOptions`) and ``positions`` ({name: ECEF m} given in the file; the
        others come from the RINEX headers).

    Raises
    ------
    CdgpsError
        Unreadable file, TOML syntax error, unknown or mistyped keys (all listed at once).
    """
    p = Path(path)
    try:
        text = p.read_text()
        text = text[1:] if text.startswith("\ufeff") else text     # a UTF-8 byte-order mark
        doc = tomllib.loads(text)
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise CdgpsError(f"{p}: not valid TOML: {exc}") from None
    if "gnss" in doc:
        return _job_from_gnss_config(p, text)
    problems = []
    extra = sorted(set(doc) - {"baseline"})
    if extra:
        problems.append(f"unknown top-level key(s) {', '.join(extra)} (a baseline job has one [baseline] table)")
    b = doc.get("baseline")
    if not isinstance(b, dict):
        raise CdgpsError(join_problems(f"{p}: invalid baseline job", problems + ["missing [baseline] table (or a [gnss] table)"]))
    for k, v in b.items():
        t = _JOB_KEYS.get(k)
        if t is None:
            problems.append(f"baseline.{k}: unknown key (known: {', '.join(sorted(_JOB_KEYS))})")
        elif not isinstance(v, t) or (t == (int, float) and isinstance(v, bool)):
            problems.append(f"baseline.{k}: expected {getattr(t, '__name__', 'a number')}, got {v!r}")
    for k in ("master", "rinex", "nav"):
        if k not in b:
            problems.append(f"baseline.{k}: required")
    base = p.parent
    rinex = {}
    if isinstance(b.get("rinex"), dict):
        for n, v in b["rinex"].items():
            if not isinstance(v, str):
                problems.append(f"baseline.rinex.{n}: expected a file path string, got {v!r}")
            else:
                rinex[str(n)] = (base / v) if not Path(v).is_absolute() else Path(v)
        if len(rinex) != 2:
            problems.append(f"baseline.rinex: expected exactly two stations, got {len(b['rinex'])}")
    nav = []
    if isinstance(b.get("nav"), list):
        for i, v in enumerate(b["nav"]):
            if not isinstance(v, str):
                problems.append(f"baseline.nav[{i}]: expected a file path string, got {v!r}")
            else:
                nav.append((base / v) if not Path(v).is_absolute() else Path(v))
        if not nav:
            problems.append("baseline.nav: at least one navigation file is needed")
    if isinstance(b.get("master"), str) and rinex and b["master"] not in rinex:
        problems.append(f"baseline.master: {b['master']!r} is not one of baseline.rinex ({', '.join(rinex)})")
    if problems:
        raise CdgpsError(join_problems(f"{p}: invalid baseline job", problems))
    kw = {}
    for k_job, k_opt in (("mask_deg", "mask_deg"), ("ratio", "ratio_threshold"), ("partial", "partial"),
                         ("weighting", "weighting"), ("troposphere", "troposphere"), ("sigma_a_m", "sigma_a_m"),
                         ("sigma_b_m", "sigma_b_m"), ("code_ratio", "code_ratio"), ("max_gap_s", "max_gap_s")):
        if k_job in b:
            kw[k_opt] = float(b[k_job]) if isinstance(b[k_job], (int, float)) and not isinstance(b[k_job], bool) else b[k_job]
    opt = BaselineOptions(**kw)
    try:
        opt.validate()
    except CdgpsError as exc:
        raise CdgpsError(f"{p}: {exc}") from None
    return {"name": b.get("name", p.stem), "master": b["master"], "rinex": rinex, "nav": nav, "options": opt,
            "positions": {}}


def _job_from_gnss_config(p: Path, text: str) -> dict:
    """A baseline job from a GNSS run config: exactly two antennas with RINEX files."""
    from cdgps_cli.config.structure import parse_gnss_config  # noqa: PLC0415

    cfg = parse_gnss_config(text, str(p), base_dir=p.resolve().parent)
    problems = []
    if not cfg.master:
        problems.append("gnss.master: required for a baseline")
    if len(cfg.antennas) != 2:
        problems.append(f"gnss.antennas: a baseline needs exactly two antennas, got {len(cfg.antennas)}")
    for a in cfg.antennas:
        if not a.rinex:
            problems.append(f"gnss.antennas.{a.name}: 'cdgps baseline' needs a rinex observation file"
                            + (" (UBX logs go through 'cdgps ingest')" if a.ubx else ""))
    if not cfg.nav:
        problems.append("gnss.nav: at least one navigation file is needed")
    if problems:
        raise CdgpsError(join_problems(f"{p}: not usable as a baseline job", problems))
    opt = cfg.baseline_options(motion="static")        # 'cdgps baseline' is the static solution
    try:
        opt.validate()
    except CdgpsError as exc:
        raise CdgpsError(f"{p}: {exc}") from None
    return {"name": cfg.name, "master": cfg.master, "rinex": {a.name: Path(a.rinex) for a in cfg.antennas},
            "nav": [Path(n) for n in cfg.nav], "options": opt,
            "positions": {a.name: a.position_ecef_m for a in cfg.antennas if a.position_ecef_m is not None}}


def starter_job_toml(rinex: dict, nav_paths, master: str | None = None, *, relative_to: Path | None = None) -> str:
    """Text of a starter baseline job for the given files (headers are read for the comments).

    The master defaults to the first station; paths are written relative to ``relative_to``
    (the job file's directory) when possible.
    """
    if len(rinex) != 2:
        raise CdgpsError(f"a baseline job needs exactly two RINEX observation files (NAME=PATH), got {len(rinex)}")
    master = master or next(iter(rinex))
    if master not in rinex:
        raise CdgpsError(f"master {master!r} is not one of the stations given: {', '.join(rinex)}")

    def rel(pth):
        return path_for_config(pth, relative_to)

    lines = ["# cdgps baseline job (format: docs/geonet.md); run:  cdgps baseline --config THIS_FILE -o OUT.json", ""]
    for name, path in rinex.items():
        h, o = read_rinex_obs(path)
        pos = h.get("approx_position_xyz_m")
        lines.append(f"# {name}: {h.get('marker_name') or '?'}, {h.get('receiver_type') or '?'}, "
                     f"{h.get('n_epochs')} epochs {_span(np.unique(o['time_gps_s']))}, "
                     f"header position {pos if pos else 'none'}")
    lines += ["", "[baseline]", f'name = "{"-".join(rinex)}"', f'master = "{master}"',
              "nav = [" + ", ".join(f'"{rel(p)}"' for p in nav_paths) + "]",
              "mask_deg = 15.0", "ratio = 3.0", "partial = true", 'weighting = "elevation"', "troposphere = true", "",
              "[baseline.rinex]"]
    lines += [f'"{n}" = "{rel(p)}"' for n, p in rinex.items()]
    return "\n".join(lines) + "\n"


def json_safe(obj):
    """Copy of a result with numpy scalars made Python and non-finite floats made JSON-safe
    (NaN → None, ±inf → "inf"/"-inf", e.g. a ratio whose best candidate has zero norm)."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [json_safe(v) for v in obj.tolist()]
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        if math.isnan(v):
            return None
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return v
    return obj


def format_summary(res: dict) -> str:
    """Human summary of a :func:`solve_static_baseline` result (several lines)."""
    ep = res["epochs"]
    amb = res["ambiguities"]
    st = res["states"]
    rv = res["rover"]
    iv = "one epoch: no interval" if ep["interval_s"] is None else f"{ep['interval_s']:g} s"
    lines = [
        f"baseline {res['master']} → {rv}: {ep['n_epochs_used']} of {ep['n_epochs_common']} common epochs "
        f"({ep['first_epoch']} – {ep['last_epoch']}, {iv}), {len(res['satellites'])} satellites, "
        f"{res['residuals']['n_dd_phase']} DD phases, {ep['n_reference_changes']} reference changes",
    ]
    r = amb["ratio"]
    rtxt = "-" if r is None else (r if isinstance(r, str) else format(r, ".2f"))
    lines.append(f"  ambiguities: {amb['n_segments']} SD segments ({amb['n_pivots']} datum), {amb['n_fixed']} of "
                 f"{amb['n_estimated']} fixed, ratio {rtxt} "
                 f"(threshold {amb['ratio_threshold']:g}){' partial' if amb['partial'] else ''} → {res['solution']}")
    sol = res["fixed"] or res["float"]
    sig = sol["sigma_enu_m"]
    lines.append(f"  {rv} displacement from its header position (ENU, m): "
                 + ", ".join(f"{k} {st[k]:+.4f} ± {s:.4f}" for k, s in zip(st, sig)))
    if res["fixed"] and res["float"]:
        df = np.array(res["fixed"]["enu_m"]) - np.array(res["float"]["enu_m"])
        lines.append(f"  fixed − float: E {df[0] * 1e3:+.1f} N {df[1] * 1e3:+.1f} U {df[2] * 1e3:+.1f} mm")
    b = res["baseline_enu_from_master_m"]
    lines.append(f"  baseline from {res['master']}: E {b[0]:.4f} N {b[1]:.4f} U {b[2]:.4f} m, length {res['baseline_length_m']:.4f} m")
    rr = res["residuals"]
    if rr["dd_phase_rms_m"] is not None:
        lines.append(f"  DD phase residuals: RMS {rr['dd_phase_rms_m'] * 1e3:.1f} mm, max {rr['dd_phase_max_abs_m'] * 1e3:.1f} mm")
    k = res["kinematic"]
    if k:
        rms = k["rms_about_static_m"]
        lines.append(f"  single-epoch fixed positions ({k['n_epochs']} epochs, PDOP {k['pdop_range'][0]:.1f}–"
                     f"{k['pdop_range'][1]:.1f}): RMS about static E {rms['e'] * 1e3:.1f} N {rms['n'] * 1e3:.1f} "
                     f"U {rms['u'] * 1e3:.1f} mm")
        g = k.get("pdop_le_max")
        if g:
            rms = g["rms_about_static_m"]
            lines.append(f"    {g['n_epochs']} epochs with PDOP ≤ {g['max_pdop']:g}: RMS E {rms['e'] * 1e3:.1f} "
                         f"N {rms['n'] * 1e3:.1f} U {rms['u'] * 1e3:.1f} mm")
    for w in res["warnings"]:
        lines.append(f"  warning: {w}")
    return "\n".join(lines)
