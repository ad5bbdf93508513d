"""The acceptance test of issue 28 on our own real data: a known vibration added to a real rover's
RINEX through each satellite's line of sight is recovered by both GNSS paths.

The real Septentrio pair of ../shared/data/real-pairs/mosaic-static (5 min at 1 Hz): every
pseudorange and carrier phase of the rover file gets Δρ_s = −e_sᵀ d(t) with d(t) = 3 mm ·
sin(2π · 0.2 Hz · t) along azimuth 120°, elevation 30° (e_s from the broadcast ephemeris; GPS and
Galileo satellites).  ``cdgps rtk`` (GPS + Galileo L1) and ``ingest → init → estimate`` (random-walk
displacement, smoothed, and its single-epoch series) must give the amplitude within 10 % and the
frequency within 1 % from at least 95 % of the rover's epochs — fitted on the solutions as they
are (the receivers' own noise and multipath stay in; nothing is subtracted).  RTKLIB on the same
files: benchmarks/bench_vibration_real.py (docs/benchmarks/vibration_real.json).
"""

import json
import math

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.analysis.sine_fit import fit_sine
from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s, range_change_of_motion
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")
BASE_XYZ = (-3817681.1213, 3562839.4311, 3650159.1593)           # base_position.txt in ECEF
T0 = 1403252400.0                                                 # 2024-06-24 08:20:00 GPST
AMP_M, F_HZ, AZ_DEG, EL_DEG = 0.003, 0.2, 120.0, 30.0
U = np.array([math.cos(math.radians(EL_DEG)) * math.sin(math.radians(AZ_DEG)),
              math.cos(math.radians(EL_DEG)) * math.cos(math.radians(AZ_DEG)), math.sin(math.radians(EL_DEG))])
N_ROVER = 301


@pytest.fixture(scope="module")
def rover(tmp_path_factory):
    d = tmp_path_factory.mktemp("vib")
    text = (MOSAIC / "rover.obs").read_text()
    nav = pd.concat([read_rinex_nav(MOSAIC / "base.nav", systems=(s,)) for s in ("G", "E")], ignore_index=True)
    xyz = np.array(BASE_XYZ) + np.array([-0.2556, -0.6052, -0.7812])
    motion = range_change_of_motion(nav, xyz, lambda t: AMP_M * math.sin(2 * math.pi * F_HZ * (t - T0)) * U,
                                    times_gps_s=epoch_times_gps_s(text))
    p = d / "rover_vib.obs"
    p.write_text(edit_rinex3_obs(text, range_change_m=motion))
    return p


def _check(t, enu, used):
    assert used.sum() >= 0.95 * N_ROVER, used.sum()
    f = fit_sine(t[used] - T0, enu[used] @ U, F_HZ)
    assert abs(f.amplitude / AMP_M - 1) < 0.10 and abs(f.frequency_hz / F_HZ - 1) < 0.01, f
    return f


def test_rtk_recovers_the_vibration(rover, tmp_path):
    out = tmp_path / "rtk.csv"
    r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", rover, "--nav", MOSAIC / "base.nav",
                "--signals", "G:L1,E:E1", "--base-xyz", *BASE_XYZ, "-o", out)
    assert r.exit_code == 0, r.output
    d = pd.read_csv(out, comment="#")
    assert len(d) == N_ROVER
    f = _check(d["time_gps_s"].to_numpy(), d[["e_m", "n_m", "u_m"]].to_numpy(), d["fixed"].to_numpy() == 1)
    assert f.residual_rms < 0.002                      # the receivers' own noise along u, about 1.2 mm


def test_ingest_init_estimate_recovers_the_vibration(rover, tmp_path):
    cfg = tmp_path / "run.toml"
    cfg.write_text("\n".join([
        "[gnss]", 'master = "base"', f'nav = ["{MOSAIC / "base.nav"}"]', 'signals = ["G:L1", "E:E1"]',
        "[gnss.displacement]", 'model = "random_walk"', "sigma_m_per_sqrt_s = 0.1",
        '[gnss.antennas."base"]', f'rinex = "{MOSAIC / "base.obs"}"', f"position_ecef_m = {list(BASE_XYZ)}",
        '[gnss.antennas."rover"]', f'rinex = "{rover}"', ""]))
    for args in (("ingest", "--config", cfg, "-o", tmp_path / "run.mcap"),
                 ("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json"),
                 ("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "-o", tmp_path / "s.mcap", "--smooth"),
                 ("export", tmp_path / "s.mcap", "-o", tmp_path / "s.csv"),
                 ("export", tmp_path / "s.mcap", "--kinematic", "-o", tmp_path / "k.csv")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    init = json.loads((tmp_path / "init.json").read_text())["rovers"]["rover"]
    assert init["solution"] == "fixed" and init["epochs"]["n_epochs_used"] == N_ROVER
    for name in ("s.csv", "k.csv"):                  # smoothed random-walk states; single-epoch fixed solutions
        d = pd.read_csv(tmp_path / name)
        enu = d[["rover_e_m", "rover_n_m", "rover_u_m"]].to_numpy()
        _check(d["time_s"].to_numpy(), enu, np.isfinite(enu).all(axis=1))
