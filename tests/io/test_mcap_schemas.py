"""Every MCAP file cdgps writes opens in Foxglove and every message is valid against its schema.

Files come from the real chains (pseudolite simulate → ingest → init → estimate; simulate-gnss →
ingest → init → estimate; a structure on a simulated GNSS run; a u-blox UBX ingest; the GEONET
RINEX run with its navigation files when ../shared is there).  Each is checked by
:func:`cdgps_cli.io.mcap_check.check_mcap`: the official ``mcap`` reader (CRCs), a restatement of
Foxglove's JSON-schema decoder rules, ``jsonschema`` validation of every message, log times in
Unix ns.  The checker itself is tested on schemas Foxglove refuses (an unchecked checker passes
anything).  Also: GPS → UTC leap seconds against the LEAP SECONDS of real RINEX headers, the
angles topic against the static report's expression, and old files (``null`` elements) still read.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.core.expressions import parse_expression
from cdgps_cli.io.mcap_check import check_mcap, foxglove_schema_problems, path_name_problems
from cdgps_cli.io.mcap import McapOut, array_schema, read_mcap
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
from cdgps_cli.io.run import read_run
from cdgps_cli.io.states import ANGLES_TOPIC, SCENE_FIXED_TOPIC, SCENE_TOPIC, States
from cdgps_cli.io.states_layout import DEFAULT_PREVIEW_RATE_HZ
from cdgps_cli.core.timescales import GPS_EPOCH_UNIX_S, gps_minus_utc_s, unix_ns

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
SHARED = ROOT.parent / "shared" / "data"
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
TOWER = ROOT / "configs" / "gnss-tower.toml"
GEONET = ROOT / "configs" / "geonet-0759-3040.toml"


def run_cli(*args):
    r = CliRunner().invoke(main, ["-q", *[str(a) for a in args]])
    assert r.exit_code == 0, (args, r.output)
    return r


def assert_opens_everywhere(path: Path, expect_topics=()) -> dict:
    """check_mcap with no failure at all; returns its result (messages counted per channel)."""
    r = check_mcap(path)
    bad = {t: c["schema_problems"] + c["problems"] for t, c in r["channels"].items() if c["schema_problems"] or c["problems"]}
    assert r["failures"] == 0 and not bad, (path, bad)
    for t in expect_topics:
        assert r["channels"].get(t, {}).get("messages", 0) > 0, (path, t, r["channels"].keys())
    return r


# ----------------------------------------------------------------------------------------------
# the checker refuses what Foxglove refuses


def test_foxglove_rules_refuse_what_the_decoder_refuses():
    ok = {"type": "object", "properties": {
        "a": {"type": "number"}, "b": {"type": "integer", "minimum": 0}, "c": {"type": "boolean"},
        "d": {"type": "string"}, "e": {"type": "string", "contentEncoding": "base64"},
        "f": {"type": "array", "items": {"type": "string"}},
        "g": {"type": "object", "properties": {"x": {"type": "array", "items": {"type": "object", "properties": {}}}}},
        "h": {"oneOf": [{"title": "A", "const": 1}, {"title": "B", "const": 2}]}, "i": {"type": "object"}}}
    assert foxglove_schema_problems(ok) == []
    refused = {
        "type list in array items": {"type": "array", "items": {"type": ["number", "null"]}},
        "number|null": {"type": "number|null"},
        "type list": {"type": ["number", "null"]},
        "null": {"type": "null"},
        "no type": {"description": "anything"},
        "array of arrays": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}},
        "array without items": {"type": "array"},
        "encoded string items": {"type": "array", "items": {"type": "string", "contentEncoding": "base64"}},
        "unknown encoding": {"type": "string", "contentEncoding": "base32"},
        "string oneOf": {"oneOf": [{"const": "a"}, {"const": 1}]},
    }
    for what, fs in refused.items():
        probs = foxglove_schema_problems({"type": "object", "properties": {"x": fs}})
        assert len(probs) == 1 and probs[0].startswith("x:"), (what, probs)
        nested = foxglove_schema_problems({"type": "object", "properties": {"o": {"type": "object", "properties": {"x": fs}}}})
        assert len(nested) == 1 and nested[0].startswith("o.x:"), (what, nested)
    assert foxglove_schema_problems({"type": "array"})                       # the root must be an object
    assert path_name_problems(ok) == []
    assert path_name_problems({"type": "object", "properties": {"o": {"type": "object", "properties": {
        "q6+q10": {"type": "number"}, "0759_e": {"type": "number"}}}}}) == [
        "o.q6+q10: name cannot be written in a message path (letters, digits, _ and - only)"]
    assert foxglove_schema_problems({"properties": {}})


def test_checker_finds_null_nan_undeclared_and_wrong_times(tmp_path):
    p = tmp_path / "bad.mcap"
    schema = {"title": "t", "type": "object", "properties": {"time_s": {"type": "number"}, "v": {"type": "number"},
                                                            "timestamp": {"type": "object"}}}
    with open(p, "wb") as fh:
        from mcap.writer import Writer

        w = Writer(fh)
        w.start()
        sid = w.register_schema("t", "jsonschema", json.dumps(schema).encode())
        cid = w.register_channel("/x", "json", sid, {"time_scale": "relative"})
        msgs = [b'{"time_s": 1.0, "v": null}', b'{"time_s": 2.0, "v": NaN}', b'{"time_s": 3.0, "v": 1, "w": 2}',
                b'{"time_s": 4.0, "v": 1}', b'{"time_s": 5.0, "v": 1}']
        for i, m in enumerate(msgs):
            t = int((i + 1) * 1e9) if i != 3 else 4
            w.add_message(cid, log_time=t, data=m, publish_time=t, sequence=i)
        w.finish()
    r = check_mcap(p)
    c = r["channels"]["/x"]
    assert r["messages"] == 5 and c["failures"] == 4, c
    text = "\n".join(c["problems"])
    assert "None is not of type 'number'" in text and "NaN is not JSON" in text
    assert "w: not declared" in text and "is not time_s 4.0" in text


def test_writer_encodes_missing_values_and_readers_get_nan_back(tmp_path):
    schema = array_schema("cdgps.T", {"a": "number|null", "s": "string"}, {"x": "number|null"})
    assert foxglove_schema_problems(schema) == []
    p = tmp_path / "t.mcap"
    with McapOut(p) as out:
        ch = out.channel("/t", schema)
        out.write(ch, 0.5, {"a": [1.0, None, float("nan")], "s": ["p", "q", "r"], "x": float("nan")})
        out.write(ch, 1.0, {"a": [2.0], "s": ["p"], "x": 3.0})
        with pytest.raises(ValueError, match="'s'"):
            out.write(ch, 2.0, {"a": [2.0], "s": [None], "x": 3.0})
    assert_opens_everywhere(p)
    msgs = [json.loads(m.data) for _, _, m in make_reader(open(p, "rb")).iter_messages()]
    assert msgs[0]["a"] == [1.0, 0.0, 0.0] and msgs[0]["a_valid"] == [True, False, False] and "x" not in msgs[0]
    tc = read_mcap(p).topics["/t"]
    np.testing.assert_array_equal(tc.column("a"), [1.0, np.nan, np.nan, 2.0])
    assert tc.scalars["x"] == [None, 3.0]


# ----------------------------------------------------------------------------------------------
# times: Unix log times, GPS → UTC with leap seconds


def test_gps_minus_utc_matches_the_leap_seconds_of_real_rinex_headers():
    checked = 0
    for f in sorted(DATA.glob("*.??[on]")):
        if f.suffix.endswith("o"):
            try:
                h, _ = read_rinex_obs(f)
            except Exception:       # noqa: BLE001 - a subset file this reader refuses is no leap-second source
                continue
            leap, t = h.get("leap_seconds"), h.get("time_first_obs_gps_s")
        else:
            nav = read_rinex_nav(f)
            leap, t = nav.attrs.get("leap_seconds"), (float(nav["toc_gps_s"].min()) if len(nav) else None)
        if leap is None or t is None:
            continue
        assert gps_minus_utc_s(t) == leap, (f.name, t, leap)
        checked += 1
    assert checked >= 3


def test_unix_log_times():
    assert unix_ns(0.0, "gps") == GPS_EPOCH_UNIX_S * 10**9                # 1980-01-06, before any leap second
    # 2005-04-02 00:00:00 GPST (GEONET) = 2005-04-01 23:59:47 UTC: 13 leap seconds
    gps = (pd.Timestamp("2005-04-02") - pd.Timestamp("1980-01-06")).total_seconds()
    assert unix_ns(gps + 0.25, "gps") == (pd.Timestamp("2005-04-01 23:59:47.25", tz="UTC").value)
    # 2017-01-01 00:00:00 UTC is 18 s after the same calendar date in GPS time
    gps17 = (pd.Timestamp("2017-01-01") - pd.Timestamp("1980-01-06")).total_seconds() + 18
    assert unix_ns(gps17, "gps") == pd.Timestamp("2017-01-01", tz="UTC").value
    # the leap second 2016-12-31 23:59:60 shares the Unix second that follows it (log times never go back)
    assert unix_ns(gps17 - 1, "gps") == pd.Timestamp("2017-01-01", tz="UTC").value
    assert unix_ns(gps17 - 2, "gps") == pd.Timestamp("2016-12-31 23:59:59", tz="UTC").value
    assert unix_ns(12.5, "relative") == 12_500_000_000
    with pytest.raises(ValueError):
        unix_ns(1.0, "tai")


# ----------------------------------------------------------------------------------------------
# the chains


@pytest.fixture(scope="module")
def pseudolite(tmp_path_factory):
    """Testbed free vibration, slips (events), C/N0 missing on some rows, smoothed; the pulse
    scenario's thruster log ingested beside it (actuators topic)."""
    tmp = tmp_path_factory.mktemp("pl")
    run_cli("simulate", TESTBED, "--duration", "30", "--seed", "4", "--noise-m", "0.002",
            "--random-slips", "2", "--out", tmp / "sim")
    rx = pd.read_csv(tmp / "sim" / "receiver.csv")
    rx.loc[::5, "snr_dbhz"] = np.nan
    rx.to_csv(tmp / "sim" / "receiver.csv", index=False)
    run_cli("ingest", tmp / "sim" / "receiver.csv", tmp / "sim" / "gyro.csv", "--config", TESTBED, "-o", tmp / "run.mcap")
    run_cli("init", tmp / "run.mcap", "--duration", "10", "-o", tmp / "init.json")
    run_cli("simulate", TESTBED, "--duration", "8", "--seed", "4", "--scenario", "pulse", "--out", tmp / "pulse")
    run_cli("ingest", tmp / "pulse" / "receiver.csv", tmp / "pulse" / "gyro.csv", "--actuators",
            tmp / "pulse" / "actuators.csv", "--config", TESTBED, "-o", tmp / "pulse.mcap")
    # JSON channels at every epoch (checked message by message below), and at the default rate
    run_cli("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "--smooth", "--foxglove-rate-hz", "0",
            "-o", tmp / "states.mcap")
    run_cli("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "--smooth", "-o", tmp / "states_1hz.mcap")
    return tmp, rx


def test_pseudolite_run_and_states_open_everywhere(pseudolite):
    tmp, rx = pseudolite
    r = assert_opens_everywhere(tmp / "run.mcap", ["/cdgps/phase", "/cdgps/gyro"])
    assert_opens_everywhere(tmp / "pulse.mcap", ["/cdgps/phase", "/cdgps/gyro", "/cdgps/actuators"])
    s = assert_opens_everywhere(tmp / "states.mcap", ["/cdgps/state", "/cdgps/state_filtered", "/cdgps/residuals",
                                                      ANGLES_TOPIC, SCENE_TOPIC, SCENE_FIXED_TOPIC])
    assert r["messages"] + s["messages"] > 1000
    s1 = assert_opens_everywhere(tmp / "states_1hz.mcap", ["/cdgps/state", "/cdgps/state_filtered", "/cdgps/residuals",
                                                           ANGLES_TOPIC, SCENE_TOPIC])
    n = len(States(tmp / "states.mcap").time_s)                   # 10 Hz run: every stride-th epoch, 5 topics + events
    stride = int(round(1.0 / (0.1 * DEFAULT_PREVIEW_RATE_HZ)))
    assert stride > 1
    # (state, state_filtered, angles, residuals, scene) per preview epoch, the transmitters once, the events
    assert s1["messages"] == 5 * len(range(0, n, stride)) + 1 + len(States(tmp / "states.mcap").events)
    assert s1["channels"][SCENE_TOPIC]["schema"] == "foxglove.SceneUpdate"
    # the missing C/N0 come back as NaN, everything else as written
    run = read_run(tmp / "run.mcap")
    assert int(np.isnan(run.phase["snr_dbhz"]).sum()) == int(rx["snr_dbhz"].isna().sum()) > 0
    # relative runs: log time = time_s after the Unix epoch, said in the channel metadata
    with open(tmp / "run.mcap", "rb") as fh:
        rd = make_reader(fh)
        _, ch, m = next(rd.iter_messages(topics=["/cdgps/phase"]))
        assert m.log_time == round(json.loads(m.data)["time_s"] * 1e9)
        assert ch.metadata["time_scale"] == "relative" and ch.metadata["time_origin_utc"] == "1970-01-01T00:00:00Z"


def test_angles_topic_plots_the_reported_angle_by_name(pseudolite):
    tmp, _ = pseudolite
    st = States(tmp / "states.mcap")
    with open(tmp / "states.mcap", "rb") as fh:
        rd = make_reader(fh)
        msgs = [(json.loads(m.data), ch) for _, ch, m in rd.iter_messages(topics=[ANGLES_TOPIC])]
        schema = json.loads(next(s for s in rd.get_summary().schemas.values() if s.name == "cdgps.AnglesDeg").data)
    body, ch = msgs[0]
    assert json.loads(ch.metadata["angles"])["C2_z"] == "q6+q10"
    assert ch.metadata["units"] == "deg"
    for name, fs in schema["properties"].items():      # flat numbers with plain names (Plot: /topic.name)
        if name not in ("timestamp",):
            assert fs["type"] == "number" and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name), name
    # C2_z against the static report's own route: parse_expression("q6+q10") on q, σ from P_xi
    U = np.asarray(st.cfg.mode_shapes)
    coef = parse_expression("q6+q10", st.cfg.coord_names)
    v = coef @ U
    got = np.array([m["C2_z"] for m, _ in msgs])
    got_s = np.array([m["sigma_C2_z"] for m, _ in msgs])
    assert len(msgs) == len(st.time_s)
    np.testing.assert_allclose(got, np.degrees(st.q @ coef), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got_s, np.degrees(np.sqrt(np.einsum("i,nij,j->n", v, st.P_xi, v))), rtol=1e-9)
    assert set(m for m, _ in [(k, 0) for k in body]) >= {"body_z", "C1_x", "C1_z", "C2_x", "C2_z", "C3_x", "C3_z"}


@pytest.fixture(scope="module")
def gnss_sim(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("gs")
    run_cli("simulate-gnss", "--duration", "600", "--seed", "5", "--slips", "2", "--out", tmp)
    run_cli("ingest", "--config", tmp / "config.toml", "-o", tmp / "run.mcap")
    run_cli("init", tmp / "run.mcap", "-o", tmp / "init.json")
    run_cli("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "-o", tmp / "states.mcap")
    return tmp


def test_simulated_gnss_run_and_states_open_everywhere(gnss_sim):
    r = assert_opens_everywhere(gnss_sim / "run.mcap", ["/cdgps/gnss/obs", "/cdgps/gnss/ephemeris"])
    s = assert_opens_everywhere(gnss_sim / "states.mcap", ["/cdgps/state", "/cdgps/residuals"])
    assert r["messages"] > 1000 and s["messages"] > 1000
    # GPS time in the payload, UTC in the log time: 2024-01-01 (GPS) is 18 s ahead of UTC
    with open(gnss_sim / "run.mcap", "rb") as fh:
        _, ch, m = next(make_reader(fh).iter_messages(topics=["/cdgps/gnss/obs"]))
    t_gps = json.loads(m.data)["time_s"]
    assert ch.metadata["time_scale"] == "gps"
    assert m.log_time == round((t_gps + GPS_EPOCH_UNIX_S - 18) * 1e9)
    assert str(pd.Timestamp(m.log_time, unit="ns")) == "2023-12-31 23:59:42"       # 2024-01-01 00:00:00 GPST


def test_structure_on_a_gnss_run_opens_everywhere(tmp_path):
    from cdgps_cli.pipeline.gnss_modal import simulate_structure_gnss

    simulate_structure_gnss(tmp_path, load_config(TOWER), duration_s=120.0, seed=3, random_walk_sigma=0.01)
    run_cli("ingest", "--config", tmp_path / "config.toml", "-o", tmp_path / "run.mcap")
    run_cli("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    run_cli("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "--structure", TOWER,
            "-o", tmp_path / "states.mcap")
    assert_opens_everywhere(tmp_path / "run.mcap", ["/cdgps/gnss/obs"])
    r = assert_opens_everywhere(tmp_path / "states.mcap", ["/cdgps/state", ANGLES_TOPIC, SCENE_TOPIC])
    assert SCENE_FIXED_TOPIC not in r["channels"]           # the config's transmitters stand for satellites: not drawn
    with open(tmp_path / "states.mcap", "rb") as fh:
        _, ch, _ = next(make_reader(fh).iter_messages(topics=["/cdgps/state"]))
    assert ch.metadata["time_scale"] == "gps"
    # the satellites used, as arrows from the master toward them: every one above the 15° mask
    # (the structure frame's z is up), each named as RINEX names it
    with open(tmp_path / "states.mcap", "rb") as fh:
        rd = make_reader(fh)
        sky = [json.loads(m.data)["entities"][1] for _, _, m in rd.iter_messages(topics=[SCENE_TOPIC])]
    assert all(e["id"] == "satellites" and len(e["arrows"]) >= 5 for e in sky)
    for e in (sky[0], sky[-1]):
        for arrow in e["arrows"]:
            o = arrow["pose"]["orientation"]
            up = 2 * (o["x"] * o["z"] - o["w"] * o["y"])                      # z of R(q) e_x
            assert up > np.sin(np.radians(15.0)) - 1e-9, arrow
        assert all(re.fullmatch(r"G\d\d", x["text"]) for x in e["texts"]) and len(e["texts"]) == len(e["arrows"])


def test_ubx_run_opens_everywhere(tmp_path):
    run_cli("ingest", "--ubx", f"u={DATA / 'pygpsdata-RXMRAWX.log'}", "-o", tmp_path / "ubx.mcap")
    r = assert_opens_everywhere(tmp_path / "ubx.mcap", ["/cdgps/gnss/obs"])
    assert r["messages"] == 14


def test_geonet_run_and_states_open_everywhere(tmp_path):
    rinex = SHARED / "rinex"
    if not (rinex / "30400920.05o").exists():
        pytest.skip(f"shared test data not available: {rinex}")
    text = GEONET.read_text().replace('"../../shared/data/', f'"{SHARED.as_posix()}/')
    cfg = tmp_path / "geonet.toml"
    cfg.write_text(text)
    run_cli("ingest", "--config", cfg, "-o", tmp_path / "run.mcap")
    run_cli("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    run_cli("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "-o", tmp_path / "states.mcap")
    r = assert_opens_everywhere(tmp_path / "run.mcap", ["/cdgps/gnss/obs", "/cdgps/gnss/ephemeris"])
    assert r["channels"]["/cdgps/gnss/ephemeris"]["messages"] >= 162
    assert_opens_everywhere(tmp_path / "states.mcap", ["/cdgps/state", "/cdgps/residuals"])
    with open(tmp_path / "run.mcap", "rb") as fh:
        _, _, m = next(make_reader(fh).iter_messages(topics=["/cdgps/gnss/obs"]))
    assert str(pd.Timestamp(m.log_time, unit="ns")) == "2005-04-01 23:59:47"        # not 1995


def test_old_files_with_nulls_still_read(tmp_path):
    """A RUN.mcap written before the validity arrays (``null`` C/N0 elements) reads as before."""
    from mcap.writer import Writer

    cfg = load_config(TESTBED)
    old_schema = {"title": "cdgps.DifferentialPhase", "type": "object", "properties": {
        "timestamp": {"type": "object"}, "time_s": {"type": "number"}, "master": {"type": "string"},
        **{k: {"type": "array", "items": {"type": t}} for k, t in
           (("receiver", "string"), ("antenna", "string"), ("transmitter", "string"), ("phase_cycles", "number"),
            ("lock", "integer"), ("snr_dbhz", ["number", "null"]))}}}
    p = tmp_path / "old.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh, enable_data_crcs=True)          # as cdgps always wrote: data-section CRC
        w.start(profile="cdgps", library="cdgps")
        sid = w.register_schema("cdgps.DifferentialPhase", "jsonschema", json.dumps(old_schema).encode())
        cid = w.register_channel("/cdgps/phase", "json", sid, {})
        for k in range(3):
            t = 0.1 * k
            body = {"timestamp": {"sec": 0, "nsec": round(t * 1e9)}, "time_s": t, "master": "m", "receiver": ["r", "r"],
                    "antenna": list(cfg.rover_names[:2]), "transmitter": [cfg.transmitter_names[0]] * 2,
                    "phase_cycles": [1.5, 2.5], "lock": [k, k], "snr_dbhz": [None, 44.0]}
            w.add_message(cid, log_time=round(t * 1e9), data=json.dumps(body).encode(), publish_time=round(t * 1e9))
        w.add_attachment(0, 0, "config.toml", "application/toml", cfg.text.encode())
        w.add_metadata("cdgps.ingest", {"created_by": "cdgps ingest"})   # older files: no record_sha256
        w.finish()
    run = read_run(p)
    np.testing.assert_array_equal(run.phase["snr_dbhz"], [np.nan, 44.0] * 3)
    assert check_mcap(p)["channels"]["/cdgps/phase"]["schema_problems"]      # and the checker refuses its schema


# ----------------------------------------------------------------------------------------------
# issue 33 item 2: the shipped Foxglove layouts and the 3-D scene channel


LAYOUTS = ROOT / "docs" / "foxglove"


def _tree_ids(node) -> list:
    if isinstance(node, str):
        return [node]
    return _tree_ids(node["first"]) + _tree_ids(node["second"])


@pytest.mark.parametrize("name,chain,states", [("cdgps-states-layout.json", "pseudolite", "states_1hz.mcap"),
                                               ("cdgps-gnss-states-layout.json", "gnss_sim", "states.mcap")])
def test_shipped_layouts_refer_only_to_what_states_hold(request, tmp_path, name, chain, states):
    """Every topic and field a shipped layout plots exists in a STATES written here (the demo's
    testbed config; a simulate-gnss run), and the layout is what ``cdgps foxglove-layout`` writes
    for that file today: neither can go stale."""
    from cdgps_cli.io.foxglove_layout import layout_paths, missing_paths

    fx = request.getfixturevalue(chain)
    path = (fx[0] if isinstance(fx, tuple) else fx) / states
    shipped = json.loads((LAYOUTS / name).read_text())
    assert sorted(_tree_ids(shipped["layout"])) == sorted(shipped["configById"])      # every panel placed, once
    paths = layout_paths(shipped)
    assert "/cdgps/residuals.nis_upper95" in paths and "/cdgps/events" in paths
    assert any(p.endswith(".@negative") for c in shipped["configById"].values() for p in
               [s["value"] for s in c.get("paths", [])])                               # the −σ half of the band
    assert missing_paths(shipped, path) == []
    stale = json.loads(json.dumps(shipped))
    next(c for k, c in stale["configById"].items() if k.startswith("Plot!"))["paths"][0]["value"] += "_gone"
    assert len(missing_paths(stale, path)) == 1                                         # (the check can fail)
    if chain == "pseudolite":
        three_d = shipped["configById"]["3D!structure"]
        assert set(three_d["topics"]) == {SCENE_TOPIC, SCENE_FIXED_TOPIC}
        with open(path, "rb") as fh:
            ch = next(c for c in make_reader(fh).get_summary().channels.values() if c.topic == SCENE_TOPIC)
        assert three_d["followTf"] == ch.metadata["frame_id"]
    run_cli("foxglove-layout", path, "-o", tmp_path / name)
    assert json.loads((tmp_path / name).read_text()) == shipped


@pytest.mark.parametrize("name,chain", [("cdgps-run-layout.json", "pseudolite"),
                                        ("cdgps-gnss-run-layout.json", "gnss_sim")])
def test_shipped_run_layouts_refer_only_to_what_runs_hold(request, tmp_path, name, chain):
    """The RUN layouts: every topic, field, index and receiver filter exists in a RUN.mcap written
    here (the demo's testbed config; a simulate-gnss run), the named phase channels sit at their
    index in every message, and ``cdgps foxglove-layout RUN.mcap`` writes the shipped bytes."""
    from cdgps_cli.io.foxglove_layout import layout_paths, missing_paths

    fx = request.getfixturevalue(chain)
    path = (fx[0] if isinstance(fx, tuple) else fx) / "run.mcap"
    shipped_text = (LAYOUTS / name).read_text()
    shipped = json.loads(shipped_text)
    assert sorted(_tree_ids(shipped["layout"])) == sorted(shipped["configById"])
    paths = layout_paths(shipped)
    assert missing_paths(shipped, path) == []
    stale = json.loads(shipped_text)
    first = next(c for k, c in stale["configById"].items() if k.startswith("Plot!"))["paths"][0]
    first["value"] = re.sub(r"\[(\d+|:)\]$", "[999]", first["value"])
    assert missing_paths(stale, path) == [first["value"]]                              # an index past the end fails
    with open(path, "rb") as fh:
        msgs = [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages(
            topics=["/cdgps/phase", "/cdgps/gyro", "/cdgps/gnss/obs"])]
    if chain == "pseudolite":
        cfg = shipped["configById"]
        assert {"Plot!phase", "Plot!lock", "Plot!cn0", "Plot!gyro", "RawMessages!phase"} <= set(cfg)
        assert "/cdgps/gyro.rate_rad_s[0]" in paths and "(rad/s)" in cfg["Plot!gyro"]["foxglovePanelTitle"]
        labels = [s["label"] for s in cfg["Plot!phase"]["paths"]]
        assert [x.split("–")[0] for x in labels] == ["a1", "a2", "a3", "a4", "a5", "a6"]      # one per antenna
        for s in cfg["Plot!phase"]["paths"]:
            k = int(re.fullmatch(r"/cdgps/phase\.phase_cycles\[(\d+)\]", s["value"]).group(1))
            assert all(f"{m['antenna'][k]}–{m['transmitter'][k]}" == s["label"] for m in msgs if "antenna" in m)
    else:
        receivers = {m["receiver"] for m in msgs}
        assert receivers == {"base", "rover"}
        assert {f'/cdgps/gnss/obs{{receiver=="{r}"}}.snr_dbhz[:]' for r in receivers} <= set(paths)
        stale["configById"]["Plot!cn0_base"]["paths"][0]["value"] = '/cdgps/gnss/obs{receiver=="nobody"}.snr_dbhz[:]'
        assert '/cdgps/gnss/obs{receiver=="nobody"}.snr_dbhz[:]' in missing_paths(stale, path)   # the filter counts
    run_cli("foxglove-layout", path, "-o", tmp_path / name)
    assert (tmp_path / name).read_text() == shipped_text                                # byte-identical


def test_run_layout_with_actuators_and_bad_input(pseudolite, tmp_path):
    """A RUN with a thruster log gets the forces plot (N); a file that is not an MCAP and a
    truncated RUN exit 2 naming the file and write nothing."""
    from cdgps_cli.io.foxglove_layout import missing_paths

    tmp, _ = pseudolite
    run_cli("foxglove-layout", tmp / "pulse.mcap", "-o", tmp_path / "pulse.json")
    layout = json.loads((tmp_path / "pulse.json").read_text())
    assert layout["configById"]["Plot!actuators"]["foxglovePanelTitle"] == "Actuator forces (N)"
    assert missing_paths(layout, tmp / "pulse.mcap") == []
    (tmp_path / "text.mcap").write_text("not an mcap\n")
    (tmp_path / "cut.mcap").write_bytes((tmp / "run.mcap").read_bytes()[:4000])
    for bad in ("text.mcap", "cut.mcap"):
        r = CliRunner().invoke(main, ["-q", "foxglove-layout", str(tmp_path / bad), "-o", str(tmp_path / "out.json")])
        assert r.exit_code == 2 and str(tmp_path / bad) in r.output and "Traceback" not in r.output, r.output
        assert not (tmp_path / "out.json").exists()


def test_scene_follows_the_preview_and_can_be_left_out(pseudolite, tmp_path):
    """The scene's messages sit at the preview epochs of /cdgps/state and draw the antennas where
    the model puts them for that preview's q (exaggeration as asked); ``--scene-exaggeration 0``
    leaves both scene channels out and changes nothing else; a bad factor is refused."""
    from cdgps_cli.analysis.scene import StructureScene
    from cdgps_cli.model.kinematics import antenna_positions

    tmp, _ = pseudolite
    run_cli("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "--smooth", "--scene-exaggeration", "20",
            "-o", tmp_path / "x20.mcap")
    run_cli("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "--smooth", "--scene-exaggeration", "0",
            "-o", tmp_path / "none.mcap")
    with open(tmp_path / "x20.mcap", "rb") as fh:
        rd = make_reader(fh)
        states = {m.log_time: json.loads(m.data) for _, _, m in rd.iter_messages(topics=["/cdgps/state"])}
        scene = [(m.log_time, json.loads(m.data), ch) for _, ch, m in rd.iter_messages(topics=[SCENE_TOPIC])]
    assert [t for t, _, _ in scene] == sorted(states) and scene[0][2].metadata["exaggeration"] == "20"
    cfg = load_config(TESTBED)
    t, msg, _ = scene[len(scene) // 2]
    q = np.array([[states[t]["q"][n] for n in cfg.coord_names]])
    sc = StructureScene(cfg, 20.0)
    expect = sc.updates(q, [t])[0]
    assert msg == json.loads(json.dumps(expect))
    rigid = np.zeros_like(q)
    rigid[:, cfg.rigid_index] = q[:, cfg.rigid_index]
    p = antenna_positions(cfg, rigid) + 20.0 * (antenna_positions(cfg, q) - antenna_positions(cfg, rigid))
    got = np.array([[s["pose"]["position"][a] for a in "xyz"] for s in msg["entities"][0]["spheres"]])
    np.testing.assert_allclose(got, p[0], atol=0.51e-3)
    r = check_mcap(tmp_path / "none.mcap")
    assert SCENE_TOPIC not in r["channels"] and SCENE_FIXED_TOPIC not in r["channels"] and r["failures"] == 0
    a, b = States(tmp_path / "none.mcap"), States(tmp_path / "x20.mcap")
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.P_xi, b.P_xi)
    bad = CliRunner().invoke(main, ["-q", "estimate", str(tmp / "run.mcap"), "--init", str(tmp / "init.json"),
                                    "--scene-exaggeration", "-1", "-o", str(tmp_path / "bad.mcap")])
    assert bad.exit_code == 2 and "--scene-exaggeration" in bad.output and "Traceback" not in bad.output
    assert not (tmp_path / "bad.mcap").exists()
    huge = CliRunner().invoke(main, ["-q", "estimate", str(tmp / "run.mcap"), "--init", str(tmp / "init.json"),
                                     "--scene-exaggeration", "1e308", "-o", str(tmp_path / "huge.mcap")])
    assert huge.exit_code == 2 and "--scene-exaggeration '1e308'" in huge.output, huge.output   # was an inf scene
    assert not (tmp_path / "huge.mcap").exists()


def test_nis_bounds_are_the_chi_square_interval(pseudolite):
    from scipy.stats import chi2

    tmp, _ = pseudolite
    with open(tmp / "states.mcap", "rb") as fh:
        msgs = [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages(topics=["/cdgps/residuals"])]
    with_nis = [m for m in msgs if "nis" in m]
    assert with_nis and all("nis_upper95" not in m for m in msgs if "nis" not in m)
    for m in with_nis[:20]:
        assert m["nis_lower95"] == pytest.approx(chi2.ppf(0.025, m["nis_dof"]), rel=1e-12)
        assert m["nis_upper95"] == pytest.approx(chi2.ppf(0.975, m["nis_dof"]), rel=1e-12)


def test_old_states_without_a_scene_still_read_and_get_a_layout():
    """A STATES.mcap of the earlier layout (no scene, no NIS bounds) still reads, and its layout
    has no 3-D panel and plots only what it holds."""
    from cdgps_cli.io.foxglove_layout import describe_states, missing_paths, states_layout

    old = DATA / "format-2026-12-03" / "structure-states.mcap"
    st = States(old)
    assert len(st.time_s) > 0
    layout = states_layout(describe_states(old))
    assert "3D!structure" not in layout["configById"] and missing_paths(layout, old) == []
