"""Shared fixtures: the two shipped structure configs, their text, and a finite-difference helper."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config

REPO_ROOT = Path(__file__).resolve().parent.parent
TESTBED_PATH = REPO_ROOT / "configs" / "testbed-1998-lumped.toml"
DOF2_PATH = REPO_ROOT / "configs" / "teague-1995-2dof.toml"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture(scope="session")
def testbed_path() -> Path:
    return TESTBED_PATH


@pytest.fixture(scope="session")
def dof2_path() -> Path:
    return DOF2_PATH


@pytest.fixture(scope="session")
def testbed_cfg():
    """The 1998 Stanford testbed model (10 coordinates, 9 modes, near-field pseudolites)."""
    return load_config(TESTBED_PATH)


@pytest.fixture(scope="session")
def dof2_cfg():
    """The 1995 two-degree-of-freedom model (2 coordinates, 2 modes, far-field signals)."""
    return load_config(DOF2_PATH)


@pytest.fixture(scope="session")
def testbed_text() -> str:
    return TESTBED_PATH.read_text()


@pytest.fixture(scope="session")
def dof2_text() -> str:
    return DOF2_PATH.read_text()


def _central_diff(f, x: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """Central finite-difference Jacobian of f at the 1-D point x.

    f maps a 1-D array (n,) to an array of any shape S; the result has shape S + (n,).
    """
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(f(x))
    J = np.zeros(f0.shape + (x.size,))
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = step
        J[..., i] = (np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * step)
    return J


@pytest.fixture(scope="session")
def central_diff():
    return _central_diff


@pytest.fixture(scope="session")
def testbed_large_q() -> np.ndarray:
    """Random large-angle testbed states (5, 10): rigid angle q10 up to ±3 rad (first state
    2.5 rad), twists q2, q5, q8 and yaws q3, q6, q9 up to ±0.5 rad, translations up to ±0.3 m."""
    rng = np.random.default_rng(7)
    n = 5
    q = np.empty((n, 10))
    q[:, [0, 3, 6]] = rng.uniform(-0.3, 0.3, (n, 3))
    q[:, [1, 4, 7]] = rng.uniform(-0.5, 0.5, (n, 3))
    q[:, [2, 5, 8]] = rng.uniform(-0.5, 0.5, (n, 3))
    q[:, 9] = rng.uniform(-3.0, 3.0, n)
    q[0, [1, 4, 7]] = [0.5, -0.5, 0.5]
    q[0, 9] = 2.5
    q.setflags(write=False)
    return q


@pytest.fixture(scope="session")
def dof2_large_q() -> np.ndarray:
    """Random large-angle 1995 states (5, 2): hub angles q1, q2 up to ±3 rad."""
    rng = np.random.default_rng(11)
    q = rng.uniform(-3.0, 3.0, (5, 2))
    q[0] = [3.0, -3.0]
    q.setflags(write=False)
    return q
