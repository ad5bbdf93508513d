"""Messages that say where (issue 12 item 9): each case is a real command on a bad input; it exits
with status 2, names the file and line, key or option at fault, and prints no traceback — or, for
inputs that are fine (spaces around CSV fields, a TOML byte-order mark), it is accepted.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import config_kind, parse_gnss_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.run import read_run
from cdgps_cli.sim.structure import SimOptions, simulate

ROOT = Path(__file__).resolve().parents[2]
DOF2 = ROOT / "configs" / "teague-1995-2dof.toml"
GNSS_CFG = ROOT / "configs" / "ubx-example.toml"


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def refused(r, *words):
    """Exit 2, one error naming every word, no traceback."""
    assert r.exit_code == 2, (r.exit_code, r.stderr)
    assert "Traceback" not in r.stderr
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    for w in words:
        assert w in r.stderr, (w, r.stderr)


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """A short 2-DOF run: simulated logs, RUN.mcap, INIT.json, STATES.mcap."""
    d = tmp_path_factory.mktemp("chain")
    assert cli("-q", "simulate", DOF2, "--duration", "30", "--seed", "3", "-o", d / "sim").exit_code == 0
    r = cli("-q", "ingest", d / "sim" / "receiver.csv", "--config", DOF2, "-o", d / "run.mcap")
    assert r.exit_code == 0, r.stderr
    assert cli("-q", "init", d / "run.mcap", "-o", d / "init.json").exit_code == 0
    assert cli("-q", "estimate", d / "run.mcap", "--init", d / "init.json", "-o", d / "states.mcap").exit_code == 0
    return d


# ---- CSV logs


def test_non_utf8_csv_names_line_and_offset(chain, tmp_path):
    lines = (chain / "sim" / "receiver.csv").read_bytes().split(b"\n")
    offset = sum(len(x) + 1 for x in lines[:5]) + 3
    lines[5] = lines[5][:3] + b"\xff" + lines[5][3:]
    p = tmp_path / "latin.csv"
    p.write_bytes(b"\n".join(lines))
    refused(cli("-q", "ingest", p, "--config", DOF2, "-o", tmp_path / "o.mcap"),
            f"{p}, line 6: not UTF-8 text (byte 0xff at offset {offset})")
    assert not (tmp_path / "o.mcap").exists()
    h = tmp_path / "header.csv"                                       # in the header too
    h.write_bytes(b"time_s,rec\xe9iver" + b"\n".join(lines)[len(b"time_s,receiver"):])
    refused(cli("-q", "ingest", h, "--config", DOF2, "-o", tmp_path / "o.mcap"), f"{h}, line 1: not UTF-8")


def test_spaces_around_csv_fields_are_stripped(chain, tmp_path):
    text = (chain / "sim" / "receiver.csv").read_text()
    p = tmp_path / "spaced.csv"
    p.write_text(text.replace(",", " , ").replace("\n", " \n"))
    r = cli("-q", "ingest", p, "--config", DOF2, "-o", tmp_path / "spaced.mcap")
    assert r.exit_code == 0, r.stderr
    a, b = read_run(chain / "run.mcap"), read_run(tmp_path / "spaced.mcap")
    assert len(a.phase) == len(b.phase) > 0
    for c in a.phase.columns:
        assert a.phase[c].tolist() == b.phase[c].tolist(), c


# ---- configs


def test_toml_with_a_byte_order_mark_is_accepted(chain, tmp_path):
    p = tmp_path / "bom.toml"
    p.write_bytes(b"\xef\xbb\xbf" + DOF2.read_bytes())
    r = cli("-q", "ingest", chain / "sim" / "receiver.csv", "--config", p, "-o", tmp_path / "o.mcap")
    assert r.exit_code == 0, r.stderr
    g = "\ufeff" + GNSS_CFG.read_text()
    assert config_kind(g) == "gnss"
    assert parse_gnss_config(g, "bom-gnss.toml").master == parse_gnss_config(GNSS_CFG.read_text()).master


@pytest.mark.parametrize("value", ["42", "true", "[\"a\", \"b\"]"])
def test_a_non_string_description_is_an_error_naming_the_key(chain, tmp_path, value):
    text = DOF2.read_text()
    model = text.split("[model]\n", 1)[1].split("\n[", 1)[0]
    line = next(ln for ln in model.splitlines() if ln.startswith("description = "))
    p = tmp_path / "desc.toml"
    p.write_text(text.replace(line, f"description = {value}", 1))
    refused(cli("-q", "ingest", chain / "sim" / "receiver.csv", "--config", p, "-o", tmp_path / "o.mcap"),
            str(p), "model.description: expected a string")
    g = GNSS_CFG.read_text().replace("[gnss.antennas.ublox]\n", f"[gnss.antennas.ublox]\ndescription = {value}\n", 1)
    assert g != GNSS_CFG.read_text()
    with pytest.raises(CdgpsError, match=r"gnss\.antennas\.ublox\.description: expected a string"):
        parse_gnss_config(g, "g.toml")


# ---- simulate


def test_simulate_names_its_options_not_internal_fields(testbed_cfg, tmp_path):
    refused(cli("-q", "simulate", DOF2, "--duration", "0", "-o", tmp_path / "s"), "--duration 0")
    with pytest.raises(CdgpsError) as e:
        simulate(testbed_cfg, SimOptions(duration_s=2.0, phase_sigma_m=-1.0, multipath_sigma_m=-2.0, random_slips=-1))
    msg = str(e.value)
    assert "--noise-m -1" in msg and "--multipath-m -2" in msg and "--random-slips -1" in msg
    assert "phase_sigma_m" not in msg and "multipath_sigma_m" not in msg


def test_pulse_without_pulse_thrusters_names_the_config(tmp_path):
    refused(cli("-q", "simulate", DOF2, "--scenario", "pulse", "-o", tmp_path / "s"),
            f"--scenario pulse: {DOF2}: [simulation] pulse_thrusters is empty")
    assert not (tmp_path / "s").exists()


# ---- init / estimate


def test_init_start_nan_names_the_option(chain, tmp_path):
    refused(cli("-q", "init", chain / "run.mcap", "--start", "nan", "-o", tmp_path / "i.json"), "--start")
    assert not (tmp_path / "i.json").exists()


def _init_with(chain, tmp_path, name, edit):
    doc = json.loads((chain / "init.json").read_text())
    edit(doc)
    p = tmp_path / name
    p.write_text(json.dumps(doc))              # NaN written as NaN, as a damaged or hand-edited file has it
    return p


def test_init_time_nan_is_blamed_on_the_init_file_and_key(chain, tmp_path):
    p = _init_with(chain, tmp_path, "nan-time.json", lambda d: d["state"].__setitem__("time_s", float("nan")))
    r = cli("-q", "estimate", chain / "run.mcap", "--init", p, "-o", tmp_path / "s.mcap")
    refused(r, f"{p}: state.time_s: expected a finite time")
    assert "run.mcap" not in r.stderr and not (tmp_path / "s.mcap").exists()
    p = _init_with(chain, tmp_path, "nan-window.json", lambda d: d["window"].__setitem__("start_s", float("nan")))
    refused(cli("-q", "estimate", chain / "run.mcap", "--init", p, "-o", tmp_path / "s.mcap"),
            f"{p}: window.start_s nan")

    def late(d):
        d["state"]["time_s"] = 1e5
        d["window"]["end_s"] = 1e5
    p = _init_with(chain, tmp_path, "late.json", late)
    refused(cli("-q", "estimate", chain / "run.mcap", "--init", p, "-o", tmp_path / "s.mcap"),
            f"{p}: state.time_s = 100000 s is after the last epoch of")


# ---- spectra


@pytest.mark.parametrize("args, option", [(["--overlap", "1"], "--overlap 1"), (["--overlap", "-0.5"], "--overlap -0.5"),
                                          (["--pad", "0"], "--pad 0"), (["--segment-s", "0"], "--segment-s 0")])
def test_spectra_names_each_option_alone(chain, tmp_path, args, option):
    r = cli("-q", "spectra", chain / "states.mcap", *args, "-o", tmp_path / "sp")
    refused(r, option)
    others = {"--overlap", "--pad", "--segment-s"} - {option.split()[0]}
    assert not any(o in r.stderr for o in others), r.stderr
    assert not (tmp_path / "sp").exists()


# ---- baseline of a single epoch (its summary line had no interval to print: a traceback)


def test_one_epoch_baseline_summary(tmp_path):
    d = tmp_path / "g"
    assert cli("-q", "simulate-gnss", "--duration", "1", "--seed", "1", "-o", d).exit_code == 0
    r = cli("baseline", "--rinex", f"A={d / 'base.rnx'}", "--rinex", f"B={d / 'rover.rnx'}", "--nav", d / "nav.rnx",
            "--master", "A", "-o", tmp_path / "b.json")
    assert r.exit_code == 0 and "Traceback" not in r.stderr, r.stderr
    assert "one epoch: no interval" in r.stderr
    assert np.isfinite(json.loads((tmp_path / "b.json").read_text())["epochs"]["n_epochs_used"])


@pytest.mark.parametrize("value", ["1e9", "0.001"])
def test_spectra_segment_outside_the_record_is_refused(chain, tmp_path, value):
    """Issue 32: 1e9 s was clamped to one segment (a rank-1 CSD) and 0.001 s to 16 samples, silently."""
    refused(cli("-q", "spectra", chain / "states.mcap", "--segment-s", value, "-o", tmp_path / "sp"),
            f"--segment-s {float(value):g}: expected", "samples, the whole record")
    assert not (tmp_path / "sp").exists()


@pytest.mark.parametrize("args,words", [
    (["--duration", "0.05"], ["--duration 0.05 s: the window", "need at least 3", "longer --duration"]),
    (["--start", "29.95"], ["--start 29.95 s: the window"]),
    (["--start", "500"], ["--start 500 s is outside the recording"]),
])
def test_init_window_messages_name_the_option(chain, tmp_path, args, words):
    refused(cli("-q", "init", chain / "run.mcap", *args, "-o", tmp_path / "i.json"), *words)
    assert not (tmp_path / "i.json").exists()


# ---- simulate-gnss / baseline (issue 32)


@pytest.mark.parametrize("args,words", [
    (["--start", "1970-01-01"], ["--start 1970-01-01 00:00:00 GPST: expected a GPS time from 1980-01-06"]),
    (["--start", "2100-01-01"], ["--start 2100-01-01", "before 2100-01-01"]),
    (["--master-xyz", "0,0,0"], ["--master-xyz 0,0,0: 0.0 km from the Earth's centre"]),
    (["--rover-xyz", "1e7,0,0"], ["--rover-xyz 1e+07,0,0: 10000.0 km"]),
])
def test_simulate_gnss_refuses_impossible_times_and_places(tmp_path, args, words):
    refused(cli("-q", "simulate-gnss", "--duration", "10", *args, "-o", tmp_path / "sim"), *words)
    assert not (tmp_path / "sim").exists()


def test_baseline_names_the_flag_not_the_field(tmp_path):
    g = ROOT.parent / "shared" / "data" / "rinex"
    if not g.exists():
        pytest.skip("../shared/data/rinex absent")
    r = cli("-q", "baseline", "--rinex", f"A={g / '07590920.05o'}", "--rinex", f"B={g / '30400920.05o'}",
            "--nav", g / "07590920.05n", "--master", "B", "--mask-deg", "-10", "-o", tmp_path / "b.json")
    refused(r, "--mask-deg -10: outside the plausible range [0, 90) deg")
    assert "mask_deg" not in r.stderr and not (tmp_path / "b.json").exists()


def test_export_kinematic_on_a_structure_states_names_the_option(chain, tmp_path):
    refused(cli("-q", "export", chain / "states.mcap", "--kinematic", "-o", tmp_path / "k.csv"),
            "--kinematic: STATES_MCAP", "expected a GNSS STATES.mcap")
    assert not (tmp_path / "k.csv").exists()


def test_evaluate_with_the_truth_of_another_config_says_so(chain):
    """Issue 32: the truth of the testbed against a 2-DOF estimate reported 'missing columns'."""
    r = cli("-q", "evaluate", "--truth", ROOT / "data" / "testbed-static", "--estimate", chain / "states.mcap")
    refused(r, "--truth", "simulated with config 'testbed-1998'", "estimates config 'teague-1995-2dof'")
