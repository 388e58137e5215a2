"""Labelling against analytic truth: component offsets, splitting at a bad edge, ambiguity on an
ill-posed rig, the paper's triangles on a De Bruijn grid, and line samples following their trace."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.extraction import GridObservation
from reconstruction.labelling import (
    LabelOptions,
    TraceOptions,
    label_epipolar,
    label_paper,
    label_samples,
    profile_drop,
    relative_labels,
    solve_base_point,
    triangle_shape,
)
from reconstruction.patterns import GridPattern
from reconstruction.rigmodel import UNLABELLED, rig_model
from tests.reconstruction._truth import lattice_edges


def _procam(t=(180.0, 60.0, 40.0), dist_proj=(0.03, 0, 0, 0, 0)) -> ProCam:
    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.array([-0.05, 0.02, 0, 0, 0]))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]), np.array(dist_proj, float))
    t = np.array(t)
    return ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t)


def _obs(junction_q: np.ndarray, edges: np.ndarray, delta: np.ndarray, q: np.ndarray | None = None,
         family: np.ndarray | None = None, junction_dir: np.ndarray | None = None) -> GridObservation:
    M = len(junction_q)
    q = np.zeros((0, 2)) if q is None else q
    P = len(q)
    return GridObservation(
        q=q, family=np.zeros(P, np.int8) if family is None else family, segment=np.full(P, -1), junction=np.full(P, -1),
        strength=np.ones(P), q_junction=junction_q,
        junction_dir=np.zeros((M, 2, 2)) if junction_dir is None else junction_dir,
        segment_family=np.zeros(0, np.int8), segment_ends=np.zeros((0, 2), np.int64), segment_rms=np.zeros(0),
        segment_centre=np.zeros((0, 2)), segment_dir=np.zeros((0, 2)), edges=edges.reshape(-1, 2).astype(np.int64),
        edge_family=np.zeros(len(edges), np.int8), edge_delta=delta.reshape(-1, 2).astype(np.int64),
        edge_segment=np.zeros(len(edges), np.int64), stats={},
    )


def _plane_junctions(procam: ProCam, pattern: GridPattern, *, z0=850.0, normal=(0.1, -0.2, -1.0), noise_px=0.05, seed=0):
    """True labels (N, 2), camera pixels (N, 2) of the pattern junctions on a plane through (0, 0, z0), and
    the grid-neighbour edges (E, 2) with their (i, j) deltas."""
    idx = pattern.indices
    ii, jj = np.meshgrid(idx, idx, indexing="ij")
    lab = np.column_stack([ii.ravel(), jj.ravel()])
    xy = procam.projector.pixels_to_normalised(pattern.junction_uv(lab[:, 0], lab[:, 1]))
    e = np.column_stack([xy, np.ones(len(xy))])
    n = np.asarray(normal) / np.linalg.norm(normal)
    p = e * ((n @ np.array([0, 0, z0])) / (e @ n))[:, None]
    q = procam.camera.project(procam.proj_to_cam(p))
    q = q + np.random.default_rng(seed).normal(0, noise_px, q.shape)
    inside = (q[:, 0] > 5) & (q[:, 0] < 634) & (q[:, 1] > 5) & (q[:, 1] < 474)
    lab, q = lab[inside], q[inside]
    return (lab, q, *lattice_edges(lab))


def _correct(labels: np.ndarray, truth: np.ndarray) -> tuple[int, int]:
    ok = labels[:, 0] != UNLABELLED
    return int(ok.sum()), int((labels[ok] == truth[ok]).all(axis=1).sum())


def test_one_offset_per_component_labels_a_plane_exactly():
    procam = _procam()
    pattern = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5))
    model = rig_model(procam, pattern, (500.0, 1200.0))
    truth, q, edges, delta = _plane_junctions(procam, pattern)
    obs = _obs(q, edges, delta)
    lab = label_epipolar(obs, model, procam.camera.pixels_to_normalised(q), options=LabelOptions(depth_min_mm=500, depth_max_mm=1200))
    n, good = _correct(lab.labels, truth)
    assert n == len(truth) and good == n
    assert np.nanmax(lab.residual) < 0.5


def test_a_component_joined_by_a_bad_edge_is_split_and_both_parts_labelled_right():
    procam = _procam()
    pattern = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5))
    model = rig_model(procam, pattern, (500.0, 1200.0))
    truth, q, edges, delta = _plane_junctions(procam, pattern)
    # Cut the grid into two halves (i < 0 and i >= 0) and join them with one edge whose delta is off by one
    # in j: the right half's relative labels are then shifted by (0, 1) from the truth.
    left = truth[:, 0] < 0
    keep = left[edges[:, 0]] == left[edges[:, 1]]
    edges, delta = edges[keep], delta[keep]
    a = np.flatnonzero((truth[:, 0] == -1) & (truth[:, 1] == 0))[0]
    b = np.flatnonzero((truth[:, 0] == 0) & (truth[:, 1] == 0))[0]
    edges = np.vstack([edges, [a, b]])
    delta = np.vstack([delta, [1, 1]])  # truth: (1, 0)
    obs = _obs(q, edges, delta)
    lab = label_epipolar(obs, model, procam.camera.pixels_to_normalised(q), options=LabelOptions(depth_min_mm=500, depth_max_mm=1200))
    n, good = _correct(lab.labels, truth)
    assert good == n, f"{n - good} wrong labels"
    assert n >= 0.95 * len(truth)
    assert lab.stats["components_split"] >= 1
    # Without outliers (no split), the mixed component is ambiguous or half wrong: at most half is right.
    no_split = LabelOptions(depth_min_mm=500, depth_max_mm=1200, max_residual_px=100.0, outlier_sigma=1e6)
    lab2 = label_epipolar(obs, model, procam.camera.pixels_to_normalised(q), options=no_split)
    _, good2 = _correct(lab2.labels, truth)
    assert good2 <= 0.6 * len(truth)


def test_an_ill_posed_rig_leaves_components_out_instead_of_guessing():
    # Camera displaced along x only: epipolar lines are horizontal, and with 30°/120° the offset (1, -3)
    # slides every junction along them (decision 0043). A wide depth range admits several offsets.
    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]))
    t = np.array([200.0, 0.0, 0.0])
    procam = ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0]), up=np.array([0.0, -1.0, 0.0])), t)
    pattern = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5))
    model = rig_model(procam, pattern, (300.0, 3000.0))
    truth, q, edges, delta = _plane_junctions(procam, pattern, normal=(0.0, 0.0, -1.0), noise_px=0.05)
    # Keep a small patch: the pattern's extent cannot pin it.
    sel = (np.abs(truth[:, 0]) <= 2) & (np.abs(truth[:, 1]) <= 2)
    ids = np.flatnonzero(sel)
    remap = -np.ones(len(truth), np.int64)
    remap[ids] = np.arange(len(ids))
    ke = sel[edges[:, 0]] & sel[edges[:, 1]]
    obs = _obs(q[ids], remap[edges[ke]], delta[ke])
    lab = label_epipolar(obs, model, procam.camera.pixels_to_normalised(q[ids]), options=LabelOptions(depth_min_mm=300, depth_max_mm=3000))
    n, good = _correct(lab.labels, truth[ids])
    assert good == n
    assert n == 0 and lab.stats["junctions_left_out"]["ambiguous"] == len(ids)


def test_paper_triangle_shape_generalises_eq2_and_solves_exactly_on_a_debruijn_grid():
    pattern = GridPattern(pitch_px=30.0, lines=33, spacing="debruijn")
    h, v = triangle_shape(pattern, 30.0, 30.0)
    d = pattern.n2 - pattern.n1
    np.testing.assert_allclose(h, [0, 30 / d, 0], atol=1e-12)
    np.testing.assert_allclose(v, [0, pattern.n2 * 30 / d, 30], atol=1e-12)
    rng = np.random.default_rng(3)
    offs = pattern.offsets_px(1)
    for _ in range(20):
        k = int(rng.integers(0, 31))
        kj = int(rng.integers(0, 31))
        i, j = pattern.indices[k], pattern.indices[kj]
        verts = pattern.junction_xy(np.array([i, i + 1, i + 1]), np.array([j, j, j + 1]))
        hh, vv = triangle_shape(pattern, offs[k + 1] - offs[k], pattern.offsets_px(2)[kj + 1] - pattern.offsets_px(2)[kj])
        np.testing.assert_allclose(verts[0] + np.column_stack([hh, vv]), verts, atol=1e-9)
        # Lines through each vertex with random slopes: the base point is the first vertex.
        m = rng.uniform(-0.5, 0.5, 3)
        b = verts[:, 1] - m * verts[:, 0]
        np.testing.assert_allclose(solve_base_point(m[None], b[None], hh, vv)[0], verts[0], atol=1e-7)


@pytest.mark.parametrize("spacing", ["uniform", "debruijn"])
def test_paper_labeller_on_exact_triangles(spacing):
    # Junctions seen without noise: every triangle's base point solves exactly and snaps to its own junction.
    procam = _procam(dist_proj=(0, 0, 0, 0, 0))
    pattern = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5), spacing=spacing)
    model = rig_model(procam, pattern, (500.0, 1200.0))
    truth, q, edges, delta = _plane_junctions(procam, pattern, noise_px=0.0)
    lab = label_paper(_obs(q, edges, delta), model, procam.camera.pixels_to_normalised(q))
    n, good = _correct(lab.labels, truth)
    assert lab.stats["triangles"] > 200
    assert n > 0.9 * len(truth) and good == n


def test_default_labeller_on_a_debruijn_grid_with_noise():
    procam = _procam()
    pattern = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5), spacing="debruijn")
    model = rig_model(procam, pattern, (500.0, 1200.0))
    truth, q, edges, delta = _plane_junctions(procam, pattern, noise_px=0.1)
    lab = label_epipolar(_obs(q, edges, delta), model, procam.camera.pixels_to_normalised(q), options=LabelOptions(depth_min_mm=500, depth_max_mm=1200))
    n, good = _correct(lab.labels, truth)
    assert n >= 0.98 * len(truth) and good == n


def _line_samples(p0, direction, n, family, start=0.0):
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    s = start + np.arange(n, dtype=float)
    return np.asarray(p0, float) + s[:, None] * d, np.full(n, family, np.int8)


def test_line_samples_follow_the_trace_to_the_border_and_stop_at_a_jump():
    # One labelled junction at (100, 100); its i-line runs right to the image border (x = 400); a second
    # piece of the same line direction continues 2 px to the side after a gap-free join (a depth edge) and
    # must not inherit the index; a parallel line 20 px away (no junction) stays unlabelled.
    d = np.array([1.0, 0.2])
    a, fa = _line_samples((100, 100), d, 200, 1, start=3.0)
    n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    end = a[-1]
    b, fb = _line_samples(end + 2.0 * n, d, 80, 1, start=1.0)
    c, fc = _line_samples(np.array([100, 100]) + 20 * n, d, 150, 1)
    q = np.vstack([a, b, c])
    fam = np.concatenate([fa, fb, fc])
    jd = np.zeros((1, 2, 2))
    jd[0, 0] = d / np.linalg.norm(d)
    jd[0, 1] = n
    obs = _obs(np.array([[100.0, 100.0]]), np.zeros((0, 2)), np.zeros((0, 2)), q=q, family=fam, junction_dir=jd)
    sl = label_samples(obs, np.array([[4, -7]]), sigma_px=1.0, seed_radius_px=8.0, options=TraceOptions())
    # Samples within the direction radius of the jump see both pieces and may be left out; none is wrong.
    assert np.all(sl.index[: len(a) - 3] == 4)
    assert np.all(np.isnan(sl.index[len(a):]))
    assert sl.stats["samples_labelled"] >= len(a) - 3


def test_line_samples_take_the_nearest_seed_when_a_trace_joins_two_lines():
    # Two labelled junctions on one trace with different indices (e.g. a wrong label): each half follows
    # its own junction, never the other's.
    d = np.array([1.0, 0.0])
    a, fa = _line_samples((50, 50), d, 300, 2)
    jd = np.zeros((2, 2, 2))
    jd[:, 1] = d
    jd[:, 0] = (0.0, 1.0)
    obs = _obs(np.array([[60.0, 50.0], [330.0, 50.0]]), np.zeros((0, 2)), np.zeros((0, 2)), q=a, family=fa, junction_dir=jd)
    sl = label_samples(obs, np.array([[0, 3], [1, 5]]), sigma_px=1.0, seed_radius_px=8.0)
    x = a[:, 0]
    assert np.all(sl.index[x < 150] == 3) and np.all(sl.index[x > 250] == 5)
    assert sl.stats["traces_conflicting"] == 1


def test_mixing_zone_samples_are_moved_onto_the_labelled_junctions_fitted_line():
    # Two lines crossing at (200, 150); near the crossing each line's samples are pulled 0.4 px towards
    # the other line (the overlap bias). With the junction labelled, those samples are moved back onto
    # the junction's fitted line and keep its index; without a label they are dropped, never kept biased.
    d1 = np.array([1.0, 0.3]) / np.hypot(1.0, 0.3)
    d2 = np.array([-0.4, 1.0]) / np.hypot(0.4, 1.0)
    c = np.array([200.0, 150.0])
    s = np.arange(-30, 31, dtype=float)
    a = c + s[:, None] * d1
    b = c + s[:, None] * d2
    near_a = np.abs(s) < 5
    a[near_a] += 0.4 * d2 * np.sign(s[near_a])[:, None]  # pulled along the other line, off its own
    b[near_a] += 0.4 * d1 * np.sign(s[near_a])[:, None]
    keep = np.abs(s) >= 1  # the crossing pixel itself belongs to neither
    q = np.vstack([a[keep], b[keep]])
    fam = np.concatenate([np.full(keep.sum(), 1, np.int8), np.full(keep.sum(), 2, np.int8)])
    jd = np.array([[d1, d2]])
    obs = _obs(c[None], np.zeros((0, 2)), np.zeros((0, 2)), q=q, family=fam, junction_dir=jd)
    sl = label_samples(obs, np.array([[7, -2]]), sigma_px=1.5, seed_radius_px=12.0)
    assert sl.stats["snapped_to_junction_line"] > 10
    moved = np.any(sl.q != q, axis=1)
    assert moved.sum() == sl.stats["snapped_to_junction_line"]
    # every moved sample lies on its family's fitted line, with its family's index
    for f, dvec, idx in ((1, d1, 7), (2, d2, -2)):
        m = moved & (fam == f)
        off = sl.q[m] - c
        assert np.abs(off[:, 0] * dvec[1] - off[:, 1] * dvec[0]).max() < 1e-9
        assert np.all(sl.index[m] == idx)
    # every sample of both lines is labelled right (the far ones along the trace)
    assert np.all(sl.index[fam == 1] == 7) and np.all(sl.index[fam == 2] == -2)
    # unlabelled junction: the biased samples are dropped, nothing is labelled
    sl0 = label_samples(obs, np.array([[UNLABELLED, UNLABELLED]]), sigma_px=1.5, seed_radius_px=12.0)
    assert np.isnan(sl0.index).all() and sl0.stats["mixing_zone"] > 10


def test_profile_drop_is_zero_on_a_ridge_and_large_where_an_occluding_edge_hides_half_the_line():
    # A vertical bright bar 10 px wide (grey 200 on 10), blurred like a lens (σ = 1 px).
    import cv2

    w = 10.0
    u = np.arange(200, dtype=np.float64)
    bar = np.where(np.abs(u - 100.0) <= w / 2, 200.0, 10.0)
    img = np.tile(bar, (60, 1)).astype(np.float32)
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    tangent = np.tile([[0.0, 1.0]], (3, 1))
    q = np.array([[100.0, 30.0], [101.2, 30.0], [98.5, 30.0]])  # on the ridge and within the plateau
    drop = profile_drop(img, q, tangent, w)
    assert np.all(drop < 0.05), drop
    # An occluder (grey 80) covers the bar's right half from u = 100 on. On the paper-intermediate scene
    # the smoothed ridge of such a half-hidden line fell on the occluder's pixels, just past the edge:
    # there the image is the occluder's, far below the line's brightest point half a width away.
    occl = np.tile(np.where(u >= 100.0, 80.0, np.where(np.abs(u - 100.0) <= w / 2, 200.0, 10.0)), (60, 1)).astype(np.float32)
    occl = cv2.GaussianBlur(occl, (0, 0), 1.0)
    t1 = tangent[:1]
    assert profile_drop(occl, np.array([[100.5, 30.0]]), t1, w)[0] > 2 * TraceOptions().max_profile_drop
    # inside the visible half, away from the edge, the sample is still on the line's light
    assert profile_drop(occl, np.array([[97.5, 30.0]]), t1, w)[0] < 0.05


def test_relative_labels_recover_a_grid_up_to_one_offset_per_component_and_drop_a_contradiction():
    # Two grid patches (8×8 and 5×5) with shuffled junction ids, every neighbour pair joined, edge
    # directions random; one extra edge contradicts the grid.
    rng = np.random.default_rng(3)
    pts = [(i, j) for i in range(8) for j in range(8)] + [(100 + i, j) for i in range(5) for j in range(5)]
    perm = rng.permutation(len(pts))
    lab = np.array(pts)[np.argsort(perm)]  # lab[id] = true label of junction id
    where = {tuple(v): k for k, v in enumerate(lab.tolist())}
    edges, delta = [], []
    for (i, j), a in where.items():
        for di, dj in ((1, 0), (0, 1)):
            b = where.get((i + di, j + dj))
            if b is not None:
                e = (a, b) if rng.random() < 0.5 else (b, a)
                edges.append(e)
                delta.append(lab[e[1]] - lab[e[0]])
    a0, b0 = where[(3, 3)], where[(3, 4)]
    edges.append((a0, b0))
    delta.append((5, 5))  # contradicts
    rel, comp, removed = relative_labels(len(lab), np.array(edges), np.array(delta))
    # clean_edges drops every edge at both ends of the contradicting one: those two junctions are isolated
    assert removed == 1 + 4 + 3
    sizes = np.bincount(comp)
    assert sizes[comp[a0]] == 1 and sizes[comp[b0]] == 1
    assert sorted(sizes[sizes > 1].tolist()) == [25, 62]
    for c in np.unique(comp):
        m = np.flatnonzero(comp == c)
        off = lab[m] - rel[m]
        # one offset for the whole component: the lowest-numbered junction is the root (label 0, 0)
        assert (off == off[0]).all(), np.unique(off, axis=0)
        assert (rel[m.min()] == 0).all()


def test_a_trace_is_cut_where_the_ridge_brightness_jumps():
    # One straight i-line, seeded at (100, 100); from x = 250 on it is 40 % darker (another surface's line
    # continuing it across an occluding edge). With the image, the dark part is cut off; without the
    # test (max_ridge_step = 0), the seed's index runs through to the end.
    d = np.array([1.0, 0.0])
    a, fa = _line_samples((100, 100), d, 300, 1, start=3.0)
    img = np.zeros((240, 480), np.float32)
    img[99:102, 100:250] = 200.0
    img[99:102, 250:410] = 120.0
    jd = np.zeros((1, 2, 2))
    jd[0, 0] = d
    jd[0, 1] = (0.0, 1.0)
    obs = _obs(np.array([[100.0, 100.0]]), np.zeros((0, 2)), np.zeros((0, 2)), q=a, family=fa, junction_dir=jd)
    opts = TraceOptions(max_profile_drop=0.0)
    cut = label_samples(obs, np.array([[4, -7]]), sigma_px=1.0, seed_radius_px=8.0, options=opts, image=img, line_width_px=3.0)
    x = a[:, 0]
    assert np.all(cut.index[x < 245] == 4)
    assert np.all(np.isnan(cut.index[x > 255]))
    whole = label_samples(obs, np.array([[4, -7]]), sigma_px=1.0, seed_radius_px=8.0, image=img, line_width_px=3.0,
                          options=TraceOptions(max_profile_drop=0.0, max_ridge_step=0.0))
    assert np.all(whole.index == 4)


@pytest.mark.parametrize("bad", [{"noise_floor_px": 0.0}, {"residual_cap_px": -1.0}, {"candidate_band_px": 0.0},
                                 {"max_residual_px": float("nan")}, {"depth_min_mm": 900.0, "depth_max_mm": 500.0}])
def test_label_options_reject_values_the_labeller_cannot_use(bad):
    # noise_floor_px = 0 made the compiled ambiguity test divide by zero and label nothing, silently
    from reconstruction.labelling import LabelOptions

    with pytest.raises(ValueError, match="LabelOptions"):
        LabelOptions(**bad)
