"""``--code-noise auto`` says when it could not measure a receiver's code noise (found by session 23's data hunt: a
real F9P car in Hong Kong with GPS L1 alone had no 30 s window of code minus carrier without a slip, and its codes
were silently weighed as modelled): the warning names the receiver and the count; where both are measured there
is none."""

from __future__ import annotations

import json

import pytest

from tests._shared import REPO_ROOT, run_cli

SHARED = REPO_ROOT.parent / "shared" / "data"
GEONET, MOSAIC = SHARED / "rinex", SHARED / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not GEONET.exists() or not MOSAIC.exists(), reason="../shared/data absent")


def _warnings(tmp_path, *args) -> list:
    r = run_cli("-q", "rtk", *args, "-o", tmp_path / "x.csv", "--json")
    assert r.exit_code == 0, r.output
    return [w for w in json.loads(r.stdout)["warnings"] if "code noise could not be measured" in w]


def test_a_receiver_whose_code_noise_is_not_measured_is_named(tmp_path):
    # GEONET at 30 s: no window holds two epochs
    got = _warnings(tmp_path, "--base", GEONET / "07590920.05o", "--rover", GEONET / "30400920.05o", "--nav",
                    GEONET / "07590920.05n", "--signals", "G:L1,G:L2")
    assert len(got) == 2 and "07590920.05o (base)" in got[0] and "30400920.05o (rover)" in got[1]
    assert all("(its epochs, 30 s apart, put fewer than the 3 a 30 s window of code minus carrier needs in each)" in w
               for w in got)
    assert _warnings(tmp_path, "--base", MOSAIC / "base.obs", "--rover", MOSAIC / "rover.obs", "--nav",
                     MOSAIC / "base.nav", "--signals", "G:L1") == []
    got = _warnings(tmp_path, "--base", GEONET / "07590920.05o", "--rover", GEONET / "30400920.05o", "--nav",
                    GEONET / "07590920.05n", "--signals", "G:L1,G:L2", "--code-noise", "model")
    assert got == []                                           # asked for the model: nothing to say


def test_the_warning_says_why_no_window_was_full():
    """Epochs farther apart than a third of the window: none can be full; else the arcs were cut too short."""
    import math

    from cdgps_cli.pipeline.gnss_multi import _code_noise_warning

    noise = {"mode": "auto", "base": math.nan, "rover": 2.0, "windows": {"base": 4, "rover": 40}}
    paths = {"base": "b.obs", "rover": "r.obs"}
    sparse, = _code_noise_warning(noise, paths, {"base": 15.0, "rover": 1.0})
    assert sparse.startswith("b.obs (base): its code noise could not be measured (its epochs, 15 s apart, put fewer "
                             "than the 3 a 30 s window")
    cut, = _code_noise_warning(noise, paths, {"base": 1.0, "rover": 1.0})
    assert "(4 full 30 s windows of code minus carrier without a slip or a gap, 10 needed)" in cut
    assert _code_noise_warning(noise, paths, {"base": 10.0, "rover": 1.0}) == [cut]      # 3 epochs fit: a full window can
    assert _code_noise_warning(dict(noise, mode="model"), paths, {"base": 15.0, "rover": 1.0}) == []
