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
    assert np.abs(x["combined"] - x["forward"]).max() < 1e-6                   # their weighted mean
    pos = {d: runs[d][1]["coords"] for d in runs}
    assert np.abs(pos["forward"][-1] - x["forward"]).max() < 1e-4               # (.pos: 0.1 mm)
    assert np.abs(pos["backward"][0] - x["backward"]).max() < 1e-4
    # combined is the smoother of a constant: every epoch holds the solution from every epoch
    assert np.abs(pos["combined"] - x["combined"]).max() < 1e-4


def _passes(n, fwd_fixed, bwd_fixed, fwd_xyz, bwd_xyz, sigma_m=1e-3):
    """Two synthetic static passes of n epochs whose solutions from every epoch are ``fwd_xyz`` (the forward pass's
    last epoch) and ``bwd_xyz`` (the backward pass's first); the other epochs hold partial solutions 5 cm off."""
    def one(fixed, xyz, k_all):
        x = np.tile(np.asarray(xyz, float) + 0.05, (n, 1))
        x[k_all] = xyz
        cov = np.tile(np.eye(3) * sigma_m**2, (n, 1, 1))
        fixed_xyz = np.where(np.asarray(fixed)[:, None], x, np.nan)
        return {"float_xyz": x + 1e-3, "float_cov": cov * 100, "fixed_xyz": fixed_xyz, "fixed_cov": cov,
                "fixed": np.asarray(fixed), "ratio": np.full(n, 5.0), "n_fixed": np.full(n, 6),
                "partial": np.zeros(n, bool), "ns": np.full(n, 8), "wrong_fix_resets": np.zeros(n, bool),
                "released": np.zeros(n, bool), "held": np.zeros(n, bool)}
    return one(fwd_fixed, fwd_xyz, -1), one(bwd_fixed, bwd_xyz, 0)


def test_static_combined_is_the_solution_from_every_epoch_at_every_epoch():
    """Closed cases of :func:`~cdgps_cli.estimation.rtk_multi._static_smoothed`: the partial solutions in between
    (5 cm off, fixed) play no part; the two solutions from every epoch decide, as one epoch of the combination."""
    from cdgps_cli.estimation.rtk_multi import _combine, _static_smoothed
    n = 5
    f, b = _passes(n, [False, True, True, True, True], [True, True, True, True, False], [1.0, 2.0, 3.0],
                   [1.0, 2.0, 3.0002])
    out = _static_smoothed(f, b)
    assert out["fixed"].all() and out["rejected"] == 0
    assert np.allclose(out["fixed_xyz"], [1.0, 2.0, 3.0001], atol=1e-12)       # equal σ: the mean
    assert np.allclose(out["fixed_cov"], np.eye(3) * 1e-6)
    # two fixes from every epoch 3 cm apart (30 σ): one is wrong; each epoch then is the two passes' own combination
    # (the per-epoch rule of a moving rover): here the partial solutions in between (both 5 cm off the forward's)
    # disagree by 3 cm too, so every epoch is float and counted rejected
    f, b = _passes(n, [True] * n, [True] * n, [1.0, 2.0, 3.0], [1.0, 2.0, 3.03])
    out, per_epoch = _static_smoothed(f, b), _combine(f, b)
    for k in ("fixed", "fixed_xyz", "float_xyz", "fixed_cov", "float_cov"):
        assert np.array_equal(out[k], per_epoch[k], equal_nan=True), k
    assert not out["fixed"].any() and out["rejected"] == per_epoch["rejected"] == n
    # the review's case: the ends disagree (9 mm, formal σ 1 mm) but the partial solutions in between agree: those
    # epochs fixed, as the per-epoch combination fixes them (going float everywhere was worse than either pass)
    f, b = _passes(n, [True] * n, [True] * n, [1.0, 2.0, 3.0], [1.0, 2.0, 3.009])
    b["fixed_xyz"][1:-1] = f["fixed_xyz"][1:-1]
    out = _static_smoothed(f, b)
    assert out["fixed"][1:-1].all() and out["rejected"] == 2
    # only the backward pass's solution from every epoch is fixed, and its float agrees: fixed there, everywhere
    f, b = _passes(n, [True] * (n - 1) + [False], [True] * n, [1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    out = _static_smoothed(f, b)
    assert out["fixed"].all() and np.allclose(out["fixed_xyz"], [1.0, 2.0, 3.0], atol=1e-12)


def test_the_files_say_which_passes_and_which_line_holds_the_solution(runs):
    """The three .pos files had one header: nothing said that a backward static solution's all-epoch line is its
    first.  The ratio column stops at RTKLIB's 999.9 (a static fix reaches 10⁵, which broke the fixed width)."""
    heads = {d: "\n".join(runs[d][1]["header"]) for d in runs}
    assert "mode static, forward pass (the last line: the solution from every epoch)" in heads["forward"]
    assert "mode static, backward pass (the first line: the solution from every epoch)" in heads["backward"]
    assert "forward and backward passes combined (every line: the solution from every epoch)" in heads["combined"]
    for d in runs:
        r = runs[d][1]["ratio"]
        assert r.max() == pytest.approx(999.9) and np.all(r <= 999.9)


def test_the_header_says_when_static_combined_fell_back_to_each_epochs_combination():
    from cdgps_cli.pipeline.gnss_multi import _passes_text
    assert _passes_text("static", "combined", True).endswith("(every line: the solution from every epoch)")
    assert "each line the passes' combination at that epoch" in _passes_text("static", "combined", False)
    assert _passes_text("kinematic", "combined") == "forward and backward passes combined"
