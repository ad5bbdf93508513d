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

__all__ = ["channel_summary", "ingest_structure"]

_KIND = {RESTART: "restart", REACQUIRED: "reacquisition"}


def channel_summary(phase: Table, sample_period_s: float) -> list[dict]:
    """Per channel (sorted by antenna, transmitter): rows, first/last time, and the lock segments after
    the first — the times (s) and kinds (``restart``: lock count 0 or decreasing; ``reacquisition``:
    after a gap the lock count did not advance over) of :func:`~cdgps_cli.measurement.channels.lock_segments`.

    Parameters
    ----------
    phase : Table
        The run's phase table (``time_s``, ``antenna``, ``transmitter``, ``lock``).
    sample_period_s : float
        The config's sample period, s (epoch index = round((t − t₀) / T)).
    """
    if len(phase) == 0:
        return []
    t = np.asarray(phase["time_s"], dtype=np.float64)
    a_codes, a_names = phase.codes("antenna")               # codes index the sorted names
    t_codes, t_names = phase.codes("transmitter")
    chan = a_codes.astype(np.int64) * len(t_names) + t_codes
    t0 = t.min()
    lock_all = phase["lock"]
    rows = np.bincount(chan)
    out = {}
    # one channel at a time (the rule cuts each channel on its own): temporaries of a channel's rows,
    # not of the record's (issue 29)
    for c in np.flatnonzero(rows).tolist():
        idx = np.flatnonzero(chan == c)
        tc = t[idx]
        step = np.rint((tc - t0) / sample_period_s).astype(np.int64)
        seg = lock_segments(np.full(idx.size, c, dtype=np.int64), step,
                            lock=np.asarray(lock_all[idx], dtype=np.int64))
        for s_first, s_last in zip(seg.first.tolist(), seg.last.tolist()):
            if c not in out:                                # the channel's first segment
                out[c] = {"antenna": a_names[c // len(t_names)], "transmitter": t_names[c % len(t_names)],
                          "rows": int(rows[c]), "first_s": float(tc[s_first]), "last_s": float(tc[s_last]),
                          "lock_restarts_s": [], "lock_restart_kinds": []}
                continue
            out[c]["lock_restarts_s"].append(float(tc[s_first]))
            out[c]["lock_restart_kinds"].append(_KIND[int(seg.cause[s_first])])
            out[c]["last_s"] = float(tc[s_last])
    for ch in out.values():
        ch["segments"] = 1 + len(ch["lock_restarts_s"])
    return list(out.values())


def ingest_structure(cfg: StructureConfig, receiver_csv: str | Path, out_path: str | Path,
                     gyro_csv: str | Path | None = None, actuator_csv: str | Path | None = None) -> dict:
    """``cdgps ingest`` of native logs: :func:`cdgps_cli.io.run.write_run` with the lock restarts
    counted by :func:`channel_summary`.  Returns the ingest summary."""
    return write_run(cfg, receiver_csv, out_path, gyro_csv, actuator_csv, channel_summary=channel_summary)
