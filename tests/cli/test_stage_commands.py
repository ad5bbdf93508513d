"""cdgps_cli/cli/stage_commands.py: which structure-run options a GNSS `estimate` counts as given."""
from cdgps_cli.cli.stage_commands import _structure_only_given
from cdgps_cli.config.options import ESTIMATE_DEFAULTS, SCENE_EXAGGERATION

_AT_DEFAULTS = dict(biases="fixed", sigma_m=None, rest=(), structure=None, receiver_map=(),
                    scene_exaggeration=SCENE_EXAGGERATION,
                    **{k: v for k, v in ESTIMATE_DEFAULTS.items()})


def test_nothing_given_at_the_defaults():
    assert not any(_structure_only_given(**_AT_DEFAULTS).values())


def test_each_option_off_its_default_is_given_alone():
    for key, value in ESTIMATE_DEFAULTS.items():
        given = _structure_only_given(**{**_AT_DEFAULTS, key: value * 0.5})
        flag = "--" + key.replace("_", "-")
        assert given[flag] and sum(given.values()) == 1, (key, given)


def test_a_gnss_runs_states_options_are_given_when_set():
    """--covariance full and --foxglove-rate-hz shape a structure run's STATES; a GNSS run's were written the one way
    whatever they said, without a word: now refused (exit 2) like the other structure-run options."""
    given = _structure_only_given(**_AT_DEFAULTS, covariance="full")
    assert given["--covariance"] and sum(given.values()) == 1
    given = _structure_only_given(**_AT_DEFAULTS, foxglove_rate_hz=0.0)
    assert given["--foxglove-rate-hz"] and sum(given.values()) == 1
