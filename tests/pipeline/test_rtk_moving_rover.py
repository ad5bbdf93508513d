"""``cdgps rtk`` on rovers that move far: a rover that climbs (its troposphere where it is at each epoch), and
the velocity of the constant-velocity mode, each checked against simulator truth.

* The simulated rover's velocity random-walks at 0.05 m/s/√s (``simulate-gnss --constant-velocity``, the
  constant-velocity model's own process sampled exactly): in 10 min it climbs about 490 m.  The simulator
  puts each epoch's troposphere at the rover's true height; ``rtk`` must evaluate it where the rover is too
  (from the float position while nothing is fixed, as RTKLIB at its current estimate).  With the delay at one
  a-priori position, the float was a metre high and only 213 of 900 epochs fixed forward (RTKLIB: 899).
* The velocity (ENU, m/s) and its σ against the simulator's true velocity: honest in each pass (error / σ
  RMS ≈ 1), the combined passes better than either; and on the Spirent hardware-simulator rose figure
  (an independent simulator, 2–5 m/s) within 1 cm/s of its true velocity.
"""

import json

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
from cdgps_cli.pipeline.gnss_multi import rtk_from_files
from tests._shared import REPO_ROOT, run_cli

ACCEL = 0.05          # m/s/√s, the simulated process and the filter's


@pytest.fixture(scope="module")
def climb(tmp_path_factory):
    d = tmp_path_factory.mktemp("climb")
    r = run_cli("-q", "simulate-gnss", "--duration", 600, "--constant-velocity", ACCEL, "--seed", 3, "-o", d)
    assert r.exit_code == 0, r.output
    return d


def _solve(d, out, **options):
    s = rtk_from_files(d / "base.rnx", d / "rover.rnx", [d / "nav.rnx"], out, options=options)
    return s, pd.read_csv(out, comment="#")


@pytest.fixture(scope="module")
def velocity(climb, tmp_path_factory):
    """The climbing rover in constant-velocity mode at the simulated ACCEL, each direction solved once
    (forward, backward and combined, the default): ``{direction: (summary, solution CSV path, solution)}``,
    read only by the tests (the two velocity tests and the output-format test used to solve them again)."""
    from cdgps_cli.config.options import MULTI_GNSS_DEFAULTS, default_direction

    assert MULTI_GNSS_DEFAULTS["direction"] is None and default_direction("constant-velocity") == "combined"
    d = tmp_path_factory.mktemp("velocity")
    out = {}
    for direction in ("forward", "backward", "combined"):
        s, sol = _solve(climb, d / f"{direction}.csv", mode="constant-velocity", accel_sigma_m_per_s_per_sqrt_s=ACCEL,
                        direction=direction)
        out[direction] = s, d / f"{direction}.csv", sol
    return out


def _truth_enu(d, sol: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """The solution's ENU positions from the rover's nominal position, and the truth's."""
    x0 = np.asarray(json.loads((d / "truth.json").read_text())["rover_nominal_ecef_m"])
    lat, lon, _ = ecef_to_geodetic(x0)
    enu = (sol[["x_m", "y_m", "z_m"]].to_numpy() - x0) @ enu_matrix(lat, lon).T
    return enu, pd.read_csv(d / "truth.csv")[["rover_e_m", "rover_n_m", "rover_u_m"]].to_numpy()


def test_a_climbing_rover_fixes_with_its_troposphere_where_it_is(climb, tmp_path):
    assert pd.read_csv(climb / "truth.csv")["rover_u_m"].max() > 300        # the premise: it climbs
    s, sol = _solve(climb, tmp_path / "k.csv", direction="forward")
    enu, truth = _truth_enu(climb, sol)
    fixed = sol["fixed"].to_numpy() == 1
    assert fixed.mean() >= 0.95, s["fixed_epochs"]
    z = (enu - truth)[fixed] / sol[["sigma_e_m", "sigma_n_m", "sigma_u_m"]].to_numpy()[fixed]
    assert np.all((0.7 < np.sqrt((z**2).mean(0))) & (np.sqrt((z**2).mean(0)) < 1.3)), np.sqrt((z**2).mean(0))
    assert np.mean(np.linalg.norm(enu - truth, axis=1)[fixed] > 0.05) < 0.01


@pytest.mark.parametrize("direction", ["forward", "backward"])
def test_each_pass_velocity_is_honest_against_the_true_velocity(climb, velocity, direction):
    _, _, sol = velocity[direction]           # mode constant-velocity, accel σ ACCEL, this direction
    truth = pd.read_csv(climb / "truth.csv")[["rover_ve_m_s", "rover_vn_m_s", "rover_vu_m_s"]].to_numpy()
    err = sol[["ve_m_s", "vn_m_s", "vu_m_s"]].to_numpy() - truth
    z = err / sol[["sigma_ve_m_s", "sigma_vn_m_s", "sigma_vu_m_s"]].to_numpy()
    rms = np.sqrt((z**2).mean(0))
    assert np.all((0.85 < rms) & (rms < 1.2)), rms            # a backward pass with its sign wrong: ≫ 1
    assert np.mean(np.abs(z) < 3) > 0.98


def test_combined_velocity_beats_each_pass_and_stays_within_its_sigma(climb, velocity):
    truth = pd.read_csv(climb / "truth.csv")[["rover_ve_m_s", "rover_vn_m_s", "rover_vu_m_s"]].to_numpy()
    rms = {}
    for direction in ("forward", "backward", "combined"):
        _, _, sol = velocity[direction]       # mode constant-velocity, accel σ ACCEL, this direction
        err = sol[["ve_m_s", "vn_m_s", "vu_m_s"]].to_numpy() - truth
        rms[direction] = np.sqrt((err**2).mean(0))
        if direction == "combined":
            z = err / sol[["sigma_ve_m_s", "sigma_vn_m_s", "sigma_vu_m_s"]].to_numpy()
            assert np.all(np.abs(z) < 4) and np.sqrt((z**2).mean()) < 1.0     # the better pass's σ: conservative
    assert np.all(rms["combined"] < rms["forward"]) and np.all(rms["combined"] < rms["backward"]), rms


GE = REPO_ROOT.parent / "shared" / "data" / "rinex-ge"


@pytest.mark.skipif(not GE.exists(), reason="../shared/data/rinex-ge absent")
def test_spirent_rose_figure_velocity_within_1_cm_per_s(tmp_path):
    """The hardware simulator's dynamic rover (a rose figure at 2–5 m/s) against its own PVA file."""
    s = rtk_from_files(GE / "Base-static_MO_Spirent.obs", GE / "Rover-dynamic_MO_Spirent.obs",
                       [GE / "RINEX_GN_Spirent.23N", GE / "RINEX_EN_Spirent.23L"], tmp_path / "v.csv",
                       options={"mode": "constant-velocity"})
    sol = pd.read_csv(tmp_path / "v.csv", comment="#")
    pva = pd.read_csv(GE / "Rover-dynamic_PVA_Spirent.csv")
    at = pd.Series(np.arange(len(pva)), index=pva["GpsToW [s]"].round(3))
    rows = at.loc[(sol["time_gps_s"] % 604800).round(3)].to_numpy()
    lat, lon, _ = ecef_to_geodetic(sol[["x_m", "y_m", "z_m"]].to_numpy())
    v_true = np.einsum("nij,nj->ni", enu_matrix(lat, lon),
                       pva[["Vel ECEF X [m/s]", "Vel ECEF Y [m/s]", "Vel ECEF Z [m/s]"]].to_numpy()[rows])
    assert np.linalg.norm(v_true, axis=1).max() > 4.5
    err = sol[["ve_m_s", "vn_m_s", "vu_m_s"]].to_numpy() - v_true
    assert s["fixed_epochs"] == len(sol) == 601
    assert np.all(np.sqrt((err**2).mean(0)) < 0.01), np.sqrt((err**2).mean(0))


@pytest.fixture(scope="module")
def short_climb(tmp_path_factory):
    """60 s of the climbing rover (the same simulation options): the output-format checks below are about
    columns and files, not the solution, and read no more."""
    d = tmp_path_factory.mktemp("short_climb")
    r = run_cli("-q", "simulate-gnss", "--duration", 60, "--constant-velocity", ACCEL, "--seed", 3, "-o", d)
    assert r.exit_code == 0, r.output
    return d


def test_velocity_in_every_output_format_and_only_in_constant_velocity_mode(short_climb, tmp_path):
    from cdgps_cli.io.solution_formats import read_pos

    climb = short_climb
    rtk_from_files(climb / "base.rnx", climb / "rover.rnx", [climb / "nav.rnx"], tmp_path / "v.pos",
                   options={"mode": "constant-velocity", "accel_sigma_m_per_s_per_sqrt_s": ACCEL})
    text = (tmp_path / "v.pos").read_text()
    head = next(ln for ln in text.splitlines() if ln.startswith("%  GPST"))
    # RTKLIB 2.4.3's out-outvel column heads, as rnx2rtkp writes them
    assert head.endswith("ratio    vn(m/s)    ve(m/s)    vu(m/s)      sdvn     sdve     sdvu    sdvne    sdveu    sdvun")
    line = next(ln for ln in text.splitlines() if not ln.startswith("%"))
    assert len(line.split()) == len(head.lstrip("%").split()) + 1          # GPST takes two fields
    # the same solve to CSV (the default direction, combined, as the .pos)
    _, csv = _solve(climb, tmp_path / "v.csv", mode="constant-velocity", accel_sigma_m_per_s_per_sqrt_s=ACCEL)
    assert read_pos(tmp_path / "v.pos")["coords"].shape == (len(csv), 3) == (60, 3)
    v_neu = np.array([[float(x) for x in ln.split()[15:18]] for ln in text.splitlines() if not ln.startswith("%")])
    assert np.abs(v_neu[:, [1, 0, 2]] - csv[["ve_m_s", "vn_m_s", "vu_m_s"]].to_numpy()).max() <= 1e-4
    rtk_from_files(climb / "base.rnx", climb / "rover.rnx", [climb / "nav.rnx"], tmp_path / "v.geojson",
                   options={"mode": "constant-velocity"})
    props = json.loads((tmp_path / "v.geojson").read_text())["features"][10]["properties"]
    assert {"ve_m_s", "vn_m_s", "vu_m_s", "sigma_ve_m_s", "sigma_vn_m_s", "sigma_vu_m_s"} <= set(props)
    rtk_from_files(climb / "base.rnx", climb / "rover.rnx", [climb / "nav.rnx"], tmp_path / "k.csv")
    assert not any(c.startswith(("ve_", "sigma_v")) for c in pd.read_csv(tmp_path / "k.csv", comment="#").columns)
    rtk_from_files(climb / "base.rnx", climb / "rover.rnx", [climb / "nav.rnx"], tmp_path / "k.pos")
    assert "vn(m/s)" not in (tmp_path / "k.pos").read_text()
