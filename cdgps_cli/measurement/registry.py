"""The registry of measurement models: every kind the engine can fuse, with a small example of each
that the contract test (tests/measurement/test_registry_contract.py) checks the same way — H against
finite differences of h, shapes, labels, units in field names, positive-definite noise.

A new sensor is registered here with its class, the unit of its readings (as in its field names)
and an example builder ``example(cfg, rng, n_epochs) -> model`` on a structure config
(docs/adding-a-sensor.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from cdgps_cli.config.sensors import FUSABLE_KINDS, SensorSpec
from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.measurement.accelerometer import Accelerometer
from cdgps_cli.measurement.gnss_position import GnssPosition
from cdgps_cli.measurement.gyro import RateGyro
from cdgps_cli.measurement.model import PseudoliteSD, SatelliteDDModal
from cdgps_cli.measurement.sensor import place
from cdgps_cli.measurement.stacked import Stacked
from cdgps_cli.measurement.strain import StrainGauge
from cdgps_cli.measurement.tilt import TiltMeter

__all__ = ["ModelKind", "REGISTRY", "UNITS", "FUSABLE", "model_from_spec"]

#: units a field name may end with (m, m/s², rad, rad/s, 1: a ratio such as strain)
UNITS = ("m", "m_s2", "rad", "rad_s", "1")


@dataclass(frozen=True)
class ModelKind:
    """A registered measurement model: its class, the unit of its readings and an example builder."""

    cls: type
    unit: str
    example: Callable


def _every_other(n_epochs: int, step: int) -> np.ndarray:
    """k_of of a sensor sampled at every ``step``-th epoch (the others: no rows)."""
    k_of = np.full(n_epochs, -1, dtype=np.int64)
    k_of[::step] = np.arange(len(range(0, n_epochs, step)))
    return k_of


def _accel(cfg, rng, n):
    r = cfg.n_modes
    k_of = _every_other(n, 1)
    return Accelerometer(cfg, cfg.antenna_names[-1], cfg.antenna_names[-1], ["x", "y", "z"],
                         rng.standard_normal((n, 3)) * 0.01, k_of, [0.002, 0.002, 0.003], 0.01, 1e-4,
                         disturbance=np.eye(cfg.n_modes)[:, :r])


def _tilt(cfg, rng, n):
    sec = next((i for i, s in enumerate(cfg.sections) if s.rotation), -1)
    return TiltMeter(cfg, "tilt1", ["x", "y"], rng.standard_normal((len(range(0, n, 2)), 2)) * 1e-3, _every_other(n, 2),
                     1e-4, section=sec, bias_sigma_rad=1e-3, bias_drift_rad_per_sqrt_s=1e-6, n_core=3 * cfg.n_modes)


def _gyro(cfg, rng, n):
    g = list(cfg.gyro_names[:2])
    return RateGyro(cfg, g, rng.standard_normal((n, len(g))) * 1e-3, _every_other(n, 1), 2e-3, 2e-3, 2e-5)


def _strain(cfg, rng, n):
    a, b = cfg.rover_names[0], cfg.rover_names[-1]          # (on the testbed: sections C1 and C3)
    return StrainGauge(cfg, "strain1", a, b, rng.standard_normal((len(range(0, n, 3)), 1)) * 1e-5, _every_other(n, 3),
                       1e-6, 1e-5, 1e-8)


def _gnss(cfg, rng, n):
    return GnssPosition(cfg, cfg.antenna_names[-1], rng.standard_normal((len(range(0, n, 5)), 3)) * 0.01,
                        _every_other(n, 5), [0.02, 0.02, 0.04])


def _pseudolite(cfg, rng, n):
    C = len(cfg.rover_names) * len(cfg.transmitter_names)
    ant = np.repeat(cfg.rover_indices, len(cfg.transmitter_names))
    tx = np.tile(np.arange(len(cfg.transmitter_names)), len(cfg.rover_names))
    return PseudoliteSD(cfg, rng.standard_normal((n, C)) * 0.01, ant, tx, np.full(C, cfg.measurement_sigma_m))


def _dd_modal(cfg, rng, n, n_sat: int = 5):
    """Synthetic single-difference tables of every rover (far satellites in random directions, one
    segment per satellite), every epoch, as :mod:`cdgps_cli.pipeline.gnss_modal` builds them."""
    from types import SimpleNamespace  # noqa: PLC0415

    from cdgps_cli.model.kinematics import antenna_positions  # noqa: PLC0415

    rov = [i for i in range(len(cfg.antenna_names)) if i != cfg.master_index]
    xm = np.array([-3978242.4, 3382841.2, 3649902.8])
    sat_xyz = xm + rng.normal(size=(n_sat, 3)) * 2.0e7
    tabs = []
    for a in rov:
        m = n * n_sat
        d = SimpleNamespace(ptr=np.arange(0, m + 1, n_sat), sat=np.tile(np.arange(n_sat), n),
                            sat_names=[f"G{j + 1:02d}" for j in range(n_sat)], rover_sat_xyz=np.tile(sat_xyz, (n, 1)))
        tabs.append({"d": d, "use": np.ones(m, dtype=bool), "r0": rng.normal(scale=0.01, size=m),
                     "var_rover": rng.uniform(1, 3, m) * 1e-5, "var_master": rng.uniform(1, 3, m) * 1e-5,
                     "ref": np.arange(n) * n_sat + 1, "xm": xm, "seg": np.tile(np.arange(n_sat), n) + 100 * a})
    p0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)))[0]
    return SatelliteDDModal(cfg, np.eye(3), tabs, [np.arange(n) for _ in rov], np.array(rov),
                            p0[rov] - p0[cfg.master_index])


def _stacked(cfg, rng, n):
    """The satellite DDs (full noise, every 5th epoch) stacked with a biased accelerometer (every epoch)."""
    dd = _dd_modal(cfg, rng, n)
    dd.k_of = [np.where(np.arange(n) % 5 == 0, np.arange(n) // 5, -1) for _ in dd.k_of]
    acc = _accel(cfg, rng, n)
    place([acc], acc.n_core)
    return Stacked([("gnss", dd), ("accel", acc)], acc.n_state)


REGISTRY: dict[str, ModelKind] = {
    "accel": ModelKind(Accelerometer, "m_s2", _accel),
    "tilt": ModelKind(TiltMeter, "rad", _tilt),
    "gyro": ModelKind(RateGyro, "rad_s", _gyro),
    "strain": ModelKind(StrainGauge, "1", _strain),
    "gnss_position": ModelKind(GnssPosition, "m", _gnss),
    "pseudolite_sd": ModelKind(PseudoliteSD, "m", _pseudolite),
    "dd_modal": ModelKind(SatelliteDDModal, "m", _dd_modal),
    "stacked": ModelKind(Stacked, "m", _stacked),          # (its parts keep their units: DDs m, accelerometer m/s²)
}

#: the sensors ``estimate --fuse`` takes (config/sensors.py FUSABLE_KINDS)
FUSABLE = FUSABLE_KINDS


def model_from_spec(cfg: StructureConfig, spec: SensorSpec, values, k_of, n_core: int, S=None, bias: bool = True):
    """The measurement model of ``spec`` (:mod:`cdgps_cli.measurement.accelerometer` …) on the leading
    ``n_core`` states (S: the disturbance selection of the accelerometer, when the state carries d)."""
    b = spec.bias_sigma if bias else None
    if spec.kind == "accel":
        if S is not None and n_core != 2 * cfg.n_modes + S.shape[1]:
            raise ValueError("accelerometer: n_core must be 2 n_m + r with the disturbance")
        return Accelerometer(cfg, spec.name, spec.point, list(spec.axes), values, k_of, spec.sigma, b, spec.bias_drift,
                             rotation_rad=spec.rotation_rad, disturbance=S)
    if spec.kind == "tilt":
        return TiltMeter(cfg, spec.name, list(spec.axes), values, k_of, spec.sigma, spec.section, spec.rotation_rad,
                         b, spec.bias_drift, n_core=n_core)
    if spec.kind == "strain":
        return StrainGauge(cfg, spec.name, spec.point, spec.point_b, values, k_of, spec.sigma, b, spec.bias_drift,
                           n_core=n_core)
    return RateGyro(cfg, [spec.name], values, k_of, spec.sigma, b, spec.bias_drift, n_core=n_core, name=spec.name)
