"""The dense Gray-code mode (reconstruction/graycode_depth.py): analytic plane, simulator, real captures."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.errors import ReconstructionError
from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.graycode_depth import (
    GrayCodeOptions,
    graycode_frame_count,
    graycode_scan_patterns,
    light_plane_normals,
    plane_family,
    reconstruct_graycode,
)

METHODS = ("rays", "planes")


# --- an analytic plane, images made by nearest-pixel lookup of the patterns ----------------------------------
def _plane_rig() -> ProCam:
    cam = Intrinsics(200, 150, [[260, 0, 99.5], [0, 260, 74.5], [0, 0, 1]])
    proj = Intrinsics(128, 96, [[150, 0, 63.5], [0, 150, 47.5], [0, 0, 1]], [0.05, -0.02, 0, 0, 0])
    eye = np.array([120.0, 10.0, 0.0])
    return ProCam(cam, proj, look_at(eye, np.array([0.0, 0.0, 500.0])), eye)


def _plane_scan(pc: ProCam, *, z_mm: float = 500.0, tilt: float = 0.2):
    """Camera images of the Gray code on the plane z = z_mm + tilt·x (world frame), and per-pixel truth."""
    cam, proj = pc.camera, pc.projector
    d = cam.rays(cam.pixel_grid()) @ pc.R_proj_cam.T
    t = pc.t_proj_cam
    lam = (z_mm + tilt * t[0] - t[2]) / (d[:, 2] - tilt * d[:, 0])
    p_true = t + lam[:, None] * d
    q_proj = proj.project(p_true)
    inside = (q_proj[:, 0] > -0.5) & (q_proj[:, 0] < proj.width - 0.5) & (q_proj[:, 1] > -0.5) & (q_proj[:, 1] < proj.height - 0.5)
    u = np.clip(np.rint(q_proj[:, 0]), 0, proj.width - 1).astype(int)
    v = np.clip(np.rint(q_proj[:, 1]), 0, proj.height - 1).astype(int)
    images = []
    for pat in graycode_scan_patterns(proj.width, proj.height):
        lit = np.where(inside, pat[v, u], 0).astype(np.float64)
        images.append((20 + 0.8 * lit).reshape(cam.height, cam.width).astype(np.uint8))
    return images, p_true.reshape(cam.height, cam.width, 3), q_proj.reshape(cam.height, cam.width, 2), inside.reshape(cam.height, cam.width)


@pytest.mark.parametrize("method", METHODS)
def test_analytic_plane(method):
    pc = _plane_rig()
    images, p_true, q_true, inside = _plane_scan(pc)
    assert len(images) == graycode_frame_count(128, 96) == 2 * (7 + 7) + 2
    r = reconstruct_graycode(images, pc, options=GrayCodeOptions(method=method, depth_min_mm=300, depth_max_mm=900))
    q = r.q_cam.astype(int)
    # Coverage: every pixel the projector lights, except those next to the projector's border.
    assert r.n_points >= 0.97 * inside.sum(), (r.n_points, inside.sum())
    assert r.stats["points"] == r.n_points and not r.warnings
    # The decoded projector pixel is the one that lit the camera pixel.
    np.testing.assert_array_equal(r.label, np.rint(q_true[q[:, 1], q[:, 0]]).astype(int))
    # Accuracy: the only error is the ±½ projector-pixel quantisation. Projected back into the projector,
    # each point is within ½ px (per axis) of where the camera pixel's true surface point projects.
    err_px = np.abs(pc.projector.project(r.points_proj.astype(np.float64)) - q_true[q[:, 1], q[:, 0]])
    limit = 0.5 if method == "planes" else 0.75  # rays: the midpoint also moves by the other coordinate's error
    assert np.percentile(err_px.max(axis=1), 99.9) < limit + 0.02
    # In 3-D: ½ projector px of disparity is about ½·range/(f_proj·baseline) of the range (1.4 % here: the
    # projector is coarse); the errors spread uniformly up to that, so their median is half of it.
    truth = p_true[q[:, 1], q[:, 0]]
    rng_mm = np.linalg.norm(truth, axis=1)
    rel = np.linalg.norm(r.points_proj - truth, axis=1) / rng_mm
    bound = 0.5 * rng_mm / (pc.projector.fx * pc.baseline_mm)
    assert np.median(rel / bound) < 0.6 and np.max(rel / bound) < 1.3
    # The range map holds the camera-frame z of the same points.
    z = r.depth_cam[q[:, 1], q[:, 0]]
    np.testing.assert_allclose(z, pc.proj_to_cam(r.points_proj.astype(np.float64))[:, 2], rtol=1e-5)
    assert np.isnan(r.depth_cam[~inside]).all()


def test_light_planes_contain_the_projector_rays():
    pc = _plane_rig()
    proj = pc.projector
    q = np.array([[10.0, 5.0], [63.0, 47.0], [120.0, 90.0]])
    for family, along in (("columns", np.array([0.0, 1.0])), ("rows", np.array([1.0, 0.0]))):
        n = light_plane_normals(proj, q, family=family)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        for s in (-1.0, 0.0, 1.0):  # rays of neighbouring pixels of the same column / row
            ray = proj.rays(q + s * along)
            ray /= np.linalg.norm(ray, axis=1, keepdims=True)
            assert np.abs(np.einsum("ij,ij->i", n, ray)).max() < 1e-5
    assert plane_family(pc) == "columns"
    above = ProCam(pc.camera, proj, np.eye(3), [20.0, -300.0, 0.0])
    assert plane_family(above) == "rows"


def test_inputs_that_do_not_fit_are_refused():
    pc = _plane_rig()
    images, *_ = _plane_scan(pc)
    with pytest.raises(ReconstructionError, match="has 30 frames, got 29"):
        reconstruct_graycode(images[:-1], pc)
    small = [im[:-1] for im in images]
    with pytest.raises(ReconstructionError, match="frame 0 is 200x149 but the calibration's camera is 200x150"):
        reconstruct_graycode(small, pc)
    with pytest.raises(ValueError, match="method"):
        GrayCodeOptions(method="columns")


def test_dark_scan_gives_an_empty_result_with_a_warning():
    pc = _plane_rig()
    images = [np.full((150, 200), 12, np.uint8) for _ in range(30)]
    r = reconstruct_graycode(images, pc)
    assert r.n_points == 0 and np.isnan(r.depth_cam).all()
    assert r.warnings and "no camera pixel decoded" in r.warnings[0]


# --- the simulator ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def sim_scan():
    from drivers.sim import RenderOptions, SimWorld, preset

    rig = preset("paper-intermediate")
    world = SimWorld(rig, options=RenderOptions(noise_grey=1.0), seed=3)
    proj = rig.procam.projector
    images = [world.render(p) for p in graycode_scan_patterns(proj.width, proj.height)]
    return rig, world.truth, images


@pytest.mark.parametrize("method", METHODS)
def test_simulated_scene_matches_truth(sim_scan, method):
    rig, truth, images = sim_scan
    lo, hi = rig.depth_range_mm
    r = reconstruct_graycode(images, rig.procam, options=GrayCodeOptions(method=method, depth_min_mm=lo, depth_max_mm=hi))
    q = r.q_cam.astype(int)
    p_true = truth.p_proj[q[:, 1], q[:, 0]].astype(np.float64)
    ok = np.all(np.isfinite(p_true), axis=1)
    assert ok.mean() > 0.999, "points only where the camera sees a surface"
    rel = np.linalg.norm(r.points_proj[ok] - p_true[ok], axis=1) / np.linalg.norm(p_true[ok], axis=1)
    assert np.median(rel) < 2e-3, np.median(rel)
    assert np.percentile(rel, 99) < 1e-2, np.percentile(rel, 99)
    # Coverage: most of what the projector lights and the camera sees.
    assert r.n_points > 0.85 * truth.lit.sum(), (r.n_points, int(truth.lit.sum()))
    # Decoded projector pixels agree with the simulator's.
    q_true = truth.q_proj[q[:, 1], q[:, 0]]
    good = np.all(np.isfinite(q_true), axis=1)
    assert np.mean(np.abs(r.label[good] - q_true[good]).max(axis=1) <= 1.0) > 0.99


def test_result_goes_into_recordings_and_ply(sim_scan, tmp_path):
    """The scan loop's outputs take the Gray-code result unchanged (rig.log_reconstruction, write_ply)."""
    import rerun as rr
    from plyfile import PlyData

    from reconstruction.io import write_ply
    from rig.log_reconstruction import log_reconstruction

    rig, _truth, images = sim_scan
    r = reconstruct_graycode(images, rig.procam)
    write_ply(tmp_path / "gc.ply", r.points_proj)
    assert PlyData.read(str(tmp_path / "gc.ply"))["vertex"].count == r.n_points
    rec = rr.RecordingStream("test-graycode")
    rec.save(str(tmp_path / "gc.rrd"))
    with rec:
        rec.set_time("frame", sequence=0)
        log_reconstruction(rec, r)
    assert (tmp_path / "gc.rrd").stat().st_size > 100_000


# --- the real captures -----------------------------------------------------------------------------------------
# Calibration of the kamino410 rig by calibration.procam.calibrate_procam on all five poses (stereo RMS 0.30 px;
# lengths in the board's units, square = "75"), and capture_0's board pose from the same camera solve. Fixed
# here so that this test checks the dense decoding and triangulation, not the calibration.
KAMINO_CAM = Intrinsics(
    1280, 1024, [[3452.4667, 0, 586.5335], [0, 3451.5526, 522.2509], [0, 0, 1]],
    [-0.2202504, -1.9577461, -0.0009399, -0.0016435, 44.7651700],
)
KAMINO_PROJ = Intrinsics(
    1024, 768, [[1897.3108, 0, 484.1013], [0, 1896.3125, 833.9979], [0, 0, 1]],
    [-0.1354317, 0.3731286, 0.0002970, -0.0055718, -0.9351132],
)
KAMINO_R = [[0.9981125757, 0.016026668, -0.0592826463], [-0.0159022717, 0.9998702491, 0.0025695756],
            [0.059316136, -0.001621997, 0.9982379301]]
KAMINO_T = [93.9755031884, -628.4566266128, -231.7819171861]
KAMINO_BOARD0_RVEC = np.array([-0.1260278535, 0.0572535875, 0.0092657892])
KAMINO_BOARD0_TVEC = np.array([-282.8161882903, -269.0610651382, 3688.826964119])


@pytest.mark.shared_data
@pytest.mark.parametrize("method", METHODS)
def test_real_graycode_capture_decodes_onto_the_board_plane(shared_data, method):
    d = shared_data / "procam_calibration_kamino410" / "capture_0"
    images = [cv2.imread(str(d / f"graycode_{k:02d}.png"), cv2.IMREAD_UNCHANGED) for k in range(42)]
    assert all(im is not None for im in images), f"unreadable captures in {d}"
    pc = ProCam(KAMINO_CAM, KAMINO_PROJ, KAMINO_R, KAMINO_T)
    r = reconstruct_graycode(images, pc, options=GrayCodeOptions(method=method))
    assert r.stats["decoded"] > 0.6 * r.stats["pixels"], r.stats
    assert r.n_points > 0.95 * r.stats["decoded"], r.stats
    # Decoded codes span the projector as the capture's REFERENCE.md describes (rows up to 767).
    assert r.label[:, 1].max() == 767 and r.label[:, 0].min() < 100 and r.label[:, 0].max() > 800
    # Points on the printed board (inside its 9x7 inner corners, located by the camera-only solve) lie on
    # the board's plane: an independent reference for the dense range map.
    obj = np.array([[x * 75.0, y * 75.0, 0.0] for y in range(7) for x in range(9)])
    corners = cv2.projectPoints(obj, KAMINO_BOARD0_RVEC, KAMINO_BOARD0_TVEC, KAMINO_CAM.K, KAMINO_CAM.dist)[0]
    hull = cv2.convexHull(corners.reshape(-1, 2).astype(np.float32))
    mask = np.zeros((1024, 1280), np.uint8)
    cv2.fillConvexPoly(mask, np.rint(hull.reshape(-1, 2)).astype(np.int32), 1)
    q = r.q_cam.astype(int)
    on_board = mask[q[:, 1], q[:, 0]] > 0
    assert on_board.sum() > 100_000
    p_cam = pc.proj_to_cam(r.points_proj[on_board].astype(np.float64))
    normal = cv2.Rodrigues(KAMINO_BOARD0_RVEC)[0][:, 2]
    dist = (p_cam - KAMINO_BOARD0_TVEC) @ normal
    depth = float(np.median(p_cam[:, 2]))
    assert np.median(np.abs(dist)) < 1.5e-3 * depth, (np.median(np.abs(dist)), depth)
    assert abs(float(np.mean(dist))) < 0.5e-3 * depth
