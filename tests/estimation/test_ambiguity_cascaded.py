"""Cascaded partial ambiguity resolution (``ambiguity.resolve_cascaded``) and its conditional float.

The case is the one the cascade is for (a u-blox static baseline's many short lock arcs): six well
determined ambiguities ("long arcs", σ ≈ 0.05 cycle, correlated), four whose float is tied to them
(``a_S = z_S + A (a_L − z_L) + ε``, σ_ε = 0.02 cycle: marginally σ of cycles, given the long arcs' integers
0.02 cycle) and two hopeless ones (independent, σ = 1.5 cycle: arcs of a few epochs).  The full set fails
on the hopeless two; partial fixing drops by marginal variance, so the tied four go before the hopeless two
and one stage fixes the long six only; conditioned on them, the tied four pass.
"""

import numpy as np
import pytest

from cdgps_cli.estimation.ambiguity import conditioned_on_integers, resolve, resolve_cascaded


LONG, TIED, HOPELESS = 6, 4, 2


def _case(seed: int = 0):
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(LONG, LONG))
    Q_L = 0.05**2 * (B @ B.T / LONG + 0.5 * np.eye(LONG))
    A = rng.normal(scale=30.0, size=(TIED, LONG))
    Q = np.zeros((LONG + TIED + HOPELESS,) * 2)
    Q[:LONG + TIED, :LONG + TIED] = np.block([[Q_L, Q_L @ A.T], [A @ Q_L, A @ Q_L @ A.T + 0.02**2 * np.eye(TIED)]])
    Q[LONG + TIED:, LONG + TIED:] = 1.5**2 * np.eye(HOPELESS)
    z = rng.integers(-20, 20, size=Q.shape[0]).astype(float)
    return Q, z, rng


def _draw(Q, z, rng):
    return z + np.linalg.cholesky(Q) @ rng.normal(size=z.size)


def test_the_conditional_float_is_the_information_forms():
    Q, z, rng = _case(1)
    a = _draw(Q, z, rng)
    mask = np.zeros(z.size, dtype=bool)
    mask[[0, 2, 3, 5, 7]] = True
    a_r, Q_r = conditioned_on_integers(a, Q, mask, z.astype(np.int64))
    L = np.linalg.inv(Q)                     # information form: Q_r|f = Λ_rr⁻¹, â_r|f = â_r − Λ_rr⁻¹ Λ_rf (z_f − â_f)
    f, r = np.flatnonzero(mask), np.flatnonzero(~mask)
    Q_ref = np.linalg.inv(L[np.ix_(r, r)])
    a_ref = a[r] - Q_ref @ L[np.ix_(r, f)] @ (z[f] - a[f])
    np.testing.assert_allclose(Q_r, Q_ref, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(a_r, a_ref, rtol=0, atol=1e-9)
    assert np.array_equal(Q_r, Q_r.T)


def test_one_stage_fixes_the_long_arcs_only_the_cascade_the_tied_ones_too():
    Q, z, rng = _case(0)
    a = _draw(Q, z, rng)
    one = resolve(a, Q, 3.0, partial=True, min_success_rate=0.999)
    assert one["fixed_mask"][:LONG].all() and not one["fixed_mask"][LONG:].any()
    got = resolve_cascaded(a, Q, 3.0, min_success_rate=0.999)
    want = np.r_[np.ones(LONG + TIED, bool), np.zeros(HOPELESS, bool)]
    np.testing.assert_array_equal(got["fixed_mask"], want)
    np.testing.assert_array_equal(got["integers"][want], z[want])
    assert got["n_fixed"] == LONG + TIED and got["partial"]
    assert got["stages"][0] == {"candidates": 12, "fixed": LONG, "ratio": one["ratio"]}
    assert [(s["candidates"], s["fixed"]) for s in got["stages"][1:]] == [(TIED + HOPELESS, TIED), (HOPELESS, 0)]
    assert got["ratio"] == one["ratio"]                                     # the first stage's figures stay


def test_no_wrong_integer_over_many_draws():
    """Monte Carlo of the same case: every integer the cascade fixes is the true one (300 draws)."""
    Q, z, rng = _case(2)
    fixed = wrong = 0
    for _ in range(300):
        got = resolve_cascaded(_draw(Q, z, rng), Q, 3.0, min_success_rate=0.999)
        m = got["fixed_mask"]
        fixed += int(m.sum())
        wrong += int((got["integers"][m] != z[m]).sum())
    assert wrong == 0 and fixed > 0.9 * 300 * (LONG + TIED)


def test_a_stage_that_fixes_nothing_ends_it_and_nothing_fixed_stays_nothing():
    Q, z, rng = _case(3)
    hopeless = 25.0 * Q                                         # σ ≈ 0.25 cycle: nothing passes
    got = resolve_cascaded(_draw(hopeless, z, rng), hopeless, 3.0, min_success_rate=0.999)
    assert got["n_fixed"] == 0 and not got["accepted"] and len(got["stages"]) == 1


@pytest.mark.parametrize("stages", [1, 2])
def test_max_stages_caps_the_cascade(stages):
    Q, z, rng = _case(0)
    a = _draw(Q, z, rng)
    got = resolve_cascaded(a, Q, 3.0, min_success_rate=0.999, max_stages=stages)
    assert len(got["stages"]) <= stages
    if stages == 1:
        assert got["n_fixed"] == resolve(a, Q, 3.0, partial=True, min_success_rate=0.999)["n_fixed"]
