"""Pieces the working volume alone labels (decision 0128, reconstruction.depth_range_labels): the stretch of a
camera ray inside the working volume against analytic geometry, the piece rule against pieces drawn on known light
sheets (right family and wrong family), and on the paper's parallel rig against the simulator's truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from benchmarks._common import bench_scenes, render_scene, sample_bilinear
from benchmarks.bench_extraction import line_coordinates
from reconstruction.depth_range_labels import index_stretch, piece_indices
from reconstruction.labelling import TraceOptions
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.rigmodel import rig_model


@pytest.fixture(scope="module")
def parallel_rig():
    sc = bench_scenes(["paper-parallel"], [], noise_grey=2.0)[0]
    return sc, rig_model(sc.procam, sc.pattern, sc.depth_range_mm)


def _line_points(sc, family: int, k: int, other: np.ndarray, normal: np.ndarray, z_cam: float):
    """Camera pixels (N, 2) of line k of `family` at the other family's fractional indices `other`, on the plane
    through the point of the line's middle ray at camera depth z_cam with projector-frame normal `normal`; and
    the points' camera depths (N,)."""
    procam, pat = sc.procam, sc.pattern
    kk = np.full(len(other), float(k))
    i, j = (kk, other) if family == 1 else (other, kk)
    xy = procam.projector.pixels_to_normalised(pat.junction_uv(i, j))
    rays = np.column_stack([xy, np.ones(len(xy))])
    r3 = procam.R_proj_cam[:, 2]
    m = len(rays) // 2
    mu = (z_cam + r3 @ procam.t_proj_cam) / (rays[m] @ r3)  # camera z = r3 · (p − t)
    p0 = mu * rays[m]
    lam = (normal @ p0) / (rays @ normal)
    p = lam[:, None] * rays
    p_cam = procam.proj_to_cam(p)
    return procam.camera.project(p_cam), p_cam[:, 2]


def test_stretch_holds_the_true_line_inside_the_volume_and_not_outside(parallel_rig):
    sc, model = parallel_rig
    rng = np.random.default_rng(1)
    lo_z, hi_z = sc.depth_range_mm
    for family in (1, 2):
        for _ in range(20):
            k = int(rng.integers(-10, 11))
            other = np.array([rng.uniform(-10, 10)])
            normal = np.array([0.0, 0.0, 1.0])
            z_in = rng.uniform(lo_z, hi_z)
            q, z = _line_points(sc, family, k, other, normal, z_in)
            lo, hi = index_stretch(model, q, np.array([family]), sc.depth_range_mm)
            assert lo[0] - 1e-6 <= k <= hi[0] + 1e-6, (family, k, z, lo, hi)
            for z_out in (lo_z * 0.97, hi_z * 1.03):
                q, z = _line_points(sc, family, k, other, normal, z_out)
                lo, hi = index_stretch(model, q, np.array([family]), sc.depth_range_mm)
                assert not (lo[0] <= k <= hi[0]), (family, k, z, lo, hi)
            # the stretch's ends are the lines' coordinates at the volume's limits
            for z_lim in (lo_z, hi_z):
                q, z = _line_points(sc, family, k, other, normal, z_lim)
                lo, hi = index_stretch(model, q, np.array([family]), sc.depth_range_mm)
                assert min(abs(lo[0] - k), abs(hi[0] - k)) < 1e-6


def test_pieces_on_known_sheets_right_family_labelled_right_wrong_family_never(parallel_rig):
    sc, model = parallel_rig
    rng = np.random.default_rng(2)
    lo_z, hi_z = sc.depth_range_mm
    n_right = n_labelled = 0
    for _ in range(300):
        family = int(rng.integers(1, 3))
        k = int(rng.integers(-12, 13))
        n = int(rng.integers(4, 40))
        o0 = rng.uniform(-12, 12)
        other = o0 + np.linspace(0, n / 40.0, n)  # up to one junction step
        normal = rng.normal(size=3) * 0.3 + np.array([0.0, 0.0, 1.0])
        q, z = _line_points(sc, family, k, other, normal, rng.uniform(lo_z, hi_z))
        if not (np.all(np.isfinite(q)) and np.all((z >= lo_z) & (z <= hi_z))):
            continue
        q = q + rng.normal(scale=0.05, size=q.shape)
        sid = np.arange(n)
        piece = np.zeros(n, np.intp)
        index = np.full(n, np.nan)
        ids, lab = piece_indices(model, q, np.full(n, family), sid, piece, index, sc.depth_range_mm)
        n_right += 1
        if len(ids):
            n_labelled += 1
            assert lab[0] == k, (family, k, lab)
        # the same samples given the other family: a piece of another line is never labelled
        ids, lab = piece_indices(model, q, np.full(n, 3 - family), sid, piece, index, sc.depth_range_mm)
        assert len(ids) == 0, (family, k, lab)
        # a piece with a labelled sample is left to the other steps
        index2 = index.copy()
        index2[0] = k
        assert len(piece_indices(model, q, np.full(n, family), sid, piece, index2, sc.depth_range_mm)[0]) == 0
    assert n_right > 100
    assert n_labelled > 10  # the rule does label on this rig (parallel: about one line per ray in the volume)


@pytest.fixture(scope="module")
def parallel_runs():
    sc = bench_scenes(["paper-parallel"], [], noise_grey=2.0)[0]
    image, truth = render_scene(sc.procam, sc.scene, sc.pattern, noise_grey=2.0, seed=0)
    runs = {}
    for on in (False, True):
        opts = ReconstructOptions(depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1],
                                  trace=replace(TraceOptions(), depth_range_labels=on))
        runs[on] = reconstruct(image, sc.procam, sc.pattern, options=opts)
    return sc, image, truth, runs


def test_parallel_rig_new_points_on_their_true_lines(parallel_runs):
    sc, image, truth, runs = parallel_runs
    off, on = runs[False], runs[True]
    assert off.stats["samples_depth_range"] == 0
    assert on.stats["samples_depth_range"] > 20
    known = {tuple(x) for x in np.round(off.q_cam, 3).tolist()}
    new = np.array([tuple(x) not in known for x in np.round(on.q_cam, 3).tolist()])
    assert new.sum() > 50
    c = line_coordinates(truth, sc.pattern)
    H, W = image.shape
    qi = np.clip(np.rint(on.q_cam[new]).astype(int), 0, [W - 1, H - 1])
    fam = on.family[new]
    lab = np.where(fam == 1, on.label[new, 0], on.label[new, 1])
    true_k = c[qi[:, 1], qi[:, 0], fam - 1]
    ok = np.isfinite(true_k)
    assert ok.mean() > 0.95
    assert np.all(np.abs(true_k[ok] - lab[ok]) < 0.5)  # every new point on the line whose index it carries
    p_true = sample_bilinear(truth.p_proj, on.q_cam, dtype=np.float32)
    rel = np.linalg.norm(on.points_proj - p_true, axis=1) / np.linalg.norm(p_true, axis=1) * 100
    rel_new = rel[new][np.isfinite(rel[new])]
    assert (rel_new > 1.0).sum() == 0
    assert np.percentile(rel[np.isfinite(rel)], 99) < 0.5


def test_parallel_rig_coverage_rises_and_option_turns_it_off(parallel_runs):
    from benchmarks._common import coverage_lines

    sc, image, truth, runs = parallel_runs
    cov_off = coverage_lines(truth, sc.pattern, runs[False].q_cam)
    cov_on = coverage_lines(truth, sc.pattern, runs[True].q_cam)
    assert cov_on > cov_off + 0.005


def test_compiled_pass_reproduces_numpy(parallel_rig):
    """Many pieces in one call (some labelled, some short, both families, right and wrong): the compiled path
    (`_k_piece_candidates`) gives the NumPy formulation's pieces and indices."""
    from reconstruction.depth_range_labels import piece_indices_numpy

    sc, model = parallel_rig
    rng = np.random.default_rng(3)
    lo_z, hi_z = sc.depth_range_mm
    qs, fams, pieces, index = [], [], [], []
    p = 0
    while p < 200:
        family = int(rng.integers(1, 3))
        n = int(rng.integers(2, 30))
        other = rng.uniform(-12, 12) + np.linspace(0, n / 40.0, n)
        normal = rng.normal(size=3) * 0.3 + np.array([0.0, 0.0, 1.0])
        q, z = _line_points(sc, family, int(rng.integers(-12, 13)), other, normal, rng.uniform(lo_z * 0.95, hi_z * 1.05))
        if not np.all(np.isfinite(q)):
            continue
        qs.append(q + rng.normal(scale=0.05, size=q.shape))
        fams.append(np.full(n, family if rng.random() < 0.8 else 3 - family))
        pieces.append(np.full(n, p))
        idx = np.full(n, np.nan)
        if rng.random() < 0.1:
            idx[0] = 0.0
        index.append(idx)
        p += 1
    q, fam, piece, index = map(np.concatenate, (qs, fams, pieces, index))
    sid = np.arange(len(q))
    for of in (True, False):
        for tol in (0.3, 1.0):
            a = piece_indices(model, q, fam, sid, piece, index, sc.depth_range_mm, tol_px=tol, other_family=of)
            b = piece_indices_numpy(model, q, fam, sid, piece, index, sc.depth_range_mm, tol_px=tol, other_family=of)
            assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert len(piece_indices(model, q, fam, sid, piece, index, sc.depth_range_mm, other_family=False)[0]) > 5


def test_paper_labeller_keeps_the_papers_method(parallel_runs):
    sc, image, truth, runs = parallel_runs
    opts = ReconstructOptions(labeller="paper", depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1])
    res = reconstruct(image, sc.procam, sc.pattern, options=opts)
    assert res.stats["samples_depth_range"] == 0
