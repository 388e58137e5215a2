"""Pinhole models: projection round trips with distortion, against OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at, rotation_from_euler_deg


@pytest.fixture
def cam() -> Intrinsics:
    return Intrinsics(1280, 1024, [[2300, 0, 641.3], [0, 2310, 505.2], [0, 0, 1]], [-0.12, 0.08, 0.0012, -0.0008, -0.01])


def test_project_matches_opencv(cam):
    rng = np.random.default_rng(1)
    p = np.column_stack([rng.uniform(-300, 300, 200), rng.uniform(-250, 250, 200), rng.uniform(700, 1500, 200)])
    ref = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.dist)[0].reshape(-1, 2)
    np.testing.assert_allclose(cam.project(p), ref, atol=1e-9)


def test_rays_invert_project(cam):
    q = cam.pixel_grid()[::997]
    rays = cam.rays(q)
    np.testing.assert_allclose(rays[:, 2], 1.0)
    np.testing.assert_allclose(cam.project(rays * 1234.5), q, atol=1e-6)


def test_points_behind_give_nan(cam):
    out = cam.project(np.array([[0, 0, -100.0], [0, 0, 100.0]]))
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all()


def test_pixel_centre_convention():
    m = Intrinsics(4, 3, [[10, 0, 1.5], [0, 10, 1.0], [0, 0, 1]])
    # The optical axis hits the image centre: (W-1)/2, (H-1)/2 in pixel-centre coordinates.
    np.testing.assert_allclose(m.project(np.array([[0, 0, 5.0]])), [[1.5, 1.0]])
    assert m.pixel_grid()[:5].tolist() == [[0, 0], [1, 0], [2, 0], [3, 0], [0, 1]]


def test_procam_frame_round_trip():
    R = rotation_from_euler_deg(10, -20, 5)
    pc = ProCam(Intrinsics(10, 10, np.eye(3)), Intrinsics(10, 10, np.eye(3)), R, [100, -50, 20])
    p_cam = np.array([[1.0, 2.0, 3.0], [0, 0, 0]])
    p_proj = pc.cam_to_proj(p_cam)
    np.testing.assert_allclose(p_proj[1], [100, -50, 20])  # the camera centre is t
    np.testing.assert_allclose(pc.proj_to_cam(p_proj), p_cam, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0)


def test_look_at_points_z_at_target():
    eye, target = np.array([300.0, -100, 0]), np.array([0.0, 50, 900])
    R = look_at(eye, target)
    z = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(R[:, 2], z)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert R[1, 1] > 0  # image y keeps pointing roughly down (world +y)
