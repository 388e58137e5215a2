"""`rig check`: devices, one trigger, one frame, and a verdict on the camera placement."""

from __future__ import annotations

import numpy as np

from calibration.file import CalibrationFile, save_calibration
from calibration.models import ProCam, look_at
from drivers.sim import preset
from rig.cli import main


def test_default_rig_checks_ok(capsys):
    assert main(["check"]) == 0
    out = capsys.readouterr().out
    assert "trigger:   pattern 0 shown" in out and "labelling is well posed" in out and out.rstrip().endswith("rig check: OK")
    assert "more than 0.15 projector px RMS (epipolar floor 0.10 px" in out  # the simulator's exact calibration: the default


def test_check_reports_the_floor_of_a_rough_calibration(tmp_path, capsys):
    truth = preset("tabletop").procam
    save_calibration(CalibrationFile.from_procam(truth, quality={"stereo_rms_px": 0.31}), tmp_path / "cal.json")
    (tmp_path / "rig.toml").write_text('calibration = "cal.json"\n')
    assert main(["check", "--config", str(tmp_path / "rig.toml")]) == 0
    assert "epipolar floor 0.31 px" in capsys.readouterr().out


def test_degenerate_placement_is_reported(tmp_path, capsys):
    truth = preset("tabletop").procam
    t = np.array([300.0, 0.0, 0.0])  # straight beside the projector: epipolar lines along a lattice direction
    bad = ProCam(truth.camera, truth.projector, look_at(t, np.array([0.0, 0.0, 850.0])), t)
    save_calibration(CalibrationFile.from_procam(bad), tmp_path / "truth.json")
    (tmp_path / "rig.toml").write_text('[sim]\ntruth = "truth.json"\n[reconstruction]\ndepth_min_mm = 700\ndepth_max_mm = 1100\n')
    assert main(["check", "--config", str(tmp_path / "rig.toml")]) == 1
    captured = capsys.readouterr()
    assert "labelling is ill-posed" in captured.out and "cannot label the grid reliably" in captured.err


def test_usage_errors_are_one_message_and_exit_2(capsys):
    assert main(["scan", "--bogus"]) == 2
    assert "No such option: --bogus" in capsys.readouterr().err
    assert main(["scan", "--frames", "0"]) == 2
