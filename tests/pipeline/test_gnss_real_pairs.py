"""`cdgps rtk` on real receiver pairs, made as hard as low-cost receivers make them (issue 28).

The clean real pair (two Septentrio mosaic-X5, ../shared/data/real-pairs/mosaic-static) is edited
with sim/rinex_edit into what a u-blox pair writes: a base that logs with gaps (a quarter of its
epochs, gaps of 1–8 s), base tags at .990/.991 s and rover tags at .991/.992 s (millisecond clock
steering, observations moved with the clock); a 5 s base; a rover carrying a known vibration.  The
answers are known: the original pair's solution, RTKLIB's fixed mean on the original files, and
the vibration that was added.
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.io.solution_formats import read_pos
from cdgps_cli.model.gps.orbits import ecef_to_enu, ecef_to_geodetic
from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s, range_change_of_motion
from tests._shared import REPO_ROOT, run_cli, write_gappy_mosaic_pair

SHARED = REPO_ROOT.parent / "shared" / "data"
MOSAIC = SHARED / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")
BASE_XYZ = np.array([-3817681.1213, 3562839.4311, 3650159.1593])   # base_position.txt in ECEF
T0 = 1403252400.0                                                   # 2024-06-24 08:20:00 GPST
VIB_AMP_M, VIB_HZ = 0.004, 0.15


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("mosaic")
    base, rover = (MOSAIC / "base.obs").read_text(), (MOSAIC / "rover.obs").read_text()
    write_gappy_mosaic_pair(d)
    (d / "base_5s.obs").write_text(edit_rinex3_obs(base, keep=lambda t: round(t) % 5 == 0))
    nav = read_rinex_nav(MOSAIC / "base.nav", systems=("G",))
    rover0 = BASE_XYZ + np.array([-0.2556, -0.6052, -0.7812])
    vib = range_change_of_motion(nav, rover0, lambda t: (VIB_AMP_M * np.sin(2 * np.pi * VIB_HZ * (t - T0)), 0.0, 0.0),
                                 times_gps_s=epoch_times_gps_s(rover))        # (vectorized: 4.3 -> 0.1 s, the same text)
    (d / "rover_vib.obs").write_text(edit_rinex3_obs(rover, range_change_m=vib))
    return d


def _rtk(d, base, rover, name, *extra):
    out = d / name
    r = run_cli("-q", "rtk", "--base", base, "--rover", rover, "--nav", MOSAIC / "base.nav", "--signals", "G:L1",
                "--base-xyz", *BASE_XYZ, "-o", out, "--json", *extra)
    assert r.exit_code == 0, r.output
    import json
    summary = json.loads(r.stdout)
    df = pd.read_csv(out, comment="#")
    return summary, df


@pytest.fixture(scope="module")
def original(files):
    return _rtk(files, MOSAIC / "base.obs", MOSAIC / "rover.obs", "orig.csv")


def _enu(df):
    return df[["e_m", "n_m", "u_m"]].to_numpy()


def test_original_pair_matches_rtklib_fixed_mean(original):
    s, df = original
    assert s["epochs"] == 301 and s["fixed_epochs"] == 301
    ref = read_pos(MOSAIC / "rtklib" / "gps_l1_kinematic.pos")
    assert ref["frame"] == "enu" and (ref["q"] == 1).sum() == 301
    ours, theirs = _enu(df).mean(axis=0), ref["coords"][ref["q"] == 1].mean(axis=0)
    assert np.all(np.abs(ours - theirs) < 0.003), (ours, theirs)     # same signals: within 3 mm (1 cm asked)
    np.testing.assert_allclose(_enu(df).std(axis=0), ref["coords"].std(axis=0), rtol=0.25)


def test_gappy_base_with_millisecond_tags_uses_every_rover_epoch(files, original):
    s, df = _rtk(files, files / "base_gappy.obs", files / "rover_ms.obs", "gappy.csv")
    ep = s["epoch_pairing"]
    assert ep["rover_epochs"] == ep["used"] == s["epochs"] == 301 and ep["dropped"] == {}
    assert ep["base_epochs"] < 80 and ep["bridged"] > 200 and 0 < ep["max_age_s"] <= 8
    assert s["fixed_epochs"] >= 295                             # RTKLIB fixes all 301 of the ungapped pair
    fixed = df["fixed"].to_numpy() == 1
    d = _enu(df)[fixed] - _enu(original[1])[fixed]
    assert np.sqrt(np.mean(d[:, :2] ** 2)) < 0.004 and np.sqrt(np.mean(d[:, 2] ** 2)) < 0.006
    assert np.abs(d).max() < 0.03                               # no wrong fix
    np.testing.assert_allclose(df["age_s"].abs().max(), ep["max_age_s"], atol=2e-3)


def test_rover_clock_steering_changes_nothing(files, original):
    s, df = _rtk(files, MOSAIC / "base.obs", files / "rover_ms.obs", "ms.csv")
    assert s["epoch_pairing"]["simultaneous"] == 301
    assert np.abs(_enu(df) - _enu(original[1])).max() < 5e-4


def test_five_second_base_bridged_with_growing_sigma(files, original):
    s, df = _rtk(files, files / "base_5s.obs", MOSAIC / "rover.obs", "b5.csv")
    assert s["epochs"] == 301 and s["fixed_epochs"] == 301 and s["epoch_pairing"]["max_age_s"] == pytest.approx(2.0)
    age = df["age_s"].abs().to_numpy()
    assert df["sigma_u_m"][age > 1.5].mean() > df["sigma_u_m"][age < 0.5].mean()   # σ grows with the base age
    assert np.abs(_enu(df) - _enu(original[1])).max() < 0.03


@pytest.mark.parametrize("base", ["base.obs", "base_gappy.obs"])
def test_known_vibration_is_recovered(files, original, base):
    """4 mm at 0.15 Hz added to the real rover's ranges, against the clean base and against the
    u-blox-like gappy base (a quarter of its epochs): within 10 % in amplitude and 1 % in frequency,
    from at least 95 % of the rover's epochs fixed."""
    s, df = _rtk(files, (MOSAIC if base == "base.obs" else files) / base, files / "rover_vib.obs", f"vib_{base}.csv")
    assert s["fixed_epochs"] >= 0.95 * 301
    e = _enu(df)[:, 0] - _enu(original[1])[:, 0]
    t = df["time_gps_s"].to_numpy() - T0
    best = None
    for f in np.linspace(0.9 * VIB_HZ, 1.1 * VIB_HZ, 401):
        A = np.c_[np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)]
        c = np.linalg.lstsq(A, e, rcond=None)[0]
        r = np.sum((A @ c - e) ** 2)
        if best is None or r < best[0]:
            best = (r, f, np.hypot(c[0], c[1]))
    assert abs(best[1] / VIB_HZ - 1) < 0.01 and abs(best[2] / VIB_AMP_M - 1) < 0.10, best


def test_output_formats(files):
    base, rover = files / "base_gappy.obs", files / "rover_ms.obs"
    for ext in ("pos", "nmea", "geojson"):
        out = files / f"sol.{ext}"
        r = run_cli("-q", "rtk", "--base", base, "--rover", rover, "--nav", MOSAIC / "base.nav", "--signals", "G:L1",
                    "--base-xyz", *BASE_XYZ, "-o", out)
        assert r.exit_code == 0, r.output
    p = read_pos(files / "sol.pos")
    csv = pd.read_csv(files / "gappy.csv", comment="#") if (files / "gappy.csv").exists() else None
    assert p["frame"] == "llh" and p["time_gps_s"].size == 301 and set(p["q"]) <= {1, 2}
    lat, lon, h = ecef_to_geodetic(BASE_XYZ)
    assert np.abs(p["coords"][:, 0] - np.degrees(lat)).max() < 1e-4 and np.all(p["ns"] >= 4)
    assert p["time_gps_s"][0] == pytest.approx(T0 - 0.009, abs=1e-3)       # the rover's own tags drive
    if csv is not None:
        np.testing.assert_array_equal(p["q"] == 1, csv["fixed"].to_numpy() == 1)
    gga = (files / "sol.nmea").read_text().splitlines()
    assert len(gga) == 301 and all(ln.startswith("$GPGGA,") for ln in gga)
    assert {ln.split(",")[6] for ln in gga} <= {"4", "5"}
    import json
    gj = json.loads((files / "sol.geojson").read_text())
    assert gj["type"] == "FeatureCollection" and len(gj["features"]) == 301


def test_geonet_pair_uses_all_120_epochs(tmp_path):
    g = SHARED / "rinex"
    r = run_cli("-q", "rtk", "--base", g / "07590920.05o", "--rover", g / "30400920.05o", "--nav", g / "07590920.05n",
                "--signals", "G:L1,G:L2", "-o", tmp_path / "g.csv", "--json")
    assert r.exit_code == 0, r.output
    import json
    s = json.loads(r.stdout)
    assert s["epochs"] == 120 and s["epoch_pairing"]["dropped"] == {} and s["fixed_epochs"] >= 110


def _init(d, base, rover, name, signals=None):
    """ingest → init of the pair (master = base); the INIT's rover record."""
    import json
    cfg = d / f"{name}.toml"
    r = run_cli("-q", "config", "--rinex", f"base={base}", "--rinex", f"rover={rover}", "--nav", MOSAIC / "base.nav",
                "--master", "base", "--signals", ",".join(signals or ["G:L1"]), "-o", cfg)
    assert r.exit_code == 0, r.output
    text = cfg.read_text()              # the base at base_position.txt (its header is 0.4 m off), as RTKLIB ran
    head, tail = text.split('[gnss.antennas."base"]\n', 1)
    text = head + '[gnss.antennas."base"]\n' + f"position_ecef_m = [{', '.join(map(str, BASE_XYZ))}]\n" + tail
    cfg.write_text(text)
    for args in (("ingest", "--config", cfg, "-o", d / f"{name}.mcap"), ("init", d / f"{name}.mcap", "-o", d / f"{name}.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    return json.loads((d / f"{name}.json").read_text())["rovers"]["rover"]


def test_init_on_a_gappy_base_uses_every_rover_epoch(files):
    """The M8P case of issue 28 (init used 88 of 1205 rover epochs: a 3 s grid guessed from the base's
    median spacing): every rover epoch is used, and the static baseline is the clean pair's."""
    a = _init(files, MOSAIC / "base.obs", MOSAIC / "rover.obs", "clean")
    b = _init(files, files / "base_gappy.obs", files / "rover_ms.obs", "gappy")
    assert a["solution"] == b["solution"] == "fixed"
    ea, eb = a["epochs"], b["epochs"]
    assert ea["n_epochs_used"] == eb["n_epochs_used"] == 301
    assert eb["epoch_pairing"]["bridged"] > 200 and eb["epoch_pairing"]["dropped"] == {}
    da, db = np.array(a["baseline_enu_from_master_m"]), np.array(b["baseline_enu_from_master_m"])
    assert np.all(np.abs(da - db) < 0.002), (da, db)
    # against RTKLIB's GPS L1 static solution of the clean pair (its last epoch), same signals
    ref = read_pos(MOSAIC / "rtklib" / "gps_l1_static.pos")
    assert np.all(np.abs(db - ref["coords"][-1]) < 0.003), (db, ref["coords"][-1])      # 1 cm asked


def test_init_with_signals_on_a_gappy_base(files):
    sig = ["G:L1", "G:L2", "E:E1"]
    a = _init(files, MOSAIC / "base.obs", MOSAIC / "rover.obs", "clean_sig", sig)
    b = _init(files, files / "base_gappy.obs", files / "rover_ms.obs", "gappy_sig", sig)
    assert b["solution"] == "fixed" and b["epochs"]["n_epochs_used"] == 301
    assert np.all(np.abs(np.array(a["baseline_enu_from_master_m"]) - np.array(b["baseline_enu_from_master_m"])) < 0.002)


@pytest.mark.parametrize("case", ["base 0 0 0", "nav of another day", "no common epochs", "no double differences"])
def test_bad_input_exits_2_naming_the_file(tmp_path, case):
    geo = SHARED / "rinex"
    base, rover, nav, extra = MOSAIC / "base.obs", MOSAIC / "rover.obs", MOSAIC / "base.nav", []
    want = {"base 0 0 0": ["base.obs (base)", "--base-xyz", "0 0 0"],
            "nav of another day": ["07590920.05n", "2024-06-24", "2005-04", "navigation file(s) of the observations' day"],
            "no common epochs": ["no common epochs", "rover.obs (rover)", "07590920.05o (base)"],
            "no double differences": ["no double differences", "rover.obs (rover)", "89° mask"]}[case]
    if case == "base 0 0 0":
        extra = ["--base-xyz", 0, 0, 0]
    elif case == "nav of another day":
        nav = geo / "07590920.05n"
    elif case == "no common epochs":                       # the 2005 GEONET base beside the 2024 rover, both navs
        base, extra = geo / "07590920.05o", ["--nav", geo / "07590920.05n", "--base-xyz", *BASE_XYZ]
    else:
        extra = ["--mask-deg", 89]
    out = tmp_path / "out.pos"
    r = run_cli("-q", "rtk", "--base", base, "--rover", rover, "--nav", nav, "--signals", "G:L1", "-o", out, *extra)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert all(w in r.stderr for w in want), r.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_rover_without_a_header_position_gets_a_single_point_position(files, original):
    """u-blox converters write APPROX POSITION XYZ 0 0 0: the rover's a-priori position is then its
    mean single-point position (a warning says so), and the solution is the same."""
    text = (MOSAIC / "rover.obs").read_text().splitlines()
    text = ["        0.0000        0.0000        0.0000                  APPROX POSITION XYZ"
            if ln[60:].strip() == "APPROX POSITION XYZ" else ln for ln in text]
    (files / "rover0.obs").write_text("\n".join(text) + "\n")
    out = files / "rover0.csv"
    r = run_cli("rtk", "--base", MOSAIC / "base.obs", "--rover", files / "rover0.obs", "--nav", MOSAIC / "base.nav",
                "--signals", "G:L1", "--base-xyz", *BASE_XYZ, "-o", out)
    assert r.exit_code == 0, r.output
    assert "single-point position" in r.stderr
    df = pd.read_csv(out, comment="#")
    assert (df["fixed"] == 1).sum() == 301
    assert np.abs(_enu(df) - _enu(original[1])).max() < 0.001


CAR = SHARED / "real-pairs" / "geonet-car"


@pytest.fixture(scope="module")
def car(tmp_path_factory):
    """`cdgps rtk` of the real car (GPS + Galileo L1 against the CORS 5 km away) with and without fix-and-hold:
    ``{hold: (--json summary, solution)}``, each solved once for the tests below (read only)."""
    d = tmp_path_factory.mktemp("car")
    out = {}
    for hold in (False, True):
        path = d / f"car-{hold}.csv"
        r = run_cli("-q", "rtk", "--base", CAR / "3034265G.21O", "--rover", CAR / "SEPT265G.21O", "--nav", CAR / "SEPT2650.21P",
                    "--base-xyz", -3959400.631, 3385704.533, 3667523.111, "--signals", "G:L1,E:E1", "-o", path, "--json",
                    "--fix-and-hold" if hold else "--no-fix-and-hold")
        assert r.exit_code == 0, r.output
        import json
        out[hold] = json.loads(r.stdout), pd.read_csv(path, comment="#")
    return out


@pytest.mark.parametrize("hold", [False, True])
def test_car_against_a_cors_5_km_away(car, hold):
    """The real car of ../shared/data/real-pairs/geonet-car (GPS + Galileo L1, forward and backward
    combined): the fixed epochs of the two standing segments lie within 1 cm horizontally of the
    static multi-GNSS answers of its README (heights within 5 cm: 5.4 km of unmodelled ionosphere);
    fix-and-hold fixes more epochs, not fewer."""
    s, d = car[hold]
    t = (d["time_gps_s"] - d["time_gps_s"].iloc[0]).to_numpy()
    e, fixed = _enu(d), d["fixed"].to_numpy() == 1
    for seg, ref in (((t <= 34), (5083.057, 1707.376, -1.192)), ((t >= 312), (5049.078, 1691.873, -1.360))):
        dev = np.abs(e[fixed & seg] - np.array(ref))
        assert dev.size == 0 or (dev[:, :2].max() < 0.01 and dev[:, 2].max() < 0.05), dev.max(axis=0)
    assert s["epochs"] == 360 and s["fixed_epochs"] >= (250 if hold else 150)
    assert (fixed & (t <= 34)).sum() == 35


@pytest.mark.parametrize("signals,rtklib_enu", [
    ("E:E1", (-0.2275, -0.9638, 0.0079)),          # README: RTKLIB Galileo E1 only, kinematic fixed mean
    ("R:G1,R:G2", None),                            # GLONASS alone, identical receivers (--glonass-fix)
    ("C:B1I", None)])
def test_one_system_carries_the_solution_alone(tmp_path, signals, rtklib_enu):
    out = tmp_path / "one.csv"
    r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", MOSAIC / "rover.obs", "--nav", MOSAIC / "base.nav",
                "--signals", signals, "--base-xyz", *BASE_XYZ, "-o", out, "--glonass-fix")
    assert r.exit_code == 0, r.output
    d = pd.read_csv(out, comment="#")
    f = d[d["fixed"] == 1]
    assert len(f) >= 295
    truth = rtklib_enu or (-0.2237, -0.9647, 0.0090)      # else RTKLIB's multi-GNSS L1+L2 mean, within 1 cm
    assert np.all(np.abs(_enu(f).mean(axis=0) - np.array(truth)) < (0.001 if rtklib_enu else 0.01))


def test_info_and_ingest_say_which_epochs_are_used_and_why(files):
    """With gnss.max_age_s = 3 s, rover epochs in the gappy base's longer gaps are not used: ingest
    warns with the reasons, info and its JSON give the same counts, init uses exactly the rest."""
    import json
    cfg = files / "short_age.toml"
    r = run_cli("-q", "config", "--rinex", f"base={files / 'base_gappy.obs'}", "--rinex", f"rover={files / 'rover_ms.obs'}",
                "--nav", MOSAIC / "base.nav", "--master", "base", "-o", cfg)
    assert r.exit_code == 0, r.output
    text = cfg.read_text()
    assert "max_age_s = 30.0" in text                       # the starter config states the default
    cfg.write_text(text.replace("max_age_s = 30.0", "max_age_s = 3.0"))
    run = files / "short_age.mcap"
    r = run_cli("ingest", "--config", cfg, "-o", run)
    assert r.exit_code == 0 and "in a base gap (no base epoch within the maximum age)" in r.stderr, r.stderr
    r = run_cli("info", run, "--json")
    g = json.loads(r.stdout)["gnss"]
    p = g["epoch_pairing"]["rover"]
    assert 0 < sum(p["dropped"].values()) and p["used"] + sum(p["dropped"].values()) == 301
    assert g["common_epochs"]["rover"] == p["used"] and p["max_age_s"] <= 3.0
    r = run_cli("info", run)
    assert f"rover: {p['used']} epochs in common with base (of 301 rover epochs:" in r.stdout and "not used" in r.stdout
    r = run_cli("-q", "init", run, "-o", files / "short_age.json")
    assert r.exit_code == 0, r.output
    assert json.loads((files / "short_age.json").read_text())["rovers"]["rover"]["epochs"]["n_epochs_used"] == p["used"]


def test_correlated_code_is_an_option_with_honest_errors(tmp_path):
    """--code-correlation 60: code multipath correlated over a minute is not taken as 60 independent
    ranges; the real pair still fixes every epoch at the same answer; a negative time is refused."""
    out = tmp_path / "cc.csv"
    r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", MOSAIC / "rover.obs", "--nav", MOSAIC / "base.nav",
                "--signals", "G:L1", "--base-xyz", *BASE_XYZ, "--code-correlation", 60, "-o", out)
    assert r.exit_code == 0, r.output
    d = pd.read_csv(out, comment="#")
    assert (d["fixed"] == 1).sum() == 301
    assert np.all(np.abs(_enu(d).mean(axis=0) - np.array((-0.2239, -0.9633, 0.0058))) < 0.003)
    r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", MOSAIC / "rover.obs", "--nav", MOSAIC / "base.nav",
                "--code-correlation", -1, "-o", tmp_path / "bad.csv")
    assert r.exit_code == 2 and "code_correlation_s" in r.stderr and not (tmp_path / "bad.csv").exists()


def test_ublox_logs_go_straight_into_rtk(tmp_path):
    """A real u-blox log (real-pairs/ublox-walk: 4 Hz RXM-RAWX with RXM-SFRBX, NMEA mixed in, tags 2 ms
    before the grid) as both base and rover, without --nav: its SFRBX ephemerides are used, slips
    come from the lock times, the unresolved half cycles stay float, and the zero baseline is fixed
    at every epoch."""
    log = SHARED / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"
    base_xyz = (-1276975.6547, -4717238.8712, 4087235.6076)       # its receiver's first NAV-PVT fix
    out = tmp_path / "zero.csv"
    r = run_cli("rtk", "--base", log, "--rover", log, "--signals", "G:L1,E:E1", "--base-xyz", *base_xyz, "-o", out, "--json")
    assert r.exit_code == 0, r.output
    import json
    s = json.loads(r.stdout)
    assert s["epochs"] == s["epoch_pairing"]["rover_epochs"] == 536 and s["fixed_epochs"] >= 0.95 * 536
    d = pd.read_csv(out, comment="#")
    assert np.abs(d[["e_m", "n_m", "u_m"]].to_numpy()).max() < 0.002
    assert "single-point position" in r.stderr


def test_a_repeated_epoch_record_is_read_once(files, original):
    """The same epoch written twice in the rover file (issue 32: an AmbiguityError traceback): read
    once, with a warning naming the file; the solution is the clean one."""
    lines = (MOSAIC / "rover.obs").read_text().splitlines()
    starts = [i for i, ln in enumerate(lines) if ln.startswith(">")]
    a, b = starts[10], starts[11]
    (files / "rover_dup.obs").write_text("\n".join(lines[:b] + lines[a:b] + lines[b:]) + "\n")
    out = files / "dup.csv"
    r = run_cli("rtk", "--base", MOSAIC / "base.obs", "--rover", files / "rover_dup.obs", "--nav", MOSAIC / "base.nav",
                "--signals", "G:L1", "--base-xyz", *BASE_XYZ, "-o", out)
    assert r.exit_code == 0, r.output
    assert "rover_dup.obs (rover): 1 epoch(s) written more than once" in r.stderr
    d = pd.read_csv(out, comment="#")
    assert len(d) == 301 and np.abs(_enu(d) - _enu(original[1])).max() < 1e-4



def test_rtk_static_gps_l1_within_0_3_mm_of_rtklib(tmp_path):
    """Issue 28 item 1 must-not-regress figure: `rtk --mode static` on the real mosaic pair, GPS L1
    (the one engine: driver, DD model, ambiguity hooks, static motion model) ends within 0.3 mm of
    RTKLIB's static solution of the same files (both written to 0.1 mm)."""
    from cdgps_cli.pipeline.gnss_multi import rtk_from_files

    out = tmp_path / "static.csv"
    s = rtk_from_files(MOSAIC / "base.obs", MOSAIC / "rover.obs", [MOSAIC / "base.nav"], out, base_xyz_m=BASE_XYZ,
                       options={"signals": ("G:L1",), "mode": "static"})
    assert s["epochs"] == 301
    ref = read_pos(MOSAIC / "rtklib" / "gps_l1_static.pos")
    assert ref["frame"] == "enu" and ref["q"][-1] == 1
    d = pd.read_csv(out, comment="#")
    assert d["fixed"].iloc[-1] == 1
    assert np.all(np.abs(_enu(d)[-1] - ref["coords"][-1]) < 0.00031), (_enu(d)[-1], ref["coords"][-1])


def test_zero_baseline_rover_troposphere_where_the_rover_is(tmp_path, monkeypatch):
    """A zero baseline must come out zero.  The u-blox walk's RINEX conversion as the rover against its
    own UBX log as the base: the conversion's APPROX POSITION XYZ is 13.7 m from the antenna (10.9 m
    low), and with the rover's troposphere evaluated there the fixed heights sat 4.3 mm low (RMS
    4.9 mm).  rtk now moves the rover's a-priori position to its static float solution before solving
    (one batch, no second solve; it solved again with the troposphere at each fixed epoch's position
    before), says so, and the zero baseline is zero.  (Ten epochs whose three or four held integers
    leave the position's σ above MAX_FIXED_SIGMA_M are reported float: 525 fixed of 536.)"""
    walk = SHARED / "real-pairs" / "ublox-walk"
    out = tmp_path / "zero.csv"
    import cdgps_cli.pipeline.gnss_multi as gm
    solves, real = [], gm.solve_rtk
    monkeypatch.setattr(gm, "solve_rtk", lambda *a, **k: solves.append(1) or real(*a, **k))
    r = run_cli("rtk", "--base", walk / "gnss_1730.ubx", "--rover", walk / "gnss_1730_convbin.obs", "--signals", "G:L1,E:E1",
                "--base-xyz", -1276975.6547, -4717238.8712, 4087235.6076, "-o", out, "--json")
    assert r.exit_code == 0, r.output
    import json
    s = json.loads(r.stdout)
    assert s["rover_troposphere"] == "at the a-priori position" and len(solves) == 1          # was 2
    assert "its APPROX POSITION XYZ is 13.7 m (height +10.9 m) from its static float solution, more than 1 m" in r.stderr
    d = pd.read_csv(out, comment="#")
    f = d[d["fixed"] == 1]
    assert len(f) >= 520
    assert np.abs(np.median(_enu(f), axis=0)).max() < 0.0005                       # was 4.3 mm in height
    assert np.sqrt(np.mean(_enu(f) ** 2, axis=0)).max() < 0.001                    # was 4.9 mm


def test_car_heights_agree_with_rtklib_where_both_fix(car):
    """The car's rover header is 17.5 m above its antenna: with the rover's troposphere evaluated there,
    the 79 epochs both programs fixed sat 16.0 mm above RTKLIB's in median (Debian rnx2rtkp, G+E+J L1,
    forward; ../shared/data/real-pairs/geonet-car/rtklib/gej_l1_kinematic.pos).  Evaluated at each fixed
    epoch's position: 3.0 mm (the reference also uses QZSS, so single epochs differ by up to 3.4 cm; with
    the same signals, side by side in benchmarks/bench_rtk_rtklib.py, 0.6 mm in median, 5.5 mm at most)."""
    from cdgps_cli.config.options import MULTI_GNSS_DEFAULTS

    assert MULTI_GNSS_DEFAULTS["fix_and_hold"] is True          # the command's default: the fixture's hold run
    _, d = car[True]
    ref = read_pos(CAR / "rtklib" / "gej_l1_kinematic.pos")
    assert ref["frame"] == "enu"
    t, fixed = d["time_gps_s"].to_numpy(), d["fixed"].to_numpy() == 1
    k = np.clip(np.searchsorted(ref["time_gps_s"], t), 0, ref["time_gps_s"].size - 1)
    both = fixed & (np.abs(ref["time_gps_s"][k] - t) < 0.1) & (ref["q"][k] == 1)
    assert both.sum() >= 50
    diff = _enu(d)[both] - ref["coords"][k[both]]
    assert np.abs(np.median(diff, axis=0)).max() < 0.005, np.median(diff, axis=0)       # was 16.0 mm
    assert np.linalg.norm(diff, axis=1).max() < 0.05


def test_baseline_does_not_depend_on_a_header_15_m_high(tmp_path):
    """The static baseline (the solver of `baseline` and `init`) of the mosaic pair with the rover's
    APPROX POSITION XYZ as written and moved 15 m up: the fixed rover positions agree within 1 mm (they
    were 10.8 mm apart with the rover's troposphere at the a-priori position; now a solution more than
    1 m from it is solved again with the troposphere there, which the result and a warning say)."""
    import json

    from cdgps_cli.model.gps.orbits import enu_matrix

    lines = (MOSAIC / "rover.obs").read_text().splitlines()
    hi = []
    for ln in lines:
        if ln[60:].strip() == "APPROX POSITION XYZ":
            x = np.array([float(v) for v in ln[:60].split()])
            lat, lon, _ = ecef_to_geodetic(x)
            ln = "".join(f"{v:14.4f}" for v in x + 15.0 * enu_matrix(lat, lon)[2]).ljust(60) + "APPROX POSITION XYZ"
        hi.append(ln)
    (tmp_path / "rover_hi.obs").write_text("\n".join(hi) + "\n")
    fixed = []
    for rover in (MOSAIC / "rover.obs", tmp_path / "rover_hi.obs"):
        r = run_cli("-q", "baseline", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={rover}",
                    "--nav", MOSAIC / "base.nav", "--master", "base", "-o", tmp_path / "bl.json", "--json")
        assert r.exit_code == 0, r.output
        s = json.loads(r.stdout)
        assert s["solution"] == "fixed"
        fixed.append(np.asarray(s["fixed"]["rover_ecef_m"]))
        assert ("rover_troposphere_ecef_m" in s) == (rover != MOSAIC / "rover.obs")
    assert np.linalg.norm(fixed[1] - fixed[0]) < 0.001, np.linalg.norm(fixed[1] - fixed[0])


def test_init_and_estimate_do_not_depend_on_a_header_15_m_high(tmp_path):
    """ingest → init → estimate of the mosaic pair with the rover's header moved 15 m up: init's fixed
    rover position is the one of the header as written within 1 mm (10.8 mm apart before), INIT.json says
    where the rover's troposphere was evaluated, and estimate evaluates it there too (its static solution
    is INIT's, bit for bit)."""
    import json

    from cdgps_cli.model.gps.orbits import enu_matrix

    lines = (MOSAIC / "rover.obs").read_text().splitlines()
    for i, ln in enumerate(lines):
        if ln[60:].strip() == "APPROX POSITION XYZ":
            x = np.array([float(v) for v in ln[:60].split()])
            lat, lon, _ = ecef_to_geodetic(x)
            lines[i] = "".join(f"{v:14.4f}" for v in x + 15.0 * enu_matrix(lat, lon)[2]).ljust(60) + "APPROX POSITION XYZ"
    (tmp_path / "rover_hi.obs").write_text("\n".join(lines) + "\n")
    fixed = {}
    for name, rover in (("as_written", MOSAIC / "rover.obs"), ("high", tmp_path / "rover_hi.obs")):
        d = tmp_path / name
        d.mkdir()
        (d / "cfg.toml").write_text(
            f'[gnss]\nname = "{name}"\nmaster = "base"\nnav = ["{MOSAIC / "base.nav"}"]\n\n'
            f'[gnss.antennas.base]\nrinex = "{MOSAIC / "base.obs"}"\nposition_ecef_m = {BASE_XYZ.tolist()}\n\n'
            f'[gnss.antennas.rover]\nrinex = "{rover}"\n')
        for args in (("ingest", "--config", d / "cfg.toml", "-o", d / "run.mcap"), ("init", d / "run.mcap", "-o", d / "init.json"),
                     ("estimate", d / "run.mcap", "--init", d / "init.json", "-o", d / "states.mcap", "--json")):
            r = run_cli("-q", *args)
            assert r.exit_code == 0, r.output
        rov = json.loads((d / "init.json").read_text())["rovers"]["rover"]
        assert ("rover_troposphere_ecef_m" in rov) == (name == "high")
        assert json.loads(r.stdout)["rovers"]["rover"]["static_enu_m"] == rov["states"]
        fixed[name] = np.asarray(rov["rover_ecef_m"])
    assert np.linalg.norm(fixed["high"] - fixed["as_written"]) < 0.001
