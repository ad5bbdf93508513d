"""The RUN's observation archives in blocks of GPS time (cdgps_cli/io/gnss_archive.py, issue 29 step 1).

The independent check: the blocks joined give the table one archive of the whole table gives (the layout of RUNs
before the blocks, still read), column for column and dtype for dtype; a window gives exactly the rows of the
whole table inside it; a RUN read back whole equals the tables read from its RINEX files; the blocks are read from
disk one at a time, each checked, and a damaged or missing one is named.
"""

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io import gnss_archive
from cdgps_cli.io.gnss_run import RAW_COLUMNS, _DTYPES, _pack_receiver, _raw_table, read_gnss_run
from tests._shared import run_cli


def _contents(attachments: dict):
    return SimpleNamespace(attachment=attachments.__getitem__, has_attachment=attachments.__contains__)


def archived(raw: pd.DataFrame, columns=None, window=None) -> pd.DataFrame:
    """``raw`` written as a RUN's receiver 0 (its blocks) and read back."""
    att = dict(_pack_receiver(SimpleNamespace(raw=raw, signals=None), 0, lambda f, *a: f(*a)))
    return _raw_table(_contents(att), 0, "test", columns, window)


def _raw(rng, t0: float, hours: float, rate_hz: float, sats=("G01", "G05", "G12", "E07")) -> pd.DataFrame:
    t = t0 + np.arange(0.0, hours * 3600.0, 1.0 / rate_hz)
    n_sat = len(sats)
    tt = np.repeat(t, n_sat)
    raw = pd.DataFrame({c: rng.integers(-1, 9, tt.size) for c in RAW_COLUMNS})
    raw["time_gps_s"] = tt
    raw["sat"] = np.tile(np.array(sats, dtype=object), t.size)
    for c in ("phase_cycles", "pseudorange_m", "clock_offset_s"):
        raw[c] = rng.normal(2e7, 1e6, tt.size)
    for c in ("snr_dbhz", "doppler_hz", "cp_std_cycles", "pr_std_m"):
        raw[c] = rng.normal(0.0, 1e3, tt.size).astype(np.float32).astype(np.float64)
    raw.loc[::11, "phase_cycles"] = np.nan
    return raw


def _one_archive(raw: pd.DataFrame, columns=None) -> pd.DataFrame:
    """The table as a RUN before the blocks stored it: one archive of the whole table."""
    att = {"gnss/obs/0.npz.zst": gnss_archive.pack_table(raw, ("sat",), _DTYPES)}
    return _raw_table(_contents(att), 0, "test", columns)


def _same(a: pd.DataFrame, b: pd.DataFrame, rows=None) -> None:
    """``a`` holds ``b``'s columns (``rows``: those rows of them) with their dtypes and values, a stored float32
    column as float32 holds it."""
    assert list(a.columns) == list(b.columns)
    for c in a.columns:
        want = b[c].to_numpy() if rows is None else b[c].to_numpy()[rows]
        if _DTYPES.get(c) == np.float32:
            want = want.astype(np.float32).astype(np.float64)
        assert a[c].dtype == b[c].dtype or (c == "sat" and not len(a)), c    # (no rows: pandas leaves object)
        np.testing.assert_array_equal(a[c].to_numpy(), want, err_msg=c)


def test_blocks_follow_the_hours_of_gps_time():
    t = np.array([3599.0, 3599.5, 3600.0, 7199.9, 7200.0, 7200.0, 20000.0])
    assert gnss_archive.block_bounds(t) == [(0, 2), (2, 4), (4, 6), (6, 7)]
    assert gnss_archive.block_bounds(np.zeros(0)) == [(0, 0)]


@pytest.mark.parametrize("columns", [None, ("time_gps_s", "phase_cycles", "lli")])
def test_the_blocks_joined_are_the_table_of_one_archive(columns):
    raw = _raw(np.random.default_rng(4), 1_400_000_400.0 - 1800.0, 2.6, 1.0)     # 4 blocks, cut mid-hour
    att = dict(_pack_receiver(SimpleNamespace(raw=raw, signals=None), 0, lambda f, *a: f(*a)))
    index = gnss_archive._block_list(_contents(att), "gnss/obs/0", "test")
    hours = np.unique(np.floor(raw["time_gps_s"].to_numpy() / 3600.0))
    assert len(index) == hours.size == 4
    from cdgps_cli.core.gps_time import gps_time_str      # noqa: PLC0415 (each block named by its number and hour)
    assert [n for n, _, _ in index] == [f"gnss/obs/0/{k}_{gps_time_str(h * 3600).replace(' ', 'T')[:13]}h.npz.zst"
                                        for k, h in enumerate(hours)]
    whole = archived(raw, columns)
    _same(whole, _one_archive(raw, columns))
    _same(whole, raw[list(whole.columns)].astype({c: np.int64 for c in whole.columns if raw[c].dtype.kind == "i"}))


def test_a_window_holds_exactly_the_rows_inside_it():
    raw = _raw(np.random.default_rng(5), 1_400_000_000.0, 3.2, 0.5)
    t = raw["time_gps_s"].to_numpy()
    whole = archived(raw)
    rng = np.random.default_rng(6)
    windows = [(t[0], t[-1] + 1), (t[0] - 10, t[0]), (t[-1] + 1, t[-1] + 100), (t[100], t[100]),
               *[tuple(sorted(rng.uniform(t[0] - 100, t[-1] + 100, 2))) for _ in range(12)]]
    for w in windows:
        got = archived(raw, window=w)
        _same(got, whole, (t >= w[0]) & (t < w[1]))


def test_a_run_read_back_whole_and_in_windows(tmp_path):
    """A simulated 1 Hz pair of 2 h across three hour blocks: the RUN's tables are the RINEX files' as read, and a
    window of it is the rows inside it, from the blocks it overlaps only."""
    sim = tmp_path / "sim"
    assert run_cli("-q", "simulate-gnss", "--duration", "7300", "--rate-hz", "0.2", "--seed", "3", "-o", sim).exit_code == 0
    run_path = tmp_path / "run.mcap"
    r = run_cli("-q", "ingest", "--config", sim / "config.toml", "-o", run_path)
    assert r.exit_code == 0, r.output
    from cdgps_cli.io.gnss_run import read_receiver_file     # noqa: PLC0415
    from cdgps_cli.io.mcap import read_mcap                  # noqa: PLC0415

    run = read_gnss_run(run_path)
    for name, f in (("base", "base.rnx"), ("rover", "rover.rnx")):
        _same(run.receivers[name].raw, read_receiver_file(name, "rinex", sim / f).raw)
    c = read_mcap(run_path, topics=[], attachments=lambda n: not n.endswith(".npz.zst"))
    blocks = sorted(n for n in c.attachment_offsets if n.startswith("gnss/obs/0/"))
    assert len(blocks) >= 3 and not any(n in c.attachments for n in blocks)
    t = run.receivers["rover"].raw["time_gps_s"].to_numpy()
    w = (t[0] + 3000.0, t[0] + 3900.0)
    part = read_gnss_run(run_path, window=w)
    keep = (t >= w[0]) & (t < w[1])
    assert 0 < keep.sum() < t.size
    _same(part.receivers["rover"].raw, run.receivers["rover"].raw, keep)
    # only the blocks the window overlaps are decoded (the rover's second hour; the master's with its margin)
    seen = []
    decode = gnss_archive._block_arrays

    def spy(data, what, *a):
        seen.append(what.split(":")[-1])
        return decode(data, what, *a)
    gnss_archive._block_arrays = spy
    try:
        read_gnss_run(run_path, window=(t[0] + 3700.0, t[0] + 3800.0))
    finally:
        gnss_archive._block_arrays = decode
    assert sorted(seen) == ["gnss/obs/0/1_2024-01-01T01h.npz.zst", "gnss/obs/1/1_2024-01-01T01h.npz.zst"], seen
    # a block damaged on disk: exit 2, the file, the block and its hour named, nothing written
    name = "gnss/obs/1/1_2024-01-01T01h.npz.zst"
    offset, length, _ = c.attachment_offsets[name]
    bad = tmp_path / "bad.mcap"
    data = bytearray(run_path.read_bytes())
    data[offset + length // 2] ^= 0x55
    bad.write_bytes(bytes(data))
    r = run_cli("init", bad, "--start", "0", "--duration", "600", "-o", tmp_path / "i.json")
    assert r.exit_code == 2 and "Traceback" not in r.output and not (tmp_path / "i.json").exists()
    assert f"bad.mcap: the MCAP data section fails its CRC check" in r.output and f"attachment '{name}'" in r.output


def test_damaged_or_missing_blocks_are_named(tmp_path):
    raw = _raw(np.random.default_rng(7), 1_400_000_000.0, 2.5, 0.1)
    att = dict(_pack_receiver(SimpleNamespace(raw=raw, signals=None), 0, lambda f, *a: f(*a)))
    names = sorted(n for n in att if n.endswith(".npz.zst"))
    gone = dict(att)
    del gone[names[1]]
    with pytest.raises(CdgpsError, match=rf"{names[1]} missing"):
        _raw_table(_contents(gone), 0, "run.mcap")
    bad = dict(att, **{names[2]: b"not an archive"})
    with pytest.raises(CdgpsError, match=rf"run.mcap:{names[2]}: damaged observation arrays"):
        _raw_table(_contents(bad), 0, "run.mcap")
    bad = dict(att, **{"gnss/obs/0/blocks.json": b"{"})
    with pytest.raises(CdgpsError, match=r"damaged block index gnss/obs/0/blocks.json"):
        _raw_table(_contents(bad), 0, "run.mcap")


def test_a_block_changed_on_disk_after_the_file_was_checked_is_refused(tmp_path):
    """read_mcap checks every byte, then leaves the blocks on disk: one read later is checked again (its CRC)."""
    from cdgps_cli.io.mcap import McapOut, read_mcap       # noqa: PLC0415

    p = tmp_path / "a.mcap"
    with McapOut(p) as out:
        out.attach("keep.json", b"{}", "application/json")
        out.attach("gnss/obs/0/0.npz.zst", b"0123456789" * 50, "application/x-npz+zstd")
    c = read_mcap(p, topics=[], attachments=lambda n: n == "keep.json")
    assert c.attachments == {"keep.json": b"{}"} and c.attachment("gnss/obs/0/0.npz.zst") == b"0123456789" * 50
    data = bytearray(p.read_bytes())
    at = data.index(b"0123456789")
    data[at] ^= 0xFF
    p.write_bytes(bytes(data))
    with pytest.raises(CdgpsError, match=r"attachment 'gnss/obs/0/0.npz.zst' fails its CRC check"):
        c.attachment("gnss/obs/0/0.npz.zst")
