"""Decision 0155: `smooth_ridges_u8` makes the Gaussian's column pass two output rows at a time (`_column_pair`, a
last odd row alone). Its working image and outputs must stay those of `gauss_u8` followed by `ridge_pass_into` (the
row-by-row reference kernels) for even and odd heights, several tap counts, and a last row pair that closes a block."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction import _extract_kernels as ek
from reconstruction import extraction


def _outputs(cap: int) -> tuple:
    i64, f32 = np.int64, np.float32
    return tuple(np.empty(cap, t) for t in (i64, i64, f32, f32, f32, f32, f32, i64, i64, f32))


def _image(seed: int, shape: tuple[int, int]) -> np.ndarray:
    rng = np.random.default_rng(seed)
    H, W = shape
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float32)
    img = 40 + 0.2 * uu + 60 * (np.abs(np.sin(0.37 * uu + 0.23 * vv)) > 0.85) + 60 * (np.abs(np.sin(0.29 * vv - 0.11 * uu)) > 0.85)
    img += rng.normal(0, 4.0, shape)
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("shape", [(97, 160), (96, 160), (33, 64), (8, 48), (7, 48), (2, 32), (1, 32), (151, 208)])
@pytest.mark.parametrize("sigma", [0.8, 1.45, 2.0])
def test_smooth_ridges_u8_equals_the_row_by_row_kernels(shape, sigma):
    img = _image(sum(shape), shape)
    taps = extraction._gauss_taps(sigma)
    if min(shape) <= len(taps) // 2:
        pytest.skip("the kernels need both sides longer than the radius (extraction._fused_smoothing)")
    thr_args = (np.float32(-0.5 * 4.0), np.float32(4.0), np.float32(-0.5), np.float32(-0.25))
    G_ref = np.empty(shape, np.float32)
    ek.gauss_u8(img, taps, G_ref)
    out_ref = _outputs(img.size)
    n, m, mx = ek.ridge_pass_into(G_ref, *thr_args, *out_ref, np.float32(3.0))
    G = np.full(shape, np.nan, np.float32)
    out = _outputs(img.size)
    assert ek.smooth_ridges_u8(img, taps, G, *thr_args, *out, np.float32(3.0)) == (n, m, mx)
    np.testing.assert_array_equal(G.view(np.uint32), G_ref.view(np.uint32))
    for a, b, cnt in zip(out, out_ref, (m,) * 7 + (mx,) * 3):
        np.testing.assert_array_equal(a[:cnt], b[:cnt])
    if shape[0] >= 33:
        assert n > ek._STEGER_BLOCK and m > 50  # several blocks: the block boundaries are exercised
        assert ek.smooth_ridges_u8(img, taps, G, *thr_args, *_outputs(m - 1), np.float32(3.0))[1] == -1


@pytest.mark.parametrize("shape", [(97, 160), (96, 160), (33, 64), (8, 48), (7, 48), (2, 32), (1, 32), (151, 208), (80, 96)])
@pytest.mark.parametrize("sigma", [0.8, 1.45, 2.0])
def test_smooth_ridges_ring_u8_equals_the_full_image_walk(shape, sigma):
    """The ring walk (no full working image, decision 0155) gives the outputs of `gauss_u8` + `ridge_pass_into`,
    also where sparse rows leave candidates pending across more rows than the ring holds (early blocks: the dark
    band below), and reports running out of room the same way."""
    img = _image(sum(shape) + 1, shape)
    if shape == (80, 96):
        img[20:60] = 0  # 40 dark rows with a few bright dots: few candidates per row, pending across the ring
        img[22::9, 5::23] = 200
    taps = extraction._gauss_taps(sigma)
    if min(shape) <= len(taps) // 2:
        pytest.skip("the kernels need both sides longer than the radius (extraction._fused_smoothing)")
    thr_args = (np.float32(-0.5 * 4.0), np.float32(4.0), np.float32(-0.5), np.float32(-0.25))
    G_ref = np.empty(shape, np.float32)
    ek.gauss_u8(img, taps, G_ref)
    out_ref = _outputs(img.size)
    n, m, mx = ek.ridge_pass_into(G_ref, *thr_args, *out_ref, np.float32(3.0))
    out = _outputs(img.size)
    assert ek.smooth_ridges_ring_u8(img, taps, *thr_args, *out, np.float32(3.0)) == (n, m, mx)
    for a, b, cnt in zip(out, out_ref, (m,) * 7 + (mx,) * 3):
        np.testing.assert_array_equal(a[:cnt], b[:cnt])
    if m > 1:
        assert ek.smooth_ridges_ring_u8(img, taps, *thr_args, *_outputs(m - 1), np.float32(3.0))[1] == -1


def test_extraction_uses_the_ring_walk_with_the_same_samples():
    """extract_grid's samples are the same with the ring walk and with the full-image walk (module switch)."""
    img = _image(5, (96, 160))
    thr_args = (np.float32(-0.5 * 4.0), np.float32(4.0), np.float32(-0.5), np.float32(-0.25), np.float32(3.0))
    taps = extraction._gauss_taps(1.45)
    res = {}
    for ring in (True, False):
        old = extraction._RING_WALK
        try:
            extraction._RING_WALK = ring
            got = extraction._ridges(np.empty((96, 160), np.float32), *thr_args, image=img, taps=taps)
            res[ring] = tuple(np.array(x) if isinstance(x, np.ndarray) else x for x in got)
        finally:
            extraction._RING_WALK = old
    for a, b in zip(res[True], res[False]):
        np.testing.assert_array_equal(a, b)
    assert len(res[True][1]) > 50
