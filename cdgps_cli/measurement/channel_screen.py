"""The channels of a receiver's signal table that carry no usable phase, screened out in one place for every GNSS
path (``rtk``, ``baseline``'s signal tables, ``init`` and ``estimate`` on a run): channels flagged lost-lock at most
of their epochs (:func:`~cdgps_cli.measurement.slips.without_unlocked_channels`) and channels whose phase runs
opposite to their code (:func:`~cdgps_cli.measurement.phase_sign.without_reversed_phases`)."""

from __future__ import annotations

from cdgps_cli.measurement.phase_sign import without_reversed_phases
from cdgps_cli.measurement.slips import without_unlocked_channels

__all__ = ["without_unusable_channels"]


def without_unusable_channels(table, where: str):
    """A receiver's signal table less its unlocked channels and its channels of reversed phase, and the warnings
    naming them (``where``: the receiver, e.g. "rover.obs (rover)"; [] when none)."""
    table, unlocked = without_unlocked_channels(table, where)
    table, reversed_ = without_reversed_phases(table, where)
    return table, unlocked + reversed_
