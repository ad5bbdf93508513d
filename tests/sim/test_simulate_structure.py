"""Tests for cdgps_cli.sim.structure: files, determinism, the measurement identity, slips, outages,
static and pulse scenarios, option validation."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.config.structure import parse_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.kinematics import gyro_matrix
from cdgps_cli.measurement.phase import channel_indices, phase_model_q
from cdgps_cli.sim.structure import (OutageSpec, SimOptions, SlipSpec, parse_outage, parse_slip, simulate,
                                write_simulation)

RECEIVER_HEADER = "time_s,receiver,master,antenna,transmitter,phase_cycles,lock,snr_dbhz"
SMALL_SIGMA = 0.001


def _read(out: Path):
    rx = pd.read_csv(out / "receiver.csv")
    truth = pd.read_csv(out / "truth.csv")
    assert list(truth.columns[:3]) == ["time_s", "q1_m", "q2_rad"]            # units in the names (issue 32)
    truth = truth.rename(columns=lambda c: re.sub(r"_(m|rad)$", "", c))      # bare names below
    info = json.loads((out / "truth.json").read_text())
    return rx, truth, info


def _truth_bias(info: dict, antenna: str, transmitter: str, t: np.ndarray) -> np.ndarray:
    """Bias (m) of one channel at times t, from truth.json: the initial bias, then each slip or
    reacquisition record's bias from its time on."""
    b0 = [b for b in info["biases"] if b["antenna"] == antenna and b["transmitter"] == transmitter]
    assert len(b0) == 1
    bias = np.full(len(t), b0[0]["bias_m"])
    events = sorted((r for r in info["slips"] if r["antenna"] == antenna and r["transmitter"] == transmitter),
                    key=lambda r: r["time_s"])
    for r in events:
        bias[t >= r["time_s"] - 1e-9] = r["bias_m"]
    return bias


def _residuals(cfg, rx: pd.DataFrame, truth: pd.DataFrame, info: dict) -> pd.Series:
    """λ·phase_cycles − h(q_truth) − bias_truth for every receiver row."""
    q_by_time = truth.set_index("time_s")[list(cfg.coord_names)]
    out = pd.Series(np.nan, index=rx.index)
    for (a, t), grp in rx.groupby(["antenna", "transmitter"]):
        q = q_by_time.loc[grp["time_s"].to_numpy()].to_numpy()
        ant, tx = channel_indices(cfg, [a], [t])
        h = phase_model_q(cfg, q, ant, tx)[:, 0]
        bias = _truth_bias(info, a, t, grp["time_s"].to_numpy())
        out[grp.index] = cfg.wavelength_m * grp["phase_cycles"].to_numpy() - h - bias
    assert not out.isna().any()
    return out


@pytest.fixture(scope="module")
def free_run(testbed_cfg, tmp_path_factory):
    """20 s testbed free run, small phase noise, a slip on a3/PL2 at 3 s and a PL4 outage 4–6 s."""
    opt = SimOptions(duration_s=20.0, seed=3, scenario="free", phase_sigma_m=SMALL_SIGMA,
                     slips=[parse_slip("a3:PL2:3.0:+3")], outages=[parse_outage("PL4:4:2")])
    result = simulate(testbed_cfg, opt)
    out = tmp_path_factory.mktemp("free")
    summary = write_simulation(result, out)
    rx, truth, info = _read(out)
    return {"result": result, "out": out, "summary": summary, "rx": rx, "truth": truth, "info": info}


# --------------------------------------------------------------------------------------------
# files and determinism


def _files(d: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir()) if p.is_file()}


@pytest.mark.parametrize("scenario", ["free", "pulse"])
def test_same_seed_byte_identical(testbed_cfg, tmp_path, scenario):
    def run(d):
        opt = SimOptions(duration_s=8.0, seed=42, scenario=scenario, slips=[parse_slip("a1:PL3:2.0:-2")],
                         outages=[parse_outage("PL5:1:1.5")], random_slips=3)
        write_simulation(simulate(testbed_cfg, opt), d)
        return _files(d)
    a, b = run(tmp_path / "one"), run(tmp_path / "two")
    expected = {"receiver.csv", "gyro.csv", "truth.csv", "truth.json"} | ({"actuators.csv"} if scenario == "pulse" else set())
    assert set(a) == expected
    assert a.keys() == b.keys()
    for name in a:
        assert a[name] == b[name], f"{name} differs between identical runs"
        assert len(a[name]) > 0


def test_different_seed_differs(testbed_cfg, tmp_path):
    for seed, d in ((1, "s1"), (2, "s2")):
        write_simulation(simulate(testbed_cfg, SimOptions(duration_s=5.0, seed=seed)), tmp_path / d)
    a, b = _files(tmp_path / "s1"), _files(tmp_path / "s2")
    for name in ("receiver.csv", "gyro.csv", "truth.csv", "truth.json"):
        assert a[name] != b[name], name


def test_dof2_runs_and_is_deterministic(dof2_cfg, tmp_path):
    opt = SimOptions(duration_s=6.0, seed=5)
    write_simulation(simulate(dof2_cfg, opt), tmp_path / "a")
    write_simulation(simulate(dof2_cfg, opt), tmp_path / "b")
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert a == b
    rx = pd.read_csv(tmp_path / "a" / "receiver.csv")
    assert len(rx) == 51 * 12                          # 3 rovers × 4 signals, 0.12 s period
    gy = (tmp_path / "a" / "gyro.csv").read_text()
    assert gy.splitlines()[0] == "time_s,gyro,rate_rad_s"   # header even with no gyros


def test_receiver_header_and_rows(free_run, testbed_cfg):
    text = (free_run["out"] / "receiver.csv").read_text()
    assert text.splitlines()[0] == RECEIVER_HEADER
    rx = free_run["rx"]
    assert (rx["master"] == "master").all()
    assert set(rx["antenna"]) == set(testbed_cfg.rover_names)
    rx_of = dict(zip(testbed_cfg.antenna_names, testbed_cfg.antenna_receiver))
    assert (rx["receiver"] == rx["antenna"].map(rx_of)).all()
    # 201 epochs × 36 channels, minus 20 epochs × 6 rovers of PL4
    assert len(rx) == 201 * 36 - 20 * 6 == free_run["summary"]["receiver_rows"]


def test_gyro_csv(free_run, testbed_cfg):
    text = (free_run["out"] / "gyro.csv").read_text()
    assert text.splitlines()[0] == "time_s,gyro,rate_rad_s"
    gy = pd.read_csv(free_run["out"] / "gyro.csv")
    assert list(gy.columns) == ["time_s", "gyro", "rate_rad_s"]
    assert len(gy) == 201 * 6
    assert list(gy["gyro"][:6]) == list(testbed_cfg.gyro_names)


def test_gyro_identity(free_run, testbed_cfg):
    """rate − G q̇_truth − initial bias ≈ white noise (gyro_noise_rad_s) plus a tiny drift."""
    res = free_run["result"]
    cfg = testbed_cfg
    qdot = res.x[:, cfg.n_modes:] @ np.asarray(cfg.mode_shapes).T
    rate = qdot @ gyro_matrix(cfg).T
    gy = pd.read_csv(free_run["out"] / "gyro.csv")
    meas = gy["rate_rad_s"].to_numpy().reshape(len(res.time_s), len(cfg.gyro_names))
    bias0 = np.array([g["bias_rad_s"] for g in free_run["info"]["gyros"]])
    err = meas - rate - bias0
    sigma = cfg.simulation["gyro_noise_rad_s"]
    assert np.std(err) == pytest.approx(sigma, rel=0.15)
    assert np.max(np.abs(rate)) > 20 * sigma            # the structure really moves


# --------------------------------------------------------------------------------------------
# the measurement identity, slips, outages


def test_measurement_identity(free_run, testbed_cfg):
    """λ·phase − h(q_truth) − bias_truth is the white phase noise (std = phase_sigma_m), on every
    channel, across the slip and the re-acquisitions (truth.json bias records)."""
    res = _residuals(testbed_cfg, free_run["rx"], free_run["truth"], free_run["info"])
    assert np.std(res) == pytest.approx(SMALL_SIGMA, rel=0.05)
    assert abs(np.mean(res)) < 1e-4
    assert np.max(np.abs(res)) < 6 * SMALL_SIGMA
    per_channel = res.groupby([free_run["rx"]["antenna"], free_run["rx"]["transmitter"]]).mean()
    assert per_channel.abs().max() < 5 * SMALL_SIGMA / np.sqrt(150)


def test_measurement_identity_uses_configured_sigma(testbed_cfg, tmp_path):
    """Without an override the noise is the config's [simulation] phase_sigma_m (0.01 m)."""
    write_simulation(simulate(testbed_cfg, SimOptions(duration_s=10.0, seed=8)), tmp_path)
    rx, truth, info = _read(tmp_path)
    res = _residuals(testbed_cfg, rx, truth, info)
    assert np.std(res) == pytest.approx(testbed_cfg.simulation["phase_sigma_m"], rel=0.05)


def test_phase_at_lock_in_unit_interval(free_run):
    """At acquisition and re-acquisition (lock == 0) the phase is in [0, 1) cycle.  A cycle slip
    also resets lock to 0 but, by design, only adds its integer (see test_slip), so the slip row
    is excluded here."""
    rx = free_run["rx"]
    at_lock = rx[rx["lock"] == 0]
    # epoch 0 on every channel, the slip, and the PL4 re-acquisition on 6 rovers
    assert len(at_lock) == 36 + 1 + 6
    is_slip = (at_lock["antenna"] == "a3") & (at_lock["transmitter"] == "PL2") & np.isclose(at_lock["time_s"], 3.0)
    assert is_slip.sum() == 1
    acq = at_lock[~is_slip]
    assert ((acq["phase_cycles"] >= 0.0) & (acq["phase_cycles"] < 1.0)).all()
    assert (rx["phase_cycles"].abs() > 1.0).any()          # phase leaves [0, 1) while locked


def test_slip(free_run):
    rx, info = free_run["rx"], free_run["info"]
    slips = [r for r in info["slips"] if r["kind"] == "slip"]
    assert len(slips) == 1
    s = slips[0]
    assert (s["time_s"], s["antenna"], s["transmitter"]) == (3.0, "a3", "PL2")
    assert s["integer_cycles_after"] - s["integer_cycles_before"] == 3
    ch = rx[(rx["antenna"] == "a3") & (rx["transmitter"] == "PL2")].set_index("time_s")
    assert ch.loc[3.0, "lock"] == 0 and ch.loc[3.1, "lock"] == 1 and ch.loc[2.9, "lock"] == 29
    # the jump, corrected for the geometric change over the step, is 3 cycles (noise ≪ 0.1 cycle)
    cfg = free_run["result"].cfg
    truth = free_run["truth"].set_index("time_s")
    ant, tx = channel_indices(cfg, ["a3"], ["PL2"])
    h = phase_model_q(cfg, truth.loc[[2.9, 3.0, 3.1], list(cfg.coord_names)].to_numpy(), ant, tx)[:, 0]
    lam = cfg.wavelength_m
    jump = (ch.loc[3.0, "phase_cycles"] - ch.loc[2.9, "phase_cycles"]) - (h[1] - h[0]) / lam
    assert jump == pytest.approx(3.0, abs=0.05)
    after = (ch.loc[3.1, "phase_cycles"] - ch.loc[3.0, "phase_cycles"]) - (h[2] - h[1]) / lam
    assert after == pytest.approx(0.0, abs=0.05)
    # other channels keep their lock
    other = rx[(rx["antenna"] == "a3") & (rx["transmitter"] == "PL1")].set_index("time_s")
    assert other.loc[3.0, "lock"] == 30


def test_outage(free_run):
    rx, info = free_run["rx"], free_run["info"]
    pl4 = rx[rx["transmitter"] == "PL4"]
    assert not ((pl4["time_s"] >= 4.0 - 1e-9) & (pl4["time_s"] < 6.0 - 1e-9)).any()
    assert set(pl4[np.isclose(pl4["time_s"], 3.9)]["antenna"]) == set(info_rovers(info))
    at6 = pl4[np.isclose(pl4["time_s"], 6.0)]
    assert len(at6) == 6 and (at6["lock"] == 0).all()
    assert ((at6["phase_cycles"] >= 0) & (at6["phase_cycles"] < 1)).all()
    assert (pl4[np.isclose(pl4["time_s"], 3.9)]["lock"] == 39).all()
    assert (pl4[np.isclose(pl4["time_s"], 6.1)]["lock"] == 1).all()
    reacq = [r for r in info["slips"] if r["kind"] == "reacquisition"]
    assert len(reacq) == 6 and all(r["transmitter"] == "PL4" and r["time_s"] == 6.0 for r in reacq)
    # other transmitters are unaffected
    assert (rx[(rx["transmitter"] == "PL1") & np.isclose(rx["time_s"], 5.0)]["lock"] == 50).all()


def info_rovers(info):
    return sorted({b["antenna"] for b in info["biases"]})


# --------------------------------------------------------------------------------------------
# scenarios


def test_static_scenario(testbed_cfg, tmp_path):
    sim = testbed_cfg.simulation
    duration = sim["static_rest_after_s"] + sim["static_settle_s"] + 10.0
    res = simulate(testbed_cfg, SimOptions(duration_s=duration, seed=4, scenario="static"))
    write_simulation(res, tmp_path)
    _, truth, info = _read(tmp_path)
    final = truth.iloc[-1]
    assert final["q10"] == pytest.approx(np.radians(-1.4), abs=1e-12)
    for name in testbed_cfg.coord_names[:9]:
        assert final[name] == pytest.approx(0.0, abs=1e-12)
    kinds = [s["kind"] for s in info["segments"]]
    assert kinds == ["motion", "settling", "rest"]
    rest = info["segments"][-1]
    assert rest["start_s"] == pytest.approx(80.0) and rest["end_s"] == pytest.approx(duration)
    assert rest["q"]["q10"] == pytest.approx(np.radians(-1.4))
    # the whole rest segment is at the target, and the structure moved before it
    at_rest = truth[truth["time_s"] >= rest["start_s"] - 1e-9]
    assert np.allclose(at_rest["q10"], np.radians(-1.4), atol=1e-12)
    assert np.allclose(at_rest[list(testbed_cfg.coord_names[:9])], 0.0, atol=1e-12)
    assert truth[truth["time_s"] < 60.0]["q5"].abs().max() > 0.01
    # modal truth is consistent with q
    np.testing.assert_allclose(res.x[:, :9] @ np.asarray(testbed_cfg.mode_shapes).T, res.q, atol=1e-10)


def test_pulse_scenario(testbed_cfg, tmp_path):
    res = simulate(testbed_cfg, SimOptions(duration_s=15.0, seed=6, scenario="pulse"))
    write_simulation(res, tmp_path)
    act_text = (tmp_path / "actuators.csv").read_text()
    assert act_text.splitlines()[0] == "time_s,actuator,force_n"
    act = pd.read_csv(tmp_path / "actuators.csv")
    pulse = testbed_cfg.simulation["pulse_thrusters"]
    on = act[act["force_n"] > 0]
    off = act[act["force_n"] == 0]
    assert sorted(on["actuator"]) == sorted(pulse) and sorted(off["actuator"]) == sorted(pulse)
    assert (on["time_s"] == 5.0).all() and (off["time_s"] == 6.0).all()
    np.testing.assert_allclose(on["force_n"], 1.4)
    assert len(act) == 8
    _, truth, info = _read(tmp_path)
    assert [s["kind"] for s in info["segments"]] == ["rest", "pulse", "free"]
    q = truth.set_index("time_s")
    # q5 (centre twist) rises and q8 (end twist) falls right after the pulse starts
    assert q.loc[5.5, "q5"] - q.loc[5.0, "q5"] > 0.03
    assert q.loc[5.5, "q8"] - q.loc[5.0, "q8"] < -0.03
    assert q.loc[6.0, "q5"] - q.loc[5.0, "q5"] > 0.15
    assert q.loc[6.0, "q8"] - q.loc[5.0, "q8"] < -0.15
    # q2 only follows through the beam: much less motion during the pulse
    assert abs(q.loc[6.0, "q2"] - q.loc[5.0, "q2"]) < 0.3 * (q.loc[6.0, "q5"] - q.loc[5.0, "q5"])


def test_free_scenario_has_no_actuators_file(testbed_cfg, tmp_path):
    write_simulation(simulate(testbed_cfg, SimOptions(duration_s=6.0, seed=1, scenario="pulse")), tmp_path)
    assert (tmp_path / "actuators.csv").exists()
    write_simulation(simulate(testbed_cfg, SimOptions(duration_s=6.0, seed=1, scenario="free")), tmp_path)
    assert not (tmp_path / "actuators.csv").exists()      # stale file removed


# --------------------------------------------------------------------------------------------
# option validation


def test_parse_slip_and_outage():
    s = parse_slip("a3:PL2:3.0:+3")
    assert (s.antenna, s.transmitter, s.time_s, s.cycles) == ("a3", "PL2", 3.0, 3)
    assert parse_slip(" a1:PL1:12.5:-2 ").cycles == -2
    o = parse_outage("PL4:4:2")
    assert (o.transmitter, o.start_s, o.duration_s) == ("PL4", 4.0, 2.0)


@pytest.mark.parametrize("spec", ["a3:PL2:3.0:0", "a3:PL2:3.0", "a3:PL2:x:+3", "a3:PL2:3.0:1.5", ""])
def test_bad_slip_spec(spec):
    with pytest.raises(CdgpsError, match="ANTENNA:TRANSMITTER:TIME_S:CYCLES"):
        parse_slip(spec)


@pytest.mark.parametrize("spec", ["PL4:4:0", "PL4:4", "PL4:4:-1", "PL4:a:2"])
def test_bad_outage_spec(spec):
    with pytest.raises(CdgpsError, match="TRANSMITTER:START_S:DURATION_S"):
        parse_outage(spec)


@pytest.mark.parametrize("kwargs, fragment", [
    ({"scenario": "wobble"}, "wobble"),
    ({"duration_s": 0.0}, "duration"),
    ({"slips": [SlipSpec("a3", "PL9", 1.0, 2)]}, "PL9"),
    ({"slips": [parse_slip("a9:PL1:1.0:+1")]}, "a9"),
    ({"slips": [SlipSpec("master", "PL1", 1.0, 2)]}, "master"),
    ({"outages": [OutageSpec("PL7", 1.0, 2.0)]}, "PL7"),
    ({"phase_sigma_m": -0.01}, "--noise-m -0.01"),
    ({"random_slips": -1}, "--random-slips -1"),
])
def test_invalid_options(testbed_cfg, kwargs, fragment):
    opt = SimOptions(**{"duration_s": 2.0, **kwargs})
    with pytest.raises(CdgpsError, match=fragment):
        simulate(testbed_cfg, opt)


def test_pulse_needs_pulse_thrusters(dof2_cfg):
    with pytest.raises(CdgpsError, match="pulse_thrusters"):
        simulate(dof2_cfg, SimOptions(duration_s=2.0, scenario="pulse"))


# --------------------------------------------------------------------------------------------
# regression tests for defects found in review

EDGE_CONFIG = """
[model]
name = "edge"
sample_period_s = 0.5
measurement_sigma_m = 0.01
wavelength_m = 1.0

[[coordinates]]
name = "xi"
kind = "modal"

[[antennas]]
name = "ref"
position_m = [0.0, 0.0, 0.0]
master = true

[[antennas]]
name = "tip"
position_m = [1.0, 0.0, 0.0]
line_bias_m = 1.9999999

[[transmitters]]
name = "S"
direction = [-1.0, 0.0, 0.0]

[[modes]]
name = "m"
frequency_hz = 1.0
time_constant_s = 10.0
shape = [1.0]

[process_noise]
space = "modal"
sigma = [0.1]
"""


def test_phase_at_lock_below_one_after_rounding():
    # h = 1 m, line bias 1.9999999 m, λ = 1 m, no noise: y/λ = 2.9999999 → phase 0.9999999 → "1.0"
    cfg = parse_config(EDGE_CONFIG, "edge.toml")
    res = simulate(cfg, SimOptions(duration_s=1.0, seed=0, phase_sigma_m=0.0))
    at_lock = res.receiver[res.receiver["lock"] == 0]
    assert len(at_lock) == 1
    assert (at_lock["phase_cycles"] < 1.0).all(), at_lock


def test_static_rest_segment_consistent_with_truth_when_short(testbed_cfg):
    res = simulate(testbed_cfg, SimOptions(duration_s=30.0, seed=4, scenario="static"))
    for seg in res.truth["segments"]:
        if seg["kind"] != "rest":
            continue
        sel = (res.time_s >= seg["start_s"] - 1e-9) & (res.time_s <= seg["end_s"] + 1e-9)
        target = np.array([seg["q"][n] for n in testbed_cfg.coord_names])
        assert np.allclose(res.q[sel], target, atol=1e-9)
