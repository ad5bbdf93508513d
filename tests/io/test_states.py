"""STATES.mcap (``cdgps estimate``), CSV export and evaluation against truth; the CLI contract.

* write_states → States round trip (smoothed and filtered topics, residuals, events, metadata);
* export_csv columns and alignment with truth.csv;
* ``evaluate`` against an independent hand computation on a tiny 1995-model case;
* CLI: ``cdgps estimate --smooth --json``, ``cdgps export``, ``cdgps evaluate --json``; bad inputs
  exit 2 with a clear message and leave no output; determinism (byte-identical STATES.mcap);
* bad INIT contents (unknown antenna, biases not a list, P not positive definite, sigma_m not a number)
  and bad ``--sigma-m`` values (0, negative, inf, nan).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
import math

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.estimation.filter import EstimateOptions, EstimateResult, estimate
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.coordinate_columns import coordinate_columns
from cdgps_cli.io.mcap import McapOut
from cdgps_cli.io.run import read_run, write_run
from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation
from cdgps_cli.io.states import coordinate_sigma, States
from cdgps_cli.pipeline.estimate_outputs import evaluate, export_csv, write_states

ROOT = Path(__file__).resolve().parents[2]
TESTBED_PATH = ROOT / "configs" / "testbed-1998-lumped.toml"
DOF2_PATH = ROOT / "configs" / "teague-1995-2dof.toml"


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def no_leftovers(directory, name):
    """No output file and no temporary sibling of it."""
    return not (directory / name).exists() and list(directory.glob(f".{name}*")) == []


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """30 s of the testbed (simulate → ingest → ``cdgps init`` on 0–20 s → ``cdgps estimate --smooth``)."""
    d = tmp_path_factory.mktemp("chain")
    cfg = load_config(TESTBED_PATH)
    write_simulation(simulate(cfg, SimOptions(duration_s=30.0, seed=21)), d / "sim")
    write_run(cfg, d / "sim" / "receiver.csv", d / "run.mcap")
    r = cli("--quiet", "init", d / "run.mcap", "--start", 0, "--duration", 20, "-o", d / "init.json")
    assert r.exit_code == 0, r.output
    r = cli("estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "--json", "-o", d / "states.mcap")
    assert r.exit_code == 0, r.output
    return {"dir": d, "cfg": cfg, "estimate_result": r}


# --------------------------------------------------------------------------------------------
# CLI happy path


def test_cli_estimate_smooth_json(chain):
    r = chain["estimate_result"]
    s = json.loads(r.stdout)
    assert s["output"] == str(chain["dir"] / "states.mcap")
    # every epoch of the run: the init window 0–20 s from the batch solution, the filter after it
    assert s["epochs"] == 301 and s["start_s"] == 0.0 and s["end_s"] == 30.0
    assert s["window"]["start_s"] == 0.0 and s["window"]["end_s"] == 20.0 and s["window"]["epochs"] == 201
    assert s["smoothed"] is True and s["events"] == 0 and s["event_list"] == []
    # simulated noise 1 cm, config sigma 2 cm: INIT estimates ≈ 1 cm from the data → NIS/dof ≈ 1
    assert 0.75 < s["mean_nis_per_dof"] < 1.3
    assert s["measurement_noise"]["sigma_m"] == pytest.approx(0.01, rel=0.15)
    assert "measurement σ" in r.stderr
    assert "wrote" in r.stderr and "mean NIS/dof" in r.stderr
    st = States(chain["dir"] / "states.mcap")
    assert st.metadata["smoothed"] == "true"
    assert json.loads(st.metadata["options"])["smooth"] is True


def test_cli_export_columns_line_up_with_truth(chain):
    d, cfg = chain["dir"], chain["cfg"]
    r = cli("export", d / "states.mcap", "--csv", d / "est.csv", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    names = coordinate_columns(cfg)                                # units in the names: q1_m, q2_rad …
    assert names[:2] == ["q1_m", "q2_rad"]
    expected = ["time_s", *names, *[f"sigma_{n}" for n in names]]
    assert s["columns"] == expected and s["rows"] == 301
    est = pd.read_csv(d / "est.csv")
    truth = pd.read_csv(d / "sim" / "truth.csv")
    assert list(est.columns) == expected
    assert list(truth.columns) == ["time_s", *names]
    merged = est.merge(truth, on="time_s", suffixes=("", "_truth"))
    assert len(merged) == len(est)                       # every estimate time is a truth.csv time
    np.testing.assert_array_equal(merged["time_s"], np.round(np.arange(0, 301) * 0.1, 9))
    assert (est[[f"sigma_{n}" for n in names]].to_numpy() > 0).all()
    # the estimate tracks the truth within a few sigma
    err = merged[names].to_numpy() - merged[[f"{n}_truth" for n in names]].to_numpy()
    assert np.mean(np.abs(err) <= 3 * est[[f"sigma_{n}" for n in names]].to_numpy()) > 0.97
    assert list(d.glob(".est.csv*")) == []


def test_cli_evaluate_json_and_text(chain):
    d = chain["dir"]
    r = cli("evaluate", "--truth", d / "sim", "--estimate", d / "states.mcap", "--json")
    assert r.exit_code == 0, r.output
    ev = json.loads(r.stdout)
    assert ev["epochs"] == 301 and ev["nees"]["dof"] == 9
    assert set(ev["rms_error"]) == set(chain["cfg"].coord_names)
    assert set(ev["rms_error_deg"]) == {"q2", "q3", "q5", "q6", "q8", "q9", "q10"}
    assert ev["bias_error"]["wrong_integers"] == 0 and ev["bias_error"]["channels"] == 36
    assert ev["events"] == 0 and "nis" in ev
    r = cli("evaluate", "--truth", d / "sim", "--estimate", d / "states.mcap")
    assert r.exit_code == 0 and "RMS error" in r.stdout and "NEES (dof 9)" in r.stdout


def test_cli_estimate_deterministic(chain, tmp_path):
    d = chain["dir"]
    for name in ("a.mcap", "b.mcap"):
        r = cli("--quiet", "estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "-o", tmp_path / name)
        assert r.exit_code == 0, r.output
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    assert (tmp_path / "a.mcap").read_bytes() == (d / "states.mcap").read_bytes()


# --------------------------------------------------------------------------------------------
# library round trip


def test_write_states_round_trip(chain, tmp_path):
    d, cfg = chain["dir"], chain["cfg"]
    init_text = (d / "init.json").read_text()
    init = json.loads(init_text)
    res = estimate(read_run(d / "run.mcap"), init, EstimateOptions(smooth=True))
    res.events.append({"time_s": 25.0, "antenna": "a2", "transmitter": "PL3", "kind": "lock restart",
                       "action": "bias dropped; re-estimating over 10 epochs"})
    s = write_states(res, d / "run.mcap", init, init_text, tmp_path / "st.mcap", {"biases": "fixed"})
    assert s["epochs"] == len(res.time_s) and s["smoothed"] is True and s["events"] == 1
    write_states(res, d / "run.mcap", init, init_text, tmp_path / "full.mcap", {"biases": "fixed"}, covariance="full")
    U = np.asarray(cfg.mode_shapes)
    nm = cfg.n_modes
    for name, topic, X, P in (("st", "/cdgps/state", res.x, res.P), ("full", "/cdgps/state", res.x, res.P),
                              ("st", "/cdgps/state_filtered", res.x_filt, res.P_filt),
                              ("full", "/cdgps/state_filtered", res.x_filt, res.P_filt)):
        st = States(tmp_path / f"{name}.mcap", topic=topic)
        np.testing.assert_array_equal(st.time_s, res.time_s)
        np.testing.assert_allclose(st.q, X[:, :nm] @ U.T, rtol=1e-15, atol=1e-15)
        np.testing.assert_array_equal(st.xi, X[:, :nm])
        if name == "full":                                           # ξ̇ of every epoch: on request
            np.testing.assert_array_equal(st.xidot, X[:, nm:2 * nm])
        else:
            assert st.xidot is None
        if name == "st" and topic == "/cdgps/state_filtered":      # the forward filter: its 1-σ only
            assert st.P_xi is None
        else:
            np.testing.assert_array_equal(st.P_xi, P[:, :nm, :nm])
        sig = np.sqrt(np.einsum("qi,nij,qj->nq", U, P[:, :nm, :nm], U))
        np.testing.assert_allclose(st.sigma_q, sig, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(st.nis, res.nis, rtol=1e-15)
        np.testing.assert_array_equal(st.nis_dof, res.nis_dof)
        assert st.events == res.events
        if name == "full":                                           # the whole state covariance
            np.testing.assert_array_equal(st.P, P)
        else:
            assert st.P is None
    assert not np.allclose(States(tmp_path / "st.mcap").q, States(tmp_path / "st.mcap", "/cdgps/state_filtered").q)
    md = st.metadata
    assert md["config_sha256"] == cfg.sha256 and md["smoothed"] == "true"
    assert json.loads(md["options"]) == {"biases": "fixed"}
    fb = {(b["antenna"], b["transmitter"]): b["bias_m"] for b in json.loads(md["final_biases"])}
    assert fb == res.biases
    import hashlib
    assert md["init_sha256"] == hashlib.sha256(init_text.encode()).hexdigest()
    assert md["run_sha256"] == hashlib.sha256((d / "run.mcap").read_bytes()).hexdigest()
    with pytest.raises(CdgpsError, match="this is a RUN.mcap .from .cdgps ingest.., not a STATES.mcap"):
        States(d / "run.mcap")
    # export_csv writes the smoothed topic's q and sigma_q
    out = export_csv(tmp_path / "st.mcap", tmp_path / "st.csv")
    df = pd.read_csv(tmp_path / "st.csv")
    assert out["rows"] == len(res.time_s) and list(df.columns) == out["columns"]
    st = States(tmp_path / "st.mcap")
    cols = coordinate_columns(cfg)
    np.testing.assert_allclose(df[cols].to_numpy(), st.q, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(df[[f"sigma_{n}" for n in cols]].to_numpy(), st.sigma_q, rtol=1e-14)


# --------------------------------------------------------------------------------------------
# evaluate on a hand-made case


def test_evaluate_against_hand_computation(tmp_path):
    """1995 model (2 modes, 2 coordinates, T = 0.12 s), 20 epochs of hand-made estimates whose first
    three are 10σ off; every figure recomputed here with closed forms (chi-square with 2 dof:
    F⁻¹(p) = −2 ln(1 − p))."""
    cfg = load_config(DOF2_PATH)
    U = np.asarray(cfg.mode_shapes)
    rng = np.random.default_rng(4)
    N, T = 20, cfg.sample_period_s
    t = np.round(np.arange(N) * T, 9)
    xi_t = rng.normal(0, 0.3, (N, 2))
    P = np.empty((N, 4, 4))
    L = np.array([[0.02, 0.0], [0.01, 0.015]])
    for k in range(N):
        P[k] = np.eye(4) * 1e-4
        P[k, :2, :2] = L @ L.T
    d = rng.standard_normal((N, 2)) @ L.T                          # 1σ errors with covariance LLᵀ
    d[:3] *= 10.0
    x = np.zeros((N, 4))
    x[:, :2] = xi_t + d
    nis = rng.chisquare(2, N)
    nis_dof = np.full(N, 2)
    nis[7], nis_dof[7] = np.nan, 0
    chans = [("s2", "S1"), ("s3", "S2")]
    lam = cfg.wavelength_m
    truth_b = {("s2", "S1"): 2 * lam, ("s3", "S2"): -3 * lam}
    after_slip = -1 * lam
    res = EstimateResult(cfg, t, x, P, None, None, chans, np.full((N, 2), 0.001), nis, nis_dof,
                         events=[{"time_s": 0.24, "antenna": "s3", "transmitter": "S2", "kind": "lock restart",
                                  "action": "bias dropped"}],
                         biases={("s2", "S1"): 2 * lam + 0.003, ("s3", "S2"): after_slip + lam})
    with McapOut(tmp_path / "run.mcap") as out:               # stand-in RUN: only its ingest record
        out.metadata("cdgps.ingest", {"kind": "structure"})
    write_states(res, tmp_path / "run.mcap", {}, "{}", tmp_path / "st.mcap", {})
    truth_dir = tmp_path / "truth"
    truth_dir.mkdir()
    tt = np.round(np.arange(-2, N + 3) * T, 9)                   # truth covers more epochs
    qt_all = np.vstack([rng.normal(0, 1, (2, 2)), xi_t @ U.T, rng.normal(0, 1, (3, 2))])
    pd.DataFrame({"time_s": tt, "q1": qt_all[:, 0], "q2": qt_all[:, 1]}).to_csv(truth_dir / "truth.csv", index=False)
    (truth_dir / "truth.json").write_text(json.dumps({
        "config_sha256": cfg.sha256,
        "biases": [{"antenna": a, "transmitter": tr, "bias_m": b} for (a, tr), b in truth_b.items()],
        "slips": [{"time_s": 0.24, "antenna": "s3", "transmitter": "S2", "bias_m": after_slip},
                  {"time_s": 99.0, "antenna": "s2", "transmitter": "S1", "bias_m": 7.0}]}))   # after the end
    ev = evaluate(truth_dir, tmp_path / "st.mcap", converge_s=0.3)

    qt = xi_t @ U.T
    qe = x[:, :2] @ U.T
    err = qe - qt
    after = t >= 0.36 - 1e-9                                        # t0 + converge_s, on the grid
    assert ev["epochs"] == N and ev["start_s"] == 0.0 and ev["end_s"] == t[-1]
    rms = np.sqrt((err[after] ** 2).mean(axis=0))
    assert ev["rms_error"] == pytest.approx({"q1": rms[0], "q2": rms[1]}, rel=1e-9)
    assert ev["rms_error_deg"] == pytest.approx({"q1": math.degrees(rms[0]), "q2": math.degrees(rms[1])}, rel=1e-9)
    assert ev["rms_error_units"] == {"q1": "rad", "q2": "rad"}
    nees = np.array([dk @ np.linalg.inv(L @ L.T) @ dk for dk in d])
    lo, hi = -2 * math.log(0.975), -2 * math.log(0.025)
    assert ev["nees"]["dof"] == 2
    assert ev["nees"]["mean"] == pytest.approx(nees[after].mean(), rel=1e-9)
    assert ev["nees"]["interval95_single"] == pytest.approx([lo, hi], rel=1e-9)
    assert ev["nees"]["fraction_in_interval"] == pytest.approx(np.mean((nees[after] >= lo) & (nees[after] <= hi)))
    sig = np.sqrt(np.einsum("qi,ij,qj->q", U, L @ L.T, U))
    assert ev["within_3sigma_fraction"] == pytest.approx(np.mean(np.all(np.abs(err[after]) <= 3 * sig, axis=1)))
    # convergence: first epoch from which NEES < 99.9% bound (−2 ln 0.001) for 1 s = 8 epochs
    ok = nees <= -2 * math.log(0.001)
    first = next(k for k in range(N - 7) if ok[k:k + 8].all())
    assert first >= 3
    assert ev["convergence_s"] == pytest.approx(t[first])
    good = nis_dof > 0
    assert ev["nis"]["mean_per_dof"] == pytest.approx(np.mean(nis[good] / 2))
    assert ev["nis"]["fraction_in_interval95"] == pytest.approx(np.mean((nis[good] >= lo) & (nis[good] <= hi)))
    e_b = np.array([0.003, lam])
    assert ev["bias_error"] == pytest.approx({"rms_m": np.sqrt(np.mean(e_b**2)), "max_abs_m": lam,
                                             "wrong_integers": 1, "channels": 2})
    assert ev["events"] == 1


def test_evaluate_errors(chain, tmp_path):
    d = chain["dir"]
    with pytest.raises(CdgpsError, match="cannot read truth.csv"):
        evaluate(tmp_path, d / "states.mcap")
    other = tmp_path / "other"
    other.mkdir()
    pd.read_csv(d / "sim" / "truth.csv").to_csv(other / "truth.csv", index=False)
    (other / "truth.json").write_text(json.dumps({"config_sha256": "0" * 64}))
    with pytest.raises(CdgpsError, match="simulated with config .*, but .* estimates config"):
        evaluate(other, d / "states.mcap")
    pd.read_csv(d / "sim" / "truth.csv").drop(columns=["q4_m"]).to_csv(other / "truth.csv", index=False)
    (other / "truth.json").write_text("{}")                # (another config is said first, see above)
    with pytest.raises(CdgpsError, match=r"missing column\(s\) q4_m"):
        evaluate(other, d / "states.mcap")


def test_evaluate_reads_truth_with_and_without_units_in_the_names(chain, tmp_path):
    """Issue 32: truth.csv columns carry units (q1_rad); a truth written before (bare q1) gives the
    same evaluation, and a file with both prefers the suffixed columns."""
    d = chain["dir"]
    new = pd.read_csv(d / "sim" / "truth.csv")
    assert list(new.columns[1:3]) == ["q1_m", "q2_rad"]
    ref = evaluate(d / "sim", d / "states.mcap")
    def bare(c):
        return re.sub(r"_(m|rad)$", "", c)
    for name, table in (("bare", new.rename(columns=bare)),
                        ("both", pd.concat([new, new.iloc[:, 1:].rename(columns=bare) + 1.0], axis=1))):
        (tmp_path / name).mkdir()
        table.to_csv(tmp_path / name / "truth.csv", index=False)
        (tmp_path / name / "truth.json").write_bytes((d / "sim" / "truth.json").read_bytes())
        assert evaluate(tmp_path / name, d / "states.mcap") == ref, name


# --------------------------------------------------------------------------------------------
# CLI bad inputs: exit 2, a clear message, no output left


def _init_variants(chain, tmp_path):
    d = chain["dir"]
    init = json.loads((d / "init.json").read_text())
    files = {}
    files["not json"] = "{ this is not json"
    files["json array"] = "[1, 2, 3]"
    files["wrong config"] = json.dumps(dict(init, config_sha256="f" * 64))
    files["missing state"] = json.dumps({k: v for k, v in init.items() if k != "state"})
    files["short x"] = json.dumps(dict(init, state=dict(init["state"], x=[0.0, 1.0])))
    out = {}
    for k, text in files.items():
        p = tmp_path / (k.replace(" ", "_") + ".json")
        p.write_text(text)
        out[k] = p
    return out


BAD_ESTIMATE = {
    # case: (argument edit, expected message fragment)
    "init missing": ("init:nope", "cannot read"),
    "init not json": ("init:not json", "not valid JSON"),
    "init json array": ("init:json array", "expected a JSON object"),
    "init wrong config": ("init:wrong config", "different structure config"),
    "init missing state": ("init:missing state", "missing key 'state'"),
    "init short x": ("init:short x", "expected x of 18 numbers"),
    "run missing": ("run:nope", "no such file"),
    "run not mcap": ("run:text", "not a valid MCAP"),
    "nis probability 2": ("opt:--nis-probability=2", "--nis-probability must be in (0.5, 1)"),
    "outlier sigma 0": ("opt:--outlier-sigma=0", "--outlier-sigma 0: outside the plausible range"),
    "rest not an interval": ("opt:--rest=abc", "--rest 'abc': expected START:END"),
    "rest end before start": ("opt:--rest=90:80", "END must be after START"),
    "rest nan": ("opt:--rest=nan:90", "START must be a finite time"),
    "rest scale negative": ("opt:--rest-process-noise-scale=-1", "--rest-process-noise-scale -1: outside the plausible range"),
    "rest retry nan": ("opt:--rest-retry-s=nan", "Invalid value for '--rest-retry-s': 'nan' is not a finite number"),
}


@pytest.mark.parametrize("case", sorted(BAD_ESTIMATE))
def test_cli_estimate_bad_input(case, chain, tmp_path):
    d = chain["dir"]
    edit, fragment = BAD_ESTIMATE[case]
    run, init, opts = d / "run.mcap", d / "init.json", []
    kind, what = edit.split(":", 1)
    if kind == "init":
        init = tmp_path / "nope.json" if what == "nope" else _init_variants(chain, tmp_path)[what]
    elif kind == "run":
        run = tmp_path / "nope.mcap"
        if what == "text":
            run.write_text("time_s,receiver\n")
    else:
        opts = what.split("=")
    r = cli("estimate", run, "--init", init, *opts, "-o", tmp_path / "states.mcap")
    assert r.exit_code == 2, r.output
    assert isinstance(r.exception, SystemExit) and "Traceback" not in r.output
    # a library refusal ('cdgps: error: …') or Click's refusal of an option value naming the option
    assert ("cdgps: error:" in r.output or "Error: Invalid value for '--" in r.output) and fragment in r.output, r.output
    assert no_leftovers(tmp_path, "states.mcap")


def test_cli_estimate_bad_choice(chain, tmp_path):
    d = chain["dir"]
    r = cli("estimate", d / "run.mcap", "--init", d / "init.json", "--biases", "floating", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 2 and "floating" in r.output
    assert no_leftovers(tmp_path, "s.mcap")


def test_cli_export_and_evaluate_bad_input(chain, tmp_path):
    d = chain["dir"]
    r = cli("export", tmp_path / "nope.mcap", "--csv", tmp_path / "o.csv")
    assert r.exit_code == 2 and "no such file" in r.output and no_leftovers(tmp_path, "o.csv")
    r = cli("export", d / "run.mcap", "--csv", tmp_path / "o.csv")
    assert r.exit_code == 2 and "this file is a structure RUN.mcap" in r.output and no_leftovers(tmp_path, "o.csv")
    r = cli("evaluate", "--truth", tmp_path, "--estimate", d / "states.mcap")
    assert r.exit_code == 2 and "cannot read truth.csv" in r.output
    r = cli("evaluate", "--truth", d / "sim", "--estimate", tmp_path / "nope.mcap")
    assert r.exit_code == 2 and "no such file" in r.output


BAD_INIT_CONTENT = {
    "bias of an antenna not in the config": lambda i: i["biases"][0].update(antenna="zz"),
    "biases not a list": lambda i: i.update(biases={"a1": 0.1}),
    "covariance not positive definite": lambda i: i["state"]["P"][0].__setitem__(0, -1.0),
    "sigma_m not a number": lambda i: i.update(sigma_m="2 cm"),
    "config_sha256 null": lambda i: i.update(config_sha256=None),        # found by tests/fuzz (TypeError)
    "window start_s null": lambda i: i["window"].update(start_s=None),   # tests/fuzz: message lacked the file
}


@pytest.mark.parametrize("case", sorted(BAD_INIT_CONTENT))
def test_cli_estimate_bad_init_content(case, chain, tmp_path):
    """Regression: these INIT contents ended in an uncaught exception (exit 1, traceback)."""
    d = chain["dir"]
    init = json.loads((d / "init.json").read_text())
    BAD_INIT_CONTENT[case](init)
    p = tmp_path / "init.json"
    p.write_text(json.dumps(init))
    r = cli("estimate", d / "run.mcap", "--init", p, "-o", tmp_path / "states.mcap")
    assert no_leftovers(tmp_path, "states.mcap")
    assert r.exit_code == 2 and f"cdgps: error: {p}" in r.output, (r.exit_code, r.exception)   # names the INIT file
    assert "Traceback" not in r.output


@pytest.mark.parametrize("value", ["0", "-0.02", "inf", "nan"])
def test_cli_estimate_bad_sigma_m(value, chain, tmp_path):
    """Regression: 0 silently meant INIT's sigma, negatives were used squared, inf ignored every
    measurement, nan ended in a traceback from the JSON writer."""
    d = chain["dir"]
    r = cli("estimate", d / "run.mcap", "--init", d / "init.json", f"--sigma-m={value}", "-o", tmp_path / "states.mcap")
    assert r.exit_code == 2 and "--sigma-m" in r.output, (r.exit_code, r.exception)
    assert no_leftovers(tmp_path, "states.mcap")


# --------------------------------------------------------------------------------------------
# memory-lean writing and reading (issue 4): streamed .npy attachments, flat column buffers


def _npy(arr):
    import io

    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


ATTACH_ARRAYS = {
    "1-d": lambda r: r.normal(size=1001),
    "c-contiguous 2-d": lambda r: r.normal(size=(257, 10)),
    "(N, n, n) modal block of a larger covariance": lambda r: r.normal(size=(301, 18, 18))[:, :9, :9],
    "column slice": lambda r: r.normal(size=(300, 18))[:, :9],
    "fortran order": lambda r: np.asfortranarray(r.normal(size=(40, 7))),
    "0-d": lambda r: np.array(2.5),
    "empty rows": lambda r: np.zeros((0, 3)),
    "empty columns": lambda r: np.zeros((5, 0)),
    "int64": lambda r: r.integers(0, 9, size=(33, 3)),
}


@pytest.mark.parametrize("streaming", [True, False])
def test_attach_npy_byte_identical_to_np_save(streaming, tmp_path, monkeypatch):
    """McapOut.attach_npy (streamed in small pieces) writes exactly the file that attach() with the
    np.save bytes writes: same records, CRCs, attachment index and statistics; with the mcap
    writer's internals missing it falls back to attach()."""
    from cdgps_cli.io import mcap as mcap_io
    from cdgps_cli.io.mcap import McapOut, read_mcap

    if not streaming:
        monkeypatch.setattr(mcap_io, "_streaming_supported", lambda w, fh: False)
    rng = np.random.default_rng(3)
    arrays = {k: f(rng) for k, f in ATTACH_ARRAYS.items()}
    schema = {"title": "t", "type": "object", "properties": {}}

    def write(path, streamed):
        with McapOut(path) as out:
            ch = out.channel("/x", schema)
            for i, (k, a) in enumerate(arrays.items()):
                out.write(ch, 0.1 * i, {"v": [float(i)]})    # messages before, between and after
                if streamed:
                    out.attach_npy(f"arrays/{k}.npy", a, chunk_bytes=100)
                else:
                    out.attach(f"arrays/{k}.npy", _npy(a), "application/x-npy")
            out.write(ch, 10.0, {"v": [1.0]})
            out.attach("config.toml", b"x = 1\n", "application/toml")
            out.metadata("m", {"k": "v"})

    write(tmp_path / "a.mcap", True)
    write(tmp_path / "b.mcap", False)
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    c = read_mcap(tmp_path / "a.mcap")                       # CRCs (attachments, data section) validated
    for k, a in arrays.items():
        np.testing.assert_array_equal(np.load(__import__("io").BytesIO(c.attachments[f"arrays/{k}.npy"])), a)
    assert len(c.topics["/x"]) == len(arrays) + 1


def test_attach_stream_size_mismatch_leaves_no_output(tmp_path):
    from cdgps_cli.io.mcap import McapOut

    with pytest.raises(ValueError, match="expected 10 bytes, got 3"):
        with McapOut(tmp_path / "o.mcap") as out:
            out.attach_stream("a.bin", 10, [b"abc"])
    assert no_leftovers(tmp_path, "o.mcap")


def test_topic_columns_flat_buffers():
    """Array fields: floats (None → NaN, ints and booleans as floats) and strings (vocabulary codes),
    empty arrays, keys missing from some messages; inconsistent fields are errors."""
    from cdgps_cli.io.mcap import TopicColumns

    tc = TopicColumns()
    tc.add({"timestamp": {}, "time_s": 0.0, "m": "A", "ant": ["a1", "a2"], "v": [1.5, None], "lock": [3, 4]})
    tc.add({"time_s": 0.1, "ant": [], "v": [], "lock": []})
    tc.add({"time_s": 0.2, "m": "B", "ant": ["a2"], "v": [True], "lock": [5], "extra": 7})
    assert len(tc) == 3 and tc.counts == [2, 0, 1]
    np.testing.assert_array_equal(tc.times(), [0.0, 0.1, 0.2])
    assert tc.scalars["m"] == ["A", None, "B"] and tc.scalars["extra"] == [None, None, 7]
    np.testing.assert_array_equal(tc.column("v"), [1.5, np.nan, 1.0])
    assert tc.column("lock").dtype == float and tc.column("lock").tolist() == [3.0, 4.0, 5.0]
    assert tc.column("ant").tolist() == ["a1", "a2", "a2"] and tc.column("ant").dtype == object
    assert tc.column("nothing").size == 0
    df = tc.table(["ant", "v"], ["m"])
    assert list(df.columns) == ["time_s", "m", "ant", "v"] and len(df) == 3
    assert df["ant"].tolist() == ["a1", "a2", "a2"] and df["m"].tolist() == ["A", "A", "B"]
    tc.add({"time_s": 0.3, "v": [2.0]})                     # still growing after column()
    assert tc.column("v").tolist()[-1] == 2.0
    for bad in ({"v": ["x"]}, {"ant": [1.0]}, {"v": [[1.0, 2.0]]}):
        with pytest.raises(ValueError):
            tc.add(bad)
    np.testing.assert_array_equal(tc.column("v"), [1.5, np.nan, 1.0, 2.0])   # failed adds left no trace


def test_write_states_makes_no_full_size_copies(tmp_path, monkeypatch):
    """The per-epoch messages and the packed attachments are written without full-size temporaries:
    the writer reads the record in chunks (issue 29), so the peak traced memory of write_states on a
    record of 8 chunks of 1024 epochs stays below two (N, n_m, n_m) covariance series of the record
    (the mcap library's chunk buffers are ~3 MB of it; the writer before the packed arrays, which
    built every .npy and its attachment record in memory, peaked at ≈ 3.5)."""
    import tracemalloc

    from cdgps_cli.io import states as states_io
    from cdgps_cli.io.mcap import McapOut

    monkeypatch.setattr(states_io, "STATES_CHUNK_EPOCHS", 1024)
    cfg = load_config(TESTBED_PATH)
    n, nm, N = cfg.n_states, cfg.n_modes, 8192
    rng = np.random.default_rng(0)
    t = np.round(np.arange(N) * 0.1, 9)
    x = rng.normal(size=(N, n))
    P = np.broadcast_to(np.eye(n) * 1e-4, (N, n, n)).copy()
    P_filt = P[:, :nm, :nm].copy()
    chans = [("a1", "PL1"), ("a2", "PL2")]
    res = EstimateResult(cfg, t, x, P, x.copy(), P_filt, chans, rng.normal(size=(N, 2)) * 1e-3,
                         np.ones(N), np.full(N, 2), smoothed=True, biases={c: 0.0 for c in chans})
    with McapOut(tmp_path / "run.mcap") as out:               # stand-in RUN: only its ingest record
        out.metadata("cdgps.ingest", {"kind": "structure"})

    def peak_of_write(name: str) -> int:
        tracemalloc.start()
        try:
            write_states(res, tmp_path / "run.mcap", {}, "{}", tmp_path / name, {})
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    block = N * nm * nm * 8                                   # 2.6 MB
    background = peak_of_write("st.mcap")
    with monkeypatch.context() as m:
        m.setattr(McapOut, "pack_in_background", lambda self: None)
        in_line = peak_of_write("in_line.mcap")
    assert in_line < 2 * block, f"write_states peaked at {in_line / 2**20:.1f} MiB (P_xi series {block / 2**20:.1f} MiB)"
    assert background < in_line + block, f"{background / 2**20:.1f} MiB packing in the background"
    st_line = States(tmp_path / "in_line.mcap")
    np.testing.assert_array_equal(st_line.P_xi, P[:, :nm, :nm])
    st = States(tmp_path / "st.mcap")
    np.testing.assert_array_equal(st.P_xi, P[:, :nm, :nm])
    filt = States(tmp_path / "st.mcap", "/cdgps/state_filtered")     # the forward filter: its 1-σ only
    assert filt.P_xi is None
    np.testing.assert_allclose(filt.sigma_q, coordinate_sigma(cfg.mode_shapes, P_filt), rtol=0, atol=0)
    np.testing.assert_array_equal(st.xi, x[:, :nm])


