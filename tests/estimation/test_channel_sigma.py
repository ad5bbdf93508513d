"""Per-channel measurement σ in the filter (issue 11 items 4 and 13): R = diag(σ_c²).

* an antenna with 5× the others' white noise (``SimOptions.noise_scale``): INIT's per-channel σ and
  the filter's residual-based σ̂ of its channels within 20 % of the simulator's, NEES/dof of the
  modal positions in [0.7, 1.4]; a filter given one σ for every channel flags that antenna's
  channels and its per-channel adaptation recovers their σ;
* independent check: ``estimate`` (compiled and numpy paths) equals a textbook covariance-form EKF
  (K = P̄Hᵀ(HP̄Hᵀ + R)⁻¹, Joseph update) with the same per-row R;
* the simulator's ``noise_scale`` and INIT.json's ``sigma_m_per_channel`` are validated.
"""

from __future__ import annotations


import numpy as np
import pytest

from cdgps_cli.estimation import kernel as ekf_kernel
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.estimation.filter import EstimateOptions, estimate
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.measurement.phase import EpochPhaseModel, channel_indices
from cdgps_cli.core.records import memory_run
from cdgps_cli.sim.structure import SimOptions, parse_noise_scale, simulate

from _shared import kernel

NOISY = "a3"


@pytest.fixture(scope="module")
def noisy_antenna(testbed_cfg):
    """Testbed, 40 s, 2 mm white noise, antenna a3 at 10 mm (5×); INIT on 0–20 s (default options)."""
    sim = simulate(testbed_cfg, SimOptions(duration_s=40.0, seed=5, phase_sigma_m=0.002, noise_scale={NOISY: 5.0}))
    run = memory_run(testbed_cfg, sim.receiver)
    init = initialize(run, InitOptions(start_s=0.0, duration_s=20.0))
    return sim, run, init


def _nees_positions(cfg, sim, res, t_from):
    """Mean NEES per dof of the modal positions over the filter's epochs after ``t_from``."""
    nm = cfg.n_modes
    k = np.searchsorted(sim.time_s, res.time_s - 1e-9)
    sel = res.time_s > t_from + 1e-9
    e = res.x[sel, :nm] - sim.x[k[sel], :nm]
    P = res.P[sel, :nm, :nm]
    return float(np.mean(np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0]))) / nm


def test_noisy_antenna_sigma_estimated_and_filter_consistent(testbed_cfg, noisy_antenna):
    sim, run, init = noisy_antenna
    truth = sim.truth["phase_sigma_m_per_channel"]
    assert truth[f"{NOISY}/PL1"] == pytest.approx(0.010) and truth["a1/PL1"] == pytest.approx(0.002)
    # INIT accepts a whole antenna's noise (it is shared by its channels) and says so
    assert any("shared by its antenna" in w for w in init["noise"]["warnings"])
    per = init["sigma_m_per_channel"]
    for key, s in per.items():
        assert s == pytest.approx(truth[key], rel=0.2), key
    res = estimate(run, init, EstimateOptions())
    assert res.noise["source"] == "INIT (estimated per channel)"
    assert res.noise["sigma_m_max"] > 4 * res.noise["sigma_m_min"]
    for p in res.noise["per_channel"]:
        if p["channel"].startswith(NOISY + "/"):
            assert p["residual_sigma_m"] == pytest.approx(truth[p["channel"]], rel=0.2), p
    nees = _nees_positions(testbed_cfg, sim, res, float(init["state"]["time_s"]))
    assert 0.7 <= nees <= 1.4, nees
    assert 0.7 <= res.noise["mean_nis_per_dof"] <= 1.4


def test_one_sigma_for_all_channels_is_flagged_and_adapted_per_channel(noisy_antenna):
    """Given one σ (INIT's RMS) for every channel, the residual pattern names the noisy antenna and
    the next passes (at most ADAPT_MAX_PASSES) take its channels' σ from the data."""
    sim, run, init = noisy_antenna
    truth = sim.truth["phase_sigma_m_per_channel"]
    one = {tuple(k.split("/")): float(init["sigma_m"]) for k in init["sigma_m_per_channel"]}
    res = estimate(run, init, EstimateOptions(channel_sigma_m=one))
    first = res.noise["first_pass"]
    assert first["adapt"] and first["worst_channel"]["channel"].split("/")[0] in (NOISY, "a1", "a2", "a4", "a5")
    rel = {p["channel"]: p["relative_variance"] for p in first["per_channel"]}
    assert min(v for k, v in rel.items() if k.startswith(NOISY + "/")) > 3.0 > max(
        v for k, v in rel.items() if not k.startswith(NOISY + "/"))
    assert res.noise["source"].startswith("innovation-adapted per channel") and not res.noise["adapt"]
    assert 0.8 <= res.noise["mean_nis_per_dof"] <= 1.25
    # 200 residuals per channel resolve a variance ratio to ±3.3·√(2/200) = ±47 % (the adaptation's
    # own significance rule): the noisy antenna is found, the others stay near their σ
    for p in res.noise["per_channel"]:
        noisy = p["channel"].startswith(NOISY + "/")
        assert p["sigma_m"] == pytest.approx(truth[p["channel"]], rel=0.2 if noisy else 0.5), p
        if noisy:
            assert p["residual_sigma_m"] == pytest.approx(truth[p["channel"]], rel=0.2), p


# --------------------------------------------------------------------------------------------
# independent check: a textbook covariance-form EKF with the same per-row R


def _textbook_ekf(cfg, sim, init, channels, sig):
    """x, P per epoch from INIT's state: predict x̄ = A x, P̄ = A P Aᵀ + Q; update with
    K = P̄Hᵀ(HP̄Hᵀ + R)⁻¹, x = x̄ + K(y − h(x̄) − b), P = (I − KH)P̄(I − KH)ᵀ + K R Kᵀ."""
    model = discrete_model(cfg)
    ant, tx = channel_indices(cfg, [c[0] for c in channels], [c[1] for c in channels])
    hmodel = EpochPhaseModel(cfg, ant, tx)
    R = np.diag(sig**2)
    bias = {(b["antenna"], b["transmitter"]): b["bias_m"] for b in init["biases"]}
    b = np.array([bias[c] for c in channels])
    rx = sim.receiver
    times = np.sort(rx["time_s"].unique())
    col = {c: i for i, c in enumerate(channels)}
    Y = np.full((len(times), len(channels)), np.nan)
    k = np.searchsorted(times, rx["time_s"].to_numpy())
    c = np.array([col[(a, t)] for a, t in zip(rx["antenna"], rx["transmitter"])])
    Y[k, c] = rx["phase_cycles"].to_numpy() * cfg.wavelength_m
    x = np.asarray(init["state"]["x"], float)
    P = np.asarray(init["state"]["P"], float)
    xs, Ps = [], []
    I = np.eye(len(x))
    for j in range(len(times)):
        if j:
            x = model.A @ x
            P = model.A @ P @ model.A.T + model.Q
        h, H = hmodel(x)
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        x = x + K @ (Y[j] - h - b)
        IKH = I - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        xs.append(x)
        Ps.append(P)
    return times, np.array(xs), np.array(Ps)


@pytest.mark.parametrize("compiled", [True, False])
def test_filter_equals_textbook_kf_with_per_row_r(testbed_cfg, compiled):
    if compiled and not ekf_kernel._ekfcore:
        pytest.skip("cdgps_cli.estimation._ekfcore is not compiled")
    cfg = testbed_cfg
    sim = simulate(cfg, SimOptions(duration_s=8.0, seed=2, phase_sigma_m=0.003))
    run = memory_run(cfg, sim.receiver)
    rng = np.random.default_rng(7)
    channels = list(cfg.channels)
    sig = rng.uniform(0.001, 0.008, len(channels))            # a different σ on every row
    n = cfg.n_states
    M = rng.standard_normal((n, n))
    init = {"config_sha256": cfg.sha256, "sigma_m": float(np.sqrt(np.mean(sig**2))),
            "sigma_m_per_channel": {f"{a}/{t}": float(s) for (a, t), s in zip(channels, sig)},
            "state": {"time_s": 0.0, "x": (sim.x[0] + 0.002).tolist(), "P": (1e-3 * (M @ M.T / n + np.eye(n))).tolist()},
            "biases": [{"antenna": b["antenna"], "transmitter": b["transmitter"], "bias_m": b["bias_m"]}
                       for b in sim.truth["biases"]]}
    with kernel(compiled):
        res = estimate(run, init, EstimateOptions(adapt_sigma=False))
    assert res.filter_path == ("c" if compiled else "numpy")
    assert res.noise["source"] == "INIT (per channel)" and not res.events
    assert res.channels == channels
    t, xs, Ps = _textbook_ekf(cfg, sim, init, channels, sig)
    np.testing.assert_allclose(res.time_s, t, atol=1e-9)
    np.testing.assert_allclose(res.x, xs, rtol=0, atol=1e-9 * max(1.0, np.abs(xs).max()))
    np.testing.assert_allclose(res.P, Ps, rtol=0, atol=1e-9 * np.abs(Ps).max())
    # and the same filter with one σ on every row differs (the per-row R is really used)
    with kernel(compiled):
        one = estimate(run, init, EstimateOptions(adapt_sigma=False, sigma_m=init["sigma_m"]))
    assert np.abs(one.P - Ps).max() > 1e-3 * np.abs(Ps).max()


# --------------------------------------------------------------------------------------------
# validation


def test_noise_scale_validated(testbed_cfg):
    assert parse_noise_scale("a3:5") == ("a3", 5.0)
    for bad in ("a3", "a3:0", "a3:-1", ":2", "a3:x"):
        with pytest.raises(CdgpsError, match="--noise-scale"):
            parse_noise_scale(bad)
    with pytest.raises(CdgpsError, match="'zz' is not a rover antenna or a transmitter"):
        simulate(testbed_cfg, SimOptions(duration_s=1.0, noise_scale={"zz": 2.0}))
    a = simulate(testbed_cfg, SimOptions(duration_s=2.0, seed=1))
    b = simulate(testbed_cfg, SimOptions(duration_s=2.0, seed=1, noise_scale={"PL2": 1.0}))
    assert a.receiver.equals(b.receiver)                          # factor 1: the same draws


def test_init_sigma_per_channel_validated(testbed_cfg, noisy_antenna):
    _, run, init = noisy_antenna
    for bad, match in (({"a9/PL1": 0.01}, "'a9/PL1' is not a channel"), ({"a1/PL1": -1.0}, r"sigma_m_per_channel\['a1/PL1'\]"),
                       ({"a1/PL1": True}, "expected a number"), ([0.01], "expected an object")):
        with pytest.raises(CdgpsError, match=match):
            estimate(run, dict(init, sigma_m_per_channel=bad), EstimateOptions())
    with pytest.raises(CdgpsError, match="cannot be combined"):
        estimate(run, init, EstimateOptions(sigma_m=0.01, channel_sigma_m={("a1", "PL1"): 0.01}))
