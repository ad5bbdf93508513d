"""RUN.mcap and STATES.mcap layouts (issue 13 item 5): the packed arrays give the same numbers as
the Foxglove messages; files of the previous layout still read, with the same numbers.

tests/data/format-2026-12-02/ holds run.mcap, init.json and states.mcap (``estimate --smooth``)
written by the code of commit 479267e, before the packed arrays: RUN without them (phase read from
the messages), STATES with ``.npy`` attachments and every epoch in JSON messages (P_ξ included).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import cdgps_cli.io.run as run_module
from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.run import PHASE_TOPIC, _phase_table, read_run, write_run
from cdgps_cli.io.states import (STATE_FILTERED_TOPIC, STATE_TOPIC, States, preview_stride)
from cdgps_cli.io.states_layout import DEFAULT_PREVIEW_RATE_HZ

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
OLD = ROOT / "tests" / "data" / "format-2026-12-02"


def cli(*args):
    r = CliRunner().invoke(main, ["--quiet", *[str(a) for a in args]])
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def new_run(tmp_path_factory):
    """A 10 s testbed run with slips and C/N0 missing on some rows, ingested by today's code."""
    d = tmp_path_factory.mktemp("newrun")
    cli("simulate", TESTBED, "--duration", "10", "--seed", "7", "--random-slips", "2", "-o", d / "sim")
    rx = pd.read_csv(d / "sim" / "receiver.csv")
    rx.loc[::7, "snr_dbhz"] = np.nan
    rx.to_csv(d / "sim" / "receiver.csv", index=False)
    cli("ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", TESTBED, "-o", d / "run.mcap")
    return d


def test_run_packed_phase_equals_the_messages(new_run):
    c = read_mcap(new_run / "run.mcap")
    assert "arrays/cdgps/phase/names.json" in c.attachments
    from_messages = _phase_table(c.topics[PHASE_TOPIC])
    run = read_run(new_run / "run.mcap")
    pd.testing.assert_frame_equal(run.phase.frame(), from_messages.frame())
    assert np.isnan(run.phase["snr_dbhz"]).sum() > 0 and run.phase["lock"].dtype == np.int64
    assert all(isinstance(run.phase.frame()[c].dtype, pd.CategoricalDtype)
               for c in ("receiver", "master", "antenna", "transmitter"))
    # and equal to the log as ingested (names, order, values)
    rx = pd.read_csv(new_run / "sim" / "receiver.csv")
    np.testing.assert_array_equal(run.phase["phase_cycles"], rx["phase_cycles"].to_numpy())
    assert list(run.phase["antenna"]) == list(rx["antenna"])


def test_run_without_packed_arrays_reads_from_the_messages(new_run, tmp_path, monkeypatch):
    cfg = load_config(TESTBED)
    monkeypatch.setattr(run_module, "_attach_phase_packed", lambda out, phase: None)    # the previous writer
    write_run(cfg, new_run / "sim" / "receiver.csv", tmp_path / "old.mcap", new_run / "sim" / "gyro.csv")
    assert "arrays/cdgps/phase/names.json" not in read_mcap(tmp_path / "old.mcap", topics=[]).attachments
    pd.testing.assert_frame_equal(read_run(tmp_path / "old.mcap").phase.frame(), read_run(new_run / "run.mcap").phase.frame())


def test_damaged_packed_phase_is_a_clean_error(new_run):
    from cdgps_cli.io.packed_arrays import pack

    att = read_mcap(new_run / "run.mcap", topics=[]).attachments
    key = "arrays/cdgps/phase/"
    names = json.loads(att[key + "names.json"])
    damaged = [
        {key + "names.json": json.dumps({**names, "antenna": names["antenna"][:-1]}).encode()},   # code past the names
        {key + "lock": pack(np.zeros(3, dtype=np.int64))},                                        # a short column
        {key + "phase_cycles": att[key + "phase_cycles"][:-9]},                                    # truncated bytes
        {key + "names.json": b"[1, 2"},
    ]
    for change in damaged:
        with pytest.raises(CdgpsError, match="damaged phase arrays"):
            run_module._phase_from_packed({**att, **change}, new_run / "run.mcap")
    missing = {k: v for k, v in att.items() if k != key + "snr_dbhz"}
    with pytest.raises(CdgpsError, match="damaged phase arrays"):
        run_module._phase_from_packed(missing, new_run / "run.mcap")


def _close_across_machines(a, b) -> None:
    """The stored files were written on another machine: equal within the golden tests' FLOAT
    tolerance (relative 1e-9 plus 1e-9 × the largest magnitude), which admits another BLAS's round-off
    grown through the filter and nothing an intended change of arithmetic makes."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = float(np.nanmax(np.abs(b))) if np.isfinite(b).any() else 0.0
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * scale)


def test_previous_layout_still_reads_with_the_same_numbers(tmp_path):
    """The old STATES (.npy + every epoch in JSON) and its RUN: read, and re-estimated by today's
    code into the packed layout with the same numbers."""
    for name in ("run.mcap", "init.json", "states.mcap"):
        shutil.copy(OLD / name, tmp_path / name)
    c = read_mcap(tmp_path / "states.mcap")
    assert "arrays/cdgps/state/q.npy" in c.attachments and "arrays/cdgps/state/xi" not in c.attachments
    old = {t: States(tmp_path / "states.mcap", topic=t) for t in (STATE_TOPIC, STATE_FILTERED_TOPIC)}
    msgs = c.topics[STATE_TOPIC]
    N, nm = len(old[STATE_TOPIC].time_s), old[STATE_TOPIC].cfg.n_modes
    assert len(msgs) == N and N > 40
    np.testing.assert_array_equal(msgs.column("P_xi").reshape(N, nm, nm), old[STATE_TOPIC].P_xi)
    assert np.isfinite(old[STATE_TOPIC].nis).sum() > 20                       # filter epochs after the window
    # today's estimate from the old RUN (no packed phase: read from its messages) and the old INIT
    cli("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "--smooth", "-o", tmp_path / "new.mcap")
    assert "arrays/cdgps/state/xi" in read_mcap(tmp_path / "new.mcap", topics=[]).attachments
    for t in (STATE_TOPIC, STATE_FILTERED_TOPIC):
        new = States(tmp_path / "new.mcap", topic=t)
        np.testing.assert_array_equal(new.time_s, old[t].time_s)
        for field in ("q", "sigma_q", "xi"):
            _close_across_machines(getattr(new, field), getattr(old[t], field))
        if t == STATE_TOPIC:
            _close_across_machines(new.P_xi, old[t].P_xi)
            _close_across_machines(new.nis, old[t].nis)
            np.testing.assert_array_equal(new.nis_dof, old[t].nis_dof)
            assert new.events == old[t].events
    # downstream commands read both layouts
    for f in ("states.mcap", "new.mcap"):
        cli("export", tmp_path / f, "--points", "all", "-o", tmp_path / f"{f}.csv")
    a, b = pd.read_csv(tmp_path / "states.mcap.csv"), pd.read_csv(tmp_path / "new.mcap.csv")
    for col in a.columns:
        _close_across_machines(b[col].to_numpy(), a[col].to_numpy())


def test_covariance_full_and_json_rate(tmp_path):
    for name in ("run.mcap", "init.json"):
        shutil.copy(OLD / name, tmp_path / name)
    cli("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "--smooth", "--covariance", "full",
        "--foxglove-rate-hz", "0", "-o", tmp_path / "full.mcap")
    cli("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "--smooth", "-o", tmp_path / "d.mcap")
    full, d = States(tmp_path / "full.mcap"), States(tmp_path / "d.mcap")
    n = full.cfg.n_states
    assert full.P.shape == (len(full.time_s), n, n) and d.P is None
    np.testing.assert_array_equal(full.P[:, :full.cfg.n_modes, :full.cfg.n_modes], full.P_xi)
    np.testing.assert_array_equal(full.P_xi, d.P_xi)
    assert States(tmp_path / "full.mcap", topic=STATE_FILTERED_TOPIC).P.shape == full.P.shape
    assert States(tmp_path / "d.mcap", topic=STATE_FILTERED_TOPIC).P_xi is None
    cf, cd = read_mcap(tmp_path / "full.mcap"), read_mcap(tmp_path / "d.mcap")
    assert len(cf.topics[STATE_TOPIC]) == len(full.time_s)                          # every epoch
    k = preview_stride(d.time_s, DEFAULT_PREVIEW_RATE_HZ)
    assert len(cd.topics[STATE_TOPIC]) == len(range(0, len(d.time_s), k))
    np.testing.assert_array_equal(cd.topics[STATE_TOPIC].times(), d.time_s[::k])
    meta = cd.metadata["cdgps.estimate"]
    assert meta["covariance"] == "modal" and meta["json_channels_every_epochs"] == str(k)
    r = CliRunner().invoke(main, ["--quiet", "estimate", str(tmp_path / "run.mcap"), "--init", str(tmp_path / "init.json"),
                                  "--foxglove-rate-hz", "nan", "-o", str(tmp_path / "x.mcap")])
    assert r.exit_code == 2 and "--foxglove-rate-hz" in r.output and not (tmp_path / "x.mcap").exists()


def test_preview_stride():
    t = np.arange(100) * 0.1
    assert preview_stride(t, 1.0) == 10 and preview_stride(t, 0) == 1 and preview_stride(t, 100.0) == 1
    assert preview_stride(t[:1], 1.0) == 1 and preview_stride(np.arange(10) * 2.0, 1.0) == 1
    with pytest.raises(ValueError):
        preview_stride(t, -1.0)
