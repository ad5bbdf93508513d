"""Docs a newcomer finds their way in (issue 33 item 3): a README of at most 200 lines whose quick start
is exactly two commands, a docs/index.md that links every guide, and no relative link to a file that
is not there."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").rglob("*.md"))
LINK = re.compile(r"\]\(([^)\s]+)\)")


def test_readme_is_short_and_starts_with_two_commands():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    quick = text.split("## Quick start", 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    assert [ln.split()[:2] for ln in quick.strip().splitlines()] == [["make", "demo"], ["make", "test"]]


def test_every_guide_is_linked_from_the_index():
    index = (ROOT / "docs" / "index.md").read_text()
    linked = {(ROOT / "docs" / t.split("#")[0]).resolve() for t in LINK.findall(index)}
    guides = [p for p in (ROOT / "docs").glob("*.md") if p.name != "index.md"]
    missing = [p.name for p in guides if p.resolve() not in linked]
    assert not missing, f"docs/index.md does not link {missing}"


@pytest.mark.parametrize("path", [ROOT / "README.md", *DOCS], ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path):
    broken = []
    for target in LINK.findall(path.read_text()):
        if re.match(r"(https?:|mailto:|#)", target):
            continue
        f = (path.parent / target.split("#")[0]).resolve()
        if not f.exists():
            broken.append(target)
    assert not broken, f"{path.relative_to(ROOT)}: links to missing files {broken}"
