"""``cdgps ingest`` of a structure's native logs, and the channel summary of ``cdgps ingest`` / ``cdgps info``.

:func:`cdgps_cli.io.run.write_run` validates the logs and writes the RUN.mcap; the lock restarts it
reports are counted here with the one lock-segment rule
(:func:`cdgps_cli.measurement.channels.lock_segments`), the rule ``cdgps init`` cuts its bias
parameters with and ``cdgps estimate`` raises its lock events by, so that the three agree.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core.table import Table
from cdgps_cli.io.run import write_run
from cdgps_cli.measurement.channels import REACQUIRED, RESTART, lock_segments

__all__ = ["ChannelCounter", "channel_summary", "ingest_structure"]

_KIND = {RESTART: "restart", REACQUIRED: "reacquisition"}


class ChannelCounter:
    """Per channel (antenna, transmitter): rows, first/last time, and the lock segments after the
    first — the times (s) and kinds (``restart``: lock count 0 or decreasing; ``reacquisition``:
    after a gap the lock count did not advance over) of
    :func:`~cdgps_cli.measurement.channels.lock_segments` — counted over blocks of the phase table
    given in time order (``cdgps ingest`` streams the record): each channel's cut rule needs only
    its previous row, carried from block to block, so the blocks give what the whole table gives.

    Parameters
    ----------
    sample_period_s : float
        The config's sample period, s (epoch index = round((t − t₀) / T), t₀ the first time).
    """

    def __init__(self, sample_period_s: float):
        self.period_s = sample_period_s
        self.t0: float | None = None
        self.out: dict = {}                                 # (antenna, transmitter) -> the channel's entry
        self.last: dict = {}                                # (antenna, transmitter) -> (time, step, lock) of its last row

    def add(self, phase: Table) -> None:
        """The next rows of the phase table (``time_s``, ``antenna``, ``transmitter``, ``lock``)."""
        if len(phase) == 0:
            return
        t = np.asarray(phase["time_s"], dtype=np.float64)
        a_codes, a_names = phase.codes("antenna")           # codes index the sorted names
        t_codes, t_names = phase.codes("transmitter")
        chan = a_codes.astype(np.int64) * len(t_names) + t_codes
        if self.t0 is None:
            self.t0 = t.min()
        lock_all = phase["lock"]
        rows = np.bincount(chan)
        # one channel at a time (the rule cuts each channel on its own): temporaries of a channel's rows
        for c in np.flatnonzero(rows).tolist():
            key = (a_names[c // len(t_names)], t_names[c % len(t_names)])
            idx = np.flatnonzero(chan == c)
            self._channel(key, int(rows[c]), t[idx], np.asarray(lock_all[idx], dtype=np.int64))

    def _channel(self, key: tuple, n: int, tc: np.ndarray, lock: np.ndarray) -> None:
        step = np.rint((tc - self.t0) / self.period_s).astype(np.int64)
        prev = self.last.get(key)
        if prev is not None:                                # the channel's previous row leads (then dropped)
            tc, step, lock = np.r_[prev[0], tc], np.r_[prev[1], step], np.r_[prev[2], lock]
        seg = lock_segments(np.zeros(step.size, dtype=np.int64), step, lock=lock)
        entry = self.out.get(key)
        for s_first, s_last in zip(seg.first.tolist(), seg.last.tolist()):
            if entry is None:                               # the channel's first segment
                entry = self.out[key] = {"antenna": key[0], "transmitter": key[1], "rows": 0,
                                         "first_s": float(tc[s_first]), "last_s": float(tc[s_last]),
                                         "lock_restarts_s": [], "lock_restart_kinds": []}
            elif prev is not None and s_first == 0:         # the segment the previous block ended in
                entry["last_s"] = float(tc[s_last])
            else:
                entry["lock_restarts_s"].append(float(tc[s_first]))
                entry["lock_restart_kinds"].append(_KIND[int(seg.cause[s_first])])
                entry["last_s"] = float(tc[s_last])
        entry["rows"] += n
        self.last[key] = (float(tc[-1]), int(step[-1]), int(lock[-1]))

    def result(self) -> list[dict]:
        """The channels, sorted by antenna and transmitter, each with its ``segments``."""
        out = [dict(self.out[k]) for k in sorted(self.out)]
        for ch in out:
            ch["lock_restarts_s"], ch["lock_restart_kinds"] = list(ch["lock_restarts_s"]), list(ch["lock_restart_kinds"])
            ch["segments"] = 1 + len(ch["lock_restarts_s"])
        return out


def channel_summary(phase: Table, sample_period_s: float) -> list[dict]:
    """:class:`ChannelCounter`'s answer for a whole phase table (``cdgps info`` of a RUN read
    message by message).

    Parameters
    ----------
    phase : Table
        The run's phase table (``time_s``, ``antenna``, ``transmitter``, ``lock``).
    sample_period_s : float
        The config's sample period, s (epoch index = round((t − t₀) / T)).
    """
    counter = ChannelCounter(sample_period_s)
    counter.add(phase)
    return counter.result()


def ingest_structure(cfg: StructureConfig, receiver_csv: str | Path, out_path: str | Path,
                     gyro_csv: str | Path | None = None, actuator_csv: str | Path | None = None) -> dict:
    """``cdgps ingest`` of native logs: :func:`cdgps_cli.io.run.write_run` (streamed) with the lock
    restarts counted by :class:`ChannelCounter`.  Returns the ingest summary."""
    return write_run(cfg, receiver_csv, out_path, gyro_csv, actuator_csv, channel_counter=ChannelCounter)
