"""One tracking family per signal at every receiver (core.signals.common_attributes, io.rinex_signals.signal_attributes).

A real case (a sweep of session 33): the matrtklib 2018 base (a Trimble NetR9) lists GPS ``L2W`` for every satellite
and ``L2X`` (L2C) for the five that broadcast it; the rover lists ``L2W`` alone.  Each file's first attribute (L2C
first) made the base's L2 L2C against the rover's P(Y): each satellite's L2C/P(Y) bias stays in the double
differences, and the static solution of G:L1 + G:L2 lay 3.7 mm N and 11.8 mm U from RTKLIB's (rnx2rtkp -f 2, GPS,
the base position given: 4.8936 / −4.4762 / −1.4450 m E/N/U; RTKLIB's code priorities take P(Y) first).  Read as
P(Y) at both: within 0.0 / 0.1 / 0.9 mm, and the base's ten satellites in its L2 group instead of five (eight in
common with the rover instead of three).  Against a u-blox rover (L2C alone) the same base reads L2C.
"""

from __future__ import annotations

import json

import numpy as np

from cdgps_cli.core.signals import common_attributes
from cdgps_cli.io.rinex_signals import phase_attributes_in_file, read_rinex_signals, signal_attributes
from tests._shared import REPO_ROOT, run_cli

DATA = REPO_ROOT / "tests" / "data" / "matrtklib-2018-static"
BASE, ROVER, NAV = DATA / "base_60s.obs.gz", DATA / "rover_60s.obs.gz", DATA / "base.nav.gz"
BASE_XYZ = ("-3937776.1063", "3354867.8075", "3718445.0835")
RTKLIB_ENU = np.array([4.8936, -4.4762, -1.4450])          # rnx2rtkp -p 3 -f 2, pos1-navsys=1, -r BASE_XYZ, final epoch


def test_the_first_family_every_receiver_holds():
    assert common_attributes("G:L2", {"base": "WX", "rover": "W"}) == ({"base": "W", "rover": "W"}, True)
    assert common_attributes("G:L2", {"base": "WX", "rover": "WL"}) == ({"base": "X", "rover": "L"}, True)   # L2C first
    assert common_attributes("G:L2", {"base": "WX", "rover": "LS"}) == ({"base": "X", "rover": "L"}, True)   # a u-blox
    assert common_attributes("G:L2", {"base": "W", "rover": "LS"}) == ({"base": "W", "rover": "L"}, False)
    assert common_attributes("G:L2", {"base": "WX", "rover": None}) == ({"base": "X", "rover": None}, True)    # RINEX 2
    assert common_attributes("G:L2", {"base": "WX", "rover": ""}) == ({"base": "X", "rover": None}, True)     # none
    assert common_attributes("J:L1", {"base": "CXZ", "rover": "C"}) == ({"base": "C", "rover": "C"}, True)
    assert common_attributes("E:E1", {"base": "X", "rover": "C"}) == ({"base": "X", "rover": "C"}, True)      # one family


def test_the_real_base_reads_one_family_with_its_partner():
    assert phase_attributes_in_file(BASE, ["G:L2"]) == {"G:L2": "XW"} and phase_attributes_in_file(ROVER, ["G:L2"]) == {"G:L2": "W"}
    attrs, notes = signal_attributes({"base": [("rinex", BASE, None)], "rover": [("rinex", ROVER, None)]}, ["G:L1", "G:L2"])
    assert attrs == {"base": {"G:L1": "C", "G:L2": "W"}, "rover": {"G:L1": "C", "G:L2": "W"}} and notes == []
    h, df = read_rinex_signals(BASE, ["G:L2"], attributes=attrs["base"])
    assert h["signal_codes"] == {"G:L2": ["L2W", "C2W"]} and df["sat"].nunique() == 10
    attrs, notes = signal_attributes({"base": [("rinex", BASE, None)], "rover": [("ubx", None, None)]}, ["G:L2"])
    assert attrs == {"base": {"G:L2": "X"}, "rover": {"G:L2": "L"}} and notes == []     # against a u-blox: L2C at both
    h, df = read_rinex_signals(BASE, ["G:L2"], attributes=attrs["base"])
    assert h["signal_codes"] == {"G:L2": ["L2X", "C2X"]} and df["sat"].nunique() == 5
    _, notes = signal_attributes({"base": [("ubx", None, None)], "rover": [("rinex", ROVER, None)]}, ["G:L2"])
    assert notes == ["G:L2: the receivers track different signals on this carrier (base L2L, rover L2W): each "
                     "satellite's bias between them stays in the double differences (centimetres, not cycles)"]


def test_a_receivers_files_each_list_the_attribute_it_reads(tmp_path):
    """The attributes all of a receiver's files list: a second file without L2W makes the first read L2C too."""
    import gzip

    text = gzip.decompress(BASE.read_bytes()).decode()
    only_x = tmp_path / "b2.obs"                      # the same header without L2W (its type renamed: not listed)
    only_x.write_text(text.replace(" C2W L2W S2W ", " C2V L2V S2V ", 1))
    attrs, _ = signal_attributes({"base": [("rinex", BASE, None), ("rinex", only_x, None)],
                                  "rover": [("ubx", None, None)]}, ["G:L2"])
    assert attrs["base"] == {"G:L2": "X"}
    head = text[:text.index("END OF HEADER") + len("END OF HEADER\n")].encode()
    assert phase_attributes_in_file("named.obs", ["G:L2"], read=(head, False)) == {"G:L2": "XW"}   # the header alone


def test_rtk_and_init_on_the_real_pair_land_on_rtklib(tmp_path):
    r = run_cli("rtk", "--base", BASE, "--rover", ROVER, "--nav", NAV, "--base-xyz", *BASE_XYZ, "--signals", "G:L1,G:L2",
                "--mode", "static", "--pos-frame", "enu", "-o", tmp_path / "s.pos", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["signal_codes"] == {"base": {"G:L1": ["L1C", "C1C"], "G:L2": ["L2W", "C2W"]},
                                                    "rover": {"G:L1": ["L1C", "C1C"], "G:L2": ["L2W", "C2W"]}}
    last = [ln.split() for ln in (tmp_path / "s.pos").read_text().splitlines() if not ln.startswith("%")][-1]
    assert int(last[5]) == 1 and np.abs(np.array(last[2:5], dtype=float) - RTKLIB_ENU).max() < 0.002, last
    cfg = tmp_path / "cfg.toml"
    r = run_cli("-q", "config", "--rinex", f"base={BASE}", "--rinex", f"rover={ROVER}", "--nav", NAV, "--master", "base",
                "--signals", "G:L1,G:L2", "-o", cfg)
    assert r.exit_code == 0, r.output
    cfg.write_text(cfg.read_text().replace("# position_ecef_m = [x, y, z]", f"position_ecef_m = [{', '.join(BASE_XYZ)}]", 1))
    for args in (("ingest", "--config", cfg, "-o", tmp_path / "run.mcap"), ("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, r.output
    rover = json.loads((tmp_path / "init.json").read_text())["rovers"]["rover"]
    assert rover["solution"] == "fixed"
    assert np.abs(np.array(rover["baseline_enu_from_master_m"]) - RTKLIB_ENU).max() < 0.003, rover["baseline_enu_from_master_m"]
    r = run_cli("baseline", "--config", cfg, "-o", tmp_path / "bl.json")      # GPS L1 alone: says so
    note = f"{cfg}: [gnss] signals G:L2 not used: 'cdgps baseline' solves GPS L1 alone"
    assert r.exit_code == 0 and note in r.output, r.output
    assert any(w.startswith(note) for w in json.loads((tmp_path / "bl.json").read_text())["warnings"])


def test_hour_by_hour_and_whole_ingest_choose_and_say_alike(tmp_path, monkeypatch):
    """A base listing L2C alone against a P(Y) rover: no common family, said once, at one place of the summary, by the
    hour-by-hour reading (from each file's header bytes) as by the whole one; the same RUN byte for byte."""
    import gzip

    from cdgps_cli.io import gnss_archive
    from cdgps_cli.config.structure import load_gnss_config
    from tests.io.test_gnss_hours import _same_run

    monkeypatch.setattr(gnss_archive, "OBS_BLOCK_S", 20.0)
    base, rover = tmp_path / "base.obs", tmp_path / "rover.obs"
    base.write_text(gzip.decompress(BASE.read_bytes()).decode().replace(" C2W L2W S2W ", " C2V L2V S2V ", 1))
    rover.write_bytes(gzip.decompress(ROVER.read_bytes()))
    cfg = tmp_path / "cfg.toml"
    r = run_cli("-q", "config", "--rinex", f"base={base}", "--rinex", f"rover={rover}", "--master", "base",
                "--signals", "G:L1,G:L2", "-o", cfg)
    assert r.exit_code == 0, r.output
    said = _same_run(load_gnss_config(cfg), tmp_path, monkeypatch)
    assert any("hour by hour" in m for m in said)
    s = __import__("cdgps_cli.pipeline.gnss_ingest", fromlist=["x"]).ingest_gnss(load_gnss_config(cfg),
                                                                                tmp_path / "again.mcap")
    notes = [w for w in s["warnings"] if w.startswith("G:L2: the receivers track different signals")]
    assert notes == ["G:L2: the receivers track different signals on this carrier (base L2X, rover L2W): each "
                     "satellite's bias between them stays in the double differences (centimetres, not cycles)"]


def test_a_plain_files_header_alone_is_read():
    from cdgps_cli.io.rinex_signals import _plain_header

    car = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "geonet-car" / "3034265G.21O"
    plain = REPO_ROOT / "tests" / "data" / "demo3.10o"
    head, compressed = _plain_header(plain)
    assert not compressed and head.rstrip().endswith(b"END OF HEADER") and len(head) < plain.stat().st_size
    assert _plain_header(BASE) is None and _plain_header(REPO_ROOT / "tests" / "data" / "P433_lli_subset.crx") is None
    if car.exists():
        assert phase_attributes_in_file(car, ["G:L2"]) == {"G:L2": "XW"}


def test_a_file_without_a_signals_types_does_not_narrow_the_receivers_attributes(monkeypatch):
    """A receiver's attributes of a signal are those every file that lists the signal lists: an hour whose header
    has no L2 types (or a file of another system, as gnss-sdr writes them) no longer makes the receiver's set empty
    (which left each file to read its own first attribute, a family mixed without a word); files that all list it
    still narrow it to what they share, and a signal no file lists stays empty (the reader refuses it)."""
    from cdgps_cli.io import rinex_signals  # noqa: PLC0415

    held = {"a": {"G:L2": "CW", "E:E1": ""}, "b": {"G:L2": "", "E:E1": "BC"}, "c": {"G:L2": "W", "E:E1": ""}}
    monkeypatch.setattr(rinex_signals, "phase_attributes_in_file", lambda path, signals, read=None: held[path])
    got = lambda *names: rinex_signals._receiver_attributes([("rinex", n, None) for n in names], ["G:L2", "E:E1"])  # noqa: E731
    assert got("a", "b") == {"G:L2": "CW", "E:E1": "BC"}
    assert got("b", "a") == {"G:L2": "CW", "E:E1": "BC"}
    assert got("a", "b", "c") == {"G:L2": "W", "E:E1": "BC"}
    assert got("a") == {"G:L2": "CW", "E:E1": ""}
    held["d"] = {"G:L2": "", "E:E1": ""}
    assert got("b", "d") == {"G:L2": "", "E:E1": "BC"}
