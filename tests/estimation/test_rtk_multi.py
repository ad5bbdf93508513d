"""Multi-GNSS RTK (estimation/rtk_multi.py) on the rinex-ge simulation against the simulator's truth."""

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
import itertools

from cdgps_cli.config.options import MULTI_GNSS_DEFAULTS
from cdgps_cli.estimation import rtk_multi
from cdgps_cli.estimation.ambiguity import resolve
from cdgps_cli.estimation.rtk_multi import check_common_signals, receiver_geometry, solve_rtk
from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.io.rinex_signals import read_rinex_signals
from cdgps_cli.model.gps.orbits import ecef_to_enu
from cdgps_cli.measurement.epoch_pairing import pair_epochs
from cdgps_cli.measurement.dd_signals import epoch_groups, paired_sd_rows
from tests._shared import REPO_ROOT

GE = REPO_ROOT / ".." / "shared" / "data" / "rinex-ge"
BASE = np.array([4157177.06580187, 671230.476590636, 4774767.03105544])
TRUTH = np.array([4156857.1195929, 673209.028774142, 4774767.03105544])
pytestmark = pytest.mark.skipif(not GE.exists(), reason="../shared/data/rinex-ge absent")


@pytest.fixture(scope="module")
def pair():
    sig = ["G:L1", "G:L2", "E:E1", "E:E5a"]
    nav = pd.concat([read_rinex_nav(GE / "RINEX_GN_Spirent.23N"), read_rinex_nav(GE / "RINEX_EN_Spirent.23L", systems=("E",))])
    _, b = read_rinex_signals(GE / "Base-static_MO_Spirent.obs", sig)
    _, r = read_rinex_signals(GE / "Rover-static-2km-east_MO_Spirent.obs", sig)
    t0 = b["time_gps_s"].min()
    b, r = b[b["time_gps_s"] < t0 + 20], r[r["time_gps_s"] < t0 + 20]
    return sig, nav, b, r


def test_kinematic_fixes_and_is_within_mm_of_truth(pair):
    sig, nav, b, r = pair
    x0 = TRUTH + np.array([3.0, -2.0, 4.0])     # a-priori metres off: the iterated update absorbs it
    res = solve_rtk(receiver_geometry(b, nav, BASE), receiver_geometry(r, nav, x0), BASE, x0)
    assert res["fixed"].mean() >= 0.9
    e = np.array([ecef_to_enu(x, TRUTH) for x in res["fixed_xyz_m"][res["fixed"]]])
    assert np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)) < 0.003 and np.sqrt(np.mean(e[:, 2] ** 2)) < 0.005
    # the float solution alone is decimetres-to-centimetres: fixing is what brings it to mm
    assert res["n_dd_ambiguities"].max() > 10


def test_missing_signal_or_system(pair):
    sig, nav, b, r = pair
    where = {"base": "base.obs", "rover": "rover.obs", "nav": "gps.nav"}
    with pytest.raises(CdgpsError, match=r"base.obs \(base\): no G:L5 phase observations"):
        check_common_signals(b, r, ["G:L1", "G:L5"], nav, where)
    with pytest.raises(CdgpsError, match=r"gps.nav\) have no Galileo ephemerides"):
        check_common_signals(b, r, sig, nav[nav["sat"].str.startswith("G")], where)


def test_paired_rows_match_a_merge_per_epoch(pair):
    """The run-wide pairing gives each epoch the groups of a base/rover merge of that epoch alone."""
    sig, nav, b, r = pair
    gb, gr = receiver_geometry(b, nav, BASE), receiver_geometry(r, nav, TRUTH)
    opt = dict(MULTI_GNSS_DEFAULTS)
    pairs = pair_epochs(gr["time_gps_s"].to_numpy(), gb["time_gps_s"].to_numpy())
    times = np.intersect1d(gb["time_gps_s"].unique(), gr["time_gps_s"].unique())
    np.testing.assert_array_equal(pairs.rover_time_s, times)      # simultaneous tags: the intersection
    rows = paired_sd_rows(gb, gr, pairs, opt)
    n_groups = 0
    for k, t in enumerate(times):
        eb, er = gb[gb["time_gps_s"] == t], gr[gr["time_gps_s"] == t]
        m = eb.merge(er[["sat", "signal", "phase_cycles", "trop_m", "sat_clock_m"]], on=["sat", "signal"], suffixes=("_b", "_r"))
        m = m[m["el_rad"] >= np.radians(opt["mask_deg"])]
        want = [(name, g["sat"].tolist(), int(np.argmax(g["el_rad"].to_numpy())),
                 (g["wavelength_m"] * (g["phase_cycles_r"] - g["phase_cycles_b"]) + (g["sat_clock_m_r"] - g["sat_clock_m_b"])
                  - (g["trop_m_r"] - g["trop_m_b"])).to_numpy())
                for name, g in m.groupby("signal", sort=True) if len(g) >= 2]
        got = epoch_groups(rows, k)
        assert [(g["signal"], list(g["sats"]), g["ref"]) for g in got] == [w[:3] for w in want]
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g["phase_sd_m"], w[3])
        n_groups += len(got)
    assert n_groups >= 4 * len(times)


def _correlated_sequence(rng, n, epochs):
    """Float ambiguities (cycles) and covariances shrinking and turning slowly over epochs, strongly
    correlated through a 3-D geometry (as DD ambiguities of a short baseline)."""
    truth = rng.integers(-50, 50, n)
    B = rng.normal(size=(n, 3))
    for k in range(epochs):
        Bk = B + 0.02 * k * np.sin(np.arange(3 * n).reshape(n, 3))
        Q = (2.0 / (1 + k)) * Bk @ Bk.T + 0.002 * np.eye(n)
        yield truth + np.linalg.cholesky(Q) @ rng.normal(size=n) * 0.3, 0.5 * (Q + Q.T)


def _brute_force_best(a, Q, radius=2):
    """Integer vector minimising (a − z)ᵀ Q⁻¹ (a − z) over a box around round(a) (independent of LAMBDA)."""
    W = np.linalg.inv(Q)
    best, zbest = np.inf, None
    for off in itertools.product(range(-radius, radius + 1), repeat=len(a)):
        z = np.round(a) + off
        v = (a - z) @ W @ (a - z)
        if v < best:
            best, zbest = v, z
    return zbest.astype(np.int64)


def test_carried_decorrelation_gives_the_integers_of_a_reduction_from_scratch():
    rng = np.random.default_rng(7)
    carried = rtk_multi._CarriedDecorrelation()
    n_carried = 0
    for part, (n, keys) in enumerate(((5, ("a",)), (5, ("b",)), (8, ("c",)))):   # key changes restart Z
        for a, Q in _correlated_sequence(rng, n, 25):
            # a success-rate floor of ~0: the whole set is tried, as resolve() tries it
            got, ref = carried.resolve(keys, a, Q, 3.0, 1e-300), resolve(a, Q, 3.0, partial=False)
            n_carried += not np.array_equal(carried.Z, np.eye(n, dtype=np.int64))
            assert got["accepted"] == ref["accepted"] and not got["partial"]
            if got["accepted"]:          # integers of z = Zᵀ a: the same integer vector a
                np.testing.assert_array_equal(np.linalg.solve(got["rows"].astype(float), got["integers"]).round(),
                                              ref["integers"])
            assert got["ratio"] == pytest.approx(ref["ratio"], rel=1e-9)
            if n == 5 and got["accepted"]:
                np.testing.assert_array_equal(ref["integers"], _brute_force_best(a, Q))
    assert n_carried > 20      # the carried transformation was used, not only the identity


def test_success_rate_selects_a_partial_set_and_refuses_a_weak_one():
    """A float solution whose bootstrapped success rate is below the floor is fixed only on the tail
    of decorrelated ambiguities that reaches it (partial), or not at all."""
    rng = np.random.default_rng(11)
    carried = rtk_multi._CarriedDecorrelation()
    n = 6
    Q = np.diag([4.0, 2.0, 1.0, 0.02, 0.01, 0.005])          # three precise, three hopeless ambiguities
    a = np.array([3.0, -7.0, 12.0, 5.0, -2.0, 9.0]) + rng.normal(size=n) * np.sqrt(np.diag(Q)) * 0.1
    got = carried.resolve(("k",), a, Q, 3.0, 0.999)
    assert got["accepted"] and got["partial"] and len(got["integers"]) == 3 and got["success_rate"] >= 0.999
    assert set(np.flatnonzero(np.abs(got["rows"]).sum(axis=0) > 0)) == {3, 4, 5}
    np.testing.assert_array_equal(got["rows"].astype(float) @ np.round(a), got["integers"])
    weak = carried.resolve(("w",), a[:3], Q[:3, :3], 3.0, 0.999)
    assert not weak["accepted"] and weak["success_rate"] == 0.0


def test_solve_rtk_carried_decorrelation_equals_reduction_from_scratch(pair, monkeypatch):
    sig, nav, b, r = pair
    # the simulator's ambiguities are all 0: whole cycles per (satellite, signal) make Z⁻ᵀ z matter
    keys = r["sat"] + r["signal"]
    cycles = dict(zip(sorted(keys.unique()), np.random.default_rng(3).integers(-40, 40, keys.nunique())))
    r = r.assign(phase_cycles=r["phase_cycles"] + keys.map(cycles).to_numpy())
    gb, gr = receiver_geometry(b, nav, BASE), receiver_geometry(r, nav, TRUTH)
    warm = solve_rtk(gb, gr, BASE, TRUTH, options={"fix_and_hold": False})   # held integers would move the float
    assert np.abs(warm["fixed_xyz_m"] - TRUTH).max() < 0.005

    def from_scratch(self, keys, Qa):      # Z = I: resolve reduces the DD covariance itself, as before
        self.Z = self.Zinv = np.eye(Qa.shape[0], dtype=np.int64)

    monkeypatch.setattr(rtk_multi._CarriedDecorrelation, "_update", from_scratch)
    cold = solve_rtk(gb, gr, BASE, TRUTH, options={"fix_and_hold": False})
    assert warm["fixed"].all() and np.array_equal(warm["fixed"], cold["fixed"])
    # the same integers in another integer basis: the fixed positions agree to rounding (1e-9 m)
    np.testing.assert_allclose(warm["fixed_xyz_m"], cold["fixed_xyz_m"], rtol=0, atol=1e-8)
    np.testing.assert_array_equal(warm["float_xyz_m"], cold["float_xyz_m"])
    np.testing.assert_allclose(warm["ratio"], cold["ratio"], rtol=1e-9)


def test_unresolved_half_cycles_stay_float():
    """Rows flagged with LLI bit 1 (half cycle not yet resolved, as u-blox receivers write for ~8 % of
    GPS L1 rows in ../shared/data/real-pairs/ublox-walk) whose phase is off by half a cycle: they get
    an ambiguity of their own that is never fixed, so every epoch fixes at millimetres.  (Before:
    7 of 20 epochs fixed, up to 10.8 cm wrong in height.)"""
    sig = ["G:L1", "G:L2"]
    nav = read_rinex_nav(GE / "RINEX_GN_Spirent.23N")
    _, b = read_rinex_signals(GE / "Base-static_MO_Spirent.obs", sig)
    _, r = read_rinex_signals(GE / "Rover-static-2km-east_MO_Spirent.obs", sig)
    t0 = b["time_gps_s"].min()
    b, r = b[b["time_gps_s"] < t0 + 40], r[r["time_gps_s"] < t0 + 40]
    t = np.sort(r["time_gps_s"].unique())
    sel = (r["sat"] == "G13") & (r["signal"] == "G:L1") & r["time_gps_s"].between(t[4], t[30])
    r = r.assign(phase_cycles=r["phase_cycles"] + np.where(sel, 0.5, 0.0), lli=r["lli"] | np.where(sel, 2, 0))
    res = solve_rtk(receiver_geometry(b, nav, BASE), receiver_geometry(r, nav, TRUTH), BASE, TRUTH)
    assert res["fixed"].all()
    e = np.array([ecef_to_enu(x, TRUTH) for x in res["fixed_xyz_m"]])
    assert np.abs(e).max() < 0.003, np.abs(e).max(axis=0)


def _pass(x, P, fixed_x=None, fixed_P=None):
    n = len(x)
    fixed = fixed_x is not None
    return {"float_xyz": np.array(x), "float_cov": np.array(P),
            "fixed_xyz": np.array(fixed_x) if fixed else np.full((n, 3), np.nan),
            "fixed_cov": np.array(fixed_P) if fixed else np.full((n, 3, 3), np.nan),
            "fixed": np.full(n, fixed), "ratio": np.full(n, np.nan), "n_fixed": np.zeros(n, np.int64),
            "partial": np.zeros(n, bool), "ns": np.zeros(n, np.int64), "wrong_fix_resets": np.zeros(n, bool),
            "released": np.zeros(n, bool), "held": np.zeros(n, bool)}


def test_combined_covariance_does_not_count_epoch_k_twice():
    """Review finding: the forward and backward estimates at epoch k both hold epoch k's measurement;
    merged as independent estimates their covariance counted it twice (R/(n+1) for n measurements of
    a static point: below the batch R/n).  The combined float and fixed covariances are the better
    pass's (never below the batch's), the positions their weighted mean."""
    from cdgps_cli.estimation.rtk_multi import _combine

    rng = np.random.default_rng(5)
    n, R = 6, 4e-4
    z = rng.normal(scale=np.sqrt(R), size=(n, 3)) + [1.0, 2.0, 3.0]
    eye = np.eye(3)
    fwd = _pass([z[:k + 1].mean(0) for k in range(n)], [R / (k + 1) * eye for k in range(n)])
    bwd = _pass([z[k:].mean(0) for k in range(n)], [R / (n - k) * eye for k in range(n)])
    out = _combine(fwd, bwd)
    var = out["float_cov"][:, 0, 0]
    assert np.all(var >= R / n * (1 - 1e-12)), var * n / R             # never better than all n measurements
    np.testing.assert_allclose(var, [R / max(k + 1, n - k) for k in range(n)])
    w = np.array([[k + 1, n - k] for k in range(n)], float)        # inverse-variance weights of the two passes
    mean = (w[:, :1] * fwd["float_xyz"] + w[:, 1:] * bwd["float_xyz"]) / w.sum(1, keepdims=True)
    np.testing.assert_allclose(out["float_xyz"], mean, atol=1e-12)
    # two agreeing fixes of one epoch share its phases: their mean is not reported twice as precise
    fx = np.tile([1.0, 2.0, 3.0], (n, 1))
    Pa, Pb = 1e-6 * eye, 2e-6 * eye
    out = _combine(_pass(fwd["float_xyz"], fwd["float_cov"], fx, np.tile(Pa, (n, 1, 1))),
                   _pass(bwd["float_xyz"], bwd["float_cov"], fx + 1e-4, np.tile(Pb, (n, 1, 1))))
    assert out["fixed"].all() and out["rejected"] == 0
    np.testing.assert_allclose(out["fixed_cov"], np.tile(Pa, (n, 1, 1)))
    np.testing.assert_allclose(out["fixed_xyz"], fx + 1e-4 / 3, atol=1e-12)


def test_dd_group_rows_carry_the_information_of_the_cholesky_whitened_dd_rows(pair):
    """The DD model of the engine (measurement/dd_signals.DDGroupModel) keeps the single differences
    and whitens them by B = (I − uuᵀ)Σ^{-1/2} per group and kind: BᵀB = Dᵀ(DΣDᵀ)⁻¹D, so its normal
    equations (HᵀWH, HᵀWr, rᵀWr) are those of the DD rows (dd_signals.epoch_rows: a reference per
    group, Cholesky-whitened D Σ Dᵀ), here on L1 + L2 with the ionosphere columns too."""
    from types import SimpleNamespace
    from cdgps_cli.measurement.dd_signals import DDGroupModel, epoch_rows

    sig, nav, b, r = pair
    gb, gr = receiver_geometry(b, nav, BASE), receiver_geometry(r, nav, TRUTH)
    opt = dict(MULTI_GNSS_DEFAULTS)
    rows = paired_sd_rows(gb, gr, pair_epochs(gr["time_gps_s"].to_numpy(), gb["time_gps_s"].to_numpy()), opt)
    groups = epoch_groups(rows, 3)
    assert len(groups) == 4
    st = rtk_multi._State(3)
    rtk_multi._prepare_state(st, groups, opt, 0.5)
    x = st.x + np.random.default_rng(1).normal(0.0, 0.3, st.x.size)
    model = DDGroupModel(lambda k: groups, BASE, TRUTH)
    model.prepare(0, SimpleNamespace(x=x))
    rw = model.rows(0)
    h, H = model.predict(x, rw)
    Hw, vw = rw.whiten(H), rw.whiten(rw.z_m - h)
    res, Hd, L = epoch_rows(x, groups, BASE, TRUTH, x.size)
    Hdw, rdw = np.linalg.solve(L, Hd), np.linalg.solve(L, res)
    np.testing.assert_allclose(Hw.T @ Hw, Hdw.T @ Hdw, rtol=1e-9, atol=1e-9 * np.abs(Hdw.T @ Hdw).max())
    np.testing.assert_allclose(Hw.T @ vw, Hdw.T @ rdw, rtol=1e-8, atol=1e-8 * np.abs(Hdw.T @ rdw).max())
    np.testing.assert_allclose(vw @ vw, rdw @ rdw, rtol=1e-9)


def test_the_rtk_path_does_not_import_scipy():
    """scipy's import (≈ 0.13 s) is not on `cdgps rtk`'s path: the start-up counts against RTKLIB."""
    import subprocess
    import sys

    code = ("import sys, cdgps_cli.cli.commands, cdgps_cli.pipeline.gnss_multi; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]", out


GOLDEN = REPO_ROOT / "tests" / "estimation" / "data" / "rtk_legacy_golden.npz"
_NO_HOLD = {"fix_and_hold": False, "code_correlation_s": 0.0}   # recorded before fix-and-hold and 30 s codes became the default
# (the ionosphere case: recorded before the zenith wet delays were estimated with it, which its 1 km threshold now asks)
_GOLDEN_CASES = {"static": {"mode": "static", **_NO_HOLD}, "kinematic": _NO_HOLD, "iono": {"iono_threshold_km": 1.0, "tropo_threshold_km": 1000.0, **_NO_HOLD},
                 "hold": {"fix_and_hold": True, "code_correlation_s": 0.0}, "backward": {"direction": "backward", **_NO_HOLD}}


def _golden_run(pair, opt):
    sig, nav, b, r = pair
    x0 = TRUTH + np.array([3.0, -2.0, 4.0])
    return solve_rtk(receiver_geometry(b, nav, BASE), receiver_geometry(r, nav, x0), BASE, x0, options=opt)


@pytest.mark.parametrize("case", sorted(_GOLDEN_CASES))
def test_rtk_on_the_driver_equals_its_former_own_loop(pair, case):
    """Issue 28 item 1: rtk's filter runs on the engine's driver (estimation/driver.drive with the DD
    model measurement/dd_signals.DDGroupModel and the ambiguity hooks).  Its results equal those of
    rtk's former own epoch loop, recorded in tests/estimation/data/rtk_legacy_golden.npz from that
    loop on this 20 s Spirent GPS+Galileo L1+L2 pair: same fixed epochs, the same DD ambiguities
    fixed, positions within 1 µm, covariances to 1e-6 relative."""
    new = _golden_run(pair, _GOLDEN_CASES[case])
    old = np.load(GOLDEN)
    assert np.array_equal(new["fixed"], old[f"{case}_fixed"]) and new["fixed"].any()
    assert np.array_equal(new["n_dd_ambiguities"], old[f"{case}_n"])
    for key in ("float_xyz_m", "fixed_xyz_m"):
        np.testing.assert_allclose(new[key], old[f"{case}_{key}"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(new["float_cov_m2"], old[f"{case}_float_cov_m2"], rtol=1e-6, atol=1e-12)


def test_constant_velocity_mode_on_the_same_engine(pair):
    """`--mode constant-velocity`: position + velocity (white acceleration) on the same driver, DD model
    and ambiguity hooks; on the static 2 km rover it fixes every epoch within mm of the truth, and the
    kinematic (random-walk) answer stays within 1 mm of it."""
    cv = _golden_run(pair, {"mode": "constant-velocity"})
    rw = _golden_run(pair, {})
    assert cv["fixed"].all()
    e = np.array([ecef_to_enu(x, TRUTH) for x in cv["fixed_xyz_m"]])
    assert np.abs(e[:, :2]).max() < 0.005 and np.abs(e[:, 2]).max() < 0.01
    assert np.abs(cv["fixed_xyz_m"] - rw["fixed_xyz_m"]).max() < 0.001


def test_constant_velocity_transition():
    from cdgps_cli.model.dynamics_models import ConstantVelocity
    A, B, Q = ConstantVelocity(3, 2.0).transition(0.5)
    x = np.r_[1.0, 2.0, 3.0, 0.1, -0.2, 0.4]
    np.testing.assert_allclose(A @ x, np.r_[1.05, 1.9, 3.2, 0.1, -0.2, 0.4])
    assert B.shape == (6, 0)
    np.testing.assert_allclose(np.diag(Q), 4.0 * np.r_[[0.5**3 / 3] * 3, [0.5] * 3])
    np.testing.assert_allclose(Q[0, 3], 4.0 * 0.5**2 / 2)
    assert np.all(np.linalg.eigvalsh(Q) > 0)


def test_rtk_modes_are_validated_by_name():
    from cdgps_cli.pipeline.gnss_multi import validate_options
    assert validate_options({"mode": "constant-velocity"})["mode"] == "constant-velocity"
    with pytest.raises(CdgpsError, match=r"mode: expected one of 'kinematic', 'constant-velocity', 'static', got 'cv'"):
        validate_options({"mode": "cv"})


def test_each_rtk_pass_is_a_drive_of_the_engine(pair, monkeypatch):
    """rtk has no epoch loop of its own: each pass is driver.drive (the first epoch, iterated up to 4
    times, then the rest) with the DD model and the ambiguity hook."""
    from cdgps_cli.measurement.dd_signals import DDGroupModel

    calls = []
    real = rtk_multi.drive

    def spy(dynamics, models, source, init, hooks=(), **kw):
        calls.append((type(models[0]), [type(h).__name__ for h in hooks], source.n_epochs, kw.get("k0", 0)))
        return real(dynamics, models, source, init, hooks, **kw)

    monkeypatch.setattr(rtk_multi, "drive", spy)
    monkeypatch.setenv("CDGPS_SERIAL", "1")            # both passes in this process, where the spy sees them
    res = _golden_run(pair, {"direction": "combined"})
    n = res["time_gps_s"].size
    assert calls == [(DDGroupModel, ["_AmbiguityHook"], 1, 0), (DDGroupModel, ["_AmbiguityHook"], n, 1)] * 2


def test_a_decorrelation_beyond_int64_is_retried_from_scratch_then_left_float(monkeypatch):
    """Real data (mosaic-static G+E+C L1+L2, 47 DD ambiguities) made ``decorrelate`` raise
    AmbiguityError ("integer entries too large for int64") and ended the whole run: now the carried Z
    restarts from the identity and, if that fails too, the epoch is simply not fixed."""
    from cdgps_cli.estimation.ambiguity import AmbiguityError

    rng = np.random.default_rng(2)
    A = rng.normal(size=(5, 5))
    Qa = A @ A.T * 0.01 + np.eye(5) * 1e-3
    a = rng.integers(-9, 9, 5) + rng.normal(scale=0.01, size=5)
    calls = {"n": 0}
    real = rtk_multi._decorrelated

    def flaky(L, d, fail_first):
        calls["n"] += 1
        if calls["n"] <= fail_first:
            raise AmbiguityError("decorrelation produced integer entries too large for int64")
        return real(L, d)

    for fail_first, accepted in ((1, True), (99, False)):
        calls["n"] = 0
        monkeypatch.setattr(rtk_multi, "_decorrelated", lambda L, d, f=fail_first: flaky(L, d, f))
        c = rtk_multi._CarriedDecorrelation()
        c.Z = c.Zinv = np.eye(5, dtype=np.int64)
        out = c.resolve(("k",), a, Qa, 3.0, 0.999)
        assert out["accepted"] is accepted and calls["n"] == 2
        if accepted:                                    # the whole set, right: Zᵀ a's integers map back to round(a)
            assert not out["partial"]
            np.testing.assert_allclose(np.linalg.solve(out["rows"].astype(float), out["integers"]), np.rint(a), atol=1e-9)


def test_group_median_is_pandas_groupby_median():
    """receiver_geometry's per-epoch median receiver clock, in numpy: pandas' groupby median exactly
    (odd and even group sizes, ties, one-element groups, unsorted keys)."""
    import pandas as pd

    rng = np.random.default_rng(3)
    for _ in range(300):
        n = int(rng.integers(1, 40))
        keys = rng.integers(0, int(rng.integers(1, 8)), n).astype(float)
        values = np.round(rng.normal(size=n), int(rng.integers(0, 4))) * 10.0 ** rng.uniform(-9, 3)
        want = pd.Series(values).groupby(keys).transform("median").to_numpy()
        assert np.array_equal(rtk_multi._group_median(values, keys), want)


def test_dd_rows_on_state_equal_the_product_with_the_dd_operator():
    """_fix's integer combinations of the state, built by column: the same numbers as ``rows @ T`` with
    T the dense DD operator (+1 on each DD's column, −1 on its group's reference column)."""
    rng = np.random.default_rng(8)
    sizes = np.array([3, 1, 4])
    plus = np.array([5, 7, 4, 9, 12, 10, 11, 14])
    ref_cols = np.array([6, 3, 13])
    rows = rng.integers(-40, 40, size=(6, plus.size))
    T = np.zeros((plus.size, 16))
    T[np.arange(plus.size), plus] = 1.0
    T[np.arange(plus.size), np.repeat(ref_cols, sizes)] = -1.0
    assert np.array_equal(rtk_multi._dd_rows_on_state(rows, plus, ref_cols, sizes, 16), rows @ T)


def _combine_per_epoch(f, b):
    """The forward/backward combination epoch by epoch (rtk_multi._combine before it was vectorised)."""
    floor = np.eye(3) * 1e-6
    out = {k: np.array(v, copy=True) for k, v in f.items()}
    out["rejected"] = 0

    def merge(xa, Pa, xb, Pb):
        K = Pa @ np.linalg.inv(Pa + Pb)
        return xa + K @ (xb - xa)

    def agree(xa, Pa, xb, Pb):
        d = xa - xb
        return float(d @ np.linalg.solve(Pa + Pb + floor, d)) <= rtk_multi._CHI2_3_999

    for k in range(f["fixed"].size):
        out["float_xyz"][k] = merge(f["float_xyz"][k], f["float_cov"][k], b["float_xyz"][k], b["float_cov"][k])
        out["float_cov"][k] = min(f["float_cov"][k], b["float_cov"][k], key=np.trace)
        ff, fb = f["fixed"][k], b["fixed"][k]
        out["fixed_xyz"][k], out["fixed_cov"][k] = np.nan, np.nan
        if ff and fb:
            if agree(f["fixed_xyz"][k], f["fixed_cov"][k], b["fixed_xyz"][k], b["fixed_cov"][k]):
                out["fixed_xyz"][k] = merge(f["fixed_xyz"][k], f["fixed_cov"][k], b["fixed_xyz"][k], b["fixed_cov"][k])
                out["fixed_cov"][k] = min(f["fixed_cov"][k], b["fixed_cov"][k], key=np.trace)
            else:
                out["rejected"] += 1
        elif ff or fb:
            src, other = (f, b) if ff else (b, f)
            if src["held"][k] or agree(src["fixed_xyz"][k], src["fixed_cov"][k], other["float_xyz"][k],
                                       other["float_cov"][k]):
                out["fixed_xyz"][k], out["fixed_cov"][k] = src["fixed_xyz"][k], src["fixed_cov"][k]
            else:
                out["rejected"] += 1
        r = [f["ratio"][k], b["ratio"][k]]
        out["ratio"][k] = np.nanmax(r) if np.isfinite(r).any() else np.nan
        out["n_fixed"][k] = max(f["n_fixed"][k], b["n_fixed"][k])
        out["partial"][k] = f["partial"][k] and b["partial"][k]
    out["fixed"] = np.isfinite(out["fixed_xyz"][:, 0])
    out["wrong_fix_resets"] = f["wrong_fix_resets"] | b["wrong_fix_resets"]
    out["released"] = f["released"] | b["released"]
    out["held"] = f["held"] | b["held"]
    return out


def test_a_held_fix_needs_no_agreement_with_the_other_passs_float():
    """One pass fixed, the other float 0.5 m away with a 5 cm σ (a moving u-blox rover's optimistic float): a
    fresh fix is rejected, a held one (fixed ``hold_after_fixes`` epochs in a row, its DD phases tested since)
    kept; two fixes that disagree are rejected whether held or not."""
    from cdgps_cli.estimation.rtk_multi import _combine

    n, eye = 4, np.eye(3)
    fx = np.tile([1.0, 2.0, 3.0], (n, 1))
    fwd = _pass(fx + [0.5, 0.0, 0.0], np.tile(0.05**2 * eye, (n, 1, 1)))
    bwd = _pass(fx + [0.001, 0.0, 0.0], np.tile(0.05**2 * eye, (n, 1, 1)), fx, np.tile(1e-6 * eye, (n, 1, 1)))
    bwd["held"][2:] = True
    out = _combine(fwd, bwd)
    assert out["fixed"].tolist() == [False, False, True, True] and out["rejected"] == 2
    np.testing.assert_array_equal(out["fixed_xyz"][2:], fx[2:])
    fwd2 = _pass(fwd["float_xyz"], fwd["float_cov"], fx + [0.2, 0.0, 0.0], np.tile(1e-6 * eye, (n, 1, 1)))
    fwd2["held"][:] = True
    out = _combine(fwd2, bwd)
    assert not out["fixed"].any() and out["rejected"] == n


def test_combine_vectorised_equals_the_per_epoch_combination():
    """_combine over all epochs at once gives the per-epoch loop's numbers exactly: merged floats and
    fixes, agreeing / disagreeing fixes (rejected), one pass fixed, ratios with NaN and inf."""
    rng = np.random.default_rng(9)
    n = 400

    def one_pass():
        A = rng.normal(size=(n, 3, 3)) * rng.choice([1e-3, 1e-2, 0.3], size=(n, 1, 1))
        cov = A @ A.transpose(0, 2, 1) + np.eye(3) * 1e-6
        fixed = rng.random(n) < 0.6
        fx = rng.normal(size=(n, 3)) * rng.choice([0.001, 0.05], size=(n, 1))
        fx[~fixed] = np.nan
        fcov = np.where(fixed[:, None, None], cov * 0.01, np.nan)
        return {"float_xyz": rng.normal(size=(n, 3)) * 0.02, "float_cov": cov, "fixed_xyz": fx, "fixed_cov": fcov,
                "fixed": fixed, "ratio": rng.choice([np.nan, np.inf, 2.0, 5.5, 30.0], n),
                "n_fixed": rng.integers(0, 20, n), "partial": rng.random(n) < 0.2, "ns": rng.integers(4, 12, n),
                "wrong_fix_resets": rng.random(n) < 0.05, "released": rng.random(n) < 0.05,
                "held": fixed & (rng.random(n) < 0.5)}

    f, b = one_pass(), one_pass()
    got, want = rtk_multi._combine(f, b), _combine_per_epoch(f, b)
    assert 0 < got["rejected"] == want["rejected"] and got["fixed"].sum() > 50
    for key in want:
        if key != "rejected":
            assert np.array_equal(got[key], want[key], equal_nan=True), key


def test_rtk_masks_at_both_receivers_as_rtklib(pair):
    """A satellite below the elevation mask at the rover (above it at the base) is not used, as in RTKLIB
    (rtkpos.c: ``selsat`` masks on the base's elevation and ``zdres`` leaves each receiver's satellites below
    the mask without a residual), and as the static engine's rows (``paired_sd_rows(mask_rover=True)``)."""
    sig, nav, b, r = pair
    rg = receiver_geometry(r, nav, TRUTH)
    t_rover = np.unique(rg["time_gps_s"].to_numpy())
    low = (rg["sat"].astype(str) == "G05").to_numpy() & (rg["time_gps_s"].to_numpy() < t_rover[5])
    assert low.any()
    rg.loc[low, "el_rad"] = 0.0                         # below the mask at the rover only, first 5 epochs
    bg = receiver_geometry(b, nav, BASE)
    full = solve_rtk(bg, receiver_geometry(r, nav, TRUTH), BASE, TRUTH)
    res = solve_rtk(bg, rg, BASE, TRUTH)
    assert (res["n_satellites"][:5] == full["n_satellites"][:5] - 1).all()
    assert (res["n_satellites"][5:] == full["n_satellites"][5:]).all()


def test_first_of_pairs_is_drop_duplicates_and_merge():
    """receiver_geometry's pairing of rows to their (epoch, satellite): the rows ``drop_duplicates``
    keeps, in their order, and for every row the index of its pair (what the left merge did)."""
    import pandas as pd

    from cdgps_cli.estimation.rtk_multi import _first_of_pairs

    rng = np.random.default_rng(5)
    t = rng.choice([0.0, 1.0, 2.5, 1e9 + 0.999], 300)
    sats = rng.choice(np.array(["G01", "E11", "R02", "C30"], dtype=object), 300)
    group, at_first = _first_of_pairs(t, sats)
    df = pd.DataFrame({"time_gps_s": t, "sat": sats})
    first = df.drop_duplicates(["time_gps_s", "sat"])
    np.testing.assert_array_equal(at_first, first.index.to_numpy())
    g = first.assign(k=np.arange(len(first)))
    np.testing.assert_array_equal(group, df.merge(g, on=["time_gps_s", "sat"], how="left")["k"].to_numpy())
    group0, at0 = _first_of_pairs(np.array([]), np.array([], dtype=object))
    assert group0.size == 0 and at0.size == 0


def test_check_common_signals_names_the_missing_signal_and_what_is_present():
    import pandas as pd

    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.estimation.rtk_multi import check_common_signals

    base = pd.DataFrame({"signal": ["G:L1", "G:L2", "G:L1"]})
    rover = pd.DataFrame({"signal": ["G:L1", "E:E1"]})
    nav = pd.DataFrame({"sat": ["G01", "E11"]})
    check_common_signals(base, rover, ["G:L1"], nav, {"base": "b.obs", "rover": "r.obs", "nav": "n"})
    with pytest.raises(CdgpsError, match=r"r\.obs \(rover\): no G:L2 phase observations.*present: E:E1, G:L1\)"):
        check_common_signals(base, rover, ["G:L1", "G:L2"], nav, {"base": "b.obs", "rover": "r.obs", "nav": "n"})
    # a reader that kept only the signals asked for: nothing to list, the way out named instead of "present: )"
    with pytest.raises(CdgpsError, match=r"b\.obs \(base\): no E:E1 phase observations; the receivers must share every "
                                         r"signal asked for \(it holds none of E:E1; --signals auto takes every signal"):
        check_common_signals(base[base["signal"] == "E:E1"], rover, ["E:E1"], nav,
                             {"base": "b.obs", "rover": "r.obs", "nav": "n"})


def test_troposphere_at_epochs_uses_each_epochs_height():
    """Rows of an epoch with a position get the hydrostatic delay at that position (each checked
    against the one-receiver evaluation); rows of an epoch without one (NaN, or not in the solution)
    keep theirs; 100 m higher is 27 mm less zenith delay (Saastamoinen near sea level: ≈ 0.27 mm per metre)."""
    import pandas as pd

    from cdgps_cli.estimation.rtk_multi import troposphere_at_epochs
    from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
    from cdgps_cli.model.gps.positioning import tropo_hydrostatic_m

    x0 = np.array([-3959400.631, 3385704.533, 3667523.111])
    lat, lon, h0 = ecef_to_geodetic(x0)
    up = enu_matrix(lat, lon)[2]
    t_ep = np.array([100.0, 101.0, 102.0])
    xyz = np.stack([x0 + 20.0 * up, np.full(3, np.nan), x0 + 120.0 * up])
    geo = pd.DataFrame({"time_gps_s": [100.0, 100.0, 101.0, 102.0, 105.0], "el_rad": np.radians([90.0, 20.0, 30.0, 90.0, 40.0]),
                        "trop_m": [9.0, 9.0, 9.0, 9.0, 9.0]})
    out = troposphere_at_epochs(geo, t_ep, xyz)
    trop = out["trop_m"].to_numpy()
    for i, e in ((0, 0), (1, 0), (3, 2)):
        la, _, h = ecef_to_geodetic(xyz[e])
        np.testing.assert_allclose(trop[i], tropo_hydrostatic_m(geo["el_rad"].to_numpy()[i:i + 1], la, h, geo["time_gps_s"][i])[0],
                                   rtol=1e-12)     # (the one-receiver kernel in C: last bits)
    assert trop[2] == 9.0 and trop[4] == 9.0                  # no position at 101 s; 105 s not in the solution
    assert geo["trop_m"].tolist() == [9.0] * 5                # the input table is not modified
    assert 0.025 < trop[0] - trop[3] < 0.030                  # zenith, 20 m against 120 m above the station: 27 mm


def test_epoch_nis_is_the_double_differences_nis():
    """rtk_multi.epoch_nis on whitened SD rows equals the NIS of explicit double differences (brute force:
    D (z − h) against D (H P Hᵀ + Σ) Dᵀ, D the DD operator of each group against its first row), for the
    phases alone and for phases and codes; its degrees of freedom are the DDs'."""
    from types import SimpleNamespace

    from cdgps_cli.measurement.dd_signals import GroupRows

    rng = np.random.default_rng(11)
    sizes = np.array([5, 3])                        # two signal groups
    M, n = int(sizes.sum()), 9
    Hlin = rng.normal(size=(2 * M, n))
    P = np.cov(rng.normal(size=(n, 40))) * 0.1
    x = rng.normal(size=n)
    var = np.r_[rng.uniform(1e-5, 4e-5, M), rng.uniform(0.1, 0.4, M)]
    z = Hlin @ x + rng.normal(size=2 * M) * np.sqrt(var) + rng.normal(size=2 * M) * 0.01
    rows = GroupRows(z, var, np.r_[sizes, sizes], {"M": M})
    model = SimpleNamespace(groups=[{}, {}], predict=lambda xx, r: (Hlin @ xx, Hlin))

    def brute(k):
        blocks = [(0, 5), (5, 8), (8, 13), (13, 16)][:2 if k == M else 4]
        D = np.zeros((sum(b - a - 1 for a, b in blocks), k))
        r = 0
        for a, b in blocks:
            for j in range(a + 1, b):
                D[r, j], D[r, a] = 1.0, -1.0
                r += 1
        d = D @ (z[:k] - Hlin[:k] @ x)
        C = D @ (Hlin[:k] @ P @ Hlin[:k].T + np.diag(var[:k])) @ D.T
        return float(d @ np.linalg.solve(C, d)), D.shape[0]

    for phase_only, k in ((True, M), (False, 2 * M)):
        got, want = rtk_multi.epoch_nis(model, rows, x, P, phase_only=phase_only), brute(k)
        assert got[1] == want[1] and got[0] == pytest.approx(want[0], rel=1e-9), (got, want)


# the arc filter's bookkeeping: the SD arcs a DD set fixes (_arcs_of), from hand-made set keys

def _arc(sat, half=False, signal="G:L1"):
    return ("N", signal, sat, half)


def test_the_arcs_of_a_set_are_its_references_and_its_resolved_arcs():
    from cdgps_cli.estimation.rtk_multi import _arcs_of

    group = (_arc("G01"), _arc("G02", half=True), _arc("G03"), _arc("G04"))
    other = (_arc("E11", signal="E:E1"), _arc("E12", signal="E:E1"))
    assert _arcs_of(((group, 0), (other, 1))) == {_arc("G01"), _arc("G03"), _arc("G04"), *other}
    # a set with arcs left out names them (third item): they are not fixed, the half-cycle one neither
    assert _arcs_of(((group, 0, (1, 3)),)) == {_arc("G01"), _arc("G03")}
    # the reference is fixed with the rest; sets without arc keys (a caller's own groups) and no set give none
    assert _arc("G04") in _arcs_of(((group, 3),))
    assert _arcs_of((("G:L1", ("G01", "G02"), 0, ()),)) == set() and _arcs_of(None) == set()
