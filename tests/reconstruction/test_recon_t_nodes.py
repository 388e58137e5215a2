"""Piece junctions with one family through (T nodes, decision 0098, reconstruction.t_nodes) against simulator
truth: the stems at a T are labelled, the through line only at the pattern's rim (never the half-hidden line
along a silhouette)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from benchmarks._common import bench_scenes, render_scene, sample_bilinear
from reconstruction.labelling import _sample_grid
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.t_nodes import t_labels, t_node_stems, through_end_samples, through_kept, through_refit, x_use


def _stem_case(continue_sample: bool):
    """Three nodes on a row: an X (both families' ends on both sides), a T (family 2 ends on one side only) and
    the same T with a family-2 trace sample 4 px past the node (the line goes on: an X)."""
    ends, outward, fams, node_end = [], [], [], []
    for k, x in enumerate((50.0, 150.0, 250.0)):
        arms = [((-5, 0), 1), ((5, 0), 1), ((0, -5), 2)] + ([((0, 5), 2)] if k == 0 else [])
        for (dx, dy), f in arms:
            ends.append((x + dx, 50.0 + dy))
            outward.append((-np.sign(dx), -np.sign(dy)))
            fams.append(f)
            node_end.append(k)
    q = np.array(ends + ([(250.0, 54.0)] if continue_sample else []), np.float64)
    fam = np.array(fams + ([2] if continue_sample else []), np.int64)
    sid = np.arange(len(q))
    grid = _sample_grid(q, np.ones(len(q), bool), sid, 8.0, fam)
    xy = np.array([(50.0, 50.0), (150.0, 50.0), (250.0, 50.0)])
    E = np.ascontiguousarray(q[: len(ends)])
    U = np.ascontiguousarray(np.array(outward, np.float64))
    return xy, np.array(node_end, np.int64), E, U, np.array(fams, np.int64), q, fam, grid


@pytest.mark.parametrize("continue_sample", [False, True])
def test_stem_is_the_family_whose_line_stops_at_the_node(continue_sample):
    xy, node_end, E, U, fe, q, fam, grid = _stem_case(continue_sample)
    stem = t_node_stems(xy, node_end, E, U, fe, 1.0, 6.0, q, fam, *grid)
    # node 0: an X; node 1: family 2 (column 1) stops; node 2: stops unless its line shows a sample past it
    assert stem.tolist() == [-1, 1, -1 if continue_sample else 1]


def test_through_line_is_kept_only_at_the_pattern_rim():
    # five pieces (edge rows): family 1 between nodes 0-1, 1-2, 2-3, 3-4 and family 2 between nodes 3-4; node 1
    # is a T whose stem is family 2 (family 1 goes through), node 3 a T whose stem is family 1 (family 2 goes
    # through); labels (i, j) = (3, k) at node k
    sel = np.arange(5)
    ed_a = np.array([0, 1, 2, 3, 3])
    ed_b = np.array([1, 2, 3, 4, 4])
    fam_s = np.array([1, 1, 1, 1, 2])
    stem = np.array([-1, 1, -1, 0, -1])
    L = np.array([[3, 0], [3, 1], [3, 2], [3, 3], [3, 4]])
    # the through line's pieces at a T (rows 0, 1 at node 1; row 4 at node 3) are dropped, the stems kept
    assert through_kept(sel, ed_a, ed_b, fam_s, stem, L, -5, 5).tolist() == [False, False, True, True, False]
    L_rim = L.copy()
    L_rim[:, 0] = 5  # the i-line through node 1 is the pattern's last line: whole, kept
    assert through_kept(sel, ed_a, ed_b, fam_s, stem, L_rim, -5, 5).tolist() == [True, True, True, True, False]
    L_rim[3, 1] = -5  # and the j-line through node 3 the first: kept too
    assert through_kept(sel, ed_a, ed_b, fam_s, stem, L_rim, -5, 5).tolist() == [True, True, True, True, True]


def test_through_end_samples_are_the_ends_at_a_T_only():
    # one piece of family 1, samples 10..17 at ts 0..7 px; its first end at node 0 (a T, stem family 2), its
    # last at node 1 (an X); trim 2.5 px: the samples at ts 0, 1, 2 of its first end
    sel = np.array([0])
    ed = np.array([0])
    cand = np.array([0])
    first, last = np.array([0]), np.array([7])
    ts = np.arange(8, dtype=np.float64)
    sid = np.arange(10, 18)
    out = through_end_samples(sel, ed, np.array([0]), np.array([1]), np.array([1]), cand, first, last, ts, sid,
                              np.array([1, -1]), 2.5, np.ones(1, bool))
    assert sorted(out.tolist()) == [10, 11, 12]
    # a piece refitted without its T (`through_refit`) is not looked at
    assert through_end_samples(sel, ed, np.array([0]), np.array([1]), np.array([1]), cand, first, last, ts, sid,
                               np.array([1, -1]), 2.5, np.zeros(1, bool)).tolist() == []
    # the stem's own piece (family 2) at that T keeps its ends
    out2 = through_end_samples(sel, ed, np.array([0]), np.array([1]), np.array([2]), cand, first, last, ts, sid,
                               np.array([1, -1]), 2.5, np.ones(1, bool))
    assert out2.tolist() == []


@pytest.fixture(scope="module")
def orthogonal():
    """The paper's orthogonal preset (758x570): a silhouette where the j-lines on the object end at an i-line that
    its occluding edge half hides (decision 0098)."""
    s = bench_scenes(["paper-orthogonal"], [], noise_grey=2.0)[0]
    image, truth = render_scene(s.procam, s.scene, s.pattern, noise_grey=s.noise_grey)
    return s, image, truth


def _run(s, image, loose: bool = False, clusters: bool = True, **trace):
    import reconstruction.labelling as L
    from reconstruction.labelling import LabelOptions

    o = ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])
    # the T nodes measured as decision 0098 did: without decision 0139's lone crossings (after them)
    o = dataclasses.replace(o, trace=dataclasses.replace(o.trace, **{"lone_crossings": False, **trace}))
    orig = L.label_piece_junctions
    if loose:  # decision 0092's looser X test alone: one family through, no T rule
        # clusters False: the labeller as decision 0098 measured it (before decisions 0108 and 0109)
        lo = {} if clusters else {"label_options": LabelOptions(min_component=3, residual_clusters=False, residual_cap_px=3.0)}
        L.label_piece_junctions = lambda *a, **k: orig(*a, **{**k, "x_both": False, **lo})
    try:
        return reconstruct(image, s.procam, s.pattern, options=o)
    finally:
        L.label_piece_junctions = orig


def _added(r0, r1):
    old = set(map(tuple, np.round(r0.q_cam.astype(np.float64), 3)))
    return np.array([tuple(x) not in old for x in np.round(r1.q_cam.astype(np.float64), 3)], bool)


def _error_pct(r, truth) -> np.ndarray:
    """Each point's distance to the true surface point at its pixel over that point's distance, % (NaN: none)."""
    p_true = sample_bilinear(truth.p_proj, r.q_cam)
    return np.linalg.norm(r.points_proj - p_true, axis=1) / np.linalg.norm(p_true, axis=1) * 100


def test_T_nodes_add_points_at_the_silhouette_without_its_half_hidden_line(orthogonal):
    s, image, truth = orthogonal
    off = _run(s, image, t_nodes=False)
    on = _run(s, image, t_nodes=True)
    loose = _run(s, image, loose=True, clusters=False, t_nodes=False)
    new_on = _added(off, on)
    new_loose = _added(off, loose)
    e_on = _error_pct(on, truth)[new_on]
    e_loose = _error_pct(loose, truth)
    # measured (decision 0098): 55 points added with the T's in the graph (round 1), 21 with the T's labelled after
    # the X nodes (round 2, the default rule), max 0.008 %; the loose test alone: 101, p99 0.78 % (the rim line)
    assert new_on.sum() >= 15
    assert np.nanmax(e_on) < 0.05
    bad = new_loose & (e_loose > 0.5)
    assert bad.sum() >= 10
    # those are the samples of one i-line, the silhouette's rim, which the T rule leaves out
    rim = np.unique(loose.label[bad, 0])
    assert np.all(loose.family[bad] == 1) and len(rim) == 1
    assert not np.any(new_on & (on.family == 1) & (on.label[:, 0] == rim[0]))
    # with decisions 0108 and 0109 (on by default) the loose test's rim line is not labelled wrong either
    loose_0108 = _run(s, image, loose=True, t_nodes=False)
    assert np.sum(_added(off, loose_0108) & (_error_pct(loose_0108, truth) > 0.5)) < 3


def test_T_nodes_label_the_rim_of_the_pattern_with_true_indices(small_scene_pitch16):
    s = small_scene_pitch16
    off = _run(s, s.image, t_nodes=False)
    on = _run(s, s.image, t_nodes=True)
    new = _added(off, on) & (on.family > 0)
    assert new.sum() >= 10
    m = on.q_cam[new].astype(np.float32).reshape(-1, 1, 2)
    qp = cv2.remap(s.truth.q_proj.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderValue=np.nan).reshape(-1, 2)
    fam = on.family[new]
    n = np.where(fam == 1, s.pattern.n1, s.pattern.n2)
    true_k = ((qp[:, 1] - s.pattern.centre_px[1]) - n * (qp[:, 0] - s.pattern.centre_px[0])) / s.pattern.pitch_px
    k = np.where(fam == 1, on.label[new, 0], on.label[new, 1])
    ok = np.isfinite(true_k)
    assert ok.mean() > 0.9
    assert np.all(np.abs(true_k[ok] - k[ok]) < 0.1)
    e = _error_pct(on, s.truth)[new]
    assert np.nanmedian(e) < 0.05 and np.nanmax(e) < 1.0


def test_refit_leaves_the_T_node_out_of_the_through_line():
    # a through piece of family 1: samples on y = 0 at x = 1 .. 10 (ts = x − 1), its first node a T pulled
    # 0.6 px off the line towards the stem (y = 0.6), its last an X on the line; trim 1.5 px
    x = np.arange(1.0, 11.0)
    q = np.stack([x, np.zeros_like(x)], axis=1)
    xy = np.array([[0.0, 0.6], [11.0, 0.0]])
    args = (np.array([0]), np.array([0]), np.array([0]), np.array([1]), np.array([1]), np.array([0]),
            np.array([0]), np.array([9]), x - 1.0, q, np.arange(10), xy)
    mom = np.zeros((1, 5))
    assert through_refit(args[0], mom, *args[1:], np.array([1, -1]), 1.5, 2).tolist() == [1]
    ang = 0.5 * np.arctan2(2 * mom[0, 4], mom[0, 2] - mom[0, 3])
    assert abs(mom[0, 1]) < 1e-12 and abs(ang) < 1e-12  # the line y = 0: the T node is not in the fit
    # with the T node as an X (stem −1) the piece is not refitted; with too few inner samples it is flagged
    assert through_refit(args[0], np.zeros((1, 5)), *args[1:], np.array([-1, -1]), 1.5, 2).tolist() == [0]
    assert through_refit(args[0], np.zeros((1, 5)), *args[1:], np.array([1, -1]), 1.5, 20).tolist() == [2]


@pytest.mark.parametrize("rule, over1_max", [("off", 0.5), ("after", 0.5), ("graph", None)])
def test_t_nodes_keep_an_ill_posed_placement_right(rule, over1_max):
    """The placement sweep's row baseline 100 mm, direction 30° (ill-posed: junctions a few labels apart share an
    epipolar line): with the T nodes in the graph given to the labeller (round 1, t_rule "graph"), T's at
    silhouettes join two surfaces and whole components take wrong labels (decision 0098, the lead's section:
    5.2 % of the points more than 1 % off). With the T's labelled after the X nodes' components from the labels
    their X neighbours agree on (round 2, "after"), and with T nodes off, the share stays within the issue's
    0.5 % (measured: 0.00 % both)."""
    import functools

    import reconstruction.labelling as L
    import reconstruction.piece_junctions as pjm
    from benchmarks._common import evaluate_grid, pooled, sweep_procam
    from drivers.sim import RenderOptions, SimWorld, preset
    from reconstruction.patterns import GridPattern

    pattern = GridPattern()
    rig = preset("tabletop", truth=sweep_procam(100.0, 30.0))
    world = SimWorld(rig, options=RenderOptions(noise_grey=2.0, supersample=2), seed=0)
    image = world.render(pattern.render(rig.procam.projector.width, rig.procam.projector.height))
    opts = ReconstructOptions(depth_min_mm=rig.depth_range_mm[0], depth_max_mm=rig.depth_range_mm[1])
    opts = dataclasses.replace(opts, trace=dataclasses.replace(opts.trace, t_nodes=rule != "off"))
    orig = L.label_piece_junctions
    if rule != "off":
        L.label_piece_junctions = functools.partial(pjm.label_piece_junctions, t_rule=rule)
    try:
        p = pooled([evaluate_grid(reconstruct(image, rig.procam, pattern, options=opts), world.truth, pattern)])
    finally:
        L.label_piece_junctions = orig
    if over1_max is not None:
        assert p["over1_pct"] <= over1_max
    else:
        assert p["over1_pct"] > 1.0


def test_x_use_labels_the_x_components_without_the_ts():
    # nodes 0, 1, 2 X's joined by edges (0-1, 1-2); node 3 a T joined to 2 (its stem); nodes 4, 5 X's joined to
    # each other and to the T 3 (edge 3-4): through the T the two X groups would be one component
    stem = np.array([-1, -1, -1, 1, -1, -1])
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5]])
    eseg = np.arange(5)
    cand = np.arange(5)
    labelled = np.array([True, True, False, True, True])  # the stem's piece (edge 2-3) unlabelled
    sub, renum, ek = x_use(6, edges, eseg, cand, labelled, stem, 3)
    # the component {0, 1, 2} holds the unlabelled stem's edge and has 3 X nodes; {4, 5} is too small (2 nodes:
    # it would have 3 with the T); the T is never given to the labeller; only X–X edges go in
    assert sub.tolist() == [0, 1, 2]
    assert renum.tolist() == [0, 1, 2, -1, -1, -1]
    assert ek.tolist() == [0, 1]
    sub2, _, ek2 = x_use(6, edges, eseg, cand, labelled, stem, 2)
    assert sub2.tolist() == [0, 1, 2] and ek2.tolist() == [0, 1]  # {4, 5}: no unlabelled edge at its nodes


def test_t_labels_only_where_the_x_neighbours_agree():
    U = np.iinfo(np.int32).min
    # T node 2 between X nodes 0 (edge 0-2, delta (1, 0)) and 1 (edge 2-1, delta (0, 1)); T node 3 next to X 0
    # only; T node 4 next to nothing labelled; X node 5 unlabelled
    stem = np.array([-1, -1, 1, 0, 1, -1])
    edges = np.array([[0, 2], [2, 1], [0, 3], [4, 5]])
    delta = np.array([[1, 0], [0, 1], [0, 1], [1, 0]])
    L = np.array([[3, 7], [4, 8], [U, U], [U, U], [U, U], [U, U]])
    comp = np.array([0, 0, -1, -1, -1, -1])
    Lc, cc = L.copy(), comp.copy()
    n_ok, n_bad = t_labels(Lc, cc, stem, edges, delta, U)
    # node 2: from 0: (4, 7); from 1: (4, 8) − (0, 1) = (4, 7): they agree; node 3: (3, 8)
    assert (n_ok, n_bad) == (2, 0)
    assert Lc[2].tolist() == [4, 7] and Lc[3].tolist() == [3, 8] and Lc[4].tolist() == [U, U]
    assert cc[2] not in (0, cc[3]) and cc[3] != 0  # each T its own component
    # the two X's in different index systems (node 1 off by 2 in i): the T stays unlabelled, no new offset
    L2 = L.copy()
    L2[1] = [6, 8]
    Lc, cc = L2.copy(), comp.copy()
    assert t_labels(Lc, cc, stem, edges, delta, U) == (1, 1)
    assert Lc[2].tolist() == [U, U] and Lc[3].tolist() == [3, 8]
    # an edge between two labelled T's that disagrees with its delta leaves both out
    edges3 = np.vstack([edges, [[2, 3]]])
    delta3 = np.vstack([delta, [[0, 0]]])  # 2 is (4, 7), 3 is (3, 8): not equal
    Lc, cc = L.copy(), comp.copy()
    assert t_labels(Lc, cc, stem, edges3, delta3, U) == (0, 2)


def test_rim_ts_are_the_ts_whose_through_piece_carries_the_rim_index():
    from reconstruction.t_nodes import rim_ts

    # nodes 0, 1 T's with stem family 2 (index 1), node 2 an X; pieces 0..2 (family 1: pieces 0, 1; family 2:
    # piece 2), each piece one sample; end rows r → piece cand[r % 3]: rows 0-2 first ends, rows 3-5 last ends
    stem = np.array([1, 1, -1])
    cand = np.array([0, 1, 2])
    first = np.array([0, 1, 2])
    sid = np.array([0, 1, 2])
    fam = np.array([1, 1, 2])
    labelled = np.array([True, True, True])
    val = np.array([5, 3, 5])  # piece 0 on the last line (5), piece 1 on line 3, piece 2 (the stem) on 5
    node_end = np.array([0, 1, 0, -1, -1, 2])  # piece 0 ends at T 0, piece 1 at T 1, the stem piece 2 at T 0
    assert rim_ts(stem, node_end, 3, cand, labelled, val, first, fam, sid, -5, 5).tolist() == [True, False, False]
    # unlabelled through piece: not known as the rim
    assert rim_ts(stem, node_end, 3, cand, np.array([False, True, True]), val, first, fam, sid, -5, 5).tolist() == [False, False, False]
