"""Many consecutive log files of one receiver as one record (``cdgps ingest`` of hourly or daily files).

Receivers write hourly or daily files; ``cdgps ingest`` accepts, per antenna (or for the receiver
CSV), a sequence of such files — the option repeated, or a glob pattern the shell did not expand
(quoted) — and joins them into one record:

* :func:`expand_paths` turns the given names and patterns into the files (a pattern matching
  nothing is an error naming it);
* :func:`join_tables` orders the files' tables by their first epoch (not by name), drops the
  epochs a file repeats from an earlier one (the earlier file's rows are kept; a warning names
  both files, the span and whether the repeated rows were identical), refuses files that are not
  consecutive (a file with epochs inside an earlier file's span that the earlier file lacks), and
  reports the gaps between files (times, length, missing epochs).

Times are whatever continuous scale the reader gives (GPS seconds since 1980 for RINEX and UBX,
run seconds for the receiver CSV), so day boundaries and GPS week rollovers inside the record
need nothing here: the readers turn calendar dates and (week, time of week) into one scale.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.file_patterns import expand_paths, is_pattern  # noqa: F401 (their home; named here too)

__all__ = ["expand_paths", "is_pattern", "JoinReport", "join_tables", "one_file_for_two_receivers"]

@dataclass
class JoinReport:
    """How the files of one record were joined (:func:`join_tables`).

    ``files``: in time order, each ``{"file", "first_s", "last_s", "epochs", "epochs_used"}``;
    ``gaps``: between consecutive files, each ``{"after", "before", "start_s", "end_s", "gap_s",
    "missing_epochs"}``; ``overlaps``: each ``{"file", "earlier_file", "start_s", "end_s",
    "epochs", "identical"}``; ``warnings``: worded.
    """

    files: list = field(default_factory=list)
    gaps: list = field(default_factory=list)
    overlaps: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"files": self.files, "gaps": self.gaps, "overlaps": self.overlaps}


def one_file_for_two_receivers(files: dict) -> list[str]:
    """The warning (a list of one, or empty) naming a file given to two receivers (``files``: the receiver's name as
    the command line or config calls it → its files, :func:`expand_paths`'s): every double difference of the same
    log against itself is zero, and the solution a baseline of zero length that checks the processing, not the
    receivers (a zero baseline of two receivers on one antenna: each writes its own log).  The same file under two
    names (a link) counts."""
    seen: list = []
    for who, paths in files.items():
        for path in paths:
            for other, q in seen:
                if other != who and _same_file(path, q):
                    also = "" if str(path) == str(q) else f" (the file {q} under another name)"
                    return [f"{path}{also}: given for two receivers ({other} and {who}): every double difference is "
                            f"zero, and the solution a zero baseline that checks the processing, not the receivers "
                            f"(two receivers on one antenna write a log each)"]
            seen.append((who, path))
    return []


def _same_file(a, b) -> bool:
    try:
        return Path(a).samefile(b)
    except OSError:
        return False


def _first_epoch(tab: pd.DataFrame, time_col: str) -> float:
    t = tab[time_col].to_numpy(dtype=np.float64)
    return float(t.min()) if t.size else np.inf


def join_tables(pieces, time_col: str, interval_s: float, time_text=lambda t: f"{t:g} s",
                what: str = "") -> tuple[pd.DataFrame, JoinReport, list]:
    """Join the tables of consecutive files of one record into one table, in time order.

    Parameters
    ----------
    pieces : list of (str, DataFrame)
        Each file's name and table (rows in time order within the file; several rows per epoch
        allowed, e.g. one per satellite).
    time_col : str
        The time column (a continuous scale, s).
    interval_s : float
        The record's nominal epoch interval, s: a step over 1.5 intervals between two files is a gap.
    time_text : callable
        Formats a time of ``time_col`` for the messages.
    what : str
        Prefix of the warnings (e.g. the antenna name).

    Returns
    -------
    table : DataFrame
        The rows of every file in time order, an epoch repeated by a later file taken from the
        earlier file only; the index is reset.
    report : JoinReport
    order : list of int
        The indices of ``pieces`` in time order (for joining companion tables the same way).

    Raises
    ------
    CdgpsError
        A file with epochs inside an earlier file's span that the earlier file does not have
        (interleaved files: not consecutive pieces of one record), naming both files and the time.
    """
    order = sorted(range(len(pieces)), key=lambda i: (_first_epoch(pieces[i][1], time_col), i))
    rep = JoinReport()
    kept: list[pd.DataFrame] = []
    prev_name, prev_last, seen = None, -np.inf, np.array([], dtype=np.float64)
    pre = f"{what}: " if what else ""
    for i in order:
        name, tab = pieces[i]
        t = tab[time_col].to_numpy(dtype=np.float64)
        epochs = np.unique(t)
        early = t <= prev_last                        # (only these can repeat or interleave an earlier file)
        dup = np.zeros(t.size, dtype=bool)
        if early.any():
            dup[early] = np.isin(t[early], seen)
        inside = ~dup & early
        if inside.any():
            t_bad = float(t[np.flatnonzero(inside)[0]])
            raise CdgpsError(f"{name}: epoch {time_text(t_bad)} lies inside the span of the earlier file {prev_name} "
                             f"(up to {time_text(prev_last)}), which does not have it: the files are not consecutive "
                             f"pieces of one record")
        if dup.any():
            _overlap(rep, kept, tab, dup, name, time_col, time_text, pre)
        use = tab[~dup] if dup.any() else tab
        if len(use) and prev_name is not None:
            _gap(rep, prev_name, name, prev_last, float(use[time_col].iloc[0]), interval_s, time_text, pre)
        rep.files.append({"file": name, "first_s": float(epochs[0]) if epochs.size else None,
                          "last_s": float(epochs[-1]) if epochs.size else None, "epochs": int(epochs.size),
                          "epochs_used": int(np.unique(t[~dup]).size)})
        if len(use):
            kept.append(use)
            u = epochs if not dup.any() else np.unique(use[time_col].to_numpy(dtype=np.float64))
            # (after every epoch seen, the usual case: appended, the same sorted union without sorting it again)
            seen = np.concatenate([seen, u]) if not seen.size or u[0] > seen[-1] else np.union1d(seen, u)
            prev_last, prev_name = float(seen[-1]), name
    table = pd.concat(kept, ignore_index=True) if kept else pieces[order[0]][1].iloc[:0].reset_index(drop=True)
    return table, rep, order


def _overlap(rep: JoinReport, kept: list, tab: pd.DataFrame, dup: np.ndarray, name: str, time_col: str,
             time_text, pre: str) -> None:
    """Record (and word) the epochs ``name`` repeats from the files kept before it."""
    rows = tab[dup].reset_index(drop=True)
    t_rep = np.unique(rows[time_col].to_numpy(dtype=np.float64))
    before = pd.concat(kept, ignore_index=True)
    src = before[np.isin(before[time_col].to_numpy(dtype=np.float64), t_rep)].reset_index(drop=True)
    earlier = sorted({e["file"] for e in rep.files if e["epochs_used"] and e["last_s"] is not None
                      and e["last_s"] >= t_rep[0] and e["first_s"] <= t_rep[-1]})
    identical = len(src) == len(rows) and src.equals(rows)
    rep.overlaps.append({"file": name, "earlier_file": ", ".join(earlier), "start_s": float(t_rep[0]),
                         "end_s": float(t_rep[-1]), "epochs": int(t_rep.size), "identical": bool(identical)})
    rep.warnings.append(f"{pre}{name} repeats {t_rep.size} epoch(s) of {', '.join(earlier)} "
                        f"({time_text(float(t_rep[0]))} – {time_text(float(t_rep[-1]))}); "
                        + ("the rows are identical; kept once" if identical else
                           f"the rows DIFFER; kept those of {', '.join(earlier)}"))


def _gap(rep: JoinReport, prev_name: str, name: str, t0: float, t1: float, interval_s: float, time_text,
         pre: str) -> None:
    """Record (and word) a gap between the last epoch of ``prev_name`` and the first of ``name``."""
    dt = t1 - t0
    if not (np.isfinite(interval_s) and interval_s > 0) or dt <= 1.5 * interval_s:
        return
    missing = int(round(dt / interval_s)) - 1
    rep.gaps.append({"after": prev_name, "before": name, "start_s": t0, "end_s": t1, "gap_s": dt,
                     "missing_epochs": missing})
    rep.warnings.append(f"{pre}gap of {dt:g} s ({missing} epochs missing) between {prev_name} (last epoch "
                        f"{time_text(t0)}) and {name} (first epoch {time_text(t1)})")
