"""Shared fixtures: the two shipped structure configs, their text, and a finite-difference helper."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config

REPO_ROOT = Path(__file__).resolve().parent.parent


def _every_cpu_runs_a_worker() -> bool:
    """True in a pytest-xdist worker when the workers are at least as many as the CPUs this process may use."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT") or 0)
    if not os.environ.get("PYTEST_XDIST_WORKER") or workers == 0:
        return False
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    return workers >= cpus


# A pair's two receivers and rtk's two passes are computed on two cores (cdgps_cli.core.beside: a forked child
# beside the caller, the same bits as in turn).  When every CPU already runs a test worker (`make test` on 2 or
# 4 cores) there is no core to spare: a fork only adds its cost (the child faulting in its pages, the parent's
# copy-on-write) — 100 of the suite's 622 CPU seconds, 1,400 forks of a worker process of ~340 MiB.  There the
# commands run the two in turn (CDGPS_SERIAL=1, as on a one-CPU machine), unless the environment says otherwise
# (CDGPS_SERIAL=0 make test: everything forked, as before).  The forked path keeps tests of its own, which force
# it (the ``forking`` fixture): tests/core/test_beside.py, tests/pipeline/test_rtk_passes_beside.py,
# tests/io/test_gnss_run_beside.py, tests/estimation/test_baseline.py and tests/pipeline/test_pair_beside.py
# (each call site of core.beside, forked against in turn, bytes and warnings).
if _every_cpu_runs_a_worker():
    os.environ.setdefault("CDGPS_SERIAL", "1")


@pytest.fixture
def forking(monkeypatch):
    """The commands fork beside (core.beside) where the machine can, whatever the suite's default
    (CDGPS_SERIAL=1 under pytest-xdist on every CPU, above)."""
    monkeypatch.setenv("CDGPS_SERIAL", "0")
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


#: the suite's slowest files (CPU seconds on a 2-core CI machine, session 36: the 24 over 7 s of its 630), handed to
#: the pytest-xdist workers first (``make test``'s ``--dist loadfile`` gives out whole files in collection order): a
#: long file collected last — docs/commands.md's blocks, 19 s, sit near the end alphabetically — would otherwise run
#: alone on one worker while the other has finished.  The other files keep their order after these.
HEAVY_FIRST = (
    "tests/pipeline/test_batch_dask.py", "tests/test_doc_commands_run_commands.py", "tests/report/test_run_report.py",
    "tests/pipeline/test_batch_faults.py", "tests/estimation/test_filter_rest.py", "tests/test_doc_commands_run.py",
    "tests/estimation/test_initializer.py", "tests/pipeline/test_gnss_real_pairs.py",
    "tests/pipeline/test_estimate_windows.py", "tests/pipeline/test_if_chain.py", "tests/report/test_sensor_reports.py",
    "tests/pipeline/test_gnss.py", "tests/analysis/test_spectra.py", "tests/test_paper_quick.py",
    "tests/io/test_log_fast_path.py", "tests/pipeline/test_batch_dask_resume.py", "tests/pipeline/test_gnss_modal.py",
    "tests/tracking/test_aiding.py", "tests/pipeline/test_gnss_multipath.py", "tests/estimation/test_init_golden.py",
    "tests/io/test_ubx_hours.py", "tests/golden/test_golden_chains.py", "tests/pipeline/test_gnss_glonass_fix.py",
    "tests/pipeline/test_init_real_edits.py",
)


def pytest_collection_modifyitems(session, config, items):
    """The files of :data:`HEAVY_FIRST` first, in its order (a stable sort: each file's tests stay together and in
    their order, as module fixtures need)."""
    rank = {path: i for i, path in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(Path(str(item.path)).relative_to(REPO_ROOT).as_posix(), len(rank)))
