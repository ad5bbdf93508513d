"""Strain gauge model (measurement/strain.py): its reading against the gauge's exact change of length
from the structure's kinematics, zero for rigid motion, and its config keys ([[strains]])."""

import numpy as np
import pytest

from cdgps_cli.config.sensors import sensor_specs
from cdgps_cli.config.structure import load_config, parse_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.registry import model_from_spec
from cdgps_cli.measurement.strain import StrainGauge
from cdgps_cli.model.kinematics import antenna_positions

TB = load_config("configs/testbed-1998-lumped.toml")   # a fixed model: the fitted testbed config may be refitted
TOWER_TEXT = open("configs/tower-fusion.toml").read()
GAUGE = '\n[[strains]]\nname = "s1"\npoint_a = "base"\npoint_b = "mid"\nsigma_strain = 1.0e-6\nbias_sigma_strain = 1.0e-5\n'


@pytest.mark.parametrize("a,b", [("a1", "a6"), ("a1", "a3"), ("a2", "a5")])
def test_reading_is_the_change_of_length(a, b):
    """h(ξ) = (|p_B(q) − p_A(q)| − L) / L to first order: the difference is second order in the motion."""
    m = StrainGauge(TB, "s", a, b, np.zeros((1, 1)), [0], 1e-6)
    ia, ib = TB.antenna_names.index(a), TB.antenna_names.index(b)
    U = np.asarray(TB.mode_shapes, float)
    rng = np.random.default_rng(1)
    for scale in (1e-3, 1e-4):
        xi = rng.standard_normal(TB.n_modes) * scale
        p = antenna_positions(TB, (U @ xi)[None])[0]
        p0 = antenna_positions(TB, np.zeros((1, TB.n_q)))[0]
        L = np.linalg.norm(p0[ib] - p0[ia])
        exact = (np.linalg.norm(p[ib] - p[ia]) - L) / L
        h = m.response(np.r_[xi, np.zeros(TB.n_modes)])[0][0]
        assert abs(exact) > 10 * scale**2 and abs(h - exact) < 5 * scale**2, (scale, h, exact)
    assert m.gauge_length_m == pytest.approx(L)


def test_rigid_rotation_reads_nothing():
    m = StrainGauge(TB, "s", "a1", "a6", np.zeros((1, 1)), [0], 1e-6)
    U = np.asarray(TB.mode_shapes, float)
    col = np.flatnonzero(np.abs(U[TB.rigid_index]) > 0)
    assert col.size and np.all(m.M[0, col] == 0)


def test_config_keys():
    cfg = parse_config(TOWER_TEXT + GAUGE, "tower.toml")
    [s] = [s for s in sensor_specs(cfg) if s.kind == "strain"]
    assert (s.name, s.point, s.point_b, s.sigma, s.bias_sigma, s.axes) == ("s1", "base", "mid", 1e-6, 1e-5, ("gauge",))
    m = model_from_spec(cfg, s, np.zeros((1, 1)), [0], 2 * cfg.n_modes)
    assert isinstance(m, StrainGauge) and m.fields == ["strain_gauge_1"] and m.extra_states[0][0] == "s1_bias_strain_gauge_1"
    for old, new, msg in (('point_b = "mid"', 'point_b = "roof"', "strains[0].point_b: 'roof' is not an antenna"),
                          ('point_b = "mid"', 'point_b = "base"', "strains[0]: point_a and point_b are the same point"),
                          ("sigma_strain = 1.0e-6", "sigma_strain = 0", "strains[0].sigma_strain")):
        with pytest.raises(CdgpsError, match="tower.toml") as e:
            sensor_specs(parse_config(TOWER_TEXT + GAUGE.replace(old, new), "tower.toml"))
        assert msg in str(e.value)



@pytest.fixture(scope="module")
def fused_strain(tmp_path_factory):
    """simulate-gnss-structure (tower + a gauge base–mid) → ingest → init → estimate --fuse strain."""
    import json

    from click.testing import CliRunner

    from cdgps_cli.cli.commands import main

    tmp = tmp_path_factory.mktemp("strain")
    (tmp / "tower.toml").write_text(TOWER_TEXT + GAUGE.replace("1.0e-6\nbias", "1.0e-7\nbias"))
    d = tmp / "sim"
    for args in (("simulate-gnss-structure", tmp / "tower.toml", "--duration", "3", "--gnss-interval", "0.1", "-o", d),
                 ("ingest", "--config", d / "config.toml", "-o", d / "run.mcap"),
                 ("init", d / "run.mcap", "-o", d / "init.json"),
                 ("estimate", d / "run.mcap", "--init", d / "init.json", "--structure", tmp / "tower.toml",
                  "--fuse", "strain", "-o", d / "f.mcap", "--json")):
        r = CliRunner().invoke(main, ["-q", *map(str, args)])
        assert r.exit_code == 0, (args, r.output)
    return d, json.loads(r.stdout)


def test_simulated_log_ingested_and_fused(fused_strain):
    """simulate-gnss-structure writes strain.csv for a [[strains]] gauge, ingest attaches it, estimate
    --fuse strain stacks it (a bias state) with the double differences."""
    from cdgps_cli.io.sensor_logs import read_sensor_csv

    d, s = fused_strain
    kind, df = read_sensor_csv(d / "strain.csv")
    assert kind == "strain" and list(df.columns) == ["time_s", "sensor", "strain_gauge_1"] and len(df) == 301
    f = s["fusion"]
    assert f["fused"] == ["strain"] and f["added_states"] == ["s1_bias_strain_gauge_1"] and f["sensors"]["s1"]["samples"] >= 1


def test_strain_readings_are_used_from_the_start(fused_strain):
    """The modal start state is honest (x = 0 on the batch's prior, not an arbitrary 5 Hz mode at the GNSS
    Nyquist with P0 = I), so the outlier gate keeps the precise gauge from the first sample."""
    assert fused_strain[1]["fusion"]["sensors"]["s1"]["samples"] > 250


def test_bad_strains_tables_refused_naming_the_key(tmp_path):
    """[[strains]] without a name, given as a table instead of an array of tables, or between two
    points at the same place: CdgpsError naming the config and key (were: a sensor named 'None',
    an AttributeError, a ValueError traceback from simulate-gnss-structure)."""
    from click.testing import CliRunner

    from cdgps_cli.cli.commands import main

    for text, msg in ((TOWER_TEXT + GAUGE.replace('name = "s1"\n', ""), "strains[0].name: expected a non-empty string"),
                      (TOWER_TEXT + '\n[strains]\nname = "s"\n', "strains: expected an array of tables ([[strains]])")):
        with pytest.raises(CdgpsError, match="tower.toml: invalid sensor config") as e:
            sensor_specs(parse_config(text, "tower.toml"))
        assert msg in str(e.value)
    twin = '\n[[points]]\nname = "mid2"\nposition_m = [0.0, 0.0, 100.0]\n'
    cfg = tmp_path / "tower.toml"
    cfg.write_text(TOWER_TEXT + GAUGE.replace('"base"', '"mid2"') + twin)
    out = tmp_path / "sim"
    r = CliRunner().invoke(main, ["simulate-gnss-structure", str(cfg), "--duration", "2", "--gnss-interval", "0.5",
                                  "-o", str(out)])
    assert r.exit_code == 2 and isinstance(r.exception, SystemExit), r.output
    assert "tower.toml: strains: point_a 'mid2' and point_b 'mid' are at the same place (gauge length 0)" in r.output
    assert not out.exists()


def test_fuse_option_empty_or_twice_exit_2(fused_strain, tmp_path):
    """``--fuse ""`` ran as if the option were absent; ``--fuse strain,strain`` was read as strain."""
    from click.testing import CliRunner

    from cdgps_cli.cli.commands import main

    d, _ = fused_strain
    for value, msg in (("", "--fuse '': empty"), ("strain,strain", "--fuse strain,strain: strain given twice")):
        out = tmp_path / "f.mcap"
        r = CliRunner().invoke(main, ["estimate", str(d / "run.mcap"), "--init", str(d / "init.json"), "--structure",
                                      str(d.parent / "tower.toml"), "--fuse", value, "-o", str(out)])
        assert r.exit_code == 2 and msg in r.output and "Traceback" not in r.output, r.output
        assert not out.exists()
