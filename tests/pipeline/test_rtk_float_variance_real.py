"""``rtk``'s float σ on a real rover (../shared/data/real-pairs/geonet-car: a mosaic-X5 on a car against the GEONET
station 3034 5.4 km away, GPS + Galileo L1): the forward and backward floats disagree by more than their σ allow
(the receivers' errors correlated over minutes), and the float σ reported are scaled by the disagreement
(rtk_multi.float_variance_factor).  Checked against the positions of the same run's fixed epochs (cm-accurate):
NEES per DoF 4.9 before the scaling, 1.6 after.  A simulated pair of white errors keeps its σ."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tests._shared import REPO_ROOT, run_cli

CAR = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "geonet-car"
BASE_XYZ = (-3959400.631, 3385704.533, 3667523.111)           # its README's (the header's is 4.4 m off)


def _rtk(tmp_path, name: str, *extra):
    r = run_cli("-q", "rtk", "--base", CAR / "3034265G.21O", "--rover", CAR / "SEPT265G.21O", "--nav",
                CAR / "SEPT2650.21P", "--base-xyz", *BASE_XYZ, "--signals", "G:L1,E:E1", "-o", tmp_path / name, "--json",
                *extra)
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout), pd.read_csv(tmp_path / name, comment="#")


@pytest.mark.skipif(not CAR.exists(), reason="../shared/data/real-pairs absent")
def test_a_real_cars_float_sigma_is_scaled_to_what_its_errors_are(tmp_path):
    _, fixed = _rtk(tmp_path, "fix.csv")
    s, flt = _rtk(tmp_path, "flt.csv", "--float-only")
    fv = s["float_variance"]
    assert s["fixed_epochs"] == 0 and fv["epochs"] == 360
    assert fv["factor"] == fv["disagreement"] > fv["threshold"] > 1, fv
    m = fixed.merge(flt, on="time_gps_s", suffixes=("_fix", ""))
    m = m[m["fixed_fix"] == 1]
    assert len(m) > 250
    e = m[["e_m", "n_m", "u_m"]].to_numpy() - m[["e_m_fix", "n_m_fix", "u_m_fix"]].to_numpy()
    sig = m[["sigma_e_m", "sigma_n_m", "sigma_u_m"]].to_numpy()
    nees_after = np.mean(np.sum((e / sig) ** 2, axis=1)) / 3
    nees_before = nees_after * fv["factor"]             # the σ the filters gave, before the scaling
    assert nees_before > 3.0 and 0.5 < nees_after < 2.5, (nees_before, nees_after)


def test_white_errors_keep_their_sigma(tmp_path):
    r = run_cli("-q", "simulate-gnss", "--duration", 600, "--seed", 5, "--code-noise-m", 3, "--phase-noise-m", 0.005,
                "-o", tmp_path / "sim")
    assert r.exit_code == 0, r.output
    d = tmp_path / "sim"
    r = run_cli("-q", "rtk", "--base", d / "base.rnx", "--rover", d / "rover.rnx", "--nav", d / "nav.rnx",
                "--float-only", "-o", tmp_path / "flt.csv", "--json")
    assert r.exit_code == 0, r.output
    fv = json.loads(r.stdout)["float_variance"]
    assert fv["factor"] == 1.0 and fv["disagreement"] < fv["threshold"], fv
