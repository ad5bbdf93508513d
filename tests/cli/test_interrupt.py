"""Ctrl-C (SIGINT, a KeyboardInterrupt in the command) ends every command with exit 130 (128 + SIGINT, as a shell
reports it) and one line on stderr, not click's "Aborted!" with exit 1; no partial output is left (the writers'
``finally`` blocks, docs/hardening.md).  A batch says what it keeps and how to go on."""

from __future__ import annotations

import pytest

import cdgps_cli.pipeline.batch_dask as batch
import cdgps_cli.sim.structure as structure
from cdgps_cli.io.atomic import INTERRUPTED_EXIT
from tests._shared import REPO_ROOT, run_cli

TESTBED = REPO_ROOT / "configs" / "testbed-1998-lumped.toml"


def _interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def test_an_interrupted_command_exits_130_and_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(structure, "write_simulation", _interrupt)
    out = tmp_path / "sim"
    r = run_cli("simulate", TESTBED, "--duration", "5", "-o", out)
    assert r.exit_code == INTERRUPTED_EXIT == 130, r.output
    assert "cdgps: interrupted (Ctrl-C); no partial output left" in r.output and "Aborted" not in r.output
    assert not out.exists() or not any(out.iterdir())


def test_an_interrupted_batch_says_how_to_go_on(tmp_path, monkeypatch):
    monkeypatch.setattr(batch, "run_batch", _interrupt)
    manifest = tmp_path / "m.toml"
    manifest.write_text("")
    r = run_cli("batch", manifest, "-o", tmp_path / "out")
    if r.exit_code == 2:
        pytest.skip(f"the batch command refused the empty manifest before running: {r.output}")
    assert r.exit_code == 130 and "run it again with --resume" in r.output and "Aborted" not in r.output, r.output


def test_integer_resolution_that_cannot_run_is_said_without_a_traceback(tmp_path, monkeypatch):
    """LAMBDA refusing what a solver gave it (a covariance that is not positive definite) is not the user's input,
    but it is said in one line, exit 2, nothing written, rather than with a traceback."""
    from cdgps_cli.core.errors import AmbiguityError
    import cdgps_cli.pipeline.gnss as gnss

    def refuse(*args, **kwargs):
        raise AmbiguityError("Q is not symmetric positive definite (Cholesky factorisation failed)")

    assert run_cli("-q", "simulate-gnss", "--duration", "60", "-o", tmp_path / "sim").exit_code == 0
    assert run_cli("-q", "ingest", "--config", tmp_path / "sim" / "config.toml", "-o", tmp_path / "run.mcap").exit_code == 0
    monkeypatch.setattr(gnss, "solve_static_baseline", refuse)
    r = run_cli("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "integer ambiguity resolution could not run: Q is not symmetric positive definite" in r.output
    assert not (tmp_path / "init.json").exists()
