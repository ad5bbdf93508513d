"""Docs that quote benchmark numbers are generated from the benchmark's JSON, so they cannot go
stale against it (issue 32: docs/fe-tower.md showed NEES/dof 5.995 after the code gave 1.08)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _bench(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_fe_tower_doc_table_is_the_json():
    fe = _bench("fe_tower")
    doc = (ROOT / "docs" / "fe-tower.md").read_text()
    block = doc[doc.index(fe.BEGIN) + len(fe.BEGIN): doc.index(fe.END)].strip()
    result = json.loads((ROOT / "docs" / "benchmarks" / "fe_tower.json").read_text())
    assert block == fe.markdown_table(result).strip()
