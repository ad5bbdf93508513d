"""Progress output (cdgps_cli/core/progress.py): silent unless enabled, tqdm bars on a terminal, plain
lines elsewhere, stderr only, and never a change in any output; `info` dates and periods."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.core import progress
from cdgps_cli.cli.commands import main
from cdgps_cli.core.time_format import format_period, format_time, median_spacing_s

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"


class _Tty(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def fast_plain(monkeypatch):
    """Plain lines for every stage at every update (the real thresholds are seconds)."""
    monkeypatch.setattr(progress, "PLAIN_MIN_S", 0.0)
    monkeypatch.setattr(progress, "PLAIN_INTERVAL_S", 0.0)
    monkeypatch.setattr(progress, "BAR_DELAY_S", 0.0)
    yield
    progress.configure(enabled=False, stream=None)


def test_disabled_by_default_prints_nothing():
    buf = io.StringIO()
    progress.configure(enabled=False, stream=buf)
    try:
        with progress.bar(10, "work") as b:
            b.update(10)
        assert list(progress.iterate(range(5), "loop")) == [0, 1, 2, 3, 4]
        with progress.stage("stage"):
            pass
        assert buf.getvalue() == ""
    finally:
        progress.configure(stream=None)


def test_plain_lines_when_not_a_terminal(fast_plain):
    buf = io.StringIO()
    progress.configure(enabled=True, stream=buf)
    assert sum(progress.iterate(range(3000), "summing", unit="epoch")) == sum(range(3000))
    text = buf.getvalue()
    assert "\r" not in text and "\x1b" not in text                 # no terminal control in logs
    lines = text.splitlines()
    assert lines[0].startswith("summing: ") and "/3000 epoch)" in lines[0]
    assert lines[-1].startswith("summing: done, 3000 epoch in ")
    assert len(lines) < 1100                                      # refreshed every ~0.1 %, not every item


def test_plain_lines_only_for_long_stages():
    buf = io.StringIO()
    progress.configure(enabled=True, stream=buf)
    try:
        list(progress.iterate(range(1000), "quick"))
        assert buf.getvalue() == ""                                # under PLAIN_MIN_S: nothing
    finally:
        progress.configure(enabled=False, stream=None)


def test_tqdm_bar_on_a_terminal(fast_plain):
    tty = _Tty()
    progress.configure(enabled=True, stream=tty)
    with progress.bar(200, "filter", "epoch") as b:
        for _ in range(200):
            b.update()
    out = tty.getvalue()
    assert "filter" in out and "\r" in out and "/200 " in out     # tqdm: a carriage-return bar, erased after
    progress.write("a message")                                    # no bar open: a plain line
    assert tty.getvalue().endswith("a message\n")


def test_stage_and_close_all(fast_plain):
    buf = io.StringIO()
    progress.configure(enabled=True, stream=buf)
    with progress.stage("smoothing"):
        pass
    assert buf.getvalue().startswith("smoothing: done in ")
    b = progress.bar(5, "left open")
    b.update(2)
    progress.close_all()                 # (before an error message: the work stopped, it is not "done")
    assert b._closed and not progress._active
    assert "left open: done" not in buf.getvalue()


def test_to_csv_in_pieces_is_byte_identical(tmp_path, fast_plain):
    rng = np.random.default_rng(3)
    df = pd.DataFrame({"time_s": np.round(np.arange(1234) * 0.1, 9), "name": ["a1", "a2"] * 617,
                       "x": rng.standard_normal(1234), "snr": np.where(rng.random(1234) < 0.1, np.nan, 40.0)})
    df.to_csv(tmp_path / "one.csv", index=False, lineterminator="\n")
    progress.configure(enabled=True, stream=io.StringIO())
    progress.to_csv(df, tmp_path / "pieces.csv", "writing", rows_per_piece=100, index=False, lineterminator="\n")
    assert (tmp_path / "pieces.csv").read_bytes() == (tmp_path / "one.csv").read_bytes()
    progress.to_csv(df.iloc[:0], tmp_path / "empty.csv", "writing", index=False, lineterminator="\n")
    df.iloc[:0].to_csv(tmp_path / "empty1.csv", index=False, lineterminator="\n")
    assert (tmp_path / "empty.csv").read_bytes() == (tmp_path / "empty1.csv").read_bytes()


def test_counting_reader_counts_every_byte(tmp_path, fast_plain):
    import lzma

    p = tmp_path / "x.csv.xz"
    p.write_bytes(lzma.compress(b"a,b\n" + b"1,2\n" * 5000))
    buf = io.StringIO()
    progress.configure(enabled=True, stream=buf)
    with progress.reading(p) as raw, lzma.open(raw, "rb") as fh:
        df = pd.read_csv(fh)
    assert len(df) == 5000
    assert f"done, {p.stat().st_size} B" in buf.getvalue()


def _chain(tmp_path, monkeypatch, name, pre=()):
    """simulate → ingest → init → estimate (smoothed) → export, in its own folder with the same
    relative paths (INIT.json and STATES.mcap record their inputs' paths); files and streams."""
    d = tmp_path / name
    d.mkdir()
    monkeypatch.chdir(d)
    r = CliRunner()
    steps = [["simulate", str(TESTBED), "--duration", "30", "--seed", "4", "-o", "sim"],
             ["ingest", "sim/receiver.csv", "sim/gyro.csv", "--config", str(TESTBED), "-o", "run.mcap", "--json"],
             ["init", "run.mcap", "-o", "init.json", "--json"],
             ["estimate", "run.mcap", "--init", "init.json", "--smooth", "-o", "states.mcap", "--json"],
             ["export", "states.mcap", "-o", "states.csv", "--json"]]
    stdout, stderr = [], []
    for s in steps:
        res = r.invoke(main, [*pre, *s])
        assert res.exit_code == 0, res.output
        stdout.append(res.stdout)
        stderr.append(res.stderr)
    files = {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}
    return files, stdout, stderr


def test_outputs_identical_with_and_without_progress(tmp_path, monkeypatch, fast_plain):
    quiet, q_out, q_err = _chain(tmp_path, monkeypatch, "quiet", pre=["-q"])
    plain, p_out, p_err = _chain(tmp_path, monkeypatch, "plain")
    progress.configure(stream=_Tty())                # bars on a (fake) terminal
    bars, b_out, _ = _chain(tmp_path, monkeypatch, "tty")
    progress.configure(stream=None)
    assert all(e == "" or all(ln.startswith("cdgps: warning: ") for ln in e.splitlines()) for e in q_err), q_err
    assert any("reading run.mcap" in e for e in p_err) and any("filter: done" in e for e in p_err)
    assert any("writing states.mcap" in e for e in p_err) and any("writing receiver.csv" in e for e in p_err)
    assert any("smoothing: done" in e for e in p_err) and any("reading receiver.csv" in e for e in p_err)
    assert set(quiet) == set(plain) == set(bars) and len(quiet) >= 8
    for f in quiet:
        assert quiet[f] == plain[f] == bars[f], f"{f} differs with progress on"
    assert q_out == p_out == b_out                   # stdout: the JSON summaries only, never progress


# ---------------------------------------------------------------------------------------------- info


def test_median_spacing_of_two_receivers_a_few_ms_apart():
    t = np.arange(120) * 30.0 + 7.96e8
    times = np.r_[t, t + 0.009]
    rx = ["3040"] * 120 + ["0759"] * 120
    order = np.argsort(times, kind="stable")
    assert median_spacing_s(times[order]) == pytest.approx(0.009, abs=1e-6)     # what info printed before
    assert median_spacing_s(times[order], np.array(rx)[order]) == pytest.approx(30.0)
    assert median_spacing_s([5.0, 5.0, 5.0]) is None
    assert median_spacing_s(np.r_[np.arange(10) * 0.1, 100.0]) == pytest.approx(0.1)   # a gap does not matter


def test_time_formats():
    assert format_time(796435200.0, "gps") == "2005-04-02 00:00:00 GPST"
    assert format_time(0.0, "utc") == "1970-01-01 00:00:00 UTC"
    assert format_time(1112400000.5, "utc") == "2005-04-02 00:00:00.500 UTC"
    assert format_time(60.0, "relative") == "60 s"
    assert format_period(30.0) == "30 s" and format_period(0.1) == "0.1 s" and format_period(None) == "-"


def test_info_on_a_gnss_run_prints_dates_and_the_real_period(tmp_path):
    data = ROOT / "tests" / "data"
    r = CliRunner()
    res = r.invoke(main, ["-q", "ingest", "--rinex", f"a={data / '07590920.05o'}", "--nav", str(data / "07590920.05n"),
                          "-o", str(tmp_path / "g.mcap")])
    assert res.exit_code == 0, res.output
    out = r.invoke(main, ["info", str(tmp_path / "g.mcap")]).stdout
    obs = next(line for line in out.splitlines() if "/cdgps/gnss/obs" in line)
    assert "2005-04-02 00:00:00 GPST – 2005-04-02 00:59:30.005 GPST" in obs and "period 30 s" in obs, obs
    assert "e+08" not in out
    js = r.invoke(main, ["info", str(tmp_path / "g.mcap"), "--json"])
    import json

    t = next(x for x in json.loads(js.stdout)["topics"] if x["topic"] == "/cdgps/gnss/obs")
    assert t["time_scale"] == "gps" and t["median_period_s"] == pytest.approx(30.0)


def test_info_on_a_structure_run_prints_run_seconds(tmp_path):
    r = CliRunner()
    assert r.invoke(main, ["-q", "simulate", str(TESTBED), "--duration", "5", "-o", str(tmp_path / "s")]).exit_code == 0
    assert r.invoke(main, ["-q", "ingest", str(tmp_path / "s" / "receiver.csv"), "--config", str(TESTBED),
                           "-o", str(tmp_path / "r.mcap")]).exit_code == 0
    out = r.invoke(main, ["info", str(tmp_path / "r.mcap")]).stdout
    assert "0–5 s  period 0.1 s" in out, out
