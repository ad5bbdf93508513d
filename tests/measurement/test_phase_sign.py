"""Carrier phases written with the wrong sign (measurement/phase_sign): found from code minus phase against code plus
phase, on synthetic channels (any range rate, a closest approach, code clock jumps, 10 Hz noise) and on the real
mosaic-X5 pair with two satellites' phases negated as gnss-sdr 0.0.19 wrote them (sim/rinex_edit): ``rtk`` and
``baseline`` leave exactly those out and land where the unedited pair does; before, such a pair gave float positions
thousands of kilometres off with σ of metres, exit 0."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.io.rinex import read_rinex_obs
from cdgps_cli.io.rinex_signals import read_rinex_signals
from cdgps_cli.measurement.phase_sign import (reversed_phase_channels, without_reversed_l1_phases,
                                              without_reversed_phases)
from cdgps_cli.sim.rinex_edit import edit_rinex3_obs
from tests._shared import MOSAIC_DIR, run_cli

NEGATED = ("G05", "G13")


def _channels(rate_hz=1.0, duration_s=300.0, code_sigma_m=1.0, seed=1):
    """Six channels of one receiver: range rates −700 … +700 m/s and one at its closest approach (rate 0.02 m/s,
    curvature 0.1 mm/s²), code noise σ, phase noise 2 mm, a common clock drift; the first three phases reversed."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    rates = np.array([-700.0, 300.0, 650.0, -200.0, 0.02, 500.0])
    clock = 3.0 * t + 1e-3 * t**2
    ch, tt, phase, code = [], [], [], []
    for k, v in enumerate(rates):
        rho = 2.2e7 + v * t + (5e-5 * t**2 if k == 4 else 0.0) + clock
        sign = -1.0 if k < 3 else 1.0
        ch.append(np.full(t.size, k))
        tt.append(t)
        phase.append(sign * rho + 0.002 * rng.standard_normal(t.size) + 1e3 * k)
        code.append(rho + code_sigma_m * rng.standard_normal(t.size))
    return tuple(np.concatenate(a) for a in (ch, tt, phase, code))


def test_reversed_channels_are_found_at_any_range_rate_and_right_ones_never():
    ch, t, phase, code = _channels()
    bad, minus, plus = reversed_phase_channels(ch, t, phase, code)
    per = {int(c): bool(bad[ch == c][0]) for c in np.unique(ch)}
    assert per == {0: True, 1: True, 2: True, 3: False, 4: False, 5: False}
    assert np.all(minus[ch == 0] > 1000) and np.all(plus[ch == 0] < 5)      # twice 700 m/s; code noise alone
    assert np.all(minus[ch == 4] < 5)          # a right channel: code noise (σ 1 m, pairs 1 s apart) whatever its rate


def test_ten_hz_noisy_codes_and_clock_jumps_in_the_codes_do_not_change_the_answer():
    ch, t, phase, code = _channels(rate_hz=10.0, duration_s=120.0, code_sigma_m=3.0)
    jumps = 299792.458 * np.floor(t / 17.0)                     # a 1 ms code clock reset every 17 s, phases continuous
    bad, _, _ = reversed_phase_channels(ch, t, phase, code + jumps)
    assert {int(c): bool(bad[ch == c][0]) for c in np.unique(ch)} == {0: True, 1: True, 2: True, 3: False, 4: False,
                                                                      5: False}


@pytest.mark.parametrize("drift_m_s", [300.0, -1000.0])
@pytest.mark.parametrize("n_reversed", [3, 5])
def test_a_code_carrier_drift_common_to_the_receiver_is_no_evidence(drift_m_s, n_reversed):
    """Code and phase parting at a rate common to every channel (gnss-sdr has written such records: a clock
    correction applied to one and not the other) cancel in double differences: no right channel is flagged, whatever
    its range rate (one at −D/2, whose code plus phase then changes as little as a reversed one's would), and the
    reversed ones still are, also when they are the majority (5 of 6)."""
    ch, t, phase, code = _channels()
    rates = np.array([-700.0, 300.0, 650.0, -200.0, 0.02, 500.0])
    right = np.flatnonzero(np.arange(6) >= 3)
    phase = phase.copy()
    for k in range(3, 3 + n_reversed - 3):                       # more reversed channels: 4 and 5 too
        phase[ch == k] = -phase[ch == k]
    sel = ch == 5                                               # a right channel at −D/2: |v − 0| small, |u| = D
    if n_reversed < 6:
        rho5 = 2.2e7 + (-drift_m_s / 2.0) * t[sel] + 3.0 * t[sel] + 1e-3 * t[sel] ** 2
        phase[sel] = rho5 + 1e3 * 5
        code[sel] = rho5 + np.random.default_rng(9).standard_normal(int(sel.sum()))
    bad, minus, plus = reversed_phase_channels(ch, t, phase, code + drift_m_s * t)
    flagged = {int(c) for c in np.unique(ch[bad])}
    assert flagged == set(range(n_reversed)) - {4}, (flagged, rates[right])   # (4: its closest approach, no evidence)
    assert np.all(minus[ch >= n_reversed] < 5.0)                # the right channels: at the common drift


def test_a_channel_too_short_or_near_its_closest_approach_is_kept():
    ch, t, phase, code = _channels()
    short = t < 5.0                                             # 5 s: 4 pairs a second apart, fewer than 5
    assert not reversed_phase_channels(ch[short], t[short], phase[short], code[short])[0].any()
    sel = ch == 4
    reversed_slow = -phase[sel]                                 # reversed at closest approach: no evidence
    assert not reversed_phase_channels(ch[sel], t[sel], reversed_slow, code[sel])[0].any()
    nan = reversed_phase_channels(ch, t, np.full(t.size, np.nan), code)
    assert not nan[0].any() and np.isnan(nan[1]).all()


@pytest.fixture(scope="module")
def edited(tmp_path_factory):
    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    d = tmp_path_factory.mktemp("phase_sign")
    (d / "rover_neg.obs").write_text(edit_rinex3_obs((MOSAIC_DIR / "rover.obs").read_text(), phase_negated=NEGATED))
    return d


def test_the_real_rovers_negated_satellites_are_named_and_no_other(edited):
    _, table = read_rinex_signals(edited / "rover_neg.obs", ("G:L1", "G:L2", "E:E1"))
    kept, said = without_reversed_phases(table, "rover")
    assert sorted(set(table["sat"]) - set(kept["sat"])) == list(NEGATED)
    held = {(g, s) for g, s in zip(table["signal"], table["sat"]) if s in NEGATED}
    assert len(said) == 1 and len(held) >= 3 and all(f"{g} {s} (" in said[0] for g, s in held)
    _, right = read_rinex_signals(MOSAIC_DIR / "rover.obs", ("G:L1", "G:L2", "E:E1"))
    assert without_reversed_phases(right, "rover") == (right, [])
    _, obs = read_rinex_obs(edited / "rover_neg.obs")
    out, said = without_reversed_l1_phases(obs, "rover")
    lost = out["phase_l1_cycles"].isna() & obs["phase_l1_cycles"].notna()
    assert sorted(set(obs.loc[lost, "sat"])) == list(NEGATED) and out["pseudorange_l1_m"].equals(obs["pseudorange_l1_m"])
    assert np.nanmax(np.abs(obs.loc[lost, "phase_l1_cycles"] * GPS_L1_WAVELENGTH_M + obs.loc[lost, "pseudorange_l1_m"])
                     ) < 3e7 and len(said) == 1                # (negated: phase ≈ −code)


def _rtk(d, rover, name):
    out = d / f"{name}.pos"
    r = run_cli("-q", "rtk", "--base", MOSAIC_DIR / "base.obs", "--rover", rover, "--nav", MOSAIC_DIR / "base.nav",
                "--signals", "G:L1", "--mode", "static", "-o", out, "--json")
    assert r.exit_code == 0, r.output
    return json.loads(r.output[r.output.index("{"):]), r.output


def test_rtk_and_baseline_leave_them_out_and_land_where_the_unedited_pair_does(edited):
    neg, said = _rtk(edited, edited / "rover_neg.obs", "neg")
    ref, _ = _rtk(edited, MOSAIC_DIR / "rover.obs", "ref")
    warned = [w for w in neg["warnings"] if "wrote it with the wrong sign" in w]
    assert len(warned) == 1 and "G:L1 G05 (" in warned[0] and "G:L1 G13 (" in warned[0] and len(re.findall(r"[A-Z]:\w+ [A-Z]\d\d \(", warned[0])) == 2
    assert neg["fixed_pct"] > 80 and ref["fixed_pct"] > 90           # (two satellites fewer: fewer epochs fix)
    moved = np.subtract(neg["static_xyz_m"], ref["static_xyz_m"])
    assert np.linalg.norm(moved) < 5e-3                         # two satellites fewer of 9: 2.5 mm
    out = edited / "bl.json"
    r = run_cli("-q", "baseline", "--rinex", f"base={MOSAIC_DIR / 'base.obs'}", "--rinex",
                f"rover={edited / 'rover_neg.obs'}", "--nav", MOSAIC_DIR / "base.nav", "--master", "base", "-o", out)
    assert r.exit_code == 0, r.output
    bl = json.loads(out.read_text())
    assert bl["solution"] == "fixed" and not set(NEGATED) & {s["sat"] for s in bl["satellites"]}
    assert any("G:L1 G05" in w and "their codes are" in w for w in bl["warnings"])


def test_init_on_a_run_leaves_them_out_too(edited):
    """The pipeline's front door (config → ingest → init) screens as ``rtk`` does (pipeline/gnss._stations)."""
    d = edited
    for args in (("config", "--rinex", f"base={MOSAIC_DIR / 'base.obs'}", "--rinex", f"rover={d / 'rover_neg.obs'}",
                  "--nav", MOSAIC_DIR / "base.nav", "--master", "base", "--signals", "G:L1,E:E1", "-o", d / "neg.toml"),
                 ("ingest", "--config", d / "neg.toml", "-o", d / "neg.mcap"),
                 ("init", d / "neg.mcap", "-o", d / "neg_init.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    init = json.loads((d / "neg_init.json").read_text())
    rover = init["rovers"]["rover"]
    said = [w for w in rover["warnings"] if "wrote it with the wrong sign" in w]
    assert len(said) == 1 and "G:L1 G05" in said[0] and "G:L1 G13" in said[0]
    assert rover["solution"] == "fixed" and not set(NEGATED) & {s["sat"] for s in rover["satellites"]}


def test_a_short_window_is_screened_on_the_whole_files_evidence(edited):
    """An 8 s window (7 pairs a second apart, too few alone) is screened as the whole record is: the sign is the
    receiver's, not the window's (a review found the window cut first, and heights 1.7–3.8 km off, exit 0)."""
    out = edited / "w.pos"
    r = run_cli("-q", "rtk", "--base", MOSAIC_DIR / "base.obs", "--rover", edited / "rover_neg.obs", "--nav",
                MOSAIC_DIR / "base.nav", "--signals", "G:L1", "--mode", "kinematic", "--start-time",
                "2024/06/24 08:21:00", "--end-time", "2024/06/24 08:21:03", "-o", out, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.output[r.output.index("{"):])
    assert any("G:L1 G05 (" in w and "wrong sign" in w for w in s["warnings"]) and s["epochs"] == 4
    up = [float(ln.split()[4]) for ln in out.read_text().splitlines() if not ln.startswith("%")]
    assert max(up) - min(up) < 1.0                              # (heights within a metre: no km-off float)


def test_every_phase_screened_out_is_said_in_the_error(edited):
    """When the screen leaves a receiver no phase of the signals asked for, the refusal says which channels it took
    out (it said the file held no phase)."""
    text = (MOSAIC_DIR / "rover.obs").read_text()
    sats = sorted({ln[:3] for ln in text.splitlines() if ln[:1] == "G" and ln[1:3].isdigit()})
    (edited / "rover_all_neg.obs").write_text(edit_rinex3_obs(text, phase_negated=tuple(sats)))
    r = run_cli("-q", "rtk", "--base", MOSAIC_DIR / "base.obs", "--rover", edited / "rover_all_neg.obs", "--nav",
                MOSAIC_DIR / "base.nav", "--signals", "G:L1", "-o", edited / "all.pos")
    assert r.exit_code == 2 and "channels left out before" in r.output and "wrong sign" in r.output, r.output
    assert not (edited / "all.pos").exists()
