"""What tests/pipeline/test_batch_dask.py and test_batch_dask_resume.py share: the structure config and length
of the simulated sessions, and the byte comparison of a batch's OUTDIR with the single commands' outputs."""

from __future__ import annotations

import filecmp
from pathlib import Path

from cdgps_cli.pipeline import batch as B

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"
DURATION_S = 16
IGNORED = {B.RECORD_DIR, B.CAMPAIGN_FILE, "batch.json", "index.html", "trends.png", "positions.png"}


def assert_same_tree(ref: Path, out: Path, n_files: int) -> None:
    """``n_files`` files in ``out`` (batch's own files aside), each byte-identical to its namesake in ``ref``."""
    files = sorted(str(p.relative_to(out)) for p in out.rglob("*")
                   if p.is_file() and not (set(p.relative_to(out).parts) & IGNORED))
    assert len(files) == n_files, files
    for f in files:
        assert (ref / f).is_file(), f"{f}: not written by the single commands"
        assert filecmp.cmp(ref / f, out / f, shallow=False), f"{f} differs from the single command's"
