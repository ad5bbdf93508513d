"""Every `cdgps …` command quoted in a shell block of README.md and docs/*.md names a command that
exists and only options that command has, spelt as its help shows them (issue 33 item 3: guides
whose commands cannot go stale; issue 32: old spellings in the demo).  Placeholders (FILE, DIR, …)
and `[…]` optional parts are fine; the values are not run here (tests/test_doc_commands_run*.py run
every shell block not marked norun).  Fences are paired line by line (tests/_doc_blocks.py)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import click
import pytest

from _doc_blocks import blocks
from cdgps_cli.cli.commands import main

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
START = re.compile(r"^(?:\$\s+)?(?:\S*/)?cdgps(?:\s+|$)")


def _invocations(path: Path) -> list[list[str]]:
    """Token lists of the cdgps commands in the code blocks of a markdown file (shell blocks, run or
    not, and ``text`` synopses alike)."""
    out = []
    for block in (b.text for b in blocks(path)):
        for line in block.replace("\\\n", " ").splitlines():
            for piece in re.split(r"&&|;|\|\|?", line.split(" #")[0]):
                piece = piece.strip()
                m = START.match(piece)
                if not m:
                    continue
                try:
                    out.append(shlex.split(piece[m.end():].split(">")[0]))
                except ValueError:
                    continue
    return out


def _command(tokens):
    cmd, rest = main, [t for t in tokens if t not in ("-q", "--quiet")]
    while isinstance(cmd, click.Group) and rest and rest[0] in cmd.commands:
        cmd, rest = cmd.commands[rest[0]], rest[1:]
    return cmd, rest


CASES = [(p, t) for p in DOCS for t in _invocations(p)]


def test_the_docs_quote_many_commands():
    assert len(CASES) > 50


@pytest.mark.parametrize("path,tokens", CASES, ids=[f"{p.relative_to(ROOT)}:{' '.join(t[:2])}" for p, t in CASES])
def test_quoted_command_exists_with_its_options(path, tokens):
    cmd, rest = _command(tokens)
    if not rest and isinstance(cmd, click.Group):
        return                                            # `cdgps report` alone: the group
    assert not isinstance(cmd, click.Group), f"{path.name}: `cdgps {' '.join(tokens)}`: no such command"
    shown = {o for p in cmd.params if isinstance(p, click.Option)
             for o in p.opts + p.secondary_opts if o not in getattr(p, "aliases", ())} | {"-h", "--help", "-q", "--quiet"}
    used = {t.split("=")[0].strip("[]") for t in rest if re.fullmatch(r"\[?--?[a-zA-Z][\w-]*(=.*)?\]?", t)}
    assert used <= shown, f"{path.name}: `cdgps {' '.join(tokens)}`: {sorted(used - shown)} not options of this command"
