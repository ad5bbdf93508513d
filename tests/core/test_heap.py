"""cdgps_cli.core.heap: glibc's heap controls, and nothing elsewhere."""

import platform
import sys

import pytest

from cdgps_cli.core import heap

glibc = pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc only")


@glibc
def test_calls_are_made_on_glibc():
    import subprocess

    assert heap.available()
    assert heap.trim() is True
    # an option is set for the rest of the process: in a child, not in this test process
    code = "from cdgps_cli.core import heap; print(heap.set_option(heap.M_MMAP_THRESHOLD, 1 << 17))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "True"


def test_nothing_elsewhere(monkeypatch):
    monkeypatch.setattr(sys, "platform", "darwin")
    assert not heap.available()
    assert heap.trim() is False
    assert heap.set_option(heap.M_MMAP_THRESHOLD, 1 << 17) is False
