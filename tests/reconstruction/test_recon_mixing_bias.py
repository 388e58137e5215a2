"""The mixing zone shaped by the crossing (decision 0073): the first-order pull of the other line and the
kernel that releases mixing-zone samples by it."""

import cv2
import numpy as np

from reconstruction import _label_kernels as _k
from reconstruction import _mixing_kernels as _mk


def _two_lines(theta_deg: float, s_px: float, step: float = 0.5):
    """Family 1 along the x axis through (0, 0) (the sample under test first), family 2 through
    (x_c, 0) at theta_deg to it, placed so that the sample at (0, 0) is s_px from family 2's line."""
    th = np.deg2rad(theta_deg)
    x_c = s_px / np.sin(th)
    t = np.arange(-6.0, 6.01, step)
    a = np.column_stack([t, np.zeros_like(t)])
    a = np.vstack([[0.0, 0.0], a[np.abs(t) > 1e-9]])
    b = np.column_stack([x_c + t * np.cos(th), t * np.sin(th)])
    q = np.vstack([a, b]) + 20.0
    fam = np.concatenate([np.ones(len(a), np.intp), np.full(len(b), 2, np.intp)])
    return np.ascontiguousarray(q), fam


def _release(q, fam, *, sigma_e, s_min, tol):
    valid, r, c, H, W, _n = _k.sample_cells(q, fam, 1.0, 2)
    rad = 3
    dr, dc = np.nonzero(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rad + 1, 2 * rad + 1)))
    dr = (dr - rad).astype(np.intp)
    dc = (dc - rad).astype(np.intp)
    near = _k.mixing_zone(r, c, fam, valid, int(H), int(W), dr, dc)
    before = near.copy()
    _mk.mixing_bias_release(q, r, c, fam, valid, near, int(H), int(W), dr, dc, sigma_e, s_min, tol, 0.5, 3)
    return before, near


def test_release_follows_the_first_order_pull():
    sigma_e = 1.8
    for theta, s, tol in ((90.0, 2.0, 0.02), (60.0, 2.0, 0.5), (60.0, 2.0, 0.3), (75.0, 2.5, 0.25), (75.0, 2.5, 0.15)):
        q, fam = _two_lines(theta, s)
        before, after = _release(q, fam, sigma_e=sigma_e, s_min=1.0, tol=tol)
        assert before[0], (theta, s)
        pull = abs(np.cos(np.deg2rad(theta))) * s * np.exp(-s * s / (2 * sigma_e**2))
        assert (not after[0]) == (pull <= tol), (theta, s, tol, pull)


def test_samples_closer_than_s_min_stay_in_the_zone():
    q, fam = _two_lines(90.0, 0.8)
    before, after = _release(q, fam, sigma_e=1.8, s_min=1.45, tol=10.0)
    assert before[0] and after[0]
    before, after = _release(q, fam, sigma_e=1.8, s_min=0.5, tol=10.0)
    assert before[0] and not after[0]
