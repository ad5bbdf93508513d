"""``cdgps init --every S``: the INITs of a long GNSS record's windows, one command (issue 29).

A day at 10 Hz is solved window by window: each window's INIT holds its own integers and static solution, and
``cdgps estimate RUN --init 'PATTERN'`` joins them into one STATES (docs/commands.md).  This writes those INITs:
the record (or ``start_s`` … ``start_s + duration_s`` of it) cut into windows of ``every_s`` seconds from its first
epoch, each read and solved alone (:func:`~cdgps_cli.pipeline.gnss.gnss_init`, the memory of one window), each INIT
the file ``cdgps init --start S --duration D`` would write, bit for bit.  A window that holds no observation of a
receiver (a logging gap) is skipped and said; any other error stops the command and no INIT is written.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.heap import trim
from cdgps_cli.io.atomic import (file_sha256, output_error, refuse_input_overwrite, refuse_output_collisions,
                                 remove_stale_temporaries, sigterm_raises, temporary_name)
from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, EmptyWindow, read_gnss_run, record_span
from cdgps_cli.pipeline.gnss import gnss_init

__all__ = ["init_windows", "window_starts"]


def window_starts(span_s: float, every_s: float, start_s: float = 0.0, duration_s: float | None = None) -> list:
    """(start_s, duration_s) of each window of ``every_s`` seconds over ``start_s`` … ``start_s + duration_s`` of a
    record ``span_s`` seconds long (None: to its end), from the record's first epoch.  The last window runs to that
    end (duration None when it is the record's: ``cdgps init --start S`` alone), a tail shorter than
    :data:`TAIL_SHARE` of a window joined to the window before it."""
    if not (math.isfinite(every_s) and every_s > 0):
        raise CdgpsError(f"--every {every_s!r}: expected a window length in seconds > 0")
    if not (math.isfinite(start_s) and start_s >= 0):
        raise CdgpsError(f"--start {start_s!r}: expected seconds from the record's first epoch, >= 0")
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise CdgpsError(f"--duration {duration_s!r}: expected seconds > 0")
    end = span_s if duration_s is None else min(span_s, start_s + duration_s)
    if start_s > span_s:
        raise CdgpsError(f"--start {start_s:g}: past the record's end ({span_s:g} s from its first epoch)")
    n = max(1, math.ceil((end - start_s) / every_s))
    if n > MAX_WINDOWS:
        raise CdgpsError(f"--every {every_s:g}: {n} windows of {end - start_s:g} s; at most {MAX_WINDOWS} (choose a "
                         f"longer window)")
    out = [start_s + k * every_s for k in range(n)]               # (k·S, not a running sum: no drift)
    if len(out) > 1 and end - out[-1] < TAIL_SHARE * every_s:     # a short tail goes with the window before it
        out.pop()
    ends = [*out[1:], None if duration_s is None else end]
    return [(a, None if b is None else b - a) for a, b in zip(out, ends)]


#: a record's tail shorter than this share of a window is solved with the window before it (not alone)
TAIL_SHARE = 0.25
#: the most windows one command cuts a record into (a day of 10 s windows is 8,640)
MAX_WINDOWS = 10_000


def _names(pattern: str, n: int) -> list:
    """The INIT file of each of ``n`` windows: ``pattern`` with its ``{k}`` field (Python format: ``init-{k:03d}.json``)
    the window's index; CdgpsError when it has none or two windows would share a file."""
    if "{k" not in pattern:
        raise CdgpsError(f"-o {pattern!r}: with --every, the output names a file per window: give a pattern with "
                         f"{{k}} for the window's index (e.g. init-{{k:03d}}.json)")
    try:
        names = [pattern.format(k=k) for k in range(n)]
    except (KeyError, IndexError, ValueError, AttributeError, TypeError) as exc:
        raise CdgpsError(f"-o {pattern!r}: not a pattern of {{k}} alone ({exc})") from None
    if len(set(names)) != n:
        raise CdgpsError(f"-o {pattern!r}: windows would share a file; give {{k}} in the name")
    return names


def init_windows(run_mcap, every_s: float, pattern: str, *, start_s: float = 0.0, duration_s: float | None = None,
                 options: dict | None = None, progress=None) -> dict:
    """Solve and write the INIT of every window (module docstring).

    Parameters
    ----------
    run_mcap : path
        A GNSS RUN.mcap.
    every_s : float
        Window length, s.
    pattern : str
        The INIT files, ``{k}`` the window's index (``init-{k:03d}.json``).
    start_s, duration_s : float
        The part of the record cut into windows, s from its first epoch (``duration_s`` None: to its end).
    options : dict, optional
        :func:`~cdgps_cli.pipeline.gnss.gnss_init`'s options (``ratio_threshold``, ``partial``, ``fix``).
    progress : callable, optional
        Gets a line per window.

    Returns
    -------
    dict
        ``windows``: per window its index, start_s, duration_s, file (None: skipped), and per rover its solution,
        integers fixed of estimated and ratio, or ``skipped`` (why); ``written``: the files.
    """
    say = progress or (lambda m: None)
    first, last = record_span(run_mcap)
    spans = window_starts(last - first, float(every_s), float(start_s), duration_s)
    names = _names(pattern, len(spans))
    outputs = [(f"-o {pattern} (window {k})", name, False) for k, name in enumerate(names)]
    refuse_output_collisions(outputs)
    refuse_input_overwrite(outputs, [("RUN_MCAP", run_mcap, False)])
    folder = next((n for n in names if Path(n).is_dir()), None)
    if folder is not None:
        raise CdgpsError(f"-o {pattern}: {folder} is a folder; the INIT of a window is a file (nothing written)")
    sha = file_sha256(run_mcap)
    texts, rows = [], []
    for k, ((s, d), name) in enumerate(zip(spans, names)):
        say(f"window {k + 1} of {len(spans)}: {s:g} s – {'the end' if d is None else f'{s + d:g} s'} → {name} …")
        try:
            run = read_gnss_run(run_mcap, columns=SOLVER_COLUMNS, window_s=(s, d))
        except EmptyWindow as exc:
            rows.append({"k": k, "start_s": s, "duration_s": d, "file": None, "skipped": str(exc)})
            continue
        res = gnss_init(run, options=options)
        del run
        trim()                               # (a window's freed arrays given back: memory one window's, not the day's)
        res["run_sha256"] = sha
        texts.append((name, json.dumps(res, indent=2) + "\n"))
        rows.append({"k": k, "start_s": s, "duration_s": d, "file": name,
                     "rovers": {r: {"solution": v["solution"], "n_fixed": v["n_fixed"],
                                    "n_estimated": v["n_estimated"], "ratio": v["ratio"]}
                                for r, v in res["rovers"].items()}})
    if not texts:
        raise CdgpsError(f"{run_mcap}: no window of {every_s:g} s holds observations of every receiver")
    _write_all(texts)
    return {"every_s": float(every_s), "windows": rows, "written": [n for n, _ in texts]}


def _write_all(texts: list) -> None:
    """Each (file, text) written whole, all or none: every text to a temporary beside its file first
    (:func:`~cdgps_cli.io.atomic.temporary_name`), then each moved into place; an error before the moves leaves no
    file, and one during them (a folder where a file goes) is named with what was already moved."""
    tmps, moved = [], []
    with sigterm_raises():
        try:
            for name, text in texts:
                p = Path(name)
                p.parent.mkdir(parents=True, exist_ok=True)          # (as every command's -o)
                remove_stale_temporaries(p)
                tmp = temporary_name(p)
                tmps.append((tmp, p))
                tmp.write_text(text)
            for tmp, p in tmps:
                os.replace(tmp, p)
                moved.append(str(p))
        except OSError as exc:
            err = output_error(p, exc)
            raise CdgpsError(f"{err}" + (f" (written before it: {', '.join(moved)})" if moved else "")) from None
        finally:
            for tmp, _ in tmps:
                if tmp.exists():
                    tmp.unlink()
