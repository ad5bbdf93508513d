"""Every command's ``--help`` text is pinned (issue 29 item 3: lazy command loading must not change
what users see).  The golden file was recorded from the eagerly loaded CLI; regenerate it only for an
intended help change::

    PYTHONPATH=$PWD python tests/cli/test_help_golden.py --regenerate
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import click
from click.testing import CliRunner

GOLDEN = Path(__file__).parent / "data" / "help_golden.json"
ROOT = Path(__file__).resolve().parents[2]


def _paths(group: click.Group, prefix: tuple = ()) -> list[tuple]:
    """Every command path below ``group`` (the group itself first), in sorted order."""
    ctx = click.Context(group, info_name="cdgps")
    out = [prefix]
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        if isinstance(cmd, click.Group):
            out += _paths(cmd, prefix + (name,))
        else:
            out.append(prefix + (name,))
    return out


def help_texts() -> dict[str, str]:
    """``{"cdgps rtk": <help text>, ...}`` at a fixed terminal width."""
    from cdgps_cli.cli.commands import main

    runner = CliRunner()
    texts = {}
    for path in _paths(main):
        r = runner.invoke(main, [*path, "--help"], prog_name="cdgps", terminal_width=100)
        assert r.exit_code == 0, (path, r.output)
        texts[" ".join(("cdgps",) + path)] = r.output
    return texts


def test_every_help_text_is_unchanged():
    golden = json.loads(GOLDEN.read_text())
    now = help_texts()
    assert sorted(now) == sorted(golden)
    for name in golden:
        assert now[name] == golden[name], name


def test_shell_completion_lists_commands_and_options():
    env = {**os.environ, "PYTHONPATH": str(ROOT), "_CDGPS_COMPLETE": "bash_complete",
           "COMP_WORDS": "cdgps r", "COMP_CWORD": "1"}
    code = "from cdgps_cli.cli.commands import main; main(prog_name='cdgps')"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True).stdout
    assert "plain,rtk" in out.split() and "plain,report" in out.split(), out
    env["COMP_WORDS"], env["COMP_CWORD"] = "cdgps rtk --ba", "2"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True).stdout
    assert "plain,--base" in out.split() and "plain,--base-xyz" in out.split(), out


if __name__ == "__main__" and sys.argv[1:] == ["--regenerate"]:
    GOLDEN.write_text(json.dumps(help_texts(), indent=1, ensure_ascii=False, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN}")
