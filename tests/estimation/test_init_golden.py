"""Golden record of the batch initializers (issue 30 item 1: one batch initializer engine), recorded on
main before the pseudolite/far-field initializer and the GNSS modal one were put on one engine.

Cases: the pseudolite testbed (lumped config, one unflagged slip and one outage; with and without a
given multipath model), the 1995 two-DOF far-field structure (no process noise), the GNSS modal
tower on GPS L1 (``cdgps init --structure``) and on four signals (several wavelengths, later
windows), and the model initializer's static-sky case with pseudorange DDs (and the phase alone).

Each stores the sha256 of the canonical INIT JSON (pseudolite: but ``elapsed_s``; GNSS: but the run's
path and its sha256, which depend on the directory), exact only on the machine that made the record (its fingerprint is stored; ``GOLDEN_EXACT=1``
forces, ``GOLDEN_EXACT=0`` relaxes), and the key numbers compared with a tolerance everywhere (relative 1e-8 on that
machine, ``tests._machine.CROSS_MACHINE_RTOL`` elsewhere).

Regenerate (only when a change of numbers is intended, and say why in the commit)::

    PYTHONPATH=$PWD python tests/estimation/test_init_golden.py --regenerate
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from tests._machine import exact_here, float_tolerance, machine
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = Path(__file__).resolve().parent / "data" / "init_golden.json"
TOWER = ROOT / "configs" / "gnss-tower.toml"
RTOL = 1e-8
CASES = ["testbed", "testbed_multipath", "dof2", "tower_l1", "tower_signals", "static_sky"]


def _sha(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=float).encode()).hexdigest()


def _structure(name: str) -> dict:
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.core.records import memory_run
    from cdgps_cli.estimation.initializer import InitOptions, initialize
    from cdgps_cli.sim.structure import SimOptions, parse_outage, parse_slip, simulate

    if name.startswith("testbed"):
        cfg = load_config(ROOT / "configs" / "testbed-1998-lumped.toml")
        sim = SimOptions(duration_s=40.0, seed=11, phase_sigma_m=0.005,
                         slips=[parse_slip("a2:PL3:24.0:+2")], outages=[parse_outage("PL5:28:3")])
        extra = {"multipath_sigma_m": 0.003, "multipath_time_constant_s": 5.0} if name.endswith("multipath") else {}
        opt = InitOptions(start_s=0.0, duration_s=12.0, starts=4, **extra)
    else:
        cfg = load_config(ROOT / "configs" / "teague-1995-2dof.toml")
        sim = SimOptions(duration_s=20.0, seed=3)
        opt = InitOptions(start_s=0.0, duration_s=2.4, process_noise=False)
    init = initialize(memory_run(cfg, simulate(cfg, sim).receiver), opt)
    body = {k: v for k, v in init.items() if k != "elapsed_s"}
    return {"sha256": _sha(body), "x": init["state"]["x"], "cost": init["cost"],
            "bias_m": [b["bias_m"] for b in init["biases"]], "integers": [b["integer_cycles"] for b in init["biases"]]}


def _gnss(signals: str | None, duration_s: float) -> dict:
    from cdgps_cli.cli.commands import main

    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        sig = ["--signals", signals] if signals else []
        for args in (["simulate-gnss-structure", TOWER, "--duration", duration_s, "--seed", 3, *sig, "--out", tmp],
                     ["ingest", "--config", tmp / "config.toml", "-o", tmp / "run.mcap"]):
            r = CliRunner().invoke(main, ["-q"] + [str(a) for a in args])
            assert r.exit_code == 0, (args, r.output)
        # the init in a fresh process, as a user runs it: in a process that has already run other
        # numerics (the pytest worker, the other cases) the last bits of the modal batch differ (≈ 1e-16
        # relative: BLAS kernels chosen by what was loaded first), which the exact digest would see
        r = subprocess.run([sys.executable, "-c", "from cdgps_cli.cli.commands import main; main()", "-q", "init", str(tmp / "run.mcap"), "--structure",
                            str(TOWER), "-o", str(tmp / "init.json")], capture_output=True, text=True, cwd=ROOT)
        assert r.returncode == 0, r.stderr
        init = json.loads((tmp / "init.json").read_text())
    mi = init["modal_init"]
    return {"sha256": _sha({k: v for k, v in init.items() if k not in ("run", "run_sha256")}), "x": mi["x1"], "cost": mi["cost_per_dof"],
            "bias_m": [s["float_cycles"] for s in mi["segments"]],
            "integers": [s["integer_cycles"] for s in mi["segments"]] + [s["a_cycles"] for s in mi.get("later_segments", [])]}


def _static_sky() -> dict:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_model_init import _solve, _static_sky_case

    from cdgps_cli.core.errors import CdgpsError

    out = {}
    for seed, code in ((0, True), (4, True), (4, False), (0, False)):
        cfg, tabs, k_of, ant, d_hdr, *_ = _static_sky_case(seed)
        try:
            _, r = _solve(cfg, tabs, k_of, ant, d_hdr, code=code)
        except CdgpsError as exc:
            out[f"{seed}{code}"] = str(exc)
            continue
        out[f"{seed}{code}"] = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in vars(r).items()}
    first = out["0True"]
    return {"sha256": _sha(out), "x": first["x"][0], "cost": first["cost"], "bias_m": first["bias_m"],
            "integers": first["integers"], "messages": [v for v in out.values() if isinstance(v, str)]}


def compute(name: str) -> dict:
    if name in ("testbed", "testbed_multipath", "dof2"):
        return _structure(name)
    if name == "tower_l1":
        return _gnss(None, 90.0)
    if name == "tower_signals":
        return _gnss("G:L1,G:L2,E:E1,E:E5a", 150.0)
    return _static_sky()


def _exact(golden: dict) -> bool:
    return exact_here(golden.get("_machine"))


@pytest.fixture(scope="module")
def golden():
    return json.loads(GOLDEN.read_text())


@pytest.mark.parametrize("name", CASES)
def test_init_reproduces_golden(name, golden):
    got, want = compute(name), golden[name]
    assert got["integers"] == want["integers"]
    assert got.get("messages") == want.get("messages")
    rtol = float_tolerance(golden.get("_machine"), RTOL)
    for key in ("x", "cost", "bias_m"):
        np.testing.assert_allclose(got[key], want[key], rtol=rtol, atol=1e-10, err_msg=f"{name}: {key}")
    if _exact(golden):
        assert got["sha256"] == want["sha256"], f"{name}: INIT changed"


if __name__ == "__main__" and "--regenerate" in sys.argv:
    rec = {"_machine": machine(), **{n: compute(n) for n in CASES}}
    GOLDEN.write_text(json.dumps(rec, indent=1, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN}")
