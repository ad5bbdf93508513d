"""docs/commands.md's shell blocks run, in order, as a user would paste them (issue 33 item 3; the machinery
and the other guides: tests/test_doc_commands_run.py).  A file of its own: the guide is long.  Its blocks
from the section SECOND on (control design, track, baseline, real receivers, multi-GNSS) read nothing the
earlier ones write: they run in tests/test_doc_commands_run_commands_second.py, so that pytest-xdist's
``--dist loadfile`` spreads the guide over two workers."""

from __future__ import annotations

from _doc_blocks import ROOT, run_guide, runnable, split_at_heading

GUIDE = ROOT / "docs" / "commands.md"
#: the heading from which on the blocks run in the second file
SECOND = "## `cdgps control design`"


def test_guide_shell_blocks_run(tmp_path):
    first, _ = split_at_heading(GUIDE, SECOND)
    run_guide(GUIDE, tmp_path, first)


def test_the_two_parts_are_the_whole_guide():
    first, second = split_at_heading(GUIDE, SECOND)
    assert first and second
    assert [b.line for b in first + second] == [b.line for b in runnable(GUIDE)]
