"""The modal GNSS filter over the engine's interfaces (cdgps_cli/estimation/model_filter.py): the
compiled whitened full-noise path = the numpy path, the outlier gate, the smoother."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.estimation import kernel
from cdgps_cli.estimation.model_filter import filter_dd_kernel, filter_numpy, outlier_gate
from cdgps_cli.estimation.smoother import rts_smooth_transitions as rts_smooth
from cdgps_cli.measurement.model import SatelliteDDModal
from cdgps_cli.model.dynamics_models import ModalZOH

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "measurement"))
from test_model import _dd_tables  # noqa: E402

needs_kernel = pytest.mark.skipif(not kernel.available(), reason="compiled kernel not available")


def _case(n_ep=40, outlier=None):
    cfg = load_config(ROOT / "configs" / "gnss-tower.toml")
    tabs, k_of, ant, d_hdr = _dd_tables(cfg, n_ep=n_ep, n_sat=6, seed=5)
    # data made by the model along a simulated trajectory (+ noise), so the filter has a signal
    model = SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr)
    dyn = ModalZOH(cfg)
    A, _, Q = dyn.transition(1.0)
    gen = np.random.default_rng(6)
    x = np.r_[0.02, -0.015, 0.002, 0.0, 0.0, 0.0]
    for k in range(n_ep):
        rows = model.rows(k)
        h, _ = model.predict(x, rows)
        slot = rows.context[0]
        for a, tb in enumerate(tabs):
            ks = np.flatnonzero(slot == a)
            lo = tb["d"].ptr[k]
            others = [i for i in range(lo, tb["d"].ptr[k + 1]) if i != tb["ref"][k]]
            tb["r0"][tb["ref"][k]] = 0.0
            tb["r0"][others] = h[ks] + 0.003 * gen.standard_normal(ks.size)
        x = A @ x + np.linalg.cholesky(Q + 1e-18 * np.eye(6)) @ gen.standard_normal(6)
    if outlier is not None:
        k, r = outlier
        tabs[0]["r0"][tabs[0]["d"].ptr[k] + r] += 0.5
    time_s = np.arange(n_ep, dtype=float)
    time_s[25:] += 1.0                                   # one gap: another spacing (a Python epoch)
    P0 = np.diag([1.0] * 3 + [1.0] * 3)
    return SatelliteDDModal(cfg, np.eye(3), tabs, k_of, ant, d_hdr), dyn, time_s, np.zeros(6), P0


@needs_kernel
def test_kernel_dd_path_equals_numpy_path():
    model, dyn, t, x0, P0 = _case()
    ref = filter_numpy(model, dyn, t, x0, P0)
    got = filter_dd_kernel(model, dyn, t, x0, P0)
    np.testing.assert_allclose(got["x"], ref["x"], rtol=1e-8, atol=1e-11)
    np.testing.assert_allclose(got["P"], ref["P"], rtol=1e-7, atol=1e-15)
    np.testing.assert_allclose(got["nis"], ref["nis"], rtol=1e-7, atol=1e-9)
    np.testing.assert_array_equal(got["nis_dof"], ref["nis_dof"])
    np.testing.assert_allclose(got["A"], ref["A"])
    xs, Ps = rts_smooth(got["x"], got["P"], got["A"], got["Q"])
    assert np.all(np.diagonal(Ps, axis1=1, axis2=2) <= np.diagonal(got["P"], axis1=1, axis2=2) * (1 + 1e-9))


@needs_kernel
def test_outlier_gate_drops_the_row_on_both_paths():
    model, dyn, t, x0, P0 = _case(outlier=(30, 2))
    ev_n, ev_k = [], []
    ref = filter_numpy(model, dyn, t, x0, P0, rows_hook=outlier_gate(model, 6.0, ev_n, t))
    got = filter_dd_kernel(model, dyn, t, x0, P0, outlier_sigma=6.0, events=ev_k)
    assert [(e["epoch"], e["label"]) for e in ev_k] == [(e["epoch"], e["label"]) for e in ev_n]
    assert any(e["epoch"] == 30 and e["label"][0] == 0 for e in ev_k)
    np.testing.assert_allclose(got["x"], ref["x"], rtol=1e-8, atol=1e-11)
    assert got["nis_dof"][30] == ref["nis_dof"][30] == model.rows(30).z_m.size - 1
    # without the gate the 0.5 m jump enters the state
    plain = filter_numpy(model, dyn, t, x0, P0)
    assert np.max(np.abs(plain["x"][30] - ref["x"][30])) > 1e-3
