"""Fuzz: structure TOML configs (config.load_config) and GNSS run configs (config.load_gnss_config).

Property: any mutation gives a validated config or a CdgpsError naming the file, and a value
replaced in one ``key = value`` line is blamed on that key; the file is never modified.  A
structure config that is accepted also simulates one second without a traceback (the checks are
up front, not in the computation: issue 12 item 5's ``time_constant_s = 1e-9``).
"""

from __future__ import annotations

import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cdgps_cli.config.structure import load_config, load_gnss_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.sim.structure import SimOptions, simulate

from fuzz_support import DOF2, TESTBED, byte_mutation, check_reader, fuzz_settings, scratch

_KEY_LINE = re.compile(r"^(\s*)([A-Za-z_]+)(\s*=\s*)(.+?)(\s*#.*)?$")

#: TOML values of every type, including the extremes a float key must refuse
TOML_VALUE = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(lambda x: "nan" if x != x else ("inf" if x == float("inf") else
                                                         "-inf" if x == -float("inf") else repr(x))),
    st.integers(-2**70, 2**70).map(str),
    st.sampled_from(["1e308", "-1e308", "1e-308", "1e-9", "0", "-1", "0.0", "1e999", "true", "false", '""',
                     '"text"', "[]", '["C1"]', "[1, 2]", "[[1.0]]", "{ a = 1 }", "{}", "1979-05-27", '"∞"']),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters='"\\\n\r'), max_size=8)
    .map(lambda s: f'"{s}"'),
)


def _key_lines(text: str) -> list[int]:
    return [i for i, line in enumerate(text.splitlines()) if _KEY_LINE.match(line)]


@st.composite
def value_mutation(draw, text: str):
    """(key, mutated text): the value of one ``key = value`` line replaced by a drawn TOML value."""
    lines = text.splitlines(keepends=True)
    i = draw(st.sampled_from(_key_lines(text)))
    m = _KEY_LINE.match(lines[i].rstrip("\n"))
    v = draw(TOML_VALUE)
    return m.group(2), "".join(lines[:i] + [f"{m.group(1)}{m.group(2)}{m.group(3)}{v}\n"] + lines[i + 1:])


def _load_and_simulate(f):
    cfg = load_config(f)
    simulate(cfg, SimOptions(duration_s=1.0))
    return cfg


@pytest.mark.parametrize("source", [DOF2, TESTBED], ids=["2dof", "testbed"])
@fuzz_settings(30)
@given(data=st.data())
def test_structure_config_value_mutations(source, data):
    key, text = data.draw(value_mutation(source.read_text()))
    with scratch() as d:
        f = d / "s.toml"
        f.write_text(text)
        try:
            cfg = load_config(f)
        except CdgpsError as exc:
            msg = str(exc)
            assert str(f) in msg, msg
            assert key in msg or "not valid TOML" in msg, f"{key!r} not named: {msg}"
            return
        check_reader(lambda: simulate(cfg, SimOptions(duration_s=1.0)), f)


@pytest.mark.parametrize("source", [DOF2, TESTBED], ids=["2dof", "testbed"])
@fuzz_settings(25)
@given(data=st.data())
def test_structure_config_byte_mutations(source, data):
    _, raw = data.draw(byte_mutation(source.read_bytes()))
    with scratch() as d:
        f = d / "s.toml"
        f.write_bytes(raw)
        check_reader(lambda: _load_and_simulate(f), f)


@fuzz_settings(25)
@given(data=st.data())
def test_gnss_config_mutations(base, data):
    src = base / "gsim" / "config.toml"
    text = src.read_text()
    mutated = data.draw(st.one_of(value_mutation(text).map(lambda m: m[1].encode()),
                                  byte_mutation(text.encode()).map(lambda m: m[1])))
    with scratch() as d:
        for name in ("base.rnx", "rover.rnx", "nav.rnx"):
            (d / name).symlink_to(base / "gsim" / name)
        f = d / "config.toml"
        f.write_bytes(mutated)
        check_reader(lambda: load_gnss_config(f), f)
