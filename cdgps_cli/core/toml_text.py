"""TOML text to a dict, every reader through one function.

:func:`tomllib.loads` recurses once per level of nested arrays and inline tables: a file nested a
few hundred levels deep (damaged, or made to break the reader) ends in a RecursionError, which no
reader's ``except tomllib.TOMLDecodeError`` catches, so the command died with a traceback.
:func:`loads` reports it as the TOML error it is, so each reader names its file as for any other
syntax error ("PATH: not valid TOML: …").
"""

from __future__ import annotations

import tomllib

__all__ = ["loads", "TOMLDecodeError"]

TOMLDecodeError = tomllib.TOMLDecodeError


def loads(text: str) -> dict:
    """:func:`tomllib.loads`; nesting too deep to parse raises :class:`tomllib.TOMLDecodeError` too."""
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise TOMLDecodeError("arrays or inline tables nested too deeply to read (hundreds of levels)") from None
