"""``estimate`` says when a moving rover's states carry no measurement.

The random-walk (and constant-velocity) states use the double differences of fixed ambiguities only.  A real
u-blox walk (20181009, beyond ../shared) had 4 of its 590 integers fixed and no such DD at any of its 2072
epochs: its STATES held the static solution ± 1 m (the prior) at every epoch, without a word.  Here a simulated
random-walk rover's INIT keeps one integer of a 26-epoch segment (the others withdrawn): 274 of its 300 epochs
have no DD of fixed ambiguities, the summary counts them, a warning says so, and the states' σ stay at the
prior's decimetres to a metre; the unedited INIT gives no warning and millimetre σ.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.io.states import States
from tests._shared import run_cli


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("blind")
    r = run_cli("-q", "simulate-gnss", "--duration", 300, "--random-walk", 0.001, "--slips", 6, "--seed", 5, "-o", d)
    assert r.exit_code == 0, r.output
    for args in (("ingest", "--config", d / "config.toml", "-o", d / "run.mcap"),
                 ("init", d / "run.mcap", "-o", d / "init.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    return d, json.loads((d / "init.json").read_text())


def _estimate(d, init: dict, name: str):
    (d / f"{name}.json").write_text(json.dumps(init))
    r = run_cli("estimate", d / "run.mcap", "--init", d / f"{name}.json", "--smooth", "-o", d / f"{name}.mcap",
                "--json")
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout), r.stderr


def test_epochs_without_fixed_double_differences_are_counted_and_said(pair):
    d, init = pair
    s, err = _estimate(d, init, "all")
    assert s["rovers"]["rover"]["epochs_without_fixed_dd"] == 0 and s["warnings"] == [], s["warnings"]
    short = [b for b in init["biases"] if not b["pivot"] and b["n_epochs"] < 50]
    assert short, [b["n_epochs"] for b in init["biases"]]
    keep = min(short, key=lambda b: b["n_epochs"])
    part = json.loads(json.dumps(init))
    for b in part["biases"]:
        if not b["pivot"] and (b["satellite"], b["segment_start_s"]) != (keep["satellite"], keep["segment_start_s"]):
            b.update(fixed=False, integer_cycles=None)
    s, err = _estimate(d, part, "one")
    rov = s["rovers"]["rover"]
    assert rov["n_fixed"] == 1 and rov["epochs"] == 300
    assert rov["epochs_without_fixed_dd"] == 300 - keep["n_epochs"]
    assert len(s["warnings"]) == 1 and f"{300 - keep['n_epochs']} of its 300 epochs" in s["warnings"][0]
    assert "cdgps: warning: rover:" in err and "prediction alone" in err, err
    # one DD for 26 epochs measures almost nothing: the states' σ stay at decimetres, not the mm of a fix
    assert States(d / "all.mcap", diagnostics=False).sigma_q.max() < 0.01
    assert States(d / "one.mcap", diagnostics=False).sigma_q.min() > 0.1


def test_a_float_only_init_of_a_moving_rover_is_said(pair):
    """With no integer fixed, the states use every DD with INIT's static float ambiguities taken as exact, which a
    moving rover's static float does not give (the review: NEES ≈ 5000 on this kind of rover, NIS ≈ 1, no word):
    every epoch is counted and a warning says so."""
    d, _ = pair
    r = run_cli("-q", "init", d / "run.mcap", "--float-only", "-o", d / "float.json")
    assert r.exit_code == 0, r.output
    s, err = _estimate(d, json.loads((d / "float.json").read_text()), "float")
    rov = s["rovers"]["rover"]
    assert rov["n_fixed"] == 0 and rov["epochs_without_fixed_dd"] == rov["epochs"] == 300
    assert len(s["warnings"]) == 1 and "none of its" in s["warnings"][0] and "integers is fixed" in s["warnings"][0]
    assert "cdgps: warning: rover: none of its" in err, err
