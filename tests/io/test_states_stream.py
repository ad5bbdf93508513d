"""The streaming STATES writer (issue 29) writes the bytes of the whole-record writer it replaced.

``tests/io/_states_writer_reference.py`` is the writer as it was (commit 6b76c01).  For estimates of
both kinds — a smoothed structure (forward filter, sigma-only forward covariance, NaN epochs, events,
angles, an anti-aliased preview), the same with ``--covariance full``, an asymmetric covariance (P_xi
instead of its triangle), and GNSS displacements (C = I, extra arrays) — the new writer gives the same
file, byte for byte, in chunks of 7, 1024 and more epochs than the record, from arrays in memory or
on disk (:class:`cdgps_cli.io.scratch.DiskHistory`).  The preview filter in blocks equals the whole-run
one bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.analysis.preview import anti_alias_decimate
from cdgps_cli.core.records import Series, StateSeries
from cdgps_cli.io import states as new
from cdgps_cli.io.scratch import DiskHistory
from cdgps_cli.io.states import STATE_FILTERED_TOPIC, STATE_TOPIC

from tests.io import _states_writer_reference as old

N = 2600


def _structure(kind: str = "modal", seed: int = 3, on_disk: bool = False) -> StateSeries:
    rng = np.random.default_rng(seed)
    nm, nq, C_ch = 4, 6, 5
    t = 100.0 + np.arange(N) * 0.1
    U = rng.normal(size=(nq, nm))
    store = DiskHistory() if on_disk else None

    def arr(shape):
        return np.empty(shape) if store is None else store.empty(shape)

    def series(smoothed, s):
        r = np.random.default_rng(s)
        x = arr((N, 2 * nm))
        x[:] = np.cumsum(r.normal(size=(N, 2 * nm)), axis=0) * 1e-3 + np.sin(2 * np.pi * 1.3 * t)[:, None] * 1e-2
        x[500:503, :nm] = np.nan                                    # a gap: the preview filters runs on their own
        A = r.normal(size=(N, 2 * nm, 2 * nm)) * 1e-3
        P = arr((N, 2 * nm, 2 * nm))
        P[:] = np.einsum("kij,klj->kil", A, A) + np.eye(2 * nm) * 1e-6
        if kind == "asymmetric":
            P[7, 0, 1] += 1e-12
        return Series(t, x, P, smoothed)

    resid = rng.normal(size=(N, C_ch)) * 1e-3
    resid[rng.random((N, C_ch)) < 0.1] = np.nan
    nis = rng.chisquare(3, N)
    nis[:20] = np.nan
    events = [{"time_s": float(t[40]), "antenna": "a1", "transmitter": "p2", "kind": "slip", "action": "re-bias",
               "jump_m": 0.19}]
    return StateSeries("structure", [f"q{i}" for i in range(nq)], ["m"] * nq, U, nm,
                       {STATE_TOPIC: series(True, 1), STATE_FILTERED_TOPIC: series(False, 2)},
                       [("a1", f"p{i}") for i in range(C_ch)], resid, nis, np.full(N, 3), events, 0.19)


def _displacement() -> StateSeries:
    rng = np.random.default_rng(5)
    t = 1.4e9 + np.arange(N) * 1.0
    x = rng.normal(size=(N, 3)) * 1e-3
    x[10:12, 1] = np.nan
    P = np.broadcast_to(np.eye(3) * 1e-6, (N, 3, 3)).copy()
    extra = {"n_sat": rng.integers(4, 12, N), "pdop": rng.random(N) + 1}
    return StateSeries("displacement", ["E", "N", "U"], ["m"] * 3, np.eye(3), 0,
                       {"/cdgps/kinematic": Series(t, x, P, False, extra, messages=False),
                        STATE_TOPIC: Series(t, x, P, False)},
                       [("r", "G01")], np.zeros((N, 1)), np.ones(N), np.ones(N, dtype=int), [], 0.19)


ANGLES = [("C1_z", "q0+q3", np.array([1.0, 0, 0, 1.0, 0, 0])), ("body_z", "q5", np.array([0, 0, 0, 0, 0, 1.0]))]


def _both(tmp_path, ss, chunk, **kw):
    kw_old = dict(kw)
    if kw.get("preview") is not None:
        kw_old["preview"] = old.reference_anti_alias_decimate
    a, b = tmp_path / "old.mcap", tmp_path / "new.mcap"
    s_old = old.write_states(ss, a, {"x": "1"}, {"init.json": (b"{}", "application/json")}, **kw_old)
    s_new = new.write_states(ss, b, {"x": "1"}, {"init.json": (b"{}", "application/json")}, chunk_epochs=chunk, **kw)
    return a.read_bytes(), b.read_bytes(), s_old, s_new


@pytest.mark.parametrize("chunk", [7, 2048, 10 * N])
@pytest.mark.parametrize("case", ["modal", "full", "asymmetric", "disk"])
def test_structure_states_bytes_as_the_whole_record_writer(tmp_path, chunk, case):
    ss = _structure("asymmetric" if case == "asymmetric" else "modal", on_disk=case == "disk")
    kw = dict(covariance="full" if case == "full" else "modal", preview_rate_hz=2.0, angles=ANGLES,
              preview=anti_alias_decimate)
    a, b, s_old, s_new = _both(tmp_path, ss, chunk, **kw)
    assert a == b
    assert s_old == {**s_new, "output": s_old["output"]}


@pytest.mark.parametrize("chunk", [7, 1024])
def test_displacement_states_bytes_as_the_whole_record_writer(tmp_path, chunk):
    a, b, _, _ = _both(tmp_path, _displacement(), chunk, time_scale="gps", preview_rate_hz=0.0)
    assert a == b


@pytest.mark.parametrize("stride", [2, 10, 25])
@pytest.mark.parametrize("block", [1, 37, 1000, 100_000])
def test_preview_in_blocks_is_the_whole_run_filter(stride, block):
    rng = np.random.default_rng(stride)
    x = np.cumsum(rng.normal(size=(3001, 3)), axis=0)
    x[1200:1207, 1] = np.nan
    x[5:6] = np.nan
    got = anti_alias_decimate(x, stride, block_epochs=block)
    ref = old.reference_anti_alias_decimate(x, stride)
    assert got.tobytes() == ref.tobytes()
