"""Sensor-test reports (1998 paper Sec. VI.A–B, Figs. 7–8) on small simulated runs through the
whole library pipeline: simulate → write_run → read_run → initialize → estimate → write_states →
States → static_report / spectrum_report, then the same through the CLI."""

from __future__ import annotations

import base64
import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from PIL import Image

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.report.sensor_reports import detect_rest, spectrum_report, static_report
from cdgps_cli.io.run import read_run
from cdgps_cli.sim.structure import SimOptions
from cdgps_cli.analysis.spectra import SpectraOptions
from cdgps_cli.io.states import States, StatesChunks

from _report_pipeline import pipeline

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
STATIC_KEYS = {"mean_deg", "survey_deg", "error_deg", "noise_rms_deg", "drift_deg_per_min", "gyro_drift_deg_per_min"}
MODE_KEYS = {"mode", "model_hz", "gps_hz", "gyro_hz", "error_pct", "damping", "seen"}


@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    """200 s static scenario (1 min motion, 20 s settling, rest at q10 = −1.4°), 2 mm phase noise,
    estimated in static mode from the rest start (as the demo does)."""
    return pipeline(tmp_path_factory.mktemp("static"),
                    SimOptions(duration_s=200, seed=2, scenario="static", phase_sigma_m=0.002), rest_from_truth=True)


@pytest.fixture(scope="module")
def free_run(testbed_free_run):
    """300 s free vibration (states over the whole record: the 60 s INIT window, the filter after it);
    the run test_run_report.py uses too (conftest.py)."""
    return testbed_free_run


def check_png(data: bytes) -> tuple[int, int]:
    assert data[:8] == PNG_MAGIC
    Image.open(io.BytesIO(data)).verify()
    im = Image.open(io.BytesIO(data))
    im.load()
    assert im.size[0] > 300 and im.size[1] > 200
    return im.size


def check_html(path: Path, pngs: dict[str, Path]) -> None:
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<!doctype html>") and text.rstrip().endswith("</html>")
    assert "data:image/png;base64," in text
    assert not re.search(r"(src|href)\s*=\s*['\"]?(https?:)?//", text, re.I), "external resource in the HTML"
    assert "http://" not in text and "https://" not in text
    assert "<script" not in text.lower() and "<link" not in text.lower()
    embedded = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", text)
    assert len(embedded) == len(pngs)
    got = {base64.b64decode(b) for b in embedded}
    assert got == {p.read_bytes() for p in pngs.values()}           # the same figures as the PNG files


# ----------------------------------------------------------------------------- static report

@pytest.fixture(scope="module")
def static_out(static_run, tmp_path_factory):
    st = States(static_run["states"], diagnostics=False)
    run = read_run(static_run["run"], phase=False)
    out = tmp_path_factory.mktemp("static_report")
    return static_report(st, run, "q6+q10", -1.4, out), out


def test_static_report_values(static_run, static_out, record_property):
    d, _ = static_out
    rest = next(s for s in static_run["truth"]["segments"] if s["kind"] == "rest")
    assert d["segment"] == "detected"
    assert rest["start_s"] <= d["start_s"] < d["end_s"] <= rest["end_s"] + 1e-9
    assert d["end_s"] - d["start_s"] > 0.8 * (rest["end_s"] - rest["start_s"])
    assert d["mean_deg"] == pytest.approx(-1.4, abs=0.1)
    assert d["error_deg"] == pytest.approx(d["mean_deg"] + 1.4)
    assert d["noise_rms_deg"] < 0.02
    assert abs(d["drift_deg_per_min"]) < 0.02
    assert d["gyro"] == ["g4", "g5"]                         # the gyros whose axis is q6 + q10
    assert d["gyro_drift_deg_per_min"] is not None
    assert abs(d["gyro_drift_deg_per_min"]) > 5 * abs(d["drift_deg_per_min"])
    assert abs(d["gyro_minus_gps_end_deg"]) > 3 * d["noise_rms_deg"]
    for k in ("mean_deg", "error_deg", "noise_rms_deg", "drift_deg_per_min", "gyro_drift_deg_per_min"):
        record_property(k, d[k] if not hasattr(d[k], "item") else d[k].item())


def test_static_report_in_chunks_as_whole(static_run, static_out, tmp_path, monkeypatch):
    """The static report from STATES read in chunks (as `cdgps report static` reads it, issue 29; 1024
    epochs a chunk here: two chunks) equals the one from the whole record, figures and report.json."""
    import cdgps_cli.config.options as options

    monkeypatch.setattr(options, "STATES_CHUNK_EPOCHS", 1024)
    d, out = static_out
    with StatesChunks(static_run["states"], covariance=True) as st:
        assert st.n_epochs > 1024
        c = static_report(st, read_run(static_run["run"], phase=False), "q6+q10", -1.4, tmp_path)
    assert json.dumps(c, sort_keys=True, default=str) == json.dumps(d, sort_keys=True, default=str)
    assert (tmp_path / "report.json").read_bytes() == (out / "report.json").read_bytes()


def test_static_report_files(static_out):
    d, out = static_out
    assert {p.name for p in out.iterdir()} == {"report.md", "report.json", "report.html", "static.png"}
    check_png((out / "static.png").read_bytes())
    check_html(out / "report.html", {"static.png": out / "static.png"})
    js = json.loads((out / "report.json").read_text())
    assert STATIC_KEYS <= set(js)
    assert js["survey_deg"] == -1.4 and js["mean_deg"] == pytest.approx(d["mean_deg"])
    md = (out / "report.md").read_text()
    assert "q6+q10" in md and "(static.png)" in md and f"{d['mean_deg']:.4f}" in md
    assert not list(out.glob(".*tmp*"))


def test_static_report_given_segment_and_errors(static_run, tmp_path):
    st = States(static_run["states"], diagnostics=False)
    d = static_report(st, None, "q6+q10", None, tmp_path / "a", start_s=120.0, end_s=180.0)
    assert d["segment"] == "given" and d["start_s"] == pytest.approx(120.0) and d["end_s"] == pytest.approx(180.0)
    assert d["error_deg"] is None and d["gyro_drift_deg_per_min"] is None
    assert d["mean_deg"] == pytest.approx(-1.4, abs=0.1)
    with pytest.raises(CdgpsError, match="must be after"):
        static_report(st, None, "q6+q10", None, tmp_path / "b", start_s=150.0, end_s=100.0)
    with pytest.raises(CdgpsError, match="fewer than 10"):
        static_report(st, None, "q6+q10", None, tmp_path / "c", start_s=150.0, end_s=150.2)
    with pytest.raises(CdgpsError, match="unknown coordinate"):
        static_report(st, None, "q6+q11", None, tmp_path / "d")
    run = read_run(static_run["run"], phase=False)
    with pytest.raises(CdgpsError, match="gyro-name"):
        static_report(st, run, "q6+q10", None, tmp_path / "e", gyro="g9")


def test_detect_rest_synthetic():
    t = np.round(np.arange(3000) * 0.1, 9)
    a = np.where(t < 100, 0.01 * np.sin(2 * np.pi * 0.2 * t), 0.0) + 1e-5 * np.random.default_rng(0).standard_normal(t.size)
    t0, t1 = detect_rest(t, a)
    assert 100 <= t0 < 110 and t1 == pytest.approx(t[-1])
    with pytest.raises(CdgpsError, match="no rest segment"):
        detect_rest(t, 0.05 * np.sin(2 * np.pi * 0.2 * t), max_std_deg=0.01)


# ----------------------------------------------------------------------------- spectrum report

@pytest.fixture(scope="module")
def spectrum_out(free_run, tmp_path_factory):
    st = StatesChunks(free_run["states"])            # as the CLI reads it (in chunks)
    run = read_run(free_run["run"], phase=False)
    out = tmp_path_factory.mktemp("spectrum_report")
    return spectrum_report(st, run, SpectraOptions(), out), out


def test_spectrum_report_files(spectrum_out, testbed_cfg):
    d, out = spectrum_out
    assert {p.name for p in out.iterdir()} == {"psd.csv", "peaks.json", "psd.png", "fdd.png",
                                              "report.md", "report.json", "report.html"}
    df = pd.read_csv(out / "psd.csv")
    assert df.columns[0] == "frequency_hz"
    f = df["frequency_hz"].to_numpy()
    assert f[0] > 0 and np.all(np.diff(f) > 0)
    cols = set(df.columns)
    for n in testbed_cfg.coord_names:
        if n == "q10":
            continue
        unit = {"rad": "rad2_hz", "m": "m2_hz"}[testbed_cfg.coord_unit(n)]
        assert f"gps_{n}_{unit}" in cols, (n, sorted(cols))
    for g in testbed_cfg.gyro_names:
        assert {f"gps_{g}_rad2_hz", f"gyro_{g}_rad2_hz", f"coherence_{g}"} <= cols
    assert {"fdd_singular_value_1_1_hz", "fdd_singular_value_2_1_hz", "fdd_singular_value_3_1_hz"} <= cols
    psd_cols = [c for c in cols if c.startswith(("gps_", "gyro_"))]
    assert all(c.endswith(("_rad2_hz", "_m2_hz")) for c in psd_cols), psd_cols
    assert np.all(np.isfinite(df[psd_cols].to_numpy()))
    peaks = json.loads((out / "peaks.json").read_text())
    assert len(peaks["modes"]) == 8
    for m in peaks["modes"]:
        assert MODE_KEYS <= set(m), m
        assert isinstance(m["seen"], bool)
    assert peaks["gyros"] == list(testbed_cfg.gyro_names)
    assert peaks["settings"]["window"] == "hann"
    for name in ("psd.png", "fdd.png"):
        check_png((out / name).read_bytes())
    check_html(out / "report.html", {n: out / n for n in ("psd.png", "fdd.png")})
    rep = json.loads((out / "report.json").read_text())
    assert rep["seen"] == sum(m["seen"] for m in rep["modes"]) == d["seen"]
    md = (out / "report.md").read_text()
    assert "(psd.png)" in md and "(fdd.png)" in md and rep["summary"] in md
    # the spectral peaks (session 30): the table of peaks.json's, in the page too
    assert rep["peaks"] == peaks["peaks"] and peaks["peaks"], peaks["peaks"]
    assert "## Spectral peaks" in md and "Spectral peaks" in (out / "report.html").read_text()
    for p in peaks["peaks"]:
        assert {"coordinate", "frequency_hz", "amplitude", "amplitude_sigma", "amplitude_psd", "steady"} <= set(p)
        assert f"| {p['coordinate']} | {p['frequency_hz']:.4f} |" in md


def test_spectrum_report_identifies_modes_from_estimates(spectrum_out, record_property):
    """300 s of smoothed estimates (the whole record: INIT's window and the filter after it; 75 s
    segments): the well-separated modes are found within 5 %; of the 0.132/0.135/0.138 Hz cluster
    FDD resolves two at this length (bending-1, bending-2; twist-2's singular vector has MAC 0.14)."""
    d, _ = spectrum_out
    modes = {m["mode"]: m for m in d["modes"]}
    for name in ("pendulum", "swing", "twist-1", "bending-3", "bending-4"):
        assert modes[name]["seen"], modes[name]
        assert abs(modes[name]["error_pct"]) < 5
    assert sum(modes[n]["seen"] for n in ("bending-1", "bending-2", "twist-2")) >= 2
    assert d["seen"] >= 7
    record_property("seen", d["seen"])
    for name, m in modes.items():
        record_property(f"{name}_error_pct", None if m["error_pct"] is None else float(round(m["error_pct"], 2)))


def test_gyro_frequency_within_its_search_band(spectrum_out):
    """Regression: gyro_hz is searched within ±band_pct of gps_hz; the parabolic refinement at the band
    edge used to extrapolate outside it (this run: pendulum gyro_hz 0.0877 Hz for a 0.0584–0.0646 Hz band)."""
    d, _ = spectrum_out
    band = d["settings"]["band_pct"] / 100
    bad = [(m["mode"], round(m["gps_hz"], 4), round(m["gyro_hz"], 4)) for m in d["modes"]
           if m["gyro_hz"] is not None and abs(m["gyro_hz"] - m["gps_hz"]) > band * m["gps_hz"] + 1e-9]
    assert not bad, bad


# regression: a gyro PSD without a maximum inside the band gave the band-edge bin as gyro_hz
def test_gyro_frequency_is_a_gyro_psd_peak(spectrum_out):
    d, out = spectrum_out
    df = pd.read_csv(out / "psd.csv")
    f = df["frequency_hz"].to_numpy()
    bad = []
    for m in d["modes"]:
        if m["gyro_hz"] is None:
            continue
        p = df[f"gyro_{m['gyro']}_rad2_hz"].to_numpy()
        i = int(np.argmin(np.abs(f - m["gyro_hz"])))
        if not (p[i] >= p[i - 1] and p[i] >= p[i + 1]):
            bad.append((m["mode"], round(m["gyro_hz"], 5)))
    assert not bad, bad


# ----------------------------------------------------------------------------- CLI

def cli(args):
    return CliRunner().invoke(main, ["--quiet", *map(str, args)])


@pytest.fixture(scope="module")
def cli_outputs(static_run, free_run, tmp_path_factory):
    """Every report command once through the CLI (the library runs above are the reference)."""
    base = tmp_path_factory.mktemp("cli")
    return base, {
        "spectra": cli(["spectra", free_run["states"], "--gyro", free_run["run"], "-o", base / "spectra", "--json"]),
        "static": cli(["report", "static", static_run["states"], "--gyro", static_run["run"], "--angle", "q6+q10",
                       "--survey-deg", "-1.4", "-o", base / "static", "--json"]),
        "spectrum": cli(["report", "spectrum", free_run["states"], "--gyro", free_run["run"], "-o", base / "spectrum",
                         "--json"]),
    }


def test_cli_json(cli_outputs):
    base, res = cli_outputs
    for name, r in res.items():
        assert r.exit_code == 0, (name, r.output)
        assert r.stderr == "", (name, r.stderr)                  # --quiet
    s = json.loads(res["spectra"].stdout)
    assert len(s["modes"]) == 8 and MODE_KEYS <= set(s["modes"][0])
    assert s["modes"] == json.loads((base / "spectra" / "peaks.json").read_text())["modes"]
    st = json.loads(res["static"].stdout)
    assert STATIC_KEYS <= set(st) and st["mean_deg"] == pytest.approx(-1.4, abs=0.1)
    assert st == json.loads((base / "static" / "report.json").read_text())
    sp = json.loads(res["spectrum"].stdout)
    assert sp == json.loads((base / "spectrum" / "report.json").read_text())


def test_cli_human_summary(static_run, tmp_path):
    r = CliRunner().invoke(main, ["report", "static", str(static_run["states"]), "--angle", "q6+q10",
                                  "--survey-deg", "-1.4", "-o", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert r.stdout == "" and re.search(r"q6\+q10: mean -1\.[34]\d*°, error [+-]0\.\d+°, noise", r.stderr), r.stderr
    assert "report.html" in r.stderr


def same_files(a: Path, b: Path, names=None) -> None:
    if names is None:
        names = sorted(p.name for p in a.iterdir())
        assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), (a, name)


def test_outputs_byte_identical_on_rerun(cli_outputs, static_out, spectrum_out):
    """Rerun = the CLI after the library call on the same STATES/RUN: every file byte-identical,
    PNGs included (and `spectra` writes exactly the spectrum report's psd.csv, peaks.json and PNGs)."""
    base, _ = cli_outputs
    same_files(static_out[1], base / "static")
    same_files(spectrum_out[1], base / "spectrum")
    same_files(base / "spectra", spectrum_out[1], ["fdd.png", "peaks.json", "psd.csv", "psd.png"])


def test_png_byte_identical_across_processes(static_run, cli_outputs, tmp_path):
    """A fresh interpreter (different hash seed) draws the same bytes as the in-process run."""
    base, _ = cli_outputs
    env = dict(os.environ, PYTHONHASHSEED="12345")
    p = subprocess.run([sys.executable, "-m", "cdgps_cli.cli.commands", "--quiet", "report", "static", str(static_run["states"]),
                        "--gyro", str(static_run["run"]), "--angle", "q6+q10", "--survey-deg", "-1.4",
                        "-o", str(tmp_path / "s")], capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    for name in ("static.png", "report.html", "report.json", "report.md"):
        assert (tmp_path / "s" / name).read_bytes() == (base / "static" / name).read_bytes(), name


@pytest.mark.parametrize("angle,what", [("q6+*q2", "expected a coordinate name"), ("q6+q11", "unknown coordinate 'q11'"),
                                        ("__import__('os')", "unexpected character"), ("", "empty")])
def test_cli_bad_expression(static_run, tmp_path, angle, what):
    out = tmp_path / "o"
    r = CliRunner().invoke(main, ["report", "static", str(static_run["states"]), "--angle", angle, "-o", str(out)])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    assert r.exception is None or isinstance(r.exception, SystemExit)
    assert r.stderr.startswith("cdgps: error: ") and what in r.stderr, r.stderr
    assert not out.exists() or not any(out.iterdir())


def test_cli_bad_spectra_inputs(free_run, static_run, tmp_path):
    r = cli(["spectra", free_run["states"], "--coords", "q2,q99", "-o", tmp_path / "a"])
    assert r.exit_code == 2 and "unknown coordinate(s) q99" in r.stderr and "Traceback" not in r.output
    r = cli(["report", "spectrum", free_run["states"], "--overlap", "1.5", "-o", tmp_path / "b"])
    assert r.exit_code == 2 and "overlap" in r.stderr
    r = cli(["spectra", free_run["run"], "-o", tmp_path / "c"])                     # a RUN, not STATES
    assert r.exit_code == 2 and "STATES.mcap" in r.stderr
    r = cli(["spectra", tmp_path / "missing.mcap", "-o", tmp_path / "d"])
    assert r.exit_code == 2 and "Traceback" not in r.output


def test_float_csv_matches_pandas_to_csv():
    """psd.csv is written by a fast formatter: the same bytes as pandas' to_csv (NaN → empty field)."""
    from cdgps_cli.report.sensor_reports import float_csv

    rng = np.random.default_rng(0)
    a = rng.standard_normal((400, 6)) * 10.0 ** rng.integers(-12, 12, (400, 6))
    a[0, 0] = a[3, 2] = a[399, 5] = np.nan
    a[7, 1], a[8, 1] = np.inf, -np.inf
    a[9] = 0.0
    df = pd.DataFrame(a, columns=["frequency_hz", "gps_q1_m2_hz", "nan_col", "c", "d", "coherence_g1"])
    assert float_csv(df) == df.to_csv(index=False, lineterminator="\n", float_format="%.7g")


# ----------------------------------------------------------------------------- item 10: reports a reader can trust

VOID = {"meta", "img", "br", "hr", "link", "input", "col", "source", "wbr"}


def assert_well_formed(text: str) -> None:
    """Every non-void element closed in order, one html/head/body, nothing after </html>."""
    from html.parser import HTMLParser

    class P(HTMLParser):
        def __init__(self):
            super().__init__(convert_charrefs=True)
            self.stack, self.seen, self.errors = [], [], []

        def handle_starttag(self, tag, attrs):
            self.seen.append(tag)
            if tag not in VOID:
                self.stack.append(tag)

        def handle_endtag(self, tag):
            if tag in VOID:
                return
            if not self.stack or self.stack[-1] != tag:
                self.errors.append(f"</{tag}> closes <{self.stack[-1] if self.stack else None}>")
            else:
                self.stack.pop()

    p = P()
    p.feed(text)
    p.close()
    assert not p.errors, p.errors[:5]
    assert p.stack == [], p.stack
    assert [p.seen.count(t) for t in ("html", "head", "body", "title")] == [1, 1, 1, 1]


def sha(path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def test_html_checker_can_fail():
    with pytest.raises(AssertionError):
        assert_well_formed("<!doctype html><html><head><title>x</title></head><body><table><tr><td>1</tr></table></body></html>")
    assert_well_formed("<!doctype html><html><head><meta charset='utf-8'><title>x</title></head><body><p>a</p></body></html>")


@pytest.mark.parametrize("which", ["static", "spectrum"])
def test_report_provenance_is_the_actual_inputs(which, static_run, free_run, static_out, spectrum_out):
    run_ = static_run if which == "static" else free_run
    out = (static_out if which == "static" else spectrum_out)[1]
    rep = json.loads((out / "report.json").read_text())
    p = rep["provenance"]
    from cdgps_cli import __version__

    assert p["command"] == f"cdgps report {which}"
    assert [(i["role"], i["path"], i["sha256"], i["bytes"]) for i in p["inputs"]] == [
        ("STATES.mcap", str(run_["states"]), sha(run_["states"]), run_["states"].stat().st_size),
        ("RUN.mcap (--gyro)", str(run_["run"]), sha(run_["run"]), run_["run"].stat().st_size)]
    # the chain recorded inside STATES: the RUN it was estimated from is the --gyro RUN here
    assert p["estimated_from"]["run_sha256"] == sha(run_["run"]) and p["gyro_run_is_estimate_run"] is True
    assert p["estimated_from"]["init_sha256"] == sha(run_["dir"] / "init.json")
    assert p["estimated_from"]["config_sha256"] == load_config(TESTBED).sha256
    assert p["estimated_from"]["options"]["smooth"] is True
    ing = p["gyro_run_ingested_from"]
    assert ing["receiver_csv"]["sha256"] == sha(run_["dir"] / "sim" / "receiver.csv")
    assert ing["gyro_csv"]["sha256"] == sha(run_["dir"] / "sim" / "gyro.csv")
    assert p["software"]["cdgps"] == __version__ and p["software"]["numpy"] == np.__version__
    if which == "static":
        assert p["options"]["--angle"] == "q6+q10" and p["options"]["--survey-deg"] == -1.4
        assert {"--start", "--end", "--gyro-name", "--gyro", "--date"} <= set(p["options"])
    else:
        assert {"--coords", "--segment-s", "--overlap", "--pad", "--gyro"} <= set(p["options"])
        assert {"band_pct", "seen_pct", "min_mac", "fmax_hz"} == set(p["settings"])      # no command-line option
    newest = max(run_["states"].stat().st_mtime, run_["run"].stat().st_mtime)
    from datetime import datetime, timezone
    assert p["date"] == datetime.fromtimestamp(int(newest), tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    assert p["date_source"] == "modification time of the newest input"
    md = (out / "report.md").read_text()
    page = (out / "report.html").read_text()
    for text in (md, page):
        assert "Provenance" in text and p["date"] in text and f"cdgps {__version__}" in text
        for i in p["inputs"]:
            assert i["sha256"] in text
        assert sha(run_["dir"] / "init.json") in text
    assert f"cdgps report {which} {run_['states']}" in md


def test_report_date_sources(static_run, tmp_path, monkeypatch):
    from cdgps_cli.io.provenance import report_date

    f = [static_run["states"]]
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    assert report_date(f, "2026-12-01") == {"date": "2026-12-01", "source": "--date"}
    assert report_date(f, "2026-12-01T23:30:00+01:00")["date"] == "2026-12-01 22:30:00 UTC"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1764633600")
    assert report_date(f) == {"date": "2025-12-02 00:00:00 UTC", "source": "SOURCE_DATE_EPOCH"}
    assert report_date(f, "2026-01-02")["source"] == "--date"                 # the option wins
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "yesterday")
    with pytest.raises(CdgpsError, match="SOURCE_DATE_EPOCH"):
        report_date(f)
    monkeypatch.delenv("SOURCE_DATE_EPOCH")
    out = tmp_path / "o"
    r = cli(["report", "static", static_run["states"], "--angle", "q6+q10", "--date", "1st of May", "-o", out])
    assert r.exit_code == 2 and "--date" in r.stderr and "Traceback" not in r.output
    assert not out.exists()
    r = cli(["report", "static", static_run["states"], "--angle", "q6+q10", "--date", "2026-12-01", "-o", out, "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["provenance"]["date"] == "2026-12-01"
    assert "| date | 2026-12-01 (--date) |" in (out / "report.md").read_text()


def test_spectrum_table_sorted_with_mode_numbers_and_zeta(spectrum_out, testbed_cfg):
    d, out = spectrum_out
    md = (out / "report.md").read_text()
    lines = [ln for ln in md.splitlines() if ln.startswith("| ")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header[:3] == ["#", "mode", "model Hz"]
    assert {"ζ", "σ ζ", "model ζ"} <= set(header) and not any("damping" in h for h in header)
    rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines[1:9]]
    hz = [float(r[2]) for r in rows]
    assert hz == sorted(hz) and len(rows) == 8
    number = {n: i + 1 for i, n in enumerate(testbed_cfg.mode_names)}          # the config's = Table 1's numbers
    assert all(int(r[0]) == number[r[1]] for r in rows)
    assert [m["number"] for m in d["modes"]] == [int(r[0]) for r in rows]       # report.json in table order
    peaks = json.loads((out / "peaks.json").read_text())
    assert all(m["number"] == number[m["mode"]] for m in peaks["modes"])
    # the figures' key under the panels uses the same numbers, in frequency order
    from cdgps_cli.report.sensor_reports import _mode_key
    key = _mode_key(testbed_cfg, {"modes": peaks["modes"]})
    assert key == "model modes: " + ", ".join(f"{r[0]} {r[1]} ({float(r[2]):g} Hz)" for r in rows)
    page = (out / "report.html").read_text()
    assert "<th>ζ</th>" in page and "<th>model ζ</th>" in page


@pytest.mark.parametrize("which", ["static", "spectrum"])
def test_every_figure_has_a_caption(which, static_out, spectrum_out):
    out = (static_out if which == "static" else spectrum_out)[1]
    names = ["static.png"] if which == "static" else ["psd.png", "fdd.png"]
    rep = json.loads((out / "report.json").read_text())
    assert list(rep["captions"]) == names and all(len(c) > 80 for c in rep["captions"].values())
    page = (out / "report.html").read_text()
    md = (out / "report.md").read_text()
    caps = re.findall(r"<figcaption>(.*?)</figcaption>", page, re.S)
    assert len(caps) == len(names) == page.count("<figure>")
    import html as _html
    for i, (name, cap) in enumerate(zip(names, caps), 1):
        text = _html.unescape(re.sub(r"<[^>]+>", "", cap))
        assert text == f"Figure {i} ({name}). {rep['captions'][name]}"
        assert f"![{name}]({name})\n\n*Figure {i} ({name}). {rep['captions'][name]}*" in md
    assert_well_formed(page)


def test_static_caption_and_sigma_reported(static_out):
    d, out = static_out
    cap = json.loads((out / "report.json").read_text())["captions"]["static.png"]
    assert f"{d['start_s']:.1f}–{d['end_s']:.1f} s" in cap and "g4, g5" in cap and "survey -1.4°" in cap
    assert d["estimated_sigma_deg"] is not None and f"{d['estimated_sigma_deg']:.4f}°" in (out / "report.md").read_text()


def test_static_figure_gps_on_its_own_scale():
    """The GPS panel's scale is the estimate's (and the survey's), whatever the gyro drifts or the
    σ band spans; the gyro difference is on the second panel."""
    from cdgps_cli.report.sensor_reports import plot_static

    t = np.arange(0, 100, 0.1)
    a = -1.4 + 0.01 * np.sin(t)                             # 0.01° of scatter
    g = a - 0.01 * t                                        # a 1° gyro drift
    fig = plot_static(t, a, np.full(t.size, 0.1), -1.4, "q6+q10", g, ["g4"])
    ax1, ax2 = fig.axes[:2]
    lo, hi = ax1.get_ylim()
    assert lo < a.min() and hi > a.max() and hi - lo < 0.1      # not flattened by the gyro or the band
    lo2, hi2 = ax2.get_ylim()
    assert lo2 <= -0.99 and hi2 >= 0                         # gyro − GPS on its own axis
    assert "beyond this axis" in " ".join(t.get_text() for t in ax1.get_legend().get_texts())
    import matplotlib.pyplot as plt
    plt.close(fig)


def _pandas_gyro_table(run):
    """The gyro table as the reports built it with pandas before issue 29 (reference for the numpy one)."""
    g = run.gyro.frame()
    names = [n for n in run.cfg.gyro_names if n in set(g["gyro"])]
    wide = g.pivot_table(index="time_s", columns="gyro", values="rate_rad_s")
    wide = wide[names].interpolate(limit_direction="both")
    return wide.index.to_numpy(dtype=float), wide.to_numpy(dtype=float), names


def test_gyro_table_as_the_pandas_pivot(static_run):
    """The reports' gyro table (numpy, from the codes) equals the pandas pivot + interpolation it
    replaced, bit for bit, also with samples missing inside and at both ends of a gyro's series."""
    from cdgps_cli.report.sensor_reports import _gyro_table

    run = read_run(static_run["run"], phase=False)
    g = run.gyro
    codes, _ = g.codes("gyro")
    keep = np.ones(len(g), dtype=bool)
    keep[100:160] = False
    keep[np.flatnonzero(codes == codes[0])[:9]] = False          # one gyro starts late
    keep[np.flatnonzero(codes == codes[-1])[-5:]] = False        # one ends early
    for table in (g, g.take(np.flatnonzero(keep))):
        run.gyro = table
        a, b = _pandas_gyro_table(run), _gyro_table(run)
        assert a[2] == b[2] and a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()
        assert not np.isnan(b[1]).any()


@pytest.mark.parametrize("command", [["spectra"], ["report", "spectrum"]])
def test_a_gyro_run_of_another_config_is_named_with_both_files(free_run, tmp_path, dof2_path, command):
    # spectra said "the gyro RUN.mcap was ingested with a different structure config than the states",
    # naming neither file; now in report run's words (one home: sensor_reports.check_gyro_run)
    other = tmp_path / "other.mcap"
    assert cli(["simulate", dof2_path, "--duration", 3, "-o", tmp_path / "sim"]).exit_code == 0
    assert cli(["ingest", tmp_path / "sim" / "receiver.csv", "--config", dof2_path, "-o", other]).exit_code == 0
    out = tmp_path / "out"
    r = cli([*command, free_run["states"], "--gyro", other, "-o", out])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert f"--gyro {other}: ingested with config" in r.stderr and f"but {free_run['states']} estimates config" \
        in r.stderr, r.stderr
    assert not out.exists() or not any(out.iterdir())
