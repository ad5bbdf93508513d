"""Every rover epoch of the file is accounted for (issue 28 item 2): an epoch that holds no carrier phase of the
signals used (code only, other systems only) was missing from ``epoch_pairing.rover_epochs`` and from
``dropped`` (the real M8P rover: 1201 reported of its 1202; an edited mosaic rover: 298 of 301); it is now counted
with its reason (gnss_multi._count_epochs_without_phase, the readers' ``file_epochs``)."""

from __future__ import annotations

import json

import pytest

from cdgps_cli.pipeline.gnss_multi import NO_PHASE
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
BASE_XYZ = (-3817681.1213, 3562839.4311, 3650159.1593)
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def _without_system(text: str, system: str, epochs: set) -> str:
    """The RINEX 3 text with the records of ``system`` removed from the epochs numbered in ``epochs``."""
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    out, e = lines[:i], 0
    while i < len(lines):
        n = int(lines[i][32:35])
        recs = lines[i + 1:i + 1 + n]
        if e in epochs:
            recs = [r for r in recs if r[0] != system]
        out += [lines[i][:32] + f"{len(recs):3d}" + lines[i][35:], *recs]
        i, e = i + 1 + n, e + 1
    return "\n".join(out) + "\n"


def test_epochs_without_a_phase_of_the_signals_used_are_counted(tmp_path):
    rover = tmp_path / "rover.obs"
    rover.write_text(_without_system((MOSAIC / "rover.obs").read_text(), "E", {10, 11, 200}))
    out = {}
    for sig in ("E:E1", "G:L1"):
        r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", rover, "--nav", MOSAIC / "base.nav",
                    "--base-xyz", *BASE_XYZ, "--signals", sig, "-o", tmp_path / "x.csv", "--json")
        assert r.exit_code == 0, r.output
        out[sig] = json.loads(r.stdout)
    ep = out["E:E1"]["epoch_pairing"]
    assert ep["rover_epochs"] == 301 and ep["used"] == 298 and ep["dropped"] == {NO_PHASE: 3}
    assert any(f"3 of 301 epochs not used: 3 {NO_PHASE}" in w for w in out["E:E1"]["warnings"])
    ep = out["G:L1"]["epoch_pairing"]                    # GPS is still in those epochs: nothing to count
    assert ep["rover_epochs"] == 301 and ep["used"] == 301 and ep["dropped"] == {}
