"""scripts/demo.sh (`make demo`) uses only the current spellings of every option (issue 32: it used
``--out`` and ``--csv``, older spellings that still parse but are no longer documented)."""

from __future__ import annotations

import shlex
from pathlib import Path

import click

from cdgps_cli.cli.commands import main

DEMO = Path(__file__).resolve().parents[2] / "scripts" / "demo.sh"


def _demo_invocations() -> list[list[str]]:
    text = DEMO.read_text().replace("\\\n", " ")
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line.startswith('"$CDGPS"'):
            out.append(shlex.split(line.split("#")[0])[1:])
    return out


def _command(tokens: list[str]) -> tuple[click.Command, list[str]]:
    cmd, rest = main, [t for t in tokens if t not in ("-q", "--quiet")]
    while isinstance(cmd, click.Group) and rest and rest[0] in cmd.commands:
        cmd, rest = cmd.commands[rest[0]], rest[1:]
    return cmd, rest


def test_the_demo_uses_documented_options_only():
    invocations = _demo_invocations()
    assert len(invocations) > 20
    for tokens in invocations:
        cmd, rest = _command(tokens)
        assert not isinstance(cmd, click.Group), tokens
        shown = {o for p in cmd.params if isinstance(p, click.Option)
                 for o in p.opts if o not in getattr(p, "aliases", ())} | {"-h", "--help", "-q", "--quiet"}
        used = {t.split("=")[0] for t in rest if t.startswith("-") and not t.lstrip("-").replace(".", "").isdigit()}
        assert used <= shown, f"{' '.join(tokens[:3])}: {sorted(used - shown)} not among {sorted(shown)}"
