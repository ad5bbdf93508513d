"""``init``'s check of its integers by the phases alone (static_engine.fixed_phase_check) on the real GEONET car
(cssrlib-data: a Septentrio mosaic-X5 on a car, GEONET 3034 5.3 km away, 6 min at 1 Hz).

With GPS L1 + L2 only, the random-walk float is biased 1–1.6 cycles on G18, G23 and G24 (5–8 σ: the car's code
multipath, correlated over the record, and a DD ionosphere of 2–3 cm), and LAMBDA took a partial set at ratio 6.0
with 5 integers one cycle off (0.31 m).  Each epoch's phases, solved alone for a position with those integers,
leave a unit variance of 11; with every signal (G+E+J, 45 of 50 integers) 1.3.  The integers are now rejected (the
solution float, with a warning), and the all-signal fix stays."""

from __future__ import annotations

import json

import pytest

from tests._shared import REPO_ROOT, run_cli

CAR = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "geonet-car"
pytestmark = pytest.mark.skipif(not CAR.exists(), reason="../shared/data/real-pairs absent")


def _init(d, tag: str, *signals: str):
    for args in (("config", "--rinex", f"base={CAR / '3034265G.21O'}", "--rinex", f"rover={CAR / 'SEPT265G.21O'}",
                  "--nav", CAR / "SEPT2650.21P", "--master", "base", "--displacement", "random_walk", "--sigma", "3",
                  *signals, "-o", d / f"{tag}.toml"),
                 ("ingest", "--config", d / f"{tag}.toml", "-o", d / f"{tag}.mcap")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args[0], r.output)
    r = run_cli("init", d / f"{tag}.mcap", "-o", d / f"{tag}.json")
    assert r.exit_code == 0, r.output
    return json.loads((d / f"{tag}.json").read_text()), r.stderr


def test_wrong_integers_of_a_biased_float_are_rejected(tmp_path):
    ref, said_ref = _init(tmp_path, "all")
    gps, said = _init(tmp_path, "gps", "--signals", "G:L1,G:L2")
    assert ref["rovers"]["rover"]["n_fixed"] >= 40 and "were rejected" not in said_ref      # 45 of 50
    rover = gps["rovers"]["rover"]
    assert rover["solution"] == "float" and rover["n_fixed"] == 0
    rejected = [w for w in rover["warnings"] if "integers passed LAMBDA" in w and "were rejected" in w]
    assert len(rejected) == 1, rover["warnings"]
    assert float(rejected[0].split("unit variance of ")[1].split()[0]) > 8.0           # measured 11.1
    # INIT says it too: the rejected set under the float, the passing check under the fixed solution
    gone = rover["float"]["rejected_fix"]
    assert gone["n_integers"] == 12 and gone["phase_check"]["unit_variance"] > gone["phase_check"]["threshold"] == 4
    # its float's misfit is said as the rejection's, not as a random walk too slow for the rover
    moving = [w for w in rover["warnings"] if "static float does not fit" in w]
    assert len(moving) == 1 and "were rejected, above" in moving[0] and "sigma_m_per_sqrt_s" not in moving[0]
    kept = ref["rovers"]["rover"]["fixed"]["phase_check"]
    assert kept["unit_variance"] < 2.0 and kept["epochs"] == 360                     # measured 1.29


def _rw_init(d, tag: str, sigma: str):
    for args in (("config", "--rinex", f"base={CAR / '3034265G.21O'}", "--rinex", f"rover={CAR / 'SEPT265G.21O'}",
                  "--nav", CAR / "SEPT2650.21P", "--master", "base", "--displacement", "random_walk",
                  "--sigma", sigma, "-o", d / f"{tag}.toml"),
                 ("ingest", "--config", d / f"{tag}.toml", "-o", d / f"{tag}.mcap")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args[0], r.output)
    r = run_cli("init", d / f"{tag}.mcap", "-o", d / f"{tag}.json")
    assert r.exit_code == 0, r.output
    return json.loads((d / f"{tag}.json").read_text())["rovers"]["rover"]


def test_a_walk_too_slow_for_the_car_is_raised_until_its_float_holds(tmp_path):
    """The car under a 1 mm/√s walk: the float's NIS is 2.7·10⁵ per row, LAMBDA took 3 integers that no epoch's
    phases could check (each epoch had fewer than four DDs of fixed arcs).  ``init`` now raises the walk's σ ×10 until
    its NIS is at most 10 (1 m/√s: 1.8) and fixes the 44 of 44 integers the all-signal car fixes, each epoch's phases
    with them at unit variance 1.6, with a warning naming both σ."""
    rover = _rw_init(tmp_path, "slow", "0.001")
    fl = rover["float"]
    tried = fl["random_walk_tried"]
    assert [t["sigma_m_per_sqrt_s"][0] for t in tried] == [0.001, 0.01, 0.1, 1.0]
    assert tried[0]["nis_per_row"] > 1e4 and all(t["nis_per_row"] > 10 for t in tried[:-1])
    assert tried[-1]["nis_per_row"] < 3 and fl["random_walk_sigma_used_m_per_sqrt_s"] == [1.0] * 3
    assert rover["n_fixed"] >= 40 and rover["fixed"]["phase_check"]["unit_variance"] < 2.0
    said = [w for w in rover["warnings"] if "did not hold the rover's motion" in w]
    assert len(said) == 1 and "0.001 m/sqrt(s)" in said[0] and "at 1 m/sqrt(s)" in said[0], rover["warnings"]


def test_unchecked_integers_of_a_float_that_does_not_hold_are_rejected(tmp_path, monkeypatch):
    """The same car with the walk's σ not raised: its 3 integers (none checkable by the phases) come from a float
    whose NIS per row is 2.7·10⁵, so they are rejected (rejected_by "float_nis"): the solution is float."""
    from cdgps_cli.estimation import static_engine
    monkeypatch.setattr(static_engine, "RANDOM_WALK_MAX_RAISES", 0)
    rover = _rw_init(tmp_path, "kept", "0.001")
    gone = rover["float"]["rejected_fix"]
    assert rover["solution"] == "float" and rover["n_fixed"] == 0
    assert gone["rejected_by"] == "float_nis" and gone["n_integers"] >= 1 and "phase_check" not in gone
    assert gone["float_nis_per_row"] > 1e4 and gone["float_nis_threshold"] == 10
    said = [w for w in rover["warnings"] if "integers passed LAMBDA" in w]
    assert len(said) == 1 and "no epoch has phases of their arcs to spare" in said[0], rover["warnings"]
