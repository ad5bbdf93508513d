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
    # white noise of the estimator's elevation model (σ² = a² + b²/sin²el per receiver: 4–12 mm per SD) beside the
    # multipath: the split of an elevation-dependent variance is what the fit's σ depends on
    r = run_cli("-q", "simulate-gnss", "--duration", "1200", "--seed", "2", "--random-walk", "0.001",
                "--multipath-m", "0.005", "--multipath-tau-s", "40", "-o", d)
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
    assert 0.004 < mp["sigma_m"] < 0.0065 and 20.0 < mp["time_constant_s"] < 80.0      # (simulated: 5 mm, 40 s)
    assert 0.1 < mp["correlated_share"] < 0.6 and mp["white_factor"] == pytest.approx(1 - mp["correlated_share"])
    assert mp["sigma_m"] ** 2 == pytest.approx(mp["correlated_share"] * mp["sd_phase_sigma_m"] ** 2)
    assert 6 <= mp["states"] <= 16                       # GPS L1 over 20 minutes: the satellites seen
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
    ('model = "random_walk"\nmultipath = "sometimes"', "gnss.displacement.multipath: expected one of"),
    ('model = "random_walk"\nmultipath = "model"\nmultipath_sigma_m = 1e300', "a multipath sigma in (0, 0.1] m"),
    ('model = "random_walk"\nmultipath = "model"\nmultipath_sigma_m = 0.01\nmultipath_time_constant_s = 1e-6',
     "a correlation time in [0.001, 1e+09] s"),
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


def test_model_mode_takes_the_given_sigma_and_several_inits_join_as_the_whole_record(multipath_rover, monkeypatch):
    """Two windows' INITs with multipath states give the whole record's states: each satellite's multipath state goes
    on over the seam (a satellite both windows hold), the filter and smoother run over both windows."""
    from cdgps_cli.io.states import States

    d, _ = multipath_rover
    text = (d / "config.toml").read_text().replace(
        'model = "random_walk"', 'model = "random_walk"\nmultipath = "model"\nmultipath_sigma_m = 0.005\n'
                                 'multipath_time_constant_s = 40', 1)
    (d / "m.toml").write_text(text)
    assert run_cli("-q", "ingest", "--config", d / "m.toml", "-o", d / "run_m.mcap").exit_code == 0
    assert run_cli("-q", "init", d / "run_m.mcap", "-o", d / "whole_m.json").exit_code == 0
    for k, (s, n) in enumerate(((0, 600), (600, 600))):
        r = run_cli("-q", "init", d / "run_m.mcap", "--start", str(s), "--duration", str(n), "-o", d / f"w{k}.json")
        assert r.exit_code == 0, r.output
    r = run_cli("-q", "estimate", d / "run_m.mcap", "--init", d / "whole_m.json", "--smooth", "-o", d / "st_m.mcap",
                "--json")
    assert r.exit_code == 0, r.output
    mp = json.loads(r.stdout)["rovers"]["rover"]["multipath"]
    n = mp.pop("states")
    assert mp == {"mode": "model", "sigma_m": 0.005, "time_constant_s": 40.0, "white_factor": 1.0} and 6 <= n <= 16
    r = run_cli("-q", "estimate", d / "run_m.mcap", "--init", d / "w0.json", "--init", d / "w1.json", "--smooth",
                "-o", d / "st2.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert any("multipath model: Gauss-Markov phase states in 2 of its 2 windows" in n for n in json.loads(r.stdout)["notes"])
    whole, two = States(d / "st_m.mcap"), States(d / "st2.mcap")
    assert two.time_s.tobytes() == whole.time_s.tobytes()
    assert np.max(np.abs(two.q - whole.q)) < 1e-6                       # (measured: 0.17 µm)
    assert np.max(np.abs(two.sigma_q / whole.sigma_q - 1.0)) < 1e-8       # (1.3e-10)
    rov = json.loads(two.metadata["rovers"])["rover"]
    assert len({w_["multipath"]["states"] for w_ in rov["windows"]}) == 2  # (12 and 11: the narrower one padded)
    assert "multipath" not in rov                                         # (each window's own, not the first's)
    r = run_cli("-q", "report", "run", d / "st2.mcap", "-o", d / "page2")
    assert r.exit_code == 0, r.output
    import html
    import re

    from cdgps_cli.report.run_report import _nis_side_text

    text = re.sub(r"<[^>]+>", " ", html.unescape((d / "page2" / "index.html").read_text()))
    assert "rover: model, in 2 of its 2 windows, each its own: σ 5.00 … 5.00 mm, τ 40 … 40 s" in text
    assert "multipath states" in _nis_side_text(0.5, 0.9, True) and "multipath states" not in _nis_side_text(0.5, 0.9)
    # the control: every multipath state started afresh at the seam, as if the windows' satellites were others
    import cdgps_cli.pipeline.gnss as gnss_mod

    real = gnss_mod.seam_transition
    monkeypatch.setattr(gnss_mod, "seam_transition", lambda dyn, n_dyn, last, first, n_prev, dt:
                        real(dyn, n_dyn, [], first, n_prev, dt))
    r = run_cli("-q", "estimate", d / "run_m.mcap", "--init", d / "w0.json", "--init", d / "w1.json", "--smooth",
                "-o", d / "st3.mcap")
    assert r.exit_code == 0, r.output
    fresh = States(d / "st3.mcap")
    assert np.max(np.abs(fresh.q - whole.q)) > 1e-4 and np.max(np.abs(fresh.sigma_q / whole.sigma_q - 1.0)) > 0.05


def test_a_state_per_arc_taken_again_once_the_process_has_forgotten():
    """Arcs of one (group, satellite) split where its DDs stop for more than 10 τ; a later arc takes the state of one
    that ended at least 10 τ before it; a row alone in its group at an epoch (no DD) gets no state."""
    from types import SimpleNamespace

    from cdgps_cli.pipeline.gnss_multipath import FORGET_TIME_CONSTANTS, state_columns

    assert FORGET_TIME_CONSTANTS == 10.0
    span = {0: (0, 99), 1: (0, 299), 2: (150, 299), 3: (120, 140), 4: (0, 299)}      # satellite: first, last epoch
    rows = [(k, s) for k in range(300) for s, (a, b) in span.items() if a <= k <= b]
    sat = np.array([s for _, s in rows])
    group = np.where(sat == 4, 1, 0)          # satellite 4: the only one of its group, never in a DD
    d = SimpleNamespace(sat=sat, epoch=np.array([k for k, _ in rows]), t_label=np.arange(300.0), group=group)
    col, n = state_columns(d, np.ones(sat.size, dtype=bool), tau_s=5.0)             # 10 τ = 50 s
    assert np.all(col[sat == 4] == -1)
    # satellite 1 alone in its group from 100 to 119 s and from 141 to 149 s
    alone = (sat == 1) & (((d.epoch >= 100) & (d.epoch < 120)) | ((d.epoch > 140) & (d.epoch < 150)))
    assert np.all(col[alone] == -1) and np.all(col[(sat < 4) & ~alone] >= 0)
    c = {s: set(col[(sat == s) & ~alone].tolist()) for s in range(4)}
    assert all(len(v) == 1 for v in c.values())
    # 0 ends at 99: satellite 3 (from 120) is within 50 s of it, satellite 2 (from 150) is not and takes its state
    assert c[2] == c[0] and c[3] != c[0] and n == 3
    col, n = state_columns(d, np.ones(sat.size, dtype=bool), tau_s=10.0)            # 100 s: no state taken again
    assert n == 4
    # a satellite away for more than 10 τ starts an arc of its own (here another state: the first is not free yet)
    gap = ~((sat == 1) & (d.epoch >= 100) & (d.epoch < 200))
    col, n = state_columns(d, gap, tau_s=5.0)
    assert len(set(col[(sat == 1) & gap].tolist()) - {-1}) == 2


def test_taking_a_forgotten_state_again_changes_the_filter_by_its_forgotten_correlation(monkeypatch):
    """A hand-made pair where satellite 5 rises 30 s (15 τ) after satellite 0 set: with its state taken again the
    filter's states and covariances are those with a state of its own, to the correlation left, exp(−15) ≈ 3e-7."""
    from types import SimpleNamespace

    import cdgps_cli.pipeline.gnss_multipath as gm

    rng = np.random.default_rng(5)
    seen = {0: (0, 29), 1: (0, 99), 2: (0, 99), 3: (0, 99), 4: (0, 99), 5: (60, 99)}
    rows = [(k, s_) for k in range(100) for s_, (a, b) in seen.items() if a <= k <= b]
    sat = np.array([s_ for _, s_ in rows])
    epoch = np.array([k for k, _ in rows])
    ptr = np.searchsorted(epoch, np.arange(101))
    d = SimpleNamespace(sat=sat, epoch=epoch, t_label=np.arange(100.0), group=None)
    g, r = rng.normal(size=(sat.size, 3)), rng.normal(scale=0.01, size=sat.size)
    var_w = rng.uniform(1e-6, 4e-6, size=sat.size)
    ref = ptr[:-1] + 1                                   # satellite 1 is every epoch's reference
    out = {}
    for forget in (10.0, 1e9):
        monkeypatch.setattr(gm, "FORGET_TIME_CONSTANTS", forget)
        col, n = gm.state_columns(d, np.ones(sat.size, dtype=bool), tau_s=2.0)
        ob = SDObservations(r, var_w, ref, ambiguity_col=col, wavelength_m=1.0)
        dd = SatelliteDDDisplacement(ptr, sat, [f"G{i:02d}" for i in range(6)], g, [ob], n_ambiguities=n)
        meas, dyn, P0 = _dynamics_of(dd, "random_walk", 0.001, None, 0.5, (n, 0.006, 2.0))
        fr = _forward(meas, dyn, d.t_label, np.zeros(dyn.n), P0)
        out[forget] = (n, np.asarray(fr["x"])[:, :3], np.asarray(fr["P"])[:, :3, :3])
    assert (out[10.0][0], out[1e9][0]) == (5, 6)
    np.testing.assert_allclose(out[10.0][1], out[1e9][1], rtol=0, atol=1e-6 * np.sqrt(out[1e9][2][:, 0, 0]).min())
    np.testing.assert_allclose(out[10.0][2], out[1e9][2], rtol=1e-6)


def test_epochs_without_two_degrees_of_freedom_stay_out_of_the_fit(multipath_rover):
    """An epoch with 3 DDs has residuals of exactly 0 after its own fit (and 4: one number): they are left out."""
    from cdgps_cli.io.file_checks import read_init_json
    from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, read_gnss_run
    from cdgps_cli.pipeline.gnss import _stations, init_window, solve_with_init_integers
    from cdgps_cli.estimation.baseline import known_phase_blocks
    from cdgps_cli.pipeline.gnss_multipath import single_epoch_dd_residuals

    d, _ = multipath_rover
    init, _ = read_init_json(d / "init_auto.json")
    run = read_gnss_run(d / "run_auto.mcap", columns=SOLVER_COLUMNS, window=init_window(init))
    _, w, _, _ = solve_with_init_integers(run, init, "rover", _stations(run))
    use = w["known_seg"][w["seg"]]

    def blocks(rows):
        return known_phase_blocks(w["data"], w["var_ph"], w["refs_ph"], w["blocks_ph"], rows)[0]

    resid, _, keys, mean_var = single_epoch_dd_residuals(w, blocks(use))
    n_dd = np.sum(np.isfinite(resid), axis=1)
    assert n_dd.max() > 5 and np.all((n_dd == 0) | (n_dd >= 5))
    # keep only 4 satellites at every epoch (3 DDs): nothing is left to fit
    d_ = w["data"]
    four = np.zeros(d_.sat.size, dtype=bool)
    for k in range(d_.t_label.size):
        rows = np.flatnonzero((d_.epoch == k) & use)[:4]
        four[rows] = True
    resid4, _, _, _ = single_epoch_dd_residuals(w, blocks(use & four))
    assert not np.isfinite(resid4).any()
    assert 1e-6 < mean_var < 1e-3


def test_the_run_report_says_what_multipath_states_the_estimate_had(multipath_rover, tmp_path):
    import html
    import re

    d, got = multipath_rover
    mp = got["auto"][0]["rovers"]["rover"]["multipath"]
    pages = {}
    for tag in ("auto", "off"):
        r = run_cli("-q", "report", "run", d / f"states_{tag}.mcap", "-o", tmp_path / tag)
        assert r.exit_code == 0, r.output
        pages[tag] = re.sub(r"<[^>]+>", " ", html.unescape((tmp_path / tag / "index.html").read_text()))
    assert (f"phase multipath states ([gnss.displacement] multipath)  rover: auto, one Gauss-Markov state per "
            f"satellite and signal, σ {1e3 * mp['sigma_m']:.2f} mm, τ {mp['time_constant_s']:.3g} s") in pages["auto"]
    assert "phase multipath states" not in pages["off"]


def test_a_fit_without_white_noise_leaves_the_phases_some(monkeypatch):
    """The fit's non-negative least squares may give no white part at all; the white variances stay positive (a DD
    covariance of zero cannot be factored): at most MAX_CORRELATED_SHARE of the variance goes to the multipath."""
    from types import SimpleNamespace

    import cdgps_cli.measurement.multipath as mm
    import cdgps_cli.pipeline.gnss_multipath as gm

    monkeypatch.setattr(gm, "single_epoch_dd_residuals", lambda w, blocks: (np.zeros((5, 1)), np.zeros((5, 1)), [(0,)], 4e-5))
    monkeypatch.setattr(mm, "fit_autocovariance", lambda r, s, dt: {
        "detected": True, "raw_sigma_m": 0.006, "white_sigma_m": 0.0, "time_constant_s": 100.0,
        "raw_time_constant_s": 100.0, "ljung_box_q": 1e4, "ljung_box_limit": 50.0, "runs": 3})
    cfg = SimpleNamespace(multipath="auto")
    mp = gm.multipath_settings(cfg, {"data": SimpleNamespace(interval_s=1.0)}, [], 1.0)
    assert mp["correlated_share"] == gm.MAX_CORRELATED_SHARE == 0.999
    assert mp["white_factor"] == pytest.approx(1e-3) and mp["sigma_m"] == pytest.approx(np.sqrt(0.999 * 4e-5))
