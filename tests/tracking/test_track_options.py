"""Issue 32: out-of-range loop options and a malformed IF manifest are refused with exit 2 and a
message naming the option (as given on the command line) or the manifest key, and the valid range."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.tracking.channel import TrackOptions

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
IQ_FILE = ROOT.parent / "shared" / "data" / "if" / "L1_20211202_084700_4MHz_IQ.bin"
needs_if = pytest.mark.skipif(not IQ_FILE.exists(), reason="bundled IF file not present")


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.mark.parametrize("field,value,words", [
    ("pll_bn_hz", 0.0, "pll_bn_hz 0.0: expected a PLL noise bandwidth in (0, 100] Hz"),
    ("pll_bn_hz", 1e6, "(0, 100] Hz"), ("pll_bn_hz", float("nan"), "pll_bn_hz nan"),
    ("fll_bn_hz", -1.0, "fll_bn_hz"), ("dll_bn_hz", float("inf"), "dll_bn_hz"), ("wide_pll_hz", 0.0, "wide_pll_hz"),
    ("pull_in_s", -1.0, "pull_in_s -1.0: expected an FLL pull-in time in [0, 1e+06] s"),
    ("wide_pll_s", float("nan"), "wide_pll_s"), ("spacing_chips", 0.0, "spacing_chips"), ("pll_order", 1, "pll_order"),
])
def test_loop_options_are_checked_by_the_library(field, value, words):
    with pytest.raises(CdgpsError) as exc:
        TrackOptions(**{field: value})
    assert words in str(exc.value)
    TrackOptions(pull_in_s=0.0, pll_bn_hz=100.0)                      # the ends of the ranges


@needs_if
@pytest.mark.parametrize("args,words", [
    (["--pll-bn", 0], "--pll-bn 0.0: expected a PLL noise bandwidth in (0, 100] Hz"),
    (["--pll-bn", 1e6], "--pll-bn 1000000.0: expected a PLL noise bandwidth in (0, 100] Hz"),
    (["--pll-bn", -3], "--pll-bn -3.0"),
    (["--pull-in", -1], "--pull-in -1.0: expected an FLL pull-in time in [0, 1e+06] s"),
    (["--prn", 31, "--prn", 31], "--prn: PRN 31 given twice"),
    (["--prn", 0], "--prn 0: expected GPS PRNs, whole numbers 1-32"),
])
def test_track_refuses_bad_loop_options(tmp_path, args, words):
    out = tmp_path / "t.mcap"
    r = _run("track", IQ_FILE, "--format", "int8-iq", "--fs", 4e6, "--duration", 0.05, *args, "-o", out)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert words in r.output, r.output
    assert not out.exists()


@pytest.mark.parametrize("args,words", [
    (["--pll-bn", 0], "--pll-bn 0.0: expected a PLL noise bandwidth in (0, 100] Hz"),
    (["--pull-in", -1], "--pull-in -1.0"),
    (["--clock-bn", 0], "--clock-bn 0.0: expected a clock loop bandwidth in (0, 100] Hz"),
    (["--clock-bn", 1e6], "--clock-bn"),
])
def test_track_structure_refuses_bad_loop_options(tmp_path, args, words):
    (tmp_path / "if.json").write_text("{}")
    r = _run("track-structure", tmp_path / "if.json", "--config", TESTBED, *args, "-o", tmp_path / "rx.csv")
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert words in r.output, r.output


def _manifest(tmp_path, **changes) -> Path:
    man = {"format": "cdgps-if-samples/1", "sample_format": "int8-iq", "iq_sign": "minus", "fs_hz": 2.2e6,
           "if_hz": 0.0, "samples": 2200, "start_s": 0.0, "config_sha256": "0" * 64, "master": "a1",
           "transmitters": [{"name": "PL1", "prn": 1}], "antennas": [{"name": "a1", "file": "a1.bin", "sha256": ""}]}
    man.update(changes)
    (tmp_path / "a1.bin").write_bytes(bytes(4400))
    p = tmp_path / "if.json"
    p.write_text(json.dumps(man))
    return p


@pytest.mark.parametrize("changes,words", [
    ({"fs_hz": "fast"}, "fs_hz 'fast': expected a sample rate in Hz between 2.1e+06 and 1e+08"),
    ({"fs_hz": 0}, "fs_hz 0"), ({"fs_hz": 2.2e6 + 0.5}, "whole number of samples per millisecond"),
    ({"if_hz": "x"}, "if_hz 'x'"), ({"if_hz": 2e6}, "if_hz 2000000.0"),
    ({"samples": -1}, "samples -1"), ({"samples": 1.5}, "samples 1.5"), ({"start_s": None}, "start_s None"),
    ({"iq_sign": 1}, "iq_sign 1"), ({"antennas": []}, "antennas: expected a non-empty list"),
    ({"antennas": [{"name": "a1", "file": 3, "sha256": ""}]}, "antennas: name, file, sha256 must be strings"),
    ({"transmitters": [{"name": "PL1", "prn": 99}]}, "transmitters: prn [99]"),
])
def test_track_structure_names_the_bad_manifest_key(tmp_path, changes, words):
    p = _manifest(tmp_path, **changes)
    r = _run("track-structure", p, "--config", TESTBED, "-o", tmp_path / "rx.csv")
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert str(p) in r.output and words in r.output, r.output
    assert not (tmp_path / "rx.csv").exists()


def test_truth_aid_needs_the_manifest_truth(tmp_path):
    from cdgps_cli.pipeline.if_chain import check_truth, read_manifest

    p = _manifest(tmp_path)
    man = read_manifest(p)
    with pytest.raises(CdgpsError, match="truth: expected time_s"):
        check_truth(p, man)
    man["truth"] = {"time_s": [0.0, 0.1], "antennas": {"a1": {"PL1": {"range_m": [1.0, 2.0], "doppler_hz": [0.0],
                                                                       "code_phase_chips": [0.0, 1.0]}}}}
    with pytest.raises(CdgpsError, match=r"truth.antennas.a1.PL1: expected range_m, doppler_hz and code_phase_chips"):
        check_truth(p, man)
    man["truth"]["antennas"]["a1"]["PL1"]["doppler_hz"] = [0.0, np.float64(1.0).item()]
    check_truth(p, man)
