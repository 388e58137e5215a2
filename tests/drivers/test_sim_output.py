"""write_simulation and `rig simulate`: a case on disk that reproduces without the simulator."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from calibration.file import load_calibration
from calibration.models import Intrinsics, ProCam
from drivers.sim import RenderOptions, SimWorld, Truth, preset, write_simulation
from reconstruction.patterns import GridPattern
from rig.cli import main
from rig.config import load_config


def _small_paper_rig():
    # The paper-orthogonal scene seen by a quarter-size camera (fast), same pose.
    rig = preset("paper-orthogonal")
    cam = rig.procam.camera
    small = Intrinsics(190, 143, np.array([[cam.fx / 4, 0, 94.5], [0, cam.fy / 4, 71.0], [0, 0, 1]]))
    return replace(rig, procam=ProCam(small, rig.procam.projector, rig.procam.R_proj_cam, rig.procam.t_proj_cam))


def test_write_simulation_writes_a_reproducible_case(tmp_path):
    rig = _small_paper_rig()
    pattern = GridPattern(pitch_px=20.0, lines=21)
    options = RenderOptions(noise_grey=1.5, supersample=2, bit_depth=16)
    out = write_simulation(tmp_path / "case", rig=rig, pattern=pattern, options=options, seed=4, frames=2)
    frames = sorted((out / "frames").glob("*.png"))
    assert [f.name for f in frames] == ["000000.png", "000001.png"]
    # the frames are exactly what the simulator renders with that seed
    world = SimWorld(rig, options=options, seed=4)
    image = pattern.render(1024, 1024)
    for f in frames:
        on_disk = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        assert on_disk.dtype == np.uint16 and np.array_equal(on_disk, world.render(image))
    assert np.array_equal(cv2.imread(str(out / "pattern.png"), cv2.IMREAD_UNCHANGED), image)
    with np.load(out / "truth.npz") as data:
        truth = Truth.from_dict(data)
    for k, v in world.truth.as_dict().items():
        np.testing.assert_array_equal(getattr(truth, k), v)
    cal = load_calibration(out / "calibration.json").to_procam()
    np.testing.assert_allclose(cal.R_proj_cam, rig.procam.R_proj_cam, atol=1e-12)
    np.testing.assert_allclose(cal.t_proj_cam, rig.procam.t_proj_cam)
    np.testing.assert_allclose(cal.camera.K, rig.procam.camera.K)
    cfg = load_config(out / "rig.toml")
    assert cfg.camera.device == "replay:" + str(out.resolve() / "frames")
    assert cfg.projector.port == "sim" and cfg.sim.scene == "paper-orthogonal" and cfg.sim.bit_depth == 16
    assert cfg.calibration == out.resolve() / "calibration.json"
    assert cfg.pattern == pattern
    assert (cfg.reconstruction.depth_min_mm, cfg.reconstruction.depth_max_mm) == rig.depth_range_mm


def test_rig_simulate_cli_writes_the_case_and_says_so(tmp_path, capsys):
    out = tmp_path / "sim"
    code = main(["simulate", "--scene", "paper-parallel", "--out", str(out), "--supersample", "1", "--noise-grey", "0", "--seed", "2"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "paper-parallel" in printed and str(out) in printed and "truth.npz" in printed
    img = cv2.imread(str(out / "frames" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (570, 758) and img.dtype == np.uint8
    with np.load(out / "truth.npz") as data:
        lit = data["lit"]
    assert lit.mean() > 0.5
    assert img[lit].mean() > img[~lit & np.isfinite(np.load(out / "truth.npz")["depth_cam"])].mean()


def test_rig_simulate_cli_rejects_an_unknown_scene(tmp_path, capsys):
    assert main(["simulate", "--scene", "nowhere", "--out", str(tmp_path / "x")]) == 2
    assert "tabletop, paper-parallel" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
