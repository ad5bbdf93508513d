"""`cdgps report run` (issue 33 item 1): the envelope and MAC numerics on analytic cases, the page
on a small simulated run (sections, figures, provenance, determinism, chunking, bad input) and the
page in headless Chromium (every image loads, no console message; a screenshot in the test's tmp dir)."""

from __future__ import annotations

import base64
import io
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.structure import load_config
from cdgps_cli.io.run import read_run
from cdgps_cli.io.states import States
from cdgps_cli.report.envelope import EnvelopeBins, envelope_line, minmax_envelope
from cdgps_cli.report.mac import mac_matrix
from cdgps_cli.report.run_data import StatesBlocks
from cdgps_cli.report.run_report import RUN_REPORT_FILES, run_report
from cdgps_cli.sim.structure import SimOptions

from _report_pipeline import pipeline

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
DOF2 = ROOT / "configs" / "teague-1995-2dof.toml"
DATE = "2026-12-04"


# ----------------------------------------------------------------------------- numerics

def test_envelope_keeps_every_extreme_and_does_not_depend_on_chunking():
    rng = np.random.default_rng(3)
    t = np.arange(10_007) * 0.1
    y = rng.standard_normal((t.size, 2))
    y[4321, 0], y[77, 1] = 50.0, -60.0                       # spikes a decimated plot must not lose
    whole = EnvelopeBins(t.size, 2, 100)
    whole.add(0, t, y)
    cut = EnvelopeBins(t.size, 2, 100)
    for a in range(0, t.size, 333):
        cut.add(a, t[a:a + 333], y[a:a + 333])
    assert np.array_equal(whole.lo, cut.lo) and np.array_equal(whole.hi, cut.hi)
    assert np.array_equal(whole.t_first, cut.t_first) and np.array_equal(whole.t_last, cut.t_last)
    assert whole.hi[:, 0].max() == 50.0 and whole.lo[:, 1].min() == -60.0
    assert np.array_equal(whole.lo.min(axis=0), y.min(axis=0)) and np.array_equal(whole.hi.max(axis=0), y.max(axis=0))
    assert whole.count.sum() == y.size and np.allclose(whole.mean().mean(axis=0), y.mean(axis=0), atol=1e-2)
    # every bin's extremes are those of its own epochs
    b = (np.arange(t.size) * 100) // t.size
    for k in (0, 43, 99):
        assert whole.lo[k, 0] == y[b == k, 0].min() and whole.hi[k, 0] == y[b == k, 0].max()


def test_envelope_of_a_short_series_is_the_series():
    t = np.arange(7.0)
    y = np.array([1.0, -2.0, 3.0, np.nan, 5.0, 0.5, 4.0])
    tc, lo, hi = minmax_envelope(t, y, n_bins=1000)
    assert np.array_equal(tc, t)
    assert np.array_equal(lo, y, equal_nan=True) and np.array_equal(hi, y, equal_nan=True)
    x, v = envelope_line(tc, lo, hi)
    assert np.array_equal(x[::2], t) and np.array_equal(v[1::2], y, equal_nan=True)


def test_envelope_band_edges_are_tracked_apart_from_the_values():
    t = np.arange(6.0)
    y = np.zeros((6, 1))
    env = EnvelopeBins(6, 1, 2)
    env.add(0, t, y, y - np.arange(6.0)[:, None], y + 1.0)
    assert np.array_equal(env.lo, [[0.0], [0.0]]) and np.array_equal(env.band_lo, [[-2.0], [-5.0]])
    assert np.array_equal(env.band_hi, [[1.0], [1.0]])


def test_mac_matrix_analytic_cases():
    a = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    assert np.array_equal(mac_matrix(a, a), np.eye(2))                  # identical → 1, orthogonal → 0
    b = np.column_stack([-3.0 * a[:, 0], (2 - 5j) * a[:, 1]])            # scaled, sign and complex factor
    assert np.allclose(mac_matrix(b, a), np.eye(2))
    c = np.array([[1.0], [1.0], [0.0]])                                 # 45° from a[:, 0] in its plane
    assert mac_matrix(c, a[:, :1])[0, 0] == pytest.approx(0.25)         # |1|² / (2 · 2)
    assert mac_matrix(np.zeros((3, 1)), a)[0].tolist() == [0.0, 0.0]
    with pytest.raises(ValueError):
        mac_matrix(np.ones((3, 1)), np.ones((4, 1)))


# ----------------------------------------------------------------------------- the page

def _pipeline(d: Path, cfg_path: Path, sim_opt: SimOptions) -> dict:
    r = pipeline(d, sim_opt, cfg_path=cfg_path)
    return {"states": r["states"], "run": r["run"], "truth": r["sim"]}


@pytest.fixture(scope="module")
def free_run(testbed_free_run):
    """300 s free vibration of the testbed (the run the spectrum report tests use: conftest.py)."""
    r = testbed_free_run
    return {"states": r["states"], "run": r["run"], "truth": r["sim"]}


def cli(args) -> "object":
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def page(free_run, tmp_path_factory):
    """The report through the CLI, with the gyro log, the truth and the static section."""
    out = tmp_path_factory.mktemp("run_report")
    r = cli(["report", "run", free_run["states"], "--gyro", free_run["run"], "--truth", free_run["truth"],
             "--angle", "q6+q10", "--survey-deg", "-5", "--date", DATE, "-o", out, "--json"])
    assert r.exit_code == 0, r.output
    return out, (out / "index.html").read_text(encoding="utf-8"), json.loads((out / "report.json").read_text())


def _images(text: str) -> dict:
    return {m.group(1): base64.b64decode(m.group(2))
            for m in re.finditer(r"<figure id='fig-([^']+)'><img[^>]*src='data:image/png;base64,([^']+)'", text)}


def test_page_holds_provenance_first_then_summary_then_every_figure(page):
    out, text, data = page
    assert sorted(p.name for p in out.iterdir()) == sorted(RUN_REPORT_FILES)
    sections = ("provenance", "summary", "time", "consistency", "residuals", "modes", "static")
    order = [text.index(f"<section id='{k}'>") for k in sections]
    assert order == sorted(order)
    for k in sections:
        assert f"<a href='#{k}'>" in text                                  # table of contents
    imgs = _images(text)
    assert set(imgs) == {"angles", "coordinates", "nis", "nees", "residuals", "psd", "fdd", "mac", "shapes", "static"}
    for name, png in imgs.items():
        im = Image.open(io.BytesIO(png))
        im.load()
        assert im.size[0] >= 700, name                                    # readable at print size
    # every figure has a caption that says where its numbers came from
    assert len(re.findall(r"<figcaption><b>Figure \d+\.</b>", text)) == len(imgs)
    assert text.count("<span class='src'>Source: ") == len(imgs)
    # offline: no script, no stylesheet or image from anywhere else
    assert "<script" not in text and not re.search(r"(src|href)=['\"]?(https?:)?//", text)
    # provenance: the command, the config digest and the commands that made the inputs
    cfg = load_config(TESTBED)
    assert "cdgps report run" in text and cfg.sha256 in text
    assert "cdgps ingest" in text and "cdgps init on" in text and "cdgps estimate" in text
    assert data["provenance"]["date"] == DATE


def test_summary_numbers_match_the_estimate(page, free_run):
    _, text, data = page
    st = States(free_run["states"])
    s = data["summary"]
    assert s["epochs"] == len(st.time_s)
    ok = (st.nis_dof > 0) & np.isfinite(st.nis)
    assert s["nis"]["epochs"] == int(ok.sum())
    assert s["nis"]["mean_per_dof"] == pytest.approx(float(np.mean(st.nis[ok] / st.nis_dof[ok])), rel=1e-12)
    for i, n in enumerate(st.coord_names):
        c = s["coordinates"][n]
        assert c["min"] == pytest.approx(float(st.q[:, i].min()), rel=1e-12)
        assert c["max"] == pytest.approx(float(st.q[:, i].max()), rel=1e-12)
        assert c["mean_sigma"] == pytest.approx(float(st.sigma_q[:, i].mean()), rel=1e-9)
    assert s["integers_fixed"] == 36
    assert 0 < s["nees"]["mean"] < 3 * s["nees"]["dof"]
    assert data["mac"]["matrix"] and len(data["mac"]["matrix"]) == len(data["mac"]["identified_modes"])
    diag = {m["number"]: m["mac"] for m in data["modes"] if m["mac"] is not None}
    M = np.array(data["mac"]["matrix"])
    for i, k in enumerate(data["mac"]["identified_modes"]):          # the table's MAC is the matrix's diagonal
        j = data["mac"]["model_modes"].index(k)
        assert M[i, j] == pytest.approx(diag[k], abs=1e-9)


def test_same_inputs_same_bytes_whatever_the_chunking(free_run, tmp_path):
    """Blocks of 701 epochs (a divisor of nothing) or the whole record at once: the same bytes."""
    run = read_run(free_run["run"], phase=False)
    for k, chunk in enumerate((100_000, 701)):
        with StatesBlocks(free_run["states"]) as st:
            run_report(st, tmp_path / str(k), run, free_run["truth"], date=DATE, n_bins=300, chunk_epochs=chunk,
                       spectra=False)
    for name in RUN_REPORT_FILES:
        assert (tmp_path / "0" / name).read_bytes() == (tmp_path / "1" / name).read_bytes(), name
    assert "<section id='modes'>" not in (tmp_path / "0" / "index.html").read_text()      # --no-spectra


def test_static_section_reuses_the_static_report(page, free_run):
    from cdgps_cli.report.sensor_reports import static_statistics

    _, _, data = page
    ref = static_statistics(States(free_run["states"], diagnostics=False), read_run(free_run["run"], phase=False),
                            "q6+q10", -5.0)[0]
    for k in ("mean_deg", "error_deg", "noise_rms_deg", "drift_deg_per_min", "start_s", "end_s", "samples"):
        assert data["static"][k] == ref[k], k


def test_bad_input_exits_2_and_writes_nothing(free_run, tmp_path):
    other = tmp_path / "other"
    other.mkdir()
    (other / "truth.json").write_text(json.dumps({"config": "x", "config_sha256": "0" * 64}))
    shutil.copy(free_run["truth"] / "truth.csv", other / "truth.csv")
    cut = tmp_path / "cut"
    cut.mkdir()
    shutil.copy(free_run["truth"] / "truth.json", cut / "truth.json")
    (cut / "truth.csv").write_text("time_s,q1\n0.0,0.0\n")
    cases = {"another config's truth": (["--truth", other], "simulated with config"),
             "a truth without a coordinate": (["--truth", cut], "missing column(s) q2"),
             "an unknown coordinate": (["--angle", "q6+q99"], "q99"),
             "an unknown spectra coordinate": (["--coords", "q2,q42"], "--coords: unknown coordinate(s) q42"),
             "a RUN.mcap as the STATES": (None, "STATES_MCAP")}
    for what, (extra, needle) in cases.items():
        out = tmp_path / what.replace(" ", "_")
        args = ["report", "run", free_run["run"] if extra is None else free_run["states"], "-o", out, "--date", DATE]
        r = CliRunner().invoke(main, [str(a) for a in args + (extra or [])])
        assert r.exit_code == 2, (what, r.output)
        assert needle in r.output and "Traceback" not in r.output, (what, r.output)
        assert not out.exists(), what


def test_states_blocks_refuses_a_run_and_a_missing_file(free_run, tmp_path):
    with pytest.raises(CdgpsError, match="this is a RUN.mcap"):
        StatesBlocks(free_run["run"])
    with pytest.raises(CdgpsError, match="no such file"):
        StatesBlocks(tmp_path / "missing.mcap")


@pytest.fixture(scope="module")
def dof2_run(tmp_path_factory):
    """The 2-dof far-field model (no sections, no gyros), 120 s."""
    return _pipeline(tmp_path_factory.mktemp("dof2"), DOF2, SimOptions(duration_s=120, seed=1))


def test_gyro_log_of_another_structure_is_refused(free_run, dof2_run, tmp_path):
    r = CliRunner().invoke(main, ["report", "run", str(free_run["states"]), "--gyro", str(dof2_run["run"]),
                                  "-o", str(tmp_path / "o"), "--date", DATE])
    assert r.exit_code == 2 and "config" in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "o").exists()


def test_another_structure_without_gyros_gets_every_section(dof2_run, tmp_path):
    with StatesBlocks(dof2_run["states"]) as st:
        d = run_report(st, tmp_path, None, date=DATE, n_bins=200)
    text = (tmp_path / "index.html").read_text()
    for k in ("summary", "time", "consistency", "residuals", "modes"):
        assert f"<section id='{k}'>" in text, k
    assert set(_images(text)) == {"angles", "coordinates", "nis", "residuals", "psd", "fdd", "mac", "shapes"}
    assert "give <code>--truth</code>" in text and d["summary"]["nees"] is None


# ----------------------------------------------------------------------------- in a browser

def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


_PROBE = ("<script>window.addEventListener('load',function(){var m=document.images,b=[];for(var i=0;i<m.length;i++)"
          "{if(!m[i].complete||m[i].naturalWidth===0)b.push(m[i].alt);}var d=document.createElement('pre');"
          "d.id='cdgps-probe';d.textContent=JSON.stringify({images:m.length,broken:b});document.body.appendChild(d);});"
          "</script>")
_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
          "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars"]


def test_page_in_headless_chromium(page, tmp_path):
    browser = _chromium()
    if browser is None:
        pytest.skip("no Chromium on this machine (Debian package chromium)")
    out, text, _ = page
    probe = tmp_path / "probe.html"                       # the page plus a probe that lists broken images
    probe.write_text(text.replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    r = subprocess.run([browser, *_FLAGS, f"--user-data-dir={tmp_path / 'profile1'}", "--enable-logging=stderr",
                        "--v=0", "--virtual-time-budget=5000", "--dump-dom", probe.as_uri()],
                       capture_output=True, text=True, timeout=120)
    m = re.search(r"<pre id=\"cdgps-probe\">([^<]*)</pre>", r.stdout)
    assert m, r.stderr[-2000:]
    seen = json.loads(m.group(1).replace("&quot;", '"'))
    assert seen == {"images": len(_images(text)), "broken": []}
    # no console message of the page itself (errors, warnings, logs)
    assert not [ln for ln in r.stderr.splitlines() if "CONSOLE" in ln], r.stderr[-2000:]
    shot = tmp_path / "index.png"
    subprocess.run([browser, *_FLAGS, f"--user-data-dir={tmp_path / 'profile2'}", "--window-size=1100,1600",
                    f"--screenshot={shot}", (out / "index.html").as_uri()], capture_output=True, timeout=120)
    im = Image.open(shot)
    assert im.size == (1100, 1600)
    assert len(np.unique(np.asarray(im.convert("L").resize((64, 64))))) > 8       # a page was drawn, not a blank


# ----------------------------------------------------------------------------- other kinds of STATES

LEGACY = ROOT / "tests" / "data"


def test_states_of_the_earlier_layouts_get_a_page(tmp_path):
    """Files written before the packed residuals (read whole by States): no residual section, the rest."""
    with StatesBlocks(LEGACY / "format-2026-12-02" / "states.mcap") as st:
        run_report(st, tmp_path / "s", None, date=DATE, n_bins=200, spectra=False)
    text = (tmp_path / "s" / "index.html").read_text()
    assert set(_images(text)) == {"angles", "coordinates", "nis"}
    with StatesBlocks(LEGACY / "format-2026-12-03" / "gnss-states.mcap") as st:
        d = run_report(st, tmp_path / "g", None, date=DATE, n_bins=200)
    text = (tmp_path / "g" / "index.html").read_text()
    assert {"coordinates", "nis"} <= set(_images(text)) and "angles" not in _images(text)
    assert "rover: FIXED (7 of 7 ambiguities fixed" in text                  # fixed/float from the INIT
    assert list(d["summary"]["coordinates"]) == ["rover_e", "rover_n", "rover_u"]


def test_gnss_states_page_has_the_single_epoch_solutions_and_satellites(tmp_path):
    """A GNSS estimate of today's layout: ENU with σ, the single-epoch series, satellites and PDOP."""
    sim, gdir = tmp_path / "sim", tmp_path / "g"
    for args in (["simulate-gnss", "--duration", "120", "--seed", "5", "--random-walk", "0.002", "-o", sim],
                 ["ingest", "--config", sim / "config.toml", "-o", sim / "run.mcap"],
                 ["init", sim / "run.mcap", "-o", sim / "init.json"],
                 ["estimate", sim / "run.mcap", "--init", sim / "init.json", "--smooth", "-o", sim / "states.mcap"],
                 ["report", "run", sim / "states.mcap", "-o", gdir, "--date", DATE]):
        r = CliRunner().invoke(main, ["-q", *map(str, args)])
        assert r.exit_code == 0, (args, r.output)
    text = (gdir / "index.html").read_text()
    assert set(_images(text)) == {"coordinates", "kinematic", "satellites", "nis", "residuals"}
    assert "ambiguities fixed" in text


def test_a_chunk_without_any_nis_value_is_no_error():
    """Fault campaign: `report run` on a 6 s STATES ended in a reshape ValueError (a chunk whose
    epochs have no NIS gave a (0,) block)."""
    from cdgps_cli.report.run_scan import Sums

    s = Sums.zeros(3)
    s.add(np.empty((0, 3)))
    s.add(np.array([[1.0, 2.0, 3.0]]))
    assert s.n.tolist() == [1, 1, 1] and s.mean().tolist() == [1.0, 2.0, 3.0]


def test_report_run_on_a_short_record(tmp_path):
    d = _pipeline(tmp_path, DOF2, SimOptions(duration_s=6, seed=1))
    r = cli(["report", "run", str(d["states"]), "-o", str(tmp_path / "o"), "--date", DATE])
    assert r.exit_code == 0 and (tmp_path / "o" / "index.html").exists(), r.output


@pytest.mark.parametrize("overlap", ["1", "-0.5"])
def test_bad_overlap_is_an_option_error_not_a_page_note(free_run, tmp_path, overlap):
    out = tmp_path / "o"
    r = cli(["report", "run", str(free_run["states"]), "--overlap", overlap, "-o", str(out), "--date", DATE])
    assert r.exit_code == 2 and "--overlap" in r.output and "Traceback" not in r.output, r.output
    assert not out.exists()


@pytest.mark.parametrize("segment_s", ["1e9", "0.001"])
def test_a_segment_the_record_cannot_take_is_an_option_error(free_run, tmp_path, segment_s):
    """A --segment-s the user gave that the record cannot take exits 2 naming the option (it was a
    "No spectra" note on a page that exited 0); only the default segment falls back to the note."""
    out = tmp_path / "o"
    r = cli(["report", "run", str(free_run["states"]), "--segment-s", segment_s, "-o", str(out), "--date", DATE])
    assert r.exit_code == 2 and "--segment-s" in r.output and "Traceback" not in r.output, r.output
    assert not out.exists()


def test_the_provenance_says_inits_window_and_integers_for_both_kinds():
    """The INIT row of the provenance table printed "window ?–? s; ;" for a GNSS INIT (no ``end_s``, no
    ``integer_fixing``): it now says the whole record or the window as given, and each rover's integers."""
    from cdgps_cli.report.run_report import _init_fixing_text, _init_window_text
    assert _init_window_text(None) == _init_window_text({}) == "the whole record"
    assert _init_window_text({"start_s": 1403252400.0, "end_s": 1403252460.5}) == "window 1403252400–1403252460.5 s"
    assert _init_window_text({"start_s": 3600.0, "duration_s": 900.0, "start_gps_s": 1.4e9}) == \
        "window from 3600 s for 900 s"
    assert _init_window_text({"start_s": 60.0, "duration_s": None}) == "window from 60 s to the end"
    assert _init_window_text({"start_s": 60.0, "duration_s": 240.000000238419}) == "window from 60 s for 240 s"
    assert _init_fixing_text({"integer_fixing": "12 of 12 fixed"}) == "12 of 12 fixed"
    assert _init_fixing_text({"rovers": {"r1": {"n_fixed": 8, "n_estimated": 8}, "r2": {"n_fixed": 0, "n_estimated": 5}}}) \
        == "r1: 8 of 8 integers fixed, r2: 0 of 5 integers fixed"


def test_a_nis_outside_its_bound_says_which_way():
    """The summary's pooled NIS outside its bound says which way (a real geodetic pair under the default weights:
    0.031 per dof, "outside" and nothing more).  Below it, it no longer calls the σ "conservative": a sweep found
    static σ 10–20 times below the window-to-window repeatability of a real M8P pair whose NIS was below its bound
    (errors correlated over minutes, which no epoch's NIS sees); it says so."""
    from cdgps_cli.report.run_report import _nis_side_text
    below = _nis_side_text(0.031, 0.944)
    assert "5.7× less" in below and "correlated over minutes" in below and "conservative" not in below
    above = _nis_side_text(3.0, 0.944)
    assert "too small" in above and "correlated" not in above


def test_the_command_row_can_be_typed_again(page):
    """The provenance's command named ``--band-pct``, ``--seen-pct``, ``--min-mac`` and ``--fmax-hz``, which no
    command takes (a sweep ran it: "No such option"): every option it names is one of ``report run``'s, and the
    fixed settings are listed apart."""
    import shlex

    from cdgps_cli.io.provenance import command_line

    prov = page[2]["provenance"]
    words = shlex.split(command_line(prov))
    cmd = main.commands["report"].commands["run"]
    known = {o for p in cmd.params for o in p.opts}
    assert words[:3] == ["cdgps", "report", "run"]
    assert {w for w in words if w.startswith("--")} <= known
    cmd.make_context("run", words[3:] + ["-o", "x"])         # the command line parses (options, values, flags)
    assert set(prov["settings"]) == {"band_pct", "seen_pct", "min_mac", "fmax_hz"}
    assert "settings" in page[1] and "--band-pct" not in page[1]
    # a flag (--no-spectra) is written as the flag alone ("--no-spectra True" could not be typed again)
    flagged = command_line({**prov, "options": {**prov["options"], "--no-spectra": True}})
    cmd.make_context("run", shlex.split(flagged)[3:] + ["-o", "x"])
    assert "--no-spectra True" not in flagged and "--no-spectra" in flagged


def test_a_static_gnss_page_shows_no_none_and_no_rounding_noise(tmp_path):
    """A static GNSS estimate's page said "age_sigma_m_per_s = None", "random_walk_sigma_m_per_sqrt_s = None" and an
    RMS about the mean of "8.232e-08" mm for a constant coordinate: options not set are left out, and the RMS about
    the mean is at most half the range (0 for a constant)."""
    sim, gdir = tmp_path / "sim", tmp_path / "g"
    for args in (["simulate-gnss", "--duration", "60", "--seed", "3", "-o", sim],
                 ["ingest", "--config", sim / "config.toml", "-o", sim / "run.mcap"],
                 ["init", sim / "run.mcap", "-o", sim / "init.json"],
                 ["estimate", sim / "run.mcap", "--init", sim / "init.json", "-o", sim / "states.mcap"],
                 ["report", "run", sim / "states.mcap", "-o", gdir, "--date", DATE]):
        r = CliRunner().invoke(main, ["-q", *map(str, args)])
        assert r.exit_code == 0, (args, r.output)
    text = (gdir / "index.html").read_text()
    assert "= None" not in text and "None;" not in text
    coords = json.loads((gdir / "report.json").read_text())["summary"]["coordinates"]
    assert all(c["rms_about_mean"] == 0.0 for c in coords.values())       # the static model: one value


def test_tables_in_the_provenance_read_as_pairs():
    """The STATES row printed a Python dict, ``{'G:L1': 0.19029367279836487, 'R:G1': None}`` (a sweep of a GPS +
    GLONASS pair): a table is written as pairs, a GLONASS signal's wavelength as one per satellite."""
    from cdgps_cli.io.provenance import _opt_text, value_text
    v = {"G:L1": 0.19029367279836487, "R:G1": None}
    assert value_text(v) == _opt_text(v) == "G:L1 0.190294, R:G1 per satellite"      # one wording in both rows
    assert value_text(["G:L1", "R:G1"]) == "G:L1,R:G1" and value_text(3.0) == "3"
