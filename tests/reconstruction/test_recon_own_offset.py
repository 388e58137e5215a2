"""Decision 0151: a line sample's δ in decision 0131's precision test is the larger of the frame's noise and the
sample's own sideways offset from its line's local fit, in projector px across its line.

- `own_offsets_px` against a constructed observation: a sample moved a known distance off its segment's straight fit
  (or off its junction's arm line) gets that distance times the family's scale; junction rows, crossing points and
  samples with neither a segment nor a junction get 0.
- `across_line_scale` against a known affine camera-from-projector map of a labelled grid.
- `imprecise_samples` with own offsets: a row is judged at max(δ, own offset), and nothing else changes.
- The small test rig's scene (well-posed; decision 0131 alone leaves nothing out): the own offsets leave out a few
  samples (under 0.1 %), each worse than the kept samples' median of their family.
- Unseen seed 148 of `benchmarks.unseen` (converged 1280 rig, i-lines at 28.6° running near the epipolar lines):
  without the own offsets its p99 is over 0.5 % (the samples pulled sideways near the crossings); with them under,
  the points it leaves out are far worse than those it keeps, and the junctions all stay.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from reconstruction.sheet_precision import (SheetPrecisionOptions, across_line_scale, imprecise_samples, own_offsets_px,
                                            predicted_error)
from reconstruction.rigmodel import UNLABELLED


def _obs(q, family, segment, junction, seg_centre, seg_dir, q_junction, junction_dir):
    return SimpleNamespace(q=np.asarray(q, float), family=np.asarray(family, np.int8), segment=np.asarray(segment, np.int32),
                           junction=np.asarray(junction, np.int32), segment_centre=np.asarray(seg_centre, np.float32),
                           segment_dir=np.asarray(seg_dir, np.float32), q_junction=np.asarray(q_junction, float),
                           junction_dir=np.asarray(junction_dir, float))


def test_own_offsets_are_the_distances_from_the_local_fits_times_the_scale():
    # segment 0: family 1, the line through (100, 100) at 30° (direction not normalised); segment 1: family 2, vertical
    a = np.deg2rad(30.0)
    t0 = np.array([np.cos(a), np.sin(a)])
    n0 = np.array([-t0[1], t0[0]])
    # junction 0 at (300, 200): its family-2 arm runs at 100°
    b = np.deg2rad(100.0)
    t2 = np.array([np.cos(b), np.sin(b)])
    n2 = np.array([-t2[1], t2[0]])
    q = [
        np.array([100.0, 100.0]) + 7.0 * t0 + 0.3 * n0,  # 0: 0.3 px off segment 0
        np.array([100.0, 100.0]) - 4.0 * t0 - 0.05 * n0,  # 1: 0.05 px off, the other side
        np.array([50.0, 40.0]) + np.array([0.2, 9.0]),  # 2: 0.2 px off segment 1 (x = 50)
        np.array([300.0, 200.0]) + 3.0 * t2 + 0.12 * n2,  # 3: a junction's arm sample (no segment), 0.12 px off the arm
        np.array([10.0, 10.0]),  # 4: neither segment nor junction
    ]
    obs = _obs(q, [1, 1, 2, 2, 1], [0, 0, 1, -1, -1], [-1, -1, -1, 0, -1], [[100.0, 100.0], [50.0, 40.0]],
               [3.0 * t0, [0.0, -1.0]], [[300.0, 200.0]], [[[1.0, 0.0], t2]])
    scale = np.array([0.8, 1.25])
    src = np.array([0, 1, 2, 3, 4, 5, -1])  # 5: a crossing point after the P samples, −1: a junction row
    got = own_offsets_px(src, np.vstack([q, [[0.0, 0.0]]]), obs, scale)
    np.testing.assert_allclose(got, [0.3 * 0.8, 0.05 * 0.8, 0.2 * 1.25, 0.12 * 1.25, 0.0, 0.0, 0.0], atol=1e-5)
    # no scale for a family (NaN): 0, never NaN
    got = own_offsets_px(src, np.vstack([q, [[0.0, 0.0]]]), obs, np.array([np.nan, 1.0]))
    assert np.all(np.isfinite(got)) and got[0] == 0.0 and got[2] == pytest.approx(0.2, abs=1e-5)


def test_across_line_scale_is_the_affine_maps_across_line_factor():
    # a 30°/120° grid (pitch 20) in the projector, seen through the camera map x_cam = A·x_proj + b
    pitch, n1, n2 = 20.0, np.tan(np.deg2rad(30.0)), np.tan(np.deg2rad(120.0))
    idx = np.arange(-6, 7)
    offsets = np.vstack([idx * pitch, idx * pitch])
    I, J = np.meshgrid(idx, idx, indexing="ij")
    I, J = I.ravel(), J.ravel()
    ci, cj = I * pitch, J * pitch
    xy = np.column_stack([(ci - cj) / (n2 - n1), (n2 * ci - n1 * cj) / (n2 - n1)])
    A = np.array([[1.3, 0.2], [-0.1, 0.9]])
    q = xy @ A.T + np.array([600.0, 500.0])
    d1 = A @ np.array([1.0, n1])
    d2 = A @ np.array([1.0, n2])
    jdir = np.stack([np.tile(d1 / np.linalg.norm(d1), (len(q), 1)), np.tile(d2 / np.linalg.norm(d2), (len(q), 1))], axis=1)
    pos = {(i, j): k for k, (i, j) in enumerate(zip(I, J))}
    edges, fam, delta = [], [], []
    for (i, j), k in pos.items():
        if (i + 1, j) in pos:  # along a j-line (family 2), to the next i-line
            edges.append((k, pos[(i + 1, j)])); fam.append(2); delta.append((1, 0))
        if (i, j + 1) in pos:  # along an i-line (family 1), to the next j-line
            edges.append((k, pos[(i, j + 1)])); fam.append(1); delta.append((0, 1))
    obs = SimpleNamespace(q_junction=q, junction_dir=jdir, edges=np.array(edges), edge_family=np.array(fam, np.int8),
                          edge_delta=np.array(delta, np.int32))
    labels = np.column_stack([I, J]).astype(np.int32)
    got = across_line_scale(obs, labels, offsets, -6, n1, n2, UNLABELLED)
    # expected: a camera displacement across the family-f line, mapped back by A⁻¹, measured across the projector line
    Ai = np.linalg.inv(A)
    for f, (d, n) in enumerate(((d1, n1), (d2, n2))):
        nc = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        npj = np.array([-n, 1.0]) / np.hypot(1.0, n)
        assert got[f] == pytest.approx(abs(npj @ (Ai @ nc)), rel=1e-9)
    # unlabelled ends: not counted; too few edges: NaN
    labels[:, 0] = UNLABELLED
    s = across_line_scale(obs, labels, offsets, -6, n1, n2, UNLABELLED)
    assert np.isnan(s[0]) and s[1] == pytest.approx(got[1])


def test_a_row_is_judged_at_the_larger_of_the_frame_delta_and_its_own_offset():
    K = np.array([[1400.0, 0, 511.5], [0, 1400.0, 383.5], [0, 0, 1]])
    t = np.array([-200.0, 0.0, 0.0])
    n1 = 0.02  # nearly along the (horizontal) epipolar lines
    p = np.array([[10.0, 5.0, 900.0]] * 5)
    fam = np.array([1, 1, 1, 1, 0], np.int8)
    pe = predicted_error(K, t, np.full(5, n1), p, 1.0)[0]  # relative error per px
    lim = 0.5
    d_cut = lim / 100.0 / pe  # δ at which a row reaches the limit
    o = SheetPrecisionOptions(max_error_pct=lim)
    delta = 0.5 * d_cut
    assert not imprecise_samples(K, t, n1, 2.0, p, fam, delta, o).any()
    # the rows' samples: 0.99, 1.01 and 10 d_cut off one straight segment (the x axis; scale 1), one on it, a junction row
    off = np.array([0.99, 1.01, 10.0, 0.0]) * d_cut
    obs = _obs(np.column_stack([np.arange(4.0), off]), [1, 1, 1, 1], [0, 0, 0, 0], [-1] * 4, [[0.0, 0.0]], [[2.0, 0.0]],
               [[0.0, 0.0]], [[[1.0, 0.0], [0.0, 1.0]]])
    src = np.array([0, 1, 2, 3, -1])
    own = (src, obs.q, obs, np.array([1.0, 1.0]), 100.0)
    assert imprecise_samples(K, t, n1, 2.0, p, fam, delta, o, own).tolist() == [False, True, True, False, False]  # a junction: never
    np.testing.assert_allclose(own_offsets_px(src, obs.q, obs, np.array([1.0, 1.0])), np.r_[off, 0.0], rtol=1e-9, atol=1e-12)
    # the cap: an own offset counts at most cap px
    assert imprecise_samples(K, t, n1, 2.0, p, fam, delta, o, own[:4] + (0.9 * d_cut,)).tolist() == [False] * 5
    assert imprecise_samples(K, t, n1, 2.0, p, fam, delta, o, own[:4] + (1.05 * d_cut,)).tolist() == [False, True, True, False, False]
    # own offsets below δ change nothing
    assert imprecise_samples(K, t, n1, 2.0, p, fam, 1.01 * d_cut, o, own).tolist() == [True, True, True, True, False]
    assert not imprecise_samples(K, t, n1, 2.0, p, fam, delta, SheetPrecisionOptions(enabled=False), own).any()


@pytest.fixture(scope="module")
def scene_148():
    from benchmarks._common import render_scene
    from benchmarks.unseen import draw_scene
    from drivers.sim.presets import depth_range

    _rig, procam, scene, pattern, noise = draw_scene(148)
    image, truth = render_scene(procam, scene, pattern, noise_grey=noise, seed=148)
    return procam, pattern, image, truth, depth_range(procam, scene)


def test_unseen_148_own_offsets_leave_out_the_samples_pulled_off_their_lines(scene_148):
    from benchmarks._common import relative_errors
    from reconstruction.pipeline import ReconstructOptions, reconstruct

    from reconstruction.extraction import ExtractOptions

    procam, pattern, image, truth, dr = scene_148
    # decision 0151's case: the ridge centres as found (decision 0154's crossing pull, which removes most of
    # these samples' offsets at the source, off)
    o = ReconstructOptions(depth_min_mm=dr[0], depth_max_mm=dr[1], extract=ExtractOptions(crossing_pull=False))
    assert o.sheet_precision.own_offset
    off = reconstruct(image, procam, pattern, options=dataclasses.replace(o, sheet_precision=SheetPrecisionOptions(own_offset=False)))
    on = reconstruct(image, procam, pattern, options=o)
    e_off = relative_errors(off.points_proj, off.q_cam, truth)
    e_on = relative_errors(on.points_proj, on.q_cam, truth)
    assert np.percentile(e_off, 99) > 0.005  # the failure: frame δ (the 0.1 px floor) keeps them all
    assert off.stats["samples_imprecise"] == 0
    assert np.percentile(e_on, 99) <= 0.005
    assert np.mean(e_on > 0.01) <= np.mean(e_off > 0.01)
    # only samples are left out, and few (under 2 % of the points)
    assert (on.family == 0).sum() == (off.family == 0).sum()
    n_left = off.n_points - on.n_points
    assert on.stats["samples_imprecise"] == n_left > 0
    assert n_left < 0.02 * off.n_points
    # the left-out points (those of `off` whose pixel `on` lacks) are far worse than the kept ones of their family
    kept = {tuple(r) for r in np.round(on.q_cam, 3).tolist()}
    gone = np.array([tuple(r) not in kept for r in np.round(off.q_cam, 3).tolist()])
    assert gone.sum() == n_left
    fam_gone = np.bincount(off.family[gone], minlength=3)
    assert fam_gone[1] > 0.9 * n_left  # the i-lines, near the epipolar lines
    e_all = relative_errors(off.points_proj, off.q_cam, truth)
    assert np.median(e_all[gone]) > 3.0 * np.median(e_all[~gone & (off.family == 1)])


def test_the_small_scene_loses_only_a_few_samples_worse_than_the_rest(small_scene):
    from benchmarks._common import sample_bilinear
    from reconstruction.pipeline import ReconstructOptions, reconstruct

    s = small_scene
    o = ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])
    on = reconstruct(s.image, s.procam, s.pattern, options=o)
    off = reconstruct(s.image, s.procam, s.pattern, options=dataclasses.replace(o, sheet_precision=SheetPrecisionOptions(own_offset=False)))
    assert off.stats["samples_imprecise"] == 0
    n_left = off.n_points - on.n_points
    assert on.stats["samples_imprecise"] == n_left
    assert n_left <= 0.001 * off.n_points
    kept = {tuple(r) for r in np.round(on.q_cam, 3).tolist()}
    gone = np.array([tuple(r) not in kept for r in np.round(off.q_cam, 3).tolist()])
    assert gone.sum() == n_left
    pt = sample_bilinear(s.truth.p_proj, off.q_cam)
    e = np.linalg.norm(off.points_proj - pt, axis=1) / np.linalg.norm(pt, axis=1)
    for fam in (1, 2):
        g = gone & (off.family == fam)
        if g.any():
            assert np.nanmin(e[g]) > np.nanmedian(e[~gone & (off.family == fam)])
