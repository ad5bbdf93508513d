"""Angle expressions such as ``q6+q10``, ``q5-q8`` or ``0.5*q2 - q5``: a tiny, safe grammar.

Grammar (whitespace ignored; no ``eval``)::

    expression := ["+" | "-"] term (("+" | "-") term)*
    term       := [number "*"] name
    name       := a generalized-coordinate name of the config (letters, digits, _ ; not starting with a digit)
    number     := decimal number, e.g. 2, 0.5, 1e-3

An expression is a linear combination of coordinates; :func:`parse_expression` returns its
coefficient vector over the config's coordinates.
"""

from __future__ import annotations

import re

import numpy as np

from cdgps_cli.core.errors import CdgpsError

_TOKEN = re.compile(r"\s*(?:(?P<num>\d+(?:\.\d*)?(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)|(?P<name>[A-Za-z_][A-Za-z0-9_]*)|(?P<op>[+\-*]))")


def parse_expression(text: str, names: list[str] | tuple[str, ...]) -> np.ndarray:
    """Coefficients (len(names),) of a linear angle expression.

    Raises
    ------
    CdgpsError
        On a syntax error (with the position) or an unknown coordinate name.
    """
    if not isinstance(text, str) or not text.strip():
        raise CdgpsError("angle expression is empty; expected e.g. \"q6+q10\"")
    tokens = []
    pos = 0
    while pos < len(text):
        if text[pos:].strip() == "":
            break
        m = _TOKEN.match(text, pos)
        if not m or m.end() == pos:
            at = pos + len(text[pos:]) - len(text[pos:].lstrip())
            raise CdgpsError(f"angle expression {text!r}: unexpected character {text[at]!r} at position {at + 1}; "
                             f"expected coordinate names joined by + or -, optionally scaled as 0.5*q2")
        kind = m.lastgroup
        tokens.append((kind, m.group(kind), m.start(kind)))
        pos = m.end()
    coef = np.zeros(len(names))
    i = 0
    sign = 1.0
    expect_term = True
    first = True
    while i < len(tokens):
        kind, val, at = tokens[i]
        if expect_term:
            if kind == "op" and val in "+-" and first:
                sign = -1.0 if val == "-" else 1.0
                i += 1
                first = False
                continue
            scale = 1.0
            if kind == "num":
                if i + 2 >= len(tokens) or tokens[i + 1][:2] != ("op", "*") or tokens[i + 2][0] != "name":
                    raise CdgpsError(f"angle expression {text!r}: a number must be followed by '*' and a name (position {at + 1})")
                scale = float(val)
                if not np.isfinite(scale):
                    raise CdgpsError(f"angle expression {text!r}: coefficient {val!r} is not a finite number (position {at + 1})")
                i += 2
                kind, val, at = tokens[i]
            if kind != "name":
                raise CdgpsError(f"angle expression {text!r}: expected a coordinate name at position {at + 1}, got {val!r}")
            if val not in names:
                raise CdgpsError(f"angle expression {text!r}: unknown coordinate {val!r} (known: {', '.join(names)})")
            coef[list(names).index(val)] += sign * scale
            expect_term = False
            first = False
            i += 1
        else:
            if kind != "op" or val not in "+-":
                raise CdgpsError(f"angle expression {text!r}: expected + or - at position {at + 1}, got {val!r}")
            sign = -1.0 if val == "-" else 1.0
            expect_term = True
            i += 1
    if expect_term:
        raise CdgpsError(f"angle expression {text!r}: ends with an operator; expected a coordinate name")
    return coef
