"""Figures of merit on closed-form signals, and `cdgps report control` end to end."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.control.metrics import (ROTATION_LIMIT_DEG, TRANSLATION_LIMIT_MM, coordinate_checks, first_peak_deg,
                                      pulse_metrics, settle_time_s, slew_metrics)


def test_first_peak_of_a_damped_sine():
    t = np.linspace(0, 20, 20001)
    a = 10 * np.exp(-t / 5) * np.sin(2 * np.pi * 0.25 * t)          # first lobe peaks near t = 0.86 s
    tp = math.atan(2 * np.pi * 0.25 * 5) / (2 * np.pi * 0.25)
    assert first_peak_deg(t, a, 0.0) == pytest.approx(10 * math.exp(-tp / 5) * math.sin(2 * np.pi * 0.25 * tp), rel=1e-6)


def test_settle_time_of_an_exponential():
    t = np.linspace(0, 30, 30001)
    assert settle_time_s(t, 5 * np.exp(-t / 4), 0.5, 0.0) == pytest.approx(4 * math.log(10), abs=2e-3)
    assert settle_time_s(t, np.ones_like(t), 0.5, 0.0) is None


def test_pulse_and_slew_metrics_on_synthetic_runs():
    t = np.linspace(0, 30, 3001)
    after = np.clip(t - 5, 0, None)
    open_ = {"q5": 10 * np.sin(2 * np.pi * 0.2 * after)}
    closed = {"q5": 3 * np.exp(-after) * np.sin(2 * np.pi * 0.2 * after)}
    m = pulse_metrics(t, open_, closed, 5.0, 6.0)["q5"]
    assert m["open_first_peak_deg"] == pytest.approx(10, rel=1e-3)
    assert m["peak_ratio"] == pytest.approx(np.abs(closed["q5"]).max() / 10, rel=1e-3)
    assert m["open_tail_peak_to_peak_deg"] == pytest.approx(20, rel=1e-3)
    rigid = np.where(t < 5, 14.0, -22 + 36 * np.exp(-(t - 5) / 3))
    s = slew_metrics(t, rigid, {"q2": 0.5 * np.sin(t)}, -22.0, 5.0)
    assert s["arrived_s_after_command"] == pytest.approx(3 * math.log(36 / 0.5), abs=0.02)
    assert s["internal_max_deg"]["q2"] == pytest.approx(0.5, rel=1e-3)


def test_coordinate_checks_limit_every_kind():
    """Rotations in degrees against 1°, translations in mm against what 1° gives at 1 m, a kind without
    a limit reported unchecked; only samples from ``after_s`` count."""
    t = np.linspace(0, 10, 101)
    v = {"q3": np.where(t < 5, 0.5, np.radians(1.2)), "q2": np.full_like(t, np.radians(0.9)),
         "q1": np.where(t < 5, 1.0, 0.017), "q4": np.full_like(t, 0.018), "xi": np.full_like(t, 7.0)}
    kinds = {"q3": "rotation", "q2": "rotation", "q1": "translation", "q4": "translation", "xi": "modal"}
    c = coordinate_checks(t, v, kinds, 5.0)
    assert c["q3"]["max_abs"] == pytest.approx(1.2) and c["q3"]["within"] is False and c["q3"]["unit"] == "deg"
    assert c["q2"]["within"] is True and c["q2"]["limit"] == ROTATION_LIMIT_DEG
    assert c["q1"]["max_abs"] == pytest.approx(17.0) and c["q1"]["within"] is True      # 1 m before 5 s ignored
    assert c["q4"]["within"] is False and c["q4"]["limit"] == pytest.approx(TRANSLATION_LIMIT_MM) == pytest.approx(17.4533, rel=1e-4)
    assert c["xi"]["limit"] is None and c["xi"]["within"] is None
    c = coordinate_checks(t, v, kinds, 5.0, {"q2": 0.5, "xi": 1.0})     # a per-name limit; no limit stays none
    assert c["q2"]["limit"] == 0.5 and c["q2"]["within"] is False and c["xi"]["limit"] is None
    c = coordinate_checks(t, v, kinds, 11.0)                             # the run ends before: not checked
    assert c["q3"]["max_abs"] is None and c["q3"]["within"] is None


def _run(*args):
    return CliRunner().invoke(main, ["-q", *map(str, args)])


@pytest.fixture(scope="module")
def pulse_runs(tmp_path_factory, testbed_path):
    d = tmp_path_factory.mktemp("ctl")
    assert _run("control", "design", testbed_path, "--qx", "100", "--rigid-factor", "0.3", "--rate-factor", "0.1",
                "-o", d / "g.json").exit_code == 0
    common = ["--scenario", "pulse", "--duration", "12", "--seed", "2", "--disturbance-scale", "0.05"]
    assert _run("simulate", testbed_path, *common, "-o", d / "open").exit_code == 0
    assert _run("simulate", testbed_path, *common, "--controller", d / "g.json", "-o", d / "closed").exit_code == 0
    return d


@pytest.fixture(scope="module")
def pulse_report(pulse_runs, tmp_path_factory):
    """`cdgps report control` of the pulse runs with --json, once for the tests reading it: (result, its folder)."""
    d, out = pulse_runs, tmp_path_factory.mktemp("pulse_report") / "rep"
    r = _run("report", "control", d / "g.json", "--open", d / "open", "--closed", d / "closed", "-o", out,
             "--date", "2026-12-02", "--json")
    assert r.exit_code == 0, r.output
    return r, out


def test_pulse_report(pulse_runs, pulse_report, tmp_path):
    d = pulse_runs
    r, rep = pulse_report
    data = json.loads(r.stdout)
    assert data["scenario"] == "pulse"
    assert data["metrics"]["closed"]["q5"]["peak_ratio"] < 0.5
    assert data["controllers"]["closed"]["estimator_process_noise_scale"] > 1.0     # the separation rule
    md = (rep / "report.md").read_text()
    assert "## Controller" in md and "(met)" in md
    names = sorted(p.name for p in rep.iterdir())
    assert names == ["coordinates.png", "poles.png", "pulse.png", "report.html", "report.json", "report.md"]
    html = (rep / "report.html").read_text()
    assert "Provenance" in html and "sha256" in html and "Figure 1" in html
    r2 = _run("report", "control", d / "g.json", "--open", d / "open", "--closed", d / "closed", "-o", tmp_path / "rep2",
              "--date", "2026-12-02")
    for n in names:
        assert (rep / n).read_bytes() == (tmp_path / "rep2" / n).read_bytes(), n


@pytest.mark.parametrize("args,words", [
    (["--closed", "{closed}"], "--open: the pulse report compares"),
    (["--closed", "{open}"], "expected a closed-loop run"),
    (["--closed", "{closed}", "--open", "{closed}"], "expected an open-loop run"),
    (["--closed", "{nowhere}"], "not a `cdgps simulate` folder"),
])
def test_report_refuses_wrong_inputs(pulse_runs, tmp_path, args, words):
    d = pulse_runs
    args = [a.replace("{closed}", str(d / "closed")).replace("{open}", str(d / "open"))
            .replace("{nowhere}", str(tmp_path / "none")) for a in args]
    r = _run("report", "control", d / "g.json", *args, "-o", tmp_path / "rep")
    assert r.exit_code == 2 and words in r.output, r.output
    assert not (tmp_path / "rep").exists()


def test_slew_report_gives_the_metrics_on_the_estimate_too(pulse_runs, testbed_path, tmp_path):
    """The paper's Fig. 11 numbers are 'as measured by GPS': the report adds them, computed from the
    controller.csv the closed loop wrote (checked against a direct computation)."""
    import pandas as pd

    d = pulse_runs
    assert _run("simulate", testbed_path, "--scenario", "slew", "--duration", "10", "--seed", "2",
                "--controller", d / "g.json", "-o", tmp_path / "slew").exit_code == 0
    r = _run("report", "control", d / "g.json", "--closed", tmp_path / "slew", "-o", tmp_path / "rep",
             "--date", "2026-12-02", "--json")
    assert r.exit_code == 0, r.output
    est = json.loads(r.stdout)["metrics"]["closed"]["estimated"]
    limits = json.loads(r.stdout)["coordinate_limits"]     # slew: q10 within 0.5° of the command 30 s after it
    (q10,) = limits["q10"]
    assert q10["centre"] == pytest.approx(math.radians(-22.0)) and q10["from_s"] == 5.0 + 30.0
    assert q10["half_width"] == pytest.approx(math.radians(0.5)) and "paper" in q10["statement"]
    assert all(len(v) == 1 and v[0]["from_s"] == 5.0 and v[0]["centre"] == 0.0 for k, v in limits.items() if k != "q10")
    checks = json.loads(r.stdout)["coordinates"]["closed"]          # a 10 s run ends before the 30 s check
    assert checks["q10"]["max_abs"] is None and checks["q10"]["within"] is None
    assert "| limit |" in (tmp_path / "rep" / "report.md").read_text()
    c = pd.read_csv(tmp_path / "slew" / "controller.csv")
    ref = slew_metrics(c["time_s"], np.degrees(c["q10_hat_rad"]), {k: np.degrees(c[f"{k}_hat_rad"]) for k in ("q2", "q5", "q8")},
                       -22.0, 5.0)
    assert est["internal_max_deg"] == pytest.approx(ref["internal_max_deg"], rel=1e-12)
    assert "as estimated" in (tmp_path / "rep" / "report.md").read_text()


def _bare_name(column: str) -> str:
    """truth.csv's ``q6_rad`` / ``q1_m`` (issue 32: units in the names) → ``q6`` / ``q1``."""
    return column.removesuffix("_rad").removesuffix("_m") if column != "time_s" else column


def test_control_reports_check_every_coordinate(pulse_runs, pulse_report):
    """Every generalized coordinate, q3, q6, q9 and q10 included, is in the pulse report, checked from 3 s
    after the pulse against its limit (q10 about its value at the pulse start), with the numbers computed
    from truth.csv, and each limit's source named: the paper's for q2/q5/q8, ours for the rest."""
    import pandas as pd

    d = pulse_runs
    r, rep = pulse_report
    checks = json.loads(r.stdout)["coordinates"]["closed"]
    assert list(checks) == [f"q{i}" for i in range(1, 11)]
    q = pd.read_csv(d / "closed" / "truth.csv").rename(columns=_bare_name)
    late = q[q["time_s"] >= 6.0 + 3.0]
    assert checks["q6"]["max_abs"] == pytest.approx(np.degrees(late["q6"].abs().max()), rel=1e-12)
    assert checks["q4"]["max_abs"] == pytest.approx(1000 * late["q4"].abs().max(), rel=1e-12)
    at_pulse = np.interp(5.0, q["time_s"], q["q10"])
    assert checks["q10"]["max_abs"] == pytest.approx(np.degrees((late["q10"] - at_pulse).abs().max()), rel=1e-9)
    assert checks["q10"]["limit"] == ROTATION_LIMIT_DEG
    assert all(c["within"] == (c["max_abs"] <= c["limit"]) for c in checks.values())
    src = json.loads(r.stdout)["coordinate_limit_sources"]
    assert sorted(src, key=lambda n: int(n[1:])) == [f"q{i}" for i in range(1, 11)]
    assert all(src[n].startswith("the paper's") for n in ("q2", "q5", "q8"))
    assert all(src[n].startswith("ours") and "paper states no limit" in src[n] for n in ("q1", "q3", "q4", "q6", "q7", "q9"))
    assert src["q10"].startswith("ours") and "Sec. VI.C" in src["q10"]
    md = (rep / "report.md").read_text()
    assert "## Every coordinate" in md and "| q3 |" in md and "| q9 |" in md and "| q10 |" in md
    assert "Where each limit comes from" in md and "| limit | ≤ 17.5 mm from 9 s |" in md


def _edited_copy(src, dst, edit):
    import shutil

    shutil.copytree(src, dst)
    edit(dst)
    return dst


def _cut_truth(d):
    text = (d / "truth.csv").read_bytes()
    (d / "truth.csv").write_bytes(text[: len(text) // 3])


def _short_controller(d):
    lines = (d / "controller.csv").read_text().splitlines(keepends=True)
    (d / "controller.csv").write_text("".join(lines[:-5]))


@pytest.mark.parametrize("edit,words", [
    (_cut_truth, "truth.csv: line"),
    (_short_controller, "controller.csv: "),
])
def test_report_refuses_a_cut_simulation_csv(pulse_runs, tmp_path, edit, words):
    """Issue 32: a truth.csv cut mid-row ended in an IndexError traceback; now the file and line are named."""
    closed = _edited_copy(pulse_runs / "closed", tmp_path / "closed", edit)
    r = _run("report", "control", pulse_runs / "g.json", "--open", pulse_runs / "open", "--closed", closed,
             "-o", tmp_path / "rep")
    assert r.exit_code == 2 and words in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "rep").exists()


@pytest.mark.parametrize("key,value,words", [
    ("poles", None, "key 'poles'"),
    ("poles", {"open_loop": [], "closed_loop": [{"z_re": "x"}]}, "key 'poles.closed_loop'"),
    ("sample_period_s", -1, "key 'sample_period_s'"),
])
def test_report_refuses_a_damaged_gains_file(pulse_runs, tmp_path, key, value, words):
    g = json.loads((pulse_runs / "g.json").read_text())
    g[key] = value
    (tmp_path / "g.json").write_text(json.dumps(g))
    r = _run("report", "control", tmp_path / "g.json", "--open", pulse_runs / "open", "--closed",
             pulse_runs / "closed", "-o", tmp_path / "rep")
    assert r.exit_code == 2 and words in r.output and "Traceback" not in r.output, r.output


def test_report_refuses_the_gain_of_another_design(pulse_runs, testbed_path, tmp_path):
    """The closed run records which K it used; a GAINS.json of another design (same config) is refused."""
    assert _run("control", "design", testbed_path, "-o", tmp_path / "paper.json").exit_code == 0
    r = _run("report", "control", tmp_path / "paper.json", "--open", pulse_runs / "open", "--closed",
             pulse_runs / "closed", "-o", tmp_path / "rep")
    assert r.exit_code == 2 and "another gain K" in r.output, r.output
    truth = json.loads((pulse_runs / "closed" / "truth.json").read_text())
    from cdgps_cli.io.gains_file import gain_sha256, read_gains

    assert truth["controller"]["gains_k_sha256"] == gain_sha256(read_gains(pulse_runs / "g.json")["K"])


def test_simulate_refuses_a_gain_of_another_sample_period(pulse_runs, testbed_path, tmp_path):
    g = json.loads((pulse_runs / "g.json").read_text())
    g["sample_period_s"] = 0.05
    (tmp_path / "g.json").write_text(json.dumps(g))
    r = _run("simulate", testbed_path, "--scenario", "pulse", "--duration", "2", "--controller", tmp_path / "g.json",
             "-o", tmp_path / "sim")
    assert r.exit_code == 2 and "sample_period_s" in r.output and "0.05" in r.output, r.output
    assert not (tmp_path / "sim").exists()


def test_every_coordinate_is_drawn_against_the_limit_the_report_states(pulse_runs, pulse_report):
    """Issues 31, 33: the closed loop's q1…q10 (q3/q6/q9 included) in coordinates.png, each drawn against
    the limit the 'Every coordinate' table checks (the same value, centre and start), its title naming the
    source; after a pulse q2, q5, q8 also carry the 'back within' band (10 % of the open-loop first peak)."""
    import pandas as pd
    from PIL import Image

    from cdgps_cli.control.metrics import BACK_FRACTION, first_peak_deg

    d = pulse_runs
    r, rep = pulse_report
    limits = json.loads(r.stdout)["coordinate_limits"]
    assert sorted(limits, key=lambda n: int(n[1:])) == [f"q{i}" for i in range(1, 11)]
    open_q = pd.read_csv(d / "open" / "truth.csv").rename(columns=_bare_name)
    start = next(s for s in json.loads((d / "closed" / "truth.json").read_text())["segments"] if s["kind"] == "pulse")
    checks = json.loads(r.stdout)["coordinates"]["closed"]
    for n, bands in limits.items():
        checked, *back = bands
        scale = np.degrees(1.0) if checks[n]["unit"] == "deg" else 1e3
        assert checked["half_width"] * scale == pytest.approx(checks[n]["limit"]) and checked["from_s"] == 9.0, n
        assert ("paper, Sec. VI.D" if n in ("q2", "q5", "q8") else "ours; the paper states none") in checked["statement"]
        if n in ("q2", "q5", "q8"):
            peak = first_peak_deg(open_q["time_s"].to_numpy(), open_q[n].to_numpy(), start["start_s"])
            assert back[0]["half_width"] == pytest.approx(BACK_FRACTION * peak) and back[0]["from_s"] == start["start_s"]
        else:
            assert back == [], n
    im = Image.open(rep / "coordinates.png")
    assert im.size[0] >= 1000 and im.size[1] >= 900                 # ten panels at print size
    caption = json.loads(r.stdout)["captions"]["coordinates.png"]
    assert "Figure" in (rep / "report.html").read_text() and "checks" in caption
    assert "no limit" not in caption
