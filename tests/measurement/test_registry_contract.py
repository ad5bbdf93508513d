"""Every registered measurement model passes one contract (issue 30 item 4): shapes, labels, units in
field names, positive-definite noise, H = ∂h/∂x against central finite differences, rows only at the
model's own epochs."""

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.measurement.registry import REGISTRY, UNITS

CFG = load_config("configs/testbed-1998.toml")
N = 12


@pytest.fixture(params=sorted(REGISTRY))
def model(request):
    kind = REGISTRY[request.param]
    return request.param, kind, kind.example(CFG, np.random.default_rng(3), N)


def test_registered_unit_is_known():
    for name, kind in REGISTRY.items():
        assert kind.unit in UNITS, name


def test_contract(model):
    name, kind, m = model
    assert isinstance(m, kind.cls)
    assert m.n_epochs == N and m.n_state >= 2 * CFG.n_modes
    rng = np.random.default_rng(7)
    x = rng.standard_normal(m.n_state) * 0.01
    seen = 0
    for k in range(N):
        r = m.rows(k)
        if hasattr(m, "k_of") and np.ndim(m.k_of) == 1:          # a sampled sensor: rows at its own epochs only
            assert (r is None) == (m.k_of[k] < 0), k
        if r is None:
            continue
        seen += 1
        n_rows = r.z_m.shape[0]
        assert r.z_m.shape == (n_rows,) and n_rows > 0
        assert len(r.labels) == n_rows and all(isinstance(lb, tuple) for lb in r.labels)
        assert r.segment.shape == (n_rows,) and r.segment.dtype.kind == "i"
        assert (r.sigma_m is None) != (r.chol_m is None)
        C = r.covariance()
        assert np.allclose(C, C.T) and np.linalg.eigvalsh(C).min() > 0
        if getattr(kind.cls, "quantity", ""):                     # sensors: units in the field names
            assert all(lb[1].endswith("_" + kind.unit) for lb in r.labels), r.labels
        h, H = m.predict(x, r)
        assert h.shape == (n_rows,) and H.shape == (n_rows, m.n_state)
        eps = 1e-6
        Hfd = np.column_stack([(m.predict(x + eps * e, r)[0] - m.predict(x - eps * e, r)[0]) / (2 * eps)
                               for e in np.eye(m.n_state)])
        assert np.allclose(H, Hfd, rtol=1e-6, atol=1e-7 * max(1.0, np.abs(H).max())), name
    assert seen > 0
    for nm_, prior, drift in getattr(m, "extra_states", ()):
        assert nm_.endswith("_" + kind.unit) and prior > 0 and drift >= 0


def test_contract_can_fail():
    """A model whose H is off by 1 % in one column fails the finite-difference check (the check can fail)."""
    m = REGISTRY["gyro"].example(CFG, np.random.default_rng(3), N)
    r = m.rows(0)
    x = np.zeros(m.n_state)
    eps = 1e-6
    Hfd = np.column_stack([(m.predict(x + eps * e, r)[0] - m.predict(x - eps * e, r)[0]) / (2 * eps)
                           for e in np.eye(m.n_state)])
    H = m.predict(x, r)[1]
    assert np.allclose(H, Hfd, rtol=1e-6, atol=1e-9)
    j = int(np.argmax(np.abs(H).sum(axis=0)))
    H[:, j] *= 1.01
    assert not np.allclose(H, Hfd, rtol=1e-6, atol=1e-7 * max(1.0, np.abs(H).max()))
