"""``[gnss.displacement] multipath``: Gauss–Markov phase-multipath states per satellite in estimate's per-epoch states
(:mod:`cdgps_cli.pipeline.gnss_multipath`).

* Independent check: with a rover that does not move (random walk of 0; constant velocity with no acceleration), the
  filter over [displacement (, velocity), multipath] is the generalised least squares of every epoch's DDs at once
  under the errors' full covariance (each satellite's SD error σ² a^|Δt|/τ plus white, the DD operator applied),
  with the prior as one more observation: same estimate and covariance to rounding.
* Simulator truth: a random-walking rover whose phases carry a Gauss–Markov multipath (σ 5 mm, τ 40 s): the states'
  NEES per dof against the truth is far above 1 with the errors taken as white and about 1 with ``"auto"``, whose
  fitted σ and τ are near the simulated ones.
* White phase errors: ``"auto"`` finds no time correlation and the states are the white model's, bit for bit.
* Config rules, and several INITs refused.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.measurement.dd_displacement import SatelliteDDDisplacement, SDObservations
from cdgps_cli.pipeline.gnss import _dynamics_of, _forward
from tests.pipeline._gnss_chain import estimate_chain
from tests._shared import run_cli


def _problem(seed: int, n_ep: int = 25, n_sat: int = 5):
    """A hand-made pair: every satellite at every epoch (1 s apart), the first row each epoch's reference."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_ep, dtype=float)
    sat = np.tile(np.arange(n_sat), n_ep)
    g = rng.normal(size=(n_ep * n_sat, 3))
    r = rng.normal(scale=0.01, size=n_ep * n_sat)
    var_w = rng.uniform(1e-6, 4e-6, size=n_ep * n_sat)
    ptr = np.arange(0, n_ep * n_sat + 1, n_sat)
    ref = np.arange(0, n_ep * n_sat, n_sat)
    return t, sat, g, r, var_w, ptr, ref


def _gls(t, sat, g, r, var_w, n_sat, sigma, tau, p0, t_of_state=None):
    """The GLS of θ = [x0 (, v)] from all DDs at once: z = D(G x0 (+ G t v)) + D m + D w; prior θ ~ N(0, p0² I)."""
    n = t.size
    cv = t_of_state is not None
    k = np.repeat(np.arange(n), n_sat)
    # SD error covariance: σ² exp(−|t_i − t_j|/τ) between rows of one satellite, white on the diagonal
    same = sat[:, None] == sat[None, :]
    C_sd = np.where(same, sigma**2 * np.exp(-np.abs(t[k][:, None] - t[k][None, :]) / tau), 0.0) + np.diag(var_w)
    D = np.zeros((n * (n_sat - 1), n * n_sat))
    for e in range(n):
        for j in range(1, n_sat):
            D[e * (n_sat - 1) + j - 1, e * n_sat + j] = 1.0
            D[e * (n_sat - 1) + j - 1, e * n_sat] = -1.0
    H_sd = np.hstack([g, g * t[k][:, None]]) if cv else g
    H, z, C = D @ H_sd, D @ r, D @ C_sd @ D.T
    W = np.linalg.inv(C)
    N = H.T @ W @ H + np.eye(H.shape[1]) / p0**2
    P = np.linalg.inv(N)
    return P @ H.T @ W @ z, P


@pytest.mark.parametrize("model", ["random_walk", "constant_velocity"])
def test_the_filter_with_multipath_states_is_the_least_squares_of_correlated_errors(model):
    n_sat, sigma, tau, p0 = 5, 0.006, 12.0, 0.5
    t, sat, g, r, var_w, ptr, ref = _problem(seed=3, n_sat=n_sat)
    ob = SDObservations(r, var_w, ref, ambiguity_col=sat, wavelength_m=1.0)
    dd = SatelliteDDDisplacement(ptr, sat, [f"G{i:02d}" for i in range(n_sat)], g, [ob], n_ambiguities=n_sat)
    meas, dyn, P0 = _dynamics_of(dd, model, 0.0, 0.0, p0, (n_sat, sigma, tau))
    assert dyn.n == P0.shape[0] == (3 if model == "random_walk" else 6) + n_sat
    fr = _forward(meas, dyn, t, np.zeros(dyn.n), P0)
    x_last, P_last = np.asarray(fr["x"])[-1], np.asarray(fr["P"])[-1]
    if model == "random_walk":
        theta, P = _gls(t, sat, g, r, var_w, n_sat, sigma, tau, p0)
        np.testing.assert_allclose(x_last[:3], theta, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(P_last[:3, :3], P, rtol=1e-7, atol=1e-14)
    else:                               # the last epoch's [x, v] = T θ, θ = [x0, v], T = [[I, t_N I], [0, I]]
        theta, P = _gls(t, sat, g, r, var_w, n_sat, sigma, tau, p0, t_of_state=t)
        T = np.block([[np.eye(3), t[-1] * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
        np.testing.assert_allclose(x_last[:6], T @ theta, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(P_last[:6, :6], T @ P @ T.T, rtol=1e-7, atol=1e-14)
    # without the multipath states the same data give a far smaller (white-noise) covariance: the states matter
    meas0, dyn0, P00 = _dynamics_of(SatelliteDDDisplacement(ptr, sat, [f"G{i:02d}" for i in range(n_sat)], g,
                                                            [SDObservations(r, var_w, ref)]), model, 0.0, 0.0, p0)
    P_white = np.asarray(_forward(meas0, dyn0, t, np.zeros(dyn0.n), P00)["P"])[-1][:3, :3]
    assert np.trace(P_white) < 0.5 * np.trace(P_last[:3, :3])




def _with(text: str, mode: str) -> str:
    return text.replace('model = "random_walk"', f'model = "random_walk"\nphase_noise = "auto"\nmultipath = "{mode}"', 1)


@pytest.fixture(scope="module")
def multipath_rover(tmp_path_factory):
    d = tmp_path_factory.mktemp("mp")
    r = run_cli("-q", "simulate-gnss", "--duration", "1200", "--seed", "2", "--phase-noise-m", "0.001",
                "--random-walk", "0.001", "--multipath-m", "0.005", "--multipath-tau-s", "40", "-o", d)
    assert r.exit_code == 0, r.output
    truth = json.loads((d / "truth.json").read_text())
    assert truth["phase_multipath"]["sigma_m"] == 0.005 and truth["phase_multipath"]["time_constant_s"] == 40.0
    text = (d / "config.toml").read_text()
    return d, {tag: estimate_chain(d, _with(text, tag), tag) for tag in ("off", "auto")}


def test_auto_multipath_states_make_the_sigma_honest_where_white_errors_do_not(multipath_rover):
    _, got = multipath_rover
    nees = {tag: ev["nees"]["mean"] / ev["nees"]["dof"] for tag, (_, ev) in got.items()}
    assert nees["off"] > 4.0                             # white errors: σ far below the error
    assert 0.7 < nees["auto"] < 1.6
    mp = got["auto"][0]["rovers"]["rover"]["multipath"]
    assert mp["mode"] == "auto" and mp["detected"]
    assert 0.0035 < mp["sigma_m"] < 0.008 and 20.0 < mp["time_constant_s"] < 80.0
    assert 0.5 < mp["correlated_share"] < 1.0 and mp["white_factor"] == pytest.approx(1 - mp["correlated_share"])
    assert "multipath" not in got["off"][0]["rovers"]["rover"]
    assert any("multipath auto: a Gauss-Markov phase state" in n for n in got["auto"][0]["notes"])


def test_auto_finds_no_correlation_in_white_errors_and_leaves_the_states_alone(tmp_path):
    from cdgps_cli.io.states import States

    r = run_cli("-q", "simulate-gnss", "--duration", "400", "--seed", "1", "--phase-noise-m", "0.002",
                "--random-walk", "0.001", "-o", tmp_path)
    assert r.exit_code == 0, r.output
    text = (tmp_path / "config.toml").read_text()
    got = {tag: estimate_chain(tmp_path, _with(text, tag), tag) for tag in ("off", "auto")}
    mp = got["auto"][0]["rovers"]["rover"]["multipath"]
    assert mp["mode"] == "auto" and not mp["detected"] and "sigma_m" not in mp
    assert any("no multipath states" in n for n in got["auto"][0]["notes"])
    a, b = (States(tmp_path / f"states_{tag}.mcap") for tag in ("off", "auto"))
    np.testing.assert_array_equal(np.asarray(a.q), np.asarray(b.q))
    np.testing.assert_array_equal(np.asarray(a.sigma_q), np.asarray(b.sigma_q))


@pytest.mark.parametrize("extra, complaint", [
    ('multipath = "auto"', 'gnss.displacement.multipath: \'auto\' is only used with model = "random_walk"'),
    ('model = "random_walk"\nmultipath = "model"', "gnss.displacement.multipath_sigma_m: needed with"),
    ('model = "random_walk"\nmultipath_sigma_m = 0.005', 'multipath_sigma_m: only used with multipath = "model"'),
    ('model = "random_walk"\nmultipath = "sometimes"', "gnss.displacement.multipath"),
])
def test_config_rules(tmp_path, extra, complaint):
    from cdgps_cli.config.structure import load_gnss_config
    from cdgps_cli.core.errors import CdgpsError

    (tmp_path / "b.obs").write_text("")
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[gnss]\nmaster = "b"\nnav = ["b.obs"]\n[gnss.displacement]\n{extra}\n'
                   f'[gnss.antennas.b]\nrinex = "b.obs"\n[gnss.antennas.r]\nrinex = "b.obs"\n')
    with pytest.raises(CdgpsError) as exc:
        load_gnss_config(cfg)
    assert complaint in str(exc.value)


def test_model_mode_takes_the_given_sigma_and_several_inits_are_refused(multipath_rover):
    d, _ = multipath_rover
    text = (d / "config.toml").read_text().replace(
        'model = "random_walk"', 'model = "random_walk"\nmultipath = "model"\nmultipath_sigma_m = 0.005\n'
                                 'multipath_time_constant_s = 40', 1)
    (d / "m.toml").write_text(text)
    assert run_cli("-q", "ingest", "--config", d / "m.toml", "-o", d / "run_m.mcap").exit_code == 0
    for k, (s, n) in enumerate(((0, 600), (600, 600))):
        r = run_cli("-q", "init", d / "run_m.mcap", "--start", str(s), "--duration", str(n), "-o", d / f"w{k}.json")
        assert r.exit_code == 0, r.output
    r = run_cli("-q", "estimate", d / "run_m.mcap", "--init", d / "w0.json", "-o", d / "st_m.mcap", "--json")
    assert r.exit_code == 0, r.output
    mp = json.loads(r.stdout)["rovers"]["rover"]["multipath"]
    assert mp == {"mode": "model", "sigma_m": 0.005, "time_constant_s": 40.0, "white_factor": 1.0}
    r = run_cli("estimate", d / "run_m.mcap", "--init", d / "w0.json", "--init", d / "w1.json", "-o", d / "st2.mcap")
    assert r.exit_code == 2 and "several INITs" in r.output and "Traceback" not in r.output
    assert not (d / "st2.mcap").exists()
