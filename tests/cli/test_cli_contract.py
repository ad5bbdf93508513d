"""The command line's contract, checked on every command (so a new one cannot forget it):
every option documented, ``-o/--output`` on every command that writes, ``-q`` accepted after
every subcommand, unknown options refused with exit 2 and no traceback, one-line summaries that
are not cut at an abbreviation, and the older output spellings still working."""

from __future__ import annotations

import re
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
READ_ONLY = {("info",), ("evaluate",)}      # print to stdout, write no file


def _commands(group=main, path=()):
    ctx = click.Context(group, info_name="cdgps")
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        yield path + (name,), cmd
        if isinstance(cmd, click.Group):
            yield from _commands(cmd, path + (name,))


ALL = list(_commands())
LEAVES = [(p, c) for p, c in ALL if not isinstance(c, click.Group)]


def _ids(items):
    return [" ".join(p) for p, _ in items]


def test_command_list_is_complete():
    names = {" ".join(p) for p, _ in ALL}
    assert {"simulate", "ingest", "info", "init", "estimate", "export", "evaluate", "spectra", "report",
            "report static", "report spectrum", "baseline", "config"} <= names


@pytest.mark.parametrize("path,cmd", ALL, ids=_ids(ALL))
def test_every_option_is_documented(path, cmd):
    undocumented = [p.opts[0] for p in cmd.params if isinstance(p, click.Option) and not (p.help or "").strip()]
    assert not undocumented, f"cdgps {' '.join(path)}: options without help: {undocumented}"
    assert (cmd.help or "").strip(), f"cdgps {' '.join(path)} has no help text"


@pytest.mark.parametrize("path,cmd", LEAVES, ids=_ids(LEAVES))
def test_every_writer_has_dash_o_output(path, cmd):
    outs = [p for p in cmd.params if isinstance(p, click.Option) and "--output" in p.opts]
    if path in READ_ONLY:
        assert not outs
        return
    assert outs, f"cdgps {' '.join(path)} writes files but has no -o/--output"
    assert "-o" in outs[0].opts and outs[0].required
    help_text = CliRunner().invoke(main, [*path, "--help"]).output
    assert "-o, --output" in help_text


@pytest.mark.parametrize("path,cmd", LEAVES, ids=_ids(LEAVES))
def test_every_command_has_json_and_quiet(path, cmd):
    """Issue 32: --json was missing on config and baseline-config."""
    names = {p.name for p in cmd.params}
    assert {"as_json", "quiet"} <= names, f"cdgps {' '.join(path)}: missing {sorted({'as_json', 'quiet'} - names)}"


@pytest.mark.parametrize("path,cmd", ALL, ids=_ids(ALL))
def test_quiet_accepted_after_every_subcommand(path, cmd):
    r = CliRunner().invoke(main, [*path, "-q", "--help"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, [*path, "--quiet", "--help"])
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("path,cmd", ALL, ids=_ids(ALL))
def test_unknown_option_refused_with_exit_2(path, cmd):
    r = CliRunner().invoke(main, [*path, "--no-such-option"])
    assert r.exit_code == 2, r.output
    assert "No such option" in r.output and "Traceback" not in r.output
    assert isinstance(r.exception, SystemExit)


_ABBREVIATION_END = re.compile(r"(\b(Eq|Eqs|Fig|Figs|Sec|Ref|cf|vs|etc|approx|no|e\.g|i\.e)\.|\.\.\.|…)$", re.I)


@pytest.mark.parametrize("group_path", [p for p, c in [((), main), *ALL] if isinstance(c, click.Group)],
                         ids=lambda p: " ".join(p) or "cdgps")
def test_summaries_are_whole_lines(group_path):
    group = main
    for name in group_path:
        group = group.commands[name]
    width = 80
    limit = width - 6 - max(len(n) for n in group.commands)
    for name, cmd in group.commands.items():
        text = cmd.get_short_help_str(limit)
        assert text, f"{name}: no summary"
        assert not _ABBREVIATION_END.search(text), f"{name}: summary cut at an abbreviation: {text!r}"
        assert len(text) <= limit, f"{name}: summary longer than one line at {width} columns: {text!r}"
    listing = CliRunner().invoke(main, [*group_path, "--help"], terminal_width=width).output
    for name, cmd in group.commands.items():
        assert f"{name}  " in listing and cmd.get_short_help_str(limit) in listing


def test_old_output_spellings_still_work(tmp_path):
    r = CliRunner()
    a = r.invoke(main, ["-q", "simulate", str(TESTBED), "--duration", "3", "--out", str(tmp_path / "a")])
    b = r.invoke(main, ["simulate", str(TESTBED), "--duration", "3", "-o", str(tmp_path / "b"), "-q"])
    c = r.invoke(main, ["simulate", str(TESTBED), "--duration", "3", "--output", str(tmp_path / "c")])
    assert a.exit_code == b.exit_code == c.exit_code == 0, (a.output, b.output, c.output)
    for f in ("receiver.csv", "gyro.csv", "truth.csv", "truth.json"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes() == (tmp_path / "c" / f).read_bytes()
    assert a.stderr == "" and b.stderr == "" and "simulating" in c.stderr
    help_text = r.invoke(main, ["simulate", "--help"]).output
    assert "--out " not in help_text.replace("--out still", "") and "older spelling --out" in help_text


def test_quiet_after_the_command_equals_quiet_before(tmp_path):
    r = CliRunner()
    sim = tmp_path / "sim"
    assert r.invoke(main, ["-q", "simulate", str(TESTBED), "--duration", "3", "-o", str(sim)]).exit_code == 0
    args = ["ingest", str(sim / "receiver.csv"), "--config", str(TESTBED)]
    before = r.invoke(main, ["-q", *args, "-o", str(tmp_path / "a.mcap")])
    after = r.invoke(main, [*args, "-o", str(tmp_path / "b.mcap"), "-q"])
    loud = r.invoke(main, [*args, "-o", str(tmp_path / "c.mcap")])
    assert before.exit_code == after.exit_code == loud.exit_code == 0
    assert before.stderr == after.stderr == "" and "wrote" in loud.stderr
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes() == (tmp_path / "c.mcap").read_bytes()
    info = r.invoke(main, ["info", str(tmp_path / "a.mcap"), "-q"])
    assert info.exit_code == 0 and "/cdgps/phase" in info.stdout and info.stderr == ""
