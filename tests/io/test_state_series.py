"""One STATES writer and reader for any state series (core/records.StateSeries, io/states.py).

* a displacement series (C = I, no rates, NaN where a rover has no solution, an arrays-only series
  with extra arrays) and a structure-like series (a non-identity output map, rates): written by
  ``write_states``, read back by ``States`` with the same numbers; q = C ξ and σ_q against a
  brute-force C P Cᵀ per epoch;
* no structure config is faked: a displacement STATES has ``states.json`` and no ``config.toml``,
  and the commands that need a structure say so;
* what each file holds by default and with ``--covariance full``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.records import Series, StateSeries
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.states import STATE_FILTERED_TOPIC, STATE_TOPIC, States, write_states

KIN = "/cdgps/kinematic"


def _spd(rng, n: int, m: int) -> np.ndarray:
    A = rng.normal(size=(n, m, m))
    return np.einsum("nij,nkj->nik", A, A) + 0.1 * np.eye(m)


def _series(kind: str, seed: int = 0, N: int = 50):
    rng = np.random.default_rng(seed)
    t = 1.0e9 + np.arange(N) * 1.0 if kind == "displacement" else np.arange(N) * 0.1
    if kind == "displacement":
        names, npos, nrate, C = ["r1_e", "r1_n", "r1_u", "r2_e", "r2_n", "r2_u"], 6, 0, np.eye(6)
    else:
        names, npos, nrate = ["q1", "q2", "q3"], 2, 2
        C = rng.normal(size=(3, 2))
    n = npos + nrate + 1                                      # a bias state after the rates
    x = rng.normal(size=(N, n))
    P = _spd(rng, N, n)
    if kind == "displacement":
        x[5:8, 3:6] = np.nan                                   # rover 2 without a solution
        P[5:8, 3:6, :] = 0.0
        P[5:8, :, 3:6] = 0.0
    series = {STATE_TOPIC: Series(t, x, P, True), STATE_FILTERED_TOPIC: Series(t, x + 1.0, P * 2.0, False)}
    if kind == "displacement":
        have = np.arange(N) % 3 != 0
        series[KIN] = Series(t[have], x[have], P[have], False,
                             {"n_sat": np.full((have.sum(), 2), 7), "pdop": rng.uniform(1, 3, (have.sum(), 2))},
                             messages=False)
    chans = [("r1", "G01"), ("r1", "G02"), ("r2", "G05")]
    res = rng.normal(scale=0.003, size=(N, 3))
    res[::4, 1] = np.nan
    nis = np.where(np.arange(N) > 2, rng.chisquare(2, N), np.nan)
    ss = StateSeries(kind, names, ["m"] * len(names), C, nrate, series, chans, res, nis,
                     np.where(np.isnan(nis), 0, 2), [{"time_s": float(t[3]), "antenna": "r1", "transmitter": "G01",
                                                      "kind": "slip", "action": "new ambiguity"}], 0.19)
    return ss


def _write(ss, path, **kw):
    return write_states(ss, path, {"created_by": "test", "kind": "gnss" if ss.kind == "displacement" else "x"},
                        {"init.json": (b"{}", "application/json")},
                        time_scale="gps" if ss.kind == "displacement" else "relative", **kw)


@pytest.mark.parametrize("kind", ["displacement", "structure"])
def test_round_trip_of_any_kind(kind, tmp_path):
    ss = _series(kind)
    s = _write(ss, tmp_path / "s.mcap")
    assert s["epochs"] == 50 and s["events"] == 1 and s["smoothed"] is True
    st = States(tmp_path / "s.mcap")
    est = ss.series[STATE_TOPIC]
    assert st.kind == kind and st.coord_names == ss.coord_names and st.n_pos == ss.n_pos
    assert (st.cfg is None) and st.wavelength_m == 0.19
    np.testing.assert_array_equal(st.output_map, ss.output_map)
    np.testing.assert_array_equal(st.time_s, est.time_s)
    np.testing.assert_array_equal(st.xi, est.x[:, :ss.n_pos])
    np.testing.assert_array_equal(st.P_xi, est.P[:, :ss.n_pos, :ss.n_pos])
    assert st.xidot is None                   # ξ̇ of every epoch only with covariance="full" (no reader needs it)
    if ss.n_rate:
        _write(ss, tmp_path / "full.mcap", covariance="full")
        np.testing.assert_array_equal(States(tmp_path / "full.mcap").xidot, est.x[:, ss.n_pos:2 * ss.n_pos])
    # q = C ξ and σ_q = sqrt(diag(C P_ξ Cᵀ)), epoch by epoch (brute force)
    for k in range(50):
        xk, Pk = est.x[k, :ss.n_pos], est.P[k, :ss.n_pos, :ss.n_pos]
        if kind == "displacement":
            np.testing.assert_array_equal(st.q[k], xk)            # NaN stays in its own coordinate
            np.testing.assert_array_equal(st.sigma_q[k], np.sqrt(np.diag(Pk)))
        else:
            np.testing.assert_allclose(st.q[k], ss.output_map @ xk, rtol=1e-13)
            np.testing.assert_allclose(st.sigma_q[k], np.sqrt(np.diag(ss.output_map @ Pk @ ss.output_map.T)),
                                       rtol=1e-12)
    np.testing.assert_array_equal(st.nis, ss.nis)
    np.testing.assert_array_equal(st.nis_dof, ss.nis_dof)
    assert st.events == ss.events
    filt = States(tmp_path / "s.mcap", topic=STATE_FILTERED_TOPIC)
    np.testing.assert_array_equal(filt.xi, ss.series[STATE_FILTERED_TOPIC].x[:, :ss.n_pos])
    assert filt.P_xi is None                                  # by default: its 1-σ only
    np.testing.assert_allclose(filt.sigma_q[10], np.sqrt(np.diag(
        ss.output_map @ (2 * est.P[10, :ss.n_pos, :ss.n_pos]) @ ss.output_map.T)), rtol=1e-12)


def test_displacement_series_has_no_structure_config(tmp_path):
    ss = _series("displacement")
    _write(ss, tmp_path / "s.mcap")
    c = read_mcap(tmp_path / "s.mcap")
    assert "config.toml" not in c.attachments
    d = json.loads(c.attachments["states.json"])
    assert d["kind"] == "displacement" and d["n_rate"] == 0 and d["series"][KIN] == {
        "smoothed": False, "extra": ["n_sat", "pdop"], "messages": False}
    assert KIN not in c.topics and STATE_TOPIC in c.topics      # arrays only for the single-epoch series
    kin = States(tmp_path / "s.mcap", topic=KIN)
    assert kin.nis is None and kin.time_s.size == ss.series[KIN].time_s.size
    np.testing.assert_array_equal(kin.extra["pdop"], ss.series[KIN].extra["pdop"])
    np.testing.assert_array_equal(kin.extra["n_sat"], ss.series[KIN].extra["n_sat"])
    st = States(tmp_path / "s.mcap")
    with pytest.raises(CdgpsError, match=r"--points needs the STATES.mcap of a structure .*displacement states"):
        st.require_structure("--points")
    # the Foxglove messages: q without the missing coordinates, xi with its validity companion
    m = c.topics[STATE_TOPIC]
    k = int(np.flatnonzero(m.times() == ss.series[STATE_TOPIC].time_s[6])[0])       # (a preview epoch at the default rate)
    assert set(m.scalars["q"][k]) == {"r1_e", "r1_n", "r1_u"}


def test_covariance_full_keeps_every_series_whole(tmp_path):
    ss = _series("structure")
    _write(ss, tmp_path / "full.mcap", covariance="full")
    for topic in (STATE_TOPIC, STATE_FILTERED_TOPIC):
        st = States(tmp_path / "full.mcap", topic=topic)
        np.testing.assert_array_equal(st.P, ss.series[topic].P)
        np.testing.assert_array_equal(st.P_xi, ss.series[topic].P[:, :2, :2])


def test_byte_identical_rewrites(tmp_path):
    for name in ("a", "b"):
        _write(_series("displacement"), tmp_path / f"{name}.mcap")
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
