"""Fixtures shared by the pipeline tests."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main

TOWER = Path(__file__).resolve().parents[2] / "configs" / "gnss-tower.toml"


def _modal_chain(tmp: Path, signals: str, duration_s: float, seed: int):
    """`simulate-gnss-structure --signals` → ingest → init → estimate --smooth → evaluate on the tower;
    (directory, truth.json, init.json, evaluate's JSON)."""
    def run(*args):
        return CliRunner().invoke(main, [str(a) for a in args])

    for args in (("simulate-gnss-structure", TOWER, "--duration", duration_s, "--seed", seed, "--signals", signals,
                  "--out", tmp),
                 ("ingest", "--config", tmp / "config.toml", "-o", tmp / "run.mcap"),
                 ("init", tmp / "run.mcap", "--structure", TOWER, "-o", tmp / "init.json"),
                 ("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "--structure", TOWER, "--smooth",
                  "-o", tmp / "states.mcap")):
        r = run("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    r = run("evaluate", "--truth", tmp, "--estimate", tmp / "states.mcap", "--json", "--converge-s", "20")
    assert r.exit_code == 0, r.output
    return tmp, json.loads((tmp / "truth.json").read_text()), json.loads((tmp / "init.json").read_text()), json.loads(r.stdout)


@pytest.fixture(scope="session")
def gnss_modal_chain():
    """The function running the multi-signal GNSS modal chain (see :func:`_modal_chain`)."""
    return _modal_chain


@pytest.fixture(scope="session")
def gnss_tower() -> Path:
    """configs/gnss-tower.toml."""
    return TOWER
