"""Piece-junction nodes at the camera frame (decision 0143): a node whose line runs out of the image a short way past
it shows that family on one side only without being a T; such a node is an X, and two X nodes joined by a piece are
a component the labeller judges. Against analytic cases (the kernels) and the simulator's truth (paper-orthogonal,
whose object in the upper left is crossed by two lines of one family, one of them cut by the image's left border)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks._common import bench_scenes, relative_errors, render_scene
from reconstruction.labelling import _sample_grid
from reconstruction.piece_junctions import _k_leaves_frame
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.t_nodes import t_node_stems


def test_leaves_frame_within_reach_only():
    # 100 × 80 frame, margin 1 px: the usable box is [1, 98] × [1, 78]
    assert _k_leaves_frame(5.0, 40.0, -1.0, 0.0, 6.0, 100.0, 80.0, 1.0)  # x 5 → −1
    assert not _k_leaves_frame(5.0, 40.0, -1.0, 0.0, 3.0, 100.0, 80.0, 1.0)  # x 5 → 2: inside
    assert not _k_leaves_frame(5.0, 40.0, 1.0, 0.0, 6.0, 100.0, 80.0, 1.0)  # away from the border
    assert _k_leaves_frame(50.0, 75.0, 0.0, 1.0, 4.0, 100.0, 80.0, 1.0)  # y 75 → 79 > 78
    assert not _k_leaves_frame(5.0, 40.0, -1.0, 0.0, 6.0, 0.0, 0.0, 1.0)  # fw 0: off
    assert not _k_leaves_frame(50.0, 78.6, 0.0, 1.0, 4.0, 100.0, 80.0, 1.0)  # the node itself in the margin band
    assert not _k_leaves_frame(-3.0, 40.0, -1.0, 0.0, 6.0, 100.0, 80.0, 1.0)  # or outside the frame


def _t_case():
    """One node at (150, 50): family 1 runs through (ends on both sides), family 2 ends from above only."""
    ends = [(145.0, 50.0), (155.0, 50.0), (150.0, 45.0)]
    outward = [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0)]
    fams = [1, 1, 2]
    q = np.array(ends, np.float64)
    fam = np.array(fams, np.int64)
    grid = _sample_grid(q, np.ones(len(q), bool), np.arange(len(q)), 8.0, fam)
    return (np.array([(150.0, 50.0)]), np.zeros(3, np.int64), np.ascontiguousarray(q), np.array(outward, np.float64), fam, q, fam, grid)


@pytest.mark.parametrize("fh, expect", [(54.0, -1), (480.0, 1), (0.0, 1)])
def test_stem_cut_by_the_frame_is_no_stem(fh, expect):
    xy, node_end, E, U, fe, q, fam, grid = _t_case()
    fw = 400.0 if fh > 0 else 0.0
    # continue_px 6: family 2's line would show past the node down to y 56; a frame 54 px high (last row 53) cuts it
    stem = t_node_stems(xy, node_end, E, U, fe, 1.0, 6.0, q, fam, *grid, fw, fh, 0.0)
    assert stem.tolist() == [expect]
    if fh == 480.0:  # the defaults (no frame) give the same as a frame far away
        assert t_node_stems(xy, node_end, E, U, fe, 1.0, 6.0, q, fam, *grid).tolist() == [1]


@pytest.fixture(scope="module")
def orthogonal():
    sc = bench_scenes(["paper-orthogonal"], [], noise_grey=2.0)[0]
    img, truth = render_scene(sc.procam, sc.scene, sc.pattern, noise_grey=2.0)
    return sc, img, truth


def _run(sc, img, **trace):
    o = ReconstructOptions(depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1])
    o = dataclasses.replace(o, trace=dataclasses.replace(o.trace, **trace))
    return reconstruct(img, sc.procam, sc.pattern, options=o)


def test_frame_nodes_label_the_patch_right(orthogonal):
    sc, img, truth = orthogonal
    off = _run(sc, img, frame_through=False, piece_junction_min_nodes=3)
    on = _run(sc, img)
    # the step labels more samples at piece junctions and adds points
    assert on.stats["samples_piece_junctions"] > off.stats["samples_piece_junctions"]
    old = set(map(tuple, np.round(off.q_cam, 3).tolist()))
    new = np.array([tuple(x) not in old for x in np.round(on.q_cam, 3).tolist()])
    assert new.sum() >= 30
    # every added point is on its true surface point: a wrong line index would put it percent off
    rel = relative_errors(on.points_proj[new], on.q_cam[new], truth) * 100
    assert len(rel) and rel.max() < 1.0, rel.max()
    # and the object in the upper left (a 2 × 2 patch of crossings whose left column the frame cuts) is covered now
    box = (on.q_cam[:, 0] < 110) & (on.q_cam[:, 1] > 40) & (on.q_cam[:, 1] < 170)
    box_off = (off.q_cam[:, 0] < 110) & (off.q_cam[:, 1] > 40) & (off.q_cam[:, 1] < 170)
    assert box.sum() >= box_off.sum() + 30
    # the junction labels are unchanged (the step labels samples only)
    assert np.array_equal(on.junction_labels, off.junction_labels)



def test_pairs_kept_only_at_the_frame_and_beyond_the_crossings_pull():
    from reconstruction.piece_junctions import _short_pairs_out

    # nodes 0-1: a pair at the frame, 40 px apart; 2-3: a pair 40 px apart inside the image; 4-5: a pair at the
    # frame 8 px apart; 6-7-8: a component of three inside the image
    xy = np.array([(5.0, 100.0), (45.0, 100.0), (300.0, 100.0), (340.0, 100.0), (5.0, 300.0), (13.0, 300.0),
                   (300.0, 300.0), (340.0, 300.0), (380.0, 300.0)])
    at_frame = xy[:, 0] < 20.0
    edges = np.array([(0, 1), (2, 3), (4, 5), (6, 7), (7, 8)], np.int64)
    sub = np.arange(9)
    renum = np.arange(9)
    ek = np.arange(5)
    s2, r2, e2 = _short_pairs_out(sub, renum, ek, edges, xy, 20.0, at_frame)
    assert s2.tolist() == [0, 1, 6, 7, 8]
    assert r2.tolist() == [0, 1, -1, -1, -1, -1, 2, 3, 4]
    assert e2.tolist() == [0, 3, 4]
