"""Epipolar lines, the paper's Eq. 3, the 2x2 base-point system, triangulation round trips."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.geometry import (
    camera_rays_proj,
    depth_cam,
    epipolar_lines,
    intersect_planes,
    paper_epipolar_mb,
    triangulate_rays,
)
from reconstruction.labelling import solve_base_point


def _procam(distorted: bool = True) -> ProCam:
    dc = np.array([-0.08, 0.05, 0.001, -0.0005, 0]) if distorted else np.zeros(5)
    dp = np.array([0.04, -0.01, 0, 0, 0]) if distorted else np.zeros(5)
    cam = Intrinsics(758, 570, np.array([[2368.0, 0, 378.5], [0, 2375.0, 284.5], [0, 0, 1]]), dc)
    prj = Intrinsics(1024, 1024, np.array([[1248.0, 0, 511.5], [0, 1248.0, 511.5], [0, 0, 1]]), dp)
    t = np.array([700.0, 1400.0, 100.0])
    return ProCam(cam, prj, look_at(t, np.array([0.0, 0.0, 3000.0])), t)


def _world_points(rng, n=200):
    return np.column_stack([rng.uniform(-600, 600, n), rng.uniform(-600, 600, n), rng.uniform(2500, 3300, n)])


def test_projector_point_lies_on_the_epipolar_line_of_its_camera_pixel_with_distortion():
    rig = _procam()
    rng = np.random.default_rng(1)
    p = _world_points(rng)
    q_cam = rig.camera.project(rig.proj_to_cam(p))
    q_proj = rig.projector.project(p)
    lines = epipolar_lines(rig, rig.camera.pixels_to_normalised(q_cam))
    xy_p = rig.projector.pixels_to_normalised(q_proj)
    d_px = np.abs(np.einsum("ij,ij->i", lines[:, :2], xy_p) + lines[:, 2]) * rig.projector.fx
    assert d_px.max() < 1e-6
    # Random projector points are not on it.
    d_wrong = np.abs(np.einsum("ij,ij->i", lines[:, :2], xy_p[::-1]) + lines[:, 2]) * rig.projector.fx
    assert np.median(d_wrong) > 10


def test_paper_eq3_slope_and_intercept_describe_the_same_line():
    rig = _procam(distorted=False)
    rng = np.random.default_rng(2)
    p = _world_points(rng)
    xy_c = rig.proj_to_cam(p)
    xy_c = xy_c[:, :2] / xy_c[:, 2:]
    m, b = paper_epipolar_mb(rig, xy_c)
    xy_p = p[:, :2] / p[:, 2:]
    np.testing.assert_allclose(xy_p[:, 1], m * xy_p[:, 0] + b, atol=1e-9)


def test_closest_approach_triangulation_round_trip_and_gap():
    rig = _procam()
    rng = np.random.default_rng(3)
    p = _world_points(rng)
    pc = rig.proj_to_cam(p)
    xy_c = pc[:, :2] / pc[:, 2:]
    xy_p = p[:, :2] / p[:, 2:]
    got, gap = triangulate_rays(rig, xy_c, xy_p)
    np.testing.assert_allclose(got, p, atol=1e-6)
    assert gap.max() < 1e-6
    # Skewed rays: the midpoint lies half way, the gap is the distance between the rays.
    got2, gap2 = triangulate_rays(rig, xy_c, xy_p + np.array([1e-4, 0.0]))
    assert np.all(gap2 > 0.01) and np.all(np.linalg.norm(got2 - p, axis=1) < 2.0)
    np.testing.assert_allclose(depth_cam(rig, p), pc[:, 2], rtol=1e-12)


def test_ray_plane_intersection_round_trip():
    rig = _procam()
    rng = np.random.default_rng(4)
    p = _world_points(rng)
    pc = rig.proj_to_cam(p)
    xy_c = pc[:, :2] / pc[:, 2:]
    # Any plane through the projector centre and p: normal ⟂ p.
    a = rng.normal(size=(len(p), 3))
    normals = np.cross(p, a)
    got = intersect_planes(rig, xy_c, normals)
    np.testing.assert_allclose(got, p, atol=1e-6)
    # A ray parallel to its plane gives NaN, not a point at infinity.
    d = camera_rays_proj(rig, xy_c[:1])
    par = np.cross(d[0], rig.t_proj_cam)[None]
    assert np.isnan(intersect_planes(rig, xy_c[:1], par)).all()


@pytest.mark.parametrize("seed", range(5))
def test_two_by_two_base_point_matches_a_brute_force_minimiser(seed):
    rng = np.random.default_rng(seed)
    m = rng.uniform(-3, 3, size=(1, 3))
    b = rng.uniform(-100, 100, size=(1, 3))
    h = rng.uniform(-20, 20, size=3)
    h[0] = 0
    v = rng.uniform(-20, 20, size=3)
    v[0] = 0

    def omega(x):
        x0, y0 = x
        return sum((b[0, k] + m[0, k] * (x0 + h[k]) - (y0 + v[k])) ** 2 / (m[0, k] ** 2 + 1) for k in range(3))

    got = solve_base_point(m, b, h, v)[0]
    ref = minimize(omega, x0=np.zeros(2), method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-14, "maxiter": 20000}).x
    np.testing.assert_allclose(got, ref, atol=1e-5)
    assert omega(got) <= omega(ref) + 1e-9


def test_base_point_is_exact_when_the_triangle_sits_on_its_lines():
    # A triangle with base (x0, y0); lines through each vertex with arbitrary slopes.
    x0, y0 = 12.5, -40.0
    h = np.array([0.0, 13.0, 0.0])
    v = np.array([0.0, -22.5, 30.0])
    m = np.array([[0.3, -1.7, 4.0]])
    b = (y0 + v) - m * (x0 + h)
    np.testing.assert_allclose(solve_base_point(m, b, h, v)[0], [x0, y0], atol=1e-9)


def test_light_sheet_intersection_round_trip_with_projector_distortion():
    # Points on pattern lines, seen through a distorted projector: the camera ray meets the (curved) sheet
    # of light of the line where the point is, not only the chord plane through the line's ends.
    from calibration.models import look_at
    from reconstruction.patterns import GridPattern
    from reconstruction.rigmodel import rig_model

    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.array([-0.05, 0.02, 0, 0, 0]))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]), np.array([0.08, 0, 0, 0, 0]))
    t = np.array([180.0, 60.0, 40.0])
    procam = ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t)
    for spacing in ("uniform", "debruijn"):
        pattern = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5), spacing=spacing)
        model = rig_model(procam, pattern, (500.0, 1200.0))
        rng = np.random.default_rng(1)
        fam = rng.integers(1, 3, 200)
        idx = rng.integers(-12, 13, 200)
        other = rng.uniform(-12, 12, 200)
        i = np.where(fam == 1, idx, other)
        j = np.where(fam == 1, other, idx)
        xy_p = prj.pixels_to_normalised(pattern.junction_uv(i, j))
        z = rng.uniform(600, 1100, 200)
        p = np.column_stack([xy_p * z[:, None], z])
        p_cam = procam.proj_to_cam(p)
        xy_c = p_cam[:, :2] / p_cam[:, 2:3]
        got = model.intersect_light_sheets(xy_c, fam, idx)
        err = np.linalg.norm(got - p, axis=1)
        assert np.max(err) < 0.01, (spacing, np.max(err))
        # The chord plane through the line's ends alone is visibly off with this much distortion.
        chord = model.intersect_light_sheets(xy_c, fam, idx, iterations=0)
        assert np.max(np.linalg.norm(chord - p, axis=1)) > 0.1


def test_camera_undistortion_table_matches_the_exact_inverse():
    # RigModel.cam_normalised interpolates a per-rig table; it must agree with Intrinsics.pixels_to_normalised
    # to far below the line-centre noise, everywhere in the image (corners included) and outside it.
    from calibration.models import look_at
    from reconstruction.patterns import GridPattern
    from reconstruction.rigmodel import rig_model

    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.array([-0.2, 0.1, 0.001, -0.001, 0]))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]))
    t = np.array([180.0, 60.0, 40.0])
    procam = ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t)
    model = rig_model(procam, GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5)), (500.0, 1200.0))
    rng = np.random.default_rng(3)
    q = np.vstack([rng.uniform([0, 0], [639, 479], (5000, 2)), [[0, 0], [639, 479], [0, 479], [639, 0], [-3, 5], [700, 20]]])
    err_px = np.abs(model.cam_normalised(q) - cam.pixels_to_normalised(q)).max() * cam.fx
    assert err_px < 5e-3, err_px  # k1 = -0.2 is strong; the line-centre noise is ~0.05 px
