"""Round four of the extraction's speed (decision 0079): each new kernel against the NumPy/OpenCV code it
replaced, on seeded images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from reconstruction import _extract_kernels as k
from reconstruction import extraction


def _noise_reference(img: np.ndarray) -> float:
    """`image_noise_grey` as it was before 0079: OpenCV's filter2D on the sampled rows, NumPy's partition."""
    H, W = img.shape
    rows = max(3, min(H, 65536 // max(W, 1)))
    if rows < H:
        starts = np.linspace(0, H - 4, max(1, rows // 4)).astype(np.intp)
        img = np.concatenate([img[s : s + 4] for s in starts])
    kern = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(img.astype(np.float32, copy=False), cv2.CV_32F, kern, borderType=cv2.BORDER_REFLECT)
    r = r.reshape(-1, 4, W)[:, 1:3, 1:-1] if rows < H else r[1:-1, 1:-1]
    a = np.abs(r).ravel()
    return float(np.partition(a, len(a) // 2)[len(a) // 2]) / (0.6745 * 6.0)


@pytest.mark.parametrize("shape", [(1024, 1280), (570, 758), (40, 50), (3, 9)])
@pytest.mark.parametrize("sigma_grey", [0.0, 2.0, 40.0])
def test_noise_kernel_gives_the_filter2d_median(shape, sigma_grey):
    rng = np.random.default_rng(7)
    H, W = shape
    vv, uu = np.mgrid[0:H, 0:W]
    base = 100 + 60 * np.sin(uu / 9.0) * (np.abs((vv % 23) - 11) < 3)  # lines and plateaus
    img = np.clip(base + rng.normal(0, sigma_grey, shape), 0, 255).astype(np.uint8)
    got = extraction.image_noise_grey(img)
    want = _noise_reference(img)
    assert got == want
    if sigma_grey == 40.0 and H > 100:
        assert 10.0 < got < 60.0  # a real estimate, not a constant (clipping lowers it)


def test_noise_kernel_saturated_extremes():
    # a one-pixel checkerboard gives the largest possible response everywhere (|r| = 8·255): the
    # histogram's last bin
    img = np.zeros((64, 64), np.uint8)
    img[::2, ::2] = 255
    img[1::2, 1::2] = 255
    assert extraction.image_noise_grey(img) == _noise_reference(img) == 2040 / (0.6745 * 6.0)
    assert k.noise_median_u8(img, np.zeros(0, np.intp), False) == 2040
