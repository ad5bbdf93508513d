"""cdgps_cli.core.beside: a computation forked beside the caller gives fn()'s value, its errors, and
falls back to the caller's own process when it cannot fork or the child dies."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from cdgps_cli.core import beside
from tests._shared import can_fork

needs_fork = pytest.mark.skipif(not can_fork(), reason="no fork or a single CPU here")


@pytest.fixture(autouse=True)
def _forks(forking):
    """Every test here forks where it can, whatever the suite's default (tests/conftest.py); a test of the
    serial path sets CDGPS_SERIAL=1 itself."""


@needs_fork
def test_result_computed_in_a_child_equals_the_callers():
    parent = os.getpid()
    x = np.random.default_rng(0).normal(size=(200, 200))

    def work():
        return os.getpid(), np.linalg.inv(x) @ x

    job = beside.start(work)
    assert job.forked
    pid, value = job.result()
    assert pid != parent
    np.testing.assert_array_equal(value, work()[1])           # bit for bit: the same code on the same data


@needs_fork
def test_a_large_result_comes_back_whole():
    job = beside.start(lambda: np.arange(3_000_000, dtype=np.float64))   # 24 MB: far beyond a pipe's buffer
    np.testing.assert_array_equal(job.result(), np.arange(3_000_000, dtype=np.float64))


@needs_fork
def test_an_error_in_the_child_is_raised_in_the_caller():
    def fails():
        raise ValueError("epoch 7: no satellites")

    with pytest.raises(ValueError, match="epoch 7: no satellites"):
        beside.start(fails).result()


@needs_fork
def test_an_unpicklable_error_becomes_a_runtime_error_naming_it():
    class Local(Exception):                                  # a local class does not pickle
        pass

    def fails():
        raise Local("odd")

    with pytest.raises(RuntimeError, match="Local: odd"):
        beside.start(fails).result()


class _OddInit(Exception):
    def __init__(self, a, b):                                # pickles as _OddInit(message): does not unpickle
        super().__init__(f"{a}/{b}")


@needs_fork
def test_an_error_that_does_not_unpickle_is_raised_by_the_callers_own_run():
    def fails():
        raise _OddInit(1, 2)

    with pytest.raises(_OddInit, match="1/2"):
        beside.start(fails).result()


@needs_fork
def test_a_child_that_dies_is_computed_again_here():
    parent = os.getpid()

    def work():
        if os.getpid() != parent:
            os.kill(os.getpid(), signal.SIGKILL)             # killed before it answers (out of memory, say)
        return "computed here"

    job = beside.start(work)
    assert job.result() == "computed here" and not job.forked


@needs_fork
def test_cancel_kills_a_running_child():
    job = beside.start(lambda: time.sleep(60))
    pid = job._pid
    t0 = time.perf_counter()
    with job:
        pass                                                  # leaving the block without collecting cancels
    assert time.perf_counter() - t0 < 5
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)                           # reaped: no zombie left


def test_serial_when_asked(monkeypatch):
    monkeypatch.setenv("CDGPS_SERIAL", "1")
    assert not beside.forking_allowed()
    job = beside.start(os.getpid)
    assert not job.forked and job.result() == os.getpid()


def test_both_gives_the_two_values_in_order():
    a, b = beside.both(lambda: np.arange(5.0), lambda: "here")
    np.testing.assert_array_equal(a, np.arange(5.0))
    assert b == "here"


@pytest.mark.parametrize("serial", [False, True])
def test_both_raises_the_first_error_as_the_calls_in_turn_would(monkeypatch, serial):
    if serial:
        monkeypatch.setenv("CDGPS_SERIAL", "1")

    def first_fails():
        raise ValueError("master: no ephemeris")

    def second_fails():
        raise KeyError("rover")

    with pytest.raises(ValueError, match="master: no ephemeris"):
        beside.both(first_fails, second_fails)
    with pytest.raises(KeyError, match="rover"):
        beside.both(lambda: 1, second_fails)
    with pytest.raises(ValueError, match="master"):
        beside.both(first_fails, lambda: 2)


def test_both_in_turn_without_a_second_core(monkeypatch):
    monkeypatch.setenv("CDGPS_SERIAL", "1")
    order = []
    assert beside.both(lambda: order.append("first") or 1, lambda: order.append("second") or 2) == (1, 2)
    assert order == ["first", "second"]


@needs_fork
def test_a_result_that_does_not_pickle_is_computed_here():
    parent = os.getpid()

    def work():
        if os.getpid() != parent:
            return [np.zeros(10), lambda: None]               # the lambda stops pickle part-way through the message
        return "computed here"

    job = beside.start(work)
    assert job.result() == "computed here" and not job.forked
