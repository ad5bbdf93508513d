"""The chain structure simulation → IF samples → tracking loops → differential phase → receiver log →
ingest → init, against the simulator's truth; and the two commands' bad-input behaviour."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.coordinate_columns import coordinate_columns
from cdgps_cli.io.logs import read_receiver_log
from cdgps_cli.pipeline.if_chain import track_structure
from cdgps_cli.sim.if_samples import IfOptions, StructureIf

ROOT = Path(__file__).resolve().parents[2]
TESTBED = str(ROOT / "configs" / "testbed-1998-lumped.toml")
FS = 2.2e6
SECONDS = 3.0


def _cli(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    return r


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """3 s of the free-vibrating testbed: 7 antennas × 6 pseudolites at 2.2 MHz, tracked."""
    d = tmp_path_factory.mktemp("ifchain")
    assert _cli("-q", "simulate", TESTBED, "--duration", 3.5, "--seed", 1, "-o", d / "sim").exit_code == 0
    r = _cli("-q", "simulate-if", TESTBED, d / "sim", "--duration", SECONDS, "--fs", FS, "--seed", 2,
             "--oscillator", "1e-22,1e-22,1e-24", "--clock-offset-ppm", 0.3, "-o", d / "if", "--json")
    assert r.exit_code == 0, r.output
    r = _cli("-q", "track-structure", d / "if" / "if.json", "--config", TESTBED, "-o", d / "receiver.csv", "--json")
    assert r.exit_code == 0, r.output
    return d, json.loads(r.output)


def _truth_integers(d: Path, cfg, df: pd.DataFrame) -> tuple[dict, np.ndarray]:
    """Per channel the integer n with λ·phase = (ρ_a + ℓ_a) − (ρ_M + ℓ_M) + λ·n, and every residual (m)."""
    man = json.loads((d / "if" / "if.json").read_text())
    tt = np.array(man["truth"]["time_s"])
    tr, master = man["truth"]["antennas"], man["master"]
    lam = cfg.wavelength_m
    ints, res = {}, []
    for (a, t), g in df.groupby(["antenna", "transmitter"]):
        k = np.searchsorted(tt, g["time_s"].to_numpy() - 1e-9)
        sd = np.array(tr[a][t]["range_m"])[k] - np.array(tr[master][t]["range_m"])[k]
        e = g["phase_cycles"].to_numpy() * lam - sd
        n = np.round(e / lam)
        assert np.unique(n).size == 1, (a, t, np.unique(n))             # no slip in 3 s at 45 dB-Hz
        ints[(a, t)] = int(n[0])
        res.append(e - n * lam)
    return ints, np.concatenate(res)


def test_receiver_log_is_the_geometric_differential_phase(chain, testbed_cfg):
    d, summary = chain
    df = read_receiver_log(d / "receiver.csv", testbed_cfg)                # the format ingest reads
    assert summary["rows"] == len(df)
    assert set(zip(df["antenna"], df["transmitter"])) == set(testbed_cfg.channels)
    assert df["time_s"].min() <= 0.5 and df["time_s"].max() >= SECONDS - 0.15
    assert all(c["segments"] == 1 for c in summary["channels"])
    _, res = _truth_integers(d, testbed_cfg, df)
    # two 45 dB-Hz channels of 15 Hz PLLs: about 1 mm (1σ) of differential phase error
    assert np.std(res) < 2.5e-3 and np.abs(res).max() < 8e-3
    assert np.abs(np.mean(res)) < 0.5e-3
    assert df["snr_dbhz"].median() == pytest.approx(45.0, abs=1.5)


def test_ingest_and_init_fix_the_true_integers(chain, testbed_cfg):
    d, _ = chain
    r = _cli("-q", "ingest", d / "receiver.csv", d / "sim" / "gyro.csv", "--config", TESTBED, "-o", d / "run.mcap")
    assert r.exit_code == 0, r.output
    # the loops' differential phase is good to about 1 mm: the config's 2 cm would call 3 cm of motion too little
    r = _cli("-q", "init", d / "run.mcap", "--sigma-m", 0.002, "-o", d / "init.json")
    assert r.exit_code == 0, r.output
    init = json.loads((d / "init.json").read_text())
    ints, _ = _truth_integers(d, testbed_cfg, read_receiver_log(d / "receiver.csv", testbed_cfg))
    assert init["n_fixed"] == len(ints) == 36
    for b in init["biases"]:
        assert b["fixed"] and b["integer_cycles"] == ints[(b["antenna"], b["transmitter"])]


def test_manifest_describes_the_files(chain):
    d, _ = chain
    man = json.loads((d / "if" / "if.json").read_text())
    assert man["sample_format"] == "int8-iq" and man["fs_hz"] == FS and man["samples"] == int(FS * SECONDS)
    assert [a["name"] for a in man["antennas"]] == ["master", "a1", "a2", "a3", "a4", "a5", "a6"]
    assert all((d / "if" / a["file"]).stat().st_size == 2 * man["samples"] for a in man["antennas"])
    assert [t["prn"] for t in man["transmitters"]] == [1, 2, 3, 4, 5, 6]
    assert len(man["truth"]["time_s"]) == len(man["truth"]["clock_error_s"]) == 31   # 0 … 3 s


def test_same_seed_same_files(chain, tmp_path):
    d, _ = chain
    shas = []
    for k in range(2):
        r = _cli("-q", "simulate-if", TESTBED, d / "sim", "--duration", 0.02, "--fs", FS, "--seed", 5,
                 "-o", tmp_path / f"o{k}")
        assert r.exit_code == 0, r.output
        shas.append([a["sha256"] for a in json.loads((tmp_path / f"o{k}" / "if.json").read_text())["antennas"]])
    assert shas[0] == shas[1] and len(set(shas[0])) == 7


@pytest.mark.parametrize("args,words", [
    (["--duration", 10], "outside the simulation"),
    (["--fs", 4.0001e6], "whole number of samples per millisecond"),
    (["--fs", 1e6], "sample rate"),
    (["--cn0", "PLX:40"], "unknown transmitter"),
    (["--cn0", "PL1:fast"], "--cn0"),
    (["--cn0", 200], "C/N0"),
    (["--prn", "PL1:40"], "PRN"),
    (["--prn", "PL1:2"], "more than one transmitter"),
    (["--oscillator", "1,2"], "--oscillator"),
    (["--clock-offset-ppm", 500], "100 ppm"),
    (["--bits", 0], "bits"),
])
def test_simulate_if_bad_input_exit_2_nothing_written(chain, tmp_path, args, words):
    d, _ = chain
    out = tmp_path / "out"
    r = _cli("simulate-if", TESTBED, d / "sim", "--duration", 0.02, *args, "-o", out)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert words in r.output
    assert not out.exists() or not any(out.iterdir())


def test_simulate_if_refuses_a_folder_of_another_config(chain, tmp_path):
    d, _ = chain
    r = _cli("simulate-if", ROOT / "configs" / "teague-1995-2dof.toml", d / "sim", "-o", tmp_path / "o")
    assert r.exit_code == 2 and "another config" in r.output


def test_track_structure_bad_input(chain, tmp_path, testbed_cfg, dof2_cfg):
    """(on 20 ms of IF samples of the chain's simulation, as test_same_seed_same_files writes them: every
    check below reads the manifest, the files' sha256 or their sizes, none the length of the record)"""
    d, _ = chain
    bad = tmp_path / "if"
    r = _cli("-q", "simulate-if", TESTBED, d / "sim", "--duration", 0.02, "--fs", FS, "--seed", 2, "-o", bad)
    assert r.exit_code == 0, r.output
    out = tmp_path / "rx.csv"
    with pytest.raises(CdgpsError, match="another config"):
        track_structure(bad / "if.json", dof2_cfg, out)
    before = (bad / "a1.bin").read_bytes()
    with pytest.raises(CdgpsError, match="overwrite"):
        track_structure(bad / "if.json", testbed_cfg, bad / "a1.bin")
    assert (bad / "a1.bin").read_bytes() == before
    raw = bytearray((bad / "a3.bin").read_bytes())
    raw[1000] ^= 0x40
    (bad / "a3.bin").write_bytes(bytes(raw))
    with pytest.raises(CdgpsError, match="sha256 differs"):
        track_structure(bad / "if.json", testbed_cfg, out)
    (bad / "a3.bin").write_bytes(bytes(raw[:-2]))
    r = _cli("track-structure", bad / "if.json", "--config", TESTBED, "-o", out)
    assert r.exit_code == 2 and "a3.bin" in r.output and "bytes" in r.output and "Traceback" not in r.output
    (bad / "if.json").write_text("{}")
    r = _cli("track-structure", bad / "if.json", "--config", TESTBED, "-o", out)
    assert r.exit_code == 2 and "not an IF manifest" in r.output
    assert not out.exists()


def test_epoch_lock_is_unbiased_by_noise():
    """cos 2φ of a locked signal at 0 dB per-ms SNR (30 dB-Hz): about 1, where the channel's
    20 ms indicator reads about 0.5; a phase rotating at 10 Hz reads about 0 (slower rotations
    are not averaged out within one 100 ms epoch: the test sees frequency errors above about 5 Hz)."""
    from cdgps_cli.pipeline.if_chain import epoch_lock

    g = np.random.default_rng(0)
    n = 10_000
    noise = g.normal(0, 1, n) + 1j * g.normal(0, 1, n)
    amp = np.sqrt(2.0)                                  # A² / (2σ²) = 1
    bits = np.repeat(g.choice([-1.0, 1.0], n // 20), 20)
    lo, hi = np.arange(0, n, 100), np.arange(100, n + 1, 100)
    locked = amp * bits * np.exp(0.2j) + noise          # 11° static error: cos 2φ = 0.92
    rot = amp * bits * np.exp(2j * np.pi * 10 * np.arange(n) * 1e-3) + noise
    lk = epoch_lock({"i_prompt": locked.real, "q_prompt": locked.imag}, lo, hi)
    rt = epoch_lock({"i_prompt": rot.real, "q_prompt": rot.imag}, lo, hi)
    assert abs(np.mean(lk) - np.cos(0.4)) < 0.05 and np.mean(lk > 0.5) > 0.9      # 100 ms at 30 dB-Hz: noisy
    assert abs(np.mean(rt)) < 0.1 and np.mean(rt > 0.5) < 0.05
    old = np.mean((locked.real**2 - locked.imag**2)[:2000].reshape(-1, 20).sum(1)
                  / (np.abs(locked[:2000]) ** 2).reshape(-1, 20).sum(1))
    assert old < 0.6                                    # the 20 ms (I² − Q²)/(I² + Q²) would call it unlocked


def test_far_field_sources_give_the_planar_differential_phase(tmp_path, dof2_cfg):
    """The 1995 model (far-field signals, h = −sᵀ(p_a − p_M)): 0.6 s through the chain, the log's
    phase is the planar differential range (+ line biases) plus one integer per channel."""
    cfg_path = ROOT / "configs" / "teague-1995-2dof.toml"
    assert _cli("-q", "simulate", cfg_path, "--duration", 1, "-o", tmp_path / "sim").exit_code == 0
    r = _cli("-q", "simulate-if", cfg_path, tmp_path / "sim", "--duration", 0.6, "--fs", FS, "-o", tmp_path / "if")
    assert r.exit_code == 0, r.output
    s = track_structure(tmp_path / "if" / "if.json", dof2_cfg, tmp_path / "rx.csv")
    df = read_receiver_log(tmp_path / "rx.csv", dof2_cfg)
    assert s["rows"] == len(df) == 2 * len(dof2_cfg.channels)             # epochs 0.36 and 0.48 s
    ints, res = _truth_integers(tmp_path, dof2_cfg, df)
    assert np.abs(res).max() < 6e-3


def test_gyro_aid_is_the_line_of_sight_doppler_of_what_the_gyros_see(chain, testbed_cfg):
    """The simulator's true line-of-sight Doppler (its ranges, full geometry) = −u·J(q) q̇/λ with J(q), u at
    the true pose (the kinematics checked against the simulator); the gyro aid is that with q̇ replaced
    by M ω (M = G⁺ or U(GU)⁺) and J, u at the pose q̂ integrated from the start pose by M ω (checked here
    with an independent integration); the simulated gyros' errors (bias, drift, noise of the config) move
    it little."""
    from scipy.integrate import cumulative_trapezoid

    from cdgps_cli.model.kinematics import antenna_positions, gyro_matrix
    from cdgps_cli.pipeline.if_chain import (ChainOptions, gyro_aid_hz, gyro_coordinate_map, gyro_rates,
                                             read_manifest, truth_aid_hz)

    d, _ = chain
    cfg = testbed_cfg
    man = read_manifest(d / "if" / "if.json")
    tr = pd.read_csv(d / "sim" / "truth.csv")
    t_q = tr["time_s"].to_numpy()
    q = tr[coordinate_columns(cfg)].to_numpy()
    qdot = np.gradient(q, t_q, axis=0, edge_order=2)
    G = gyro_matrix(cfg)
    ideal = (t_q, qdot @ G.T)
    measured = gyro_rates(cfg, d / "sim" / "gyro.csv")
    k = np.flatnonzero((t_q - man["start_s"] > 0.3) & (t_q - man["start_s"] < 2.5))
    t = t_q[k] - man["start_s"]
    lam = 299792458.0 / 1575.42e6
    p, J = antenna_positions(cfg, q[k], jacobian=True)
    i0 = int(np.argmin(abs(t_q - man["start_s"])))
    assert abs(t_q[i0] - man["start_s"]) < 1e-9
    for a, tx in (("a3", "PL2"), ("a6", "PL5")):
        ai = list(cfg.antenna_names).index(a)
        pj = np.array(next(x for x in man["transmitters"] if x["name"] == tx)["position_m"])
        u = (p[:, ai] - pj) / np.linalg.norm(p[:, ai] - pj, axis=1)[:, None]
        truth = truth_aid_hz(man, a, tx, t)
        kin = -np.einsum("ni,nij,nj->n", u, J[:, ai], qdot[k]) / lam
        assert np.abs(kin - truth).max() < 0.03 * np.abs(truth).max()
        for modes in (False, True):
            M = gyro_coordinate_map(cfg, modes)
            qd_hat = qdot @ G.T @ M.T
            q_hat = q[i0] + cumulative_trapezoid(qd_hat, t_q, axis=0, initial=0.0) \
                - cumulative_trapezoid(qd_hat, t_q, axis=0, initial=0.0)[i0]
            ph, Jh = antenna_positions(cfg, q_hat[k], jacobian=True)
            uh = (ph[:, ai] - pj) / np.linalg.norm(ph[:, ai] - pj, axis=1)[:, None]
            got = gyro_aid_hz(cfg, man, ideal, a, tx, t, modes, q[i0])
            assert got == pytest.approx(-np.einsum("ni,nij,nj->n", uh, Jh[:, ai], qd_hat[k]) / lam, abs=1e-6)
            assert np.sqrt(np.mean((gyro_aid_hz(cfg, man, measured, a, tx, t, modes, q[i0]) - got) ** 2)) < 0.02


def test_gyro_aid_needs_the_current_pose_not_the_rest_pose(chain, testbed_cfg):
    """The testbed's rigid-body angle q10 sits at tenths of a radian: the aid through the mode shapes with
    the geometry carried from the true start pose follows the line-of-sight Doppler of the centre-section
    antennas (which the gyros observe) to a few per cent; from the rest pose its error is several times
    larger (the defect of the first gyro aid: J and the line of sight at q = 0)."""
    from cdgps_cli.pipeline.if_chain import gyro_aid_hz, gyro_rates, read_manifest, start_pose, truth_aid_hz

    d, _ = chain
    cfg = testbed_cfg
    man = read_manifest(d / "if" / "if.json")
    measured = gyro_rates(cfg, d / "sim" / "gyro.csv")
    q0 = start_pose(cfg, d / "sim" / "truth.csv", man["start_s"])
    assert abs(q0[cfg.coord_names.index("q10")]) > 0.1
    t = np.arange(300, 2500) * 1e-3
    for a, tx in (("a3", "PL4"), ("a4", "PL6")):
        truth = truth_aid_hz(man, a, tx, t)
        scale = np.sqrt(np.mean(truth ** 2))
        posed = np.sqrt(np.mean((gyro_aid_hz(cfg, man, measured, a, tx, t, True, q0) - truth) ** 2))
        rest = np.sqrt(np.mean((gyro_aid_hz(cfg, man, measured, a, tx, t, True) - truth) ** 2))
        assert posed < 0.04 * scale and rest > 3 * posed, (a, tx, posed, rest, scale)


def test_start_pose_names_bad_files(tmp_path, testbed_cfg):
    from cdgps_cli.pipeline.if_chain import ChainOptions, start_pose

    f = tmp_path / "pose.csv"
    f.write_text("time_s,q1\n0,0\n")
    with pytest.raises(CdgpsError, match="missing column"):
        start_pose(testbed_cfg, f, 0.0)
    f.write_text("time_s," + ",".join(testbed_cfg.coord_names) + "\n" + "1.0" + ",0" * testbed_cfg.n_q + "\n")
    with pytest.raises(CdgpsError, match="outside the pose file"):
        start_pose(testbed_cfg, f, 0.0)
    with pytest.raises(CdgpsError, match="aids 'gyro' and 'model' only"):
        ChainOptions(pose_csv=str(f)).check()
    with pytest.raises(CdgpsError, match="gyro log"):
        ChainOptions(aid="gyro").check()


def test_gyro_observability_is_named(testbed_cfg):
    """The testbed's six gyros determine 5 of its 10 coordinate rates (and 5 of its 9 modal rates): the
    kinematics-only aid guesses the rest, which made it worse than no aid on some channels."""
    from cdgps_cli.pipeline.if_chain import gyro_observability_note

    assert "determine 5 of the 10 coordinate rates" in gyro_observability_note(testbed_cfg, False)
    assert "--aid model" in gyro_observability_note(testbed_cfg, False)
    assert "determine 5 of the 9 modal rates" in gyro_observability_note(testbed_cfg, True)


def test_a_shared_clock_loop_in_the_chain_keeps_the_differential_phase(chain, tmp_path, testbed_cfg):
    """Each antenna's six channels with 3 Hz loops (true line-of-sight aid) under one 15 Hz clock loop:
    the clock estimate is common to an antenna's channels, not to the antennas, yet the differential
    phase stays the geometric one (no slip; 5 mm RMS with the pull-in transients, median 2 mm) on nearly
    every epoch."""
    from cdgps_cli.pipeline.if_chain import ChainOptions
    from cdgps_cli.tracking.channel import TrackOptions

    d, _ = chain
    opt = ChainOptions(track=TrackOptions(pll_bn_hz=3.0), aid="truth", acquisition="truth", clock_bn_hz=15.0)
    s = track_structure(d / "if" / "if.json", testbed_cfg, tmp_path / "rx.csv", opt)
    df = read_receiver_log(tmp_path / "rx.csv", testbed_cfg)
    _, res = _truth_integers(d, testbed_cfg, df)
    assert s["options"]["clock_bn_hz"] == 15.0 and len(df) > 0.8 * s["epochs"] * len(testbed_cfg.channels)
    assert np.sqrt(np.mean(res ** 2)) < 5e-3 and np.median(np.abs(res)) < 2e-3    # the first epochs settle
    with pytest.raises(CdgpsError, match="clock loop bandwidth"):
        ChainOptions(clock_bn_hz=0.0).check()
