"""A structural engineer's own FE model (issue 11, item 13): gyros on modal coordinates, refusal of
gyros that read nothing, damping_ratio, full process-noise covariance, per-channel σ, point
displacements with σ (export --points), unit labels, and the whole chain on the bundled
FE-model tower (configs/tower-120m-fe.toml)."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import channel_sigma_m, load_config, parse_config, scalar_sigma_m
from cdgps_cli.model.dynamics import continuous_model, discrete_model
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.kinematics import gyro_matrix, point_positions
from cdgps_cli.model.points import point_displacements, select_points
from cdgps_cli.analysis.spectra import SpectraOptions, compute_spectra

TOWER = Path(__file__).resolve().parents[2] / "configs" / "tower-120m-fe.toml"


@pytest.fixture(scope="module")
def tower():
    return load_config(TOWER)


# a minimal FE-style model: two modal coordinates, far-field signals, no sections
BASE = """
[model]
name = "fe-mini"
sample_period_s = 0.1
measurement_sigma_m = 0.005

[[coordinates]]
name = "x1"
kind = "modal"

[[coordinates]]
name = "x2"
kind = "modal"

[[antennas]]
name = "ref"
position_m = [0.0, 0.0, 0.0]
master = true

[[antennas]]
name = "tip"
position_m = [0.0, 0.0, 10.0]
displacement_m = { x1 = [1.0, 0.0, 0.0], x2 = [0.0, 1.0, 0.0] }

[[transmitters]]
name = "S1"
direction = [0.0, 0.6, 0.8]

[[transmitters]]
name = "S2"
direction = [0.6, 0.0, 0.8]

[[modes]]
name = "m1"
frequency_hz = 0.5
MODE1_DAMPING
shape = [1.0, 0.0]

[[modes]]
name = "m2"
frequency_hz = 2.0
time_constant_s = 8.0
shape = [0.0, 1.0]

[process_noise]
space = "modal"
PROCESS_NOISE
"""


def mini(extra: str = "", damping: str = "damping_ratio = 0.02", noise: str = "sigma = [0.1, 0.2]") -> str:
    return BASE.replace("MODE1_DAMPING", damping).replace("PROCESS_NOISE", noise) + extra


def problems(text: str) -> str:
    with pytest.raises(CdgpsError) as e:
        parse_config(text, "fe-mini.toml")
    return str(e.value)


# ---------------------------------------------------------------------------------------- config


def test_generated_tower_config_in_sync(repo_root):
    r = subprocess.run([sys.executable, "scripts/make_tower_config.py", "--check"], cwd=repo_root,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


def test_tower_config_is_an_fe_model(tower):
    """Modal coordinates, no sections, FE shapes at the antennas, damping_ratio, full W, gyros on
    modal coordinates: the config exercises every FE-model key."""
    assert set(tower.coord_kinds) == {"modal"} and tower.sections == ()
    np.testing.assert_allclose(tower.mode_shapes, np.eye(4))
    # the top antenna moves 1 m per unit of each mode (shapes normalized at the top)
    top = tower.antenna_names.index("a120")
    np.testing.assert_allclose(tower.antenna_displacement[top][:2], [[1, 0, 1, 0], [0, 1, 0, 1]])
    np.testing.assert_allclose(tower.mode_damping_ratio, [0.01, 0.01, 0.015, 0.015])
    W = tower.process_noise_W
    assert W[0, 2] < 0 and W[0, 1] == 0                     # correlated within x, independent x/y
    assert np.all(np.linalg.eigvalsh(W) > 0)
    assert len(tower.gyro_names) == 3 and np.all(tower.gyro_section == -1)
    assert tower.point_names == ("z30", "z100", "top")
    assert tower.coord_unit_label("qx-1") == "m at the top (x)"


def test_gyro_rotation_rad_hand_computed():
    """Gyro with axis (0.6, 0.8, 0) (normalized from [3, 4, 0]) and rotation vectors per coordinate:
    G = [a·r1, a·r2] = [0.6·0.1 + 0.8·0.2, 0.8·(−0.5)] = [0.22, −0.4]."""
    cfg = parse_config(mini('[[gyros]]\nname = "g"\naxis = [3.0, 4.0, 0.0]\n'
                            'rotation_rad = { x1 = [0.1, 0.2, 0.7], x2 = [0.0, -0.5, 0.0] }\n'))
    np.testing.assert_allclose(gyro_matrix(cfg), [[0.22, -0.4]])


def test_tower_gyro_matrix_from_fe_rotations(tower):
    """g120x reads θx = −du_y/dz of the y-bending modes, g120y θy = du_x/dz of the x modes; the
    values are the FE slopes at the top: the slope of the beam at 120 m, checked against the finite
    difference of the FE displacements between the 100 m point and the top."""
    G = gyro_matrix(tower)
    gx, gy = tower.gyro_names.index("g120x"), tower.gyro_names.index("g120y")
    assert G[gx, 0] == 0 and G[gx, 2] == 0 and G[gy, 1] == 0 and G[gy, 3] == 0
    assert G[gx, 1] < 0 and G[gy, 0] > 0
    p100 = tower.point_displacement[tower.point_names.index("z100")]
    slope_fd = (1.0 - p100[0, 0]) / 20.0                   # mode bend-x-1: u(120) = 1
    assert G[gy, 0] == pytest.approx(slope_fd, rel=0.25)    # secant vs tangent slope of a cantilever
    assert G[gx, 1] == pytest.approx(-G[gy, 0], rel=1e-12)  # same shape in y, θx = −du_y/dz


def test_gyro_that_reads_nothing_is_refused():
    sec = ('[[sections]]\nname = "s"\npivot_m = [0.0, 0.0, 0.0]\n'
           '[[gyros]]\nname = "g"\nsection = "s"\naxis = "x"\n')
    msg = problems(mini(sec))
    assert "fe-mini.toml" in msg and "gyros[0]" in msg and "reads nothing" in msg
    assert "section 's' has no rotation coordinates" in msg
    msg = problems(mini('[[gyros]]\nname = "g"\naxis = "x"\n'))
    assert "gyros[0]" in msg and "rotation_rad" in msg
    # rotation only about z, axis x: perpendicular
    msg = problems(mini('[[gyros]]\nname = "g"\naxis = "x"\nrotation_rad = { x1 = [0.0, 0.0, 1.0] }\n'))
    assert "gyros[0]" in msg and "perpendicular" in msg
    msg = problems(mini('[[gyros]]\nname = "g"\naxis = "x"\nrotation_rad = { nope = [1.0, 0.0, 0.0] }\n'))
    assert "gyros[0].rotation_rad.nope" in msg


def test_gyro_that_senses_no_mode_is_refused():
    """A gyro on a coordinate that no mode moves (shape entry 0) would read 0 forever."""
    text = mini('[[gyros]]\nname = "g"\naxis = "x"\nrotation_rad = { x3 = [1.0, 0.0, 0.0] }\n')
    text = text.replace('[[antennas]]', '[[coordinates]]\nname = "x3"\nkind = "modal"\n\n[[antennas]]', 1)
    text = text.replace("shape = [1.0, 0.0]", "shape = [1.0, 0.0, 0.0]").replace("shape = [0.0, 1.0]", "shape = [0.0, 1.0, 0.0]")
    msg = problems(text)
    assert "gyros[0]" in msg and "senses none of the modes" in msg


def test_spectra_refuses_a_blind_gyro(tower):
    """Configs cannot declare one any more, but a config built in code (or read from an old file)
    with a gyro that sees no mode must not give an all-zero curve silently."""
    blind = dataclasses.replace(tower, gyro_rotation=np.zeros_like(tower.gyro_rotation))
    t = np.arange(400) * 0.1
    q = np.random.default_rng(0).standard_normal((400, 4))
    rate = np.zeros((400, 3))
    with pytest.raises(CdgpsError, match="g120x, g120y, g60y .*sense none of the modes"):
        compute_spectra(blind, t, q, t, rate, SpectraOptions())


def test_damping_ratio_gives_the_time_constant_and_the_poles():
    """ζ = 0.02 at 0.5 Hz → τ = 1/(ζω) = 15.915 s; the continuous model's poles are
    −ζω ± iω√(1−ζ²) (independent check: eigenvalues of A_c)."""
    cfg = parse_config(mini())
    w = 2 * np.pi * 0.5
    assert cfg.mode_time_constant_s[0] == pytest.approx(1 / (0.02 * w), rel=1e-14)
    assert cfg.mode_damping_ratio[1] == pytest.approx(1 / (2 * np.pi * 2.0 * 8.0), rel=1e-14)
    Ac, _, _ = continuous_model(cfg)
    lam = np.linalg.eigvals(Ac)
    lam1 = lam[np.argmin(np.abs(np.abs(lam) - w))]
    assert -lam1.real == pytest.approx(0.02 * w, rel=1e-10)
    assert abs(lam1.imag) == pytest.approx(w * np.sqrt(1 - 0.02**2), rel=1e-10)


@pytest.mark.parametrize("damping, expect", [
    ("damping_ratio = 0.02\ntime_constant_s = 10.0", "exactly one of time_constant_s"),
    ("", "exactly one of time_constant_s"),
    ("damping_ratio = 1.2", "0 < ζ < 1"),
    ("damping_ratio = -0.1", "positive"),
])
def test_bad_damping_is_refused(damping, expect):
    msg = problems(mini(damping=damping))
    assert "modes[0]" in msg and expect in msg


def test_damping_ratio_on_a_rigid_mode_is_refused():
    text = mini().replace('frequency_hz = 0.5', 'frequency_hz = 0.0\nrigid = true')
    assert "modes[0].damping_ratio: a rigid-body mode has no damping ratio" in problems(text)


def test_process_noise_covariance_and_cholesky():
    W = [[0.01, -0.004], [-0.004, 0.04]]
    cfg = parse_config(mini(noise=f"covariance = {W}"))
    np.testing.assert_array_equal(cfg.process_noise_W, W)
    np.testing.assert_allclose(cfg.process_noise_sigma, [0.1, 0.2])
    np.testing.assert_allclose(discrete_model(cfg).W, W)
    L = cfg.process_noise_factor
    np.testing.assert_allclose(L @ L.T, W, rtol=1e-14)
    cfg2 = parse_config(mini(noise="cholesky = [[0.1, 0.0], [-0.04, 0.2]]"))
    np.testing.assert_allclose(cfg2.process_noise_W, [[0.01, -0.004], [-0.004, 0.0016 + 0.04]])
    # diagonal sigma: W = diag(σ²), unchanged behaviour
    np.testing.assert_array_equal(parse_config(mini()).process_noise_W, np.diag(np.array([0.1, 0.2]) ** 2))


def test_semidefinite_covariance_gets_a_factor():
    cfg = parse_config(mini(noise="covariance = [[0.01, 0.02], [0.02, 0.04]]"))   # rank 1
    L = cfg.process_noise_factor
    np.testing.assert_allclose(L @ L.T, cfg.process_noise_W, atol=1e-15)


@pytest.mark.parametrize("noise, expect", [
    ("covariance = [[0.01, 0.002], [-0.004, 0.04]]", "process_noise.covariance: expected a symmetric matrix; [0][1] = 0.002 but [1][0] = -0.004"),
    ("covariance = [[0.01, 0.05], [0.05, 0.04]]", "process_noise.covariance: expected a positive semi-definite"),
    ("covariance = [[0.01, 0.0, 0.0], [0.0, 0.04, 0.0], [0.0, 0.0, 1.0]]", "process_noise.covariance: expected a 2×2 matrix"),
    ("covariance = [[0.01], [0.0, 0.04]]", "expected a 2×2 matrix"),
    ("cholesky = [[0.1, 0.3], [0.0, 0.2]]", "process_noise.cholesky: expected a lower-triangular factor"),
    ("sigma = [0.1, 0.2]\ncovariance = [[1.0, 0.0], [0.0, 1.0]]", "give exactly one of sigma"),
    ("", "give exactly one of sigma"),
])
def test_bad_process_noise_is_refused(noise, expect):
    assert expect in problems(mini(noise=noise))


def test_simulated_forcing_has_the_config_covariance(tmp_path):
    """Correlated forcing reaches the simulator: the modal accelerations implied by the simulated
    truth (ξ_{k+1} − A ξ_k recovered through B_w) have the config's W (Monte Carlo, 6000 samples)."""
    from cdgps_cli.sim.structure import SimOptions, simulate

    W = np.array([[0.01, -0.012], [-0.012, 0.04]])       # correlation −0.6
    text = mini(noise=f"covariance = {W.tolist()}") + "[simulation]\ndisturbance_scale = 1.0\n"
    cfg = parse_config(text)
    x = simulate(cfg, SimOptions(duration_s=600.0, seed=3)).x
    m = discrete_model(cfg)
    resid = x[1:] - x[:-1] @ m.A.T
    w = np.linalg.lstsq(m.Bw, resid.T, rcond=None)[0].T
    C = np.cov(w.T)
    assert C[0, 1] / np.sqrt(C[0, 0] * C[1, 1]) == pytest.approx(-0.6, abs=0.04)
    np.testing.assert_allclose(np.diag(C), np.diag(W), rtol=0.08)


def test_channel_sigma_precedence():
    extra = ('[[channel_sigma]]\nantenna = "tip"\ntransmitter = "S2"\nsigma_m = 0.011\n')
    cfg = parse_config(mini(extra))
    np.testing.assert_array_equal(channel_sigma_m(cfg, [("tip", "S1"), ("tip", "S2")]), [0.005, 0.011])
    text = mini(extra).replace('name = "S1"\n', 'name = "S1"\nsigma_m = 0.003\n')
    cfg = parse_config(text)
    np.testing.assert_array_equal(channel_sigma_m(cfg, cfg.channels), [0.003, 0.011])
    text = text.replace('name = "tip"\n', 'name = "tip"\nsigma_m = 0.007\n')
    cfg = parse_config(text)
    np.testing.assert_array_equal(channel_sigma_m(cfg, cfg.channels), [0.007, 0.011])
    assert scalar_sigma_m(np.array([0.005, 0.005])) == 0.005
    assert scalar_sigma_m(np.array([0.003, 0.004])) == pytest.approx(np.sqrt(12.5e-6))
    with pytest.raises(CdgpsError, match="channel nope/S1"):
        channel_sigma_m(cfg, [("nope", "S1")])


def test_bad_channel_sigma_is_refused():
    msg = problems(mini('[[channel_sigma]]\nantenna = "ref"\ntransmitter = "S9"\nsigma_m = 0\n'))
    assert "channel_sigma[0].antenna: expected a rover antenna (tip)" in msg
    assert "channel_sigma[0].transmitter: expected a transmitter (S1, S2)" in msg
    assert "channel_sigma[0].sigma_m: expected a positive number" in msg
    msg = problems(mini().replace("master = true", "master = true\nsigma_m = 0.01"))
    assert "antennas[0].sigma_m: the master is in every channel" in msg


def test_modal_coordinates_without_unit_are_labelled():
    cfg = parse_config(mini())
    assert cfg.coord_unit_label("x1") == "modal amplitude" and cfg.coord_unit("x1") == "1"


# -------------------------------------------------------------------------------------- points


def test_point_sigma_is_exact_for_fe_shapes(tower):
    """Linear FE shapes: d = D U ξ and Cov = D U P Uᵀ Dᵀ (computed here by hand)."""
    rng = np.random.default_rng(1)
    xi = rng.standard_normal((5, 4)) * 0.05
    A = rng.standard_normal((5, 4, 4)) * 1e-3
    P = A @ A.transpose(0, 2, 1)
    pts = select_points(tower, "a120,z100")
    d, s, cov = point_displacements(tower, pts, xi, P)
    for k, name in enumerate(pts.names):
        D = pts.displacement[k]
        np.testing.assert_allclose(d[:, k], xi @ D.T, atol=1e-14)
        want = np.einsum("im,nmk,jk->nij", D, P, D)
        np.testing.assert_allclose(cov[:, k], want, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(s[:, k], np.sqrt(np.einsum("nii->ni", want)), rtol=1e-12)


def test_point_jacobian_matches_finite_differences(testbed_cfg, central_diff):
    """On the testbed (section rotations, rigid-body angle) the Jacobian J used for σ equals the
    central finite difference of the point positions."""
    pts = select_points(testbed_cfg, "antennas")
    q0 = np.random.default_rng(2).standard_normal(testbed_cfg.n_q) * 0.2
    _, J = point_positions(testbed_cfg, q0[None], pts.section, pts.position_m, pts.displacement, jacobian=True)
    fd = central_diff(lambda q: point_positions(testbed_cfg, q[None], pts.section, pts.position_m, pts.displacement)[0], q0)
    np.testing.assert_allclose(J[0], fd, atol=1e-7)


def test_point_sigma_matches_monte_carlo(testbed_cfg):
    """Nonlinear case: draws of ξ ~ N(ξ̂, P) mapped through p(Uξ) have the predicted σ (small P)."""
    rng = np.random.default_rng(3)
    nm = testbed_cfg.n_modes
    xi = rng.standard_normal(nm) * 0.1
    A = rng.standard_normal((nm, nm)) * 2e-3
    P = A @ A.T
    pts = select_points(testbed_cfg, "a1,a6")
    _, s, _ = point_displacements(testbed_cfg, pts, xi[None], P[None])
    draws = rng.multivariate_normal(xi, P, size=20000)
    U = np.asarray(testbed_cfg.mode_shapes)
    p = point_positions(testbed_cfg, draws @ U.T, pts.section, pts.position_m, pts.displacement)
    mc = p.std(axis=0)
    # MC relative error of a std from 20000 draws ≈ 0.5 %; linearization error is far smaller here
    np.testing.assert_allclose(s[0], mc, rtol=0.03, atol=1e-6)


def test_select_points_names_and_errors(tower):
    assert select_points(tower, "all").names == ("base", "a60", "a90", "a120", "z30", "z100", "top")
    assert select_points(tower, "points,a60").names == ("z30", "z100", "top", "a60")
    with pytest.raises(CdgpsError, match="'roof' is not an antenna or a \\[\\[points\\]\\] name"):
        select_points(tower, "roof")
    with pytest.raises(CdgpsError, match="selects no point"):
        select_points(tower, " , ")


# -------------------------------------------------------------------------------- the whole chain


def run_cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def tower_chain(tmp_path_factory):
    """simulate → ingest → init → estimate on the FE tower, 300 s, a cycle slip inside the window."""
    d = tmp_path_factory.mktemp("tower")
    r = run_cli("-q", "simulate", TOWER, "--duration", 300, "--seed", 5, "--slip", "a120:PL3:30:2",
                "--out", d / "sim")
    assert r.exit_code == 0, r.output
    r = run_cli("-q", "ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", TOWER,
                "-o", d / "run.mcap")
    assert r.exit_code == 0, r.output
    r_init = run_cli("init", d / "run.mcap", "-o", d / "init.json")
    assert r_init.exit_code == 0, r_init.output
    r = run_cli("-q", "estimate", d / "run.mcap", "--init", d / "init.json", "-o", d / "states.mcap")
    assert r.exit_code == 0, r.output
    return d, r_init.output


def test_tower_init_counts_channels_and_segments(tower_chain):
    """18 channels; the slip at 30 s inside the 0–60 s window makes 19 bias segments, all fixed."""
    d, out = tower_chain
    init = json.loads((d / "init.json").read_text())
    assert init["window"]["channels"] == 18 and init["window"]["bias_segments"] == 19
    assert "INIT: 18 channels, 19 bias segments, 19 of 19 segment integers fixed" in out


def test_tower_estimate_is_honest(tower_chain):
    """NEES/dof and NIS/dof near 1 and 3σ coverage as promised, biases right (simulated noise and
    forcing are the model's: 5 mm, disturbance scale 1)."""
    d, _ = tower_chain
    r = run_cli("evaluate", "--truth", d / "sim", "--estimate", d / "states.mcap", "--json")
    assert r.exit_code == 0, r.output
    ev = json.loads(r.output)
    assert 0.7 <= ev["nees"]["mean"] / ev["nees"]["dof"] <= 1.4, ev["nees"]
    assert 0.7 <= ev["nis"]["mean_per_dof"] <= 1.4, ev["nis"]
    assert ev["within_3sigma_fraction"] >= 0.95
    assert ev["bias_error"]["wrong_integers"] == 0
    assert ev["rms_error"]["qx-1"] < 0.005                  # metres at the top
    assert ev["rms_error_units"]["qx-1"] == "m at the top (x)"
    text = run_cli("evaluate", "--truth", d / "sim", "--estimate", d / "states.mcap").output
    assert re.search(r"RMS error +qx-1: [0-9.]+ m at the top \(x\)", text), text


def test_tower_spectra_see_the_modes_and_the_gyros(tower_chain):
    d, _ = tower_chain
    r = run_cli("-q", "spectra", d / "states.mcap", "--gyro", d / "run.mcap", "-o", d / "spec", "--json")
    assert r.exit_code == 0, r.output
    modes = {m["mode"]: m for m in json.loads(r.output)["modes"]}
    for name in ("bend-x-1", "bend-y-1"):
        assert modes[name]["seen"], modes[name]
        assert abs(modes[name]["error_pct"]) < 1.0
        assert modes[name]["gyro"] in ("g120x", "g120y", "g60y")
    psd = pd.read_csv(d / "spec" / "psd.csv")
    for g in ("g120x", "g120y", "g60y"):                    # GPS-derived gyro angles are not all zero
        col = next(c for c in psd.columns if c.startswith(f"gps_{g}"))
        assert psd[col].max() > 0


def test_tower_export_points_sigma(tower_chain, tower):
    """export --points: displacement columns equal D·q and σ equal sqrt(diag(D P_q Dᵀ)) from the
    STATES file; a bad name exits 2 without writing."""
    from cdgps_cli.io.states import States

    d, _ = tower_chain
    out = d / "points.csv"
    r = run_cli("export", d / "states.mcap", "--csv", out, "--points", "a120,top", "--json")
    assert r.exit_code == 0, r.output
    df = pd.read_csv(out)
    st = States(d / "states.mcap", diagnostics=False)
    D = tower.antenna_displacement[tower.antenna_names.index("a120")]
    np.testing.assert_allclose(df["a120_dx_m"], st.q @ D[0], atol=1e-12)
    var = np.einsum("m,nmk,k->n", D[0], st.P_xi, D[0])
    np.testing.assert_allclose(df["sigma_a120_dx_m"], np.sqrt(var), rtol=1e-9)
    # the top point moves like the top antenna horizontally (σ too); its σ is a few mm at most
    np.testing.assert_allclose(df["sigma_top_dy_m"], df["sigma_a120_dy_m"], rtol=1e-9)
    assert 0 < df["sigma_top_dx_m"].median() < 0.005
    # the σ is a promise: the true top displacement (truth q through the same shapes) lies within
    # 2σ at about 95 % of the epochs
    truth = pd.read_csv(d / "sim" / "truth.csv").set_index(np.round(pd.read_csv(d / "sim" / "truth.csv")["time_s"], 6))
    qt = truth.loc[np.round(df["time_s"], 6), [f"{n}_m" for n in tower.coord_names]].to_numpy()     # qx-1_m …
    Dt = tower.point_displacement[tower.point_names.index("top")]
    for a, ax in enumerate("xy"):
        z = (df[f"top_d{ax}_m"].to_numpy() - qt @ Dt[a]) / df[f"sigma_top_d{ax}_m"].to_numpy()
        assert 0.90 <= np.mean(np.abs(z) <= 2.0) <= 0.99, (ax, np.mean(np.abs(z) <= 2.0))
    bad = d / "bad.csv"
    r = run_cli("export", d / "states.mcap", "--csv", bad, "--points", "roof")
    assert r.exit_code == 2 and "roof" in r.output and not bad.exists()
