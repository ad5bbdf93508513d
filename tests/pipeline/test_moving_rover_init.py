"""``init`` on a rover under a motion model whose integers are not fixed, when its static float lies far from its
code's mean (``static_engine._code_mean_of_moving_rover``): the rule must fire on a rover that moves and on nothing
else, and the σ of the mean it reports must say metres when the rover moves metres.

A review of the first version found it starting the random-walk float from the code's mean (five wrong G20
integers on the real car, which ``estimate`` then took) and firing on a static rover seen through a 40° mask for a
minute (its static float tens of metres off with a σ as large); both are checked here on the real files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.estimation.static_engine import _code_unit_variance
from tests._shared import REPO_ROOT, run_cli

REAL = REPO_ROOT.parent / "shared" / "data" / "real-pairs"
CAR, MOSAIC = REAL / "geonet-car", REAL / "mosaic-static"


def test_code_unit_variance_is_the_dd_chi_square():
    """Each group's SD code residuals weighted as their DDs equal rᵀDᵀ(DΣDᵀ)⁻¹Dr, summed, over the DDs less three."""
    rng = np.random.default_rng(4)
    sizes = (4, 6, 5)
    n = sum(sizes)
    base = np.array([-3.95e6, 3.38e6, 3.66e6])
    origin = base + np.array([120.0, -40.0, 15.0])
    sat = base + rng.normal(0.0, 1.0, (n, 3)) * 1.5e7 + np.array([0.0, 0.0, 2.0e7])
    var = rng.uniform(0.2, 2.0, n)
    offset = np.array([0.3, -0.7, 1.1])
    geo = np.linalg.norm(sat - (origin + offset), axis=1) - np.linalg.norm(sat - base, axis=1)
    code = geo + rng.normal(0.0, 1.0, n) * np.sqrt(var) + 3.0          # + a receiver clock (cancels in the DDs)
    start = np.cumsum((0,) + sizes[:-1])
    rows = {"groups": {"start": start, "stop": start + np.array(sizes)}, "sat_base_xyz": sat, "sat_xyz": sat,
            "var_phase": np.ones(n), "var_code": var, "lam_m": np.full(n, 0.19), "phase_sd_m": np.zeros(n),
            "code_sd_m": code}
    got = _code_unit_variance(rows, np.zeros(n, dtype=np.int64), base, origin, offset)
    r = code - geo
    chi2 = 0.0
    for a, m in zip(start, sizes):
        D = np.hstack([-np.ones((m - 1, 1)), np.eye(m - 1)])
        d = D @ r[a:a + m]
        chi2 += d @ np.linalg.solve(D @ np.diag(var[a:a + m]) @ D.T, d)
    assert got == pytest.approx(chi2 / (n - len(sizes) - 3), rel=1e-7)      # (ranges of 2e7 m differenced)


def _init(tmp_path, tag: str, config_args: tuple, init_args: tuple = (), edit=None) -> dict:
    cfg = tmp_path / f"{tag}.toml"
    r = run_cli("-q", "config", *config_args, "-o", cfg)
    assert r.exit_code == 0, r.output
    if edit:
        cfg.write_text(edit(cfg.read_text()))
    for args in (("ingest", "--config", cfg, "-o", tmp_path / f"{tag}.mcap"),
                 ("init", tmp_path / f"{tag}.mcap", *init_args, "-o", tmp_path / f"{tag}.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args[0], r.output)
    return json.loads((tmp_path / f"{tag}.json").read_text())["rovers"]


@pytest.mark.skipif(not CAR.exists(), reason="../shared/data/real-pairs absent")
def test_the_car_under_a_motion_model_keeps_its_integers(tmp_path):
    """The car with GPS L1 under constant velocity fixes 15 of 15 integers, the random-walk float started from the
    static float as before (started from the code's mean: 7 fixed, five of them wrong), and says nothing moved."""
    rov = _init(tmp_path, "car", ("--rinex", f"base={CAR / '3034265G.21O'}", "--rinex", f"rover={CAR / 'SEPT265G.21O'}",
                                  "--nav", CAR / "SEPT2650.21P", "--master", "base", "--displacement",
                                  "constant_velocity", "--signals", "G:L1"))["rover"]
    assert rov["n_fixed"] == rov["n_estimated"] == 15 and "moving_rover" not in rov["float"]


@pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")
def test_a_static_rover_through_a_high_mask_is_not_taken_for_a_moving_one(tmp_path):
    """The static mosaic rover through a 40° mask for one minute: its static float lies tens of metres from its code's
    mean with a σ as large, which says nothing of motion: 3 of 3 integers fixed, within a metre of the record."""
    rov = _init(tmp_path, "m40", ("--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={MOSAIC / 'rover.obs'}",
                                  "--nav", MOSAIC / "base.nav", "--master", "base", "--displacement", "random_walk",
                                  "--sigma", "0.1", "--signals", "G:L1"), ("--duration", "60"),
                edit=lambda t: t.replace("mask_deg = 15.0", "mask_deg = 40.0"))["rover"]
    assert "moving_rover" not in rov["float"] and rov["n_fixed"] == rov["n_estimated"] == 3
    assert np.max(np.abs(rov["float"]["enu_m"])) < 1.0
