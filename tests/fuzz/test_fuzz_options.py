"""Fuzz: every command's numeric options (Click's test runner, in-process).

Two properties:

* the option layer of every command (walked from the CLI: new commands and options are included
  automatically): any text given to a float or integer option is accepted, or refused with exit 2
  and a message naming the option, never a traceback.  The command body is replaced by a stub, so
  this covers parsing, the finite-float check and the plausible bounds (limits.OPTION_BOUNDS) of
  every option at once;
* the real commands on small files, with values drawn inside those bounds (durations capped to
  keep runs short): exit 0, or exit 2 naming an option or a file, no traceback, nothing left at the
  output path after an error, inputs unchanged.
"""

from __future__ import annotations

import math

import click
import pytest
from hypothesis import given
from hypothesis import strategies as st

from cdgps_cli.cli.commands import main
from cdgps_cli.config.limits import OPTION_BOUNDS
from cdgps_cli.cli.guard import OUTPUT_PARAMS, _is_named_files, _spelling

from _shared import cli_commands
from fuzz_support import DOF2, NUMBER_TEXT, check_command, cli, fuzz_settings, scratch, sha256


def _is_numeric(p: click.Parameter) -> bool:
    return isinstance(p, click.Option) and not p.is_flag and p.type.name in ("float", "integer")


NUMERIC = [(path, cmd, p) for path, cmd in cli_commands(main) for p in cmd.params if _is_numeric(p)]


def _required_args(cmd: click.Command, d) -> list[str]:
    """Dummy values for the required parameters (the body is stubbed: only parsing must pass)."""
    args = []
    for i, p in enumerate(cmd.params):
        if not p.required:
            continue
        if p.name in OUTPUT_PARAMS:
            value = str(d / "out")
        elif _is_named_files(p):
            value = f"A={d / f'in{i}'}"
        elif isinstance(p.type, click.Path):
            value = str(d / f"in{i}")
        elif isinstance(p.type, click.Choice):
            value = str(p.type.choices[0])
        elif p.type.name in ("float", "integer", "finite float"):
            value = "1"
        else:
            value = "x"
        args += [value] if isinstance(p, click.Argument) else [p.opts[0], value]
    return args


def test_every_numeric_option_is_known():
    assert len(NUMERIC) > 30, "the walk over the CLI found too few numeric options"


@fuzz_settings(150)
@given(data=st.data())
def test_option_layer_of_every_command(data, monkeypatch_module):
    path, cmd, p = data.draw(st.sampled_from(NUMERIC), label="option")
    value = data.draw(NUMBER_TEXT, label="value")
    with scratch() as d:
        monkeypatch_module.setattr(cmd, "callback", lambda **kw: None)
        r = cli(*path, *_required_args(cmd, d), p.opts[0], value)
        monkeypatch_module.undo()
        spelling = _spelling(p)
        assert r.exception is None or isinstance(r.exception, SystemExit), f"{spelling} {value!r}: {r.exception!r}"
        assert r.exit_code in (0, 2), (spelling, value, r.output)
        if r.exit_code == 2:
            assert spelling in r.output or p.opts[0] in r.output, f"{spelling} {value!r}: {r.output!r}"


@pytest.fixture
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


# ---- real commands ------------------------------------------------------------------------------

#: cheap sub-ranges (a long --duration is a valid but slow run; the campaign tries the extremes)
CAPS = {"duration_s": (0.0, 20.0), "random_slips": (0, 50), "starts": (1, 16), "max_iterations": (1, 40),
        "pad": (1, 16), "n_slips": (0, 20), "rate_hz": (0.01, 5.0)}


def _value(data, name: str, is_int: bool):
    b = OPTION_BOUNDS.get(name)
    lo, hi = CAPS.get(name, (b.lo, b.hi) if b else (-1e6, 1e6))
    edges = [lo, hi] + ([0, 1, -1] if lo <= 0 <= hi else [])
    if is_int:
        return data.draw(st.one_of(st.sampled_from([int(e) for e in edges]), st.integers(int(lo), int(min(hi, 2**62)))))
    return data.draw(st.one_of(st.sampled_from([float(e) for e in edges]),
                               st.floats(lo, hi, allow_nan=False, allow_infinity=False)))


def _real_cases(base):
    run, init, states, sim = base / "RUN.mcap", base / "INIT.json", base / "STATES.mcap", base / "sim"
    return {
        "init": (["init", run], "json", [run]),
        "estimate": (["estimate", run, "--init", init], "mcap", [run, init]),
        "spectra": (["spectra", states], "", [states]),
        "evaluate": (["evaluate", "--truth", sim, "--estimate", states], None, [states]),
        "simulate": (["simulate", DOF2], "", [DOF2]),
        "report static": (["report", "static", states, "--angle", "q1"], "", [states]),
    }


@fuzz_settings(20)
@given(data=st.data())
def test_real_commands_with_numeric_options(base, data):
    cases = _real_cases(base)
    name = data.draw(st.sampled_from(sorted(cases)), label="command")
    argv, out_kind, inputs = cases[name]
    cmd = main
    for part in name.split():
        cmd = cmd.commands[part]
    opts = [p for p in cmd.params if _is_numeric(p) and p.name not in ("seed",) or (p.name == "seed" and name == "simulate")]
    chosen = data.draw(st.lists(st.sampled_from(opts), min_size=1, max_size=3, unique_by=lambda p: p.name), label="options")
    extra = []
    for p in chosen:
        v = _value(data, p.name, p.type.name == "integer")
        extra += [p.opts[0], repr(v) if isinstance(v, float) else str(v)]
    with scratch() as d:
        out = d / (f"out.{out_kind}" if out_kind else "out")
        before = {f: sha256(f) for f in inputs if f.is_file()}
        r = cli(*argv, *extra, *(["-o", out] if out_kind is not None else []))
        names = [_spelling(p) for p in chosen] + [str(f) for f in inputs] + ["--"]
        check_command(r, before, [out] if out_kind is not None else [], *names)


@pytest.mark.parametrize("argv,words", [
    (["simulate", DOF2, "--duration", "0"], ["--duration"]),
    (["spectra", "{states}", "--overlap", "-1"], ["--overlap -1: expected a fraction of a segment in [0, 1)"]),
])
def test_found_messages_name_the_option(base, tmp_path, argv, words):
    """Found by this suite: 'duration: expected …' (simulate's field name) and spectra's one combined
    'segment must be positive, pad ≥ 1, 0 ≤ overlap < 1'."""
    argv = [str(a).replace("{states}", str(base / "STATES.mcap")) for a in argv]
    r = cli(*argv, "-o", tmp_path / "out")
    assert r.exit_code == 2 and isinstance(r.exception, SystemExit), r.output
    for w in words:
        assert w in r.output, r.output
    assert not (tmp_path / "out").exists()
