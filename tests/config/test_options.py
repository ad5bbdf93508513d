"""Every default has one home (config/options.py): the library and the CLI read it from there."""

import inspect

from cdgps_cli.cli.commands import main
from cdgps_cli.config import options
from cdgps_cli.config.structure import GnssConfig
from cdgps_cli.estimation import ambiguity
from cdgps_cli.estimation.baseline import BaselineOptions
from cdgps_cli.estimation.initializer import InitOptions
from cdgps_cli.measurement.differencing import sd_variance


def _default(fn, name):
    return inspect.signature(fn).parameters[name].default


def test_ratio_threshold_everywhere_is_the_one_default():
    r = options.RATIO_THRESHOLD
    assert _default(ambiguity.ratio_test, "threshold") is r
    assert _default(ambiguity.partial_fix, "threshold") is r
    assert _default(ambiguity.resolve, "threshold") is r
    assert InitOptions().ratio_threshold is r and BaselineOptions().ratio_threshold is r
    assert GnssConfig.__dataclass_fields__["ratio"].default is r
    init = main.commands["init"]
    assert next(p for p in init.params if p.name == "ratio_threshold").default is r


def test_init_and_gnss_defaults_come_from_options():
    assert InitOptions().starts == options.INIT_STARTS and InitOptions().max_iterations == options.INIT_MAX_ITERATIONS
    init = {p.name: p.default for p in main.commands["init"].params}
    assert init["starts"] == options.INIT_STARTS and init["max_iterations"] == options.INIT_MAX_ITERATIONS
    assert _default(sd_variance, "sigma_a_m") == options.PHASE_SIGMA_A_M == options.GNSS_DEFAULTS["sigma_a_m"]
    assert BaselineOptions().mask_deg == options.GNSS_DEFAULTS["mask_deg"]
    help_text = {p.name: p.help for p in main.commands["baseline"].params}
    assert f"[{options.GNSS_DEFAULTS['mask_deg']:g}]" in help_text["mask_deg"]


def test_toml_value():
    assert [options.toml_value(v) for v in (True, 3.0, 15, "elevation")] == ["true", "3.0", "15", '"elevation"']


def _cli_default(command, name):
    """The default of option ``name`` of a click command (a group's subcommand path)."""
    return next(p.default for p in command.params if p.name == name)


def test_estimate_spectra_and_tracking_defaults_are_one_value_read_by_library_and_cli():
    """Each default below is written once (config/options.py); the library's option class and the
    command's option both read it, so the help text and the library agree."""
    from dataclasses import fields

    from cdgps_cli.analysis.spectra import SpectraOptions
    from cdgps_cli.cli.commands import main
    from cdgps_cli.config import options
    from cdgps_cli.estimation.filter import EstimateOptions
    from cdgps_cli.tracking.channel import TrackOptions

    cases = [(EstimateOptions, main.commands["estimate"], options.ESTIMATE_DEFAULTS),
             (SpectraOptions, main.commands["spectra"], options.SPECTRA_DEFAULTS),
             (TrackOptions, main.commands["track"], options.TRACK_DEFAULTS),
             (TrackOptions, main.commands["track-structure"], options.TRACK_DEFAULTS)]
    for cls, command, defaults in cases:
        lib = {f.name: f.default for f in fields(cls)}
        for key, value in defaults.items():
            assert lib[key] == value, (cls.__name__, key)
            assert _cli_default(command, key) == value, (command.name, key)
    assert _cli_default(main.commands["estimate"], "x_axis_azimuth_deg") == options.X_AXIS_AZIMUTH_DEG
    assert _cli_default(main.commands["simulate-gnss-structure"], "x_axis_azimuth_deg") == options.X_AXIS_AZIMUTH_DEG
