"""The modal structure model on GNSS double differences (cdgps_cli/pipeline/gnss_modal.py).

A small tower (configs/gnss-tower.toml: two sway modes of the top, a rigid yaw about the master)
is simulated with one GPS receiver per antenna written as RINEX; then the ordinary GNSS pipeline
(`cdgps ingest`, `cdgps init` with random-walk float → LAMBDA) and `cdgps estimate --structure`
(EKF + RTS on the DDs with time-varying satellite directions) must recover q(t) with honest 1σ and
the right integers; `export`/`evaluate` read the STATES.mcap.  Units: the joint DD covariance over
rovers with a common master, the measurement Jacobian, the frame placement.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.measurement.differencing import dd_covariance, dd_operator
from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.gnss_run import read_gnss_run
from cdgps_cli.pipeline.gnss_modal import (StructurePlacement, _h_and_H, gnss_modal_estimate, joint_dd_covariance,
                                          nominal_receiver_positions, simulate_structure_gnss)
from cdgps_cli.model.kinematics import EpochGeometry, antenna_positions
from cdgps_cli.io.states import States
from cdgps_cli.pipeline.gnss import rover_segments

ROOT = Path(__file__).resolve().parents[2]
TOWER = ROOT / "configs" / "gnss-tower.toml"


def run_cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def tower(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tower")
    cfg = load_config(TOWER)
    sim = simulate_structure_gnss(tmp, cfg, duration_s=600.0, seed=3, random_walk_sigma=0.01)
    for args in (("ingest", "--config", tmp / "config.toml", "-o", tmp / "run.mcap"),
                 ("init", tmp / "run.mcap", "-o", tmp / "init.json"),
                 ("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "--structure", TOWER, "--smooth",
                  "-o", tmp / "states.mcap"),
                 ("export", tmp / "states.mcap", "--csv", tmp / "states.csv")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    ev = {}
    for topic in ("/cdgps/state", "/cdgps/state_filtered"):
        st = States(tmp / "states.mcap", topic=topic)
        truth = pd.read_csv(tmp / "truth.csv")
        ev[topic] = st, truth
    r = run_cli("evaluate", "--truth", tmp, "--estimate", tmp / "states.mcap", "--json", "--converge-s", "30")
    assert r.exit_code == 0, r.output
    return tmp, cfg, sim, json.loads((tmp / "init.json").read_text()), json.loads(r.stdout), ev


@pytest.fixture(scope="module")
def tower_run(tower):
    """The tower's RUN.mcap read once (read only by the tests)."""
    return read_gnss_run(tower[0] / "run.mcap")


@pytest.fixture(scope="module")
def modal_default(tower, tower_run, tmp_path_factory):
    """gnss_modal_estimate on the integer INIT with the default 60 s batch-init window (the same call
    test_float_only_init_is_fixed_by_the_modal_batch_init and test_the_window_grows_until_every_integer_is_fixed
    compare with; computed once)."""
    from cdgps_cli.pipeline.gnss_modal import INIT_WINDOW_S

    assert INIT_WINDOW_S == 60.0
    tmp, *_ = tower
    text = (tmp / "init.json").read_text()
    return gnss_modal_estimate(tower_run, json.loads(text), text, tower[1], tmp_path_factory.mktemp("modal") / "z.mcap")


def test_integers_fixed_and_right(tower):
    tmp, cfg, sim, init, _, _ = tower
    truth = sim["integers"]                         # per receiver and satellite (one lock segment each here)
    m = init["master"]
    for r, rov in init["rovers"].items():
        assert rov["solution"] == "fixed" and rov["n_fixed"] == rov["n_estimated"] >= 5
        segs = rover_segments(init, r)
        assert len({s["sat"] for s in segs}) == len(segs)
        piv = [s["sat"] for s in segs if s["pivot"]]
        assert len(piv) == 1
        sd = {s: truth[r][s] - truth[m][s] for s in truth[r]}
        for s in segs:
            if not s["pivot"]:
                assert s["integer"] == sd[s["sat"]] - sd[piv[0]], (r, s["sat"])


def test_modal_states_recover_the_truth_with_honest_sigma(tower):
    tmp, cfg, sim, init, ev, series = tower
    assert json.loads(States(tmp / "states.mcap").metadata["options"])["model"] == "gnss-modal"
    # q really moves: centimetres of sway, 1e-2 rad of yaw (≈ 3 cm at the rovers)
    assert all(hi - lo > 0.02 for c, (lo, hi) in sim["q_range"].items() if c != "psi")
    assert sim["q_range"]["psi"][1] - sim["q_range"]["psi"][0] > 0.003
    rms = ev["rms_error"]
    assert rms["ex"] < 0.005 and rms["ey"] < 0.005 and rms["psi"] < 5e-4
    assert 1.5 < ev["nees"]["mean"] < 4.5 and ev["within_3sigma_fraction"] > 0.95       # dof 3
    assert 0.85 < ev["nis"]["mean_per_dof"] < 1.15 and ev["nis"]["fraction_in_interval95"] > 0.9
    # the smoother beats the forward filter on every coordinate
    errs = {}
    for topic, (st, truth) in series.items():
        t = np.round(truth["time_s"].to_numpy(), 3)
        k = np.searchsorted(t, np.round(st.time_s, 3))
        err = st.q[30:] - truth[[f"{n}_{'rad' if n == 'psi' else 'm'}" for n in cfg.coord_names]].to_numpy()[k][30:]
        errs[topic] = np.sqrt(np.mean(err**2, axis=0))
    assert np.all(errs["/cdgps/state"] < errs["/cdgps/state_filtered"])
    # CSV export: the structure's coordinates
    df = pd.read_csv(tmp / "states.csv")
    assert list(df.columns[:4]) == ["time_s", "psi_rad", "ex_m", "ey_m"] and len(df) == 601


def test_residuals_and_events(tower):
    tmp, *_ = tower
    st = States(tmp / "states.mcap")
    kinds = {e["kind"] for e in st.events}
    assert "reference satellite" in kinds
    assert np.nanmean(st.nis / st.nis_dof) == pytest.approx(1.0, abs=0.15)


def test_joint_dd_covariance():
    va = np.array([1.0, 2.0, 3.0])
    vm = np.array([0.5, 0.7, 0.9])
    # one rover: D diag(σ²_a + σ²_M) Dᵀ
    np.testing.assert_allclose(joint_dd_covariance([va], [vm], [["G1", "G2", "G3"]], [1]), dd_covariance(va + vm, 1))
    # two rovers sharing G2, G3: build from the undifferenced observations [M(G1..G4), a, b]
    sats_a, sats_b = ["G1", "G2", "G3"], ["G2", "G3", "G4"]
    vb = np.array([1.5, 2.5, 3.5])
    vm_all = {"G1": 0.5, "G2": 0.7, "G3": 0.9, "G4": 1.1}
    C = joint_dd_covariance([va, vb], [[vm_all[s] for s in sats_a], [vm_all[s] for s in sats_b]], [sats_a, sats_b], [0, 2])
    mi = {s: i for i, s in enumerate(vm_all)}
    Sig = np.diag(list(vm_all.values()) + va.tolist() + vb.tolist())
    rows = []
    for off, sats, ref in ((4, sats_a, 0), (7, sats_b, 2)):
        sd = np.zeros((3, 10))
        for j, s in enumerate(sats):
            sd[j, off + j] = 1.0
            sd[j, mi[s]] = -1.0
        rows.append(dd_operator(3, ref) @ sd)
    D = np.vstack(rows)
    np.testing.assert_allclose(C, D @ Sig @ D.T, atol=1e-12)


@pytest.mark.parametrize("config", [TOWER, ROOT / "configs" / "teague-1995-2dof.toml"])
def test_measurement_jacobian_matches_finite_differences(config):
    """h and H of the DD model, also with a master that moves with q (the 1995 model's master is on hub 1)."""
    cfg = load_config(config)
    geo = EpochGeometry(cfg)
    U = np.asarray(cfg.mode_shapes)
    nm = cfg.n_modes
    ant = np.array([i for i in range(len(cfg.antenna_names)) if i != cfg.master_index])
    p0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)))[0]
    d_hdr = p0[ant] - p0[cfg.master_index]
    gen = np.random.default_rng(0)
    slot = np.repeat(np.arange(ant.size), 3)
    srows = gen.normal(size=(slot.size, 3))
    xi = gen.normal(scale=0.2, size=nm)
    h, H = _h_and_H(geo, U, xi, cfg.master_index, ant, slot, srows, d_hdr)
    eps = 1e-6
    for j in range(nm):
        dx = np.zeros(nm)
        dx[j] = eps
        hp, _ = _h_and_H(geo, U, xi + dx, cfg.master_index, ant, slot, srows, d_hdr)
        hm, _ = _h_and_H(geo, U, xi - dx, cfg.master_index, ant, slot, srows, d_hdr)
        np.testing.assert_allclose(H[:, j], (hp - hm) / (2 * eps), atol=1e-7)
    h0, _ = _h_and_H(geo, U, np.zeros(nm), cfg.master_index, ant, slot, srows, d_hdr)
    np.testing.assert_allclose(h0, 0.0, atol=1e-12)                  # nominal = header: no signal


def test_placement_axes():
    xm = (-3978242.4348, 3382841.1715, 3649902.7667)
    lat, lon, _ = ecef_to_geodetic(np.asarray(xm))
    E = enu_matrix(lat, lon)
    R = StructurePlacement(xm).rotation()
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(E @ R, np.eye(3), atol=1e-12)          # default: x east, y north, z up
    R0 = StructurePlacement(xm, 0.0).rotation()
    np.testing.assert_allclose(E @ R0, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)   # x north, y west
    cfg = load_config(TOWER)
    nom = nominal_receiver_positions(cfg, StructurePlacement(xm, 0.0))
    np.testing.assert_allclose(nom["base"], xm)
    np.testing.assert_allclose(E @ (nom["r1"] - np.asarray(xm)), [0.0, 3.0, 8.0], atol=1e-9)   # 3 m north, 8 m up


def test_a_wrong_placement_shows_in_the_nis(tower, tmp_path):
    """The structure turned by 90° about the vertical (x north instead of east): the DDs no longer fit."""
    tmp, *_ = tower
    r = run_cli("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "--structure", TOWER,
                "--x-axis-azimuth-deg", "0", "--json", "-o", tmp_path / "rot.mcap")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["mean_nis_per_dof"] > 20 and s["placement"]["x_axis_azimuth_deg"] == 0.0
    assert max(s["nominal_mismatch_m"].values()) > 3.0


def test_cli_refuses_bad_structure_mappings(tower, tmp_path):
    tmp, *_ = tower
    base = ("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "-o", tmp_path / "x.mcap")
    r = run_cli("-q", *base, "--structure", TOWER, "--receiver", "r2=nope")
    assert r.exit_code != 0 and "without a rover receiver" in r.output and "r2 → nope" in r.output
    r = run_cli("-q", *base, "--structure", TOWER, "--receiver", "zz=r1")
    assert r.exit_code != 0 and "not an antenna" in r.output
    r = run_cli("-q", *base, "--receiver", "r1=r1")
    assert r.exit_code != 0 and "--receiver needs --structure" in r.output
    assert not (tmp_path / "x.mcap").exists()


def test_float_only_init_is_fixed_by_the_modal_batch_init(tower, tower_run, modal_default, tmp_path):
    """A float-only INIT has no integers: the modal batch initialization fixes the window's own
    (the same as the integer INIT's, which test_integers_fixed_and_right checks against the truth);
    without it the estimate is refused."""
    tmp, cfg, *_ = tower
    assert run_cli("-q", "init", tmp / "run.mcap", "--float-only", "-o", tmp_path / "float.json").exit_code == 0
    text = (tmp_path / "float.json").read_text()
    run = tower_run
    with pytest.raises(CdgpsError, match="no fixed integers"):
        gnss_modal_estimate(run, json.loads(text), text, cfg, tmp_path / "x.mcap", batch_init=False)
    assert not (tmp_path / "x.mcap").exists()
    out = gnss_modal_estimate(run, json.loads(text), text, cfg, tmp_path / "y.mcap", init_window_s=60.0)
    mi = out["modal_init"]
    assert mi["n_fixed"] == mi["n_segments"] >= 10 and mi["agree_with_init"]["compared"] == 0
    ref = modal_default                     # gnss_modal_estimate(run, the integer INIT, its text, cfg, …): defaults
    assert ref["modal_init"]["agree_with_init"]["equal"] == ref["modal_init"]["agree_with_init"]["compared"] >= 10
    assert [s["integer_cycles"] for s in mi["segments"]] == [s["integer_cycles"] for s in ref["modal_init"]["segments"]]


def test_simulate_gnss_structure_command_is_deterministic(tmp_path):
    """The simulator as a command: RINEX per antenna + nav + truth + config; same seed → same bytes."""
    for d in ("a", "b"):
        r = run_cli("-q", "simulate-gnss-structure", TOWER, "--duration", "60", "--seed", "5", "--out", tmp_path / d)
        assert r.exit_code == 0, r.output
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert {"truth.csv", "truth.json", "config.toml"} <= set(files) and any(f.endswith(".rnx") for f in files)
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    r = run_cli("simulate-gnss-structure", TOWER, "--duration", "-1", "--out", tmp_path / "c")
    assert r.exit_code == 2 and "--duration" in r.output and "Traceback" not in r.output and not (tmp_path / "c").exists()


@pytest.mark.parametrize("args,message", [
    (("--x-axis-azimuth-deg", "nan"), "--x-axis-azimuth-deg': 'nan' is not a finite number"),   # issue 12: the CLI float type
    (("--master-xyz", "0,0,0"), "master_ecef_m must be 3 finite ECEF coordinates"),
])
def test_simulate_gnss_structure_bad_input_leaves_nothing(tmp_path, args, message):
    out = tmp_path / "sim"
    r = run_cli("simulate-gnss-structure", TOWER, "--duration", "30", *args, "--out", out)
    assert r.exit_code == 2 and message in r.output, r.output
    assert not out.exists()


def test_init_with_structure_writes_the_modal_init_and_estimate_uses_it(tower, tower_run, tmp_path):
    """`cdgps init RUN --structure S` adds INIT.json's modal_init (the batch initialization on the
    first 60 s); `estimate --structure S` applies it instead of solving the window again."""
    tmp, cfg, sim, *_ = tower
    r = run_cli("-q", "init", tmp / "run.mcap", "--structure", TOWER, "-o", tmp_path / "init.json")
    assert r.exit_code == 0, r.output
    init = json.loads((tmp_path / "init.json").read_text())
    mi = init["modal_init"]
    assert mi["structure_sha256"] == cfg.sha256 and mi["window"]["epochs"] == 60
    assert mi["n_fixed"] == mi["n_segments"] >= 10 and mi["agree_with_init"]["equal"] == mi["agree_with_init"]["compared"]
    text = (tmp_path / "init.json").read_text()
    run = tower_run
    used = gnss_modal_estimate(run, init, text, cfg, tmp_path / "a.mcap")["modal_init"]
    assert used is not None and used["segments"] == mi["segments"] and "structure_sha256" in used
    # another azimuth: the stored record does not apply, the window is solved again
    other = gnss_modal_estimate(run, init, text, cfg, tmp_path / "b.mcap", x_axis_azimuth_deg=80.0)["modal_init"]
    assert "structure_sha256" not in other
    r = run_cli("-q", "init", tmp / "run.mcap", "--receiver", "r1=r1", "-o", tmp_path / "bad.json")
    assert r.exit_code == 2 and "--receiver needs --structure" in r.output and not (tmp_path / "bad.json").exists()


def test_the_window_grows_until_every_integer_is_fixed(tower, tower_run, modal_default, tmp_path, monkeypatch):
    """A first window whose integers are not all fixed is extended ×1.5 up to 3× (and no further);
    each attempt is recorded.  Windows under 25 epochs are made to fail here, so the growth path is
    taken whatever the data: 10 s → 15 s → 22.5 s → 30 s (the cap), where the real fix stands."""
    from cdgps_cli.estimation import model_init

    real = model_init.model_batch_init

    def weak(model, dyn, epochs, *args, **kwargs):
        res = real(model, dyn, epochs, *args, **kwargs)
        if len(epochs) < 25:
            res.fixed = np.zeros_like(res.fixed)
            res.note = "made to fail by the test"
        return res

    monkeypatch.setattr(model_init, "model_batch_init", weak)
    tmp, cfg, *_ = tower
    run = tower_run
    text = (tmp / "init.json").read_text()
    mi = gnss_modal_estimate(run, json.loads(text), text, cfg, tmp_path / "g.mcap", init_window_s=10.0)["modal_init"]
    tried = mi["windows_tried"]
    assert [w["window_s"] for w in tried] == [10.0, 15.0, 22.5, 30.0], tried
    solved = [w for w in tried if "refused" not in w]     # a window may be refused (not converged): skipped
    assert all(w["n_fixed"] == 0 for w in solved if w["epochs"] < 25)
    assert solved[-1]["n_fixed"] == mi["n_fixed"] and mi["window"]["epochs"] == solved[-1]["epochs"]
    # a window fixed at once is not extended and records no attempts (the default window, 60 s, unpatched)
    mi60 = modal_default["modal_init"]
    assert "windows_tried" not in mi60 and mi60["window"]["epochs"] == 60


def test_the_set_up_keeps_only_what_the_modal_filter_reads(tower, tower_run):
    """Issue 29: each rover's table keeps neither the baseline's result nor its working arrays, and of
    its SD table only the fields read after the set-up (the same arrays, not copies)."""
    from cdgps_cli.io.gnss_run import read_gnss_run
    from cdgps_cli.pipeline import gnss_modal
    from cdgps_cli.pipeline.gnss import _stations, solve_with_init_integers

    tmp, cfg, _, init, _, _ = tower
    run = tower_run
    su = gnss_modal._modal_setup(run, init, cfg, None, 90.0, lambda m: None)
    for tb in su.tabs:
        assert tb["res"] is None and set(tb["w"]) == {"known_seg"}
        assert set(vars(tb["d"])) == set(gnss_modal._SETUP_DATA_FIELDS)
    _, w, _, _ = solve_with_init_integers(run, init, run.rovers[0], _stations(run))
    d, slim = w["data"], su.tabs[0]["d"]
    for k in gnss_modal._SETUP_DATA_FIELDS:
        a = getattr(slim, k)
        assert a == getattr(d, k) if isinstance(a, list) else np.array_equal(a, getattr(d, k))
    assert np.array_equal(su.tabs[0]["w"]["known_seg"], w["known_seg"])
