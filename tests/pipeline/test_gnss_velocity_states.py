"""The constant-velocity model's velocities in STATES and in ``cdgps export`` (``rover_ve_m_s`` … and their σ), and
the warning ``estimate`` gives when its model cannot follow the rover.

* A simulated rover whose velocity random-walks at 1 mm/s/√s (``simulate-gnss --constant-velocity``: the model's
  own process, sampled exactly; it wanders ≈ 5 m in 5 min), run through the chain as the simulator's config says:
  the exported velocities against the true ones are honest (error / σ RMS ≈ 1) and equal the time derivative of
  the exported positions (an independent check: the smoother's states are one trajectory); a random-walk
  model's STATES have no velocity columns.
* The same rover with init's random walk at 1 mm/√s (the simulator's config before it took ``3 σ_a √T``): no
  integer fixed; ``init`` says its static float does not fit a rover that moves, and ``estimate`` that the model
  does not hold (mean NIS per DoF ≈ 800), instead of nothing.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.io.states import States
from tests._shared import run_cli

ACCEL = 0.001        # m/s/√s


@pytest.fixture(scope="module")
def rover(tmp_path_factory):
    d = tmp_path_factory.mktemp("cv")
    r = run_cli("-q", "simulate-gnss", "--duration", 300, "--constant-velocity", ACCEL, "--seed", 3, "-o", d)
    assert r.exit_code == 0, r.output
    return d


def _chain(d, config, tag: str, init_said: list | None = None):
    """ingest → init → estimate --smooth; estimate's --json summary and stderr.  ``init_said``: a list that gets
    init's stderr (init then runs without -q: the same INIT, with what it says)."""
    r = run_cli("-q", "ingest", "--config", config, "-o", d / f"{tag}.mcap")
    assert r.exit_code == 0, ("ingest", r.output)
    r = run_cli(*(() if init_said is not None else ("-q",)), "init", d / f"{tag}.mcap", "-o", d / f"{tag}_init.json")
    assert r.exit_code == 0, ("init", r.output)
    if init_said is not None:
        init_said.append(r.stderr)
    r = run_cli("estimate", d / f"{tag}.mcap", "--init", d / f"{tag}_init.json", "--smooth", "-o",
                d / f"{tag}_states.mcap", "--json")
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout), r.stderr


def test_the_simulators_config_follows_its_rover(rover):
    text = (rover / "config.toml").read_text()
    sigma = float(re.search(r"^sigma_m_per_sqrt_s = ([0-9.eE+-]+)", text, re.M).group(1))
    assert sigma == pytest.approx(3 * ACCEL * 300**0.5)          # 3 σ of the velocity at the end, m/s per √s


@pytest.fixture(scope="module")
def cv_chain(rover):
    """The simulated rover's own config through the chain once: (estimate's summary, its stderr, init's stderr)."""
    said = []
    s, err = _chain(rover, rover / "config.toml", "cv", said)
    return s, err, said[0]


def test_velocities_are_exported_and_honest(rover, cv_chain):
    s, err, _ = cv_chain
    assert s["warnings"] == [] and "warning" not in err, err
    init = json.loads((rover / "cv_init.json").read_text())
    assert init["rovers"]["rover"]["n_fixed"] == init["rovers"]["rover"]["n_estimated"]
    st = States(rover / "cv_states.mcap", diagnostics=False)
    assert st.xidot.shape == st.q.shape and st.sigma_xidot.shape == st.q.shape
    r = run_cli("-q", "export", rover / "cv_states.mcap", "-o", rover / "cv_states.csv")
    assert r.exit_code == 0, r.output
    out = pd.read_csv(rover / "cv_states.csv")
    vel = [f"rover_v{c}_m_s" for c in "enu"]
    assert list(out.columns[-6:]) == vel + [f"sigma_{v}" for v in vel]
    truth = pd.read_csv(rover / "truth.csv")
    m = out.merge(truth, on="time_s", suffixes=("", "_true"))
    assert len(m) == len(out) == 300
    err_v = m[vel].to_numpy() - m[[v + "_true" for v in vel]].to_numpy()
    z = err_v / m[[f"sigma_{v}" for v in vel]].to_numpy()
    rms = np.sqrt((z**2).mean(0))
    assert np.all((0.8 < rms) & (rms < 1.3)), rms
    assert np.sqrt((err_v**2).mean()) < 0.2 * truth[[v for v in vel]].to_numpy().std()   # it follows the rover
    t = out["time_s"].to_numpy()
    for c in "enu":                           # the smoothed positions' derivative is the smoothed velocity
        d = np.gradient(out[f"rover_{c}_m"].to_numpy(), t) - out[f"rover_v{c}_m_s"].to_numpy()
        assert np.sqrt(np.mean(d**2)) < 0.1 * out[f"sigma_rover_v{c}_m_s"].mean(), c


def test_a_random_walk_has_no_velocity_columns(rover, tmp_path):
    cfg = tmp_path / "rw.toml"
    text = (rover / "config.toml").read_text().replace('model = "constant_velocity"', 'model = "random_walk"')
    cfg.write_text(re.sub(r"^accel_sigma_m_per_s_per_sqrt_s = .*$", "", text, flags=re.M)
                   .replace('"base.rnx"', f'"{rover / "base.rnx"}"').replace('"rover.rnx"', f'"{rover / "rover.rnx"}"')
                   .replace('"nav.rnx"', f'"{rover / "nav.rnx"}"'))
    _chain(tmp_path, cfg, "rw")
    assert States(tmp_path / "rw_states.mcap", diagnostics=False).xidot is None
    r = run_cli("-q", "export", tmp_path / "rw_states.mcap", "-o", tmp_path / "rw.csv")
    assert r.exit_code == 0, r.output
    assert not any("_v" in c and c.endswith("_m_s") for c in pd.read_csv(tmp_path / "rw.csv").columns)


def _slow_walk_config(rover, tmp_path):
    cfg = tmp_path / "bad.toml"
    text = re.sub(r"^sigma_m_per_sqrt_s = .*$", "sigma_m_per_sqrt_s = 0.001", (rover / "config.toml").read_text(),
                  flags=re.M)
    cfg.write_text(text.replace('"base.rnx"', f'"{rover / "base.rnx"}"').replace('"rover.rnx"', f'"{rover / "rover.rnx"}"')
                   .replace('"nav.rnx"', f'"{rover / "nav.rnx"}"'))
    return cfg


def test_a_model_that_cannot_follow_the_rover_is_said(rover, tmp_path, monkeypatch):
    """init's float under a 1 mm/√s walk, with the walk not raised (RANDOM_WALK_MAX_RAISES 0): nothing fixed.  The
    rover moves (its static float lands tens of metres from its code's mean), so INIT's static displacement is that
    mean, init says so, and estimate refuses the INIT (exit 2, nothing written) instead of states that would follow
    the mean with millimetre σ."""
    from cdgps_cli.estimation import static_engine
    monkeypatch.setattr(static_engine, "RANDOM_WALK_MAX_RAISES", 0)
    cfg = _slow_walk_config(rover, tmp_path)
    assert run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "bad.mcap").exit_code == 0
    r = run_cli("init", tmp_path / "bad.mcap", "-o", tmp_path / "bad_init.json")
    assert r.exit_code == 0, r.output
    assert "no integer fixed, and the rover moves: its static float solution lands" in r.stderr, r.stderr
    rov = json.loads((tmp_path / "bad_init.json").read_text())["rovers"]["rover"]
    mean_true = pd.read_csv(rover / "truth.csv")[["rover_e_m", "rover_n_m", "rover_u_m"]].to_numpy().mean(axis=0)
    assert np.max(np.abs(np.asarray(rov["float"]["enu_m"]) - mean_true)) < 2.0          # the code's mean, not 73 m off
    assert rov["n_fixed"] == 0 and rov["float"]["moving_rover"]["static_float_apart_m"] > 20
    r = run_cli("estimate", tmp_path / "bad.mcap", "--init", tmp_path / "bad_init.json", "--smooth", "-o",
                tmp_path / "bad_states.mcap")
    assert r.exit_code == 2 and "INIT fixed none of its integers and the rover moves" in r.output, r.output
    assert "Traceback" not in r.output and not (tmp_path / "bad_states.mcap").exists()


def test_init_raises_a_walk_its_float_cannot_follow_and_the_chain_holds(rover, tmp_path):
    """The same 1 mm/√s walk as init's float, raised as init now does: its NIS per row 26 (the walk does not hold
    the rover), solved again at 0.01 m/√s (1.8), every integer fixed, said in a warning; estimate's constant-velocity
    states then hold (NIS per dof ≈ 1, measured 1.00), where nothing was fixed and the NIS was above 100."""
    said = []
    s, err = _chain(tmp_path, _slow_walk_config(rover, tmp_path), "bad", said)
    assert "init's random-walk float at [gnss.displacement] sigma_m_per_sqrt_s 0.001 m/sqrt(s) " \
        "leaves a NIS of" in said[0] and "it did not hold the rover's motion" in said[0], said[0]
    assert "a constant_velocity model's do not" in said[0]
    rov = json.loads((tmp_path / "bad_init.json").read_text())["rovers"]["rover"]
    tried = rov["float"]["random_walk_tried"]
    assert rov["float"]["random_walk_sigma_used_m_per_sqrt_s"] == [0.01] * 3 and len(tried) == 2
    assert tried[0]["nis_per_row"] > 10 >= tried[1]["nis_per_row"]
    assert rov["n_fixed"] == rov["n_estimated"] == 10
    assert 0.7 < s["mean_nis_per_dof"] < 1.3 and not any("mean NIS" in w for w in s["warnings"]), s
    # STATES say that INIT's integers came from a raised walk
    from cdgps_cli.io.states import States
    opts = json.loads(States(tmp_path / "bad_states.mcap", diagnostics=False).metadata["options"])
    assert opts["init_random_walk_sigma_used_m_per_sqrt_s"] == {"rover": [0.01] * 3}


def test_init_says_what_its_states_are_under_a_moving_model(cv_chain):
    """Under constant velocity INIT's states are the record's mean (static) position, the origin estimate's
    states move about: init says so instead of calling them the rover's static displacement (init on the
    simulator's config, as cv_chain runs it: ingest, then init without -q)."""
    line = next(ln for ln in cv_chain[2].splitlines() if ln.startswith("INIT "))
    assert "the mean over the record; the origin of estimate's constant_velocity states, m): rover_e " in line, line
