"""A GNSS ingest reads its receivers' files on two cores (io.gnss_run._read_single_files): the RUN is the
one of reading them in turn, byte for byte, and a bad file is named as in turn (the first given first)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests._shared import can_fork

ROOT = Path(__file__).resolve().parents[2]
GEONET = ROOT / "configs" / "geonet-0759-3040.toml"
RINEX = ROOT.parent / "shared" / "data" / "rinex"

pytestmark = pytest.mark.skipif(not (RINEX / "30400920.05o").exists(), reason="../shared/data/rinex absent")


def _ingest(out: Path, *extra, serial: bool) -> subprocess.CompletedProcess:
    env = {"CDGPS_SERIAL": "1" if serial else "0", "PATH": "/usr/bin:/bin"}
    return subprocess.run([sys.executable, "-c", "from cdgps_cli.cli.commands import main; main()", "-q", "ingest",
                           "--config", str(GEONET), *extra, "-o", str(out)], capture_output=True, text=True, env=env)


@pytest.mark.skipif(not can_fork(), reason="no second core here")
def test_a_run_read_on_two_cores_is_the_run_read_in_turn(tmp_path):
    a, b = _ingest(tmp_path / "two.mcap", serial=False), _ingest(tmp_path / "one.mcap", serial=True)
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    assert (tmp_path / "two.mcap").read_bytes() == (tmp_path / "one.mcap").read_bytes()


@pytest.mark.parametrize("serial", [False, True])
def test_when_both_files_are_bad_the_first_given_is_named(tmp_path, serial):
    bad = []
    for name in ("30400920.05o", "07590920.05o"):
        text = (RINEX / name).read_text().splitlines(keepends=True)
        cut = next(i for i, ln in enumerate(text) if "END OF HEADER" in ln) + 3
        p = tmp_path / name
        p.write_text("".join(text[:cut]) + "this is not an observation line\n" + "".join(text[cut:cut + 40]))
        bad.append(p)
    shutil.copy(RINEX / "30400920.05n", tmp_path)
    r = _ingest(tmp_path / "run.mcap", "--rinex", f"3040={bad[0]}", "--rinex", f"0759={bad[1]}", serial=serial)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "30400920.05o" in r.stderr and "07590920.05o" not in r.stderr, r.stderr
    assert not (tmp_path / "run.mcap").exists()
