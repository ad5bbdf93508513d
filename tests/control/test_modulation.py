"""PWPF modulator: closed-form dead zone, saturation, on/off times and minimum pulse; an independent
fine-step time-domain simulation; thruster allocation keeps the generalized force."""

import math

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.control.allocation import opposing_pairs, realize_forces
from cdgps_cli.control.modulation import (PwpfParams, dead_zone, duty_cycle, minimum_pulse_s, modulate,
                                          off_time_s, on_time_s, pwpf_interval, saturation_level)
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.kinematics import thruster_forcing

P = PwpfParams()


def test_defaults_minimum_pulse_is_59_ms():
    assert minimum_pulse_s(P) == pytest.approx(-0.85 * math.log(1 - 0.3 / 4.5), rel=1e-15)
    assert 0.058 < minimum_pulse_s(P) < 0.059


def _steady_pulses(e, periods=600, T=0.1):
    pulses, frac = modulate(np.full((periods, 1), e), [1.0], T, P)
    return pulses[0], frac[:, 0]


@pytest.mark.parametrize("e", [0.15, 0.3, 0.5, 0.8, 1.0])
def test_steady_cycle_matches_closed_form(e):
    pulses, frac = _steady_pulses(e)
    on = [b - a for a, b in pulses[3:-1]]
    off = [pulses[i + 1][0] - pulses[i][1] for i in range(3, len(pulses) - 1)]
    assert np.allclose(on, on_time_s(P, e), rtol=1e-9)
    assert np.allclose(off, off_time_s(P, e), rtol=1e-9)
    cycle = on_time_s(P, e) + off_time_s(P, e)
    tail = frac[-int(20 * cycle / 0.1):]                 # whole cycles' worth of periods, roughly
    assert tail.mean() == pytest.approx(duty_cycle(P, e), abs=0.02)


def test_dead_zone_edge():
    dz = dead_zone(P)
    assert dz == pytest.approx(0.1)
    assert _steady_pulses(dz * (1 - 1e-6))[0] == []
    pulses, _ = _steady_pulses(dz * (1 + 1e-6))
    assert pulses and pulses[1][1] - pulses[1][0] == pytest.approx(minimum_pulse_s(P), rel=1e-4)


def test_saturation_edge():
    sat = saturation_level(P)
    assert sat == pytest.approx(1 + 0.15 / 4.5)
    pulses, frac = _steady_pulses(sat * (1 + 1e-6), periods=100)
    assert len(pulses) == 1 and pulses[0][1] == pytest.approx(10.0)       # on to the end
    assert np.all(frac[10:] == 1.0)
    pulses, _ = _steady_pulses(sat * (1 - 1e-3), periods=600)
    assert len(pulses) > 2                                               # still pulsing below it


def _ode_reference(commands, T):
    """Independent integration of T_m ḟ = K_m(e − y) − f with scipy's solve_ivp and event location of
    the trigger levels (the modulator under test uses closed-form exponentials instead)."""
    from scipy.integrate import solve_ivp

    f, y, edges = 0.0, 0, []
    for k, e in enumerate(commands):
        t, end = k * T, (k + 1) * T
        while True:
            level = P.u_off if y else P.u_on
            event = lambda _t, s: s[0] - level  # noqa: E731
            event.terminal = True
            sol = solve_ivp(lambda _t, s: [(P.gain * (max(e, 0.0) - y) - s[0]) / P.time_constant_s],
                            (t, end), [f], events=event, rtol=1e-12, atol=1e-14)
            if sol.t_events[0].size and sol.t_events[0][0] < end:
                t, f, y = float(sol.t_events[0][0]), level, 1 - y
                edges.append(t)
                continue
            f = float(sol.y[0, -1])
            break
    return edges


def test_time_varying_command_matches_fine_step_simulation():
    T = 0.1
    k = np.arange(80)
    cmd = 0.6 + 0.5 * np.sin(2 * np.pi * k * T / 3.0) - 0.3 * (k > 50)
    pulses, _ = modulate(cmd[:, None], [1.0], T, P)
    exact = [t for a, b in pulses[0] for t in (a, b) if t < len(cmd) * T - 1e-12]
    ref = _ode_reference(cmd, T)
    assert len(exact) == len(ref) and len(ref) > 10
    np.testing.assert_allclose(exact, ref, atol=1e-8)


def test_force_never_exceeds_max_and_fraction_is_mean_force():
    g = np.random.default_rng(3)
    cmd = np.abs(g.normal(0, 2.0, size=(200, 4)))          # often far above the max force
    fmax = np.array([1.4, 1.4, 0.7, 2.0])
    pulses, frac = modulate(cmd, fmax, 0.1, P)
    assert frac.min() >= 0 and frac.max() <= 1
    for j in range(4):
        on_total = sum(b - a for a, b in pulses[j])
        assert on_total == pytest.approx(frac[:, j].sum() * 0.1, abs=1e-9)
        assert all(b > a for a, b in pulses[j])


def test_interval_is_additive():
    """Advancing 0.1 s in one call equals two calls of 0.05 s (exact propagation, no step error)."""
    f1, on1, sw1 = pwpf_interval(0.3, False, 0.7, 0.1, P)
    fa, ona, swa = pwpf_interval(0.3, False, 0.7, 0.05, P)
    fb, onb, swb = pwpf_interval(fa, ona, 0.7, 0.05, P)
    assert (f1, on1) == pytest.approx((fb, onb), abs=1e-12)
    assert sw1 == pytest.approx(swa + [0.05 + s for s in swb], abs=1e-12)


def test_a_saturated_request_does_not_wind_up_the_filter():
    """5 s of a request 14 times the jet's force, then none: the jet switches off
    T_m ln((K_m + U_on)/(K_m + U_off)) (53 ms) after the request drops (closed form: the input limit
    1 + U_on/K_m holds the on-state filter at U_on).  The unlimited filter charges towards
    K_m (14 − 1) = 58.5 and keeps the jet on for seconds (the lag that destabilized the paper's gain)."""
    T, cmd = 0.1, np.r_[np.full(50, 14.0), np.zeros(40)][:, None]
    pulses, _ = modulate(cmd, [1.0], T, P)
    start = P.time_constant_s * math.log(P.input_limit * P.gain / (P.input_limit * P.gain - P.u_on))
    stop = 5.0 + P.time_constant_s * math.log((P.gain + P.u_on) / (P.gain + P.u_off))
    assert P.input_limit == pytest.approx(1.1) and stop - 5.0 == pytest.approx(0.0531, abs=1e-4)
    assert len(pulses[0]) == 1
    assert pulses[0][0] == pytest.approx((start, stop), abs=1e-12)
    wound, _ = modulate(cmd, [1.0], T, PwpfParams(anti_windup=False))
    assert len(wound[0]) == 1 and wound[0][0][1] - 5.0 > 1.5


def test_filter_never_exceeds_the_on_level_with_the_input_limit():
    g = np.random.default_rng(7)
    f, on = 0.0, False
    for e in np.abs(g.normal(0.0, 5.0, size=2000)):
        f, on, _ = pwpf_interval(f, on, e, 0.1, P)
        assert f <= P.u_on + 1e-12
    assert not math.isfinite(PwpfParams(anti_windup=False).input_limit)


@pytest.mark.parametrize("kw,words", [({"gain": 0}, "gain"), ({"u_off": 0.5}, "u_off: must be below u_on"),
                                      ({"time_constant_s": float("nan")}, "time_constant_s"),
                                      ({"u_off": -1}, "u_off")])
def test_bad_parameters_are_named(kw, words):
    with pytest.raises(CdgpsError, match=words):
        PwpfParams(**kw)


def test_modulate_refuses_bad_input():
    with pytest.raises(CdgpsError, match="finite"):
        modulate(np.array([[np.nan]]), [1.0], 0.1)
    with pytest.raises(CdgpsError, match="one max force per thruster"):
        modulate(np.zeros((3, 2)), [1.0], 0.1)


def test_testbed_pairs_realize_the_same_generalized_force(repo_root):
    cfg = load_config(repo_root / "configs" / "testbed-1998-lumped.toml")
    pairs = opposing_pairs(cfg.thruster_section, cfg.thruster_position_m, cfg.thruster_direction)
    assert len(pairs) == 12
    Ups = thruster_forcing(cfg)
    u = np.random.default_rng(0).normal(size=(50, 24))
    f = realize_forces(u, pairs)
    assert f.min() >= 0
    np.testing.assert_allclose(f @ Ups.T, u @ Ups.T, atol=1e-12)
    for i, j in pairs:
        assert np.all((f[:, i] == 0) | (f[:, j] == 0))          # never both jets of a pair
