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
