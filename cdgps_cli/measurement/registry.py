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
from cdgps_cli.measurement.model import PseudoliteSD
from cdgps_cli.measurement.tilt import TiltMeter

__all__ = ["ModelKind", "REGISTRY", "UNITS", "FUSABLE", "model_from_spec"]

#: units a field name may end with (m, m/s², rad, rad/s)
UNITS = ("m", "m_s2", "rad", "rad_s")


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


def _gnss(cfg, rng, n):
    return GnssPosition(cfg, cfg.antenna_names[-1], rng.standard_normal((len(range(0, n, 5)), 3)) * 0.01,
                        _every_other(n, 5), [0.02, 0.02, 0.04])


def _pseudolite(cfg, rng, n):
    C = len(cfg.rover_names) * len(cfg.transmitter_names)
    ant = np.repeat(cfg.rover_indices, len(cfg.transmitter_names))
    tx = np.tile(np.arange(len(cfg.transmitter_names)), len(cfg.rover_names))
    return PseudoliteSD(cfg, rng.standard_normal((n, C)) * 0.01, ant, tx, np.full(C, cfg.measurement_sigma_m))


REGISTRY: dict[str, ModelKind] = {
    "accel": ModelKind(Accelerometer, "m_s2", _accel),
    "tilt": ModelKind(TiltMeter, "rad", _tilt),
    "gyro": ModelKind(RateGyro, "rad_s", _gyro),
    "gnss_position": ModelKind(GnssPosition, "m", _gnss),
    "pseudolite_sd": ModelKind(PseudoliteSD, "m", _pseudolite),
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
    return RateGyro(cfg, [spec.name], values, k_of, spec.sigma, b, spec.bias_drift, n_core=n_core, name=spec.name)
