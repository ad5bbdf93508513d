"""File names and glob patterns given for one input (``--init 'init-*.json'``, ``rinex = "base_*.rnx"``): the files
they name, in order, each once.  No numerics: the command line expands patterns before it imports a solver."""

from __future__ import annotations

import glob
from pathlib import Path

from cdgps_cli.core.errors import CdgpsError

__all__ = ["expand_paths", "is_pattern"]

_GLOB_CHARS = ("*", "?", "[")


def is_pattern(name: str) -> bool:
    """Whether ``name`` is a glob pattern (has ``*``, ``?`` or ``[``) rather than a file name."""
    return any(c in str(name) for c in _GLOB_CHARS)


def expand_paths(items, what: str, repeats: str = "refuse") -> list[str]:
    """The files of ``items``: each a file name, or a glob pattern (its matches, in name order;
    a name that exists as a file is taken literally even with glob characters).

    Parameters
    ----------
    items : iterable of str
        File names and patterns, as given.
    what : str
        What they are, for the messages (``"--rinex 3040"``, ``"RECEIVER_CSV"``).
    repeats : {"refuse", "once"}
        A file given twice (by name or pattern): refused (a record's pieces), or kept once (files whose
        contents are merged, e.g. navigation files).

    Raises
    ------
    CdgpsError
        A pattern that matches no file; a file name that does not exist (named with ``what``, e.g. the
        config and key that give it); a file given twice.
    """
    out: list[str] = []
    for it in items:
        it = str(it)
        if is_pattern(it) and not Path(it).is_file():
            hits = sorted(p for p in glob.glob(it) if Path(p).is_file())
            if not hits:
                raise CdgpsError(f"{what}: the pattern {it!r} matches no file")
            out.extend(hits)
        elif not Path(it).exists():
            raise CdgpsError(f"{what}: {it}: cannot read: no such file")
        else:
            out.append(it)
    seen: dict[str, str] = {}
    for p in out:
        key = str(Path(p).resolve())
        if key in seen and repeats != "once":
            raise CdgpsError(f"{what}: the file {p} is given twice")
        seen.setdefault(key, p)
    return list(seen.values())
