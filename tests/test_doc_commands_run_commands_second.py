"""docs/commands.md's shell blocks from its section ``cdgps control design`` on, run in order as a user would
paste them, in a work directory of their own (they read nothing the guide's earlier blocks write): the second
part of tests/test_doc_commands_run_commands.py, in a file of its own for pytest-xdist's ``--dist loadfile``."""

from __future__ import annotations

from _doc_blocks import run_guide, split_at_heading
from test_doc_commands_run_commands import GUIDE, SECOND


def test_guide_shell_blocks_run(tmp_path):
    _, second = split_at_heading(GUIDE, SECOND)
    run_guide(GUIDE, tmp_path, second)
