"""The fused run gives the set-up's freed heap back before its filter (pipeline/fusion.py, issue 29)."""

import platform
import sys

import pytest

from cdgps_cli.pipeline.fusion import release_freed_heap


@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_release_freed_heap_calls_malloc_trim_on_glibc():
    assert release_freed_heap() is True


def test_release_freed_heap_is_a_no_op_elsewhere(monkeypatch):
    monkeypatch.setattr(sys, "platform", "darwin")
    assert release_freed_heap() is False
