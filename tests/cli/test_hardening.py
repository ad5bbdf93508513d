"""Issue 12 hardening: readers linear in their input, values what they claim to be."""

from __future__ import annotations

import time

import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.logs import read_receiver_log

HEADER = b"time_s,receiver,master,antenna,transmitter,phase_cycles,lock,snr_dbhz\n"
ROW = b"0.0,rx1,master,a1,PL1,0.797688,0,46.5\n"


def _ten_mb(kind: str) -> bytes:
    if kind == "cr_only":
        return (HEADER + ROW * 270_000).replace(b"\n", b"\r")
    if kind == "long_line":
        return b"x" * 10_000_000
    return b"time_s," * 1_430_000 + b"\n" + ROW      # huge header


@pytest.mark.parametrize("kind,words", [("cr_only", "CR only"), ("long_line", "longer than"), ("huge_header", "longer than")])
def test_ten_megabyte_adversarial_csv_fails_fast_and_clearly(tmp_path, testbed_cfg, kind, words):
    p = tmp_path / "receiver.csv"
    p.write_bytes(_ten_mb(kind))
    assert p.stat().st_size >= 10_000_000
    t0 = time.perf_counter()
    with pytest.raises(CdgpsError) as e:
        read_receiver_log(p, testbed_cfg)
    elapsed = time.perf_counter() - t0
    assert words in str(e.value) and "line 1" in str(e.value) and str(p) in str(e.value)
    assert len(str(e.value)) < 500
    assert elapsed < 1.0, elapsed      # was 78.6 s at 438 KB (quadratic header check)


@pytest.mark.parametrize("lock", ["1e20", "inf", "-1", "1.5"])
def test_lock_out_of_range_is_refused_with_line(tmp_path, testbed_cfg, lock):
    p = tmp_path / "receiver.csv"
    p.write_bytes(HEADER + ROW + ROW.replace(b"PL1", b"PL2").replace(b",0,", f",{lock},".encode()))
    with pytest.raises(CdgpsError, match=r"line 3: column lock: expected a non-negative integer"):
        read_receiver_log(p, testbed_cfg)


def test_crlf_log_still_reads(tmp_path, testbed_cfg):
    p = tmp_path / "receiver.csv"
    p.write_bytes((HEADER + ROW).replace(b"\n", b"\r\n"))
    assert len(read_receiver_log(p, testbed_cfg)) == 1


# ---- values are what they claim to be (issue 12 item 6) ----------------------------------------

import click  # noqa: E402
import numpy as np  # noqa: E402
from click.testing import CliRunner  # noqa: E402

from cdgps_cli.cli.commands import main  # noqa: E402
from cdgps_cli.estimation.filter import load_init_state, validate_rest_segments  # noqa: E402
from cdgps_cli.sim.structure import parse_outage, parse_slip  # noqa: E402


def _init(cfg, **changes):
    n = cfg.n_states
    init = {"config_sha256": cfg.sha256,
            "state": {"time_s": 0.0, "x": [0.0] * n, "P": np.eye(n).tolist()},
            "biases": [{"antenna": cfg.rover_names[0], "transmitter": cfg.transmitter_names[0], "bias_m": 0.5,
                        "current": True}]}
    init.update(changes)
    return init


def test_valid_init_loads(testbed_cfg):
    t0, x, P, biases = load_init_state(_init(testbed_cfg), testbed_cfg)
    assert list(biases.values()) == [0.5]


@pytest.mark.parametrize("mutate,words", [
    (lambda i: i["biases"][0].update(bias_m=True), "not true/false"),
    (lambda i: i["state"].update(x=[True] * len(i["state"]["x"])), "not true/false"),
    (lambda i: i["state"]["P"][0].__setitem__(0, True), "not true/false"),
    (lambda i: i["state"].update(time_s=False), "not true/false"),
    (lambda i: i["biases"].append(dict(i["biases"][0], bias_m=0.7)), "second current bias"),
])
def test_init_values_must_be_what_they_claim(testbed_cfg, mutate, words):
    init = _init(testbed_cfg)
    mutate(init)
    with pytest.raises(CdgpsError, match=words):
        load_init_state(init, testbed_cfg)


def test_overlapping_rest_segments_refused():
    assert validate_rest_segments([(0, 10), (10, 20)], 0.05) == [(0.0, 10.0), (10.0, 20.0)]
    with pytest.raises(CdgpsError, match="overlap"):
        validate_rest_segments([(30, 50), (0, 40)], 0.05)
    with pytest.raises(CdgpsError, match="overlap"):
        validate_rest_segments([(0, float("inf")), (80, 90)], 0.05)


@pytest.mark.parametrize("text", ["a1:PL1:-5:2", "a1:PL1:1e:2", "a1:PL1:inf:2"])
def test_negative_or_bad_slip_time_refused(text):
    with pytest.raises(CdgpsError, match="TIME_S >= 0"):
        parse_slip(text)


@pytest.mark.parametrize("text", ["PL1:-5:10", "PL1:5:-1", "PL1:inf:1"])
def test_negative_outage_refused(text):
    with pytest.raises(CdgpsError, match="START_S >= 0"):
        parse_outage(text)


@pytest.mark.parametrize("args,option", [
    (["estimate", "R.mcap", "--init", "I.json", "--outlier-sigma", "nan", "-o", "S.mcap"], "--outlier-sigma"),
    (["report", "static", "S.mcap", "--angle", "q1", "--survey-deg", "nan", "-o", "rep"], "--survey-deg"),
    (["evaluate", "--truth", "t", "--estimate", "S.mcap", "--converge-s", "nan"], "--converge-s"),
    (["simulate", "c.toml", "--duration", "inf", "--out", "d"], "--duration"),
    (["init", "R.mcap", "--start", "nan", "-o", "I.json"], "--start"),
])
def test_nan_float_options_refused_naming_the_option(tmp_path, args, option):
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2 and option in r.output and "not a finite number" in r.output


def test_every_float_option_is_finite_checked():
    from cdgps_cli.cli.guard import FINITE_FLOAT
    from _shared import cli_commands

    COMMANDS = list(cli_commands(main))

    floats = [(c, p.name) for c, cmd in COMMANDS for p in cmd.params if isinstance(p.type, click.types.FloatParamType)]
    assert floats == []
    assert sum(p.type is FINITE_FLOAT for _, cmd in COMMANDS for p in cmd.params) > 20


def test_library_functions_check_their_own_floats():
    from cdgps_cli.pipeline.estimate_outputs import evaluate

    with pytest.raises(CdgpsError, match="converge_s must be a finite number"):
        evaluate("no-such-dir", "no.mcap", float("nan"))
