"""DD measurement model of measurement/dd_signals.py: Jacobian against finite differences, noise D Σ Dᵀ."""

import numpy as np

from cdgps_cli.measurement.dd_signals import epoch_rows


def _case(iono: bool, wet: bool = False):
    rng = np.random.default_rng(4)
    base = np.array([4157177.0, 671230.0, 4774767.0])
    origin = base + np.array([-320.0, 1978.0, 0.0])
    sat = base + rng.normal(size=(5, 3)) * 1.2e7 + np.array([1.5e7, 0, 1.5e7])
    n = 3 + 5 + (5 if iono else 0) + (2 if wet else 0)
    g = {"sat_xyz": sat, "ref": 2, "lam_m": 0.19, "mu": 1.6, "phase_sd_m": rng.normal(size=5), "code_sd_m": rng.normal(size=5),
         "var_phase": np.full(5, 1e-5), "var_code": np.full(5, 0.1), "amb_col": np.arange(3, 8),
         "iono_col": np.arange(8, 13) if iono else np.full(5, -1)}
    if wet:       # the base's and the rover's zenith wet delays, last; mapping factors of a 164 km baseline's elevations
        g.update(wet_col=np.array([n - 2, n - 1]), mw_b=rng.uniform(1.0, 3.9, 5), mw_r=rng.uniform(1.0, 3.9, 5))
    return rng.normal(size=n), [g], base, origin, n


def test_jacobian_matches_finite_differences():
    for iono, wet in ((False, False), (True, False), (True, True), (False, True)):
        x, groups, base, origin, n = _case(iono, wet)
        r0, H, _ = epoch_rows(x, groups, base, origin, n)
        for j in range(n):
            h = 1e-2 if j < 3 else 1e-4   # metres on ranges of 2e7 m: rounding ~1e-9 m
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            fd = -(epoch_rows(xp, groups, base, origin, n)[0] - epoch_rows(xm, groups, base, origin, n)[0]) / (2 * h)
            assert np.allclose(H[:, j], fd, atol=1e-6), (iono, wet, j)


def test_wet_delays_enter_phase_and_code_alike_and_the_engine_model_carries_their_information():
    """The zenith wet delays Z_b, Z_r add m_r Z_r − m_b Z_b to every SD, phase and code (not dispersive): in
    epoch_rows (D applied, here checked term by term) and in the engine's DDGroupModel, whose whitened SD rows carry
    the same information as epoch_rows' Cholesky-whitened DD rows."""
    from types import SimpleNamespace

    from cdgps_cli.measurement.dd_signals import DDGroupModel, dd_operator

    x, groups, base, origin, n = _case(True, True)
    g = groups[0]
    r_wet, H_wet, L = epoch_rows(x, groups, base, origin, n)
    r_dry, H_dry, _ = epoch_rows(x, [{k: v for k, v in g.items() if k not in ("wet_col", "mw_b", "mw_r")}], base,
                                 origin, n)
    D = dd_operator(5, 2)
    term = D @ (g["mw_r"] * x[n - 1] - g["mw_b"] * x[n - 2])
    np.testing.assert_allclose(r_dry - r_wet, np.r_[term, term], atol=1e-9)
    np.testing.assert_allclose(H_wet[:, n - 1], np.r_[D @ g["mw_r"], D @ g["mw_r"]], rtol=1e-14)
    np.testing.assert_allclose(H_wet[:, n - 2], -np.r_[D @ g["mw_b"], D @ g["mw_b"]], rtol=1e-14)
    np.testing.assert_array_equal(H_wet[:, :n - 2], H_dry[:, :n - 2])
    gm = dict(g, sats=np.array([f"G{k:02d}" for k in range(5)], dtype=object), sat_base_xyz=g["sat_xyz"],
              lam_m=np.full(5, 0.19), mu=np.full(5, 1.6))
    model = DDGroupModel(lambda k: [gm], base, origin)
    model.prepare(0, SimpleNamespace(x=x))
    rows = model.rows(0)
    h, H = model.predict(x, rows)
    Hw, vw = rows.whiten(H), rows.whiten(rows.z_m - h)
    Hd, rd = np.linalg.solve(L, H_wet), np.linalg.solve(L, r_wet)
    np.testing.assert_allclose(Hw.T @ Hw, Hd.T @ Hd, rtol=1e-9, atol=1e-9 * np.abs(Hd.T @ Hd).max())
    np.testing.assert_allclose(Hw.T @ vw, Hd.T @ rd, rtol=1e-8, atol=1e-8 * np.abs(Hd.T @ rd).max())
    np.testing.assert_allclose(vw @ vw, rd @ rd, rtol=1e-9)


def test_noise_is_dd_covariance_and_ref_has_no_row():
    x, groups, base, origin, n = _case(False)
    r, H, L = epoch_rows(x, groups, base, origin, n)
    assert r.shape == (8,) and H.shape == (8, n)
    C = L @ L.T
    assert np.allclose(C[:4, :4], 1e-5 * (np.eye(4) + np.ones((4, 4))))
    assert np.allclose(C[:4, 4:], 0)
    # the reference satellite's ambiguity enters every phase row with −λ
    assert np.allclose(H[:4, 3 + 2], -0.19)



def test_a_given_noise_factor_is_reused_and_rows_are_unchanged():
    """Iterated updates pass the epoch's L back in: r and H are those of a full call at the new x."""
    x, groups, base, origin, n = _case(True)
    _, _, L = epoch_rows(x, groups, base, origin, n)
    x2 = x + 0.01
    r_full, H_full, L_full = epoch_rows(x2, groups, base, origin, n)
    r, H, L2 = epoch_rows(x2, groups, base, origin, n, noise_chol=L)
    assert L2 is L and np.array_equal(L_full, L)
    assert np.array_equal(r, r_full) and np.array_equal(H, H_full)


def test_signal_sd_table_dd_is_the_true_integer_per_signal():
    """Two static receivers ~36 m apart on GPS L1/L2 and Galileo E5a (simulator truth), with different
    drifting clocks: per signal, every DD of the SD residual at the true positions, in cycles of that
    signal, is the DD of the simulated integers (fractional biases and receiver clocks cancel) to the
    phase noise, and every DD of the SD pseudorange residual is zero to the code noise; satellites are
    named per signal."""
    from cdgps_cli.core.gps_time import gps_seconds
    from cdgps_cli.core.signals import signal
    from cdgps_cli.estimation.rtk_multi import receiver_geometry
    from cdgps_cli.measurement.dd_signals import signal_sd_table
    from cdgps_cli.measurement.differencing import select_reference
    from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
    from cdgps_cli.model.gps.positioning import synthetic_nav
    from cdgps_cli.sim.gnss_signals import simulate_receiver_signals

    t0, sigs = gps_seconds(2024, 3, 1), ("G:L1", "G:L2", "E:E5a")
    nav = synthetic_nav("GE", t0, 60.0, seed=1)
    xb = np.array([-3978242.4, 3382841.2, 3649902.8])
    xr = xb + np.array([30.0, 20.0, 5.0]) @ enu_matrix(*ecef_to_geodetic(xb)[:2])
    sims = [simulate_receiver_signals(nav, x, t0, 30, 2.0, sigs, seed=k, clock_drift_ms=dr)
            for x, k, dr in ((xb, 1, 2.0), (xr, 2, -3.0))]
    geo = []
    for s, x in zip(sims, (xb, xr)):
        o = s["obs"].assign(wavelength_m=[signal(g).wavelength_m for g in s["obs"]["signal"]])
        geo.append(receiver_geometry(o, nav, x))
    amb = [s["ambiguities"].set_index(["signal", "sat"])["n_cycles"] for s in sims]
    for g in sigs:
        d = signal_sd_table(geo[0][geo[0]["signal"] == g], geo[1][geo[1]["signal"] == g], xb, xr,
                            mask_rad=np.radians(15.0), max_gap_s=None)
        assert d.lam_m == signal(g).wavelength_m and d.t_label.size == 30
        assert all(n.endswith(":" + g.split(":")[1]) for n in d.sat_names)
        ref = select_reference(d.ptr, d.sat, d.el_rover, d.slip)
        names = [n.split(":")[0] for n in d.sat_names]
        n_sd = np.array([amb[1][(g, names[k])] - amb[0][(g, names[k])] for k in d.sat], float)
        rows = np.flatnonzero(np.arange(d.sat.size) != ref[d.epoch])
        r = ref[d.epoch[rows]]
        dd_cycles = (d.r_raw_m[rows] - d.r_raw_m[r]) / d.lam_m
        err = dd_cycles - (n_sd[rows] - n_sd[r])
        assert rows.size > 100 and np.max(np.abs(err)) < 0.25 and np.std(err) < 0.06, (g, np.abs(err).max())
        # the code DDs at the true positions: zero to the code noise (simulated σ 0.5 m per receiver → DD σ 1 m)
        code_dd = d.r_code_m[rows] - d.r_code_m[r]
        assert np.all(np.isfinite(code_dd)) and abs(np.mean(code_dd)) < 0.3 and 0.5 < np.std(code_dd) < 1.5, g


def test_group_layout_equals_the_per_epoch_cut():
    """paired_sd_rows' ``groups`` layout (every epoch's groups and references at once) gives the same
    groups, references and row ranges as cutting each epoch on its own, half-cycle flags included
    (a reference prefers a satellite without one, unless the whole group has it)."""
    from cdgps_cli.measurement.dd_signals import _group_layout, epoch_groups

    rng = np.random.default_rng(11)
    n_ep = 40
    sizes = rng.integers(0, 9, n_ep)                 # rows per epoch, some epochs empty
    ptr = np.r_[0, np.cumsum(sizes)]
    epoch = np.repeat(np.arange(n_ep), sizes)
    code = np.concatenate([np.sort(rng.integers(0, 3, s)) for s in sizes]).astype(np.int64)
    el = rng.choice([0.3, 0.5, 0.7, 0.9], ptr[-1])   # ties: the first of equal elevations
    half = rng.random(ptr[-1]) < 0.4
    keys = ("sats", "lam_m", "mu", "sat_xyz", "sat_base_xyz", "phase_sd_m", "code_sd_m", "slip", "half", "var_phase", "var_code")
    rows = {k: np.zeros(ptr[-1]) for k in keys}
    rows.update(ptr=ptr, code=code, el=el, half=half, names=np.array(["E:E1", "G:L1", "G:L2"]),
                sats=np.array([f"G{i:02d}" for i in range(ptr[-1])], dtype=object))
    with_layout = dict(rows, groups=_group_layout(epoch, code, el, half, n_ep))
    n_groups = 0
    for k in range(n_ep):
        fast, slow = epoch_groups(with_layout, k), epoch_groups(rows, k)
        assert [(g["signal"], g["ref"], g["rows"]) for g in fast] == [(g["signal"], g["ref"], g["rows"]) for g in slow]
        n_groups += len(fast)
    assert n_groups > 30


def test_glonass_codes_weigh_less_while_glonass_is_float():
    """GLONASS code variance × GLONASS_FLOAT_CODE_VARIANCE_FACTOR while float (inter-channel code biases that do not
    cancel), × 1 with glonass_fix (identical receivers) and for every other system."""
    from cdgps_cli.config.options import GLONASS_FLOAT_CODE_VARIANCE_FACTOR
    from cdgps_cli.measurement.dd_signals import glonass_code_factor

    sats = np.array(["G05", "R07", "E11", "C20", "R21:G1", "G05:L1"], dtype=object)
    f = glonass_code_factor(sats, glonass_fix=False)
    assert GLONASS_FLOAT_CODE_VARIANCE_FACTOR > 1
    assert f.tolist() == [1.0, GLONASS_FLOAT_CODE_VARIANCE_FACTOR, 1.0, 1.0, GLONASS_FLOAT_CODE_VARIANCE_FACTOR, 1.0]
    assert np.all(glonass_code_factor(sats, glonass_fix=True) == 1.0)


def test_rows_at_segment_starts_take_the_nearest_epoch_within_half_a_step():
    """signal_sd_table's segment_starts: each (satellite, time) marks that satellite's row at the nearest epoch, when
    within half a step of it; unknown satellites and times off the grid mark nothing."""
    from cdgps_cli.measurement.dd_signals import _rows_at_starts
    names, t_label = np.array(["G01", "G03"]), np.array([10.0, 11.0, 12.0, 13.0])
    epoch, sat = np.repeat(np.arange(4), 2), np.tile([0, 1], 4)
    got = _rows_at_starts([("G03", 12.2), ("G01", 9.9), ("G09", 11.0), ("G01", 14.0), ("G01", 13.6)], names, sat, epoch,
                          t_label, 1.0)
    assert np.flatnonzero(got).tolist() == [0, 5]
    assert not _rows_at_starts([], names, sat, epoch, t_label, 1.0).any()
    assert np.flatnonzero(_rows_at_starts([("G03", 10.0)], names, sat[:2], epoch[:2], t_label[:1], 1.0)).tolist() == [1]


def test_a_step_called_linear_leaves_every_dd_linear_to_the_tolerance():
    """DDGroupModel.linear_within: never without a tolerance; with one, a rover step is called linear up to
    √(tol·ρ_min), and at that length the DD linearization error (brute force: the exact DD change minus its
    first-order term, random satellites at the shortest range and random step directions) is within the tolerance."""
    from cdgps_cli.measurement.dd_signals import MIN_SATELLITE_RANGE_M, DDGroupModel

    tol = 1e-6
    assert not DDGroupModel(None, np.zeros(3), np.zeros(3)).linear_within(np.zeros(5))
    model = DDGroupModel(None, np.zeros(3), np.zeros(3), linearization_tol_m=tol)
    limit = np.sqrt(tol * MIN_SATELLITE_RANGE_M)
    assert model.linear_within(np.r_[0.999 * limit, 0.0, 0.0, 5.0e6])          # ambiguity columns do not count
    assert not model.linear_within(np.r_[0.0, 1.001 * limit, 0.0, 0.0])
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(2000):
        u = rng.normal(size=(2, 3))
        sats = MIN_SATELLITE_RANGE_M * u / np.linalg.norm(u, axis=1)[:, None]
        step = rng.normal(size=3)
        step *= limit / np.linalg.norm(step)
        rng0 = np.linalg.norm(sats, axis=1)
        exact = np.linalg.norm(sats - step, axis=1) - rng0
        first = -(sats / rng0[:, None]) @ step
        worst = max(worst, abs((exact[0] - first[0]) - (exact[1] - first[1])))
    assert 0.3 * tol < worst <= tol
