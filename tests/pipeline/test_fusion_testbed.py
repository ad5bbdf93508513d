"""`estimate --fuse gyro` on the pseudolite testbed path (issue 30 item 3): simulate → ingest → init →
estimate --fuse gyro; NEES per dof of the fused states in 0.8–1.25 over three seeds, the angles better
than the phases alone, spectra says the gyros are no longer an independent check, and what the fused
pseudolite filter does not take exits 2 naming it."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998.toml"
SEEDS = (1, 2, 3)


def run_cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def evaluate(d, states):
    r = run_cli("evaluate", "--truth", d / "sim", "--estimate", states, "--json")
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = {}
    for seed in SEEDS:
        d = tmp_path_factory.mktemp(f"tb{seed}")
        steps = (("simulate", TESTBED, "--duration", "40", "--seed", seed, "--disturbance-scale", "1", "-o", d / "sim"),
                 ("ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", TESTBED, "-o", d / "run.mcap"),
                 ("init", d / "run.mcap", "--duration", "10", "-o", d / "init.json"),
                 ("estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "--fuse", "gyro", "-o", d / "fused.mcap"))
        for args in steps:
            r = run_cli("-q", *args)
            assert r.exit_code == 0, (args, r.output)
        out[seed] = d
    return out


def test_nees_of_fused_states(runs):
    nees = []
    for d in runs.values():
        e = evaluate(d, d / "fused.mcap")
        assert e["epochs"] == 301                       # from INIT's window end (10 s) to 40 s
        nees.append(e["nees"]["mean"] / e["nees"]["dof"])
    print("NEES per dof", [round(v, 3) for v in nees])
    assert 0.8 <= np.mean(nees) <= 1.25, nees
    assert all(0.7 <= v <= 1.4 for v in nees), nees


def test_gyros_sharpen_the_angles_and_spectra_says_so(runs):
    d = runs[SEEDS[0]]
    r = run_cli("-q", "estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "-o", d / "phase.mcap")
    assert r.exit_code == 0, r.output
    fused, alone = evaluate(d, d / "fused.mcap")["rms_error"], evaluate(d, d / "phase.mcap")["rms_error"]
    assert fused["q2"] < 0.5 * alone["q2"] and fused["q5"] < 0.5 * alone["q5"]      # section rotations, rad
    r = run_cli("spectra", d / "fused.mcap", "-o", d / "sp")
    assert r.exit_code == 0, r.output
    assert "no longer an independent check" in r.output
    assert json.loads((d / "sp" / "peaks.json").read_text())["fusion"]["gyros_independent_check"] is False
    r = run_cli("-q", "estimate", d / "run.mcap", "--init", d / "init.json", "--fuse", "gyro", "--hold-out", "g1",
                "-o", d / "held.mcap", "--json")
    assert r.exit_code == 0, r.output
    f = json.loads(r.stdout)["fusion"]
    assert f["gyro_independent_check"] and set(f["sensors"]) == {"g2", "g3", "g4", "g5", "g6"}


@pytest.mark.parametrize("args,message", [
    (("--fuse", "accel"), "config 'testbed-1998' has no accel sensor"),
    (("--fuse", "gyro", "--biases", "states"), "--biases states is not available with fusion"),
    (("--fuse", "gyro", "--hold-out", "g9"), "--hold-out: g9 is not a sensor"),
])
def test_refusals_exit_2(runs, tmp_path, args, message):
    d = runs[SEEDS[0]]
    out = tmp_path / "x.mcap"
    r = run_cli("estimate", d / "run.mcap", "--init", d / "init.json", *args, "-o", out)
    assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output, r.output
    assert not out.exists()


def test_filter_only_and_thruster_refusal(runs, tmp_path):
    """Without --smooth the forward filter's states are written; a run with thruster commands is
    refused (the fused dynamics have no known inputs)."""
    from types import SimpleNamespace

    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.estimation.filter import EstimateOptions
    from cdgps_cli.pipeline.fusion import _refuse_pseudolite_options

    d = runs[SEEDS[0]]
    r = run_cli("-q", "estimate", d / "run.mcap", "--init", d / "init.json", "--fuse", "gyro", "-o", tmp_path / "f.mcap",
                "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["epochs"] == 301 and not s["smoothed"] and s["fusion"]["added_states"][0] == "g1_bias_gyro_x_rad_s"
    with pytest.raises(CdgpsError, match="r.mcap has thruster commands"):
        _refuse_pseudolite_options(SimpleNamespace(actuators=[1], path="r.mcap"), EstimateOptions(), ("gyro",))
