"""Extended Kalman filter and Rauch–Tung–Striebel smoother of the structure's modal state.

Teague, How & Parkinson (1998) Eq. 16–23, in information form with diagonal R = diag(σ_c²), one σ
per channel (antenna, transmitter): INIT's per-channel estimate (the batch's variance factors), or
``--sigma-m`` for all:

    time update        x̄_k = A x_{k−1} + B u_{k−1},   P̄_k = A P_{k−1} Aᵀ + B_w W B_wᵀ
    measurement update P_k = (P̄_k⁻¹ + H_kᵀ R⁻¹ H_k)⁻¹            (Eq. 20, by Cholesky: stays SPD)
                       ρ_k = Δφ_k − h(x̄_k) − b,  K = P_k H_kᵀ R⁻¹,  x_k = x̄_k + K ρ_k   (Eq. 21–23)

Biases come from INIT.json (``biases="fixed"``) or are carried in the state with a small fictitious
process noise (``biases="states"``, the 1995 paper's variant).  Integrity: each epoch's normalized
innovation squared (NIS) is tested against its chi-square bound; a channel whose lock counter
restarts, or whose normalized innovation is an outlier, has its bias dropped and re-estimated from
the filter's prediction over a short window (its integer re-fixed when the float value is
unambiguous).  Persistent NIS failures trigger a batch re-initialization on a window after the
event, as in the 1995 paper's Fig. 7.  Every event is logged (time, channel, kind, action).
The epoch loop is the engine's one driver (:func:`cdgps_cli.estimation.driver.drive`); the
integrity logic is its hooks (:mod:`cdgps_cli.estimation.integrity`, :class:`cdgps_cli.estimation.rest.StaticMode`).

Speed: with fixed biases the steady-state epochs (no lock event, no channel being re-estimated, no
outlier, no re-initialization) run in the compiled kernel of :mod:`cdgps_cli.estimation.kernel` (same
arithmetic, sparse A, H non-zero only in the position columns), which returns to the driver at the
first epoch that needs a hook; the smoother's pass is compiled too.  Without the extension (or
with ``CDGPS_NO_KERNEL=1``) every epoch runs through the driver's numpy update, with the same
results to rounding.

Multipath: when INIT.json has a ``multipath`` model (:mod:`cdgps_cli.measurement.multipath`, from ``[model]
multipath_sigma_m`` or ``init --multipath-sigma-m``), each channel gets a first-order Gauss–Markov
state after the structure (and bias) states — transition exp(−T/τ), process noise σ²(1 − exp(−2T/τ)),
started from INIT's window-end estimate with its covariance and cross-covariance — that enters its
phase additively; those runs use the numpy path (the compiled kernel has no such states), the
others keep the kernel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from cdgps_cli.estimation import kalman

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.estimation import kernel as ekf_kernel
from cdgps_cli.core import progress
from cdgps_cli.config.options import ESTIMATE_CHUNK_EPOCHS, ESTIMATE_DEFAULTS
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.limits import INIT_BOUNDS, OPTION_BOUNDS
from cdgps_cli.core.checks import has_bool, is_json_number, require_finite
from cdgps_cli.measurement.model import PseudoliteSD, Rows
from cdgps_cli.measurement.phase import channel_indices, phase_model, row_channel_indices
from cdgps_cli.measurement.channels import lock_segments
from cdgps_cli.measurement import multipath
from cdgps_cli.measurement.noise import filter_sigma_estimate, init_channel_sigma_m
from cdgps_cli.core.records import Run
from cdgps_cli.estimation.window_smoother import batch_window, extend_smoothing, window_states
from cdgps_cli.estimation.smoother import rts_smooth
from cdgps_cli.estimation.driver import EpochGrid, HistorySink, drive
from cdgps_cli.estimation.history import MemoryHistory
from cdgps_cli.estimation.integrity import (EpochDynamics, LockRestart, NewBiasStates, OutlierGate, PhaseRows, PostFit,
                                            Rebias, Reinit)
from cdgps_cli.estimation.rest import (REST_ENTRY_POSITION_INFLATION, REST_NIS_FAILURES, StaticMode,
                                       q_segments as _q_segments, rest_mask, rest_motion, true_runs as _true_runs,
                                       validate_rest_segments, velocity_nis, zero_velocity_update)

# moved to rest.py with the static-mode hook; still importable from here
_MOVED_TO_REST = (REST_ENTRY_POSITION_INFLATION, REST_NIS_FAILURES, rest_motion, velocity_nis, zero_velocity_update)


@dataclass
class EstimateOptions:
    """Options of :func:`estimate` (all echoed in STATES.mcap metadata)."""

    biases: str = "fixed"              # "fixed" (from INIT) or "states" (estimated in the filter)
    smooth: bool = False               # Rauch–Tung–Striebel pass after the filter
    sigma_m: float | None = None       # measurement noise of every channel (default: INIT's per channel, else config)
    channel_sigma_m: dict | None = None  # {(antenna, transmitter): σ (m)}: per-channel σ (overrides INIT's; not with sigma_m)
    adapt_sigma: bool = True           # innovation-based σ: re-run once with it when the NIS disagrees
    bias_process_sigma_m: float = 1e-4  # per-epoch random walk of bias states (biases="states")
    nis_probability: float = ESTIMATE_DEFAULTS["nis_probability"]     # chi-square test level of the per-epoch NIS
    outlier_sigma: float = ESTIMATE_DEFAULTS["outlier_sigma"]         # |ν_i| / sqrt(S_ii) above this → suspected slip on channel i
    rebias_epochs: int = 10            # epochs used to re-estimate a dropped channel's bias
    refix_max_sigma_cycles: float = 0.1   # re-fix the integer when the float's sigma is below this
    refix_max_offset_cycles: float = 0.25  # … and it is this close to an integer
    reinit_after_epochs: int = 20      # consecutive NIS failures → batch re-initialization
    reinit_window_s: float = 30.0
    restart_sigma_cycles: float = 10.0  # biases="states": variance inflation at a lock restart
    keep_filtered_covariance: str = "full"  # with smooth: "full" (n×n) or "modal" (the n_m×n_m block the outputs use)
    process_noise_scale: float = ESTIMATE_DEFAULTS["process_noise_scale"]   # multiplies the config's process-noise sigma (Q × scale²), filter and smoother
    rest_segments_s: tuple = ()        # ((start_s, end_s), …): the structure is declared at rest (static mode)
    rest_process_noise_scale: float = ESTIMATE_DEFAULTS["rest_process_noise_scale"] # … and there the process-noise sigma is further multiplied by this
    rest_retry_s: float = ESTIMATE_DEFAULTS["rest_retry_s"]          # after the data contradict a rest segment, try rest again this much later (0: never)
    rest_auto: bool = False            # rest segments found from the data (zero-velocity test, :mod:`cdgps_cli.estimation.rest`)
    rest_window_s: float = ESTIMATE_DEFAULTS["rest_window_s"]         # … its sliding window
    rest_dwell_s: float = ESTIMATE_DEFAULTS["rest_dwell_s"]          # … and how long it must pass before rest is entered
    progress: object = None
    init_source: str = "INIT.json"     # how messages name the INIT (its path); not echoed in outputs
    # where the forward pass keeps x_k, P_k for the smoother (None: in memory, estimation.history.MemoryHistory;
    # cdgps estimate gives io.scratch.DiskHistory) and every how many epochs it drops pages it is done with;
    # keep_covariance "modal": the result's P holds only the n_m×n_m modal-position block (what STATES
    # --covariance modal stores).  None of the three changes a number; not echoed in outputs
    history: object = None
    chunk_epochs: int = ESTIMATE_CHUNK_EPOCHS
    keep_covariance: str = "full"

    def echo(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k not in _NOT_ECHOED}
        # JSON has no infinity: an open-ended rest segment is echoed with end null
        d["rest_segments_s"] = [[float(a), None if np.isinf(float(b)) else float(b)] for a, b in self.rest_segments_s]
        if self.channel_sigma_m:
            d["channel_sigma_m"] = {f"{a}/{t}": float(v) for (a, t), v in self.channel_sigma_m.items()}
        return d


_NOT_ECHOED = ("progress", "init_source", "history", "chunk_epochs", "keep_covariance")


@dataclass
class EstimateResult:
    cfg: StructureConfig
    time_s: np.ndarray            # (N,)
    x: np.ndarray                 # (N, n) filtered (or smoothed) modal state
    P: np.ndarray                 # (N, n, n)
    x_filt: np.ndarray | None
    P_filt: np.ndarray | None
    channels: list                # [(antenna, transmitter)]
    residual_m: np.ndarray        # (N, C) post-fit residual (NaN where not used)
    nis: np.ndarray               # (N,)
    nis_dof: np.ndarray           # (N,) int
    events: list = field(default_factory=list)
    biases: dict = field(default_factory=dict)   # channel → final bias (m)
    smoothed: bool = False
    filter_path: str = "numpy"    # "c": steady-state epochs ran in the compiled kernel (ekf_kernel)
    window: dict | None = None    # INIT's batch window when its epochs come from the batch solution
    rest_active_s: list = field(default_factory=list)   # [[start_s, end_s]]: epochs that ran in static mode
    rest_detection: dict | None = None   # --rest auto: detector settings, sigma and segments (rest_detect)
    noise: dict = field(default_factory=dict)    # σ used (RMS and per channel), its source, the innovation-based estimates


# Test hook: when a dict, ``estimate`` records in it the prior covariance of every numpy-path
# measurement update ("prior": {k: P̄}), the prior of every zero-velocity update ("zupt": {k: P̄}), and the
# smoother's inputs (A, Q, Q_rest, at_rest, extra_q, no_link, filtered P).  None in normal use.
_TRACE: dict | None = None


def load_init_state(init: dict, cfg: StructureConfig, source: str = "INIT.json") -> tuple[float, np.ndarray, np.ndarray, dict]:
    """Initial time, state, covariance and per-channel biases (current segments) from INIT.json.

    ``source`` names the INIT file in the messages (its path).
    """
    problems = []
    for key in ("state", "biases", "config_sha256"):
        if key not in init:
            problems.append(f"missing key {key!r}")
    if problems:
        raise CdgpsError(f"{source}: " + "; ".join(problems))
    if not isinstance(init["config_sha256"], str):
        raise CdgpsError(f"{source}: config_sha256: expected the config's sha256 as text, got {init['config_sha256']!r}")
    if init["config_sha256"] != cfg.sha256:
        raise CdgpsError(f"{source} was made with a different structure config than the RUN "
                         f"(INIT config_sha256 {init['config_sha256'][:12]}…, RUN {cfg.sha256[:12]}…)")
    st = init["state"]
    n = cfg.n_states
    try:
        x = np.asarray(st["x"], dtype=float)
        P = np.asarray(st["P"], dtype=float)
        t0 = float(st["time_s"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CdgpsError(f"{source}: state: expected time_s, x ({n} numbers) and P ({n}×{n}): {exc}") from None
    if not math.isfinite(t0):
        raise CdgpsError(f"{source}: state.time_s: expected a finite time in seconds, got {st['time_s']!r}")
    if has_bool(st["x"]) or has_bool(st["P"]) or isinstance(st["time_s"], bool):
        raise CdgpsError(f"{source}: state: time_s, x and P must be numbers, not true/false")
    if x.shape != (n,) or P.shape != (n, n) or not np.all(np.isfinite(P)) or not np.all(np.isfinite(x)):
        raise CdgpsError(f"{source}: state: expected x of {n} numbers and P of {n}×{n} finite numbers")
    for name, v in (("state.x", x), ("state.P", P)):
        b = INIT_BOUNDS[name]
        if not np.all((v >= b.lo) & (v <= b.hi)):
            raise CdgpsError(f"{source}: {name}: values outside the plausible range {b.text()} "
                             f"(largest magnitude {float(np.max(np.abs(v))):g})")
    P = 0.5 * (P + P.T)
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        raise CdgpsError(f"{source}: state.P is not positive definite") from None
    if not isinstance(init["biases"], list):
        raise CdgpsError(f"{source}: biases: expected a list of objects {{antenna, transmitter, bias_m, …}}")
    biases = {}
    problems = []
    for i, b in enumerate(init["biases"]):
        if not isinstance(b, dict):
            problems.append(f"biases[{i}]: expected an object")
            continue
        try:
            key = (str(b["antenna"]), str(b["transmitter"]))
            if not is_json_number(b["bias_m"]) or not isinstance(b.get("current", True), bool):
                raise TypeError
            val = float(b["bias_m"])
        except (KeyError, TypeError, ValueError):
            problems.append(f"biases[{i}]: expected antenna, transmitter, a numeric bias_m (not true/false) and a "
                            f"boolean current")
            continue
        if key[0] not in cfg.rover_names:
            problems.append(f"biases[{i}]: antenna {key[0]!r} is not a rover antenna of the config")
        elif key[1] not in cfg.transmitter_names:
            problems.append(f"biases[{i}]: transmitter {key[1]!r} is not in the config")
        elif not np.isfinite(val):
            problems.append(f"biases[{i}]: bias_m is not finite")
        elif b.get("current", True) and key in biases:
            problems.append(f"biases[{i}]: a second current bias for {key[0]}/{key[1]} (one per channel)")
        elif b.get("current", True):
            biases[key] = val
    if problems:
        raise CdgpsError(f"{source}: " + "; ".join(problems[:10]) + (f" (+{len(problems) - 10} more)" if len(problems) > 10 else ""))
    sig = init.get("sigma_m")
    if sig is not None and (isinstance(sig, bool) or not isinstance(sig, (int, float)) or not sig > 0):
        raise CdgpsError(f"{source}: sigma_m: expected a positive number, got {sig!r}")
    if sig is not None and not OPTION_BOUNDS["sigma_m"].contains(sig):
        raise CdgpsError(f"{source}: sigma_m = {sig!r} m is outside the plausible range {OPTION_BOUNDS['sigma_m'].text()}")
    return t0, x, P, biases


def estimate(run: Run, init: dict, opt: EstimateOptions | None = None) -> EstimateResult:
    """Run the EKF (and optionally the RTS smoother) over a RUN from INIT's state.

    One forward filter (:class:`_ForwardPass`: predict, information-form update, NIS) with its
    integrity as hooks called in a fixed order each epoch — lock events, rest mode, new bias states,
    re-bias, the outlier gate inside the update, batch re-initialization — then the smoother, the
    INIT window's states and the noise estimates (:func:`_finish`).

    Parameters
    ----------
    run : Run
    init : dict
        INIT.json contents (from :func:`cdgps_cli.estimation.initializer.initialize`).
    opt : EstimateOptions

    Returns
    -------
    EstimateResult
    """
    opt = opt or EstimateOptions()
    _check_options(opt)
    if opt.rest_auto:
        from cdgps_cli.estimation.rest import estimate_auto_rest

        return estimate_auto_rest(run, init, opt)
    adapting = opt.adapt_sigma and opt.sigma_m is None
    res = _one_pass(run, init, opt, provisional=adapting)
    if adapting and res.noise.get("adapt"):
        from dataclasses import replace
        first = res.noise
        for npass in range(2, ADAPT_MAX_PASSES + 1):
            new = {ch: float(v["adapted_sigma_m"]) for ch, v in zip(res.channels, res.noise["per_channel"])}
            res = None                        # (the discarded pass's arrays are freed before the next)
            res = _one_pass(run, init, replace(opt, channel_sigma_m=new, adapt_sigma=False),
                            provisional=npass < ADAPT_MAX_PASSES)
            if not res.noise.get("adapt"):
                break
        res.noise = dict(res.noise, source=f"innovation-adapted per channel (pass {npass})", first_pass=first)
    return res


def _one_pass(run: Run, init: dict, opt: EstimateOptions, provisional: bool) -> EstimateResult:
    """One filter pass and its finish; ``provisional``: a pass that is re-run when its noise
    estimate says so, which then stops before the smoother (its noise is all the caller reads)."""
    _check_options(opt)
    fp = _ForwardPass(run, init, opt)
    fp.run()
    return _finish(fp, provisional)


def _check_options(opt: EstimateOptions) -> None:
    """Refuse options the filter cannot use, naming each (EstimateOptions' own field names)."""
    for name in ("outlier_sigma", "nis_probability"):
        require_finite(getattr(opt, name), f"EstimateOptions.{name}", positive=True)
    if not 0.5 < opt.nis_probability < 1.0:      # 1.5 gave a NaN chi-square bound: every test passed (issue 32)
        raise CdgpsError(f"EstimateOptions.nis_probability: expected a probability in (0.5, 1), got {opt.nis_probability!r}")
    if opt.sigma_m is not None and not (np.isfinite(opt.sigma_m) and opt.sigma_m > 0):
        raise CdgpsError(f"--sigma-m must be a positive number of metres, got {opt.sigma_m!r}")
    if opt.biases not in ("fixed", "states"):
        raise CdgpsError(f"--biases: expected fixed or states, got {opt.biases!r}")
    pns = opt.process_noise_scale
    if (isinstance(pns, bool) or not isinstance(pns, (int, float, np.integer, np.floating))
            or not (np.isfinite(pns) and pns > 0)):
        raise CdgpsError(f"--process-noise-scale must be a positive number, got {pns!r}")


class _ForwardPass:
    """The forward filter over one run: its set-up (epoch grid, phases, channels, σ, state layout,
    INIT's state and window) and the working state its hooks share.

    :meth:`run` is the one driver (:func:`cdgps_cli.estimation.driver.drive`) with the pass's
    dynamics (:class:`~cdgps_cli.estimation.integrity.EpochDynamics`), its single-difference model
    (:class:`~cdgps_cli.estimation.integrity.PhaseRows`), the compiled kernel as the driver's spans
    (fixed biases, no multipath states) and the hooks, each epoch in this order: lock events
    (:class:`~cdgps_cli.estimation.integrity.LockRestart`), static mode
    (:class:`~cdgps_cli.estimation.rest.StaticMode`), new bias states, re-bias, the outlier gate,
    the engine's update, post-fit residuals and the NIS test, the epoch stored in the sink
    (:class:`~cdgps_cli.estimation.driver.HistorySink`), then the batch re-initialization after
    persistent NIS failures (1995 Fig. 7).  The state (x, P) is the engine's step
    (:class:`cdgps_cli.estimation.kalman.StepFilter`, ``self.step``; ``self.x``, ``self.P`` are its arrays).
    """

    def __init__(self, run: Run, init: dict, opt: EstimateOptions):
        self.run_, self.init, self.opt = run, init, opt
        self.rest = validate_rest_segments(opt.rest_segments_s, opt.rest_process_noise_scale, opt.rest_retry_s)
        cfg = self.cfg = run.cfg
        self.t0, self.x0, self.P0, self.init_bias = load_init_state(init, cfg, opt.init_source)
        # INIT from 'cdgps init': its state is the batch solution at the window end, which used that
        # epoch's data; the filter starts from it without using them again, and the window's epochs
        # take the batch solution (window_states)
        self.win = batch_window(init, self.t0, opt.init_source)
        self.model = discrete_model(cfg)
        self.T, self.lam, self.nm, self.n = cfg.sample_period_s, cfg.wavelength_m, cfg.n_modes, cfg.n_states
        self._epoch_data()
        self._thruster_inputs()
        self._state_layout()
        self._initial_state()
        # INIT's window is solved first: its epochs get rows in front of the result's arrays (residuals
        # here; states and covariances in the history's arrays in memory, in _finish's copies on disk),
        # so nothing is joined by copy
        self.solution = _window_solution(self)
        self.lead = _window_lead(self.solution[0], self.grid)
        self._working_records()

    # ------------------------------------------------------------------------------------------
    # set-up

    def _epoch_data(self) -> None:
        """Epoch grid from INIT time to the end; Y (N, C) phase in metres and LOCK; the channels.

        The phase rows are read in blocks of :data:`PHASE_BLOCK_ROWS` (passes for the last time, the
        names, the channels present, then Y and LOCK), so the temporaries are those of a block, not of
        the record's rows."""
        run, cfg, opt, T, t0 = self.run_, self.cfg, self.opt, self.T, self.t0
        ph = run.phase
        t_first = float(ph["time_s"].min()) if len(ph) else t0
        if t0 < t_first - T:
            raise CdgpsError(f"{opt.init_source}: state.time_s = {t0:g} s is before the first epoch of {run.path} "
                             f"({t_first:g} s): expected the INIT.json of this run (its batch window end)")
        time_all = ph["time_s"]
        R = len(time_all)
        blocks = [slice(a, min(a + PHASE_BLOCK_ROWS, R)) for a in range(0, R, PHASE_BLOCK_ROWS)]
        scan = _scan_phase_rows(ph, blocks, t0, cfg)
        if not np.isfinite(scan.t_last):
            raise CdgpsError(f"{opt.init_source}: state.time_s = {t0:g} s is after the last epoch of {run.path} "
                             f"({float(time_all.max()) if R else float('nan'):g} s): no phase data to "
                             f"filter; expected the INIT.json of this run")
        if scan.unknown_names:
            row_channel_indices(cfg, ph, run.path)    # (raises the error naming them)
        t_last, counts, n_pairs = scan.t_last, scan.pair_counts, scan.pair_counts.size
        nT = len(cfg.transmitter_names)

        def block_rows(rows):
            """The kept rows of a block (time ≥ t0): their times, pair codes and the selection."""
            sel = _kept_rows(time_all, rows, t0)
            return time_all[sel], scan.pair_of_joint[scan.joint(sel)], sel

        N = self.N = int(round((t_last - t0) / T)) + 1
        self.grid = t0 + np.arange(N) * T
        # each row's channel as (antenna, transmitter) indices in the config: pair codes ascend in the
        # config's channel order, the order the channels are put in below
        pairs = np.flatnonzero(counts)                 # the pairs present, ascending
        seen = [(cfg.antenna_names[pc // nT], cfg.transmitter_names[pc % nT]) for pc in pairs.tolist()]
        chans = self.chans = sorted(set(seen) | set(self.init_bias),
                                    key=lambda c: (cfg.antenna_names.index(c[0]), cfg.transmitter_names.index(c[1])))
        cidx = {c: i for i, c in enumerate(chans)}
        C = self.C = len(chans)
        self.sig_c, self.sigma_source = filter_sigma(self.init, cfg, chans, opt)
        self.r_var = self.sig_c**2                          # R = diag(σ_c²)
        self.sigma = float(np.sqrt(np.mean(self.r_var)))    # their RMS: the re-initialization's batch σ
        chan_of_pair = np.full(n_pairs, -1, dtype=np.int32)
        chan_of_pair[pairs] = [cidx[c] for c in seen]
        # (N, C) on the history (on disk with a DiskHistory: pages dropped behind, memory flat in N)
        hist = self.opt.history
        self.Y = _scratch(hist, (N, C), np.nan)
        LOCK = _scratch(hist, (N, C), -1, np.int32)
        phase_cycles, lock = ph["phase_cycles"], ph["lock"]
        for rows in blocks:                           # in row order: a repeated (epoch, channel) keeps its last row
            t, pair_code, sel = block_rows(rows)
            k_of = np.rint((t - t0) / T).astype(np.int32)
            c_of = chan_of_pair[pair_code]
            self.Y[k_of, c_of] = phase_cycles[sel] * self.lam
            LOCK[k_of, c_of] = lock[sel]
            if k_of.size:
                _release(hist, (self.Y, LOCK), 0, int(k_of.min()))
        self.EVENT = lock_events(self.Y, LOCK, release=getattr(hist, "release", None))
        del LOCK
        self.ant, self.tx = channel_indices(cfg, [c[0] for c in chans], [c[1] for c in chans])
        self.line = cfg.antenna_line_bias_m[self.ant] - cfg.antenna_line_bias_m[cfg.master_index]
        # h(x), H of every channel through the measurement-model interface (the compiled kernel has its own copy)
        self.meas = PseudoliteSD(cfg, self.Y, self.ant, self.tx, self.sig_c)
        self.all_channels = Rows(np.zeros(C), chans, np.full(C, -1, dtype=np.int64), sigma_m=self.sig_c,
                                 context=np.arange(C))

    def _thruster_inputs(self) -> None:
        """U_in (N, n_thrusters): thruster commands held over each epoch (zero-order hold)."""
        cfg, run = self.cfg, self.run_
        act = run.actuators
        if not len(act):
            # no command logged: one row of zeros seen N times (no (N, n_thrusters) array in memory)
            self.U_in = np.broadcast_to(np.zeros(len(cfg.thruster_names)), (self.N, len(cfg.thruster_names)))
            return
        self.U_in = _scratch(self.opt.history, (self.N, len(cfg.thruster_names)), 0.0)
        codes, words = act.codes("actuator")
        t_all, f_all = act["time_s"], act["force_n"]
        names = list(cfg.thruster_names)
        for code in np.unique(codes).tolist():
            j = names.index(words[code])
            rows = codes == code
            times, forces = t_all[rows], f_all[rows]
            idx = np.searchsorted(times, self.grid + 1e-9, side="right") - 1
            self.U_in[:, j] = np.where(idx >= 0, forces[np.maximum(idx, 0)], 0.0)
            _release(self.opt.history, (self.U_in,), 0, self.N)

    def _state_layout(self) -> None:
        """x = [structure (n), bias states (C, biases="states"), multipath states (C, INIT's model)]: A, Q, B."""
        opt, n, C, T, model = self.opt, self.n, self.C, self.T, self.model
        self.use_bias_states = opt.biases == "states"
        # INIT's multipath model: a Gauss–Markov state per channel after the bias states (numpy path only)
        mp = self.mp = multipath.from_init(self.init)
        self.mp0 = n + (C if self.use_bias_states else 0) if mp.active else None
        p = self.p = n + (C if self.use_bias_states else 0) + (C if mp.active else 0)
        self.A = np.eye(p)
        self.A[:n, :n] = model.A
        self.Qd = np.zeros((p, p))
        self.Qd[:n, :n] = model.Q * float(opt.process_noise_scale) ** 2
        if self.use_bias_states:
            self.Qd[n:n + C, n:n + C] = np.eye(C) * opt.bias_process_sigma_m**2
        if mp.active:
            self.A[self.mp0:, self.mp0:] = np.eye(C) * mp.transition(T)
            self.Qd[self.mp0:, self.mp0:] = np.eye(C) * mp.process_variance_m2(T)
        # static mode: the prediction into epoch k inside a declared rest segment uses Q_rest
        self.Qd_rest = self.Qd.copy()
        self.Qd_rest[:n, :n] *= float(opt.rest_process_noise_scale) ** 2
        self.at_rest = rest_mask(self.grid, self.rest)
        self.rest_outside = [(a, b) for a, b in self.rest if not rest_mask(self.grid, [(a, b)]).any()]
        self.q_bounds = np.flatnonzero(np.diff(self.at_rest.astype(np.int8))) + 1   # where the Q in use changes
        # entering a rest stretch the modal velocities are observed as zero (a zero-velocity update, as in
        # inertial navigation), with the sigma of one step of the rest process noise on each velocity
        self.zupt_var = np.maximum(np.diag(self.Qd_rest)[self.nm:n], 1e-30)
        self.Bu = np.zeros((p, model.B.shape[1]))
        self.Bu[:n] = model.B

    @property
    def x(self) -> np.ndarray:
        """The filter's state (p,): the step's (predicted, then updated)."""
        return self.step.x

    @x.setter
    def x(self, value: np.ndarray) -> None:
        self.step.x = value

    @property
    def P(self) -> np.ndarray:
        """Its covariance (p, p)."""
        return self.step.P

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self.step.P = value

    def _initial_state(self) -> None:
        """x, P at INIT's time; the biases INIT fixed (NaN where it has none)."""
        n, C, p, mp0 = self.n, self.C, self.p, self.mp0
        self.step = kalman.StepFilter(np.zeros(p), np.zeros((p, p)))
        self.bias = np.full(C, np.nan)
        for c, key in enumerate(self.chans):
            if key in self.init_bias:
                self.bias[c] = self.init_bias[key]
        self.x[:n] = self.x0
        self.P[:n, :n] = self.P0
        if self.use_bias_states:
            self.x[n:n + C] = np.nan_to_num(self.bias)
            self.P[n:n + C, n:n + C] = np.diag(self.r_var)
        if self.mp.active:
            self.x[mp0:], self.P[mp0:, mp0:], self.P[:n, mp0:] = multipath.init_states(self.init, self.chans, n, self.mp)
            self.P[mp0:, :n] = self.P[:n, mp0:].T
        if self.win is not None:
            for c, key in enumerate(self.chans):
                if key in self.init_bias:
                    self.Y[0, c] = np.nan          # already in INIT's state (the batch's last epoch)

    def _working_records(self) -> None:
        """Outputs (xs, Ps, residuals, NIS), the event log and the hooks' bookkeeping."""
        N, p, C = self.N, self.p, self.C
        # the history the smoother reads back (on disk with a DiskHistory), dropped from memory chunk by chunk
        self.sink = HistorySink(N, p, self.opt.history, self.opt.chunk_epochs, lead=self.lead)
        self.hist, self.chunk = self.sink.history, self.sink.chunk
        self.xs, self.Ps = self.sink.xs, self.sink.Ps
        self.nis, self.nis_dof = self.sink.nis, self.sink.nis_dof
        hist = self.opt.history                     # (on disk with a DiskHistory, like xs, Ps)
        self.resid_all = _scratch(hist, (self.lead + N, C), np.nan)     # (lead rows for INIT's window)
        self.resid = self.resid_all[self.lead:]
        self.hph = _scratch(hist, (N, C), np.nan)   # H P⁺ Hᵀ of the noise estimate (the kernel's epochs)
        # the sink drops these (N, C) rows from memory too, behind the filter
        self.sink.also = (self.Y, self.resid, self.hph, self.U_in)
        self.events: list = []
        self.rebias: dict[int, list] = {}           # channel → list of (k, y − h(x̄), var_h)
        self.extra_q: dict[int, list] = {}          # epoch → [(state index, added variance)]
        self.new_states: list = []
        self.chi2_bound: dict = {}
        self.fail_run = 0                           # consecutive NIS failures
        self.k_reinit_block = -1                    # no re-initialization before this epoch
        self.no_link = np.zeros(N, dtype=bool)      # smoother: epoch k is not linked to k+1 (re-init boundary)
        self.rest_stretch_end = -1                  # end (exclusive) of the rest stretch being run
        self.rest_fail = 0                          # consecutive NIS failures inside a rest stretch
        self.hx_at = None                           # state at which h, Hx were last evaluated in this epoch
        self.P_kin = None                           # kinematic prior covariance at the current rest stretch's entry
        for a, b in self.rest_outside:
            self.log(0, None, "rest segment ignored", f"no epoch of the estimate in {a:g}–{b:g} s "
                     f"(the estimate runs {self.grid[0]:g}–{self.grid[-1]:g} s)")
        # compiled steady-state epochs (fixed biases): the kernel writes xs, Ps, resid, nis, nis_dof and
        # stops at the first epoch that needs the hooks, which then run for that epoch only
        self.kern = None
        if not self.use_bias_states and not self.mp.active and ekf_kernel.available():
            opt = self.opt
            self.kern = ekf_kernel.ForwardKernel(self.cfg, self.ant, self.tx, self.A, self.Qd, self.Bu, self.sig_c,
                                                 opt.outlier_sigma, opt.nis_probability, opt.reinit_after_epochs,
                                                 self.Y, self.EVENT, self.U_in, self.xs, self.Ps, self.resid,
                                                 self.nis, self.nis_dof, self.hph)

    # ------------------------------------------------------------------------------------------
    # the epoch loop

    def log(self, k, c, kind, action, **detail) -> None:
        ev = {"time_s": float(self.grid[k]), "antenna": self.chans[c][0] if c is not None else "",
              "transmitter": self.chans[c][1] if c is not None else "", "kind": kind, "action": action}
        ev.update(detail)
        self.events.append(ev)

    @property
    def trace(self) -> dict | None:
        """The test hook :data:`_TRACE` (read at call time: tests set it on this module)."""
        return _TRACE

    def run(self) -> None:
        """All epochs through the driver: the kernel's spans, then the hooks at the epochs they claim
        (:mod:`cdgps_cli.estimation.integrity` and :class:`cdgps_cli.estimation.rest.StaticMode`, in
        the order the filter has always run them)."""
        bar = progress.bar(self.N, "filter", "epoch")
        model = PhaseRows(self)
        hooks = [LockRestart(self), StaticMode(self), NewBiasStates(self), Rebias(self), OutlierGate(self),
                 PostFit(self, model), Reinit(self)]

        def singular(k):
            raise CdgpsError(f"filter covariance lost positive definiteness at {self.grid[k]:g} s")

        drive(EpochDynamics(self), [model], EpochGrid(self.grid, self.chunk), self.step, hooks, self.sink,
              spans=lambda ctx, k: self._kernel_span(k, bar), progress=bar, on_singular=singular)
        bar.close()

    def _kernel_span(self, k: int, bar) -> int:
        """Run the compiled kernel from epoch k until an epoch that needs a hook; returns that epoch."""
        at_rest = self.at_rest
        # the first epoch of a rest stretch (and the first after one) runs in Python
        edge = (at_rest[k] and k >= self.rest_stretch_end) or (k > 0 and at_rest[k - 1] and not at_rest[k])
        if self.kern is None or edge:
            return k
        k0, in_rest = k, bool(at_rest[k])
        nxt = self.q_bounds[self.q_bounds > k]         # the span ends where the process noise changes
        k_end = int(nxt[0]) if nxt.size else self.N
        while True:
            # in rest, every NIS failure comes back here (to the rest checks); the span is cut at the
            # history's chunk ends (the kernel carries on from its own state: the same numbers)
            cap = min(k_end, (k // self.chunk + 1) * self.chunk)
            k, self.fail_run, self.x, self.P = self.kern.run(
                k, self.x, self.P, self.bias, self.rebias, self.fail_run, self.k_reinit_block,
                cap, Q=self.Qd_rest if in_rest else self.Qd, stop_on_nis_failure=in_rest)
            self.sink.release_before(k)
            if k < cap or cap >= k_end:
                break
        if in_rest and (self.nis_dof[k0:k] > 0).any():
            self.rest_fail = 0                   # an epoch with data passed the NIS test
        bar.update_to(k)
        return k


def _finish(fp: _ForwardPass, provisional: bool = False) -> EstimateResult:
    """The forward pass's result; the smoother; INIT's window epochs; the noise estimates.

    ``provisional``: stop before the smoother when the noise estimate asks for another pass (the
    caller re-runs the filter and reads only ``res.noise``).  With a history on disk
    (``fp.hist.on_disk``) the result's arrays are compact copies taken chunk by chunk (the smoother
    runs backwards in chunks over the history), the history's pages dropped behind; in memory they
    are views of the history, as before."""
    cfg, opt, n, nm, p, grid = fp.cfg, fp.opt, fp.n, fp.nm, fp.p, fp.grid
    xs, Ps = fp.xs, fp.Ps
    if _TRACE is not None:
        _TRACE.update(A=fp.A, Q=fp.Qd, Q_rest=fp.Qd_rest, at_rest=fp.at_rest.copy(), no_link=fp.no_link.copy(),
                      Pf=np.array(Ps), extra_q={kk_: list(v) for kk_, v in fp.extra_q.items()})
    filter_path = "c" if fp.kern is not None else "numpy"
    fp.Y = fp.EVENT = fp.kern = fp.meas = None      # free the (N, C) inputs before the smoother (memory)
    C = fp.C
    res = EstimateResult(cfg, grid, None, None, None, None, fp.chans, fp.resid_all, fp.nis,
                         fp.nis_dof, fp.events, {fp.chans[c]: (float(xs[-1, n + c]) if fp.use_bias_states
                                                               else float(fp.bias[c])) for c in range(C)},
                         filter_path=filter_path)
    res.rest_active_s = [[float(grid[a]), float(grid[b - 1])] for a, b in _true_runs(fp.at_rest)]
    chan_est = _channel_noise_estimate(cfg, fp.ant, fp.tx, xs[:, :n], Ps, fp.resid, n, fp.hph,
                                       release=fp.hist.release,   # (filtered P, before smoothing)
                                       block_rows=fp.chunk if fp.hist.on_disk else None)
    fp.hph = None                           # (N, C): only the noise estimate reads it
    noise = _innovation_noise(res, fp.sig_c, fp.sigma_source, chan_est)
    if provisional and noise.get("adapt"):
        res.noise = noise                   # re-run with the adapted sigma: no smoother, no window
        return res
    m = nm if opt.keep_covariance == "modal" else n
    solution, lead = fp.solution, fp.lead      # (INIT's window, solved before the filter)
    if opt.smooth:
        # keep the filter's states and covariances, then smooth in place (one copy instead of three)
        mf = n if opt.keep_filtered_covariance == "full" else nm
        res.x_filt, res.P_filt = _history_out(fp, n, mf, forward=True, lead=lead)
        with progress.stage("smoothing"):
            if fp.hist.on_disk:
                res.x, res.P = _smooth_chunks(fp, m, lead)
            else:
                rts_smooth(fp.A, fp.Qd, fp.Bu, fp.U_in, xs, Ps, fp.extra_q, fp.no_link, in_place=True,
                           q_segments=_q_segments(fp.at_rest, fp.Qd, fp.Qd_rest))
        res.smoothed = True
    if not fp.hist.on_disk or not opt.smooth:
        res.x, res.P = _history_out(fp, n, m, forward=False, lead=lead)
    res.P_first = Ps[0, :n, :n].copy() if len(Ps) else None     # full, for the INIT window's smoothing
    _window_epochs(fp, res, solution, lead)
    del res.P_first
    res.noise = noise
    if fp.mp.active:
        res.noise["multipath"] = dict(fp.mp.echo(), source="INIT.json", filter_path="numpy (kernel has no multipath states)")
    return res


def _history_out(fp: _ForwardPass, n: int, m: int, forward: bool, lead: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """States (N, n) and covariances (N, m, m) of the history as the result holds them.

    In memory: the history itself when it has no further states and m = n (views, no copy), else
    copies (``forward``: the filter's values kept before the smoother overwrites them).  On disk:
    compact copies taken chunk by chunk, the history's pages dropped behind.  Either way ``lead``
    rows come first for INIT's window (filled by :func:`_join_window`)."""
    xs, Ps, p = fp.xs, fp.Ps, fp.p
    N = len(xs)
    if not fp.hist.on_disk:
        # the history's arrays have the window's rows in front (HistorySink lead): views of them, or copies
        xa, Pa = fp.sink.xs_lead, fp.sink.Ps_lead
        if p == n and not forward:
            x_all = xa
        else:
            x_all = np.empty((lead + N, n))
            x_all[lead:] = xs[:, :n]
        if p == n and m == n and not forward:
            P_all = Pa
        else:
            P_all = np.empty((lead + N, m, m))
            P_all[lead:] = Ps[:, :m, :m]
        return x_all, P_all
    x_all, P_all = fp.hist.empty((lead + N, n)), fp.hist.empty((lead + N, m, m))   # (on disk too: issue 29)
    x_out, P_out = x_all[lead:], P_all[lead:]
    for a in range(0, N, fp.chunk):
        b = min(a + fp.chunk, N)
        x_out[a:b] = xs[a:b, :n]
        P_out[a:b] = Ps[a:b, :m, :m]
        for arr in (xs, Ps, x_out, P_out):
            fp.hist.release(arr, a, b)
    return x_all, P_all


def _smooth_chunks(fp: _ForwardPass, m: int, lead: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The RTS pass over the history on disk in reverse chunks: smoothed (N, n) states and (N, m, m)
    covariances after ``lead`` rows left for INIT's window, copied out of each chunk as it is finished
    (its pages then dropped)."""
    xs, Ps, n = fp.xs, fp.Ps, fp.n
    N = len(xs)
    x_all, P_all = fp.hist.empty((lead + N, n)), fp.hist.empty((lead + N, m, m))   # (on disk too: issue 29)
    x_out, P_out = x_all[lead:], P_all[lead:]

    def done(a: int, b: int) -> None:
        x_out[a:b] = xs[a:b, :n]
        P_out[a:b] = Ps[a:b, :m, :m]
        for arr in (xs, Ps, x_out, P_out, fp.U_in):
            fp.hist.release(arr, a, b)

    rts_smooth(fp.A, fp.Qd, fp.Bu, fp.U_in, xs, Ps, fp.extra_q, fp.no_link, in_place=True,
               q_segments=_q_segments(fp.at_rest, fp.Qd, fp.Qd_rest), chunk=fp.chunk, on_done=done)
    return x_all, P_all


def _window_solution(fp: _ForwardPass) -> tuple:
    """INIT's window from the batch solution (window_states): (ws, None), or (None, the event saying why
    not), or (None, None) without a window."""
    win, grid = fp.win, fp.grid
    if win is None:
        return None, None
    try:
        with progress.stage(f"batch solution over INIT's window {win[0]:g}–{win[1]:g} s"):
            return window_states(fp.run_, fp.init, win, fp.x0, fp.P0), None
    except CdgpsError as exc:          # e.g. an INIT edited by hand: the filter part is still right
        return None, {"time_s": float(grid[0]), "antenna": "", "transmitter": "",
                      "kind": "batch window", "action": f"window epochs not recomputed: {exc}; "
                      f"STATES start at the window end"}


def _window_lead(ws, grid: np.ndarray) -> int:
    """Epochs of the window before the filter's first (rows to reserve in front of the result's arrays;
    0 when the window does not join, which :func:`_join_window` then reports)."""
    if ws is None:
        return 0
    nw = len(ws.time_s) - 1
    return nw if nw > 0 and abs(float(ws.time_s[-1]) - float(grid[0])) <= 1e-6 else 0


def _window_epochs(fp: _ForwardPass, res: EstimateResult, solution: tuple | None = None, lead: int = 0) -> None:
    """INIT's window epochs from the batch solution (``solution``: :func:`_window_solution`'s, computed
    here when None; ``lead``: rows already reserved for them in front of x, P, x_filt, P_filt); say
    where STATES start if not at the run's start."""
    run, win = fp.run_, fp.win
    ws, failed = _window_solution(fp) if solution is None else solution
    if failed is not None:
        res.events.insert(0, failed)
    if ws is not None:
        _join_window(res, ws, fp.x0, fp.P0, fp.opt, lead)
    t_first = float(run.phase["time_s"].min())
    if win is not None and res.time_s[0] > t_first + 1e-6:     # (a hand-made INIT is a prior where it says)
        where = "INIT's window start" if res.window else "INIT's state time"
        res.events.insert(0, {"time_s": float(res.time_s[0]), "antenna": "", "transmitter": "",
                              "kind": "epochs not estimated",
                              "action": f"the run starts at {t_first:g} s, STATES at {res.time_s[0]:g} s ({where}); "
                                        "initialize from the run start (cdgps init --start) to cover it"})


def _join_window(res: EstimateResult, ws, x0: np.ndarray, P0: np.ndarray, opt: EstimateOptions,
                 lead: int = 0) -> None:
    """Put the window's batch solution before the filter's epochs (in place on ``res``).

    ``res`` starts at the window end with INIT's state (x0, P0) as its first filtered value; with
    smoothing the pass is carried into the window (:func:`cdgps_cli.estimation.window_smoother.extend_smoothing`).
    ``lead`` > 0: x, P, x_filt, P_filt already have that many rows in front (:func:`_window_lead`), which
    are filled (no concatenated copies); the other arrays are concatenated."""
    nw = len(ws.time_s) - 1                   # window epochs before its end (the end is res's first)
    nm = res.cfg.n_modes
    if nw < 0 or abs(float(ws.time_s[-1]) - float(res.time_s[0])) > 1e-6:
        raise CdgpsError("INIT's window does not end where the filter starts")
    if lead and lead != nw:
        raise ValueError(f"_join_window: {lead} rows reserved for a window of {nw} epochs")
    P_first = getattr(res, "P_first", None)          # the full covariance at the window end (res.P may be modal)

    def joined(front: np.ndarray, rest: np.ndarray) -> np.ndarray:
        if not lead:
            return np.concatenate([front, rest])
        rest[:lead] = front
        return rest

    if res.smoothed:
        xw, Pw = extend_smoothing(ws, res.x[lead], res.P[lead] if P_first is None else P_first, x0, P0)
        res.x_filt = joined(ws.x[:-1], res.x_filt)
        Pf = ws.P[:-1] if res.P_filt.shape[1] == ws.P.shape[1] else ws.P[:-1, :nm, :nm]
        res.P_filt = joined(Pf, res.P_filt)
    else:
        xw, Pw = ws.x[:-1], ws.P[:-1]
    if res.P.shape[1] != Pw.shape[1]:
        Pw = Pw[:, :nm, :nm]
    res.x = joined(xw, res.x)
    res.P = joined(Pw, res.P)
    res.time_s = np.concatenate([ws.time_s[:-1], res.time_s])
    C = len(res.channels)
    resid = np.full((nw + 1, C), np.nan)
    col = {c: i for i, c in enumerate(res.channels)}
    for j, c in enumerate(ws.channels):
        if c in col:
            resid[:, col[c]] = ws.residual_m[:, j]
    first = resid[-1]
    res.residual_m = joined(resid[:-1], res.residual_m)
    row0 = res.residual_m[nw]
    row0[np.isnan(row0)] = first[np.isnan(row0)]   # the window end: the batch's residuals
    res.nis = np.concatenate([np.full(nw, np.nan), res.nis])
    res.nis_dof = np.concatenate([np.zeros(nw, dtype=res.nis_dof.dtype), res.nis_dof])
    res.window = {"start_s": float(ws.time_s[0]), "end_s": float(ws.time_s[-1]), "epochs": int(nw + 1),
                  "source": "batch solution (INIT's window, recomputed from RUN + INIT)",
                  "iterations": int(ws.iterations), "free_biases": int(ws.n_free_biases),
                  "segments_without_init_bias": list(ws.segments_without_bias)}


# innovation-based adaptation: the filter is re-run with the adapted σ per channel when the mean
# NIS/dof, or one channel's variance ratio σ̂_c²/σ_c², is outside this band and outside its own
# 3.3-σ interval (independent epochs: relative std of a variance estimate from m values is √(2/m))
ADAPT_NIS_BAND = (0.8, 1.25)
ADAPT_MAX_PASSES = 4           # filter passes at most (the first + re-runs with the adapted σ)
ADAPT_MIN_EPOCHS = 50          # a channel with fewer post-fit residuals keeps the pooled factor


def filter_sigma(init: dict, cfg, chans, opt: EstimateOptions) -> tuple[np.ndarray, str]:
    """The filter's per-channel σ (m), shape (C,), and where it comes from: ``opt.sigma_m`` for every
    channel, else ``opt.channel_sigma_m`` (listed channels; the others as below), else INIT's per
    channel (:func:`cdgps_cli.measurement.noise.init_channel_sigma_m`)."""
    if opt.sigma_m is not None and opt.channel_sigma_m:
        raise CdgpsError("--sigma-m and a per-channel sigma cannot be combined")
    sig, source = init_channel_sigma_m(init, cfg, chans, opt.sigma_m)
    if opt.sigma_m is None and opt.channel_sigma_m:
        over = {tuple(k): v for k, v in opt.channel_sigma_m.items()}
        for c, key in enumerate(chans):
            if key in over:
                v = over[key]
                if isinstance(v, bool) or not (np.isfinite(v) and OPTION_BOUNDS["sigma_m"].contains(v)):
                    raise CdgpsError(f"channel sigma {key[0]}/{key[1]} = {v!r}: expected a number of metres in "
                                     f"{OPTION_BOUNDS['sigma_m'].text()}")
                sig[c] = float(v)
        source = "per-channel sigma (option)"
    return sig, source


def _channel_noise_estimate(cfg, ant, tx, xs: np.ndarray, Ps: np.ndarray, resid: np.ndarray, n: int,
                            hph: np.ndarray | None = None, release=None, block_rows: int | None = None) -> tuple:
    """Residual-based σ̂_c of every channel (:func:`cdgps_cli.measurement.noise.filter_sigma_estimate`).

    Its term H_c P⁺ H_cᵀ (m²) is taken from the filtered covariances Ps (N, p, p) with the Jacobian at
    the filtered state xs (N, n) (with bias states, p > n, the row also has a 1 in the channel's bias
    column).  ``hph`` (N, C), when given, holds that term already for the epochs the compiled kernel
    ran (it is updated in place); the other epochs with a residual are computed here, in chunks
    (``release(arr, start, stop)``, when given, is told after each which rows of xs and Ps it read).
    ``block_rows``: resid and hph are read in blocks of that many epochs too, their rows released
    behind (arrays on disk: memory flat in N); the numbers are the same.
    Returns (σ̂ (C,), count (C,)).
    """
    N, C = resid.shape
    nm = cfg.n_modes
    if hph is None:
        hph = np.full((N, C), np.nan)
    step = max(N if not block_rows else int(block_rows), 1)
    rows = []
    for a in range(0, N, step):                 # the epochs with a residual and no H P Hᵀ yet, by blocks
        e, h = resid[a:a + step], hph[a:a + step]
        rows.append(a + np.flatnonzero((np.isfinite(e) & ~np.isfinite(h)).any(axis=1)))
        if release is not None and block_rows:
            release(resid, a, a + step)
            release(hph, a, a + step)
    rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
    bias_states = Ps.shape[1] > n
    for j in range(0, rows.size, 500):
        k = rows[j:j + 500]
        _, H = phase_model(cfg, xs[k], ant, tx, jacobian=True)          # (m, C, 2 n_m)
        Hm = H[:, :, :nm]
        hph[k] = np.sum(np.matmul(Hm, Ps[k, :nm, :nm]) * Hm, axis=2)     # diag(H P Hᵀ) per epoch
        if bias_states:
            cb = n + np.arange(C)
            hph[k] += Ps[k][:, cb, cb] + 2.0 * np.einsum("kci,kic->kc", Hm, Ps[k][:, :nm, cb])
        if release is not None:
            release(xs, int(k[0]), int(k[-1]) + 1)
            release(Ps, int(k[0]), int(k[-1]) + 1)
            if block_rows:
                release(hph, int(k[0]), int(k[-1]) + 1)
    return filter_sigma_estimate(resid, hph, block_rows, release if block_rows else None)


def _innovation_noise(res: EstimateResult, sig_c: np.ndarray, source: str, chan_est: tuple) -> dict:
    """σ used (RMS and per channel) and the innovation-based estimates; ``adapt`` when one is outside
    the band (``ADAPT_NIS_BAND``) and its own sampling interval.

    The scale comes from the pooled NIS: f = mean NIS/dof, σ·√f.  The channels' relative noise comes
    from the residual-based σ̂_c² = mean(e_c² + H_c P⁺ H_cᵀ): its ratio r_c = σ̂_c²/σ_c² is exact for a
    consistent filter but biased, differently for each channel's geometry, when σ is far off (P⁺ is
    then wrong too).  So only a channel whose relative ratio rel_c = r_c / r̄ (r̄: the
    residual-weighted mean) is off the band and its sampling interval takes it: adapted
    σ_c = σ_c·√(f·rel_c); the others keep their pattern, σ_c·√f.  The caller re-runs the filter
    with the adapted σ until nothing is off (at most ``ADAPT_MAX_PASSES`` passes): a fixed-point
    iteration that converges in 2–4 passes when σ starts 4× off or one antenna is 5× noisier than
    one σ assumed."""
    ok = res.nis_dof > 0
    sigma = float(np.sqrt(np.mean(sig_c**2)))
    out = {"sigma_m": sigma, "source": source,
           "sigma_m_min": float(sig_c.min()), "sigma_m_max": float(sig_c.max())}
    if not ok.any():
        return out
    dof = float(res.nis_dof[ok].sum())
    f = float(res.nis[ok].sum()) / dof
    half = 3.3 * np.sqrt(2.0 / dof)
    scale_off = bool((f < ADAPT_NIS_BAND[0] or f > ADAPT_NIS_BAND[1]) and abs(f - 1.0) > half)
    adapt = scale_off
    s_hat, cnt = chan_est
    enough = cnt >= ADAPT_MIN_EPOCHS
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(cnt > 0, s_hat**2 / sig_c**2, np.nan)
    r_bar = float(np.sum(np.where(enough, r * cnt, 0.0)) / np.sum(np.where(enough, cnt, 0))) if enough.any() else 1.0
    per, worst = [], None
    for c, (a, t) in enumerate(res.channels):
        rel = float(r[c] / r_bar) if enough[c] else 1.0          # this channel's noise relative to the others
        off = bool(enough[c] and (rel < ADAPT_NIS_BAND[0] or rel > ADAPT_NIS_BAND[1])
                   and abs(rel - 1.0) > 3.3 * np.sqrt(2.0 / cnt[c]))
        adapt |= off
        per.append({"channel": f"{a}/{t}", "sigma_m": float(sig_c[c]),
                    "residual_sigma_m": float(s_hat[c]) if cnt[c] > 0 else None, "residuals": int(cnt[c]),
                    "variance_ratio": float(r[c]) if cnt[c] > 0 else None, "relative_variance": rel,
                    "adapted_sigma_m": float(sig_c[c] * np.sqrt(max(f * (rel if off else 1.0), 1e-6)))})
        if off and (worst is None or abs(np.log(rel)) > abs(np.log(worst[1]))):
            worst = (f"{a}/{t}", rel)
    out.update(mean_nis_per_dof=f, innovation_sigma_m=float(sigma * np.sqrt(max(f, 1e-6))), adapt=adapt,
               per_channel=per)
    if worst:
        out["worst_channel"] = {"channel": worst[0], "relative_variance": worst[1]}
    return out


PHASE_BLOCK_ROWS = 1 << 20                 # phase rows per block when Y and LOCK are built


def lock_events(Y: np.ndarray, LOCK: np.ndarray, release=None, group: int = 8) -> np.ndarray:
    """Per (epoch, channel) the cause of a new lock segment (:func:`cdgps_cli.measurement.channels.lock_segments`):
    1 = first sighting, 2 = lock restart (slip), 3 = re-acquisition after a gap with a lock counter
    that does not continue; 0 otherwise.  Y, LOCK: (N, C), NaN / −1 = absent.

    One channel at a time (a channel's segments depend on its own rows only), so the temporaries
    are those of one column, not of the record's N·C rows; the columns are copied out ``group`` at a
    time, after which ``release(arr, 0, N)`` (when given: arrays on disk) drops Y's and LOCK's pages."""
    N, C = Y.shape
    ev = np.zeros(Y.shape, dtype=np.int8)
    step = max(N, 1) if release is None else max(PHASE_BLOCK_ROWS >> 5, 1)
    for g in range(0, C, group):
        cols = range(g, min(g + group, C))
        Yg, Lg = np.empty((N, len(cols))), np.empty((N, len(cols)), dtype=LOCK.dtype)
        for a in range(0, N, step):              # (by blocks of rows: Y's pages dropped behind)
            Yg[a:a + step], Lg[a:a + step] = Y[a:a + step, g:cols.stop], LOCK[a:a + step, g:cols.stop]
            if release is not None:
                release(Y, a, a + step)
                release(LOCK, a, a + step)
        for j, c in enumerate(cols):
            kk = np.flatnonzero(~np.isnan(Yg[:, j]))
            if kk.size:
                ev[kk, c] = lock_segments(np.full(kk.size, c, dtype=np.int64), kk, lock=Lg[kk, j]).cause
    return ev


def _kept_rows(time_all, rows: slice, t0: float):
    """The rows of block ``rows`` at or after ``t0`` (s): a slice when they are one run (a time-ordered
    RUN: read as one), else their indices."""
    keep = time_all[rows] >= t0 - 1e-9
    first = int(np.argmax(keep)) if keep.any() else keep.size
    if keep[first:].all():
        return slice(rows.start + first, rows.stop)
    return np.arange(rows.start, rows.stop)[keep]


@dataclass
class _PhaseScan:
    """One pass over a RUN's phase rows (:func:`_scan_phase_rows`)."""
    t_last: float                  # the last time at or after t0, s (−inf: none)
    unknown_names: bool            # some row names an antenna or transmitter the config does not have
    pair_counts: np.ndarray        # (n_antennas · n_transmitters,) kept rows per config channel pair
    pair_of_joint: np.ndarray      # config pair code of each (antenna word, transmitter word) code, −1: none
    joint: object                  # rows → their (antenna word, transmitter word) codes


def _scan_phase_rows(ph, blocks, t0: float, cfg) -> _PhaseScan:
    """The last kept time, whether some row names what the config lacks, and the kept rows per channel
    pair, from the name columns' codes in one pass (block by block: memory of a block)."""
    (a_codes, a_words), (t_codes, t_words) = ph.codes("antenna"), ph.codes("transmitter")
    n_tw = max(len(t_words), 1)
    lut_a = _word_positions(a_words, cfg.antenna_names)
    lut_t = _word_positions(t_words, cfg.transmitter_names)
    used_a, used_t = np.zeros(len(a_words), np.int64), np.zeros(len(t_words), np.int64)
    joint_counts = np.zeros(max(len(a_words), 1) * n_tw, np.int64)
    t_last = -np.inf
    for rows in blocks:
        t, ca, ct = ph["time_s"][rows], np.asarray(a_codes[rows]), np.asarray(t_codes[rows])
        used_a += np.bincount(ca, minlength=used_a.size)
        used_t += np.bincount(ct, minlength=used_t.size)
        keep = t >= t0 - 1e-9
        if keep.any():
            t_last = max(t_last, float(t[keep].max()))
            joint_counts += np.bincount(ca[keep].astype(np.int64) * n_tw + ct[keep], minlength=joint_counts.size)
    unknown = bool((lut_a[used_a > 0] < 0).any() or (lut_t[used_t > 0] < 0).any())
    nT = len(cfg.transmitter_names)
    pos_a, pos_t = np.full(joint_counts.size // n_tw, -1, np.int64), np.full(n_tw, -1, np.int64)
    pos_a[:lut_a.size], pos_t[:lut_t.size] = lut_a, lut_t
    ja, jt = np.divmod(np.arange(joint_counts.size), n_tw)
    a, t = pos_a[ja], pos_t[jt]
    pair_of_joint = np.where((a >= 0) & (t >= 0), a * nT + t, -1)
    ok = pair_of_joint >= 0
    pair_counts = np.bincount(pair_of_joint[ok], weights=joint_counts[ok],
                              minlength=len(cfg.antenna_names) * nT).astype(np.int64)
    return _PhaseScan(t_last, unknown, pair_counts, pair_of_joint,
                      lambda sel: np.asarray(a_codes[sel]).astype(np.int64) * n_tw + np.asarray(t_codes[sel]))


def _word_positions(words, names) -> np.ndarray:
    """(len(words),) position of each word in ``names``, −1 where it is not there."""
    where = {w: i for i, w in enumerate(names)}
    return np.array([where.get(w, -1) for w in words], dtype=np.int64)


def _scratch(history, shape: tuple, fill, dtype=np.float64) -> np.ndarray:
    """An array of ``shape`` filled with ``fill``: ``np.full`` without a history on disk, else one of
    the history's (:class:`cdgps_cli.io.scratch.DiskHistory`) filled block by block, its pages dropped
    behind (the values are the same; only where they live differs)."""
    if not getattr(history, "on_disk", False):
        arr = MemoryHistory.empty(shape, dtype)         # (large: base pages, see MemoryHistory.empty)
        arr[...] = fill
        return arr
    arr = history.empty(shape, dtype)
    step = max(1, (PHASE_BLOCK_ROWS >> 3))
    for a in range(0, shape[0], step):
        arr[a:a + step] = fill
        history.release(arr, a, a + step)
    return arr


def _release(history, arrays, start: int, stop: int) -> None:
    """Tell a history on disk that rows start … stop−1 of ``arrays`` can leave memory."""
    if getattr(history, "on_disk", False) and stop > start:
        for arr in arrays:
            history.release(arr, start, stop)
