"""The fusable sensors' config keys (config/sensors.py, declared in config/schema.py)."""

import numpy as np
import pytest

from cdgps_cli.config.sensors import fusion_settings, sensor_specs
from cdgps_cli.config.structure import load_config, parse_config
from cdgps_cli.core.errors import CdgpsError

TEXT = open("configs/tower-fusion.toml").read()


def test_tower_fusion_sensors():
    specs = sensor_specs(load_config("configs/tower-fusion.toml"))
    by = {s.name: s for s in specs}
    assert [s.kind for s in specs] == ["accel", "accel", "tilt", "gyro"]
    assert by["acc-top"].axes == ("x", "y", "z") and by["acc-top"].sigma == 0.002 and by["acc-top"].point == "top"
    assert by["tilt-top"].sample_period_s == 0.1 and by["tilt-top"].rotation_rad.shape == (3, 4)
    assert by["gyro-top"].sigma == 1e-4 and np.allclose(by["gyro-top"].axes[0], [0, 1, 0])


def test_gyro_noise_defaults_come_from_simulation():
    cfg = load_config("configs/tower-120m-fe.toml")
    g = [s for s in sensor_specs(cfg) if s.kind == "gyro"]
    assert len(g) == 3 and g[0].sigma == cfg.simulation["gyro_noise_rad_s"]
    assert g[0].bias_sigma == cfg.simulation["gyro_bias_sigma_rad_s"]


@pytest.mark.parametrize("old,new,msg", [
    ('point = "mid"', 'point = "nowhere"', "accelerometers[1].point: 'nowhere' is not an antenna"),
    ('sigma_m_s2 = 0.002\nbias_sigma_m_s2 = 0.01\nbias_drift_m_s2_per_sqrt_s = 1.0e-4\n\n[[tilts]]',
     'sigma_m_s2 = -1\nbias_sigma_m_s2 = 0.01\nbias_drift_m_s2_per_sqrt_s = 1.0e-4\n\n[[tilts]]', "accelerometers[1].sigma_m_s2"),
    ('axes = "x"', 'axes = "w"', "accelerometers[1].axes"),
    ('name = "tilt-top"', 'name = "acc-mid"', "duplicate name(s) acc-mid"),
])
def test_bad_sensor_keys_are_named(old, new, msg):
    assert old in TEXT
    cfg = parse_config(TEXT.replace(old, new, 1), "tower.toml")
    with pytest.raises(CdgpsError, match="tower.toml") as e:
        sensor_specs(cfg)
    assert msg in str(e.value)


def test_unknown_sensor_key_is_refused_by_the_structure_parser():
    with pytest.raises(CdgpsError, match=r"accelerometers\[0\]|unknown key"):
        sensor_specs(parse_config(TEXT.replace('point = "top"', 'point = "top"\nrange_g = 2', 1), "t.toml"))


def test_fusion_table():
    cfg = parse_config(TEXT + '\n[fusion]\nfuse = ["accel", "tilt"]\nhold_out = ["acc-mid"]\n')
    assert fusion_settings(cfg) == {"fuse": ("accel", "tilt"), "hold_out": ("acc-mid",)}
    assert fusion_settings(load_config("configs/tower-fusion.toml")) == {"fuse": (), "hold_out": ()}
    with pytest.raises(CdgpsError, match="fusion: expected fuse"):
        fusion_settings(parse_config(TEXT + '\n[fusion]\nfuse = ["wind"]\n'))
