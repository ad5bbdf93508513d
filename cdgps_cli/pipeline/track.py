"""`cdgps track`: read a raw sample file, acquire and track, write TRACK.mcap.

The file is read in blocks of its native sample type (:func:`cdgps_cli.io.iq_samples.iter_samples`),
tracked block by block and each 20 ms window of outputs written as soon as it is complete
(:func:`cdgps_cli.tracking.receiver.track_stream_to`): memory does not grow with the file's length.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cdgps_cli import __version__
from cdgps_cli.io.atomic import file_sha256
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.options import TRACK_BLOCK_SAMPLES
from cdgps_cli.io.iq_samples import FORMATS, iter_samples, read_samples
from cdgps_cli.io.mcap import NULLABLE, McapOut, array_schema
from cdgps_cli.tracking.acquisition import FALSE_ALARM, NONCOHERENT_MS
from cdgps_cli.tracking.channel import TrackOptions
from cdgps_cli.tracking.receiver import track_stream_to

TRACK_TOPIC = "/cdgps/track"
TRACK_SCHEMA = array_schema("cdgps.Track", {
    "prn": "integer", "doppler_hz": "number", "carrier_phase_cycles": "number", "code_phase_chips": "number",
    "i_prompt": "number", "q_prompt": "number", "cn0_dbhz": NULLABLE, "phase_lock": NULLABLE})


def track_file(path: str | Path, out_path: str | Path, *, fmt: str, fs_hz: float, if_hz: float = 0.0,
               iq_sign: str = "minus", prns=None, duration_s: float | None = None, opt: TrackOptions | None = None,
               noncoherent_ms: int | None = None, false_alarm: float | None = None, progress=None,
               block_samples: int = TRACK_BLOCK_SAMPLES) -> dict:
    """Track every satellite in a sample file; write TRACK.mcap; return the summary (no arrays).
    ``noncoherent_ms``, ``false_alarm``: the acquisition's (None: its defaults, NONCOHERENT_MS, FALSE_ALARM);
    ``block_samples``: samples read and tracked at a time (the results do not depend on it)."""
    noncoherent_ms = NONCOHERENT_MS if noncoherent_ms is None else noncoherent_ms
    false_alarm = FALSE_ALARM if false_alarm is None else false_alarm
    if not (np.isfinite(fs_hz) and 2.1e6 <= fs_hz <= 1e9):
        raise CdgpsError(f"--fs {fs_hz!r}: expected a sample rate in Hz between 2.1e6 and 1e9")
    if not (np.isfinite(if_hz) and abs(if_hz) < fs_hz / 2):
        raise CdgpsError(f"--if {if_hz!r}: expected a frequency below half the sample rate")
    if duration_s is not None and not (np.isfinite(duration_s) and duration_s > 0):
        raise CdgpsError(f"--duration {duration_s!r}: expected a positive number of seconds")
    if not (isinstance(noncoherent_ms, int) and 1 <= noncoherent_ms and noncoherent_ms * 1e-3 * fs_hz * 32 <= 4e8):
        raise CdgpsError(f"--noncoherent-ms {noncoherent_ms!r}: expected a whole number of ms ≥ 1 "
                         "(at most 4e8 / (32 × samples per ms))")
    if not (np.isfinite(false_alarm) and 0 < false_alarm < 1):
        raise CdgpsError(f"--false-alarm {false_alarm!r}: expected a probability between 0 and 1")
    if fmt not in FORMATS:
        raise CdgpsError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")
    size = Path(path).stat().st_size if Path(path).exists() else 0
    per = np.dtype(FORMATS[fmt][0]).itemsize * (2 if FORMATS[fmt][1] else 1)
    n = size // per if duration_s is None else min(size // per, int(duration_s * fs_hz))
    head = read_samples(path, fmt, iq_sign, max_samples=min(n, round(fs_hz * 1e-3) * noncoherent_ms))
    if n < fs_hz * 0.02:
        raise CdgpsError(f"{path}: {n / fs_hz * 1e3:.1f} ms of samples; tracking needs at least 20 ms")
    if n < fs_hz * 1e-3 * noncoherent_ms:
        raise CdgpsError(f"{path}: {n / fs_hz * 1e3:.1f} ms of samples; --noncoherent-ms {noncoherent_ms} needs more")
    warnings = ([f"--duration {duration_s:g} s: {path} holds {size // per / fs_hz:.4g} s of samples; all of them "
                 f"are tracked"] if duration_s is not None and duration_s * fs_hz > size // per else [])
    blocks = iter_samples(path, fmt, iq_sign, block_samples=block_samples, max_samples=n)
    with McapOut(out_path) as out:
        writer = _TrackWriter(out)
        try:
            res = track_stream_to(writer, head, blocks, fs_hz, prns, n_samples=n, if_hz=if_hz, opt=opt,
                                  progress=progress, noncoherent_ms=noncoherent_ms, false_alarm=false_alarm)
        except CdgpsError as exc:                 # (the acquisition's words name no file)
            raise CdgpsError(f"{path}: {exc}" if str(path) not in str(exc) else str(exc)) from None
        summary = {"input": str(path), "input_sha256": file_sha256(path), "format": fmt, "iq_sign": iq_sign,
                   "fs_hz": fs_hz, "if_hz": if_hz, "duration_s": n / fs_hz, "cdgps_version": __version__,
                   "options": {**(opt or TrackOptions()).__dict__, "noncoherent_ms": noncoherent_ms,
                               "false_alarm": false_alarm}, "acquisition": res["acquisition"],
                   "satellites": res["satellites"]}
        out.metadata("track", {key: (v if isinstance(v, str) else json.dumps(v)) for key, v in summary.items()})
    return dict(summary, warnings=warnings)


class _TrackWriter:
    """The sink of :func:`cdgps_cli.tracking.receiver.track_stream_to`: one message per 1 ms update on
    ``/cdgps/track``, the channels in PRN order (the channel is registered at the first call)."""

    COLUMNS = ("doppler_hz", "carrier_phase_cycles", "code_phase_chips", "i_prompt", "q_prompt", "cn0_dbhz",
               "phase_lock")

    def __init__(self, out: McapOut):
        self.out, self.ch = out, None

    def __call__(self, prns: list, columns: list) -> None:
        order = sorted(range(len(prns)), key=lambda j: prns[j])
        srt = [prns[j] for j in order]
        if self.ch is None:
            self.ch = self.out.channel(TRACK_TOPIC, TRACK_SCHEMA, {"prns": ",".join(map(str, srt))})
        cols = {k: np.stack([columns[j][k] for j in order], axis=1) for k in self.COLUMNS}
        t = columns[order[0]]["time_s"]
        for k in range(t.size):
            self.out.write(self.ch, float(t[k]), {"prn": srt, **{c: v[k].tolist() for c, v in cols.items()}})
