"""The one lock-segment rule (cdgps_cli.measurement.channels) against a plain per-row reference."""

from __future__ import annotations

import math

import numpy as np

from cdgps_cli.measurement.channels import FIRST, REACQUIRED, RESTART, LockTime, lock_segments, ubx_restarts


def _reference(channel, step, lock=None, lock_time=None, slip=None, max_step=1.0, reset=None):
    """The rule written out row by row, channel by channel, in time order."""
    n = len(step)
    cause = np.zeros(n, dtype=int)
    for c in sorted(set(channel)):
        rows = sorted((i for i in range(n) if channel[i] == c), key=lambda i: (step[i], i))
        for j, i in enumerate(rows):
            if j == 0:
                cause[i] = FIRST
                continue
            p = rows[j - 1]
            d = step[i] - step[p]
            restart = bool(slip is not None and slip[i]) or bool(reset is not None and reset[i])
            bridged = False
            if lock is not None and lock_time is None:
                restart = restart or lock[i] == 0 or lock[i] < lock[p]
                bridged = lock[i] == lock[p] + d
            elif lock is not None:
                short = lock[i] < min(lock[p] + d * lock_time.per_step, lock_time.cap) - lock_time.tolerance
                restart, bridged = restart or short, not short
            if d > max_step and (restart or not bridged):
                cause[i] = REACQUIRED
            elif restart:
                cause[i] = RESTART
    return cause


def test_hand_made_lock_counts():
    # channel 0: continuous; 1: count back to 0; 2: gap bridged by the count; 3: gap, count jumps;
    # 4: count decreases without reaching 0; 5: gap then 0
    ch = [0] * 4 + [1] * 4 + [2] * 3 + [3] * 3 + [4] * 3 + [5] * 2
    st = [0, 1, 2, 3] + [0, 1, 2, 3] + [0, 1, 4] + [0, 1, 4] + [0, 1, 2] + [0, 3]
    lk = [5, 6, 7, 8] + [5, 6, 0, 1] + [5, 6, 9] + [5, 6, 12] + [5, 6, 2] + [5, 0]
    got = lock_segments(np.array(ch), np.array(st), lock=np.array(lk))
    np.testing.assert_array_equal(got.cause, [1, 0, 0, 0, 1, 0, 2, 0, 1, 0, 0, 1, 0, 3, 1, 0, 2, 1, 3])
    assert got.cause.dtype == np.int8
    assert got.first.tolist() == [0, 4, 6, 8, 11, 13, 14, 16, 17, 18]
    assert got.last.tolist() == [3, 5, 7, 10, 12, 13, 15, 16, 17, 18]
    assert got.n_rows.tolist() == [4, 2, 2, 3, 2, 1, 2, 1, 1, 1]
    np.testing.assert_array_equal(got.segment, np.repeat(np.arange(10), got.n_rows)[np.argsort(np.argsort(got.segment, kind="stable"), kind="stable")])


def test_random_rows_in_any_order_match_the_reference():
    rng = np.random.default_rng(11)
    for trial in range(40):
        n = int(rng.integers(1, 120))
        ch = rng.integers(0, 5, n)
        st = rng.permutation(400)[:n] % 60                  # repeats across channels, gaps
        lk = rng.integers(0, 8, n)
        slip = rng.random(n) < 0.1
        reset = rng.random(n) < 0.05
        kw = [dict(lock=lk), dict(slip=slip, max_step=2.0), dict(lock=lk, slip=slip, reset=reset),
              dict(lock=lk * 1000.0, lock_time=LockTime(1000.0, 5000.0, 500.0), max_step=math.inf)][trial % 4]
        # unique (channel, step): a channel has one row per step
        _, keep = np.unique(np.c_[ch, st], axis=0, return_index=True)
        ch, st = ch[keep], st[keep]
        kw = {k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in kw.items()}
        perm = rng.permutation(ch.size)
        got = lock_segments(ch[perm], st[perm], **{k: (v[perm] if isinstance(v, np.ndarray) else v) for k, v in kw.items()})
        want = _reference(ch[perm].tolist(), st[perm].tolist(),
                          **{k: (v[perm].tolist() if isinstance(v, np.ndarray) else v) for k, v in kw.items()})
        np.testing.assert_array_equal(got.cause, want)
        # segments: numbered by (channel, first step); each row's segment holds its channel and step range
        assert np.all(np.diff(got.channel) >= 0)
        for s in range(got.first.size):
            rows = np.flatnonzero(got.segment == s)
            assert got.cause[got.first[s]] > 0 and np.all(got.cause[rows[rows != got.first[s]]] == 0)
            assert set(ch[perm][rows]) == {got.channel[s]}
            assert st[perm][got.first[s]] == st[perm][rows].min() and st[perm][got.last[s]] == st[perm][rows].max()


def test_empty_and_single_row():
    e = lock_segments(np.zeros(0, int), np.zeros(0, int), lock=np.zeros(0, int))
    assert e.cause.size == e.first.size == 0
    one = lock_segments(np.array([3]), np.array([7.5]), slip=np.array([True]))
    assert one.cause.tolist() == [FIRST] and one.channel.tolist() == [3]


def test_ubx_lock_time_restart_and_cap():
    # lock time grows 1 s per 1 s epoch; restart at row 3; at the cap it only has to stay; a restart
    # during a gap; a gap with the lock time grown by the gap is no restart
    lock = [5000, 6000, 7000, 200, 1200, 64500, 64500, 64500, 3000, 9000]
    t = [0, 1, 2, 3, 4, 5, 6, 7, 12, 18]
    got = ubx_restarts(["G05"] * 10, np.array(t, float), np.array(lock, float), 1.0, 64500.0)
    np.testing.assert_array_equal(got, [0, 0, 0, 1, 0, 0, 0, 0, 1, 0])
