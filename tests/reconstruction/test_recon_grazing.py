"""The measuring tools of decision 0100 (benchmarks/grazing_faces.py): where extraction loses the lines of faces
lit at grazing incidence. The replica of extraction's ridge tests must reproduce extraction's samples exactly
(else its "first failing test" table would describe another detector); the camera line width from the
truth's projector map against an analytic affine map; the two mechanisms the record names (a dim line next
to a bright one fails the relative-strength test, a line much wider than the smoothing has no ridge at its
centre until the scale grows) on synthetic bars; and the merge of a coarse pass into the fine observation."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.grazing_faces import TESTS, camera_line_width, first_failing_test, merge_coarse, ridge_tests, true_lines
from reconstruction.extraction import (ExtractOptions, GridObservation, _laplacian_noise_gain, _smooth, extract_grid,
                                       image_noise_grey, sigma_for)
from reconstruction.patterns import GridPattern
from reconstruction.rigmodel import rig_model


def test_ridge_tests_reproduce_extractions_samples(small_scene):
    s = small_scene
    model = rig_model(s.procam, s.pattern, s.depth_range_mm)
    eo = ExtractOptions()
    obs = extract_grid(s.image, model, options=eo)
    sigma = sigma_for(model, eo)
    assert obs.stats["scale"] == 1
    noise = max(image_noise_grey(s.image), 0.5) * _laplacian_noise_gain(round(sigma, 3), 1)
    t = ridge_tests(_smooth(s.image, sigma, 1), thr=eo.threshold_sigma * noise, anisotropy=eo.anisotropy,
                    min_relative_strength=eo.min_relative_strength, dir_cam=model.dir_cam, cell_px=model.cell_px,
                    family_margin=eo.family_margin)  # fmt: skip
    ok = np.ones(s.image.shape[:2], bool)
    for name in TESTS:
        if name != "family":
            ok &= t[name]
    v, u = np.nonzero(ok)
    assert len(obs.q) > 2000
    assert len(u) == len(obs.q)
    # row-major order in both; the same sample positions and families
    np.testing.assert_allclose(np.c_[t["qx"][v, u], t["qy"][v, u]], obs.q, atol=1e-4)
    np.testing.assert_array_equal(t["fam"][v, u], obs.family)


def test_camera_line_width_of_an_affine_projector_map():
    pattern = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5), line_width_px=3.0)
    A = np.array([[1.7, 0.4], [-0.3, 0.6]])  # projector px per camera px
    v, u = np.mgrid[0:60, 0:80].astype(float)
    q_proj = np.stack([A[0, 0] * u + A[0, 1] * v + 300.0, A[1, 0] * u + A[1, 1] * v + 250.0], -1)
    for f, n in ((1, pattern.n1), (2, pattern.n2)):
        # s = (y − n x)/hypot(1, n): its gradient over camera pixels is Aᵀ(−n, 1)/hypot(1, n)
        g = A.T @ np.array([-n, 1.0]) / np.hypot(1, n)
        want = pattern.line_width_px / np.linalg.norm(g)
        np.testing.assert_allclose(camera_line_width(q_proj, pattern, f)[5:-5, 5:-5], want, rtol=1e-9)
    # the distance to the nearest line: zero on a line's centre
    tl = true_lines(np.array([[pattern.centre_px[0], pattern.centre_px[1] + 3 * pattern.pitch_px]]), pattern)
    assert tl[1][1][0] == pytest.approx(0.0, abs=1e-9) and tl[1][2][0] == 3


def _bars():
    """A bright 3-px bar (x = 30), a dim 3-px bar (x = 46, a tenth of it) and a dim 9-px bar (x = 66), vertical."""
    H, W = 64, 96
    x = np.arange(W)[None, :].repeat(H, 0).astype(float)

    def bar(x0, w, a):
        return a * np.clip(np.minimum(x - (x0 - w / 2) + 0.5, (x0 + w / 2) - x + 0.5), 0, 1)

    img = (10 + bar(30, 3, 200) + bar(46, 3, 20) + bar(66, 9, 30)).astype(np.float32)
    dir_cam = np.zeros((4, 4, 2, 2))
    dir_cam[..., 0, :] = (0.0, 1.0)  # i-lines vertical
    dir_cam[..., 1, :] = (1.0, 0.0)
    return img, dir_cam


def _first(img, dir_cam, sigma, min_rel, x0):
    t = ridge_tests(_smooth(img, sigma, 1), thr=1.0, anisotropy=0.5, min_relative_strength=min_rel, dir_cam=dir_cam,
                    cell_px=32.0, family_margin=0.15)  # fmt: skip
    v = np.arange(20, 44)
    return set(first_failing_test(t, np.full(len(v), x0), v, np.ones(len(v), int)).tolist())


def test_dim_line_fails_relative_strength_and_wide_line_has_no_fine_ridge():
    img, dir_cam = _bars()
    done = len(TESTS)
    # fine scale (σ = 0.4 × a 2.5-px line): the bright bar passes; the dim narrow bar is strong enough for the
    # noise threshold but under 15 % of the bright one within 3×3 cells of 16 px
    assert _first(img, dir_cam, 1.0, 0.15, 30) == {done}
    assert _first(img, dir_cam, 1.0, 0.15, 46) == {TESTS.index("relative strength")}
    assert _first(img, dir_cam, 1.0, 0.0, 46) == {done}
    # the 9-px bar's top is flat at σ = 1: no Laplacian response at its centre
    assert _first(img, dir_cam, 1.0, 0.0, 66) == {TESTS.index("Laplacian")}
    # at σ = 3 (≥ 9/(2√3)) it has a single ridge at its centre
    assert _first(img, dir_cam, 3.0, 0.0, 66) == {done}
    # and on the wrong family's direction grid it fails the family test
    assert _first(img, dir_cam[..., ::-1, :].copy(), 3.0, 0.0, 66) == {TESTS.index("family")}


def _obs(q, fam, seg_linked, n_seg):
    P = len(q)
    return GridObservation(
        q=np.asarray(q, float), family=np.asarray(fam, np.int8), segment=np.asarray(seg_linked, np.int64),
        junction=np.full(P, -1, np.int64), strength=np.ones(P), q_junction=np.zeros((0, 2)), junction_dir=np.zeros((0, 2, 2)),
        segment_family=np.ones(n_seg, np.int8), segment_ends=np.full((n_seg, 2), -1, np.int64), segment_rms=np.zeros(n_seg),
        segment_centre=np.zeros((n_seg, 2)), segment_dir=np.tile([0.0, 1.0], (n_seg, 1)), edges=np.zeros((0, 2), np.int64),
        edge_family=np.zeros(0, np.int8), edge_delta=np.zeros((0, 2), np.int64), edge_segment=np.zeros(0, np.int64),
        stats={"scale": 1}, segment_linked=np.asarray(seg_linked, np.int64))  # fmt: skip


def test_merge_coarse_adds_whole_segments_away_from_fine_samples():
    y = np.arange(10.0)
    fine = _obs(np.c_[np.full(10, 5.0), y], [1] * 10, [0] * 10, 1)
    # coarse: segment 0 on the fine line (x = 5.4), segment 1 far (x = 20), segment 2 far but 3 samples only,
    # segment 3 half near (x = 6, 6 samples) half far (x = 30, 4 samples): fewer than half far -> left out
    q2 = np.r_[np.c_[np.full(10, 5.4), y], np.c_[np.full(10, 20.0), y], np.c_[np.full(3, 40.0), y[:3]],
               np.c_[np.full(6, 6.0), y[:6]], np.c_[np.full(4, 30.0), y[:4]]]  # fmt: skip
    seg2 = np.r_[[0] * 10, [1] * 10, [2] * 3, [3] * 10]
    coarse = _obs(q2, [2] * len(q2), seg2, 4)
    merged, add = merge_coarse(fine, coarse, min_gap_px=1.5)
    np.testing.assert_array_equal(add, np.arange(10, 20))
    assert len(merged.q) == 20 and (merged.family[10:] == 2).all()
    np.testing.assert_array_equal(merged.segment_linked[10:], 1 + 1)  # coarse segment 1, after the fine one
    assert len(merged.segment_centre) == 5 and (merged.segment_ends[1:] == -1).all()
    assert (merged.junction[10:] == -1).all()
