"""The σ a bridged base observation gains per second of age, from the base itself (``rtk --age-noise auto``,
rtk_multi.base_age_noise, base_interpolation.base_drift_m_per_s), on the real mosaic pair
(../shared/data/real-pairs/mosaic-static) with its base's first 30 s cut, so that the rover's first 30 epochs take
a base observation carried up to 30 s back.

Every satellite's observations at both receivers get a range that grows at a rate of its own (σ 10 mm/s, as the
satellite clocks of a 2008 base pair that RTKLIB's test data hold depart from their broadcast drift): it cancels
where the receivers observe at the same time, and shows in the carried epochs as rate × age.  With RTKLIB's
1.5 mm/s some of those epochs are "fixed" 5–7 cm off; with the base's own drift none is."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
BASE_XYZ = (-3817681.1213, 3562839.4311, 3650159.1593)
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


@pytest.fixture(scope="module")
def drifting(tmp_path_factory):
    d = tmp_path_factory.mktemp("age")
    base, rover = (MOSAIC / "base.obs").read_text(), (MOSAIC / "rover.obs").read_text()
    t0 = epoch_times_gps_s(base)[0]
    rng = np.random.default_rng(1)
    rate: dict = {}

    def drift(t, sats):
        return np.array([rate.setdefault(s, rng.normal(0.0, 0.01)) * (t - t0) for s in sats])

    (d / "base.obs").write_text(edit_rinex3_obs(base, keep=lambda t: t >= t0 + 30, range_change_m=drift))
    (d / "rover.obs").write_text(edit_rinex3_obs(rover, range_change_m=drift))
    return d


def _rtk(d, mode: str):
    r = run_cli("-q", "rtk", "--base", d / "base.obs", "--rover", d / "rover.obs", "--nav", MOSAIC / "base.nav",
                "--base-xyz", *BASE_XYZ, "--signals", "G:L1", "--age-noise", mode, "-o", d / f"{mode}.csv", "--json")
    assert r.exit_code == 0, r.output
    s, df = json.loads(r.stdout), pd.read_csv(d / f"{mode}.csv", comment="#")
    enu, age, fixed = df[["e_m", "n_m", "u_m"]].to_numpy(), df["age_s"].to_numpy(), df["fixed"].to_numpy() == 1
    err = np.linalg.norm(enu - enu[(np.abs(age) < 0.1) & fixed].mean(axis=0), axis=1)
    sigma = np.linalg.norm(df[["sigma_e_m", "sigma_n_m", "sigma_u_m"]].to_numpy(), axis=1)
    return s, age, fixed, err, sigma


def test_the_bases_own_drift_weighs_the_carried_epochs(drifting):
    s_m, age, fixed_m, err_m, sigma_m = _rtk(drifting, "model")
    s_a, _, fixed_a, err_a, sigma_a = _rtk(drifting, "auto")
    assert s_m["epochs"] == s_a["epochs"] == 301 and int((np.abs(age) > 0.1).sum()) == 30
    assert s_m["age_noise"] == {"mode": "model", "sigma_m_per_s": pytest.approx(5e-12 * 299792458.0),
                                "estimate_m_per_s": None}
    assert 0.004 < s_a["age_noise"]["estimate_m_per_s"] == s_a["age_noise"]["sigma_m_per_s"] < 0.012
    assert int((fixed_m & (err_m > 0.05)).sum()) >= 3               # RTKLIB's σ: carried epochs fixed 5-7 cm off
    assert int((fixed_a & (err_a > 0.05)).sum()) == 0
    carried = np.abs(age) > 0.1
    z_m, z_a = (np.max(e[carried] / s[carried]) for e, s in ((err_m, sigma_m), (err_a, sigma_a)))
    assert z_a < 0.8 * z_m and z_a < 1.0, (z_m, z_a)                # 3-D error / 3-D σ: 1.13 -> 0.70
    assert fixed_a[~carried].sum() == fixed_m[~carried].sum()         # the simultaneous epochs fix as before


RCVRAW = REPO_ROOT / "tests" / "data" / "rtklib-rcvraw"


def test_a_real_base_that_starts_late_fixes_nothing_wrong_with_its_own_drift(tmp_path):
    """RTKLIB's own test pair of 2008 (a Hemisphere Crescent base, a u-blox LEA-4T rover; tests/data/README.md): the
    rover's first 29 used epochs precede the base's first.  With RTKLIB's 1.5 mm/s four of them, carried 25–28 s
    back, were fixed about 0.2 m from every later fix with σ of 3–8 cm; the base's own drift is 10 mm/s, and with
    it none is (RTKLIB fixes no epoch of this pair)."""
    out = {}
    for mode in ("model", "auto"):
        r = run_cli("-q", "rtk", "--base", RCVRAW / "cres.obs.gz", "--rover", RCVRAW / "ubx.obs.gz", "--nav",
                    RCVRAW / "cres.nav.gz", "--nav", RCVRAW / "ubx.nav.gz", "--signals", "G:L1", "--age-noise", mode,
                    "-o", tmp_path / f"{mode}.csv", "--json")
        assert r.exit_code == 0, r.output
        df = pd.read_csv(tmp_path / f"{mode}.csv", comment="#")
        fixed, age = df["fixed"].to_numpy() == 1, df["age_s"].to_numpy()
        enu = df[["e_m", "n_m", "u_m"]].to_numpy()
        err = np.linalg.norm(enu - np.median(enu[fixed & (np.abs(age) < 0.1)], axis=0), axis=1)
        out[mode] = (json.loads(r.stdout), fixed, err, age)
    s_m, fixed_m, err_m, age = out["model"]
    s_a, fixed_a, err_a, _ = out["auto"]
    assert s_m["epochs"] == s_a["epochs"] == 142 and int((age < -20).sum()) == 10
    assert 0.007 < s_a["age_noise"]["estimate_m_per_s"] < 0.014
    wrong_m, wrong_a = (int((f & (e > 0.05)).sum()) for f, e in ((fixed_m, err_m), (fixed_a, err_a)))
    assert wrong_m >= 3 and np.all(age[fixed_m & (err_m > 0.05)] < -20), (wrong_m, age[fixed_m & (err_m > 0.05)])
    assert wrong_a == 0 and fixed_a.sum() >= fixed_m.sum() - wrong_m


def _init_run(d, base, rover):
    """The pair through ``config`` and ``ingest`` (GPS + GLONASS + Galileo + BeiDou as the files hold them)."""
    for args in (("config", "--rinex", f"base={base}", "--rinex", f"rover={rover}", "--nav", MOSAIC / "base.nav",
                  "--master", "base", "-o", d / "cfg.toml"),
                 ("ingest", "--config", d / "cfg.toml", "-o", d / "run.mcap")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, r.output
    return d / "run.mcap"


def test_init_weighs_the_carried_epochs_by_the_bases_own_drift(drifting, tmp_path):
    """``init`` (the static engine and the batch tables it renders with) takes the age σ as rtk's ``--age-noise
    auto`` does: on the drifting pair it finds 4-12 mm/s, records it in INIT (the rover's ``epochs.age_noise`` and
    its ``options``, which ``estimate`` weighs with), and its static solution is that of the unedited pair (whose
    epochs are all simultaneous) to 0.6 mm, where RTKLIB's 1.5 mm/s leaves 2 mm; ``estimate``'s NIS per degree of
    freedom is then below 1 (3.7 at 1.5 mm/s)."""
    from cdgps_cli.io.gnss_run import read_gnss_run
    from cdgps_cli.pipeline.gnss import gnss_init

    (tmp_path / "clean").mkdir()
    (tmp_path / "drift").mkdir()
    clean = gnss_init(read_gnss_run(_init_run(tmp_path / "clean", MOSAIC / "base.obs", MOSAIC / "rover.obs")))
    drift_run = _init_run(tmp_path / "drift", drifting / "base.obs", drifting / "rover.obs")
    auto = gnss_init(read_gnss_run(drift_run))
    rtklib = gnss_init(read_gnss_run(drift_run), options={"age_sigma_m_per_s": 5e-12 * 299792458.0})
    enu = {k: np.array(v["rovers"]["rover"]["fixed"]["enu_m"]) for k, v in
           (("clean", clean), ("auto", auto), ("rtklib", rtklib))}
    noise = auto["rovers"]["rover"]["epochs"]["age_noise"]
    assert noise["mode"] == "auto" and 0.004 < noise["estimate_m_per_s"] == noise["sigma_m_per_s"] < 0.012
    assert auto["rovers"]["rover"]["options"]["age_sigma_m_per_s"] == noise["sigma_m_per_s"]
    assert clean["rovers"]["rover"]["epochs"]["age_noise"]["estimate_m_per_s"] is None      # nothing carried
    assert rtklib["rovers"]["rover"]["epochs"]["age_noise"]["mode"] == "model"
    d_auto, d_rtklib = (float(np.linalg.norm(enu[k] - enu["clean"])) for k in ("auto", "rtklib"))
    assert d_auto < 0.6e-3 < 1.5e-3 < d_rtklib, (d_auto, d_rtklib)
    (tmp_path / "init.json").write_text(json.dumps(auto))
    r = run_cli("-q", "estimate", drift_run, "--init", tmp_path / "init.json", "-o", tmp_path / "states.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["mean_nis_per_dof"] < 1.0
    for bad in (-1.0, "NaN"):                     # an INIT whose recorded σ is not one: named, nothing written
        auto["rovers"]["rover"]["options"]["age_sigma_m_per_s"] = bad
        (tmp_path / "bad.json").write_text(json.dumps(auto))
        r = run_cli("-q", "estimate", drift_run, "--init", tmp_path / "bad.json", "-o", tmp_path / "bad.mcap")
        assert r.exit_code == 2 and "Traceback" not in r.output, r.output
        assert "bad.json: bad options for rover (rovers.rover.options)" in r.output and "age_sigma_m_per_s" in r.output
        assert not (tmp_path / "bad.mcap").exists()
