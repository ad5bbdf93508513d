"""Simulator of the papers' tests: structure truth, carrier-phase log, gyro log, actuator log.

Scenarios
---------
``free``
    Free vibration that excites every mode: random modal initial conditions (amplitude
    ``initial_modal_sigma`` per elastic mode, ``initial_rigid_sigma_rad`` on a rigid-body mode)
    plus a small white modal-acceleration disturbance (``disturbance_scale`` × the config's
    process-noise sigma).
``static``
    Free vibration for ``static_rest_after_s`` seconds (for bias initialization), then the structure
    is brought smoothly to rest over ``static_settle_s`` seconds and held at the surveyed
    configuration: every coordinate zero except ``static_angle_coordinate`` =
    ``static_angle_deg``.  ``truth.json`` gives the segments.
``pulse``
    Structure at rest, then the zero-net-momentum thruster pulse of Fig. 9 (thrusters
    ``pulse_thrusters`` at ``pulse_force_n`` from ``pulse_time_s`` for ``pulse_duration_s``); the
    thruster commands are written to ``actuators.csv``.

Measurement model: λ·phase_cycles = h(q) + bias + white noise + multipath, bias = line bias
+ λ·integer, where the integer makes the phase reported at lock lie in [0, 1) cycle and is kept
while lock is held; a cycle slip adds an integer and resets the lock counter; a signal outage
removes rows and re-acquires with a new integer.  Gyros read G·q̇ + bias + drift (random walk)
+ white noise.  Same seed → byte-identical files.
"""

from __future__ import annotations

import copy
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from cdgps_cli.core import progress
from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.io.atomic import output_set, write_atomic
from cdgps_cli.io.coordinate_columns import coordinate_columns
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.limits import check_table_size
from cdgps_cli.model.kinematics import gyro_matrix
from cdgps_cli.measurement.phase import all_channels, phase_model_q

SCENARIOS = ("free", "static", "pulse", "slew")


@dataclass
class SlipSpec:
    """A cycle slip on one channel: ``antenna:transmitter:time_s:cycles``."""

    antenna: str
    transmitter: str
    time_s: float
    cycles: int


@dataclass
class OutageSpec:
    """A loss of one transmitter (all its channels): ``transmitter:start_s:duration_s``."""

    transmitter: str
    start_s: float
    duration_s: float


@dataclass
class SimOptions:
    """Simulation options; ``None`` means "use the config's [simulation] value"."""

    duration_s: float = 60.0
    seed: int = 0
    scenario: str = "free"
    phase_sigma_m: float | None = None
    multipath_sigma_m: float | None = None
    slips: list = field(default_factory=list)
    outages: list = field(default_factory=list)
    random_slips: int = 0
    disturbance_scale: float | None = None
    noise_scale: dict = field(default_factory=dict)   # {antenna or transmitter name: factor on the white noise σ}


def check_receiver_epochs(duration_s: float, sample_period_s: float, gnss_interval_s: float | None = None) -> int:
    """Receiver epochs of ``simulate-gnss-structure``: the structure is simulated at ``sample_period_s``
    for ``duration_s`` and every ``gnss_interval_s`` (default: the sample period) becomes a receiver epoch.

    Returns
    -------
    int
        The epoch count; CdgpsError naming ``--gnss-interval`` (or ``--duration``) if it is below 2
        (one epoch makes no phase track).  An interval that is no whole multiple of the sample
        period is left to :func:`~cdgps_cli.pipeline.gnss_modal.simulate_structure_gnss`, which refuses it.
    """
    T = float(sample_period_s)
    interval = T if gnss_interval_s is None else float(gnss_interval_s)
    if not (np.isfinite(duration_s) and duration_s > 0 and np.isfinite(interval) and interval > 0):
        return 0
    step = max(int(round(interval / T)), 1)
    n_truth = int(round(duration_s / T)) + 1
    n = len(range(0, n_truth, step))
    if n < 2:
        what = (f"--gnss-interval {interval:g} s" if gnss_interval_s is not None
                else f"--duration {duration_s:g} s at the config's sample_period_s {T:g} s")
        raise CdgpsError(f"{what}: leaves {n} receiver epoch(s) in --duration {duration_s:g} s; expected at least 2 "
                         f"(an interval of at most {(n_truth - 1) * T:g} s, or a longer --duration)")
    return n


def parse_noise_scale(text: str) -> tuple[str, float]:
    """``NAME:FACTOR`` (``--noise-scale a3:5``) → (name, factor): the white phase noise of every channel
    of antenna or transmitter NAME is multiplied by FACTOR (> 0)."""
    name, _, val = text.strip().rpartition(":")
    f = _float_or_nan(val)
    if not name or not (np.isfinite(f) and f > 0):
        raise CdgpsError(f"--noise-scale {text!r}: expected NAME:FACTOR with an antenna or transmitter NAME and a "
                         f"positive FACTOR, e.g. a3:5")
    return name, f


def noise_scale_per_channel(cfg: StructureConfig, scale: dict, ant: np.ndarray, tx: np.ndarray) -> np.ndarray:
    """(C,) factor on the white noise σ of each channel: the product of its antenna's and its
    transmitter's factors in ``scale`` (1 where not given)."""
    f = np.ones(len(ant))
    for name, v in scale.items():
        if name in cfg.antenna_names:
            f[ant == cfg.antenna_names.index(name)] *= v
        if name in cfg.transmitter_names:
            f[tx == cfg.transmitter_names.index(name)] *= v
    return f


def parse_slip(text: str) -> SlipSpec:
    m = re.fullmatch(r"([^:]+):([^:]+):([0-9.eE+-]+):([+-]?\d+)", text.strip())
    t = _float_or_nan(m.group(3)) if m else float("nan")
    if not m or int(m.group(4)) == 0 or not (np.isfinite(t) and t >= 0):
        raise CdgpsError(f"--slip {text!r}: expected ANTENNA:TRANSMITTER:TIME_S:CYCLES with a finite TIME_S >= 0 and "
                         f"non-zero integer CYCLES, e.g. a3:PL2:30.0:+3")
    return SlipSpec(m.group(1), m.group(2), t, int(m.group(4)))


def _float_or_nan(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return float("nan")


def parse_outage(text: str) -> OutageSpec:
    m = re.fullmatch(r"([^:]+):([0-9.eE+-]+):([0-9.eE+-]+)", text.strip())
    start, dur = (_float_or_nan(m.group(2)), _float_or_nan(m.group(3))) if m else (float("nan"),) * 2
    if not m or not (np.isfinite(start) and start >= 0 and np.isfinite(dur) and dur > 0):
        raise CdgpsError(f"--outage {text!r}: expected TRANSMITTER:START_S:DURATION_S with a finite START_S >= 0 and a "
                         f"positive duration, e.g. PL4:40:10")
    return OutageSpec(m.group(1), start, dur)


@dataclass
class Simulation:
    """Everything a simulation produced (arrays in memory; :func:`write_simulation` saves them)."""

    cfg: StructureConfig
    options: SimOptions
    time_s: np.ndarray            # (N,)
    q: np.ndarray                 # (N, n_q) truth coordinates
    x: np.ndarray                 # (N, 2 n_m) truth modal state
    receiver: pd.DataFrame
    gyro: pd.DataFrame
    actuators: pd.DataFrame | None
    truth: dict
    tables: dict = field(default_factory=dict)    # further CSV files by name (closed loop: controller.csv)


#: the command-line option of each :class:`SimOptions` field (messages name what the user typed)
SIM_OPTION_NAMES = {"scenario": "--scenario", "duration_s": "--duration", "phase_sigma_m": "--noise-m",
                    "multipath_sigma_m": "--multipath-m", "disturbance_scale": "--disturbance-scale",
                    "random_slips": "--random-slips", "slips": "--slip", "outages": "--outage"}


def _validate(cfg: StructureConfig, opt: SimOptions, closed_loop: bool = False) -> None:
    """Refuse options out of range, each problem named by its option (:data:`SIM_OPTION_NAMES`)."""
    on = SIM_OPTION_NAMES
    problems = _closed_loop_problems(cfg, opt, closed_loop)
    if opt.scenario not in SCENARIOS:
        problems.append(f"{on['scenario']}: expected one of {', '.join(SCENARIOS)}, got {opt.scenario!r}")
    if not (opt.duration_s > 0 and np.isfinite(opt.duration_s)):
        problems.append(f"{on['duration_s']} {opt.duration_s:g}: expected a positive number of seconds")
    if opt.scenario == "pulse" and not cfg.simulation["pulse_thrusters"]:
        problems.append(f"--scenario pulse: {cfg.path}: [simulation] pulse_thrusters is empty; list the thrusters "
                        f"to pulse (known: {', '.join(cfg.thruster_names) or 'none: the config has no [[thrusters]]'})")
    for s in opt.slips:
        if s.antenna not in cfg.rover_names:
            problems.append(f"--slip: unknown rover antenna {s.antenna!r} (known: {', '.join(cfg.rover_names)})")
        if s.transmitter not in cfg.transmitter_names:
            problems.append(f"--slip: unknown transmitter {s.transmitter!r}")
        if not (np.isfinite(s.time_s) and s.time_s >= 0):
            problems.append(f"--slip: TIME_S: expected a finite time >= 0 s, got {s.time_s}")
    for o in opt.outages:
        if o.transmitter not in cfg.transmitter_names:
            problems.append(f"--outage: unknown transmitter {o.transmitter!r} (known: {', '.join(cfg.transmitter_names)})")
        if not (np.isfinite(o.start_s) and o.start_s >= 0 and np.isfinite(o.duration_s) and o.duration_s > 0):
            problems.append(f"--outage: expected START_S >= 0 and DURATION_S > 0 (finite), got {o.start_s}, {o.duration_s}")
    for name in ("phase_sigma_m", "multipath_sigma_m", "disturbance_scale"):
        v = getattr(opt, name)
        if v is not None and not (v >= 0 and np.isfinite(v)):
            problems.append(f"{on[name]} {v:g}: expected a non-negative number")
    if opt.random_slips < 0:
        problems.append(f"{on['random_slips']} {opt.random_slips}: expected a non-negative count")
    for name, v in (opt.noise_scale or {}).items():
        if name not in cfg.rover_names and name not in cfg.transmitter_names:
            problems.append(f"--noise-scale: {name!r} is not a rover antenna or a transmitter of the config "
                            f"(rovers: {', '.join(cfg.rover_names)}; transmitters: {', '.join(cfg.transmitter_names)})")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and v > 0):
            problems.append(f"--noise-scale {name}: expected a positive factor, got {v!r}")
    if problems:
        raise CdgpsError("invalid simulation options:\n  - " + "\n  - ".join(problems))
    check_table_size(opt.duration_s / cfg.sample_period_s + 1, len(cfg.channels), SIM_BYTES_PER_VALUE,
                     "the simulated phase log", f"--duration {opt.duration_s:g} s")


def _closed_loop_problems(cfg: StructureConfig, opt: SimOptions, closed_loop: bool) -> list[str]:
    if not closed_loop:
        return ["scenario slew: needs a controller (--controller GAINS.json)"] if opt.scenario == "slew" else []
    problems = []
    if opt.scenario not in ("pulse", "slew"):
        problems.append(f"--controller: runs the pulse or slew scenario, not {opt.scenario!r}")
    if opt.slips or opt.outages or opt.random_slips:
        problems.append("--controller: slips and outages are not simulated in the closed loop (its estimator "
                        "sees every channel with known biases)")
    if opt.scenario == "slew" and cfg.rigid_index is None:
        problems.append("scenario slew: the config has no rigid-body coordinate to slew")
    return problems


#: memory per epoch and channel while simulating (phase, lock, noise, geometry arrays and the
#: receiver-log table), bytes: for the bound of :func:`cdgps_cli.config.limits.check_table_size`
SIM_BYTES_PER_VALUE = 200


def simulate(cfg: StructureConfig, opt: SimOptions, trajectory=None) -> Simulation:
    """Run a simulation (pure computation, no I/O).

    Parameters
    ----------
    cfg : StructureConfig
    opt : SimOptions
    trajectory : callable, optional
        Replaces the open-loop propagation (the closed loop of :mod:`cdgps_cli.control`):
        ``trajectory(time_s, x0, w, noise_m) -> (x, actuators, extra)`` with the true modal states
        (N, 2 n_m), the actuator log as fired (or None) and a dict merged into truth.json;
        ``noise_m`` (N, C) is the carrier-phase error the receiver log will carry.

    Returns
    -------
    Simulation
    """
    _validate(cfg, opt, closed_loop=trajectory is not None)
    rng = np.random.default_rng(opt.seed)
    model = discrete_model(cfg)
    T = cfg.sample_period_s
    n = int(round(opt.duration_s / T)) + 1
    time_s = np.round(np.arange(n) * T, 9)
    w = _disturbance(cfg, opt, rng, n, model.Bw.shape[1])
    x0 = _initial_state(cfg, opt, rng)
    u, actuators = _thruster_commands(cfg, opt, time_s)
    extra = {}
    if trajectory is not None:
        noise_m = _phase_noise(cfg, opt, copy.deepcopy(rng), n, len(all_channels(cfg)[0]))
        x, actuators, extra = trajectory(time_s, x0, w, noise_m)
    else:
        x = _propagate(model, x0, u, w)
    U = np.asarray(cfg.mode_shapes)
    q = x[:, :cfg.n_modes] @ U.T
    qdot = x[:, cfg.n_modes:] @ U.T
    truth = {"scenario": opt.scenario, "seed": opt.seed, "duration_s": float(time_s[-1]),
             "sample_period_s": T, "config": cfg.name, "config_sha256": cfg.sha256,
             "coordinates": dict(zip(cfg.coord_names, cfg.coord_kinds))}   # kinds: the reports' limits per coordinate
    if opt.scenario == "static":
        q, qdot, x, truth["segments"] = _static_rest(cfg, time_s, q, qdot)
    else:
        truth["segments"] = _segments(cfg, opt, time_s)
    truth.update(extra)
    receiver, truth["biases"], truth["slips"] = _phase_log(cfg, opt, rng, time_s, q)
    truth.update(_noise_scale_truth(cfg, opt))
    gyro, truth["gyros"] = _gyro_log(cfg, rng, time_s, qdot)
    return Simulation(cfg, opt, time_s, q, x, receiver, gyro, actuators, truth)


def _disturbance(cfg: StructureConfig, opt: SimOptions, rng, n: int, n_w: int) -> np.ndarray:
    """The true disturbance input, (n, n_w): the config's process noise scaled by
    ``disturbance_scale`` (white, or correlated ``w = L z`` with W = L Lᵀ)."""
    dscale = cfg.simulation["disturbance_scale"] if opt.disturbance_scale is None else opt.disturbance_scale
    w = rng.standard_normal((n, n_w))
    if cfg.process_noise_covariance is None:
        w *= dscale * np.asarray(cfg.process_noise_sigma)
    else:
        w = w @ (dscale * cfg.process_noise_factor).T
    return w


def _initial_state(cfg: StructureConfig, opt: SimOptions, rng) -> np.ndarray:
    """The initial modal state (2 n_m): random modal amplitudes and rates for free and static, nearly
    at rest otherwise (slew: the rigid-body angle at ``slew_from_deg``)."""
    sim = cfg.simulation
    nm = cfg.n_modes
    U = np.asarray(cfg.mode_shapes)
    rigid_mode = np.asarray(cfg.mode_frequency_hz) == 0.0
    omega = 2 * np.pi * np.asarray(cfg.mode_frequency_hz)
    x0 = np.zeros(2 * nm)
    amp = np.where(rigid_mode, 0.0, sim["initial_modal_sigma"])
    if opt.scenario in ("free", "static"):
        x0[:nm] = rng.standard_normal(nm) * amp
        x0[nm:] = rng.standard_normal(nm) * amp * omega
        if rigid_mode.any() and cfg.rigid_index is not None:
            # rigid-body angle: q_rigid = U[rigid, j] ξ_j
            scale = U[cfg.rigid_index, rigid_mode]
            x0[:nm][rigid_mode] = rng.standard_normal(rigid_mode.sum()) * sim["initial_rigid_sigma_rad"] / scale
    else:
        x0[:nm] = rng.standard_normal(nm) * amp * 0.02       # nearly at rest
        if opt.scenario == "slew":
            x0[:nm][rigid_mode] = np.radians(sim["slew_from_deg"]) / U[cfg.rigid_index, rigid_mode]
    return x0


def _thruster_commands(cfg: StructureConfig, opt: SimOptions, time_s: np.ndarray):
    """(thruster forces (N, n_u) N, the actuator log or None): the pulse scenario fires the
    config's ``pulse_thrusters``; pulse and slew get a (possibly empty) log, free and static none."""
    sim = cfg.simulation
    names = list(cfg.thruster_names)
    u = np.zeros((len(time_s), len(names)))
    if opt.scenario in ("free", "static"):
        return u, None
    t0, dur, f = sim["pulse_time_s"], sim["pulse_duration_s"], sim["pulse_force_n"]
    on = (time_s >= t0 - 1e-9) & (time_s < t0 + dur - 1e-9)
    rows = []
    for tname in (sim["pulse_thrusters"] if opt.scenario == "pulse" else []):
        k = names.index(tname)
        u[on, k] = f
        rows.append((t0, tname, f))
        rows.append((t0 + dur, tname, 0.0))
    rows.sort(key=lambda r: (r[0], names.index(r[1])))
    return u, pd.DataFrame(rows, columns=["time_s", "actuator", "force_n"])


def _propagate(model, x0: np.ndarray, u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The open-loop modal state (N, 2 n_m), zero-order hold on ``u`` and ``w``."""
    x = np.empty((len(u), x0.size))
    x[0] = x0
    drive = u @ model.B.T + w @ model.Bw.T
    A_T = model.A.T
    for k in range(1, len(u)):
        x[k] = x[k - 1] @ A_T + drive[k - 1]
    return x


def _static_rest(cfg: StructureConfig, time_s: np.ndarray, q: np.ndarray, qdot: np.ndarray):
    """The static scenario: the free motion blended smoothly into rest at the surveyed angle.
    Returns (q, qdot, modal state x, truth segments: motion, settling, rest)."""
    sim = cfg.simulation
    t_rest, t_settle = sim["static_rest_after_s"], sim["static_settle_s"]
    target = np.zeros(cfg.n_q)
    if sim["static_angle_coordinate"]:
        target[cfg.coord_names.index(sim["static_angle_coordinate"])] = np.radians(sim["static_angle_deg"])
    s = np.clip((time_s - t_rest) / max(t_settle, 1e-9), 0.0, 1.0)
    blend = 0.5 - 0.5 * np.cos(np.pi * s)                 # smooth 0 → 1
    dblend = np.where((s > 0) & (s < 1), 0.5 * np.pi * np.sin(np.pi * s) / max(t_settle, 1e-9), 0.0)
    q_free = q
    q = (1 - blend)[:, None] * q_free + blend[:, None] * target
    qdot = (1 - blend)[:, None] * qdot + dblend[:, None] * (target - q_free)
    Uinv = np.linalg.pinv(np.asarray(cfg.mode_shapes))
    x = np.hstack([q @ Uinv.T, qdot @ Uinv.T])
    end = float(time_s[-1])
    rest_start = t_rest + t_settle
    segments = [{"kind": "motion", "start_s": 0.0, "end_s": float(min(t_rest, end))}]
    if t_rest < end:
        segments.append({"kind": "settling", "start_s": float(t_rest), "end_s": float(min(rest_start, end))})
    if rest_start < end:
        segments.append({"kind": "rest", "start_s": float(rest_start), "end_s": end,
                         "q": {nme: float(v) for nme, v in zip(cfg.coord_names, target)}})
    return q, qdot, x, segments


def _segments(cfg: StructureConfig, opt: SimOptions, time_s: np.ndarray) -> list[dict]:
    """truth.json segments of the free, pulse and slew scenarios."""
    sim = cfg.simulation
    end = float(time_s[-1])
    if opt.scenario == "pulse":
        t0, t1 = float(sim["pulse_time_s"]), float(sim["pulse_time_s"] + sim["pulse_duration_s"])
        return [{"kind": "rest", "start_s": 0.0, "end_s": t0},
                {"kind": "pulse", "start_s": t0, "end_s": t1,
                 "thrusters": list(sim["pulse_thrusters"]), "force_n": float(sim["pulse_force_n"])},
                {"kind": "free", "start_s": t1, "end_s": end}]
    if opt.scenario == "slew":
        return [{"kind": "rest", "start_s": 0.0, "end_s": float(sim["slew_time_s"]),
                 "rigid_angle_deg": float(sim["slew_from_deg"])},
                {"kind": "slew", "start_s": float(sim["slew_time_s"]), "end_s": end,
                 "command_deg": float(sim["slew_to_deg"])}]
    return [{"kind": "motion", "start_s": 0.0, "end_s": end}]


def _noise_scale_truth(cfg: StructureConfig, opt: SimOptions) -> dict:
    """truth.json: the ``--noise-scale`` factors and the white phase σ of every channel (empty without them)."""
    if not opt.noise_scale:
        return {}
    ant, tx = all_channels(cfg)
    s0 = cfg.simulation["phase_sigma_m"] if opt.phase_sigma_m is None else opt.phase_sigma_m
    f = noise_scale_per_channel(cfg, opt.noise_scale, ant, tx)
    return {"noise_scale": dict(opt.noise_scale),
            "phase_sigma_m_per_channel": {f"{cfg.antenna_names[a]}/{cfg.transmitter_names[t]}": float(s0 * v)
                                          for a, t, v in zip(ant, tx, f)}}


def _phase_log(cfg, opt, rng, time_s, q):
    """The receiver log (carrier phase, lock count, SNR per visible channel and epoch), the initial
    bias of every channel and its slip/relock events."""
    lam = cfg.wavelength_m
    n = len(time_s)
    ant, tx = all_channels(cfg)
    C = len(ant)
    h = phase_model_q(cfg, q, ant, tx)                          # (N, C)
    noise = _phase_noise(cfg, opt, rng, n, C)
    line_bias = cfg.antenna_line_bias_m[ant] - cfg.antenna_line_bias_m[cfg.master_index]
    ant_names = np.array(cfg.antenna_names, dtype=object)[ant]
    tx_names = np.array(cfg.transmitter_names, dtype=object)[tx]
    visible = _visibility(cfg, opt, time_s, tx)
    slip_at = _slip_schedule(cfg, opt, rng, time_s, C)
    y = h + line_bias + noise                                   # range + line bias + error, m (N, C)
    phase = np.empty((n, C))
    lock = np.zeros((n, C), dtype=np.int64)
    bias_records, slip_records = [], []
    for c in range(C):
        names = {"antenna": ant_names[c], "transmitter": tx_names[c]}
        integers, lock[:, c], events = _channel_integers(y[:, c], lam, visible[:, c], slip_at.get(c, []))
        bias_records.append({**names, "bias_m": float(line_bias[c] + lam * integers[0]),
                             "integer_cycles": int(integers[0]), "line_bias_m": float(line_bias[c])})
        slip_records += [{"time_s": float(time_s[k]), **names, "kind": kind, "integer_cycles_before": before,
                          "integer_cycles_after": new, "bias_m": float(line_bias[c] + lam * new)}
                         for k, kind, before, new in events]
        phase[:, c] = y[:, c] / lam + integers
    slip_records.sort(key=lambda r: (r["time_s"], r["antenna"], r["transmitter"]))
    return _receiver_table(cfg, rng, time_s, phase, lock, visible, ant_names, tx_names), bias_records, slip_records


def _visibility(cfg, opt, time_s, tx) -> np.ndarray:
    """(N, C) bool: every channel visible but during its transmitter's outages."""
    visible = np.ones((len(time_s), len(tx)), dtype=bool)
    for o in opt.outages:
        j = cfg.transmitter_names.index(o.transmitter)
        off = (time_s >= o.start_s - 1e-9) & (time_s < o.start_s + o.duration_s - 1e-9)
        visible[np.ix_(off, tx == j)] = False
    return visible


def _slip_schedule(cfg, opt, rng, time_s, C: int) -> dict:
    """{channel: [(epoch, cycles), …]}: the explicit slips plus random ones (random channel, time,
    ±1..5 cycles), each at the first epoch at or after its time (none at the first epoch)."""
    n = len(time_s)
    slips = [(s.time_s, cfg.rover_names.index(s.antenna) * len(cfg.transmitter_names)
              + cfg.transmitter_names.index(s.transmitter), s.cycles) for s in opt.slips]
    for _ in range(opt.random_slips):
        c = int(rng.integers(C))
        k = int(rng.integers(max(n // 10, 1), n))
        cyc = int(rng.integers(1, 6)) * (1 if rng.random() < 0.5 else -1)
        slips.append((float(time_s[k]), c, cyc))
    slip_at = {}
    for t, c, cyc in slips:
        k = int(np.searchsorted(time_s, t - 1e-9))
        if 0 < k < n:
            slip_at.setdefault(c, []).append((k, cyc))
    return slip_at


def _channel_integers(y: np.ndarray, lam: float, vis: np.ndarray, slips: list):
    """One channel's integer ambiguity per epoch (N,) int64, its lock count (N,) and its events
    ``(epoch, "slip" | "reacquisition", integer before, after)``.  Lock segments are the contiguous
    visible runs; a slip splits a run without losing signal; at each lock the integer makes the
    phase as written lie in [0, 1) cycles."""
    n = len(y)
    starts = list(np.flatnonzero(vis & ~np.r_[False, vis[:-1]]))
    todo = sorted([(k, "reacquisition", 0) for k in starts[1:]] + [(k, "slip", cyc) for k, cyc in slips if vis[k]])
    k0 = starts[0] if starts else 0
    integers = np.full(n, -int(np.floor(np.round(y[k0] / lam, 6))), dtype=np.int64)
    lock_start = np.full(n, k0)
    events = []
    for k, kind, cyc in todo:
        before = int(integers[k])
        new = before + cyc if kind == "slip" else -int(np.floor(np.round(y[k] / lam, 6)))
        integers[k:] = new
        lock_start[k:] = k
        events.append((k, kind, before, new))
    return integers, np.arange(n) - lock_start, events


def _receiver_table(cfg, rng, time_s, phase, lock, visible, ant_names, tx_names) -> pd.DataFrame:
    """receiver.csv: a row per visible channel and epoch, SNR the config's ``snr_dbhz`` ± 1 dB-Hz."""
    n, C = phase.shape
    snr = np.round(cfg.simulation["snr_dbhz"] + rng.standard_normal((n, C)), 1)
    rx_of = {a: cfg.antenna_receiver[i] for i, a in enumerate(cfg.antenna_names)}
    mask = visible.ravel()
    return pd.DataFrame({
        "time_s": np.repeat(time_s, C)[mask],
        "receiver": np.tile(np.array([rx_of[a] for a in ant_names], dtype=object), n)[mask],
        "master": cfg.antenna_names[cfg.master_index],
        "antenna": np.tile(ant_names, n)[mask],
        "transmitter": np.tile(tx_names, n)[mask],
        "phase_cycles": np.round(phase.ravel()[mask], 6),
        "lock": lock.ravel()[mask],
        "snr_dbhz": snr.ravel()[mask],
    })


def _phase_noise(cfg, opt, rng, n, C):
    """Carrier-phase error of every channel, m, shape (n, C): white noise plus first-order
    Gauss–Markov multipath (the config's [simulation] values unless the options override them)."""
    sim = cfg.simulation
    sigma = sim["phase_sigma_m"] if opt.phase_sigma_m is None else opt.phase_sigma_m
    mp_sigma = sim["multipath_sigma_m"] if opt.multipath_sigma_m is None else opt.multipath_sigma_m
    noise = rng.standard_normal((n, C)) * sigma
    if opt.noise_scale:
        ant, tx = all_channels(cfg)
        noise *= noise_scale_per_channel(cfg, opt.noise_scale, ant, tx)
    if mp_sigma > 0:
        a = np.exp(-cfg.sample_period_s / sim["multipath_time_constant_s"])
        e = rng.standard_normal((n, C)) * mp_sigma * np.sqrt(1 - a * a)
        e[0] = rng.standard_normal(C) * mp_sigma
        noise += lfilter([1.0], [1.0, -a], e, axis=0)
    return noise


def _gyro_log(cfg, rng, time_s, qdot):
    sim = cfg.simulation
    ng = len(cfg.gyro_names)
    if ng == 0:
        return pd.DataFrame({"time_s": [], "gyro": [], "rate_rad_s": []}), []
    n = len(time_s)
    G = gyro_matrix(cfg)
    rate = qdot @ G.T
    T = cfg.sample_period_s
    bias0 = rng.standard_normal(ng) * sim["gyro_bias_sigma_rad_s"]
    drift = np.cumsum(rng.standard_normal((n, ng)) * sim["gyro_bias_drift_rad_s_per_sqrt_s"] * np.sqrt(T), axis=0)
    drift -= drift[0]
    bias = bias0 + drift
    meas = rate + bias + rng.standard_normal((n, ng)) * sim["gyro_noise_rad_s"]
    df = pd.DataFrame({
        "time_s": np.repeat(time_s, ng),
        "gyro": np.tile(np.array(cfg.gyro_names, dtype=object), n),
        "rate_rad_s": np.round(meas.ravel(), 9),
    })
    info = [{"gyro": g, "bias_rad_s": float(bias0[i]), "final_bias_rad_s": float(bias[-1, i])}
            for i, g in enumerate(cfg.gyro_names)]
    return df, info


_write_atomic = write_atomic

#: every file ``write_simulation`` may write (its output set: replaced as a whole)
SIMULATION_FILES = ("receiver.csv", "gyro.csv", "truth.csv", "truth.json", "actuators.csv", "controller.csv")


def write_simulation(result: Simulation, out_dir: str | Path) -> dict:
    """Write receiver.csv, gyro.csv, truth.csv, truth.json (and actuators.csv) into ``out_dir``.

    The files replace an earlier simulation there as a set (:func:`cdgps_cli.io.atomic.output_set`):
    a failed or interrupted write leaves the earlier files untouched, a successful one leaves
    exactly the new set (a stale ``actuators.csv`` or ``controller.csv`` is removed; other files are kept).
    ``result.tables`` adds files to the set (the closed loop's controller.csv).  Returns a summary.
    """
    out = Path(out_dir)
    cfg = result.cfg
    files = {}
    with output_set(out, replaces=SIMULATION_FILES) as dest:
        def csv(df, name):
            _write_atomic(dest.path(name), lambda p: progress.to_csv(df, p, f"writing {name}", index=False,
                                                                     lineterminator="\n"))
            files[name] = str(out / name)

        csv(result.receiver, "receiver.csv")
        csv(result.gyro, "gyro.csv")
        truth_df = pd.DataFrame(np.round(result.q, 12), columns=coordinate_columns(cfg))     # q1_rad, qx-1_m …
        truth_df.insert(0, "time_s", result.time_s)
        csv(truth_df, "truth.csv")
        for name, df in result.tables.items():
            csv(df, name)
        if result.actuators is not None:
            csv(result.actuators, "actuators.csv")
        text = json.dumps(result.truth, indent=2, sort_keys=False) + "\n"
        _write_atomic(dest.path("truth.json"), lambda p: p.write_text(text))
        files["truth.json"] = str(out / "truth.json")
    return {"out_dir": str(out), "files": files, "epochs": int(len(result.time_s)),
            "receiver_rows": int(len(result.receiver)), "gyro_rows": int(len(result.gyro)),
            "slips": len(result.truth["slips"]), "scenario": result.options.scenario,
            "seed": result.options.seed, "config_sha256": cfg.sha256}
