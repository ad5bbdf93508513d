"""The measurement-model interface (cdgps_cli/measurement/model.py): each implementation's H against
central finite differences of its h, its noise against the covariance it stands for, and its
ambiguity-segment columns."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.measurement.differencing import dd_covariance, joint_dd_covariance
from cdgps_cli.measurement.model import PseudoliteSD, SatelliteDDModal
from cdgps_cli.measurement.phase import phase_model
from cdgps_cli.model.kinematics import antenna_positions

ROOT = Path(__file__).resolve().parents[2]
TOWER = ROOT / "configs" / "gnss-tower.toml"


def _fd_jacobian(model, x, rows, eps=1e-6):
    H = np.zeros((rows.z_m.size, x.size))
    for j in range(x.size):
        dx = np.zeros(x.size)
        dx[j] = eps
        H[:, j] = (model.predict(x + dx, rows)[0] - model.predict(x - dx, rows)[0]) / (2 * eps)
    return H


def _dd_tables(cfg, n_ep=3, n_sat=5, seed=0, slip_at=None):
    """Synthetic SD tables of every rover (satellites far away, random directions)."""
    gen = np.random.default_rng(seed)
    rov = [i for i in range(len(cfg.antenna_names)) if i != cfg.master_index]
    xm = np.array([-3978242.4, 3382841.2, 3649902.8])
    sat_xyz = xm + gen.normal(size=(n_sat, 3)) * 2.0e7
    tabs = []
    for a in rov:
        nrow = n_ep * n_sat
        seg = np.repeat(np.arange(n_sat)[None, :], n_ep, axis=0).reshape(-1) + 100 * a
        if slip_at is not None:
            ep, s = slip_at
            seg[ep * n_sat + s::n_sat] += 50         # satellite s starts a new segment at epoch ep
        d = SimpleNamespace(ptr=np.arange(0, nrow + 1, n_sat), sat=np.tile(np.arange(n_sat), n_ep),
                            sat_names=[f"G{j + 1:02d}" for j in range(n_sat)],
                            rover_sat_xyz=np.tile(sat_xyz, (n_ep, 1)))
        tabs.append({"d": d, "use": np.ones(nrow, dtype=bool), "r0": gen.normal(scale=0.01, size=nrow),
                     "var_rover": gen.uniform(1, 3, nrow) * 1e-5, "var_master": gen.uniform(1, 3, nrow) * 1e-5,
                     "ref": np.arange(n_ep) * n_sat + 1, "xm": xm, "seg": seg})
    k_of = [np.arange(n_ep) for _ in rov]
    p0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)))[0]
    d_hdr = p0[rov] - p0[cfg.master_index]
    return tabs, k_of, np.array(rov), d_hdr


@pytest.mark.parametrize("config", [TOWER, ROOT / "configs" / "teague-1995-2dof.toml"])
def test_satellite_dd_modal_jacobian_is_the_finite_difference(config):
    cfg = load_config(config)
    tabs, k_of, ant, d_hdr = _dd_tables(cfg)
    model = SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr)
    rows = model.rows(1)
    x = np.random.default_rng(1).normal(scale=0.2, size=model.n_state)
    h, H = model.predict(x, rows)
    np.testing.assert_allclose(H, _fd_jacobian(model, x, rows), atol=1e-7)
    assert np.all(H[:, cfg.n_modes:] == 0.0)                  # the rates do not enter
    h0, _ = model.predict(np.zeros(model.n_state), rows)
    np.testing.assert_allclose(h0, 0.0, atol=1e-12)            # nominal = header position: no signal


def test_satellite_dd_modal_noise_and_segments():
    cfg = load_config(TOWER)
    tabs, k_of, ant, d_hdr = _dd_tables(cfg, slip_at=(2, 3))
    model = SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr)
    rows = model.rows(0)
    sats = [[f"G{j + 1:02d}" for j in range(5)]] * len(tabs)
    C = joint_dd_covariance([tb["var_rover"][:5] for tb in tabs], [tb["var_master"][:5] for tb in tabs], sats,
                            [1] * len(tabs))
    np.testing.assert_allclose(rows.covariance(), C, rtol=1e-12)
    np.testing.assert_allclose(rows.covariance()[:4, :4], dd_covariance(tabs[0]["var_rover"][:5] + tabs[0]["var_master"][:5], 1),
                               rtol=1e-12)
    v = np.random.default_rng(2).normal(size=rows.z_m.size)
    np.testing.assert_allclose(rows.whiten(v), np.linalg.solve(np.linalg.cholesky(C), v), rtol=1e-10)
    # z: DD of the SD residuals against the reference; 4 DDs per rover, labelled (slot, satellite)
    np.testing.assert_allclose(rows.z_m[:4], np.delete(tabs[0]["r0"][:5], 1) - tabs[0]["r0"][1])
    assert rows.labels[:4] == [(0, "G01"), (0, "G03"), (0, "G04"), (0, "G05")]
    # segments: the same columns at epoch 1, a new column for G04 of every rover after its slip at epoch 2
    s0, s1, s2 = rows.segment, model.rows(1).segment, model.rows(2).segment
    np.testing.assert_array_equal(s0, s1)
    changed = s2 != s0
    assert [rows.labels[i][1] for i in np.flatnonzero(changed)] == ["G04"] * len(tabs)
    assert len(model.segment_keys) == s0.size + len(tabs)


def test_pseudolite_sd_jacobian_noise_and_segments():
    cfg = load_config(ROOT / "configs" / "testbed-1998-lumped.toml")
    ant = np.repeat(cfg.rover_indices, len(cfg.transmitter_names))
    tx = np.tile(np.arange(len(cfg.transmitter_names)), len(cfg.rover_indices))
    gen = np.random.default_rng(3)
    x = gen.normal(scale=0.05, size=2 * cfg.n_modes)
    y = np.tile(phase_model(cfg, x, ant, tx)[0], (2, 1))
    y[1, 2] = np.nan
    seg = np.tile(np.arange(ant.size) * 3, (2, 1))
    sig = gen.uniform(0.002, 0.004, ant.size)
    model = PseudoliteSD(cfg, y, ant, tx, sig, segment=seg)
    rows = model.rows(1)
    assert rows.z_m.size == ant.size - 1 and rows.labels[0] == (cfg.antenna_names[ant[0]], cfg.transmitter_names[tx[0]])
    h, H = model.predict(x, rows)
    np.testing.assert_allclose(h, rows.z_m, atol=1e-12)        # the data were made by the model
    np.testing.assert_allclose(H, _fd_jacobian(model, x, rows), atol=1e-6)
    np.testing.assert_allclose(rows.covariance(), np.diag(np.delete(sig, 2) ** 2))
    np.testing.assert_array_equal(rows.segment, np.delete(np.arange(ant.size), 2))   # columns, not raw ids
    assert model.rows(0).segment.size == ant.size
    with pytest.raises(ValueError, match="sigma_m"):
        PseudoliteSD(cfg, y, ant, tx, np.zeros(ant.size))


def test_packed_dd_rows_equal_the_per_epoch_rows():
    """pack_dd (vectorized over epochs) = rows(k) of every epoch: values, noise, geometry, segments."""
    from cdgps_cli.measurement.model import pack_dd

    cfg = load_config(TOWER)
    tabs, k_of, ant, d_hdr = _dd_tables(cfg, n_ep=4, slip_at=(2, 3))
    tabs[1]["use"][3 * 5 + 2] = False                          # a row of slot 1 not usable at epoch 3
    k_of[0] = np.array([0, 1, -1, 2])                          # slot 0 misses common epoch 2 …
    tabs[0]["ref"] = np.r_[tabs[0]["ref"][:3], -1]             # … and has no reference at its last epoch
    model = SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr)
    pk = pack_dd(model)
    x = np.random.default_rng(4).normal(scale=0.1, size=model.n_state)
    for k in range(4):
        rows = model.rows(k)
        m = pk.m[k]
        assert m == (0 if rows is None else rows.z_m.size)
        if rows is None:
            continue
        np.testing.assert_allclose(pk.z_m[k, :m], rows.z_m, rtol=1e-15)
        np.testing.assert_allclose(pk.L[k, :m, :m], rows.chol_m, rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(pk.segment[k, :m], rows.segment)
        assert [(int(s), pk.sat_names[j]) for s, j in zip(pk.slot[k, :m], pk.sat[k, :m])] == rows.labels
        h, _ = model.predict(x, rows)
        slot, srows = rows.context
        np.testing.assert_allclose(pk.srows[k, :m], srows, rtol=1e-15)
        np.testing.assert_allclose(pk.hconst_m[k, :m], np.einsum("mi,mi->m", srows, d_hdr[slot]), rtol=1e-13)
        assert np.all(pk.L[k, m:, m:] == np.eye(pk.L.shape[1] - m)) and np.all(pk.z_m[k, m:] == 0)


def _with_code(tabs, ratio=100.0, seed=5):
    """The tables with SD pseudorange residuals (``rc``, m) and the code / phase σ ratio."""
    gen = np.random.default_rng(seed)
    return [dict(tb, rc=gen.normal(scale=1.0, size=tb["r0"].size), code_ratio=ratio) for tb in tabs]


def test_satellite_dd_modal_code_rows_jacobian_noise_and_values():
    """Pseudorange DD rows (``code=True``): after the phase rows, the same far-field h (H = the finite
    difference), no ambiguity (segment −1), z the DD of ``rc``, noise D Σ_P Dᵀ with Σ_P = ratio² Σ built
    here by brute force (SD covariance over every SD of both rovers, D explicit), independent of the phase."""
    cfg = load_config(TOWER)
    tabs, k_of, ant, d_hdr = _dd_tables(cfg)
    tabs = _with_code(tabs, ratio=50.0)
    phase = SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr).rows(1)
    model = SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr, code=True)
    rows = model.rows(1)
    n_p = phase.z_m.size
    assert rows.z_m.size == 2 * n_p
    np.testing.assert_array_equal(rows.z_m[:n_p], phase.z_m)
    np.testing.assert_array_equal(rows.segment[:n_p], phase.segment)
    assert np.all(rows.segment[n_p:] == -1) and rows.labels[n_p] == (0, "G01/code")
    rc = tabs[0]["rc"][5:10]
    np.testing.assert_allclose(rows.z_m[n_p:n_p + 4], np.delete(rc, 1) - rc[1])
    # brute-force covariance: SDs (slot, satellite) of both rovers, the master's noise common per satellite
    n_rov, n_sat = len(tabs), 5
    vr = np.concatenate([tb["var_rover"][5:10] for tb in tabs]) * 50.0**2
    vm = np.concatenate([tb["var_master"][5:10] for tb in tabs]) * 50.0**2
    sat = np.tile(np.arange(n_sat), n_rov)
    S = np.diag(vr) + np.where(sat[:, None] == sat[None, :], np.sqrt(np.outer(vm, vm)), 0.0)
    D = np.zeros((n_rov * (n_sat - 1), n_rov * n_sat))
    for a in range(n_rov):
        for i, j in enumerate(np.delete(np.arange(n_sat), 1)):
            D[a * (n_sat - 1) + i, a * n_sat + j] = 1.0
            D[a * (n_sat - 1) + i, a * n_sat + 1] = -1.0
    C = rows.covariance()
    np.testing.assert_allclose(C[n_p:, n_p:], D @ S @ D.T, rtol=1e-12)
    np.testing.assert_allclose(C[:n_p, :n_p], phase.covariance(), rtol=1e-12)
    assert np.all(C[:n_p, n_p:] == 0.0)
    x = np.random.default_rng(6).normal(scale=0.2, size=model.n_state)
    h, H = model.predict(x, rows)
    np.testing.assert_allclose(H, _fd_jacobian(model, x, rows), atol=1e-7)
    np.testing.assert_allclose(h[n_p:], h[:n_p], rtol=1e-15)   # code and phase DDs see the same geometry


def test_satellite_dd_modal_code_rows_skip_missing_pseudoranges():
    """A satellite without a pseudorange has no code DD; a reference without one, no code DD of that
    rover at that epoch (the phase rows are unchanged)."""
    cfg = load_config(TOWER)
    tabs, k_of, ant, d_hdr = _dd_tables(cfg)
    tabs = _with_code(tabs)
    tabs[0]["rc"][5 + 3] = np.nan            # slot 0, epoch 1: G04 has no code
    tabs[1]["rc"][5 + 1] = np.nan            # slot 1, epoch 1: the reference G02 has no code
    rows = SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr, code=True).rows(1)
    code = [lb for lb in rows.labels if lb[1].endswith("/code")]
    assert code == [(0, "G01/code"), (0, "G03/code"), (0, "G05/code")]
    assert sum(not lb[1].endswith("/code") for lb in rows.labels) == 8


def test_unique_pairs_equals_numpy_unique_of_rows():
    """The one-key pair uniquing used by pack_dd equals np.unique(..., axis=0) (values, order, inverse)."""
    from cdgps_cli.measurement.model import _unique_pairs
    rng = np.random.default_rng(3)
    for n in (0, 1, 7, 2000):
        a, b = rng.integers(-1, 40, n), rng.integers(-1, 300, n)
        pairs, inv = np.unique(np.stack([a, b], axis=1), axis=0, return_inverse=True)
        got_pairs, got_inv = _unique_pairs(a, b)
        np.testing.assert_array_equal(got_pairs, pairs.reshape(-1, 2))
        np.testing.assert_array_equal(got_inv.reshape(-1), inv.reshape(-1))


def test_solve_lower_gives_scipy_solve_triangular_s_numbers():
    """The whitening's trtrs call without scipy's wrapper: bit for bit its numbers, in C and
    Fortran order, for vectors and matrices; empty and mismatched shapes through scipy itself."""
    import numpy as np
    import pytest
    from scipy.linalg import solve_triangular

    from cdgps_cli.measurement.model import solve_lower

    rng = np.random.default_rng(3)
    for m, p in [(1, None), (7, None), (12, 3), (30, 6)]:
        A = rng.normal(size=(m, m))
        L = np.linalg.cholesky(A @ A.T + m * np.eye(m))
        v = rng.normal(size=(m,) if p is None else (m, p))
        for LL in (L, np.asfortranarray(L)):
            want = solve_triangular(LL, v, lower=True, check_finite=False)
            got = solve_lower(LL, v)
            assert got.shape == want.shape and np.array_equal(got, want)
            assert not np.shares_memory(got, v)
    assert solve_lower(np.eye(3), np.zeros((3, 0))).shape == (3, 0)
    with pytest.raises(ValueError):
        solve_lower(np.eye(3), np.zeros(4))
