"""The compiled triangulation kernels (decision 0065) against the NumPy formulations they replace."""

from __future__ import annotations

import numpy as np

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.geometry import camera_rays_proj, triangulate_rays
from reconstruction.patterns import GridPattern
from reconstruction.rigmodel import rig_model

K_CAM = np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]])
K_PROJ = np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]])
PATTERN = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5))


def _procam(proj_dist) -> ProCam:
    t = np.array([180.0, 60.0, 40.0])
    cam = Intrinsics(640, 480, K_CAM, np.array([-0.05, 0.02, 0, 0, 0]))
    return ProCam(cam, Intrinsics(800, 600, K_PROJ, np.asarray(proj_dist, float)), look_at(t, np.array([0, 0, 800.0])), t)


def _samples(procam: ProCam, n: int, seed: int):
    """Camera points of line samples on a plane at z = 800 mm: family, integer index, normalised camera xy."""
    rng = np.random.default_rng(seed)
    fam = rng.integers(1, 3, n)
    idx = rng.integers(-12, 13, n)
    other = rng.uniform(-12, 12, n)
    i, j = np.where(fam == 1, idx, other), np.where(fam == 1, other, idx)
    xy_p = procam.projector.pixels_to_normalised(PATTERN.junction_uv(i, j))
    p = np.column_stack([xy_p * 800.0, np.full(n, 800.0)])
    pc = procam.proj_to_cam(p)
    return fam, idx, pc[:, :2] / pc[:, 2:], p


def test_light_sheet_kernel_equals_the_opencv_projection_path():
    # 8 coefficients with the rational ones zero: the same lens, but intersect_light_sheets takes the path that
    # projects with Intrinsics.project (OpenCV) between passes instead of the kernel's closed form.
    five = rig_model(_procam([0.08, -0.02, 0.001, -0.0005, 0.0]), PATTERN, (500.0, 1200.0))
    eight = rig_model(_procam([0.08, -0.02, 0.001, -0.0005, 0.0, 0.0, 0.0, 0.0]), PATTERN, (500.0, 1200.0))
    fam, idx, xy_c, p_true = _samples(five.procam, 2000, 1)
    for it in (0, 1, 2):
        a = five.intersect_light_sheets(xy_c, fam, idx, iterations=it)
        b = eight.intersect_light_sheets(xy_c, fam, idx, iterations=it)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    # and both find the true points (the sheets are curved by the projector's distortion)
    assert np.abs(five.intersect_light_sheets(xy_c, fam, idx) - p_true).max() < 0.01
    assert np.abs(five.intersect_light_sheets(xy_c, fam, idx, iterations=0) - p_true).max() > 0.05


def test_light_sheet_kernel_gives_nan_for_a_ray_inside_the_sheet():
    model = rig_model(_procam([0.0] * 5), PATTERN, (500.0, 1200.0))
    R, t = model.procam.R_proj_cam, model.procam.t_proj_cam
    N = model.sheet_end_normals[0, 12]  # family 1, index 0 (no projector distortion: the sheet is this plane)
    d = np.cross(N, t)  # a camera ray lying in the plane: it never crosses it
    w = R.T @ d
    w = w if w[2] > 0 else -w
    xy = (w[:2] / w[2])[None]
    assert np.isnan(model.intersect_light_sheets(xy, np.array([1]), np.array([0]))).all()
    # a ray that does cross it, in front of the camera, gives a point on the plane
    p = model.intersect_light_sheets(np.array([[0.01, -0.02]]), np.array([1]), np.array([0]))
    assert np.isfinite(p).all() and abs(p[0] @ N) < 1e-9 * np.linalg.norm(p)
    assert model.intersect_light_sheets(np.zeros((0, 2)), np.zeros(0, int), np.zeros(0, int)).shape == (0, 3)


def test_camera_table_lookup_uses_the_exact_inverse_outside_the_table():
    model = rig_model(_procam([0.0] * 5), PATTERN, (500.0, 1200.0))
    cam = model.procam.camera
    q = np.array([[-0.4, 10.0], [10.0, -0.3], [320.2, 240.7], [639.4, 479.4], [np.nan, 3.0]])
    got = model.cam_normalised(q)
    exact = cam.pixels_to_normalised(q[:4])
    np.testing.assert_allclose(got[[0, 1]], exact[[0, 1]], atol=1e-12)  # outside: exact
    assert np.abs(got[2:4] - exact[2:4]).max() * cam.fx < 0.005  # inside: the table
    assert np.isnan(got[4]).all()


def test_ray_triangulation_kernel_against_the_closed_form():
    procam = _procam([0.0] * 5)
    rng = np.random.default_rng(3)
    xy_c = rng.uniform(-0.3, 0.3, (200, 2))
    xy_p = rng.uniform(-0.3, 0.3, (200, 2))
    got, gap = triangulate_rays(procam, xy_c, xy_p)
    # the NumPy formulation (before the kernel): the 2×2 normal equations of the closest approach
    d = camera_rays_proj(procam, xy_c)
    e = np.column_stack([xy_p, np.ones(200)])
    t = procam.t_proj_cam
    A = np.stack([np.stack([np.sum(d * d, 1), -np.sum(d * e, 1)], 1), np.stack([np.sum(d * e, 1), -np.sum(e * e, 1)], 1)], 1)
    lam_mu = np.linalg.solve(A, np.stack([-(d @ t), -(e @ t)], 1)[..., None])[..., 0]
    pc = t + lam_mu[:, :1] * d
    pp = lam_mu[:, 1:] * e
    np.testing.assert_allclose(got, 0.5 * (pc + pp), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(gap, np.linalg.norm(pc - pp, axis=1), rtol=1e-9, atol=1e-9)
    # parallel rays: NaN
    d_axis = procam.R_proj_cam[:, 2]  # the camera's optical axis in the world frame
    par, g = triangulate_rays(procam, np.zeros((1, 2)), (d_axis[:2] / d_axis[2])[None])
    assert np.isnan(par).all() and np.isnan(g).all()


# --- the triangulate stage's frame kernel (pipeline._k_frame_points, decision 0071) ---------------------------


def _frame_inputs(procam: ProCam, seed: int):
    """Stand-ins for the extraction, labelling and sample-labelling results that `_triangulate` reads: line
    samples on a plane at 800 mm (working volume 500–1200 mm) and samples given a wrong line (most land
    outside the working volume), some without an index, some just outside the camera table (u < 0), some on one pixel (the later one must win), and
    labelled junctions at 800 mm."""
    from types import SimpleNamespace

    from reconstruction.rigmodel import UNLABELLED

    rng = np.random.default_rng(seed)
    fam, idx, xy_c, _ = _samples(procam, 1500, seed)
    fam2, idx2, xy_c2, _ = _samples(procam, 300, seed + 1)
    q = procam.camera.normalised_to_pixels(np.vstack([xy_c, xy_c2]))
    fam = np.concatenate([fam, fam2]).astype(np.int8)
    index = np.concatenate([idx, idx2 + 3]).astype(np.float64)  # +3: the wrong line, a point far off the plane
    index[rng.random(len(index)) < 0.1] = np.nan
    q[:5, 0] = -0.3 - rng.random(5)  # outside the camera table: the exact inverse
    q[10:14] = np.rint(q[10]) + rng.uniform(-0.2, 0.2, (4, 2))  # one pixel, four samples
    inside = (q[:, 0] < procam.camera.width - 1) & (q[:, 1] >= 0) & (q[:, 1] < procam.camera.height - 1)
    q, fam, index = q[inside], fam[inside], index[inside]
    n = len(q)
    ij = rng.integers(-10, 11, (40, 2))
    xy_pj = procam.projector.pixels_to_normalised(PATTERN.junction_uv(ij[:, 0].astype(float), ij[:, 1].astype(float)))
    pj = procam.proj_to_cam(np.column_stack([xy_pj * 800.0, np.full(40, 800.0)]))
    q_junction = procam.camera.normalised_to_pixels(pj[:, :2] / pj[:, 2:])
    labels = ij.astype(np.int64)
    labels[::7] = UNLABELLED
    residual = rng.random(40)
    junction = rng.integers(-1, 40, n)
    obs = SimpleNamespace(q=q, family=fam, q_junction=q_junction, segment_family=np.zeros(0, np.int8), edges=np.zeros((0, 2)),
                          stats={}, segment=np.full(n, -1), segment_centre=np.zeros((0, 2)), segment_dir=np.zeros((0, 2)),
                          segment_ends=np.zeros((0, 2), np.int64))
    lab = SimpleNamespace(labels=labels, residual=residual, stats={})
    sl = SimpleNamespace(index=index, q=q, junction=junction, stats={})
    return obs, lab, sl


def _frame_reference(model, obs, lab, sl, z_range, shape):
    """What the triangulate stage computes, in NumPy with the RigModel methods (the formulation before the
    frame kernel): junction rays, sample light sheets, the working volume, the depth map in point order."""
    from reconstruction.geometry import depth_cam
    from reconstruction.rigmodel import UNLABELLED

    procam = model.procam
    jl = np.flatnonzero(lab.labels[:, 0] != UNLABELLED)
    p_j, _ = triangulate_rays(procam, model.cam_normalised(obs.q_junction[jl]), model.junction_xy(*lab.labels[jl].T))
    ok = np.isfinite(sl.index)
    k = sl.index[ok].astype(np.intp)
    f = obs.family[ok]
    p_s = model.intersect_light_sheets(model.cam_normalised(sl.q[ok]), f, k)
    p = np.vstack([p_j, p_s])
    q = np.vstack([obs.q_junction[jl], sl.q[ok]])
    fam = np.concatenate([np.zeros(len(jl), np.int8), f])
    lab_out = np.vstack([lab.labels[jl], np.column_stack([np.where(f == 1, k, UNLABELLED), np.where(f == 2, k, UNLABELLED)])])
    res = np.concatenate([lab.residual[jl], lab.residual[np.maximum(sl.junction[ok], 0)]])
    z = depth_cam(procam, p)
    with np.errstate(invalid="ignore"):
        keep = np.isfinite(p).all(axis=1) & (z >= z_range[0]) & (z <= z_range[1])
    depth = np.full(shape, np.nan, np.float32)
    for (u, v), zz in zip(q[keep], z[keep]):  # in order: a later point overwrites an earlier one
        depth[min(max(int(np.rint(v)), 0), shape[0] - 1), min(max(int(np.rint(u)), 0), shape[1] - 1)] = zz
    return p[keep], q[keep], fam[keep], lab_out[keep], res[keep], depth, int(len(p) - keep.sum())


def _check_frame(model, seed):
    from reconstruction.pipeline import ReconstructOptions, _triangulate

    procam = model.procam
    obs, lab, sl = _frame_inputs(procam, seed)
    image = np.zeros((procam.camera.height, procam.camera.width), np.uint8)
    from reconstruction.sheet_precision import SheetPrecisionOptions

    # the kernel against the RigModel methods: decision 0131's step after it is off (the random residuals, up to
    # 1 px, would make it leave out samples the reference keeps)
    options = ReconstructOptions(depth_min_mm=500.0, depth_max_mm=1200.0, sheet_precision=SheetPrecisionOptions(enabled=False))
    got = _triangulate(image, obs, lab, sl, model, model.cam_normalised(obs.q_junction), options)
    p, q, fam, lab_out, res, depth, dropped = _frame_reference(model, obs, lab, sl, (500.0, 1200.0), image.shape)
    assert dropped > 50  # samples given a wrong line
    assert len(p) > 300
    np.testing.assert_array_equal(got.points_proj, p.astype(np.float32))
    np.testing.assert_array_equal(got.q_cam, q.astype(np.float32))
    np.testing.assert_array_equal(got.family, fam)
    np.testing.assert_array_equal(got.label, lab_out.astype(np.int32))
    np.testing.assert_array_equal(got.residual, res.astype(np.float32))
    assert (np.isnan(got.depth_cam) == np.isnan(depth)).all()
    np.testing.assert_allclose(got.depth_cam, depth, rtol=1e-6)  # NumPy's matmul may round z differently
    assert got.stats["points"] == len(p) and got.stats["points_dropped_out_of_range"] == dropped
    assert got.stats["points_junctions"] == int((fam == 0).sum()) > 20
    # and the samples with their true index are the true points: on the 800 mm plane
    assert (np.abs(got.points_proj[:, 2] - 800.0) < 0.5).sum() > 300


def test_frame_kernel_equals_the_rig_model_methods_with_both_distortions():
    _check_frame(rig_model(_procam([0.08, -0.02, 0.001, -0.0005, 0.0]), PATTERN, (500.0, 1200.0)), 5)


def test_frame_kernel_without_distortion_and_with_a_rational_projector_model():
    # no lens distortion at all: no camera table (the pinhole inverse in the kernel), no chord iteration
    t = np.array([180.0, 60.0, 40.0])
    plain = ProCam(Intrinsics(640, 480, K_CAM), Intrinsics(800, 600, K_PROJ), look_at(t, np.array([0, 0, 800.0])), t)
    model = rig_model(plain, PATTERN, (500.0, 1200.0))
    assert model.cam_xy_table is None and model.pixel_sheet_tables[0]
    _check_frame(model, 6)
    # 8 coefficients: the projector projects with OpenCV, the sample points come from intersect_light_sheets
    eight = rig_model(_procam([0.08, -0.02, 0.001, -0.0005, 0.0, 0.01, 0.0, 0.0]), PATTERN, (500.0, 1200.0))
    assert not eight.pixel_sheet_tables[0]
    _check_frame(eight, 7)


def test_segment_overlay_kernel_against_numpy():
    from types import SimpleNamespace

    from reconstruction.pipeline import _segment_overlay
    from reconstruction.rigmodel import UNLABELLED

    rng = np.random.default_rng(11)
    S, n = 60, 2000
    centre = rng.uniform(0, 600, (S, 2))
    ang = rng.uniform(0, np.pi, S)
    direction = np.column_stack([np.cos(ang), np.sin(ang)])
    segment = rng.integers(-1, S, n)
    segment[segment == 7] = -1  # a segment without samples
    segment[np.flatnonzero(segment == 9)[1:]] = -1  # one with a single sample
    q = centre[np.maximum(segment, 0)] + rng.uniform(-20, 20, (n, 1)) * direction[np.maximum(segment, 0)] + rng.normal(0, 0.3, (n, 2))
    ends = rng.integers(-1, 30, (S, 2))
    labels = np.where(rng.random((30, 1)) < 0.5, UNLABELLED, rng.integers(-5, 5, (30, 2)))
    obs = SimpleNamespace(q=q, segment=segment, segment_centre=centre, segment_dir=direction, segment_ends=ends,
                          segment_family=np.ones(S, np.int8))
    segs, seg_lab = _segment_overlay(obs, SimpleNamespace(labels=labels))
    s = np.einsum("ij,ij->i", q - centre[np.maximum(segment, 0)], direction[np.maximum(segment, 0)])
    smin = np.full(S, np.inf)
    smax = np.full(S, -np.inf)
    np.minimum.at(smin, segment[segment >= 0], s[segment >= 0])
    np.maximum.at(smax, segment[segment >= 0], s[segment >= 0])
    good = np.isfinite(smin) & (smax > smin)
    assert not good[7] and not good[9] and good.sum() > 50
    want = np.stack([centre + smin[:, None] * direction, centre + smax[:, None] * direction], axis=1)[good].astype(np.float32)
    np.testing.assert_array_equal(segs, want)
    labelled = labels[:, 0] != UNLABELLED
    np.testing.assert_array_equal(seg_lab, ((ends >= 0) & labelled[np.maximum(ends, 0)]).any(axis=1)[good])
