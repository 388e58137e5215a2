"""Calibration of the simulated rig: render a printed board under the Gray code, recover the known truth."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from calibration.boards import Chessboard
from calibration.file import CalibrationFile, load_calibration, save_calibration
from calibration.models import Intrinsics, ProCam, look_at
from calibration.procam import calibrate_procam, process_pose

pytest.importorskip("drivers.sim")

from drivers.sim import RenderOptions  # noqa: E402
from rig.calibrate_session import plan_board_poses, render_pose_images  # noqa: E402

# Small images keep the test fast: 640x512 camera, 512x384 projector with lens shift (principal point low).
TRUTH = ProCam(
    Intrinsics(640, 512, [[800.0, 0, 322.0], [0, 800.0, 259.0], [0, 0, 1]], [-0.05, 0.08, 0, 0, 0]),
    Intrinsics(512, 384, [[700.0, 0, 260.0], [0, 700.0, 350.0], [0, 0, 1]], [0.01, 0, 0, 0, 0]),
    look_at(np.array([200.0, -20.0, 10.0]), np.array([0.0, 0.0, 700.0])),
    [200.0, -20.0, 10.0],
)
BOARD = Chessboard(11, 8, 16.0)


@pytest.fixture(scope="module")
def sim_result():
    opts = RenderOptions(noise_grey=2.0, supersample=2)
    poses = plan_board_poses(TRUTH, BOARD, n_poses=12, seed=0)
    views = [
        process_pose(render_pose_images(TRUTH, BOARD, pose, options=opts, seed=k), board=BOARD, projector_width=512, projector_height=384, name=f"pose{k}")
        for k, pose in enumerate(poses)
    ]
    return calibrate_procam(views, board=BOARD, projector_width=512, projector_height=384)


def test_simulated_rig_is_recovered(sim_result):
    est = sim_result.procam
    assert sim_result.joint  # 12 poses: joint refinement by default
    for e, t in ((est.camera, TRUTH.camera), (est.projector, TRUTH.projector)):
        assert e.fx == pytest.approx(t.fx, rel=0.002) and e.fy == pytest.approx(t.fy, rel=0.002)
        assert abs(e.cx - t.cx) < 1.0 and abs(e.cy - t.cy) < 1.0
    dR = cv2.Rodrigues(est.R_proj_cam @ TRUTH.R_proj_cam.T)[0]
    assert np.degrees(np.linalg.norm(dR)) < 0.05
    assert np.linalg.norm(est.t_proj_cam - TRUTH.t_proj_cam) < 0.003 * TRUTH.baseline_mm
    assert sim_result.camera.rms_px <= 0.15
    assert sim_result.projector.rms_px <= 0.25
    assert all(v.projector_ok.all() for v in sim_result.views)


def test_simulated_quality_and_file_round_trip(sim_result, tmp_path):
    from calibration.procam import procam_calibration_file

    cal = procam_calibration_file(sim_result, board=BOARD, inputs=["sim"])
    save_calibration(cal, tmp_path / "c.json")
    back = load_calibration(tmp_path / "c.json")
    pc = back.to_procam()
    assert np.allclose(pc.R_proj_cam, sim_result.procam.R_proj_cam) and back.quality["baseline_mm"] == pytest.approx(TRUTH.baseline_mm, rel=0.003)
    assert back.quality["camera"]["views"] == 12 and back.provenance["joint_refinement"] is True


def test_guided_session_on_the_simulated_rig(tmp_path):
    # `rig calibrate --config rig.toml --out calibration.json --poses 4` on a rig built with TRUTH.
    truth_file = tmp_path / "truth.json"
    save_calibration(CalibrationFile.from_procam(TRUTH), truth_file)
    (tmp_path / "rig.toml").write_text('[sim]\nscene = "tabletop"\ntruth = "truth.json"\nnoise_grey = 2.0\n')
    from rig.cli import main

    out = tmp_path / "calibration.json"
    assert main(["calibrate", "--config", str(tmp_path / "rig.toml"), "--out", str(out), "--poses", "4"]) == 0
    cal = load_calibration(out)
    captures = sorted((tmp_path / "calibration_captures").iterdir())
    assert [c.name for c in captures] == ["pose_00", "pose_01", "pose_02", "pose_03"]
    manifest = json.loads((captures[0] / "manifest.json").read_text())
    assert manifest["complete"] and len(manifest["frames"]) == 2 * (9 + 9) + 2
    assert manifest["pattern"]["kind"] == "graycode"
    est = cal.to_procam()
    assert est.projector.fx == pytest.approx(700.0, rel=0.02)  # 4 poses: a rough, but right, answer
    assert est.baseline_mm == pytest.approx(TRUTH.baseline_mm, rel=0.03)
    assert cal.quality["camera"]["views"] == 4
