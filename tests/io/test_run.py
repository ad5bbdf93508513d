"""Ingest → RUN.mcap round trip, bad-input handling and the CLI contract (issue 2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.run import read_run, write_run
from cdgps_cli.sim.structure import SimOptions, parse_outage, parse_slip, simulate, write_simulation

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    cfg = load_config(TESTBED)
    d = tmp_path_factory.mktemp("sim")
    res = simulate(cfg, SimOptions(duration_s=8.0, seed=5, scenario="pulse",
                                   slips=[parse_slip("a2:PL3:2.0:-2")], outages=[parse_outage("PL6:3:1")]))
    write_simulation(res, d)
    return d


@pytest.fixture(scope="module")
def run_file(sim_dir, tmp_path_factory):
    cfg = load_config(TESTBED)
    out = tmp_path_factory.mktemp("run") / "run.mcap"
    write_run(cfg, sim_dir / "receiver.csv", out, sim_dir / "gyro.csv", sim_dir / "actuators.csv")
    return out


def test_round_trip_every_row(sim_dir, run_file):
    run = read_run(run_file)
    src = pd.read_csv(sim_dir / "receiver.csv")
    assert len(run.phase) == len(src)
    got = run.phase.frame()
    for c in ("time_s", "phase_cycles", "lock", "snr_dbhz"):
        np.testing.assert_array_equal(got[c].to_numpy(), src[c].to_numpy(), err_msg=c)
    for c in ("receiver", "master", "antenna", "transmitter"):
        assert list(got[c]) == list(src[c]), c
    gy = pd.read_csv(sim_dir / "gyro.csv")
    np.testing.assert_array_equal(run.gyro["rate_rad_s"], gy["rate_rad_s"].to_numpy())
    act = pd.read_csv(sim_dir / "actuators.csv")
    assert list(run.actuators["actuator"]) == list(act["actuator"])
    assert run.cfg.sha256 == load_config(TESTBED).sha256
    assert run.metadata["receiver_csv_sha256"]


def test_mcap_layout_foxglove_ready(run_file):
    from mcap.reader import make_reader
    with open(run_file, "rb") as fh:
        r = make_reader(fh, validate_crcs=True)
        summary = r.get_summary()
        topics = {c.topic for c in summary.channels.values()}
        assert any("phase" in t for t in topics)
        for s in summary.schemas.values():
            assert s.encoding == "jsonschema"
            json.loads(s.data)
        for c in summary.channels.values():
            assert c.message_encoding == "json"
        assert all(ci.compression == "zstd" for ci in summary.chunk_indexes)
        _, ch, msg = next(iter(r.iter_messages(topics=["/cdgps/phase"])))
        body = json.loads(msg.data)
        assert set(body["timestamp"]) == {"sec", "nsec"}
        assert msg.log_time == body["timestamp"]["sec"] * 10**9 + body["timestamp"]["nsec"]
        assert len(body["phase_cycles"]) == len(body["antenna"]) == 36


def test_epoch_gap_is_reported_not_error(sim_dir, tmp_path):
    cfg = load_config(TESTBED)
    df = pd.read_csv(sim_dir / "receiver.csv")
    df = df[(df.time_s < 3.0) | (df.time_s >= 4.0)]
    p = tmp_path / "gap.csv"
    df.to_csv(p, index=False)
    s = write_run(cfg, p, tmp_path / "gap.mcap")
    assert len(s["gaps"]) == 1 and s["gaps"][0]["missing_epochs"] == 10


def _corrupt(sim_dir, tmp_path, edit):
    lines = (sim_dir / "receiver.csv").read_text().splitlines()
    lines = edit(lines)
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


BAD_CASES = {
    "missing column": (lambda L: [L[0].replace(",snr_dbhz", "")] + [x.rsplit(",", 1)[0] for x in L[1:]], "line 1", "missing column(s) snr_dbhz"),
    "unknown column": (lambda L: [L[0] + ",extra"] + [x + ",1" for x in L[1:]], "line 1", "unknown column(s) extra"),
    "non-numeric": (lambda L: L[:5] + [L[5].replace(L[5].split(",")[5], "abc")] + L[6:], "line 6", "phase_cycles: not a number"),
    "time backwards": (lambda L: L[:1] + L[40:41] + L[1:40] + L[41:], "line 3", "time goes backwards"),
    "duplicate": (lambda L: L[:3] + [L[2]] + L[3:], "line 4", "duplicate row"),
    "nan phase": (lambda L: L[:7] + [L[7].replace(L[7].split(",")[5], "nan")] + L[8:], "line 8", "NaN value"),
    "unknown antenna": (lambda L: L[:9] + [",".join(L[9].split(",")[:3] + ["zz"] + L[9].split(",")[4:])] + L[10:], "line 10", "antenna not in the config"),
    "unknown transmitter": (lambda L: L[:2] + [L[2].replace(",PL2,", ",PL9,")] + L[3:], "line 3", "transmitter not in the config"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_cli(case, sim_dir, tmp_path):
    edit, where, what = BAD_CASES[case]
    bad = _corrupt(sim_dir, tmp_path, edit)
    out = tmp_path / "out.mcap"
    r = CliRunner().invoke(main, ["ingest", str(bad), "--config", str(TESTBED), "-o", str(out)])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    assert str(bad) in r.output and where in r.output and what in r.output, r.output
    assert not out.exists()
    assert list(tmp_path.glob(".out.mcap*")) == []


def test_missing_input_file(tmp_path):
    r = CliRunner().invoke(main, ["ingest", str(tmp_path / "nope.csv"), "--config", str(TESTBED), "-o", str(tmp_path / "o.mcap")])
    assert r.exit_code == 2 and "cannot read" in r.output


def test_truncated_mcap_clear_error(run_file, tmp_path):
    data = run_file.read_bytes()
    for cut in (len(data) // 2, len(data) - 20, 10):
        p = tmp_path / f"trunc{cut}.mcap"
        p.write_bytes(data[:cut])
        with pytest.raises(CdgpsError, match="truncated or corrupt|no summary"):
            read_run(p)
        r = CliRunner().invoke(main, ["info", str(p)])
        assert r.exit_code == 2 and "Traceback" not in r.output


def test_crc_corruption_detected(run_file, tmp_path):
    data = bytearray(run_file.read_bytes())
    mid = len(data) // 3
    data[mid] ^= 0xFF
    p = tmp_path / "flip.mcap"
    p.write_bytes(bytes(data))
    with pytest.raises(CdgpsError):
        read_run(p)


def test_inputs_never_modified_and_deterministic(sim_dir, tmp_path):
    cfg = load_config(TESTBED)
    before = (sim_dir / "receiver.csv").read_bytes()
    write_run(cfg, sim_dir / "receiver.csv", tmp_path / "a.mcap", sim_dir / "gyro.csv")
    write_run(cfg, sim_dir / "receiver.csv", tmp_path / "b.mcap", sim_dir / "gyro.csv")
    assert (sim_dir / "receiver.csv").read_bytes() == before
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def test_cli_json_and_quiet(sim_dir, tmp_path):
    out = tmp_path / "r.mcap"
    r = CliRunner().invoke(main, ["--quiet", "ingest", str(sim_dir / "receiver.csv"), "--config", str(TESTBED),
                                  "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["channels"] == 36 and s["phase_rows"] > 0
    r = CliRunner().invoke(main, ["info", str(out), "--json"])
    assert json.loads(r.stdout)["topics"][0]["topic"] == "/cdgps/phase"


def test_one_run_module_with_a_kind(run_file, tmp_path):
    """io/run.py tells the kinds apart and writes the ingest record of both the same way: a
    structure RUN, a GNSS RUN (tests/data/format-2026-12-03) and a STATES file."""
    from cdgps_cli.core.records import Run
    from cdgps_cli.io.gnss_run import GnssRun, read_gnss_run
    from cdgps_cli.io.mcap import read_mcap
    from cdgps_cli.io.run import contents_kind, ingest_metadata, read_any_run, run_kind

    gnss_run = ROOT / "tests" / "data" / "format-2026-12-03" / "gnss-run.mcap"
    states = ROOT / "tests" / "data" / "format-2026-12-03" / "structure-states.mcap"
    assert run_kind(run_file) == "structure" and run_kind(gnss_run) == "gnss" and run_kind(states) is None
    assert contents_kind(read_mcap(run_file, topics=[])) == "structure"
    assert contents_kind(read_mcap(gnss_run, topics=[])) == "gnss"
    assert isinstance(read_any_run(run_file), Run) and isinstance(read_any_run(gnss_run), GnssRun)
    # the common part of the record: the same keys for both kinds (main wrote the GNSS one)
    common = ("cdgps_version", "created_by", "config_name", "config_sha256", "config_path")
    g = read_gnss_run(gnss_run).metadata
    s = read_run(run_file).metadata
    assert all(k in g and k in s for k in common) and g["kind"] == "gnss" and "kind" not in s
    cfg = load_config(TESTBED)
    meta = ingest_metadata("structure", cfg, {"receiver_csv": run_file}, sample_period_s="0.1")
    assert meta["config_path"] == TESTBED.name and meta["receiver_csv"] == run_file.name
    assert meta["receiver_csv_sha256"] == __import__("hashlib").sha256(run_file.read_bytes()).hexdigest()
    with pytest.raises(ValueError, match="run kind"):
        ingest_metadata("other", cfg, {})


def test_damage_in_a_column_read_on_first_use_is_a_clean_error(run_file, tmp_path):
    """receiver, master and C/N₀ are decoded when first read: damage found then names the file
    (a packed array that does not decode)."""
    import json as _json

    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.io import run as run_module

    att = {"arrays/cdgps/phase/names.json": _json.dumps({"receiver": ["r"], "master": ["a0"], "antenna": ["a1"],
                                                          "transmitter": ["PL1"]}).encode()}
    from cdgps_cli.io.packed_arrays import pack
    for key, arr in {"time_s": np.arange(3.0), "phase_cycles": np.zeros(3), "lock": np.arange(3),
                     "antenna_code": np.zeros(3, np.int32), "transmitter_code": np.zeros(3, np.int32),
                     "master_code": np.zeros(3, np.int32), "receiver_code": np.zeros(3, np.int32)}.items():
        att["arrays/cdgps/phase/" + key] = pack(arr)
    att["arrays/cdgps/phase/snr_dbhz"] = b"not a packed array"
    phase = run_module._phase_from_packed(att, "x.mcap")
    assert phase["phase_cycles"].tolist() == [0.0, 0.0, 0.0]         # the others read
    with pytest.raises(CdgpsError, match=r"x\.mcap: damaged phase arrays .*snr_dbhz"):
        phase["snr_dbhz"]


def test_phase_messages_with_a_number_for_a_name_are_a_clean_error():
    """Files written before the packed arrays are read from their messages: a name field holding
    numbers is refused naming the file and the topic."""
    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.io.mcap import TopicColumns
    from cdgps_cli.io.run import _phase_table

    tc = TopicColumns()
    tc.add({"time_s": 0.0, "master": "a0", "receiver": [1.0], "antenna": ["a1"], "transmitter": ["PL1"],
            "phase_cycles": [1.0], "lock": [1], "snr_dbhz": [40.0]})
    with pytest.raises(CdgpsError, match=r"old\.mcap: damaged /cdgps/phase messages.*receiver"):
        _phase_table(tc, "old.mcap")
