"""The README's command chains run exactly as a user types them (CLI through files on disk)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.run import read_run


def _cdgps(*args) -> str:
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, f"cdgps {' '.join(map(str, args))} exited {r.exit_code}: {r.output}"
    return r.output


def test_simulate_then_ingest_without_gyros(tmp_path, dof2_path, dof2_cfg, monkeypatch):
    """teague-1995-2dof has no gyros: the simulator's receiver.csv + gyro.csv ingest as they are."""
    assert not dof2_cfg.gyro_names
    monkeypatch.chdir(tmp_path)
    out = _cdgps("simulate", dof2_path, "--duration", 10, "--seed", 1, "--out", "run1")
    assert "no gyros" in out
    assert pd.read_csv("run1/gyro.csv").empty                      # the header, no rows
    out = _cdgps("ingest", "run1/receiver.csv", "run1/gyro.csv", "--config", dof2_path, "-o", "run1/run.mcap")
    assert "header only" in out
    run = read_run("run1/run.mcap")
    assert len(run.gyro) == 0 and len(run.phase) == len(pd.read_csv("run1/receiver.csv"))


def test_header_only_gyro_log_refused_when_the_config_has_gyros(tmp_path, testbed_path):
    _cdgps("simulate", testbed_path, "--duration", 2, "--seed", 1, "--out", tmp_path / "s")
    (tmp_path / "g.csv").write_text("time_s,gyro,rate_rad_s\n")
    r = CliRunner().invoke(main, ["ingest", str(tmp_path / "s/receiver.csv"), str(tmp_path / "g.csv"),
                                  "--config", str(testbed_path), "-o", str(tmp_path / "r.mcap")])
    assert r.exit_code == 2 and "no data rows" in r.output and not (tmp_path / "r.mcap").exists()


README_CHAIN_INTRO = "The same chain as a shell pipeline"
README_CHAIN_START = "cdgps simulate configs/testbed-1998.toml --duration 60"


def readme_chain(readme: str) -> list[str]:
    """The commands of the README's example pipeline: the ```sh block after its introduction."""
    assert README_CHAIN_INTRO in readme, "the README lost its example pipeline"
    block = readme.split(README_CHAIN_INTRO, 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    lines = [ln.strip() for ln in block.splitlines() if ln.strip()]
    assert lines and lines[0].startswith(README_CHAIN_START), lines
    return lines


def test_readme_chain_as_written(tmp_path, repo_root, monkeypatch):
    """The README's pipeline, command by command as printed there (read from README.md, so the
    test follows the README), from a directory holding the configs like a checkout."""
    readme = (repo_root / "README.md").read_text()
    chain = readme_chain(readme)
    assert [ln.split()[1] for ln in chain] == ["simulate", "ingest", "info", "init", "estimate", "evaluate",
                                              "spectra", "report"], chain
    (tmp_path / "configs").symlink_to(repo_root / "configs")
    monkeypatch.chdir(tmp_path)
    outputs = [_cdgps(*line.split()[1:]) for line in chain]
    truth = pd.read_csv("run1/truth.csv")
    # STATES cover every epoch of the 60 s run (the init window from the batch, the filter after it)
    assert "601 epochs (0–60 s; 0–60 s from INIT" in outputs[4]
    # no filter epoch after the window: said in words, never "nan" (the innovation-based σ too)
    assert "nan" not in outputs[4].lower() and "innovation-based estimate none" in outputs[4]
    ev = json.loads(_cdgps("evaluate", "--truth", "run1", "--estimate", "run1/states.mcap", "--json"))
    assert ev["epochs"] == len(truth) == 601
    assert all(np.isfinite(v) and v > 0 for v in ev["rms_error"].values())
    assert "nan" not in outputs[5].lower()
    _cdgps("export", "run1/states.mcap", "--csv", "run1/est.csv")
    est = pd.read_csv("run1/est.csv")
    np.testing.assert_allclose(est["time_s"], truth["time_s"], atol=1e-9)
    names = [c for c in truth.columns if c != "time_s"]               # q1_rad … (units in the names)
    assert names[:2] == ["q1_m", "q2_rad"]
    err = est[names].to_numpy() - truth[names].to_numpy()
    sig = est[["sigma_" + n for n in names]].to_numpy()
    assert np.all(np.isfinite(err)) and np.all(sig > 0)
    # the errors are explained by the states' σ (honest, not inflated): per coordinate the RMS of
    # error/σ lies in [0.5, 1.5] (one 60 s run: its epochs are strongly correlated, so wider than
    # a chi-square band over independent draws), ≥ 99 % of values within 3σ
    ratio = np.sqrt(np.mean((err / sig) ** 2, axis=0))
    assert np.all((ratio > 0.5) & (ratio < 1.5)), dict(zip(names, ratio.round(3)))
    assert np.mean(np.abs(err) <= 3 * sig) >= 0.99
    peaks = json.loads(open("run1/spectra/peaks.json").read())
    assert any(m["seen"] for m in peaks["modes"])


def _short_states(tmp_path, dof2_cfg, N):
    """A hand-made STATES of N epochs (1995 model) and a truth dir."""
    from cdgps_cli.estimation.filter import EstimateResult
    from cdgps_cli.io.mcap import McapOut
    from cdgps_cli.pipeline.estimate_outputs import write_states

    T = dof2_cfg.sample_period_s
    t = np.round(np.arange(N) * T, 9)
    x = np.zeros((N, 4))
    P = np.broadcast_to(np.eye(4) * 1e-4, (N, 4, 4)).copy()
    res = EstimateResult(dof2_cfg, t, x, P, None, None, [("s2", "S1")], np.full((N, 1), np.nan),
                         np.full(N, np.nan), np.zeros(N, dtype=int))
    with McapOut(tmp_path / "run.mcap") as out:               # stand-in RUN: only its ingest record
        out.metadata("cdgps.ingest", {"kind": "structure"})
    write_states(res, tmp_path / "run.mcap", {}, "{}", tmp_path / "st.mcap", {})
    (tmp_path / "truth").mkdir(exist_ok=True)
    pd.DataFrame({"time_s": t, "q1": 0.0, "q2": 0.0}).to_csv(tmp_path / "truth" / "truth.csv", index=False)
    (tmp_path / "truth" / "truth.json").write_text(json.dumps({"config_sha256": dof2_cfg.sha256}))
    return tmp_path / "st.mcap"


def test_too_short_states_are_clear_errors(tmp_path, dof2_cfg):
    st = _short_states(tmp_path, dof2_cfg, 1)
    for args, words in ((["evaluate", "--truth", tmp_path / "truth", "--estimate", st], "too short to evaluate"),
                        (["spectra", st, "-o", tmp_path / "sp"], "too short for spectra")):
        r = CliRunner().invoke(main, [str(a) for a in args])
        assert r.exit_code == 2 and words in r.output and "nan" not in r.output.lower(), r.output
