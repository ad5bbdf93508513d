"""A GNSS pair's ingest (hour by hour) and init with their receivers computed on two cores (cdgps_cli.core.beside):
the same RUN bytes, INIT and warnings as with the receivers one after the other (``CDGPS_SERIAL=1``).

The suite runs the commands in turn when every CPU already runs a test worker (tests/conftest.py), so the call
sites of ``beside.both`` that no other test forks on purpose are forked here: io.gnss_hours._read_blocks (the
pair's blocks), estimation.baseline._both_receivers, ._prepare and ._run_engine (the engine's geometry) — on the
real mosaic-X5 pair with GPS L1/L2 and Galileo E1, the base's records thinned to a gappy grid and both clocks
stepped (tests/pipeline/test_gnss_real_pairs.py's gappy case).
"""

from __future__ import annotations

import json

import pytest

from cdgps_cli.core import beside
from tests._shared import MOSAIC_DIR as MOSAIC, can_fork, run_cli, write_gappy_mosaic_pair

pytestmark = [pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent"),
              pytest.mark.skipif(not can_fork(), reason="no fork or a single CPU here")]
BASE_XYZ = (-3817681.1213, 3562839.4311, 3650159.1593)


def _pair(d):
    write_gappy_mosaic_pair(d, "base.obs", "rover.obs")
    r = run_cli("-q", "config", "--rinex", f"base={d / 'base.obs'}", "--rinex", f"rover={d / 'rover.obs'}",
                "--nav", MOSAIC / "base.nav", "--master", "base", "--signals", "G:L1,G:L2,E:E1", "-o", d / "pair.toml")
    assert r.exit_code == 0, r.output
    text = (d / "pair.toml").read_text()
    head, tail = text.split('[gnss.antennas."base"]\n', 1)
    (d / "pair.toml").write_text(head + '[gnss.antennas."base"]\n' + f"position_ecef_m = [{', '.join(map(str, BASE_XYZ))}]\n"
                                 + tail)


def _ingest_init(d, monkeypatch, serial: bool) -> tuple[bytes, dict, list]:
    """ingest → init into ``d/out`` (the RUN names its inputs, not its own path: the same path each time)."""
    monkeypatch.setenv("CDGPS_SERIAL", "1" if serial else "0")
    calls = []
    both = beside.both
    monkeypatch.setattr(beside, "both", lambda a, b: calls.append(beside.forking_allowed()) or both(a, b))
    out = d / "out"
    out.mkdir()
    said = []
    for args in (("ingest", "--config", d / "pair.toml", "-o", out / "run.mcap"), ("init", out / "run.mcap", "-o", out / "init.json")):
        r = run_cli(*args)
        assert r.exit_code == 0, (args, r.output)
        said.append(r.output)                                      # what each receiver read, what init did
    run, init = (out / "run.mcap").read_bytes(), json.loads((out / "init.json").read_text())
    out.rename(d / ("serial" if serial else "forked"))
    assert calls and set(calls) == {not serial}                # every pair of receivers: forked, or in turn
    return run, init, said


def _drop_times(o):
    if isinstance(o, dict):
        return {k: _drop_times(v) for k, v in o.items() if not k.startswith("elapsed") and k != "timing_s"}
    if isinstance(o, list):
        return [_drop_times(v) for v in o]
    return o


def test_a_pair_forked_beside_gives_the_bytes_and_warnings_of_the_receivers_in_turn(tmp_path, monkeypatch):
    _pair(tmp_path)
    run_f, init_f, said_f = _ingest_init(tmp_path, monkeypatch, serial=False)
    run_s, init_s, said_s = _ingest_init(tmp_path, monkeypatch, serial=True)
    assert run_f == run_s
    assert _drop_times(init_f) == _drop_times(init_s)
    assert init_f["rovers"]["rover"]["solution"] == "fixed"
    assert said_f == said_s and "hour by hour" in said_f[0] and "bridged" in said_f[0], said_f
