"""Fused runs keep their STATES when their history moves to disk (issue 29, helper `fusedisk`).

Golden digests written from main (9b902ba) on this machine, before the fused path stored its
transitions once per distinct (A, Q) and its x, P on disk: a 5 s tower-fusion run fused with
accel, gyro and tilt (GNSS DDs, ``estimate --structure --fuse``) and a 20 s testbed run fused with
the gyros (``estimate --fuse gyro``).  The digest is over every numeric array of the STATES
(time, modal states, covariances, q, σ_q, NIS): exact equality, bit for bit; the fusion summary of the
options (per sensor: samples, residual RMS, final bias) and the events are compared alike.
"""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.states import States

ROOT = Path(__file__).resolve().parents[2]
TOWER = ROOT / "configs" / "tower-fusion.toml"
TESTBED = ROOT / "configs" / "testbed-1998.toml"
GOLDEN = {"tower": "6cbddc798a6d6bbd20792dfd778bba2df79fecaa1add614888cca972eca9ad43",
          "testbed": "e15035d831e15052cff751d32a93c72a2e47bd48a2e739216ba5aa1ef473b644"}
GOLDEN_FUSION = {"tower": ("d81abd10971ce645f106b2f1b552f8ced52f3c75684a6fb90063149b49cd4a2e", 1),
                 "testbed": ("620946e1c767fb625a893f5eb9148ddb3a61661588afcc9295ec7c23b61f5ee3", 0)}


def run_cli(*args):
    r = CliRunner().invoke(main, ["-q"] + [str(a) for a in args])
    assert r.exit_code == 0, (args, r.output)


def digest(path) -> str:
    s = States(path)
    h = hashlib.sha256()
    for k in sorted(vars(s)):
        v = getattr(s, k)
        if isinstance(v, np.ndarray) and v.dtype.kind in "fiub":
            h.update(k.encode())
            h.update(np.ascontiguousarray(v).tobytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def tower(tmp_path_factory):
    d = tmp_path_factory.mktemp("tower")
    run_cli("simulate-gnss-structure", TOWER, "--duration", "5", "--gnss-interval", "0.1", "--seed", "3", "-o", d)
    run_cli("ingest", "--config", d / "config.toml", "-o", d / "run.mcap")
    run_cli("init", d / "run.mcap", "-o", d / "init.json")
    run_cli("estimate", d / "run.mcap", "--init", d / "init.json", "--structure", TOWER, "--smooth",
            "--fuse", "accel,gyro,tilt", "-o", d / "fused.mcap")
    return d


@pytest.fixture(scope="module")
def testbed(tmp_path_factory):
    d = tmp_path_factory.mktemp("testbed")
    run_cli("simulate", TESTBED, "--duration", "20", "--seed", "1", "--disturbance-scale", "1", "-o", d / "sim")
    run_cli("ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", TESTBED, "-o", d / "run.mcap")
    run_cli("init", d / "run.mcap", "--duration", "10", "-o", d / "init.json")
    run_cli("estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "--fuse", "gyro", "-o", d / "fused.mcap")
    return d


def fusion_digest(path) -> tuple:
    s = States(path)
    summary = json.loads(s.metadata["options"])["fusion"]
    return hashlib.sha256(json.dumps(summary, sort_keys=True).encode()).hexdigest(), len(s.events)


def test_tower_fused_states_unchanged(tower):
    assert digest(tower / "fused.mcap") == GOLDEN["tower"]
    assert fusion_digest(tower / "fused.mcap") == GOLDEN_FUSION["tower"]


def test_testbed_fused_states_unchanged(testbed):
    assert digest(testbed / "fused.mcap") == GOLDEN["testbed"]
    assert fusion_digest(testbed / "fused.mcap") == GOLDEN_FUSION["testbed"]
