"""Tests for cdgps_cli.config.structure: loading, the generator script, validation messages, FE-style configs."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from cdgps_cli.config.structure import load_config, parse_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.phase import all_channels, phase_model, phase_model_q

TESTBED_NAME = "testbed-1998-lumped.toml"
TESTBED_PSEUDO_PATH = "configs/" + TESTBED_NAME
#: the configs scripts/make_testbed_config.py writes (the fitted testbed, and the lumped model the tests use)
GENERATED_CONFIGS = ("testbed-1998.toml", "testbed-1998-lumped.toml")

# The bending-1 mode (modes[2]) of the testbed, as written by the generator.
BENDING1_FREQ = "frequency_hz = 0.132\n"
BENDING1_SHAPE = "shape = [-0.0512905, 0, 0.0664222, 0.102581, 0, 0, -0.0512905, 0, -0.0664222, 0]"
A1_SECTION = 'name = "a1"\nsection = "C1"\n'


def _replace_once(text: str, old: str, new: str) -> str:
    """str.replace that insists the pattern occurs exactly once (so the test really mutates)."""
    assert text.count(old) == 1, f"pattern occurs {text.count(old)} times: {old!r}"
    return text.replace(old, new)


def _error(text: str, path: str = TESTBED_PSEUDO_PATH) -> str:
    with pytest.raises(CdgpsError) as exc:
        parse_config(text, path)
    return str(exc.value)


# --------------------------------------------------------------------------------------------
# the shipped configs


def test_testbed_config_loads(testbed_cfg, testbed_path):
    cfg = testbed_cfg
    assert cfg.name == "testbed-1998"
    assert cfg.path == str(testbed_path)
    assert cfg.n_q == 10 and cfg.n_modes == 9 and cfg.n_states == 18
    assert cfg.coord_names == tuple(f"q{i}" for i in range(1, 11))
    assert cfg.rigid_index == 9
    assert cfg.sample_period_s == pytest.approx(0.1)
    assert cfg.measurement_sigma_m == pytest.approx(0.02)
    assert cfg.antenna_names[cfg.master_index] == "master"
    assert cfg.rover_names == ("a1", "a2", "a3", "a4", "a5", "a6")
    assert cfg.transmitter_names == tuple(f"PL{i}" for i in range(1, 7))
    assert not cfg.transmitter_far_field
    assert len(cfg.thruster_names) == 24 and len(cfg.gyro_names) == 6
    # Table 1 of the 1998 paper
    table1 = {"pendulum": (0.059, 20.0), "swing": (0.160, 130.0), "bending-1": (0.132, 200.0),
              "twist-1": (0.085, 45.0), "twist-2": (0.138, 35.0), "bending-2": (0.135, 140.0),
              "bending-3": (0.23, 50.0), "bending-4": (0.28, 25.0), "rigid-body": (0.0, 140.0)}
    assert set(cfg.mode_names) == set(table1)
    for name, f, tau in zip(cfg.mode_names, cfg.mode_frequency_hz, cfg.mode_time_constant_s):
        assert (f, tau) == pytest.approx(table1[name])
    assert cfg.mode_shapes.shape == (10, 9)
    np.testing.assert_allclose(cfg.antenna_position_m[cfg.antenna_names.index("a5")], [4.0, 1.0, 0.05])
    np.testing.assert_allclose(cfg.antenna_line_bias_m[cfg.antenna_names.index("a3")], 0.051)
    assert cfg.simulation["pulse_thrusters"] == ["a3+z", "a4-z", "a5-z", "a6+z"]
    assert cfg.simulation["static_angle_deg"] == pytest.approx(-1.4)
    # arrays are read-only
    with pytest.raises(ValueError):
        cfg.mode_shapes[0, 0] = 1.0


def test_dof2_config_loads(dof2_cfg):
    cfg = dof2_cfg
    assert cfg.name == "teague-1995-2dof"
    assert cfg.n_q == 2 and cfg.n_modes == 2
    assert cfg.rigid_index is None
    assert cfg.transmitter_far_field
    assert cfg.transmitter_names == ("S1", "S2", "S3", "S4")
    np.testing.assert_allclose(np.linalg.norm(cfg.transmitter_position_m, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(cfg.mode_frequency_hz, [0.1, 0.26])
    assert cfg.process_noise_space == "coordinates"
    np.testing.assert_allclose(cfg.process_noise_sigma, [0.02, 0.02])
    assert cfg.antenna_names[cfg.master_index] == "m"
    assert cfg.sample_period_s == pytest.approx(0.12)
    # unset [simulation] keys take their defaults, set ones override
    assert cfg.simulation["disturbance_scale"] == pytest.approx(1.0)
    assert cfg.simulation["pulse_thrusters"] == []


def test_load_config_missing_file_is_user_error(tmp_path):
    missing = tmp_path / "nope.toml"
    with pytest.raises(CdgpsError, match="nope.toml"):
        load_config(missing)


# --------------------------------------------------------------------------------------------
# the generator script


def test_generated_testbed_config_in_sync(repo_root):
    r = subprocess.run([sys.executable, "scripts/make_testbed_config.py", "--check"], cwd=repo_root,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


def _run_check_on(repo_root, tmp_path, config_text):
    """Run a copy of the generator's --check against ``config_text`` as the shipped config."""
    (tmp_path / "scripts").mkdir(exist_ok=True)
    (tmp_path / "configs").mkdir(exist_ok=True)
    shutil.copy(repo_root / "scripts" / "make_testbed_config.py", tmp_path / "scripts")
    for shipped in GENERATED_CONFIGS:                  # the script renders (and checks) both testbed configs
        shutil.copy(repo_root / "configs" / shipped, tmp_path / "configs")
    (tmp_path / "configs" / TESTBED_NAME).write_text(config_text)
    return subprocess.run([sys.executable, "scripts/make_testbed_config.py", "--check"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=60)


def test_generated_shapes_have_no_round_off(testbed_text):
    """Shapes are written machine-independently: no LAPACK round-off (|x| < 1e-9 of the largest
    entry) and no negative zero, which would make the file's bytes depend on the BLAS kernel."""
    shapes = re.findall(r"^shape = \[(.*)\]$", testbed_text, flags=re.M)
    assert len(shapes) == 9
    for line in shapes:
        assert "-0," not in line + "," and "e-" not in line, line
        v = np.array([float(x) for x in line.split(",")])
        small = v[v != 0]
        assert np.all(np.abs(small) > 1e-6 * np.abs(v).max()), line


def test_generator_check_tolerates_last_digit_round_off(repo_root, testbed_text, tmp_path):
    """Another machine's BLAS may move the 6th significant digit: --check compares numbers with a
    tolerance, not bytes."""
    text = _replace_once(testbed_text, "0.102581,", "0.1025811,")
    r = _run_check_on(repo_root, tmp_path, text)
    assert r.returncode == 0, r.stderr


def test_generator_check_prints_first_difference(repo_root, testbed_text, tmp_path):
    text = _replace_once(testbed_text, BENDING1_SHAPE, BENDING1_SHAPE.replace("0.102581", "0.1031"))
    r = _run_check_on(repo_root, tmp_path, text)
    assert r.returncode == 1
    line_no = testbed_text.splitlines().index(BENDING1_SHAPE) + 1
    assert f"{TESTBED_NAME}:{line_no}:" in r.stderr, r.stderr
    assert "0.1031" in r.stderr and "0.102581" in r.stderr, r.stderr


def test_generator_check_detects_drift(repo_root, testbed_text, tmp_path):
    """--check must fail on a config that differs from what the script renders (so the test above
    is meaningful).  Runs a copy of the script against a modified copy of the config."""
    (tmp_path / "scripts").mkdir()
    (tmp_path / "configs").mkdir()
    shutil.copy(repo_root / "scripts" / "make_testbed_config.py", tmp_path / "scripts")
    for shipped in GENERATED_CONFIGS:
        shutil.copy(repo_root / "configs" / shipped, tmp_path / "configs")
    (tmp_path / "configs" / TESTBED_NAME).write_text(_replace_once(testbed_text, BENDING1_FREQ, "frequency_hz = 0.133\n"))
    r = subprocess.run([sys.executable, "scripts/make_testbed_config.py", "--check"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1, (r.stdout, r.stderr)


# --------------------------------------------------------------------------------------------
# invalid configs: each error names the file, the key path and what was expected


def test_unknown_top_level_key(testbed_text):
    msg = _error("bogus_key = 1\n" + testbed_text)
    assert TESTBED_NAME in msg
    assert re.search(r"\bbogus_key: unknown key", msg), msg
    assert "allowed:" in msg and "modes" in msg


def test_unknown_key_inside_mode(testbed_text):
    text = _replace_once(testbed_text, 'name = "bending-1"\n', 'name = "bending-1"\ndampng = 0.1\n')
    msg = _error(text)
    assert TESTBED_NAME in msg
    assert "modes[2].dampng" in msg
    assert "unknown key" in msg and "time_constant_s" in msg      # lists the allowed keys


def test_missing_mode_frequency(testbed_text):
    msg = _error(_replace_once(testbed_text, BENDING1_FREQ, ""))
    assert TESTBED_NAME in msg
    assert "modes[2].frequency_hz" in msg
    assert "missing required key" in msg


def test_zero_frequency_without_rigid(testbed_text):
    msg = _error(_replace_once(testbed_text, BENDING1_FREQ, "frequency_hz = 0.0\n"))
    assert TESTBED_NAME in msg
    assert "modes[2].frequency_hz" in msg
    assert "expected a positive number" in msg
    assert "rigid = true" in msg                          # hint for the rigid-body case


def test_negative_frequency(testbed_text):
    msg = _error(_replace_once(testbed_text, BENDING1_FREQ, "frequency_hz = -0.132\n"))
    assert TESTBED_NAME in msg
    assert "modes[2].frequency_hz" in msg
    assert "expected a positive number" in msg and "-0.132" in msg


def test_rigid_mode_with_nonzero_frequency(testbed_text):
    text = _replace_once(testbed_text, "frequency_hz = 0.0\ntime_constant_s = 140.0\nrigid = true",
                         "frequency_hz = 0.02\ntime_constant_s = 140.0\nrigid = true")
    msg = _error(text)
    assert "modes[8].frequency_hz" in msg and "frequency_hz = 0" in msg


def test_mode_shape_wrong_size(testbed_text):
    msg = _error(_replace_once(testbed_text, BENDING1_SHAPE, "shape = [0.1, 0.2, 0.3]"))
    assert TESTBED_NAME in msg
    assert "modes[2].shape" in msg
    assert "expected 10 finite numbers" in msg and "got 3 values" in msg


def test_two_masters(testbed_text):
    text = _replace_once(testbed_text, "line_bias_m = 0.012", "line_bias_m = 0.012\nmaster = true")
    msg = _error(text)
    assert TESTBED_NAME in msg
    assert "antennas:" in msg
    assert "exactly one antenna must have master = true" in msg and "found 2" in msg


def test_no_master(testbed_text):
    msg = _error(_replace_once(testbed_text, "master = true\n", ""))
    assert "exactly one antenna must have master = true, found 0" in msg


def test_unknown_section_reference(testbed_text):
    msg = _error(_replace_once(testbed_text, A1_SECTION, 'name = "a1"\nsection = "C9"\n'))
    assert TESTBED_NAME in msg
    assert "antennas[1].section" in msg
    assert "'C9'" in msg and "C1, C2, C3" in msg          # what was given and what is allowed


def test_invalid_toml(testbed_text):
    msg = _error(_replace_once(testbed_text, "[body]\n", "[body\n"))
    assert TESTBED_NAME in msg
    assert "not valid TOML" in msg
    assert "line 13" in msg                               # where the syntax error is


def test_several_problems_reported_together(testbed_text):
    text = "bogus_key = 1\n" + testbed_text
    text = _replace_once(text, BENDING1_FREQ, "frequency_hz = -1.0\n")
    text = _replace_once(text, BENDING1_SHAPE, "shape = [1.0]")
    text = _replace_once(text, A1_SECTION, 'name = "a1"\nsection = "C9"\n')
    text = _replace_once(text, "line_bias_m = 0.007", "line_bias_m = 0.007\nmaster = true")
    msg = _error(text)
    assert TESTBED_NAME in msg
    assert "5 problems" in msg
    for key in ("bogus_key", "modes[2].frequency_hz", "modes[2].shape", "antennas[1].section", "antennas:"):
        assert key in msg, key
    assert msg.count("\n  - ") == 5


def test_valid_config_text_parses(testbed_text):
    """Control for the mutation tests: the unmodified text parses under the same pseudo path."""
    cfg = parse_config(testbed_text, TESTBED_PSEUDO_PATH)
    assert cfg.path == TESTBED_PSEUDO_PATH and cfg.n_modes == 9


# --------------------------------------------------------------------------------------------
# a user-defined finite-element-style config: modal coordinates, displacement tables, far field

FE_CONFIG = """
[model]
name = "fe-plate"
sample_period_s = 0.2
measurement_sigma_m = 0.005

[[coordinates]]
name = "xi1"
kind = "modal"

[[coordinates]]
name = "xi2"
kind = "modal"

[[antennas]]
name = "ref"
position_m = [0.0, 0.0, 0.0]
master = true
displacement_m = { xi1 = [0.0, 0.0, 0.02] }

[[antennas]]
name = "tip"
position_m = [1.0, 0.0, 0.0]
displacement_m = { xi1 = [0.0, 0.0, 0.1], xi2 = [0.05, 0.0, 0.0] }

[[transmitters]]
name = "zenith"
direction = [0.0, 0.0, 1.0]

[[transmitters]]
name = "slant"
direction = [3.0, 0.0, 4.0]

[[modes]]
name = "m1"
frequency_hz = 1.5
time_constant_s = 10.0
shape = [1.0, 0.0]

[[modes]]
name = "m2"
frequency_hz = 4.0
time_constant_s = 5.0
shape = [0.0, 2.0]

[process_noise]
space = "modal"
sigma = [0.1, 0.1]
"""


def test_fe_style_config_loads():
    cfg = parse_config(FE_CONFIG, "fe-plate.toml")
    assert cfg.coord_kinds == ("modal", "modal")
    assert cfg.sections == ()
    assert list(cfg.antenna_section) == [-1, -1]
    assert cfg.transmitter_far_field
    np.testing.assert_allclose(cfg.transmitter_position_m[1], [0.6, 0.0, 0.8])   # normalized
    np.testing.assert_allclose(cfg.antenna_displacement[1], [[0.0, 0.05], [0.0, 0.0], [0.1, 0.0]])
    np.testing.assert_allclose(cfg.antenna_displacement[0], [[0.0, 0.0], [0.0, 0.0], [0.02, 0.0]])
    assert cfg.rover_names == ("tip",)
    assert cfg.coord_unit("xi1") == "1"


def test_fe_style_config_measurement_hand_computed():
    """ξ = (2, −0.5) → q = Uξ = (2, −1): tip = (1,0,0) + 2·(0,0,0.1) − (0.05,0,0) = (0.95, 0, 0.2),
    ref = (0, 0, 0.04); baseline (0.95, 0, 0.16).  h = −s·b: zenith −0.16, slant −(0.57+0.128)."""
    cfg = parse_config(FE_CONFIG, "fe-plate.toml")
    ant, tx = all_channels(cfg)
    x = np.array([[2.0, -0.5, 0.3, -0.7]])
    h, H = phase_model(cfg, x, ant, tx, jacobian=True)
    np.testing.assert_allclose(h, [[-0.16, -0.698]], atol=1e-12)
    # ∂h/∂q: zenith (−0.08, 0), slant (−0.8·0.08, −0.6·0.05); ∂h/∂ξ = ∂h/∂q · diag(1, 2)
    np.testing.assert_allclose(H[0], [[-0.08, 0.0, 0.0, 0.0], [-0.064, -0.06, 0.0, 0.0]], atol=1e-12)
    hq = phase_model_q(cfg, np.array([[2.0, -1.0]]), ant, tx)
    np.testing.assert_allclose(hq, h, atol=1e-12)


def test_fe_style_config_bad_displacement_reference():
    text = _replace_once(FE_CONFIG, "xi2 = [0.05, 0.0, 0.0]", "xi3 = [0.05, 0.0]")
    msg = _error(text, "fe-plate.toml")
    assert "fe-plate.toml" in msg
    assert "antennas[1].displacement_m.xi3" in msg
    assert "expected the name of a coordinate" in msg and "expected 3 finite numbers" in msg


@pytest.mark.parametrize("sample,config", [("testbed-free", "testbed-1998-lumped.toml"), ("testbed-static", "testbed-1998-lumped.toml"),
                                           ("teague-1995", "teague-1995-2dof.toml")])
def test_bundled_samples_match_their_config(repo_root, sample, config):
    """The demo evaluates the bundled samples against their truth.json, which refuses a config other
    than the one simulated: regenerating a config (scripts/make_testbed_config.py) must come with
    scripts/make_samples.sh, or `make demo` fails at 'evaluate'."""
    import json
    truth = json.loads((repo_root / "data" / sample / "truth.json").read_text())
    assert truth["config_sha256"] == load_config(repo_root / "configs" / config).sha256, (
        f"data/{sample}/truth.json was simulated with another configs/{config}: run scripts/make_samples.sh")


@pytest.mark.parametrize("char", ["\\u0000", "\\n", "\\t", "\\u001b"])
def test_names_with_control_characters_are_refused(testbed_text, char):
    """Issue 32: a NUL byte in an antenna name was accepted and carried into every output file."""
    msg = _error(_replace_once(testbed_text, A1_SECTION, A1_SECTION.replace('"a1"', f'"a{char}1"')))
    assert "antennas[" in msg and ".name: expected printable characters" in msg
