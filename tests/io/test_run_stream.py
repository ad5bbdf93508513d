"""``cdgps ingest`` streams the CSV logs (issue 29 item 1) and writes the RUN the whole-record code wrote.

The reference is the writer as it was (tests/io/_run_writer_reference.py: every log read whole,
joined as tables, then written).  For one file per log, for gzip-compressed logs and for a record
in consecutive files (an epoch repeated with the same rows and with other rows, a gap), read in
blocks of a few lines, of a few hundred lines and whole, the RUN is the same file byte for byte
(messages, packed phase arrays, gyro arrays, the channels' lock restarts in the info record) and
the summary the same dict (joins and warnings included).
"""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest

import _run_writer_reference as reference
from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.run import write_run
from cdgps_cli.pipeline.ingest import ChannelCounter, channel_summary
from cdgps_cli.sim.structure import SimOptions, parse_outage, parse_slip, simulate, write_simulation

ROOT = Path(__file__).resolve().parents[2]
CFG = load_config(ROOT / "configs" / "testbed-1998-lumped.toml")
BLOCKS = [400, 30_000, None]          # bytes of CSV text at a time: a few lines, a few hundred, the default
SMALL = 3000                          # (about 40 lines)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    res = simulate(CFG, SimOptions(duration_s=6.0, seed=7, scenario="pulse", random_slips=4,
                                   slips=[parse_slip("a2:PL3:2.0:-2")], outages=[parse_outage("PL6:3:1")]))
    write_simulation(res, d)
    return d


def _both(tmp_path, rx, gyro, act, block):
    new = write_run(CFG, rx, tmp_path / "new.mcap", gyro, act, channel_counter=ChannelCounter, block_bytes=block)
    old = reference.write_run(CFG, rx if isinstance(rx, (str, Path)) else list(rx), tmp_path / "old.mcap", gyro,
                              act if act is None or isinstance(act, (str, Path)) else list(act),
                              channel_summary=channel_summary)
    assert (tmp_path / "new.mcap").read_bytes() == (tmp_path / "old.mcap").read_bytes()
    new.pop("output"), old.pop("output")
    assert new == old
    return new


@pytest.mark.parametrize("block", BLOCKS)
def test_one_file_per_log(sim, tmp_path, block):
    s = _both(tmp_path, sim / "receiver.csv", sim / "gyro.csv", sim / "actuators.csv", block)
    assert s["lock_restarts"] >= 4 and s["gyro_rows"] > 0 and s["actuator_rows"] > 0


@pytest.mark.parametrize("block", [SMALL, None])
def test_compressed_logs(sim, tmp_path, block):
    for name in ("receiver.csv", "gyro.csv"):
        with open(sim / name, "rb") as src, gzip.open(tmp_path / (name + ".gz"), "wb") as dst:
            shutil.copyfileobj(src, dst)
    _both(tmp_path, tmp_path / "receiver.csv.gz", tmp_path / "gyro.csv.gz", None, block)


def _pieces(src: Path, out: Path, stem: str, bounds, repeat_at=None, change=False) -> list[Path]:
    lines = src.read_text().splitlines(keepends=True)
    t = np.array([float(x.split(",", 1)[0]) for x in lines[1:]])
    paths = []
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        rows = [x for x, ti in zip(lines[1:], t) if a <= ti < b]
        if i == 0 and repeat_at is not None:            # the next file's first epoch, here too
            extra = [x for x, ti in zip(lines[1:], t) if ti == repeat_at]
            if change:
                f = extra[0].split(",")
                f[5] = "12.5"
                extra[0] = ",".join(f)
            rows += extra
        p = out / f"{stem}_{i:02d}.csv"
        p.write_text(lines[0] + "".join(rows))
        paths.append(p)
    return paths


@pytest.mark.parametrize("block", [SMALL, None])
@pytest.mark.parametrize("change", [False, True])
def test_consecutive_files(sim, tmp_path, block, change):
    rx = _pieces(sim / "receiver.csv", tmp_path, "rx", [-np.inf, 2.0, 2.5, 4.0, np.inf], repeat_at=2.0, change=change)
    rx[1].unlink()                                      # a gap of 0.5 s
    rx = [rx[2], rx[0], rx[3]]                          # (given out of time order)
    gyro = _pieces(sim / "gyro.csv", tmp_path, "gyro", [-np.inf, 3.0, np.inf])
    s = _both(tmp_path, rx, gyro, sim / "actuators.csv", block)
    rep = s["joins"]["receiver_csv"]
    assert [f["file"] for f in rep["files"]] == ["rx_00.csv", "rx_02.csv", "rx_03.csv"]
    assert rep["gaps"] and rep["overlaps"] == [] and len(s["warnings"]) == 1


@pytest.mark.parametrize("change", [False, True])
def test_repeated_epoch_identical_or_not(sim, tmp_path, change):
    rx = _pieces(sim / "receiver.csv", tmp_path, "rx", [-np.inf, 3.0, np.inf], repeat_at=3.0, change=change)
    s = _both(tmp_path, rx, None, None, SMALL)
    (ov,) = s["joins"]["receiver_csv"]["overlaps"]
    assert ov["identical"] is (not change) and ov["start_s"] == 3.0


def test_files_not_of_one_record_are_refused_naming_them(sim, tmp_path):
    """Interleaved files (epochs inside an earlier file's span that it lacks) and a file of another
    rate are refused as the whole-record join refused them, naming the files, with no output."""
    lines = (sim / "receiver.csv").read_text().splitlines(keepends=True)
    t = np.array([float(x.split(",", 1)[0]) for x in lines[1:]])
    step = np.rint(t * 10).astype(int)
    (tmp_path / "rx_00.csv").write_text(lines[0] + "".join(x for x, k in zip(lines[1:], step) if k % 2 == 0))
    (tmp_path / "rx_01.csv").write_text(lines[0] + "".join(x for x, k in zip(lines[1:], step) if k % 2 == 1))
    last_even = t[step % 2 == 0].max()
    with pytest.raises(CdgpsError, match=rf"rx_01\.csv: epoch 0\.1 s lies inside the span of the earlier file "
                                         rf"rx_00\.csv \(up to {last_even:g} s\), which does not have it"):
        write_run(CFG, [tmp_path / "rx_01.csv", tmp_path / "rx_00.csv"], tmp_path / "a.mcap", block_bytes=SMALL)
    (tmp_path / "rx_00.csv").write_text(lines[0] + "".join(x for x, k in zip(lines[1:], step) if k % 2 == 0 and k < 30))
    (tmp_path / "rx_01.csv").write_text(lines[0] + "".join(x for x, k in zip(lines[1:], step) if k >= 30))
    with pytest.raises(CdgpsError, match=r"rx_00\.csv: epoch interval 0\.2 s differs from 0\.1 s in .*rx_01\.csv"):
        write_run(CFG, [tmp_path / "rx_01.csv", tmp_path / "rx_00.csv"], tmp_path / "a.mcap", block_bytes=SMALL)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rx_00.csv", "rx_01.csv"]
