"""RigModel.sheet_check (decision 0078): one compiled call equal to the NumPy calls it replaces
(cam_normalised + intersect_light_sheets, geometry.depth_cam, continuation.project_nearest_line), and the
cached per-rig values equal to their formulas."""

from __future__ import annotations

import numpy as np

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.continuation import nearest_line, project_nearest_line
from reconstruction.geometry import depth_cam
from reconstruction.patterns import GridPattern
from reconstruction.rigmodel import rig_model

K_CAM = np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]])
K_PROJ = np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]])
PATTERN = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5))


def _procam(cam_dist, proj_dist) -> ProCam:
    t = np.array([180.0, 60.0, 40.0])
    cam = Intrinsics(640, 480, K_CAM, np.asarray(cam_dist, float))
    return ProCam(cam, Intrinsics(800, 600, K_PROJ, np.asarray(proj_dist, float)), look_at(t, np.array([0, 0, 800.0])), t)


def _pixels_on_plane(procam: ProCam, n: int, seed: int):
    """Camera pixels of true line points on a plane at z = 800 mm (projector frame), their family, index and points."""
    rng = np.random.default_rng(seed)
    fam = rng.integers(1, 3, n)
    idx = rng.integers(-12, 13, n)
    other = rng.uniform(-12, 12, n)
    i, j = np.where(fam == 1, idx, other), np.where(fam == 1, other, idx)
    xy_p = procam.projector.pixels_to_normalised(PATTERN.junction_uv(i, j))
    p = np.column_stack([xy_p * 800.0, np.full(n, 800.0)])
    q = procam.camera.project(procam.proj_to_cam(p))
    return q, fam, idx, p, other


def _reference(model, q, fam, idx):
    p = model.intersect_light_sheets(model.cam_normalised(q), fam, idx)
    k, d = project_nearest_line(model, 3 - fam, p)
    return p, depth_cam(model.procam, p), k, d


def test_sheet_check_equals_the_numpy_calls():
    for cam_dist, proj_dist in (([-0.05, 0.02, 0, 0, 0], [0.08, -0.02, 0.001, -0.0005, 0.0]),
                                ([-0.05, 0.02, 0, 0, 0], [0.0] * 5),
                                ([0.0] * 5, [0.08, -0.02, 0.001, -0.0005, 0.0]),  # no camera table: the NumPy path
                                ([-0.05, 0.02, 0, 0, 0], [0.08, -0.02, 0.001, -0.0005, 0, 0.01, 0, 0])):  # rational: NumPy
        model = rig_model(_procam(cam_dist, proj_dist), PATTERN, (500.0, 1200.0))
        q, fam, idx, p_true, other = _pixels_on_plane(model.procam, 3000, 3)
        # a wrong index for a third of them: the nearest line is then some other line, at some distance
        idx = idx + np.where(np.arange(len(idx)) % 3 == 0, 1, 0)
        got = model.sheet_check(q, fam, idx)
        ref = _reference(model, q, fam, idx)
        for a, b in zip(got[0:4:2], ref[0:4:2]):  # the points and the nearest lines: the same kernels
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(got[3], ref[3])
        # the depth: a plain sum in the kernel, NumPy's matmul (BLAS, may differ in the last bit) in depth_cam
        np.testing.assert_allclose(got[1], ref[1], rtol=1e-12, atol=0)
        # against truth where the index is right: the point, its depth, the crossing line of the other family
        ok = np.arange(len(idx)) % 3 != 0
        assert np.abs(got[0][ok] - p_true[ok]).max() < 0.01
        np.testing.assert_allclose(got[1][ok], model.procam.proj_to_cam(p_true[ok])[:, 2], atol=0.01)
        near = np.abs(other - np.rint(other)) < 0.3
        assert np.array_equal(got[2][ok & near], np.rint(other[ok & near]).astype(np.int64))


def test_sheet_check_outside_the_camera_table_and_empty():
    model = rig_model(_procam([-0.05, 0.02, 0, 0, 0], [0.08, -0.02, 0.001, -0.0005, 0.0]), PATTERN, (500.0, 1200.0))
    q, fam, idx, _, _ = _pixels_on_plane(model.procam, 200, 4)
    q[5] = (-30.0, 700.0)  # outside the table: the whole call takes the exact inverse
    got = model.sheet_check(q, fam, idx)
    ref = _reference(model, q, fam, idx)
    for a, b in zip(got, ref):  # the NumPy path itself
        np.testing.assert_array_equal(a, b)
    e = model.sheet_check(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64))
    assert [a.shape for a in e] == [(0, 3), (0,), (0,), (0,)]


def test_cached_rig_values_equal_their_formulas():
    model = rig_model(_procam([-0.05, 0.02, 0, 0, 0], [0.08, -0.02, 0.001, -0.0005, 0.0]), PATTERN, (500.0, 1200.0))
    p, n1, n2 = PATTERN.pitch_px, PATTERN.n1, PATTERN.n2
    step = min(np.hypot(1, n1), np.hypot(1, n2)) * p / abs(n2 - n1) * model.cam_per_proj_px
    assert model.junction_step_cam_px == step
    assert model.line_width_cam_px == PATTERN.line_width_px * model.cam_per_proj_px
    # the cached nearest-line tables give nearest_line's answer on projector pixels
    uv = np.random.default_rng(5).uniform((0, 0), (800, 600), (500, 2))
    fam = np.where(np.arange(500) % 2 == 0, 1, 2)
    k_ref, d_ref = nearest_line(model, fam, uv)
    xy = model.procam.projector.pixels_to_normalised(uv)
    k, d = project_nearest_line(model, fam, np.column_stack([xy * 700.0, np.full(500, 700.0)]))
    assert np.array_equal(k, k_ref)
    np.testing.assert_allclose(d, d_ref, atol=1e-6)
