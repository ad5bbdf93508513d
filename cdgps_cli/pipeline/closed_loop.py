"""Closed loop with GPS in the loop (1998 paper, Sec. V–VI.C–D): structure, carrier-phase
measurements, EKF at the control rate, LQR on the estimate, PWPF modulators and on/off thrusters.

Per control period k (length T, the config's sample period):

1. the carrier phase of every channel at t_k is h(x_k) + v_k (the simulator's noise and multipath,
   biases removed: they are known from an initialization, here exactly);
2. the EKF updates its prediction with it (:class:`cdgps_cli.estimation.loop_filter.LoopFilter`, the config's
   σ per channel; with the config's ``[model] multipath_sigma_m``, one Gauss–Markov phase-error
   state per channel beside the structure's);
3. the regulator commands u = u_ff,k − K (x̂_k − x_ref,k) (``estimator="truth"`` feeds back the true
   state instead, to show what estimation costs; a slew's reference and feed-forward are planned
   from that fed-back state when commanded), realized on opposing jets
   (:func:`cdgps_cli.control.allocation.realize_forces`);
4. each jet's PWPF modulator turns its held command into on/off firings inside the period (exact
   switching instants); jets that fire a disturbance pulse are taken from the controller meanwhile;
5. the true state advances by the exact response to every firing (:class:`PulseResponse`) plus the
   simulator's disturbance; the EKF predicts with the response to the firings it commanded (known)
   but not to the disturbance (unknown to it), with the config's process noise scaled by the
   separation rule for the gain in use (:mod:`cdgps_cli.control.estimator_design`).

The orchestration of the loop (here) is above the numerics it steps: the regulator, modulator,
allocation and slew planning in :mod:`cdgps_cli.control`, the filter in
:mod:`cdgps_cli.estimation.loop_filter`, the structure's response in :mod:`cdgps_cli.control.propagation`;
:func:`simulate_closed_loop` runs it inside :func:`cdgps_cli.sim.structure.simulate`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from cdgps_cli.config.structure import StructureConfig, channel_sigma_m
from cdgps_cli.control.allocation import opposing_pairs, realize_forces
from cdgps_cli.control.design import rigid_only_gain
from cdgps_cli.control.estimator_design import loop_estimator
from cdgps_cli.control.modulation import PwpfParams, merge_firings, modulate_period
from cdgps_cli.control.propagation import PulseResponse
from cdgps_cli.control.slew import slew_reference
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.coordinate_columns import column_unit
from cdgps_cli.io.gains_file import gain_sha256
from cdgps_cli.estimation.loop_filter import INITIAL_ESTIMATE_SIGMA, LoopFilter
from cdgps_cli.measurement.multipath import model_from
from cdgps_cli.measurement.phase import EpochPhaseModel, all_channels
from cdgps_cli.model.dynamics import continuous_model, discrete_model
from cdgps_cli.sim.structure import simulate


@dataclass(frozen=True)
class Disturbance:
    """Jets fired open loop at ``force_n`` during [start_s, end_s) (the Fig. 9 pulse)."""

    thrusters: tuple
    start_s: float
    end_s: float
    force_n: float


@dataclass
class ClosedLoopResult:
    """Arrays of a closed-loop run; N epochs, n states, m jets."""

    time_s: np.ndarray          # (N,)
    x_true: np.ndarray          # (N, n)
    x_hat: np.ndarray           # (N, n) estimate after the update at each epoch
    sigma_hat: np.ndarray       # (N, n) its 1σ
    nis: np.ndarray             # (N,)
    command_n: np.ndarray       # (N, m) thrust requested from each jet's modulator, N
    firings: list               # (thruster index, on_s, off_s, force_n, source) absolute times
    saturated_fraction: float   # fraction of jet-periods whose request exceeded the jet's max force
    sigma_q_hat: np.ndarray = None  # (N, n_coords) 1σ of the estimated coordinates q = U ξ̂ (rad or m)
    x_ref: np.ndarray = None        # (N, n) the reference the regulator used (as planned in the loop)
    estimator: dict = None          # the in-loop filter's process-noise choice (:func:`loop_estimator`)


def run_closed_loop(cfg: StructureConfig, K: np.ndarray, x0: np.ndarray, disturbance_w: np.ndarray,
                    noise_m: np.ndarray, x_ref: np.ndarray, pulse: Disturbance | None = None, *,
                    pwpf: PwpfParams | None = None, estimator: str = "gps", u_ff=None,
                    process_noise_scale: float = 1.0, planner=None, plan_epochs=(),
                    multipath=None, actuator: str = "pwpf", pulse_known: bool = False) -> ClosedLoopResult:
    """Simulate the closed loop for N = len(noise_m) epochs.

    Parameters
    ----------
    cfg : StructureConfig
    K : ndarray, shape (m, n)
        LQR gain (u = −K x), designed on this config's discrete model.
    x0 : ndarray, shape (n,)
        True initial modal state.
    disturbance_w : ndarray, shape (N, n_w)
        True process disturbance per period (held), in the model's noise-input units.
    noise_m : ndarray, shape (N, C)
        Carrier-phase error of every channel (config channel order), m.
    x_ref : ndarray, shape (N, n)
        Reference state per epoch (zero for regulation; the target rigid-body angle for a slew).
    pulse : Disturbance, optional
    pwpf : PwpfParams, optional
    estimator : {"gps", "truth"}
        Feed back the EKF's estimate, or the true state (full-state feedback).
    u_ff : ndarray, shape (N, m), optional
        Feed-forward signed thruster commands added to −K (x̂ − x_ref), N (a slew profile's thrust).
    process_noise_scale : float
        The EKF predicts with this multiple of the config's process noise (the separation rule of
        :mod:`cdgps_cli.control.estimator_design`; 1: the config's W).
    planner : callable, optional
        ``planner(x_fb) -> (x_ref, u_ff)``, both for all N epochs: at each epoch of ``plan_epochs``,
        after the update, the reference and feed-forward from that epoch on are replaced by the plan
        made from the state the controller feeds back (the estimate, or the truth with
        ``estimator="truth"``) — a slew planned when it is commanded, from what the controller knows.
    plan_epochs : iterable of int
    multipath : MultipathModel, optional
        When active, the filter carries one first-order Gauss–Markov phase-error state per channel
        (:mod:`cdgps_cli.measurement.multipath`, stationary prior) beside the structure's, as the estimation
        pipeline does with ``[model] multipath_sigma_m``.
    actuator : {"pwpf", "ideal"}
        On/off jets through the PWPF modulators, or (for comparison only) an ideal continuous force:
        each jet's request clipped to its maximum force and held over the period.
    pulse_known : bool
        The filter predicts with the disturbance pulse's firings too (the paper's time update
        x̄ = A x + B u with u every firing the computer commanded, Eq. 18); False: the pulse is
        unknown to it.
    """
    _check_loop_options(estimator, actuator, process_noise_scale)
    pwpf = PwpfParams() if pwpf is None else pwpf
    lp = _loop_plant(cfg, K, noise_m.shape[0], pulse, multipath, process_noise_scale)
    N, n, m, T, U = lp.N, lp.n, lp.m, lp.T, lp.U
    x_ref = np.array(x_ref, dtype=float)
    u_ff = None if u_ff is None else np.array(u_ff, dtype=float)
    plan_epochs = set(plan_epochs)
    out = ClosedLoopResult(time_s=np.round(np.arange(N) * T, 9), x_true=np.empty((N, n)), x_hat=np.empty((N, n)),
                           sigma_hat=np.empty((N, n)), nis=np.empty(N), command_n=np.zeros((N, m)), firings=[],
                           saturated_fraction=0.0, sigma_q_hat=np.empty((N, U.shape[0])))
    x = np.asarray(x0, dtype=float).copy()
    lp.filt.start(x)
    f_state, on_state = np.zeros(m), np.zeros(m, dtype=bool)
    saturated = 0
    for k in range(N):
        fb = _loop_update(lp, out, k, x, noise_m[k], estimator)
        if planner is not None and k in plan_epochs:
            u_ff = _replan(planner, fb, k, x_ref, u_ff, N, m)
        error = fb - x_ref[k]
        u = -K @ error if u_ff is None else u_ff[k] - K @ error
        ctrl, dist = _actuate(lp, out, k, u, f_state, on_state, pulse, pwpf, actuator)
        saturated += int(np.sum(out.command_n[k] > lp.fmax))
        known = lp.response(*_columns(ctrl))
        pulse_response = lp.response(*_columns(dist))
        x = lp.model.A @ x + known + pulse_response + lp.model.Bw @ disturbance_w[k]
        lp.filt.predict(known + pulse_response if pulse_known else known)
    out.saturated_fraction = saturated / max(N * m, 1)
    out.x_ref = x_ref
    return out


def _check_loop_options(estimator: str, actuator: str, process_noise_scale: float) -> None:
    """Refuse an unknown feedback source or actuator, or a non-positive process-noise scale."""
    if estimator not in ("gps", "truth"):
        raise CdgpsError(f"estimator: expected 'gps' or 'truth', got {estimator!r}")
    if actuator not in ("pwpf", "ideal"):
        raise CdgpsError(f"actuator: expected 'pwpf' or 'ideal', got {actuator!r}")
    if not (np.isfinite(process_noise_scale) and process_noise_scale > 0):
        raise CdgpsError(f"process_noise_scale: expected a positive number, got {process_noise_scale!r}")


def _loop_plant(cfg: StructureConfig, K: np.ndarray, N: int, pulse: Disturbance | None, multipath,
                process_noise_scale: float) -> SimpleNamespace:
    """The loop's fixed parts: discrete model, pulse response, phase model and σ per channel (m),
    opposing jet pairs, max forces (N), disturbance jets, the loop filter and the mode shapes."""
    model = discrete_model(cfg)
    Ac, Bc, _ = continuous_model(cfg)
    n, m = model.A.shape[0], Bc.shape[1]
    if K.shape != (m, n):
        raise CdgpsError(f"gain K: expected shape ({m}, {n}) for this config, got {K.shape}")
    ant, tx = all_channels(cfg)
    U = np.asarray(cfg.mode_shapes)
    return SimpleNamespace(
        model=model, T=model.T, N=N, n=n, m=m, response=PulseResponse(Ac, Bc, model.T),
        h_of=EpochPhaseModel(cfg, ant, tx),
        sigma_m=channel_sigma_m(cfg, [(cfg.antenna_names[a], cfg.transmitter_names[t]) for a, t in zip(ant, tx)]),
        pairs=opposing_pairs(cfg.thruster_section, cfg.thruster_position_m, cfg.thruster_direction),
        fmax=np.asarray(cfg.thruster_max_force_n, dtype=float),
        pulse_jets=[list(cfg.thruster_names).index(j) for j in pulse.thrusters] if pulse else [],
        filt=LoopFilter(model.A, process_noise_scale * model.Q, len(ant), multipath, model.T),
        U=U, nm=U.shape[1])


def _loop_update(lp: SimpleNamespace, out: ClosedLoopResult, k: int, x: np.ndarray, noise_m: np.ndarray,
                 estimator: str) -> np.ndarray:
    """Epoch k's measurement update from the true phases plus ``noise_m`` (C,), m, recorded in ``out``;
    the state fed back (n,): the estimate, or the truth with ``estimator="truth"``."""
    h_true, _ = lp.h_of(x)
    xh, P, nis = lp.filt.update(h_true + noise_m, lp.h_of, lp.sigma_m)
    out.x_true[k], out.x_hat[k], out.sigma_hat[k], out.nis[k] = x, xh, np.sqrt(np.diag(P)), nis
    out.sigma_q_hat[k] = np.sqrt(np.einsum("ij,jk,ik->i", lp.U, P[:lp.nm, :lp.nm], lp.U))
    return xh if estimator == "gps" else x


def _replan(planner, fb: np.ndarray, k: int, x_ref: np.ndarray, u_ff, N: int, m: int):
    """Replace ``x_ref`` (N, n) from epoch k on (in place) by the plan made from ``fb``; the
    feed-forward (N, m), N, with its part from k on replaced (zero when the plan has none)."""
    ref, ff = planner(fb)
    x_ref[k:] = ref[k:]
    if ff is not None:
        u_ff = np.zeros((N, m)) if u_ff is None else u_ff
        u_ff[k:] = ff[k:]
    elif u_ff is not None:
        u_ff[k:] = 0.0
    return u_ff


def _actuate(lp: SimpleNamespace, out: ClosedLoopResult, k: int, u: np.ndarray, f_state, on_state,
             pulse: Disturbance | None, pwpf: PwpfParams, actuator: str) -> tuple[list, list]:
    """Period k's firings: the command u (m,) realized on the jets (request recorded in ``out``, N),
    disturbance jets taken from the controller, modulated (``pwpf``) or held (``ideal``);
    ``(control, disturbance)`` as (jet, start, end, force) lists, times from the period's start."""
    request = realize_forces(u, lp.pairs)
    t0 = k * lp.T
    dist = _pulse_intervals(pulse, lp.pulse_jets, t0, lp.T)
    for j, _a, _b, _f in dist:                       # jets firing the disturbance leave the loop
        request[j], f_state[j], on_state[j] = 0.0, 0.0, False
    out.command_n[k] = request
    if actuator == "pwpf":
        ctrl = modulate_period(request / lp.fmax, f_state, on_state, lp.T, pwpf, lp.fmax)
    else:
        ctrl = [(j, 0.0, lp.T, float(min(request[j], lp.fmax[j]))) for j in range(lp.m) if request[j] > 0]
    out.firings += [(j, t0 + a, t0 + b, f, "control") for j, a, b, f in ctrl] + \
                   [(j, t0 + a, t0 + b, f, "disturbance") for j, a, b, f in dist]
    return ctrl, dist


def _columns(intervals):
    if not intervals:
        return [], [], [], []
    j, a, b, f = zip(*intervals)
    return list(j), list(a), list(b), list(f)


def _pulse_intervals(pulse: Disturbance | None, jets, t0: float, T: float):
    """(jet, start, end, force) of the disturbance pulse inside [t0, t0 + T), times from t0."""
    if pulse is None:
        return []
    a, b = max(pulse.start_s, t0) - t0, min(pulse.end_s, t0 + T) - t0
    if b - a <= 1e-12:
        return []
    return [(j, a, b, pulse.force_n) for j in jets]


def closed_loop_trajectory(cfg: StructureConfig, scenario: str, gains: dict, *, vibration_control: bool = True,
                           feedback: str = "gps", pwpf: PwpfParams | None = None, record: dict | None = None,
                           slew_reference_kind: str = "profile", estimator_noise_scale: float | None = None,
                           actuator: str = "pwpf", pulse_known: bool = False):
    """The ``trajectory`` hook of :func:`cdgps_cli.sim.structure.simulate` for a closed-loop run.

    Parameters
    ----------
    cfg : StructureConfig
    scenario : {"pulse", "slew"}
    gains : dict
        A GAINS record (:func:`cdgps_cli.io.gains_file.read_gains`) designed on this config.
    vibration_control : bool
        False: the rigid-body-only regulator of Fig. 12 (:func:`rigid_only_gain`), its rigid pole
        matched to the gain's.
    feedback : {"gps", "truth"}
    pwpf : PwpfParams, optional
    record : dict, optional
        Receives ``result`` (the :class:`ClosedLoopResult`) for the caller's logs.
    slew_reference_kind : {"profile", "step"}
        See :func:`slew_reference`.
    estimator_noise_scale : float, optional
        The in-loop EKF's process-noise scale; None: the separation rule for the gain in use
        (:func:`loop_estimator`).
    actuator, pulse_known
        See :func:`run_closed_loop`.
    """
    model = discrete_model(cfg)
    if "sample_period_s" in gains and not math.isclose(float(gains["sample_period_s"]), cfg.sample_period_s,
                                                       rel_tol=1e-12, abs_tol=0.0):
        raise CdgpsError(f"GAINS.json: key 'sample_period_s' is {gains['sample_period_s']!r} s, the config's "
                         f"model.sample_period_s is {cfg.sample_period_s!r} s; design the gain for this config "
                         "with `cdgps control design`")
    if gains["A"].shape != model.A.shape or not (np.allclose(gains["A"], model.A, rtol=0, atol=1e-9)
                                                 and np.allclose(gains["B"], model.B, rtol=0, atol=1e-9)):
        raise CdgpsError("GAINS.json: its A and B are not this config's discrete model")
    names = list(gains.get("thruster_names", cfg.thruster_names))
    if names != list(cfg.thruster_names):
        unknown = [t for t in names if t not in cfg.thruster_names]
        raise CdgpsError("GAINS.json: key 'thruster_names' does not match the config's [[thrusters]] in order"
                         + (f" (unknown: {', '.join(unknown)})" if unknown else " (same names, another order)"))
    K = gains["K"]
    if not vibration_control:
        target = gains["poles"]["settling_time_s"]["closed_loop"].get(_rigid_name(cfg))
        if target is None:
            raise CdgpsError("--no-vibration-control: the gain's rigid-body pole does not settle, so there is "
                             "no rigid-body pole to match")
        K = rigid_only_gain(cfg, model.A, model.B, float(target))
    est = loop_estimator(cfg, K) if estimator_noise_scale is None else {"scale": float(estimator_noise_scale),
                                                                        "rule": "given", "met": None}
    mp = model_from(cfg)                     # the config's [model] multipath, as the pipeline's filter
    sim = cfg.simulation
    pwpf = PwpfParams() if pwpf is None else pwpf

    def trajectory(time_s, x0, w, noise_m):
        n = model.A.shape[0]
        x_ref = np.zeros((len(time_s), n))
        pulse, planner, epochs = None, None, ()
        if scenario == "slew":
            # held at the initial estimate, then planned from the estimate when the step is commanded
            planner = lambda x_fb: slew_reference(cfg, time_s, x_fb, slew_reference_kind)  # noqa: E731
            epochs = (0, int(np.searchsorted(np.asarray(time_s), sim["slew_time_s"] - 1e-9)))
        else:
            pulse = Disturbance(tuple(sim["pulse_thrusters"]), sim["pulse_time_s"],
                                sim["pulse_time_s"] + sim["pulse_duration_s"], sim["pulse_force_n"])
        r = run_closed_loop(cfg, K, x0, w, noise_m, x_ref, pulse, pwpf=pwpf, estimator=feedback,
                            process_noise_scale=est["scale"], planner=planner, plan_epochs=epochs, multipath=mp,
                            actuator=actuator, pulse_known=pulse_known)
        r.estimator = est
        if record is not None:
            record["result"], record["x_ref"] = r, r.x_ref
        extra = {"controller": {"feedback": feedback, "vibration_control": vibration_control,
                                **({"slew_reference": slew_reference_kind} if scenario == "slew" else {}),
                                "gains_config_sha256": gains["config"]["sha256"],
                                "gains_k_sha256": gain_sha256(gains["K"]),
                                "weight_set": gains.get("weight_set", "custom"),
                                "pwpf": {"gain": pwpf.gain, "time_constant_s": pwpf.time_constant_s,
                                         "u_on": pwpf.u_on, "u_off": pwpf.u_off, "anti_windup": pwpf.anti_windup,
                                         **({"input_limit": pwpf.input_limit} if pwpf.anti_windup else {})},
                                "firings": len(merge_firings(r.firings)),
                                "saturated_fraction": r.saturated_fraction,
                                "estimator_nis_per_dof": float(np.mean(r.nis) / noise_m.shape[1]),
                                "estimator_process_noise_scale": est["scale"],
                                "estimator_rule": est.get("rule"),
                                "estimator_rule_met": est.get("met"),
                                **({"estimator_multipath": mp.echo()} if mp.active else {}),
                                **({"estimator_knows_pulse": True} if pulse_known else {}),
                                **({"actuator": actuator} if actuator != "pwpf" else {}),
                                "initial_estimate": "the truth, covariance "
                                                    f"({INITIAL_ESTIMATE_SIGMA:g})² I; biases known exactly"}}
        return r.x_true, actuator_log(cfg, r.firings), extra

    return trajectory


def _rigid_name(cfg: StructureConfig) -> str:
    return cfg.mode_names[list(cfg.mode_frequency_hz).index(0.0)]


def actuator_log(cfg: StructureConfig, firings):
    """The native actuator log (time_s, actuator, force_n) of the firings: per jet a row at each change
    of its force — the force at a switch-on, 0 at a switch-off.  Firings of one jet that abut (a
    control firing running into the disturbance pulse on the same jet, or firings continued across
    periods) are one level: no off-and-on pair at the same instant, which ``cdgps ingest`` would
    refuse as a duplicate row."""
    import pandas as pd

    names = list(cfg.thruster_names)
    spans: dict = {}
    for j, a, b, f, _src in firings:
        spans.setdefault(j, []).append((round(a, 9), round(b, 9), float(f)))
    rows = []
    for j, jet_spans in spans.items():
        runs: list = []                                 # [start, end, force], contiguous equal forces joined
        for a, b, f in sorted(jet_spans):
            if runs and a <= runs[-1][1] + 1e-9 and f == runs[-1][2]:
                runs[-1][1] = max(runs[-1][1], b)
            else:
                runs.append([a, b, f])
        for k, (a, b, f) in enumerate(runs):
            rows.append((a, names[j], f))
            if k + 1 == len(runs) or runs[k + 1][0] > b + 1e-9:    # else the next run's row sets the force
                rows.append((b, names[j], 0.0))
    rows.sort(key=lambda r: (r[0], names.index(r[1]), r[2]))
    return pd.DataFrame(rows, columns=["time_s", "actuator", "force_n"])


def controller_log(cfg: StructureConfig, result: ClosedLoopResult, x_ref: np.ndarray):
    """controller.csv: per epoch the estimate the controller used (``<q>_hat_<unit>``), its 1σ
    (``<q>_hat_sigma_<unit>``), the reference (``<q>_ref_<unit>``),
    the reference, the EKF's NIS and the thrust requested from every jet's modulator (N)."""
    import pandas as pd

    nm = cfg.n_modes
    U = np.asarray(cfg.mode_shapes)
    q_hat = result.x_hat[:, :nm] @ U.T
    cols = {"time_s": result.time_s}
    units = [column_unit(cfg, c) for c in cfg.coord_names]          # q10_hat_rad … (issue 32: units in names)
    for i, (c, u) in enumerate(zip(cfg.coord_names, units)):
        cols[f"{c}_hat_{u}"] = np.round(q_hat[:, i], 12)
    for i, (c, u) in enumerate(zip(cfg.coord_names, units)):
        cols[f"{c}_hat_sigma_{u}"] = np.round(result.sigma_q_hat[:, i], 12)
    for i, (c, u) in enumerate(zip(cfg.coord_names, units)):
        cols[f"{c}_ref_{u}"] = np.round(x_ref[:, :nm] @ U[i], 12)
    cols["nis"] = np.round(result.nis, 6)
    for j, name in enumerate(cfg.thruster_names):
        cols[f"command_{name}_n"] = np.round(result.command_n[:, j], 9)
    return pd.DataFrame(cols)


def simulate_closed_loop(cfg: StructureConfig, opt, gains: dict, *, vibration_control: bool = True,
                         feedback: str = "gps", pwpf: PwpfParams | None = None, slew_reference_kind: str = "profile",
                         estimator_noise_scale: float | None = None, actuator: str = "pwpf",
                         pulse_known: bool = False):
    """:func:`cdgps_cli.sim.structure.simulate` with the closed loop in place of the open-loop propagation;
    the Simulation gains ``controller.csv`` (:func:`controller_log`).  Keywords: :func:`closed_loop_trajectory`."""
    record: dict = {}
    hook = closed_loop_trajectory(cfg, opt.scenario, gains, vibration_control=vibration_control,
                                  feedback=feedback, pwpf=pwpf, record=record,
                                  slew_reference_kind=slew_reference_kind,
                                  estimator_noise_scale=estimator_noise_scale, actuator=actuator,
                                  pulse_known=pulse_known)
    sim = simulate(cfg, opt, trajectory=hook)
    sim.tables["controller.csv"] = controller_log(cfg, record["result"], record["x_ref"])
    return sim, record["result"]
