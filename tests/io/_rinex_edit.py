"""A copy of a RINEX file with its lines edited, for the readers' bad-input and fallback tests."""

from __future__ import annotations


def edited_copy(tmp_path, src, edit):
    """Write ``src`` to ``tmp_path`` after ``edit(lines, end_of_header_index)`` changed its lines in place."""
    lines = src.read_text(encoding="latin-1").split("\n")
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln)
    edit(lines, end)
    out = tmp_path / src.name
    out.write_text("\n".join(lines), encoding="latin-1")
    return out
