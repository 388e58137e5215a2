"""A crossing-score maximum that is no crossing suppresses nothing (decision 0152, reconstruction.unsuppressed_seeds):
the kernels on constructed crossing pixels (a line's own blob hides a weaker X; a blob with both families, or with no
line through it, still suppresses), the incremental stamp and look-up against the full ones, and on
paper-intermediate (rendered as the bench renders it) the X at (658.5, 527.4) that decision 0148 found without a
candidate: with the option its points appear, each on its true line (simulator truth) and accurate."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from benchmarks._common import bench_scenes, relative_errors, render_scene, sample_bilinear
from benchmarks.grazing_faces import true_lines
from reconstruction import _extract_kernels as K
from reconstruction import unsuppressed_seeds as U
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.rigmodel import UNLABELLED

CELL = 4.0
GH, GW = 40, 40


def _blobs(centres_scores):
    """Crossing pixels (row-major, as the ridge pass emits them) of round blobs: (x, y, peak score, radius)."""
    pix = {}
    for cx, cy, peak, rad in centres_scores:
        for y in range(int(cy - rad), int(cy + rad) + 1):
            for x in range(int(cx - rad), int(cx + rad) + 1):
                d = np.hypot(x - cx, y - cy)
                if d <= rad:
                    pix[(y, x)] = max(pix.get((y, x), 0.0), peak * (1 - 0.5 * d / rad))
    keys = sorted(pix)
    xv = np.array([k[0] for k in keys], np.int64)
    xu = np.array([k[1] for k in keys], np.int64)
    xs = np.array([pix[k] for k in keys], np.float32)
    return xu, xv, xs


def _run(ring_of_blob):
    # a strong blob at (60, 60) and a weaker one at (67, 61), 7 px apart: in neighbouring cells of 4 px
    xu, xv, xs = _blobs([(60.0, 60.0, 10.0, 3.0), (67.0, 61.0, 4.0, 3.0)])
    seed, m = K.crossing_seeds_max(xu, xv, xs, CELL, GH, GW)
    strong = np.nonzero(seed)[0]
    assert len(strong) == 1 and (xu[strong[0]], xv[strong[0]]) == (60, 60)  # the weaker X has no seed
    sx, sy = np.array([60.0]), np.array([60.0])
    ids, masked = U.unsuppressed_seeds(xu, xv, xs, seed, CELL, m, sx, sy, np.array([ring_of_blob], np.int64), 3.5, 3.0)
    return xu, xv, ids, masked


def test_a_lines_own_blob_hides_no_crossing():
    xu, xv, ids, masked = _run([9, 0])
    assert [(int(xu[i]), int(xv[i])) for i in ids] == [(67, 61)]
    assert masked.sum() > 0 and not masked[ids].any()


@pytest.mark.parametrize("ring", [[3, 4], [0, 0], [1, 1], [2, 0]])
def test_a_crossing_or_no_line_through_still_suppresses(ring):
    # [3, 4]: a crossing; [0, 0], [1, 1]: no line through the blob (a line's end, a spot at a depth edge);
    # [2, 0]: fewer samples of the one family than the ring holds of a line through it (3 here)
    _, _, ids, masked = _run(ring)
    assert len(ids) == 0 and masked.sum() == 0


def test_stamp_more_equals_one_stamp_and_relook_equals_look_dist():
    rng = np.random.default_rng(3)
    cs, pad, radius, r0 = 2.0, 16, 7.5, np.float32(2.5)
    H, W = 200, 260
    cen = np.column_stack([rng.uniform(5, W - 5, 60), rng.uniform(5, H - 5, 60)])
    first = 45
    shape = (int(H / cs) + 2 + 2 * pad, int(W / cs) + 2 + 2 * pad)
    g_all = np.empty(shape, np.int32)
    K.stamp(cen[:, 0].copy(), cen[:, 1].copy(), radius, cs, g_all, pad)
    g_inc = np.empty(shape, np.int32)
    K.stamp(cen[:first, 0].copy(), cen[:first, 1].copy(), radius, cs, g_inc, pad)
    # samples in row-major order
    n = 4000
    qy = np.sort(rng.uniform(0, H - 1, n)).astype(np.float32)
    qx = rng.uniform(0, W - 1, n).astype(np.float32)
    v = np.floor(qy).astype(np.int64)
    fam = rng.integers(1, 3, n).astype(np.int8)
    row_start = K.row_starts(v, H)
    c32 = cen.astype(np.float32)
    near, dist = K.look_dist(g_inc, qx, qy, np.float32(1 / cs), pad, c32[:first, 0].copy(), c32[:first, 1].copy(), np.float32(radius - 1.5))
    ring = np.concatenate([K.ring_counts(near, dist, fam, r0, first), np.zeros((len(cen) - first, 2), np.int64)])
    U.stamp_more(cen[:, 0].copy(), cen[:, 1].copy(), first, radius, cs, g_inc, pad)
    assert np.array_equal(g_inc, g_all)
    U.relook(g_inc, qx, qy, np.float32(1 / cs), pad, c32[:, 0].copy(), c32[:, 1].copy(), first, np.float32(radius - 1.5),
             radius + 2 * cs, r0, fam, near, dist, ring, row_start, 0, H)
    near2, dist2 = K.look_dist(g_all, qx, qy, np.float32(1 / cs), pad, c32[:, 0].copy(), c32[:, 1].copy(), np.float32(radius - 1.5))
    assert np.array_equal(near, near2) and np.array_equal(dist, dist2)
    assert np.array_equal(ring, K.ring_counts(near2, dist2, fam, r0, len(cen)))


@pytest.fixture(scope="module")
def intermediate():
    sc = bench_scenes(["paper-intermediate"], [], noise_grey=2.0)[0]
    img, truth = render_scene(sc.procam, sc.scene, sc.pattern, noise_grey=sc.noise_grey)
    return sc, img, truth


def test_the_hidden_x_on_paper_intermediate(intermediate):
    sc, img, truth = intermediate
    o = ReconstructOptions(depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1])
    res = {on: reconstruct(img, sc.procam, sc.pattern, options=replace(o, extract=replace(o.extract, unsuppressed_seeds=on)))
           for on in (False, True)}
    X = np.array([658.5, 527.4])
    near = {on: np.hypot(*(r.q_cam.astype(np.float64) - X).T) < 40 for on, r in res.items()}
    assert near[False].sum() == 0 and near[True].sum() >= 30
    on = res[True]
    q = on.q_cam[near[True]].astype(np.float64)
    fam = on.family[near[True]]
    tl = true_lines(sample_bilinear(truth.q_proj, q), sc.pattern)
    lab = on.label[near[True]]
    for f in (1, 2):  # every line sample there carries its true line
        sel = fam == f
        got = lab[sel][:, f - 1]
        assert np.all(got != UNLABELLED) and np.array_equal(got, tl[f][2][sel])
    rel = relative_errors(on.points_proj[near[True]], on.q_cam[near[True]], truth) * 100
    assert rel.max() < 0.5
