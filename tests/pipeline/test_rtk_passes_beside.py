"""``cdgps rtk``'s backward pass runs beside the forward one on a second core (cdgps_cli.core.beside):
the same solution bytes and JSON summary as the two passes one after the other (``CDGPS_SERIAL=1``),
on the real car against its CORS (geonet-car: the combination differs from the forward pass, so it reads
both) and in each direction mode."""

from __future__ import annotations

import json

import pytest

from tests._shared import REPO_ROOT, can_fork, run_cli

CAR = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "geonet-car"
pytestmark = [pytest.mark.skipif(not CAR.exists(), reason="../shared/data/real-pairs absent"),
              pytest.mark.skipif(not can_fork(), reason="no fork or a single CPU here")]
BASE_XYZ = ("-3959400.631", "3385704.533", "3667523.111")


def _rtk(tmp_path, monkeypatch, serial: bool, direction: str) -> tuple[bytes, dict]:
    monkeypatch.setenv("CDGPS_SERIAL", "1" if serial else "0")
    out = tmp_path / f"{direction}-{'serial' if serial else 'beside'}.pos"
    r = run_cli("-q", "rtk", "--base", CAR / "3034265G.21O", "--rover", CAR / "SEPT265G.21O", "--nav", CAR / "SEPT2650.21P",
                "--signals", "G:L1,E:E1", "--base-xyz", *BASE_XYZ, "--direction", direction, "-o", out, "--json")
    assert r.exit_code == 0, r.output
    summary = json.loads(r.output[r.output.index("{\n"):])         # after the warnings (stderr, mixed in)
    summary.pop("elapsed_s", None)
    assert summary.pop("output") == str(out)                       # (the two runs' outputs are named apart)
    return out.read_bytes(), summary


@pytest.mark.parametrize("direction", ["combined", "backward"])
def test_beside_equals_serial(tmp_path, monkeypatch, direction):
    body, summary = _rtk(tmp_path, monkeypatch, False, direction)
    body_serial, summary_serial = _rtk(tmp_path, monkeypatch, True, direction)
    assert body == body_serial
    assert summary == summary_serial
    if direction == "combined":                       # the combination did read the backward pass: not the forward one
        assert body != _rtk(tmp_path, monkeypatch, True, "forward")[0]
