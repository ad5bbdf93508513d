"""``cdgps init --every S`` (pipeline/gnss_init_windows): a long GNSS record's INITs in one command, each the file
``init --start S --duration D`` writes (the last window: ``--start S`` alone), bit for bit; a window without
observations (a logging gap) skipped and said; bad patterns and options refused before any work, nothing written."""

from __future__ import annotations

import filecmp
import json

import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.pipeline.gnss_init_windows import window_starts
from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s
from tests._shared import run_cli


def _ok(*args):
    r = run_cli(*args)
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A simulated 300 s pair at 1 Hz, ingested; and the same pair with 100–200 s cut out of both receivers."""
    d = tmp_path_factory.mktemp("init_windows")
    _ok("-q", "simulate-gnss", "--duration", "300", "--rate-hz", "1", "--seed", "3", "-o", d / "sim")
    _ok("-q", "ingest", "--config", d / "sim" / "config.toml", "-o", d / "run.mcap")
    t0 = float(epoch_times_gps_s((d / "sim" / "rover.rnx").read_text())[0])
    for f in ("base.rnx", "rover.rnx"):
        text = (d / "sim" / f).read_text()
        (d / "sim" / f).write_text(edit_rinex3_obs(text, keep=lambda t: not 100 <= t - t0 < 200))
    _ok("-q", "ingest", "--config", d / "sim" / "config.toml", "-o", d / "gap.mcap")
    return d


def test_each_windows_init_is_the_one_init_writes_for_that_window(run):
    d = run
    r = _ok("init", d / "run.mcap", "--every", "100", "-o", str(d / "w-{k:02d}.json"), "--json")
    s = json.loads(r.output[r.output.index("{"):])
    assert [w["file"] for w in s["windows"]] == [str(d / f"w-{k:02d}.json") for k in range(3)]
    assert "--init '" + str(d / "w-*.json") + "'" in r.output
    for k, extra in enumerate((("--duration", "100"), ("--duration", "100"), ())):
        _ok("-q", "init", d / "run.mcap", "--start", str(100 * k), *extra, "-o", d / f"m-{k}.json")
        assert filecmp.cmp(d / f"w-{k:02d}.json", d / f"m-{k}.json", shallow=False), k
    _ok("-q", "estimate", d / "run.mcap", "--init", str(d / "w-*.json"), "-o", d / "joined.mcap")


def test_a_window_without_observations_is_skipped_and_said(run):
    d = run
    r = _ok("init", d / "gap.mcap", "--every", "100", "-o", str(d / "g-{k}.json"), "--json")
    s = json.loads(r.output[r.output.index("{"):])
    assert [w["file"] is None for w in s["windows"]] == [False, True, False]
    assert "window 1 (100 s …) skipped" in r.output and "holds no observation" in r.output
    assert not (d / "g-1.json").exists() and (d / "g-0.json").exists() and (d / "g-2.json").exists()


@pytest.mark.parametrize("args, said", [
    (("--every", "100", "-o", "one.json"), "give a pattern with {k}"),
    (("--every", "0", "-o", "w{k}.json"), "--every 0.0: expected a window length"),
    (("--every", "100", "--start", "400", "-o", "w{k}.json"), "--start 400: past the record's end"),
    (("--every", "100", "--sigma-m", "0.01", "-o", "w{k}.json"), "--sigma-m: structure-run option"),
    (("--every", "100", "-o", "w{k}{k}.json", "--structure", "x.toml"), "--every: windows of a GNSS"),
    (("--every", "1e-7", "-o", "w{k}.json"), "at most 10000 (choose a longer window)"),
    (("--every", "100", "-o", "a-{k.foo}.json"), "not a pattern of {k} alone"),
    (("--every", "100", "-o", "b-{k[0]}.json"), "not a pattern of {k} alone"),
])
def test_bad_requests_exit_2_before_any_work_and_write_nothing(run, tmp_path, monkeypatch, args, said):
    monkeypatch.chdir(tmp_path)
    r = run_cli("-q", "init", run / "run.mcap", *args)
    assert r.exit_code == 2 and said in r.output and "Traceback" not in r.output, r.output
    assert not list(tmp_path.iterdir())


def test_an_input_or_a_folder_where_an_init_goes_is_refused_before_any_work(run, tmp_path):
    """A window's file that is the RUN itself (a review overwrote the RUN with ``-o 'w{k}.mcap'``), or a folder where a
    window's file goes (it wrote the first and left temporaries): refused before any work, nothing written."""
    import shutil  # noqa: PLC0415

    shutil.copy(run / "run.mcap", tmp_path / "w0.mcap")
    before = (tmp_path / "w0.mcap").read_bytes()
    r = run_cli("-q", "init", tmp_path / "w0.mcap", "--every", "100", "-o", str(tmp_path / "w{k}.mcap"))
    assert r.exit_code == 2 and "would overwrite an input" in r.output and (tmp_path / "w0.mcap").read_bytes() == before
    (tmp_path / "q1.json").mkdir()
    r = run_cli("-q", "init", run / "run.mcap", "--every", "100", "-o", str(tmp_path / "q{k}.json"))
    assert r.exit_code == 2 and "q1.json is a folder" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["q1.json", "w0.mcap"]


def test_window_starts():
    assert window_starts(300, 100) == [(0.0, 100.0), (100.0, 100.0), (200.0, None)]
    assert window_starts(310, 100) == [(0.0, 100.0), (100.0, 100.0), (200.0, None)]       # a 10 s tail joins
    assert window_starts(340, 100)[-1] == (300.0, None)                                   # a 40 s one is its own
    assert window_starts(300, 100, 50, 120) == [(50, 120)]
    assert window_starts(50, 100) == [(0.0, None)]
    with pytest.raises(CdgpsError, match="--duration -1"):
        window_starts(300, 100, 0, -1)
    starts = [a for a, _ in window_starts(900, 0.1)]                       # k·S, no running sum's drift
    assert starts[-1] == 0.1 * (len(starts) - 1) and starts[3] == 0.1 * 3
