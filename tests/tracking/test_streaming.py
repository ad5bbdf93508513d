"""Issue 29: `cdgps track` and `track-structure` read IF files in blocks of their native sample type
and track them block by block; the results are those of the whole-file path exactly (same arrays,
same output bytes), whatever the block length — also with blocks cut inside a 1 ms update / code period."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.iq_samples import iter_samples, read_samples
from cdgps_cli.pipeline.track import track_file
from cdgps_cli.tracking.acquisition import acquire
from cdgps_cli.tracking.channel import TrackOptions, track
from cdgps_cli.tracking.receiver import BlockTracker, to_baseband, track_all, track_stream
from cdgps_cli.tracking.shared_clock import track_shared_clock

from _track_signals import ca_signal as _signal

ROOT = Path(__file__).resolve().parents[2]
IQ_FILE = ROOT.parent / "shared" / "data" / "if" / "L1_20211202_084700_4MHz_IQ.bin"
needs_if = pytest.mark.skipif(not IQ_FILE.exists(), reason="bundled IF file not present")
FS = 4e6


_ACQUIRED: dict = {}


@pytest.fixture(autouse=True)
def _each_acquisition_once(monkeypatch):
    """The trackers' acquisition (the costly part of these short records: a 10 ms search of 32 PRNs) computed
    once per distinct input: acquire reads only its first noncoherent_ms ms of samples, so those samples
    (bytes and dtype), the rate, the PRNs and the options are the key; equal keys give equal results (a pure
    function), and the copies handed out are fresh.  The whole-array and the block paths, and the tests'
    repeated records, then share one search instead of repeating it (10 searches -> 2 in this file)."""
    import copy
    import hashlib

    from cdgps_cli.tracking import receiver
    from cdgps_cli.tracking.acquisition import NONCOHERENT_MS

    real = receiver.acquire

    def once(samples, fs_hz, prns=range(1, 33), **kw):
        x = np.asarray(samples)[: int(round(fs_hz * 1e-3)) * int(kw.get("noncoherent_ms", NONCOHERENT_MS))]
        key = (x.dtype.str, hashlib.sha256(x.tobytes()).hexdigest(), fs_hz, tuple(prns), tuple(sorted(kw.items())))
        if key not in _ACQUIRED:
            _ACQUIRED[key] = real(samples, fs_hz, list(prns), **kw)
        return copy.deepcopy(_ACQUIRED[key])

    monkeypatch.setattr(receiver, "acquire", once)


def _same_tracks(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for prn in a:
        assert sorted(a[prn]) == sorted(b[prn])
        for k in a[prn]:
            assert np.array_equal(a[prn][k], b[prn][k], equal_nan=True), (prn, k)


@pytest.mark.parametrize("fmt,dtype", [("int8-iq", np.int8), ("int16-iq", "<i2"), ("int8-real", np.int8)])
def test_blocks_are_the_whole_file(tmp_path, fmt, dtype):
    f = tmp_path / "x.bin"
    f.write_bytes(np.random.default_rng(1).integers(-3, 4, 2 * 5003).astype(dtype).tobytes())
    whole = read_samples(f, fmt, "plus")
    for block in (1, 2, 999, 10**6):
        parts = list(iter_samples(f, fmt, "plus", block_samples=block))
        assert all(p.size == block for p in parts[:-1]) and 0 < parts[-1].size <= block
        assert np.array_equal(np.concatenate(parts), whole)
    assert np.array_equal(np.concatenate(list(iter_samples(f, fmt, block_samples=700, max_samples=1500))),
                          read_samples(f, fmt, max_samples=1500))


def test_block_reader_refuses_bad_blocks_and_a_cut_file(tmp_path):
    f = tmp_path / "x.bin"
    f.write_bytes(bytes(4000))
    with pytest.raises(CdgpsError, match="block_samples 0"):
        iter_samples(f, "int8-iq", block_samples=0)
    blocks = iter_samples(f, "int8-iq", block_samples=500)
    next(blocks)
    f.write_bytes(bytes(1500))                                      # cut while it is read
    with pytest.raises(CdgpsError, match="ended after 750 of 2000"):
        list(blocks)


def test_mixing_a_piece_is_mixing_the_whole_array():
    """to_baseband of pieces (any length, 1 included) equals the whole-array expression of the old
    path, ``x * np.exp(…)``, to the last bit (complex and real samples)."""
    g = np.random.default_rng(3)
    for x in (g.integers(-3, 4, 60000) + 1j * g.integers(-3, 4, 60000), g.integers(-3, 4, 60000).astype(float)):
        whole = x * np.exp(-2j * np.pi * 1234.5 * np.arange(x.size) / 2.2e6)
        cuts = np.r_[0, np.cumsum(g.integers(1, 3000, 60)), 50000, 50001, 50003, x.size]
        cuts = np.unique(np.clip(cuts, 0, x.size))
        parts = [to_baseband(x[a:b], 2.2e6, 1234.5, a) for a, b in zip(cuts[:-1], cuts[1:])]
        assert np.array_equal(np.concatenate(parts), whole)


def _pieces(x, g, sizes=(1, 2, 2199, 2201, 3000, 7777)):
    """``x`` cut into pieces of random lengths (1 sample among them; cuts inside 1 ms updates)."""
    out, i = [], 0
    while i < x.size:
        k = int(g.choice(sizes))
        out.append(x[i:i + k])
        i += k
    return out


@pytest.mark.parametrize("shared_clock", [False, True])
def test_block_tracker_equals_whole_array_tracking(shared_clock):
    """Real samples at an IF, aided and unaided channels, independent loops or a shared clock loop:
    fed in pieces of any length the tracker gives the arrays of track / track_shared_clock."""
    fs, if_hz = 2.2e6, 2.5e5
    x, _ = _signal(9, 900.0, 50.0, 48.0, 0.25, seed=5, bits=True, fs=fs)
    real = (x * np.exp(2j * np.pi * if_hz * np.arange(x.size) / fs)).real
    m = x.size // 2200
    aid = 3.0 * np.sin(np.arange(m) * 0.01)
    starts = [(9, 900.0, 50.0), (9, 890.0, 50.2)]
    aids = [aid, None]
    opt = TrackOptions(pll_bn_hz=10.0, pull_in_s=0.02, wide_pll_s=0.03)
    base = real * np.exp(-2j * np.pi * if_hz * np.arange(real.size) / fs)       # the old path's mixing
    if shared_clock:
        ref = track_shared_clock(base, fs, starts, opt, clock_bn_hz=15.0, aids=aids)["tracks"]
    else:
        ref = [track(base, fs, p, d, c, opt, aid_doppler_hz=a) for (p, d, c), a in zip(starts, aids)]
    rx = BlockTracker(fs, starts, opt, n_samples=real.size, if_hz=if_hz, aids=aids,
                      clock_bn_hz=15.0 if shared_clock else None)
    for piece in _pieces(real, np.random.default_rng(2)):
        rx.feed(piece)
    _same_tracks(dict(enumerate(ref)), dict(enumerate(rx.results())))


def test_block_tracker_refuses_a_short_recording():
    rx = BlockTracker(2.2e6, [(9, 0.0, 0.0)], n_samples=22000)
    rx.feed(np.zeros(10000, complex))
    with pytest.raises(CdgpsError, match="4 of the recording's 10 updates"):
        rx.results()


@needs_if
@pytest.mark.parametrize("if_hz", [0.0, 1234.5])
def test_real_file_in_blocks_equals_the_whole_file(if_hz):
    """0.2 s of the real file, blocks of 10,007 samples (2.5 ms: every boundary inside a code period):
    acquisition, summaries and every tracking array equal the whole-array path's exactly."""
    n = 800_000
    ref = track_all(read_samples(IQ_FILE, "int8-iq", max_samples=n), FS, if_hz=if_hz)
    res = track_stream(read_samples(IQ_FILE, "int8-iq", max_samples=40_000),
                       iter_samples(IQ_FILE, "int8-iq", block_samples=10_007, max_samples=n), FS,
                       n_samples=n, if_hz=if_hz)
    assert res["acquisition"] == ref["acquisition"] and res["satellites"] == ref["satellites"]
    assert len(res["tracks"]) >= 4
    _same_tracks(ref["tracks"], res["tracks"])


def _old_track_file(path, out_path, *, n, opt, if_hz=0.0) -> None:
    """`cdgps track` before issue 29: the whole file as complex128, track_all, then TRACK.mcap written
    from the whole arrays (the writer as it was)."""
    import json as _json

    from cdgps_cli import __version__
    from cdgps_cli.io.atomic import file_sha256
    from cdgps_cli.io.mcap import McapOut
    from cdgps_cli.pipeline.track import TRACK_SCHEMA, TRACK_TOPIC

    res = track_all(read_samples(path, "int8-iq", max_samples=n), FS, if_hz=if_hz, opt=opt)
    summary = {"input": str(path), "input_sha256": file_sha256(path), "format": "int8-iq", "iq_sign": "minus",
               "fs_hz": FS, "if_hz": if_hz, "duration_s": n / FS, "cdgps_version": __version__,
               "options": {**(opt or TrackOptions()).__dict__, "noncoherent_ms": 10, "false_alarm": 1e-4},
               "acquisition": res["acquisition"], "satellites": res["satellites"]}
    tracks = res["tracks"]
    prns = sorted(tracks)
    m = min(len(tracks[p]["time_s"]) for p in prns)
    cols = {k: np.stack([tracks[p][k][:m] for p in prns], axis=1)
            for k in ("doppler_hz", "carrier_phase_cycles", "code_phase_chips", "i_prompt", "q_prompt",
                      "cn0_dbhz", "phase_lock")}
    t = tracks[prns[0]]["time_s"][:m]
    with McapOut(out_path) as out:
        ch = out.channel(TRACK_TOPIC, TRACK_SCHEMA, {"prns": ",".join(map(str, prns))})
        for k in range(m):
            out.write(ch, float(t[k]), {"prn": prns, **{c: v[k].tolist() for c, v in cols.items()}})
        out.metadata("track", {key: (v if isinstance(v, str) else _json.dumps(v)) for key, v in summary.items()})


@needs_if
@pytest.mark.parametrize("block,opt,if_hz", [(3_999, None, 0.0), (10_007, None, 1234.5),
                                             (1 << 19, TrackOptions(pll_bn_hz=5.0, pull_in_s=0.13), 0.0)])
def test_track_file_writes_the_bytes_of_the_whole_file_path(tmp_path, block, opt, if_hz):
    """TRACK.mcap streamed window by window (blocks cut inside code periods; a pull-in ending inside a
    window and a PLL that starts late) is byte for byte the old whole-array writer's."""
    n = int(0.15 * FS)
    _old_track_file(IQ_FILE, tmp_path / "old.mcap", n=n, opt=opt, if_hz=if_hz)
    s = track_file(IQ_FILE, tmp_path / "new.mcap", fmt="int8-iq", fs_hz=FS, if_hz=if_hz, duration_s=0.15, opt=opt,
                   block_samples=block)
    assert (tmp_path / "new.mcap").read_bytes() == (tmp_path / "old.mcap").read_bytes()
    assert s["duration_s"] == 0.15 and len(s["satellites"]) >= 4


def test_running_summary_equals_the_whole_array_summary():
    """The summary accumulated over pieces (20 ms windows) equals _summary of the whole arrays, also
    with sign changes across pieces, a PLL start inside a piece and no lock at all."""
    from cdgps_cli.tracking.acquisition import Acquisition
    from cdgps_cli.tracking.receiver import RunningSummary, _summary

    a = Acquisition(prn=9, acquired=True, doppler_hz=900.0, code_phase_chips=50.0, code_phase_samples=0,
                    peak_ratio=3.0)
    x, _ = _signal(9, 900.0, 50.0, 40.0, 0.5, seed=5, bits=True, fs=2.2e6)
    for opt in (TrackOptions(pull_in_s=0.037), TrackOptions(pull_in_s=0.49)):
        r = track(x, 2.2e6, 9, 900.0, 50.0, opt)
        rs = RunningSummary(a)
        for lo in range(0, r["time_s"].size, 60):
            rs.add({k: v[lo:lo + 60] for k, v in r.items()})
        assert rs.result() == _summary(a, r)


def test_track_structure_in_blocks_equals_the_whole_files(tmp_path, dof2_cfg):
    """A simulated structure at an IF, tracked in 3,001-sample blocks (cut inside the 2,200-sample
    updates) and in one block: the same receiver log bytes; and one antenna's tracks equal the old
    whole-file path (read_samples, acquire, mix, track)."""
    from cdgps_cli.pipeline.if_chain import ChainOptions, _track_antenna, read_manifest, track_structure

    cfg_path = ROOT / "configs" / "teague-1995-2dof.toml"
    run = lambda *a: CliRunner().invoke(main, ["-q", *map(str, a)])            # noqa: E731
    assert run("simulate", cfg_path, "--duration", 1, "-o", tmp_path / "sim").exit_code == 0
    r = run("simulate-if", cfg_path, tmp_path / "sim", "--duration", 0.6, "--fs", 2.2e6, "--if", 3e4,
            "-o", tmp_path / "if")
    assert r.exit_code == 0, r.output
    man_path = tmp_path / "if" / "if.json"
    logs = []
    for block in (3_001, 10**9):
        out = tmp_path / f"rx{block}.csv"
        s = track_structure(man_path, dof2_cfg, out, ChainOptions(block_samples=block))
        logs.append((out.read_bytes(), json.dumps(s["antennas"])))
    assert logs[0] == logs[1] and s["rows"] > 0
    man = read_manifest(man_path)
    ant = man["antennas"][0]
    prns = sorted(int(t["prn"]) for t in man["transmitters"])
    got = _track_antenna(man_path.parent / ant["file"], man, prns, ChainOptions(block_samples=3_001),
                         lambda m: None, ant["name"])["tracks"]
    x = read_samples(man_path.parent / ant["file"], "int8-iq", man["iq_sign"])
    fs, if_hz = man["fs_hz"], man["if_hz"]
    found = [a for a in acquire(x, fs, prns, if_hz=if_hz) if a.acquired]
    x = x * np.exp(-2j * np.pi * if_hz * np.arange(x.size) / fs)
    _same_tracks({a.prn: track(x, fs, a.prn, a.doppler_hz, a.code_phase_chips) for a in found}, got)


@needs_if
def test_a_file_cut_while_tracking_leaves_no_output(tmp_path, monkeypatch):
    """An IF file that ends early while it is tracked (after TRACK.mcap was opened): exit 2 naming the
    file, no TRACK.mcap and no temporary left."""
    import cdgps_cli.pipeline.track as track_mod

    f = tmp_path / "if.bin"
    f.write_bytes(IQ_FILE.read_bytes()[: 2 * 400_000])
    real = track_mod.iter_samples

    def cut(*args, **kw):
        for i, blk in enumerate(real(*args, **{**kw, "block_samples": 50_000})):
            if i == 3:
                f.write_bytes(f.read_bytes()[: 2 * 200_000])
            yield blk

    monkeypatch.setattr(track_mod, "iter_samples", cut)
    out = tmp_path / "t.mcap"
    r = CliRunner().invoke(main, ["-q", "track", str(f), "--format", "int8-iq", "--fs", "4e6", "-o", str(out)])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert f"{f}: ended after" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["if.bin"]
