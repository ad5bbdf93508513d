"""Baseline job files (pipeline/baseline_job.py): the GNSS-config form, the older [baseline] form, errors.

The solver itself is tested in tests/estimation/test_baseline.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
from cdgps_cli.pipeline.baseline_job import baseline_from_files, load_baseline_job

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared" / "data" / "rinex"
JOB = ROOT / "configs" / "geonet-0759-3040.toml"
ROVER_XYZ = np.array([-3976219.5082, 3382372.5671, 3652512.9849])    # 0759 RINEX header APPROX POSITION XYZ


def shared(name: str) -> Path:
    p = SHARED / name
    if not p.exists():
        pytest.skip(f"shared test data not available: {p} (the ../shared/data folder beside the repository)")
    return p


def test_geonet_job_file_loads():
    job = load_baseline_job(JOB)
    assert job["master"] == "3040" and set(job["rinex"]) == {"3040", "0759"}
    assert job["rinex"]["0759"].name == "07590920.05o" and len(job["nav"]) == 2
    assert job["options"].mask_deg == 15.0 and job["options"].ratio_threshold == 3.0


def test_baseline_config_writer_round_trip(tmp_path):
    obs = [shared("30400920.05o"), shared("07590920.05o")]
    out = tmp_path / "job.toml"
    r = CliRunner().invoke(main, ["baseline-config", "--rinex", f"3040={obs[0]}", "--rinex", f"0759={obs[1]}",
                                  "--nav", str(shared("30400920.05n")), "-o", str(out)])
    assert r.exit_code == 0, r.output
    job = load_baseline_job(out)
    assert job["master"] == "3040" and job["rinex"]["3040"].resolve() == obs[0].resolve()
    assert "TRIMBLE 5700" in out.read_text()


def test_job_file_errors(tmp_path):
    p = tmp_path / "job.toml"
    p.write_text('[baseline]\nmaster = "A"\nnav = []\nmask_deg = "x"\ncolour = 1\n[baseline.rinex]\nA = "a.o"\n')
    with pytest.raises(CdgpsError) as e:
        load_baseline_job(p)
    msg = str(e.value)
    for part in ("invalid baseline job", "baseline.mask_deg", "baseline.colour: unknown key", "exactly two stations",
                 "at least one navigation file"):
        assert part in msg, msg
    p.write_text("[baseline\n")
    with pytest.raises(CdgpsError, match="not valid TOML"):
        load_baseline_job(p)
    with pytest.raises(CdgpsError, match="cannot read"):
        load_baseline_job(tmp_path / "missing.toml")


def test_old_baseline_job_form_still_loads_and_gnss_positions_are_used(tmp_path):
    obs = [shared("30400920.05o"), shared("07590920.05o")]
    old = tmp_path / "old.toml"
    old.write_text(f'[baseline]\nmaster = "3040"\nnav = ["{shared("30400920.05n")}"]\nratio = 4.0\n'
                   f'[baseline.rinex]\n"3040" = "{obs[0]}"\n"0759" = "{obs[1]}"\n')
    job = load_baseline_job(old)
    assert job["master"] == "3040" and job["options"].ratio_threshold == 4.0 and job["positions"] == {}
    # a [gnss] config: position_ecef_m replaces the header position (here the rover's, moved 1 m up)
    up = ROVER_XYZ + enu_matrix(*ecef_to_geodetic(ROVER_XYZ)[:2]).T @ np.array([0.0, 0.0, 1.0])
    new = tmp_path / "new.toml"
    new.write_text(f'[gnss]\nmaster = "3040"\nnav = ["{shared("30400920.05n")}"]\n'
                   f'[gnss.antennas."3040"]\nrinex = "{obs[0]}"\n'
                   f'[gnss.antennas."0759"]\nrinex = "{obs[1]}"\nposition_ecef_m = [{float(up[0])!r}, {float(up[1])!r}, {float(up[2])!r}]\n')
    job = load_baseline_job(new)
    assert set(job["positions"]) == {"0759"}
    r = baseline_from_files(job["rinex"], job["nav"], job["master"], job["options"], positions=job["positions"])
    assert r["rover_apriori_source"] == "given"
    np.testing.assert_allclose(r["rover_ecef_m"], [-3976219.6636, 3382372.5422, 3652513.0576], atol=1e-3)
    assert abs(r["states"]["0759_u"] - (0.12545 - 1.0)) < 1e-3
    bad = tmp_path / "bad.toml"
    bad.write_text('[gnss]\nmaster = "a"\n[gnss.antennas.a]\nubx = "a.ubx"\n')
    with pytest.raises(CdgpsError, match=r"not usable as a baseline job: 3 problems"):
        load_baseline_job(bad)


@pytest.mark.parametrize("form", ["gnss", "baseline"])
@pytest.mark.parametrize("missing", ["rinex", "nav"])
def test_baseline_names_the_job_key_of_a_missing_file(tmp_path, form, missing):
    # 'baseline --config' said "PATH: cannot read: No such file or directory", without the job file and key
    obs, nav = shared("07590920.05o"), shared("07590920.05n")
    rover = "gone.obs" if missing == "rinex" else str(obs)
    navs = "gone.nav" if missing == "nav" else str(nav)
    job = tmp_path / "job.toml"
    if form == "gnss":
        job.write_text(f'[gnss]\nmaster = "A"\nnav = ["{navs}"]\n[gnss.antennas.A]\nrinex = "{obs}"\n'
                       f'[gnss.antennas.B]\nrinex = "{rover}"\n')
        key = "[gnss.antennas.B] rinex" if missing == "rinex" else "[gnss] nav"
    else:
        job.write_text(f'[baseline]\nmaster = "A"\nnav = ["{navs}"]\n[baseline.rinex]\nA = "{obs}"\nB = "{rover}"\n')
        key = "[baseline.rinex] B" if missing == "rinex" else "[baseline] nav"
    out = tmp_path / "b.json"
    r = CliRunner().invoke(main, ["baseline", "--config", str(job), "-o", str(out)])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    gone = tmp_path / ("gone.obs" if missing == "rinex" else "gone.nav")
    assert f"{job}: {key}: {gone}: cannot read: no such file" in r.output, r.output
    assert not out.exists()
    # given on the command line instead, the file is named by its option
    opt = ["--rinex", f"A={obs}", "--rinex", "B=gone.obs"] if missing == "rinex" else ["--nav", "gone.nav"]
    r = CliRunner().invoke(main, ["baseline", "--config", str(job), *opt, "-o", str(out)])
    assert r.exit_code == 2, r.output
    assert ("--rinex B: gone.obs" if missing == "rinex" else "--nav: gone.nav") in r.output, r.output


def test_baseline_refuses_a_long_baseline_as_init_does(tmp_path):
    """`cdgps baseline` is init's static solution: it neglects the DD ionosphere and the wet delays, so the real 35 km
    pair DELF → ZEGV (tests/data/georust-delf-zegv) is refused at the same threshold (exit 2, nothing written) —
    with the IGS broadcast file it was "partially fixed" 0.49 m off with a σ of millimetres — and taken with
    ``--iono-threshold-km`` raised past it; a [baseline] job's key is checked."""
    from _shared import run_cli

    data = Path(__file__).resolve().parents[1] / "data" / "georust-delf-zegv"
    args = ("baseline", "--rinex", f"delf={data / 'delf0010.21d'}", "--rinex", f"zegv={data / 'zegv0010.21d'}",
            "--nav", data / "cbw10010.21n.gz", "--master", "delf")
    out = tmp_path / "b.json"
    r = run_cli(*args, "-o", out)
    text = " ".join(r.output.split())
    assert r.exit_code == 2 and not out.exists() and "Traceback" not in r.output, r.output
    assert "35.272 km long" in text and "--iono-threshold-km" in text and "'cdgps rtk'" in text, text
    r = run_cli(*args, "-o", out, "--iono-threshold-km", 40)
    assert "at or above" not in " ".join(r.output.split()) and "Traceback" not in r.output, r.output
    job = tmp_path / "job.toml"
    job.write_text(f'[baseline]\nmaster = "delf"\nnav = ["{data / "cbw10010.21n.gz"}"]\niono_threshold_km = 40\n'
                   f'[baseline.rinex]\ndelf = "{data / "delf0010.21d"}"\nzegv = "{data / "zegv0010.21d"}"\n')
    assert load_baseline_job(job)["iono_threshold_km"] == 40.0
    job.write_text(job.read_text().replace("iono_threshold_km = 40", "iono_threshold_km = -1"))
    with pytest.raises(CdgpsError, match=r"baseline.iono_threshold_km: expected a baseline length in km >= 0"):
        load_baseline_job(job)


def test_what_is_given_beside_a_job_goes_on_top_of_it():
    """``baseline_inputs``: the job's stations, navigation files, master and options, each replaced by what is given
    beside it (``cdgps baseline --config JOB --master … --mask-deg …``); stations given replace the job's and drop
    its origins; every refusal names what is missing or wrong."""
    from cdgps_cli.pipeline.baseline_job import baseline_inputs  # noqa: PLC0415

    job = load_baseline_job(JOB)
    got = baseline_inputs(job)
    assert (got["rinex"], got["nav_paths"], got["master"], got["options"]) == (job["rinex"], job["nav"], job["master"],
                                                                              job["options"])
    got = baseline_inputs(job, master="0759", nav_paths=["x.nav"], changes={"mask_deg": 20.0, "partial": False})
    assert (got["master"], got["nav_paths"], got["options"].mask_deg, got["options"].partial) == ("0759", ["x.nav"],
                                                                                                   20.0, False)
    assert got["options"].ratio_threshold == job["options"].ratio_threshold and "nav" not in got["origins"]
    two = {"a": "a.obs", "b": "b.obs"}
    got = baseline_inputs(None, stations=two, nav_paths=["n"], master="a", antenna_types={"b": "none"})
    assert got["rinex"] == two and "rinex" not in got["origins"] and got["antenna_types"] == {"b": "none"}
    got = baseline_inputs(job, master_xyz=(-3978242.4348, 3382841.1715, 3649902.7667))
    assert got["positions"] == {job["master"]: pytest.approx([-3978242.4348, 3382841.1715, 3649902.7667])}
    for kw, said in (({"stations": {"a": "a.obs"}, "nav_paths": ["n"], "master": "a"}, "exactly two stations"),
                     ({"stations": two, "master": "a"}, "at least one navigation file"),
                     ({"stations": two, "nav_paths": ["n"]}, "--master is required"),
                     ({"stations": two, "nav_paths": ["n"], "master": "c"}, "master 'c' is not one of"),
                     ({"stations": two, "nav_paths": ["n"], "master": "a", "changes": {"mask_deg": 95.0}},
                      "mask_deg must be in"),
                     ({"stations": two, "nav_paths": ["n"], "master": "a", "antenna_types": {"c": "none"}},
                      "--antenna c: not one of"),
                     ({"stations": two, "nav_paths": ["n"], "master": "a", "master_xyz": (0, 0, 0)},
                      "--master-xyz 0,0,0: 0.0 km from the Earth's centre")):
        with pytest.raises(CdgpsError, match=said):
            baseline_inputs(None, **kw)


def test_a_job_files_errors_name_its_keys_whatever_flags_are_given(tmp_path):
    """A job file's bad value is named by its key, also when a flag of the same field is given beside it (a review
    found ``gnss.--mask-deg``: the flags' renaming ran over the job's reading too)."""
    bad = tmp_path / "bad.toml"
    bad.write_text(JOB.read_text().replace("mask_deg = 15.0", "mask_deg = 95.0"))
    for extra in ((), ("--mask-deg", "10")):
        r = CliRunner().invoke(main, ["-q", "baseline", "--config", str(bad), *extra, "-o", str(tmp_path / "o.json")])
        assert r.exit_code == 2 and "gnss.mask_deg" in r.output and "--mask-deg" not in r.output, r.output


def test_master_xyz_places_a_master_whose_header_has_no_position(tmp_path):
    """``baseline --master-xyz``: the real mosaic base with its APPROX POSITION XYZ written as 0 0 0 (as software
    receivers and converters write it) is refused naming the option; given its position, the baseline is the one
    of the unedited file, bit for bit."""
    from tests._shared import MOSAIC_DIR  # noqa: PLC0415

    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    text = (MOSAIC_DIR / "base.obs").read_text()
    line = next(ln for ln in text.splitlines() if ln[60:].strip() == "APPROX POSITION XYZ")
    xyz = line[:60].split()
    (tmp_path / "base0.obs").write_text(text.replace(line, f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}".ljust(60) + line[60:]))
    run = lambda base, *extra: CliRunner().invoke(main, [  # noqa: E731
        "-q", "baseline", "--rinex", f"base={base}", "--rinex", f"rover={MOSAIC_DIR / 'rover.obs'}", "--nav",
        str(MOSAIC_DIR / "base.nav"), "--master", "base", *extra, "-o", str(tmp_path / f"{Path(base).stem}.json")])
    r = run(tmp_path / "base0.obs")
    assert r.exit_code == 2 and "--master-xyz X Y Z" in r.output, r.output
    assert run(tmp_path / "base0.obs", "--master-xyz", *xyz).exit_code == 0
    assert run(MOSAIC_DIR / "base.obs").exit_code == 0
    import json  # noqa: PLC0415

    given, header = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("base0", "base"))
    assert given["states"] == header["states"] and given["solution"] == header["solution"] == "fixed"
