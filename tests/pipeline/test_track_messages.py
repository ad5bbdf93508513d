"""``track``'s words on the real IF samples (a sweep): a file read in the wrong format acquires nothing, and the
message named no file; ``--duration`` beyond the file tracked what there was without a word."""

from __future__ import annotations

import json

import pytest

from tests._shared import REPO_ROOT, run_cli

IQ = REPO_ROOT.parent / "shared" / "data" / "if" / "L1_20211202_084700_4MHz_IQ.bin"


@pytest.fixture(autouse=True)
def _needs_the_samples():
    if not IQ.exists():
        pytest.skip("../shared/data/if absent")


def test_nothing_acquired_names_the_file(tmp_path):
    out = tmp_path / "t.mcap"
    r = run_cli("-q", "track", IQ, "--format", "int16-iq", "--fs", "4e6", "-o", out)
    assert r.exit_code == 2 and f"{IQ}: no satellite acquired" in r.output and not out.exists()


def test_a_duration_beyond_the_file_is_said(tmp_path):
    r = run_cli("track", IQ, "--format", "int8-iq", "--fs", "4000000", "--if", "0", "--duration", "5",
                "-o", tmp_path / "t.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert "--duration 5 s:" in r.output and "holds 0.5 s of samples" in r.output
    s = json.loads(r.stdout)
    assert s["duration_s"] == pytest.approx(0.5) and any("holds 0.5 s" in w for w in s["warnings"])
