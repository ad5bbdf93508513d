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
