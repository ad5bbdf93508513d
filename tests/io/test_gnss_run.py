"""GNSS run configs, `cdgps ingest --rinex/--ubx/--nav`, `cdgps info`, `cdgps config`, bad inputs,
u-blox lock-time slips, and every real file of ../shared/data (ingested or refused with a reason).
"""

from __future__ import annotations

import fnmatch
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import config_kind, load_gnss_config, parse_gnss_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.baseline import BaselineOptions
from cdgps_cli.io.gnss_run import GnssReceiver, RAW_COLUMNS, read_gnss_run, read_receiver_file
from cdgps_cli.pipeline.gnss_ingest import lock_summary, processing_obs
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.rinex import read_rinex_obs

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
SHARED = ROOT.parent / "shared" / "data"
GEONET = ROOT / "configs" / "geonet-0759-3040.toml"
UBX_EXAMPLE = ROOT / "configs" / "ubx-example.toml"


def shared(rel: str) -> Path:
    p = SHARED / rel
    if not p.exists():
        pytest.skip(f"shared test data not available: {p} (the ../shared/data folder beside the repository)")
    return p


def run_cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def simdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    r = run_cli("-q", "simulate-gnss", "--duration", "300", "--seed", "2", "--slips", "3", "--out", d)
    assert r.exit_code == 0, r.output
    return d


# ----------------------------------------------------------------------------------------------
# config


def test_config_validation_lists_every_problem_with_its_key():
    text = """
[gnss]
master = "a"
mask_deg = 95
ratio = 0.5
weighting = "snr"
colour = 1
[gnss.displacement]
model = "wobbly"
sigma_m_per_sqrt_s = [1, 2]
[gnss.antennas.b]
rinex = "b.o"
ubx = "b.ubx"
position_ecef_m = [1, 2, 3]
speed = 2
"""
    with pytest.raises(CdgpsError) as e:
        parse_gnss_config(text, "bad.toml")
    msg = str(e.value)
    for key in ("gnss.colour", "gnss.mask_deg", "gnss.ratio", "gnss.weighting", "gnss.displacement.model",
                "gnss.displacement.sigma_m_per_sqrt_s", "gnss.antennas.b:", "gnss.antennas.b.position_ecef_m",
                "gnss.antennas.b.speed", "gnss.master"):
        assert key in msg, (key, msg)
    assert msg.startswith("bad.toml: invalid GNSS config: 10 problems")
    with pytest.raises(CdgpsError, match=r"baseline: unknown top-level key.*'cdgps baseline' reads it"):
        parse_gnss_config('[baseline]\nmaster = "a"\n', "old.toml")
    with pytest.raises(CdgpsError, match="only used with model = \"random_walk\""):
        parse_gnss_config('[gnss]\n[gnss.displacement]\nsigma_m_per_sqrt_s = 0.1\n')


def test_geonet_config_loads_for_both_commands():
    cfg = load_gnss_config(GEONET)
    assert cfg.master == "3040" and cfg.antenna_names == ("3040", "0759") and len(cfg.nav) == 2
    assert cfg.displacement == "static" and cfg.mask_deg == 15.0 and cfg.ratio == 3.0
    assert cfg.antenna("0759").rinex.endswith("07590920.05o") and Path(cfg.antenna("0759").rinex).is_absolute()
    assert config_kind(GEONET.read_text()) == "gnss" and config_kind((ROOT / "configs" / "testbed-1998-lumped.toml").read_text()) == "structure"
    opt = BaselineOptions.from_gnss_config(cfg)
    assert opt.ratio_threshold == 3.0 and opt.motion == "static"
    rw = parse_gnss_config('[gnss]\nmaster = "a"\n[gnss.displacement]\nmodel = "random_walk"\nsigma_m_per_sqrt_s = [0.001, 0.001, 0.002]\n')
    assert rw.random_walk_sigma == (0.001, 0.001, 0.002) and BaselineOptions.from_gnss_config(rw).motion == "random_walk"


# ----------------------------------------------------------------------------------------------
# ingest and info


def test_ingest_simulated_pair_round_trip(simdir, tmp_path):
    out = tmp_path / "run.mcap"
    r = run_cli("ingest", "--config", simdir / "config.toml", "-o", out, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["kind"] == "gnss" and s["master"] == "base" and [x["name"] for x in s["receivers"]] == ["base", "rover"]
    assert s["common_epochs"]["rover"]["common_epochs"] == 300 and s["ephemerides"] > 0 and not s["warnings"]
    run = read_gnss_run(out)
    assert run.master == "base" and run.rovers == ["rover"] and run.cfg.name == "simulated-base-rover"
    # the raw observations come back as recorded in the RINEX file
    for n in ("base", "rover"):
        _, o = read_rinex_obs(simdir / f"{n}.rnx")
        raw = run.receivers[n].raw
        assert list(raw.columns) == list(RAW_COLUMNS)
        np.testing.assert_array_equal(raw["phase_cycles"].to_numpy(), o["phase_l1_cycles"].to_numpy())
        np.testing.assert_array_equal(raw["time_gps_s"].to_numpy(), o["time_gps_s"].to_numpy())
        np.testing.assert_array_equal(raw["lli"].to_numpy(), o["lli_l1"].to_numpy())
        assert (raw["lock_time_ms"] == -1).all()
    # the MCAP file: messages per receiver epoch, ephemerides, attachments, metadata with sha256
    c = read_mcap(out)
    assert len(c.topics["/cdgps/gnss/obs"]) == 600 and len(c.topics["/cdgps/gnss/ephemeris"]) == len(run.nav)
    assert {"config.toml", "gnss/receivers.json", "gnss/ephemeris.json"} <= set(c.attachments)
    md = c.metadata["cdgps.ingest"]
    assert md["kind"] == "gnss" and len(md["rinex:rover_sha256"]) == 64 and md["nav[0]"] == "nav.rnx"
    # info
    r = run_cli("info", out)
    assert r.exit_code == 0, r.output
    assert "GNSS run: config simulated-base-rover" in r.stdout and "rover: 300 epochs in common with base" in r.stdout
    info = json.loads(run_cli("info", out, "--json").stdout)
    rov = next(x for x in info["gnss"]["receivers"] if x["name"] == "rover")
    truth = json.loads((simdir / "truth.json").read_text())
    n_slips = sum(1 for x in truth["cycle_slips"] if x["receiver"] == "rover"
                  and any(a["kind"] == "slip" and a["sat"] == x["sat"] and a["receiver"] == "rover" for a in truth["ambiguities"]))
    assert rov["slips"] == n_slips and info["gnss"]["coordinates"] == ["rover_e", "rover_n", "rover_u"]


def test_obs_messages_made_a_block_at_a_time_are_the_same_file(simdir, tmp_path, monkeypatch):
    """The observation messages' rows become Python lists a block of messages at a time (issue 29:
    the lists of a whole day took ~0.5 GB); blocks of 5 messages, cut anywhere between the two
    receivers' interleaved epochs, give the same RUN as one block."""
    import cdgps_cli.io.gnss_run as gnss_run

    r = run_cli("-q", "ingest", "--config", simdir / "config.toml", "-o", tmp_path / "one.mcap")
    assert r.exit_code == 0, r.output
    monkeypatch.setattr(gnss_run, "_OBS_MESSAGES_PER_BLOCK", 5)
    r = run_cli("-q", "ingest", "--config", simdir / "config.toml", "-o", tmp_path / "blocks.mcap")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "one.mcap").read_bytes() == (tmp_path / "blocks.mcap").read_bytes()


def test_ingest_from_command_line_without_config(simdir, tmp_path):
    out = tmp_path / "cli.mcap"
    r = run_cli("-q", "ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--rinex", f"r={simdir / 'rover.rnx'}",
                "--nav", simdir / "nav.rnx", "--master", "m", "-o", out)
    assert r.exit_code == 0, r.output
    run = read_gnss_run(out)
    assert run.master == "m" and run.rovers == ["r"] and run.cfg.displacement == "static"
    assert [p.name for p in tmp_path.iterdir()] == ["cli.mcap"]


def test_csv_and_gnss_inputs_cannot_be_mixed(simdir, tmp_path):
    r = run_cli("ingest", "receiver.csv", "--rinex", f"m={simdir / 'base.rnx'}", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and "cannot be mixed" in r.stderr
    r = run_cli("ingest", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and "RECEIVER_CSV" in r.output


def test_geonet_ingest_and_info(tmp_path):
    shared("rinex/30400920.05o")
    out = tmp_path / "geonet.mcap"
    r = run_cli("ingest", "--config", GEONET, "-o", out)
    assert r.exit_code == 0, r.output
    assert "3040     rinex 30400920.05o: 120 epochs" in r.stderr and "0759: 120 epochs in common with 3040" in r.stderr
    info = json.loads(run_cli("info", out, "--json").stdout)["gnss"]
    g = {x["name"]: x for x in info["receivers"]}
    assert g["0759"]["slips"] == 7 and g["3040"]["slips"] == 3           # the real LLI = 1 flags of low satellites
    assert g["3040"]["position_source"] == "RINEX header APPROX POSITION XYZ"
    assert info["ephemerides"] == 164 and info["config"]["name"] == "geonet-0759-3040"


def test_starter_config_command(tmp_path):
    obs = [shared("rinex/30400920.05o"), shared("rinex/07590920.05o")]
    out = tmp_path / "cfg" / "job.toml"
    r = run_cli("config", "--rinex", f"3040={obs[0]}", "--rinex", f"0759={obs[1]}", "--nav",
                shared("rinex/30400920.05n"), "--displacement", "random_walk", "--sigma", "0.002", "-o", out)
    assert r.exit_code == 0, r.output
    text = out.read_text()
    assert "TRIMBLE 5700" in text and "header position (-3978242.4348" in text
    cfg = load_gnss_config(out)
    assert cfg.master == "3040" and cfg.displacement == "random_walk" and cfg.random_walk_sigma == (0.002,) * 3
    assert Path(cfg.antenna("3040").rinex).resolve() == obs[0].resolve()
    # 'cdgps baseline --config' reads it too; baseline-config writes the same format
    from cdgps_cli.pipeline.baseline_job import load_baseline_job

    assert load_baseline_job(out)["master"] == "3040"
    r = run_cli("config", "--rinex", f"a={obs[0]}", "--sigma", "0.1", "-o", tmp_path / "x.toml")
    assert r.exit_code == 2 and "--displacement random_walk" in r.stderr


# ----------------------------------------------------------------------------------------------
# u-blox: lock times and half-cycle flags → slips


def _ubx_receiver(lock, half, t=None):
    n = len(lock)
    t = np.arange(n, dtype=float) if t is None else np.asarray(t, dtype=float)
    raw = pd.DataFrame({
        "time_gps_s": t, "sat": "G05", "phase_cycles": 1000.0 + np.arange(n), "pseudorange_m": 2e7,
        "snr_dbhz": 40.0, "doppler_hz": 0.0, "lli": -1, "ssi": 0, "half_cycle": np.asarray(half, dtype=int),
        "sub_half": 0, "lock_time_ms": np.asarray(lock, dtype=np.int64), "cp_std_cycles": 0.01, "pr_std_m": 0.5,
        "epoch_flag": 0, "clock_offset_s": np.nan, "clock_reset": 0}, columns=list(RAW_COLUMNS))
    return GnssReceiver("u", "ubx", "u.ubx", {}, raw, {})


def test_ubx_lock_time_restarts_and_half_cycles_become_lli():
    # grows 1 s per epoch; restart at row 3; capped at 64.5 s (no slip); restart during a gap at row 8
    lock = [5000, 6000, 7000, 200, 1200, 64500, 64500, 64500, 3000]
    t = [0, 1, 2, 3, 4, 5, 6, 7, 12]
    rx = _ubx_receiver(lock, [0] * 9, t)
    lli = processing_obs(rx, interval_s=1.0)["lli_l1"].to_numpy()
    np.testing.assert_array_equal(lli & 1, [0, 0, 0, 1, 0, 0, 0, 0, 1])
    # a gap with continuous lock (lock grew by the gap) is no slip
    rx = _ubx_receiver([1000, 2000, 7000], [0, 0, 0], [0, 1, 6])
    np.testing.assert_array_equal(processing_obs(rx, interval_s=1.0)["lli_l1"].to_numpy(), [0, 0, 0])
    # half cycle unresolved → bit 1; becoming resolved → new ambiguity (bit 0)
    rx = _ubx_receiver([1000, 2000, 3000, 4000], [1, 1, 0, 0])
    np.testing.assert_array_equal(processing_obs(rx, interval_s=1.0)["lli_l1"].to_numpy(), [2, 2, 1, 0])
    assert lock_summary(rx)["G05"] == {"rows": 4, "slips": 1, "half_cycle_rows": 2, "arcs": 2}


def test_real_ubx_rawx_log_and_example_config(tmp_path):
    log = shared("ubx/pygpsdata-RXMRAWX.log")
    rx = read_receiver_file("u", "ubx", log)
    o = processing_obs(rx)
    assert len(o) == 56 and (o["lli_l1"] == 0).all()               # lock times grow steadily: no slip
    out = tmp_path / "ubx.mcap"
    r = run_cli("ingest", "--config", UBX_EXAMPLE, "-o", out)
    assert r.exit_code == 0, r.output
    assert "14 epochs" in r.stderr and "no navigation file" in r.stderr
    run = read_gnss_run(out)
    assert run.master == "ublox" and run.receivers["ublox"].format == "ubx"
    assert (run.receivers["ublox"].raw["lock_time_ms"] >= 41440).all()
    r = run_cli("init", out, "-o", tmp_path / "i.json")
    assert r.exit_code == 2 and "no broadcast ephemerides" in r.stderr and not (tmp_path / "i.json").exists()


# ----------------------------------------------------------------------------------------------
# bad inputs: clear errors (file + what), exit code 2, nothing left behind

def _no_output(tmp_path, name="o.mcap"):
    return not (tmp_path / name).exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_obs_without_carrier_phase(simdir, tmp_path):
    txt = (simdir / "rover.rnx").read_text().replace("G    3 C1C L1C S1C", "G    3 C1C D1C S1C")
    (tmp_path / "nophase.rnx").write_text(txt)
    r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--rinex", f"r={tmp_path / 'nophase.rnx'}",
                "--nav", simdir / "nav.rnx", "--master", "m", "-o", tmp_path / "o.mcap")
    assert r.exit_code == 2 and "nophase.rnx" in r.stderr and "no GPS L1 carrier-phase observation type" in r.stderr
    # an L1 phase column that is empty everywhere
    lines = (simdir / "rover.rnx").read_text().split("\n")
    body = [ln[:19] + " " * 14 + ln[33:] if ln.startswith("G") else ln for ln in lines]
    (tmp_path / "empty.rnx").write_text("\n".join(body))
    r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--rinex", f"r={tmp_path / 'empty.rnx'}",
                "--master", "m", "-o", tmp_path / "o.mcap")
    assert r.exit_code == 2 and "empty.rnx: no GPS L1 carrier-phase observations" in r.stderr
    assert _no_output(tmp_path)


def test_obs_with_phase_but_no_pseudorange_warns_at_ingest(simdir, tmp_path):
    """L1 phase without C1: ingested with a warning naming the file (init needs the pseudoranges)."""
    text = (simdir / "rover.rnx").read_text()
    head, body = text.split("END OF HEADER", 1)
    body = body.split("\n")
    (tmp_path / "nocode.rnx").write_text(head.replace("G    3 C1C L1C S1C", "G    2 L1C S1C    ") + "END OF HEADER"
                                         + "\n".join(ln[:3] + ln[19:] if ln.startswith("G") else ln for ln in body))
    (tmp_path / "blankcode.rnx").write_text(head + "END OF HEADER" + "\n".join(
        ln[:3] + " " * 16 + ln[19:] if ln.startswith("G") else ln for ln in body))
    for f, what in (("nocode.rnx", "no GPS L1 pseudorange observation type"), ("blankcode.rnx", "column (C1C) is empty")):
        out = tmp_path / f"{f}.mcap"
        r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--rinex", f"r={tmp_path / f}",
                    "--nav", simdir / "nav.rnx", "--master", "m", "-o", out, "--json")
        assert r.exit_code == 0, r.output
        _, o = read_rinex_obs(tmp_path / f)
        assert o["pseudorange_l1_m"].isna().all() and o["phase_l1_cycles"].notna().all()
        warn = [w for w in json.loads(r.stdout)["warnings"] if "pseudorange" in w]
        assert len(warn) == 1 and warn[0].startswith(f"r ({tmp_path / f}): L1 carrier phase but no L1 pseudoranges")
        assert what in warn[0] and "'cdgps init' needs" in warn[0]
        assert "warning: r (" in r.stderr and f in r.stderr                 # on stderr, like the other warnings
        r = run_cli("init", out, "-o", tmp_path / "i.json")
        assert r.exit_code == 2 and "no L1 pseudoranges" in r.stderr
    # the master's complete file gives no such warning
    r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--nav", simdir / "nav.rnx", "-o", tmp_path / "ok.mcap",
                "--json")
    assert r.exit_code == 0 and not any("pseudorange" in w for w in json.loads(r.stdout)["warnings"])


def test_nav_not_covering_the_observations(simdir, tmp_path):
    r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--rinex", f"r={simdir / 'rover.rnx'}",
                "--nav", DATA / "brdc1820_subset.10n", "--master", "m", "-o", tmp_path / "o.mcap")
    assert r.exit_code == 2, r.output
    assert "navigation data do not cover the observations of m" in r.stderr and "2010-07-01" in r.stderr
    assert _no_output(tmp_path)


def test_mismatched_epochs_between_receivers(simdir, tmp_path):
    # the rover's time tags an hour later than the master's last epoch: no master epoch within max_age_s
    # (a 0.5 s shift is now bridged: the rover drives and base epochs up to 30 s away are used)
    lines = (simdir / "rover.rnx").read_text().split("\n")
    shifted = []
    for ln in lines:
        if ln.startswith("> "):
            ln = ln[:13] + f"{(int(ln[13:15]) + 2) % 24:02d}" + ln[15:]
        shifted.append(ln)
    (tmp_path / "late.rnx").write_text("\n".join(shifted))
    r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--rinex", f"r={tmp_path / 'late.rnx'}",
                "--nav", simdir / "nav.rnx", "--master", "m", "-o", tmp_path / "o.mcap")
    assert r.exit_code == 2 and "no common epochs: master m" in r.stderr and "late.rnx" in r.stderr
    assert _no_output(tmp_path)
    # partly overlapping receivers: documented handling (only common epochs), with a warning
    half = []
    keep = True
    n_ep = 0
    for ln in lines:
        if ln.startswith("> "):
            n_ep += 1
            keep = n_ep <= 150
        if keep or not (ln.startswith("> ") or ln.startswith("G")):
            half.append(ln)
    (tmp_path / "half.rnx").write_text("\n".join(half))
    r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--rinex", f"r={tmp_path / 'half.rnx'}",
                "--nav", simdir / "nav.rnx", "--master", "m", "-o", tmp_path / "o.mcap")
    assert r.exit_code == 0 and "r: 150 epochs in common with m" in r.stderr     # the rover drives: all of its epochs


def test_other_ingest_errors(simdir, tmp_path):
    r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--rinex", f"r={simdir / 'rover.rnx'}", "-o",
                tmp_path / "o.mcap")
    assert r.exit_code == 2 and "--master is required" in r.stderr
    r = run_cli("ingest", "--rinex", "nonsense", "-o", tmp_path / "o.mcap")
    assert r.exit_code == 2 and "ANTENNA=FILE" in r.stderr
    r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "--master", "x", "-o", tmp_path / "o.mcap")
    assert r.exit_code == 2 and "master 'x' is not one of" in r.stderr
    r = run_cli("ingest", "--rinex", f"m={simdir / 'base.rnx'}", "-o", simdir / "base.rnx")
    assert r.exit_code == 2 and "would overwrite" in r.stderr
    # a master without any position while there are rovers
    txt = "\n".join(ln for ln in (simdir / "base.rnx").read_text().split("\n") if "APPROX POSITION XYZ" not in ln)
    (tmp_path / "nopos.rnx").write_text(txt)
    r = run_cli("ingest", "--rinex", f"m={tmp_path / 'nopos.rnx'}", "--rinex", f"r={simdir / 'rover.rnx'}",
                "--master", "m", "-o", tmp_path / "o.mcap")
    assert r.exit_code == 2 and "master m" in r.stderr and "has no position" in r.stderr
    # a GNSS run given to a structure-only command
    out = tmp_path / "ok.mcap"
    assert run_cli("-q", "ingest", "--config", simdir / "config.toml", "-o", out).exit_code == 0
    r = run_cli("spectra", out, "-o", tmp_path / "sp")
    assert r.exit_code == 2
    assert _no_output(tmp_path)


# ----------------------------------------------------------------------------------------------
# every real file in ../shared/data ingests or is refused with a clear reason

REFUSED = {
    "rinex/07590920.05n": "this is a RINEX navigation file, not an observation file",
    "rinex/30400920.05n": "this is a RINEX navigation file, not an observation file",
    "rinex/14601736.18n": "this is a RINEX navigation file, not an observation file",
    "rinex-ge/RINEX_GN_Spirent.23N": "this is a RINEX navigation file, not an observation file",
    "rinex-ge/RINEX_EN_Spirent.23L": "this is a RINEX navigation file, not an observation file",
    "ubx/pygpsdata-ESF.log": "no RXM-RAWX messages (found: ESF-MEAS",
    "ubx/ubx_20080526.ubx": "legacy u-blox raw log with 242 RXM-RAW messages",
    "real-pairs/geonet-car/SEPT2650.21P": "this is a RINEX navigation file, not an observation file",
    "real-pairs/mosaic-static/base.nav": "this is a RINEX navigation file, not an observation file",
    "real-pairs/ublox-walk/gnss_1730_convbin.nav": "this is a RINEX navigation file, not an observation file",
}
# files in ../shared/data that are not receiver logs: licences, READMEs, the simulator's true
# trajectory (CSV), raw IF samples for the tracking loops (read by other tests), and beside the real
# pairs their reference coordinates (*.txt), RTKLIB solutions (*.pos) and RTKLIB option files (*.conf)
NOT_RECEIVER_LOGS = ("README.md", "LICENSE-*", "*.csv", "if/*", "real-pairs/*.txt", "real-pairs/*.pos",
                     "real-pairs/*.conf")
NAV_PAIRS = (("rinex/14601736.18o", "rinex/14601736.18n"), ("rinex/07590920.05o", "rinex/07590920.05n"),
             ("rinex/30400920.05o", "rinex/30400920.05n"),
             ("rinex-ge/Base-static_MO_Spirent.obs", "rinex-ge/RINEX_GN_Spirent.23N"),
             ("real-pairs/mosaic-static/base.obs", "real-pairs/mosaic-static/base.nav"),
             ("real-pairs/geonet-car/SEPT265G.21O", "real-pairs/geonet-car/SEPT2650.21P"),
             ("real-pairs/ublox-walk/gnss_1730_convbin.obs", "real-pairs/ublox-walk/gnss_1730_convbin.nav"))


def _receiver_logs(root):
    """Every receiver log below ``root`` (relative POSIX paths), found by walking the folder so that
    a file added to ../shared/data is tried too."""
    def skip(rel):
        return any(fnmatch.fnmatch(rel, pat) or fnmatch.fnmatch(rel.rsplit("/", 1)[-1], pat)
                   for pat in NOT_RECEIVER_LOGS)
    rels = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
    return [r for r in rels if not skip(r)]


def test_every_real_file_ingests_or_is_refused(tmp_path):
    root = shared("README.md").parent
    files = _receiver_logs(root)
    assert set(REFUSED) <= set(files) and len(files) >= 15, files
    for rel in files:
        p = root / rel
        opt = "--ubx" if rel.startswith("ubx/") or rel.endswith(".ubx") else "--rinex"
        out = tmp_path / "one.mcap"
        r = run_cli("-q", "ingest", opt, f"a={p}", "-o", out)
        if rel in REFUSED:
            assert r.exit_code == 2, (rel, r.output)
            assert REFUSED[rel] in r.stderr and str(p) in r.stderr, (rel, r.stderr)
            assert not out.exists()
        else:
            assert r.exit_code == 0, (rel, r.output)
            assert "corrupt" not in r.stderr, (rel, r.stderr)       # none of the real logs is damaged
            run = read_gnss_run(out)
            assert np.isfinite(run.receivers["a"].raw["phase_cycles"]).any()
            out.unlink()
    # the navigation files are read as --nav with their observation files
    for obs, nav in NAV_PAIRS:
        r = run_cli("-q", "ingest", "--rinex", f"a={root / obs}", "--nav", root / nav, "-o", tmp_path / "n.mcap")
        assert r.exit_code == 0, (obs, r.output)
        assert len(read_gnss_run(tmp_path / "n.mcap").nav) > 0


def test_sfrbx_ephemerides_count_as_a_navigation_source(tmp_path):
    """A real u-blox log with RXM-SFRBX (real-pairs/ublox-walk): ingest uses its ephemerides and does
    not also warn 'no navigation file' (issue 28)."""
    log = shared("real-pairs/ublox-walk/gnss_1730.ubx")
    r = run_cli("ingest", "--ubx", f"a={log}", "-o", tmp_path / "w.mcap")
    assert r.exit_code == 0, r.output
    assert "broadcast ephemerides decoded from the UBX logs' RXM-SFRBX" in r.stderr
    assert "no navigation file" not in r.stderr
    assert len(read_gnss_run(tmp_path / "w.mcap").nav) > 0


def test_observation_arrays_round_trip_as_float64_and_int64_columns():
    """The RUN's observation table: every column back with its values, floats as float64 and integers
    as int64 (the frame is built on the decoded columns without a consolidated copy)."""
    from tests.io.test_gnss_archive import archived  # noqa: PLC0415

    rng = np.random.default_rng(3)
    n = 500
    raw = pd.DataFrame({c: rng.integers(-1, 9, n) for c in RAW_COLUMNS})
    raw["sat"] = rng.choice(["G01", "G12", "E05"], n).astype(object)
    for c in ("time_gps_s", "phase_cycles", "pseudorange_m", "clock_offset_s"):
        raw[c] = rng.normal(0.0, 1e7, n)
    for c in ("snr_dbhz", "doppler_hz", "cp_std_cycles", "pr_std_m"):
        raw[c] = rng.normal(0.0, 1e3, n).astype(np.float32).astype(np.float64)
    raw.loc[::7, "phase_cycles"] = np.nan
    back = archived(raw)
    assert list(back.columns) == list(RAW_COLUMNS)
    for c in RAW_COLUMNS:
        want = raw[c].to_numpy()
        got = back[c].to_numpy()
        assert got.dtype == (object if c == "sat" else np.float64 if want.dtype.kind == "f" else np.int64), c
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("key, line", [("[gnss.antennas.rover] rinex", 'rinex = "nope/rover.obs"'),
                                       ("[gnss] nav", 'nav = ["nope.nav"]')])
def test_ingest_names_the_config_key_of_a_missing_file(tmp_path, key, line):
    # the message named the missing file but not the config and key that point to it
    data = ROOT / "tests" / "data"
    cfg = tmp_path / "run.toml"
    rover = line if "rinex" in line else f'rinex = "{data / "07590920.05o"}"'     # a zero baseline
    nav = line if "nav" in line else f'nav = ["{data / "07590920.05n"}"]'
    cfg.write_text(f'[gnss]\nmaster = "base"\n{nav}\n\n[gnss.antennas.base]\nrinex = "{data / "07590920.05o"}"\n\n'
                   f'[gnss.antennas.rover]\n{rover}\n')
    out = tmp_path / "run.mcap"
    r = CliRunner().invoke(main, ["ingest", "--config", str(cfg), "-o", str(out)])
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert f"run.toml: {key}: {tmp_path / 'nope'}" in r.output and "cannot read: no such file" in r.output, r.output
    assert not out.exists()
