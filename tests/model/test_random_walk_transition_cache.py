"""RandomWalk / Static keep the last spacing's (A, B, Q): the same values as formed afresh, read-only."""

import numpy as np
import pytest

from cdgps_cli.model.dynamics_models import RandomWalk, Static, WithConstants


@pytest.mark.parametrize("dyn", [RandomWalk(3, [0.1, 0.2, 0.3]), RandomWalk(2, 0.5), Static(4)])
def test_transition_kept_for_the_same_spacing(dyn):
    for dt in (1.0, 1.0, 0.5, 1.0, 1.0):
        A, B, Q = dyn.transition(dt)
        assert np.array_equal(A, np.eye(dyn.n)) and B.shape == (dyn.n, 0)
        assert np.array_equal(Q, np.eye(dyn.n) * np.asarray(dyn.sigma) ** 2 * dt)
        assert not (A.flags.writeable or Q.flags.writeable)
    assert dyn.transition(1.0)[2] is dyn.transition(1.0)[2]
    with pytest.raises(ValueError):
        dyn.transition(0.0)


def test_with_constants_copies_the_kept_arrays():
    dyn = WithConstants(RandomWalk(3, 0.1), 2)
    A, _, Q = dyn.transition(2.0)
    A[0, 0] = 7.0                                    # its own arrays: the kept ones are untouched
    assert np.array_equal(dyn.transition(2.0)[0], np.eye(5))
