"""STATES' residual messages of epochs that use only some channels (every GNSS epoch) made from the
texts of a block of epochs (issue 29) are the bytes of the per-message path (``McapOut.write`` of each
epoch's payload), with missing NIS and bounds, epochs using no channel, and odd names."""

from __future__ import annotations

import numpy as np
import pytest

import cdgps_cli.io.states as states_io
from cdgps_cli.io.mcap import McapOut
from cdgps_cli.io.states import (RESIDUAL_SCHEMA, RESIDUAL_TOPIC, _RESIDUAL_BOUNDS_SCHEMA, _residual_message,
                                 _write_used_channels)


def _epochs(rng, n: int, k: int):
    t = 1.4e9 + np.arange(n, dtype=float) + 0.25
    R = rng.normal(0, 0.01, (n, k))
    R[rng.random((n, k)) < 0.4] = np.nan
    R[3] = np.nan                                          # an epoch using no channel
    R[5, 0] = -0.0
    used = ~np.isnan(R)
    nis = [None if rng.random() < 0.2 else float(v) for v in rng.chisquare(4, n)]
    dof = rng.integers(0, 9, n).tolist()
    bounds = [None if rng.random() < 0.2 else (float(rng.random()), float("nan") if rng.random() < 0.1 else 9.5)
              for _ in range(n)]
    return t, used, R, nis, dof, bounds


def _both(tmp_path, name, ants, txs, epochs, with_bounds: bool):
    t, used, R, nis, dof, bounds = epochs
    bounds = bounds if with_bounds else None
    schema = _RESIDUAL_BOUNDS_SCHEMA if with_bounds else RESIDUAL_SCHEMA
    fast, ref = tmp_path / f"{name}_fast.mcap", tmp_path / f"{name}_ref.mcap"
    with McapOut(fast, time_scale="gps") as out:
        _write_used_channels(out, out.channel(RESIDUAL_TOPIC, schema), t, used, R, nis, dof, bounds, ants, txs)
    with McapOut(ref, time_scale="gps") as out:
        ch = out.channel(RESIDUAL_TOPIC, schema)
        for i in range(len(t)):
            out.write(ch, float(t[i]), _residual_message(ants, txs, R[i], used[i], nis[i], dof[i],
                                                         None if bounds is None else bounds[i]))
    return fast.read_bytes(), ref.read_bytes()


@pytest.mark.parametrize("with_bounds", [False, True])
def test_used_channel_messages_are_the_per_message_bytes(tmp_path, with_bounds):
    rng = np.random.default_rng(11)
    ants = ["rover"] * 6 + ["rover2"] * 6
    txs = [f"G{i:02d}" for i in range(1, 13)]
    fast, ref = _both(tmp_path, "plain", ants, txs, _epochs(rng, 300, 12), with_bounds)
    assert fast == ref


def test_odd_names_and_values_take_the_per_message_rules(tmp_path, monkeypatch):
    """Names holding ``],[`` or ``null``; blocks of 7 epochs."""
    monkeypatch.setattr(states_io, "_RESIDUAL_MESSAGES_PER_BLOCK", 7)
    rng = np.random.default_rng(12)
    ants = ["a],[b", "rover", "nullant"]
    txs = ["G01", "x", "G02"]
    fast, ref = _both(tmp_path, "odd", ants, txs, _epochs(rng, 40, 3), True)
    assert fast == ref


def test_an_infinite_residual_is_refused_as_before(tmp_path):
    rng = np.random.default_rng(13)
    t, used, R, nis, dof, bounds = _epochs(rng, 10, 3)
    R[6, :] = np.inf
    used = ~np.isnan(R)
    with pytest.raises(ValueError), McapOut(tmp_path / "bad.mcap", time_scale="gps") as out:
        _write_used_channels(out, out.channel(RESIDUAL_TOPIC, RESIDUAL_SCHEMA), t, used, R, nis, dof, None,
                             ["a"] * 3, ["G01", "G02", "G03"])
