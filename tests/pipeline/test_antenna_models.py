"""Receiver antenna models in the static and modal path (``pipeline.antenna_models``): ``baseline --antex``, and
``[gnss] antex`` through ``ingest`` → ``init`` → ``estimate``.

Real data: the real mosaic-X5 rover of ``real-pairs/mosaic-static`` given a known phase-centre offset — every
pseudorange and phase moved by the range change of that offset along each satellite's line of sight
(``sim.rinex_edit``, computed from the broadcast orbits independently of the module under test) — is the
observations an antenna with that offset would have made at the same reference point.  Without the model the
solution moves by the offset; with an ANTEX file giving it, the solution is the unedited file's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from _shared import MOSAIC_DIR, REPO_ROOT, run_cli

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.io.antex import model_from_json, model_to_json, read_antex
from cdgps_cli.model.gps.orbits import ecef_to_enu, ecef_to_geodetic, enu_matrix, sat_position_ecef, select_ephemeris
from cdgps_cli.model.gps.positioning import synthetic_nav
from cdgps_cli.pipeline.antenna_models import obs_with_antenna_model, signals_with_antenna_model
from tests.io.test_antex import antenna_block, write_antex

#: the rover antenna's phase-centre offset, north, east, up (mm), the same on every frequency
PCO_MM = (4.0, -3.0, 120.0)
ZEN = np.arange(0.0, 90.1, 5.0)
PCV_L1_MM = np.round(2.0 * np.sin(np.radians(ZEN)), 2)      # as the file writes them


@pytest.fixture(scope="module")
def antex(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("atx") / "r.atx"
    write_antex(p, [antenna_block("ROVERANT        NONE", {f: (PCO_MM, np.zeros(19)) for f in ("G01", "G02")}),
                    antenna_block("VARIANT         NONE", {"G01": (PCO_MM, PCV_L1_MM)})])
    return p


def _independent_range_m(nav, sat, t, xyz, pco_mm, pcv_mm):
    """−PCO·u + PCV(z) of one satellite at time t from ``xyz``, from the ENU vector to the satellite."""
    p, _ = sat_position_ecef(select_ephemeris(nav, sat, np.array([t])), np.array([t]))
    v = ecef_to_enu(np.asarray(p, float).reshape(3), xyz)
    u = v / np.linalg.norm(v)
    n, e, up = np.asarray(pco_mm) * 1e-3
    zen = np.degrees(np.arccos(u[2]))
    return -(u @ [e, n, up]) + np.interp(zen, ZEN, pcv_mm) * 1e-3


def test_a_gps_l1_table_and_a_signal_table_are_corrected_as_the_closed_form_says(antex):
    t0 = gps_seconds(2024, 3, 1)
    nav = synthetic_nav(("G", "E"), t0, 3600.0, seed=3)
    xyz = np.array([-3978242.4, 3382841.2, 3649902.8])
    model = read_antex(antex)[("VARIANT", "NONE")]
    # three satellites above the horizon (47.8°, 16.3°, 31.1°), one below it, a Galileo row (not GPS L1) and a
    # satellite without ephemeris
    sats = ["G05", "G07", "G15", "G01", "E11", "G99"]
    obs = pd.DataFrame({"time_gps_s": np.full(6, t0 + 600.0), "sat": sats, "phase_l1_cycles": np.full(6, 1.0e8),
                        "pseudorange_l1_m": np.full(6, 2.2e7), "lli_l1": np.zeros(6, dtype=np.int64)})
    obs.attrs = {"note": 1}
    out = obs_with_antenna_model(obs, nav, xyz, model)
    d = obs["pseudorange_l1_m"] - out["pseudorange_l1_m"]
    for k, s in enumerate(sats[:4]):
        assert d[k] == pytest.approx(_independent_range_m(nav, s, t0 + 600.0, xyz, PCO_MM, PCV_L1_MM), abs=1e-8), s
    assert d[4] == 0.0 and d[5] == 0.0
    np.testing.assert_allclose((obs["phase_l1_cycles"] - out["phase_l1_cycles"]) * GPS_L1_WAVELENGTH_M, d, atol=1e-6)
    assert out.attrs == {"note": 1} and list(out.columns) == list(obs.columns)
    assert out["lli_l1"].equals(obs["lli_l1"])
    sig = pd.DataFrame({"time_gps_s": [t0 + 600.0] * 2, "sat": ["G05", "G05"], "signal": ["G:L1", "G:L2"],
                        "phase_cycles": [1.0e8, 0.8e8], "pseudorange_m": [2.2e7, 2.2e7], "wavelength_m": [0.1903, 0.2442]})
    with pytest.raises(Exception, match="no calibration for G:L2"):       # VARIANT has G01 only
        signals_with_antenna_model(sig, nav, xyz, model)
    both = read_antex(antex)[("ROVERANT", "NONE")]
    got = signals_with_antenna_model(sig, nav, xyz, both)
    dd = sig["pseudorange_m"] - got["pseudorange_m"]
    assert dd[0] == pytest.approx(_independent_range_m(nav, "G05", t0 + 600.0, xyz, PCO_MM, np.zeros(19)), abs=1e-8)
    np.testing.assert_allclose((sig["phase_cycles"] - got["phase_cycles"]) * sig["wavelength_m"], dd, atol=1e-6)


def test_a_calibration_survives_its_json_round_trip(antex):
    m = read_antex(antex)[("VARIANT", "NONE")]
    back = model_from_json(json.loads(json.dumps(model_to_json(m))), "here")
    assert back.name == m.name and back.source == "r.atx"          # by name: a RUN holds no machine's path
    np.testing.assert_array_equal(back.zenith_deg, m.zenith_deg)
    np.testing.assert_array_equal(back.variations_mm["G01"], m.variations_mm["G01"])
    np.testing.assert_array_equal(back.offsets_neu_mm["G01"], m.offsets_neu_mm["G01"])
    bad = model_to_json(m)
    bad["variations_mm"]["G01"] = bad["variations_mm"]["G01"][:-1]
    with pytest.raises(Exception, match="here: not an antenna calibration"):
        model_from_json(bad, "here")


# ---- the real mosaic pair, the rover given a known offset


def _pcv_change(nav, xyz, pcv_mm, times):
    """``range_change_m`` of a variation ``pcv_mm`` on :data:`ZEN` (the same on every band): each GPS satellite's
    zenith angle from its broadcast orbit at the epoch (0 for the other systems' satellites), every satellite's
    angles at the file's epochs ``times`` computed at once."""
    times = np.asarray(times, float)
    pcv = {}
    for s in sorted(set(nav["sat"])):
        try:
            p, _ = sat_position_ecef(select_ephemeris(nav, s, times), times)
        except Exception:                                   # (a satellite not covered at every epoch: none)
            continue
        v = ecef_to_enu(np.asarray(p, float).reshape(-1, 3), xyz)
        zen = np.degrees(np.arccos(v[:, 2] / np.linalg.norm(v, axis=1)))
        pcv[s] = np.interp(zen, ZEN, pcv_mm) * 1e-3

    def change(t, sats):
        k = int(np.searchsorted(times, t))
        return np.array([pcv[s][k] if s in pcv else 0.0 for s in sats])
    return change


@pytest.fixture(scope="module")
def pco_pair(tmp_path_factory):
    """The real mosaic rover given a phase centre :data:`PCO_MM` off its reference point and the variation
    :data:`PCV_L1_MM` on both GPS bands, and the ANTEX file that says so (``ROVERANT``)."""
    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    import gzip

    from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s, range_change_of_motion

    d = tmp_path_factory.mktemp("pco")
    nav = read_rinex_nav(MOSAIC_DIR / "base.nav", systems=("G",))
    text = (MOSAIC_DIR / "rover.obs").read_text()
    xyz = np.asarray(read_rinex_obs(MOSAIC_DIR / "rover.obs")[0]["approx_position_xyz_m"], float)
    enu = np.array([PCO_MM[1], PCO_MM[0], PCO_MM[2]]) * 1e-3
    pco = range_change_of_motion(nav, xyz, lambda t: enu, epoch_times_gps_s(text))
    pcv = _pcv_change(nav, xyz, PCV_L1_MM, epoch_times_gps_s(text))
    edited = edit_rinex3_obs(text, range_change_m=lambda t, sats: pco(t, sats) + pcv(t, sats))
    (d / "rover_pco.obs").write_text(edited)
    (d / "rover_pco.obs.gz").write_bytes(gzip.compress(edited.encode(), mtime=0))    # read whole by ingest
    write_antex(d / "r.atx", [antenna_block("ROVERANT        NONE", {f: (PCO_MM, PCV_L1_MM) for f in ("G01", "G02")}),
                              antenna_block("L1ONLY          NONE", {"G01": (PCO_MM, np.zeros(19))})])
    return d


def _baseline(d, rover, *extra):
    out = d / f"b{len(list(d.glob('b*.json')))}.json"
    r = run_cli("baseline", "--rinex", f"base={MOSAIC_DIR / 'base.obs'}", "--rinex", f"rover={rover}", "--nav",
                MOSAIC_DIR / "base.nav", "--master", "base", "-o", out, "-q", *extra)
    assert r.exit_code == 0, r.output
    return json.loads(out.read_text())


def test_baseline_takes_a_known_offset_out_of_a_real_rover(pco_pair):
    d = pco_pair
    orig = np.array(_baseline(d, MOSAIC_DIR / "rover.obs")["baseline_enu_from_master_m"])
    raw = _baseline(d, d / "rover_pco.obs")
    assert "antennas" not in raw
    model = _baseline(d, d / "rover_pco.obs", "--antex", d / "r.atx", "--antenna", "rover=ROVERANT NONE", "--antenna",
                      "base=none")
    assert model["antennas"] == {"antex": str(d / "r.atx"), "receivers": {"base": None, "rover": "ROVERANT NONE"}}
    e, n, u = (PCO_MM[1], PCO_MM[0], PCO_MM[2])
    off = np.array(raw["baseline_enu_from_master_m"]) - orig          # the offset, and the variation's mean part
    np.testing.assert_allclose(off[:2], np.array([e, n]) * 1e-3, atol=5e-4)
    assert 1e-3 * u - 3e-3 < off[2] < 1e-3 * u + 3e-3
    np.testing.assert_allclose(np.array(model["baseline_enu_from_master_m"]) - orig, 0.0, atol=2e-5)


def _config(d, name: str, rover: Path, antex: bool, signals: bool = True) -> Path:
    lines = ["[gnss]", 'master = "base"', f'nav = ["{MOSAIC_DIR / "base.nav"}"]']
    lines += ['signals = ["G:L1", "G:L2"]'] if signals else []
    lines += ['antex = "r.atx"'] if antex else []
    lines += ["[gnss.antennas.base]", f'rinex = "{MOSAIC_DIR / "base.obs"}"'] + (['antenna_type = "none"'] if antex else [])
    lines += ["[gnss.antennas.rover]", f'rinex = "{rover}"'] + (['antenna_type = "ROVERANT NONE"'] if antex else [])
    p = d / f"{name}.toml"
    p.write_text("\n".join(lines) + "\n")
    return p


def _ingest_init(d, name, rover, antex, signals: bool = True):
    cfg = _config(d, name, rover, antex, signals)
    for args in (("ingest", "--config", cfg, "-o", d / f"{name}.mcap", "-q"),
                 ("init", d / f"{name}.mcap", "-o", d / f"{name}.json", "-q")):
        r = run_cli(*args)
        assert r.exit_code == 0, r.output
    return json.loads((d / f"{name}.json").read_text())


def test_init_and_estimate_take_the_run_s_calibrations(pco_pair):
    d = pco_pair
    orig = _ingest_init(d, "orig", MOSAIC_DIR / "rover.obs", False)
    got = _ingest_init(d, "model", d / "rover_pco.obs", True)
    assert "antennas" not in orig
    assert got["antennas"] == {"antex": "r.atx", "receivers": {"base": None, "rover": "ROVERANT NONE"}}
    for c in "enu":
        assert got["states"][f"rover_{c}"] == pytest.approx(orig["states"][f"rover_{c}"], abs=2e-5), c
    r = run_cli("info", d / "model.mcap")
    assert r.exit_code == 0 and "antenna models from r.atx: base none, rover ROVERANT NONE" in r.output, r.output
    deep = run_cli("info", "--deep", "--json", d / "model.mcap")
    assert deep.exit_code == 0, deep.output
    assert json.loads(deep.output[deep.output.index("{"):])["gnss"]["antennas"]["receivers"]["rover"] == "ROVERANT NONE"
    r = run_cli("estimate", d / "model.mcap", "--init", d / "model.json", "-o", d / "model_states.mcap", "-q", "--json")
    assert r.exit_code == 0, r.output
    r = run_cli("export", d / "model_states.mcap", "-o", d / "model.csv", "-q")
    assert r.exit_code == 0, r.output
    states = pd.read_csv(d / "model.csv", comment="#")
    assert len(states) == 301
    for c in "enu":
        col = next(k for k in states.columns if k.startswith(f"rover_{c}"))
        assert states[col].iloc[-1] == pytest.approx(orig["states"][f"rover_{c}"], abs=2e-5), c


def test_init_on_gps_l1_takes_the_calibration_out_of_a_rover_read_whole(pco_pair):
    """The GPS L1 path (no ``[gnss] signals``: the receivers' raw tables anchor the solution) with the rover gzipped,
    which ``ingest`` reads whole (not hour by hour): INIT is the recorded rover's, and two RUNs made of the same
    files from two directories are the same bytes (the RUN keeps the ANTEX file by name, not by path)."""
    d = pco_pair
    orig = _ingest_init(d, "orig_l1", MOSAIC_DIR / "rover.obs", False, signals=False)
    got = _ingest_init(d, "model_l1", d / "rover_pco.obs.gz", True, signals=False)
    for c in "enu":
        assert got["states"][f"rover_{c}"] == pytest.approx(orig["states"][f"rover_{c}"], abs=2e-5), c
    other = d / "elsewhere"
    other.mkdir()
    (other / "r.atx").write_bytes((d / "r.atx").read_bytes())
    cfg = (d / "model_l1.toml").read_text()
    (other / "model_l1.toml").write_text(cfg)
    r = run_cli("ingest", "--config", other / "model_l1.toml", "-o", other / "model_l1.mcap", "-q")
    assert r.exit_code == 0, r.output
    assert (other / "model_l1.mcap").read_bytes() == (d / "model_l1.mcap").read_bytes()


def test_a_run_s_antenna_problems_are_named_before_anything_is_written(pco_pair, tmp_path):
    d = pco_pair
    cfg = _config(d, "ok", d / "rover_pco.obs", True).read_text()
    cases = (
        (cfg.replace("ROVERANT NONE", "OTHER NONE"), ("no calibration of", "'OTHER NONE'", "[gnss.antennas.rover] antenna_type")),
        (cfg.replace('antex = "r.atx"\n', ""), ("gnss.antennas.rover.antenna_type", "no gnss.antex file")),
        (cfg.replace("ROVERANT NONE", "L1ONLY NONE"), ("antenna L1ONLY NONE", "has no calibration for G:L2",
                                                       "[gnss] signals")),
    )
    cases += ((cfg.replace('antex = "r.atx"', 'antex = "absent.atx"'),
               ("bad3.toml: [gnss] antex", "absent.atx: cannot read: no such file")),)
    for k, (text, words) in enumerate(cases):
        p = d / f"bad{k}.toml"
        p.write_text(text)
        out = tmp_path / f"bad{k}.mcap"
        r = run_cli("ingest", "--config", p, "-o", out, "-q")
        flat = " ".join(r.output.split())
        assert r.exit_code == 2 and "Traceback" not in r.output and not out.exists(), r.output
        assert all(w in flat for w in words), (words, flat)


def test_ingest_says_when_the_antennas_differ_and_no_file_is_given(tmp_path):
    car = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "geonet-car"
    if not car.exists():
        pytest.skip("../shared/data/real-pairs absent")
    r = run_cli("ingest", "--rinex", f"base={car / '3034265G.21O'}", "--rinex", f"car={car / 'SEPT265G.21O'}",
                "--nav", car / "SEPT2650.21P", "--master", "base", "-o", tmp_path / "car.mcap", "-q", "--json")
    assert r.exit_code == 0, r.output
    warn = json.loads(r.output[r.output.index("{"):])["warnings"]
    assert any(w.startswith("the antennas differ") and "TRM159900.00 SCIS" in w and "JAVRINGANT_DM JVDM" in w
               and "[gnss] antex" in w for w in warn), warn


def test_a_starter_config_names_each_header_s_antenna_for_an_antex_file(tmp_path):
    """``cdgps config`` writes each RINEX header's antenna type as a commented ``antenna_type`` and a commented
    ``[gnss] antex``: uncommented as written, the config is one that ``ingest`` takes (a blank or ``Unknown``
    header writes none)."""
    car = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "geonet-car"
    if not car.exists():
        pytest.skip("../shared/data/real-pairs absent")
    from cdgps_cli.config.structure import parse_gnss_config

    out = tmp_path / "car.toml"
    r = run_cli("config", "--rinex", f"base={car / '3034265G.21O'}", "--rinex", f"car={car / 'SEPT265G.21O'}",
                "--rinex", f"ms={MOSAIC_DIR / 'rover.obs'}", "--nav", car / "SEPT2650.21P", "-o", out, "-q")
    assert r.exit_code == 0, r.output
    text = out.read_text()
    assert '# antenna_type = "TRM159900.00 SCIS"' in text and '# antenna_type = "JAVRINGANT_DM JVDM"' in text
    assert text.count("# antenna_type =") == 2                     # the mosaic rover's header says "Unknown"
    cfg = parse_gnss_config(text.replace("# antex =", "antex =").replace("# antenna_type =", "antenna_type ="), "x.toml")
    assert cfg.antex == "igs20.atx"
    assert {a.name: a.antenna_type for a in cfg.antennas} == {"base": "TRM159900.00 SCIS", "car": "JAVRINGANT_DM JVDM",
                                                              "ms": None}


def test_baseline_with_a_job_s_types_and_stations_renamed_on_the_command_line(pco_pair):
    """``--rinex`` replaces a job's stations, and with them the job's antenna types (a review found them kept and
    refused as "--antenna base: not one of the stations given", no --antenna given): the renamed stations' antennas
    are their headers' ("Unknown" here: named by --antenna)."""
    d = pco_pair
    cfg = _config(d, "job", d / "rover_pco.obs", True, signals=False)
    args = ("baseline", "--config", cfg, "--rinex", f"a={MOSAIC_DIR / 'base.obs'}", "--rinex", f"b={d / 'rover_pco.obs'}",
            "--master", "a", "-q")
    r = run_cli(*args, "-o", d / "renamed.json")
    flat = " ".join(r.output.split())
    assert r.exit_code == 2 and "not one of the stations" not in flat and "names no antenna" in flat, flat
    r = run_cli(*args, "-o", d / "renamed.json", "--antenna", "a=none", "--antenna", "b=ROVERANT NONE")
    assert r.exit_code == 0, r.output
    got = json.loads((d / "renamed.json").read_text())
    assert got["antennas"]["receivers"] == {"a": None, "b": "ROVERANT NONE"}


def test_ingest_takes_the_antex_file_and_the_types_from_the_command_line(pco_pair):
    """``ingest --rinex … --antex FILE --antenna NAME=TYPE`` without a config: the RUN keeps the same calibrations as
    a config's ``[gnss] antex`` gives, and INIT is the same; a type without a file is refused (exit 2, no RUN)."""
    d = pco_pair
    common = ("ingest", "--rinex", f"base={MOSAIC_DIR / 'base.obs'}", "--rinex", f"rover={d / 'rover_pco.obs'}",
              "--nav", MOSAIC_DIR / "base.nav", "--master", "base", "--signals", "G:L1", "-q")
    r = run_cli(*common, "--antex", d / "r.atx", "--antenna", "base=none", "--antenna", "rover=ROVERANT NONE",
                "-o", d / "cli.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["antennas"] == {"antex": "r.atx", "receivers": {"base": None, "rover": "ROVERANT NONE"}}
    r = run_cli("init", d / "cli.mcap", "-o", d / "cli.json", "-q")
    assert r.exit_code == 0, r.output
    got = json.loads((d / "cli.json").read_text())
    ref = _ingest_init(d, "cfg_l1", d / "rover_pco.obs", True, signals=False)
    assert got["antennas"] == ref["antennas"]
    for c in "enu":
        assert got["states"][f"rover_{c}"] == pytest.approx(ref["states"][f"rover_{c}"], abs=1e-9), c
    out = d / "cli_bad.mcap"
    r = run_cli(*common, "--antenna", "rover=ROVERANT NONE", "-o", out)
    assert r.exit_code == 2 and "no ANTEX file" in r.output and not out.exists(), r.output


def test_an_antenna_named_with_a_third_word_is_refused(pco_pair, tmp_path):
    """IGS types hold no space: "LEIAR10 NONE junk" took LEIAR10's calibration, the third word dropped unsaid (a
    sweep of real files); now refused naming the option, in every command."""
    d = pco_pair
    out = tmp_path / "b.json"
    r = run_cli("baseline", "--rinex", f"base={MOSAIC_DIR / 'base.obs'}", "--rinex", f"rover={d / 'rover_pco.obs'}",
                "--nav", MOSAIC_DIR / "base.nav", "--master", "base", "-o", out, "--antex", d / "r.atx", "--antenna",
                "rover=ROVERANT NONE junk", "--antenna", "base=none")
    flat = " ".join(r.output.split())
    assert r.exit_code == 2 and "expected an antenna type and at most its radome" in flat and "got 3 words" in flat
    assert not out.exists()
    out = tmp_path / "run.mcap"
    r = run_cli("ingest", "--rinex", f"base={MOSAIC_DIR / 'base.obs'}", "--rinex", f"rover={d / 'rover_pco.obs'}",
                "--nav", MOSAIC_DIR / "base.nav", "--master", "base", "--antex", d / "r.atx", "--antenna",
                "rover=ROVERANT NONE junk", "-o", out)
    assert r.exit_code == 2 and "got 3 words" in " ".join(r.output.split()) and not out.exists(), r.output
