"""Every guide's shell blocks run (issue 33 item 3): README.md and docs/*.md, each guide's ``sh``/``bash``
blocks in order in a temporary directory, as a user would paste them; every command must exit 0 and
write the ``-o`` output the next one reads (tests/_doc_blocks.py).  A block that cannot run carries
``<!-- norun: reason -->`` on the line before its fence; those are counted and listed here, and at
least 80 % of the ``cdgps`` commands quoted in the hand-written guides' shell blocks run.  The two
long guides run in their own files (tests/test_doc_commands_run_*.py) so that pytest-xdist's
``--dist loadfile`` spreads them (docs/commands.md over two files, split at a heading).  Not run twice:
README.md's one block, its example pipeline, run as written by
tests/cli/test_user_chains.py::test_readme_chain_as_written (with checks of its outputs), and
docs/tracking.md's one block, a copy of a block of docs/commands.md.  The parse-only check of every
quoted command's options is tests/test_doc_commands.py; the inventory: ``python tests/_doc_blocks.py``."""

from __future__ import annotations

import pytest

from _doc_blocks import GENERATED, GUIDES, ROOT, blocks, cdgps_commands, run_guide, runnable

#: guides run by their own test files
OWN_FILE = {"docs/commands.md", "docs/gnss-pipeline.md"}
#: guides whose only runnable block another test runs line by line as written, with checks of its outputs
#: (test_the_chain_run_elsewhere_is_the_guides_only_block holds them to that)
RUN_ELSEWHERE = {"README.md": "tests/cli/test_user_chains.py::test_readme_chain_as_written"}
#: guides whose every runnable block is, word for word, a self-contained block of another guide that runs
#: (test_a_guide_of_copied_blocks_has_only_copies holds them to that): the same command, not run twice
COPIES_OF = {"docs/tracking.md": "docs/commands.md"}
HERE = [p for p in GUIDES if runnable(p) and str(p.relative_to(ROOT)) not in OWN_FILE | set(RUN_ELSEWHERE) | set(COPIES_OF)]


@pytest.mark.parametrize("path", HERE, ids=lambda p: str(p.relative_to(ROOT)))
def test_guide_shell_blocks_run(path, tmp_path):
    run_guide(path, tmp_path)


def test_the_long_guides_have_their_own_files():
    for rel in OWN_FILE:
        stem = rel.split("/")[-1].removesuffix(".md").replace("-", "_")
        assert (ROOT / "tests" / f"test_doc_commands_run_{stem}.py").exists(), rel


def test_the_chain_run_elsewhere_is_the_guides_only_block():
    """README.md's one runnable block is its example pipeline, which test_readme_chain_as_written reads from
    README.md and runs command by command (in-process, from a directory holding configs/, as here): the
    same commands, not run a second time here.  A second runnable block, or a changed one, fails here."""
    from tests.cli.test_user_chains import readme_chain

    (block,) = runnable(ROOT / "README.md")
    assert [ln.strip() for ln in block.lines()] == readme_chain((ROOT / "README.md").read_text())
    assert all(c[0] == "cdgps" for ln in block.lines() for c in [ln.split()])


def test_a_guide_of_copied_blocks_has_only_copies():
    for guide, source in COPIES_OF.items():
        runs = {b.text for b in runnable(ROOT / source)}
        copies = runnable(ROOT / guide)
        assert copies and all(b.text in runs for b in copies), f"{guide}: a block not in {source}: run it here"


def _all_blocks():
    return [b for p in GUIDES for b in blocks(p)]


def test_a_block_quoting_a_command_says_what_it_is():
    """A fence holding ``cdgps …`` lines is ``sh``/``bash`` (run, or norun with its reason) or ``text``
    (a usage synopsis with placeholders); a bare fence is neither."""
    bare = [b.where for b in _all_blocks() if not b.info and cdgps_commands(b)]
    assert not bare, f"fences quoting cdgps commands without an info string (sh, or text for a synopsis): {bare}"


def test_norun_blocks_give_a_reason_and_most_commands_run():
    every = [b for b in _all_blocks() if str(b.path.relative_to(ROOT)) not in GENERATED]
    marked = [b for b in every if b.norun is not None]
    assert all(b.norun for b in marked), f"norun without a reason: {[b.where for b in marked if not b.norun]}"
    stray = [b.where for b in marked if not b.shell]
    assert not stray, f"norun markers before blocks that are not shell blocks: {stray}"
    shell = [b for b in every if b.shell]
    total = sum(len(cdgps_commands(b)) for b in shell)
    run = sum(len(cdgps_commands(b)) for b in shell if not b.norun)
    listing = "\n".join(f"  {b.where} ({len(cdgps_commands(b))} cdgps): {b.norun}" for b in marked)
    assert total > 80 and run >= 0.8 * total, f"{run} of {total} quoted cdgps commands run; not run:\n{listing}"
