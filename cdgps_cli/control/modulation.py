"""Pulse-width pulse-frequency (PWPF) modulation of on/off thrusters (1998 paper, Sec. V).

The 1998 testbed realizes the LQR's continuous commands with on/off gas jets through a PWPF
modulator; the paper gives no parameters, so the common textbook values are the defaults
(K_m = 4.5, T_m = 0.85 s, U_on = 0.45, U_off = 0.15; e.g. Wie, *Space Vehicle Dynamics and Control*,
Sec. 7.3).  Per thruster, with the command e normalized by the thruster's maximum force and the
output y ∈ {0, 1}:

    T_m ḟ = K_m (e − y) − f          (first-order filter of the error)
    y: 0 → 1 when f ≥ U_on,  1 → 0 when f ≤ U_off     (Schmitt trigger, hysteresis h = U_on − U_off)

With e held constant over a control period the filter is linear between switchings, so switching
instants are computed exactly (no sub-stepping): f(t) = a + (f₀ − a) e^{−t/T_m} with a = K_m (e − y).
Closed-form static characteristics for a constant e (used by the tests as the independent check):

* dead zone: no pulse from rest for e < U_on / K_m
* saturation: the thruster stays on for e > 1 + U_off / K_m
* on-time  T_on  = −T_m ln(1 − h / (U_on − K_m (e − 1)))
* off-time T_off = −T_m ln(1 − h / (K_m e − U_off))
* minimum pulse Δ = −T_m ln(1 − h / K_m) (59 ms with the defaults)

The thrust is y times the thruster's maximum force, so it never exceeds that force.

**Input limit (anti-windup).**  Above the saturation level the jet is already on all the time, and a
larger command only charges the filter: on, f tends to K_m (e − 1), so a request of 14 × F_max (what
a high-gain regulator asks for at times) drives f towards 58 and the jet stays on for
T_m ln((f + K_m)/(U_off + K_m)) ≈ 2.2 s after the request has dropped to zero — a lag inside the
loop that the regulator never designed for.  The command is therefore limited to
e_max = 1 + U_on/K_m (1.1 with the defaults), above the saturation level, so a saturated jet stays on
as before, and the filter never exceeds U_on: a jet turns off at most
T_m ln((K_m + U_on)/(K_m + U_off)) (53 ms with the defaults) after its request drops to zero.
``PwpfParams(anti_windup=False)`` keeps the unlimited textbook filter (for comparison only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cdgps_cli.core.errors import CdgpsError


@dataclass(frozen=True)
class PwpfParams:
    """PWPF parameters: filter gain K_m (−), filter time constant T_m (s), trigger on/off levels (−),
    and whether the command is limited to :attr:`input_limit` (anti-windup, module docstring)."""

    gain: float = 4.5
    time_constant_s: float = 0.85
    u_on: float = 0.45
    u_off: float = 0.15
    anti_windup: bool = True

    def __post_init__(self):
        problems = []
        for name in ("gain", "time_constant_s", "u_on"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                problems.append(f"{name}: expected a positive number, got {v!r}")
        if not (isinstance(self.u_off, (int, float)) and math.isfinite(self.u_off) and 0 <= self.u_off):
            problems.append(f"u_off: expected a number >= 0, got {self.u_off!r}")
        elif not problems and not self.u_off < self.u_on:
            problems.append(f"u_off: must be below u_on ({self.u_on:g}), got {self.u_off:g}")
        if problems:
            raise CdgpsError("invalid PWPF parameters:\n  - " + "\n  - ".join(problems))

    @property
    def hysteresis(self) -> float:
        """h = U_on − U_off."""
        return self.u_on - self.u_off

    @property
    def input_limit(self) -> float:
        """Largest normalized command the filter is driven with, 1 + U_on/K_m (inf without anti-windup)."""
        return 1.0 + self.u_on / self.gain if self.anti_windup else math.inf


def dead_zone(p: PwpfParams) -> float:
    """Largest normalized command that never fires from rest, U_on / K_m."""
    return p.u_on / p.gain


def saturation_level(p: PwpfParams) -> float:
    """Normalized command above which the thruster stays on, 1 + U_off / K_m."""
    return 1.0 + p.u_off / p.gain


def minimum_pulse_s(p: PwpfParams) -> float:
    """Shortest pulse the modulator emits (at the dead-zone edge), s."""
    return -p.time_constant_s * math.log(1.0 - p.hysteresis / p.gain)


def on_time_s(p: PwpfParams, e: float) -> float:
    """Steady-cycle pulse width for a constant normalized command e in (dead zone, saturation), s."""
    return -p.time_constant_s * math.log(1.0 - p.hysteresis / (p.u_on - p.gain * (e - 1.0)))


def off_time_s(p: PwpfParams, e: float) -> float:
    """Steady-cycle gap between pulses for a constant normalized command e above the dead zone, s."""
    return -p.time_constant_s * math.log(1.0 - p.hysteresis / (p.gain * e - p.u_off))


def duty_cycle(p: PwpfParams, e: float) -> float:
    """Steady on-fraction T_on / (T_on + T_off) for a constant command e (0 in the dead zone, 1 saturated)."""
    if e <= dead_zone(p):
        return 0.0
    if e >= saturation_level(p):
        return 1.0
    ton, toff = on_time_s(p, e), off_time_s(p, e)
    return ton / (ton + toff)


def _time_to_switch(f: float, on: bool, e: float, p: PwpfParams) -> float:
    """Time until the trigger flips under constant e, s (inf if it never does)."""
    a = p.gain * (e - (1.0 if on else 0.0))
    if on:
        if a >= p.u_off:
            return math.inf
        return 0.0 if f <= p.u_off else p.time_constant_s * math.log((f - a) / (p.u_off - a))
    if a <= p.u_on:
        return 0.0 if f >= p.u_on else math.inf
    return 0.0 if f >= p.u_on else p.time_constant_s * math.log((a - f) / (a - p.u_on))


def pwpf_interval(f: float, on: bool, e: float, duration_s: float, p: PwpfParams):
    """Advance one modulator over ``duration_s`` with the constant normalized command ``e``.

    Parameters
    ----------
    f : float
        Filter state at the start (−).
    on : bool
        Trigger output at the start.
    e : float
        Normalized command over the interval (negative values count as 0, values above
        ``p.input_limit`` as that limit).
    duration_s : float
        Interval length, s.
    p : PwpfParams

    Returns
    -------
    f, on : float, bool
        State at the end.
    switches_s : list of float
        Switching instants from the start of the interval, s, ascending (each flips ``on``).
    """
    e = min(max(float(e), 0.0), p.input_limit)
    t, switches = 0.0, []
    limit = int(duration_s / minimum_pulse_s(p)) * 2 + 4
    while len(switches) <= limit:
        dt = _time_to_switch(f, on, e, p)
        if t + dt >= duration_s:
            a = p.gain * (e - (1.0 if on else 0.0))
            return a + (f - a) * math.exp(-(duration_s - t) / p.time_constant_s), on, switches
        t += dt
        f = p.u_off if on else p.u_on
        on = not on
        switches.append(t)
    raise AssertionError("PWPF: more switchings than the minimum pulse allows")  # unreachable by construction


def modulate(commands, max_force_n, period_s: float, p: PwpfParams | None = None):
    """Run one PWPF modulator per thruster over a series of held commands (zero-order hold).

    Parameters
    ----------
    commands : array_like, shape (N, m)
        Thrust requested per control period and thruster, N (≥ 0; negative values fire nothing).
    max_force_n : array_like, shape (m,)
        Each thruster's force when on, N (> 0).
    period_s : float
        Control period, s.
    p : PwpfParams, optional
        Defaults to :class:`PwpfParams` ().

    Returns
    -------
    pulses : list of list of (float, float)
        Per thruster, its firings as (on_s, off_s) from the start of the first period; a firing still
        on at the end closes at N · period_s.
    on_fraction : ndarray, shape (N, m)
        Fraction of each period each thruster was on (the period's mean force / max force).
    """
    p = PwpfParams() if p is None else p
    u = np.asarray(commands, dtype=float)
    fmax = np.asarray(max_force_n, dtype=float)
    if u.ndim != 2 or fmax.shape != (u.shape[1],):
        raise CdgpsError(f"PWPF: commands must be (periods, thrusters) with one max force per thruster, "
                         f"got {u.shape} and {fmax.shape}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(fmax)) and np.all(fmax > 0)):
        raise CdgpsError("PWPF: commands must be finite and every max force positive")
    N, m = u.shape
    pulses: list[list[tuple[float, float]]] = [[] for _ in range(m)]
    frac = np.zeros((N, m))
    for j in range(m):
        f, on, start = 0.0, False, None
        for k in range(N):
            t0 = k * period_s
            was_on = on
            f, on, sw = pwpf_interval(f, on, u[k, j] / fmax[j], period_s, p)
            frac[k, j] = _on_time_in_period(was_on, sw, period_s) / period_s
            for ts in sw:
                if start is None:
                    start = t0 + ts
                else:
                    pulses[j].append((start, t0 + ts))
                    start = None
        if start is not None:
            pulses[j].append((start, N * period_s))
    return pulses, frac


def _on_time_in_period(was_on: bool, switches, period_s: float) -> float:
    edges = [0.0, *switches, period_s]
    on, total = was_on, 0.0
    for a, b in zip(edges[:-1], edges[1:]):
        if on:
            total += b - a
        on = not on
    return total


def modulate_period(e, f_state, on_state, T, pwpf, fmax):
    """Advance every jet's modulator over one control period with its command held.

    Parameters
    ----------
    e : ndarray, shape (m,)
        Command of each jet divided by its maximum force (−).
    f_state : ndarray, shape (m,)
        Filter state of each jet, updated in place.
    on_state : ndarray of bool, shape (m,)
        Trigger output of each jet, updated in place.
    T : float
        Period, s.
    pwpf : PwpfParams
    fmax : ndarray, shape (m,)
        Maximum force per jet, N.

    Returns
    -------
    list of (int, float, float, float)
        (jet, on_s, off_s, force_n) of every firing inside the period, times from its start.
    """
    firings = []
    for j in range(len(e)):
        was_on = bool(on_state[j])
        f_state[j], on_state[j], switches = pwpf_interval(f_state[j], was_on, e[j], T, pwpf)
        edges = [0.0, *switches, T]
        on = was_on
        for a, b in zip(edges[:-1], edges[1:]):
            if on and b > a:
                firings.append((j, a, b, float(fmax[j])))
            on = not on
    return firings


def merge_firings(firings) -> list:
    """Join a jet's firings that continue across period boundaries: (jet, on_s, off_s, force, source)."""
    out: list = []
    last: dict = {}
    for j, a, b, f, src in sorted(firings, key=lambda r: (r[0], r[4], r[1])):
        key = (j, src)
        if key in last and abs(out[last[key]][2] - a) < 1e-9:
            jj, aa, _, ff, ss = out[last[key]]
            out[last[key]] = (jj, aa, b, ff, ss)
        else:
            last[key] = len(out)
            out.append((j, a, b, f, src))
    return sorted(out, key=lambda r: (r[1], r[0]))
