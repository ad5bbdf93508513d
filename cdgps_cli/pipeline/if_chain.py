"""Simulated IF samples of a structure → tracking loops → differential carrier phase → receiver log
(issue 16 item 4): ``cdgps simulate-if`` and ``cdgps track-structure``.

:func:`simulate_if` writes one sample file per antenna (:mod:`cdgps_cli.sim.if_samples`, all
antennas on one receiver oscillator) and the manifest ``if.json``.  :func:`track_structure` tracks
every antenna's file with the loops of :mod:`cdgps_cli.tracking` (FFT acquisition, FLL pull-in,
Costas PLL, carrier-aided DLL) and writes the native receiver log (:mod:`cdgps_cli.io.logs`) from
the loops' NCO phases at the structure's epochs:

* phase_cycles = −(φ̂_a − φ̂_M) + ½·p + n, the antenna's tracked carrier phase minus the master's for
  the same transmitter, negated (the tracked baseband phase falls as the range grows,
  φ = … − ρ/λ; the log's phase grows with it: λ·phase = ρ_a − ρ_M + bias, :mod:`cdgps_cli.measurement.phase`).
  The receiver clock and the transmitter clock are common to both and cancel.
* p ∈ {0, 1}: the Costas loops leave each antenna's phase ambiguous by half a cycle; both antennas
  receive the same navigation bits, so the signs of their prompt correlations agree when their
  half cycles agree: p = 1 when the sign products over the epoch's 1 ms updates sum below zero.
  A change of p inside a lock segment is a half-cycle slip: a new segment starts.
* n: an integer per lock segment making the first phase of the segment lie in [0, 1) cycle
  (the convention of ``cdgps simulate``); ``init`` resolves the true integer.
* lock counts epochs since lock; a segment starts (lock 0) when both PLLs have run for ``settle_s``
  and both pass the noise-corrected lock indicator (:func:`epoch_lock`) over the interval since the
  last epoch; it ends when one fails, or at a half-cycle slip.  Epochs without lock have no row.
* snr_dbhz is the antenna's C/N0 (moments estimator over the 20 ms window).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.core import progress as _progress
from cdgps_cli.io.atomic import file_sha256, refuse_input_overwrite, write_atomic
from cdgps_cli.io.coordinate_columns import coordinate_columns, coordinate_table
from cdgps_cli.io.file_checks import refuse_deep_json
from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.options import TRACK_BLOCK_SAMPLES
from cdgps_cli.io.iq_samples import iter_samples, read_samples
from cdgps_cli.io.logs import RECEIVER_COLUMNS
from cdgps_cli.sim.if_samples import (C_M_S, FS_RANGE_HZ, KNOT_S, L1_HZ, MANIFEST_FORMAT, StructureIf,
                                      simulate_structure_if)
from cdgps_cli.tracking.acquisition import NONCOHERENT_MS, Acquisition, acquire
from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, CODE_LENGTH, G2_TAPS, ca_code
from cdgps_cli.tracking.channel import PHASE_LOCK_THRESHOLD, WINDOW, TrackOptions
from cdgps_cli.tracking.receiver import BlockTracker

#: external Doppler aids of :func:`track_structure`
AIDS = ("none", "truth", "gyro", "model")
#: how the loops start: FFT search, or the manifest's truth (an assisted start)
ACQUISITIONS = ("search", "truth")
#: keys every if.json must have
MANIFEST_KEYS = ("format", "sample_format", "iq_sign", "fs_hz", "if_hz", "samples", "start_s", "config_sha256",
                 "master", "transmitters", "antennas")


def simulate_if(cfg: StructureConfig, sim_dir: str | Path, out_dir: str | Path, spec: StructureIf | None = None,
                progress=None) -> dict:
    """:func:`cdgps_cli.sim.if_samples.simulate_structure_if` with the GPS C/A codes."""
    return simulate_structure_if(cfg, sim_dir, out_dir, {p: ca_code(p) for p in G2_TAPS}, spec, progress)


def read_manifest(path: str | Path) -> dict:
    """The manifest ``if.json`` of :func:`simulate_if`, checked (keys, format, the files' sizes)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
        refuse_deep_json(text, p, "the if.json written by 'cdgps simulate-if'")
        man = json.loads(text)
    except (OSError, ValueError) as exc:
        raise CdgpsError(f"{p}: cannot read the IF manifest: {exc}") from None
    if not isinstance(man, dict) or man.get("format") != MANIFEST_FORMAT:
        raise CdgpsError(f"{p}: not an IF manifest of `cdgps simulate-if` (format {MANIFEST_FORMAT!r})")
    missing = [k for k in MANIFEST_KEYS if k not in man]
    if missing:
        raise CdgpsError(f"{p}: missing key(s) {', '.join(missing)}")
    if man["sample_format"] != "int8-iq":
        raise CdgpsError(f"{p}: sample_format {man['sample_format']!r}: expected 'int8-iq'")
    _check_manifest_values(p, man)
    for a in man["antennas"]:
        f = p.parent / a["file"]
        size = f.stat().st_size if f.exists() else -1
        if size != 2 * man["samples"]:
            raise CdgpsError(f"{f}: {'missing' if size < 0 else f'{size} bytes'}; the manifest {p} says "
                             f"{2 * man['samples']} bytes ({man['samples']} int8 I/Q samples)")
    return man


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_manifest_values(p: Path, man: dict) -> None:
    """The manifest's numbers and lists are of the kind and range :func:`simulate_if` writes (a CdgpsError
    naming the file and the key otherwise)."""
    lo, hi = FS_RANGE_HZ
    fs = man["fs_hz"]
    if not (_number(fs) and lo <= fs <= hi and abs(fs * KNOT_S - round(fs * KNOT_S)) <= 1e-6):
        raise CdgpsError(f"{p}: fs_hz {fs!r}: expected a sample rate in Hz between {lo:g} and {hi:g}, a whole "
                         "number of samples per millisecond")
    if not (_number(man["if_hz"]) and abs(man["if_hz"]) < fs / 2):
        raise CdgpsError(f"{p}: if_hz {man['if_hz']!r}: expected a frequency in Hz below half the sample rate")
    if isinstance(man["samples"], bool) or not isinstance(man["samples"], int) or man["samples"] < 1:
        raise CdgpsError(f"{p}: samples {man['samples']!r}: expected a whole number of samples ≥ 1")
    if not _number(man["start_s"]):
        raise CdgpsError(f"{p}: start_s {man['start_s']!r}: expected a time in seconds")
    if man["iq_sign"] not in ("minus", "plus"):
        raise CdgpsError(f"{p}: iq_sign {man['iq_sign']!r}: expected 'minus' or 'plus'")
    for key, need in (("antennas", ("name", "file", "sha256")), ("transmitters", ("name", "prn"))):
        items = man[key]
        if not (isinstance(items, list) and items and all(isinstance(a, dict) and all(k in a for k in need)
                                                          for a in items)):
            raise CdgpsError(f"{p}: {key}: expected a non-empty list of objects with {', '.join(need)}")
        if not all(isinstance(a[k], str) for a in items for k in need if k != "prn"):
            raise CdgpsError(f"{p}: {key}: {', '.join(k for k in need if k != 'prn')} must be strings")
    prns = [t["prn"] for t in man["transmitters"]]
    if not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 32 for v in prns) or len(set(prns)) < len(prns):
        raise CdgpsError(f"{p}: transmitters: prn {prns!r}: expected distinct GPS PRNs 1-32")


def check_truth(p: Path, man: dict) -> None:
    """The manifest's ``truth`` (used by ``--aid truth`` and ``--acquisition truth``): epoch times and,
    per antenna and transmitter, range, Doppler and code phase at each epoch."""
    tr = man.get("truth")
    t = tr.get("time_s") if isinstance(tr, dict) else None
    if not (isinstance(t, list) and t and all(_number(v) for v in t) and isinstance(tr.get("antennas"), dict)):
        raise CdgpsError(f"{p}: truth: expected time_s (a list of times, s) and antennas (the aid and the "
                         "truth acquisition need them)")
    for a in man["antennas"]:
        for tx in man["transmitters"]:
            ch = tr["antennas"].get(a["name"], {})
            ch = ch.get(tx["name"]) if isinstance(ch, dict) else None
            ok = isinstance(ch, dict) and all(isinstance(ch.get(k), list) and len(ch[k]) == len(t)
                                              and all(_number(v) for v in ch[k])
                                              for k in ("range_m", "doppler_hz", "code_phase_chips"))
            if not ok:
                raise CdgpsError(f"{p}: truth.antennas.{a['name']}.{tx['name']}: expected range_m, doppler_hz and "
                                 f"code_phase_chips, {len(t)} numbers each (one per truth.time_s)")


@dataclass
class ChainOptions:
    """Loop settings and the logging rule of :func:`track_structure`."""

    track: TrackOptions = field(default_factory=TrackOptions)
    settle_s: float = 0.1           # PLL running this long (after any wide stage) before the phase is logged
    verify_sha256: bool = True      # check each sample file against the manifest's digest
    aid: str = "none"               # "truth": feed each PLL the true line-of-sight Doppler (truth_aid_hz);
                                    # "gyro" / "model": the Doppler of the gyro-derived antenna velocity
                                    # through the kinematics / through the mode shapes (gyro_aid_hz)
    gyro_csv: str | None = None     # gyro.csv of `cdgps simulate` (time_s, gyro, rate_rad_s), for those aids
    pose_csv: str | None = None     # the structure's pose at the first sample for those aids (truth.csv or an
                                    # estimate's states CSV; default: the rest pose), integrated on by the gyros
    acquisition: str = "search"     # "truth": start the loops from the manifest's true Doppler and code phase
    clock_bn_hz: float | None = None  # each antenna's channels share a clock loop of this bandwidth (Hz;
                                      # tracking.shared_clock, Alban et al.'s clock-error frequency), or not
    block_samples: int = TRACK_BLOCK_SAMPLES  # samples of a file read and tracked at a time (no effect on results)

    def check(self) -> None:
        if self.aid not in AIDS:
            raise CdgpsError(f"aid {self.aid!r}: expected one of {', '.join(AIDS)}")
        if (self.aid in ("gyro", "model")) != (self.gyro_csv is not None):
            raise CdgpsError("aids 'gyro' and 'model' need the gyro log (--gyro, gyro_csv: gyro.csv of `cdgps simulate`), and only they use it")
        if self.pose_csv is not None and self.aid not in ("gyro", "model"):
            raise CdgpsError("a start pose (--pose, pose_csv) is used by the aids 'gyro' and 'model' only")
        if self.acquisition not in ACQUISITIONS:
            raise CdgpsError(f"acquisition {self.acquisition!r}: expected one of {', '.join(ACQUISITIONS)}")
        if self.clock_bn_hz is not None and not (math.isfinite(self.clock_bn_hz) and 0 < self.clock_bn_hz <= 100):
            raise CdgpsError(f"clock_bn_hz {self.clock_bn_hz!r}: expected a clock loop bandwidth in (0, 100] Hz")
        if not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise CdgpsError(f"settle_s {self.settle_s!r}: expected a non-negative number of seconds")


def truth_aid_hz(man: dict, antenna: str, transmitter: str, time_s: np.ndarray) -> np.ndarray:
    """Line-of-sight Doppler −(dρ/dt)/λ (Hz) of one channel at ``time_s`` (s from the first sample),
    from the manifest's true ranges at the structure's epochs (cubic spline): the aid of a perfect
    inertial or structural-model prediction (no receiver or transmitter clock in it)."""
    from scipy.interpolate import CubicSpline

    t = np.asarray(man["truth"]["time_s"], dtype=float) - man["start_s"]
    rho = np.asarray(man["truth"]["antennas"][antenna][transmitter]["range_m"], dtype=float)
    if t.size < 4:
        raise CdgpsError("aid: the manifest holds fewer than 4 truth epochs (a file shorter than 4 epochs)")
    return -CubicSpline(t, rho)(np.clip(time_s, t[0], t[-1]), 1) / (C_M_S / L1_HZ)


def gyro_rates(cfg: StructureConfig, gyro_csv: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(time_s (n,), rates (n, n_g) rad/s in ``cfg.gyro_names`` order) from a gyro log of ``cdgps simulate``."""
    try:
        df = pd.read_csv(gyro_csv)
    except (OSError, ValueError) as exc:
        raise CdgpsError(f"{gyro_csv}: cannot read the gyro log: {exc}") from None
    need = {"time_s", "gyro", "rate_rad_s"}
    if not need <= set(df.columns):
        raise CdgpsError(f"{gyro_csv}: expected columns {', '.join(sorted(need))}, got {', '.join(df.columns)}")
    wide = df.pivot_table(index="time_s", columns="gyro", values="rate_rad_s", aggfunc="first")
    absent = [g for g in cfg.gyro_names if g not in wide.columns]
    if absent or wide[list(cfg.gyro_names)].isna().any().any() or len(wide) < 2:
        raise CdgpsError(f"{gyro_csv}: needs every epoch of gyro(s) {', '.join(cfg.gyro_names)} "
                         f"(missing: {', '.join(absent) or 'some epochs'})")
    return wide.index.to_numpy(dtype=float), wide[list(cfg.gyro_names)].to_numpy(dtype=float)


def gyro_coordinate_map(cfg: StructureConfig, through_modes: bool = False) -> np.ndarray:
    """(n_q, n_g) map from gyro rates to coordinate rates: G⁺ (kinematics only, minimum norm), or
    U (G U)⁺ with the mode shapes U (the structural model: q̇ = U η̇, η̇ fitted to the gyros)."""
    from cdgps_cli.model.kinematics import gyro_matrix

    G = gyro_matrix(cfg)
    if not through_modes:
        return np.linalg.pinv(G)
    U = np.asarray(cfg.mode_shapes, dtype=float)
    return U @ np.linalg.pinv(G @ U)


def gyro_observability_note(cfg: StructureConfig, through_modes: bool) -> str:
    """A warning when the gyros do not determine the coordinate rates (rank of G, or of G U through the
    mode shapes, below the count): the aid then guesses the unobserved motion (minimum norm) and can
    be worse than no aid on the channels that see it.  Empty when they do."""
    from cdgps_cli.model.kinematics import gyro_matrix

    G = gyro_matrix(cfg)
    A = G @ np.asarray(cfg.mode_shapes, dtype=float) if through_modes else G
    rank, n = int(np.linalg.matrix_rank(A)), A.shape[1]
    if rank >= n:
        return ""
    what = "modal" if through_modes else "coordinate"
    return (f"note: the {len(cfg.gyro_names)} gyros determine {rank} of the {n} {what} rates; the aid takes the "
            f"minimum-norm guess for the rest" + ("" if through_modes else
                                                  " (--aid model resolves more through the mode shapes)"))


def start_pose(cfg: StructureConfig, pose_csv: str | Path, time_s: float) -> np.ndarray:
    """The structure's coordinates (n_q,) at ``time_s`` (s), interpolated in a CSV with ``time_s`` and one
    column per coordinate of ``cfg`` (truth.csv of `cdgps simulate`, or the states CSV of `cdgps estimate`)."""
    try:
        df = pd.read_csv(pose_csv)
    except (OSError, ValueError) as exc:
        raise CdgpsError(f"{pose_csv}: cannot read the pose file: {exc}") from None
    df, missing = coordinate_table(df, cfg)              # q1_rad, or a bare q1 (files before issue 32)
    missing = [c for c in ("time_s",) if c not in df.columns] + missing
    if missing:
        raise CdgpsError(f"{pose_csv}: missing column(s) {', '.join(missing)}; expected time_s and the coordinates "
                         f"{', '.join(coordinate_columns(cfg))} (truth.csv of `cdgps simulate` or the states CSV of "
                         f"`cdgps export`)")
    t = df["time_s"].to_numpy(dtype=float)
    if t.size == 0 or not (t[0] - 1e-9 <= time_s <= t[-1] + 1e-9):
        span = f"{t[0]:g}–{t[-1]:g} s" if t.size else "no rows"
        raise CdgpsError(f"{pose_csv}: the samples start at {time_s:g} s, outside the pose file's span ({span})")
    return np.array([np.interp(time_s, t, df[c].to_numpy(dtype=float)) for c in cfg.coord_names])


def gyro_pose(time_s: np.ndarray, qdot: np.ndarray, t0_s: float, q0: np.ndarray) -> np.ndarray:
    """Coordinates (n, n_q) at the gyro epochs ``time_s`` (n,): ``q0`` at ``t0_s`` plus the trapezoidal
    integral of the coordinate rates ``qdot`` (n, n_q) — dead reckoning of the pose from the gyros."""
    steps = 0.5 * (qdot[1:] + qdot[:-1]) * np.diff(time_s)[:, None]
    integral = np.vstack([np.zeros((1, qdot.shape[1])), np.cumsum(steps, axis=0)])
    at_t0 = np.array([np.interp(t0_s, time_s, integral[:, j]) for j in range(qdot.shape[1])])
    return q0 + integral - at_t0


def gyro_aid_hz(cfg: StructureConfig, man: dict, gyro: tuple, antenna: str, transmitter: str,
                time_s: np.ndarray, through_modes: bool = False, q0: np.ndarray | None = None) -> np.ndarray:
    """Line-of-sight Doppler (Hz) of one channel from the structure's rate gyros, at ``time_s`` (s from
    the first sample).

    The rates with their biases and noise, ω (n_g), give the coordinate rates q̇ = M ω (M =
    :func:`gyro_coordinate_map`: G⁺ from ``kinematics.gyro_matrix``, or U (G U)⁺ through the structural
    model's mode shapes) and, integrated from the pose ``q0`` at the first sample (:func:`gyro_pose`;
    default the rest pose q = 0), the pose q̂(t).  The antenna velocity is v = J_a(q̂) q̇ (J_a = ∂p_a/∂q at
    the current pose: the rigid-body rotation of the testbed swings by tenths of a radian, so the rest
    pose's Jacobian points the velocities wrongly) and the Doppler −u·v/λ with u = ∂ρ/∂p_a the line of sight
    from the current antenna position to the transmitter (known).  Gyros measure rotation rates only: the
    motion of the coordinates that no gyro sees (translations, rigid sway; the null space of G) is missing
    from v; a gyro bias b gives a velocity error J_a M b and a pose drift M b t.
    """
    from cdgps_cli.model.kinematics import antenna_positions
    from cdgps_cli.sim.if_samples import line_of_sight_range_m, Transmitter

    t_g, w = gyro
    qdot = w @ gyro_coordinate_map(cfg, through_modes).T                   # (n, n_q)
    q_hat = gyro_pose(t_g, qdot, man["start_s"], np.zeros(cfg.n_q) if q0 is None else np.asarray(q0, dtype=float))
    p, J = antenna_positions(cfg, q_hat, jacobian=True)
    a = list(cfg.antenna_names).index(antenna)
    tx = next(t for t in man["transmitters"] if t["name"] == transmitter)
    try:
        tr = Transmitter(**tx)
    except TypeError as exc:                   # a hand-edited manifest: a key missing or unknown
        raise CdgpsError(f"IF manifest transmitters: {transmitter}: {exc} (expected the keys of `cdgps simulate-if`)") from None
    pa = p[:, a]                                                            # (n, 3)
    h = 1e-4                                                                # central difference of ρ(p): u = ∂ρ/∂p
    u = np.stack([(line_of_sight_range_m(tr, pa + h * e) - line_of_sight_range_m(tr, pa - h * e)) / (2 * h)
                  for e in np.eye(3)], axis=1)
    rho_dot = np.einsum("ni,nij,nj->n", u, J[:, a], qdot)                  # (n,)
    return -np.interp(np.asarray(time_s) + man["start_s"], t_g, rho_dot) / (C_M_S / L1_HZ)


def _truth_start(man: dict, antenna: str, prns: list) -> list:
    """Acquisition results from the manifest's truth at the first sample (an assisted start: Doppler
    and code phase at the first truth epoch, the code phase carried back to the first sample)."""
    tx_of = {int(t["prn"]): t["name"] for t in man["transmitters"]}
    dt = man["truth"]["time_s"][0] - man["start_s"]
    out = []
    for prn in prns:
        tr = man["truth"]["antennas"][antenna][tx_of[prn]]
        dop = float(tr["doppler_hz"][0])
        code = (tr["code_phase_chips"][0] - CHIP_RATE_HZ * (1 + dop / L1_HZ) * dt) % CODE_LENGTH
        out.append(Acquisition(prn=prn, acquired=True, doppler_hz=dop, code_phase_chips=float(code),
                               code_phase_samples=0, peak_ratio=float("inf")))
    return out


def _track_antenna(path: Path, man: dict, prns: list, opt: ChainOptions, say, antenna: str = "",
                   gyro_aid=None) -> dict:
    """Acquire the manifest's PRNs in one antenna's file and track those found (a PRN not acquired
    gives its channels no rows and is listed under ``missing``); ``opt.aid`` feeds each loop its
    line-of-sight Doppler (:func:`truth_aid_hz`, or ``gyro_aid``); with ``opt.clock_bn_hz`` the channels
    share a clock loop (:func:`cdgps_cli.tracking.shared_clock.track_shared_clock`).  The file is read and
    tracked in blocks of ``opt.block_samples`` (:class:`cdgps_cli.tracking.receiver.BlockTracker`)."""
    fs, if_hz, total = man["fs_hz"], man["if_hz"], man["samples"]
    if opt.acquisition == "search":
        head = read_samples(path, "int8-iq", man["iq_sign"], max_samples=round(fs * 1e-3) * NONCOHERENT_MS)
        acq = acquire(head, fs, prns, if_hz=if_hz)
    else:
        acq = _truth_start(man, antenna, prns)
    found = [a for a in acq if a.acquired]
    missing = [{"prn": a.prn, "peak_ratio": a.peak_ratio, "peak_to_noise": a.peak_to_noise, "threshold": a.threshold}
               for a in acq if not a.acquired]
    if not found:
        raise CdgpsError(f"{path}: none of PRN {', '.join(map(str, prns))} acquired (peak over noise, threshold: "
                         + ", ".join(f"{m['peak_to_noise']:.2f}, {m['threshold']:.2f}" for m in missing) + ")")
    tx_of = {int(t["prn"]): t["name"] for t in man["transmitters"]}
    n = int(round(fs * KNOT_S))
    aids = {}
    for a in found:
        aid = None
        if opt.aid == "truth":
            aid = truth_aid_hz(man, antenna, tx_of[a.prn], np.arange(total // n) * n / fs)
        elif opt.aid in ("gyro", "model"):
            aid = gyro_aid(antenna, tx_of[a.prn], np.arange(total // n) * n / fs)
        aids[a.prn] = aid
    starts = [(a.prn, a.doppler_hz - (aids[a.prn][0] if aids[a.prn] is not None else 0.0), a.code_phase_chips)
              for a in found]
    rx = BlockTracker(fs, starts, opt.track, n_samples=total, if_hz=if_hz, aids=[aids[a.prn] for a in found],
                      clock_bn_hz=opt.clock_bn_hz)
    for blk in iter_samples(path, "int8-iq", man["iq_sign"], block_samples=opt.block_samples, max_samples=total):
        rx.feed(blk)
    tracks = dict(zip([a.prn for a in found], rx.results()))
    sats = []
    for a in found:
        r = tracks[a.prn]
        cn0 = r["cn0_dbhz"][::WINDOW][-5:]
        sats.append({"prn": a.prn, "doppler_hz": float(np.mean(r["doppler_hz"][-100:])),
                     "cn0_dbhz": float(np.nanmedian(cn0)) if np.isfinite(cn0).any() else None,
                     "phase_lock_fraction": float(np.mean(r["phase_lock"][::WINDOW] > PHASE_LOCK_THRESHOLD))})
    say(f"  {path.name}: " + ", ".join(f"PRN {s['prn']} {s['cn0_dbhz'] or float('nan'):.1f} dB-Hz"
                                       for s in sats)
        + "".join(f", PRN {m['prn']} not acquired (peak {m['peak_to_noise']:.2f} × noise, threshold {m['threshold']:.2f})" for m in missing))
    return {"tracks": tracks, "satellites": sats, "missing": missing}


def _running(r: dict, opt: ChainOptions, T: float) -> np.ndarray:
    """Per 1 ms update: the PLL has run for settle_s (after its wide stage, if any)."""
    pll = np.flatnonzero(r["pll"])
    ok = np.zeros(r["pll"].size, dtype=bool)
    if pll.size:
        wide = opt.track.wide_pll_s if opt.track.pll_bn_hz < opt.track.wide_pll_hz else 0.0
        ok[pll[0] + int(round((wide + opt.settle_s) / T)):] = True
    return ok


def epoch_lock(r: dict, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Noise-corrected phase-lock indicator per interval of updates [lo, hi): Σ(I² − Q²) over N times the
    signal power P_d of the moments (M2M4) estimator.  The noise adds equally to I² and Q², so this is
    an unbiased estimate of the mean cos 2φ (1 in lock, 0 for a rotating phase), usable at C/N0 where
    the channel's 20 ms indicator (I² − Q²)/(I² + Q²) stays below its threshold (0.8 needs about 40 dB-Hz).
    A phase rotating by less than about half a cycle within the interval (a frequency error below
    about 5 Hz over 100 ms) is not averaged out: such slips show as data-bit parity changes or not at all."""
    i, q = r["i_prompt"], r["q_prompt"]
    p = i * i + q * q
    c = [np.r_[0.0, np.cumsum(v)] for v in (i * i - q * q, p, p * p)]
    n = np.maximum(hi - lo, 1)
    m2, m4 = (c[1][hi] - c[1][lo]) / n, (c[2][hi] - c[2][lo]) / n
    pd = np.sqrt(np.maximum(2 * m2 * m2 - m4, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(pd > 0, (c[0][hi] - c[0][lo]) / n / pd, 0.0)


#: epoch-level lock threshold on :func:`epoch_lock` (cos 2φ = 0.5 at a 30° phase error)
EPOCH_LOCK_THRESHOLD = 0.5


def differential_phase(ra: dict, rm: dict, epochs: np.ndarray, opt: ChainOptions, T: float) -> dict:
    """Differential phase of one channel at the epoch updates ``epochs`` (indices of 1 ms updates).

    An epoch has a row when both loops run (settled) through the interval since the previous epoch,
    both pass :func:`epoch_lock` over it and the data-bit vote on the half cycle is clear.

    Returns ``ok`` (bool, a row), ``phase_cycles`` (with each segment's integer), ``lock`` (epochs since lock),
    ``parity`` (the half cycle p), ``segments`` (count).
    """
    good = _running(ra, opt, T) & _running(rm, opt, T)
    bad_cum = np.r_[0, np.cumsum(~good)]
    agree = np.r_[0.0, np.cumsum(np.sign(ra["i_prompt"]) * np.sign(rm["i_prompt"]))]
    prev = np.r_[-1, epochs[:-1]]
    lo = np.maximum(prev + 1, 0)
    hi = epochs + 1
    ok = (bad_cum[hi] - bad_cum[lo] == 0) & good[epochs]
    ok &= (epoch_lock(ra, lo, hi) > EPOCH_LOCK_THRESHOLD) & (epoch_lock(rm, lo, hi) > EPOCH_LOCK_THRESHOLD)
    vote = agree[hi] - agree[lo]
    ok &= np.abs(vote) >= 0.2 * (hi - lo)          # data-bit agreement clear (not a mixed epoch)
    parity = (vote < 0).astype(int)
    raw = -(ra["carrier_phase_cycles"][epochs] - rm["carrier_phase_cycles"][epochs]) + 0.5 * parity
    phase = np.full(epochs.size, np.nan)
    lock = np.zeros(epochs.size, dtype=np.int64)
    segments, start, count = 0, None, 0
    for i in range(epochs.size):
        if not ok[i]:
            start = None
            continue
        if start is None or parity[i] != parity[i - 1] or not ok[i - 1]:
            start, count, segments = raw[i], 0, segments + 1
            offset = -math.floor(start)
        phase[i] = raw[i] + offset
        lock[i] = count
        count += 1
    return {"ok": ok, "phase_cycles": phase, "lock": lock, "parity": parity, "segments": segments}


def track_structure(manifest_path: str | Path, cfg: StructureConfig, out_csv: str | Path,
                    opt: ChainOptions | None = None, progress=None) -> dict:
    """Track every antenna's samples of an IF manifest and write the receiver log ``out_csv``.

    Returns a summary: rows, epochs, per channel the rows, lock segments and C/N0, per antenna the
    tracking summary of each satellite.  Nothing is written when a file or a PRN fails.
    """
    opt = opt or ChainOptions()
    opt.check()
    say = progress or (lambda m: None)
    path = Path(manifest_path)
    man = read_manifest(path)
    if man["config_sha256"] != cfg.sha256:
        raise CdgpsError(f"{path}: simulated with another config than {cfg.path} (config_sha256 differs)")
    refuse_input_overwrite([("out_csv", out_csv, False)],
                           [("manifest", path, False)] + [("sample file", path.parent / a["file"], False) for a in man["antennas"]])
    if "truth" in (opt.aid, opt.acquisition):
        check_truth(path, man)
    names = [a["name"] for a in man["antennas"]]
    master = cfg.antenna_names[cfg.master_index]
    if master not in names:
        raise CdgpsError(f"{path}: no samples of the master antenna {master!r}")
    tx_of = {int(t["prn"]): t["name"] for t in man["transmitters"]}
    prns = sorted(tx_of)
    T = round(man["fs_hz"] * KNOT_S) / man["fs_hz"]
    gyro_aid = None
    if opt.aid in ("gyro", "model"):
        rates = gyro_rates(cfg, opt.gyro_csv)
        q0 = None if opt.pose_csv is None else start_pose(cfg, opt.pose_csv, man["start_s"])
        note = gyro_observability_note(cfg, opt.aid == "model")
        if note:
            say(note)
        gyro_aid = lambda ant, tx, t: gyro_aid_hz(cfg, man, rates, ant, tx, t, opt.aid == "model", q0)  # noqa: E731
    per = {}
    for a in man["antennas"]:
        f = path.parent / a["file"]
        if opt.verify_sha256 and file_sha256(f) != a["sha256"]:
            raise CdgpsError(f"{f}: sha256 differs from the manifest's (the file was changed)")
        say(f"tracking {a['name']} ({f.name}) …")
        per[a["name"]] = _track_antenna(f, man, prns, opt, say, a["name"], gyro_aid)
    n_upd = min(len(r["time_s"]) for p in per.values() for r in p["tracks"].values())
    period = cfg.sample_period_s
    t_end = man["start_s"] + n_upd * T
    first = math.ceil(man["start_s"] / period - 1e-9)
    epoch_t = np.arange(first, math.floor(t_end / period - 1e-9) + 1) * period
    epochs = np.rint((epoch_t - man["start_s"]) / T).astype(np.int64)
    keep = (epochs >= 0) & (epochs < n_upd)
    epoch_t, epochs = np.round(epoch_t[keep], 9), epochs[keep]
    rows, channels = [], []
    rx_of = dict(zip(cfg.antenna_names, cfg.antenna_receiver))
    for ant in cfg.rover_names:
        if ant not in per:
            continue
        for tx in cfg.transmitter_names:
            prn = next((p for p, n in tx_of.items() if n == tx), None)
            if prn is None:
                continue
            if prn not in per[ant]["tracks"] or prn not in per[master]["tracks"]:
                channels.append({"antenna": ant, "transmitter": tx, "prn": prn, "rows": 0, "segments": 0,
                                 "cn0_dbhz": None, "not_acquired": True})
                continue
            ra, rm = per[ant]["tracks"][prn], per[master]["tracks"][prn]
            d = differential_phase(ra, rm, epochs, opt, T)
            cn0 = ra["cn0_dbhz"][epochs]
            sel = np.flatnonzero(d["ok"])
            rows.append(pd.DataFrame({"time_s": epoch_t[sel], "receiver": rx_of[ant], "master": master, "antenna": ant,
                                      "transmitter": tx, "phase_cycles": np.round(d["phase_cycles"][sel], 6),
                                      "lock": d["lock"][sel],
                                      "snr_dbhz": np.where(np.isfinite(cn0[sel]), np.round(cn0[sel], 1), np.nan)}))
            channels.append({"antenna": ant, "transmitter": tx, "prn": prn, "rows": int(sel.size),
                             "segments": d["segments"],
                             "cn0_dbhz": float(np.nanmedian(cn0)) if np.isfinite(cn0).any() else None})
    if not rows or sum(len(r) for r in rows) == 0:
        raise CdgpsError(f"{path}: no epoch with both the master and a rover antenna in phase lock; nothing written")
    order = {n: i for i, n in enumerate(cfg.antenna_names)}, {n: i for i, n in enumerate(cfg.transmitter_names)}
    df = pd.concat(rows, ignore_index=True)
    df = df.assign(_a=df["antenna"].map(order[0]), _t=df["transmitter"].map(order[1]))
    df = df.sort_values(["time_s", "_a", "_t"], kind="stable")[list(RECEIVER_COLUMNS)]
    write_atomic(out_csv, lambda p: _progress.to_csv(df, p, "writing receiver log", index=False,
                                                     lineterminator="\n", na_rep=""))
    return {"output": str(out_csv), "manifest": str(path), "rows": int(len(df)), "epochs": int(epochs.size),
            "start_s": float(epoch_t[0]) if epoch_t.size else None, "channels": channels,
            "antennas": {n: {"satellites": p["satellites"], "not_acquired": p["missing"]} for n, p in per.items()},
            "options": {**opt.track.__dict__,
                                                                                   "settle_s": opt.settle_s, "aid": opt.aid, "acquisition": opt.acquisition,
                        "pose": opt.pose_csv, "clock_bn_hz": opt.clock_bn_hz}}


# ---------------------------------------------------------------------------------------------
# command-line values (the messages name the options of `cdgps simulate-if`)


def parse_cn0(texts) -> tuple[float | None, dict]:
    """``--cn0`` values: ``DB`` for every transmitter, ``NAME:DB`` for one (repeatable) → (DB or None, {NAME: DB})."""
    every, per = None, {}
    for text in texts:
        name, _, val = str(text).strip().rpartition(":")
        try:
            v = float(val)
        except ValueError:
            v = float("nan")
        if not math.isfinite(v):
            raise CdgpsError(f"--cn0 {text!r}: expected DB or TRANSMITTER:DB (dB-Hz), e.g. 45 or PL3:38")
        if name:
            per[name] = v
        else:
            every = v
    return every, per


def parse_prns(texts) -> dict:
    """``--prn NAME:PRN`` (repeatable) → {transmitter: PRN}."""
    out = {}
    for text in texts:
        name, _, val = str(text).strip().rpartition(":")
        if not name or not val.isdigit():
            raise CdgpsError(f"--prn {text!r}: expected TRANSMITTER:PRN, e.g. PL1:7")
        out[name] = int(val)
    return out


def parse_oscillator(text: str, offset_ppm: float = 0.0):
    """``--oscillator H0,H_1,H_2`` (fractional-frequency PSD coefficients) and ``--clock-offset-ppm``."""
    from cdgps_cli.sim.if_samples import Oscillator

    try:
        h = [float(v) for v in str(text).split(",")]
    except ValueError:
        h = []
    if len(h) != 3 or not all(math.isfinite(v) and v >= 0 for v in h):
        raise CdgpsError(f"--oscillator {text!r}: expected three non-negative numbers H0,H-1,H-2, e.g. 1e-21,1e-22,1e-24")
    osc = Oscillator(h[0], h[1], h[2], offset_ppm * 1e-6)
    try:
        osc.check()
    except CdgpsError as exc:
        raise CdgpsError(f"--clock-offset-ppm {offset_ppm:g}: {exc}") from None
    return osc
