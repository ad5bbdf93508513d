"""benchmarks/tree_memory.py: the memory of a command and of the processes it forks is summed."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("tree_memory", ROOT / "benchmarks" / "tree_memory.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.skipif(not Path("/proc/self/smaps_rollup").exists(), reason="Linux /proc only")
def test_a_forked_child_holding_memory_is_counted():
    """A parent and a child each touching 150 MB of their own: the sum holds both (≥ 280 MiB), one
    process alone could not show it."""
    code = ("import os, time\n"
            "b = bytearray(150 * 2**20)\n"
            "for i in range(0, len(b), 4096): b[i] = 1\n"
            "pid = os.fork()\n"
            "if pid == 0:\n"
            "    c = bytearray(150 * 2**20)\n"
            "    for i in range(0, len(c), 4096): c[i] = 1\n"
            "    time.sleep(1.0); os._exit(0)\n"
            "os.waitpid(pid, 0)\n")
    res = _tool().measure([sys.executable, "-c", code], every_s=0.05)
    assert res["exit"] == 0 and res["max_processes"] == 2
    assert res["peak_tree_pss_mib"] >= 280                 # 150 + 150 private, the parent's 150 shared once
    assert res["peak_tree_rss_mib"] >= res["peak_tree_pss_mib"]
