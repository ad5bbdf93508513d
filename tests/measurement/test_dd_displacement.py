"""Satellite DDs on a displacement state (cdgps_cli/measurement/dd_displacement.py): H against central
finite differences of h, the whitened information against the DD weights P = Dᵀ(DΣDᵀ)⁻¹D of
dd_weight_blocks and against the reference-free projected weight (brute force), the rows and labels."""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.measurement.dd_displacement import SatelliteDDDisplacement, SDObservations
from cdgps_cli.measurement.differencing import (dd_operator, dd_weight_blocks, epoch_pointers, projected_weight,
                                                select_reference)


def _case(seed=0, n_ep=12):
    """SD rows of n_ep epochs with 0–7 satellites each (an epoch with one row has no DDs)."""
    gen = np.random.default_rng(seed)
    counts = gen.integers(0, 8, n_ep)
    counts[3] = 1
    epoch = np.repeat(np.arange(n_ep), counts)
    sat = np.concatenate([np.sort(gen.choice(9, c, replace=False)) for c in counts]).astype(np.int64)
    n = sat.size
    ptr = epoch_pointers(epoch, n_ep)
    el = gen.uniform(0.3, 1.5, n)
    usable = gen.uniform(size=n) > 0.1
    ref = select_reference(ptr, sat, el, usable=usable)
    g = gen.normal(size=(n, 3))
    r = gen.normal(size=n) * 0.01 + 1e5          # a common clock term: DDs remove it
    var = gen.uniform(1e-5, 4e-5, n)
    names = [f"G{i + 1:02d}" for i in range(9)]
    model = SatelliteDDDisplacement(ptr, sat, names, g, [SDObservations(r, var, ref, usable=usable)])
    return model, (ptr, epoch, sat, r, g, var, ref, usable)


def test_jacobian_against_finite_differences():
    model, _ = _case()
    x = np.array([0.02, -0.01, 0.03])
    seen = 0
    for k in range(model.n_epochs):
        rows = model.rows(k)
        if rows is None:
            continue
        seen += 1
        h, H = model.predict(x, rows)
        fd = np.column_stack([(model.predict(x + e, rows)[0] - model.predict(x - e, rows)[0]) / 2e-6
                              for e in np.eye(3) * 1e-6])
        np.testing.assert_allclose(H, fd, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(h, H @ x, rtol=1e-14, atol=1e-15)
    assert seen >= 5


def test_whitened_information_equals_the_dd_weights():
    model, (ptr, epoch, sat, r, g, var, ref, usable) = _case(seed=1, n_ep=20)
    checked = 0
    for rows_idx, P in dd_weight_blocks(ptr, var, ref, usable=usable):
        for rws, Pk in zip(rows_idx, P):
            k = int(epoch[rws[0]])
            mk = model.rows(k)
            Hw, zw = mk.whiten(mk.context), mk.whiten(mk.z_m)
            np.testing.assert_allclose(Hw.T @ Hw, g[rws].T @ Pk @ g[rws], rtol=1e-9, atol=1e-6)
            np.testing.assert_allclose(Hw.T @ zw, g[rws].T @ Pk @ r[rws], rtol=1e-6, atol=1e-3)
            # brute force: the reference-free weight (one clock per epoch eliminated)
            Pb = projected_weight(var[rws])
            np.testing.assert_allclose(Hw.T @ Hw, g[rws].T @ Pb @ g[rws], rtol=1e-9, atol=1e-6)
            assert mk.z_m.size == rws.size - 1 and len(mk.labels) == mk.z_m.size
            np.testing.assert_allclose(mk.covariance(), np.linalg.cholesky(mk.covariance()) @
                                       np.linalg.cholesky(mk.covariance()).T)
            checked += 1
    assert checked >= 10
    # epochs without two usable rows give no rows
    no = [k for k in range(model.n_epochs) if ref[k] < 0]
    assert no and all(model.rows(k) is None for k in no)


def test_labels_name_the_satellite_and_its_reference():
    model, (ptr, epoch, sat, r, g, var, ref, usable) = _case(seed=2)
    for k in range(model.n_epochs):
        mk = model.rows(k)
        if mk is None:
            continue
        rws = np.arange(ptr[k], ptr[k + 1])[usable[ptr[k]:ptr[k + 1]]]
        ref_name = f"G{sat[ref[k]] + 1:02d}"
        assert [lab[2] for lab in mk.labels] == [ref_name] * (rws.size - 1)
        assert [lab[1] for lab in mk.labels] == [f"G{s + 1:02d}" for s in sat[rws] if s != sat[ref[k]]]
        assert {lab[0] for lab in mk.labels} == {"phase"}
        np.testing.assert_allclose(mk.z_m, r[rws[rws != ref[k]]] - r[ref[k]], rtol=0, atol=1e-9)
        assert np.all(mk.segment == -1)


def test_ambiguity_columns_and_a_code_kind():
    """x = [δx, a]: the phase DD of satellite j against reference r has +λ at a_j, −λ at a_r (none
    for a known ambiguity); the code DDs (own reference, no ambiguities) follow with independent noise."""
    gen = np.random.default_rng(6)
    n_ep, n_sat = 5, 6
    epoch = np.repeat(np.arange(n_ep), n_sat)
    sat = np.tile(np.arange(n_sat), n_ep)
    ptr = epoch_pointers(epoch, n_ep)
    N = sat.size
    g = gen.normal(size=(N, 3))
    col = sat.copy() - 1                         # satellite 0: known ambiguity (the datum)
    var = gen.uniform(1e-5, 3e-5, N)
    el = gen.uniform(0.3, 1.5, N)
    ref_ph = select_reference(ptr, sat, el)
    code_ok = gen.uniform(size=N) > 0.2
    ref_cd = select_reference(ptr, sat, el, usable=code_ok)
    r_ph, r_cd = gen.normal(size=N), gen.normal(size=N)
    obs = [SDObservations(r_ph, var, ref_ph, ambiguity_col=col),
           SDObservations(r_cd, var * 1e4, ref_cd, usable=code_ok, kind="code")]
    model = SatelliteDDDisplacement(ptr, sat, [f"G{i:02d}" for i in range(n_sat)], g, obs, n_ambiguities=n_sat - 1)
    assert model.n_state == 3 + n_sat - 1
    x = gen.normal(size=model.n_state) * 0.1
    for k in range(n_ep):
        mk = model.rows(k)
        h, H = model.predict(x, mk)
        fd = np.column_stack([(model.predict(x + e, mk)[0] - model.predict(x - e, mk)[0]) / 2e-6
                              for e in np.eye(model.n_state) * 1e-6])
        np.testing.assert_allclose(H, fd, rtol=1e-7, atol=1e-9)
        # the explicit model: phase D [G, λE] and code D G, noise blockdiag(D Σ Dᵀ)
        rows = np.arange(ptr[k], ptr[k + 1])
        E = np.zeros((rows.size, n_sat - 1))
        E[col[rows] >= 0, col[rows][col[rows] >= 0]] = GPS_L1_WAVELENGTH_M
        Dp = dd_operator(rows.size, int(ref_ph[k] - ptr[k]))
        cr = rows[code_ok[rows]]
        Dc = dd_operator(cr.size, int(np.flatnonzero(cr == ref_cd[k])[0]))
        H_want = np.vstack([np.hstack([Dp @ g[rows], Dp @ E]), np.hstack([Dc @ g[cr], np.zeros((cr.size - 1, n_sat - 1))])])
        np.testing.assert_allclose(H, H_want, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(mk.z_m, np.r_[Dp @ r_ph[rows], Dc @ r_cd[cr]], rtol=1e-12, atol=1e-12)
        C_want = np.zeros((H.shape[0],) * 2)
        m = rows.size - 1
        C_want[:m, :m] = (Dp * var[rows]) @ Dp.T
        C_want[m:, m:] = (Dc * var[cr] * 1e4) @ Dc.T
        np.testing.assert_allclose(mk.covariance(), C_want, rtol=1e-12, atol=1e-20)
        assert [lab[0] for lab in mk.labels] == ["phase"] * m + ["code"] * (cr.size - 1)
