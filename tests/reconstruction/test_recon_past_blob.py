"""Samples past a released blob are no line samples (decision 0153, `ExtractOptions.unsuppressed_past_blob`,
`reconstruction.unsuppressed_seeds.past_blobs`): on constructed samples, exactly the blob's line's samples within the
attachment reach on the side away from the new candidate are flagged (not the other family's, not the near side's,
not for a blob that is a crossing or lies too far); on unseen seed 142 (rendered as `benchmarks.unseen` renders it),
where two surfaces' lines are collinear across object 2's silhouette next to two new junctions, the option removes
every point more than 1 % off there (simulator truth) that the released blobs let the new junctions' labels reach,
and keeps the new junctions' points."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from benchmarks._common import relative_errors, render_scene
from reconstruction import unsuppressed_seeds as U
from reconstruction.pipeline import ReconstructOptions, reconstruct


def _samples():
    # a horizontal i-line (family 1) through y = 50 and a vertical j-line (family 2) through x = 53, row-major
    pts = [(float(x), 50.0, 1) for x in range(30, 71)] + [(53.0, float(y), 2) for y in range(30, 71) if y != 50]
    pts.sort(key=lambda p: (int(p[1]), p[0]))
    q = np.array([(p[0], p[1]) for p in pts], np.float32)
    fam = np.array([p[2] for p in pts], np.int64)
    H = 80
    row_start = np.searchsorted(q[:, 1].astype(np.int64), np.arange(H + 1)).astype(np.int64)
    return q, fam, row_start, H


def _run(ring_blob, new_xy, near_px=12.0, r_att=6.0):
    q, fam, row_start, H = _samples()
    cx = np.array([50.0, new_xy[0]])  # the blob, then the new candidate (first = 1)
    cy = np.array([50.0, new_xy[1]])
    drop = np.zeros(len(q), np.bool_)
    n = U.past_blobs(cx, cy, 1, np.array([ring_blob, [0, 0]], np.int64), 3.0, near_px, r_att, q[:, 0].copy(),
                     q[:, 1].copy(), fam, row_start, 0, H, drop)
    return q, fam, drop, n


def test_the_blobs_line_past_it_is_flagged():
    q, fam, drop, n = _run([9, 0], (42.0, 50.0))
    want = (fam == 1) & (q[:, 0] > 50) & (q[:, 0] <= 56)
    assert n == want.sum() == 6 and np.array_equal(drop, want)


@pytest.mark.parametrize("ring,new_xy", [([3, 4], (42.0, 50.0)), ([0, 0], (42.0, 50.0)), ([9, 0], (30.0, 50.0))])
def test_no_flag_for_a_crossing_no_line_or_a_far_blob(ring, new_xy):
    # [3, 4]: a crossing; [0, 0]: no line through it; a new candidate 20 px away: beyond near_px
    _, _, drop, n = _run(ring, new_xy)
    assert n == 0 and not drop.any()


@pytest.fixture(scope="module")
def seed142():
    from benchmarks.unseen import draw_scene
    from drivers.sim.presets import depth_range

    _, procam, scene, pattern, noise = draw_scene(142)
    img, truth = render_scene(procam, scene, pattern, noise_grey=noise, seed=142)
    return procam, scene, pattern, img, truth, depth_range(procam, scene)


def test_no_label_past_the_blobs_at_seed_142s_depth_edge(seed142):
    procam, scene, pattern, img, truth, dr = seed142
    o = ReconstructOptions(depth_min_mm=dr[0], depth_max_mm=dr[1])
    res = {pb: reconstruct(img, procam, pattern, options=replace(o, extract=replace(
        o.extract, unsuppressed_seeds=pb is not None, unsuppressed_past_blob=bool(pb)))) for pb in (None, False, True)}
    # the two new junctions next to object 2's silhouette (decision 0152): (682.0, 655.2) and (650.5, 787.6)
    J = np.array([[682.0, 655.2], [650.5, 787.6]])
    bad_near, near = {}, {}
    for pb, r in res.items():
        d = np.min(np.hypot(*(r.q_cam.astype(np.float64)[:, None, :] - J[None]).transpose(2, 0, 1)), axis=1)
        rel = relative_errors(r.points_proj, r.q_cam, truth) * 100
        bad_near[pb] = int(((d < 16) & (rel > 1)).sum())
        near[pb] = int((d < 16).sum())
    # None: unsuppressed_seeds off; False: on without this step; True: on with it (measured 1, 8, 0 points > 1 % off
    # and 81, 145, 130 points within 16 px of the two junctions)
    assert bad_near[False] >= 5  # the carried labels
    assert bad_near[True] == 0
    assert bad_near[None] < bad_near[False]  # without the new junctions those labels are not carried there
    assert near[True] >= near[None] + 20  # the new junctions' points stay
