"""grouped_epoch_fit (measurement/epoch_fit.py): each epoch's least squares for 3 parameters and one term per
group, against numpy's lstsq on the explicit design (the 3 columns and one indicator column per group)."""

from __future__ import annotations

import numpy as np

from cdgps_cli.measurement.epoch_fit import grouped_epoch_fit


def test_each_epoch_is_its_own_weighted_least_squares():
    """Four epochs of 7–11 rows in two or three groups, random weights (one row weighted 0: left out): every epoch's
    solution, χ² and inverse normal matrix as lstsq on the explicit weighted design gives them (1e-9); an epoch
    marked not usable, and one whose rows cannot fix the 3 parameters, are not fitted."""
    rng = np.random.default_rng(3)
    ys, ws, gs, groups, epochs, n_grp = [], [], [], [], [], 0
    for e, (m, k) in enumerate([(9, 2), (11, 3), (7, 2), (8, 2)]):
        g = rng.normal(size=(m, 3)) if e != 3 else np.tile(rng.normal(size=(1, 3)), (m, 1))   # epoch 3: rank 1
        grp = n_grp + np.arange(m) % k
        n_grp += k
        ys.append(g @ rng.normal(size=3) + rng.normal(size=k)[grp - (n_grp - k)] + rng.normal(0, 0.01, m))
        w = rng.uniform(0.5, 2.0, m)
        w[0] = 0.0 if e == 0 else w[0]
        ws.append(w), gs.append(g), groups.append(grp), epochs.append(np.full(m, e))
    y, w, g, grp, ep = map(np.concatenate, (ys, ws, gs, groups, epochs))
    usable = np.array([True, True, False, True])
    fit = grouped_epoch_fit(y, w, g, grp, ep, n_grp, 4, usable=usable)
    assert fit.ok.tolist() == [True, True, False, False]
    for e in (0, 1):
        r = ep == e
        cols = np.unique(grp[r])
        A = np.column_stack([g[r]] + [(grp[r] == c).astype(float) for c in cols])
        sw = np.sqrt(w[r])
        sol, *_ = np.linalg.lstsq(A * sw[:, None], y[r] * sw, rcond=None)
        res = y[r] - A @ sol
        np.testing.assert_allclose(fit.step[e], sol[:3], atol=1e-9)
        np.testing.assert_allclose(fit.chi2[e], np.sum(w[r] * res**2), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(fit.n_inv[e], np.linalg.inv((A * w[r][:, None]).T @ A)[:3, :3], rtol=1e-8, atol=1e-12)
    assert not fit.step[2:].any() and not fit.chi2[2:].any()
