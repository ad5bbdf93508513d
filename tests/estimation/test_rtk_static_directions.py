"""``rtk --mode static --direction backward|combined`` (RTKLIB's static solution type with pos1-soltype backward /
combined).

On the real mosaic pair (GPS L1, 301 epochs) the forward static pass leaves its first epochs float (it has seen too few
epochs for the ratio test) and the backward pass its last ones; combined fixes every epoch, as RTKLIB's static run
does.  Independent check: the forward pass's last epoch and the backward pass's first have both seen every epoch of a
static rover, so the two solutions, made in opposite orders, are one least-squares solution and agree to rounding."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.io.solution_formats import read_pos
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    if not MOSAIC.exists():
        pytest.skip("../shared/data/real-pairs absent")
    d = tmp_path_factory.mktemp("static_directions")
    out = {}
    for direction in ("forward", "backward", "combined"):
        pos = d / f"{direction}.pos"
        r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", MOSAIC / "rover.obs", "--nav",
                    MOSAIC / "base.nav", "--signals", "G:L1", "--mode", "static", "--direction", direction,
                    "--pos-frame", "xyz", "-o", pos, "--json")
        assert r.exit_code == 0, r.output
        out[direction] = (json.loads(r.stdout), read_pos(pos))
    return out


def test_each_direction_runs_and_says_so(runs):
    for direction, (s, pos) in runs.items():
        assert s["direction"] == direction and s["mode"] == "static" and s["epochs"] == 301
        assert pos["time_gps_s"].size == 301


def test_combined_fixes_every_epoch_where_one_pass_leaves_some_float(runs):
    fixed = {d: int(np.sum(runs[d][1]["q"] == 1)) for d in runs}
    assert fixed["combined"] == 301 == runs["combined"][0]["fixed_epochs"]         # RTKLIB static: 301 of 301
    assert fixed["forward"] < 301 and fixed["backward"] < 301
    fwd, bwd = (runs[d][1]["q"] == 1 for d in ("forward", "backward"))
    assert not fwd[0] and not bwd[-1]                # each pass's first epochs are its float ones
    assert fwd[-1] and bwd[0]


def test_the_passes_that_saw_every_epoch_agree(runs):
    x = {d: np.array(runs[d][0]["static_xyz_m"]) for d in runs}
    assert np.abs(x["forward"] - x["backward"]).max() < 1e-6                    # one solution, two orders: rounding
    assert np.array_equal(x["combined"], x["forward"])                         # combined reports the forward pass's
    pos = {d: runs[d][1]["coords"] for d in runs}
    assert np.abs(pos["forward"][-1] - x["forward"]).max() < 1e-4               # (.pos: 0.1 mm)
    assert np.abs(pos["backward"][0] - x["backward"]).max() < 1e-4
    # every combined epoch is the weighted mean of two estimates of one point: within a millimetre of it
    assert np.abs(pos["combined"] - x["forward"]).max() < 1e-3
