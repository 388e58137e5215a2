"""Decision 0155: `hypot_le` / `hypot_gt` give the truth value of `math.hypot(dx, dy) <= r` / `> r` exactly, and the
kernels that use them (centroids, end_walks, junction_verdicts) are unchanged."""

import math

import numpy as np
from numba import njit

from reconstruction._extract_kernels import hypot_gt, hypot_le


@njit
def _both(dx, dy, r):
    n = len(dx)
    le = np.empty(n, np.bool_)
    gt = np.empty(n, np.bool_)
    for i in range(n):
        le[i] = hypot_le(dx[i], dy[i], r[i])
        gt[i] = hypot_gt(dx[i], dy[i], r[i])
    return le, gt


@njit
def _reference(dx, dy, r):
    n = len(dx)
    le = np.empty(n, np.bool_)
    gt = np.empty(n, np.bool_)
    for i in range(n):
        h = math.hypot(dx[i], dy[i])
        le[i] = h <= r[i]
        gt[i] = h > r[i]
    return le, gt


def _cases():
    rng = np.random.default_rng(155)
    n = 200_000
    dx = rng.normal(0, 5, n)
    dy = rng.normal(0, 5, n)
    h = np.hypot(dx, dy)
    # radii at the distance itself and a few ulps either side (where the sum of squares alone could decide wrongly),
    # plus random radii
    r = np.concatenate([h, np.nextafter(h, np.inf), np.nextafter(h, -np.inf), h * (1 + 1e-12), h * (1 - 1e-12),
                        h * (1 + 2e-9), h * (1 - 2e-9), rng.uniform(0, 15, n)])
    dx = np.tile(dx, 8)
    dy = np.tile(dy, 8)
    # special values: NaN, inf, zero, negative and tiny / huge radii (outside the short cut's range)
    sp = [(np.nan, 1.0, 2.0), (1.0, np.nan, 2.0), (1.0, 1.0, np.nan), (np.inf, 0.0, 2.0), (1.0, 0.0, np.inf),
          (np.inf, 0.0, np.inf), (0.0, 0.0, 0.0), (1e-300, 0.0, 0.0), (1e-300, 0.0, 1e-300), (3.0, 4.0, 5.0),
          (3.0, 4.0, -5.0), (1e200, 1e200, 1.5e200), (1e-200, 1e-200, 1.5e-200), (1.0, 1.0, -0.0), (0.0, 0.0, -1.0)]
    dx = np.concatenate([dx, [a for a, _, _ in sp]])
    dy = np.concatenate([dy, [b for _, b, _ in sp]])
    r = np.concatenate([r, [c for _, _, c in sp]])
    return dx, dy, r


def test_hypot_le_gt_equal_the_hypot_comparisons():
    dx, dy, r = _cases()
    le, gt = _both(dx, dy, r)
    le_ref, gt_ref = _reference(dx, dy, r)
    assert np.array_equal(le, le_ref)
    assert np.array_equal(gt, gt_ref)
    # the band cases were exercised: both outcomes occur where r equals the distance to within a few ulps
    assert le_ref.any() and (~le_ref).any() and gt_ref.any()


def test_hypot_short_cut_is_taken_and_matters():
    """A comparison by the sum of squares without the band would be wrong somewhere in these cases (so the test can
    fail if the band were dropped), and the band is narrow enough that hypot is rarely evaluated."""
    dx, dy, r = _cases()
    le_ref, _ = _reference(dx, dy, r)
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        d2, r2 = dx * dx + dy * dy, r * r
    naive = d2 <= r2
    ok = np.isfinite(r) & (r > 0)
    assert (naive[ok] != le_ref[ok]).any()
    band = ok & (d2 >= r2 * (1 - 1e-9)) & (d2 <= r2 * (1 + 1e-9))
    assert band.mean() < 0.7  # the random radii (1/8 of the cases) decide outside the band


@njit
def _centroids_reference(grid, xu, xv, xs, sx, sy, cs, pad, rmax):
    """`_extract_kernels.centroids` before decision 0155 (math.hypot(…) > rmax)."""
    GH, GW = grid.shape
    n = len(sx)
    wsum = np.zeros(n)
    su = np.zeros(n)
    sv = np.zeros(n)
    for i in range(len(xs)):
        qx = np.float64(xu[i])
        qy = np.float64(xv[i])
        c = min(max(int(qx / cs) + pad, 0), GW - 1)
        r = min(max(int(qy / cs) + pad, 0), GH - 1)
        k = grid[r, c]
        if k < 0 or math.hypot(qx - sx[k], qy - sy[k]) > rmax:
            continue
        w = np.float64(xs[i])
        wsum[k] += w
        su[k] += w * qx
        sv[k] += w * qy
    out = np.empty((n, 2))
    for k in range(n):
        d = max(wsum[k], 1e-12)
        out[k, 0] = su[k] / d
        out[k, 1] = sv[k] / d
    return out


def test_centroids_equal_the_hypot_version():
    """Crossing pixels around centres whose radius is the exact distance of some pixels (3-4-5 offsets): the
    centroids equal those of the former kernel bit for bit."""
    from reconstruction._extract_kernels import centroids, stamp

    rng = np.random.default_rng(7)
    pad, cs = 16, 2.0
    H, W = 120, 160
    sx = rng.uniform(10, W - 10, 40).round()
    sy = rng.uniform(10, H - 10, 40).round()
    grid = np.empty((int(H / cs) + 2 + 2 * pad, int(W / cs) + 2 + 2 * pad), np.int32)
    stamp(sx, sy, 8.0, cs, grid, pad)
    xu = rng.integers(0, W, 5000).astype(np.int64)
    xv = rng.integers(0, H, 5000).astype(np.int64)
    xs = rng.uniform(0.1, 3.0, 5000).astype(np.float32)
    for rmax in (5.0, 3.0, math.sqrt(8.0), 4.5):
        a = centroids(grid, xu, xv, xs, sx, sy, cs, pad, rmax)
        b = _centroids_reference(grid, xu, xv, xs, sx, sy, cs, pad, rmax)
        assert np.array_equal(a, b)
