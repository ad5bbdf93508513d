"""A GNSS ingest of RINEX 3 files read block by block of GPS time (issue 29: a day of a 10 Hz pair in bounded memory).

The independent check is the whole-file ingest (every file read at once, as before): the RUN written hour by hour
is the same file, byte for byte, on simulated pairs (GPS L1 and several signals) and on the real mosaic-X5 pair;
the blocks are made a minute long here so that short files cross many of them.  A file the blocks cannot give
exactly (an epoch out of order across blocks, a compressed file, RINEX 2) and a file with an error are read whole:
the same RUN, the same error.
"""

import gzip
import shutil

import pytest

from cdgps_cli.config.structure import load_gnss_config, parse_gnss_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io import gnss_archive, gnss_hours
from cdgps_cli.io.rinex_hours import join_obs_headers, rinex_hours
from cdgps_cli.pipeline import gnss_ingest
from tests._shared import REPO_ROOT, run_cli

BLOCK_S = 60.0
MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
SPIRENT = REPO_ROOT.parent / "shared" / "data" / "rinex-ge"


@pytest.fixture
def minute_blocks(monkeypatch):
    monkeypatch.setattr(gnss_archive, "OBS_BLOCK_S", BLOCK_S)


def _ingest(cfg, out, whole: bool, monkeypatch, **kw) -> tuple[dict, list]:
    """The ingest summary and its progress lines, hour by hour or (``whole``) every file at once."""
    said = []
    with monkeypatch.context() as m:
        if whole:
            m.setattr(gnss_hours, "hourly_inputs", lambda *a, **k: None)
        s = gnss_ingest.ingest_gnss(cfg, out, progress=said.append, **kw)
    return s, said


def _fell_back(said: list) -> bool:
    """Whether the ingest went back to reading the files whole (its progress lines say so)."""
    return any("reading the files whole" in m or "reading them whole" in m for m in said)


def _same_run(cfg, tmp_path, monkeypatch, **kw) -> list:
    s_h, said = _ingest(cfg, tmp_path / "hours.mcap", False, monkeypatch, **kw)
    s_w, _ = _ingest(cfg, tmp_path / "whole.mcap", True, monkeypatch, **kw)
    assert (tmp_path / "hours.mcap").read_bytes() == (tmp_path / "whole.mcap").read_bytes()
    s_h.pop("output"), s_w.pop("output")
    how = s_h.pop("reading")
    assert how["hour_by_hour"] == any("hour by hour" in m for m in said) and not _fell_back(said) or \
        not how["hour_by_hour"] and how["why_whole"]                  # (the summary says how, and why whole)
    assert not s_w.pop("reading")["hour_by_hour"]
    assert s_h == s_w
    return said


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("hours") / "sim"
    assert run_cli("-q", "simulate-gnss", "--duration", "330", "--rate-hz", "2", "--slips", "6", "--seed", "3",
                   "--raw-tags", "-o", d).exit_code == 0
    return d


def test_hour_by_hour_is_the_whole_file_ingest(sim, tmp_path, monkeypatch, minute_blocks):
    said = _same_run(load_gnss_config(sim / "config.toml"), tmp_path, monkeypatch)
    assert any("hour by hour" in m for m in said) and not _fell_back(said)
    idx = __import__("json").loads(__import__("cdgps_cli.io.mcap", fromlist=["x"]).read_mcap(
        tmp_path / "hours.mcap").attachment("gnss/obs/1/blocks.json"))
    assert len(idx["blocks"]) >= 6                   # 330 s in blocks of a minute


def test_blocks_join_to_the_whole_header(sim):
    from cdgps_cli.io.rinex import read_rinex_obs  # noqa: PLC0415

    h = rinex_hours(sim / "rover.rnx", BLOCK_S)
    parts = [read_rinex_obs(h.path, read=h.block_bytes(j)) for j in range(len(h.blocks))]
    h.close()
    whole_info, whole = read_rinex_obs(sim / "rover.rnx")
    assert len(parts) >= 6
    assert join_obs_headers([i for i, _ in parts]) == whole_info
    import pandas as pd  # noqa: PLC0415
    pd.testing.assert_frame_equal(pd.concat([o for _, o in parts], ignore_index=True), whole)


@pytest.mark.skipif(not SPIRENT.is_dir(), reason="needs ../shared/data/rinex-ge")
def test_several_signals_hour_by_hour(tmp_path, monkeypatch, minute_blocks):
    files = {"base": SPIRENT / "Base-static_MO_Spirent.obs", "rover": SPIRENT / "Rover-static-2km-east_MO_Spirent.obs"}
    nav = [SPIRENT / "RINEX_GN_Spirent.23N", SPIRENT / "RINEX_EN_Spirent.23L"]
    said = _same_run(_config(files, nav, ("G:L1", "G:L2", "E:E1", "E:E5a"), tmp_path), tmp_path, monkeypatch,
                     rinex=files, nav_paths=nav)
    assert any("hour by hour" in m for m in said)


def _config(files: dict, nav: list, signals: tuple, tmp_path):
    from cdgps_cli.pipeline.gnss_ingest import starter_gnss_config  # noqa: PLC0415

    text = starter_gnss_config(files, nav_paths=nav, master="base", signals=list(signals))
    return parse_gnss_config(text, str(tmp_path / "c.toml"), base_dir=tmp_path)


@pytest.mark.skipif(not MOSAIC.is_dir(), reason="needs ../shared/data/real-pairs")
def test_real_mosaic_pair_hour_by_hour(tmp_path, monkeypatch, minute_blocks):
    files = {"base": MOSAIC / "base.obs", "rover": MOSAIC / "rover.obs"}
    for signals in (("G:L1",), ("G:L1", "G:L2", "E:E1", "C:B1I")):
        cfg = _config(files, [MOSAIC / "base.nav"], signals, tmp_path)
        said = _same_run(cfg, tmp_path, monkeypatch, rinex=files, nav_paths=[MOSAIC / "base.nav"])
        assert any("hour by hour" in m for m in said)


def _move_epoch(src, dst, k_from: int, k_to: int) -> None:
    """A RINEX 3 file with epoch record ``k_from`` moved before record ``k_to`` (out of time order)."""
    text = src.read_text()
    at = text.index("\n", text.index("END OF HEADER")) + 1
    recs = [">" + r for r in text[at:].split(">")[1:]]
    recs.insert(k_to, recs.pop(k_from))
    dst.write_text(text[:at] + "".join(recs))


def _copy_sim(sim, d, rover_name="rover.rnx"):
    d.mkdir()
    for f in ("base.rnx", "nav.rnx", "config.toml"):
        shutil.copy(sim / f, d / f)
    return d


def test_files_the_blocks_cannot_give_are_read_whole(sim, tmp_path, monkeypatch, minute_blocks):
    d = _copy_sim(sim, tmp_path / "late")
    _move_epoch(sim / "rover.rnx", d / "rover.rnx", 400, 100)       # minute 3's epoch written in minute 0's
    said = _same_run(load_gnss_config(d / "config.toml"), tmp_path, monkeypatch)
    assert any("reading the files whole" in m for m in said)
    z = _copy_sim(sim, tmp_path / "gz")
    (z / "rover.rnx").write_bytes(gzip.compress((sim / "rover.rnx").read_bytes(), mtime=0))
    assert rinex_hours(z / "rover.rnx", BLOCK_S) is None
    said = _same_run(load_gnss_config(z / "config.toml"), tmp_path, monkeypatch)
    assert not any("hour by hour" in m for m in said)
    s, _ = _ingest(load_gnss_config(z / "config.toml"), tmp_path / "gz.mcap", False, monkeypatch)
    assert s["reading"] == {"hour_by_hour": False, "blocks": None, "why_whole": "rover.rnx: compressed"}
    s, _ = _ingest(load_gnss_config(sim / "config.toml"), tmp_path / "sim.mcap", False, monkeypatch)
    assert s["reading"] == {"hour_by_hour": True, "blocks": 6, "why_whole": None}


def test_an_error_in_a_late_block_is_the_whole_file_error(sim, tmp_path, monkeypatch, minute_blocks):
    d = _copy_sim(sim, tmp_path / "bad")
    lines = (sim / "rover.rnx").read_text().splitlines(keepends=True)
    k = [i for i, ln in enumerate(lines) if ln.startswith(">")][500] + 2       # a record line in minute 4
    lines[k] = lines[k][:3] + "  12x45678.123" + lines[k][17:]
    (d / "rover.rnx").write_text("".join(lines))
    cfg = load_gnss_config(d / "config.toml")
    errors = []
    for whole in (False, True):
        with pytest.raises(CdgpsError) as e:
            _ingest(cfg, tmp_path / f"bad-{whole}.mcap", whole, monkeypatch)
        errors.append(str(e.value))
        assert not (tmp_path / f"bad-{whole}.mcap").exists()
    assert errors[0] == errors[1] and f"line {k + 1}:" in errors[0]
    r = run_cli("ingest", "--config", d / "config.toml", "-o", tmp_path / "bad.mcap")
    assert r.exit_code == 2 and "Traceback" not in r.output and str(d / "rover.rnx") in r.output


def test_thin_tables_keep_what_the_checks_read(sim):
    from cdgps_cli.io.gnss_run import read_receiver_file  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    rx = read_receiver_file("rover", "rinex", sim / "rover.rnx")
    thin = gnss_hours.ThinTables()
    half = len(rx.raw) // 2
    thin.add(rx.raw.iloc[half:], None)                  # (satellites met in another order than sorted)
    thin.add(rx.raw.iloc[:half], None)
    t = thin.frame("raw")
    assert list(t["sat"].cat.categories) == sorted(set(rx.raw["sat"]))
    back = np.r_[rx.raw["sat"].to_numpy()[half:], rx.raw["sat"].to_numpy()[:half]]
    assert (t["sat"].to_numpy() == back).all()
    ph = np.r_[rx.raw["phase_cycles"].to_numpy()[half:], rx.raw["phase_cycles"].to_numpy()[:half]]
    assert (np.isfinite(t["phase_cycles"].to_numpy()) == np.isfinite(ph)).all()


def _split(src, dst_dir, cuts: list, drop: tuple = ()) -> list:
    """A RINEX 3 file as consecutive files, cut before the epoch records of ``cuts`` (record numbers); the
    records of ``drop`` (ranges) left out (a gap).  Returns the files, last first (given out of order)."""
    text = src.read_text()
    at = text.index("\n", text.index("END OF HEADER")) + 1
    recs = [">" + r for r in text[at:].split(">")[1:]]
    keep = [i for i in range(len(recs)) if not any(a <= i < b for a, b in drop)]
    edges = [0, *cuts, len(recs)]
    out = []
    for m, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        p = dst_dir / f"{src.stem}_{m}.rnx"
        p.write_text(text[:at] + "".join(recs[i] for i in keep if a <= i < b))
        out.append(p)
    return out[::-1]


def test_consecutive_files_hour_by_hour(sim, tmp_path, monkeypatch, minute_blocks):
    """Hourly files (here cut mid-block, given last first, with a gap between two) join as the whole reading joins
    them: the same RUN, joins and warnings."""
    d = _copy_sim(sim, tmp_path / "pieces")
    base = _split(sim / "base.rnx", d, [150, 333])
    rover = _split(sim / "rover.rnx", d, [97, 400, 520], drop=((380, 400),))
    cfg = load_gnss_config(d / "config.toml")
    files = {"base": base, "rover": rover}
    said = _same_run(cfg, tmp_path, monkeypatch, rinex=files, nav_paths=[d / "nav.rnx"])
    assert any("hour by hour" in m for m in said)
    s, _ = _ingest(cfg, tmp_path / "again.mcap", False, monkeypatch, rinex=files, nav_paths=[d / "nav.rnx"])
    assert len(s["joins"]["rover"]["gaps"]) == 1 and any("gap" in w for w in s["warnings"])
    (tmp_path / "over").mkdir()
    over = _split(sim / "rover.rnx", tmp_path / "over", [300])       # epochs 300 … again: overlaps the last files
    said = _same_run(cfg, tmp_path, monkeypatch, rinex={"base": base, "rover": rover + over[:1]},
                     nav_paths=[d / "nav.rnx"])
    assert any("reading the files whole" in m for m in said) or not any("hour by hour" in m for m in said)


def test_a_file_cut_in_a_value_is_refused_as_whole(sim, tmp_path, monkeypatch, minute_blocks):
    d = _copy_sim(sim, tmp_path / "cut")
    text = (sim / "rover.rnx").read_text()
    (d / "rover.rnx").write_text(text[:text.rstrip("\n").rfind("\n") + 12])      # the last line cut in its first value
    cfg = load_gnss_config(d / "config.toml")
    errors = []
    for whole in (False, True):
        with pytest.raises(CdgpsError, match="ends inside a value") as e:
            _ingest(cfg, tmp_path / f"cut-{whole}.mcap", whole, monkeypatch)
        errors.append(str(e.value))
    assert errors[0] == errors[1] and not list(tmp_path.glob("cut-*.mcap"))


def test_the_checks_on_the_whole_record_refuse_without_reading_again(sim, tmp_path, monkeypatch, minute_blocks):
    """A navigation file of another day: refused by the same check on the thin tables, with the whole reading's
    message, and the files are not read whole for it."""
    d = _copy_sim(sim, tmp_path / "day")
    shutil.copy(sim / "rover.rnx", d / "rover.rnx")
    nav = (sim / "nav.rnx").read_text().splitlines(keepends=True)
    (d / "nav.rnx").write_text("".join(ln[:4] + str(int(ln[4:8]) + 1) + ln[8:] if ln[:1] == "G" and ln[4:8].isdigit()
                                       else ln for ln in nav))                 # every ephemeris a year later
    cfg = load_gnss_config(d / "config.toml")
    out = []
    for whole in (False, True):
        said = []
        with monkeypatch.context() as m:
            if whole:
                m.setattr(gnss_hours, "hourly_inputs", lambda *a, **k: None)
            with pytest.raises(CdgpsError, match="do not cover") as e:
                gnss_ingest.ingest_gnss(cfg, tmp_path / f"day-{whole}.mcap", progress=said.append)
        out.append((str(e.value), said))
    assert out[0][0] == out[1][0]
    assert any("hour by hour" in m for m in out[0][1]) and not _fell_back(out[0][1])


def test_one_epoch_files_and_files_of_one_name(sim, tmp_path, monkeypatch, minute_blocks):
    """A file of one epoch is cut too; files of one name in two folders are named as given."""
    d = _copy_sim(sim, tmp_path / "one")
    (d / "a").mkdir(), (d / "b").mkdir()
    pieces = _split(sim / "rover.rnx", d, [1, 300])[::-1]                        # the first holds one epoch
    names = [d / "a" / "rover.rnx", d / "b" / "rover.rnx", d / "rover_2.rnx"]
    for p, q in zip(pieces, names):
        p.replace(q)
    rover = [f"./{q.relative_to(tmp_path)}" for q in names]
    monkeypatch.chdir(tmp_path)
    cfg = load_gnss_config(d / "config.toml")
    said = _same_run(cfg, tmp_path, monkeypatch, rinex={"base": d / "base.rnx", "rover": rover},
                     nav_paths=[d / "nav.rnx"])
    assert any("hour by hour" in m for m in said) and not _fell_back(said)


def test_a_satellite_written_twice_in_an_epoch_with_signals(sim, tmp_path, monkeypatch, minute_blocks):
    """The signal table keeps a (time, satellite, signal) once, the first record, hour by hour as whole."""
    d = _copy_sim(sim, tmp_path / "twice")
    text = (sim / "rover.rnx").read_text()
    at = text.index("\n", text.index("END OF HEADER")) + 1
    recs = [">" + r for r in text[at:].split(">")[1:]]
    lines = recs[150].splitlines(keepends=True)
    recs[150] = lines[0][:32] + f"{len(lines):3d}" + lines[0][35:] + "".join(lines[1:]) + lines[3]
    (d / "rover.rnx").write_text(text[:at] + "".join(recs))
    cfg = parse_gnss_config((d / "config.toml").read_text().replace("[gnss]\n", '[gnss]\nsignals = ["G:L1"]\n', 1),
                            str(d / "config.toml"), base_dir=d)
    assert any("hour by hour" in m for m in _same_run(cfg, tmp_path, monkeypatch))


def test_a_record_across_a_day_and_a_gps_week(tmp_path, monkeypatch):
    """A record from Saturday 23:30 to Sunday 00:30 GPST (a new day and a new GPS week at midnight), in hour blocks:
    the same RUN hour by hour as whole, its blocks named by the hours of both days."""
    d = tmp_path / "week"
    assert run_cli("-q", "simulate-gnss", "--duration", "3600", "--rate-hz", "0.2", "--seed", "4",
                   "--start", "2024-01-06T23:30:00", "-o", d).exit_code == 0
    said = _same_run(load_gnss_config(d / "config.toml"), tmp_path, monkeypatch)
    assert any("hour by hour" in m for m in said) and not _fell_back(said)
    from cdgps_cli.io.mcap import read_mcap  # noqa: PLC0415
    import json  # noqa: PLC0415

    blocks = json.loads(read_mcap(tmp_path / "hours.mcap").attachment("gnss/obs/1/blocks.json"))["blocks"]
    assert [b["name"].split("_", 1)[1] for b in blocks] == ["2024-01-06T23h.npz.zst", "2024-01-07T00h.npz.zst"]
