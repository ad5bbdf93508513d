"""The batch manifest (cdgps_cli.pipeline.batch): every kind of mistake listed at once with file,
line and column; the stage graph; the equivalent single commands; the weighted trend against numpy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.pipeline import batch as B

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "rx.csv").write_text("x\n")
    (tmp_path / "gyro.csv").write_text("x\n")
    (tmp_path / "run.mcap").write_bytes(b"x")
    (tmp_path / "cfg.toml").write_text(CONFIG.read_text())
    (tmp_path / "broken.toml").write_text("[structure\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "gnss.toml").write_text('[gnss]\nname = "pair"\nmaster = "base"\nnav = ["nav.rnx"]\n'
                                        '[gnss.antennas."base"]\nrinex = "base.rnx"\n'
                                        '[gnss.antennas."rover"]\nrinex = "rover.rnx"\n')
    return tmp_path


def _problems(path) -> list[str]:
    with pytest.raises(CdgpsError) as ei:
        B.read_manifest(path)
    lines = str(ei.value).splitlines()
    assert "problem" in lines[0] and "nothing was run" in lines[0]
    return [ln.strip() for ln in lines[1:]]


def _assert_exactly(problems: list[str], want: list[str]) -> None:
    """Each wanted message begins one of the problems, and there are no others."""
    for w in want:
        assert any(x.startswith(w) for x in problems), f"{w!r} not in:\n" + "\n".join(problems)
    assert len(problems) == len(want), "\n".join(problems)


def test_good_csv_manifest(folder):
    (folder / "m.csv").write_text("session,receiver_csv,gyro_csv,config,time,smooth,stages,init_duration_s\n"
                                  "day1,rx.csv,gyro.csv,cfg.toml,2026-11-01T06:00:00+01:00,yes,,20\n"
                                  "\n# a comment row\n"
                                  "day2,rx.csv,,cfg.toml,,,ingest+init estimate,\n")
    a, b = B.read_manifest(folder / "m.csv")
    assert a.name == "day1" and a.inputs["receiver_csv"] == str(folder / "rx.csv")
    assert a.time == "2026-11-01T05:00:00Z" and a.stages == B.STAGES
    assert a.options["smooth"] is True and a.options["init_duration_s"] == 20.0
    assert b.stages == ("ingest", "init", "estimate") and "gyro_csv" not in b.inputs
    assert b.options == {k: o.default for k, o in B.OPTIONS.items()}
    B.prepare_outdir([a, b], folder / "m.csv", folder / "out")
    assert B.stage_argv(a, "init") == ["init", str(folder / "out/day1/run.mcap"), "--duration", "20",
                                       "-o", str(folder / "out/day1/init.json")]
    assert B.stage_argv(a, "estimate")[-3:] == ["--smooth", "-o", str(folder / "out/day1/states.mcap")]
    assert B.stage_argv(b, "ingest") == ["ingest", str(folder / "rx.csv"), "--config", str(folder / "cfg.toml"),
                                         "-o", str(folder / "out/day2/run.mcap")]


def test_csv_manifest_with_every_kind_of_mistake(folder):
    (folder / "m.csv").write_text(
        "session,receiver_csv,config,run_mcap,smooth,stages,ratio,time,date,biases,colour\n"   # 1: colour unknown
        "ok,rx.csv,cfg.toml,,,,,,,,\n"                                # 2: fine
        "ok,rx.csv,cfg.toml,,,,,,,,\n"                                # 3: duplicate name
        "bad/name,rx.csv,cfg.toml,,,,,,,,\n"                          # 4: not a folder name
        ",rx.csv,cfg.toml,,,,,,,,\n"                                  # 5: no name
        "s6,missing.csv,cfg.toml,,,,,,,,\n"                           # 6: no such file
        "s7,,cfg.toml,,,,,,,,\n"                                      # 7: no input
        "s8,rx.csv,cfg.toml,run.mcap,,,,,,,\n"                        # 8: two inputs
        "s9,rx.csv,,,,,,,,,\n"                                        # 9: no config
        "s10,rx.csv,cfg.toml,,maybe,,nan,yesterday,1 Dec,wobbly,\n"   # 10: five bad values
        "s11,rx.csv,cfg.toml,,,init estimate fly,,,,,\n"              # 11: unknown stage
        "s12,rx.csv,cfg.toml,,,init estimate,,,,,\n"                  # 12: init without ingest
        "s13,,,run.mcap,,ingest init,,,,,\n"                          # 13: ingest of a RUN.mcap
        "s14,rx.csv,broken.toml,,,,,,,,\n"                            # 14: a broken config
        "s15,sub,cfg.toml,,,,,,,,\n"                                  # 15: a folder as a file
        "s16,rx.csv,cfg.toml\n"                                       # 16: too few fields
        "s17,rx.csv,cfg.toml,,,,-1,,,,\n"                            # 17: ratio ≤ 0
        "index.html,rx.csv,cfg.toml,,,,,,,,\n")                      # 18: a name of the batch's own files
    p = _problems(folder / "m.csv")
    m = str(folder / "m.csv")
    want = [f"{m}:1:11: colour: unknown column",
            f"{m}:3:1: session: 'ok' is given twice (first on line 2)",
            f"{m}:4:1: session: 'bad/name' is not a usable folder name",
            f"{m}:5:1: session: missing",
            f"{m}:6:2: receiver_csv: missing.csv: no such file",
            f"{m}:7:2: receiver_csv: missing: give the receiver log",
            f"{m}:8:4: run_mcap: give one of receiver_csv (CSV logs), gnss_config",
            f"{m}:9:3: config: missing: ingesting receiver_csv needs",
            f"{m}:10:5: smooth: expected true or false, got 'maybe'",
            f"{m}:10:7: ratio: expected a finite number (--ratio), got 'nan'",
            f"{m}:10:8: time: expected an ISO 8601",
            f"{m}:10:9: date: expected an ISO date",
            f"{m}:10:10: biases: expected one of fixed, states, got 'wobbly'",
            f"{m}:11:6: stages: unknown stage 'fly'",
            f"{m}:12:6: stages: init needs ingest",
            f"{m}:13:6: stages: ingest with run_mcap",
            f"{m}:14: config: {folder / 'broken.toml'}",
            f"{m}:15:2: receiver_csv: sub: is a folder",
            f"{m}:16: 3 fields where the header has 11",
            f"{m}:17:7: ratio: must be > 0 (--ratio)",
            f"{m}:18:1: session: 'index.html' is the name of a file the batch writes"]
    _assert_exactly(p, want)


def test_gnss_sessions_and_their_mistakes(folder):
    (folder / "m.csv").write_text("session,gnss_config,receiver_csv,gyro_csv,stages,smooth,biases\n"
                                  "g1,gnss.toml,,,,true,\n"                       # 2: fine
                                  "g2,gnss.toml,,,ingest init estimate spectra,,\n"   # 3: spectra
                                  "g3,gnss.toml,,,,,states\n"                     # 4: structure-only option
                                  "g4,gnss.toml,rx.csv,,,,\n"                     # 5: two inputs
                                  "g5,gnss.toml,,gyro.csv,,,\n")                  # 6: gyro with GNSS
    p = _problems(folder / "m.csv")
    m = str(folder / "m.csv")
    want = [f"{m}:3:5: stages: a GNSS session (RINEX/UBX) runs ingest init estimate; spectra are for structure",
            f"{m}:4:7: biases: not for a GNSS session",
            f"{m}:5:2: gnss_config: give one of receiver_csv",
            f"{m}:6:4: gyro_csv: only with receiver_csv (structure logs), not with gnss_config"]
    _assert_exactly(p, want)
    (folder / "m.csv").write_text("session,gnss_config,smooth\ng1,gnss.toml,true\n")
    (g,) = B.read_manifest(folder / "m.csv")
    assert g.kind == "gnss" and g.stages == B.GNSS_STAGES
    B.prepare_outdir([g], folder / "m.csv", folder / "out")
    assert B.stage_argv(g, "ingest") == ["ingest", "--config", str(folder / "gnss.toml"), "-o",
                                         str(folder / "out/g1/run.mcap")]
    assert B.stage_argv(g, "estimate")[-3:] == ["--smooth", "-o", str(folder / "out/g1/states.mcap")]


def test_toml_manifest_and_its_mistakes(folder):
    (folder / "m.toml").write_text(
        '[defaults]\nconfig = "cfg.toml"\nsmooth = true\n\n'
        '[[session]]\nsession = "a"\nreceiver_csv = "rx.csv"\ntime = 2026-11-01T00:00:00Z\n\n'
        '[[session]]\nsession = "b"\nreceiver_csv = "rx.csv"\nsmooth = "often"\n  colour = "red"\n'
        'stages = ["init"]\n')
    p = _problems(folder / "m.toml")
    m = str(folder / "m.toml")
    assert any(x.startswith(f"{m}:13:1: smooth: expected true or false, got 'often'") for x in p), p
    assert any(x.startswith(f"{m}:14:3: colour: unknown key") for x in p), p
    assert any(x.startswith(f"{m}:15:1: stages: init needs ingest") for x in p), p
    assert len(p) == 3, p
    (folder / "m.toml").write_text('[defaults]\nconfig = "cfg.toml"\nsmooth = true\n[[session]]\nsession = "a"\n'
                                   'receiver_csv = "rx.csv"\ntime = 2026-11-01T00:00:00Z\n')
    (s,) = B.read_manifest(folder / "m.toml")
    assert s.options["smooth"] is True and s.time == "2026-11-01T00:00:00Z"
    assert s.inputs["config"] == str(folder / "cfg.toml")
    (folder / "bad.toml").write_text('[[session]]\nsession = "a"\nreceiver_csv = \n')
    (p,) = _problems(folder / "bad.toml")
    assert p.startswith(f"{folder / 'bad.toml'}:3:") and "not valid TOML" in p


def test_options_outside_the_commands_ranges_are_refused_as_the_commands_refuse_them(folder):
    # ratio = 1e308 ran (init never fixes), while 'cdgps init --ratio 1e308' is refused: the manifest
    # checked only finite and > 0, not the flags' plausible ranges (config.limits.OPTION_BOUNDS)
    (folder / "m.toml").write_text(
        '[[session]]\nsession = "a"\nreceiver_csv = "rx.csv"\nconfig = "cfg.toml"\n'
        'ratio = 1e308\ninit_start_s = 1e300\ninit_duration_s = 1e12\ninit_sigma_m = 1e9\n'
        'process_noise_scale = 1e9\nsegment_s = 1e12\n')
    m = str(folder / "m.toml")
    _assert_exactly(_problems(folder / "m.toml"), [
        f"{m}:5:1: ratio: outside the plausible range [1, 1e+12] (--ratio), got 1e+308",
        f"{m}:6:1: init_start_s: outside the plausible range [-1e+10, 1e+10] s (--start)",
        f"{m}:7:1: init_duration_s: outside the plausible range [0, 1e+09] s (--duration)",
        f"{m}:8:1: init_sigma_m: outside the plausible range [1e-06, 100] m (--sigma-m)",
        f"{m}:9:1: process_noise_scale: outside the plausible range (0, 1e+06] (--process-noise-scale)",
        f"{m}:10:1: segment_s: outside the plausible range (0, 1e+09] s (--segment-s)"])
    (folder / "m.toml").write_text('[[session]]\nsession = "a"\nreceiver_csv = "rx.csv"\nconfig = "cfg.toml"\n'
                                   'ratio = 2.5\ninit_start_s = -3\ninit_sigma_m = 0.002\n')
    (s,) = B.read_manifest(folder / "m.toml")
    assert s.options["ratio"] == 2.5 and s.options["init_start_s"] == -3.0


def test_unreadable_manifests(folder):
    for name, text, words in (("m.txt", "x", "a .csv or a .toml"), ("e.csv", "", "empty manifest"),
                              ("h.csv", "session,receiver_csv\n", "no session")):
        (folder / name).write_text(text)
        with pytest.raises(CdgpsError, match=words):
            B.read_manifest(folder / name)
    with pytest.raises(CdgpsError, match="not found"):
        B.read_manifest(folder / "nope.csv")


def test_outdir_of_another_manifest_or_foreign_files_is_refused(folder):
    (folder / "m.csv").write_text("session,run_mcap\na,run.mcap\n")
    (folder / "n.csv").write_text("session,run_mcap\na,run.mcap\n")
    ss = B.read_manifest(folder / "m.csv")
    B.prepare_outdir(ss, folder / "m.csv", folder / "out")
    B.prepare_outdir(ss, folder / "m.csv", folder / "out")          # the same campaign: fine
    with pytest.raises(CdgpsError, match="another batch manifest"):
        B.prepare_outdir(ss, folder / "n.csv", folder / "out")
    (folder / "other").mkdir()
    (folder / "other" / "thesis.tex").write_text("x")
    with pytest.raises(CdgpsError, match="not empty and not a batch output folder"):
        B.prepare_outdir(ss, folder / "m.csv", folder / "other")


def test_cli_bad_manifest_exits_2_without_traceback(folder):
    (folder / "m.csv").write_text("session,receiver_csv,config\na,nope.csv,cfg.toml\nb,rx.csv,nope.toml\n")
    r = CliRunner().invoke(main, ["batch", str(folder / "m.csv"), "-o", str(folder / "out")])
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert "2 problems" in r.output and ":2:2: receiver_csv" in r.output and ":3:3: config" in r.output
    assert not (folder / "out").exists()                # nothing written before the manifest is valid


def test_weighted_trend_matches_numpy_polyfit():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 30, 12))
    sigma = rng.uniform(0.001, 0.004, 12)
    y = 1.2 - 0.0005 * t + rng.normal(0, sigma)
    tr = B.weighted_trend(t, y, sigma)
    (b, a), cov = np.polyfit(t, y, 1, w=1 / sigma, cov="unscaled")
    assert tr["slope_per_day"] == pytest.approx(b, rel=1e-10)
    assert tr["intercept"] == pytest.approx(a, rel=1e-10)
    assert tr["slope_sigma_per_day"] == pytest.approx(np.sqrt(cov[0, 0]), rel=1e-10)
    assert 0.3 < tr["chi2_per_dof"] < 3.0               # noise drawn with the stated σ
    assert B.weighted_trend(t[:2], y[:2], sigma[:2]) is None
