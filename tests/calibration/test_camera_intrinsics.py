"""Camera intrinsics: real photographs (OpenCV's chessboard and ChArUco samples) and synthetic bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from calibration.boards import CharucoBoard, Chessboard, detect_charuco, detect_chessboard, read_image
from calibration.camera import calibrate_camera_images
from calibration.errors import CalibrationError
from calibration.file import load_calibration
from calibration.intrinsics import calibrate_intrinsics, check_same_size, find_outliers
from calibration.models import Intrinsics, rotation_from_euler_deg
from calibration.report import coverage_fraction, empty_regions

# OpenCV modules/python/test/test_calibration.py (square 1.0, flags 0)
K_OPENCV = np.array([[532.80992189, 0, 342.4952186], [0, 532.93346422, 233.8879292], [0, 0, 1]])
RMS_OPENCV = 0.196334638034


def _left_images(shared_data):
    d = shared_data / "opencv_samples_chessboard"
    return sorted(d.glob("left*.jpg"))


@pytest.mark.shared_data
def test_opencv_chessboard_photos_match_opencv_reference(shared_data):
    cal, res = calibrate_camera_images(_left_images(shared_data), board=Chessboard(9, 6, 1.0))
    assert len(res.names) == 13
    assert abs(res.rms_px - RMS_OPENCV) <= 0.02
    assert np.abs(res.intrinsics.K - K_OPENCV).sum() < 10.0  # OpenCV's own test: L1 norm < 10
    assert res.std["fx"] < 2.0 and res.std["cx"] < 2.0
    assert not cal.has_projector and cal.quality["camera"]["views"] == 13
    assert 0.3 < res.coverage < 0.8


@pytest.mark.shared_data
def test_left02_is_the_outlier_with_the_cpp_samples_refinement_window(shared_data):
    # The C++ sample refines with an 11x11 half-window (23x23 px) on ~35 px squares: left02's corners are
    # pulled off (1.18 px in left_intrinsics.yml). Our per-view diagnostic must single it out, and
    # --reject-outliers must drop exactly that view.
    board = Chessboard(9, 6, 25.0)
    files = _left_images(shared_data)
    views = [detect_chessboard(read_image(f), board=board, subpix_half_window_px=11, source=f.name) for f in files]
    P = [v.object_points_mm(board) for v in views]
    Q = [v.q_cam for v in views]
    names = [v.source for v in views]
    res = calibrate_intrinsics(P, Q, width=640, height=480, names=names)
    assert res.outliers == ("left02.jpg",)
    assert res.per_view_rms_px[names.index("left02.jpg")] == pytest.approx(1.18, abs=0.1)
    dropped = calibrate_intrinsics(P, Q, width=640, height=480, names=names, reject_outliers=True)
    assert dropped.rejected == ("left02.jpg",) and dropped.outliers == ()
    assert dropped.rms_px < 0.25 < res.rms_px


@pytest.mark.shared_data
def test_our_default_refinement_does_not_make_left02_an_outlier(shared_data):
    board = Chessboard(9, 6, 25.0)
    views = [detect_chessboard(read_image(f), board=board, source=f.name) for f in _left_images(shared_data)]
    res = calibrate_intrinsics([v.object_points_mm(board) for v in views], [v.q_cam for v in views], width=640, height=480,
                               names=[v.source for v in views])
    assert res.outliers == ()
    assert res.per_view_rms_px.max() < 0.3


@pytest.mark.shared_data
def test_charuco_marker_corners_match_opencv_gold(shared_data):
    d = shared_data / "opencv_contrib_charuco"
    gold = json.loads((d / "GOLD_marker_corners_from_opencv_test.json").read_text())["images"]
    board = CharucoBoard(5, 7, 40.0, 20.0, "DICT_6X6_250")
    for name, ref in gold.items():
        v = detect_charuco(read_image(d / name), board=board, source=name)
        assert v is not None
        assert set(v.markers) == {int(k) for k in ref["markers"]}
        for k, corners in ref["markers"].items():
            assert np.abs(v.markers[int(k)] - np.array(corners, float)).max() <= ref["tolerance_px"]


@pytest.mark.shared_data
def test_charuco_calibration(shared_data):
    d = shared_data / "opencv_contrib_charuco"
    cal, res = calibrate_camera_images(sorted(d.glob("img_0*.jpg")), board=CharucoBoard(5, 7, 40.0, 20.0))
    assert len(res.names) == 4
    assert res.rms_px <= 0.25
    # tutorial_camera_charuco.yml: fx 452.5, fy 456.8 (only 4 views: compare loosely)
    assert res.intrinsics.fx == pytest.approx(452.5, rel=0.03)
    assert res.intrinsics.fy == pytest.approx(456.8, rel=0.03)


@pytest.mark.shared_data
def test_cli_writes_camera_only_file(shared_data, tmp_path):
    from rig.cli import main

    out = tmp_path / "camera.json"
    files = [str(f) for f in _left_images(shared_data)]
    assert main(["calibrate", "camera", *files, "--board", "chessboard", "--cols", "9", "--rows", "6", "--square-mm", "25", "--out", str(out)]) == 0
    cal = load_calibration(out)
    assert not cal.has_projector
    assert cal.camera.width == 640 and abs(cal.quality["camera"]["rms_px"] - RMS_OPENCV) <= 0.02
    assert cal.provenance["board"] == {"kind": "chessboard", "cols": 9, "rows": 6, "square_mm": 25.0}
    assert len(cal.provenance["inputs"]) == 13


# --- synthetic views ------------------------------------------------------------------------------------------

TRUE_CAM = Intrinsics(800, 600, np.array([[700.0, 0, 410.0], [0, 702.0, 290.0], [0, 0, 1]]), np.array([-0.1, 0.05, 0, 0, 0]))
BOARD = Chessboard(9, 6, 20.0)


def _views(rotations_deg, *, noise_px=0.05, seed=0):
    rng = np.random.default_rng(seed)
    P = BOARD.object_points_mm - np.array([80.0, 50.0, 0.0])
    out_p, out_q = [], []
    for rx, ry, rz in rotations_deg:
        R = rotation_from_euler_deg(rx, ry, rz)
        p_cam = P @ R.T + np.array([0.0, 0.0, 500.0])
        q = TRUE_CAM.project(p_cam) + rng.normal(0, noise_px, (len(P), 2))
        out_p.append(BOARD.object_points_mm)
        out_q.append(q)
    return out_p, out_q


def test_synthetic_views_recover_the_camera():
    rots = [(20, 0, 0), (-20, 0, 5), (0, 25, 0), (0, -25, -5), (15, 15, 10), (-15, 15, 0), (15, -15, -10), (-15, -20, 3)]
    P, Q = _views(rots)
    res = calibrate_intrinsics(P, Q, width=800, height=600)
    assert res.intrinsics.fx == pytest.approx(700.0, rel=0.01)
    assert res.intrinsics.cx == pytest.approx(410.0, abs=3.0)
    assert res.rms_px == pytest.approx(0.05 * np.sqrt(2) * np.sqrt(1 - 15 / (2 * 54 * 8)), rel=0.25)


def test_parallel_poses_are_refused_with_advice():
    P, Q = _views([(0, 0, 0)] * 6)
    with pytest.raises(CalibrationError, match="same orientation.*tilted"):
        calibrate_intrinsics(P, Q, width=800, height=600)


def test_too_few_views_are_refused():
    P, Q = _views([(20, 0, 0), (0, 20, 0)])
    with pytest.raises(CalibrationError, match="too few usable views.*need at least 3"):
        calibrate_intrinsics(P, Q, width=800, height=600)


def test_images_of_different_sizes_are_refused():
    with pytest.raises(CalibrationError, match="b.png: camera image is 640x480 but a.png is 800x600"):
        check_same_size([(800, 600), (640, 480)], ["a.png", "b.png"])


def test_board_not_found_says_what_to_check(tmp_path):
    files = []
    for i in range(4):
        f = tmp_path / f"blank{i}.png"
        cv2.imwrite(str(f), np.full((120, 160), 128, np.uint8))
        files.append(f)
    with pytest.raises(CalibrationError, match="found in only 0 of 4 images.*INNER corners"):
        calibrate_camera_images(files, board=BOARD)


def test_find_outliers():
    assert find_outliers(np.array([0.2, 0.21, 1.2, 0.19, 0.22])).tolist() == [2]
    assert find_outliers(np.array([0.02, 0.021, 0.07, 0.019])).tolist() == []  # below the 0.1 px floor
    assert find_outliers(np.array([0.2, 0.5, 0.19, 0.22])).tolist() == []  # 0.5 < 3 x median


def test_coverage_and_empty_regions():
    q = [np.array([[0, 0], [399, 0], [399, 299], [0, 299]], float)]  # top-left quarter of 800x600
    assert coverage_fraction(q, width=800, height=600) == pytest.approx(0.25, abs=0.03)
    regions = empty_regions(q, width=800, height=600)
    assert "top left" not in regions and "bottom right" in regions and "top right" in regions
