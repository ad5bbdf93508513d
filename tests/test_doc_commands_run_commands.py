"""docs/commands.md's shell blocks run, in order, as a user would paste them (issue 33 item 3; the machinery
and the other guides: tests/test_doc_commands_run.py).  A file of its own: the guide is long."""

from __future__ import annotations

from _doc_blocks import ROOT, run_guide


def test_guide_shell_blocks_run(tmp_path):
    run_guide(ROOT / "docs" / "commands.md", tmp_path)
