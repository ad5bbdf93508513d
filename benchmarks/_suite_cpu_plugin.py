"""pytest plugin for ``suite_cpu.py``: CPU seconds (user + system, this process and its waited-for children)
and wall seconds of every test item, fixture setup and teardown included, written as JSON rows
``[nodeid, cpu_s, wall_s]`` to the file named by ``$SUITE_CPU_RAW`` at the end of the session."""

from __future__ import annotations

import json
import os
import resource
import time

import pytest

_ROWS: list = []


def _cpu_s() -> float:
    """User + system CPU seconds of this process and of its finished children."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    cpu0, wall0 = _cpu_s(), time.perf_counter()
    yield
    _ROWS.append([item.nodeid, round(_cpu_s() - cpu0, 4), round(time.perf_counter() - wall0, 4)])


def pytest_sessionfinish(session):
    path = os.environ.get("SUITE_CPU_RAW")
    if path:
        with open(path, "w", encoding="utf-8") as f:
            json.dump(_ROWS, f)
