"""`cdgps info` on a GNSS RUN from its summary and the ingest's info record (gnss/info.json), the observations not
decoded (issue 29 item 3: a 3 h 10 Hz pair took 14 s and 680 MB, every message read).

The independent check: on every kind of GNSS run at hand (a simulated pair with slips, the real u-blox walk log, a
real multi-GNSS RINEX pair with signals, a single receiver), `info --json` answered from the record is byte for
byte `info --deep --json`, which decodes every message and computes the receivers' counts again; a record that
disagrees with the observations is refused by `--deep`; a RUN written before the record is still answered.
"""

import json
import shutil

import pytest

from tests._shared import REPO_ROOT, run_cli

DATA = REPO_ROOT / "tests" / "data"
MATRTKLIB = DATA / "matrtklib-2018-static"


def _runs(tmp_path):
    sim = tmp_path / "sim"
    assert run_cli("-q", "simulate-gnss", "--duration", "300", "--slips", "3", "--seed", "2", "-o", sim).exit_code == 0
    yield "simulated pair", ["--config", sim / "config.toml"]
    yield "one receiver", ["--rinex", f"base={sim / 'base.rnx'}", "--nav", sim / "nav.rnx"]
    one = tmp_path / "one"                # one epoch: no interval (null in the record, "one epoch" in the text)
    assert run_cli("-q", "simulate-gnss", "--duration", "1", "--seed", "2", "-o", one).exit_code == 0
    yield "one epoch", ["--config", one / "config.toml"]
    ubx = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"
    if ubx.is_file():                    # (../shared: CI has it; without it the other runs are checked)
        yield "u-blox log", ["--ubx", f"U={ubx}"]
    cfg = tmp_path / "mg.toml"
    base_xyz = "-3937776.1063, 3354867.8075, 3718445.0835"
    assert run_cli("-q", "config", "--rinex", f"base={MATRTKLIB / 'base_60s.obs.gz'}", "--rinex",
                   f"rover={MATRTKLIB / 'rover_60s.obs.gz'}", "--nav", MATRTKLIB / "base.nav.gz", "--master", "base",
                   "--signals", "G:L1,C:B1I", "-o", cfg).exit_code == 0
    text = cfg.read_text()
    head, tail = text.split('[gnss.antennas."base"]')
    cfg.write_text(head + '[gnss.antennas."base"]'
                   + tail.replace("# position_ecef_m = [x, y, z]", f"position_ecef_m = [{base_xyz}]", 1))
    yield "real multi-GNSS pair with signals", ["--config", cfg]


def test_info_from_the_record_is_info_decoded(tmp_path):
    for what, args in _runs(tmp_path):
        run = tmp_path / f"{what.replace(' ', '_')}.mcap"
        r = run_cli("-q", "ingest", *args, "-o", run)
        assert r.exit_code == 0, (what, r.output)
        fast = run_cli("info", "--json", run)
        deep = run_cli("info", "--deep", "--json", run)
        assert fast.exit_code == deep.exit_code == 0, (what, fast.output, deep.output)
        assert fast.stdout == deep.stdout, what
        s = json.loads(fast.stdout)
        assert "gnss/info.json" in s["attachments"] and s["gnss"]["receivers"], what
        assert "reading" not in fast.stderr, what                # (no message read: no progress of it)
        text = run_cli("info", run)
        assert text.exit_code == 0 and text.output == run_cli("info", "--deep", run).stdout, what


def test_info_answers_without_decoding_the_observations(tmp_path, monkeypatch):
    sim = tmp_path / "sim"
    assert run_cli("-q", "simulate-gnss", "--duration", "60", "--seed", "1", "-o", sim).exit_code == 0
    run = tmp_path / "run.mcap"
    assert run_cli("-q", "ingest", "--config", sim / "config.toml", "-o", run).exit_code == 0
    from cdgps_cli.io import gnss_run        # noqa: PLC0415

    def refuse(*a, **k):
        raise AssertionError("the observations were decoded")
    monkeypatch.setattr(gnss_run, "read_gnss_run", refuse)
    r = run_cli("info", run)
    assert r.exit_code == 0, r.output
    assert "rover: 60 epochs in common with base" in r.output


def test_a_record_that_disagrees_with_the_observations_is_refused_by_deep(tmp_path):
    """The record altered (its CRC made right again, as a tool rewriting the file would): `info` says what the
    record says, `info --deep` decodes the observations and refuses the file."""
    from cdgps_cli.io.mcap import McapOut, read_mcap        # noqa: PLC0415

    sim = tmp_path / "sim"
    assert run_cli("-q", "simulate-gnss", "--duration", "60", "--seed", "1", "-o", sim).exit_code == 0
    run = tmp_path / "run.mcap"
    assert run_cli("-q", "ingest", "--config", sim / "config.toml", "-o", run).exit_code == 0
    c = read_mcap(run)
    rec = json.loads(c.attachments["gnss/info.json"])
    rec["receivers"][1]["slips"] += 7
    bad = tmp_path / "bad.mcap"
    shutil.copy(run, bad)
    from mcap.reader import make_reader      # noqa: PLC0415
    with open(run, "rb") as fh, McapOut(bad, time_scale="gps") as out:
        reader = make_reader(fh)
        summary = reader.get_summary()
        ids = {}
        for cid, ch in summary.channels.items():
            sc = summary.schemas[ch.schema_id]
            ids[cid] = out.channel(ch.topic, json.loads(sc.data), dict(ch.metadata or {}))
        for _, ch, m in reader.iter_messages():
            out.write(ids[ch.id], json.loads(m.data)["time_s"], {k: v for k, v in json.loads(m.data).items()
                                                                   if k not in ("timestamp", "time_s")})
        for a in reader.iter_attachments():
            data = json.dumps(rec).encode() if a.name == "gnss/info.json" else a.data
            out.attach(a.name, data, a.media_type)
        for md in reader.iter_metadata():
            if md.name != "cdgps.info":            # (McapOut writes its own, and each record's checksum)
                out.metadata(md.name, {k: v for k, v in md.metadata.items() if k != "record_sha256"})
    r = run_cli("info", "--json", bad)
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["gnss"]["receivers"][1]["slips"] == rec["receivers"][1]["slips"]
    r = run_cli("info", "--deep", bad)
    assert r.exit_code == 2 and "gnss/info.json record differs from its observations decoded (receivers)" in r.output


def test_a_run_written_before_the_record_is_still_answered():
    old = DATA / "format-2026-12-03" / "gnss-run.mcap"
    r = run_cli("info", "--json", old)
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert "gnss/info.json" not in s["attachments"] and s["gnss"]["receivers"]


def test_epoch_gaps_closed_cases():
    """``info`` said "321 epochs … (sampled at 1 s)" of a u-blox base with 964 epochs missing over 20 min (a sweep):
    each receiver's gaps are counted (spacings over 1.5 intervals), with the epochs they miss and the longest."""
    import numpy as np

    from cdgps_cli.io.gnss_run import gaps_summary
    t = np.array([0.0, 1.0, 2.0, 5.0, 6.0, 18.0, 19.0])
    assert gaps_summary(t, 1.0) == {"count": 2, "missing_epochs": 2 + 11, "longest_s": 12.0}
    assert gaps_summary(np.arange(10.0), 1.0) == {"count": 0, "missing_epochs": 0, "longest_s": 0.0}
    assert gaps_summary(np.array([3.0]), None) is None


def test_info_counts_the_gaps_of_a_receiver(tmp_path):
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s
    from tests._shared import run_cli
    d = tmp_path / "sim"
    assert run_cli("-q", "simulate-gnss", "--duration", "120", "--seed", "2", "-o", d).exit_code == 0
    text = (d / "base.rnx").read_text()
    t0 = float(epoch_times_gps_s(text)[0])
    gone = [(30, 40), (70, 72)]                                            # 10 + 2 epochs missing
    (d / "base.rnx").write_text(edit_rinex3_obs(text, keep=lambda t: not any(a <= round(t - t0) < b for a, b in gone)))
    assert run_cli("-q", "ingest", "--config", d / "config.toml", "-o", d / "run.mcap").exit_code == 0
    r = run_cli("info", d / "run.mcap")
    assert r.exit_code == 0, r.output
    assert "(sampled at 1 s; 2 gaps, 12 epochs missing, the longest 11 s)" in r.output
    assert "(sampled at 1 s; no gap)" in r.output                          # the rover
    deep = run_cli("info", "--deep", "--json", d / "run.mcap")
    assert deep.exit_code == 0 and run_cli("info", "--json", d / "run.mcap").stdout == deep.stdout
