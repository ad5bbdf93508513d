"""core/toml_text.loads: tomllib's result, and nesting too deep for its recursion as a TOML error."""

from __future__ import annotations

import tomllib

import pytest

from cdgps_cli.core import toml_text


def test_plain_toml_reads_as_tomllib_reads_it():
    text = 'a = [1, [2, 3]]\n[t]\nb = {c = "d"}\n'
    assert toml_text.loads(text) == tomllib.loads(text)


@pytest.mark.parametrize("opener,closer", [("[", "]"), ("{x = ", "}")])
def test_nesting_too_deep_is_a_toml_decode_error_not_a_recursion_error(opener, closer):
    # tomllib's RecursionError escaped every reader's `except tomllib.TOMLDecodeError`: a traceback
    text = "a = " + opener * 5000 + ("1" if opener == "[" else "1") + closer * 5000 + "\n"
    with pytest.raises(tomllib.TOMLDecodeError, match="nested too deeply"):
        toml_text.loads(text)
    with pytest.raises(tomllib.TOMLDecodeError):     # a syntax error stays one
        toml_text.loads("a = [1,\n")
