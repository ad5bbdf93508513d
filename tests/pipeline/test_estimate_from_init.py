"""``estimate`` on a GNSS run never solves the baseline again (issue 28 item 1), also when INIT leaves
ambiguities float: GLONASS (FDMA) segments on the mosaic pair (GPS L1 + GLONASS G1) and a partially
fixed INIT (one GEONET integer withdrawn).  The batch solver is made to raise; the states are INIT's
(an engine INIT: the engine's float solution conditioned on INIT's integers, as ``init`` made it), and
within 0.1 mm of what the former path (the batch solved again from INIT's integers) gives."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.estimation import ambiguity, baseline
from cdgps_cli.io.gnss_run import read_gnss_run
from cdgps_cli.io.states import States
from cdgps_cli.pipeline import gnss
from tests._shared import REPO_ROOT, run_cli

SHARED = REPO_ROOT.parent / "shared" / "data"
MOSAIC = SHARED / "real-pairs" / "mosaic-static"
GEONET_OBS = SHARED / "rinex" / "30400920.05o"
pytestmark = pytest.mark.skipif(not (MOSAIC.exists() and GEONET_OBS.exists()), reason="../shared/data absent")


def _ingest_init(d: Path, lines: list) -> dict:
    (d / "run.toml").write_text("\n".join(lines) + "\n")
    for args in (("ingest", "--config", d / "run.toml", "-o", d / "run.mcap"),
                 ("init", d / "run.mcap", "-o", d / "init.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    return json.loads((d / "init.json").read_text())


@pytest.fixture(scope="module")
def mosaic_gr(tmp_path_factory):
    d = tmp_path_factory.mktemp("gr")
    m = MOSAIC
    return d, _ingest_init(d, ["[gnss]", 'master = "base"', f'nav = ["{m / "base.nav"}"]', 'signals = ["G:L1", "R:G1"]',
                               '[gnss.antennas."base"]', f'rinex = "{m / "base.obs"}"',
                               '[gnss.antennas."rover"]', f'rinex = "{m / "rover.obs"}"'])


@pytest.fixture(scope="module")
def mosaic_partial(tmp_path_factory):
    d = tmp_path_factory.mktemp("partial")
    m = MOSAIC
    (d / "run.toml").write_text("\n".join([
        "[gnss]", 'master = "base"', f'nav = ["{m / "base.nav"}"]',
        'signals = ["G:L1", "G:L2", "E:E1", "E:E5b", "C:B1I"]', "[gnss.displacement]", 'model = "random_walk"',
        "sigma_m_per_sqrt_s = 0.3", '[gnss.antennas."base"]', f'rinex = "{m / "base.obs"}"',
        '[gnss.antennas."rover"]', f'rinex = "{m / "rover.obs"}"']) + "\n")
    for args in (("ingest", "--config", d / "run.toml", "-o", d / "run.mcap"),
                 ("init", d / "run.mcap", "--ratio", "500", "-o", d / "init.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    return d, json.loads((d / "init.json").read_text())


@pytest.fixture(scope="module")
def geonet(tmp_path_factory):
    d = tmp_path_factory.mktemp("geonet")
    text = (REPO_ROOT / "configs" / "geonet-0759-3040.toml").read_text().replace("../../shared", str(SHARED.parent))
    return d, _ingest_init(d, text.splitlines())


def _no_batch(monkeypatch):
    """Every way of solving the baseline again raises."""
    def boom(*a, **k):
        raise AssertionError("the baseline was solved again")
    monkeypatch.setattr(gnss, "solve_static_baseline", boom)
    monkeypatch.setattr(baseline, "solve_static_baseline", boom)
    for name in ("_float_solution", "_integer_fix", "_fixed_solution", "resolve"):
        monkeypatch.setattr(baseline, name, boom)
    monkeypatch.setattr(ambiguity, "resolve", boom)


def _estimate(d: Path, init: dict, name: str) -> States:
    (d / f"{name}.json").write_text(json.dumps(init))
    r = run_cli("-q", "estimate", d / "run.mcap", "--init", d / f"{name}.json", "-o", d / f"{name}.mcap")
    assert r.exit_code == 0, r.output
    return States(d / f"{name}.mcap")


def _former_path(d: Path, init: dict, rover: str) -> np.ndarray:
    """The batch solved again from INIT's integers (the former estimate path)."""
    run = read_gnss_run(d / "run.mcap")
    st = gnss._stations(run)
    opt = baseline.BaselineOptions(**{k: (tuple(v) if isinstance(v, list) else v)
                                      for k, v in init["rovers"][rover]["options"].items()
                                      if k in baseline.BaselineOptions.__dataclass_fields__})
    res = baseline.solve_static_baseline(st[run.master], st[rover], run.nav, opt,
                                         master_xyz=gnss._position_args(run, run.master),
                                         rover_xyz=gnss._position_args(run, rover),
                                         integers=gnss._integers_from_init(init, rover))
    return np.array(res["fixed"]["enu_m"]), np.array(res["fixed"]["sigma_enu_m"])


def _without_solution_values(init: dict) -> dict:
    """A copy of INIT without its float segments' values at the solution (as INIT was before it held them)."""
    out = json.loads(json.dumps(init))
    for b in out["biases"]:
        b.pop("solution_cycles", None)
        b.pop("solution_sigma_cycles", None)
    return out


def _no_engine(monkeypatch):
    """Neither the batch nor the static engine may solve."""
    def boom(*a, **k):
        raise AssertionError("the static engine ran again")
    _no_batch(monkeypatch)
    monkeypatch.setattr(baseline, "_run_engine", boom)


def test_glonass_init_is_not_solved_again(mosaic_gr, monkeypatch):
    """GLONASS float segments: INIT's values of them at its solution are evaluated, the engine does not run; the
    states are those of the engine's float conditioned on INIT's integers (an INIT without those values)."""
    d, init = mosaic_gr
    rov = init["rovers"]["rover"]
    assert rov["solver"] == "static_engine" and rov.get("n_float_glonass", 0) > 0
    former, _ = _former_path(d, init, "rover")
    conditioned = _estimate(d, _without_solution_values(init), "gr_engine")
    with monkeypatch.context() as mp:
        _no_engine(mp)
        st = _estimate(d, init, "gr")
    assert st.q[0].tolist() == rov["fixed"]["enu_m"]                   # INIT's solution, bit for bit
    assert st.sigma_q[0].tolist() == rov["fixed"]["sigma_enu_m"]
    assert np.max(np.abs(st.q[0] - former)) < 1e-4
    np.testing.assert_allclose(st.q, conditioned.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(st.sigma_q, conditioned.sigma_q, rtol=1e-12, atol=0)


def test_a_partially_fixed_engine_init_is_evaluated_not_solved(mosaic_partial, monkeypatch):
    """A real partially fixed engine INIT (the mosaic pair, every signal, random walk 0.3 m/√s, ratio 500: 32 of
    41 integers): estimate evaluates INIT's position, integers and float segments' values (the engine does not
    run); its states equal those of the engine's float conditioned on INIT's integers, the former path."""
    d, init = mosaic_partial
    rov = init["rovers"]["rover"]
    assert rov["solver"] == "static_engine" and rov["solution"] == "partially fixed", rov["solution"]
    floats = [b for b in init["biases"] if not b["fixed"] and not b["pivot"]]
    assert floats and all(isinstance(b.get("solution_cycles"), float) for b in floats)
    assert np.shape(rov["fixed"]["cov_enu_m2"]) == (3, 3)
    conditioned = _estimate(d, _without_solution_values(init), "partial_engine")
    with monkeypatch.context() as mp:
        _no_engine(mp)
        st = _estimate(d, init, "partial_given")
        run = read_gnss_run(d / "run.mcap")
        res, _, _, _ = gnss.solve_with_init_integers(run, init, "rover", gnss._stations(run))
    assert res["solver"] == "given (INIT's solution, its float ambiguities too)"
    assert res["solution"] == "partially fixed" and res["ambiguities"]["n_fixed"] == rov["n_fixed"]
    np.testing.assert_allclose(st.q, conditioned.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(st.sigma_q, conditioned.sigma_q, rtol=1e-12, atol=0)
    # a float segment's value moved by a tenth of a cycle is not INIT's solution on these data: the engine serves
    moved = json.loads(json.dumps(init))
    next(b for b in moved["biases"] if b.get("solution_cycles") is not None)["solution_cycles"] += 0.1
    res2, _, _, _ = gnss.solve_with_init_integers(run, moved, "rover", gnss._stations(run))
    assert res2["solver"] == "static_engine (integers given)"


def test_partially_fixed_init_is_not_solved_again(geonet, monkeypatch):
    """One integer withdrawn from GEONET's engine INIT: the engine conditions on the others (not the batch), and
    a batch INIT of that partial solution is evaluated at its position (the floats at it), equal to the batch's."""
    d, init = geonet
    assert init["rovers"]["0759"]["solver"] == "static_engine"
    part = json.loads(json.dumps(init))
    b = next(b for b in part["biases"] if not b["pivot"])
    b.update(fixed=False, integer_cycles=None)
    former, former_sigma = _former_path(d, part, "0759")
    with monkeypatch.context() as mp:
        _no_batch(mp)
        st = _estimate(d, part, "partial")
        run = read_gnss_run(d / "run.mcap")
        res, w, _, _ = gnss.solve_with_init_integers(run, part, "0759", gnss._stations(run))
    assert res["solver"] == "static_engine (integers given)" and res["solution"] == "partially fixed"
    assert res["ambiguities"]["n_fixed"] == init["n_fixed"] - 1
    assert np.max(np.abs(st.q[0] - former)) < 1e-4
    # the same partial solution as a batch INIT: taken at its position, the float ambiguity solved at it
    part["rovers"]["0759"]["solver"] = "batch (test)"
    part["rovers"]["0759"]["fixed"]["enu_m"] = former.tolist()
    with monkeypatch.context() as mp:
        _no_batch(mp)
        res2, w2, _, _ = gnss.solve_with_init_integers(run, part, "0759", gnss._stations(run))
    assert res2["solver"] == "given (INIT's position, float ambiguities at it)"
    assert w2["x_final"].tolist() == former.tolist()
    np.testing.assert_allclose(np.sqrt(np.diag(w2["q_final"])), former_sigma, rtol=1e-6)


def test_float_only_init_is_not_solved_again(geonet, monkeypatch):
    """A float-only INIT: an engine one is the engine's float solution again (INIT's, bit for bit); a batch one
    is evaluated at its float position, equal to the batch's float solution."""
    d, _ = geonet
    r = run_cli("-q", "init", d / "run.mcap", "--float-only", "-o", d / "float.json")
    assert r.exit_code == 0, r.output
    init = json.loads((d / "float.json").read_text())
    rov = init["rovers"]["0759"]
    assert rov["solver"] == "static_engine" and rov["fixed"] is None
    run = read_gnss_run(d / "run.mcap")
    former = baseline.solve_static_baseline(*(gnss._stations(run)[n] for n in (run.master, "0759")), run.nav,
                                            baseline.BaselineOptions.from_gnss_config(run.cfg, kinematic_series=False,
                                                                                      fix=False),
                                            master_xyz=gnss._position_args(run, run.master),
                                            rover_xyz=gnss._position_args(run, "0759"))["float"]
    with monkeypatch.context() as mp:
        _no_batch(mp)
        st = _estimate(d, init, "float_states")
        assert st.q[0].tolist() == rov["float"]["enu_m"] and st.sigma_q[0].tolist() == rov["float"]["sigma_enu_m"]
        init["rovers"]["0759"]["solver"] = "batch (test)"
        init["rovers"]["0759"]["float"]["enu_m"] = former["enu_m"]
        res, w, _, _ = gnss.solve_with_init_integers(run, init, "0759", gnss._stations(run))
    assert res["solver"] == "given (INIT's position, float ambiguities at it)" and res["solution"] == "float"
    assert w["x_final"].tolist() == former["enu_m"]
    np.testing.assert_allclose(np.sqrt(np.diag(w["q_final"])), former["sigma_enu_m"], rtol=1e-6)


def test_an_init_nothing_can_take_is_refused_not_solved_again(geonet, monkeypatch, tmp_path):
    """A batch INIT whose position is not the solution of its integers on the run, with an option only the batch
    implements: estimate exits 2 saying to run init again (no traceback, no STATES), and never solves the batch."""
    d, init = geonet
    bad = json.loads(json.dumps(init))
    rov = bad["rovers"]["0759"]
    rov["solver"], rov["options"]["epoch_alignment"] = "batch (test)", "doppler"
    rov["fixed"]["enu_m"][0] += 1e-3
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    _no_batch(monkeypatch)
    r = run_cli("estimate", d / "run.mcap", "--init", tmp_path / "bad.json", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 2 and "run 'cdgps init' again" in r.stderr and "epoch_alignment" in r.stderr, r.output
    assert f"cdgps: error: {tmp_path / 'bad.json'}: the solution of 0759 cannot be used" in r.stderr, r.stderr
    assert "Traceback" not in r.output and not (tmp_path / "s.mcap").exists()


def test_a_non_finite_init_position_is_refused(geonet, tmp_path):
    """INIT.json's fixed ENU with a NaN: exit 2 naming the file and key, no STATES (it was solved from the integers)."""
    d, init = geonet
    bad = json.loads(json.dumps(init))
    bad["rovers"]["0759"]["fixed"]["enu_m"][0] = float("nan")
    (tmp_path / "nan.json").write_text(json.dumps(bad))
    r = run_cli("estimate", d / "run.mcap", "--init", tmp_path / "nan.json", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 2 and f"{tmp_path / 'nan.json'}: rovers.0759.fixed.enu_m: expected 3 finite" in r.stderr, r.output
    assert "Traceback" not in r.output and not (tmp_path / "s.mcap").exists()


@pytest.mark.parametrize("case", ["geonet", "mosaic_gr"])
def test_the_engine_runs_before_the_batch_tables_exist(case, request, monkeypatch):
    """An INIT the engine conditions (GEONET partially fixed, mosaic GPS + GLONASS float): the engine builds its
    receiver geometry and releases it before ``_prepare``'s batch tables are built (from its arc check), then
    filters — the order of ``init``'s engine, so the two never peak together; the solver is still the engine's."""
    import gc
    import weakref
    from cdgps_cli.estimation import rtk_multi, static_engine
    d, init = request.getfixturevalue(case)
    rover = "0759" if case == "geonet" else "rover"
    init = _without_solution_values(init)        # (INIT's float segments at its solution would be evaluated)
    if case == "geonet":
        next(b for b in init["biases"] if not b["pivot"]).update(fixed=False, integer_cycles=None)
    seen, geo = [], []
    real_geo, real_prep, real_filter = rtk_multi.receiver_geometry, baseline._prepare, static_engine.static_least_squares

    def geometry(*a, **k):
        out = real_geo(*a, **k)
        geo.append(weakref.ref(out))
        seen.append("geometry")
        return out

    def prepare(*a, **k):
        gc.collect()
        seen.append("prepare" + (" (geometry held)" if any(r() is not None for r in geo) else ""))
        return real_prep(*a, **k)

    def static_filter(*a, **k):
        seen.append("filter")
        return real_filter(*a, **k)
    monkeypatch.setenv("CDGPS_SERIAL", "1")            # both receivers in this process, where the spies see them
    monkeypatch.setattr(rtk_multi, "receiver_geometry", geometry)
    monkeypatch.setattr(baseline, "_prepare", prepare)
    monkeypatch.setattr(static_engine, "static_least_squares", static_filter)
    run = read_gnss_run(d / "run.mcap")
    res, _, _, _ = gnss.solve_with_init_integers(run, init, rover, gnss._stations(run))
    assert res["solver"] == "static_engine (integers given)"
    assert seen == ["geometry", "geometry", "prepare", "filter"], seen


@pytest.mark.parametrize("cov", ["abc", [[1.0, 2.0], [3.0, 4.0]], [[float("nan"), 0, 0], [0, 1, 0], [0, 0, 1]],
                                 [[1, 0, 0], [0, -1, 0], [0, 0, 1]]])
def test_a_bad_init_covariance_is_refused(mosaic_partial, tmp_path, cov):
    """INIT's fixed.cov_enu_m2 not a symmetric 3 x 3 of finite numbers with a positive diagonal: exit 2 naming the
    file and key, no traceback, no STATES."""
    d, init = mosaic_partial
    bad = json.loads(json.dumps(init))
    bad["rovers"]["rover"]["fixed"]["cov_enu_m2"] = cov
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    r = run_cli("estimate", d / "run.mcap", "--init", tmp_path / "bad.json", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 2 and f"{tmp_path / 'bad.json'}: rovers.rover.fixed.cov_enu_m2: expected a symmetric" \
        in r.stderr, r.output
    assert "Traceback" not in r.output and not (tmp_path / "s.mcap").exists()


@pytest.mark.parametrize("residuals", ["x", {"per_satellite_rms_m": "abc"}, {"per_satellite_rms_m": {"C01:B1I": "abc"}}])
def test_a_malformed_init_residual_table_sends_estimate_to_the_engine(mosaic_partial, tmp_path, residuals):
    """INIT's residuals, which the evaluated path checks its values against, damaged: not INIT's solution on these
    data, so the engine conditions on the integers again (as for an INIT without the values), no traceback."""
    d, init = mosaic_partial
    bad = json.loads(json.dumps(init))
    rov = bad["rovers"]["rover"]
    rov["residuals"] = (dict(rov["residuals"], per_satellite_rms_m=dict(rov["residuals"]["per_satellite_rms_m"],
                                                                        **residuals["per_satellite_rms_m"]))
                        if isinstance(residuals, dict) and isinstance(residuals["per_satellite_rms_m"], dict)
                        else residuals)
    run = read_gnss_run(d / "run.mcap")
    res, _, _, _ = gnss.solve_with_init_integers(run, bad, "rover", gnss._stations(run))
    assert res["solver"] == "static_engine (integers given)"
