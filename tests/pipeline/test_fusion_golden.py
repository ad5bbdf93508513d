"""Fused runs keep their STATES when their history moves to disk (issue 29, helper `fusedisk`).

A 5 s tower-fusion run fused with accel, gyro and tilt (GNSS DDs, ``estimate --structure --fuse``) and a
20 s testbed run fused with the gyros (``estimate --fuse gyro``).  The record
(tests/pipeline/data/fusion_golden.json) holds, per run, the sha256 over every numeric array of the
STATES (time, modal states, covariances, q, σ_q, NIS) and of the fusion summary of the options (per
sensor: samples, residual RMS, final bias), the number of events, and each array sampled at 12 epochs
with the fusion summary's numbers.  The digests are compared exactly on the machine that made the
record (its fingerprint is stored, tests/_machine.py); elsewhere the samples are compared within
``CROSS_MACHINE_RTOL``.  The first record (main 9b902ba, on another machine) held the digests only;
it was remade on 2026-12-05 from main 89ec799, whose fused STATES matched those digests on the
machine that made them.

Regenerate (only when a change of numbers is intended, and say why in the commit)::

    PYTHONPATH=$PWD python tests/pipeline/test_fusion_golden.py --regenerate
"""

import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.states import States
from tests._machine import CROSS_MACHINE_RTOL, assert_json_close, exact_here, machine

ROOT = Path(__file__).resolve().parents[2]
TOWER = ROOT / "configs" / "tower-fusion.toml"
TESTBED = ROOT / "configs" / "testbed-1998.toml"
GOLDEN = Path(__file__).resolve().parent / "data" / "fusion_golden.json"
N_SAMPLES = 12


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


def make_tower(d: Path) -> Path:
    run_cli("simulate-gnss-structure", TOWER, "--duration", "5", "--gnss-interval", "0.1", "--seed", "3", "-o", d)
    run_cli("ingest", "--config", d / "config.toml", "-o", d / "run.mcap")
    run_cli("init", d / "run.mcap", "-o", d / "init.json")
    run_cli("estimate", d / "run.mcap", "--init", d / "init.json", "--structure", TOWER, "--smooth",
            "--fuse", "accel,gyro,tilt", "-o", d / "fused.mcap")
    return d


def make_testbed(d: Path) -> Path:
    run_cli("simulate", TESTBED, "--duration", "20", "--seed", "1", "--disturbance-scale", "1", "-o", d / "sim")
    run_cli("ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", TESTBED, "-o", d / "run.mcap")
    run_cli("init", d / "run.mcap", "--duration", "10", "-o", d / "init.json")
    run_cli("estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "--fuse", "gyro", "-o", d / "fused.mcap")
    return d


def record(path) -> dict:
    """What the golden keeps of one fused STATES file."""
    s = States(path)
    samples = {}
    for k in sorted(vars(s)):
        v = getattr(s, k)
        if not (isinstance(v, np.ndarray) and v.dtype.kind in "fiub"):
            continue
        v = v.astype(float)
        idx = np.unique(np.linspace(0, len(v) - 1, N_SAMPLES).round().astype(int)) if len(v) else []
        samples[k] = {"value": np.where(np.isfinite(v[idx]), v[idx], 0.0).tolist(),
                      "nan": np.isnan(v[idx]).tolist(),
                      "max_abs": float(np.nanmax(np.abs(v))) if np.isfinite(v).any() else 0.0}
    return {"digest": digest(path), "fusion_sha256": fusion_digest(path)[0], "events": len(s.events),
            "samples": samples, "fusion": json.loads(s.metadata["options"])["fusion"]}


def fusion_digest(path) -> tuple:
    s = States(path)
    summary = json.loads(s.metadata["options"])["fusion"]
    return hashlib.sha256(json.dumps(summary, sort_keys=True).encode()).hexdigest(), len(s.events)


def check(path, name: str) -> None:
    golden = json.loads(GOLDEN.read_text())
    want, got = golden[name], record(path)
    assert got["events"] == want["events"]
    assert got["samples"].keys() == want["samples"].keys(), "STATES arrays changed"
    if exact_here(golden.get("_machine")):
        assert got["digest"] == want["digest"], f"{name}: STATES not bit-identical"
        assert got["fusion_sha256"] == want["fusion_sha256"], f"{name}: fusion summary changed"
        return
    for k, w in want["samples"].items():
        g = got["samples"][k]
        assert g["nan"] == w["nan"], f"{name}/{k}: NaN pattern"
        np.testing.assert_allclose(g["value"], w["value"], rtol=CROSS_MACHINE_RTOL,
                                   atol=CROSS_MACHINE_RTOL * w["max_abs"], err_msg=f"{name}/{k}")
    assert_json_close(got["fusion"], want["fusion"], f"{name}/fusion", abs_tol=1e-12)


@pytest.fixture(scope="module")
def tower(tmp_path_factory):
    return make_tower(tmp_path_factory.mktemp("tower"))


@pytest.fixture(scope="module")
def testbed(tmp_path_factory):
    return make_testbed(tmp_path_factory.mktemp("testbed"))


def test_tower_fused_states_unchanged(tower):
    check(tower / "fused.mcap", "tower")


def test_testbed_fused_states_unchanged(testbed):
    check(testbed / "fused.mcap", "testbed")


def test_check_flags_a_changed_state(tower, monkeypatch):
    """The comparison itself: a sample moved by 1e-4 relative fails on any machine."""
    rec = record(tower / "fused.mcap")
    k = "q"
    assert k in rec["samples"]
    golden = json.loads(GOLDEN.read_text())
    golden["_machine"] = "another machine"
    v = golden["tower"]["samples"][k]["value"]
    i = int(np.argmax(np.abs(np.asarray(v, float)).ravel()))
    flat = np.asarray(v, float).ravel()
    flat[i] *= 1 + 1e-4
    golden["tower"]["samples"][k]["value"] = flat.reshape(np.shape(v)).tolist()
    fake = tower / "golden.json"
    fake.write_text(json.dumps(golden))
    monkeypatch.setattr(sys.modules[__name__], "GOLDEN", fake)
    with pytest.raises(AssertionError, match="tower/q"):
        check(tower / "fused.mcap", "tower")


if __name__ == "__main__" and "--regenerate" in sys.argv:
    with tempfile.TemporaryDirectory() as d:
        rec = {"_machine": machine(),
               "tower": record(make_tower(Path(d) / "tower") / "fused.mcap"),
               "testbed": record(make_testbed(Path(d) / "testbed") / "fused.mcap")}
    GOLDEN.parent.mkdir(parents=True, exist_ok=True)
    GOLDEN.write_text(json.dumps(rec, indent=1, sort_keys=True) + "\n")
    print(f"{GOLDEN}: written")
