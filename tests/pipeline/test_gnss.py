"""The GNSS pipeline: ingest → init → estimate → export on GNSS runs (cdgps_cli.pipeline.gnss).

* GEONET 3040 → 0759 (real data, ../shared/data): integers fixed, the static displacement equal to
  `cdgps baseline`'s (which agrees with RTKLIB within 0.2 mm, tests/estimation/test_baseline.py), the
  single-epoch scatter, CSV export;
* simulated pairs written as RINEX (static and random-walk rovers): the truth is recovered,
  NEES consistent, slips become events, INIT's integers are the ones used;
* the random-walk float solution reduces to the static one for a vanishing walk, and fixes a
  wandering rover that the static float cannot;
* errors: mismatched INIT, structure-only options, runs without a rover.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.estimation.baseline import BaselineOptions, Station, solve_static_baseline
from cdgps_cli.cli.commands import main
from cdgps_cli.model.gps.orbits import ecef_to_enu
from cdgps_cli.model.gps.positioning import simulate_static_pair, synthetic_gps_nav
from cdgps_cli.pipeline.gnss import KINEMATIC_TOPIC, rover_segments
from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.io.states import States

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared" / "data" / "rinex"
GEONET = ROOT / "configs" / "geonet-0759-3040.toml"
ROVER_XYZ = np.array([-3976219.5082, 3382372.5671, 3652512.9849])
MASTER_XYZ = np.array([-3978242.4348, 3382841.1715, 3649902.7667])
RTKLIB_FIX_AND_HOLD = (-3976219.6637, 3382372.5422, 3652513.0576)     # docs/geonet.md, tests/estimation/test_baseline.py


def run_cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def pipeline(tmp: Path, config: Path, *estimate_args) -> dict:
    for args in (("ingest", "--config", config, "-o", tmp / "run.mcap"),
                 ("init", tmp / "run.mcap", "-o", tmp / "init.json"),
                 ("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "-o", tmp / "states.mcap", *estimate_args),
                 ("export", tmp / "states.mcap", "--csv", tmp / "states.csv"),
                 ("export", tmp / "states.mcap", "--csv", tmp / "kinematic.csv", "--kinematic")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    return json.loads((tmp / "init.json").read_text())


# ----------------------------------------------------------------------------------------------
# GEONET


@pytest.fixture(scope="module")
def geonet(tmp_path_factory):
    if not (SHARED / "30400920.05o").exists():
        pytest.skip(f"shared test data not available: {SHARED}")
    tmp = tmp_path_factory.mktemp("geonet")
    init = pipeline(tmp, GEONET)
    r = run_cli("-q", "baseline", "--config", GEONET, "-o", tmp / "baseline.json")
    assert r.exit_code == 0, r.output
    return tmp, init, json.loads((tmp / "baseline.json").read_text())


def test_geonet_pipeline_equals_baseline_and_rtklib(geonet):
    tmp, init, bl = geonet
    rov = init["rovers"]["0759"]
    assert init["format"] == "cdgps.init/2" and init["kind"] == "gnss" and init["master"] == "3040" and init["coordinates"] == ["0759_e", "0759_n", "0759_u"]
    assert rov["solution"] == "fixed" and rov["n_fixed"] == rov["n_estimated"] == 6 and rov["ratio"] > 100
    # the same numbers as `cdgps baseline` (to the last bit: same data, same code)
    assert init["states"] == bl["states"]
    assert [s["integer"] for s in rover_segments(init, "0759")] == [s["integer"] for s in bl["ambiguities"]["segments"]]
    # and so within 0.2 mm of RTKLIB's fixed solution (the requirement is 1 cm)
    rtk = ecef_to_enu(np.array(RTKLIB_FIX_AND_HOLD), ROVER_XYZ)
    ours = np.array([init["states"][f"0759_{c}"] for c in "enu"])
    assert np.all(np.abs(ours - rtk) < 0.0003), (ours - rtk)
    # STATES: the static solution at every epoch, its 1σ, the single-epoch solutions
    csv = pd.read_csv(tmp / "states.csv")
    assert list(csv.columns) == ["time_s", "0759_e_m", "0759_n_m", "0759_u_m", "sigma_0759_e_m", "sigma_0759_n_m",
                                 "sigma_0759_u_m"]
    assert len(csv) == 120
    np.testing.assert_allclose(csv[["0759_e_m", "0759_n_m", "0759_u_m"]].to_numpy(), np.tile(ours, (120, 1)), atol=1e-12)
    np.testing.assert_allclose(csv.iloc[0, 4:].to_numpy(), [init["sigma"][f"0759_{c}"] for c in "enu"], rtol=1e-9)
    kin = pd.read_csv(tmp / "kinematic.csv")
    assert len(kin) == 120 and set(kin["n_sat_0759"]) <= {5, 6, 7}
    good = kin["pdop_0759"] <= 10
    rms = np.sqrt(((kin.loc[good, ["0759_e_m", "0759_n_m", "0759_u_m"]].to_numpy() - ours) ** 2).mean(axis=0))
    assert good.sum() == 114 and np.all(rms < [0.005, 0.006, 0.012]), rms
    assert np.allclose(rms, [bl["kinematic"]["pdop_le_max"]["rms_about_static_m"][c] for c in "enu"], atol=1e-9)


BIAS_FIELDS = {"bias_m", "sigma_m", "integer_cycles", "fixed", "segment_start_s", "segment_end_s"}


def test_geonet_init_biases_have_the_structure_init_fields(geonet, tmp_path):
    """INIT v2: one ``biases`` entry per ambiguity segment, the same fields as a structure INIT's, the
    channel named rover/satellite/reference; a fixed entry's bias is λ × its integer, the pivot's 0."""
    tmp, init, _ = geonet
    segs = rover_segments(init, "0759")
    assert "ambiguities" not in init["rovers"]["0759"]            # the biases are the one record of them
    assert len(init["biases"]) == len(segs) == init["rovers"]["0759"]["n_segments"]
    for b, s in zip(init["biases"], segs):
        assert BIAS_FIELDS <= set(b) and (b["master"], b["rover"], b["satellite"]) == ("3040", "0759", s["sat"])
        assert b["fixed"] and b["integer_cycles"] == s["integer"] and b["sigma_m"] == 0.0
        assert b["bias_m"] == pytest.approx(GPS_L1_WAVELENGTH_M * s["integer"], rel=1e-15)
        assert b["segment_start_s"] < b["segment_end_s"]
    pivots = [b for b in init["biases"] if b["pivot"]]
    assert len(pivots) == 1 and pivots[0]["integer_cycles"] == 0
    assert {b["reference"] for b in init["biases"]} == {pivots[0]["satellite"]}
    # an INIT of the earlier GNSS format (kind "cdgps gnss init", no format, no biases) is still read,
    # and gives the same states
    old = {k: v for k, v in init.items() if k not in ("format", "biases")}
    old["kind"] = "cdgps gnss init"
    old["rovers"] = {r: dict(v, ambiguities=rover_segments(init, r)) for r, v in init["rovers"].items()}
    (tmp_path / "old.json").write_text(json.dumps(old))
    r = run_cli("-q", "estimate", tmp / "run.mcap", "--init", tmp_path / "old.json", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(States(tmp_path / "s.mcap").q, States(tmp / "states.mcap").q)


def test_geonet_states_file(geonet):
    tmp = geonet[0]
    st = States(tmp / "states.mcap")
    assert st.kind == "displacement" and st.cfg is None                  # no structure config faked
    assert st.coord_names == ["0759_e", "0759_n", "0759_u"] and st.q.shape == (120, 3)
    np.testing.assert_array_equal(st.output_map, np.eye(3))
    assert st.metadata["kind"] == "gnss" and st.metadata["displacement_model"] == "static"
    kinds = {e["kind"] for e in st.events}
    assert "reference satellite" in kinds
    assert st.nis is not None and np.isfinite(st.nis).all()
    k = States(tmp / "states.mcap", topic=KINEMATIC_TOPIC)
    assert k.q.shape == (120, 3)
    r = run_cli("info", tmp / "states.mcap")
    assert r.exit_code == 0 and "/cdgps/state" in r.stdout and "/cdgps/residuals" in r.stdout
    # what needs a structure says so (exit 2, nothing written)
    f = tmp / "states.mcap"
    for args, out in ((["export", f, "--points", "antennas", "-o", tmp / "p.csv"], tmp / "p.csv"),
                      (["report", "static", f, "--angle", "0759_e", "-o", tmp / "rep"], tmp / "rep")):
        r = run_cli(*args)
        assert r.exit_code == 2 and "needs the STATES.mcap of a structure" in r.output, r.output
        assert not out.exists()
    # a static estimate is constant: no spectrum (its figures were empty log axes), exit 2, nothing written
    r = run_cli("spectra", f, "-o", tmp / "sp", "--json")
    assert r.exit_code == 2 and "constant over the 120 epochs" in r.output and "random-walk" in r.output, r.output
    assert not (tmp / "sp").exists()


# ----------------------------------------------------------------------------------------------
# simulated pairs


@pytest.fixture(scope="module")
def static_sim(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("static")
    r = run_cli("-q", "simulate-gnss", "--duration", "900", "--seed", "11", "--slips", "4", "--out", tmp)
    assert r.exit_code == 0, r.output
    init = pipeline(tmp, tmp / "config.toml")
    return tmp, init


def test_static_simulation_recovers_the_truth(static_sim):
    tmp, init = static_sim
    truth = json.loads((tmp / "truth.json").read_text())
    rov = init["rovers"]["rover"]
    assert rov["solution"] == "fixed" and rov["n_fixed"] == rov["n_estimated"]
    est = np.array([init["states"][f"rover_{c}"] for c in "enu"])
    assert np.all(np.abs(est - truth["displacement_enu_m"]) < 0.002), est
    r = run_cli("evaluate", "--truth", tmp, "--estimate", tmp / "states.mcap", "--json")
    assert r.exit_code == 0, r.output
    ev = json.loads(r.stdout)
    assert max(ev["rms_error"].values()) < 0.002 and ev["within_3sigma_fraction"] == 1.0
    # every simulated slip on a tracked arc became an event
    st = States(tmp / "states.mcap")
    slips = [e for e in st.events if e["kind"].startswith("slip")]
    tracked = [a for a in truth["ambiguities"] if a["kind"] == "slip"]
    assert len(slips) == len(tracked) and all(e["action"].startswith("new ambiguity, fixed") for e in slips)


def test_estimate_does_not_solve_the_baseline_again(static_sim, geonet):
    """estimate takes INIT's fixed solution as it is (issue 28 item 1): no float solution, no LAMBDA,
    no iterations — the same states, bit for bit, as when it solved them again; an engine INIT position that
    is not the solution of its integers gets the engine's float solution conditioned on INIT's integers
    (a warning says so), not the batch; a batch INIT's, when the engine cannot serve, a clear error."""
    from cdgps_cli.io.gnss_run import read_gnss_run
    from cdgps_cli.pipeline.gnss import _stations, solve_with_init_integers

    tmp, init = static_sim
    run = read_gnss_run(tmp / "run.mcap")
    res, w, _, _ = solve_with_init_integers(run, init, "rover", _stations(run))
    assert res["fixed"]["given"].startswith("position and integers given") and res["timing_s"]["float"] == 0.0
    assert w["x_final"].tolist() == [init["states"][f"rover_{c}"] for c in "enu"]     # exactly INIT's
    assert np.array_equal(States(tmp / "states.mcap").q[0], w["x_final"])
    gtmp, ginit, _ = geonet
    assert ginit["rovers"]["0759"]["solver"] == "static_engine"
    grun = read_gnss_run(gtmp / "run.mcap")
    x_init = np.array(ginit["rovers"]["0759"]["fixed"]["enu_m"])
    moved = json.loads(json.dumps(ginit))
    moved["rovers"]["0759"]["fixed"]["enu_m"][0] += 1e-3
    res2, w2, _, _ = solve_with_init_integers(grun, moved, "0759", _stations(grun))
    assert res2["solver"] == "static_engine (integers given)" and any("solved again from the integers" in m
                                                                      for m in res2["warnings"])
    np.testing.assert_allclose(w2["x_final"], x_init, atol=1e-9)        # the engine's solution of these integers
    if init["rovers"]["rover"]["solver"] != "static_engine":           # a batch INIT the engine cannot serve
        moved = json.loads(json.dumps(init))
        moved["rovers"]["rover"]["fixed"]["enu_m"][0] += 1e-4
        with pytest.raises(CdgpsError, match="run 'cdgps init' again"):
            solve_with_init_integers(run, moved, "rover", _stations(run))


def test_estimate_uses_the_integers_of_init(static_sim, geonet, tmp_path):
    gtmp, ginit, _ = geonet
    bad = json.loads(json.dumps(ginit))
    seg = next(b for b in bad["biases"] if not b["pivot"])
    seg["integer_cycles"] += 1
    (tmp_path / "gbad.json").write_text(json.dumps(bad))
    r = run_cli("-q", "estimate", gtmp / "run.mcap", "--init", tmp_path / "gbad.json", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 0, r.output
    q = States(tmp_path / "s.mcap").q[0]
    good = np.array(ginit["rovers"]["0759"]["fixed"]["enu_m"])
    assert np.linalg.norm(q - good) > 0.002                            # a wrong integer moves the solution
    tmp, init = static_sim
    bad = json.loads(json.dumps(init))
    # an INIT whose segments do not match, or from another run: clear errors, no output
    bad["biases"] = [b for b in bad["biases"] if b["rover"] == "rover"][1:]
    (tmp_path / "bad2.json").write_text(json.dumps(bad))
    r = run_cli("estimate", tmp / "run.mcap", "--init", tmp_path / "bad2.json", "-o", tmp_path / "s2.mcap")
    assert r.exit_code == 2 and "do not match the ambiguity segments" in r.stderr
    other = dict(init, config_sha256="0" * 64)
    (tmp_path / "other.json").write_text(json.dumps(other))
    r = run_cli("estimate", tmp / "run.mcap", "--init", tmp_path / "other.json", "-o", tmp_path / "s3.mcap")
    assert r.exit_code == 2 and "made from another run" in r.stderr
    r = run_cli("estimate", tmp / "run.mcap", "--init", tmp_path / "other.json", "--biases", "states", "-o", tmp_path / "s3.mcap")
    assert r.exit_code == 2 and "--biases: structure-run option" in r.stderr
    for opt in (("--covariance", "full"), ("--foxglove-rate-hz", "0")):
        r = run_cli("estimate", tmp / "run.mcap", "--init", tmp_path / "other.json", *opt, "-o", tmp_path / "s3.mcap")
        assert r.exit_code == 2 and f"{opt[0]}: structure-run option" in r.stderr, r.output
    r = run_cli("init", tmp / "run.mcap", "--no-process-noise", "-o", tmp_path / "i.json")    # (--start: a window)
    assert r.exit_code == 2 and "--no-process-noise: structure-run option" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad2.json", "gbad.json", "other.json", "s.mcap"]


def test_init_options_float_only_and_ratio(static_sim, tmp_path):
    tmp, init = static_sim
    r = run_cli("-q", "init", tmp / "run.mcap", "--float-only", "-o", tmp_path / "f.json")
    assert r.exit_code == 0, r.output
    f = json.loads((tmp_path / "f.json").read_text())
    assert f["rovers"]["rover"]["solution"] == "float" and f["n_fixed"] == 0
    r = run_cli("-q", "init", tmp / "run.mcap", "--ratio", "1e9", "--no-partial", "-o", tmp_path / "r.json")
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "r.json").read_text())["rovers"]["rover"]["solution"] == "float"
    # INIT.json is reproducible
    r = run_cli("-q", "init", tmp / "run.mcap", "-o", tmp_path / "again.json")
    assert (tmp_path / "again.json").read_text() == (tmp / "init.json").read_text()


@pytest.fixture(scope="module")
def rw_sim(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rw")
    r = run_cli("-q", "simulate-gnss", "--duration", "1200", "--seed", "5", "--random-walk", "0.002", "--slips", "3",
                "--out", tmp)
    assert r.exit_code == 0, r.output
    init = pipeline(tmp, tmp / "config.toml", "--smooth")
    r = run_cli("-q", "estimate", tmp / "run.mcap", "--init", tmp / "init.json", "-o", tmp / "filtered.mcap")
    assert r.exit_code == 0, r.output
    return tmp, init


def test_random_walk_rover_filter_and_smoother(rw_sim):
    tmp, init = rw_sim
    rov = init["rovers"]["rover"]
    assert rov["solution"] == "fixed" and rov["n_fixed"] == rov["n_estimated"] and rov["float"]["motion"] == "random_walk"
    res = {}
    for name in ("states", "filtered"):
        r = run_cli("evaluate", "--truth", tmp, "--estimate", tmp / f"{name}.mcap", "--json", "--converge-s", "30")
        assert r.exit_code == 0, r.output
        res[name] = json.loads(r.stdout)
    sm, fi = res["states"], res["filtered"]
    assert max(sm["rms_error"].values()) < 0.006 and max(fi["rms_error"].values()) < 0.008
    assert all(sm["rms_error"][k] < fi["rms_error"][k] for k in sm["rms_error"])       # smoothing helps
    assert 0.3 < sm["nees"]["mean"] < 4.5 and sm["within_3sigma_fraction"] > 0.97       # honest 1σ
    st = States(tmp / "states.mcap")
    assert st.metadata["smoothed"] == "true" and st.metadata["displacement_model"] == "random_walk"
    assert States(tmp / "states.mcap", topic="/cdgps/state_filtered").q.shape == st.q.shape
    truth = pd.read_csv(tmp / "truth.csv")
    assert truth["rover_u_m"].max() - truth["rover_u_m"].min() > 0.03                      # it really wanders



def test_constant_velocity_rover_against_simulator_truth(tmp_path):
    """[gnss.displacement] model = "constant_velocity": a simulated rover whose velocity random-walks (white
    acceleration 5e-5 m/s/√s, the model's own process, sampled exactly), 10 min, 2 slips.  init fixes every
    integer on the random-walk float; estimate --smooth gives the states of the [displacement, velocity] filter
    and smoother, honest against the truth (measured: NEES mean 2.76, NIS 0.99 per DoF, 99 % within 3σ, rms
    error ≤ 1.8 mm), the filtered series beside them, and the model in the STATES metadata; the starter config
    writes the model and its white acceleration."""
    r = run_cli("-q", "simulate-gnss", "--duration", "600", "--seed", "8", "--constant-velocity", "5e-5",
                "--slips", "2", "--out", tmp_path)
    assert r.exit_code == 0, r.output
    cfg = (tmp_path / "config.toml").read_text()
    assert 'model = "constant_velocity"' in cfg and "accel_sigma_m_per_s_per_sqrt_s = 5e-05" in cfg
    init = pipeline(tmp_path, tmp_path / "config.toml", "--smooth")
    rov = init["rovers"]["rover"]
    assert rov["solution"] == "fixed" and rov["n_fixed"] == rov["n_estimated"] and rov["float"]["motion"] == "random_walk"
    r = run_cli("evaluate", "--truth", tmp_path, "--estimate", tmp_path / "states.mcap", "--json")
    assert r.exit_code == 0, r.output
    ev = json.loads(r.stdout)
    assert 1.5 < ev["nees"]["mean"] < 4.5 and ev["within_3sigma_fraction"] > 0.95
    assert 0.9 < ev["nis"]["mean_per_dof"] < 1.1 and max(ev["rms_error"].values()) < 0.004
    st = States(tmp_path / "states.mcap")
    assert st.metadata["displacement_model"] == "constant_velocity" and st.metadata["smoothed"] == "true"
    opts = json.loads(st.metadata["options"])
    assert opts["accel_sigma_m_per_s_per_sqrt_s"] == 5e-05 and opts["init_random_walk_sigma_m_per_sqrt_s"]
    assert States(tmp_path / "states.mcap", topic="/cdgps/state_filtered").q.shape == st.q.shape
    truth = pd.read_csv(tmp_path / "truth.csv")
    assert np.ptp(truth["rover_e_m"].to_numpy()) > 0.02                                   # it really moves


def test_constant_velocity_options_refused_where_they_do_not_apply(tmp_path):
    """accel_sigma_m_per_s_per_sqrt_s is the constant-velocity model's; the simulator takes one motion model."""
    from cdgps_cli.config.structure import parse_gnss_config
    from cdgps_cli.core.errors import CdgpsError
    text = ('[gnss]\nmaster = "a"\nnav = ["n.rnx"]\n[gnss.displacement]\nmodel = "random_walk"\n'
            'accel_sigma_m_per_s_per_sqrt_s = 0.1\n[gnss.antennas.a]\nrinex = "a.obs"\n'
            'position_ecef_m = [-3978242.4, 3382841.2, 3649902.8]\n[gnss.antennas.b]\nrinex = "b.obs"\n')
    with pytest.raises(CdgpsError, match="accel_sigma_m_per_s_per_sqrt_s: only used with model = \"constant_velocity\""):
        parse_gnss_config(text, "x.toml")
    r = run_cli("simulate-gnss", "--duration", "60", "--random-walk", "0.001", "--constant-velocity", "1e-4",
                "--out", tmp_path / "s")
    assert r.exit_code == 2 and "two motion models" in r.output and "Traceback" not in r.output


def test_spectra_of_random_walk_displacements(rw_sim):
    """Spectra of time-varying displacement states: PSDs and FDD of the coordinates, no model modes."""
    tmp = rw_sim[0]
    r = run_cli("spectra", tmp / "filtered.mcap", "-o", tmp / "sp", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["modes"] == []
    psd = pd.read_csv(tmp / "sp" / "psd.csv")
    cols = [c for c in psd.columns if c.startswith("gps_") and c.endswith("_m2_hz")]
    assert len(cols) == 3 and (psd[cols].to_numpy() > 0).all()

def _information_kf_oracle(t, N, b, c, has, sigma_rw, p0_sigma):
    """The random-walk displacement filter + RTS as the pipeline ran it before the engine (textbook
    information form on N = GᵀPG, b = GᵀPr, c = rᵀPr; inverse-gain RTS): the reference."""
    q = np.asarray(sigma_rw) ** 2
    n = t.size
    xf, pf, xp, pp = np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 3, 3))
    nis = np.full(n, np.nan)
    x, P = np.zeros(3), np.eye(3) * p0_sigma**2
    for k in range(n):
        if k:
            P = P + np.diag(q * (t[k] - t[k - 1]))
        xp[k], pp[k] = x, P
        if has[k]:
            Pn = np.linalg.inv(np.linalg.inv(P) + N[k])
            v = b[k] - N[k] @ x
            nis[k] = c[k] - 2.0 * x @ b[k] + x @ N[k] @ x - v @ Pn @ v
            x, P = x + Pn @ v, Pn
        xf[k], pf[k] = x, P
    xs, ps = xf.copy(), pf.copy()
    for k in range(n - 2, -1, -1):
        C = pf[k] @ np.linalg.inv(pp[k + 1])
        xs[k] = xf[k] + C @ (xs[k + 1] - xp[k + 1])
        ps[k] = pf[k] + C @ (ps[k + 1] - pp[k + 1]) @ C.T
    return xs, ps, xf, pf, nis


def _random_dd_layout(gen, n_ep: int, gap_at: int, gap_s: float, no_dd: list):
    """Random SD rows of 4–8 of 12 satellites per epoch (one row, so no DD, at the epochs ``no_dd``), the epochs 1 s
    apart with a gap of ``gap_s`` more before epoch ``gap_at``: times, counts, epoch, satellite, pointers, references
    (highest of random elevations) and a random design (N, 3)."""
    from cdgps_cli.measurement.differencing import epoch_pointers, select_reference
    t = np.arange(n_ep, dtype=float)
    t[gap_at:] += gap_s
    counts = gen.integers(4, 9, n_ep)
    counts[no_dd] = 1
    epoch = np.repeat(np.arange(n_ep), counts)
    sat = np.concatenate([np.sort(gen.choice(12, c, replace=False)) for c in counts]).astype(np.int64)
    ptr = epoch_pointers(epoch, n_ep)
    ref = select_reference(ptr, sat, gen.uniform(0.3, 1.5, sat.size))
    return t, counts, epoch, sat, ptr, ref, gen.normal(size=(sat.size, 3))


def test_random_walk_displacement_is_the_engine_and_equals_the_information_filter():
    """pipeline.gnss._random_walk (engine: SatelliteDDDisplacement + RandomWalk + filter_numpy +
    rts_smooth_transitions) against the information-form filter it replaced, on DD rows with gaps
    (two spacings: the smoother runs in stretches) and epochs without DDs."""
    from cdgps_cli.measurement.dd_displacement import SatelliteDDDisplacement, SDObservations
    from cdgps_cli.measurement.differencing import dd_weight_blocks
    from cdgps_cli.pipeline.gnss import _random_walk

    gen = np.random.default_rng(4)
    n_ep = 60
    t, counts, epoch, sat, ptr, ref, g = _random_dd_layout(gen, n_ep, 30, 4.0, [10, 11, 40])
    truth = np.cumsum(gen.normal(0, 0.002, (n_ep, 3)), axis=0)
    var = gen.uniform(1e-5, 3e-5, sat.size)
    r = np.einsum("ic,ic->i", g, truth[epoch]) + gen.normal(size=sat.size) * np.sqrt(var) + 3.0
    N, b, c = np.zeros((n_ep, 3, 3)), np.zeros((n_ep, 3)), np.zeros(n_ep)
    has = np.zeros(n_ep, dtype=bool)
    for rows, P in dd_weight_blocks(ptr, var, ref):
        ep = epoch[rows[:, 0]]
        N[ep] = np.einsum("kic,kij,kjd->kcd", g[rows], P, g[rows])
        b[ep] = np.einsum("kic,kij,kj->kc", g[rows], P, r[rows])
        c[ep] = np.einsum("ki,kij,kj->k", r[rows], P, r[rows])
        has[ep] = True
    sig = (0.002, 0.003, 0.004)
    want = _information_kf_oracle(t, N, b, c, has, sig, 0.05)
    model = SatelliteDDDisplacement(ptr, sat, [f"G{i:02d}" for i in range(12)], g, [SDObservations(r, var, ref)])
    got = _random_walk(model, t, sig, 0.05, smooth=True)
    for name, a, e in zip(("xs", "Ps", "xf", "Pf"), got[:4], want[:4]):
        np.testing.assert_allclose(a, e, rtol=1e-9, atol=1e-9 * np.abs(e).max(), err_msg=name)
    np.testing.assert_allclose(got[4], want[4], rtol=1e-8, atol=1e-8, equal_nan=True)
    assert np.isnan(got[4][[10, 11, 40]]).all() and np.isfinite(got[4][has]).all()
    filt = _random_walk(model, t, sig, 0.05, smooth=False)
    np.testing.assert_array_equal(filt[0], got[2])


def test_constant_velocity_displacement_is_the_batch_least_squares_of_its_model():
    """pipeline.gnss._constant_velocity (engine: the DD model stacked on [δx, v], ConstantVelocity, filter_numpy,
    rts_smooth_indexed) against the whole record's least squares written out (an independent check: the RTS
    smoother of a linear-Gaussian model is the batch MAP, its covariance the inverse of the batch's Hessian):
    the prior, each step's white-acceleration transition (A, Q of the exact discretization, written here) and the
    DD information of every epoch, on rows with a gap and epochs without DDs."""
    from cdgps_cli.measurement.dd_displacement import SatelliteDDDisplacement, SDObservations
    from cdgps_cli.measurement.differencing import dd_weight_blocks
    from cdgps_cli.pipeline.gnss import _constant_velocity

    gen = np.random.default_rng(11)
    n_ep = 50
    t, counts, epoch, sat, ptr, ref, g = _random_dd_layout(gen, n_ep, 25, 3.0, [7, 8, 33])
    truth = np.cumsum(np.cumsum(gen.normal(0, 0.001, (n_ep, 3)), axis=0), axis=0)
    var = gen.uniform(1e-5, 3e-5, sat.size)
    r = np.einsum("ic,ic->i", g, truth[epoch]) + gen.normal(size=sat.size) * np.sqrt(var) + 3.0
    qa, p0 = 0.004, 0.05
    # the batch: cost ½ Σ (x_k − A x_{k−1})ᵀ Q⁻¹ (…) + ½ x_0ᵀ P0⁻¹ x_0 + Σ_k ½ δx_kᵀ N_k δx_k − b_kᵀ δx_k
    H = np.zeros((6 * n_ep, 6 * n_ep))
    rhs = np.zeros(6 * n_ep)
    H[:6, :6] += np.eye(6) / p0**2
    for rows, P in dd_weight_blocks(ptr, var, ref):
        ep = epoch[rows[:, 0]]
        for e, gk, Pk, rk in zip(ep, g[rows], P, r[rows]):
            H[6 * e:6 * e + 3, 6 * e:6 * e + 3] += gk.T @ Pk @ gk
            rhs[6 * e:6 * e + 3] += gk.T @ Pk @ rk
    for k in range(1, n_ep):
        dt = t[k] - t[k - 1]
        A = np.block([[np.eye(3), dt * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
        Q = qa**2 * np.block([[dt**3 / 3 * np.eye(3), dt**2 / 2 * np.eye(3)], [dt**2 / 2 * np.eye(3), dt * np.eye(3)]])
        W = np.linalg.inv(Q)
        J = np.hstack([-A, np.eye(6)])                        # x_k − A x_{k−1}
        sl = slice(6 * (k - 1), 6 * (k + 1))
        H[sl, sl] += J.T @ W @ J
    x = np.linalg.solve(H, rhs).reshape(n_ep, 6)
    C = np.linalg.inv(H)
    P_want = np.array([C[6 * k:6 * k + 6, 6 * k:6 * k + 6] for k in range(n_ep)])      # [δx, v] (velocities too)
    model = SatelliteDDDisplacement(ptr, sat, [f"G{i:02d}" for i in range(12)], g, [SDObservations(r, var, ref)])
    xs, ps, xf, pf, nis = _constant_velocity(model, t, qa, p0, smooth=True)
    np.testing.assert_allclose(xs[:, :3], x[:, :3], rtol=0, atol=1e-9 * np.abs(x[:, :3]).max())
    np.testing.assert_allclose(xs[:, 3:], x[:, 3:], rtol=0, atol=1e-9 * np.abs(x[:, 3:]).max())
    np.testing.assert_allclose(ps, P_want, rtol=1e-7, atol=1e-12)
    assert np.abs(xs[:, :3] - truth).max() < 0.02
    # the filter's last epoch is the smoother's (both condition on every epoch)
    np.testing.assert_allclose(xf[-1], xs[-1], rtol=1e-12, atol=1e-12)
    assert np.isnan(nis[[7, 8, 33]]).all() and np.isfinite(nis[counts > 1]).all()
    filt = _constant_velocity(model, t, qa, p0, smooth=False)
    np.testing.assert_array_equal(filt[0], xf)


def test_default_simulation_is_consistent_with_the_default_weighting(tmp_path):
    """The simulator's default phase noise is the estimator's default weighting (σ² = a² + b²/sin²el,
    a = b = 3 mm per receiver): NIS per dof ≈ 1 and NEES ≈ its dof (with 2 mm white noise they
    were ≈ 0.11 and ≈ 0.2 of 3)."""
    from cdgps_cli.sim.gnss import simulate_gnss_pair

    simulate_gnss_pair(tmp_path, duration_s=1200.0, seed=7, n_slips=3, random_walk_sigma=0.0005)
    pipeline(tmp_path, tmp_path / "config.toml", "--smooth")
    r = run_cli("evaluate", "--truth", tmp_path, "--estimate", tmp_path / "states.mcap", "--json")
    assert r.exit_code == 0, r.output
    ev = json.loads(r.stdout)
    assert 0.9 < ev["nis"]["mean_per_dof"] < 1.1 and ev["nis"]["fraction_in_interval95"] > 0.9
    assert 1.5 < ev["nees"]["mean"] < 4.5 and ev["within_3sigma_fraction"] > 0.95


def test_random_walk_float_reduces_to_static_and_fixes_a_wandering_rover():
    t0 = gps_seconds(2024, 1, 1)
    nav = synthetic_gps_nav(t0, 3600.0)
    n = 1800
    gen = np.random.default_rng(1)
    off = np.cumsum(gen.normal(0, 0.002, size=(n, 3)), axis=0)        # wanders ~8 cm in 30 min
    off[0] = 0
    out = {}
    for label, offs in (("static", None), ("moving", off)):
        sim = simulate_static_pair(nav, MASTER_XYZ, ROVER_XYZ, t0, float(n), 1.0, seed=2, rover_offset_enu_m=offs,
                                   slips=[("rover", "G05", t0 + 900, 3)])
        runs = ((("static", (1e-3,) * 3), ("random_walk", (1e-9,) * 3)) if offs is None else
                (("static", (1e-3,) * 3), ("random_walk", (2e-3,) * 3)))       # the four solves compared below
        for motion, sig in runs:
            r = solve_static_baseline(Station("B", sim["base_header"], sim["base"]), Station("R", sim["rover_header"], sim["rover"]),
                                      nav, BaselineOptions(motion=motion, random_walk_sigma=sig, kinematic_series=False))
            out[(label, motion, sig[0])] = r["ambiguities"]
    a, b = out[("static", "static", 1e-3)], out[("static", "random_walk", 1e-9)]
    fa = [s["float_cycles"] for s in a["segments"] if not s["pivot"]]
    fb = [s["float_cycles"] for s in b["segments"] if not s["pivot"]]
    np.testing.assert_allclose(fb, fa, atol=1e-4)                       # a vanishing walk = the static float
    def ints(amb):
        return [s["integer"] for s in amb["segments"]]

    # the wandering rover (same seed: same integers as the static one): the static float model gets
    # some wrong or leaves some unfixed; the random-walk float fixes all, correctly
    ms, mr = out[("moving", "static", 1e-3)], out[("moving", "random_walk", 2e-3)]
    assert ints(ms) != ints(a)
    assert mr["n_fixed"] == mr["n_estimated"] and mr["ratio"] > 10 and ints(mr) == ints(a)


def test_init_raises_a_walk_too_slow_for_the_simulated_rover(tmp_path):
    """Simulator truth: a rover random-walking at 5 cm/√s (≈ 1 m in 10 min) with the simulator's phase noise at the
    default weighting.  At the true σ the random-walk float's NIS per SD row is under 1 (each epoch's NIS has a degree
    of freedom per DD, a row fewer per group; measured 0.73) and nothing is raised.  Configured at 0.5 mm/√s its NIS
    is 47: init solves it again at 5 mm/√s (NIS 5.4, at most UNCHECKED_FIX_NIS_MAX), fixes every integer, the same
    integers as at the true σ, and says so."""
    from cdgps_cli.config.options import UNCHECKED_FIX_NIS_MAX
    from cdgps_cli.sim.gnss import simulate_gnss_pair

    simulate_gnss_pair(tmp_path, duration_s=600.0, seed=7, n_slips=3, random_walk_sigma=0.05)
    text = (tmp_path / "config.toml").read_text()
    assert "sigma_m_per_sqrt_s = 0.05" in text
    got = {}
    for sigma in ("0.05", "0.0005"):
        (tmp_path / f"c{sigma}.toml").write_text(text.replace("sigma_m_per_sqrt_s = 0.05",
                                                             f"sigma_m_per_sqrt_s = {sigma}"))
        for args in (("ingest", "--config", tmp_path / f"c{sigma}.toml", "-o", tmp_path / f"r{sigma}.mcap"),
                     ("init", tmp_path / f"r{sigma}.mcap", "-o", tmp_path / f"i{sigma}.json")):
            r = run_cli("-q", *args)
            assert r.exit_code == 0, r.output
        got[sigma] = json.loads((tmp_path / f"i{sigma}.json").read_text())
    true, slow = got["0.05"]["rovers"]["rover"], got["0.0005"]["rovers"]["rover"]
    assert "random_walk_tried" not in true["float"] and 0.5 < true["float"]["random_walk_nis_per_row"] < 1.0
    tried = slow["float"]["random_walk_tried"]
    assert tried[0]["nis_per_row"] > 3 * UNCHECKED_FIX_NIS_MAX and tried[-1]["nis_per_row"] <= UNCHECKED_FIX_NIS_MAX
    assert [t["sigma_m_per_sqrt_s"][0] for t in tried] == [0.0005, 0.005]
    assert true["n_fixed"] == true["n_estimated"] == slow["n_fixed"] == slow["n_estimated"] > 5

    def ints(init):
        return [(b["satellite"], b["first"], b["integer_cycles"]) for b in init["biases"]]
    assert ints(got["0.05"]) == ints(got["0.0005"])
    assert any("did not hold the rover's motion" in w for w in slow["warnings"])

    # at the true σ, one 1 km code blunder at one epoch lifts the NIS above 10; raising σ does not lower it, so it
    # stops at once, keeps the configured σ, and says the misfit is not the motion (every integer still fixed)
    from tests.pipeline.test_init_real_edits import _slip
    rover = (tmp_path / "rover.rnx").read_text()
    sat = next(ln[:3] for ln in rover.splitlines()[40:] if ln[:1] == "G")
    (tmp_path / "rover.rnx").write_text(_slip(_slip(rover, sat, "C1C", 300, 1000.0), sat, "C1C", 301, -1000.0))
    for args in (("ingest", "--config", tmp_path / "c0.05.toml", "-o", tmp_path / "blunder.mcap"),
                 ("init", tmp_path / "blunder.mcap", "-o", tmp_path / "blunder.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, r.output
    blunder = json.loads((tmp_path / "blunder.json").read_text())["rovers"]["rover"]
    tried = blunder["float"]["random_walk_tried"]
    assert len(tried) == 2 and tried[0]["nis_per_row"] > UNCHECKED_FIX_NIS_MAX and tried[1]["nis_per_row"] > 0.5 * tried[0]["nis_per_row"]
    assert blunder["float"]["random_walk_sigma_used_m_per_sqrt_s"] == [0.05] * 3
    assert blunder["n_fixed"] == blunder["n_estimated"]
    assert any("so the misfit is not the rover's motion" in w for w in blunder["warnings"]), blunder["warnings"]
    assert not any("did not hold" in w for w in true["warnings"])


@pytest.fixture(scope="module")
def short_pair(tmp_path_factory):
    """`cdgps simulate-gnss --duration 60` (default seed), once for the two refusal tests below (read only)."""
    d = tmp_path_factory.mktemp("short") / "s"
    assert run_cli("-q", "simulate-gnss", "--duration", "60", "--out", d).exit_code == 0
    return d


def test_single_receiver_run_is_refused_by_init(short_pair, tmp_path):
    d = short_pair
    r = run_cli("-q", "ingest", "--rinex", f"b={d / 'base.rnx'}", "--nav", d / "nav.rnx", "-o", tmp_path / "one.mcap")
    assert r.exit_code == 0, r.output
    r = run_cli("init", tmp_path / "one.mcap", "-o", tmp_path / "i.json")
    assert r.exit_code == 2 and "only the master receiver 'b'" in r.stderr and not (tmp_path / "i.json").exists()


def test_a_solver_error_names_the_run_and_the_files(short_pair, tmp_path, monkeypatch):
    # 'cdgps init' of a RUN from a badly damaged u-blox log said only 'float solution: the normal equations are
    # singular (...)', naming no file; 'cdgps baseline' the same
    import cdgps_cli.pipeline.baseline_job as baseline_job
    import cdgps_cli.pipeline.gnss as gnss

    def singular(*args, **kwargs):
        raise CdgpsError("float solution: the normal equations are singular (too few satellites or epochs for the unknowns)")

    d = short_pair
    rinex = sorted(d.glob("*.rnx"))
    obs = [p for p in rinex if p.name != "nav.rnx"]
    args = [x for k, p in zip("ab", obs) for x in ("--rinex", f"{k}={p}")] + ["--nav", d / "nav.rnx", "--master", "a"]
    r = run_cli("-q", "ingest", *args, "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output
    monkeypatch.setattr(gnss, "solve_static_baseline", singular)
    monkeypatch.setattr(baseline_job, "solve_static_baseline", singular)
    r = run_cli("init", tmp_path / "run.mcap", "-o", tmp_path / "i.json")
    assert r.exit_code == 2 and f"{tmp_path / 'run.mcap'}: baseline a → b: float solution: the normal equations" in r.stderr, r.output
    r = run_cli("baseline", *args, "-o", tmp_path / "b.json")
    assert r.exit_code == 2 and f"baseline a ({obs[0]}) → b ({obs[1]}): float solution" in r.stderr, r.output
    assert not (tmp_path / "i.json").exists() and not (tmp_path / "b.json").exists()


@pytest.mark.parametrize("model", ["random_walk", "static"])
def test_a_rover_without_some_epochs_has_states_at_every_epoch(rw_sim, tmp_path, model):
    """Two rovers, the second the first's file with 60 s cut out: STATES hold both at every epoch of the common
    axis, so ``export`` writes every row (it refused the whole file: "epochs with non-finite states").  Static:
    the static solution holds in the gap.  Random walk: the filter and smoother carry the walk through the gap,
    σ growing to its middle and back (σ² of a random walk bridged over 60 s: about σ_rw² · 30 s on top of the
    neighbours'); far from the gap the second rover's walk is the first's (< 1e-6 m: the same data), near it
    within its own 3σ (measured: 2.7 mm at the gap's edge, σ 3–5 mm there, 8–9 mm in its middle)."""
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s

    src, _ = rw_sim
    text = (src / "rover.rnx").read_text()
    t = epoch_times_gps_s(text)
    (tmp_path / "rover2.rnx").write_text(edit_rinex3_obs(text, keep=lambda s: not (t[600] <= s < t[660])))
    cfg = (src / "config.toml").read_text()
    if model == "static":
        cfg = "\n".join(ln for ln in cfg.replace('model = "random_walk"', 'model = "static"').splitlines()
                        if not ln.startswith("sigma_m_per_sqrt_s"))
    cfg = cfg.replace('rinex = "base.rnx"', f'rinex = "{src / "base.rnx"}"').replace(
        'rinex = "rover.rnx"', f'rinex = "{src / "rover.rnx"}"').replace('nav = ["nav.rnx"]', f'nav = ["{src / "nav.rnx"}"]')
    cfg += f'\n[gnss.antennas."rover2"]\nrinex = "{tmp_path / "rover2.rnx"}"\n'
    (tmp_path / "config.toml").write_text(cfg)
    for args in (("ingest", "--config", tmp_path / "config.toml", "-o", tmp_path / "run.mcap"),
                 ("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json"),
                 ("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "--smooth", "-o", tmp_path / "st.mcap"),
                 ("export", tmp_path / "st.mcap", "-o", tmp_path / "st.csv")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    df = pd.read_csv(tmp_path / "st.csv")
    assert len(df) == t.size and np.isfinite(df.to_numpy()).all()
    one, two = df[[f"rover_{c}_m" for c in "enu"]].to_numpy(), df[[f"rover2_{c}_m" for c in "enu"]].to_numpy()
    s2 = df[[f"sigma_rover2_{c}_m" for c in "enu"]].to_numpy()
    if model == "static":
        assert np.ptp(two, axis=0).max() == 0.0 and np.ptp(s2, axis=0).max() == 0.0
        assert np.allclose(two[0], one[0], atol=1e-3)          # the same antenna, the same nominal position
    else:
        d = np.abs(two - one)
        assert d[:5].max() < 1e-6 and d[-5:].max() < 1e-6          # far from the gap: the same data, the same walk
        assert (d < 3 * s2).all()                                   # near it: within the second's own σ
        mid = 630
        assert (s2[mid] > s2[595]).all() and (s2[mid] > s2[665]).all()
        walk = 0.002 ** 2 * 30.0 * 0.5           # the bridge's variance at its middle: σ² τ (T − τ) / T, T = 60 s
        assert (s2[mid] ** 2 - s2[595] ** 2 > 0.5 * walk).all()


def test_smoothing_a_static_model_is_said_to_do_nothing(static_sim, tmp_path):
    """``estimate --smooth`` on [gnss.displacement] model = "static" (its states are the static solution at every
    epoch) used to write smoothed = false without a word; it now says so, and the STATES are the unsmoothed ones."""
    from cdgps_cli.pipeline.gnss import STATIC_SMOOTH_NOTE

    tmp, _ = static_sim
    out = tmp_path / "s.mcap"
    r = run_cli("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "--smooth", "-o", out, "--json")
    assert r.exit_code == 0, r.output
    assert STATIC_SMOOTH_NOTE in json.loads(r.stdout)["warnings"]
    assert np.array_equal(States(out).q, States(tmp / "states.mcap").q)
