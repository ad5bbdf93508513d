"""The same log given to two receivers (``--rinex base=F --rinex rover=F``, ``rtk --base F --rover F``): every double
difference is zero and the solution a baseline of zero length.  A sweep of real files found ``rtk``, ``config``,
``ingest`` and ``baseline`` took it without a word.  It is a way to check the processing (the tests' own zero
baselines), so each command goes on, with a warning naming the file (a link to it too)."""

from __future__ import annotations

import json

import pytest

from cdgps_cli.io.log_sequence import one_file_for_two_receivers
from tests._shared import run_cli


def test_the_rule(tmp_path):
    a, b = tmp_path / "a.obs", tmp_path / "b.obs"
    a.write_text("x")
    b.write_text("x")                               # equal bytes, two files: two receivers' logs may be equal
    assert one_file_for_two_receivers({"base": [str(a)], "rover": [str(b)]}) == []
    assert one_file_for_two_receivers({"base": [str(a), str(a)]}) == []      # (one receiver's repeats: join_tables's)
    assert one_file_for_two_receivers({"base": [str(tmp_path / "no.obs")], "rover": [str(tmp_path / "no.obs")]}) == []
    link = tmp_path / "link.obs"
    link.symlink_to(a)
    (w,) = one_file_for_two_receivers({"base": [str(a)], "rover": [str(a)]})
    assert w.startswith(f"{a}: given for two receivers (base and rover): every double difference is zero")
    (w,) = one_file_for_two_receivers({"base": [str(a)], "rover": [str(b), str(link)]})
    assert w.startswith(f"{link} (the file {a} under another name): given for two receivers (base and rover)")


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    r = run_cli("-q", "simulate-gnss", "--duration", "30", "--seed", "2", "-o", d)
    assert r.exit_code == 0, r.output
    return d


@pytest.mark.parametrize("command", ["config", "ingest", "baseline"])
def test_config_ingest_and_baseline_say_so(sim, tmp_path, command):
    out = tmp_path / {"config": "c.toml", "ingest": "run.mcap", "baseline": "b.json"}[command]
    r = run_cli(command, "--rinex", f"base={sim / 'rover.rnx'}", "--rinex", f"rover={sim / 'rover.rnx'}",
                "--nav", sim / "nav.rnx", "--master", "base", "-o", out)
    assert r.exit_code == 0, r.output
    assert "rover.rnx: given for two receivers (--rinex base and --rinex rover): every double difference" in r.output
    assert out.exists()


def test_rtk_says_so(sim, tmp_path):
    out = tmp_path / "x.pos"
    r = run_cli("rtk", "--base", sim / "base.rnx", "--rover", sim / "base.rnx", "--nav", sim / "nav.rnx", "-o", out,
                "--json")
    assert r.exit_code == 0, r.output
    assert "base.rnx: given for two receivers (--base and --rover)" in r.output
    assert any("given for two receivers" in w for w in json.loads(r.stdout)["warnings"])
