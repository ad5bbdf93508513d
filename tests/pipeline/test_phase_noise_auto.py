"""``[gnss.displacement] phase_noise = "auto"``: estimate's per-epoch phase variances scaled by the unit variance of
the single-epoch solutions' DD phase residuals (:func:`cdgps_cli.pipeline.gnss.phase_variance_factor`).

* Honest σ on data whose noise the model does not describe: a simulated rover (random walk 2 mm/√s) with 1 mm white
  phase noise, where the default model (3 mm + 3 mm / sin el per receiver) is 2–16 times too large in variance:
  the smoothed states' NEES per dof against the simulator's truth is about 0.5 with the model and about 1 with
  auto; with the model's own noise the factor is 1 within its scatter.
* Independent check of each epoch's residual square sum: a brute-force weighted least squares on the epoch's single
  differences with one bias per signal group (np.linalg.lstsq; the DD least squares is that one with the bias
  eliminated), against the accumulated DD normal equations.
* Real data (the mosaic pair, GPS L1 + Galileo E1, two groups): the geodetic receivers scatter far less than the
  model: factor ≈ 0.05 (σ × 0.2)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.pipeline._gnss_chain import estimate_chain
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"




def _auto(text: str) -> str:
    return text.replace('model = "random_walk"', 'model = "random_walk"\nphase_noise = "auto"', 1)


@pytest.fixture(scope="module")
def quiet_receivers(tmp_path_factory):
    d = tmp_path_factory.mktemp("pn1")
    r = run_cli("-q", "simulate-gnss", "--duration", "600", "--seed", "1", "--phase-noise-m", "0.001",
                "--random-walk", "0.002", "-o", d)
    assert r.exit_code == 0, r.output
    text = (d / "config.toml").read_text()
    return d, {tag: estimate_chain(d, t, tag) for tag, t in (("model", text), ("auto", _auto(text)))}


def test_auto_gives_honest_sigma_where_the_model_is_too_large(quiet_receivers):
    _, got = quiet_receivers
    nees = {tag: ev["nees"]["mean"] / ev["nees"]["dof"] for tag, (_, ev) in got.items()}
    assert nees["model"] < 0.7                                # σ conservative: the model's variances too large
    assert 0.85 < nees["auto"] < 1.2
    pn = got["auto"][0]["rovers"]["rover"]["phase_noise"]
    assert pn["mode"] == "auto" and 0.015 < pn["factor"] < 0.05 and pn["dof"] > 1000
    assert pn["sigma_scale"] == pytest.approx(np.sqrt(pn["factor"]))
    assert "phase_noise" not in got["model"][0]["rovers"]["rover"]
    assert any("phase_noise auto" in n for n in got["auto"][0]["notes"])
    # the smaller R also lets the walk follow the truth closer
    rms = {tag: np.linalg.norm(list(ev["rms_error"].values())) for tag, (_, ev) in got.items()}
    assert rms["auto"] < 0.8 * rms["model"]


def test_with_the_models_own_noise_the_factor_is_one(tmp_path):
    r = run_cli("-q", "simulate-gnss", "--duration", "300", "--seed", "4", "--random-walk", "0.002", "-o", tmp_path)
    assert r.exit_code == 0, r.output
    est, _ = estimate_chain(tmp_path, _auto((tmp_path / "config.toml").read_text()), "auto")
    pn = est["rovers"]["rover"]["phase_noise"]
    n = pn["dof"]
    assert abs(pn["factor"] - 1.0) < 4 * np.sqrt(2.0 / n)            # χ²/n: relative σ √(2/n)


def test_each_epochs_residual_square_sum_is_the_brute_force_least_squares(quiet_receivers):
    from cdgps_cli.io.file_checks import read_init_json
    from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, read_gnss_run
    from cdgps_cli.pipeline.gnss import _stations, init_window, solve_with_init_integers

    d, _ = quiet_receivers
    init, _ = read_init_json(d / "init_model.json")
    run = read_gnss_run(d / "run_model.mcap", columns=SOLVER_COLUMNS, window=init_window(init))
    _, w, _, _ = solve_with_init_integers(run, init, "rover", _stations(run))
    _check_brute_force(w, n_epochs=40)


def _check_brute_force(w: dict, n_epochs: int) -> None:
    dd, ka = w["data"], w["kinematic"]
    group = dd.group if getattr(dd, "group", None) is not None else np.zeros(dd.epoch.size, dtype=np.int64)
    known = w["known_seg"][w["seg"]]
    pick = np.linspace(0, ka["epoch"].size - 1, n_epochs).astype(int)
    for j in pick:
        e = ka["epoch"][j]
        rows = np.flatnonzero((dd.epoch == e) & known)
        cols = [w["g"][rows]]
        kept = []
        for gk in np.unique(group[rows]):
            in_g = group[rows] == gk
            if in_g.sum() >= 2:                       # a group of one row forms no DD
                cols.append(in_g[:, None].astype(float))
                kept.append(in_g)
        use = np.any(kept, axis=0)
        A = np.hstack(cols)[use]
        sw = 1.0 / np.sqrt(w["var_ph"][rows][use])
        x, *_ = np.linalg.lstsq(A * sw[:, None], w["r_ph"][rows][use] * sw, rcond=None)
        e_w = (w["r_ph"][rows][use] - A @ x) * sw
        assert ka["sse"][j] == pytest.approx(float(e_w @ e_w), rel=1e-7, abs=1e-12)
        assert ka["dof"][j] == use.sum() - len(kept) - 3


def test_real_geodetic_receivers_scatter_far_less_than_the_model(tmp_path):
    if not MOSAIC.exists():
        pytest.skip("../shared/data/real-pairs absent")
    cfg = tmp_path / "c.toml"
    r = run_cli("-q", "config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={MOSAIC / 'rover.obs'}",
                "--nav", MOSAIC / "base.nav", "--master", "base", "--signals", "G:L1,E:E1", "--displacement",
                "random_walk", "-o", cfg)
    assert r.exit_code == 0, r.output
    est, _ = estimate_chain(tmp_path, _auto(cfg.read_text()), "auto")
    pn = est["rovers"]["rover"]["phase_noise"]
    assert 0.02 < pn["factor"] < 0.1 and pn["dof"] > 1000
    from cdgps_cli.io.file_checks import read_init_json
    from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, read_gnss_run
    from cdgps_cli.pipeline.gnss import _stations, init_window, solve_with_init_integers

    init, _ = read_init_json(tmp_path / "init_auto.json")
    run = read_gnss_run(tmp_path / "run_auto.mcap", columns=SOLVER_COLUMNS, window=init_window(init))
    _, w, _, _ = solve_with_init_integers(run, init, "rover", _stations(run))
    assert len(set(np.asarray(w["data"].group).tolist())) == 2
    _check_brute_force(w, n_epochs=20)
