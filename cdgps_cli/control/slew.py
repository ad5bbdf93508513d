"""The slew command of the 1998 paper's Figs. 11–12 as the regulator's reference: the raw step, the
step through a rate- and acceleration-limited command filter, or a bang-bang profile with its
feed-forward thrust, planned from the state the controller feeds back.  Numerics only."""

from __future__ import annotations

import numpy as np

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.dynamics import discrete_model


#: fraction of the jets' rigid-body authority a slew profile may use (the rest is left to the feedback)
SLEW_AUTHORITY_FRACTION = 0.7


def rigid_authority(cfg: StructureConfig, direction: float = 1.0) -> tuple[int, np.ndarray, float]:
    """The rigid-body mode's index, its generalized force per newton of each jet (Uᵀ Υ row, shape (m,))
    and the largest modal acceleration the jets can give it in ``direction`` (sign), each jet at its
    maximum force where it pushes that way and one jet of each opposing pair firing."""
    from cdgps_cli.model.kinematics import thruster_forcing

    rigid = list(cfg.mode_frequency_hz).index(0.0)
    g = (np.asarray(cfg.mode_shapes).T @ thruster_forcing(cfg))[rigid]
    push = np.clip(np.sign(direction) * g, 0.0, None) * np.asarray(cfg.thruster_max_force_n, dtype=float)
    return rigid, g, float(push.sum())


def slew_reference(cfg: StructureConfig, time_s, x0, kind: str = "profile"):
    """Reference states (N, n) and feed-forward signed commands (N, m) or None for a slew from the
    initial angle to ``[simulation] slew_to_deg`` commanded at ``slew_time_s``.

    ``"step"``: the paper's command, the reference jumps to the target (no feed-forward).
    ``"shaped-step"``: the paper's step command through the controller's command filter: the
    reference angle and rate follow the profile's rigid-body shape below (acceleration and rate
    limited), with no feed-forward thrust and no elastic reference — what a servo does with a step
    its actuators cannot follow.
    ``"profile"``: a bang-bang (accelerate, then decelerate) rigid-body angle and rate profile at
    :data:`SLEW_AUTHORITY_FRACTION` of the jets' rigid authority, with the feed-forward thrust that
    produces it (minimum-norm over the jets, including the rate damping of the rigid mode).
    """
    sim = cfg.simulation
    nm = cfg.n_modes
    rigid = list(cfg.mode_frequency_hz).index(0.0)
    scale = cfg.mode_shapes[cfg.rigid_index, rigid]
    a0, a1 = float(x0[rigid]), np.radians(sim["slew_to_deg"]) / scale
    _, g, acc_max = rigid_authority(cfg, a1 - a0)
    t = np.asarray(time_s) - sim["slew_time_s"]
    x_ref = np.zeros((len(t), 2 * nm))
    if kind == "step":
        x_ref[:, rigid] = np.where(t >= -1e-9, a1, a0)
        return x_ref, None
    if kind not in ("profile", "shaped-step"):
        raise CdgpsError(f"slew reference: expected 'profile', 'shaped-step' or 'step', got {kind!r}")
    acc = SLEW_AUTHORITY_FRACTION * acc_max * np.sign(a1 - a0)
    half = np.sqrt(abs(a1 - a0) / max(abs(acc), 1e-300))
    tt = np.clip(t, 0.0, 2 * half)
    first = tt <= half
    amp = np.where(first, a0 + 0.5 * acc * tt**2, a1 - 0.5 * acc * (2 * half - tt) ** 2)
    rate = np.where(first, acc * tt, acc * (2 * half - tt))
    accel = np.where((t > 0) & (t < 2 * half), np.where(first, acc, -acc), 0.0)
    x_ref[:, rigid], x_ref[:, nm + rigid] = amp, rate
    if kind == "shaped-step":
        return x_ref, None
    from cdgps_cli.model.dynamics import modal_damping

    force = accel + modal_damping(cfg)[rigid] * rate          # ξ̈ + c ξ̇ = g·u
    u_ff = np.outer(force, g / (g @ g))
    # the elastic modes' reference is the model's own response to the feed-forward thrust, so the
    # feedback damps deviations from the planned motion instead of fighting the plan
    model = discrete_model(cfg)
    elastic = np.ones(2 * nm, dtype=bool)
    elastic[[rigid, nm + rigid]] = False
    xe = np.zeros(2 * nm)
    for k in range(len(t)):
        x_ref[k, elastic] = xe[elastic]
        xe = model.A @ xe + model.B @ u_ff[k]
    return x_ref, u_ff


def bang_bang_slew_time_s(cfg: StructureConfig, angle_rad: float, fraction: float = 1.0) -> float:
    """Rest-to-rest time of a rigid-body slew by ``angle_rad`` with the jets' rigid-body authority
    times ``fraction``: accelerate for half, decelerate for half, 2 √(|Δθ| / (fraction · α_max)), s.

    α_max is the rigid-body angle's acceleration with every jet that turns the body that way at its
    maximum force (:func:`rigid_authority`; on the testbed 6 jets × 1.4 N × 1 m over the rigid mode's
    inertia).  The flexible modes, the rigid mode's rate damping and the modulator are ignored: this
    is the physical lower bound the slew profile is planned against, not a prediction.
    """
    if not (np.isfinite(fraction) and 0 < fraction <= 1):
        raise CdgpsError(f"fraction: expected a number in (0, 1], got {fraction!r}")
    rigid = list(cfg.mode_frequency_hz).index(0.0)
    scale = cfg.mode_shapes[cfg.rigid_index, rigid]                    # rad of the rigid angle per unit ξ
    _, _, acc = rigid_authority(cfg, np.sign(angle_rad * scale) or 1.0)
    alpha = acc * abs(scale)          # rad/s² of the rigid-body angle
    return float(2.0 * np.sqrt(abs(angle_rad) / (fraction * alpha)))
