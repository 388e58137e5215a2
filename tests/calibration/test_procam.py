"""Projector–camera calibration: the real Gray-code captures (kamino410), our convention, bad input."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest

from calibration.boards import Chessboard
from calibration.errors import CalibrationError
from calibration.file import load_calibration
from calibration.graycode import graycode_patterns
from calibration.models import Intrinsics, ProCam, look_at, rotation_from_euler_deg
from calibration.procam import ProcamView, calibrate_procam, calibrate_procam_dirs, load_pose, pose_image_paths

KAMINO_BOARD = Chessboard(9, 7, 75.0)


@pytest.fixture(scope="module")
def kamino_views(request):
    from tests.conftest import SHARED_DATA  # the shared_data fixture is function-scoped; same rule here

    d = SHARED_DATA / "procam_calibration_kamino410"
    if not d.is_dir():
        pytest.skip(f"real captures not found at {d} (clone the project beside ../shared to run this)")
    return [load_pose(d / f"capture_{i}", board=KAMINO_BOARD, projector_width=1024, projector_height=768) for i in range(5)]


@pytest.fixture(scope="module")
def kamino_result(kamino_views):
    return calibrate_procam(kamino_views, board=KAMINO_BOARD, projector_width=1024, projector_height=768)


@pytest.mark.shared_data
def test_kamino_all_five_poses_used(kamino_views, kamino_result):
    assert len(kamino_result.views) == 5
    assert all(len(v.ids) == 63 for v in kamino_views)
    assert sum(int(v.projector_ok.sum()) for v in kamino_views) >= 5 * 63 - 5


@pytest.mark.shared_data
def test_kamino_camera_matches_published(kamino_result):
    cam = kamino_result.procam.camera
    assert cam.fx == pytest.approx(3452.4, rel=0.005) and cam.fy == pytest.approx(3449.9, rel=0.005)
    assert abs(cam.cx - 587.2) < 5 and abs(cam.cy - 521.4) < 5


@pytest.mark.shared_data
def test_kamino_projector_and_pose_near_the_plain_solve(kamino_result):
    r = kamino_result
    proj = r.procam.projector
    assert r.stereo_rms_px <= 0.5
    assert proj.fx == pytest.approx(1890, rel=0.02) and proj.fy == pytest.approx(1890, rel=0.02)
    assert proj.cy > 768  # principal point below the image: lens shift
    assert r.rotation_deg == pytest.approx(3.6, abs=0.3)
    assert r.procam.baseline_mm == pytest.approx(680, rel=0.02)  # board units: square = "75"
    # the camera sits above the projector (t is the camera centre in the projector frame, y down)
    assert r.procam.t_proj_cam[1] < -500


@pytest.mark.shared_data
def test_kamino_convention_maps_camera_board_poses_into_the_projector(kamino_result):
    # p_proj = R p_cam + t: the camera's board pose moved by (R, t) must reproject onto the projector corners.
    r = kamino_result
    pc = r.procam
    for v, rvec, tvec in zip(r.views, r.camera.rvecs, r.camera.tvecs):
        P = KAMINO_BOARD.object_points_mm[v.ids]
        p_cam = P @ cv2.Rodrigues(rvec)[0].T + tvec
        q_proj = pc.projector.project(pc.cam_to_proj(p_cam))
        ok = v.projector_ok
        assert np.sqrt(np.mean(np.sum((q_proj[ok] - v.q_proj[ok]) ** 2, axis=1))) < 2.5


@pytest.mark.shared_data
def test_kamino_quality_block(kamino_result):
    q = kamino_result.quality()
    assert set(q) >= {"camera", "projector", "stereo_rms_px", "baseline_mm", "rotation_deg", "stereo_per_view_rms_px"}
    assert q["camera"]["views"] == 5 and len(q["camera"]["per_view_rms_px"]) == 5
    assert q["projector"]["std"]["fx"] > 0 and 0 < q["projector"]["coverage"] < 1
    assert q["camera"]["rms_px"] < 0.5 and q["projector"]["rms_px"] < 0.5


@pytest.mark.shared_data
def test_manifest_layout_reads_the_same_frames(shared_data, tmp_path):
    src = shared_data / "procam_calibration_kamino410" / "capture_0"
    order = np.random.default_rng(3).permutation(42)
    (tmp_path / "frames").mkdir()
    frames = []
    for k, pattern in enumerate(order):
        name = f"frames/{k:06d}.png"
        os.symlink(src / f"graycode_{pattern:02d}.png", tmp_path / name)
        frames.append({"file": name, "pattern": int(pattern)})
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "rig-capture", "frames": frames}))
    paths = pose_image_paths(tmp_path, n_patterns=42)
    assert [os.readlink(p) for p in paths] == [str(src / f"graycode_{i:02d}.png") for i in range(42)]


# --- synthetic observations (exact projections of a known rig) -----------------------------------------------

TRUTH = ProCam(
    Intrinsics(640, 480, [[900.0, 0, 330.0], [0, 905.0, 245.0], [0, 0, 1]], [-0.05, 0.02, 0, 0, 0]),
    Intrinsics(800, 600, [[1100.0, 0, 410.0], [0, 1100.0, 560.0], [0, 0, 1]], [0.01, 0, 0, 0, 0]),
    rotation_from_euler_deg(2.0, -8.0, 1.0),
    [180.0, -20.0, 15.0],
)
BOARD = Chessboard(9, 7, 50.0)


def _synthetic_views(rotations_deg, *, noise_px=0.05, seed=0):
    rng = np.random.default_rng(seed)
    centre = np.array([200.0, 150.0, 0.0])
    views = []
    for k, (rx, ry, rz) in enumerate(rotations_deg):
        R_cam_board = rotation_from_euler_deg(rx, ry, rz)
        t = np.array([-60.0 + 15 * (k % 3), -10.0 * (k % 2), 900.0 + 20 * k])
        p_cam = (BOARD.object_points_mm - centre) @ R_cam_board.T + t
        q_cam = TRUTH.camera.project(p_cam) + rng.normal(0, noise_px, (len(p_cam), 2))
        q_proj = TRUTH.projector.project(TRUTH.cam_to_proj(p_cam)) + rng.normal(0, noise_px, (len(p_cam), 2))
        views.append(ProcamView(f"pose{k}", np.arange(BOARD.n_corners), q_cam, q_proj, np.full(len(q_cam), 100), 640, 480, 0.6))
    return views


ROTS = [(20, 0, 0), (-20, 5, 0), (0, 25, 5), (5, -25, 0), (15, 15, 10), (-15, 15, -5), (15, -15, 0), (-15, -20, 5), (0, 0, 20), (25, 10, -10)]


def test_synthetic_recovery_and_convention():
    res = calibrate_procam(_synthetic_views(ROTS), board=BOARD, projector_width=800, projector_height=600)
    pc = res.procam
    assert pc.camera.fx == pytest.approx(900, rel=0.002) and pc.projector.fy == pytest.approx(1100, rel=0.002)
    assert abs(pc.projector.cy - 560) < 1.5
    dR = pc.R_proj_cam @ TRUTH.R_proj_cam.T
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(dR)[0])) < 0.05
    assert np.linalg.norm(pc.t_proj_cam - TRUTH.t_proj_cam) < 0.003 * TRUTH.baseline_mm
    assert res.stereo_rms_px < 0.1


def test_synthetic_joint_refinement_also_recovers():
    res = calibrate_procam(_synthetic_views(ROTS), board=BOARD, projector_width=800, projector_height=600, joint=True)
    assert np.linalg.norm(res.procam.t_proj_cam - TRUTH.t_proj_cam) < 0.003 * TRUTH.baseline_mm


def test_too_few_poses():
    with pytest.raises(CalibrationError, match="too few board poses: 2.*at least 3"):
        calibrate_procam(_synthetic_views(ROTS[:2]), board=BOARD, projector_width=800, projector_height=600)


def test_parallel_poses():
    with pytest.raises(CalibrationError, match="same orientation.*tilted"):
        calibrate_procam(_synthetic_views([(10, 5, 0)] * 6), board=BOARD, projector_width=800, projector_height=600)


def test_different_camera_sizes():
    views = _synthetic_views(ROTS[:4])
    v = views[2]
    views[2] = ProcamView(v.name, v.ids, v.q_cam, v.q_proj, v.samples, 1280, 960, v.valid_fraction)
    with pytest.raises(CalibrationError, match="pose2: camera image is 1280x960 but pose0 is 640x480"):
        calibrate_procam(views, board=BOARD, projector_width=800, projector_height=600)


def _write_pose(d, images):
    d.mkdir(parents=True)
    for i, im in enumerate(images):
        cv2.imwrite(str(d / f"graycode_{i:02d}.png"), im)
    return d


def test_pose_dirs_that_do_not_decode(tmp_path):
    flat = [np.full((48, 64), 128, np.uint8)] * 24
    dirs = [_write_pose(tmp_path / f"p{i}", flat) for i in range(3)]
    with pytest.raises(CalibrationError, match="p0: the Gray code does not decode"):
        calibrate_procam_dirs(dirs, board=Chessboard(4, 3, 10.0), projector_width=64, projector_height=32)


def test_pose_dirs_without_a_board(tmp_path):
    # The camera sees the patterns directly: decodes perfectly, but there is no board.
    dirs = [_write_pose(tmp_path / f"p{i}", graycode_patterns(64, 32)) for i in range(3)]
    with pytest.raises(CalibrationError, match="p0: the board was not found in the white image"):
        calibrate_procam_dirs(dirs, board=Chessboard(4, 3, 10.0), projector_width=64, projector_height=32)


def test_pose_dir_with_wrong_image_count_or_sizes(tmp_path):
    pats = graycode_patterns(64, 32)
    d = _write_pose(tmp_path / "short", pats[:-3])
    with pytest.raises(CalibrationError, match="holds 21 images.*needs 24.*--projector-size"):
        load_pose(d, board=Chessboard(4, 3, 10.0), projector_width=64, projector_height=32)
    d = _write_pose(tmp_path / "sizes", pats[:-1] + [np.zeros((10, 10), np.uint8)])
    with pytest.raises(CalibrationError, match="is 10x10 but graycode_00.png is 64x32"):
        load_pose(d, board=Chessboard(4, 3, 10.0), projector_width=64, projector_height=32)
    with pytest.raises(CalibrationError, match="too few board poses: 1 directories"):
        calibrate_procam_dirs([d], board=Chessboard(4, 3, 10.0), projector_width=64, projector_height=32)
