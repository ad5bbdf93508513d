"""The single-epoch positions of the batch baseline (``baseline._single_epoch_positions``) take only epochs whose DDs
fix a position.  Counting DDs is not enough: with L1 and L2, an epoch's DDs can come from two or three satellites
(each satellite's L1 and L2 DDs share one direction), a singular system.  The real u-blox walk of
../shared/data/real-pairs/ublox-walk as a zero baseline (its RINEX conversion as base and rover, GPS L1 + L2,
random walk) ended ``init`` in a LinAlgError traceback; it now fixes its integers and gives the other epochs'
single-epoch positions."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.measurement.epoch_fit import full_rank as _full_rank
from tests._shared import REPO_ROOT, run_cli

WALK = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "ublox-walk"


def test_full_rank_against_the_eigenvalues():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 3))
    full = a @ a.T
    u = rng.normal(size=(3, 2))
    rank2 = u @ u.T                                       # two directions only: singular
    assert _full_rank(np.array([full, rank2, np.zeros((3, 3)), np.eye(3) * 1e-30])).tolist() == [True, False, False,
                                                                                                    True]
    assert _full_rank(np.zeros((0, 3, 3))).shape == (0,)


@pytest.mark.skipif(not WALK.exists(), reason="../shared/data absent")
def test_a_real_l1_l2_log_with_too_few_satellites_at_some_epochs(tmp_path):
    obs, nav = WALK / "gnss_1730_convbin.obs", WALK / "gnss_1730_convbin.nav"
    r = run_cli("-q", "config", "--rinex", f"base={obs}", "--rinex", f"rover={obs}", "--nav", nav,
                "--displacement", "random_walk", "-o", tmp_path / "c.toml")
    assert r.exit_code == 0, r.output
    assert '"G:L2"' in (tmp_path / "c.toml").read_text()
    for args in (("ingest", "--config", tmp_path / "c.toml", "-o", tmp_path / "run.mcap"),
                 ("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0 and "Traceback" not in r.output, (args, r.output)
    rov = json.loads((tmp_path / "init.json").read_text())["rovers"]["rover"]
    assert rov["n_fixed"] > 0 and 0 < rov["kinematic"]["n_epochs"] < rov["epochs"]["n_epochs_used"]
