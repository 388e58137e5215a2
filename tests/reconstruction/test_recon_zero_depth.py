"""A point in the projector's plane (z = 0) in the compiled kernels: no pixel, no line, no exception.

The placement sweep stopped on a frame where a surface-label prediction (decision 0093) put a point exactly at
z = 0: `project_nearest_line` divided by z before testing it, and numba's default error model raises
ZeroDivisionError where NumPy gives inf. Kernels now use NumPy's error model (`reconstruction._jit.njit`)."""

from __future__ import annotations

import numpy as np

from reconstruction._label_kernels import project_nearest_line


def test_project_nearest_line_skips_points_at_or_behind_the_projector():
    K = np.array([[1000.0, 0.0, 512.0], [0.0, 1000.0, 384.0], [0.0, 0.0, 1.0]])
    dist = np.zeros(5)
    offs = np.array([np.arange(-5, 6) * 20.0, np.arange(-5, 6) * 20.0])
    n12 = np.array([0.5, -2.0])
    hyp = np.hypot(1.0, n12)
    indices = np.arange(-5, 6)
    p = np.array([[0.0, 0.0, 1000.0], [10.0, 5.0, 0.0], [0.0, 0.0, 0.0], [3.0, 1.0, -200.0], [1.0, 1.0, 500.0]])
    fam = np.array([1, 1, 2, 2, 2], np.int64)
    for distorted in (False, True):
        idx, d = project_nearest_line(p, fam, K, dist, distorted, 512.0, 384.0, n12, offs, hyp, indices)
        # the point on the axis lies on line 0 of family 1 (s = 0), the fifth at pixel (514, 386): s = 2 + 2·2 = 6
        assert idx[0] == 0 and d[0] == 0.0
        assert idx[4] == 0 and abs(d[4] - 6.0 / hyp[1]) < 1e-9
        # z = 0 and z < 0: no pixel, no line
        assert list(idx[1:4]) == [0, 0, 0]
        assert np.all(np.isinf(d[1:4]))


def test_kernels_divide_as_numpy_does():
    """The shared decorator's error model: a zero divisor gives inf / NaN, not an exception."""
    from reconstruction._jit import njit

    @njit(cache=False)
    def ratio(a, b):
        return a / b

    assert ratio(1.0, 0.0) == np.inf
    assert np.isnan(ratio(0.0, 0.0))
