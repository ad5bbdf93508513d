"""Rest segments found from the data (``estimate --rest auto``, :mod:`cdgps_cli.estimation.rest`).

* the per-epoch statistic and the window sums against brute force;
* the detector on synthetic sequences with analytic answers: entry exactly after the dwell (and not
  one epoch of passes short of it), a sequence that must never enter, chatter around the entry bound
  that must not toggle, a leave at the first window above the leave bound;
* the bounds are the chi-square quantiles: on independent chi-square draws the pass rate is p_enter;
* one static seed (rest found within 5 s of the simulator's rest start, the paper's figure met) and
  one free-vibration seed (no rest) end to end; compiled kernel = numpy path with --smooth;
* report static says when the STATES ran without static mode on its segment.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.stats import chi2

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.estimation.filter import EstimateOptions, estimate
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.estimation.rest import (REST_ENTER_PROBABILITY, REST_LEAVE_PROBABILITY, detect_rest,
                                   static_mode_coverage, validate_detector, velocity_nis_series, window_sums)
from cdgps_cli.core.records import memory_run
from cdgps_cli.io.run import write_run
from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation

from _shared import REPO_ROOT as ROOT
from _shared import COMPILED, kernel

NM, W = 3, 4
B_IN = chi2.ppf(REST_ENTER_PROBABILITY, W * NM)
B_OUT = chi2.ppf(REST_LEAVE_PROBABILITY, W * NM)


def _t(n):
    return 10.0 + 0.1 * np.arange(n)


# --------------------------------------------------------------------------------------------
# the statistic


def test_velocity_nis_series_brute_force():
    rng = np.random.default_rng(1)
    N, nm = 50, 4
    M = rng.standard_normal((N, nm, nm))
    P = M @ M.transpose(0, 2, 1) + 0.1 * np.eye(nm)
    v = rng.standard_normal((N, nm))
    P[7] = -np.eye(nm)                       # not positive definite
    v[9, 2] = np.nan
    d = velocity_nis_series(v, P)
    for k in range(N):
        if k in (7, 9):
            assert d[k] == np.inf
        else:
            assert d[k] == pytest.approx(float(v[k] @ np.linalg.inv(P[k]) @ v[k]), rel=1e-10)


def test_window_sums_brute_force():
    rng = np.random.default_rng(2)
    d = rng.random(40)
    d[25] = np.inf
    D = window_sums(d, 6)
    assert np.isnan(D[:5]).all()
    for k in range(5, 40):
        assert D[k] == (np.inf if 25 <= k <= 30 else pytest.approx(d[k - 5:k + 1].sum(), rel=1e-12))
    assert np.isnan(window_sums(d[:3], 6)).all()


# --------------------------------------------------------------------------------------------
# hysteresis on synthetic sequences


def test_enters_exactly_after_the_dwell():
    # d = 100 (motion) for k < 50, then 0: the first window without motion ends at k = 50 + W − 1
    d = np.r_[np.full(50, 100.0), np.zeros(60)]
    t = _t(len(d))
    segs, ev = detect_rest(t, d, NM, W, dwell=10)
    k0 = 50 + W - 1
    assert segs == [(t[k0], np.inf)]
    assert [e["kind"] for e in ev] == ["rest detected"] and ev[0]["time_s"] == t[k0]
    assert f"to {t[k0 + 9]:g} s" in ev[0]["action"]        # the dwell's last epoch confirmed it
    # the same quiet stretch one epoch shorter than the dwell: never entered
    d2 = np.r_[np.full(50, 100.0), np.zeros(W - 1 + 9), np.full(30, 100.0)]
    assert detect_rest(_t(len(d2)), d2, NM, W, dwell=10) == ([], [])
    # exactly the dwell, then motion: entered, and left at the first failing window
    d3 = np.r_[np.full(50, 100.0), np.zeros(W - 1 + 10), np.full(30, 100.0)]
    t3 = _t(len(d3))
    segs, ev = detect_rest(t3, d3, NM, W, dwell=10)
    k_fail = 50 + W - 1 + 10
    assert segs == [(t3[k0], t3[k_fail - 1])]
    assert [e["kind"] for e in ev] == ["rest detected", "rest ended"] and ev[1]["time_s"] == t3[k_fail]


def test_never_enters_just_above_the_bound():
    d = np.full(500, 1.001 * B_IN / W)          # every window just fails the entry bound
    assert detect_rest(_t(500), d, NM, W, dwell=5) == ([], [])
    rng = np.random.default_rng(3)              # "free vibration": velocities 3σ on average
    d = 9.0 * chi2.rvs(NM, size=2000, random_state=rng)
    assert detect_rest(_t(2000), d, NM, W, dwell=5) == ([], [])


def test_chatter_does_not_toggle():
    w, dwell = 1, 5                              # window of one epoch: D_k = d_k
    b_in, b_out = chi2.ppf(REST_ENTER_PROBABILITY, NM), chi2.ppf(REST_LEAVE_PROBABILITY, NM)
    lo, mid = 0.98 * b_in, 0.5 * (b_in + b_out)
    assert b_in < mid < b_out
    # outside rest: passes in runs of dwell − 1, then one above → never enters
    d = np.tile(np.r_[np.full(dwell - 1, lo), mid], 40)
    assert detect_rest(_t(len(d)), d, NM, w, dwell) == ([], [])
    # inside rest: chatter across the entry bound, below the leave bound → stays, one segment
    d = np.r_[np.full(dwell, lo), np.tile([lo, mid], 100)]
    segs, ev = detect_rest(_t(len(d)), d, NM, w, dwell)
    assert segs == [(_t(1)[0], np.inf)] and len(ev) == 1
    # … until one epoch above the leave bound
    d[120] = 1.01 * b_out
    t = _t(len(d))
    segs, ev = detect_rest(t, d, NM, w, dwell)
    assert segs[0] == (t[0], t[119]) and ev[1]["kind"] == "rest ended" and ev[1]["time_s"] == t[120]
    assert len(segs) == 1                        # outside again, the chatter does not re-enter …
    d[129], d[130:130 + dwell] = mid, lo        # … a full dwell of passes does
    segs, ev = detect_rest(t, d, NM, w, dwell)
    assert segs == [(t[0], t[119]), (t[130], np.inf)]


def test_bounds_are_chi_square_quantiles():
    # at rest with a consistent covariance d_k ~ χ²(nm): windows of independent draws pass at p_enter
    d = chi2.rvs(NM, size=40000, random_state=np.random.default_rng(4))
    D = window_sums(d, W)[W - 1:]
    assert np.mean(D <= B_IN) == pytest.approx(REST_ENTER_PROBABILITY, abs=0.003)
    assert np.mean(D <= B_OUT) == pytest.approx(REST_LEAVE_PROBABILITY, abs=0.0005)


@pytest.mark.parametrize("window, dwell", [(0.0, 2.0), (3.0, -1.0), (float("nan"), 2.0), (True, 2.0)])
def test_detector_options_validated(window, dwell):
    with pytest.raises(CdgpsError, match="--rest-(window|dwell)-s"):
        validate_detector(window, dwell, 0.1)


# --------------------------------------------------------------------------------------------
# end to end: one static seed, one free-vibration seed


@pytest.fixture(scope="module")
def testbed():
    return load_config(ROOT / "configs" / "testbed-1998-lumped.toml")


@pytest.fixture(scope="module")
def static_run(testbed):
    sim = simulate(testbed, SimOptions(duration_s=140.0, seed=5, scenario="static", phase_sigma_m=0.002))
    run = memory_run(testbed, sim.receiver)
    return {"sim": sim, "run": run, "init": initialize(run, InitOptions(start_s=0.0, duration_s=60.0)),
            "rest": [s for s in sim.truth["segments"] if s["kind"] == "rest"][0]}


def _angle_deg(tb, res):
    U = np.asarray(tb.mode_shapes)
    c = U[tb.coord_names.index("q6")] + U[tb.coord_names.index("q10")]
    return np.degrees(res.x[:, :tb.n_modes] @ c)


def test_static_seed_rest_found(testbed, static_run):
    res = estimate(static_run["run"], static_run["init"], EstimateOptions(rest_auto=True))
    segs = res.rest_detection["segments_s"]
    assert len(segs) == 1 and segs[0][1] is None
    assert abs(segs[0][0] - static_run["rest"]["start_s"]) <= 5.0
    kinds = [e["kind"] for e in res.events]
    assert kinds == ["rest detected", "rest segment"], kinds
    assert res.rest_active_s == [[segs[0][0], float(res.time_s[-1])]]
    sel = res.time_s >= segs[0][0] - 1e-9
    ang = _angle_deg(testbed, res)[sel]
    assert abs(ang.mean() - (-1.4)) < 0.1 and ang.std() < 0.02
    # the detection pass weighted the data with the batch's a-posteriori sigma (≈ the 2 mm simulated)
    assert 0.0015 < res.rest_detection["sigma_m"] < 0.003
    # the same result as declaring the detected segment by hand
    decl = estimate(static_run["run"], static_run["init"], EstimateOptions(rest_segments_s=((segs[0][0], np.inf),)))
    np.testing.assert_array_equal(decl.x, res.x)


@pytest.mark.skipif(not COMPILED, reason="cdgps_cli.estimation._ekfcore is not compiled")
def test_auto_rest_kernel_equals_numpy_smoothed(static_run):
    opt = EstimateOptions(rest_auto=True, smooth=True)
    with kernel(True):
        a = estimate(static_run["run"], static_run["init"], opt)
    with kernel(False):
        b = estimate(static_run["run"], static_run["init"], opt)
    assert a.filter_path == "c" and b.filter_path == "numpy"
    assert a.rest_detection["segments_s"] == b.rest_detection["segments_s"]
    assert [e["kind"] for e in a.events] == [e["kind"] for e in b.events]
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-11)
    np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-13)


def test_free_seed_no_rest(testbed):
    sim = simulate(testbed, SimOptions(duration_s=100.0, seed=1, scenario="free", phase_sigma_m=0.002))
    run = memory_run(testbed, sim.receiver)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=60.0))
    res = estimate(run, init, EstimateOptions(rest_auto=True))
    assert res.rest_detection["segments_s"] == [] and res.rest_active_s == []
    assert not any("rest" in e["kind"] for e in res.events)
    np.testing.assert_array_equal(res.x, estimate(run, init, EstimateOptions()).x)


def test_auto_and_declared_rest_cannot_be_combined(static_run):
    with pytest.raises(CdgpsError, match="cannot be combined"):
        estimate(static_run["run"], static_run["init"], EstimateOptions(rest_auto=True, rest_segments_s=((80.0, 90.0),)))


# --------------------------------------------------------------------------------------------
# report static: "ran without static mode"


def test_static_mode_coverage_statements():
    t = np.arange(80.0, 100.01, 0.1)
    none = static_mode_coverage({"options": json.dumps({"rest_segments_s": []}), "rest_active_s": "[]"}, t)
    assert none["active_fraction"] == 0.0 and none["statement"].startswith("Without static mode")
    part = static_mode_coverage({"options": json.dumps({"rest_segments_s": [[90.0, None]]}),
                                 "rest_active_s": "[[90.0, 140.0]]"}, t)
    assert part["active_fraction"] == pytest.approx(101 / 201) and "50 % of this segment only" in part["statement"]
    elsewhere = static_mode_coverage({"options": json.dumps({"rest_segments_s": [[120.0, None]]}),
                                      "rest_active_s": "[[120.0, 140.0]]"}, t)
    assert elsewhere["active_fraction"] == 0.0 and "not active anywhere" in elsewhere["statement"]
    full = static_mode_coverage({"options": json.dumps({"rest_auto": True, "rest_segments_s": []}),
                                 "rest_active_s": "[[70.0, 140.0]]"}, t)
    assert full["active_fraction"] == 1.0 and full["statement"].startswith("Static mode on the whole segment")
    unknown = static_mode_coverage({}, t)
    assert unknown["active_fraction"] is None and "do not record" in unknown["statement"]


def test_report_static_says_without_static_mode(tmp_path, testbed):
    sim = simulate(testbed, SimOptions(duration_s=30.0, seed=21))
    write_simulation(sim, tmp_path / "sim")
    write_run(testbed, tmp_path / "sim" / "receiver.csv", tmp_path / "run.mcap")
    cli = CliRunner()
    for args in (["init", tmp_path / "run.mcap", "--start", 0, "--duration", 20, "-o", tmp_path / "init.json"],
                 ["estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "-o", tmp_path / "kin.mcap"],
                 ["estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "--rest", "20:",
                  "-o", tmp_path / "rest.mcap"]):
        r = cli.invoke(main, ["-q"] + [str(a) for a in args])
        assert r.exit_code == 0, r.output
    r = cli.invoke(main, ["report", "static", str(tmp_path / "kin.mcap"), "--angle", "q6+q10", "--start", "22",
                          "-o", str(tmp_path / "rk")])
    assert r.exit_code == 0, r.output
    assert "warning: Without static mode" in r.stderr
    assert "**Without static mode" in (tmp_path / "rk" / "report.md").read_text()
    assert "<strong>Without static mode" in (tmp_path / "rk" / "report.html").read_text()
    assert json.loads((tmp_path / "rk" / "report.json").read_text())["static_mode"]["active_fraction"] == 0.0
    r = cli.invoke(main, ["report", "static", str(tmp_path / "rest.mcap"), "--angle", "q6+q10", "--start", "22",
                          "-o", str(tmp_path / "rr")])
    assert r.exit_code == 0, r.output
    d = json.loads((tmp_path / "rr" / "report.json").read_text())["static_mode"]
    # 30 s of free vibration: the rest declaration is refused/broken by the data wherever it moves
    assert d["rest_option"] == "declared" and d["active_fraction"] is not None
    assert ("Without static mode" in r.stderr) == (d["active_fraction"] == 0.0)


def test_non_finite_statistic_leaves_rest():
    d = np.r_[np.zeros(20), np.inf, np.zeros(3)]        # e.g. a covariance that is not positive definite
    t = _t(len(d))
    segs, ev = detect_rest(t, d, NM, 1, 5)
    assert segs == [(t[0], t[19])] and ev[1]["kind"] == "rest ended" and ev[1]["time_s"] == t[20]
    assert "velocity_chi2" not in ev[1] and "velocity_chi2" in ev[0]          # JSON has no infinity

