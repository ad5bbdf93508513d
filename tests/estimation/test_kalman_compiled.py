"""The static engine's compiled update (``_ekfcore.sd_update`` through
:func:`cdgps_cli.estimation.kalman.iterated_update_covariance`) gives the numpy path's x, P and NIS bit for bit,
epoch by epoch, on the real DD rows of the Spirent G+E L1+L2 pair (both memory orders of the satellite positions:
epochs whose groups are one view of the run and epochs whose groups are concatenated), and hands back to numpy
(None) the cases it does not cover."""

import numpy as np
import pytest

from cdgps_cli.estimation import kalman
from cdgps_cli.estimation import static_engine as se
from tests.measurement.test_dd_run_model import BASE, ROVER, run  # noqa: F401  (the module's fixture)


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.fixture()
def kernel():
    fn = kalman._sd_kernel()
    if not fn:
        pytest.skip("the compiled kernel or numpy's OpenBLAS is not available")
    return fn


@pytest.mark.parametrize("max_iterations, order", [(1, "F"), (2, "F"), (3, "F"), (2, "C")])
def test_compiled_update_is_the_numpy_update_epoch_by_epoch(run, kernel, monkeypatch, max_iterations, order):  # noqa: F811
    """Every epoch, both paths from the same prior; the satellite positions as the run holds them (pandas'
    column-major order) or C-ordered (numpy's einsum sums ‖los‖² in another order then)."""
    rows, cols, times = run
    if order == "C":
        rows = {**rows, "sat_xyz": np.ascontiguousarray(rows["sat_xyz"])}
    seen = {"compiled": 0, "c_order": 0, "f_order": 0, "second_iteration": 0}
    numpy_path = kalman.iterated_update_covariance

    def both(model, mk, xbar, Pbar, max_it=5, sparse=True, kernel=None):
        assert kernel is kalman._sd_kernel()                # the filter looked it up once
        want = numpy_path(model, mk, xbar, Pbar, max_it, sparse, kernel=False)
        got = kalman._compiled_range_update(model.range_terms(mk), mk, xbar, Pbar, max_it)
        assert got is not None
        assert _same(got[0], want[0]) and _same(got[1], want[1]) and _same(got[2], want[2])
        sx = mk.context["sat_xyz"]
        seen["compiled"] += 1
        seen["c_order" if sx.strides[1] == 8 else "f_order"] += 1
        seen["second_iteration"] += int(not _same(want[0], numpy_path(model, mk, xbar, Pbar, 1, sparse, kernel=False)[0]))
        return want

    monkeypatch.setattr(kalman, "iterated_update_covariance", both)
    se.static_filter(rows, times, BASE, ROVER, cols=cols, max_iterations=max_iterations)
    assert seen["compiled"] >= times.size - 2 and seen[f"{order.lower()}_order"] == seen["compiled"]
    assert (seen["second_iteration"] > 0) == (max_iterations > 1)


def test_static_filter_with_and_without_the_kernel(run, kernel, monkeypatch):  # noqa: F811
    rows, cols, times = run
    x1, P1, _ = se.static_filter(rows, times, BASE, ROVER, cols=cols)
    monkeypatch.setenv("CDGPS_NO_KERNEL", "1")
    assert kalman._compiled_range_update((None,) * 9, None, None, None, 2) is None
    x0, P0, _ = se.static_filter(rows, times, BASE, ROVER, cols=cols)
    assert _same(x0, x1) and _same(P0, P1)


def _epoch(run, k=12):  # noqa: F811
    """One epoch's model, rows and prior (x̄, P̄) of the run."""
    rows, cols, _ = run
    n = int(cols.max()) + 1
    model = se._model(rows, cols, BASE, ROVER)
    xbar = np.random.default_rng(5).normal(size=n) * np.r_[0.5, 0.5, 0.5, np.full(n - 3, 40.0)]
    model.prepare(k, type("Ctx", (), {"x": xbar})())
    A = np.random.default_rng(6).normal(size=(n, n))
    return model, model.rows(k), xbar, A @ A.T + n * np.eye(n)


def test_cases_it_does_not_cover_go_back_to_numpy(run, kernel):  # noqa: F811
    model, mk, xbar, Pbar = _epoch(run)
    terms = model.range_terms(mk)
    sx, sb, base, lam, amb, origin, u, inv, blk = terms
    upd = kalman._compiled_range_update

    def with_(**kw):
        t = {**dict(zip(("sx", "sb", "base", "lam", "amb", "origin", "u", "inv", "blk"), terms)), **kw}
        return upd(tuple(t.values()), mk, xbar, Pbar, 2)

    assert with_() is not None
    dup = amb.copy()
    dup[1] = dup[0]
    assert with_(amb=dup) is None                                   # two rows on one column
    assert with_(amb=np.minimum(amb, 2)) is None                    # a position column
    zero = lam.copy()
    zero[0] = 0.0
    assert with_(lam=zero) is None                                  # an inactive column
    n_dense = 3 + lam.size                                          # every column active: the dense form
    assert upd((sx, sb, base, lam, np.arange(3, n_dense), origin, u, inv, blk), mk, xbar[:n_dense],
               Pbar[:n_dense, :n_dense], 2) is None
    assert with_(sx=np.ascontiguousarray(sx[:, ::-1]), sb=np.ascontiguousarray(sb)) is not None
    assert with_(sx=sx[::-1, ::-1]) is None                         # negative strides
    assert with_(sb=sb[::-1]) is None
    assert upd(terms, mk, xbar, np.asfortranarray(Pbar + np.triu(Pbar, 1) * 1e-9), 2) is None
    assert with_(blk=blk.astype(np.int32)) is None                  # not the layout's int64


def test_rows_form_their_whitening_and_h_template_on_first_use(run):  # noqa: F811
    """RunDDModel's rows hold B, the base ranges and H unformed until the numpy path reads them."""
    model, mk, xbar, Pbar = _epoch(run)
    assert mk._B is None and "H" not in mk.context and "base_rng" not in mk.context
    kalman.iterated_update_covariance(model, mk, xbar, Pbar, 2)
    if kalman._sd_kernel():                                         # the compiled update formed neither
        assert mk._B is None and "H" not in mk.context and "base_rng" not in mk.context
    B = mk.B
    assert mk.B is B
    H = mk.context["H"]
    assert mk.context["H"] is H and H.shape == (mk.z_m.size, xbar.size)
    with pytest.raises(KeyError):
        mk.context["nothing"]


def test_a_covariance_that_is_not_positive_definite_raises_as_before(run, kernel):  # noqa: F811
    model, mk, xbar, Pbar = _epoch(run)
    bad = -Pbar
    assert kalman._compiled_range_update(model.range_terms(mk), mk, xbar, bad, 2) is None
    with pytest.raises(np.linalg.LinAlgError):
        kalman.iterated_update_covariance(model, mk, xbar, bad, 2)
