"""`pipeline._drop_rows` (decision 0151's dropped rows, compiled) against the NumPy version it replaced."""

from types import SimpleNamespace

import numpy as np
import pytest

from reconstruction import pipeline


def _reference(R, t, depth, bad, out_p, out_q, out_f, out_l, out_r, n_keep, n_keep_j):
    """The NumPy version of `_drop_imprecise`'s drop (main before the kernels), kept as the test's reference."""
    H, W = depth.shape
    q = out_q[:n_keep].astype(np.float64)
    pix = np.clip(np.rint(q[:, 1]), 0, H - 1).astype(np.intp) * W + np.clip(np.rint(q[:, 0]), 0, W - 1).astype(np.intp)
    drop = np.zeros(n_keep, np.bool_)
    drop[n_keep_j:] = bad
    flat = depth.reshape(-1)
    hit = np.zeros(H * W, np.bool_)
    hit[pix[drop]] = True
    flat[pix[drop]] = np.nan
    re = np.flatnonzero(~drop & hit[pix])
    if len(re):
        flat[pix[re]] = (out_p[re].astype(np.float64) - t) @ R[:, 2]
    keep = np.flatnonzero(~drop)
    for a in (out_p, out_q, out_f, out_l, out_r):
        a[: len(keep)] = a[keep]
    return len(keep)


def _frame(rng, n_max, n_keep, H, W):
    out_p = rng.normal(0, 500, (n_max, 3)).astype(np.float32)
    # positions on few pixels (many rows share one), some outside the image (clipped), some exactly on .5
    q = np.column_stack([rng.integers(-3, W + 3, n_max), rng.integers(-3, H + 3, n_max)]).astype(np.float64)
    q += rng.choice([0.0, 0.5, 0.25, -0.5, 0.49], size=(n_max, 2))
    out_q = q.astype(np.float32)
    out_f = rng.integers(0, 3, n_max).astype(np.int8)
    out_l = rng.integers(-5, 5, (n_max, 2)).astype(np.int32)
    out_r = rng.random(n_max).astype(np.float32)
    depth = rng.random((H, W)).astype(np.float32)
    return [depth, out_p, out_q, out_f, out_l, out_r]


@pytest.mark.parametrize("seed", range(12))
def test_drop_rows_equals_the_numpy_version(seed):
    rng = np.random.default_rng(seed)
    H, W = int(rng.integers(3, 12)), int(rng.integers(3, 12))
    n_max = int(rng.integers(5, 300))
    n_keep = int(rng.integers(1, n_max + 1))
    n_keep_j = int(rng.integers(0, n_keep + 1))
    bad = rng.random(n_keep - n_keep_j) < rng.choice([0.02, 0.3, 0.9, 1.0])
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    t = rng.normal(0, 100, 3)
    a = _frame(rng, n_max, n_keep, H, W)
    b = [x.copy() for x in a]
    n_ref = _reference(R, t, *a[:1], bad, *a[1:], n_keep, n_keep_j)
    model = SimpleNamespace(procam=SimpleNamespace(R_proj_cam=R, t_proj_cam=t))
    n = pipeline._drop_rows(model, b[0], bad, *b[1:], n_keep, n_keep_j)
    assert n == n_ref == n_keep - int(bad.sum())
    np.testing.assert_array_equal(b[0], a[0])  # depth map, NaN where cleared
    for x, y in zip(a[1:], b[1:]):
        np.testing.assert_array_equal(x[:n], y[:n])


def test_drop_rows_breaks_when_a_cleared_pixel_is_not_rewritten():
    """The test above can fail: a depth map that keeps the dropped point's value differs from the reference."""
    rng = np.random.default_rng(3)
    a = _frame(rng, 50, 50, 4, 4)
    bad = np.zeros(40, np.bool_)
    bad[5] = True
    b = [x.copy() for x in a]
    R, t = np.eye(3), np.zeros(3)
    _reference(R, t, a[0], bad, *a[1:], 50, 10)
    pipeline._k_compact_rows(bad, 50, 10, *b[1:])  # the rows alone, no depth pass
    assert not np.array_equal(a[0], b[0], equal_nan=True)
