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
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy.linalg import cho_factor, cho_solve

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M, SPEED_OF_LIGHT_M_S
from cdgps_cli.core import beside, progress
from cdgps_cli.core.checks import header_position_m
from cdgps_cli.core.signals import SIGNALS
from cdgps_cli.estimation.ambiguity import AmbiguityError, resolve
from cdgps_cli.estimation.model_filter import filter_numpy
from cdgps_cli.estimation.kalman import positive_definite
from cdgps_cli.measurement.dd_displacement import SatelliteDDDisplacement, SDObservations
from cdgps_cli.model.dynamics_models import RandomWalk, WithConstants
from cdgps_cli.config.limits import MASK_DEG
from cdgps_cli.config.options import (EPOCH_PAIRING_DEFAULTS, FIXED_PHASE_UNIT_VARIANCE_MAX, FIXED_PHASE_WINDOW_S,
                                      FIXED_PHASE_WINDOW_UNIT_VARIANCE_MAX, GNSS_DEFAULTS, GNSS_WEIGHTINGS,
                                      HEADER_CHECK_EPOCHS, HEADER_POSITION_TOL_M, UNCHECKED_FIX_NIS_MAX)
from cdgps_cli.measurement.slips import unflagged_slip_text
from cdgps_cli.measurement.differencing import (
    ambiguity_datum,
    ambiguity_segments,
    dd_weight_blocks,
    double_differences,
    epoch_pointers,
    sd_variance,
    select_reference,
)
from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
from cdgps_cli.core.errors import CdgpsError, join_problems
from cdgps_cli.model.gps.positioning import (
    antenna_reference_point_m,
    rover_delta_note,
    ephemeris_coverage_all,
    estimate_receiver_clock,
    nominal_interval_s,
    reception_geometry,
    spp_spread,
    tropo_hydrostatic_m,
)
from cdgps_cli.core.gps_time import gps_time_str, spans_meet, time_span
from cdgps_cli.measurement.dd_signals import glonass_code_factor
from cdgps_cli.measurement.epoch_fit import full_rank
from cdgps_cli.measurement.epoch_pairing import age_variance_m2, nearest_tags, pair_epochs, rows_for_pairs, NO_DD, without_dd
from cdgps_cli.measurement.noise import correlated_variance_factor
from cdgps_cli.model.gps.epoch_align import ALIGN_MODES, align_receiver, carry_slips

__all__ = [
    "BaselineOptions",
    "Station",
    "solve_static_baseline",
    "baseline_from_init",
    "format_summary",
    "json_safe",
]


# prior σ of the ambiguity corrections in the random-walk float filter, cycles (removed exactly afterwards;
# large against any correction, small enough to keep the filter's covariance well conditioned)
AMBIGUITY_PRIOR_SIGMA_CYCLES = 100.0


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
        Largest offset of a rover epoch's time tag from its grid time of GPS seconds, s (epochs
        farther away are dropped; :mod:`cdgps_cli.model.gps.epoch_align`); base and rover epochs this
        close are simultaneous (:mod:`cdgps_cli.measurement.epoch_pairing`).
    max_age_s : float
        Oldest base epoch bridged to a rover epoch, s (a base with gaps or a lower rate; RTKLIB's
        ``pos2-maxage``): the rover's epochs drive, each paired with the nearest base epoch.
    code_correlation_s : float
        Correlation time of the code errors, s: their variance is inflated by (1+ρ)/(1−ρ),
        ρ = exp(−interval/τ) (:func:`~cdgps_cli.measurement.noise.correlated_variance_factor`; 0: white).
    epoch_alignment : {"geometry", "doppler"}
        Off-grid epochs modelled at their own reception instants, or their phase and range moved
        to the grid time by carrier-phase rate × offset.
    max_gap_s : float or None
        Largest gap within one ambiguity segment, s (None: no limit — a satellite missing while others are
        observed starts a new segment, an epoch with no observation at all does not;
        :func:`~cdgps_cli.measurement.differencing.ambiguity_segments`).
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
    min_success_rate : float
        Besides the ratio test, the integer set (or partial subset) must reach this bootstrapped
        success rate (Teunissen 1998) to be fixed; 0 turns the criterion off.
    glonass_fix : bool
        GLONASS double differences fixed as integers (identical receivers only: their inter-frequency
        biases cancel); the static engine only (the batch keeps GLONASS float and refuses the option).
    age_sigma_m_per_s : float or None
        σ a bridged base observation gains per second of its age, m/s (:func:`~cdgps_cli.measurement.epoch_pairing.
        age_variance_m2`); None: rtk's ``--age-noise auto``, the base's own drift where it exceeds RTKLIB's 1.5 mm/s
        (:func:`~cdgps_cli.measurement.base_interpolation.base_age_noise`, found once per baseline when some rover
        epoch is bridged; the value found is what the result's ``options`` record, so ``estimate`` weighs as
        ``init`` did).
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
    max_age_s: float = GNSS_DEFAULTS["max_age_s"]
    code_correlation_s: float = GNSS_DEFAULTS["code_correlation_s"]
    epoch_alignment: str = GNSS_DEFAULTS["epoch_alignment"]
    max_gap_s: float | None = None
    min_sats_kinematic: int = 4
    kinematic_max_pdop: float = 10.0
    kinematic_series: bool = True
    motion: str = "static"
    random_walk_sigma: tuple = GNSS_DEFAULTS["random_walk_sigma"]
    initial_sigma_m: float = GNSS_DEFAULTS["initial_sigma_m"]
    min_success_rate: float = GNSS_DEFAULTS["min_success_rate"]
    glonass_fix: bool = GNSS_DEFAULTS["glonass_fix"]
    age_sigma_m_per_s: float | None = None

    @classmethod
    def from_gnss_config(cls, cfg, **overrides) -> "BaselineOptions":
        """The solver settings of a GNSS run config (:class:`~cdgps_cli.config.structure.GnssConfig`),
        with ``overrides`` (field name → value) on top."""
        kw = dict(mask_deg=cfg.mask_deg, ratio_threshold=cfg.ratio, partial=cfg.partial, fix=cfg.fix,
                  weighting=cfg.weighting, sigma_a_m=cfg.sigma_a_m, sigma_b_m=cfg.sigma_b_m,
                  code_ratio=cfg.code_ratio, troposphere=cfg.troposphere, max_gap_s=cfg.max_gap_s,
                  sync_tol_s=cfg.sync_tol_s, max_age_s=cfg.max_age_s, code_correlation_s=cfg.code_correlation_s,
                  epoch_alignment=cfg.epoch_alignment, random_walk_sigma=tuple(cfg.random_walk_sigma),
                  # a constant-velocity rover's integers: resolved on the random-walk float (the weaker motion prior)
                  motion="random_walk" if cfg.displacement == "constant_velocity" else cfg.displacement,
                  initial_sigma_m=cfg.initial_sigma_m, min_success_rate=cfg.min_success_rate,
                  glonass_fix=cfg.glonass_fix)
        kw.update(overrides)
        return cls(**kw)

    def validate(self) -> None:
        """Raise :class:`CdgpsError` listing every invalid setting."""
        p = []
        if not (math.isfinite(self.mask_deg) and MASK_DEG.contains(self.mask_deg)):
            p.append(f"mask_deg must be in {MASK_DEG.text()}, got {self.mask_deg!r}")
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
        if not (math.isfinite(self.max_age_s) and self.max_age_s >= self.sync_tol_s):
            p.append(f"max_age_s must be a number of seconds >= sync_tol_s, got {self.max_age_s!r}")
        if not (math.isfinite(self.code_correlation_s) and self.code_correlation_s >= 0):
            p.append(f"code_correlation_s must be >= 0 s, got {self.code_correlation_s!r}")
        if self.epoch_alignment not in ALIGN_MODES:
            p.append(f"epoch_alignment must be one of {', '.join(ALIGN_MODES)}, got {self.epoch_alignment!r}")
        if self.max_gap_s is not None and not (math.isfinite(self.max_gap_s) and self.max_gap_s > 0):
            p.append(f"max_gap_s must be > 0 s, got {self.max_gap_s!r}")
        if not (math.isfinite(self.kinematic_max_pdop) and self.kinematic_max_pdop > 0):
            p.append(f"kinematic_max_pdop must be > 0, got {self.kinematic_max_pdop!r}")
        if self.motion not in ("static", "random_walk"):
            p.append(f"motion must be 'static' or 'random_walk', got {self.motion!r}")
        rw = tuple(self.random_walk_sigma) if isinstance(self.random_walk_sigma, (tuple, list)) else ()
        if len(rw) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in rw):
            p.append(f"random_walk_sigma must be three positive numbers (m/√s), got {self.random_walk_sigma!r}")
        if not (isinstance(self.min_success_rate, (int, float)) and 0.0 <= self.min_success_rate < 1.0):
            p.append(f"min_success_rate must be a probability in [0, 1), got {self.min_success_rate!r}")
        if not isinstance(self.glonass_fix, bool):
            p.append(f"glonass_fix must be true or false, got {self.glonass_fix!r}")
        a = self.age_sigma_m_per_s
        if a is not None and not (isinstance(a, (int, float)) and not isinstance(a, bool) and math.isfinite(a) and a > 0):
            p.append(f"age_sigma_m_per_s must be a number > 0 (m/s) or null (found from the base), got {a!r}")
        if not (math.isfinite(self.initial_sigma_m) and self.initial_sigma_m > 0):
            p.append(f"initial_sigma_m must be > 0, got {self.initial_sigma_m!r}")
        if not (isinstance(self.min_sats_kinematic, int) and self.min_sats_kinematic >= 4):
            p.append(f"min_sats_kinematic must be an integer >= 4, got {self.min_sats_kinematic!r}")
        if p:
            raise CdgpsError(join_problems("invalid baseline options", p))


class Station(NamedTuple):
    """One receiver: a name, the RINEX header dict and the observation table of
    :func:`~cdgps_cli.io.rinex.read_rinex_obs`; optionally its multi-signal table
    (:func:`~cdgps_cli.io.rinex_signals.read_rinex_signals`: ``time_gps_s``, ``sat``, ``signal``,
    ``phase_cycles``, ``pseudorange_m``, ``lli``, ``wavelength_m``), whose signals are then the
    observations (:mod:`cdgps_cli.estimation.baseline_signals`)."""

    name: str
    header: dict
    obs: pd.DataFrame
    signals: pd.DataFrame | None = None
    #: where the receiver's troposphere is evaluated (ECEF m; None: at its a-priori position), see
    #: :func:`solve_static_baseline`
    troposphere_xyz_m: np.ndarray | None = None


# ----------------------------------------------------------------------------------------------
# preparation: epochs, clocks, single differences, geometry
# ----------------------------------------------------------------------------------------------


def _where(st: Station) -> str:
    return f"{st.name} ({st.header.get('path', '?')})"


def _spans_meet(master: Station, rover: Station, max_age_s: float) -> bool:
    """Whether the two receivers' records meet in time (within ``max_age_s``): a pair that does not is refused for
    having no common epoch (the preparation's words), whatever its length."""
    return spans_meet(*(time_span(st.obs["time_gps_s"].to_numpy(dtype=np.float64)) for st in (master, rover)),
                      max_age_s)


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
    group: np.ndarray | None = None     # (N,) signal group of each row (None: GPS L1 only, one group)
    group_names: tuple = ("G:L1",)      # signal of each group
    lam_m: float | np.ndarray = GPS_L1_WAVELENGTH_M    # wavelength, m: one, or (N,) per row
    age_var_m2: np.ndarray | None = None    # (N,) SD variance added by the base epoch's age, m² (None: none)


def _group_masks(d: _Data) -> list:
    """Rows of each signal group (``[None]``: one group, all rows).  DDs are formed within a group,
    each with its own reference satellite; groups share no DD (inter-system and inter-frequency
    receiver biases cancel)."""
    group = getattr(d, "group", None)
    if group is None:
        return [None]
    return [group == k for k in range(len(d.group_names))]


def _lam(d: _Data):
    """Wavelength of the rows, m: GPS L1's, or (N,) per row (signal groups)."""
    return getattr(d, "lam_m", GPS_L1_WAVELENGTH_M)


def _block_of_row(d: _Data) -> tuple[np.ndarray, int]:
    """(epoch, group) block of each row (rows are sorted by epoch, group, satellite) and their number."""
    n_ep = d.t_label.size
    if getattr(d, "group", None) is None:
        return d.epoch, n_ep
    n_g = len(d.group_names)
    return d.epoch * n_g + d.group, n_ep * n_g


class _Epochs(NamedTuple):
    """The pair's epochs: the rover's, each with its base epoch (measurement/epoch_pairing)."""

    aligned: dict              # receiver name → its observations (grid_gps_s, tag_gps_s, row)
    align_info: dict           # receiver name → alignment summary
    grid: dict                 # receiver name → (its distinct epoch times, its epoch of each common epoch)
    t_label: np.ndarray        # (n_ep,) epoch times (the rover's grid times), GPS s
    interval_s: float
    n_tags: dict               # receiver name → number of distinct time tags
    pairing: dict              # pair_epochs summary: rover epochs used, bridged, dropped with reasons


def _align(st: Station, opt: BaselineOptions, warnings: list, step_s: float | None = None):
    """One receiver's observations on the grid of GPS times (warnings for what is not used)."""
    try:
        aligned, a = align_receiver(st.obs, tol_s=opt.sync_tol_s, mode=opt.epoch_alignment, what=_where(st), step_s=step_s)
    except ValueError as exc:
        raise CdgpsError(str(exc)) from None
    lost = a["dropped_off_grid"] + a["dropped_duplicate"]
    if lost:
        warnings.append(f"{st.name}: {lost} of {a['epochs']} epochs not used: more than {a['tolerance_ms']:g} ms from "
                        f"the {a['grid_s']:.6g} s grid of GPS times ({a['dropped_off_grid']}) or a second epoch on "
                        f"one grid time ({a['dropped_duplicate']})")
    if a["rows_dropped_no_rate"]:
        warnings.append(f"{st.name}: {a['rows_dropped_no_rate']} off-grid observations without a carrier-phase rate "
                        f"(lock segments under 3 epochs) could not be moved to the grid and are not used")
    return aligned, a


def _as_recorded(st: Station) -> tuple[pd.DataFrame, dict]:
    """A base receiver's epochs as recorded ("geometry" alignment: no grid, no epoch dropped)."""
    t = st.obs["time_gps_s"].to_numpy(dtype=np.float64)
    out = st.obs.assign(grid_gps_s=t, tag_gps_s=t, row=np.arange(len(st.obs)))
    n = int(np.unique(t).size)
    return out, {"epochs": n, "on_grid": None, "off_grid_kept": None, "corrected": 0, "dropped_off_grid": 0,
                 "dropped_duplicate": 0, "rows_dropped_no_rate": 0, "max_offset_ms": None, "grid_s": None,
                 "tolerance_ms": None, "mode": "as recorded (base epochs paired by time)"}


def _common_epochs(master: Station, rover: Station, opt: BaselineOptions, warnings: list) -> _Epochs:
    """The rover's epochs, each paired with the nearest base (master) epoch within ``max_age_s``
    (:func:`~cdgps_cli.measurement.epoch_pairing.pair_epochs`: base gaps and lower base rates bridged,
    millisecond tag offsets simultaneous); every rover epoch not used is counted with its reason."""
    for st in (master, rover):
        o = st.obs
        if len(o) == 0 or not np.isfinite(o["phase_l1_cycles"].to_numpy(dtype=float)).any():
            raise CdgpsError(f"{_where(st)}: no GPS L1 carrier-phase observations (in a run whose [gnss] signals leave "
                             f"out G:L1: none of its first signal, which fixes the epochs); a carrier-phase baseline needs "
                             f"that phase at both receivers")
    tm = np.unique(master.obs["time_gps_s"].to_numpy())
    tr = np.unique(rover.obs["time_gps_s"].to_numpy())
    interval = nominal_interval_s(tr)
    aligned, align_info = {}, {}
    aligned[rover.name], align_info[rover.name] = _align(rover, opt, warnings)
    if opt.epoch_alignment == "geometry":          # the base as recorded: its geometry is modelled at its own instants
        aligned[master.name], align_info[master.name] = _as_recorded(master)
    else:                                          # moved to the rover's grid (its own grid may be guessed from gaps)
        aligned[master.name], align_info[master.name] = _align(master, opt, warnings, step_s=align_info[rover.name]["grid_s"])
    gm = np.unique(aligned[master.name]["grid_gps_s"].to_numpy())
    gr, first = np.unique(aligned[rover.name]["grid_gps_s"].to_numpy(), return_index=True)
    # the instant each rover epoch was measured: its tag ("geometry": observations as recorded, as
    # ingest and info pair them), or its grid time ("doppler": observations moved there)
    tr_meas = aligned[rover.name]["tag_gps_s"].to_numpy()[first] if opt.epoch_alignment == "geometry" else gr
    pairs = pair_epochs(tr_meas, gm, sync_tol_s=opt.sync_tol_s, max_age_s=opt.max_age_s)
    ps = pairs.summary
    if ps["used"] == 0:
        raise CdgpsError(f"no common epochs: master {_where(master)} has {tm.size} epochs ({_span(tm)}), rover "
                         f"{_where(rover)} has {tr.size} ({_span(tr)}); no rover epoch has a master epoch within "
                         f"{opt.max_age_s:g} s (gnss.max_age_s)")
    if ps["dropped"]:
        warnings.append(f"{rover.name}: {sum(ps['dropped'].values())} of {ps['rover_epochs']} epochs not used: "
                        + "; ".join(f"{n} {why}" for why, n in ps["dropped"].items())
                        + f" (master {master.name}; gnss.max_age_s = {opt.max_age_s:g} s)")
    im, ir = pairs.base_index, pairs.rover_index
    for st, n_m in ((master, ps["base_epochs_used"]), (rover, ir.size)):
        align_info[st.name]["matched"] = int(n_m)
    q = 10.0 ** math.floor(math.log10(interval)) / 10.0 if math.isfinite(interval) and interval > 0 else 1e-3
    t_label = np.round(gr[ir] / q) * q
    return _Epochs(aligned, align_info, {master.name: (gm, im), rover.name: (gr, ir)}, t_label, interval,
                   {master.name: tm.size, rover.name: tr.size}, ps)


def _receiver_rows(st: Station, ce: _Epochs, nav: pd.DataFrame, pos, opt: BaselineOptions, warnings: list):
    """One receiver's rows in the common epochs with an ephemeris, their epoch index and true
    reception times; its clock per epoch, s; its time tag per epoch (NaN: none), GPS s.  A base
    epoch serving several rover epochs gives its rows to each, its slip flags to the first only."""
    t_all, idx = ce.grid[st.name]
    t_label = ce.t_label
    n_ep = t_label.size
    o = ce.aligned[st.name]
    take, k, first = rows_for_pairs(np.searchsorted(t_all, o["grid_gps_s"].to_numpy()), idx)
    tag = np.full(n_ep, np.nan)
    tag[k] = o["tag_gps_s"].to_numpy()[take]
    # slip flags of rows that are not differenced move to the satellite's next differenced row
    used = np.zeros(len(st.obs), dtype=bool)
    used[o["row"].to_numpy()[take]] = True
    lli_all = carry_slips(st.obs["time_gps_s"].to_numpy(dtype=np.float64), st.obs["sat"].to_numpy(),
                          st.obs["lli_l1"].to_numpy(dtype=np.int64), used)
    lli = lli_all[o["row"].to_numpy()[take]]
    o = o.iloc[take]                      # a new frame already (copy-on-write): no second copy
    o["lli_l1"] = np.where(first, lli, lli & ~1)
    o["ep"] = k
    cov = _covered(nav, o["sat"].to_numpy(), t_label[o["ep"].to_numpy()], o["time_gps_s"].to_numpy())
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
    clk, measured = _receiver_clock(st, o, tag, t_label, nav, pos, opt)
    o["t_true"] = o["time_gps_s"].to_numpy() - clk[ep]
    return o, clk, tag, measured


#: a row's ephemeris must cover its time tag this far on either side: the receiver clock puts its reception time
#: there (milliseconds; a tag 5 ms before a window opens on a real F9P's edited log stopped init)
COVERAGE_MARGIN_S = 1.0


def _covered(nav: pd.DataFrame, sats, label_s, tag_s) -> np.ndarray:
    """Which rows have a healthy broadcast ephemeris at their epoch's label ``label_s`` and within
    :data:`COVERAGE_MARGIN_S` of their time tag ``tag_s`` (GPS s), where the receiver clock and the satellites'
    geometry are evaluated."""
    tag_s = np.asarray(tag_s, dtype=np.float64)
    return ephemeris_coverage_all(nav, sats, (label_s, tag_s - COVERAGE_MARGIN_S, tag_s + COVERAGE_MARGIN_S))


def _receiver_clock(st: Station, o: pd.DataFrame, tag: np.ndarray, t_label: np.ndarray, nav: pd.DataFrame, pos,
                    opt: BaselineOptions) -> tuple:
    """The receiver's clock at each common epoch, s, and whether it was measured there (a code with an ephemeris
    above the horizon; else interpolated): from its GPS L1 rows ``o`` (each epoch's own, as before); with a
    signal table, from :func:`_clock_rows` estimated once per time tag and given to every epoch of that tag (a
    master epoch bridged to several rover epochs is one measurement instant); epochs without a tag take it
    interpolated (no row of this receiver uses them)."""
    n_ep = t_label.size
    rows = _clock_rows(st, tag, t_label, nav)
    if rows is None:
        return estimate_receiver_clock(o["ep"].to_numpy(), o["sat"].to_numpy(), o["time_gps_s"].to_numpy(),
                                       o["pseudorange_l1_m"].to_numpy(), nav, pos, n_epochs=n_ep,
                                       troposphere=opt.troposphere, what=_where(st), return_measured=True)
    k_tag, n_tag, c_sat, c_t, c_pr, tag_of_epoch = rows
    c, good = estimate_receiver_clock(k_tag, c_sat, c_t, c_pr, nav, pos, n_epochs=n_tag,
                                      troposphere=opt.troposphere, what=_where(st), return_measured=True)
    have = tag_of_epoch >= 0
    clk = np.zeros(n_ep)
    clk[have] = c[tag_of_epoch[have]]
    if not have.all():
        clk[~have] = np.interp(np.flatnonzero(~have), np.flatnonzero(have), clk[have])
    measured = np.zeros(n_ep, dtype=bool)
    measured[have] = good[tag_of_epoch[have]]
    return clk, measured


#: systems whose pseudoranges give a receiver's clock with the anchor's (CDMA: one range model for all satellites)
_CLOCK_SYSTEMS = ("G", "E", "C", "J")


def _clock_rows(st: Station, tag: np.ndarray, t_label: np.ndarray, nav: pd.DataFrame):
    """The rows a receiver's clock is estimated from when it has a signal table: one pseudorange per satellite
    and time tag of every GPS, Galileo, BeiDou and QZSS signal recorded at the common epochs' tags ``tag`` (GPS s; NaN:
    no epoch) and covered by ``nav``, as (tag index, number of tags, satellites, time tags, pseudoranges m, each
    epoch's tag index (−1: none)); None without a signal table, or when no row qualifies (the GPS L1 rows serve).

    Every system's codes, as :func:`~cdgps_cli.estimation.rtk_multi.receiver_geometry` takes them: where the anchor
    has one or two satellites with an ephemeris the clock from them alone can be far off or missing and
    interpolated (a real F9P pair whose GPS ephemerides begin 34 min into the record: 88 µs against its Galileo
    clock, which put the Galileo rows' satellites centimetres off in the double differences); the systems' biases
    (tens of ns) move a satellite by micrometres."""
    if st.signals is None:
        return None
    sig = st.signals
    pr = sig["pseudorange_m"].to_numpy(dtype=np.float64)
    keep = np.flatnonzero(sig["sat"].astype(str).str[0].isin(_CLOCK_SYSTEMS).to_numpy() & np.isfinite(pr))
    t = sig["time_gps_s"].to_numpy(dtype=np.float64)[keep]
    have = np.isfinite(tag)
    if not have.any():
        return None
    tt, inv = np.unique(tag[have], return_inverse=True)        # one clock per measurement instant
    tag_of_epoch = np.full(tag.size, -1, dtype=np.int64)
    tag_of_epoch[have] = inv
    i, at = nearest_tags(tt, t)                       # a row belongs to the tag that is its own
    rows = pd.DataFrame({"k": i[at], "sat": sig["sat"].to_numpy()[keep][at], "t": t[at], "pr": pr[keep][at]})
    rows = rows.drop_duplicates(["k", "sat"], keep="first")
    # the ephemeris serving each tag: that of its first epoch's label (the bridged epochs' labels are within max age)
    first = np.unique(inv, return_index=True)[1]      # each tag's first epoch (tags 0 … n − 1 in order)
    label_of_tag = t_label[np.flatnonzero(have)[first]]
    rows = rows[_covered(nav, rows["sat"].to_numpy(), label_of_tag[rows["k"].to_numpy()], rows["t"].to_numpy())]
    if rows.empty:
        return None
    return (rows["k"].to_numpy(), tt.size, rows["sat"].to_numpy(), rows["t"].to_numpy(), rows["pr"].to_numpy(),
            tag_of_epoch)


def _both_receivers(master_fn, rover_fn, warnings: list) -> tuple:
    """``(master_fn(w), rover_fn(w))``, the master's computed beside the rover's on a second core
    (:func:`cdgps_cli.core.beside.both`: the same values bit for bit); each appends its warnings to its
    own list, joined to ``warnings`` master first, and an error is the master's first, as in turn."""
    w_m, w_r = [], []
    out = beside.both(lambda: (master_fn(w_m), w_m), lambda: rover_fn(w_r))
    warnings.extend(out[0][1])
    warnings.extend(w_r)
    return out[0][0], out[1]


def _prepare(master: Station, rover: Station, nav: pd.DataFrame, opt: BaselineOptions,
             master_xyz, rover_xyz, warnings: list) -> _Data:
    """The pair's single differences in the common epochs above the mask, with geometry and clocks."""
    mask = math.radians(opt.mask_deg)
    ce = _common_epochs(master, rover, opt, warnings)
    t_label, n_ep = ce.t_label, ce.t_label.size
    (om, clk_m, tag_m, meas_m), (orv, clk_r, tag_r, meas_r) = _both_receivers(
        lambda w: _receiver_rows(master, ce, nav, master_xyz, opt, w),
        lambda w: _receiver_rows(rover, ce, nav, rover_xyz, opt, w), warnings)
    om = om[np.isfinite(om["phase_l1_cycles"].to_numpy())]
    orv = orv[np.isfinite(orv["phase_l1_cycles"].to_numpy())]
    j = pd.merge(orv, om, on=["ep", "sat"], suffixes=("_r", "_b"), how="inner", sort=True)
    del om, orv                     # (each receiver's rows: in ``j`` now, not held beside its geometry and SD rows)
    if len(j) == 0:
        raise CdgpsError(f"no common satellites: no satellite has L1 phase at both {_where(master)} and {_where(rover)} "
                         f"in any of the {n_ep} common epochs")
    sat_r = j["sat"].to_numpy()
    ep = j["ep"].to_numpy()
    t_ep = t_label[ep]
    gb, gr = beside.both(
        lambda: reception_geometry(nav, sat_r, t_ep, j["t_true_b"].to_numpy(), master_xyz, troposphere=opt.troposphere),
        lambda: reception_geometry(nav, sat_r, t_ep, j["t_true_r"].to_numpy(), rover_xyz, troposphere=opt.troposphere))
    keep = (gb["el_rad"] >= mask) & (gr["el_rad"] >= mask)
    below = pd.Series(sat_r[~keep]).value_counts()
    # epochs with fewer than two satellites form no double difference: their rows go, and a slip flagged on a row
    # that goes (there, or below the mask) moves to its satellite's next row that stays (the engine's arc starts there)
    cnt = np.bincount(ep[keep], minlength=n_ep)
    keep &= cnt[ep] >= 2
    if not keep.all():
        j = j.assign(**{c: carry_slips(ep.astype(np.float64), sat_r, j[c].to_numpy(dtype=np.int64), keep)
                        for c in ("lli_l1_r", "lli_l1_b")})
    if keep.sum() < 2:
        raise CdgpsError(f"no double differences: fewer than two satellites of {_where(master)} and {_where(rover)} "
                         f"in common above the {opt.mask_deg:g}° mask at every common epoch ({n_ep} epochs, {_span(t_label)})")
    sel = np.flatnonzero(keep)
    n_no_dd = n_ep - int(np.unique(ep[sel]).size)
    if n_no_dd:
        warnings.append(f"{rover.name}: {n_no_dd} of {n_ep} paired epochs not used: {NO_DD}")
    age_ep = tag_r - tag_m                                   # rover − base time of each epoch, s
    simultaneous = np.abs(age_ep) <= opt.sync_tol_s
    age_var_ep = age_variance_m2(np.nan_to_num(age_ep), opt.sync_tol_s, _age_sigma(opt))
    info = {
        "n_epochs_master": int(ce.n_tags[master.name]),
        "n_epochs_rover": int(ce.n_tags[rover.name]),
        "n_epochs_common": int(n_ep),
        "n_epochs_used": int(np.unique(ep[sel]).size),
        "interval_s": ce.interval_s,
        "first_epoch": gps_time_str(float(t_label[0])),
        "last_epoch": gps_time_str(float(t_label[-1])),
        "max_tag_difference_ms": float(np.nanmax(np.where(simultaneous, np.abs(tag_m - tag_r), 0.0)) * 1e3),
        # the paired epochs that hold no double difference (no phase at both, fewer than two satellites above the
        # mask) are not used either: counted with their reason, as rtk counts them
        "epoch_pairing": without_dd(ce.pairing, n_no_dd),
        "epoch_alignment": ce.align_info,
        "rx_clock_ms": {
            master.name: [float(np.min(clk_m) * 1e3), float(np.max(clk_m) * 1e3)],
            rover.name: [float(np.min(clk_r) * 1e3), float(np.max(clk_r) * 1e3)],
        },
        "below_mask_sd_rows": {str(k): int(v) for k, v in below.items()},
    }
    if master.signals is not None and rover.signals is not None:
        d = _signal_data(master, rover, _clocked_tags((tag_m, tag_r), (meas_m, meas_r), (master, rover), warnings),
                         (clk_m, clk_r), j, t_label, nav, (master_xyz, rover_xyz), opt, ce.interval_s, info, warnings)
    else:
        d = _sd_data(j, sel, gb, gr, t_label, ce.interval_s, info)
    d = _rover_troposphere_moved(d, rover, rover_xyz, opt)
    n_interp = 0
    if np.any(age_var_ep > 0):
        d, n_interp = _interpolated_base(d, master, rover, ce.grid[master.name], tag_r, nav, master_xyz, opt)
    d.info["epoch_pairing"] = dict(d.info["epoch_pairing"], interpolated=n_interp)
    return d


#: DD phase residuals of a static solution beyond this rms (m) are not noise, multipath or an unmodelled ionosphere
#: (millimetres to decimetres) but a rover that moves: its static solution is nowhere, and its "fixed" integers
#: fit nothing (a simulated 5-min walk: 9.9 m rms, "fixed" 670 m away with σ 0.4 mm; the real car of
#: real-pairs/geonet-car: 26 m; the 20181009 u-blox walk: 5.6 m; the real static pairs: 2–10 mm)
STATIC_FIT_LIMIT_M = 1.0


def _check_static_fit(opt: BaselineOptions, residuals: dict, rover: Station) -> None:
    """CdgpsError when a static solution's DD phase residuals (rms, m) exceed :data:`STATIC_FIT_LIMIT_M`: the rover
    moves (the excess on every satellite) or the phase jumps where the receiver flagged no slip (on a few), and
    its static solution (and any integers fixed on it) would be reported as if neither."""
    rms = residuals.get("dd_phase_rms_m")
    if opt.motion != "static" or rms is None or not rms > STATIC_FIT_LIMIT_M:
        return
    per = sorted((residuals.get("per_satellite_rms_m") or {}).items(), key=lambda kv: -kv[1])
    worst = ", ".join(f"{s} {v:.3g} m" for s, v in per[:4])
    raise CdgpsError(f"{_where(rover)}: the double-difference phase residuals of its static solution have an rms of "
                     f"{rms:.3g} m, more than {STATIC_FIT_LIMIT_M:g} m (a static antenna's are millimetres to "
                     f"decimetres; largest per satellite: {worst}): the rover moves (large on every satellite) or its "
                     f"phase jumps where the receiver flagged no cycle slip (large on a few), and no static position "
                     f"fits it.  For a moving antenna: [gnss.displacement] model = \"random_walk\" (or "
                     f"\"constant_velocity\") in a run's config, or 'cdgps rtk'")


def _rover_troposphere_moved(d: _Data, rover: Station, rover_xyz, opt: BaselineOptions) -> _Data:
    """``d`` with the rover's hydrostatic delay evaluated at ``rover.troposphere_xyz_m`` instead of its a-priori
    position ``rover_xyz`` (the same elevations: a kilometre moves them by less than 0.01°)."""
    if rover.troposphere_xyz_m is None or not opt.troposphere:
        return d
    t = d.t_label[d.epoch]
    at = [ecef_to_geodetic(np.asarray(x, dtype=np.float64)) for x in (rover.troposphere_xyz_m, rover_xyz)]
    moved = [tropo_hydrostatic_m(d.el_rover, lat, h, t) for lat, _, h in at]
    return d._replace(rover_clk_trop_m=d.rover_clk_trop_m + (moved[0] - moved[1]))


def _interpolated_base(d: _Data, master: Station, rover: Station, base_grid, rover_tag_s, nav, master_xyz,
                       opt: BaselineOptions) -> tuple[_Data, int]:
    """``d`` with the base's phase and range of each bridged rover epoch interpolated to the rover's time between
    the base epochs on both sides, and every row's age variance (``age_var_m2``), as the static engine's and rtk's
    rows have them: :func:`~cdgps_cli.measurement.base_interpolation.interpolate_base` on the base rows of
    :func:`_base_rows_around` (the engine's own).  ``base_grid``: the base's distinct epoch times and its epoch of
    each common epoch; ``rover_tag_s`` (n_ep,): the rover's time of each.  Returns it and the number of rover
    epochs interpolated (in at least one signal group)."""
    from cdgps_cli.measurement.base_interpolation import BASE_ROW_COLUMNS as cols, interpolate_base
    t_base = base_grid[0][base_grid[1]]                          # (n_ep,) each common epoch's base time
    age_ep = rover_tag_s - t_base
    bridged = np.abs(age_ep) > opt.sync_tol_s
    b, tb = _base_rows_around(master, rover, nav, master_xyz, t_base, bridged, opt)
    b0 = np.clip(np.searchsorted(tb, t_base), 0, max(tb.size - 1, 0))
    b0 = np.where((tb.size > 0) & (tb[b0] == t_base), b0, -1)
    sig = _satellite_signals(d)
    sat = np.array([n.split(":")[0] for n in d.sat_names], dtype=object)
    signal_of = np.array([v["signal"] for v in sig] if sig else ["G:L1"] * len(sat), dtype=object)
    cols = list(cols) + [c for c in ("eph_row",) if c in b.columns]          # the same ephemeris at t₀ and t₁
    at0 = b[cols].rename(columns={c: c + "_b" for c in cols[3:]})
    m = pd.DataFrame({"_ep": d.epoch, "_bep": b0[d.epoch], "sat": sat[d.sat], "signal": signal_of[d.sat],
                      "wavelength_m": np.broadcast_to(np.asarray(_lam(d), dtype=np.float64), d.epoch.shape)})
    m = m.merge(at0, on=["_bep", "sat", "signal"], how="left", sort=False)
    age = age_ep[d.epoch]
    if len(m) != d.epoch.size or tb.size == 0:          # a repeated base row: the nearest epoch's, as the engine's
        return d._replace(age_var_m2=age_variance_m2(age, opt.sync_tol_s, _age_sigma(opt))), 0
    ph0, rg0 = m["phase_cycles_b"].to_numpy(dtype=float), m["pseudorange_m_b"].to_numpy(dtype=float)
    ph, rg, age_i, done = interpolate_base(m.assign(_bep=np.maximum(m["_bep"].to_numpy(), 0)), b, tb,
                                           rover_tag_s[d.epoch], base_xyz_m=master_xyz, sync_tol_s=opt.sync_tol_s,
                                           max_age_s=opt.max_age_s, troposphere=opt.troposphere)
    age = np.where(done, age_i, age)
    d = d._replace(y_phase_m=d.y_phase_m - np.where(done, m["wavelength_m"].to_numpy() * (ph - ph0), 0.0),
                   y_code_m=d.y_code_m - np.where(done, rg - rg0, 0.0),
                   age_var_m2=age_variance_m2(age, opt.sync_tol_s, _age_sigma(opt)))
    return d, int(np.unique(d.epoch[done]).size)


def _with_age_noise(master: Station, rover: Station, nav, opt: BaselineOptions, xm) -> tuple:
    """``opt`` with its age σ resolved, and the record of it (:func:`~cdgps_cli.measurement.base_interpolation.
    base_age_noise`'s): as given; else ("auto") the base's own drift where it exceeds RTKLIB's 1.5 mm/s, when some
    rover epoch is bridged (the engine's signal tables paired as the engine pairs them; the base's geometry built for
    it alone).  Bad input is left to the stages after, whose messages name it: RTKLIB's σ then."""
    from dataclasses import replace
    from cdgps_cli.estimation.rtk_multi import receiver_geometry
    from cdgps_cli.measurement.base_interpolation import base_age_noise
    if opt.age_sigma_m_per_s is not None:
        return opt, {"mode": "model", "sigma_m_per_s": float(opt.age_sigma_m_per_s), "estimate_m_per_s": None}
    floor = EPOCH_PAIRING_DEFAULTS["age_sigma_m_per_s"]
    noise = {"mode": "auto", "sigma_m_per_s": floor, "estimate_m_per_s": None}
    try:
        tb, tr = (_engine_table(master, rover, st) for st in (master, rover))
        pairs = pair_epochs(np.unique(tr["time_gps_s"].to_numpy()), np.unique(tb["time_gps_s"].to_numpy()),
                            sync_tol_s=opt.sync_tol_s, max_age_s=opt.max_age_s)
        if pairs.summary.get("bridged"):
            noise = base_age_noise(receiver_geometry(tb, nav, xm), pairs, xm,
                                   {"age_noise": "auto", "age_sigma_m_per_s": floor, "troposphere": opt.troposphere,
                                    "max_age_s": opt.max_age_s, "mask_deg": opt.mask_deg})
    except CdgpsError:
        pass
    return replace(opt, age_sigma_m_per_s=noise["sigma_m_per_s"]), noise


def _age_sigma(opt: BaselineOptions) -> float:
    """The σ per second of base age the options weigh with, m/s (:attr:`BaselineOptions.age_sigma_m_per_s`; RTKLIB's
    1.5 mm/s while it is not resolved)."""
    return EPOCH_PAIRING_DEFAULTS["age_sigma_m_per_s"] if opt.age_sigma_m_per_s is None else float(opt.age_sigma_m_per_s)


def _base_rows_around(master: Station, rover: Station, nav, master_xyz, t_base, bridged, opt: BaselineOptions):
    """The base rows the static engine pairs (its signal table, :func:`_run_engine`'s, without the rows
    :func:`~cdgps_cli.estimation.rtk_multi.receiver_geometry` drops, slip flags carried as
    :func:`~cdgps_cli.measurement.base_interpolation.base_rows` carries them for the base epochs ``t_base``
    used) with their geometry, at the base epochs on both sides of each ``bridged`` common epoch only; and the
    distinct epoch times of all of them (GPS s)."""
    from cdgps_cli.estimation.rtk_multi import geometry_rows, receiver_geometry
    from cdgps_cli.measurement.base_interpolation import base_rows
    tab = geometry_rows(_engine_table(master, rover, master), nav)
    tb = np.unique(tab["time_gps_s"].to_numpy(dtype=np.float64))
    if tb.size == 0:
        return tab.assign(_bep=np.zeros(0, np.int64)), tb
    used = np.searchsorted(tb, t_base)
    ok = (used < tb.size) & (tb[np.minimum(used, tb.size - 1)] == t_base)
    b = base_rows(tab, tb, np.bincount(used[ok], minlength=tb.size))
    near = np.searchsorted(tb, t_base[bridged])
    need = np.zeros(tb.size + 1, dtype=bool)
    need[np.clip(np.r_[near - 1, near, near + 1], 0, tb.size)] = True
    b = b[need[b["_bep"].to_numpy()]]
    return receiver_geometry(b, nav, master_xyz), tb


def _clocked_tags(tags: tuple, measured: tuple, stations: tuple, warnings: list) -> tuple:
    """Each receiver's time tags (n_ep,) where its clock was measured, NaN elsewhere: the signal rows of an epoch
    whose clock is only interpolated (no code with an ephemeris there: e.g. GPS + GLONASS while the GPS
    ephemerides have not begun; a drifting or jumping clock would put the rows' satellites metres off) are not
    used, and a warning counts them."""
    out = []
    for tag, ok, st in zip(tags, measured, stations):
        lost = np.isfinite(tag) & ~ok
        if lost.any():
            warnings.append(f"{st.name}: {int(lost.sum())} epoch(s) without a code from a satellite with an ephemeris "
                            f"(GPS, Galileo, BeiDou, QZSS) to find its clock: their signal rows are not used")
        out.append(np.where(ok, tag, np.nan))
    return tuple(out)


def _signal_data(master: Station, rover: Station, tags, clocks, j, t_label, nav, xyz, opt: BaselineOptions,
                 interval: float, info: dict, warnings: list) -> _Data:
    """The signal groups' SD rows (:func:`~cdgps_cli.estimation.baseline_signals.signal_sd_fields`) at the common
    epochs' time tags (``tags``: master's, rover's) and clocks; receiver resets from the L1 epoch flags."""
    from cdgps_cli.estimation.baseline_signals import signal_sd_fields  # noqa: PLC0415

    if opt.epoch_alignment != "geometry":
        raise CdgpsError(f"epoch_alignment {opt.epoch_alignment!r} is not available with [gnss] signals: the signal "
                         f"rows are modelled at their own reception instants (use epoch_alignment = \"geometry\")")
    f = signal_sd_fields(master.signals, rover.signals, tags[0], tags[1], clocks[0], clocks[1], t_label, nav,
                         xyz[0], xyz[1], mask_rad=math.radians(opt.mask_deg), troposphere=opt.troposphere,
                         names=(_where(master), _where(rover)), warnings=warnings)
    reset = np.unique(j["ep"].to_numpy()[(j["epoch_flag_r"].to_numpy() == 1) | (j["epoch_flag_b"].to_numpy() == 1)])
    info = dict(info, below_mask_sd_rows=None, **f.pop("info"))
    return _Data(t_label=t_label, reset_epochs=reset.astype(np.int64), interval_s=interval, info=info, **f)


def _sd_data(j: pd.DataFrame, sel, gb: dict, gr: dict, t_label, interval: float, info: dict) -> _Data:
    """The selected rows ``sel`` of the merged rover/master table ``j`` as the solver's :class:`_Data`."""
    sat_r = j["sat"].to_numpy()
    ep_sel = j["ep"].to_numpy()[sel]
    names = sorted(set(sat_r[sel].tolist()))
    sat_idx = {s: i for i, s in enumerate(names)}
    lli_r = j["lli_l1_r"].to_numpy()[sel]
    lli_b = j["lli_l1_b"].to_numpy()[sel]
    reset = set(np.unique(j["ep"].to_numpy()[(j["epoch_flag_r"].to_numpy() == 1) | (j["epoch_flag_b"].to_numpy() == 1)]).tolist())
    return _Data(
        ptr=epoch_pointers(ep_sel, t_label.size),
        epoch=ep_sel,
        sat=np.array([sat_idx[s] for s in sat_r[sel]], dtype=np.int64),
        sat_names=names,
        t_label=t_label,
        y_phase_m=GPS_L1_WAVELENGTH_M * (j["phase_l1_cycles_r"].to_numpy()[sel] - j["phase_l1_cycles_b"].to_numpy()[sel]),
        y_code_m=j["pseudorange_l1_m_r"].to_numpy()[sel] - j["pseudorange_l1_m_b"].to_numpy()[sel],
        base_model_m=(gb["range_m"] - SPEED_OF_LIGHT_M_S * gb["sat_clock_s"] + gb["trop_m"])[sel],
        rover_sat_xyz=gr["sat_xyz_m"][sel],
        rover_clk_trop_m=(-SPEED_OF_LIGHT_M_S * gr["sat_clock_s"] + gr["trop_m"])[sel],
        el_rover=gr["el_rad"][sel],
        el_base=gb["el_rad"][sel],
        az_rover=gr["az_rad"][sel],
        slip=((lli_r & 1) | (lli_b & 1)).astype(bool),
        half=((lli_r & 2) | (lli_b & 2)).astype(bool),
        slip_rover=(lli_r & 1).astype(bool),
        slip_base=(lli_b & 1).astype(bool),
        reset_epochs=np.array(sorted(reset), dtype=np.int64),
        interval_s=interval,
        info=info,
    )


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


def _accumulate(blocks, g, r, col, n_par: int, lam):
    """Normal equations Σ_k [G λE]ᵀ P_k [G λE] and right side from per-epoch DD weight blocks.

    ``col[i]`` is the parameter index (≥ 3) of row i's ambiguity, or −1 (known / datum); ``lam`` the
    wavelength (m), one for all rows or (N,) per row (signal groups)."""
    per_row = np.ndim(lam) > 0
    nmat = np.zeros((n_par, n_par))
    rhs = np.zeros(n_par)
    size = n_par + 1
    for rows, p in blocks:
        gk = g[rows]                       # (K, n, 3)
        rk = r[rows]                       # (K, n)
        pg = p @ gk                        # batched matmul (BLAS), not einsum's loops: a day at 1 Hz 1.1 -> 0.2 s
        pr = (p @ rk[:, :, None])[:, :, 0]
        g2 = gk.reshape(-1, 3)
        nmat[:3, :3] += g2.T @ pg.reshape(-1, 3)
        rhs[:3] += g2.T @ pr.ravel()
        if col is None:
            continue
        c = col[rows]
        cc = np.where(c >= 0, c, n_par)    # dummy slot for rows without an unknown ambiguity
        lin = (cc[:, :, None] * size + cc[:, None, :]).ravel()
        lk = lam[rows] if per_row else lam
        lpl = (lk[:, :, None] * p * lk[:, None, :]) if per_row else lam * lam * p
        nmat += (np.bincount(lin, weights=lpl.ravel(), minlength=size * size)
                 .reshape(size, size)[:n_par, :n_par])
        flat_c = cc.ravel()
        for q in range(3):  # cross terms λ·(P G)[i, q] at (ambiguity of row i, q); c >= 3, so x block untouched
            v = np.bincount(flat_c, weights=(lk * pg[:, :, q]).ravel(), minlength=size)[:n_par]
            nmat[:, q] += v
            nmat[q, :] += v
        rhs += np.bincount(flat_c, weights=(lk * pr).ravel(), minlength=size)[:n_par]
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
        s += float(np.sum(rk * (p @ rk[:, :, None])[:, :, 0]))
        m += rows.shape[0] * (rows.shape[1] - 1)
    return s, m


def _float_random_walk(d: _Data, sg: "_Segments", w: "_Weights", fl: "_Float", opt: BaselineOptions):
    """Float ambiguities (and covariance) for a rover whose position random-walks, by the engine.

    Model per epoch k (phase and code DDs, :class:`~cdgps_cli.measurement.dd_displacement.SatelliteDDDisplacement`
    linearized at the static float solution): ``z_k = D G δx_k + λ D E_k a + ν_k`` with
    ``δx_k = δx_{k−1} + w_k``, ``w_k ~ N(0, diag(σ²)·Δt)``, δx_1 ~ N(0, ``initial_sigma_m``²) and
    constant ambiguity corrections ``a`` (cycles).  The engine's forward filter
    (:func:`~cdgps_cli.estimation.model_filter.filter_numpy`, one update per epoch: the model is
    linear) runs on x = [δx, a] (:class:`~cdgps_cli.model.dynamics_models.WithConstants`) from a
    prior a ~ N(0, σ_a² I); a is constant, so its estimate and covariance at the last epoch are its
    posterior given every epoch, whose information is J + σ_a⁻² I with J the information of the
    exact joint (positions + ambiguities) least-squares problem.  The prior is removed exactly:
    ``Cov(â) = J⁻¹``, ``â = J⁻¹ (J + σ_a⁻² I) â_post``.

    Returns
    -------
    da : ndarray (n_amb,)
        Correction to the ambiguities behind ``fl.r_ph``, cycles.
    q_aa : ndarray (n_amb, n_amb)
        Their covariance, cycles².
    """
    n_amb = sg.n_par - 3
    par = sg.par_of_seg[sg.seg]
    acol = np.where(par >= 0, par - 3, -1)
    obs = _group_observations(d, w, fl.r_ph, acol) + _group_observations(d, w, fl.r_cd, None)
    model = SatelliteDDDisplacement(d.ptr, d.sat, d.sat_names, fl.g, obs, n_ambiguities=n_amb)
    dyn = WithConstants(RandomWalk(3, opt.random_walk_sigma), n_amb)
    P0 = np.diag(np.r_[np.full(3, opt.initial_sigma_m**2), np.full(n_amb, AMBIGUITY_PRIOR_SIGMA_CYCLES**2)])
    fr = filter_numpy(model, dyn, d.t_label, np.zeros(3 + n_amb), P0, max_iterations=1, history=False, form="covariance")
    if not positive_definite(fr["P"]):         # (rounding of a long record's covariance form: static_engine._long_filter)
        fr = filter_numpy(model, dyn, d.t_label, np.zeros(3 + n_amb), P0, max_iterations=1, history=False,
                          form="information")
    post = np.linalg.inv(fr["P"][3:, 3:])
    J = post - np.eye(n_amb) / AMBIGUITY_PRIOR_SIGMA_CYCLES**2
    J = 0.5 * (J + J.T)
    try:
        cf = cho_factor(J, lower=False, check_finite=True)
    except np.linalg.LinAlgError:
        raise CdgpsError("random-walk float solution: the ambiguities are not separable from the rover's motion "
                         "(too few epochs per lock segment for the random-walk rate); lower random_walk sigma") from None
    return cho_solve(cf, post @ fr["x"][3:]), cho_solve(cf, np.eye(n_amb))


class _Segments(NamedTuple):
    """Ambiguity segments of the SD rows and their parametrization (one datum pivot per connected set)."""

    seg: np.ndarray            # (N,) segment of each SD row
    segtab: dict               # per segment: sat, first_epoch, last_epoch, n_rows
    n_seg: int
    pivots: np.ndarray         # datum segments
    comp: np.ndarray           # (n_seg,) connected set of each segment
    is_pivot: np.ndarray       # (n_seg,) bool
    seg_half: np.ndarray       # (n_seg,) bool: a half-cycle flag in the segment
    free: np.ndarray           # segments that are parameters (not pivots)
    par_of_seg: np.ndarray     # (n_seg,) parameter index (≥ 3) of each segment, −1 for pivots
    n_par: int                 # 3 + free.size


class _Weights(NamedTuple):
    """SD variances, reference rows and DD weight blocks of the phase and code rows (the blocks of
    every signal group; ``refs_*`` one reference array per group, ``ref_*`` the first group's)."""

    var_ph: np.ndarray
    ref_ph: np.ndarray
    blocks_ph: list
    code_ok: np.ndarray
    var_code: np.ndarray
    ref_code: np.ndarray
    blocks_code: list
    y_code: np.ndarray         # SD pseudorange, 0 where missing
    refs_ph: list
    refs_code: list


def _group_observations(d: _Data, w: _Weights, r, acol, usable=None) -> list:
    """The engine's DD observations of SD residuals ``r``: one per signal group (own reference,
    own wavelength); ``acol`` the ambiguity column of each row (None: pseudorange, the code
    references)."""
    out = []
    phase = acol is not None
    base_use = usable if phase else w.code_ok
    for k, m in enumerate(_group_masks(d)):
        use = base_use if m is None else (m if base_use is None else base_use & m)
        if not phase:
            out.append(SDObservations(r, w.var_code, w.refs_code[k], usable=use, kind="code"))
            continue
        lam = None if m is None else float(_lam(d)[np.argmax(m)])
        out.append(SDObservations(r, w.var_ph, w.refs_ph[k], usable=use, ambiguity_col=acol, wavelength_m=lam))
    return out


class _Float(NamedTuple):
    x: np.ndarray              # ENU displacement, m
    a_seg: np.ndarray          # SD ambiguities, cycles (pivots 0)
    q: np.ndarray              # covariance of [x, free ambiguities]
    block: dict                # the result's "float" block
    g: np.ndarray              # (N, 3) design at x
    r_ph: np.ndarray           # SD phase residuals at x, m
    r_cd: np.ndarray           # SD code residuals at x, m
    n_dd_code: int


class _Fix(NamedTuple):
    a_float: np.ndarray        # float ambiguities of the free segments, cycles
    q_aa: np.ndarray           # their covariance, cycles²
    fixed_mask: np.ndarray     # (free.size,) bool
    integers: np.ndarray       # (free.size,) int
    ratio: float | None
    ratio_full: float | None
    accepted: bool
    partial: bool
    success_rate: float | None = None   # bootstrapped success rate of the fixed set (of the full set if none)
    glonass_fixed: np.ndarray | None = None   # (n_seg,) GLONASS segments whose DD the engine fixed (glonass_fix)
    glonass_dd: np.ndarray | None = None      # (n_seg,) their DD integers N_i − N_p (own cycles; pivot 0), NaN: none


class _Final(NamedTuple):
    block: dict | None         # the result's "fixed" block (None: nothing fixed)
    x: np.ndarray              # reported ENU displacement, m
    kind: str                  # "fixed", "partially fixed" or "float"
    a_seg: np.ndarray          # SD ambiguities of the reported solution, cycles
    known_seg: np.ndarray      # (n_seg,) bool: ambiguity known (pivot or fixed)
    q3: np.ndarray             # (3, 3) covariance of x
    g: np.ndarray
    r_ph: np.ndarray
    a_sigma: np.ndarray | None = None   # (n_seg,) 1σ of a_seg, cycles (0: known)
    pivot_arc: np.ndarray | None = None  # (n_seg,) a glonass_fix solution's GLONASS pivots' own arc values x_p, cycles


def _a_priori_positions(master: Station, rover: Station, nav, master_xyz, rover_xyz, warnings: list):
    """Master position (given or header) and the rover's a priori position with its source."""
    xm = (antenna_reference_point_m(master.header, _where(master)) if master_xyz is None     # marker + DELTA H/E/N
          else np.asarray(master_xyz, dtype=np.float64))
    if xm is None:
        raise CdgpsError(f"{_where(master)}: the RINEX header has no usable APPROX POSITION XYZ; the master (reference) "
                         f"receiver must be at a known position: give its surveyed one (baseline --master-xyz X Y Z, or "
                         f"position_ecef_m in a job file's [gnss.antennas.<name>])")
    if master_xyz is None:
        _check_master_header(master, nav, xm)
    xr0 = header_position_m(rover.header) if rover_xyz is None else np.asarray(rover_xyz, dtype=np.float64)
    warnings += rover_delta_note(rover.header, _where(rover))
    rover_pos_source = ("RINEX header APPROX POSITION XYZ" if rover_xyz is None else
                        rover.header.get("given_position_source") or "given")   # (the run's words, when it gave it)
    if xr0 is None:
        xr0 = _station_spp(rover, nav, xm)
        rover_pos_source = "pseudorange single-point position (no header position)"
        warnings.append(f"{rover.name}: no APPROX POSITION XYZ in the header; a priori position from pseudoranges")
    elif rover_xyz is None and len(rover.obs):
        try:
            spp = _station_spp(rover, nav, xm, max_epochs=HEADER_CHECK_EPOCHS)
        except CdgpsError:                      # no single-point position: the header's stands, as before
            spp = None
        off = np.linalg.norm(spp - xr0) if spp is not None else 0.0
        if off > HEADER_POSITION_TOL_M:
            warnings.append(f"{rover.name}: its header's APPROX POSITION XYZ is {off / 1e3:.3g} km from its "
                            f"pseudorange single-point position, which serves as its a priori position instead")
            xr0, rover_pos_source = spp, (f"pseudorange single-point position (the header's APPROX POSITION XYZ is "
                                          f"{off / 1e3:.3g} km from it)")
    return xm, xr0, rover_pos_source




def _check_master_header(master: Station, nav, xm) -> None:
    """CdgpsError when the master's header position ``xm`` is more than :data:`HEADER_POSITION_TOL_M` from its
    single-point position: every rover would be solved against a master that is not there (a Trimble NetR9's RINEX
    3.02 file put it 207 km off; `init` then took a 6.8 m pair for a 207 km baseline and blamed the ionosphere).  No
    check when the master has no GPS L1 pseudoranges for one."""
    if not len(master.obs):
        return
    try:
        spp = _station_spp(master, nav, xm, max_epochs=HEADER_CHECK_EPOCHS)
    except CdgpsError:
        return
    off = float(np.linalg.norm(spp - xm))
    if off > HEADER_POSITION_TOL_M:
        raise CdgpsError(f"{_where(master)}: the master's header position (APPROX POSITION XYZ) is {off / 1e3:.4g} km "
                         f"from its pseudorange single-point position ({' '.join(f'{v:.1f}' for v in spp)}); the master "
                         f"must be at a known position: give its surveyed one as position_ecef_m in the config's "
                         f"[gnss.antennas.\"{master.name}\"] (the single-point position is good to a few metres)")


def _station_spp(station: Station, nav, x0, max_epochs: int | None = None) -> np.ndarray:
    """A receiver's static single-point position from its GPS L1 pseudoranges (ECEF m), from ``max_epochs`` epochs
    spread over the record (None: all), started at ``x0`` (:func:`~cdgps_cli.model.gps.positioning.spp_spread`)."""
    o = station.obs
    x = spp_spread(o["sat"].to_numpy(), o["time_gps_s"].to_numpy(), o["pseudorange_l1_m"].to_numpy(), nav,
                   x0_ecef_m=x0, max_epochs=max_epochs, what=_where(station))
    if x is None:
        raise CdgpsError(f"{_where(station)}: no L1 pseudorange covered by the navigation data for a single-point "
                         f"position")
    return x


def _segments(d: _Data, opt: BaselineOptions) -> _Segments:
    """Ambiguity segments, datum pivots and the parameter index of every free segment."""
    seg, segtab = ambiguity_segments(d.epoch, d.sat, d.slip, epoch_time_s=d.t_label, max_gap_s=opt.max_gap_s,
                                     reset_epochs=d.reset_epochs, half=d.half)
    n_seg = segtab["sat"].size
    pivots, comp = ambiguity_datum(_block_of_row(d)[0], seg, n_seg)     # one datum per signal group
    is_pivot = np.zeros(n_seg, dtype=bool)
    is_pivot[pivots] = True
    seg_half = np.bincount(seg, weights=d.half.astype(float), minlength=n_seg) > 0
    free = np.flatnonzero(~is_pivot)                   # parameters: segments that are not pivots
    par_of_seg = np.full(n_seg, -1, dtype=np.int64)
    par_of_seg[free] = 3 + np.arange(free.size)
    return _Segments(seg, segtab, n_seg, pivots, comp, is_pivot, seg_half, free, par_of_seg, 3 + free.size)


def _weights(d: _Data, opt: BaselineOptions) -> _Weights:
    """SD variances and DD weights of the phase rows and of the code rows (its own references)."""
    var_ph = sd_variance(d.el_rover, d.el_base, sigma_a_m=opt.sigma_a_m, sigma_b_m=opt.sigma_b_m, weighting=opt.weighting)
    var_code = var_ph * opt.code_ratio**2 * correlated_variance_factor(d.interval_s, opt.code_correlation_s)
    if len(d.sat_names) and not opt.glonass_fix:  # per satellite name, then by each row's satellite index
        var_code = var_code * glonass_code_factor(list(d.sat_names), False)[d.sat]
    age_var = getattr(d, "age_var_m2", None)
    if age_var is not None:                       # a bridged base epoch: σ grows with its age (epoch_pairing)
        var_ph, var_code = var_ph + age_var, var_code + age_var
    code_ok = np.isfinite(d.y_code_m)
    refs_ph, refs_code, blocks_ph, blocks_code = [], [], [], []
    for m in _group_masks(d):
        ref_ph = select_reference(d.ptr, d.sat, d.el_rover, d.slip, usable=m)
        blocks_ph += dd_weight_blocks(d.ptr, var_ph, ref_ph, usable=m)
        cm = code_ok if m is None else (code_ok & m)
        ref_code = select_reference(d.ptr, d.sat, d.el_rover, usable=cm)
        blocks_code += dd_weight_blocks(d.ptr, var_code, ref_code, usable=cm)
        refs_ph.append(ref_ph)
        refs_code.append(ref_code)
    return _Weights(var_ph, refs_ph[0], blocks_ph, code_ok, var_code, refs_code[0], blocks_code,
                    np.where(code_ok, d.y_code_m, 0.0), refs_ph, refs_code)


def _residuals(d: _Data, xr, r_enu, a_seg, seg, w: _Weights, code: bool = True):
    """Design g (N, 3) at rover position xr and the epoch-centred SD phase (and code) residuals, m."""
    block, n_blocks = _block_of_row(d)       # the clock (and each group's receiver bias) removed per block
    model, g = _rover_model(d, xr, r_enu)
    r_ph = _center(block, d.y_phase_m - model - _lam(d) * a_seg[seg], n_blocks)
    r_cd = _center(block, w.y_code - model, n_blocks, w.code_ok) if code else None
    return g, r_ph, r_cd


def _float_solution(d: _Data, sg: _Segments, w: _Weights, xr0, r_enu, opt: BaselineOptions) -> _Float:
    """Float solution from phase and code DDs: Gauss–Newton on [δx, free SD ambiguities]."""
    # start the SD ambiguities from code-minus-phase (keeps the numbers small), relative to the pivots
    cmp_ = np.where(w.code_ok, (d.y_phase_m - w.y_code) / _lam(d), np.nan)
    a0 = pd.Series(cmp_).groupby(sg.seg).mean().reindex(range(sg.n_seg)).fillna(0.0).to_numpy()
    a_seg = np.round(a0 - a0[sg.pivots][sg.comp])
    a_seg[sg.is_pivot] = 0.0
    x_enu = np.zeros(3)
    col = sg.par_of_seg[sg.seg]
    it_float = 0
    for it_float in range(1, opt.max_iterations + 1):
        g, r_ph, r_cd = _residuals(d, xr0 + r_enu.T @ x_enu, r_enu, a_seg, sg.seg, w)
        n1, b1 = _accumulate(w.blocks_ph, g, r_ph, col, sg.n_par, _lam(d))
        n2, b2 = _accumulate(w.blocks_code, g, r_cd, None, sg.n_par, _lam(d))
        nmat, rhs = n1 + n2, b1 + b2
        cf, dx = _solve(nmat, rhs, "float solution")
        x_enu = x_enu + dx[:3]
        a_seg[sg.free] += dx[3:]
        if np.max(np.abs(dx[:3])) < _FLOAT_STOP_M and (dx.size == 3 or np.max(np.abs(dx[3:])) < 1e-4):
            break
    q_float = cho_solve(cf, np.eye(sg.n_par))
    g, r_ph, r_cd = _residuals(d, xr0 + r_enu.T @ x_enu, r_enu, a_seg, sg.seg, w)
    sq_ph, n_dd_ph = _quad(w.blocks_ph, r_ph)
    sq_cd, n_dd_cd = _quad(w.blocks_code, r_cd)
    dof_float = n_dd_ph + n_dd_cd - sg.n_par
    block = {
        "enu_m": x_enu.tolist(),
        "sigma_enu_m": np.sqrt(np.diag(q_float)[:3]).tolist(),
        "iterations": it_float,
        "unit_variance": (sq_ph + sq_cd) / dof_float if dof_float > 0 else None,
    }
    return _Float(x_enu.copy(), a_seg, q_float, block, g, r_ph, r_cd, n_dd_cd)


def _given_integers(integers: dict, d: _Data, sg: _Segments, fixed_mask, integers_fix) -> None:
    """Apply integers given per (satellite, first epoch) of each segment (e.g. INIT's), checking that
    they name exactly these data's segments and datum; fills ``fixed_mask`` / ``integers_fix``."""
    given = _keyed(integers)
    keys = _segment_keys(d, sg)
    unknown = [f"{k[0]} from {gps_time_str(k[1])}" for k in keys if k not in given]
    extra = [f"{k[0]} from {gps_time_str(k[1])}" for k in given if k not in set(keys)]
    if unknown or extra:
        raise CdgpsError(f"the given integers do not match the ambiguity segments of these data ({sg.n_seg} segments): "
                         + (f"no integer for {', '.join(unknown[:5])}" if unknown else "")
                         + ("; " if unknown and extra else "")
                         + (f"integers for segments these data do not have: {', '.join(extra[:5])}" if extra else ""))
    for k in range(sg.n_seg):
        v = given[keys[k]]
        if sg.is_pivot[k]:
            if v not in (0, None):
                raise CdgpsError(f"the given integers use another datum: segment {keys[k][0]} from "
                                 f"{gps_time_str(keys[k][1])} is a pivot (0) here, given {v}")
            continue
        j = sg.par_of_seg[k] - 3
        if v is not None:
            fixed_mask[j] = True
            integers_fix[j] = int(v)


def _lambda_fix(a_float, q_aa, fixable, opt: BaselineOptions, fixed_mask, integers_fix, warnings: list):
    """LAMBDA with the ratio test and partial fixing on the fixable ambiguities; fills ``fixed_mask`` /
    ``integers_fix`` and returns (ratio, ratio of the full set, accepted, partial)."""
    fi = np.flatnonzero(fixable)
    try:
        with progress.bar(fi.size if opt.partial else 1, "integer fixing (LAMBDA)", unit="subset") as bar:
            pf = resolve(a_float[fi], q_aa[np.ix_(fi, fi)], opt.ratio_threshold, partial=opt.partial,
                         progress=lambda done, total: bar.update_to(done),
                         min_success_rate=opt.min_success_rate or None)
    except AmbiguityError as exc:
        warnings.append(f"integer ambiguity resolution failed: {exc}")
        return None, None, False, False, None
    fixed_mask[fi[pf["fixed_mask"]]] = True
    integers_fix[fi[pf["fixed_mask"]]] = pf["integers"][pf["fixed_mask"]]
    if pf["limit_message"]:
        warnings.append(f"integer ambiguity resolution: {pf['limit_message']} "
                        f"({'partial fixing tried subsets' if opt.partial else 'no partial fixing'}); "
                        f"{pf['n_fixed']} of {fi.size} fixed")
    p_s = pf.get("success_rate", math.nan)
    return (None if math.isnan(pf["ratio"]) else pf["ratio"],
            None if math.isnan(pf["ratio_full_set"]) else pf["ratio_full_set"], pf["accepted"], pf["partial"],
            None if math.isnan(p_s) else p_s)


def _integer_fix(d: _Data, sg: _Segments, w: _Weights, fl: _Float, opt: BaselineOptions, integers, warnings) -> _Fix:
    """Float ambiguities (static, or under a random-walking rover) and their integers: given, or LAMBDA."""
    a_float = fl.a_seg[sg.free].copy()
    q_aa = fl.q[3:, 3:]
    if opt.motion == "random_walk" and sg.free.size:
        da, q_aa = _float_random_walk(d, sg, w, fl, opt)
        a_float = a_float + da
        fl.block["motion"] = "random_walk"
        fl.block["random_walk_sigma_m_per_sqrt_s"] = list(opt.random_walk_sigma)
    fixable = ~sg.seg_half[sg.free] & ~_fdma_segments(d, sg)[sg.free]
    fixed_mask = np.zeros(sg.free.size, dtype=bool)
    integers_fix = np.zeros(sg.free.size, dtype=np.int64)
    ratio, ratio_full, accepted, partial_used, p_s = None, None, False, False, None
    if integers is not None:
        _given_integers(integers, d, sg, fixed_mask, integers_fix)
        accepted = bool(fixed_mask.any())
    elif opt.fix and fixable.sum() >= 1:
        ratio, ratio_full, accepted, partial_used, p_s = _lambda_fix(a_float, q_aa, fixable, opt, fixed_mask,
                                                                     integers_fix, warnings)
    return _Fix(a_float, q_aa, fixed_mask, integers_fix, ratio, ratio_full, accepted, partial_used, p_s)


#: largest correction (m) the given solution may need to be that of its integers on these data (the fixed
#: solution's own convergence step); beyond it the solution is solved again from the integers
_KNOWN_SOLUTION_TOL_M = 1e-6
#: the float solution stops once its position step is below this (m): a given float position (a float-only
#: INIT's) is that solution when one more step from it is below it too (its convergence is not quadratic:
#: geonet's float stops after a step below 1e-5 m, and one more step moves it 1.2e-6 m)
_FLOAT_STOP_M = 1e-5
#: the same for a solution the static engine made (INIT's ``solver`` "static_engine"): its fixed position
#: agrees with this module's fixed solution of the same integers within 0.062 mm on the goldens
ENGINE_SOLUTION_TOL_M = 1e-4


def _known_solution(d: _Data, sg: _Segments, w: _Weights, integers: dict, solution: dict, xr0, r_enu, warnings: list,
                    tol_m: float = _KNOWN_SOLUTION_TOL_M, floats: bool = False):
    """The fixed solution given whole (e.g. INIT's): every ambiguity an integer or a datum pivot, the
    position ``solution["enu_m"]`` — evaluated there (design, residuals, covariance), not solved again.

    Returns (float, fix, final) in the solver's forms, or None when the given integers leave a segment
    float or the data hold GLONASS (FDMA) segments (unless ``floats``: the float segments' ambiguities are
    then the phase-only least squares at the given position), or the position is not the fixed solution
    of these integers (one least-squares step would move it more than ``tol_m``; a warning says so)."""
    fixed_mask, integers_fix = _integer_masks(integers, d, sg)
    fdma = _fdma_segments(d, sg)
    if not floats and (not fixed_mask.all() or fdma.any()):
        return None
    x = np.asarray(solution["enu_m"], dtype=np.float64).reshape(3)
    a_fix, known, unk = _known_ambiguities(sg, fixed_mask, integers_fix)
    par2 = np.full(sg.n_seg, -1, dtype=np.int64)
    par2[unk] = 3 + np.arange(unk.size)
    g, r_ph, _ = _residuals(d, xr0 + r_enu.T @ x, r_enu, a_fix, sg.seg, w, code=False)
    nmat, rhs = _accumulate(w.blocks_ph, g, r_ph, par2[sg.seg], 3 + unk.size, _lam(d))
    cf, dx = _solve(nmat, rhs, "fixed solution")
    if np.max(np.abs(dx[:3])) > tol_m:        # not the solution of these integers on these data
        warnings.append(f"the given solution is {1e3 * float(np.linalg.norm(dx[:3])):.3g} mm from the fixed solution "
                        f"of the given integers on these data; solved again from the integers")
        return None
    if unk.size:                              # the float ambiguities at the given position
        a_fix[unk] += dx[3:]
        g, r_ph, _ = _residuals(d, xr0 + r_enu.T @ x, r_enu, a_fix, sg.seg, w, code=False)
    q = cho_solve(cf, np.eye(3 + unk.size))
    a_sig = np.zeros(sg.n_seg)
    a_sig[unk] = np.sqrt(np.diag(q)[3:])
    how = ("position and integers given (not solved again)" if not unk.size else
           "position and integers given (not solved again); the float ambiguities at that position")
    return _evaluated(d, sg, w, solution, (fixed_mask, integers_fix), _Final(None, x, "", a_fix, known, q[:3, :3], g,
                                                                          r_ph, a_sig), how)


def _given_solution(d: _Data, sg: _Segments, w: _Weights, integers: dict, solution: dict, xr0, r_enu,
                    warnings: list, glonass: tuple | None = None):
    """A partially fixed solution given whole (INIT's): position ``solution["enu_m"]`` and its covariance
    ``cov_enu_m2``, the integers, and each float segment's value and σ in it (``solution_cycles``
    ``{(satellite, first s): (cycles, σ)}``) — evaluated, nothing solved (no normal equations).

    The values are INIT's on these data when the DD phase residuals they leave are INIT's, satellite by
    satellite (``solution["residuals"]``, :func:`_residual_summary`'s, within 1e-9 relative); else None with a
    warning.  None without a warning when a value, the covariance or the residuals are missing (an INIT written
    before it held them).  ``glonass``: a glonass_fix solution's GLONASS DD integers (:func:`_given_glonass`'s
    segments and integers; :func:`_glonass_values_agree` checks them first), reported as the engine reports them.
    Returns (float, fix, final) in the solver's forms."""
    fixed_mask, integers_fix = _integer_masks(integers, d, sg)
    a_fix, known, unk = _known_ambiguities(sg, fixed_mask, integers_fix)
    keys = _segment_keys(d, sg)
    given = _given_values(solution.get("solution_cycles"), [keys[k] for k in unk])
    res = solution.get("residuals")
    cov, ref = solution.get("cov_enu_m2"), res.get("per_satellite_rms_m") if isinstance(res, dict) else None
    if given is None or cov is None or not ref or not unk.size:
        return None
    x = np.asarray(solution["enu_m"], dtype=np.float64).reshape(3)
    a_fix[unk] = given[0]
    g, r_ph, _ = _residuals(d, xr0 + r_enu.T @ x, r_enu, a_fix, sg.seg, w, code=False)
    if not _same_residuals(_residual_summary(d, w, r_ph, 0)["per_satellite_rms_m"], ref):
        warnings.append("the given float ambiguities do not leave INIT's residuals on these data; solved again")
        return None
    a_sig = np.zeros(sg.n_seg)
    a_sig[unk] = given[1]
    q3 = np.asarray(cov, dtype=np.float64).reshape(3, 3)
    fl, fx, fin = _evaluated(d, sg, w, solution, (fixed_mask, integers_fix),
                             _Final(None, x, "", a_fix, known, q3, g, r_ph, a_sig),
                             "position, integers and the float ambiguities given (not solved again)")
    return (fl, fx, fin) if glonass is None else (fl, *_with_glonass_integers(d, sg, fx, fin, glonass))


def _same_residuals(here: dict, ref) -> bool:
    """Whether per-satellite DD residual rms ``here`` are ``ref``'s (INIT's) to 1e-9 relative; False for a ``ref``
    that is not such a table (an edited INIT)."""
    try:
        return set(here) == set(ref) and all(math.isclose(here[k], float(ref[k]), rel_tol=1e-9, abs_tol=1e-12)
                                             for k in here)
    except (TypeError, ValueError):
        return False


def _with_glonass_integers(d: _Data, sg: _Segments, fx: _Fix, fin: _Final, glonass: tuple) -> tuple:
    """(fix, final) of :func:`_given_solution` with a glonass_fix solution's GLONASS DD integers recorded as
    :func:`_engine_solution` records them (each fixed segment's N_k − N_p, its pivot's 0) and its kind counting them."""
    segs, ints = glonass
    fdma = _fdma_segments(d, sg)
    dd = np.full(sg.n_seg, np.nan)
    dd[segs] = ints
    dd[fdma & sg.is_pivot] = 0.0                  # every GLONASS pivot, as the engine's conditioning records them
    glo_fixed = np.zeros(sg.n_seg, dtype=bool)
    glo_fixed[segs] = True
    fixed_all = int(fx.fixed_mask.sum()) + segs.size == sg.free.size
    fx = fx._replace(glonass_fixed=glo_fixed & fdma, glonass_dd=dd, accepted=True)
    return fx, fin._replace(kind="fixed" if fixed_all else "partially fixed")


def _glonass_values_agree(d: _Data, sg: _Segments, solution: dict, glonass: tuple) -> bool:
    """Whether a glonass_fix solution's GLONASS values are its GLONASS DD integers: each fixed segment's value
    a_k = N_k − N_p + x_p (1 − λ_p/λ_k) (:func:`_datum_map`; x_p its pivot's own arc value,
    ``solution["pivot_arc_cycles"]``) within 1e-6 cycle.  An edited integer, or a value missing, sends the
    solve to the engine, which conditions on the integers given."""
    segs, ints = glonass
    keys = _segment_keys(d, sg)
    piv = sg.pivots[sg.comp[segs]]
    vals = _given_values(solution.get("solution_cycles"), [keys[k] for k in segs])
    arcs = _given_values({k: (v, 0.0) for k, v in (solution.get("pivot_arc_cycles") or {}).items()},
                         [keys[k] for k in piv])
    if vals is None or arcs is None:
        return False
    lam = np.zeros(sg.n_seg)
    lam[sg.seg] = np.broadcast_to(np.asarray(_lam(d), dtype=np.float64), d.sat.shape)
    want = ints + arcs[0] * (1.0 - lam[piv] / lam[segs])
    return bool(np.all(np.abs(vals[0] - want) < 1e-6))


def _integer_masks(integers: dict, d: _Data, sg: _Segments) -> tuple:
    """(fixed mask, integers) of the free segments from integers given (:func:`_given_integers`)."""
    fixed_mask = np.zeros(sg.free.size, dtype=bool)
    integers_fix = np.zeros(sg.free.size, dtype=np.int64)
    _given_integers(integers, d, sg, fixed_mask, integers_fix)
    return fixed_mask, integers_fix


def _known_ambiguities(sg: _Segments, fixed_mask, integers_fix) -> tuple:
    """(SD ambiguities, cycles: the integers, 0 elsewhere; known mask (pivot or fixed); the unknown segments)."""
    a_fix = np.zeros(sg.n_seg)
    a_fix[sg.free] = np.where(fixed_mask, integers_fix, 0)
    known = sg.is_pivot.copy()
    known[sg.free[fixed_mask]] = True
    return a_fix, known, np.flatnonzero(~known)


def _evaluated(d: _Data, sg: _Segments, w: _Weights, solution: dict, fixed: tuple, fin: _Final, how: str) -> tuple:
    """(float, fix, final) of a solution evaluated at given values (``fin``: its position, ambiguities, known
    mask, covariance, design, residuals and σ; ``fixed``: the free segments' fixed mask and integers)."""
    fixed_mask, integers_fix = fixed
    n_unk = int(np.sum(~fin.known_seg))
    sq, n_dd = _quad(w.blocks_ph, fin.r_ph)
    dof = n_dd - 3 - n_unk
    block = {"enu_m": fin.x.tolist(), "sigma_enu_m": np.sqrt(np.diag(fin.q3)).tolist(), "iterations": 0,
             "unit_variance": sq / dof if dof > 0 else None,
             "observations": ("L1 carrier phase only" if getattr(d, "group", None) is None
                              else f"carrier phase only ({', '.join(d.group_names)})"),
             "given": how}
    keys = _segment_keys(d, sg)
    a_float, sig = _given_values(solution.get("float_cycles"), [keys[k] for k in sg.free], partial=True)
    fl = _Float(fin.x, fin.a_seg.copy(), None, None, fin.g, fin.r_ph, None, 0)
    fx = _Fix(a_float, np.diag(sig**2) if sig.size else np.zeros((0, 0)), fixed_mask, integers_fix, None, None,
              bool(fixed_mask.all() or fixed_mask.any()), False)
    fdma = _fdma_segments(d, sg)
    kind = "fixed" if int(fixed_mask.sum()) == int(np.sum(~fdma[sg.free])) else "partially fixed"
    return fl, fx, fin._replace(block=block, kind=kind)


def _segment_keys(d: _Data, sg: _Segments) -> list:
    """(satellite, first epoch's time tag s, rounded to 1 ms) of every segment: how INIT names them."""
    return [(d.sat_names[int(sg.segtab["sat"][k])], round(float(d.t_label[sg.segtab["first_epoch"][k]]), 3))
            for k in range(sg.n_seg)]


def _keyed(given: dict) -> dict:
    """``given`` ``{(satellite, first s): …}`` keyed as :func:`_segment_keys` names the segments."""
    return {(str(k[0]), round(float(k[1]), 3)): v for k, v in given.items()}


def _given_values(given: dict | None, keys: list, partial: bool = False):
    """(values, σ) (cycles, arrays in ``keys``' order) of ``given`` ``{(satellite, first s): (value, σ)}``;
    None when one is missing or not finite, unless ``partial`` (NaN there)."""
    given = _keyed(given or {})
    out = np.full((2, len(keys)), np.nan)
    for i, k in enumerate(keys):
        v = given.get(k)
        for j in (0, 1):
            try:
                out[j, i] = float(v[j])
            except (TypeError, ValueError, IndexError):
                pass
    if not partial and not np.all(np.isfinite(out)):
        return None
    return out[0], out[1]


def _known_float(d: _Data, sg: _Segments, w: _Weights, enu_m, xr0, r_enu, tol_m: float):
    """A float solution given by its position ``enu_m`` (3,) (e.g. a float-only INIT's): the ambiguities and the
    covariance of the phase and code least squares evaluated there (one step, linear in the ambiguities); None when
    that step would move the position more than ``tol_m`` (not the float solution of these data)."""
    x = np.asarray(enu_m, dtype=np.float64).reshape(3)
    a_seg = np.zeros(sg.n_seg)
    col = sg.par_of_seg[sg.seg]
    g, r_ph, r_cd = _residuals(d, xr0 + r_enu.T @ x, r_enu, a_seg, sg.seg, w)
    n1, b1 = _accumulate(w.blocks_ph, g, r_ph, col, sg.n_par, _lam(d))
    n2, b2 = _accumulate(w.blocks_code, g, r_cd, None, sg.n_par, _lam(d))
    cf, dx = _solve(n1 + n2, b1 + b2, "float solution")
    if np.max(np.abs(dx[:3])) > tol_m:
        return None
    a_seg[sg.free] += dx[3:]
    q = cho_solve(cf, np.eye(sg.n_par))
    g, r_ph, r_cd = _residuals(d, xr0 + r_enu.T @ x, r_enu, a_seg, sg.seg, w)
    sq_ph, n_ph = _quad(w.blocks_ph, r_ph)
    sq_cd, n_cd = _quad(w.blocks_code, r_cd)
    dof = n_ph + n_cd - sg.n_par
    block = {"enu_m": x.tolist(), "sigma_enu_m": np.sqrt(np.diag(q)[:3]).tolist(), "iterations": 0,
             "unit_variance": (sq_ph + sq_cd) / dof if dof > 0 else None,
             "given": "position given (not solved again); the ambiguities at that position"}
    fl = _Float(x, a_seg, q, block, g, r_ph, r_cd, n_cd)
    fx = _Fix(a_seg[sg.free], q[3:, 3:], np.zeros(sg.free.size, dtype=bool), np.zeros(sg.free.size, dtype=np.int64),
              None, None, False, False)
    a_sig = np.zeros(sg.n_seg)
    a_sig[sg.free] = np.sqrt(np.diag(q)[3:])
    return fl, fx, _Final(None, x, "float", a_seg.copy(), sg.is_pivot.copy(), q[:3, :3], g, r_ph, a_sig)


def _fixed_solution(d: _Data, sg: _Segments, w: _Weights, fl: _Float, fx: _Fix, xr0, r_enu,
                    opt: BaselineOptions) -> _Final:
    """The fixed solution from the L1 phase only (fixed integers removed from the unknowns, the others
    float), iterated to convergence; the float solution when nothing is fixed."""
    n_fixed = int(fx.fixed_mask.sum())
    if not n_fixed:
        a_sig = np.zeros(sg.n_seg)
        a_sig[sg.free] = np.sqrt(np.diag(fl.q)[3:])
        return _Final(None, fl.x, "float", fl.a_seg.copy(), sg.is_pivot.copy(), fl.q[:3, :3], fl.g, fl.r_ph, a_sig)
    a_fix = fl.a_seg.copy()
    known_seg = sg.is_pivot.copy()
    fsegs = sg.free[fx.fixed_mask]
    a_fix[fsegs] = fx.integers[fx.fixed_mask]
    known_seg[fsegs] = True
    unk = np.flatnonzero(~known_seg)
    par2 = np.full(sg.n_seg, -1, dtype=np.int64)
    par2[unk] = 3 + np.arange(unk.size)
    n_par2 = 3 + unk.size
    col2 = par2[sg.seg]
    x_fix = fl.x.copy()
    it_fix = 0
    for it_fix in range(1, opt.max_iterations + 1):
        g, r_ph, _ = _residuals(d, xr0 + r_enu.T @ x_fix, r_enu, a_fix, sg.seg, w, code=False)
        nmat, rhs = _accumulate(w.blocks_ph, g, r_ph, col2, n_par2, _lam(d))
        cf2, dx = _solve(nmat, rhs, "fixed solution")
        x_fix = x_fix + dx[:3]
        a_fix[unk] += dx[3:]
        if np.max(np.abs(dx[:3])) < 1e-6 and (dx.size == 3 or np.max(np.abs(dx[3:])) < 1e-5):
            break
    g, r_ph, _ = _residuals(d, xr0 + r_enu.T @ x_fix, r_enu, a_fix, sg.seg, w, code=False)
    q_fix = cho_solve(cf2, np.eye(n_par2))
    sq, n_dd = _quad(w.blocks_ph, r_ph)
    dof = n_dd - n_par2
    block = {
        "enu_m": x_fix.tolist(),
        "sigma_enu_m": np.sqrt(np.diag(q_fix)[:3]).tolist(),
        "iterations": it_fix,
        "unit_variance": sq / dof if dof > 0 else None,
        "observations": ("L1 carrier phase only" if getattr(d, "group", None) is None
                         else f"carrier phase only ({', '.join(d.group_names)})"),
    }
    kind = "fixed" if n_fixed == int(np.sum(~_fdma_segments(d, sg)[sg.free])) else "partially fixed"
    a_sig = np.zeros(sg.n_seg)
    a_sig[unk] = np.sqrt(np.diag(q_fix)[3:])
    return _Final(block, x_fix, kind, a_fix, known_seg, q_fix[:3, :3], g, r_ph, a_sig)


def _residual_summary(d: _Data, w: _Weights, r_ph, n_dd_code: int) -> dict:
    """DD phase residuals of the reported solution (every signal group): RMS, largest, per satellite."""
    parts = [double_differences(d.ptr, ref, r_ph, usable=m) for m, ref in zip(_group_masks(d), w.refs_ph)]
    dd_res = {k: np.concatenate([p[k] for p in parts]) for k in ("value", "row")}
    res_v = dd_res["value"]
    return {
        "dd_phase_rms_m": float(np.sqrt(np.mean(res_v**2))) if res_v.size else None,
        "dd_phase_max_abs_m": float(np.max(np.abs(res_v))) if res_v.size else None,
        "n_dd_phase": int(res_v.size),
        "n_dd_code": int(n_dd_code),
        "per_satellite_rms_m": {
            d.sat_names[s]: float(np.sqrt(np.mean(res_v[d.sat[dd_res["row"]] == s] ** 2)))
            for s in np.unique(d.sat[dd_res["row"]])
        },
    }


def known_phase_blocks(d: _Data, var_ph, refs_ph: list, blocks_ph: list, usable) -> list:
    """The DD phase weight blocks (rows, P) of the rows ``usable`` (N,) bool (those whose ambiguity is known), every
    signal group's with its own reference (:func:`select_reference` keeping a satellite while it does not slip);
    when every row is usable they are the phase weights' own ``blocks_ph`` (references ``refs_ph``): the same
    calls on the same arrays, so not made again (a day at 1 Hz: ≈ 1 s each).  Returns ``[(rows, P), ...]`` in
    group order, and the references used, one (n_ep,) array per group."""
    if np.all(usable):
        return blocks_ph, list(refs_ph)
    blocks, refs = [], []
    for m in _group_masks(d):
        u = usable if m is None else usable & m
        ref_k = select_reference(d.ptr, d.sat, d.el_rover, d.slip, usable=u)
        blocks += dd_weight_blocks(d.ptr, var_ph, ref_k, usable=u)
        refs.append(ref_k)
    return blocks, refs


def _single_epoch_positions(d: _Data, w: _Weights, fin: _Final, seg, opt: BaselineOptions):
    """Every epoch solved alone from its phase DDs (all signal groups) with the known ambiguities →
    (epoch, ENU m, n_sat, PDOP, covariance m²) by epoch, or None when no epoch has enough satellites.
    ``n_sat`` counts satellite-signal rows; an epoch needs ``min_sats_kinematic`` − 1 DDs.  Also each solution's
    weighted residual square sum ``sse`` (eᵀPe of its DD phases after the fit, the weights of ``w``) and its degrees
    of freedom ``dof`` (DDs − 3): their ratio over the epochs is the phase variances' scale the data show
    (:func:`cdgps_cli.pipeline.gnss.phase_variance_factor`)."""
    n_ep = d.t_label.size
    nmat, rhs, gcg = np.zeros((n_ep, 3, 3)), np.zeros((n_ep, 3)), np.zeros((n_ep, 3, 3))
    rpr = np.zeros(n_ep)
    n_sat, n_dd = np.zeros(n_ep, dtype=np.int64), np.zeros(n_ep, dtype=np.int64)
    blocks, _ = known_phase_blocks(d, w.var_ph, w.refs_ph, w.blocks_ph, fin.known_seg[seg])
    for rows, p in blocks:
        gk, rk = fin.g[rows], fin.r_ph[rows]
        ep = d.epoch[rows[:, 0]]
        gt = np.swapaxes(gk, 1, 2)
        pg = p @ gk
        nmat[ep] += gt @ pg
        rhs[ep] += (np.swapaxes(pg, 1, 2) @ rk[:, :, None])[:, :, 0]
        rpr[ep] += np.einsum("ki,kij,kj->k", rk, p, rk)
        gc = gk - gk.mean(axis=1, keepdims=True)       # geometry with the clock (group bias) eliminated
        gcg[ep] += np.swapaxes(gc, 1, 2) @ gc
        n_sat[ep] += rows.shape[1]
        n_dd[ep] += rows.shape[1] - 1
    ep = np.flatnonzero(n_dd >= opt.min_sats_kinematic - 1)
    ep = ep[full_rank(nmat[ep]) & full_rank(gcg[ep])]     # (L1 and L2 DDs of too few satellites: not enough)
    if not ep.size:
        return None
    ck = np.linalg.inv(nmat[ep])
    dk = np.einsum("kcd,kd->kc", ck, rhs[ep])
    pdop = np.sqrt(np.trace(np.linalg.inv(gcg[ep]), axis1=1, axis2=2))
    sse = rpr[ep] - np.einsum("kc,kc->k", dk, rhs[ep])          # rᵀPr − δᵀNδ: the fit's residual square sum
    return {"epoch": ep, "enu_m": fin.x + dk, "n_sat": n_sat[ep], "pdop": pdop, "cov_m2": ck,
            "sse": np.maximum(sse, 0.0), "dof": n_dd[ep] - 3}


def _kinematic_summary(d: _Data, ka: dict, x_final, opt: BaselineOptions) -> dict:
    """Scatter of the single-epoch positions about the static solution (all, and PDOP ≤ the maximum)."""
    ep_k, enu_k, ns_k, pd_k = ka["epoch"], ka["enu_m"], ka["n_sat"], ka["pdop"]
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
    return kin


def _fdma_segments(d: _Data, sg: _Segments) -> np.ndarray:
    """(n_seg,) bool: segments of GLONASS (FDMA) signals, kept float and never passed to LAMBDA.

    A GLONASS SD segment's phase in metres carries λ_i·N_i with its satellite's own wavelength, so
    the DD λ_i·N_i − λ_r·N_r (plus the receivers' inter-frequency bias difference of the two
    channels) is not an integer of one wavelength: each segment is one float bias (m, λ_i × its
    float cycles, relative to its group's datum segment), as ``cdgps rtk`` keeps GLONASS."""
    names = np.array([str(n)[:1] for n in d.sat_names], dtype=object)
    return names[sg.segtab["sat"]] == "R" if len(names) else np.zeros(sg.n_seg, dtype=bool)


_FDMA_REASON = ("GLONASS (FDMA): the DD ambiguity λ_i·N_i − λ_r·N_r plus the inter-frequency bias is not an integer "
                "of one wavelength; kept float (one bias per lock segment, m), never passed to LAMBDA")


def _fdma_row(row: dict, lam: float, a_cycles: float, sigma_cycles: float) -> dict:
    """A GLONASS segment's table row: float, no integer, its value in the reported solution (cycles
    of its own wavelength and the bias in metres, relative to its group's datum segment; LAMBDA never
    sees it), and the reason."""
    if row["pivot"]:
        return dict(row, fixed=False, integer=None, float_bias_m=0.0, sigma_bias_m=0.0, reason=_FDMA_REASON)
    return dict(row, fixed=False, integer=None, float_cycles=a_cycles, sigma_cycles=sigma_cycles,
                float_bias_m=lam * a_cycles, sigma_bias_m=lam * sigma_cycles, reason=_FDMA_REASON)


def _segment_table(d: _Data, sg: _Segments, fx: _Fix, fin: _Final) -> list:
    """One row per SD ambiguity segment: satellite, span, datum, float value, integer (and with signal
    groups its ``signal`` and ``wavelength_m``; GLONASS segments: :func:`_fdma_row` from ``fin``)."""
    rows = []
    sig = _satellite_signals(d)
    for k in range(sg.n_seg):
        p_idx = sg.par_of_seg[k] - 3
        piv = sg.is_pivot[k]
        rows.append({
            "sat": d.sat_names[int(sg.segtab["sat"][k])],
            "first": gps_time_str(float(d.t_label[sg.segtab["first_epoch"][k]])),
            "last": gps_time_str(float(d.t_label[sg.segtab["last_epoch"][k]])),
            "n_epochs": int(sg.segtab["n_rows"][k]),
            "pivot": bool(piv),
            "reference": d.sat_names[int(sg.segtab["sat"][sg.pivots[sg.comp[k]]])],     # its connected set's datum
            "half_cycle_flag": bool(sg.seg_half[k]),
            "float_cycles": None if piv else float(fx.a_float[p_idx]),
            "sigma_cycles": None if piv else float(math.sqrt(fx.q_aa[p_idx, p_idx])),
            "fixed": bool(piv or (p_idx >= 0 and fx.fixed_mask[p_idx])),
            "integer": (0 if piv else (int(fx.integers[p_idx]) if fx.fixed_mask[p_idx] else None)),
            "first_gps_s": float(d.t_label[sg.segtab["first_epoch"][k]]),
            "last_gps_s": float(d.t_label[sg.segtab["last_epoch"][k]]),
            **(sig[int(sg.segtab["sat"][k])] if sig else {}),
            **_solution_value(fin, k),
        })
    fdma = _fdma_segments(d, sg) if sig else np.zeros(sg.n_seg, dtype=bool)
    for k in np.flatnonzero(fdma):
        rows[k] = _fdma_row(rows[k], rows[k]["wavelength_m"], float(fin.a_seg[k]), float(fin.a_sigma[k]))
    return rows


def _solution_value(fin: _Final, k: int) -> dict:
    """A float segment's value and σ in a (partially) fixed solution (cycles; conditioned on the fixed
    integers), which ``estimate`` evaluates instead of solving again; a glonass_fix solution's GLONASS pivot: its
    own arc value x_p (cycles; a GLONASS segment's value is N_k − N_p + x_p (1 − λ_p/λ_k)); nothing for another
    known segment or a float solution."""
    if fin.block is not None and fin.pivot_arc is not None and np.isfinite(fin.pivot_arc[k]):
        return {"pivot_arc_cycles": float(fin.pivot_arc[k])}
    if fin.block is None or fin.known_seg[k] or fin.a_sigma is None:
        return {}
    return {"solution_cycles": float(fin.a_seg[k]), "solution_sigma_cycles": float(fin.a_sigma[k])}


def _satellite_signals(d: _Data) -> list:
    """Per satellite-signal name: its ``signal`` and ``wavelength_m`` (empty list: GPS L1 only)."""
    if getattr(d, "group", None) is None:
        return []
    grp = np.zeros(len(d.sat_names), dtype=np.int64)
    lam = np.zeros(len(d.sat_names))
    grp[d.sat] = d.group
    lam[d.sat] = d.lam_m
    return [{"signal": d.group_names[g], "wavelength_m": float(v)} for g, v in zip(grp, lam)]


def _satellite_table(d: _Data, sg: _Segments) -> list:
    out = []
    for s, nm in enumerate(d.sat_names):
        m = d.sat == s
        out.append({"sat": nm, "n_epochs": int(m.sum()),
                    "elevation_deg": [float(np.degrees(d.el_rover[m].min())), float(np.degrees(d.el_rover[m].max()))],
                    "slips": int(d.slip[m].sum()), "segments": int(np.sum(sg.segtab["sat"] == s))})
    return out


def _reference_satellites(d: _Data, refs_ph: list) -> tuple[list, int]:
    """The reference satellites of each signal group in time order (satellite, from) and the number
    of changes."""
    ref_list, n_changes = [], 0
    for k, ref_ph in enumerate(refs_ph):
        ref_ep = np.flatnonzero(ref_ph >= 0)
        if not ref_ep.size:                     # a group never differenced (one satellite at a time): no reference
            continue
        ref_sat = d.sat[ref_ph[ref_ep]]
        starts = np.flatnonzero(np.r_[True, np.diff(ref_sat) != 0])
        sig = {} if getattr(d, "group", None) is None else {"signal": d.group_names[k]}
        ref_list += [{"sat": d.sat_names[int(ref_sat[i])], "from": gps_time_str(float(d.t_label[ref_ep[i]])), **sig}
                     for i in starts]
        n_changes += int(starts.size - 1) if starts.size else 0
    return ref_list, n_changes


def _fdma_count(seg_rows: list) -> dict:
    """``{"n_float_glonass": n}``: GLONASS segments estimated as float biases (datum excluded); {} when none."""
    n = sum(1 for r in seg_rows if "reason" in r and not r["pivot"])
    return {"n_float_glonass": n} if n else {}


_GLONASS_FIXED_REASON = ("GLONASS fixed by the static engine (glonass_fix, identical receivers): its DD integer is "
                         "N_i − N_r in each satellite's own cycles (dd_integer_cycles); this table's datum shows the "
                         "engine's fixed value as a bias (m)")


def fdma_channel(signal: str, wavelength_m: float) -> int:
    """GLONASS frequency number k (−7 … 6) of an FDMA ``signal`` (e.g. ``"R:G1"``) at ``wavelength_m``."""
    sig = SIGNALS[signal]
    return int(round((SPEED_OF_LIGHT_M_S / wavelength_m - sig.frequency_hz) / sig.fdma_step_hz))


def _glonass_integer_rows(sg: _Segments, fx: _Fix, seg_rows: list) -> None:
    """Each GLONASS segment row with a DD integer the engine fixed (glonass_fix) gets it: ``dd_integer_cycles``
    (N_i − N_p, each satellite in its own cycles, against its datum pivot ``reference``; 0 on the pivot), and
    ``fdma_channel`` (frequency number k) with ``reference_fdma_channel``; the fixed ones ``fixed_by_engine``."""
    for k in np.flatnonzero(np.isfinite(fx.glonass_dd)):
        row, piv = seg_rows[k], seg_rows[int(sg.pivots[sg.comp[k]])]
        ids = {"dd_integer_cycles": int(fx.glonass_dd[k]),
               "fdma_channel": fdma_channel(row["signal"], row["wavelength_m"]),
               "reference_fdma_channel": fdma_channel(piv["signal"], piv["wavelength_m"])}
        seg_rows[k] = dict(row, **ids, **({"reason": _GLONASS_FIXED_REASON, "fixed_by_engine": True}
                                          if fx.glonass_fixed[k] else {}))


def _ambiguity_summary(sg: _Segments, fx: _Fix, opt: BaselineOptions, seg_rows: list) -> dict:
    glonass = {}
    if fx.glonass_fixed is not None and fx.glonass_fixed.any():
        _glonass_integer_rows(sg, fx, seg_rows)
        glonass = {"n_glonass_fixed_by_engine": int(fx.glonass_fixed.sum())}
    return {
        "n_segments": int(sg.n_seg),
        "n_pivots": int(sg.pivots.size),
        "n_estimated": int(sg.free.size),
        "n_fixed": int(fx.fixed_mask.sum()),
        "n_half_cycle_excluded": int(np.sum(sg.seg_half[sg.free])),
        **_fdma_count([r for r in seg_rows if not r.get("fixed_by_engine")]),
        **glonass,
        "ratio": fx.ratio,
        "ratio_full_set": fx.ratio_full,
        "ratio_threshold": opt.ratio_threshold,
        "success_rate": fx.success_rate,
        "min_success_rate": opt.min_success_rate,
        "accepted": bool(fx.accepted),
        "partial": fx.partial,
        "segments": seg_rows,
    }


def _result(master: Station, rover: Station, xm, xr0, source: str, r_enu, fl: _Float, fin: _Final) -> dict:
    """The result's solution part: states, positions, baseline, float and fixed blocks."""
    names = [f"{rover.name}_{c}" for c in ("e", "n", "u")]
    xr_final = xr0 + r_enu.T @ fin.x
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

    return {
        "kind": "cdgps static baseline",
        "master": master.name,
        "rover": rover.name,
        "solution": fin.kind,
        "states": dict(zip(names, fin.x.tolist())),
        "state_units": "m (rover displacement from its a priori position, local east/north/up at that position)",
        "master_ecef_m": xm.tolist(),
        "rover_apriori_ecef_m": xr0.tolist(),
        "rover_apriori_source": source,
        "rover_ecef_m": xr_final.tolist(),
        "baseline_enu_from_master_m": base_enu.tolist(),
        "baseline_length_m": float(np.linalg.norm(xr_final - xm)),
        "float": _block(fl.block, fl.x),
        "fixed": (dict(_block(fin.block, fin.x), cov_enu_m2=np.asarray(fin.q3).tolist()) if fin.block else None),
    }


def _work(d: _Data, sg: _Segments, w: _Weights, fin: _Final, xr0, xm, r_enu, kin_arrays) -> dict:
    """The solver's working arrays for the GNSS pipeline's estimators (``keep_work``)."""
    return {
        "data": d, "seg": sg.seg, "segtab": sg.segtab, "is_pivot": sg.is_pivot, "seg_half": sg.seg_half,
        "known_seg": fin.known_seg, "a_seg": fin.a_seg, "var_ph": w.var_ph, "ref_ph": w.ref_ph, "refs_ph": w.refs_ph, "blocks_ph": w.blocks_ph, "xr0": xr0, "xm": xm,
        "r_enu": r_enu, "x_final": np.asarray(fin.x), "q_final": fin.q3, "r_ph": fin.r_ph, "g": fin.g,
        "kinematic": kin_arrays,
    }


def check_iono_rule(master: str, rover: str, length_m: float, threshold_km: float) -> None:
    """Refuse a baseline at or above the ionosphere threshold.

    The displacement path (GPS L1 alone or with ``[gnss] signals``, :mod:`.baseline_signals`) neglects the
    double-differenced ionosphere and the zenith wet delays, as ``cdgps rtk`` does only below its
    ``iono_threshold_km``; at or above it they (a few mm per km, more on dual frequency's wide lane) would bias the
    position and the integers.  The real DELF → ZEGV pair, 35 km, GPS L1: ``init`` took it and "fixed" 5 of 9
    integers 0.49 m off the station's coordinate with a σ of 4–7 mm; ``cdgps rtk`` leaves it float within its σ.

    Parameters
    ----------
    master, rover : str
        Station names, for the message.
    length_m : float
        Baseline length (master to rover a priori position), m.
    threshold_km : float
        ``gnss.iono_threshold_km``, km.

    Raises
    ------
    CdgpsError
        ``length_m`` ≥ ``threshold_km`` km, naming the length, the key and ``cdgps rtk``.
    """
    if length_m >= 1e3 * threshold_km:
        raise CdgpsError(
            f"baseline {master} → {rover} is {length_m / 1e3:.3f} km long, at or above gnss.iono_threshold_km = "
            f"{threshold_km:g} km: the static solution of 'cdgps init' and 'cdgps baseline' neglects the "
            f"double-differenced ionosphere and the zenith wet delays; use 'cdgps rtk' (estimates them at or above its "
            f"iono_threshold_km), or raise gnss.iono_threshold_km in the config (baseline: --iono-threshold-km) to "
            f"accept their error")


# ----------------------------------------------------------------------------------------------
# the static engine's solution in this solver's forms (issue 28 item 1)
# ----------------------------------------------------------------------------------------------


def _engine_epochs(t_label, time_s) -> np.ndarray:
    """Index (n,) of this solver's epoch nearest each of the engine's epoch times ``time_s`` (rover time
    tags, s), −1 where none is within half the epoch spacing (the rover's clock may offset its tags by ms)."""
    t = np.asarray(t_label, dtype=np.float64)
    x = np.asarray(time_s, dtype=np.float64)
    if t.size == 0:
        return np.full(x.size, -1, dtype=np.int64)
    half = 0.5 * float(np.median(np.diff(t))) if t.size > 1 else np.inf
    i = np.searchsorted(0.5 * (t[1:] + t[:-1]), x)
    return np.where(np.abs(t[i] - x) < half, i, -1).astype(np.int64)


def _engine_columns(d: _Data, sg: _Segments, arcs: dict):
    """The engine's state column of every SD segment (n_seg,) matched on (satellite, signal, first epoch in a
    double difference: the one of this solver's epochs nearest that time tag), or a string saying why the two
    sets of arcs differ.  An engine arc never in a double difference (its rows alone in their epochs: a satellite
    seen by itself at the end of a record) holds only its prior and has no segment here (this solver drops the
    rows of epochs with fewer than two satellites): it is left out of the match."""
    sig = _satellite_signals(d)
    in_dd = np.flatnonzero(np.isfinite(arcs["first_dd_s"]))
    epoch = _engine_epochs(d.t_label, arcs["first_dd_s"][in_dd])
    key = {(arcs["sat"][i], arcs["signal"][i], int(e)): 3 + int(i) for i, e in zip(in_dd, epoch)}
    if len(key) != sg.n_seg or (epoch < 0).any():
        return f"the engine has {len(key)} ambiguity arcs in double differences, this solver {sg.n_seg} segments"
    out = np.empty(sg.n_seg, dtype=np.int64)
    for k in range(sg.n_seg):
        s = int(sg.segtab["sat"][k])
        name = d.sat_names[s].split(":")[0]
        e = int(sg.segtab["first_epoch"][k])
        c = key.get((name, sig[s]["signal"] if sig else "G:L1", e))
        if c is None:
            return f"segment {d.sat_names[s]} from {gps_time_str(float(d.t_label[e]))} is no arc of the engine"
        out[k] = c
    return out


def _datum_map(d: _Data, sg: _Segments, cols, n_state: int) -> np.ndarray:
    """J (n_seg, n_state): this solver's SD ambiguity of each segment (its pivot at 0) from the engine's arc
    states, a_k = x_k − (λ_p / λ_k) x_p with p the segment's pivot (the DDs are the same)."""
    lam_row = np.broadcast_to(np.asarray(_lam(d), dtype=np.float64), d.sat.shape)
    lam_seg = np.zeros(sg.n_seg)
    lam_seg[sg.seg] = lam_row
    piv = sg.pivots[sg.comp]
    J = np.zeros((sg.n_seg, n_state))
    J[np.arange(sg.n_seg), cols] += 1.0
    J[np.arange(sg.n_seg), cols[piv]] -= lam_seg[piv] / lam_seg
    return J


def _nan_none(v):
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else v


def _random_walk_notes(rw, opt: BaselineOptions) -> dict:
    """INIT's float-block fields of the engine's random-walk float ``rw``
    (:class:`~cdgps_cli.estimation.static_engine.RandomWalkFloat`; {} without one): the configured σ, its NIS per
    row, and when σ was raised the σ used and every σ tried."""
    if rw is None:
        return {}
    out = {"motion": "random_walk", "random_walk_sigma_m_per_sqrt_s": list(opt.random_walk_sigma),
           "random_walk_nis_per_row": _nan_none(rw.nis_per_row)}
    if len(rw.tried) > 1:                   # the walk's σ raised until its float held the motion
        out["random_walk_sigma_used_m_per_sqrt_s"] = list(rw.sigma_m_per_sqrt_s)
        out["random_walk_tried"] = [{"sigma_m_per_sqrt_s": list(sig), "nis_per_row": _nan_none(nis)}
                                    for sig, nis in rw.tried]
    return out


def _phase_check_record(res: dict) -> dict | None:
    """The integers' check by the phases alone (:func:`~.static_engine.fixed_phase_check`) with its thresholds, or
    None when it could not judge them."""
    check = res.get("phase_check")
    if check is None:
        return None
    return dict(check, threshold=FIXED_PHASE_UNIT_VARIANCE_MAX, window_s=FIXED_PHASE_WINDOW_S,
                window_threshold=FIXED_PHASE_WINDOW_UNIT_VARIANCE_MAX)


def _rejected_fix_record(res: dict, check: dict | None) -> dict:
    """INIT's ``float.rejected_fix``: how many integers were not taken, their ratio, and why (the phase check, or,
    with none possible, the float's NIS)."""
    why = ({"phase_check": check} if check is not None else
           {"float_nis_per_row": _nan_none(res.get("float_nis_per_row")), "float_nis_threshold": UNCHECKED_FIX_NIS_MAX})
    return {"n_integers": int(res["rejected_n_fixed"]), "ratio": _nan_none(res.get("ratio")),
            "rejected_by": res.get("rejected_by", "phase_check"), **why}


def _engine_solution(d: _Data, sg: _Segments, w: _Weights, eng: dict, xr0, r_enu, opt: BaselineOptions):
    """(float, fix, final) in this solver's forms from :func:`~cdgps_cli.estimation.static_engine.static_baseline`'s
    result ``eng`` (its float and fixed states and integers): the rendering (segment table, residuals,
    single-epoch positions) is this module's, every number solved is the engine's.  A string instead when
    the engine's arcs are not this solver's segments (the caller then solves here)."""
    cols = _engine_columns(d, sg, eng["arcs"])
    if isinstance(cols, str):
        return cols
    x, P, ai = eng["state"], eng["cov"], eng["arc_integers"]
    J = _datum_map(d, sg, cols, x.size)
    Jf = np.vstack([np.hstack([r_enu, np.zeros((3, x.size - 3))]), J[sg.free]])
    a_fl = J @ x
    q_fl = Jf @ P @ Jf.T
    x_fl = r_enu @ x[:3]
    g, r_ph, r_cd = _residuals(d, xr0 + r_enu.T @ x_fl, r_enu, a_fl, sg.seg, w)
    sq_ph, n_ph = _quad(w.blocks_ph, r_ph)
    sq_cd, n_cd = _quad(w.blocks_code, r_cd)
    dof = n_ph + n_cd - sg.n_par
    fl = _Float(x_fl, a_fl, q_fl, {"enu_m": x_fl.tolist(), "sigma_enu_m": np.sqrt(np.diag(q_fl)[:3]).tolist(),
                                   "iterations": 0, "unit_variance": (sq_ph + sq_cd) / dof if dof > 0 else None},
                g, r_ph, r_cd, n_cd)
    seg_int = ai[cols] - ai[cols[sg.pivots[sg.comp]]]                   # NaN unless both arcs are fixed
    fixed_mask = np.isfinite(seg_int[sg.free]) & ~_fdma_segments(d, sg)[sg.free]
    ints = np.where(fixed_mask, np.nan_to_num(seg_int[sg.free]), 0).astype(np.int64)
    res = eng["resolution"] or {}
    a_res, q_res = a_fl[sg.free], q_fl[3:, 3:]
    if eng.get("lambda_float") is not None:     # the float ambiguities LAMBDA saw (random walk, ionosphere-weighted)
        Ja = J[sg.free][:, 3:]
        a_res, q_res = Ja @ eng["lambda_float"][0], Ja @ eng["lambda_float"][1] @ Ja.T
    fl.block.update(_random_walk_notes(eng.get("random_walk"), opt))
    if eng.get("moving_rover") is not None:        # the float is the code's mean and the random walk's arcs
        fl.block["moving_rover"] = eng["moving_rover"]
    glo = np.where(_fdma_segments(d, sg) & np.isfinite(seg_int), seg_int, np.nan) if opt.glonass_fix else None
    fx = _Fix(a_res, q_res, fixed_mask, ints, _nan_none(res.get("ratio")),
              _nan_none(res.get("ratio_full_set")), bool(res.get("accepted", False)), bool(res.get("partial", False)),
              _nan_none(res.get("success_rate")), None if glo is None else np.isfinite(glo) & ~sg.is_pivot, glo)
    n_glo = int(fx.glonass_fixed.sum()) if fx.glonass_fixed is not None else 0     # GLONASS DDs fixed too
    n_fixed = int(fixed_mask.sum())
    check = _phase_check_record(res)
    if res.get("rejected_n_fixed"):
        fl.block["rejected_fix"] = _rejected_fix_record(res, check)
    if not n_fixed + n_glo:
        a_sig = np.zeros(sg.n_seg)
        a_sig[sg.free] = np.sqrt(np.diag(q_fl)[3:])
        return fl, fx, _Final(None, x_fl, "float", a_fl, sg.is_pivot.copy(), q_fl[:3, :3], g, r_ph, a_sig)
    xf, Pf = eng["state_fixed"], eng["cov_fixed"]
    a_fix = J @ xf
    known = sg.is_pivot.copy()
    known[sg.free[fixed_mask]] = True
    a_fix[sg.free[fixed_mask]] = ints[fixed_mask]
    a_fix[sg.is_pivot] = 0.0
    x_fix = r_enu @ xf[:3]
    q3 = r_enu @ Pf[:3, :3] @ r_enu.T
    g, r_ph, _ = _residuals(d, xr0 + r_enu.T @ x_fix, r_enu, a_fix, sg.seg, w, code=False)
    if known.all():      # every ambiguity known: the covariance as estimate evaluates INIT's solution (phase only)
        nmat, _ = _accumulate(w.blocks_ph, g, r_ph, np.full(sg.seg.size, -1, dtype=np.int64), 3, _lam(d))
        q3 = cho_solve(cho_factor(nmat), np.eye(3))
    sq, n_dd = _quad(w.blocks_ph, r_ph)
    dof = n_dd - 3 - int(np.sum(~known))
    block = {"enu_m": x_fix.tolist(), "sigma_enu_m": np.sqrt(np.diag(q3)).tolist(), "iterations": 0,
             "unit_variance": sq / dof if dof > 0 else None,
             "observations": ("L1 carrier phase only" if getattr(d, "group", None) is None
                              else f"carrier phase only ({', '.join(d.group_names)})"),
             **({"phase_check": check} if check is not None else {})}
    fdma = _fdma_segments(d, sg)[sg.free]
    kind = ("fixed" if n_fixed + n_glo == int(np.sum(~fdma)) + (int(fdma.sum()) if opt.glonass_fix else 0)
            else "partially fixed")
    a_sig = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, Pf, J), 0.0))
    a_sig[known] = 0.0
    piv_arc = None
    if glo is not None and np.isfinite(glo).any():     # what estimate needs to evaluate the GLONASS values again
        piv_arc = np.full(sg.n_seg, np.nan)
        fdma_piv = _fdma_segments(d, sg) & sg.is_pivot
        piv_arc[fdma_piv] = xf[cols[fdma_piv]]
    return fl, fx, _Final(block, x_fix, kind, a_fix, known, q3, g, r_ph, a_sig, piv_arc)


def _starts_with(values: np.ndarray, prefix: str) -> np.ndarray:
    """``Series(values).astype(str).str.startswith(prefix)`` (a missing value: False) with the test made
    once per distinct value (a day's table of a few dozen satellites: 1 M rows, 0.08 s instead of 0.34)."""
    codes, distinct = pd.factorize(values)
    hit = np.array([str(v).startswith(prefix) for v in distinct] + [False], dtype=bool)
    return hit[codes]                                     # code −1 (missing) takes the appended False


def l1_signal_table(obs: pd.DataFrame) -> pd.DataFrame:
    """GPS L1 rows of an :data:`~cdgps_cli.core.records.OBS_COLUMNS` table (those with a phase) as a signal
    table (:data:`~cdgps_cli.io.rinex_signals.SIGNAL_COLUMNS`, signal ``G:L1``): the engine's input for the
    observations this solver uses without signal tables."""
    o = obs[np.isfinite(obs["phase_l1_cycles"].to_numpy()) & _starts_with(obs["sat"].to_numpy(), "G")]
    return pd.DataFrame({"time_gps_s": o["time_gps_s"].to_numpy(dtype=np.float64), "sat": o["sat"].to_numpy(),
                         "signal": "G:L1", "phase_cycles": o["phase_l1_cycles"].to_numpy(dtype=np.float64),
                         "pseudorange_m": o["pseudorange_l1_m"].to_numpy(dtype=np.float64),
                         "lli": np.nan_to_num(o["lli_l1"].to_numpy(dtype=np.float64)).astype(np.int64),
                         "wavelength_m": GPS_L1_WAVELENGTH_M})


def _run_engine(master: Station, rover: Station, nav, opt: BaselineOptions, xm, xr0,
                iono_threshold_km, arcs_check=None, segment_starts=None) -> dict | str:
    """:func:`~cdgps_cli.estimation.static_engine.static_baseline` on the two receivers' signal tables (their
    GPS L1 rows without them), or the reason (a string) it cannot serve these options or (``arcs_check``,
    before solving) these arcs.  ``segment_starts``: a given solution's segments (INIT's), where the engine cuts its
    arcs instead of searching for slips no receiver flagged."""
    from cdgps_cli.estimation.rtk_multi import receiver_geometry
    from cdgps_cli.estimation.static_engine import options_from_baseline, static_baseline
    from dataclasses import replace
    render = {"kinematic_series": False, "min_sats_kinematic": BaselineOptions.min_sats_kinematic,
              "kinematic_max_pdop": BaselineOptions.kinematic_max_pdop}     # this module's rendering, not the engine's
    try:
        eopt = options_from_baseline(replace(opt, **render))
    except CdgpsError as exc:
        return str(exc).replace("static baseline: ", "")
    eopt["iono_threshold_km"] = math.inf if iono_threshold_km is None else iono_threshold_km
    if segment_starts is not None:
        eopt["segment_starts"] = list(segment_starts)
    tables = [_engine_table(master, rover, st) for st in (master, rover)]
    t_m, t_r = tables
    del tables
    # the master's geometry beside the rover's (a second core); each signal table dropped once its
    # geometry is built (the master's stays in this process only while a child computes it)
    geo = list(beside.both(lambda: receiver_geometry(t_m, nav, xm), lambda: receiver_geometry(t_r, nav, xr0)))
    del t_m, t_r
    if rover.troposphere_xyz_m is not None and opt.troposphere:
        from cdgps_cli.estimation.rtk_multi import troposphere_at_epochs
        t_ep = np.unique(geo[1]["time_gps_s"].to_numpy())
        geo[1] = troposphere_at_epochs(geo[1], t_ep, np.tile(np.asarray(rover.troposphere_xyz_m, float), (t_ep.size, 1)))
    # the tables handed over (not held here): static_baseline releases them once its SD rows are built
    return static_baseline(geo.pop(0), geo.pop(0), xm, xr0, eopt, arcs_check=arcs_check)


def _engine_table(master: Station, rover: Station, st: Station) -> pd.DataFrame:
    """The signal table the static engine takes of receiver ``st`` (one of ``master``, ``rover``): its signals when
    both receivers have them, else its GPS L1 rows (:func:`l1_signal_table`)."""
    return (st.signals if st.signals is not None and master.signals is not None and rover.signals is not None
            else l1_signal_table(st.obs))


def _engine_first(master: Station, rover: Station, nav, opt: BaselineOptions, xm, xr0, iono_threshold_km,
                  prepared):
    """:func:`_run_engine` before this module's batch tables exist: ``prepared()`` (:func:`_prepare`, the segments
    and weights) is first called by the engine's arc check, once the engine has released its receiver geometry
    (the peak of a long record's ``init``: ≈ 620 MiB on the 24 h pair) and holds only its SD rows, instead of
    the tables (≈ 310 MiB) being built before and held beside that geometry; arcs that are not the segments
    still stop it before it solves.  Returns its result (state, covariance, arc table, integers: small), the
    reason it cannot serve (a string), or the CdgpsError it raised (not :func:`_prepare`'s): raised by
    :func:`_engine_or_batch` once :func:`_prepare` has run, whose messages on bad input come first, as before."""
    def check(arcs):
        prepared.add_slips(arcs["unflagged_slips"])        # the engine's finds start segments here too
        return _engine_columns(*prepared(weights=False)[:2], arcs)

    try:
        return _run_engine(master, rover, nav, opt, xm, xr0, iono_threshold_km, arcs_check=check,
                           segment_starts=prepared.segment_starts)
    except CdgpsError as exc:
        if getattr(exc, "from_prepare", False):        # the batch tables' own message: passed on as it is
            raise
        return exc


def _engine_or_batch(master: Station, rover: Station, nav, opt: BaselineOptions, xm, xr0, iono_threshold_km,
                     prepared: tuple, engine: bool, solved=None, warnings: list | None = None):
    """((float, fix, final) of the static engine, "static_engine"), or (None, "batch (reason)") when the batch
    solver is to serve (engine not asked for, an option only the batch implements, arcs that are not the segments).
    ``solved``: :func:`_engine_first`'s answer (the engine already ran; arcs that are not the segments are then
    found after its solve), else the engine runs here, its arcs checked before it solves."""
    if not engine:
        return None, "batch (engine not asked for)"
    d, sg, w, r_enu = prepared
    if isinstance(solved, CdgpsError):
        raise solved
    # arcs that are not the segments are known before the engine solves: no solve to throw away
    eng = solved if solved is not None else _run_engine(master, rover, nav, opt, xm, xr0, iono_threshold_km,
                                                        arcs_check=lambda arcs: _engine_columns(d, sg, arcs))
    known = eng if isinstance(eng, str) else _engine_solution(d, sg, w, eng, xr0, r_enu, opt)
    if warnings is not None and not isinstance(eng, str):
        warnings += (_rejected_fix_warning(eng.get("resolution")) + _random_walk_misfit_warning(eng)
                     + _code_step_warning(eng.get("code_clock_steps")))
    return (None, f"batch ({known})") if isinstance(known, str) else (known, "static_engine")


def _unflagged_slip_warning(events: dict | None) -> list:
    """The warning naming the slips no receiver flagged that the engine found (a new ambiguity from each)."""
    if not events:
        return []
    return unflagged_slip_text(events["sat"], events["signal"], events["time_s"])


def _code_step_warning(steps: dict | None) -> list:
    """The warning naming the steps of the SD codes that the phases did not take (a receiver clock jump in the
    codes alone, :func:`~cdgps_cli.measurement.code_steps.code_clock_steps`), which the engine took out."""
    if not steps:
        return []
    from cdgps_cli.measurement.code_steps import code_steps_warning
    return code_steps_warning(steps["step_m"], steps["signal"], steps["time_s"])


def _random_walk_misfit_warning(eng: dict) -> list:
    """The warning for a random-walk float that did not hold at the configured σ (NIS per row above
    :data:`~cdgps_cli.config.options.UNCHECKED_FIX_NIS_MAX`): what raising σ gave, or that it did not help."""
    rw, res = eng.get("random_walk"), eng.get("resolution") or {}
    if rw is None or len(rw.tried) < 2:
        return []
    (sig0, nis0), sig, nis = rw.tried[0], rw.sigma_m_per_sqrt_s, rw.nis_per_row
    head = (f"init's random-walk float at [gnss.displacement] sigma_m_per_sqrt_s {_sigma_text(sig0)} m/sqrt(s) leaves "
            f"a NIS of {nis0:.3g} per row (about 1 when its model holds; above {UNCHECKED_FIX_NIS_MAX:g} its sigma "
            f"is too small by about as much): ")
    if tuple(sig) == tuple(sig0):
        why = ("" if res.get("rejected_by") == "float_nis" else
               "; its integers were judged by the phases alone")
        return [head + f"raising sigma to {_sigma_text(rw.tried[-1][0])} m/sqrt(s) did not lower it "
                       f"({rw.tried[-1][1]:.3g}), so the misfit is not the rover's motion (a code or phase blunder, noise "
                       f"the weights do not describe); the float was kept at the configured sigma{why}"]
    if nis > UNCHECKED_FIX_NIS_MAX:
        return [head + f"it did not hold the rover's motion; raised to {_sigma_text(sig)} m/sqrt(s) the NIS is still "
                       f"{nis:.3g}, and the float's integers and sigma are doubtful"]
    return [head + f"it did not hold the rover's motion; LAMBDA saw its float at {_sigma_text(sig)} m/sqrt(s) (NIS "
                   f"{nis:.3g}). Set sigma_m_per_sqrt_s near {_sigma_text(sig)} so that init need not raise it (a "
                   f"random_walk model's states in estimate use it too; a constant_velocity model's do not)"]


def _sigma_text(sigma) -> str:
    """A walk's σ (3,) as one number when its components are equal."""
    v = [float(x) for x in sigma]
    return f"{v[0]:g}" if len(set(v)) == 1 else "/".join(f"{x:g}" for x in v)


def _rejected_fix_warning(res: dict | None) -> list:
    """The warning for integers the engine rejected (:func:`~.static_engine.fixed_integers_rejected`): by the
    phase check (:func:`~.static_engine.fixed_phase_check`), or, unchecked, by the random-walk float's NIS."""
    if not res or not res.get("rejected_n_fixed"):
        return []
    if res.get("rejected_by") == "float_nis":
        return [f"{res['rejected_n_fixed']} integers passed LAMBDA (ratio {res['ratio']:.1f}) and were not taken: no "
                f"epoch has phases of their arcs to spare to judge them, and the random-walk float they came from "
                f"does not fit its data (NIS {res['float_nis_per_row']:.3g} per row, above {UNCHECKED_FIX_NIS_MAX:g}; "
                f"about 1 when it fits), so its sigma, which LAMBDA's ratio and success rate trust, is too small by "
                f"about as much; the solution is float"]
    chk = res["phase_check"]
    win = chk.get("window_unit_variance")
    worst = "" if win is None else f", {win:.3g} in its worst {FIXED_PHASE_WINDOW_S:g} s"
    return [f"{res['rejected_n_fixed']} integers passed LAMBDA (ratio {res['ratio']:.1f}) and were rejected: with them "
            f"each epoch's carrier phases, solved alone for a position, leave a unit variance of "
            f"{chk['unit_variance']:.3g} over {chk['n_dd']} DDs in {chk['epochs']} epochs{worst} (above "
            f"{FIXED_PHASE_UNIT_VARIANCE_MAX:g} over the record or {FIXED_PHASE_WINDOW_UNIT_VARIANCE_MAX:g} in a "
            f"window; about 1 when they are right): the float was biased beyond its sigma (correlated code multipath, "
            f"the ionosphere, a cycle slip the receiver did not flag); the solution is float"]


def _given_glonass(given: dict, d: _Data, sg: _Segments, rover: str) -> tuple[np.ndarray, np.ndarray]:
    """The GLONASS DD integers given (INIT's of a glonass_fix solution, ``{(satellite, first epoch s): {"dd",
    "channel", "reference", "pivot"}}`` for every GLONASS segment, ``dd`` None where not fixed) on these data's
    FDMA segments: (segments (m,), their integers N_i − N_p (m,), own cycles against the datum pivot p).

    Raises CdgpsError ``INIT.json: …`` naming what does not match: a GLONASS segment without an entry or an
    entry without a segment, another FDMA channel, another reference (datum pivot)."""
    keys = _segment_keys(d, sg)
    here = {keys[k]: int(k) for k in np.flatnonzero(_fdma_segments(d, sg))}
    init = _keyed(given)
    bad = [f"no entry for {n} from {gps_time_str(t)}" for n, t in here if (n, t) not in init]
    bad += [f"an entry for {n} from {gps_time_str(t)}, which these data do not have" for n, t in init if (n, t) not in here]
    sig = _satellite_signals(d)
    segs, ints = [], []
    for (n, t), k in here.items():
        v = init.get((n, t))
        if v is None:
            continue
        s, p = int(sg.segtab["sat"][k]), int(sg.pivots[sg.comp[k]])
        ch, ref = fdma_channel(sig[s]["signal"], sig[s]["wavelength_m"]), d.sat_names[int(sg.segtab["sat"][p])]
        if v["channel"] != ch:
            bad.append(f"{n} from {gps_time_str(t)} has FDMA channel {v['channel']} in INIT, {ch} in this run")
        if v["reference"] != ref or bool(v["pivot"]) != bool(sg.is_pivot[k]):
            bad.append(f"{n} from {gps_time_str(t)} is against {v['reference']} in INIT, {ref} in this run")
        if v["dd"] is not None and not sg.is_pivot[k]:
            segs.append(k)
            ints.append(v["dd"])
    if bad:
        raise CdgpsError(f"INIT.json: the GLONASS integers (dd_integer_cycles) of {rover} do not match this run's "
                         f"{len(here)} GLONASS segments: {'; '.join(bad[:5])}"
                         + (f" (and {len(bad) - 5} more)" if len(bad) > 5 else ""))
    return np.array(segs, dtype=np.int64), np.array(ints, dtype=np.int64)


def _engine_float(master: Station, rover: Station, nav, opt: BaselineOptions, xm, xr0, prepared, check=None,
                  segment_starts=None):
    """The static engine's float solution (static, nothing fixed) and its state column of every SD segment:
    (:func:`_run_engine`'s result, columns (n_seg,)), or the reason (a string) the engine cannot serve these
    options or arcs.  ``prepared()`` (this module's batch tables, built once) is first called from the engine's arc
    check, once the engine has released its receiver geometry (as :func:`_engine_first`); ``check(d, sg)``, when
    given, then runs there, before the filter (a CdgpsError of the given integers stops it before it solves).
    ``segment_starts``: the given integers' segments (:func:`_run_engine`)."""
    from dataclasses import replace
    found = {}

    def arcs_check(arcs):
        d, sg = prepared(weights=False)[:2]
        if check is not None:
            check(d, sg)
        found["cols"] = _engine_columns(d, sg, arcs)
        return found["cols"]

    # the float only (a random-walk float would only feed LAMBDA, which does not run here)
    eng = _run_engine(master, rover, nav, replace(opt, fix=False, motion="static"), xm, xr0, None, arcs_check=arcs_check,
                      segment_starts=segment_starts)
    return eng if isinstance(eng, str) else (eng, found["cols"])


def _engine_given(master: Station, rover: Station, nav, opt: BaselineOptions, xm, xr0, prepared: tuple,
                  integers: dict, glonass: tuple | None = None, solved=None):
    """(float, fix, final) of the static engine's float solution conditioned on the given integers (each fixed
    segment's DD against its datum pivot, and ``glonass``'s (segments, integers) from :func:`_given_glonass`,
    the GLONASS DDs N_i − N_p in cycles, :func:`~cdgps_cli.estimation.static_engine.condition_on_integers`), or
    the reason (a string) the engine cannot serve these options or arcs.  Nothing is resolved: no LAMBDA.
    ``solved``: :func:`_engine_float`'s answer when the engine already ran before ``prepared`` existed (or the
    CdgpsError it raised, raised here), else it runs here."""
    from cdgps_cli.estimation.static_engine import condition_on_integers
    d, sg, w, r_enu = prepared
    fixed_mask = np.zeros(sg.free.size, dtype=bool)
    integers_fix = np.zeros(sg.free.size, dtype=np.int64)
    _given_integers(integers, d, sg, fixed_mask, integers_fix)
    if isinstance(solved, CdgpsError):
        raise solved
    eng = solved if solved is not None else _engine_float(master, rover, nav, opt, xm, xr0,
                                                          lambda weights=True: prepared, segment_starts=list(integers))
    if isinstance(eng, str):
        return eng
    (eng, cols), x, P = eng, eng[0]["state"], eng[0]["cov"]
    segs = sg.free[fixed_mask]
    g_segs, g_ints = glonass if glonass is not None else (np.zeros(0, dtype=np.int64),) * 2
    D_glo = np.zeros((g_segs.size, x.size))                 # N_i − N_p: each arc in its own cycles
    D_glo[np.arange(g_segs.size), cols[g_segs]] = 1.0
    D_glo[np.arange(g_segs.size), cols[sg.pivots[sg.comp[g_segs]]]] = -1.0
    x_fix, P_fix = condition_on_integers(x, P, np.vstack([_datum_map(d, sg, cols, x.size)[segs], D_glo]),
                                         np.r_[integers_fix[fixed_mask], g_ints])
    ai = np.full(x.size, np.nan)
    ai[cols[sg.is_pivot]] = 0.0
    ai[cols[segs]] = integers_fix[fixed_mask]
    ai[cols[g_segs]] = g_ints
    eng = dict(eng, state_fixed=x_fix, cov_fixed=P_fix, arc_integers=ai,
               resolution={"accepted": bool(fixed_mask.any() or g_segs.size), "partial": False})
    return _engine_solution(d, sg, w, eng, xr0, r_enu, opt)


def _engine_needed_first(integers: dict, solution: dict | None, engine_init: bool, glonass_integers) -> bool:
    """Whether :func:`baseline_from_init` will condition the engine's float on the integers (so that the engine is
    run before the batch tables are built): a glonass_fix INIT, or an engine INIT that leaves a segment float or has
    no fixed position (INIT's fully fixed solution is evaluated at its position instead).  Only the order depends
    on it: when it guesses wrong the engine runs where it did before (or runs unused), the result the same."""
    if solution is not None and solution.get("enu_m") is not None and solution.get("cov_enu_m2") is not None \
            and solution.get("solution_cycles") and (glonass_integers is None or solution.get("pivot_arc_cycles")):
        return False                    # a partially fixed INIT with its float segments' values: evaluated
    if glonass_integers is not None:
        return True
    fully_fixed = (solution is not None and solution.get("enu_m") is not None
                   and all(v is not None for v in integers.values()))
    return engine_init and not fully_fixed


def baseline_from_init(master: Station, rover: Station, nav: pd.DataFrame, options: BaselineOptions, *,
                       integers: dict, solution: dict | None, engine_init: bool, master_xyz=None, rover_xyz=None,
                       keep_work: bool = True, glonass_integers: dict | None = None) -> dict:
    """The static baseline of a solution made before (``cdgps estimate`` on INIT's): nothing is resolved and the
    batch normal equations do not solve (issue 28 item 1).

    In this order: every ambiguity given an integer → the solution evaluated at ``solution["enu_m"]``
    (:func:`_known_solution`); ``engine_init`` (the solution is the static engine's) → the engine's float solution
    conditioned on the given integers (the remaining floats solved with them, as ``init`` did); otherwise the
    given position with the float ambiguities at it (phase only, as the batch's fixed solution); the other of the
    last two when one cannot serve (options only the batch implements, a position that is not the solution of
    the integers on these data); else :class:`CdgpsError`.  Parameters and result as
    :func:`solve_static_baseline`'s (``integers``, ``solution``: the same forms); ``solver`` says which served.
    ``glonass_integers`` (a glonass_fix INIT's GLONASS DD integers, :func:`_given_glonass`'s form): the engine
    conditions on them too, and only the engine may serve (the other ways keep GLONASS float).
    """
    tol = ENGINE_SOLUTION_TOL_M if engine_init else _KNOWN_SOLUTION_TOL_M
    solved = {}

    def check(d, sg):           # what decide checks before the engine serves: mismatches stop it before it solves
        if glonass_integers is not None:
            _given_glonass(glonass_integers, d, sg, rover.name)
        _given_integers(integers, d, sg, np.zeros(sg.free.size, dtype=bool), np.zeros(sg.free.size, dtype=np.int64))

    def first(xm, xr0, prepared):    # the engine's geometry released before the batch tables are built
        if _engine_needed_first(integers, solution, engine_init, glonass_integers):
            try:
                solved["engine"] = _engine_float(master, rover, nav, prepared.opt, xm, xr0, prepared, check,
                                                 segment_starts=list(integers))
            except CdgpsError as exc:
                if getattr(exc, "from_prepare", False):     # the batch tables' own message: passed on as it is
                    raise
                solved["engine"] = exc              # raised where the engine would have run (decide's checks first)

    def decide(prepared, xm, xr0, warnings, opt):
        d, sg, w, r_enu = prepared
        glo = None if glonass_integers is None else _given_glonass(glonass_integers, d, sg, rover.name)
        fixed = solution is not None and solution.get("enu_m") is not None
        if fixed:
            known = _known_solution(d, sg, w, integers, solution, xr0, r_enu, warnings, tol)
            if known is not None:
                return known, "given (INIT's solution)"
            known = (_given_solution(d, sg, w, integers, solution, xr0, r_enu, warnings, glo)
                     if glo is None or _glonass_values_agree(d, sg, solution, glo) else None)
            if known is not None:
                return known, "given (INIT's solution, its float ambiguities too)"

        def at_position():
            if fixed:
                k = _known_solution(d, sg, w, integers, solution, xr0, r_enu, [], tol, floats=True)
                return "the given position is not the solution of its integers" if k is None else k
            if solution is None or solution.get("float_enu_m") is None:
                return "no position given"
            _given_integers(integers, d, sg, np.zeros(sg.free.size, dtype=bool), np.zeros(sg.free.size, dtype=np.int64))
            k = _known_float(d, sg, w, solution["float_enu_m"], xr0, r_enu, max(tol, _FLOAT_STOP_M))
            return "the given float position is not the float solution of these data" if k is None else k
        tries = [("static_engine (integers given)", lambda: _engine_given(master, rover, nav, opt, xm, xr0,
                                                                           prepared, integers, glo,
                                                                           solved.pop("engine", None))),
                 ("given (INIT's position, float ambiguities at it)", at_position)]
        why = []
        for name, f in (tries[:1] if glo is not None else tries if engine_init else tries[::-1]):
            known = f()
            if not isinstance(known, str):
                return known, name
            why.append(known)
        raise CdgpsError(f"INIT.json: the solution of {rover.name} cannot be used on these data without solving "
                         f"the baseline again ({'; '.join(why)}); run 'cdgps init' again")

    return _baseline(master, rover, nav, options, master_xyz, rover_xyz, keep_work, None, decide, integers, first)


def solve_static_baseline(master: Station, rover: Station, nav: pd.DataFrame, options: BaselineOptions | None = None,
                          **kwargs) -> dict:
    """Static baseline from two receivers' RINEX observations (see the module docstring); parameters and
    result as :func:`_solve_static_baseline_once`, whose docstring holds them.

    The rover's troposphere is first evaluated at its a-priori position (``rover_xyz``, the RINEX header's
    APPROX POSITION XYZ or a single-point position).  When the solution lies more than
    :data:`~cdgps_cli.config.options.ROVER_ORIGIN_TOL_M` from it, the baseline is solved again with the
    rover's delay at that solution (``rover.troposphere_xyz_m``; about 0.8 mm of height per metre
    otherwise), the a-priori position staying the origin of the reported offsets; the result's
    ``rover_troposphere_ecef_m`` then says where, and a warning why.
    """
    from cdgps_cli.config.options import ROVER_ORIGIN_TOL_M

    res = _solve_static_baseline_once(master, rover, nav, options, **kwargs)
    opt = options or BaselineOptions()
    sol, apriori = res.get("rover_ecef_m"), res.get("rover_apriori_ecef_m")
    if (not opt.troposphere or rover.troposphere_xyz_m is not None or sol is None or apriori is None
            or not np.all(np.isfinite(sol)) or np.linalg.norm(np.subtract(sol, apriori)) <= ROVER_ORIGIN_TOL_M):
        return res
    moved = np.subtract(sol, apriori)
    lat, lon, _ = ecef_to_geodetic(np.asarray(apriori, dtype=np.float64))
    up = float(enu_matrix(lat, lon)[2] @ moved)
    res = _solve_static_baseline_once(master, rover._replace(troposphere_xyz_m=np.asarray(sol, dtype=np.float64)), nav,
                                      options, **kwargs)
    res["warnings"].append(f"{rover.name}: the solution is {np.linalg.norm(moved):.1f} m from the a-priori position "
                           f"({res['rover_apriori_source']}; height {up:+.1f} m), more than {ROVER_ORIGIN_TOL_M:g} m: "
                           f"solved again with its troposphere at the first solution")
    res["rover_troposphere_ecef_m"] = [float(v) for v in sol]
    return res


def _solve_static_baseline_once(master: Station, rover: Station, nav: pd.DataFrame, options: BaselineOptions | None = None,
                          *, master_xyz=None, rover_xyz=None, integers: dict | None = None,
                          solution: dict | None = None,
                          keep_work: bool = False, iono_threshold_km: float | None = None,
                          engine: bool = False, solution_tol_m: float = _KNOWN_SOLUTION_TOL_M) -> dict:
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
    solution : dict, optional
        With ``integers``: the fixed solution they belong to (e.g. INIT's), ``{"enu_m": (3,),
        "float_cycles": {(sat, first_epoch_gps_s): (float value, σ) cycles}}`` (the second only for the
        segment table).  When every ambiguity is given an integer (no float segment, no GLONASS), the
        solution is evaluated at ``enu_m`` — design, residuals and covariance for the estimators —
        without a float solution, LAMBDA or iterations: the states then are INIT's static solution
        exactly (``cdgps estimate`` does not solve the baseline again).  Otherwise the fixed solution
        is solved from the integers as without it.
    keep_work : bool
        Also return the internal arrays under ``"_work"`` (not JSON: SD rows, geometry,
        ambiguities, weights, single-epoch solutions), for the GNSS pipeline's estimators.
    iono_threshold_km : float, optional
        With both stations' signal tables: refuse a baseline (master to rover a priori) at least
        this long, km, since the DD ionosphere is neglected (:func:`check_iono_rule`).  None: no check.
    engine : bool
        Solve on the static engine (:func:`~cdgps_cli.estimation.static_engine.static_baseline`) and render its
        numbers here; the batch below serves when the options or data need it (the result's ``solver`` says which).
    solution_tol_m : float
        With ``solution``: how far (m) one least-squares step may move it and it still be taken as given.

    Returns
    -------
    dict
        JSON-ready result: ``states`` (``<rover>_e/_n/_u`` of the reported solution, m),
        ``solution`` ("fixed", "partially fixed" or "float"), ``float`` / ``fixed`` blocks
        (ENU displacement, 1σ, ECEF position, baseline from the master), ``ambiguities``
        (counts, ratio, acceptance, per-segment table), ``residuals`` (DD phase RMS),
        ``kinematic`` (single-epoch scatter), ``epochs``, ``satellites``, ``warnings``,
        ``options``, ``solver`` ("static_engine" or "batch (reason)"), ``timing_s``.

    Raises
    ------
    CdgpsError
        Missing phase, missing master position, navigation data not covering the span, no
        common epochs or satellites, singular normal equations.
    """
    solved = {}

    def first(xm, xr0, prepared):    # the engine's geometry released before the batch tables are built
        if engine and integers is None:
            solved["engine"] = _engine_first(master, rover, nav, prepared.opt, xm, xr0, iono_threshold_km, prepared)

    def decide(prepared, xm, xr0, warnings, opt):
        d, sg, w, r_enu = prepared
        if integers is None:
            return _engine_or_batch(master, rover, nav, opt, xm, xr0, iono_threshold_km, prepared, engine,
                                    solved.pop("engine", None), warnings)
        return (None if solution is None else _known_solution(d, sg, w, integers, solution, xr0, r_enu, warnings,
                                                              solution_tol_m)), "batch (integers given)"

    opt = options or BaselineOptions()
    return _baseline(master, rover, nav, opt, master_xyz, rover_xyz, keep_work, iono_threshold_km, decide, integers,
                     first)


class _BatchTables:
    """:func:`_baseline`'s batch tables (data, segments, weights, r_enu), built once when first called (``prepare()``:
    :func:`_prepare`'s data); a CdgpsError of it raised again on each call, marked ``from_prepare``.  A call with
    ``weights=False`` (the engine's arc check) leaves the weights (≈ 130 bytes an SD row) unbuilt (None) until asked
    for, so they are not held beside the engine's solve.  ``t_prep``: the seconds spent building them."""

    def __init__(self, prepare, opt: BaselineOptions, r_enu):
        self._prepare, self._opt, self._r_enu = prepare, opt, r_enu
        self._tables, self._error, self.t_prep = None, None, 0.0
        self._slips, self._starts = None, []

    def add_slips(self, events: dict) -> None:
        """Slips no receiver flagged that the static engine found (``sat``, ``signal``, ``time_s`` arrays,
        :func:`~cdgps_cli.estimation.static_engine.unflagged_slips`): each starts a segment here too, so that
        the segments stay the engine's arcs (the tables built again if they already were)."""
        self._slips = events if len(events["sat"]) else None
        if self._tables is not None and self._slips is not None:
            d = self._tables[0]
            _mark_slips(d, self._slips)
            self._tables = (d, _segments(d, self._opt), None, self._r_enu)

    def start_segments_at(self, keys) -> None:
        """Segments also start where the given integers' do (``{(satellite, first s): …}``, INIT's): arcs INIT cut
        at slips no receiver flagged (:meth:`add_slips`) are these data's segments too.  Before the tables are built."""
        self._starts = list(keys)

    def slip_warnings(self) -> list:
        """The warning naming the slips :meth:`add_slips` put here (whichever solver then serves)."""
        return _unflagged_slip_warning(self._slips)

    @property
    def opt(self) -> BaselineOptions:
        """The options the tables are built with (the age σ resolved, :func:`_with_age_noise`)."""
        return self._opt

    @property
    def segment_starts(self):
        """The given segments' (satellite, first s) (:meth:`start_segments_at`), or None when none were given."""
        return self._starts if self._starts else None

    def __call__(self, weights: bool = True) -> tuple:
        if self._error is not None:
            raise self._error
        if self._tables is None:
            t0 = time.perf_counter()
            try:
                d = self._prepare()
            except CdgpsError as exc:
                exc.from_prepare = True
                self._error = exc
                raise
            self.t_prep += time.perf_counter() - t0
            if self._slips is not None:
                _mark_slips(d, self._slips)
            sg = _segments(d, self._opt)
            if self._starts:                 # only the given starts that are no segment's start here (INIT's cuts)
                have = set(_segment_keys(d, sg))
                new = [k for k in _keyed(dict.fromkeys(self._starts)) if k not in have]
                if new:
                    _mark_segment_starts(d, new)
                    sg = _segments(d, self._opt)
            self._tables = (d, sg, None, self._r_enu)
        d, sg, w, _ = self._tables
        if weights and w is None:
            t0 = time.perf_counter()
            self._tables = (d, sg, _weights(d, self._opt), self._r_enu)
            self.t_prep += time.perf_counter() - t0
        return self._tables


def _mark_slips(d: _Data, events: dict) -> None:
    """Set ``d.slip`` at the rows of ``events`` (``sat``, ``signal``, ``time_s``: the epoch nearest each time)."""
    sig = _satellite_signals(d)
    name = {(d.sat_names[s].split(":")[0], sig[s]["signal"] if sig else "G:L1"): d.sat_names[s]
            for s in range(len(d.sat_names))}
    _mark_segment_starts(d, [(name.get((str(a), str(b)), ""), t)
                             for a, b, t in zip(events["sat"], events["signal"], events["time_s"])])


def _mark_segment_starts(d: _Data, keys) -> None:
    """Set ``d.slip`` at the row of each (satellite as ``d.sat_names`` names it, time s: the epoch nearest it), so a
    segment starts there."""
    keys = list(keys)
    if not keys or not d.sat.size:
        return
    index = {n: s for s, n in enumerate(d.sat_names)}
    epoch = _engine_epochs(d.t_label, np.array([float(t) for _, t in keys]))
    sat = np.array([index.get(str(k[0]), -1) for k in keys], dtype=np.int64)
    ok = (sat >= 0) & (epoch >= 0)
    n_ep = d.t_label.size
    key = d.sat.astype(np.int64) * n_ep + d.epoch
    order = np.argsort(key, kind="stable")
    want = sat[ok] * n_ep + epoch[ok]
    at = np.minimum(np.searchsorted(key[order], want), key.size - 1)
    hit = key[order][at] == want
    d.slip[order[at[hit]]] = True


def _baseline(master: Station, rover: Station, nav: pd.DataFrame, opt: BaselineOptions, master_xyz, rover_xyz,
              keep_work: bool, iono_threshold_km, decide, integers, first=None) -> dict:
    """:func:`solve_static_baseline`'s and :func:`baseline_from_init`'s body: ``decide(prepared, xm, xr0, warnings,
    opt)`` (``opt`` with its age σ resolved, :func:`_with_age_noise`) returns ((float, fix, final), solver) of a
    solution made elsewhere, or (None, solver): the batch below solves;
    ``first(xm, xr0, prepared)``, when given, runs before the batch tables are built (``prepared()`` builds them
    once, when first called; the time of ``first`` besides them counts as the solve's)."""
    t_start = time.perf_counter()
    opt.validate()
    warnings: list[str] = []
    xm, xr0, source = _a_priori_positions(master, rover, nav, master_xyz, rover_xyz, warnings)
    if iono_threshold_km is not None and _spans_meet(master, rover, opt.max_age_s):
        check_iono_rule(master.name, rover.name, float(np.linalg.norm(xr0 - xm)), iono_threshold_km)
    clock = [time.perf_counter()]

    def lap() -> float:
        clock.append(time.perf_counter())
        return clock[-1] - clock[-2]

    r_enu = enu_matrix(*ecef_to_geodetic(xr0)[:2])
    opt, age_noise = _with_age_noise(master, rover, nav, opt, xm)
    prepared = _BatchTables(lambda: _prepare(master, rover, nav, opt, xm, xr0, warnings), opt, r_enu)
    if integers is not None:
        prepared.start_segments_at(integers)

    t_first = 0.0
    if first is not None:
        first(xm, xr0, prepared)
        t_first = lap() - prepared.t_prep
    d, sg, w, _ = prepared()
    lap()
    t_prep = prepared.t_prep
    known, solver = decide((d, sg, w, r_enu), xm, xr0, warnings, opt)
    warnings += prepared.slip_warnings()
    if known is None and opt.glonass_fix:
        raise CdgpsError(f"glonass_fix: GLONASS integers are fixed by the static engine only, which cannot solve "
                         f"{rover.name} here: {solver}")
    if known is not None:
        fl, fx, fin = known
        t_float = t_lambda = 0.0
        t_fixed = lap() + t_first
    else:
        fl = _float_solution(d, sg, w, xr0, r_enu, opt)
        t_float = lap() + t_first             # with the engine's solve, when it ran first and the batch serves
        fx = _integer_fix(d, sg, w, fl, opt, integers, warnings)
        t_lambda = lap()
        fin = _fixed_solution(d, sg, w, fl, fx, xr0, r_enu, opt)
        t_fixed = lap()
    residuals = _residual_summary(d, w, fin.r_ph, fl.n_dd_code)
    _check_static_fit(opt, residuals, rover)
    ka = _single_epoch_positions(d, w, fin, sg.seg, opt) if fx.fixed_mask.any() else None
    kin = None if ka is None else _kinematic_summary(d, ka, fin.x, opt)
    t_kin = lap()
    ref_list, n_ref_changes = _reference_satellites(d, w.refs_ph)
    result = _result(master, rover, xm, xr0, source, r_enu, fl, fin)
    result.update({
        "ambiguities": _ambiguity_summary(sg, fx, opt, _segment_table(d, sg, fx, fin)),
        "residuals": residuals,
        "kinematic": kin,
        "epochs": dict(d.info, n_reference_changes=n_ref_changes, reference_satellites=ref_list, age_noise=age_noise),
        "satellites": _satellite_table(d, sg),
        "warnings": warnings,
        "options": asdict(opt),
        "solver": solver,
        "timing_s": {"prepare": t_prep, "float": t_float, "lambda": t_lambda, "fixed": t_fixed, "kinematic": t_kin,
                     "total": time.perf_counter() - t_start},
    })
    if keep_work:
        result["_work"] = _work(d, sg, w, fin, xr0, xm, r_enu, ka if kin is not None else None)
        # GLONASS segments whose DD integer a glonass_fix solution holds: known to the estimators too
        result["_work"]["glonass_known"] = (np.zeros(sg.n_seg, dtype=bool) if fx.glonass_fixed is None
                                            else np.asarray(fx.glonass_fixed, dtype=bool))
    return result


# ----------------------------------------------------------------------------------------------
# summaries
# ----------------------------------------------------------------------------------------------


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
    win = ep.get("time_window")
    if win is not None:
        lines.append(f"  rover epochs asked for: {win['window']} (--start-time / --end-time); "
                     f"{win['rover_epochs_outside']} of the rover's epochs are outside it")
    r = amb["ratio"]
    rtxt = "-" if r is None else (r if isinstance(r, str) else format(r, ".2f"))
    lines.append(f"  ambiguities: {amb['n_segments']} SD segments ({amb['n_pivots']} datum), {amb['n_fixed']} of "
                 f"{amb['n_estimated']} fixed, ratio {rtxt} "
                 f"(threshold {amb['ratio_threshold']:g})"
                 + (f", success rate {amb['success_rate']:.4f}" if amb.get("success_rate") is not None else "")
                 + f"{' partial' if amb['partial'] else ''} → {res['solution']}")
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
