"""DD residuals of the modal path (cdgps_cli/pipeline/gnss_modal.py ``_dd_residuals``): made in one
pass on a disk history (columns by first appearance, then sorted) they equal the in-memory two-pass
result exactly, channels and every value (NaN where a channel was not used), across block ends."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

import cdgps_cli.pipeline.gnss_modal as gm
from cdgps_cli.io.scratch import DiskHistory
from cdgps_cli.measurement.model import Rows


class _Model:
    """Two slots over four satellites; h = the sum of x times the row number + 1."""

    code = False

    def __init__(self):
        self.tabs = [{"d": SimpleNamespace(sat_names=["G01", "G02", "G03", "G04"])} for _ in range(2)]

    def predict(self, x, rows):
        w = np.arange(1, rows.z_m.size + 1, dtype=float)
        return w * x.sum(), np.outer(w, np.ones(x.size))


def _meas(n, seed=5):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        if k % 7 == 3:
            out.append(None)
            continue
        labels = [(a, s) for a in (1, 0) for s in ("G04", "G02", "G01") if rng.random() < 0.7]
        if k < 20:
            labels = [lb for lb in labels if lb[1] != "G01"]          # G01 appears late: a later column
        if not labels:
            out.append(None)
            continue
        m = len(labels)
        out.append(Rows(rng.normal(size=m), labels, np.full(m, -1), sigma_m=np.ones(m)))
    return out


def test_one_pass_on_disk_equals_the_two_pass_in_memory(tmp_path, monkeypatch):
    monkeypatch.setattr(gm, "ESTIMATE_CHUNK_EPOCHS", 16)
    n = 75
    xs = np.random.default_rng(2).normal(size=(n, 3))
    meas, model, slots = _meas(n), _Model(), ["base", "top"]
    ref_ch, ref = gm._dd_residuals(model, meas, xs, slots)
    disk = DiskHistory(tmp_path)
    got_ch, got = gm._dd_residuals(model, meas, xs.copy(), slots, disk)
    assert got_ch == ref_ch and len(ref_ch) == 6
    assert isinstance(got, np.memmap)
    assert np.array_equal(np.asarray(got), ref, equal_nan=True)
    assert np.isfinite(ref).any() and np.isnan(ref).any()
