"""QZSS (``J``) in every GNSS path (issue 28 item 3): its signals J:L1, J:L2, J:L5 from RINEX 3 and from u-blox
RXM-RAWX (gnssId 5), its ephemerides from RINEX ``J`` records, a reference satellite of its own per signal.

Simulated: QZSS satellites on GPS orbits (a QZSS record is a GPS-form Kepler record with the GPS constants,
IS-QZSS-PNT), so the truth is the simulator's; the checks are the fixed DD integers of each signal against the
simulated ones (``ingest`` → ``init`` → ``estimate`` from u-blox logs) and ``rtk``'s static position against the
true one.  Real: the car pair of ../shared/data/real-pairs/geonet-car (a GEONET base 5.3 km away), whose RTKLIB
reference runs use GPS + Galileo + QZSS: its standing end segment, float with GPS + Galileo L1 (ratio 2.3, 30 cm
off), fixes with QZSS L1 added and lands within 2 mm of RTKLIB's G+E+J L1 static solution.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.io.rinex_write import write_rinex_nav, write_rinex_obs_signals
from cdgps_cli.model.gps.orbits import enu_matrix
from cdgps_cli.model.gps.positioning import synthetic_nav
from cdgps_cli.pipeline.gnss import rover_segments
from cdgps_cli.sim.gnss_signals import simulate_receiver_signals
from tests._shared import run_cli, run_commands
from tests.io.test_ubx_signals import rawx_log

SIGS = ["G:L1", "J:L1", "J:L2"]
T0, N = 1_400_000_000.0, 120
BASE = np.array([3_875_000.0, 332_000.0, 5_028_000.0])
ROVER = BASE + enu_matrix(math.radians(52.3), math.radians(4.9)).T @ np.array([120.0, -45.0, 3.0])
AS_QZSS = {"G12": "J01", "G33": "J02", "G36": "J03", "G22": "J04"}   # four satellites in view, renamed
_UBX_ID = {"G:L1": (0, 0), "J:L1": (5, 0), "J:L2": (5, 5)}          # (gnssId, sigId) as an F9 reports them
CAR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real-pairs" / "geonet-car"


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("qzss")
    nav = synthetic_nav({"G"}, T0, float(N), seed=4)
    nav["sat"] = nav["sat"].replace(AS_QZSS)
    write_rinex_nav(tmp / "nav.rnx", nav)
    ints = {}
    for name, xyz, seed, drift in (("base", BASE, 1, 0.3), ("rover", ROVER, 2, -0.4)):
        s = simulate_receiver_signals(nav, xyz, T0, N, 1.0, SIGS, seed=seed, clock_drift_ms=drift)
        rawx_log(s["obs"], tmp / f"{name}.ubx", _UBX_ID)
        write_rinex_obs_signals(tmp / f"{name}.rnx", s["obs"], SIGS, {"marker_name": name, "approx_position_xyz_m": xyz})
        amb = s["ambiguities"].drop_duplicates(["signal", "sat"])
        ints[name] = {(r.signal, r.sat): int(r.n_cycles) for r in amb.itertuples()}
        ints[f"{name}_sats"] = {g: sorted(s["obs"].loc[s["obs"]["signal"] == g, "sat"].unique()) for g in SIGS}
    return tmp, ints


def test_the_simulation_has_qzss_satellites_in_view(pair):
    _, ints = pair
    assert len(ints["rover_sats"]["J:L1"]) == 4 and all(s[0] == "J" for s in ints["rover_sats"]["J:L2"])
    assert len(ints["rover_sats"]["G:L1"]) >= 4


def test_ublox_qzss_through_ingest_init_estimate_fixes_the_simulated_integers(pair):
    tmp, ints = pair
    (tmp / "job.toml").write_text(
        f'[gnss]\nmaster = "base"\nsignals = {json.dumps(SIGS)}\nnav = ["nav.rnx"]\n'
        f'[gnss.antennas.base]\nubx = "base.ubx"\nposition_ecef_m = {BASE.tolist()}\n'
        f'[gnss.antennas.rover]\nubx = "rover.ubx"\nposition_ecef_m = {ROVER.tolist()}\n')
    run_commands(("ingest", "--config", tmp / "job.toml", "-o", tmp / "run.mcap"),
                 ("init", tmp / "run.mcap", "-o", tmp / "init.json"),
                 ("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "-o", tmp / "states.mcap"))
    init = json.loads((tmp / "init.json").read_text())
    rov = init["rovers"]["rover"]
    assert rov["solution"] == "fixed" and rov["n_fixed"] == rov["n_estimated"]
    segs = rover_segments(init, "rover")
    assert {s["signal"] for s in segs} == set(SIGS)
    for s in segs:
        g, sat, ref = s["signal"], s["sat"].split(":")[0], s["reference"].split(":")[0]
        assert sat[0] == ref[0] == g[0]                       # a QZSS satellite differenced with a QZSS reference
        if s["pivot"]:
            continue
        want = (ints["rover"][(g, sat)] - ints["base"][(g, sat)]) - (ints["rover"][(g, ref)] - ints["base"][(g, ref)])
        assert s["integer"] == want, s
    assert np.linalg.norm(list(init["states"].values())) < 0.01
    info = json.loads(run_cli("info", tmp / "run.mcap", "--json").stdout)
    assert {rx["name"]: rx["signal_satellites"]["J"] for rx in info["gnss"]["receivers"]} == {"base": 4, "rover": 4}


def test_rtk_with_qzss_lands_on_the_true_position(pair):
    tmp, _ = pair
    for sigs, used in (("G:L1,J:L1,J:L2", SIGS), ("auto", ["G:L1"])):       # auto leaves QZSS out, and says so
        r = run_cli("rtk", "--base", tmp / "base.rnx", "--rover", tmp / "rover.rnx", "--nav", tmp / "nav.rnx",
                    "--base-xyz", *map(str, BASE), "--signals", sigs, "--mode", "static", "-o", tmp / "q.pos", "--json")
        assert r.exit_code == 0, r.output
        out = json.loads(r.stdout)
        assert out["signals"] == used
        assert (sigs == "auto") == any("QZSS signals held by both files (J:L1, J:L2)" in w for w in out["warnings"])
        if sigs != "auto":                                           # (GPS alone, four satellites: float)
            assert out["fixed_epochs"] > 0.9 * N
            assert np.linalg.norm(np.array(out["static_xyz_m"]) - ROVER) < 0.005


def test_a_qzss_only_run_works(pair):
    tmp, _ = pair
    r = run_cli("rtk", "--base", tmp / "base.rnx", "--rover", tmp / "rover.rnx", "--nav", tmp / "nav.rnx",
                "--base-xyz", *map(str, BASE), "--signals", "J:L1,J:L2", "--mode", "static", "-o", tmp / "j.pos", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)                 # four satellites alone: fixed, within their weak geometry's centimetre
    assert out["signals"] == ["J:L1", "J:L2"] and out["fixed_epochs"] > 0.8 * N
    assert np.linalg.norm(np.array(out["static_xyz_m"]) - ROVER) < 0.02


@pytest.mark.skipif(not CAR.exists(), reason="../shared/data/real-pairs absent")
def test_the_real_car_end_segment_fixes_with_qzss_as_rtklib_does(tmp_path):
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s

    files = {}
    for who, name in (("base", "3034265G.21O"), ("rover", "SEPT265G.21O")):
        text = (CAR / name).read_text()
        t0 = epoch_times_gps_s(text)[0]
        files[who] = tmp_path / f"{who}.obs"
        files[who].write_text(edit_rinex3_obs(text, keep=lambda t, t0=t0: 312.0 <= t - t0 <= 359.5))   # 06:35:12–59
    got = {}
    for sigs in ("G:L1,E:E1", "G:L1,E:E1,J:L1"):
        r = run_cli("rtk", "--base", files["base"], "--rover", files["rover"], "--nav", CAR / "SEPT2650.21P",
                    "--base-xyz", "-3959400.631", "3385704.533", "3667523.111", "--signals", sigs, "--mode", "static",
                    "--direction", "combined", "--pos-frame", "enu", "-o", tmp_path / "end.pos", "--json")
        assert r.exit_code == 0, r.output
        last = [ln.split() for ln in (tmp_path / "end.pos").read_text().splitlines() if not ln.startswith("%")][-1]
        got[sigs] = (np.array(last[2:5], dtype=float), int(last[5]))
    assert got["G:L1,E:E1"][1] == 2                                  # float without QZSS (RTKLIB's GPS L1: float too)
    enu, q = got["G:L1,E:E1,J:L1"]
    rtklib = np.array([5049.078, 1691.873, -1.356])                   # its G+E+J L1 static, README of the pair
    assert q == 1 and np.abs(enu - rtklib).max() < 0.002, enu
    (tmp_path / "job.toml").write_text(                               # the same through ingest → init
        '[gnss]\nmaster = "base"\nsignals = ["G:L1", "E:E1", "J:L1"]\nnav = ["%s"]\n'
        '[gnss.antennas.base]\nrinex = "base.obs"\nposition_ecef_m = [-3959400.631, 3385704.533, 3667523.111]\n'
        '[gnss.antennas.rover]\nrinex = "rover.obs"\n' % (CAR / "SEPT2650.21P"))
    run_commands(("ingest", "--config", tmp_path / "job.toml", "-o", tmp_path / "run.mcap"),
                 ("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json"))
    rov = json.loads((tmp_path / "init.json").read_text())["rovers"]["rover"]
    assert rov["solution"] == "fixed" and rov["n_fixed"] == rov["n_estimated"] >= 12
    assert np.abs(np.array(rov["baseline_enu_from_master_m"]) - rtklib).max() < 0.002, rov["baseline_enu_from_master_m"]


def test_a_signal_group_that_is_never_differenced_does_not_stop_init(tmp_path):
    """The real matrtklib 2018 pair holds QZSS phases, but its navigation file no QZSS ephemeris covering them: the
    J:L1 group is left without a row, and `init` failed with an IndexError listing its reference satellites."""
    data = Path(__file__).resolve().parents[1] / "data" / "matrtklib-2018-static"
    cfg = tmp_path / "cfg.toml"
    run_commands(("config", "--rinex", f"base={data / 'base_60s.obs.gz'}", "--rinex", f"rover={data / 'rover_60s.obs.gz'}",
                  "--nav", data / "base.nav.gz", "--master", "base", "--signals", "G:L1,E:E1,J:L1", "-o", cfg))
    text = cfg.read_text().replace("# position_ecef_m = [x, y, z]", "position_ecef_m = [-3937776.1063, 3354867.8075, "
                                   "3718445.0835]", 1)
    cfg.write_text(text)
    r = run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output
    r = run_cli("-q", "init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    assert r.exit_code == 0 and "Traceback" not in r.output, r.output
    rover = json.loads((tmp_path / "init.json").read_text())["rovers"]["rover"]
    assert not [s for s in rover["satellites"] if s["sat"].startswith("J")]
