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


_FRAGMENT = """
import sys
import numpy as np
from cdgps_cli.pipeline.fusion import map_large_blocks

def rss_mib():
    with open("/proc/self/status") as fh:
        return next(int(ln.split()[1]) for ln in fh if ln.startswith("VmRSS:")) / 1024

if sys.argv[1] == "fixed":
    assert map_large_blocks()
big = np.ones(1 << 21)          # 16 MiB, mapped; freed: glibc would raise its threshold to it
del big
before = rss_mib()
blocks = [np.ones(1 << 17) for _ in range(48)]     # 48 × 1 MiB (from the heap once the threshold rose)
pin = np.ones(512)                                 # a small block above them: the heap top cannot shrink
del blocks
print(rss_mib() - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_map_large_blocks_returns_freed_arrays_to_the_system():
    import os
    import subprocess
    from pathlib import Path

    # glibc's own defaults: a MALLOC_*_ variable (dask sets MALLOC_TRIM_THRESHOLD_ in the environment of
    # a process that started a cluster, as the batch tests do in this worker) fixes the threshold too
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[2])
    held = {m: float(subprocess.run([sys.executable, "-c", _FRAGMENT, m], env=env, capture_output=True, text=True,
                                    check=True).stdout) for m in ("default", "fixed")}
    assert held["default"] > 12.0          # the case exists: glibc keeps the freed 1 MiB arrays
    assert held["fixed"] < 4.0              # fixed threshold: each was its own mapping, given back


def test_map_large_blocks_is_a_no_op_elsewhere(monkeypatch):
    from cdgps_cli.pipeline.fusion import map_large_blocks

    monkeypatch.setattr(sys, "platform", "darwin")
    assert map_large_blocks() is False
