"""`cdgps control design`: GAINS.json contents, figure, determinism and bad input."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.io.atomic import file_sha256
from cdgps_cli.cli.commands import main
from cdgps_cli.control.design import design_for_structure
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.gains_file import read_gains


def _run(*args):
    return CliRunner().invoke(main, ["-q", *map(str, args)])


def _clean_error(r, *words):
    assert r.exit_code == 2, r.output
    assert isinstance(r.exception, SystemExit) and "Traceback" not in r.output
    for w in words:
        assert w in r.output, r.output


@pytest.fixture(scope="module")
def gains(tmp_path_factory, testbed_path):
    d = tmp_path_factory.mktemp("gains")
    r = _run("control", "design", testbed_path, "-o", d / "gains.json", "--figure", d / "poles.png", "--json")
    assert r.exit_code == 0, r.output
    return d, json.loads(r.stdout)


def test_gains_json_holds_the_design(gains, testbed_path, testbed_cfg):
    d, summary = gains
    doc = read_gains(d / "gains.json", testbed_path)
    ref, poles = design_for_structure(testbed_cfg)
    for key in ("A", "B", "Qx", "Qu", "K"):
        np.testing.assert_array_equal(doc[key], getattr(ref, key))
    assert doc["config"]["sha256"] == file_sha256(testbed_path)
    assert len(doc["poles"]["closed_loop"]) == testbed_cfg.n_modes
    assert summary["settling_time_s"]["closed_loop"]["rigid-body"] == pytest.approx(
        poles["settling_time_s"]["closed_loop"]["rigid-body"])
    assert (d / "poles.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_same_inputs_same_bytes(gains, testbed_path, tmp_path):
    d, _ = gains
    assert _run("control", "design", testbed_path, "-o", tmp_path / "g.json", "--figure", tmp_path / "p.png").exit_code == 0
    assert (tmp_path / "g.json").read_bytes() == (d / "gains.json").read_bytes()
    assert (tmp_path / "p.png").read_bytes() == (d / "poles.png").read_bytes()


def test_gain_for_another_config_is_refused(gains, dof2_path):
    d, _ = gains
    with pytest.raises(CdgpsError, match="designed for config"):
        read_gains(d / "gains.json", dof2_path)


@pytest.mark.parametrize("args,words", [
    (["--qx", "nan"], ["Qx: every entry must be a finite"]),
    (["--qx", "-5"], ["Qx: must be positive semi-definite"]),
    (["--qx", "a,b"], ["--qx 'a,b': expected a number"]),
    (["--qu", "0"], ["Qu: must be positive definite"]),
    (["--qx", "1,2"], ["qx: expected one number or 18 numbers"]),
    (["--qx", ",".join(["5000"] * 8 + ["0"] + ["50"] * 8 + ["0"])], ["rigid-body", "undetectable"]),
])
def test_bad_weights_exit_2_and_write_nothing(testbed_path, tmp_path, args, words):
    r = _run("control", "design", testbed_path, *args, "-o", tmp_path / "g.json", "--figure", tmp_path / "p.png")
    _clean_error(r, *words)
    assert list(tmp_path.iterdir()) == []


def test_config_without_thrusters_is_refused(dof2_path, tmp_path):
    _clean_error(_run("control", "design", dof2_path, "-o", tmp_path / "g.json"), "no [[thrusters]]")
    assert list(tmp_path.iterdir()) == []


def test_corrupt_gains_file_is_named(tmp_path):
    p = tmp_path / "g.json"
    p.write_text('{"format": "cdgps-gains", "version": 1, "state_names": ["a"], "thruster_names": ["t"], '
                 '"A": [[1]], "B": [[1]], "Qx": [[1]], "Qu": [[1]], "K": [["x"]], "config": {}}')
    with pytest.raises(CdgpsError, match="key 'K'"):
        read_gains(p)


def test_design_records_the_in_loop_filter_rule(testbed_path, tmp_path):
    """GAINS.json says which process-noise scale the closed loop's filter will use (separation rule),
    and the paper's weights (the default), too fast for any filter on our Υ, are flagged at design time."""
    out = tmp_path / "g.json"
    r = CliRunner().invoke(main, ["-q", "control", "design", str(testbed_path), "--weights", "tuned", "-o", str(out)])
    assert r.exit_code == 0, r.output
    le = json.loads(out.read_text())["loop_estimator"]
    assert le["met"] is True and le["process_noise_scale"] == pytest.approx(30.2, rel=0.01)
    r = CliRunner().invoke(main, ["control", "design", str(testbed_path), "-o", str(tmp_path / "p.json")])
    assert r.exit_code == 0 and "cannot be made 3x faster" in r.output


def test_defaults_are_the_papers_weights_and_the_set_is_recorded(testbed_path, testbed_cfg, tmp_path):
    """Issue 15 item 1: the paper's Q_x* = 5000 diag(1, …, 1, 0.01) (0.01 on the rigid-body mode),
    Q_x = diag(Q_x*, 0.01 Q_x*), Q_u = I by default, written out here from the paper's text; the
    experiments' tuned set by name; GAINS.json says which set it holds."""
    from cdgps_cli.config.options import CONTROL_TUNED_WEIGHTS

    m = len(testbed_cfg.thruster_names)
    rigid = np.asarray(testbed_cfg.mode_frequency_hz) == 0.0
    assert rigid.sum() == 1
    star = np.where(rigid, 5000.0 * 0.01, 5000.0)
    assert _run("control", "design", testbed_path, "-o", tmp_path / "d.json").exit_code == 0
    doc = read_gains(tmp_path / "d.json", testbed_path)
    np.testing.assert_array_equal(doc["Qx"], np.diag(np.concatenate([star, 0.01 * star])))
    np.testing.assert_array_equal(doc["Qu"], np.eye(m))
    assert doc["weight_set"] == "paper" and doc["options"]["weights"] == "paper"

    assert _run("control", "design", testbed_path, "--weights", "tuned", "-o", tmp_path / "t.json").exit_code == 0
    doc = read_gains(tmp_path / "t.json", testbed_path)
    w = CONTROL_TUNED_WEIGHTS
    star = np.where(rigid, w["qx"] * w["rigid_factor"], w["qx"])
    np.testing.assert_array_equal(doc["Qx"], np.diag(np.concatenate([star, w["rate_factor"] * star])))
    assert doc["weight_set"] == "tuned"
    # the same numbers given one by one are still the named set; anything else is "custom"
    for args, name in ((["--qx", "5000", "--rigid-factor", "0.01"], "paper"), (["--qx", "4000"], "custom"),
                       (["--weights", "tuned", "--qu", "2"], "custom")):
        assert _run("control", "design", testbed_path, *args, "-o", tmp_path / "c.json").exit_code == 0
        assert read_gains(tmp_path / "c.json", testbed_path)["weight_set"] == name, args
    r = _run("control", "design", testbed_path, "--weights", "mine", "-o", tmp_path / "x.json")
    assert r.exit_code == 2 and "Traceback" not in r.output and not (tmp_path / "x.json").exists()


@pytest.mark.parametrize("args,words", [
    (["--qx", "1e308"], ["Qx: entries up to 1e+308", "at most 1e+100"]),
    (["--qx", "1e60"], ["no LQR gain", "--qx"]),
    (["--qu", "1e-300,1,1,1,1,1,1,1"], []),
])
def test_extreme_weights_are_refused_cleanly(testbed_path, tmp_path, args, words):
    """Issue 32: --qx 1e308 ended in a ValueError traceback inside the Riccati solver."""
    r = _run("control", "design", testbed_path, *args, "-o", tmp_path / "g.json")
    if not words:                                           # whatever the outcome, never a traceback
        assert r.exit_code in (0, 2) and "Traceback" not in r.output, r.output
        return
    _clean_error(r, *words)
    assert not (tmp_path / "g.json").exists()


@pytest.mark.parametrize("figure", ["g.json", "./g.json", "sub/../g.json"])
def test_figure_and_gains_on_one_path_are_refused(testbed_path, tmp_path, monkeypatch, figure):
    """Issue 32: `--figure X -o X` wrote the PNG over the gains file."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    r = _run("control", "design", testbed_path, "-o", "g.json", "--figure", figure)
    _clean_error(r, "--figure", "same path as --output g.json")
    assert not (tmp_path / "g.json").exists()
