"""Physically plausible bounds of every number a user gives (issue 12 item 5), in one place.

A value outside these bounds is refused up front with a :class:`~cdgps_cli.core.errors.CdgpsError`
naming the config key or the option, instead of overflowing, dividing by zero or asking for
terabytes later.  The bounds are wide (they refuse nonsense such as ``1e308`` m or a
``1e-308`` s sample period, never a real structure or receiver) and are listed in
docs/config-format.md ("Bounds").

* :data:`CONFIG_BOUNDS`: structure-config keys, as ``table.key`` patterns (``[]`` for any element
  of an array of tables or of a vector; ``*`` for any key of a table);
* :data:`OPTION_BOUNDS`: command-line options (Python parameter name → bounds), checked for every
  command by :class:`cdgps_cli.cli.guard.GuardedCommand`;
* :data:`LOG_BOUNDS`: CSV log columns; :data:`INIT_BOUNDS`: the INIT.json state;
* :data:`MAX_TABLE_BYTES`: the largest table a run may need in memory (epochs × channels), see
  :func:`check_table_size`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cdgps_cli.core.errors import CdgpsError


@dataclass(frozen=True)
class Bound:
    """Closed interval ``[lo, hi]`` of a value with its unit; ``lo_open`` / ``hi_open``: ``lo`` / ``hi``
    itself refused."""

    lo: float
    hi: float
    unit: str = ""
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, v: float) -> bool:
        return (v > self.lo if self.lo_open else v >= self.lo) and (v < self.hi if self.hi_open else v <= self.hi)

    def text(self) -> str:
        u = f" {self.unit}" if self.unit else ""
        return f"{'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}{u}"


_LENGTH = Bound(-1e7, 1e7, "m")          # a structure in a lab or on Earth: within 10,000 km
_SIGMA = Bound(0.0, 100.0, "m", lo_open=True)
#: an elevation mask (every GNSS command's option and the config's ``[gnss] mask_deg``): the one home of its range
MASK_DEG = Bound(0.0, 90.0, "deg", hi_open=True)
_DURATION = Bound(0.0, 1e9, "s")         # 31.7 years
_NOISE = Bound(0.0, 100.0, "m")          # a simulated noise or multipath σ (0 = none)
_SCALE = Bound(0.0, 1e3)                 # a simulated disturbance scale

#: structure-config keys (docs/config-format.md)
CONFIG_BOUNDS: dict[str, Bound] = {
    "model.sample_period_s": Bound(1e-4, 3600.0, "s"),
    "model.wavelength_m": Bound(1e-3, 10.0, "m"),
    "model.measurement_sigma_m": _SIGMA,
    "model.multipath_sigma_m": _NOISE,
    "model.multipath_time_constant_s": Bound(1e-3, 1e9, "s"),
    "body.origin_m[]": _LENGTH,
    "sections[].pivot_m[]": _LENGTH,
    "antennas[].position_m[]": _LENGTH,
    "antennas[].line_bias_m": _LENGTH,
    "antennas[].sigma_m": _SIGMA,
    "antennas[].displacement_m.*[]": Bound(-1e4, 1e4, "m per unit coordinate"),
    "transmitters[].position_m[]": _LENGTH,
    "transmitters[].sigma_m": _SIGMA,
    "channel_sigma[].sigma_m": _SIGMA,
    "modes[].frequency_hz": Bound(0.0, 1e4, "Hz"),
    "modes[].time_constant_s": Bound(1e-3, 1e9, "s"),
    "modes[].damping_ratio": Bound(0.0, 10.0),
    "modes[].shape[]": Bound(-1e6, 1e6),
    "process_noise.sigma[]": Bound(0.0, 1e6),
    "process_noise.covariance[][]": Bound(-1e12, 1e12),
    "process_noise.cholesky[][]": Bound(-1e6, 1e6),
    "gyros[].rotation_rad.*[]": Bound(-1e4, 1e4, "rad per unit coordinate"),
    "points[].position_m[]": _LENGTH,
    "points[].displacement_m.*[]": Bound(-1e4, 1e4, "m per unit coordinate"),
    "simulation.phase_sigma_m": _NOISE,
    "simulation.multipath_sigma_m": _NOISE,
    "simulation.multipath_time_constant_s": Bound(1e-3, 1e9, "s"),
    "simulation.snr_dbhz": Bound(0.0, 100.0, "dB-Hz"),
    "simulation.initial_modal_sigma": Bound(0.0, 1e6),
    "simulation.initial_rigid_sigma_rad": Bound(0.0, 1e3, "rad"),
    "simulation.disturbance_scale": _SCALE,
    "simulation.gyro_noise_rad_s": Bound(0.0, 1e3, "rad/s"),
    "simulation.gyro_bias_sigma_rad_s": Bound(0.0, 1e3, "rad/s"),
    "simulation.gyro_bias_drift_rad_s_per_sqrt_s": Bound(0.0, 1e3, "rad/s/√s"),
    "simulation.gyro_sample_period_s": Bound(0.0, 3600.0, "s"),
    "simulation.static_rest_after_s": _DURATION,
    "simulation.static_settle_s": _DURATION,
    "simulation.static_angle_deg": Bound(-360.0, 360.0, "deg"),
    "simulation.pulse_time_s": _DURATION,
    "simulation.pulse_duration_s": _DURATION,
    "simulation.pulse_force_n": Bound(-1e9, 1e9, "N"),
    "simulation.slew_from_deg": Bound(-360.0, 360.0, "deg"),
    "simulation.slew_to_deg": Bound(-360.0, 360.0, "deg"),
    "simulation.slew_time_s": _DURATION,
}

#: the multipath model ``init`` fits to its residuals when the data show time-correlated errors
#: (cdgps_cli.measurement.multipath.fit_autocovariance): σ and τ are clamped to these
AUTO_MULTIPATH_SIGMA = Bound(5e-4, 0.1, "m")
AUTO_MULTIPATH_TAU = Bound(1.0, 600.0, "s")
#: a GNSS run config's ``[gnss.displacement] multipath_sigma_m`` (a carrier's multipath stays within a quarter of its
#: wavelength, 5 cm at L1) and ``multipath_time_constant_s`` (the structure config's range)
GNSS_MULTIPATH_SIGMA = Bound(0.0, 0.1, "m", lo_open=True)
GNSS_MULTIPATH_TAU = CONFIG_BOUNDS["model.multipath_time_constant_s"]

#: command-line options, by Python parameter name (the same bound wherever the option appears)
OPTION_BOUNDS: dict[str, Bound] = {
    "seed": Bound(0, 2**63 - 1),
    "duration_s": _DURATION,
    "phase_sigma_m": _NOISE,
    "multipath_sigma_m": _NOISE,
    "multipath_time_constant_s": Bound(1e-3, 1e9, "s"),
    "disturbance_scale": _SCALE,
    "random_slips": Bound(0, 1_000_000),
    "ratio_threshold": Bound(1.0, 1e12),
    "starts": Bound(1, 10_000),
    "max_iterations": Bound(1, 100_000),
    "sigma_m": Bound(1e-6, 100.0, "m"),
    "start_s": Bound(-1e10, 1e10, "s"),
    "end_s": Bound(-1e10, 1e10, "s"),
    "process_noise_scale": Bound(0.0, 1e6, lo_open=True),
    "rest_process_noise_scale": Bound(0.0, 1e6),
    "rest_retry_s": Bound(0.0, 1e9, "s"),
    "rest_window_s": Bound(0.0, 1e6, "s", lo_open=True),
    "rest_dwell_s": Bound(0.0, 1e6, "s"),
    "outlier_sigma": Bound(0.0, 1e6, lo_open=True),
    "segment_s": Bound(0.0, 1e9, "s", lo_open=True),
    "pad": Bound(1, 64),
    "converge_s": Bound(0.0, 1e9, "s"),
    "survey_deg": Bound(-360.0, 360.0, "deg"),
    "mask_deg": MASK_DEG,
    "iono_threshold_km": Bound(0.0, 1e6, "km"),
    "tropo_threshold_km": Bound(0.0, 1e6, "km"),
    "rate_hz": Bound(0.0, 1000.0, "Hz", lo_open=True),
    "foxglove_rate_hz": Bound(0.0, 1e6, "Hz"),
    "random_walk": Bound(0.0, 10.0, "m/√s"),
    "phase_noise_m": _NOISE,
    "code_noise_m": Bound(0.0, 1e4, "m"),
    "n_slips": Bound(0, 1_000_000),
    "sigma": Bound(0.0, 10.0, "m/√s", lo_open=True),
}

#: CSV log columns (logs.py): times within 31.7 years of the run's start (log times are
#: nanoseconds in 64 bits), phases and forces far beyond any real value refused
LOG_BOUNDS: dict[str, Bound] = {
    "time_s": Bound(0.0, 1e9, "s"),
    "phase_cycles": Bound(-1e12, 1e12, "cycles"),
    "snr_dbhz": Bound(-100.0, 200.0, "dB-Hz"),
    "rate_rad_s": Bound(-1e4, 1e4, "rad/s"),
    "force_n": Bound(-1e9, 1e9, "N"),
}

#: INIT.json state (ekf.load_init_state): modal coordinates, angles (rad), translations (m) and
#: their velocities, and the covariance entries
INIT_BOUNDS: dict[str, Bound] = {
    "state.x": Bound(-1e6, 1e6),
    "state.P": Bound(-1e12, 1e12),
}

#: largest in-memory table a command may build (epochs × channels × bytes per value), bytes
MAX_TABLE_BYTES = 8 * 2**30


def _matches(pattern: str, doc: dict):
    """(key path, value) of every number the pattern addresses in a parsed TOML document."""
    parts = pattern.replace("[]", ".[]").split(".")
    found = [("", doc)]
    for part in parts:
        nxt = []
        for where, v in found:
            if part == "[]":
                if isinstance(v, list):
                    nxt += [(f"{where}[{i}]", e) for i, e in enumerate(v)]
            elif part == "*":
                if isinstance(v, dict):
                    nxt += [(f"{where}.{k}", e) for k, e in v.items()]
            elif isinstance(v, dict) and part in v:
                nxt.append((f"{where}.{part}" if where else part, v[part]))
        found = nxt
    return [(w, v) for w, v in found if isinstance(v, (int, float)) and not isinstance(v, bool)]


def config_range_problems(doc: dict) -> list[str]:
    """``key: …`` problems of the finite numbers of a structure config outside :data:`CONFIG_BOUNDS`
    (non-numbers and non-finite numbers are left to the config checker's own messages)."""
    out = []
    for pattern, b in CONFIG_BOUNDS.items():
        for where, v in _matches(pattern, doc):
            try:
                x = float(v)
            except OverflowError:                 # a TOML integer beyond the float range
                x = math.inf
            if math.isfinite(x) and not b.contains(x):
                out.append(f"{where}: {v!r} is outside the plausible range {b.text()}")
    return out


def check_option(name: str, spelling: str, value) -> None:
    """Refuse an option value outside :data:`OPTION_BOUNDS` (``spelling``: ``--seed``)."""
    b = OPTION_BOUNDS.get(name)
    if b is None or value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if math.isfinite(value) and not b.contains(value):
        raise CdgpsError(f"{spelling} {value:g}: outside the plausible range {b.text()}")


def check_table_size(rows: float, columns: float, bytes_per_value: int, what: str, cause: str) -> None:
    """Refuse a computation whose table of ``rows × columns`` values would exceed
    :data:`MAX_TABLE_BYTES`; ``cause`` names the option or key that sets ``rows``."""
    need = float(rows) * float(columns) * bytes_per_value
    if not need <= MAX_TABLE_BYTES:
        raise CdgpsError(f"{cause}: {what} would need about {_size(need)} of memory ({rows:.4g} epochs × "
                         f"{columns:g} channels); the limit is {_size(MAX_TABLE_BYTES)}")


def _size(n: float) -> str:
    for unit, k in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20)):
        if n >= k:
            return f"{n / k:.3g} {unit}"
    return f"{n:.0f} B"


#: a receiver on or near the Earth: its distance from the geocentre, m (WGS-84 radii 6 356 752–6 378 137 m,
#: from the Dead Sea shore to above the highest summits and aircraft altitudes)
GEOCENTRIC_RANGE_M = (6.30e6, 6.45e6)
#: the GNSS epochs a simulation may start at: GPS time 0 (1980-01-06) up to 2100 (broadcast week numbers,
#: RINEX and GPS-UTC tables beyond it are guesses)
SIMULATION_START_RANGE = ("1980-01-06", "2100-01-01")


def check_on_earth(xyz_m, what: str) -> None:
    """Refuse an ECEF position that is not on or near the Earth (e.g. 0 0 0), naming ``what``.

    Parameters
    ----------
    xyz_m : array_like, shape (3,)
        ECEF position, m.
    what : str
        The option or key it came from, for the message.
    """
    v = [float(x) for x in xyz_m]
    r = math.sqrt(sum(x * x for x in v))
    if not (all(math.isfinite(x) for x in v) and GEOCENTRIC_RANGE_M[0] <= r <= GEOCENTRIC_RANGE_M[1]):
        raise CdgpsError(f"{what} {','.join(f'{x:g}' for x in v)}: {r / 1e3:.1f} km from the Earth's centre; expected "
                         f"an ECEF position on the Earth ({GEOCENTRIC_RANGE_M[0] / 1e3:.0f}–{GEOCENTRIC_RANGE_M[1] / 1e3:.0f} km)")
