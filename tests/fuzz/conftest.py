"""The fuzz suite's fixture: the base files every mutation starts from (helpers: fuzz_support.py)."""

from __future__ import annotations

import pytest

from fuzz_support import DOF2, TESTBED, cli


@pytest.fixture(scope="session")
def base(tmp_path_factory):
    """Small artefacts built once: sim/ (2-DOF, 6 s), RUN.mcap, INIT.json, STATES.mcap; tsim/
    (the 1998 testbed, 2 s pulse: gyro and actuator logs); gsim/ (a 60 s simulated RINEX pair)
    and GRUN.mcap."""
    d = tmp_path_factory.mktemp("fuzzbase")
    steps = [["simulate", DOF2, "--duration", "6", "-o", d / "sim"],
             ["ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", DOF2, "-o", d / "RUN.mcap"],
             ["init", d / "RUN.mcap", "-o", d / "INIT.json"],
             ["estimate", d / "RUN.mcap", "--init", d / "INIT.json", "-o", d / "STATES.mcap"],
             ["simulate", TESTBED, "--duration", "2", "--scenario", "pulse", "-o", d / "tsim"],
             ["simulate-gnss", "--duration", "60", "-o", d / "gsim"],
             ["ingest", "--rinex", f"A={d / 'gsim' / 'rover.rnx'}", "--rinex", f"B={d / 'gsim' / 'base.rnx'}",
              "--nav", d / "gsim" / "nav.rnx", "--master", "A", "-o", d / "GRUN.mcap"]]
    for s in steps:
        r = cli(*s)
        assert r.exit_code == 0, (s, r.output, r.exception)
    return d
