"""Angle expressions (``cdgps report static --angle``): the safe linear grammar of
:func:`cdgps_cli.core.expressions.parse_expression` — exact coefficients, clear errors, no ``eval``."""

from __future__ import annotations

import builtins

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.expressions import parse_expression

NAMES = tuple(f"q{i}" for i in range(1, 11))        # the testbed's coordinates


def vec(**coef) -> np.ndarray:
    v = np.zeros(len(NAMES))
    for k, c in coef.items():
        v[NAMES.index(k)] = c
    return v


VALID = {
    "q6+q10": vec(q6=1, q10=1),
    " - 0.5*q2 + q5 -q8": vec(q2=-0.5, q5=1, q8=-1),
    "1e-3*q1": vec(q1=1e-3),
    "q10": vec(q10=1),
    "-q10": vec(q10=-1),
    "+q3": vec(q3=1),
    "q5-q8": vec(q5=1, q8=-1),
    "0.5*q2 - q5": vec(q2=0.5, q5=-1),
    ".25*q4": vec(q4=0.25),
    "2.*q4": vec(q4=2.0),
    "1E+2*q9 - 3e0*q1": vec(q9=100.0, q1=-3.0),
    "q1+q1": vec(q1=2),                 # repeated names add up
    "q1 - q1": vec(),                   # … and cancel
    "q1\t+\nq2": vec(q1=1, q2=1),       # any whitespace
    "q1+q10": vec(q1=1, q10=1),         # q1 is not a prefix match of q10 (and vice versa)
}


@pytest.mark.parametrize("text", list(VALID))
def test_valid_expressions_exact(text):
    got = parse_expression(text, NAMES)
    assert got.shape == (len(NAMES),)
    assert got.dtype == float
    np.testing.assert_array_equal(got, VALID[text])


def test_accepts_list_of_names_and_custom_names():
    np.testing.assert_array_equal(parse_expression("theta_1 - 2*hub_B", ["hub_B", "theta_1"]), [-2.0, 1.0])
    np.testing.assert_array_equal(parse_expression("q2", list(NAMES)), vec(q2=1))


# (expression, words the message must contain)
MALFORMED = {
    "": ["empty"],
    "   ": ["empty"],
    "q6+": ["ends with an operator"],
    "q6 -": ["ends with an operator"],
    "-": ["ends with an operator"],
    "2q3": ["number must be followed by '*'", "position 1"],
    "2*": ["number must be followed by '*'"],
    "5": ["number must be followed by '*'"],
    "2*3*q1": ["number must be followed by '*'"],
    "q6 q7": ["expected + or -", "'q7'"],
    "q6+*q2": ["expected a coordinate name", "position 4", "'*'"],
    "*q1": ["expected a coordinate name", "position 1"],
    "+-q1": ["expected a coordinate name", "'-'"],
    "q11": ["unknown coordinate 'q11'", "known: q1, q2"],
    "Q1": ["unknown coordinate 'Q1'"],
    "q6+theta": ["unknown coordinate 'theta'"],
    "__import__('os')": ["unexpected character '('"],
    "(q1+q2)": ["unexpected character '('", "position 1"],
    "q1+(q2)": ["unexpected character '('", "position 4"],
    "q1**2": ["expected + or -", "position 3", "'*'"],
    "q1*2": ["expected + or -", "'*'"],
    "q1/2": ["unexpected character '/'"],
    "q1;q2": ["unexpected character ';'"],
    "q1−q2": ["unexpected character '−'"],           # unicode minus
    "0x10*q1": ["number must be followed by '*'"],
    "1_000*q1": ["number must be followed by '*'"],
    "q1.5": ["expected + or -"],
    "q1[0]": ["unexpected character '['"],
    "q1 if 1 else q2": ["expected + or -"],
    "lambda: q1": ["unexpected character ':'"],
}


@pytest.mark.parametrize("text", list(MALFORMED))
def test_malformed_expressions_clear_error(text):
    with pytest.raises(CdgpsError) as ei:
        parse_expression(text, NAMES)
    msg = str(ei.value)
    assert msg.startswith("angle expression"), msg
    for word in MALFORMED[text]:
        assert word in msg, (text, msg)
    assert "Traceback" not in msg
    if text.strip():
        assert repr(text) in msg                   # the message quotes the user's input
        assert any(w in msg for w in ("expected", "unknown", "must be"))   # … and says what was wanted


@pytest.mark.parametrize("bad", [None, 3, b"q1", ["q1"]])
def test_non_string_is_a_user_error(bad):
    with pytest.raises(CdgpsError, match="empty"):
        parse_expression(bad, NAMES)


@pytest.mark.parametrize("name", ["exit", "quit", "print", "open", "eval", "__import__", "os", "sys", "True", "None",
                                  "__builtins__", "np", "lambda", "e", "pi", "nan", "inf"])
def test_python_names_are_unknown_coordinates(name):
    """Nothing is evaluated: every identifier that is not a coordinate is rejected by name."""
    with pytest.raises(CdgpsError, match=f"unknown coordinate '{name}'"):
        parse_expression(f"q1+{name}", NAMES)


def test_no_eval_or_compile(monkeypatch):
    """The parser works with eval/exec/compile disabled, so it cannot be using them."""
    def boom(*a, **k):
        raise AssertionError("eval/exec/compile called")

    for fn in ("eval", "exec", "compile"):
        monkeypatch.setattr(builtins, fn, boom)
    np.testing.assert_array_equal(parse_expression("q6+q10", NAMES), vec(q6=1, q10=1))
    with pytest.raises(CdgpsError):
        parse_expression("__import__('os').system('true')", NAMES)


def test_random_linear_combinations_round_trip():
    """Property: any formatted linear combination parses back to its coefficients."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        k = int(rng.integers(1, 5))
        idx = rng.choice(len(NAMES), size=k, replace=False)
        coef = np.round(rng.uniform(-5, 5, k), 3).tolist()
        coef = [c if c != 0 else 1.0 for c in coef]
        parts = []
        for j, (i, c) in enumerate(zip(idx, coef)):
            sign = "-" if c < 0 else "+"
            mag = abs(c)
            style = int(rng.integers(3))
            num = {0: f"{mag:g}", 1: f"{mag:.3e}", 2: f"{mag!r}"}[style]
            term = NAMES[i] if mag == 1.0 and rng.random() < 0.5 else f"{num}*{NAMES[i]}"
            sp = " " * int(rng.integers(0, 3))
            parts.append(f"{'' if (j == 0 and sign == '+' and rng.random() < 0.5) else sign}{sp}{term}{sp}")
        text = "".join(parts)
        want = np.zeros(len(NAMES))
        want[idx] = coef
        np.testing.assert_allclose(parse_expression(text, NAMES), want, rtol=1e-12, atol=0, err_msg=text)


# ----------------------------------------------------------------------------- regressions (defects found, now fixed)

@pytest.mark.parametrize("text,pos,char", [("q1 + (q2)", 6, "("), ("q1 - q2 $", 9, "$"), ("  @q1", 3, "@"), ("q1+\t[", 5, "[")])
def test_error_position_points_at_the_character(text, pos, char):
    """The reported position is the offending character's, not the whitespace before it
    (was: 'q1 + (q2)' → position 5)."""
    with pytest.raises(CdgpsError) as ei:
        parse_expression(text, NAMES)
    assert f"unexpected character {char!r} at position {pos};" in str(ei.value), str(ei.value)
    assert text[pos - 1] == char


@pytest.mark.parametrize("text", ["1e999*q1", "q2 - 1e400*q3"])
def test_non_finite_coefficient_rejected(text):
    """A coefficient that overflows to inf is an error (was: accepted as an inf coefficient)."""
    with pytest.raises(CdgpsError, match="not a finite number"):
        parse_expression(text, NAMES)
