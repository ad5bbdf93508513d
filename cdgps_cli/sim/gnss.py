"""``cdgps simulate-gnss``: a synthetic two-receiver GPS L1 recording written as RINEX files.

:func:`simulate_gnss_pair` runs :func:`~cdgps_cli.model.gps.positioning.simulate_static_pair` (receiver clocks with
millisecond-stepped time tags, troposphere, integer ambiguities with a fractional receiver bias,
cycle slips flagged by LLI on tracked arcs, phase noise following the estimator's default
elevation weighting, white code noise, C/N0 35 + 15·sin el dB-Hz) for a master at a known position and a
rover whose antenna is displaced from its nominal position — a constant displacement (static) or
a constant plus a random walk — and writes into one directory:

* ``<master>.rnx``, ``<rover>.rnx`` — RINEX 3.04 observation files (C1C L1C S1C), the header
  APPROX POSITION XYZ being the master's true and the rover's *nominal* position;
* ``nav.rnx`` — RINEX 3.04 GPS navigation file (the ephemerides the data were made with: a
  synthetic constellation, or the records of ``--nav``);
* ``truth.csv`` — ``time_s`` (GPS s of the nominal epochs) and the rover's true displacement
  ``<rover>_e_m``, ``<rover>_n_m``, ``<rover>_u_m`` (m, local east/north/up at the nominal position),
  with ``--constant-velocity`` also its true velocity ``<rover>_ve_m_s`` … (m/s, the same axes);
  the column names match the estimate's, so ``cdgps evaluate --truth DIR --estimate STATES.mcap``
  compares them;
* ``truth.json`` — positions, displacement model, slips, the integer ambiguities, settings;
* ``config.toml`` — a GNSS run config for the pair (``cdgps ingest --config DIR/config.toml``).

Same seed and settings → byte-identical files.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli import __version__
from cdgps_cli.io.atomic import output_set, write_atomic, write_bytes_atomic
from cdgps_cli.io.coordinate_columns import coordinate_column
from cdgps_cli.config.structure import GnssConfig, gnss_config_toml
from cdgps_cli.model.gps.orbits import MAX_EPHEMERIS_AGE_S, ecef_to_geodetic, enu_matrix
from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.gps.positioning import simulate_static_pair, synthetic_gps_nav
from cdgps_cli.config.limits import SIMULATION_START_RANGE, check_on_earth, check_table_size
from cdgps_cli.config.options import SIM_MASTER_ECEF_M
from cdgps_cli.core.gps_time import gps_seconds, gps_time_str
from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.io.rinex_write import rinex_calendar, write_rinex_nav, write_rinex_obs

__all__ = ["DEFAULT_MASTER_XYZ", "DEFAULT_ROVER_XYZ", "simulate_gnss_pair", "parse_start", "parse_vector"]

# the GEONET pair of docs/geonet.md (3.3 km apart): realistic positions for the default scenario
DEFAULT_MASTER_XYZ = SIM_MASTER_ECEF_M
DEFAULT_ROVER_XYZ = (-3976219.5082, 3382372.5671, 3652512.9849)


def parse_vector(text: str, what: str, n: int = 3) -> tuple:
    """"a,b,c" → floats (CdgpsError naming ``what`` if malformed)."""
    try:
        v = tuple(float(x) for x in str(text).split(","))
    except ValueError:
        v = ()
    if len(v) != n or not all(math.isfinite(x) for x in v):
        raise CdgpsError(f"{what} expects {n} comma-separated numbers, got {text!r}")
    return v


def check_simulation_start(start_gps_s: float) -> None:
    """Refuse a first epoch before GPS time 0 or after 2100 (``--start 1970-01-01`` gave negative GPS
    seconds and week numbers, silently; issue 32)."""
    lo, hi = (parse_start(d) for d in SIMULATION_START_RANGE)
    if not (math.isfinite(start_gps_s) and lo <= start_gps_s < hi):
        raise CdgpsError(f"--start {gps_time_str(start_gps_s) if math.isfinite(start_gps_s) else start_gps_s}: expected a GPS "
                         f"time from {SIMULATION_START_RANGE[0]} (GPS time 0) to before {SIMULATION_START_RANGE[1]}")


def parse_start(text: str) -> float:
    """``YYYY-MM-DD[THH:MM[:SS]]`` (GPS time) → GPS seconds."""
    import datetime as dt

    for fmt in ("%Y-%m-%dT%H:%M:%S", "%Y-%m-%dT%H:%M", "%Y-%m-%d %H:%M:%S", "%Y-%m-%d"):
        try:
            d = dt.datetime.strptime(text, fmt)
            return gps_seconds(d.year, d.month, d.day, d.hour, d.minute, d.second)
        except ValueError:
            continue
    raise CdgpsError(f"--start expects a GPS date/time YYYY-MM-DD or YYYY-MM-DDTHH:MM:SS, got {text!r}")


#: satellites a simulated receiver may track at once (GPS PRN 1-32), for the memory bound
GPS_PRN_SLOTS = 32
#: memory per epoch and receiver-satellite pair while simulating (geometry, observables, RINEX text),
#: bytes: an upper estimate for :func:`cdgps_cli.config.limits.check_table_size`
PAIR_BYTES_PER_VALUE = 100


#: the files every GNSS simulation writes besides one RINEX observation file per receiver
GNSS_SIMULATION_FILES = ("nav.rnx", "truth.csv", "truth.json", "config.toml")


def previous_simulation_files(out_dir: str | Path, kind: str) -> tuple[str, ...]:
    """The output set of an earlier GNSS simulation of ``kind`` in ``out_dir``, which a new one
    replaces as a whole: the fixed files and the RINEX files its truth.json names (another
    ``--master``/``--rover`` or receiver mapping wrote other ones)."""
    try:
        tj = json.loads((Path(out_dir) / "truth.json").read_text())
    except (OSError, ValueError):
        return GNSS_SIMULATION_FILES
    if not isinstance(tj, dict) or tj.get("kind") != kind:
        return GNSS_SIMULATION_FILES
    names = (tj.get("files") or {}).get("rinex") or {}
    names = list(names.values()) if isinstance(names, dict) else []
    receivers = tj.get("receivers")
    if isinstance(receivers, dict):
        names += [f"{v}.rnx" for v in receivers.values()]
    plain = [n for n in names if isinstance(n, str) and n and "/" not in n and not n.startswith(".")]
    return (*GNSS_SIMULATION_FILES, *plain)


def simulate_gnss_pair(out_dir: str | Path, *, duration_s: float = 3600.0, rate_hz: float = 1.0, seed: int = 0,
                       start_gps_s: float | None = None, nav_paths=(), master: str = "base", rover: str = "rover",
                       master_xyz=DEFAULT_MASTER_XYZ, rover_xyz=DEFAULT_ROVER_XYZ,
                       displacement_enu_m=(0.031, -0.022, 0.017), random_walk_sigma: float | None = None,
                       n_slips: int = 0, phase_sigma_m: float | None = None, code_sigma_m: float = 0.5,
                       mask_deg: float = 10.0, clock_offset_ms=(0.0, 0.0), clock_drift_ms=(-4.0, 5.0),
                       raw_tags: bool = False, master_rate_hz: float | None = None,
                       accel_sigma: float | None = None, multipath_sigma_m: float = 0.0,
                       multipath_tau_s: float = 30.0, progress=None) -> dict:
    """Simulate a master and a (displaced) rover and write RINEX, truth and config files.

    Parameters
    ----------
    out_dir : path
        Output directory (created).
    duration_s, rate_hz : float
        Span and sampling rate (epochs ``start + k/rate``).
    seed : int
        Random seed (noise, ambiguities, slips, random walk, synthetic orbits' clocks).
    start_gps_s : float, optional
        First epoch, GPS s (default: 2024-01-01 00:00 GPST with the synthetic constellation, or the
        first whole hour of ``nav_paths``).
    nav_paths : sequence of path
        Real RINEX navigation files to simulate with (default: a synthetic 36-satellite
        constellation, :func:`~cdgps_cli.model.gps.positioning.synthetic_gps_nav`).
    master, rover : str
        Antenna names (files ``<name>.rnx``, coordinates ``<rover>_e/_n/_u``).
    master_xyz, rover_xyz : 3 floats
        Master (true) and rover nominal positions, ECEF m.
    displacement_enu_m : 3 floats
        Rover's constant displacement from its nominal position, m (E, N, U).
    random_walk_sigma : float, optional
        If given, the rover also random-walks with this white-noise rate per component, m/√s.
    accel_sigma : float, optional
        If given (instead of ``random_walk_sigma``), the rover's velocity random-walks with this rate per
        component (white acceleration, m/s/√s; from rest), sampled exactly at the epochs: the constant-velocity
        model's process, and the config's ``constant_velocity`` displacement model.
    n_slips : int
        Random cycle slips (LLI-flagged), each at a random receiver and record among those the
        run's config will use — satellite tracked at both receivers above the config's mask
        (``max(mask_deg, GnssConfig.mask_deg)``) for ≥ 10 epochs before and after, inside
        5–95 % of the span — with a random size; all ``n_slips`` are made unless there are too
        few such records (then truth.json ``slips_note`` and the progress output say so).
    phase_sigma_m : float, optional
        Undifferenced white phase noise, m.  Default: the elevation model of the estimator's
        default weighting, σ² = a² + b²/sin²el per receiver with a = b = 3 mm
        (``GnssConfig.sigma_a_m``/``sigma_b_m``), so that NIS/NEES of the default run are ≈ 1.
    code_sigma_m : float
        Undifferenced white pseudorange noise, m (the estimator weights code as
        ``code_ratio`` = 100 × the phase σ: 0.42 m at the zenith, 1.2 m at 15°).
    mask_deg : float
        Tracking mask of the simulated receivers, degrees.
    clock_offset_ms, clock_drift_ms : 2 floats
        Master and rover receiver-clock offset at the start, and its change over the span, ms
        (default 0 and −4 / +5 ms).
    raw_tags : bool
        Time tags are the nominal epochs plus the clock offset as it is (u-blox-like: off whole
        seconds by the offset, e.g. .992 s for −8 ms); default: the offset rounded to 1 ms
        (GEONET-like).  The receivers measure at the nominal GPS epochs in the first case, at
        the tag minus the offset in both.
    master_rate_hz : float, optional
        The master records at this lower rate (``rate_hz`` a whole multiple of it), e.g. 0.2 for
        a 5 s CORS receiver beside a 1 Hz rover.
    multipath_sigma_m, multipath_tau_s : float
        Phase multipath of the rover (0: none): each satellite's L1 phase carries a first-order Gauss–Markov error
        of stationary σ ``multipath_sigma_m`` (m) and time constant ``multipath_tau_s`` (s), independent between
        satellites (:func:`rover_phase_multipath`), beside the white noise; the errors a static antenna's
        reflections give, correlated over tens of seconds.

    Returns
    -------
    dict
        Summary: files, epochs, rows, slips, positions, displacement model.
    """
    say = progress or (lambda m: None)
    _check_multipath(multipath_sigma_m, multipath_tau_s)
    every = _check_pair_options(duration_s, rate_hz, master, rover, master_xyz, rover_xyz, start_gps_s,
                                clock_offset_ms, clock_drift_ms, master_rate_hz, random_walk_sigma, n_slips,
                                accel_sigma)
    nav, start_gps_s, nav_source = _navigation(nav_paths, start_gps_s, duration_s, seed)
    run = _PairRun(duration_s=duration_s, rate_hz=rate_hz, seed=seed, start_gps_s=start_gps_s, master=master,
                   rover=rover, master_xyz=master_xyz, rover_xyz=rover_xyz, every=every,
                   random_walk_sigma=random_walk_sigma, accel_sigma=accel_sigma, n_slips=n_slips,
                   code_sigma_m=code_sigma_m,
                   mask_deg=mask_deg, clock_offset_ms=clock_offset_ms, clock_drift_ms=clock_drift_ms,
                   raw_tags=raw_tags, master_rate_hz=master_rate_hz, nav_source=nav_source,
                   multipath_sigma_m=float(multipath_sigma_m), multipath_tau_s=float(multipath_tau_s))
    disp = np.asarray(displacement_enu_m, dtype=np.float64)
    offsets, velocity = _rover_offsets(run, disp)
    phase_noise, phase_model = _phase_noise_model(phase_sigma_m)
    sim = _simulate_pair(run, nav, disp, offsets, phase_noise, say)
    if run.multipath_sigma_m > 0:
        sim["rover"] = rover_phase_multipath(sim["rover"], run.multipath_sigma_m, run.multipath_tau_s, run.seed)
    slip_note = _slip_note(run, sim["slips"], say)
    say(f"writing RINEX: {len(sim['base'])} + {len(sim['rover'])} satellite-epoch records …")
    out = Path(out_dir)
    with output_set(out, replaces=previous_simulation_files(out, "cdgps gnss simulation")) as dest:
        files = _write_pair_rinex(dest, run, sim, nav)
        names = _write_pair_truth_csv(dest, run, offsets, velocity)
        truth_json = {**_truth_run_fields(run),
                      **_truth_rover_fields(run, disp, offsets, names, phase_noise, phase_model),
                      **_truth_event_fields(run, sim, slip_note),
                      "files": {"rinex": files, "nav": "nav.rnx", "truth": "truth.csv", "config": "config.toml"}}
        write_bytes_atomic(dest.path("truth.json"), (json.dumps(truth_json, indent=2) + "\n").encode())
        write_bytes_atomic(dest.path("config.toml"), _pair_config_toml(run, files).encode())
    amb = sim["ambiguities"]
    return {
        "output": str(out), "files": sorted([*files.values(), *GNSS_SIMULATION_FILES]),
        "epochs": run.n_ep, "records": {master: int(len(sim["base"])), rover: int(len(sim["rover"]))},
        "satellites": int(pd.concat([sim["base"]["sat"], sim["rover"]["sat"]]).nunique()),
        "slips": int((amb["kind"] == "slip").sum()), "slips_requested": n_slips, "start": gps_time_str(start_gps_s),
        "displacement_model": truth_json["displacement_model"], "displacement_enu_m": disp.tolist(),
    }


@dataclass(frozen=True)
class _PairRun:
    """The settings of one :func:`simulate_gnss_pair` run, checked (see its parameters)."""

    duration_s: float
    rate_hz: float
    seed: int
    start_gps_s: float
    master: str
    rover: str
    master_xyz: tuple
    rover_xyz: tuple
    every: int
    random_walk_sigma: float | None
    accel_sigma: float | None
    n_slips: int
    code_sigma_m: float
    mask_deg: float
    clock_offset_ms: tuple
    clock_drift_ms: tuple
    raw_tags: bool
    master_rate_hz: float | None
    nav_source: object
    multipath_sigma_m: float = 0.0
    multipath_tau_s: float = 30.0

    @property
    def interval_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def n_ep(self) -> int:
        return int(math.floor(self.duration_s / self.interval_s - 1e-9)) + 1

    @property
    def slip_mask_deg(self) -> float:
        return max(float(self.mask_deg), GnssConfig.mask_deg)

    @property
    def displacement_model(self) -> str:
        if self.accel_sigma is not None:
            return "constant_velocity"
        return "random_walk" if self.random_walk_sigma is not None else "static"

    def receiver(self, who: str) -> str:
        """The antenna name of the simulator's ``"base"`` / ``"rover"``."""
        return self.master if who == "base" else self.rover


def _check_pair_options(duration_s, rate_hz, master, rover, master_xyz, rover_xyz, start_gps_s,
                        clock_offset_ms, clock_drift_ms, master_rate_hz, random_walk_sigma, n_slips,
                        accel_sigma=None) -> int:
    """Refuse options out of range (CdgpsError naming the option); returns how many rover epochs
    make one master epoch."""
    if not (duration_s > 0 and math.isfinite(duration_s)):
        raise CdgpsError(f"--duration must be positive, got {duration_s!r}")
    if not (rate_hz > 0 and math.isfinite(rate_hz)) or rate_hz > 100:
        raise CdgpsError(f"--rate-hz must be in (0, 100], got {rate_hz!r}")
    if master == rover:
        raise CdgpsError("the master and rover names must differ")
    check_on_earth(master_xyz, "--master-xyz")
    check_on_earth(rover_xyz, "--rover-xyz")
    if start_gps_s is not None:
        check_simulation_start(start_gps_s)
    for what, v in (("--clock-offset-ms", clock_offset_ms), ("--clock-drift-ms", clock_drift_ms)):
        if len(v) != 2 or not all(math.isfinite(x) and abs(x) <= 1000.0 for x in v):
            raise CdgpsError(f"{what} expects two offsets (master, rover) within ±1000 ms, got {v!r}")
    every = 1 if master_rate_hz is None else _master_every(rate_hz, master_rate_hz)
    if random_walk_sigma is not None and not random_walk_sigma > 0:
        raise CdgpsError(f"--random-walk must be a positive rate (m/√s), got {random_walk_sigma!r}")
    if accel_sigma is not None and not accel_sigma > 0:
        raise CdgpsError(f"--constant-velocity must be a positive rate (m/s/√s), got {accel_sigma!r}")
    if accel_sigma is not None and random_walk_sigma is not None:
        raise CdgpsError("--random-walk and --constant-velocity are two motion models: give one")
    if n_slips < 0:
        raise CdgpsError(f"--slips must be >= 0, got {n_slips}")
    check_table_size(duration_s * rate_hz + 1, 2 * GPS_PRN_SLOTS, PAIR_BYTES_PER_VALUE,
                     "the simulated observation tables", f"--duration {duration_s:g} s at --rate-hz {rate_hz:g}")
    return every


def _master_every(rate_hz: float, master_rate_hz: float) -> int:
    """``rate_hz / master_rate_hz``, refused unless a whole number >= 1."""
    ratio = rate_hz / master_rate_hz if master_rate_hz > 0 and math.isfinite(master_rate_hz) else math.nan
    if not (math.isfinite(ratio) and ratio >= 1 and abs(ratio - round(ratio)) < 1e-9):
        raise CdgpsError(f"--master-rate-hz must divide --rate-hz {rate_hz:g} (rate / master rate a whole number "
                         f">= 1), got {master_rate_hz!r}")
    return int(round(ratio))


def _navigation(nav_paths, start_gps_s, duration_s: float, seed: int):
    """(ephemerides, first epoch GPS s, their source for truth.json): the records of ``nav_paths``,
    refused unless they cover the span, or a synthetic constellation."""
    if not nav_paths:
        if start_gps_s is None:
            start_gps_s = gps_seconds(2024, 1, 1)
        nav = synthetic_gps_nav(start_gps_s, duration_s, seed=seed)
        return nav, start_gps_s, "synthetic constellation (cdgps_cli.model.gps.positioning.synthetic_gps_nav)"
    navs = [read_rinex_nav(p) for p in nav_paths]
    nav = pd.concat(navs, ignore_index=True).drop_duplicates(subset=["sat", "toe_gps_s", "iode", "af0_s"])
    nav = nav.sort_values(["sat", "toe_gps_s"], kind="stable").reset_index(drop=True)
    if start_gps_s is None:
        start_gps_s = math.ceil(float(nav["toe_gps_s"].min()) / 3600.0) * 3600.0
    lo, hi = float(nav["toe_gps_s"].min()) - MAX_EPHEMERIS_AGE_S, float(nav["toe_gps_s"].max()) + MAX_EPHEMERIS_AGE_S
    if start_gps_s < lo or start_gps_s + duration_s > hi:
        raise CdgpsError(f"the navigation data ({gps_time_str(lo)} – {gps_time_str(hi)} with ±2 h validity) do not cover "
                         f"the simulated span {gps_time_str(start_gps_s)} – {gps_time_str(start_gps_s + duration_s)}; "
                         f"choose --start/--duration inside it or omit --nav (synthetic constellation)")
    return nav, start_gps_s, [str(p) for p in nav_paths]


def _rover_offsets(run: _PairRun, disp: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The rover's true displacement at every nominal epoch, m (n_ep, 3) ENU: ``disp`` plus the
    random walk if any (its own generator, seed + 7919); and its true velocity (n_ep, 3; m/s ENU) with
    ``accel_sigma`` (the constant-velocity process), else None."""
    gen = np.random.default_rng(run.seed + 7919)
    offsets = np.tile(disp, (run.n_ep, 1))
    if run.random_walk_sigma is not None:
        steps = gen.normal(0.0, run.random_walk_sigma * math.sqrt(run.interval_s), size=(run.n_ep, 3))
        steps[0] = 0.0
        offsets = offsets + np.cumsum(steps, axis=0)
    if run.accel_sigma is not None:               # (position, velocity) per axis: x_k = A x_{k−1} + w, w ~ N(0, Q)
        dt = run.interval_s
        A = np.array([[1.0, dt], [0.0, 1.0]])
        L = np.linalg.cholesky(run.accel_sigma**2 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))
        w = gen.normal(size=(run.n_ep, 2, 3))
        x = np.zeros((2, 3))
        path, velocity = np.zeros((run.n_ep, 3)), np.zeros((run.n_ep, 3))
        for k in range(1, run.n_ep):
            x = A @ x + L @ w[k]
            path[k], velocity[k] = x[0], x[1]
        return offsets + path, velocity
    return offsets, None


def _phase_noise_model(phase_sigma_m: float | None):
    """(phase noise argument of the simulator, its description): the estimator's default
    elevation weighting, or white noise of ``phase_sigma_m`` m (refused if negative)."""
    if phase_sigma_m is None:
        phase_noise = (GnssConfig.sigma_a_m, GnssConfig.sigma_b_m)
        return phase_noise, (f"elevation: sigma^2 = a^2 + b^2/sin^2(el) per receiver, a = {phase_noise[0]:g} m, "
                             f"b = {phase_noise[1]:g} m (the estimator's default weighting)")
    if not (phase_sigma_m >= 0 and math.isfinite(phase_sigma_m)):
        raise CdgpsError(f"--phase-noise-m must be >= 0, got {phase_sigma_m!r}")
    phase_noise = float(phase_sigma_m)
    return phase_noise, f"white: sigma = {phase_noise:g} m at every elevation"


def _simulate_pair(run: _PairRun, nav, disp: np.ndarray, offsets: np.ndarray, phase_noise, say) -> dict:
    """The observables of both receivers (:func:`simulate_static_pair`); refused if no satellite is seen."""
    say(f"simulating {run.n_ep} epochs at {run.rate_hz:g} Hz from {gps_time_str(run.start_gps_s)} …")
    sim = simulate_static_pair(nav, np.asarray(run.master_xyz, float), np.asarray(run.rover_xyz, float),
                               run.start_gps_s, run.duration_s, run.interval_s, seed=run.seed,
                               mask_rad=math.radians(run.mask_deg), phase_sigma_m=phase_noise,
                               code_sigma_m=run.code_sigma_m,
                               rover_offset_enu_m=None if run.random_walk_sigma is None and not disp.any() else offsets,
                               random_slips=run.n_slips, slip_mask_rad=math.radians(run.slip_mask_deg),
                               slip_min_epochs=10, clock_offset_ms=tuple(map(float, run.clock_offset_ms)),
                               clock_drift_ms=tuple(map(float, run.clock_drift_ms)),
                               tag_resolution_s=None if run.raw_tags else 1e-3, base_every=run.every)
    if len(sim["base"]) == 0 or len(sim["rover"]) == 0:
        raise CdgpsError("no satellite is visible in the simulated span (check the positions and the navigation data)")
    return sim


def _check_multipath(sigma_m: float, tau_s: float) -> None:
    """--multipath-m: 0 (none) or the run config's range; --multipath-tau-s: the run config's range."""
    from cdgps_cli.config.limits import GNSS_MULTIPATH_SIGMA, GNSS_MULTIPATH_TAU  # noqa: PLC0415

    if not (math.isfinite(sigma_m) and (sigma_m == 0 or GNSS_MULTIPATH_SIGMA.contains(sigma_m))):
        raise CdgpsError(f"--multipath-m must be 0 (none) or in {GNSS_MULTIPATH_SIGMA.text()}, got {sigma_m!r}")
    if not (math.isfinite(tau_s) and GNSS_MULTIPATH_TAU.contains(tau_s)):
        raise CdgpsError(f"--multipath-tau-s must be in {GNSS_MULTIPATH_TAU.text()}, got {tau_s!r}")


def rover_phase_multipath(obs: pd.DataFrame, sigma_m: float, tau_s: float, seed: int) -> pd.DataFrame:
    """``obs`` (a receiver's records: ``time_gps_s``, ``sat``, ``phase_l1_cycles``) with a first-order Gauss–Markov
    phase error per satellite added: m_1 ~ N(0, σ²), m_k = a m_{k−1} + σ √(1 − a²) ω_k, a = exp(−Δt/τ) over each
    step Δt between the satellite's records (a gap lets it decorrelate as the process does), ω_k ~ N(0, 1) from its
    own generator (``seed``; the white noise is not changed).  σ ``sigma_m`` m, τ ``tau_s`` s."""
    from scipy.signal import lfilter  # noqa: PLC0415

    _check_multipath(sigma_m, tau_s)
    out = obs.copy()
    gen = np.random.default_rng(seed + 7919)
    t = out["time_gps_s"].to_numpy(dtype=np.float64)
    err = np.zeros(len(out))
    for _, rows in sorted(out.groupby("sat", sort=True).indices.items()):
        rows = rows[np.argsort(t[rows], kind="stable")]
        w = gen.standard_normal(rows.size)
        dt = np.diff(t[rows])
        m = np.empty(rows.size)
        m[0] = sigma_m * w[0]               # (a satellite seen once: that draw alone)
        # runs of one spacing are one linear recursion each (lfilter), carried on from the run before
        cuts = np.flatnonzero(np.diff(dt) != 0) + 1
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, dt.size]) if dt.size else ():
            a = math.exp(-dt[lo] / tau_s)
            drive = sigma_m * math.sqrt(-math.expm1(-2.0 * dt[lo] / tau_s)) * w[lo + 1:hi + 1]
            m[lo + 1:hi + 1], _ = lfilter([1.0], [1.0, -a], drive, zi=[a * m[lo]])
        err[rows] = m
    out["phase_l1_cycles"] = out["phase_l1_cycles"].to_numpy() + err / GPS_L1_WAVELENGTH_M
    return out


def _slip_note(run: _PairRun, slips, say) -> str | None:
    """Why fewer slips were made than requested (also said as a warning), or None."""
    if len(slips) >= run.n_slips:
        return None
    note = (f"{run.n_slips} slips requested, {len(slips)} simulated: slips are placed only on records tracked at "
            f"both receivers above {run.slip_mask_deg:g} deg with >= 10 such epochs before and after, 5-95 % into "
            f"the span, >= 10 epochs apart per satellite, and there are not enough of those")
    say(f"warning: {note}")
    return note


def _write_pair_rinex(dest, run: _PairRun, sim: dict, nav) -> dict:
    """Write ``<master>.rnx``, ``<rover>.rnx`` and ``nav.rnx``; returns {antenna: observation file name}."""
    y, mo, d, hh, mi, ss = rinex_calendar(run.start_gps_s)
    stamp = f"{y:04d}{mo:02d}{d:02d} {hh:02d}{mi:02d}{int(ss):02d} UTC"     # reproducible files
    files = {}
    for who in ("base", "rover"):
        name = run.receiver(who)
        hdr = {"marker_name": name, "observer": "cdgps simulate-gnss", "agency": "simulated",
               "receiver_type": "CDGPS SIMULATOR", "receiver_version": __version__, "antenna_type": "SIMULATED",
               "approx_position_xyz_m": (run.master_xyz if who == "base" else run.rover_xyz),
               "interval_s": run.interval_s * (run.every if who == "base" else 1),
               "comments": [f"simulated by cdgps {__version__}, seed {run.seed}",
                            "master: true position" if who == "base" else "rover: NOMINAL position (truth.csv: displacement)"]}
        f = dest.path(f"{name}.rnx")
        write_rinex_obs(f, sim[who], hdr, created=stamp)
        files[name] = f.name
    write_rinex_nav(dest.path("nav.rnx"), nav, comments=[f"ephemerides used by cdgps simulate-gnss (seed {run.seed})"],
                    created=stamp)
    return files


def _write_pair_truth_csv(dest, run: _PairRun, offsets: np.ndarray, velocity: np.ndarray | None = None) -> list[str]:
    """Write truth.csv (nominal epochs, the rover's true ENU displacement, and its velocity ``<rover>_ve_m_s`` …
    when given); returns its coordinate columns."""
    names = [coordinate_column(f"{run.rover}_{c}", "m") for c in "enu"]
    t_nom = run.start_gps_s + np.arange(run.n_ep) * run.interval_s
    truth = pd.DataFrame({"time_s": t_nom, names[0]: offsets[:, 0], names[1]: offsets[:, 1], names[2]: offsets[:, 2],
                          **({} if velocity is None else
                             {f"{run.rover}_v{c}_m_s": velocity[:, i] for i, c in enumerate("enu")})})
    write_atomic(dest.path("truth.csv"), lambda p: truth.to_csv(p, index=False, lineterminator="\n", float_format="%.6f"))
    return names


def _truth_run_fields(run: _PairRun) -> dict:
    """truth.json: the run's settings (seed, span, rates, clocks, receivers and positions)."""
    m, r = run.master, run.rover
    return {
        "kind": "cdgps gnss simulation",
        "cdgps_version": __version__,
        "seed": run.seed, "start_gps_s": run.start_gps_s, "start": gps_time_str(run.start_gps_s),
        "duration_s": run.duration_s, "rate_hz": run.rate_hz, "epochs": run.n_ep,
        **({"master_rate_hz": run.master_rate_hz} if run.every > 1 else {}),
        "clock_offset_ms": {m: float(run.clock_offset_ms[0]), r: float(run.clock_offset_ms[1])},
        "clock_drift_ms": {m: float(run.clock_drift_ms[0]), r: float(run.clock_drift_ms[1])},
        "time_tags": "nominal epoch + clock offset" if run.raw_tags else "nominal epoch + clock offset rounded to 1 ms",
        "master": m, "rover": r,
        "master_ecef_m": list(map(float, run.master_xyz)),
        "rover_nominal_ecef_m": list(map(float, run.rover_xyz)),
    }


def _truth_rover_fields(run: _PairRun, disp, offsets, names, phase_noise, phase_model) -> dict:
    """truth.json: the displacement model and the noise models."""
    lat, lon, _ = ecef_to_geodetic(np.asarray(run.rover_xyz, float))
    return {
        "displacement_model": run.displacement_model,
        "displacement_enu_m": disp.tolist(),
        "random_walk_sigma_m_per_sqrt_s": run.random_walk_sigma,
        "accel_sigma_m_per_s_per_sqrt_s": run.accel_sigma,
        "rover_mean_ecef_m": (np.asarray(run.rover_xyz, float) + enu_matrix(lat, lon).T @ offsets.mean(axis=0)).tolist(),
        "coordinates": names,
        "phase_sigma_m": list(phase_noise) if isinstance(phase_noise, tuple) else phase_noise,
        "phase_noise_model": phase_model,
        "code_sigma_m": run.code_sigma_m, "code_noise_model": "white",
        "cn0_model": "C/N0 = 35 + 15 sin(el) dB-Hz (no noise); RINEX S1C and the L1C signal-strength digit from it",
        "mask_deg": run.mask_deg,
        "navigation": run.nav_source,
        **({"phase_multipath": {"sigma_m": run.multipath_sigma_m, "time_constant_s": run.multipath_tau_s,
                                "model": "first-order Gauss-Markov per satellite on the rover's L1 phase"}}
           if run.multipath_sigma_m > 0 else {}),
    }


def _truth_event_fields(run: _PairRun, sim: dict, slip_note: str | None) -> dict:
    """truth.json: the slips, the integer ambiguities and the fractional receiver biases."""
    return {
        "slips_requested": run.n_slips,
        "slip_mask_deg": run.slip_mask_deg,
        "cycle_slips": [{"receiver": run.receiver(d["receiver"]), "sat": d["sat"], "time_gps_s": d["time_gps_s"],
                         "cycles": d["cycles"], "elevation_deg": d["elevation_deg"]} for d in sim["slips"]],
        **({"slips_note": slip_note} if slip_note else {}),
        "ambiguities": [{"receiver": run.receiver(r["receiver"]), "sat": r["sat"], "kind": r["kind"],
                         "from_gps_s": float(r["t_from_s"]), "cycles": int(r["n_cycles"])}
                        for _, r in sim["ambiguities"].iterrows()],
        "frac_bias_cycles": {run.receiver(k): v for k, v in sim["frac_bias_cycles"].items()},
    }


def _init_float_sigma(run: _PairRun) -> float | None:
    """``sigma_m_per_sqrt_s`` of the pair's config: the random walk simulated, or for a constant-velocity rover the
    random walk ``init``'s float needs to follow it — three times the velocity's σ at the record's end,
    ``3 σ_a √T`` (m/s, a step per second; at least 1 mm/√s).  The earlier 1 mm/√s left a rover wandering 5 m in
    5 min (σ_a 1 mm/s/√s) with no integer fixed and the whole chain's NEES at 10⁸, without a word."""
    if run.accel_sigma is None:
        return run.random_walk_sigma
    return max(1e-3, 3.0 * run.accel_sigma * math.sqrt(run.duration_s))


def _pair_config_toml(run: _PairRun, files: dict) -> str:
    """config.toml: the GNSS run config of the pair."""
    m, r = run.master, run.rover
    return gnss_config_toml(
        {m: ("rinex", files[m]), r: ("rinex", files[r])}, ["nav.rnx"], m,
        name=f"simulated-{m}-{r}",
        description=f"cdgps simulate-gnss: {run.duration_s:g} s at {run.rate_hz:g} Hz, seed {run.seed}",
        displacement=run.displacement_model,
        sigma_m_per_sqrt_s=_init_float_sigma(run), accel_sigma_m_per_s_per_sqrt_s=run.accel_sigma,
        comments=["GNSS run config written by cdgps simulate-gnss (format: docs/gnss-pipeline.md).",
                  f"{m}: master at its true position; {r}: nominal position in its header,",
                  "true displacement in truth.csv.  Run:",
                  "  cdgps ingest --config config.toml -o run.mcap && cdgps init run.mcap -o init.json",
                  "  cdgps estimate run.mcap --init init.json -o states.mcap && cdgps evaluate --truth . --estimate states.mcap"],
    )
