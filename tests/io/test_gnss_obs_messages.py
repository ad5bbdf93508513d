"""The GNSS RUN's observation messages made from texts of whole blocks (issue 29: a day's ingest spent
10 s on a dict per message) are the bytes of the per-message path (``McapOut.write`` of each epoch's
payload), also with missing values, odd names and values the schema cannot hold."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

import cdgps_cli.io.gnss_run as gnss_run
from cdgps_cli.io.gnss_run import GNSS_OBS_TOPIC, OBS_SCHEMA, RAW_COLUMNS, _obs_payload, _write_obs_messages
from cdgps_cli.io.mcap import McapOut, read_mcap


def _raw(rng, t0: float, epochs: int, sats: list, clock_nan_every: int = 5) -> pd.DataFrame:
    """A receiver's raw table: each epoch some of ``sats``, NaNs sprinkled in the nullable columns."""
    rows = []
    for e in range(epochs):
        for s in sats:
            if rng.random() < 0.8:
                rows.append((t0 + e, s))
    n = len(rows)
    df = pd.DataFrame({c: np.zeros(n) for c in RAW_COLUMNS})
    df["time_gps_s"] = [r[0] for r in rows]
    df["sat"] = np.array([r[1] for r in rows], dtype=object)
    df["phase_cycles"] = rng.normal(0, 1e7, n)
    df["pseudorange_m"] = rng.normal(2e7, 1e6, n)
    df["snr_dbhz"] = rng.normal(40, 5, n).astype(np.float32).astype(np.float64)
    df["doppler_hz"] = np.where(rng.random(n) < 0.5, np.nan, rng.normal(0, 1e3, n))
    for c in ("phase_cycles", "pseudorange_m", "snr_dbhz"):
        df.loc[rng.random(n) < 0.1, c] = np.nan
    df.loc[rng.random(n) < 0.05, "phase_cycles"] = -0.0
    for c in ("lli", "half_cycle", "epoch_flag"):
        df[c] = rng.integers(0, 3, n)
    df["lock_time_ms"] = rng.integers(-1, 64_000, n)
    clk = rng.normal(0, 1e-4, n)
    ep = (df["time_gps_s"].to_numpy() - t0).astype(int)
    clk[ep % clock_nan_every == 0] = np.nan
    df["clock_offset_s"] = clk
    return df


def _files(tmp_path, receivers: dict, name: str) -> tuple:
    """The RUN-like file of ``receivers``' observation messages, written by the block path and by the
    per-message reference (``McapOut.write`` of :func:`_obs_payload` of each epoch, in time order)."""
    fast, ref = tmp_path / f"{name}_fast.mcap", tmp_path / f"{name}_ref.mcap"
    with McapOut(fast, time_scale="gps") as out:
        ch = out.channel(GNSS_OBS_TOPIC, OBS_SCHEMA)
        n_fast = _write_obs_messages(out, ch, receivers)
    with McapOut(ref, time_scale="gps") as out:
        ch = out.channel(GNSS_OBS_TOPIC, OBS_SCHEMA)
        msgs = []
        for i, (n, rx) in enumerate(receivers.items()):
            r = rx.raw
            t = r["time_gps_s"].to_numpy()
            cuts = np.flatnonzero(np.r_[True, t[1:] != t[:-1], True])
            cols = {c: r[c].to_numpy() for c in (*gnss_run._NULLABLE_OBS, *gnss_run._INT_OBS)}
            cols["sat"] = r["sat"].to_numpy()
            p = (n, t, cuts, cols, r["epoch_flag"].to_numpy(), r["clock_offset_s"].to_numpy())
            msgs += [(float(t[a]), i, k, p, a, b) for k, (a, b) in enumerate(zip(cuts[:-1], cuts[1:]))]
        for t, _, _, p, a, b in sorted(msgs, key=lambda m: m[:3]):
            out.write(ch, t, _obs_payload(p, int(a), int(b)))
    return fast, ref, n_fast, len(msgs)


@pytest.mark.parametrize("block", [4096, 7])
def test_block_texts_are_the_per_message_bytes(tmp_path, monkeypatch, block):
    monkeypatch.setattr(gnss_run, "_OBS_MESSAGES_PER_BLOCK", block)
    rng = np.random.default_rng(5)
    sats = ["G01", "G05", "G12", "G31", "E07"]
    receivers = {"base": SimpleNamespace(raw=_raw(rng, 1.4e9, 40, sats)),
                 "rover%d": SimpleNamespace(raw=_raw(rng, 1.4e9 + 0.5, 37, sats, 3))}
    fast, ref, n_fast, n_ref = _files(tmp_path, receivers, "plain")
    assert n_fast == n_ref > 70
    assert fast.read_bytes() == ref.read_bytes()
    c = read_mcap(fast)
    assert len(c.topics[GNSS_OBS_TOPIC]) == n_ref


def test_odd_names_and_unusual_values_take_the_per_message_rules(tmp_path):
    """A name holding ``null`` or ``],[``, an infinite clock (left out, as NaN): still the same bytes."""
    rng = np.random.default_rng(6)
    a = _raw(rng, 1.4e9, 12, ["G01", "G03", "G02"])
    b = _raw(rng, 1.4e9, 12, ["G01", "nullsat", "G07"])
    c = _raw(rng, 1.4e9, 12, ["G01", "x],[y", "G07"])
    c.loc[3, "clock_offset_s"] = np.inf
    receivers = {"null-receiver": SimpleNamespace(raw=a), "b": SimpleNamespace(raw=b), "c": SimpleNamespace(raw=c)}
    fast, ref, _, _ = _files(tmp_path, receivers, "odd")
    assert fast.read_bytes() == ref.read_bytes()


def test_a_value_the_schema_cannot_hold_is_refused_as_before(tmp_path):
    rng = np.random.default_rng(7)
    a = _raw(rng, 1.4e9, 6, ["G01", "G02"])
    a.loc[4, "phase_cycles"] = np.inf
    with pytest.raises(ValueError), McapOut(tmp_path / "bad.mcap", time_scale="gps") as out:
        _write_obs_messages(out, out.channel(GNSS_OBS_TOPIC, OBS_SCHEMA), {"a": SimpleNamespace(raw=a)})


def test_solver_columns_read_alone_hold_the_same_values():
    """``read_gnss_run(columns=SOLVER_COLUMNS)`` (init, estimate): the columns the solvers read, equal to the
    whole table's; the others are not decoded (memory of a day's pair)."""
    from cdgps_cli.io.gnss_run import SOLVER_COLUMNS  # noqa: PLC0415
    from tests.io.test_gnss_archive import archived  # noqa: PLC0415

    raw = _raw(np.random.default_rng(8), 1.4e9, 30, ["G01", "G02", "G09"])
    whole, part = archived(raw), archived(raw, columns=SOLVER_COLUMNS)
    assert list(part.columns) == [c for c in RAW_COLUMNS if c in SOLVER_COLUMNS]
    assert {"doppler_hz", "cp_std_cycles"}.isdisjoint(part.columns) and {"lock_time_ms", "half_cycle"} <= set(part.columns)
    for c in part.columns:
        assert part[c].dtype == whole[c].dtype, c
        np.testing.assert_array_equal(part[c].to_numpy(), whole[c].to_numpy())
