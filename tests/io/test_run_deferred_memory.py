"""read_run's deferred phase columns keep only their own packed bytes (issue 29: not every
attachment of the RUN, which is the RUN's size in memory for as long as the run is held)."""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.table import Deferred
from cdgps_cli.io.run import PHASE_PACKED, read_run, write_run
from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation


def _deferred(obj, seen=None):
    """Every Deferred reachable from the table's attributes (dicts, tuples, lists)."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return []
    seen.add(id(obj))
    if isinstance(obj, Deferred):
        return [obj]
    if isinstance(obj, dict):
        return [d for v in obj.values() for d in _deferred(v, seen)]
    if isinstance(obj, (list, tuple)):
        return [d for v in obj for d in _deferred(v, seen)]
    if hasattr(obj, "__dict__") and not isinstance(obj, np.ndarray):
        return [d for v in vars(obj).values() for d in _deferred(v, seen)]
    return []


def test_deferred_columns_hold_one_attachment(testbed_cfg, tmp_path):
    sim = simulate(testbed_cfg, SimOptions(duration_s=3.0, seed=1))
    write_simulation(sim, tmp_path)
    write_run(testbed_cfg, tmp_path / "receiver.csv", tmp_path / "run.mcap")
    run = read_run(tmp_path / "run.mcap")
    deferred = _deferred(run.phase)
    assert len(deferred) == 3                           # receiver, master, snr_dbhz
    for d in deferred:
        held = [c.cell_contents for c in d.make.__closure__ if isinstance(c.cell_contents, dict)]
        assert len(held) == 1 and len(held[0]) == 1 and next(iter(held[0])).startswith(PHASE_PACKED)
    assert np.isfinite(run.phase["snr_dbhz"]).all()     # and they still decode
    assert len(run.phase.codes("receiver")[1]) >= 1
