"""Crossing candidates (decision 0129): the weaker curvature against the noise of one eigenvalue, and two maxima
of one crossing merged.

The camera sees the projector image itself (analytic lines and junctions, as in test_recon_compressed_crossings.py):
every true crossing is known exactly. A dim, compressed grid (one family's lines 4–5 px apart, as on the obliquely
seen faces of unseen seeds 128, 130, 146) has crossings whose weaker curvature −λ2 lies between 3 and 5 Laplacian
noise deviations: with the Laplacian's threshold they give no crossing pixel at all."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam
from reconstruction import extraction
from reconstruction.crossing_candidates import merge_within, remap_grid
from reconstruction.extraction import ExtractOptions, extract_grid
from reconstruction.patterns import GridPattern
from reconstruction.rigmodel import rig_model

_OFF = ExtractOptions(crossing_eigen_noise=False, merge_close_candidates=False)  # before decision 0129
_ON = ExtractOptions()


def _rig(alpha1_deg: float, alpha2_deg: float, pitch_px: float, *, line_width_px: float = 1.5):
    K = np.array([[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]])
    dev = Intrinsics(640, 480, K)
    procam = ProCam(dev, dev, np.eye(3), np.array([1.0, 0.5, 0.0]))
    pattern = GridPattern(alpha1_deg=alpha1_deg, alpha2_deg=alpha2_deg, pitch_px=pitch_px, lines=41,
                          line_width_px=line_width_px, centre_px=(320.3, 240.7))
    return pattern, rig_model(procam, pattern, (900.0, 1100.0))


def _image(rendered: np.ndarray, seed: int, *, noise: float, amplitude: float) -> np.ndarray:
    img = rendered.astype(np.float32) / 255 * amplitude + 10
    img += np.random.default_rng(seed).normal(0, noise, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def _truth(pattern, *, inside: bool = True) -> np.ndarray:
    """The pattern's junctions in the camera (= projector) image; inside: only those 15 px or more from the border."""
    idx = pattern.indices
    ii, jj = np.meshgrid(idx, idx, indexing="ij")
    q = pattern.junction_uv(ii.ravel(), jj.ravel())
    return q[(q[:, 0] > 15) & (q[:, 0] < 625) & (q[:, 1] > 15) & (q[:, 1] < 465)] if inside else q


def _dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For each point of a (N, 2): the distance (px) to the nearest point of b (M, 2)."""
    if len(a) == 0 or len(b) == 0:
        return np.full(len(a), np.inf)
    return np.hypot(*(a[:, None, :] - b[None]).transpose(2, 0, 1)).min(axis=1)


@pytest.mark.parametrize("sigma", [1.0, 1.6, 2.4])
def test_second_derivative_noise_gain_is_that_of_white_noise_smoothed(sigma):
    """The gain against a Monte-Carlo estimate: the std of the [1, −2, 1] response of smoothed white noise, in x
    and in y (isotropic), and about 0.6 of the Laplacian's gain (the figure the decision's threshold rests on)."""
    noise = np.random.default_rng(3).normal(0, 1, (600, 600)).astype(np.float32)
    G = extraction._smooth(noise, sigma, 1)[20:-20, 20:-20]
    gxx = G[:, 2:] - 2 * G[:, 1:-1] + G[:, :-2]
    gyy = G[2:] - 2 * G[1:-1] + G[:-2]
    gain = extraction._second_derivative_noise_gain(sigma, 1)
    assert abs(gxx.std() / gain - 1) < 0.03 and abs(gyy.std() / gain - 1) < 0.03, (gxx.std(), gyy.std(), gain)
    assert 0.55 < gain / extraction._laplacian_noise_gain(sigma, 1) < 0.65


# (alpha1, alpha2, pitch, noise, amplitude): compressed grids (crossings 4.3 / 4.6 px apart along the sparse
# family) at a contrast where many crossings' −λ2 is under the Laplacian's threshold
DIM = [(5.0, 82.0, 30.0, 3.0, 80.0), (20.0, 100.0, 26.0, 4.0, 100.0)]


@pytest.mark.parametrize("alpha1, alpha2, pitch, noise, amplitude", DIM)
def test_dim_compressed_crossings_are_found_on_their_junctions(alpha1, alpha2, pitch, noise, amplitude):
    pattern, model = _rig(alpha1, alpha2, pitch)
    assert model.junction_step_cam_px < 5.0
    img = _image(pattern.render(640, 480), 1, noise=noise, amplitude=amplitude)
    q_true = _truth(pattern)
    off = extract_grid(img, model, options=_OFF)
    on = extract_grid(img, model, options=_ON)
    r_off = float((_dist(q_true, off.q_junction) <= 1.0).mean())
    r_on = float((_dist(q_true, on.q_junction) <= 1.0).mean())
    # measured: 57 -> 69 % and 77 -> 85 % of the analytic junctions
    assert r_on >= r_off + 0.06, (r_off, r_on)
    # every junction kept is on a true crossing (measured: within 0.17 and 0.12 px)
    assert _dist(on.q_junction, _truth(pattern, inside=False)).max() < 0.4
    assert len(on.edges) > len(off.edges)


def _one_family(pattern, family: int) -> np.ndarray:
    """(480, 640) float image of one family's lines only (a box profile of the pattern's line width, anti-aliased
    over one pixel), 0 to 1."""
    u = np.arange(640)[None, :] - pattern.centre_px[0]
    v = np.arange(480)[:, None] - pattern.centre_px[1]
    n = pattern.n1 if family == 1 else pattern.n2
    c = (v - n * u) / pattern.pitch_px
    d = np.abs(c - np.rint(c)) * pattern.pitch_px / np.sqrt(1 + n * n)  # distance to the nearest line, px
    return np.clip(0.5 * pattern.line_width_px - d + 0.5, 0, 1)


@pytest.mark.parametrize("family", [1, 2])
def test_no_crossing_where_lines_do_not_cross(family):
    """One family only, noisy: the sparse family's lines 24 px apart, or the compressed family's 4.5 px apart.
    The lower threshold for −λ2 must not turn noise on a line into crossings: no junction."""
    pattern, model = _rig(20.0, 100.0, 26.0)
    for noise in (2.0, 4.0):
        img = _image(255 * _one_family(pattern, family), 5, noise=noise, amplitude=100.0)
        obs = extract_grid(img, model, options=_ON)
        assert obs.stats["samples"] > 3000
        assert len(obs.q_junction) == 0, obs.q_junction


def test_merge_within_joins_close_candidates_at_their_weighted_mean():
    x = np.array([10.0, 11.0, 30.0, 30.0, 31.5, 50.0])
    y = np.array([10.0, 10.0, 30.0, 31.2, 31.2, 50.0])
    score = np.array([1.0, 3.0, 1.0, 2.0, 4.0, 5.0], np.float32)  # weakest first, as extraction orders them
    keep, remap, mx, my, n = merge_within(x, y, score, 2.0)
    # (0, 1) merge into 1; 2–3 and 3–4 are within 2 px, 2–4 is not: one group, transitively, into 4
    assert keep.tolist() == [False, True, False, False, True, True]
    assert n == 3
    assert remap.tolist() == [0, 0, 1, 1, 1, 2]
    assert np.allclose([mx[0], my[0]], [(10 + 33) / 4, 10.0])
    assert np.allclose([mx[1], my[1]], [(30 + 60 + 126) / 7, (30 + 62.4 + 124.8) / 7])
    assert (mx[2], my[2]) == (50.0, 50.0)
    grid = np.array([[-1, 0, 1], [2, 3, 4], [5, -1, -1]], np.int32)
    remap_grid(grid, remap)
    assert grid.tolist() == [[-1, 0, 0], [1, 1, 1], [2, -1, -1]]
    keep, remap, mx, my, n = merge_within(x, y, score, 0.5)  # nothing that close: unchanged
    assert keep.all() and n == 0 and (mx == x).all() and (my == y).all()
