"""The channels of a receiver's signal table that carry no usable phase, screened out in one place for every GNSS
path (``rtk``, ``baseline``'s signal tables, ``init`` and ``estimate`` on a run): channels flagged lost-lock at most
of their epochs (:func:`~cdgps_cli.measurement.slips.without_unlocked_channels`) and channels whose phase runs
opposite to their code (:func:`~cdgps_cli.measurement.phase_sign.without_reversed_phases`)."""

from __future__ import annotations

from contextlib import contextmanager

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.phase_sign import without_reversed_phases
from cdgps_cli.measurement.slips import without_unlocked_channels

__all__ = ["without_unusable_channels", "naming_screened"]


def without_unusable_channels(table, where: str):
    """A receiver's signal table less its unlocked channels and its channels of reversed phase, and the warnings
    naming them (``where``: the receiver, e.g. "rover.obs (rover)"; [] when none)."""
    table, unlocked = without_unlocked_channels(table, where)
    table, reversed_ = without_reversed_phases(table, where)
    return table, unlocked + reversed_


@contextmanager
def naming_screened(screened: list):
    """A CdgpsError raised inside (no phase, no common signal or satellite, no single-point position …) with the
    warnings of the channels left out before (``screened``) added: what a file seems to lack may be what the screen
    took out of it."""
    try:
        yield
    except CdgpsError as exc:
        if not screened or not any(w in str(exc) for w in _WANTING):
            raise
        raise CdgpsError(f"{exc} (channels left out before: {'; '.join(screened)})") from None


#: words of the refusals that what the screen took out may explain (no phase, signal, satellite, DD, position …); a
#: refusal of something else (a base without a position, a bad option) is said without the screen's notes
_WANTING = ("phase", "signal", "satellite", "common", "double difference", "solvable", "no DD", "fewer than")
